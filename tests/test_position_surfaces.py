"""Geometric fixes (fgnav.iod.surfaces): the INS/CNS lecture's worked example -- a
Mars-transfer cruise fixed from two Sun-star angles (cones ``r . i = -r cos A``) and one
Sun-Earth angle (the torus ``r . r_p = r^2 - r |r - r_p| cos A``), "the redundant points
removed with the previous orbit" -- and the fixes of a simulated sextant pass against truth."""

from __future__ import annotations

import numpy as np
import pytest

from factors.celestial_angles import body_body_angle_residual, body_star_angle_residual
from fgnav.iod.surfaces import fibonacci_directions, intersect_surfaces, position_surface_fixes
from fgnav.measurements import build_pass
from fgnav.scenarios import load_scenario
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.iod.prior import initial_guess
from fgnav.solvers.options import SmootherOptions
from fgnav.time import j2000_seconds

AU_M = 1.495978707e11
SIGMA_RAD = 1e-5                      # 2 arcsec: an arcsecond-class star sensor


def _angle(a, b):
    return float(np.arccos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1, 1)))


def _cruise(rng):
    """Heliocentric frame (the Sun at the origin): the Earth at 1 AU, the spacecraft at 1.3 AU
    35 deg ahead of it and 2 deg out of the ecliptic; two stars; the three true angles."""
    earth = AU_M * np.array([1.0, 0.0, 0.0])
    th = np.radians(35.0)
    sc = 1.3 * AU_M * np.array([np.cos(th), np.sin(th), np.sin(np.radians(2.0))])
    stars = np.array([[0.2, 0.9, 0.4], [-0.7, 0.1, 0.7]])
    stars /= np.linalg.norm(stars, axis=1, keepdims=True)
    A = np.array([_angle(-sc, stars[0]), _angle(-sc, stars[1]), _angle(-sc, earth - sc)])
    return earth, sc, stars, A


def _residual(earth, stars, A):
    """Whitened residuals of the lecture's three surfaces at a heliocentric position."""
    def residual(r):
        R = np.tile(r, (2, 1))
        e1, H1 = body_star_angle_residual(R, np.zeros((2, 3)), stars, A[:2])
        e2, H2 = body_body_angle_residual(r[None], np.zeros((1, 3)), earth[None], A[2:])
        return (np.concatenate([e1[:, 0], e2[:, 0]]) / SIGMA_RAD,
                np.concatenate([H1[:, 0], H2[:, 0]]) / SIGMA_RAD)
    return residual


def test_the_lectures_two_cones_and_torus_have_several_roots_and_the_previous_orbit_picks_one():
    rng = np.random.default_rng(18)
    earth, sc, stars, A = _cruise(rng)
    # the lecture's equations hold at the truth
    for i, a in zip(stars, A[:2]):
        assert sc @ i == pytest.approx(-np.linalg.norm(sc) * np.cos(a), rel=1e-12)
    rn = np.linalg.norm(sc)
    assert sc @ earth == pytest.approx(rn ** 2 - rn * np.linalg.norm(sc - earth) * np.cos(A[2]),
                                       rel=1e-12)
    res = _residual(earth, stars, A)
    prior = sc + np.array([2e9, -1e9, 5e8])                 # the previous orbit, 2.5e6 km off
    starts = np.concatenate([s * fibonacci_directions(48) for s in (0.7 * rn, 1.3 * rn, 2 * rn)])
    fix = intersect_surfaces(res, prior, starts=starts)
    assert fix is not None and fix.m == 3 and fix.chi2 < 1e-12
    assert len(fix.roots) >= 2, "the three surfaces meet in more than one point"
    np.testing.assert_allclose(fix.r_eci_m, sc, atol=1.0)     # noise-free: exact to < 1 m
    far = [np.linalg.norm(r - sc) for r in fix.roots[1:]]
    assert min(far) > 1e9, "the other roots are distinct points"
    for r in fix.roots:                                      # every root lies on all three
        b, _ = res(r)
        assert np.max(np.abs(b)) < 1e-6
    # a prior next to another root picks that one instead: the prior decides
    other = fix.roots[1]
    fix2 = intersect_surfaces(res, other + 1e8, starts=starts)
    np.testing.assert_allclose(fix2.r_eci_m, other, atol=1.0)


def test_the_fix_covariance_from_the_gradients_matches_monte_carlo():
    """``P = (J^T W J)^-1`` against the scatter of 300 fixes from noisy angles."""
    rng = np.random.default_rng(7)
    earth, sc, stars, A = _cruise(rng)
    fix = intersect_surfaces(_residual(earth, stars, A), sc + 1e7, starts=np.zeros((0, 3)))
    errs = []
    for _ in range(300):
        An = A + SIGMA_RAD * rng.standard_normal(3)
        f = intersect_surfaces(_residual(earth, stars, An), sc + 1e7, starts=np.zeros((0, 3)))
        errs.append(f.r_eci_m - sc)
    errs = np.array(errs)
    C = errs.T @ errs / len(errs)
    nees = np.mean(np.einsum("ki,ij,kj->k", errs, np.linalg.inv(fix.P_m2), errs))
    assert 2.6 < nees < 3.4                                   # chi2(900)/300: 2.74..3.27 (99 %)
    assert np.sqrt(np.trace(C)) == pytest.approx(np.sqrt(np.trace(fix.P_m2)), rel=0.15)


def test_sextant_fixes_against_truth_are_consistent_with_their_covariance():
    sim = simulate_pass(load_scenario("sextant-leo").with_options(duration_h=1.0), seed=1)
    p = build_pass(sim.log)
    xg = initial_guess(p, SmootherOptions().motion_model(), float(j2000_seconds(p.epoch0)))
    fixes, n_roots = position_surface_fixes(p, xg)
    assert len(fixes.k) == p.n_epochs
    xt = sim.x_true[np.searchsorted(sim.t_s, fixes.t_s)]
    d = fixes.r_eci_m - xt[:, :3]
    nees = np.einsum("ki,kij,kj->k", d, np.linalg.inv(fixes.P_m2), d)
    lo, hi = [2.3, 3.8]                          # chi2(3 x 61)/61 at 99.9 %: 2.3..3.8
    assert lo < nees.mean() < hi, nees.mean()
    # far better than the prior orbit it started from (which is ~100 km off)
    prior_err = np.linalg.norm(xg[fixes.k, :3] - xt[:, :3], axis=1)
    assert np.median(prior_err) > 20e3 and np.sqrt(np.mean(np.sum(d ** 2, 1))) < 2e3
    assert np.any(n_roots >= 2)                  # spurious roots were found, and removed
