"""Legged robots in the runtime: the floating-base observation blocks, the
velocity command and gait clock, fall detection with a damped safe stop, and the base
estimator's state in the runtime's state_dict."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from onnx import helper

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.runtime import FAULT_CAUSES, Mode, Runtime
from sim2real.deploy.runtime.reference import ReferenceRuntime
from sim2real.deploy.spec.policy_spec import LEGGED_DEFAULT_BLOCKS, PolicySpec, SpecError
from sim2real.robots import load_robot
from tests.runtime_fixtures import linear_onnx, shipped_onnx

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def stand_policy(go2, tmp_path_factory):
    """An ONNX policy of go2's default spec whose action is 0: the home pose (the action's
    offset), whatever it observes."""
    spec = PolicySpec.for_robot(go2)
    d, n = spec.obs_dim, spec.act_dim
    nodes = [helper.make_node("MatMul", ["obs", "w"], ["action"])]
    weights = {"w": np.zeros((d, n), np.float32)}
    return _linear_policy(go2, spec, "stand", nodes, weights, tmp_path_factory)


def _linear_policy(go2, spec, name, nodes, weights, tmp_path_factory) -> OnnxPolicy:
    """An ONNX policy of ``spec`` on ``go2``: ``nodes`` from input ``obs`` to output ``action``
    with the initializers ``weights`` (name -> float32 array), saved in a temporary folder."""
    path = tmp_path_factory.mktemp("go2") / f"{name}.onnx"
    return OnnxPolicy(linear_onnx(spec, path, nodes, weights, name), go2)


def runtime(go2, policy, envs=2, seed=0, reference=False) -> tuple[Runtime, SimBackend]:
    plant = SimBackend(go2, "position", envs=envs, seed=seed)
    rt = (ReferenceRuntime if reference else Runtime)(go2, policy, plant)
    rt.start()
    return rt, plant


def test_default_legged_spec_reads_the_base_the_command_and_the_gait_clock(go2, stand_policy):
    spec = stand_policy.spec
    assert tuple(b.name for b in spec.observation_blocks) == LEGGED_DEFAULT_BLOCKS
    assert spec.obs_dim == 3 + 3 + 3 + 2 + 12 + 12 + 12
    np.testing.assert_allclose(spec.action.offset, go2.home)  # actions about the home pose
    rt, plant = runtime(go2, stand_policy)
    rt.velocity_command[:] = [[0.5, 0.0, 0.2], [-0.3, 0.1, 0.0]]
    rt.run(60)
    s = spec.block_slices()
    obs = spec.observation(rt.state, rt.goal)
    np.testing.assert_allclose(obs[:, s["velocity_command"]], [[1.0, 0, 0.05], [-0.6, 0.2, 0]])
    phase = 2 * np.pi * rt.state.clock / spec.observation_blocks[3].period
    np.testing.assert_allclose(obs[:, s["gait_phase"]], np.c_[np.sin(phase), np.cos(phase)], 1e-6)
    np.testing.assert_allclose(obs[:, s["joint_position"]], rt.state.q - go2.home, atol=1e-6)
    # projected gravity: the estimate's, close to the true base's (standing, sensor noise on)
    true_up = plant.true_base_state()[:, 3:7]  # [w x y z]
    w, x, y = true_up[:, 0], true_up[:, 1], true_up[:, 2]
    true_g_z = -(1 - 2 * (x * x + y * y))
    np.testing.assert_allclose(obs[:, s["projected_gravity"]][:, 2], true_g_z, atol=0.01)
    assert (rt.mode == Mode.RUNNING).all() and rt.counters.safe_stops.sum() == 0
    del w


def test_legged_blocks_are_refused_on_an_arm_and_foot_count_checked(go2, arm3):
    spec = PolicySpec.for_robot(go2)
    with pytest.raises(SpecError, match="robot: policy is for 'go2'"):
        spec.check_robot(arm3)
    arm_spec = PolicySpec.for_robot(arm3, blocks=("joint_position", "joint_velocity"))
    legged = arm_spec.__class__(
        **{**vars(arm_spec), "observation_blocks": spec.observation_blocks[1:2]}
    )
    with pytest.raises(SpecError, match="'projected_gravity' cannot be provided: the robot"):
        legged.check_robot(arm3, check_hash=False)
    with pytest.raises(SpecError, match="period must be a positive number of s"):
        gait = spec.observation_blocks[3]
        bad = spec.__class__(
            **{**vars(spec), "observation_blocks": (gait.__class__(**{**vars(gait), "period": 0}),)}
        )
        bad.validate()


@pytest.mark.parametrize("reference", [False, True])
def test_fall_detection_trips_on_a_pushed_over_robot_and_not_on_a_standing_one(
    go2, stand_policy, reference
):
    rt, plant = runtime(go2, stand_policy, reference=reference)
    rt.run(150)  # 3 s standing, with encoder and IMU noise
    assert rt.counters.faults["fall"].sum() == 0
    assert (rt.mode == Mode.RUNNING).all()
    plant.set_external_force(0, np.array([0.0, 300.0, 0.0]))  # env 0 shoved sideways
    rt.run(15)
    plant.set_external_force(0, np.zeros(3))
    rt.run(150)
    assert rt.counters.faults["fall"].tolist() == [1, 0]
    assert rt.cause_names()[0] == "fall" and rt.mode[1] == Mode.RUNNING
    assert rt.mode[0] == Mode.FAULTED  # latched once the joints came to rest
    # the fall stop damps: the command follows the measured pose (no stiff hold)
    assert rt.damping.tolist() == [True, False]
    np.testing.assert_array_equal(rt.command[0], rt.state.q[0])
    assert np.abs(rt.command[1] - rt.state.q[1]).max() > 1e-4  # the other holds its pose
    rt.reset_faults()
    assert rt.mode[0] == Mode.RAMP_IN and not rt.damping[0]
    assert FAULT_CAUSES.index("fall") == 6


def test_a_low_base_trips_the_fall_check_only_when_it_stays_low(go2, stand_policy):
    """The height check trips once the base has stayed under the limit for FALL_HEIGHT_TIME (a
    collapsed robot), not on the single-tick dips of a low trot's estimate on one foot (the
    shipped Go2 was stopped as fallen, walking, by one such tick); the count is state."""
    from copy import deepcopy

    from sim2real.deploy.estimation.fall import FALL_HEIGHT_TIME

    rt, _ = runtime(go2, stand_policy)
    rt.run(50)  # standing: every foot in contact
    detector = rt.fall_detector
    standing = deepcopy(rt.state)
    collapsed = deepcopy(rt.state)
    collapsed.q[:] = standing.q
    for leg in range(4):  # thighs forward and calves folded: the base sinks to the feet
        collapsed.q[:, 3 * leg + 1] = 1.5
        collapsed.q[:, 3 * leg + 2] = -2.7
    assert not detector.check(standing).any()
    assert detector.height_ticks == round(FALL_HEIGHT_TIME / go2.control_period) == 10
    for _ in range(20):  # a dip on every other tick never persists
        assert not detector.check(collapsed).any()
        assert (detector.height < detector.height_limit).all()
        assert not detector.check(standing).any()
    for _ in range(detector.height_ticks - 1):
        assert not detector.check(collapsed).any()
    saved = detector.state_dict()
    assert saved["low_ticks"].tolist() == [9, 9]
    assert detector.check(collapsed).all()  # the tenth tick in a row
    detector.load_state_dict(saved)
    assert detector.check(collapsed).all()
    assert "fall_detector/low_ticks" in rt.state_dict()


def test_a_base_sinking_upright_trips_the_fall_check_with_its_feet_still_under_it(
    go2, stand_policy
):
    """The feet fall with the base (through a floor, a robot dropped on a slack support): the
    kinematic height and the tilt stay normal, the estimated base sinks faster than FALL_SPEED;
    upright on its feet, UPRIGHT_SINK_TIME in a row (15 ticks) trip the check, 14 do not (a
    robot crouching to catch a push); a walking base's bob never does."""
    from copy import deepcopy

    from sim2real.deploy.estimation.fall import FALL_SPEED

    rt, _ = runtime(go2, stand_policy)
    rt.run(50)
    detector = rt.fall_detector
    standing, sinking = deepcopy(rt.state), deepcopy(rt.state)
    sinking.base.linear_velocity_world[:, 2] = -1.5 * FALL_SPEED
    bobbing = deepcopy(rt.state)
    for k in range(40):  # +-0.3 m/s, the walk's vertical velocity
        bobbing.base.linear_velocity_world[:, 2] = 0.3 * (-1) ** k
        assert not detector.check(bobbing).any()
    for _ in range(detector.upright_ticks - 1):
        assert not detector.check(sinking).any()
    assert not detector.check(standing).any()  # the count starts again
    for _ in range(detector.upright_ticks - 1):
        assert not detector.check(sinking).any()
    assert detector.check(sinking).all() and detector.upright_ticks == 15
    assert (detector.height > detector.height_limit).all()  # the feet did not say so


