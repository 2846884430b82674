"""OnnxPolicy: loading, verification against the robot, batch-first inference, refusals."""

import dataclasses
import json
import os
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch
from helpers_policies import externalize, linear_onnx, make_spec, torch_out, write_spec

from sim2real.deploy.export import export_policy
from sim2real.deploy.policy.mlp_checkpoint import MLPActor, save_checkpoint
from sim2real.deploy.policy.obs_normalizer import ObservationNormalizer
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.spec.onnx_checks import PolicyLoadError
from sim2real.deploy.spec.policy_spec import PolicySpec
from sim2real.robots import load_robot

RNG = np.random.default_rng(11)


@pytest.fixture(scope="module")
def robot():
    return load_robot("arm3")


@pytest.fixture(scope="module")
def spec(robot):
    return make_spec(robot)


@pytest.fixture(scope="module")
def exported(tmp_path_factory, spec):
    """(onnx path, actor, normalizer) of a tiny exported checkpoint."""
    folder = tmp_path_factory.mktemp("exported")
    torch.manual_seed(0)
    actor = MLPActor(21, 3, hidden=(32, 32)).eval()
    norm = ObservationNormalizer(RNG.normal(0, 0.1, 21), RNG.uniform(0.5, 1.5, 21), 1e-8, 5.0)
    path = export_policy(save_checkpoint(folder / "arm.pt", actor, spec, norm))
    return path, actor, norm


def expected_actions(actor, norm, obs):
    return np.clip(torch_out(actor, norm.normalize(obs)), -1.0, 1.0)


@pytest.fixture()
def foreign(tmp_path):
    """A foreign ONNX file (no metadata, input 'x', output 'y') and its weights."""
    w, b = RNG.normal(0, 0.3, (21, 3)), RNG.normal(0, 0.1, 3)
    path = tmp_path / "foreign.onnx"
    onnx.save(linear_onnx(w, b, input_name="x", output_name="y"), str(path))
    return path, w, b


# ---------------------------------------------------------------------- the normal case
def test_exported_policy_loads_and_matches_torch(exported, robot, spec):
    path, actor, norm = exported
    policy = OnnxPolicy(path, robot)
    assert policy.spec.observation_blocks == spec.observation_blocks
    assert policy.spec.baked == {"observation_normalizer": True, "action_clip": True}
    assert policy.parity["max_abs_error"] <= 1e-5
    assert json.loads(policy.metadata["policy_spec"])["robot"] == "arm3"
    assert set(policy.metadata) >= {"policy_spec", "source_sha256", "tool_versions", "parity"}
    assert (policy.input_name, policy.output_name) == ("obs", "action")
    options = policy.session.get_session_options()
    assert (options.intra_op_num_threads, options.inter_op_num_threads) == (1, 1)
    for envs in (1, 5, 1):
        obs = RNG.uniform(-3, 3, (envs, 21)).astype(np.float32)
        action = policy(obs)
        assert action.shape == (envs, 3) and action.dtype == np.float32
        np.testing.assert_allclose(action, expected_actions(actor, norm, obs), atol=1e-5)


def test_output_buffer_is_reused_until_the_batch_size_changes(exported, robot):
    path, actor, norm = exported
    policy = OnnxPolicy(path, robot)
    a, b = (RNG.uniform(-1, 1, (4, 21)).astype(np.float32) for _ in range(2))
    first = policy(a)
    first_values = first.copy()
    second = policy(b)
    assert second is first  # preallocated, overwritten in place
    np.testing.assert_allclose(second, expected_actions(actor, norm, b), atol=1e-5)
    assert not np.allclose(first_values, second)
    # float64 input is converted; a new batch size rebinds
    single = policy(b[:1].astype(np.float64))
    np.testing.assert_allclose(single, expected_actions(actor, norm, b[:1]), atol=1e-5)


