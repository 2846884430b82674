"""The camera faults of a soak session, drawn from its seed (:func:`session_camera_faults`), on the
plant camera of a batch whose policy reads an image (:func:`attach_session_cameras`), and the
session result's ``camera`` section (:func:`camera_result`).

Each session draws its :class:`sim2real.deploy.backends.sim.camera.CameraFaults` (dropped
frames, latency spikes, frozen spells, a covered lens, a camera knocked a few degrees on its
mount, a lighting change; the ranges :class:`~sim2real.deploy.backends.sim.camera.
CameraFaultRanges`) from its own ``camera`` stream (``sim2real.eval.world.session_draw.STREAMS``),
so a session's other draws are what they were without a camera; the same generator then draws
the camera's per-frame faults and sensor noise, so a session's camera is its own whatever its
neighbours in the batch. A session run without faults (``SessionConfig.faults`` False) draws
none: its camera only has its sensor model. A frame that comes late or frozen is judged by the
runtime's camera stage (:mod:`sim2real.deploy.runtime.camera`): stale past its limit, a safe stop
``stale_sensor`` like any sensor.

A policy with several cameras (a LeRobot export's ``front`` and ``wrist``) has one plant camera per
image block, each with faults of its own: the first camera draws from the session's ``camera``
stream as a lone camera does, camera ``i`` from ``default_rng([seed, STREAMS["camera"], i])``
(:func:`camera_rng`); the result's ``camera`` section then holds ``cameras`` (one section per
camera name) beside the session's verdict, whose labels name the camera
(:mod:`sim2real.eval.soak.camera_verdict`).

Hooks (the only lines outside this module): :class:`sim2real.eval.soak.batch.SessionBatch`
calls :func:`attach_session_cameras` before it makes its runtime;
:func:`sim2real.eval.soak.result.session_result` adds :func:`camera_result`'s section.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.backends.sim.camera import (
    CameraFaultRanges,
    CameraFaults,
    attach_plant_camera,
)
from sim2real.eval.world.session_draw import STREAMS, session_rng

#: The session stream the camera draws from (``sim2real.eval.world.session_draw.STREAMS``).
CAMERA_STREAM = "camera"


def session_camera_faults(
    seed: int, ranges: CameraFaultRanges | None = None, rng=None
) -> CameraFaults:
    """Session ``seed``'s camera faults: the first draws of its ``camera`` stream (or of
    ``rng``, that stream's generator, when given).

    Raises:
        ValueError: a negative seed (:func:`sim2real.eval.world.session_draw.session_rng`)."""
    rng = session_rng(seed, CAMERA_STREAM) if rng is None else rng
    return (ranges or CameraFaultRanges()).sample(rng)


def camera_rng(seed: int, i: int = 0) -> np.random.Generator:
    """The generator of camera ``i`` of session ``seed`` (module docstring): the session's
    ``camera`` stream for the first, ``default_rng([seed, STREAMS["camera"], i])`` after it.

    Raises:
        ValueError: a negative seed."""
    rng = session_rng(seed, CAMERA_STREAM)  # checks the seed
    return rng if i == 0 else np.random.default_rng([int(seed), STREAMS[CAMERA_STREAM], i])


def attach_session_cameras(backend, spec, configs, ranges: CameraFaultRanges | None = None):
    """For a batch's plant ``backend`` (one env per session of ``configs``, in order) and a
    policy ``spec`` with an image block: the plant's camera, each env with its session's drawn
    faults (none where the session runs without faults) and its session's generator, made the
    runtime's frame source (several image blocks: one camera each, each with its own faults
    and generator, :func:`camera_rng`); None without an image block.

    Raises:
        CameraError: the robot's MJCF has no camera of the block's name.
        RuntimeError: no OpenGL context (naming ``MUJOCO_GL``).
    """
    images = getattr(spec, "images", ())
    if not images:
        return None
    faults, seeds = {}, {}
    for i, block in enumerate(images):
        rngs = [camera_rng(c.seed, i) for c in configs]
        faults[block.camera] = [
            session_camera_faults(c.seed, ranges, rng) if c.faults else CameraFaults()
            for c, rng in zip(configs, rngs, strict=True)
        ]
        seeds[block.camera] = rngs
    if len(images) == 1:
        (faults,), (seeds,) = faults.values(), seeds.values()
    return attach_plant_camera(backend, spec, faults=faults, seed=seeds)


def camera_result(session) -> dict:
    """The session result's ``camera`` section, ``{}`` without a camera (several cameras:
    ``{"camera": {cameras: {name: the per-camera fields below}, verdict, stale_stops}}``):
    ``{"camera": {camera,
    kind, rate_hz, latency_s, faults (the drawn CameraFaults), frames, delivered, dropped,
    spiked, frozen (the plant's counts), frames_taken, frames_repeated (the runtime's: fresh
    frames and frozen ones refused), oldest_s (the largest age of the last fresh frame, s),
    stale_stops (the first stale-camera stops of the session, each ``{t_s, camera_s, followed,
    verdict}``: its time, the last fresh frame's age, what the camera's faults did in the
    second before (:meth:`~sim2real.deploy.backends.sim.plant_camera.PlantCamera.recent`) and
    the runtime's verdict; all are counted in ``verdict.stops``), verdict (what the faults did:
    :meth:`sim2real.eval.soak.camera_verdict.CameraVerdict.section`)}}``."""
    b, e = session.batch, session.e
    source = getattr(b.backend, "camera_source", None)
    stage = getattr(b.rt, "cameras", None)
    if source is None or stage is None:
        return {}

    def one(src, st) -> dict:
        return {
            **src.summary(e),
            "frames_taken": int(st.taken[e]),
            "frames_repeated": int(st.repeated[e]),
            "oldest_s": round(float(st.oldest[e]), 6),
        }

    if len(stage.inputs) == 1:
        out = one(source, stage)
    else:  # several cameras: a section each (module docstring)
        out = {"cameras": {c.block.camera: one(c.source, c) for c in stage.inputs}}
    verdict = getattr(b, "camera_verdict", None)
    if verdict is not None:
        out["verdict"] = verdict.section(e, out)
        out["stale_stops"] = out["verdict"]["stops"]["sample"]
    return {"camera": out}