def test_a_sinking_base_trips_the_fall_check_in_a_tenth_of_a_second_only_when_it_is_not_upright(
    go2, stand_policy
):
    """The sinking signal stopped an upright robot catching a push (a holosoma G1:
    0.4 deg, base 0.67 of 0.757 m), and an H1 coming down from the hop a push threw it into
    (no foot in contact, upright, its base at its standing height). Sinking past FALL_SPEED for
    five ticks (0.1 s) trips the check when the base is tilted past SINK_TILT_SHARE of the tilt
    limit or its kinematic height is under SINK_HEIGHT_SHARE of the standing height; upright, on
    its feet or in the air, it does not (UPRIGHT_SINK_TIME does, below)."""
    from copy import deepcopy

    from sim2real.deploy.core.attitude import projected_gravity
    from sim2real.deploy.estimation.fall import FALL_SPEED

    rt, _ = runtime(go2, stand_policy)
    rt.run(50)
    detector = rt.fall_detector
    assert detector.sink_tilt == pytest.approx(0.4) and detector.sink_height == pytest.approx(
        0.5 * 0.3257
    )
    upright = deepcopy(rt.state)
    upright.base.linear_velocity_world[:, 2] = -1.5 * FALL_SPEED
    tilted, flying = deepcopy(upright), deepcopy(upright)
    angle = 0.5  # rad about x: past the 0.4 rad gate, under the 1 rad tilt limit
    quat = np.array([np.cos(angle / 2), np.sin(angle / 2), 0.0, 0.0])
    tilted.base.orientation[:] = quat
    tilted.base.projected_gravity[:] = projected_gravity(quat[None])[0]
    flying.foot_contact[:] = 0.0
    tilted_flying = deepcopy(tilted)
    tilted_flying.foot_contact[:] = 0.0
    for state in (upright, tilted, flying, tilted_flying):
        detector.load_state_dict({k: 0 * v for k, v in detector.state_dict().items()})
        fired = [bool(detector.check(state).all()) for _ in range(detector.speed_ticks)]
        fast = state is tilted or state is tilted_flying
        assert fired == [False] * 4 + [fast], fired
        assert detector.signals[:, 0].sum() == 0  # not the tilt signal
    detector.load_state_dict({k: 0 * v for k, v in detector.state_dict().items()})
    fired = [bool(detector.check(flying).all()) for _ in range(detector.upright_ticks)]
    assert fired == [False] * (detector.upright_ticks - 1) + [True], fired


