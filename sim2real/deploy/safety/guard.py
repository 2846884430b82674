"""SafetyGuard: every target is checked with Pinocchio before it may reach the smoother.

The checks are listed in :mod:`sim2real.deploy.safety.checks` (limits: :mod:`~sim2real.deploy.safety.limits`,
velocity band: :mod:`~sim2real.deploy.safety.velocity`, the checks at the predicted state:
:mod:`~sim2real.deploy.safety.predicted`), each with its own counter (``SafetyGuard.counts[name]``,
(envs,) int64). A clamp changes the target; a reject holds the env: the last accepted target in
position mode, zero velocity in velocity mode, gravity compensation with a brake in torque mode.
The predicted next state is the target itself in position mode, ``q + v dt`` in velocity mode
and ``q + dq dt`` in torque mode.

A target is not the path to it: after the smoother's step, :meth:`SafetyGuard.check_motion`
certifies the motion the robot is committed to with the motion envelope
(:mod:`sim2real.deploy.safety.envelope`) and brakes the envs it cannot certify, counted as
``self_collision`` or ``workspace`` interventions (position mode, fixed base;
:mod:`sim2real.deploy.safety.guard_motion`).

Speed: the per-env Pinocchio calls run only when an exact bound says they could fire: every point
moves at most ``sweep * sum|dq_i|`` (m) when the joints move by ``dq`` (rad), the end effector at
most ``sum lever_i |dq_i|`` (:func:`end_effector_lever`), a collision pair's distance at most
``weights_p @ |dq|`` (:func:`collision_pair_weights`), and gravity stays below a per-joint bound
(the masses beyond the joint at their longest lever). The outcome is exactly that of checking
every tick; only the cost differs. Collision geometry: the MJCF geoms (the plant keeps them at
``contype="0"``, so Pinocchio files them as visual geometry) and the pairs named in robot.toml.
"""

from __future__ import annotations

import warnings

import numpy as np
import pinocchio as pin
from numba.core.errors import NumbaExperimentalFeatureWarning

from sim2real.deploy.core.state import RobotState
from sim2real.deploy.core.stateful import put, take
from sim2real.deploy.kernels.calls import bind
from sim2real.deploy.kinds import robot_kind
from sim2real.deploy.safety import kernel as gk
from sim2real.deploy.safety.check import (
    ACC,
    EFFORT,
    LIM_ROWS,
    LOWER,
    MODES,
    SOFT_LOWER,
    SOFT_UPPER,
    TORQUE,
    UPPER,
    VEL,
)
from sim2real.deploy.safety.checks import CHECKS, GUARD_CHECKS, PREPARING, row
from sim2real.deploy.safety.collision import collision_model, collision_query
from sim2real.deploy.safety.drive import VelocityDrive
from sim2real.deploy.safety.envelope import MotionEnvelope
from sim2real.deploy.safety.guard_motion import MotionCheck
from sim2real.deploy.safety.torque_drive import TorqueDrive
from sim2real.robots import Robot
from sim2real.robots.chain_bounds import (
    collision_pair_weights,
    end_effector_lever,
    end_effector_reach,
    motion_bounds,
)
from sim2real.robots.thermal import EffortDerating

#: Slack of the screens, m (round-off of the kinematics): a check runs when within it.
SCREEN_MARGIN = 1e-9
# rad: a position target this close past a hard limit is at the limit. An absolute position
# action of exactly +-1 maps to ``offset +- scale`` (PolicySpec), which float rounding can put
# 1 ulp past the limit (4.4e-16 rad on so101's wrist_roll); that is a full action, not a
# crossing. Far below any encoder count (1.5e-3 rad at 4096 counts/rev).
TARGET_TOLERANCE = 1e-9


