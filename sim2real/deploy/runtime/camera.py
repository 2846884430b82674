"""The runtime's camera input (:class:`CameraInput`): the depth or colour frames a policy's image
block reads, the last one delivered and its age, the frame history the graph takes, and a camera
judged stale like any sensor.

Each tick its ``source`` (a simulated plant's camera,
:class:`sim2real.deploy.backends.sim.plant_camera.PlantCamera`; on hardware a driver's feed,
:class:`sim2real.deploy.backends.camera.feed.CameraFeed`) leaves the newest delivered frame in
``frame.depth_image`` ((envs, rows, columns) m) and its capture time in ``frame.depth_stamp``
((envs,) s); for an RGB block (:class:`sim2real.deploy.spec.camera.RgbImageBlock`)
``frame.rgb_image`` ((envs, rows, columns, 3) uint8 R, G, B; a driver delivering OpenCV's BGR flips
it first) and ``frame.rgb_stamp`` (``FRAME_FIELDS``; the plant's
:class:`sim2real.deploy.backends.sim.rgb_camera.PlantRgbCamera`). A frame is fresh when its stamp
is newer than the last one taken and its image is not the last one's again (a frozen driver repeats
its buffer with new stamps; a real image never repeats bit for bit, its noise differs; a frame
without one valid (non-zero) pixel, a view of open sky or a black image, may, and is fresh). A
fresh frame is checked (:func:`sim2real.deploy.spec.camera.check_frames`: a non-numeric frame or
one of another shape is refused in one line), preprocessed
(:func:`sim2real.deploy.spec.camera.preprocess`) and pushed into the history; the graph's image
input ((envs, frames, rows, columns) of depth, its layout the block's ``input_shape``; oldest
first, ``skip`` delivered frames apart) is written in place into the array the policy binds
(``policy.images[block.input]``). Until an env has the history's span of frames, its oldest entries
repeat its first frame (Extreme Parkour fills its ``depth_buffer`` with copies of the first image
at an episode's start).

Stale: an env whose last fresh frame is older than its ``stale_limit`` (or that has had none
``stale_limit`` s after the stage's first tick: a camera streams before the loop starts) is
safe-stopped (``stale_sensor``), as a silent IMU is. The limit is the robot's
``Robot.stale_limit`` plus the block's training latency plus ``STALE_FRAMES`` frame periods of its
rate (a 30 Hz camera is not stale between two frames; our choice: three frames lost in a row are).
Several cameras: one :class:`CameraInput` per image block, run by :class:`CameraInputs`.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from sim2real.deploy.core.stateful import load_named, put, take
from sim2real.deploy.runtime.height_map import height_map_stage
from sim2real.deploy.spec.camera import DepthImageBlock, RgbImageBlock, check_frames, preprocess

#: Frame periods past the robot's stale limit before a camera is stale (module docstring).
STALE_FRAMES = 3
#: The frame's (image, stamp) fields of each block kind (module docstring).
FRAME_FIELDS = {"depth": ("depth_image", "depth_stamp"), "rgb": ("rgb_image", "rgb_stamp")}


class CameraInput:
    """The depth or colour image input of ``envs`` robots (module docstring).

    Args:
        block: The policy's image block (depth or RGB). envs: Robots.
        stale_limit: s, a camera whose last fresh frame is older stops the robot.
        source: ``fill(frame)`` writing the frame's image each tick, or None (the backend
            writes the frame itself).
        own_frame: The source fills a frame of this camera's own (its ``time`` the tick's),
            not the runtime's (several cameras: :class:`CameraInputs`).

    Attributes:
        image: float32 (envs, *block.input_shape), the graph's image input of the last tick.
        stamp: (envs,) s, the last fresh frame's capture time (-inf: none yet).
        time_since_fresh: (envs,) s, since that frame (none yet: since the first tick).
        stale: (envs,) bool, this tick's.
        taken: (envs,) int64 fresh frames taken. repeated: (envs,) int64 frames that came again
            with a new stamp (frozen). oldest: (envs,) s, the largest age after the first frame.
    """

    def __init__(
        self,
        block: DepthImageBlock | RgbImageBlock,
        envs: int,
        stale_limit: float,
        source=None,
        own_frame: bool = False,
    ):
        self.block, self.envs, self.stale_limit, self.source = block, envs, stale_limit, source
        self._frame = SimpleNamespace(time=0.0) if own_frame and source is not None else None
        self.image_field, self.stamp_field = FRAME_FIELDS[block.kind]
        span = (block.frames - 1) * block.skip + 1
        self._ring = np.zeros((envs, span, *block.input_shape[1:]), np.float32)
        # the last raw frame taken (float: NaN is none)
        self._raw = np.full((envs, *block.frame_shape), np.nan, np.float32)
        self.image = np.zeros((envs, *block.input_shape), np.float32)
        self.stamp = np.full(envs, -np.inf)
        #: the newest stamp looked at, fresh or repeated (a repeated frame counts once, not once
        #: per tick it stays in the frame)
        self._looked = np.full(envs, -np.inf)
        self._start = np.nan  # the first tick's time: a camera's first frame is due by then
        self.time_since_fresh = np.full(envs, np.inf)
        self.stale = np.zeros(envs, dtype=bool)
        self.taken = np.zeros(envs, dtype=np.int64)
        self.repeated = np.zeros(envs, dtype=np.int64)
        self._frozen = np.zeros(envs, dtype=np.int64)  # repeated since the last fresh frame
        self.oldest = np.zeros(envs)
        #: ring positions of the graph's frames, oldest first, relative to the newest
        self._back = block.skip * np.arange(block.frames - 1, -1, -1)

    @property
    def inputs(self) -> tuple[CameraInput, ...]:
        """The stage's cameras: this one (:class:`CameraInputs` has several)."""
        return (self,)

    @property
    def blocks(self) -> tuple:
        """The image blocks read, in the spec's order: this camera's."""
        return (self.block,)

    def update(self, frame, images: np.ndarray | None = None) -> np.ndarray:
        """Take the frame's image (``image_field``) where it is fresh, write the graph's image input into
        :attr:`image` and into ``images`` (the policy's bound input) when given; returns
        :attr:`stale`.

        Raises:
            CameraError: a non-numeric frame or one of another shape (module docstring).
        """
        into = frame
        if self._frame is not None:  # a camera's own frame (several cameras)
            into = self._frame
            into.time = frame.time
        if self.source is not None:
            self.source.fill(into)
        raw = getattr(into, self.image_field, None)
        if raw is not None:
            raw = check_frames(raw, self.block, self.envs, f"frame.{self.image_field}")
            stamp = np.asarray(getattr(into, self.stamp_field), dtype=float)
            newer = stamp > self._looked  # NaN: nothing delivered
            for e in np.flatnonzero(newer):
                self._looked[e] = stamp[e]
                if np.array_equal(raw[e], self._raw[e]) and (raw[e] > 0).any():  # frozen
                    self.repeated[e] += 1
                    self._frozen[e] += 1
                    continue
                self._push(e, raw[e], stamp[e])
        if np.isnan(self._start):
            self._start = float(np.min(frame.time))
        np.subtract(frame.time, np.maximum(self.stamp, self._start), out=self.time_since_fresh)
        np.maximum(
            self.oldest, np.where(self.taken > 0, self.time_since_fresh, 0.0), out=self.oldest
        )
        np.greater(self.time_since_fresh, self.stale_limit, out=self.stale)
        if images is not None and images is not self.image:
            images[:] = self.image
        return self.stale

    def feed(self, frame, policy, supervision) -> None:
        """The tick's :meth:`update`, written into ``policy.images[block.input]`` (the array an
        :class:`~sim2real.deploy.policy.onnx_policy.OnnxPolicy` binds), and the safe stop
        (``stale_sensor``) of the envs whose camera is stale."""
        bind = getattr(policy, "bind_batch", None)
        if bind is not None:  # its image inputs of this batch before the first call
            bind(self.envs)
        images = getattr(policy, "images", {}).get(self.block.input)
        supervision.safe_stop(self.update(frame, images), "stale_sensor")

    def _push(self, e: int, raw: np.ndarray, stamp: float) -> None:
        span = self._ring.shape[1]
        image = preprocess(raw[None], self.block)[0]
        if self.taken[e] == 0:  # the first frame fills the history
            self._ring[e] = image
        else:
            self._ring[e, self.taken[e] % span] = image
        self.taken[e] += 1
        self._frozen[e] = 0
        self._raw[e] = raw
        self.stamp[e] = stamp
        newest = (self.taken[e] - 1) % span
        self.image[e] = self._ring[e, (newest - self._back) % span]

    def stale_phrase(self, e: int) -> str:
        """What env ``e``'s camera did, for a stale stop's verdict: frames repeated since its last
        fresh one (frozen) or none fresh."""
        n = int(self._frozen[e])
        if n:
            return f"{n} frame{'s' if n != 1 else ''} repeated with new stamps (frozen)"
        return "no fresh frame arrived (dropped or late)"

    def reset(self, envs: np.ndarray) -> None:
        """Start the history of the envs of ``envs`` (bool mask) again: their next fresh frame
        fills it (their stamps and counts are kept). The runtime does not call it at a restart:
        the history then refills within ``frames x skip`` frames."""
        envs = np.asarray(envs, dtype=bool)
        self.taken[envs] = 0
        self._raw[envs] = np.nan

    def summary(self) -> dict:
        """The run report's lines: the camera, frames taken and repeated, the oldest age, s."""
        return {
            "camera": self.block.camera,
            "stale_limit_s": self.stale_limit,
            "frames_taken": self.taken.tolist(),
            "frames_repeated": self.repeated.tolist(),
            "oldest_s": [round(float(v), 6) for v in self.oldest],
        }

    def _fields(self) -> dict:
        return {
            "ring": self._ring,
            "raw": self._raw,
            "image": self.image,
            "stamp": self.stamp,
            "looked": self._looked,
            "taken": self.taken,
            "repeated": self.repeated,
            "frozen": self._frozen,
            "oldest": self.oldest,
        }

    def state_dict(self, env: int | None = None) -> dict:
        """The history, the last frame, its stamp and the counts (copies, leading env axis;
        :mod:`sim2real.deploy.core.stateful`)."""
        return take(self._fields(), env)

    def load_state_dict(self, state, env: int | None = None) -> None:
        """Raises StateDictError: a missing field or another shape (nothing written)."""
        put(self._fields(), state, env)


