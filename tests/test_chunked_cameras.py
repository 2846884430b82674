"""A LeRobot export with two cameras (``observation.images.front`` and ``.wrist``, as LeRobot's
SO-101 setups name them) through the runtime: one camera stage per image block
(sim2real/deploy/runtime/camera.py ``CameraInputs``), each at its own rate and latency, stale on its
own (a stale wrist camera stops the robot, and the stop names it), each in the runtime's state dict;
the plant rendering both of so101_scene.xml's cameras; ``--camera-source NAME=...`` once per
camera, on the plant and on the Feetech bus emulator; the refusals in one line. The policies are
small chunked ONNX files with LeRobot's contract, written here (tests/lerobot_folder.py
``write_chunk_onnx``)."""

from __future__ import annotations

import json
from dataclasses import replace
from types import SimpleNamespace as NS

import numpy as np
import pytest

from sim2real.deploy.cli.deploy_run import deploy_run_main as deploy_run
from sim2real.deploy.cli.run_verdict import EXIT_BAD_INPUT, EXIT_CLEAN, EXIT_FAULT
from sim2real.robots import load_robot
from tests.lerobot_folder import write_chunk_onnx

SHAPE = (48, 64)
FRONT, WRIST = "observation.images.front", "observation.images.wrist"


@pytest.fixture(scope="module")
def so101():
    return load_robot("so101")


def two_camera_policy(tmp_path, keys=(FRONT, WRIST), name="two.onnx"):
    """A chunked stand-in of ACT reading both cameras (3 x 48 x 64 each), 30 fps, chunk 6, 4
    actions per chunk."""
    return write_chunk_onnx(
        tmp_path / name, chunk_size=6, n_action_steps=4, fps=30.0, step_deg=1.5,
        cameras=[(k, (3, *SHAPE)) for k in keys],
    )  # fmt: skip


def _run(tmp_path, policy, *extra) -> tuple[int, dict]:
    report = tmp_path / "report.json"
    code = deploy_run(
        ["--robot", "so101", "--policy", str(policy), "--report", str(report), *extra]
    )
    return code, (json.loads(report.read_text()) if report.exists() else {})


def _rig(so101, path, faults=None, spec_images=None, seed=0):
    """A rig of the two-camera policy on the plant, both cameras rendered from the task scene
    (``faults``: by camera name; ``spec_images``: the policy's image blocks replaced)."""
    from sim2real.deploy.backends.sim.camera import attach_plant_camera
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.policy.lerobot_policy import LeRobotChunkPolicy
    from sim2real.deploy.rig.rig import Rig

    policy = LeRobotChunkPolicy(path, so101)
    if spec_images is not None:
        policy.spec = replace(policy.spec, images=spec_images)  # same shapes: same arrays
    backend = SimBackend(so101, "position", envs=1, seed=seed)
    backend.open()
    attach_plant_camera(backend, policy.spec, faults=faults, seed=seed)
    rig = Rig(so101, policy, backend, envs=1)
    rig.start()
    return rig, policy


def test_deploy_run_renders_both_cameras_of_the_scene_for_a_two_camera_export(tmp_path):
    """--backend sim: the plant renders so101_scene.xml's front and wrist cameras, each into
    its own graph input; the report has a camera section per camera."""
    code, r = _run(tmp_path, two_camera_policy(tmp_path), "--backend", "sim", "--duration", "2")
    assert code == EXIT_CLEAN and r["final_state"] == ["RUNNING"]
    assert set(r["camera"]) == {"front", "wrist"}
    for name, cam in r["camera"].items():
        assert cam["camera"] == name and cam["plant"]["camera"] == name
        assert cam["frames_taken"][0] >= 55 and cam["frames_repeated"] == [0]  # 2 s at 30 Hz
    assert r["chunks"]["policy_ticks_per_chunk"] == [4]


def test_each_camera_runs_at_its_own_rate_into_its_own_input(tmp_path, so101):
    """The wrist camera at 10 Hz and 50 ms late beside the front one at 30 Hz: each stage takes
    its own camera's frames, and the two inputs hold different images (the two views)."""
    path = two_camera_policy(tmp_path)
    from sim2real.deploy.policy.lerobot_policy import LeRobotChunkPolicy

    front, wrist = LeRobotChunkPolicy(path, so101).spec.images
    rig, policy = _rig(so101, path, spec_images=(front, replace(wrist, rate=10.0, latency=0.05)))
    rig.runtime.run(100)  # 1 s
    taken = {c.block.camera: int(c.taken[0]) for c in rig.runtime.cameras.inputs}
    assert 29 <= taken["front"] <= 31 and 9 <= taken["wrist"] <= 10
    limits = {c.block.camera: c.stale_limit for c in rig.runtime.cameras.inputs}
    assert limits["wrist"] == pytest.approx(limits["front"] + 0.05 + 3 / 10 - 3 / 30)
    a, b = policy.images[FRONT], policy.images[WRIST]
    assert a.shape == b.shape == (1, 1, 3, *SHAPE) and not np.array_equal(a, b)
    assert rig.runtime.mode_names() == ["RUNNING"]


