"""Checkpoint format and policy-export: every input format, metadata, parity gate, bad input."""

import hashlib
import json
import os
import pickle
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from helpers_policies import (
    NoisyNet,
    PlainNet,
    clip_action,
    folder,
    make_spec,
    torch_out,
    write_spec,
)
from torch import nn

from sim2real.deploy import export as export_module
from sim2real.deploy.cli import policy_export as export_cli
from sim2real.deploy.cli.policy_export import main
from sim2real.deploy.export import ExportError, ParityError, export_policy, run_export
from sim2real.deploy.policy.mlp_checkpoint import (
    FORMAT,
    MLPActor,
    load_checkpoint,
    read_checkpoint,
    save_checkpoint,
)
from sim2real.deploy.policy.obs_normalizer import ObservationNormalizer
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.policy.onnx_spec import spec_differences
from sim2real.deploy.policy.torch_file import CheckpointError
from sim2real.deploy.spec.policy_spec import PolicySpec

REPO = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit:FutureWarning")
RNG = np.random.default_rng(7)


@pytest.fixture(scope="module")
def spec(arm3):
    return make_spec(arm3)  # obs 21, act 3


@pytest.fixture(scope="module")
def normalizer():
    return ObservationNormalizer(
        mean=RNG.normal(0.0, 0.2, 21), var=RNG.uniform(0.05, 2.0, 21), epsilon=1e-8, clip=5.0
    )


def make_actor(seed=0, obs_dim=21, act_dim=3, **kw):
    torch.manual_seed(seed)
    actor = MLPActor(obs_dim, act_dim, hidden=kw.pop("hidden", (32, 32)), **kw)
    with torch.no_grad():  # larger weights so the action clip is exercised
        [m for m in actor.net if isinstance(m, nn.Linear)][-1].weight.mul_(8.0)
    return actor.eval()


def observations(n=64, scale=2.0):
    return RNG.uniform(-scale, scale, (n, 21)).astype(np.float32)


def run_onnx(path, obs):
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return sess.run(["action"], {"obs": obs})[0]


def assert_exported(path, spec, source, normalized):
    """The file is a valid ONNX model with the full contract in its metadata."""
    model = onnx.load(str(path))
    onnx.checker.check_model(model, full_check=True)
    assert model.opset_import[0].version == export_module.OPSET
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    (inp,), (out,) = sess.get_inputs(), sess.get_outputs()
    assert (inp.name, inp.type, inp.shape) == ("obs", "tensor(float)", ["batch", 21])
    assert (out.name, out.type, out.shape) == ("action", "tensor(float)", ["batch", 3])
    meta = sess.get_modelmeta().custom_metadata_map
    stored = PolicySpec.from_json(meta["policy_spec"])
    assert spec_differences(stored, spec) == []
    assert stored.baked == {"observation_normalizer": normalized, "action_clip": True}
    parity = stored.parity
    assert parity == json.loads(meta["parity"])
    assert parity["max_abs_error"] <= 1e-5 and parity["replay_max_abs_error"] <= 1e-5
    assert parity["samples"] >= 1000 and parity["replay_ticks"] == 1000
    assert meta["source_sha256"] == hashlib.sha256(Path(source).read_bytes()).hexdigest()
    assert {"torch", "onnx", "onnxruntime", "sim2real-deploy"} <= set(
        json.loads(meta["tool_versions"])
    )
    return meta


# ---------------------------------------------------------------------- checkpoint format
def test_checkpoint_round_trip(tmp_path, spec, normalizer):
    actor = make_actor(activation="tanh", output="tanh")
    path = save_checkpoint(tmp_path / "run" / "arm.pt", actor, spec, normalizer, info={"steps": 5})
    assert folder(path.parent) == {"arm.pt"}  # no temporary file left behind
    raw = torch.load(path, weights_only=True)
    assert raw["format"] == FORMAT and raw["format_version"] == 1
    assert raw["architecture"] == {
        "obs_dim": 21,
        "act_dim": 3,
        "hidden": [32, 32],
        "activation": "tanh",
        "output": "tanh",
    }
    assert PolicySpec.from_json(raw["spec"]) == spec
    loaded, loaded_spec, loaded_norm = load_checkpoint(path)
    assert loaded_spec == spec and read_checkpoint(path).info == {"steps": 5}
    obs = observations()
    np.testing.assert_array_equal(torch_out(loaded, obs), torch_out(actor, obs))
    np.testing.assert_array_equal(loaded_norm.normalize(obs), normalizer.normalize(obs))


