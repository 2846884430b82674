"""Depth cameras: the image block's preprocessing (Extreme Parkour's crop, clip, resize and
normalisation), one-line refusals of bad frames and bad camera configurations, the plant's
rendered depth and its D435 noise at 1 m and 2 m, the camera's own rate beside the control rate,
a multi-input ONNX policy fed by the runtime, and a frozen or dropped camera stopping the robot
as a stale sensor does. Tiny frames, a few ticks: rendering runs on Mesa's software EGL here."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import replace
from functools import cache
from types import SimpleNamespace

import mujoco
import numpy as np
import pytest
from onnx import TensorProto, helper, numpy_helper

from sim2real.deploy.backends.sim.camera import (
    CameraFaults,
    DepthNoise,
    PlantDepthCamera,
    attach_plant_camera,
    depth_error,
)
from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.runtime import FAULT_CAUSES, Mode, Runtime
from sim2real.deploy.runtime.camera import CameraInput
from sim2real.deploy.spec.camera import CameraError, DepthImageBlock, check_frames, preprocess
from sim2real.deploy.spec.onnx_checks import PolicyLoadError
from sim2real.deploy.spec.policy_spec import PolicySpec, SpecError

#: The head camera of the tests: on the Go2's base ahead of its box, looking ahead (MuJoCo
#: cameras look along their -z), 58 deg vertical field of view (the D435's depth FOV).
HEAD = {"pos": [0.36, 0.0, 0.03], "xyaxes": [0, -1, 0, 0, 0, 1], "fovy": 58.0}
#: A tiny depth image: 12 x 16 delivered, 2 rows off the bottom, resized to 8 x 10.
TINY = DepthImageBlock(
    camera="head_depth", shape=(12, 16), crop=(0, 2, 1, 1), resize=(8, 10), frames=2, skip=2,
    rate=25.0, far=3.0,
)  # fmt: skip


@cache
def egl_works() -> bool:
    probe = (
        "import mujoco; from sim2real.deploy.backends.sim.depth_render import DepthRenderer; "
        'm = mujoco.MjModel.from_xml_string(\'<mujoco><worldbody><camera name="c"/>'
        "</worldbody></mujoco>'); DepthRenderer(m, 'c', (4, 4), 'probe').render(mujoco.MjData(m))"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["MUJOCO_GL"] = os.environ.get("MUJOCO_GL", "egl")
    done = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True)
    return done.returncode == 0


needs_gl = pytest.mark.skipif(
    "not egl_works()", reason="no EGL OpenGL context here (MUJOCO_GL=egl): nothing to render"
)


def head_camera_model(robot, wall: float | None = None) -> mujoco.MjModel:
    """The robot's plant model with the head camera on its base and, given ``wall``, a wall
    ``wall`` m ahead of the camera (as a user adds a ``<camera>`` to the robot's MJCF)."""
    spec = robot.mjspec("position")
    spec.body("base").add_camera(name="head_depth", **HEAD)
    if wall is not None:
        x = HEAD["pos"][0] + wall + 0.05
        spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.05, 3, 1], pos=[x, 0, 1])
    return spec.compile()


# ---------------------------------------------------------------------- the block, no GL
def test_preprocess_crops_fills_holes_clips_resizes_and_centres_as_extreme_parkour():
    block = DepthImageBlock(shape=(6, 8), crop=(0, 2, 1, 1), resize=(4, 6), near=0.0, far=2.0)
    frame = np.full((1, 6, 8), 1.0)
    frame[0, 4:] = 9.0  # the two bottom rows the crop removes
    frame[0, :, 0] = 9.0  # the left column it removes
    np.testing.assert_allclose(preprocess(frame, block), 0.0)  # (1 - 0) / 2 - 0.5
    frame[0, 1, 3] = 0.0  # no return: reads far, +0.5 after normalisation
    frame[0, 2, 4] = 5.0  # past far: clipped to far
    out = preprocess(frame, replace(block, resize=(4, 6)))
    assert out.shape == (1, 4, 6) and out.dtype == np.float32
    assert out[0, 1, 2] == pytest.approx(0.5) and out[0, 2, 3] == pytest.approx(0.5)
    ramp = np.tile(np.linspace(0.5, 1.5, 8), (1, 6, 1))  # bilinear keeps a linear ramp linear
    wide = preprocess(ramp, replace(block, crop=(0, 0, 0, 0), resize=(6, 4), far=2.0))
    np.testing.assert_allclose(np.diff(wide[0, 0]), np.diff(wide[0, 0])[0], atol=1e-6)


