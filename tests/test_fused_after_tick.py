"""The rig's after-tick work as one compiled call (:class:`sim2real.deploy.rig.after_tick.
FusedAfterTick`) counts, issues, records and measures what the separate calls of the monitors,
the goal scheduler and the motion hook do, bit for bit.

Two rigs run the same ticks against identical seeded plants: one as it is (a simulated fixed
base: the fused call), one whose after-tick work is the separate calls (:class:`SeparateRig`).
The policy is the adversarial one on a sweep into the joints' limits, with a push and a cable
pull (violations, interventions, the collision screen's coal checks), goals every second with a
wide success radius (goals issued, reached and missed), and, half-way, one env given its model
again (a new MjData: the call's table is built again); the soak's call (:meth:`Rig.monitor`
alone) too. A legged robot (two Go2s, one pushed down, one stopped by a stale sensor) under the
velocity task: the same. Tolerance: none.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from sim2real.deploy.backends.sim.faults import Fault, FaultInjector
from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.rig.after_tick import FusedAfterTick
from sim2real.deploy.rig.after_tick_kernel import monotonic_ns
from sim2real.deploy.rig.rig import MotionHook, Rig
from tests.runtime_fixtures import adversarial_onnx, assert_same_arrays
from tests.test_compiled_tick import SweepingPolicy

TICKS = 1500
#: The tick at which env 0 is given its model again (a new MjData).
NEW_MODEL = 700
#: Fields of a report that are measurements of wall time, not results.
TIMING = ("wall_s", "monitor_cost_us", "hook_cost_us")


class SeparateRig(Rig):
    """A rig whose monitors, task and motion hook run as separate calls."""

    def _fused_call(self, runtime):
        return None


def build(robot, mode: str, onnx, rig_type: type[Rig], envs: int) -> Rig:
    dt = robot.control_period
    plant = SimBackend(robot, mode=mode, envs=envs, seed=3)
    faults = [
        Fault("push", 100 * dt, 40 * dt, envs=(0,), magnitude=400.0),
        Fault("cable", 300 * dt, 200 * dt, envs=(envs - 1,), magnitude=30.0),
    ]
    policy = SweepingPolicy(OnnxPolicy(onnx, robot), dt)
    task = {"period": 1.0, "rng": np.random.default_rng(5), "success_time": 0.8}
    runtime = {"injector": FaultInjector(faults, plant)}
    rig = rig_type(robot, policy, plant, envs=envs, task=task, runtime=runtime)
    rig.add(MotionHook(rig))
    rig.task.scheduler.success_radius = 0.15  # goals reached now and then
    rig.start()
    return rig


def run(rig: Rig, monitor_only: bool = False) -> Rig:
    """``TICKS`` ticks, each followed by the rig's after-tick work (or, ``monitor_only``, by
    :meth:`Rig.monitor` alone: the soak's call)."""
    on_tick = rig.monitor if monitor_only else rig.after_tick
    rig.runtime.run(NEW_MODEL, on_tick=on_tick)
    rig.backend.set_model(0, rig.backend.models[0])
    rig.runtime.run(TICKS - NEW_MODEL, on_tick=on_tick)
    return rig


def results(rig: Rig) -> dict:
    out = {f"violations/{k}": v for k, v in rig.violations.state_dict().items()}
    out |= {f"interventions/{k}": v for k, v in rig.interventions.state_dict().items()}
    out |= {f"goals/{k}": v for k, v in rig.task.scheduler.state_dict().items()}
    hook = rig.hooks[0]
    for name in ("peak", "max_speed", "dq", "acc", "jerk_sum", "jerk_ticks"):
        out[f"motion/{name}"] = getattr(hook, name)
    out["samples"] = np.array(
        [rig.monitor_cost.counts.sum(), *rig.hook_cost.counts.sum(axis=1)], dtype=np.int64
    )
    out["true_q"] = rig.backend.true_position()
    return out


