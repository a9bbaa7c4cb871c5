"""NEES / NIS / ANEES and their chi-square bands (fgnav.diagnostics.consistency)."""

from __future__ import annotations

import numpy as np
import pytest

from fgnav.diagnostics.consistency import (anees, chi2_band, nees, nees_curve, nis_ekf, nis_smoother,
                                        nis_summary)


def _random_spd(rng, d=6):
    A = rng.standard_normal((d, d))
    return A @ A.T + d * np.eye(d)


def test_chi2_band_covers_95_percent_of_simulated_anees():
    rng = np.random.default_rng(1)
    lo, hi = chi2_band(6, 100)
    means = rng.chisquare(6, size=(20000, 100)).mean(axis=1)
    frac = np.mean((means >= lo) & (means <= hi))
    assert 0.94 < frac < 0.96
    assert lo < 6 < hi
    with pytest.raises(ValueError):
        chi2_band(6, 0)


def test_nees_matches_definition_and_chi2_mean():
    rng = np.random.default_rng(2)
    P = _random_spd(rng)
    L = np.linalg.cholesky(P)
    e = (L @ rng.standard_normal((6, 50000))).T
    v = nees(e, np.broadcast_to(P, (len(e), 6, 6)), np.zeros_like(e))
    assert v[0] == pytest.approx(e[0] @ np.linalg.inv(P) @ e[0], rel=1e-10)
    assert abs(v.mean() - 6.0) < 0.1
    # an overconfident covariance (half the true one) doubles the ANEES and leaves the band
    a = anees(nees(e[:200], np.broadcast_to(P / 2, (200, 6, 6)), np.zeros((200, 6))))
    assert not a.inside and a.ratio == pytest.approx(2.0, rel=0.15)
    good = anees(v[:200])
    assert good.inside and good.n_runs == 200


def test_nees_curve_shape_and_fraction():
    rng = np.random.default_rng(3)
    runs = rng.chisquare(6, size=(100, 400))
    curve, lo, hi, frac = nees_curve(runs)
    assert curve.shape == (400,) and 0.9 < frac <= 1.0
    assert (lo, hi) == chi2_band(6, 100)
    _, _, _, frac_bad = nees_curve(runs * 1.5)
    assert frac_bad < 0.2
    with pytest.raises(ValueError):
        nees_curve(runs[0])


@pytest.fixture(scope="module")
def monte_carlo():
    """20 runs of gto-transfer (1 h at 60 s, random a-priori error): batch and EKF."""
    from fgnav.measurements import build_pass
    from fgnav.pipeline import solve
    from fgnav.scenarios import load_scenario
    from fgnav.simulate.pass_sim import simulate_pass
    from fgnav.solvers.options import SmootherOptions

    scn = load_scenario("gto-transfer").with_options(step_s=60.0, duration_h=1.0)
    opt = SmootherOptions()
    out = []
    for seed in range(20):
        sim = simulate_pass(scn, seed)
        p = build_pass(sim.log)
        sols = {m: solve(p, m, opt) for m in ("batch", "ekf")}
        out.append((sim, p, sols))
    return opt, out


def test_ekf_nis_reconstructs_the_filter_innovations(monte_carlo):
    from fgnav.graph import linearize_family

    opt, runs = monte_carlo
    sim, p, sols = runs[0]
    sol = sols["ekf"]
    nis, dof = nis_ekf(p, sol, opt)
    assert len(nis) == p.n_epochs - 1 and set(dof) == {2}
    # the EKF stored its whitened innovations: |nu|^2 must equal what the predicted state gives
    stored = sol.residuals["earth_direction"]
    fam = p.families["earth_direction"]
    # recompute the predicted state of epoch 5 independently of nis_ekf
    from factors.dynamics import propagate
    from fgnav.time import j2000_seconds

    k = 5
    x_pred, _ = propagate(sol.x_eci[k - 1], p.t_s[k] - p.t_s[k - 1], opt.motion_model(),
                          float(j2000_seconds(p.epoch0)) + p.t_s[k - 1])
    row = int(np.flatnonzero(fam.k == k)[0])
    _, _, b, _ = linearize_family(p, "earth_direction", fam.subset(np.array([row]), 0), x_pred[None])
    np.testing.assert_allclose(-np.ravel(b), stored[row], rtol=1e-9, atol=1e-12)


def test_nis_of_ekf_and_smoother_inside_band(monte_carlo):
    opt, runs = monte_carlo
    for method in ("ekf", "batch"):
        ns, ds = [], []
        for sim, p, sols in runs:
            n, d = nis_ekf(p, sols[method], opt) if method == "ekf" else nis_smoother(p, sols[method])
            assert np.all(n >= 0)
            ns.append(n)
            ds.append(d)
        s = nis_summary(np.concatenate(ns), np.concatenate(ds))
        assert s["nis_band_lo"] <= s["nis_per_dof"] <= s["nis_band_hi"], (method, s)


def test_anees_of_smoother_and_ekf_final_epoch_20_runs(monte_carlo):
    opt, runs = monte_carlo
    for method in ("batch", "ekf"):
        final = []
        for sim, p, sols in runs:
            sol = sols[method]
            x_true = sim.x_true[sim.t_s.searchsorted(sol.t_s)]
            final.append(nees(sol.x_eci[-1:], sol.P_eci[-1:], x_true[-1:])[0])
        a = anees(final)
        assert a.inside, (method, a.as_dict())
