"""robot-import keeps an MJCF's explicit ``<contact><pair>``s with their own friction and solver
settings (following the geoms' new names) and its ``<exclude>``s; pairs naming the scene's
floor keep working on the importer's floor, which takes that name."""

from __future__ import annotations

import re

import numpy as np
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.robots import load_robot
from sim2real.robots.importer.pipeline import EXIT_REFUSED
from tests.import_fixtures import humanoid_with, import_tiny

pytest.importorskip("coal")


def pair_only_humanoid(folder, ground: str = "ground", extra: str = ""):
    """The test humanoid written as mjlab/Menagerie write G1: the foot spheres named and touching
    only through explicit pairs with the scene's floor (``ground``, not in the file)."""
    pairs = "".join(
        f'<pair geom1="sole{k}" geom2="{ground}" condim="3" friction="0.7 0.7 0.005 0.0001 '
        f'0.0001" solref="0.008 1" margin="0.001"/>'
        for k in range(8)
    )
    exclude = '<exclude body1="left_hip_roll_link" body2="right_hip_roll_link"/>'
    source = humanoid_with(folder, f"<contact>{pairs}{extra}{exclude}</contact>")
    count = iter(range(100))

    def named(match: re.Match) -> str:
        return f'<geom name="sole{next(count)}" contype="0" conaffinity="0" size="0.005"'

    source.write_text(re.sub(r'<geom size="0\.005"', named, source.read_text()))
    return source


def test_explicit_pairs_are_kept_with_their_settings_on_the_named_floor(tmp_path, capsys):
    code, out = import_tiny(pair_only_humanoid(tmp_path), tmp_path)
    assert code == 0
    printed = capsys.readouterr().out
    assert "name ['ground'], a geom of the scene" in printed
    assert "8 <contact><pair>s kept" in printed
    robot = load_robot(out)  # Pinocchio parses the file with its pairs
    model = robot.mj_model
    assert model.npair == 8 and model.geom("ground").type == 0  # the importer's plane, renamed
    names = {model.geom(int(g)).name for g in [*model.pair_geom1, *model.pair_geom2]}
    assert "ground" in names
    names.discard("ground")
    # the geoms were renamed (<body>_<k>): the pairs follow them
    assert names <= {model.geom(g).name for g in range(model.ngeom)} and "sole0" not in names
    assert {model.body(int(model.geom(n).bodyid[0])).name for n in names} == {
        "left_ankle_link",
        "right_ankle_link",
    }
    np.testing.assert_allclose(model.pair_friction[:, :2], 0.7)
    np.testing.assert_allclose(model.pair_solref[:, 0], 0.008)
    np.testing.assert_allclose(model.pair_margin, 0.001)
    assert set(model.pair_dim) == {3}
    # the <exclude> stays: the plant never checks the two hip links
    excluded = {(int(s) >> 16, int(s) & 0xFFFF) for s in model.exclude_signature}
    left, right = model.body("left_hip_roll_link").id, model.body("right_hip_roll_link").id
    assert (min(left, right), max(left, right)) in excluded
    # the feet touch the floor only through the pairs: the robot stands on them
    plant = SimBackend(robot, envs=1)
    plant.reset()
    for _ in range(100):
        plant.advance()
    assert np.all(np.isfinite(plant.true_position())) and plant.datas[0].qpos[2] > 0.5


def test_pairs_naming_several_scene_geoms_are_refused_in_one_line(tmp_path, capsys):
    extra = '<pair geom1="sole0" geom2="stairs"/>'
    code, out = import_tiny(pair_only_humanoid(tmp_path, extra=extra), tmp_path)
    assert code == EXIT_REFUSED
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "['ground', 'stairs']" in err and "import the scene file" in err
    assert not out.exists()
