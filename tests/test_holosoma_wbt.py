"""holosoma's whole-body tracking export (``fastsac_g1_29dof_dancing.onnx`` of amazon-far/holosoma,
read from its checkout under ``SIM2REAL_STACKS``, :mod:`tests.stacks`; skipped without it): its contract with holosoma_inference's wbt configs,
the clip baked in its graph as holosoma_inference plays it, bad clips refused in one line, and a
few seconds of the dance through deploy-run with no hand spec."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper

from sim2real.deploy.spec.motion_blocks import quat_conj, quat_mul
from sim2real.deploy.tasks.motion.clip import ClipError
from sim2real.deploy.tasks.motion.clock import MotionClock
from sim2real.deploy.tasks.motion.onnx_holosoma import WAIST, read_holosoma_onnx_motion
from tests.motion_files import G1_FLAGS, g1_xml

ort = pytest.importorskip("onnxruntime")

WBT = "src/holosoma_inference/holosoma_inference/models/wbt/fastsac_g1_29dof_dancing.onnx"


def _wbt(stacks, root: Path) -> Path:
    data = stacks.read("holosoma", WBT)
    if data.startswith(b"version https://git-lfs"):
        pytest.skip(f"{WBT} is a Git LFS pointer in the checkout")
    out = root / "fastsac_g1_29dof_dancing.onnx"
    out.write_bytes(data)
    return out


@pytest.fixture(scope="module")
def wbt(stacks, tmp_path_factory) -> Path:
    return _wbt(stacks, tmp_path_factory.mktemp("wbt"))


def _names(path: Path) -> list[str]:
    md = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    return json.loads(md["dof_names"])


def test_the_contract_is_holosoma_inferences_wbt_config(wbt):
    """Terms in holosoma_inference's sorted order with our blocks (the torso's error reading
    the waist), scale 1 (task wbt, not the 0.25 of holosoma #125), its G1 default pose by name,
    50 Hz, time_step fed 0, the clip named as the graph itself."""
    from sim2real.deploy.spec.foreign.registry import OnnxFacts, read_contract

    c = read_contract(OnnxFacts.of(wbt, onnx.load(str(wbt))))
    assert c.format == "holosoma" and c.obs_dim == 154
    assert [(t.name, t.kind, c.term_size(t)) for t in c.terms] == [
        ("actions", "last_action", 29),
        ("base_ang_vel", "base_angular_velocity", 3),
        ("dof_pos", "joint_position", 29),
        ("dof_vel", "joint_velocity", 29),
        ("motion_command", "motion_command", 58),
        ("motion_ref_ori_b", "motion_anchor_ori_b", 6),
    ]
    names = _names(wbt)
    assert c.terms[-1].joints == tuple(names.index(j) for j in WAIST)
    assert c.action_scale == 1.0 and c.action_clip == 100.0 and c.control_rate == 50.0
    assert c.default_pose[names.index("left_knee_joint")] == 0.669
    assert c.constant_inputs == {"time_step": 0.0}
    assert c.motion.file == str(wbt) and c.motion.timing == "holosoma_onnx"


def test_the_clock_gives_each_tick_the_graphs_frame_of_the_tick_before(wbt):
    """holosoma_inference feeds step k at tick k and observes the outputs of tick k - 1: the
    clock's joints, velocities and torso at tick k are the graph's at time_step max(k - 1, 0),
    through the clip's end (held)."""
    names = _names(wbt)
    clip = read_holosoma_onnx_motion(wbt, 50.0, names)
    clock = MotionClock(clip, names, WAIST, 1)
    session = ort.InferenceSession(str(wbt))
    obs = np.zeros((1, 154), np.float32)
    last = clip.frames - 2  # the graph's last frame
    for k in (0, 1, 2, 777, last + 1, last + 40):
        step = np.array([[min(max(k - 1, 0), last + 5)]], np.float32)
        pos, vel, quat = session.run(
            ["joint_pos", "joint_vel", "ref_quat_xyzw"], {"obs": obs, "time_step": step}
        )
        p, v, torso = clock.sample(k / 50.0)
        np.testing.assert_allclose(p, pos[0], atol=1e-5)
        np.testing.assert_allclose(v, vel[0], atol=1e-4)
        d = quat_mul(quat_conj(torso), quat[0][[3, 0, 1, 2]])
        assert abs(abs(d[0]) - 1.0) < 1e-6  # the same rotation


def test_the_actions_read_obs_alone_and_a_graph_whose_actions_read_time_step_is_refused(tmp_path):
    step = helper.make_tensor_value_info("time_step", TensorProto.FLOAT, [1, 1])
    obs = helper.make_tensor_value_info("obs", TensorProto.FLOAT, [1, 2])
    out = helper.make_tensor_value_info("actions", TensorProto.FLOAT, [1, 2])
    graph = helper.make_graph(
        [helper.make_node("Add", ["obs", "time_step"], ["actions"])], "g", [obs, step], [out]
    )
    path = tmp_path / "bad.onnx"
    onnx.save(helper.make_model(graph), str(path))
    with pytest.raises(ClipError, match=r"bad.onnx: actions: .* read time_step"):
        read_holosoma_onnx_motion(path, 50.0, ["a", "b"])


def _small_wbt(path: Path, frames: int) -> Path:
    """A graph shaped as holosoma's WBT export (module docstring of
    sim2real/deploy/tasks/motion/onnx_holosoma.py): ``actions`` from ``obs``, the clip's tables
    gathered at ``time_step``; joints: the waist's three and one more, the clip at rest."""
    cols = 4
    tables = {
        "joint_pos": np.zeros((frames, cols)),
        "joint_vel": np.zeros((frames, cols)),
        "ref_pos_xyz": np.tile([0.0, 0.0, 1.0], (frames, 1)),
        "ref_quat_xyzw": np.tile([0.0, 0.0, 0.0, 1.0], (frames, 1)),
    }
    inits = [helper.make_tensor("index", TensorProto.INT64, [], [0])]
    nodes = [helper.make_node("Identity", ["obs"], ["actions"])]
    outputs = [helper.make_tensor_value_info("actions", TensorProto.FLOAT, [1, cols])]
    for name, table in tables.items():
        inits.append(helper.make_tensor(f"{name}_table", TensorProto.FLOAT, table.shape,
                                        table.ravel().tolist()))  # fmt: skip
        nodes.append(helper.make_node("Gather", [f"{name}_table", "index"], [name]))
        outputs.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, [table.shape[1]]))
    inputs = [
        helper.make_tensor_value_info("obs", TensorProto.FLOAT, [1, cols]),
        helper.make_tensor_value_info("time_step", TensorProto.FLOAT, [1, 1]),
    ]
    onnx.save(helper.make_model(helper.make_graph(nodes, "wbt", inputs, outputs, inits)), path)
    return path


