"""The deputy's state relative to the chief (fgnav.frames): Jacobians, the
LVLH convention of relative_motion, covariance propagation, and two integrated orbits
against the Clohessy-Wiltshire solution."""

import numpy as np
import pytest

from factors.testing import check_jacobians, random_positions_m, random_rotations
from fgnav.formation.relative_motion import (
    chief_circular_state, circular_relative_orbit, cw_matrices, lvlh_from_eci, mean_motion,
    two_body_relative_truth,
)
from fgnav.frames import (
    deputy_from_relative_lvlh, lvlh_axes, relative_covariance_body, relative_covariance_lvlh,
    relative_position_body, relative_state_body, relative_state_lvlh,
)
from fgnav.orbit import integrate_truth, rtn_frame


@pytest.fixture
def pair():
    """Six chiefs (LEO to GEO radii, eccentric: random velocities 3-9 km/s) and deputies
    1-3,000 m and 0.1-2 m/s away."""
    rng = np.random.default_rng(11)
    n = 6
    r = random_positions_m(rng, n)
    v = rng.normal(size=(n, 3))
    v *= rng.uniform(3e3, 9e3, size=(n, 1)) / np.linalg.norm(v, axis=1, keepdims=True)
    xc = np.hstack([r, v])
    dr = rng.normal(size=(n, 3))
    dr *= np.geomspace(1.0, 3e3, n)[:, None] / np.linalg.norm(dr, axis=1, keepdims=True)
    xd = xc + np.hstack([dr, rng.normal(size=(n, 3))])
    return xc, xd


def _check_state_columns(f, x, H, name):
    """Position columns with a 0.1 m step, velocity columns with 1e-4 m/s (one step for both
    would be 1e-6 |x| ~ 10 m, far too large for velocity)."""
    check_jacobians(lambda r: f(np.hstack([r, x[:, 3:]])), (x[:, :3],), (H[:, :, :3],),
                    ("vector",), eps=(0.1,), names=(name + " position",))
    check_jacobians(lambda v: f(np.hstack([x[:, :3], v])), (x[:, 3:],), (H[:, :, 3:],),
                    ("vector",), eps=(1e-4,), names=(name + " velocity",))


def test_lvlh_jacobians(pair):
    xc, xd = pair
    rel, J_c, J_d = relative_state_lvlh(xc, xd)
    assert rel.shape == (6, 6) and J_c.shape == J_d.shape == (6, 6, 6)
    _check_state_columns(lambda x: relative_state_lvlh(x, xd), xc, J_c, "chief")
    _check_state_columns(lambda x: relative_state_lvlh(xc, x), xd, J_d, "deputy")


def test_lvlh_convention_is_relative_motions_and_rtn(pair):
    """Same axes as relative_motion.lvlh_from_eci (x radial, y along-track, z normal) and as
    orbit.rtn_frame, the rotating-frame term omega x rho included, and invertible."""
    xc, xd = pair
    rel, _, _ = relative_state_lvlh(xc, xd)
    C, wz = lvlh_axes(xc)
    assert np.allclose(C, rtn_frame(xc), atol=1e-15)
    for k in range(xc.shape[0]):
        Ck, wk = lvlh_from_eci(xc[k, :3], xc[k, 3:])
        assert np.allclose(C[k], Ck, atol=1e-15) and wz[k] == pytest.approx(wk[2], rel=1e-14)
        rho = Ck @ (xd[k, :3] - xc[k, :3])
        assert np.allclose(rel[k, :3], rho, rtol=0, atol=1e-9)
        assert np.allclose(rel[k, 3:], Ck @ (xd[k, 3:] - xc[k, 3:]) - np.cross(wk, rho),
                           rtol=0, atol=1e-12)
    assert np.allclose(deputy_from_relative_lvlh(xc, rel), xd, rtol=1e-15, atol=1e-8)


def test_body_frame_position_and_jacobians(pair):
    xc, xd = pair
    rng = np.random.default_rng(5)
    R = random_rotations(rng, xc.shape[0])
    r_body, J_c, J_d, J_att = relative_position_body(xc, xd, R)
    assert np.allclose(np.einsum("nij,nj->ni", R, r_body), xd[:, :3] - xc[:, :3], atol=1e-9)
    _check_state_columns(lambda x: relative_position_body(x, xd, R), xc, J_c, "chief")
    _check_state_columns(lambda x: relative_position_body(xc, x, R), xd, J_d, "deputy")
    check_jacobians(lambda Rr: relative_position_body(xc, xd, Rr), (R,), (J_att,), ("rot3",),
                    eps=(1e-4,), names=("attitude",))
    # with the velocity seen from the rotating body (1 deg/s about a random axis)
    w = np.deg2rad(1.0) * rng.normal(size=(xc.shape[0], 3))
    rel, J_c6, J_d6, J_att6, J_w = relative_state_body(xc, xd, R, w)
    assert np.allclose(rel[:, :3], r_body) and np.allclose(J_c6[:, :3], J_c)
    assert np.allclose(np.einsum("nij,nj->ni", R, rel[:, 3:] + np.cross(w, r_body)),
                       xd[:, 3:] - xc[:, 3:], rtol=0, atol=1e-9)
    _check_state_columns(lambda x: relative_state_body(x, xd, R, w), xc, J_c6, "chief")
    _check_state_columns(lambda x: relative_state_body(xc, x, R, w), xd, J_d6, "deputy")
    check_jacobians(lambda Rr, ww: relative_state_body(xc, xd, Rr, ww), (R, w), (J_att6, J_w),
                    ("rot3", "vector"), eps=(1e-4, 1e-6), names=("attitude", "rate"))
    still, *_ = relative_state_body(xc, xd, R)
    assert np.allclose(still[:, 3:], np.einsum("nji,nj->ni", R, xd[:, 3:] - xc[:, 3:]))


