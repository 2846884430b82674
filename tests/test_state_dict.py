"""Explicit state: every stateful stage's ``state_dict`` / ``load_state_dict`` (sim2real.deploy.core.stateful).

For each stage: run N ticks, take its state, run M more ticks recording its outputs, load the
state into a freshly built instance and replay the same M ticks: every output is equal bit for
bit. A fresh instance without the state gives other outputs (the state is what matters). And
sim2real/eval/ reads or writes no private attribute of another object (the soak's checkpoint goes
through the state dicts only).
"""

from __future__ import annotations

import io
import tokenize
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from sim2real.deploy.backends.sim.faults import Fault, FaultInjector
from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.core.backend import SensorFrame
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.core.stateful import StateDictError, load_part, prefixed, put, take
from sim2real.deploy.estimation.joints import JointStateEstimator
from sim2real.deploy.estimation.reference import ReferenceJointStateEstimator
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.runtime import Runtime
from sim2real.deploy.safety.guard import SafetyGuard
from sim2real.deploy.smoothing import CommandSmoother
from sim2real.deploy.spec.policy_spec import PolicySpec
from sim2real.deploy.tasks.goals import GoalScheduler
from tests.runtime_fixtures import feedback_mlp_onnx

REPO = Path(__file__).resolve().parent.parent
ENVS = 2
N, M = 60, 60  # ticks before the state is taken, ticks replayed


class Rig:
    """Stages run together (one's output another's input), composed into one state dict."""

    def __init__(self, step, **parts):
        self.step, self.parts = step, parts

    def state_dict(self, env=None):
        out = {}
        for name, part in self.parts.items():
            out.update(prefixed(name, part.state_dict(env)))
        return out

    def load_state_dict(self, state, env=None):
        for name, part in self.parts.items():
            load_part(name, part, state, env)


class Arrays:
    """Plain arrays with a leading env axis as a stage (the inputs a rig keeps between ticks)."""

    def __init__(self, **fields):
        self.fields = fields

    def state_dict(self, env=None):
        return take(self.fields, env)

    def load_state_dict(self, state, env=None):
        put(self.fields, state, env)


def replay(build, per_env: bool = False):
    """Run ``build()``'s rig N ticks, take its state, record M ticks; load the state into a fresh
    rig (env by env with ``per_env``) and replay them. Returns (recorded, replayed, unloaded):
    the outputs of the source, of the loaded rig and of a fresh rig without the state."""
    a = build()
    for k in range(N):
        a.step(k)
    states = [a.state_dict(e) for e in range(ENVS)] if per_env else [a.state_dict()]
    recorded = [a.step(k) for k in range(N, N + M)]
    b = build()
    for e, state in enumerate(states):
        b.load_state_dict(state, e if per_env else None)
    replayed = [b.step(k) for k in range(N, N + M)]
    c = build()
    unloaded = [c.step(k) for k in range(N, N + M)]
    return recorded, replayed, unloaded


def assert_bit_identical(recorded, replayed):
    for k, (x, y) in enumerate(zip(recorded, replayed, strict=True)):
        for i, (u, v) in enumerate(zip(x, y, strict=True)):
            np.testing.assert_array_equal(u, v, err_msg=f"tick {N + k}, output {i}")


def differs(recorded, other) -> bool:
    return any(
        not np.array_equal(u, v, equal_nan=True)
        for x, y in zip(recorded, other, strict=True)
        for u, v in zip(x, y, strict=True)
    )


def moves(recorded) -> bool:
    """The outputs change over the replayed ticks (a replay of a constant proves nothing)."""
    return any(not np.array_equal(recorded[0][0], x[0], equal_nan=True) for x in recorded[1:])


# ---------------------------------------------------------------- inputs
def sim_frames(robot, ticks: int, seed: int = 1):
    """Sensor frames of a moving, noisy, lossy plant (velocity mode), and the true velocities."""
    plant = SimBackend(robot, mode="velocity", envs=ENVS, seed=seed)
    plant.dropout_probability[:] = 0.2
    frames, t = [], np.arange(ticks) * robot.control_period
    for k in range(ticks):
        plant.write(0.8 * np.sin(3.0 * t[k] + np.arange(ENVS)[:, None]) * np.ones(robot.n_joints))
        plant.advance()
        f = plant.read()
        frames.append(SensorFrame(**{k: np.copy(v) for k, v in vars(f).items()}))
    return frames


