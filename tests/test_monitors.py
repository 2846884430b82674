"""The compiled monitors (sim2real/deploy/monitors/kernel.py) count what their numpy references count.

Goals, violations, interventions and motor heat are what a soak report is made of: the kernels
only decide faster whether anything happened on a tick, so every count, record and state must
equal the reference's exactly (no tolerance: the goal distance keeps numpy's operation order).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pinocchio as pin
import pytest

from sim2real.deploy.backends.sim.faults import Fault, FaultInjector
from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.monitors.interventions import InterventionMonitor
from sim2real.deploy.monitors.kernel import temperature_bands
from sim2real.deploy.monitors.reference import (
    ReferenceInterventionMonitor,
    ReferenceViolationMonitor,
)
from sim2real.deploy.monitors.violations import ViolationMonitor
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.runtime import Mode, Runtime
from sim2real.deploy.tasks.goals import GoalScheduler
from sim2real.deploy.tasks.reference import ReferenceGoalScheduler
from tests.runtime_fixtures import adversarial_onnx
from tests.test_compiled_tick import SweepingPolicy


def scripted_run(robot, scheduler: type[GoalScheduler], ticks: int = 6000) -> GoalScheduler:
    """A goal scheduler over 3 envs whose modes and end effectors follow a seeded script: envs
    pause (not RUNNING) at random, and the end effector jumps around the goal."""
    envs, dt = 3, 0.01
    radius = robot.config.task.success_radius
    script = np.random.default_rng(11)
    rt = SimpleNamespace(
        time=0.0,
        mode=np.full(envs, Mode.RUNNING, dtype=np.int8),
        goal=np.zeros((envs, 3)),
        backend=None,  # not a simulated plant: the scheduler judges rt.state
        state=SimpleNamespace(
            ee_position=np.zeros((envs, 3)), q=np.zeros((envs, 2)), dq=np.zeros((envs, 2))
        ),
    )
    goals = scheduler(robot, envs, 1.5, None, 0.8, np.random.default_rng(5), window=10.0)
    for _ in range(ticks):
        rt.time += dt
        rt.mode[:] = np.where(script.random(envs) < 0.003, Mode.SAFE_STOP, Mode.RUNNING)
        if script.random() < 0.002:
            rt.mode[:] = Mode.IDLE  # no env runs
        # within the success radius on ~0.5 % of ticks: about a third of the goals are reached
        rt.state.ee_position[:] = rt.goal + script.normal(0.0, 4.0 * radius, (envs, 3))
        goals(rt)
    return goals


def test_compiled_goal_scheduler_equals_the_reference(arm3):
    a, b = scripted_run(arm3, GoalScheduler), scripted_run(arm3, ReferenceGoalScheduler)
    sa, sb = a.state_dict(), b.state_dict()
    assert sa.keys() == sb.keys()
    for key in sa:
        np.testing.assert_array_equal(sa[key], sb[key], err_msg=key)
    # the script exercised what it is meant to: hits, misses, paused goals
    assert a.hits > 20 and a.goals - a.hits > 20, (a.hits, a.goals)
    assert np.isfinite(a.best_distance).any() and len(a.missed[0]) > 0


@pytest.mark.parametrize("mode", ["position", "velocity", "torque"])
def test_compiled_violation_and_intervention_monitors_equal_the_references(tmp_path, arm6, mode):
    """Both monitors watch the same run of an adversarial policy (random actions on a square wave
    that sweeps the joints into their limits, a push beyond what the servos hold, and a cable
    pull: with the motion envelope the policy alone no longer breaks a limit)."""
    dt = arm6.control_period
    plant = SimBackend(arm6, mode=mode, envs=2, seed=3)
    faults = [
        Fault("push", 100 * dt, 40 * dt, envs=(0,), magnitude=400.0),
        Fault("cable", 300 * dt, 200 * dt, envs=(1,), magnitude=30.0),
    ]
    policy = SweepingPolicy(OnnxPolicy(adversarial_onnx(tmp_path, arm6, mode), arm6), dt)
    rt = Runtime(arm6, policy, plant, injector=FaultInjector(faults, plant))
    rt.start()
    monitors = [
        (violation(arm6, 2), intervention(rt.guard, rt.smoother))
        for violation, intervention in (
            (ViolationMonitor, InterventionMonitor),
            (ReferenceViolationMonitor, ReferenceInterventionMonitor),
        )
    ]
    for _ in range(2500):
        rt.tick()
        for violations, interventions in monitors:
            violations.update(plant)
            interventions.update()
    (va, ia), (vb, ib) = monitors
    for x, y in ((va, vb), (ia, ib)):
        sx, sy = x.state_dict(), y.state_dict()
        assert sx.keys() == sy.keys()
        for key in sx:
            np.testing.assert_array_equal(sx[key], sy[key], err_msg=key)
    assert va.totals()["any"] > 0 and ia.any.sum() > 0, (va.totals(), ia.summary())


class ScriptedTruth:
    """A backend's ground truth drawn at random around the limits, one part at a time."""

    def __init__(self, robot, envs: int, seed: int):
        self.robot, self.rng, self.envs = robot, np.random.default_rng(seed), envs
        n = robot.n_joints
        self.q, self.dq, self.tau = np.zeros((envs, n)), np.zeros((envs, n)), np.zeros((envs, n))
        self.ee = np.zeros((envs, 3))

    def draw(self) -> None:
        r, rng, shape = self.robot, self.rng, self.q.shape
        lo, hi = r.position_lower, r.position_upper
        self.q[:] = rng.uniform(0.7 * lo + 0.3 * hi, 0.3 * lo + 0.7 * hi, shape)  # inside
        self.dq[:] = rng.uniform(-0.5, 0.5, shape) * r.velocity_limit
        self.tau[:] = rng.uniform(-0.5, 0.5, shape) * r.effort_limit
        ws_min, ws_max = (np.array(v) for v in (r.config.safety.workspace_min,
                                                  r.config.safety.workspace_max))  # fmt: skip
        self.ee[:] = rng.uniform(0.6 * ws_min + 0.4 * ws_max, 0.4 * ws_min + 0.6 * ws_max)
        part = rng.integers(5)  # one part (or none) near or past its limit, in one env
        e, j = rng.integers(self.envs), rng.integers(shape[1])
        near = rng.uniform(0.9, 1.1)
        if part == 0:
            self.q[e, j] = lo[j] + (hi[j] - lo[j]) * rng.choice([1 - near, near])
        elif part == 1:
            self.dq[e, j] = rng.choice([-near, near]) * r.velocity_limit[j]
        elif part == 2:
            self.tau[e, j] = rng.choice([-near, near]) * r.effort_limit[j] * 1.05
        elif part == 3:
            i = rng.integers(3)
            self.ee[e, i] = ws_min[i] + (ws_max[i] - ws_min[i]) * rng.choice([1 - near, near])

    def true_position(self):
        return self.q

    def true_velocity(self):
        return self.dq

    def joint_torque(self):
        return self.tau

    def end_effector_position(self, out):
        out[:] = self.ee
        return out


