"""The operator in a run: :class:`OperatorHook`, the rig's after-tick hook that steps the
:class:`~sim2real.deploy.operator.machine.OperatorMachine`, hands the ROS 2 node's ``~/resume``
and ``~/reset_faults`` to its authority table, and writes the report's ``operator`` entry: every
transition and refusal, the policy switches, and the hand-overs' largest steps.

The hand-over figures: the largest tick-to-tick change of the guarded target (rad, position
mode) and of the command written (after the smoother) over the ticks of every blend, against the
same figures over the rest of the RUNNING ticks (the policies' own stepping), and the command's
largest step as a share of the smoother's velocity limit per control period
(``command_velocity_limit * dt``, per joint; at most 1 by construction).
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.modes import RUNNING
from sim2real.deploy.operator.machine import OperatorMachine
from sim2real.deploy.rig.hooks import RunHook


class OperatorHook(RunHook):
    """The operator's after-tick hook (module docstring).

    Args:
        rig: The run's :class:`~sim2real.deploy.rig.rig.Rig` (one env).
        machine: The :class:`OperatorMachine` over ``rig.runtime``.
        mapping_path: Where the mapping came from (for the report).
    """

    name = "operator"

    def __init__(self, rig, machine: OperatorMachine, mapping_path: str = ""):
        self.rig, self.machine, self.mapping_path = rig, machine, str(mapping_path)
        rt = rig.runtime
        self._prev_target = np.zeros(rt.n)
        self._prev_cmd = np.zeros(rt.n)
        self._limit = np.asarray(rig.robot.command_velocity_limit, dtype=np.float64) * rt.dt
        self._blend_ticks = 0
        self.handover = {"target": 0.0, "command": 0.0, "share": 0.0}
        self.steady = {"target": 0.0, "command": 0.0, "share": 0.0}
        self._running_before = False

    def start(self, rig) -> None:
        for hook in rig.hooks:  # the ROS 2 node's resume and reset: the authority table's
            node = getattr(hook, "node", None)
            if hook.name == "ros2" and node is not None:
                node.authorize = self._authorize
        self.machine.start()

    def _authorize(self, kind: str) -> str | None:
        right = "resume" if kind == "resume" else "reset"
        if self.machine.may(right, "ros2"):
            return None
        why = f"'ros2' lacks the right '{right}' (operator configuration)"
        self.machine.refuse(f"ros2 ~/{kind}", "ros2", why)
        return why

    def after_tick(self, rt) -> None:
        self.machine.step(rt.time)
        running = int(rt.mode[0]) == RUNNING
        target, cmd = rt.target[0], rt.command[0]
        if running and self._running_before:
            blending = rt.handover is not None or self._blend_ticks > 0
            figures = self.handover if blending else self.steady
            t_step = float(np.max(np.abs(target - self._prev_target)))
            c_step = np.abs(cmd - self._prev_cmd)
            figures["target"] = max(figures["target"], t_step)
            figures["command"] = max(figures["command"], float(c_step.max()))
            figures["share"] = max(figures["share"], float(np.max(c_step / self._limit)))
        # the tick after a blend's last one still steps from a blended target
        self._blend_ticks = 1 if rt.handover is not None else max(0, self._blend_ticks - 1)
        self._running_before = running
        self._prev_target[:] = target
        self._prev_cmd[:] = cmd

    def close(self) -> None:
        for src in self.machine.sources:
            src.close()

    def contribute(self, report: dict) -> None:
        m = self.machine
        log = [t.__dict__ for t in m.log]
        report["operator"] = {
            "mapping": self.mapping_path,
            "sources": [s.source for s in m.sources],
            "policies": list(m.policies),
            "final_state": m.state,
            "policy": m.active,
            "transitions": [t for t in log if t["refused"] is None],
            "refused": [t for t in log if t["refused"] is not None],
            "switches": m.switches,
            "deadman_events": m.deadman_events,
            "handover_max_target_step": self.handover["target"],
            "handover_max_command_step": self.handover["command"],
            "handover_max_command_step_share_of_limit": self.handover["share"],
            "steady_max_target_step": self.steady["target"],
            "steady_max_command_step": self.steady["command"],
            "steady_max_command_step_share_of_limit": self.steady["share"],
            "units": f"{self.rig.runtime.mode_name} mode units (rad in position mode)",
        }
