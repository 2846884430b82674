"""A phase-clocked dance: the ``motion_phase`` block (``t / T``), the motion clock the runtime
owns (sim2real/deploy/core/phase_clock.py), rl_sar's ``RoboMimic_Deploy/phase`` mapped onto
them, and the sizes ``policy-export --inspect`` reads from a TorchScript module that wraps its
network. CI runs them on files written the way rl_sar writes its RoboMimic folder
(tests/robomimic_files.py); the last tests play rl_sar's own charleston on unitree_mujoco's G1
against a bare loop of RoboMimic_Deploy's runtime (sim2real/stacks/loops/robomimic_dance.py), through the
``stacks`` fixture."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import yaml
from onnx import helper

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.core.phase_clock import MotionPhaseClock
from sim2real.deploy.core.stateful import StateDictError
from sim2real.deploy.export.folder_torchscript import contract_sizes
from sim2real.deploy.export.inspect_torch import inspect_torchscript
from sim2real.deploy.export.pipeline import parity_errors
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.runtime import Mode, Runtime
from sim2real.deploy.spec.foreign.contract import ForeignFormatError
from sim2real.deploy.spec.foreign.registry import read_folder_contract
from sim2real.deploy.spec.policy_spec import ObservationBlock, PolicySpec
from tests.robomimic_files import KEY, write_robomimic_folder
from tests.runtime_fixtures import linear_onnx

T = 6.0  # s, the motion's length of the go2 tests
LEAD = 0.02 / T  # the offset of rl_sar's first tick (one period of 50 Hz), as its reader sets it


@pytest.fixture(scope="module")
def phase_policy(go2, tmp_path_factory):
    """go2's default spec with a ``motion_phase`` block (T = 6 s, rl_sar's first-tick offset)
    appended, its action 0 (the home pose), as an ONNX policy."""
    spec = PolicySpec.for_robot(go2)
    block = ObservationBlock("motion_phase", 1, (1.0,), (-LEAD,), clip=100.0, period=T)
    spec = dataclasses.replace(spec, observation_blocks=(*spec.observation_blocks, block))
    spec.validate()
    nodes = [helper.make_node("MatMul", ["obs", "w"], ["action"])]
    weights = {"w": np.zeros((spec.obs_dim, spec.act_dim), np.float32)}
    path = tmp_path_factory.mktemp("phase") / "phase.onnx"
    return OnnxPolicy(linear_onnx(spec, path, nodes, weights, "phase"), go2)


def _runtime(go2, policy, seed=0):
    rt = Runtime(go2, policy, SimBackend(go2, "position", envs=2, seed=seed))
    rt.start()
    return rt


def _phase(rt) -> np.ndarray:
    """The phase entry of the last observation (the spec's last column)."""
    return rt.spec.observation(rt.state, rt.goal)[:, -1]


def test_the_phase_ramps_from_the_first_running_tick_and_a_stop_starts_it_again(go2, phase_policy):
    """t / T of the runtime's clock: 0 on an env's first RUNNING tick (read + the offset: rl_sar
    reads one period there), one period more each RUNNING tick; a safe stop ends the play and the
    next RUNNING tick starts it at 0 again."""
    rt = _runtime(go2, phase_policy)
    clock = rt.base_tick.phase_clock
    first = np.full(2, -1)
    for _ in range(40):
        rt.tick()
        new = (rt.mode == Mode.RUNNING) & (first < 0)
        first[new] = rt.ticks
        assert (clock.ticks[new] == 0).all()  # the first RUNNING tick reads 0
    assert (first > 0).all()
    running = rt.ticks - first  # RUNNING ticks before the last one
    np.testing.assert_array_equal(clock.ticks, running)
    np.testing.assert_allclose(rt.state.motion_time, running * rt.dt)
    np.testing.assert_allclose(_phase(rt), running * rt.dt / T + LEAD, atol=1e-6)

    rt.supervision.safe_stop(np.array([True, False]), "operator")
    rt.tick()  # env 0 stopped: its clock reads 0; env 1 plays on
    assert rt.mode[0] != Mode.RUNNING and clock.ticks[0] == 0 and rt.state.motion_time[0] == 0
    assert clock.ticks[1] == running[1] + 1


def test_the_motion_clock_survives_the_runtime_state_dict(go2, phase_policy):
    rt = _runtime(go2, phase_policy, seed=1)
    rt.run(25)
    saved = rt.state_dict()
    assert "motion_phase/ticks" in saved and "motion_phase/time" in saved  # a part
    rt.run(15)
    expected = (rt.base_tick.phase_clock.ticks.copy(), _phase(rt))
    again = _runtime(go2, phase_policy, seed=7)
    again.run(3)  # another history: the state must replace it
    again.load_state_dict(saved)
    again.run(15)
    np.testing.assert_array_equal(again.base_tick.phase_clock.ticks, expected[0])
    np.testing.assert_allclose(_phase(again), expected[1], atol=1e-7)


def test_the_policys_own_loop_plays_the_motion_on(go2, phase_policy):
    """OwnLoop (the soak's fall replay) on a runtime's state: the motion time moves one period a
    tick from where the runtime left it, never frozen."""
    from sim2real.deploy.rig.own_loop import OwnLoop

    rt = _runtime(go2, phase_policy)
    rt.run(10)
    before = rt.state.motion_time.copy()
    loop = OwnLoop(rt.policy, rt.backend, rt.state, rt.goal, rt.dt, rt.time, rt.ticks)
    for _ in range(5):
        loop.tick()
    np.testing.assert_allclose(rt.state.motion_time, before + 5 * rt.dt)


def test_the_export_replay_plays_the_motion_on_from_its_first_tick(go2, phase_policy):
    """policy-export --robot on a phase-clocked policy: the closed-loop replay gives the phase
    block a motion clock (it used to refuse the observation) that plays on every tick."""
    from sim2real.deploy.export.parity import closed_loop_parity

    phases = []

    def reference(obs):
        phases.append(obs[0, -1])
        return np.zeros((len(obs), phase_policy.spec.act_dim), np.float32)

    loop = closed_loop_parity(phase_policy, None, go2, ticks=5, envs=1, reference=reference)
    assert loop["max_abs_error"] == 0.0
    want = np.arange(5) * go2.control_period / T + LEAD  # the offset: rl_sar reads one period on
    np.testing.assert_allclose(phases, want, atol=1e-6)


def test_the_clock_alone_counts_running_ticks_and_restores_its_state():
    """From the modes the previous tick ended in: RUNNING plays on one period, else 0."""
    clock = MotionPhaseClock(3, 0.02)
    mode = np.array([Mode.RUNNING, Mode.RAMP_IN, Mode.RUNNING])
    for _ in range(3):
        clock.advance(mode)
    np.testing.assert_allclose(clock.time, [0.06, 0.0, 0.06])
    mode[2] = Mode.SAFE_STOP
    clock.advance(mode)
    np.testing.assert_array_equal(clock.ticks, [4, 0, 0])
    other = MotionPhaseClock(3, 0.02)
    other.load_state_dict(clock.state_dict())
    np.testing.assert_array_equal(other.ticks, clock.ticks)
    other.load_state_dict(MotionPhaseClock(3, 0.02).state_dict(1), env=1)
    with pytest.raises(StateDictError, match="field 'ticks'"):
        other.load_state_dict({"ticks": np.zeros(2), "time": np.zeros(3)})
    with pytest.raises(ValueError, match="period"):
        MotionPhaseClock(1, 0.0)


def test_a_phase_block_without_a_length_is_refused_naming_the_period(go2):
    spec = PolicySpec.for_robot(go2)
    block = ObservationBlock("motion_phase", 1, (1.0,), (0.0,))
    spec = dataclasses.replace(spec, observation_blocks=(*spec.observation_blocks, block))
    with pytest.raises(ValueError, match="period must be a positive number"):
        spec.validate()


# ---------------------------------------------------------------- rl_sar's RoboMimic folder
def _phase_term(folder):
    contract = read_folder_contract(folder / "dance.pt")
    return contract, next(t for t in contract.terms if t.name == "RoboMimic_Deploy/phase")


def test_rl_sars_robomimic_phase_is_t_over_its_fsms_motion_length(tmp_path):
    """charleston's key: T = 18 s (rl_sar's fsm), the first tick one control period (its
    RunModel counts before the observation); the folder's 4 frames of 94: 376 in, 29 out."""
    contract, term = _phase_term(write_robomimic_folder(tmp_path))
    assert term.kind == "motion_phase" and term.size == 1 and term.period == 18.0
    assert term.offset == pytest.approx(-0.02 / 18.0)
    assert contract.history_length == 4 and contract.history_order == "newest_first"
    assert contract_sizes(contract)[:2] == (376, 29)


def test_a_motion_length_in_config_yaml_wins_and_a_bad_one_is_refused(tmp_path):
    _, term = _phase_term(write_robomimic_folder(tmp_path / "a", extra={"motion_length": 9.5}))
    assert term.period == 9.5 and term.offset == pytest.approx(-0.02 / 9.5)
    with pytest.raises(ForeignFormatError, match=r"config\.yaml: 'motion_length': expected"):
        _phase_term(write_robomimic_folder(tmp_path / "b", extra={"motion_length": 0}))


def test_a_phase_of_unknown_length_cannot_be_mapped_and_says_where_to_give_it(tmp_path):
    folder = write_robomimic_folder(tmp_path, key="g1/robomimic/other_dance")
    _, term = _phase_term(folder)
    assert term.kind is None and "motion_length: T" in term.reason


def test_inspect_reads_a_wrapping_modules_own_sizes_not_its_inner_networks(tmp_path, capsys):
    """rl_sar's DanceWrapper layout: the module takes 376 and answers 29, its network 380 -> 23."""
    from sim2real.deploy.cli.policy_export import main as policy_export

    source = write_robomimic_folder(tmp_path) / "dance.pt"
    r = inspect_torchscript(source)
    assert r["inputs"][0]["shape"] == ["batch", 376]
    assert r["outputs"][0]["shape"] == ["batch", 29]
    assert r["details"]["network layers (first in, last out)"] == [380, 23]
    assert policy_export([str(source)]) == 0  # the contract's 376 -> 29 runs the module
    assert source.with_suffix(".onnx").is_file()
    capsys.readouterr()


def test_the_gates_message_reads_without_a_closed_loop_replay():
    """A failed gate with no --robot (no replay figures) is a message, not a KeyError."""
    text = parity_errors({"samples": 9, "max_abs_error": 0.1, "tolerance": 1e-5})
    assert "over 9 observations" in text and "replay" not in text


# ---------------------------------------------------------------- rl_sar's charleston (stacks)
CHARLESTON = "policy/g1/robomimic/charleston"


@pytest.fixture(scope="module")
def charleston(stacks, tmp_path_factory):
    """rl_sar's charleston exported, unitree_mujoco's G1 imported with robot-level flags only,
    and RoboMimic_Deploy's own network and Dance.yaml written from their contents here (the
    mirror is not a stack of tests/stacks.py; the bare loop reads rl_sar's inner network)."""
    from sim2real.deploy.cli.robot_import import main as robot_import
    from sim2real.deploy.export.folder_torchscript import export_folder_torchscript
    from sim2real.robots.loading import load_robot
    from tests.motion_files import G1_FLAGS, g1_xml

    root = tmp_path_factory.mktemp("charleston")
    for name in ("policy/g1/base.yaml", f"{CHARLESTON}/config.yaml",
                 f"{CHARLESTON}/dance_0605_aligned.pt"):  # fmt: skip
        out = root / name
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(stacks.read("rl_sar", name))
    source = root / CHARLESTON / "dance_0605_aligned.pt"
    xml = g1_xml(stacks, root)
    out = root / "robots" / "g1"
    assert robot_import([str(xml), *G1_FLAGS, "--drive-from", str(source), "--out", str(out)]) == 0
    # the module's code fixes float32: its noise floor is measured on the exported graph; the
    # closed-loop replay on the G1 plays the motion phase on from its first tick
    exported = export_folder_torchscript(source, robot=load_robot(out))
    onnx_path = exported.path
    return root, out, onnx_path, source, exported.parity


def test_charleston_passes_the_parity_gate_with_no_flag_on_its_graphs_noise_floor(charleston):
    """The module's code fixes float32, so the floor is its graph's own float32 rounding; at
    the edge cases (+-clip_obs = 100) its actions reach ~3.6e3 and ONNX Runtime and TorchScript
    differ by 4.15e-3, far above the absolute 1e-5 and within 4 x that floor (3.77e-3). The
    closed-loop replay on the G1 (its phase from the replay's clock) passes too."""
    f = charleston[-1]
    assert f["passed"] is True and f["noise_floor_of"] == "graph"
    assert f["tolerance_basis"] == "relative" and "tolerance_note" not in f
    assert 1e-3 < f["max_abs_error"] <= f["tolerance"] == pytest.approx(4 * f["noise_floor"])
    assert f["replay_ticks"] == 1000 and f["replay_plant_resets"] == 0
    assert f["replay_max_abs_error"] <= f["replay_tolerance"]


def test_inspect_reads_charleston_as_376_to_29(charleston):
    *_, source, _ = charleston
    r = inspect_torchscript(source)
    assert (r["inputs"][0]["shape"], r["outputs"][0]["shape"]) == (["batch", 376], ["batch", 29])


def test_charleston_plays_its_motion_within_10_percent_of_robomimics_own_loop(charleston, tmp_path):
    """deploy-run --backend sim with no spec: the whole 18 s, no fall; the joints' error against
    the policy's targets within 10 % of the bare loop of RoboMimic_Deploy's runtime on the same
    MJCF (the inner network of rl_sar's module, RoboMimic's Dance.yaml values from rl_sar's
    config.yaml, physics 0.002 s x 10 as the import's)."""
    import torch

    from sim2real.deploy.cli.deploy_run import deploy_run_main
    from sim2real.stacks.loops import robomimic_dance

    root, robot, policy, source, _ = charleston
    report = tmp_path / "r.json"
    argv = ["--backend", "sim", "--robot", str(robot), "--policy", str(policy)]
    deploy_run_main([*argv, "--duration", "18", "--report", str(report)])
    r = json.loads(report.read_text())
    p = r["motion_phase"]
    assert r["locomotion"]["falls"] == 0 and p["completed"] == 1.0 and p["stopped"] == 0
    # its self-collision ticks (the torso's hull against the arms) are its own loop's too:
    # RoboMimic's Dance on the same plant, judged by the soak's rule, passes them (exit 0)
    own = r["own_loop"]
    assert own["compared"] and own["own"]["stack"] == "robomimic" and own["own"]["falls"] == 0
    assert own["verdict"]["self_collision"]["passed"] and own["own"]["self_collision_ticks"] > 50
    assert r["violations"]["by_type"]["self_collision"] > 50 and r["exit_code"] == 0

    cfg = yaml.safe_load((root / CHARLESTON / "config.yaml").read_text())[KEY]
    dance = {
        "kps": cfg["rl_kp"], "kds": cfg["rl_kd"], "default_angles": cfg["default_dof_pos"],
        "dof23_index": list(range(19)) + [22, 23, 24, 25], "ang_vel_scale": 0.25,
        "dof_pos_scale": 1.0, "dof_vel_scale": 0.05, "action_scale": 0.25,
        "history_length": 4, "motion_length": 18.0, "num_actions": 23,
    }  # fmt: skip  # RoboMimic_Deploy's policy/dance/config/Dance.yaml
    (tmp_path / "Dance.yaml").write_text(yaml.safe_dump(dance))
    inner = torch.jit.load(str(source)).model  # RoboMimic's dance_0605 network (380 -> 23)

    def net(obs):
        with torch.no_grad():
            return inner(torch.from_numpy(obs)).numpy()

    scene = robot.parents[1] / "unitree_robots" / "g1" / "scene_29dof.xml"
    bare = robomimic_dance.run(
        None, tmp_path / "Dance.yaml", scene, timestep=0.002, decimation=10, net=net
    )
    assert not bare["fell"] and bare["share"] == 1.0
    assert abs(p["joint_rms_rad"] / bare["joint_rms"] - 1.0) < 0.10


def test_a_switch_to_a_phase_clocked_policy_starts_its_motion_clock_at_0(go2, phase_policy):
    """A runtime started on a policy with no motion phase keeps no clock; switch_policy to a
    phase-clocked one while RUNNING gives it one, and its first tick reads t = 0 (then one
    period a tick), as rl_sar's fsm state's Enter starts its episode; a second switch to it
    starts the motion again."""
    from tests.runtime_fixtures import linear_onnx

    spec = PolicySpec.for_robot(go2)
    nodes = [helper.make_node("MatMul", ["obs", "w"], ["action"])]
    weights = {"w": np.zeros((spec.obs_dim, spec.act_dim), np.float32)}
    path = linear_onnx(spec, phase_policy.path.parent / "plain.onnx", nodes, weights, "plain")
    rt = _runtime(go2, OnnxPolicy(path, go2))
    assert rt.base_tick.phase_clock is None
    rt.run(40)
    assert (rt.mode == Mode.RUNNING).all()
    rt.switch_policy(phase_policy)
    clock = rt.base_tick.phase_clock
    assert clock is not None and rt.state.motion_time is clock.time
    rt.tick()
    np.testing.assert_array_equal(clock.ticks, 0)
    np.testing.assert_allclose(_phase(rt), LEAD, atol=1e-7)
    rt.run(9)
    np.testing.assert_allclose(_phase(rt), 9 * rt.dt / T + LEAD, atol=1e-6)
    rt.switch_policy(phase_policy)  # entered again: the motion starts again
    rt.tick()
    np.testing.assert_array_equal(clock.ticks, 0)
