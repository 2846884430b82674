"""A ros2_control robot as a :class:`~sim2real.deploy.core.backend.Backend` (one robot, wall clock):
``deploy-run --backend ros2``.

The runtime reads ``joint_states`` (``sensor_msgs/JointState``, as ros2_control's
``joint_state_broadcaster`` publishes it; joints matched by name, in any order) and writes the
forward command controller of its control mode (:mod:`sim2real.deploy.ros2.controllers`:
``forward_position_controller`` / ``forward_velocity_controller`` / ``forward_effort_controller``,
``std_msgs/Float64MultiArray`` in the controller's joint order, checked against the robot folder).
The subscription's callback runs on the node's own thread and keeps the newest state; a
:meth:`Ros2ControlBackend.read` takes it.

Watchdogs, as the other hardware backends have them:

- **stale state**: a read with no new ``joint_states`` since the last is a missing reading (NaN);
  the runtime's estimator predicts through it and stops the robot (``stale_sensor``) past the
  robot's ``Robot.stale_limit``, as for a servo bus's lost packets;
- **missing joints**: ``open()`` refuses a robot whose first state lacks a joint (naming it and
  what the robot publishes); a later state without a joint is a missing reading of that joint;
- **rate**: ``open()`` measures the state rate and warns below the control rate.

``joint_states`` carries no winding temperature: the runtime keeps the ambient (no thermal
derating or over-temperature stop from this backend). ``close()`` leaves a position or effort
controller holding the last command (ros2_control's forward controllers do), and sends zero
velocity to a velocity controller, which would otherwise keep the joints moving.
"""

from __future__ import annotations

import sys
import threading
import time

import numpy as np

from sim2real.deploy.core.backend import BackendLifecycle, SensorFrame, checked_command
from sim2real.deploy.core.latency import LatencyHistogram
from sim2real.deploy.core.stale import arrivals_phrase, context
from sim2real.deploy.kinds import robot_kind
from sim2real.deploy.ros2.context import NodeThread
from sim2real.deploy.ros2.controllers import FORWARD_CONTROLLERS, command_order, command_topic
from sim2real.robots.errors import Sim2RealError

#: s ``open()`` waits for the first ``joint_states``.
STATE_TIMEOUT = 5.0
#: s ``open()`` listens to measure the state rate (our choice: 25 periods at 50 Hz).
RATE_WINDOW = 0.5
#: Depth of the subscription's and the publisher's history (rclpy's default, 10).
QOS_DEPTH = 10


class Ros2BackendError(Sim2RealError, OSError):
    """The ros2_control robot does not come up (no state, joints missing): ``deploy-run``
    exits 3."""


def _stderr(text: str) -> None:
    print(f"ros2: {text}", file=sys.stderr, flush=True)


