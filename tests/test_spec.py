"""PolicySpec: JSON round trip, observation layout and normalization, action mapping, robot checks."""

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest
from helpers_policies import ARM3_BLOCKS as ALL_BLOCKS

from sim2real.deploy.core.state import Kinematics, RobotState
from sim2real.deploy.spec.policy_spec import PolicySpec, SpecError


@pytest.fixture(scope="module")
def spec(arm3):
    return PolicySpec.for_robot(arm3, blocks=ALL_BLOCKS)


def state_at(robot, q, dq=None, envs=1):
    state = RobotState.zeros(envs, robot.n_joints, robot.config.sensors.ambient_temperature)
    state.q[:] = q
    state.dq[:] = 0.0 if dq is None else dq
    return Kinematics(robot).update(state)


# ---------------------------------------------------------------------- JSON
def test_json_round_trip_preserves_every_field(spec):
    filled = dataclasses.replace(
        spec,
        baked={"observation_normalizer": True, "action_clip": True},
        parity={"max_abs_error": 1e-7, "samples": 1049},
    )
    back = PolicySpec.from_json(filled.to_json())
    assert back == filled
    assert back.obs_dim == 21 and back.act_dim == 3
    assert back.block_slices()["goal_in_ee"] == slice(12, 15)


def test_unknown_format_version_is_refused(spec):
    d = json.loads(spec.to_json())
    d["format_version"] = 2
    with pytest.raises(SpecError, match=r"my_spec.json: format_version 2 is not supported"):
        PolicySpec.from_json(json.dumps(d), source="my_spec.json")


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d.pop("joint_names"), r"field 'joint_names' is missing"),
        (lambda d: d["action"].update(mode="teleport"), r"action.mode: 'teleport' is unknown"),
        (lambda d: d["observation"][0].update(size=7), r"observation\[0\].*scale and offset"),
        (lambda d: d["observation"][1].update(scale=[0, 1, 1]), r"scale must be finite"),
    ],
)
def test_invalid_spec_json_names_the_field(spec, edit, message):
    d = json.loads(spec.to_json())
    edit(d)
    with pytest.raises(SpecError, match=message):
        PolicySpec.from_json(json.dumps(d), source="s.json")


def test_not_json_is_refused():
    with pytest.raises(SpecError, match=r"s.json: not valid JSON"):
        PolicySpec.from_json("{oops", source="s.json")


# ---------------------------------------------------------------------- observation
def test_joint_limits_and_velocity_limits_map_to_plus_minus_one(arm3, spec):
    sl = spec.block_slices()
    goal = np.zeros((1, 3))
    upper = spec.observation(state_at(arm3, arm3.position_upper, arm3.velocity_limit), goal)
    lower = spec.observation(state_at(arm3, arm3.position_lower, -arm3.velocity_limit), goal)
    assert upper.dtype == np.float32 and upper.shape == (1, 21)
    np.testing.assert_allclose(upper[0, sl["joint_position"]], 1.0, atol=1e-6)
    np.testing.assert_allclose(lower[0, sl["joint_position"]], -1.0, atol=1e-6)
    np.testing.assert_allclose(upper[0, sl["joint_velocity"]], 1.0, atol=1e-6)
    np.testing.assert_allclose(lower[0, sl["joint_velocity"]], -1.0, atol=1e-6)
    centre = spec.observation(state_at(arm3, np.zeros(3)), goal)
    np.testing.assert_allclose(centre[0, sl["joint_position"]], 0.0, atol=1e-6)


def test_positions_are_scaled_by_reach(arm3, spec):
    sl = spec.block_slices()
    reach = Kinematics(arm3).reach()
    stretched = state_at(arm3, np.zeros(3))  # arm3 straight out along +x
    goal = np.array([[0.3, -0.45, 0.0]])
    obs = spec.observation(stretched, goal)
    np.testing.assert_allclose(obs[0, sl["ee_position"]], stretched.ee_position[0] / reach, 1e-6)
    assert np.linalg.norm(stretched.ee_position[0]) == pytest.approx(reach, rel=1e-6)
    np.testing.assert_allclose(obs[0, sl["goal_position"]], goal[0] / reach, rtol=1e-6)