class CameraInputs:
    """Several cameras of one policy (a LeRobot policy's ``front`` and ``wrist``): one
    :class:`CameraInput` per image block of the spec, in the spec's order (the observation's layout
    stays the spec's image blocks), run in that order each tick; an env is stopped when any of them
    is stale (the stop's record names the camera, :mod:`sim2real.deploy.runtime.stale`).

    Each camera's source is the backend's ``camera_source`` group's
    (:class:`sim2real.deploy.backends.camera.sources.CameraSources`) of its name, and writes into a
    frame of the camera's own (two cameras of one kind share the frame's field names). One stage per
    camera rather than one stage of N cameras: a camera's arrays, rate, limit and state are the
    single-camera stage's unchanged, so a one-camera policy runs exactly as before.

    Args:
        inputs: The cameras' stages (each with its own block, rate, stale limit and source).
        source: The backend's camera group (its ``state_dict`` is the runtime's
            ``camera_source`` part), or None.

    Attributes:
        stale: (envs,) bool, this tick's: any camera stale.
    """

    def __init__(self, inputs, source=None):
        self.inputs = tuple(inputs)
        self.source = source
        self.blocks = tuple(c.block for c in self.inputs)
        self.envs = self.inputs[0].envs
        self.stale = np.zeros(self.envs, dtype=bool)

    @property
    def time_since_fresh(self) -> np.ndarray:
        """(envs,) s, the oldest of the cameras' last fresh frames' ages."""
        return np.max([c.time_since_fresh for c in self.inputs], axis=0)

    def update(self, frame, images: dict | None = None) -> np.ndarray:
        """Each camera's :meth:`CameraInput.update` (into ``images[block.input]`` where
        ``images``, the policy's bound inputs, has it); returns :attr:`stale`.

        Raises:
            CameraError: a camera's frame refused (:meth:`CameraInput.update`)."""
        self.stale[:] = False
        for c in self.inputs:
            bound = None if images is None else images.get(c.block.input)
            self.stale |= c.update(frame, bound)
        return self.stale

    def feed(self, frame, policy, supervision) -> None:
        """Every camera's update into the policy's bound inputs, then one safe stop
        (``stale_sensor``) of the envs where any camera is stale (its record sees them all)."""
        bind = getattr(policy, "bind_batch", None)
        if bind is not None:
            bind(self.envs)
        supervision.safe_stop(self.update(frame, getattr(policy, "images", {})), "stale_sensor")

    def reset(self, envs: np.ndarray) -> None:
        """:meth:`CameraInput.reset` of every camera."""
        for c in self.inputs:
            c.reset(envs)

    def summary(self) -> dict:
        """Per camera name, its :meth:`CameraInput.summary`."""
        return {c.block.camera: c.summary() for c in self.inputs}

    def state_dict(self, env: int | None = None) -> dict:
        """Each camera's :meth:`CameraInput.state_dict` under ``<camera>/``."""
        return {
            f"{c.block.camera}/{k}": v for c in self.inputs for k, v in c.state_dict(env).items()
        }

    def load_state_dict(self, state, env: int | None = None) -> None:
        """Raises StateDictError: a camera's field missing or of another shape (nothing
        written: the cameras loaded before it are put back)."""
        load_named(((c.block.camera, c) for c in self.inputs), state, env)


