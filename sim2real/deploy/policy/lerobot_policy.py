"""An exported LeRobot policy as a policy of the runtime (:class:`LeRobotChunkPolicy`): the ONNX
graph of :mod:`sim2real.deploy.export.lerobot_act` at its own rate (the contract's ``fps``) beside
the faster servo loop, its action chunks executed by
:class:`~sim2real.deploy.policy.action_chunks.ActionChunks`, and the robot's joints in LeRobot's
units (:data:`LEROBOT_UNITS`).

The runtime calls a policy once per control tick (the servo loop's rate, ``Robot.control_period``);
this one is a policy whose rate is below it. Its own tick (a *policy tick*) comes every ``1 / fps``
s of the servo loop's time (30 Hz beside 100 Hz: a policy tick every 3 or 4 servo ticks, on
average every 3.33); between policy ticks it returns the action of the last one again, and the
runtime takes that held target through the guard and the smoother on every servo tick as it does
any policy's. At a policy tick the graph is called when a chunk is needed (the action queue: every
``n_action_steps`` policy ticks; temporal ensembling: every policy tick). The runtime's
``reset(envs)`` (the start, the end of RAMP_IN, a resume) starts the envs' chunks afresh: the
first RUNNING tick is a policy tick with a new chunk, so the policy sees the robot at home, not a
queue filled during the ramp. The state (each env's queue or ensemble, the time to its next policy
tick, the held action) is the stage's (:meth:`state_dict` / :meth:`load_state_dict`).

Inference (``inference``): ``"sync"`` calls the graph inside the servo tick that needs a chunk;
``"async"`` on a worker thread (:class:`~sim2real.deploy.policy.chunk_worker.ChunkWorker`), one
policy period of latency on every backend: the chunk asked at a policy tick is taken (awaited) at
the next, its first action dropped (its time has passed), ``min(n_action_steps, chunk_size - 1)``
actions played, the next asked at the tick of the last, held meanwhile
(:meth:`LeRobotChunkPolicy._policy_tick_async`; a late chunk: :attr:`LeRobotChunkPolicy.late`).

Observation, action and units: :class:`LeRobotChunkPolicy`.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from sim2real.deploy.core.stateful import put, take
from sim2real.deploy.policy.action_chunks import ActionChunks
from sim2real.deploy.policy.chunk_worker import ChunkRequest, ChunkWorker
from sim2real.deploy.spec.camera import RgbImageBlock
from sim2real.deploy.spec.foreign import lerobot as lr

#: Per robot, LeRobot's unit of each joint in our joint order: ``deg`` (degrees) or ``range_0_100``
#: (percent of the joint's range, our hard limits). Module docstring for the sources.
LEROBOT_UNITS: dict[str, tuple[str, ...]] = {
    "so101": ("deg", "deg", "deg", "deg", "deg", "range_0_100"),
}
#: The prefix of a LeRobot camera key; the rest is the camera's name (lerobot's
#: ``OBS_IMAGES`` in ``lerobot/utils/constants.py``).
IMAGE_PREFIX = "observation.images."
#: The inference modes (module docstring): the network call inside the servo tick, or beside it.
INFERENCE = ("sync", "async")


def camera_blocks(contract: lr.LeRobotContract, where: str) -> tuple[RgbImageBlock, ...]:
    """The contract's camera keys as RGB image blocks (:class:`LeRobotChunkPolicy`), in the
    contract's order (``config.json``'s, the graph's inputs'): input the key, camera the key's
    last part, shape and resize the contract's (H, W), rate its fps.

    Raises:
        lr.LeRobotFormatError: a key without the ``observation.images.`` prefix, a shape that
            is not (3, H, W).
    """
    blocks = []
    for key, shape in contract.cameras:
        if not key.startswith(IMAGE_PREFIX) or len(key) == len(IMAGE_PREFIX):
            raise lr.LeRobotFormatError(
                f"{where}: camera key {key!r}; expected {IMAGE_PREFIX}<name>"
            )
        if len(shape) != 3 or shape[0] != 3:
            raise lr.LeRobotFormatError(
                f"{where}: camera {key} of shape {list(shape)}; expected [3, H, W]"
            )
        hw = (int(shape[1]), int(shape[2]))
        blocks.append(
            RgbImageBlock(
                input=key, camera=key[len(IMAGE_PREFIX) :], shape=hw, resize=hw,
                rate=float(contract.fps),
            )
        )  # fmt: skip
    return tuple(blocks)


class LeRobotChunkPolicy:
    """A LeRobot export as the runtime's policy of one robot (module docstring).

    Observation: the spec (:attr:`LeRobotChunkPolicy.spec`) is the robot's standard one over
    ``joint_position`` (and ``goal_position`` when the policy reads an
    ``observation.environment_state`` of 3 entries: the goal, m, in the base frame, as
    :mod:`sim2real.eval.lerobot.dataset` writes it); this class reads the joints and the goal back out
    of that vector exactly (its blocks' offset and scale) and converts them to LeRobot's units. Each
    camera key ``observation.images.<name>`` is an :class:`~sim2real.deploy.spec.camera.RgbImageBlock`
    of the MJCF camera or ``--camera-source`` named ``<name>``: a uint8 RGB frame of the contract's
    (H, W), one frame, ``CHW``, ``x / 255`` (lerobot's ``prepare_observation_for_inference``); the
    runtime's camera stage writes it into :attr:`images` and stops a stale camera (``stale_sensor``)
    as any sensor. Several cameras (``front`` and ``wrist``) are one block each, in the
    contract's order, each at the policy's fps and each stale on its own.

    Action: the graph's action (LeRobot's units) converted to joint targets, rad, returned as the
    spec's absolute position action (``(target - offset) / scale``, clipped to the soft range as any
    policy's full action; the guard clamps at the soft limits anyway).

    Units: lerobot 0.4.4's SO-100/SO-101 follower (``lerobot/robots/so_follower/so_follower.py``
    lines 51-60, ``config_so_follower.py`` line 43 ``use_degrees: bool = True``) reads and writes the
    five arm joints in degrees (``MotorNormMode.DEGREES``: 0 at the middle of the calibrated range) and
    the gripper in percent of its calibrated range (``MotorNormMode.RANGE_0_100``). Here degrees are
    about the MJCF's zero, and the gripper's calibrated range is the MJCF's hard limits of the gripper
    joint: a real arm's calibration must put those where they are in the MJCF.

    Args:
        path: The ONNX file ``policy-export FOLDER`` wrote (its ``lerobot_contract`` metadata).
        robot: Our robot description; its name must be in :data:`LEROBOT_UNITS` and its joints
            as many as the contract's state and action entries.
        inference: ``"sync"`` (the default of this class: the network call in the servo tick)
            or ``"async"`` (on a worker thread, one policy period of latency; module docstring).

    Attributes:
        contract: The file's :class:`~sim2real.deploy.spec.foreign.lerobot.LeRobotContract`.
        spec: The runtime's :class:`~sim2real.deploy.spec.policy_spec.PolicySpec` (above);
            its ``control_rate`` is the servo loop's, at which the runtime calls it.
        period: s, one policy tick (``1 / fps``). dt: s, the servo period.
        images: {camera key: float32 (envs, 1, 3, H, W)}, written by the runtime's camera stage.
        chunks: One :class:`~sim2real.deploy.policy.action_chunks.ActionChunks` per env.
        new_chunk: (envs,) bool, the last call took a new chunk (a network call) in that env.
        policy_tick: (envs,) bool, the last call was a policy tick in that env.
        policy_ticks, calls: (envs,) int64, policy ticks and network calls so far (async:
            chunks taken).
        servo_thread_calls: (envs,) int64, network calls run on the calling (servo) thread.
        waits: (envs,) int64, async: chunks not done at the tick that takes them (the servo
            thread waited); wait_max: s, the longest such wait.
        late: (envs,) bool, async: a chunk still not done ``late_limit`` s into its wait (the
            env holds its target and asks nothing until its reset); late_chunks: (envs,) int64.
        late_limit: s, half the robot's ``stale_limit`` (robot.toml): a wait longer than that
            would let the bus's readings go stale. wall_clock: bound the wait by it (set by the
            chunk hook from the run's clock; False in lockstep, where the wait is unbounded, so
            a lockstep run is repeatable).

    Raises:
        lr.LeRobotFormatError: the file has no contract or no fps, the robot does not fit (no
            LeRobot units, another joint count), an environment state that is not the goal's 3
            entries, a camera key or shape refused, temporal ensembling or a chunk of one
            action with async inference (one line naming the file).
        ValueError: an ``inference`` not in :data:`INFERENCE`.
    """

    def __init__(self, path: str | Path, robot, inference: str = "sync"):
        import onnxruntime as ort

        from sim2real.deploy.spec.policy_spec import PolicySpec

        self.path = str(path)
        self.contract = c = lr.read_onnx(path)
        units = LEROBOT_UNITS.get(robot.name)
        if units is None:
            raise lr.LeRobotFormatError(
                f"{path}: robot {robot.name!r} has no LeRobot joint units (known: "
                f"{', '.join(LEROBOT_UNITS)})"
            )
        if c.state_dim != robot.n_joints or c.action_dim != robot.n_joints:
            raise lr.LeRobotFormatError(
                f"{path}: state {c.state_dim} and action {c.action_dim} entries, robot "
                f"{robot.name} has {robot.n_joints} joints"
            )
        if c.fps is None:
            raise lr.LeRobotFormatError(f"{path}: the contract has no fps")
        if inference not in INFERENCE:
            raise ValueError(f"inference {inference!r}; expected one of {', '.join(INFERENCE)}")
        if inference == "async" and c.temporal_ensemble_coeff is not None:
            raise lr.LeRobotFormatError(
                f"{path}: temporal_ensemble_coeff {c.temporal_ensemble_coeff:g} with async "
                "inference (every policy tick's chunk would be a period late); expected sync "
                "inference (--inference sync) or an export without temporal ensembling"
            )
        if inference == "async" and c.chunk_size < 2:
            raise lr.LeRobotFormatError(
                f"{path}: chunk_size {c.chunk_size} with async inference (its one action is late "
                "when taken); expected chunk_size >= 2 or sync inference (--inference sync)"
            )
        self.inference = inference
        self.late_limit = 0.5 * float(robot.stale_limit)
        self.wall_clock = False
        self._worker = ChunkWorker(self._run) if inference == "async" else None
        if c.env_state_dim not in (0, 3):
            raise lr.LeRobotFormatError(
                f"{path}: {lr.ENV_STATE_KEY} of {c.env_state_dim} entries; the runtime feeds "
                "it the goal (3 entries, m, base frame) or nothing"
            )
        blocks = ("joint_position", "goal_position") if c.env_state_dim else ("joint_position",)
        spec = PolicySpec.for_robot(robot, blocks=blocks, mode="position")
        self.spec = replace(spec, images=camera_blocks(c, str(path)))
        self.spec.validate()
        self.units = np.array([u == "deg" for u in units])
        self.lower = np.asarray(robot.position_lower, float)
        self.upper = np.asarray(robot.position_upper, float)
        # one thread, no spinning pool beside the servo loop (OnnxPolicy's session options): on a
        # loaded 2-core machine the two-camera ACT's call took 48 ms with ONNX Runtime's default
        # pool and 23 ms with one thread, the same chunk bit for bit (docs/lerobot.md)
        options = ort.SessionOptions()
        options.intra_op_num_threads = options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        options.add_session_config_entry("session.inter_op.allow_spinning", "0")
        self.session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        self.period = 1.0 / float(c.fps)
        self.dt = float(robot.control_period)
        self.n = robot.n_joints
        a = self.spec.action
        self._offset, self._scale = np.asarray(a.offset), np.asarray(a.scale)
        self._clip = float(a.clip)
        self._bind(1)

    # ------------------------------------------------------------------ batch
    def _bind(self, envs: int) -> None:
        self.envs = envs
        self.images = {
            b.input: np.zeros((envs, *b.input_shape), np.float32) for b in self.spec.images
        }
        c = self.contract
        self.chunks = [
            ActionChunks(c.chunk_size, c.n_action_steps, c.temporal_ensemble_coeff)
            for _ in range(envs)
        ]
        self._out = np.zeros((envs, self.n), np.float32)  # the held actions, in [-1, 1]
        self._wait = np.zeros(envs)  # s to each env's next policy tick (<= 0: this call)
        self.new_chunk = np.zeros(envs, dtype=bool)
        self.policy_tick = np.zeros(envs, dtype=bool)
        self.policy_ticks = np.zeros(envs, dtype=np.int64)
        self.calls = np.zeros(envs, dtype=np.int64)
        self.servo_thread_calls = np.zeros(envs, dtype=np.int64)
        self.waits = np.zeros(envs, dtype=np.int64)
        self.wait_max = 0.0
        self.late = np.zeros(envs, dtype=bool)
        self.late_chunks = np.zeros(envs, dtype=np.int64)
        self._drain(range(len(getattr(self, "_pending", ()))))
        self._pending: list[ChunkRequest | None] = [None] * envs

    def bind_batch(self, envs: int) -> None:
        """Arrays for ``envs`` robots (the runtime's camera stage calls it before its first
        write into :attr:`images`); a new batch size starts every env afresh."""
        if envs != self.envs:
            self._bind(envs)

    def reset(self, envs: np.ndarray | None = None) -> None:
        """An episode's start in the envs of ``envs`` (bool mask; None: all): no queued action,
        their next call is a policy tick with a new chunk (module docstring). The counters run
        on."""
        if envs is not None:
            self.bind_batch(len(envs))  # the runtime's batch (its start resets every env)
        mask = np.ones(self.envs, bool) if envs is None else np.asarray(envs, dtype=bool)
        for e in np.flatnonzero(mask):
            self.chunks[e].reset()
        self._wait[mask] = 0.0
        # on the wall clock (the end of RAMP_IN, a resume) a pending request is forgotten, not
        # waited for: the servo tick does not stall; the next request queues behind it. Before
        # the run's clock (the runtime's warm-up call) and in lockstep it is waited for.
        self._drain(np.flatnonzero(mask), wait=not self.wall_clock)
        self.late[mask] = False

    def _drain(self, envs, wait: bool = True) -> None:
        """Forget the pending requests of ``envs`` (``wait``: each waited for first, at most one
        network call's time, so the worker's next request starts at once)."""
        for e in envs:
            request, self._pending[e] = self._pending[e], None
            if request is not None and wait:
                request.wait(None)

    @property
    def pending(self) -> np.ndarray:
        """(envs,) bool: async, a chunk asked and not taken yet in that env."""
        return np.array([r is not None for r in self._pending], dtype=bool)

    def close(self) -> None:
        """End the worker thread (async inference; the run's end, every exit path): the call
        running finishes, the pending requests are forgotten. A later call starts a new one."""
        for e in range(len(self._pending)):
            self._pending[e] = None
        if self._worker is not None:
            self._worker.close()

    # ------------------------------------------------------------------ units
    def to_lerobot(self, q: np.ndarray) -> np.ndarray:
        """(n,) rad -> LeRobot's state (degrees, gripper percent), float32."""
        pct = (q - self.lower) / (self.upper - self.lower) * 100.0
        return np.where(self.units, np.rad2deg(q), pct).astype(np.float32)

    def to_joints(self, action: np.ndarray) -> np.ndarray:
        """LeRobot's action (degrees, gripper percent) -> (n,) rad."""
        a = np.asarray(action, float)
        rad = self.lower + a / 100.0 * (self.upper - self.lower)
        return np.where(self.units, np.deg2rad(a), rad)

    def _read(self, obs_row: np.ndarray) -> dict[str, np.ndarray]:
        """One env's observation (the spec's blocks) back to ``{"joint_position", "goal_position"}``
        in rad and m (``value * scale + offset``)."""
        out, i = {}, 0
        for b in self.spec.observation_blocks:
            v = obs_row[i : i + b.size].astype(np.float64)
            out[b.name] = v * np.asarray(b.scale) + np.asarray(b.offset)
            i += b.size
        return out

    # ------------------------------------------------------------------ the call
    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """(envs, obs_dim) float32 -> (envs, n) float32 actions in [-1, 1], one servo tick:
        a new action where a policy period has passed (the graph called when a chunk is
        needed), else the held one; in a buffer the next call overwrites.

        Raises:
            ValueError: a chunk of another shape than the contract's.
        """
        envs = obs.shape[0]
        self.bind_batch(envs)
        due = self._wait <= 1e-9
        np.copyto(self.policy_tick, due)
        self.new_chunk[:] = False
        for e in np.flatnonzero(due):
            self._policy_tick(e, obs[e])
        self._wait[due] += self.period
        self._wait -= self.dt
        return self._out

    def _feed(self, e: int, values: dict, copy: bool) -> dict:
        """The graph's inputs for env ``e`` (``copy``: images copied, for a call beside the loop
        while the camera stage writes the next frames)."""
        feed = {lr.STATE_KEY: self.to_lerobot(values["joint_position"])[None]}
        if self.contract.env_state_dim:
            feed[lr.ENV_STATE_KEY] = values["goal_position"].astype(np.float32)[None]
        for key, image in self.images.items():
            # (1, 3, H, W): the block's one frame is the batch axis
            feed[key] = image[e].copy() if copy else image[e]
        return feed

    def _run(self, feed: dict) -> np.ndarray:
        return self.session.run(None, feed)[0]

    def _hold(self, e: int, target: np.ndarray) -> None:
        """Env ``e``'s held action: the joint target ``target`` (rad) in the spec's units."""
        action = (target - self._offset) / self._scale
        self._out[e] = np.clip(action, -self._clip, self._clip)

    def _policy_tick(self, e: int, obs_row: np.ndarray) -> None:
        if self._worker is not None:
            self._policy_tick_async(e, obs_row)
            return
        chunks, calls = self.chunks[e], self.chunks[e].calls
        values = self._read(obs_row)

        def predict() -> np.ndarray:
            self.servo_thread_calls[e] += 1
            return self._run(self._feed(e, values, copy=False))

        self._hold(e, self.to_joints(chunks.step(predict)))
        self.policy_ticks[e] += 1
        if chunks.calls != calls:
            self.new_chunk[e] = True
            self.calls[e] += 1

    def _policy_tick_async(self, e: int, obs_row: np.ndarray) -> None:
        """Async inference's policy tick (module docstring): take the chunk asked one policy
        tick ago, play the next queued action (none queued: hold the measured joints, a
        stretch's first tick), and ask for the next chunk when the queue is empty."""
        chunks, values = self.chunks[e], self._read(obs_row)
        self.policy_ticks[e] += 1
        request, self._pending[e] = self._pending[e], None
        if request is not None:
            if not request.done.is_set():
                self.waits[e] += 1
                t0 = time.perf_counter()
                done = request.wait(self.late_limit if self.wall_clock else None)
                self.wait_max = max(self.wait_max, time.perf_counter() - t0)
                if not done:  # the computer cannot keep this policy's rate: hold, stop
                    self.late[e] = True
                    self.late_chunks[e] += 1
            if not self.late[e]:
                chunks.take(request.chunk(), skip=1)  # its first action's time has passed
                self.new_chunk[e] = True
                self.calls[e] += 1
        if self.late[e]:
            return  # the held action stays until the env's reset
        action = chunks.pop()
        if action is not None:
            self._hold(e, self.to_joints(action))
        elif request is None:  # a stretch's first tick: hold where the joints are
            self._hold(e, values["joint_position"])
        if chunks.queued() == 0:
            self._pending[e] = self._worker.submit(self._feed(e, values, copy=True))

    # ------------------------------------------------------------------ state
    def _packed(self) -> dict:
        """Each env's :class:`ActionChunks` state as arrays with a leading env axis: ``queue``
        (envs, n_action_steps, n) and ``queue_len``; ``ens`` (envs, chunk_size, n) and
        ``ens_len`` (-1: no ensemble yet), ``count`` (envs, chunk_size); ``chunk_calls``."""
        c, envs, n = self.contract, self.envs, self.contract.action_dim
        out = {
            "queue": np.zeros((envs, c.n_action_steps, n), np.float32),
            "queue_len": np.zeros(envs, np.int64),
            "ens": np.zeros((envs, c.chunk_size, n), np.float32),
            "ens_len": np.full(envs, -1, np.int64),
            "count": np.zeros((envs, c.chunk_size), np.int64),
            "chunk_calls": np.zeros(envs, np.int64),
        }
        for e, ch in enumerate(self.chunks):
            st = ch.state_dict()
            out["queue_len"][e] = len(st["queue"])
            if st["queue"]:
                out["queue"][e, : len(st["queue"])] = np.stack(st["queue"])
            if st["ens"] is not None:
                k = len(st["ens"])
                out["ens"][e, :k], out["count"][e, :k], out["ens_len"][e] = (
                    st["ens"],
                    st["count"],
                    k,
                )
            out["chunk_calls"][e] = st["calls"]
        return out

    def _fields(self) -> dict:
        fields = {
            "out": self._out,
            "wait": self._wait,
            "policy_ticks": self.policy_ticks,
            "calls": self.calls,
        }
        if self._worker is not None:  # async: the pending requests' chunks, waited for
            c, envs = self.contract, self.envs
            pending = np.zeros(envs, bool)
            chunk = np.zeros((envs, c.chunk_size, c.action_dim), np.float32)
            for e, request in enumerate(self._pending):
                if request is not None:
                    request.wait(None)
                    pending[e] = True
                    chunk[e] = np.asarray(request.chunk(), np.float32).reshape(chunk[e].shape)
            fields |= {"pending": pending, "pending_chunk": chunk, "late": self.late}
        return fields

    def state_dict(self, env: int | None = None) -> dict:
        """Each env's queue or ensemble (:meth:`_packed`), the time to its next policy tick
        (``wait``, s), the held action (``out``) and the counters (copies with a leading env
        axis; ``env``: that env's only). Async inference adds each env's pending request as its
        chunk (``pending`` (envs,) bool, ``pending_chunk`` (envs, chunk_size, n)): a checkpoint
        taken while a request is pending waits for its result (at most one network call), so
        the run loaded from it takes the same chunk at the same tick; and ``late``."""
        return take(self._fields() | self._packed(), env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Restore :meth:`state_dict`'s output (of all envs, or into ``env``).

        Raises:
            StateDictError: a missing field or another shape (nothing written)."""
        if env is None and "wait" in state:  # a batch's state: its size
            self.bind_batch(len(np.asarray(state["wait"])))
        packed = self._packed()
        fields = self._fields() | packed
        put(fields, state, env)  # checks every field before writing
        envs = range(self.envs) if env is None else [env]
        if self._worker is not None:
            for e in envs:
                self._pending[e] = None  # waited for in _fields
                if fields["pending"][e]:
                    self._pending[e] = ChunkRequest.finished(fields["pending_chunk"][e])
        for e in envs:
            k, q = int(packed["ens_len"][e]), int(packed["queue_len"][e])
            self.chunks[e].load_state_dict(
                {
                    "queue": list(packed["queue"][e, :q]),
                    "ens": None if k < 0 else packed["ens"][e, :k],
                    "count": None if k < 0 else packed["count"][e, :k],
                    "calls": int(packed["chunk_calls"][e]),
                }
            )
