"""Every randomization a legged_gym-family config writes is read into the soak's ranges or refused
by name; the soak's floor friction reaches feet that touch the floor through contact pairs; a
policy's recorded command ranges drive the soak's commands also with ``--spec``; the report names
the joints that went past their hard limits.

The configs are written here in the stacks' own layouts (read, not copied): humanoid-gym's
``humanoid/envs/custom/humanoid_config.py`` (``domain_rand`` with ``action_delay``,
``action_noise``, ``max_push_ang_vel``; ``terrain.static_friction`` 0.6) and a legged_gym fork's
nested ``domain_rands`` (``rigid_body``, ``dof``, ... classes, as engineai's biped configs).
"""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest

from sim2real.eval.world.domain import DomainError, contract_commands, legged_gym_domain
from sim2real.eval.world.dynamics import DynamicsRanges, randomized_model, sample_dynamics
from sim2real.eval.world.floor import apply_floor_friction
from sim2real.eval.world.legged_gym_groups import GROUPS
from sim2real.eval.world.ranges_file import load_ranges_text
from sim2real.robots import load_robot
from tests.legged_gym_trees import UPSTREAM_BASE, write_base, write_task

HUMANOID_GYM = """
from humanoid.envs.base.legged_robot_config import LeggedRobotCfg, LeggedRobotCfgPPO

class XBotLCfg(LeggedRobotCfg):
    class env(LeggedRobotCfg.env):
        frame_stack = 15
        num_single_obs = 47
    class terrain(LeggedRobotCfg.terrain):
        mesh_type = 'plane'
        static_friction = 0.6
        dynamic_friction = 0.6
    class noise:
        add_noise = True
        noise_level = 0.6
        class noise_scales:
            dof_pos = 0.05
            dof_vel = 0.5
            ang_vel = 0.1
            lin_vel = 0.05
            quat = 0.03
            height_measurements = 0.1
    class domain_rand:
        randomize_friction = True
        friction_range = [0.1, 2.0]
        randomize_base_mass = True
        added_mass_range = [-5., 5.]
        push_robots = True
        push_interval_s = 4
        max_push_vel_xy = 0.2
        max_push_ang_vel = 0.4
        action_delay = 0.5
        action_noise = 0.02
    class commands(LeggedRobotCfg.commands):
        class ranges:
            lin_vel_x = [-0.3, 0.6]
            lin_vel_y = [-0.3, 0.3]
            ang_vel_yaw = [-0.3, 0.3]
            heading = [-3.14, 3.14]

class XBotLCfgPPO(LeggedRobotCfgPPO):
    seed = 5
"""

FORK = """
from legged_gym.envs.base.legged_robot_config import LeggedRobotCfg

class BipedCfg(LeggedRobotCfg):
    class terrain(LeggedRobotCfg.terrain):
        static_friction = 0.6
    class domain_rands(LeggedRobotCfg.domain_rands):
        class rigid_shape:
            randomize_friction = True
            friction_range = [0.2, 1.3]
            randomize_restitution = False
            restitution_range = [0.0, 0.4]
        class rigid_body:
            randomize_base_mass = True
            added_mass_range = [-4.0, 4.0]
            randomize_com = True
            com_displacement_range = [-0.06, 0.06]
            randomize_link_mass = True
            link_mass_multi_range = [0.8, 1.2]
        class dof:
            randomize_gains = True
            stiffness_multi_range = [0.8, 1.2]
            damping_multi_range = [0.9, 1.1]
            randomize_torque = True
            torque_multi_range = [0.85, 1.15]
            randomize_motor_offset = True
            motor_offset_range = [-0.035, 0.035]
            randomize_joint_friction = True
            randomize_joint_friction_each_joint = False
            joint_friction_multi_range = [0.5, 1.5]
            joint_friction_multi_range_each_joint = {"hip": [0.01, 1.15], "knee": [0.5, 1.3]}
            randomize_joint_armature = True
            joint_armature_multi_range = [0.8, 1.3]
        class disturbance:
            push_robots = True
            push_interval_s = 8
            max_push_vel_xy = 0.4
    class commands(LeggedRobotCfg.commands):
        class ranges:
            lin_vel_x = [-1.5, 1.5]
            lin_vel_y = [-0.5, 0.5]
            ang_vel_yaw = [-1.5, 1.5]
            heading = [-3.14, 3.14]
"""


