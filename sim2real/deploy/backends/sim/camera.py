"""A simulated depth camera on each env of a plant (:class:`PlantDepthCamera`): the MJCF
``<camera>`` rendered at its own rate, with a D435's depth model and the session's faults.

Timing. Frame ``k`` is captured at ``k / rate`` s (the first control tick at or after it renders
the scene: a 30 Hz camera beside a 200 Hz control loop captures every 6th or 7th tick) and is
delivered ``latency`` s later (plus ``spike_latency`` when a latency spike hits it). Each tick the
frame carries the newest delivered image (``frame.depth_image`` (envs, rows, columns) m) and its
capture time (``frame.depth_stamp`` (envs,) s; NaN: nothing delivered yet); the runtime's camera
stage (:mod:`sim2real.deploy.runtime.camera`) sees its age.

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

Faults (:class:`CameraFaults`, drawn per frame from the generator seeded by ``seed``): a frame
is lost with probability ``drop``; with probability ``spike`` it arrives ``spike_latency`` s
later; a frozen spell starts at a frame with probability ``freeze`` and lasts ``freeze_frames``
frames, each delivered on time with a fresh stamp and the image of the frame before it (a
driver stuck on its buffer: the runtime sees a repeated image, which is not fresh). Two faults
hold for the whole session: ``occlusion``, the fraction of the image's columns, from its left
edge, that a covered or smudged lens blinds (they read 0, no depth); ``extrinsic``, the camera
knocked on its mount, turned by (rx, ry, rz) rad about its own x (right), y (up) and z (back)
axes in that order (the MJCF pose is the calibrated one the policy trained with).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import mujoco
import numpy as np

from sim2real.deploy.backends.sim.depth_render import DepthRenderer
from sim2real.deploy.backends.sim.task_scene import task_scene
from sim2real.deploy.spec.camera import DepthImageBlock

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


@dataclass(frozen=True)
class CameraFaults:
    """A session's camera faults (module docstring): ``drop``, ``spike`` and ``freeze``
    probabilities per frame, ``spike_latency`` s, ``freeze_frames`` frames; ``occlusion`` (a
    fraction of the columns) and ``extrinsic`` (rad) for the session."""

    drop: float = 0.0
    spike: float = 0.0
    spike_latency: float = 0.1
    freeze: float = 0.0
    freeze_frames: int = 10
    occlusion: float = 0.0
    extrinsic: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        if not (
            0 <= self.occlusion <= 1
            and len(self.extrinsic) == 3
            and np.all(np.isfinite(self.extrinsic))
            and 0 <= self.drop <= 1
            and 0 <= self.spike <= 1
            and 0 <= self.freeze <= 1
            and self.spike_latency >= 0
            and self.freeze_frames >= 1
        ):
            raise ValueError(
                f"CameraFaults: probabilities and occlusion in [0, 1], spike_latency >= 0 s, "
                f"freeze_frames >= 1, extrinsic 3 finite rad; got {self}"
            )

    def to_dict(self) -> dict:
        return asdict(self)


class PlantDepthCamera:
    """The depth camera of every env of ``plant`` (module docstring).

    Args:
        plant: A simulated plant (its ``models``, ``datas``, ``envs``).
        block: The policy's image block (its ``camera`` and ``shape``).
        rate: Frames per second (default the block's). latency: s from capture to delivery
            (default the block's).
        noise: The sensor model (default the D435's; None for :class:`DepthNoise`).
        faults: The session's faults (default none), or one per env (a soak's sessions).
            seed: Of the noise and fault draws.
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
        self.plant, self.block, self.scene = plant, block, scene
        self.rate = float(block.rate if rate is None else rate)
        self.latency = float(block.latency if latency is None else latency)
        if not (self.rate > 0 and self.latency >= 0):
            raise ValueError(
                f"PlantDepthCamera: rate > 0 Hz, latency >= 0 s; got {self.rate}, {self.latency}"
            )
        self.noise = DepthNoise() if noise is None else noise
        per_env = isinstance(faults, list | tuple) and not isinstance(faults, CameraFaults)
        envs = plant.envs
        #: each env's faults; ``faults`` is the first env's (one for all, as deploy-run's)
        self.env_faults = tuple(faults) if per_env else (faults or CameraFaults(),) * envs
        if len(self.env_faults) != envs:
            raise ValueError(f"faults: expected one per env ({envs}), got {len(self.env_faults)}")
        self.faults = self.env_faults[0]
        self.rng = np.random.default_rng(seed)
        models = plant.models if scene is None else scene.models
        self.renderers = [DepthRenderer(m, block.camera, block.shape, where) for m in models]
        for r, f in zip(self.renderers, self.env_faults, strict=True):
            if any(f.extrinsic):  # the camera knocked on its mount
                turn = np.zeros(4)
                mujoco.mju_euler2Quat(turn, np.asarray(f.extrinsic, float), "XYZ")
                cid, quat = r.cam.fixedcamid, np.zeros(4)
                mujoco.mju_mulQuat(quat, r.model.cam_quat[cid].copy(), turn)
                r.model.cam_quat[cid] = quat
        #: the columns a covered lens blinds
        self._blind = [int(round(f.occlusion * block.shape[1])) for f in self.env_faults]
        self.frames = np.zeros(envs, dtype=np.int64)
        self.delivered = np.zeros(envs, dtype=np.int64)
        self.dropped = np.zeros(envs, dtype=np.int64)
        self.spiked = np.zeros(envs, dtype=np.int64)
        self.frozen = np.zeros(envs, dtype=np.int64)
        self._freeze_left = np.zeros(envs, dtype=np.int64)
        self._last = np.zeros((envs, *block.shape), np.float32)  # the last image made
        #: per env, frames in flight: [(deliver_at s, stamp s, image)]
        self._queue: list[list[tuple[float, float, np.ndarray]]] = [[] for _ in range(envs)]
        self._truth = np.zeros(block.shape, np.float32)

    def true_depth(self, env: int = 0) -> np.ndarray:
        """(rows, columns) float32 m, the camera's true z-depth of env ``env`` now."""
        data = self.plant.datas[env]
        if self.scene is not None:  # the plant's pose, geometry and the goal, in the scene
            data = self.scene.sync(env, data, self.renderers[env].model)
        return self.renderers[env].render(data, self._truth)

    def _capture(self, e: int, stamp: float) -> None:
        f, rng = self.env_faults[e], self.rng
        self.frames[e] += 1
        if self._freeze_left[e] > 0:  # a stuck driver: the old image again, stamped anew
            self._freeze_left[e] -= 1
            self.frozen[e] += 1
            image = self._last[e].copy()
        else:
            image = self.noise.apply(self.true_depth(e), rng).astype(np.float32)
            image[:, : self._blind[e]] = 0.0  # a covered lens: no depth
            self._last[e] = image
            if f.freeze and rng.random() < f.freeze:
                self._freeze_left[e] = f.freeze_frames
        if f.drop and rng.random() < f.drop:
            self.dropped[e] += 1
            return
        late = self.latency
        if f.spike and rng.random() < f.spike:
            self.spiked[e] += 1
            late += f.spike_latency
        self._queue[e].append((stamp + late, stamp, image))

    def fill(self, frame) -> None:
        """Capture the frames due by ``frame.time`` and write the newest delivered one into
        ``frame.depth_image`` and ``frame.depth_stamp`` (made on the first call; module
        docstring)."""
        envs = self.plant.envs
        if getattr(frame, "depth_image", None) is None:
            frame.depth_image = np.zeros((envs, *self.block.shape), np.float32)
            frame.depth_stamp = np.full(envs, np.nan)
        now = np.broadcast_to(np.asarray(frame.time, dtype=float), (envs,))
        for e in range(envs):
            while self.frames[e] / self.rate <= now[e] + 1e-9:
                self._capture(e, self.frames[e] / self.rate)
            queue = self._queue[e]
            ready = [item for item in queue if item[0] <= now[e] + 1e-9]
            if ready:
                newest = max(ready, key=lambda item: item[1])
                self._queue[e] = [item for item in queue if item[1] > newest[1]]
                self.delivered[e] += 1
                frame.depth_image[e] = newest[2]
                frame.depth_stamp[e] = newest[1]

    def summary(self) -> dict:
        """The run report's camera lines: rate, latency, faults and the counts per env."""
        return {
            "camera": self.block.camera,
            "rate_hz": self.rate,
            "latency_s": self.latency,
            "faults": self.faults.to_dict()
            if len(set(self.env_faults)) == 1
            else [f.to_dict() for f in self.env_faults],
            **{
                k: getattr(self, k).tolist()
                for k in ("frames", "delivered", "dropped", "spiked", "frozen")
            },
        }

    def close(self) -> None:
        for r in self.renderers:
            r.close()


@dataclass(frozen=True)
class CameraFaultRanges:
    """The ranges a session's :class:`CameraFaults` are drawn from, uniformly (our choice):
    ``drop`` 0-5 % of frames, ``spike`` 0-2 % of frames 50-200 ms late, ``freeze`` 0-0.5 % of
    frames starting a 5-30 frame spell, ``occlusion`` 0-10 % of the columns, ``extrinsic`` up
    to 2 deg about each axis (a camera knocked on its mount)."""

    drop: tuple[float, float] = (0.0, 0.05)
    spike: tuple[float, float] = (0.0, 0.02)
    spike_latency: tuple[float, float] = (0.05, 0.2)
    freeze: tuple[float, float] = (0.0, 0.005)
    freeze_frames: tuple[int, int] = (5, 30)
    occlusion: tuple[float, float] = (0.0, 0.1)
    extrinsic: float = float(np.radians(2.0))

    def sample(self, rng: np.random.Generator) -> CameraFaults:
        """One session's draw (seven draws of ``rng``, in the fields' order; ``extrinsic``
        three uniform in +-``extrinsic`` rad)."""
        return CameraFaults(
            drop=float(rng.uniform(*self.drop)),
            spike=float(rng.uniform(*self.spike)),
            spike_latency=float(rng.uniform(*self.spike_latency)),
            freeze=float(rng.uniform(*self.freeze)),
            freeze_frames=int(rng.integers(self.freeze_frames[0], self.freeze_frames[1] + 1)),
            occlusion=float(rng.uniform(*self.occlusion)),
            extrinsic=tuple(float(v) for v in rng.uniform(-self.extrinsic, self.extrinsic, 3)),
        )


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


def attach_depth_camera(
    backend,
    spec,
    rate: float | None = None,
    latency: float | None = None,
    noise: DepthNoise | None = None,
    faults: CameraFaults | None = None,
    seed: int = 0,
) -> PlantDepthCamera | None:
    """For a simulated plant (its ``models``, ``datas``) and a spec with an image block: the
    plant's camera (rendering the robot's task scene where robot.toml names one,
    :func:`~sim2real.deploy.backends.sim.task_scene.task_scene`; its goal marker then shows
    ``camera.scene.goal``, which the run sets) made the runtime's frame source (``backend.camera_source``,
    :func:`sim2real.deploy.runtime.camera.camera_stage`) and returned; else None (a backend that
    is no plant: its own driver writes the frames).

    Raises:
        CameraError: the robot's MJCF (or task scene) has no camera of the block's name (one
            line naming the file and ``images[0].camera``). ValueError: a task scene that does
            not fit the robot.
    """
    images = getattr(spec, "images", ())
    if not images or not all(hasattr(backend, a) for a in ("models", "datas")):
        return None
    robot = getattr(backend, "robot", None)
    scene = None if robot is None else task_scene(robot, backend)
    mjcf = getattr(robot, "mjcf_path", "MJCF") if scene is None else scene.path
    where = f"{mjcf}: images[0].camera"
    camera = PlantDepthCamera(
        backend, images[0], rate, latency, noise, faults, seed, where, scene=scene
    )
    backend.camera_source = camera
    return camera
