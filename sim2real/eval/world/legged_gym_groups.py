"""What each ``domain_rand`` key of a legged_gym config becomes in a ranges file (:data:`GROUPS`);
read by :func:`sim2real.eval.world.legged_gym_domain.legged_gym_domain`, whose text
:mod:`sim2real.eval.world.legged_gym_lines` writes.

A :class:`Group` is one randomization: its switches (``randomize_X``; any on turns it on), the
keys that give its values, and what it becomes with where it came from (``Context.prov``), or
why the soak cannot run it (then a group that is on is named in one line, ``Context.apart``:
"not modelled"; a group that is off in one line too, ``Context.off``). Ranges of factors
``[a, b]`` become the half-range ``max(1 - a, b - 1)`` of a factor drawn from
``U(1 - r, 1 + r)`` (the ranges file's ``[dynamics]``); an asymmetric range is widened to the
symmetric one that holds it, and the file says so in a comment.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

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
    """One config being read: its values (``cfg`` of ``read_legged_gym_config``: each a
    :class:`~sim2real.eval.world.legged_gym_tree.Setting`) and what the groups make of them
    (``top``, ``dynamics``, ``sensors``, ``pushes``, ``notes``), with the account of each
    (``prov``: ``key = value <- where it came from``; ``apart``: what the soak does not model,
    one line each; ``off``: randomizations the training had off)."""

    def __init__(self, path: Path, cfg: dict):
        self.path, self.cfg, self.rand = path, cfg, cfg["domain_rand"]
        self.top: dict[str, str] = {}
        self.dynamics: dict[str, str] = {}
        self.sensors: dict[str, str] = {}
        self.pushes: list[str] = []
        self.notes: list[str] = []
        self.prov: list[str] = []
        self.apart: list[str] = []
        self.off: list[str] = []

    def value(self, key: str):
        return self.rand[key].value if key in self.rand else None

    def where(self, key: str) -> str:
        """``key``'s place in the config (``domain_rand.friction_range``)."""
        return self.rand[key].path

    def source(self, key: str) -> str:
        """``key``'s place, value, file and line: ``domain_rand.x [a, b] (file.py:12)``."""
        s = self.rand[key]
        return f"{s.path} {s.value!r} ({s.where})"

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
        """Of ``keys`` the config has, the one written nearest the task's class (a fork's
        ``added_base_mass_range`` over its base's ``added_mass_range``; the first of ``keys``
        on a tie); None: none."""
        present = [k for k in keys if k in self.rand]
        return min(present, key=lambda k: self.rand[k].depth) if present else None

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
        stems = [k[len("randomize_") :].lower() for k, s in self.rand.items()
                 if k.startswith("randomize_") and not s.value]  # fmt: skip
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
        """Apply the group to ``c`` when it is on (its keys named in ``c.off`` when it is off,
        in ``c.apart`` when the soak cannot run it).

        Raises:
            ValueError: a value is malformed (named).
        """
        keys = [k for k in (*self.switches, *self.values) if k in c.rand]
        if not self.on(c):
            if keys:
                c.off.append(f"{', '.join(c.source(k) for k in keys)}: {self.what}")
            return
        if self.read_into is None:
            c.apart.append(f"{', '.join(c.source(k) for k in keys)}: {self.what}: {self.why}")
            return
        self.read_into(c, self)


def _floor(c: Context, g: Group) -> None:
    key = c.first(g.values)
    if key is None:
        raise ValueError(f"{c.where(g.switches[0])}: no friction range ({', '.join(g.values)})")
    lo, hi = c.pair(key)
    static = c.cfg["terrain"]["static_friction"]
    t = float(static.value)
    c.top["floor_friction"] = f"[{(lo + t) / 2:.6g}, {(hi + t) / 2:.6g}]"
    c.prov.append(
        f"floor_friction = {c.top['floor_friction']} <- {c.source(key)} and {static.path} "
        f"{t:g} ({static.where}), averaged (PhysX's default friction combine)"
    )


def _base_mass(c: Context, g: Group) -> None:
    key = c.first(g.values) or g.values[0]
    lo, hi = c.pair(key)
    c.top["added_base_mass"] = f"[{lo:.6g}, {hi:.6g}]"
    c.prov.append(
        f"added_base_mass = {c.top['added_base_mass']} <- {c.source(key)}, kg on the robot's "
        "base body (added_mass_body left to the soak: the robot's own base)"
    )


def _factor(field: str) -> Callable[[Context, Group], None]:
    def read_into(c: Context, g: Group) -> None:
        key = c.first(g.values)
        if key is None:
            raise ValueError(f"{c.where(g.switches[0])}: no range ({', '.join(g.values)})")
        c.dynamics[field] = f"{c.half_range(key, field):.6g}"
        c.prov.append(f"dynamics.{field} = {c.dynamics[field]} <- {c.source(key)}")

    return read_into


#: Armature ranges in kg m^2, drawn as the armature itself (engineai's and humanoid forks'
#: ``dof_props["armature"] = joint_armatures``), not as a factor of the robot's.
ABSOLUTE_ARMATURE = ("joint_armature_range",)


def _armature(c: Context, g: Group) -> None:
    key = c.first(g.values)
    if key in ABSOLUTE_ARMATURE:
        c.apart.append(
            f"{c.source(key)}: armature values in kg m^2 that replace the robot's; the soak's "
            "[dynamics] armature scales the robot's own armature by a factor"
        )
        return
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
    c.prov.append(
        f"dynamics.com_offset = {c.dynamics['com_offset']} <- {c.source(key)}, m per axis, "
        "the robot's base body (body left to the soak)"
    )