def test_save_checkpoint_refuses_bad_content(tmp_path, spec):
    with pytest.raises(CheckpointError, match=r"the actor maps 17 -> 3, the spec 21 -> 3"):
        save_checkpoint(tmp_path / "a.pt", MLPActor(17, 3), spec)
    actor = make_actor()
    with torch.no_grad():
        actor.net[0].weight[0, 0] = float("nan")
    with pytest.raises(CheckpointError, match=r"'net.0.weight'.*non-finite"):
        save_checkpoint(tmp_path / "a.pt", actor, spec)
    with pytest.raises(CheckpointError, match=r"info.run: object is not plain data"):
        save_checkpoint(tmp_path / "a.pt", make_actor(), spec, info={"run": object()})
    assert folder(tmp_path) == set()


def _checkpoint_dict(the_spec, **changes):
    actor = make_actor()
    d = {
        "format": FORMAT,
        "format_version": 1,
        "architecture": actor.architecture,
        "state_dict": actor.state_dict(),
        "spec": the_spec.to_json(),
        "obs_normalizer": None,
    }
    d.update(changes)
    return d


def _nan_state(spec):
    sd = make_actor().state_dict()
    sd["net.2.bias"][1] = float("inf")
    return sd


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"format": "other"}, r"field 'format' is 'other'"),
        ({"format_version": 2}, r"field 'format_version' is 2"),
        ({"architecture": {"obs_dim": 21}}, r"field 'architecture'.act_dim: missing"),
        ({"spec": "{}"}, r"field 'spec': format_version None is not supported"),
        ({"state_dict": {}}, r"field 'state_dict' does not match the architecture"),
        ("nan", r"field 'state_dict'\['net.2.bias'\]: 1 non-finite"),
        ({"obs_normalizer": {"mean": torch.zeros(21)}}, r"field 'obs_normalizer'.var: missing"),
    ],
)
def test_load_checkpoint_names_file_and_field(tmp_path, spec, changes, message):
    if changes == "nan":
        changes = {"state_dict": _nan_state(spec)}
    path = tmp_path / "bad.pt"
    torch.save(_checkpoint_dict(spec, **changes), path)
    with pytest.raises(CheckpointError, match=str(path).replace(".", r"\.") + ".*" + message):
        load_checkpoint(path)


def test_load_checkpoint_refuses_damaged_and_pickled_files(tmp_path, spec):
    good = save_checkpoint(tmp_path / "good.pt", make_actor(), spec)
    (tmp_path / "cut.pt").write_bytes(good.read_bytes()[:700])
    with pytest.raises(CheckpointError, match=r"cut.pt: not a readable torch file \(truncated"):
        load_checkpoint(tmp_path / "cut.pt")
    torch.save(PlainNet(), tmp_path / "module.pt")
    with pytest.raises(CheckpointError, match=r"module.pt: holds pickled Python objects"):
        load_checkpoint(tmp_path / "module.pt")
    with pytest.raises(CheckpointError, match=r"missing.pt: no such file"):
        load_checkpoint(tmp_path / "missing.pt")


# ---------------------------------------------------------------------- every input format
def test_export_our_checkpoint_with_normalizer(tmp_path, spec, normalizer):
    actor = make_actor()
    src = save_checkpoint(tmp_path / "arm.pt", actor, spec, normalizer)
    out = export_policy(src)
    assert out == tmp_path / "arm.onnx"
    assert folder(tmp_path) == {"arm.pt", "arm.onnx"}
    meta = assert_exported(out, spec, src, normalized=True)
    assert meta["source_format"] == "checkpoint"
    obs = observations(scale=6.0)  # beyond the normalizer clip too
    expected = clip_action(torch_out(actor, normalizer.normalize(obs)))
    np.testing.assert_allclose(run_onnx(out, obs), expected, atol=1e-5)
    np.testing.assert_allclose(run_onnx(out, obs[:1]), expected[:1], atol=1e-5)  # batch 1


