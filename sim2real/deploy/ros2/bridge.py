"""``deploy-run --ros2``: the runtime as a ROS 2 node.

:class:`RuntimeNode` is an rclpy node (:class:`~sim2real.deploy.ros2.context.NodeThread`, its own
thread) beside one robot's :class:`~sim2real.deploy.runtime.Runtime`. Topic names are relative to
``--ros2-namespace`` (``/diagnostics`` excepted, where ``diagnostic_aggregator`` listens); the
README's "ROS 2" section has the table of types and rates:

- out, every control tick: ``joint_states`` (``sensor_msgs/JointState``, the estimate), for a
  legged robot ``imu`` (``sensor_msgs/Imu``) and ``odom`` (``nav_msgs/Odometry``, the base
  estimate); ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``: ``<node>: runtime``,
  ``motors``, ``timing``) every ``DIAGNOSTICS_PERIOD`` and at once when the state changes;
- in: ``cmd_vel`` (``geometry_msgs/Twist``, legged) or ``goal_point``
  (``geometry_msgs/PointStamped``, arm, m in the base frame);
- services (``std_srvs/Trigger``): ``~/stop`` (an operator's safe stop, cause ``operator``),
  ``~/resume`` (end it), ``~/reset_faults`` (clear a latched fault).

The tick never waits for the node. After every tick the control thread (:meth:`RuntimeNode.
after_tick`, the runtime's ``on_tick``) applies what arrived (the newest ``cmd_vel``, a goal,
service requests), copies the tick into a :class:`~sim2real.deploy.ros2.snapshot.TripleBuffer` and
triggers a guard condition; the node's thread wakes and publishes. The callbacks only store what
arrived under a lock held for a copy; a service call waits on its own thread (up to
``SERVICE_TIMEOUT``) for the control thread to answer it.

A ``cmd_vel`` older than ``CMD_VEL_TIMEOUT`` sets the command to zero (the robot stands), as
``twist_mux`` and the robots' own teleoperation nodes time out a silent operator.
"""

from __future__ import annotations

import queue
import threading
import time

import numpy as np

from sim2real.deploy.core.latency import LatencyHistogram
from sim2real.deploy.ros2.context import NodeThread
from sim2real.deploy.ros2.messages import (
    ERROR,
    OK,
    WARN,
    Status,
    diagnostic_array,
    fill_imu,
    fill_joint_state,
    fill_odometry,
)
from sim2real.deploy.ros2.snapshot import TripleBuffer

#: The node's default name.
NODE_NAME = "deploy_runtime"
#: s between two ``/diagnostics`` messages (``diagnostic_updater``'s default period: 1 s).
DIAGNOSTICS_PERIOD = 1.0
#: s after the last ``cmd_vel`` at which the command goes to zero (``twist_mux``'s usual
#: timeout, 0.5 s).
CMD_VEL_TIMEOUT = 0.5
#: s a service call waits for the control thread's answer (our choice: many ticks).
SERVICE_TIMEOUT = 2.0
#: Depth of the publishers' and subscriptions' history (rclpy's ``qos_profile_default``: 10).
QOS_DEPTH = 10


class _Request:
    """A service call waiting for the control thread's answer."""

    def __init__(self, kind: str):
        self.kind, self.done = kind, threading.Event()
        self.success, self.message = False, "the control loop did not answer"