def write(tmp_path, text: str, name: str = "config.py"):
    """The task ``text`` in a legged_gym tree (the package its import names: ``humanoid`` for
    humanoid-gym's; a fork's ``domain_rands`` over a base that writes ``domain_rands``)."""
    package = "humanoid" if "from humanoid." in text else "legged_gym"
    if "domain_rands(" in text:
        write_base(tmp_path, package, UPSTREAM_BASE.replace("domain_rand:", "domain_rands:"))
        return write_task(tmp_path, text, name, package, base=False)
    return write_task(tmp_path, text, name, package)


def not_modelled(text: str) -> list[str]:
    """The stored domain's lines naming what the soak does not model."""
    return [line for line in text.splitlines() if line.startswith("# not modelled: ")]


def test_humanoid_gyms_action_delay_noise_and_angular_pushes_are_named_as_not_modelled(tmp_path):
    """humanoid-gym's XBot-L: its action blending, action noise and angular pushes are not
    something the soak runs; the stored domain names each in one line (file and line) instead
    of dropping it, and runs the rest."""
    text = legged_gym_domain(write(tmp_path, HUMANOID_GYM))
    lines = not_modelled(text)
    blend = [line for line in lines if "domain_rand.action_delay 0.5" in line]
    assert len(blend) == 1 and "domain_rand.action_noise 0.02" in blend[0]
    assert "humanoid/envs/task/config.py:" in blend[0]
    assert any("domain_rand.max_push_ang_vel 0.4" in line for line in lines)
    ranges = load_ranges_text(text, "xbot", load_robot("h1"))
    assert ranges.pushes.max_velocity == 0.2 and ranges.added_base_mass == (-5.0, 5.0)


def test_a_forks_nested_domain_rands_are_read_key_by_key(tmp_path):
    """Base mass +-4 kg (not legged_gym's default +-1), link mass, centre of mass, motor strength,
    kp and kd, joint friction, armature, motor offset, the terrain's friction and the command
    ranges all reach the soak's ranges."""
    text = legged_gym_domain(write(tmp_path, FORK))
    ranges = load_ranges_text(text, "fork", load_robot("h1"))
    assert ranges.added_base_mass == (-4.0, 4.0)
    assert ranges.floor_friction == pytest.approx(((0.2 + 0.6) / 2, (1.3 + 0.6) / 2))
    d = ranges.dynamics
    assert (d.mass, d.kp, d.kd, d.friction) == pytest.approx((0.2, 0.2, 0.1, 0.5))
    assert (d.actuator_strength, d.armature) == pytest.approx((0.15, 0.3))
    assert "[0.8, 1.3]: armature +-0.3 (widened" in text
    com = ranges.com_offset
    assert (com.body, com.x, com.z) == ("", (-0.06, 0.06), (-0.06, 0.06))
    assert ranges.sensors.encoder_bias == (-0.035, 0.035)
    assert (ranges.pushes.interval, ranges.pushes.max_velocity) == (8.0, 0.4)
    c = ranges.commands  # the base's heading command: the yaw rate is not drawn
    assert (c.vx, c.vy, c.heading_command, c.heading) == (
        (-1.5, 1.5),
        (-0.5, 0.5),
        True,
        (-3.14, 3.14),
    )
    assert any("ang_vel_yaw [-1.5, 1.5]" in line for line in not_modelled(text))


