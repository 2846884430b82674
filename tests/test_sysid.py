"""sysid: a robot's motors fitted from its own log. The "robot" is the plant running a plant
motors file the fit does not read (friction, twice the armature, a 20 % weaker torque-speed
line, 8 ms of command delay); the fit recovers them from deploy-run's command log and the gap
report shows the fitted plant reading as close as the truth."""

import json
from pathlib import Path

import numpy as np
import pytest

from sim2real.deploy.cli.deploy_run import deploy_run_main
from sim2real.deploy.observe.command_log import CommandLogError, read_command_log
from sim2real.eval.sysid import cli
from tests.runtime_fixtures import shipped_onnx

#: the worn SO-101 `make sysid` runs on: 0.02 N m of friction, twice the armature, a line
#: 20 % weaker (no-load 3.77 rad/s), 8 ms of command delay
TRUTH = (
    Path(__file__).resolve().parent.parent
    / "sim2real"
    / "eval"
    / "sysid"
    / "examples"
    / "so101_worn.toml"
)


@pytest.fixture(scope="module")
def worn_log(tmp_path_factory):
    """4 s of the shipped SO-101 policy on the worn robot, recorded."""
    folder = tmp_path_factory.mktemp("sysid")
    log = folder / "run.npz"
    argv = ["--robot", "so101", "--policy", str(shipped_onnx("so101", folder)), "--duration", "4"]
    argv += ["--plant-motors", str(TRUTH), "--record-commands", str(log)]
    assert deploy_run_main(argv) == 0
    return folder, log, TRUTH


def test_the_log_holds_every_tick(worn_log, so101):
    _, log, _ = worn_log
    meta, arrays = read_command_log(log)
    assert meta["robot"] == "so101" and meta["control_mode"] == "position"
    ticks = round(4.0 / so101.control_period)
    assert arrays["command"].shape == (ticks, so101.n_joints)
    np.testing.assert_allclose(np.diff(arrays["t"]), so101.control_period)


def test_sysid_recovers_the_worn_motors(worn_log, so101):
    folder, log, truth = worn_log
    out = folder / "fit"
    argv = ["--robot", "so101", "--log", str(log), "--out", str(out), "--max-delay", "0.016"]
    assert cli.main([*argv, "--truth", str(truth)]) == cli.EXIT_OK
    fitted = (out / "plant_motors.toml").read_text()
    assert "command_delay = 0.008" in fitted
    from sim2real.robots.plant_motors import load_plant_motors

    plant = load_plant_motors(out / "plant_motors.toml", so101)
    assert plant.robot.motors[0].max_velocity == pytest.approx(3.77, rel=0.05)
    armature = plant.values[:, 1]
    assert armature == pytest.approx(2 * 0.0119025, rel=0.10)
    gap = json.loads((out / "gap.json").read_text())["plants"]
    rms = {name: max(p["rms_rad"].values()) for name, p in gap.items()}
    assert rms["fitted"] < 0.25 * rms["described"]
    assert rms["fitted"] < 1.5 * rms["truth"]  # as close as the truth reads
    assert (out / "gap.md").exists() and (out / "gap.png").stat().st_size > 0
    page = (out / "gap.html").read_text()
    assert "shoulder_pan" in page and "data:image/png;base64," in page


def test_a_bad_log_is_refused_naming_the_file(tmp_path, capsys):
    bad = tmp_path / "run.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(CommandLogError, match=rf"{bad}: not a command log"):
        read_command_log(bad)
    argv = ["--robot", "so101", "--log", str(bad), "--out", str(tmp_path / "o")]
    assert cli.main(argv) == cli.EXIT_BAD_INPUT
    assert f"sysid: error: {bad}" in capsys.readouterr().err


#: a short excitation (deploy-run --excitation FILE): every joint together, a 0.3-2 Hz chirp and
#: three steps, 6.8 s; the joints share one motor model, so one sweep shows its friction
SHORT_EXCITATION = """
hold = 0.5
move = 0.3
chirp = 0.0
chirp_together = 4.0
f_start = 0.3
f_end = 2.0
steps = [1.0, -1.0, 0.0]
step_time = 0.4
"""


def test_an_excitation_run_recovers_the_friction(tmp_path, so101):
    """The excitation in the policy's place, through the runtime (guard, smoother), recorded
    on the worn robot: the fit finds the friction the policy's log could not (0.031 N m there)."""
    spec = tmp_path / "excitation.toml"
    spec.write_text(SHORT_EXCITATION)
    log = tmp_path / "run.npz"
    argv = ["--robot", "so101", "--excitation", str(spec), "--duration", "7"]
    assert (
        deploy_run_main([*argv, "--plant-motors", str(TRUTH), "--record-commands", str(log)]) == 0
    )
    meta, arrays = read_command_log(log)
    assert arrays["command"].shape == (700, so101.n_joints)
    out = tmp_path / "fit"
    argv = ["--robot", "so101", "--log", str(log), "--out", str(out), "--max-delay", "0.010"]
    assert cli.main(argv) == cli.EXIT_OK
    from sim2real.robots.plant_motors import load_plant_motors

    fitted = load_plant_motors(out / "plant_motors.toml", so101)
    assert fitted.robot.motors[0].command_delay == pytest.approx(0.008, abs=1e-6)
    assert fitted.values[:, 0] == pytest.approx(0.02, rel=0.15)  # friction, N m
    assert fitted.values[:, 1] == pytest.approx(2 * 0.0119025, rel=0.15)  # armature, kg m^2
    assert fitted.robot.motors[0].max_velocity == pytest.approx(3.77, rel=0.15)


def test_the_excitation_stays_inside_the_soft_limits(so101, tmp_path):
    from sim2real.deploy.policy.excitation import Excitation, ExcitationPolicy, trajectory

    targets = trajectory(so101, Excitation())
    assert (targets >= so101.soft_lower - 1e-12).all() and (
        targets <= so101.soft_upper + 1e-12
    ).all()
    policy = ExcitationPolicy(so101)
    obs = np.zeros((2, policy.spec.obs_dim), np.float32)
    first = policy(obs).copy()
    assert first.shape == (2, so101.n_joints) and np.abs(first).max() <= 1.0
    policy.reset(np.ones(2, dtype=bool))
    np.testing.assert_array_equal(policy(obs), first)
    bad = tmp_path / "bad.toml"
    bad.write_text("chirps = 3\n")
    with pytest.raises(ValueError, match="unknown keys"):
        Excitation.load(str(bad))