def test_wrong_observation_shape_is_refused(exported, robot):
    policy = OnnxPolicy(exported[0], robot)
    with pytest.raises(ValueError, match=r"obs: expected shape \(envs, 21\), got \(21,\)"):
        policy(np.zeros(21, np.float32))
    with pytest.raises(ValueError, match=r"got \(2, 15\)"):
        policy(np.zeros((2, 15), np.float32))


# ---------------------------------------------------------------------- robot checks
def _with_spec(src: Path, dst: Path, edit) -> Path:
    model = onnx.load(str(src))
    for prop in model.metadata_props:
        if prop.key == "policy_spec":
            d = json.loads(prop.value)
            edit(d)
            prop.value = json.dumps(d)
    onnx.save(model, str(dst))
    return dst


def test_other_robot_is_refused(exported):
    with pytest.raises(
        PolicyLoadError, match=r"arm.onnx: robot: policy is for 'arm3', the robot is 'arm6'"
    ):
        OnnxPolicy(exported[0], load_robot("arm6"))


def test_changed_description_hash_is_refused(exported, robot, tmp_path):
    path = _with_spec(exported[0], tmp_path / "old.onnx", lambda d: d.update(robot_hash="a" * 64))
    with pytest.raises(
        PolicyLoadError, match=r"old.onnx: robot_hash: policy was made for description aaaaaaaaaaaa"
    ):
        OnnxPolicy(path, robot)
    assert OnnxPolicy(path, robot, check_hash=False).spec.robot_hash == "a" * 64


def test_invalid_stored_spec_is_refused(exported, robot, tmp_path):
    path = _with_spec(exported[0], tmp_path / "v2.onnx", lambda d: d.update(format_version=2))
    with pytest.raises(
        PolicyLoadError, match=r"v2.onnx: metadata 'policy_spec': format_version 2 is not supported"
    ):
        OnnxPolicy(path, robot)


def test_spec_passed_in_must_agree_with_the_file(exported, robot, spec):
    other = dataclasses.replace(spec, control_rate=100.0)
    with pytest.raises(
        PolicyLoadError, match=r"differs from the one stored in the file in \['control_rate'\]"
    ):
        OnnxPolicy(exported[0], robot, spec=other)
    assert OnnxPolicy(exported[0], robot, spec=spec).spec.parity  # the stored spec is kept


# ---------------------------------------------------------------------- foreign models
def test_foreign_model_needs_a_spec(foreign, robot, spec, tmp_path):
    path, w, b = foreign
    with pytest.raises(
        PolicyLoadError, match=r"foreign.onnx: no 'policy_spec' metadata .*pass the policy's spec"
    ):
        OnnxPolicy(path, robot)
    obs = RNG.uniform(-1, 1, (3, 21)).astype(np.float32)
    for given in (spec, write_spec(spec, tmp_path / "spec.json"), str(tmp_path / "spec.json")):
        policy = OnnxPolicy(path, robot, spec=given)
        assert (policy.input_name, policy.output_name) == ("x", "y")
        assert policy.metadata == {}
        np.testing.assert_allclose(policy(obs), obs @ w + b, atol=1e-5)


def test_missing_spec_file_is_named(foreign, robot, tmp_path):
    with pytest.raises(PolicyLoadError, match=r"nope.json: cannot read the spec file"):
        OnnxPolicy(foreign[0], robot, spec=tmp_path / "nope.json")


def test_extra_inputs_are_refused_by_name(robot, spec, tmp_path):
    path = tmp_path / "lstm.onnx"
    model = linear_onnx(RNG.normal(size=(21, 3)), np.zeros(3), extra_inputs=("h_in", "c_in"))
    onnx.save(model, str(path))
    with pytest.raises(
        PolicyLoadError,
        # no 'h_out' / 'c_out' outputs: not recurrent state, refused by name and shape
        match=r"lstm.onnx: the graph has extra input\(s\) 'h_in' \[.*\], 'c_in' \[.*\] besides "
        r"the observation 'obs'.*'<name>_in'",
    ):
        OnnxPolicy(path, robot, spec=spec)


