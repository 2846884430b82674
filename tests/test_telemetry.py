"""MCAP telemetry: the raw per-stage topics and Foxglove's well-known schemas read back."""

import json

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.observe.telemetry import Telemetry
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.runtime import Runtime
from tests.runtime_fixtures import adversarial_onnx, shipped_onnx

pytest.importorskip("foxglove_schemas_protobuf", reason="the foxglove extra is not installed")
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms  # noqa: E402
from foxglove_schemas_protobuf.JointStates_pb2 import JointStates  # noqa: E402
from foxglove_schemas_protobuf.Log_pb2 import Log  # noqa: E402
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate  # noqa: E402
from mcap.reader import make_reader  # noqa: E402

RAW_TOPICS = {"/read", "/estimate", "/infer", "/guard", "/smooth", "/thermal", "/state"}


def run(tmp_path, robot, mode, ticks, telemetry=None, envs=1, name="adv.onnx"):
    policy = OnnxPolicy(adversarial_onnx(tmp_path, robot, mode, name=name), robot)
    backend = SimBackend(robot, mode=mode, envs=envs, seed=3)
    rt = Runtime(robot, policy, backend, telemetry=telemetry)
    rt.start()
    rt.run(ticks)
    return rt


def read(path):
    """{topic: [(log_time_ns, schema name, schema encoding, data)]}"""
    out = {}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            out.setdefault(channel.topic, []).append(
                (message.log_time, schema.name, schema.encoding, message.data)
            )
    return out


# The tests reading the module fixture recorded: on one pytest-xdist worker (make test's
# --dist loadgroup), which builds it once, not once per worker.
ON_ONE_WORKER = pytest.mark.xdist_group("recorded")


@pytest.fixture(scope="module")
def recorded(tmp_path_factory, arm3):
    """A 2 s position-mode run of the adversarial policy (it leans on the guard), every 5th tick
    sampled, a small ring buffer so that the flush runs several times."""
    tmp = tmp_path_factory.mktemp("telemetry")
    path = tmp / "run.mcap"
    tel = Telemetry(
        path, 1, arm3.n_joints, every=5, capacity=16, robot=arm3, control_mode="position"
    )
    rt = run(tmp, arm3, "position", 400, telemetry=tel)
    tel.close()
    return rt, path, read(path)


@ON_ONE_WORKER
def test_end_effector_frame_transforms_equal_forward_kinematics_of_the_logged_joints(
    recorded, arm3
):
    _, _, topics = recorded
    states = {t: JointStates.FromString(d) for t, _, _, d in topics["/joint_states"]}
    estimates = {t: json.loads(d)["q"][0] for t, _, _, d in topics["/estimate"]}
    tf = topics["/tf"]
    assert len(tf) == 400 // 5
    ee = arm3.pin_model.frames[arm3.ee_frame_id].name
    checked = 0
    for t, _, _, data in tf:
        msg = FrameTransforms.FromString(data)
        (pose,) = [x for x in msg.transforms if x.child_frame_id == ee]
        assert pose.parent_frame_id == "world"
        assert pose.timestamp.seconds * 10**9 + pose.timestamp.nanos == t
        q = np.array([j.position for j in states[t].joints])
        np.testing.assert_array_equal(q, estimates[t])  # the same logged estimate
        fk = arm3.forward_kinematics(q)
        p = pose.translation
        np.testing.assert_allclose([p.x, p.y, p.z], fk, atol=1e-12)
        r = pose.rotation
        assert abs(r.x**2 + r.y**2 + r.z**2 + r.w**2 - 1.0) < 1e-12
        checked += 1
    assert checked == 80
    # one transform per link body plus the end-effector site, all in world
    names = {x.child_frame_id for x in FrameTransforms.FromString(tf[0][3]).transforms}
    assert names == {"base", "link1", "link2", "link3", ee}


@ON_ONE_WORKER
def test_foxglove_topics_have_the_well_known_schemas_and_the_raw_topics_stay(recorded, arm3):
    _, _, topics = recorded
    schema = {topic: (rows[0][1], rows[0][2]) for topic, rows in topics.items()}
    assert schema["/joint_states"] == ("foxglove.JointStates", "protobuf")
    assert schema["/joint_commands"] == ("foxglove.JointStates", "protobuf")
    assert schema["/tf"] == ("foxglove.FrameTransforms", "protobuf")
    assert schema["/robot"] == ("foxglove.SceneUpdate", "protobuf")
    assert schema["/guard_events"] == ("foxglove.Log", "protobuf")
    assert RAW_TOPICS <= set(topics)
    first = JointStates.FromString(topics["/joint_states"][0][3])
    assert [j.name for j in first.joints] == list(arm3.joint_names)
    # position mode: the command is a position, equal to the raw /smooth topic
    commands = JointStates.FromString(topics["/joint_commands"][-1][3])
    smooth = json.loads(topics["/smooth"][-1][3])["command"][0]
    assert [j.position for j in commands.joints] == smooth
    assert not any(j.HasField("velocity") for j in commands.joints)
    (scene,) = topics["/robot"]
    entities = SceneUpdate.FromString(scene[3]).entities
    assert {e.frame_id for e in entities} >= {"link1", "link2", "link3"}
    assert all(e.frame_locked for e in entities)
    # the adversarial policy's targets beyond the soft limits are clamped: WARNING events
    logs = [Log.FromString(d) for _, _, _, d in topics["/guard_events"]]
    assert any(x.level == Log.WARNING and "soft_limit" in x.message for x in logs)


