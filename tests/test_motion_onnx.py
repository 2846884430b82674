"""The clip BeyondMimic bakes into its exported ONNX, read into MotionClip by the metadata's names.

The files are exported here the way whole_body_tracking's ``utils/exporter.py`` exports (read,
not copied): a module whose forward returns the actor's actions and the clip's tables gathered at
``time_step`` clamped to the last frame, ``torch.onnx.export`` opset 11 with its input and output
names, then ``metadata_props`` written as ``attach_onnx_metadata`` writes them (lists
comma-joined, numbers at three decimals).
"""

from __future__ import annotations

import io
import warnings
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest

from sim2real.deploy.tasks.motion.npz_beyondmimic import BEYONDMIMIC_G1_JOINTS
from sim2real.deploy.tasks.motion.onnx_beyondmimic import read_beyondmimic_onnx_motion
from tests.test_motion_npz import SDK, one_line_refusal

torch = pytest.importorskip("torch")
OUTPUTS = ["actions", "joint_pos", "joint_vel", "body_pos_w", "body_quat_w"]
OUTPUTS += ["body_lin_vel_w", "body_ang_vel_w"]
BODIES = ["pelvis", "left_knee_link", "torso_link"]


class MotionPolicy(torch.nn.Module):
    """The exporter's module: actor plus the clip's tables (plain tensor attributes)."""

    def __init__(self, obs_dim: int, tables: dict):
        super().__init__()
        self.actor = torch.nn.Linear(obs_dim, 29)
        for name, value in tables.items():
            setattr(self, name, torch.as_tensor(value, dtype=torch.float32))
        self.time_step_total = tables["joint_pos"].shape[0]

    def forward(self, x, time_step):
        t = torch.clamp(time_step.long().squeeze(-1), max=self.time_step_total - 1)
        return (
            self.actor(x),
            self.joint_pos[t],
            self.joint_vel[t],
            self.body_pos_w[t],
            self.body_quat_w[t],
            self.body_lin_vel_w[t],
            self.body_ang_vel_w[t],
        )


def clip_tables(frames=20, seed=4) -> dict:
    rng = np.random.default_rng(seed)
    yaw = np.linspace(0.0, 1.0, frames)
    quat = np.stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], axis=1)  # w x y z
    joint_pos = rng.normal(0.0, 0.3, (frames, 29))  # BEYONDMIMIC_G1_JOINTS order
    return {
        "joint_pos": joint_pos,
        "joint_vel": np.gradient(joint_pos, 0.02, axis=0),
        "body_pos_w": rng.normal(0.0, 0.5, (frames, len(BODIES), 3)),
        "body_quat_w": np.repeat(quat[:, None], len(BODIES), axis=1),
        "body_lin_vel_w": np.zeros((frames, len(BODIES), 3)),
        "body_ang_vel_w": np.zeros((frames, len(BODIES), 3)),
    }


def csv_str(values) -> str:
    """whole_body_tracking's ``list_to_csv_str``: numbers ``{:.3f}``, strings as they are."""
    return ",".join(f"{v:.3f}" if isinstance(v, (int, float)) else str(v) for v in values)


def export(path: Path, tables: dict, outputs=OUTPUTS, drop=()) -> Path:
    module = MotionPolicy(154, tables).eval()
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            module,
            (torch.zeros(1, 154), torch.zeros(1, 1)),
            buf,
            export_params=True,
            opset_version=11,
            input_names=["obs", "time_step"],
            output_names=outputs,
            dynamic_axes={},
            dynamo=False,
        )
    model = onnx.load_from_string(buf.getvalue())
    metadata = {
        "joint_names": csv_str(BEYONDMIMIC_G1_JOINTS),
        "default_joint_pos": csv_str([0.0] * 29),
        "action_scale": csv_str([0.547546] * 29),
        "anchor_body_name": "torso_link",
        "body_names": csv_str(BODIES),
    }
    for key, value in metadata.items():
        if key not in drop:
            model.metadata_props.append(onnx.StringStringEntryProto(key=key, value=value))
    onnx.save(model, str(path))
    return path


