"""The robustness sweep (``soak-test --sweep``): how far past its world a policy holds.

Each randomized quantity (:data:`QUANTITIES`: link mass, joint friction, joint damping, floor
friction, motor strength, sensor latency, push size) is widened in turn, level by level, from
the campaign's ranges (the policy's training domain, a ranges file, or the robot kind's own),
the others left as they are. Every level runs ``sessions`` sessions of ``minutes`` simulated
minutes each, on the same seeds for every level (common random numbers: the levels differ in that
quantity only), without the fault schedule (the soak's own run judges the faults) and without the
domain's pushes (pushes are a quantity of their own: with a push every few seconds in every level,
each level would measure the pushes). A **reference** at those ranges comes first. A level
**holds** when its sessions fell at most ``FALL_ALLOWANCE`` times more than the reference's (a
policy that falls now and then in its own world falls at random in any short run) and their
success (a legged robot's tracking, or the share of its clips no stop ended where a motion clip
commands it; an arm's goals) is within ``TOLERANCE`` of the reference's. A
quantity's **margin** is its last level that holds with every milder level holding too (None: not
even the first). Where the reference itself falls more than ``FALL_ALLOWANCE`` times, the policy
does not hold in its own world: no margin is given (``reference.holds`` False).

Levels are in the quantity's own terms (:class:`Quantity`): a relative half-range (link mass
``+-0.2``: every link's mass drawn from ``U(0.8, 1.2)`` times its own), the floor's lowest
friction coefficient, ticks of latency (encoders and IMU), the largest push (m/s, legged_gym's
``max_push_vel_xy``). A quantity whose nominal value is zero in the robot's model (joint friction
or damping in an MJCF without them) cannot be widened relatively: it is reported ``n/a``.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import multiprocessing
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from sim2real.deploy.kinds import robot_kind
from sim2real.eval.world.pushes import PushRanges
from sim2real.eval.world.session_ranges import SessionRanges, session_ranges
from sim2real.eval.world.world_faces import WORLD_OF_KIND

#: A level holds when its success is at most this far below the reference's (a fraction).
#: Our choice: 0.1, ten points of tracking or goal success.
TOLERANCE = 0.1
#: A level holds with at most this many more falls than the reference, over the same sessions.
#: Our choice: 1, one fall in the ten simulated minutes of a level by default (a policy that
#: falls a few times an hour in its own world).
FALL_ALLOWANCE = 1
#: Simulated minutes of each session of a level (default of ``--sweep-minutes``).
MINUTES = 5.0
#: Sessions per level (seeds ``seed .. seed + SESSIONS - 1``).
SESSIONS = 2
#: s between pushes of the push-size quantity where the ranges have no pushes (legged_gym's
#: unitree humanoids' ``push_interval_s``).
PUSH_INTERVAL = 5.0


@dataclass(frozen=True)
class Quantity:
    """One quantity of the sweep.

    Attributes:
        name: Its key in report.json.
        label: What the table says.
        unit: The levels' unit.
        levels: Increasingly severe levels.
        apply: ``(ranges, level) -> ranges`` with the quantity at that level.
        needs: What the robot kind's soak world must have (:func:`_fits`): ``"floor"`` (its
            range defaults draw a floor, :data:`~sim2real.eval.world.session_ranges.SESSION_RANGES`),
            ``"pushes"`` (its world passes domain pushes on,
            :data:`~sim2real.eval.world.world_faces.WORLD_OF_KIND`), or None.
        model_field: The MuJoCo ``dof_*`` field a relative range scales (None: not relative to
            the model), for the ``n/a`` of a robot without it.
    """

    name: str
    label: str
    unit: str
    levels: tuple[float, ...]
    apply: Callable[[SessionRanges, float], SessionRanges]
    needs: str | None = None
    model_field: str | None = None


def _dynamics(field: str) -> Callable[[SessionRanges, float], SessionRanges]:
    def apply(ranges: SessionRanges, level: float) -> SessionRanges:
        return replace(ranges, dynamics=replace(ranges.dynamics, **{field: level}))

    return apply


def _floor(ranges: SessionRanges, level: float) -> SessionRanges:
    high = ranges.floor_friction[1] if ranges.floor_friction else 1.0
    return replace(ranges, floor_friction=(level, max(high, level)))


def _latency(ranges: SessionRanges, level: float) -> SessionRanges:
    k = int(level)
    out = replace(ranges, sensors=replace(ranges.sensors, latency_ticks=(k, k)))
    if ranges.imu is not None:
        out = replace(out, imu=replace(ranges.imu, latency_ticks=(k, k)))
    return out


def _push(ranges: SessionRanges, level: float) -> SessionRanges:
    interval = ranges.pushes.interval if ranges.pushes is not None else PUSH_INTERVAL
    return replace(ranges, pushes=PushRanges(interval=interval, max_velocity=level))


#: The quantities, in the order of the table.
QUANTITIES = (
    Quantity("link_mass", "link mass", "+-", (0.1, 0.2, 0.3, 0.45, 0.6), _dynamics("mass")),
    Quantity(
        "joint_friction",
        "joint friction",
        "+-",
        (0.25, 0.5, 0.75, 0.95),
        _dynamics("friction"),
        model_field="dof_frictionloss",
    ),
    Quantity(
        "joint_damping",
        "joint damping",
        "+-",
        (0.25, 0.5, 0.75, 0.95),
        _dynamics("damping"),
        model_field="dof_damping",
    ),
    Quantity(
        "floor_friction",
        "floor friction (lowest)",
        "mu",
        (0.5, 0.4, 0.3, 0.2, 0.1),
        _floor,
        needs="floor",
    ),
    Quantity(
        "motor_strength",
        "motor strength",
        "+-",
        (0.1, 0.2, 0.3, 0.45, 0.6),
        _dynamics("actuator_strength"),
    ),
    Quantity("latency", "sensor latency", "ticks", (1, 2, 3, 4), _latency),
    Quantity("push_size", "push size", "m/s", (0.5, 1.0, 1.5, 2.0, 2.5), _push, needs="pushes"),
)


def session_success(result: dict) -> float | None:
    """A sweep session's success (module docstring): an arm's goal success rate; a legged
    robot's velocity tracking success; for a session a motion clip commands (``locomotion.
    commanded_by`` ``clip``: its velocity tracker read a zero command), the share of its clips
    no stop ended (its ``exhibition`` section: the one the session's end cut short counts as not
    ended by a stop), None before any clip started."""
    loco = result.get("locomotion")
    if loco is None:
        return result["goals"]["success_rate"]
    if loco.get("commanded_by") != "clip":
        return loco["tracking_success"]
    clips = (result.get("exhibition") or {}).get("clips") or []
    if not clips:
        return None
    return sum(1 for c in clips if not c["stopped"]) / len(clips)


def _falls(result: dict) -> int:
    loco = result.get("locomotion")
    return 0 if loco is None else int(loco["falls"])


def _mean(values: list) -> float | None:
    kept = [v for v in values if v is not None]
    return sum(kept) / len(kept) if kept else None


def _run_one(config, out: str) -> dict:
    """One level's session (in a worker process)."""
    from sim2real.eval.soak.executors import run_sessions

    return run_sessions([config], out)[0]


