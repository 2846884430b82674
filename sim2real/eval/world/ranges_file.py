"""A TOML file of session ranges: overrides of the defaults a robot kind's soak and training draw
from (:func:`sim2real.eval.world.session_ranges.session_ranges`), read by ``soak-test --ranges FILE`` and
the training recipes' ``--ranges FILE`` (:func:`load_ranges`).

Every table and key is optional; what the file leaves out keeps the robot kind's default. A range
is ``[low, high]`` (drawn uniformly; integers inclusive), in the units of the class it sets::

    floor_friction = [0.6, 1.0]   # floating base only, as added_base_mass (kg), added_mass_body

    [dynamics]    # relative half-ranges in [0, 1): a factor is drawn from U(1 - r, 1 + r)
    mass = 0.3    # also link_length, friction, damping, armature, actuator_strength, kp, kd
    com_offset = {body = "torso_link", x = [-0.05, 0.05]}  # m added to body_ipos per session

    [sensors]     # encoder: noise_sigma (rad), latency_ticks (ticks), dropout, encoder_bias
    encoder_bias = [-0.015, 0.015]  # rad, each joint's offset, drawn once per session
    [imu]  [drift]  [faults]   # see their classes
    [commands]    # floating base only: vx, vy, yaw_rate (over the policy contract's ranges),
                  # zero_fraction, period (s or [low, high]; not with --goal-period), heading_*
    [pushes]      # floating base only: interval (s or [low, high]), mode ("set" or "add"),
                  # max_velocity (m/s) or velocity = {x, y, z}, angular_velocity = {roll, ...},
                  # apply ("force", default, or "velocity_hidden_from_imu"), window (s, 0.1)
    [terrain]     # floating base only: legged_gym's terrain (terrain_proportions, levels, ...)

The tables are the classes of :data:`TABLES` (:class:`~sim2real.eval.world.dynamics.DynamicsRanges`,
:class:`~sim2real.eval.world.terrain.TerrainRanges` and the others);
the inline tables ``dynamics.com_offset`` (:class:`~sim2real.eval.world.dynamics.ComOffsetRanges`) and
``pushes.velocity``, ``pushes.angular_velocity`` (:class:`~sim2real.eval.world.pushes.PushRanges`' axes)
are :data:`SUBTABLES`; their docstrings give each key's meaning, unit and default. Bad input
is a one-line :class:`RangesError` naming the file, ``table.key`` and the value expected.
"""

from __future__ import annotations

import dataclasses
import sys
import types
import typing
from pathlib import Path

from sim2real.deploy.tasks.commands import CommandRanges
from sim2real.eval.world.drift import DriftRanges
from sim2real.eval.world.dynamics import ComOffsetRanges, DynamicsRanges
from sim2real.eval.world.fault_schedule import FaultRanges
from sim2real.eval.world.pushes import PushRanges
from sim2real.eval.world.sensors import ImuRanges, SensorRanges
from sim2real.eval.world.session_ranges import SessionRanges, session_ranges
from sim2real.eval.world.terrain import TerrainRanges
from sim2real.robots import Robot
from sim2real.robots.errors import Sim2RealError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

#: The tables of a ranges file and the class each one sets (a field of :class:`SessionRanges`).
TABLES = {
    "dynamics": DynamicsRanges,
    "sensors": SensorRanges,
    "imu": ImuRanges,
    "drift": DriftRanges,
    "faults": FaultRanges,
    "pushes": PushRanges,
    "commands": CommandRanges,
    "terrain": TerrainRanges,
}
#: The inline tables of a table: ``(table, key)`` -> (the field of :class:`SessionRanges` they
#: set, the keys of the inline table: fields of that field's class). mjlab's velocity task
#: writes a push's ranges per axis, ``velocity_range = {"x": ..., "roll": ...}``; a file splits
#: them in two.
SUBTABLES = {
    ("dynamics", "com_offset"): ("com_offset", ("body", "x", "y", "z")),
    ("pushes", "velocity"): ("pushes", ("x", "y", "z")),
    ("pushes", "angular_velocity"): ("pushes", ("roll", "pitch", "yaw")),
}
#: The class of each field of :class:`SessionRanges` a file sets: a table's or an inline table's.
FIELDS = {**TABLES, "com_offset": ComOffsetRanges}
#: ``(field, key)`` -> the key as the file writes it (``pushes.velocity.x``), for messages.
FILE_KEYS = {
    (field, key): f"{table}.{sub}.{key}"
    for (table, sub), (field, keys) in SUBTABLES.items()
    for key in keys
}
#: Keys of a ranges file outside any table, with their type.
TOP_LEVEL = {
    "floor_friction": tuple[float, float],
    "added_base_mass": tuple[float, float],
    "added_mass_body": str,
}
#: What only a floating-base robot draws.
FLOATING_BASE_ONLY = (
    "imu",
    "floor_friction",
    "added_base_mass",
    "added_mass_body",
    "pushes",
    "commands",
    "terrain",
)


class RangesError(Sim2RealError, ValueError):
    """A bad ranges file; the message names the file, the ``table.key`` and the value expected."""


