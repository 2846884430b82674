"""Policies that carry their own contract deploy on the shipped go2 without a spec file.

One file a training stack, written the way it writes its own (``tests/foreign_stacks.py``: mjlab's
metadata, holosoma's metadata, an Isaac Lab run folder; rsl_rl's bare export), each with its
joints in another order than go2's: the spec built from it must put every joint where the stack
put it, build the observation the stack's own formula gives for a known state, map the actions
with the stack's scale about its default pose, carry its PD gains, and run through deploy-run.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.cli.deploy_run import deploy_run_main
from sim2real.deploy.cli.policy_contract import check_drive_applied
from sim2real.deploy.cli.policy_export import main as policy_export_main
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.runtime import Runtime
from sim2real.deploy.spec.drive import drive_robot
from sim2real.deploy.spec.onnx_checks import PolicyLoadError
from sim2real.deploy.spec.policy_spec import UNCLIPPED, PolicySpec
from tests import foreign_stacks as fs

OBS_DIM = 48
#: A distinct small bias per graph output: which joint each output drives is visible.
BIAS = [0.01 * (k + 1) for k in range(12)]


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def known_state(go2, seed: int = 0) -> RobotState:
    """A go2 state with every quantity the blocks read set to distinct values."""
    rng = np.random.default_rng(seed)
    state = RobotState.legged(1, go2.n_joints, go2.n_feet)
    state.q[:] = np.asarray(go2.home) + rng.uniform(-0.2, 0.2, (1, 12))
    state.dq[:] = rng.uniform(-3, 3, (1, 12))
    state.last_action[:] = rng.uniform(-1, 1, (1, 12))
    state.base.linear_velocity[:] = [[0.4, -0.1, 0.05]]
    state.base.angular_velocity[:] = [[0.3, -0.2, 0.7]]
    g = np.array([0.1, -0.05, -1.0])
    state.base.projected_gravity[:] = g / np.linalg.norm(g)
    state.command[:] = [[0.5, 0.2, -0.3]]
    return state


def observe(policy, state) -> np.ndarray:
    """The runtime's observation of ``state`` under the policy's spec (float32, one env)."""
    return policy.spec.observation(state, np.zeros((1, 3)))[0]


def order_index(go2, names) -> list[int]:
    return [go2.joint_names.index(n) for n in names]


def run_deploy(capsys, path) -> tuple[int, str, str]:
    code = deploy_run_main(
        ["--robot", "go2", "--policy", str(path), "--command", "0.5,0,0", "--duration", "1"]
    )
    out, err = capsys.readouterr()
    return code, out, err


def inspect(capsys, path, *extra) -> str:
    assert policy_export_main(["--inspect", str(path), *extra]) == 0
    return capsys.readouterr().out


def check_actions(policy, go2, order, scale, default, obs_dim=OBS_DIM) -> None:
    """Output k of the graph (bias k) drives joint ``order[k]``: target = default + scale * a."""
    action = policy(np.zeros((1, obs_dim), np.float32)).copy()
    idx = order_index(go2, order)
    expected = np.zeros(12)
    expected[idx] = BIAS
    np.testing.assert_allclose(action[0], expected, atol=2e-3)  # gain 1e-3: bias dominates
    state = RobotState.legged(1, 12, 4)
    target = policy.spec.action_to_target(action, state)[0]
    scale_r, default_r = np.zeros(12), np.zeros(12)
    scale_r[idx], default_r[idx] = scale, default
    np.testing.assert_allclose(target, default_r + scale_r * action[0], atol=1e-3)


# ------------------------------------------------------------------------------------ mjlab
def test_mjlab_export_deploys_on_go2_with_its_joint_order_gains_pose_and_scales(
    go2, tmp_path, capsys
):
    md = fs.mjlab_metadata(scales={"base_ang_vel": 0.25, "joint_vel": 0.05})
    path = fs.write_mjlab(tmp_path / "policy.onnx", md, OBS_DIM, bias=BIAS)
    policy = OnnxPolicy(path, go2)
    assert policy.foreign.format == "mjlab" and policy.spec.robot_hash == ""
    idx = order_index(go2, fs.MJLAB_ORDER)
    default = np.array(md["default_joint_pos"])  # policy order
    drive = policy.spec.drive
    np.testing.assert_allclose(np.array(drive.kp)[idx], md["joint_stiffness"], atol=1e-3)
    np.testing.assert_allclose(np.array(drive.kd)[idx], md["joint_damping"], atol=1e-3)
    np.testing.assert_allclose(np.array(drive.default_pose)[idx], default, atol=1e-3)
    # mjlab's observation: the terms in observation_names order, clip then scale, joints in its
    # order, joint_pos about its default, actions the last raw action, command the twist
    state = known_state(go2)
    base = state.base
    expected = np.concatenate(
        [
            base.linear_velocity[0],
            0.25 * base.angular_velocity[0],
            base.projected_gravity[0],
            state.q[0, idx] - default,
            0.05 * state.dq[0, idx],
            state.last_action[0, idx],
            state.command[0],
        ]
    )
    np.testing.assert_allclose(observe(policy, state), expected, rtol=0, atol=2e-6)
    check_actions(policy, go2, fs.MJLAB_ORDER, md["action_scale"], default)
    code, out, err = run_deploy(capsys, path)
    assert code == 0, out + err
    assert "mjlab policy: spec built from its ONNX metadata" in err
    assert "observes the base's linear velocity (term 'base_lin_vel')" in err
    assert "robot.toml differs from the policy's drive, which the run uses: kp" in err
    report = inspect(capsys, path)
    assert "foreign contract: mjlab" in report
    assert "base_ang_vel [3] -> base_angular_velocity (x 0.25, unclipped)" in report
    assert "base linear velocity: observed by the policy (base_lin_vel)" in report
    assert "missing: control rate: not recorded" in report


def test_older_mjlab_metadata_without_term_scales_is_unscaled_and_says_so(go2, tmp_path, capsys):
    path = fs.write_mjlab(tmp_path / "old.onnx", fs.mjlab_metadata(newer=False), OBS_DIM)
    spec = OnnxPolicy(path, go2).spec
    assert all(s == 1.0 for b in spec.observation_blocks for s in b.scale)
    report = inspect(capsys, path)
    assert "missing: observation scales: not recorded (older mjlab); 1 (unscaled) assumed" in report


def test_mjlab_joint_the_robot_lacks_and_unmappable_terms_are_refused_by_name(go2, tmp_path):
    md = fs.mjlab_metadata()
    md["joint_names"][1] = "FR_knee_joint"
    path = fs.write_mjlab(tmp_path / "joint.onnx", md, OBS_DIM)
    with pytest.raises(PolicyLoadError, match=r"mjlab policy: joints \['FR_knee_joint'\] are not"):
        OnnxPolicy(path, go2)
    terms = fs.MJLAB_TERMS[:-1] + ("height_scan",)
    path = fs.write_mjlab(tmp_path / "scan.onnx", fs.mjlab_metadata(terms=terms), OBS_DIM)
    with pytest.raises(PolicyLoadError, match="mjlab policy: observation term 'height_scan'"):
        OnnxPolicy(path, go2)


def test_our_policy_spec_metadata_wins_over_the_stacks(go2, tmp_path):
    import onnx

    path = fs.write_mjlab(tmp_path / "both.onnx", fs.mjlab_metadata(), OBS_DIM)
    foreign = OnnxPolicy(path, go2).spec
    ours = json.loads(foreign.to_json())
    ours["action"]["clip"] = 3.0
    model = onnx.load(str(path))
    entry = model.metadata_props.add()
    entry.key, entry.value = "policy_spec", json.dumps(ours)
    onnx.save(model, str(path))
    policy = OnnxPolicy(path, go2)
    assert policy.foreign is None and policy.spec.action.clip == 3.0


# ------------------------------------------------------------------------------------ holosoma
def test_holosoma_export_deploys_on_go2_with_sorted_terms_and_split_command(go2, tmp_path, capsys):
    experiment = fs.holosoma_experiment(fs.HOLOSOMA_ORDER)
    path = fs.write_holosoma(tmp_path / "policy.onnx", experiment, OBS_DIM, bias=BIAS)
    policy = OnnxPolicy(path, go2)
    assert policy.foreign.format == "holosoma" and policy.spec.control_rate == 50.0
    idx = order_index(go2, fs.HOLOSOMA_ORDER)
    pose = experiment["robot"]["init_state"]["default_joint_angles"]
    default = np.array([pose[n] for n in fs.HOLOSOMA_ORDER])
    # holosoma's observation: terms sorted by name, each scaled then clipped (+-100)
    state = known_state(go2, seed=1)
    base = state.base
    expected = np.concatenate(
        [
            state.last_action[0, idx],  # actions
            0.25 * base.angular_velocity[0],  # base_ang_vel
            2.0 * base.linear_velocity[0],  # base_lin_vel
            state.command[0, 2:3],  # command_ang_vel
            state.command[0, :2],  # command_lin_vel
            state.q[0, idx] - default,  # dof_pos
            0.05 * state.dq[0, idx],  # dof_vel
            base.projected_gravity[0],  # projected_gravity
        ]
    )
    np.testing.assert_allclose(observe(policy, state), expected, rtol=0, atol=2e-6)
    assert policy.spec.action.clip == 100.0  # clip_actions with action_clip_value 100
    check_actions(policy, go2, fs.HOLOSOMA_ORDER, [0.25] * 12, default)
    code, out, err = run_deploy(capsys, path)
    assert code == 0, out + err
    assert "holosoma policy: spec built from its ONNX metadata" in err
    assert "differs from the policy's drive" not in err  # kp 20, kd 0.5 and home: go2's own
    report = inspect(capsys, path, "--robot", "go2")
    assert "command_ang_vel [1] -> velocity_command (unscaled, entries [2] of the vector" in report
    assert "drive differs from robot.toml: none" in report


def holosoma_phases(commands, rate: float, period: float) -> np.ndarray:
    """(ticks, 2) the left and right foot's phase holosoma_inference observes each tick under
    ``commands`` (ticks, 3): ``LocomotionPolicy.update_phase_time`` before each observation,
    from ``[0, pi]`` at the policy's start (``BasePolicy._init_phase_components``)."""
    phase, standing, step, out = np.array([0.0, np.pi]), False, 2 * np.pi / (rate * period), []
    for vx, vy, yaw in commands:
        phase = np.fmod(phase + step + np.pi, 2 * np.pi) - np.pi
        if np.linalg.norm([vx, vy]) < 0.01 and np.linalg.norm([yaw]) < 0.01:
            phase, standing = np.array([np.pi, np.pi]), True
        elif standing:
            phase, standing = np.array([0.0, np.pi]), False
        out.append(phase)
    return np.array(out)


