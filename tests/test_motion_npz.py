"""Motion NPZ clips of BeyondMimic and holosoma read into MotionClip: joints by name, quaternions
w x y z, refusals in one line naming file and field.

The BeyondMimic files are written as its ``scripts/csv_to_npz.py`` writes them (re-implemented
here in numpy, read not copied: the CSV resampled to 50 Hz, joints lerped and the root slerped,
``joint_vel`` by ``np.gradient``, joints in the articulation's order, body 0 the root, ``fps`` as
``[50]``), from rl_sar's dance_102 CSV (its checkout under ``SIM2REAL_STACKS``; skipped without it) or a synthetic clip. The
holosoma file is its own ``sub3_largebox_003_mj.npz`` (amazon-far/holosoma, its checkout) and a
synthetic one in its converter's layout (qpos/qvel columns, names, ``world`` body 0).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sim2real.deploy.tasks.motion.clip import ClipError
from sim2real.deploy.tasks.motion.npz_beyondmimic import BEYONDMIMIC_G1_JOINTS, read_beyondmimic_npz
from sim2real.deploy.tasks.motion.npz_holosoma import read_holosoma_npz

DANCE_CSV = "policy/g1/whole_body_tracking/dance_102/G1_Take_102.bvh_60hz.csv"
HOLOSOMA_NPZ = (
    "src/holosoma/holosoma/data/motions/g1_29dof/whole_body_tracking/sub3_largebox_003_mj.npz"
)
#: unitree's G1 motor order (rl_sar's policy/g1/base.yaml joint_names), the CSV's columns.
SDK = (
    tuple(
        f"{side}_{j}_joint"
        for side, joints in (
            ("left", ("hip_pitch", "hip_roll", "hip_yaw", "knee", "ankle_pitch", "ankle_roll")),
            ("right", ("hip_pitch", "hip_roll", "hip_yaw", "knee", "ankle_pitch", "ankle_roll")),
        )
        for j in joints
    )
    + ("waist_yaw_joint", "waist_roll_joint", "waist_pitch_joint")
    + tuple(
        f"{side}_{j}_joint"
        for side in ("left", "right")
        for j in ("shoulder_pitch", "shoulder_roll", "shoulder_yaw", "elbow")
        + ("wrist_roll", "wrist_pitch", "wrist_yaw")
    )
)


def stack_file(stacks, name: str, path: str, dest: Path) -> Path:
    """``path`` of stack ``name``'s checkout (:mod:`tests.stacks`) written to ``dest``."""
    dest.write_bytes(stacks.read(name, path))
    return dest


def slerp(a, b, t):
    dot = float(np.dot(a, b))
    if dot < 0:
        b, dot = -b, -dot
    if dot > 0.9995:
        q = a + t * (b - a)
        return q / np.linalg.norm(q)
    th = np.arccos(dot)
    return (np.sin((1 - t) * th) * a + np.sin(t * th) * b) / np.sin(th)


def csv_to_npz(rows: np.ndarray, path: Path, input_fps=60.0, output_fps=50, **changes) -> Path:
    """csv_to_npz.py's output for CSV ``rows`` (root xyz, quat x y z w, joints in SDK order)."""
    root_pos, root_quat, joints = rows[:, :3], rows[:, [6, 3, 4, 5]], rows[:, 7:]
    duration = (len(rows) - 1) / input_fps
    times = np.arange(0, duration, 1 / output_fps)
    phase = times / duration * (len(rows) - 1)
    i0 = np.floor(phase).astype(int)
    i1 = np.minimum(i0 + 1, len(rows) - 1)
    blend = (phase - i0)[:, None]
    pos = root_pos[i0] * (1 - blend) + root_pos[i1] * blend
    quat = np.array(
        [slerp(root_quat[a], root_quat[b], s) for a, b, s in zip(i0, i1, blend[:, 0], strict=True)]
    )
    dof = joints[i0] * (1 - blend) + joints[i1] * blend
    articulation = [SDK.index(n) for n in BEYONDMIMIC_G1_JOINTS]  # robot.find_joints by name
    dof = dof[:, articulation]
    torso = np.tile([1.0, 0.0, 0.0, 0.0], (len(times), 1))  # a second body: not under test
    fields = {
        "fps": [output_fps],
        "joint_pos": dof,
        "joint_vel": np.gradient(dof, 1 / output_fps, axis=0),
        "body_pos_w": np.stack([pos, pos + [0.0, 0.0, 0.05]], axis=1),
        "body_quat_w": np.stack([quat, torso], axis=1),
        "body_lin_vel_w": np.zeros((len(times), 2, 3)),
        "body_ang_vel_w": np.zeros((len(times), 2, 3)),
    }
    fields.update(changes)
    np.savez(path, **{k: v for k, v in fields.items() if v is not None})
    return path