class Ros2ControlBackend(BackendLifecycle):
    """A ros2_control robot (module docstring).

    Args:
        robot: The robot folder's :class:`~robots.Robot`.
        mode: 'position', 'velocity' or 'torque' (the policy's control mode).
        namespace: The namespace of the robot's topics ('' : the root).
        controller: The forward command controller's name (default ``FORWARD_CONTROLLERS``).
        joints: The controller's joint order (default the robot's); checked against the robot.
        state_timeout: s ``open()`` waits for the first state.
        log: Where ``open()``'s warnings go (default stderr, ``ros2: ...``).

    Attributes:
        envs: 1. frame: the last :class:`SensorFrame`.
        received: ``joint_states`` taken. sent: commands written. reads: reads.
        stale_reads: reads with no new state. missing_joint_readings: joints absent from a state.
        state_rate_hz: the state rate ``open()`` measured.
        read_cost, write_cost: :class:`LatencyHistogram` (ns) of a read and a write.
        state_age: :class:`LatencyHistogram` (ns) of the newest state's age at a read, from its
            header stamp (meaningful when the robot's clock is this computer's).
        loop_times: (2,) s on the frames' clock, for the command log (``sysid``): when the
            state the last read took was sampled (its header stamp moved onto this computer's
            clock by the smallest receive-minus-stamp difference seen so far, so that any
            clock offset between the robot and this computer cancels; NaN when the read took
            no new state or the state had no stamp), and when the last command's publish
            returned (the middleware sends it at the end of the call).

    Raises:
        ValueError: an unknown mode, a floating-base robot, a joint order that does not match
            the robot.
    """

    def __init__(
        self,
        robot,
        mode: str,
        *,
        namespace: str = "",
        controller: str | None = None,
        joints: list[str] | None = None,
        state_timeout: float = STATE_TIMEOUT,
        log=_stderr,
    ):
        if mode not in FORWARD_CONTROLLERS:
            raise ValueError(f"mode '{mode}': expected one of {sorted(FORWARD_CONTROLLERS)}")
        if robot_kind(robot).sensor_frame(robot, 1).foot_contact is not None:
            raise ValueError(
                f"--backend ros2 reads joint_states only: {robot.name} is a floating-base robot "
                "whose IMU and foot contacts it does not read (use --backend unitree, or "
                "deploy-run --ros2 on --backend sim)"
            )
        self.robot, self.mode, self.log = robot, mode, log
        self.envs, self.n = 1, robot.n_joints
        self.names = list(robot.joint_names)
        self.controller = controller or FORWARD_CONTROLLERS[mode]
        self.joints = list(joints) if joints is not None else list(self.names)
        self.order = np.array(command_order(self.names, self.joints, "--controller-joints"))
        self.namespace, self.state_timeout = namespace, state_timeout
        self.frame = SensorFrame.empty(1, self.n)
        self.received = self.sent = self.reads = self.stale_reads = 0
        self.missing_joint_readings = 0
        self.state_rate_hz = 0.0
        self.read_cost, self.write_cost = LatencyHistogram(), LatencyHistogram()
        self.state_age = LatencyHistogram()
        self._index: dict[tuple[str, ...], tuple[np.ndarray, np.ndarray]] = {}
        self._newest = np.full(self.n, np.nan)
        self._newest_at = 0.0
        self._newest_stamp_ns = 0
        self._newest_sampled = np.nan
        self._stamp_offset = np.inf  # s, the smallest receive time minus header stamp
        self.loop_times = np.full(2, np.nan)
        self._seq = self._read_seq = 0
        #: (stale_context) states lacking a robot's joint since the last whole one (the node's
        #: thread), the count of states and when the last whole state a read took arrived
        self._incomplete, self._taken_seq, self._taken_at = 0, 0, -np.inf
        self._lock = threading.Lock()
        self._node: NodeThread | None = None
        self._pub = self._msg = None
        self._t0 = time.monotonic()
        self._opened_at: float | None = None

    # ------------------------------------------------------------------ lifecycle
    def open(self) -> None:
        """Join ROS 2, wait for the first state, check its joints, measure its rate.

        Raises:
            Ros2BackendError: no ``joint_states`` within ``state_timeout`` s, or a joint of the
                robot missing from it.
        """
        if self._node is not None:
            return
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray

        self._node = NodeThread("deploy_ros2_backend", self.namespace)
        node = self._node.node
        node.create_subscription(JointState, "joint_states", self._on_state, QOS_DEPTH)
        topic = command_topic(self.controller)
        self._pub = node.create_publisher(Float64MultiArray, topic, QOS_DEPTH)
        self._msg = Float64MultiArray()
        self._node.start()
        self._opened_at = time.monotonic()
        try:
            self._come_up()
        except BaseException:
            self.close()
            raise

    def _come_up(self) -> None:
        end = time.monotonic() + self.state_timeout
        while self._seq == 0 and time.monotonic() < end:
            time.sleep(0.01)
        if self._seq == 0:
            raise Ros2BackendError(
                f"no joint_states on '{self._node.node.resolve_topic_name('joint_states')}' "
                f"within {self.state_timeout} s (is the controller manager's "
                "joint_state_broadcaster running, on this ROS_DOMAIN_ID?)"
            )
        with self._lock:
            missing = [j for j, q in zip(self.names, self._newest, strict=True) if np.isnan(q)]
            published = sorted({n for names in self._index for n in names})
        if missing:
            raise Ros2BackendError(
                f"joint_states lacks the robot's joints {missing}; it publishes {published}"
            )
        first = self._seq
        time.sleep(RATE_WINDOW)
        self.state_rate_hz = (self._seq - first) / RATE_WINDOW
        rate = 1.0 / self.robot.control_period
        if self.state_rate_hz < 0.9 * rate:
            self.log(
                f"joint_states at {self.state_rate_hz:.0f} Hz, below the control rate "
                f"{rate:.0f} Hz: ticks without a new state are missing readings"
            )

    def close(self) -> None:
        """A velocity controller gets zeros; then leave ROS 2 (idempotent)."""
        if self._node is None:
            return
        try:
            if self.mode == "velocity" and self.sent:
                self._publish(np.zeros(self.n))
                time.sleep(0.05)  # the zeros leave before the node goes
        finally:
            self._node.close()
            self._node = None

    def enable(self) -> None:
        """Nothing: a forward command controller has no torque switch (the controller manager
        activates and deactivates it)."""

    def disable(self) -> None:
        """Nothing (see :meth:`enable`)."""

    # ------------------------------------------------------------------ the node's thread
    def _on_state(self, msg) -> None:
        names = tuple(msg.name)
        index = self._index.get(names)
        if index is None:
            pairs = [(i, self.names.index(n)) for i, n in enumerate(names) if n in self.names]
            src = np.array([p[0] for p in pairs], dtype=np.int64)
            dst = np.array([p[1] for p in pairs], dtype=np.int64)
            index = self._index[names] = (src, dst)
        src, dst = index
        position = np.asarray(msg.position, dtype=np.float64)
        stamp = msg.header.stamp
        whole = len(position) == len(names) and len(dst) == self.n  # every joint of the robot
        with self._lock:
            self._newest.fill(np.nan)
            if len(position) == len(names):
                self._newest[dst] = position[src]
            self._incomplete = 0 if whole else self._incomplete + 1
            self._newest_at = time.monotonic() - self._t0
            self._newest_stamp_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
            self._newest_sampled = np.nan
            if self._newest_stamp_ns > 0:
                sampled = self._newest_stamp_ns * 1e-9
                self._stamp_offset = min(self._stamp_offset, self._newest_at - sampled)
                self._newest_sampled = sampled + self._stamp_offset
            self._seq += 1
            self.received += 1

    # ------------------------------------------------------------------ the three calls
    def read(self) -> SensorFrame:
        """The newest state since the last read (NaN where none arrived or a joint was
        missing); the frame is overwritten by the next read."""
        t0 = time.perf_counter_ns()
        f = self.frame
        f.time[0] = time.monotonic() - self._t0
        with self._lock:
            fresh = self._seq != self._read_seq
            self._read_seq = self._seq
            if fresh:
                f.position[0] = self._newest
                f.position_stamp[0] = self._newest_at
                stamp_ns = self._newest_stamp_ns
                self.loop_times[0] = self._newest_sampled
        if fresh:
            missing = np.isnan(f.position[0])
            if missing.any():
                f.position_stamp[0, missing] = np.nan
                self.missing_joint_readings += int(missing.sum())
            else:  # a whole state taken (stale_context's window starts again)
                self._taken_seq, self._taken_at = self._read_seq, f.position_stamp[0, 0]
            if stamp_ns > 0:
                self.state_age.add(0, max(0, time.time_ns() - stamp_ns))
        else:
            f.position[0] = f.position_stamp[0] = self.loop_times[0] = np.nan
            self.stale_reads += 1
        self.reads += 1
        self.read_cost.add(0, time.perf_counter_ns() - t0)
        return f

    def write(self, command: np.ndarray) -> None:
        """One command, ``command`` (1, n_joints) in the robot's joint order, published in the
        controller's.

        Raises:
            ValueError: wrong shape or a non-finite value (nothing is written).
        """
        command = checked_command(command, self.n)
        t0 = time.perf_counter_ns()
        self._publish(command[0])
        self.loop_times[1] = time.monotonic() - self._t0  # sent: DDS writes at publish's end
        self.write_cost.add(0, time.perf_counter_ns() - t0)

    def _publish(self, command: np.ndarray) -> None:
        self._msg.data = command[self.order]
        self._pub.publish(self._msg)
        self.sent += 1

    def advance(self) -> None:
        """Nothing: the robot runs on its own; the runtime's wall clock paces the loop."""

    # ------------------------------------------------------------------ reports
    def drive_errors(self) -> None:
        """None: ``joint_states`` reports no drive errors."""
        return None

    def describe_drive_error(self, joint: int, bits: int) -> str:
        return f"joint {self.names[joint]}: error {bits:#x}"

    def stale_context(self, env: int = 0) -> dict:
        """What the ``joint_states`` subscription saw since the last whole state a read took
        (:mod:`sim2real.deploy.core.stale`; ``env`` is 0): states arrived since, those lacking
        a robot's joint (``refused``, ``without_joints``), the newest one's age by its header
        stamp, s since that whole state arrived, the joints absent from the newest state;
        ``other_side``: ``publisher silent`` when nothing arrived."""
        now_ns, now = time.time_ns(), time.monotonic() - self._t0
        with self._lock:
            arrived, incomplete = self._seq - self._taken_seq, self._incomplete
            stamp_ns, absent = self._newest_stamp_ns, np.isnan(self._newest)
        refused = {"without_joints": min(incomplete, arrived)}
        other = arrivals_phrase(arrived, refused, "publisher silent")
        if arrived and not incomplete:  # whole states that came after this tick's read
            other = f"{arrived} state{'s' if arrived > 1 else ''} arrived after the read"
        topic = self._node.node.resolve_topic_name("joint_states") if self._node else "joint_states"
        return context(
            "ros2",
            "joint_states",
            f"{topic} (sensor_msgs/JointState) over ROS 2",
            arrived=arrived,
            refused=refused,
            newest_sample_age_s=(now_ns - stamp_ns) / 1e9 if stamp_ns > 0 else None,
            last_accepted_s=now - self._taken_at,
            joints={
                n: "absent from the newest state"
                for n, a in zip(self.names, absent, strict=True)
                if a
            },
            other_side=other,
            stale_reads=self.stale_reads,
        )

    def bus_summary(self) -> dict:
        """Figures for the run's report: topics, states taken and their rate, stale reads,
        missing joint readings, commands sent, the cost of a read and a write and the newest
        state's age at a read (us percentiles)."""
        elapsed = time.monotonic() - (self._opened_at or self._t0)
        return {
            "transport": "ros2",
            "controller": self.controller,
            "command_topic": command_topic(self.controller),
            "joint_states_received": self.received,
            "joint_states_rate_hz": self.received / elapsed if elapsed > 0 else 0.0,
            "reads": self.reads,
            "stale_reads": self.stale_reads,
            "missing_joint_readings": self.missing_joint_readings,
            "commands_sent": self.sent,
            "read_us": self.read_cost.summary(),
            "write_us": self.write_cost.summary(),
            "state_age_us": self.state_age.summary(),
        }
