"""The ranges file (TOML text) of a legged_gym config read with its bases (:func:`domain_lines`),
every value with where it came from and every key the soak does not model named in one line.

The text opens with its account, comment lines a reader audits against the config:

- ``# from: KEY = VALUE <- SOURCE``: each value the file sets, SOURCE the config's key, value,
  file and line (relative to the package root), or a stack's documented default named as such;
- ``# not modelled: ...``: a key the training used that the soak does not model, and why;
- ``# off: ...``: a randomization the training had off (its keys, files and lines).

``policy-export --inspect`` and the soak's report print these lines
(:func:`sim2real.eval.world.domain.domain_account`).
"""

from __future__ import annotations

import ast
from pathlib import Path

from sim2real.eval.world.legged_gym_groups import NOISE_APART, NOISE_READ, Context, G
from sim2real.eval.world.legged_gym_tree import Setting

#: legged_gym ``terrain`` keys a ranges file's ``[terrain]`` takes as they are
#: (:class:`sim2real.eval.world.terrain.TerrainRanges`).
TERRAIN_KEYS = ("mesh_type", "terrain_proportions", "num_rows", "num_cols", "curriculum",
                "horizontal_scale", "vertical_scale", "terrain_length", "terrain_width",
                "slope_treshold")  # fmt: skip
#: The side of the soak's grid of tiles (``[terrain] tiles``) for a legged_gym terrain: our
#: choice, 5 x 5 tiles of 8 m (40 m), past what a command of HIMLoco's (10 s, up to 2 m/s)
#: walks from the centre; legged_gym's own robots walk on a grid of ``num_rows x num_cols``.
GRID_TILES = 5
#: legged_gym's ``env.episode_length_s`` where the config sets none (``LeggedRobotCfg.env``,
#: legged_gym/envs/base/legged_robot_config.py: ``episode_length_s = 20 # episode length in
#: seconds``; HIMLoco's the same).
EPISODE_LENGTH_S = 20.0
#: Why the other ``terrain`` keys are not modelled.
TERRAIN_APART = {
    "dynamic_friction": "MuJoCo's contact has one sliding friction: the static one is drawn",
    "restitution": "the soak's ground has no restitution",
    "border_size": "the flat ground around the soak's tiles is its own",
    "measure_heights": "height samples are the policy's observation (its contract), not the world",
    "measured_points_x": "height samples are the policy's observation (its contract)",
    "measured_points_y": "height samples are the policy's observation (its contract)",
    "selected": "one terrain kind with terrain_kwargs (legged_gym's selected_terrain); the soak "
    "draws the kinds by terrain_proportions",
    "terrain_kwargs": "the arguments of a selected terrain",
    "max_init_terrain_level": "the curriculum's first level; the soak draws every level",
}
#: legged_gym's heading command as upstream legged_gym writes it (leggedrobotics/legged_gym
#: ``legged_robot.py`` ``_post_physics_step_callback``: ``clip(0.5 * wrap_to_pi(heading - yaw),
#: -1, 1)``), used when the tree's own ``legged_robot.py`` does not say: 1/s and rad/s.
UPSTREAM_HEADING = (0.5, 1.0)


