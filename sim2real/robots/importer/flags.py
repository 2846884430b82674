"""Per-joint flags of robot-import: ``JOINT=VALUE`` where ``JOINT`` is a shell pattern.

``--motor``, ``--limit``, ``--velocity``, ``--kp``, ``--kd`` and ``--home`` all read the same way
(:func:`per_joint`): the pattern (``fnmatch``, case-sensitive: ``*``, ``?``, ``[1-4]``) picks
joints, a flag matching no joint is an error naming the joints there are, and when several flags
match a joint the later one wins (``--motor '*=a' --motor 'knee*=b'``). A motor is a catalog
model or the path of a motor TOML file (:func:`read_motor_flag`).
"""

from __future__ import annotations

import fnmatch
import math
from collections.abc import Callable
from pathlib import Path

from sim2real.robots.importer.source import RobotImportError
from sim2real.robots.loading import MOTORS_DIR, motor_catalog, read_motor_file
from sim2real.robots.robot import RobotSpecError
from sim2real.robots.schema import MotorConfig


def split(flag: str, text: str, expected: str) -> tuple[str, str]:
    """``(pattern, value)`` of ``JOINT=VALUE``.

    Raises:
        RobotImportError: no ``=``, or an empty pattern or value (the message shows ``expected``).
    """
    pattern, sep, value = text.partition("=")
    if not sep or not pattern or not value:
        raise RobotImportError(f"{flag} '{text}': expected {expected}")
    return pattern, value


def matching(flag: str, text: str, pattern: str, joints: list[str], source: str) -> list[str]:
    """The joints of ``joints`` that ``pattern`` matches, in their order.

    Raises:
        RobotImportError: none matches (the message lists ``joints`` of ``source``).
    """
    hits = [j for j in joints if fnmatch.fnmatchcase(j, pattern)]
    if not hits:
        raise RobotImportError(
            f"{flag} '{text}': pattern '{pattern}' matches no joint of {source} (joints: {joints})"
        )
    return hits


def per_joint(
    flags: list[str],
    joints: list[str],
    flag: str,
    parse: Callable[[str], object],
    expected: str,
    source: str,
) -> dict[str, object]:
    """Joint -> value from ``JOINT=VALUE`` flags (shell patterns; later flags win).

    Args:
        flags: The flag texts in command-line order. joints: The joints patterns match.
        flag: The flag's name, for messages. parse: Value text -> value; raises ``ValueError``
            for a bad value. expected: What a good flag looks like, for messages. source: The
            description's file name, for messages.

    Raises:
        RobotImportError: a malformed flag or value, or a pattern that matches no joint.
    """
    out: dict[str, object] = {}
    for text in flags:
        pattern, value = split(flag, text, expected)
        try:
            parsed = parse(value)
        except RobotSpecError:  # a ValueError with its own message (a motor file's)
            raise
        except ValueError:
            raise RobotImportError(f"{flag} '{text}': expected {expected}") from None
        for j in matching(flag, text, pattern, joints, source):
            out[j] = parsed
    return out


def finite(value: str) -> float:
    """A finite float (``ValueError`` otherwise)."""
    number = float(value)
    if not math.isfinite(number):
        raise ValueError(value)
    return number


def positive(value: str) -> float:
    """A finite float > 0 (``ValueError`` otherwise)."""
    number = finite(value)
    if not number > 0:
        raise ValueError(value)
    return number


def position_range(value: str) -> tuple[float, float]:
    """``LOWER:UPPER`` -> (lower, upper), finite, lower < upper (``ValueError`` otherwise)."""
    lo, sep, hi = value.partition(":")
    if not sep:
        raise ValueError(value)
    lower, upper = finite(lo), finite(hi)
    if not lower < upper:
        raise ValueError(value)
    return lower, upper


def is_motor_file(model: str) -> bool:
    """Whether a ``--motor`` value names a file (a path, or a name ending in ``.toml``)."""
    return model.endswith(".toml") or "/" in model or "\\" in model


def read_motor_flag(flag_text: str, model: str) -> tuple[str, MotorConfig, dict | None]:
    """The motor a ``--motor`` value names: ``(name, config, table)``.

    A catalog model (``sim2real/robots/motors/NAME.toml``) gives ``table`` None (robot.toml names it);
    a file path gives its file name without ``.toml`` as the name and its table, which robot.toml
    then holds as ``[motors.NAME]`` (same schema as the catalog, ``sim2real.robots.schema.MotorConfig``).

    Raises:
        RobotImportError: an unknown catalog model, a missing file, or an invalid file (the
            message names the file and the field).
    """
    if not is_motor_file(model):
        catalog = motor_catalog()
        if model not in catalog:
            raise RobotImportError(
                f"--motor '{flag_text}': motor model '{model}' is not in the catalog {MOTORS_DIR} "
                f"(known: {sorted(catalog)}); add {MOTORS_DIR}/{model}.toml or give the path of "
                "a motor TOML file (--motor 'JOINT=path/to/my_motor.toml')"
            )
        path = catalog[model]
    else:
        path = Path(model).expanduser()
        if not path.is_file():
            raise RobotImportError(
                f"--motor '{flag_text}': no such file {path.resolve()} (expected a motor TOML "
                f"file, the schema of {MOTORS_DIR}/*.toml)"
            )
    try:
        table = read_motor_file(path)
    except RobotSpecError as exc:
        raise RobotImportError(f"--motor '{flag_text}': {exc}") from None
    config = MotorConfig.model_validate(table)
    path = path.resolve()
    if path.parent == MOTORS_DIR.resolve():
        return path.stem, config, None
    return path.stem, config, table


def assign_motors(
    source: Path, joints: list[str], flag_texts: list[str]
) -> tuple[dict[str, str], dict[str, MotorConfig], dict[str, tuple[Path, dict]]]:
    """Joint -> motor name from ``--motor JOINT=MODEL`` flags (shell patterns; later flags win;
    MODEL a catalog model or a motor TOML file). Returns ``(chosen, configs by name, tables of
    the motors given as files by name)``."""
    motors: dict[str, tuple[MotorConfig, dict | None, Path]] = {}

    def parse(model: str) -> str:
        name, config, table = read_motor_flag(text, model)
        path = Path(model).expanduser().resolve()
        if name in motors and motors[name][1] is not None and table is not None:
            if motors[name][2] != path:
                raise RobotImportError(
                    f"--motor '{text}': motor name '{name}' is already given by "
                    f"{motors[name][2]}; expected motor files with different names"
                )
        if name in motors and (motors[name][1] is None) != (table is None):
            raise RobotImportError(
                f"--motor '{text}': motor file {path} has the name of the catalog model "
                f"'{name}'; rename the file"
            )
        motors[name] = (config, table, path)
        return name

    chosen: dict[str, str] = {}
    for text in flag_texts:
        chosen.update(
            per_joint(
                [text],
                joints,
                "--motor",
                parse,
                "JOINT=MODEL (JOINT may be '*'; MODEL a catalog model or a motor TOML file)",
                source.name,
            )
        )
    for j in joints:
        if j not in chosen:
            raise RobotImportError(
                f"{source}: <joint name='{j}'>: no motor model; expected --motor {j}=MODEL "
                f"(or --motor '*=MODEL'; catalog: {sorted(motor_catalog())}, or a motor TOML file)"
            )
    used = set(chosen.values())
    configs = {name: motors[name][0] for name in used}
    tables = {
        name: (motors[name][2], motors[name][1]) for name in used if motors[name][1] is not None
    }
    return chosen, configs, tables
