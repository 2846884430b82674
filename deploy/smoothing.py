"""Command smoothing: jerk-limited commands with Ruckig (community edition), batched over ``envs``.

One ``ruckig.Ruckig`` instance serves the whole batch: its degrees of freedom are the ``envs * n``
joints (DoF ``e * n + j``), ``Synchronization.No`` makes them independent, ``delta_time`` is the
robot's control period and the limits are the robot's per-joint soft velocity limit (the margin
to the hard velocity limit absorbs the servo's overshoot), acceleration and jerk limits, tiled over
the envs. The result equals one instance per env to rounding (~1e-16), not bit
for bit: Ruckig recalculates only when its input changed, otherwise it samples the trajectory it
has, and a batch's input changes whenever any env's target does.

"Starts from the measured state". :meth:`CommandSmoother.sync` (and :meth:`~CommandSmoother.reset`)
writes the *measured* joint position and velocity into Ruckig's current state, with zero
acceleration. Between syncs Ruckig's own output is passed back as its next input
(``OutputParameter.pass_to_input``), so consecutive commands are continuous in position, velocity
and acceleration and never jump to follow sensor noise. The runtime syncs at start, on every
state-machine transition, and when :meth:`~CommandSmoother.tracking_error` (commanded against
measured position) exceeds its tolerance.

Modes (the robot's control modes):
    position: ``ControlInterface.Position``; target position clamped to the hard position limits
        (the community edition has no position limits), target velocity 0; the command is Ruckig's
        ``new_position``, clipped to the hard limits. Where the trajectory's position extrema leave
        the limits (a joint too fast to stop in time, typically right after a sync) the clip bites
        and ``extrema_violations`` counts it.
    velocity: ``ControlInterface.Velocity``; target velocity clamped to +-soft_velocity_limit and
        to the speed from which the joint can still stop before its *soft* limits
        (:func:`stopping_speed` of the distance left, counted in ``stopping_distance_clamps``);
        and set to 0 (Ruckig's time-optimal, hence shortest, brake) where one more period of the
        worst acceleration the jerk limit allows would leave too little room to stop. Ruckig's
        integrated position thus never passes a soft limit (unless a sync put the joint beyond
        saving), the velocity-mode analogue of the guard clamping position targets to the soft
        limits; the margin to the hard limits is left to the drive's tracking error and the
        estimator's noise. The command is Ruckig's ``new_velocity``.
    torque: no Ruckig; the command is the target clamped to +-effort_limit and rate limited to
        ``effort_limit / TORQUE_RISE_TIME`` (N m/s).

Safe stop. :meth:`CommandSmoother.safe_stop` switches the chosen envs to
``ControlInterface.Velocity`` with target velocity 0 (also in position mode) and returns the time
Ruckig predicts to reach rest;
:meth:`~CommandSmoother.step` then ignores their targets, brings them to zero velocity within the
acceleration and jerk limits and holds them there (position mode: the command settles at the
stopping position) until the next :meth:`~CommandSmoother.sync`.
"""

from __future__ import annotations

import numpy as np
from ruckig import (
    ControlInterface,
    InputParameter,
    OutputParameter,
    Result,
    Ruckig,
    RuckigError,
    Synchronization,
    Trajectory,
)

from deploy.errors import Sim2RealError
from deploy.kernels import smoothing as sk
from deploy.stateful import env_index, put, scalar, take
from robots import CONTROL_MODES, Robot

#: Torque rise time, s: full effort may be reached from zero in 50 ms at the fastest, i.e. a rate
#: limit of ``effort_limit * control_period / TORQUE_RISE_TIME`` per tick. Our choice: an order of
#: magnitude slower than the drives' current loops (~1 ms) and faster than the arm's mechanical
#: time constants, so it removes steps from the policy's output but not its intent.
TORQUE_RISE_TIME = 0.05

#: Safety factor on the worst-case stopping distance below which the position extrema of a
#: position-mode trajectory are checked exactly (farther from the limits they cannot reach them).
EXTREMA_SCREEN_FACTOR = 1.5


#: Ruckig's per-DoF input fields a smoother's state holds (``InputParameter`` attributes).
RUCKIG_INPUT_FIELDS = (
    "current_position",
    "current_velocity",
    "current_acceleration",
    "target_position",
    "target_velocity",
    "target_acceleration",
)

#: Rad. Ruckig's extrema of a trajectory that ends exactly at a limit come out up to ~1e-13 rad
#: beyond it (rounding); the check ignores excursions below this (the finest encoder of our robots
#: resolves 2 pi / 2^20 = 6e-6 rad).
EXTREMA_TOLERANCE = 1e-9


class SmoothingError(Sim2RealError, RuntimeError):
    """Ruckig could not compute a trajectory; the message has Ruckig's result and the input."""


