"""What a legged robot did on its terrain tiles (sim2real/eval/soak/terrain_figures.py): time on the
feature and on the platform, crossings and falls placed where they happened, from a scripted base
path and from a short go2 soak on a stairs tile (its report row, and a resume that keeps the
figures); and legged_gym's own cumulative rule for ``terrain_proportions``
(sim2real/eval/world/terrain_choice.py), against its ``make_terrain`` chain."""

from __future__ import annotations

import types

import numpy as np
import pytest

from sim2real.eval.soak.terrain_figures import TerrainFigures
from sim2real.eval.world.terrain import TerrainDraw, TerrainRanges, parse_terrain, sample_terrain
from sim2real.eval.world.terrain_choice import cumulative_proportions, kind_shares, legged_gym_kind
from sim2real.eval.world.tile_parts import TileLayout

DT = 0.02


class Walk:
    """A scripted base on ``layout``'s tiles, through one env's :class:`TerrainFigures`."""

    def __init__(self, layout: TileLayout):
        self.figures = TerrainFigures([layout], DT)
        self.xy, self.falls, self.t = np.zeros(2), 0, 0.0

    def to(self, x: float, y: float = 0.0, speed: float = 0.5, running: bool = True) -> None:
        """Walk in a straight line to ``(x, y)`` at ``speed`` m/s, one tick per ``DT``."""
        goal = np.array([x, y])
        step = goal - self.xy
        ticks = max(int(np.ceil(np.linalg.norm(step) / (speed * DT))), 1)
        v = step / (ticks * DT)
        for k in range(1, ticks + 1):
            self.tick(self.xy + step * k / ticks if k < ticks else goal, v, running)
        self.xy = goal

    def tick(self, xy, v=(0.0, 0.0), running=True, fall=False) -> None:
        self.falls += fall
        self.t += DT
        self.figures.step(
            np.asarray(xy, float)[None], np.asarray(v, float)[None], np.array([running]),
            np.array([self.falls]), self.t,
        )  # fmt: skip

    def teleport(self, x: float, y: float = 0.0) -> None:
        """An operator's stand-up: the base put at ``(x, y)`` while not RUNNING."""
        self.xy = np.array([x, y])
        self.tick(self.xy, running=False)


def test_a_walk_down_the_steps_and_back_is_a_crossing_out_then_in():
    """stairs_down:0.10 (one tile): the platform's last sample at 1.2 m (its boxes to 1.25 m),
    the steps to the rim at 3.95 m. Walking out at 0.5 m/s to 5 m: about 2.5 s on the platform,
    5.4 s and 2.7 m on the steps, one crossing out; back to the centre, one in."""
    walk = Walk(TileLayout.of(parse_terrain("stairs_down:0.10")))
    walk.to(5.0)
    s = walk.figures.summary(0)
    assert s["feature"] == "steps"
    assert (s["crossings_out"], s["crossings_in"]) == (1, 0)
    assert s["platform_s"] == pytest.approx(1.25 / 0.5, abs=2 * DT)
    assert s["feature_s"] == pytest.approx(2.7 / 0.5, abs=2 * DT)
    assert s["off_s"] == pytest.approx(1.05 / 0.5, abs=2 * DT)
    assert s["feature_m"] == pytest.approx(2.7, abs=0.02)
    walk.to(0.0)
    s = walk.figures.summary(0)
    assert (s["crossings_out"], s["crossings_in"]) == (1, 1)
    assert s["feature_m"] == pytest.approx(5.4, abs=0.04)


def test_onto_the_steps_and_back_crosses_nothing_and_a_fall_is_placed_where_it_happened():
    walk = Walk(TileLayout.of(parse_terrain("stairs_up:0.10")))
    walk.to(3.0)  # onto the steps, short of the rim
    walk.to(0.0, 1.0)  # back onto the platform
    s = walk.figures.summary(0)
    assert (s["crossings_out"], s["crossings_in"]) == (0, 0) and s["feature_s"] > 3.0
    walk.tick((0.0, 1.0), fall=True)  # a push fall on the platform: a platform fall
    walk.teleport(0.0)
    walk.to(0.0, -2.5)
    walk.tick((0.0, -2.5), fall=True)  # on the steps
    walk.teleport(6.0)  # slid off the tile while lying: no crossing
    walk.teleport(0.0)  # stood up at the start: no crossing either
    s = walk.figures.summary(0)
    assert s["falls_on"] == {"platform": 1, "feature": 1, "off": 0}
    assert [(p["part"], p["tile"]) for p in s["fall_places"]] == [
        ("platform", [0, 0]),
        ("feature", [0, 0]),
    ]
    assert (s["crossings_out"], s["crossings_in"]) == (0, 0)


