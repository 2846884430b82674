"""The parity gate: the ONNX graph, run through :class:`sim2real.deploy.policy.onnx_policy.OnnxPolicy`
exactly as the runtime runs it, against the torch module (max abs error over all action entries;
the tolerance is judged against the network's own float32 noise floor, measured on the same
observations by a float64 copy of the source when it has one, at least ``TOLERANCE`` = 1e-5:
:mod:`sim2real.deploy.export.noise_floor`).

1. :func:`static_parity`: ``PARITY_SAMPLES`` observations uniform in [-1.2, 1.2] per normalized
   entry, plus edge cases (:func:`parity_observations`), in one batch and the first
   ``PARITY_BATCH1`` again one by one (batch 1);
2. :func:`closed_loop_parity`: a replay of ``REPLAY_TICKS`` control ticks on the MuJoCo plant
   (``SimBackend``, ``REPLAY_ENVS`` envs, the spec's control mode), goals from the robot's task
   region every ``GOAL_PERIOD`` s (:func:`sample_goals`), torch and ONNX compared at every tick.

Recurrent policies are compared over sequences with the state carried on both sides: step 1 is
replaced by :func:`sequence_parity` (``SEQUENCE_STEPS`` sequential steps of a bounded random walk
through the normalized observation space, several envs, some of them reset half way, then a
batch-1 run), and the replay of step 2 uses a :class:`RecurrentStepper`. A source that runs
as it is (legged_gym's stateful TorchScript) is also stepped against the ONNX at batch 1
(:func:`source_sequence_parity`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import nn

from sim2real.deploy.backends.sim.height_scan import attach_height_scanner
from sim2real.deploy.backends.sim.plant import (
    NonFiniteCommandError,
    SimBackend,
    SimulationDivergedError,
)
from sim2real.deploy.core.phase_clock import phase_clock_for
from sim2real.deploy.core.state import Kinematics, RobotState
from sim2real.deploy.export.noise_floor import TOLERANCE, NoiseFloor, _max_abs  # noqa: F401 - TOLERANCE
from sim2real.deploy.export.recurrent import RecurrentPolicyModule, RecurrentStepper
from sim2real.deploy.kinds import robot_kind
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.spec.history import per_input_entry
from sim2real.deploy.spec.policy_spec import PolicySpec
from sim2real.deploy.tasks.task import follows_velocity_commands
from sim2real.robots import Robot

PARITY_SAMPLES = 1000
PARITY_BATCH1 = 32
REPLAY_TICKS = 1000
REPLAY_ENVS = 2
GOAL_PERIOD = 2.0  # s between goals in the replay
#: Sequential steps of the sequence parity run (the closed-loop replay adds its own ticks).
SEQUENCE_STEPS = 500
SEQUENCE_ENVS = 4
SEQUENCE_BATCH1_STEPS = 100
#: Per-step standard deviation of the random walk through the normalized observation space.
WALK_SIGMA = 0.15


def _graph(policy: OnnxPolicy, obs: np.ndarray) -> np.ndarray:
    """A copy of the graph's own outputs for ``obs`` (:attr:`OnnxPolicy.graph_action`: the order
    torch gives them in, before a policy over part of the robot is scattered into its joints)."""
    policy(obs)
    return policy.graph_action.copy()


def parity_observations(spec: PolicySpec, samples: int, rng: np.random.Generator) -> np.ndarray:
    """float32 (samples + 7 + 2 obs_dim, obs_dim): uniform in [-1.2, 1.2], then edge cases."""
    d = spec.obs_dim
    clips = per_input_entry(
        spec, np.concatenate([np.full(b.size, b.clip) for b in spec.observation_blocks])
    )
    ones = np.ones(d)
    edges = [np.zeros(d), ones, -ones, 1.2 * ones, -1.2 * ones, clips, -clips]
    rows = [rng.uniform(-1.2, 1.2, (samples, d)), np.stack(edges), np.eye(d), -np.eye(d)]
    return np.concatenate(rows).astype(np.float32)


def sample_goals(robot: Robot, rng: np.random.Generator, envs: int) -> np.ndarray:
    """(envs, 3) m, goals drawn uniformly from the robot's task region (robot.toml ``[task]``)."""
    task = robot.config.task
    if task.region == "planar_annulus":
        r = rng.uniform(*task.radius, envs)
        a = rng.uniform(*task.angle, envs)
        return np.stack([r * np.cos(a), r * np.sin(a), np.zeros(envs)], axis=1)
    return rng.uniform(task.box_min, task.box_max, (envs, 3))