def test_a_stale_wrist_camera_stops_the_robot_safely_and_the_stop_names_it(tmp_path, so101):
    """The wrist camera frozen (its driver repeats its buffer), the front one fine: the runtime
    stops the robot (stale_sensor) and the stop's record and verdict name the wrist camera."""
    from sim2real.deploy.backends.sim.plant_camera import CameraFaults
    from sim2real.deploy.core.modes import FAULT_CAUSES

    frozen = CameraFaults(freeze=1.0, freeze_frames=1000)
    rig, _ = _rig(so101, two_camera_policy(tmp_path), faults={"wrist": frozen})
    rt = rig.runtime
    rt.run(100)
    assert FAULT_CAUSES[rt.cause[0]] == "stale_sensor"
    record = rt.stale_stops.records[0]
    assert record["stream"] == "colour camera 'wrist'" and record["other_side"]["camera"] == "wrist"
    assert record["verdict"].startswith("colour camera 'wrist'") and "(frozen)" in record["verdict"]
    assert record["other_side"]["camera_faults"]["frozen"] >= 3
    front, wrist = rt.cameras.inputs
    assert wrist.repeated[0] >= 3 and front.repeated[0] == 0 and front.taken[0] >= 10


def test_the_runtimes_state_dict_carries_both_cameras(tmp_path, so101):
    """A run with both plant cameras (one with dropped and late frames) loaded into a second
    rig mid-chunk: both feed the same images of each camera and write the same commands."""
    from sim2real.deploy.backends.sim.plant_camera import CameraFaults

    path = two_camera_policy(tmp_path)
    faults = {"wrist": CameraFaults(drop=0.2, spike=0.3, spike_latency=0.05)}
    (a, pa), (b, pb) = (_rig(so101, path, faults=faults) for _ in range(2))
    a.runtime.run(157)
    state = a.runtime.state_dict()
    for key in ("camera/front/ring", "camera/wrist/ring", "camera_source/wrist/queue_image",
                "camera_source/front/streams", "camera_source/wrist/streams"):  # fmt: skip
        assert key in state, key
    b.runtime.load_state_dict(state)
    for _ in range(40):
        a.runtime.tick()
        b.runtime.tick()
        np.testing.assert_array_equal(a.runtime.command, b.runtime.command)
        for key in (FRONT, WRIST):
            np.testing.assert_array_equal(pa.images[key], pb.images[key])
    taken = [[int(c.taken[0]) for c in r.runtime.cameras.inputs] for r in (a, b)]
    assert taken[0] == taken[1]


@pytest.mark.parametrize(
    "sources, said",
    [
        (["front=opencv:f.mkv", "top=opencv:t.mkv"],
         "--camera-source top=opencv:t.mkv: the policy has no camera 'top'"),
        (["front=opencv:f.mkv", "front=opencv:g.mkv", "wrist=opencv:w.mkv"],
         "--camera-source front=opencv:g.mkv: camera 'front' given twice; expected one "
         "--camera-source per camera of ['front', 'wrist']"),
        (["front=opencv:f.mkv"],
         "--camera-source: camera 'wrist' of the policy has none; expected one --camera-source "
         "NAME=KIND:WHERE for each of ['front', 'wrist']"),
    ],
    ids=["no-such-camera", "given-twice", "left-without"],
)  # fmt: skip
def test_camera_sources_that_do_not_fit_the_cameras_are_refused_in_one_line(
    tmp_path, capsys, sources, said
):
    extra = [x for s in sources for x in ("--camera-source", s)]
    code, _ = _run(tmp_path, two_camera_policy(tmp_path), "--backend", "sim", "--realtime",
                   "--duration", "1", *extra)  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert code == EXIT_BAD_INPUT and said in err[-1]
    assert "Traceback" not in "\n".join(err)


