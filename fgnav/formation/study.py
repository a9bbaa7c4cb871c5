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

The track case (:func:`run_track`, ``fgnav formation track``) is a study on the one
pipeline: a 1 km closed Clohessy-Wiltshire orbit in LEO (Clohessy & Wiltshire 1960) built as
a formation scenario (:func:`track_scenario`), flown by the formation simulator and solved by
:func:`fgnav.pipeline.smooth_log`; its results are reported in sat 1's body frame, Cartesian
or spherical (Xing et al.'s parameterizations), mapped by the Jacobian.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass

import numpy as np

from factors.geometry import so3_exp
from factors.pseudorange import (ANTENNA_RX_BODY_M, ANTENNA_TX_BODY_M, offset_range_residual,
                                 predict_ranges, spherical_to_cartesian)
from fgnav.errors import UserError
from fgnav.io.log_spacecraft import spacecraft_index
from fgnav.formation.relative_motion import (chief_circular_state, circular_relative_orbit,
                                             mean_motion)
from fgnav.frames import (deputy_from_relative_lvlh, relative_position_body,
                          relative_state_lvlh)
from fgnav.iod.single_epoch import (
    PARAMS, conditioning, design_matrix, from_param, solve_single_epoch, solve_single_epoch_many,
    to_param,
)
from fgnav.measurements import spacecraft_states
from fgnav.models.registry import ATTITUDE, EARTH_DIRECTION
from fgnav.pipeline import smooth_log
from fgnav.results import relative_rows
from fgnav.scenarios import (FormationSpec, LinkSpec, RangingSpec, Scenario, SensorSpec,
                             SpacecraftSpec)
from fgnav.simulate.formation_sim import attitude_law, simulate_formation_pass
from fgnav.defaults import DEFAULT_Q_M2_S3
from fgnav.solvers.options import SmootherOptions

__all__ = ["FORMATION_REFERENCE", "formation_reference_truth", "conditioning_study", "coverage_monte_carlo",
           "covariance_change", "range_coverage", "predicted_ranges", "reference_ranges",
           "TRACK_COLUMNS", "FormationScenario", "track_scenario", "track_solution", "run_track",
           "write_rerun"]

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
    ("nees_pos", "position NEES in the reported coordinates (--param; 3 dof)"),
]
"""Columns of ``trajectory.csv`` written by :func:`run_track` (name, meaning)."""

TRACK_IDS = ("sat1", "sat2")
TRACK_EPOCH = "2025-03-01T00:00:00Z"
TRACK_STREAM = 5
"""Second entropy word of the deputy's draw off the design (``default_rng([seed, 5])``); the
formation simulator's own streams use ``seed`` and ``[seed, 3, ...]``."""
_ARCSEC = np.pi / (180.0 * 3600.0)
XING_ANTENNAS = (("tx0", tuple(ANTENNA_TX_BODY_M)),) + tuple(
    (f"rx{j + 1}", tuple(a)) for j, a in enumerate(ANTENNA_RX_BODY_M))
"""Xing et al.'s antennas, the same on both cubes (name, body m; factors.pseudorange)."""


@dataclass(frozen=True)
class FormationScenario:
    """The track case (SI inside; km/deg/arcsec only where named): a circular chief at
    ``alt_km``, the deputy on the closed Clohessy-Wiltshire orbit of separation ``radius_m``
    (:func:`~fgnav.formation.relative_motion.circular_relative_orbit`, ``phase_rad`` at
    t = 0) off by ``sigma_init_*`` (its truth's draw off the design), Xing et al.'s six
    antenna-to-antenna links (code ``sigma_code_m``; with ``carrier`` carrier phase
    ``sigma_carrier_m`` and float ambiguities ``sigma_ambiguity_m``), a random-walk relative
    clock (``sigma_init_clock_m`` at the start, PSD ``q_clock_m2_s``), and the absolute rows
    a formation scenario has: each spacecraft's Earth direction (``earth_direction_sigma_deg``),
    attitude rows (``attitude_sigma_arcsec``) and a prior (``prior_*``). ``q_m2_s3``: the
    smoother's process noise on each orbit (white acceleration PSD)."""

    alt_km: float = 500.0
    radius_m: float = 1000.0
    phase_rad: float = 0.3
    duration_s: float = 600.0
    step_s: float = 10.0
    sigma_code_m: float = 0.01          # pseudorange noise (Xing et al.)
    sigma_carrier_m: float = 1e-5       # carrier-phase noise (Xing et al. ref. [1]: 10 um)
    carrier: bool = False
    q_m2_s3: float = DEFAULT_Q_M2_S3
    q_clock_m2_s: float = 1e-4          # clock random-walk PSD (c dt in m)
    sigma_init_pos_m: float = 1.0       # the deputy's truth off the design at t = 0
    sigma_init_vel_mps: float = 1e-3
    sigma_init_clock_m: float = 1.0
    sigma_ambiguity_m: float = 1.0
    inc_deg: float = 97.4
    earth_direction_sigma_deg: float = 0.01
    attitude_sigma_arcsec: float = 1.0
    prior_position_sigma_m: float = 100.0
    prior_velocity_sigma_mps: float = 0.1

    def validate(self):
        if not (self.step_s > 0 and self.duration_s >= 2 * self.step_s):
            raise UserError("need step_s > 0 and duration_s >= 2 step_s")
        for name in ("sigma_code_m", "sigma_carrier_m", "q_m2_s3", "q_clock_m2_s", "radius_m"):
            if not getattr(self, name) > 0:
                raise UserError(f"{name} must be positive, got {getattr(self, name)}")


