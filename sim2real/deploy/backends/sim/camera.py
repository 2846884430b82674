"""A simulated depth camera on each env of a plant (:class:`PlantDepthCamera`): the MJCF
``<camera>`` rendered at its own rate, with a D435's depth model and the session's faults.

Depth model (:class:`DepthNoise`; Intel RealSense D400 Series datasheet 337029, D435: depth RMS
error <= 2 % at 2 m, depth unit 1 mm, range up to 10 m; minimum depth 0.11 m, Intel's figure for
the D435 on its forum, the datasheet's min-Z table giving it per resolution): the true z-depth
``z`` plus Gaussian noise of standard deviation ``k z^2`` (stereo depth error grows with the
square of the distance: ``dz = z^2 d / (f b)`` for a disparity error ``d``, focal length ``f`` px
and baseline ``b``); ``k`` = 0.01 / m gives 2 % (4 cm) at 2 m and 1 % at 1 m, the datasheet's
bound. A pixel nearer than ``min_range`` or past ``max_range`` is invalid (0, as librealsense
writes it); so is a pixel at a depth edge (a 4-neighbour more than ``edge_jump`` times its own
depth away: the stereo matcher's holes beside a foreground object, our choice 0.1); the rest is
rounded to ``depth_unit``.

The frame's timing and the faults (a covered lens reads 0, no depth; a lighting change is a colour
camera's) are :mod:`sim2real.deploy.backends.sim.plant_camera`'s, shared with the colour camera
(:mod:`sim2real.deploy.backends.sim.rgb_camera`); :func:`attach_plant_camera` attaches the one a
policy's image block asks for. The depth frame is ``frame.depth_image`` (envs, rows, columns) m.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import mujoco
import numpy as np

from sim2real.deploy.backends.camera.sources import CameraSources
from sim2real.deploy.backends.sim.depth_render import DepthRenderer
from sim2real.deploy.backends.sim.plant_camera import CameraFaultRanges, CameraFaults, PlantCamera
from sim2real.deploy.backends.sim.rgb_camera import PlantRgbCamera
from sim2real.deploy.backends.sim.task_scene import task_scene
from sim2real.deploy.spec.camera import DepthImageBlock

__all__ = [
    "CameraFaultRanges",
    "CameraFaults",
    "DepthNoise",
    "PlantCamera",
    "PlantDepthCamera",
    "attach_plant_camera",
    "depth_error",
]

#: D435 depth RMS error bound, fraction of the distance, at ``D435_AT`` m (datasheet).
D435_RMS = 0.02
D435_AT = 2.0


@dataclass(frozen=True)
class DepthNoise:
    """A depth camera's sensor model (module docstring). Defaults: the D435's.

    Attributes:
        k: Noise standard deviation per squared metre, 1/m (``sigma = k z^2``).
        min_range, max_range: Valid depths, m. depth_unit: Quantum of the depth, m (0: none).
        edge_jump: A neighbour further than this fraction of the depth marks an edge (0: none).
    """

    k: float = D435_RMS * D435_AT / D435_AT**2
    min_range: float = 0.11
    max_range: float = 10.0
    depth_unit: float = 0.001
    edge_jump: float = 0.1

    def sigma(self, z):
        """The depth noise's standard deviation at ``z`` m, m."""
        return self.k * np.square(z)

    def apply(self, z: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(rows, columns) true depth m -> the camera's depth m (0: invalid)."""
        out = z + rng.standard_normal(z.shape) * self.sigma(z)
        invalid = (z < self.min_range) | (z > self.max_range)
        if self.edge_jump > 0:
            jump = np.zeros(z.shape, dtype=bool)
            dv = np.abs(np.diff(z, axis=0)) > self.edge_jump * np.minimum(z[1:], z[:-1])
            dh = np.abs(np.diff(z, axis=1)) > self.edge_jump * np.minimum(z[:, 1:], z[:, :-1])
            jump[1:] |= dv
            jump[:-1] |= dv
            jump[:, 1:] |= dh
            jump[:, :-1] |= dh
            invalid |= jump
        if self.depth_unit > 0:
            out = np.round(out / self.depth_unit) * self.depth_unit
        out[invalid] = 0.0
        return out

    def to_dict(self) -> dict:
        return asdict(self)


class PlantDepthCamera(PlantCamera):
    """The depth camera of every env of ``plant`` (module docstring).

    Args:
        plant: A simulated plant (its ``models``, ``datas``, ``envs``).
        block: The policy's image block (its ``camera`` and ``shape``).
        rate: Frames per second (default the block's). latency: s from capture to delivery
            (default the block's).
        noise: The sensor model (default the D435's; None for :class:`DepthNoise`).
        faults: The session's faults (default none; or one per env, :class:`PlantCamera`).
        seed: Of the noise and fault draws (or one generator per env).
        where: Named in a refusal (the robot's MJCF).
        scene: The robot's task scene
            (:class:`~sim2real.deploy.backends.sim.task_scene.TaskScene`: the robot's MJCF with
            a goal marker and the cameras watching the task), rendered instead of the plant's
            models where given; None: the plant's models.

    Attributes:
        frames: (envs,) frames captured; delivered, dropped, spiked, frozen: counts (envs,).

    Raises:
        CameraError: the MJCF has no such camera. RuntimeError: no OpenGL context.
    """

    def __init__(
        self,
        plant,
        block: DepthImageBlock,
        rate: float | None = None,
        latency: float | None = None,
        noise: DepthNoise | None = None,
        faults: CameraFaults | None = None,
        seed: int = 0,
        where: str = "MJCF",
        scene=None,
    ):
        self.noise = DepthNoise() if noise is None else noise
        super().__init__(plant, block, rate, latency, faults, seed, where, DepthRenderer, scene)
        self._truth = np.zeros(block.shape, np.float32)

    def true_depth(self, env: int = 0) -> np.ndarray:
        """(rows, columns) float32 m, the camera's true z-depth of env ``env`` now."""
        return self.renderers[env].render(self.scene_data(env), self._truth)

    def _sense(self, e: int, rng: np.random.Generator) -> np.ndarray:
        image = self.noise.apply(self.true_depth(e), rng).astype(np.float32)
        image[:, : self._blind[e]] = 0.0  # a covered lens: no depth
        return image


def depth_error(camera: PlantDepthCamera, frames: int, at: float, env: int = 0) -> dict:
    """The camera's depth error over ``frames`` noisy frames of the scene as it stands, on the
    pixels whose true depth is within 5 % of ``at`` m (a flat target there): ``pixels`` counted,
    ``rms_m``, ``rms_fraction`` (of ``at``) over the valid ones, ``invalid_fraction``.

    Raises:
        ValueError: no pixel of the view is within 5 % of ``at``."""
    truth = camera.true_depth(env).astype(np.float64)
    band = np.abs(truth - at) <= 0.05 * at
    if not band.any():
        raise ValueError(
            f"depth_error: no pixel at {at} m +- 5 % in camera '{camera.block.camera}'"
        )
    errors, invalid = [], 0
    for _ in range(frames):
        z = camera.noise.apply(truth, camera.rng)[band]
        valid = z > 0
        invalid += int((~valid).sum())
        errors.append((z - truth[band])[valid])
    rms = float(np.sqrt(np.mean(np.concatenate(errors) ** 2)))
    return {
        "pixels": int(band.sum()),
        "rms_m": rms,
        "rms_fraction": rms / at,
        "invalid_fraction": invalid / (frames * int(band.sum())),
    }


def attach_plant_camera(
    backend,
    spec,
    rate: float | None = None,
    latency: float | None = None,
    noise=None,
    faults=None,
    seed=0,
):
    """For a simulated plant (its ``models``, ``datas``) and a spec with image blocks: the
    plant's camera of each block (:class:`PlantDepthCamera` for a depth block,
    :class:`sim2real.deploy.backends.sim.rgb_camera.PlantRgbCamera` for an RGB one; a camera the
    robot's MJCF lacks renders the robot's task scene where robot.toml names one,
    :func:`~sim2real.deploy.backends.sim.task_scene.task_scene`: its goal marker then shows
    ``camera.scene.goal``, which the run sets) made the runtime's frame source
    (``backend.camera_source``, :func:`sim2real.deploy.runtime.camera.camera_stage`) and
    returned; several blocks: one camera each, at each block's rate and latency, in a
    :class:`~sim2real.deploy.backends.camera.sources.CameraSources` by camera name. None for a
    backend that is no plant (its own driver writes the frames). ``rate``, ``latency``: every
    camera's, None: each block's. ``noise``: the blocks' sensor model (None: the datasheet's).
    ``faults`` and ``seed`` as :class:`PlantCamera` takes them, or a dict of them by camera
    name; one value for several cameras: the faults are every camera's, the seed the first
    camera's and camera ``i``'s stream ``default_rng([seed, i])`` (a generator per env:
    ``generator.spawn(1)``), so a first camera draws as it would alone.

    Raises:
        CameraError: the robot's MJCF (or task scene) has no camera of a block's name (one
            line naming the file and ``images[i].camera``). ValueError: a task scene that does
            not fit the robot.
    """
    images = getattr(spec, "images", ())
    if not images or not all(hasattr(backend, a) for a in ("models", "datas")):
        return None
    robot = getattr(backend, "robot", None)
    cameras, scene = {}, None
    for i, block in enumerate(images):
        # a camera of the robot's own MJCF (on its head, its wrist) renders the plant; another
        # (one watching the task) the robot's task scene, where robot.toml names one
        own = mujoco.mj_name2id(backend.models[0], mujoco.mjtObj.mjOBJ_CAMERA, block.camera) >= 0
        here = None
        if robot is not None and not own:
            if scene is None:  # one scene for every camera watching the task
                scene = task_scene(robot, backend)
            here = scene
        mjcf = getattr(robot, "mjcf_path", "MJCF") if here is None else here.path
        where = f"{mjcf}: images[{i}].camera"
        kind = PlantRgbCamera if block.kind == "rgb" else PlantDepthCamera
        f = faults.get(block.camera) if isinstance(faults, dict) else faults
        s = (
            seed.get(block.camera, 0)
            if isinstance(seed, dict)
            else _nth_seed(seed, i, backend.envs)
        )
        cameras[block.camera] = kind(backend, block, rate, latency, noise, f, s, where, scene=here)
    if len(cameras) == 1:
        (camera,) = cameras.values()
    else:
        camera = CameraSources(cameras)
    backend.camera_source = camera
    return camera


def _nth_seed(seed, i: int, envs: int):
    """Camera ``i``'s seed of a run's one ``seed`` (:func:`attach_plant_camera`): the seed for
    the first camera; an int's ``default_rng([seed, i])`` for every env, or each env's
    generator's ``spawn(1)``."""
    if i == 0:
        return seed
    if isinstance(seed, int | np.integer):
        return [np.random.default_rng([int(seed), i])] * envs
    return [g.spawn(1)[0] for g in seed]
