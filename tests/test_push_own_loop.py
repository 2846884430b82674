"""The push benchmark's own loops (``python -m bench.push_reference``): rl_sar's loop of the robot
given, not the Go2's (``--rl-sar``), a refusal in one line when its folder or MJCF is not that
robot's, every bad flag one line with exit 2, and, for a policy that observes the base's linear
velocity, its own loop on our plant fed the truth and fed our estimate.

The rl_sar checkout, unitree_mujoco's MJCF and the robot import are written here the way those
stacks write them (a made-up quadruped ``quad``: go2.xml's layout with its base body renamed
``torso``, unitree_mujoco's sensors and ``home`` key; rl_sar's ``policy/quad/base.yaml`` and
``policy/quad/walk/config.yaml``), so CI, which has no stacks, runs them."""

from __future__ import annotations

import numpy as np
import onnx
import pytest
import torch
from onnx import TensorProto, helper, numpy_helper

from bench.push_reference import main
from sim2real.deploy.cli.robot_import import main as robot_import
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.rig.own_loop import OwnLoop
from sim2real.deploy.spec.policy_spec import PolicySpec
from sim2real.robots import load_robot
from sim2real.stacks.loops import rl_sar_robot
from tests.go2_layout import ACTUATORS, write_go2
from tests.runtime_fixtures import linear_onnx

#: rl_sar's HIMLoco keys for the Go2 (policy/go2/base.yaml, go2/himloco/config.yaml, e384912), the
#: history left out: the policy reads its present frame only
BASE = {
    "dt": 0.005,
    "decimation": 4,
    "num_of_dofs": 12,
    "wheel_indices": [],
    "joint_names": [f"{a}_joint" for a in ACTUATORS],
    "fixed_kp": [60.0] * 12,
    "fixed_kd": [5.0] * 12,
}
CONFIG = {
    "model_name": "policy.pt",
    "num_observations": 45,
    "observations": ["commands", "ang_vel", "gravity_vec", "dof_pos", "dof_vel", "actions"],
    "observations_history": [],
    "observations_history_priority": "time",
    "clip_obs": 100.0,
    "clip_actions_lower": [-100.0] * 12,
    "clip_actions_upper": [100.0] * 12,
    "rl_kp": [40.0] * 12,
    "rl_kd": [1.0] * 12,
    "action_scale": [0.125, 0.25, 0.25] * 4,
    "lin_vel_scale": 2.0,
    "ang_vel_scale": 0.25,
    "dof_pos_scale": 1.0,
    "dof_vel_scale": 0.05,
    "commands_scale": [2.0, 2.0, 0.25],
    "default_dof_pos": [0.1, 0.8, -1.5, -0.1, 0.8, -1.5, 0.1, 1.0, -1.5, -0.1, 1.0, -1.5],
    "joint_mapping": [3, 4, 5, 0, 1, 2, 9, 10, 11, 6, 7, 8],
}
#: unitree_mujoco's sensors (go2.xml: each motor's angle, speed and torque, then the IMU) and
#: its home key (the legs folded, as go2.xml's)
SENSORS = "".join(
    f'    <{kind} name="{a}_{kind}" {attr}="{a}_joint" />\n'
    for kind, attr in (("jointpos", "joint"), ("jointvel", "joint"), ("jointactuatorfrc", "joint"))
    for a in ACTUATORS
)
EXTRA = f"""  <sensor>
{SENSORS}    <framequat name="imu_quat" objtype="site" objname="imu" />
    <gyro name="imu_gyro" site="imu" />
    <accelerometer name="imu_acc" site="imu" />
  </sensor>
  <keyframe>
    <key name="home" qpos="0 0 0.27 1 0 0 0 {" ".join(["0 0.9 -1.8"] * 4)}" />
  </keyframe>
"""
FEET = ["FL", "FR", "RL", "RR"]


def _quad_xml(folder, base="torso"):
    """go2.xml's layout as ``quad``'s unitree_mujoco MJCF in ``folder``, its base body ``base``."""
    folder.mkdir(parents=True)
    text = write_go2(folder).read_text().replace("base_link", base)
    (folder / "go2.xml").unlink()
    path = folder / "quad.xml"
    path.write_text(text.replace("</mujoco>", EXTRA + "</mujoco>"))
    return path


def _yaml(path, key, value):
    import yaml

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump({key: value}))


