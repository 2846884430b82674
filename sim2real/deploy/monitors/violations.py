"""Violations: the robot's *true* state past a limit, counted from the simulator's ground truth.

A **violation** is what the robot really did (docs/architecture.md, "Words"); an
**intervention** is a command the guard or the smoother changed
(:mod:`sim2real.deploy.monitors.interventions`). A clamp is an intervention, never a violation; a violation
can happen without any clamp (a push, a drive overshooting its command, a lagging estimate).

Types (``VIOLATION_TYPES``), each counted per env in control ticks (a tick counts once per type,
however many joints are past the limit), apart for the ticks a legged robot lies damped after a
stop (``down``: what the fallen robot's joints do on the floor is not what its policy did):

- ``hard_limit``: a true joint position outside ``[position_lower, position_upper]``.
- ``soft_limit``: a true joint position in the soft band: outside ``[soft_lower, soft_upper]`` but
  not beyond the hard limit (a joint beyond it counts as ``hard_limit``).
- ``velocity``: a true joint speed above ``velocity_limit`` (the hard velocity limit).
- ``effort``: a joint's actuator torque above ``effort_limit`` by more than the relative tolerance
  ``EFFORT_TOLERANCE``: the plant clamps each joint's actuator torque to the effort limit itself,
  so torque *at* the limit (saturation) is not a violation.
- ``workspace``: the true end effector (MuJoCo's site, the randomized geometry) outside the box
  ``safety.workspace_min/max``.
- ``self_collision``: a pair of ``safety.collision_pairs`` in contact at the true joint positions
  (coal, the guard's collision model of the *nominal* geometry:
  :func:`sim2real.deploy.safety.collision.collision_model`).

Ground truth exists only in simulation (:class:`~sim2real.deploy.backends.sim.plant.SimBackend`'s true
state), sampled once per control tick after its physics; on hardware only interventions and the
guard's hard-limit detections on the estimate can be reported.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from sim2real.deploy.kernels.calls import bind
from sim2real.deploy.monitors import kernel as mk
from sim2real.deploy.monitors.monitor_state import MonitorState
from sim2real.deploy.monitors.pair_bounds import APART, PairBounds, pair_lower_bounds
from sim2real.deploy.monitors.violation_readings import ViolationReadings
from sim2real.deploy.safety.collision import collision_model, collision_query
from sim2real.deploy.safety.guard import SCREEN_MARGIN
from sim2real.robots import Robot
from sim2real.robots.chain_bounds import collision_pair_weights

VIOLATION_TYPES = ("hard_limit", "soft_limit", "velocity", "effort", "workspace", "self_collision")
#: The violations of the hard kind: every type but ``soft_limit`` (a warning band). deploy-run
#: exits 1 after any of them (README, exit codes).
HARD_VIOLATION_TYPES = tuple(t for t in VIOLATION_TYPES if t != "soft_limit")
#: Relative tolerance on the effort limit: the plant saturates each joint at exactly its limit.
EFFORT_TOLERANCE = 1e-9
#: Relative shrink of the screen's bounds (round-off of ``|x - centre| > half``): a tick within it
#: is checked exactly.
_SCREEN_SHRINK = 1e-12
#: Consecutive coal checks of an env between two measurements of its pairs' distances
#: (:meth:`ViolationMonitor._in_collision`): the distances cost as much as the contact query
#: and spare no check while the screen's bound trips every tick.
DISTANCE_REFRESH = 16


class ViolationMonitor(ViolationReadings, MonitorState):
    """Count true-state violations of ``envs`` simulated robots, per env and tick.

    Args:
        robot: The robot description (limits, workspace box, collision pairs).
        envs: Batch size (the backend's ``envs``).
        pair_bounds: Screen the pairs by compiled lower bounds of their distances where the
            model allows (:mod:`sim2real.deploy.monitors.pair_bounds`); False: by coal's
            distances alone. The same counts either way.

    Attributes:
        counts: dict type (``VIOLATION_TYPES``) -> (envs,) int64, ticks on which that type
            occurred while the env was up.
        pair_ticks: (envs, pairs) int64, ticks on which each collision pair of the guard's
            model (``pair_names``) touched while the env was up: which links make the
            ``self_collision`` ticks of ``counts``.
        reference_ticks: (envs,) int64, self-collision ticks (while up) whose touching pairs
            the reference motion itself touches then (:meth:`excuse_contacts`): the reference's
            contact under this collision model, not a violation; reference_pair_ticks: (envs,
            pairs) int64, their pairs.
        pair_names: (pairs,) ``"geom_a|geom_b"``, the guard's collision pairs in its order.
        hard_joint_ticks: (envs, n) int64, ticks on which each joint was beyond its hard limit
            while the env was up: which joints make the ``hard_limit`` ticks of ``counts``.
        hard_joint_depth: (envs, n) rad, how far past its hard limit each joint's true position
            ever was while the env was up (0: never past): how deep the ``hard_limit`` ticks went.
        down_hard_joint_ticks, down_hard_joint_depth: the same, of the ticks the env was down.
        speed_joint_ticks, speed_joint_excess: (envs, n) int64 and rad/s, ticks on which each
            joint's true speed was above its velocity limit and by how much at most (up or
            down); effort_joint_ticks, effort_joint_excess: the same of its torque (N m).
        any: (envs,) int64, ticks with at least one violation of any type.
        down_counts, down_any: the same, of the ticks on which the env was *down*: a legged
            robot lying damped after a stop (``down`` of :meth:`update`). What a fallen robot's
            joints do while it lies on the floor is counted there, apart from what the robot
            did while it stood and walked (``counts``); nothing is dropped.
        ticks: int, ticks observed (calls of :meth:`update`).

    Per tick (:meth:`update`) it allocates nothing unless some env is near a limit: one
    compiled screen (``|x - centre| > half range`` over joint positions, speeds, torques and the
    end effector) decides whether the exact per-type tests run, and coal checks the collision
    pairs of the envs the guard's exact per-pair screen flags. Its numpy reference is
    :class:`sim2real.deploy.monitors.reference.ReferenceViolationMonitor`.
    """

    _state_name = "violations"

    def __init__(self, robot: Robot, envs: int, pair_bounds: bool = True):
        if envs < 1:
            raise ValueError(f"envs: expected an integer >= 1, got {envs}")
        self.robot, self.envs = robot, envs
        n = self.n = robot.n_joints
        self.counts = {t: np.zeros(envs, dtype=np.int64) for t in VIOLATION_TYPES}
        self.any = np.zeros(envs, dtype=np.int64)
        self.down_counts = {t: np.zeros(envs, dtype=np.int64) for t in VIOLATION_TYPES}
        self.down_any = np.zeros(envs, dtype=np.int64)
        self._down = np.zeros(envs, dtype=bool)  # this tick's ``down`` of :meth:`update`
        self._tick_count = np.zeros(1, dtype=np.int64)
        s = robot.config.safety
        self._lower, self._upper = robot.position_lower, robot.position_upper
        self._soft_lower, self._soft_upper = robot.soft_lower, robot.soft_upper
        #: a robot without a workspace box (a legged one): no workspace violations
        self._has_workspace = s.workspace_min is not None
        if self._has_workspace:
            self._ws_min = np.array(s.workspace_min, dtype=np.float64)
            self._ws_max = np.array(s.workspace_max, dtype=np.float64)
        else:
            self._ws_min, self._ws_max = np.full(3, -np.inf), np.full(3, np.inf)
        self._velocity = robot.velocity_limit
        self._effort = robot.effort_limit * (1.0 + EFFORT_TOLERANCE)
        # the screen: one row per env, [q - soft centre, dq, tau, ee - box centre]
        width = 3 * n + 3
        # a continuous joint (infinite soft limits, a wheel): centre 0, infinite bound
        lo, hi = (np.where(np.isfinite(b), b, 0.0) for b in (self._soft_lower, self._soft_upper))
        self._offset_q = 0.5 * (lo + hi)
        self._offset_ee = np.zeros(3)
        if self._has_workspace:
            self._offset_ee = 0.5 * (self._ws_min + self._ws_max)
        bound = np.concatenate(
            [
                0.5 * (self._soft_upper - self._soft_lower),
                self._velocity,
                self._effort,
                0.5 * (self._ws_max - self._ws_min),
            ]
        )
        self._bound = bound * (1.0 - _SCREEN_SHRINK)
        self._buf = np.zeros((envs, width))
        self._q_part = self._buf[:, :n]
        self._dq_part = self._buf[:, n : 2 * n]
        self._tau_part = self._buf[:, 2 * n : 3 * n]
        self._ee_part = self._buf[:, 3 * n :]
        self._mask = np.zeros((envs, width), dtype=bool)
        self._ee = np.zeros((envs, 3))
        self._collided = np.zeros(envs, dtype=bool)
        self._hit = np.zeros(envs, dtype=bool)
        self._model = robot.fixed_base_model
        self._data = self._model.createData()
        self._geom_model, self._geom_data = collision_model(robot)
        self._has_pairs = bool(self._geom_model.collisionPairs)
        objects = self._geom_model.geometryObjects
        self.pair_names = [
            f"{objects[p.first].name}|{objects[p.second].name}"
            for p in self._geom_model.collisionPairs
        ]
        self.pair_ticks = np.zeros((envs, len(self.pair_names)), dtype=np.int64)
        self._excuse = None  # excuse_contacts
        self.reference_ticks = np.zeros(envs, dtype=np.int64)
        self.reference_pair_ticks = np.zeros((envs, len(self.pair_names)), dtype=np.int64)
        self.hard_joint_ticks = np.zeros((envs, n), dtype=np.int64)
        self.hard_joint_depth = np.zeros((envs, n))
        self.down_hard_joint_ticks = np.zeros((envs, n), dtype=np.int64)
        self.down_hard_joint_depth = np.zeros((envs, n))
        self.speed_joint_ticks = np.zeros((envs, n), dtype=np.int64)
        self.speed_joint_excess = np.zeros((envs, n))
        self.effort_joint_ticks = np.zeros((envs, n), dtype=np.int64)
        self.effort_joint_excess = np.zeros((envs, n))
        # the collision screen (compiled path): no pair can touch while its distance computed at
        # checked_q exceeds its own bound on how far the joints moved since
        # (sim2real.robots.chain_bounds.collision_pair_weights; an exact screen, as the guard's)
        self._pair_weights = collision_pair_weights(robot)
        self._margin = SCREEN_MARGIN
        self._checked_q = np.zeros((envs, n))
        self._clearance = np.full((envs, len(self._pair_weights)), -np.inf)  # none yet: check
        self._need = np.zeros(envs, dtype=bool)
        self._tmp = np.zeros((envs, n))
        self._screen_bound = self._collision_bound = None  # the screens' calls (see _screen)
        # each env's consecutive coal checks and the tick of its last (see _in_collision)
        self._run, self._last_check = np.zeros(envs, np.int64), np.full(envs, -2, np.int64)
        # coal's pairs of a check between measurements, those the screen lets touch (_in_collision),
        # in the upper triangle of the geoms' map (where setActiveCollisionPairs reads a pair)
        pairs = [sorted((p.first, p.second)) for p in self._geom_model.collisionPairs]
        pairs = np.array(pairs, dtype=np.int64).reshape(-1, 2)
        self._pair_first, self._pair_second = pairs[:, 0].copy(), pairs[:, 1].copy()
        self._pair_map, self._every_pair = np.zeros((2,) + (self._geom_model.ngeoms,) * 2, bool)
        self._every_pair[self._pair_first, self._pair_second] = True
        self._some_pairs = False  # coal checks a part of the pairs (_pair_map) now
        self._pairs_bound = None  # pairs_to_check bound to q (see _active_pairs)
        self._pair_bounds = PairBounds.build(self._model, self._geom_model) if pair_bounds else None
        self._bounds_call = None  # pair_lower_bounds bound to q
        mk.warm_up()

    # ------------------------------------------------------------------ per tick
    def update(self, backend, down: np.ndarray | None = None) -> None:
        """Count this tick's violations from ``backend``'s ground truth.

        Args:
            backend: A :class:`~sim2real.deploy.backends.sim.plant.SimBackend` with ``envs`` envs (its
                ``true_position()`` rad, ``true_velocity()`` rad/s, ``joint_torque()`` N m, all
                (envs, n), and ``end_effector_position(out)`` m, (envs, 3)).
            down: (envs,) bool, the envs lying damped after a stop this tick
                (:attr:`sim2real.deploy.runtime.Runtime.damping`); their ticks go to
                :attr:`down_counts`. None: every env is up (an arm).
        """
        if down is None:
            self._down.fill(False)
        else:
            np.copyto(self._down, down)
        q, dq, tau = backend.true_position(), backend.true_velocity(), backend.joint_torque()
        if self._has_workspace:
            backend.end_effector_position(out=self._ee)
        self._tick_count[0] += 1
        need = self._has_pairs and self._collision_screen(q)
        self.count_flagged(q, dq, tau, need, self._screen(q, dq, tau))

    def count_flagged(
        self, q: np.ndarray, dq: np.ndarray, tau: np.ndarray, need: bool, flagged: bool
    ) -> None:
        """What :meth:`update` does after its screens, given their answers (also for a compiled
        call that ran them over :meth:`kernel_arrays`): coal checks the collision pairs of the
        envs marked in ``need`` of :meth:`kernel_arrays` (when ``need``), then the exact
        per-type tests run if a pair touched or ``flagged``.

        Args:
            q: This tick's true joint positions, (envs, n) rad (the end effector is this
                tick's in ``kernel_arrays()["ee"]``).
            dq: This tick's true joint speeds, (envs, n) rad/s.
            tau: This tick's true joint torques, (envs, n) N m.
            need: Some env's pairs need coal.
            flagged: Some env may be past a limit.
        """
        collided = False
        if need:
            for e in np.flatnonzero(self._need) if self.envs > 1 else (0,):  # need: some env's
                if self._in_collision(q, e):
                    if not collided:
                        self._collided.fill(False)
                        collided = True
                    touching = self._touching()
                    allowed = None if self._excuse is None else self._excuse(e)
                    if allowed is not None and not (touching & ~allowed).any():
                        if not self._down[e]:  # the reference's own contact: apart
                            self.reference_ticks[e] += 1
                            self.reference_pair_ticks[e] += touching
                        continue
                    self._collided[e] = True
                    if not self._down[e]:  # which pairs touched while the robot was up
                        self.pair_ticks[e] += touching
        if collided or flagged:
            self._count(q, dq, tau, collided)

    def kernel_arrays(self) -> dict[str, np.ndarray]:
        """The monitor's live arrays, by name, for a compiled call that runs :meth:`update`'s
        screens (the arrays themselves, C-contiguous, never rebound): ``ee`` (envs, 3) m, this
        tick's end effector; the screen's ``offset_q`` (n,) rad, ``offset_ee`` (3,) m and
        ``bound`` (3 n + 3,) (:func:`sim2real.deploy.monitors.kernel.violation_screen`); the
        collision screen's ``checked_q`` (envs, n) rad, ``clearance`` (envs, pairs) m,
        ``pair_weights`` (pairs, n) m/rad, ``tmp`` (envs, n) and ``need`` (envs,) bool
        (:func:`~sim2real.deploy.monitors.kernel.collision_screen`; its margin
        :attr:`screen_margin`); ``down`` (envs,) bool, this tick's envs down; ``ticks`` (1,)
        int64, what :attr:`ticks` reads. Raises nothing."""
        return {
            "ee": self._ee, "offset_q": self._offset_q, "offset_ee": self._offset_ee,
            "bound": self._bound, "checked_q": self._checked_q, "clearance": self._clearance,
            "pair_weights": self._pair_weights, "tmp": self._tmp, "need": self._need,
            "down": self._down, "ticks": self._tick_count,
        }  # fmt: skip

    def pair_bound_arrays(self) -> tuple | None:
        """The pair bounds' arrays (:meth:`sim2real.deploy.monitors.pair_bounds.PairBounds.
        arrays`) for a compiled call of their screen with :meth:`kernel_arrays`'s
        ``pair_weights``, ``checked_q`` and ``clearance``, or None: no bounds (coal's distances
        screen the pairs)."""
        return None if self._pair_bounds is None else self._pair_bounds.arrays()

    @property
    def screen_margin(self) -> float:
        """m, the collision screen's margin (the guard's)."""
        return self._margin

    @property
    def has_workspace(self) -> bool:
        """Whether the robot has a workspace box (its end effector is screened)."""
        return self._has_workspace

    @property
    def has_pairs(self) -> bool:
        """Whether the guard's collision model has pairs (screened, then checked by coal)."""
        return self._has_pairs

    def _screen(self, q: np.ndarray, dq: np.ndarray, tau: np.ndarray) -> bool:
        """Whether some env may be past a limit (the kernel
        :func:`sim2real.deploy.monitors.kernel.violation_screen`, bound to ``q``, ``dq`` and
        ``tau``: the plant hands the same arrays every tick)."""
        bound = self._screen_bound
        if bound is None or bound[0] is not q or bound[1] is not dq or bound[2] is not tau:
            call = bind(
                mk.violation_screen, q, dq, tau, self._ee, self._offset_q, self._offset_ee,
                self._bound, self._has_workspace,
            )  # fmt: skip
            self._screen_bound = bound = (q, dq, tau, call)
        return bound[3]()

    def _collision_screen(self, q: np.ndarray) -> bool:
        """Mark in ``_need`` the envs whose pairs coal must check at ``q``; returns whether any:
        the guard's exact screen (:func:`sim2real.deploy.monitors.kernel.collision_screen`,
        bound to ``q``)."""
        bound = self._collision_bound
        if bound is None or bound[0] is not q:
            args = (self._checked_q, self._clearance, self._pair_weights, self._margin, self._tmp)
            self._collision_bound = bound = (q, bind(mk.collision_screen, q, *args, self._need))
        return bound[1]()

    def _in_collision(self, q: np.ndarray, e: int) -> bool:
        """Whether a collision pair of env ``e`` touches at ``q[e]`` (coal); also remembers each
        pair's distance there for :meth:`_collision_screen`, unless env ``e`` was checked on the
        tick before too: then the distances measured there did not spare this tick a check, and
        they are measured again only every ``DISTANCE_REFRESH`` consecutive checks (a walking
        robot's legs pass the screen's bound every tick). The screen stays exact with the pair
        of configuration and distances it keeps, however old: the same answers. A model with
        :class:`~sim2real.deploy.monitors.pair_bounds.PairBounds` measures lower bounds of the
        distances instead (compiled): coal only where one is ``APART`` or less, every pair."""
        if self._pair_bounds is not None:
            bound = self._bounds_call
            if bound is None or bound[0] is not q:
                args = (*self.pair_bound_arrays(), self._pair_weights, self._margin)
                args += (self._checked_q, self._clearance, APART)
                bound = self._bounds_call = (q, bind(pair_lower_bounds, q, *args, rest=(0,)))
            if not bound[1](e):  # every pair's bound above APART: coal finds no contact
                return False
            self._every_pair_active()
            hit = collision_query(self._model, self._data, self._geom_model, self._geom_data, q[e])
            if hit:  # checked again next tick
                self._clearance[e] = -np.inf
            return hit
        tick = int(self._tick_count[0])
        run = self._run[e] + 1 if self._last_check[e] == tick - 1 else 0
        self._run[e], self._last_check[e] = run, tick
        args = (self._model, self._data, self._geom_model, self._geom_data, q[e])
        if run % DISTANCE_REFRESH == 0:
            self._every_pair_active()
            self._checked_q[e] = q[e]
            return collision_query(*args, distances=self._clearance[e])
        if not self._active_pairs(q, e):  # no pair of env e may touch
            return False
        hit = collision_query(*args)
        if hit:  # as a query with distances leaves them: all -inf, checked again next tick
            self._every_pair_active()
            self._checked_q[e] = q[e]
            self._clearance[e] = -np.inf
        return hit

    def _active_pairs(self, q: np.ndarray, e: int) -> bool:
        """Let coal check only the pairs of env ``e`` that may touch at ``q[e]`` by the screen's
        bound, pair by pair (:func:`sim2real.deploy.monitors.kernel.pairs_to_check`, bound to
        ``q``: a pair it keeps apart cannot touch); returns whether any may."""
        bound = self._pairs_bound
        if bound is None or bound[0] is not q:
            args = (self._checked_q, self._clearance, self._pair_weights, self._margin, self._tmp)
            pairs = (self._pair_first, self._pair_second, self._pair_map)
            self._pairs_bound = bound = (q, bind(mk.pairs_to_check, q, *args, *pairs, rest=(0,)))
        if not bound[1](e):
            return False
        self._geom_data.setActiveCollisionPairs(self._geom_model, self._pair_map, True)
        self._some_pairs = True
        return True

    def _every_pair_active(self) -> None:
        """Let coal check every pair again (for a distance measurement and :meth:`_touching`)."""
        if self._some_pairs:
            self._geom_data.setActiveCollisionPairs(self._geom_model, self._every_pair, True)
            self._some_pairs = False

    def _touching(self) -> np.ndarray:
        """(pairs,) bool, the pairs that touch (after a hit of :meth:`_in_collision`, whose
        placements the geometry data still holds)."""
        self._every_pair_active()
        pin.computeCollisions(self._geom_model, self._geom_data, False)
        return np.array([r.isCollision() for r in self._geom_data.collisionResults], dtype=bool)

    def excuse_contacts(self, allowed) -> None:
        """Count a self-collision whose touching pairs the reference motion itself brings into
        contact apart (:attr:`reference_ticks`), not as a violation.

        Args:
            allowed: ``allowed(env) -> (pairs,) bool`` in :attr:`pair_names` order, the pairs
                the reference touches around env's moment now, or None (no reference playing:
                every contact is a violation). A
                :meth:`sim2real.deploy.tasks.motion.tracking.TrackingTask.reference_contacts`.
        """
        self._excuse = allowed

    def _count(self, q: np.ndarray, dq: np.ndarray, tau: np.ndarray, collided: bool) -> None:
        """The exact per-type tests (only on ticks the screen or coal flagged)."""
        hit, counts = self._hit, self.counts
        hit.fill(False)
        beyond = (q < self._lower) | (q > self._upper)
        band = ((q < self._soft_lower) | (q > self._soft_upper)) & ~beyond
        ee = self._ee
        tests = (
            ("hard_limit", beyond.any(axis=1)),
            ("soft_limit", band.any(axis=1)),
            ("velocity", (np.abs(dq) > self._velocity).any(axis=1)),
            ("effort", (np.abs(tau) > self._effort).any(axis=1)),
            ("workspace", ((ee < self._ws_min) | (ee > self._ws_max)).any(axis=1)),
        )
        if collided:
            tests += (("self_collision", self._collided),)
        down = self._down
        up = ~down  # only on a tick something was flagged
        self.hard_joint_ticks += beyond & up[:, None]
        self.down_hard_joint_ticks += beyond & down[:, None]
        if beyond.any():  # rad past the limit, the deepest kept (up and down apart)
            depth = np.maximum(self._lower - q, q - self._upper)
            for rows, deepest in ((up, self.hard_joint_depth), (down, self.down_hard_joint_depth)):
                np.maximum(deepest, np.where(beyond & rows[:, None], depth, 0.0), out=deepest)
        for value, limit, ticks, excess in (
            (dq, self._velocity, self.speed_joint_ticks, self.speed_joint_excess),
            (tau, self._effort, self.effort_joint_ticks, self.effort_joint_excess),
        ):
            above = np.abs(value) - limit
            ticks += above > 0.0
            np.maximum(excess, np.where(above > 0.0, above, 0.0), out=excess)
        for name, flags in tests:
            counts[name] += flags & up
            self.down_counts[name] += flags & down
            hit |= flags
        self.any += hit & up
        self.down_any += hit & down

    # ------------------------------------------------------------------ checkpoints
    def _arrays(self) -> dict[str, np.ndarray]:
        out = {f"counts/{t}": v for t, v in self.counts.items()}
        out["any"] = self.any
        out.update({f"down/{t}": v for t, v in self.down_counts.items()})
        out["down_any"] = self.down_any
        out["pair_ticks"] = self.pair_ticks
        out["reference_ticks"] = self.reference_ticks
        out["reference_pair_ticks"] = self.reference_pair_ticks
        out["hard_joint_ticks"] = self.hard_joint_ticks
        out["hard_joint_depth"] = self.hard_joint_depth
        out["down/hard_joint_ticks"] = self.down_hard_joint_ticks
        out["down/hard_joint_depth"] = self.down_hard_joint_depth
        out["speed_joint_ticks"] = self.speed_joint_ticks
        out["speed_joint_excess"] = self.speed_joint_excess
        out["effort_joint_ticks"] = self.effort_joint_ticks
        out["effort_joint_excess"] = self.effort_joint_excess
        return out