def _fits(q: Quantity, robot) -> bool:
    """The robot kind's soak world has what ``q`` needs (:attr:`Quantity.needs`): a floor its
    range defaults draw, or domain pushes its world face passes on."""
    if q.needs is None:
        return True
    ranges = session_ranges(robot)
    if q.needs == "floor":
        return ranges.floor_friction is not None
    world = WORLD_OF_KIND.get(robot_kind(robot))
    return world.domain_pushes(q.apply(ranges, q.levels[0])) is not None


def _applies(q: Quantity, robot) -> bool:
    if not _fits(q, robot):
        return False
    if q.model_field is not None:
        model = robot.mj_model
        dofs = [model.jnt_dofadr[model.joint(j).id] for j in robot.joint_names]
        return bool((getattr(model, q.model_field)[dofs] > 0).any())
    return True


def run_sweep(
    template,
    out: str | Path,
    minutes: float = MINUTES,
    workers: int = 1,
    sessions: int = SESSIONS,
) -> dict:
    """Run the sweep of ``template`` (a :class:`sim2real.eval.soak.session.SessionConfig`: robot,
    policy, seed, ranges) and return report.json's ``robustness`` entry (successes are the mean
    over the level's sessions, falls their sum)::

        minutes, sessions, seed, tolerance, fall_allowance, wall_s,
        reference {success, falls, holds},
        quantities [{name, label, unit, applies, levels [{level, success, falls, holds}],
                     margin (a level or None), failed_at (the first level that did not hold)}]

    Raises:
        SessionError: bad options (named).
    """
    from sim2real.robots import load_robot

    t0 = time.perf_counter()
    out = Path(out)
    robot = load_robot(template.robot)
    base = replace(
        template,
        hours=minutes / 60.0,
        faults=False,
        checkpoint_minutes=0.0,
        curve_seconds=30.0,
        ranges=replace(template.ranges, pushes=None),
    )
    jobs = {("reference", 0.0): base}
    quantities = [q for q in QUANTITIES if _fits(q, robot)]
    for q in quantities:
        if _applies(q, robot):
            for level in q.levels:
                jobs[(q.name, level)] = replace(base, ranges=q.apply(base.ranges, level))
    runs: dict = {key: [] for key in jobs}
    context = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
        futures = {
            pool.submit(
                _run_one, replace(config, seed=config.seed + i), str(out / f"{key[0]}_{key[1]:g}")
            ): key
            for key, config in jobs.items()
            for i in range(sessions)
        }
        for future in concurrent.futures.as_completed(futures):
            runs[futures[future]].append(future.result())
    results = {
        key: {
            "success": _mean([session_success(r) for r in rs]),
            "falls": sum(_falls(r) for r in rs),
        }
        for key, rs in runs.items()
    }
    applies = {q.name: _applies(q, robot) for q in quantities}
    return {
        "minutes": minutes,
        "sessions": sessions,
        "seed": template.seed,
        "tolerance": TOLERANCE,
        "fall_allowance": FALL_ALLOWANCE,
        "ranges": dataclasses.asdict(template.ranges),
        **margins(results, quantities, applies),
        "wall_s": time.perf_counter() - t0,
    }


