"""The ``mars-cruise`` study: geometric fixes, the smoother, the Cramér–Rao bound and the NEES
over many seeds (``scripts/study_mars_cruise.py`` prints it; a slow test checks it).

Per seed: the built-in heliocentric scenario ``mars-cruise`` is simulated (truth from the
independent DOP853 integrator, the Sun and the planets) and smoothed by batch from no prior
(its first guess the orbit of the geometric fixes, :mod:`fgnav.iod.geometric`). Measured
against the truth:

* the geometric fix of every epoch (two Sun-star cones and a Sun-Earth torus intersected,
  the root nearest the true orbit kept), its position error and the sigma predicted from
  the surfaces' gradients, and the fixes' NEES (3 dof);
* the smoother's position and velocity RMS over the pass, its own 1-sigma and its NEES
  (6 dof), and the Cramér–Rao bound of the pass (:func:`fgnav.diagnostics.crb.cramer_rao_bound`:
  the information of every row mapped through the motion model's state-transition matrices
  to the first state, along the truth; the star choice and the truth do not depend on the
  seed, so the bound is computed once);
* the same smoother with the angles' aberration not modelled (``aberration=False``: geometric
  lines of sight, as ``fgnav smooth --no-aberration``), to show what the correction is worth
  on data that has it.

The NEES band over n seeds is the two-sided 95 % interval of a chi-square with 6 n (3 n M
for the fixes) degrees of freedom divided by n (Bar-Shalom, Li & Kirubarajan 2001,
*Estimation with Applications to Tracking and Navigation*, sec. 5.4.2).
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from fgnav.diagnostics.crb import cramer_rao_bound
from fgnav.iod.geometric import fixes_along
from fgnav.measurements import build_pass
from fgnav.pipeline import accuracy_metrics, smooth_log
from fgnav.scenarios import load_scenario
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.solvers.options import SmootherOptions

__all__ = ["run_cruise_study", "format_cruise_study"]


def run_cruise_study(seeds=range(20), duration_h: float | None = None,
                     step_s: float | None = None) -> dict:
    """Run the study (module docstring) over ``seeds``; ``duration_h``/``step_s`` override
    the scenario's. Returns a dict of per-seed rows, the pooled figures and seed 0's
    per-epoch fixes."""
    scn = load_scenario("mars-cruise").with_options(duration_h=duration_h, step_s=step_s)
    model = SmootherOptions(centre=scn.centre).motion_model()
    rows, crb, per_epoch = [], None, None
    fix_z2 = []
    for seed in seeds:
        sim = simulate_pass(scn, seed=seed)
        res, p = smooth_log(sim.log, truth=(sim.t_s, sim.x_true))
        sol = res.solution
        xt = sim.x_true[np.searchsorted(sim.t_s, sol.t_s)]
        if crb is None:
            crb = cramer_rao_bound(p, xt, model)
        m = accuracy_metrics(sol, xt)
        res_noab, _ = smooth_log(sim.log, truth=(sim.t_s, sim.x_true), aberration=False)
        m_noab = accuracy_metrics(res_noab.solution, xt)
        fx, nroots = fixes_along(build_pass(sim.log), xt)
        e = fx.r_eci_m - xt[fx.k, :3]
        z2 = np.einsum("ki,kij,kj->k", e, np.linalg.inv(fx.P_m2), e)
        fix_z2.append(z2)
        sig_fix = np.sqrt(np.trace(fx.P_m2, axis1=1, axis2=2))
        iod = sol.extras.get("initial_orbit", {})
        rows.append({"seed": int(seed), "fix_rms_m": float(np.sqrt(np.mean(np.sum(e * e, 1)))),
                     "fix_sigma_m": float(np.sqrt(np.mean(sig_fix ** 2))),
                     "fix_nees": float(np.mean(z2)), "fix_epochs": int(len(fx.k)),
                     "two_roots": int(np.sum(nroots > 1)),
                     "start": iod.get("method", ""),
                     "no_aberration_position_rms_m": m_noab["position_rms_m"],
                     "no_aberration_nees_mean": m_noab["nees_mean"],
                     **{k: m[k] for k in ("position_rms_m", "velocity_rms_mps",
                                          "sigma_position_rms_m", "nees_mean")}})
        if per_epoch is None:
            err_s = np.linalg.norm(sol.x_eci[fx.k, :3] - xt[fx.k, :3], axis=1)
            sig_s = np.sqrt(np.trace(sol.P_eci[fx.k, :3, :3], axis1=1, axis2=2))
            per_epoch = {"t_day": (sol.t_s[fx.k] / 86400.0).tolist(),
                         "fix_error_m": np.linalg.norm(e, axis=1).tolist(),
                         "fix_sigma_m": sig_fix.tolist(), "smoother_error_m": err_s.tolist(),
                         "smoother_sigma_m": sig_s.tolist()}
    n = len(rows)
    nees = float(np.mean([r["nees_mean"] for r in rows]))
    z = np.concatenate(fix_z2)
    return {
        "scenario": scn.name, "duration_h": scn.duration_h, "step_s": scn.step_s, "seeds": n,
        "rows": rows, "per_epoch_seed0": per_epoch,
        "crb_position_rms_m": float(crb.position_rms_m),
        "crb_velocity_rms_mps": float(crb.velocity_rms_mps),
        "position_rms_m": float(np.sqrt(np.mean([r["position_rms_m"] ** 2 for r in rows]))),
        "velocity_rms_mps": float(np.sqrt(np.mean([r["velocity_rms_mps"] ** 2 for r in rows]))),
        "sigma_position_rms_m": float(np.mean([r["sigma_position_rms_m"] for r in rows])),
        "nees_mean": nees,
        "no_aberration_position_rms_m": float(np.sqrt(np.mean(
            [r["no_aberration_position_rms_m"] ** 2 for r in rows]))),
        "no_aberration_nees_mean": float(np.mean([r["no_aberration_nees_mean"] for r in rows])),
        "nees_band_95": [float(b) for b in chi2.ppf([0.025, 0.975], 6 * n) / n],
        "fix_rms_m": float(np.sqrt(np.mean([r["fix_rms_m"] ** 2 for r in rows]))),
        "fix_sigma_m": float(np.sqrt(np.mean([r["fix_sigma_m"] ** 2 for r in rows]))),
        "fix_nees": float(np.mean(z)),
        "fix_nees_band_95": [float(b) for b in chi2.ppf([0.025, 0.975], 3 * len(z)) / len(z)],
    }


def format_cruise_study(s: dict) -> str:
    """The study as Markdown: the pooled figures, per seed, and seed 0's fixes once a day."""
    km = 1e-3
    lo, hi = s["nees_band_95"]
    flo, fhi = s["fix_nees_band_95"]
    out = [f"# {s['scenario']}: {s['seeds']} seeds, {s['duration_h']:g} h, an angle set every "
           f"{s['step_s'] / 3600:g} h",
           "",
           "| | position RMS | velocity RMS | own 1-sigma | NEES (95 % band) |",
           "|---|---|---|---|---|",
           f"| geometric fixes (each epoch alone) | {s['fix_rms_m'] * km:,.0f} km | - | "
           f"{s['fix_sigma_m'] * km:,.0f} km | {s['fix_nees']:.2f} (3 dof; {flo:.2f}-{fhi:.2f}) |",
           f"| batch smoother (no prior) | {s['position_rms_m'] * km:,.0f} km | "
           f"{s['velocity_rms_mps']:.3f} m/s | {s['sigma_position_rms_m'] * km:,.0f} km | "
           f"{s['nees_mean']:.2f} (6 dof; {lo:.2f}-{hi:.2f}) |",
           f"| same, aberration not modelled (`--no-aberration`) | "
           f"{s['no_aberration_position_rms_m'] * km:,.0f} km | - | - | "
           f"{s['no_aberration_nees_mean']:.2f} |",
           f"| Cramér–Rao bound | {s['crb_position_rms_m'] * km:,.0f} km | "
           f"{s['crb_velocity_rms_mps']:.3f} m/s | | |",
           "", "| seed | fix RMS | fix sigma | fix NEES | epochs with 2 roots | start | smoother RMS | NEES |",
           "|---|---|---|---|---|---|---|---|"]
    for r in s["rows"]:
        out.append(f"| {r['seed']} | {r['fix_rms_m'] * km:,.0f} km | {r['fix_sigma_m'] * km:,.0f} km | "
                   f"{r['fix_nees']:.2f} | {r['two_roots']}/{r['fix_epochs']} | {r['start']} | "
                   f"{r['position_rms_m'] * km:,.0f} km | {r['nees_mean']:.2f} |")
    pe = s["per_epoch_seed0"]
    out += ["", "Seed 0, once a day:", "", "| day | fix error | fix sigma | smoother error | smoother sigma |", "|---|---|---|---|---|"]
    last = -1.0
    for i, t in enumerate(pe["t_day"]):
        if t - last >= 1.0 - 1e-9 or i == len(pe["t_day"]) - 1:
            last = t
            out.append(f"| {t:.2f} | {pe['fix_error_m'][i] * km:,.0f} km | {pe['fix_sigma_m'][i] * km:,.0f} km | "
                       f"{pe['smoother_error_m'][i] * km:,.0f} km | {pe['smoother_sigma_m'][i] * km:,.0f} km |")
    return "\n".join(out) + "\n"
