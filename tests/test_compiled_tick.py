"""The compiled tick gives the reference's results: every command, counter and state, bit for bit.

Two runtimes, one with the compiled kernels of ``sim2real.deploy.kernels`` (:class:`Runtime`) and one with
the numpy references of the supervision, action screen, observation, guard and smoother
(:class:`ReferenceRuntime`; the estimator is the compiled one in both), run the same ticks against identical
seeded plants: arm3 and arm6 in position, velocity and torque mode, 2 envs each, ``TICKS`` ticks
per case (10,000 ticks over the six cases). The policy is the adversarial one (uniform random
actions, 2 % NaN) and the plant has its sensor noise and dropouts, the fault injector's dropout,
stale frame, latency spike, NaN burst, push and cable pull, a backend that reports an
over-temperature winding (then cools: the thermal resume), a drive error and a clock that reports
a burst of overruns; latched faults are reset by the operator (``reset_faults``) two ticks later,
so every cause, transition and screen runs; a slow sweep added to the actions drives the joints
into their soft bands and limits (the guard's clamps, holds and governor). Tolerance: none; the kernels keep the references'
operation order (numpy's pairwise row sums included), so equality is exact.
"""

from __future__ import annotations

from dataclasses import replace
from functools import partial

import numpy as np
import pytest

from sim2real.deploy.backends.sim.faults import Fault, FaultInjector
from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.core.latency import LatencyHistogram
from sim2real.deploy.core.state import Kinematics, RobotState
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.runtime import FAULT_CAUSES, Mode, Runtime
from sim2real.deploy.runtime.reference import ReferenceRuntime
from sim2real.deploy.safety.checks import CHECKS
from sim2real.deploy.safety.reference import ReferenceGuard
from sim2real.deploy.smoothing.reference import ReferenceSmoother
from sim2real.deploy.spec.policy_spec import ObservationBlock, PolicySpec, SpecError
from sim2real.deploy.spec.reference import observation_reference
from tests.runtime_fixtures import adversarial_onnx

TICKS = 1667  # per case; 6 cases: 10,002 ticks through each path
ENVS = 2
#: Ticks of the scripted events (each on env 0 or 1, see ScriptedBackend / ScriptedClock).
HOT = (300, 420)  # env 1 reports a winding 5 degC above its maximum, then ambient (cool)
DRIVE_ERROR = 700  # env 0's drive reports an error bit
OVERRUN = (1000, 1002)  # the clock reports 2 overruns that missed 300 periods each
SWEEP_PERIOD = 4.0  # s
#: Fields of the runtime's state that are measurements of wall time, not results.
TIMING = ("latency/", "tick_cost/", "clock/jitter/")


class ScriptedBackend:
    """A SimBackend whose drives report a hot winding and a drive error at scripted ticks."""

    def __init__(self, backend: SimBackend, hot: float):
        self.backend, self.hot = backend, hot
        self.ticks = 0
        self._errors = np.zeros((backend.envs, backend.n_joints), dtype=np.int64)

    def __getattr__(self, name):
        return getattr(self.backend, name)

    def read(self):
        frame = self.backend.read()
        if HOT[0] <= self.ticks < HOT[1]:
            frame.winding_temperature[1, 0] = self.hot
        return frame

    def drive_errors(self):
        self._errors.fill(0)
        if self.ticks == DRIVE_ERROR:
            self._errors[0, -1] = 0x20
        return self._errors

    def advance(self):
        self.backend.advance()
        self.ticks += 1


class SweepingPolicy:
    """Half the adversarial policy's action plus a slow square wave of amplitude 0.7 (period
    ``SWEEP_PERIOD``, joint ``j`` shifted by ``j`` rad): it drives every joint into its soft band
    and against its limits."""

    def __init__(self, policy: OnnxPolicy, dt: float):
        self.policy, self.spec, self.calls, self.dt = policy, policy.spec, 0, dt
        self._phase = np.arange(policy.spec.act_dim, dtype=np.float64)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        raw = self.policy(obs)
        phase = 2.0 * np.pi * self.calls * self.dt / SWEEP_PERIOD + self._phase
        self.calls += 1
        return (0.5 * raw + 0.7 * np.sign(np.sin(phase))).astype(np.float32)


class ScriptedClock:
    """A real-time clock that never waits and reports overruns at scripted ticks."""

    realtime = True
    late_ns = 0

    def __init__(self, period: float):
        self.period, self.overruns, self.missed_periods = period, 0, 0
        self.jitter = LatencyHistogram()
        self.ticks = 0

    def start(self) -> None:
        pass

    def wait(self) -> int:
        self.ticks += 1
        late = OVERRUN[0] <= self.ticks < OVERRUN[1]
        self.overruns += late
        return 300 if late else 0


