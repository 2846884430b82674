"""legged_gym's terrain tiles in the soak's plant (sim2real/eval/world/terrain.py): the heights its
``make_terrain`` gives at a difficulty, read back from the compiled MuJoCo height field by ray casts;
a terrain the soak cannot build refused by name; the robot put on the ground, not in it; the fall
check and the truth's fall judged against the ground under the robot, not z = 0."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.estimation.fall import FallDetector
from sim2real.eval.world.floor import apply_floor_friction, floor_geoms
from sim2real.eval.world.ranges_file import RangesError, load_ranges_text
from sim2real.eval.world.session_draw import sample_session
from sim2real.eval.world.terrain import (
    TerrainDraw,
    TerrainRanges,
    apply_terrain,
    parse_terrain,
)
from sim2real.robots import load_robot

GO2 = load_robot("go2")
HEIGHTFIELD = TerrainRanges(mesh_type="heightfield")


def compiled(draw: TerrainDraw, seed: int = 0):
    spec = GO2.mjspec("position")
    ground = apply_terrain(spec, draw, np.random.default_rng(seed))
    model = spec.compile()
    return model, mujoco.MjData(model), ground


def ray_height(model, data, x: float, y: float) -> float:
    """m, the compiled height field's top at ``(x, y)``: MuJoCo's own ray cast on it."""
    field = int(np.flatnonzero(model.geom_type == mujoco.mjtGeom.mjGEOM_HFIELD)[0])
    down = np.array([0, 0, -1.0])
    return 5.0 - mujoco.mj_rayHfield(model, data, field, np.array([x, y, 5.0]), down)


@pytest.mark.parametrize("kind, sign", [("stairs_up", 1), ("stairs_down", -1)])
def test_stairs_are_legged_gyms_step_height_at_the_level(kind, sign):
    """Row 3 of 10 (difficulty 0.3): step_height = 0.05 + 0.18 * 0.3 = 0.104 m, 20 units of
    0.005 m (legged_gym truncates): walking out from the platform, every 0.30 m step rises (up)
    or falls (down) 0.10 m, nine of them, up to the tile's rim at 0."""
    draw = TerrainDraw(kind, 0.3, 3, HEIGHTFIELD)
    model, data, _ = compiled(draw)
    mujoco.mj_forward(model, data)
    # the middles of the steps along +x (three samples each): the platform ends at 1.3 m
    xs = [0.0] + [1.4 + 0.3 * k for k in range(9)]
    heights = [ray_height(model, data, x, 0.0) for x in xs]
    rises = np.diff(heights)
    assert rises == pytest.approx([sign * 0.10] * 9, abs=1e-6)
    assert heights[-1] == pytest.approx(0.0, abs=1e-6)


def test_a_slope_has_legged_gyms_gradient_and_a_stated_angle_is_its_difficulty():
    """slope_up:15deg is difficulty tan(15 deg) / 0.4; along the tile's axis its ground rises
    by that gradient (legged_gym's slope = 0.4 * difficulty, rise over run), within one height
    unit per metre."""
    draw = parse_terrain("slope_up:15deg")
    assert draw.difficulty == pytest.approx(np.tan(np.radians(15)) / 0.4)
    draw = TerrainDraw(draw.kind, draw.difficulty, None, HEIGHTFIELD)
    model, data, ground = compiled(draw)
    mujoco.mj_forward(model, data)
    rise = ray_height(model, data, 3.5, 0.0) - ray_height(model, data, 2.5, 0.0)
    assert rise == pytest.approx(np.tan(np.radians(15)), abs=0.006)
    assert ground.height_at(3.0, 0.0) == pytest.approx(ray_height(model, data, 3.0, 0.0), abs=1e-6)


def test_a_terrain_the_soak_cannot_build_is_refused_by_name():
    with pytest.raises(ValueError, match="'gaps' is not one the soak builds"):
        parse_terrain("gaps:0.2")
    with pytest.raises(RangesError, match="terrain stepping_stones .share 0.1. is not one"):
        text = "[terrain]\nterrain_proportions = [0.1, 0.1, 0.3, 0.3, 0.1, 0.1]\n"
        load_ranges_text(text, "r.toml", GO2)
    with pytest.raises(RangesError, match="terrain.mesh: unknown key"):
        load_ranges_text("[terrain]\nmesh = 'trimesh'\n", "r.toml", GO2)
    with pytest.raises(RangesError, match="terrain.mesh_type: 'cubes' is not one the soak builds"):
        load_ranges_text("[terrain]\nmesh_type = 'cubes'\n", "r.toml", GO2)


