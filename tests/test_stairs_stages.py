"""``python -m bench.stairs_stages``: deploy-run's own rig on one terrain tile, judged as the bare
loop judges its own (docs/soak.md, "The first-step stall is the start's draw")."""

from __future__ import annotations

import pytest

from bench.stairs_stages import main, one_run

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_a_stairs_run_builds_deploy_runs_rig_on_the_tile(go2_onnx, capsys):
    """The tile given as deploy-run's ``--terrain`` text is read as deploy-run's main reads it
    (its parse after the parser; the rig took the text itself and failed on it): the shipped Go2
    stands on the platform of the 0.10-m stairs-up pit for 1 s of
    deploy-run's start, with no stop and exit 0, and the command line prints the run's line."""
    r = one_run("go2", str(go2_onnx), "stairs_up:0.10", 0, 1.0, "0.5,0,0", set(), None, True)
    assert r["exit"] == 0 and r["stop"] is None and not r["crossed"]
    assert abs(r["x_m"]) < 0.2  # still on the platform
    argv = ["--robot", "go2", "--policy", str(go2_onnx), "--tile", "stairs_up:0.10"]
    assert main([*argv, "--seeds", "0", "--seconds", "1.0", "--whole"]) == 0
    assert "stairs_up:0.10 off=-: crossed 0/1" in capsys.readouterr().out
