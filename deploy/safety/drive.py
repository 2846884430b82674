"""The guard's model of a velocity-mode drive: where its PI loop will take the joint.

A velocity drive is not a speed source. Its PI velocity loop (robot.toml's ``kp``, ``kd``; the
plant's, :meth:`robots.Robot.mjspec`) is

    tau = kd (v_cmd - dq) + kp (s - q),     s' = v_cmd,

with ``s`` the integral of the commands (the loop's integrator, started at the pose when the
drive is enabled, kept within ``effort_limit / kp`` of the joint by its anti-windup and within
the joint's range). Written for the lag ``e = s - q``, the joint is a position servo with
velocity feed-forward:

    e'' + (kd / M) e' + (kp / M) e = a_cmd - d / M,

``M`` the joint's inertia, ``d`` gravity, friction and the other joints' coupling. Wherever the
commands stop, the joint comes to rest where its lag balances gravity, ``q = s - g(q) / kp``
(:meth:`VelocityDrive.equilibrium`); while the commands brake at ``a`` it runs ahead of ``s``
by up to ``M a / kp`` (the lead), and the loop's anti-windup never lets ``|e|`` exceed
``effort_limit / kp``. So the motion a velocity command commits the robot to is the path of the
equilibrium ``s - g / kp`` (the integral of the smoother's commands and of its brake), widened
by the lead, the uncertainty of the gravity load and the dry friction the loop must overcome
(:meth:`VelocityDrive.slack`). The motion envelope (:mod:`deploy.safety.envelope`) certifies
that, as it certifies the command path of a position servo.

The runtime does not see ``s``; it integrates its own commands as the drive does
(:meth:`VelocityDrive.integrate`), with the same anti-windup on the estimated pose: the model is
exact up to the estimate's error wherever the anti-windup clamps.
"""

from __future__ import annotations

import numpy as np

from deploy.stateful import put, take
from robots import Robot
from robots.chain_bounds import inertia_bound

#: Share of each joint's gravity torque the guard does not trust (our choice): the soak
#: randomizes link masses +-20 % and actuator strength +-10 % (``eval.world.dynamics``).
GRAVITY_UNCERTAINTY = 0.3
#: Share by which a joint's true inertia may exceed the nominal model's (our choice): the soak's
#: link masses +-20 % and link lengths +-10 % (inertia ~ m l^2: 1.2 x 1.1^2 = 1.45).
INERTIA_UNCERTAINTY = 0.45
#: Multiple of the model's dry friction (``frictionloss``) the drive may have to overcome (our
#: choice): the soak's +-50 % and its drift of up to 6 % per hour over 8 hours.
FRICTION_FACTOR = 3.0
#: Standard deviations of the estimated speed a joint must be past its velocity limit by before
#: the guard trusts that it runs away (our choice: three, a 0.3 % false alarm per joint and tick
#: for a Gaussian error; the estimate of a drive commanded at its limit crosses it half the time).
ESTIMATE_SIGMAS = 3.0


#: Shares of each joint's inertia bound over which :func:`unwind_factor` takes its worst case
#: (our choice: a joint's inertia changes with the pose; a lighter load unwinds faster).
INERTIA_SHARES = (0.25, 0.5, 1.0)


def unwind_factor(kp: np.ndarray, kd: np.ndarray, inertia: np.ndarray) -> np.ndarray:
    """(n,) 1/s, the peak speed error per radian of lag of a PI velocity loop's free response,
    ``max_t |e'(t)| / e(0)`` for ``M e'' + kd e' + kp e = 0`` from ``e(0) = 1``, ``e'(0) = 0``,
    worst over ``M`` in :data:`INERTIA_SHARES` of ``inertia`` (n,) kg m^2; ``kp`` (n,) N m/rad,
    ``kd`` (n,) N m s/rad. Integrated numerically (semi-implicit Euler, 4,000 steps over ten
    undamped periods)."""
    worst = np.zeros(len(kp))
    for share in INERTIA_SHARES:
        m = share * np.asarray(inertia, dtype=float)
        omega = np.sqrt(kp / m)
        dt = 10.0 * 2.0 * np.pi / omega / 4000.0
        e, de = np.ones(len(kp)), np.zeros(len(kp))
        for _ in range(4000):
            de += dt * (-(kd * de + kp * e) / m)
            e += dt * de
            np.maximum(worst, np.abs(de), out=worst)
    return worst