class RuntimeNode:
    """The runtime's ROS 2 node (module docstring) for one robot (``envs`` 1).

    Args:
        runtime: The :class:`~sim2real.deploy.runtime.Runtime` (started or not).
        namespace: The node's namespace ('' : the root).
        name: The node's name.
        task: Optional task of the run (:func:`sim2real.deploy.tasks.task.task_for`); an arm's
            ``goal_point`` goes to its ``set_goal``.
        interventions: Optional :class:`~sim2real.deploy.monitors.interventions.InterventionMonitor`
            (``/diagnostics`` reports its counts).

    Attributes:
        buffer: The :class:`TripleBuffer` (its ``skipped``: ticks the node did not publish).
        published: Messages published by topic. received: Messages received by topic.
        cmd_vel_timeouts: Times the command went to zero for want of a ``cmd_vel``.
        services: Service calls answered, by name.
        after_tick_cost: :class:`~sim2real.deploy.core.latency.LatencyHistogram` of
            :meth:`after_tick`'s duration on the control thread (ns), the node's whole cost to
            the loop outside the tick.

    Raises:
        ValueError: a runtime of more than one env.
        sim2real.deploy.ros2.context.Ros2UnavailableError: rclpy is not installed.
    """

    def __init__(
        self,
        runtime,
        *,
        namespace: str = "",
        name: str = NODE_NAME,
        task=None,
        interventions=None,
    ):
        if runtime.envs != 1:
            raise ValueError(f"--ros2 publishes one robot: --envs must be 1, got {runtime.envs}")
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
        from geometry_msgs.msg import PointStamped, Twist
        from nav_msgs.msg import Odometry
        from sensor_msgs.msg import Imu, JointState
        from std_srvs.srv import Trigger

        self._diag_types = (DiagnosticArray, DiagnosticStatus, KeyValue)
        self.robot, self.task, self.interventions = runtime.robot, task, interventions
        self.base = runtime.base_estimator is not None  # an IMU and odometry to publish
        self.torque = runtime.mode_name == "torque"
        self.dt = runtime.dt
        self.thread = NodeThread(name, namespace)
        node = self.thread.node
        self.name = node.get_fully_qualified_name()
        self.buffer = TripleBuffer(runtime.n, self.base)
        self.published = {"joint_states": 0, "imu": 0, "odom": 0, "diagnostics": 0}
        self.received = {"cmd_vel": 0, "goal_point": 0}
        self.services = {"stop": 0, "resume": 0, "reset_faults": 0}
        #: who may resume and reset (an operator's authority table, deploy-run --operator):
        #: ``authorize(kind)`` -> None (allowed) or why not, called on the control thread for
        #: ``resume`` and ``reset_faults`` (``stop`` is open to all); None: every caller may
        self.authorize = None
        self.refused = 0
        self.cmd_vel_timeouts = 0
        self._joint_state = JointState()
        self._joint_state.name = list(runtime.robot.joint_names)
        self._pub_joints = node.create_publisher(JointState, "joint_states", QOS_DEPTH)
        self._pub_imu = self._pub_odom = None
        if self.base:
            self._imu, self._odom = Imu(), Odometry()
            base = runtime.robot.config.base
            self._imu.header.frame_id = base.imu_site
            self._odom.header.frame_id, self._odom.child_frame_id = "odom", base.body
            self._pub_imu = node.create_publisher(Imu, "imu", QOS_DEPTH)
            self._pub_odom = node.create_publisher(Odometry, "odom", QOS_DEPTH)
            node.create_subscription(Twist, "cmd_vel", self._on_cmd_vel, QOS_DEPTH)
        else:
            node.create_subscription(PointStamped, "goal_point", self._on_goal, QOS_DEPTH)
        self._pub_diag = node.create_publisher(DiagnosticArray, "/diagnostics", QOS_DEPTH)
        for kind in self.services:
            node.create_service(Trigger, f"~/{kind}", self._service(kind))
        self._wake = node.create_guard_condition(self._publish_tick)
        self._wake_diag = node.create_guard_condition(self._publish_diagnostics)
        self._lock = threading.Lock()
        self._cmd_in, self._cmd_new, self._cmd_at = np.zeros(3), False, -np.inf
        self._cmd_active = False
        self._goal_in: np.ndarray | None = None
        self._requests: queue.SimpleQueue[_Request] = queue.SimpleQueue()
        self._statuses: list[Status] = []
        self._diag_every = max(1, int(round(DIAGNOSTICS_PERIOD / self.dt)))
        self._last_state = (-1, -2)
        self._position = np.zeros(3)
        self.after_tick_cost = LatencyHistogram()
        self.thread.start()

    # ------------------------------------------------------------------ the control thread
    def after_tick(self, rt) -> None:
        """After each tick, on the control thread: apply what arrived, hand the tick to the
        node. Costs a few array copies; never waits for the node. Its own duration goes to
        :attr:`after_tick_cost`."""
        t0 = time.perf_counter_ns()
        self._apply_inputs(rt)
        s = self.buffer.back
        s.tick, s.time, s.wall_ns = rt.ticks, rt.time, time.time_ns()
        s.mode, s.cause = int(rt.mode[0]), int(rt.cause[0])
        st = rt.state
        s.q[:], s.dq[:], s.command[:] = st.q[0], st.dq[0], rt.command[0]
        if self.base:
            b = st.base
            s.orientation[:] = b.orientation[0]
            s.angular_velocity[:] = b.angular_velocity[0]
            s.linear_velocity[:] = b.linear_velocity[0]
            s.acceleration[:] = rt.backend.frame.imu_acceleration[0]
            self._position += b.linear_velocity_world[0] * self.dt
            s.position[:] = self._position
        self.buffer.publish()
        self._wake.trigger()
        state = (s.mode, s.cause)
        if state != self._last_state or rt.ticks % self._diag_every == 0:
            self._last_state = state
            self._statuses = self._diagnose(rt)
            self._wake_diag.trigger()
        self.after_tick_cost.add(0, time.perf_counter_ns() - t0)

    def _apply_inputs(self, rt) -> None:
        if self._cmd_new:
            with self._lock:
                rt.velocity_command[0] = self._cmd_in
                self._cmd_new = False
            self._cmd_active = True
        if self._cmd_active and time.monotonic() - self._cmd_at > CMD_VEL_TIMEOUT:
            rt.velocity_command[0] = 0.0
            self._cmd_active = False
            self.cmd_vel_timeouts += 1
        if self._goal_in is not None:
            with self._lock:
                goal, self._goal_in = self._goal_in, None
            if self.task is not None and hasattr(self.task, "set_goal"):
                self.task.set_goal(rt, goal)
            else:
                rt.goal[0] = goal
        while True:
            try:
                request = self._requests.get_nowait()
            except queue.Empty:
                break
            request.success, request.message = self._serve(rt, request.kind)
            request.done.set()

    def _serve(self, rt, kind: str) -> tuple[bool, str]:
        """An operator's request: ``stop``, ``resume`` or ``reset_faults``; (success, message)."""
        from sim2real.deploy.core.modes import FAULT_CAUSES, FAULTED, SAFE_STOP, Mode

        mode, cause = int(rt.mode[0]), int(rt.cause[0])
        cause_name = FAULT_CAUSES[cause] if cause >= 0 else None
        if kind == "stop":
            if mode in (SAFE_STOP, FAULTED):
                return True, f"already stopped ({Mode(mode).name}, cause {cause_name})"
            rt.supervision.safe_stop(np.ones(1, dtype=bool), "operator")
            return True, "safe stop begun (cause operator)"
        if self.authorize is not None:
            why = self.authorize(kind)
            if why is not None:
                self.refused += 1
                return False, f"refused: {why}"
        if mode == SAFE_STOP:
            return False, f"still stopping (cause {cause_name}): call again once at rest"
        if mode != FAULTED:
            return True, f"nothing to {kind} ({Mode(mode).name})"
        if kind == "resume" and cause_name != "operator":
            return False, (
                f"latched fault '{cause_name}', not an operator's stop: call reset_faults to "
                "acknowledge it"
            )
        rt.reset_faults()
        return True, f"{cause_name} cleared: RAMP_IN"

    def _diagnose(self, rt) -> list[Status]:
        """The ``/diagnostics`` statuses of the runtime now (the control thread's values)."""
        from sim2real.deploy.core.modes import FAULT_CAUSES, FAULTED, SAFE_STOP, Mode

        mode, cause = int(rt.mode[0]), int(rt.cause[0])
        cause_name = FAULT_CAUSES[cause] if cause >= 0 else "none"
        level = ERROR if mode == FAULTED else WARN if mode == SAFE_STOP else OK
        text = Mode(mode).name + (f" ({cause_name})" if cause >= 0 else "")
        values = {"mode": Mode(mode).name, "cause": cause_name, "time_s": float(rt.time)}
        values["safe_stops"] = int(rt.counters.safe_stops[0])
        values["non_finite_actions"] = int(rt.counters.non_finite_actions[0])
        for c, counts in rt.counters.faults.items():
            values[f"faults/{c}"] = int(counts[0])
        if self.interventions is not None:
            values["interventions"] = int(self.interventions.any[0])
            values["intervention_fraction"] = self.interventions.any[0] / max(rt.ticks, 1)
        names = self.robot.joint_names
        temp, scale = rt.state.winding_temperature[0], rt.guard.effort_scale[0]
        motors = {f"{j}/winding_temperature_c": float(t) for j, t in zip(names, temp, strict=True)}
        motors.update({f"{j}/effort_scale": float(s) for j, s in zip(names, scale, strict=True)})
        derated = [j for j, s in zip(names, scale, strict=True) if s < 1.0]
        hottest = int(np.argmax(temp))
        motor_text = f"hottest {names[hottest]} {temp[hottest]:.1f} degC" + (
            f"; derated: {', '.join(derated)}" if derated else ""
        )
        cost, clock = rt.tick_cost, rt.clock
        timing = {
            "tick_p50_us": cost.percentile(0, 50),
            "tick_p99_us": cost.percentile(0, 99),
            "tick_max_us": float(cost.max_ns[0] / 1e3),
            "overruns": int(getattr(clock, "overruns", 0)),
            "missed_periods": int(getattr(clock, "missed_periods", 0)),
            "control_rate_hz": 1.0 / self.dt,
            "ros2_ticks_skipped": self.buffer.skipped,
        }
        over = timing["overruns"] > 0
        return [
            Status(level, f"{self.name}: runtime", text, values),
            Status(WARN if derated else OK, f"{self.name}: motors", motor_text, motors),
            Status(
                WARN if over else OK,
                f"{self.name}: timing",
                f"tick p50 {timing['tick_p50_us']:.0f} us, {timing['overruns']} overruns",
                timing,
            ),
        ]

    # ------------------------------------------------------------------ the node's thread
    def _stamp(self, wall_ns: int):
        from builtin_interfaces.msg import Time

        return Time(sec=wall_ns // 1_000_000_000, nanosec=wall_ns % 1_000_000_000)

    def _publish_tick(self) -> None:
        if not self.buffer.take():
            return
        s = self.buffer.front
        stamp = self._stamp(s.wall_ns)
        fill_joint_state(self._joint_state, s, stamp, self.torque)
        self._pub_joints.publish(self._joint_state)
        self.published["joint_states"] += 1
        if self.base:
            fill_imu(self._imu, s, stamp)
            self._pub_imu.publish(self._imu)
            fill_odometry(self._odom, s, stamp)
            self._pub_odom.publish(self._odom)
            self.published["imu"] += 1
            self.published["odom"] += 1

    def _publish_diagnostics(self) -> None:
        statuses = self._statuses
        if not statuses:
            return
        msg = diagnostic_array(
            *self._diag_types, statuses, self._stamp(time.time_ns()), self.robot.name
        )
        self._pub_diag.publish(msg)
        self.published["diagnostics"] += 1

    def _on_cmd_vel(self, msg) -> None:
        cmd = (msg.linear.x, msg.linear.y, msg.angular.z)
        self.received["cmd_vel"] += 1
        if not all(np.isfinite(cmd)):
            return  # a non-finite command is dropped: the last one holds until it times out
        with self._lock:
            self._cmd_in[:] = cmd
            self._cmd_new, self._cmd_at = True, time.monotonic()

    def _on_goal(self, msg) -> None:
        goal = np.array([msg.point.x, msg.point.y, msg.point.z])
        self.received["goal_point"] += 1
        if np.isfinite(goal).all():
            with self._lock:
                self._goal_in = goal

    def _service(self, kind: str):
        def serve(request, response):
            call = _Request(kind)
            self._requests.put(call)
            call.done.wait(SERVICE_TIMEOUT)
            response.success, response.message = call.success, call.message
            self.services[kind] += 1
            return response

        return serve

    # ------------------------------------------------------------------ lifecycle, report
    def summary(self) -> dict:
        """Figures for the run's report: node name, messages published and received by topic,
        ticks skipped (the node fell behind), ``cmd_vel`` time-outs, service calls."""
        return {
            "node": self.name,
            "published": dict(self.published),
            "received": dict(self.received),
            "ticks_skipped": self.buffer.skipped,
            "cmd_vel_timeouts": self.cmd_vel_timeouts,
            "services": dict(self.services),
            "services_refused": self.refused,
            "after_tick_us": self.after_tick_cost.summary(),
        }

    def close(self) -> None:
        """Publish the last diagnostics, stop the node's thread, leave ROS 2 (idempotent)."""
        self.thread.close()
