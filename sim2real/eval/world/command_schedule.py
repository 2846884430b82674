"""A legged robot's soak command schedule and where each part of it came from
(:func:`command_schedule`): the ranges of the velocity commands, the fraction of zero
(standing) commands and the period between commands, each from the ranges file's ``[commands]``
table when it gives it, else from the policy's contract (the ranges: Unitree's deploy.yaml,
holosoma's ``command_ranges``), else from ``soak-test --goal-period`` (the period), else the
defaults (:class:`~sim2real.deploy.tasks.commands.CommandRanges`, a 4-s period). Heading
commands (legged_gym's ``heading_command``: :data:`HEADING_KEYS`) come from the file's table or
CommandRanges' defaults (off; legged_gym's gain 0.5 and clip 1 rad/s when the file turns them on
without its own).
"""

from __future__ import annotations

import dataclasses

from sim2real.deploy.tasks.commands import CommandRanges

#: s between commands when nothing sets it: ``soak-test --goal-period``'s default.
DEFAULT_PERIOD = 4.0
#: The keys of a velocity command's ranges (fields of :class:`CommandRanges`).
RANGE_KEYS = ("vx", "vy", "yaw_rate")
#: The keys of heading commands (fields of :class:`CommandRanges`): on or off, the heading's
#: range (rad), the stiffness (1/s), the clip (rad/s), the share of heading commands.
HEADING_KEYS = (
    "heading_command",
    "heading",
    "heading_stiffness",
    "max_yaw_rate",
    "heading_fraction",
)
#: Where a heading key CommandRanges' default comes from, for the account.
_HEADING_DEFAULTS = {
    "heading_command": "CommandRanges' default (off: the contract's ranges are raw yaw rates)",
    "heading": "CommandRanges' default ([-pi, pi]: legged_gym's ranges.heading)",
    "heading_stiffness": "CommandRanges' default (legged_gym's 0.5, legged_robot.py)",
    "max_yaw_rate": "CommandRanges' default (legged_gym's clip of 1 rad/s, legged_robot.py)",
    "heading_fraction": "CommandRanges' default (1: legged_gym's, all commands)",
}


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
        ``zero_fraction``, ``vx``, ``vy``, ``yaw_rate`` (``[low, high]``, m/s and rad/s),
        ``heading_command`` (bool) and, when it is on, ``heading`` (``[low, high]`` rad),
        ``heading_stiffness`` (1/s), ``max_yaw_rate`` (rad/s), ``heading_fraction``; and
        ``sources`` (``{key: where it came from}`` for ``period``, ``zero_fraction``, each
        range and each heading key).

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
    for key in HEADING_KEYS:
        sources[key] = from_file if key in given else _HEADING_DEFAULTS[key]
    low, high = commands.period
    account = {
        "period_s": low if low == high else [low, high],
        "zero_fraction": commands.zero_fraction,
        **{k: list(getattr(commands, k)) for k in RANGE_KEYS},
        "heading_command": commands.heading_command,
        "sources": sources,
    }
    if commands.heading_command:
        account["heading"] = list(commands.heading)
        for key in ("heading_stiffness", "max_yaw_rate", "heading_fraction"):
            account[key] = getattr(commands, key)
    return commands, account


def schedule_text(account: dict) -> str:
    """One line of the schedule's account (:func:`command_schedule`): the period, the share
    of zero commands and the ranges, each with where it came from."""
    s = account["sources"]
    period = account["period_s"]
    every = (
        f"{period:g} s" if not isinstance(period, list) else f"U({period[0]:g}, {period[1]:g}) s"
    )
    heading = account.get("heading_command", False)
    share = account.get("heading_fraction", 1.0) if heading else 0.0
    keys = (("vx", "m/s"), ("vy", "m/s"))
    keys += (("yaw_rate", "rad/s"),) if share < 1.0 else ()  # all heading: no raw yaw rate
    if heading:
        keys += (("heading", "rad"), ("heading_stiffness", "1/s"), ("max_yaw_rate", "rad/s"))
        keys += (("heading_fraction", "of the commands"),) if share < 1.0 else ()
    groups: dict[str, list[str]] = {}
    for key, unit in keys:
        name = {"yaw_rate": "yaw rate", "heading_stiffness": "stiffness"}.get(key, key)
        name = {"max_yaw_rate": "yaw-rate clip +-", "heading_fraction": "heading share"}.get(
            key, name
        )
        value = account[key]
        text = f"{name}{value:g}" if key == "max_yaw_rate" else f"{name} {value} {unit}"
        groups.setdefault(s[key], []).append(text + (" rad/s" if key == "max_yaw_rate" else ""))
    ranges = "; ".join(f"{', '.join(v)} ({k})" for k, v in groups.items())
    unused = [k for k in HEADING_KEYS[1:] if s.get(k, "").endswith("[commands]")]
    if not heading and unused:  # set in the file, but heading commands are off
        ranges += f"; {', '.join(unused)} set but not used (heading_command off)"
    if heading:
        ranges = (
            f"heading commands ({s['heading_command']}): the policy is given yaw rate = "
            "clip(stiffness * wrap(heading - estimated yaw), +-clip) every tick"
            + ("" if share < 1.0 else ", no raw yaw rate drawn")
            + f"; {ranges}"
        )
    return (
        f"a new command every {every} ({s['period']}), zero (standing) "
        f"{account['zero_fraction']:g} of the time ({s['zero_fraction']}); {ranges}"
    )
