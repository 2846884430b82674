"""The command smoother, :class:`CommandSmoother`: the limits, work arrays, lifecycle and tick
(the kernels of :mod:`sim2real.deploy.smoothing.kernel` around Ruckig); Ruckig's call and state dict:
:class:`~sim2real.deploy.smoothing.ruckig_state.RuckigState`; numpy reference:
:class:`~sim2real.deploy.smoothing.reference.ReferenceSmoother`."""

from __future__ import annotations

import numpy as np
from ruckig import Result, Trajectory

from sim2real.deploy.core.velocity_drive import velocity_drives
from sim2real.deploy.kernels.calls import bind
from sim2real.deploy.smoothing import kernel as sk
from sim2real.deploy.smoothing.braking import stopping_distance
from sim2real.deploy.smoothing.ruckig_state import (
    RUCKIG_ERRORS,
    RuckigState,
    SmoothingError,
    doubles,
)
from sim2real.robots import CONTROL_MODES, Robot

#: Torque rise time, s: full effort may be reached from zero in 50 ms at the fastest, i.e. a rate
#: limit of ``effort_limit * control_period / TORQUE_RISE_TIME`` per tick. Our choice: an order of
#: magnitude slower than the drives' current loops (~1 ms) and faster than the arm's mechanical
#: time constants, so it removes steps from the policy's output but not its intent.
TORQUE_RISE_TIME = 0.05

#: Safety factor on the worst-case stopping distance below which the position extrema of a
#: position-mode trajectory are checked exactly (farther from the limits they cannot reach them).
EXTREMA_SCREEN_FACTOR = 1.5


#: ``wheels``' default: the robot's own velocity drives
_DRIVES = object()