def _expected(hint) -> str:
    """What a value of type ``hint`` looks like in TOML, for messages."""
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return " or ".join(_expected(a) for a in typing.get_args(hint) if a is not type(None))
    if typing.get_origin(hint) is tuple:
        args = typing.get_args(hint)
        item = {float: "numbers", int: "integers", str: "strings"}[args[0]]
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {item}"
        return f"a range [low, high] of two {item}"
    return {float: "a number", int: "an integer", str: "a string", bool: "true or false"}[hint]


def _convert(value, hint):
    """``value`` (parsed TOML) as type ``hint``; raises ``TypeError`` when it is not one."""
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        for arg in typing.get_args(hint):  # the first type the value is
            if arg is not type(None):
                try:
                    return _convert(value, arg)
                except TypeError:
                    pass
        raise TypeError
    if typing.get_origin(hint) is tuple:
        args = typing.get_args(hint)
        if not isinstance(value, list):
            raise TypeError
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(v, args[0]) for v in value)
        if len(value) != len(args):
            raise TypeError
        return tuple(_convert(v, a) for v, a in zip(value, args, strict=True))
    if hint is bool and isinstance(value, bool):
        return value
    if isinstance(value, bool) or hint is bool:
        raise TypeError
    if hint is float and isinstance(value, (int, float)):
        return float(value)
    if hint in (int, str) and isinstance(value, hint):
        return value
    raise TypeError


def _typed(path: Path, where: str, value, hint):
    try:
        return _convert(value, hint)
    except TypeError:
        raise RangesError(f"{path}: {where}: expected {_expected(hint)}, got {value!r}") from None


def read_overrides(path: str | Path) -> dict:
    """The overrides of ranges file ``path``, parsed and type-checked (the ranges' own bounds are
    checked when they are applied, :func:`apply_overrides`).

    Returns:
        ``{field: {key: value}}`` for the tables of ``TABLES`` and ``com_offset`` (the fields of
        :class:`SessionRanges`; an inline table's keys are its class's fields, :data:`SUBTABLES`),
        and ``floor_friction: (low, high)`` when set; ranges as tuples, numbers as float (int
        where the field is an integer).

    Raises:
        RangesError: an unreadable file, invalid TOML, an unknown table or key, a value of the
            wrong type, or ``[pushes]`` with both ``max_velocity`` and per-axis ranges (named).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise RangesError(f"{path}: cannot read the ranges file ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise RangesError(f"{path}: not valid TOML: {exc}") from None
    return parse_overrides(text, path)


def parse_overrides(text: str, path: str | Path) -> dict:
    """:func:`read_overrides` of the TOML ``text`` of ranges file ``path`` (named in errors; a
    policy's training domain, :mod:`sim2real.eval.world.domain`, is such a text).

    Raises:
        RangesError: invalid TOML, unknown tables or keys (all of them named in one message),
            or a value of the wrong type.
    """
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RangesError(f"{path}: not valid TOML: {exc}") from None
    unknown = _unknown_keys(doc)
    if unknown:
        raise RangesError(f"{path}: " + "; ".join(unknown))
    out: dict = {}
    for key, value in doc.items():
        if key in TOP_LEVEL:
            out[key] = _typed(path, key, value, TOP_LEVEL[key])
            continue
        if not isinstance(value, dict):
            raise RangesError(f"{path}: {key}: expected a table [{key}], got {value!r}")
        hints = typing.get_type_hints(TABLES[key])
        table = out.setdefault(key, {})
        for name, item in value.items():
            if (key, name) in SUBTABLES:
                field, keys = SUBTABLES[key, name]
                out.setdefault(field, {}).update(_subtable(path, key, name, item, field, keys))
                continue
            table[name] = _typed(path, f"{key}.{name}", item, hints[name])
        if key == "pushes" and "max_velocity" in value:
            both = [s for s in ("velocity", "angular_velocity") if s in value]
            if both:
                raise RangesError(
                    f"{path}: pushes.{both[0]}: expected max_velocity (legged_gym: x and y in "
                    "[-max, max]) or velocity and angular_velocity (mjlab's per-axis ranges), "
                    "not both"
                )
    return out


def _table_keys(key: str) -> list[str]:
    """The keys table ``[key]`` of a ranges file takes: its class's fields (less those its
    inline sub-tables hold) and its sub-tables."""
    hints = typing.get_type_hints(TABLES[key])
    inner = {k for (t, _), (f, keys) in SUBTABLES.items() if t == key and f == key for k in keys}
    return [n for n in hints if n not in inner] + [s for t, s in SUBTABLES if t == key]


def _unknown_keys(doc: dict) -> list[str]:
    """Every unknown key of the parsed ranges file ``doc`` (top level, in a table, in an inline
    sub-table), one ``"<where>: unknown key; expected one of ..."`` each, in file order: the
    user fixes them all in one round."""
    known = [f"[{t}]" for t in TABLES] + list(TOP_LEVEL)
    out = []
    for key, value in doc.items():
        if key in TOP_LEVEL:
            continue
        if key not in TABLES:
            out.append(f"unknown key '{key}'; expected one of {', '.join(known)}")
            continue
        if not isinstance(value, dict):
            continue  # refused with its type below
        names = _table_keys(key)
        for name, item in value.items():
            if (key, name) in SUBTABLES:
                keys = SUBTABLES[key, name][1]
                out += [
                    f"{key}.{name}.{sub}: unknown key; expected one of {', '.join(keys)}"
                    for sub in (item if isinstance(item, dict) else {})
                    if sub not in keys
                ]
            elif name not in names:
                out.append(f"{key}.{name}: unknown key; expected one of {', '.join(names)}")
    return out


def _subtable(path, table: str, name: str, value, field: str, keys: tuple[str, ...]) -> dict:
    """The inline table ``table.name`` of file ``path`` as ``{field of its class: value}`` (its
    keys checked already: :func:`_unknown_keys`)."""
    if not isinstance(value, dict):
        raise RangesError(
            f"{path}: {table}.{name}: expected an inline table {{{', '.join(keys)}}}, got {value!r}"
        )
    hints = typing.get_type_hints(FIELDS[field])
    out = {}
    for sub, item in value.items():
        out[sub] = _typed(path, f"{table}.{name}.{sub}", item, hints[sub])
    return out


def _reason(exc: ValueError, owner: str, name: str) -> str:
    """The message of a range class's check without its own ``Owner.name: `` prefix."""
    message = str(exc)
    prefix = f"{owner}.{name}: "
    return message[len(prefix) :] if message.startswith(prefix) else message