def synthetic_rows(frames=40, seed=0) -> np.ndarray:
    """A CSV clip: root walking in x, turned 30 deg about z, joints moving."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames) / 60.0
    half = np.deg2rad(30.0) / 2
    quat_xyzw = np.tile([0.0, 0.0, np.sin(half), np.cos(half)], (frames, 1))
    joints = 0.3 * np.sin(t[:, None] * 3 + rng.uniform(0, 6, 29))
    return np.hstack([np.c_[0.1 * t, 0 * t, 0.78 + 0 * t], quat_xyzw, joints])


def test_a_beyondmimic_clip_from_rl_sars_dance_csv_is_read_by_joint_name(stacks, tmp_path):
    """The dance CSV through csv_to_npz: the clip in the robot's motor order equals the CSV's
    columns at t = 0 and the resampled CSV later; the root quaternion is the CSV's x y z w as
    w x y z."""
    csv = stack_file(stacks, "rl_sar", DANCE_CSV, tmp_path / "dance.csv")
    rows = np.loadtxt(csv, delimiter=",")[:121]
    clip = read_beyondmimic_npz(
        csv_to_npz(rows, tmp_path / "dance.npz"), BEYONDMIMIC_G1_JOINTS, robot_joints=SDK
    )
    assert clip.fps == 50.0 and clip.frames == 100 and clip.joint_names == SDK
    np.testing.assert_allclose(clip.joint_pos[0], rows[0, 7:], atol=1e-12)
    at = 7 / 50 * 60  # frame 7 at 50 Hz: between CSV rows 8 and 9
    k = int(at)
    expected = rows[k, 7:] * (k + 1 - at) + rows[k + 1, 7:] * (at - k)
    np.testing.assert_allclose(clip.joint_pos[7], expected, atol=1e-9)
    np.testing.assert_allclose(clip.root_quat[0], rows[0, [6, 3, 4, 5]], atol=1e-6)
    np.testing.assert_allclose(clip.root_pos[0], rows[0, :3], atol=1e-12)
    waist = clip.joint_names.index("waist_yaw_joint")
    np.testing.assert_allclose(
        clip.joint_vel[1:-1, waist], (clip.joint_pos[2:, waist] - clip.joint_pos[:-2, waist]) * 25
    )


def test_the_files_joint_order_is_kept_without_robot_joints_and_bodies_named_when_given(tmp_path):
    rows = synthetic_rows()
    path = csv_to_npz(rows, tmp_path / "m.npz")
    clip = read_beyondmimic_npz(path, BEYONDMIMIC_G1_JOINTS, body_names=["pelvis", "torso_link"])
    assert clip.joint_names == BEYONDMIMIC_G1_JOINTS
    np.testing.assert_allclose(
        clip.joint_pos[0], rows[0, 7:][[SDK.index(n) for n in clip.joint_names]]
    )
    assert clip.body_names == ("pelvis", "torso_link")
    np.testing.assert_allclose(clip.body_quat_w[:, 0], clip.root_quat)
    half = np.deg2rad(15.0)
    np.testing.assert_allclose(clip.root_quat[0], [np.cos(half), 0, 0, np.sin(half)], atol=1e-12)


def one_line_refusal(call, path: Path, field: str) -> str:
    with pytest.raises(ClipError) as info:
        call()
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"{path}: {field}: expected"), message
    return message


@pytest.mark.parametrize("fps", [[0], [float("nan")], ["fifty"], [50, 60], [-50.0]])
def test_an_fps_that_is_not_one_positive_number_is_refused(tmp_path, fps):
    path = csv_to_npz(synthetic_rows(), tmp_path / "m.npz", fps=np.asarray(fps))
    one_line_refusal(lambda: read_beyondmimic_npz(path, BEYONDMIMIC_G1_JOINTS), path, "fps")


def test_a_23_dof_clip_for_the_29_dof_robot_is_refused_naming_the_field(tmp_path):
    rows = synthetic_rows()
    path = csv_to_npz(rows, tmp_path / "m.npz")
    with np.load(path) as data:
        fields = dict(data)
    fields["joint_pos"], fields["joint_vel"] = (
        fields["joint_pos"][:, :23],
        fields["joint_vel"][:, :23],
    )
    np.savez(path, **fields)
    message = one_line_refusal(
        lambda: read_beyondmimic_npz(path, BEYONDMIMIC_G1_JOINTS), path, "joint_pos"
    )
    assert "(frames, 29)" in message and "(33, 23)" in message  # 40 rows at 60 Hz: 33 frames at 50
    names23 = BEYONDMIMIC_G1_JOINTS[:23]
    message = one_line_refusal(
        lambda: read_beyondmimic_npz(path, names23, robot_joints=SDK), path, "joint_names"
    )
    assert "none for" in message


@pytest.mark.parametrize(
    "change, field",
    [
        ({"body_quat_w": None}, "body_quat_w"),
        ({"body_quat_w": np.zeros((40, 2, 4))}, "body_quat_w"),
        ({"body_pos_w": np.zeros((40, 2, 2))}, "body_pos_w"),
    ],
)
def test_missing_or_malformed_body_fields_are_refused_in_one_line(tmp_path, change, field):
    path = csv_to_npz(synthetic_rows(48), tmp_path / "m.npz", **change)
    one_line_refusal(lambda: read_beyondmimic_npz(path, BEYONDMIMIC_G1_JOINTS), path, field)


def test_a_file_that_is_not_an_npz_is_refused_in_one_line(tmp_path):
    path = tmp_path / "clip.npz"
    path.write_text("0,0,0.78,0,0,0,1\n")
    one_line_refusal(lambda: read_beyondmimic_npz(path, BEYONDMIMIC_G1_JOINTS), path, "file")


def write_holosoma(path: Path, frames=30, joints=SDK, **changes) -> Path:
    """convert_data_format_mj.py's layout: qpos/qvel columns, names, body 0 ``world``."""
    rng = np.random.default_rng(1)
    half = np.deg2rad(-20.0) / 2
    root = np.tile([0.2, -0.1, 0.75, np.cos(half), 0.0, 0.0, np.sin(half)], (frames, 1))
    qpos = np.hstack([root, rng.normal(0, 0.2, (frames, len(joints)))])
    bodies = ["world", "pelvis", "torso_link"]
    body_quat = np.tile([1.0, 0.0, 0.0, 0.0], (frames, 3, 1))
    body_quat[:, 1] = root[:, 3:7]
    fields = {
        "fps": [30],
        "joint_pos": qpos,
        "joint_vel": np.hstack([np.zeros((frames, 6)), np.gradient(qpos[:, 7:], 1 / 30, axis=0)]),
        "body_pos_w": np.stack([np.zeros((frames, 3)), root[:, :3], root[:, :3]], axis=1),
        "body_quat_w": body_quat,
        "body_lin_vel_w": np.zeros((frames, 3, 3)),
        "body_ang_vel_w": np.zeros((frames, 3, 3)),
        "joint_names": list(joints),
        "body_names": bodies,
    }
    fields.update(changes)
    np.savez(path, **{k: v for k, v in fields.items() if v is not None})
    return path