def test_covariance_propagation_against_monte_carlo(pair):
    """J P J^T against the sample covariance of the relative states of 40,000 draws of the
    joint [chief; deputy] state (correlated, 10 m / 1 cm/s level: linear to ~1e-6)."""
    xc, xd = pair
    rng = np.random.default_rng(8)
    n = xc.shape[0]
    scale = np.array([10.0] * 3 + [0.01] * 3 + [10.0] * 3 + [0.01] * 3)
    P = np.empty((n, 12, 12))
    for k in range(n):
        A = rng.normal(size=(12, 12))
        corr = A @ A.T + 12 * np.eye(12)
        d = np.sqrt(np.diag(corr))
        P[k] = (corr / np.outer(d, d)) * np.outer(scale, scale)
    P_rel = relative_covariance_lvlh(xc, xd, P)
    R = random_rotations(rng, n)
    w = np.deg2rad(1.0) * rng.normal(size=(n, 3))
    P_body = relative_covariance_body(xc, xd, R, P, w)
    n_draw = 40000
    for k in range(n):
        L = np.linalg.cholesky(P[k])
        draws = rng.normal(size=(n_draw, 12)) @ L.T
        xs_c = xc[k] + draws[:, :6]
        xs_d = xd[k] + draws[:, 6:]
        rel, _, _ = relative_state_lvlh(xs_c, xs_d)
        S = np.cov(rel.T)
        sd = np.sqrt(np.diag(P_rel[k]))
        # sample covariance: standard error of a correlation ~ 1/sqrt(n_draw) = 0.005
        assert np.allclose(S / np.outer(sd, sd), P_rel[k] / np.outer(sd, sd), atol=0.03)
        rb, *_ = relative_state_body(xs_c, xs_d, np.broadcast_to(R[k], (n_draw, 3, 3)), w[k])
        Sb = np.cov(rb.T)
        sb = np.sqrt(np.diag(P_body[k]))
        assert np.allclose(Sb / np.outer(sb, sb), P_body[k] / np.outer(sb, sb), atol=0.03)
    assert np.allclose(P_rel, np.swapaxes(P_rel, 1, 2))
    with pytest.raises(ValueError, match="joint covariance"):
        relative_covariance_lvlh(xc, xd, P[:, :6, :6])


def test_two_integrated_orbits_follow_clohessy_wiltshire():
    """A 1 km closed CW orbit about a 500 km circular chief (Keplerian truth, DOP853):
    relative_state_lvlh of the two integrated orbits equals relative_motion's own two-body
    difference to 1e-5 m / 1e-8 m/s (measured 1.1e-6 m, 1.4e-9 m/s), and the CW solution
    to its known accuracy over 10 min: the neglected quadratic terms, 3 n^2 rho^2/(2 r) =
    2.8e-7 m/s^2, give 2.8e-7 * 600^2 / 2 = 5 cm (measured 4.2 cm, 0.13 mm/s), far below
    the rotating frame's term n rho = 1.1 m/s."""
    n = mean_motion(500.0)
    xc0 = chief_circular_state(500.0)
    t = np.arange(0.0, 601.0, 30.0)
    rel_cw = circular_relative_orbit(1000.0, n, t)
    xd0 = deputy_from_relative_lvlh(xc0[None], rel_cw[:1])[0]
    xc = integrate_truth(xc0, t, j2=False)
    xd = integrate_truth(xd0, t, j2=False)
    rel, _, _ = relative_state_lvlh(xc, xd)
    ref = two_body_relative_truth(xc0, rel_cw[0], t)
    assert np.abs(rel[:, :3] - ref[:, :3]).max() < 1e-5
    assert np.abs(rel[:, 3:] - ref[:, 3:]).max() < 1e-8
    # the CW prediction: closed form, and the STM of cw_matrices
    Phi, _ = cw_matrices(n, t[-1], 0.0)
    assert np.allclose(Phi @ rel_cw[0], rel_cw[-1], atol=1e-9)
    err_r = np.linalg.norm(rel[:, :3] - rel_cw[:, :3], axis=1)
    err_v = np.linalg.norm(rel[:, 3:] - rel_cw[:, 3:], axis=1)
    assert err_r.max() < 0.1 and err_v.max() < 5e-4
    assert err_r[-1] > 0.01          # CW's neglected terms are there, at their size
    # without the frame's rotation the velocity would be off by ~n rho
    C, _ = lvlh_axes(xc)
    v_no_rotation = np.einsum("nij,nj->ni", C, xd[:, 3:] - xc[:, 3:])
    assert np.linalg.norm(v_no_rotation - rel_cw[:, 3:], axis=1).min() > 0.5
