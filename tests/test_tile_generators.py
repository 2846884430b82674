"""The terrain tiles are a registry, not chains on their names
(:mod:`sim2real.eval.world.tile_generators`): legged_gym's kinds are registered with every part,
a generator missing one is refused by name, and a kind made up here is stated, laid out, put in
the plant and walked on by deploy-run with no other file edited."""

import json

import mujoco
import numpy as np
import pytest

from sim2real.eval.world.terrain import apply_terrain, ground_map, parse_terrain
from sim2real.eval.world.terrain_tiles import KINDS, square_platform
from sim2real.eval.world.tile_generators import (
    PARTS,
    TILE_GENERATORS,
    TileGenerator,
    register_tile_generator,
    tile_kinds,
)
from sim2real.eval.world.tile_parts import TileLayout
from sim2real.robots import load_robot

#: m, the made-up ridge's height at difficulty 1.
RIDGE = 0.2


def _ridge(hf, difficulty, hs, vs, rng):
    """A ridge across the tile (along y) at 2 m from its centre, ``RIDGE * difficulty`` high."""
    n = hf.shape[0]
    at = n // 2 + int(round(2.0 / hs))
    hf[at : at + int(round(0.4 / hs)), :] = int(round(RIDGE * difficulty / vs))


RIDGE_TILE = TileGenerator(
    "ridge",
    _ridge,
    square_platform,
    "ridge",
    lambda d: f"{RIDGE * d:.3g}",
    lambda text: float(text) / RIDGE,
)


@pytest.fixture
def scoped():
    with TILE_GENERATORS.scoped():
        yield


def test_legged_gyms_kinds_are_registered_and_a_part_missing_is_named(scoped):
    assert set(KINDS) <= set(tile_kinds())  # every kind terrain_proportions draws is built
    assert {"name", "build", "platform", "feature", "size", "difficulty"} == set(PARTS)
    from dataclasses import replace

    for part in PARTS[1:]:
        with pytest.raises(ValueError, match=rf"terrain kind 'ridge': .*missing \['{part}'\]"):
            register_tile_generator(replace(RIDGE_TILE, **{part: None}))
    with pytest.raises(ValueError, match="terrain kind 'stairs_up' is registered already"):
        register_tile_generator(replace(RIDGE_TILE, name="stairs_up"))


def test_a_made_up_tile_kind_is_stated_laid_out_and_walked_on(scoped, tmp_path, go2_onnx):
    with pytest.raises(ValueError, match="terrain kind 'ridge' is not one the soak builds"):
        parse_terrain("ridge:0.1")
    register_tile_generator(RIDGE_TILE)  # the registration line
    draw = parse_terrain("ridge:0.1")
    assert (draw.kind, draw.difficulty, draw.label) == ("ridge", 0.5, "ridge:0.1")
    ground = ground_map(draw, np.random.default_rng(0))
    assert ground.height_at(2.2, 0.0) == pytest.approx(0.1)  # on the ridge
    assert ground.height_at(0.0, 0.0) == 0.0 and ground.height_at(-2.2, 0.0) == 0.0
    layout = TileLayout.of(draw)
    assert layout.feature == "ridge"
    tile, on_platform = layout.locate(np.array([[0.0, 0.0], [2.2, 0.0]]))
    assert tile.tolist() == [0, 0] and on_platform.tolist() == [True, False]
    # in the plant: a height field whose top is the ridge (MuJoCo's own ray cast)
    go2 = load_robot("go2")
    spec = go2.mjspec("position")
    apply_terrain(spec, draw, np.random.default_rng(0))
    model = spec.compile()
    data = mujoco.MjData(model)
    data.qpos[:2] = [500.0, 500.0]  # the robot out of the ray's way
    mujoco.mj_forward(model, data)
    geom = np.zeros(1, np.int32)
    down = np.array([0.0, 0.0, -1.0])
    top = 5.0 - mujoco.mj_ray(model, data, np.array([2.2, 0.0, 5.0]), down, None, 1, -1, geom)
    assert top == pytest.approx(0.1, abs=1e-6)
    # deploy-run --terrain walks the go2 on it
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    report = tmp_path / "run.json"
    argv = ["--backend", "sim", "--robot", "go2", "--policy", str(go2_onnx)]
    argv += ["--terrain", "ridge:0.1", "--command", "0.5,0,0", "--duration", "1.5"]
    assert deploy_run_main([*argv, "--report", str(report)]) == 0
    loco = json.loads(report.read_text())["locomotion"]
    assert loco["falls"] == 0 and loco["distance_m"] > 0.2
