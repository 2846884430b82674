"""An Isaac Lab or mjlab run's ``params/env.yaml`` is its policy's training domain: every event read
into the soak's ranges or refused by name.

The files are written here the way each stack dumps its configuration (read, not copied): Isaac
Lab's ``dump_yaml`` of ``class_to_dict`` (functions as ``"module:name"``, tuples tagged
``!!python/tuple``) with unitree_rl_lab's G1 velocity events (``tasks/locomotion/robots/g1/29dof/
velocity_env_cfg.py``: ``randomize_rigid_body_material``, ``randomize_rigid_body_mass`` on the
torso, a zero ``apply_external_force_torque``, the resets, ``push_by_setting_velocity`` every 5 s)
and Isaac Lab's terrain material (``friction_combine_mode`` multiply); mjlab's ``yaml.dump`` of its
dataclasses (``!!python/object`` and ``!!python/name`` tags) with unitree_rl_mjlab's velocity
events (``randomize_field`` of ``geom_friction`` and ``body_ipos``, ``randomize_encoder_bias``, a
six-axis push).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pytest
import yaml

from sim2real.eval.world.domain import DomainError, domain_toml, training_domain
from sim2real.eval.world.ranges_file import RangesError, load_ranges_text
from sim2real.robots import load_robot
from tests import foreign_stacks as fs


def isaaclab_events(body: str = "pelvis") -> dict:
    def term(func: str, mode: str, params: dict, **extra) -> dict:
        return {"func": f"isaaclab.envs.mdp.events:{func}", "mode": mode, "params": params,
                "interval_range_s": None, "is_global_time": False, **extra}  # fmt: skip

    robot = {"name": "robot", "body_names": ".*", "joint_names": None}
    return {
        "physics_material": term("randomize_rigid_body_material", "startup", {
            "asset_cfg": robot, "static_friction_range": (0.3, 1.0),
            "dynamic_friction_range": (0.3, 1.0), "restitution_range": (0.0, 0.0),
            "num_buckets": 64}),
        "add_base_mass": term("randomize_rigid_body_mass", "startup", {
            "asset_cfg": {**robot, "body_names": body}, "mass_distribution_params": (-1.0, 3.0),
            "operation": "add"}),
        "base_external_force_torque": term("apply_external_force_torque", "reset", {
            "asset_cfg": {**robot, "body_names": body}, "force_range": (0.0, 0.0),
            "torque_range": (-0.0, 0.0)}),
        "reset_base": term("reset_root_state_uniform", "reset", {
            "pose_range": {"x": (-0.5, 0.5), "yaw": (-3.14, 3.14)}, "velocity_range": {}}),
        "reset_robot_joints": term("reset_joints_by_scale", "reset", {
            "position_range": (1.0, 1.0), "velocity_range": (-1.0, 1.0)}),
        "push_robot": term("push_by_setting_velocity", "interval", {
            "velocity_range": {"x": (-0.5, 0.5), "y": (-0.5, 0.5)}},
            interval_range_s=(5.0, 5.0)),
    }  # fmt: skip


def isaaclab_env_yaml(tmp_path, events: dict):
    env = fs.isaaclab_env()
    env["events"] = events
    env["scene"]["terrain"] = {
        "physics_material": {"friction_combine_mode": "multiply", "static_friction": 1.0}
    }
    # the policy group's noise as foreign_stacks writes it (Isaac Lab's Go2 task's): base_ang_vel
    # +-0.2, projected_gravity +-0.05, joint_pos_rel +-0.01, joint_vel_rel +-1.5
    env["commands"]["base_velocity"]["ranges"].update(
        lin_vel_x=(-0.1, 0.1), lin_vel_y=(-0.1, 0.1), ang_vel_z=(-0.1, 0.1)
    )
    return fs.write_isaaclab_run(tmp_path / "run", env, 48, 12)


def test_an_isaac_lab_env_yaml_is_read_event_by_event(tmp_path):
    """unitree_rl_lab's G1 events: the robot's friction 0.3-1.0 times the terrain's 1.0 (multiply),
    a payload of -1..3 kg on the body the event names, pushes adding U(+-0.5) m/s every 5 s, the
    policy group's noise as sigmas of uniform noise, the command's ranges; soak-test finds the
    run folder's env.yaml beside the policy."""
    policy = isaaclab_env_yaml(tmp_path, isaaclab_events("left_knee_link"))
    text = training_domain(policy)
    assert text == domain_toml(tmp_path / "run" / "params" / "env.yaml")
    ranges = load_ranges_text(text, "env.yaml", load_robot("h1"))
    assert ranges.floor_friction == (0.3, 1.0)
    assert (ranges.added_base_mass, ranges.added_mass_body) == ((-1.0, 3.0), "left_knee_link")
    p = ranges.pushes
    assert (p.interval, p.mode, p.x, p.y, p.z) == (
        (5.0, 5.0),
        "add",
        (-0.5, 0.5),
        (-0.5, 0.5),
        None,
    )
    root12 = math.sqrt(12.0)
    assert ranges.imu.gyro_noise_sigma[1] == pytest.approx(0.4 / root12, rel=1e-5)
    assert ranges.imu.accel_noise_sigma[1] == pytest.approx(9.80665 * 0.1 / root12, rel=1e-5)
    assert ranges.sensors.noise_sigma[1] == pytest.approx(0.02 / root12, rel=1e-5)
    assert ranges.commands.vx == (-0.1, 0.1) and ranges.dynamics.mass == 0.0
    with pytest.raises(RangesError, match="added_mass_body: 'torso_link' is no body of robot h1"):
        load_ranges_text(
            domain_toml(
                isaaclab_env_yaml(tmp_path / "g1", isaaclab_events("torso_link")).parent.parent
                / "params"
                / "env.yaml"
            ),
            "env.yaml",
            load_robot("h1"),
        )


