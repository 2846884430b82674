"""The clip formats deploy-run --motion plays (sim2real.deploy.tasks.motion.formats): an rl_sar CSV,
a BeyondMimic NPZ written as whole_body_tracking's csv_to_npz.py writes it and a holosoma NPZ in its
converter's layout (the writers of tests/test_motion_npz.py) each resolve to their reader and give
the motion clock the same joints by name; a file no format recognises is refused in one line naming
the file and the formats known. The robot and the policy are the G1's joint names and a tracking
spec's blocks (no stacks needed); deploy-run on unitree_mujoco's G1 is in test_motion_tracking.py.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from sim2real.deploy.spec.foreign.contract import MotionSource
from sim2real.deploy.tasks.motion.clip import ClipError
from sim2real.deploy.tasks.motion.formats import clip_formats, recognise
from sim2real.deploy.tasks.motion.npz_beyondmimic import BEYONDMIMIC_G1_JOINTS
from sim2real.deploy.tasks.motion.source import motion_for
from tests.test_motion_npz import SDK, csv_to_npz, synthetic_rows, write_holosoma


def g1() -> SimpleNamespace:
    """The G1's 29 joints in unitree's motor order, wide limits, home at 0."""
    n = len(SDK)
    return SimpleNamespace(
        name="g1", joint_names=SDK, position_lower=np.full(n, -3.0),
        position_upper=np.full(n, 3.0), home=np.zeros(n),
    )  # fmt: skip


def tracker(csv: Path, metadata=None) -> SimpleNamespace:
    """A tracking policy as motion_for reads one: a motion_command block, an rl_sar contract
    naming ``csv`` at 60 Hz with unitree's motor order as its columns, ``metadata``."""
    spec = SimpleNamespace(
        observation_blocks=[SimpleNamespace(name="motion_command")], joint_names=SDK
    )
    contract = SimpleNamespace(motion=MotionSource(str(csv), 60.0, SDK), source="config.yaml")
    return SimpleNamespace(spec=spec, foreign=contract, metadata=metadata or {})


def write_csv(rows: np.ndarray, path: Path) -> Path:
    path.write_text("\n".join(",".join(f"{v:.9f}" for v in r) for r in rows) + "\n")
    return path


def test_each_format_plays_through_its_reader_with_joints_by_name(tmp_path):
    """The same motion as rl_sar's CSV (60 Hz, motor order) and as csv_to_npz.py's NPZ (50 Hz,
    articulation order): both clocks hold the robot's joints in its order, equal at the first
    frame; holosoma's NPZ names its own joints."""
    rows = synthetic_rows(frames=61)
    csv = write_csv(rows, tmp_path / "dance.csv")
    npz = csv_to_npz(rows, tmp_path / "dance.npz")
    holo = write_holosoma(tmp_path / "holo.npz")
    robot = g1()
    clocks = {p.name: motion_for(tracker(csv), robot, 1, p)[0] for p in (csv, npz, holo)}
    assert {recognise(p).name for p in (csv, npz, holo)} == {
        "rl_sar_csv", "beyondmimic_npz", "holosoma_npz"
    }  # fmt: skip
    assert [c.clip.fps for c in clocks.values()] == [60.0, 50.0, 30.0]
    np.testing.assert_allclose(clocks["dance.csv"].pos[0], rows[0, 7:], atol=1e-8)
    np.testing.assert_allclose(clocks["dance.npz"].pos[0], rows[0, 7:], atol=1e-8)
    expected = np.load(holo)["joint_pos"][0, 7:]
    np.testing.assert_allclose(clocks["holo.npz"].pos[0], expected, atol=1e-12)


def test_a_beyondmimic_npz_takes_its_column_names_from_the_policys_metadata_first(tmp_path):
    """An Isaac Lab export's ``joint_names`` metadata names the NPZ's columns (here the
    articulation order reversed: the clock's joints come out reversed), before the G1's."""
    rows = synthetic_rows(frames=30)
    csv = write_csv(rows, tmp_path / "dance.csv")
    npz = csv_to_npz(rows, tmp_path / "dance.npz")
    articulation = [SDK.index(n) for n in BEYONDMIMIC_G1_JOINTS]
    reversed_names = ",".join(BEYONDMIMIC_G1_JOINTS[::-1])
    clock, _ = motion_for(tracker(csv, {"joint_names": reversed_names}), g1(), 1, npz)
    np.testing.assert_allclose(
        clock.pos[0][articulation][::-1], rows[0, 7:][articulation], atol=1e-8
    )


