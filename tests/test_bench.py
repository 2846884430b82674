"""The benchmark suite runs and writes the documented results.json (no timing thresholds: speed is
measured by ``make bench``, never asserted in unit tests)."""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SUMMARY_KEYS = {"p50_us", "p99_us", "p99.9_us", "max_us", "mean_us", "samples"}
FULL_STAGES = {"read", "estimate", "observe", "infer", "guard", "smooth", "write", "physics"}
BARE_STAGES = {"read", "observe", "infer", "target", "pd", "physics"}
# One pytest-xdist worker runs both (make test's --dist loadgroup): each bench subprocess loads
# every kernel and starts a campaign process per CPU; two at once only crowd each other.
pytestmark = pytest.mark.xdist_group("bench")


def positive_finite(x) -> bool:
    return isinstance(x, int | float) and math.isfinite(x) and x > 0


def run_bench(out: Path, *argv: str) -> subprocess.CompletedProcess:
    """``python -m bench --quick ARGV --out OUT`` in the repository; asserts it exits 0."""
    proc = subprocess.run(
        [sys.executable, "-m", "bench", "--quick", *argv, "--out", str(out)],
        cwd=REPO,
        env=dict(os.environ, ORT_DISABLE_TELEMETRY="1"),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    return proc


def test_quick_tick_and_session_on_arm3(tmp_path):
    out = tmp_path / "results.json"
    proc = run_bench(out, "--only", "tick,session", "--robots", "arm3")
    assert "targets" in proc.stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results.json"]  # no temp file left

    r = json.loads(out.read_text())
    assert r["schema"] == "sim2real-deploy/bench/1"
    assert r["quick"] is True
    assert r["items"] == ["tick", "session"]
    assert {"platform", "python", "cpu_count", "versions"} <= set(r["machine"])
    pol = r["policies"]["arm3"]
    assert pol["hidden"] == [64, 64] and pol["control_mode"] == "velocity"
    assert set(r["sections"]) == {"tick", "session"}

    tick = r["sections"]["tick"]["robots"]["arm3"]
    full, bare = tick["full"], tick["bare"]
    assert set(full["stages"]) == FULL_STAGES
    assert set(bare["stages"]) == BARE_STAGES
    for s in (*full["stages"].values(), *bare["stages"].values()):
        assert set(s) == SUMMARY_KEYS
    for s in (full["overhead"], full["tick"], bare["overhead"], bare["tick"]):
        assert set(s) == SUMMARY_KEYS
        assert tick["ticks"] - tick["rounds"] <= s["samples"] <= tick["ticks"]
        assert all(positive_finite(s[k]) for k in ("p50_us", "p99_us", "p99.9_us", "mean_us"))
    assert set(tick["ratio"]) == {"tick_p50", "tick_mean", "overhead_p50", "overhead_mean"}
    assert all(positive_finite(v) for v in tick["ratio"].values())
    assert full["final_state"] == ["RUNNING"]

    session = r["sections"]["session"]["robots"]["arm3"]
    for key in ("simulated_s", "wall_s", "real_time_factor", "estimate_8h_s"):
        assert positive_finite(session[key]), key
    assert session["estimate_8h_s"] >= session["wall_s"]
    assert "28800" in session["extrapolation"]

    targets = {t["key"]: t for t in r["targets"]}
    assert set(targets) == {
        "tick_ratio",
        "overhead_p50",
        "overhead_p999",
        "session_8h",
        "campaign",
        "campaign_physics",
    }
    assert targets["session_8h"]["pass"] in (True, False)
    assert targets["session_8h"]["value"] == session["estimate_8h_s"]
    assert targets["tick_ratio"]["pass"] is None  # arm6 was not measured
    assert targets["campaign"]["pass"] is None
    assert targets["campaign_physics"]["pass"] is None


def test_quick_inference_and_campaign_with_its_physics_only_baseline(tmp_path):
    """The export/inference item runs, and the campaign reports the physics-only stepping of the
    same models beside its throughput (the fraction is their ratio)."""
    out = tmp_path / "results.json"
    run_bench(out, "--only", "inference,campaign", "--campaign-envs", "1,2")
    r = json.loads(out.read_text())
    inference = r["sections"]["inference"]
    assert all(e["parity"] for e in inference["exports"]), inference["exports"]
    assert {row["name"] for row in inference["rows"]} >= {"OnnxPolicy (IOBinding, 1 thread)"}
    campaign = r["sections"]["campaign"]
    assert [c["envs_per_worker"] for c in campaign["configs"]] == [1, 2]
    for c in campaign["configs"]:
        assert positive_finite(c["throughput_x"]) and positive_finite(c["physics_only_x"])
        assert math.isclose(c["physics_fraction"], c["throughput_x"] / c["physics_only_x"])
    targets = {t["key"]: t for t in r["targets"]}
    assert targets["campaign_physics"]["value"] == campaign["best"]["physics_fraction"]
