"""robot-import keeps the integrator and solver settings of the description's ``<option>`` and
takes a training stack's with ``--option KEY=VALUE``; the plant runs what the robot file says."""

from __future__ import annotations

import mujoco
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.cli.robot_import import main
from sim2real.robots import load_robot
from sim2real.robots.importer.pipeline import EXIT_REFUSED
from tests.import_fixtures import humanoid_with, import_tiny
from tests.test_import_humanoid import FLAGS, write_humanoid


def test_the_mjcfs_integrator_and_solver_settings_are_kept_and_flags_win(tmp_path, capsys):
    option = '<option integrator="Euler" iterations="12"/>'
    source = humanoid_with(tmp_path, option, before="<worldbody>")
    code, out = import_tiny(source, tmp_path, "--option", "ls_iterations=20")
    assert code == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if "physics:" in ln)
    assert "integrator Euler (the MJCF)" in line and "iterations 12 (the MJCF)" in line
    assert "ls_iterations 20 (--option)" in line
    model = SimBackend(load_robot(out), envs=1).models[0]
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER
    assert (model.opt.iterations, model.opt.ls_iterations) == (12, 20)
    # without an <option>: the toolkit's implicit-fast integrator, MuJoCo's iterations
    plain = tmp_path / "robots" / "plain"
    assert main([str(write_humanoid(tmp_path / "p")), "--out", str(plain), *FLAGS]) == 0
    assert "integrator implicitfast (the toolkit's default)" in capsys.readouterr().out
    model = SimBackend(load_robot(plain), envs=1).models[0]
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    assert model.opt.iterations == 100


@pytest.mark.parametrize(
    "flag, message",
    [
        ("substeps=4", "unknown key 'substeps'"),
        ("integrator=RK5", "expected one of ['Euler', 'RK4', 'implicit', 'implicitfast']"),
        ("iterations=ten", "expected an integer"),
        ("iterations", "expected KEY=VALUE"),
    ],
)
def test_a_bad_option_is_refused_in_one_line(tmp_path, capsys, flag, message):
    code, out = import_tiny(write_humanoid(tmp_path), tmp_path, "--option", flag)
    assert code == EXIT_REFUSED
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and message in err and not out.exists()


def test_a_robot_file_whose_pairs_name_the_scenes_floor_imports(tmp_path, capsys):
    """Published robot files meant to be included in a scene name its floor in their contact
    pairs (MuJoCo refuses the file alone); a legged import stands the importer's floor in for
    it (the robot stands on it), a fixed-base import says to import the scene, in one line."""
    import numpy as np

    pairs = '<contact><pair geom1="left_sole" geom2="floor" friction="0.6 0.6"/></contact>'
    source = humanoid_with(tmp_path, pairs)
    text = source.read_text().replace(
        '<geom size="0.005"', '<geom name="left_sole" size="0.005"', 1
    )
    source.write_text(text)
    code, out = import_tiny(source, tmp_path)
    assert code == 0
    assert "pair>s name ['floor'], a geom of the scene" in capsys.readouterr().out
    robot = load_robot(out)
    plant = SimBackend(robot, envs=1)
    plant.reset()
    for _ in range(50):
        plant.advance()
    assert np.all(np.isfinite(plant.true_position())) and plant.datas[0].qpos[2] > 0.5
    fixed = [str(source), "--out", str(tmp_path / "arm"), "--motor", "*=h1_hip"]
    assert main(fixed) == EXIT_REFUSED
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "import the scene file" in err and "['floor']" in err


def test_the_mjcfs_timestep_and_flags_are_kept_and_the_flag_wins(tmp_path, capsys):
    """A training stack's MJCF that states its timestep and turns eulerdamp off: the plant steps
    at that timestep with that flag; --physics-timestep still wins; a timestep that does not
    divide the control period is refused in one line."""
    option = '<option timestep="0.005" integrator="Euler"><flag eulerdamp="disable"/></option>'
    source = humanoid_with(tmp_path, option, before="<worldbody>")
    code, out = import_tiny(source, tmp_path)
    assert code == 0
    assert "timestep 0.005 s (the MJCF)" in capsys.readouterr().out
    robot = load_robot(out)
    assert robot.physics_timestep == 0.005
    model = SimBackend(robot, envs=1).models[0]
    assert model.opt.timestep == 0.005
    assert model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_EULERDAMP
    flagged = tmp_path / "robots" / "flagged"
    assert main([str(source), "--out", str(flagged), *FLAGS, "--physics-timestep", "0.001"]) == 0
    assert "timestep 0.001 s (--physics-timestep)" in capsys.readouterr().out
    assert load_robot(flagged).physics_timestep == 0.001
    odd = source.read_text().replace('timestep="0.005"', 'timestep="0.003"')
    source.write_text(odd)
    assert main([str(source), "--out", str(tmp_path / "odd"), *FLAGS]) == EXIT_REFUSED
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "timestep='0.003'" in err and "--physics-timestep" in err
