"""A policy's training domain: the world it was trained in, as a ranges file
(:mod:`sim2real.eval.world.ranges_file`), so that the soak runs that world plus its own faults.

Where it comes from:

- **legged_gym** (unitree_rl_gym, humanoid-gym and their forks): the task's config class, a Python
  file such as ``legged_gym/envs/h1/h1_config.py``. :func:`legged_gym_domain` reads its
  ``domain_rand`` and ``noise`` classes *as text* (Python's ``ast``; the file is never run), over
  the defaults of legged_gym's ``LeggedRobotCfg`` (``LEGGED_GYM_DEFAULTS``) for what it does not
  set.
- **a ranges file** (TOML) written by hand, or by :func:`domain_toml`.
- **our own recipes**: they train on the soak's own ranges (:func:`sim2real.eval.world.session_ranges.
  session_ranges`), which is what ``soak-test`` runs without a domain.

``policy-export --domain FILE`` stores the domain in the ONNX file (metadata ``training_domain``,
:data:`METADATA_KEY`: the ranges file's text); ``soak-test`` runs it when no ``--ranges`` is given.

legged_gym's quantities and what they become: :func:`legged_gym_domain`.
"""

from __future__ import annotations

import ast
import math
from pathlib import Path

from sim2real.robots.errors import Sim2RealError

#: The ONNX metadata key of a policy's training domain (a ranges file's TOML text).
METADATA_KEY = "training_domain"
#: legged_gym's ``LeggedRobotCfg`` defaults of what :func:`legged_gym_domain` reads
#: (legged_gym/envs/base/legged_robot_config.py, unitree_rl_gym commit 276801e).
LEGGED_GYM_DEFAULTS = {
    "domain_rand": {
        "randomize_friction": True,
        "friction_range": [0.5, 1.25],
        "randomize_base_mass": False,
        "added_mass_range": [-1.0, 1.0],
        "push_robots": True,
        "push_interval_s": 15.0,
        "max_push_vel_xy": 1.0,
    },
    "noise": {
        "add_noise": True,
        "noise_level": 1.0,
        "noise_scales": {
            "dof_pos": 0.01,
            "dof_vel": 1.5,
            "lin_vel": 0.1,
            "ang_vel": 0.2,
            "gravity": 0.05,
            "height_measurements": 0.1,
        },
    },
}
#: Standard gravity, m/s^2 (the projected gravity's noise as an accelerometer's).
G = 9.80665


class DomainError(Sim2RealError, ValueError):
    """A training-domain source that cannot be read (named with its file and what was
    expected)."""


def _literal(node: ast.AST, path: Path, where: str):
    try:
        return ast.literal_eval(node)
    except (ValueError, TypeError, SyntaxError):
        return None  # an expression we do not evaluate (a name, a call): the default stands


def _class_values(cls: ast.ClassDef, path: Path, where: str) -> dict:
    """The literal assignments of a class body, nested classes as dicts."""
    out: dict = {}
    for item in cls.body:
        if isinstance(item, ast.Assign) and len(item.targets) == 1:
            target = item.targets[0]
            if isinstance(target, ast.Name):
                value = _literal(item.value, path, f"{where}.{target.id}")
                if value is not None:
                    out[target.id] = value
        elif isinstance(item, ast.ClassDef):
            out[item.name] = _class_values(item, path, f"{where}.{item.name}")
    return out


