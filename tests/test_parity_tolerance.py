"""The parity gate judges against what float32 can reach: its tolerance is max(1e-5, 4 x the
source's float32 noise floor), the floor measured by a float64 copy of the source on the same
observations; ``--parity-tolerance`` sets it; a candidate that fails is kept under
``<stem>.parity-failed.onnx`` and nothing is written under the real name."""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import onnx
import pytest
import torch
from helpers_policies import folder, make_spec, write_spec
from onnx import numpy_helper
from torch import nn

from sim2real.deploy.cli.policy_export import main
from sim2real.deploy.export import pipeline as export_pipeline
from sim2real.deploy.export.noise_floor import NOISE_MULTIPLIER, TOLERANCE, float64_twin
from sim2real.deploy.policy.onnx_policy import OnnxPolicy

pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit:FutureWarning")

#: Large enough that no action of the wide network below is clipped.
WIDE_CLIP = 1e5


class WideNet(nn.Module):
    """Linear-Tanh-Linear with a large output layer: actions of some thousands, whose float32
    rounding is far above 1e-5 (float32 keeps about 7 significant digits)."""

    def __init__(self, obs_dim: int = 21, act_dim: int = 3, hidden: int = 64, gain: float = 3e3):
        super().__init__()
        torch.manual_seed(3)
        self.body = nn.Sequential(nn.Linear(obs_dim, hidden), nn.Tanh())
        self.head = nn.Linear(hidden, act_dim)
        with torch.no_grad():
            self.head.weight.mul_(gain)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.head(self.body(obs))


class Float32Net(WideNet):
    """The same network, but its code computes in float32 whatever its weights are."""

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        w, b = self.head.weight.float(), self.head.bias.float()
        body = self.body[1](
            obs.float() @ self.body[0].weight.float().t() + self.body[0].bias.float()
        )
        return body @ w.t() + b


@pytest.fixture(scope="module")
def wide(arm3, tmp_path_factory):
    """(TorchScript file, spec file) of the wide network for arm3, action clip ``WIDE_CLIP``."""
    tmp = tmp_path_factory.mktemp("wide")
    spec = make_spec(arm3)
    spec = dataclasses.replace(spec, action=dataclasses.replace(spec.action, clip=WIDE_CLIP))
    src = tmp / "wide.pt"
    torch.jit.script(WideNet().eval()).save(str(src))
    return src, write_spec(spec, tmp / "wide.spec.json")


def float32_floor(net: nn.Module, obs_dim: int = 21) -> float:
    obs = torch.from_numpy(np.random.default_rng(0).uniform(-1.2, 1.2, (2000, obs_dim)))
    with torch.no_grad():
        f32 = net(obs.float()).double()
        f64 = nn.Module.double(net)(obs)
    return float((f32 - f64).abs().max())


def test_the_wide_network_rounds_above_the_absolute_tolerance():
    """The premise of the tests below: float32 alone moves this network's actions by more
    than 1e-5."""
    assert float32_floor(WideNet().eval()) > TOLERANCE


def test_a_network_whose_float32_floor_is_above_1e_5_passes_on_its_relative_tolerance(
    wide, tmp_path, capsys, arm3
):
    src, spec = wide
    out = tmp_path / "wide.onnx"
    assert main([str(src), "--spec", str(spec), "--out", str(out)]) == 0
    stdout = capsys.readouterr().out
    m = re.search(
        r"tolerance (\S+) = 4 x the float32 noise floor (\S+)", stdout
    )  # the message names both
    assert m, stdout
    tolerance, floor = float(m.group(1)), float(m.group(2))
    assert floor > TOLERANCE and tolerance == pytest.approx(NOISE_MULTIPLIER * floor, rel=1e-2)
    parity = OnnxPolicy(out, arm3).parity
    assert parity["tolerance_basis"] == "relative" and parity["passed"] is True
    assert parity["noise_floor"] > TOLERANCE
    assert parity["tolerance"] == NOISE_MULTIPLIER * parity["noise_floor"]
    assert TOLERANCE < parity["max_abs_error"] <= parity["tolerance"]


def _perturbing_exporter(monkeypatch, delta: float) -> None:
    """Make the export's graph wrong: ``delta`` added to one weight of the first layer."""
    real = export_pipeline.to_onnx

    def perturbed(module, obs_dim, exporter="torchscript"):
        model = real(module, obs_dim, exporter)
        init = max(model.graph.initializer, key=lambda t: int(np.prod(t.dims)))
        w = numpy_helper.to_array(init).copy()
        w.flat[0] += delta
        init.CopyFrom(numpy_helper.from_array(w, init.name))
        return model

    monkeypatch.setattr(export_pipeline, "to_onnx", perturbed)


def test_a_wrong_export_fails_and_is_kept_under_a_failed_name(wide, tmp_path, capsys, monkeypatch):
    src, spec = wide
    out = tmp_path / "wide.onnx"
    _perturbing_exporter(monkeypatch, 1e-2)
    assert main([str(src), "--spec", str(spec), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    kept = tmp_path / "wide.parity-failed.onnx"
    assert folder(tmp_path) == {"wide.parity-failed.onnx"}  # nothing under the real name
    assert "parity check FAILED" in err and f"the candidate kept as {kept}" in err
    assert re.search(r"tolerance \S+ = 4 x the float32 noise floor \S+", err), err
    meta = {p.key: p.value for p in onnx.load(str(kept)).metadata_props}
    figures = json.loads(meta["parity"])
    assert figures["passed"] is False and figures["max_abs_error"] > figures["tolerance"]

    # --parity-tolerance accepts it; the stale failed candidate goes
    assert (
        main([str(src), "--spec", str(spec), "--out", str(out), "--parity-tolerance", "1e3"]) == 0
    )
    stdout = capsys.readouterr().out
    assert "from --parity-tolerance, float32 noise floor" in stdout
    assert folder(tmp_path) == {"wide.onnx"}
    assert (
        json.loads({p.key: p.value for p in onnx.load(str(out)).metadata_props}["parity"])[
            "tolerance_basis"
        ]
        == "explicit"
    )


@pytest.mark.parametrize("value", ["0", "-1e-5", "nan"])
def test_a_parity_tolerance_that_is_not_a_positive_number_is_bad_input(
    wide, tmp_path, capsys, value
):
    src, spec = wide
    args = [str(src), "--spec", str(spec), "--out", str(tmp_path / "x.onnx")]
    assert main([*args, f"--parity-tolerance={value}"]) == 2
    assert "--parity-tolerance: expected a finite number > 0" in capsys.readouterr().err
    assert folder(tmp_path) == set()


def test_a_source_that_cannot_run_in_float64_keeps_the_absolute_tolerance_and_says_so(
    arm3, tmp_path, capsys
):
    net = Float32Net(gain=1.0).eval()
    scripted = torch.jit.script(net)
    twin, why = float64_twin(scripted, recurrent=False, obs_dim=21)
    assert twin is None and "cannot run in float64" in why
    src = tmp_path / "f32.pt"
    scripted.save(str(src))
    spec = write_spec(make_spec(arm3), tmp_path / "spec.json")
    assert main([str(src), "--spec", str(spec)]) == 0
    stdout = capsys.readouterr().out
    assert "tolerance 1.00e-05, absolute: the source cannot run in float64" in stdout
