"""The height scan in the simulated stack: ray casts on the plant's scene (a plane, a box step)
equal the analytic heights, the runtime's scan is the truth plus the stated seeded noise, and a
frozen elevation map stops the robot safely (stale_sensor)."""

from __future__ import annotations

from dataclasses import replace

import mujoco
import numpy as np
import pytest
from onnx import helper

from sim2real.deploy.backends.sim.height_scan import HeightScanNoise, PlantHeightScanner
from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.runtime import FAULT_CAUSES, Mode, Runtime
from sim2real.deploy.spec.height_scan import HeightScanPattern
from sim2real.deploy.spec.policy_spec import ObservationBlock, PolicySpec
from tests.runtime_fixtures import linear_onnx

#: The step: a box 0.1 m high whose near edge is 0.35 m ahead of the base, off the grid's
#: points (0.1 m apart), so that a point is on it or off it whatever the stance's few mm.
STEP_X, STEP_HALF, STEP_TOP = 0.6, (0.25, 1.0, 0.05), 0.1


def step_model(robot) -> mujoco.MjModel:
    spec = robot.mjspec("position")
    spec.worldbody.add_geom(
        type=mujoco.mjtGeom.mjGEOM_BOX, size=list(STEP_HALF), pos=[STEP_X, 0.0, STEP_HALF[2]]
    )
    return spec.compile()


def analytic(base: np.ndarray, pattern: HeightScanPattern) -> np.ndarray:
    """(envs, P) m, base z minus the floor's or the step's height under each point turned by
    the base's yaw (the true base state (envs, 13))."""
    w, x, y, z = base[:, 3:7].T
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    p = pattern.points()
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    px = base[:, :1] + c * p[:, 0] - s * p[:, 1]
    py = base[:, 1:2] + s * p[:, 0] + c * p[:, 1]
    on = (np.abs(px - STEP_X) <= STEP_HALF[0]) & (np.abs(py) <= STEP_HALF[1])
    return base[:, 2:3] - np.where(on, STEP_TOP, 0.0)


def scan_policy(go2, tmp_path) -> OnnxPolicy:
    """go2's default spec plus legged_gym's height_scan block; the action 0 whatever it
    observes (the home pose: a stand)."""
    spec = PolicySpec.for_robot(go2)
    p = HeightScanPattern()
    block = ObservationBlock(
        "height_scan", p.count, (0.2,) * p.count, (0.5,) * p.count, 5.0, scan=p
    )
    spec = replace(spec, observation_blocks=(*spec.observation_blocks, block))
    nodes = [helper.make_node("MatMul", ["obs", "w"], ["action"])]
    weights = {"w": np.zeros((spec.obs_dim, spec.act_dim), np.float32)}
    return OnnxPolicy(linear_onnx(spec, tmp_path / "scan.onnx", nodes, weights), go2)


def test_ray_casts_on_a_plane_and_a_box_step_equal_the_analytic_heights(go2):
    plant = SimBackend(
        go2, "position", envs=2, models=[go2.plant_model("position"), step_model(go2)]
    )
    pattern = HeightScanPattern()
    truth = PlantHeightScanner(plant, pattern).true_scan()
    base = plant.true_base_state()
    np.testing.assert_allclose(truth[0], base[0, 2], rtol=0, atol=1e-9)  # the plane: base z
    expected = analytic(base[1:], pattern)
    assert (expected[0] < base[1, 2]).sum() == 5 * 11  # five rows of points on the step
    np.testing.assert_allclose(truth[1:], expected, rtol=0, atol=1e-9)


def test_the_runtimes_scan_is_the_truths_ray_casts_plus_the_stated_seeded_noise(go2, tmp_path):
    plant = SimBackend(go2, "position", envs=1, models=[step_model(go2)])
    pattern, noise = HeightScanPattern(), HeightScanNoise(noise=0.03)
    plant.height_map_source = PlantHeightScanner(plant, pattern, noise, seed=7)
    rt = Runtime(go2, scan_policy(go2, tmp_path), plant)
    rt.start()
    draws = np.random.default_rng(7)
    for _ in range(5):
        base = plant.true_base_state().copy()  # the pose the tick's read casts from
        rt.run(1)
        error = rt.state.height_scan - analytic(base, pattern)
        np.testing.assert_allclose(error, draws.uniform(-0.03, 0.03, (1, 187)), rtol=0, atol=1e-9)
    assert rt.height_map.stamp[0] == pytest.approx(plant.frame.time[0])
    assert rt.mode[0] != Mode.SAFE_STOP
    saved = rt.state_dict()  # the map is part of the runtime's state
    np.testing.assert_array_equal(saved["height_map/scan"], rt.state.height_scan)
    rt.height_map.scan[:] = 0.0
    rt.load_state_dict(saved)
    np.testing.assert_array_equal(rt.state.height_scan, saved["height_map/scan"])


class FrozenMap:
    """An elevation map node that stops publishing after ``ticks`` maps: the frame keeps its
    last map and stamp (a frozen map)."""

    def __init__(self, scanner: PlantHeightScanner, ticks: int):
        self.scanner, self.left = scanner, ticks

    def fill(self, frame) -> None:
        if self.left > 0:
            self.scanner.fill(frame)
            self.left -= 1


def test_a_frozen_elevation_map_stops_the_robot_safely_past_the_stale_limit(go2, tmp_path):
    plant = SimBackend(go2, "position", envs=1, models=[step_model(go2)])
    plant.height_map_source = FrozenMap(PlantHeightScanner(plant, HeightScanPattern()), 10)
    rt = Runtime(go2, scan_policy(go2, tmp_path), plant)
    rt.start()
    limit = go2.stale_limit
    rt.run(10 + round(limit / go2.control_period) - 1)  # frozen for the stale limit: running
    assert rt.mode[0] not in (Mode.SAFE_STOP, Mode.FAULTED)
    rt.run(3)  # the limit is a whole number of periods here: the stop comes at it or one after
    assert rt.mode[0] in (Mode.SAFE_STOP, Mode.FAULTED)
    assert FAULT_CAUSES[rt.cause[0]] == "stale_sensor"
    record = rt.stale_stops.records[0]
    assert (
        record["height_map_s"] >= limit - 1e-9 and record["imu_s"] is None and not record["joints"]
    )


def test_a_walker_with_an_unused_height_scan_input_runs_through_deploy_run(
    go2_onnx, tmp_path, capsys
):
    """The plumbing of a perceptive policy (not a perceptive policy): the shipped walker given a
    legged_gym height_scan input it ignores walks through deploy-run --backend sim, a map taken
    every tick."""
    import json

    from sim2real.deploy.cli.deploy_run import deploy_run_main
    from sim2real.deploy.export.scan_input import add_unused_scan

    path, spec = add_unused_scan(go2_onnx, tmp_path / "go2_scan.onnx")
    assert spec.observation_blocks[-1].name == "height_scan" and spec.obs_dim == 47 + 187
    report = tmp_path / "report.json"
    args = ["--robot", "go2", "--policy", str(path), "--command", "0.5,0,0", "--duration", "1"]
    assert deploy_run_main([*args, "--report", str(report)]) == 0
    assert "height scan: ray casts on the plant" in capsys.readouterr().err
    summary = json.loads(report.read_text())
    assert summary["final_state"] == ["RUNNING"]
    assert summary["height_map"]["maps"] == [50] and summary["height_map"]["points"] == 187
    assert summary["height_map"]["oldest_s"][0] <= summary["height_map"]["stale_limit_s"]