def test_holosoma_two_foot_gait_clock_stops_while_standing_as_holosoma_runs_it(
    go2, tmp_path, capsys
):
    terms = {**fs.HOLOSOMA_TERMS, **fs.HOLOSOMA_PHASE_TERMS}
    experiment = fs.holosoma_experiment(fs.HOLOSOMA_ORDER, terms, gait=fs.holosoma_gait(0.8))
    path = fs.write_holosoma(tmp_path / "phase.onnx", experiment, OBS_DIM + 4)
    policy = OnnxPolicy(path, go2)  # no spec file: the metadata alone
    rate = policy.spec.control_rate
    # sorted terms: actions 12, base_ang_vel 3, base_lin_vel 3, command_ang_vel 1,
    # command_lin_vel 2, cos_phase 2, dof_pos 12, dof_vel 12, projected_gravity 3, sin_phase 2
    cos_at, sin_at = slice(21, 23), slice(50, 52)
    stand, walk, turn = (0.0, 0.0, 0.0), (0.5, 0.0, 0.0), (0.0, 0.0, 0.3)
    creep = (0.006, 0.007, 0.009)  # below holosoma's 0.01: standing
    env0 = [stand] * 10 + [walk] * 60 + [creep] * 20 + [turn] * 45 + [stand] * 5
    env1 = [walk] * 40 + [stand] * 15 + [walk] * 85  # walking from its first tick
    commands = np.array([env0, env1])  # (envs, ticks, 3)
    state = RobotState.legged(2, go2.n_joints, go2.n_feet)
    policy.spec.plan.reset_history()  # the runtime's start (the policy's reset)
    seen, t = [], 0.0
    for tick in range(commands.shape[1]):
        state.command[:] = commands[:, tick]
        state.clock[:] = t
        obs = policy.spec.observation(state, np.zeros((2, 3)))
        seen.append(np.stack([obs[:, sin_at], obs[:, cos_at]], axis=1))  # (envs, 2, feet)
        t += 1.0 / rate
    seen = np.array(seen)  # (ticks, envs, sin/cos, feet)
    for env in range(2):
        phase = holosoma_phases(commands[env], rate, 0.8)
        np.testing.assert_allclose(seen[:, env, 0], np.sin(phase), rtol=0, atol=2e-6)
        np.testing.assert_allclose(seen[:, env, 1], np.cos(phase), rtol=0, atol=2e-6)
    # standing (below 0.01): both feet at pi; turning on the spot restarts the feet at 0 and pi
    assert np.all(seen[75, 0, 1] == np.float32(-1.0))
    np.testing.assert_allclose(seen[90, 0, 1], [1.0, -1.0], rtol=0, atol=1e-6)
    report = inspect(capsys, path, "--robot", "go2")
    assert (
        "sin_phase [2] -> gait_phase (unscaled, entries [0, 2] of the vector, period 0.8 s, "
        in (report)
    )
    assert "stops below a command of 0.01, every foot at 3.142 rad" in report
    code, out, err = run_deploy(capsys, path)
    assert code == 0, out + err