def test_export_torchscript_with_spec_file(tmp_path, spec):
    torch.manual_seed(1)
    net = PlainNet()
    src = tmp_path / "ts.pt"
    torch.jit.save(torch.jit.script(net), str(src))
    spec_file = write_spec(spec, tmp_path / "spec.json")
    out = export_policy(src, spec=spec_file, out=tmp_path / "exported.onnx")
    meta = assert_exported(out, spec, src, normalized=False)
    assert meta["source_format"] == "torchscript"
    obs = observations()
    np.testing.assert_allclose(run_onnx(out, obs), clip_action(torch_out(net, obs)), atol=1e-5)


class _Env:
    """A tiny gymnasium env with the spec's sizes (never stepped: the models are not trained)."""

    @staticmethod
    def make():
        import gymnasium as gym

        class Env(gym.Env):
            observation_space = gym.spaces.Box(-np.inf, np.inf, (21,), np.float32)
            action_space = gym.spaces.Box(-1.0, 1.0, (3,), np.float32)

            def reset(self, seed=None, options=None):
                return np.zeros(21, np.float32), {}

            def step(self, action):
                return np.zeros(21, np.float32), 0.0, False, False, {}

        return Env()


@pytest.fixture(scope="module")
def sb3_models(tmp_path_factory):
    from stable_baselines3 import PPO, SAC

    folder_ = tmp_path_factory.mktemp("sb3")
    ppo = PPO(
        "MlpPolicy",
        _Env.make(),
        n_steps=8,
        batch_size=8,
        seed=0,
        device="cpu",
        policy_kwargs={"net_arch": {"pi": [32, 32], "vf": [16]}},
    )
    sac = SAC(
        "MlpPolicy",
        _Env.make(),
        buffer_size=10,
        seed=0,
        device="cpu",
        policy_kwargs={"net_arch": [32, 32], "activation_fn": nn.ELU},
    )
    ppo.save(folder_ / "ppo.zip")
    sac.save(folder_ / "sac.zip")
    return {"ppo": (ppo, folder_ / "ppo.zip"), "sac": (sac, folder_ / "sac.zip")}


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_export_sb3_zip_matches_sb3_predict(tmp_path, spec, sb3_models, algo):
    model, zip_path = sb3_models[algo]
    src = tmp_path / zip_path.name
    src.write_bytes(zip_path.read_bytes())
    out = export_policy(src, spec=write_spec(spec, tmp_path / "spec.json"))
    meta = assert_exported(out, spec, src, normalized=False)
    assert meta["source_format"] == f"sb3-{algo}"
    obs = observations()
    expected, _ = model.predict(obs, deterministic=True)
    np.testing.assert_allclose(run_onnx(out, obs), expected, atol=1e-5)


def test_export_sb3_with_vecnormalize_npz_and_pickle(tmp_path, spec, sb3_models, normalizer):
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    model, zip_path = sb3_models["ppo"]
    src = tmp_path / "ppo.zip"
    src.write_bytes(zip_path.read_bytes())
    spec_file = write_spec(spec, tmp_path / "spec.json")
    vn = VecNormalize(DummyVecEnv([_Env.make]), clip_obs=5.0)
    vn.obs_rms.mean = normalizer.mean.numpy().copy()
    vn.obs_rms.var = normalizer.var.numpy().copy()
    obs = observations(scale=6.0)
    expected, _ = model.predict(vn.normalize_obs(obs), deterministic=True)

    stats = tmp_path / "vecnormalize.npz"
    np.savez(
        stats, mean=vn.obs_rms.mean, var=vn.obs_rms.var, clip_obs=vn.clip_obs, epsilon=vn.epsilon
    )
    out = export_policy(src, spec=spec_file, vecnormalize=stats)
    assert_exported(out, spec, src, normalized=True)
    np.testing.assert_allclose(run_onnx(out, obs), expected, atol=1e-5)

    pkl = tmp_path / "vecnormalize.pkl"
    vn.save(str(pkl))
    out.unlink()
    with pytest.raises(ExportError, match=r"vecnormalize.pkl: .*pickle.*--trust-pickle"):
        export_policy(src, spec=spec_file, vecnormalize=pkl)
    assert not out.exists()
    out = export_policy(src, spec=spec_file, vecnormalize=pkl, trust_pickle=True)
    np.testing.assert_allclose(run_onnx(out, obs), expected, atol=1e-5)


