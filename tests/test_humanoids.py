"""unitree_rl_gym's published humanoid walking policies (the H1 and the H1-2) walk through the full
runtime (estimator, guard, smoother, default sensor noise) on the robots imported from their MJCF.

Test data: ``tests/data/unitree_rl_gym`` (its README says where each file comes from).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from deploy.cli.deploy_run import deploy_run_main

DATA = Path(__file__).parent / "data" / "unitree_rl_gym"


@pytest.mark.parametrize("robot", ["h1", "h1_2"])
def test_published_humanoid_walks_without_a_fall_or_a_safe_stop(robot, tmp_path):
    """Eight simulated seconds commanded at 0.5 m/s: the robot walks at least 3 m, never falls,
    is never stopped, and the joint estimator does not re-initialize (at the limits the importer
    derives for PD targets)."""
    report = tmp_path / "run.json"
    deploy_run_main(
        [
            "--robot", f"robots/{robot}",
            "--policy", str(DATA / robot / f"{robot}.onnx"),
            "--command", "0.5,0,0",
            "--duration", "8",
            "--report", str(report),
        ]
    )  # fmt: skip
    summary = json.loads(report.read_text())
    walk = summary["locomotion"]
    assert walk["falls"] == 0, walk
    assert summary["faults"]["safe_stops"] == 0, summary["faults"]
    assert summary["final_state"] == ["RUNNING"]
    assert summary["faults"]["estimator"]["reinitializations"] == 0, summary["faults"]
    assert walk["distance_m"] >= 3.0, walk
    # the first two seconds accelerate from standing, outside the 0.2 m/s band
    assert walk["tracking_success"] >= 0.7, walk