def track_scenario(sc: FormationScenario, seed: int = 0) -> Scenario:
    """The track case as a formation :class:`~fgnav.scenarios.Scenario` (two spacecraft on
    their own ``[spacecraft.orbit]``, Xing et al.'s antennas and links, two-body + J2 truth
    from the independent integrator). ``seed`` draws the deputy's start off the design
    (``default_rng([seed, TRACK_STREAM])``).

    Attitude: each spacecraft Earth-pointing in its LVLH plan, sat 1 yawed about nadir so its
    antenna face (+x) points at the deputy's start (in the x-z plane), sat 2 yawed 180 deg
    more, so the faces face each other (``M21 = diag(-1, -1, 1)``, Xing et al.); the line of
    sight then moves in the body frame as the deputy circles."""
    sc.validate()
    n = mean_motion(sc.alt_km)
    chief = chief_circular_state(sc.alt_km, sc.inc_deg)
    rel0 = circular_relative_orbit(sc.radius_m, n, np.array([0.0]), sc.phase_rad)[0]
    rng = np.random.default_rng([seed, TRACK_STREAM])
    rel0[:3] += sc.sigma_init_pos_m * rng.standard_normal(3)
    rel0[3:] += sc.sigma_init_vel_mps * rng.standard_normal(3)
    deputy = deputy_from_relative_lvlh(chief[None], rel0[None])[0]
    # the deputy's direction in sat 1's LVLH plan (x ahead, z nadir), yaw about z
    u = attitude_law(chief[None], 0.0)[0].T @ (deputy[:3] - chief[:3])
    yaw_deg = float(np.rad2deg(np.arctan2(u[1], u[0])))
    antennas = tuple((i, name, tuple(arm)) for i in TRACK_IDS for name, arm in XING_ANTENNAS)
    links = tuple(LinkSpec(rx=rx, tx=tx, rx_antenna=f"rx{j}", tx_antenna="tx0")
                  for rx, tx in (("sat1", "sat2"), ("sat2", "sat1")) for j in (1, 2, 3))
    ranging = RangingSpec(
        sigma_m=sc.sigma_code_m, carrier_sigma_m=sc.sigma_carrier_m if sc.carrier else 0.0,
        ambiguity_sigma_m=sc.sigma_ambiguity_m, clock_sigma0_m=sc.sigma_init_clock_m,
        clock_random_walk_m_per_sqrt_s=float(np.sqrt(sc.q_clock_m2_s)),
        attitude_sigma_rad=sc.attitude_sigma_arcsec * _ARCSEC)
    formation = FormationSpec(
        spacecraft=(SpacecraftSpec("sat1", tuple(chief), yaw_deg=yaw_deg),
                    SpacecraftSpec("sat2", tuple(deputy), yaw_deg=yaw_deg + 180.0)),
        antennas=antennas, links=links, ranging=ranging)
    return Scenario(
        name="formation-track", description=f"LEO {sc.alt_km:g} km, {sc.radius_m:g} m CW "
        "relative orbit, Xing et al.'s six links", epoch=TRACK_EPOCH,
        duration_h=sc.duration_s / 3600.0, step_s=sc.step_s, x0_eci=tuple(chief),
        truth_j2=True, prior_position_sigma_m=sc.prior_position_sigma_m,
        prior_velocity_sigma_mps=sc.prior_velocity_sigma_mps,
        sensors=(SensorSpec(kind=EARTH_DIRECTION.kind, sigma_deg=sc.earth_direction_sigma_deg),),
        formation=formation)


