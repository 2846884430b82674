"""What each ``domain_rand`` key of a legged_gym config becomes in a ranges file (:data:`GROUPS`),
and the file's lines (:func:`domain_lines`); read by
:func:`sim2real.eval.world.legged_gym_domain.legged_gym_domain`.

A :class:`Group` is one randomization: its switches (``randomize_X``; any on turns it on), the
keys that give its values, and what it becomes, or why the soak cannot run it (then a group
that is on is refused, naming its keys). Ranges of factors ``[a, b]`` become the half-range
``max(1 - a, b - 1)`` of a factor drawn from ``U(1 - r, 1 + r)`` (the ranges file's
``[dynamics]``); an asymmetric range is widened to the symmetric one that holds it, and the
file says so in a comment.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

#: legged_gym's ``LeggedRobotCfg`` defaults of what the reader reads
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
    "terrain": {
        "mesh_type": "trimesh",
        "static_friction": 1.0,
        "dynamic_friction": 1.0,
        "terrain_proportions": [0.1, 0.1, 0.35, 0.25, 0.2],
        "num_rows": 10,
        "num_cols": 20,
        "curriculum": True,
        "horizontal_scale": 0.1,
        "vertical_scale": 0.005,
        "terrain_length": 8.0,
        "terrain_width": 8.0,
        "slope_treshold": 0.75,
    },  # fmt: skip
    "commands": {
        "resampling_time": 10.0,
        "heading_command": True,
        "ranges": {"lin_vel_x": [-1.0, 1.0], "lin_vel_y": [-1.0, 1.0], "ang_vel_yaw": [-1.0, 1.0]},
    },
    "sim": {"dt": 0.005},
    "control": {"decimation": 4},
}
#: Where the defaults' keys are said to be written (their ``where``).
DEFAULTS_PATH = "LeggedRobotCfg.domain_rand"
#: Standard gravity, m/s^2 (the projected gravity's noise as an accelerometer's).
G = 9.80665
#: The ``noise_scales`` a ranges file draws: the encoders', the gyro's, the accelerometer's.
NOISE_READ = ("dof_pos", "ang_vel", "gravity")
#: Why the others are not drawn.
NOISE_APART = (
    "the runtime estimates joint and base velocities and the attitude from the encoders and the "
    "IMU, whose noise it draws; no robot here measures heights"
)


class Context:
    """One config being read: its values (``cfg`` of ``read_legged_gym_config``) and what the
    groups make of them (``top``, ``dynamics``, ``sensors``, ``pushes``, ``notes``)."""

    def __init__(self, path: Path, cfg: dict):
        self.path, self.cfg, self.rand = path, cfg, cfg["domain_rand"]
        self.top: dict[str, str] = {}
        self.dynamics: dict[str, str] = {}
        self.sensors: dict[str, str] = {}
        self.pushes: list[str] = []
        self.notes: list[str] = []

    def value(self, key: str):
        return self.rand[key][1] if key in self.rand else None

    def where(self, key: str) -> str:
        return self.rand[key][0]

    def pair(self, key: str) -> tuple[float, float]:
        """``[low, high]`` of ``key``.

        Raises:
            ValueError: not two finite numbers low <= high (named)."""
        value = self.value(key)
        try:
            lo, hi = (float(v) for v in value)
        except (TypeError, ValueError):
            raise ValueError(f"{self.where(key)}: expected [low, high], got {value!r}") from None
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise ValueError(f"{self.where(key)}: expected low <= high, got {value!r}")
        return lo, hi

    def first(self, keys: tuple[str, ...]) -> str | None:
        """The first of ``keys`` the config sets itself, else the first of legged_gym's defaults
        (a fork's ``added_base_mass_range`` over the default ``added_mass_range``); None: none."""
        own = [k for k in keys if k in self.rand and not self.is_default(k)]
        return own[0] if own else next((k for k in keys if k in self.rand), None)

    def is_default(self, key: str) -> bool:
        """``key`` is legged_gym's default (``LEGGED_GYM_DEFAULTS``), not the config's own."""
        return self.where(key).startswith(DEFAULTS_PATH + ".")

    def half_range(self, key: str, what: str) -> float:
        """A factor range ``[a, b]`` as the half-range about 1 that holds it (noted when
        widened)."""
        lo, hi = self.pair(key)
        r = max(1.0 - lo, hi - 1.0, 0.0)
        if not r < 1.0:
            raise ValueError(f"{self.where(key)}: a factor range {[lo, hi]} reaches 0 or below")
        if not math.isclose(1.0 - lo, hi - 1.0):
            self.notes.append(f"{self.where(key)} {[lo, hi]}: {what} +-{r:.4g} (widened to 1 +- r)")
        return r

    def switched_off(self, key: str, value) -> bool:
        """A key no group knows that belongs to a switch that is off: itself a switch that is
        off, or containing the ``X`` of a ``randomize_X`` that is off."""
        if value is False or key.startswith("randomize_") and not value:
            return True
        stems = [k[len("randomize_") :].lower() for k, (_, v) in self.rand.items()
                 if k.startswith("randomize_") and not v]  # fmt: skip
        return any(stem and stem in key.lower() for stem in stems)


@dataclass(frozen=True)
class Group:
    """One randomization of legged_gym's ``domain_rand`` (module docstring).

    Attributes:
        what: What it randomizes (messages). switches: Keys that turn it on (any true).
        values: Keys that give it its values. fixed: Keys among ``values`` that turn it on
            when nonzero whatever the switches (humanoid-gym's ``action_delay``).
        read_into: ``(context, group) -> None``, what it becomes; None: the soak cannot run it
            (``why``), and a group that is on is refused.
    """

    what: str
    switches: tuple[str, ...]
    values: tuple[str, ...]
    read_into: Callable[[Context, Group], None] | None = None
    why: str = ""
    fixed: tuple[str, ...] = ()

    def on(self, c: Context) -> bool:
        if any(c.value(k) for k in self.switches):
            return True
        return any(c.value(k) not in (None, 0, 0.0, False, [], ()) for k in self.fixed)

    def read(self, c: Context) -> None:
        """Apply the group to ``c`` when it is on.

        Raises:
            ValueError: it is on and the soak cannot run it, or a value is malformed (named).
        """
        if not self.on(c):
            return
        if self.read_into is None:
            keys = [c.where(k) for k in (*self.switches, *self.values) if c.value(k)]
            raise ValueError(f"{', '.join(keys)}: {self.what}: {self.why}")
        self.read_into(c, self)


def _floor(c: Context, g: Group) -> None:
    key = c.first(g.values)
    if key is None:
        raise ValueError(f"{c.where(g.switches[0])}: no friction range ({', '.join(g.values)})")
    lo, hi = c.pair(key)
    t = float(c.cfg["terrain"]["static_friction"])
    c.top["floor_friction"] = f"[{(lo + t) / 2:.6g}, {(hi + t) / 2:.6g}]"


def _base_mass(c: Context, g: Group) -> None:
    lo, hi = c.pair(c.first(g.values) or g.values[0])
    c.top["added_base_mass"] = f"[{lo:.6g}, {hi:.6g}]"


def _factor(field: str) -> Callable[[Context, Group], None]:
    def read_into(c: Context, g: Group) -> None:
        key = c.first(g.values)
        if key is None:
            raise ValueError(f"{c.where(g.switches[0])}: no range ({', '.join(g.values)})")
        c.dynamics[field] = f"{c.half_range(key, field):.6g}"

    return read_into


#: Armature ranges in kg m^2, drawn as the armature itself (engineai's and humanoid forks'
#: ``dof_props["armature"] = joint_armatures``), not as a factor of the robot's.
ABSOLUTE_ARMATURE = ("joint_armature_range",)


def _armature(c: Context, g: Group) -> None:
    key = c.first(g.values)
    if key in ABSOLUTE_ARMATURE:
        lo, hi = c.pair(key)
        raise ValueError(
            f"{c.where(key)} = [{lo:g}, {hi:g}]: armature values in kg m^2 that replace the "
            "robot's; the soak's [dynamics] armature scales the robot's own armature by a "
            "factor: write that factor in a ranges file (soak-test --ranges FILE.toml)"
        )
    _factor("armature")(c, g)


def _com(c: Context, g: Group) -> None:
    key = c.first(g.values)
    if key is None:
        raise ValueError(f"{c.where(g.switches[0])}: no range ({', '.join(g.values)})")
    value = c.value(key)
    if key == "rand_com_vec":  # half-widths per axis
        axes = [(-abs(float(v)), abs(float(v))) for v in value]
    else:
        axes = [c.pair(key)] * 3
    parts = ", ".join(
        f"{a} = [{lo:.6g}, {hi:.6g}]" for a, (lo, hi) in zip("xyz", axes, strict=True)
    )
    c.dynamics["com_offset"] = "{" + parts + "}"  # the base body


def _motor_offset(c: Context, g: Group) -> None:
    lo, hi = c.pair(c.first(g.values) or g.values[0])
    c.sensors["encoder_bias"] = f"[{lo:.6g}, {hi:.6g}]"


def _pushes(c: Context, g: Group) -> None:
    angular = c.value("max_push_ang_vel")
    if angular:
        raise ValueError(
            f"{c.where('max_push_ang_vel')} = {angular}: a push that sets the base's angular "
            "velocity (humanoid-gym): the soak's legged_gym pushes set the horizontal velocity "
            "only"
        )
    interval = float(c.value("push_interval_s") or 15.0)
    vmax = float(c.value("max_push_vel_xy") or 1.0)
    c.pushes = [f"interval = {interval:.6g}", f"max_velocity = {vmax:.6g}"]


_LATENCY = "a latency in physics steps; the soak's latencies are whole control ticks and act on "
_WRITE = "; leave it out of a ranges file written by hand if the soak may skip it"
#: Every randomization of legged_gym's ``domain_rand`` and its forks' (unitree_rl_gym,
#: humanoid-gym, engineai's ``domain_rands``), in the order the ranges file is written.
GROUPS: tuple[Group, ...] = (
    Group("floor friction ((range + terrain.static_friction) / 2: PhysX averages the two)",
          ("randomize_friction",), ("friction_range",), _floor),
    Group("restitution", ("randomize_restitution",), ("restitution_range",), None,
          "the soak's floor has no restitution to draw" + _WRITE),
    Group("base mass", ("randomize_base_mass",), ("added_mass_range", "added_base_mass_range"),
          _base_mass),
    Group("link mass", ("randomize_link_mass",),
          ("link_mass_range", "multiplied_link_mass_range", "link_mass_multi_range"),
          _factor("mass")),
    Group("centre of mass", ("randomize_base_com", "randomize_com"),
          ("added_com_range", "added_base_com_range", "com_displacement_range", "rand_com_vec"),
          _com),
    Group("motor strength", ("randomize_motor", "randomize_motor_strength", "randomize_torque",
                             "randomize_motor_torque"),
          ("motor_strength_range", "torque_multi_range", "randomize_motor_torque_range"),
          _factor("actuator_strength")),
    Group("kp", ("randomize_gains", "randomize_pd_gains", "randomize_Kp", "randomize_kp"),
          ("stiffness_multi_range", "stiffness_multiplier_range", "randomize_Kp_range",
           "kp_range"), _factor("kp")),
    Group("kd", ("randomize_gains", "randomize_pd_gains", "randomize_Kd", "randomize_kd"),
          ("damping_multi_range", "damping_multiplier_range", "randomize_Kd_range", "kd_range"),
          _factor("kd")),
    Group("joint friction", ("randomize_joint_friction",),
          ("joint_friction_range", "joint_friction_multi_range"), _factor("friction")),
    Group("joint friction per joint", ("randomize_joint_friction_each_joint",),
          ("joint_friction_multi_range_each_joint",), None,
          "a range per joint; the soak's joint friction has one range" + _WRITE),
    Group("joint damping", ("randomize_joint_damping",),
          ("joint_damping_range", "joint_damping_multi_range"), _factor("damping")),
    Group("armature", ("randomize_joint_armature", "randomize_armature"),
          ("joint_armature_multi_range", "armature_range", "joint_armature_range"),
          _armature),
    Group("armature per joint", ("randomize_joint_armature_each_joint",),
          ("joint_armature_multi_range_each_joint",), None,
          "a range per joint; the soak's armature has one range" + _WRITE),
    Group("Coulomb and viscous joint friction", ("randomize_coulomb_friction",),
          ("joint_coulomb_range", "joint_viscous_range"), None,
          "absolute friction torques; the soak scales the robot's own" + _WRITE),
    Group("inertia", ("randomize_inertia",), ("randomize_inertia_range", "inertia_range"), None,
          "inertia apart from mass; the soak scales both together" + _WRITE),
    Group("motor zero offset", ("randomize_motor_offset", "randomize_motor_zero_offset"),
          ("motor_offset_range", "motor_zero_offset_range"), _motor_offset),
    Group("pushes", ("push_robots",), ("push_interval_s", "max_push_vel_xy", "max_push_ang_vel"),
          _pushes),
    Group("external forces", ("rand_force", "apply_forces", "randomize_external_force"),
          ("force_resampling_time_s", "max_force", "rand_force_curriculum_level", "force_range"),
          None, "a force held on the base for seconds; the soak's pushes are short" + _WRITE),
    Group("action delay and noise (humanoid-gym: a blend with the previous action and "
          "multiplicative noise)", (), ("action_delay", "action_noise"), None,
          "the soak's runtime sends the policy's action as it is" + _WRITE,
          fixed=("action_delay", "action_noise")),
    Group("action lag", ("randomize_action_lag_timesteps", "randomize_lag_timesteps", "add_lag",
                         "randomize_action_delay"),
          ("action_lag_timesteps", "action_lag_timesteps_range", "lag_timesteps_range",
           "randomize_action_lag_timesteps_perstep", "randomize_lag_timesteps_perstep",
           "action_buf_len"),
          None, _LATENCY + "the readings, not the commands" + _WRITE,
          fixed=("action_lag_timesteps",)),
    Group("observation lag", ("randomize_motor_lag_timesteps", "randomize_imu_lag_timesteps",
                              "add_obs_lag", "randomize_obs_motor_lag_timesteps",
                              "randomize_obs_imu_lag_timesteps",
                              "randomize_obs_actions_lag_timesteps"),
          ("motor_lag_timesteps", "motor_lag_timesteps_range", "imu_lag_timesteps",
           "imu_lag_timesteps_range", "randomize_motor_lag_timesteps_perstep",
           "randomize_imu_lag_timesteps_perstep", "obs_motor_lag_timesteps_range",
           "obs_imu_lag_timesteps_range", "obs_actions_lag_timesteps_range",
           "randomize_obs_motor_lag_timesteps_perstep", "randomize_obs_imu_lag_timesteps_perstep",
           "randomize_obs_actions_lag_timesteps_perstep"),
          None, _LATENCY + "the readings as a whole" + _WRITE,
          fixed=("motor_lag_timesteps", "imu_lag_timesteps")),
)  # fmt: skip


def domain_lines(c: Context, root3: float) -> list[str]:
    """The ranges file's lines of a config read into ``c`` (its groups applied)."""
    cfg = c.cfg
    terrain = float(cfg["terrain"]["static_friction"])
    lines = [
        f"# training domain of {cfg['source']}",
        "# (read by sim2real.eval.world.legged_gym_domain)",
        f"# terrain: {cfg['terrain'].get('mesh_type')}, static friction {terrain:g}",
        *(f"# {note}" for note in c.notes),
    ]
    fixed = f"{(1 + terrain) / 2:.6g}"  # not randomized: the shapes' 1 with the terrain's
    lines.append(f"floor_friction = {c.top.get('floor_friction', f'[{fixed}, {fixed}]')}")
    if "added_base_mass" in c.top:
        lines.append(f"added_base_mass = {c.top['added_base_mass']}")
    dynamics = {"link_length": "0.0", "mass": "0.0", "friction": "0.0", "damping": "0.0",
                "actuator_strength": "0.0", **c.dynamics}  # fmt: skip
    lines += ["", "[dynamics]", *(f"{k} = {v}" for k, v in dynamics.items())]
    noise = cfg["noise"]
    level = float(noise.get("noise_level", 1.0)) if noise.get("add_noise") else 0.0
    scales = noise["noise_scales"]
    apart = [k for k, v in scales.items() if k not in NOISE_READ and level * float(v)]
    if apart:  # after the other comment lines: the file's first line names its source
        lines.insert(3, f"# noise_scales {', '.join(apart)}: not drawn ({NOISE_APART})")
    lines += [
        "",
        "[sensors]",
        f"noise_sigma = [0.0, {level * float(scales['dof_pos']) / root3:.6g}]",
        "latency_ticks = [0, 0]",
        *(f"{k} = {v}" for k, v in c.sensors.items()),
        "",
        "[imu]",
        f"gyro_noise_sigma = [0.0, {level * float(scales['ang_vel']) / root3:.6g}]",
        f"accel_noise_sigma = [0.0, {G * level * float(scales.get('gravity', 0.0)) / root3:.6g}]",
        "bias_scale = [0.0, 0.0]",
        "latency_ticks = [0, 0]",
    ]
    if c.pushes:
        lines += ["", "[pushes]", *c.pushes]
    ranges = cfg["commands"]["ranges"]
    pick = {"vx": "lin_vel_x", "vy": "lin_vel_y", "yaw_rate": "ang_vel_yaw"}
    lines += ["", "[commands]"]
    for ours, theirs in pick.items():
        lo, hi = (float(v) for v in ranges[theirs])
        lines.append(f"{ours} = [{lo:.6g}, {hi:.6g}]")
    # a new command every resampling_time s; legged_gym has no share of standing commands (it
    # zeroes the x and y of a command under 0.2 m/s, keeping its yaw): zero_fraction stays ours
    lines.append(f"period = {float(cfg['commands']['resampling_time']):.6g}")
    return lines + (terrain_lines(cfg["terrain"]) if cfg.get("terrain_written") else [])


#: legged_gym ``terrain`` keys a ranges file's ``[terrain]`` takes as they are
#: (:class:`sim2real.eval.world.terrain.TerrainRanges`).
TERRAIN_KEYS = ("mesh_type", "terrain_proportions", "num_rows", "num_cols", "curriculum",
                "horizontal_scale", "vertical_scale", "terrain_length", "terrain_width",
                "slope_treshold")  # fmt: skip


def terrain_table(terrain: dict) -> dict | None:
    """The ``[terrain]`` table (``{key: value}``) of legged_gym's ``terrain`` class ``terrain``,
    every level drawn; None for a flat one (``plane``, ``none``): the soak's plane."""
    if terrain.get("mesh_type") in ("plane", "none"):
        return None
    out = {k: terrain[k] for k in TERRAIN_KEYS if k in terrain}
    out["levels"] = [0, int(terrain.get("num_rows", 10)) - 1]
    return out


def terrain_lines(terrain: dict) -> list[str]:
    """:func:`terrain_table` as TOML lines (none for a flat terrain)."""
    table = terrain_table(terrain)
    if table is None:
        return []

    def toml(v) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return f'"{v}"'
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(toml(x) for x in v) + "]"
        return f"{v:.6g}" if isinstance(v, float) else str(v)

    return ["", "[terrain]", *(f"{k} = {toml(v)}" for k, v in table.items())]