def test_the_baked_clip_is_what_the_graph_plays_with_joints_by_name(tmp_path):
    tables = clip_tables()
    path = export(tmp_path / "policy.onnx", tables)
    clip = read_beyondmimic_onnx_motion(path, fps=50.0, robot_joints=SDK)
    columns = [BEYONDMIMIC_G1_JOINTS.index(n) for n in SDK]
    assert clip.fps == 50.0 and clip.frames == 20 and clip.joint_names == SDK
    np.testing.assert_allclose(clip.joint_pos, tables["joint_pos"][:, columns], atol=1e-6)
    np.testing.assert_allclose(clip.root_pos, tables["body_pos_w"][:, 0], atol=1e-6)
    np.testing.assert_allclose(clip.root_quat[-1], [np.cos(0.5), 0, 0, np.sin(0.5)], atol=1e-6)
    assert clip.body_names == tuple(BODIES)
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    feed = {"obs": np.zeros((1, 154), np.float32), "time_step": np.array([[7.0]], np.float32)}
    _, joint_pos, _, body_pos, body_quat, *_ = session.run(None, feed)
    np.testing.assert_allclose(clip.joint_pos[7], joint_pos[0][columns], atol=1e-6)
    np.testing.assert_allclose(clip.body_pos_w[7], body_pos[0], atol=1e-6)
    np.testing.assert_allclose(clip.body_quat_w[7], body_quat[0], atol=1e-6)


def test_a_policy_without_a_baked_clip_is_refused_naming_the_output(tmp_path):
    path = export(tmp_path / "policy.onnx", clip_tables(), outputs=["actions", "q", "dq"])
    message = one_line_refusal(lambda: read_beyondmimic_onnx_motion(path, 50.0), path, "joint_pos")
    assert "no such output" in message


def test_metadata_without_joint_names_is_refused(tmp_path):
    path = export(tmp_path / "policy.onnx", clip_tables(), drop=("joint_names",))
    one_line_refusal(lambda: read_beyondmimic_onnx_motion(path, 50.0), path, "joint_names")


def test_a_root_body_the_clip_does_not_track_is_refused(tmp_path):
    path = export(tmp_path / "policy.onnx", clip_tables())
    message = one_line_refusal(
        lambda: read_beyondmimic_onnx_motion(path, 50.0, root_body="base_link"), path, "body_names"
    )
    assert "pelvis, left_knee_link, torso_link" in message


def test_a_file_that_is_not_an_onnx_model_is_refused(tmp_path):
    path = tmp_path / "policy.onnx"
    path.write_bytes(b"\x00 not a model")
    one_line_refusal(lambda: read_beyondmimic_onnx_motion(path, 50.0), path, "file")


def test_the_baked_clip_plays_through_motion_as_its_registered_format(tmp_path):
    """deploy-run --motion policy.onnx (the exporter's file): recognised by its outputs as
    beyondmimic_onnx, played at --motion-fps, its joints by the metadata's names."""
    from sim2real.deploy.tasks.motion.formats import recognise
    from sim2real.deploy.tasks.motion.source import motion_for
    from tests.test_clip_formats import g1, synthetic_rows, tracker, write_csv

    tables = clip_tables()
    path = export(tmp_path / "policy.onnx", tables)
    policy = tracker(write_csv(synthetic_rows(frames=10), tmp_path / "dance.csv"))
    clock, _ = motion_for(policy, g1(), 1, path, fps="50")
    assert recognise(path).name == "beyondmimic_onnx" and clock.clip.fps == 50.0
    columns = [BEYONDMIMIC_G1_JOINTS.index(n) for n in SDK]
    np.testing.assert_allclose(clock.pos[7], tables["joint_pos"][7, columns], atol=1e-6)
