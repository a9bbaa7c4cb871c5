"""Conditioning study (Cartesian vs spherical) on Xing et al.'s geometry, and the track case.

Xing et al. geometry, worked out from its Table 1 and printed matrices A, A': sat 2 on sat 1's
body +x axis (the antenna-face normal), az = el = 0, true range 999.922 m (epoch 1) and
999.891 m (epoch 2), relative attitude zero (``M21 = I``, both satellites mount the antennas
identically), clock 0, Gauss–Newton started from R = 1992 m, az = el = 0 (Xing et al.'s
"initial conditions"). Its printed A (rows 0.9999, -0.005, 0.0129, +-1) is the design matrix
at its epoch-1 *estimate* (az = -0.00519 rad, el = 0.014 rad; Xing et al.'s "arc" is radians).
All covariances here are evaluated at the estimate, as in Xing et al.

Units of the unknowns: metres (x, y, z, R, c dt) and radians (az, el). ``rcond`` is
lambda_min / lambda_max of ``A^T A`` (A unwhitened, Xing et al.'s), ``rcond_1norm`` the
1-norm figure MATLAB's ``rcond`` estimates.
"""

from __future__ import annotations

import json
import os

import numpy as np

from factors.pseudorange import offset_range_residual, predict_ranges, spherical_to_cartesian
from fgnav.iod.single_epoch import (
    PARAMS, conditioning, design_matrix, from_param, solve_single_epoch, solve_single_epoch_many,
    to_param,
)
from fgnav.formation.smoother import (
    nees_of, scenario_dict, simulate_formation, solve_batch, solve_isam2,
)

__all__ = ["FORMATION_REFERENCE", "formation_reference_truth", "conditioning_study", "coverage_monte_carlo",
           "covariance_change", "range_coverage", "predicted_ranges", "reference_ranges"]

FORMATION_REFERENCE = {
    "R_m": (999.922, 999.891),          # Table 1, true range at epochs 1 and 2
    "az_rad": 0.0, "el_rad": 0.0, "cdt_m": 0.0,
    "rpy_rad": (0.0, 0.0, 0.0),
    "x0_cart_m": (1992.0, 0.0, 0.0, 0.0),
    "sigma_code_m": 0.01,
    "reported": {"rcond_cartesian": 1.09e-7, "rcond_spherical": 2.5e-2, "sigma_R_m": 0.0041,
                 "sigma_clock_m": 0.0122, "sigma_angle_rad": 0.01,
                 "coverage_1sigma_120_runs": 0.675, "coverage_predicted": 0.682},
}


def formation_reference_truth(epoch):
    """True ``(r_m (3,), cdt_m, M21 (3, 3))`` of Xing et al. at epoch 1 or 2."""
    R = FORMATION_REFERENCE["R_m"][epoch - 1]
    r, _ = spherical_to_cartesian(np.array([R, FORMATION_REFERENCE["az_rad"], FORMATION_REFERENCE["el_rad"]]))
    return r, FORMATION_REFERENCE["cdt_m"], np.eye(3)


def covariance_change(P1, P2):
    """How much a covariance changed between two epochs.

    ``relative_change`` = max_ij |P2 - P1|_ij / sqrt(P1_ii P1_jj) (change in units of the
    epoch-1 standard deviations; 0 = identical), and the Frobenius ratio
    ``||P2 - P1||_F / ||P1||_F``.
    """
    d = np.sqrt(np.diag(P1))
    rel = float(np.max(np.abs(P2 - P1) / np.outer(d, d)))
    fro = float(np.linalg.norm(P2 - P1) / np.linalg.norm(P1))
    return rel, fro


def coverage_monte_carlo(runs=5000, seed=0, sigma_m=0.01, param="spherical"):
    """Fraction of Monte Carlo runs whose range error lies within +-sigma_R.

    Xing et al.'s epoch-1 geometry; each run draws six pseudorange errors N(0, sigma_m^2),
    solves by Gauss–Newton (from R = 1992 m) and compares |R_hat - R_true| with that run's
    sigma_R = sqrt(P_RR) at its estimate (Xing et al.: 120 runs, 67.5 %; Gaussian 68.27 %).
    Returns ``(fraction, errors (runs,), sigmas (runs,))``.
    """
    r, cdt, M21 = formation_reference_truth(1)
    return range_coverage(r, cdt, M21, runs, seed, sigma_m, param,
                          np.asarray(FORMATION_REFERENCE["x0_cart_m"]))


