"""Per-stage latency histograms and downsampled MCAP telemetry.

MCAP is the robotics log format Foxglove opens. The recorder keeps a preallocated ring buffer,
samples every ``every``-th tick into it, and flushes it to the MCAP file when full and on close, so
a long run keeps its whole (downsampled) history with nothing allocated per tick in between. One
topic per stage of the tick, JSON messages (schemas are JSON Schema):

``/read`` encoder positions (rad) and their stamps (s); ``/estimate`` q (rad), dq (rad/s) and,
for a floating base, the estimated base orientation (``base_orientation``, ``[w, x, y, z]``),
``projected_gravity``, ``linear_velocity`` (m/s) and ``angular_velocity`` (rad/s, base frame);
``/truth`` (a floating base in simulation) the same four of the simulator's base and its height
(``height``, m), for plotting the estimate against it;
``/infer`` the policy action; ``/guard`` the guarded target; ``/smooth`` the command sent;
``/thermal`` reported winding temperatures (degC); ``/state`` the state machine of every env;
``/long_ticks`` (one message at the end, :meth:`Telemetry.close`) the run's longest control periods
and their parts (:meth:`sim2real.deploy.observe.long_ticks.LongTicks.rows`), stamped at their ticks' times.

Given the robot (``robot=``) and with the ``foxglove`` extra installed, the file also carries
Foxglove's well-known schemas (:mod:`sim2real.deploy.observe.foxglove`): ``/tf`` link poses
(``foxglove.FrameTransforms``), ``/robot`` the robot's geometry (``foxglove.SceneUpdate``),
``/joint_states`` and ``/joint_commands`` (``foxglove.JointStates``) and ``/guard_events``
(``foxglove.Log``), so that Foxglove draws the robot moving in 3D. They are built from the ring
buffer when it is flushed (link poses by forward kinematics of the logged estimated joint
positions and, for a floating base, the estimated base orientation with the base at the origin),
not in the tick: sampling a tick costs the same few array copies with or without them.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

_TOPICS = (
    "/read",
    "/estimate",
    "/infer",
    "/guard",
    "/smooth",
    "/thermal",
    "/state",
    "/long_ticks",
    "/truth",
)
#: The base fields of ``/estimate`` and ``/truth``: name, width.
_BASE_FIELDS = (
    ("base_orientation", 4),
    ("projected_gravity", 3),
    ("linear_velocity", 3),
    ("angular_velocity", 3),
)


class Telemetry:
    """Downsampled telemetry of a :class:`~sim2real.deploy.runtime.Runtime`, written as MCAP.

    Args:
        path: Output ``.mcap`` file; written to ``path + '.part'`` and renamed on close, so a file
            under the final name is always complete.
        envs, n_joints: Shapes of the runtime.
        every: Keep one tick in ``every``.
        capacity: Rows of the ring buffer before a flush.
        robot: Optional :class:`~robots.Robot`: adds the Foxglove topics (module docstring).
        control_mode: With ``robot``: ``position``, ``velocity`` or ``torque`` (the field of
            ``/joint_commands``); default the robot's.
        tf_every: With ``robot``: one ``/tf`` message per ``tf_every`` sampled rows (so one per
            ``every * tf_every`` ticks).

    Raises:
        ImportError: ``robot`` given without ``foxglove-schemas-protobuf`` installed.
    """

    def __init__(
        self,
        path: str | Path,
        envs: int,
        n_joints: int,
        every: int = 10,
        capacity: int = 4096,
        robot=None,
        control_mode: str | None = None,
        tf_every: int = 1,
    ):
        from mcap.writer import Writer

        self.path = Path(path)
        self.every, self.capacity = every, capacity
        self._tmp = self.path.with_name(self.path.name + ".part")
        self._file = open(self._tmp, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._file)
        self._writer.start(profile="", library="sim2real-deploy")
        self._channels = {}
        for topic in _TOPICS:
            self._json_channel(topic)
        self.foxglove = None
        if robot is not None:
            self._register_foxglove(robot, envs, control_mode or robot.control_mode)
        self.tf_every = max(1, int(tf_every))
        self._sampled = 0  # rows sampled so far (for tf_every)
        shape = (capacity, envs, n_joints)
        self._t = np.zeros(capacity)
        self._pos = np.zeros(shape)
        self._stamp = np.zeros(shape)
        self._q = np.zeros(shape)
        self._dq = np.zeros(shape)
        self._action = np.zeros(shape, dtype=np.float32)
        self._target = np.zeros(shape)
        self._cmd = np.zeros(shape)
        self._temp = np.zeros(shape)
        # a floating base's estimate and (simulation) truth: the _BASE_FIELDS, and the height
        self._base = {k: np.zeros((capacity, envs, w)) for k, w in _BASE_FIELDS}
        self._base_orientation = self._base["base_orientation"]  # [w, x, y, z]
        self._base_orientation[..., 0] = 1.0
        self._true = {k: np.zeros((capacity, envs, w)) for k, w in _BASE_FIELDS}
        self._true_height = np.zeros((capacity, envs))
        self._true_base = None  # a BaseState filled from the plant's truth (simulation)
        self._legged = False  # a floating base's estimate seen: /estimate has its base
        self._truth = False  # ... and the simulator's base: /truth
        self._mode = np.zeros((capacity, envs), dtype=np.int8)
        self._cause = np.zeros((capacity, envs), dtype=np.int8)
        self._guard_counts = None  # (capacity, checks, envs) once the first row shows the guard
        self._last_mode = np.zeros(envs, dtype=np.int8)  # IDLE
        self._last_counts = None
        self._rows = 0
        self.messages = 0

    def _register_foxglove(self, robot, envs: int, control_mode: str) -> None:
        from sim2real.deploy.observe import foxglove as fx

        self.foxglove = enc = fx.FoxgloveEncoder(robot, envs, control_mode)
        schemas = {
            name: self._writer.register_schema(
                name=name, encoding="protobuf", data=fx.file_descriptor_set(enc.classes[name])
            )
            for name in enc.classes
        }
        for topic, schema_name in (
            ("/tf", fx.FRAME_TRANSFORMS),
            ("/robot", fx.SCENE_UPDATE),
            ("/joint_states", fx.JOINT_STATES),
            ("/joint_commands", fx.JOINT_STATES),
            ("/guard_events", fx.LOG),
        ):
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="protobuf", schema_id=schemas[schema_name]
            )
        self._scene_written = False

    def record(self, rt) -> None:
        """Sample the runtime's latest tick (every ``every``-th call)."""
        if rt.ticks % self.every:
            return
        i = self._rows
        frame = rt.backend.frame
        self._t[i] = rt.time
        self._pos[i] = frame.position
        self._stamp[i] = frame.position_stamp
        self._q[i] = rt.state.q
        self._dq[i] = rt.state.dq
        self._action[i] = rt.action
        self._target[i] = rt.target
        self._cmd[i] = rt.command
        self._temp[i] = rt.state.winding_temperature
        self._mode[i] = rt.mode
        if rt.state.base is not None:
            self._legged = True
            self._sample_base(i, rt)
        if self.foxglove is not None:
            self._cause[i] = rt.cause
            counts = rt.guard.count_matrix
            if self._guard_counts is None:
                self._guard_counts = np.zeros((self.capacity, *counts.shape), dtype=np.int64)
                self._guard_checks = tuple(rt.guard.counts)
                self._last_counts = np.zeros(counts.shape, dtype=np.int64)
            self._guard_counts[i] = counts
        self._rows += 1
        if self._rows == self.capacity:
            self.flush()

    def _sample_base(self, i: int, rt) -> None:
        """Row ``i``'s floating base: the estimate and, in simulation, the truth."""
        base = rt.state.base
        self._base["base_orientation"][i] = base.orientation
        self._base["projected_gravity"][i] = base.projected_gravity
        self._base["linear_velocity"][i] = base.linear_velocity
        self._base["angular_velocity"][i] = base.angular_velocity
        truth = getattr(rt.backend, "true_base_state", None)
        if truth is None:
            return
        from sim2real.deploy.core.state import BaseState

        if self._true_base is None:
            self._true_base = BaseState.zeros(rt.envs)
        state = truth()
        t = self._true_base.set_truth(state)
        self._truth = True
        self._true["base_orientation"][i] = t.orientation
        self._true["projected_gravity"][i] = t.projected_gravity
        self._true["linear_velocity"][i] = t.linear_velocity
        self._true["angular_velocity"][i] = t.angular_velocity
        self._true_height[i] = state[:, 2]

    def flush(self) -> None:
        """Write the buffered rows to the MCAP file."""

        def clean(a):
            return np.where(np.isfinite(a), a, None).tolist()

        for i in range(self._rows):
            t_ns = int(round(self._t[i] * 1e9))
            estimate = {"q": self._q[i].tolist(), "dq": self._dq[i].tolist()}
            if self._legged:
                estimate.update({k: self._base[k][i].tolist() for k, _ in _BASE_FIELDS})
            msgs = {
                "/read": {"position": clean(self._pos[i]), "stamp": clean(self._stamp[i])},
                "/estimate": estimate,
                "/infer": {"action": clean(self._action[i])},
                "/guard": {"target": self._target[i].tolist()},
                "/smooth": {"command": self._cmd[i].tolist()},
                "/thermal": {"winding_temperature": self._temp[i].tolist()},
                "/state": {"mode": self._mode[i].tolist()},
            }
            if self._truth:
                msgs["/truth"] = {k: self._true[k][i].tolist() for k, _ in _BASE_FIELDS}
                msgs["/truth"]["height"] = self._true_height[i].tolist()
            for topic, msg in msgs.items():
                self._write(topic, t_ns, json.dumps(msg).encode())
            if self.foxglove is not None:
                self._flush_foxglove(i, t_ns)
        self._rows = 0

    def _flush_foxglove(self, i: int, t_ns: int) -> None:
        """The Foxglove messages of buffered row ``i`` (module docstring)."""
        from sim2real.deploy.core.modes import FAULT_CAUSES, Mode

        enc = self.foxglove
        msgs = []
        if not self._scene_written:
            msgs.append(("/robot", enc.scene(t_ns)))
            self._scene_written = True
        if self._sampled % self.tf_every == 0:
            msgs.append(("/tf", enc.frame_transforms(t_ns, self._q[i], self._base_orientation[i])))
        self._sampled += 1
        msgs.append(("/joint_states", enc.joint_states(t_ns, self._q[i], self._dq[i])))
        msgs.append(("/joint_commands", enc.joint_commands(t_ns, self._cmd[i])))
        mode = self._mode[i]
        for e in np.flatnonzero(mode != self._last_mode):
            new = Mode(int(mode[e])).name
            cause = int(self._cause[i, e])
            text = f"env {e}: {Mode(int(self._last_mode[e])).name} -> {new}"
            if cause >= 0 and new in ("SAFE_STOP", "FAULTED"):
                text += f" ({FAULT_CAUSES[cause]})"
            level = "ERROR" if new in ("SAFE_STOP", "FAULTED") else "INFO"
            msgs.append(("/guard_events", enc.log(t_ns, level, text)))
        self._last_mode[:] = mode
        if self._guard_counts is not None:
            rose = np.maximum(self._guard_counts[i] - self._last_counts, 0)  # (checks, envs)
            for e in np.flatnonzero(rose.any(axis=0)):
                checks = ", ".join(
                    f"{name} {int(rose[c, e])}"
                    for c, name in enumerate(self._guard_checks)
                    if rose[c, e]
                )
                text = f"env {e}: guard intervened ({checks} ticks since the last sample)"
                msgs.append(("/guard_events", enc.log(t_ns, "WARNING", text)))
            self._last_counts[:] = self._guard_counts[i]
        for topic, data in msgs:
            self._write(topic, t_ns, data)

    def _json_channel(self, topic: str) -> None:
        """Register ``topic``'s channel: JSON messages, any object."""
        schema = self._writer.register_schema(
            name=topic.strip("/"), encoding="jsonschema", data=b'{"type": "object"}'
        )
        self._channels[topic] = self._writer.register_channel(
            topic=topic, message_encoding="json", schema_id=schema
        )

    def _write(self, topic: str, t_ns: int, data: bytes) -> None:
        """One message ``data`` on ``topic``'s channel, logged and published at ``t_ns`` ns."""
        self._writer.add_message(
            channel_id=self._channels[topic], log_time=t_ns, publish_time=t_ns, data=data
        )
        self.messages += 1

    def event(self, topic: str, t: float, data: dict) -> None:
        """One JSON message ``data`` on ``topic`` (its channel registered at the first message)
        stamped at the run's time ``t`` s: an event that is not a tick's sample (the operator's
        transitions on ``/operator``)."""
        if topic not in self._channels:
            self._json_channel(topic)
        self._write(topic, int(round(t * 1e9)), json.dumps(data).encode())

    def close(self, long_ticks: list[dict] | None = None, period: float | None = None) -> Path:
        """Flush, finish the MCAP file and move it to its final name; returns the path.

        Args:
            long_ticks: Optional rows of :meth:`sim2real.deploy.observe.long_ticks.LongTicks.rows`: one
                ``/long_ticks`` message per row, stamped at its tick's time (``tick * period``).
            period: The control period, s (with ``long_ticks``).
        """
        self.flush()
        for row in long_ticks or ():
            t_ns = int(round(row["tick"] * (period or 0.0) * 1e9))
            self._write("/long_ticks", t_ns, json.dumps(row).encode())
        self._writer.finish()
        self._file.close()
        os.replace(self._tmp, self.path)
        return self.path

    def discard(self) -> None:
        """Close the file unfinished and remove it, so that a run that ended in an error leaves
        no partial ``.part`` behind; after :meth:`close`, nothing is touched."""
        if not self._file.closed:
            self._file.close()
            self._tmp.unlink(missing_ok=True)
