"""The camera arm policy of ours (``sim2real/policies/arm_camera.onnx``): arm3's task scene (its
goal marker where the goal is, in the goal camera's view), the shipped two-input graph and its
contract, and one short deploy-run in which it reaches a goal it sees only in the depth image.
No training here (``make train-camera``); rendering runs on Mesa's software EGL."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from sim2real.deploy.backends.sim.camera import DepthNoise, attach_plant_camera
from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.backends.sim.task_scene import TaskScene
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.policies.camera_student import BLOCK
from tests.test_camera import egl_works, needs_gl  # noqa: F401 - the skipif names egl_works

POLICY = Path(__file__).resolve().parents[1] / "sim2real" / "policies" / "arm_camera.onnx"


def test_the_shipped_camera_policy_loads_and_its_contract_names_the_image_block(arm3):
    policy = OnnxPolicy(POLICY, arm3)
    spec = policy.spec
    assert [b.name for b in spec.observation_blocks] == [
        "joint_position",
        "joint_velocity",
        "ee_position",
    ]  # no goal block: the goal is the camera's to see
    (block,) = spec.images
    assert block == BLOCK and block.camera == "goal_camera" and block.rate == 30.0
    assert policy.images["depth"].shape == (1, 1, 48, 36)
    assert spec.control_rate == arm3.config.control.control_rate == 200.0
    assert spec.parity["passed"]


@needs_gl
def test_the_goal_marker_appears_where_the_goal_is_in_the_goal_cameras_view(arm3):
    plant = SimBackend(arm3, "velocity", envs=1)
    camera = attach_plant_camera(plant, _spec_with_block(arm3), noise=DepthNoise(k=0))
    try:
        centres = []
        for goal in ([0.6, 0.4, 0.0], [0.6, -0.4, 0.0], [0.3, 0.0, 0.0]):
            camera.scene.goal = np.array([goal])
            depth = camera.true_depth()
            rows, cols = np.nonzero(depth < BLOCK.far)  # the marker alone is in range
            assert len(rows) > 10
            centres.append((rows.mean(), cols.mean()))
        (r_up, c_up), (r_down, c_down), (r_near, c_near) = centres
        # image rows run down along -y, columns along +x (arm3_scene.xml's goal_camera)
        assert r_up < BLOCK.shape[0] / 2 < r_down and c_up == pytest.approx(c_down, abs=0.5)
        assert c_near < c_up and r_near == pytest.approx(BLOCK.shape[0] / 2 - 0.5, abs=1)
    finally:
        camera.close()


def test_a_task_scene_without_a_goal_marker_is_refused_in_one_line(arm3, tmp_path):
    scene = tmp_path / "scene.xml"
    scene.write_text(
        f'<mujoco><include file="{arm3.mjcf_path}"/><worldbody><camera name="c"/></worldbody>'
        "</mujoco>"
    )
    plant = SimBackend(arm3, "velocity", envs=1)
    with pytest.raises(ValueError) as err:
        TaskScene(scene, plant)
    assert str(err.value).startswith(f'{scene}: expected a mocap body <body name="goal"')
    assert "\n" not in str(err.value)


@needs_gl
def test_deploy_run_with_the_camera_at_30_hz_reaches_a_goal_it_sees_only_in_the_image(tmp_path):
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    report = tmp_path / "report.json"
    code = deploy_run_main(
        ["--robot", "arm3", "--policy", str(POLICY), "--duration", "4", "--seed", "3",
         "--envs", "2", "--goal", "0.55,0.35,0", "--camera-rate", "30", "--report", str(report)]
    )  # fmt: skip  # two robots: the graph's image input bound for the runtime's batch
    assert code == 0
    summary = json.loads(report.read_text())
    assert summary["camera"]["plant"]["rate_hz"] == 30.0
    assert summary["camera"]["frames_taken"] == [119, 119]  # 4 s at 30 Hz, the last in flight
    assert summary["goals"]["issued"] == summary["goals"]["reached"] == 2, summary["goals"]


def _spec_with_block(robot):
    from dataclasses import replace

    from sim2real.deploy.spec.policy_spec import PolicySpec

    return replace(PolicySpec.for_robot(robot), images=(BLOCK,))


@needs_gl
def test_a_soak_of_the_camera_policy_draws_each_sessions_camera_faults_and_reports_them(
    tmp_path, capsys
):
    from sim2real.eval import cli

    out = tmp_path / "soak"
    code = cli.main(
        ["--robot", "arm3", "--policy", str(POLICY), "--hours", "0.002", "--sessions", "2",
         "--sessions-per-process", "2", "--seed", "14", "--out", str(out), "--min-success", "0",
         "--min-window-success", "0", "--max-interventions", "1", "--no-progress", "--no-film"]
    )  # fmt: skip  # both sessions in one batch: one plant camera, each env its own faults
    report = json.loads((out / "report.json").read_text())
    assert code == report["exit_code"]
    cameras = [s["camera"] for s in report["sessions"]]
    assert [c["frames"] for c in cameras] == [217, 217]  # at 0, 1/30 .. 7.2 s
    assert cameras[0]["faults"] != cameras[1]["faults"]  # drawn from each session's seed
    assert all(c["faults"]["drop"] > 0 and c["dropped"] <= c["frames"] for c in cameras)
    assert all(c["frames_taken"] + c["dropped"] + c["frozen"] <= c["frames"] for c in cameras)
    said = capsys.readouterr().out
    assert "camera       seed0014: 'goal_camera' 30 Hz, 217 frames; met " in said
    assert "camera       seed0015: 'goal_camera' 30 Hz" in said
    # seed 14 draws a frozen spell: the runtime stops the robot and says why
    assert "camera stop  at " in said and "frames repeated with new stamps (frozen)" in said