def test_bad_frames_are_refused_in_one_line_naming_the_camera_and_the_shape_expected():
    with pytest.raises(CameraError) as shape:
        check_frames(np.zeros((1, 10, 16)), TINY, 1, "frame.depth_image")
    with pytest.raises(CameraError) as text:
        check_frames(np.full((1, 12, 16), "1.0"), TINY, 1, "frame.depth_image")
    with pytest.raises(CameraError) as millimetres:  # a RealSense's uint16 depth units
        check_frames(np.full((1, 12, 16), 1000, np.uint16), TINY, 1, "frame.depth_image")
    assert "multiply by the device's depth scale" in str(millimetres.value)
    for err in (shape, text, millimetres):
        line = str(err.value)
        assert "\n" not in line and "frame.depth_image" in line and "'head_depth'" in line
    assert "(1, 12, 16)" in str(shape.value) and "<U3" in str(text.value)


def test_a_spec_with_an_image_block_round_trips_and_bad_entries_are_refused_in_one_line(go2):
    spec = replace(PolicySpec.for_robot(go2), images=(TINY,))
    assert PolicySpec.from_json(spec.to_json()) == spec
    d = json.loads(spec.to_json())
    for field, value, words in (
        ("resize", ["a", 3], "images[0].resize: expected a list of integers"),
        ("crop", [0, 20, 0, 0], "images[0].crop: [0, 20, 0, 0] leaves"),
        ("lens", 1, "images[0]: unknown field(s) ['lens']"),
        ("near", 4.0, "images[0]: near 4.0 m, far 3.0 m"),
    ):
        bad = json.loads(json.dumps(d))
        bad["images"][0][field] = value
        with pytest.raises(SpecError) as err:
            PolicySpec.from_json(json.dumps(bad), "policy.json")
        assert str(err.value).startswith("policy.json: " + words) and "\n" not in str(err.value)


def test_a_camera_the_mjcf_lacks_is_refused_in_one_line_naming_the_file(go2):
    spec = replace(PolicySpec.for_robot(go2), images=(replace(TINY, camera="chin"),))
    plant = SimBackend(go2, "position", envs=1, models=[head_camera_model(go2)])
    with pytest.raises(CameraError) as err:
        attach_plant_camera(plant, spec)
    line = str(err.value)
    assert "\n" not in line and str(go2.mjcf_path) in line and "images[0].camera" in line
    assert '<camera name="chin">' in line and "['head_depth']" in line


class Frames:
    """A camera driver's frames by hand: ``deliver(t, depth, stamp)`` as a backend writes them."""

    def __init__(self, block, envs=1):
        self.time = np.zeros(envs)
        self.depth_image = np.zeros((envs, *block.shape), np.float32)
        self.depth_stamp = np.full(envs, np.nan)

    def deliver(self, t, depth, stamp):
        self.time[:] = t
        self.depth_image[:] = depth
        self.depth_stamp[:] = stamp
        return self


def test_the_camera_stage_stacks_frames_skip_apart_and_takes_a_repeated_image_for_no_frame():
    block = replace(TINY, crop=(0, 0, 0, 0), resize=TINY.shape, near=0.0, far=10.0, frames=3)
    stage = CameraInput(block, 1, stale_limit=0.2)
    frames = Frames(block)
    value = lambda k: 1.0 + 0.5 * k  # noqa: E731 - frame k's depth everywhere, m
    norm = lambda d: d / 10.0 - 0.5  # noqa: E731 - centered over [0, 10] m
    stage.update(frames.deliver(0.0, value(0), 0.0))
    np.testing.assert_allclose(stage.image[0, :, 0, 0], norm(value(0)))  # the first fills it
    for k in range(1, 6):
        stage.update(frames.deliver(0.04 * k, value(k), 0.04 * k))
    # skip 2: the newest (5), two before it (3), two before that (1); oldest first
    np.testing.assert_allclose(stage.image[0, :, 0, 0], [norm(value(k)) for k in (1, 3, 5)])
    assert not stage.stale[0] and stage.taken[0] == 6
    frozen = value(5)  # the same image again with new stamps: not fresh
    for k in range(6, 12):
        stale = stage.update(frames.deliver(0.04 * k, frozen, 0.04 * k))
    assert stage.repeated[0] == 6 and stage.taken[0] == 6 and stale[0]
    assert stage.time_since_fresh[0] == pytest.approx(0.04 * 11 - 0.2)
    for t in (0.45, 0.46):  # the last frozen frame held over two more ticks: still one frame
        stage.update(frames.deliver(t, frozen, 0.04 * 11))
    assert stage.repeated[0] == 6 and stage.stale_phrase(0).startswith("6 frames repeated")
    stage.update(frames.deliver(0.48, value(12), 0.48))  # fresh, then frozen once: a stop says 1
    stage.update(frames.deliver(0.52, value(12), 0.52))
    assert stage.repeated[0] == 7 and stage.stale_phrase(0).startswith("1 frame repeated")
    state = stage.state_dict()
    other = CameraInput(block, 1, stale_limit=0.2)
    other.load_state_dict(state)
    np.testing.assert_array_equal(other.image, stage.image)
    narrow = SimpleNamespace(
        time=np.full(1, 0.5), depth_stamp=np.full(1, 0.5), depth_image=np.zeros((1, 12, 15))
    )
    with pytest.raises(CameraError) as err:  # a driver's frame of another shape
        stage.update(narrow)
    assert "frame.depth_image: camera 'head_depth' gave a frame of shape (1, 12, 15)" in str(
        err.value
    )


