"""Whole-body motion tracking from rl_sar's folder: the nested dance_102 folder read and exported,
its CSV clip read as rl_sar's MotionLoader reads it, the motion clock's interpolation and yaw
alignment, the anchor block against MuJoCo's torso, refusals of clips that do not fit, and a
few seconds of the dance through deploy-run (rl_sar and unitree_mujoco mirrors: skipped without)."""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import onnx
import pytest
import yaml

from sim2real.deploy.spec.motion_blocks import (
    axis_quat,
    motion_anchor_ori_b,
    torso_quat,
)
from sim2real.deploy.tasks.motion.clip import ClipError, MotionClip
from sim2real.deploy.tasks.motion.clock import MotionClock
from sim2real.deploy.tasks.motion.csv_clip import read_csv_clip
from tests.motion_files import CLIP, G1_FLAGS, dance_folder, g1_xml
from tests.rl_sar_files import write_tracking_folder

WAIST = ("waist_yaw_joint", "waist_roll_joint", "waist_pitch_joint")


def _rows(path: Path) -> np.ndarray:
    return np.array([[float(c) for c in line.split(",")] for line in path.read_text().split()])


def _columns(dance: Path) -> tuple[str, ...]:
    base = yaml.safe_load((dance.parents[1] / "base.yaml").read_text())
    return tuple(base["g1"]["joint_names"])


def _clip(dance: Path) -> str:
    """The clip's file name (config.yaml's ``motion_file``)."""
    doc = yaml.safe_load((dance / "config.yaml").read_text())
    return next(iter(doc.values()))["motion_file"]


def _motion_argv(robot, policy, clip) -> list[str]:
    """deploy-run's arguments for ``policy`` on ``robot`` in simulation, playing ``clip``."""
    return [
        "--backend",
        "sim",
        "--robot",
        str(robot),
        "--policy",
        str(policy),
        "--motion",
        str(clip),
    ]


def _errors(capsys) -> list[str]:
    """The lines of the captured standard error that say ``error``."""
    return [line for line in capsys.readouterr().err.splitlines() if "error" in line]


@pytest.fixture(params=["generated", pytest.param("rl_sar", marks=pytest.mark.stacks)])
def dance(request, tmp_path) -> Path:
    """A tracking folder: one written as rl_sar writes its dances (``tests/rl_sar_files.py``: on
    every machine), and rl_sar's own dance_102 (under ``SIM2REAL_STACKS``)."""
    if request.param == "generated":
        return write_tracking_folder(tmp_path)
    return dance_folder(request.getfixturevalue("stacks"), tmp_path)


# ---------------------------------------------------------------------- the folder
def test_the_nested_folder_is_read_with_its_motion_terms_and_clip(dance):
    """config key g1/whole_body_tracking/dance_102: base.yaml two folders up (a base.yaml of
    another key between them is passed over); its two tracking terms are our motion blocks (the
    anchor's joints the waist slots 12, 13, 14 of joint_mapping); its clip plays at the control
    rate 1 / (dt x decimation) = 50 Hz, as rl_sar's fsm plays it."""
    from sim2real.deploy.export.folder_torchscript import folder_contract

    (dance.parent / "base.yaml").write_text("decoy:\n  dt: 1.0\n")
    contract = folder_contract(dance / "policy.pt")
    assert contract.format == "rl_sar"
    kinds = [(t.kind, t.size if t.size >= 0 else len(contract.joint_slots)) for t in contract.terms]
    assert kinds == [
        ("motion_command", 58),
        ("motion_anchor_ori_b", 6),
        ("base_angular_velocity", 3),
        ("joint_position", 29),
        ("joint_velocity", 29),
        ("last_action", 29),
    ]
    mapping = [0, 6, 12, 1, 7, 13, 2, 8, 14, 3, 9, 15, 22, 4, 10, 16, 23, 5, 11, 17, 24, 18, 25]
    anchor = contract.terms[1]
    assert anchor.joints == tuple(mapping.index(s) for s in (12, 13, 14)) == (2, 5, 8)
    assert contract.motion.file == str(dance / _clip(dance))
    assert contract.motion.fps == pytest.approx(50.0)
    assert contract.motion.columns == _columns(dance)


