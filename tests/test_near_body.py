"""factors.near_body (limb radius and centre direction of the Earth, the Moon and the Sun,
with light time and aberration): analytic Jacobians (factors.testing), the Earth's limb as
factors.limb has it, the models against the independent simulator of
fgnav.simulate.near_bodies (barycentric, iterated light time, ERFA's ab) to the simulator's
precision, and what each correction is worth."""

import numpy as np
import pytest

from factors.constants import R_EARTH_M, R_MOON_M, R_SUN_M
from factors.jpl_ephemeris import moon_state_de421, sun_state_de421
from factors.limb import limb_radius_residual
from factors.near_body import (
    make_near_body_direction_factor, make_near_body_limb_factor,
    near_body_direction_body_residual, near_body_direction_residual, near_body_limb_residual,
)
from factors.testing import check_jacobians, random_rotations
from fgnav.simulate.near_bodies import apparent_body

T0 = 8.5e8
N = 12
RADIUS = {"earth": R_EARTH_M, "moon": R_MOON_M, "sun": R_SUN_M}


def _translunar(rng, n=N):
    """Spacecraft between the Earth and the Moon (60,000-300,000 km out, 0.8-3 km/s), at
    hourly epochs."""
    t = T0 + np.arange(n) * 3600.0
    rm, _ = moon_state_de421(t)
    f = rng.uniform(0.15, 0.8, n)
    r = f[:, None] * rm + rng.normal(size=(n, 3)) * 2e7
    v = rng.normal(size=(n, 3))
    v *= rng.uniform(800.0, 3000.0, n)[:, None] / np.linalg.norm(v, axis=1)[:, None]
    return t, np.column_stack([r, v])


def _lunar(rng, n=N):
    """Moon-centred states 3,000-70,000 km from the Moon (an NRHO's range), 0.1-1.6 km/s."""
    t = T0 + np.arange(n) * 3600.0
    r = rng.normal(size=(n, 3))
    r *= rng.uniform(R_MOON_M + 3e6, 7e7, n)[:, None] / np.linalg.norm(r, axis=1)[:, None]
    v = rng.normal(size=(n, 3))
    v *= rng.uniform(100.0, 1600.0, n)[:, None] / np.linalg.norm(v, axis=1)[:, None]
    return t, np.column_stack([r, v])


def _body_in_frame(body, t, centre):
    """The body's position and velocity in the pass's frame, from DE421 (the models' input)."""
    rm, vm = moon_state_de421(t)
    rs, vs = sun_state_de421(t)
    geo = {"earth": (np.zeros_like(rm), np.zeros_like(vm)), "moon": (rm, vm), "sun": (rs, vs)}[body]
    if centre == "moon":
        return geo[0] - rm, geo[1] - vm
    return geo


def _angle(a, b):
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.sum(a * b, axis=1))


@pytest.mark.parametrize("body", ["earth", "moon", "sun"])
def test_jacobians(body):
    rng = np.random.default_rng(7)
    t, x = _translunar(rng)
    p, v = _body_in_frame(body, t, "earth")
    w = p - x[:, :3]
    rho = np.arcsin(RADIUS[body] / np.linalg.norm(w, axis=1)) + 1e-5
    for lt in (True, False):
        for ab in (True, False):
            e, H = near_body_limb_residual(x, rho, RADIUS[body], p, v, lt, ab)
            check_jacobians(lambda xx: near_body_limb_residual(xx, rho, RADIUS[body], p, v, lt, ab),
                            (x,), (H,), kinds=("vector",))
    u = w / np.linalg.norm(w, axis=1)[:, None] + rng.normal(size=(N, 3)) * 1e-4
    u /= np.linalg.norm(u, axis=1)[:, None]
    for lt in (True, False):
        for ab in (True, False):
            e, H = near_body_direction_residual(x, u, p, v, lt, ab)
            check_jacobians(lambda xx: near_body_direction_residual(xx, u, p, v, lt, ab), (x,),
                            (H,), kinds=("vector",))
            if not ab:
                assert np.all(H[:, :, 3:] == 0.0)
    R = random_rotations(rng, N)
    ub = np.einsum("nji,nj->ni", R, u)
    e, Hx, HR = near_body_direction_body_residual(x, R, ub, p, v)
    check_jacobians(lambda xx, RR: near_body_direction_body_residual(xx, RR, ub, p, v), (x, R),
                    (Hx, HR), kinds=("vector", "rot3"))
    # the body-frame row is the ECI row rotated: the same angle (each in its own tangent basis)
    assert np.allclose(np.linalg.norm(near_body_direction_residual(x, u, p, v)[0], axis=1),
                       np.linalg.norm(e, axis=1), rtol=1e-9, atol=1e-15)