def test_base_estimate_and_gait_clock_survive_state_dict(go2, stand_policy):
    rt, plant = runtime(go2, stand_policy, seed=3)
    rt.velocity_command[:] = [0.4, 0.0, 0.0]
    rt.run(40)
    saved = rt.state_dict()
    assert "base_estimator/gyro_bias" in saved and "state/base/projected_gravity" in saved
    assert "state/sensed_orientation" in saved  # go2's IMU sends its own attitude
    rt.run(30)
    expected = (rt.command.copy(), rt.state.base.orientation.copy(), rt.state.clock.copy())
    sensed = rt.state.sensed_orientation.copy()
    again, _ = runtime(go2, stand_policy, seed=11)  # other noise: the state must replace it
    again.load_state_dict(saved)
    again.run(30)
    np.testing.assert_array_equal(again.command, expected[0])
    np.testing.assert_array_equal(again.state.base.orientation, expected[1])
    np.testing.assert_array_equal(again.state.clock, expected[2])
    np.testing.assert_array_equal(again.state.sensed_orientation, sensed)


def test_shipped_go2_walks_at_the_commanded_speed_through_the_runtime(tmp_path):
    """sim2real/policies/go2.pt (PPO residual on the trot generator, sim2real.policies.train_legged) through
    deploy-run with sensor noise: forward at >= 0.35 m/s for a 0.5 m/s command, no fall, no hard
    violation; the committed checkpoint has the recipe's spec and architecture, and its curve
    names the command that trained it."""
    import json

    from sim2real.deploy.cli.deploy_run import deploy_run_main
    from sim2real.deploy.policy.mlp_checkpoint import read_checkpoint
    from sim2real.policies.gait import make_policy

    shipped = read_checkpoint(REPO / "sim2real" / "policies" / "go2.pt")
    actor, spec = make_policy()
    assert shipped.spec == spec and shipped.actor.architecture == actor.architecture
    curve = json.loads((REPO / "sim2real" / "policies" / "go2.curve.json").read_text())
    assert curve["command"].startswith("python -m sim2real.policies.train_legged")
    onnx_path = shipped_onnx("go2", tmp_path)
    report = tmp_path / "run.json"
    code = deploy_run_main(
        ["--robot", "go2", "--policy", str(onnx_path), "--command", "0.5,0,0"]
        + ["--duration", "12", "--report", str(report)]
    )
    r = json.loads(report.read_text())
    walk = r["locomotion"]
    assert code == 0 and walk["falls"] == 0, walk
    assert walk["mean_forward_speed_m_s"] >= 0.35, walk
    assert walk["tracking_success"] > 0.8, walk
    assert r["violations"]["by_type"]["hard_limit"] == 0
    assert set(r["peak_winding_temperature_c"]) == set(load_robot("go2").joint_names)
    # the base estimate against the truth, over the whole run (settling included): the
    # Mahony + velocity-KF estimator it replaced read the forward speed 13 % low, 2.5 deg off
    est = r["estimation"]
    assert walk["true_falls"] == 0 and est["true_falls"] == 0
    assert est["attitude_error_deg"]["mean"] < 1.5, est
    assert abs(est["velocity_bias_fraction"]) < 0.05, est
    assert est["velocity_rms_m_s"] < 0.1, est