def test_a_ranges_files_terrain_mix_is_drawn_per_session_and_replayable():
    text = "[terrain]\nterrain_proportions = [0, 0, 0.5, 0.5, 0]\nlevels = [2, 3]\n"
    ranges = load_ranges_text(text, "r.toml", GO2)
    draws = [sample_session(GO2, s, 5.0, ranges, faults=False) for s in range(12)]
    kinds = {d.terrain.kind for d in draws}
    assert kinds == {"stairs_up", "stairs_down"}
    assert {d.terrain.level for d in draws} == {2, 3}
    again = type(draws[0]).from_dict(draws[0].to_dict())
    assert again.terrain == draws[0].terrain
    flat = sample_session(GO2, 0, 5.0, load_ranges_text("", "r.toml", GO2), faults=False)
    assert flat.terrain is None and "terrain" not in flat.to_dict()


def test_a_trimesh_terrains_stairs_are_boxes_with_vertical_faces():
    """legged_gym's trimesh makes faces steeper than slope_treshold vertical: the stairs are
    boxes, each 0.30 m step 0.10 m higher within 2 cm of its edge (the platform's edge at
    1.25 m: its 26 samples of 0.1 m about x = -1.3 ... 1.2)."""
    model, data, ground = compiled(parse_terrain("stairs_up:0.10"))
    assert not model.nhfield and ground.stepped
    mujoco.mj_forward(model, data)
    for k in range(9):
        edge = 1.25 + 0.3 * k
        low, high = (ground_ray(model, data, edge + d, 0.0) for d in (-0.01, 0.01))
        assert high - low == pytest.approx(0.10, abs=1e-9)
        assert ground.height_at(edge + 0.01, 0.0) == pytest.approx(high, abs=1e-9)


def ground_ray(model, data, x: float, y: float) -> float:
    """m, the ground's top at ``(x, y)``: MuJoCo's ray cast, the robot moved out of its way."""
    data.qpos[:2] = [500.0, 500.0]
    mujoco.mj_forward(model, data)
    geom = np.zeros(1, np.int32)
    down = np.array([0, 0, -1.0])
    return 5.0 - mujoco.mj_ray(model, data, np.array([x, y, 5.0]), down, None, 1, -1, geom)


@pytest.mark.parametrize("text", ["stairs_up:0.10", "slope_up:15deg"])
def test_the_floor_friction_applies_to_the_terrain_and_its_border(text):
    model, _, _ = compiled(parse_terrain(text))
    floor = floor_geoms(model)
    on_field = text.startswith("slope")
    types = {int(mujoco.mjtGeom.mjGEOM_BOX)} | (
        {int(mujoco.mjtGeom.mjGEOM_HFIELD)} if on_field else set()
    )
    assert set(model.geom_type[floor].tolist()) == types
    assert len(floor) > 4
    robot = np.flatnonzero(model.geom_bodyid != 0)
    assert not np.isin(robot, floor).any()
    apply_floor_friction(model, 0.4)
    assert np.all(model.geom_friction[floor, 0] == 0.4)


def standing_plant(draw: TerrainDraw | None, seconds: float = 1.0):
    """The Go2 holding its home pose for ``seconds`` on ``draw``'s ground (None: the plane)."""
    spec = GO2.mjspec("position")
    ground = None if draw is None else apply_terrain(spec, draw, np.random.default_rng(0))
    plant = SimBackend(GO2, mode="position", models=[spec.compile()])
    plant.grounds = None if ground is None else [ground]
    for _ in range(int(seconds / GO2.control_period)):
        plant.write(np.asarray(GO2.home, float)[None])
        plant.advance()
    return plant, ground


