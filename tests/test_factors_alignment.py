"""The star camera's mounting alignment (factors.alignment): truth, Jacobians on both rotations,
the GTSAM adapter, and a small graph that recovers a mounting error."""

import gtsam
import numpy as np
import pytest

from factors.adapters import whiten
from factors.alignment import aligned_star_direction_residual, make_aligned_star_direction_factor
from factors.constants import ARCSEC
from factors.direction import star_direction_residual
from factors.geometry import so3_exp, so3_log
from factors.testing import check_jacobians, check_linearization, random_rotations

N = 40
A, M = gtsam.symbol("a", 3), gtsam.symbol("m", 3)


@pytest.fixture
def rng():
    return np.random.default_rng(7101)


def _stars(rng, n):
    """``n`` catalogue directions spread over the sphere (unit vectors, ECI)."""
    s = rng.normal(size=(n, 3))
    return s / np.linalg.norm(s, axis=-1, keepdims=True)


def _seen(R_att, R_mount, s):
    return np.einsum("nji,nj->ni", R_att @ R_mount, s)


def test_zero_at_truth_and_jacobians_on_both_rotations(rng):
    R, Mt = random_rotations(rng, N), random_rotations(rng, N)
    s = _stars(rng, N)
    e, _, _ = aligned_star_direction_residual(R, Mt, s, _seen(R, Mt, s))
    np.testing.assert_allclose(e, 0.0, atol=1e-14)
    u_meas = _seen(R, Mt @ so3_exp(rng.normal(0, 30 * ARCSEC, (N, 3))), s)
    e, H_A, H_M = aligned_star_direction_residual(R, Mt, s, u_meas)
    assert np.all(np.abs(e) > 0)
    check_jacobians(aligned_star_direction_residual, (R, Mt, s, u_meas), (H_A, H_M, None, None),
                    ("rot3", "rot3", None, None), names=("attitude", "mounting", "s", "u"))


def test_identity_mounting_is_the_plain_star_model(rng):
    R = random_rotations(rng, N)
    s = _stars(rng, N)
    u = _seen(R, so3_exp(rng.normal(0, 1e-4, (N, 3))), s)
    e, H_A, H_M = aligned_star_direction_residual(R, np.broadcast_to(np.eye(3), (N, 3, 3)), s, u)
    e0, H0 = star_direction_residual(R, s, u)
    np.testing.assert_allclose(e, e0, atol=1e-15)
    np.testing.assert_allclose(H_A, H0, atol=1e-15)
    np.testing.assert_allclose(H_M, H0, atol=1e-15)


def test_factor_linearizes_like_numpy(rng):
    R, Mt = random_rotations(rng, 1), random_rotations(rng, 1)
    s = _stars(rng, 1)
    u = _seen(R, Mt @ so3_exp(rng.normal(0, 1e-4, (1, 3))), s)
    sigma = 5.0 * ARCSEC
    f = make_aligned_star_direction_factor(A, M, s[0], u[0], sigma)
    values = gtsam.Values()
    values.insert(A, gtsam.Rot3(R[0]))
    values.insert(M, gtsam.Rot3(Mt[0]))
    e, H_A, H_M = aligned_star_direction_residual(R, Mt, s, u)
    (W_A, W_M), b = whiten(e, [H_A, H_M], sigma)
    check_linearization(f, values, [W_A[0], W_M[0]], b[0])


def test_two_attitudes_and_a_known_direction_recover_the_mounting(rng):
    """The mounting is observable when the body attitude is known another way: here priors of
    1 arcsec on two attitudes and ten stars each seen through a 30 arcsec mounting error."""
    from factors.random_walk import make_rot3_prior_factor

    M_true = so3_exp(np.array([20.0, -35.0, 10.0]) * ARCSEC)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    key_M = gtsam.symbol("m", 0)
    graph.add(make_rot3_prior_factor(key_M, np.eye(3), 300 * ARCSEC))
    values.insert(key_M, gtsam.Rot3())
    for k in range(2):
        R = random_rotations(rng, 1)[0]
        key_A = gtsam.symbol("a", k)
        graph.add(make_rot3_prior_factor(key_A, R, 1 * ARCSEC))
        values.insert(key_A, gtsam.Rot3(R))
        for s in _stars(rng, 10):
            u = (R @ M_true).T @ s
            graph.add(make_aligned_star_direction_factor(key_A, key_M, s, u, 1 * ARCSEC))
    est = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    err = so3_log(M_true.T @ est.atRot3(key_M).matrix())
    assert np.linalg.norm(err) < 1 * ARCSEC


def test_aberrated_through_the_mounting_jacobians_and_factor(rng):
    """The mounted star camera with aberration: Jacobians on both rotations and on the
    observer's velocity (~1/c, checked with a step it resolves), and the three-key factor."""
    from factors.alignment import (aligned_star_direction_apparent_residual,
                                   make_aligned_star_direction_apparent_factor)
    from factors.aberration import SPEED_OF_LIGHT_MPS

    R, Mt = random_rotations(rng, N), random_rotations(rng, N)
    s = _stars(rng, N)
    v = rng.normal(size=(N, 3)) * 2e4
    u = _seen(R, Mt @ so3_exp(rng.normal(0, 30 * ARCSEC, (N, 3))), s)
    e, H_A, H_M, H_v = aligned_star_direction_apparent_residual(R, Mt, s, v, u)
    check_jacobians(lambda RR, MM, vv: aligned_star_direction_apparent_residual(RR, MM, s, vv, u)[0],
                    [R, Mt, v], [H_A, H_M, H_v], ["rot3", "rot3", "vector"], rtol=1e-5,
                    eps=[1e-6, 1e-6, 100.0])
    assert 2.0e-9 < np.max(np.abs(H_v)) < 1.01 / SPEED_OF_LIGHT_MPS
    e0, _, _ = aligned_star_direction_residual(R, Mt, s, u)
    assert np.max(np.abs(e - e0)) > 5 * ARCSEC          # the aberration is not lost

    X = gtsam.symbol("x", 3)
    x = np.concatenate([rng.normal(size=3) * 7e6, v[0] * 0.3])
    v_earth = v[0] * 0.7
    f = make_aligned_star_direction_apparent_factor(X, A, M, s[0], v_earth, u[0], 5 * ARCSEC)
    values = gtsam.Values()
    values.insert(X, x)
    values.insert(A, gtsam.Rot3(R[0]))
    values.insert(M, gtsam.Rot3(Mt[0]))
    e1, HA1, HM1, Hv1 = aligned_star_direction_apparent_residual(
        R[:1], Mt[:1], s[:1], (v_earth + x[3:])[None], u[:1])
    H_x = np.zeros((1, 2, 6))
    H_x[..., 3:] = Hv1
    (W_x, W_A, W_M), b = whiten(e1, [H_x, HA1, HM1], 5 * ARCSEC)
    check_linearization(f, values, [W_x[0], W_A[0], W_M[0]], b[0])