def _fmt(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return f"{v:.6g}" if isinstance(v, float) else str(v)


def _flat(section: dict) -> list[Setting]:
    out = []
    for v in section.values():
        out += _flat(v) if isinstance(v, dict) else [v]
    return out


def _src(s: Setting) -> str:
    return f"{s.path} {s.value!r} ({s.where})"


def domain_lines(c: Context, root3: float) -> list[str]:
    """The ranges file's lines of a config read into ``c`` (its groups applied): the account
    (module docstring), then the tables.

    Raises:
        ValueError: a command or terrain value the soak cannot take (named).
    """
    cfg = c.cfg
    terrain = cfg["terrain"]
    t = float(terrain["static_friction"].value)
    body: list[str] = []
    fixed = f"{(1 + t) / 2:.6g}"  # not randomized: the shapes' 1 with the terrain's
    if "floor_friction" not in c.top:
        c.prov.append(
            f"floor_friction = [{fixed}, {fixed}] <- no friction randomization: legged_gym's "
            f"shape friction 1 and {_src(terrain['static_friction'])}, averaged"
        )
    body.append(f"floor_friction = {c.top.get('floor_friction', f'[{fixed}, {fixed}]')}")
    if "added_base_mass" in c.top:
        body.append(f"added_base_mass = {c.top['added_base_mass']}")
    zeros = [k for k in ("link_length", "mass", "friction", "damping", "actuator_strength")
             if k not in c.dynamics]  # fmt: skip
    if zeros:
        c.prov.append(f"dynamics.{', '.join(zeros)} = 0 <- no randomization of them is on")
    dynamics = {**{k: "0.0" for k in zeros}, **c.dynamics}
    body += ["", "[dynamics]", *(f"{k} = {v}" for k, v in dynamics.items())]
    body += _noise_lines(c, root3)
    if c.pushes:
        body += ["", "[pushes]", *c.pushes]
    body += command_lines(c)
    body += terrain_lines(c)
    _control(c)
    head = [
        f"# training domain of {cfg['source']}",
        f"# (read by sim2real.eval.world.legged_gym_domain; classes: {', '.join(cfg['classes'])})",
        f"# terrain: {terrain.get('mesh_type', Setting(None, '', '', 0)).value}, static "
        f"friction {t:g}",
        *(f"# {note}" for note in c.notes),
        *(f"# from: {line}" for line in c.prov),
        *(f"# not modelled: {line}" for line in c.apart),
        *(f"# off: {line}" for line in c.off),
    ]
    return head + body


def _noise_lines(c: Context, root3: float) -> list[str]:
    noise = c.cfg["noise"]
    scales = noise.get("noise_scales", {})
    add = noise.get("add_noise")
    level_s = noise.get("noise_level")
    on = bool(add.value) if add is not None else False
    level = float(level_s.value) if (on and level_s is not None) else 0.0
    why = (
        f"{_src(add)} x {_src(level_s)}" if add is not None and level_s is not None
        else "no noise in the config"
    )  # fmt: skip

    def sigma(key: str, factor: float = 1.0) -> str:
        s = scales.get(key)
        value = level * factor * float(s.value) / root3 if s is not None else 0.0
        return f"{value:.6g}"

    dof, gyro, accel = sigma("dof_pos"), sigma("ang_vel"), sigma("gravity", G)
    for name, key, out, unit in (
        ("sensors.noise_sigma", "dof_pos", dof, ""),
        ("imu.gyro_noise_sigma", "ang_vel", gyro, ""),
        ("imu.accel_noise_sigma", "gravity", accel, " x g (a unit vector's noise)"),
    ):
        s = scales.get(key)
        what = _src(s) if s is not None else f"noise.noise_scales.{key} not in the config"
        c.prov.append(f"{name} = [0, {out}] <- {what}, {why}{unit}, U(-s, s) as sigma s/sqrt(3)")
    for s in _flat(scales):
        if s.path.rsplit(".", 1)[-1] not in NOISE_READ:
            c.apart.append(f"{_src(s)}: not drawn ({NOISE_APART})")
    c.prov.append(
        "sensors.latency_ticks, imu.latency_ticks = [0, 0], imu.bias_scale = [0, 0] <- no "
        "latency or bias in legged_gym's noise"
    )
    return [
        "",
        "[sensors]",
        f"noise_sigma = [0.0, {dof}]",
        "latency_ticks = [0, 0]",
        *(f"{k} = {v}" for k, v in c.sensors.items()),
        "",
        "[imu]",
        f"gyro_noise_sigma = [0.0, {gyro}]",
        f"accel_noise_sigma = [0.0, {accel}]",
        "bias_scale = [0.0, 0.0]",
        "latency_ticks = [0, 0]",
    ]


def heading_clip(env_files: list[tuple[Path, str]]) -> tuple[float, float, str] | None:
    """The heading command's stiffness (1/s) and yaw-rate clip (rad/s) as the tree's
    ``legged_robot.py`` writes them (``torch.clip(K * wrap_to_pi(...), -M, M)``), with its file
    and line: ``(K, M, where)``; None when no file says it in exactly one way."""
    found = set()
    for path, rel in env_files:
        try:
            tree = ast.parse(path.read_text(encoding="utf-8"))
        except (OSError, SyntaxError, UnicodeDecodeError):
            continue
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Call) and ast.unparse(node.func).endswith("clip")):
                continue
            if len(node.args) != 3 or not isinstance(node.args[0], ast.BinOp):
                continue
            op = node.args[0]
            call = op.right if isinstance(op.right, ast.Call) else op.left
            k = op.left if call is op.right else op.right
            if not (isinstance(op.op, ast.Mult) and isinstance(call, ast.Call)
                    and ast.unparse(call.func).endswith("wrap_to_pi")):  # fmt: skip
                continue
            try:
                k, lo, hi = (float(ast.literal_eval(x)) for x in (k, *node.args[1:]))
            except (ValueError, TypeError, SyntaxError):
                continue
            if lo == -hi:
                found.add((k, hi, f"{rel}:{node.lineno}"))
        if found:
            break
    values = {(k, m) for k, m, _ in found}
    return next(iter(found)) if len(values) == 1 and len(found) == 1 else None