def exteroception(spec, state, envs: int, robot, backend) -> tuple:
    """The runtime's exteroceptive stages: ``(height map, camera)``, each None where the spec
    has no such input (:func:`sim2real.deploy.runtime.height_map.height_map_stage`,
    :func:`camera_stage`)."""
    return (
        height_map_stage(spec, state, envs, robot, backend),
        camera_stage(spec, envs, robot, backend),
    )


def camera_stage(spec, envs: int, robot, backend) -> CameraInput | CameraInputs | None:
    """The runtime's camera stage for a spec with image blocks (module docstring), else None:
    one block, a :class:`CameraInput` (its source the backend's ``camera_source`` where it has
    one); several, a :class:`CameraInputs` of one per block, each fed by the backend's camera
    group's source of its name (``camera_source.sources``).

    Raises:
        ValueError: several image blocks and a backend whose ``camera_source`` is no group
            serving every one of them (one line naming the cameras)."""
    images = getattr(spec, "images", ())
    if not images:
        return None

    def limit(block) -> float:
        return float(robot.stale_limit) + block.latency + STALE_FRAMES / block.rate

    source = getattr(backend, "camera_source", None)
    if len(images) == 1:
        return CameraInput(images[0], envs, limit(images[0]), source)
    names = [b.camera for b in images]
    if len(set(names)) < len(names):
        raise ValueError(f"images: cameras {names}; expected each camera once")
    served = getattr(source, "sources", {})
    missing = [n for n in names if n not in served]
    if missing:
        raise ValueError(
            f"images: cameras {names}; the backend delivers no frames of {missing} (expected a "
            "source for each: the plant's cameras or one --camera-source per camera)"
        )
    inputs = [CameraInput(b, envs, limit(b), served[b.camera], own_frame=True) for b in images]
    return CameraInputs(inputs, source)