def test_on_three_by_three_tiles_a_walk_to_the_next_platform_crosses_out_and_in():
    """From the middle tile's platform over its rim (4 m) to the next tile's centre (8 m along
    x): one crossing out of the middle tile, one in on the next ([1, 0] from the start)."""
    layout = TileLayout.of(TerrainDraw("discrete", 0.5, 5, TerrainRanges(tiles=3)))
    walk = Walk(layout)
    walk.to(8.0)
    s = walk.figures.summary(0)
    assert s["feature"] == "obstacles" and s["off_s"] == 0.0
    assert (s["crossings_out"], s["crossings_in"]) == (1, 1)
    walk.tick((8.0, 0.0), fall=True)
    assert walk.figures.summary(0)["fall_places"][0]["tile"] == [1, 0]


def test_a_slopes_platform_is_where_legged_gyms_pyramid_is_clipped():
    """pyramid_sloped_terrain clips ``x * y`` at the 3-m platform's corner: flat to 1.5 m along
    a diagonal, to 2.4 m along an axis."""
    layout = TileLayout.of(parse_terrain("slope_up:15deg"))
    tile, on = layout.locate(np.array([[1.4, 1.4], [1.6, 1.6], [2.3, 0.0], [2.6, 0.0], [5, 0]]))
    assert on.tolist() == [True, False, True, False, False]
    assert tile.tolist() == [0, 0, 0, 0, -1]


def test_the_compiled_tick_places_a_point_as_the_layout_does():
    """The kernel's place of a fall (its nearest sample, the tile, the platform's mask) is
    :meth:`TileLayout.locate`'s, on every kind and on 3 x 3 tiles."""
    rng = np.random.default_rng(0)
    for kind in ("stairs_up", "slope_down", "rough_slope", "discrete"):
        layout = TileLayout.of(TerrainDraw(kind, 0.4, 4, TerrainRanges(tiles=3)))
        figures = TerrainFigures([layout], DT)
        points = rng.uniform(-13.0, 13.0, (300, 2))
        points[:100] = np.round(points[:100] / 0.05) * 0.05  # halves of a sample: rint's ties
        for k, xy in enumerate(points):
            figures.step(xy[None], np.zeros((1, 2)), np.array([True]), np.array([k + 1]), 0.0)
        tile, on = layout.locate(points)
        parts = np.where(tile < 0, "off", np.where(on, "platform", "feature"))
        places = figures.summary(0)["fall_places"]
        assert [p["part"] for p in places] == parts.tolist()
        assert [p["tile"] for p in places] == [layout.offset(int(t)) for t in tile]


