"""Direction residuals (factors.direction): truth, Jacobians, angle scale, GTSAM adapters."""

import gtsam
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from factors.adapters import pad_position_jacobian, whiten
from factors.constants import DEG
from factors.direction import (SERIES_BELOW, body_direction_residual, earth_direction_residual,
                               make_body_direction_factor, make_earth_direction_factor,
                               make_star_direction_factor, sphere_log, star_direction_residual)
from factors.geometry import so3_exp, tangent_basis
from factors.testing import (check_jacobians, check_linearization, random_positions_m,
                             random_rotations)

N = 40
X, A = gtsam.symbol("x", 3), gtsam.symbol("a", 3)


@pytest.fixture
def rng():
    return np.random.default_rng(7001)


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _perturb(u, rng, sigma_rad):
    """Rotate unit vectors by small random rotations (measurement noise), independent of B."""
    return np.einsum("nij,nj->ni", so3_exp(sigma_rad * rng.normal(size=u.shape)), u)


def test_earth_direction_zero_at_truth_and_angle_scale(rng):
    r = random_positions_m(rng, N)
    e, H_r = earth_direction_residual(r, _unit(-r))
    assert e.shape == (N, 2) and H_r.shape == (N, 2, 3)
    np.testing.assert_allclose(e, 0.0, atol=1e-15)
    # a measurement rotated by a known angle theta gives |e| = theta (the log map), at
    # every angle up to the antipode, where the tangent-plane projection gave sin(theta)
    axis = _unit(np.cross(r, rng.normal(size=(N, 3))))
    for theta in (0.01 * DEG, 30 * DEG, 90 * DEG, 170 * DEG, 179.9 * DEG):
        u_meas = np.einsum("nij,nj->ni", so3_exp(theta * axis), _unit(-r))
        e, _ = earth_direction_residual(r, u_meas)
        np.testing.assert_allclose(np.linalg.norm(e, axis=1), theta, rtol=1e-12)


def test_earth_direction_jacobian(rng):
    r = random_positions_m(rng, N)
    u_meas = _perturb(_unit(-r), rng, 0.05)
    e, H_r = earth_direction_residual(r, u_meas)
    assert np.all(np.abs(e) > 0)
    check_jacobians(earth_direction_residual, (r, u_meas), (H_r, None), ("vector", None),
                    names=("r_eci_m", "u_meas_eci"))


def _body_truth(rng):
    r = random_positions_m(rng, N)
    R = random_rotations(rng, N)
    p = random_positions_m(rng, N, 3.6e8, 4.1e8)  # Moon-like distances
    u_body = np.einsum("nji,nj->ni", R, _unit(p - r))
    return r, R, p, u_body


def test_body_direction_zero_at_truth_and_jacobians(rng):
    r, R, p, u_body = _body_truth(rng)
    e, H_r, H_R = body_direction_residual(r, R, p, u_body)
    np.testing.assert_allclose(e, 0.0, atol=1e-14)
    # parallax: the spacecraft position moves the predicted Moon direction by ~|r|/|p|
    assert np.all(np.linalg.norm(H_r, axis=(1, 2)) > 0)
    u_meas = _perturb(u_body, rng, 0.03)
    e, H_r, H_R = body_direction_residual(r, R, p, u_meas)
    check_jacobians(body_direction_residual, (r, R, p, u_meas), (H_r, H_R, None, None),
                    ("vector", "rot3", None, None),
                    names=("r_eci_m", "R_eci_from_body", "p_target_eci_m", "u_meas_body"))


def test_body_direction_earth_centre_matches_earth_direction(rng):
    r = random_positions_m(rng, N)
    R = random_rotations(rng, N)
    u_meas_eci = _perturb(_unit(-r), rng, 0.02)
    u_meas_body = np.einsum("nji,nj->ni", R, u_meas_eci)
    e_b, H_r_b, _ = body_direction_residual(r, R, np.zeros((N, 3)), u_meas_body)
    e_e, H_r_e = earth_direction_residual(r, u_meas_eci)
    # same angle, expressed in two tangent bases related by a 2x2 rotation
    np.testing.assert_allclose(np.linalg.norm(e_b, axis=1), np.linalg.norm(e_e, axis=1),
                               rtol=1e-12)
    # B^T B = I - u u^T in both frames, so the information H^T H is the same
    info_b = np.einsum("nji,njk->nik", H_r_b, H_r_b)
    info_e = np.einsum("nji,njk->nik", H_r_e, H_r_e)
    np.testing.assert_allclose(info_b, info_e, rtol=0, atol=1e-12 * np.abs(info_e).max())


