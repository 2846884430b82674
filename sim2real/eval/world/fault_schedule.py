"""The fault schedule of a soak session: which faults, when, and how hard.

A session's faults (:class:`FaultRanges`, drawn by :func:`sample_fault_schedule` from the session's
``faults`` stream) are sized so that the runtime can survive each of them by design: sensor faults
against the session's stale budget (:func:`stale_budget`: the longest gap in readings the runtime
bridges), cable pulls against the drives' short-time reserve (:func:`cable_budget`: the largest
hanging load the derating drives hold in any pose for the pull's duration). A fault beyond those
budgets would test the sensor or motor sizing, not the runtime: the soak would fail whatever the
controller did.

Schedules are lists of :class:`sim2real.deploy.backends.sim.faults.Fault`; :func:`fault_to_dict` and
:func:`fault_from_dict` write and read them in reports and checkpoints.
"""

from __future__ import annotations

import dataclasses
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from sim2real.deploy.kinds import robot_kind
from sim2real.eval.world.checks import check_range
from sim2real.eval.world.fault_draws import (
    FAULT_DRAWS,
    DrawContext,
    default_fault_kinds,
    sensor_gap_kinds,
)
from sim2real.eval.world.world_faces import WORLD_OF_KIND
from sim2real.robots import Robot

if TYPE_CHECKING:
    from sim2real.eval.world.sensors import SensorDraw


@dataclass(frozen=True)
class FaultRanges:
    """The fault schedule of a session: onsets of a Poisson process, kinds drawn by weight, one
    fault at a time.

    Attributes:
        mean_interval: Mean time between the end of one fault and the onset of the next, s
            (exponential; our choice: 120 s, about 240 faults in 8 hours).
        min_gap: Quiet time after each fault, s (at least ``FAULT_SETTLE + 1``; the runtime's
            response is judged ``FAULT_SETTLE`` s after the fault ends).
        warmup: No fault before this session time, s (ramp-in).
        kinds: Kinds to draw from, each with a registered draw
            (:data:`~sim2real.eval.world.fault_draws.FAULT_DRAWS`); default: those
            ``in_default_draw`` (the six built-in ones), in registration order.
        weights: Relative weights of ``kinds`` (None: equal).
        dropout: Duration of a dropout burst, as a fraction of the stale budget.
        stale: Duration of a stale (frozen) sensor frame, as a fraction of the stale budget.
        nan_ticks: Consecutive non-finite actions, control ticks (inclusive; below
            ``sim2real.deploy.runtime.NAN_ACTION_LIMIT`` = 10 the runtime holds, at it it stops).
        latency_ticks: Extra encoder latency of a spike, as a fraction of the largest spike that
            stays within the stale limit (:func:`gap_ticks`; rounded, at least 1 tick; a session
            where no tick fits draws no spike).
        latency_duration: Duration of a latency spike, s.
        push_force: Force of a push on the end effector (on the base of a floating-base robot),
            N (along +X; ``PUSH_FORCE`` is 20).
        push_duration: Duration of a push, s.
        cable_force: Force of a cable pulling on the end effector (along gravity), as a fraction
            of the robot's :func:`cable_budget` for the pull's duration: at 1 the drives of a
            warm arm in its worst pose just hold it.
        cable_duration: Duration of a cable pull, s.
    """

    mean_interval: float = 120.0
    min_gap: float = 5.0
    warmup: float = 10.0
    kinds: tuple[str, ...] = field(default_factory=default_fault_kinds)
    weights: tuple[float, ...] | None = None
    dropout: tuple[float, float] = (0.2, 0.8)
    stale: tuple[float, float] = (0.2, 0.8)
    nan_ticks: tuple[int, int] = (1, 5)
    latency_ticks: tuple[float, float] = (0.3, 1.0)
    latency_duration: tuple[float, float] = (0.2, 2.0)
    push_force: tuple[float, float] = (5.0, 25.0)
    push_duration: tuple[float, float] = (0.05, 0.5)
    cable_force: tuple[float, float] = (0.5, 1.0)
    cable_duration: tuple[float, float] = (10.0, 60.0)

    def __post_init__(self):
        from sim2real.deploy.backends.sim.fault_kinds import FAULT_KINDS

        owner = "FaultRanges"
        drawn = tuple(k for k in FAULT_DRAWS.names() if k in FAULT_KINDS.names())
        if not (np.isfinite(self.mean_interval) and self.mean_interval > 0):
            raise ValueError(f"{owner}.mean_interval: expected > 0 s, got {self.mean_interval}")
        if not (np.isfinite(self.min_gap) and self.min_gap >= FAULT_SETTLE + 1.0):
            raise ValueError(
                f"{owner}.min_gap: expected >= {FAULT_SETTLE + 1.0} s, got {self.min_gap}"
            )
        if not (np.isfinite(self.warmup) and self.warmup >= 0):
            raise ValueError(f"{owner}.warmup: expected >= 0 s, got {self.warmup}")
        if not self.kinds:
            raise ValueError(f"{owner}.kinds: expected at least one of {drawn}")
        for kind in self.kinds:
            if kind not in drawn:
                raise ValueError(f"{owner}.kinds: '{kind}' is unknown; expected one of {drawn}")
        if self.weights is not None and (
            len(self.weights) != len(self.kinds)
            or not all(np.isfinite(w) and w >= 0 for w in self.weights)
            or sum(self.weights) <= 0
        ):
            raise ValueError(
                f"{owner}.weights: expected {len(self.kinds)} weights >= 0 (one per kind) with a "
                f"positive sum, got {self.weights}"
            )
        for name in ("dropout", "stale", "latency_ticks", "latency_duration", "push_force"):
            check_range(owner, name, *getattr(self, name))
        for name in ("push_duration", "cable_duration"):
            check_range(owner, name, *getattr(self, name))
        check_range(owner, "cable_force", *self.cable_force)
        if self.cable_force[1] > 1.0:
            raise ValueError(
                f"{owner}.cable_force: expected fractions of the cable budget in [0, 1] (above 1 "
                f"the drives cannot hold the pull: that tests the motor sizing, not the runtime), "
                f"got {self.cable_force}"
            )
        check_range(owner, "nan_ticks", *self.nan_ticks, minimum=1)
        for name in ("dropout", "stale", "latency_duration", "push_duration", "cable_duration"):
            if getattr(self, name)[0] <= 0:
                raise ValueError(
                    f"{owner}.{name}: expected durations > 0, got {getattr(self, name)}"
                )