def test_a_true_fall_the_runtime_did_not_see_is_counted_once_until_the_robot_is_up(go2):
    """EstimationMonitor on the truth alone: a base that sinks below 0.4 of its standing
    height while RUNNING is one true fall however long it lies there, a second after it was up;
    an estimate equal to the truth has no attitude error and no velocity bias."""
    from types import SimpleNamespace

    from sim2real.deploy.core.state import BaseState
    from sim2real.deploy.monitors.estimation import EstimationMonitor

    monitor = EstimationMonitor(go2, 1)
    stand = go2.config.base.standing_height
    truth = np.zeros((1, 13))
    truth[0, 3] = 1.0  # upright
    truth[0, 7] = 0.5  # 0.5 m/s forward
    rt = SimpleNamespace(mode=np.array([int(Mode.RUNNING)]), state=SimpleNamespace(base=None))
    heights = [stand] * 5 + [0.1 * stand] * 10 + [stand] * 5 + [0.2 * stand] * 3
    for h in heights:
        truth[0, 2] = h
        rt.state.base = BaseState.zeros(1).set_truth(truth)
        monitor.update(rt, truth)
    s = monitor.summary()
    assert s["true_falls"] == 2
    assert s["attitude_error_deg"]["mean"] < 1e-6
    assert s["velocity_bias_fraction"] == pytest.approx(0.0, abs=1e-12)
    assert EstimationMonitor(go2, 1).summary() is None  # never RUNNING: unknown, not zero