@pytest.mark.parametrize("text", ["stairs_up:0.10", "stairs_down:0.10", "slope_up:15deg"])
def test_the_robot_starts_on_the_ground_and_stands_with_no_fall_signal(text):
    """Spawned on the tile's platform (0.9 m below z = 0 in the stairs-up pit, 0.9 m above
    it on the stairs-down tower), the Go2 stands at its standing height above the ground under
    it as high as on the plane; its fall check (no ground truth read) sees no tilt, low or
    sinking base."""
    flat, _ = standing_plant(None)
    plant, ground = standing_plant(parse_terrain(text))
    truth = plant.true_base_state()
    above = truth[0, 2] - plant.ground_height(truth)[0]
    assert abs(plant.ground_height(truth)[0]) > 0.4  # far from the plane z = 0
    assert above == pytest.approx(flat.true_base_state()[0, 2], abs=0.01)
    state = RobotState.legged(1, GO2.n_joints, len(GO2.foot_frame_ids))
    state.base.set_truth(truth)
    state.q[:] = plant.true_position()
    state.foot_contact[:] = 1.0
    detector = FallDetector(GO2, 1)
    for _ in range(20):
        assert not detector.check(state)[0]


def test_a_fall_on_a_slope_is_seen_by_the_fall_check():
    """On the 15-degree slope, the Go2 put on its side half-way up tips over: the fall check
    (tilt, from its own attitude) trips, and the truth lies low on the slope, not 0.3 m
    and more above z = 0 where a plane's judge would put it."""
    draw = parse_terrain("slope_down:15deg")
    spec = GO2.mjspec("position")
    ground = apply_terrain(spec, draw, np.random.default_rng(0))
    model = spec.compile()
    plant = SimBackend(GO2, mode="position", models=[model])
    plant.grounds = [ground]
    d = plant.datas[0]
    d.qpos[:3] = [2.5, 0.0, float(ground.height_at(2.5, 0.0)) + 0.3]
    d.qpos[3:7] = [np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0]  # rolled 90 degrees
    mujoco.mj_forward(model, d)
    for _ in range(50):
        plant.write(np.asarray(GO2.home, float)[None])
        plant.advance()
    truth = plant.true_base_state()
    state = RobotState.legged(1, GO2.n_joints, len(GO2.foot_frame_ids))
    state.base.set_truth(truth)
    state.q[:] = plant.true_position()
    detector = FallDetector(GO2, 1)
    assert detector.check(state)[0] and detector.signals[0, 0]  # tilt
    assert truth[0, 2] - plant.ground_height(truth)[0] < 0.5 * GO2.config.base.standing_height
    assert truth[0, 2] > GO2.config.base.standing_height


def test_the_flat_plane_is_untouched_without_terrain():
    """No terrain drawn: the plant's model is the robot's own (the plane), bit for bit."""
    a = GO2.mjspec("position").compile()
    plant = SimBackend(GO2, mode="position")
    assert plant.grounds is None
    assert plant.ground_height(plant.true_base_state()).tolist() == [0.0]
    assert plant.models[0].ngeom == a.ngeom and not plant.models[0].nhfield


def _task(tmp_path, terrain: str):
    """A legged_gym task config whose ``terrain`` class is ``terrain`` (class body lines)."""
    from tests.legged_gym_trees import write_task

    body = "\n".join(f"        {line}" for line in terrain.splitlines())
    return write_task(
        tmp_path,
        "from legged_gym.envs.base.legged_robot_config import LeggedRobotCfg\n\n"
        "class GO2RoughCfg(LeggedRobotCfg):\n"
        f"    class terrain(LeggedRobotCfg.terrain):\n{body}\n",
        "go2_config.py",
    )


def test_a_legged_gym_tasks_terrain_becomes_the_soaks_tiles(tmp_path):
    """HIMLoco's terrain class (trimesh, [0.1, 0.2, 0.3, 0.3, 0.1]) becomes the ranges file's
    [terrain] table, every level drawn; a plane gives none; a kind past legged_gym's five with
    a share is refused naming it."""
    from sim2real.eval.world.legged_gym_domain import DomainError, legged_gym_domain

    text = legged_gym_domain(
        _task(tmp_path, "mesh_type = 'trimesh'\nterrain_proportions = [0.1, 0.2, 0.3, 0.3, 0.1]")
    )
    ranges = load_ranges_text(text, "domain", GO2)
    assert ranges.terrain.terrain_proportions == (0.1, 0.2, 0.3, 0.3, 0.1)
    assert ranges.terrain.levels == (0, 9) and ranges.terrain.mesh_type == "trimesh"
    plane = legged_gym_domain(_task(tmp_path, "mesh_type = 'plane'"))
    assert load_ranges_text(plane, "domain", GO2).terrain is None
    gaps = "mesh_type = 'trimesh'\nterrain_proportions = [0.1, 0.1, 0.3, 0.2, 0.1, 0.0, 0.2]"
    with pytest.raises(DomainError, match="terrain.terrain_proportions: terrain gaps"):
        legged_gym_domain(_task(tmp_path, gaps))


