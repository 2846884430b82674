"""rl_sar ships its policies as TorchScript (``policy/go2w/robot_lab/policy.pt``, model_name in
config.yaml; its C++ runs ``torch::jit::load`` on one (1, n) observation): ``policy-export
policy.pt`` exports it with the folder's own contract (sim2real/deploy/export/folder_torchscript.py)
and ``robot-import --drive-from policy.pt`` reads the drive from the same files. The folder is
rl_sar's Go2-W layout (tests/test_rl_sar_contract.py writes its base.yaml and config.yaml); the
TorchScript is written as Isaac Lab's policy exporter writes the file rl_sar ships (an ``actor``
``nn.Sequential`` behind an identity ``normalizer``, ``torch.jit.script`` then ``torch.jit.save``;
``torch.jit.trace`` as legged_gym's exporters do)."""

from __future__ import annotations

import json

import numpy as np
import onnx
import pytest
import torch
import yaml
from torch import nn

from sim2real.deploy.cli.policy_export import main as policy_export
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.robots import load_robot
from tests.test_rl_sar_contract import base_yaml, config_yaml

OBS, ACT = 57, 16  # rl_sar go2w/robot_lab: num_observations 57, 16 joints (12 legs, 4 wheels)


class PolicyExporter(nn.Module):
    """An rsl_rl actor as Isaac Lab's exporter wraps it: ``normalizer`` then ``actor``."""

    def __init__(self, obs_dim: int = OBS, seed: int = 3, gain: float = 1.0):
        super().__init__()
        g = torch.Generator().manual_seed(seed)
        self.actor = nn.Sequential(
            nn.Linear(obs_dim, 32), nn.ELU(), nn.Linear(32, 32), nn.ELU(), nn.Linear(32, ACT)
        )
        self.normalizer = nn.Identity()
        with torch.no_grad():
            for p in self.actor.parameters():
                p.copy_(0.3 * torch.randn(p.shape, generator=g))
            self.actor[-1].weight.mul_(gain)
            self.actor[-1].bias.mul_(gain)

    def forward(self, x):
        return self.actor(self.normalizer(x))


class WithHidden(nn.Module):
    """A forward that takes a second tensor (a memory's state), as no contract gives it."""

    def __init__(self):
        super().__init__()
        self.actor = nn.Linear(OBS + 8, ACT)

    def forward(self, obs, hidden):
        return self.actor(torch.cat([obs, hidden], dim=-1))


def write_folder(tmp_path, module: nn.Module, how: str = "script", **changes):
    """rl_sar's ``policy/go2w/{base.yaml, robot_lab/config.yaml, robot_lab/policy.pt}``."""
    folder = tmp_path / "policy" / "go2w"
    (folder / "robot_lab").mkdir(parents=True)
    (folder / "base.yaml").write_text(yaml.safe_dump(base_yaml(), default_flow_style=None))
    cfg = config_yaml(**changes)
    (folder / "robot_lab" / "config.yaml").write_text(yaml.safe_dump(cfg, default_flow_style=None))
    module = module.eval()
    if how == "script":
        ts = torch.jit.script(module)
    else:
        ts = torch.jit.trace(module, torch.zeros(1, OBS))
    path = folder / "robot_lab" / "policy.pt"
    torch.jit.save(ts, str(path))
    return path


@pytest.mark.parametrize("how", ["script", "trace"])
def test_policy_export_writes_rl_sars_torchscript_as_the_bare_graph_its_contract_reads(
    tmp_path, capsys, how
):
    """No --spec, no --trust-pickle: the bare ``obs`` (1, 57) -> ``actions`` (1, 16) graph beside
    config.yaml, parity passed, no policy_spec in it; the runtime reads it through the folder's
    rl_sar contract and answers as the TorchScript does; --inspect reports the contract."""
    module = PolicyExporter()
    source = write_folder(tmp_path, module, how)
    assert policy_export([str(source)]) == 0, capsys.readouterr().err
    printed = capsys.readouterr().out
    out = source.with_suffix(".onnx")
    assert f"-> {out}" in printed and "rl_sar contract" in printed
    model = onnx.load(str(out))
    dims = [[d.dim_value for d in v.type.tensor_type.shape.dim] for v in model.graph.input]
    assert [i.name for i in model.graph.input] == ["obs"] and dims == [[1, OBS]]
    assert [o.name for o in model.graph.output] == ["actions"]
    meta = {p.key: p.value for p in model.metadata_props}
    assert "policy_spec" not in meta and meta["source_format"] == "torchscript (rl_sar contract)"
    parity = json.loads(meta["parity"])
    assert parity["passed"] and parity["samples"] > 1000
    assert parity["max_abs_error"] <= parity["tolerance"]

    go2w = load_robot("go2w")
    policy = OnnxPolicy(out, go2w)
    assert policy.foreign is not None and policy.foreign.format == "rl_sar"
    obs = np.random.default_rng(1).uniform(-1, 1, (1, OBS)).astype(np.float32)
    policy(obs)
    with torch.no_grad():
        expected = module(torch.from_numpy(obs)).numpy()
    np.testing.assert_allclose(policy.graph_action, expected, rtol=0, atol=1e-5)

    assert policy_export([str(out), "--inspect"]) == 0
    assert "foreign contract: rl_sar" in capsys.readouterr().out