class VelocityDrive:
    """The guard's model of ``envs`` velocity drives' PI loops (module docstring).

    Args:
        robot: The robot (``kp``, ``kd`` per joint, the effort and acceleration limits, the
            control period, the MJCF's dry friction).
        envs: Batch size.

    Attributes:
        setpoint: (envs, n) rad, each drive's integrator ``s``: the integral of the commands
            since :meth:`reset`, kept within the joint's range and within ``effort_limit / kp``
            of the estimated pose.
        kp: (n,) N m/rad; kd (n,) N m s/rad; from robot.toml.
        inertia: (n,) kg m^2, :func:`robots.chain_bounds.inertia_bound`.
        unwind: (n,) 1/s, :func:`unwind_factor`.

    Raises:
        RobotSpecError: (from the robot) a joint without ``kp`` (a velocity drive needs it).
    """

    def __init__(self, robot: Robot, envs: int):
        self.robot, self.envs = robot, envs
        n = robot.n_joints
        self.dt = robot.control_period
        self.kp = np.array([j.kp for j in robot.config.joints], dtype=float)
        self.kd = np.array([j.kd for j in robot.config.joints], dtype=float)
        self.inertia = inertia_bound(robot)
        self.unwind = unwind_factor(self.kp, self.kd, self.inertia)
        #: rad/s: a joint estimated faster than its hard velocity limit runs away
        self._runaway = np.asarray(robot.velocity_limit, dtype=float)
        m = robot.mj_model
        dofs = [m.jnt_dofadr[m.joint(name).id] for name in robot.joint_names]
        self.friction = FRICTION_FACTOR * np.asarray(m.dof_frictionloss[dofs], dtype=float)
        self.lower, self.upper = robot.position_lower, robot.position_upper
        self.setpoint = np.tile(np.asarray(robot.home, dtype=float), (envs, 1))
        self._model = robot.fixed_base_model
        self._data = self._model.createData()
        self._sag = np.zeros((envs, n))
        self._mass = np.zeros((envs, n, n))
        self._bound = np.zeros((envs, n))
        #: (envs, n, 2, 2) the joint estimator's covariance of ``[q, dq]`` (rad^2, rad^2/s^2),
        #: a view the runtime sets (:class:`deploy.estimation.joints.JointStateEstimator`), or
        #: None: then no joint counts as running away
        self.covariance = None

    def reset(self, q: np.ndarray, envs: np.ndarray | None = None) -> None:
        """The drives of ``envs`` (bool mask (envs,), default all) enabled at the estimated pose
        ``q`` (envs, n) rad: the integrator starts there."""
        which = slice(None) if envs is None else np.asarray(envs, dtype=bool)
        self.setpoint[which] = q[which]

    def state_dict(self, env: int | None = None) -> dict[str, np.ndarray]:
        """``setpoint`` (envs, n) rad (a copy; the env axis has length 1 for one env ``env``)."""
        return take({"setpoint": self.setpoint}, env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict`.

        Raises:
            StateDictError: a missing field or a shape that differs; nothing is changed.
        """
        put({"setpoint": self.setpoint}, state, env)

    def windup_bound(self, effort_scale: np.ndarray) -> np.ndarray:
        """(envs, n) rad, the largest lag ``|s - q|`` the anti-windup allows: the (derated)
        effort limit over ``kp``; a view reused per call."""
        np.multiply(effort_scale, self.robot.effort_limit / self.kp, out=self._bound)
        return self._bound

    def equilibrium(self, q: np.ndarray) -> np.ndarray:
        """(envs, n) rad, where each joint comes to rest if the commands stop now: the setpoint
        less the gravity sag ``g(q) / kp`` at the estimated pose ``q`` (envs, n) (Pinocchio's
        gravity torque at the nominal masses); a new array. Also keeps the mass matrix at ``q``
        (CRBA) for :meth:`lead` and :meth:`overspeed`."""
        import pinocchio as pin

        model, data = self._model, self._data
        for e in range(self.envs):
            self._sag[e] = pin.computeGeneralizedGravity(model, data, q[e])
            upper = pin.crba(model, data, q[e])  # the upper triangle
            mass = self._mass[e]
            np.copyto(mass, upper)
            mass += np.triu(upper, 1).T
        return self.setpoint - self._sag / self.kp

    def slack(self, velocity: np.ndarray) -> np.ndarray:
        """(envs, n) rad, how far a joint may stray either way from the path of its equilibrium
        (:meth:`equilibrium`): the untrusted share of the gravity sag (of the last
        :meth:`equilibrium`), the dry friction over ``kp``, and one period of the commanded
        ``velocity`` (envs, n) rad/s (the drive holds each command for a period; the smoother's
        position integrates it continuously). A new array."""
        slack = GRAVITY_UNCERTAINTY * np.abs(self._sag) / self.kp
        slack += self.friction / self.kp
        slack += np.abs(velocity) * self.dt
        return slack

    def lead(
        self, velocity: np.ndarray, acceleration: np.ndarray, share: np.ndarray, effort_scale
    ) -> np.ndarray:
        """(envs, n) rad, signed: how far past the brake's rest point a joint runs ahead of its
        integrator while the smoother brakes it from ``velocity`` (rad/s) and ``acceleration``
        (rad/s^2), (envs, n) each, at the acceleration limit times ``share`` (envs, n) (a
        derated drive's headroom): ``inertia * a_peak / kp`` in the direction of the motion,
        ``inertia`` the mass matrix's diagonal at the pose of the last :meth:`equilibrium`
        (:data:`INERTIA_UNCERTAINTY` above it), ``a_peak`` the brake's peak deceleration (the
        limit, or ``sqrt(v j)`` for a brake too
        short to reach it, ``v`` the speed once the acceleration toward the motion is ramped
        down), never above the anti-windup's bound at the drives' derating ``effort_scale``
        (envs, n). A new array."""
        j = self.robot.jerk_limit
        sign = np.where(velocity != 0.0, np.sign(velocity), np.sign(acceleration))
        toward = np.maximum(acceleration * sign, 0.0)
        v_eff = np.abs(velocity) + toward * toward / (2.0 * j)
        amax = self.robot.acceleration_limit * share
        peak = np.minimum(amax, np.sqrt(v_eff * j))
        inertia = (1.0 + INERTIA_UNCERTAINTY) * np.diagonal(self._mass, axis1=1, axis2=2)
        lead = np.minimum(inertia * peak / self.kp, self.windup_bound(effort_scale))
        return sign * lead

    def overspeed(
        self, q: np.ndarray, dq: np.ndarray, velocity, acceleration, out: np.ndarray
    ) -> np.ndarray:
        """(envs,) bool into ``out``: the envs where a joint commanded ``velocity`` (envs, n)
        rad/s may run past its hard velocity limit, or already runs past it
        (the estimate ``dq`` (envs, n) rad/s). A drive gives way to two
        things: the lag it carries (the integrator ``s`` ahead of the estimate ``q`` (envs, n)
        rad in the direction of the command, less the gravity sag that holds it steady, of which
        :data:`GRAVITY_UNCERTAINTY` is not trusted), whose unwinding peaks at :attr:`unwind`
        times that lag (an acceleration phase leaves it; ur5's first wrist joint ran 12 % past
        its command after one); and the torque the other joints' commanded
        ``acceleration`` (envs, n) rad/s^2 push it with through the mass matrix's coupling at the
        pose of the last :meth:`equilibrium`, the sum of ``-M_ij a_j`` along joint ``i``'s
        motion over ``kd_i`` (a PI loop's speed error under a step disturbance torque, before
        its integral catches up, peaks below ``D / kd``; :data:`INERTIA_UNCERTAINTY` above the
        model; a push against the motion is not credited). A joint whose estimated speed is past
        its hard velocity limit by more than :data:`ESTIMATE_SIGMAS` of its error
        (:attr:`covariance`) runs away: its env brakes too."""
        # the lag that unwinds: what the gravity sag (its untrusted share aside) does not hold
        sag = self._sag / self.kp
        lag = (self.setpoint - q - sag) * np.sign(velocity) + GRAVITY_UNCERTAINTY * np.abs(sag)
        excess = np.abs(velocity) + self.unwind * np.maximum(lag, 0.0)
        # joint j's acceleration pushes joint i with -M_ij a_j; only the pushes along i's
        # motion count, none is credited against it
        sign = np.sign(velocity)
        push = -self._mass * acceleration[:, None, :] * sign[:, :, None]
        np.maximum(push, 0.0, out=push)
        push = push.sum(axis=2) - np.diagonal(push, axis1=1, axis2=2)
        excess += (1.0 + INERTIA_UNCERTAINTY) * push / self.kd
        over = excess > self.robot.velocity_limit
        if self.covariance is not None:  # the estimate's speed, less its error, past the limit
            sigma = np.sqrt(np.maximum(self.covariance[..., 1, 1], 0.0))
            over |= np.abs(dq) - ESTIMATE_SIGMAS * sigma > self._runaway
        np.any(over, axis=1, out=out)
        return out

    def settle(self, q: np.ndarray, effort_scale: np.ndarray) -> None:
        """The anti-windup of the period just ended: each integrator within the (derated)
        ``effort_limit / kp`` of the estimated pose ``q`` (envs, n) rad, as the drive keeps it
        of the true one."""
        bound = self.windup_bound(effort_scale)
        np.clip(self.setpoint, q - bound, q + bound, out=self.setpoint)

    def integrate(self, command: np.ndarray) -> None:
        """One control period of the integrators under ``command`` (envs, n) rad/s, within the
        joints' range."""
        s = self.setpoint
        s += command * self.dt
        np.clip(s, self.lower, self.upper, out=s)
