"""unitree_mujoco's elastic band in the Unitree emulator's plant: the gantry holds a limp humanoid
until its release, then lets it fall; a bad ``--band`` is refused in one line."""

from __future__ import annotations

import numpy as np
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.backends.unitree.emulator.band import ElasticBand, parse_band
from sim2real.robots import load_robot


def _pelvis_heights(band, seconds=2.5):
    """The base's height (m) at 0.5 s steps of a limp H1 (every joint torque 0) on the band
    ``(length, release)`` (None: no band); the band's clock runs from 0."""
    robot = load_robot("h1")
    plant = SimBackend(robot, mode="torque")
    hang = ElasticBand(plant, *band) if band else None
    dt, heights = robot.control_period, []
    for k in range(int(round(seconds / dt))):
        if hang is not None:
            hang.apply(k * dt)
        plant.write(np.zeros((1, robot.n_joints)))
        plant.advance()
        if (k + 1) % int(round(0.5 / dt)) == 0:
            heights.append(float(plant.true_base_state()[0, 2]))
    return heights, hang


def test_the_band_holds_a_limp_humanoid_until_it_is_released():
    free, _ = _pelvis_heights(None)
    held, band = _pelvis_heights((0.0, None))
    let_go, released = _pelvis_heights((0.0, 1.0))
    assert free[-1] < 0.2  # limp, it lies on the floor
    assert min(held[1:]) > 0.6 and not band.released and band.force[2] > 300.0
    assert let_go[1] > 0.6 and let_go[-1] < 0.45  # held, then released at 1 s: falling
    assert released.released and not released.force.any()


@pytest.mark.parametrize("text", ["x", "-1", "0.8@-2", "0.8@1@2"])
def test_a_bad_band_is_refused_naming_it(text):
    assert parse_band("0.8@6") == (0.8, 6.0) and parse_band("0.8") == (0.8, None)
    with pytest.raises(ValueError, match=r"--band '.*': expected"):
        parse_band(text)
