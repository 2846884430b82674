"""The training domain of a legged_gym task (unitree_rl_gym, humanoid-gym and their forks) as a
ranges file (:mod:`sim2real.eval.world.ranges_file`): :func:`legged_gym_domain`.

The task's config class is read *as text* (Python's ``ast``; the file is never run): its
``domain_rand`` class (or ``domain_rands`` with nested classes, as some forks write it: their keys
are read as one table), ``noise``, ``terrain`` (a ``[terrain]`` table of tiles,
:mod:`sim2real.eval.world.terrain`, where the file writes its ``mesh_type``: legged_gym's base
says trimesh, unitree_rl_gym's plane) and ``commands.ranges``, over the defaults of legged_gym's
``LeggedRobotCfg`` (``LEGGED_GYM_DEFAULTS``) for what it does not set. Every
``domain_rand`` key is read (:data:`GROUPS`: a switch and the keys it turns on) or refused by
name (:class:`~sim2real.eval.world.domain.DomainError`): a randomization the soak cannot run
(restitution, action latency, action noise, external forces) is refused when its switch is on;
a key no group knows is refused unless it is a switch that is off or belongs to one
(``randomize_X = False`` and a key containing ``X``).
"""

from __future__ import annotations

import ast
import math
from pathlib import Path

from sim2real.eval.world.legged_gym_groups import (
    DEFAULTS_PATH,
    GROUPS,
    LEGGED_GYM_DEFAULTS,
    Context,
    domain_lines,
    terrain_table,
)
from sim2real.robots.errors import Sim2RealError


class DomainError(Sim2RealError, ValueError):
    """A training-domain source that cannot be read (named with its file and what was
    expected)."""


def _literal(node: ast.AST):
    try:
        return ast.literal_eval(node)
    except (ValueError, TypeError, SyntaxError):
        return None  # an expression we do not evaluate (a name, a call): the default stands


class _Section(dict):
    """A nested class's values (apart from a dict literal's)."""


def _class_values(cls: ast.ClassDef) -> dict:
    """The literal assignments of a class body, nested classes as :class:`_Section` dicts."""
    out: dict = _Section()
    for item in cls.body:
        if isinstance(item, ast.Assign) and len(item.targets) == 1:
            target = item.targets[0]
            if isinstance(target, ast.Name):
                value = _literal(item.value)
                if value is not None:
                    out[target.id] = value
        elif isinstance(item, ast.ClassDef):
            out[item.name] = _class_values(item)
    return out


def _flatten(table: dict, prefix: str) -> dict[str, tuple[str, object]]:
    """``{key: (its path, value)}`` of a class's values, nested classes' keys at the top."""
    out: dict[str, tuple[str, object]] = {}
    for key, value in table.items():
        if isinstance(value, _Section):
            out.update(_flatten(value, f"{prefix}.{key}"))
        else:
            out[key] = (f"{prefix}.{key}", value)
    return out


def _choose(classes: list[ast.ClassDef], path: Path, config_class: str | None) -> ast.ClassDef:
    if config_class is not None:
        chosen = [c for c in classes if c.name == config_class]
        if not chosen:
            raise DomainError(
                f"{path}: no class '{config_class}'; expected one of {[c.name for c in classes]}"
            )
        return chosen[0]

    def has(c: ast.ClassDef, *names: str) -> bool:
        return any(isinstance(i, ast.ClassDef) and i.name in names for i in c.body)

    chosen = [c for c in classes if has(c, "domain_rand", "domain_rands", "noise")] or [
        c
        for c in classes
        if any(isinstance(b, (ast.Name, ast.Attribute)) and ast.unparse(b).endswith("Cfg")
               for b in c.bases)
    ]  # fmt: skip
    if not chosen:
        raise DomainError(
            f"{path}: no legged_gym config class (a class with a 'domain_rand' or 'noise' "
            f"class, or deriving from LeggedRobotCfg); classes: {[c.name for c in classes]}"
        )
    return chosen[0]