def test_a_beyondmimic_npz_of_unknown_joints_is_refused_not_guessed(tmp_path):
    """Without the policy's joint_names metadata, only the G1's 29 columns are known."""
    rows = synthetic_rows(frames=30)
    csv = write_csv(rows, tmp_path / "dance.csv")
    npz = csv_to_npz(rows, tmp_path / "dance.npz", joint_pos=np.zeros((30, 23)))
    message = one_line(lambda: motion_for(tracker(csv), g1(), 1, npz))
    assert message.startswith(f"{npz}: joint_names: BeyondMimic's NPZ names no joints")


def one_line(call) -> str:
    with pytest.raises(ClipError) as err:
        call()
    message = str(err.value)
    assert "\n" not in message
    return message


@pytest.mark.parametrize(
    "name, write",
    [
        ("clip.bvh", lambda p: p.write_text("HIERARCHY\n")),
        ("clip.npz", lambda p: np.savez(p, frames=np.zeros((3, 4)))),
        ("clip.npz", lambda p: p.write_text("not a zip")),
        ("clip.onnx", lambda p: p.write_bytes(b"\x00\x01")),
    ],
)
def test_a_file_no_format_recognises_is_refused_naming_the_formats_known(tmp_path, name, write):
    path = tmp_path / name
    write(path)
    csv = write_csv(synthetic_rows(frames=10), tmp_path / "dance.csv")
    message = one_line(lambda: motion_for(tracker(csv), g1(), 1, path))
    assert message.startswith(f"{path}: format: no clip format recognises it")
    assert all(f"{f} (" in message for f in clip_formats())


def test_a_rate_flag_for_a_file_that_states_its_rate_is_refused(tmp_path):
    """--motion-fps overrides a contract's rate, never the rate a BeyondMimic NPZ states."""
    rows = synthetic_rows(frames=30)
    csv = write_csv(rows, tmp_path / "dance.csv")
    npz = csv_to_npz(rows, tmp_path / "dance.npz")
    message = one_line(lambda: motion_for(tracker(csv), g1(), 1, npz, fps="30"))
    assert message.startswith(f"{npz}: fps: the file states its rate (50 Hz)")


def test_a_clip_joint_the_robot_lacks_is_refused_by_name(tmp_path):
    csv = write_csv(synthetic_rows(frames=10), tmp_path / "dance.csv")
    holo = write_holosoma(tmp_path / "h.npz", joints=(*SDK[:-1], "tail_joint"))
    message = one_line(lambda: motion_for(tracker(csv), g1(), 1, holo))
    assert message == f"{holo}: joint_names: joints ['tail_joint'] are no joints of 'g1'"


def test_an_exports_motion_metadata_names_the_clip_when_no_contract_is_read(tmp_path):
    """A re-exported tracking ONNX (its spec stored, no contract read): the ``motion`` entry
    names the clip beside the file, its rate and columns; an entry without columns is refused."""
    rows = synthetic_rows(frames=30)
    write_csv(rows, tmp_path / "dance.csv")
    entry = {"file": "dance.csv", "sha256": "0", "fps": 50.0, "timing": "rl_sar"}
    policy = tracker(tmp_path / "dance.csv")
    policy.foreign, policy.path = None, tmp_path / "policy.g1.onnx"
    policy.metadata = {"motion": json.dumps({**entry, "columns": list(SDK)})}
    clock, _ = motion_for(policy, g1(), 1)
    assert clock.clip.source == tmp_path / "dance.csv" and clock.clip.fps == 50.0
    np.testing.assert_allclose(clock.pos[0], rows[0, 7:], atol=1e-8)
    policy.metadata = {"motion": json.dumps(entry)}
    message = one_line(lambda: motion_for(policy, g1(), 1))
    assert message.startswith(f"{policy.path}: metadata 'motion': expected JSON with file, fps")
