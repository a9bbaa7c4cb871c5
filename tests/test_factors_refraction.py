"""Starlight refraction (factors.refraction): Li et al. 2017's model, geometry, noise budget,
adapter.

Li et al. 2017 (patent CN104236546B): gamma = 2350.1074 exp(-0.10326788 h)
arcsec, h in km; claim 1 step 4 builds the measured tangent height from a uniform
refraction-angle error and an atmosphere-model error on the height.
"""

import math

import gtsam
import numpy as np
import pytest

from factors.adapters import pad_position_jacobian, whiten
from factors.constants import ARCSEC, R_EARTH_M
from factors.refraction import (GLADSTONE_DALE_M3_KG, REFRACTION_MODELS,
                                REFRACTION_VALID_BAND_M, US76_DENSITY_KG_M3,
                                apparent_tangent_height_m, in_valid_band,
                                make_refraction_bias_factor, make_refraction_factor,
                                refraction_angle_rad,
                                refraction_residual, refraction_sigma_m,
                                tangent_height_from_refraction_m)
from factors.testing import check_jacobians, check_linearization, random_positions_m

X = gtsam.symbol("x", 4)
B = gtsam.symbol("b", 4)
A_OBL_M = 1.5e3  # an arbitrary oblateness correction, to exercise the parameter


@pytest.fixture
def rng():
    return np.random.default_rng(7004)


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def star_for_tangent_height(r, h_m, gamma_rad, r_earth_m=R_EARTH_M, a_m=A_OBL_M, rng=None):
    """A star direction s with apparent tangent height h: s = -cos(t) r/|r| + sin(t) e,
    sin(t + gamma) = (R_e + a + h) cos(gamma)/|r| (closed form of the classic geometry)."""
    rhat = _unit(r)
    e = _unit(np.cross(r, rng.normal(size=r.shape)))
    x = (r_earth_m + a_m + h_m) * np.cos(gamma_rad) / np.linalg.norm(r, axis=1)
    t = np.arcsin(x) - gamma_rad
    return -np.cos(t)[:, None] * rhat + np.sin(t)[:, None] * e


def test_li_patent_formula_at_band_heights():
    for h_km in (20.0, 30.0, 40.0, 50.0):
        expected_arcsec = 2350.1074 * math.exp(-0.10326788 * h_km)
        got = refraction_angle_rad(h_km * 1e3)
        assert got == pytest.approx(expected_arcsec * ARCSEC, rel=1e-13)
    # vectorized, and the inverse round trip for both models
    h = np.linspace(*REFRACTION_VALID_BAND_M, 31)
    for model in REFRACTION_MODELS:
        g = refraction_angle_rad(h, model)
        assert np.all(np.diff(g) < 0)
        np.testing.assert_allclose(tangent_height_from_refraction_m(g, model), h, atol=1e-8)
    assert REFRACTION_VALID_BAND_M == (20e3, 50e3)
    np.testing.assert_array_equal(in_valid_band([19.9e3, 20e3, 35e3, 50e3, 50.1e3]),
                                  [False, True, True, True, False])


def test_density_model_follows_us76_physics():
    """gamma = k rho(h) sqrt(2 pi R_t / H) with US-1976 densities: the exponential fit stays
    within 8 % of the tabulated density at every tabulated height of the band."""
    m = REFRACTION_MODELS["exponential-density"]
    assert 6.0e3 < m.scale_height_m < 7.5e3  # stratospheric density scale height
    factor = GLADSTONE_DALE_M3_KG * np.sqrt(2 * np.pi * (R_EARTH_M + m.h_ref_m) / m.scale_height_m)
    for h, rho in US76_DENSITY_KG_M3.items():
        got = refraction_angle_rad(h, "exponential-density")
        assert got == pytest.approx(factor * rho, rel=0.08)


def test_inverse_rejects_nonpositive_angle_and_unknown_model():
    with pytest.raises(ValueError, match="positive"):
        tangent_height_from_refraction_m(np.array([1e-4, 0.0]))
    with pytest.raises(ValueError, match="unknown refraction model"):
        refraction_angle_rad(30e3, "isothermal")


def test_apparent_height_without_refraction_is_closest_approach(rng):
    """gamma = 0: h_a is the straight line's closest approach to the Earth centre minus R_e + a
    (checked by brute-force minimization along the line of sight)."""
    r = random_positions_m(rng, 5)
    s = star_for_tangent_height(r, np.full(5, 30e3), np.zeros(5), rng=rng)
    h_a, _ = apparent_tangent_height_m(r, s, np.zeros(5), R_EARTH_M, A_OBL_M)
    t = np.linspace(0, 2 * 4.0e7, 400001)
    for k in range(5):
        d = np.linalg.norm(r[k] + t[:, None] * s[k], axis=1)
        i = np.argmin(d)
        tt = np.linspace(t[max(i - 1, 0)], t[i + 1], 20001)
        d_min = np.min(np.linalg.norm(r[k] + tt[:, None] * s[k], axis=1))
        assert h_a[k] == pytest.approx(d_min - R_EARTH_M - A_OBL_M, abs=1e-3)


