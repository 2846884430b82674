"""A legged robot's soak command schedule and where each part of it came from
(:func:`command_schedule`): the ranges of the velocity commands, the fraction of zero
(standing) commands and the period between commands, each from the ranges file's ``[commands]``
table when it gives it, else from the policy's contract (the ranges: Unitree's deploy.yaml,
holosoma's ``command_ranges``), else from ``soak-test --goal-period`` (the period), else the
defaults (:class:`~sim2real.deploy.tasks.commands.CommandRanges`, a 4-s period).
"""

from __future__ import annotations

import dataclasses

from sim2real.deploy.tasks.commands import CommandRanges

#: s between commands when nothing sets it: ``soak-test --goal-period``'s default.
DEFAULT_PERIOD = 4.0
#: The keys of a velocity command's ranges (fields of :class:`CommandRanges`).
RANGE_KEYS = ("vx", "vy", "yaw_rate")


def command_schedule(
    file_commands: CommandRanges | None,
    given: dict,
    file_source: str | None,
    contract: tuple[CommandRanges | None, str | None],
    goal_period: float | None,
) -> tuple[CommandRanges, dict]:
    """The command ranges a legged robot's soak draws from, with their ``period`` set, and
    the report's account of them.

    Args:
        file_commands: The ``commands`` of the ranges (a ranges file's table over the
            defaults), or None.
        given: The keys the file's ``[commands]`` table sets (``{key: value}``; empty: none).
        file_source: The file (or training domain) that set them, for the account.
        contract: ``(ranges, where)`` of the policy's contract
            (:func:`sim2real.eval.world.domain.contract_commands`); ``(None, None)``: none.
        goal_period: ``--goal-period`` when given on the command line, else None.

    Returns:
        ``(ranges, account)``; ``account``: ``period_s`` (s, or ``[low, high]``),
        ``zero_fraction``, ``vx``, ``vy``, ``yaw_rate`` (``[low, high]``, m/s and rad/s) and
        ``sources`` (``{key: where it came from}`` for ``period``, ``zero_fraction`` and
        each range).

    Raises:
        ValueError: ``goal_period`` given while the file sets ``period`` (named), or a period
            :class:`CommandRanges` refuses.
    """
    if goal_period is not None and "period" in given:
        raise ValueError(f"--goal-period: {file_source} sets commands.period too; give one of them")
    from_file = f"{file_source} [commands]"
    ranges, where = contract
    base = ranges if ranges is not None else (file_commands or CommandRanges())
    base_source = where if ranges is not None else "CommandRanges' default (our choice)"
    keep = {k: getattr(file_commands, k) for k in given if file_commands is not None}
    commands = dataclasses.replace(base, **keep)
    sources = {k: from_file if k in given else base_source for k in RANGE_KEYS}
    sources["zero_fraction"] = (
        from_file if "zero_fraction" in given else "CommandRanges' default (our choice)"
    )
    if "period" in given:
        sources["period"] = f"{from_file} period"
    elif goal_period is not None:
        commands = dataclasses.replace(commands, period=goal_period)
        sources["period"] = "--goal-period"
    else:
        commands = dataclasses.replace(commands, period=DEFAULT_PERIOD)
        sources["period"] = f"soak-test's default ({DEFAULT_PERIOD:g} s)"
    low, high = commands.period
    account = {
        "period_s": low if low == high else [low, high],
        "zero_fraction": commands.zero_fraction,
        **{k: list(getattr(commands, k)) for k in RANGE_KEYS},
        "sources": sources,
    }
    return commands, account


def schedule_text(account: dict) -> str:
    """One line of the schedule's account (:func:`command_schedule`): the period, the share
    of zero commands and the ranges, each with where it came from."""
    s = account["sources"]
    period = account["period_s"]
    every = (
        f"{period:g} s" if not isinstance(period, list) else f"U({period[0]:g}, {period[1]:g}) s"
    )
    groups: dict[str, list[str]] = {}
    for key, unit in (("vx", "m/s"), ("vy", "m/s"), ("yaw_rate", "rad/s")):
        name = "yaw rate" if key == "yaw_rate" else key
        groups.setdefault(s[key], []).append(f"{name} {account[key]} {unit}")
    ranges = "; ".join(f"{', '.join(v)} ({k})" for k, v in groups.items())
    return (
        f"a new command every {every} ({s['period']}), zero (standing) "
        f"{account['zero_fraction']:g} of the time ({s['zero_fraction']}); {ranges}"
    )