def test_star_direction_zero_at_truth_and_jacobian(rng):
    R = random_rotations(rng, N)
    s = _unit(rng.normal(size=(N, 3)))
    u_body = np.einsum("nji,nj->ni", R, s)
    e, H_R = star_direction_residual(R, s, u_body)
    np.testing.assert_allclose(e, 0.0, atol=1e-15)
    u_meas = _perturb(u_body, rng, 10.0 / 3600 * DEG)
    e, H_R = star_direction_residual(R, s, u_meas)
    check_jacobians(star_direction_residual, (R, s, u_meas), (H_R, None, None),
                    ("rot3", None, None))


def test_star_direction_recovers_attitude_error(rng):
    """A small known attitude error w shows up as e = -B skew(u) w to first order."""
    R = random_rotations(rng, N)
    s = _unit(rng.normal(size=(N, 3)))
    u_body = np.einsum("nji,nj->ni", R, s)
    w = 1e-6 * rng.normal(size=(N, 3))
    e, H_R = star_direction_residual(R @ so3_exp(w), s, u_body)
    np.testing.assert_allclose(e, np.einsum("nij,nj->ni", H_R, w), atol=1e-11)


def test_earth_direction_factor_linearizes_like_numpy(rng):
    """The factor's numba kernel against the vectorized residual, over random geometries
    (every axis choice of the tangent basis) and both noise-model kinds."""
    r = random_positions_m(rng, 12)
    v = rng.normal(size=(12, 3)) * 3e3
    u_meas = _perturb(_unit(-r), rng, 0.01)
    e, H_r = earth_direction_residual(r, u_meas)
    for k in range(12):
        sigma = 0.01 * DEG if k % 2 else np.array([0.01, 0.02]) * DEG
        f = make_earth_direction_factor(X, u_meas[k], sigma)
        values = gtsam.Values()
        values.insert(X, np.concatenate([r[k], v[k]]))
        A_, b = whiten(e[k:k + 1], pad_position_jacobian(H_r[k:k + 1]), np.broadcast_to(sigma, (1, 2)))
        check_linearization(f, values, [A_[0]], b[0])
        np.testing.assert_allclose(f.unwhitenedError(values), e[k], rtol=1e-12)
        assert f.error(values) == pytest.approx(0.5 * np.sum((e[k] / sigma) ** 2), rel=1e-12)


def test_body_direction_factor_linearizes_like_numpy(rng):
    """The factor's numba kernel against the numpy residual, row by row (targets near and
    far, every axis choice of the tangent basis, both noise-model kinds, a longer state)."""
    r, R, p, _ = _body_truth(rng)
    p[::3] = 0.0                                   # the Earth's centre
    u_meas = _perturb(np.einsum("nji,nj->ni", R, _unit(p - r)), rng, 0.01)
    e, H_r, H_R = body_direction_residual(r, R, p, u_meas)
    for k in range(len(r)):
        sigma = np.array([0.02, 0.03]) * DEG if k % 2 else 0.02 * DEG
        n = 6 + k % 3
        f = make_body_direction_factor(X, A, p[k], u_meas[k], sigma)
        values = gtsam.Values()
        values.insert(X, np.concatenate([r[k], rng.normal(size=n - 3)]))
        values.insert(A, gtsam.Rot3(R[k]))
        (A_x, A_R), b = whiten(e[k:k + 1], [pad_position_jacobian(H_r[k:k + 1], n), H_R[k:k + 1]],
                               np.broadcast_to(sigma, (1, 2)))
        check_linearization(f, values, [A_x[0], A_R[0]], b[0])
        np.testing.assert_allclose(f.unwhitenedError(values), e[k], rtol=1e-12, atol=1e-15)


def test_star_direction_factor_linearizes_like_numpy(rng):
    R = random_rotations(rng, 1)
    s = _unit(rng.normal(size=(1, 3)))
    u_meas = _perturb(np.einsum("nji,nj->ni", R, s), rng, 1e-4)
    sigma = 5.0 / 3600 * DEG
    f = make_star_direction_factor(A, s[0], u_meas[0], sigma)
    values = gtsam.Values()
    values.insert(A, gtsam.Rot3(R[0]))
    e, H_R = star_direction_residual(R, s, u_meas)
    A_R, b = whiten(e, H_R, sigma)
    check_linearization(f, values, [A_R[0]], b[0])


