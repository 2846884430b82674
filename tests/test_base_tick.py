"""The legged base estimate's compiled tick (sim2real.deploy.estimation.base_tick) gives the numbers
of its per-env Python steps (base_steps, the path the filterpy reference takes), through every
branch: missing, stale and future IMU readings, contacts without a stamp, non-finite joints,
reported drive velocities, a slipping leg that opens the gate, a frozen force sensor taken for
dead (kinematic contacts), a reset of one env and a state_dict round trip. The compiled fall
check gives the numbers of its numpy form; the attitude functions' compiled paths give numpy's."""

from __future__ import annotations

import copy

import numpy as np
import pinocchio as pin
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.core import attitude
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.estimation.base import BaseStateEstimator
from sim2real.deploy.estimation.base_steps import BaseSteps
from sim2real.deploy.estimation.fall import FallDetector

TICKS = 400


class PerEnvEstimator(BaseStateEstimator):
    """The estimator on its per-env Python steps (a subclass that replaces a step, as the
    reference does, is not compiled)."""

    def _legs_step(self, e, frame, q, dq) -> None:
        BaseSteps._legs_step(self, e, frame, q, dq)


def perturbed_frames(robot, envs=2, seed=0):
    """(frame, q, dq) per tick of a standing go2, perturbed (module docstring)."""
    plant = SimBackend(robot, "position", envs=envs, seed=seed)
    rng = np.random.default_rng(seed)
    target = np.tile(robot.home, (envs, 1))
    held, previous = None, None
    for k in range(TICKS):
        frame = copy.deepcopy(plant.read())  # the plant reuses its frame
        q, dq = frame.position.copy(), np.zeros_like(frame.position)
        q[np.isnan(q)] = np.asarray(robot.home)[np.isnan(q).nonzero()[1]]
        e, u = rng.integers(envs), rng.random(7)
        if u[0] < 0.05:
            frame.imu_angular_velocity[e, 1] = np.nan
        if u[1] < 0.05 and previous is not None:
            frame.imu_stamp[e] = previous[e]
        if u[2] < 0.05:
            frame.contact_stamp[e] = np.nan
        if u[3] < 0.03:
            q[e, 2] = np.nan
        if u[4] < 0.03:
            frame.imu_stamp[e] = frame.time[e] + 0.01  # from the future
        if k >= TICKS // 2:
            frame.velocity = np.where(rng.random(q.shape) < 0.2, np.nan, dq + 0.01)
        if 100 <= k < 130:  # a drive reports a leg that disagrees: gated out, the gate opens
            frame.velocity = np.full(q.shape, np.nan)
            frame.velocity[:, 0] = 3.0
        if k >= 150:  # env 1's foot 2 reads a constant: dead, in contact by the kinematics
            held = frame.foot_force[envs - 1, 2] if held is None else held
            frame.foot_force[envs - 1, 2] = held
        previous = frame.imu_stamp.copy()
        yield frame, q, dq
        plant.write(target)
        plant.advance()


def test_the_compiled_tick_gives_the_per_env_steps_numbers(go2):
    frames = list(perturbed_frames(go2))
    runs = []
    for cls in (BaseStateEstimator, PerEnvEstimator):
        est = cls(go2, 2)
        assert est._compiled == (cls is BaseStateEstimator)
        first = frames[0][0]
        est.reset(first.time - 0.02, first.imu_acceleration, orientation=first.imu_orientation)
        rows = []
        for k, (frame, q, dq) in enumerate(frames):
            if k == 250:
                est.reset(frame.time - 0.02, frame.imu_acceleration, envs=[0])
            if k == 300:  # a fresh estimator from the state
                state = est.state_dict()
                est = cls(go2, 2)
                est.load_state_dict(state)
            out = est.update(frame, q, dq)
            rows.append((out, est.state_dict()))
        runs.append(rows)
        assert est.dead_feet[1, 2] and not est.dead_feet[0].any()
        assert est.rejected_contacts.sum() > 0 and est.missing_readings.sum() > 0
        assert est.stale_readings.sum() > 0
    for (out_a, sd_a), (out_b, sd_b) in zip(*runs, strict=True):
        for name in ("orientation", "projected_gravity", "angular_velocity",
                     "linear_velocity", "linear_velocity_world"):  # fmt: skip
            # the per-env output goes through numpy's matmul (BLAS): the same to rounding
            np.testing.assert_allclose(getattr(out_a, name), getattr(out_b, name), atol=1e-12)
        for key, value in sd_a.items():
            np.testing.assert_array_equal(value, sd_b[key], err_msg=key)


def numpy_fall_check(fall: FallDetector, state: RobotState) -> tuple[np.ndarray, np.ndarray]:
    """The fall check's signals and height in numpy (its form before it was compiled), on the
    state before ``fall.check``: (envs, 3) bool, (envs,) m."""
    signals = np.zeros_like(fall.signals)
    tilt = attitude.tilt_of(state.base.projected_gravity)
    signals[:, 0] = tilt > fall.tilt_limit
    sinking = state.base.linear_velocity_world[:, 2] < -1.0
    ticks = np.where(sinking, fall.sinking_ticks + 1, 0)
    contact = state.foot_contact > 0.5
    height = np.full(len(contact), np.nan)
    for e in np.flatnonzero(contact.any(axis=1)):
        pin.forwardKinematics(fall.model, fall.data, state.q[e])
        rot = attitude.quaternion_to_matrix(state.base.orientation[e])
        height[e] = max(  # above the lowest foot, with one in contact
            radius - (rot @ pin.updateFramePlacement(fall.model, fall.data, f).translation)[2]
            for f, radius in zip(fall.feet, fall.radii, strict=True)
        )
    low = np.where(height < fall.height_limit, fall.low_ticks + 1, 0)
    signals[:, 1] = low >= fall.height_ticks
    upright = (tilt <= fall.sink_tilt) & ~(height < fall.sink_height)  # NaN (a hop): upright
    signals[:, 2] = ticks >= np.where(upright, fall.upright_ticks, fall.speed_ticks)
    return signals, height