#: s after a fault ends at which the soak harness judges the runtime's response.
FAULT_SETTLE = 2.0
#: The built-in fault kinds that leave the estimator without a fresh reading for a while, sized
#: against :func:`gap_ticks`; a session in which no whole tick fits draws none of them (every
#: kind whose draw says ``sensor_gap``: :func:`~sim2real.eval.world.fault_draws.sensor_gap_kinds`).
SENSOR_GAP_KINDS = sensor_gap_kinds()


def gap_ticks(robot: Robot, latency_ticks: int) -> int:
    """The longest gap in fresh encoder readings, whole control ticks, that the runtime bridges
    without a safe stop with a sensor latency of ``latency_ticks``: the largest ``k`` with
    ``(latency_ticks + k + 1) * control_period`` strictly below ``Robot.stale_limit`` (one period
    for the reading in flight). The runtime stops when the newest absorbed reading is older than
    the limit (``JointStateEstimator.time_since_fresh``); in the plant a gap of ``k`` ticks ages
    it to ``(latency_ticks + k) * control_period``. The limit spans at least
    ``MIN_STALE_TICKS`` (8) periods (``Robot.stale_limit``): with the soak's latencies (0-2
    ticks) 4 or more ticks fit at any control rate (before, a 50 Hz robot's 0.05 s limit fitted
    none with 1-2 ticks of latency, and those sessions drew no sensor fault). 0 or less: no gap
    fits, and the session draws no sensor fault."""
    ratio = robot.stale_limit / robot.control_period
    return int(np.ceil(ratio - 1e-9)) - 2 - int(latency_ticks)


def stale_budget(robot: Robot, latency_ticks: int) -> float:
    """Longest gap in fresh encoder readings (s) the runtime bridges without a safe stop, with a
    sensor latency of ``latency_ticks``: :func:`gap_ticks` control periods (0 when none fits)."""
    return max(gap_ticks(robot, latency_ticks), 0) * robot.control_period


