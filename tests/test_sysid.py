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


# The tests reading the module fixture worn_log: on one pytest-xdist worker (make test's
# --dist loadgroup), which builds it once, not once per worker.
ON_ONE_WORKER = pytest.mark.xdist_group("worn_log")


@pytest.fixture(scope="module")
def worn_log(tmp_path_factory):
    """4 s of the shipped SO-101 policy on the worn robot, recorded."""
    folder = tmp_path_factory.mktemp("sysid")
    log = folder / "run.npz"
    argv = ["--robot", "so101", "--policy", str(shipped_onnx("so101", folder)), "--duration", "4"]
    argv += ["--plant-motors", str(TRUTH), "--record-commands", str(log)]
    assert deploy_run_main(argv) == 0
    return folder, log, TRUTH


@ON_ONE_WORKER
def test_the_log_holds_every_tick(worn_log, so101):
    _, log, _ = worn_log
    meta, arrays = read_command_log(log)
    assert meta["robot"] == "so101" and meta["control_mode"] == "position"
    ticks = round(4.0 / so101.control_period)
    assert arrays["command"].shape == (ticks, so101.n_joints)
    np.testing.assert_allclose(np.diff(arrays["t"]), so101.control_period)


@ON_ONE_WORKER
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


def test_a_robot_loop_log_replays_on_the_loops_updates(so101):
    """A robot with its own fixed-rate update loop (ros2_control): each update samples the state
    (its stamp) and then applies the newest command that arrived; the host reads 3.7 ms after
    an update and sends 0.4 ms after its read, so tick k's command acts from update k + 1. The
    replay on the loop's updates reads exactly the positions the loop sampled; on the host's
    ticks (the log without the loop's times) it does not."""
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.eval.sysid.replay import reading_errors, replay, timeline
    from sim2real.robots.plant_motors import load_plant_motors

    truth = load_plant_motors(TRUTH, so101)
    model = truth.apply(truth.robot.plant_model("position"))
    robot_plant = SimBackend(truth.robot, mode="position", models=[model])
    dt, ticks, after_update, send = so101.control_period, 300, 0.0037, 0.0004
    home = np.asarray(so101.home)
    robot_plant.reset(home)
    k = np.arange(ticks)
    swing = 0.25 * np.sin(2 * np.pi * 1.5 * k * dt)[:, None] * np.ones(so101.n_joints)
    command = home + np.where(k[:, None] > 0, swing, 0.0)
    reads = 100.0 + k * dt
    updates = reads - after_update
    position = np.empty((ticks, so101.n_joints))
    for j in range(ticks):  # update j: sample, then the newest command sent by then (j - 1)
        position[j] = robot_plant.true_position()[0]
        if j > 0:
            robot_plant.write(command[j - 1][None])
        robot_plant.advance()
    meta = {"joint_names": list(so101.joint_names), "control_period": dt,
            "control_mode": "position", "robot_loop": True}  # fmt: skip
    arrays = {"t": k * dt, "read_time": reads, "command": command, "position": position,
              "position_stamp": np.repeat(updates[:, None] + 2e-4, so101.n_joints, axis=1),
              "loop_stamp": updates, "write_time": reads + send}  # fmt: skip
    times, rows, first = timeline(arrays, dt)
    np.testing.assert_allclose(times, updates, atol=1e-9)
    assert first == 0 and rows[0] == 0 and list(rows[1:4]) == [0, 1, 2]
    errors = reading_errors(arrays, replay(so101, meta, arrays, truth), dt)
    assert np.isfinite(errors).sum() == ticks * so101.n_joints
    assert np.nanmax(np.abs(errors)) < 1e-9
    ticked = {key: v for key, v in arrays.items() if key not in ("loop_stamp", "write_time")}
    off = reading_errors(ticked, replay(so101, meta, ticked, truth), dt)
    assert np.nanmax(np.abs(off)) > 0.01  # a period off on a 1.5 Hz swing