def test_holosoma_gait_clock_in_the_runtime_ticks_is_holosomas(go2, tmp_path):
    """The runtime's own ticks (its clock, its command, its start) give the policy holosoma's
    phases through a stand, a walk, a stand and a turn on the spot."""
    terms = {**fs.HOLOSOMA_TERMS, **fs.HOLOSOMA_PHASE_TERMS}
    experiment = fs.holosoma_experiment(fs.HOLOSOMA_ORDER, terms, gait=fs.holosoma_gait(0.8))
    policy = OnnxPolicy(fs.write_holosoma(tmp_path / "p.onnx", experiment, OBS_DIM + 4), go2)
    seen = []

    class Seen:  # the policy, keeping each observation it is given
        spec = policy.spec

        def __call__(self, obs):
            seen.append(obs[0].copy())
            return policy(obs)

    rt = Runtime(go2, Seen(), SimBackend(go2, "position", envs=1, seed=0))
    rt.start()
    commands = [(0.0, 0.0, 0.0)] * 10 + [(0.5, 0.0, 0.0)] * 60 + [(0.0, 0.0, 0.0)] * 20
    commands += [(0.0, 0.0, 0.3)] * 30
    for command in commands:
        rt.velocity_command[:] = [command]
        rt.run(1)
    seen = np.array(seen)
    phase = holosoma_phases(np.array(commands), policy.spec.control_rate, 0.8)
    np.testing.assert_allclose(seen[:, 50:52], np.sin(phase), rtol=0, atol=2e-6)  # sin_phase
    np.testing.assert_allclose(seen[:, 21:23], np.cos(phase), rtol=0, atol=2e-6)  # cos_phase