def margins(results: dict, quantities, applies: dict[str, bool]) -> dict:
    """``reference`` and ``quantities`` of :func:`run_sweep` from the levels' results.

    Args:
        results: ``{(quantity name, level): {"success": float | None, "falls": int}}``, and the
            reference under ``("reference", 0.0)``.
        quantities: The :class:`Quantity` rows swept.
        applies: Per quantity name, whether the robot's model has it (else ``n/a``).
    """
    ref = results[("reference", 0.0)]
    ref_success, ref_falls = ref["success"], ref["falls"]
    ref_holds = ref_falls <= FALL_ALLOWANCE and ref_success is not None
    rows = []
    for q in quantities:
        levels, margin, failed_at, holding = [], None, None, ref_holds
        for level in q.levels if applies[q.name] else ():
            r = results[(q.name, level)]
            success, falls = r["success"], r["falls"]
            holds = (
                falls <= ref_falls + FALL_ALLOWANCE
                and success is not None
                and ref_success is not None
                and success >= ref_success - TOLERANCE
            )
            levels.append({"level": level, "success": success, "falls": falls, "holds": holds})
            if holding and holds:
                margin = level
            elif holding:
                holding, failed_at = False, level
        rows.append(
            {
                **{k: getattr(q, k) for k in ("name", "label", "unit")},
                "applies": applies[q.name],
                "levels": levels,
                "margin": margin,
                "failed_at": failed_at,
            }
        )
    return {
        "reference": {"success": ref_success, "falls": ref_falls, "holds": ref_holds},
        "quantities": rows,
    }


def margin_text(row: dict) -> str:
    """``"+-0.3"``, ``"down to mu 0.2"``, ``"3 ticks"``, ``"1.5 m/s"``, ``"none"`` or ``"n/a"``."""
    if not row["applies"]:
        return "n/a (not in the robot's model)"
    if row["margin"] is None and row["failed_at"] is None and row["levels"]:
        return "none (the policy does not hold in the reference world itself)"
    m = row["margin"]
    if m is None:
        return "none (fails at the first level)"
    unit = row["unit"]
    if unit == "+-":
        text = f"+-{100 * m:.0f} %"
    elif unit == "mu":
        text = f"floor friction down to {m:g}"
    else:
        text = f"{m:g} {unit}"
    if row["failed_at"] is None:
        text += " (every level held)"
    return text