@pytest.mark.parametrize(
    ("shape", "message"),
    [
        ((17, 3), r"graph input 'obs' has size 17, the spec's observation has 21"),
        ((21, 4), r"graph output 'action' has size 4, the spec's action has 3"),
    ],
)
def test_wrong_sizes_are_refused(robot, spec, tmp_path, shape, message):
    path = tmp_path / "sized.onnx"
    onnx.save(linear_onnx(RNG.normal(size=shape), np.zeros(shape[1])), str(path))
    with pytest.raises(PolicyLoadError, match=r"sized.onnx: " + message):
        OnnxPolicy(path, robot, spec=spec)


# ---------------------------------------------------------------------- damaged or unsafe files
def test_truncated_corrupt_and_empty_files_are_refused(exported, robot, tmp_path):
    data = exported[0].read_bytes()
    (tmp_path / "cut.onnx").write_bytes(data[: len(data) // 2])
    (tmp_path / "noise.onnx").write_bytes(os.urandom(4096))
    (tmp_path / "empty.onnx").write_bytes(b"")
    for name, message in (
        ("cut.onnx", r"cut.onnx: (not a valid ONNX file \(truncated or corrupt\?\)|the ONNX)"),
        ("noise.onnx", r"noise.onnx: (not a valid ONNX file|the ONNX model has no graph)"),
        ("empty.onnx", r"empty.onnx: the file is empty"),
        ("missing.onnx", r"missing.onnx: no such file"),
    ):
        with pytest.raises(PolicyLoadError, match=message):
            OnnxPolicy(tmp_path / name, robot)


def test_non_finite_initializer_is_refused(robot, spec, tmp_path):
    w = RNG.normal(size=(21, 3))
    w[4, 1] = np.nan
    path = tmp_path / "nan.onnx"
    onnx.save(linear_onnx(w, np.zeros(3)), str(path))
    with pytest.raises(
        PolicyLoadError, match=r"nan.onnx: initializer 'W' holds 1 non-finite value"
    ):
        OnnxPolicy(path, robot, spec=spec)


@pytest.mark.parametrize(
    ("location", "message"),
    [
        ("/etc/weights.bin", r"absolute path \('/etc/weights.bin'\)"),
        ("../outside.bin", r"outside the model's folder \('../outside.bin' resolves to"),
        ("sub/../../outside.bin", r"outside the model's folder"),
        ("link.bin", r"outside the model's folder \('link.bin' resolves to"),
        ("absent.bin", r"external data file 'absent.bin' is missing"),
    ],
)
def test_external_data_outside_the_folder_is_refused(robot, spec, tmp_path, location, message):
    model_dir = tmp_path / "model"
    model_dir.mkdir()
    outside = tmp_path / "outside.bin"
    model = linear_onnx(RNG.normal(size=(21, 3)), np.zeros(3))
    externalize(model, "W", location, outside)
    (model_dir / "link.bin").symlink_to(outside)
    path = model_dir / "policy.onnx"
    onnx.save(model, str(path))
    with pytest.raises(PolicyLoadError, match=r"policy.onnx: initializer 'W'.*" + message):
        OnnxPolicy(path, robot, spec=spec)


def test_external_data_inside_the_folder_is_accepted(robot, spec, tmp_path):
    w = RNG.normal(size=(21, 3))
    model = linear_onnx(w, np.zeros(3))
    externalize(model, "W", "weights/w.bin", tmp_path / "weights" / "w.bin")
    path = tmp_path / "policy.onnx"
    onnx.save(model, str(path))
    policy = OnnxPolicy(path, robot, spec=spec)
    obs = RNG.uniform(-1, 1, (2, 21)).astype(np.float32)
    np.testing.assert_allclose(policy(obs), obs @ w, atol=1e-5)


def test_errors_are_value_errors():
    assert issubclass(PolicyLoadError, ValueError)


# ---------------------------------------------------------------------- files already exported
def test_shipped_arm_policy_loads_and_gives_the_actions_of_its_stored_spec(robot, tmp_path):
    """policies/arm.onnx as ``make export`` writes it (exported here from sim2real/policies/arm.pt when
    absent, as in a fresh clone): its stored spec (explicit scale/offset lists, written before
    the JSON shorthands existed) gives the observation ``(raw - offset) / scale`` clipped, entry
    for entry, and OnnxPolicy's actions are plain ONNX Runtime's, bit for bit."""
    import onnxruntime as ort

    from sim2real.deploy.core.state import Kinematics, RobotState

    root = Path(__file__).resolve().parent.parent / "sim2real" / "policies"
    path = root / "arm.onnx"
    if not path.is_file():
        (tmp_path / "arm.pt").write_bytes((root / "arm.pt").read_bytes())
        path = export_policy(tmp_path / "arm.pt")
    policy = OnnxPolicy(path, robot)
    stored = {p.key: p.value for p in onnx.load(str(path)).metadata_props}["policy_spec"]
    assert policy.spec.to_json() == stored
    blocks = json.loads(stored)["observation"]
    assert [b["name"] for b in blocks] == [b.name for b in policy.spec.observation_blocks]

    rng = np.random.default_rng(5)
    envs = 16
    state = RobotState.zeros(envs, 3, 25.0)
    state.q[:] = rng.uniform(-1.5, 1.5, (envs, 3))
    state.dq[:] = rng.uniform(-4, 4, (envs, 3))
    Kinematics(robot).update(state)
    goal = rng.uniform(-0.9, 0.9, (envs, 3))
    raw = {
        "joint_position": state.q,
        "joint_velocity": state.dq,
        "ee_position": state.ee_position,
        "goal_position": goal,
        "goal_in_ee": np.einsum("ei,eij->ej", goal - state.ee_position, state.ee_rotation),
    }
    expected = np.concatenate(
        [
            np.clip(
                (raw[b["name"]] - np.array(b["offset"])) / np.array(b["scale"]),
                -b["clip"],
                b["clip"],
            )
            for b in blocks
        ],
        axis=1,
    ).astype(np.float32)
    obs = policy.spec.observation(state, goal)
    np.testing.assert_allclose(obs, expected, rtol=1e-6, atol=1e-7)
    plain = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    np.testing.assert_array_equal(policy(obs), plain.run(None, {policy.input_name: obs})[0])


def test_adversarial_nan_seed_probe_finds_the_seed_of_the_one_by_one_search(monkeypatch):
    """``adversarial_model`` probes many NaN-stream seeds per ONNX Runtime session: it finds the
    seed that building and probing the whole model for every candidate finds (here with a NaN
    probability that puts it about 20 candidates on, and 8 candidates a session so the search
    crosses sessions)."""
    import onnxruntime as ort

    from sim2real.deploy.policy import adversarial

    spec = PolicySpec.for_robot(load_robot("arm3"), mode="position", position_range="hard")
    p, obs = 4.5e-4, {"obs": np.zeros((1, spec.obs_dim), np.float32)}
    one_by_one = 1.0
    while True:
        model = adversarial._build(spec, p, 0.0, one_by_one, "uniform")
        if np.isfinite(ort.InferenceSession(model.SerializeToString()).run(None, obs)[0]).all():
            break
        one_by_one += 1.0
    assert one_by_one > 8.0  # the search crossed at least one session
    monkeypatch.setattr(adversarial, "PROBE_SEEDS", 8)
    assert adversarial._first_finite_nan_seed(spec.act_dim, p, 1.0) == one_by_one
    model = adversarial.adversarial_model(spec, p, 0.0)
    expected = adversarial._build(spec, p, 0.0, one_by_one, "uniform")
    assert model.SerializeToString() == expected.SerializeToString()