def test_goal_is_expressed_in_the_end_effector_frame(arm3, spec):
    sl = spec.block_slices()
    state = state_at(arm3, [0.4, -0.3, 0.2])
    reach = Kinematics(arm3).reach()
    R, p = state.ee_rotation[0], state.ee_position[0]
    offset_in_ee = np.array([0.1, 0.05, 0.0])
    goal = (p + R @ offset_in_ee)[None]
    obs = spec.observation(state, goal)
    np.testing.assert_allclose(obs[0, sl["goal_in_ee"]], offset_in_ee / reach, atol=1e-6)
    # a goal at the end effector is the origin of that frame
    obs = spec.observation(state, p[None])
    np.testing.assert_allclose(obs[0, sl["goal_in_ee"]], 0.0, atol=1e-6)


def test_temperature_last_action_and_clip(arm3, spec):
    sl = spec.block_slices()
    state = state_at(arm3, np.zeros(3))
    ambient = arm3.config.sensors.ambient_temperature
    state.winding_temperature[:] = [ambient, arm3.motors[1].max_winding_temperature, 1e6]
    state.last_action[:] = [0.5, -1.0, 0.0]
    obs = spec.observation(state, np.zeros((1, 3)))
    np.testing.assert_allclose(obs[0, sl["winding_temperature"]], [0.0, 1.0, 5.0], atol=1e-6)
    np.testing.assert_allclose(obs[0, sl["last_action"]], [0.5, -1.0, 0.0])


def test_observation_is_batched_and_writes_into_out(arm3, spec):
    state = state_at(arm3, [[0.1, 0.2, 0.3], [-0.5, 0.0, 1.0]], envs=2)
    out = np.full((2, 21), np.nan, np.float32)
    result = spec.observation(state, np.zeros((2, 3)), out=out)
    assert result is out and np.isfinite(out).all()
    one = spec.observation(state_at(arm3, [-0.5, 0.0, 1.0]), np.zeros((1, 3)))
    np.testing.assert_allclose(out[1], one[0])


def test_wrapping_joints_use_sin_cos(arm6):
    spec = PolicySpec.for_robot(arm6, blocks=("joint_position", "joint_position_sincos"))
    blocks = {b.name: b for b in spec.observation_blocks}
    assert blocks["joint_position"].joints == (2,)  # the elbow is the only bounded joint
    assert blocks["joint_position_sincos"].joints == (0, 1, 3, 4, 5)
    state = state_at(arm6, arm6.home)
    obs = spec.observation(state, np.zeros((1, 3)))
    q = arm6.home[[0, 1, 3, 4, 5]]
    np.testing.assert_allclose(obs[0, 1:], np.concatenate([np.sin(q), np.cos(q)]), atol=1e-6)


# ---------------------------------------------------------------------- action
def test_action_to_target_in_each_mode(arm3):
    state = state_at(arm3, [0.2, -0.1, 0.3])
    a = np.array([[1.0, -0.5, 3.0]])  # the last entry is clipped to 1
    vel = PolicySpec.for_robot(arm3, mode="velocity").action_to_target(a, state)
    # a full velocity action is the smoother's soft velocity limit, 0.9 x 3.14 rad/s: never clamped
    np.testing.assert_allclose(vel, [[2.826, -1.413, 2.826]])
    torque = PolicySpec.for_robot(arm3, mode="torque").action_to_target(a, state)
    np.testing.assert_allclose(torque, [[22.5, -11.25, 22.5]])
    absolute = PolicySpec.for_robot(arm3, mode="position").action_to_target(a, state)
    # a full absolute action is the soft limit, 0.9 x 1.57 rad about the centre
    np.testing.assert_allclose(absolute, [[1.413, -0.7065, 1.413]])
    hard = PolicySpec.for_robot(arm3, mode="position", position_range="hard")
    np.testing.assert_allclose(hard.action_to_target(a, state), [[1.57, -0.785, 1.57]])
    current = PolicySpec.for_robot(arm3, mode="position", reference="current")
    step = 3.14 * arm3.control_period
    np.testing.assert_allclose(
        current.action_to_target(a, state), [[0.2 + step, -0.1 - 0.5 * step, 0.3 + step]]
    )
    out = np.empty((1, 3))
    assert current.action_to_target(a, state, out=out) is out


