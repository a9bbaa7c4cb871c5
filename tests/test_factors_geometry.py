"""Geometry building blocks and the shared Jacobian checker (factors.geometry, factors.testing)."""

import gtsam
import numpy as np
import pytest

from factors.geometry import (skew, so3_exp, so3_log, so3_right_jacobian_inv, tangent_basis,
                              unit_and_jacobian)
from factors.testing import (check_jacobians, numerical_jacobian, numerical_jacobian_rot3,
                             random_positions_m, random_rotations)


@pytest.fixture
def rng():
    return np.random.default_rng(20240601)


def test_skew_is_cross_product(rng):
    a, b = rng.normal(size=(2, 50, 3))
    np.testing.assert_allclose(skew(a) @ b[..., None], np.cross(a, b)[..., None], atol=1e-14)
    np.testing.assert_array_equal(skew(a), -np.swapaxes(skew(a), -1, -2))


def test_tangent_basis_orthonormal_right_handed(rng):
    u = rng.normal(size=(500, 3))
    u[:5] = np.eye(3)[[0, 1, 2, 0, 1]] * [[1], [1], [1], [-1], [-1]]  # axis-aligned cases
    B = tangent_basis(u)
    un = u / np.linalg.norm(u, axis=1, keepdims=True)
    assert B.shape == (500, 2, 3)
    np.testing.assert_allclose(B @ np.swapaxes(B, 1, 2), np.broadcast_to(np.eye(2), (500, 2, 2)),
                               atol=1e-14)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", B, un), 0.0, atol=1e-14)
    np.testing.assert_allclose(np.cross(B[:, 0], B[:, 1]), un, atol=1e-14)
    # deterministic, and independent of the length of u
    np.testing.assert_array_equal(tangent_basis(u), B)
    np.testing.assert_allclose(tangent_basis(3.7 * u), B, atol=1e-15)


def test_tangent_basis_smooth_within_a_region(rng):
    u = np.array([0.8, 0.5, 0.1])
    du = 1e-7 * rng.normal(size=3)
    dB = tangent_basis(u + du) - tangent_basis(u)
    assert np.max(np.abs(dB)) < 1e-6


def test_unit_and_jacobian(rng):
    r = random_positions_m(rng, 20)
    u, J = unit_and_jacobian(r)
    np.testing.assert_allclose(np.linalg.norm(u, axis=1), 1.0, atol=1e-15)
    check_jacobians(lambda x: unit_and_jacobian(x)[0], (r,), (J,), ("vector",))


def test_so3_exp_log_match_gtsam(rng):
    w = rng.normal(size=(30, 3))
    w *= rng.uniform(0.0, 3.1, size=(30, 1)) / np.linalg.norm(w, axis=1, keepdims=True)
    w[0] = 0.0
    w[1] = [1e-10, -2e-10, 0.0]
    R = so3_exp(w)
    for k in range(30):
        np.testing.assert_allclose(R[k], gtsam.Rot3.Expmap(w[k]).matrix(), atol=1e-14)
        np.testing.assert_allclose(so3_log(R[k]), gtsam.Rot3.Logmap(gtsam.Rot3(R[k])),
                                   atol=1e-12)
    np.testing.assert_allclose(so3_log(R), w, atol=1e-12)


def test_so3_right_jacobian_inverse(rng):
    w = rng.normal(size=(10, 3)) * 0.7
    w[0] = [1e-7, 0.0, 0.0]
    Jinv = so3_right_jacobian_inv(w)
    R = so3_exp(w)
    # Log(R Exp(d)) ~ w + Jr^-1(w) d: the Jacobian of Log with respect to the right perturbation
    check_jacobians(lambda Rx: so3_log(Rx), (R,), (Jinv,), ("rot3",))


def test_random_rotations_are_rotations(rng):
    R = random_rotations(rng, 100)
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape),
                               atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-14)
    r = np.linalg.norm(random_positions_m(rng, 1000), axis=1)
    assert r.min() >= 7.0e6 and r.max() <= 4.0e7


def test_numerical_jacobian_of_known_function(rng):
    A = rng.normal(size=(4, 3))
    x = rng.normal(size=3)
    J = numerical_jacobian(lambda v: A @ v + np.sin(v[0]) * np.ones(4), x)
    expected = A.copy()
    expected[:, 0] += np.cos(x[0])
    np.testing.assert_allclose(J, expected, atol=1e-8)


def test_numerical_jacobian_rot3_right_perturbation(rng):
    R = random_rotations(rng, 5)
    s = rng.normal(size=(5, 3))
    # d(R^T s)/dw = skew(R^T s) for R <- R Exp(w)
    Rts = np.einsum("nji,nj->ni", R, s)
    J = numerical_jacobian_rot3(lambda Rx: np.einsum("nji,nj->ni", Rx, s), R)
    np.testing.assert_allclose(J, skew(Rts), atol=1e-8)
    # and it is the right, not the left, perturbation: d(R s)/dw = -R skew(s)
    J = numerical_jacobian_rot3(lambda Rx: Rx @ s[0], R[0])
    np.testing.assert_allclose(J, -R[0] @ skew(s[0]), atol=1e-8)


def test_check_jacobians_reports_wrong_jacobian(rng):
    r = random_positions_m(rng, 4)
    u, J = unit_and_jacobian(r)
    J_bad = J.copy()
    J_bad[2, 1, 0] *= 1.01
    with pytest.raises(AssertionError, match=r"Jacobian of r_eci_m .*index \(2, 1, 0\)"):
        check_jacobians(lambda x: unit_and_jacobian(x)[0], (r,), (J_bad,), ("vector",),
                        names=("r_eci_m",))
    with pytest.raises(AssertionError, match="shape"):
        check_jacobians(lambda x: unit_and_jacobian(x)[0], (r,), (J[:, :2],), ("vector",))
    with pytest.raises(ValueError, match="kind"):
        check_jacobians(lambda x: unit_and_jacobian(x)[0], (r,), (J,), ("quaternion",))


def test_tangent_basis_kernel_equals_numpy_version(rng):
    """The numba single-vector basis of the per-factor route is the numpy construction,
    including ties of |u_i| (first axis wins in both) and the coordinate axes."""
    from factors.direction import tangent_basis_kernel

    u = rng.normal(size=(200, 3)) * rng.uniform(0.1, 10.0, size=(200, 1))
    u = np.concatenate([u, np.eye(3), -np.eye(3), [[1.0, 1.0, 1.0], [0.0, 1.0, 1.0],
                                                    [1.0, 0.0, 1.0], [-1.0, 1.0, -1.0]]])
    B = np.empty((2, 3))
    for v in u:
        tangent_basis_kernel(v, B)
        np.testing.assert_allclose(B, tangent_basis(v), atol=1e-15, rtol=0)


def test_so3_log_is_exact_near_pi():
    """Log(Exp(w)) = w at every angle up to pi (at pi exactly, w or -w: the same rotation);
    the quotient theta v / (2 sin theta) alone was off by 2e8 rad at pi - 1e-8."""
    from factors.geometry import so3_exp, so3_log

    rng = np.random.default_rng(3)
    for eps in (1e-2, 1.0001e-3, 9.999e-4, 1e-6, 1e-8, 1e-12, 0.0):
        ax = rng.normal(size=(50, 3))
        ax /= np.linalg.norm(ax, axis=1, keepdims=True)
        w = (np.pi - eps) * ax
        back = so3_log(so3_exp(w))
        err = np.abs(back - w).max(axis=1)
        if eps == 0.0:
            err = np.minimum(err, np.abs(back + w).max(axis=1))
        assert err.max() < 1e-11, eps