def build(robot, mode: str, policy_path, runtime: type[Runtime]) -> Runtime:
    dt = robot.control_period
    plant = SimBackend(robot, mode=mode, envs=ENVS, seed=7)
    plant.dropout_probability[:] = 0.05
    backend = ScriptedBackend(plant, robot.motors[0].max_winding_temperature + 5.0)
    faults = [
        Fault("dropout", 150 * dt, 8 * dt, envs=(0,)),
        Fault("stale", 520 * dt, 5 * dt),
        Fault("latency", 600 * dt, 20 * dt, envs=(1,)),
        Fault("nan-action", 800 * dt, 15 * dt, envs=(1,)),
        Fault("push", 1100 * dt, 30 * dt, envs=(0,), magnitude=15.0),
        Fault("cable", 1300 * dt, 200 * dt, envs=(1,), magnitude=8.0),
        Fault("dropout", 1550 * dt, 80 * dt, envs=(1,)),  # long: a stale-sensor stop
    ]
    policy = SweepingPolicy(OnnxPolicy(policy_path, robot), dt)
    rt = runtime(
        robot,
        policy,
        backend,
        clock=ScriptedClock(dt),
        injector=FaultInjector(faults, plant),
    )
    rt.start()
    return rt


def record(rt: Runtime, ticks: int) -> dict[str, np.ndarray]:
    """Run ``ticks`` ticks; per tick the observation, screened action, guarded target, command,
    modes, causes and every counter. Latched faults are reset two ticks after they latch."""
    envs, n = rt.envs, rt.n
    out = {
        "obs": np.zeros((ticks, envs, rt.spec.obs_dim), dtype=np.float32),
        "action": np.zeros((ticks, envs, n), dtype=np.float32),
        "target": np.zeros((ticks, envs, n)),
        "command": np.zeros((ticks, envs, n)),
        "mode": np.zeros((ticks, envs), dtype=np.int8),
        "cause": np.zeros((ticks, envs), dtype=np.int8),
        "guard_counts": np.zeros((ticks, len(CHECKS), envs), dtype=np.int64),
        "faults": np.zeros((ticks, len(FAULT_CAUSES), envs), dtype=np.int64),
        "smoother_counts": np.zeros((ticks, 4, envs), dtype=np.int64),
        "runtime_counts": np.zeros((ticks, 4, envs), dtype=np.int64),
        "effort_scale": np.zeros((ticks, envs, n)),
    }
    faulted_since = np.full(envs, -1)
    sm, c = rt.smoother, rt.counters
    for k in range(ticks):
        rt.tick()
        out["obs"][k] = rt._obs
        out["action"][k] = rt.action
        out["target"][k] = rt.target
        out["command"][k] = rt.command
        out["mode"][k] = rt.mode
        out["cause"][k] = rt.cause
        out["guard_counts"][k] = rt.guard.count_matrix
        out["faults"][k] = [c.faults[f] for f in FAULT_CAUSES]
        out["smoother_counts"][k] = [
            sm.non_finite_targets,
            sm.target_clamps,
            sm.extrema_violations,
            sm.stopping_distance_clamps,
        ]
        out["runtime_counts"][k] = [c.non_finite_actions, c.safe_stops, c.resyncs, c.anchors]
        out["effort_scale"][k] = rt.guard.effort_scale
        faulted = rt.mode == Mode.FAULTED
        faulted_since[~faulted] = -1
        faulted_since[faulted & (faulted_since < 0)] = k
        reset = faulted & (k - faulted_since >= 2)
        if reset.any():
            rt.reset_faults(reset)
    return out