@pytest.mark.parametrize("name", ["arm3", "arm6", "so101"])
def test_a_full_absolute_position_action_is_never_clamped_by_the_guard(name):
    """The default spec maps +-1 to the soft limits, inside them in float64 (a saturated joint,
    such as a gripper held closed, is not a soft-limit intervention on every tick); the
    adversary's hard range is clamped."""
    from sim2real.deploy.safety.guard import SafetyGuard
    from sim2real.robots import load_robot

    robot = load_robot(name)
    n = robot.n_joints
    rng = np.random.default_rng(0)
    actions = np.vstack([np.ones(n), -np.ones(n), rng.choice([-1.0, 1.0], (62, n))])
    state = RobotState.zeros(len(actions), n)
    state.q[:] = robot.home
    target = PolicySpec.for_robot(robot, mode="position").action_to_target(actions, state)
    assert (target >= robot.soft_lower).all() and (target <= robot.soft_upper).all()
    np.testing.assert_allclose(target[0], robot.soft_upper, rtol=0, atol=1e-12)
    np.testing.assert_allclose(target[1], robot.soft_lower, rtol=0, atol=1e-12)
    guard = SafetyGuard(robot, len(actions), "position")
    guard.filter(target.copy(), state)
    assert guard.totals()["soft_limit"] == 0
    hard = PolicySpec.for_robot(robot, mode="position", position_range="hard")
    guard.filter(hard.action_to_target(actions, state), state)
    assert guard.totals()["soft_limit"] == len(actions)


def test_an_unknown_position_range_is_refused(arm3):
    with pytest.raises(SpecError, match=r"position range 'wide' is unknown; expected one of"):
        PolicySpec.for_robot(arm3, mode="position", position_range="wide")


def test_current_reference_only_in_position_mode(arm3):
    with pytest.raises(SpecError, match=r"action.reference: 'current' is not valid for mode"):
        PolicySpec.for_robot(arm3, mode="velocity", reference="current")


# ---------------------------------------------------------------------- robot checks
def test_check_robot_accepts_its_robot(arm3, spec):
    spec.check_robot(arm3)


def test_arm3_spec_refused_on_arm6(arm6, spec):
    with pytest.raises(SpecError, match=r"robot: policy is for 'arm3', the robot is 'arm6'"):
        spec.check_robot(arm6)


def test_changed_description_hash_is_refused(arm3, spec):
    stale = dataclasses.replace(spec, robot_hash="0" * 64)
    with pytest.raises(SpecError, match=r"robot_hash: .*robot.toml or MJCF changed"):
        stale.check_robot(arm3)
    stale.check_robot(arm3, check_hash=False)


def test_joint_order_and_rate_mismatch_are_named(arm3, spec):
    swapped = dataclasses.replace(spec, joint_names=("elbow", "shoulder", "wrist"))
    with pytest.raises(SpecError, match=r"joint_names: policy expects \['elbow', 'shoulder'"):
        swapped.check_robot(arm3)
    slow = dataclasses.replace(spec, control_rate=100.0)
    with pytest.raises(SpecError, match=r"control_rate: policy runs at 100.0 Hz, the robot at 200"):
        slow.check_robot(arm3)


# ---------------------------------------------------------------------- JSON shorthands
REPO = Path(__file__).resolve().parent.parent
EXAMPLES = REPO / "docs" / "examples"
GODOT_FILE = REPO / "tests" / "data" / "godot_rl_0.8.2_ppo_arm3.onnx"


def _arm3_doc(arm3, **changes) -> dict:
    d = {
        "format_version": 1,
        "robot": "arm3",
        "joint_names": list(arm3.joint_names),
        "control_rate": 200.0,
        "observation": [{"name": "joint_position", "scale": 3.141592653589793}],
        "action": {"mode": "velocity", "scale": 3.14},
    }
    d.update(changes)
    return d


def test_scale_and_offset_take_a_number_a_list_or_nothing_and_joints_by_name(arm3):
    doc = _arm3_doc(
        arm3,
        observation=[
            {"name": "joint_position", "scale": 2.0, "offset": [0.1, 0.2, 0.3]},
            {"name": "joint_velocity", "joints": ["wrist", "shoulder"], "scale": [4, 5]},
            {"name": "goal_position"},
            {"name": "last_action", "clip": 100},
        ],
        action={"mode": "position", "offset": [0.0, 0.5, 0.5], "scale": 0.25, "clip": 100},
    )
    spec = PolicySpec.from_json(json.dumps(doc))
    jp, jv, goal, last = spec.observation_blocks
    assert (jp.size, jp.scale, jp.offset, jp.joints) == (3, (2.0,) * 3, (0.1, 0.2, 0.3), (0, 1, 2))
    assert (jv.size, jv.scale, jv.offset, jv.joints) == (2, (4.0, 5.0), (0.0, 0.0), (2, 0))
    assert (goal.size, goal.scale, goal.offset) == (3, (1.0,) * 3, (0.0,) * 3)  # raw metres
    assert (last.size, last.joints, last.clip) == (3, (0, 1, 2), 100.0)
    a = spec.action
    assert (a.size, a.scale, a.offset, a.clip) == (3, (0.25,) * 3, (0.0, 0.5, 0.5), 100.0)
    assert spec.robot_hash == "" and spec.obs_dim == 11
    spec.check_robot(arm3)  # no hash given: not checked
    # the stored form is explicit and reads back equal
    stored = json.loads(spec.to_json())
    assert stored["observation"][1]["scale"] == [4.0, 5.0] and "constant_inputs" not in stored
    assert PolicySpec.from_json(spec.to_json()) == spec