def test_a_hardware_backend_without_sources_and_a_camera_the_mjcf_lacks_are_refused(
    tmp_path, so101, capsys
):
    from sim2real.deploy.cli.exteroception import attach_camera
    from sim2real.deploy.policy.lerobot_policy import LeRobotChunkPolicy

    policy = LeRobotChunkPolicy(two_camera_policy(tmp_path), so101)
    args = NS(backend="feetech", camera_source=[], camera_rate=None, camera_latency=None,
              camera_faults="none", seed=0, realtime=True)  # fmt: skip
    with pytest.raises(ValueError) as err:
        attach_camera(args, NS(), policy.spec)  # a bus: no plant, no camera of its own
    assert str(err.value) == (
        "the policy reads cameras ['front', 'wrist']; --backend feetech has none: give one "
        "--camera-source NAME=KIND:WHERE per camera, NAME one of front, wrist (opencv:INDEX, "
        "realsense:SERIAL, ros2:/TOPIC; docs/cameras.md)"
    )
    top = two_camera_policy(tmp_path, keys=(FRONT, "observation.images.top"), name="top.onnx")
    code, _ = _run(tmp_path, top, "--backend", "sim", "--duration", "1")
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == EXIT_BAD_INPUT
    assert "so101_scene.xml: images[1].camera" in line and 'no <camera name="top">' in line


# ---------------------------------------------------------------- recorded videos
cv2 = pytest.importorskip(
    "cv2", reason="OpenCV is not installed (the extra 'camera': opencv-python-headless)"
)


def _video(path, frames: int, seed: int, fps=30.0):
    """``frames`` random RGB frames of SHAPE written by cv2.VideoWriter, lossless (FFV1)."""
    rng = np.random.default_rng(seed)
    w = cv2.VideoWriter(
        str(path), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*"FFV1"), fps, (SHAPE[1], SHAPE[0]), []
    )
    assert w.isOpened()
    for _ in range(frames):
        w.write(rng.integers(0, 255, (*SHAPE, 3), dtype=np.uint8))
    w.release()
    return path


@pytest.mark.wallclock
@pytest.mark.alone  # the bus on a pty misses replies beside another process at normal priority
def test_a_two_camera_policy_on_the_feetech_emulator_with_two_recorded_videos(tmp_path):
    """deploy-run --backend feetech against the bus emulator backed by the MuJoCo plant, each
    camera from its own recorded video (--camera-source given once per camera): both cameras'
    frames taken, the chunks' cadence and the smoother's bound on the bus. A loaded machine may
    stop it on a stale reading (the runtime's right answer), judged up to there."""
    from sim2real.deploy.backends.emulator import ServoBusEmulator

    pytest.importorskip("scservo_sdk", reason="the Feetech SDK (extra 'servo') is not installed")
    front, wrist = _video(tmp_path / "front.mkv", 30, 0), _video(tmp_path / "wrist.mkv", 30, 1)
    so101 = load_robot("so101")
    with ServoBusEmulator(so101, "feetech") as emu:
        code, r = _run(
            tmp_path, two_camera_policy(tmp_path), "--backend", "feetech", "--port", emu.port,
            "--duration", "4", "--camera-source", f"front=opencv:{front},loop",
            "--camera-source", f"wrist=opencv:{wrist},loop", "--overrun-limit", "1",
        )  # fmt: skip
    faults = r["faults"]
    stale = faults["by_cause"]["stale_sensor"]
    assert code == EXIT_CLEAN or (
        code == EXIT_FAULT and stale >= 1 and faults["safe_stops"] == stale
    ), faults
    assert faults["by_cause"]["hard_limit"] == 0
    assert r["chunks"]["policy_ticks_per_chunk"] == [4] and r["chunks"]["running_ticks"] > 50
    for name in ("front", "wrist"):
        cam = r["camera"][name]
        assert f"{name}=opencv:" in cam["hardware"]["source"]
        assert cam["frames_taken"][0] >= 15
    limit = float(np.max(so101.jerk_limit))
    assert r["chunks"]["command"]["boundary_max"] <= 1.01 * limit


def test_a_state_dict_missing_one_cameras_fields_loads_nothing(tmp_path, so101):
    """The second camera's history missing from a checkpoint: refused naming the field, and
    the first camera's state is left as it was (nothing written)."""
    from sim2real.deploy.core.stateful import StateDictError

    path = two_camera_policy(tmp_path)
    (a, _), (b, _) = (_rig(so101, path) for _ in range(2))
    a.runtime.run(60)
    b.runtime.run(20)
    state = {k: v for k, v in a.runtime.cameras.state_dict().items() if k != "wrist/ring"}
    front = b.runtime.cameras.inputs[0]
    before = front.taken.copy()
    with pytest.raises(StateDictError, match="ring"):
        b.runtime.cameras.load_state_dict(state)
    np.testing.assert_array_equal(front.taken, before)