@pytest.mark.parametrize("reference", [False, True])
def test_a_legged_target_past_a_hard_limit_passes_and_an_estimate_stops_only_when_held_or_far(
    go2, reference
):
    """A Go2's PD targets act as torques: a calf target past its hard limit (what a legged policy
    or its exploration commands), its joint far from the stop, passes (its predicted motion is
    safe: sim2real/deploy/safety/pd_barrier.py), not a safe stop. Its
    estimate a few hundredths of a radian past the hard limit for one stride (0.8 s, the H1's gait
    cycle) is not a stop either (a stop lays a walking robot down), nor is a joint bouncing off its
    stop more than ``LEGGED_HARD_LIMIT_TOLERANCE`` (0.1 rad) past it for a tick or two, however
    long it was past by less before. Held past it longer than ``LEGGED_HARD_LIMIT_DURATION``
    (1 s), or more than the tolerance past it for longer than ``LEGGED_HARD_LIMIT_BOUNCE``
    (0.1 s), is."""
    from sim2real.deploy.core.state import RobotState
    from sim2real.deploy.safety.guard import SafetyGuard
    from sim2real.deploy.safety.limits import (
        LEGGED_HARD_LIMIT_BOUNCE,
        LEGGED_HARD_LIMIT_DURATION,
        LEGGED_HARD_LIMIT_TOLERANCE,
    )
    from sim2real.deploy.safety.reference import ReferenceGuard

    envs = 3
    guard = (ReferenceGuard if reference else SafetyGuard)(go2, envs, "position")
    state = RobotState.legged(envs, go2.n_joints, go2.n_feet, 25.0)
    state.q[:] = go2.home
    guard.reset(state.q)
    calf = go2.joint_names.index("FL_calf_joint")
    lower = go2.position_lower[calf]
    target = np.tile(go2.home, (envs, 1))
    target[0, calf] = lower - 0.2

    def tick(q_calf):
        state.q[:, calf] = q_calf
        out = guard.filter(target.copy(), state, out=np.empty_like(target))
        return out, guard.hard_violation.tolist()

    far = lower - LEGGED_HARD_LIMIT_TOLERANCE - 0.02
    out, stops = tick([go2.home[calf], lower - 0.04, far])
    assert out[0, calf] == target[0, calf]  # a torque request whose motion is safe: passed
    assert guard.counts["soft_limit"][0] == 0 and guard.counts["pd_barrier"][0] == 0
    assert stops == [False, False, False]  # far past for a tick: a bounce off the stop
    assert tick([go2.home[calf], go2.home[calf], lower - 0.01])[1] == [False, False, False]
    assert tick([go2.home[calf], go2.home[calf], go2.home[calf]])[1] == [False, False, False]
    bounce = round(LEGGED_HARD_LIMIT_BOUNCE / go2.control_period)
    verdicts = [tick([go2.home[calf], go2.home[calf], far])[1][2] for _ in range(bounce + 1)]
    assert verdicts == [False] * bounce + [True]  # far past and staying: a stop after 0.1 s
    # past by a little for 0.1 s (a crouch), then far past for two ticks (the stop's impact):
    # a bounce, however long it was past before (the H1-2's ankle, seed 20 of its domain)
    guard.reset(state.q)
    for _ in range(bounce + 1):
        assert tick([go2.home[calf], go2.home[calf], lower - 0.02])[1] == [False, False, False]
    for _ in range(2):
        assert tick([go2.home[calf], go2.home[calf], far])[1] == [False, False, False]
    assert tick([go2.home[calf], go2.home[calf], lower - 0.02])[1] == [False, False, False]
    guard.reset(state.q)
    stride = round(0.8 / go2.control_period)  # a stride past the limit, then back
    for _ in range(stride - 1):
        assert tick([go2.home[calf], lower - 0.04, go2.home[calf]])[1] == [False, False, False]
    assert tick([go2.home[calf], lower + 0.01, go2.home[calf]])[1] == [False, False, False]
    held = round(LEGGED_HARD_LIMIT_DURATION / go2.control_period)
    verdicts = [tick([go2.home[calf], lower - 0.04, go2.home[calf]])[1][1] for _ in range(held + 1)]
    assert verdicts == [False] * held + [True]  # held past it: a stop after 1 s


@pytest.fixture(scope="module")
def chatter_policy(go2, tmp_path_factory):
    """An ONNX policy of go2's default spec whose action alternates between ``CHATTER`` and 0 on
    every joint from one tick to the next (``action = CHATTER - last_action``): PD targets that
    jump up to 0.15 rad each tick, which the low-gain drives barely follow."""
    spec = PolicySpec.for_robot(go2)
    d, n = spec.obs_dim, spec.act_dim
    w = np.zeros((d, n), np.float32)
    w[d - n :, :] = -np.eye(n, dtype=np.float32)  # the last block is last_action
    nodes = [
        helper.make_node("MatMul", ["obs", "w"], ["minus_last"]),
        helper.make_node("Add", ["minus_last", "b"], ["action"]),
    ]
    weights = {"w": w, "b": np.full(n, CHATTER, np.float32)}
    return _linear_policy(go2, spec, "chatter", nodes, weights, tmp_path_factory)


#: The chatter policy's action on every joint every other tick (0.15 rad of target at the Go2's
#: action scale of 0.25).
CHATTER = 0.6


@pytest.mark.parametrize("latency", [0, 1])
def test_a_legged_joint_estimate_does_not_follow_its_pd_targets_chatter(
    go2, chatter_policy, latency
):
    """A floating base's PD targets are torques, not the joints' motion: targets that jump by
    a tenth of a radian every tick (a legged policy answering a late reading, as the H1-2 did in a latency
    fault of its soak) move the Go2's joints by a few hundredths. The joint estimate must follow
    the joints, not the targets, with and without a tick of encoder latency. Fed the smoother's
    acceleration as its control input, the estimate swung with the targets, 0.12 rad off without
    latency (in the H1-2's soak, 0.47 rad off with it)."""
    plant = SimBackend(go2, "position", envs=1, seed=0)
    plant.latency_ticks[:] = latency
    rt = Runtime(go2, chatter_policy, plant)
    rt.start()
    rt.run(150)  # 3 s: through RAMP_IN into RUNNING, the chatter at full size
    errors, targets = [], []
    joints = [plant.true_position()[0].copy()]  # where the joints are at each tick's time

    def compare(r):
        errors.append(np.abs(r.state.q[0] - joints[-1]).max())
        targets.append(r.command[0].copy())
        joints.append(plant.true_position()[0].copy())

    rt.run(100, on_tick=compare)
    assert rt.mode_names() == ["RUNNING"], rt.cause_names()
    swing = np.abs(np.diff(np.array(targets), axis=0)).max()
    assert swing > 0.05, swing  # the targets do chatter
    assert max(errors) < 0.05, (max(errors), swing)


