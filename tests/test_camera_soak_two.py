"""The soak with a policy that reads two cameras: each camera of each session has faults of its
own (sim2real/eval/soak/camera_faults.py ``camera_rng``), the session result has a section per
camera, and the verdict's labels name the camera whose fault came before a stop or a failure
(sim2real/eval/soak/camera_verdict.py). arm3 with two cameras above it (a copy of its folder),
one session of a few simulated seconds."""

from __future__ import annotations

import shutil
from dataclasses import replace

import numpy as np
import pytest
from onnx import TensorProto, helper, numpy_helper

from sim2real.deploy.backends.sim.camera import CameraFaults
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.spec.policy_spec import PolicySpec
from sim2real.eval.report.summary import camera_lines
from sim2real.eval.soak.camera_faults import camera_rng, session_camera_faults
from sim2real.eval.world.session_draw import session_rng
from sim2real.robots import load_robot
from sim2real.robots.loading import ROBOTS_DIR
from tests.soak_fixtures import short_session
from tests.test_camera import egl_works, needs_gl  # noqa: F401 - egl_works: needs_gl's condition
from tests.test_camera_rgb import TINY

CAMERAS = (
    '<camera name="overhead" pos="0.3 0 1.5" xyaxes="1 0 0 0 1 0"/>',
    '<camera name="side" pos="0.3 -1.2 0.4" xyaxes="1 0 0 0 0 1"/>',
)
BLOCKS = (replace(TINY, rate=10.0), replace(TINY, input="rgb_side", camera="side", rate=15.0))


def two_camera_arm3(out):
    """A copy of arm3's folder in ``out`` with :data:`CAMERAS` in its world body."""
    out.mkdir(parents=True)
    for f in ("robot.toml", "arm3.xml"):
        shutil.copy(ROBOTS_DIR / "arm3" / f, out / f)
    xml = (out / "arm3.xml").read_text()
    xml = xml.replace("<worldbody>", "<worldbody>\n    " + "\n    ".join(CAMERAS), 1)
    (out / "arm3.xml").write_text(xml)
    return out


def two_camera_policy(robot, tmp_path):
    """A policy of ``robot``'s default spec and :data:`BLOCKS`: every action is the mean of both
    images over ten (the vector ignored)."""
    spec = replace(PolicySpec.for_robot(robot), images=BLOCKS)
    d, n = spec.obs_dim, spec.act_dim
    a, b = BLOCKS
    nodes = [
        helper.make_node("MatMul", ["obs", "w"], ["zero"]),
        helper.make_node("ReduceMean", [a.input, "axes"], ["ma"], keepdims=0),
        helper.make_node("ReduceMean", [b.input, "axes"], ["mb"], keepdims=0),
        helper.make_node("Add", ["ma", "mb"], ["m"]),
        helper.make_node("Mul", ["m", "tenth"], ["small"]),
        helper.make_node("Unsqueeze", ["small", "one"], ["column"]),
        helper.make_node("Add", ["zero", "column"], ["action"]),
    ]
    weights = {
        "w": np.zeros((d, n), np.float32),
        "axes": np.arange(1, 1 + len(a.input_shape), dtype=np.int64),
        "one": np.array([1], np.int64),
        "tenth": np.array(0.05, np.float32),
    }
    graph = helper.make_graph(
        nodes,
        "two_means",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", d])]
        + [
            helper.make_tensor_value_info(x.input, TensorProto.FLOAT, ["batch", *x.input_shape])
            for x in BLOCKS
        ],
        [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", n])],
        initializer=[numpy_helper.from_array(v, k) for k, v in weights.items()],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 9
    helper.set_model_props(model, {"policy_spec": spec.to_json()})
    path = tmp_path / "two.onnx"
    path.write_bytes(model.SerializeToString())
    return OnnxPolicy(path, robot)


def test_each_camera_of_a_session_draws_its_own_faults_the_first_as_a_lone_camera():
    assert session_camera_faults(3, rng=camera_rng(3, 0)) == session_camera_faults(3)
    first = camera_rng(3, 0).random(4)
    np.testing.assert_array_equal(first, session_rng(3, "camera").random(4))
    assert session_camera_faults(3, rng=camera_rng(3, 1)) != session_camera_faults(3)


@needs_gl
def test_a_soak_session_of_a_two_camera_policy_names_the_camera_of_each_fault(tmp_path):
    """Both cameras freeze often (10-frame spells, past the stale limit): the session's stale
    stops are labelled by the camera that froze, each camera has its own section and its own
    line in the summary."""
    from sim2real.eval.soak import camera_faults
    from sim2real.eval.soak.batch import SessionBatch

    folder = two_camera_arm3(tmp_path / "arm3_two")
    robot = load_robot(folder)
    policy = two_camera_policy(robot, tmp_path)
    config = replace(short_session("arm3", policy.path, hours=8.0 / 3600), robot=str(folder))
    freezing = CameraFaults(freeze=0.08, freeze_frames=10)
    mp = pytest.MonkeyPatch()
    mp.setattr(camera_faults, "session_camera_faults", lambda *a, **k: freezing)
    try:
        (result,) = SessionBatch([replace(config, seed=5)], tmp_path / "soak", progress=False).run()
    finally:
        mp.undo()
    c = result["camera"]
    assert set(c["cameras"]) == {"overhead", "side"}
    overhead, side = c["cameras"]["overhead"], c["cameras"]["side"]
    assert overhead["rate_hz"] == 10.0 and side["rate_hz"] == 15.0
    assert overhead["frames"] >= 60 and side["frames"] >= 90  # 8 s, once started
    stops = c["verdict"]["stops"]
    assert stops["count"] >= 1
    labels = set(stops["by_fault"])
    assert labels and all(x.split(" ")[0] in ("overhead", "side") for x in labels), labels
    assert c["verdict"]["stopped_safely"].get("frozen", 0) >= 1
    lines = camera_lines({"id": "seed0005", "camera": c})
    assert sum(line.startswith("  camera       seed0005: 'overhead' 10 Hz") for line in lines) == 1
    assert sum(line.startswith("  camera       seed0005: 'side' 15 Hz") for line in lines) == 1


def test_a_failures_label_names_the_cameras_whose_faults_came_before_it():
    from sim2real.eval.soak.camera_verdict import fault_kind, fault_label

    quiet = {"dropped": 0, "spiked": 0, "frozen": 0}
    recent = {
        "window_s": 1.0, "dropped": 1, "spiked": 1, "frozen": 2,
        "by_camera": {"front": {**quiet, "frozen": 2, "spiked": 1}, "wrist": {**quiet, "dropped": 1},
                      "top": quiet},
    }  # fmt: skip
    assert fault_label(recent) == "front frozen+late; wrist dropped"
    assert fault_label({"window_s": 1.0, **quiet, "by_camera": {"front": quiet}}) == "none"
    assert fault_kind("wrist frozen+late") == "frozen" and fault_kind("dropped") == "dropped"
