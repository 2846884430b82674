"""A camera policy's soak (:func:`soak_camera`): the plant's camera on every session of a batch,
each session's camera faults drawn from its seed, and the camera section of its result
(:func:`camera_result`).

A policy with an image block (:mod:`sim2real.deploy.spec.camera`) gets the plant's depth camera
(:func:`sim2real.deploy.backends.sim.camera.attach_depth_camera`: the robot's task scene where it
has one, its goal marker at the session's goals; the block's rate and latency; the D435 depth
model). With the session's faults on (``SessionConfig.faults``), each session draws its camera
faults (:class:`~sim2real.deploy.backends.sim.camera.CameraFaultRanges`: dropped, late and frozen
frames, a covered lens, a knocked mount) from its own stream (``camera``), so that its other draws
stay as they were. A frozen or silent camera is a stale sensor: the runtime safe-stops the robot
(``stale_sensor``) and the soak's operator restarts it, as after any safe stop.
"""

from __future__ import annotations

import numpy as np

from sim2real.eval.world.session_draw import session_rng


def soak_camera(backend, spec, configs):
    """The plant camera of a batch of sessions (``configs``, one env each) for a spec with an
    image block, its faults drawn per session; None for a spec without one.

    Raises:
        CameraError: the robot's MJCF (or task scene) lacks the block's camera. RuntimeError: no
            OpenGL context to render with."""
    if not getattr(spec, "images", ()):
        return None
    from sim2real.deploy.backends.sim.camera import (
        CameraFaultRanges,
        CameraFaults,
        attach_depth_camera,
    )

    faults = [
        CameraFaultRanges().sample(session_rng(c.seed, "camera")) if c.faults else CameraFaults()
        for c in configs
    ]
    seed = int(session_rng(configs[0].seed, "camera").integers(2**31))
    return attach_depth_camera(backend, spec, faults=faults, seed=seed)


def show_goals(camera, goal: np.ndarray) -> None:
    """The camera's task scene (where it has one) shows ``goal`` ((envs, 3) m, the runtime's)."""
    if camera is not None and camera.scene is not None:
        camera.scene.goal = goal


def camera_result(batch, e: int) -> dict | None:
    """Session ``e``'s ``camera`` section: the faults drawn, the plant camera's frames
    (captured, delivered, dropped, late, frozen), the runtime's (taken, repeated, the oldest
    age) and the camera's safe stops (``stale_sensor``, with the runtime's verdict of each: its
    frames frozen, or none arriving); None without a camera."""
    camera = getattr(batch, "camera", None)
    if camera is None:
        return None
    stage, rt = batch.rt.cameras, batch.rt
    return {
        "camera": camera.block.camera,
        "rate_hz": camera.rate,
        "latency_s": camera.latency,
        "faults": camera.env_faults[e].to_dict(),
        **{
            k: int(getattr(camera, k)[e])
            for k in ("frames", "delivered", "dropped", "spiked", "frozen")
        },
        "frames_taken": int(stage.taken[e]),
        "frames_repeated": int(stage.repeated[e]),
        "oldest_s": round(float(stage.oldest[e]), 6),
        "stale_stops": int(rt.counters.faults["stale_sensor"][e]),
        # the runtime's record of each stop the camera made (its verdict: frozen or silent)
        "stops": [
            {"t_s": r["t_s"], "camera_s": r["camera_s"], "verdict": r["verdict"]}
            for r in rt.stale_stops.records
            if r["env"] == e and r.get("camera_s") is not None
        ],
    }