def test_stored_specs_read_back_byte_for_byte(arm3):
    """The explicit format written by earlier versions (the shipped checkpoint's spec) reads
    back to the same JSON: files already exported keep their meaning."""
    torch = pytest.importorskip("torch")
    stored = torch.load(REPO / "sim2real" / "policies" / "arm.pt", weights_only=True)["spec"]
    assert PolicySpec.from_json(stored).to_json() == stored
    made = PolicySpec.for_robot(arm3, blocks=ALL_BLOCKS).to_json()
    assert PolicySpec.from_json(made).to_json() == made


def test_legged_gym_conventions_are_expressed_exactly(arm6):
    """legged_gym: obs = (dof_pos - default) * 1.0, dof_vel * 0.05, actions (clip 100);
    target = default + 0.25 * clip(action, -100, 100)."""
    spec = PolicySpec.from_json((EXAMPLES / "legged_gym_style_arm6.spec.json").read_text())
    spec.check_robot(arm6)
    default = np.array(arm6.home)
    rng = np.random.default_rng(3)
    state = RobotState.zeros(2, 6, 25.0)
    state.q[:] = default + rng.uniform(-0.5, 0.5, (2, 6))
    state.dq[:] = rng.uniform(-3, 3, (2, 6))
    state.last_action[:] = rng.uniform(-2, 2, (2, 6))
    Kinematics(arm6).update(state)
    obs = spec.observation(state, np.zeros((2, 3)))
    legged = np.concatenate([(state.q - default) * 1.0, state.dq * 0.05, state.last_action], 1)
    np.testing.assert_allclose(obs, legged, rtol=1e-6, atol=1e-7)
    action = rng.uniform(-150, 150, (2, 6))
    target = spec.action_to_target(action, state)
    np.testing.assert_allclose(target, default + 0.25 * np.clip(action, -100, 100), rtol=1e-12)


@pytest.mark.parametrize(
    "block, why",
    [
        ("base_ang_vel", "this toolkit calls it 'base_angular_velocity'"),
        ("commands", "this toolkit calls it 'velocity_command'"),
        ("base_height", "no robot here measures it"),
        ("projected_gravity", "the robot 'arm3' is a fixed-base arm"),
        ("foot_contact", "the robot 'arm3' is a fixed-base arm"),
    ],
)
def test_a_block_the_robot_cannot_provide_is_refused_at_load_naming_it(arm3, block, why, tmp_path):
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.spec.onnx_checks import PolicyLoadError

    doc = _arm3_doc(arm3)
    doc["observation"].insert(0, {"name": block, "scale": 4.0})
    path = tmp_path / "legged.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(
        PolicyLoadError,
        match=rf"legged.json: observation\[0\] \('{block}'\): block '{block}' cannot be provided: "
        + re.escape(why),
    ):
        OnnxPolicy(GODOT_FILE, arm3, spec=path)
    doc["observation"][0]["name"] = "joint_torque"
    with pytest.raises(SpecError, match=r"block 'joint_torque' is unknown: no robot provides it"):
        PolicySpec.from_json(json.dumps(doc))


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            lambda d: d["observation"][0].update(scales=2.0),
            r"s.json: field 'observation\[0\].scales' is not a PolicySpec field",
        ),
        (
            lambda d: d["observation"][0].update(joints=["shoulder", "knee"]),
            r"s.json: observation\[0\] \('joint_position'\).joints: joint 'knee' is not in",
        ),
        (lambda d: d["action"].update(scale="fast"), r"field 'action.scale': .*'fast'"),
        (lambda d: d["observation"][0].update(scale=[1, 2]), r"scale and offset need 3 entries"),
        (
            lambda d: d.update(constant_inputs={"state_ins": float("nan")}),
            r"constant_inputs\['state_ins'\]: must be finite",
        ),
    ],
)
def test_bad_shorthand_is_refused_naming_the_field(arm3, edit, message):
    d = _arm3_doc(arm3)
    edit(d)
    with pytest.raises(SpecError, match=message):
        PolicySpec.from_json(json.dumps(d), source="s.json")


