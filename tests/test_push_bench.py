"""The push benchmark (``python -m bench.push_reference``): a policy's own loop on the true state
and our runtime take the same push at the same time of the same clock, and the table counts what
a user reads from it (pushes survived before the fatal one, the paired sign test)."""

from __future__ import annotations

import numpy as np
import pytest

from bench.push_loops import runtime_loop, truth_loop
from bench.push_reference import Entry, _load, sign_test, summary, survived
from sim2real.eval.world.pushes import PushRanges, push_velocity
from sim2real.stacks.loops.bare import QUIET_AFTER_PUSH, Run, past_hard_limit, quiet
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


def test_on_terrain_ours_is_judged_above_the_ground_and_each_seed_draws_its_tile(tmp_path):
    """--terrain: the shipped go2 in the 1.26-m pit of a stairs-up tile (level 5) walks 1 s in
    our runtime without a fall (a plane's judge would see its base 1 m under z = 0 and call it
    fallen at once); a ranges file's [terrain] gives each seed its own draw, the same one each
    time it is asked (both loops of a seed lay the same tile)."""
    from argparse import Namespace

    from bench.push_reference import terrain_of
    from sim2real.eval.world.terrain import parse_terrain

    go2 = Entry("go2", "go2", shipped_onnx("go2", tmp_path))
    robot, policy = _load(go2)
    pit = parse_terrain("stairs_up@5")
    ours = runtime_loop(robot, policy, 0, 1.0, None, [0.3, 0.0, 0.0], terrain=pit)
    assert ours.fell_at is None and ours.ticks > 0
    mix = tmp_path / "mix.toml"
    mix.write_text("[terrain]\nterrain_proportions = [0.1, 0.2, 0.3, 0.3, 0.1]\nlevels = [0, 9]\n")
    args = Namespace(terrain=str(mix), terrain_tiles=3)
    draws = [terrain_of(s, args) for s in range(12)]
    assert draws == [terrain_of(s, args) for s in range(12)]
    assert len({d.label for d in draws}) > 3 and all(d.ranges.tiles == 3 for d in draws)
    assert terrain_of(0, Namespace(terrain="stairs_down:0.10", terrain_tiles=1)).kind == (
        "stairs_down"
    )


def test_a_level_base_collapsing_vertically_is_no_upright_stop():
    """The bench's upright-stop rule is the soak's ``false_fall_stops``: a level base at its
    standing height is upright while still, not while sinking at 0.5 m/s or faster."""
    from sim2real.robots import load_robot
    from sim2real.stacks.loops.bare import true_upright

    go2 = load_robot("go2")
    level, height = np.array([1.0, 0.0, 0.0, 0.0]), go2.config.base.standing_height
    assert true_upright(go2, height, level)
    assert true_upright(go2, height, level, vz=-0.2)  # a walking base's bob
    assert not true_upright(go2, height, level, vz=-0.8)
