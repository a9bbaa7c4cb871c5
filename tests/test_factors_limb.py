"""Limb angular-radius residual (factors.limb)."""

import gtsam
import numpy as np
import pytest

from factors.adapters import pad_position_jacobian, whiten
from factors.constants import DEG, R_LIMB_UV_M
from factors.limb import limb_radius_residual, make_limb_radius_factor
from factors.testing import check_jacobians, check_linearization, random_positions_m

N = 40
X = gtsam.symbol("x", 0)


@pytest.fixture
def rng():
    return np.random.default_rng(7002)


def test_zero_at_truth_and_jacobian(rng):
    r = random_positions_m(rng, N)
    rl = np.full(N, R_LIMB_UV_M)
    rho_true = np.arcsin(rl / np.linalg.norm(r, axis=1))
    e, H_r = limb_radius_residual(r, rho_true, rl)
    assert e.shape == (N, 1) and H_r.shape == (N, 1, 3)
    np.testing.assert_allclose(e, 0.0, atol=1e-15)
    rho_meas = rho_true + 0.01 * DEG * rng.normal(size=N)
    e, H_r = limb_radius_residual(r, rho_meas, rl)
    np.testing.assert_allclose(e[:, 0], rho_true - rho_meas, atol=1e-15)
    check_jacobians(limb_radius_residual, (r, rho_meas, rl), (H_r, None, None),
                    ("vector", None, None))


def test_wu_apparent_diameter():
    """Wu et al.: Earth apparent diameter 77.232 deg at 4,000 km and
    17.579 deg at 36,000 km with omega = arcsin((R + d)/(R + H)), R = 6,375 km, d = 100 km."""
    r_limb = R_LIMB_UV_M + 100e3
    for alt_m, diameter_deg in ((4000e3, 77.232), (36000e3, 17.579)):
        r = np.array([[0.0, R_LIMB_UV_M + alt_m, 0.0]])
        e, _ = limb_radius_residual(r, np.array([diameter_deg / 2 * DEG]), np.array([r_limb]))
        assert abs(e[0, 0]) < 0.0005 * DEG  # table rounded to 0.001 deg


def test_range_sensitivity_falls_with_altitude():
    """|d rho / d|r|| = R / (|r| sqrt(|r|^2 - R^2)): the limb fixes range worse when high."""
    alts = np.array([500e3, 4000e3, 36000e3])
    r = np.stack([R_LIMB_UV_M + alts, 0 * alts, 0 * alts], axis=1)
    _, H_r = limb_radius_residual(r, np.zeros(3), np.full(3, R_LIMB_UV_M))
    n = np.linalg.norm(r, axis=1)
    expected = R_LIMB_UV_M / (n * np.sqrt(n**2 - R_LIMB_UV_M**2))
    np.testing.assert_allclose(-H_r[:, 0, 0], expected, rtol=1e-12)
    assert np.all(np.diff(np.abs(H_r[:, 0, 0])) < 0)


def test_inside_limb_raises():
    r = np.array([[7.0e6, 0, 0], [R_LIMB_UV_M - 1.0, 0, 0]])
    with pytest.raises(ValueError, match="limb radius"):
        limb_radius_residual(r, np.zeros(2), np.full(2, R_LIMB_UV_M))


def test_factor_linearizes_like_numpy(rng):
    r = random_positions_m(rng, 1)
    rl = np.array([R_LIMB_UV_M])
    rho = np.arcsin(rl / np.linalg.norm(r, axis=1)) + 0.003
    sigma = 0.02 * DEG
    f = make_limb_radius_factor(X, rho[0], rl[0], sigma)
    values = gtsam.Values()
    values.insert(X, np.concatenate([r[0], [1.0, 2.0, 3.0]]))
    e, H_r = limb_radius_residual(r, rho, rl)
    A_, b = whiten(e, pad_position_jacobian(H_r), sigma)
    check_linearization(f, values, [A_[0]], b[0])
