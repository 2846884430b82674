"""A soak session walking its terrain as legged_gym's curriculum does
(sim2real/eval/soak/curriculum_walk.py): the ground is its kind's column of legged_gym's map (one
tile per level along x), the robot starts at its level's tile centre, each episode's end moves
its level by legged_gym's ``_update_terrain_curriculum`` rule and respawns it on that level's
tile; from a legged_gym config tree written in ``tmp_path`` (HIMLoco's layout) to a go2 soak's
figures, and a resume that keeps them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim2real.eval.soak.curriculum_walk import CurriculumWalk
from sim2real.eval.world.terrain import TerrainDraw, TerrainRanges, ground_map, sample_terrain
from sim2real.eval.world.terrain_tiles import difficulty_terms
from sim2real.eval.world.tile_parts import TileLayout

#: A curriculum walk of stairs down, 4 levels, one tile across (small and quick).
WALK = TerrainRanges(
    terrain_proportions=(0.0, 0.0, 0.0, 1.0, 0.0), num_rows=4, num_cols=1, tiles=1,
    walk="curriculum", episode_length_s=20.0,
)  # fmt: skip


def _walk(level: int, seed: int = 0) -> CurriculumWalk:
    draw = TerrainDraw("stairs_down", level / WALK.num_rows, level, WALK)
    ground = ground_map(draw, np.random.default_rng(0))
    return CurriculumWalk(
        [TileLayout.of(draw)], [level], [ground], WALK, 0.02, [np.random.default_rng(seed)]
    )


def test_the_ground_is_the_kinds_column_one_level_per_row_and_the_start_its_levels_centre():
    """Row ``i`` of the column is level ``i`` (legged_gym's ``difficulty = i / num_rows``): its
    steps ``0.05 + 0.18 i / 4`` m high; the world origin (the spawn) is the centre of the drawn
    level's tile, on its platform; a grid walk's ground is unchanged (one tile, its level)."""
    draw = TerrainDraw("stairs_down", 2 / 4, 2, WALK)
    ground = ground_map(draw, np.random.default_rng(0))
    layout = TileLayout.of(draw)
    assert (layout.rows, layout.cols, layout.start) == (4, 1, (2, 0))
    n = layout.n
    border = round((ground.heights.shape[0] - 4 * n) / 2)
    for i in range(4):
        tile = ground.heights[border + i * n : border + (i + 1) * n, border : border + n]
        steps = np.unique(np.round(np.diff(np.unique(tile)), 4))
        assert steps == pytest.approx([difficulty_terms(i / 4)["step_height"]], abs=0.005)
    tile, on = layout.locate(np.zeros(2))
    assert (int(tile), bool(on)) == (2, True)
    assert layout.centre(2, 0) == pytest.approx([0.0, 0.0])
    assert layout.centre(3, 0) - layout.centre(2, 0) == pytest.approx([8.0, 0.0])
    grid = dataclasses.replace(draw, ranges=dataclasses.replace(WALK, walk="grid"))
    assert ground_map(grid, np.random.default_rng(0)).heights.shape == (2 * border + n,) * 2


@pytest.mark.parametrize(
    "level, end_xy, command, expected",
    [
        (1, (4.01, 0.0), (0.0, 0.0), (2, 1)),  # over terrain_length / 2 = 4 m: up
        (1, (3.9, 0.0), (0.5, 0.0), (0, -1)),  # under 0.5 m/s * 20 s / 2 = 5 m: down
        (1, (3.9, 0.0), (0.3, 0.0), (1, 0)),  # over 0.3 * 20 / 2 = 3 m, under 4 m: stays
        (0, (0.5, 0.5), (0.2, 0.1), (0, -1)),  # down from level 0: stays at 0 (clipped)
    ],
)  # fmt: skip
def test_the_rule_is_legged_gyms_update_terrain_curriculum(level, end_xy, command, expected):
    """legged_gym ``_update_terrain_curriculum`` (HIMLoco legged_robot.py:557-576): the
    distance from the tile's centre against ``terrain_length / 2`` and against half of the
    command's distance over the episode's nominal length."""
    walk = _walk(level)
    centre = walk.centre[0]
    assert walk.next_level(0, centre + np.array(end_xy), np.array(command)) == expected


def test_past_the_last_level_a_robot_goes_to_a_uniform_level():
    """``torch.randint_like(levels, max_terrain_level)``: from the env's own stream."""
    walk = _walk(3, seed=7)
    level, move = walk.next_level(0, walk.centre[0] + [5.0, 0.0], np.zeros(2))
    assert move == 1 and level == int(np.random.default_rng(7).integers(4))


def test_a_legged_gym_configs_curriculum_is_walked_and_sessions_start_on_their_level(tmp_path):
    """The legged_gym reader on HIMLoco's layout (a task inheriting its terrain class) writes a
    curriculum walk of ``env.episode_length_s`` (legged_gym's 20 s where the tree sets none,
    named as its documented default; the config's own when it sets one) and names where each
    came from; its sessions' start tile is their drawn level's."""
    from sim2real.eval.world.domain import domain_account, legged_gym_domain
    from sim2real.eval.world.ranges_file import load_ranges_text
    from sim2real.robots import load_robot
    from tests.test_legged_gym_tree import himloco_tree

    task = himloco_tree(tmp_path / "a")
    text = legged_gym_domain(task)
    terrain = load_ranges_text(text, "himloco", load_robot("go2")).terrain
    assert (terrain.walk, terrain.episode_length_s, terrain.num_rows) == ("curriculum", 20.0, 10)
    account = domain_account(text)
    assert any(
        a.startswith('# from: terrain.walk = "curriculum" <- terrain.curriculum True')
        for a in account
    )
    assert any("episode_length_s = 20 <- legged_gym's env.episode_length_s 20 (documented default)"
               in a for a in account)  # fmt: skip
    base = task.parents[1] / "base" / "legged_robot_config.py"
    base.write_text(base.read_text().replace(
        "class LeggedRobotCfg(BaseConfig):\n",
        "class LeggedRobotCfg(BaseConfig):\n    class env:\n        episode_length_s = 12\n", 1,
    ))  # fmt: skip
    text = legged_gym_domain(task)
    assert load_ranges_text(text, "himloco", load_robot("go2")).terrain.episode_length_s == 12.0
    assert any("episode_length_s = 12 <- env.episode_length_s 12 (legged_gym/envs/base/"
               "legged_robot_config.py:" in a for a in domain_account(text))  # fmt: skip
    for seed in range(5):
        draw = sample_terrain(np.random.default_rng(seed), terrain)
        layout = TileLayout.of(draw)
        assert layout.start == (draw.level, terrain.tiles // 2)
        assert int(layout.locate(np.zeros(2))[0]) == draw.level * terrain.tiles + terrain.tiles // 2


#: A go2 walking forward on a curriculum walk of discrete obstacles, 4 levels, 5-s episodes.
WALK_TOML = """
[terrain]
terrain_proportions = [0.0, 0.0, 0.0, 0.0, 1.0]
num_rows = 4
num_cols = 1
levels = [1, 1]
tiles = 1
walk = "curriculum"
episode_length_s = 5.0

[commands]
vx = [0.5, 0.5]
vy = [0.0, 0.0]
yaw_rate = [0.0, 0.0]
zero_fraction = 0.0
"""


def test_a_go2_soak_walks_its_episodes_respawns_on_its_level_and_a_resume_keeps_it(
    go2_onnx, go2, tmp_path
):
    """18 s of go2 on ``discrete`` level 1 in 5-s episodes: a timed-out robot that walked less
    than half its command's distance goes down a level and is put at rest within 1 m (x and y)
    of that level's tile centre, on the ground there, with a new command, the carry no
    crossing; the session's result counts its episodes (3 timeouts), the rule's moves, and the
    seconds on each level, which add up to its time on the tiles; the report's line says so;
    resumed from its checkpoint at 12 s, the result is the uninterrupted run's."""
    from sim2real.eval.report.build import build_report
    from sim2real.eval.report.by_terrain import terrain_lines
    from sim2real.eval.soak.batch import SessionBatch
    from sim2real.eval.world.ranges_file import load_ranges_text
    from tests.soak_fixtures import short_session

    ranges = load_ranges_text(WALK_TOML, "walk.toml", go2, None)
    config = short_session("go2", go2_onnx, 0.005, checkpoint_minutes=0.1, ranges=ranges)
    config = dataclasses.replace(config, faults=False)
    batch = SessionBatch([config], tmp_path / "respawn", progress=False)
    walk, layout = batch.curriculum, batch.terrain_figures.layouts[0]
    assert walk.level[0] == 1 and walk.centre[0] == pytest.approx([0.0, 0.0])
    # at the centre under 0.5 m/s: under half of 0.5 * 5 m walked, down to level 0, 8 m back
    batch.rt.velocity_command[0, :2] = [0.5, 0.0]
    batch.stand_up(np.array([True]), end="timeout")
    truth = batch.backend.true_base_state(np.zeros((1, 13)))[0]
    assert layout.centre(0, 0) == pytest.approx([-8.0, 0.0])
    assert walk.level[0] == 0 and np.abs(truth[:2] - layout.centre(0, 0)).max() <= 1.0
    assert tuple(walk.moves[0]) == (0, 1) and tuple(walk.ended[0]) == (1, 0)
    ground = batch.backend.grounds[0]
    assert truth[2] - float(ground.height_at(truth[0], truth[1])) > 0.2  # on its feet, not in
    assert batch.task.schedule.t_command[0] == -np.inf  # a new command at its next tick
    batch.rt.run(50, on_tick=batch.on_tick)  # RUNNING again at once: the carry crossed nothing
    assert batch.rt.mode[0] == 2 and tuple(batch.terrain_figures.crossings[0]) == (0, 0)

    result = SessionBatch([config], tmp_path / "s", progress=False).run()[0]
    did = result["locomotion"]["on_terrain"]
    cur = did["curriculum"]
    assert cur["ended_by"]["timeout"] == 3 and cur["first_level"] == 1
    assert cur["moved_up"] + cur["moved_down"] + cur["stayed"] == cur["episodes_ended"]
    on_tiles = did["platform_s"] + did["feature_s"]
    assert sum(v["s"] for v in cur["levels"].values()) == pytest.approx(on_tiles, abs=0.05)
    assert sum(v["episodes"] for v in cur["levels"].values()) == cur["episodes_ended"] + 1
    report = build_report({"robot": "go2"}, [result])
    (row,) = report["totals"]["by_terrain"]
    line = [x for x in terrain_lines([row]) if "curriculum walk" in x]
    assert len(line) == 1 and "3 timeouts of 5 s" in line[0]
    resumed = SessionBatch([config], tmp_path / "s", resume=True, progress=False)
    assert resumed.rt.time == pytest.approx(12.0)
    again = resumed.run()[0]
    assert {k: v for k, v in again.items() if k != "wall"} == {
        k: v for k, v in result.items() if k != "wall"
    }


def test_our_rule_equals_himlocos_own_update_terrain_curriculum(stacks):
    """HIMLoco's ``_update_terrain_curriculum`` itself (its checkout under ``SIM2REAL_STACKS``,
    :mod:`tests.stacks`), run with torch on 200 episodes' ends (levels below the last, whose
    move past it is a random level): the levels and the tile centres ours gives."""
    import ast
    import types

    import torch

    text = stacks.read("HIMLoco", "legged_gym/legged_gym/envs/base/legged_robot.py").decode()
    cls = next(n for n in ast.parse(text).body if getattr(n, "name", "") == "LeggedRobot")
    fn = next(f for f in cls.body if getattr(f, "name", "") == "_update_terrain_curriculum")
    space = {"torch": torch}
    exec(compile(ast.Module([fn], []), "legged_robot.py", "exec"), space)  # noqa: S102
    rng = np.random.default_rng(3)
    n, walk = 200, _walk(1)
    layout = walk.layouts[0]
    levels = rng.integers(0, WALK.num_rows - 1, n)
    origins = np.array([[layout.centre(i, 0) for _ in range(1)] for i in range(WALK.num_rows)])
    ends = origins[levels, 0] + rng.uniform(-6, 6, (n, 2))
    commands = rng.uniform(-1, 1, (n, 3))
    himloco = types.SimpleNamespace(
        init_done=True, terrain=types.SimpleNamespace(env_length=WALK.terrain_length),
        max_episode_length_s=WALK.episode_length_s, max_terrain_level=WALK.num_rows,
        terrain_levels=torch.tensor(levels), terrain_types=torch.zeros(n, dtype=torch.long),
        terrain_origins=torch.tensor(np.concatenate([origins, np.zeros((4, 1, 1))], -1)),
        root_states=torch.tensor(np.concatenate([ends, np.zeros((n, 11))], 1)),
        env_origins=torch.tensor(np.concatenate([origins[levels, 0], np.zeros((n, 1))], 1)),
        commands=torch.tensor(commands),
    )  # fmt: skip
    space["_update_terrain_curriculum"](himloco, torch.arange(n))
    for k in range(n):
        walk.level[0], walk.centre[0] = levels[k], origins[levels[k], 0]
        level, _ = walk.next_level(0, ends[k], commands[k, :2])
        assert level == int(himloco.terrain_levels[k]), k
        assert layout.centre(level, 0) == pytest.approx(himloco.env_origins[k, :2].numpy())
