"""An operator's stand-up (the plant's reset of some envs) leaves the IMU reading the new pose at
once, as if the robot had rested there: with a sensor latency, the readings taken before the
reset (the robot lying on the floor) must not be the last ones a loop holds. They were: the
latency buffer of the reset envs was cleared, the IMU missing for ``latency`` ticks, a loop kept
the lying robot's attitude, and the G1's next dance clip was aligned to that heading (it turned
up to 165 deg to follow it and fell within 1.4 s of the clip's start, 4 of 7 stand-ups)."""

from __future__ import annotations

import mujoco
import numpy as np


def test_a_stand_up_reads_the_new_pose_at_once_through_the_imu_latency(go2):
    from sim2real.deploy.backends.sim.plant import SimBackend

    backend = SimBackend(go2, "position", envs=2, seed=0)
    backend.base_sensors.imu_latency_ticks[:] = 3
    backend.reset()
    m, d = backend.models[0], backend.datas[0]
    d.qpos[3:7] = [np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0]  # on its side
    mujoco.mj_forward(m, d)
    for _ in range(10):
        backend.advance()
    lying = backend.read().imu_acceleration[0].copy()
    assert abs(lying[2]) < 5.0, lying  # gravity across the body: the buffer holds the side
    backend.reset(envs=np.array([True, False]))  # stood up
    for _ in range(4):  # every tick of the latency reads the standing robot
        frame = backend.read()
        acc = frame.imu_acceleration[0]
        assert np.isfinite(acc).all() and acc[2] > 8.0, acc
        assert np.isfinite(frame.imu_stamp[0]) and frame.imu_stamp[0] <= frame.time[0]
        backend.advance()
