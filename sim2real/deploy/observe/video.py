"""``deploy-run --video run.mp4``: render a run offscreen with MuJoCo and write an H.264 MP4.

The recorder keeps its own copy of the robot's MuJoCo model and data: it poses them from the
plant's true joint positions (simulation) or the runtime's estimate (a servo bus), so the run
itself is the same with or without it. Drawn on top of the robot (env 0): the goal as a green
sphere, the end-effector path of the last ``TRAIL_SECONDS`` as a fading trail, and the links of
joints whose target the guard changed on the frame's tick tinted red, over a dark backdrop plane
(no shadows, reflections or skybox: a software renderer draws three times as many frames). The
soak's film strip (:mod:`sim2real.eval.film.render`) renders its replays with the same recorder.

Rendering uses :class:`mujoco.Renderer`, whose OpenGL backend ``MUJOCO_GL`` selects (``egl``
headless; ``osmesa`` software; ``glfw`` with a display); frames go to ffmpeg through
``imageio-ffmpeg`` (its own ffmpeg binary; the ``video`` extra). Where no GL context can be made,
:func:`open_video` prints one line naming ``MUJOCO_GL`` and the run goes on without video.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np

#: Seconds of end-effector path drawn behind the end effector.
TRAIL_SECONDS = 2.0
GOAL_RGBA = np.array([0.1, 0.8, 0.2, 0.6], dtype=np.float32)
TRAIL_RGB = np.array([1.0, 0.55, 0.0], dtype=np.float32)
TINT_RGBA = np.array([0.9, 0.15, 0.1, 1.0], dtype=np.float32)
BACKDROP_RGBA = np.array([0.2, 0.23, 0.28, 1.0], dtype=np.float32)


def parse_size(text: str) -> tuple[int, int]:
    """``'640x480'`` -> (width, height) pixels.

    Raises:
        ValueError: not WIDTHxHEIGHT with both in [16, 4096].
    """
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size {text!r}: expected WIDTHxHEIGHT, e.g. 640x480") from None
    if not (16 <= w <= 4096 and 16 <= h <= 4096):
        raise ValueError(f"--size {text!r}: width and height must be within 16..4096 pixels")
    return w, h


class VideoRecorder:
    """Render env 0 of a run at ``fps`` frames per second of run time into an MP4.

    Call it after every tick (it renders when a frame is due) and :meth:`close` at the end.

    Args:
        robot: The :class:`~robots.Robot` (``mjcf_path``, ``ee_site_id``, joint names).
        path: Output ``.mp4`` (written to ``path + '.part.mp4'``, renamed on close).
        fps: Frames per second of run time (> 0).
        size: (width, height) pixels.
        camera: Optional MJCF camera name; default a free camera framing the robot.
        true_state: Optional callable returning the (envs, n) true joint positions, rad
            (a simulated plant's ``true_position``); default the runtime's estimate.
        model: Optional ``mujoco.MjModel`` to draw (copied), e.g. a soak session's randomized
            plant model; default the robot's MJCF.
        start: Run time of the first frame, s (a replay that starts mid-run).
        crf: x264 constant rate factor (quality: 18 near lossless .. 35 small; ffmpeg's 23).
        verbose: Print one line on :meth:`close`.

    Attributes:
        frames: Frames written. render_s: s spent rendering and encoding them.
        last_frame: (height, width, 3) uint8, the last frame rendered (None before).

    Raises:
        ValueError: an unknown camera or ``fps`` not > 0.
        RuntimeError: no OpenGL context could be made (message names ``MUJOCO_GL``).
        ImportError: imageio-ffmpeg is not installed.
    """

    def __init__(
        self,
        robot,
        path,
        fps=30.0,
        size=(640, 480),
        camera=None,
        true_state=None,
        model=None,
        start=0.0,
        crf=23,
        verbose=True,
    ):
        import copy

        import mujoco

        if not (np.isfinite(fps) and fps > 0):
            raise ValueError(f"--fps: expected frames per second > 0, got {fps}")
        import imageio_ffmpeg

        self.mj = mujoco
        self.robot, self.path, self.fps = robot, Path(path), float(fps)
        self.width, self.height = size
        if model is None:
            m = mujoco.MjModel.from_xml_path(str(robot.mjcf_path))
        else:
            m = copy.deepcopy(model)
        m.vis.global_.offwidth = max(m.vis.global_.offwidth, self.width)
        m.vis.global_.offheight = max(m.vis.global_.offheight, self.height)
        self.model, self.data = m, mujoco.MjData(m)
        self.qpos_adr = np.array([m.joint(name).qposadr[0] for name in robot.joint_names])
        self.joint_body = np.array([m.joint(name).bodyid[0] for name in robot.joint_names])
        self.camera = _camera(m, self.data, camera)
        mujoco.mj_kinematics(m, self.data)
        self.renderer = _renderer(m, self.height, self.width)
        self.true_state = true_state
        self.goal_radius = float(robot.config.task.success_radius)
        self._tmp = self.path.with_name(self.path.name + ".part.mp4")
        self._writer = imageio_ffmpeg.write_frames(
            str(self._tmp),
            (self.width, self.height),
            fps=self.fps,
            codec="libx264",
            pix_fmt_in="rgb24",
            pix_fmt_out="yuv420p",
            macro_block_size=2,
            ffmpeg_log_level="error",
            quality=None,  # the rate factor below instead of imageio-ffmpeg's mapping
            output_params=["-crf", str(int(crf)), "-movflags", "+faststart"],
        )
        self._writer.send(None)
        self._done = False  # closed or discarded
        self._trail = np.zeros((max(2, int(TRAIL_SECONDS * self.fps)), 3))
        self._trail_len = 0
        self._next = float(start)
        self.verbose = verbose
        self.last_frame = None
        self._raw = np.zeros((1, robot.n_joints))
        self.frames = 0
        self.render_s = 0.0

    def guard_joints(self, rt) -> np.ndarray:
        """(n,) bool: env 0's joints whose target the guard changed on the last tick (RUNNING
        only; in the other modes the runtime overrides the target itself)."""
        from sim2real.deploy.core.modes import RUNNING

        if rt.mode[0] != RUNNING:
            return np.zeros(rt.n, dtype=bool)
        raw = rt.spec.action_to_target(rt.action[:1], _Env0(rt.state), out=self._raw)[0]
        return np.abs(raw - rt.target[0]) > 1e-9

    def __call__(self, rt) -> None:
        """Render a frame if one is due at ``rt.time``."""
        if rt.time + 1e-9 < self._next:
            return
        self._next += 1.0 / self.fps
        t0 = time.perf_counter()
        mj, m, d = self.mj, self.model, self.data
        q = self.true_state()[0] if self.true_state is not None else rt.state.q[0]
        d.qpos[self.qpos_adr] = q
        mj.mj_kinematics(m, d)
        ee = d.site_xpos[self.robot.ee_site_id].copy()
        trail = self._trail
        trail[:-1] = trail[1:]
        trail[-1] = ee
        self._trail_len = min(self._trail_len + 1, len(trail))
        r = self.renderer
        r.update_scene(d, camera=self.camera)
        scene = r.scene
        tinted = set(self.joint_body[self.guard_joints(rt)].tolist())
        if tinted:
            for i in range(scene.ngeom):
                g = scene.geoms[i]
                if g.objtype == mj.mjtObj.mjOBJ_GEOM and m.geom_bodyid[g.objid] in tinted:
                    g.rgba[:] = TINT_RGBA
        self._add_backdrop(scene)
        self._add_sphere(scene, rt.goal[0], self.goal_radius, GOAL_RGBA)
        n = self._trail_len
        for k in range(len(trail) - n, len(trail) - 1):
            age = (len(trail) - 1 - k) / len(trail)
            rgba = np.append(TRAIL_RGB, 0.9 * (1.0 - age)).astype(np.float32)
            self._add_line(scene, trail[k], trail[k + 1], rgba)
        frame = self.last_frame = r.render()
        self._writer.send(np.ascontiguousarray(frame))
        self.frames += 1
        self.render_s += time.perf_counter() - t0

    def _add_backdrop(self, scene) -> None:
        """A light plane under the robot (normal +Z, below the model's lowest point along Z),
        so that the picture is not black around it."""
        if scene.ngeom >= scene.maxgeom:
            return
        mj, m = self.mj, self.model
        size = 4.0 * m.stat.extent
        z = m.stat.center[2] - 0.6 * m.stat.extent
        mj.mjv_initGeom(
            scene.geoms[scene.ngeom],
            mj.mjtGeom.mjGEOM_PLANE,
            np.array([size, size, 0.1]),
            np.array([m.stat.center[0], m.stat.center[1], z]),
            np.eye(3).reshape(-1),
            BACKDROP_RGBA,
        )
        scene.ngeom += 1

    def _add_sphere(self, scene, pos, radius, rgba) -> None:
        if scene.ngeom >= scene.maxgeom:
            return
        mj = self.mj
        mj.mjv_initGeom(
            scene.geoms[scene.ngeom],
            mj.mjtGeom.mjGEOM_SPHERE,
            np.array([radius, 0, 0]),
            np.asarray(pos, dtype=np.float64),
            np.eye(3).reshape(-1),
            rgba,
        )
        scene.ngeom += 1

    def _add_line(self, scene, a, b, rgba) -> None:
        if scene.ngeom >= scene.maxgeom or np.allclose(a, b):
            return
        mj = self.mj
        g = scene.geoms[scene.ngeom]
        mj.mjv_initGeom(g, mj.mjtGeom.mjGEOM_CAPSULE, np.zeros(3), np.zeros(3), np.zeros(9), rgba)
        mj.mjv_connector(g, mj.mjtGeom.mjGEOM_CAPSULE, 0.004, a, b)
        scene.ngeom += 1

    def close(self) -> Path:
        """Finish the MP4, move it to its final name and print one line (frames, frames per
        second rendered); returns the path."""
        self._done = True
        self._writer.close()
        self.renderer.close()
        os.replace(self._tmp, self.path)
        rate = self.frames / self.render_s if self.render_s > 0 else float("nan")
        if not self.verbose:
            return self.path
        print(
            f"deploy-run: video {self.path}: {self.frames} frames at {self.fps:g} fps, "
            f"{self.width}x{self.height}, rendered and encoded at {rate:.0f} frames/s"
        )
        return self.path

    def discard(self) -> None:
        """Stop the encoder and remove the unfinished ``.part.mp4``, so that a run that ended in
        an error leaves no partial video; after :meth:`close`, the MP4 is not touched."""
        if self._done:
            return
        self._done = True
        import logging

        quiet = logging.getLogger("imageio_ffmpeg")  # "no frames written": not worth a line
        level = quiet.level
        quiet.setLevel(logging.ERROR)
        try:
            self._writer.close()
        finally:
            quiet.setLevel(level)
            self.renderer.close()
            self._tmp.unlink(missing_ok=True)


class _Env0:
    """The first env's rows of a RobotState (what ``action_to_target`` reads: ``q``)."""

    def __init__(self, state):
        self.q = state.q[:1]


def _camera(m, data, camera: str | None):
    """The model's camera named ``camera`` (``ValueError`` when it has none so named), else a
    free camera on the robot's base whose frame its reach fills."""
    import mujoco

    if camera is not None:
        if mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0:
            cams = [m.camera(i).name for i in range(m.ncam)]
            raise ValueError(f"--camera {camera!r}: not in the model (cameras: {cams})")
        return camera
    cam = mujoco.MjvCamera()
    mujoco.mjv_defaultFreeCamera(m, cam)
    mujoco.mj_kinematics(m, data)
    cam.lookat[:] = data.xpos[1]  # the robot's base body
    cam.distance = 2.4 * m.stat.extent  # the reach fills the frame (fovy 45 deg)
    g = m.opt.gravity
    if abs(g[1]) > abs(g[2]):  # Y-up scene (arm3): look down the Z axis
        cam.azimuth, cam.elevation = 90.0, -89.9
    else:
        cam.azimuth, cam.elevation = 135.0, -25.0
    return cam


def _renderer(m, height: int, width: int):
    """MuJoCo's offscreen renderer without shadows, reflections or skybox (3x the frame rate on
    a software renderer); ``RuntimeError`` naming ``MUJOCO_GL`` and what a headless machine
    needs when no OpenGL context can be made."""
    import mujoco

    try:
        renderer = mujoco.Renderer(m, height, width)
        for flag in ("mjRND_SHADOW", "mjRND_REFLECTION", "mjRND_SKYBOX"):
            renderer.scene.flags[getattr(mujoco.mjtRndFlag, flag)] = False
    except Exception as exc:  # noqa: BLE001 - every GL backend fails differently
        raise no_gl_context(exc) from None
    return renderer


def no_gl_context(exc: BaseException, who: str = "") -> RuntimeError:
    """The one-line error of an OpenGL context that could not be made (``exc``, the GL
    backend's own error, its last line kept), naming ``MUJOCO_GL`` and what a headless machine
    needs; ``who`` (``"camera 'head': "``) heads it."""
    backend = os.environ.get("MUJOCO_GL", "(unset)")
    text = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
    return RuntimeError(
        f"{who}no OpenGL context with MUJOCO_GL={backend} ({text}); headless machines need "
        "MUJOCO_GL=egl (libegl1, libgl1-mesa-dri) or MUJOCO_GL=osmesa (libosmesa6, PyOpenGL)"
    )


def open_video(args, robot, backend) -> VideoRecorder | None:
    """The recorder ``deploy-run --video`` asks for, or None after printing a one-line error
    when no GL context (or no ffmpeg writer) can be made: the run goes on without video.

    Raises:
        ValueError: a bad ``--size``, ``--fps`` or ``--camera`` (bad input, exit 3).
    """
    from sim2real.deploy.core.backend import SimulatedPlant

    size = parse_size(args.size)
    true_state = backend.true_position if isinstance(backend, SimulatedPlant) else None
    try:
        return VideoRecorder(robot, args.video, args.fps, size, args.camera, true_state)
    except (RuntimeError, ImportError) as exc:
        print(f"deploy-run: error: --video: {exc}; running without video", file=sys.stderr)
        return None


def import_mujoco() -> str | None:
    """Import mujoco, which loads the OpenGL backend ``MUJOCO_GL`` names at import time; where
    that backend cannot load (``osmesa`` without libOSMesa, a misspelt name), import it again
    without ``MUJOCO_GL`` (simulation needs no GL) and return a one-line error, else None."""
    try:
        import mujoco  # noqa: F401
    except Exception as exc:  # noqa: BLE001 - each GL backend fails differently
        backend = os.environ.pop("MUJOCO_GL", "")
        for name in [
            k for k in sys.modules if k.split(".")[0] in ("mujoco", "OpenGL")
        ]:  # the half-imported packages
            del sys.modules[name]
        import mujoco  # noqa: F401, F811

        return (
            f"MUJOCO_GL={backend}: mujoco cannot load this OpenGL backend "
            f"({type(exc).__name__}: {exc}); no video; headless machines use MUJOCO_GL=egl"
        )
    return None


def headless_gl_default(environ=None) -> str | None:
    """Choose EGL for offscreen rendering where nothing is chosen: on Linux without a display and
    without ``MUJOCO_GL``, set ``MUJOCO_GL=egl`` in ``environ`` (default ``os.environ``; it must
    happen before mujoco is imported, which reads it then) and return ``'egl'``; else None (the
    user's choice, or GLFW on a desktop, stands)."""
    environ = os.environ if environ is None else environ
    if environ.get("MUJOCO_GL") or not sys.platform.startswith("linux"):
        return None
    if environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY"):
        return None
    environ["MUJOCO_GL"] = "egl"
    return "egl"