def test_deploy_run_drives_the_go2w_from_the_exported_torchscript(tmp_path, capsys):
    """The exported file runs in deploy-run with no --spec (the contract beside it)."""
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    source = write_folder(tmp_path, PolicyExporter(seed=5, gain=1e-3))  # stands at default
    assert policy_export([str(source)]) == 0
    capsys.readouterr()
    args = ["--robot", "go2w", "--policy", str(source.with_suffix(".onnx")), "--backend", "sim"]
    code = deploy_run_main([*args, "--duration", "1", "--command", "0,0,0"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "rl_sar policy: spec built from" in err


def test_a_module_the_contracts_observation_does_not_run_is_refused_in_one_line(tmp_path, capsys):
    """A forward of two tensors, or an actor of 45 inputs in a folder whose contract gives 57:
    exit 2, one line naming the file and what it takes; nothing written."""
    source = write_folder(tmp_path / "a", WithHidden())
    assert policy_export([str(source)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and str(source) in err
    assert "its forward takes (obs: Tensor, hidden: Tensor)" in err and "(1, 57)" in err
    assert not source.with_suffix(".onnx").exists()

    source = write_folder(tmp_path / "b", PolicyExporter(obs_dim=45), how="script")
    assert policy_export([str(source)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and str(source) in err
    assert "'actor.0.weight' takes 45 inputs" in err and "(1, 57)" in err
    assert not source.with_suffix(".onnx").exists()


def test_robot_import_drive_from_rl_sars_torchscript_reads_its_folder(tmp_path):
    """``robot-import --drive-from policy.pt``: the drive comes from config.yaml and base.yaml
    (no graph needed): kp 20 on the legs, 0 on the wheels, the default pose, 50 Hz, joint by
    joint through rl_sar's joint_mapping and the unitree_go motor slots."""
    from sim2real.deploy.spec.foreign.drive import policy_drive
    from sim2real.robots.importer.unitree import motor_slot

    source = write_folder(tmp_path, PolicyExporter())
    go2w = load_robot("go2w")
    joints = go2w.joint_names
    drive = policy_drive(source, joints, [1] * len(joints), [motor_slot(j) for j in joints])
    assert drive.control_rate == pytest.approx(50.0)
    assert "rl_sar contract" in drive.source
    wheel = ["wheel" in n for n in joints]
    assert drive.kp == tuple(0.0 if w else 20.0 for w in wheel)
    np.testing.assert_allclose(drive.home, go2w.home, atol=1e-12)


def test_inspect_reads_the_rl_sar_folders_contract_as_the_export_does(tmp_path, capsys):
    """``policy-export --inspect policy.pt`` in an rl_sar folder prints the contract the export
    reads beside it (config.yaml, base.yaml), not a request for --spec the export does not need;
    a TorchScript file with no contract beside it is still asked for one."""
    path = write_folder(tmp_path, PolicyExporter())
    assert policy_export([str(path), "--inspect"]) == 0
    out = capsys.readouterr().out
    assert "--spec" not in out, out
    assert "foreign contract: rl_sar (from " in out and "config.yaml" in out, out
    assert f"joints: {ACT}, order rl_sar joint_mapping" in out and f"dof_pos [{ACT}] ->" in out, out

    alone = tmp_path / "alone" / "policy.pt"
    alone.parent.mkdir()
    alone.write_bytes(path.read_bytes())
    assert policy_export([str(alone), "--inspect"]) == 0
    assert "policy spec: none (give one with --spec FILE.json)" in capsys.readouterr().out
