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
(:meth:`VelocityDrive.motion`); while the commands brake at ``a`` it runs ahead of ``s``
by up to ``M a / kp`` (the lead), and the loop's anti-windup never lets ``|e|`` exceed
``effort_limit / kp``. So the motion a velocity command commits the robot to is the path of the
equilibrium ``s - g / kp`` (the integral of the smoother's commands and of its brake), widened
by the lead, the uncertainty of the gravity load and the dry friction the loop must overcome
(:meth:`VelocityDrive.motion`). The motion envelope (:mod:`sim2real.deploy.safety.envelope`) certifies
that, as it certifies the command path of a position servo.

The runtime does not see ``s``; it integrates its own commands as the drive does
(:meth:`VelocityDrive.integrate`), with the same anti-windup on the estimated pose: the model is
exact up to the estimate's error wherever the anti-windup clamps.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.stateful import put, take
from sim2real.deploy.safety import drive_kernel as dk
from sim2real.robots import Robot
from sim2real.robots.chain_bounds import inertia_bound

#: Share of each joint's gravity torque the guard does not trust (our choice): the soak
#: randomizes link masses +-20 % and actuator strength +-10 % (``sim2real.eval.world.dynamics``).
GRAVITY_UNCERTAINTY = 0.3
#: Share by which a joint's true inertia may exceed the nominal model's (our choice): the soak's
#: link masses +-20 % and link lengths +-10 % (inertia ~ m l^2: 1.2 x 1.1^2 = 1.45).
INERTIA_UNCERTAINTY = 0.45
#: Multiple of the model's dry friction (``frictionloss``) the drive may have to overcome (our
#: choice): the soak's +-50 % and its drift of up to 6 % per hour over 8 hours.
FRICTION_FACTOR = 3.0
#: Standard deviations of the joint estimate's error the guard allows for (our choice: three, a
#: 0.3 % false alarm per joint and tick for a Gaussian error). Velocity mode: how far past its
#: velocity limit a joint's estimated speed must be before the guard trusts that it runs away
#: (the estimate of a drive commanded at its limit crosses it half the time). Torque mode
#: (:mod:`sim2real.deploy.safety.torque_drive`): how far its motion is widened (every figure of torque
#: mode comes from the estimate; arm3's encoder noise put its estimated tip 2 cm from where it was).
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
        inertia: (n,) kg m^2, :func:`sim2real.robots.chain_bounds.inertia_bound`.
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
        m = robot.mj_model
        dofs = [m.jnt_dofadr[m.joint(name).id] for name in robot.joint_names]
        self.friction = FRICTION_FACTOR * np.asarray(m.dof_frictionloss[dofs], dtype=float)
        self.lower, self.upper = robot.position_lower, robot.position_upper
        self.setpoint = np.tile(np.asarray(robot.home, dtype=float), (envs, 1))
        self._model = robot.fixed_base_model
        self._data = self._model.createData()
        self._gravity = np.zeros((envs, n))
        self._mass = np.zeros((envs, n, n))
        # the kernel's per-joint figures (sim2real.deploy.safety.drive_kernel.velocity_drive_motion)
        self._joint = np.array([
            self.kp, self.kd, self.unwind, self.friction, robot.effort_limit,
            self.lower, self.upper, robot.jerk_limit, robot.acceleration_limit,
            robot.velocity_limit,
        ], dtype=float)  # fmt: skip
        self._uncertainty = np.array([GRAVITY_UNCERTAINTY, INERTIA_UNCERTAINTY, ESTIMATE_SIGMAS])
        self.covariance = None  # compiles the kernel for it (the setter)
        # the integrators' kernel for the limits' own arrays (read-only ones type differently)
        dk.integrate(
            self.setpoint.copy(), np.zeros_like(self.setpoint), self.dt, self.lower, self.upper
        )

    @property
    def covariance(self) -> np.ndarray | None:
        """(envs, n, 2, 2) the joint estimator's covariance of ``[q, dq]`` (rad^2, rad^2/s^2), a
        view the runtime sets (:meth:`sim2real.deploy.safety.guard.SafetyGuard.trust_estimate`), or None:
        the estimated speed is then taken as exact."""
        return self._covariance

    @covariance.setter
    def covariance(self, value: np.ndarray | None) -> None:
        self._covariance = value
        # the speed's variance, a strided view (one kernel specialization either way)
        source = np.zeros((self.envs, self.robot.n_joints, 2, 2)) if value is None else value
        self._variance = source[..., 1, 1]
        dk.warm_up(self._variance)  # its layout's specialization, before any tick

    @property
    def joint_figures(self) -> np.ndarray:
        """(10, n) float64, the kernel's per-joint rows (the live array): ``kp`` N m/rad, ``kd``
        N m s/rad, ``unwind`` 1/s, ``friction`` N m, effort limit N m, ``lower``, ``upper`` rad,
        jerk rad/s^3, acceleration rad/s^2 and velocity limits rad/s
        (:func:`sim2real.deploy.safety.drive_kernel.velocity_drive_motion`'s ``joint``)."""
        return self._joint

    @property
    def speed_variance(self) -> np.ndarray:
        """(envs, n) float64 rad^2/s^2, the estimated speed's variance: a strided view of
        :attr:`covariance` (zeros without one), a new array each time the covariance is set."""
        return self._variance

    @property
    def uncertainty(self) -> np.ndarray:
        """(3,) float64, the model's margins: ``GRAVITY_UNCERTAINTY``, ``INERTIA_UNCERTAINTY``
        (fractions) and ``ESTIMATE_SIGMAS`` (standard deviations of the speed estimate)."""
        return self._uncertainty

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

    def motion(
        self,
        q: np.ndarray,
        dq: np.ndarray,
        after: np.ndarray,
        effort_scale: np.ndarray,
        limits: np.ndarray,
        start: np.ndarray,
        end: np.ndarray,
        slack: np.ndarray,
        lead: np.ndarray,
        beyond: np.ndarray,
        stopping: np.ndarray,
    ) -> bool:
        """The drives' part of the step's motion, into the arrays given (one compiled call,
        :func:`sim2real.deploy.safety.drive_kernel.velocity_drive_motion`, after Pinocchio's gravity
        torque and mass matrix (CRBA) at the estimate, nominal masses).

        First the anti-windup of the period just ended: each integrator within the (derated)
        ``effort_limit / kp`` of the estimated pose, as the drive keeps it of the true one. Then:

        - ``start``, ``end`` (envs, n) rad: where each joint comes to rest if the commands stop
          now, the setpoint less the gravity sag ``g(q) / kp``, and once the step's command
          (``after[1]``) has been integrated for a period (within the joint's range).
        - ``slack`` (envs, n) rad: how far a joint may stray either way from that path: the
          untrusted share (:data:`GRAVITY_UNCERTAINTY`) of the sag, the dry friction
          (:data:`FRICTION_FACTOR` times the MJCF's) over ``kp``, and one period of the commanded
          speed (the drive holds each command for a period; the smoother's position integrates
          it continuously).
        - ``lead`` (envs, n) rad, signed along the motion: how far past the brake's rest point a
          joint runs ahead of its integrator while the smoother brakes it from ``after[1]`` and
          ``after[2]``: ``M_ii a_peak / kp`` (:data:`INERTIA_UNCERTAINTY` above the model's
          diagonal), ``a_peak`` the brake's peak deceleration (the acceleration limit at the
          derated drive's headroom, or ``sqrt(v j)`` for a brake too short to reach it, ``v``
          the speed once the acceleration toward the motion is ramped down), never above the
          anti-windup's bound.
        - ``beyond`` (envs,) bool: a joint commanded ``after[1]`` may run past its hard velocity
          limit, or already runs past it. A drive gives way to two things: the lag it carries
          (the integrator ahead of the estimate along the command, less the gravity sag that
          holds it steady, of which :data:`GRAVITY_UNCERTAINTY` is not trusted), whose unwinding
          peaks at :attr:`unwind` times that lag (an acceleration phase leaves it; ur5's first
          wrist joint ran 12 % past its command after one); and the torque the other joints'
          commanded accelerations push it with through the mass matrix, the sum of
          ``-M_ij a_j`` along joint ``i``'s motion over ``kd_i`` (a PI loop's speed error under
          a step disturbance torque, before its integral catches up, peaks below ``D / kd``;
          :data:`INERTIA_UNCERTAINTY` above the model; a push against the motion is not
          credited). A joint whose estimated speed is past its hard velocity limit by more than
          :data:`ESTIMATE_SIGMAS` of its error (:attr:`covariance`) runs away.

        Args:
            q: (envs, n) rad, dq: (envs, n) rad/s, the estimate.
            after: (3, envs, n), the smoother's position, velocity and acceleration after its
                step (rad, rad/s, rad/s^2).
            effort_scale: (envs, n), the drives' thermal derating.
            limits: (4, n) the envelope's limits: rows 2 and 3 the worst gravity load's share of
                the effort limit and the brake's headroom floor
                (:func:`sim2real.deploy.safety.envelope_kernel.brake_headroom`).
            stopping: (envs,) bool, the envs braking to a stop already: ``beyond`` False.

        Returns:
            Whether ``beyond`` has an env set.
        """
        import pinocchio as pin

        model, data = self._model, self._data
        for e in range(self.envs):
            self._gravity[e] = pin.computeGeneralizedGravity(model, data, q[e])
            self._mass[e] = pin.crba(model, data, q[e])  # the upper triangle is read
        return dk.velocity_drive_motion(
            self.setpoint, q, dq, after[1], after[2], self._gravity, self._mass, effort_scale,
            self._joint, limits, self._variance, self._uncertainty, self.dt, start, end, slack,
            lead, beyond, stopping,
        )  # fmt: skip

    def dynamics_at(self, q: np.ndarray):
        """For the estimate ``q`` (envs, n) rad an envelope passes every tick (the same array,
        updated in place): ``(update, gravity, mass)``, a call that evaluates Pinocchio's gravity
        torque and mass matrix (CRBA) at ``q`` as :meth:`motion` does, and the (envs, n) N m and
        (envs, n, n) kg m^2 arrays it leaves them in (one env: Pinocchio's own, read in place;
        else copies per env)."""
        import pinocchio as pin

        model, data = self._model, self._data
        gravity_at, crba = pin.computeGeneralizedGravity, pin.crba
        if self.envs == 1:
            row = q[0]

            def update() -> None:
                gravity_at(model, data, row)
                crba(model, data, row)

            return update, data.g.reshape(1, -1), data.M[None]
        rows = [q[e] for e in range(self.envs)]
        gravity, mass = self._gravity, self._mass

        def update_each() -> None:
            for e, row in enumerate(rows):
                gravity[e] = gravity_at(model, data, row)
                mass[e] = crba(model, data, row)

        return update_each, gravity, mass

    def integrate(self, command: np.ndarray) -> None:
        """One control period of the integrators under ``command`` (envs, n) rad/s, within the
        joints' range."""
        dk.integrate(self.setpoint, command, self.dt, self.lower, self.upper)
