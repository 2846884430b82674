"""Policies that read a history of frames and the base's Euler angles run from a spec, no wrapper.

Each stack's observation is built here the way its own code builds it (read, not copied):
humanoid-gym's ``scripts/sim2sim.py`` (a deque of ``frame_stack`` single frames, zeros at the
start, the oldest first, Euler angles of the base from its quaternion), Unitree's C++ deployment of
unitree_rl_lab (``deploy/include/isaaclab/manager``: each term's deque of ``history_length``
readings, filled with the first at the reset, clipped then scaled, the oldest first) and rl_sar's
``ObservationBuffer`` (zeros at the start, ``observations_history`` the ticks to read, 0 the
newest, ``time`` or ``term`` priority). The spec's observation must equal theirs tick by tick,
through a reset.
"""

from __future__ import annotations

import json
import math
from collections import deque

import numpy as np
import onnx
import pytest
import torch
from scipy.spatial.transform import Rotation
from torch import nn

from sim2real.deploy.cli.deploy_run import deploy_run_main
from sim2real.deploy.cli.policy_export import main as policy_export_main
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.spec.policy_spec import PolicySpec, SpecError
from sim2real.deploy.spec.reference import observation_reference
from sim2real.robots import load_robot
from tests import foreign_stacks as fs

pytestmark = pytest.mark.usefixtures("one_torch_thread")

#: humanoid-gym's XBot-L (humanoid/envs/custom/humanoid_config.py): frame_stack 15, the gait
#: cycle 0.64 s, obs_scales lin_vel 2, ang_vel 1, dof_pos 1, dof_vel 0.05, quat 1, clip 18.
FRAME_STACK, CYCLE, CLIP = 15, 0.64, 18.0


@pytest.fixture(scope="module")
def h1():
    return load_robot("h1")


def humanoid_gym_spec(h1) -> dict:
    """The spec a user writes for a humanoid-gym policy on h1 (its ``compute_observations``:
    sin and cos of the phase, the command times (2, 2, 1), q - default, dq x 0.05, the actions,
    the base angular velocity, the base Euler angles; ``frame_stack`` frames, oldest first)."""
    home = [float(x) for x in h1.home]
    blocks = [
        {"name": "gait_phase", "period": CYCLE},
        {"name": "velocity_command", "scale": [0.5, 0.5, 1.0]},
        {"name": "joint_position", "offset": home},
        {"name": "joint_velocity", "scale": 20.0},
        {"name": "last_action"},
        {"name": "base_angular_velocity"},
        {"name": "base_euler_angles"},
    ]
    return {
        "format_version": 1,
        "robot": "h1",
        "joint_names": list(h1.joint_names),
        "observation": [{**b, "clip": CLIP} for b in blocks],
        "action": {"mode": "position", "scale": 0.25, "offset": home, "clip": CLIP},
        "control_rate": 1.0 / h1.control_period,
        "history": {"length": FRAME_STACK, "order": "oldest_first", "layout": "per_frame"},
    }


def euler_state(robot, rng, roll_pitch_yaw) -> RobotState:
    """A legged state of ``robot`` with every quantity the blocks read drawn, its base at the
    given roll, pitch, yaw (rad; the quaternion built by scipy, yaw then pitch then roll)."""
    n = robot.n_joints
    state = RobotState.legged(1, n, robot.n_feet)
    state.q[:] = np.asarray(robot.home) + rng.uniform(-0.3, 0.3, (1, n))
    state.dq[:] = rng.uniform(-4, 4, (1, n))
    state.last_action[:] = rng.uniform(-1, 1, (1, n))
    state.command[:] = rng.uniform(-1, 1, (1, 3))
    state.base.angular_velocity[:] = rng.uniform(-2, 2, (1, 3))
    state.base.projected_gravity[:] = rng.uniform(-1, 1, (1, 3))
    roll, pitch, yaw = roll_pitch_yaw
    x, y, z, w = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_quat()
    state.base.orientation[:] = [w, x, y, z]
    return state


