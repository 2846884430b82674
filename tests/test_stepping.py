"""The plant's physics steps with the sensors computed in the last step of a period only
(sim2real.deploy.backends.sim.stepping): the same motion and readings as computing them in
every step, and the models' flags as they were."""

import mujoco
import numpy as np
import pytest

from sim2real.deploy.backends.sim import stepping
from sim2real.deploy.backends.sim.plant import SimBackend


def _run(robot, ticks: int, monkeypatch, every_step: bool):
    """A seeded two-env plant of ``robot`` driven ``ticks`` ticks around home; its states,
    sensor data and frames per tick."""
    with monkeypatch.context() as m:
        if every_step:
            m.setattr(stepping, "SENSORS_OFF", 0)
        backend = SimBackend(robot, mode="position", envs=2, seed=3)
        rng = np.random.default_rng(5)
        out = []
        for _ in range(ticks):
            backend.write(robot.home + rng.normal(0.0, 0.3, (2, robot.n_joints)))
            backend.advance()
            frame = backend.read()
            out.append(
                [d.qpos.copy() for d in backend.datas]
                + [d.qvel.copy() for d in backend.datas]
                + [d.sensordata.copy() for d in backend.datas]
                + [frame.imu_acceleration.copy(), frame.foot_force.copy(), frame.position.copy()]
            )
    return out


def test_sensors_in_the_last_step_only_change_nothing_read(go2, monkeypatch):
    """go2's plant (its motors stepped one step at a time): the joint and base states, every
    sensor value and the frames' IMU, contact and encoder readings equal, bit for bit, those of
    a plant computing the sensors in every step."""
    assert go2.mj_model.nsensor > 0 and go2.decimation > 1
    ours = _run(go2, 60, monkeypatch, every_step=False)
    every = _run(go2, 60, monkeypatch, every_step=True)
    for a, b in zip(ours, every, strict=True):
        for x, y in zip(a, b, strict=True):
            assert np.array_equal(x, y)


def test_a_period_in_two_calls_steps_as_one_call_of_every_step(go2):
    """Without motors stepped one at a time: ``decimation - 1`` steps without sensors and the
    last with them give the state and sensor data of ``mj_step(nstep=decimation)``, period
    after period of random controls (the base falling, the feet touching down)."""
    m = go2.mj_model
    ours, every = mujoco.MjData(m), mujoco.MjData(m)
    rng, touched = np.random.default_rng(2), False
    for _ in range(100):
        ctrl = rng.normal(0.0, 5.0, m.nu)
        ours.ctrl[:], every.ctrl[:] = ctrl, ctrl
        stepping.step_period([(m, ours)], [True], go2.decimation)
        mujoco.mj_step(m, every, nstep=go2.decimation)
        for field in ("qpos", "qvel", "act", "qacc_warmstart", "sensordata"):
            assert np.array_equal(getattr(ours, field), getattr(every, field)), field
        touched = touched or bool(np.any(every.sensordata[:4] > 0.0))
    assert touched  # a foot's touch sensor read a force


def test_the_sensor_flag_is_set_for_all_steps_but_the_last_and_then_restored(go2, monkeypatch):
    """Each env's model steps with ``mjDSBL_SENSOR`` in its first ``decimation - 1`` steps and
    without it in the last; after the period its flags are what they were."""
    assert stepping.SENSORS_OFF  # this MuJoCo has the flag
    backend = SimBackend(go2, mode="position", envs=2, seed=0)
    before = [m.opt.disableflags for m in backend.models]
    seen = []
    step = mujoco.mj_step

    def recording(m, d, nstep=1):
        seen.extend([bool(m.opt.disableflags & stepping.SENSORS_OFF)] * nstep)
        step(m, d, nstep=nstep)

    monkeypatch.setattr(mujoco, "mj_step", recording)
    backend.write(np.tile(go2.home, (2, 1)))
    backend.advance()
    period = [True] * (go2.decimation - 1) + [False]
    assert seen == period * 2
    assert [m.opt.disableflags for m in backend.models] == before


def test_a_model_whose_readings_depend_on_earlier_steps_computes_them_in_every_step(go2):
    """A sensor with a delay (MuJoCo keeps a history of its samples) is read from earlier steps:
    such a model is stepped as MuJoCo steps it; go2's sensors (the last step's alone) are not."""
    assert stepping.quiet_sensors(go2.mj_model)
    if not hasattr(go2.mj_model, "sensor_delay"):
        pytest.skip("this MuJoCo has no delayed sensors")
    xml = (
        '<mujoco><worldbody><body><joint type="hinge"/><geom size="0.1"/><site name="s"/>'
        '</body></worldbody><sensor><gyro site="s" delay="0.01" nsample="3"/></sensor></mujoco>'
    )
    assert not stepping.quiet_sensors(mujoco.MjModel.from_xml_string(xml))
    no_sensor = mujoco.MjModel.from_xml_string("<mujoco/>")
    assert not stepping.quiet_sensors(no_sensor)
