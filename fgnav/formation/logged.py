"""Xing et al.'s single-epoch study on one epoch of a logged formation pass.

Xing et al. (ST-3 Autonomous Formation Flyer pseudorange positioning) solve sat 2's position
in sat 1's body frame and the relative clock from the six pseudoranges of one epoch, and
compare the conditioning of the Cartesian and the spherical unknowns. Here the same solution
(:mod:`fgnav.iod.single_epoch`) runs on a measurement log (format v1 with the
``spacecraft`` column, :mod:`fgnav.io.log_spacecraft`):

* the epoch's ``isl_pseudorange`` rows (six: sat 2's transmit antenna to sat 1's three
  receive antennas and back), between the log's first two spacecraft;
* their antennas' lever arms from the ``# antenna:`` declarations (an empty antenna is the
  centre of mass);
* the relative attitude ``M21 = R_body1_from_body2 = R1^T R2`` from the two spacecraft's
  ``attitude`` rows at that epoch (``R_eci_from_body`` as rotation vectors).

A row received by sat 1 from sat 2 is ``|r + M21 a_tx - a_rx| + c dt``, one received by sat 2
from sat 1 ``|r + M21 a_rx - a_tx| - c dt`` (Xing et al., eq. (1); ``c dt`` = c (dt_1 - dt_2),
the clock of the log's format). The model is instantaneous: the light time of a logged pass
moves each transmitter by ``v tau`` (~3 cm in the formation-gto scenario), which changes the
two directions' ranges by ``-/+ u.v tau`` -- the pattern of the clock term -- so it appears in
the clock estimate (``c dt - u.v tau``), not in the range or the angles.

Figures (those of :func:`fgnav.formation.study.conditioning_study`, at the logged estimate
since a log has no truth): rcond of the unwhitened ``A^T A`` for both parameterizations, the
1-sigma of (R, az, el, c dt) from ``(A^T W A)^-1`` with the rows' sigmas, and the Monte Carlo
1-sigma coverage of the range around the estimate (Xing et al.: 67.5 % of 120 runs).
"""

from __future__ import annotations

import numpy as np

from factors.pseudorange import ANTENNA_RX_BODY_M, ANTENNA_TX_BODY_M
from fgnav.errors import UserError
from fgnav.iod.links import N_LINKS_LOGGED, LoggedEpoch, far_field_guess, logged_epoch  # noqa: F401
from fgnav.iod.single_epoch import PARAMS, conditioning, solve_single_epoch
from fgnav.formation.study import FORMATION_REFERENCE, range_coverage, reference_ranges
from fgnav.io.log_csv import MeasurementLog, log_from_arrays, write_log
from fgnav.io.log_spacecraft import ISL_KINDS
from fgnav.models.registry import ATTITUDE
from fgnav.paths import data_dir

__all__ = ["LoggedEpoch", "logged_epoch", "far_field_guess", "logged_conditioning",
           "xing_single_epoch_log", "XING_LOG_NAME", "XING_EPOCH", "N_LINKS_LOGGED"]

XING_LOG_NAME = "formation/xing-single-epoch.csv"
"""Xing et al.'s two epochs as a log, under the package data (:func:`xing_single_epoch_log`)."""
XING_EPOCH = "2025-01-01T00:00:00Z"
"""The first epoch of that log (Xing et al. give no date; the second epoch is 10 s later)."""
XING_ATTITUDE_SIGMA_RAD = 4.84813681109536e-06
"""The 1-sigma written on that log's attitude rows: 1 arcsec (a star tracker's)."""