def read_legged_gym_config(path: str | Path, config_class: str | None = None) -> dict:
    """The settings of a legged_gym config file, over ``LEGGED_GYM_DEFAULTS``: ``{"domain_rand":
    {key: (path, value)}, "noise": {...}, "terrain": {...}, "commands": {...}, "sim": {...},
    "source": str}`` (``domain_rand`` flattened: a fork's nested classes' keys at the top, each
    with the path it was written at; the defaults' paths are ``LeggedRobotCfg.domain_rand.X``).

    Args:
        path: The config's Python file (read as text, never run).
        config_class: The config class (default: the first top-level class with a
            ``domain_rand``, ``domain_rands`` or ``noise`` class, else the first that derives
            from a name ending in ``Cfg``).

    Raises:
        DomainError: an unreadable file, not Python, or no such config class (named).
    """
    path = Path(path)
    try:
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    except OSError as exc:
        raise DomainError(f"{path}: cannot read the legged_gym config ({exc.strerror})") from None
    except (SyntaxError, UnicodeDecodeError) as exc:
        raise DomainError(f"{path}: not a Python file: {exc}") from None
    cls = _choose([n for n in tree.body if isinstance(n, ast.ClassDef)], path, config_class)
    values = _class_values(cls)
    defaults = LEGGED_GYM_DEFAULTS
    rand = _flatten(defaults["domain_rand"], DEFAULTS_PATH)
    for name in ("domain_rand", "domain_rands"):
        if name in values:
            rand.update(_flatten(values[name], name))
    noise = {**defaults["noise"], **values.get("noise", {})}
    noise["noise_scales"] = {
        **defaults["noise"]["noise_scales"],
        **values.get("noise", {}).get("noise_scales", {}),
    }
    commands = values.get("commands", {})
    return {
        "domain_rand": rand,
        "noise": noise,
        "terrain": {**defaults["terrain"], **values.get("terrain", {})},
        # whether the task's file writes its terrain's mesh_type (the forks' bases differ)
        "terrain_written": "mesh_type" in values.get("terrain", {}),
        "commands": {
            **defaults["commands"],
            **commands,
            "ranges": {**defaults["commands"]["ranges"], **commands.get("ranges", {})},
        },
        "sim": {**defaults["sim"], **values.get("sim", {})},
        "control": {**defaults["control"], **values.get("control", {})},
        "source": f"{path.name} ({cls.name}, legged_gym)",
    }


def _terrain_refusals(terrain: dict) -> list[str]:
    """Why the soak cannot build legged_gym's ``terrain`` class (its kinds past the fifth share,
    a mesh type it does not know; named), or nothing."""
    from sim2real.eval.world.terrain import TerrainRanges

    table = terrain_table(terrain)
    if table is None:
        return []
    try:
        TerrainRanges(**{k: tuple(v) if isinstance(v, list) else v for k, v in table.items()})
    except (TypeError, ValueError) as exc:
        return [str(exc).replace("TerrainRanges.", "terrain.", 1)]
    return []


def legged_gym_domain(path: str | Path, config_class: str | None = None) -> str:
    """The ranges file (TOML text) of a legged_gym task's training domain. What each key
    becomes is its group's (:data:`sim2real.eval.world.legged_gym_groups.GROUPS`, which says
    it); the noise (``noise_scales`` times ``noise_level``, 0 without ``add_noise``; a uniform
    noise of half-width ``s`` has the standard deviation ``s / sqrt(3)``): ``dof_pos`` ->
    ``[sensors] noise_sigma``, ``ang_vel`` -> ``[imu] gyro_noise_sigma``, ``gravity`` (a unit
    vector's) -> ``[imu] accel_noise_sigma`` (times g); ``commands.ranges`` and
    ``commands.resampling_time`` (s between commands) -> ``[commands]`` (its ``period``).

    Raises:
        DomainError: an unreadable config, a malformed range, a randomization the soak cannot
            run that is on, or a key no group knows (each named with the file and its path).
    """
    path = Path(path)
    cfg = read_legged_gym_config(path, config_class)
    context = Context(path, cfg)
    known = {key for group in GROUPS for key in (*group.switches, *group.values)}
    unknown = [
        where
        for key, (where, value) in cfg["domain_rand"].items()
        if key not in known and not context.switched_off(key, value)
    ]
    if unknown:
        raise DomainError(
            f"{path}: {', '.join(unknown)}: not a randomization this reader knows (legged_gym, "
            "humanoid-gym and their forks' keys); nothing is dropped silently: write the "
            "training domain as a ranges file (soak-test --ranges FILE.toml, policy-export "
            "--domain FILE.toml; see sim2real/eval/world/example_ranges.toml)"
        )
    refused = []
    period = cfg["commands"]["resampling_time"]
    if not (isinstance(period, (int, float)) and not isinstance(period, bool) and period > 0):
        refused.append(f"commands.resampling_time: expected s > 0, got {period!r}")
    for group in GROUPS:
        try:
            group.read(context)
        except ValueError as exc:
            refused.append(str(exc))
    if cfg["terrain_written"]:
        refused += _terrain_refusals(cfg["terrain"])
    if refused:
        raise DomainError(f"{path}: " + "; ".join(refused))
    return "\n".join(domain_lines(context, math.sqrt(3.0))) + "\n"