def apply_overrides(
    ranges: SessionRanges, overrides: dict, robot: Robot, source: str | Path
) -> SessionRanges:
    """``ranges`` with ``overrides`` (from :func:`read_overrides` of file ``source``) set.

    Keys are set in the order of their class's fields (``kinds`` before ``weights``), each
    checked by its class (:meth:`FaultRanges.__post_init__` and the others).

    Raises:
        RangesError: an IMU or floor setting for a fixed-base robot, or a range its class refuses
            (inverted, out of bounds; named with the file and ``table.key``).
    """
    if not robot.floating_base:
        for key in FLOATING_BASE_ONLY:
            if key in overrides:
                raise RangesError(
                    f"{source}: {key}: robot {robot.name} has a fixed base (no IMU, no floor "
                    f"drawn); {key} applies to floating-base robots only"
                )
    changes = {}
    for table, cls in FIELDS.items():
        if not overrides.get(table):
            continue
        current = getattr(ranges, table)
        if current is None:  # e.g. a floating-base robot's ranges without IMU: from defaults
            current = cls()
        for field in dataclasses.fields(cls):
            if field.name not in overrides[table]:
                continue
            try:
                current = dataclasses.replace(current, **{field.name: overrides[table][field.name]})
            except ValueError as exc:
                key = FILE_KEYS.get((table, field.name), f"{table}.{field.name}")
                reason = _reason(exc, cls.__name__, field.name)
                raise RangesError(f"{source}: {key}: {reason}") from None
        changes[table] = current
    if "com_offset" in changes:  # the body must be the robot's
        try:
            changes["com_offset"].body_of(robot)
        except ValueError as exc:
            reason = _reason(exc, "ComOffsetRanges", "body")
            raise RangesError(f"{source}: dynamics.com_offset.body: {reason}") from None
    body = overrides.get("added_mass_body")
    bodies = [robot.mj_model.body(i).name for i in range(1, robot.mj_model.nbody)]
    if body is not None and body not in bodies:
        raise RangesError(
            f"{source}: added_mass_body: '{body}' is no body of robot {robot.name} (its bodies: "
            f"{bodies})"
        )
    for key in TOP_LEVEL:
        if key in overrides:
            try:
                dataclasses.replace(ranges, **{key: overrides[key]})
            except ValueError as exc:
                raise RangesError(
                    f"{source}: {key}: {_reason(exc, 'SessionRanges', key)}"
                ) from None
            changes[key] = overrides[key]
    return dataclasses.replace(ranges, **changes)


def load_ranges(
    path: str | Path, robot: Robot, mean_interval: float | None = None
) -> SessionRanges:
    """The ranges of ``robot``'s sessions with ranges file ``path``: the robot kind's defaults
    (:func:`sim2real.eval.world.session_ranges.session_ranges` with ``mean_interval`` s between faults when
    given), then the file's overrides (module docstring).

    Raises:
        RangesError: a bad file (:func:`read_overrides`, :func:`apply_overrides`; named).
    """
    overrides = read_overrides(path)
    return apply_overrides(session_ranges(robot, mean_interval), overrides, robot, path)


def load_ranges_text(
    text: str, source: str, robot: Robot, mean_interval: float | None = None
) -> SessionRanges:
    """:func:`load_ranges` of a ranges file's TOML ``text`` (``source`` names it in errors).

    Raises:
        RangesError: a bad text (named with ``source``).
    """
    overrides = parse_overrides(text, source)
    return apply_overrides(session_ranges(robot, mean_interval), overrides, robot, source)