class HumanoidGymObservation:
    """humanoid-gym's sim2sim observation: a deque of ``FRAME_STACK`` zero frames, each tick's
    frame appended (the oldest dropped) and the deque concatenated, the oldest first."""

    def __init__(self, home):
        self.home = np.asarray(home)
        self.reset()

    def reset(self) -> None:
        self.frames = deque(np.zeros((1, 41), np.float32) for _ in range(FRAME_STACK))

    def __call__(self, state, clock, euler) -> np.ndarray:
        obs = np.zeros((1, 41), np.float32)
        obs[0, 0] = math.sin(2 * math.pi * clock / CYCLE)
        obs[0, 1] = math.cos(2 * math.pi * clock / CYCLE)
        obs[0, 2:5] = state.command[0] * np.array([2.0, 2.0, 1.0])
        obs[0, 5:15] = (state.q[0] - self.home) * 1.0
        obs[0, 15:25] = state.dq[0] * 0.05
        obs[0, 25:35] = state.last_action[0]
        obs[0, 35:38] = state.base.angular_velocity[0] * 1.0
        obs[0, 38:41] = np.asarray(euler) * 1.0
        obs = np.clip(obs, -CLIP, CLIP)
        self.frames.append(obs)
        self.frames.popleft()
        return np.concatenate(list(self.frames), axis=1)


def test_a_humanoid_gym_frame_stack_with_euler_angles_is_the_stacks_observation(h1):
    """15 frames of 41 entries, the oldest first, zeros before the first, Euler angles of the
    base: the spec's observation equals humanoid-gym's over 40 ticks and again after a reset;
    the numpy reference gives the same numbers bit for bit."""
    spec = PolicySpec.from_json(json.dumps(humanoid_gym_spec(h1)))
    assert (spec.frame_dim, spec.obs_dim) == (41, 41 * FRAME_STACK)
    theirs = HumanoidGymObservation(h1.home)
    rng = np.random.default_rng(3)
    goal = np.zeros((1, 3))
    spec.plan.reset_history()
    for tick in range(40):
        if tick == 25:  # the policy's reset: both histories start again
            spec.plan.reset_history()
            theirs.reset()
        euler = (rng.uniform(-3.1, 3.1), rng.uniform(-1.5, 1.5), rng.uniform(-3.1, 3.1))
        state = euler_state(h1, rng, euler)
        state.clock[:] = 0.02 * tick
        ours = spec.observation(state, goal).copy()
        reference = observation_reference(spec, state, goal)
        np.testing.assert_array_equal(ours, reference)
        expected = theirs(state, 0.02 * tick, euler)
        np.testing.assert_allclose(ours, expected, rtol=2e-7, atol=1e-6, err_msg=f"tick {tick}")
        frames = min(tick % 25 + 1, FRAME_STACK)  # since the reset; the ticks before read 0
        assert not ours[0, : 41 * (FRAME_STACK - frames)].any()
        assert np.count_nonzero(ours[0, -41:]) >= 40


def slot_order(go2) -> list[int]:
    """The go2 joint of each motor slot 0..11 (robot.toml ``[unitree] motor_index``): the
    policy's joint order under deploy.yaml's ``joint_ids_map`` 0..11."""
    index = list(go2.config.unitree.motor_index)
    return [index.index(slot) for slot in range(12)]


def isaac_history_deploy(go2, length: int) -> dict:
    """unitree_rl_lab's deploy.yaml for go2 with every term's ``history_length`` = ``length``
    (its G1 velocity policy's is 5); per-joint lists in the policy's order."""
    home = [float(go2.home[j]) for j in slot_order(go2)]
    cfg = fs.unitree_deploy(range(12), home, scale=0.25)
    for term in cfg["observations"].values():
        term["history_length"] = length
    cfg["observations"]["base_ang_vel"]["clip"] = [-3.0, 3.0]
    return cfg


