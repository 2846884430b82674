"""A LeRobot export (ACT's action chunks) as a policy of the runtime
(sim2real/deploy/policy/lerobot_policy.py) through deploy-run: at its own rate beside the servo
loop, a new chunk every ``n_action_steps`` policy ticks, each servo tick's held target through the
guard and the smoother, the state machine's ramp-in and safe stops (a stale camera stops it), on
the simulated SO-101 and on the Feetech bus emulator with frames from a recorded video; the jerk at
chunk boundaries in the report (sim2real/deploy/rig/chunk_hook.py); wrong cameras refused in one
line. The policies are small chunked ONNX files with LeRobot's contract, written here
(tests/lerobot_folder.py ``write_chunk_onnx``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sim2real.deploy.cli.deploy_run import deploy_run_main as deploy_run
from sim2real.deploy.cli.run_verdict import EXIT_BAD_INPUT, EXIT_CLEAN, EXIT_FAULT
from sim2real.deploy.observe.chunk_jerk import boundary_jerk
from sim2real.robots import load_robot
from tests.lerobot_folder import write_chunk_onnx


@pytest.fixture(scope="module")
def so101():
    return load_robot("so101")


def _run(tmp_path, policy, *extra) -> tuple[int, dict]:
    report = tmp_path / "report.json"
    code = deploy_run(
        ["--robot", "so101", "--policy", str(policy), "--report", str(report), *extra]
    )
    return code, (json.loads(report.read_text()) if report.exists() else {})


def test_a_chunked_policy_runs_in_the_runtime_at_its_own_rate(tmp_path, so101, capsys):
    """25 Hz beside 100 Hz: a policy tick every 4 servo ticks, a new chunk every 4 policy ticks
    (n_action_steps), the held target through the guard and Ruckig: the command's jerk stays
    within the SO-101's jerk limits where the unsmoothed target jumps at every boundary."""
    path = write_chunk_onnx(
        tmp_path / "act.onnx", chunk_size=6, n_action_steps=4, fps=25.0, image_shape=None,
        step_deg=1.5,
    )  # fmt: skip
    code, r = _run(tmp_path, path, "--backend", "sim", "--duration", "3")
    captured = capsys.readouterr()
    out = captured.out
    assert code == EXIT_CLEAN, out
    assert "LeRobot act policy at 25 Hz beside the servo loop, 4 of 6 actions" in captured.err
    c = r["chunks"]
    assert c["policy_ticks_per_chunk"] == [4] and c["servo_ticks_per_policy_tick"] == [4]
    assert c["running_stretches"] == 1 and c["joints"] == "true"
    assert c["target"]["boundaries"] >= 10
    # the ramp jumps back at a boundary: the target (no smoother) jerks more there than inside
    assert c["target"]["boundary_median"] > 2 * c["target"]["inside_median"]
    limit = float(np.max(so101.jerk_limit))
    assert (
        c["command"]["boundary_max"] <= 1.01 * limit and c["command"]["inside_max"] <= 1.01 * limit
    )
    assert c["target"]["boundary_median"] > 20 * c["command"]["boundary_median"]
    assert r["interventions"]["checks"]["target_clamp"]["count"] == 0  # nothing clamped here
    assert r["final_state"] == ["RUNNING"]
    assert "chunk jerk, target, no smoother: after a boundary" in out


def test_a_batch_of_robots_runs_one_chunk_queue_each(tmp_path):
    path = write_chunk_onnx(
        tmp_path / "act.onnx", chunk_size=6, n_action_steps=3, fps=25.0, image_shape=None
    )
    code, r = _run(tmp_path, path, "--backend", "sim", "--duration", "2", "--envs", "2")
    assert code == EXIT_CLEAN and r["final_state"] == ["RUNNING", "RUNNING"]
    assert r["chunks"]["policy_ticks_per_chunk"] == [3]


def test_the_guard_clamps_a_chunk_that_leaves_the_soft_limits(tmp_path):
    """A chunk that runs the arm away (a 6 deg step per action on every joint, an arm that
    climbs): the guard holds the held targets inside the workspace and off self-collision,
    counted as interventions, and the true state violates nothing."""
    path = write_chunk_onnx(
        tmp_path / "climb.onnx", chunk_size=8, n_action_steps=8, fps=25.0, image_shape=None,
        step_deg=6.0, gain=1.0,
    )  # fmt: skip
    code, r = _run(tmp_path, path, "--backend", "sim", "--duration", "6")
    assert code == EXIT_CLEAN
    checks = r["interventions"]["checks"]
    assert checks["workspace"]["count"] > 0 and checks["self_collision"]["count"] > 0
    assert r["faults"]["by_cause"]["hard_limit"] == 0
    assert r["violations"]["any"] == 0