def test_compiled_violation_screen_misses_nothing_the_reference_counts(arm6):
    """States drawn at and around each limit in turn (joint angle, speed, torque, workspace):
    the compiled screen lets through exactly the violations the reference counts."""
    truth = ScriptedTruth(arm6, envs=3, seed=4)
    monitors = [monitor(arm6, 3) for monitor in (ViolationMonitor, ReferenceViolationMonitor)]
    for _ in range(4000):
        truth.draw()
        for m in monitors:
            m.update(truth)
    a, b = (m.state_dict() for m in monitors)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    totals = monitors[0].totals()
    for kind in ("hard_limit", "soft_limit", "velocity", "effort", "workspace"):
        assert totals[kind] > 50, totals


def test_temperature_bands_count_as_numpy_does():
    rng = np.random.default_rng(0)
    start, maximum = np.array([60.0, 70.0, 80.0]), np.array([90.0, 100.0, 110.0])
    peak = np.full((4, 3), 25.0)
    window = peak.copy()
    band = np.zeros((4, 3), dtype=np.int64)
    over = band.copy()
    ref = [peak.copy(), window.copy(), band.copy(), over.copy()]
    for _ in range(500):
        t = rng.uniform(20.0, 130.0, (4, 3))
        t[0, 0] = 60.0  # at the derating start: in the band
        temperature_bands(t, start, maximum, peak, window, band, over)
        np.maximum(ref[0], t, out=ref[0])
        np.maximum(ref[1], t, out=ref[1])
        ref[2] += t >= start
        ref[3] += t > maximum
    for got, want in zip((peak, window, band, over), ref, strict=True):
        np.testing.assert_array_equal(got, want)
    assert band.min() > 0 and over.max() > 0


