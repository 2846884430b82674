"""deploy-run --print-joints HZ and --video (its error path everywhere, a real MP4 where EGL
works)."""

import io
import os
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from sim2real.deploy.observe.joint_printer import JointPrinter
from sim2real.deploy.runtime import SimClock
from sim2real.robots import load_robot
from tests.runtime_fixtures import adversarial_onnx


def fake_runtime(envs=1):
    n = 3
    return SimpleNamespace(
        time=0.0,
        envs=envs,
        mode=np.full(envs, 2, dtype=np.int8),
        clock=SimClock(0.005),
        command=np.tile([0.1, -0.2, 0.3], (envs, 1)),
        state=SimpleNamespace(
            q=np.tile([1.0, -0.5, 0.25], (envs, 1)),
            dq=np.tile([0.01, 0.0, -2.0], (envs, 1)),
            winding_temperature=np.full((envs, n), 31.25),
        ),
    )


def test_prints_one_line_per_period_of_simulated_time():
    out = io.StringIO()
    printer = JointPrinter(("shoulder", "elbow", "wrist"), 4.0, "velocity", stream=out)
    rt = fake_runtime()
    for k in range(1, 201):  # 1 s at 200 Hz
        rt.time = k * 0.005
        printer(rt)
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("print-joints: every 0.25 s") and "cmd rad/s" in lines[0]
    assert printer.lines == 4 and len(lines) == 5
    assert lines[1] == (
        "joints t=0.005s RUNNING | shoulder q=+1.000 dq=+0.010 cmd=+0.100 T=31.2 | "
        "elbow q=-0.500 dq=+0.000 cmd=-0.200 T=31.2 | wrist q=+0.250 dq=-2.000 cmd=+0.300 T=31.2"
    )
    assert [float(x.split()[1][2:-1]) for x in lines[1:]] == [0.005, 0.255, 0.505, 0.755]


def test_one_line_per_env_and_bad_rate():
    out = io.StringIO()
    JointPrinter(("a", "b", "c"), 1.0, "torque", stream=out)(fake_runtime(envs=2))
    lines = out.getvalue().splitlines()
    assert "cmd N m" in lines[0] and " env=0 " in lines[1] and " env=1 " in lines[2]
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="print-joints"):
            JointPrinter(("a",), bad, "position")


def deploy_run(tmp_path, *extra, env=None, duration="2"):
    # a policy made here: policies/arm.onnx exists only after `make export` (not in a clone)
    policy = adversarial_onnx(tmp_path, load_robot("arm3"), "velocity")
    cmd = [
        sys.executable,
        "-m",
        "sim2real.deploy.cli.deploy_run",
        "--policy",
        str(policy),
        "--duration",
        duration,
        "--report",
        str(tmp_path / "r.json"),
        *extra,
    ]
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    environ = {**os.environ, **(env or {})}
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=root, env=environ)


def test_deploy_run_print_joints(tmp_path):
    done = deploy_run(tmp_path, "--print-joints", "2")
    assert done.returncode == 0, done.stderr
    lines = [x for x in done.stdout.splitlines() if x.startswith("joints t=")]
    assert len(lines) == 4  # 2 s at 2 Hz
    assert all("shoulder q=" in x and "wrist q=" in x and " T=" in x for x in lines)
    assert "goals reached" in done.stdout


def test_video_without_a_gl_backend_is_one_error_line_and_the_run_goes_on(tmp_path):
    video = tmp_path / "run.mp4"
    done = deploy_run(tmp_path, "--video", str(video), env={"MUJOCO_GL": "osmesa"}, duration="1")
    errors = [x for x in done.stderr.splitlines() if "error" in x]
    if not errors:
        pytest.skip("osmesa works on this machine: no failing GL backend to test with")
    assert done.returncode == 0, done.stderr
    assert len(errors) == 1 and "MUJOCO_GL=osmesa" in errors[0]
    assert "Traceback" not in done.stderr
    assert not video.exists() and "goals reached" in done.stdout


def egl_works() -> bool:
    probe = (
        "import mujoco; m = mujoco.MjModel.from_xml_string('<mujoco/>'); "
        "mujoco.Renderer(m, 32, 32).render()"
    )
    env = {**os.environ, "MUJOCO_GL": "egl"}
    return (
        subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True).returncode == 0
    )


@pytest.mark.skipif(not egl_works(), reason="no EGL OpenGL context here (MUJOCO_GL=egl)")
def test_video_renders_an_h264_mp4(tmp_path):
    import imageio_ffmpeg

    video = tmp_path / "run.mp4"
    done = deploy_run(
        tmp_path, "--video", str(video), "--fps", "20", "--size", "320x240",
        env={"MUJOCO_GL": "egl"}, duration="1",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "frames/s" in done.stdout
    reader = imageio_ffmpeg.read_frames(str(video))
    meta = next(reader)
    assert meta["size"] == (320, 240) and meta["codec"].startswith("h264")
    frames = [np.frombuffer(f, np.uint8) for f in reader]
    assert len(frames) == 21  # t = 0.005 .. 1.0 s at 20 fps: the first frame after the first tick
    assert frames[-1].reshape(240, 320, 3).std() > 1.0  # not a blank image


def test_bad_video_size_is_bad_input(tmp_path):
    done = deploy_run(tmp_path, "--video", str(tmp_path / "x.mp4"), "--size", "big", duration="1")
    assert done.returncode == 3 and "--size" in done.stderr
