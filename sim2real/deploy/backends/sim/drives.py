"""The simulated drives of the plant (:class:`SimDrives`): torque limits derated from the winding
temperature, and the velocity loop's anti-windup.

Each drive's actuator torque is limited to its joint's effort limit, which the drive derates from
its own (true) winding temperature with :class:`sim2real.robots.thermal.EffortDerating` (peak torque below
the derating start, continuous torque, or the arm's gravity load where that is more, at the
maximum winding temperature), applied before every control period's physics steps.

:class:`SimDrives` is a stage of :class:`~sim2real.deploy.backends.sim.plant.SimBackend`: it owns
its arrays (the limits, the derating screen's flags, the anti-windup bounds) and the plant's
compiled step reads them through the plant's ``kernel_arrays``; it works on the plant's models
(a list the plant shares with it), and is given the temperatures and joint angles it needs.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.backends.sim.drives_kernel import derating_due, windup_exceeded
from sim2real.deploy.kernels import all_finite
from sim2real.robots.chain_bounds import motion_bounds
from sim2real.robots.thermal import EffortDerating


class SimDrives:
    """The drive model of a plant of ``envs`` robots in ``mode`` (module docstring).

    Args:
        robot: The robot. mode: The control mode. envs: The batch size.
        models: The plant's compiled models, one per env (the plant's list: a new model of an
            env is seen here). free_base: The models' first joint is the free joint (the
            plant's :attr:`~sim2real.deploy.backends.sim.disturbances.SimDisturbances.free_base`).

    Attributes:
        derating: The drives' :class:`~sim2real.robots.thermal.EffortDerating`.
        effort_limit: (envs, n) N m, each drive's present torque limit.
        derated, hot: (envs,) bool: an env whose model may hold a derated limit; an env with a
            winding above its derating start.
        windup_bound: (envs, n) rad, ``effort_limit / kp`` (velocity mode). lag: (envs, n) rad,
            the velocity loop's setpoints' scratch. acts: per env, the drives' setpoints
            (``MjData.act``, velocity mode; else empty).
    """

    def __init__(self, robot, mode: str, envs: int, models: list, free_base: bool):
        n = robot.n_joints
        self.robot, self.mode, self.models, self.n = robot, mode, models, n
        self._jnt_offset = 1 if free_base else 0  # the free joint comes first
        self.acts: list[np.ndarray] = [np.empty(0)] * envs  # velocity mode: drive setpoints
        self.windup_bound = np.zeros((envs, n))
        self.derating = EffortDerating(robot, hold=motion_bounds(robot)[1])
        self.effort_limit = np.tile(self.derating.peak, (envs, 1))
        self._derate = np.ones((envs, n))
        self.derated = np.zeros(envs, dtype=bool)  # envs whose model may hold a derated limit
        self.hot = np.zeros(envs, dtype=bool)  # envs with a winding above its derating start
        all_finite(self.hot[:, None] * 0.0)  # compiled (or loaded from cache) before a tick
        self.lag = np.zeros((envs, n))
        # the drive kernels too (sim2real.deploy.backends.sim.drives_kernel), on arrays of their types
        z = np.zeros((envs, n))
        derating_due(z, np.zeros(n), np.zeros(envs, dtype=bool), np.zeros(envs, dtype=bool))
        windup_exceeded(z.copy(), z, z)

    def bind(self, e: int, m, d) -> None:
        """Env ``e``'s new model ``m`` and data ``d``: re-derate at the next period; velocity
        mode: its setpoints and their anti-windup bound."""
        self.derated[e] = True  # a new model has the peak limits: re-derate at the next advance
        if self.mode == "velocity":  # the setpoints and their anti-windup bound
            self.acts[e] = d.act
            kp = m.actuator_gainprm[: self.n, 0]
            self.windup_bound[e] = self.robot.effort_limit / kp

    def state_fields(self) -> dict[str, np.ndarray]:
        """The drives' part of the plant's state dict: ``effort_limit`` (envs, n) N m."""
        return {"effort_limit": self.effort_limit}

    def derate(self, winding_temperature: np.ndarray) -> None:
        """Each drive's torque limit from its winding temperature ((envs, n) degC; module
        docstring): ``effort_limit``, MuJoCo's ``jnt_actfrcrange`` and, in velocity mode, the
        anti-windup bound follow it. Only envs with a winding above its derating start, or
        derated before, are touched. The step of the Python path before the plant's compiled
        one (:func:`sim2real.deploy.backends.sim.reference.reference_advance`, the pybullet
        plant). Raises nothing."""
        if derating_due(winding_temperature, self.derating.start, self.derated, self.hot):
            self.set_derated_limits(winding_temperature)

    def set_derated_limits(self, winding_temperature: np.ndarray) -> None:
        """The action of :meth:`derate` once its screen (``hot``) found work: the limits of the
        hot envs and of those derated before follow their windings' temperature."""
        hot = self.hot
        for e in np.flatnonzero(hot | self.derated):
            limit = self.effort_limit[e]
            np.multiply(
                self.derating.factor(winding_temperature[e], out=self._derate[e]),
                self.derating.peak,
                out=limit,
            )
            m = self.models[e]
            joints = slice(self._jnt_offset, self._jnt_offset + self.n)
            m.jnt_actfrcrange[joints, 0] = -limit
            m.jnt_actfrcrange[joints, 1] = limit
            if self.mode == "velocity":
                np.divide(limit, m.actuator_gainprm[: self.n, 0], out=self.windup_bound[e])
        self.derated[:] = hot

    def anti_windup(self, qpos: np.ndarray) -> None:
        """Velocity mode: keep each drive's setpoint (``MjData.act``, rad) within
        ``effort_limit / kp`` of its joint angle gathered at the end of the period (``qpos``
        (envs, n) rad; the drive's present, derated, limit). A step of the Python path, as
        :meth:`derate`; raises nothing.

        The integral term of the PI velocity loop, ``kp (s - q)``, then never asks for more than
        the drive's peak torque: when the torque saturates (a command accelerating faster than the
        motor can under load) the setpoint stops running ahead, and the joint does not overshoot
        the commanded speed to catch up afterwards (clamping anti-windup, K. J. Astrom and T.
        Hagglund, *Advanced PID Control*, ISA 2006, sec. 3.5). Applied once per control period.
        """
        lag, bound, acts = self.lag, self.windup_bound, self.acts
        for e, act in enumerate(acts):
            lag[e] = act
        if windup_exceeded(lag, qpos, bound):
            wound = np.abs(lag) > bound
            for e in np.flatnonzero(wound.any(axis=1)):
                q = qpos[e]
                np.clip(acts[e], q - bound[e], q + bound[e], out=acts[e])