def _logged_attitude(log, sc, k_of, n):
    """R_eci_from_body (n, 3, 3) of spacecraft index ``sc`` from its attitude rows at the
    epochs ``k_of`` (row times -> solution epoch indices)."""
    rows = np.flatnonzero((np.asarray(log.kind) == ATTITUDE.kind) & (spacecraft_index(log) == sc))
    R = np.full((n, 3, 3), np.nan)
    R[k_of(np.asarray(log.t_s, dtype=float)[rows])] = so3_exp(np.asarray(log.xyz, dtype=float)[rows])
    return R


def _nees(e, P):
    return np.einsum("ki,ki->k", e, np.linalg.solve(P, e[..., None])[..., 0])


def track_solution(sim, sol, p, sc: FormationScenario, param: str = "spherical"):
    """The track's per-epoch figures from a pipeline solution of ``sim``: sat 2 in sat 1's
    body frame (estimate through sat 1's logged attitude, truth through its true attitude),
    its covariance ``J P J^T`` from the joint marginals of the two orbits
    (:func:`fgnav.frames.relative_position_body`) plus the attitude rows'
    ``skew(r) s^2 skew(r)^T``, the spherical form by the Jacobian of ``r(R, az, el)``
    (:func:`factors.pseudorange.spherical_to_cartesian`), the relative clock, and the NEES in
    the coordinates ``param`` names: of the position (3 dof) and of the state (7 dof: that
    position, the LVLH relative velocity, the clock; joint covariance)."""
    lay = p.layout
    t = np.asarray(sol.t_s, dtype=float)
    n = t.size

    def k_of(ts):
        k = np.clip(np.searchsorted(t, ts - 1e-6), 0, n - 1)
        if not np.allclose(t[k], ts, atol=1e-6):
            raise RuntimeError("the solution's epochs are not the track's epochs")
        return k

    kt = np.searchsorted(sim.t_s, t - 1e-6)   # the truth at the solution's epochs
    if not np.allclose(sim.t_s[np.minimum(kt, sim.t_s.size - 1)], t, atol=1e-6):
        raise RuntimeError("the simulated truth does not hold the solution's epochs")
    xt = [sim.x_true[i][kt] for i in TRACK_IDS]
    Rt = sim.R_eci_from_body[TRACK_IDS[0]][kt]
    (xc, _), (xd, _) = spacecraft_states(sol, lay)
    r, J_c, J_d, J_att = relative_position_body(xc, xd, _logged_attitude(sim.log, 0, k_of, n))
    rel, _, (Jl_c, Jl_d, _) = relative_rows(sol, p, 1, 0)
    clock = next(name for name in sol.variables if name.startswith("clock_"))
    cdt, Pcdt = sol.variables[clock]
    cdt_true = np.interp(t, sim.t_link, sim.clock_m)
    r_true = relative_position_body(xt[0], xt[1], Rt)[0]
    s, s_true = to_param(r, "spherical"), to_param(r_true, "spherical")
    G = np.linalg.inv(spherical_to_cartesian(s)[1])           # d(R, az, el)/dr
    # joint covariance of [body position; LVLH velocity; clock] from the block marginals
    sl = [lay.slices[v.name] for v in lay.orbits[:2]] + [lay.slices[clock]]
    idx = np.concatenate([np.arange(q.start, q.stop) for q in sl])
    Pj = sol.P_block[:, idx[:, None], idx[None, :]]
    J = np.zeros((n, 7, idx.size))
    J[:, :3, :12] = np.concatenate([J_c, J_d], axis=2)
    J[:, 3:6, :12] = np.concatenate([Jl_c[:, 3:], Jl_d[:, 3:]], axis=2)
    J[:, 6, 12] = 1.0
    P7 = np.einsum("kij,kjl,kml->kim", J, Pj, J)
    s_att = sc.attitude_sigma_arcsec * _ARCSEC
    P7[:, :3, :3] += s_att ** 2 * np.einsum("kij,klj->kil", J_att, J_att)
    P7 = 0.5 * (P7 + np.swapaxes(P7, 1, 2))
    Pc = P7[:, :3, :3]
    Ps = np.einsum("kij,kjl,kml->kim", G, Pc, G)
    e_s = s - s_true
    e_s[:, 1] = np.angle(np.exp(1j * e_s[:, 1]))
    e7 = np.concatenate([r - r_true, rel[:, 3:] - relative_state_lvlh(xt[0], xt[1])[0][:, 3:],
                         (cdt[:, 0] - cdt_true)[:, None]], axis=1)
    if param == "spherical":   # the position rows in (R, az, el)
        M = np.tile(np.eye(7), (n, 1, 1))
        M[:, :3, :3] = G
        P7 = np.einsum("kij,kjl,kml->kim", M, P7, M)
        e7[:, :3] = e_s
    sd = lambda P: np.sqrt(np.maximum(np.diagonal(P, axis1=1, axis2=2), 0.0))  # noqa: E731
    return {"t_s": t, "r": r, "r_true": r_true, "sigma_r": sd(Pc), "s": s, "s_true": s_true,
            "e_s": e_s, "sigma_s": sd(Ps), "cdt": cdt[:, 0], "cdt_true": cdt_true,
            "sigma_cdt": np.sqrt(Pcdt[:, 0, 0]), "nees_position": _nees(e7[:, :3], P7[:, :3, :3]),
            "nees_state": _nees(e7, P7)}