def command_lines(c: Context) -> list[str]:
    """The ``[commands]`` table: ``period`` (``resampling_time``), ``heading_command``,
    ``heading``, ``heading_stiffness`` and ``max_yaw_rate`` (the tree's ``legged_robot.py``,
    else upstream's, named), and ``vx``, ``vy``, ``yaw_rate`` where the training draws them
    (``lin_vel_x`` widened to ``+-max_curriculum`` under the command curriculum; no
    ``yaw_rate`` under a heading command: it comes from the heading).

    Raises:
        ValueError: a malformed period or range (named).
    """
    cmd = c.cfg["commands"]
    if not cmd:
        c.prov.append("[commands]: none <- the config has no commands class")
        return []
    ranges = cmd.get("ranges", {})
    used: set[str] = set()
    out = ["", "[commands]"]

    def get(key, where=cmd):
        s = where.get(key)
        if s is not None:
            used.add(s.path)
        return s

    period = get("resampling_time")
    if period is not None:
        p = period.value
        if not (isinstance(p, (int, float)) and not isinstance(p, bool) and p > 0):
            raise ValueError(f"{period.path}: expected s > 0, got {p!r}")
        out.append(f"period = {float(p):.6g}")
        c.prov.append(f"commands.period = {float(p):.6g} <- {_src(period)}")

    def pair(s: Setting) -> tuple[float, float]:
        try:
            lo, hi = (float(v) for v in s.value)
        except (TypeError, ValueError):
            raise ValueError(f"{s.path}: expected [low, high], got {s.value!r}") from None
        if not lo <= hi:
            raise ValueError(f"{s.path}: expected low <= high, got {s.value!r}")
        return lo, hi

    heading = get("heading_command")
    on = heading is not None and bool(heading.value)
    if heading is not None:
        out.append(f"heading_command = {_fmt(on)}")
        c.prov.append(f"commands.heading_command = {_fmt(on)} <- {_src(heading)}")
    if on:
        h = get("heading", ranges)
        if h is None:
            raise ValueError(f"{heading.path}: a heading command and no commands.ranges.heading")
        lo, hi = pair(h)
        out.append(f"heading = [{lo:.6g}, {hi:.6g}]")
        c.prov.append(f"commands.heading = [{lo:.6g}, {hi:.6g}] <- {_src(h)}, rad")
        clip = heading_clip(c.cfg.get("env_files", []))
        if clip is not None:
            k, m, where = clip
            src = f"clip({k:g} * wrap_to_pi(heading - yaw), -{m:g}, {m:g}) ({where})"
        else:
            (k, m), src = (
                UPSTREAM_HEADING,
                (
                    "upstream legged_gym's documented default, clip(0.5 * wrap_to_pi(heading - yaw), "
                    "-1, 1) in its legged_robot.py (the tree's own legged_robot.py does not say it in "
                    "one way)"
                ),
            )
        out += [f"heading_stiffness = {k:.6g}", f"max_yaw_rate = {m:.6g}"]
        c.prov.append(f"commands.heading_stiffness = {k:g}, max_yaw_rate = {m:g} <- {src}")
    elif "heading" in ranges:
        used.add(ranges["heading"].path)
        c.apart.append(f"{_src(ranges['heading'])}: unused (heading_command is off)")
    curriculum = get("curriculum")
    top = get("max_curriculum")
    for ours, theirs in (("vx", "lin_vel_x"), ("vy", "lin_vel_y"), ("yaw_rate", "ang_vel_yaw")):
        s = get(theirs, ranges)
        if s is None:
            continue
        if ours == "yaw_rate" and on:
            c.apart.append(
                f"{_src(s)}: not drawn (heading_command: the yaw rate comes from the heading)"
            )
            continue
        lo, hi = pair(s)
        src = _src(s)
        if ours == "vx" and curriculum is not None and curriculum.value and top is not None:
            m = float(top.value)
            lo, hi = -m, m
            src += (
                f", widened by the command curriculum to +-{_src(top)} (legged_gym's "
                "update_command_curriculum: lin_vel_x's ends moved toward +-max_curriculum); its "
                "final range"
            )
        out.append(f"{ours} = [{lo:.6g}, {hi:.6g}]")
        c.prov.append(f"commands.{ours} = [{lo:.6g}, {hi:.6g}] <- {src}")
    if curriculum is not None and not curriculum.value and top is not None:
        c.off.append(f"{_src(curriculum)}, {_src(top)}: the command curriculum")
    for s in _flat(cmd):
        if s.path not in used:
            c.apart.append(f"{_src(s)}: not a command the soak draws (the policy contract's)")
    # legged_gym has no share of standing commands (it zeroes the x and y of a command under
    # 0.2 m/s, keeping its yaw): zero_fraction stays the soak's
    c.prov.append(
        "commands.zero_fraction: the soak's own (legged_gym zeroes commands under 0.2 m/s in "
        "its code, not a key)"
    )
    return out