def _rsl_rl_checkpoint(path, v3=False, poison=False):
    """What rsl_rl's OnPolicyRunner.save writes: actor-critic state dict, optimizer, iteration,
    and the EmpiricalNormalization buffers (_mean, _var, _std, count), shaped (1, obs_dim)."""
    torch.manual_seed(2)
    actor = nn.Sequential(
        nn.Linear(21, 32), nn.ELU(), nn.Linear(32, 32), nn.ELU(), nn.Linear(32, 3)
    )
    critic = nn.Sequential(nn.Linear(21, 32), nn.ELU(), nn.Linear(32, 1))
    if poison:
        with torch.no_grad():
            actor[2].weight[3, 4] = float("inf")
    msd = {f"actor.{k}": v for k, v in actor.state_dict().items()}
    msd.update({f"critic.{k}": v for k, v in critic.state_dict().items()})
    msd["std"] = torch.ones(3)
    var = torch.rand(1, 21) + 0.1
    norm = {
        "_mean": torch.randn(1, 21),
        "_var": var,
        "_std": var.sqrt(),
        "count": torch.tensor(4096),
    }
    params = [*actor.parameters(), *critic.parameters()]
    saved = {
        "model_state_dict": msd,
        "optimizer_state_dict": torch.optim.Adam(params).state_dict(),
        "iter": 1500,
        "infos": None,
    }
    if v3:
        msd.update({f"actor_obs_normalizer.{k}": v for k, v in norm.items()})
    else:
        saved["obs_norm_state_dict"] = norm
    torch.save(saved, path)
    return actor, norm


@pytest.mark.parametrize("v3", [False, True], ids=["rsl_rl-2", "rsl_rl-3"])
def test_export_rsl_rl_checkpoint(tmp_path, spec, v3):
    src = tmp_path / "model_1500.pt"
    actor, norm = _rsl_rl_checkpoint(src, v3=v3)
    out = export_policy(src, spec=spec)
    meta = assert_exported(out, spec, src, normalized=True)
    assert meta["source_format"] == "rsl_rl"
    obs = observations(scale=4.0)
    normalized = (obs - norm["_mean"].numpy()) / (norm["_std"].numpy() + 1e-2)  # rsl_rl's eps
    np.testing.assert_allclose(
        run_onnx(out, obs), clip_action(torch_out(actor, normalized)), atol=1e-5
    )


def test_pickled_module_needs_trust(tmp_path, spec):
    torch.manual_seed(3)
    net = PlainNet()
    src = tmp_path / "module.pt"
    torch.save(net, src)
    with pytest.raises(
        ExportError, match=r"module.pt: holds a pickled Python object .*--trust-pickle"
    ):
        export_policy(src, spec=spec)
    assert folder(tmp_path) == {"module.pt"}
    out = export_policy(src, spec=spec, trust_pickle=True)
    assert assert_exported(out, spec, src, normalized=False)["source_format"] == "pickled-module"
    obs = observations()
    np.testing.assert_allclose(run_onnx(out, obs), clip_action(torch_out(net, obs)), atol=1e-5)


def test_dynamo_exporter(tmp_path, spec, normalizer):
    actor = make_actor(seed=4)
    src = save_checkpoint(tmp_path / "arm.pt", actor, spec, normalizer)
    result = run_export(src, exporter="dynamo")
    assert_exported(result.path, spec, src, normalized=True)
    assert "dynamo=True" in result.exporter
    obs = observations()
    expected = clip_action(torch_out(actor, normalizer.normalize(obs)))
    np.testing.assert_allclose(run_onnx(result.path, obs), expected, atol=1e-5)


