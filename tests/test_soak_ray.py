"""A soak campaign on Ray without a shared disk: its inputs travel with the tasks, the sessions'
folders come back to the driver (sim2real/eval/soak/transport.py, ray_executor.py).

The fast tests run the worker's side in this process, with the driver's campaign folder moved
away while it runs (so the worker cannot read a driver's file, whatever path it is named by); the
nightly one runs the CLI on a two-node local Ray cluster whose worker node sees the campaign folder
as an empty tmpfs (tests/ray_cluster.py), killed and resumed, against a local run of the same
seeds.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest

from sim2real.eval.soak import checkpoint as ckpt
from sim2real.eval.soak.campaign import run_campaign
from sim2real.eval.soak.ray_executor import batch_task
from sim2real.eval.soak.result import read_result
from sim2real.eval.soak.session import session_dir
from sim2real.eval.soak.transport import (
    FolderSync,
    Relabel,
    TransportError,
    apply_changes,
    materialise,
    opened_files,
    pack_inputs,
    pack_sessions,
    worker_config,
)
from sim2real.robots import load_robot
from sim2real.robots.loading import ROBOTS_DIR
from tests.soak_fixtures import kill_after_first_checkpoint, short_session
from tests.test_soak import tiny_policy

#: Where the in-process worker's temporary folders are made (tempfile.mkdtemp's prefix).
WORKER_PREFIX = "sim2real-soak-"


def arm_session(robot: str, policy, hours: float, **options):
    """arm3's short test session (tests/soak_fixtures.py) for ``robot`` (arm3's copy)."""
    return replace(short_session("arm3", policy, hours, **options), robot=robot)


def seeded(result: dict) -> dict:
    """A session's result without its wall-clock part."""
    return {k: v for k, v in result.items() if k != "wall"}


def strings(doc) -> list[str]:
    if isinstance(doc, dict):
        return [s for v in doc.values() for s in strings(v)]
    if isinstance(doc, list):
        return [s for v in doc for s in strings(v)]
    return [doc] if isinstance(doc, str) else []


@pytest.fixture
def driver(tmp_path, arm3):
    """A driver's campaign folder: a robot folder (a copy of arm3's) and the tiny policy."""
    d = tmp_path / "driver"
    shutil.copytree(ROBOTS_DIR / "arm3", d / "robots" / "myarm")
    tiny_policy(d / "my_arm.onnx", arm3)
    return d


def run_worker(inputs, batch, out: Path, resume: bool, hidden: Path, park: Path):
    """Run :func:`batch_task` in this process with the folder ``hidden`` moved to ``park`` (the
    worker sees none of it), then move it back and write the changes into ``out`` as the driver
    does; the results."""
    sessions = pack_sessions(out, [c.seed for c in batch]) if resume else None
    hidden.rename(park)
    try:
        messages = list(batch_task(inputs, batch, str(out.resolve()), resume, sessions))
    finally:
        park.rename(hidden)
    for kind, payload in messages[:-1]:
        assert kind == "files"
        apply_changes(out, payload)
    kind, results = messages[-1]
    assert kind == "results"
    return results