def _result(terrain: dict | None, falls: int, tracked: float, any_: int) -> dict:
    """A session's result as report.json holds it (the fields the terrain rows read)."""
    return {
        "randomization": {} if terrain is None else {"terrain": terrain},
        "simulated_hours": 0.5,
        "locomotion": {
            "falls": falls,
            "running_s": 100.0,
            "tracked_s": tracked,
            "distance_m": 10.0,
        },
        "interventions": {"ticks": 1000, "any": {"count": any_}},
        "runtime": {"latched_faults": falls},
    }


def test_the_report_gives_falls_tracking_and_interventions_per_terrain_and_level():
    from sim2real.eval.report.by_terrain import terrain_lines, terrain_rows

    up3 = TerrainDraw("stairs_up", 0.3, 3).to_dict()
    slope = TerrainDraw("slope_up", 0.5, 5).to_dict()
    rows = terrain_rows(
        [_result(up3, 2, 50.0, 100), _result(up3, 0, 90.0, 0), _result(slope, 1, 80.0, 10)]
    )
    assert [(r["kind"], r["level"], r["sessions"]) for r in rows] == [
        ("slope_up", 5, 1),
        ("stairs_up", 3, 2),
    ]
    stairs = rows[1]
    assert stairs["terrain"] == "stairs_up@3"
    assert stairs["falls"] == 2 and stairs["falls_per_hour"] == pytest.approx(2.0)
    assert stairs["tracking_success"] == pytest.approx(0.7)
    assert stairs["interventions_fraction"] == pytest.approx(0.05)
    assert any("stairs_up@3" in line and "2 falls" in line for line in terrain_lines(rows))
    assert terrain_rows([_result(None, 0, 1.0, 0)]) is None  # the plane only: no rows


def test_a_clip_sessions_row_reads_no_velocity_tracking():
    """A session a motion clip commands (``commanded_by: clip``) stands on a zero command for
    the velocity tracker: its tracked time is no figure of the dance. Its terrain row counts its
    falls and interventions, and its tracking from the velocity sessions only (n/a, "a clip",
    for a row of clips alone; it read the clip's 100 % before)."""
    from sim2real.eval.report.by_terrain import terrain_lines, terrain_rows

    up3 = TerrainDraw("stairs_up", 0.3, 3).to_dict()
    slope = TerrainDraw("slope_up", 0.5, 5).to_dict()
    clip = _result(up3, 1, 100.0, 10)
    clip["locomotion"]["commanded_by"] = "clip"
    walk = _result(up3, 0, 50.0, 0)
    dance = _result(slope, 0, 100.0, 0)
    dance["locomotion"]["commanded_by"] = "clip"
    slope_row, stairs = terrain_rows([clip, walk, dance])
    assert stairs["sessions"] == 2 and stairs["falls"] == 1 and stairs["clip_sessions"] == 1
    assert stairs["tracking_success"] == pytest.approx(0.5)  # the walker's 50 of 100 s
    assert slope_row["tracking_success"] is None and slope_row["clip_sessions"] == 1
    lines = terrain_lines([slope_row, stairs])
    assert any("slope_up@5" in line and "tracking n/a (a clip)" in line for line in lines)
    assert any("stairs_up@3" in line and "tracking 50.0 %" in line for line in lines)


def test_deploy_run_refuses_terrain_off_the_simulated_legged_robot(capsys):
    """--terrain names an unknown kind, an arm, or a hardware backend: refused in one line."""
    from sim2real.deploy.cli.deploy_run import EXIT_BAD_INPUT, deploy_run_main

    for value, expected in (
        ("pits:0.2", "terrain kind 'pits' is not one the soak builds; expected one of"),
        ("stairs_up", "expected KIND:SIZE or KIND@LEVEL"),
        ("stairs_up:high", "expected KIND:SIZE (a number; slopes may end in deg)"),
        ("stairs_up@99", "KIND@LEVEL (0..9)"),
    ):  # before: argparse's 21 lines of usage and exit 2, deploy-run's code of a latched fault
        argv = ["--robot", "go2", "--policy", "x.onnx", "--terrain", value]
        assert deploy_run_main(argv) == EXIT_BAD_INPUT
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "usage" not in err, err
        assert err.startswith(f"deploy-run: error: --terrain {value}: ") and expected in err, err
    # the parser's own refusals too: one line naming the option, exit 3 (before: usage, exit 2)
    for argv, expected in (
        (["--robot", "go2", "--policy", "x.onnx", "--duration", "x"], "argument --duration"),
        (["--robot", "go2"], "one of the arguments --policy --excitation is required"),
    ):
        assert deploy_run_main(argv) == EXIT_BAD_INPUT
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("deploy-run: error: ") and expected in err
    args = type("A", (), {"terrain": parse_terrain("stairs_up:0.10"), "backend": "sim"})()
    args.command = None
    from sim2real.deploy.cli.run_checks import check_options

    with pytest.raises(ValueError, match="robot arm3 does not walk"):
        check_options(args, load_robot("arm3"))
    args.backend = "unitree"
    with pytest.raises(ValueError, match="--backend sim only"):
        check_options(args, GO2)