class CommandSmoother(RuckigState):
    """Jerk-limited commands for ``envs`` robots of ``n`` joints.

    :meth:`sync` (and :meth:`reset`) writes the *measured* position and velocity into Ruckig's
    state, zero acceleration; between syncs Ruckig's output is its next input, so commands are
    continuous and never follow sensor noise. The runtime syncs at start, on every state-machine
    transition, and when :meth:`tracking_error` exceeds its tolerance.

    Modes (the robot's control modes):

    - position: ``ControlInterface.Position``; the target clamped to the hard position limits
      (the community edition has none), target velocity 0; the command is Ruckig's
      ``new_position``, clipped to the hard limits. Where the trajectory's extrema leave the
      limits (a joint too fast to stop in time, typically right after a sync) the clip bites and
      ``extrema_violations`` counts it.
    - velocity: ``ControlInterface.Velocity``; the target velocity clamped to
      +-command_velocity_limit and to the speed from which the joint can still stop before its
      *soft* limits (:func:`~sim2real.deploy.smoothing.braking.stopping_speed` of the distance left,
      counted in ``stopping_distance_clamps``), and set to 0 (Ruckig's time-optimal brake) where
      one more period of the worst acceleration the jerk limit allows would leave too little room
      to stop: Ruckig's integrated position never passes a soft limit (unless a sync put the joint
      beyond saving). The command is Ruckig's ``new_velocity``.
    - torque: no Ruckig; the target clamped to +-effort_limit and rate limited to
      ``effort_limit / TORQUE_RISE_TIME`` (N m/s).

    Safe stop: :meth:`safe_stop` switches the chosen envs to ``ControlInterface.Velocity`` with
    target velocity 0 (also in position mode) and returns the time Ruckig predicts to reach rest;
    :meth:`step` then ignores their targets, brings them to rest within the acceleration and jerk
    limits and holds them (position mode: at the stopping position) until the next :meth:`sync`.

    Args:
        robot: The robot description (limits, control period).
        envs: Batch size.
        mode: ``'position'`` (rad), ``'velocity'`` (rad/s) or ``'torque'`` (N m); default the
            robot's control mode.
        bounded: Position mode: the targets and the command are clamped to the hard position
            limits (default), True or False for every joint or (n,) bool per joint. False on a
            joint whose drive runs a PD law on its target (the robot kind's
            :meth:`DriveTargets.bounded <sim2real.deploy.kinds.targets.DriveTargets.bounded>`):
            a target past the range is a torque request, which the guard judges
            (:mod:`sim2real.deploy.safety.pd_barrier`), and the drive takes.
        wheels: The command stage of the velocity-driven joints (the robot kind's
            :meth:`~sim2real.deploy.robot_kind.RobotKind.wheel_drives`, which the runtime
            passes), or None; default
            :func:`~sim2real.deploy.core.velocity_drive.velocity_drives` of the robot.

    Attributes:
        command: (envs, n) the last command, in the units of the mode (overwritten by each step).
        position, velocity, acceleration: (envs, n) rad, rad/s, rad/s^2, Ruckig's state after the
            last step (the start of the next one); not maintained in torque mode.
        mean_acceleration: (envs, n) rad/s^2, the commanded acceleration averaged over the last
            step (velocity change / control period; 0 after a sync, and in torque mode): the
            control input of the state estimator over the period the command is in force.
        stopping: (envs,) bool, envs in safe stop.
        trajectory: (3, envs, n) ``position``, ``velocity``, ``acceleration`` as one view.
        before: (3, envs, n) the same before the last step (where :meth:`brake` starts).
        non_finite_targets, target_clamps, extrema_violations, stopping_distance_clamps: (envs,)
            int counters since :meth:`reset` (sums over the joints of ``*_per_joint``, (envs, n)):
            NaN/inf targets replaced by the previous target; targets clamped to the hard position
            limits, the velocity limits or the effort limits; position-mode ticks on which the
            trajectory's extrema left the hard limits (command clipped); velocity-mode targets
            reduced so that the joint can stop before its hard limit.

    Raises:
        ValueError: ``envs < 1`` or an unknown mode.
    """

    def __init__(
        self,
        robot: Robot,
        envs: int,
        mode: str | None = None,
        bounded: bool | np.ndarray = True,
        wheels=_DRIVES,
    ):
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
        # Position mode without ``bounded`` (a PD-target robot): none; its targets are torque
        # requests, and the guard judges them by their predicted motion (safety/pd_barrier.py).
        if mode == "velocity":
            self._lo, self._hi = tiled(robot.soft_lower), tiled(robot.soft_upper)
        else:  # position (bounded per joint) or torque mode
            hard = np.broadcast_to(bounded, (n,)) | (mode != "position")
            self._lo = tiled(np.where(hard, robot.position_lower, -np.inf))
            self._hi = tiled(np.where(hard, robot.position_upper, np.inf))
        # commands stay within the command velocity limit: the soft velocity limit, whose margin
        # to the hard limit absorbs the servo's tracking overshoot, or a legged robot's PD
        # targets' own (see ``Robot.command_velocity_limit``)
        self._vmax = tiled(robot.command_velocity_limit)
        self._amax = tiled(robot.acceleration_limit)
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
        # exact brake trigger (ReferenceSmoother._brake_needed): rows toward the upper / lower limit
        self._sign = np.array([[1.0], [-1.0]])
        self._limits = np.stack([self._hi, self._lo])
        self._jdt, self._jdt2_2 = self._jmax * dt, self._jmax * dt**2 / 2.0
        self._jdt3_6 = self._jmax * dt**3 / 6.0
        self._inv_dt = 1.0 / dt
        self._inv_j, self._inv_2j = 1.0 / self._jmax, 0.5 / self._jmax
        self._inv_2a, self._a_2j = 0.5 / self._amax, self._amax / (2.0 * self._jmax)
        self._guard = {k: np.zeros((2, dofs)) for k in ("u", "b", "room", "t1", "t2", "t3")}
        self._unsafe = np.zeros((2, dofs), dtype=bool)

        # state and work arrays: rows of one block, the compiled step's (sim2real.deploy.smoothing.kernel)
        self._w = w = np.zeros((sk.W_ROWS, dofs))
        self.command = w[sk.CMD].reshape(shape)
        self._cmd = w[sk.CMD]
        self._pos, self._vel, self._acc = w[sk.POS], w[sk.VEL], w[sk.ACC]
        # the rows Ruckig's new state lands in, as ctypes arrays over their memory: a list of
        # floats (what the binding returns) is copied into one faster than into a numpy row,
        # the same doubles; they keep ``w`` alive
        self._cmd_in, self._pos_in, self._vel_in, self._acc_in = (
            doubles(w, row) for row in (sk.CMD, sk.POS, sk.VEL, sk.ACC)
        )
        self._mean_acc = w[sk.MEAN_ACC]
        self.mean_acceleration = self._mean_acc.reshape(shape)
        self.position = self._pos.reshape(shape)
        self.velocity = self._vel.reshape(shape)
        self.acceleration = self._acc.reshape(shape)
        self.trajectory = w[sk.POS : sk.ACC + 1].reshape(3, envs, n)
        self._cmd_position = w[sk.CMD_POSITION]  # what tracking_error compares with
        self._held = w[sk.HELD]  # last finite target
        self._raw = w[sk.RAW]
        self._raw2d = self._raw.reshape(shape)
        self._goal = w[sk.GOAL]
        # Ruckig's state (position, velocity, acceleration) before the last step: the start of
        # the brake that may replace it (brake) and of the guard's motion envelope
        self._before = w[sk.BEFORE : sk.BEFORE + 3]
        self.before = self._before.reshape(3, envs, n)
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
        # velocity-driven joints (wheels) in position mode: their command is a speed, braked to
        # 0 rad/s in a safe stop (the robot kind's, a wheel-legged robot's)
        self.wheels = velocity_drives(robot, envs, mode) if wheels is _DRIVES else wheels
        #: (envs,) bool: the envs whose targets the runtime commands as emitted this tick
        #: (:meth:`follow`; its RUNNING envs, set before :meth:`step`): their wheels unclamped
        self.follow_envs = np.zeros(envs, dtype=bool)
        # PD targets the policy was trained to step (follow): its position-driven joints
        self._follow_joints = ~np.asarray(robot.velocity_driven, dtype=bool)
        self._follow_mask = np.zeros(shape, dtype=bool)
        self._follow_flat = self._follow_mask.reshape(-1)
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
        # the kernels bound to the target and out of the last step (_step); unbound yet
        self._bound_target = self._bound_out = self
        self._warm_up()

        if mode != "torque":
            self._build_ruckig()

    def _warm_up(self) -> None:
        """Compile the kernels of :mod:`sim2real.deploy.smoothing.kernel` (or load numba's cache) now, on
        copies of the work arrays, not in a tick."""
        w, c, shape = self._w, self._c_rows, (self.envs, self.n_joints)
        for has_target in (True, False):
            sk.before_ruckig(
                self._kernel_mode,
                np.zeros(shape),
                has_target,
                w.copy(),
                c,
                self._counts.copy(),
                self._stop_dof.copy(),
                self.control_period,
                np.zeros(shape),
            )
        sk.after_ruckig(
            self._kernel_mode, True, w.copy(), c, self._inv_dt, self._mask.copy(), np.zeros(shape)
        )

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
        except RUCKIG_ERRORS as exc:
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
        if (
            target is not self._bound_target
            and target is not None
            and (target.shape != self.command.shape)
        ):  # the bound target's shape was checked when it was bound
            raise ValueError(f"target: expected shape {self.command.shape}, got {target.shape}")
        return self._step(target, out)

    def _step(self, target: np.ndarray | None, out: np.ndarray | None) -> np.ndarray:
        """:meth:`step` after its checks: the kernels of :mod:`sim2real.deploy.smoothing.kernel` around
        Ruckig (which also note Ruckig's state before the step in :attr:`before` and write the
        command to ``out``), bound (:mod:`sim2real.deploy.kernels.calls`) to the arrays of the last
        call: a runtime passes the same ones every tick."""
        if target is not self._bound_target or out is not self._bound_out:
            self._bind_step(target, out)
        self._before_ruckig()
        mode = self._kernel_mode
        if mode == sk.VELOCITY:
            inp, result = self._inp, self._out
            inp.target_velocity = self._goal.tolist()  # pybind converts a list faster
            self._update()
            self._cmd_in[:] = result.new_velocity
            self._pos_in[:] = result.new_position
            self._acc_in[:] = result.new_acceleration
            self._after_ruckig()
            result.pass_to_input(inp)
        elif mode == sk.POSITION:
            inp, result = self._inp, self._out
            if self.wheels is not None:  # Ruckig holds a wheel at rest; its command is a speed
                self.wheels.hold_goal(self._goal, self.position)
            inp.target_position = self._goal.tolist()  # pybind converts a list faster
            self._update()
            self._cmd_in[:] = result.new_position
            self._vel_in[:] = result.new_velocity
            self._acc_in[:] = result.new_acceleration
            near = self._after_new() if result.new_calculation else self._after_ruckig()
            if near:
                self._count_extrema()
            result.pass_to_input(inp)
            if self.wheels is not None:
                dest = self.command if out is None else out
                counts, free = self.target_clamps_per_joint, self.follow_envs
                self.wheels.command(target, dest, self.stopping, counts, free)
        return self.command if out is None else out

    def _bind_step(self, target: np.ndarray | None, out: np.ndarray | None) -> None:
        """Bind the kernels of :meth:`_step` to ``target`` and ``out`` (either may be None)."""
        has = target is not None
        dest = self.command if out is None else out
        mode, w, c, mask = self._kernel_mode, self._w, self._c_rows, self._mask
        inv_dt = self._inv_dt
        self._before_ruckig = bind(
            sk.before_ruckig, mode, target if has else self.command, has, w, c, self._counts,
            self._stop_dof, self.control_period, dest,
        )  # fmt: skip
        # after Ruckig's step, without and with a new calculation (the extrema's screen)
        self._after_ruckig = bind(sk.after_ruckig, mode, False, w, c, inv_dt, mask, dest)
        self._after_new = bind(sk.after_ruckig, mode, True, w, c, inv_dt, mask, dest)
        self._bound_target, self._bound_out = target, out

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