def test_every_stop_of_a_walking_robot_counts_as_a_fall_with_its_cause(go2, stand_policy):
    """The runtime lays a legged robot down at every stop: a stale-sensor stop leaves the base on
    the ground as a tilt stop does, so both are falls (by cause); a stop during the RAMP_IN of a
    robot still lying is not another fall."""
    from sim2real.deploy.tasks.locomotion import CommandTracker

    rt, plant = runtime(go2, stand_policy)
    tracker = CommandTracker(2, go2.control_period, plant)

    def run(ticks):
        rt.run(ticks, on_tick=tracker)

    run(150)
    plant.set_external_force(0, np.array([0.0, 300.0, 0.0]))  # env 0 shoved over
    run(15)
    plant.set_external_force(0, np.zeros(3))
    rt.supervision.safe_stop(np.array([False, True]), "stale_sensor")  # env 1: a sensor stops
    run(150)
    assert tracker.falls.tolist() == [1, 1]
    assert tracker.causes(0) == {"fall": 1} and tracker.causes(1) == {"stale_sensor": 1}
    record = tracker.fall_log[0][0]  # the truth at the stop: height, tilt, vertical velocity
    assert {"true_height_m", "true_tilt_deg", "true_vz_m_s"} <= set(record), record
    assert tracker.summary(rt)["falls"] == 2
    rt.reset_faults()
    rt.supervision.safe_stop(np.array([True, True]), "stale_sensor")  # during RAMP_IN: lying
    run(5)
    assert tracker.falls.tolist() == [1, 1]


def test_a_stop_the_operator_asked_for_is_not_a_fall(go2, stand_policy):
    """A lie-down, a damp or a ROS 2 ``~/stop`` (cause ``operator``) of a walking robot is the
    operator's: counted as an operator stop, never as a fall of the policy."""
    from sim2real.deploy.tasks.locomotion import CommandTracker

    rt, plant = runtime(go2, stand_policy)
    tracker = CommandTracker(2, go2.control_period, plant)
    rt.run(150, on_tick=tracker)
    rt.supervision.safe_stop(np.array([True, False]), "operator")
    rt.run(50, on_tick=tracker)
    summary = tracker.summary(rt)
    assert tracker.falls.tolist() == [0, 0] and summary["falls"] == 0
    assert tracker.operator_stops.tolist() == [1, 0] and summary["operator_stops"] == 1
    assert summary["falls_by_cause"] == {}


@pytest.fixture(scope="module")
def shipped_go2(go2, tmp_path_factory):
    return OnnxPolicy(shipped_onnx("go2", tmp_path_factory.mktemp("shipped")), go2)


def test_one_tick_latency_bursts_do_not_make_the_shipped_go2_fall(go2, shipped_go2):
    """Real links jitter by a control period: bursts of one extra tick of encoder latency (0.2 to
    2 s, every 3 s) while the command changes every 4 s must not make the walking Go2 fall. The
    estimate bridges the late reading at constant velocity: extrapolated with the smoother's
    acceleration (a PD target's, not the joint's), the same policy fell in three of the four."""
    from sim2real.deploy.backends.sim.faults import Fault, FaultInjector
    from sim2real.deploy.tasks.locomotion import CommandTracker

    envs, seconds = 4, 40.0
    rng = np.random.default_rng(0)
    plant = SimBackend(go2, "position", envs=envs, seed=0)
    bursts = [
        Fault("latency", float(t), float(rng.uniform(0.2, 2.0)), magnitude=1.0)
        for t in np.arange(2.0, seconds, 3.0)
    ]
    rt = Runtime(go2, shipped_go2, plant, injector=FaultInjector(bursts, plant))
    rt.start()
    tracker = CommandTracker(envs, go2.control_period, plant)
    every = int(round(4.0 / go2.control_period))

    def on_tick(runtime):
        tracker(runtime)
        if runtime.ticks % every == 0:  # vx 0-0.5 m/s, yaw rate +-0.5 rad/s, one for all
            runtime.velocity_command[:] = [rng.uniform(0.0, 0.5), 0.0, rng.uniform(-0.5, 0.5)]

    rt.velocity_command[:] = [rng.uniform(0.0, 0.5), 0.0, rng.uniform(-0.5, 0.5)]
    rt.run(int(round(seconds / go2.control_period)), on_tick=on_tick)
    assert plant.latency_ticks.max() == 0 and len(bursts) == 13
    assert tracker.falls.tolist() == [0] * envs, [tracker.causes(e) for e in range(envs)]
    assert (tracker.distance > 5.0).all(), tracker.distance


