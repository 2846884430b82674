"""The push benchmark (``python -m bench.push_reference``): a policy's own loop on the true state
and our runtime take the same push at the same time of the same clock, and the table counts what
a user reads from it (pushes survived before the fatal one, the paired sign test)."""

from __future__ import annotations

import numpy as np
import pytest

from bench.push_loops import (
    QUIET_AFTER_PUSH,
    Run,
    past_hard_limit,
    quiet,
    runtime_loop,
    truth_loop,
)
from bench.push_reference import Entry, _load, sign_test, summary, survived
from sim2real.eval.world.pushes import PushRanges, push_velocity
from tests.runtime_fixtures import shipped_onnx


def test_the_own_loop_and_the_runtime_are_pushed_alike(tmp_path):
    """The shipped go2 walking at 0.5 m/s, one 0.5-m/s push at 1 s as a force over 0.1 s: both
    loops push at 1.0 s on their clock (the policy's gait clock) and walk on; ours is judged on
    its estimate in the second after it and counts its interventions per RUNNING tick."""
    pushes = PushRanges(interval=1.0, max_velocity=0.5)
    go2 = Entry("go2", "go2", shipped_onnx("go2", tmp_path))  # a fresh clone has no go2.onnx
    robot, policy = _load(go2)
    own = truth_loop(robot, policy, 3, 1.6, pushes, [0.5, 0.0, 0.0])
    robot, policy = _load(go2)
    ours = runtime_loop(robot, policy, 3, 1.6, pushes, [0.5, 0.0, 0.0])
    assert own.pushes == ours.pushes == [pytest.approx(1.0)]
    assert own.fell_at is None and ours.fell_at is None
    assert ours.after_push["ticks"] == 30 and ours.after_push["mean_m_s"] < 0.3
    assert 0 <= ours.intervened <= ours.ticks and ours.ticks >= 75
    assert np.linalg.norm(push_velocity(3, 1, 0.5)) > 0.2  # a push that moves the robot


def test_pushes_survived_leave_out_the_fatal_one_and_the_sign_test_pairs_seeds():
    """A run that fell counts the pushes before the one that felled it; one that walked on
    counts them all; falls per hour are over the time walked."""
    fell = Run(fell_at=12.0, walked=12.0, pushes=[5.0, 10.0])
    walked = Run(walked=60.0, pushes=[5.0 * k for k in range(1, 12)])
    assert survived(fell) == 1 and survived(walked) == 11
    s = summary([fell, walked])
    assert s["survived"] == 12 and s["falls"] == 1
    assert s["falls_per_hour"] == pytest.approx(3600.0 / 72.0)
    same, fewer, more, p = sign_test([3, 2, 5, 1], [3, 1, 4, 1])
    assert (same, fewer, more) == (2, 2, 0) and p == pytest.approx(0.5)


def test_the_table_counts_ticks_past_a_hard_limit_and_undisturbed_walking_apart(go2):
    """A joint a hair past its hard limit counts, one at it does not; a tick is undisturbed
    before the first push and more than QUIET_AFTER_PUSH after the last; the summary sums the
    ticks past a limit over the runs, with the pushes applied, and takes the interventions of
    undisturbed walking over its own ticks."""
    q = go2.home.copy()
    assert not past_hard_limit(go2, q)
    q[1] = go2.position_upper[1]
    assert not past_hard_limit(go2, q)
    q[1] += 1e-6
    assert past_hard_limit(go2, q)
    assert quiet(3.0, []) and not quiet(3.0, [2.0]) and quiet(2.0 + QUIET_AFTER_PUSH + 0.02, [2.0])
    runs = [
        Run(walked=10.0, pushes=[5.0], past_limit=4, quiet_ticks=400, quiet_intervened=2),
        Run(walked=10.0, pushes=[5.0, 9.0], past_limit=2, quiet_ticks=100, quiet_intervened=3),
    ]
    s = summary(runs)
    assert s["past_limit"] == 6 and s["pushes"] == 3
    assert s["quiet"] == pytest.approx(5 / 500)