@pytest.mark.parametrize("robot_name", ["arm3", "arm6"])
@pytest.mark.parametrize("mode", ["position", "velocity", "torque"])
def test_compiled_tick_equals_the_reference(tmp_path, request, robot_name, mode):
    robot = request.getfixturevalue(robot_name)
    path = adversarial_onnx(tmp_path, robot, mode, nan_probability=0.02)
    compiled = build(robot, mode, path, Runtime)
    reference = build(robot, mode, path, ReferenceRuntime)
    refs = (ReferenceGuard, ReferenceSmoother)
    assert not isinstance(compiled.guard, refs) and not isinstance(compiled.smoother, refs)
    assert isinstance(reference.guard, ReferenceGuard)
    assert isinstance(reference.smoother, ReferenceSmoother)
    a, b = record(compiled, TICKS), record(reference, TICKS)
    for key in a:
        for k in range(TICKS):  # the first tick that differs, named
            if not np.array_equal(a[key][k], b[key][k], equal_nan=True):
                np.testing.assert_array_equal(a[key][k], b[key][k], err_msg=f"{key}, tick {k}")
    sa, sb = compiled.state_dict(), reference.state_dict()
    assert sa.keys() == sb.keys()
    for key in sa:
        if not key.startswith(TIMING):
            np.testing.assert_array_equal(sa[key], sb[key], err_msg=key)

    # the replay exercised what it is meant to: safe stops of several causes and the states
    # around them, the derating band, non-finite actions, the guard's clamps and holds
    faults = {f: int(compiled.counters.faults[f].sum()) for f in FAULT_CAUSES}
    assert sum(v > 0 for v in faults.values()) >= 2, faults
    assert (a["mode"] == Mode.RUNNING).any() and (a["mode"] == Mode.SAFE_STOP).any()
    assert (a["effort_scale"] < 1.0).any()
    assert int(compiled.counters.non_finite_actions.sum()) > 0
    counts = dict(zip(CHECKS, a["guard_counts"][-1].sum(axis=1), strict=True))
    assert sum(v > 0 for v in counts.values()) >= 2, counts


@pytest.mark.parametrize("robot_name", ["arm3", "arm6"])
def test_compiled_observation_equals_the_reference_for_every_block(request, robot_name):
    """Every block kind (sin/cos, last action and temperatures too, which the default specs do not
    use) at random states: the kernel's observation equals numpy's bit for bit."""
    robot = request.getfixturevalue(robot_name)
    base = PolicySpec.for_robot(robot)
    n = robot.n_joints
    joints = tuple(range(n))
    extra = (
        ObservationBlock(
            "joint_position_sincos", 2 * n, (1.0,) * 2 * n, (0.0,) * 2 * n, 5.0, joints
        ),
        ObservationBlock("last_action", n, (0.5,) * n, (0.1,) * n, 1.5, joints),
        ObservationBlock("winding_temperature", n, (100.0,) * n, (25.0,) * n, 0.8, joints[::-1]),
    )
    spec = replace(base, observation_blocks=base.observation_blocks + extra)
    envs = 5
    rng = np.random.default_rng(3)
    state = RobotState.zeros(envs, n)
    kin = Kinematics(robot)
    out_a = np.zeros((envs, spec.obs_dim), dtype=np.float32)
    out_b = np.zeros_like(out_a)
    clipped = 0
    for _ in range(300):
        state.q[:] = rng.uniform(robot.position_lower, robot.position_upper, (envs, n))
        state.dq[:] = rng.normal(0.0, 3.0, (envs, n))
        state.last_action[:] = rng.uniform(-1.5, 1.5, (envs, n))
        state.winding_temperature[:] = rng.uniform(20.0, 200.0, (envs, n))
        kin.update(state)
        goal = rng.uniform(-1.0, 1.0, (envs, 3))
        spec.observation(state, goal, out=out_a)
        observation_reference(spec, state, goal, out=out_b)
        np.testing.assert_array_equal(out_a, out_b)
        clipped += int((np.abs(out_a) == 0.8).sum())
    assert clipped > 0  # the clip ran


