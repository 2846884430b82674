"""The compiled attitude rows (sim2real.deploy.core.attitude_kernel) give the numpy functions'
numbers (sim2real.deploy.core.attitude) bit for bit: rotation matrices, Hamilton products, rotation
quaternions."""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core import attitude
from sim2real.deploy.core.attitude_kernel import (
    quat_mul_finite_rows,
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


def test_products_of_the_finite_rows_give_quat_multiplys_numbers_and_leave_the_others():
    """What a legged tick's sensed orientation takes from the IMU (``LeggedTick.sense``): each env
    whose attitude reading is finite turned by one quaternion, an env whose reading is lost or
    not finite keeps its last."""
    rng = np.random.default_rng(11)
    a = rng.normal(size=(40, 4))
    a[3, 1], a[7, 3], a[9] = np.nan, np.inf, np.nan
    b = rng.normal(size=4)
    out = np.full((40, 4), 7.0)
    quat_mul_finite_rows(a, b, out)
    ok = np.isfinite(a).all(axis=1)
    assert ok.sum() == 37
    np.testing.assert_array_equal(out[ok], attitude.quat_multiply(a[ok], b))
    np.testing.assert_array_equal(out[~ok], 7.0)


def test_rotation_rows_equal_rotation_quaternions_bit_for_bit():
    rng = np.random.default_rng(9)
    for scale in (1e-14, 1e-3, 3.0):  # below the first-order threshold, small, large
        rotvec = scale * rng.normal(size=(300, 3))
        got = np.empty((300, 4))
        rotation_rows(rotvec, got)
        np.testing.assert_array_equal(got, attitude.rotation_quaternions(rotvec))