@pytest.mark.parametrize("model", sorted(REFRACTION_MODELS))
def test_zero_at_truth_and_jacobian(rng, model):
    n = 30
    r = random_positions_m(rng, n)
    h = rng.uniform(*REFRACTION_VALID_BAND_M, size=n)
    g = refraction_angle_rad(h, model)
    s = star_for_tangent_height(r, h, g, rng=rng)
    assert np.all(np.sum(r * s, axis=1) < 0)  # looking towards the limb
    e, H_r = refraction_residual(r, s, g, R_EARTH_M, A_OBL_M, model)
    assert e.shape == (n, 1) and H_r.shape == (n, 1, 3)
    np.testing.assert_allclose(e, 0.0, atol=1e-6)  # m
    g_meas = g * (1 + 0.05 * rng.normal(size=n))
    r_off = r + 5e3 * rng.normal(size=r.shape)
    e, H_r = refraction_residual(r_off, s, g_meas, R_EARTH_M, A_OBL_M, model)
    check_jacobians(lambda x: refraction_residual(x, s, g_meas, R_EARTH_M, A_OBL_M, model),
                    (r_off,), (H_r,), ("vector",))


def test_jacobian_at_random_geometry(rng):
    """Random stars (either side, r.s of either sign), orbits 7,000-40,000 km."""
    n = 40
    r = random_positions_m(rng, n)
    s = _unit(rng.normal(size=(n, 3)))
    g = rng.uniform(1e-5, 1e-3, size=n)
    e, H_r = refraction_residual(r, s, g)
    check_jacobians(refraction_residual, (r, s, g), (H_r, None, None), ("vector", None, None))


def test_li_patent_error_budget_monte_carlo(rng):
    """Li et al. 2017, claim 1 step 4: gamma error uniform on [-D, D], atmosphere-model error added
    to the tangent height. Simulated as a real atmosphere equal to the model shifted in
    height by the model error (so the inverse model returns h + dh_model), the residual at
    the true position has the standard deviation refraction_sigma_m gives with the
    line-of-sight term; each source can be switched off."""
    n = 40000
    r = np.tile([[0.0, R_EARTH_M + 500e3, 0.0]], (n, 1))
    h_true = np.full(n, 30e3)
    D_rad = 2.0 * ARCSEC
    sigma_model_m = 150.0
    for sig_g, sig_m in ((D_rad / math.sqrt(3), sigma_model_m), (D_rad / math.sqrt(3), 0.0),
                         (0.0, sigma_model_m)):
        dh_model = sig_m * rng.normal(size=n)
        g_real = refraction_angle_rad(h_true + dh_model)  # bending by the real atmosphere
        s = star_for_tangent_height(r, h_true, g_real, rng=rng)  # catalogue directions
        g_meas = g_real + (math.sqrt(3) * sig_g) * rng.uniform(-1, 1, size=n)
        e, _ = refraction_residual(r, s, g_meas, R_EARTH_M, A_OBL_M)
        los_m = float(np.mean(np.abs(np.sum(r * s, axis=1))))
        sigma = refraction_sigma_m(float(refraction_angle_rad(30e3)), sig_g, sig_m,
                                   los_range_m=los_m)
        assert np.std(e) == pytest.approx(sigma, rel=0.03)
        assert abs(np.mean(e)) < 5 * sigma / math.sqrt(n) + 0.01 * sigma
    # the line-of-sight term matters in LEO (~13 % at 500 km altitude, 30 km tangent height)
    g30 = float(refraction_angle_rad(30e3))
    ratio = refraction_sigma_m(g30, 1.0, 0.0, los_range_m=los_m) / refraction_sigma_m(g30, 1.0, 0.0)
    assert 1.10 < ratio < 1.16


def test_sigma_matches_numerical_derivative():
    g = refraction_angle_rad(35e3)
    dg = 1e-6 * g
    h_plus = tangent_height_from_refraction_m(g + dg)
    h_minus = tangent_height_from_refraction_m(g - dg)
    dhdg = (h_plus - h_minus) / (2 * dg)
    assert refraction_sigma_m(g, 1 * ARCSEC, 0.0) == pytest.approx(abs(dhdg) * ARCSEC, rel=1e-8)
    assert refraction_sigma_m(g, 0.0, 80.0) == pytest.approx(80.0)
    both = math.hypot(abs(dhdg) * ARCSEC, 80.0)
    assert refraction_sigma_m(g, 1 * ARCSEC, 80.0) == pytest.approx(both)