def range_coverage(r_m, cdt_m, M21, runs, seed, sigma_m, param="spherical", x0_cart=None,
                   links=None):
    """Monte Carlo 1-sigma coverage of the range at any geometry: sat 2 at ``r_m`` (3,) in
    the sat-1 body frame, clock ``cdt_m``, Xing et al.'s links through ``M21`` or ``links``
    (:class:`~fgnav.iod.single_epoch.LinkGeometry`); ``sigma_m`` scalar or per link (m);
    Gauss–Newton from ``x0_cart`` (4,) Cartesian. Returns ``(fraction, errors, sigmas)`` as
    :func:`coverage_monte_carlo`."""
    rng = np.random.default_rng(seed)
    r = np.asarray(r_m, dtype=float)
    clean = predicted_ranges(r, cdt_m, M21, links)
    sigma = np.asarray(sigma_m, dtype=float)
    z = clean + sigma * rng.standard_normal((runs, clean.size))
    x0 = np.tile(np.asarray(x0_cart, dtype=float), (runs, 1))
    x, _, conv = solve_single_epoch_many(z, M21, param, x0, links=links)
    if param == "cartesian":
        s = to_param(from_param(x[:, :3], param), "spherical")
    else:
        s = x[:, :3]
    err = s[:, 0] - float(np.linalg.norm(r))
    # sigma_R at each estimate (spherical design matrix)
    sig = np.empty(runs)
    for i in range(runs):
        A = design_matrix(np.r_[s[i], x[i, 3]], M21, "spherical", links)
        if sigma.ndim == 0:
            sig[i] = sigma * np.sqrt(np.linalg.inv(A.T @ A)[0, 0])
        else:
            Aw = A / sigma[:, None]
            sig[i] = np.sqrt(np.linalg.inv(Aw.T @ Aw)[0, 0])
    return float(np.mean(np.abs(err) <= sig)), err, sig


def predicted_ranges(r_m, cdt_m, M21, links=None):
    """Noise-free pseudoranges (L,), m: sat 2 at ``r_m`` (3,) in the sat-1 body frame, clock
    ``cdt_m``; Xing et al.'s six links through ``M21`` or any ``links``."""
    if links is None:
        return predict_ranges(np.asarray(r_m, dtype=float), cdt_m, M21)
    e, _, _ = offset_range_residual(np.asarray(r_m, dtype=float)[None], np.array([cdt_m]),
                                    np.zeros((1, len(links.signs))), links.offsets_m, links.signs)
    return e[0]


def reference_ranges(seed=0, sigma_m=0.01):
    """Xing et al.'s measured pseudoranges (2, 6), m, at epochs 1 and 2 as the study draws
    them: the true geometry (:func:`formation_reference_truth`) plus N(0, sigma_m^2) noise from
    ``default_rng(seed)`` (epoch 1's six draws first)."""
    rng = np.random.default_rng(seed)
    out = np.empty((2, 6))
    for ep in (1, 2):
        r, cdt, M21 = formation_reference_truth(ep)
        out[ep - 1] = predict_ranges(r, cdt, M21) + sigma_m * rng.standard_normal(6)
    return out