def test_star_factors_solve_attitude(rng):
    """Three star factors and a wrong initial attitude: GTSAM recovers the true attitude."""
    R_true = random_rotations(rng, 1)[0]
    graph = gtsam.NonlinearFactorGraph()
    for _ in range(3):
        s = _unit(rng.normal(size=3))
        graph.add(make_star_direction_factor(A, s, R_true.T @ s, 1e-5))
    values = gtsam.Values()
    values.insert(A, gtsam.Rot3(R_true @ so3_exp(np.array([0.05, -0.03, 0.02]))))
    result = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    np.testing.assert_allclose(result.atRot3(A).matrix(), R_true, atol=1e-9)


# --- the log map of the sphere: angle, farthest point, Jacobians at any angle ------------

LARGE_ANGLES_DEG = (1e-5, 0.5, 45.0, 90.0, 135.0, 170.0, 179.0)


def _rotated_by(u, rng, angle_rad):
    """Unit vectors at exactly ``angle_rad`` from ``u`` (N,3), about random perpendicular axes."""
    axis = _unit(np.cross(u, rng.normal(size=u.shape)))
    return np.einsum("nij,nj->ni", so3_exp(angle_rad * axis), u)


_vec = st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=3, max_size=3).filter(
    lambda v: np.linalg.norm(v) > 1e-3)


@settings(max_examples=300, deadline=None)
@given(_vec, _vec)
@example([1.0, 0.0, 0.0], [-1.0, 0.0, 1.536940249506729e-161])  # antipodal, a subnormal tangent
@example([0.0, 1.0, 0.0], [5e-324, -1.0, 5e-324])  # antipodal, two subnormal components
def test_sphere_log_is_the_angle_and_inverts_the_exponential_map(a, b):
    """|e| is the angle between the two directions (atan2 of |u x v| and u.v, computed
    here independently), and Exp_u(B^T e) = u cos|e| + (B^T e/|e|) sin|e| gives v back."""
    u, v = _unit(np.array(a)), _unit(np.array(b))
    e, J = sphere_log(u, v)
    assert np.all(np.isfinite(e)) and np.all(np.isfinite(J))
    angle = np.arctan2(np.linalg.norm(np.cross(u, v)), u @ v)
    assert np.linalg.norm(e) == pytest.approx(angle, abs=1e-12)
    th = np.linalg.norm(e)
    if 1e-9 < th < np.pi - 1e-6:
        d = tangent_basis(u).T @ e / th
        np.testing.assert_allclose(u * np.cos(th) + d * np.sin(th), v, atol=1e-12)


@pytest.mark.parametrize("angle_deg", LARGE_ANGLES_DEG)
def test_direction_jacobians_at_large_angles(rng, angle_deg):
    """Central differences at errors from 1e-5 deg (series branch) to 179 deg, for the log
    map itself and for the three residuals (position and attitude links)."""
    a = np.radians(angle_deg)
    r = random_positions_m(rng, N)
    u_meas = _rotated_by(_unit(-r), rng, a)
    e, H_r = earth_direction_residual(r, u_meas)
    np.testing.assert_allclose(np.linalg.norm(e, axis=1), a, rtol=1e-10, atol=1e-15)
    check_jacobians(earth_direction_residual, (r, u_meas), (H_r, None), ("vector", None),
                    rtol=1e-5, names=("r_eci_m", "u_meas_eci"))
    u_pred = _unit(-r)
    _, J = sphere_log(u_meas, u_pred)
    check_jacobians(lambda v, w: sphere_log(w, v), (u_pred, u_meas), (J, None),
                    ("vector", None), rtol=1e-5, eps=(1e-7, None))
    # body direction (Moon-like target) and star: attitude link at the same angles
    R = random_rotations(rng, N)
    p = random_positions_m(rng, N, 3.6e8, 4.1e8)
    u_body = _rotated_by(np.einsum("nji,nj->ni", R, _unit(p - r)), rng, a)
    e, H_r, H_R = body_direction_residual(r, R, p, u_body)
    np.testing.assert_allclose(np.linalg.norm(e, axis=1), a, rtol=1e-10, atol=1e-15)
    check_jacobians(body_direction_residual, (r, R, p, u_body), (H_r, H_R, None, None),
                    ("vector", "rot3", None, None), rtol=1e-5,
                    names=("r_eci_m", "R_eci_from_body", "p_target_eci_m", "u_meas_body"))
    s = _unit(rng.normal(size=(N, 3)))
    u_star = _rotated_by(np.einsum("nji,nj->ni", R, s), rng, a)
    e, H_R = star_direction_residual(R, s, u_star)
    np.testing.assert_allclose(np.linalg.norm(e, axis=1), a, rtol=1e-10, atol=1e-15)
    check_jacobians(star_direction_residual, (R, s, u_star), (H_R, None, None),
                    ("rot3", None, None), rtol=1e-5)


