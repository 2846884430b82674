"""The training domain of a legged_gym task (unitree_rl_gym, HIMLoco, humanoid-gym and their forks)
as a ranges file (:mod:`sim2real.eval.world.ranges_file`): :func:`legged_gym_domain`.

The task's config class is read *as text* (Python's ``ast``; no file is run) with everything it
inherits from the tree its file sits in (:mod:`sim2real.eval.world.legged_gym_tree`: the fork's
own base, a nested class over its base's; a base the tree lacks is refused in one line naming the
class and the module, no stack's defaults stand in): its ``domain_rand`` class (or
``domain_rands`` with nested classes, as some forks write it: their keys are read as one table),
``noise``, ``terrain`` (a ``[terrain]`` table of tiles, :mod:`sim2real.eval.world.terrain`, where
its ``mesh_type``, the task's or its base's, has tiles), ``commands`` and ``control``. Every
``domain_rand`` key is read (:data:`GROUPS`: a switch and the keys it turns on) or named in one
line of the stored domain: a randomization the soak cannot run (restitution, HIMLoco's
disturbance and action delay, latencies in physics steps, action noise, external forces) as not
modelled, a key no group knows as not modelled unless it is a switch that is off or belongs to
one (``randomize_X = False`` and a key containing ``X``), a randomization that is off as off; the
other classes' keys the same way (:mod:`sim2real.eval.world.legged_gym_lines`). Every value
names the file and line it came from. A malformed value of a key the soak models, or a terrain it
cannot build, is refused (:class:`DomainError`, named).
"""

from __future__ import annotations

import math
from pathlib import Path

from sim2real.deploy.core.stacks import DomainReader
from sim2real.eval.world.legged_gym_groups import GROUPS, Context
from sim2real.eval.world.legged_gym_lines import domain_lines, terrain_table
from sim2real.eval.world.legged_gym_tree import Setting, TreeError, resolve_config
from sim2real.eval.world.manager_config import refuse_manager_config
from sim2real.robots.errors import Sim2RealError


class DomainError(Sim2RealError, ValueError):
    """A training-domain source that cannot be read (named with its file and what was
    expected)."""


def _rand(values: dict) -> dict[str, Setting]:
    """``domain_rand`` (or a fork's ``domain_rands`` with nested classes) flattened: every key
    at the top, each keeping its path."""
    out: dict[str, Setting] = {}
    for value in values.values():
        if isinstance(value, dict):
            out.update(_rand(value))
        else:
            out[value.path.rsplit(".", 1)[-1]] = value
    return out


def read_legged_gym_config(path: str | Path, config_class: str | None = None) -> dict:
    """The settings of a legged_gym config class with everything it inherits
    (:func:`~sim2real.eval.world.legged_gym_tree.resolve_config`): ``{"domain_rand": {key:
    Setting}, "noise": {...}, "terrain": {key: Setting}, "commands": {...}, "control": {...},
    "source": str, "classes": [str], "env_files": [(Path, str)]}`` (``domain_rand``
    flattened: a fork's nested classes' keys at the top, each with its path, file and line;
    ``noise`` and ``commands`` nested as written; ``env_files``: the ``legged_robot.py`` beside
    each base's file, the environment the heading command is read from).

    Args:
        path: The config's Python file (read as text, never run), in its own tree.
        config_class: The config class (default: the first top-level class with a
            ``domain_rand``, ``domain_rands``, ``noise``, ``terrain`` or ``commands`` class,
            else the first that derives from a name ending in ``Cfg``).

    Raises:
        DomainError: an unreadable file, not Python, no such config class, a base the tree
            does not hold (one line naming the class and the module), or an Isaac Lab or mjlab
            config in Python (:func:`~sim2real.eval.world.manager_config.refuse_manager_config`:
            one line naming the file, the class and the run folder's ``params/env.yaml``).
    """
    path = Path(path)
    refusal = refuse_manager_config(path, config_class)
    if refusal is not None:  # Isaac Lab's or mjlab's Python: not readable as legged_gym's
        raise DomainError(refusal)
    try:
        resolved = resolve_config(path, config_class)
    except TreeError as exc:
        raise DomainError(str(exc)) from None
    rand: dict[str, Setting] = {}
    for name in ("domain_rand", "domain_rands"):
        rand.update(_rand(resolved.section(name)))
    env_files = []
    for entry in resolved.classes:
        rel = entry[entry.index("(") + 1 : -1]
        candidate = (resolved.root or path.parent) / Path(rel).parent / "legged_robot.py"
        if candidate.is_file() and all(candidate != f for f, _ in env_files):
            env_files.append((candidate, str(Path(rel).parent / "legged_robot.py")))
    terrain = {k: v for k, v in resolved.section("terrain").items() if isinstance(v, Setting)}
    return {
        "domain_rand": rand,
        "noise": resolved.section("noise"),
        "terrain": terrain,
        "commands": resolved.section("commands"),
        "control": resolved.section("control"),
        "env": {k: v for k, v in resolved.section("env").items() if isinstance(v, Setting)},
        "source": f"{resolved.file} ({resolved.name}, legged_gym)",
        "classes": resolved.classes,
        "env_files": env_files,  # the task's own folder first, then its bases' in order
    }


