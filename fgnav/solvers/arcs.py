"""Long gaps: bridge them with one chain of states, or solve the log as separate arcs.

A gap is bridged (motion factors across it, measurement-free states inside it from
:func:`fgnav.measurements.fill_gaps`) while the state predicted across it from the data
before it is still described by a Gaussian in Cartesian coordinates. The filter's
covariance at the last epoch before the gap is propagated across it with the state
transition matrix, ``P1 = Phi P Phi^T + Q``; its position block has principal 1-sigma
``sigma_max`` (along track, where the uncertainty of the orbital period accumulates) and
``sigma_min``. The true spread lies on the orbit, a curve of radius ``|r|``: a chord of
half-length ``sigma_max`` leaves the curve by ``sigma_max^2 / (2 |r|)`` (the sagitta), and
the linearized prediction is only valid while that is small against the thinnest sigma,

    kappa = sigma_max^2 / (2 |r| sigma_min) <= KAPPA_MAX = 1.

Beyond that the Gaussian prediction claims a precision across track that the curved
distribution does not have (on gto-transfer, 1 h of directions at 0.01 deg then a 1-day
gap: kappa = 226, and the filter's NEES inside the gap is 1.9e5), and Gauss-Newton across
the gap can diverge (20 days: kappa = 188, the batch solve ran 52 s and ended
thousands of km off).

The curvature ratio looks at the position alone. The linearized prediction can fail first
in a thin direction that mixes position and velocity (the orbit's phase against its energy):
on gto-transfer, 1 h of directions every 10 s then an 8 h gap gives kappa = 0.44, yet
sigma points of ``P`` propagated through the full dynamics spread 16x the linear sigma in
that direction, their mean 7 sigma off; the EKF and the fixed-lag smoother took that
prediction as it was and their NEES after the gap stayed at ~120 through the next two hours
of data. So the prediction is also tested with the unscented transform (Julier & Uhlmann
2004, "Unscented filtering and nonlinear estimation", Proc. IEEE 92(3)): the 2n symmetric
sigma points ``x +- sqrt(n) L_i`` (``P = L L^T``, n = 6) give a mean ``m`` and covariance
``P_s`` (plus ``Q``); the expected NEES of that spread under the linear prediction,

    rho = (tr(P1^-1 P_s) + (m - x1)^T P1^-1 (m - x1)) / n <= RHO_MAX = 1.5,

is 1 for a linear propagation (1.5: the linear covariance is on average at most 1.5x
optimistic in chi-square, the integrity verdict's "suspect" bound). The same pass with gaps
of 1, 2, 5, 6, 7 and 8 h gives rho = 1.00, 1.00, 1.25, 2.2, 8.2, 52.

Such a gap separates two arcs: each is solved on its own, the later
one from an a-priori state predicted across the gap with an isotropic 1-sigma equal to the
largest principal sigma of the prediction (position and velocity; conservative: it
contains the full prediction covariance), so the later arc is determined by its own data.
No states are inserted inside a gap that is not bridged; the summary lists it under
``gaps`` with its prediction figures.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from factors.dynamics import process_noise, propagate, propagate_many
from fgnav.diagnostics.crb import CrbResult, cramer_rao_bound
from fgnav.errors import UserError
from fgnav.measurements import (Pass, covering_sigmas, fill_gaps, format_duration, long_gaps,
                                slice_pass)
from fgnav.solution import Solution
from fgnav.solvers.ekf import run_ekf
from fgnav.solvers.ekf_numba import numba_supports, run_ekf_numba
from fgnav.time import j2000_seconds

KAPPA_MAX = 1.0
"""Largest curvature ratio ``sigma_max^2 / (2 |r| sigma_min)`` of a bridged gap."""
RHO_MAX = 1.5
"""Largest expected NEES per dimension of the sigma points under the linear prediction."""


def _filter(p: Pass, options):
    """Filtered states and covariances of a pass (the numba EKF where it applies)."""
    plain = dataclasses.replace(options, gate_probability=None, robust=None)
    if numba_supports(p):
        try:
            return run_ekf_numba(p, plain, normalized=False)
        except ValueError:
            pass
    return run_ekf(p, plain)


def predict_across(p: Pass, k: int, x: np.ndarray, P: np.ndarray, options) -> dict:
    """The prediction from epoch ``k`` (state ``x``, covariance ``P``) across the step to
    ``k + 1``: predicted state and covariance and the figures of the bridging test."""
    dt = float(p.t_s[k + 1] - p.t_s[k])
    t0 = float(j2000_seconds(p.epoch0)) + float(p.t_s[k])
    x1, Phi = propagate(x, dt, options.motion_model(), t0)
    P1 = Phi @ P @ Phi.T + process_noise(dt, options.q_m2_s3)
    lam = np.sqrt(np.maximum(np.linalg.eigvalsh(0.5 * (P1[:3, :3] + P1[:3, :3].T)), 0.0))
    r = float(np.linalg.norm(x1[:3]))
    kappa = float(lam[-1] ** 2 / (2.0 * r * max(lam[0], 1e-9)))
    # (not needed, and ~1 s of propagation for 20 days, where the curvature already decides)
    rho = sigma_point_nees_ratio(x, P, x1, P1, dt, options, t0) if kappa <= KAPPA_MAX else None
    return {"t_start_s": float(p.t_s[k]), "t_end_s": float(p.t_s[k + 1]), "length_s": dt,
            "predicted_sigma_max_m": float(lam[-1]), "predicted_sigma_min_m": float(lam[0]),
            "radius_m": r, "kappa": kappa, "rho": rho,
            "bridged": rho is not None and rho <= RHO_MAX, "x_pred": x1, "P_pred": P1}


def sigma_point_nees_ratio(x, P, x1, P1, dt_s, options, t0_j2000_s) -> float:
    """``rho``: the expected NEES per dimension, under the linear prediction ``(x1, P1)``,
    of the unscented prediction of ``(x, P)`` over ``dt_s`` (see the module docstring);
    ``inf`` where either covariance is not positive definite. Only computed where the
    curvature ratio allows bridging (``rho`` is None in the gap notes elsewhere)."""
    n = len(x)
    try:
        L = np.linalg.cholesky(0.5 * (P + P.T))
        L1 = np.linalg.cholesky(0.5 * (P1 + P1.T))
    except np.linalg.LinAlgError:
        return float("inf")
    S = np.concatenate([x + np.sqrt(n) * L.T, x - np.sqrt(n) * L.T])
    Y, _ = propagate_many(S, dt_s, options.motion_model(), t0_j2000_s, with_stm=False)
    m = Y.mean(axis=0)
    Z = np.linalg.solve(L1, (Y - m).T)                     # whitened by the linear P1
    zq = np.linalg.solve(L1, np.linalg.cholesky(process_noise(dt_s, options.q_m2_s3)))
    zm = np.linalg.solve(L1, m - x1)
    return float((np.sum(Z * Z) / len(S) + np.sum(zq * zq) + zm @ zm) / n)


def plan_gaps(p: Pass, options, gap_factor: float = 10.0, *, start: tuple | None = None) -> Pass:
    """Decide for every long gap whether it is bridged (see the module docstring) and fill
    the bridged ones; returns the pass the solvers see (``breaks``, ``arc_priors``,
    ``gap_notes`` set). A pass already planned is returned as is.

    ``start = (x (6,), sigma_position_m, sigma_velocity_mps)``: the a-priori state of the
    planning filter at epoch 0 for a pass without prior rows (the initial orbit)."""
    if p.inserted is not None:
        return p
    gaps = long_gaps(p, gap_factor)
    if not len(gaps):
        return fill_gaps(p, gap_factor)
    breaks, priors, notes = [], [], []
    prior = start
    start = 0
    while True:
        sub, _ = slice_pass(p, start, p.n_epochs, prior)
        sol = _filter(sub, options)
        split = None
        for i in gaps[gaps >= start]:
            g = predict_across(p, int(i), sol.x_eci[i - start], sol.P_eci[i - start], options)
            x1, P1 = g.pop("x_pred"), g.pop("P_pred")
            notes.append(g)
            if not g["bridged"]:
                split = int(i) + 1
                prior = (x1, *covering_sigmas(P1))
                break
        if split is None:
            break
        breaks.append(split)
        priors.append(prior)
        start = split
    planned = dataclasses.replace(p, breaks=tuple(breaks), arc_priors=priors, gap_notes=notes)
    out = fill_gaps(planned, gap_factor)
    if breaks:
        split = [g for g in notes if not g["bridged"]]
        where = ", ".join(f"{format_duration(g['length_s'])} from t = {g['t_start_s']:.0f} s "
                          f"({_figures(g)})" for g in split[:3])
        out.warnings = out.warnings + [
            f"{len(breaks)} gap(s) too long to bridge: {where}{' ...' if len(split) > 3 else ''}; "
            f"the prediction across leaves the linear regime (kappa > {KAPPA_MAX:g} or its sigma "
            f"points' NEES per dimension rho > {RHO_MAX:g}), so the log "
            f"is solved as {len(breaks) + 1} separate arcs, each from its own data"]
    return out


def arc_priors(p: Pass, breaks, options, start: tuple | None = None) -> list:
    """The a-priori state of each arc after the first of ``p`` cut at ``breaks`` (epoch
    indices of ``p``, before any filling), as :func:`plan_gaps` gives them: each arc filtered
    from its own a-priori state (``start`` for the first: as :func:`plan_gaps`), the last
    state predicted across the gap (:func:`predict_across`) and covered by isotropic sigmas
    (:func:`fgnav.measurements.covering_sigmas`); ``[(x (6,), sigma_r, sigma_v)]`` per break.
    A formation's further spacecraft take their arcs' priors from here, on the first's
    breaks (:func:`fgnav.pipeline.formation_gaps`)."""
    out, prior, k0 = [], start, 0
    for b in breaks:
        sub, _ = slice_pass(p, k0, int(b), prior)
        sol = _filter(sub, options)
        g = predict_across(p, int(b) - 1, sol.x_eci[-1], sol.P_eci[-1], options)
        prior = (g["x_pred"], *covering_sigmas(g["P_pred"]))
        out.append(prior)
        k0 = int(b)
    return out


def _figures(g: dict) -> str:
    """The bridging figures of a gap note for a warning: kappa, and rho where computed."""
    return f"kappa {g['kappa']:.3g}" + ("" if g["rho"] is None else f", rho {g['rho']:.3g}")


def solve_arcs(p: Pass, solve_one, method: str) -> Solution:
    """Solve each arc of a planned pass with ``solve_one(arc_pass)`` and join the results
    (states, covariances and residuals in the order of ``p``)."""
    bounds = [0, *p.breaks, p.n_epochs]
    sols, rows = [], []
    for j, (k0, k1) in enumerate(zip(bounds[:-1], bounds[1:])):
        sub, rows_of = slice_pass(p, k0, k1, p.arc_priors[j - 1] if j else None)
        try:
            sols.append(solve_one(sub))
        except UserError as exc:
            raise type(exc)(f"arc {j + 1} of {len(bounds) - 1} ({p.t_s[k0]:.0f} to "
                            f"{p.t_s[k1 - 1]:.0f} s, after a gap too long to bridge): {exc}") from exc
        rows.append(rows_of)
    return join_solutions(p, sols, rows, method)


def join_solutions(p: Pass, sols: list[Solution], rows: list[dict], method: str) -> Solution:
    """One :class:`Solution` from consecutive arcs; residuals of rows added by
    :func:`fgnav.measurements.slice_pass` (the arcs' a-priori states) are left out."""
    def cat(name):
        parts = [getattr(s, name) for s in sols]
        return None if any(v is None for v in parts) else np.concatenate(parts)

    def join_rows(per_arc: list[dict]) -> dict:
        """kind -> (M_arc, m) arrays of the arcs -> kind -> (M, m) in the order of ``p``."""
        out = {}
        for kind, fam in p.families.items():
            for arc, r in zip(per_arc, rows):
                if kind in arc and kind in r:
                    res = arc[kind]
                    if kind not in out:
                        out[kind] = np.full((len(fam), res.shape[1]), np.nan)
                    keep = r[kind] >= 0
                    out[kind][r[kind][keep]] = res[keep]
        return out

    residuals = join_rows([s.residuals for s in sols])
    extras = dict(sols[0].extras)
    if all("normalized_innovations" in s.extras for s in sols):   # a filter's, per row
        extras["normalized_innovations"] = join_rows(
            [s.extras["normalized_innovations"] for s in sols])
    else:
        extras.pop("normalized_innovations", None)
    weights = {}  # robust weights / gate decisions of every row, in the order of p
    for s, r in zip(sols, rows):
        for kind, w in (s.extras.get("row_weights") or {}).items():
            if kind in r and kind in p.families:
                keep = r[kind] >= 0
                weights.setdefault(kind, np.ones(len(p.families[kind])))[r[kind][keep]] = \
                    np.asarray(w)[keep]
    extras["row_weights"] = weights
    for key in ("chi2_measurements", "chi2_motion"):
        if all(key in s.extras for s in sols):
            extras[key] = float(sum(s.extras[key] for s in sols))
    if all("converged" in s.extras for s in sols):
        extras["converged"] = bool(all(s.extras["converged"] for s in sols))
    extras["arcs"] = len(sols)
    variables = {name: tuple(np.concatenate([s.variables[name][i] for s in sols]) for i in (0, 1))
                 for name in sols[0].variables if all(name in s.variables for s in sols)}
    formation = {}
    if p.spacecraft:   # the joint marginals (relative states), the online states of each orbit
        formation["P_block"] = cat("P_block")
        online = [s.extras.get("online_variables") for s in sols]
        extras.pop("online_variables", None)
        if all(o for o in online):
            extras["online_variables"] = {
                name: tuple(np.concatenate([o[name][i] for o in online]) for i in (0, 1))
                for name in online[0] if all(name in o for o in online)}
        tests = [s.extras["mirror_test"] for s in sols if "mirror_test" in s.extras]
        if tests:   # the verdict's: an arc whose mirror fits as well, else the first arc's
            extras["mirror_test"] = next((t for t in tests if t.get("status") != "ok"), tests[0])
    return Solution(method=method, epoch0=p.epoch0, t_s=np.concatenate([s.t_s for s in sols]),
                    x_eci=cat("x_eci"), P_eci=cat("P_eci"), variables=variables,
                    iterations=int(sum(s.iterations for s in sols)),
                    chi2=float(sum(s.chi2 for s in sols)), wall_s=float(sum(s.wall_s for s in sols)),
                    residuals=residuals, online_x_eci=cat("online_x_eci"),
                    online_P_eci=cat("online_P_eci"), latency_s=cat("latency_s"), extras=extras,
                    **formation)


def arcs_bound(p: Pass, x_ref: np.ndarray, model):
    """The Cramér–Rao bound of a pass split into arcs: each arc's own (its a-priori state
    included), pooled over all epochs (a :class:`fgnav.diagnostics.crb.CrbResult`)."""
    bounds = [0, *p.breaks, p.n_epochs]
    cs = [cramer_rao_bound(slice_pass(p, a, b, p.arc_priors[j - 1] if j else None)[0],
                           x_ref[a:b], model)
          for j, (a, b) in enumerate(zip(bounds[:-1], bounds[1:]))]
    var_r = np.concatenate([c.position_var_m2 for c in cs])
    var_v = np.concatenate([c.velocity_var_m2s2 for c in cs])
    return CrbResult(P_eci=None, position_rms_m=float(np.sqrt(var_r.mean())),
                     velocity_rms_mps=float(np.sqrt(var_v.mean())),
                     final_position_m=cs[-1].final_position_m,
                     final_velocity_mps=cs[-1].final_velocity_mps,
                     J0_measurements=cs[0].J0_measurements, J0_geometry=cs[0].J0_geometry,
                     position_var_m2=var_r, velocity_var_m2s2=var_v)


def gap_summary(p: Pass) -> list[dict]:
    """summary.json entries for the long gaps (times in s from the pass epoch, km)."""
    return [{"t_start_s": g["t_start_s"], "length_s": g["length_s"], "bridged": bool(g["bridged"]),
             "kappa": round(g["kappa"], 4), "rho": None if g["rho"] is None else round(g["rho"], 4),
             "predicted_sigma_max_km": round(g["predicted_sigma_max_m"] / 1e3, 3)}
            for g in p.gap_notes]