def terrain_table(terrain: dict, env: dict | None = None) -> dict | None:
    """The ``[terrain]`` table (``{key: value}``) of legged_gym's ``terrain`` class ``terrain``
    (``{key: Setting}``), every level drawn; None for a flat one (``plane``, ``none``): the
    soak's plane. With its ``curriculum`` on (legged_gym's default) the sessions walk it as the
    curriculum does (``walk = "curriculum"``: :mod:`sim2real.eval.soak.curriculum_walk`), in
    episodes of the ``env`` class's ``episode_length_s`` (``{key: Setting}``; else
    :data:`EPISODE_LENGTH_S`)."""
    mesh = terrain.get("mesh_type")
    if mesh is None or mesh.value in ("plane", "none"):
        return None
    out = {k: terrain[k].value for k in TERRAIN_KEYS if k in terrain}
    rows = terrain.get("num_rows")
    out["levels"] = [0, int(rows.value if rows is not None else 10) - 1]
    out["tiles"] = GRID_TILES
    if out.get("curriculum", True) is True:
        out["walk"] = "curriculum"
        length = (env or {}).get("episode_length_s")
        out["episode_length_s"] = float(length.value) if length is not None else EPISODE_LENGTH_S
    return out


def terrain_lines(c: Context) -> list[str]:
    """:func:`terrain_table` as TOML lines (none for a flat terrain), each key's source in
    ``c.prov``, the rest of the class in ``c.apart``."""
    terrain = c.cfg["terrain"]
    env = c.cfg.get("env") or {}
    table = terrain_table(terrain, env)
    friction = {"static_friction"}
    if table is None:
        mesh = terrain.get("mesh_type")
        what = _src(mesh) if mesh is not None else "terrain.mesh_type not in the config"
        c.prov.append(f"[terrain]: none (the soak's flat plane) <- {what}")
        tiles = [k for k in terrain if k not in friction | {"mesh_type"}]
        if tiles:
            c.off.append(f"terrain.{', '.join(tiles)}: tile keys of a flat plane, unused")
        return []
    lines = ["", "[terrain]"]
    for key, value in table.items():
        lines.append(f"{key} = {_fmt(value)}")
        if key == "tiles" and table.get("walk") == "curriculum":
            c.prov.append(
                f"terrain.tiles = {value} <- the soak's: each session walks its kind's column "
                f"of legged_gym's map, one tile per level along x (num_rows), {value} tiles "
                "of its kind along y (legged_gym's neighbouring columns hold other kinds)"
            )
        elif key == "walk":
            on = terrain.get("curriculum")
            src = (
                _src(on)
                if on is not None
                else "legged_gym's curriculum = True (documented default)"
            )
            c.prov.append(
                f'terrain.walk = "curriculum" <- {src}: the robot spawns at its level\'s tile '
                "centre, each episode's end moves its level by legged_gym's "
                "_update_terrain_curriculum (legged_robot.py) and respawns it there"
            )
        elif key == "episode_length_s":
            length = env.get("episode_length_s")
            src = (
                _src(length)
                if length is not None
                else (
                    f"legged_gym's env.episode_length_s {EPISODE_LENGTH_S:g} (documented default)"
                )
            )
            c.prov.append(f"terrain.episode_length_s = {value:g} <- {src}")
        elif key == "tiles":
            c.prov.append(
                f"terrain.tiles = {value} <- the soak's: legged_gym's robot walks on a grid of "
                "num_rows x num_cols tiles, off its own onto its neighbours; ours on a "
                f"{value} x {value} grid of the session's kind and level "
                f"({value * float(table.get('terrain_length', 8.0)):g} m), so that its commands walk "
                "it across tiles, not off them onto the flat border"
            )
        elif key == "levels":
            rows = terrain.get("num_rows")
            src = _src(rows) if rows is not None else "legged_gym's 10 rows (documented default)"
            c.prov.append(f"terrain.levels = {_fmt(value)} <- every row of {src}")
        else:
            c.prov.append(f"terrain.{key} = {_fmt(value)} <- {_src(terrain[key])}")
    for key, s in terrain.items():
        if key in TERRAIN_KEYS or key in friction or not isinstance(s, Setting):
            continue
        why = TERRAIN_APART.get(key, "not a terrain key the soak knows")
        c.apart.append(f"{_src(s)}: {why}")
    return lines


def _control(c: Context) -> None:
    """The ``control`` class's keys, each named: the policy's contract and the robot's."""
    for s in _flat(c.cfg["control"]):
        c.apart.append(
            f"{_src(s)}: not the domain's (the policy contract's and the robot's: the spec, "
            "robot.toml)"
        )
