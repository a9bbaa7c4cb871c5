"""Altimeter, attitude prior, TRIAD and the GTSAM adapters (factors.altimeter, .attitude,
.adapters)."""

import gtsam
import numpy as np
import pytest

from factors.adapters import (custom_factor, jacobian_factors, noise_model,
                              pad_position_jacobian, whiten)
from factors.altimeter import altitude_residual, make_altitude_factor
from factors.attitude import (attitude_residual, make_attitude_prior_factor, triad,
                              triad_covariance)
from factors.constants import DEG, R_EARTH_M
from factors.direction import earth_direction_residual, make_earth_direction_factor
from factors.geometry import so3_exp, so3_log
from factors.testing import (check_jacobians, check_linearization, random_positions_m,
                             random_rotations)

N = 30
X, A = gtsam.symbol("x", 1), gtsam.symbol("a", 1)
ARCMIN = DEG / 60


@pytest.fixture
def rng():
    return np.random.default_rng(7005)


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# --- altimeter ---------------------------------------------------------------------------

def test_altitude_zero_at_truth_and_jacobian(rng):
    r = random_positions_m(rng, N)
    h = np.linalg.norm(r, axis=1) - R_EARTH_M
    e, H_r = altitude_residual(r, h, R_EARTH_M)
    assert e.shape == (N, 1) and H_r.shape == (N, 1, 3)
    np.testing.assert_allclose(e, 0.0, atol=1e-8)
    h_meas = h + 333.0 * rng.normal(size=N)  # the INS/CNS lecture: 1 km 3-sigma
    e, H_r = altitude_residual(r, h_meas, np.full(N, R_EARTH_M))
    np.testing.assert_allclose(e[:, 0], h - h_meas, atol=1e-7)
    check_jacobians(altitude_residual, (r, h_meas, np.full(N, R_EARTH_M)), (H_r, None, None),
                    ("vector", None, None))


def test_altitude_factor_linearizes_like_numpy(rng):
    r = random_positions_m(rng, 1)
    h = np.linalg.norm(r, axis=1) - R_EARTH_M + 250.0
    f = make_altitude_factor(X, h[0], R_EARTH_M, 1000.0 / 3)
    values = gtsam.Values()
    values.insert(X, np.concatenate([r[0], [0.0, 7.5e3, 0.0]]))
    e, H_r = altitude_residual(r, h, R_EARTH_M)
    A_, b = whiten(e, pad_position_jacobian(H_r), 1000.0 / 3)
    check_linearization(f, values, [A_[0]], b[0])


def test_ins_cns_lecture_direct_fix_from_altimeter_and_triad(rng):
    """The INS/CNS lecture's direct fix r = -(R_e + H) C_b^i L_we^b (TRIAD attitude from Sun and Moon)
    reproduces the position exactly from noise-free measurements, and its residuals vanish."""
    r = random_positions_m(rng, 1, R_EARTH_M + 400e3, R_EARTH_M + 600e3)[0]
    R_true = random_rotations(rng, 1)[0]  # C_b^i = R_eci_from_body
    sun, moon = _unit(rng.normal(size=(2, 3)))
    C = triad(R_true.T @ moon, R_true.T @ sun, moon, sun)
    L_we_body = R_true.T @ _unit(-r)
    H = np.linalg.norm(r) - R_EARTH_M
    r_fix = -(R_EARTH_M + H) * (C @ L_we_body)
    np.testing.assert_allclose(r_fix, r, atol=1e-6)
    e, _ = altitude_residual(r_fix[None], np.array([H]), R_EARTH_M)
    assert abs(e[0, 0]) < 1e-6


# --- attitude ----------------------------------------------------------------------------