@pytest.fixture(scope="module")
def quad(tmp_path_factory):
    """(root, robot folder, ONNX) of the made-up quadruped: ``root/rl_sar``,
    ``root/unitree_mujoco`` and the import ``root/robots/quad`` (module docstring); its
    TorchScript and ONNX policies stand still (zero action)."""
    root = tmp_path_factory.mktemp("quad")
    xml = _quad_xml(root / "unitree_mujoco" / "unitree_robots" / "quad")
    _yaml(root / "rl_sar" / "policy" / "quad" / "base.yaml", "quad", BASE)
    folder = root / "rl_sar" / "policy" / "quad" / "walk"
    _yaml(folder / "config.yaml", "quad/walk", CONFIG)
    net = torch.nn.Linear(45, 12)
    torch.nn.init.zeros_(net.weight)
    torch.nn.init.zeros_(net.bias)
    torch.jit.script(net).save(str(folder / "policy.pt"))
    graph = helper.make_graph(  # the bare obs -> actions graph policy-export writes beside it
        [helper.make_node("MatMul", ["obs", "w"], ["actions"])],
        "walk",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", 45])],
        [helper.make_tensor_value_info("actions", TensorProto.FLOAT, ["batch", 12])],
        initializer=[numpy_helper.from_array(np.zeros((45, 12), np.float32), "w")],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.save(model, folder / "policy.onnx")
    robot = root / "robots" / "quad"
    flags = [
        "--floating-base",
        "--motor",
        "*=go_m8010_6",
        "--motor",
        "*_calf_joint=go_m8010_6_knee",
    ]
    flags += [x for f in FEET for x in ("--foot", f"{f}_foot")]
    flags += ["--drive-from", str(folder / "policy.pt")]
    assert robot_import([str(xml), "--out", str(robot), *flags]) == 0
    return root, robot, folder / "policy.onnx"


def _bench(quad, *extra, unitree_mujoco=None):
    root, robot, onnx_file = quad
    um = unitree_mujoco or root / "unitree_mujoco"
    return main(
        ["--robots", "", "--user", f"quad={robot},{onnx_file}"]
        + ["--rl-sar", f"quad={root / 'rl_sar'},{um}", *extra]
    )


def test_the_own_loop_is_rl_sars_loop_of_the_robot_given(quad, capsys):
    """--rl-sar runs the quadruped's own rl_sar folder (quad/walk) on its own MJCF (quad.xml,
    base body torso), not the Go2's HIMLoco folder and go2.xml: the row names them, and the
    standing policy walks its 0.4 s in both loops."""
    code = _bench(quad, "--no-pushes", "--seeds", "0-0", "--seconds", "0.4")
    out = capsys.readouterr().out
    assert code == 0
    row = next(line for line in out.splitlines() if "| own (" in line)
    assert row.startswith("| quad | own (rl_sar quad/walk on quad.xml) | 0 | 0/1 |")
    root, robot, _ = quad
    model = rl_sar_robot.load_spec(rl_sar_robot.mjcf(root / "unitree_mujoco", "quad/walk"))
    assert model.compile().body("torso").id == 1  # the loop's base body is the quad's
    cfg, folder = rl_sar_robot.read_folder(root / "rl_sar", "quad/walk")
    assert folder.name == "walk" and cfg["fixed_kp"] == [60.0] * 12  # config.yaml over base.yaml


def test_a_robot_its_rl_sar_files_do_not_hold_is_refused_in_one_line(quad, tmp_path, capsys):
    """An MJCF without the import's base body, an rl_sar checkout without the policy's folder
    and an ONNX file with no rl_sar config.yaml beside it: each one line naming --rl-sar and
    what is missing, exit 2, before any run."""
    other = tmp_path / "um"
    _quad_xml(other / "unitree_robots" / "quad", base="trunk")
    assert _bench(quad, "--seeds", "0-0", unitree_mujoco=other) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err
    assert err.startswith("python -m bench.push_reference: error: --rl-sar quad: ")
    assert "quad.xml: no body 'torso' of robot" in err
    root, robot, onnx_file = quad
    assert main(["--robots", "", "--user", f"quad={robot},{onnx_file}",
                 "--rl-sar", f"quad={tmp_path},{root / 'unitree_mujoco'}"]) == 2  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert (
        err.count("\n") == 0
        and "no such rl_sar policy folder (for the policy's key 'quad/walk')" in err
    )
    alone = tmp_path / "alone.onnx"
    alone.write_bytes(onnx_file.read_bytes())
    assert main(["--robots", "", "--user", f"quad={robot},{onnx_file}", "--user",
                 f"q2={robot},{alone}", "--rl-sar", f"q2={root / 'rl_sar'},{root}"]) == 2  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "alone.onnx: no rl_sar config.yaml beside it" in err


@pytest.mark.parametrize(
    ("flags", "said"),
    [
        (["--terrain", "bogus:1"], "--terrain bogus:1: terrain kind 'bogus' is not one"),
        (["--terrain", "stairs_up:abc"], "--terrain stairs_up:abc: expected KIND:SIZE"),
        (["--terrain", "none.toml"], "--terrain none.toml: none.toml: cannot read the ranges file"),
        (["--seeds", "a-b"], "--seeds 'a-b': expected FIRST-LAST"),
        (["--command", "0.5,0"], "--command '0.5,0': expected VX,VY,YAW"),
        (["--command", "0.5,0.2,0"], "--rl-sar quad: rl_sar's loop walks at vx only"),
        (["--terrain-tiles", "2", "--terrain", "plane:0"], "--terrain-tiles 2: expected an odd"),
        (["--apply", "push"], "argument --apply: invalid choice: 'push'"),
        (["--domain", "quad=none.toml"], "--domain 'quad=none.toml': none.toml: no such file"),
    ],
)
def test_every_bad_flag_is_one_line_with_exit_2(quad, capsys, flags, said):
    """No traceback and no usage block: one line naming the flag and the value expected."""
    assert _bench(quad, *flags) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert captured.out == "" and err.count("\n") == 0, err
    assert err.startswith("python -m bench.push_reference: error: ") and said in err, err


def _standing_onnx(robot, path, blocks=None):
    """A zero-action policy of ``robot``'s default spec (with ``blocks`` in place of its
    observation blocks): it holds the home pose."""
    spec = PolicySpec.for_robot(robot, blocks=blocks)
    nodes = [helper.make_node("MatMul", ["obs", "w"], ["action"])]
    return linear_onnx(spec, path, nodes, {"w": np.zeros((spec.obs_dim, spec.act_dim), np.float32)})


def test_the_estimate_rows_are_those_of_a_policy_that_observes_the_base_velocity(tmp_path, capsys):
    """The shipped go2 with a standing policy: observing the base's linear velocity, its table has
    the own loop on our plant fed the truth and fed our estimate, the second paired with the
    first; without it, neither row."""
    go2 = load_robot("go2")
    blocks = tuple(b.name for b in PolicySpec.for_robot(go2).observation_blocks)
    with_velocity = _standing_onnx(go2, tmp_path / "v.onnx", ("base_linear_velocity", *blocks))
    without = _standing_onnx(go2, tmp_path / "p.onnx")
    flags = ["--seeds", "0-0", "--seconds", "0.3", "--no-pushes", "--robots", ""]
    assert main([*flags, "--user", f"v=go2,{with_velocity}", "--user", f"p=go2,{without}"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| v |")]
    assert [r.split(" | ")[1] for r in rows] == [
        "own (truth-fed spec)",
        "own on our plant, fed the truth",
        "own on our plant, fed our estimate",
        "our runtime",
    ]
    assert "with the row above: 1 / 0 / 0 (p = 1.000)" in rows[2]
    out = capsys.readouterr().out
    assert "| p | own on our plant" not in out


def test_the_own_loops_policy_sees_the_base_its_base_hook_writes(tmp_path):
    """OwnLoop's ``base``: the observation's base velocity is what the hook wrote after the
    truth (the estimate-fed loop's), not the truth."""
    from sim2real.stacks.loops.bare import bare_plant

    go2 = load_robot("go2")
    blocks = ("base_linear_velocity",) + tuple(
        b.name for b in PolicySpec.for_robot(go2).observation_blocks
    )
    policy = OnnxPolicy(_standing_onnx(go2, tmp_path / "v.onnx", blocks), go2)
    seen = []

    class Recording:
        spec = policy.spec

        def __call__(self, obs):
            seen.append(obs[0, :3].copy())
            return policy(obs)

    def hook(state):
        state.base.linear_velocity[:] = (0.7, -0.2, 0.1)

    plant = bare_plant(go2, (np.full(12, 20.0), np.full(12, 0.5), np.array(go2.home, float)))
    state = RobotState.legged(1, go2.n_joints, go2.n_feet)
    for base in (None, hook):
        OwnLoop(Recording(), plant, state, np.zeros((1, 3)), go2.control_period, base=base).act()
    assert np.abs(seen[0]).max() < 1e-6  # the truth: at rest
    np.testing.assert_allclose(seen[1] / seen[1][0], [1.0, -0.2 / 0.7, 0.1 / 0.7], rtol=1e-5)


def test_rl_sars_b2_runs_on_b2_xml_and_lite3_without_an_mjcf_is_refused(stacks, tmp_path):
    """The stacks' own files (their checkouts under ``SIM2REAL_STACKS``, :mod:`tests.stacks`):
    rl_sar's B2 folder (robot_lab) matches unitree_mujoco's b2.xml and stands up and walks 3 s
    at 0.5 m/s in its own loop (its meshes absent: dropped); Lite3's HIMLoco folder has no unitree_mujoco
    MJCF and is refused naming the file."""
    from sim2real.stacks.loops.himloco_terrain_loop import run

    names = ["policy/b2/base.yaml", "policy/b2/robot_lab/config.yaml"]
    names += ["policy/b2/robot_lab/policy.pt", "policy/lite3/base.yaml"]
    names += ["policy/lite3/himloco/config.yaml", "policy/lite3/himloco/policy_6_11.pt"]
    stacks.copy("rl_sar", names, tmp_path / "rl_sar")
    stacks.copy("unitree_mujoco", ["unitree_robots/b2/b2.xml"], tmp_path / "um")
    rl_sar_robot.match(tmp_path / "rl_sar", tmp_path / "um", "b2/robot_lab")
    out = run(tmp_path / "rl_sar", tmp_path / "um", None, 3.0, 0.5, key="b2/robot_lab")
    assert not out["fell"] and out["x_m"] > 0.5  # 0.75 m at e384912 (c598f10's b2.xml)
    with pytest.raises(rl_sar_robot.Mismatch, match=r"unitree_robots/lite3/lite3.xml: no such"):
        rl_sar_robot.match(tmp_path / "rl_sar", tmp_path / "um", "lite3/himloco")


def test_the_velocity_feedback_policy_sees_its_command_corrected_by_the_base_velocity(tmp_path):
    """bench.velocity_feedback_policy: the new file observes base_linear_velocity first; its
    action is the source's at the command ``cmd + K (cmd - v)`` in x and y (the yaw rate and
    everything else as observed)."""
    import onnxruntime as ort

    from bench.velocity_feedback_policy import feedback_policy

    go2 = load_robot("go2")
    spec = PolicySpec.for_robot(go2)
    w = np.random.default_rng(0).normal(0, 0.3, (spec.obs_dim, spec.act_dim)).astype(np.float32)
    source = linear_onnx(
        spec, tmp_path / "s.onnx", [helper.make_node("MatMul", ["obs", "w"], ["action"])], {"w": w}
    )
    assert feedback_policy(source, tmp_path / "v.onnx", gain=0.5) == spec.obs_dim + 3
    policy = OnnxPolicy(tmp_path / "v.onnx", go2)
    assert policy.spec.observation_blocks[0].name == "base_linear_velocity"
    inner = np.random.default_rng(1).normal(0, 1, (1, spec.obs_dim)).astype(np.float32)
    at = [b.name for b in spec.observation_blocks].index("velocity_command")
    c = sum(b.size for b in spec.observation_blocks[:at])
    v = np.array([[0.3, -0.4, 2.0]], np.float32)  # scaled as the command's entries
    run = ort.InferenceSession(str(tmp_path / "v.onnx")).run
    got = run(None, {"obs": np.concatenate([v, inner], axis=1)})[0]
    seen = inner.copy()
    seen[0, c : c + 2] += 0.5 * (inner[0, c : c + 2] - v[0, :2])
    np.testing.assert_allclose(got, seen @ w, rtol=1e-5, atol=1e-5)


def test_the_bare_loop_starts_as_our_plant_spawns_or_with_rl_sars_get_up(quad):
    """``sim2real.stacks.loops.himloco_terrain_loop``'s ``start``: ``standing`` hands the policy the robot as
    deploy-run's plant spawns it (the default pose at rest, the base level at the import's
    standing height above the tile's ground, at its centre); rl_sar's ``get-up`` (its home key
    dropped, 1 s of its fixed gains to the default pose) hands it over elsewhere (on the Go2
    2.6 cm forward and 1.5 cm lower, docs/soak.md: what decides the first-step stall). An
    unknown start is refused naming it."""
    from sim2real.stacks.loops.himloco_terrain_loop import run

    root, robot_dir, _ = quad
    height = load_robot(robot_dir).config.base.standing_height
    args = (root / "rl_sar", root / "unitree_mujoco", "stairs_up:0.10", 0.0, 0.5)
    kw = {"key": "quad/walk", "motors": robot_dir, "timestep": 0.002, "plant_of": robot_dir}
    standing = run(*args, start="standing", **kw)["start_base_m"]
    assert standing == pytest.approx([0.0, 0.0, height], abs=1e-9)
    got_up = run(*args, **kw)["start_base_m"]  # rl_sar's, the default
    assert abs(got_up[2] - height) > 0.005
    with pytest.raises(ValueError, match="start 'lying'"):
        run(*args, start="lying", **kw)


def test_the_own_loop_judges_its_robot_by_its_own_standing_height(quad):
    """rl_sar's loop of a robot judges its falls and places its standing start by that robot's
    standing height, never the Go2's: the import given, else the shipped robot of its name, else
    its MJCF's ``home`` key."""
    from sim2real.stacks.loops.himloco_terrain_loop import standing_height

    root, robot_dir, _ = quad
    ours = load_robot(robot_dir).config.base.standing_height
    assert standing_height("quad/walk", motors=robot_dir) == ours
    assert standing_height("quad/walk", unitree_mujoco=root / "unitree_mujoco") == 0.27
    go2 = load_robot("go2").config.base.standing_height
    assert standing_height("go2/himloco") == go2 != 0.27