def run_track(sc, param="spherical", solver="batch", seed=0, out_dir=None, rerun_path=None):
    """Simulate the track case as a formation (:func:`track_scenario`, the formation
    simulator's independent truth), solve it with the one pipeline (``solver`` batch or
    isam2: both spacecraft's orbits, the relative clock and the ambiguities as ordinary
    variables, :func:`fgnav.pipeline.smooth_log`), and report sat 2 in sat 1's body frame
    (:func:`track_solution`).

    ``param`` names the coordinates the result is *reported* in (the NEES column and
    ``mean_nees_position``); the smoother's minimum does not depend on the chart: it solves
    Cartesian ECI states and both coordinate sets are mapped by the Jacobian of
    ``r(R, az, el)`` (Xing et al. 2008's spherical parameterization).

    Writes ``out_dir/trajectory.csv`` (columns :data:`TRACK_COLUMNS`) and
    ``out_dir/summary.json``. Returns the summary dict.
    """
    if param not in PARAMS:
        raise UserError(f"param must be one of {PARAMS}, got {param!r}")
    if solver not in ("batch", "isam2"):
        raise UserError(f"solver must be batch or isam2, got {solver!r}")
    scn = track_scenario(sc, seed)
    sim = simulate_formation_pass(scn, seed)
    res, p = smooth_log(sim.log, solver, SmootherOptions(q_m2_s3=sc.q_m2_s3))
    sol = res.solution
    tr = track_solution(sim, sol, p, sc, param)
    err_s, nees = tr["e_s"], tr["nees_position"]
    rms = lambda e: float(np.sqrt(np.mean(e ** 2)))  # noqa: E731
    ss = tr["sigma_s"]
    summary = {
        "param": param, "solver": solver, "seed": int(seed), "n_epochs": int(tr["t_s"].size),
        "carrier": bool(sc.carrier), "iterations": int(sol.iterations),
        "rms_error": {"R_m": rms(err_s[:, 0]), "az_rad": rms(err_s[:, 1]),
                      "el_rad": rms(err_s[:, 2]),
                      "position_m": rms(np.linalg.norm(tr["r"] - tr["r_true"], axis=1)),
                      "cdt_m": rms(tr["cdt"] - tr["cdt_true"])},
        "mean_sigma": {"R_m": float(ss[:, 0].mean()), "az_rad": float(ss[:, 1].mean()),
                       "el_rad": float(ss[:, 2].mean()), "cdt_m": float(tr["sigma_cdt"].mean())},
        "mean_nees_position": float(nees.mean()), "mean_nees_state": float(tr["nees_state"].mean()),
        "info": {"route": "fgnav.pipeline (one graph: both orbits, relative clock"
                          + (", ambiguities)" if sc.carrier else ")"),
                 "final_error": 0.5 * float(sol.chi2), "chi2": float(sol.chi2),
                 "wall_s": float(sol.wall_s), "converged": sol.extras.get("converged"),
                 "integrity": res.summary["integrity"]["status"],
                 "integrity_reasons": list(res.summary["integrity"].get("reasons", [])),
                 "yaw_deg": [s.yaw_deg for s in scn.formation.spacecraft],
                 "measurements": res.summary["measurements"]},
        "scenario": asdict(sc),
        "csv_columns": [c for c, _ in TRACK_COLUMNS],
    }
    if rerun_path is not None:
        write_rerun(rerun_path, tr["t_s"], tr["r"], tr["r_true"], ss)
        summary["rerun"] = str(rerun_path)
    if out_dir is not None:
        os.makedirs(out_dir, exist_ok=True)
        table = np.column_stack([tr["t_s"], tr["r"], tr["r_true"], tr["sigma_r"], tr["s"],
                                 tr["s_true"], ss, tr["cdt"], tr["cdt_true"], tr["sigma_cdt"],
                                 nees])
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
