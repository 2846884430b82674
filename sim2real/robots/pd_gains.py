"""The PD gains and the home pose of a robot.toml, compared with another source and rewritten in
place: :func:`gain_differences`, :func:`write_gains`.

A policy trained elsewhere comes with the joint stiffness ``kp`` (N m/rad), damping ``kd``
(N m s/rad) and default pose (rad) it was trained with (a legged_gym deploy config's ``kps``,
``kds``, ``default_angles``). The robot folder's ``[[joints]] kp``, ``kd`` and ``[control] home``
are the plant's and the runtime's; :func:`write_gains` replaces those values in the file's text,
keeping every other line and comment, writes it atomically and loads the robot again to check it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim2real.robots.files import atomic_write
from sim2real.robots.loading import load_robot, resolve_robot_toml
from sim2real.robots.robot import Robot, RobotSpecError

#: Values closer than this (relative, and absolute for zeros) count as equal.
RELATIVE_TOLERANCE = 1e-9


@dataclass(frozen=True)
class GainDifference:
    """One value that differs: ``field`` 'kp', 'kd' or 'home' of ``joint``, ``robot`` the
    robot.toml's value, ``wanted`` the other source's."""

    field: str
    joint: str
    robot: float
    wanted: float

    def __str__(self) -> str:
        return f"{self.joint} {self.field} {self.robot:g} in robot.toml, {self.wanted:g} wanted"


def _differs(a: float, b: float) -> bool:
    return not np.isclose(a, b, rtol=RELATIVE_TOLERANCE, atol=RELATIVE_TOLERANCE)


def gain_differences(
    robot: Robot, kp: np.ndarray, kd: np.ndarray, home: np.ndarray
) -> list[GainDifference]:
    """The kp, kd and home values of ``robot`` that differ from ``kp``, ``kd``, ``home``
    ((n_joints,) each, the robot's joint order), joint by joint, kp first."""
    out = []
    for i, (name, joint) in enumerate(zip(robot.joint_names, robot.config.joints, strict=True)):
        for field, have, want in (
            ("kp", joint.kp, kp[i]),
            ("kd", joint.kd, kd[i]),
            ("home", robot.home[i], home[i]),
        ):
            if _differs(float(have), float(want)):
                out.append(GainDifference(field, name, float(have), float(want)))
    return out


def _number(x: float) -> str:
    """A TOML float: shortest repr, always with a point or exponent."""
    text = repr(float(x))
    return text if any(c in text for c in ".einf") else text + ".0"


def write_gains(
    robot: Robot, kp: np.ndarray, kd: np.ndarray, home: np.ndarray, source: str
) -> Robot:
    """Write ``kp``, ``kd`` (one per joint, the robot's joint order) and ``home`` into the
    robot's robot.toml, in place, then load it again.

    Each joint's ``kp = ...`` and ``kd = ...`` line of its ``[[joints]]`` table and the
    ``home = [...]`` array of ``[control]`` whose value differs gets the new value and the comment
    ``source``; every other line is kept.

    Args:
        robot: The robot loaded from the folder to rewrite. kp: (n,) N m/rad. kd: (n,)
            N m s/rad. home: (n,) rad. source: Where the values come from (the comment).

    Returns:
        The robot loaded again from the rewritten file.

    Raises:
        RobotSpecError: a joint table without its own ``kp``/``kd`` line, no single-array
            ``home`` line, or the rewritten file does not load with the new values (the file is
            then restored).
    """
    return _write(resolve_robot_toml(robot.directory), robot, kp, kd, home, source)


def _write(path: Path, robot: Robot, kp, kd, home, source: str) -> Robot:
    text = path.read_text(encoding="utf-8")
    lines = text.splitlines(keepends=True)
    section, joint = None, None
    seen: dict[str, set[str]] = {}
    home_done = False
    values = {n: (kp[i], kd[i]) for i, n in enumerate(robot.joint_names)}
    current = {j.name: (j.kp, j.kd) for j in robot.config.joints}
    for k, line in enumerate(lines):
        stripped = line.strip()
        if stripped.startswith("["):
            section = stripped.split("#")[0].strip()
            joint = None
            continue
        if section == "[[joints]]":
            m = re.match(r'\s*name\s*=\s*"([^"]+)"', line)
            if m:
                joint = m.group(1)
                seen.setdefault(joint, set())
                continue
            m = re.match(r"(\s*)(kp|kd)(\s*=\s*)[^#\n]*", line)
            if m and joint in values:
                field = 0 if m.group(2) == "kp" else 1
                unit = ("N m/rad", "N m s/rad")[field]
                value = values[joint][field]
                key = f"{m.group(1)}{m.group(2)}{m.group(3)}"
                if _differs(current[joint][field], value):  # an equal value keeps its line
                    lines[k] = f"{key}{_number(value)}  # {unit}, {source}\n"
                seen[joint].add(m.group(2))
        elif section == "[control]" and re.match(r"\s*home\s*=\s*\[[^\]]*\]", line):
            if any(_differs(a, b) for a, b in zip(robot.home, home, strict=True)):
                vec = ", ".join(_number(h) for h in home)
                lines[k] = f"home = [{vec}]  # rad, {source}\n"
            home_done = True
    missing = [
        f"{j} {f}" for j in robot.joint_names for f in ("kp", "kd") if f not in seen.get(j, ())
    ]
    if missing or not home_done:
        what = ", ".join(missing[:4]) if missing else "a one-line 'home = [...]' in [control]"
        raise RobotSpecError(f"{path}: cannot rewrite the gains in place: no line for {what}")
    atomic_write(path, "".join(lines))
    try:
        again = load_robot(path)
        if gain_differences(again, np.asarray(kp), np.asarray(kd), np.asarray(home)):
            raise RobotSpecError(f"{path}: the rewritten file does not hold the new values")
    except Exception:
        atomic_write(path, text)
        raise
    return again