class UnitreeDeployObservation:
    """Unitree's C++ deployment (``ObservationTermCfg``): per term a deque of ``history_length``
    raw readings, filled with the current reading at the reset; each tick the reading appended
    and the deque given clipped then scaled, the oldest first, term after term."""

    def __init__(self, cfg: dict, readings):
        self.terms = cfg["observations"]
        self.readings = readings
        self.buffers = {}

    def reset(self, state) -> None:
        for name, term in self.terms.items():
            self.buffers[name] = deque([self.readings[name](state)] * term["history_length"])

    def __call__(self, state) -> np.ndarray:
        out = []
        for name, term in self.terms.items():
            buffer = self.buffers[name]
            buffer.append(self.readings[name](state))
            buffer.popleft()
            for reading in buffer:
                value = reading.astype(np.float32)
                if term["clip"] is not None:
                    value = np.clip(value, *np.float32(term["clip"]))
                out.append(value * np.float32(term["scale"]))
        return np.concatenate(out)[None]


def test_unitree_deploy_history_length_maps_to_a_per_term_history(go2, tmp_path):
    """deploy.yaml ``history_length: 5`` on every term (refused before): the policy loads and
    its observation equals the C++ deployment's, through a reset."""
    cfg = isaac_history_deploy(go2, 5)
    path = fs.write_unitree_policy(tmp_path / "v0", cfg, 45 * 5)
    policy = OnnxPolicy(path, go2)
    spec = policy.spec
    history = spec.history
    assert (history.length, history.layout, history.order, history.fill) == (
        5,
        "per_term",
        "oldest_first",
        "first",
    )
    order = slot_order(go2)  # the C++ code reads motor_state[joint_ids_map[i]]
    home = np.asarray(cfg["default_joint_pos"])
    readings = {
        "base_ang_vel": lambda s: s.base.angular_velocity[0].copy(),
        "projected_gravity": lambda s: s.base.projected_gravity[0].copy(),
        "velocity_commands": lambda s: s.command[0].copy(),
        "joint_pos_rel": lambda s: s.q[0, order] - home,
        "joint_vel_rel": lambda s: s.dq[0, order],
        "last_action": lambda s: s.last_action[0, order],
    }
    theirs = UnitreeDeployObservation(cfg, readings)
    rng = np.random.default_rng(5)
    goal = np.zeros((1, 3))
    for tick in range(12):
        state = euler_state(go2, rng, (0.1, -0.2, 0.3))
        state.base.angular_velocity[:] = rng.uniform(-14, 14, (1, 3))  # some past the clip
        if tick in (0, 7):
            spec.plan.reset_history()
            theirs.reset(state)
        ours = spec.observation(state, goal)
        np.testing.assert_allclose(ours, theirs(state), rtol=2e-7, atol=1e-6, err_msg=str(tick))
    assert np.isfinite(policy(ours)).all()


class RlSarBuffer:
    """rl_sar's ``ObservationBuffer``: ``length`` frames, zeros at the start, a new frame in
    front; ``get`` the frames of ``ids`` (0 the newest), by ``time`` (whole frames) or ``term``
    (each term's ticks in turn)."""

    def __init__(self, length: int, sizes: list[int], priority: str):
        self.frames = [np.zeros(sum(sizes), np.float32) for _ in range(length)]
        self.sizes, self.priority = sizes, priority

    def __call__(self, frame: np.ndarray, ids: list[int]) -> np.ndarray:
        self.frames = [frame.copy()] + self.frames[:-1]
        if self.priority == "time":
            return np.concatenate([self.frames[i] for i in ids])[None]
        out, start = [], 0
        for size in self.sizes:
            out += [self.frames[i][start : start + size] for i in ids]
            start += size
        return np.concatenate(out)[None]


