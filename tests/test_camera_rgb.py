"""RGB cameras: the RGB image block (crop, resize, channel order, layout, normalisation, frame
history), one-line refusals of bad frames and bad configurations, the plant's rendered colour
frames with the OV5647 sensor model and the session's faults (lighting, a covered lens, a knocked
camera), a multi-input ONNX policy fed by the runtime, and a frozen colour camera stopping the
robot as a stale sensor. arm3 with a camera above it, tiny frames, a few ticks."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import mujoco
import numpy as np
import pytest

from sim2real.deploy.backends.sim.camera import CameraFaults, attach_plant_camera
from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.backends.sim.rgb_camera import PlantRgbCamera, RgbNoise
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.runtime import FAULT_CAUSES, Mode, Runtime
from sim2real.deploy.runtime.camera import CameraInput
from sim2real.deploy.spec.camera import (
    CameraError,
    RgbImageBlock,
    check_frames,
    image_blocks,
    preprocess,
)
from sim2real.deploy.spec.onnx_checks import PolicyLoadError
from sim2real.deploy.spec.policy_spec import PolicySpec
from tests.test_camera import depth_policy, egl_works, needs_gl  # noqa: F401 - egl_works: needs_gl's condition

#: A tiny colour image: 12 x 16 delivered, one column off each side, resized to 6 x 7, two
#: frames two apart, 25 Hz.
TINY = RgbImageBlock(
    camera="overhead", shape=(12, 16), crop=(0, 0, 1, 1), resize=(6, 7), frames=2, skip=2,
    rate=25.0,
)  # fmt: skip


def overhead_model(robot, mode: str = "position") -> mujoco.MjModel:
    """arm3's plant model with a grey floor and a camera 1.5 m above the arm looking down
    (MuJoCo cameras look along their -z), as a user adds a ``<camera>`` to the MJCF."""
    spec = robot.mjspec(mode)
    spec.worldbody.add_camera(name="overhead", pos=[0.3, 0, 1.5], xyaxes=[1, 0, 0, 0, 1, 0])
    spec.worldbody.add_geom(
        type=mujoco.mjtGeom.mjGEOM_PLANE, size=[2, 2, 0.1], pos=[0, 0, -0.05],
        rgba=[0.5, 0.5, 0.5, 1], contype=0, conaffinity=0,
    )  # fmt: skip
    return spec.compile()


# ---------------------------------------------------------------------- the block, no GL
def test_preprocess_crops_resizes_scales_and_lays_out_the_channels_as_the_block_says():
    frame = np.zeros((1, 4, 6, 3), np.uint8)
    frame[..., 0], frame[..., 1], frame[..., 2] = 255, 51, 0  # R 1.0, G 0.2, B 0.0
    frame[0, :, 0] = 7  # the column the crop removes
    block = RgbImageBlock(shape=(4, 6), crop=(0, 0, 1, 0), resize=(2, 5))
    chw = preprocess(check_frames(frame, block, 1, "t"), block)
    assert chw.shape == (1, 3, 2, 5) and chw.dtype == np.float32
    np.testing.assert_allclose(chw[0, :, 0, 0], [1.0, 0.2, 0.0], atol=1e-6)
    bgr = replace(block, channel_order="BGR", layout="HWC", normalisation="mean_std")
    hwc = preprocess(frame, bgr)
    assert hwc.shape == (1, 2, 5, 3) == (1, *bgr.input_shape[1:])
    want = (np.array([0.0, 0.2, 1.0]) - np.array(bgr.mean)) / np.array(bgr.std)
    np.testing.assert_allclose(hwc[0, 1, 4], want, atol=1e-5)


def test_an_rgb_block_round_trips_in_a_spec_and_bad_entries_are_refused_in_one_line(arm3):
    spec = replace(PolicySpec.for_robot(arm3), images=(TINY,))
    text = spec.to_json()
    assert '"kind": "rgb"' in text
    assert PolicySpec.from_json(text).images == (TINY,)
    bad = [
        ({"kind": "rgb", "shape": [8, 10], "resize": [9, 10]}, "images[0].resize: [9, 10] is "
         "bigger than the cropped render [8, 10]; expected at most [8, 10]"),
        ({"kind": "rgb", "layout": "NCHW"}, "images[0].layout: 'NCHW', expected one of"),
        ({"kind": "rgb", "std": [0.2, 0, 0.2]}, "images[0].std: [0.2, 0.0, 0.2], expected 3 "
         "positive"),
        ({"kind": "rgb", "shape": ["a", 3]}, "images[0].shape: expected a list of integers"),
        ({"kind": "colour"}, "images[0].kind: 'colour', expected one of ('depth', 'rgb')"),
    ]  # fmt: skip
    for entry, said in bad:
        with pytest.raises(CameraError) as err:
            image_blocks([entry])
        assert "\n" not in str(err.value) and str(err.value).startswith(said), str(err.value)


def test_bad_rgb_frames_are_refused_in_one_line_naming_the_camera_and_what_was_expected():
    for frame, said in [
        (np.zeros((1, 12, 16, 3), np.float32), "dtype float32; expected uint8 RGB"),
        (np.zeros((1, 12, 16), np.uint8), "shape (1, 12, 16); expected (1, 12, 16, 3)"),
        (np.full((1, 12, 16, 3), "x"), "dtype <U1; expected uint8 RGB"),
    ]:
        with pytest.raises(CameraError) as err:
            check_frames(frame, TINY, 1, "frame.rgb_image")
        line = str(err.value)
        assert "\n" not in line and line.startswith("frame.rgb_image: camera 'overhead'")
        assert said in line


def test_the_camera_stage_stacks_rgb_frames_skip_apart_and_a_repeated_image_is_no_frame():
    block = replace(TINY, crop=(0, 0, 0, 0), resize=TINY.shape, frames=3)
    stage = CameraInput(block, 1, stale_limit=0.2)
    frame = SimpleNamespace(time=np.zeros(1), rgb_stamp=np.zeros(1), rgb_image=None)
    for k in range(6):
        frame.time[:] = frame.rgb_stamp[:] = 0.04 * k
        frame.rgb_image = np.full((1, 12, 16, 3), 10 * (k + 1), np.uint8)
        stage.update(frame)
    assert stage.image.shape == (1, 3, 3, 12, 16)
    np.testing.assert_allclose(stage.image[0, :, 0, 0, 0], [20 / 255, 40 / 255, 60 / 255])
    for k in range(6, 12):  # the same image, new stamps: a frozen driver
        frame.time[:] = frame.rgb_stamp[:] = 0.04 * k
        stale = stage.update(frame)
    assert stage.repeated[0] == 6 and stale[0]


def rgb_policy(robot, tmp_path, block=TINY, stored=None) -> OnnxPolicy:
    """A two-input policy: every action is the mean of the colour image input over ten
    (:func:`tests.test_camera.depth_policy`, which takes either kind of block)."""
    return depth_policy(robot, tmp_path, block, stored)


def test_a_graph_input_of_another_layout_than_the_rgb_block_is_refused_in_one_line(arm3, tmp_path):
    with pytest.raises(PolicyLoadError) as err:
        rgb_policy(arm3, tmp_path, stored=replace(TINY, layout="HWC"))
    line = str(err.value)
    assert "\n" not in line and "graph input 'rgb'" in line
    assert "expects float [batch, frames, rows, columns, 3] = [batch, 2, 6, 7, 3]" in line


def test_the_ov5647_model_gives_the_datasheets_snr_and_quantises_to_uint8():
    noise = RgbNoise(exposure_drift=0, white_balance_drift=0)
    assert noise.snr_db(1.0) == pytest.approx(36.0, abs=0.5)  # the brief's 36 dB
    grey = np.full((64, 64, 3), 128, np.uint8)
    out = noise.apply(grey, np.zeros(4), np.random.default_rng(0))
    assert out.dtype == np.uint8
    x = 128 / 255
    assert out.std() / 255 == pytest.approx(np.sqrt(noise.sigma(x) ** 2 + 1 / 12 / 255**2), rel=0.1)
    drifting = RgbNoise()
    state, rng = np.zeros(4), np.random.default_rng(1)
    seen = []
    for _ in range(3000):  # 100 s at 30 Hz: the drift's spread
        drifting.drift(state, 1 / 30, rng)
        seen.append(state.copy())
    spread = np.std(seen, axis=0)
    assert spread[0] == pytest.approx(0.05, rel=0.35) and spread[1] == pytest.approx(0.03, rel=0.5)


# ---------------------------------------------------------------------- rendered
@needs_gl
def test_the_plant_renders_colour_at_its_rate_and_lighting_occlusion_and_a_knock_change_it(arm3):
    model = overhead_model(arm3)
    plant = SimBackend(arm3, "position", envs=2, models=[model, model])
    block = replace(TINY, shape=(24, 32), crop=(0, 0, 0, 0), resize=(24, 32))
    quiet = RgbNoise(full_well=1e12, read_noise=0, exposure_drift=0, white_balance_drift=0)
    faults = [CameraFaults(), CameraFaults(lighting=0.3, occlusion=0.25, extrinsic=(0.2, 0, 0))]
    camera = PlantRgbCamera(plant, block, noise=quiet, faults=faults, seed=[
        np.random.default_rng(0), np.random.default_rng(1)])  # fmt: skip
    bright, dim = camera.true_image(0).copy(), camera.true_image(1).copy()
    assert bright.mean() > 40 and dim.mean() < 0.6 * bright.mean()
    frame = SimpleNamespace(time=np.zeros(2))
    camera.fill(frame)
    frame.time[:] = 0.1
    camera.fill(frame)
    assert list(camera.frames) == [3, 3]  # at 0, 0.04 and 0.08 s
    assert frame.rgb_image.shape == (2, 24, 32, 3) and frame.rgb_stamp[0] == pytest.approx(0.08)
    blind = round(0.25 * 32)
    assert (frame.rgb_image[1, :, :blind] == round(0.03 * 255 * 1)).all()  # a covered lens
    assert camera.summary(1)["faults"]["lighting"] == 0.3


@needs_gl
def test_the_runtime_feeds_a_two_input_policy_colour_frames_and_a_frozen_camera_stops_it(
    arm3, tmp_path
):
    for faults in (None, CameraFaults(freeze=1.0, freeze_frames=1000)):
        policy = rgb_policy(arm3, tmp_path)
        mode = policy.spec.action.mode
        plant = SimBackend(arm3, mode, envs=1, models=[overhead_model(arm3, mode)])
        camera = attach_plant_camera(plant, policy.spec, latency=0.02, faults=faults)
        assert isinstance(camera, PlantRgbCamera)
        rt = Runtime(arm3, policy, plant)
        rt.start()
        rt.run(int(round(0.6 / arm3.control_period)))
        if faults is None:
            assert (rt.mode == Mode.RUNNING).all() and rt.cameras.taken[0] >= 12
            image = policy.images["rgb"]
            assert image.shape == (1, 2, 3, 6, 7) and 0 < image.mean() < 1
            assert policy.graph_action[0, 0] == pytest.approx(0.1 * image.mean(), abs=1e-6)
        else:
            assert FAULT_CAUSES[rt.cause[0]] == "stale_sensor"
            record = rt.stale_stops.records[0]
            verdict = record["verdict"]
            assert verdict.startswith("colour camera 'overhead'") and "(frozen)" in verdict
            followed = record["other_side"]["camera_faults"]  # what the plant's camera did
            assert followed["frozen"] >= 3 and followed["dropped"] == 0
            assert followed["last"]["fault"] == "frozen"
            assert "in the 1 s before: " in verdict and " frames frozen, 0 dropped" in verdict
            # each frozen frame counted once, however many ticks it stays the newest
            assert camera.frozen[0] - 1 <= rt.cameras.repeated[0] <= camera.frozen[0]


def test_policy_export_inspect_shows_the_rgb_block(arm3, tmp_path, capsys):
    from sim2real.deploy.cli.policy_export import main

    policy = rgb_policy(arm3, tmp_path, block=replace(TINY, normalisation="mean_std"))
    assert main([str(policy.path), "--inspect"]) == 0
    out = capsys.readouterr().out
    assert "rgb          float32  [batch, 2, 3, 6, 7]" in out
    assert (
        "images: rgb <- colour camera 'overhead' 12x16 at 25 Hz, crop [0, 0, 1, 1] (top, bottom, "
        "left, right), resize 6x7 bilinear, RGB CHW x/255, mean [0.485, 0.456, 0.406] std "
        "[0.229, 0.224, 0.225], 2 frames 2 apart, latency 0 s"
    ) in out


def test_deploy_run_refuses_a_colour_camera_the_robots_mjcf_lacks_in_one_line(
    arm3, tmp_path, capsys
):
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    policy = rgb_policy(arm3, tmp_path)  # the shipped arm3 has no <camera name="overhead">
    code = deploy_run_main(["--robot", "arm3", "--policy", str(policy.path), "--duration", "0.2"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 3 and len([line for line in err if "error" in line]) == 1
    # a camera the robot's MJCF lacks is looked for in its task scene (arm3's: a goal camera)
    scene = arm3.mjcf_path.parent / "arm3_scene.xml"
    assert err[-1].startswith(f"deploy-run: error: {scene}: images[0].camera")
    assert '<camera name="overhead">' in err[-1] and "(its cameras: ['goal_camera'])" in err[-1]


def test_a_resize_bigger_than_the_render_is_refused_naming_the_file_and_the_field(arm3, tmp_path):
    from sim2real.deploy.spec.camera import DepthImageBlock

    spec = replace(PolicySpec.for_robot(arm3), images=(TINY,))
    text = spec.to_json().replace('"resize": [6, 7]', '"resize": [24, 7]')
    with pytest.raises(ValueError) as err:
        PolicySpec.from_json(text, "policy.onnx")
    assert str(err.value) == (
        "policy.onnx: images[0].resize: [24, 7] is bigger than the cropped render [12, 14]; "
        "expected at most [12, 14] (rows, columns)"
    )
    depth = DepthImageBlock(shape=(12, 16), crop=(0, 0, 0, 0), resize=(13, 16))
    assert depth.problems("images[0]")[0].startswith("images[0].resize: [13, 16] is bigger")


@needs_gl
def test_a_plant_camera_loaded_from_its_state_dict_delivers_the_same_frames(arm3):
    model = overhead_model(arm3)
    plant = SimBackend(arm3, "position", envs=2, models=[model, model])
    faults = CameraFaults(drop=0.2, spike=0.3, spike_latency=0.1, freeze=0.1, freeze_frames=3)
    make = lambda: PlantRgbCamera(plant, TINY, latency=0.05, faults=faults, seed=7)  # noqa: E731
    source, frame = make(), SimpleNamespace(time=np.zeros(2))
    for t in np.arange(0.0, 0.5, 0.01):
        frame.time[:] = t
        source.fill(frame)
    assert any(source._queue)  # frames in flight at the checkpoint
    copy = make()
    copy.load_state_dict(source.state_dict())
    other = SimpleNamespace(time=frame.time.copy(), rgb_image=frame.rgb_image.copy(),
                            rgb_stamp=frame.rgb_stamp.copy())  # fmt: skip
    for t in np.arange(0.5, 1.0, 0.01):
        frame.time[:] = other.time[:] = t
        source.fill(frame)
        copy.fill(other)
        np.testing.assert_array_equal(other.rgb_image, frame.rgb_image)
        np.testing.assert_array_equal(other.rgb_stamp, frame.rgb_stamp)
    assert copy.summary() == source.summary() and source.spiked.sum() > 0
    one = PlantRgbCamera(
        SimBackend(arm3, "position", envs=1, models=[model]),
        TINY,
        latency=0.05,
        faults=faults,
        seed=7,
    )
    one.load_state_dict(source.state_dict(env=1))  # one env of a batch into a one-env camera
    assert one.frames[0] == source.frames[1]


@needs_gl
def test_a_runtime_resumed_from_its_state_dict_feeds_the_same_colour_images(arm3, tmp_path):
    def start():
        policy = rgb_policy(arm3, tmp_path)
        mode = policy.spec.action.mode
        plant = SimBackend(arm3, mode, envs=2, models=[overhead_model(arm3, mode)] * 2)
        faults = CameraFaults(spike=0.3, spike_latency=0.1, drop=0.1)
        attach_plant_camera(plant, policy.spec, latency=0.05, faults=faults, seed=3)
        rt = Runtime(arm3, policy, plant)
        rt.start()
        return rt, policy

    (first, seen), (resumed, fed) = start(), start()
    first.run(37)
    state = first.state_dict()
    assert "camera_source/queue_image" in state and "camera_source/streams" in state
    resumed.load_state_dict(state)
    for _ in range(30):
        first.run(1)
        resumed.run(1)
        np.testing.assert_array_equal(fed.images["rgb"], seen.images["rgb"])
    assert resumed.cameras.taken.tolist() == first.cameras.taken.tolist()