def _without(
    kinds: tuple[str, ...], weights: np.ndarray, drop: tuple[str, ...], refusal: str
) -> tuple[tuple[str, ...], np.ndarray]:
    """``kinds`` and their ``weights`` without those in ``drop``.

    Raises:
        ValueError: ``refusal``, when none is left to draw (no kind, or no weight).
    """
    keep = [i for i, k in enumerate(kinds) if k not in drop]
    kinds, weights = tuple(kinds[i] for i in keep), weights[keep]
    if not kinds or weights.sum() <= 0:
        raise ValueError(refusal)
    return kinds, weights


def fault_ranges(robot, mean_interval: float | None = None) -> FaultRanges:
    """The soak's fault ranges for ``robot``: the defaults, with what its ``[soak]`` table
    (:class:`sim2real.robots.schema.SoakConfig`) sizes to it, and ``mean_interval`` (s) when given.

    Raises:
        ValueError: a range out of bounds (:meth:`FaultRanges.__post_init__`).
    """
    changes = {}
    soak = robot.config.soak
    if soak is not None and soak.push_force is not None:
        changes["push_force"] = tuple(float(f) for f in soak.push_force)
    if mean_interval is not None:
        changes["mean_interval"] = mean_interval
    return dataclasses.replace(FaultRanges(), **changes)


#: s, time step of the thermal integration of :func:`cable_budget` (winding time constants are tens
#: of seconds: the error is far below the bisection's resolution).
BUDGET_STEP = 0.05
#: Candidate torques per joint in :func:`cable_budget`, evenly between the gravity bound and the
#: peak torque.
BUDGET_CANDIDATES = 256


def cable_budget(
    robot: Robot, durations: np.ndarray, model: mujoco.MjModel | None = None
) -> np.ndarray:
    """The largest force (N) a cable may pull on the end effector, along gravity, for each of
    ``durations`` (s), such that the derating drives still hold the arm: the short-time rating of
    the robot at its end effector (IEC 60034-1 duty type S2, from the motor thermal model).

    Worst case over all poses, so a pull within the budget is survivable by design, as the sensor
    faults are sized against the stale budget (:func:`stale_budget`): each joint's load is its
    gravity bound plus the cable force times its lever (``sim2real.robots.chain_bounds.motion_bounds`` and
    ``end_effector_lever``, both for ``model``); its motor starts warm from holding the gravity
    bound (the steady state, or the derating start where that is lower or none exists) and must not
    fold back below the load (:class:`sim2real.robots.thermal.EffortDerating`, the plant's law) before the
    duration ends. A pull above the budget tests the motor sizing, not the runtime: the arm yields
    onto its limits whatever the controller does.

    Args:
        robot: The robot (effort limits, motors, end-effector site).
        durations: (k,) s, pull durations, >= 0.
        model: The plant's MuJoCo model (a randomized session's); default ``robot.mj_model``.

    Returns:
        (k,) N, >= 0, non-increasing in the duration; 0 where some joint has no torque left above
        gravity (an arm whose motors cannot hold it stretched gets no cable pulls).
    """
    from sim2real.robots.chain_bounds import end_effector_lever, motion_bounds
    from sim2real.robots.thermal import EffortDerating, TwoNodeThermalModel

    durations = np.asarray(durations, dtype=np.float64)
    if durations.ndim != 1 or not np.all(np.isfinite(durations)) or np.any(durations < 0):
        raise ValueError(f"cable_budget: expected durations (k,) >= 0 s, got {durations}")
    n = robot.n_joints
    nominal_hold = motion_bounds(robot)[1]
    hold = nominal_hold if model is None else motion_bounds(robot, model)[1]
    lever = end_effector_lever(robot, model)
    derating = EffortDerating(robot, hold=nominal_hold)  # the plant's law (nominal)
    ambient = robot.config.sensors.ambient_temperature
    frac = np.linspace(0.0, 1.0, BUDGET_CANDIDATES)[:, None]
    torque = hold + frac * np.maximum(derating.peak - hold, 0.0)  # (K, n) candidate loads
    thermal = TwoNodeThermalModel(robot.motors, BUDGET_CANDIDATES, ambient)
    try:
        warm = thermal.steady_state(np.broadcast_to(hold, (BUDGET_CANDIDATES, n)))
    except ValueError:  # thermal runaway: holding the gravity bound overheats the motor
        warm = np.full((BUDGET_CANDIDATES, n), np.inf)
    warm = np.minimum(warm, derating.start)
    thermal.winding_temperature[:] = warm
    # the housing on the same steady heat flow: T_h - T_a = (T_w - T_a) R_ha / (R_wh + R_ha)
    thermal.housing_temperature[:] = ambient + (warm - ambient) * (
        thermal.r_ha / (thermal.r_wh + thermal.r_ha)
    )
    held = np.full((BUDGET_CANDIDATES, n), np.inf)  # s, when each candidate load first yields
    held[derating.peak * derating.factor(warm) < torque] = 0.0
    steps = int(np.ceil(durations.max(initial=0.0) / BUDGET_STEP))
    for s in range(steps):
        thermal.step(torque, BUDGET_STEP)
        yields = (derating.peak * derating.factor(thermal.winding_temperature) < torque) & (
            held == np.inf
        )
        held[yields] = (s + 1) * BUDGET_STEP
    budget = np.zeros(len(durations))
    for k, d in enumerate(durations):
        force = np.inf
        for j in range(n):
            if lever[j] <= 0:
                continue
            ok = held[:, j] >= d
            reserve = torque[ok, j].max() - hold[j] if ok.any() else 0.0
            force = min(force, max(reserve, 0.0) / lever[j])
        budget[k] = 0.0 if force == np.inf else force
    return budget