@pytest.mark.parametrize("priority", ["time", "term"])
def test_rl_sar_observations_history_newest_first(go2, priority):
    """rl_sar's ``observations_history: [0, 1, 2, 3]`` (the newest first) with either priority
    is a spec's history ``newest_first``, ``per_frame`` (time) or ``per_term`` (term), zeros."""
    home = [float(x) for x in go2.home]
    blocks = [
        {"name": "base_angular_velocity", "scale": 4.0},
        {"name": "projected_gravity"},
        {"name": "velocity_command"},
        {"name": "joint_position", "offset": home},
        {"name": "joint_velocity", "scale": 20.0},
        {"name": "last_action"},
    ]
    layout = {"time": "per_frame", "term": "per_term"}[priority]
    doc = {
        "format_version": 1,
        "robot": "go2",
        "joint_names": list(go2.joint_names),
        "observation": blocks,
        "action": {"mode": "position", "scale": 0.25, "offset": home},
        "control_rate": 1.0 / go2.control_period,
        "history": {"length": 4, "order": "newest_first", "layout": layout, "fill": "zeros"},
    }
    spec = PolicySpec.from_json(json.dumps(doc))
    sizes = [3, 3, 3, 12, 12, 12]
    theirs = RlSarBuffer(4, sizes, priority)
    rng = np.random.default_rng(9)
    spec.plan.reset_history()
    for _ in range(6):
        state = euler_state(go2, rng, (0.0, 0.1, 0.0))
        s = state
        frame = np.concatenate(
            [
                s.base.angular_velocity[0] * 0.25,
                s.base.projected_gravity[0],
                s.command[0],
                s.q[0] - np.asarray(home),
                s.dq[0] * 0.05,
                s.last_action[0],
            ]
        ).astype(np.float32)
        ours = spec.observation(state, np.zeros((1, 3)))
        np.testing.assert_allclose(ours, theirs(frame, [0, 1, 2, 3]), rtol=2e-7, atol=1e-6)


@pytest.mark.parametrize(
    "history",
    [
        {"length": 3, "order": "oldest_first", "layout": "per_frame", "fill": "first"},
        {"length": 4, "order": "newest_first", "layout": "per_term", "fill": "zeros"},
        {"length": 4, "layout": "per_term", "fill": "first", "lengths": [1, 4, 2]},
    ],
)
def test_the_compiled_stacking_equals_its_numpy_oracle_with_resets_per_env(go2, history):
    """Three envs, one reset part way: the kernel and the numpy reference give the same numbers
    bit for bit, and a reset env's past reads its fill while the others keep theirs."""
    doc = {
        "format_version": 1,
        "robot": "go2",
        "joint_names": list(go2.joint_names),
        "observation": [
            {"name": "base_euler_angles", "components": [2, 0]},
            {"name": "joint_velocity", "scale": 20.0},
            {"name": "projected_gravity"},
        ],
        "action": {"mode": "position", "scale": 0.25},
        "control_rate": 1.0 / go2.control_period,
        "history": history,
    }
    spec = PolicySpec.from_json(json.dumps(doc))
    rng = np.random.default_rng(1)
    state = RobotState.legged(3, 12, 4)
    goal = np.zeros((3, 3))
    spec.plan.reset_history()
    for tick in range(8):
        state.dq[:] = rng.uniform(-5, 5, (3, 12))
        q = rng.normal(size=(3, 4))
        state.base.orientation[:] = q / np.linalg.norm(q, axis=1, keepdims=True)
        state.base.projected_gravity[:] = rng.uniform(-1, 1, (3, 3))
        if tick == 5:
            spec.plan.reset_history(np.array([False, True, False]))
        ours = spec.observation(state, goal).copy()
        np.testing.assert_array_equal(ours, observation_reference(spec, state, goal))
    frame = ours[1].reshape(-1)
    if history["fill"] == "zeros":  # env 1 has 3 frames since its reset: the 4th tick back is 0
        assert np.count_nonzero(frame) < np.count_nonzero(ours[0])


def test_a_history_that_does_not_fit_the_blocks_is_refused_naming_the_field(go2):
    doc = {
        "format_version": 1,
        "robot": "go2",
        "joint_names": list(go2.joint_names),
        "observation": [{"name": "projected_gravity"}, {"name": "joint_velocity"}],
        "action": {"mode": "position"},
        "control_rate": 50.0,
        "history": {"length": 3, "layout": "per_frame", "lengths": [1, 3]},
    }
    with pytest.raises(SpecError, match="history.lengths: per-block ticks need layout 'per_term'"):
        PolicySpec.from_json(json.dumps(doc), source="f.json")
    doc["history"] = {"length": 3, "layout": "per_term", "lengths": [4, 3]}
    with pytest.raises(SpecError, match=r"f.json: history.lengths: \[4\] outside 1..3"):
        PolicySpec.from_json(json.dumps(doc), source="f.json")
    doc["history"] = {"length": 3, "order": "backwards"}
    with pytest.raises(SpecError, match="f.json: field 'history.order'"):
        PolicySpec.from_json(json.dumps(doc), source="f.json")


