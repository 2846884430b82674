"""The ros2_control controller manager over the MuJoCo plant: ``python -m sim2real.deploy.ros2.emulator``.

:class:`ControllerManagerEmulator` plays what a ros2_control robot's bring-up runs: a
``joint_state_broadcaster`` publishing ``joint_states`` (``sensor_msgs/JointState``: position,
velocity, effort of every joint) at the controller manager's update rate, and one forward command
controller (``forward_position_controller`` / ``forward_velocity_controller`` /
``forward_effort_controller``, :mod:`sim2real.deploy.ros2.controllers`) taking
``std_msgs/Float64MultiArray`` on ``<controller>/commands``. Behind them: a
:class:`~sim2real.deploy.backends.sim.plant.SimBackend` of the robot in that control mode (its drives,
sensor noise and thermal model) on a thread paced by the wall clock. Each update is a hardware
loop's at a fixed rate, ``read`` / ``update`` / ``write``: the plant's state at the update's time
(``t0 + k * period``, which stamps ``joint_states``), then the newest command that arrived before
that time (a forward controller holds the last; before the first, the plant's initial command
holds the robot at home), then the plant steps one period under it (its motion until the next
update). The link is instantaneous: a command counts from when it was sent (its message info's
source timestamp), and the thread that updates also takes the commands, all that are waiting
before each update: an update the thread runs late (a loaded computer) still takes every command
sent before its time, and none sent after.
Nothing in the runtime knows it talks to an emulator.

The emulator counts what the robot really did (:class:`~sim2real.deploy.monitors.violations.
ViolationMonitor` on the plant's true state) and prints its counters as one JSON line at exit.
A fault for the tests and ``make hil``: ``--silence START:DURATION`` (s after the first command)
stops ``joint_states`` for a while, as a broadcaster whose controller manager stalls.

Command line::

    python -m sim2real.deploy.ros2.emulator --robot arm3 --mode velocity [--namespace NS] [--seed N]

It prints one line when it serves (``ready: ...``), then serves until SIGTERM or Ctrl-C.
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
import threading
import time

import numpy as np

from sim2real.deploy.backends.emulator_main import emulator_parser, open_emulator, serve
from sim2real.deploy.core.collector import collector_paused
from sim2real.deploy.ros2.context import NodeThread
from sim2real.deploy.ros2.controllers import FORWARD_CONTROLLERS, command_topic

#: s the plant may fall behind the wall clock before its time origin moves up (as the Unitree
#: emulator's).
MAX_LAG = 0.25


class ControllerManagerEmulator:
    """A ros2_control robot's topics over the MuJoCo plant (module docstring).

    Args:
        robot: A :class:`robots.Robot` or a shipped robot's name / robot.toml path.
        mode: 'position', 'velocity' or 'torque' (default robot.toml's).
        namespace: The topics' namespace. seed: The plant's seed (sensor noise).
        silence: Optional (start s, duration s) after the first command without
            ``joint_states``.

    Attributes:
        plant: The :class:`SimBackend`. violations: The true-state ViolationMonitor.
        stats: Counters: ``updates``, ``joint_states_published``, ``commands_received``,
            ``commands_refused`` (wrong length or non-finite), ``updates_without_command``
            (since the first command), ``plant_lag_resets``, ``silenced_updates``.
    """

    def __init__(self, robot, mode: str | None = None, *, namespace: str = "", seed: int = 0,
                 silence: tuple[float, float] | None = None,
                 plant_motors: str | None = None):  # fmt: skip
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray

        from sim2real.deploy.backends.sim.options import plant_for
        from sim2real.deploy.backends.sim.plant import SimBackend
        from sim2real.deploy.monitors.violations import ViolationMonitor
        from sim2real.robots import Robot, load_robot

        self.robot = robot if isinstance(robot, Robot) else load_robot(robot)
        self.mode = mode or self.robot.control_mode
        self.controller = FORWARD_CONTROLLERS[self.mode]
        self.period = self.robot.control_period
        plant_robot, models = plant_for(self.robot, self.mode, plant_motors, 1)
        self.plant = SimBackend(plant_robot, mode=self.mode, seed=seed, models=models)
        self.violations = ViolationMonitor(self.robot, 1)
        self.silence = silence
        self.stats = dict.fromkeys(
            ("updates", "joint_states_published", "commands_received", "commands_refused",
             "updates_without_command", "plant_lag_resets", "silenced_updates"), 0,
        )  # fmt: skip
        self._command: np.ndarray | None = None
        #: (arrival s on time.monotonic, command) not yet applied, oldest first
        self._inbox: collections.deque = collections.deque(maxlen=64)
        self._first_command: float | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.node = NodeThread("controller_manager", namespace)
        node = self.node.node
        self._msg = JointState()
        self._msg.name = list(self.robot.joint_names)
        self._pub = node.create_publisher(JointState, "joint_states", 10)
        node.create_subscription(
            Float64MultiArray, command_topic(self.controller), self._on_command, 10
        )
        self._wall_ns = time.time_ns() - time.monotonic_ns()  # time.time_ns() at monotonic 0
        self.plant.read()

    def _on_command(self, msg, info) -> None:
        now = time.monotonic()
        sent = info.get("source_timestamp") or 0  # the link is instantaneous
        arrival = (sent - self._wall_ns) * 1e-9
        if not now - 1.0 < arrival <= now:  # a middleware without the stamp, or another clock
            arrival = now
        data = np.asarray(msg.data, dtype=np.float64)
        with self._lock:
            self.stats["commands_received"] += 1
            if data.shape != (self.robot.n_joints,) or not np.isfinite(data).all():
                self.stats["commands_refused"] += 1  # as the forward controller refuses it
                return
            self._inbox.append((arrival, data))
            if self._first_command is None:
                self._first_command = arrival

    # ------------------------------------------------------------------ serving
    def request_stop(self) -> None:
        """Ask :meth:`serve` to return (safe from a signal handler)."""
        self._stop.set()

    def serve(self) -> None:
        """Update at the control rate, paced by the wall clock, until :meth:`request_stop`, with
        the garbage collector paused (:func:`~sim2real.deploy.core.collector.collector_paused`:
        a full collection is a gap in ``joint_states``)."""
        with collector_paused():
            self._serve()

    def _serve(self) -> None:
        t0, steps, period = time.monotonic(), 0, self.period
        wall_ns = self._wall_ns
        while not self._stop.is_set():
            self._take_commands()
            due = int((time.monotonic() - t0) / period) + 1  # the updates whose time has come
            if due - steps > MAX_LAG / period:
                t0 += (due - 1 - steps) * period
                self.stats["plant_lag_resets"] += 1
                due = steps + 1
            while steps < due and not self._stop.is_set():
                at = t0 + steps * period
                self._update(at, wall_ns + round(at * 1e9))
                steps += 1
            self.node.spin_once(max(0.0, t0 + steps * period - time.monotonic()))

    def _take_commands(self) -> None:
        """Run the node's callbacks until none is waiting (at most 64)."""
        for _ in range(64):
            before = self.stats["commands_received"]
            self.node.spin_once(0.0)
            if self.stats["commands_received"] == before:
                return

    def _update(self, at: float, stamp_ns: int) -> None:
        """One update of the controller manager at ``at`` (s, time.monotonic; ``stamp_ns`` the
        same on time.time_ns): read the hardware, publish its state stamped ``stamp_ns``, write
        the newest command that arrived by ``at``, step the plant one period."""
        plant = self.plant
        with self._lock:
            fresh = False
            while self._inbox and self._inbox[0][0] <= at:
                self._command, fresh = self._inbox.popleft()[1], True
            command, first = self._command, self._first_command
        frame = plant.read()
        if self._silenced(first):
            self.stats["silenced_updates"] += 1
        else:
            msg = self._msg
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
            msg.position = frame.position[0]
            msg.velocity = plant.true_velocity()[0]
            msg.effort = plant.joint_torque()[0]
            self._pub.publish(msg)
            self.stats["joint_states_published"] += 1
        if first is not None and first <= at and not fresh:
            self.stats["updates_without_command"] += 1
        if command is not None:  # before the first, the plant holds its initial command
            plant.write(command[None, :])
        plant.advance()
        self.violations.update(plant)
        self.stats["updates"] += 1

    def _silenced(self, first: float | None) -> bool:
        if self.silence is None or first is None:
            return False
        t = time.monotonic() - first
        return self.silence[0] <= t < self.silence[0] + self.silence[1]

    def counters(self) -> dict:
        """The counters and the true violations (ticks by type) since the start."""
        return {**self.stats, "violations": self.violations.totals()}

    def close(self) -> None:
        self._stop.set()
        self.node.close()


def _pair(text: str) -> tuple[float, float]:
    try:
        start, duration = (float(x) for x in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected START:DURATION (s)") from None
    return start, duration


def main(argv: list[str] | None = None) -> int:
    """Serve until SIGTERM or Ctrl-C (module docstring); the counters go to stderr at the end as
    JSON. Exit code 0, or 2 on a bad argument or robot."""
    p = emulator_parser(
        "sim2real.deploy.ros2.emulator",
        "A ros2_control controller manager (joint_state_broadcaster and a forward command "
        "controller) over the MuJoCo plant.",
    )
    p.add_argument("--mode", choices=sorted(FORWARD_CONTROLLERS), default=None)
    p.add_argument("--namespace", default="", help="the topics' namespace")
    p.add_argument(
        "--silence",
        type=_pair,
        default=None,
        metavar="START:DURATION",
        help="no joint_states for DURATION s, START s after the first command",
    )
    args = p.parse_args(argv)
    emulator = open_emulator("ros2", ControllerManagerEmulator, args)
    if emulator is None:
        return 2

    def announce() -> None:
        print(
            f"ready: {emulator.robot.name}, joint_states at {1 / emulator.period:.0f} Hz, "
            f"{command_topic(emulator.controller)}",
            flush=True,
        )

    counters = serve(emulator, emulator.close, emulator.counters, announce)
    print(f"emulator counters: {json.dumps(counters)}", file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