def sample_fault_schedule(
    robot: Robot,
    rng: np.random.Generator,
    duration: float,
    sensors: SensorDraw,
    ranges: FaultRanges | None = None,
    model: mujoco.MjModel | None = None,
) -> list:
    """A seeded fault schedule over ``[0, duration)`` s of session time.

    Onsets follow a Poisson process (exponential gaps of mean ``ranges.mean_interval`` after each
    fault's end plus ``min_gap``), never before ``warmup``; a fault ends before ``duration``. The
    kind and its parameters are drawn per fault (see :class:`FaultRanges`); sensor faults are sized
    against the session's own encoder latency (``sensors``), cable pulls against the drives'
    reserve (:func:`cable_budget`) in the session's plant ``model`` (default: the nominal one).
    A floating-base robot gets no cable pulls (``cable`` is left out of its kinds, and its weight
    with it): it has no end effector to pull on, and the cable budget is an arm's. A session whose
    latency leaves no whole tick of gap within the stale limit (:func:`gap_ticks` < 1) gets no
    dropout, stale or latency fault (:data:`SENSOR_GAP_KINDS`, left out the same way): the
    shortest of them would stop the robot whatever the runtime did.

    Raises:
        ValueError: the kinds left after those leave none to draw.

    Returns:
        list of :class:`sim2real.deploy.backends.sim.faults.Fault` (``envs`` None: every env of the injector
        they are given to), sorted by start.
    """
    from sim2real.deploy.backends.sim.faults import Fault

    ranges = FaultRanges() if ranges is None else ranges
    dt = robot.control_period
    budget = stale_budget(robot, sensors.latency_ticks)
    max_spike = gap_ticks(robot, sensors.latency_ticks)
    kinds, weights = _drawable_kinds(robot, ranges, sensors, max_spike)
    weights = weights / weights.sum()
    context = DrawContext(robot, ranges, budget, max_spike, _CableBudget(robot, ranges, model))
    draws = FAULT_DRAWS.entries()
    faults = []
    t = ranges.warmup
    while True:
        t += float(rng.exponential(ranges.mean_interval))
        kind = kinds[int(rng.choice(len(kinds), p=weights))]
        length, magnitude = draws[kind].draw(context, rng)
        # start on a control tick, last whole ticks: the schedule means the same at any rate
        start = np.ceil(t / dt) * dt
        length = max(np.round(length / dt), 1.0) * dt
        if start + ranges.min_gap > duration:
            return faults
        if start + length + ranges.min_gap > duration:
            continue  # too long for the time left: a shorter one may still fit
        faults.append(Fault(kind, round(float(start), 9), round(float(length), 9), None, magnitude))
        t = start + length + ranges.min_gap