def test_earth_limb_is_the_existing_kind():
    """The Earth from a geocentric pass (p = 0, v_b = 0) without aberration (the existing
    kind's meaning, which the empty body column keeps): factors.limb's residual exactly,
    its Jacobian to rounding (the same equation, its terms in another order)."""
    rng = np.random.default_rng(2)
    _, x = _translunar(rng)
    rho = np.full(N, 0.02)
    e0, H0 = limb_radius_residual(x[:, :3], rho, R_EARTH_M)
    e1, H1 = near_body_limb_residual(x, rho, R_EARTH_M, np.zeros(3), np.zeros(3), aberration=False)
    assert np.array_equal(e0, e1) and np.allclose(H0, H1[:, :, :3], rtol=1e-14, atol=0)
    assert np.all(H1[:, :, 3:] == 0.0)


@pytest.mark.parametrize("centre", ["earth", "moon"])
@pytest.mark.parametrize("body", ["earth", "moon", "sun"])
def test_model_against_simulator(body, centre):
    """The first-order planetary aberration against the simulator's barycentric light time
    and ERFA's ab: within 3 mas for every body (the remainder ~ beta^2 with the Earth's
    30 km/s, and the Earth's curved path over the Sun's 500 s); the limb radius within 3 mas
    too (measured 2 mas at worst, the Earth 4.4 deg across from 84,000 km: the simulator
    takes the limb at the centre's light time, the limb being nearer by ~R^2/2d, and
    averages the aberrated limb, both ~ beta rho^2; relative to rho 1e-8 or less beyond)."""
    rng = np.random.default_rng(11)
    t, x = (_translunar if centre == "earth" else _lunar)(rng)
    p, v = _body_in_frame(body, t, centre)
    if centre == body:   # the central body: seen from the spacecraft, at the origin
        assert np.all(p == 0.0)
    u_sim, rho_sim, tau = apparent_body(body, t, x, RADIUS[body], centre=centre)
    e, _ = near_body_direction_residual(x, u_sim, p, v)
    assert np.linalg.norm(e, axis=1).max() < 1.5e-8
    e, _ = near_body_limb_residual(x, rho_sim, RADIUS[body], p, v)
    assert np.abs(e[:, 0]).max() < 1.5e-8
    if body == "moon" and centre == "earth":
        assert 0.15 < tau.min() and tau.max() < 1.4


