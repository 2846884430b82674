"""The soak's camera faults: drawn per session from its seed (its own ``camera`` stream), on the
batch's plant camera of a policy that reads an RGB image, recorded in the session result. arm3
with a camera above it (a copy of its folder), two sessions of a few simulated seconds."""

from __future__ import annotations

import shutil
from dataclasses import replace

import numpy as np

from sim2real.deploy.backends.sim.camera import CameraFaultRanges, CameraFaults
from sim2real.eval.soak.camera_faults import session_camera_faults
from sim2real.eval.world.session_draw import session_rng
from sim2real.robots import load_robot
from sim2real.robots.loading import ROBOTS_DIR
from tests.soak_fixtures import short_session
from tests.test_camera import egl_works, needs_gl  # noqa: F401 - egl_works: needs_gl's condition
from tests.test_camera_rgb import TINY, rgb_policy

OVERHEAD = '<camera name="overhead" pos="0.3 0 1.5" xyaxes="1 0 0 0 1 0"/>'


def overhead_arm3(out):
    """A copy of arm3's folder in ``out`` with :data:`OVERHEAD` in its world body."""
    out.mkdir(parents=True)
    for f in ("robot.toml", "arm3.xml"):
        shutil.copy(ROBOTS_DIR / "arm3" / f, out / f)
    xml = (out / "arm3.xml").read_text().replace("<worldbody>", "<worldbody>\n    " + OVERHEAD, 1)
    (out / "arm3.xml").write_text(xml)
    return out


def test_a_sessions_camera_faults_are_its_seeds_and_leave_its_other_draws_alone():
    a, b = session_camera_faults(3), session_camera_faults(4)
    assert a == session_camera_faults(3) and a != b
    again = CameraFaultRanges().sample(session_rng(3, "camera"))
    assert a == again and isinstance(a, CameraFaults)
    assert 0.5 <= a.lighting <= 1.5 and max(np.abs(a.extrinsic)) <= np.radians(2.0)


@needs_gl
def test_a_soak_batch_of_a_camera_policy_draws_each_sessions_camera_faults(tmp_path):
    from sim2real.eval.soak.batch import SessionBatch

    folder = overhead_arm3(tmp_path / "arm3_overhead")
    robot = load_robot(folder)
    policy = rgb_policy(robot, tmp_path, block=replace(TINY, rate=10.0))
    base = replace(short_session("arm3", policy.path, hours=3.0 / 3600), robot=str(folder))
    configs = [replace(base, seed=5), replace(base, seed=6)]
    results = SessionBatch(configs, tmp_path / "soak", progress=False).run()
    for config, result in zip(configs, results, strict=True):
        camera = result["camera"]
        drawn = session_camera_faults(config.seed)
        assert camera["faults"] == drawn.to_dict()
        assert camera["kind"] == "rgb" and camera["camera"] == "overhead"
        assert camera["frames"] >= 30  # 3 s at 10 Hz, once started
        assert camera["frames_taken"] + camera["frames_repeated"] <= camera["delivered"]
    assert results[0]["camera"]["faults"] != results[1]["camera"]["faults"]


@needs_gl
def test_deploy_run_renders_a_colour_camera_with_the_runs_drawn_faults(tmp_path, capsys):
    import json

    from sim2real.deploy.cli.deploy_run import deploy_run_main

    folder = overhead_arm3(tmp_path / "arm3_overhead")
    policy = rgb_policy(load_robot(folder), tmp_path)
    report = tmp_path / "report.json"
    code = deploy_run_main(
        ["--robot", str(folder), "--policy", str(policy.path), "--duration", "0.5",
         "--camera-faults", "drawn", "--seed", "4", "--report", str(report)]
    )  # fmt: skip
    out, err = capsys.readouterr()
    assert code != 3, out + err  # a frozen spell may stop it: a safe stop, not a refusal
    assert "deploy-run: colour camera 'overhead' 12x16 at 25 Hz" in err
    drawn = CameraFaultRanges().sample(np.random.default_rng([4, 99])).to_dict()
    camera = json.loads(report.read_text())["camera"]
    assert camera["plant"]["faults"] == json.loads(json.dumps(drawn))
    assert camera["plant"]["noise"]["full_well"] == 4300.0 and camera["frames_taken"][0] >= 5