def test_an_unmapped_tracking_term_is_refused_by_name(dance):
    """A term of the folder no block computes (BeyondMimic's anchor position) is refused naming
    it, never zeroed."""
    from sim2real.deploy.export.errors import ExportError
    from sim2real.deploy.export.folder_torchscript import export_folder_torchscript

    cfg = dance / "config.yaml"
    doc = yaml.safe_load(cfg.read_text())
    key = next(iter(doc))
    doc[key]["observations"].insert(2, "whole_body_tracking/motion_anchor_pos_b")
    cfg.write_text(yaml.safe_dump(doc))
    with pytest.raises(ExportError, match="'whole_body_tracking/motion_anchor_pos_b': not an obs"):
        export_folder_torchscript(dance / "policy.pt")


def test_policy_export_writes_the_graph_and_names_the_clip_with_its_hash(dance):
    """policy-export policy.pt: the ONNX beside it (parity passed), read back as rl_sar's, its
    ``motion`` metadata the clip's name, sha256, rate and columns."""
    from sim2real.deploy.export.folder_torchscript import export_folder_torchscript

    result = export_folder_torchscript(dance / "policy.pt")
    assert (result.obs_dim, result.act_dim) == (154, 29)
    assert result.parity["passed"]
    meta = {p.key: p.value for p in onnx.load(result.path).metadata_props}
    motion = json.loads(meta["motion"])
    digest = hashlib.sha256((dance / _clip(dance)).read_bytes()).hexdigest()
    assert motion == {
        "file": _clip(dance), "sha256": digest, "fps": 50.0, "timing": "rl_sar",
        "columns": list(_columns(dance)),
    }  # fmt: skip


# ---------------------------------------------------------------------- the CSV clip
def test_csv_clip_values_are_the_files_as_rl_sar_reads_them(dance):
    """Frame 0's joints are the file's columns 8..36; the quaternion x y z w becomes w x y z;
    velocities are the forward difference at the given rate, the last frame repeating the one
    before (rl_sar's ComputeVelocities)."""
    rows = _rows(dance / _clip(dance))
    clip = read_csv_clip(dance / _clip(dance), _columns(dance), 50.0)
    assert clip.frames == len(rows) > 100
    np.testing.assert_array_equal(clip.joint_pos[0], rows[0, 7:])
    np.testing.assert_array_equal(clip.root_pos[0], rows[0, :3])
    np.testing.assert_array_equal(clip.root_quat[0], rows[0, [6, 3, 4, 5]])
    np.testing.assert_allclose(clip.joint_vel[10], (rows[11, 7:] - rows[10, 7:]) * 50.0)
    np.testing.assert_array_equal(clip.joint_vel[-1], clip.joint_vel[-2])


def _csv(path: Path, rows: np.ndarray) -> Path:
    path.write_text("\n".join(",".join(f"{v:.6f}" for v in r) for r in rows) + "\n")
    return path


def _small(joints: int = 4, frames: int = 3) -> np.ndarray:
    rows = np.zeros((frames, 7 + joints))
    rows[:, 6] = 1.0  # w
    return rows


@pytest.mark.parametrize(
    ("change", "fps", "match"),
    [
        ("joints", 50.0, r"row 1: expected 11 columns .* got 10 \(3 joints\)"),
        (
            "limit",
            50.0,
            r"frame 2 joint b: 1\.5000 rad is past its hard limit \[-1\.0000, 1\.0000\]",
        ),
        ("none", "sixty", r"fps: expected a positive number of frames per second, got 'sixty'"),
        ("cell", 50.0, r"row 2 column 9: expected a number, got 'nan\?'"),
    ],
)
def test_a_clip_that_does_not_fit_is_refused_in_one_line(tmp_path, change, fps, match):
    """A wrong joint count, a frame past a hard limit, a rate that is not a number, a cell that
    is not a number: one line naming the file and the field."""
    rows = _small()
    if change == "joints":
        rows = rows[:, :-1]
    if change == "limit":
        rows[2, 8] = 1.5
    path = _csv(tmp_path / "clip.csv", rows)
    if change == "cell":
        lines = path.read_text().splitlines()
        cells = lines[1].split(",")
        cells[8] = "nan?"
        lines[1] = ",".join(cells)
        path.write_text("\n".join(lines))
    limits = {"b": (-1.0, 1.0)}
    with pytest.raises(ClipError) as err:
        read_csv_clip(path, ("a", "b", "c", "d"), fps, limits)
    message = str(err.value)
    assert "\n" not in message and message.startswith(str(path))
    assert __import__("re").search(match, message), message