# ---------------------------------------------------------------- the transport
def test_inputs_cross_under_their_driver_paths_and_sessions_come_back_in_order(
    driver, tmp_path, monkeypatch
):
    """The inputs land under the worker's root at their driver paths (a relative option names
    the same file from the worker's folder, an absolute one is moved under the root; the file the
    driver opened beside the policy goes too); the sessions' files come back to the driver
    relabelled, data before the manifest, removals after, and nothing outside sessions/."""
    monkeypatch.chdir(driver)
    (driver / "config.yaml").write_text("beside: the policy\n")
    policy = str(driver / "my_arm.onnx")  # absolute
    cfg = arm_session("robots/myarm", policy, 0.001)  # relative robot folder
    with opened_files() as opened:
        (driver / "config.yaml").read_text()
    inputs = pack_inputs(cfg, opened)
    assert set(inputs.files) == {
        str((driver / "robots" / "myarm").resolve()),
        str((driver / "my_arm.onnx").resolve()),
        str((driver / "config.yaml").resolve()),
    }
    root = (tmp_path / "root").resolve()
    work = materialise(inputs, root)
    assert work == root / str(driver.resolve()).lstrip("/")
    on_worker = worker_config(cfg, inputs, root)
    assert on_worker.robot == "robots/myarm" and (work / on_worker.robot / "robot.toml").is_file()
    assert on_worker.policy == str(root) + str(Path(policy).resolve())
    assert Path(on_worker.policy).read_bytes() == Path(policy).read_bytes()

    relabel = Relabel([cfg], inputs, root)
    doc = {"options": on_worker.batch_key(), "clip": f"{work}/clip.csv", "n": [1.5, "x"]}
    assert relabel.to_driver(doc) == {
        "options": cfg.batch_key(),
        "clip": f"{driver.resolve()}/clip.csv",
        "n": [1.5, "x"],
    }
    assert relabel.to_worker(relabel.to_driver(doc))["options"] == on_worker.batch_key()
    err = relabel.error(ValueError(f"{work}/sessions/x: bad; {on_worker.policy} differs"))
    assert str(err) == f"{driver.resolve()}/sessions/x: bad; {policy} differs"

    out_w, out_d = tmp_path / "worker_out", tmp_path / "driver_out"
    d = session_dir(out_w, 0)
    d.mkdir(parents=True)
    sync = FolderSync(out_w, [0], relabel)
    (d / "state-1.npz").write_bytes(b"arrays")
    (d / "checkpoint.json").write_text(json.dumps({"meta": {"config": on_worker.batch_key()}}))
    (d / "progress.json").write_text("{}")
    changes = sync.changes()
    assert [rel.rsplit("/", 1)[-1] for rel, _ in changes] == [
        "state-1.npz",
        "checkpoint.json",
        "progress.json",
    ]
    apply_changes(out_d, changes)
    manifest = json.loads((session_dir(out_d, 0) / "checkpoint.json").read_text())
    assert manifest["meta"]["config"] == cfg.batch_key()
    (d / "state-1.npz").unlink()
    (d / "state-2.npz").write_bytes(b"later")
    (d / "result.json").write_text("{}")
    changes = sync.changes()
    assert [(rel.rsplit("/", 1)[-1], data is None) for rel, data in changes] == [
        ("state-2.npz", False),
        ("result.json", False),
        ("state-1.npz", True),
    ]
    apply_changes(out_d, changes)
    assert sorted(p.name for p in session_dir(out_d, 0).iterdir()) == [
        "checkpoint.json",
        "progress.json",
        "result.json",
        "state-2.npz",
    ]
    assert sync.changes() == []
    with pytest.raises(TransportError, match="outside"):
        apply_changes(out_d, [("../escape.txt", b"x")])


def test_a_batch_runs_where_the_driver_files_are_not_and_comes_back_as_a_local_run(
    driver, tmp_path, monkeypatch
):
    """Two sessions (robot folder and policy named relative to the driver's folder) run by the
    worker's task with the driver's folder gone from its path: the results, and the session
    folders written back into the driver's campaign folder, equal a local run's."""
    monkeypatch.chdir(driver)
    cfg = arm_session("robots/myarm", "my_arm.onnx", 6.0 / 3600.0)
    local = run_campaign(cfg, 2, driver / "local", sessions_per_process=2, progress=False)
    with opened_files() as opened:
        robot = load_robot(cfg.robot)
        policy = cfg.load_policy(robot)
    inputs = pack_inputs(cfg, opened, policy)
    monkeypatch.chdir(tmp_path)
    batch = [replace(cfg, seed=s) for s in (0, 1)]
    out = driver / "ray"
    results = run_worker(inputs, batch, out, False, driver, tmp_path / "parked")
    assert [seeded(r) for r in results] == [seeded(r) for r in local]
    assert not any(WORKER_PREFIX in s for s in strings(results))
    for s in (0, 1):
        assert seeded(read_result(out, s)) == seeded(local[s])
        names = sorted(p.name for p in session_dir(out, s).iterdir())
        assert names == sorted(p.name for p in session_dir(driver / "local", s).iterdir())