@pytest.mark.parametrize("steps, coeff", [(4, None), (1, 0.01)], ids=["queue", "ensembling"])
def test_a_chunked_policy_state_round_trips(tmp_path, so101, steps, coeff):
    from sim2real.deploy.policy.lerobot_policy import LeRobotChunkPolicy

    path = write_chunk_onnx(
        tmp_path / "a.onnx", chunk_size=6, n_action_steps=steps, coeff=coeff, fps=30.0
    )
    a, b = LeRobotChunkPolicy(path, so101), LeRobotChunkPolicy(path, so101)
    obs = np.zeros((1, a.spec.obs_dim), np.float32)
    for _ in range(7):
        a(obs)
    b.load_state_dict(a.state_dict())
    for _ in range(12):
        np.testing.assert_array_equal(a(obs), b(obs))
        assert (a.new_chunk == b.new_chunk).all()


def test_the_runtimes_state_dict_carries_the_chunks(tmp_path, so101):
    """A run's state (the runtime's, the chunked policy's among its stages, the plant's) loaded
    into a second rig mid-chunk: both write the same commands after."""
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.policy.lerobot_policy import LeRobotChunkPolicy
    from sim2real.deploy.rig.rig import Rig

    path = write_chunk_onnx(tmp_path / "a.onnx", chunk_size=6, n_action_steps=4, image_shape=None)
    rigs = []
    for _ in range(2):
        backend = SimBackend(so101, "position", envs=1, seed=0)
        backend.open()
        rig = Rig(so101, LeRobotChunkPolicy(path, so101), backend, envs=1)
        rig.start()
        rigs.append(rig)
    a, b = rigs
    for _ in range(157):  # past RAMP_IN, mid-chunk
        a.runtime.tick()
    assert a.runtime.mode_names() == ["RUNNING"]
    b.runtime.load_state_dict(a.runtime.state_dict())
    for _ in range(40):
        a.runtime.tick()
        b.runtime.tick()
        np.testing.assert_array_equal(a.runtime.command, b.runtime.command)
    assert (a.runtime.policy.calls == b.runtime.policy.calls).all()


def test_boundary_jerk_of_a_step_at_a_boundary():
    """A unit step at servo tick 12 of a signal held 4 ticks per policy tick: its window sees it,
    the windows inside see nothing."""
    x = np.zeros((40, 1))
    x[12:] = 1.0
    f = boundary_jerk(x, 0.01, 0.04, boundaries=[12], policy_ticks=[4, 8, 12, 16, 20])
    assert f["boundary_median"] == pytest.approx(2.0 / 0.01**3)  # a step's differences: 1, -2, 1
    assert f["inside"] == 4 and f["inside_max"] == 0.0


# ---------------------------------------------------------------- cameras
cv2 = pytest.importorskip(
    "cv2", reason="OpenCV is not installed (the extra 'camera': opencv-python-headless)"
)


def _video(path, frames: int, shape=(48, 64), fps=30.0):
    """``frames`` random RGB frames written by cv2.VideoWriter, lossless (FFV1)."""
    rng = np.random.default_rng(0)
    w = cv2.VideoWriter(
        str(path), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*"FFV1"), fps, (shape[1], shape[0]), []
    )
    assert w.isOpened()
    for _ in range(frames):
        w.write(rng.integers(0, 255, (*shape, 3), dtype=np.uint8))
    w.release()
    return path


def _clean_or_stale(code: int, r: dict) -> None:
    """A wall-clock run ended clean, or was safe-stopped by a stale reading or an overrun only
    (a loaded machine starves the loop, the bus reader or the video's decoder, or delays the
    chunk worker past half the stale limit: the runtime's right answer) with no hard limit
    crossed; it is judged up to there."""
    faults = r["faults"]
    starved = faults["by_cause"]["stale_sensor"] + faults["by_cause"]["overrun"]
    assert code == EXIT_CLEAN or (
        code == EXIT_FAULT and starved >= 1 and faults["safe_stops"] == starved
    ), faults
    assert faults["by_cause"]["hard_limit"] == 0


def _camera_policy(tmp_path, **kw):
    return write_chunk_onnx(
        tmp_path / "cam.onnx", chunk_size=6, n_action_steps=4, fps=30.0, image_shape=(3, 48, 64),
        step_deg=1.5, **kw,
    )  # fmt: skip