# ---------------------------------------------------------------------- the JSON Schema
def test_committed_schema_is_the_generated_one():
    from sim2real.deploy.spec.schema import SCHEMA_PATH, schema_text

    assert SCHEMA_PATH.read_text() == schema_text(), (
        "docs/policy_spec.schema.json is stale: run python -m sim2real.deploy.spec.schema"
    )


def test_shipped_and_example_specs_validate_against_the_schema(arm3, arm6):
    jsonschema = pytest.importorskip("jsonschema")
    torch = pytest.importorskip("torch")
    from sim2real.deploy.spec.schema import SCHEMA_PATH

    schema = json.loads(SCHEMA_PATH.read_text())
    validator = jsonschema.Draft202012Validator(schema)
    docs = [json.loads(p.read_text()) for p in sorted(EXAMPLES.glob("*.json"))]
    for name in ("arm.pt", "arm_position.pt"):
        docs.append(
            json.loads(torch.load(REPO / "sim2real" / "policies" / name, weights_only=True)["spec"])
        )
    docs.append(json.loads(PolicySpec.for_robot(arm6).to_json()))
    assert len(docs) == 5
    for doc in docs:
        validator.validate(doc)
    bad = dict(docs[0], observation=[{"name": "joint_position", "scale": "pi"}])
    assert not validator.is_valid(bad)
    assert not validator.is_valid(dict(docs[0], observation=[{"name": "base_lin_vel"}]))


def test_the_docs_show_the_example_specs_as_they_are_tested():
    page = (REPO / "docs" / "foreign-policies.md").read_text()
    for path in sorted(EXAMPLES.glob("*.json")):
        assert path.read_text().strip() in page, path.name


# ---------------------------------------------------------------------- the kind registry
def test_every_registered_kind_has_a_kernel_branch_and_a_numpy_writer():
    from sim2real.deploy.spec import kernel
    from sim2real.deploy.spec.kinds import KINDS

    codes = [k.kernel_code for k in KINDS.values() if not k.numpy_only]
    assert sorted(codes) == sorted(kernel.BRANCHES)  # one kind per branch, no branch unused
    # a kind without a branch states why: the motion-tracking blocks, the motion phase (the
    # runtime's motion clock) and the height scan (inputs the kernel does not take) run in numpy
    numpy_only = sorted(k.name for k in KINDS.values() if k.kernel_code is None)
    assert numpy_only == ["height_scan", "motion_anchor_ori_b", "motion_command", "motion_phase"]
    assert all(k.numpy_only for k in KINDS.values() if k.kernel_code is None)
    assert all(callable(k.numpy) and k.units for k in KINDS.values())


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"kernel_code": None}, r"'joint_torque': no kernel_code: every kind runs in the compiled"),
        ({"kernel_code": 999}, r"'joint_torque': kernel_code 999 has no branch"),
        ({"kernel_code": 0}, r"'joint_torque': kernel_code 0 is the code of 'joint_position'"),
        ({"numpy": None}, r"'joint_torque': no numpy writer"),
        ({"name": "joint_velocity"}, r"'joint_velocity': the name is empty or already registered"),
        ({"size": 3}, r"either a fixed size or entries per joint"),
    ],
)
def test_a_kind_without_a_kernel_branch_is_refused_at_registration(changes, message):
    from sim2real.deploy.spec.kinds import KINDS, KindError, ObservationKind, register_kind

    before = dict(KINDS)
    kind = ObservationKind("joint_torque", "N m", lambda *a: None, None, per_joint=1)
    kind = dataclasses.replace(kind, **{"kernel_code": None, **changes})
    with pytest.raises(KindError, match=message):
        register_kind(kind)
    assert KINDS == before  # nothing registered