def _motor_offset(c: Context, g: Group) -> None:
    key = c.first(g.values) or g.values[0]
    lo, hi = c.pair(key)
    c.sensors["encoder_bias"] = f"[{lo:.6g}, {hi:.6g}]"
    c.prov.append(f"sensors.encoder_bias = {c.sensors['encoder_bias']} <- {c.source(key)}")


def _pushes(c: Context, g: Group) -> None:
    if c.value("max_push_ang_vel"):
        c.apart.append(
            f"{c.source('max_push_ang_vel')}: a push that sets the base's angular velocity "
            "(humanoid-gym): the soak's legged_gym pushes set the horizontal velocity only"
        )
    for key in ("push_interval_s", "max_push_vel_xy"):
        if key not in c.rand:
            raise ValueError(f"{c.where('push_robots')}: pushes on and no {key}")
    interval = float(c.value("push_interval_s"))
    vmax = float(c.value("max_push_vel_xy"))
    c.pushes = [f"interval = {interval:.6g}", 'mode = "set"', f"max_velocity = {vmax:.6g}"]
    c.prov.append(
        f"pushes.interval = {interval:.6g}, mode = set, max_velocity = {vmax:.6g} <- "
        f"{c.source('push_interval_s')}, {c.source('max_push_vel_xy')} (the base's x and y "
        "velocity set to U(-max, max) m/s); apply = force, the soak's own: legged_gym writes "
        "the root velocity between physics steps (legged_robot.py _push_robots), which no IMU "
        'feels; a ranges file with apply = "velocity_hidden_from_imu" runs it as trained'
    )


_LATENCY = "a latency in physics steps; the soak's latencies are whole control ticks and act on "
#: Every randomization of legged_gym's ``domain_rand`` and its forks' (unitree_rl_gym,
#: humanoid-gym, engineai's ``domain_rands``), in the order the ranges file is written.
GROUPS: tuple[Group, ...] = (
    Group("floor friction ((range + terrain.static_friction) / 2: PhysX averages the two)",
          ("randomize_friction",), ("friction_range",), _floor),
    Group("restitution", ("randomize_restitution",), ("restitution_range",), None,
          "the soak's floor has no restitution to draw"),
    Group("base mass (HIMLoco's payload)", ("randomize_base_mass", "randomize_payload_mass"),
          ("added_mass_range", "added_base_mass_range", "payload_mass_range"), _base_mass),
    Group("link mass", ("randomize_link_mass",),
          ("link_mass_range", "multiplied_link_mass_range", "link_mass_multi_range"),
          _factor("mass")),
    Group("centre of mass", ("randomize_base_com", "randomize_com", "randomize_com_displacement"),
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
          "a range per joint; the soak's joint friction has one range"),
    Group("joint damping", ("randomize_joint_damping",),
          ("joint_damping_range", "joint_damping_multi_range"), _factor("damping")),
    Group("armature", ("randomize_joint_armature", "randomize_armature"),
          ("joint_armature_multi_range", "armature_range", "joint_armature_range"),
          _armature),
    Group("armature per joint", ("randomize_joint_armature_each_joint",),
          ("joint_armature_multi_range_each_joint",), None,
          "a range per joint; the soak's armature has one range"),
    Group("Coulomb and viscous joint friction", ("randomize_coulomb_friction",),
          ("joint_coulomb_range", "joint_viscous_range"), None,
          "absolute friction torques; the soak scales the robot's own"),
    Group("inertia", ("randomize_inertia",), ("randomize_inertia_range", "inertia_range"), None,
          "inertia apart from mass; the soak scales both together"),
    Group("motor zero offset", ("randomize_motor_offset", "randomize_motor_zero_offset"),
          ("motor_offset_range", "motor_zero_offset_range"), _motor_offset),
    Group("pushes", ("push_robots",), ("push_interval_s", "max_push_vel_xy", "max_push_ang_vel"),
          _pushes),
    Group("external forces", ("rand_force", "apply_forces", "randomize_external_force"),
          ("force_resampling_time_s", "max_force", "rand_force_curriculum_level", "force_range"),
          None, "a force held on the base for seconds; the soak's pushes are short"),
    Group("action delay and noise (humanoid-gym: a blend with the previous action and "
          "multiplicative noise)", (), ("action_delay", "action_noise"), None,
          "the soak's runtime sends the policy's action as it is",
          fixed=("action_delay", "action_noise")),
    Group("action lag", ("randomize_action_lag_timesteps", "randomize_lag_timesteps", "add_lag",
                         "randomize_action_delay"),
          ("action_lag_timesteps", "action_lag_timesteps_range", "lag_timesteps_range",
           "randomize_action_lag_timesteps_perstep", "randomize_lag_timesteps_perstep",
           "action_buf_len"),
          None, _LATENCY + "the readings, not the commands",
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
          None, _LATENCY + "the readings as a whole",
          fixed=("motor_lag_timesteps", "imu_lag_timesteps")),
    Group("disturbance (HIMLoco: a force of U(range) N per axis on the base, in its frame, for "
          "one physics step every disturbance_interval control ticks; legged_robot.py "
          "_disturbance_robots)", ("disturbance",), ("disturbance_range", "disturbance_interval"),
          None, "the soak's pushes are one kind a session, the config's push_robots"),
    Group("action delay (HIMLoco: each tick the new action reaches the motors after U{0, "
          "decimation - 1} physics steps, the previous one held before; legged_robot.py step)",
          ("delay",), (), None, "the soak's runtime sends the action at once"),
    Group("initial joint positions (the default pose times a factor at each reset)",
          ("randomize_initial_joint_pos",), ("initial_joint_pos_range",), None,
          "the soak's sessions start from the robot's standing pose"),
)  # fmt: skip