def test_an_unknown_randomization_is_named_as_not_modelled_unless_its_switch_is_off(tmp_path):
    on = FORK.replace("class disturbance:", "class gravity:\n            randomize_gravity = True\n"
                      "            gravity_range = [-1.0, 1.0]\n        class disturbance:")  # fmt: skip
    lines = not_modelled(legged_gym_domain(write(tmp_path, on)))
    assert [line for line in lines if "gravity" in line] == [
        f"# not modelled: domain_rands.gravity.{key} ({where}): not a randomization this reader "
        "knows (legged_gym, HIMLoco, humanoid-gym and their forks' keys)"
        for key, where in (("randomize_gravity True", "legged_gym/envs/task/config.py:35"),
                           ("gravity_range [-1.0, 1.0]", "legged_gym/envs/task/config.py:36"))
    ]  # fmt: skip
    off = on.replace("randomize_gravity = True", "randomize_gravity = False")
    text = legged_gym_domain(write(tmp_path, off, "off.py"))
    assert not [line for line in not_modelled(text) if "gravity" in line]
    assert "# off: domain_rands.gravity.randomize_gravity False" in text
    lag = FORK.replace("class disturbance:", "class obs_lag:\n            "
                       "randomize_motor_lag_timesteps = True\n            motor_lag_timesteps_range"
                       " = [5, 15]\n        class disturbance:")  # fmt: skip
    lines = not_modelled(legged_gym_domain(write(tmp_path, lag, "lag.py")))
    assert any("obs_lag.motor_lag_timesteps_range [5, 15]" in line and "observation lag" in line
               for line in lines)  # fmt: skip


def test_kp_kd_and_armature_factors_reach_the_plant_and_leave_other_draws_alone():
    h1 = load_robot("h1")
    plain = sample_dynamics(h1, np.random.default_rng(4), DynamicsRanges())
    ranges = DynamicsRanges(kp=0.2, kd=0.3, armature=0.5)
    draw = sample_dynamics(h1, np.random.default_rng(4), ranges)
    assert draw.mass == plain.mass and draw.actuator_strength == plain.actuator_strength
    assert "kp" not in plain.to_dict() and type(plain).from_dict(plain.to_dict()) == plain
    nominal = h1.mjspec("position").compile()
    model = randomized_model(h1, "position", draw)
    for a in range(model.nu):
        j = h1.joint_names.index(model.joint(model.actuator_trnid[a, 0]).name)
        k = draw.actuator_strength[j]
        assert model.actuator_gainprm[a, 0] == pytest.approx(
            nominal.actuator_gainprm[a, 0] * k * draw.kp[j]
        )
        assert model.actuator_biasprm[a, 2] == pytest.approx(
            nominal.actuator_biasprm[a, 2] * k * draw.kd[j]
        )
        dof = model.jnt_dofadr[model.actuator_trnid[a, 0]]
        assert model.dof_armature[dof] == pytest.approx(
            nominal.dof_armature[dof] * draw.armature[j]
        )


PAIRED = """
<mujoco>
  <option timestep="0.002"/>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1" contype="1" conaffinity="1"/>
    <body name="foot" pos="0 0 0.05">
      <freejoint/>
      <geom name="sole" type="box" size="0.1 0.1 0.05" mass="2" contype="2" conaffinity="2"/>
    </body>
  </worldbody>
  <contact>
    <pair geom1="floor" geom2="sole" friction="1 1 0.005 0.0001 0.0001"/>
  </contact>
</mujoco>
"""


def slide(friction: float) -> float:
    """How far the paired box slides in 0.5 s from 2 m/s on the floor of ``friction``."""
    model = mujoco.MjModel.from_xml_string(PAIRED)
    apply_floor_friction(model, friction)
    data = mujoco.MjData(model)
    data.qvel[0] = 2.0
    mujoco.mj_step(model, data, nstep=250)
    return float(data.qpos[0])


def test_the_floor_friction_draw_reaches_feet_that_touch_through_contact_pairs():
    """A foot whose geom collides with nothing (other contype bits) touches the floor through a
    <pair> with its own friction: the draw sets the pair's sliding friction, and a slippery
    draw slides further."""
    from sim2real.eval.world.floor import floor_pairs

    model = mujoco.MjModel.from_xml_string(PAIRED)
    assert list(floor_pairs(model)) == [0]
    apply_floor_friction(model, 0.2)
    assert model.pair_friction[0].tolist() == pytest.approx([0.2, 0.2, 0.005, 0.0001, 0.0001])
    assert slide(0.1) > 1.5 * slide(0.8)


