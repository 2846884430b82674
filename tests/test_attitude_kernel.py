"""The compiled attitude rows (deploy.estimation.attitude_kernel) give the numpy expressions'
numbers bit for bit: rotation matrices, Hamilton products and Mahony's update with its bias,
including the still (zero gyro) and free-fall (zero acceleration) rows."""

from __future__ import annotations

import numpy as np

from deploy.estimation import attitude


def test_rows_of_quaternions_give_the_numpy_expressions_numbers_bit_for_bit():
    rng = np.random.default_rng(7)
    q = rng.normal(size=(500, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    b = rng.normal(size=(500, 4))
    # a (1, k, 4) batch takes the numpy path; (k, 4) rows take the kernel
    np.testing.assert_array_equal(
        attitude.quaternion_to_matrix(q), attitude.quaternion_to_matrix(q[None])[0]
    )
    np.testing.assert_array_equal(
        attitude.quat_multiply(q, b), attitude.quat_multiply(q[None], b[None])[0]
    )


def test_mahony_update_compiled_equals_its_numpy_reference_bit_for_bit():
    rng = np.random.default_rng(8)
    k = 1000
    q = rng.normal(size=(k, 4))
    gyro, acc = rng.normal(size=(k, 3)), 5 * rng.normal(size=(k, 3))
    gyro[:40] = 0.0  # still: quaternion and bias kept
    acc[40:80] = 0.0  # free fall: no correction
    dt = rng.uniform(0.001, 0.03, k)
    bias = 0.01 * rng.normal(size=(k, 3))
    expected_bias = bias.copy()
    expected = attitude.mahony_update_reference(q, expected_bias, gyro, acc, dt, 1.0, 0.3)
    got = attitude.mahony_update(q, bias, gyro, acc, dt, 1.0, 0.3)
    np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(bias, expected_bias)
    assert not np.array_equal(bias[80:], 0.01 * np.zeros((k - 80, 3)))


def test_rotation_quaternions_and_one_quaternions_matrix_compiled_bit_for_bit():
    rng = np.random.default_rng(9)
    for scale in (1e-14, 1e-3, 3.0):  # below the first-order threshold, small, large
        rotvec = scale * rng.normal(size=(300, 3))
        np.testing.assert_array_equal(
            attitude.rotation_quaternions(rotvec), attitude.rotation_quaternions_reference(rotvec)
        )
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    np.testing.assert_array_equal(
        attitude.quaternion_to_matrix(q), attitude.quaternion_to_matrix(q[None, None])[0, 0]
    )