def test_attitude_residual_matches_prior_factor_rot3(rng):
    R = random_rotations(rng, N)
    R_meas = R @ so3_exp(0.05 * rng.normal(size=(N, 3)))
    e, H_R = attitude_residual(R, R_meas)
    check_jacobians(attitude_residual, (R, R_meas), (H_R, None), ("rot3", None))
    np.testing.assert_allclose(attitude_residual(R, R)[0], 0.0, atol=1e-14)
    sigma = np.array([10.0, 10.0, 30.0]) / 3600 * DEG
    for k in range(3):
        f = make_attitude_prior_factor(A, R_meas[k], sigma)
        values = gtsam.Values()
        values.insert(A, gtsam.Rot3(R[k]))
        # GTSAM's PriorFactorRot3 error is Logmap(R_meas^-1 R): the same as attitude_residual
        np.testing.assert_allclose(f.unwhitenedError(values), e[k], atol=1e-12)
        A_, b = whiten(e[k:k + 1], H_R[k:k + 1], sigma[None, :])
        check_linearization(f, values, [A_[0]], b[0], rtol=1e-7, atol=1e-6)


def test_attitude_prior_pulls_attitude_to_measurement(rng):
    """With a prior alone the optimum is the measured attitude; with a covariance the
    linearized information is P^-1."""
    R_meas = random_rotations(rng, 1)[0]
    graph = gtsam.NonlinearFactorGraph()
    P = triad_covariance([1.0, 0, 0], [0.3, 1.0, 0], 1 * ARCMIN, 0.02 * DEG)
    graph.add(make_attitude_prior_factor(A, gtsam.Rot3(R_meas), P))
    values = gtsam.Values()
    values.insert(A, gtsam.Rot3(R_meas @ so3_exp(np.array([0.2, -0.1, 0.3]))))
    result = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    np.testing.assert_allclose(result.atRot3(A).matrix(), R_meas, atol=1e-10)
    Ab, _ = graph.at(0).linearize(result).jacobian()
    info = np.linalg.inv(P)
    np.testing.assert_allclose(Ab.T @ Ab, info, rtol=1e-8, atol=1e-9 * np.abs(info).max())


def test_triad_recovers_rotation_exactly(rng):
    R = random_rotations(rng, N)
    v1_ref, v2_ref = _unit(rng.normal(size=(2, N, 3)))
    v1_body = np.einsum("nji,nj->ni", R, v1_ref) * rng.uniform(0.5, 2, size=(N, 1))
    v2_body = np.einsum("nji,nj->ni", R, v2_ref) * 3.0
    R_est = triad(v1_body, v2_body, v1_ref, v2_ref)
    np.testing.assert_allclose(R_est, R, atol=1e-13)
    with pytest.raises(ValueError, match="parallel"):
        triad(v1_body, -2 * v1_body, v1_ref, v2_ref)


def test_triad_first_vector_is_exact(rng):
    R = random_rotations(rng, 1)[0]
    v1, v2 = _unit(rng.normal(size=(2, 3)))
    b1 = R.T @ v1
    b2 = so3_exp(np.array([0.01, 0.02, -0.01])) @ (R.T @ v2)  # noisy second vector
    R_est = triad(b1, b2, v1, v2)
    np.testing.assert_allclose(R_est @ b1, v1, atol=1e-14)


def test_triad_covariance_against_monte_carlo(rng):
    """The INS/CNS lecture's sensors: Sun sensor 1' (3 sigma) as the second vector, UV Moon direction
    0.02 deg (3 sigma) as the first; the Monte Carlo covariance of Log(R_true^T R_hat) matches
    triad_covariance within sampling error."""
    R = random_rotations(rng, 1)[0]
    moon_ref, sun_ref = _unit(np.array([[1.0, 0.2, 0.1], [0.3, 1.0, -0.4]]))
    b1, b2 = R.T @ moon_ref, R.T @ sun_ref
    s1, s2 = 0.02 * DEG / 3, 1 * ARCMIN / 3
    n = 20000

    def noisy(b, sigma):
        # perpendicular Gaussian noise, sigma per tangent axis
        d = sigma * rng.normal(size=(n, 3))
        d -= (d @ b)[:, None] * b
        return b + d

    R_hat = triad(noisy(b1, s1), noisy(b2, s2), np.tile(moon_ref, (n, 1)),
                  np.tile(sun_ref, (n, 1)))
    phi = so3_log(R.T @ R_hat)
    P_mc = np.cov(phi.T)
    P = triad_covariance(b1, b2, s1, s2)
    # compare in the eigenbasis of P: diagonal within 5 %, correlations within 0.03
    w, V = np.linalg.eigh(P)
    Q = V.T @ P_mc @ V
    np.testing.assert_allclose(np.diag(Q), w, rtol=0.05)
    corr = Q / np.sqrt(np.outer(np.diag(Q), np.diag(Q)))
    np.testing.assert_allclose(corr - np.diag(np.diag(corr)), 0.0, atol=0.03)