@pytest.mark.parametrize(("key", "value"), [("fps", 0), ("control_decimation", 0),
                                             ("control_decimation", 2.5), ("fps", -200)])  # fmt: skip
def test_a_holosoma_rate_of_zero_or_below_is_refused_naming_the_key(tmp_path, capsys, key, value):
    """``simulator.config.sim``'s ``fps / control_decimation`` is the control rate: a
    control_decimation of 0 was a ZeroDivisionError traceback (exit 1, a hard violation's
    code), 2.5 a rate read silently; one line naming the key, exit 3."""
    experiment = fs.holosoma_experiment(fs.HOLOSOMA_ORDER)
    experiment["simulator"]["config"]["sim"][key] = value
    path = fs.write_holosoma(tmp_path / "policy.onnx", experiment, OBS_DIM)
    argv = ["--robot", "go2", "--policy", str(path), "--backend", "sim", "--duration", "0.1"]
    assert deploy_run_main(argv) == 3
    err = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert len(err) == 1 and f"'simulator.config.sim.{key}': expected" in err[0], err
    assert f"got {value!r}" in err[0], err


@pytest.mark.parametrize(
    ("where", "key", "value"),
    [("sim", "dt", 0), ("sim", "dt", -0.005), ("sim", "dt", "fast"), (None, "decimation", 0),
     (None, "decimation", 2.5)],
)  # fmt: skip
def test_an_isaaclab_period_of_zero_or_below_is_refused_naming_the_key(
    tmp_path, capsys, where, key, value
):
    """env.yaml's ``sim.dt`` x ``decimation`` is the control period: 0 was a ZeroDivisionError
    traceback (exit 1), a decimation of 2.5 read as 2 (a 100-Hz policy); one line naming the
    file and key, exit 3."""
    env = fs.isaaclab_env()
    (env[where] if where else env)[key] = value
    path = fs.write_isaaclab_run(tmp_path / "run", env, OBS_DIM, 12)
    argv = ["--robot", "go2", "--policy", str(path), "--backend", "sim", "--duration", "0.1"]
    assert deploy_run_main(argv) == 3
    err = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    name = f"{where}.{key}" if where else key
    assert len(err) == 1 and f"env.yaml: '{name}': expected a number of" in err[0], err
    assert f"got {value!r}" in err[0], err