def test_soak_with_spec_takes_the_command_ranges_the_file_records(tmp_path):
    """A holosoma-style file whose contract does not map here (no experiment_config) still
    records its command_ranges: read as soak-test --spec reads it, they are the soak's
    commands."""
    import onnx
    from onnx import TensorProto, helper

    graph = helper.make_graph(
        [helper.make_node("Identity", ["actor_obs"], ["action"])],
        "g",
        [helper.make_tensor_value_info("actor_obs", TensorProto.FLOAT, [1, 12])],
        [helper.make_tensor_value_info("action", TensorProto.FLOAT, [1, 12])],
    )
    model = helper.make_model(graph)
    ranges = {"lin_vel_x": [-0.5, 1.0], "lin_vel_y": [-0.3, 0.3], "ang_vel_yaw": [-0.8, 0.8]}
    for key, value in {
        "dof_names": json.dumps([f"j{i}" for i in range(12)]),
        "kp": json.dumps([20.0] * 12),
        "command_ranges": json.dumps(ranges),
    }.items():
        prop = model.metadata_props.add()
        prop.key, prop.value = key, value
    path = tmp_path / "holosoma.onnx"
    onnx.save(model, str(path))
    commands, source = contract_commands(path, strict=False)
    assert (commands.vx, commands.vy, commands.yaw_rate) == ((-0.5, 1.0), (-0.3, 0.3), (-0.8, 0.8))
    # read as holosoma's partial contract (no experiment_config), or as the metadata key
    assert "holosoma" in source or "command_ranges" in source


def holosoma_randomization(delay_enabled: bool) -> dict:
    """holosoma's G1 locomotion preset (config_values/loco/g1/randomization.py) as
    ``to_serializable_dict`` writes it."""
    module = "holosoma.managers.randomization.terms.locomotion"

    def term(func, **params):
        return {"func": f"{module}:{func}", "params": params}

    return {
        "setup_terms": {
            "push_randomizer_state": term("PushRandomizerState", push_interval_s=[5, 10],
                                          max_push_vel=[1.0, 1.0], enabled=True),
            "setup_action_delay_buffers": term("setup_action_delay_buffers",
                                               ctrl_delay_step_range=[0, 1], enabled=delay_enabled),
            "setup_torque_rfi": term("setup_torque_rfi", enabled=False, rfi_lim=0.1),
            "setup_dof_pos_bias": term("setup_dof_pos_bias", dof_pos_bias_range=[-0.01, 0.01],
                                       enabled=False),
            "actuator_randomizer_state": term("ActuatorRandomizerState", kp_range=[0.9, 1.1],
                                              kd_range=[0.9, 1.1], rfi_lim_range=[0.5, 1.5],
                                              enable_pd_gain=True, enable_rfi_lim=False),
            "mass_randomizer": term("randomize_mass_startup", enable_link_mass=True,
                                    link_mass_range=[0.9, 1.2], enable_base_mass=True,
                                    added_mass_range=[-1.0, 3.0]),
            "randomize_friction_startup": term("randomize_friction_startup",
                                               friction_range=[0.5, 1.25], enabled=True),
            "randomize_base_com_startup": term("randomize_base_com_startup", enabled=True,
                                               base_com_range={"x": [-0.05, 0.05],
                                                               "y": [-0.05, 0.05],
                                                               "z": [-0.05, 0.05]}),
        },
        "reset_terms": {
            "push_randomizer_state": {"func": f"{module}:PushRandomizerState", "params": {}},
            "randomize_push_schedule": {"func": f"{module}:randomize_push_schedule"},
            "randomize_dof_state": term("randomize_dof_state", joint_pos_scale_range=[0.5, 1.5]),
        },
        "step_terms": {"apply_pushes": {"func": f"{module}:apply_pushes", "params": {}}},
    }  # fmt: skip