def test_what_each_correction_is_worth():
    """From the translunar coast, against the simulator: the Moon without its light time is
    off by its velocity across the line of sight over c (~0.3-0.7 arcsec), the directions
    without aberration by the spacecraft's own (0.2-2 arcsec), the Sun without its light
    time by the Earth's velocity (20.5 arcsec: the annual aberration); each more than 30
    times the full model's error; the limb radius by ~1e-5 of itself."""
    rng = np.random.default_rng(5)
    t, x = _translunar(rng)
    arcsec = np.pi / 180 / 3600
    p, v = _body_in_frame("moon", t, "earth")
    u_sim = apparent_body("moon", t, x, R_MOON_M)[0]
    full = np.linalg.norm(near_body_direction_residual(x, u_sim, p, v)[0], axis=1)
    no_lt = np.linalg.norm(near_body_direction_residual(x, u_sim, p, v, light_time=False)[0], axis=1)
    no_ab = np.linalg.norm(near_body_direction_residual(x, u_sim, p, v, aberration=False)[0], axis=1)
    u = (p - x[:, :3]) / np.linalg.norm(p - x[:, :3], axis=1)[:, None]
    cross = lambda w: np.linalg.norm(w - np.sum(w * u, axis=1)[:, None] * u, axis=1) / 299792458.0
    assert np.allclose(no_lt, cross(v), rtol=0.05, atol=0.01 * arcsec)     # the Moon's motion
    assert np.allclose(no_ab, cross(x[:, 3:]), rtol=0.05, atol=0.01 * arcsec)   # the observer's
    assert 0.1 * arcsec < no_lt.min() and no_lt.max() < 0.8 * arcsec
    assert no_lt.min() > 30 * full.max() and no_ab.min() > 30 * full.max()
    ps, vs = _body_in_frame("sun", t, "earth")
    us = apparent_body("sun", t, x, R_SUN_M)[0]
    no_ab = np.linalg.norm(near_body_direction_residual(x, us, ps, vs, aberration=False)[0], axis=1)
    no_lt = np.linalg.norm(near_body_direction_residual(x, us, ps, vs, light_time=False)[0], axis=1)
    # the Sun's light time carries the Earth's 30 km/s (the annual aberration, 20.5 arcsec);
    # without the aberration of the spacecraft's own velocity, that velocity's part is missing
    us_ = (ps - x[:, :3]) / np.linalg.norm(ps - x[:, :3], axis=1)[:, None]
    cross_s = lambda w: np.linalg.norm(w - np.sum(w * us_, axis=1)[:, None] * us_, axis=1) / 299792458.0
    assert 19 * arcsec < no_lt.min() and no_lt.max() < 21.5 * arcsec
    assert np.allclose(no_lt, cross_s(vs), rtol=0.01)
    assert np.allclose(no_ab, cross_s(x[:, 3:]), rtol=0.05, atol=0.01 * arcsec)
    # the Moon's limb radius: the corrections scale it by (v - v_b) . u/c, ~1e-5
    rho_sim = apparent_body("moon", t, x, R_MOON_M)[1]
    full = np.abs(near_body_limb_residual(x, rho_sim, R_MOON_M, p, v)[0][:, 0])
    none = np.abs(near_body_limb_residual(x, rho_sim, R_MOON_M, p, v, False, False)[0][:, 0])
    rel = np.abs(np.sum((x[:, 3:] - v) * u, axis=1)) / 299792458.0
    assert np.allclose(none / rho_sim, rel, rtol=0.02, atol=1e-9)
    assert full.max() < 0.01 * none.max()


def test_gtsam_factors_are_the_residuals():
    """The GTSAM adapters linearize to the numpy residuals' rows (whitened by sigma)."""
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(4)
    t, x = _translunar(rng, 3)
    p, v = _body_in_frame("moon", t, "earth")
    w = p - x[:, :3]
    u = w / np.linalg.norm(w, axis=1)[:, None] + 1e-5
    u /= np.linalg.norm(u, axis=1)[:, None]
    R = random_rotations(rng, 3)
    ub = np.einsum("nji,nj->ni", R, u)
    rho = np.arcsin(R_MOON_M / np.linalg.norm(w, axis=1)) + 2e-6
    sig = 1e-5
    for k in range(3):
        vals = gtsam.Values()
        vals.insert(0, x[k])
        vals.insert(1, gtsam.Rot3(R[k]))
        e, H = near_body_limb_residual(x[k:k + 1], rho[k], R_MOON_M, p[k], v[k])
        lf = make_near_body_limb_factor(0, rho[k], R_MOON_M, p[k], v[k], sig).linearize(vals)
        A, b = lf.jacobian()
        assert np.allclose(A, H[0] / sig, rtol=1e-12) and np.allclose(-b, e[0] / sig, rtol=1e-12)
        e, Hx = near_body_direction_residual(x[k:k + 1], u[k], p[k], v[k])
        A, b = make_near_body_direction_factor(0, u[k], p[k], v[k], sig).linearize(vals).jacobian()
        assert np.allclose(A, Hx[0] / sig, rtol=1e-12) and np.allclose(-b, e[0] / sig, rtol=1e-12)
        e, Hx, HR = near_body_direction_body_residual(x[k:k + 1], R[k:k + 1], ub[k], p[k], v[k])
        A, b = make_near_body_direction_factor(0, ub[k], p[k], v[k], sig, key_R=1).linearize(vals).jacobian()
        assert np.allclose(A, np.hstack([Hx[0], HR[0]]) / sig, rtol=1e-9, atol=1e-12)
        assert np.allclose(-b, e[0] / sig, rtol=1e-9)
