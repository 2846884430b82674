"""MuJoCo's offscreen z-depth of an MJCF ``<camera>`` (:class:`DepthRenderer`), headless, and the
offscreen drawing it shares with the colour renderer (:class:`OffscreenCamera`).

The OpenGL context follows ``MUJOCO_GL`` (``egl``, ``osmesa``, ``glfw``); where it is unset on a
Linux machine without a display, EGL (Mesa's ``libEGL``; Debian ``libegl1 libgl1-mesa-dri``, as
``.ci/run`` installs them). The depth buffer is linearised as :class:`mujoco.Renderer` does
(``near / (1 - z (1 - near / far))`` with ``near``, ``far`` the model's ``vis.map.znear``,
``zfar`` times ``stat.extent``): metres along the camera's optical axis, the z-depth a RealSense
reports. A ray that meets nothing reads ``far``.

Mesa's software renderer (llvmpipe) and triton (torch's compiler) each load their own LLVM; a
process that has loaded Mesa's first crashes (segfault) when it imports triton. Where triton is
installed, :class:`DepthRenderer` imports it before it makes its first context (0.2 s, once).
"""

from __future__ import annotations

import copy
import importlib.util
import os
import sys

import mujoco
import numpy as np

from sim2real.deploy.observe.video import no_gl_context
from sim2real.deploy.spec.camera import CameraError


def camera_id(model: mujoco.MjModel, name: str, where: str) -> int:
    """The id of the MJCF camera ``name``.

    Raises:
        CameraError: the model has no such camera (one line naming ``where``, the camera and the
            cameras it has).
    """
    cid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name)
    if cid < 0:
        have = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_CAMERA, i) for i in range(model.ncam)]
        raise CameraError(
            f'{where}: the MJCF has no <camera name="{name}"> (its cameras: {have or "none"}); '
            "add one to the robot's MJCF or name one it has"
        )
    return cid


def _triton_first() -> None:
    """Import triton, where it is installed, before any OpenGL context loads Mesa's LLVM
    (module docstring)."""
    if importlib.util.find_spec("triton") is not None:
        import triton  # noqa: F401


def _context_class():
    """The GL context class ``MUJOCO_GL`` names (module docstring)."""
    gl = os.environ.get("MUJOCO_GL", "").lower()
    headless = not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    if gl == "egl" or (not gl and sys.platform.startswith("linux") and headless):
        from mujoco.egl import GLContext
    elif gl == "osmesa":
        from mujoco.osmesa import GLContext
    else:
        from mujoco.rendering.classic.gl_context import GLContext
    return GLContext


class OffscreenCamera:
    """One MJCF camera of a copy of one model drawn offscreen, headless (module docstring): what
    the depth and the colour renderers share (:class:`DepthRenderer`,
    :class:`sim2real.deploy.backends.sim.rgb_render.RgbRenderer`).

    Args:
        model: The model (a copy is rendered, its offscreen buffer the frame's size and without
            multisampling). camera: The ``<camera>``'s name. shape: (rows, columns).
        where: Named in errors. flags_off: ``mjtRndFlag`` names turned off in the scene.

    Attributes:
        model: The copy drawn (its ``cam_quat``, lights and headlight may be changed: a knocked
            camera, a lighting change). cam: The ``MjvCamera`` (``fixedcamid``).

    Raises:
        CameraError: no such camera. RuntimeError: no OpenGL context (naming ``MUJOCO_GL``).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        camera: str,
        shape: tuple[int, int],
        where: str,
        flags_off: tuple[str, ...] = (),
    ):
        self.model = model = copy.copy(model)
        self.shape = (int(shape[0]), int(shape[1]))
        self.cam = mujoco.MjvCamera()
        self.cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self.cam.fixedcamid = camera_id(model, camera, where)
        rows, cols = self.shape
        vis = model.vis.global_
        vis.offwidth, vis.offheight = cols, rows
        model.vis.quality.offsamples = 0
        _triton_first()
        try:
            self._gl = _context_class()(cols, rows)
            self._gl.make_current()
            self._con = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        except Exception as exc:  # noqa: BLE001 - every GL backend fails differently
            raise no_gl_context(exc, f"camera '{camera}': ") from None
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._con)
        self._scene = mujoco.MjvScene(model, maxgeom=10000)
        for flag in flags_off:
            self._scene.flags[getattr(mujoco.mjtRndFlag, flag)] = False
        self._opt, self._pert = mujoco.MjvOption(), mujoco.MjvPerturb()
        self._rect = mujoco.MjrRect(0, 0, cols, rows)

    def draw(self, data: mujoco.MjData) -> None:
        """Draw the scene in ``data`` (its kinematics and camera poses recomputed from ``qpos``
        first) into the offscreen buffer; :meth:`read` then reads it."""
        m = self.model
        mujoco.mj_kinematics(m, data)
        mujoco.mj_camlight(m, data)
        self._gl.make_current()
        mujoco.mjv_updateScene(
            m, data, self._opt, self._pert, self.cam, mujoco.mjtCatBit.mjCAT_ALL, self._scene
        )
        mujoco.mjr_render(self._rect, self._scene, self._con)

    def read(self, rgb: np.ndarray | None, depth: np.ndarray | None) -> None:
        """Read the drawn buffer's colour (rows, columns, 3) uint8 and/or raw depth (rows,
        columns) float32 into the arrays given (OpenGL's rows: bottom-up)."""
        mujoco.mjr_readPixels(rgb, depth, self._rect, self._con)

    def close(self) -> None:
        """Free the GL context (the renderer is unusable after)."""
        if getattr(self, "_gl", None) is not None:
            self._gl.make_current()  # free this context's buffers, not the current one's
            self._con.free()
            self._gl.free()
            self._gl = None

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001, S110 - at interpreter exit GL may be gone
            pass


class DepthRenderer(OffscreenCamera):
    """The z-depth of one MJCF camera of one model, (rows, columns) m per call.

    Args:
        model: The model (a copy is rendered, its offscreen buffer the frame's size and without
            multisampling: a depth pixel is one ray's, not an average across an edge).
        camera: The ``<camera>``'s name. shape: (rows, columns). where: Named in errors.

    Raises:
        CameraError: no such camera. RuntimeError: no OpenGL context (naming ``MUJOCO_GL``).
    """

    def __init__(self, model: mujoco.MjModel, camera: str, shape: tuple[int, int], where: str):
        # no depth in shadows, reflections and the skybox
        super().__init__(
            model, camera, shape, where, ("mjRND_SHADOW", "mjRND_REFLECTION", "mjRND_SKYBOX")
        )
        self._z = np.zeros(self.shape, np.float32)
        extent = self.model.stat.extent
        self.near, self.far = self.model.vis.map.znear * extent, self.model.vis.map.zfar * extent

    def render(self, data: mujoco.MjData, out: np.ndarray | None = None) -> np.ndarray:
        """(rows, columns) float32 z-depth, m, of the scene in ``data`` (its kinematics and
        camera poses recomputed from ``qpos`` first)."""
        self.draw(data)
        self.read(None, self._z)
        out = np.empty(self.shape, np.float32) if out is None else out
        z = self._z[::-1]  # OpenGL's rows run bottom-up
        np.divide(self.near, 1.0 - z * (1.0 - self.near / self.far), out=out)
        return out