# ---------------------------------------------------------------------- the clock
def _yaw_clip(tmp_path) -> MotionClip:
    """5 frames at 10 Hz: root yaw 0.5 + 0.2 i, waist yaw 0.1 i, joint ``a`` = i."""
    frames = np.arange(5.0)
    root = axis_quat(2, 0.5 + 0.2 * frames)
    pos = np.zeros((5, 4))
    pos[:, 0] = 0.1 * frames
    pos[:, 3] = frames
    return MotionClip(
        source=tmp_path / "c.csv", fps=10.0, joint_names=(*WAIST, "a"), joint_pos=pos,
        joint_vel=np.gradient(pos, axis=0), root_pos=np.zeros((5, 3)), root_quat=root,
    )  # fmt: skip


def _yaw(q: np.ndarray) -> float:
    w, x, y, z = q
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def test_the_clock_interpolates_as_rl_sars_update(tmp_path):
    """Length T / fps = 0.5 s; t = 0.2 s is frame 0.2 / 0.5 x 4 = 1.6: joints 0.4 x frame 1 + 0.6 x
    frame 2, the root's yaw slerped likewise, the anchor's yaw root plus waist; past the end the
    last frame."""
    clock = MotionClock(_yaw_clip(tmp_path), ("a", *WAIST), WAIST, envs=1)
    assert clock.length == pytest.approx(0.5)
    assert clock.frame(0.2) == (1, 2, pytest.approx(0.6))
    pos, vel, anchor = clock.sample(0.2)
    assert pos[0] == pytest.approx(1.6) and pos[1] == pytest.approx(0.16)
    assert _yaw(anchor) == pytest.approx(0.5 + 0.2 * 1.6 + 0.16)
    assert clock.sample(9.0)[0][0] == pytest.approx(4.0)


def test_the_clip_is_yaw_aligned_to_the_robots_torso_at_its_start(tmp_path):
    """A robot whose base yaws 1.0 rad with its waist at 0.3: the aligned anchor at t = 0 faces
    the robot's torso (1.3 rad), so the anchor block of that robot reads the identity's columns;
    a second robot's alignment is its own."""
    clock = MotionClock(_yaw_clip(tmp_path), ("a", *WAIST), WAIST, envs=2)
    base = axis_quat(2, np.array([1.0, -2.0]))
    waist = np.array([[0.3, 0.0, 0.0], [0.0, 0.0, 0.0]])
    clock.align(np.ones(2, bool), base, waist)
    assert _yaw(clock.init[0]) == pytest.approx(1.3 - 0.5)
    out = np.zeros((2, 2 * 4 + 4))
    clock.write(out)
    assert _yaw(out[0, 8:]) == pytest.approx(1.3)
    assert _yaw(out[1, 8:]) == pytest.approx(-2.0)
    state = SimpleNamespace(q=np.zeros((2, 4)), base=SimpleNamespace(orientation=base), motion=out)
    state.q[:, 1:] = waist
    raw = np.zeros((2, 6))
    block = SimpleNamespace(joints=np.array([1, 2, 3]), kind=SimpleNamespace(name="x"))
    motion_anchor_ori_b(state, None, raw, block, None, None)
    np.testing.assert_allclose(raw, [[1, 0, 0, 1, 0, 0]] * 2, atol=1e-12)


@pytest.mark.parametrize(("playback", "time", "plays"), [("once", 0.5, 1), ("loop", 0.1, 2)])
def test_the_clip_plays_once_holding_its_last_frame_or_loops(tmp_path, playback, time, plays):
    """0.6 s of a 0.5 s clip: once holds at its end (the last frame), loop starts again at 0
    (its second play); an env not started stays unstarted; its state survives a reload."""
    clock = MotionClock(_yaw_clip(tmp_path), ("a", *WAIST), WAIST, envs=2, playback=playback)
    clock.start(np.array([True, False]))
    for _ in range(6):
        clock.advance(0.1, np.ones(2, bool))
    assert clock.time[0] == pytest.approx(time) and np.isnan(clock.time[1])
    assert clock.plays.tolist() == [plays, 0]
    again = MotionClock(_yaw_clip(tmp_path), ("a", *WAIST), WAIST, envs=2, playback=playback)
    again.load_state_dict(clock.state_dict())
    assert np.array_equal(again.time, clock.time, equal_nan=True)