# ------------------------------------------------------------------------------------ Isaac Lab
def test_isaaclab_run_deploys_on_go2_in_the_articulation_order(go2, tmp_path, capsys):
    run = tmp_path / "logs" / "rsl_rl" / "unitree_go2_flat" / "2026-01-01_00-00-00"
    path = fs.write_isaaclab_run(run, fs.isaaclab_env(), OBS_DIM, 12, bias=BIAS)
    policy = OnnxPolicy(path, go2)
    assert policy.foreign.format == "isaaclab" and policy.spec.control_rate == 50.0
    order = fs.isaaclab_order()
    idx = order_index(go2, order)
    default = np.asarray(go2.home)[idx]  # UNITREE_GO2_CFG's init_state: go2's home
    np.testing.assert_array_equal(policy.spec.drive.kp, [25.0] * 12)
    np.testing.assert_array_equal(policy.spec.drive.kd, [0.5] * 12)
    # Isaac Lab's observation: the policy group's terms in order, unscaled, joints in the
    # articulation's (breadth-first) order
    state = known_state(go2, seed=2)
    base = state.base
    expected = np.concatenate(
        [
            base.linear_velocity[0],
            base.angular_velocity[0],
            base.projected_gravity[0],
            state.command[0],
            state.q[0, idx] - default,
            state.dq[0, idx],
            state.last_action[0, idx],
        ]
    )
    np.testing.assert_allclose(observe(policy, state), expected, rtol=0, atol=2e-6)
    check_actions(policy, go2, order, [0.25] * 12, default)
    code, out, err = run_deploy(capsys, path)
    assert code == 0, out + err
    assert "isaaclab policy: joint order: not in any file" in err
    assert "kp (N m/rad): policy [25.0 x 12], robot.toml [20.0 x 12]" in err
    report = inspect(capsys, path, "--robot", "go2")
    assert "foreign contract: isaaclab" in report and "missing: joint order" in report
    assert "graph outputs -> robot joints: FL_hip_joint -> 0, FR_hip_joint -> 3" in report


def test_rsl_rl_export_without_a_run_folder_is_refused_saying_where_it_looked(
    go2, tmp_path, capsys
):
    path = fs._export(
        fs.Actor(OBS_DIM, 12, 0, 1e-3), OBS_DIM, tmp_path / "p.onnx", 18, ["obs"], ["actions"]
    )
    code, _, err = run_deploy(capsys, path)
    assert code == 3
    assert "isaaclab policy: Isaac Lab / rsl_rl export (obs -> actions) without metadata" in err
    assert "params/env.yaml" in err and "pass --spec FILE" in err
    assert "cannot be read" in inspect(capsys, path)


def test_rsl_rl_opset_18_export_in_an_isaaclab_run_folder_deploys(go2, tmp_path):
    path = fs.write_isaaclab_run(tmp_path / "run", fs.isaaclab_env(), OBS_DIM, 12, opset=18)
    assert OnnxPolicy(path, go2).foreign.format == "isaaclab"