def test_factor_linearizes_like_numpy(rng):
    r = random_positions_m(rng, 1, 6.9e6, 7.5e6)
    g = refraction_angle_rad(np.array([32e3]))
    s = star_for_tangent_height(r, np.array([32e3]), g, rng=rng)
    r_lin = r + [[300.0, -200.0, 100.0]]
    sigma = refraction_sigma_m(g[0], 1 * ARCSEC, 100.0)
    f = make_refraction_factor(X, s[0], g[0], sigma, R_EARTH_M, A_OBL_M)
    values = gtsam.Values()
    values.insert(X, np.concatenate([r_lin[0], [7e3, 0.0, 0.0]]))
    e, H_r = refraction_residual(r_lin, s, g, R_EARTH_M, A_OBL_M)
    A_, b = whiten(e, pad_position_jacobian(H_r), sigma)
    check_linearization(f, values, [A_[0]], b[0])
    with pytest.raises(ValueError, match="unknown refraction model"):
        make_refraction_factor(X, s[0], g[0], sigma, model="nope")


def test_bias_residual_zero_at_truth_and_sign(rng):
    """A real atmosphere shifted in height by b against the model, gamma_real(h) =
    gamma_model(h + b): at the true position the residual is -b without the bias variable and
    0 with bias_m = b (the sign the simulator's atmosphere-model error has)."""
    n = 25
    r = random_positions_m(rng, n, 6.9e6, 7.5e6)
    h = rng.uniform(22e3, 48e3, size=n)
    b = rng.uniform(-600.0, 600.0, size=n)
    g_real = refraction_angle_rad(h + b)
    s = star_for_tangent_height(r, h, g_real, rng=rng)
    e0, H0 = refraction_residual(r, s, g_real, R_EARTH_M, A_OBL_M)
    e, H_r, H_b = refraction_residual(r, s, g_real, R_EARTH_M, A_OBL_M, bias_m=b)
    assert e.shape == (n, 1) and H_r.shape == (n, 1, 3) and H_b.shape == (n, 1, 1)
    np.testing.assert_allclose(e0[:, 0], -b, atol=1e-6)  # m
    np.testing.assert_allclose(e, 0.0, atol=1e-6)
    np.testing.assert_array_equal(H_r, H0)  # the bias does not change the geometry
    # a scalar bias broadcasts to every row
    e_s, _, _ = refraction_residual(r, s, g_real, R_EARTH_M, A_OBL_M, bias_m=250.0)
    np.testing.assert_allclose(e_s[:, 0], e0[:, 0] + 250.0, rtol=0, atol=1e-9)


@pytest.mark.parametrize("model", sorted(REFRACTION_MODELS))
def test_bias_jacobians(rng, model):
    n = 30
    r = random_positions_m(rng, n, 6.9e6, 7.5e6) + 5e3 * rng.normal(size=(n, 3))
    h = rng.uniform(*REFRACTION_VALID_BAND_M, size=n)
    g = refraction_angle_rad(h, model) * (1 + 0.05 * rng.normal(size=n))
    s = star_for_tangent_height(r, h, g, rng=rng)
    b = rng.normal(0.0, 300.0, size=(n, 1))
    _, H_r, H_b = refraction_residual(r, s, g, R_EARTH_M, A_OBL_M, model, bias_m=b[:, 0])

    def f(r_, b_):
        return refraction_residual(r_, s, g, R_EARTH_M, A_OBL_M, model, bias_m=b_[:, 0])

    check_jacobians(f, (r, b), (H_r, H_b), ("vector", "vector"), names=("r_eci_m", "bias_m"))


def test_bias_factor_linearizes_like_numpy(rng):
    r = random_positions_m(rng, 1, 6.9e6, 7.5e6)
    g = refraction_angle_rad(np.array([32e3 + 300.0]))
    s = star_for_tangent_height(r, np.array([32e3]), g, rng=rng)
    r_lin = r + [[300.0, -200.0, 100.0]]
    b_lin = np.array([180.0])
    sigma = refraction_sigma_m(g[0], 1 * ARCSEC, 100.0)
    f = make_refraction_bias_factor(X, B, s[0], g[0], sigma, R_EARTH_M, A_OBL_M)
    assert list(f.keys()) == [X, B]
    values = gtsam.Values()
    values.insert(X, np.concatenate([r_lin[0], [7e3, 0.0, 0.0]]))
    values.insert(B, b_lin)
    e, H_r, H_b = refraction_residual(r_lin, s, g, R_EARTH_M, A_OBL_M, bias_m=b_lin)
    (A_x, A_b), b = whiten(e, [pad_position_jacobian(H_r), H_b], sigma)
    check_linearization(f, values, [A_x[0], A_b[0]], b[0])
    assert f.error(values) == pytest.approx(0.5 * (e[0, 0] / sigma) ** 2, rel=1e-12)
    with pytest.raises(ValueError, match="unknown refraction model"):
        make_refraction_bias_factor(X, B, s[0], g[0], sigma, model="nope")
