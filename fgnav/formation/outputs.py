"""What a formation's solution adds to the outputs: relative states, their spherical form, the
joint solution's verdict.

``fgnav smooth`` on a log with a ``spacecraft`` column runs the one route of
:mod:`fgnav.pipeline` (``smooth_log``, ``summarize``, ``write_outputs``), which writes, with
the pieces below:

* ``trajectory-<id>.oem`` per spacecraft (states and marginal covariances);
* ``relative.csv``: every further spacecraft's state relative to the first (the reference),
  in the reference's LVLH frame (:mod:`fgnav.formation.relative_state`) with its 1-sigmas and
  the full 6x6 covariance (upper triangle), and in the reference's body frame where the log
  gives its attitude at that epoch;
* ``variables.csv`` (the pairs' clocks, the carrier ambiguities), ``residuals.csv``;
* ``summary.json`` with ``spacecraft`` (per id: the one-spacecraft keys) and ``relative``
  (``position_rms_m``, ``velocity_rms_mps``, ``nees_mean`` against truth when given, the
  sigmas always), and the integrity verdict of the joint solution.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fgnav.formation.relative_state import (relative_covariance, relative_state_body,
                                            relative_state_lvlh)
from fgnav.diagnostics.integrity import (ADVICE, FALSE_ALARM_PROBABILITY, _chi2_test,
                                         _family_test, _severity)
from fgnav.measurements import spacecraft_states
from fgnav.models.model import COLUMN_PREFIX
from fgnav.models.registry import ATTITUDE
from fgnav.time import add_seconds, format_utc

__all__ = ["relative_rows", "truth_path_of", "relative_csv_text", "formation_integrity",
           "spherical_position", "spherical_position_nees", "spherical_summary", "sigma_rms"]

_LVLH = ("x", "y", "z", "vx", "vy", "vz")


def truth_path_of(truth: str | Path, spacecraft_id: str) -> Path:
    """``truth-<id>.oem`` in the directory ``truth`` (or beside the file ``truth``)."""
    d = Path(truth)
    return (d if d.is_dir() else d.parent) / f"truth-{spacecraft_id}.oem"


def relative_rows(sol, p, s: int):
    """Spacecraft ``s``'s state relative to the first: LVLH state (N, 6) and covariance
    (N, 6, 6) from the joint marginals (cross-covariances included)."""
    lay = p.layout
    states = spacecraft_states(sol, lay)
    xc, xd = states[0][0], states[s][0]
    rel, J_c, J_d = relative_state_lvlh(xc, xd)
    sl_c, sl_d = lay.slices[lay.orbits[0].name], lay.slices[lay.orbits[s].name]
    idx = np.r_[np.arange(sl_c.start, sl_c.stop), np.arange(sl_d.start, sl_d.stop)]
    P_joint = sol.P_block[:, idx[:, None], idx[None, :]]
    return rel, relative_covariance(J_c, J_d, P_joint), (J_c, J_d, P_joint)


def _reference_attitude(p, sol):
    """R_eci_from_body (N, 3, 3) of the reference spacecraft at the solution's epochs where
    the log has an attitude row for it (NaN elsewhere)."""
    R = np.full((len(sol.t_s), 3, 3), np.nan)
    fam = p.deferred.get(ATTITUDE.kind)
    if fam is not None:
        own = np.asarray(fam.values[COLUMN_PREFIX + "orbit"]) == 0
        R[fam.k[own]] = fam.values["R_eci_from_body"][own]
    return R


def sigma_rms(P) -> dict:
    """RMS position and velocity 1-sigma (m, m/s) of covariances ``P`` (N, 6, 6)."""
    return {"sigma_position_rms_m": float(np.sqrt(np.mean(np.trace(P[:, :3, :3], axis1=1, axis2=2)))),
            "sigma_velocity_rms_mps": float(np.sqrt(np.mean(np.trace(P[:, 3:, 3:], axis1=1, axis2=2))))}


def spherical_position(r_lvlh, C_lvlh):
    """Range (m), azimuth and elevation (rad) of relative positions (N, 3) in LVLH
    (``factors.pseudorange.cartesian_to_spherical``: azimuth about z from x, elevation from
    the x-y plane) and their covariances (N, 3, 3) by the Jacobian at the estimate."""
    from factors.pseudorange import cartesian_to_spherical, spherical_to_cartesian

    s = cartesian_to_spherical(r_lvlh)
    J = np.linalg.inv(spherical_to_cartesian(s)[1])
    return s, np.einsum("kij,kjl,kml->kim", J, C_lvlh, J)


def _spherical_error(s_est, r_true):
    """``s_est`` (N, 3: range, azimuth, elevation) minus the spherical coordinates of the
    true positions ``r_true`` (N, 3), the azimuth difference wrapped to [-pi, pi)."""
    from factors.pseudorange import cartesian_to_spherical

    e = s_est - cartesian_to_spherical(r_true)
    e[:, 1] = (e[:, 1] + np.pi) % (2 * np.pi) - np.pi
    return e


def spherical_summary(rel, C, rel_true) -> dict:
    """summary.json's spherical keys of a relative state ``rel`` (N, 6, LVLH) with covariances
    ``C``: the range, azimuth and elevation sigmas, and with ``rel_true`` their errors."""
    s, Cs = spherical_position(rel[:, :3], C[:, :3, :3])
    sig = np.sqrt(np.diagonal(Cs, axis1=1, axis2=2))
    out = {"parameterization": "spherical (range, azimuth, elevation in LVLH)",
           "sigma_range_rms_m": float(np.sqrt(np.mean(sig[:, 0] ** 2))),
           "sigma_azimuth_rms_rad": float(np.sqrt(np.mean(sig[:, 1] ** 2))),
           "sigma_elevation_rms_rad": float(np.sqrt(np.mean(sig[:, 2] ** 2)))}
    if rel_true is not None:
        e = _spherical_error(s, rel_true[:, :3])
        out.update({"range_rms_m": float(np.sqrt(np.mean(e[:, 0] ** 2))),
                    "azimuth_rms_rad": float(np.sqrt(np.mean(e[:, 1] ** 2))),
                    "elevation_rms_rad": float(np.sqrt(np.mean(e[:, 2] ** 2)))})
    return out


def spherical_position_nees(r_est, C, r_true) -> float:
    """Mean NEES (3 dof) of a relative position in spherical coordinates (range, azimuth,
    elevation; ``factors.pseudorange``), its covariance mapped by the Jacobian at the
    estimate. Ranges fix the relative position on a sphere: an error of metres along it
    is, in Cartesian coordinates, also a chord error of ``d^2/2R`` across it, beyond a
    centimetre sigma there, so the Cartesian NEES overstates the inconsistency of a
    consistent estimate (Xing et al. 2008's case for the spherical parameterization)."""
    s_est, Cs = spherical_position(r_est, C)
    e = _spherical_error(s_est, r_true)
    return float(np.mean(np.einsum("ki,ki->k", e, np.linalg.solve(Cs, e[..., None])[..., 0])))


def formation_integrity(sol, p) -> dict:
    """The verdict of a joint solution from its data alone (:mod:`fgnav.diagnostics.integrity`'s
    chi-square tests): each family's whitened residuals, the process rows (every orbit's
    motion and the clocks' random walks), convergence and finite numbers."""
    tests, reasons, advice, status = {}, [], [], "ok"
    rank = {"ok": 0, "suspect": 1, "failed": 2}

    def worse(s, why, adv):
        nonlocal status
        if rank[s] > rank[status]:
            status = s
        if s != "ok":
            reasons.append(why)
            if adv and ADVICE[adv] not in advice:
                advice.append(ADVICE[adv])

    weights = sol.extras.get("row_weights") or {}
    # a filter's innovations are tested normalized by their own covariance A P A^T + I
    residuals = sol.extras.get("normalized_innovations") or sol.residuals
    for kind, r in residuals.items():
        test, _ = _family_test(r, weights.get(kind))
        test["status"] = _severity(test)
        tests[kind] = test
        worse(test["status"], f"{kind}: chi2/dof {test['normalized']:.3g} over {test['dof']} "
              f"components (p = 1e{test['log10_p']:.0f})", "outliers")
    if "chi2_motion" in sol.extras:   # (a filter has no process residuals)
        motion = _chi2_test(float(sol.extras["chi2_motion"]), max(p.n_epochs - 1, 1) * p.layout.n)
        motion["status"] = _severity(motion)
        tests["motion"] = motion
        worse(motion["status"], f"motion: chi2/dof {motion['normalized']:.3g}", "force")
    if not sol.extras.get("converged", True):
        worse("failed", "the solver did not converge", "converge")
    mirror = sol.extras.get("mirror_test")
    if mirror is not None:
        tests["mirror"] = mirror
        if mirror["status"] != "ok":
            better = mirror["chi2_mirrored"] < mirror["chi2"]
            worse("failed", f"the relative geometry mirrored through the first spacecraft "
                  f"{'fits the data better' if better else 'fits the data as well'} "
                  f"(chi-square {mirror['chi2_mirrored']:.6g} against {mirror['chi2']:.6g}, "
                  f"{mirror['largest_difference_m']:.3g} m apart): the links cannot tell the "
                  f"relative position from its mirror image", "mirror")
    if not (np.all(np.isfinite(sol.x_eci)) and np.all(np.isfinite(sol.P_block))):
        worse("failed", "non-finite states or covariances", None)
    return {"status": status, "reasons": reasons, "advice": advice, "tests": tests,
            "false_alarm_probability": FALSE_ALARM_PROBABILITY}


def relative_csv_text(sol, p) -> str:
    """``relative.csv`` (module docstring) of a formation's solution."""
    spherical = sol.extras.get("relative_parameterization") == "spherical"
    cols = ["epoch", "t_s", "reference", "spacecraft"]
    cols += [f"lvlh_{c}_{'mps' if c.startswith('v') else 'm'}" for c in _LVLH]
    cols += [f"lvlh_{c}_sigma_{'mps' if c.startswith('v') else 'm'}" for c in _LVLH]
    iu = np.triu_indices(6)
    cols += [f"lvlh_c{i + 1}{j + 1}" for i, j in zip(*iu)]
    cols += [f"body_{c}_m" for c in "xyz"] + [f"body_{c}_sigma_m" for c in "xyz"]
    if spherical:
        cols += ["range_m", "azimuth_rad", "elevation_rad", "range_sigma_m", "azimuth_sigma_rad",
                 "elevation_sigma_rad"]
    epochs = add_seconds(sol.epoch0, sol.t_s)
    R_ref = _reference_attitude(p, sol)
    lines = [",".join(cols)]
    states = spacecraft_states(sol, p.layout)
    for j in range(1, len(states)):
        rel, C, (J_c, J_d, P_joint) = relative_rows(sol, p, j)
        sig = np.sqrt(np.diagonal(C, axis1=1, axis2=2))
        ok = np.all(np.isfinite(R_ref), axis=(1, 2))
        body = np.full((len(rel), 3), np.nan)
        body_sig = np.full((len(rel), 3), np.nan)
        if ok.any():
            rb, Jb_c, Jb_d = relative_state_body(states[0][0][ok], states[j][0][ok], R_ref[ok])[:3]
            body[ok] = rb[:, :3]
            Cb = relative_covariance(Jb_c[:, :3], Jb_d[:, :3], P_joint[ok])
            body_sig[ok] = np.sqrt(np.diagonal(Cb, axis1=1, axis2=2))
        if spherical:
            sph, Cs = spherical_position(rel[:, :3], C[:, :3, :3])
            sph_sig = np.sqrt(np.diagonal(Cs, axis1=1, axis2=2))
        for k in range(len(rel)):
            vals = [*rel[k], *sig[k], *C[k][iu], *body[k], *body_sig[k]]
            if spherical:
                vals += [*sph[k], *sph_sig[k]]
            lines.append(",".join([format_utc(epochs[k]), f"{sol.t_s[k]:.6f}", p.spacecraft[0],
                                   p.spacecraft[j]] + ["" if not np.isfinite(v) else f"{v:.9g}"
                                                       for v in vals]))
    return "\n".join(lines) + "\n"