# ---------------------------------------------------------------------- the anchor block
def test_the_anchor_block_is_mujocos_torso_against_the_reference(stacks, tmp_path):
    """On unitree_mujoco's g1_29dof posed at random (base orientation, waist angles), rl_sar's
    torso formula is MuJoCo's xquat of torso_link, and the block is the first two columns of
    R_torso^T R_ref from MuJoCo's xmat, row by row."""
    import mujoco

    model = mujoco.MjModel.from_xml_path(str(g1_xml(stacks, tmp_path)))
    data = mujoco.MjData(model)
    rng = np.random.default_rng(4)
    torso = model.body("torso_link").id
    adr = [model.jnt_qposadr[model.joint(j).id] for j in WAIST]
    for _ in range(5):
        base = rng.normal(size=4)
        base /= np.linalg.norm(base)
        waist = rng.uniform(-0.5, 0.5, 3)
        data.qpos[3:7], data.qpos[adr] = base, waist
        mujoco.mj_kinematics(model, data)
        ours = torso_quat(base, waist)
        assert (
            min(np.abs(ours - data.xquat[torso]).max(), np.abs(ours + data.xquat[torso]).max())
            < 1e-9
        )
        ref = rng.normal(size=4)
        ref /= np.linalg.norm(ref)
        r_ref = np.zeros(9)
        mujoco.mju_quat2Mat(r_ref, ref)
        expected = (data.xmat[torso].reshape(3, 3).T @ r_ref.reshape(3, 3))[:, :2].reshape(-1)
        state = SimpleNamespace(
            q=waist[None], base=SimpleNamespace(orientation=base[None]),
            motion=np.concatenate([np.zeros(6), ref])[None],
        )  # fmt: skip
        raw = np.zeros((1, 6))
        block = SimpleNamespace(joints=np.arange(3), kind=SimpleNamespace(name="x"))
        motion_anchor_ori_b(state, None, raw, block, None, None)
        np.testing.assert_allclose(raw[0], expected, atol=1e-9)


# ---------------------------------------------------------------------- a dance
#: The tests of :func:`g1_dance` on one pytest-xdist worker (make test's --dist loadgroup): the
#: export and the import run once, not on each worker.
ON_G1_DANCE_WORKER = pytest.mark.xdist_group("g1_dance")


@pytest.fixture(scope="module")
def g1_dance(stacks, tmp_path_factory):
    """dance_102 exported and unitree_mujoco's G1 imported with robot-level flags only."""
    from sim2real.deploy.cli.robot_import import main as robot_import
    from sim2real.deploy.export.folder_torchscript import export_folder_torchscript

    root = tmp_path_factory.mktemp("dance")
    dance = dance_folder(stacks, root)
    xml = g1_xml(stacks, root)
    onnx_path = export_folder_torchscript(dance / "policy.pt").path
    out = root / "robots" / "g1"
    flags = [str(xml), *G1_FLAGS, "--drive-from", str(dance / "policy.pt"), "--out", str(out)]
    assert robot_import(flags) == 0
    return out, onnx_path


@ON_G1_DANCE_WORKER
def test_a_few_seconds_of_the_dance_play_without_a_fall(g1_dance, tmp_path):
    """deploy-run --backend sim plays the clip its contract names once RUNNING: 4 s, no fall,
    the clip started and tracked within 0.15 rad RMS, 10 degrees of anchor error and 60 mm of
    root-relative body position error over the G1's 29 moving bodies."""
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    robot, policy = g1_dance
    report = tmp_path / "r.json"
    argv = ["--backend", "sim", "--robot", str(robot), "--policy", str(policy)]
    assert deploy_run_main([*argv, "--duration", "4", "--report", str(report)]) == 0
    r = json.loads(report.read_text())
    t = r["tracking"]
    assert r["locomotion"]["falls"] == 0 and t["plays"] == 1
    assert 0.05 < t["completed"] < 0.15
    assert t["joint_rms_rad_all"] < 0.15 and t["anchor_error_deg_mean"] < 10.0
    assert 0.0 < t["mpjpe_mm"] < 60.0 and t["bodies"] == 29