# --- adapters ----------------------------------------------------------------------------

def test_whiten_shapes_and_sigma_forms(rng):
    e = rng.normal(size=(5, 2))
    H = rng.normal(size=(5, 2, 6))
    A1, b1 = whiten(e, H, 0.5)
    np.testing.assert_allclose(A1, H / 0.5)
    np.testing.assert_allclose(b1, -e / 0.5)
    sig_n = rng.uniform(0.1, 1, size=5)
    A2, b2 = whiten(e, H, sig_n)
    np.testing.assert_allclose(A2, H / sig_n[:, None, None])
    sig_nm = rng.uniform(0.1, 1, size=(5, 2))
    (A3, A4), b3 = whiten(e, [H, H[..., :3]], sig_nm)
    np.testing.assert_allclose(A3, H / sig_nm[..., None])
    np.testing.assert_allclose(A4, H[..., :3] / sig_nm[..., None])
    np.testing.assert_allclose(b3, -e / sig_nm)
    with pytest.raises(ValueError):
        whiten(e, H, np.ones((5, 3)))
    with pytest.raises(ValueError):
        whiten(e, H, -1.0)


def test_pad_and_noise_model(rng):
    H = rng.normal(size=(4, 2, 3))
    P = pad_position_jacobian(H)
    assert P.shape == (4, 2, 6)
    np.testing.assert_array_equal(P[..., :3], H)
    np.testing.assert_array_equal(P[..., 3:], 0.0)
    assert noise_model(0.1, 2).sigmas() == pytest.approx([0.1, 0.1])
    assert noise_model([0.1, 0.2], 2).sigmas() == pytest.approx([0.1, 0.2])
    with pytest.raises(ValueError):
        noise_model([0.1, 0.2, 0.3], 2)
    with pytest.raises(ValueError):
        noise_model(0.0, 1)
    with pytest.raises(ValueError, match="dim"):
        custom_factor([X], 0.1, lambda values: (np.zeros(1), [np.zeros((1, 6))]))


def test_bulk_jacobian_factors_equal_custom_factors(rng):
    """The batch route (whiten + JacobianFactor) and the per-factor CustomFactor give the same
    linear system and the same Gauss-Newton step."""
    n = 6
    r = random_positions_m(rng, n)
    u = _unit(-r + 2e4 * rng.normal(size=r.shape))
    keys = np.array([gtsam.symbol("x", k) for k in range(n)])
    sigma = 0.01 * DEG
    e, H_r = earth_direction_residual(r, u)
    A_, b = whiten(e, pad_position_jacobian(H_r), sigma)
    bulk = jacobian_factors([keys], [A_], b)
    values = gtsam.Values()
    g_custom = gtsam.GaussianFactorGraph()
    g_bulk = gtsam.GaussianFactorGraph()
    for k in range(n):
        values.insert(int(keys[k]), np.concatenate([r[k], np.zeros(3)]))
    for k in range(n):
        g_custom.add(make_earth_direction_factor(int(keys[k]), u[k], sigma).linearize(values))
        g_bulk.add(bulk[k])
        # a weak prior makes each 6-D state determined
        prior = gtsam.JacobianFactor(int(keys[k]), np.eye(6) * 1e-6, np.zeros(6),
                                     gtsam.noiseModel.Unit.Create(6))
        g_custom.add(prior)
        g_bulk.add(prior)
    d_custom = g_custom.optimize()
    d_bulk = g_bulk.optimize()
    for k in keys:
        np.testing.assert_allclose(d_bulk.at(int(k)), d_custom.at(int(k)), rtol=1e-9, atol=1e-9)
    assert g_bulk.error(d_bulk) == pytest.approx(g_custom.error(d_custom), rel=1e-9)
