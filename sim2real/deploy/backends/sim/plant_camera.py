"""What a simulated camera of a plant is, whatever it senses (:class:`PlantCamera`; the depth
camera :mod:`sim2real.deploy.backends.sim.camera` and the colour camera
:mod:`sim2real.deploy.backends.sim.rgb_camera` make each frame's image).

Timing. Frame ``k`` is captured at ``k / rate`` s (the first control tick at or after it renders
the scene: a 30 Hz camera beside a 200 Hz control loop captures every 6th or 7th tick) and is
delivered ``latency`` s later (plus ``spike_latency`` when a latency spike hits it). Each tick the
frame carries the newest delivered image and its capture time (NaN: nothing delivered yet); the
runtime's camera stage (:mod:`sim2real.deploy.runtime.camera`) sees its age.

Faults (:class:`CameraFaults`, drawn from :class:`CameraFaultRanges`; per frame from the env's
generator): a frame is lost with probability ``drop``; with probability ``spike`` it arrives
``spike_latency`` s later; a frozen spell starts at a frame with probability ``freeze`` and lasts
``freeze_frames`` frames, each delivered on time with a fresh stamp and the image of the frame
before it (a driver stuck on its buffer: the runtime sees a repeated image, which is not fresh).
For the whole session: ``occlusion``, the fraction of the image's columns, from its left edge,
that a covered or smudged lens blinds; ``extrinsic``, the camera knocked on its mount, turned by
(rx, ry, rz) rad about its own x (right), y (up) and z (back) axes in that order (the MuJoCo
camera's pose in the renderer's copy of the model; the MJCF pose is the calibrated one the policy
trained with); ``lighting``, the scene's light scaled (a colour camera's). Every env may have
faults and a generator of its own (a soak batch's sessions, :mod:`sim2real.eval.soak.camera_faults`).
"""

from __future__ import annotations

from collections import deque
from dataclasses import asdict, dataclass

import mujoco
import numpy as np

from sim2real.deploy.core.stateful import (
    env_list,
    put,
    read_streams,
    set_streams,
    streams_json,
    take,
)

#: Faulted frames each env's camera remembers for :meth:`PlantCamera.recent` (our choice).
RECENT_EVENTS = 256


@dataclass(frozen=True)
class CameraFaults:
    """A session's camera faults (module docstring): ``drop``, ``spike`` and ``freeze``
    probabilities per frame, ``spike_latency`` s, ``freeze_frames`` frames; ``occlusion`` (a
    fraction of the columns), ``extrinsic`` (rad) and ``lighting`` (the scene's light scaled by
    it: a colour camera's; 1 is the model's own) for the session."""

    drop: float = 0.0
    spike: float = 0.0
    spike_latency: float = 0.1
    freeze: float = 0.0
    freeze_frames: int = 10
    occlusion: float = 0.0
    extrinsic: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lighting: float = 1.0

    def __post_init__(self):
        if not (
            np.isfinite(self.lighting)
            and self.lighting >= 0
            and 0 <= self.occlusion <= 1
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
                f"freeze_frames >= 1, extrinsic 3 finite rad, lighting >= 0; got {self}"
            )

    def to_dict(self) -> dict:
        return asdict(self)


