"""The ``height_scan`` block: its pattern as legged_gym and Isaac Lab define it, read from a spec
file and from an Isaac Lab run's env.yaml, and its observation."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from sim2real.deploy.core.state import RobotState
from sim2real.deploy.spec.height_scan import HeightScanPattern
from sim2real.deploy.spec.policy_spec import ObservationBlock, PolicySpec, SpecError
from tests import foreign_stacks as fs


def scan_block(pattern: HeightScanPattern | None = None) -> ObservationBlock:
    """legged_gym's block: offset 0.5 m, obs_scales.height_measurements 5, clip 1 m."""
    p = pattern or HeightScanPattern()
    return ObservationBlock("height_scan", p.count, (0.2,) * p.count, (0.5,) * p.count, 5.0, scan=p)


def scan_spec(robot, pattern: HeightScanPattern | None = None) -> PolicySpec:
    spec = PolicySpec.for_robot(robot)
    return replace(spec, observation_blocks=(*spec.observation_blocks, scan_block(pattern)))


def test_legged_gym_grid_is_17_by_11_with_y_fastest_and_isaaclab_grid_x_fastest():
    lg = HeightScanPattern()
    assert lg.count == 187
    np.testing.assert_allclose(lg.points()[:3], [[-0.8, -0.5], [-0.8, -0.4], [-0.8, -0.3]])
    il = HeightScanPattern.grid(0.1, (1.6, 1.0))
    assert il.count == 187 and il.ordering == "xy"
    np.testing.assert_allclose(il.points()[:2], [[-0.8, -0.5], [-0.7, -0.5]], atol=1e-12)


def test_a_height_scan_spec_round_trips_and_observes_legged_gyms_measured_heights(go2):
    spec = scan_spec(go2)
    again = PolicySpec.from_json(spec.to_json())
    assert again == spec
    assert again.plan.numpy_reason and "kernel does not take" in again.plan.numpy_reason
    state = RobotState.legged(2, go2.n_joints, 4)
    heights = np.random.default_rng(0).uniform(-1.0, 2.5, (2, 187))  # sensor z - terrain z, m
    state.height_scan = heights
    obs = again.observation(state, np.zeros((2, 3)))[:, -187:]
    # legged_gym: clip(root z - 0.5 - terrain height, -1, 1) * 5
    np.testing.assert_allclose(obs, np.clip(heights - 0.5, -1, 1) * 5.0, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize(
    "change, message",
    [
        ({"scan": None}, "scan is for height_scan blocks"),
        ({"size": 10, "scale": (0.2,) * 10, "offset": (0.5,) * 10}, "size 10, expected 187"),
        ({"scan": HeightScanPattern(alignment="roll")}, "scan.alignment: 'roll'"),
    ],
)
def test_a_bad_height_scan_block_is_refused_naming_the_field(go2, change, message):
    spec = PolicySpec.for_robot(go2)
    block = replace(scan_block(), **change)
    with pytest.raises(SpecError, match=message):
        replace(spec, observation_blocks=(*spec.observation_blocks, block)).validate()


def test_a_spec_file_states_the_scan_and_its_size_follows(go2):
    doc = json.loads(PolicySpec.for_robot(go2).to_json())
    doc["observation"].append(
        {"name": "height_scan", "offset": 0.5, "scale": 0.2, "clip": 5.0,
         "scan": {"x": [-0.1, 0.0, 0.1], "y": [0.0, 0.1], "ordering": "xy"}}
    )  # fmt: skip
    spec = PolicySpec.from_json(json.dumps(doc))
    block = spec.observation_blocks[-1]
    assert block.size == 6 and block.scan.alignment == "yaw" and block.scan.ordering == "xy"


def isaaclab_scan_env(**sensor) -> dict:
    """Isaac Lab's Go2 rough velocity environment's policy group with its ``height_scan`` term
    and the scene's ``height_scanner`` (velocity_env_cfg: GridPatternCfg resolution 0.1, size
    [1.6, 1.0], offset 20 m up, yaw alignment; the term clipped (-1, 1))."""
    env = fs.isaaclab_env()
    env["observations"]["policy"]["height_scan"] = fs._isaac_obs(
        "height_scan", {"sensor_cfg": {"name": "height_scanner"}}, clip=(-1.0, 1.0)
    )
    env["scene"]["height_scanner"] = {
        "class_type": "isaaclab.sensors.ray_caster.ray_caster:RayCaster",
        "prim_path": "/World/envs/env_.*/Robot/base",
        "offset": {"pos": (0.0, 0.0, 20.0), "rot": (1.0, 0.0, 0.0, 0.0)},
        "ray_alignment": "yaw",
        "pattern_cfg": {
            "func": "isaaclab.sensors.ray_caster.patterns.patterns:grid_pattern",
            "resolution": 0.1,
            "size": [1.6, 1.0],
            "direction": (0.0, 0.0, -1.0),
            "ordering": "xy",
        },
        "mesh_prim_paths": ["/World/ground"],
    } | sensor
    return env


def test_isaaclab_height_scan_term_reads_its_sensors_grid(go2, tmp_path):
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy

    path = fs.write_isaaclab_run(tmp_path / "run", isaaclab_scan_env(), 48 + 187, 12)
    spec = OnnxPolicy(path, go2).spec
    block = spec.observation_blocks[-1]
    assert block.name == "height_scan" and block.size == 187
    assert block.scan == HeightScanPattern.grid(0.1, (1.6, 1.0), ordering="xy", alignment="yaw")
    assert block.offset == (0.5,) * 187 and block.scale == (1.0,) * 187 and block.clip == 1.0


def test_isaaclab_height_scan_of_a_sensor_that_is_no_grid_is_refused_by_name(go2, tmp_path):
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.spec.onnx_checks import PolicyLoadError

    env = isaaclab_scan_env(pattern_cfg={"func": "patterns:lidar_pattern", "channels": 16})
    path = fs.write_isaaclab_run(tmp_path / "run", env, 48 + 187, 12)
    with pytest.raises(PolicyLoadError, match="height_scanner.pattern_cfg is not a GridPatternCfg"):
        OnnxPolicy(path, go2)