# ------------------------------------------------------------------------------------ drive
def test_the_policys_gains_drive_the_simulated_plant_and_hardware_refuses_them(go2, tmp_path):
    path = fs.write_isaaclab_run(tmp_path / "run", fs.isaaclab_env(stiffness=30.0), OBS_DIM, 12)
    spec = OnnxPolicy(path, go2).spec
    robot, differences = drive_robot(go2, spec)
    model = robot.plant_model("position")
    np.testing.assert_array_equal(model.actuator_gainprm[:12, 0], [30.0] * 12)
    np.testing.assert_array_equal(-model.actuator_biasprm[:12, 2], [0.5] * 12)
    assert set(differences) == {"kp"} and robot.description_hash != go2.description_hash
    check_drive_applied(differences, sets_gains=True, backend_name="sim")
    with pytest.raises(ValueError, match="feetech backend cannot set its drives' gains"):
        check_drive_applied(differences, sets_gains=False, backend_name="feetech")
    same, none = drive_robot(go2, PolicySpec.for_robot(go2))
    assert same is go2 and none == {}


def test_a_spec_with_drive_components_and_output_order_round_trips_through_json(go2, tmp_path):
    experiment = fs.holosoma_experiment(fs.HOLOSOMA_ORDER)
    spec = OnnxPolicy(fs.write_holosoma(tmp_path / "p.onnx", experiment, OBS_DIM), go2).spec
    back = PolicySpec.from_json(spec.to_json())
    assert back == spec and back.action.joints and back.drive.kp
    assert [b.components for b in back.observation_blocks if b.components] == [(2,), (0, 1)]


# ------------------------------------------------------------------- Unitree's deploy.yaml
def test_unitree_deploy_yaml_beside_the_policy_is_its_contract(go2, tmp_path, capsys):
    """unitree_rl_lab / unitree_rl_mjlab ship ``exported/policy.onnx`` (+ ``policy.onnx.data``)
    and ``params/deploy.yaml``: deploy-run reads the yaml with no --spec. ``joint_ids_map`` gives
    each policy joint's motor slot (sim2real/robots/go2 ``[unitree] motor_index``), so the policy's joint
    order here is Unitree's motor order (FR, FL, RR, RL); the observation is what their C++
    deployment computes (``joint_pos[i] - default_joint_pos[i]``, clip then scale) and the target
    ``raw * scale + offset``. A per-joint clip of the targets is refused in one line."""
    default = [fs.mjlab_pose(n) for n in fs.MJLAB_ORDER]
    cfg = fs.unitree_deploy(range(12), default, scale=0.3, stiffness=30.0, damping=0.7)
    path = fs.write_unitree_policy(tmp_path / "v0", cfg, 45, bias=BIAS)
    assert (path.parent / "policy.onnx.data").is_file()
    policy = OnnxPolicy(path, go2)
    assert policy.foreign.format == "unitree_deploy"
    idx = order_index(go2, fs.MJLAB_ORDER)
    drive = policy.spec.drive
    np.testing.assert_allclose(np.array(drive.kp)[idx], 30.0)
    np.testing.assert_allclose(np.array(drive.default_pose)[idx], default)
    state = known_state(go2)
    base = state.base
    expected = np.concatenate(
        [
            0.25 * base.angular_velocity[0],
            base.projected_gravity[0],
            state.command[0],
            state.q[0, idx] - default,
            0.05 * state.dq[0, idx],
            state.last_action[0, idx],
        ]
    )
    np.testing.assert_allclose(observe(policy, state), expected, rtol=0, atol=2e-6)
    check_actions(policy, go2, fs.MJLAB_ORDER, 0.3, default, obs_dim=45)
    code, out, err = run_deploy(capsys, path)
    assert code == 0, out + err
    assert "unitree_deploy policy: spec built from" in err
    report = inspect(capsys, path)
    assert "foreign contract: unitree_deploy" in report
    assert "base_ang_vel [3] -> base_angular_velocity (x 0.25, unclipped)" in report
    cfg["actions"]["JointPositionAction"]["clip"] = [[-1.0, 1.0]] * 12
    path = fs.write_unitree_policy(tmp_path / "v1", cfg, 45, bias=BIAS)
    with pytest.raises(PolicyLoadError, match=r"JointPositionAction.clip: a per-joint clip"):
        OnnxPolicy(path, go2)