class PlantCamera:
    """A camera on every env of ``plant`` at its own rate and latency, with per-frame faults
    (module docstring): what the depth and the colour camera share. A subclass makes each
    frame's image (:meth:`_sense`) and names the frame's fields (``image_field``,
    ``stamp_field``).

    Args:
        plant: A simulated plant (its ``models``, ``datas``, ``envs``).
        block: The policy's image block (its ``camera``, ``shape`` and ``frame_shape``).
        rate: Frames per second (default the block's). latency: s from capture to delivery
            (default the block's).
        faults: The faults (default none): one :class:`CameraFaults` for every env, or a
            sequence of one per env (a soak batch's sessions).
        seed: Of the noise and fault draws: an int (one generator for every env), or a sequence
            of one ``numpy.random.Generator`` per env (a soak session's own stream).
        where: Named in a refusal (the robot's MJCF).

    Attributes:
        frames: (envs,) frames captured; delivered, dropped, spiked, frozen: counts (envs,).
        faults: The env 0's faults; ``env_faults``: every env's.
    """

    image_field = "depth_image"
    stamp_field = "depth_stamp"
    dtype = np.float32

    def __init__(self, plant, block, rate, latency, faults, seed, where: str, renderer, scene=None):
        self.plant, self.block, self.scene = plant, block, scene
        self.rate = float(block.rate if rate is None else rate)
        self.latency = float(block.latency if latency is None else latency)
        if not (self.rate > 0 and self.latency >= 0):
            raise ValueError(
                f"{type(self).__name__}: rate > 0 Hz, latency >= 0 s; got {self.rate}, "
                f"{self.latency}"
            )
        envs = plant.envs
        if faults is None or isinstance(faults, CameraFaults):
            self.env_faults = [faults or CameraFaults()] * envs
        else:
            self.env_faults = list(faults)
            if len(self.env_faults) != envs:
                raise ValueError(
                    f"{type(self).__name__}: {len(self.env_faults)} faults, {envs} envs"
                )
        self.faults = self.env_faults[0]
        if isinstance(seed, int | np.integer):
            self.rng = np.random.default_rng(seed)
            self.rngs = [self.rng] * envs
        else:
            self.rngs = list(seed)
            self.rng = self.rngs[0]
        models = plant.models if scene is None else scene.models
        self.renderers = [renderer(m, block.camera, block.shape, where) for m in models]
        for r, f in zip(self.renderers, self.env_faults, strict=True):
            if any(f.extrinsic):  # the camera knocked on its mount: its MuJoCo pose turned
                turn, quat = np.zeros(4), np.zeros(4)
                mujoco.mju_euler2Quat(turn, np.asarray(f.extrinsic, float), "XYZ")
                cid = r.cam.fixedcamid
                mujoco.mju_mulQuat(quat, r.model.cam_quat[cid].copy(), turn)
                r.model.cam_quat[cid] = quat
        #: per env, the columns a covered lens blinds
        self._blind = [int(round(f.occlusion * block.shape[1])) for f in self.env_faults]
        self.frames = np.zeros(envs, dtype=np.int64)
        #: per env, the index of the next frame to capture (-1: the first fill's frame, the last
        #: due by its time: a camera attached to a plant resumed from a checkpoint streams from
        #: there, not from 0 s)
        self._next = np.full(envs, -1, dtype=np.int64)
        self.delivered = np.zeros(envs, dtype=np.int64)
        self.dropped = np.zeros(envs, dtype=np.int64)
        self.spiked = np.zeros(envs, dtype=np.int64)
        self.frozen = np.zeros(envs, dtype=np.int64)
        self._freeze_left = np.zeros(envs, dtype=np.int64)
        self._last = np.zeros((envs, *block.frame_shape), self.dtype)  # the last image made
        #: per env, the latest faulted frames: (stamp s, 'dropped' | 'spiked' | 'frozen')
        self._events = [deque(maxlen=RECENT_EVENTS) for _ in range(envs)]
        #: per env, frames in flight: [(deliver_at s, stamp s, image)]
        self._queue: list[list[tuple[float, float, np.ndarray]]] = [[] for _ in range(envs)]
        #: the most frames in flight at once: each stays at most latency + spike_latency s
        spike = max(f.spike_latency for f in self.env_faults)
        self.in_flight = int(np.ceil((self.latency + spike) * self.rate)) + 2

    def show_goal(self, goal) -> None:
        """The task scene's goal marker (where the robot has a task scene,
        :mod:`sim2real.deploy.backends.sim.task_scene`) shows ``goal`` ((envs, 3) m, the run's
        goals, an array the run writes in place each tick); without a scene, nothing."""
        if self.scene is not None:
            self.scene.goal = goal

    def scene_data(self, env: int):
        """The ``MjData`` env ``env``'s camera renders: the plant's, or the robot's task scene
        (:class:`~sim2real.deploy.backends.sim.task_scene.TaskScene`) given the plant's pose,
        geometry and the goal."""
        data = self.plant.datas[env]
        if self.scene is not None:
            data = self.scene.sync(env, data, self.renderers[env].model)
        return data

    def _sense(self, e: int, rng: np.random.Generator) -> np.ndarray:
        """Env ``e``'s image now through the sensor model, its covered columns blinded."""
        raise NotImplementedError

    def _capture(self, e: int, stamp: float) -> None:
        f, rng = self.env_faults[e], self.rngs[e]
        self.frames[e] += 1
        self._next[e] += 1
        if self._freeze_left[e] > 0:  # a stuck driver: the old image again, stamped anew
            self._freeze_left[e] -= 1
            self.frozen[e] += 1
            self._events[e].append((stamp, "frozen"))
            image = self._last[e].copy()
        else:
            image = self._sense(e, rng)
            self._last[e] = image
            if f.freeze and rng.random() < f.freeze:
                self._freeze_left[e] = f.freeze_frames
        if f.drop and rng.random() < f.drop:
            self.dropped[e] += 1
            self._events[e].append((stamp, "dropped"))
            return
        late = self.latency
        if f.spike and rng.random() < f.spike:
            self.spiked[e] += 1
            self._events[e].append((stamp, "spiked"))
            late += f.spike_latency
        self._queue[e].append((stamp + late, stamp, image))

    def fill(self, frame) -> None:
        """Capture the frames due by ``frame.time`` and write the newest delivered one into the
        frame's image and stamp fields (``image_field``, ``stamp_field``; made on the first
        call; module docstring)."""
        envs = self.plant.envs
        if getattr(frame, self.image_field, None) is None:
            setattr(frame, self.image_field, np.zeros((envs, *self.block.frame_shape), self.dtype))
            setattr(frame, self.stamp_field, np.full(envs, np.nan))
        images, stamps = getattr(frame, self.image_field), getattr(frame, self.stamp_field)
        now = np.broadcast_to(np.asarray(frame.time, dtype=float), (envs,))
        for e in range(envs):
            if self._next[e] < 0:
                self._next[e] = max(int(np.floor(now[e] * self.rate + 1e-9)), 0)
            while self._next[e] / self.rate <= now[e] + 1e-9:
                self._capture(e, self._next[e] / self.rate)
            queue = self._queue[e]
            ready = [item for item in queue if item[0] <= now[e] + 1e-9]
            if ready:
                newest = max(ready, key=lambda item: item[1])
                self._queue[e] = [item for item in queue if item[1] > newest[1]]
                self.delivered[e] += 1
                images[e] = newest[2]
                stamps[e] = newest[1]

    def recent(self, env: int, now: float, window: float = 1.0) -> dict:
        """What env ``env``'s camera faults did in the ``window`` s before ``now``: frames
        ``dropped``, ``spiked`` (late) and ``frozen`` captured then, and the ``last`` faulted
        frame's fault and capture time (None: none among the latest ``RECENT_EVENTS``); a stale
        stop's record names it (:mod:`sim2real.deploy.runtime.stale`)."""
        counts = {"dropped": 0, "spiked": 0, "frozen": 0}
        for stamp, kind in self._events[env]:
            if now - window < stamp <= now + 1e-9:
                counts[kind] += 1
        events = self._events[env]
        last = {"fault": events[-1][1], "stamp_s": events[-1][0]} if events else None
        return {"window_s": window, **counts, "last": last}

    def summary(self, env: int | None = None) -> dict:
        """The run report's camera lines: rate, latency, faults and the counts per env (of env
        ``env`` alone when given: its faults and counts as numbers)."""
        counts = ("frames", "delivered", "dropped", "spiked", "frozen")
        if env is not None:
            return {
                "camera": self.block.camera,
                "kind": self.block.kind,
                "rate_hz": self.rate,
                "latency_s": self.latency,
                "faults": self.env_faults[env].to_dict(),
                **{k: int(getattr(self, k)[env]) for k in counts},
            }
        return {
            "camera": self.block.camera,
            "rate_hz": self.rate,
            "latency_s": self.latency,
            "faults": self.faults.to_dict(),
            **{k: getattr(self, k).tolist() for k in counts},
        }

    def _fields(self) -> dict:
        """The per-env arrays of the state (leading env axis); a subclass adds its own."""
        return {
            "frames": self.frames,
            "delivered": self.delivered,
            "dropped": self.dropped,
            "spiked": self.spiked,
            "frozen": self.frozen,
            "freeze_left": self._freeze_left,
            "next": self._next,
            "last": self._last,
        }

    def state_dict(self, env: int | None = None) -> dict:
        """The counts, the next frame's index, the frozen spell, the last image, the frames in
        flight (``queue_deliver``, ``queue_stamp`` s, NaN: none; ``queue_image``; at most
        :attr:`in_flight` per env) and each env's random stream (JSON; :mod:`sim2real.deploy.
        core.stateful`): a fresh camera of the same arguments loaded with it captures and
        delivers the same frames. The recent faults (:meth:`recent`) are not kept."""
        envs = env_list(self.plant.envs, env)
        deliver = np.full((len(envs), self.in_flight), np.nan)
        stamp = np.full((len(envs), self.in_flight), np.nan)
        image = np.zeros((len(envs), self.in_flight, *self.block.frame_shape), self.dtype)
        for i, e in enumerate(envs):
            for j, (at, st, im) in enumerate(self._queue[e][: self.in_flight]):
                deliver[i, j], stamp[i, j], image[i, j] = at, st, im
        return {
            **take(self._fields(), env),
            "queue_deliver": deliver,
            "queue_stamp": stamp,
            "queue_image": image,
            "streams": streams_json(self.rngs, envs),
        }

    def load_state_dict(self, state, env: int | None = None) -> None:
        """Raises StateDictError: a missing field or another shape (nothing written)."""
        envs = env_list(self.plant.envs, env)
        queue = {
            "queue_deliver": np.zeros((self.plant.envs, self.in_flight)),
            "queue_stamp": np.zeros((self.plant.envs, self.in_flight)),
            "queue_image": np.zeros((self.plant.envs, self.in_flight, *self.block.frame_shape)),
        }
        streams = read_streams(state, "streams", len(envs))
        put({**self._fields(), **queue}, state, env)  # checks every field first
        set_streams(self.rngs, envs, streams, "streams")
        for i, e in enumerate(envs):
            self._events[e].clear()
            self._queue[e] = [
                (float(at), float(st), np.array(im, dtype=self.dtype))
                for at, st, im in zip(
                    state["queue_deliver"][i], state["queue_stamp"][i], state["queue_image"][i],
                    strict=True,
                )
                if np.isfinite(st)
            ]  # fmt: skip

    def close(self) -> None:
        for r in self.renderers:
            r.close()