def test_scene_geometry_frames_are_the_kinematics_frames(arm3):
    """The scene's geoms are MuJoCo's, locked to Pinocchio's body frames: both must agree."""
    import pinocchio as pin

    m = mujoco.MjModel.from_xml_path(str(arm3.mjcf_path))
    d = mujoco.MjData(m)
    q = np.array([0.3, -0.7, 1.1])
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    data = arm3.pin_model.createData()
    pin.framesForwardKinematics(arm3.pin_model, data, q)
    for name in ("link1", "link2", "link3"):
        placement = data.oMf[arm3.pin_model.getFrameId(name)]
        np.testing.assert_allclose(placement.translation, d.body(name).xpos, atol=1e-12)
        np.testing.assert_allclose(placement.rotation, d.body(name).xmat.reshape(3, 3), atol=1e-12)


def test_several_envs_prefix_frames_and_joints(tmp_path, arm3):
    path = tmp_path / "two.mcap"
    tel = Telemetry(path, 2, arm3.n_joints, every=10, robot=arm3, control_mode="velocity")
    run(tmp_path, arm3, "velocity", 40, telemetry=tel, envs=2)
    tel.close()
    topics = read(path)
    msg = FrameTransforms.FromString(topics["/tf"][0][3])
    assert {"env0/link3", "env1/link3", "env1/ee"} <= {x.child_frame_id for x in msg.transforms}
    states = JointStates.FromString(topics["/joint_commands"][0][3])
    assert [j.name for j in states.joints][3] == "env1/shoulder"
    assert all(j.HasField("velocity") for j in states.joints)  # velocity mode


def test_telemetry_leaves_the_run_bit_for_bit_identical(tmp_path, arm3):
    plain = run(tmp_path, arm3, "position", 200)
    tel = Telemetry(tmp_path / "x.mcap", 1, arm3.n_joints, every=1, capacity=32, robot=arm3)
    logged = run(tmp_path, arm3, "position", 200, telemetry=tel, name="b.onnx")
    tel.close()
    for a, b in ((plain.state.q, logged.state.q), (plain.command, logged.command)):
        np.testing.assert_array_equal(a, b)
    assert (plain.guard.count_matrix == logged.guard.count_matrix).all()


def test_deploy_run_telemetry_on_a_floating_base_robot(tmp_path, go2):
    """``deploy-run --telemetry`` on the Go2: a complete MCAP whose ``/tf`` poses are forward
    kinematics of the logged joints with the logged estimate of the base's orientation."""
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    policy = adversarial_onnx(tmp_path, go2, "position")
    path = tmp_path / "go2.mcap"
    code = deploy_run_main(
        ["--robot", "go2", "--policy", str(policy), "--command", "0.5,0,0"]
        + ["--duration", "0.5", "--telemetry", str(path)]
    )
    assert code in (0, 2) and path.exists() and not path.with_name("go2.mcap.part").exists()
    topics = read(path)
    estimates = {t: json.loads(d) for t, _, _, d in topics["/estimate"]}
    foot = "FL_foot"
    data = go2.pin_model.createData()
    checked = 0
    for t, _, _, raw in topics["/tf"]:
        poses = {x.child_frame_id: x for x in FrameTransforms.FromString(raw).transforms}
        q, wxyz = estimates[t]["q"][0], estimates[t]["base_orientation"][0]
        r = poses["base"].rotation
        np.testing.assert_allclose([r.w, r.x, r.y, r.z], wxyz, atol=1e-12)
        configuration = go2.pin_configuration(np.array(q), None, np.array(wxyz))
        pin.framesForwardKinematics(go2.pin_model, data, configuration)
        p = poses[foot].translation
        expected = data.oMf[go2.pin_model.getFrameId(foot, pin.FrameType.BODY)].translation
        np.testing.assert_allclose([p.x, p.y, p.z], expected, atol=1e-12)
        checked += 1
    assert checked >= 2


def test_a_legged_runs_telemetry_carries_the_base_estimate_beside_the_truth(tmp_path, go2):
    """``/estimate`` has the base's projected gravity, linear and angular velocity; ``/truth``
    (simulation) the simulator's, stamped alike: a user plots one against the other. The
    shipped Go2 walking: the logged estimate follows the logged truth."""
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    policy = shipped_onnx("go2", tmp_path)
    path = tmp_path / "go2.mcap"
    code = deploy_run_main(
        ["--robot", "go2", "--policy", str(policy), "--command", "0.5,0,0"]
        + ["--duration", "6", "--telemetry", str(path)]
    )
    assert code == 0 and path.exists()
    topics = read(path)
    est = {t: json.loads(d) for t, _, _, d in topics["/estimate"]}
    true = {t: json.loads(d) for t, _, _, d in topics["/truth"]}
    assert set(est) == set(true) and len(true) > 20
    late = [t for t in true if t > 3e9]  # walking
    g_e = np.array([est[t]["projected_gravity"][0] for t in late])
    g_t = np.array([true[t]["projected_gravity"][0] for t in late])
    v_e = np.array([est[t]["linear_velocity"][0] for t in late])
    v_t = np.array([true[t]["linear_velocity"][0] for t in late])
    assert np.degrees(np.arccos(np.clip((g_e * g_t).sum(1), -1, 1))).mean() < 2.0
    assert abs(v_e[:, 0].mean() - v_t[:, 0].mean()) < 0.05 and v_t[:, 0].mean() > 0.3
    assert all(0.1 < true[t]["height"][0] < 0.4 for t in late)