# ---------------------------------------------------------------------- the parity gate
def test_parity_failure_writes_nothing(tmp_path, spec, capsys):
    src = tmp_path / "noisy.pt"
    torch.save(NoisyNet(), src)
    previous = tmp_path / "noisy.onnx"
    previous.write_bytes(b"an older export")
    with pytest.raises(ParityError, match=r"noisy.pt: ONNX and torch disagree") as info:
        export_policy(src, spec=spec, trust_pickle=True)
    assert info.value.figures["max_abs_error"] > 1e-5
    assert "the candidate kept as" in str(info.value)
    # its noise is not rounding: no float32 noise floor, the absolute tolerance
    assert "tolerance 1.00e-05, absolute: the source answers the same observation differently" in (
        str(info.value)
    )
    # no temporary file; the candidate kept under a failed name
    assert folder(tmp_path) == {"noisy.pt", "noisy.onnx", "noisy.parity-failed.onnx"}
    assert previous.read_bytes() == b"an older export"  # untouched
    spec_file = write_spec(spec, tmp_path / "spec.json")
    assert main([str(src), "--spec", str(spec_file), "--trust-pickle"]) == 1
    assert "parity check FAILED" in capsys.readouterr().err


def test_perturbed_onnx_output_fails_the_gate(tmp_path, spec, monkeypatch, capsys):
    src = save_checkpoint(tmp_path / "arm.pt", make_actor(), spec)
    original = OnnxPolicy.__call__

    def perturbed(self, obs):
        out = original(self, obs)
        out += 2e-5
        return out

    monkeypatch.setattr(OnnxPolicy, "__call__", perturbed)
    assert main([str(src)]) == 1
    err = capsys.readouterr().err
    assert re.search(r"max abs error 2\.\d+e-05 over 1049 observations", err)
    assert "(tolerance 1.00e-05, the least: 4 x the float32 noise floor" in err
    assert folder(tmp_path) == {"arm.pt", "arm.parity-failed.onnx"}


# ---------------------------------------------------------------------- bad input
def _write_bad_inputs(tmp_path, spec):
    """name -> (argv extras, expected message), all files written into tmp_path."""
    good = save_checkpoint(tmp_path / "good.pt", make_actor(), spec)
    (tmp_path / "truncated.pt").write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    # random bytes (seeded; not starting like a zip or a pickle, which os.urandom did 1 time in 256)
    (tmp_path / "corrupt.pt").write_bytes(b"\x13\x37" + RNG.bytes(2046))
    (tmp_path / "empty.pt").write_bytes(b"")
    torch.save(_checkpoint_dict(spec, state_dict=_nan_state(spec)), tmp_path / "nan.pt")
    torch.save(_checkpoint_dict(spec, format_version=9), tmp_path / "version.pt")
    torch.save({"weights": torch.zeros(3)}, tmp_path / "unknown.pt")
    (tmp_path / "exported.onnx").write_bytes(b"onnx")
    _rsl_rl_checkpoint(tmp_path / "rsl_inf.pt", poison=True)
    torch.jit.save(torch.jit.script(PlainNet(obs_dim=17)), str(tmp_path / "ts17.pt"))
    torch.jit.save(torch.jit.script(PlainNet(act_dim=4)), str(tmp_path / "ts_out4.pt"))
    torch.jit.save(torch.jit.script(PlainNet()), str(tmp_path / "ts.pt"))
    spec_file = str(write_spec(spec, tmp_path / "spec.json"))
    stale = json.loads(spec.to_json())
    stale["robot_hash"] = "f" * 64
    (tmp_path / "stale.json").write_text(json.dumps(stale))
    return {
        "missing": (["missing.pt"], r"missing.pt: no such file"),
        "truncated": (["truncated.pt"], r"truncated.pt: not a readable torch file \(truncated"),
        # our words, not torch's advice to pass weights_only=False (which does not apply)
        "corrupt": (
            ["corrupt.pt"],
            r"corrupt.pt: not a torch file: it starts with bytes 13 37 .*, neither a zip archive "
            r".* nor a pickle .*damaged or of another kind$",
        ),
        "empty": (["empty.pt"], r"empty.pt: the file is empty"),
        "nan weights": (["nan.pt"], r"nan.pt: field 'state_dict'\['net.2.bias'\]: 1 non-finite"),
        "format version": (["version.pt"], r"version.pt: field 'format_version' is 9"),
        "unknown dict": (["unknown.pt"], r"unknown.pt: unrecognized content"),
        "rsl_rl inf": (["rsl_inf.pt", "--spec", spec_file], r"rsl_inf.pt: .*non-finite"),
        "input size": (
            ["ts17.pt", "--spec", spec_file],
            r"ts17.pt: wrong input size: the network takes 17 inputs, the spec's observation has 21",
        ),
        "output size": (["ts_out4.pt", "--spec", spec_file], r"ts_out4.pt: wrong output size"),
        "no spec": (
            ["ts.pt"],
            r"ts.pt: a TorchScript module carries no PolicySpec; pass its spec with --spec",
        ),
        "stale hash": (
            ["ts.pt", "--spec", str(tmp_path / "stale.json")],
            r"ts.pt: robot_hash: policy was made for description ffffffffffff",
        ),
        "other robot": (
            ["good.pt", "--robot", "arm6"],
            r"good.pt: robot: policy is for 'arm3', the robot is 'arm6'",
        ),
        "spec mismatch": (
            ["good.pt", "--spec", str(tmp_path / "stale.json")],
            r"good.pt: the checkpoint's spec differs from the --spec given in \['robot_hash'\]",
        ),
        "not a policy": (["spec.json"], r"spec.json: not a torch file: it starts with bytes 7b"),
        "onnx source": (["exported.onnx"], r"exported.onnx: not a valid ONNX file"),
        "no out folder": (
            ["good.pt", "--out", str(tmp_path / "nodir" / "x.onnx")],
            r"nodir/x.onnx: the output folder .*nodir does not exist",
        ),
    }


