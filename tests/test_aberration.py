"""Stellar aberration (factors.aberration) and the apparent star-direction factor
(factors.direction.star_direction_apparent_residual): against ERFA reference values,
central differences and the GTSAM adapter."""

import gtsam
import numpy as np
import pytest

from factors.aberration import (SPEED_OF_LIGHT_MPS, aberrate, apparent_direction,
                                earth_velocity_bcrs_mps)
from factors.adapters import whiten
from factors.constants import ARCSEC
from factors.direction import (make_star_direction_apparent_factor, star_direction_apparent_residual,
                               star_direction_residual)
from factors.geometry import so3_log
from factors.testing import check_jacobians, check_linearization, random_rotations

X, A = gtsam.symbol("x", 4), gtsam.symbol("a", 4)
DAY_S = 86400.0

# ERFA 2.0.1.5 (pyerfa), ``epv00(jd, 0)``: the Earth's barycentric velocity (au/d, BCRS ~
# EME2000 to 23 mas) at TT Julian dates, converted to m/s (1 au = 149597870700 m). VSOP2000
# based, ~ mm/s: the reference for the analytic model's velocity.
EPV00_BARYCENTRIC_MPS = {
    2451545.0: (-29784.947, -5029.754, -2180.644),
    2455000.5: (29254.344, -1655.661, -717.78),
    2458849.5: (-29863.382, -4740.002, -2053.804),
    2460000.5: (-12689.945, -25054.462, -10861.96),
    2461371.5: (-27318.629, 11725.063, 5083.339),
    2461500.25: (6911.1, -26584.426, -11525.023),
    2462000.5: (16943.561, 22083.089, 9573.53),
    2463000.5: (23162.561, -16713.736, -7244.964),
}


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@pytest.fixture
def rng():
    return np.random.default_rng(1505)


def test_aberrate_matches_erfa_ab():
    """ERFA ``ab(pnat, v, s=1 au, bm1)`` at one direction and velocity, values from pyerfa
    2.0.1.5 (its extra Sun-deflection term, ``SRS/s`` times ``beta``, is ~2e-12 here)."""
    u = _unit(np.array([[0.3, -0.5, 0.81]]))
    v = np.array([[2.9e4, -1.2e4, 5e3]])
    erfa_ab = np.array([0.30066461, -0.50098649, 0.81154995])
    u_app, _ = aberrate(u, v / SPEED_OF_LIGHT_MPS)
    np.testing.assert_allclose(u_app[0], erfa_ab, atol=1e-8)  # the reference's 8 digits


def test_aberration_size_unit_norm_and_first_order(rng):
    """|u'| = 1; the shift is beta sin(theta) to first order (20.5 arcsec for the Earth's
    29.8 km/s at 90 deg), and the relativistic formula differs from the first-order one by
    at most beta^2."""
    u = _unit(rng.normal(size=(500, 3)))
    beta = rng.normal(size=(500, 3))
    beta *= (rng.uniform(0.0, 1.1e-4, 500) / np.linalg.norm(beta, axis=1))[:, None]
    u_app, _ = aberrate(u, beta)
    np.testing.assert_allclose(np.linalg.norm(u_app, axis=1), 1.0, atol=1e-15)
    b = np.linalg.norm(beta, axis=1)
    sin_t = np.linalg.norm(np.cross(u, beta), axis=1) / np.maximum(b, 1e-300)
    shift = np.arccos(np.clip(np.sum(u * u_app, axis=1), -1, 1))
    first = u + beta - np.sum(u * beta, axis=1)[:, None] * u
    np.testing.assert_allclose(shift, b * sin_t, atol=2.0 * 1.1e-4 ** 2)
    assert np.max(np.linalg.norm(first - u_app, axis=1)) <= 1.1e-4 ** 2
    u90 = np.array([[0.0, 0.0, 1.0]])
    shift90 = np.arccos(aberrate(u90, np.array([[29.8e3 / SPEED_OF_LIGHT_MPS, 0, 0]]))[0][0, 2])
    assert shift90 / ARCSEC == pytest.approx(20.50, abs=0.01)


def test_aberration_jacobian_central_differences(rng):
    u = _unit(rng.normal(size=(30, 3)))
    v = rng.normal(size=(30, 3)) * 2e4
    _, J = apparent_direction(u, v)
    check_jacobians(lambda uu, vv: apparent_direction(uu, vv)[0], [u, v], [None, J],
                    [None, "vector"], rtol=1e-6, eps=[None, 10.0])


