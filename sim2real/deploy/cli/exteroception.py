"""What deploy-run attaches to a simulated plant for a policy's exteroceptive inputs: the
elevation map of a ``height_scan`` block (:func:`attach_height_map`) and the depth camera of an
image input (:func:`attach_camera`), and the run report's camera section
(:func:`camera_report`)."""

from __future__ import annotations

import sys

import numpy as np


def attach_height_map(args, backend, spec) -> None:
    """A policy with a ``height_scan`` block on the plant: its ray casts as the elevation map,
    with noise, latency, dropout and drift drawn from ``--seed``
    (:mod:`sim2real.deploy.backends.sim.height_scan`), said on stderr."""
    from sim2real.deploy.backends.sim.height_scan import HeightScanRanges, attach_height_scanner

    noise = HeightScanRanges().sample(np.random.default_rng(args.seed))
    if attach_height_scanner(backend, spec, noise, args.seed) is not None:
        print(
            f"deploy-run: height scan: ray casts on the plant, {noise.to_dict()}", file=sys.stderr
        )


def attach_camera(args, backend, spec) -> None:
    """A policy with a depth image input on the plant: its MJCF camera rendered at
    ``--camera-rate`` with ``--camera-latency``, the D435 depth model and, with
    ``--camera-faults drawn``, faults drawn from ``--seed``
    (:mod:`sim2real.deploy.backends.sim.camera`), said on stderr.

    Raises:
        ValueError: a camera the MJCF lacks (CameraError), a rate <= 0 or a latency < 0, no
            OpenGL context to render with."""
    from sim2real.deploy.backends.sim.camera import CameraFaultRanges, attach_depth_camera

    if getattr(spec, "images", ()) and not (
        (args.camera_rate is None or args.camera_rate > 0)
        and (args.camera_latency is None or args.camera_latency >= 0)
    ):
        raise ValueError(
            f"--camera-rate {args.camera_rate} Hz, --camera-latency {args.camera_latency} s: "
            "expected a positive rate and a latency >= 0"
        )
    faults = None
    if args.camera_faults == "drawn":  # its own stream: the other draws of --seed stay as they are
        faults = CameraFaultRanges().sample(np.random.default_rng([args.seed, 99]))
    try:
        camera = attach_depth_camera(
            backend, spec, args.camera_rate, args.camera_latency, faults=faults, seed=args.seed
        )
    except RuntimeError as exc:  # no OpenGL context: one line naming MUJOCO_GL
        raise ValueError(str(exc)) from None
    if camera is not None:
        print(
            f"deploy-run: depth camera '{camera.block.camera}' {camera.block.shape[0]}x"
            f"{camera.block.shape[1]} at {camera.rate:g} Hz, latency {camera.latency:g} s, "
            f"{camera.noise.to_dict()}, faults {camera.faults.to_dict()}",
            file=sys.stderr,
        )


def camera_report(rt, backend) -> dict | None:
    """The report's ``camera``: the runtime's camera stage (frames taken, repeated, the oldest
    age) and the plant camera's counts (captured, delivered, dropped, late, frozen); None
    without an image input."""
    if rt.cameras is None:
        return None
    source = getattr(backend, "camera_source", None)
    return {**rt.cameras.summary(), "plant": source.summary() if source is not None else None}


def show_goal(backend, goal) -> None:
    """The plant camera's task scene (where the robot has one) shows ``goal`` ((envs, 3) m, the
    runtime's goals, written in place each tick) at its goal marker."""
    scene = getattr(getattr(backend, "camera_source", None), "scene", None)
    if scene is not None:
        scene.goal = goal