def test_bad_input_exits_2_naming_the_file_and_writes_nothing(tmp_path, spec, capsys):
    cases = _write_bad_inputs(tmp_path, spec)
    before = folder(tmp_path)
    failures = []
    for name, (argv, message) in cases.items():
        argv = [str(tmp_path / argv[0]), *argv[1:]]
        code = main(argv)
        err = capsys.readouterr().err
        if code != 2 or not re.search(message, err):
            failures.append(f"{name}: exit {code}, stderr {err!r}")
    assert not failures, "\n".join(failures)
    assert folder(tmp_path) == before  # nothing written, no temporary file


# ---------------------------------------------------------------------- the command line
def test_command_line_as_make_export_runs_it(tmp_path, spec, normalizer):
    src = save_checkpoint(tmp_path / "arm.pt", make_actor(), spec, normalizer)
    env = {**os.environ, "ORT_DISABLE_TELEMETRY": "1"}
    # `make export POLICY=...` runs `policy-export $(POLICY)`, i.e. sim2real.deploy.cli.policy_export.main
    proc = subprocess.run(
        [sys.executable, "-m", "sim2real.deploy.cli.policy_export", str(src)],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert "parity: max |onnx - torch|" in proc.stdout and "export time" in proc.stdout
    assert_exported(tmp_path / "arm.onnx", spec, src, normalized=True)


def test_bare_name_is_found_in_policies(tmp_path, spec, monkeypatch, capsys):
    policies = tmp_path / "policies"
    policies.mkdir()
    save_checkpoint(policies / "tiny.pt", make_actor(), spec)
    monkeypatch.setattr(export_cli, "POLICIES_DIR", policies)
    monkeypatch.chdir(tmp_path)
    assert main(["tiny.pt"]) == 0
    assert (policies / "tiny.onnx").is_file()
    assert f"-> {policies / 'tiny.onnx'}" in capsys.readouterr().out


def test_unpickling_is_never_attempted_without_trust(tmp_path, spec, monkeypatch):
    """A malicious pickle must not run: torch.load is only ever called with weights_only=True."""
    src = tmp_path / "evil.pt"
    torch.save(PlainNet(), src)
    calls = []
    real_load = torch.load

    def spy(*args, **kwargs):
        calls.append(kwargs.get("weights_only"))
        return real_load(*args, **kwargs)

    monkeypatch.setattr(torch, "load", spy)
    monkeypatch.setattr(pickle, "load", lambda *a, **k: pytest.fail("pickle.load called"))
    with pytest.raises(ExportError):
        export_policy(src, spec=spec)
    assert calls and all(w is True for w in calls)