def test_the_reference_gives_the_kernels_numbers_with_components_in_any_order(go2):
    """``observation_reference`` equals ``observation`` bit for bit, and the kernel runs blocks
    that read some components of their raw vector: holosoma's split command, and two-foot gait
    clocks read as ``[cos p0, cos p1, sin p0, sin p1]`` or with their cos and sin terms apart
    (p1 = p0 + pi), one of them sign-flipped by a negative scale."""
    from sim2real.deploy.spec.policy_spec import ObservationBlock
    from sim2real.deploy.spec.reference import observation_reference

    base = PolicySpec.for_robot(go2)
    assert base.plan.compiled and base.plan.numpy_reason is None
    yaw = ObservationBlock("velocity_command", 1, (0.25,), (0.0,), components=(2,))
    split = dataclasses.replace(base, observation_blocks=(yaw,) + base.observation_blocks)
    clock = ObservationBlock(
        "gait_phase", 4, (1.0,) * 4, (0.0,) * 4, period=0.8, components=(1, 3, 0, 2)
    )
    cos_apart = ObservationBlock(
        "gait_phase", 2, (1.0, -1.0), (0.0,) * 2, period=0.8, components=(1, 3)
    )
    split = dataclasses.replace(
        base, observation_blocks=(yaw, clock) + base.observation_blocks + (cos_apart,)
    )
    split.validate()
    assert split.plan.compiled and split.plan.numpy_reason is None
    rng = np.random.default_rng(2)
    state = RobotState.legged(3, go2.n_joints, go2.n_feet)
    state.q[:] = rng.uniform(go2.position_lower, go2.position_upper, (3, go2.n_joints))
    state.command[:] = rng.uniform(-1.0, 1.0, (3, 3))
    state.clock[:] = rng.uniform(0.0, 10.0, 3)
    goal = np.zeros((3, 3))
    for spec in (base, split):
        np.testing.assert_array_equal(
            spec.observation(state, goal), observation_reference(spec, state, goal)
        )
    obs = split.observation(state, goal)
    np.testing.assert_array_equal(obs[:, 0], (state.command[:, 2] / 0.25).astype(np.float32))
    p = 2 * np.pi * state.clock / 0.8
    two_feet = np.stack([np.cos(p), np.cos(p + np.pi), np.sin(p), np.sin(p + np.pi)], axis=1)
    np.testing.assert_allclose(obs[:, 1:5], two_feet, atol=1e-6)
    np.testing.assert_allclose(obs[:, -2:], np.stack([np.cos(p), np.cos(p)], axis=1), atol=1e-6)
    for bad, message in (((1, 4), "must be in 0..3"), ((0,), None)):
        block = dataclasses.replace(
            cos_apart,
            size=len(bad),
            scale=(1.0,) * len(bad),
            offset=(0.0,) * len(bad),
            components=bad,
        )
        spec = dataclasses.replace(base, observation_blocks=base.observation_blocks + (block,))
        if message is None:
            spec.validate()
        else:
            with pytest.raises(SpecError, match=message):
                spec.validate()
    zero = dataclasses.replace(cos_apart, scale=(1.0, 0.0))
    with pytest.raises(SpecError, match="finite and nonzero"):
        dataclasses.replace(base, observation_blocks=(zero,)).validate()


def test_a_gait_clock_that_stops_round_trips_its_json_and_refuses_bad_values(go2):
    """``stand_below`` and ``stand_phase`` are written only when set (an existing spec's JSON is
    unchanged), read back equal, and refused on another block, negative or not finite."""
    from sim2real.deploy.spec.policy_spec import ObservationBlock

    base = PolicySpec.for_robot(go2)
    assert "stand_below" not in base.to_json() and "stand_phase" not in base.to_json()
    clock = ObservationBlock(
        "gait_phase", 2, (1.0,) * 2, (0.0,) * 2, period=1.0, components=(0, 2),
        stand_below=0.01, stand_phase=np.pi,
    )  # fmt: skip
    spec = dataclasses.replace(base, observation_blocks=(clock,) + base.observation_blocks)
    text = spec.to_json()
    assert json.loads(text)["observation"][0]["stand_below"] == 0.01
    assert PolicySpec.from_json(text) == spec
    command = dataclasses.replace(base.observation_blocks[2], stand_below=0.01)
    assert command.name == "velocity_command"
    for block, message in (
        (command, r"observation\[0\] \('velocity_command'\): stand_below and stand_phase are for"),
        (dataclasses.replace(clock, stand_below=-0.1), r"stand_below must be a command speed"),
        (dataclasses.replace(clock, stand_phase=np.inf), r"stand_phase must be a finite phase"),
    ):
        with pytest.raises(SpecError, match=message):
            dataclasses.replace(base, observation_blocks=(block,)).validate()
    d = json.loads(text)
    d["observation"][0]["stand_below"] = -1
    with pytest.raises(SpecError, match=r"stand_below"):
        PolicySpec.from_json(json.dumps(d), source="spec.json")