def test_robot_import_takes_the_drive_from_the_policys_contract(tmp_path, capsys):
    """``robot-import --drive-from POLICY``: kp, kd, home and the control rate come from the
    policy's deploy.yaml, joint by joint through its motor slots (a ``unitree_hg`` humanoid's
    slots are its description's joint order), so the PD-target limits are the policy's; a
    ``--kp`` after it wins; a different --control-rate or a policy for other joints is refused in
    one line."""
    from sim2real.deploy.cli.robot_import import main
    from sim2real.robots import load_robot
    from sim2real.robots.importer.pipeline import EXIT_REFUSED
    from tests.test_import_humanoid import MOTORS, write_humanoid

    source = write_humanoid(tmp_path)
    joints = [m.joint(i).name for m in [load_mj(source)] for i in range(1, m.njnt)]
    n = len(joints)
    default = [0.0, -0.1, 0.3, -0.2] * 2
    slots = list(range(n))[::-1]  # the policy lists the joints from the last motor slot down
    cfg = fs.unitree_deploy(slots, [default[s] for s in slots])
    cfg["stiffness"] = [10.0 + s for s in range(n)]  # the motor slots' order, as their C++ reads it
    cfg["damping"] = [0.5 + 0.1 * s for s in range(n)]
    policy = fs.write_unitree_policy(tmp_path / "v0", cfg, 9 + 3 * n)
    out = tmp_path / "robots" / "tiny"
    common = [
        str(source),
        "--floating-base",
        "--unitree",
        "unitree_hg",
        "--unitree-damping-kd",
        "2",
        *[a for m in MOTORS for a in ("--motor", m)],
        "--drive-from",
        str(policy),
    ]
    assert main([*common, "--out", str(out), "--kp", "left_knee_joint=77"]) == 0
    robot = load_robot(out)
    assert robot.joint_names == tuple(joints) and robot.control_period == pytest.approx(0.02)
    kp = [j.kp for j in robot.config.joints]
    assert kp == [77.0 if name == "left_knee_joint" else 10.0 + i for i, name in enumerate(joints)]
    np.testing.assert_allclose([j.kd for j in robot.config.joints], 0.5 + 0.1 * np.arange(n))
    np.testing.assert_allclose(robot.home, default)
    ankle = robot.config.joints[joints.index("left_ankle_joint")]
    # --target-limits pd: the target's speed when the full torque moves it (effort / kp)
    assert ankle.command_velocity_limit == pytest.approx(2 * 40.0 / 13.0 / 0.02, rel=0.01)
    printed = capsys.readouterr().out
    assert "--drive-from unitree_deploy contract" in printed and "kp, kd, home read" in printed
    assert "kp: the policy's (--drive-from" in printed and "--kp for ['left_knee_joint']" in printed
    toml = (out / "robot.toml").read_text()
    assert "# control rate: the policy's (--drive-from: unitree_deploy contract" in toml
    assert "kp = 77.0  # N m/rad, --kp\n" in toml and "--kd" not in toml

    code = main([*common, "--out", str(tmp_path / "b"), "--control-rate", "100"])
    err = capsys.readouterr().err.strip()
    assert code == EXIT_REFUSED and "\n" not in err and "runs at 50 Hz" in err
    cfg["joint_ids_map"] = list(range(n + 1))
    for key in ("stiffness", "damping", "default_joint_pos"):
        cfg[key] = cfg[key] + [1.0]
    action = cfg["actions"]["JointPositionAction"]
    action["scale"], action["offset"] = action["scale"] + [0.25], action["offset"] + [0.0]
    policy = fs.write_unitree_policy(tmp_path / "v1", cfg, 12 + 3 * n)
    common[-1] = str(policy)
    assert main([*common, "--out", str(tmp_path / "c")]) == EXIT_REFUSED
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--drive-from" in err and "motor slots [8]" in err


def load_mj(path):
    import mujoco

    return mujoco.MjModel.from_xml_path(str(path))