# ---------------------------------------------------------------------- rendered
def depth_policy(robot, tmp_path, block=TINY, stored=None) -> OnnxPolicy:
    """A two-input policy of ``robot``'s default spec plus ``block`` (a depth or an RGB block):
    every action is the mean of the image input (batch, *block.input_shape) over ten, whatever
    the vector says; its spec in the file names ``stored`` (default ``block``)."""
    spec = replace(PolicySpec.for_robot(robot), images=(block,))
    d, n = spec.obs_dim, spec.act_dim
    nodes = [
        helper.make_node("MatMul", ["obs", "w"], ["zero"]),
        helper.make_node("ReduceMean", [block.input, "axes"], ["mean"], keepdims=0),
        helper.make_node("Mul", ["mean", "tenth"], ["small"]),
        helper.make_node("Unsqueeze", ["small", "one"], ["column"]),
        helper.make_node("Add", ["zero", "column"], ["action"]),
    ]
    weights = {
        "w": np.zeros((d, n), np.float32),
        "axes": np.arange(1, 1 + len(block.input_shape), dtype=np.int64),
        "one": np.array([1], np.int64),
        "tenth": np.array(0.1, np.float32),
    }
    graph = helper.make_graph(
        nodes,
        "depth_mean",
        [
            helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", d]),
            helper.make_tensor_value_info(
                block.input, TensorProto.FLOAT, ["batch", *block.input_shape]
            ),
        ],
        [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", n])],
        initializer=[numpy_helper.from_array(v, k) for k, v in weights.items()],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 9
    stored = spec if stored is None else replace(spec, images=(stored,))
    helper.set_model_props(model, {"policy_spec": stored.to_json()})
    path = tmp_path / f"{block.input}.onnx"
    path.write_bytes(model.SerializeToString())
    return OnnxPolicy(path, robot)


def test_a_graph_input_of_another_shape_than_the_image_block_is_refused_in_one_line(go2, tmp_path):
    with pytest.raises(PolicyLoadError) as err:
        depth_policy(go2, tmp_path, stored=replace(TINY, resize=(9, 10)))
    line = str(err.value)
    assert "\n" not in line and "graph input 'depth'" in line and "[batch, 2, 9, 10]" in line


@needs_gl
def test_the_depth_of_a_wall_and_the_d435_models_error_at_1_m_and_2_m(go2):
    for at in (1.0, 2.0):
        plant = SimBackend(go2, "position", envs=1, models=[head_camera_model(go2, wall=at)])
        camera = PlantDepthCamera(plant, replace(TINY, shape=(24, 32)), seed=3)
        truth = camera.true_depth()
        centre = truth[6:12, 12:20]  # above the horizon: the wall, straight ahead
        np.testing.assert_allclose(centre, at, rtol=0, atol=2e-3)
        e = depth_error(camera, 40, at)
        sigma = DepthNoise().sigma(at)  # 1 % at 1 m, 2 % at 2 m: the datasheet's bound
        assert e["rms_m"] == pytest.approx(sigma, rel=0.1)
        camera.close()


@needs_gl
def test_the_runtime_feeds_a_two_input_policy_the_cameras_frames_at_the_cameras_rate(go2, tmp_path):
    plant = SimBackend(go2, "position", envs=1, models=[head_camera_model(go2, wall=1.0)])
    policy = depth_policy(go2, tmp_path)
    camera = attach_plant_camera(
        plant, policy.spec, latency=0.03, noise=DepthNoise(k=0, edge_jump=0)
    )
    rt = Runtime(go2, policy, plant)
    rt.start()
    rt.run(50)  # 1 s at 50 Hz; the camera at 25 Hz
    assert camera.frames[0] == pytest.approx(25 + 1, abs=1)
    age = rt.cameras.time_since_fresh[0]
    assert 0.03 - 1e-9 <= age <= 0.03 + 1 / 25 + 1e-9
    assert (rt.mode == Mode.RUNNING).all() and rt.cameras.taken[0] >= 20
    expected = preprocess(camera.true_depth()[None], TINY)[0]  # the robot stands: one view
    np.testing.assert_allclose(policy.images["depth"][0, -1], expected, atol=0.01)  # 2 cm
    assert policy.graph_action[0, 0] == pytest.approx(0.1 * policy.images["depth"].mean(), abs=1e-6)


@needs_gl
@pytest.mark.parametrize(
    "faults",
    [
        CameraFaults(freeze=1.0, freeze_frames=1000),  # the first image again, stamped anew
        CameraFaults(drop=1.0),  # nothing arrives
        CameraFaults(spike=1.0, spike_latency=0.5),  # every frame half a second late
    ],
)
def test_a_frozen_silent_or_late_camera_stops_the_robot_as_a_stale_sensor(go2, tmp_path, faults):
    plant = SimBackend(go2, "position", envs=1, models=[head_camera_model(go2, wall=1.0)])
    policy = depth_policy(go2, tmp_path)
    attach_plant_camera(plant, policy.spec, faults=faults)
    rt = Runtime(go2, policy, plant)
    rt.start()
    rt.run(30)
    assert rt.mode[0] >= Mode.SAFE_STOP
    assert FAULT_CAUSES[rt.cause[0]] == "stale_sensor"
    record = rt.stale_stops.records[0]
    assert record["camera_s"] > rt.cameras.stale_limit and not record["joints"]
    frozen = "frames repeated with new stamps (frozen)"
    said = frozen if faults.freeze else "no fresh frame arrived (dropped or late)"
    assert record["verdict"].startswith("depth camera 'head_depth': no fresh reading for")
    assert said in record["verdict"]


def test_policy_export_inspect_shows_the_image_input_and_its_block(go2, tmp_path, capsys):
    from sim2real.deploy.cli.policy_export import main

    policy = depth_policy(go2, tmp_path)
    assert main([str(policy.path), "--inspect"]) == 0
    out = capsys.readouterr().out
    assert "depth        float32  [batch, 2, 8, 10]" in out
    assert (
        "images: depth <- depth camera 'head_depth' 12x16 at 25 Hz, crop [0, 2, 1, 1] (top, "
        "bottom, left, right), resize 8x10 bilinear, clip 0-3 m centered, 2 frames 2 apart, "
        "latency 0 s"
    ) in out


@needs_gl
def test_the_bench_item_times_the_render_and_states_the_error_at_1_m_and_2_m(tmp_path):
    from bench.camera_cost import measure

    sec = measure(tmp_path, 5)
    assert [r["what"] for r in sec["rows"]] == [
        "render 60 x 106 (Extreme Parkour)",
        "render 240 x 424",
        "render arm3 task scene 96 x 72",
        "render RGB 96 x 128",
        "RGB sensor model 96 x 128",
        "render RGB 480 x 640 (LeRobot)",
        "RGB sensor model 480 x 640",
        "preprocess 60 x 106 -> 58 x 87",
        "preprocess RGB 480 x 640 -> 96 x 128",
    ]
    assert all(r["samples"] == 5 and r["p50_us"] > 0 for r in sec["rows"])
    errors = {e["at_m"]: e for e in sec["errors"]}
    assert errors[1.0]["rms_percent"] == pytest.approx(1.0, rel=0.1)
    assert errors[2.0]["rms_percent"] == pytest.approx(2.0, rel=0.1)
    assert errors[2.0]["datasheet_percent"] == 2.0


def test_deploy_run_refuses_a_camera_the_robots_mjcf_lacks_in_one_line(go2, tmp_path, capsys):
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    policy = depth_policy(go2, tmp_path)  # the shipped Go2 has no <camera name="head_depth">
    code = deploy_run_main(["--robot", "go2", "--policy", str(policy.path), "--duration", "0.2"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 3 and len([line for line in err if "error" in line]) == 1
    assert err[-1].startswith(f"deploy-run: error: {go2.mjcf_path}: images[0].camera")
    assert '<camera name="head_depth">' in err[-1]


@needs_gl
def test_deploy_run_renders_the_head_camera_of_a_robot_folder_at_the_rate_asked(tmp_path, capsys):
    from bench.camera_cost import head_camera_robot
    from sim2real.deploy.cli.deploy_run import deploy_run_main
    from sim2real.robots import load_robot

    folder = head_camera_robot(tmp_path / "go2_head", target=1.5)  # as a user adds a camera
    policy = depth_policy(load_robot(folder), tmp_path)
    report = tmp_path / "report.json"
    code = deploy_run_main(
        ["--robot", str(folder), "--policy", str(policy.path), "--duration", "1",
         "--camera-rate", "30", "--camera-latency", "0.02", "--report", str(report)]
    )  # fmt: skip
    out, err = capsys.readouterr()
    assert code == 0, out + err
    assert "deploy-run: depth camera 'head_depth' 12x16 at 30 Hz, latency 0.02 s" in err
    camera = json.loads(report.read_text())["camera"]
    assert camera["plant"]["frames"] == [
        30
    ]  # captured at 0, 1/30 .. 29/30 s and camera["plant"]["rate_hz"] == 30
    assert camera["frames_taken"][0] >= 29 and camera["frames_repeated"] == [0]
    assert camera["oldest_s"][0] <= 0.02 + 1 / 30 + 1e-6  # the newest frame's age at most


@needs_gl
def test_a_knocked_camera_sees_the_wall_obliquely_and_a_covered_lens_reads_no_depth(go2):
    plant = SimBackend(go2, "position", envs=1, models=[head_camera_model(go2, wall=1.0)])
    faults = CameraFaults(occlusion=0.25, extrinsic=(0.0, 0.3, 0.0))  # 0.3 rad about its up axis
    block = replace(TINY, shape=(25, 33))  # an odd size: a centre pixel on the optical axis
    camera = PlantDepthCamera(plant, block, noise=DepthNoise(k=0, edge_jump=0), faults=faults)
    straight = PlantDepthCamera(plant, block, noise=DepthNoise(k=0, edge_jump=0))
    assert straight.true_depth()[12, 16] == pytest.approx(1.0, abs=2e-3)
    assert camera.true_depth()[12, 16] == pytest.approx(1.0 / np.cos(0.3), abs=2e-3)
    frame = SimpleNamespace(time=np.zeros(1))
    camera.fill(frame)
    blind = round(0.25 * 33)
    assert (frame.depth_image[0, :, :blind] == 0).all()
    assert (frame.depth_image[0, :12, blind:] > 0).all()  # the wall above the horizon


@needs_gl
def test_deploy_run_draws_the_runs_camera_faults_from_its_seed(tmp_path, capsys):
    from bench.camera_cost import head_camera_robot
    from sim2real.deploy.backends.sim.camera import CameraFaultRanges
    from sim2real.deploy.cli.deploy_run import deploy_run_main
    from sim2real.robots import load_robot

    folder = head_camera_robot(tmp_path / "go2_head", target=1.5)
    policy = depth_policy(load_robot(folder), tmp_path)
    report = tmp_path / "report.json"
    code = deploy_run_main(
        ["--robot", str(folder), "--policy", str(policy.path), "--duration", "0.5",
         "--camera-faults", "drawn", "--seed", "3", "--report", str(report)]
    )  # fmt: skip
    out, err = capsys.readouterr()
    assert code != 3, out + err  # a frozen spell or late frames may stop it (the test's policy
    # is no walker: it may then lie down onto a joint limit, exit 1)
    drawn = CameraFaultRanges().sample(np.random.default_rng([3, 99])).to_dict()
    assert f"faults {drawn}" in err
    assert json.loads(report.read_text())["camera"]["plant"]["faults"] == json.loads(
        json.dumps(drawn)
    )


@needs_gl
@pytest.mark.parametrize("trained", [0.5, 0.0])
def test_a_camera_as_late_as_in_training_runs_and_one_later_than_its_spec_says_stops(
    go2, tmp_path, trained
):
    """Frames half a second old at 10 Hz: the Go2's stale limit (0.16 s) and three frame
    periods do not cover them; the block's training latency does (Robot Parkour Learning's
    Go1 student trains with frames 0.25-0.30 s late)."""
    plant = SimBackend(go2, "position", envs=1, models=[head_camera_model(go2, wall=1.0)])
    policy = depth_policy(go2, tmp_path, replace(TINY, rate=10.0, latency=trained))
    attach_plant_camera(plant, policy.spec, latency=0.5)
    rt = Runtime(go2, policy, plant)
    rt.start()
    rt.run(50)
    if trained:
        assert (rt.mode == Mode.RUNNING).all(), (rt.cause_names(), rt.stale_stops.records)
        assert rt.cameras.taken[0] >= 4  # delivered at 0.5 .. 0.9 s
    else:
        assert FAULT_CAUSES[rt.cause[0]] == "stale_sensor"


def test_an_image_input_the_spec_does_not_name_is_refused_saying_how_to_name_it(go2, tmp_path):
    import onnx

    policy = depth_policy(go2, tmp_path)
    model = onnx.load(policy.path)
    del model.metadata_props[:]  # a foreign file: the spec comes from the user
    bare = tmp_path / "bare.onnx"
    onnx.save(model, bare)
    with pytest.raises(PolicyLoadError) as err:
        OnnxPolicy(bare, go2, spec=replace(policy.spec, images=()))
    line = str(err.value)
    assert "\n" not in line and "'depth' ['batch', 2, 8, 10]" in line
    assert 'an "images" entry naming it (docs/cameras.md)' in line
    assert OnnxPolicy(bare, go2, spec=policy.spec).images["depth"].shape == (1, 2, 8, 10)


@needs_gl
def test_a_process_that_rendered_depth_can_still_import_torchs_compiler():
    """Mesa's llvmpipe and triton each load an LLVM: triton imported second crashed the process
    (a pytest worker with it); the renderer imports triton first where it is installed."""
    pytest.importorskip("triton")
    probe = (
        "import mujoco; from sim2real.deploy.backends.sim.depth_render import DepthRenderer; "
        'm = mujoco.MjModel.from_xml_string(\'<mujoco><worldbody><camera name="c"/>'
        "</worldbody></mujoco>'); DepthRenderer(m, 'c', (4, 4), 'probe').render(mujoco.MjData(m)); "
        "import triton; print('alive')"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    done = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True)
    assert done.returncode == 0 and "alive" in done.stdout, done.stderr[-500:]


@needs_gl
def test_a_switch_to_a_camera_policy_carries_the_camera_and_one_without_drops_it(go2, tmp_path):
    """The runtime starts on a policy without an image input, the plant's camera attached for a
    second one that reads it; switch_policy builds the camera stage for the second, which then
    gets the camera's frames and stays RUNNING; back to the first, no stage (no stale stop for
    a camera nobody reads). A camera policy the backend's camera does not serve is refused in
    one line and the policy in control stays."""
    plant = SimBackend(go2, "position", envs=1, models=[head_camera_model(go2, wall=1.0)])
    seeing = depth_policy(go2, tmp_path)
    blind = OnnxPolicy(linear_policy_file(go2, tmp_path), go2)
    attach_plant_camera(plant, seeing.spec, latency=0.0, noise=DepthNoise(k=0, edge_jump=0))
    rt = Runtime(go2, blind, plant)
    assert rt.cameras is None
    rt.start()
    rt.run(30)
    rt.switch_policy(seeing)
    assert rt.cameras is not None and rt.cameras.block == seeing.spec.images[0]
    rt.run(30)
    assert (rt.mode == Mode.RUNNING).all() and rt.cameras.taken[0] >= 10
    assert np.isfinite(seeing.images["depth"]).all() and seeing.images["depth"].any()
    rt.switch_policy(blind)
    assert rt.cameras is None
    (tmp_path / "other").mkdir()
    other = depth_policy(go2, tmp_path / "other", block=replace(TINY, camera="tail_depth"))
    with pytest.raises(ValueError) as err:
        rt.switch_policy(other)
    line = str(err.value)
    assert "\n" not in line and "'tail_depth'" in line and "'head_depth'" in line
    assert rt.policy is blind and rt.cameras is None


def linear_policy_file(robot, tmp_path):
    """A zero-action ONNX policy of ``robot``'s default spec (the home pose), no image input."""
    from tests.runtime_fixtures import linear_onnx

    spec = PolicySpec.for_robot(robot)
    nodes = [helper.make_node("MatMul", ["obs", "w"], ["action"])]
    weights = {"w": np.zeros((spec.obs_dim, spec.act_dim), np.float32)}
    return linear_onnx(spec, tmp_path / "blind.onnx", nodes, weights, "blind")