def test_earth_velocity_against_erfa_epv00():
    """The analytic Earth velocity (derivative of Montenbruck & Gill's Sun series) is within
    70 m/s (2.3e-3, 0.05 arcsec of aberration) of ERFA's barycentric velocity, 2000-2031."""
    for jd, v_ref in EPV00_BARYCENTRIC_MPS.items():
        v = earth_velocity_bcrs_mps((jd - 2451545.0) * DAY_S)
        assert np.linalg.norm(v - np.array(v_ref)) < 70.0, jd
    # (N,) -> (N, 3)
    t = (np.array(list(EPV00_BARYCENTRIC_MPS)) - 2451545.0) * DAY_S
    assert earth_velocity_bcrs_mps(t).shape == (len(t), 3)


def test_star_direction_apparent_residual_jacobians(rng):
    """Attitude (right perturbation) and observer velocity against central differences,
    at a point off the truth; the velocity Jacobian is ~1/c (3.3e-9 rad per m/s)."""
    n = 25
    R = random_rotations(rng, n)
    s = _unit(rng.normal(size=(n, 3)))
    v = rng.normal(size=(n, 3)) * 2e4
    u_meas = _unit(np.einsum("nji,nj->ni", R, s) + 1e-3 * rng.normal(size=(n, 3)))
    e, H_R, H_v = star_direction_apparent_residual(R, s, v, u_meas)
    assert np.all(np.abs(e) > 0)
    check_jacobians(lambda RR, vv: star_direction_apparent_residual(RR, s, vv, u_meas)[0],
                    [R, v], [H_R, H_v], ["rot3", "vector"], rtol=1e-5, eps=[1e-6, 100.0])
    assert 2.0e-9 < np.max(np.abs(H_v)) < 1.0 / SPEED_OF_LIGHT_MPS * 1.01


def test_apparent_residual_zero_at_the_apparent_direction_and_catalogue_off_by_aberration(rng):
    n = 20
    R = random_rotations(rng, n)
    s = _unit(rng.normal(size=(n, 3)))
    v = np.tile([-29.8e3 + 7.5e3, 3e3, 1e3], (n, 1))
    s_app, _ = apparent_direction(s, v)
    u_true = np.einsum("nji,nj->ni", R, s_app)
    e, _, _ = star_direction_apparent_residual(R, s, v, u_true)
    np.testing.assert_allclose(e, 0.0, atol=1e-14)
    e_cat, _ = star_direction_residual(R, s, u_true)
    ang = np.linalg.norm(e_cat, axis=1) / ARCSEC
    assert ang.max() > 15.0 and ang.max() < 27.0
    e_none, H_R, H_v = star_direction_apparent_residual(R, s, None, u_true)
    np.testing.assert_allclose(e_none, e_cat, atol=1e-15)
    assert not np.any(H_v)


def test_star_direction_apparent_factor_linearizes_like_numpy(rng):
    R = random_rotations(rng, 3)
    s = _unit(rng.normal(size=(3, 3)))
    v_earth = np.array([-2.5e4, 1.4e4, 6e3])
    x = np.concatenate([[7.0e6, 0.0, 0.0], [0.0, 7.5e3, 1e2]])
    sigma = 5.0 * ARCSEC
    for k in range(3):
        u_meas = _unit(R[k].T @ s[k] + 2e-4 * rng.normal(size=3))
        values = gtsam.Values()
        values.insert(X, x)
        values.insert(A, gtsam.Rot3(R[k]))
        for v_e in (v_earth, None):
            f = make_star_direction_apparent_factor(X, A, s[k], v_e, u_meas, sigma)
            v_obs = None if v_e is None else (v_e + x[3:])[None]
            e, H_R, H_v = star_direction_apparent_residual(R[k:k + 1], s[k:k + 1], v_obs,
                                                           u_meas[None])
            H_x = np.zeros((1, 2, 6))
            H_x[..., 3:] = H_v
            (A_x, A_R), b = whiten(e, [H_x, H_R], sigma)
            check_linearization(f, values, [A_x[0], A_R[0]], b[0])