def test_a_killed_campaign_resumes_through_the_transport(driver, tmp_path, monkeypatch):
    """A session killed after its first checkpoint resumes on a worker that cannot see the
    driver's folder from the checkpoint shipped to it, to the uninterrupted run's result; a
    resume with other options is refused there, in one line naming the driver's checkpoint."""
    monkeypatch.chdir(tmp_path)
    cfg = short_session("arm3", driver / "my_arm.onnx", 9.0 / 3600.0, seed=3)
    whole = run_campaign(cfg, 1, driver / "whole", progress=False)[0]
    out = driver / "ray"
    kill_after_first_checkpoint(cfg, out)
    manifest = session_dir(out, 3) / ckpt.MANIFEST
    assert manifest.exists() and read_result(out, 3) is None
    with opened_files() as opened:
        policy = cfg.load_policy(load_robot(cfg.robot))
    inputs = pack_inputs(cfg, opened, policy)

    other = replace(cfg, goal_period=3.0)
    with pytest.raises(ckpt.CheckpointError) as err:
        run_worker(inputs, [other], out, True, driver, tmp_path / "parked")
    message = str(err.value)
    assert str(manifest.resolve()) in message and "goal_period" in message
    assert WORKER_PREFIX not in message and "\n" not in message

    results = run_worker(inputs, [cfg], out, True, driver, tmp_path / "parked")
    assert seeded(results[0]) == seeded(whole)
    assert seeded(read_result(out, 3)) == seeded(whole)


# ---------------------------------------------------------------- on a two-node cluster
def same_figures(report: dict) -> dict:
    """A report without what differs between two runs of the same seeds: wall time and tick
    cost, the creation time, the executor and whether it was resumed."""
    drop = {"wall", "wall_s", "simulated_per_wall", "tick_cost_us", "created"}
    drop |= {"executor", "address", "resumed"}

    def walk(doc):
        if isinstance(doc, dict):
            return {k: walk(v) for k, v in doc.items() if k not in drop}
        if isinstance(doc, list):
            return [walk(v) for v in doc]
        return doc

    return walk(report)


@pytest.mark.nightly  # two Ray nodes and three 4-session campaigns: about 2 minutes
def test_a_campaign_on_a_node_that_cannot_see_the_driver_gives_the_local_report(driver, tmp_path):
    """soak-test --executor ray, run from the campaign's folder with relative paths as the issue's
    user did, on a cluster whose only CPU is on a node that sees the campaign folder as an empty
    tmpfs: killed after its first checkpoint reached the driver, refused in one line when resumed
    with other options, then resumed; its report equals a local run's of the same seeds."""
    from tests.ray_cluster import cluster_env, two_node_cluster, unshare_command

    if unshare_command() is None:
        pytest.skip("unshare cannot make a mount namespace here (root or user namespaces)")
    soak = [Path(sys.executable).with_name("soak-test"), "--robot", "robots/myarm"]
    soak += ["--policy", "my_arm.onnx", "--hours", "0.01", "--sessions", "4", "--no-film"]
    soak += ["--checkpoint-minutes", "0.05", "--no-progress"]
    env = cluster_env()

    def run(*extra: str, timeout: float = 600) -> subprocess.CompletedProcess:
        return subprocess.run(
            [*map(str, soak), *extra], cwd=driver, env=env, capture_output=True, text=True,
            timeout=timeout,
        )  # fmt: skip

    local = run("--workers", "1", "--out", "local")
    assert local.returncode == 6, local.stderr  # the tiny policy misses its goals
    with two_node_cluster(driver, tmp_path / "nodes") as address:
        ray = ["--executor", "ray", "--address", address, "--out", "ray"]
        proc = subprocess.Popen(
            [*map(str, soak), *ray], cwd=driver, env=env, start_new_session=True,
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        first = driver / "ray" / "sessions" / "seed0000" / ckpt.MANIFEST
        deadline = time.monotonic() + 300
        try:
            while not first.exists():
                assert proc.poll() is None, "the campaign ended before its first checkpoint"
                assert time.monotonic() < deadline, "no checkpoint reached the driver in 300 s"
                time.sleep(0.05)
        finally:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        assert not (driver / "ray" / "report.json").exists()

        # seed 0 alone: the other sessions' tasks must not start with other options
        refused = run(*ray, "--resume", "--goal-period", "3", "--sessions", "1")
        assert refused.returncode == 3
        line = refused.stderr.strip().splitlines()[-1]
        assert line.startswith("soak-test: error: ") and "goal_period" in line, refused.stderr
        assert "Traceback" not in refused.stderr and WORKER_PREFIX not in refused.stderr

        resumed = run(*ray, "--resume")
    assert resumed.returncode == 6, resumed.stderr
    a = json.loads((driver / "local" / "report.json").read_text())
    b = json.loads((driver / "ray" / "report.json").read_text())
    assert b["campaign"]["executor"] == "ray" and b["campaign"]["resumed"]
    assert same_figures(b) == same_figures(a)