@ON_G1_DANCE_WORKER
def test_a_clip_pinned_at_its_first_frame_stands_still_until_it_starts(g1_dance, stacks, tmp_path):
    """--motion-start-after pins the clip at its first frame: the policy reads that frame with
    zero joint velocity while it waits. dance_102's clip with gangnam_style's first-row jump
    (26 rad/s from row 0 to row 1; rl_sar reads it for one tick) pinned for 2 s: no fall (read
    for the whole wait, the G1 fell within the 2 s, 86 hard-limit ticks)."""
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    robot, policy = g1_dance
    g = "policy/g1/whole_body_tracking/gangnam_style/G1_gangnam_style_V01.bvh_60hz.csv"
    rows = np.loadtxt(Path(policy).parent / CLIP, delimiter=",")
    jump = np.loadtxt(stacks.read("rl_sar", g).decode().splitlines()[:2], delimiter=",")
    rows[0, 7:] = rows[1, 7:] - (jump[1, 7:] - jump[0, 7:])
    clip = _csv(tmp_path / "jump.csv", rows)
    report = tmp_path / "r.json"
    argv = ["--backend", "sim", "--robot", str(robot), "--policy", str(policy), "--motion"]
    argv += [str(clip), "--motion-start-after", "2", "--duration", "2.5", "--report", str(report)]
    assert deploy_run_main(argv) == 0
    assert json.loads(report.read_text())["locomotion"]["falls"] == 0


@ON_G1_DANCE_WORKER
def test_a_beyondmimic_npz_of_the_dance_plays_through_deploy_run(g1_dance, stacks, tmp_path):
    """The dance's CSV turned into BeyondMimic's NPZ as whole_body_tracking's csv_to_npz.py
    writes it (50 Hz, articulation order, no names) plays through deploy-run --motion: 4 s, no
    fall, tracked as the CSV is (0.15 rad RMS, 10 degrees of anchor error)."""
    from sim2real.deploy.cli.deploy_run import deploy_run_main
    from tests.test_motion_npz import csv_to_npz

    robot, policy = g1_dance
    dance = dance_folder(stacks, tmp_path)
    npz = csv_to_npz(_rows(dance / _clip(dance)), tmp_path / "dance_102.npz")
    report = tmp_path / "r.json"
    argv = _motion_argv(robot, policy, npz)
    assert deploy_run_main([*argv, "--duration", "4", "--report", str(report)]) == 0
    t = json.loads(report.read_text())["tracking"]
    assert json.loads(report.read_text())["locomotion"]["falls"] == 0 and t["plays"] == 1
    assert t["joint_rms_rad_all"] < 0.15 and t["anchor_error_deg_mean"] < 10.0


@ON_G1_DANCE_WORKER
def test_a_re_exported_tracking_onnx_keeps_its_clip_and_plays(g1_dance, tmp_path):
    """policy-export of the dance's ONNX for the G1 stores its spec (the folder's contract no
    longer read) and keeps the clip in its ``motion`` metadata: deploy-run plays it, 2 s, no
    fall."""
    from sim2real.deploy.cli.deploy_run import deploy_run_main
    from sim2real.deploy.export.onnx_source import export_onnx_policy
    from sim2real.robots import load_robot

    robot, policy = g1_dance
    written = export_onnx_policy(policy, load_robot(robot), out=policy.with_name("re.onnx")).path
    meta = {p.key: p.value for p in onnx.load(written).metadata_props}
    assert "policy_spec" in meta and json.loads(meta["motion"])["columns"]
    report = tmp_path / "r.json"
    argv = ["--backend", "sim", "--robot", str(robot), "--policy", str(written)]
    assert deploy_run_main([*argv, "--duration", "2", "--report", str(report)]) == 0
    r = json.loads(report.read_text())
    assert r["locomotion"]["falls"] == 0 and r["tracking"]["plays"] == 1


@ON_G1_DANCE_WORKER
def test_deploy_run_refuses_a_clip_no_format_recognises_in_one_line(g1_dance, tmp_path, capsys):
    """deploy-run --motion with a BVH file exits 3 before the run: one line naming the file and
    the formats known."""
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    robot, policy = g1_dance
    clip = tmp_path / "take.bvh"
    clip.write_text("HIERARCHY\n")
    argv = _motion_argv(robot, policy, clip)
    assert deploy_run_main([*argv, "--duration", "1"]) == 3
    err = _errors(capsys)
    assert len(err) == 1 and f"{clip}: format: no clip format recognises it" in err[0], err
    assert "beyondmimic_npz (.npz)" in err[0] and "rl_sar_csv (.csv)" in err[0]


