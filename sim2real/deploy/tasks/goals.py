"""Goals of a reaching run and whether they were reached: the goal scheduler ``deploy-run`` and the
soak harness share (:class:`GoalScheduler`), as their task (:class:`GoalTask`, chosen by
:func:`sim2real.deploy.tasks.task.task_for`), the task-region sampler training uses too
(:func:`sample_goal`), and the success rate per window of time (:func:`success_windows`).
"""

from __future__ import annotations

import math

import numpy as np

from sim2real.deploy.core.backend import SimulatedPlant
from sim2real.deploy.core.stateful import (
    check,
    env_list,
    from_json,
    load_parts,
    parts_state_dict,
    put,
    read_records,
    read_streams,
    records_json,
    rng_state,
    set_rng_state,
    set_streams,
    streams_json,
    take,
    to_json,
)
from sim2real.deploy.monitors import kernel as mk

#: Joint poses drawn per goal before :func:`sample_goal` gives up on a ``joint_fraction`` box.
GOAL_TRIES = 1000


def sample_goal(robot, rng: np.random.Generator) -> np.ndarray:
    """A goal (m, base frame, (3,)) from the robot's task region
    (:class:`sim2real.robots.schema.TaskConfig`).

    Raises:
        RuntimeError: a ``joint_fraction`` box that ``GOAL_TRIES`` joint poses never reach.
    """
    task = robot.config.task
    if task.region == "planar_annulus":
        r = rng.uniform(*task.radius)
        a = rng.uniform(*task.angle)
        return np.array([r * np.cos(a), r * np.sin(a), 0.0])
    if task.joint_fraction is None:
        return rng.uniform(task.box_min, task.box_max)
    home = np.asarray(robot.home)
    span = task.joint_fraction * (robot.position_upper - robot.position_lower) / 2.0
    lo, hi = np.asarray(task.box_min), np.asarray(task.box_max)
    for _ in range(GOAL_TRIES):
        q = np.clip(home + rng.uniform(-span, span), robot.soft_lower, robot.soft_upper)
        p = robot.forward_kinematics(q)
        if ((p >= lo) & (p <= hi)).all():
            return p
    raise RuntimeError(
        f"robot {robot.name}: [task] no end-effector position inside box_min/box_max in "
        f"{GOAL_TRIES} joint poses within joint_fraction {task.joint_fraction} of the ranges"
    )


def success_windows(issued: list[int], reached: list[int], window: float, end: float) -> list[dict]:
    """Goal success rate per window of simulated time.

    The run ``[0, end]`` is cut into windows ``[k window, (k + 1) window)``; a goal counts in the
    window in which it was issued (also when it was reached after the window ended). A final
    partial window shorter than half a window is merged into the previous one; windows in which
    no goal was issued are left out.

    Args:
        issued: Goals issued per window (index ``floor(t_issue / window)``); missing trailing
            windows count as 0, indices past the last window count in the last one.
        reached: Goals reached per window of issue, as ``issued``.
        window: Window length, s (> 0).
        end: End of the run, s (>= 0).

    Returns:
        ``[{"start_s", "end_s", "issued", "reached", "success_rate"}]`` in time order.

    Raises:
        ValueError: ``window <= 0`` or ``end < 0``.
    """
    if not window > 0:
        raise ValueError(f"window: expected a number of seconds > 0, got {window}")
    if not end >= 0:
        raise ValueError(f"end: expected a time >= 0 s, got {end}")
    count = max(1, math.ceil(end / window - 1e-9))
    rows = [[k * window, min((k + 1) * window, end), 0, 0] for k in range(count)]
    for column, values in ((2, issued), (3, reached)):
        for k, n in enumerate(values):
            rows[min(k, count - 1)][column] += int(n)
    if count > 1 and rows[-1][1] - rows[-1][0] < 0.5 * window:
        last = rows.pop()
        rows[-1][1] = last[1]
        rows[-1][2] += last[2]
        rows[-1][3] += last[3]
    return [
        {"start_s": a, "end_s": b, "issued": i, "reached": r, "success_rate": r / i}
        for a, b, i, r in rows
        if i > 0
    ]


