"""A soak's falls replayed in the policy's own loop and with other sensor noise
(:mod:`sim2real.eval.soak.fall_replay`)."""

from __future__ import annotations

import copy

import numpy as np
import pytest

H1_2 = "tests/data/unitree_rl_gym/h1_2/h1_2.onnx"


#: The tests of :func:`pushed_h1_2` on one pytest-xdist worker (make test's --dist loadgroup): its
#: session runs once, not on each worker.
ON_ONE_WORKER = pytest.mark.xdist_group("pushed_h1_2")


@pytest.fixture(scope="module")
def pushed_h1_2(tmp_path_factory):
    """H1-2 seed 1 in its training domain (legged_gym's pushes), 7 s: pushed at 5 s, it falls
    (the fall check's stop before 6 s)."""
    from sim2real.eval.soak.batch import SessionBatch
    from sim2real.eval.soak.session import SessionConfig
    from sim2real.eval.world.domain import training_domain
    from sim2real.eval.world.ranges_file import load_ranges_text
    from sim2real.robots import load_robot

    ranges = load_ranges_text(training_domain(H1_2), H1_2, load_robot("h1_2"), None)
    config = SessionConfig(robot="h1_2", policy=H1_2, seed=1, hours=1.0, ranges=ranges)
    batch = SessionBatch([config], tmp_path_factory.mktemp("own"), progress=False)
    batch.rt.run(int(round(7.0 / batch.dt)), on_tick=batch.on_tick)
    return batch


@ON_ONE_WORKER
def test_a_fall_is_replayed_in_the_policys_own_loop_from_the_seconds_before_it(pushed_h1_2):
    """The fall check's fall carries its replays: the own loop's, each from a capture 2-6 s
    before the stop (the push among them), each falling after the push as the session did
    (legged_gym's H1-2 falls under these pushes in unitree_rl_gym's own loop too); the
    runtime's with other sensor-noise draws from 4 s before; the result counts them."""
    from sim2real.eval.soak.counterfactual import HORIZON
    from sim2real.eval.soak.fall_replay import CAPTURE_PERIOD, LEAD, REDRAW_LEAD, REDRAWS
    from sim2real.eval.soak.falls import fall_replays

    batch = pushed_h1_2
    log = batch.task.parts()["tracker"].fall_log[0]
    falls = [r for r in log if r["cause"] == "fall"]
    assert len(falls) == 1
    t, own, push = falls[0]["t_s"], falls[0]["own_loop"], batch.pushes.times[0][0]
    assert push < t
    assert len(own["from_s"]) >= 2 and len(own["fall_s"]) == len(own["from_s"])
    early, late = t - max(LEAD) - CAPTURE_PERIOD, t - min(LEAD)
    assert all(early <= s <= late and s < push for s in own["from_s"])
    assert all(f is not None and push < f <= t + HORIZON for f in own["fall_s"])
    redraw = falls[0]["redraw"]
    assert t - REDRAW_LEAD - CAPTURE_PERIOD <= redraw["from_s"] <= t - REDRAW_LEAD
    assert len(redraw["fall_s"]) == REDRAWS
    assert all(f is None or push < f <= t + HORIZON for f in redraw["fall_s"])
    assert len(set(redraw["fall_s"])) > 1  # other noise: not the session's one run again
    fell = sum(f is not None for f in redraw["fall_s"])
    n = len(own["fall_s"])
    assert fall_replays(log) == {
        "falls": 1, "own_loop": n, "own_loop_fell": n, "redraw": REDRAWS, "redraw_fell": fell
    }  # fmt: skip


@ON_ONE_WORKER
def test_the_own_loop_replay_carries_the_worlds_push(pushed_h1_2):
    """The same replay with the push taken out of the twin's world stands past the stop's
    horizon: the replay's fall is the push's, not a defect of the own loop."""
    from sim2real.eval.soak.counterfactual import HORIZON
    from sim2real.eval.soak.fall_replay import own_loop

    batch = pushed_h1_2
    fall = next(r for r in batch.task.parts()["tracker"].fall_log[0] if r["cause"] == "fall")
    arrays, meta = batch.fall_replay.captures[0][0]
    assert meta["tick"] * batch.dt <= fall["own_loop"]["from_s"][0]
    twin = batch.stop_replay.copy_of(0)
    until = fall["t_s"] + HORIZON
    twin.restore(arrays, copy.deepcopy(meta), "test")
    ticks, now = twin.rt.ticks, twin.rt.time
    assert own_loop(twin, until) is not None  # with the push: it falls
    assert (twin.rt.ticks, twin.rt.time) == (ticks, now)  # the own loop ran on its own clock
    twin.restore(arrays, copy.deepcopy(meta), "test")
    twin.pushes = None  # the world without the training domain's pushes
    assert own_loop(twin, until) is None


