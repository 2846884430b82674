"""The compiled tick of a floating base's IMU and foot contacts
(:mod:`sim2real.deploy.backends.sim.legged_sensors_kernel`) gives what the numpy path of
:class:`~sim2real.deploy.backends.sim.legged_sensors.BaseSensorModel` gives, bit for bit.

Two Go2 plants of the same seed step the same commands, one with the model as it is, one with
``compiled = False`` (numpy's sample and read); every frame, the sensor state and the streams'
next draws must be equal, under settings that reach every branch: dropout, latencies, an IMU and
contacts slower than the control rate, no onboard attitude, a drifting onboard heading, per-env
streams, an env reset alone,
a new model for an env, a copy of the plant. Tolerance: none.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend

ENVS = 2
TICKS = 120


def settings(sensors, case: str) -> None:
    if case in ("dropout", "slow"):
        sensors.imu_dropout[:] = (0.3, 0.1)
        sensors.imu_latency_ticks[:] = (2, 0)
        sensors.contact_latency_ticks[:] = (0, 3)
    if case == "slow":
        sensors.imu_every, sensors.contact_every = 2, 3
    if case == "no_attitude":
        sensors.has_orientation = False
    if case in ("heading", "streams"):  # the onboard heading's drift and walk
        sensors.has_heading = True
        sensors.heading_rate_sigma[:] = (0.01, 0.02)
        sensors.heading_walk[:] = (0.005, 0.01)
    sensors.gyro_bias_walk[:] = (0.01, 0.03)  # a walk large enough to see
    sensors.force_noise_sigma[1] = 5.0


def build(go2, case: str, compiled: bool) -> SimBackend:
    plant = SimBackend(go2, "position", envs=ENVS, seed=7)
    if case == "streams":
        plant.set_sensor_streams([np.random.default_rng(20 + e) for e in range(ENVS)])
    sensors = plant.base_sensors
    sensors.compiled = compiled
    settings(sensors, case)
    plant.reset()
    return plant


def snapshot(plant) -> dict:
    frame = {f"frame/{k}": v.copy() for k, v in plant.frame.arrays().items()}
    sensors = plant.base_sensors
    state = {f"state/{k}": np.array(v) for k, v in sensors.state_fields().items()}
    return frame | state


def assert_same(a: dict, b: dict, when: str) -> None:
    assert a.keys() == b.keys()
    for key in a:
        x, y = a[key], b[key]
        assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), (
            f"{key} at {when}"
        )


@pytest.mark.parametrize(
    "case", ["default", "dropout", "slow", "no_attitude", "heading", "streams"]
)
def test_compiled_sensors_equal_numpy(go2, case, monkeypatch):
    from sim2real.deploy.backends.sim import legged_sensors

    calls = {"sample": 0, "read": 0}  # numpy's sample in a tick's advance, numpy's read
    ticking = []
    for name in ("sample", "read"):
        original = getattr(legged_sensors.BaseSensorModel, f"reference_{name}")

        def counted(self, *args, _original=original, _name=name, **kwargs):
            if self.compiled and (_name == "read" or ticking):
                calls[_name] += 1
            return _original(self, *args, **kwargs)

        monkeypatch.setattr(legged_sensors.BaseSensorModel, f"reference_{name}", counted)
    advance = SimBackend.advance

    def advancing(self):
        ticking.append(True)
        try:
            advance(self)
        finally:
            ticking.pop()

    monkeypatch.setattr(SimBackend, "advance", advancing)
    fast, slow = build(go2, case, True), build(go2, case, False)
    rng = np.random.default_rng(3)
    home = np.asarray(go2.home)
    for k in range(TICKS):
        command = home + 0.3 * rng.standard_normal((ENVS, go2.n_joints))
        for plant in (fast, slow):
            plant.read()
            plant.write(command)
            plant.advance()
        assert_same(snapshot(fast), snapshot(slow), f"tick {k}")
        if k == 40:  # env 1 alone restarts: its forced sample is numpy's, the next compiled
            for plant in (fast, slow):
                plant.reset(envs=np.array([False, True]))
        if k == 55:  # new correlation times of the IMU's attitude error, set in place
            for plant in (fast, slow):
                plant.base_sensors.orientation_tau[0] = 0.25
        if k == 70:  # a new model for env 0: the compiled call reads the new MjData
            for plant in (fast, slow):
                plant.set_model(0, go2.plant_model("position"))
                plant.reset(envs=np.array([True, False]))
        if k == 90:  # a copy goes on from here, binding its own MjData and streams
            fast, slow = copy.deepcopy(fast), copy.deepcopy(slow)
    assert calls == {"sample": 0, "read": 0}  # the compiled calls did every tick
    fast.read(), slow.read()
    assert_same(snapshot(fast), snapshot(slow), "the end")
    for a, b in zip(draws(fast), draws(slow), strict=True):  # the streams stand at one place
        assert np.array_equal(a, b)
    lost = np.isnan(snapshot(fast)["state/imu/buffer_stamp"]).any()
    assert lost == (case in ("dropout", "slow"))  # readings lost, or none at some ticks


def draws(plant) -> list[np.ndarray]:
    rng = plant.joint_sensors.rng
    generators = getattr(rng, "generators", [rng])
    return [g.standard_normal(4) for g in generators]


def test_compiled_read_takes_numpy_path_for_a_foreign_frame(go2):
    """A frame whose fields the call cannot take (here a Fortran-ordered force array) is read
    by numpy, with the same numbers."""
    plant = SimBackend(go2, "position", envs=ENVS, seed=1)
    for _ in range(3):
        plant.read()
        plant.write(np.tile(go2.home, (ENVS, 1)))
        plant.advance()
    frame = copy.deepcopy(plant.frame)
    frame.foot_force = np.asfortranarray(np.zeros((go2.n_feet, ENVS)).T)
    plant.base_sensors.read(frame, plant.tick)
    mine = copy.deepcopy(frame)
    plant.base_sensors.reference_read(frame, plant.tick)
    for key, value in frame.arrays().items():
        assert np.array_equal(value, mine.arrays()[key], equal_nan=value.dtype.kind == "f")
    assert np.isfinite(frame.foot_force).all()