def test_self_collision_ticks_are_counted_by_the_pair_that_touched(arm6):
    """Drawn poses anywhere within the hard limits (a fifth of them fold arm6 into itself): every
    self-collision tick is put on the pairs coal finds touching, so the pairs' ticks name what
    collided and add up to at least the self-collision ticks; the reference counts the same."""
    from sim2real.deploy.safety.collision import collision_model

    truth = ScriptedTruth(arm6, envs=2, seed=7)
    monitors = [monitor(arm6, 2) for monitor in (ViolationMonitor, ReferenceViolationMonitor)]
    geom_model, geom_data = collision_model(arm6)
    model = arm6.fixed_base_model
    data = model.createData()
    expected = np.zeros((2, len(geom_model.collisionPairs)), dtype=np.int64)
    rng = np.random.default_rng(8)
    for _ in range(300):
        truth.draw()
        truth.q[:] = rng.uniform(arm6.position_lower, arm6.position_upper, truth.q.shape)
        for e in range(2):
            pin.computeCollisions(model, data, geom_model, geom_data, truth.q[e], False)
            expected[e] += [r.isCollision() for r in geom_data.collisionResults]
        for m in monitors:
            m.update(truth)
    for m in monitors:
        np.testing.assert_array_equal(m.pair_ticks, expected)
    ours = monitors[0]
    collided = ours.counts["self_collision"]
    assert collided.sum() > 20
    assert (expected.sum(axis=1) >= collided).all()
    top, ticks = next(iter(ours.pair_counts(0).items()))
    k = ours.pair_names.index(top)
    assert ticks == expected[0].max() == expected[0, k] and "|" in top


def test_violations_of_a_robot_lying_down_are_counted_apart_and_none_is_lost(arm6):
    """Ticks on which an env is down (a legged robot lying damped after a stop) go to
    ``down_counts``, the others to ``counts``: together they are what a monitor told nothing
    counts, type by type, and the pairs' ticks are those of the ticks up; both kinds survive a
    state_dict round trip (the soak's checkpoints)."""
    truth = ScriptedTruth(arm6, envs=2, seed=5)
    split, whole = ViolationMonitor(arm6, 2), ViolationMonitor(arm6, 2)
    rng = np.random.default_rng(9)
    up_only = ViolationMonitor(arm6, 2)
    down_ticks = 0
    for _ in range(3000):
        truth.draw()
        down = np.array([rng.random() < 0.5, False])
        down_ticks += int(down[0])
        split.update(truth, down=down)
        whole.update(truth)
        if not down[0]:
            up_only.update(truth)
    for kind in split.counts:
        np.testing.assert_array_equal(
            split.counts[kind] + split.down_counts[kind], whole.counts[kind], err_msg=kind
        )
        assert split.down_counts[kind][1] == 0  # env 1 was never down
        assert split.counts[kind][0] == up_only.counts[kind][0], kind
    np.testing.assert_array_equal(split.any + split.down_any, whole.any)
    assert split.down_any[0] > 0 and split.totals(down=True)["any"] == split.down_any.sum()
    assert split.env_counts(0, down=True)["hard_limit"] == split.down_counts["hard_limit"][0] > 0
    np.testing.assert_array_equal(split.pair_ticks[0], up_only.pair_ticks[0])
    restored = ViolationMonitor(arm6, 2)
    restored.load_state_dict(split.state_dict())
    for kind in split.counts:
        np.testing.assert_array_equal(restored.down_counts[kind], split.down_counts[kind])
        np.testing.assert_array_equal(restored.counts[kind], split.counts[kind])
    assert 0 < down_ticks < 3000