def test_tasks_are_chosen_by_name_from_the_registry():
    """task_for picks a registered task by name (the robot kind's by default); an unknown name
    and a name registered twice are refused; tracking without a clip is refused."""
    from sim2real.deploy.tasks.task import TASKS, register_task, task_for

    assert {"goals", "locomotion", "tracking"} <= set(TASKS)
    robot = SimpleNamespace(control_period=0.02)
    with pytest.raises(ValueError, match=r"task 'dance': expected one of \['goals', 'locomotion'"):
        task_for(robot, 1, None, period=1.0, rng=None, task="dance")
    with pytest.raises(ValueError, match="task 'goals': already registered"):
        register_task("goals", TASKS["goals"])
    with pytest.raises(ValueError, match="needs a reference motion"):
        task_for(robot, 1, None, period=1.0, rng=None, task="tracking")


@ON_G1_DANCE_WORKER
def test_a_tracking_policy_without_its_clip_is_refused_not_fed_zeros(g1_dance):
    """A runtime of the dance with no tracking task (a soak or a script that forgot the clip):
    its first tick refuses, naming the block, rather than read a clip of zeros."""
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.runtime import Runtime
    from sim2real.deploy.spec.motion_blocks import MotionBlockError
    from sim2real.robots import load_robot

    robot_dir, policy_path = g1_dance
    robot = load_robot(robot_dir)
    runtime = Runtime(robot, OnnxPolicy(policy_path, robot), SimBackend(robot, "position", envs=1))
    runtime.start()
    with pytest.raises(MotionBlockError, match="block 'motion_command' needs a reference motion"):
        runtime.tick()


@ON_G1_DANCE_WORKER
def test_deploy_run_refuses_a_clip_of_another_robot_in_one_line(g1_dance, tmp_path, capsys):
    """deploy-run --motion with a clip of 23 joints (a G1 23-dof's) exits 3 before the run, one
    line naming the file, the row and the joint count."""
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    robot, policy = g1_dance
    rows = _small(joints=23, frames=4)
    clip = _csv(tmp_path / "g1_23dof.csv", rows)
    argv = _motion_argv(robot, policy, clip)
    assert deploy_run_main([*argv, "--duration", "1"]) == 3
    err = _errors(capsys)
    assert len(err) == 1 and f"{clip}: row 1: expected 36 columns" in err[0], err


@pytest.mark.parametrize("fps", ["0", "-50", "nan", "fast"])
def test_a_motion_fps_not_above_zero_is_refused_naming_the_flag(go2_onnx, fps, capsys):
    """``--motion-fps 0``: one line naming the flag and the expected value, exit 3, before the
    run (it named the clip's ``fps`` field, or on a policy that reads no clip went unread)."""
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    argv = ["--backend", "sim", "--robot", "go2", "--policy", str(go2_onnx), "--duration", "0.1"]
    assert deploy_run_main([*argv, "--motion-fps", fps]) == 3
    err = _errors(capsys)
    assert err == [
        f"deploy-run: error: --motion-fps {fps}: expected the clip's frames per second, "
        "a number > 0"
    ], err


@ON_G1_DANCE_WORKER
def test_a_motion_fps_of_zero_for_the_dance_names_the_flag(g1_dance, capsys):
    """The same for the dance, whose contract names a clip and its rate."""
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    robot, policy = g1_dance
    argv = ["--backend", "sim", "--robot", str(robot), "--policy", str(policy)]
    assert deploy_run_main([*argv, "--duration", "0.1", "--motion-fps", "0"]) == 3
    err = _errors(capsys)
    assert len(err) == 1 and "--motion-fps 0: expected" in err[0] and "> 0" in err[0], err


