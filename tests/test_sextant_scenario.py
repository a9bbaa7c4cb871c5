"""The sextant in low Earth orbit (built-in scenario ``sextant-leo``: star - Earth-limb,
Moon - star and Earth - Moon angles, no attitude): the smoother against the truth of the
independent DOP853 integrator and against the Cramér–Rao bound (``fgnav.diagnostics.crb``,
the information of every row mapped to the first state, evaluated along the truth), and
its NEES over many seeds."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from fgnav.diagnostics.crb import cramer_rao_bound
from fgnav.cli import main
from fgnav.measurements import build_pass
from fgnav.models.registry import BODY_BODY_ANGLE, BODY_STAR_ANGLE, LIMB_STAR_ANGLE
from fgnav.pipeline import accuracy_metrics, solve
from fgnav.scenarios import load_scenario
from fgnav.simulate.pass_sim import simulate_pass


def _runs(seeds, duration_h, methods=("batch",)):
    out = {m: [] for m in methods}
    crb = None
    for seed in seeds:
        sim = simulate_pass(load_scenario("sextant-leo").with_options(duration_h=duration_h),
                            seed=seed)
        p = build_pass(sim.log)
        assert {LIMB_STAR_ANGLE.kind, BODY_STAR_ANGLE.kind, BODY_BODY_ANGLE.kind} <= set(p.families)
        xt = sim.x_true[np.searchsorted(sim.t_s, p.t_s)]
        if crb is None:   # the truth and the star choice do not depend on the seed
            crb = cramer_rao_bound(p, xt)
        for m in methods:
            sol = solve(p, m)
            out[m].append(accuracy_metrics(sol, sim.x_true[np.searchsorted(sim.t_s, sol.t_s)]))
    return out, crb


def test_the_smoother_reaches_the_bound_with_a_credible_covariance_over_20_seeds():
    seeds = range(20)
    runs, crb = _runs(seeds, 3.0)
    b = runs["batch"]
    sig = np.mean([m["sigma_position_rms_m"] for m in b])
    pos = np.sqrt(np.mean([m["position_rms_m"] ** 2 for m in b]))
    vel = np.sqrt(np.mean([m["velocity_rms_mps"] ** 2 for m in b]))
    # the smoother's covariance is the bound (same information, linear enough)
    assert sig == pytest.approx(crb.position_rms_m, rel=0.02)
    # its errors over 20 seeds: the bound within the sampling spread of 20 passes
    assert 0.8 * crb.position_rms_m < pos < 1.25 * crb.position_rms_m, (pos, crb.position_rms_m)
    assert 0.8 * crb.velocity_rms_mps < vel < 1.25 * crb.velocity_rms_mps
    nees = np.mean([m["nees_mean"] for m in b])
    lo, hi = chi2.ppf([0.025, 0.975], 6 * len(seeds)) / len(seeds)
    assert lo < nees < hi, (nees, lo, hi)
    assert crb.position_rms_m < 200.0      # the sextant fixes LEO to ~100 m (0.005 deg angles)


@pytest.mark.slow
def test_six_hour_passes_over_30_seeds_and_the_ekf_behind_the_smoother():
    seeds = range(100, 130)
    runs, crb = _runs(seeds, 6.0, methods=("batch", "ekf"))
    pos = np.sqrt(np.mean([m["position_rms_m"] ** 2 for m in runs["batch"]]))
    ekf = np.sqrt(np.mean([m["position_rms_m"] ** 2 for m in runs["ekf"]]))
    assert 0.85 * crb.position_rms_m < pos < 1.2 * crb.position_rms_m
    nees = np.mean([m["nees_mean"] for m in runs["batch"]])
    lo, hi = chi2.ppf([0.025, 0.975], 6 * len(seeds)) / len(seeds)
    print(f"sextant-leo 6 h, {len(seeds)} seeds: batch {pos:.1f} m (bound "
          f"{crb.position_rms_m:.1f} m), NEES {nees:.2f} (band {lo:.2f}-{hi:.2f}), EKF {ekf:.1f} m")
    assert lo < nees < hi, (nees, lo, hi)
    assert ekf > 1.5 * pos


def test_schemes_position_surfaces_prints_the_table_and_its_json(capsys):
    import json

    assert main(["schemes", "position-surfaces", "--duration-h", "0.5", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["scheme"] == "position-surfaces" and r["n_fixes"] == len(r["epochs"]) > 20
    e = r["epochs"][0]
    assert set(e) == {"t_s", "fix_error_m", "fix_sigma_m", "roots", "smoother_error_m",
                      "smoother_sigma_m"}
    # the smoother, using every epoch and the dynamics, beats the single-epoch fixes
    assert r["batch_position_rms_m"] < 0.5 * r["fix_rms_m"]
    assert 1.0 < r["fix_nees"] < 6.0
    assert main(["schemes", "position-surfaces", "--duration-h", "0.2"]) == 0
    out = capsys.readouterr().out
    assert "fix err m" in out and "Cramér-Rao bound" in out


@pytest.mark.parametrize("drop", [
    ("prior_",),
    # star-Earth-limb angles alone: no closed form, the roots are searched
    ("prior_", "body_star_angle", "body_body_angle")])
def test_without_prior_rows_the_sextant_starts_from_its_geometric_fixes(tmp_path, drop):
    """No prior: the Moon-star cones and the Earth-Moon torus give closed-form fixes, or
    (limb angles alone) the roots are searched from a grid of starts; the track of roots
    over a short arc (fgnav.iod.geometric.MAX_TRACK_ARC of the period: a LEO's fixes hours
    apart are revolutions apart) gives the orbit, and the smoother reaches the solution it
    reaches with the prior."""
    from fgnav.io.log_csv import read_log, write_log
    from fgnav.pipeline import smooth_log

    sim = simulate_pass(load_scenario("sextant-leo").with_options(duration_h=1.0), seed=4)
    full = tmp_path / "full.csv"
    write_log(full, sim.log)
    lines = full.read_text().splitlines(keepends=True)
    kept = [ln for ln in lines if not any(f",{k}" in ln for k in drop)]
    (tmp_path / "cut.csv").write_text("".join(kept))
    assert len(lines) - len(kept) >= 2
    keep_ref = [ln for ln in lines if not any(f",{k}" in ln for k in drop if k != "prior_")]
    (tmp_path / "ref.csv").write_text("".join(keep_ref))
    truth = (sim.t_s, sim.x_true)
    res, _ = smooth_log(read_log(tmp_path / "cut.csv"), truth=truth)
    ref, _ = smooth_log(read_log(tmp_path / "ref.csv"), truth=truth)
    assert res.summary["initial_orbit"]["method"] == "geometric-fixes+lm"
    m, m_ref = res.summary, ref.summary
    # the same optimum and covariance as with the prior (whose 10 km / 10 m/s add little)
    assert m["position_rms_m"] == pytest.approx(m_ref["position_rms_m"], rel=0.01)
    assert m["sigma_position_rms_m"] == pytest.approx(m_ref["sigma_position_rms_m"], rel=0.01)
