"""A PD-target policy's targets reach its drives as it was trained (``action.smoothing``).

A policy trained in legged_gym, Isaac Lab or mjlab stepped its PD targets from one control period
to the next with nothing between them and the drives: each target is a torque request. Its spec
says ``'none'`` (or leaves it to the robot's default, which is ``'none'`` for a PD-target robot),
and the runtime's RUNNING envs command the guard's target itself. The toolkit's own legged
policies were trained through the runtime's Ruckig stage; their spec says ``'jerk_limited'``.
Built on unitree_rl_gym's H1 (its own deploy.yaml and exported network in tests/data) and rl_sar's
Go2-W contract (wheels on speed targets).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.kinds import ARM
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.runtime import Mode, Runtime
from sim2real.deploy.spec.policy_spec import PolicySpec, SpecError
from sim2real.robots import load_robot

H1 = "tests/data/unitree_rl_gym/h1/h1.onnx"


@pytest.fixture(scope="module")
def h1():
    return load_robot("h1")


def walk(robot, policy, seconds):
    """The RUNNING ticks' (command, target) of ``seconds`` of walking at 0.5 m/s."""
    plant = SimBackend(robot, "position", envs=1, seed=0)
    rt = Runtime(robot, policy, plant)
    rt.velocity_command[0] = [0.5, 0.0, 0.0]
    rt.start()
    pairs = []
    for _ in range(round(seconds / rt.dt)):
        rt.tick()
        if rt.mode[0] == Mode.RUNNING:
            pairs.append((rt.command[0].copy(), rt.target[0].copy()))
    assert pairs, "the policy never ran"
    return rt, pairs


@pytest.mark.parametrize("smoothing", ["", "none", "jerk_limited"])
def test_a_pd_target_policy_commands_its_targets_as_it_was_trained(h1, smoothing):
    """unitree_rl_gym's H1 walking: with its spec's smoothing left out or 'none' every RUNNING
    tick commands the guard's target itself; through the smoother ('jerk_limited', how the
    toolkit's own policies train) the command lags its stepping targets."""
    policy = OnnxPolicy(H1, h1)
    policy.spec = replace(policy.spec, action=replace(policy.spec.action, smoothing=smoothing))
    rt, pairs = walk(h1, policy, 2.0)
    gaps = np.array([np.abs(c - t).max() for c, t in pairs])
    assert rt.follows_targets == (smoothing != "jerk_limited")
    if rt.follows_targets:
        assert gaps.max() == 0.0
    else:
        assert gaps.max() > 0.05, gaps.max()


def test_smoothing_none_is_refused_on_a_robot_without_pd_targets(arm3):
    spec = PolicySpec.for_robot(arm3, mode="position")
    none = replace(spec, action=replace(spec.action, smoothing="none"))
    from sim2real.deploy.runtime.handover import check_policy

    check_policy(spec, arm3, "position", ARM.targets(arm3))
    with pytest.raises(ValueError, match="smoothing 'none'.*does not run PD targets"):
        check_policy(none, arm3, "position", ARM.targets(arm3))
    velocity = PolicySpec.for_robot(arm3, mode="velocity")
    bad = replace(velocity, action=replace(velocity.action, smoothing="none"))
    with pytest.raises(SpecError, match="action.smoothing"):
        bad.validate()


def test_the_spec_round_trips_its_smoothing_and_the_toolkits_legged_specs_say_jerk_limited(h1):
    ours = PolicySpec.for_robot(h1)
    assert ours.action.smoothing == "jerk_limited"
    assert PolicySpec.from_json(ours.to_json()).action.smoothing == "jerk_limited"
    default = replace(ours, action=replace(ours.action, smoothing=""))
    assert "smoothing" not in default.to_json()  # what earlier versions wrote
    assert PolicySpec.from_json(default.to_json()).action.smoothing == ""


def test_a_wheel_speed_target_past_its_soft_limit_passes_when_the_policy_was_trained_so():
    """A Go2-W policy's wheel speed target is a torque request (``kd (v_target - dq)``, kp 0):
    rl_sar's loop sends it as the policy emits it. The smoother clamps it to the soft velocity
    limit only for a policy trained through it; a following env's target passes, no clamp
    counted."""
    from sim2real.deploy.smoothing.smoother import CommandSmoother
    from sim2real.robots.drive import with_drive

    go2w = load_robot("go2w")
    wheels = np.array(["wheel" in n for n in go2w.joint_names])  # rl_sar's kp 0, kd 0.5
    kinds = tuple("velocity" if w else "position" for w in wheels)
    robot = with_drive(go2w, kp=np.where(wheels, 0.0, 20.0), kd=np.full(16, 0.5), kinds=kinds)
    wheel = int(np.flatnonzero(robot.velocity_driven)[0])
    limit = robot.soft_velocity_limit[wheel]
    smoother = CommandSmoother(robot, 2, "position", bounded=False)
    q = np.tile(robot.home, (2, 1))
    smoother.reset(q, np.zeros_like(q))
    target = q.copy()
    target[:, wheel] = 1.5 * limit
    smoother.follow_envs[:] = [True, False]
    cmd = smoother.step(target, out=np.empty_like(target))
    smoother.follow(target, smoother.follow_envs, cmd)
    assert cmd[0, wheel] == 1.5 * limit and cmd[1, wheel] == pytest.approx(limit)
    assert smoother.target_clamps_per_joint[:, wheel].tolist() == [0, 1]
    assert np.array_equal(cmd[0], target[0])
