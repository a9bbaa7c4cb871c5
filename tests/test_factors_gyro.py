"""The gyro interval residual: value, Jacobians on the rotation manifold and in the bias, and
its GTSAM factor (``factors/gyro.py``)."""

from __future__ import annotations

import gtsam
import numpy as np

from factors.adapters import whiten
from factors.geometry import so3_exp, so3_log
from factors.gyro import gyro_residual, make_gyro_factor, so3_right_jacobian
from factors.testing import check_jacobians, check_linearization, random_rotations


def _case(rng, M=8):
    R0 = random_rotations(rng, M)
    omega = rng.normal(0.0, 0.05, (M, 3))
    bias = rng.normal(0.0, 0.01, (M, 3))
    dt = rng.uniform(0.5, 20.0, M)
    # the attitude moved nearly as the gyro says, plus an error of ~0.05 rad
    R1 = R0 @ so3_exp((omega - bias) * dt[:, None]) @ so3_exp(rng.normal(0.0, 0.05, (M, 3)))
    return R0, R1, bias, omega, dt


def test_zero_when_the_attitude_moved_as_the_gyro_says():
    rng = np.random.default_rng(1)
    R0, _, bias, omega, dt = _case(rng)
    R1 = R0 @ so3_exp((omega - bias) * dt[:, None])
    e, *_ = gyro_residual(R0, R1, bias, omega, dt)
    np.testing.assert_allclose(e, 0.0, atol=1e-12)


def test_jacobians_on_the_manifold_and_in_the_bias():
    rng = np.random.default_rng(2)
    R0, R1, bias, omega, dt = _case(rng)
    e, H0, H1, Hb = gyro_residual(R0, R1, bias, omega, dt)
    check_jacobians(gyro_residual, (R0, R1, bias, omega, dt), (H0, H1, Hb, None, None),
                    ("rot3", "rot3", "vector", None, None), rtol=1e-5)


def test_right_jacobian_against_differences():
    rng = np.random.default_rng(3)
    w = rng.normal(0.0, 1.0, (6, 3))
    d = 1e-6
    for i in range(3):
        step = np.zeros(3)
        step[i] = d
        num = []
        for wk in w:
            A = so3_exp(wk).T @ so3_exp(wk + step)
            B = so3_exp(wk).T @ so3_exp(wk - step)
            num.append((so3_log(A) - so3_log(B)) / (2 * d))
        np.testing.assert_allclose(np.array(num), so3_right_jacobian(w)[:, :, i], atol=1e-8)


def test_factor_linearizes_like_the_numpy_route():
    rng = np.random.default_rng(4)
    R0, R1, bias, omega, dt = _case(rng, 3)
    e, H0, H1, Hb = gyro_residual(R0, R1, bias, omega, dt)
    for i in range(3):
        sig = 1e-4 * dt[i]
        f = make_gyro_factor(1, 2, 3, omega[i], dt[i], sig)
        v = gtsam.Values()
        v.insert(1, gtsam.Rot3(R0[i]))
        v.insert(2, gtsam.Rot3(R1[i]))
        v.insert(3, bias[i])
        A, b = whiten(e[i:i + 1], [H0[i:i + 1], H1[i:i + 1], Hb[i:i + 1]], np.array([sig]))
        check_linearization(f, v, [A[0][0], A[1][0], A[2][0]], b[0], rtol=1e-6, atol=1e-6)