def test_the_figures_state_round_trips_per_env():
    layouts = [TileLayout.of(parse_terrain(t)) for t in ("stairs_up:0.10", "discrete:0.10")]
    a = TerrainFigures(layouts, DT)
    xy = np.array([[0.0, 0.0], [0.0, 0.0]])
    for k in range(300):
        xy += [[0.02, 0.0], [0.0, -0.03]]
        a.step(xy, np.ones((2, 2)), np.array([True, k % 7 > 0]), np.array([k // 100, 0]), k * DT)
    b = TerrainFigures(layouts, DT)
    for e in (0, 1):
        b.load_state_dict(a.state_dict(e), e)
    assert [b.summary(e) for e in (0, 1)] == [a.summary(e) for e in (0, 1)]
    assert a.summary(0)["falls_on"]["feature"] + a.summary(0)["falls_on"]["off"] == 2


# ---------------------------------------------------------------------- proportions
def make_terrain_chain(choice: float, proportions: list[float]) -> str:
    """legged_gym's ``Terrain.make_terrain`` kind choice as its source writes it (legged_gym and
    OpenRobotLab/HIMLoco ``legged_gym/utils/terrain.py``), the generators' names for its calls:
    the reference our rule must equal."""
    if choice < proportions[0]:
        return "slope_up" if choice < proportions[0] / 2 else "slope_down"
    elif choice < proportions[1]:
        return "rough_slope"
    elif choice < proportions[3]:
        return "stairs_up" if choice < proportions[2] else "stairs_down"
    elif choice < proportions[4]:
        return "discrete"
    elif choice < proportions[5]:
        return "stepping_stones"
    elif choice < proportions[6]:
        return "gaps"
    else:
        return "pits"


MIXES = (
    [0.1, 0.2, 0.3, 0.3, 0.1],  # HIMLoco's: sums to 1 + 2e-16
    [0.1, 0.1, 0.35, 0.25, 0.2],  # legged_gym's
    [0.5, 0.5, 0.5, 0.5, 0.5],  # sum > 1: the last kinds get nothing
    [0.1, 0.1, 0.3, 0.2, 0.1, 0.0, 0.1, 0.1],  # sum 1, the last three stepping, gaps, pits
    [0.1, 0.1, 0.3, 0.2, 0.1, 0.1, 0.0, 0.0],  # sum < 1 with 8: the rest to pits
    [0.2, 0.2, 0.2, 0.1, 0.1],  # sum < 1 with 5: legged_gym's IndexError past 0.8
)


@pytest.mark.parametrize("shares", MIXES)
def test_the_kind_of_a_choice_is_legged_gyms_cumulative_rule(shares):
    proportions = [np.sum(shares[: i + 1]) for i in range(len(shares))]  # legged_gym's own
    assert cumulative_proportions(shares) == proportions
    for choice in [*np.linspace(0.0, 1.0, 2001)[:-1], *proportions, 0.999999]:
        try:
            expected = make_terrain_chain(choice, proportions)
        except IndexError as exc:
            expected = f"IndexError {exc}"
        got = legged_gym_kind(float(choice), shares)
        if got.startswith("terrain_proportions["):
            got = "IndexError list index out of range"
        assert got == expected, (shares, choice)


def test_shares_under_and_over_one_give_the_last_kinds_the_rest_or_nothing():
    over = kind_shares([0.5, 0.5, 0.5, 0.5, 0.5], None)
    assert over == pytest.approx({"slope_up": 0.25, "slope_down": 0.25, "rough_slope": 0.5})
    curriculum = kind_shares([0.5, 0.5, 0.5, 0.5, 0.5], 20)
    assert curriculum == pytest.approx({"slope_up": 0.25, "slope_down": 0.25, "rough_slope": 0.5})
    assert kind_shares([0.1, 0.2, 0.3, 0.3, 0.1], 20) == pytest.approx(
        {"slope_up": 0.05, "slope_down": 0.05, "rough_slope": 0.2, "stairs_up": 0.3,
         "stairs_down": 0.3, "discrete": 0.1}
    )  # fmt: skip
    # ten columns: legged_gym's j / 10 + 0.001 puts no column below 0.05 on slope_down
    assert kind_shares([0.1, 0.2, 0.3, 0.3, 0.1], 10)["slope_up"] == pytest.approx(0.1)
    assert "slope_down" not in kind_shares([0.1, 0.2, 0.3, 0.3, 0.1], 10)
    with pytest.raises(ValueError, match=r"sums to 0\.8; .* with terrain_proportions\[5\]"):
        TerrainRanges(terrain_proportions=(0.2, 0.2, 0.2, 0.1, 0.1), curriculum=False)
    with pytest.raises(ValueError, match=r"terrain pits \(share 0\.1\) is not one"):
        TerrainRanges(terrain_proportions=(0.1, 0.1, 0.3, 0.2, 0.2, 0.0, 0.0, 0.0))
    # a curriculum of 20 columns puts none past 0.96 (its last choice is 0.951): allowed
    fine = TerrainRanges(terrain_proportions=(0.1, 0.1, 0.3, 0.3, 0.16), curriculum=True)
    assert sum(fine.kind_shares.values()) == pytest.approx(1.0)


def test_sessions_draw_kinds_by_legged_gyms_rule():
    """A share over one starves the last kinds: sessions of [0.5, 0.5, 0.5, 0.5, 0.5] walk only
    slopes, half of them rough (normalising would have given the stairs 60 %)."""
    ranges = TerrainRanges(terrain_proportions=(0.5, 0.5, 0.5, 0.5, 0.5), curriculum=False)
    kinds = [sample_terrain(np.random.default_rng(s), ranges).kind for s in range(400)]
    assert set(kinds) == {"slope_up", "slope_down", "rough_slope"}
    assert kinds.count("rough_slope") / 400 == pytest.approx(0.5, abs=0.08)
    said = ranges.describe()  # soak-test's "terrain:" line says so before it runs
    assert "rough_slope 50 %" in said and "stairs" not in said


def test_our_rule_equals_himlocos_own_make_terrain(stacks, tmp_path):
    """HIMLoco's ``make_terrain`` itself (its checkout under ``SIM2REAL_STACKS``,
    :mod:`tests.stacks`), run with its Isaac Gym generators replaced by recorders of the kind
    and sign they are called with: the kind our rule gives every choice."""
    text = stacks.read("HIMLoco", "legged_gym/legged_gym/utils/terrain.py").decode()
    text = text.replace("from isaacgym import terrain_utils", "")
    text = text.replace("from legged_gym.envs.base.legged_robot_config import LeggedRobotCfg", "")
    calls: list[str] = []

    def record(name):
        def generator(terrain, *args, **kwargs):
            sign = kwargs.get("slope", kwargs.get("step_height", 1.0))
            calls.append(name + ("-" if sign < 0 else "+"))

        return generator

    utils = types.SimpleNamespace(
        SubTerrain=lambda *a, **k: types.SimpleNamespace(),
        pyramid_sloped_terrain=record("slope"),
        random_uniform_terrain=record("rough"),
        pyramid_stairs_terrain=record("stairs"),
        discrete_obstacles_terrain=record("discrete"),
        stepping_stones_terrain=record("stepping_stones"),
    )
    ns = {"__name__": "himloco_terrain", "LeggedRobotCfg": types.SimpleNamespace(terrain=None)}
    exec(compile(text, "terrain.py", "exec"), ns)  # noqa: S102 - the stack's own source
    ns["terrain_utils"] = utils
    ns["gap_terrain"], ns["pit_terrain"] = record("gaps"), record("pits")
    ours = {"slope+": "slope_down", "slope-": "slope_up", "stairs+": "stairs_down",
            "stairs-": "stairs_up", "discrete+": "discrete", "stepping_stones+": "stepping_stones",
            "gaps+": "gaps", "pits+": "pits"}  # fmt: skip
    for shares in MIXES[:-1]:
        terrain = ns["Terrain"].__new__(ns["Terrain"])
        cfg = types.SimpleNamespace(terrain_proportions=shares, vertical_scale=0.005,
                                    horizontal_scale=0.1)  # fmt: skip
        terrain.cfg, terrain.width_per_env_pixels = cfg, 80
        terrain.proportions = [np.sum(shares[: i + 1]) for i in range(len(shares))]
        for choice in np.linspace(0.0, 1.0, 401)[:-1]:
            calls.clear()
            terrain.make_terrain(float(choice), 0.5)
            theirs = "rough_slope" if "rough+" in calls else ours[calls[0]]
            assert legged_gym_kind(float(choice), shares) == theirs, (shares, choice)


# ---------------------------------------------------------------------- a soak on a stairs tile
STAIRS_WALK = """
[terrain]
terrain_proportions = [0, 0, 0, 1, 0]
levels = [3, 3]
[commands]
vx = [0.5, 0.5]
vy = [0.0, 0.0]
yaw_rate = [0.0, 0.0]
zero_fraction = 0.0
"""


def test_a_go2_soak_down_a_stairs_tile_reports_its_figures_and_a_resume_keeps_them(
    go2_onnx, go2, tmp_path
):
    """18 s of go2 walking 0.5 m/s forward from the platform of stairs_down@3 (0.104 m steps):
    its row says how long it walked on the steps and the platform, the parts' times add up to
    its RUNNING time, its falls are all placed; resumed from its checkpoint at 12 s, the
    figures are those of the uninterrupted run."""
    from dataclasses import replace

    from sim2real.eval.report.build import build_report
    from sim2real.eval.report.by_terrain import terrain_lines
    from sim2real.eval.soak.batch import SessionBatch
    from sim2real.eval.world.ranges_file import load_ranges_text
    from tests.soak_fixtures import short_session

    ranges = load_ranges_text(STAIRS_WALK, "stairs.toml", go2, None)
    config = short_session("go2", go2_onnx, 0.005, checkpoint_minutes=0.1, ranges=ranges)
    config = replace(config, faults=False)
    whole = SessionBatch([config], tmp_path / "s", progress=False).run()[0]
    loco = whole["locomotion"]
    did = loco["on_terrain"]
    assert whole["randomization"]["terrain"]["label"] == "stairs_down@3"
    assert did["feature"] == "steps"
    parts = did["platform_s"] + did["feature_s"] + did["off_s"]
    assert parts == pytest.approx(loco["running_s"], abs=0.05)
    assert did["platform_s"] > 1.0 and did["feature_s"] > 1.0 and did["feature_m"] > 0.5
    assert sum(did["falls_on"].values()) == loco["falls"] == len(did["fall_places"])
    assert all("where" in f for f in loco["fall_records"])
    report = build_report({"robot": "go2"}, [whole])
    (row,) = report["totals"]["by_terrain"]
    assert row["terrain"] == "stairs_down@3" and row["feature_s"] == did["feature_s"]
    assert row["crossings_out"] == did["crossings_out"]
    assert any("s on the steps" in line for line in terrain_lines([row]))
    resumed = SessionBatch([config], tmp_path / "s", resume=True, progress=False)
    assert resumed.rt.time == pytest.approx(12.0)
    again = resumed.run()[0]
    assert again["locomotion"]["on_terrain"] == did
    assert {k: v for k, v in again.items() if k != "wall"} == {
        k: v for k, v in whole.items() if k != "wall"
    }