def stopping_distance(velocity, acceleration_limit, jerk_limit):
    """Distance, rad, a joint moving at ``velocity`` (rad/s, with zero acceleration) needs to stop
    under the acceleration limit (rad/s^2) and jerk limit (rad/s^3):
    ``v^2 / (2 a) + |v| a / (2 j)``.

    Exact for a jerk-limited brake that reaches the acceleration limit (``|v| >= a^2 / j``: jerk
    ramp, constant deceleration, jerk ramp, symmetric in time, average speed ``|v| / 2`` over
    ``|v| / a + a / j``); an upper bound below (the distance is then ``|v|^1.5 / sqrt(j)``).
    Arrays broadcast.
    """
    v = np.abs(velocity)
    return v * v / (2.0 * acceleration_limit) + v * acceleration_limit / (2.0 * jerk_limit)


def stopping_speed(distance, acceleration_limit, jerk_limit, latency=0.0):
    """Largest speed, rad/s, from which a joint stops within ``distance`` (rad, >= 0) when the
    brake begins ``latency`` s (>= 0) later: the inverse of ``v latency + stopping_distance(v)``,
    ``(sqrt(b^2 + 8 a d) - b) / 2`` with ``b = a^2 / j + 2 a latency``. Arrays broadcast."""
    b = acceleration_limit**2 / jerk_limit + 2.0 * acceleration_limit * latency
    return 0.5 * (np.sqrt(b * b + 8.0 * acceleration_limit * np.maximum(distance, 0.0)) - b)


