"""What deploy-run attaches for a policy's exteroceptive inputs: the elevation map of a
``height_scan`` block on a simulated plant (:func:`attach_height_map`), the camera of an image
input (:func:`attach_camera`: a hardware source of ``--camera-source`` on any backend, else the
plant's MJCF camera), and the run report's camera section (:func:`camera_report`)."""

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


#: s deploy-run waits for a hardware camera's first frame before it refuses it (our choice: a
#: ROS 2 topic needs discovery, a USB camera its first exposure).
FIRST_FRAME_S = 10.0


def attach_camera(args, backend, spec) -> None:
    """The camera of a policy's image input: ``--camera-source`` on any backend
    (:func:`attach_hardware_camera`), else on the plant its MJCF camera
    (:func:`attach_plant_camera`); a policy with an image input on a backend that is no plant,
    without ``--camera-source``, is refused.

    Raises:
        ValueError: ``--camera-source`` for a camera the policy lacks, or a hardware camera
            that does not open or deliver (CameraError), or with ``--backend sim`` off the wall
            clock (without ``--realtime``); a hardware backend without one; the plant camera's
            refusals."""
    sources = getattr(args, "camera_source", None) or []
    images = getattr(spec, "images", ())
    if sources:
        if getattr(args, "backend", None) == "sim" and not getattr(args, "realtime", False):
            raise ValueError(
                f"{sources[0].label}: a hardware camera delivers on the wall clock; with "
                "--backend sim add --realtime (the plant then runs on it too)"
            )
        attach_hardware_camera(sources, backend, images)
        return
    camera = attach_plant_camera(args, backend, spec)
    if images and camera is None:
        raise ValueError(
            f"the policy reads camera '{images[0].camera}' ({images[0].input}); --backend "
            f"{getattr(args, 'backend', '?')} has none: give --camera-source "
            f"{images[0].camera}=KIND:WHERE (opencv:INDEX, realsense:SERIAL, ros2:/TOPIC; "
            "docs/cameras.md)"
        )


def open_hardware_camera(source, block):
    """The driver of one ``--camera-source`` value (a :class:`~sim2real.deploy.backends.camera.
    options.CameraSource`) for ``block``: an :class:`~sim2real.deploy.backends.camera.
    opencv_source.OpenCvCamera`, a :class:`~sim2real.deploy.backends.camera.realsense_source.
    RealSenseCamera` or an :class:`~sim2real.deploy.ros2.camera.ImageSubscriber`, started.

    Raises:
        CameraError: the driver is missing or the device, file or recording does not open.
        Ros2UnavailableError: ``ros2:`` without ROS 2."""
    from sim2real.deploy.backends.camera.convert import target_for

    target = target_for(block)
    if source.kind == "opencv":
        from sim2real.deploy.backends.camera.opencv_source import OpenCvCamera

        return OpenCvCamera(source.where, target, source.label, block.rate, loop=source.loop)
    if source.kind == "realsense":
        from sim2real.deploy.backends.camera.realsense_source import RealSenseCamera

        return RealSenseCamera(source.where, target, source.label, block.rate, loop=source.loop)
    from sim2real.deploy.ros2.camera import ImageSubscriber

    return ImageSubscriber(source.where, target, source.label)


def attach_hardware_camera(sources, backend, images, wait: float = FIRST_FRAME_S):
    """The hardware camera of ``--camera-source`` made the backend's ``camera_source`` (the
    runtime's camera stage reads it), once its first frame arrived and fits the block; said on
    stderr; returned.

    Raises:
        ValueError: a source naming no camera of the policy, two sources, a camera that does
            not open, delivers nothing within ``wait`` s, or a frame the block refuses."""
    from sim2real.deploy.spec.camera import CameraError

    names = [b.camera for b in images]
    if not images:
        raise CameraError(f"{sources[0].label}: the policy has no image input (no images entry)")
    if len(sources) > 1:
        raise CameraError(
            f"{sources[1].label}: one --camera-source per run (the runtime reads one camera)"
        )
    source = sources[0]
    if source.name not in names:
        raise CameraError(
            f"{source.label}: the policy has no camera '{source.name}' (its images entries name "
            f"{names}); expected NAME to be one of them"
        )
    camera = open_hardware_camera(source, images[names.index(source.name)])
    try:
        camera.feed.wait_first(wait)
    except Exception:
        camera.close()
        raise
    backend.camera_source = camera
    print(f"deploy-run: camera '{source.name}' from {source.kind}:{source.where}", file=sys.stderr)
    return camera


def close_camera(backend) -> None:
    """Close the backend's hardware camera (its thread and device), if it has one."""
    camera = getattr(backend, "camera_source", None)
    close = getattr(camera, "close", None)
    if close is not None and hasattr(camera, "feed"):  # the plant's camera closes with the plant
        close()


def attach_plant_camera(args, backend, spec):
    """A policy with a depth or RGB image input on the plant: its MJCF camera rendered at
    ``--camera-rate`` with ``--camera-latency``, the D435 depth model (or the OV5647 colour
    model, :mod:`sim2real.deploy.backends.sim.rgb_camera`) and, with
    ``--camera-faults drawn``, faults drawn from ``--seed``
    (:mod:`sim2real.deploy.backends.sim.camera`), said on stderr.

    Raises:
        ValueError: a camera the MJCF lacks (CameraError), a rate <= 0 or a latency < 0, no
            OpenGL context to render with."""
    from sim2real.deploy.backends.sim import camera as plant_camera

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
        faults = plant_camera.CameraFaultRanges().sample(np.random.default_rng([args.seed, 99]))
    try:
        camera = plant_camera.attach_plant_camera(
            backend, spec, args.camera_rate, args.camera_latency, faults=faults, seed=args.seed
        )
    except RuntimeError as exc:  # no OpenGL context: one line naming MUJOCO_GL
        raise ValueError(str(exc)) from None
    if camera is not None:
        print(
            f"deploy-run: {'colour' if camera.block.kind == 'rgb' else 'depth'} camera "
            f"'{camera.block.camera}' {camera.block.shape[0]}x"
            f"{camera.block.shape[1]} at {camera.rate:g} Hz, latency {camera.latency:g} s, "
            f"{camera.noise.to_dict()}, faults {camera.faults.to_dict()}",
            file=sys.stderr,
        )
    return camera


def camera_report(rt, backend) -> dict | None:
    """The report's ``camera``: the runtime's camera stage (frames taken, repeated, the oldest
    age) and the plant camera's counts (``plant``: captured, delivered, dropped, late, frozen)
    or a hardware camera's (``hardware``: its source, frames received, taken, overwritten, the
    last one's age); None without an image input."""
    if rt.cameras is None:
        return None
    source = getattr(backend, "camera_source", None)
    key = "hardware" if hasattr(source, "feed") else "plant"
    return {**rt.cameras.summary(), key: source.summary() if source is not None else None}


def show_goal(backend, goal) -> None:
    """The plant camera's task scene shows ``goal`` ((envs, 3) m, the runtime's goals) at its
    goal marker (:meth:`sim2real.deploy.backends.sim.plant_camera.PlantCamera.show_goal`); a
    hardware camera or none: nothing."""
    show = getattr(getattr(backend, "camera_source", None), "show_goal", None)
    if show is not None:
        show(goal)