def test_flipped_direction_is_the_farthest_point_and_stays_finite(rng):
    """-u_meas: |e| = pi (the tangent-plane projection gave 0 there), finite e and Jacobians,
    for exact antipodes (e = (pi, 0) along b1) and for antipodes up to rounding."""
    r = random_positions_m(rng, N)
    e, H_r = earth_direction_residual(r, _unit(r))      # measured +r/|r|: flipped
    np.testing.assert_allclose(np.linalg.norm(e, axis=1), np.pi, rtol=1e-12)
    assert np.all(np.isfinite(H_r))
    for u in np.eye(3):
        e, J = sphere_log(u, -u)
        np.testing.assert_array_equal(e, [np.pi, 0.0])
        assert np.all(np.isfinite(J))
    # a measured direction 0.1 deg from the antipode: |e| = 179.9 deg, pointing away
    u_pred = _unit(-r)
    u_meas = -_rotated_by(u_pred, rng, np.radians(0.1))
    e, _ = sphere_log(u_meas, u_pred)
    np.testing.assert_allclose(np.linalg.norm(e, axis=1), np.radians(179.9), rtol=1e-12)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_sphere_log_continuous_across_the_series_threshold(rng, sign):
    """e is continuous where the series (near u_meas) and cut-locus (near -u_meas) branches
    take over at |B u_pred| = SERIES_BELOW; near u_meas so is the Jacobian."""
    u = _unit(rng.normal(size=(N, 3)))
    B = tangent_basis(u)
    d = _unit(np.einsum("nij,ni->nj", B, rng.normal(size=(N, 2))))   # tangent unit
    out = []
    for s in (SERIES_BELOW * (1 - 1e-9), SERIES_BELOW * (1 + 1e-9)):
        v = sign * np.sqrt(1 - s * s) * u + s * d
        out.append(sphere_log(u, v, B))
    (e0, J0), (e1, J1) = out
    np.testing.assert_allclose(e0, e1, rtol=1e-7, atol=1e-20)
    if sign > 0:
        np.testing.assert_allclose(J0, J1, rtol=0, atol=1e-9)


@pytest.mark.parametrize("angle_deg", (*LARGE_ANGLES_DEG, 180.0))
def test_earth_direction_factor_kernel_equals_numpy_at_large_angles(rng, angle_deg):
    """The GTSAM factor's numba kernel against the vectorized residual at every angle,
    flipped measurements included."""
    r = random_positions_m(rng, 6)
    u_meas = (_unit(r) if angle_deg == 180.0
              else _rotated_by(_unit(-r), rng, np.radians(angle_deg)))
    e, H_r = earth_direction_residual(r, u_meas)
    sigma = 0.01 * DEG
    for k in range(len(r)):
        f = make_earth_direction_factor(X, u_meas[k], sigma)
        values = gtsam.Values()
        values.insert(X, np.concatenate([r[k], np.zeros(3)]))
        A_, b = whiten(e[k:k + 1], pad_position_jacobian(H_r[k:k + 1]), np.full((1, 2), sigma))
        check_linearization(f, values, [A_[0]], b[0])
        np.testing.assert_array_equal(f.unwhitenedError(values), e[k])


def test_residual_at_truth_is_the_noise_the_simulator_drew():
    """fgnav.simulate rotates the true direction by the tangent vector n ~ N(0, sigma^2 I)
    (Exp map); the log map at the truth returns n itself, at any noise level."""
    from fgnav.simulate.noise import perturb_directions

    rng = np.random.default_rng(5)
    u = _unit(rng.normal(size=(200, 3)))
    sigma = np.repeat([1e-4, 0.1, 1.0], [100, 50, 50])
    u_meas = perturb_directions(u, sigma, np.random.default_rng(11))
    n = np.random.default_rng(11).standard_normal((200, 2)) * sigma[:, None]
    ok = np.linalg.norm(n, axis=1) < np.pi
    e, _ = sphere_log(u, u_meas)
    np.testing.assert_allclose(e[ok], n[ok], rtol=0, atol=1e-12)