def test_compiled_observation_equals_the_reference_for_the_floating_base_blocks(go2):
    """Every floating-base block kind (base velocities, gravity, command, gait phase with its
    period, foot contact, heading) runs in the kernel, not the reference, and equals numpy's bit
    for bit; a fixed-base state is refused in the kernel's path as in the reference's."""
    n, feet = go2.n_joints, go2.n_feet
    legged = (
        ObservationBlock("base_linear_velocity", 3, (0.5, 0.5, 0.5), (0.0,) * 3, 100.0),
        ObservationBlock("base_angular_velocity", 3, (4.0,) * 3, (0.1, 0.0, -0.1), 100.0),
        ObservationBlock("projected_gravity", 3, (1.0,) * 3, (0.0,) * 3, 0.9),
        ObservationBlock("velocity_command", 3, (0.5, 0.5, 4.0), (0.0,) * 3, 100.0),
        ObservationBlock("gait_phase", 2, (1.0, 1.0), (0.0, 0.0), 100.0, period=0.8),
        ObservationBlock("foot_contact", feet, (1.0,) * feet, (0.0,) * feet, 5.0),
        ObservationBlock("heading_sincos", 2, (1.0, 1.0), (0.0, 0.0), 5.0),
        ObservationBlock("gait_phase", 2, (2.0, 2.0), (0.0, 0.0), 100.0, period=0.37),
    )
    base = PolicySpec.for_robot(go2)
    spec = replace(base, observation_blocks=legged + base.observation_blocks)
    assert spec.plan.compiled  # the kernel runs these blocks
    envs = 4
    rng = np.random.default_rng(5)
    state = RobotState.legged(envs, n, feet)
    out_a = np.zeros((envs, spec.obs_dim), dtype=np.float32)
    out_b = np.zeros_like(out_a)
    goal = np.zeros((envs, 3))
    clipped = 0
    for tick in range(300):
        state.q[:] = rng.uniform(go2.position_lower, go2.position_upper, (envs, n))
        state.dq[:] = rng.normal(0.0, 3.0, (envs, n))
        state.last_action[:] = rng.uniform(-3.0, 3.0, (envs, n))
        b = state.base
        b.linear_velocity[:] = rng.normal(0.0, 1.0, (envs, 3))
        b.angular_velocity[:] = rng.normal(0.0, 2.0, (envs, 3))
        quat = rng.normal(size=(envs, 4))
        b.orientation[:] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
        b.projected_gravity[:] = rng.normal(0.0, 0.7, (envs, 3))
        state.command[:] = rng.uniform(-1.0, 1.0, (envs, 3))
        state.foot_contact[:] = rng.integers(0, 2, (envs, feet))
        state.clock[:] = tick * 0.02 + rng.uniform(0.0, 100.0, envs)
        spec.observation(state, goal, out=out_a)
        observation_reference(spec, state, goal, out=out_b)
        np.testing.assert_array_equal(out_a, out_b)
        clipped += int((np.abs(out_a[:, 6:9]) == np.float32(0.9)).sum())
    assert clipped > 0  # the gravity block's clip ran
    fixed = RobotState.zeros(envs, n)
    for observe in (spec.observation, partial(observation_reference, spec)):
        with pytest.raises(SpecError, match="needs a floating-base robot's state"):
            observe(fixed, np.zeros((envs, 3)))


def test_compiled_gait_clock_that_stops_equals_the_reference_through_stands_and_resets(go2):
    """A gait clock that stops while the command is small (holosoma's two feet, held at pi) gives
    the kernel's numbers bit for bit in numpy's reference across stands, restarts and a policy's
    reset of some envs, and its standing ticks read every foot at the held phase."""
    n, feet = go2.n_joints, go2.n_feet
    stop = {"period": 0.8, "stand_below": 0.01, "stand_phase": np.pi}
    blocks = (
        ObservationBlock("gait_phase", 2, (1.0,) * 2, (0.0,) * 2, 100.0, components=(0, 2), **stop),
        ObservationBlock(
            "gait_phase", 4, (1.0,) * 4, (0.0,) * 4, 100.0, components=(1, 3, 2, 0), **stop
        ),  # fmt: skip
        ObservationBlock("gait_phase", 2, (1.0,) * 2, (0.0,) * 2, 100.0, period=0.8),
    )
    base = PolicySpec.for_robot(go2)
    spec = replace(base, observation_blocks=blocks + base.observation_blocks)
    assert spec.plan.compiled
    envs, rng = 6, np.random.default_rng(7)
    state = RobotState.legged(envs, n, feet)
    out_a = np.zeros((envs, spec.obs_dim), dtype=np.float32)
    out_b, goal, stood = np.zeros_like(out_a), np.zeros((envs, 3)), 0
    for tick in range(400):
        walking = rng.random(envs) < 0.8  # runs of standing ticks and of walking ones
        state.command[:] = np.where(walking[:, None], rng.uniform(-1, 1, (envs, 3)), 0.0)
        state.command[0] = (0.005, 0.005, 0.009) if tick % 50 < 10 else (0.5, 0.0, 0.0)
        state.clock[:] = tick * 0.02
        if tick % 97 == 0:
            spec.plan.reset_history(rng.random(envs) < 0.5)
        spec.observation(state, goal, out=out_a)
        observation_reference(spec, state, goal, out=out_b)
        np.testing.assert_array_equal(out_a, out_b)
        held = ~walking
        held[0] = tick % 50 < 10  # below the threshold: standing
        stood += int(held.sum())
        at_pi = np.float32([-1.0, -1.0, np.sin(np.pi), np.sin(np.pi)])  # cos, cos, sin, sin
        assert np.all(out_a[held, 2:6] == at_pi)
        np.testing.assert_array_equal(out_a[held, 0], out_a[held, 1])
        assert not np.any(out_a[~held, 2] == out_a[~held, 3])  # walking: half a period apart
    assert stood > 100