def test_stand_appends_a_transition_to_home_then_holds_it(tmp_path):
    """``stand`` (holosoma's default_pose_append): past the 0.5 s clip, joints and velocities
    blend linearly from the last frame to home and zero over stand_s = 1 s, the root turns
    upright keeping the last frame's heading; then home holds; without a home it is refused."""
    home = np.array([-0.5, 0.05, 0.0, 0.0])  # robot order: a, waist yaw, roll, pitch
    clip = _yaw_clip(tmp_path)
    clock = MotionClock(clip, ("a", *WAIST), WAIST, envs=1, playback="stand", home=home,
                        stand_s=1.0)  # fmt: skip
    assert clock.total == pytest.approx(1.5)
    last_pos, last_vel, _ = clock.sample(clock.length)
    pos, vel, anchor = clock.sample(clock.length + 0.5)
    np.testing.assert_allclose(pos, 0.5 * (last_pos + home))
    np.testing.assert_allclose(vel, 0.5 * last_vel)
    pos, vel, anchor = clock.sample(clock.total)
    np.testing.assert_allclose(pos, home) and np.testing.assert_allclose(vel, 0.0)
    assert _yaw(anchor) == pytest.approx(0.5 + 0.2 * 4 + 0.05)  # the last heading, home's waist
    clock.start(np.ones(1, bool))
    for _ in range(30):
        clock.advance(0.1, np.ones(1, bool))
    assert clock.time[0] == pytest.approx(1.5) and clock.finished()[0]
    out = np.zeros((1, 12))
    clock.write(out)
    np.testing.assert_allclose(out[0, :4], home)
    assert len(clock.reference_poses()) == 5 + 10  # the clip's frames, then 1 s at 10 Hz
    assert clock.reference_index(clock.total) == 14
    with pytest.raises(ClipError, match=r"c\.csv: playback 'stand': home: expected 4"):
        MotionClock(clip, ("a", *WAIST), WAIST, envs=1, playback="stand")


def test_an_exhibition_plays_the_clip_rests_at_home_then_plays_it_again(tmp_path):
    """``exhibition``: the 0.5 s clip, 1 s to home, 2 s standing at home, then the clip again
    from its first frame (its second play, marked for a new yaw alignment)."""
    home = np.array([-0.5, 0.05, 0.0, 0.0])
    clock = MotionClock(_yaw_clip(tmp_path), ("a", *WAIST), WAIST, envs=1, playback="exhibition",
                        home=home, stand_s=1.0, rest_s=2.0)  # fmt: skip
    clock.start(np.ones(1, bool))
    out, seen = np.zeros((1, 12)), []
    for _ in range(40):  # 4 s at 10 Hz
        clock.advance(0.1, np.ones(1, bool))
        clock.write(out)
        seen.append((round(float(clock.time[0]), 6), bool(clock.restarted[0]), out[0, 0]))
    restarts = [i for i, (_, r, _) in enumerate(seen) if r]
    assert restarts == [34]  # after 0.5 + 1 + 2 = 3.5 s
    assert seen[34][0] == 0.0 and seen[34][2] == pytest.approx(0.0)  # the first frame again
    assert all(a == pytest.approx(-0.5) for t, _, a in seen[15:34])  # home from 1.5 s on
    assert clock.plays[0] == 2
    with pytest.raises(ClipError, match="rest_s: expected s >= 0"):
        MotionClock(_yaw_clip(tmp_path), ("a", *WAIST), WAIST, 1, "exhibition", home, 1.0, -1.0)


def test_the_heat_report_names_the_windings_that_derate_and_the_clip_they_start_in():
    """Three clips: the left knee passes its derating start in the second, the ankle in the
    third; the joint error of the clips before against the derated ones; a stopped clip is a
    fall."""
    from sim2real.eval.soak.exhibition import heat_report

    def play(rms, derating, hottest_c, stopped=False):
        return {"joint_rms_rad": rms, "derating": derating, "hottest": "left_knee_joint",
                "hottest_c": hottest_c, "stopped": stopped}  # fmt: skip

    plays = [play(0.08, [], 60.0), play(0.10, ["left_knee_joint"], 95.0),
             play(0.12, ["left_knee_joint", "left_ankle_pitch_joint"], 99.0, stopped=True)]  # fmt: skip
    h = heat_report(plays)
    assert h["derating"] == {"left_knee_joint": 2, "left_ankle_pitch_joint": 3}
    assert h["first_derated_clip"] == 2 and h["falls"] == 1 and h["completed"] == 2
    assert h["joint_rms_rad_before"] == pytest.approx(0.08)
    assert h["joint_rms_rad_derated"] == pytest.approx(0.11)
    assert h["hottest"] == {"left_knee_joint": 99.0}
    assert heat_report(plays[:1])["derating"] == {} and heat_report([])["clips"] == 0