class SafetyGuard(MotionCheck):
    """Clamp or reject targets that would break a limit; count every intervention.

    Args:
        robot: The robot description (limits, workspace, collision pairs, motors).
        envs: Batch size.
        mode: Control mode of the targets: 'position' (rad), 'velocity' (rad/s), 'torque' (N m).
        kind: The robot's :class:`~sim2real.deploy.robot_kind.RobotKind` (the rig's, handed down);
            None: :func:`~sim2real.deploy.kinds.robot_kind` of ``robot``.

    Attributes:
        kind: The robot's kind.
        targets: What a command means to each drive (the kind's
            :class:`~sim2real.deploy.kinds.targets.DriveTargets`), whose answers the guard's
            checks take (target bounds, hard-limit bounce, self-collision holds, the PD barrier's
            joints, the joint filters' input).
        counts: dict check name -> (envs,) int64, interventions so far; each check counts at
            most once per env and tick, except ``effort`` in torque mode (a hold and a clamp).
        count_matrix: (len(CHECKS), envs) int64, the same counters as rows in ``CHECKS`` order
            (``counts[name]`` are views of its rows): one array to sum or compare per tick.
        hard_violation: (envs,) bool, set by the last :meth:`filter` when a hard limit was crossed
            (the runtime answers with a safe stop).
        effort_scale: (envs, n) derating factor in [continuous / peak torque, 1] applied to the
            effort limits, from the winding temperatures (see :meth:`update_thermal`).
    """

    def __init__(self, robot: Robot, envs: int, mode: str, kind=None):
        self.robot, self.envs, self.mode = robot, envs, mode
        self.kind = kind = kind or robot_kind(robot)
        n = robot.n_joints
        self.dt = robot.control_period
        self.lower, self.upper = robot.position_lower, robot.position_upper
        #: what a command means to each drive (the kind's): a PD joint's target is a torque
        #: request, judged, not stopped (its bounds infinite)
        self.targets = targets = kind.targets(robot)
        self._target_lower, self._target_upper = targets.target_bounds(
            self.lower - TARGET_TOLERANCE, self.upper + TARGET_TOLERANCE
        )
        self.soft_lower, self.soft_upper = robot.soft_lower, robot.soft_upper
        self.acc = robot.acceleration_limit
        self.jerk = robot.jerk_limit
        self.vel = robot.velocity_limit
        s = robot.config.safety
        self.ws_min = np.array(s.workspace_min)
        self.ws_max = np.array(s.workspace_max)
        self.count_matrix = np.zeros((len(CHECKS), envs), dtype=np.int64)
        self.counts = {name: self.count_matrix[i] for i, name in enumerate(CHECKS)}
        self.hard_violation = np.zeros(envs, dtype=bool)
        #: (envs,) int64, consecutive ticks with an estimate past a hard limit (a floating
        #: base's tolerance, :mod:`sim2real.deploy.safety.limits`)
        self.beyond_ticks = np.zeros(envs, dtype=np.int64)
        #: (envs,) int64, consecutive ticks with an estimate farther past a hard limit than a
        #: floating base's tolerance
        self.far_ticks = np.zeros(envs, dtype=np.int64)
        self.effort_scale = np.ones((envs, n))
        self._last_valid = np.tile(robot.home, (envs, 1))
        self._pred = np.zeros((envs, n))
        self._tmp = np.zeros((envs, n))
        self._mask = np.zeros((envs, n), dtype=bool)
        #: Torque mode, N m s/rad: braking torque per rad/s of excess speed; full effort at
        #: 0.1 rad/s over the allowed speed (our choice).
        self._brake_gain = 10.0 * robot.effort_limit
        self.model = robot.fixed_base_model
        self.data = self.model.createData()
        self.geom_model, self.geom_data = collision_model(robot)
        self._has_pairs = bool(self.geom_model.collisionPairs)
        #: m per rad: bound on any point's displacement per unit of sum |dq| (module docstring).
        self.sweep, self.gravity_bound = motion_bounds(robot)
        #: (n,) m per rad: bound on the end effector's displacement per radian of each joint
        #: (:func:`end_effector_lever`; ``sweep`` each without a workspace box)
        self.ee_lever = (
            end_effector_lever(robot) if s.workspace_min is not None else np.full(n, self.sweep)
        )
        self.derating = EffortDerating(robot, hold=self.gravity_bound)
        # caches of the screens: configuration of the last computation (rows of one array for
        # the kernel: workspace, collision) and its result (the margin; each pair's distance)
        self._screen_q = np.zeros((2, envs, n))
        self._ws_q = self._screen_q[0]
        self._ws_margin = np.full(envs, -np.inf)  # m inside the workspace box (-inf: unknown)
        self._col_q = self._screen_q[1]
        #: (pairs, n) m/rad: how fast each collision pair approaches per radian of each joint
        self.pair_weights = collision_pair_weights(robot)
        self._pair_clearance = np.full((envs, len(self.pair_weights)), -np.inf)  # m, per pair
        if s.workspace_min is None:  # no workspace box (a legged robot): never screened
            self._ws_margin[:] = np.inf
        #: the motion envelope (:mod:`sim2real.deploy.safety.envelope`): checks the smoother's step after it
        #: (:meth:`check_motion`); position and velocity mode (the drives' model,
        #: :mod:`sim2real.deploy.safety.drive`), a fixed base only (not for PD targets)
        reach = end_effector_reach(robot) if s.workspace_min is not None else np.inf
        self.envelope = targets.motion_envelope(
            lambda: MotionEnvelope(
                robot,
                envs,
                collision_model(robot),
                self.pair_weights,
                self.ee_lever,
                self.gravity_bound,
                reach,
                s.clearance_margin,
                VelocityDrive(robot, envs) if mode == "velocity" else None,
                TorqueDrive(robot, envs) if mode == "torque" else None,
            )
        )
        # the rows the motion envelope counts in: collision, workspace, torque mode's joint limits
        self._geometric_rows = [row("self_collision"), row("workspace"), row("velocity")]
        self._counted = np.zeros((3, envs), dtype=np.int64)  # those rows when filter began
        self._move = np.zeros(envs)
        self._held = np.zeros(envs, dtype=bool)
        self.screen_margin = SCREEN_MARGIN
        # the kernel's arrays (sim2real.deploy.safety.kernel.GuardArrays)
        self._needs = np.zeros((len(CHECKS), envs), dtype=bool)
        self._over = np.zeros((envs, n))  # torque mode: rad/s above each joint's band
        self._under = np.zeros((envs, n))  # and below it (sim2real.deploy.safety.velocity)
        self._arrays = self._kernel_arrays()
        # the kernel's phases bound to the arrays of the last filter (_filter)
        self._bound_key = (None, None, None, None)
        self._phase0 = self._phase1 = None
        self._motion_key, self._certify_motion = (None,) * 4, None  # check_motion's binding
        self._warm_up()

    def _kernel_arrays(self) -> gk.GuardArrays:
        """The arrays of :func:`sim2real.deploy.safety.kernel.guard_filter` (:class:`GuardArrays`): the
        guard's own, updated in place, and the checks' constants."""
        lim = np.zeros((LIM_ROWS, self.robot.n_joints))
        lim[LOWER], lim[UPPER] = self.lower, self.upper
        lim[SOFT_LOWER], lim[SOFT_UPPER] = self.soft_lower, self.soft_upper
        lim[VEL], lim[ACC], lim[EFFORT] = self.vel, self.acc, self.robot.effort_limit
        envs = self.envs
        return gk.GuardArrays(
            mode=MODES.get(self.mode, TORQUE),
            lim=lim,
            scalars=np.array([self.dt, SCREEN_MARGIN, float(self._has_pairs)]),
            effort_scale=self.effort_scale,
            counts=self.count_matrix,
            hard_violation=self.hard_violation,
            beyond_ticks=self.beyond_ticks,
            far_ticks=self.far_ticks,
            pred=self._pred,
            tmp=self._tmp,
            screen=self._screen_q,
            workspace_margin=self._ws_margin,
            over=self._over,
            under=self._under,
            held=self._held,
            last_valid=self._last_valid,
            pair_clearance=self._pair_clearance,
            pair_weights=self.pair_weights,
            fired=np.zeros((len(CHECKS), envs), dtype=bool),
            needs=self._needs,
            stops=np.array([c.stops for c in GUARD_CHECKS]),
            geometric=np.array(self._geometric_rows, dtype=np.int64),
            counted=self._counted,
            own=tuple(np.ascontiguousarray(c.constants(self)) for c in GUARD_CHECKS),
        )

    def _warm_up(self) -> None:
        """Compile the kernel (or load numba's cache) now, on copies, not in a tick."""
        a = self._arrays
        copies = a._replace(
            **{
                k: np.copy(getattr(a, k))
                for k in a._fields
                if isinstance(getattr(a, k), np.ndarray) and k not in ("lim", "scalars")
            }
        )
        zeros = np.zeros((self.envs, self.robot.n_joints))
        out = np.zeros_like(zeros)
        with warnings.catch_warnings():  # numba: a tuple of functions is "experimental"
            warnings.simplefilter("ignore", NumbaExperimentalFeatureWarning)
            gk.guard_filter(0, out, zeros, zeros, zeros, False, copies, a.own)
            gk.guard_filter(1, out, zeros, zeros, zeros, False, copies, a.own)
            bind(gk.guard_table, 0, gk.GUARD.empty(), False, a.own)  # compiled (or loaded)

    def reset(self, q: np.ndarray, envs: np.ndarray | None = None, drives: bool = True) -> None:
        """Start from measured positions ``q`` (envs, n): they become the hold target.

        ``envs``: optional boolean mask (envs,) of the envs to reset; default all. ``drives``:
        the drives were (re-)enabled at ``q`` (a start, a new episode): a velocity drive's
        integrator starts there (:meth:`sim2real.deploy.safety.drive.VelocityDrive.reset`); False when
        the drives ran on (a resume after a safe stop), so the model keeps what they integrated.
        """
        which = slice(None) if envs is None else np.asarray(envs, dtype=bool)
        self._last_valid[which] = q[which]
        self.hard_violation[which] = False
        self.beyond_ticks[which] = 0
        self.far_ticks[which] = 0
        drive = self.envelope.drive if self.envelope is not None else None
        if self.envelope is not None:  # an escape from outside the box starts afresh
            self.envelope.escape_floor[which] = np.nan
        if drives and drive is not None:
            drive.reset(q, envs)

    def _state_fields(self) -> dict[str, np.ndarray]:
        fields = {f"counts/{name}": values for name, values in self.counts.items()}
        fields.update(
            hard_violation=self.hard_violation,
            beyond_ticks=self.beyond_ticks,
            far_ticks=self.far_ticks,
            effort_scale=self.effort_scale,
            last_valid=self._last_valid,
            workspace_q=self._ws_q,
            workspace_margin=self._ws_margin,
            collision_q=self._col_q,
            pair_clearance=self._pair_clearance,
        )
        if self.envelope is not None and self.envelope.has_workspace:
            fields["escape_floor"] = self.envelope.escape_floor
        if self.envelope is not None and self.envelope.drive is not None:
            fields["drive_setpoint"] = self.envelope.drive.setpoint
        if self.envelope is not None and self.envelope.torque is not None:
            fields["torque_command"] = self.envelope.torque.command
            fields["torque_acceleration"] = self.envelope.torque.acceleration
            fields["torque_hold"] = self.envelope.torque.hold
            fields["torque_braked"] = self.envelope.torque.braked
        return fields

    def state_dict(self, env: int | None = None) -> dict[str, np.ndarray]:
        """The guard's state (copies; conventions of :mod:`sim2real.deploy.core.stateful`):
        ``counts/<check>`` (envs,) int64, ``hard_violation`` (envs,) bool, ``beyond_ticks`` and
        ``far_ticks`` (envs,) int64 (:mod:`sim2real.deploy.safety.limits`),
        ``effort_scale`` (envs, n), ``last_valid`` (envs, n) the hold target (rad in position mode),
        and the screens' caches (``workspace_q``, ``collision_q`` (envs, n) rad;
        ``workspace_margin`` (envs,) m; ``pair_clearance`` (envs, pairs) m, each collision pair's
        distance), with a motion envelope and a workspace box ``escape_floor`` (envs,) m
        (:attr:`sim2real.deploy.safety.envelope.MotionEnvelope.escape_floor`, NaN: none), in
        velocity mode ``drive_setpoint`` (envs, n) rad, the drives' integrators
        (:class:`sim2real.deploy.safety.drive.VelocityDrive`), in torque mode ``torque_command`` (envs, n) N
        m and ``torque_acceleration`` (envs, n) rad/s^2, the last committed torque and its
        acceleration, ``torque_hold`` (envs, n) rad and ``torque_braked`` (envs,) bool, where the
        stop began and whether the last tick braked
        (:class:`sim2real.deploy.safety.torque_drive.TorqueDrive`); the env axis has length 1 for one env
        ``env``.
        """
        return take(self._state_fields(), env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``).

        Raises:
            StateDictError: a missing field or a shape that differs; nothing is changed.
        """
        put(self._state_fields(), state, env)

    def set_stopping(self, check: str, stops: bool) -> None:
        """Whether check ``check``'s firing is a hard violation (the runtime's safe stop).

        Evaluation only: the soak replays the moment of a stop with it off, to tell a stop that
        laid a standing robot down from one on a robot already falling
        (:mod:`sim2real.eval.soak.counterfactual`). The check still runs and counts. A setting, not
        state: :meth:`state_dict` leaves it out and :meth:`load_state_dict` does not change it.

        Raises:
            KeyError: ``check`` is not a guard check name (:data:`sim2real.deploy.safety.check.CHECKS`).
        """
        names = [c.name for c in GUARD_CHECKS]
        if check not in names:
            raise KeyError(f"check: expected one of {names}, got {check!r}")
        self._arrays.stops[names.index(check)] = bool(stops)

    def trust_estimate(self, covariance: np.ndarray) -> None:
        """The joint estimator's covariance ``covariance`` (envs, n, 2, 2) of ``[q, dq]``
        (rad^2, rad^2/s^2; a view the estimator keeps current,
        :attr:`sim2real.deploy.estimation.joints.JointStateEstimator.covariance`) for the motion
        envelope's drive models: torque mode widens the motion by the estimate's error, velocity
        mode counts a drive as running away only beyond it. Nothing in position mode or for a
        floating base."""
        if self.envelope is None:
            return
        for model in (self.envelope.drive, self.envelope.torque):
            if model is not None:
                model.covariance = covariance

    def estimator_input(self, smoother) -> np.ndarray | None:
        """(envs, n) rad/s^2, a view: the joint estimator's control input, the acceleration
        commanded over the last period: the smoother's (``mean_acceleration``, position and
        velocity mode); in torque mode the last committed torque's at the estimate
        (:attr:`sim2real.deploy.safety.torque_drive.TorqueDrive.acceleration`). None where the
        kind's drives do not follow their command (:meth:`DriveTargets.estimator_input
        <sim2real.deploy.kinds.targets.DriveTargets.estimator_input>`, a legged robot's): its
        filter runs the constant-velocity model, since its PD targets' acceleration is not its
        joints'."""
        if self.mode != "torque":
            return self.targets.estimator_input(smoother.mean_acceleration)
        torque = self.envelope.torque.acceleration if self.envelope is not None else None
        return self.targets.estimator_input(torque)

    def update_thermal(self, winding_temperature: np.ndarray) -> np.ndarray:
        """Derate the effort limits as the drives do (:class:`sim2real.robots.thermal.EffortDerating`:
        linearly across the derating band, down to the continuous torque); returns
        ``effort_scale``."""
        return self.derating.factor(winding_temperature, out=self.effort_scale)

    # ------------------------------------------------------------------ geometry at one config
    def _ee_outside(self, q: np.ndarray, cache: int | None = None) -> float:
        """Distance (m) of the end effector outside the workspace box at ``q`` (0 inside).

        With ``cache = e``, remember ``q`` and the margin inside the box for env ``e``'s screen.
        """
        pin.forwardKinematics(self.model, self.data, q)
        ee = pin.updateFramePlacement(self.model, self.data, self.robot.ee_frame_id).translation
        below, above = self.ws_min - ee, ee - self.ws_max
        if cache is not None:
            self._ws_q[cache] = q
            self._ws_margin[cache] = -max(below.max(), above.max())
        return float(np.linalg.norm(np.maximum(below, 0.0) + np.maximum(above, 0.0)))

    def _in_collision(self, q: np.ndarray, cache: int | None = None) -> bool:
        """Whether a listed collision pair is in contact at ``q`` (coal).

        With ``cache = e``, also compute and remember each pair's distance for env ``e`` at ``q``.
        """
        if not self._has_pairs:
            return False
        args = (self.model, self.data, self.geom_model, self.geom_data, q)
        if cache is None:
            return collision_query(*args)
        self._col_q[cache] = q
        return collision_query(*args, distances=self._pair_clearance[cache])

    # ------------------------------------------------------------------ the check
    def filter(
        self,
        target: np.ndarray,
        state: RobotState,
        out: np.ndarray | None = None,
        commanded_position: np.ndarray | None = None,
    ):
        """Return the safe target, (envs, n), in the units of the mode.

        Args:
            target: (envs, n) finite target (non-finite policy output is handled before).
            state: Estimated state (``q``, ``dq`` rad, rad/s).
            out: Optional (envs, n) array to write into (may be ``target`` itself).
            commanded_position: Velocity mode: (envs, n) rad, the position the commands have
                integrated to (the drive's setpoint, ahead of the lagging joint). The stopping
                bounds use whichever of it and ``q`` is closer to each limit.
        """
        if out is None:
            out = target.copy()
        elif out is not target:
            np.copyto(out, target)
        for check in PREPARING:  # the constants that follow the estimate
            check.prepare(self, state)
        return self._filter(state.q, state.dq, commanded_position, out)

    def _filter(self, q: np.ndarray, dq: np.ndarray, commanded: np.ndarray | None, out):
        """:meth:`filter` with the kernel: phase 0 (which first notes the count rows
        :meth:`check_motion` shares in ``_counted``), the checks' Python parts, phase 1. The
        kernel's calls are bound (:mod:`sim2real.deploy.kernels.calls`) to the arrays of the last
        call: a runtime passes the same ones every tick."""
        key = self._bound_key
        if out is not key[0] or q is not key[1] or dq is not key[2] or commanded is not key[3]:
            self._bind_filter(out, q, dq, commanded)
        if self._phase0():
            self._resolve(self._needs, q, dq, out)
            self._phase1()
        return out

    def _bind_filter(self, out, q, dq, commanded) -> None:
        """Bind the kernel's phases to these arrays (:meth:`_filter`): as one table of them and
        the guard's (:func:`~sim2real.deploy.safety.kernel.guard_table`) where each is of its
        dtype and dimensions, else to the arrays themselves."""
        a, has = self._arrays, commanded is not None
        args = (out, q, dq, q if commanded is None else commanded)
        named = dict(zip(("out", "q", "dq", "commanded"), args, strict=True))
        own = {k: v for k, v in a._asdict().items() if k != "own"}
        table = gk.GUARD.pack_or_none(**named, **own)
        with warnings.catch_warnings():  # numba: a tuple of functions is "experimental"
            warnings.simplefilter("ignore", NumbaExperimentalFeatureWarning)
            if table is not None:
                self._phase0 = bind(gk.guard_table, 0, table, has, a.own)
                self._phase1 = bind(gk.guard_table, 1, table, has, a.own)
            else:
                self._phase0 = bind(gk.guard_filter, 0, *args, has, a, a.own)
                self._phase1 = bind(gk.guard_filter, 1, *args, has, a, a.own)
        self._bound_key = (out, q, dq, commanded)

    def _resolve(self, needs: np.ndarray, q: np.ndarray, dq: np.ndarray, out) -> None:
        """The Python (Pinocchio) parts of the checks, in count-row order, for the envs each
        asked for (``needs`` (checks, envs) bool)."""
        asked = needs.any(axis=1).tolist()  # one reduction, not one per check
        for k, check in enumerate(GUARD_CHECKS):
            if asked[k]:
                check.resolve(self, k, needs[k], q, dq, out)

    def reject(self, k: int, e: int, q: np.ndarray, dq: np.ndarray, out: np.ndarray) -> None:
        """Check ``k`` rejects env ``e``'s target: count it, hold (:meth:`_hold`; ``q``, ``dq``
        env ``e``'s estimate, (n,)) and mark the env held (the later checks skip it)."""
        self.count_matrix[k, e] += 1
        self._hold(e, q, dq, out)
        self._held[e] = True

    def _hold(self, e: int, q: np.ndarray, dq: np.ndarray, out: np.ndarray) -> None:
        """Replace env ``e``'s target by a hold: the last accepted target (position mode), zero
        velocity (velocity mode), or in torque mode gravity compensation with the guard's brake on
        the measured velocity (``g - brake_gain dq``): a moving joint is stopped, not let coast."""
        if self.mode == "position":
            out[e] = self._last_valid[e]
        elif self.mode == "velocity":
            out[e] = 0.0
        else:
            out[e] = pin.computeGeneralizedGravity(self.model, self.data, q)
            out[e] -= self._brake_gain * dq

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """Gravity torque (N m, (n,)) at one configuration ``q`` (rad); a view reused per call."""
        return pin.computeGeneralizedGravity(self.model, self.data, q)

    def totals(self) -> dict[str, int]:
        """Interventions per check, summed over envs."""
        return {k: int(v.sum()) for k, v in self.counts.items()}