def test_a_holosoma_clip_takes_its_names_and_its_root_from_qpos(tmp_path):
    path = write_holosoma(tmp_path / "h.npz")
    robot = tuple(reversed(SDK))
    clip = read_holosoma_npz(path, robot_joints=robot)
    with np.load(path) as data:
        qpos, qvel = data["joint_pos"], data["joint_vel"]
    assert clip.fps == 30.0 and clip.joint_names == robot
    np.testing.assert_allclose(clip.joint_pos, qpos[:, 7:][:, ::-1])
    np.testing.assert_allclose(clip.joint_vel, qvel[:, 6:][:, ::-1])
    half = np.deg2rad(-20.0) / 2
    np.testing.assert_allclose(clip.root_quat[0], [np.cos(half), 0, 0, np.sin(half)])
    assert clip.body_names == ("pelvis", "torso_link")  # MuJoCo's world dropped
    np.testing.assert_allclose(clip.body_quat_w[:, 0], clip.root_quat)


@pytest.mark.parametrize(
    "change, field",
    [
        ({"joint_names": list(SDK[:23])}, "joint_pos"),
        ({"joint_names": None}, "joint_names"),
        ({"fps": ["30"]}, "fps"),
        ({"body_names": ["world", "pelvis"]}, "body_pos_w"),
    ],
)
def test_a_holosoma_clip_that_disagrees_with_itself_is_refused_in_one_line(tmp_path, change, field):
    path = write_holosoma(tmp_path / "h.npz", **change)
    one_line_refusal(lambda: read_holosoma_npz(path), path, field)


def test_a_holosoma_clip_for_a_robot_missing_one_of_its_joints_is_refused(tmp_path):
    path = write_holosoma(tmp_path / "h.npz")
    message = one_line_refusal(
        lambda: read_holosoma_npz(path, robot_joints=SDK[:-1]), path, "joint_names"
    )
    assert "'right_wrist_yaw_joint' is not one" in message


def test_holosomas_own_motion_file_reads_as_a_29_dof_g1_clip(stacks, tmp_path):
    path = stack_file(stacks, "holosoma", HOLOSOMA_NPZ, tmp_path / "sub3.npz")
    clip = read_holosoma_npz(path, robot_joints=SDK)
    with np.load(path) as data:
        qpos, names = data["joint_pos"], list(data["joint_names"])
        pelvis = list(data["body_names"]).index("pelvis")
        pelvis_quat = data["body_quat_w"][:, pelvis]
    assert clip.fps == 50.0 and clip.joint_names == SDK and clip.frames == len(qpos)
    np.testing.assert_allclose(clip.joint_pos, qpos[:, 7:][:, [names.index(n) for n in SDK]])
    np.testing.assert_allclose(clip.root_quat, pelvis_quat, atol=1e-6)  # qpos w x y z = xquat
    assert "world" not in clip.body_names and "torso_link" in clip.body_names
