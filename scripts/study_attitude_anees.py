"""Consistency of the joint orbit-attitude solution: ANEES of the 9-dimensional error.

    python scripts/study_attitude_anees.py [--runs 50] [--seed0 0] [--methods batch,isam2]
                                           [--out DIR]

Each run simulates 20 minutes of LEO (the ``refraction-leo`` orbit at a 10 s step, truth from
the independent DOP853 integrator with J2; its prior drawn at random about the truth) with an
altimeter (50 m) and, under a true attitude that follows the estimator's own attitude model
(a random walk on SO(3) of the attitude variable's spectral density,
``fgnav.simulate.attitude_profiles.random_walk``: a check of the estimator, not of the
model), attitude rows (0.2 mrad) at one epoch in three and Earth directions in the body frame
(0.3 mrad, factors on orbit and attitude) at every epoch; it is solved with
``--estimate attitude``. The error of each epoch is ``[r - r_true, v - v_true,
Log(R_true^T R)]`` (m, m/s, rad; the attitude error a right perturbation, as the solvers'
covariance is) and its NEES ``e^T P^-1 e`` with ``P`` the solver's joint 9x9 marginal
covariance of orbit and attitude (``Solution.P_block``: from the batch elimination's
block marginals, iSAM2's from the same elimination of its final chain), cross terms included.

Over R runs the ANEES at an epoch, ``mean_r NEES``, times R is chi2(9 R) for a consistent
estimator: the 95 % band is ``chi2.ppf([0.025, 0.975], 9 R) / R`` (Bar-Shalom, Li &
Kirubarajan 2001, "Estimation with Applications to Tracking and Navigation", sec. 5.4.2).
It is reported at the middle and the last epoch, and as the fraction of all epochs whose
ANEES lies in the band (about 95 % if consistent; epochs of one run are correlated, so
that fraction has no band of its own). Prints a table, writes ``DIR/attitude_anees.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from factors.geometry import so3_exp, so3_log
from fgnav.diagnostics.consistency import anees, chi2_band
from fgnav.measurements import build_pass
from fgnav.models.registry import ATTITUDE_VARIABLE
from fgnav.pipeline import solve
from fgnav.scenarios import SensorSpec, load_scenario
from fgnav.simulate.attitude_profiles import random_walk, with_attitude_truth
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.solvers.options import SmootherOptions

DOF = 9
OPTIONS = replace(SmootherOptions(), estimate=(ATTITUDE_VARIABLE.name,))


def simulate_run(seed: int, duration_h: float = 1.0 / 3.0):
    """One run's pass and truth: ``(pass, x_true (N, 6), R_true (N, 3, 3))`` at its epochs."""
    base = load_scenario("refraction-leo")
    scenario = base.with_options(duration_h=duration_h,
                                 sensors=(SensorSpec("altitude", sigma_m=50.0),))
    sim = simulate_pass(scenario, seed=seed)
    rng = np.random.default_rng(10_000 + seed)
    t_ep = np.unique(sim.log.t_s)
    R_true = random_walk(t_ep, ATTITUDE_VARIABLE.psd, rng, so3_exp(rng.normal(0.0, 1.0, 3)))
    log = with_attitude_truth(sim.log, sim.t_s, sim.x_true, R_true, rng, attitude_every=3,
                              sigma_attitude_rad=2e-4, earth_body_sigma_rad=3e-4)
    p = build_pass(log)
    return p, sim.x_true[np.searchsorted(sim.t_s, p.t_s)], R_true


def joint_errors(sol, x_true, R_true):
    """The 9-dimensional errors (N, 9) and the joint covariances (N, 9, 9) of a solution."""
    lay_att = slice(6, 9)            # the layout: orbit, then the attitude
    w = sol.variables[ATTITUDE_VARIABLE.name][0]
    e = np.concatenate([sol.x_eci - x_true,
                        so3_log(np.swapaxes(R_true, 1, 2) @ so3_exp(w))], axis=1)
    P = sol.P_block[:, :9, :9]
    np.testing.assert_allclose(P[:, lay_att, lay_att], sol.variables[ATTITUDE_VARIABLE.name][1])
    return e, P


def study(n_runs: int = 50, seed0: int = 0, methods=("batch", "isam2")):
    """Errors and joint covariances of every run: ``{method: (E (R, N, 9), P (R, N, 9, 9))}``
    and the wall time (s)."""
    out = {m: ([], []) for m in methods}
    t0 = time.perf_counter()
    for r in range(n_runs):
        p, x_true, R_true = simulate_run(seed0 + r)
        for m in methods:
            e, P = joint_errors(solve(p, m, OPTIONS), x_true, R_true)
            out[m][0].append(e)
            out[m][1].append(P)
    return {m: (np.array(E), np.array(P)) for m, (E, P) in out.items()}, time.perf_counter() - t0


def nees_runs(E, P, scale: float = 1.0):
    """NEES (R, N) of errors ``E`` (R, N, 9) with the covariances ``scale * P``: ``scale`` 1
    as the solver gives them (the tests use 0.5 and 2 to show that the check sees a
    covariance wrong by a factor of two)."""
    return np.einsum("...i,...i->...", E, np.linalg.solve(scale * P, E[..., None])[..., 0])


def summarize(nees: dict) -> dict:
    """Per method: ANEES at the middle and the last epoch with the 95 % band, the fraction of
    epochs inside the band, and the mean NEES over runs and epochs (per dof)."""
    out = {}
    for m, v in nees.items():
        R, N = v.shape
        lo, hi = chi2_band(DOF, R)
        curve = v.mean(axis=0)
        out[m] = {"runs": R, "epochs": N, "band": [lo, hi],
                  "anees_mid": anees(v[:, N // 2], DOF).as_dict(),
                  "anees_final": anees(v[:, -1], DOF).as_dict(),
                  "fraction_of_epochs_in_band": float(np.mean((curve >= lo) & (curve <= hi))),
                  "mean_nees_per_dof": float(v.mean() / DOF)}
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--seed0", type=int, default=0)
    ap.add_argument("--methods", default="batch,isam2")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args(argv)
    runs, wall = study(args.runs, args.seed0, tuple(args.methods.split(",")))
    res = summarize({m: nees_runs(E, P) for m, (E, P) in runs.items()})
    print(f"joint orbit-attitude ANEES, {DOF} dof, {args.runs} runs ({wall:.0f} s)")
    print("| method | ANEES mid | ANEES final | 95 % band | epochs in band | mean NEES/dof |")
    print("|---|---|---|---|---|---|")
    for m, r in res.items():
        print(f"| {m} | {r['anees_mid']['anees']:.2f} | {r['anees_final']['anees']:.2f} | "
              f"[{r['band'][0]:.2f}, {r['band'][1]:.2f}] | "
              f"{100 * r['fraction_of_epochs_in_band']:.0f} % | {r['mean_nees_per_dof']:.3f} |")
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "attitude_anees.json").write_text(json.dumps(res, indent=2))
    return res


if __name__ == "__main__":
    main()