def logged_conditioning(ep: LoggedEpoch, runs: int = 5000, seed: int = 0) -> dict:
    """The single-epoch study on a logged epoch as one JSON-able dict (module docstring).

    Keys: ``cartesian`` and ``spherical`` (each: ``rcond``, ``cond``, ``rcond_1norm`` of the
    unwhitened ``A^T A`` at its estimate; ``unknowns``; ``covariance`` (4x4 at the estimate,
    m^2 / rad^2); ``cofactor`` ``(A^T A)^-1``; ``sigmas``; ``iterations``; ``converged``),
    ``estimate`` (``R_m``, ``az_rad``, ``el_rad``, ``cdt_m``, ``r_body1_m``),
    ``coverage_1sigma``, ``runs``, ``seed``, ``rcond_ratio_spherical_over_cartesian``,
    ``log`` (path, epoch, spacecraft, links, M21) and ``seed003_reported`` (Xing et al.).
    """
    if isinstance(runs, bool) or not isinstance(runs, (int, np.integer)) or runs < 1:
        raise UserError(f"--runs must be an integer >= 1, got {runs!r}")
    x0 = far_field_guess(ep.rho_m, ep.links, ep.face_m)
    w = 1.0 / ep.sigma_m
    out = {}
    est = None
    for param in PARAMS:
        sol = solve_single_epoch(ep.rho_m, ep.M21, param, x0, sigma_m=1.0, links=ep.links)
        if not sol.converged:
            raise UserError(f"{ep.path}: epoch {ep.epoch_utc}: Gauss–Newton did not converge "
                            f"({param}, {sol.iterations} iterations); the links do not fix "
                            "the relative position")
        Aw = sol.A * w[:, None]
        cov = np.linalg.inv(Aw.T @ Aw)
        out[param] = {
            **conditioning(sol.A),
            "unknowns": (["x_m", "y_m", "z_m", "cdt_m"] if param == "cartesian"
                         else ["R_m", "az_rad", "el_rad", "cdt_m"]),
            "covariance": cov.tolist(), "cofactor": sol.cofactor.tolist(),
            "sigmas": np.sqrt(np.diag(cov)).tolist(), "iterations": sol.iterations,
            "converged": sol.converged,
        }
        if param == "spherical":
            est = sol
    cov, _, _ = range_coverage(est.r_m, est.cdt_m, None, runs, seed + 1, ep.sigma_m,
                               "spherical", np.r_[est.r_m, est.cdt_m], links=ep.links)
    out["estimate"] = {"R_m": float(est.spherical[0]), "az_rad": float(est.spherical[1]),
                       "el_rad": float(est.spherical[2]), "cdt_m": est.cdt_m,
                       "r_body1_m": est.r_m.tolist()}
    out["coverage_1sigma"] = cov
    out["runs"] = int(runs)
    out["seed"] = int(seed)
    out["rcond_ratio_spherical_over_cartesian"] = (out["spherical"]["rcond"]
                                                   / out["cartesian"]["rcond"])
    out["log"] = {"path": ep.path, "epoch": ep.epoch_utc, "spacecraft": list(ep.ids),
                  "links": [{"link": lab, "line": int(ln), "rho_m": float(r), "sigma_m": float(s)}
                            for lab, ln, r, s in zip(ep.labels, ep.lines, ep.rho_m, ep.sigma_m)],
                  "M21": ep.M21.tolist(),
                  "units": "x, y, z, R, c dt in m; az, el in rad; rcond = lambda_min/lambda_max "
                           "of A^T A (A unwhitened) at the estimate"}
    out["seed003_reported"] = FORMATION_REFERENCE["reported"]
    return out


def xing_single_epoch_log(seed: int = 0, sigma_m: float = 0.01) -> MeasurementLog:
    """Xing et al.'s geometry as a log: spacecraft ``sat1``, ``sat2`` with the ST-3 antennas
    (:data:`factors.pseudorange.ANTENNA_TX_BODY_M`, ``ANTENNA_RX_BODY_M``) declared, both
    attitudes the identity (``M21 = I``) as attitude rows, and the six pseudoranges of each
    of the two epochs (:data:`XING_EPOCH` and 10 s later) as the built-in study draws them
    (:func:`fgnav.formation.study.reference_ranges`), so a logged epoch and the built-in
    geometry give the same estimate. Link order: sat 1's receive antennas rx1-rx3 from sat
    2's tx0, then sat 2's from sat 1's (``factors.pseudorange.link_offsets``)."""
    ids = ("sat1", "sat2")
    antennas = {}
    for s in ids:
        antennas[(s, "tx0")] = ANTENNA_TX_BODY_M
        for j, a in enumerate(ANTENNA_RX_BODY_M):
            antennas[(s, f"rx{j + 1}")] = a
    rho = reference_ranges(seed, sigma_m)
    t, kind, xyz, sig = [], [], [], []
    ex = {c: [] for c in ("spacecraft", "tx_spacecraft", "rx_antenna", "tx_antenna")}

    def row(t_s, k, v, s, sc, txs=None, rxa=None, txa=None):
        t.append(t_s)
        kind.append(k)
        xyz.append(v)
        sig.append(s)
        for c, val in zip(ex, (sc, txs, rxa, txa)):
            ex[c].append(val)

    for e in range(2):
        t_s = 10.0 * e
        for s in ids:
            row(t_s, ATTITUDE.kind, [0.0, 0.0, 0.0], XING_ATTITUDE_SIGMA_RAD, s)
        for l in range(6):
            rx, txs = (ids[0], ids[1]) if l < 3 else (ids[1], ids[0])
            row(t_s, ISL_KINDS[0], [rho[e, l], np.nan, np.nan], sigma_m, rx, txs,
                f"rx{l % 3 + 1}", "tx0")
    return log_from_arrays(XING_EPOCH, t, kind, xyz, sig, {c: np.array(v, dtype=object)
                                                           for c, v in ex.items()},
                           spacecraft=ids, antennas=antennas)


def write_xing_single_epoch_log(path) -> None:
    """Write :func:`xing_single_epoch_log` (the shipped ``fgnav/data/`` + :data:`XING_LOG_NAME`
    is this function's output: ``python -m fgnav.formation.logged``)."""
    write_log(path, xing_single_epoch_log(), comments=(
        "Xing et al., ST-3 Autonomous Formation Flyer pseudorange positioning: Table 1 "
        "geometry (sat 2 on sat 1's body +x, R = 999.922 m then 999.891 m, az = el = 0, "
        "M21 = I, c dt = 0), 1 cm noise as the built-in study draws it (seed 0)",
        "written by fgnav.formation.logged.write_xing_single_epoch_log"))


if __name__ == "__main__":   # regenerate the shipped log
    target = data_dir() / XING_LOG_NAME
    target.parent.mkdir(parents=True, exist_ok=True)
    write_xing_single_epoch_log(target)
    print(target)
