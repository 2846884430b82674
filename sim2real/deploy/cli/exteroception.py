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
    """The cameras of a policy's image inputs: ``--camera-source`` on any backend, one per
    camera (:func:`attach_hardware_camera`), else on the plant its MJCF cameras
    (:func:`attach_plant_camera`); a policy with an image input on a backend that is no plant,
    without ``--camera-source``, is refused.

    Raises:
        ValueError: ``--camera-source`` for a camera the policy lacks, a camera given twice, a
            camera of the policy left without one, a hardware camera that does not open or
            deliver (CameraError), or with ``--backend sim`` off the wall clock (without
            ``--realtime``); a hardware backend without one; the plant camera's refusals."""
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
        if len(images) == 1:
            raise ValueError(
                f"the policy reads camera '{images[0].camera}' ({images[0].input}); --backend "
                f"{getattr(args, 'backend', '?')} has none: give --camera-source "
                f"{images[0].camera}=KIND:WHERE (opencv:INDEX, realsense:SERIAL, ros2:/TOPIC; "
                "docs/cameras.md)"
            )
        names = [b.camera for b in images]
        raise ValueError(
            f"the policy reads cameras {names}; --backend {getattr(args, 'backend', '?')} has "
            "none: give one --camera-source NAME=KIND:WHERE per camera, NAME one of "
            f"{', '.join(names)} (opencv:INDEX, realsense:SERIAL, ros2:/TOPIC; docs/cameras.md)"
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
    """The hardware cameras of ``--camera-source`` (one per camera of the policy) made the
    backend's ``camera_source`` (one camera: its driver; several: a
    :class:`~sim2real.deploy.backends.camera.sources.CameraSources` by name; the runtime's camera
    stage reads it), once each one's first frame arrived and fits its block; said on stderr;
    returned.

    Raises:
        ValueError: a source naming no camera of the policy, a camera given twice, a camera of
            the policy without a source, a camera that does not open, delivers nothing within
            ``wait`` s, or a frame the block refuses (one line naming ``--camera-source`` and
            the expected names)."""
    from sim2real.deploy.backends.camera.sources import CameraSources
    from sim2real.deploy.spec.camera import CameraError

    names = [b.camera for b in images]
    if not images:
        raise CameraError(f"{sources[0].label}: the policy has no image input (no images entry)")
    given: dict = {}
    for source in sources:
        if source.name not in names:
            raise CameraError(
                f"{source.label}: the policy has no camera '{source.name}' (its images entries "
                f"name {names}); expected NAME to be one of them"
            )
        if source.name in given:
            raise CameraError(
                f"{source.label}: camera '{source.name}' given twice; expected one "
                f"--camera-source per camera of {names}"
            )
        given[source.name] = source
    missing = [n for n in names if n not in given]
    if missing:
        raise CameraError(
            f"--camera-source: camera {missing[0]!r} of the policy has none; expected one "
            f"--camera-source NAME=KIND:WHERE for each of {names}"
        )
    opened = {}
    try:
        for name, block in zip(names, images, strict=True):
            opened[name] = open_hardware_camera(given[name], block)
        for camera in opened.values():
            camera.feed.wait_first(wait)
    except Exception:
        for camera in opened.values():
            camera.close()
        raise
    camera = opened[names[0]] if len(names) == 1 else CameraSources(opened)
    backend.camera_source = camera
    for name in names:
        source = given[name]
        print(f"deploy-run: camera '{name}' from {source.kind}:{source.where}", file=sys.stderr)
    return camera


def close_camera(backend) -> None:
    """Close the backend's hardware camera (its thread and device), if it has one."""
    camera = getattr(backend, "camera_source", None)
    if hasattr(camera, "sources"):  # several cameras: their drivers
        camera.close(hardware_only=True)
        return
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
    images = getattr(spec, "images", ())
    if args.camera_faults == "drawn":  # its own stream: the other draws of --seed stay as they are
        # several cameras: camera i's from [seed, 99, i] (the first's as it would be alone)
        faults = {
            b.camera: plant_camera.CameraFaultRanges().sample(
                np.random.default_rng([args.seed, 99] + ([i] if i else []))
            )
            for i, b in enumerate(images)
        }
        if len(images) <= 1:
            faults = next(iter(faults.values()), None)
    try:
        camera = plant_camera.attach_plant_camera(
            backend, spec, args.camera_rate, args.camera_latency, faults=faults, seed=args.seed
        )
    except RuntimeError as exc:  # no OpenGL context: one line naming MUJOCO_GL
        raise ValueError(str(exc)) from None
    for cam in getattr(camera, "sources", {"": camera}).values() if camera is not None else ():
        print(
            f"deploy-run: {'colour' if cam.block.kind == 'rgb' else 'depth'} camera "
            f"'{cam.block.camera}' {cam.block.shape[0]}x"
            f"{cam.block.shape[1]} at {cam.rate:g} Hz, latency {cam.latency:g} s, "
            f"{cam.noise.to_dict()}, faults {cam.faults.to_dict()}",
            file=sys.stderr,
        )
    return camera


def camera_report(rt, backend) -> dict | None:
    """The report's ``camera``: the runtime's camera stage (frames taken, repeated, the oldest
    age) and the plant camera's counts (``plant``: captured, delivered, dropped, late, frozen)
    or a hardware camera's (``hardware``: its source, frames received, taken, overwritten, the
    last one's age); several cameras: that section per camera name; None without an image
    input."""
    if rt.cameras is None:
        return None

    def section(stage, source) -> dict:
        key = "hardware" if hasattr(source, "feed") else "plant"
        return {**stage.summary(), key: source.summary() if source is not None else None}

    if len(rt.cameras.inputs) > 1:
        return {c.block.camera: section(c, c.source) for c in rt.cameras.inputs}
    return section(rt.cameras, getattr(backend, "camera_source", None))


def show_goal(backend, goal) -> None:
    """The plant camera's task scene shows ``goal`` ((envs, 3) m, the runtime's goals) at its
    goal marker (:meth:`sim2real.deploy.backends.sim.plant_camera.PlantCamera.show_goal`); a
    hardware camera or none: nothing."""
    show = getattr(getattr(backend, "camera_source", None), "show_goal", None)
    if show is not None:
        show(goal)