def mode_targets(robot, mode: str, ticks: int, seed: int, hold: int = 1) -> np.ndarray:
    """(ticks, envs, n) random targets in the units of ``mode``, each held ``hold`` ticks,
    reaching beyond the limits (clamps, holds) and with a few NaN."""
    rng = np.random.default_rng(seed)
    n = robot.n_joints
    if mode == "position":
        centre = 0.5 * (robot.position_lower + robot.position_upper)
        half = 0.5 * (robot.position_upper - robot.position_lower)
        x = centre + 1.1 * half * rng.uniform(-1, 1, (ticks, ENVS, n))
    elif mode == "velocity":
        x = 1.2 * robot.velocity_limit * rng.uniform(-1, 1, (ticks, ENVS, n))
    else:
        x = 1.2 * robot.effort_limit * rng.uniform(-1, 1, (ticks, ENVS, n))
    x = np.repeat(x[::hold], hold, axis=0)[:ticks]
    x[rng.random(x.shape) < 0.01] = np.nan
    return x


# ---------------------------------------------------------------- the stages
def estimator_rig(robot, estimator: type[JointStateEstimator]):
    frames = sim_frames(robot, N + M)
    acc = np.random.default_rng(2).normal(0.0, 5.0, (N + M, ENVS, robot.n_joints))

    def build():
        est = estimator(robot, ENVS)
        est.reset(robot.home, 0.0)

        def step(k):
            state = RobotState.zeros(ENVS, robot.n_joints)
            est.update(frames[k], state, acc[k])
            return state.q, state.dq, est.covariance.copy(), est.stale_per_joint.copy()

        return Rig(step, estimator=est)

    return build


def guard_rig(robot, mode: str):
    rng = np.random.default_rng(3)
    n, ticks = robot.n_joints, N + M
    span = robot.position_upper - robot.position_lower
    q = robot.position_lower + span * rng.uniform(-0.02, 1.02, (ticks, ENVS, n))
    dq = robot.velocity_limit * rng.uniform(-1, 1, (ticks, ENVS, n))
    temperature = np.linspace(25.0, 140.0, ticks)[:, None, None] * np.ones((ENVS, n))
    targets = np.nan_to_num(mode_targets(robot, mode, ticks, 4))

    def build():
        guard = SafetyGuard(robot, ENVS, mode)
        guard.reset(np.tile(robot.home, (ENVS, 1)))

        def step(k):
            state = RobotState.zeros(ENVS, n)
            state.q[:], state.dq[:] = q[k], dq[k]
            guard.update_thermal(temperature[k])
            out = guard.filter(targets[k].copy(), state)
            return out, guard.count_matrix.copy(), guard.hard_violation.copy()

        return Rig(step, guard=guard)

    return build


def smoother_rig(robot, mode: str):
    # targets held 40 ticks (the snapshot 20 ticks into a hold): between changes Ruckig samples
    # the trajectory it keeps, which a recalculation matches to ~1e-16 only (state_dict's care)
    targets = mode_targets(robot, mode, N + M, 5, hold=40)

    def build():
        sm = CommandSmoother(robot, ENVS, mode)
        sm.reset(np.tile(robot.home, (ENVS, 1)), np.zeros((ENVS, robot.n_joints)))

        def step(k):
            if k == N - 5:
                sm.safe_stop(np.array([False, True]))  # env 1 brakes across the snapshot
            cmd = sm.step(targets[k]).copy()
            return cmd, sm.acceleration.copy(), sm.target_clamps_per_joint.copy()

        return Rig(step, smoother=sm)

    return build


def sim_rig(robot, mode: str, streams: bool):
    def build():
        plant = SimBackend(robot, mode=mode, envs=ENVS, seed=7)
        if streams:
            plant.set_sensor_streams([np.random.default_rng(10 + e) for e in range(ENVS)])
            plant.reset()
        plant.dropout_probability[:] = 0.1
        plant.latency_ticks[:] = [1, 3]
        dt = robot.control_period

        def step(k):
            if k == N - 10:
                plant.set_external_force(0, np.array([15.0, 0.0, 0.0]))  # on across the snapshot
            wave = 0.5 * np.sin(2.0 * k * dt + np.arange(ENVS))[:, None] * np.ones(robot.n_joints)
            plant.write(robot.home + wave if mode == "position" else wave)
            plant.advance()
            f = plant.read()
            return (
                f.position.copy(),
                f.position_stamp.copy(),
                plant.true_position().copy(),
                plant.true_velocity().copy(),
                plant.joint_torque().copy(),
                plant.thermal.winding_temperature.copy(),
            )

        return Rig(step, backend=plant)

    return build