def conditioning_study(runs=5000, seed=0, sigma_m=0.01):
    """The Xing et al. conditioning comparison as one JSON-able dict.

    Keys: ``cartesian`` and ``spherical`` (each: ``rcond``, ``cond``, ``rcond_1norm`` at the
    true geometry; ``covariance`` = {``epoch1``, ``epoch2`` (4x4 at each epoch's estimate,
    m^2 / rad^2), ``cofactor_epoch1/2`` ((A^T A)^-1 as Xing et al. print it), ``relative_change``,
    ``frobenius_change``}; ``sigmas_epoch1``; ``estimate_epoch1/2``), ``coverage_1sigma``,
    ``runs``, ``seed``, ``geometry`` and ``seed003_reported``.
    """
    out = {}
    measured = reference_ranges(seed, sigma_m)
    for param in PARAMS:
        r, cdt, M21 = formation_reference_truth(1)
        cd = conditioning(design_matrix(np.r_[to_param(r, param), cdt], M21, param))
        sols = []
        for ep in (1, 2):
            r, cdt, M21 = formation_reference_truth(ep)
            sols.append(solve_single_epoch(measured[ep - 1], M21, param, np.asarray(FORMATION_REFERENCE["x0_cart_m"]),
                                           sigma_m=sigma_m))
        rel, fro = covariance_change(sols[0].covariance, sols[1].covariance)
        out[param] = {
            **cd,
            "unknowns": (["x_m", "y_m", "z_m", "cdt_m"] if param == "cartesian"
                         else ["R_m", "az_rad", "el_rad", "cdt_m"]),
            "covariance": {"epoch1": sols[0].covariance.tolist(),
                           "epoch2": sols[1].covariance.tolist(),
                           "cofactor_epoch1": sols[0].cofactor.tolist(),
                           "cofactor_epoch2": sols[1].cofactor.tolist(),
                           "relative_change": rel, "frobenius_change": fro,
                           "max_abs_cofactor": float(np.abs(sols[0].cofactor).max())},
            "rcond_at_estimate": [s.rcond for s in sols],
            "sigmas_epoch1": sols[0].sigmas.tolist(),
            "estimate_epoch1": {"R_m": float(sols[0].spherical[0]),
                                "az_rad": float(sols[0].spherical[1]),
                                "el_rad": float(sols[0].spherical[2]), "cdt_m": sols[0].cdt_m},
            "estimate_epoch2": {"R_m": float(sols[1].spherical[0]),
                                "az_rad": float(sols[1].spherical[1]),
                                "el_rad": float(sols[1].spherical[2]), "cdt_m": sols[1].cdt_m},
            "iterations": [s.iterations for s in sols],
        }
    cov, _, _ = coverage_monte_carlo(runs, seed + 1, sigma_m)
    out["coverage_1sigma"] = cov
    out["runs"] = int(runs)
    out["seed"] = int(seed)
    out["sigma_code_m"] = sigma_m
    out["rcond_ratio_spherical_over_cartesian"] = out["spherical"]["rcond"] / out["cartesian"]["rcond"]
    out["geometry"] = {"R_true_m": list(FORMATION_REFERENCE["R_m"]), "az_rad": 0.0, "el_rad": 0.0,
                       "M21": "identity (roll = pitch = yaw = 0)",
                       "initial_guess": "R = 1992 m, az = el = 0, c dt = 0",
                       "units": "x, y, z, R, c dt in m; az, el in rad; rcond = "
                                "lambda_min/lambda_max of A^T A (A unwhitened)"}
    out["seed003_reported"] = FORMATION_REFERENCE["reported"]
    return out


TRACK_COLUMNS = [
    ("t_s", "time from the first epoch, s"),
    ("est_x_m", "estimated x of sat 2 in sat-1 body frame, m"),
    ("est_y_m", "estimated y, m"), ("est_z_m", "estimated z, m"),
    ("true_x_m", "true x, m"), ("true_y_m", "true y, m"), ("true_z_m", "true z, m"),
    ("sigma_x_m", "1-sigma of x, m"), ("sigma_y_m", "1-sigma of y, m"),
    ("sigma_z_m", "1-sigma of z, m"),
    ("est_R_m", "estimated range, m"), ("est_az_rad", "estimated azimuth, rad"),
    ("est_el_rad", "estimated elevation, rad"),
    ("true_R_m", "true range, m"), ("true_az_rad", "true azimuth, rad"),
    ("true_el_rad", "true elevation, rad"),
    ("sigma_R_m", "1-sigma of range, m"), ("sigma_az_rad", "1-sigma of azimuth, rad"),
    ("sigma_el_rad", "1-sigma of elevation, rad"),
    ("est_cdt_m", "estimated relative clock bias c dt, m"), ("true_cdt_m", "true c dt, m"),
    ("sigma_cdt_m", "1-sigma of c dt, m"),
    ("nees_pos", "position NEES in the solved parameterization (3 dof)"),
]
"""Columns of ``trajectory.csv`` written by :func:`run_track` (name, meaning)."""


