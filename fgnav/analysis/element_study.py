"""Orbital elements against the Cartesian state: the filter and the smoother on the Pan & Yao
2017 transfer orbit (built-in ``gto-transfer``: e = 0.72, geocentric directions only) at
several measurement steps, and the linearization error of the state transition itself.

The INS/CNS lecture claims that the six orbital elements propagated by Gauss's variational
equations have a smaller linearization error than the Cartesian state for long filter
steps and high eccentricity. Two measurements test it:

* :func:`pass_rows`: the EKF (numpy, :func:`fgnav.solvers.ekf.run_ekf`) and the batch smoother
  (:func:`fgnav.solvers.batch.smooth_batch` through :func:`fgnav.pipeline.solve`) on one
  simulated pass, each with ``state="cartesian"`` and ``state="elements"``
  (:mod:`fgnav.solvers.state_elements`); position RMS and 6-dof NEES against the truth of
  the independent DOP853 integrator, and the Cramér–Rao bound along the truth.
* :func:`transition_nonlinearity`: the nonlinearity index of one motion step in each
  coordinate system (Junkins, Akella & Alfriend 1996, "Non-Gaussian error propagation in
  orbital mechanics", J. Astronautical Sciences 44(4): how far the propagated error departs
  from the STM's linear prediction): deviations ``d`` drawn from the a-priori covariance are
  propagated through the full motion model, and the part the STM misses,
  ``eps = f(x + d) - f(x) - Phi d`` (in the elements: ``e(f(c(E + dE))) - e(f(x)) -
  Phi_E dE`` with ``dE = (dc/dE)^-1 d``, the same draw), is measured against the propagated
  covariance, ``mean(eps^T (Phi P Phi^T)^-1 eps)``: 0 for a linear step, ~1 when the linear
  prediction is off by a whole sigma.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from factors.dynamics import MotionModel, propagate, propagate_many
from factors.dynamics import accel_j2
from factors.elements import cartesian_from_mee, mee_from_cartesian
from factors.elements import gauss_propagate
from fgnav.measurements import build_pass
from fgnav.orbit import integrate_truth
from fgnav.pipeline import accuracy_metrics, crb_metrics, prepare_pass, solve
from fgnav.scenarios import load_scenario
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.solvers.ekf import run_ekf
from fgnav.solvers.options import SmootherOptions

SCENARIO = "gto-transfer"
STEPS_S = (10.0, 100.0, 1000.0)
STATES = ("cartesian", "elements")
METHODS = ("ekf", "batch")


def pass_rows(step_s: float, seed: int, methods=METHODS, prior_scale: float = 1.0,
              with_crb: bool = True) -> list[dict]:
    """One simulated ``gto-transfer`` pass at ``step_s`` (seed ``seed``; the a-priori sigmas
    times ``prior_scale``) solved by each method in each state: one row per (method, state)
    with position RMS (m), NEES (mean over the epochs, 6 dof), velocity RMS, final position
    error, iterations, and the CRB position RMS (m) along the truth."""

    scn = load_scenario(SCENARIO).with_options(step_s=step_s)
    if prior_scale != 1.0:
        scn = replace(scn, prior_position_sigma_m=scn.prior_position_sigma_m * prior_scale,
                      prior_velocity_sigma_mps=scn.prior_velocity_sigma_mps * prior_scale)
    sim = simulate_pass(scn, seed=seed)
    p = build_pass(sim.log)
    rows = []
    crb = None
    for method in methods:
        for state in STATES:
            opt = SmootherOptions(state=state)
            if method == "ekf":
                q = prepare_pass(p, opt)
                sol = run_ekf(q, opt)
            else:
                sol = solve(p, method, opt)
            x_true = sim.x_true[np.searchsorted(sim.t_s, sol.t_s)]
            acc = accuracy_metrics(sol, x_true)
            if with_crb and crb is None:
                crb = crb_metrics(p, x_true, opt, sol.t_s)["crb_position_rms_m"]
            rows.append({"step_s": step_s, "seed": seed, "prior_scale": prior_scale,
                         "method": method, "state": state, "epochs": len(sol.t_s),
                         "iterations": int(sol.iterations),
                         "position_rms_m": acc["position_rms_m"],
                         "velocity_rms_mps": acc["velocity_rms_mps"],
                         "final_position_error_m": acc["final_position_error_m"],
                         "nees_mean": acc["nees_mean"], "crb_position_rms_m": crb})
    return rows


def transition_nonlinearity(x0: np.ndarray, P0: np.ndarray, dt_s: float, *,
                            model: MotionModel = MotionModel(), samples: int = 400,
                            seed: int = 0) -> dict:
    """The nonlinearity index of the step ``x0 -> f(x0)`` over ``dt_s`` (s) in Cartesian
    coordinates and in modified equinoctial elements, for deviations ~ N(0, P0) (Cartesian,
    SI) at ``x0``: ``{"cartesian": index, "elements": index}`` (dimensionless, see the module
    docstring)."""
    rng = np.random.default_rng(seed)
    d = rng.standard_normal((samples, 6)) @ np.linalg.cholesky(P0).T
    x1, Phi = propagate(x0, dt_s, model)
    X1 = propagate_many(x0 + d, np.full(samples, dt_s), model, with_stm=False)[0]
    out = {"cartesian": _index(X1 - x1 - d @ Phi.T, Phi @ P0 @ Phi.T)}
    E0 = mee_from_cartesian(x0)
    _, J0 = cartesian_from_mee(E0)
    _, J1 = cartesian_from_mee(mee_from_cartesian(x1))
    dE = np.linalg.solve(J0, d.T).T
    XE = propagate_many(cartesian_from_mee(E0 + dE, jacobian=False), np.full(samples, dt_s),
                        model, with_stm=False)[0]
    PhiE = np.linalg.solve(J1, Phi @ J0)
    DE = mee_from_cartesian(XE) - mee_from_cartesian(x1)
    DE[:, 5] = np.angle(np.exp(1j * DE[:, 5]))   # L differences in (-pi, pi]
    P0E = np.linalg.solve(J0, np.linalg.solve(J0, P0).T)
    out["elements"] = _index(DE - dE @ PhiE.T, PhiE @ P0E @ PhiE.T)
    return out


def _index(eps, P):
    L = np.linalg.cholesky(0.5 * (P + P.T))
    w = np.linalg.solve(L, eps.T)
    return float(np.mean(np.sum(w * w, axis=0)))


def orbit_nonlinearity(x_start: np.ndarray, P0: np.ndarray, steps_s=(10.0, 100.0, 1000.0, 10000.0),
                       starts: int = 8, samples: int = 400, model: MotionModel = MotionModel()):
    """:func:`transition_nonlinearity` averaged over ``starts`` points spread in time over one
    orbit of ``x_start`` (the index depends on where the step starts: near perigee or
    apogee). Returns ``{step_s: {"cartesian": mean index, "elements": mean index}}``."""
    E = mee_from_cartesian(x_start)
    mu = model.mu
    a = E[0] / (1.0 - E[1] ** 2 - E[2] ** 2)
    period = 2.0 * np.pi * np.sqrt(a ** 3 / mu)
    xs = [x_start]
    for _ in range(starts - 1):
        xs.append(propagate(xs[-1], period / starts, model, with_stm=False)[0])
    out = {}
    for dt in steps_s:
        vals = [transition_nonlinearity(x, P0, dt, model=model, samples=samples, seed=i)
                for i, x in enumerate(xs)]
        out[float(dt)] = {s: float(np.mean([v[s] for v in vals])) for s in STATES}
    return out


def propagation_errors(x0: np.ndarray, duration_s: float = 4 * 3600.0,
                       substeps_s=(5.0, 30.0, 120.0, 600.0)) -> dict:
    """Position error (m) after ``duration_s`` of two-body + J2 motion from ``x0``, against the
    independent DOP853 integrator (:func:`fgnav.orbit.integrate_truth`), of RK4 in Cartesian
    coordinates (the solvers' motion model, :func:`factors.dynamics.propagate`) and of RK4 of
    Gauss's variational equations in the elements (:func:`factors.elements.gauss_propagate`),
    at each sub-step (s): ``{substep: {"cartesian": m, "elements": m}}``. The two integrate the
    same flow; they differ by their integration error only."""

    x_ref = integrate_truth(x0, np.array([0.0, duration_s]))[-1]
    mu = MotionModel().mu

    def j2_term(r):
        r2 = r.reshape(-1, 3)
        a = accel_j2(r2) + mu * r2 / np.linalg.norm(r2, axis=1, keepdims=True) ** 3
        return a.reshape(r.shape)

    out = {}
    for h in substeps_s:
        n = int(np.ceil(duration_s / h))
        xc = propagate(x0, duration_s, MotionModel(max_step_s=h), with_stm=False)[0]
        xe = cartesian_from_mee(gauss_propagate(mee_from_cartesian(x0), duration_s, n, j2_term),
                                jacobian=False)
        out[float(h)] = {"cartesian": float(np.linalg.norm(xc[:3] - x_ref[:3])),
                         "elements": float(np.linalg.norm(xe[:3] - x_ref[:3]))}
    return out


def summary_table(rows: list[dict]) -> str:
    """Markdown: per step and method, over the seeds, the pooled position RMS
    (``sqrt(mean(rms^2))``) and the mean NEES (6 dof; 6 is consistent), Cartesian beside
    elements, and the pooled CRB position RMS."""
    out = ["| step (s) | method | position RMS, Cartesian (m) | position RMS, elements (m) | "
           "NEES, Cartesian | NEES, elements | CRB position RMS (m) | seeds |",
           "|---|---|---|---|---|---|---|---|"]
    keys = sorted({(r["prior_scale"], r["step_s"], r["method"]) for r in rows},
                  key=lambda k: (k[0], k[1], METHODS.index(k[2])))
    for scale, step, method in keys:
        sel = {s: [r for r in rows if (r["prior_scale"], r["step_s"], r["method"], r["state"])
                   == (scale, step, method, s)] for s in STATES}
        stats = {s: pooled(sel[s]) for s in STATES}
        crb = stats["cartesian"]["crb_position_rms_m"]
        label = f"{step:g}" + (f" (prior x{scale:g})" if scale != 1.0 else "")
        out.append(f"| {label} | {method} | {stats['cartesian']['position_rms_m']:.4g} | "
                   f"{stats['elements']['position_rms_m']:.4g} | "
                   f"{stats['cartesian']['nees_mean']:.3g} | {stats['elements']['nees_mean']:.3g} | "
                   f"{'-' if crb is None else f'{crb:.4g}'} | {len(sel['cartesian'])} |")
    return "\n".join(out)


def pooled(rows: list[dict]) -> dict:
    """Over runs: position RMS and CRB pooled as ``sqrt(mean(x^2))``, NEES averaged."""
    crb = [r["crb_position_rms_m"] for r in rows if r.get("crb_position_rms_m") is not None]
    return {"position_rms_m": float(np.sqrt(np.mean([r["position_rms_m"] ** 2 for r in rows]))),
            "nees_mean": float(np.mean([r["nees_mean"] for r in rows])),
            "crb_position_rms_m": float(np.sqrt(np.mean(np.square(crb)))) if crb else None}


def nonlinearity_table(results: dict) -> str:
    """Markdown: orbit name -> ``orbit_nonlinearity`` result, one row per (orbit, step)."""
    out = ["| orbit | step (s) | nonlinearity index, Cartesian | nonlinearity index, elements | "
           "ratio |", "|---|---|---|---|---|"]
    for name, res in results.items():
        for dt, v in res.items():
            ratio = v["cartesian"] / v["elements"] if v["elements"] > 0 else float("inf")
            out.append(f"| {name} | {dt:g} | {v['cartesian']:.3g} | {v['elements']:.3g} | "
                       f"{ratio:.3g} |")
    return "\n".join(out)