def test_no_replay_starts_before_a_previous_fall_or_stand_up(tmp_path):
    """H1-2 seed 1 in its training domain, stood up 1 s after each stop, 32 s: falls at 5.9,
    21.1, 25.4 and 31.8 s (with the push on the base alone: a hard-limit stop at 20.6 s, falls at
    25.4 and 31.1 s). Every replay starts after the stop before its fall (the
    captures before it are of another stretch of running): the fall 4.9 s after the stop has no
    capture 2-6 s before it in its own stretch and is not replayed; the next one replays from
    its own stretch only (before, they were replayed from 19-20 s and 25 s, across the stops,
    and "fell" at the previous fall)."""
    from sim2real.eval.soak.batch import SessionBatch
    from sim2real.eval.soak.session import SessionConfig
    from sim2real.eval.world.domain import training_domain
    from sim2real.eval.world.ranges_file import load_ranges_text
    from sim2real.robots import load_robot

    ranges = load_ranges_text(training_domain(H1_2), H1_2, load_robot("h1_2"), None)
    config = SessionConfig(
        robot="h1_2", policy=H1_2, seed=1, hours=1.0, ranges=ranges, operator_reset=1.0
    )
    batch = SessionBatch([config], tmp_path, progress=False)
    batch.rt.run(int(round(32.0 / batch.dt)), on_tick=batch.on_tick)
    log = batch.task.parts()["tracker"].fall_log[0]
    assert len(log) >= 3 and log[0]["cause"] == "fall"
    replayed = 0
    for before, record in zip(log[:-1], log[1:], strict=True):
        starts = list(record.get("own_loop", {}).get("from_s", []))
        if "redraw" in record:
            starts.append(record["redraw"]["from_s"])
        assert all(s > before["t_s"] for s in starts), (before["t_s"], record)
        replayed += bool(starts)
    assert log[2]["cause"] == "fall" and log[2]["own_loop"]["from_s"] == []
    assert replayed >= 1  # a fall far enough after its stand-up is still replayed


@ON_ONE_WORKER
def test_a_fallen_robots_interventions_are_counted_apart_from_a_standing_ones(pushed_h1_2):
    """The pushed H1-2 falls before 6 s and lies damped to 7 s: the interventions of the ticks it
    lay (the guard's hard-limit check on its folded legs among them) are in ``while_down``, of
    the lying ticks; the headline counts and fractions are of the ticks it stood, and the two
    make up every tick and every intervention (before, 7 s of it shared one fraction)."""
    from sim2real.eval.soak.result import session_result

    batch = pushed_h1_2
    iv = batch.interventions
    result = session_result(batch.sessions[0])["interventions"]
    down = result["while_down"]
    lying = int(np.count_nonzero(batch.rt.mode[:1] >= 3))  # SAFE_STOP or FAULTED now
    assert lying == 1 and 0 < down["ticks"] < iv.ticks
    assert result["ticks"] + down["ticks"] == iv.ticks
    assert result["any"]["count"] + down["any"]["count"] == int(iv.any[0])
    for check, entry in result["checks"].items():
        assert entry["count"] + down["checks"][check]["count"] == int(iv.counts[check][0])
    assert down["any"]["count"] > 0
    assert down["any"]["fraction"] == pytest.approx(down["any"]["count"] / down["ticks"])
    assert result["any"]["fraction"] == pytest.approx(result["any"]["count"] / result["ticks"])


def test_a_fall_replay_on_terrain_rebuilds_the_sessions_own_tiles(tmp_path, go2_onnx):
    """A Go2 session on a stairs-down tower (its platform 1.26 m above z = 0): the one-session
    copy the fall replays run in has the session's very ground (the same tile geoms and
    height field, the same ground heights), not a flat plane; the own loop replayed from a
    capture stands on the tower, its base judged above the ground under it, where the
    session's base is."""
    from sim2real.eval.soak.batch import SessionBatch
    from sim2real.eval.soak.fall_replay import own_loop
    from sim2real.eval.soak.session import SessionConfig
    from sim2real.eval.world.ranges_file import load_ranges_text
    from sim2real.robots import load_robot

    text = "[terrain]\nterrain_proportions = [0, 0, 0, 1, 0]\nlevels = [5, 5]\n"
    ranges = load_ranges_text(text, "terrain.toml", load_robot("go2"), None)
    config = SessionConfig(robot="go2", policy=str(go2_onnx), seed=3, hours=1.0, ranges=ranges)
    batch = SessionBatch([config], tmp_path / "s", progress=False)
    batch.rt.run(int(round(2.5 / batch.dt)), on_tick=batch.on_tick)
    twin = batch.stop_replay.copy_of(0)
    ours, theirs = batch.backend.models[0], twin.backend.models[0]
    assert ours.ngeom == theirs.ngeom and ours.nhfield == theirs.nhfield
    assert np.array_equal(ours.geom_pos, theirs.geom_pos)
    assert np.array_equal(ours.geom_size, theirs.geom_size)
    assert np.array_equal(ours.hfield_data, theirs.hfield_data)
    xy = np.random.default_rng(0).uniform(-4.0, 4.0, (20, 2))
    mine, copy_ = batch.backend.grounds[0], twin.backend.grounds[0]
    assert np.array_equal(mine.height_at(xy[:, 0], xy[:, 1]), copy_.height_at(xy[:, 0], xy[:, 1]))
    assert mine.height_at(0.0, 0.0) > 0.5  # the tower's top, far from the plane z = 0
    arrays, meta = batch.fall_replay.captures[0][-1]
    twin.restore(arrays, copy.deepcopy(meta), "test")
    start = meta["tick"] * batch.dt
    assert own_loop(twin, start + 1.0) is None  # stands on the tower: no fall judged
    base = twin.backend.true_base_state()[0]
    assert base[2] - twin.backend.ground_height(twin.backend.true_base_state())[0] > 0.1
    assert base[2] > 1.0  # on the tower (1.26 m), not dropped to a plane at z = 0