def test_a_camera_key_feeds_from_a_recorded_video_on_the_plant(tmp_path):
    """--backend sim --realtime with --camera-source front=opencv:FILE,loop: the runtime's camera
    stage takes the video's frames into the chunked policy's image input."""
    video = _video(tmp_path / "front.mkv", 30)
    code, r = _run(
        tmp_path, _camera_policy(tmp_path), "--backend", "sim", "--realtime", "--duration", "2",
        "--camera-source", f"front=opencv:{video},loop", "--overrun-limit", "1",
    )  # fmt: skip
    _clean_or_stale(code, r)
    assert r["camera"]["camera"] == "front" and r["camera"]["frames_taken"][0] >= 15
    assert r["chunks"]["policy_ticks_per_chunk"] == [4]
    assert set(r["chunks"]["servo_ticks_per_policy_tick"]) <= {3, 4}  # 100 / 30 = 3.33


def test_a_video_that_ends_stops_the_chunked_policy_safely(tmp_path):
    """No loop: the video's last frame is 1.5 s in; the camera falls silent, is stale, and the
    runtime stops the robot (stale_sensor) as for any sensor."""
    video = _video(tmp_path / "front.mkv", 45)
    code, r = _run(
        tmp_path, _camera_policy(tmp_path), "--backend", "sim", "--realtime", "--duration", "3",
        "--camera-source", f"front=opencv:{video}", "--overrun-limit", "1",
    )  # fmt: skip
    assert code == EXIT_FAULT
    assert r["faults"]["by_cause"]["stale_sensor"] == 1
    assert r["final_state"] in (["SAFE_STOP"], ["FAULTED"])
    assert r["faults"]["by_cause"]["hard_limit"] == 0


@pytest.mark.parametrize(
    "source, shape, said",
    [
        ("wrist=opencv:{video}", (48, 64), "the policy has no camera 'wrist'"),
        ("front=opencv:{video}", (24, 32), "expects 48 x 64"),
    ],
    ids=["wrong-key", "wrong-shape"],
)
def test_a_wrong_camera_is_refused_in_one_line(tmp_path, capsys, source, shape, said):
    video = _video(tmp_path / "v.mkv", 10, shape=shape)
    code, _ = _run(
        tmp_path, _camera_policy(tmp_path), "--backend", "sim", "--realtime", "--duration", "1",
        "--camera-source", source.format(video=video),
    )  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert code == EXIT_BAD_INPUT
    assert said in err[-1] and "Traceback" not in "\n".join(err)


def test_an_export_whose_camera_is_not_rgb_or_the_mjcf_lacks_is_refused(tmp_path, capsys):
    grey = write_chunk_onnx(tmp_path / "grey.onnx", image_shape=(1, 48, 64))
    code, _ = _run(tmp_path, grey, "--backend", "sim", "--duration", "1")
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == EXIT_BAD_INPUT
    assert "camera observation.images.front of shape [1, 48, 64]; expected [3, H, W]" in line
    code, _ = _run(tmp_path, _camera_policy(tmp_path, camera_key="observation.images.top"),
                   "--backend", "sim", "--duration", "1")  # fmt: skip
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == EXIT_BAD_INPUT and 'no <camera name="top">' in line


# ---------------------------------------------------------------- the Feetech bus emulator
@pytest.mark.wallclock
@pytest.mark.alone  # the bus on a pty misses replies beside another process at normal priority
def test_a_chunked_camera_policy_on_the_feetech_emulator(tmp_path):
    """deploy-run --backend feetech against the bus emulator backed by the MuJoCo plant, the
    camera from a recorded video: the chunks' cadence and the smoother's bound hold on the
    bus. In this process (deploy-run in a second one takes seconds to start, while the
    unpowered arm falls to a pose outside its workspace box, from which the guard keeps it from
    ramping in). A loaded machine may stop it (:func:`_clean_or_stale`)."""
    from sim2real.deploy.backends.emulator import ServoBusEmulator

    pytest.importorskip("scservo_sdk", reason="the Feetech SDK (extra 'servo') is not installed")
    video = _video(tmp_path / "front.mkv", 30)
    so101 = load_robot("so101")
    with ServoBusEmulator(so101, "feetech") as emu:
        code, r = _run(
            tmp_path, _camera_policy(tmp_path), "--backend", "feetech", "--port", emu.port,
            "--duration", "4", "--camera-source", f"front=opencv:{video},loop",
            "--overrun-limit", "1",
        )  # fmt: skip
    _clean_or_stale(code, r)
    assert r["chunks"]["running_ticks"] > 50 and r["chunks"]["joints"] == "estimated"
    assert r["chunks"]["policy_ticks_per_chunk"] == [4]
    assert r["camera"]["hardware"] is not None and r["camera"]["frames_taken"][0] >= 15
    limit = float(np.max(so101.jerk_limit))
    assert r["chunks"]["command"]["boundary_max"] <= 1.01 * limit