def test_star_model_velocity_columns_and_switch():
    """The registry's star_direction_body model: its orbit columns are the velocity Jacobian
    of the aberration (zero on the position), against central differences at the scale of
    those columns (the registry test's atol, relative to the attitude columns, cannot see
    3e-9 rad per m/s); with the correction switched off they vanish and the residual moves
    by the aberration."""
    from fgnav.apparent import without_aberration
    from fgnav.measurements import build_pass, with_estimates
    from fgnav.models.registry import ATTITUDE_VARIABLE, STAR_DIRECTION_BODY
    from fgnav.scenarios import load_scenario
    from fgnav.simulate.pass_sim import raw_star_scenario, simulate_pass

    sim = simulate_pass(raw_star_scenario(load_scenario("geo-limb").with_options(
        duration_h=0.1)), seed=2)
    p = with_estimates(build_pass(sim.log), (ATTITUDE_VARIABLE.name,))
    lay = p.layout
    fam = p.families[STAR_DIRECTION_BODY.kind]
    X = np.zeros((p.n_epochs, lay.n))
    X[:, :6] = sim.x_true[np.searchsorted(sim.t_s, p.t_s)]
    att = lay.slices[ATTITUDE_VARIABLE.name]
    X[:, att] = so3_log(sim.truth_attitude()[np.searchsorted(sim.t_s, p.t_s)])
    e, H = STAR_DIRECTION_BODY.evaluate(fam, X, lay)
    # at the truth the residual is the star noise (5 arcsec), not the aberration
    assert np.sqrt(np.mean(e ** 2)) / ARCSEC == pytest.approx(5.0, rel=0.2)
    assert not np.any(H[..., :3])
    Hv = H[..., 3:6]
    assert 2.0e-9 < np.max(np.abs(Hv)) <= 1.01 / SPEED_OF_LIGHT_MPS
    for c in range(3, 6):
        dX = np.zeros_like(X)
        dX[:, c] = 100.0
        fd = (STAR_DIRECTION_BODY.evaluate(fam, X + dX, lay)[0]
              - STAR_DIRECTION_BODY.evaluate(fam, X - dX, lay)[0]) / 200.0
        np.testing.assert_allclose(fd, H[..., c], rtol=1e-5, atol=1e-5 * np.max(np.abs(Hv)))
    off = without_aberration(p).families[STAR_DIRECTION_BODY.kind]
    e_off, H_off = STAR_DIRECTION_BODY.evaluate(off, X, lay)
    assert not np.any(H_off[..., :6])
    shift = np.linalg.norm(e_off - e, axis=1) / ARCSEC
    assert 5.0 < np.median(shift) < 30.0


def test_the_compiled_row_kernel_is_aberrate_row_by_row():
    """``aberrate_row_kernel`` (the angle kernels' form) gives ``aberrate``'s direction and
    velocity Jacobian, and a direction Jacobian that central differences confirm."""
    from factors.aberration import aberrate, aberrate_row_kernel

    rng = np.random.default_rng(7)
    u = rng.normal(size=(20, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    beta = rng.normal(size=(20, 3)) * 1e-4
    ua_np, Jb_np = aberrate(u, beta)
    for i in range(20):
        ua, Ju, Jb = np.empty(3), np.empty((3, 3)), np.empty((3, 3))
        aberrate_row_kernel(u[i], beta[i], ua, Ju, Jb)
        np.testing.assert_allclose(ua, ua_np[i], rtol=0, atol=1e-15)
        np.testing.assert_allclose(Jb, Jb_np[i], rtol=1e-12, atol=1e-15)
        h = 1e-6
        num = np.column_stack([(aberrate((u[i] + h * e)[None], beta[i][None])[0][0]
                                - aberrate((u[i] - h * e)[None], beta[i][None])[0][0]) / (2 * h)
                               for e in np.eye(3)])
        # aberrate normalizes u first: compare on the tangent plane, where a unit u moves
        P = np.eye(3) - np.outer(u[i], u[i])
        np.testing.assert_allclose(Ju @ P, num @ P, atol=1e-8)


def test_the_row_kernel_refuses_an_observer_at_or_beyond_light_speed():
    """|beta| >= 1 lies outside the model: the kernel says so (-1.0, outputs untouched) rather
    than raising ``math domain error`` in the solver (the integrity issue, item 4); inside the
    domain it returns 1.0."""
    from factors.aberration import aberrate_row_kernel

    u = np.array([0.0, 0.6, 0.8])
    for beta, expected in ((np.array([1e-4, 0.0, 0.0]), 1.0), (np.array([1.0, 0.0, 0.0]), -1.0),
                           (np.array([0.6, 0.9, 0.0]), -1.0), (np.array([np.nan, 0.0, 0.0]), -1.0)):
        ua, Ju, Jb = np.full(3, 7.0), np.full((3, 3), 7.0), np.full((3, 3), 7.0)
        assert aberrate_row_kernel(u, beta, ua, Ju, Jb) == expected
        if expected < 0:
            assert (ua == 7.0).all() and (Ju == 7.0).all() and (Jb == 7.0).all()
