"""MuJoCo's offscreen colour image of an MJCF ``<camera>`` (:class:`RgbRenderer`), headless.

The drawing (OpenGL context by ``MUJOCO_GL``, EGL where unset on a headless Linux machine; triton
imported first) is :class:`sim2real.deploy.backends.sim.depth_render.OffscreenCamera`'s. The
colour renderer draws without shadows and reflections unless asked (``shadows``): on Mesa's
software renderer MuJoCo's 4096 x 4096 shadow map cost many times the frame itself
(docs/cameras.md); without multisampling (its cost; a
camera's own anti-aliasing is its lens's blur, not modelled). The skybox stays.
A lighting change (:meth:`RgbRenderer.set_lighting`) scales the headlight's and every light's
ambient and diffuse colour in the renderer's copy of the model.
"""

from __future__ import annotations

import mujoco
import numpy as np

from sim2real.deploy.backends.sim.depth_render import OffscreenCamera


class RgbRenderer(OffscreenCamera):
    """The colour image of one MJCF camera of one model, (rows, columns, 3) uint8 R, G, B per
    call.

    Args:
        model: The model (a copy is rendered). camera: The ``<camera>``'s name.
        shape: (rows, columns). where: Named in errors.
        shadows: Draw shadows and reflections (module docstring: their cost).

    Raises:
        CameraError: no such camera. RuntimeError: no OpenGL context (naming ``MUJOCO_GL``).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        camera: str,
        shape: tuple[int, int],
        where: str,
        shadows: bool = False,
    ):
        off = () if shadows else ("mjRND_SHADOW", "mjRND_REFLECTION")
        super().__init__(model, camera, shape, where, off)
        self._rgb = np.zeros((*self.shape, 3), np.uint8)
        m = self.model
        self._lights = (
            m.vis.headlight.ambient.copy(),
            m.vis.headlight.diffuse.copy(),
            m.light_ambient.copy(),
            m.light_diffuse.copy(),
        )

    def set_lighting(self, scale: float) -> None:
        """Scale the scene's light (the headlight's and each light's ambient and diffuse colour,
        from the model's own) by ``scale`` >= 0: 1 is the model's lighting."""
        m = self.model
        head_a, head_d, amb, dif = self._lights
        m.vis.headlight.ambient[:] = np.clip(head_a * scale, 0.0, 1.0)
        m.vis.headlight.diffuse[:] = np.clip(head_d * scale, 0.0, 1.0)
        m.light_ambient[:] = np.clip(amb * scale, 0.0, 1.0)
        m.light_diffuse[:] = np.clip(dif * scale, 0.0, 1.0)

    def render(self, data: mujoco.MjData, out: np.ndarray | None = None) -> np.ndarray:
        """(rows, columns, 3) uint8 R, G, B of the scene in ``data`` (its kinematics and camera
        poses recomputed from ``qpos`` first)."""
        self.draw(data)
        self.read(self._rgb, None)
        out = np.empty((*self.shape, 3), np.uint8) if out is None else out
        out[:] = self._rgb[::-1]  # OpenGL's rows run bottom-up
        return out