# ----------------------------------------------------------------------- a humanoid-gym policy
def humanoid_gym_actor(obs_dim: int, act_dim: int) -> nn.Module:
    """humanoid-gym's ActorCritic.actor: Linear and ELU layers (its actor_hidden_dims, smaller
    here), the last layer's weights small: the robot stands about its default pose."""
    torch.manual_seed(0)
    actor = nn.Sequential(nn.Linear(obs_dim, 32), nn.ELU(), nn.Linear(32, act_dim))
    with torch.no_grad():
        actor[2].weight.mul_(1e-3)
        actor[2].bias.zero_()
    return actor.eval()


def test_a_humanoid_gym_policy_runs_from_its_spec_and_policy_export_embeds_it(h1, tmp_path, capsys):
    """humanoid-gym's export (``export_policy_as_jit``: ``torch.jit.script`` of the actor to
    ``exported/policies/policy_1.pt``) and the same actor as a bare ONNX file, with a hand-written
    spec of 15 frames and Euler angles: deploy-run runs the ONNX file from the spec (no wrapper);
    ``policy-export POLICY.onnx --spec F --robot h1`` (refused before) and ``policy-export
    policy_1.pt --spec F`` write files that carry the spec and run with no flag."""
    doc = humanoid_gym_spec(h1)
    spec_path = tmp_path / "spec.json"
    spec_path.write_text(json.dumps(doc))
    actor = humanoid_gym_actor(41 * FRAME_STACK, h1.n_joints)
    folder = tmp_path / "logs" / "XBot_ppo" / "exported" / "policies"
    folder.mkdir(parents=True)
    torch.jit.script(actor).save(str(folder / "policy_1.pt"))
    bare = fs._export(actor, 41 * FRAME_STACK, tmp_path / "policy.onnx", 13, ["input"], ["output"])

    def run(*args) -> tuple[int, str, str]:
        code = deploy_run_main(["--robot", "h1", "--duration", "1.0", *args])
        out, err = capsys.readouterr()
        return code, out, err

    code, out, err = run("--policy", str(bare), "--spec", str(spec_path))
    assert code in (0, 2) and "error" not in err, out + err

    written = tmp_path / "policy.h1.onnx"
    code = policy_export_main([str(bare), "--spec", str(spec_path), "--robot", "h1"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "max |written - source| 0.0e+00" in out and f"spec from {spec_path}" in out
    stored = {p.key: p.value for p in onnx.load(str(written)).metadata_props}["policy_spec"]
    assert PolicySpec.from_json(stored) == PolicySpec.from_json(json.dumps(doc))
    code, out, err = run("--policy", str(written))
    assert code in (0, 2) and "error" not in err, out + err

    code = policy_export_main([str(folder / "policy_1.pt"), "--spec", str(spec_path)])
    out, err = capsys.readouterr()
    assert code == 0, err
    exported = folder / "policy_1.onnx"
    stored = {p.key: p.value for p in onnx.load(str(exported)).metadata_props}["policy_spec"]
    assert PolicySpec.from_json(stored).history == PolicySpec.from_json(json.dumps(doc)).history
    code, out, err = run("--policy", str(exported))
    assert code in (0, 2) and "error" not in err, out + err


class Witness:
    """A policy that keeps what the runtime feeds it and, beside it, the frame its spec's blocks
    make of the same state (the history-free twin of its spec), and when the runtime resets it."""

    def __init__(self, spec: PolicySpec, twin: PolicySpec):
        self.spec, self.twin, self.runtime = spec, twin, None
        self.fed: list[np.ndarray] = []
        self.frames: list[list[np.ndarray]] = [[]]  # the frames since each reset

    def reset(self, envs) -> None:
        self.frames.append([])

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        rt = self.runtime
        self.frames[-1].append(self.twin.observation(rt.state, rt.goal)[0].copy())
        self.fed.append((obs[0].copy(), len(self.frames) - 1, len(self.frames[-1])))
        return np.zeros((1, self.spec.act_dim), dtype=np.float32)


def stacked(frames: list[np.ndarray], sizes: list[int], ticks: int) -> np.ndarray:
    """Per term, the oldest first, the first frame since the reset before it (Isaac Lab's)."""
    out, start = [], 0
    for size in sizes:
        for lag in range(ticks - 1, -1, -1):
            frame = frames[max(len(frames) - 1 - lag, 0)]
            out.append(frame[start : start + size])
        start += size
    return np.concatenate(out)


@pytest.mark.parametrize("runtime_type", ["Runtime", "ReferenceRuntime"])
def test_the_runtime_feeds_the_frames_and_starts_them_again_when_the_policy_takes_over(
    arm3, runtime_type
):
    """An arm (the fixed base's fused estimate-observe path runs its four stages apart then) and
    the numpy reference runtime: every tick the policy gets its blocks' frames of the last 4
    ticks, and RAMP_IN handing over to it starts the history again."""
    import dataclasses

    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.runtime import Runtime
    from sim2real.deploy.runtime.reference import ReferenceRuntime
    from sim2real.deploy.spec.history import ObservationHistory

    twin = PolicySpec.for_robot(arm3)
    history = ObservationHistory(4, layout="per_term", fill="first")
    witness = Witness(dataclasses.replace(twin, history=history), twin)
    kind = {"Runtime": Runtime, "ReferenceRuntime": ReferenceRuntime}[runtime_type]
    rt = kind(arm3, witness, SimBackend(arm3, seed=0))
    witness.runtime = rt
    rt.start()
    rt.run(400)
    assert rt.mode_names() == ["RUNNING"] and len(witness.frames) >= 3  # start, took over
    sizes = [b.size for b in twin.observation_blocks]
    for obs, reset, count in witness.fed:
        expected = stacked(witness.frames[reset][:count], sizes, 4)
        np.testing.assert_array_equal(obs, expected)


def test_mjlab_holosoma_and_isaac_lab_histories_map_as_each_stack_lays_them_out(go2, tmp_path):
    """mjlab's ``observation_terms_history_length`` (per term, first-value fill), holosoma's
    group ``history_length`` (every term, zeros until full) and an Isaac Lab run's per-term
    ``history_length`` (refused before) load, each a per-term history, the oldest first."""
    md = fs.mjlab_metadata()
    md["observation_terms_history_length"] = [3, 3, 3, 3, 3, 3, 0]  # the command: present only
    mjlab = OnnxPolicy(fs.write_mjlab(tmp_path / "mjlab.onnx", md, 45 * 3 + 3), go2)
    h = mjlab.spec.history
    assert (h.layout, h.order, h.fill, h.lengths) == ("per_term", "oldest_first", "first",
                                                      (3, 3, 3, 3, 3, 3, 1))  # fmt: skip
    experiment = fs.holosoma_experiment(fs.HOLOSOMA_ORDER)
    experiment["observation"]["groups"]["actor_obs"]["history_length"] = 4
    holosoma = OnnxPolicy(fs.write_holosoma(tmp_path / "h.onnx", experiment, 48 * 4), go2)
    h = holosoma.spec.history
    assert (h.length, h.layout, h.fill, h.lengths) == (4, "per_term", "zeros", ())
    env = fs.isaaclab_env()
    for term in env["observations"]["policy"].values():
        if isinstance(term, dict) and "func" in term:
            term["history_length"] = 2
    isaac = OnnxPolicy(fs.write_isaaclab_run(tmp_path / "run", env, 48 * 2, 12), go2)
    assert (isaac.spec.history.length, isaac.spec.obs_dim) == (2, 96)
