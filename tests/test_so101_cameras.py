"""The SO-101's task scene (sim2real/robots/so101/so101_scene.xml): LeRobot's front and wrist
cameras, rendered by the plant's colour camera (sim2real/eval/lerobot/cameras.py), see the goal
marker; the scene's robot is so101.xml's."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.eval.lerobot.cameras import CAMERAS, SceneCameras

SHAPE = (48, 64)


def red(image: np.ndarray) -> int:
    """Pixels of the goal marker's red (1, 0.1, 0.1) in a uint8 R, G, B image."""
    r, g, b = (image[..., i].astype(int) for i in range(3))
    return int(np.sum((r > 100) & (r > 2 * g) & (r > 2 * b)))


@pytest.fixture(scope="module")
def rig(so101):
    plant = SimBackend(so101, envs=1, seed=0)
    plant.open()
    cams = SceneCameras(so101, plant, rate=25.0, shape=SHAPE)
    yield so101, plant, cams
    cams.close()


def test_scene_robot_is_so101s_own(so101):
    scene = mujoco.MjModel.from_xml_path(str(so101.directory / so101.config.task.scene))
    robot = so101.mj_model
    nb, ng, nj = robot.nbody, robot.ngeom, robot.njnt
    for field in ("body_pos", "body_quat", "body_mass", "body_inertia", "body_parentid"):
        np.testing.assert_array_equal(getattr(scene, field)[:nb], getattr(robot, field), field)
    for field in ("geom_pos", "geom_quat", "geom_size", "geom_bodyid", "geom_type"):
        np.testing.assert_array_equal(getattr(scene, field)[:ng], getattr(robot, field), field)
    np.testing.assert_array_equal(scene.jnt_range[:nj], robot.jnt_range)
    np.testing.assert_array_equal(scene.dof_armature, robot.dof_armature)
    assert sorted(scene.camera(i).name for i in range(scene.ncam)) == sorted(CAMERAS)
    # the wrist camera rides on the gripper
    assert scene.body(int(scene.cam_bodyid[scene.camera("wrist").id])).name == "gripper_link"


def test_cameras_render_at_the_shape_and_see_the_goal(rig):
    robot, plant, cams = rig
    ahead = robot.forward_kinematics(robot.home) + np.array([0.06, 0.0, -0.03])
    seen = cams.capture(0.0, ahead)  # just ahead of the gripper at home, inside both views
    away = cams.capture(0.04, [3.0, 3.0, -3.0])  # the next frame (25 Hz): behind the table
    for name in CAMERAS:
        assert seen[name].shape == (*SHAPE, 3) and seen[name].dtype == np.uint8
        assert red(seen[name]) >= 4, name
        assert red(away[name]) == 0, name
    # a goal elsewhere in the goal box: the front camera still sees it, where the wrist does not
    corner = np.array(robot.config.task.box_min) + [0.05, 0.05, 0.05]
    side = cams.capture(0.08, corner)
    assert red(side["front"]) >= 2


def test_deploy_run_renders_the_front_camera_of_the_scene_for_a_lerobot_export(tmp_path):
    """A LeRobot export with an ``observation.images.front`` key on ``deploy-run --backend sim``
    takes its frames from the plant's camera rendering so101_scene.xml's ``front``."""
    import json

    from sim2real.deploy.cli.deploy_run import deploy_run_main as deploy_run
    from sim2real.deploy.cli.run_verdict import EXIT_CLEAN
    from tests.lerobot_folder import write_chunk_onnx

    path = write_chunk_onnx(tmp_path / "front.onnx", fps=25.0, image_shape=(3, *SHAPE))
    report = tmp_path / "report.json"
    code = deploy_run(
        ["--robot", "so101", "--policy", str(path), "--report", str(report)]
        + ["--backend", "sim", "--duration", "2"]
    )
    r = json.loads(report.read_text())
    assert code == EXIT_CLEAN
    cam = r["camera"]
    assert cam["camera"] == "front" and cam["plant"]["rate_hz"] == 25.0
    assert cam["frames_taken"][0] >= 45 and cam["plant"]["delivered"][0] >= 45  # 2 s at 25 Hz
