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


def test_a_clip_started_by_a_stand_up_is_aligned_to_the_robot_standing(go2, go2_onnx, tmp_path):
    """A stand-up puts the robot at home at rest, so its RAMP_IN ends on the first tick: the
    clip starts with no idle tick after it. It must be aligned to the robot as it stands then
    (rl_sar's ``Reset`` on entering its state), not to the heading of the torso lying on the
    floor (it was: the clip kept the alignment of the last tick the robot was not RUNNING)."""
    from sim2real.deploy.core.attitude import yaw_of
    from sim2real.deploy.core.modes import FAULTED, RUNNING
    from sim2real.deploy.spec.motion_blocks import anchor_base_orientation
    from tests.test_imu_attitude_anchor import _rig

    rig = _rig(go2, go2_onnx, tmp_path, 0.0)
    rt, backend, clock = rig.runtime, rig.backend, rig.task.motion

    def tick():
        rt.tick()
        rig.monitor(rt)

    while not (rt.mode[0] == RUNNING and np.isfinite(clock.time[0])):
        tick()
    rt.supervision.safe_stop(np.array([True]), "fall")
    while rt.mode[0] != FAULTED:
        tick()
    for _ in range(10):
        tick()
    down = yaw_of(clock.init)[0]  # aligned while down, to the lying robot's torso
    backend.reset(envs=np.array([True]))  # the operator stands it up (the IMU's heading anew)
    rt.restart(np.array([True]), backend.read().position, backend.frame.time)
    tick()
    assert rt.mode[0] == RUNNING and clock.time[0] > 0.0  # started on that first tick
    sensed = yaw_of(anchor_base_orientation(rt.state))[0]
    assert abs(sensed) < 0.1 and abs(down - sensed) > 0.3  # the lying heading was another
    assert abs(yaw_of(clock.init)[0] - sensed) < 0.05, (down, yaw_of(clock.init))