def static_parity(
    policy: OnnxPolicy,
    module: nn.Module,
    spec: PolicySpec,
    samples: int,
    seed: int,
    floor: NoiseFloor | None = None,
) -> tuple[float, int]:
    """Max abs error ONNX vs torch over the parity observations (batch and batch-1 runs);
    ``floor`` (if given) measures the float32 noise floor on the same observations."""
    obs = parity_observations(spec, samples, np.random.default_rng(seed))
    with torch.no_grad():
        ref = module(torch.from_numpy(obs)).numpy()
    if floor is not None:
        floor.stateless(obs, ref)
    err = _max_abs(_graph(policy, obs), ref)
    for i in range(min(PARITY_BATCH1, len(obs))):
        err = max(err, _max_abs(_graph(policy, obs[i : i + 1]), ref[i : i + 1]))
    return err, len(obs)


def closed_loop_parity(
    policy: OnnxPolicy,
    module: nn.Module,
    robot: Robot,
    ticks: int = REPLAY_TICKS,
    envs: int = REPLAY_ENVS,
    seed: int = 0,
    reference=None,
    floor: NoiseFloor | None = None,
) -> dict[str, Any]:
    """Drive the MuJoCo plant with the ONNX policy for ``ticks`` control ticks and compare torch
    and ONNX actions at every tick.

    ``reference(obs) -> action`` (numpy, (envs, act_dim)) replaces ``module`` as the torch side
    when given (a recurrent policy's :class:`RecurrentStepper`,
    which carries the state as the ONNX policy does). ``floor`` (if given) runs the float64 twin
    on the same observations (:mod:`sim2real.deploy.export.noise_floor`).

    Returns:
        ``{"max_abs_error", "ticks", "envs", "mode", "plant_resets"}``.
    """
    spec = policy.spec
    n = robot.n_joints
    plant = SimBackend(robot, mode=spec.action.mode, envs=envs, seed=seed)
    scanner = attach_height_scanner(plant, spec)  # a height_scan block: the plant's ray casts
    kin = Kinematics(robot)
    rng = np.random.default_rng(seed)
    kind = robot_kind(robot)
    state = kind.state(robot, envs)  # the runtime's layout
    # a phase-clocked policy (a motion_phase block) plays its motion on from the first tick
    clock = phase_clock_for(spec, state, robot.control_period)
    walks = follows_velocity_commands(robot)
    if walks:  # a random velocity command per env (the base: the plant's truth, below)
        state.command[:] = rng.uniform([-0.5, -0.3, -1.0], [1.0, 0.3, 1.0], (envs, 3))
        goal = np.zeros((envs, 3))
    else:
        goal = sample_goals(robot, rng, envs)
    goal_every = max(1, int(round(GOAL_PERIOD / robot.control_period)))
    obs = np.zeros((envs, spec.obs_dim), np.float32)
    target = np.zeros((envs, n))
    worst, resets = 0.0, 0
    twin = floor.stepper("replay") if floor is not None and reference is not None else None
    spec.plan.reset_history()  # a frame history starts with the replay
    for tick in range(ticks):
        if tick and tick % goal_every == 0 and not walks:
            goal = sample_goals(robot, rng, envs)
        state.q[:] = plant.true_position()
        state.dq[:] = plant.true_velocity()
        state.winding_temperature[:] = plant.thermal.winding_temperature
        if clock is not None:
            state.motion_time[:] = tick * robot.control_period
        kin.update(state)
        if state.base is not None:
            _true_base(plant, state, tick * robot.control_period)
        if scanner is not None:
            state.height_scan = scanner.true_scan()
        spec.observation(state, goal, out=obs)
        action = policy(obs)
        graph = policy.graph_action  # the graph's own outputs, as torch gives them
        if reference is not None:
            ref = reference(obs)
            if twin is not None:
                twin(obs, ref)
        else:
            with torch.no_grad():
                ref = module(torch.from_numpy(obs)).numpy()
            if floor is not None:
                floor.stateless(obs, ref, "replay")
        worst = max(worst, _max_abs(graph, ref))
        if not np.isfinite(action).all():
            break
        spec.action_to_target(action, state, out=target)
        state.last_action[:] = action
        try:
            plant.write(target)
            plant.advance()
        except (SimulationDivergedError, NonFiniteCommandError):
            plant.reset()
            state.last_action.fill(0.0)
            resets += 1
    return {
        "max_abs_error": worst,
        "ticks": ticks,
        "envs": envs,
        "mode": spec.action.mode,
        "plant_resets": resets,
    }


def _true_base(plant: SimBackend, state: RobotState, t: float) -> None:
    """Fill a legged state's base fields from the plant's truth (parity replays only)."""
    state.base.set_truth(plant.true_base_state())
    state.foot_contact[:] = plant.read().foot_contact
    state.clock[:] = t


