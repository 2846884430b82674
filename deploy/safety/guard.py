"""SafetyGuard: every target is checked with Pinocchio before it may reach the smoother.

Checks, each with its own counter (``SafetyGuard.counts[name]``, (envs,) int64), and the response:

- ``soft_limit``: target position beyond the soft limit (``soft_limit_fraction`` of the range, 90 %
  by default; seed section 6), or the estimated position inside the soft band. Clamp to the soft
  limit; a warning.
- ``hard_limit``: target position beyond the hard limit, or the estimated (or, in velocity mode,
  predicted) position beyond it. A violation: :attr:`SafetyGuard.hard_violation` is set and the
  runtime makes a safe stop. A floating-base robot's *target* past a hard limit is clamped to the
  soft limit (``soft_limit``) instead: its low-gain PD's targets act as torques
  (``kp (target - q)``), and legged policies command past the joint range by design (legged_gym
  trains without any bound on the targets); its estimated position past a hard limit still stops.
- ``velocity``: a velocity that could not stop before the soft limit, ``d`` the distance left:
  velocity limits that shrink to zero at the position limits. Clamp. Position and velocity mode:
  under the acceleration and jerk limits with one control period of delay,
  ``v dt + v^2 / (2 a) + v a / (2 j) <= d``; torque mode: ``|v| <= sqrt(2 a_max d)``. (In velocity
  mode the smoother also brakes exactly at the soft limits from Ruckig's own state.)
- ``workspace``: end effector of the predicted next state outside the workspace box (and not moving
  back toward it). Reject and hold.
- ``self_collision``: a listed collision pair in contact at the predicted next state (coal).
  Reject and hold.
- ``effort``: gravity torque at the predicted state above the temperature-derated effort limit
  (reject and hold); in torque mode also a commanded torque above it (clamp).

"Hold" keeps the robot where it is: the last accepted target in position mode, zero velocity in
velocity mode, the gravity torque in torque mode. The predicted next state is the target itself
in position mode, ``q + v dt`` in velocity mode and ``q + dq dt`` in torque mode.

A target is not the path to it: after the smoother's step, :meth:`SafetyGuard.check_motion`
certifies the motion the robot is committed to (the step and the brake after it) with the motion
envelope (:mod:`deploy.safety.envelope`) and brakes the envs it cannot certify, counted as
``self_collision`` or ``workspace`` interventions (position mode, fixed base).

Speed: the per-env Pinocchio calls (forward kinematics, coal collision, gravity) run only when
an exact bound says they could fire. Every point of the robot moves at most ``sweep * sum|dq_i|``
(m) when the joints move by ``dq`` (rad), ``sweep`` being the longest kinematic chain plus the
largest geometry radius, and the end effector at most ``sum lever_i |dq_i|``, ``lever_i`` the
chain from joint ``i`` to it (:func:`end_effector_lever`); so the end effector cannot leave the
workspace box while its last computed margin exceeds its bound, two geometries cannot touch while
their last computed distance exceeds the pair's own bound (:func:`collision_pair_weights`: only
the joints between the two move them apart or together), and gravity cannot exceed the effort
limit while a per-joint bound (the masses beyond the joint at their longest lever) stays below
it. The outcome is exactly that of checking every tick; only the cost differs.

Collision geometry: the MJCF geoms. The plant keeps them at ``contype="0"`` (MuJoCo does not
simulate self-contact), so Pinocchio's MJCF parser files them as visual geometry; the guard builds
its coal collision pairs from those shapes and the pairs named in robot.toml.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pinocchio as pin

from deploy.safety import kernel as gk
from deploy.safety.checks import CHECKS, row
from deploy.safety.collision import collision_model, collision_query
from deploy.safety.envelope import MotionEnvelope
from deploy.smoothing import stopping_speed
from deploy.state import RobotState
from deploy.stateful import put, take
from robots import Robot
from robots.chain_bounds import (
    collision_pair_weights,
    end_effector_lever,
    end_effector_reach,
    motion_bounds,
)
from robots.thermal import EffortDerating

#: Slack of the screens, m (round-off of the kinematics): a check runs when within it.
SCREEN_MARGIN = 1e-9
# rad: a position target this close past a hard limit is at the limit. An absolute position
# action of exactly +-1 maps to ``offset +- scale`` (PolicySpec), which float rounding can put
# 1 ulp past the limit (4.4e-16 rad on so101's wrist_roll); that is a full action, not a
# crossing. Far below any encoder count (1.5e-3 rad at 4096 counts/rev).
TARGET_TOLERANCE = 1e-9


class SafetyGuard:
    """Clamp or reject targets that would break a limit; count every intervention.

    Args:
        robot: The robot description (limits, workspace, collision pairs, motors).
        envs: Batch size.
        mode: Control mode of the targets: 'position' (rad), 'velocity' (rad/s), 'torque' (N m).
        reference: Run the numpy reference of :meth:`filter` instead of the compiled kernel
            (:mod:`deploy.safety.kernel`, the default); both give the same numbers bit for bit.

    Attributes:
        counts: dict check name -> (envs,) int64, interventions so far; each check counts at
            most once per env and tick, except ``effort`` in torque mode (a hold and a clamp).
        count_matrix: (len(CHECKS), envs) int64, the same counters as rows in ``CHECKS`` order
            (``counts[name]`` are views of its rows): one array to sum or compare per tick.
        hard_violation: (envs,) bool, set by the last :meth:`filter` when a hard limit was crossed
            (the runtime answers with a safe stop).
        effort_scale: (envs, n) derating factor in [continuous / peak torque, 1] applied to the
            effort limits, from the winding temperatures (see :meth:`update_thermal`).
    """

    def __init__(self, robot: Robot, envs: int, mode: str, reference: bool = False):
        self.robot, self.envs, self.mode = robot, envs, mode
        self.reference = reference
        n = robot.n_joints
        self.dt = robot.control_period
        self.lower, self.upper = robot.position_lower, robot.position_upper
        self._target_lower = self.lower - TARGET_TOLERANCE
        self._target_upper = self.upper + TARGET_TOLERANCE
        if robot.floating_base:  # targets are torques through a low-gain PD: clamp, not stop
            self._target_lower = np.full(robot.n_joints, -np.inf)
            self._target_upper = np.full(robot.n_joints, np.inf)
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
        #: the motion envelope (:mod:`deploy.safety.envelope`): checks the smoother's step after it
        #: (:meth:`check_motion`); position mode and a fixed base only (deploy.safety.envelope)
        self.envelope = None
        if mode == "position" and not robot.floating_base:
            reach = end_effector_reach(robot) if s.workspace_min is not None else np.inf
            self.envelope = MotionEnvelope(
                robot,
                envs,
                collision_model(robot),
                self.pair_weights,
                self.ee_lever,
                self.gravity_bound,
                reach,
                s.clearance_margin,
            )
        self._geometric_rows = [row("self_collision"), row("workspace")]
        self._counted = np.zeros((2, envs), dtype=np.int64)  # those rows when filter began
        self._move = np.zeros(envs)
        self._held = np.zeros(envs, dtype=bool)
        self._no_env = np.zeros(envs, dtype=bool)  # read only
        # the kernel's constants (rows of deploy.safety.kernel) and work arrays
        self._kernel_mode = {"position": gk.POSITION, "velocity": gk.VELOCITY}.get(mode, gk.TORQUE)
        lim = np.zeros((gk.ROWS, n))
        lim[gk.LOWER], lim[gk.UPPER] = self.lower, self.upper
        lim[gk.TARGET_LOWER], lim[gk.TARGET_UPPER] = self._target_lower, self._target_upper
        lim[gk.SOFT_LOWER], lim[gk.SOFT_UPPER] = self.soft_lower, self.soft_upper
        lim[gk.VEL], lim[gk.ACC] = self.vel, self.acc
        # stopping_speed(d, a, j, dt) = 0.5 (sqrt(b^2 + 8 a d) - b), b as stopping_speed has it
        lim[gk.SPEED_B] = self.acc**2 / self.jerk + 2.0 * self.acc * self.dt
        lim[gk.EIGHT_A] = 8.0 * self.acc
        lim[gk.EFFORT], lim[gk.GRAVITY_BOUND] = robot.effort_limit, self.gravity_bound
        lim[gk.EE_LEVER] = self.ee_lever
        self._lim = lim
        self._scalars = np.array([self.dt, SCREEN_MARGIN, float(self._has_pairs)])
        self._over = np.zeros((envs, n))
        self._under = np.zeros((envs, n))
        self._checks = np.zeros((3, envs), dtype=bool)
        if not reference:  # compile (or load numba's cache) now, on copies, not in a tick
            zeros = np.zeros((envs, n))
            args = self._kernel_args(self._copies(), zeros, zeros, None, np.zeros((envs, n)))
            gk.guard_filter(0, *args)
            gk.guard_filter(1, *args)
        self._tail = self._kernel_tail(self)

    def reset(self, q: np.ndarray, envs: np.ndarray | None = None) -> None:
        """Start from measured positions ``q`` (envs, n): they become the hold target.

        ``envs``: optional boolean mask (envs,) of the envs to reset; default all.
        """
        which = slice(None) if envs is None else np.asarray(envs, dtype=bool)
        self._last_valid[which] = q[which]
        self.hard_violation[which] = False

    def _state_fields(self) -> dict[str, np.ndarray]:
        fields = {f"counts/{name}": values for name, values in self.counts.items()}
        fields.update(
            hard_violation=self.hard_violation,
            effort_scale=self.effort_scale,
            last_valid=self._last_valid,
            workspace_q=self._ws_q,
            workspace_margin=self._ws_margin,
            collision_q=self._col_q,
            pair_clearance=self._pair_clearance,
        )
        return fields

    def state_dict(self, env: int | None = None) -> dict[str, np.ndarray]:
        """The guard's state (copies; conventions of :mod:`deploy.stateful`): ``counts/<check>``
        (envs,) int64, ``hard_violation`` (envs,) bool, ``effort_scale`` (envs, n),
        ``last_valid`` (envs, n) the hold target (rad in position mode), and the screens' caches
        (``workspace_q``, ``collision_q`` (envs, n) rad; ``workspace_margin`` (envs,) m;
        ``pair_clearance`` (envs, pairs) m, each collision pair's distance); the env axis has
        length 1 for one env ``env``."""
        return take(self._state_fields(), env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``).

        Raises:
            StateDictError: a missing field or a shape that differs; nothing is changed.
        """
        put(self._state_fields(), state, env)

    def update_thermal(self, winding_temperature: np.ndarray) -> np.ndarray:
        """Derate the effort limits as the drives do (:class:`robots.thermal.EffortDerating`:
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
        q, dq = state.q, state.dq
        self._counted[0] = self.count_matrix[self._geometric_rows[0]]
        self._counted[1] = self.count_matrix[self._geometric_rows[1]]
        if not self.reference:
            return self._kernel(q, dq, commanded_position, out)
        self.hard_violation[:] = False
        counts = self.counts

        # hard limits: the estimated state itself, then the target
        np.logical_or(q < self.lower, q > self.upper, out=self._mask)
        crossed = self._mask.any(axis=1)
        if self.mode == "position":
            np.logical_or(out < self._target_lower, out > self._target_upper, out=self._mask)
            crossed |= self._mask.any(axis=1)
            # soft limits: clamp positions into the soft band
            np.logical_or(out < self.soft_lower, out > self.soft_upper, out=self._mask)
            counts["soft_limit"] += self._mask.any(axis=1)
            np.minimum(np.maximum(out, self.soft_lower, out=out), self.soft_upper, out=out)
            self._pred[:] = out
        elif self.mode == "velocity":
            v_up, v_down = self._velocity_band(q, commanded_position)
            np.logical_or(out > v_up, out < -v_down, out=self._mask)
            counts["velocity"] += self._mask.any(axis=1)
            np.negative(v_down, out=v_down)
            np.minimum(np.maximum(out, v_down, out=out), v_up, out=out)
            np.logical_or(q > self.soft_upper, q < self.soft_lower, out=self._mask)
            counts["soft_limit"] += self._mask.any(axis=1)
            np.multiply(out, self.dt, out=self._pred)
            self._pred += q
            np.logical_or(self._pred < self.lower, self._pred > self.upper, out=self._mask)
            crossed |= self._mask.any(axis=1)
        else:  # torque
            np.multiply(dq, self.dt, out=self._pred)
            self._pred += q
            np.logical_or(q > self.soft_upper, q < self.soft_lower, out=self._mask)
            counts["soft_limit"] += self._mask.any(axis=1)
            # velocity governor: torque may not drive a joint faster than it can stop before its
            # soft limit; above that speed it is replaced by gravity compensation plus braking
            v_up, v_down = self._velocity_band(q, None)
            over = np.maximum(dq - v_up, 0.0)
            under = np.maximum(-v_down - dq, 0.0)
            np.logical_or(over > 0, under > 0, out=self._mask)
            if self._mask.any():
                counts["velocity"] += self._mask.any(axis=1)
                self._govern(q, over, under, out)
        counts["hard_limit"] += crossed
        self.hard_violation |= crossed

        # per-env geometric and effort checks at the predicted next state, where a bound says
        # they could fire (module docstring)
        effort = self.robot.effort_limit
        move = self._move
        np.subtract(self._pred, self._ws_q, out=self._tmp)
        np.abs(self._tmp, out=self._tmp)
        np.multiply(self._tmp, self.ee_lever, out=self._tmp)
        np.sum(self._tmp, axis=1, out=move)
        check_ws = self._ws_margin <= move + SCREEN_MARGIN
        check_col = self._no_env
        if self._has_pairs:
            check_col = np.zeros(self.envs, dtype=bool)
            moved = np.abs(self._pred - self._col_q)  # rad per joint since the last check
            for p, weights in enumerate(self.pair_weights):
                np.multiply(moved, weights, out=self._tmp)
                np.sum(self._tmp, axis=1, out=move)
                check_col |= self._pair_clearance[:, p] <= move + SCREEN_MARGIN
        check_effort = (self.gravity_bound > effort * self.effort_scale).any(axis=1)
        held = self._held
        held[:] = False
        self._check_predicted(check_ws, check_col, check_effort, q, dq, out)
        if self.mode == "position":
            keep = ~held
            self._last_valid[keep] = out[keep]
        if self.mode == "torque":
            limit = effort * self.effort_scale
            np.logical_or(out > limit, out < -limit, out=self._mask)
            counts["effort"] += self._mask.any(axis=1)
            np.clip(out, -limit, limit, out=out)
        return out

    def check_motion(self, smoother, state: RobotState, command: np.ndarray) -> np.ndarray:
        """Certify the smoother's last step with the motion envelope
        (:mod:`deploy.safety.envelope`):
        the envs whose committed motion could bring a collision pair, or the end effector and
        the workspace box's faces, within the clearance margin are braked instead
        (:meth:`deploy.smoothing.CommandSmoother.brake`) and counted as ``self_collision`` or
        ``workspace`` interventions (once per env and tick with :meth:`filter`'s).

        Args:
            smoother: The :class:`~deploy.smoothing.CommandSmoother` that just stepped.
            state: The estimated state (``q`` rad).
            command: (envs, n) the command of that step (rewritten where braked).

        Returns:
            ``command``.
        """
        envelope = self.envelope
        if envelope is None or not envelope.check(
            state.q,
            smoother.before,
            smoother.trajectory,
            smoother.stopping,
            self.effort_scale,
        ):
            return command
        unsafe = envelope.unsafe
        braked = unsafe[0] | unsafe[1]
        for k, r in enumerate(self._geometric_rows):
            first = unsafe[k] & (self.count_matrix[r] == self._counted[k])
            self.count_matrix[r] += first
        smoother.brake(braked, envelope.joints)
        command[braked] = smoother.command[braked]
        return command

    def _govern(self, q: np.ndarray, over: np.ndarray, under: np.ndarray, out: np.ndarray) -> None:
        """Torque mode's velocity governor: in the envs with a joint faster than its band
        (``over``, ``under`` > 0, rad/s), cap the torque toward the limit at gravity plus the
        brake (one Pinocchio gravity call per such env)."""
        for e in np.flatnonzero((over > 0).any(axis=1) | (under > 0).any(axis=1)):
            g = pin.computeGeneralizedGravity(self.model, self.data, q[e])
            brake = self._brake_gain * (under[e] - over[e])
            out[e] = np.where(over[e] > 0, np.minimum(out[e], g + brake), out[e])
            out[e] = np.where(under[e] > 0, np.maximum(out[e], g + brake), out[e])

    def _check_predicted(self, check_ws, check_col, check_effort, q, dq, out) -> None:
        """The per-env Pinocchio checks at the predicted state ``_pred`` of the envs the screens
        flagged ((envs,) bool each): count, hold and mark ``_held`` the envs that fail one."""
        effort, counts, held = self.robot.effort_limit, self.counts, self._held
        for e in np.flatnonzero(check_ws | check_col | check_effort):
            qp = self._pred[e]
            reason = None
            if check_ws[e]:
                outside = self._ee_outside(qp, cache=e)
                if outside > 0.0 and outside >= self._ee_outside(q[e]) - 1e-12:
                    reason = "workspace"
            if reason is None and check_col[e] and self._in_collision(qp, cache=e):
                reason = "self_collision"
            if reason is None and check_effort[e]:
                g = pin.computeGeneralizedGravity(self.model, self.data, qp)
                if np.any(np.abs(g) > effort * self.effort_scale[e]):
                    reason = "effort"
            if reason is not None:
                counts[reason][e] += 1
                self._hold(e, q[e], dq[e], out)
                held[e] = True

    def _copies(self) -> SimpleNamespace:
        """Copies of the arrays the kernel writes (the warm-up call must change nothing)."""
        names = ("effort_scale", "count_matrix", "hard_violation", "_pred", "_tmp", "_screen_q")
        names += ("_ws_margin", "_over", "_under", "_checks", "_held", "_last_valid")
        return SimpleNamespace(
            **{k: np.copy(getattr(self, k)) for k in names},
            _kernel_mode=self._kernel_mode,
            _lim=self._lim,
            _scalars=self._scalars,
            _pair_clearance=self._pair_clearance,  # read only
            pair_weights=self.pair_weights,
        )

    def _kernel(self, q: np.ndarray, dq: np.ndarray, commanded: np.ndarray | None, out):
        """:meth:`filter` with the kernel: phase 0, Pinocchio where it says, phase 1."""
        has = commanded is not None
        mode = self._kernel_mode
        code = gk.guard_filter(0, mode, out, q, dq, commanded if has else q, has, *self._tail)
        if code:
            if code & gk.NEEDS_GOVERNOR:
                self._govern(q, self._over, self._under, out)
            if code & gk.NEEDS_SCREENS:
                c = self._checks
                self._check_predicted(c[0], c[1], c[2], q, dq, out)
            gk.guard_filter(1, *self._kernel_args(self, q, dq, commanded, out))
        return out

    @staticmethod
    def _kernel_args(g, q: np.ndarray, dq: np.ndarray, commanded: np.ndarray | None, out):
        """Arguments of :func:`deploy.safety.kernel.guard_filter` after ``phase``, on the arrays
        of ``g`` (the guard, or its :meth:`_copies` to warm the kernel up)."""
        has = commanded is not None
        return (
            g._kernel_mode,
            out,
            q,
            dq,
            commanded if has else q,
            has,
            *SafetyGuard._kernel_tail(g),
        )

    @staticmethod
    def _kernel_tail(g) -> tuple:
        """The arguments of :func:`deploy.safety.kernel.guard_filter` after ``has_commanded``
        (the guard's own arrays: made once, updated in place)."""
        return (
            g._lim,
            g._scalars,
            g.effort_scale,
            g.count_matrix,
            g.hard_violation,
            g._pred,
            g._tmp,
            g._screen_q,
            g._ws_margin,
            g._over,
            g._under,
            g._checks,
            g._held,
            g._last_valid,
            g._pair_clearance,
            g.pair_weights,
        )

    def _velocity_band(self, q: np.ndarray, commanded: np.ndarray | None):
        """(v_up, v_down) >= 0, (envs, n): speeds from which each joint still stops before its
        soft limit, capped at the velocity limit. Position and velocity mode: under the
        acceleration and jerk limits of the smoother's trajectories, the brake beginning one
        control period later (:func:`deploy.smoothing.stopping_speed`). Torque mode (no Ruckig,
        the torque governor brakes): ``sqrt(2 a d)``, ``a`` scaled by the thermal derating."""
        upper = q if commanded is None else np.maximum(q, commanded)
        lower = q if commanded is None else np.minimum(q, commanded)
        d_up = np.maximum(self.soft_upper - upper, 0.0)
        d_down = np.maximum(lower - self.soft_lower, 0.0)
        if self.mode == "torque":
            # a derated drive brakes with a proportionally smaller torque
            acc = self.acc * self.effort_scale
            v_up = np.minimum(np.sqrt(2.0 * acc * d_up), self.vel)
            v_down = np.minimum(np.sqrt(2.0 * acc * d_down), self.vel)
        else:
            v_up = np.minimum(stopping_speed(d_up, self.acc, self.jerk, self.dt), self.vel)
            v_down = np.minimum(stopping_speed(d_down, self.acc, self.jerk, self.dt), self.vel)
        return v_up, v_down

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