def _drawable_kinds(robot: Robot, ranges: FaultRanges, sensors: SensorDraw, max_spike: int):
    """The fault kinds the session may draw and their weights (not normalized): no sensor gap
    where none fits the stale limit, none the kind's world refuses (a legged robot's: no cable
    pull, :data:`~sim2real.eval.world.world_faces.WORLD_OF_KIND`), none a kind's draw refuses
    the robot (:attr:`~sim2real.eval.world.fault_draws.FaultDraw.refuses`).

    Raises:
        ValueError: the kinds left after those leave none to draw.
    """
    kinds = ranges.kinds
    dt = robot.control_period
    weights = np.ones(len(kinds)) if ranges.weights is None else np.array(ranges.weights)
    gaps = sensor_gap_kinds()
    if max_spike < 1 and any(k in gaps for k in kinds):
        kinds, weights = _without(
            kinds, weights, gaps,
            f"robot {robot.name}: no sensor gap fits its stale limit "
            f"({robot.stale_limit} s at {1 / dt:g} Hz with "
            f"{sensors.latency_ticks} ticks of latency); the fault kinds {ranges.kinds} "
            "leave none to draw",
        )  # fmt: skip
    refused = WORLD_OF_KIND.get(robot_kind(robot)).refused_faults()
    for fault in [k for k in refused if k in kinds]:  # the kind's world's (a legged: no cable)
        kinds, weights = _without(
            kinds, weights, (fault,),
            f"robot {robot.name}: {refused[fault]}; the fault kinds {ranges.kinds} leave none "
            "to draw",
        )  # fmt: skip
    draws = FAULT_DRAWS.entries()
    for fault in list(kinds):  # a kind's own refusal (a camera fault: a robot without one)
        why = draws[fault].refuses(robot) if draws[fault].refuses is not None else None
        if why is not None:
            kinds, weights = _without(
                kinds, weights, (fault,),
                f"robot {robot.name}: {why}; the fault kinds {ranges.kinds} leave none to draw",
            )  # fmt: skip
    return kinds, weights


class _CableBudget:
    """A cable pull's budget (N) for its duration: :func:`cable_budget` on a grid of durations,
    computed at the first pull, read at the next longer duration on the grid (never above the
    pull's own)."""

    def __init__(self, robot: Robot, ranges: FaultRanges, model):
        self.robot, self.model = robot, model
        self.durations = np.linspace(0.0, ranges.cable_duration[1], 241)
        self.budget = None

    def __call__(self, length: float) -> float:
        if self.budget is None:
            self.budget = cable_budget(self.robot, self.durations, self.model)
        k = min(int(np.searchsorted(self.durations, length)), len(self.durations) - 1)
        return float(self.budget[k])


def fault_to_dict(fault) -> dict:
    """A :class:`sim2real.deploy.backends.sim.faults.Fault` as a JSON-ready dict."""
    d = asdict(fault)
    for key in ("envs", "direction"):
        if d.get(key) is not None:
            d[key] = list(d[key])
    return d


def fault_from_dict(data: dict):
    """Inverse of :func:`fault_to_dict`.

    Raises:
        ValueError: a missing or invalid field (named).
    """
    from sim2real.deploy.backends.sim.faults import FAULT_KINDS, Fault

    try:
        kind = str(data["kind"])
        if kind not in FAULT_KINDS.names():
            raise ValueError(
                f"fault kind '{kind}' is unknown; expected one of {FAULT_KINDS.names()}"
            )
        envs = data.get("envs")
        direction = data.get("direction")
        magnitude = data.get("magnitude")
        return Fault(
            kind,
            float(data["start"]),
            float(data["duration"]),
            None if envs is None else tuple(int(e) for e in envs),
            None if magnitude is None else float(magnitude),
            None if direction is None else tuple(float(x) for x in direction),
        )
    except KeyError as exc:
        raise ValueError(f"fault {data!r}: missing field {exc}") from None