def test_a_drifted_accelerometer_bias_is_learned_and_not_read_as_sinking(go2, shipped_go2):
    """The accelerometer bias the soak's random walk reached after three hours (seed 0:
    (0.07, 0.25, -1.11) m/s^2) on the shipped Go2 walking at 0.5 m/s: the filter estimates it
    from the legs, so the vertical velocity stays unbiased and the fall check's sinking signal
    (1 m/s for 0.1 s) has margin. Without the bias state the estimate read -0.17 m/s vertical on
    average and -0.56 at worst, and that soak stopped a walking robot as a fall."""
    plant = SimBackend(go2, "position", envs=1, seed=0)
    rt = Runtime(go2, shipped_go2, plant)
    rt.velocity_command[0] = [0.5, 0.0, 0.0]
    rt.start()
    bias = np.array([0.07, 0.25, -1.11])
    plant.base_sensors.accel_bias[:] = bias
    error = []
    for k in range(round(30.0 / rt.dt)):
        rt.tick()
        if k * rt.dt > 10.0:
            true = plant.true_base_state()[0, 7:10]
            error.append(rt.state.base.linear_velocity_world[0, 2] - true[2])
    error = np.array(error)
    assert rt.mode[0] == Mode.RUNNING
    assert abs(error.mean()) < 0.08 and error.min() > -0.5, (error.mean(), error.min())
    assert abs(rt.base_estimator.accel_bias[0, 2] - bias[2]) < 0.2


class NoFootSensors(SimBackend):
    """The plant as a unitree_hg LowState reads: no foot force (NaN) under a fresh stamp."""

    def read(self):
        frame = super().read()
        frame.foot_force[:] = np.nan
        frame.foot_contact[:] = False
        return frame


def test_a_robot_without_foot_sensors_walks_on_kinematic_contacts(go2, shipped_go2):
    """unitree_hg robots (G1, H1-2) send no foot force: the backend fills the frame's force with
    NaN under a fresh contact stamp. The estimator takes those feet as sensorless at once and
    finds contacts by kinematics; the shipped Go2 walks 20 s so, the base estimate close to the
    truth. Before, the leg odometry never ran: the IMU alone read the base sinking at 5 m/s and
    the fall check stopped the robot within seconds."""

    plant = NoFootSensors(go2, "position", envs=1, seed=0)
    rt = Runtime(go2, shipped_go2, plant)
    rt.velocity_command[0] = [0.5, 0.0, 0.0]
    rt.start()
    error = []
    for k in range(round(20.0 / rt.dt)):
        rt.tick()
        if k * rt.dt > 5.0:
            true = plant.true_base_state()[0, 7:10]
            error.append(rt.state.base.linear_velocity_world[0] - true)
    assert rt.mode[0] == Mode.RUNNING, rt.cause_names()
    assert rt.base_estimator.dead_feet.all()
    rms = float(np.sqrt(np.square(np.array(error)).sum(axis=1).mean()))
    assert rms < 0.2, rms
    assert plant.true_base_state()[0, 0] > 4.0  # it walked


def test_kinematic_contacts_do_not_turn_the_heading(go2, shipped_go2):
    """A Go2 whose feet report no force (Unitree's simulation bridge; a dead foot sensor) walks
    on kinematic contacts, whose errors the filter's gain carried into the heading through its
    cross-covariances, learning a gyro bias about the up axis that was not there: 30 s of a
    straight command read a 121 deg true turn as 88 deg (and unitree_mujoco's Go2 -23 deg for
    -107). The heading is locked against the corrections (sim2real.deploy.estimation.base_kernel): the
    estimate's yaw is the gyro's, within 10 % + 5 deg of the truth's (the plant's gyro bias of
    seed 0 about the up axis, unobservable, turns it 6 deg)."""
    from sim2real.deploy.core.attitude import yaw_of

    plant = NoFootSensors(go2, "position", envs=1, seed=0)
    rt = Runtime(go2, shipped_go2, plant)
    rt.velocity_command[0] = [0.5, 0.0, 0.0]
    rt.start()
    estimated, true = [], []
    for _ in range(round(30.0 / rt.dt)):
        rt.tick()
        estimated.append(yaw_of(rt.state.base.orientation[0]))
        true.append(yaw_of(plant.true_base_state()[0, 3:7]))
    assert rt.mode[0] == Mode.RUNNING, rt.cause_names()
    turn_est = np.degrees(np.unwrap(estimated)[-1] - estimated[0])
    turn_true = np.degrees(np.unwrap(true)[-1] - true[0])
    assert abs(turn_true) > 45.0, turn_true  # the policy turns on a straight command
    assert abs(turn_est - turn_true) < 0.1 * abs(turn_true) + 5.0, (turn_est, turn_true)


