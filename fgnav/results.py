"""A solution directory for S >= 1 spacecraft: what ``fgnav smooth`` writes, and the relative
states of a formation's pairs that its files and summary.json carry.

One spacecraft (:func:`write_outputs`): ``trajectory.oem`` (states and marginal covariances),
``summary.json``, ``residuals.csv``; the online methods add ``online.oem`` and
``latency.csv``; estimated variables ``variables.csv`` (and with an attitude ``attitude.aem``,
``attitude_covariance.csv``).

Several spacecraft (the first is the reference):

* ``trajectory-<id>.oem`` per spacecraft; the online methods ``online-<id>.oem`` per
  spacecraft and ``latency.csv``;
* ``relative.csv``: every pair's relative state (:func:`pairs`: each further spacecraft
  relative to the reference, then each pair of further spacecraft), the deputy in the
  chief's LVLH frame (:mod:`fgnav.frames`) with its 1-sigmas and the full 6x6 covariance
  (upper triangle), and in the chief's body frame where the log gives its attitude at that
  epoch;
* ``variables.csv`` (the pairs' clocks, the carrier ambiguities), ``residuals.csv``;
* ``summary.json`` with ``spacecraft`` (per id: the one-spacecraft keys) and ``relative``
  (``position_rms_m``, ``velocity_rms_mps``, ``nees_mean`` against truth when given, the
  sigmas always), built by :func:`fgnav.pipeline.summarize`.

A formation's online states: ``Solution.online_x_eci``/``online_P_eci`` are the reference's
(as ``x_eci``/``P_eci`` are), ``extras["online_variables"]`` holds each further spacecraft's
``(x (N, 6), P (N, 6, 6))`` under its orbit variable's name (as ``Solution.variables`` holds
its final states).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from factors.geometry import so3_exp
from factors.pseudorange import cartesian_to_spherical, spherical_to_cartesian
from fgnav.frames import relative_covariance, relative_state_body, relative_state_lvlh
from fgnav.io.aem import write_aem
from fgnav.io.atomic import atomic_write_text, atomic_writer
from fgnav.io.attitude_covariance import write_attitude_covariance
from fgnav.io.number_text import render_rows
from fgnav.errors import UserError
from fgnav.io.oem import oem_frame, read_oem, write_oem
from fgnav.io.outputs import check_readable_file, commit_outputs, staged
from fgnav.io.summary import write_summary
from fgnav.measurements import Pass, spacecraft_states
from fgnav.models.model import COLUMN_PREFIX
from fgnav.models.registry import ATTITUDE, ATTITUDE_VARIABLE, variable
from fgnav.solution import Solution
from fgnav.time import add_seconds, format_utc, seconds_since

__all__ = ["read_truth", "read_formation_truth", "write_outputs", "write_variables_csv", "write_attitude_outputs",
           "write_residuals_csv", "residual_times", "pairs", "relative_rows",
           "relative_csv_text", "truth_path_of", "sigma_rms", "spherical_position",
           "spherical_position_nees", "spherical_summary", "online_states"]

_LVLH = ("x", "y", "z", "vx", "vy", "vz")


# ----------------------------------------------------------------- relative states (S > 1)

def truth_path_of(truth: str | Path, spacecraft_id: str) -> Path:
    """``truth-<id>.oem`` in the directory ``truth`` (or beside the file ``truth``)."""
    d = Path(truth)
    return (d if d.is_dir() else d.parent) / f"truth-{spacecraft_id}.oem"


def read_truth(path: str | Path, p: Pass, centre: str = "earth") -> tuple[np.ndarray, np.ndarray]:
    """A truth OEM as ``(t_s, x_eci)`` on the pass's time axis (s from ``p.epoch0``, SI),
    validated before any solving: readable, finite states, epochs covering the pass, about
    the log's ``centre``."""
    check_readable_file(path, "--truth")
    oem = read_oem(path)
    if str(oem.meta.get("CENTER_NAME", "EARTH")).lower() != centre:
        raise UserError(f"--truth {path}: CENTER_NAME = {oem.meta.get('CENTER_NAME')}, but the "
                        f"log's positions are about the {centre} (its '# centre:' line)")
    t_truth = np.asarray(seconds_since(np.asarray(oem.epoch0 + (oem.t_s * 1e9).astype(
        "timedelta64[ns]")), p.epoch0), dtype=float)
    x = np.asarray(oem.x_eci, dtype=float)
    if len(t_truth) == 0 or not np.all(np.isfinite(x)):
        raise UserError(f"--truth {path}: expected finite states, found "
                        f"{'none' if len(t_truth) == 0 else 'NaN or infinite values'}")
    if t_truth[0] > p.t_s[0] + 1e-6 or t_truth[-1] < p.t_s[-1] - 1e-6:
        raise UserError(f"--truth {path}: the truth does not cover the log's epochs "
                        f"({t_truth[0]:.1f}..{t_truth[-1]:.1f} s vs {p.t_s[0]:.1f}.."
                        f"{p.t_s[-1]:.1f} s from {p.epoch0}Z)")
    return t_truth, x