def injector_rig(robot):
    dt = robot.control_period
    faults = [
        Fault("stale", (N - 5) * dt, 12 * dt, envs=(1,)),  # a frozen frame across the snapshot
        Fault("dropout", (N - 3) * dt, 10 * dt),
        Fault("latency", (N + 5) * dt, 10 * dt),
        Fault("nan-action", (N + 2) * dt, 5 * dt, envs=(0,)),
        Fault("cable", (N - 20) * dt, 40 * dt, magnitude=5.0),
    ]

    def build():
        plant = SimBackend(robot, mode="position", envs=ENVS, seed=8)
        injector = FaultInjector(faults, plant)

        def step(k):
            t = k * dt
            injector.before_read(t)
            frame = injector.filter_frame(t, plant.read())
            action = injector.filter_action(t, np.ones((ENVS, robot.n_joints)))
            plant.write(np.tile(robot.home, (ENVS, 1)))
            plant.advance()
            return (
                frame.position.copy(),
                frame.position_stamp.copy(),
                action,
                plant.latency_ticks.copy(),
                plant.true_position().copy(),
                np.array([len(injector.log)]),
            )

        return Rig(step, injector=injector, backend=plant)

    return build


def goals_rig(robot):
    dt = robot.control_period

    def build():
        plant = SimBackend(robot, mode="position", envs=ENVS, seed=9)
        goals = GoalScheduler(robot, ENVS, 0.1, None, 0.08, np.random.default_rng(11), window=0.2)
        rt = SimpleNamespace(
            time=0.0,
            mode=np.full(ENVS, 2),
            goal=np.zeros((ENVS, 3)),
            backend=plant,
            state=RobotState.zeros(ENVS, robot.n_joints),
        )

        def step(k):
            wave = 0.6 * np.sin(3.0 * k * dt + np.arange(ENVS))[:, None]
            plant.write(robot.home + wave * np.ones(robot.n_joints))
            plant.advance()
            rt.time = (k + 1) * dt
            goals(rt)
            return (
                rt.goal.copy(),
                goals.best_distance.copy(),
                goals.issued.copy(),
                np.array([len(m) for m in goals.missed]),
            )

        return Rig(step, goals=goals, backend=plant, rt=Arrays(goal=rt.goal))

    return build


def tiny_onnx(path: Path, robot, mode: str) -> Path:
    """A deterministic MLP with joint-position feedback (ONNX built with onnx.helper)."""
    spec = PolicySpec.for_robot(robot, mode=mode)
    if mode == "torque":  # gentle torques: the arm stays inside its limits
        spec = replace(spec, action=replace(spec.action, scale=tuple(0.2 * robot.effort_limit)))
    return feedback_mlp_onnx(path, spec, "tiny")


def runtime_rig(robot, mode: str, tmp_path: Path):
    """The runtime (estimator, guard, smoother, policy, plant, fault injector) and a goal
    scheduler, as the soak runs them; short faults around the snapshot are held."""
    policy_file = tiny_onnx(tmp_path / f"tiny_{mode}.onnx", robot, mode)
    dt = robot.control_period
    faults = [
        Fault("stale", (N - 2) * dt, 4 * dt),
        Fault("nan-action", (N + 3) * dt, 3 * dt, envs=(1,)),
        Fault("push", (N - 10) * dt, 30 * dt, envs=(0,), magnitude=8.0),
        Fault("dropout", (N + 20) * dt, 5 * dt),
    ]

    def build():
        plant = SimBackend(robot, mode=mode, envs=ENVS, seed=3)
        plant.set_sensor_streams([np.random.default_rng(20 + e) for e in range(ENVS)])
        plant.reset()
        rt = Runtime(
            robot, OnnxPolicy(policy_file, robot), plant, injector=FaultInjector(faults, plant)
        )
        rt.start()
        goals = GoalScheduler(robot, ENVS, 0.2, None, 0.15, np.random.default_rng(1))

        def step(k):
            rt.tick()
            goals(rt)
            return (
                rt.command.copy(),
                rt.target.copy(),
                rt.mode.copy(),
                rt.estimator.covariance.copy(),
                rt.goal.copy(),
                rt.counters.non_finite_actions.copy(),
                plant.true_position().copy(),
            )

        return Rig(step, runtime=rt, goals=goals)

    return build