def test_the_truths_fall_judge_measures_the_base_above_the_ground_under_it():
    """Upright on the platform of the stairs-up pit, 0.9 m below z = 0: no true fall when the
    monitor knows the ground (the plant on terrain); judged against z = 0 it was one."""
    from types import SimpleNamespace

    from sim2real.deploy.core.state import BaseState
    from sim2real.deploy.monitors.estimation import EstimationMonitor

    plant, _ = standing_plant(parse_terrain("stairs_up:0.10"))
    truth = plant.true_base_state()
    assert truth[0, 2] < 0.0
    counts = []
    for ground in (plant.ground_height, None):
        monitor = EstimationMonitor(GO2, 1)
        monitor.ground = ground
        base = BaseState.zeros(1)
        base.set_truth(truth)
        runtime = SimpleNamespace(mode=np.full(1, 2, np.int8), state=SimpleNamespace(base=base))
        runtime.lying_expected = np.zeros(1, bool)
        monitor.update(runtime, truth)
        counts.append(int(monitor.true_falls[0]))
    assert counts == [0, 1]


def test_walking_down_stairs_with_the_rear_feet_on_the_step_above_is_no_fall():
    """HIMLoco's Go2 walking down 0.176 m steps (stairs_down@7 of its training mix, seed 9 of the
    push benchmark) at the tick its fall check stopped it: pitched 22 deg nose-down, only the
    rear feet in contact on the step above, the front feet reaching down past the step below. The
    base stood 0.27 m above the ground under it, but 0.10 m above the rear feet, so a height
    taken over the feet in contact read a collapse (under ``fall_height``, 0.12 m, for
    ``FALL_HEIGHT_TIME``). A foot lower than those in contact says the ground under the base is
    lower too: no fall signal however long the pose lasts; with the front feet drawn up to the
    rear feet's level (a base sunk onto its feet) it trips the check."""
    from sim2real.deploy.core.attitude import align_up

    gravity = np.array([0.383, -0.047, -0.923])  # the estimate's projected gravity
    gravity /= np.linalg.norm(gravity)
    feet = np.array(  # m, base frame (FL, FR, RL, RR), the estimator's kinematics
        [[0.327, 0.156, -0.277], [0.262, -0.197, -0.285], [-0.182, 0.173, -0.169],
         [-0.168, -0.163, -0.147]]
    )  # fmt: skip
    state = RobotState.legged(1, GO2.n_joints, len(GO2.foot_frame_ids))
    state.base.orientation[0] = align_up(-gravity)
    state.base.projected_gravity[0] = gravity
    state.foot_contact[0] = [0.0, 0.0, 1.0, 1.0]
    rows = {"stairs": feet, "collapsed": feet.copy()}
    level = (feet[2:] @ gravity).max()  # m, the rear feet below the base
    front = rows["collapsed"][:2]  # drawn up to the rear feet's level
    front[:, 2] = (level - front[:, :2] @ gravity[:2]) / gravity[2]
    for pose, expected in (("stairs", False), ("collapsed", True)):
        detector = FallDetector(GO2, 1)

        def positions(e: int, out: np.ndarray, pose=pose) -> bool:
            out[:] = rows[pose]
            return True

        fired = [bool(detector.check(state, positions)[0]) for _ in range(20)]
        assert fired[-1] is expected, pose
        assert detector.signals[0, 1] is np.bool_(expected)
        if expected:
            assert fired.index(True) == detector.height_ticks - 1
        else:
            assert detector.height[0] > 0.3  # the base above the lowest foot
