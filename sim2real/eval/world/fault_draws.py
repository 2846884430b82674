"""How the soak draws each fault kind (:data:`FAULT_DRAWS`): a :class:`FaultDraw` registered
under the fault kind's name, the schedule's face of a kind the injector registered
(:data:`sim2real.deploy.backends.sim.fault_kinds.FAULT_KINDS`).

A draw turns the session's random stream into a fault's ``(length s, magnitude or None)``
(:meth:`FaultDraw.draw`, given a :class:`DrawContext`: the robot, the session's
:class:`~sim2real.eval.world.fault_schedule.FaultRanges`, its stale budget and the cable budget),
its random draws in a fixed order: a seeded soak gives the same schedule run after run.

To add a fault kind to the soak (a camera's, say):

1. register what it does to the plant, the frame or the action
   (:func:`sim2real.deploy.backends.sim.fault_kinds.register_fault_kind`);
2. register its draw here (:func:`register_fault_draw`), with ``in_default_draw=True`` for every
   soak's default schedule (:attr:`FaultRanges.kinds`), or not, for a ranges file's ``[faults]
   kinds = [...]`` to name it; ``refuses`` says why a robot gets none (no camera), and such a
   robot's draws stay those without the kind.

Adding a default kind changes the seeded schedules of the robots that draw it (one more kind to
choose from); the others' stay as they were. ``tests/test_fault_registry.py`` names a kind
registered in one room and not the other.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sim2real.deploy.core.registry import Registry


@dataclass(frozen=True)
class DrawContext:
    """What a fault's draw is sized against.

    Attributes:
        robot: The :class:`~sim2real.robots.Robot`.
        ranges: The session's :class:`~sim2real.eval.world.fault_schedule.FaultRanges`.
        budget: s, the session's stale budget (:func:`~sim2real.eval.world.fault_schedule.
            stale_budget`).
        max_spike: The largest latency spike that stays within the stale limit, control ticks
            (:func:`~sim2real.eval.world.fault_schedule.gap_ticks`).
        cable: ``cable(length)``: N, the drives' reserve for a pull of ``length`` s
            (:func:`~sim2real.eval.world.fault_schedule.cable_budget`, computed at first use).
    """

    robot: object
    ranges: object
    budget: float
    max_spike: int
    cable: Callable[[float], float]


@dataclass(frozen=True)
class FaultDraw:
    """The soak's draw of one fault kind (module docstring).

    Attributes:
        name: The fault kind's name.
        draw: ``draw(context, rng) -> (length s, magnitude or None)``.
        sensor_gap: It leaves the estimator without a fresh reading (sized against the stale
            budget): a session where no tick of gap fits draws none.
        in_default_draw: In :attr:`FaultRanges.kinds`' default (every soak's schedule).
        only_while_running: Applied only to a robot RUNNING since the schedule's warmup (a
            push, as the training stacks push); skipped and recorded otherwise.
        refuses: ``refuses(robot) -> str | None``: why ``robot`` gets none of it (one line), or
            None; None: every robot may.
    """

    name: str
    draw: Callable[[DrawContext, np.random.Generator], tuple[float, float | None]]
    sensor_gap: bool = False
    in_default_draw: bool = False
    only_while_running: bool = False
    refuses: Callable[[object], str | None] | None = None


#: The soak's draw of each fault kind, by the kind's name (the built-in ones registered below).
FAULT_DRAWS: Registry[FaultDraw] = Registry("fault draw")


def register_fault_draw(entry: FaultDraw) -> FaultDraw:
    """Register ``entry`` under its kind's name; returns it.

    Raises:
        ValueError: the name has a draw already.
    """
    return FAULT_DRAWS.register(entry.name, entry)


def default_fault_kinds() -> tuple[str, ...]:
    """The kinds of every soak's default schedule (``in_default_draw``), in registration order."""
    return tuple(n for n, d in FAULT_DRAWS.entries().items() if d.in_default_draw)


def sensor_gap_kinds() -> tuple[str, ...]:
    """The kinds sized against the stale budget (``sensor_gap``)."""
    return tuple(n for n, d in FAULT_DRAWS.entries().items() if d.sensor_gap)


def _dropout(c: DrawContext, rng):
    return c.budget * float(rng.uniform(*c.ranges.dropout)), None


def _stale(c: DrawContext, rng):
    return c.budget * float(rng.uniform(*c.ranges.stale)), None


def _nan_action(c: DrawContext, rng):
    ticks = c.ranges.nan_ticks
    return c.robot.control_period * int(rng.integers(ticks[0], ticks[1] + 1)), None


def _latency(c: DrawContext, rng):
    fraction = float(rng.uniform(*c.ranges.latency_ticks))
    magnitude = float(max(1, round(c.max_spike * fraction)))
    return float(rng.uniform(*c.ranges.latency_duration)), magnitude


def _push(c: DrawContext, rng):
    magnitude = float(rng.uniform(*c.ranges.push_force))
    return float(rng.uniform(*c.ranges.push_duration)), magnitude


def _cable(c: DrawContext, rng):
    fraction = float(rng.uniform(*c.ranges.cable_force))
    length = float(rng.uniform(*c.ranges.cable_duration))
    return length, fraction * c.cable(length)


for _entry in (
    FaultDraw("dropout", _dropout, sensor_gap=True, in_default_draw=True),
    FaultDraw("stale", _stale, sensor_gap=True, in_default_draw=True),
    FaultDraw("nan-action", _nan_action, in_default_draw=True),
    FaultDraw("latency", _latency, sensor_gap=True, in_default_draw=True),
    FaultDraw("push", _push, in_default_draw=True, only_while_running=True),
    FaultDraw("cable", _cable, in_default_draw=True),
):
    register_fault_draw(_entry)
