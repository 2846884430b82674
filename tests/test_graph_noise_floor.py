"""The parity gate's noise floor for a module whose code fixes float32 (rl_sar's RoboMimic
``DanceWrapper``: ``torch.zeros(..., dtype=6)``), measured on its exported graph run in float64
(sim2real/deploy/export/graph_twin.py): such a module exports with no ``--parity-tolerance``
where float32 rounding alone is above the absolute 1e-5, and a graph that computes another
function (a wrong weight, swapped outputs) still fails. On files written the way rl_sar writes its
RoboMimic folder (tests/robomimic_files.py); rl_sar's own charleston is exported in
tests/test_motion_phase.py (``stacks``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from onnx import numpy_helper

import sim2real.deploy.export.folder_torchscript as folder_ts
from sim2real.deploy.export.errors import ParityError
from sim2real.deploy.export.graph_twin import GraphTwin
from sim2real.deploy.export.noise_floor import TOLERANCE, float64_twin
from sim2real.deploy.export.torchscript import load_torchscript
from tests.robomimic_files import FRAME, FRAMES, DanceWrapper, write_robomimic_folder

# Every test reads the module fixture: on one pytest-xdist worker (make test's --dist
# loadgroup), which builds it once, not once per worker.
pytestmark = pytest.mark.xdist_group("robomimic_dance")

#: Weights large enough that at the parity's edge cases (+-clip_obs = 100) the actions reach
#: ~1e2 and float32 rounding alone is above the absolute TOLERANCE.
GAIN = 0.3


@pytest.fixture(scope="module")
def dance(tmp_path_factory):
    """A generated RoboMimic folder (weights of ``GAIN``) and its clean export's parity figures."""
    folder = write_robomimic_folder(tmp_path_factory.mktemp("dance"), gain=GAIN)
    return folder / "dance.pt", folder_ts.export_folder_torchscript(folder / "dance.pt").parity


def test_the_generated_module_fixes_float32_as_rl_sars_does(dance):
    source, _ = dance
    twin, why = float64_twin(load_torchscript(source), recurrent=False, obs_dim=FRAME * FRAMES)
    assert twin is None and "cannot run in float64" in why


def test_the_graph_twin_computes_in_float64(dance):
    """The float64 graph answers as the wrapper's own network in float64 does (to 1e-9), its
    float32 run as ONNX Runtime: the floor is float32 against a float64 reference."""
    source, _ = dance
    net = load_torchscript(source).eval()
    twin = GraphTwin(folder_ts.to_bare_onnx(net, FRAME * FRAMES))
    obs = np.random.default_rng(0).uniform(-100, 100, (1, FRAME * FRAMES)).astype(np.float32)
    out32, out64 = twin(obs)
    ref = DanceWrapper(gain=GAIN).double()  # the same seed: the same weights, in float64
    ref.model.double()
    x = torch.from_numpy(obs).double()
    with torch.no_grad():
        want = torch.zeros(1, 29, dtype=torch.float64)
        want[:, ref.idx] = ref.model(_robomimic_obs(ref, x))
    assert out32.dtype == np.float32 and out64.dtype == np.float64
    assert np.abs(out64 - want.numpy()).max() < 1e-9
    assert 0 < np.abs(out32 - out64).max() < 1e-5 * np.abs(out64).max()


def _robomimic_obs(w: DanceWrapper, x: torch.Tensor) -> torch.Tensor:
    """The wrapper's observation layout, in the dtype of ``x``."""
    terms: list[list[torch.Tensor]] = [[], [], [], [], [], []]
    for k in range(FRAMES):
        f = x[:, k * FRAME : (k + 1) * FRAME]
        for i, part in enumerate([f[:, 64:93][:, w.idx], f[:, 0:3], f[:, 6:35][:, w.idx],
                                  f[:, 35:64][:, w.idx], f[:, 3:6], f[:, 93:94]]):  # fmt: skip
            terms[i].append(part)
    history = torch.cat([torch.cat(t, -1) for t in terms], -1)
    phase = torch.clamp(terms[5][0], max=1.0)
    return torch.cat([t[0] for t in terms[:4]] + [history, terms[4][0], phase], -1)


def test_a_module_that_fixes_float32_exports_with_no_flag_on_its_graphs_floor(dance):
    """float32 rounding at the edge cases is above the absolute 1e-5 (the gate before this
    failed it); the floor measured on the graph admits it, as the tolerance says."""
    _, f = dance
    assert f["passed"] is True and f["tolerance_basis"] == "relative"
    assert f["noise_floor_of"] == "graph" and "tolerance_note" not in f
    assert f["max_abs_error"] > TOLERANCE  # the absolute tolerance would have failed it
    assert f["tolerance"] == pytest.approx(f["noise_multiplier"] * f["noise_floor"])
    assert f["max_abs_error"] <= f["tolerance"]


def _corrupted(monkeypatch, change):
    """Export through a graph ``change``d after torch wrote it (the mismatch the gate catches)."""
    write = folder_ts.to_bare_onnx

    def to_bare_onnx(net, obs_dim):
        model = write(net, obs_dim)
        for t in model.graph.initializer:
            a = change(t.name, numpy_helper.to_array(t).copy())
            if a is not None:
                t.CopyFrom(numpy_helper.from_array(a, t.name))
        return model

    monkeypatch.setattr(folder_ts, "to_bare_onnx", to_bare_onnx)


def _wrong_weight(name, a):
    if name == "model.0.weight":  # one of the 6080 weights of the first layer 1 % off
        a[3, 5] *= 1.01
        return a
    return None


def _swapped_outputs(name, a):
    if name in ("model.2.weight", "model.2.bias"):  # the network's actions 0 and 1 swapped
        a[[0, 1]] = a[[1, 0]]
        return a
    return None


@pytest.mark.parametrize("change", [_wrong_weight, _swapped_outputs])
def test_a_graph_that_computes_another_function_still_fails(dance, monkeypatch, change):
    """The graph's floor is its own rounding, not its distance to the source: a wrong weight or
    swapped outputs leave the floor as it was and fail the gate; the candidate is kept."""
    source, clean = dance
    _corrupted(monkeypatch, change)
    with pytest.raises(ParityError, match="disagree") as caught:
        folder_ts.export_folder_torchscript(source, source.with_name("bad.onnx"))
    f = caught.value.figures
    assert f["noise_floor"] == pytest.approx(clean["noise_floor"], rel=0.5)
    assert f["max_abs_error"] > f["tolerance"] == pytest.approx(4 * f["noise_floor"])
    assert not source.with_name("bad.onnx").exists()
    assert source.with_name("bad.parity-failed.onnx").is_file()