def read_legged_gym_config(path: str | Path, config_class: str | None = None) -> dict:
    """The ``domain_rand`` and ``noise`` settings of a legged_gym config file, over
    ``LEGGED_GYM_DEFAULTS``: ``{"domain_rand": {...}, "noise": {...}, "source": str}``.

    Args:
        path: The config's Python file (read as text, never run).
        config_class: The config class (default: the first top-level class with a
            ``domain_rand`` or ``noise`` class, else the first that derives from a name ending
            in ``Cfg``).

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
    classes = [n for n in tree.body if isinstance(n, ast.ClassDef)]
    if config_class is not None:
        chosen = [c for c in classes if c.name == config_class]
        if not chosen:
            raise DomainError(
                f"{path}: no class '{config_class}'; expected one of {[c.name for c in classes]}"
            )
    else:

        def has(c: ast.ClassDef, name: str) -> bool:
            return any(isinstance(i, ast.ClassDef) and i.name == name for i in c.body)

        chosen = [c for c in classes if has(c, "domain_rand") or has(c, "noise")] or [
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
    cls = chosen[0]
    values = _class_values(cls, path, cls.name)
    out = {
        "domain_rand": {**LEGGED_GYM_DEFAULTS["domain_rand"], **values.get("domain_rand", {})},
        "noise": {**LEGGED_GYM_DEFAULTS["noise"], **values.get("noise", {})},
        "source": f"{path.name} ({cls.name}, legged_gym)",
    }
    scales = dict(LEGGED_GYM_DEFAULTS["noise"]["noise_scales"])
    scales.update(values.get("noise", {}).get("noise_scales", {}))
    out["noise"]["noise_scales"] = scales
    return out


def _pair(value, path: Path, key: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise DomainError(
            f"{path}: domain_rand.{key}: expected [low, high], got {value!r}"
        ) from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
        raise DomainError(f"{path}: domain_rand.{key}: expected low <= high, got {value!r}")
    return lo, hi


def legged_gym_domain(path: str | Path, config_class: str | None = None) -> str:
    """The ranges file (TOML text) of a legged_gym task's training domain:

    - shape ``friction_range`` [a, b] -> ``floor_friction = [(a + 1) / 2, (b + 1) / 2]``
      (PhysX averages the shapes' coefficient with the terrain's 1.0; here the contact takes the
      floor's);
    - ``added_mass_range`` [a, b] kg -> ``added_base_mass = [a, b]``;
    - ``push_interval_s``, ``max_push_vel_xy`` -> ``[pushes] interval, max_velocity``;
    - link masses, lengths, joint friction, damping, motor strength -> ``[dynamics]`` all 0
      (legged_gym does not randomize them; a fork's ``link_mass_range`` is read);
    - ``noise_scales.dof_pos`` s (uniform +-s) -> ``[sensors] noise_sigma = [0, s / sqrt(3)]``;
      ``ang_vel`` -> ``[imu] gyro_noise_sigma``; ``gravity`` (a unit vector's) ->
      ``[imu] accel_noise_sigma = [0, g s / sqrt(3)]``;
    - no latency, no IMU bias: latencies ``[0, 0]``, ``bias_scale = [0, 0]``.

    Each ``noise_scales`` entry is multiplied by ``noise.noise_level`` (0 without ``add_noise``); a
    uniform noise of half-width ``s`` has the standard deviation ``s / sqrt(3)``.

    Raises:
        DomainError: an unreadable config or a malformed range (named).
    """
    path = Path(path)
    cfg = read_legged_gym_config(path, config_class)
    dr, noise = cfg["domain_rand"], cfg["noise"]
    lines = [
        f"# training domain of {cfg['source']}",
        "# (read by sim2real.eval.world.domain.legged_gym_domain)",
        "# legged_gym randomizes no link mass, length, joint friction, damping or motor strength.",
    ]
    if dr.get("randomize_friction"):
        lo, hi = _pair(dr["friction_range"], path, "friction_range")
        lines.append(f"floor_friction = [{(lo + 1) / 2:.6g}, {(hi + 1) / 2:.6g}]")
    else:
        lines.append("floor_friction = [1.0, 1.0]")
    if dr.get("randomize_base_mass"):
        lo, hi = _pair(dr["added_mass_range"], path, "added_mass_range")
        lines.append(f"added_base_mass = [{lo:.6g}, {hi:.6g}]")
    mass = 0.0
    if dr.get("randomize_link_mass") and "link_mass_range" in dr:  # a fork's factor range
        lo, hi = _pair(dr["link_mass_range"], path, "link_mass_range")
        mass = max(1.0 - lo, hi - 1.0)
    lines += [
        "",
        "[dynamics]",
        "link_length = 0.0",
        f"mass = {mass:.6g}",
        "friction = 0.0",
        "damping = 0.0",
        "actuator_strength = 0.0",
    ]
    level = float(noise.get("noise_level", 1.0)) if noise.get("add_noise") else 0.0
    scales = noise["noise_scales"]
    root3 = math.sqrt(3.0)
    lines += [
        "",
        "[sensors]",
        f"noise_sigma = [0.0, {level * float(scales['dof_pos']) / root3:.6g}]",
        "latency_ticks = [0, 0]",
        "",
        "[imu]",
        f"gyro_noise_sigma = [0.0, {level * float(scales['ang_vel']) / root3:.6g}]",
        f"accel_noise_sigma = [0.0, {G * level * float(scales['gravity']) / root3:.6g}]",
        "bias_scale = [0.0, 0.0]",
        "latency_ticks = [0, 0]",
    ]
    if dr.get("push_robots"):
        interval, vmax = float(dr["push_interval_s"]), float(dr["max_push_vel_xy"])
        lines += ["", "[pushes]", f"interval = {interval:.6g}", f"max_velocity = {vmax:.6g}"]
    return "\n".join(lines) + "\n"


def domain_toml(path: str | Path) -> str:
    """The ranges file (TOML text) of a training-domain source: a legged_gym config (``.py``)
    through :func:`legged_gym_domain`, a ranges file (``.toml``) as it is.

    Raises:
        DomainError: another suffix, or an unreadable source (named).
    """
    path = Path(path)
    if path.suffix == ".py":
        return legged_gym_domain(path)
    if path.suffix == ".toml":
        try:
            return path.read_text(encoding="utf-8")
        except OSError as exc:
            raise DomainError(f"{path}: cannot read the ranges file ({exc.strerror})") from None
    raise DomainError(
        f"{path}: a training domain is a legged_gym config (.py) or a ranges file (.toml)"
    )


def training_domain(policy: str | Path) -> str | None:
    """The training domain an ONNX policy carries (metadata ``training_domain``, the text of a
    ranges file), or None.

    Raises:
        DomainError: the file cannot be read as ONNX (named).
    """
    import onnx

    try:
        model = onnx.load(str(policy), load_external_data=False)
    except Exception as exc:  # noqa: BLE001 - onnx raises OSError, DecodeError, ...
        raise DomainError(f"{policy}: cannot read the ONNX file's metadata ({exc})") from None
    for prop in model.metadata_props:
        if prop.key == METADATA_KEY:
            return prop.value
    return None


def contract_commands(policy: str | Path):
    """The velocity commands a policy trained elsewhere was trained on, from the contract its
    stack wrote (:mod:`sim2real.deploy.spec.foreign`: Unitree's deploy.yaml ``commands.base_velocity.
    ranges``, holosoma's ``command_ranges``): ``(CommandRanges, where)``, or ``(None, None)``
    for a policy with our own metadata, no recognised contract, or none recorded. The fraction of
    zero commands stays :class:`~sim2real.deploy.tasks.commands.CommandRanges`' default.

    Raises:
        DomainError: the file cannot be read as ONNX, or its contract cannot be read (named).
    """
    import onnx

    from sim2real.deploy.spec.foreign.registry import OnnxFacts, read_contract
    from sim2real.deploy.spec.policy_spec import SpecError
    from sim2real.deploy.tasks.commands import CommandRanges

    try:
        model = onnx.load(str(policy), load_external_data=False)
    except Exception as exc:  # noqa: BLE001 - onnx raises OSError, DecodeError, ...
        raise DomainError(f"{policy}: cannot read the ONNX file ({exc})") from None
    if any(p.key == "policy_spec" for p in model.metadata_props):
        return None, None
    try:
        contract = read_contract(OnnxFacts.of(policy, model))
    except SpecError as exc:
        raise DomainError(str(exc)) from None
    if contract is None or contract.command_ranges is None:
        return None, None
    r = contract.command_ranges
    return CommandRanges(vx=r["vx"], vy=r["vy"], yaw_rate=r["yaw_rate"]), contract.source