@dataclass(frozen=True)
class CameraFaultRanges:
    """The ranges a session's :class:`CameraFaults` are drawn from, uniformly (our choice):
    ``drop`` 0-5 % of frames, ``spike`` 0-2 % of frames 50-200 ms late, ``freeze`` 0-0.5 % of
    frames starting a 5-30 frame spell, ``occlusion`` 0-10 % of the columns, ``extrinsic`` up
    to 2 deg about each axis (a camera knocked on its mount), ``lighting`` the scene's light
    times 0.5-1.5 (a lamp switched off or on, the sun through a window; a colour camera's)."""

    drop: tuple[float, float] = (0.0, 0.05)
    spike: tuple[float, float] = (0.0, 0.02)
    spike_latency: tuple[float, float] = (0.05, 0.2)
    freeze: tuple[float, float] = (0.0, 0.005)
    freeze_frames: tuple[int, int] = (5, 30)
    occlusion: tuple[float, float] = (0.0, 0.1)
    extrinsic: float = float(np.radians(2.0))
    lighting: tuple[float, float] = (0.5, 1.5)

    def sample(self, rng: np.random.Generator) -> CameraFaults:
        """One session's draw (eight draws of ``rng``, in the fields' order; ``extrinsic``
        three uniform in +-``extrinsic`` rad; ``lighting`` last, so the others are what they
        were before it was drawn)."""
        return CameraFaults(
            drop=float(rng.uniform(*self.drop)),
            spike=float(rng.uniform(*self.spike)),
            spike_latency=float(rng.uniform(*self.spike_latency)),
            freeze=float(rng.uniform(*self.freeze)),
            freeze_frames=int(rng.integers(self.freeze_frames[0], self.freeze_frames[1] + 1)),
            occlusion=float(rng.uniform(*self.occlusion)),
            extrinsic=tuple(float(v) for v in rng.uniform(-self.extrinsic, self.extrinsic, 3)),
            lighting=float(rng.uniform(*self.lighting)),
        )