def test_the_compiled_fall_check_gives_the_numpy_numbers(go2):
    rng = np.random.default_rng(3)
    envs = 6
    fall = FallDetector(go2, envs)
    state = RobotState.legged(envs, go2.n_joints, go2.n_feet)
    seen, low = np.zeros(3, dtype=bool), 0
    for k in range(60):
        state.q[:] = np.asarray(go2.home) + rng.normal(0.0, 0.6, (envs, go2.n_joints))
        quat = rng.normal(size=(envs, 4)) * [3.0, 1.0, 1.0, 1.0]
        state.base.orientation[:] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
        state.base.projected_gravity[:] = attitude.projected_gravity(state.base.orientation)
        state.base.linear_velocity_world[:, 2] = rng.normal(
            -2.0 if 20 <= k < 40 else -0.5, 0.5, envs
        )
        state.foot_contact[:] = rng.random((envs, go2.n_feet)) < 0.5
        signals, height = numpy_fall_check(fall, state)
        fallen = fall.check(state)
        np.testing.assert_array_equal(fall.signals, signals)
        np.testing.assert_allclose(fall.height, height, atol=1e-12)
        np.testing.assert_array_equal(fallen, signals.any(axis=1))
        seen |= fall.signals.any(axis=0)
        low = max(low, fall.low_ticks.max())
    assert seen[0] and seen[2] and low > 0  # tilted, sinking, low: every branch ran


def test_the_fall_check_on_the_estimators_feet_gives_the_numbers_of_its_own_kinematics(go2):
    envs = 2
    est, per_env = BaseStateEstimator(go2, envs), PerEnvEstimator(go2, envs)
    given, own = FallDetector(go2, envs), FallDetector(go2, envs)
    state = RobotState.legged(envs, go2.n_joints, go2.n_feet)
    held = skipped = 0
    row = np.empty((go2.n_feet, 3))
    for k, (frame, q, dq) in enumerate(perturbed_frames(go2)):
        if k == 0:
            for x in (est, per_env):
                x.reset(
                    frame.time - 0.02, frame.imu_acceleration, orientation=frame.imu_orientation
                )
        state.q[:] = q
        est.update(frame, state.q, dq, out=state.base)
        per_env.update(frame, q, dq)
        assert not per_env.foot_position(0, row) and not per_env.foot_position(1, row)
        state.foot_contact[:] = est.contact
        for e in range(envs):
            row[:] = np.nan
            if not est.foot_position(e, row):
                assert np.isnan(row).all()  # untouched
                skipped += 1
                continue
            held += 1
            pin.forwardKinematics(own.model, own.data, state.q[e])
            for i, f in enumerate(own.feet):  # the same placements, to the bit
                mine = pin.updateFramePlacement(own.model, own.data, f).translation
                assert row[i].tobytes() == mine.tobytes()
        np.testing.assert_array_equal(given.check(state, est.foot_position), own.check(state))
        np.testing.assert_array_equal(given.height, own.height)
        np.testing.assert_array_equal(given.signals, own.signals)
        np.testing.assert_array_equal(given.low_ticks, own.low_ticks)
    assert held > TICKS // 2 and skipped > TICKS // 2  # both paths of the handover ran


@pytest.mark.parametrize(
    ("a", "b"),
    [((5, 4), (5, 4)), ((5, 4), (1, 4)), ((1, 4), (5, 4)), ((4,), (4,)), ((4,), (5, 4))],
)
def test_quat_multiply_of_rows_gives_the_numpy_numbers(a, b):
    rng = np.random.default_rng(1)
    x, y = rng.normal(size=a), rng.normal(size=b)
    ref = np.stack(  # the numpy expressions (attitude.quat_multiply's general path)
        [
            x[..., 0] * y[..., 0] - x[..., 1] * y[..., 1] - x[..., 2] * y[..., 2] - x[..., 3] * y[..., 3],
            x[..., 0] * y[..., 1] + x[..., 1] * y[..., 0] + x[..., 2] * y[..., 3] - x[..., 3] * y[..., 2],
            x[..., 0] * y[..., 2] - x[..., 1] * y[..., 3] + x[..., 2] * y[..., 0] + x[..., 3] * y[..., 1],
            x[..., 0] * y[..., 3] + x[..., 1] * y[..., 2] - x[..., 2] * y[..., 1] + x[..., 3] * y[..., 0],
        ],
        axis=-1,
    )  # fmt: skip
    np.testing.assert_array_equal(attitude.quat_multiply(x, y), ref)
    with pytest.raises(ValueError):
        attitude.quat_multiply(np.zeros((3, 4)), np.zeros((2, 4)))