MODES = ("position", "velocity", "torque")
#: stage -> (rig builder, its arguments after the robot); runtime rigs take tmp_path too
STAGES = {
    "estimator-compiled": (estimator_rig, (JointStateEstimator,)),
    "estimator-filterpy": (estimator_rig, (ReferenceJointStateEstimator,)),
    **{f"guard-{m}": (guard_rig, (m,)) for m in MODES},
    **{f"smoother-{m}": (smoother_rig, (m,)) for m in MODES},
    "sim-position": (sim_rig, ("position", False)),
    "sim-velocity-per-env-streams": (sim_rig, ("velocity", True)),
    "fault-injector": (injector_rig, ()),
    "goal-scheduler": (goals_rig, ()),
    **{f"runtime-{m}": (runtime_rig, (m,)) for m in MODES},
}


def rig(stage: str, robot, tmp_path: Path):
    """The ``build`` function of ``stage``'s rig."""
    make, args = STAGES[stage]
    return make(robot, *args, tmp_path) if make is runtime_rig else make(robot, *args)


@pytest.mark.parametrize("stage", list(STAGES))
def test_a_loaded_state_replays_bit_for_bit(stage, arm3, tmp_path):
    recorded, replayed, unloaded = replay(rig(stage, arm3, tmp_path))
    assert moves(recorded), "the outputs must change over the replay"
    assert_bit_identical(recorded, replayed)
    assert differs(recorded, unloaded), "a fresh instance without the state must differ"


PER_ENV = [
    "smoother-velocity",
    "sim-velocity-per-env-streams",
    "goal-scheduler",
    "runtime-position",
]


@pytest.mark.parametrize("stage", PER_ENV)
def test_states_of_single_envs_load_env_by_env(stage, arm3, tmp_path):
    """``state_dict(env)`` (env axis of length 1) into ``load_state_dict(state, env)``."""
    recorded, replayed, _ = replay(rig(stage, arm3, tmp_path), per_env=True)
    assert_bit_identical(recorded, replayed)


def test_the_runtime_state_of_arm6_replays_bit_for_bit(arm6, tmp_path):
    recorded, replayed, _ = replay(runtime_rig(arm6, "velocity", tmp_path))
    assert_bit_identical(recorded, replayed)


def test_a_state_that_does_not_fit_is_refused_with_the_field_named(arm3, tmp_path):
    rt_state = rig("runtime-velocity", arm3, tmp_path)().state_dict()
    fresh = rig("runtime-velocity", arm3, tmp_path)()
    bad = dict(rt_state)
    del bad["runtime/estimator/covariance"]
    with pytest.raises(StateDictError, match=r"field 'runtime/estimator/covariance' is missing"):
        fresh.load_state_dict(bad)
    bad = {**rt_state, "runtime/smoother/position": np.zeros((3, arm3.n_joints))}
    with pytest.raises(
        StateDictError, match=r"field 'runtime/smoother/position': expected shape \(2, 3\)"
    ):
        fresh.load_state_dict(bad)
    bad = {**rt_state, "runtime/backend/sensor_rng": '{"bit_generator": "MT19937"}'}
    with pytest.raises(StateDictError, match=r"field 'runtime/backend/sensor_rng'"):
        fresh.load_state_dict(bad)


# ---------------------------------------------------------------- no private access in sim2real/eval/
def private_accesses(source: str) -> list[tuple[int, str]]:
    """``(line, expression)`` of every attribute access ``<x>._<name>`` in Python code (strings
    and comments excluded) whose object is not ``self`` itself."""
    tokens = [
        t
        for t in tokenize.generate_tokens(io.StringIO(source).readline)
        if t.type not in (tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE)
    ]
    found = []
    for i in range(1, len(tokens) - 1):
        before, dot, name = tokens[i - 1], tokens[i], tokens[i + 1]
        if dot.string != "." or name.type != tokenize.NAME:
            continue
        if not (name.string.startswith("_") and name.string[1:2].isalpha()):
            continue
        own = before.type == tokenize.NAME and before.string == "self"
        if own and (i < 2 or tokens[i - 2].string != "."):  # self._x, not obj.self._x
            continue
        found.append((name.start[0], f"{before.string}.{name.string}"))
    return found


def test_the_private_access_check_finds_what_it_must():
    code = "a = rt.smoother._ruckig\nb = self._x\nc = self.backend._rng\nd = '''x._y'''  # e._f\n"
    assert private_accesses(code) == [(1, "smoother._ruckig"), (3, "backend._rng")]


def test_eval_touches_no_private_attribute_of_another_object():
    offenders = [
        f"{path.relative_to(REPO)}:{line}: {expr}"
        for path in sorted((REPO / "sim2real" / "eval").glob("*.py"))
        for line, expr in private_accesses(path.read_text())
    ]
    assert not offenders, "private attributes accessed from sim2real/eval/:\n" + "\n".join(
        offenders
    )