def test_isaac_lab_events_the_soak_cannot_run_are_refused_by_name(tmp_path):
    events = isaaclab_events()
    events["physics_material"]["params"]["restitution_range"] = (0.0, 0.5)
    events["base_external_force_torque"]["params"]["force_range"] = (-10.0, 10.0)
    events["scale_gravity"] = {"func": "isaaclab.envs.mdp.events:randomize_physics_scene_gravity",
                               "mode": "interval", "params": {}}  # fmt: skip
    isaaclab_env_yaml(tmp_path, events)
    with pytest.raises(DomainError) as refused:
        domain_toml(tmp_path / "run" / "params" / "env.yaml")
    message = str(refused.value)
    assert "events.physics_material.params.restitution_range [0.0, 0.5]" in message
    assert "events.base_external_force_torque: an external force" in message
    assert "events.scale_gravity (randomize_physics_scene_gravity): not an event" in message


# ------------------------------------------------------------------ mjlab's dataclass dump
def push_by_setting_velocity():
    """Stands for mjlab's event function (only its name is dumped)."""


def randomize_field():
    """Stands for mjlab's event function."""


def randomize_encoder_bias():
    """Stands for mjlab's event function."""


@dataclass
class EventTermCfg:
    func: object
    mode: str
    params: dict = field(default_factory=dict)
    interval_range_s: tuple | None = None


@dataclass
class EnvCfg:
    events: dict


def test_an_mjlab_env_yaml_dumped_with_python_tags_is_read(tmp_path):
    """unitree_rl_mjlab's velocity events, dumped as mjlab dumps its config: the feet's friction
    0.3-1.2 the floor's, a centre-of-mass shift of +-0.05 m on the body named, the encoders'
    bias, and a push adding a six-axis twist after 1-3 s."""
    axes = {"x": (-0.5, 0.5), "y": (-0.5, 0.5), "z": (-0.25, 0.25), "roll": (-0.52, 0.52),
            "pitch": (-0.52, 0.52), "yaw": (-0.78, 0.78)}  # fmt: skip
    cfg = EnvCfg(events={
        "push_robot": EventTermCfg(push_by_setting_velocity, "interval", {"velocity_range": axes},
                                   (1.0, 3.0)),
        "body_friction": EventTermCfg(randomize_field, "startup", {
            "asset_cfg": {"name": "robot", "geom_names": ".*_collision"}, "operation": "abs",
            "field": "geom_friction", "ranges": (0.3, 1.2)}),
        "encoder_bias": EventTermCfg(randomize_encoder_bias, "startup", {
            "bias_range": (-0.015, 0.015)}),
        "base_com": EventTermCfg(randomize_field, "startup", {
            "asset_cfg": {"name": "robot", "body_names": ("pelvis",)}, "operation": "add",
            "field": "body_ipos", "ranges": {0: (-0.05, 0.05), 1: (-0.05, 0.05),
                                             2: (-0.05, 0.05)}}),
        "off": None,
    })  # fmt: skip
    path = tmp_path / "env.yaml"
    path.write_text(yaml.dump(cfg, sort_keys=False))
    assert "!!python/object" in path.read_text() and "!!python/name" in path.read_text()
    ranges = load_ranges_text(domain_toml(path), "env.yaml", load_robot("h1"))
    assert ranges.floor_friction == (0.3, 1.2)
    assert ranges.sensors.encoder_bias == (-0.015, 0.015)
    com = ranges.com_offset
    assert (com.body, com.x, com.y, com.z) == ("pelvis", *[(-0.05, 0.05)] * 3)
    p = ranges.pushes
    assert (p.interval, p.mode, p.z, p.yaw) == ((1.0, 3.0), "add", (-0.25, 0.25), (-0.78, 0.78))
    assert np.allclose(p.ranges()[:, 1], [0.5, 0.5, 0.25, 0.52, 0.52, 0.78])