def test_the_clip_is_named_by_holosomas_frames_and_rate_not_the_clocks(tmp_path):
    """holosoma_inference plays the graph's T frames one a tick at rl_rate (50 Hz): the clip
    carries T + 1 frames at 50 x (T + 1) / T Hz for the clock (the first frame twice), and is
    named as holosoma plays it, T frames at 50 Hz, its length T / 50 s (a report said 6775
    frames at 50.0074 Hz for the 6774 of fastsac_g1_29dof_dancing.onnx)."""
    frames = 200
    columns = ["a_joint", *WAIST]
    clip = read_holosoma_onnx_motion(_small_wbt(tmp_path / "w.onnx", frames), 50.0, columns)
    assert clip.frames == frames + 1 and clip.fps == pytest.approx(50.0 * 201 / 200)
    assert clip.shown == (frames, 50.0)
    assert MotionClock(clip, columns, WAIST, 1).length == pytest.approx(frames / 50.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"columns": 23}, r"joint_pos: expected a clip table \(\d+, 23\)"),
        (
            {"limits": {"left_knee_joint": (-0.08, 0.5)}},
            r"frame \d+ joint left_knee_joint: .* hard limit",
        ),
        ({"rate": float("nan")}, r"fps: expected a positive number"),
        ({"rate": 0.0}, r"fps: expected a positive number"),
        ({"rate": "50"}, r"fps: expected a positive number"),
    ],
)
def test_a_clip_that_does_not_fit_is_refused_in_one_line(wbt, kwargs, match):
    names = _names(wbt)
    columns = names[: kwargs.pop("columns")] if "columns" in kwargs else names
    args = {"rate": 50.0, "columns": columns, **kwargs}
    with pytest.raises(ClipError, match=match) as err:
        read_holosoma_onnx_motion(wbt, **args)
    assert str(err.value).startswith(str(wbt)) and "\n" not in str(err.value)


def test_dof_names_of_another_robot_are_refused_by_name(wbt, tmp_path):
    from sim2real.deploy.spec.foreign.contract import ForeignFormatError
    from sim2real.deploy.spec.foreign.registry import OnnxFacts, read_contract

    model = onnx.load(str(wbt))
    for p in model.metadata_props:
        if p.key == "dof_names":
            p.value = json.dumps([n.replace("waist", "torso") for n in json.loads(p.value)])
    other = tmp_path / "other.onnx"
    onnx.save(model, str(other))
    with pytest.raises(ForeignFormatError, match="dof_names.*not the G1 29-DoF"):
        read_contract(OnnxFacts.of(other, onnx.load(str(other))))


def test_a_few_seconds_of_holosomas_dance_play_with_no_hand_spec(stacks, wbt, tmp_path):
    """unitree_mujoco's G1 imported with robot-level flags (gains from the file), then
    deploy-run --backend sim on the file alone: 4 s, no fall, the clip tracked; started 1 s
    into RUNNING (--motion-start-after: the policy holds the first frame meanwhile)."""
    from sim2real.deploy.cli.deploy_run import deploy_run_main
    from sim2real.deploy.cli.robot_import import main as robot_import

    robot = tmp_path / "g1"
    xml = g1_xml(stacks, tmp_path)
    assert robot_import([str(xml), *G1_FLAGS, "--drive-from", str(wbt), "--out", str(robot)]) == 0
    report = tmp_path / "r.json"
    argv = ["--backend", "sim", "--robot", str(robot), "--policy", str(wbt)]
    argv += ["--motion-start-after", "1", "--duration", "4", "--report", str(report)]
    assert deploy_run_main(argv) == 0
    r = json.loads(report.read_text())
    t = r["tracking"]
    assert r["locomotion"]["falls"] == 0 and t["plays"] == 1
    assert t["fps"] == 50.0 and t["length_s"] == pytest.approx(t["frames"] / 50.0)
    played = t["completed"] * t["length_s"]
    assert abs(played - (r["locomotion"]["running_s"] - 1.0)) < 0.03  # a tick
    assert t["joint_rms_rad_all"] < 0.15 and t["anchor_error_deg_mean"] < 10.0