@pytest.mark.parametrize(
    "robot_name,envs,monitor_only", [("arm3", 1, False), ("arm6", 2, False), ("arm6", 2, True)]
)
@pytest.mark.parametrize("mode", ["position", "velocity"])
def test_the_fused_call_equals_the_separate_calls(
    tmp_path, request, robot_name, envs, monitor_only, mode
):
    robot = request.getfixturevalue(robot_name)
    onnx = adversarial_onnx(tmp_path, robot, mode)
    fused, separate = (
        run(build(robot, mode, onnx, t, envs), monitor_only) for t in (Rig, SeparateRig)
    )
    assert isinstance(fused._fused, FusedAfterTick) and fused._fused.motion
    assert fused._fused.ready(fused.runtime)  # built again over env 0's new data
    a, b = results(fused), results(separate)
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    ra, rb = fused.report(), separate.report()
    for key in TIMING:
        ra.pop(key, None), rb.pop(key, None)
    assert ra == rb
    assert fused.monitor_cost.counts.sum() == fused.interventions.ticks == TICKS
    # the run exercised what it is meant to
    s = fused.task.scheduler
    assert s.hits > 0 and s.goals - s.hits > 0, (s.hits, s.goals)
    assert fused.violations.totals()["any"] > 0
    assert fused.interventions.any.sum() > 0, fused.interventions.summary()


def test_the_kernels_clock_is_perf_counter_ns():
    """The call times the monitors from a stamp of ``time.perf_counter_ns`` to its own clock's:
    both must be the same clock."""
    scratch = np.zeros(2, dtype=np.int64)
    for _ in range(100):
        before = time.perf_counter_ns()
        now = monotonic_ns(scratch)
        after = time.perf_counter_ns()
        assert before <= now <= after


def build_legged(robot, onnx, rig_type: type[Rig], task: dict) -> Rig:
    """Two Go2s: a push that lays env 0 down (its ticks lying damped counted apart), a stale
    sensor that stops env 1, the velocity task and the motion hook."""
    dt = robot.control_period
    plant = SimBackend(robot, envs=2, seed=3)
    faults = [
        Fault("push", 150 * dt, 15 * dt, envs=(0,), magnitude=600.0),
        Fault("stale", 500 * dt, 30 * dt, envs=(1,)),
    ]
    runtime = {"injector": FaultInjector(faults, plant)}
    rig = rig_type(robot, OnnxPolicy(onnx, robot), plant, envs=2, task=task, runtime=runtime)
    rig.add(MotionHook(rig))
    rig.start()
    return rig


def legged_results(rig: Rig) -> dict:
    out = {f"violations/{k}": v for k, v in rig.violations.state_dict().items()}
    out |= {f"interventions/{k}": v for k, v in rig.interventions.state_dict().items()}
    out |= {f"estimation/{k}": v for k, v in rig.estimation.state_dict().items()}
    out |= {f"task/{k}": v for k, v in rig.task.state_dict().items()}
    hook = rig.hooks[0]
    for name in ("peak", "max_speed", "dq", "acc", "jerk_sum", "jerk_ticks"):
        out[f"motion/{name}"] = getattr(hook, name)
    out["samples"] = np.array(
        [rig.monitor_cost.counts.sum(), *rig.hook_cost.counts.sum(axis=1)], dtype=np.int64
    )
    out |= {"command": rig.runtime.velocity_command, "mode": rig.runtime.mode}
    return out


@pytest.mark.parametrize("monitor_only", [False, True])
@pytest.mark.parametrize("heading", [True, False])
def test_a_legged_robots_fused_call_equals_the_separate_calls(go2, go2_onnx, heading, monitor_only):
    """A legged robot: the call screens the violations (the envs lying down apart), the
    interventions and the motion figures; the estimation monitor and the velocity task follow
    in Python. Scheduled commands, or a fixed one under the heading hold."""
    ticks = 900

    def task():
        if heading:
            return {"period": 2.0, "rng": None, "command": "0.5,0,0", "heading_gain": 0.5}
        return {"period": 2.0, "rng": [np.random.default_rng(5 + e) for e in range(2)]}

    rigs = [build_legged(go2, go2_onnx, t, task()) for t in (Rig, SeparateRig)]
    for rig in rigs:
        rig.runtime.run(ticks, on_tick=rig.monitor if monitor_only else rig.after_tick)
    fused, separate = rigs
    assert isinstance(fused._fused, FusedAfterTick) and fused._fused.motion
    a, b = legged_results(fused), legged_results(separate)
    assert_same_arrays(a, b)
    ra, rb = fused.report(), separate.report()
    for key in TIMING:
        ra.pop(key, None), rb.pop(key, None)
    assert ra == rb
    assert fused.monitor_cost.counts.sum() == fused.interventions.ticks == ticks
    # the run exercised what it is meant to: env 0 lay down, its ticks down counted apart
    assert fused.task.tracker.falls[0] >= 1
    assert sum(fused.violations.totals(down=True).values()) > 0
