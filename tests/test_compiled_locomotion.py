"""The compiled ticks of the estimation monitor and the velocity-command tracker
(:mod:`sim2real.deploy.monitors.estimation_kernel`, :mod:`sim2real.deploy.tasks.locomotion_kernel`)
count and sum what their numpy references do, bit for bit.

Two rigs run the same Go2 ticks against identical seeded plants: one as it is (the kernels), one
with the monitor and the tracker forced onto numpy (``compiled = False``). Two envs, a push that
lays env 0 down (a runtime fall and a true fall), a NaN action and a stale sensor on env 1 (a
stop of another cause), scheduled commands, or a fixed one under the heading hold. Tolerance:
none.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from sim2real.deploy.backends.sim.faults import Fault, FaultInjector
from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.core.state import BaseState
from sim2real.deploy.monitors import estimation_kernel
from sim2real.deploy.monitors.estimation import EstimationMonitor
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.rig.rig import Rig
from sim2real.deploy.tasks.heading import HeadingHold
from sim2real.deploy.tasks.locomotion import CommandTracker
from tests.runtime_fixtures import assert_same_arrays

TICKS = 900
ENVS = 2
TASKS = {
    "schedule": lambda: {"period": 2.0, "rng": [np.random.default_rng(5 + e) for e in range(ENVS)]},
    "heading": lambda: {"period": 2.0, "rng": None, "command": "0.5,0,0", "heading_gain": 0.5},
}


def build(robot, onnx, task: dict, compiled: bool) -> Rig:
    dt = robot.control_period
    plant = SimBackend(robot, envs=ENVS, seed=3)
    faults = [
        Fault("push", 150 * dt, 15 * dt, envs=(0,), magnitude=800.0),
        Fault("nan-action", 400 * dt, 5 * dt, envs=(1,)),
        Fault("stale", 600 * dt, 30 * dt, envs=(1,)),
    ]
    runtime = {"injector": FaultInjector(faults, plant)}
    rig = Rig(robot, OnnxPolicy(onnx, robot), plant, envs=ENVS, task=task, runtime=runtime)
    rig.estimation.compiled = compiled
    rig.task.tracker.compiled = compiled
    if rig.task.heading is not None:
        rig.task.heading.compiled = compiled
    rig.runtime.base_tick.compiled = compiled
    rig.start()
    return rig


def results(rig: Rig) -> dict:
    out = {f"estimation/{k}": v for k, v in rig.estimation.state_dict().items()}
    tracker = rig.task.tracker
    out |= {f"tracker/{k}": v for k, v in tracker.state_dict().items()}
    base = tracker.kernel_arrays()["true_base"]
    for name in ("orientation", "projected_gravity", "linear_velocity", "linear_velocity_world"):
        out[f"true_base/{name}"] = getattr(base, name)
    out["command"] = rig.runtime.velocity_command
    rt = rig.runtime
    out |= {"mode": rt.mode, "cause": rt.cause, "foot_contact": rt.state.foot_contact}
    out |= {"clock": rt.state.clock, "signals": rt.fall_detector.signals}
    out |= {f"fall/{k}": v for k, v in rt.fall_detector.state_dict().items()}
    out |= {f"faults/{k}": np.asarray(v) for k, v in rt.counters.faults.items()}
    if rig.task.heading is not None:
        out |= {f"heading/{k}": v for k, v in rig.task.heading.state_dict().items()}
    return out


@pytest.mark.parametrize("task", sorted(TASKS))
def test_compiled_equals_numpy(go2, go2_onnx, monkeypatch, task):
    numpy_ticks = {"estimation": 0, "tracker": 0, "heading": 0}

    def counted(cls, name, key):
        original = getattr(cls, name)

        def wrapper(self, *args, **kwargs):
            numpy_ticks[key] += 1
            return original(self, *args, **kwargs)

        monkeypatch.setattr(cls, name, wrapper)

    counted(EstimationMonitor, "reference_update", "estimation")
    counted(CommandTracker, "reference_call", "tracker")
    counted(HeadingHold, "reference_call", "heading")
    fast = build(go2, go2_onnx, TASKS[task](), compiled=True)
    fast.runtime.run(TICKS, on_tick=fast.monitor)
    assert numpy_ticks == {"estimation": 0, "tracker": 0, "heading": 0}  # the kernels did all
    assert fast.task._call.fits  # the tracker's and the hold's kernels over one table
    slow = build(go2, go2_onnx, TASKS[task](), compiled=False)
    slow.runtime.run(TICKS, on_tick=slow.monitor)
    held = TICKS if task == "heading" else 0
    assert numpy_ticks == {"estimation": TICKS, "tracker": TICKS, "heading": held}
    a, b = results(fast), results(slow)
    assert_same_arrays(a, b)
    assert fast.report()["locomotion"] == slow.report()["locomotion"]
    assert fast.report()["estimation"] == slow.report()["estimation"]
    tracker = fast.task.tracker
    assert tracker.falls[0] >= 1 and tracker.fall_log[0]  # the push laid env 0 down
    assert tracker.falls[1] >= 1  # a stop of another cause
    assert fast.estimation.true_falls[0] >= 1
    assert fast.estimation.ticks > 0 and tracker.heading_change.any()
    faults = fast.runtime.counters.faults  # both compiled screens stopped an env
    assert faults["fall"][0] >= 1 and faults["stale_sensor"][1] >= 1
    assert fast.runtime.base_tick.bound is not None


def test_true_base_is_set_truth():
    """:func:`~sim2real.deploy.monitors.estimation_kernel.true_base` equals ``BaseState.set_truth``
    on this machine in one of its variants (else the kernels are not used: numpy's matmul
    through another BLAS), the one found once per process."""
    variant = estimation_kernel.gemv_variant(4096)
    assert variant in estimation_kernel.VARIANTS
    assert estimation_kernel.gemv_variant() == variant and estimation_kernel.gemv_matches()
    assert estimation_kernel.gemv_fused() == (variant == "fma")


@pytest.mark.parametrize("fused", [True, False])
def test_true_base_variants_round_as_stated(fused):
    """Each variant of ``R^T v``, whatever this machine's BLAS does: ``fused``, one rounding per
    fused multiply-add in the rows' order (exact rational arithmetic rounded once); else the
    three products summed left to right, each rounded."""
    from fractions import Fraction

    from sim2real.deploy.core.attitude import quaternion_to_matrix

    rng = np.random.default_rng(2)
    truth = rng.normal(size=(200, 13))
    truth[:, 3:7] = random_quaternions(rng, 200)
    base = BaseState.zeros(200)
    estimation_kernel._fill(truth, *estimation_kernel.fields(base), fused)
    rot, v = quaternion_to_matrix(truth[:, 3:7]), truth[:, 7:10]

    def fma(a, b, c):
        return float(Fraction(float(a)) * Fraction(float(b)) + Fraction(float(c)))

    for e in range(200):
        r = rot[e]
        for i in range(3):
            if fused:
                want = fma(r[2, i], v[e, 2], fma(r[1, i], v[e, 1], r[0, i] * v[e, 0]))
            else:
                want = (r[0, i] * v[e, 0] + r[1, i] * v[e, 1]) + r[2, i] * v[e, 2]
            assert base.linear_velocity[e, i] == want
    assert np.array_equal(base.orientation, truth[:, 3:7])
    assert np.array_equal(base.projected_gravity, -rot[:, 2])


def random_quaternions(rng, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    q[: n // 2, 0] += 4.0 * rng.random(n // 2)  # about half of them near upright
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_estimation_kernels_equal_numpy_on_random_states(go2):
    """The monitor's kernels against numpy over random truths, estimates, modes and lie-downs:
    any attitude (upside down too), heights about the fall height, estimates that differ."""
    from sim2real.deploy.core.attitude import projected_gravity

    envs, rng = 4, np.random.default_rng(11)
    fast, slow = EstimationMonitor(go2, envs), EstimationMonitor(go2, envs)
    slow.compiled = False
    base = BaseState.zeros(envs)
    runtime = SimpleNamespace(
        mode=np.zeros(envs, dtype=np.int8),
        state=SimpleNamespace(base=base),
        lying_expected=np.zeros(envs, dtype=bool),
    )
    for _ in range(3000):
        truth = np.concatenate(
            [
                rng.normal(size=(envs, 2)),
                fast.fall_height * 2.0 * rng.random((envs, 1)),
                random_quaternions(rng, envs),
                rng.normal(size=(envs, 6)),
            ],
            axis=1,
        )
        runtime.mode[:] = rng.choice([0, 1, 2, 2, 2, 3, 4], size=envs)
        runtime.lying_expected[:] = rng.random(envs) < 0.2
        base.projected_gravity[:] = projected_gravity(random_quaternions(rng, envs))
        base.projected_gravity *= rng.uniform(0.5, 2.0, size=(envs, 1))  # not unit
        base.linear_velocity[:] = rng.normal(size=(envs, 3))
        base.linear_velocity_world[:] = rng.normal(size=(envs, 3))
        fast.update(runtime, truth)
        slow.update(runtime, truth.copy())
    a, b = fast.state_dict(), slow.state_dict()
    for key in a:
        assert np.array_equal(a[key], b[key]), key
    assert fast.summary() == slow.summary()
    assert fast.true_falls.sum() > 10 and fast.ticks > 1000


def test_tracker_kernels_equal_numpy_on_random_states():
    """The tracker's kernels against numpy over random truths, modes, stops of every cause but
    a hard limit, command steps and drifts, and fall-check heights (NaN at times)."""
    from sim2real.deploy.core.modes import FAULT_CAUSES

    envs, dt, rng = 3, 0.02, np.random.default_rng(12)
    causes = [i for i, c in enumerate(FAULT_CAUSES) if c != "hard_limit"] + [-1]
    now = {"truth": np.zeros((envs, 13))}
    backend = SimpleNamespace(true_base_state=lambda: now["truth"].copy())
    fast, slow = CommandTracker(envs, dt, backend), CommandTracker(envs, dt, backend)
    slow.compiled = False
    runtime = SimpleNamespace(
        mode=np.zeros(envs, dtype=np.int8),
        cause=np.full(envs, -1, dtype=np.int8),
        time=0.0,
        ticks=0,
        velocity_command=np.zeros((envs, 3)),
        fall_detector=SimpleNamespace(height=np.zeros(envs), signals=np.zeros((envs, 3), bool)),
        state=SimpleNamespace(base=BaseState.zeros(envs)),
    )
    for _ in range(4000):
        runtime.ticks += 1
        runtime.time += dt
        change = rng.random(envs) < 0.02
        runtime.mode[change] = rng.choice([0, 1, 2, 3, 4], size=int(change.sum()))
        runtime.mode[rng.random(envs) < 0.05] = 2
        runtime.cause[:] = rng.choice(causes, size=envs)
        step = rng.random(envs) < 0.01
        runtime.velocity_command[step] = rng.uniform(-1.0, 1.0, size=(int(step.sum()), 3))
        runtime.velocity_command += rng.normal(scale=0.01, size=(envs, 3))  # a joystick's drift
        heights = rng.uniform(0.1, 0.4, size=envs)
        heights[rng.random(envs) < 0.1] = np.nan
        runtime.fall_detector.height[:] = heights
        runtime.fall_detector.signals[:] = rng.random((envs, 3)) < 0.5
        runtime.state.base.projected_gravity[:] = rng.normal(size=(envs, 3))
        now["truth"] = np.concatenate(
            [rng.normal(size=(envs, 3)), random_quaternions(rng, envs), rng.normal(size=(envs, 6))],
            axis=1,
        )
        fast(runtime)
        slow(runtime)
    a, b = fast.state_dict(), slow.state_dict()
    for key in a:
        x, y = np.asarray(a[key]), np.asarray(b[key])
        nan = x.dtype.kind == "f"
        assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=nan), key
    assert fast.summary(runtime) == slow.summary(runtime)
    assert fast.falls.sum() > 10 and fast.operator_stops.sum() > 0
    assert fast.tracked_time.sum() > 0 and fast.heading_change.any()


def test_heading_kernels_equal_numpy_on_random_states():
    """The heading hold's kernels against numpy over random estimates (any attitude, NaN at
    times), modes and commands with and without a yaw rate: the same commands, references and
    holds, bit for bit."""
    envs, rng = 4, np.random.default_rng(13)
    fast, slow = HeadingHold(envs, gain=0.7, max_rate=0.4), HeadingHold(envs, 0.7, 0.4)
    slow.compiled = False

    def runtime():
        return SimpleNamespace(
            mode=np.zeros(envs, dtype=np.int8),
            velocity_command=np.zeros((envs, 3)),
            state=SimpleNamespace(base=BaseState.zeros(envs)),
        )

    a, b = runtime(), runtime()
    asked = np.zeros((envs, 3))
    held = 0
    for _ in range(3000):
        orientation = random_quaternions(rng, envs)
        orientation[rng.random(envs) < 0.02] = np.nan
        mode = rng.choice([0, 1, 2, 2, 2, 2, 3], size=envs).astype(np.int8)
        asked[:] = rng.normal(size=(envs, 3))
        asked[rng.random(envs) < 0.7, 2] = 0.0
        for r in (a, b):
            r.state.base.orientation[:] = orientation
            r.mode[:] = mode
        fast(a, asked)
        slow(b, asked.copy())
        assert np.array_equal(a.velocity_command, b.velocity_command, equal_nan=True)
        held += int(fast.holding.sum())
    for key, value in fast.state_dict().items():
        assert np.array_equal(value, slow.state_dict()[key], equal_nan=True), key
    assert fast._calls is not None and held > 1000  # the kernels ran, holds taken