def test_holosomas_randomization_is_read_term_by_term(tmp_path, go2):
    """holosoma's G1 preset on a go2-shaped export: its action delay is refused by name; without
    it, pushes, link and base mass, the feet's friction (averaged with the terrain's 1), the
    base's centre of mass, kp and kd, the actor's dof_pos noise and the command ranges all
    reach the soak's ranges (soak-test reads them from the file)."""
    from sim2real.eval.world.domain import training_domain
    from tests import foreign_stacks as fs

    experiment = fs.holosoma_experiment(fs.HOLOSOMA_ORDER)
    experiment["randomization"] = holosoma_randomization(delay_enabled=True)
    refused = fs.write_holosoma(tmp_path / "delay.onnx", experiment, 45)
    with pytest.raises(DomainError, match=r"setup_action_delay_buffers.ctrl_delay_step_range "
                                          r"\[0, 1\]: an action delay"):  # fmt: skip
        training_domain(refused)
    experiment["randomization"] = holosoma_randomization(delay_enabled=False)
    path = fs.write_holosoma(tmp_path / "policy.onnx", experiment, 45)
    ranges = load_ranges_text(training_domain(path), "holosoma", go2)
    p = ranges.pushes
    assert (p.interval, p.mode, p.x, p.y) == ((5.0, 10.0), "set", (-1.0, 1.0), (-1.0, 1.0))
    d = ranges.dynamics
    assert (d.mass, d.kp, d.kd) == pytest.approx((0.2, 0.1, 0.1))
    assert ranges.added_base_mass == (-1.0, 3.0)
    assert ranges.floor_friction == pytest.approx((0.75, 1.125))
    assert ranges.com_offset.x == (-0.05, 0.05) and ranges.sensors.encoder_bias is None
    assert ranges.sensors.noise_sigma[1] == pytest.approx(0.01 / 3**0.5, rel=1e-5)
    assert ranges.commands is not None


def _one_key(key: str, switch: str, value: str) -> str:
    """A legged_gym config whose ``domain_rand`` sets ``switch`` and ``key = value`` only."""
    return (
        "from legged_gym.envs.base.legged_robot_config import LeggedRobotCfg\n\n"
        "class OneCfg(LeggedRobotCfg):\n"
        "    class domain_rand(LeggedRobotCfg.domain_rand):\n"
        f"        {switch} = True\n"
        f"        {key} = {value}\n"
    )


#: Every range key a legged_gym-family reader turns into the soak's ranges, a switch of its own, and the
#: ranges file's line it must write from the config's own value ([0.77, 1.23] or [-0.37, 0.37]).
TRACED = [
    (key, group.switches[-1], line)
    for group, line in (
        (g, "added_base_mass = [-0.37, 0.37]") if g.what == "base mass"
        else (g, "encoder_bias = [-0.37, 0.37]") if g.what == "motor zero offset"
        else (g, " = 0.23")
        for g in GROUPS
        if g.read_into is not None and g.what in (
            "base mass", "link mass", "motor strength", "kp", "kd", "joint friction",
            "joint damping", "armature", "motor zero offset")
    )
    for key in group.values
    if key != "joint_armature_range"
]  # fmt: skip


@pytest.mark.parametrize(("key", "switch", "line"), TRACED, ids=[t[0] for t in TRACED])
def test_every_range_key_is_written_from_the_configs_own_value(tmp_path, key, switch, line):
    """Each key the reader knows reaches the ranges file with the config's own value, never
    legged_gym's default over it (a fork's ``added_base_mass_range = [-4, 4]`` was written as the
    default ``added_mass_range``'s [-1, 1])."""
    value = "[-0.37, 0.37]" if "bias" in line or "mass =" in line else "[0.77, 1.23]"
    text = legged_gym_domain(write(tmp_path, _one_key(key, switch, value)))
    assert line in text, text


def test_an_absolute_armature_range_is_named_not_read_as_a_factor(tmp_path):
    """``joint_armature_range = [0.008, 0.06]`` (kg m^2, the armature itself in engineai's
    forks) is not a factor on the robot's armature (it was read as +-0.992): named as not
    modelled, and no armature is drawn."""
    config = _one_key("joint_armature_range", "randomize_joint_armature", "[0.008, 0.06]")
    text = legged_gym_domain(write(tmp_path, config))
    assert any("joint_armature_range [0.008, 0.06]" in line and "kg m^2" in line
               for line in not_modelled(text))  # fmt: skip
    assert "armature =" not in text