class CommandSmoother:
    """Jerk-limited commands for ``envs`` robots of ``n`` joints.

    Args:
        robot: The robot description (limits, control period).
        envs: Batch size.
        mode: ``'position'`` (rad), ``'velocity'`` (rad/s) or ``'torque'`` (N m); default the
            robot's control mode.
        reference: Run the numpy reference of :meth:`step` around Ruckig instead of the compiled
            kernels (:mod:`deploy.kernels.smoothing`, the default); both give the same numbers
            bit for bit.

    Attributes:
        command: (envs, n) the last command, in the units of the mode (overwritten by each step).
        position, velocity, acceleration: (envs, n) rad, rad/s, rad/s^2, Ruckig's state after the
            last step (the start of the next one); not maintained in torque mode.
        mean_acceleration: (envs, n) rad/s^2, the commanded acceleration averaged over the last
            step (velocity change / control period; 0 after a sync, and in torque mode): the
            control input of the state estimator over the period the command is in force.
        stopping: (envs,) bool, envs in safe stop.
        non_finite_targets, target_clamps, extrema_violations, stopping_distance_clamps: (envs,)
            int counters since :meth:`reset` (sums over the joints of ``*_per_joint``, (envs, n)):
            NaN/inf targets replaced by the previous target; targets clamped to the hard position
            limits, the velocity limits or the effort limits; position-mode ticks on which the
            trajectory's extrema left the hard limits (command clipped); velocity-mode targets
            reduced so that the joint can stop before its hard limit.

    Raises:
        ValueError: ``envs < 1`` or an unknown mode.
    """

    def __init__(self, robot: Robot, envs: int, mode: str | None = None, reference: bool = False):
        mode = robot.control_mode if mode is None else mode
        if mode not in CONTROL_MODES:
            raise ValueError(f"control mode '{mode}' is unknown; expected one of {CONTROL_MODES}")
        if envs < 1:
            raise ValueError(f"envs must be >= 1, got {envs}")
        n = robot.n_joints
        self.robot, self.envs, self.n_joints, self.mode = robot, envs, n, mode
        self.dofs = dofs = envs * n
        self.control_period = dt = robot.control_period
        shape = (envs, n)

        def tiled(values) -> np.ndarray:
            return np.tile(np.asarray(values, dtype=np.float64), envs)

        # per-DoF limits, flat (envs * n,)
        # position bounds of the commanded trajectory. Position mode: the hard limits (a backstop;
        # the guard has clamped the targets to the soft limits already). Velocity mode: the soft
        # limits, the velocity-mode analogue of the guard's clamp: only Ruckig knows its own
        # acceleration, and a joint accelerating toward a limit needs a / j more time to brake
        # than any velocity-only rule allows for; the margin to the hard limits is then left to
        # the drive's tracking error and the estimator's noise.
        if mode == "velocity":
            self._lo, self._hi = tiled(robot.soft_lower), tiled(robot.soft_upper)
        else:
            self._lo, self._hi = tiled(robot.position_lower), tiled(robot.position_upper)
        # commands stay within the soft velocity limit: the margin to the hard limit absorbs the
        # servo's tracking overshoot (see ``Robot.soft_velocity_limit``)
        self._vmax, self._amax = tiled(robot.soft_velocity_limit), tiled(robot.acceleration_limit)
        self._jmax, self._emax = tiled(robot.jerk_limit), tiled(robot.effort_limit)
        self._rate = self._emax * dt / TORQUE_RISE_TIME
        self._neg_vmax, self._neg_emax, self._neg_rate = -self._vmax, -self._emax, -self._rate
        # worst-case stopping distance from any state within the limits: ramp the acceleration
        # from a_max to 0 (speed grows by a^2 / 2j, distance <= v a / j), then brake
        v_eff = self._vmax + self._amax**2 / (2.0 * self._jmax)
        reach = v_eff * self._amax / self._jmax + stopping_distance(v_eff, self._amax, self._jmax)
        self._screen_hi = self._hi - EXTREMA_SCREEN_FACTOR * reach
        self._screen_lo = self._lo + EXTREMA_SCREEN_FACTOR * reach
        # velocity guard constants: stopping_speed(d) = 0.5 (sqrt(c^2 + 8 a d) - c)
        self._c = self._amax**2 / self._jmax
        self._c2, self._8a = self._c**2, 8.0 * self._amax
        # exact brake trigger (see _brake_needed): rows toward the upper / the lower limit
        self._sign = np.array([[1.0], [-1.0]])
        self._limits = np.stack([self._hi, self._lo])
        self._jdt, self._jdt2_2 = self._jmax * dt, self._jmax * dt**2 / 2.0
        self._jdt3_6 = self._jmax * dt**3 / 6.0
        self._inv_dt = 1.0 / dt
        self._inv_j, self._inv_2j = 1.0 / self._jmax, 0.5 / self._jmax
        self._inv_2a, self._a_2j = 0.5 / self._amax, self._amax / (2.0 * self._jmax)
        self._guard = {k: np.zeros((2, dofs)) for k in ("u", "b", "room", "t1", "t2", "t3")}
        self._unsafe = np.zeros((2, dofs), dtype=bool)

        # state and work arrays: rows of one block, the compiled step's (deploy.kernels.smoothing)
        self._w = w = np.zeros((sk.W_ROWS, dofs))
        self.command = w[sk.CMD].reshape(shape)
        self._cmd = w[sk.CMD]
        self._pos, self._vel, self._acc = w[sk.POS], w[sk.VEL], w[sk.ACC]
        self._mean_acc = w[sk.MEAN_ACC]
        self.mean_acceleration = self._mean_acc.reshape(shape)
        self.position = self._pos.reshape(shape)
        self.velocity = self._vel.reshape(shape)
        self.acceleration = self._acc.reshape(shape)
        self._cmd_position = w[sk.CMD_POSITION]  # what tracking_error compares with
        self._held = w[sk.HELD]  # last finite target
        self._raw = w[sk.RAW]
        self._raw2d = self._raw.reshape(shape)
        self._goal = w[sk.GOAL]
        self._tmp = np.zeros(dofs)
        self._tmp2d = self._tmp.reshape(shape)
        self._cmd_position2d = self._cmd_position.reshape(shape)
        self._finite = np.ones(dofs, dtype=bool)
        self._mask = np.zeros(dofs, dtype=bool)
        self._mask2 = np.zeros(dofs, dtype=bool)
        self._stop_dof = np.zeros(dofs, dtype=bool)
        self._count = np.zeros(dofs, dtype=np.int64)
        self._one_int = np.ones(dofs, dtype=np.int64)
        self.stopping = np.zeros(envs, dtype=bool)
        self._counts = counts = np.zeros((4, dofs), dtype=np.int64)
        self.non_finite_per_joint = counts[sk.NON_FINITE].reshape(shape)
        self.target_clamps_per_joint = counts[sk.TARGET_CLAMPS].reshape(shape)
        self.extrema_violations_per_joint = counts[sk.EXTREMA].reshape(shape)
        self.stopping_distance_clamps_per_joint = counts[sk.STOPPING].reshape(shape)
        self._synced = False
        self.reference = reference
        self._kernel_mode = {"position": sk.POSITION, "velocity": sk.VELOCITY}.get(mode, sk.TORQUE)
        c = np.zeros((sk.C_ROWS, dofs))
        c[sk.LO], c[sk.HI], c[sk.VMAX], c[sk.AMAX] = self._lo, self._hi, self._vmax, self._amax
        c[sk.EMAX], c[sk.RATE] = self._emax, self._rate
        c[sk.SCREEN_LO], c[sk.SCREEN_HI] = self._screen_lo, self._screen_hi
        c[sk.C], c[sk.C2], c[sk.EIGHT_A] = self._c, self._c2, self._8a
        c[sk.JDT], c[sk.JDT2_2], c[sk.JDT3_6] = self._jdt, self._jdt2_2, self._jdt3_6
        c[sk.INV_J], c[sk.INV_2J] = self._inv_j, self._inv_2j
        c[sk.INV_2A], c[sk.A_2J] = self._inv_2a, self._a_2j
        self._c_rows = c
        if not reference:  # compile (or load numba's cache) now, on copies, not in a tick
            for has_target in (True, False):
                sk.before_ruckig(
                    self._kernel_mode,
                    np.zeros(shape),
                    has_target,
                    w.copy(),
                    c,
                    counts.copy(),
                    self._stop_dof.copy(),
                    dt,
                )
            sk.after_ruckig(self._kernel_mode, True, w.copy(), c, self._inv_dt, self._mask.copy())

        if mode != "torque":
            self._ruckig = Ruckig(dofs, dt)
            self._planner = Ruckig(dofs)  # offline: predicts safe-stop durations
            self._inp = inp = InputParameter(dofs)
            self._out = OutputParameter(dofs)
            inp.synchronization = Synchronization.No
            inp.max_velocity = self._vmax
            inp.max_acceleration = self._amax
            inp.max_jerk = self._jmax
            zeros = np.zeros(dofs)
            inp.current_position = zeros
            inp.current_velocity = zeros
            inp.current_acceleration = zeros
            inp.target_position = zeros
            inp.target_velocity = zeros
            inp.target_acceleration = zeros
            self._interface = (
                ControlInterface.Position if mode == "position" else ControlInterface.Velocity
            )
            inp.control_interface = self._interface

    @property
    def commanded(self) -> np.ndarray:
        """(envs, n) rad, the commanded position :meth:`tracking_error` compares with (the last
        position command, or Ruckig's integrated position in velocity mode); a view."""
        return self._cmd_position2d

    # ------------------------------------------------------------------ counters
    @property
    def non_finite_targets(self) -> np.ndarray:
        """(envs,) NaN/inf target values replaced by the previous target."""
        return self.non_finite_per_joint.sum(axis=1)

    @property
    def target_clamps(self) -> np.ndarray:
        """(envs,) targets clamped to the hard position, velocity or effort limits."""
        return self.target_clamps_per_joint.sum(axis=1)

    @property
    def extrema_violations(self) -> np.ndarray:
        """(envs,) position-mode trajectories whose extrema left the hard limits (clipped)."""
        return self.extrema_violations_per_joint.sum(axis=1)

    @property
    def stopping_distance_clamps(self) -> np.ndarray:
        """(envs,) velocity-mode targets reduced so that the joint stops before its limit."""
        return self.stopping_distance_clamps_per_joint.sum(axis=1)

    # ------------------------------------------------------------------ state
    def _state_fields(self) -> dict[str, np.ndarray]:
        shape = (self.envs, self.n_joints)
        return {
            "command": self.command,
            "position": self.position,
            "velocity": self.velocity,
            "acceleration": self.acceleration,
            "mean_acceleration": self.mean_acceleration,
            "commanded_position": self._cmd_position2d,
            "held": self._held.reshape(shape),
            "stopping": self.stopping,
            "non_finite_per_joint": self.non_finite_per_joint,
            "target_clamps_per_joint": self.target_clamps_per_joint,
            "extrema_violations_per_joint": self.extrema_violations_per_joint,
            "stopping_distance_clamps_per_joint": self.stopping_distance_clamps_per_joint,
        }

    def _ruckig_input(self) -> dict[str, np.ndarray]:
        """Copies of Ruckig's per-DoF input, (envs, n) (the binding returns lists)."""
        if self.mode == "torque":
            return {}
        shape = (self.envs, self.n_joints)
        return {
            f"ruckig/{name}": np.asarray(getattr(self._inp, name), dtype=np.float64).reshape(shape)
            for name in RUCKIG_INPUT_FIELDS
        }

    def recalculate(self) -> None:
        """Make the next :meth:`step` calculate every trajectory afresh from Ruckig's input
        (``Ruckig.reset()``) instead of sampling the one it keeps. The two agree to ~1e-16, not
        bit for bit (module docstring); a recalculation depends on the input alone: the same
        numbers whatever the other envs of the batch, and after :meth:`load_state_dict`."""
        if self.mode != "torque":
            self._ruckig.reset()

    def state_dict(self, env: int | None = None) -> dict:
        """The smoother's state (copies; conventions of :mod:`deploy.stateful`).

        Fields, (envs, n) unless stated (length 1 for one env ``env``): ``command`` (the units of
        the mode), Ruckig's state ``position``, ``velocity``, ``acceleration`` (rad, rad/s,
        rad/s^2) and ``mean_acceleration``, ``commanded_position`` (rad), ``held`` (the last
        finite target), ``stopping`` (envs,) bool, the per-joint counters (int64); Ruckig's input
        ``ruckig/<field>`` (``RUCKIG_INPUT_FIELDS``; not in torque mode) and ``synced`` (bool,
        shared).

        Ruckig keeps the trajectory it calculated inside the ``Ruckig`` object, which its Python
        binding can neither read nor set. Taking the state therefore calls :meth:`recalculate`:
        this smoother's next step calculates from the input, as a smoother loaded from this
        state does, and both continue bit for bit alike.
        """
        out: dict = take(self._state_fields(), env)
        index = env_index(env)
        out.update({k: v[index].copy() for k, v in self._ruckig_input().items()})
        out["synced"] = bool(self._synced)
        self.recalculate()
        return out

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``): Ruckig's input is
        re-seeded (current and target position, velocity, acceleration), the per-DoF control
        interfaces follow the ``stopping`` flags, and the next step recalculates
        (:meth:`recalculate`).

        Raises:
            StateDictError: a missing field or a shape that differs; nothing is changed.
        """
        synced = scalar(state, "synced", bool)
        ruckig = self._ruckig_input()
        put({**self._state_fields(), **ruckig}, state, env)
        for key, values in ruckig.items():
            setattr(self._inp, key.split("/", 1)[1], values.reshape(-1))
        self._stop_dof[:] = np.repeat(self.stopping, self.n_joints)
        self._synced = synced
        if self.mode != "torque":
            self._set_interfaces()
        self.recalculate()

    # ------------------------------------------------------------------ lifecycle
    def reset(self, q: np.ndarray, dq: np.ndarray, effort: np.ndarray | None = None) -> None:
        """Anchor every env at its measured state, leave safe stop and zero the counters.

        Args and errors as :meth:`sync` (with ``envs=None``).
        """
        for counter in (
            self.non_finite_per_joint,
            self.target_clamps_per_joint,
            self.extrema_violations_per_joint,
            self.stopping_distance_clamps_per_joint,
        ):
            counter[:] = 0
        self.sync(q, dq, effort=effort)

    def sync(
        self,
        q: np.ndarray,
        dq: np.ndarray,
        envs: np.ndarray | None = None,
        effort: np.ndarray | None = None,
    ) -> None:
        """Anchor the trajectory of the selected envs at their *measured* state.

        Ruckig's current position and velocity become ``q`` and ``dq``, its acceleration 0; the
        held target (used in place of a non-finite one) becomes ``q`` in position mode and 0 in
        velocity mode; the envs leave safe stop. The next :meth:`step` therefore starts exactly
        at the measured state: its command differs from ``q`` by about ``dq * control_period``.
        In torque mode the rate limit starts from ``effort``.

        Args:
            q: (envs, n) rad, measured (estimated) joint positions.
            dq: (envs, n) rad/s, measured (estimated) joint velocities.
            envs: Optional boolean mask (envs,) or indices of the envs to sync; default all.
            effort: (envs, n) N m, torque mode only: the torque in force; default the gravity
                torque at ``q`` (``robot.gravity_torque``), which holds the arm where it is.

        Raises:
            ValueError: wrong shapes, or non-finite values in a synced env.
        """
        shape = (self.envs, self.n_joints)
        sel = np.zeros(self.envs, dtype=bool)
        sel[np.arange(self.envs) if envs is None else envs] = True
        q = np.asarray(q, dtype=np.float64)
        dq = np.asarray(dq, dtype=np.float64)
        if q.shape != shape or dq.shape != shape:
            raise ValueError(f"sync: q and dq must be {shape}, got {q.shape} and {dq.shape}")
        if not (np.isfinite(q[sel]).all() and np.isfinite(dq[sel]).all()):
            raise ValueError("sync: q and dq must be finite in the synced envs")
        dof = np.repeat(sel, self.n_joints)
        self.stopping[sel] = False
        self._stop_dof[dof] = False
        if self.mode == "torque":
            if effort is None:
                effort = np.zeros(shape)
                for e in np.flatnonzero(sel):
                    effort[e] = self.robot.gravity_torque(q[e])
            effort = np.asarray(effort, dtype=np.float64)
            if effort.shape != shape or not np.isfinite(effort[sel]).all():
                raise ValueError(f"sync: effort must be {shape} and finite in the synced envs")
            self._cmd[dof] = effort.reshape(-1)[dof]
            self._held[dof] = self._cmd[dof]
        else:
            inp = self._inp
            pos = np.array(inp.current_position)
            vel = np.array(inp.current_velocity)
            acc = np.array(inp.current_acceleration)
            pos[dof], vel[dof], acc[dof] = q.reshape(-1)[dof], dq.reshape(-1)[dof], 0.0
            inp.current_position, inp.current_velocity, inp.current_acceleration = pos, vel, acc
            self._pos[:], self._vel[:], self._acc[:] = pos, vel, acc
            self._mean_acc[dof] = 0.0
            self._cmd_position[dof] = pos[dof]
            self._held[dof] = pos[dof] if self.mode == "position" else 0.0
            self._cmd[dof] = pos[dof] if self.mode == "position" else vel[dof]
            self._set_interfaces()
        self._synced = True

    def safe_stop(self, envs: np.ndarray | None = None) -> np.ndarray:
        """Bring the selected envs to zero velocity and hold them there, until the next sync.

        Position and velocity mode: their DoFs switch to ``ControlInterface.Velocity`` with target
        velocity and acceleration 0, starting from Ruckig's current state (the commands stay
        continuous); their targets are ignored by :meth:`step` (pass anything, or None).
        Torque mode: the smoother has no model to brake with; the envs are only marked, and the
        runtime's braking torque (e.g. gravity compensation plus damping) keeps going through the
        rate limit of :meth:`step`.

        Args:
            envs: Optional boolean mask (envs,) or indices; default all.

        Returns:
            (envs,) s, the time Ruckig predicts until every joint of the env is at rest, counted
            from the last command (the command of the k-th step after this call is the stopping
            trajectory at ``k * control_period``); 0 for envs not stopping, NaN in torque mode.

        Raises:
            RuntimeError: before the first :meth:`reset`/:meth:`sync`.
            SmoothingError: Ruckig cannot compute the stop.
        """
        if not self._synced:
            raise RuntimeError("CommandSmoother.safe_stop before reset(q, dq)")
        sel = np.zeros(self.envs, dtype=bool)
        sel[np.arange(self.envs) if envs is None else envs] = True
        self.stopping |= sel
        self._stop_dof[:] = np.repeat(self.stopping, self.n_joints)
        if self.mode == "torque":
            return np.where(self.stopping, np.nan, 0.0)
        self._set_interfaces()
        self._inp.target_velocity = np.zeros(self.dofs)
        trajectory = Trajectory(self.dofs)
        try:
            result = self._planner.calculate(self._inp, trajectory)
        except RuckigError as exc:
            raise SmoothingError(f"Ruckig rejected the safe-stop input: {exc}") from exc
        if result not in (Result.Working, Result.Finished):
            raise SmoothingError(f"Ruckig returned {result!r} for the safe stop")
        durations = np.asarray(trajectory.independent_min_durations).reshape(self.envs, -1)
        stop_dofs = self._stop_dof.reshape(self.envs, -1)
        return np.where(stop_dofs, durations, 0.0).max(axis=1)

    # ------------------------------------------------------------------ the tick
    def step(self, target: np.ndarray | None, out: np.ndarray | None = None) -> np.ndarray:
        """One control period: the next command toward ``target``.

        Args:
            target: (envs, n) in the units of the mode (rad, rad/s or N m), or None to keep the
                previous targets. Non-finite entries are replaced by the previous target of that
                joint (counted in ``non_finite_targets``); they never reach Ruckig. Targets of
                envs in safe stop are ignored.
            out: Optional (envs, n) array for the command; default ``self.command``.

        Returns:
            (envs, n) the command: position mode rad, velocity mode rad/s, torque mode N m.

        Raises:
            RuntimeError: before the first :meth:`reset`/:meth:`sync`.
            ValueError: ``target`` of the wrong shape.
            SmoothingError: Ruckig returned an error (or raised ``RuckigError``).
        """
        if not self._synced:
            raise RuntimeError("CommandSmoother.step before reset(q, dq)")
        if target is not None and target.shape != self.command.shape:
            raise ValueError(f"target: expected shape {self.command.shape}, got {target.shape}")
        if not self.reference:
            return self._step_compiled(target, out)
        raw, mask = self._raw, self._mask
        if target is not None:
            np.copyto(self._raw2d, target)
            np.isfinite(raw, out=self._finite)
            if np.count_nonzero(self._finite) != self.dofs:
                np.logical_not(self._finite, out=mask)
                np.logical_and(mask, ~self._stop_dof, out=mask)
                self._increment(self.non_finite_per_joint, mask)
                np.copyto(raw, self._held, where=~self._finite)
            np.copyto(self._held, raw)
        else:
            np.copyto(raw, self._held)
        if self.mode == "torque":
            self._step_torque()
        else:
            np.copyto(self._mean_acc, self._vel)  # Ruckig's velocity before the step
            if self.mode == "position":
                self._step_position()
            else:
                self._step_velocity()
            np.subtract(self._vel, self._mean_acc, out=self._mean_acc)
            self._mean_acc *= self._inv_dt
        if out is None:
            return self.command
        np.copyto(out, self.command)
        return out

    def _step_compiled(self, target: np.ndarray | None, out: np.ndarray | None) -> np.ndarray:
        """:meth:`step` with the kernels of :mod:`deploy.kernels.smoothing` around Ruckig."""
        mode, w = self._kernel_mode, self._w
        has = target is not None
        sk.before_ruckig(
            mode,
            target if has else self.command,
            has,
            w,
            self._c_rows,
            self._counts,
            self._stop_dof,
            self.control_period,
        )
        if mode != sk.TORQUE:
            result = self._out
            if mode == sk.POSITION:
                self._inp.target_position = self._goal
                self._update()
                self._cmd[:] = result.new_position
                self._vel[:] = result.new_velocity
            else:
                self._inp.target_velocity = self._goal
                self._update()
                self._cmd[:] = result.new_velocity
                self._pos[:] = result.new_position
            self._acc[:] = result.new_acceleration
            new = mode == sk.POSITION and result.new_calculation
            if sk.after_ruckig(mode, new, w, self._c_rows, self._inv_dt, self._mask):
                self._count_extrema()
            result.pass_to_input(self._inp)
        if out is None:
            return self.command
        np.copyto(out, self.command)
        return out

    def tracking_error(self, q: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(envs,) rad, ``max_j |commanded position - q|``: how far the command has drifted from
        the measured pose ``q`` (envs, n). The commanded position is the last position command
        (position mode) or Ruckig's integrated position (velocity mode); 0 in torque mode, which
        commands no position. The runtime syncs the envs above its tolerance."""
        out = np.empty(self.envs) if out is None else out
        if self.mode == "torque":
            out.fill(0.0)
            return out
        np.subtract(self._cmd_position2d, q, out=self._tmp2d)
        np.abs(self._tmp2d, out=self._tmp2d)
        return np.max(self._tmp2d, axis=1, out=out)

    def anchor(self, q: np.ndarray, tolerance: float, out: np.ndarray | None = None) -> np.ndarray:
        """Velocity mode: keep Ruckig's integrated position within ``tolerance`` of ``q``.

        Ruckig integrates its own velocity commands. A drive that cannot follow them (its torque
        saturates, an obstacle or a push holds the joint; its anti-windup then holds its own
        integrator back) leaves the joint behind that integral for good, and without an anchor
        the gap only grows over hours of operation: the soft-limit brake and the guard's
        stopping bounds, which read this position, then stop the joint in parts of its range
        it is nowhere near. Each joint's position is clamped into ``[q - tolerance,
        q + tolerance]``; velocity and acceleration are untouched, so the velocity command stays
        continuous. A no-op in position and torque mode (position mode re-syncs through
        :meth:`tracking_error`).

        Args:
            q: (envs, n) measured (estimated) joint positions, rad.
            tolerance: rad, the largest lag of the drive behind its command accepted as
                tracking (:data:`deploy.runtime.VELOCITY_TRACKING_TOLERANCE` in the runtime).
            out: Optional (envs,) int64 array; 1 where an env's position was moved, else 0.

        Returns:
            (envs,) int64, 1 for the envs whose position was moved.
        """
        out = np.zeros(self.envs, dtype=np.int64) if out is None else out
        out.fill(0)
        if self.mode != "velocity":
            return out
        pos, tmp = self.position, self._tmp2d
        np.subtract(pos, q, out=tmp)
        np.abs(tmp, out=tmp)
        if tmp.max() <= tolerance:  # the common case
            return out
        np.greater(tmp, tolerance, out=self._mask.reshape(pos.shape))
        out += self._mask.reshape(pos.shape).any(axis=1)
        np.minimum(np.maximum(pos, q - tolerance, out=pos), q + tolerance, out=pos)
        self._inp.current_position = self._pos
        np.copyto(self._cmd_position, self._pos)
        return out

    # ------------------------------------------------------------------ internals
    def _increment(self, counter: np.ndarray, mask: np.ndarray) -> None:
        flat = counter.reshape(-1)
        np.add(flat, self._one_int, out=self._count)
        np.copyto(flat, self._count, where=mask)

    def _count_changed(self, counter: np.ndarray, before: np.ndarray, after: np.ndarray) -> None:
        np.not_equal(before, after, out=self._mask2)
        if np.count_nonzero(self._mask2):
            np.logical_and(self._mask2, ~self._stop_dof, out=self._mask2)
            self._increment(counter, self._mask2)

    def _set_interfaces(self) -> None:
        """Per-DoF control interface: velocity (target 0) for stopping envs."""
        inp = self._inp
        if not self.stopping.any():
            inp.per_dof_control_interface = None
            inp.control_interface = self._interface
        elif self.stopping.all():
            inp.per_dof_control_interface = None
            inp.control_interface = ControlInterface.Velocity
        else:
            inp.per_dof_control_interface = [
                ControlInterface.Velocity if s else self._interface for s in self._stop_dof
            ]

    def _update(self) -> None:
        try:
            result = self._ruckig.update(self._inp, self._out)
        except RuckigError as exc:
            raise SmoothingError(f"Ruckig rejected the input: {exc}") from exc
        if result != Result.Working and result != Result.Finished:
            raise SmoothingError(
                f"Ruckig returned {result!r}: current position {self._pos.tolist()}, velocity "
                f"{self._vel.tolist()}, acceleration {self._acc.tolist()}, targets "
                f"{self._goal.tolist()}"
            )

    def _step_position(self) -> None:
        raw, goal, out, cmd = self._raw, self._goal, self._out, self._cmd
        np.minimum(np.maximum(raw, self._lo, out=goal), self._hi, out=goal)
        self._count_changed(self.target_clamps_per_joint, raw, goal)
        self._inp.target_position = goal
        self._update()
        cmd[:] = out.new_position
        self._pos[:] = cmd
        self._vel[:] = out.new_velocity
        self._acc[:] = out.new_acceleration
        if out.new_calculation:
            self._check_extrema()
        np.minimum(np.maximum(cmd, self._lo, out=cmd), self._hi, out=cmd)
        np.copyto(self._cmd_position, cmd)
        out.pass_to_input(self._inp)

    def _near_limits(self) -> bool:
        """``_mask`` = DoFs within ``EXTREMA_SCREEN_FACTOR`` worst-case stopping distances of a
        hard limit, or faster than the velocity limit (possible right after a sync): only these
        can reach a limit within one trajectory. Returns whether any."""
        near, tmp = self._mask, self._mask2
        np.greater(self._pos, self._screen_hi, out=near)
        np.less(self._pos, self._screen_lo, out=tmp)
        np.logical_or(near, tmp, out=near)
        np.abs(self._vel, out=self._tmp)
        np.greater(self._tmp, self._vmax, out=tmp)
        np.logical_or(near, tmp, out=near)
        return bool(np.count_nonzero(near))

    def _check_extrema(self) -> None:
        """Count the DoFs whose new trajectory leaves the hard limits (screened by
        :meth:`_near_limits`: far from the limits the extrema are not even computed)."""
        if self._near_limits():
            self._count_extrema()

    def _count_extrema(self) -> None:
        """Count the DoFs marked in ``_mask`` whose new trajectory leaves the hard limits."""
        near = self._mask
        extrema = self._out.trajectory.position_extrema
        for i in np.flatnonzero(near):
            bound = extrema[i]
            if (
                bound.min < self._lo[i] - EXTREMA_TOLERANCE
                or bound.max > self._hi[i] + EXTREMA_TOLERANCE
            ):
                self.extrema_violations_per_joint.reshape(-1)[i] += 1

    def _step_velocity(self) -> None:
        raw, goal, out, tmp = self._raw, self._goal, self._out, self._tmp
        np.minimum(np.maximum(raw, self._neg_vmax, out=goal), self._vmax, out=goal)
        self._count_changed(self.target_clamps_per_joint, raw, goal)
        np.copyto(goal, 0.0, where=self._stop_dof)
        np.copyto(raw, goal)
        if self._near_limits():
            # stopping guard 1 (smooth): |v_target| <= stopping_speed(distance to the limit ahead)
            np.subtract(self._hi, self._pos, out=tmp)
            self._stopping_speed(tmp)
            np.minimum(goal, tmp, out=goal)
            np.subtract(self._pos, self._lo, out=tmp)
            self._stopping_speed(tmp)
            np.negative(tmp, out=tmp)
            np.maximum(goal, tmp, out=goal)
            # stopping guard 2 (exact): brake now where the next state could not stop in time
            if self._brake_needed():
                unsafe = self._unsafe
                np.minimum(goal, 0.0, out=tmp)
                np.copyto(goal, tmp, where=unsafe[0])
                np.maximum(goal, 0.0, out=tmp)
                np.copyto(goal, tmp, where=unsafe[1])
        self._count_changed(self.stopping_distance_clamps_per_joint, raw, goal)
        self._inp.target_velocity = goal
        self._update()
        self._cmd[:] = out.new_velocity
        self._pos[:] = out.new_position
        self._vel[:] = self._cmd
        self._acc[:] = out.new_acceleration
        np.copyto(self._cmd_position, self._pos)
        out.pass_to_input(self._inp)

    def _brake_needed(self) -> bool:
        """Fill ``_unsafe`` (2, dofs): rows toward the upper / lower limit, True where, after one
        more period of the worst acceleration the jerk limit allows, the joint could no longer
        stop before the limit. Ruckig's brake to velocity 0 is time-optimal, hence the shortest;
        its distance from velocity u and acceleration b toward the limit is at most
        ``u1 b1 / j + b1^3 / (3 j^2) + stopping_distance(u1 + b1^2 / (2 j))`` (ramp the
        acceleration to 0, then brake; ``u1, b1`` the worst next state). Returns whether any."""
        w, dt = self._guard, self.control_period
        u, b, room, t1, t2, t3 = w["u"], w["b"], w["room"], w["t1"], w["t2"], w["t3"]
        np.multiply(self._sign, self._vel, out=u)
        np.multiply(self._sign, self._acc, out=b)
        np.subtract(self._limits, self._pos, out=room)
        np.multiply(room, self._sign, out=room)
        # worst next displacement u dt + b dt^2 / 2 + j dt^3 / 6 uses up room
        np.multiply(u, dt, out=t1)
        np.multiply(b, 0.5 * dt * dt, out=t2)
        np.add(t1, t2, out=t1)
        np.add(t1, self._jdt3_6, out=t1)
        np.subtract(room, t1, out=room)
        # worst next speed u1 = max(u + b dt + j dt^2 / 2, 0), acceleration b1 = clip(b + j dt)
        np.multiply(b, dt, out=t2)
        np.add(t2, u, out=t2)
        np.add(t2, self._jdt2_2, out=t2)
        np.maximum(t2, 0.0, out=t2)
        np.add(b, self._jdt, out=t3)
        np.minimum(np.maximum(t3, 0.0, out=t3), self._amax, out=t3)
        # braking distance from (u1, b1)
        np.multiply(t3, self._inv_j, out=t1)  # b1 / j
        np.multiply(t2, t1, out=b)  # u1 b1 / j
        np.multiply(t1, t1, out=t1)
        np.multiply(t1, t3, out=t1)
        np.multiply(t1, 1.0 / 3.0, out=t1)  # b1^3 / (3 j^2)
        np.add(b, t1, out=b)
        np.multiply(t3, t3, out=t1)
        np.multiply(t1, self._inv_2j, out=t1)
        np.add(t1, t2, out=t1)  # u2 = u1 + b1^2 / (2 j)
        np.multiply(t1, self._inv_2a, out=t2)
        np.add(t2, self._a_2j, out=t2)
        np.multiply(t2, t1, out=t2)  # stopping_distance(u2)
        np.add(b, t2, out=b)
        np.greater(b, room, out=self._unsafe)
        return bool(np.count_nonzero(self._unsafe))

    def _stopping_speed(self, distance: np.ndarray) -> None:
        """In place: ``distance`` (rad) -> :func:`stopping_speed` (rad/s), no allocation."""
        np.maximum(distance, 0.0, out=distance)
        np.multiply(distance, self._8a, out=distance)
        np.add(distance, self._c2, out=distance)
        np.sqrt(distance, out=distance)
        np.subtract(distance, self._c, out=distance)
        np.multiply(distance, 0.5, out=distance)

    def _step_torque(self) -> None:
        raw, goal, tmp, cmd = self._raw, self._goal, self._tmp, self._cmd
        np.clip(raw, self._neg_emax, self._emax, out=goal)
        self._count_changed(self.target_clamps_per_joint, raw, goal)
        np.subtract(goal, cmd, out=tmp)
        np.clip(tmp, self._neg_rate, self._rate, out=tmp)
        np.add(cmd, tmp, out=cmd)