def read_formation_truth(truth: str | Path, p: Pass) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each spacecraft's truth ``(t_s, x_eci)`` from ``truth-<id>.oem`` (``fgnav simulate``
    writes them; :func:`truth_path_of`), checked against the pass's
    epochs before any solving."""
    out = []
    for sc in p.spacecraft:
        path = truth_path_of(truth, sc)
        if not path.exists():
            raise UserError(f"--truth {truth}: expected {path.name} (the truth of spacecraft "
                            f"'{sc}') in {path.parent}")
        out.append(read_truth(path, p, p.centre))
    return out


def pairs(n_spacecraft: int) -> list[tuple[int, int]]:
    """The (chief, deputy) index pairs whose relative states the outputs carry: each further
    spacecraft relative to the reference (0, j), then every pair (i, j), 1 <= i < j, of the
    further ones (a two-spacecraft formation: [(0, 1)])."""
    return ([(0, j) for j in range(1, n_spacecraft)]
            + [(i, j) for i in range(1, n_spacecraft) for j in range(i + 1, n_spacecraft)])


def relative_rows(sol, p, s: int, c: int = 0):
    """Spacecraft ``s``'s state relative to spacecraft ``c`` (default the first): LVLH state
    (N, 6) and covariance (N, 6, 6) from the joint marginals (cross-covariances included),
    and ``(J_c, J_s, P_joint)``."""
    lay = p.layout
    states = spacecraft_states(sol, lay)
    xc, xd = states[c][0], states[s][0]
    rel, J_c, J_d = relative_state_lvlh(xc, xd)
    sl_c, sl_d = lay.slices[lay.orbits[c].name], lay.slices[lay.orbits[s].name]
    idx = np.r_[np.arange(sl_c.start, sl_c.stop), np.arange(sl_d.start, sl_d.stop)]
    P_joint = sol.P_block[:, idx[:, None], idx[None, :]]
    return rel, relative_covariance(J_c, J_d, P_joint), (J_c, J_d, P_joint)


def _attitude_of(p, sol, c: int = 0):
    """R_eci_from_body (N, 3, 3) of spacecraft ``c`` at the solution's epochs where the log
    has an attitude row for it (NaN elsewhere)."""
    R = np.full((len(sol.t_s), 3, 3), np.nan)
    fam = p.deferred.get(ATTITUDE.kind)
    if fam is not None:
        own = np.asarray(fam.values[COLUMN_PREFIX + "orbit"]) == c
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
    s = cartesian_to_spherical(r_lvlh)
    J = np.linalg.inv(spherical_to_cartesian(s)[1])
    return s, np.einsum("kij,kjl,kml->kim", J, C_lvlh, J)


def _spherical_error(s_est, r_true):
    """``s_est`` (N, 3: range, azimuth, elevation) minus the spherical coordinates of the
    true positions ``r_true`` (N, 3), the azimuth difference wrapped to [-pi, pi)."""
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


def relative_csv_text(sol, p) -> str:
    """``relative.csv`` (module docstring) of a formation's solution: one block of rows per
    pair of :func:`pairs` (``reference`` the chief, ``spacecraft`` the deputy)."""
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
    lines = [",".join(cols)]
    states = spacecraft_states(sol, p.layout)
    for c, j in pairs(len(states)):
        R_c = _attitude_of(p, sol, c)
        rel, C, (J_c, J_d, P_joint) = relative_rows(sol, p, j, c)
        sig = np.sqrt(np.diagonal(C, axis1=1, axis2=2))
        ok = np.all(np.isfinite(R_c), axis=(1, 2))
        body = np.full((len(rel), 3), np.nan)
        body_sig = np.full((len(rel), 3), np.nan)
        if ok.any():
            rb, Jb_c, Jb_d = relative_state_body(states[c][0][ok], states[j][0][ok], R_c[ok])[:3]
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
            lines.append(",".join([format_utc(epochs[k]), f"{sol.t_s[k]:.6f}", p.spacecraft[c],
                                   p.spacecraft[j]] + ["" if not np.isfinite(v) else f"{v:.9g}"
                                                       for v in vals]))
    return "\n".join(lines) + "\n"


def online_states(sol, p) -> list:
    """Each spacecraft's online states ``(x (N, 6), P (N, 6, 6))`` (module docstring), None
    for a spacecraft whose online states the solution does not carry; ``[]`` without any."""
    if sol.online_x_eci is None:
        return []
    more = sol.extras.get("online_variables") or {}
    out = [(sol.online_x_eci, sol.online_P_eci)]
    for v in p.layout.orbits[1:]:
        out.append(more.get(v.name))
    return out


# ----------------------------------------------------------------------------- the files

def residual_times(res, p: Pass) -> dict:
    """kind -> (M,) seconds from epoch0 of each row of ``solution.residuals``."""
    return {kind: p.t_s[p.families[kind].k] for kind in res.solution.residuals if kind in p.families}


def write_variables_csv(path: Path, sol: Solution, variables=None) -> None:
    """``variables.csv``: the estimated variables beside the orbit at every epoch, columns
    ``epoch,t_s`` then per component ``<component>`` and ``<component>_sigma`` (its marginal
    1-sigma), e.g. ``refraction_bias_m,refraction_bias_m_sigma``. ``variables``: the
    :class:`~fgnav.models.variables.Variable` of each name to write (default every one of
    ``sol.variables``, from the registry)."""
    cols, data = ["epoch", "t_s"], []
    for name, (x, P) in sol.variables.items():
        if variables is not None and name not in variables:
            continue
        v = variable(name) if variables is None else variables[name]
        sig = np.sqrt(np.diagonal(P, axis1=1, axis2=2))
        for i, c in enumerate(v.components):
            cols += [c, f"{c}_sigma"]
            data += [x[:, i], sig[:, i]]
    epochs = add_seconds(sol.epoch0, sol.t_s)
    lines = [",".join(cols)]
    for k in range(len(sol.t_s)):
        lines.append(",".join([format_utc(epochs[k]), f"{sol.t_s[k]:.6f}"]
                              + [f"{d[k]:.9g}" for d in data]))
    atomic_write_text(path, "\n".join(lines) + "\n")


def write_attitude_outputs(out: Path, sol: Solution) -> list[str]:
    """``attitude.aem`` (CCSDS AEM 2.0, the estimated R_eci_from_body as quaternions from
    EME2000 to SC_BODY_1, :mod:`fgnav.io.aem`) and ``attitude_covariance.csv`` (its 3x3
    body-frame covariance per epoch, :mod:`fgnav.io.attitude_covariance`) in ``out``."""
    w, P = sol.variables[ATTITUDE_VARIABLE.name]
    write_aem(out / "attitude.aem", sol.epoch0, sol.t_s, so3_exp(w),
              comments=(f"fgnav {sol.method} solution: attitude at every epoch",
                        "its 3x3 covariance (body frame, rad^2) is in attitude_covariance.csv"))
    write_attitude_covariance(out / "attitude_covariance.csv", sol.epoch0, sol.t_s, P,
                              comments=(f"fgnav {sol.method} solution: attitude covariance, "
                                        "right perturbation in the body frame, rad^2",))
    return ["attitude.aem", "attitude_covariance.csv"]


def write_residuals_csv(path: Path, residuals: dict, times: dict, chunk: int = 65536) -> None:
    """residuals.csv: one line ``t_s,kind,component,whitened`` per finite whitened residual
    component (``residuals``: kind -> (M, m); ``times``: kind -> (M,) s from the pass epoch),
    by kind, row and component. Streamed in chunks of rows: a 1,000,000-epoch pass would
    otherwise hold its ~2,000,000 lines as Python strings at once."""
    with atomic_writer(path, "wb") as f:
        f.write(b"t_s,kind,component,whitened\n")
        for kind, r in residuals.items():
            t = np.asarray(times[kind], dtype=float)
            middle = [f",{kind},{c}," for c in range(np.shape(r)[1])]
            for a in range(0, len(r), chunk):
                rc = np.asarray(r[a:a + chunk], dtype=float)
                i, j = np.nonzero(np.isfinite(rc))
                f.write(render_rows(["", (middle, j), "\n"],
                                    np.column_stack([t[a + i], rc[i, j]]), [("f", 6), ("g", 6)]))


def _write_trajectories(stage: Path, sol: Solution, p: Pass) -> list[str]:
    """The state files: ``trajectory.oem`` (+ ``online.oem``) of one spacecraft, or
    ``trajectory-<id>.oem`` (+ ``online-<id>.oem``) per spacecraft of a formation."""
    names = []
    online = online_states(sol, p) if sol.method != "ekf" else []
    frame = oem_frame(sol.extras.get("centre", p.centre))
    if len(p.spacecraft) > 1:
        for s, (sc, (x, P)) in enumerate(zip(p.spacecraft, spacecraft_states(sol, p.layout))):
            name = f"trajectory-{sc}.oem"
            write_oem(stage / name, sol.epoch0, sol.t_s, x, P,
                      comments=(f"fgnav {sol.method} solution of a formation: spacecraft {sc}",
                                "states and marginal covariances at every epoch"),
                      object_name=sc, **frame)
            names.append(name)
            if s < len(online) and online[s] is not None:
                name = f"online-{sc}.oem"
                write_oem(stage / name, sol.epoch0, sol.t_s, *online[s],
                          comments=(f"fgnav {sol.method}: spacecraft {sc}'s state at each epoch "
                                    "as estimated when it arrived",), object_name=sc, **frame)
                names.append(name)
        return names
    write_oem(stage / "trajectory.oem", sol.epoch0, sol.t_s, sol.x_eci, sol.P_eci,
              **frame, comments=(f"fgnav {sol.method} solution",
                                 "states and marginal covariances at every epoch"))
    names.append("trajectory.oem")
    if online:
        write_oem(stage / "online.oem", sol.epoch0, sol.t_s, sol.online_x_eci,
                  sol.online_P_eci, **frame,
                  comments=(f"fgnav {sol.method}: each epoch's state as estimated when "
                            "it arrived",))
        names.append("online.oem")
    return names


def write_outputs(out_dir: str | Path, res, p: Pass) -> list[Path]:
    """Write a solution directory (module docstring) for ``res`` (a
    :class:`fgnav.pipeline.SmoothResult`: its ``solution`` and ``summary``) of pass ``p``:
    trajectory.oem, summary.json, residuals.csv (+ online.oem, latency.csv; with an
    estimated attitude attitude.aem and attitude_covariance.csv); for a formation's pass
    trajectory-<id>.oem per spacecraft (+ online-<id>.oem), relative.csv and the clocks'
    and ambiguities' variables.csv instead.

    Nothing lost: every file is first written into a staging directory inside ``out_dir``
    and the set replaces the previous outputs only once all are complete (``os.replace``
    per file, microseconds apart). An error or interrupt before that leaves the previous
    outputs untouched and removes the staging directory.

    One set: files of ours from an earlier run that this one did not rewrite (online.oem
    and latency.csv of an online method, a report's plots) are removed, and so are staging
    folders left by a killed run (:mod:`fgnav.io.outputs`); other files are left alone.
    """
    formation = len(p.spacecraft) > 1
    with staged(out_dir) as (out, stage):
        sol = res.solution
        names = _write_trajectories(stage, sol, p)
        if formation:
            atomic_write_text(stage / "relative.csv", relative_csv_text(sol, p))
            names.append("relative.csv")
        write_residuals_csv(stage / "residuals.csv", sol.residuals, residual_times(res, p))
        names.append("residuals.csv")
        if sol.latency_s is not None:
            atomic_write_text(stage / "latency.csv", "t_s,latency_s\n" + "".join(
                f"{t:.6f},{lat:.9f}\n" for t, lat in zip(sol.t_s, sol.latency_s)))
            names.append("latency.csv")
        if formation:
            params = {v.name: v for v in p.layout.parameters}
            if params:   # the clocks and ambiguities
                write_variables_csv(stage / "variables.csv", sol, params)
                names.append("variables.csv")
        else:
            if sol.variables:
                write_variables_csv(stage / "variables.csv", sol)
                names.append("variables.csv")
            if ATTITUDE_VARIABLE.name in sol.variables:
                names += write_attitude_outputs(stage, sol)
        write_summary(stage / "summary.json", res.summary)
        names.append("summary.json")
        return commit_outputs(out, stage, names, "smooth", replaces=("smooth", "report"))