def run_track(sc, param="spherical", solver="batch", seed=0, out_dir=None, rerun_path=None):
    """Simulate and solve the time-series case; optionally write CSV, summary and Rerun.

    Writes ``out_dir/trajectory.csv`` (columns :data:`TRACK_COLUMNS`, sigmas mapped to both
    coordinate sets by the Jacobian of r(R, az, el)) and ``out_dir/summary.json``.
    Returns the summary dict.
    """
    rng = np.random.default_rng(seed)
    sim = simulate_formation(sc, rng)
    res = (solve_batch if solver == "batch" else solve_isam2)(sim, sc, param)
    s, ss = res.spherical()
    r, sr = res.cartesian()
    ts = to_param(sim["r_body_m"], "spherical")
    sig_c = np.sqrt(res.cov[:, 6, 6])
    nees = nees_of(res, sim)
    nees_state = nees_of(res, sim, "state")
    err_s = s - ts
    err_s[:, 1] = np.angle(np.exp(1j * err_s[:, 1]))
    rms = lambda e: float(np.sqrt(np.mean(e ** 2)))  # noqa: E731
    summary = {
        "param": param, "solver": solver, "seed": int(seed), "n_epochs": int(sim["t_s"].size),
        "carrier": bool(sc.carrier), "iterations": int(res.iterations),
        "rms_error": {"R_m": rms(err_s[:, 0]), "az_rad": rms(err_s[:, 1]),
                      "el_rad": rms(err_s[:, 2]),
                      "position_m": rms(np.linalg.norm(r - sim["r_body_m"], axis=1)),
                      "cdt_m": rms(res.cdt_m - sim["cdt_m"])},
        "mean_sigma": {"R_m": float(ss[:, 0].mean()), "az_rad": float(ss[:, 1].mean()),
                       "el_rad": float(ss[:, 2].mean()), "cdt_m": float(sig_c.mean())},
        "mean_nees_position": float(nees.mean()), "mean_nees_state": float(nees_state.mean()),
        "info": {k: v for k, v in res.info.items() if not isinstance(v, np.ndarray)},
        "scenario": scenario_dict(sc),
        "csv_columns": [c for c, _ in TRACK_COLUMNS],
    }
    if rerun_path is not None:
        write_rerun(rerun_path, sim["t_s"], r, sim["r_body_m"], ss)
        summary["rerun"] = str(rerun_path)
    if out_dir is not None:
        os.makedirs(out_dir, exist_ok=True)
        table = np.column_stack([sim["t_s"], r, sim["r_body_m"], sr, s, ts, ss, res.cdt_m,
                                 sim["cdt_m"], sig_c, nees])
        header = ",".join(c for c, _ in TRACK_COLUMNS)
        tmp = os.path.join(out_dir, "trajectory.csv.tmp")
        np.savetxt(tmp, table, delimiter=",", header=header, comments="", fmt="%.12g")
        os.replace(tmp, os.path.join(out_dir, "trajectory.csv"))
        with open(os.path.join(out_dir, "summary.json.tmp"), "w") as fh:
            json.dump(summary, fh, indent=2)
        os.replace(os.path.join(out_dir, "summary.json.tmp"), os.path.join(out_dir, "summary.json"))
    return summary


def write_rerun(path, t_s, r_est_m, r_true_m, sigma_sph):
    """Rerun recording: estimated and true relative positions (sat-1 body frame, m) and the
    range/angle sigmas over time, logged with ``rr.send_columns``."""
    import rerun as rr

    rec = rr.RecordingStream("fgnav_formation")
    rec.save(str(path))
    times = [rr.TimeColumn("t_s", duration=np.asarray(t_s, dtype=float))]
    rr.send_columns("formation/estimate", indexes=times,
                    columns=rr.Points3D.columns(positions=np.asarray(r_est_m)), recording=rec)
    rr.send_columns("formation/truth", indexes=times,
                    columns=rr.Points3D.columns(positions=np.asarray(r_true_m)), recording=rec)
    for i, name in enumerate(("sigma_R_m", "sigma_az_rad", "sigma_el_rad")):
        rr.send_columns(f"formation/{name}", indexes=times,
                        columns=rr.Scalars.columns(scalars=np.asarray(sigma_sph[:, i])),
                        recording=rec)
    rec.flush()