def _terrain_refusals(terrain: dict, env: dict) -> list[str]:
    """Why the soak cannot build legged_gym's ``terrain`` class (its kinds past the fifth share,
    a mesh type it does not know; named), or nothing."""
    from sim2real.eval.world.terrain import TerrainRanges

    table = terrain_table(terrain, env)
    if table is None:
        return []
    try:
        TerrainRanges(**{k: tuple(v) if isinstance(v, list) else v for k, v in table.items()})
    except (TypeError, ValueError) as exc:
        return [str(exc).replace("TerrainRanges.", "terrain.", 1)]
    return []


def legged_gym_domain(path: str | Path, config_class: str | None = None) -> str:
    """The ranges file (TOML text) of a legged_gym task's training domain, read with everything
    its class inherits. What each ``domain_rand`` key becomes is its group's
    (:data:`sim2real.eval.world.legged_gym_groups.GROUPS`, which says it); the noise
    (``noise_scales`` times ``noise_level``, 0 without ``add_noise``; a uniform noise of
    half-width ``s`` has the standard deviation ``s / sqrt(3)``): ``dof_pos`` -> ``[sensors]
    noise_sigma``, ``ang_vel`` -> ``[imu] gyro_noise_sigma``, ``gravity`` (a unit vector's) ->
    ``[imu] accel_noise_sigma`` (times g); ``commands`` -> ``[commands]``
    (:func:`~sim2real.eval.world.legged_gym_lines.command_lines`); ``terrain`` -> ``[terrain]``
    where its ``mesh_type`` has tiles. Every value is written with where it came from, every key
    of ``domain_rand``, ``terrain``, ``commands``, ``noise`` and ``control`` the soak does not
    model is named in one line (:mod:`sim2real.eval.world.legged_gym_lines`).

    Raises:
        DomainError: an unreadable config, a base the tree does not hold, a malformed value of
            a key the soak models, or a terrain the soak cannot build (each named with the file
            and its path).
    """
    path = Path(path)
    cfg = read_legged_gym_config(path, config_class)
    context = Context(path, cfg)
    known = {key for group in GROUPS for key in (*group.switches, *group.values)}
    for key, setting in cfg["domain_rand"].items():
        if key in known:
            continue
        if context.switched_off(key, setting.value):
            context.off.append(f"{context.source(key)}: a switch that is off, or its key")
        else:
            context.apart.append(
                f"{context.source(key)}: not a randomization this reader knows (legged_gym, "
                "HIMLoco, humanoid-gym and their forks' keys)"
            )
    refused = []
    if "static_friction" not in cfg["terrain"]:
        refused.append(
            "terrain.static_friction: not in the config (legged_gym averages the shapes' "
            "friction with it)"
        )
    else:
        for group in GROUPS:
            try:
                group.read(context)
            except ValueError as exc:
                refused.append(str(exc))
    refused += _terrain_refusals(cfg["terrain"], cfg["env"])
    if not refused:
        try:
            text = "\n".join(domain_lines(context, math.sqrt(3.0))) + "\n"
        except ValueError as exc:
            refused.append(str(exc))
    if refused:
        raise DomainError(f"{path}: " + "; ".join(refused))
    return text


#: legged_gym's training-domain face (the ``legged_gym`` stack's, :mod:`sim2real.stacks`): a task's
#: config class (``.py``); its exports record none.
DOMAIN = DomainReader("a legged_gym config (.py)", (".py",), legged_gym_domain)