def test_a_spec_that_leaves_out_every_optional_key_runs_the_policy_as_the_explicit_one(
    go2, tmp_path, capsys
):
    """Every optional key of a spec file has a documented default, and leaving it out is the same
    as writing that default: the two specs are equal and the same policy walks the same run
    through the runtime (no silent clip, scale or joint order)."""
    import json

    n = go2.n_joints
    path = fs._export(
        fs.Actor(45, n, 4, 1e-2, list(go2.home)),
        45,
        tmp_path / "policy.onnx",
        18,
        ["obs"],
        ["actions"],
    )
    kinds = {"base_angular_velocity": 3, "projected_gravity": 3, "velocity_command": 3}
    minimal = {
        "format_version": 1,
        "robot": "go2",
        "joint_names": list(go2.joint_names),
        "control_rate": 50.0,
        "observation": [{"name": k} for k in kinds]
        + [{"name": k} for k in ("joint_position", "joint_velocity", "last_action")],
        "action": {"mode": "position"},
    }
    every = list(range(n))
    explicit = json.loads(json.dumps(minimal))
    explicit["robot_hash"] = ""
    for block in explicit["observation"]:
        size = kinds.get(block["name"], n)
        block.update(size=size, scale=[1.0] * size, offset=[0.0] * size, clip=UNCLIPPED)
        if block["name"] in kinds:
            block["components"] = [0, 1, 2]
        else:
            block["joints"] = every
    explicit["action"].update(
        size=n, scale=[1.0] * n, offset=[0.0] * n, clip=UNCLIPPED, reference="absolute",
        joints=every,
    )  # fmt: skip
    specs = {}
    for name, doc in (("minimal", minimal), ("explicit", explicit)):
        specs[name] = tmp_path / f"{name}.json"
        specs[name].write_text(json.dumps(doc))
    a, b = (PolicySpec.from_json(p.read_text()) for p in specs.values())
    import dataclasses

    # output i drives joint i: left out (empty) or written as every joint in order
    assert a.action == dataclasses.replace(b.action, joints=()) and a.obs_dim == b.obs_dim == 45
    assert a.action.driven == b.action.driven == tuple(range(n))
    for x, y in zip(a.observation_blocks, b.observation_blocks, strict=True):
        assert (x.name, x.size, x.scale, x.offset, x.clip, x.joints) == (
            y.name, y.size, y.scale, y.offset, y.clip, y.joints,
        )  # fmt: skip
    runs = []
    for spec in specs.values():
        argv = ["--robot", "go2", "--policy", str(path), "--spec", str(spec)]
        code = deploy_run_main([*argv, "--command", "0.3,0,0", "--duration", "2"])
        out = capsys.readouterr().out
        lines = out.splitlines()
        runs.append((code, [ln for ln in lines if ln.split()[:1] in (["walked"], ["violations"])]))
    assert runs[0] == runs[1] and runs[0][0] == 0 and len(runs[0][1]) == 2, runs


def test_policy_export_writes_a_foreign_onnx_with_our_spec_in_one_file(go2, tmp_path, capsys):
    """``policy-export policy.onnx --robot go2``: the published graph (weights in
    ``policy.onnx.data``, contract in ``params/deploy.yaml``) becomes one file that carries our
    spec, runs with neither sidecar, and gives the source's actions to the bit; without --robot,
    or with a --spec file that is not there, it is refused in one line."""
    import shutil

    import onnx

    default = [fs.mjlab_pose(n) for n in fs.MJLAB_ORDER]
    cfg = fs.unitree_deploy(range(12), default, scale=0.3, stiffness=30.0, damping=0.7)
    path = fs.write_unitree_policy(tmp_path / "v0", cfg, 45, bias=BIAS)
    for argv, message in (
        ([], "needs --robot"),
        (["--robot", "go2", "--spec", "x.json"], "x.json: cannot read the spec file"),
    ):
        assert policy_export_main([str(path), *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and message in err
    assert policy_export_main([str(path), "--robot", "go2"]) == 0
    out = path.with_name("policy.go2.onnx")
    assert str(out) in capsys.readouterr().out
    alone = tmp_path / "alone" / "policy.onnx"
    alone.parent.mkdir()
    shutil.copy(out, alone)  # no policy.onnx.data, no params/deploy.yaml beside it
    meta = {p.key: p.value for p in onnx.load(str(alone)).metadata_props}
    assert "policy_spec" in meta and json.loads(meta["parity"])["max_abs_error"] == 0.0
    source, written = OnnxPolicy(path, go2), OnnxPolicy(alone, go2)
    assert written.foreign is None and written.spec.drive == source.spec.drive
    for row in np.random.default_rng(0).uniform(-1, 1, (8, 1, 45)).astype(np.float32):
        np.testing.assert_array_equal(written(row).copy(), source(row).copy())