def sequence_parity(
    policy,
    module: RecurrentPolicyModule,
    spec: PolicySpec,
    seed: int,
    floor: NoiseFloor | None = None,
) -> tuple[float, float, int]:
    """Max abs error ONNX vs torch over sequences, the state carried on both sides.

    ``SEQUENCE_ENVS`` envs walk ``SEQUENCE_STEPS`` steps through [-1.2, 1.2]^obs_dim (random walk,
    ``WALK_SIGMA`` a step); at the half, envs 0 and 2 are reset on both sides (``policy.reset``);
    then env 0's walk again at batch 1 for ``SEQUENCE_BATCH1_STEPS`` steps. Actions and the final
    states of the first part are compared.

    Args:
        policy: The :class:`sim2real.deploy.policy.onnx_policy.OnnxPolicy` under test. module: The torch
        module. floor: Measures the float32 noise floor of actions and state on the same walk
        (:mod:`sim2real.deploy.export.noise_floor`).

    Returns:
        ``(max abs error of the actions, max abs error of the final state, actions compared)``.
    """
    rng = np.random.default_rng(seed)
    envs, d = SEQUENCE_ENVS, spec.obs_dim
    steps = rng.normal(0.0, WALK_SIGMA, (SEQUENCE_STEPS, envs, d))
    walk = np.clip(np.cumsum(steps, axis=0), -1.2, 1.2).astype(np.float32)
    ref = RecurrentStepper(module)
    twin = floor.stepper() if floor is not None else None
    worst, compared = 0.0, 0
    mask = np.zeros(envs, dtype=bool)
    mask[::2] = True
    policy.reset(np.ones(envs, dtype=bool))
    for t in range(SEQUENCE_STEPS):
        if t == SEQUENCE_STEPS // 2:
            policy.reset(mask)
            ref.reset(mask)
            if twin is not None:
                twin.reset(mask)
        expected = ref(walk[t])
        worst = max(worst, _max_abs(_graph(policy, walk[t]), expected))
        if twin is not None:
            twin(walk[t], expected)
        compared += envs
    state_err = 0.0
    for s, t in zip(policy.states, ref.state, strict=True):
        state_err = max(state_err, _max_abs(policy.state_dict()[s.input], t.numpy()))
    if twin is not None:
        twin.compare_states()
    policy.reset(np.ones(1, dtype=bool))
    for t in range(SEQUENCE_BATCH1_STEPS):
        expected = ref(walk[t, :1])
        worst = max(worst, _max_abs(_graph(policy, walk[t, :1]), expected))
        if twin is not None:
            twin(walk[t, :1], expected)
        compared += 1
    return worst, state_err, compared


def source_sequence_parity(
    policy, reference, spec: PolicySpec, seed: int, floor: NoiseFloor | None = None
) -> tuple[float, int]:
    """Max abs error ONNX vs the source itself, stepped at batch 1 with its own state.

    For sources whose original form can be run (a stateful TorchScript file,
    :class:`sim2real.deploy.export.torchscript_lstm.StatefulScriptReference`): ``SEQUENCE_STEPS`` steps of
    one env's random walk (as :func:`sequence_parity`, ``seed + 1``), both sides reset at the
    half (``reference.reset()``, ``policy.reset``).

    Args:
        policy: The :class:`sim2real.deploy.policy.onnx_policy.OnnxPolicy` under test. reference:
            ``ref(obs)`` -> action (1, act_dim), clip applied, with ``reset()``.
        spec: The PolicySpec. floor: Measures the float32 noise floor on the same walk (the
            rebuilt module in float32 and float64, not the source file).

    Returns:
        ``(max_abs_error, actions compared)``.
    """
    rng = np.random.default_rng(seed + 1)
    steps = rng.normal(0.0, WALK_SIGMA, (SEQUENCE_STEPS, 1, spec.obs_dim))
    walk = np.clip(np.cumsum(steps, axis=0), -1.2, 1.2).astype(np.float32)
    twin = floor.stepper() if floor is not None else None
    one = np.ones(1, dtype=bool)
    policy.reset(one)
    reference.reset()
    worst = 0.0
    for t in range(SEQUENCE_STEPS):
        if t == SEQUENCE_STEPS // 2:
            policy.reset(one)
            reference.reset()
            if twin is not None:
                twin.reset()
        worst = max(worst, _max_abs(_graph(policy, walk[t]), reference(walk[t])))
        if twin is not None:
            twin(walk[t])
    return worst, SEQUENCE_STEPS
