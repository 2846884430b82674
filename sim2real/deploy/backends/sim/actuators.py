"""The plant's motors between the drive command and the physics: each motor's torque-speed line
and its command delay, applied before every physics step.

- **Torque-speed line** (:class:`sim2real.robots.torque_speed.TorqueSpeedEnvelope`): the joint's actuator
  torque range follows its speed, its stall torque its winding's temperature. A session may draw
  the supply voltage (a battery's charge, :attr:`ActuatorModel.supply`): the stall torque and
  the no-load speed scale with it.
- **Command delay**: a motor file's ``command_delay`` (s, the drive's and the link's transport
  delay) holds each joint's command back by that many physics steps; the commands of the
  control periods before are kept (:attr:`ActuatorModel.history`, part of the plant's state).

Both run in one compiled call per env and physics step
(:func:`sim2real.deploy.backends.sim.drives_kernel.actuator_step`) for MuJoCo and pybullet alike; a robot
whose motors have neither keeps MuJoCo's stepping of a whole control period in one call.
"""

from __future__ import annotations

import math

import numpy as np

from sim2real.deploy.backends.sim.drives_kernel import actuator_step
from sim2real.robots.torque_speed import TorqueSpeedEnvelope


class ActuatorModel:
    """The actuators of ``envs`` simulated robots.

    Args:
        robot: The robot (its motors' ``max_velocity`` and ``command_delay``).
        envs: Batch size.
        timestep: s, the physics step.
        decimation: Physics steps per control period.

    Attributes:
        envelope: The motors' :class:`~sim2real.robots.torque_speed.TorqueSpeedEnvelope`.
        supply: (envs,) the supply voltage over its nominal value (1.0; a session's draw).
        delay_steps: (n,) int64, each joint's command delay in physics steps.
        history: (envs, depth, n) the drive commands of the last ``depth`` control periods, by
            tick modulo ``depth`` (units of the control mode).
        active: Some motor has a torque-speed line or a delay: the plant steps one physics step
            at a time.
    """

    def __init__(self, robot, envs: int, timestep: float, decimation: int):
        n = robot.n_joints
        self.envelope = TorqueSpeedEnvelope(robot.motors)
        self.supply = np.ones(envs)
        delays = [m.command_delay or 0.0 for m in robot.motors]
        self.delay_steps = np.array([round(d / timestep) for d in delays], dtype=np.int64)
        self.decimation = decimation
        depth = 1 + math.ceil(int(self.delay_steps.max(initial=0)) / decimation)
        self.history = np.zeros((envs, depth, n))
        self.active = bool(self.envelope.any or self.delay_steps.any())
        self._stall = np.zeros((envs, n))
        self._no_load = np.tile(self.envelope.no_load_speed, (envs, 1))
        self._tick = 0
        z = np.zeros(n)  # compiled (or loaded from its cache) before a tick
        actuator_step(
            self.history[0], 0, 0, decimation, self.delay_steps, np.zeros((1, n)), z, z, z,
            self._no_load[0], self.envelope.active, np.zeros((n, 2)),
        )  # fmt: skip

    def kernel_arrays(self) -> dict[str, np.ndarray]:
        """The model's live arrays, by name, for a compiled step that keeps their addresses
        (:class:`sim2real.deploy.backends.sim.compiled_step.CompiledStep`): the arrays themselves,
        not copies, C-contiguous, never rebound.

        ``history`` (envs, depth, n) float64 (units of the control mode), ``delay_steps`` (n,)
        int64, ``supply`` (envs,) float64 (over nominal), and the torque-speed line of the present
        period, (envs, n) float64 each, written by :meth:`start_period`: ``stall`` (N m, the
        stall torque at the winding temperature and supply) and ``no_load`` (rad/s, the no-load
        speed at the supply). Raises nothing.
        """
        return {
            "history": self.history,
            "delay_steps": self.delay_steps,
            "supply": self.supply,
            "stall": self._stall,
            "no_load": self._no_load,
        }

    def reset(self, which: np.ndarray, command: np.ndarray) -> None:
        """The envs of the boolean mask ``which`` restart holding ``command`` (envs, n): their
        history is that command."""
        self.history[which] = command[which][:, None, :]

    def start_period(self, tick: int, command: np.ndarray, winding_temperature: np.ndarray):
        """Before a control period's physics steps: record tick ``tick``'s ``command`` (envs, n)
        and take each motor's stall torque at ``winding_temperature`` (envs, n) degC and the
        supply."""
        self._tick = tick
        self.history[:, tick % self.history.shape[1]] = command
        e = self.envelope
        if not e.any:  # delays only: no line to follow
            return
        np.subtract(winding_temperature, e.t_ref, out=self._stall)
        np.multiply(self._stall, e.alpha, out=self._stall)
        np.add(self._stall, 1.0, out=self._stall)
        np.divide(e.stall_coefficient, self._stall, out=self._stall)
        np.multiply(self._stall, self.supply[:, None], out=self._stall)
        np.multiply(e.no_load_speed, self.supply[:, None], out=self._no_load)

    def before_step(self, e: int, sub: int, ctrl, velocity, limit, out) -> None:
        """Before physics step ``sub`` of the period, env ``e``: the delayed commands into
        ``ctrl`` (actuators per joint, n) and the torque range at joint ``velocity`` (n,) rad/s
        under the current ``limit`` (n,) N m into ``out`` (n, 2) N m (MuJoCo's
        ``jnt_actfrcrange`` rows)."""
        actuator_step(
            self.history[e], self._tick, sub, self.decimation, self.delay_steps, ctrl,
            velocity, limit, self._stall[e], self._no_load[e], self.envelope.active, out,
        )  # fmt: skip

    def state_fields(self) -> dict[str, np.ndarray]:
        """``actuators/history`` (envs, depth, n) when some motor delays its command; else
        nothing (a plant without delays checkpoints as before)."""
        return {"actuators/history": self.history} if self.delay_steps.any() else {}