class GoalScheduler:
    """New goals every ``period`` s (or one fixed goal); records when each was reached (sim).

    Only time in RUNNING counts: while an env is not running its unreached goal's clock is reset
    (so after a safe stop the goal gets its full ``period`` and ``success_time`` again), and an
    env gets its first goal when it starts running. A goal counts as reached when the end
    effector comes within ``task.success_radius`` of it at most ``success_time`` s after it was
    issued. A goal replaced by the next one without having been reached is *missed*: its end
    state is recorded (:attr:`missed`).

    Args:
        robot: The robot (task region, success radius).
        envs: Number of envs.
        period: s between new goals (ignored with ``fixed``).
        fixed: Optional fixed goal (3,) m, base frame, for every env.
        success_time: s.
        rng: One ``numpy.random.Generator`` for the batch (goals drawn in env order), or a
            sequence of ``envs`` generators, one goal stream per env (batched soak sessions, so
            that a session's goals do not depend on its neighbours).
        window: s, the windows of :meth:`windows` (windowed success rate).
        interventions: Optional :class:`sim2real.deploy.monitors.interventions.InterventionMonitor`, updated
        before
            this scheduler each tick: a missed goal then records the ticks of each check during
            its period.
        max_missed: Missed goals recorded per env; later ones are only counted
            (``missed_dropped``).

    Attributes:
        t_goal: (envs,) s, when each env's goal was issued, moved on while the env was not
            running. issued_at: (envs,) s, when it was issued. reached: (envs,) bool.
        best_distance: (envs,) m, the closest the true end effector came to the current goal
            while it could still be reached (within ``success_time`` of running time); inf before.
        issued, hit_count: (envs,) int, goals issued and reached per env. hit_times: per env, the
            list of times to reach (s). goals, hits, times: the same summed over envs.
        window_issued, window_reached: per env, goals issued and reached per window of issue.
        missed: per env, the missed goals (:meth:`missed_record`), at most ``max_missed``;
            missed_dropped: (envs,) int64, those not recorded.

    With a simulated backend (:class:`~sim2real.deploy.core.backend.SimulatedPlant`) whether a goal was
    reached is judged on the true end effector, and missed goals record the true joint state; with
    any other backend (a servo bus: no ground truth) on the runtime's estimate (forward kinematics
    of the estimated joint angles, ``rt.state``).
    """

    def __init__(
        self,
        robot,
        envs,
        period,
        fixed,
        success_time,
        rng,
        window: float = 600.0,
        interventions=None,
        max_missed: int = 2000,
    ):
        self.robot, self.period, self.fixed = robot, period, fixed
        self.streams = list(rng) if isinstance(rng, (list, tuple)) else None
        if self.streams is not None and len(self.streams) != envs:
            raise ValueError(f"rng: expected {envs} generators (one per env), got {len(rng)}")
        if not window > 0:
            raise ValueError(f"window: expected a number of seconds > 0, got {window}")
        self.rng = rng if self.streams is None else None  # the batch's one stream
        self.success_radius = robot.config.task.success_radius
        self.success_time = success_time
        self.envs = envs
        self.window = float(window)
        self.interventions = interventions
        self.max_missed = int(max_missed)
        self.t_goal = np.zeros(envs)
        self.issued_at = np.zeros(envs)
        self.reached = np.zeros(envs, dtype=bool)
        self.best_distance = np.full(envs, np.inf)
        self.issued = np.zeros(envs, dtype=np.int64)
        self.hit_count = np.zeros(envs, dtype=np.int64)
        self.hit_times: list[list[float]] = [[] for _ in range(envs)]
        self.window_issued: list[list[int]] = [[] for _ in range(envs)]
        self.window_reached: list[list[int]] = [[] for _ in range(envs)]
        self.missed: list[list[dict]] = [[] for _ in range(envs)]
        self.missed_dropped = np.zeros(envs, dtype=np.int64)
        checks = len(interventions.counts) + 1 if interventions is not None else 0
        #: the intervention monitor's counters (and ``any``) when each env's goal was issued
        self.intervention_base = np.zeros((checks, envs), dtype=np.int64)
        self._ee = np.zeros((envs, 3))
        self._diff = np.zeros((envs, 3))
        self._distance = np.zeros(envs)
        self._age = np.zeros(envs)
        self._due = np.zeros(envs, dtype=bool)
        self._check = np.zeros(envs, dtype=bool)
        self._hit = np.zeros(envs, dtype=bool)
        self._backend, self._is_plant = None, False  # the last backend seen (see _simulated)
        mk.warm_up()

    # ------------------------------------------------------------------ state
    def _state_fields(self) -> dict[str, np.ndarray]:
        return {
            "t_goal": self.t_goal,
            "issued_at": self.issued_at,
            "reached": self.reached,
            "best_distance": self.best_distance,
            "issued": self.issued,
            "hit_count": self.hit_count,
            "missed_dropped": self.missed_dropped,
            "intervention_base": self.intervention_base.T,  # (envs, checks + 1), a view
        }

    def _records(self) -> dict[str, list]:
        return {
            "hit_times": self.hit_times,
            "window_issued": self.window_issued,
            "window_reached": self.window_reached,
            "missed": self.missed,
        }

    def state_dict(self, env: int | None = None) -> dict:
        """The scheduler's state (copies; conventions of :mod:`sim2real.deploy.core.stateful`).

        Arrays, (envs,) (length 1 for one env ``env``): ``t_goal``, ``issued_at`` (s),
        ``reached`` (bool), ``best_distance`` (m), ``issued``, ``hit_count``, ``missed_dropped``
        (int64), and ``intervention_base`` (envs, checks + 1) int64. JSON text, a list over the
        envs: ``hit_times``, ``window_issued``, ``window_reached``, ``missed``. ``rng``: JSON of
        the goal streams' ``bit_generator.state`` (a list over the envs with one stream per
        env; the batch's one stream, shared, otherwise; absent without a generator).
        """
        envs = env_list(self.envs, env)
        out: dict = take(self._state_fields(), env) | records_json(self._records(), envs)
        if self.streams is not None:
            out["rng"] = streams_json(self.streams, envs)
        elif self.rng is not None:
            out["rng"] = to_json(rng_state(self.rng))
        return out

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``), into a scheduler
        built with the same kind of random streams.

        Raises:
            StateDictError: a missing field, a shape or an env count that differs; nothing is
                changed.
        """
        fields = self._state_fields()
        check(fields, state, env)
        envs = env_list(self.envs, env)
        records = read_records(state, self._records(), len(envs))
        rng = None
        if self.streams is not None:
            rng = read_streams(state, "rng", len(envs))
        elif self.rng is not None:
            rng = from_json(state, "rng")
        put(fields, state, env)
        for key, lists in self._records().items():
            for e, value in zip(envs, records[key], strict=True):
                lists[e] = list(value)
        if self.streams is not None:
            set_streams(self.streams, envs, rng, "rng")
        elif self.rng is not None:
            set_rng_state(self.rng, rng, "rng")

    @property
    def goals(self) -> int:
        return int(self.issued.sum())

    @property
    def hits(self) -> int:
        return int(self.hit_count.sum())

    @property
    def times(self) -> list[float]:
        return [t for times in self.hit_times for t in times]

    def windows(self, e: int, end: float) -> list[dict]:
        """Env ``e``'s goal success per window of ``window`` s over ``[0, end]`` s
        (:func:`success_windows`)."""
        return success_windows(self.window_issued[e], self.window_reached[e], self.window, end)

    def _window(self, counts: list[int], t: float) -> None:
        k = int(t // self.window)
        if len(counts) <= k:
            counts.extend([0] * (k + 1 - len(counts)))
        counts[k] += 1

    def new_goal(self, rt, e: int) -> None:
        if self.issued[e] > 0 and not self.reached[e]:
            self.missed_record(rt, e)
        if self.fixed is not None:
            rt.goal[e] = self.fixed
        else:
            rt.goal[e] = sample_goal(self.robot, self.streams[e] if self.streams else self.rng)
        self.t_goal[e] = rt.time
        self.issued_at[e] = rt.time
        self.reached[e] = False
        self.best_distance[e] = np.inf
        self.issued[e] += 1
        self._window(self.window_issued[e], rt.time)
        if self.interventions is not None:
            base = self.intervention_base
            for i, values in enumerate(self.interventions.counts.values()):
                base[i, e] = values[e]
            base[-1, e] = self.interventions.any[e]

    def missed_record(self, rt, e: int) -> None:
        """Record env ``e``'s current goal as missed (at the end of its period), in
        :attr:`missed` (or count it in ``missed_dropped`` past ``max_missed``)::

            {"t_s": s, now; "issued_s": s; "goal": [x, y, z] m; "q": true joint positions, rad;
             "dq": true joint velocities, rad/s; "q_estimate": the runtime's estimate, rad;
             "distance_m": true end effector to goal now; "best_distance_m": the closest it came
             while the goal could be reached (None if it never could);
             "interventions": {check: ticks during the goal's period, ..., "any": ticks}}
        """
        if len(self.missed[e]) >= self.max_missed:
            self.missed_dropped[e] += 1
            return
        goal = rt.goal[e]
        ee = self.end_effector(rt)[e]
        best = float(self.best_distance[e])
        true = self._simulated(rt.backend)
        q = rt.backend.true_position() if true else rt.state.q
        dq = rt.backend.true_velocity() if true else rt.state.dq
        record = {
            "t_s": float(rt.time),
            "issued_s": float(self.issued_at[e]),
            "goal": [float(x) for x in goal],
            "q": [float(x) for x in q[e]],
            "dq": [float(x) for x in dq[e]],
            "q_estimate": [float(x) for x in rt.state.q[e]],
            "distance_m": float(np.sqrt(np.sum((ee - goal) ** 2))),
            "best_distance_m": best if math.isfinite(best) else None,
            "interventions": {},
        }
        if self.interventions is not None:
            base = self.intervention_base
            names = [*self.interventions.counts, "any"]
            values = [*self.interventions.counts.values(), self.interventions.any]
            record["interventions"] = {
                name: int(v[e] - base[i, e])
                for i, (name, v) in enumerate(zip(names, values, strict=True))
            }
        self.missed[e].append(record)

    def _simulated(self, backend) -> bool:
        """Whether ``backend`` is a simulated plant (remembered per backend: a Protocol's
        isinstance check is slow)."""
        if backend is not self._backend:
            self._backend, self._is_plant = backend, isinstance(backend, SimulatedPlant)
        return self._is_plant

    def end_effector(self, rt) -> np.ndarray:
        """(envs, 3) m: the true end effector (simulation) or the estimated one (class doc)."""
        if self._simulated(rt.backend):
            return rt.backend.end_effector_position(out=self._ee)
        return rt.state.ee_position

    def __call__(self, rt) -> None:
        """One tick after the runtime's: issue the goals that are due (in env order), record the
        goals reached (class doc), with the kernels :func:`sim2real.deploy.monitors.kernel.goal_screen`
        and ``goal_hits`` (their numpy reference:
        :class:`sim2real.deploy.tasks.reference.ReferenceGoalScheduler`)."""
        t = rt.time
        due, check, hit = self._due, self._check, self._hit
        bits = mk.goal_screen(
            t, rt.mode, 2, self.issued, self.t_goal, self.reached, self.period,
            self.fixed is None, self.success_time, self._age, due, check,
        )  # fmt: skip
        if bits & mk.ANY_DUE:
            self.issue_due(rt)
        if bits & mk.ANY_CHECK:
            ee = self.end_effector(rt)
            any_hit = mk.goal_hits(
                ee, rt.goal, check, self.best_distance, self.success_radius, self._distance, hit
            )
            if any_hit:
                self.record_hits()

    def issue_due(self, rt) -> None:
        """Issue a new goal to each env marked due by this tick's screen (``due`` of
        :meth:`kernel_arrays`), in env order (one stream for a batch)."""
        for e in np.flatnonzero(self._due):
            self.new_goal(rt, e)

    def record_hits(self) -> None:
        """Record the goals this tick's hit test found reached (``hit`` of :meth:`kernel_arrays`,
        at the ages of ``age``)."""
        self._record_hits(np.flatnonzero(self._hit), self._age)

    def kernel_arrays(self) -> dict[str, np.ndarray]:
        """The live arrays of a tick (:meth:`__call__`), by name, for a compiled call that runs
        its screen and hit test (:func:`sim2real.deploy.monitors.kernel.goal_screen`,
        ``goal_hits``; the arrays themselves, C-contiguous, never rebound), (envs,) each:
        ``issued`` int64, ``t_goal`` s, ``reached`` bool, ``best_distance`` m, this tick's
        ``age`` s, ``due``, ``check`` and ``hit`` bool and ``distance`` m; ``ee`` (envs, 3) m, the
        end effector judged. Python then calls :meth:`issue_due` and :meth:`record_hits` as the
        screen says. Raises nothing."""
        return {
            "issued": self.issued, "t_goal": self.t_goal, "reached": self.reached,
            "best_distance": self.best_distance, "age": self._age, "due": self._due,
            "check": self._check, "hit": self._hit, "distance": self._distance, "ee": self._ee,
        }  # fmt: skip

    def _record_hits(self, envs: np.ndarray, age: np.ndarray) -> None:
        """The envs ``envs`` reached their goal at ``age[e]`` s after it was issued."""
        for e in envs:
            self.reached[e] = True
            self.hit_count[e] += 1
            self.hit_times[e].append(float(age[e]))
            self._window(self.window_reached[e], self.issued_at[e])


class GoalTask:
    """The reach-goals task (:class:`sim2real.deploy.tasks.task.Task`) of an arm: a :class:`GoalScheduler`
    (its arguments; ``window`` None: its default).

    Attributes:
        scheduler: The :class:`GoalScheduler`; checkpoint prefix ``goals``.
    """

    name = "goals"

    def __init__(
        self, robot, envs, period, fixed, success_time, rng, window=None, interventions=None
    ):
        extra = {} if window is None else {"window": window}
        self.scheduler = GoalScheduler(
            robot, envs, period, fixed, success_time, rng, interventions=interventions, **extra
        )

    def reset(self, runtime, envs: np.ndarray) -> None:
        """Nothing: an env gets its first goal when it first runs."""

    def __call__(self, runtime) -> None:
        self.scheduler(runtime)

    def set_goal(self, runtime, goal) -> None:
        """An operator's goal ((3,) m, base frame; ``deploy-run --ros2``'s ``goal_point``):
        issued at once to every env and kept (a fixed goal) until the next one; the goal it
        replaces counts as missed if it was not reached."""
        s = self.scheduler
        s.fixed = np.array(goal, dtype=np.float64).reshape(3)
        for e in range(runtime.envs):
            s.new_goal(runtime, e)

    def success(self, env: int | None = None) -> float | None:
        """Goals reached / goals issued (of env ``env``, or all envs); None before any."""
        s = self.scheduler
        issued = s.goals if env is None else int(s.issued[env])
        hits = s.hits if env is None else int(s.hit_count[env])
        return hits / issued if issued else None

    def report(self, runtime) -> dict:
        s = self.scheduler
        judged = "true" if s._simulated(runtime.backend) else "estimated"
        return {
            "goals": {
                "issued": s.goals,
                "reached": s.hits,
                "success_rate": self.success(),
                "median_time_to_reach_s": float(np.median(s.times)) if s.times else None,
                "within_s": s.success_time,
                "judged_on": f"{judged} end effector",
            },
            "locomotion": None,
            "missed_goals": sum(len(m) for m in s.missed) + int(s.missed_dropped.sum()),
        }

    def curve_start(self) -> dict[str, list]:
        return {"issued": [0], "reached": [0]}

    def curve_point(self, curve: dict[str, list], e: int) -> None:
        curve["issued"].append(int(self.scheduler.issued[e]))
        curve["reached"].append(int(self.scheduler.hit_count[e]))

    def parts(self) -> dict:
        """The task's stateful parts by checkpoint prefix."""
        return {"goals": self.scheduler}

    def state_dict(self, env: int | None = None) -> dict:
        return parts_state_dict(self.parts(), env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        load_parts(self.parts(), state, env)
