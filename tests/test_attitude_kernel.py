"""The compiled attitude rows (deploy.estimation.attitude_kernel) give the numpy functions'
numbers (deploy.estimation.attitude) bit for bit: rotation matrices, Hamilton products, rotation
quaternions and Mahony's update with its bias, including the still (zero gyro) and free-fall
(zero acceleration) rows."""

from __future__ import annotations

import numpy as np

from deploy.estimation import attitude
from deploy.estimation.attitude_kernel import (
    mahony_rows,
    quat_mul_rows,
    quat_to_mat_rows,
    rotation_rows,
)


def test_rows_of_quaternions_give_the_numpy_expressions_numbers_bit_for_bit():
    rng = np.random.default_rng(7)
    q = rng.normal(size=(500, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    b = rng.normal(size=(500, 4))
    matrices, products = np.empty((500, 3, 3)), np.empty((500, 4))
    quat_to_mat_rows(q, matrices)
    quat_mul_rows(q, b, products)
    # a (1, k, 4) batch takes quaternion_to_matrix's numpy path
    np.testing.assert_array_equal(matrices, attitude.quaternion_to_matrix(q[None])[0])
    np.testing.assert_array_equal(attitude.quaternion_to_matrix(q), matrices)
    np.testing.assert_array_equal(attitude.quaternion_to_matrix(q[3]), matrices[3])
    np.testing.assert_array_equal(products, attitude.quat_multiply(q, b))


def test_mahony_rows_equal_mahony_update_bit_for_bit():
    rng = np.random.default_rng(8)
    k = 1000
    q = rng.normal(size=(k, 4))
    gyro, acc = rng.normal(size=(k, 3)), 5 * rng.normal(size=(k, 3))
    gyro[:40] = 0.0  # still: quaternion and bias kept
    acc[40:80] = 0.0  # free fall: no correction
    dt = rng.uniform(0.001, 0.03, k)
    bias = 0.01 * rng.normal(size=(k, 3))
    expected_bias = bias.copy()
    expected = attitude.mahony_update(q, expected_bias, gyro, acc, dt, 1.0, 0.3)
    got = np.empty((k, 4))
    mahony_rows(q, bias, gyro, acc, dt, 1.0, 0.3, got)
    np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(bias, expected_bias)
    assert not np.array_equal(expected_bias[80:], 0.01 * np.zeros((k - 80, 3)))


def test_rotation_rows_equal_rotation_quaternions_bit_for_bit():
    rng = np.random.default_rng(9)
    for scale in (1e-14, 1e-3, 3.0):  # below the first-order threshold, small, large
        rotvec = scale * rng.normal(size=(300, 3))
        got = np.empty((300, 4))
        rotation_rows(rotvec, got)
        np.testing.assert_array_equal(got, attitude.rotation_quaternions(rotvec))