def test_the_locked_heading_leaves_the_velocity_estimate_as_good_over_minutes(go2, shipped_go2):
    """With the heading locked, its error variance had nothing to bound it: it grew to 1.8 rad^2
    in 3 minutes, fed the velocity's variance through ``[R f]x`` at every acceleration of the
    base, and the Go2's planar velocity error in a soak doubled (0.09 -> 0.21 m/s RMS in half an
    hour, 0.46 over 8 hours). The heading's variance is held at zero: 3 minutes of changing
    commands keep the planar error under 0.1 m/s RMS (0.126 before)."""
    from sim2real.deploy.core.state import BaseState

    plant = SimBackend(go2, "position", envs=1, seed=0)
    rt = Runtime(go2, shipped_go2, plant)
    rt.start()
    commands = [[0.5, 0, 0], [0.1, 0, 0.5], [0.4, 0, -0.4], [0.0, 0, 0], [0.5, 0, 0.2]]
    truth = BaseState.zeros(1)
    error = []
    for k in range(round(180.0 / rt.dt)):
        rt.velocity_command[0] = commands[(k // 100) % len(commands)]
        rt.tick()
        if k * rt.dt > 5.0:
            true = truth.set_truth(plant.true_base_state()).linear_velocity[0, :2]
            error.append(rt.state.base.linear_velocity[0, :2] - true)
    assert rt.mode[0] == Mode.RUNNING, rt.cause_names()
    rms = float(np.sqrt(np.square(np.array(error)).sum(axis=1).mean()))
    assert rms < 0.1, rms
    assert rt.base_estimator.covariance[0, 2, 2] == 0.0


def test_a_policy_reading_its_last_action_starts_from_zero_after_a_stop_and_reset(go2, tmp_path):
    """While a robot lies stopped the drives run the runtime's override, not the policy: the
    policy's last action reads 0 there (its output fed back to itself would grow unchecked, a
    policy of Isaac Lab's reading its last action reached 1e6 lying damped), and after the
    operator's reset it starts from 0 as after the start. Policy: action = last action + 0.002."""
    spec = PolicySpec.for_robot(go2, blocks=(*LEGGED_DEFAULT_BLOCKS, "last_action"))
    n, start = spec.act_dim, spec.block_slices()["last_action"].start
    w = np.zeros((spec.obs_dim, n), np.float32)
    w[start : start + n] = np.eye(n)  # the block's scale is 1
    nodes = [
        helper.make_node("MatMul", ["obs", "w"], ["a"]),
        helper.make_node("Add", ["a", "b"], ["action"]),
    ]
    weights = {"w": w, "b": np.full(n, 0.002, np.float32)}
    policy = OnnxPolicy(linear_onnx(spec, tmp_path / "integrator.onnx", nodes, weights), go2)
    rt, plant = runtime(go2, policy)
    rt.run(60)
    assert (rt.mode == Mode.RUNNING).all()
    running = rt.state.last_action.copy()
    assert (running > 0.02).all()  # the action grows while it drives the robot
    rt.supervision.safe_stop(np.array([True, False]), "operator")
    rt.run(100)  # env 0 stopped, then latched, lying damped
    assert rt.mode[0] in (Mode.SAFE_STOP, Mode.FAULTED)
    np.testing.assert_array_equal(rt.state.last_action[0], 0.0)
    assert (rt.state.last_action[1] > running[1]).all()  # env 1 runs on
    first = np.array([True, False])
    plant.reset(envs=first)  # the operator stands it up at home and restarts it there
    rt.restart(first, np.broadcast_to(go2.home, rt.state.q.shape), plant.read().time)
    np.testing.assert_array_equal(rt.state.last_action[0], 0.0)
    rt.run(50)
    assert rt.mode[0] == Mode.RUNNING
    assert 0 < rt.state.last_action[0].max() < running[0].min() + 0.1
