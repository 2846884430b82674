"""The push benchmark for a whole-body tracking policy (``bench.push_reference --tracking``): rl_sar's
own loop on the true state and our runtime with the tracking task take the same pushes after the
same frames of the clip. rl_sar's dance_102 on unitree_mujoco's G1, read from the mirrors (skipped
without them: ``SIM2REAL_STACKS``, :mod:`tests.stacks`)."""

from __future__ import annotations

import numpy as np

from bench.push_reference import Entry, _load
from bench.push_tracking import tracking_runtime_loop
from sim2real.eval.world.pushes import PushRanges
from sim2real.stacks.loops.rl_sar_pushed import rl_sar_loop
from tests.motion_files import G1_FLAGS, dance_folder, g1_xml


def test_both_loops_take_the_same_pushes_after_the_same_clip_frames(stacks, tmp_path):
    """1.5 s of the dance, a push every 0.5 s (0.3 m/s at most, added): in each loop two pushes,
    after the same frames (those at 0.5 and 1.0 s of the clip), and neither falls."""
    from sim2real.deploy.cli.robot_import import main as robot_import
    from sim2real.deploy.export.folder_torchscript import export_folder_torchscript

    dance = dance_folder(stacks, tmp_path)
    xml = g1_xml(stacks, tmp_path)
    export_folder_torchscript(dance / "policy.pt")
    out = tmp_path / "robots" / "g1"
    flags = [str(xml), *G1_FLAGS, "--drive-from", str(dance / "policy.pt"), "--out", str(out)]
    assert robot_import(flags) == 0
    robot, policy = _load(Entry("dance", str(out), dance / "policy.onnx", tracking=dance))
    pushes = PushRanges(interval=(0.5, 0.5), mode="add", x=(-0.3, 0.3), y=(-0.3, 0.3))
    own = rl_sar_loop(robot, dance, 4, 1.5, pushes)
    ours = tracking_runtime_loop(robot, policy, 4, 1.5, pushes)
    assert own.fell_at is None and ours.fell_at is None
    assert own.walked == ours.walked == 1.5
    np.testing.assert_allclose(own.pushes, [0.5, 1.0], atol=1e-9)
    np.testing.assert_allclose(ours.pushes, own.pushes, atol=1e-9)
