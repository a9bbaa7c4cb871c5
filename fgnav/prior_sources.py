"""A prior from the files a spacecraft's user has: an OMM or a TLE (SGP4 mean elements), an
OPM (a state vector) or an OEM (an ephemeris), turned into the a-priori state at the log's
first epoch and the ``prior_position`` / ``prior_velocity`` rows a log would carry
(``fgnav smooth LOG --prior FILE``).

- **OMM, TLE**: SGP4 (the ``sgp4`` package, Vallado et al. 2006's code) at the log's first
  epoch, in TEME, rotated to EME2000 by the IAU 1976 precession and IAU 1980 nutation:
  ``r_EME2000 = (N P)^T R3(-Eq) r_TEME`` with the equation of the equinoxes
  ``Eq = dpsi cos(eps_A)`` without its kinematic terms (Vallado et al. 2006, sec. "TEME";
  Vallado 2013, Example 3-15, reproduced to its printed 0.1 m in the tests); the same
  rotation for the velocity (the frame's own rotation, ~1e-11 rad/s, neglected as there).
- **OPM**: its state (TEME rotated as above), propagated to the log's first epoch by the
  independent integrator (:func:`fgnav.orbit.integrate_truth`, J2 + Sun and Moon).
- **OEM**: its state at the log's first epoch, interpolated as ``--truth`` is
  (:func:`fgnav.orbit.truth_at`: cubic Hermite in position and velocity); the OEM must
  cover that epoch.

Covariance: the file's where it has one (an OMM's or OPM's at its epoch, propagated with
the integrator's state transition matrix by central differences, ``P1 = Phi P0 Phi^T``;
an OEM's block nearest the log's first epoch, as given: the standard defines no
interpolation of covariances, and over an ephemeris step they change little), an RTN covariance rotated
to EME2000 with the state's RTN axes. Prior rows carry one sigma per row, so the covariance
enters as its covering sphere (:func:`fgnav.measurements.covering_sigmas`). Without one, the
default of the source (:data:`DEFAULT_SIGMAS`). ``--prior-sigma-km`` / ``--prior-sigma-mps``
replace either.
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass, replace

import numpy as np

from fgnav.errors import UserError
from fgnav.io.oem import read_oem
from fgnav.io.omm import MeanElements, read_omm
from fgnav.io.opm import OPM_FRAMES, OpmData, read_opm
from fgnav.io.tle import looks_like_tle, read_tle
from fgnav.measurements import covering_sigmas
from fgnav.models.registry import PRIOR_POSITION, PRIOR_VELOCITY
from fgnav.frames import rtn_frame
from fgnav.orbit import integrate_truth, truth_at
from fgnav.time import add_seconds, format_utc, j2000_seconds, seconds_since

__all__ = ["PriorState", "DEFAULT_SIGMAS", "SOURCES", "prior_from_file", "source_kind",
           "teme_to_eme2000_matrix", "sgp4_teme", "sgp4_eme2000", "propagate_state",
           "with_prior_rows", "prior_for_log", "check_no_prior_rows"]

SOURCES = ("omm", "tle", "opm", "oem")

DEFAULT_SIGMAS = {"omm": (10e3, 10.0), "tle": (10e3, 10.0), "opm": (1e3, 1.0),
                  "oem": (1e3, 1.0)}
"""1-sigma (position m, velocity m/s) of a prior whose file has no covariance. SGP4 element
sets (OMM, TLE) state no accuracy: SGP4's own theory error against a numerical orbit
through the same elements is 68 m to 1.24 km over 7 h on 28 GLONASS sets (measured in
tests/test_prior_sources.py) and a set's fit error grows by kilometres per day of age, so 10 km and 10 m/s (the velocity of 10 km of along-track error in LEO);
an OPM or OEM comes from an orbit determination but carries no age or quality, so 1 km and
1 m/s. All are loose against what the measurements give: a prior only starts the solvers
and weighs little against a pass of data."""

INERTIAL_FRAMES = tuple(f for f in OPM_FRAMES if f != "TEME")
"""Covariance frames taken as EME2000 (one inertial frame in fgnav)."""

_JD_J2000 = 2451545.0
_SGP4_EPOCH0 = _dt.datetime(1949, 12, 31)


@dataclass(frozen=True)
class PriorState:
    """A prior at ``epoch`` (fgnav's time scale): ``x_eci`` (6,) m, m/s, EME2000 about the
    log's centre; ``P_eci`` the file's covariance there (6, 6) SI or None; the rows' 1-sigma
    ``sigma_position_m``, ``sigma_velocity_mps`` and where they came from (``sigma_from``:
    ``file``, ``default`` or ``option``); ``source`` (one of :data:`SOURCES`), ``path``,
    ``file_epoch`` (the file's epoch; ``age_s`` = epoch - file_epoch)."""

    source: str
    path: str
    epoch: np.datetime64
    x_eci: np.ndarray
    P_eci: np.ndarray | None
    sigma_position_m: float
    sigma_velocity_mps: float
    sigma_from: str
    file_epoch: np.datetime64
    name: str = ""

    @property
    def age_s(self) -> float:
        return float(seconds_since(np.array([self.epoch]), self.file_epoch)[0])

    def summary(self) -> dict:
        """summary.json's ``prior_file``."""
        return {"path": self.path, "source": self.source, "object": self.name,
                "file_epoch": format_utc(self.file_epoch), "epoch": format_utc(self.epoch),
                "age_s": self.age_s, "sigma_position_m": self.sigma_position_m,
                "sigma_velocity_mps": self.sigma_velocity_mps, "sigma_from": self.sigma_from}


def source_kind(path) -> str:
    """Which of :data:`SOURCES` a file is, from its content: the CCSDS version keyword of
    its first line (or the XML root ``omm``), else two TLE lines."""
    try:
        with open(path, "rb") as f:
            head = f.read(4096).decode("utf-8", errors="replace").lstrip("\ufeff")
    except OSError as exc:
        raise UserError(f"--prior {path}: cannot read: {exc.strerror or exc}") from None
    first = head.lstrip().split("\n", 1)[0].strip()
    for key, kind in (("CCSDS_OMM_VERS", "omm"), ("CCSDS_OPM_VERS", "opm"),
                      ("CCSDS_OEM_VERS", "oem")):
        if first.startswith(key):
            return kind
    if first.startswith("<"):
        return "omm" if "<omm" in head else "xml"
    if looks_like_tle(head):
        return "tle"
    raise UserError(f"--prior {path}: expected an OMM (CCSDS KVN or XML), an OPM or an OEM "
                    f"(CCSDS KVN, first line CCSDS_OMM_VERS / CCSDS_OPM_VERS / CCSDS_OEM_VERS) "
                    f"or a TLE (two lines, '1 ...' and '2 ...'), found {first[:40]!r}")


def _tt_jd(t64) -> tuple[float, float]:
    """(2451545.0, days since J2000 TT) of one epoch: erfa's two-part TT Julian date."""
    return _JD_J2000, float(j2000_seconds(np.array([t64], dtype="datetime64[ns]"))[0]) / 86400.0


def teme_to_eme2000_matrix(t64) -> np.ndarray:
    """``R`` (3, 3) with ``r_EME2000 = R r_TEME`` at epoch ``t64``: ``(N P)^T R3(-Eq)``, IAU
    1976/1980 (``erfa.pnm80``), ``Eq = dpsi cos(eps_A)`` without the kinematic terms
    (Vallado et al. 2006; Vallado 2013, Example 3-15)."""
    import erfa   # noqa: heavy third-party, loaded when a prior is converted

    d1, d2 = _tt_jd(t64)
    dpsi, _ = erfa.nut80(d1, d2)
    eq = dpsi * math.cos(erfa.obl80(d1, d2))
    return erfa.pnm80(d1, d2).T @ erfa.rz(-eq, np.eye(3))


def _satrec(el: MeanElements):
    """The ``sgp4`` package's satellite record of mean elements (WGS-72, 'i' mode: as its
    ``omm.initialize`` and ``twoline2rv`` do)."""
    from sgp4.api import WGS72, Satrec   # noqa: third-party, loaded with a prior

    label = _dt.datetime.strptime(format_utc(el.epoch, "us"), "%Y-%m-%dT%H:%M:%S.%fZ")
    epoch_days = (label - _SGP4_EPOCH0).total_seconds() / 86400.0
    sat = Satrec()
    deg = math.pi / 180.0
    sat.sgp4init(WGS72, "i", el.satnum if el.satnum < 100000 else 0, epoch_days, el.bstar,
                 el.ndot / (1036800.0 / math.pi), el.nddot / (2985984000.0 / 2.0 / math.pi),
                 el.e, el.argp_deg * deg, el.i_deg * deg, el.M_deg * deg,
                 el.n_rev_day / 720.0 * math.pi, el.raan_deg * deg)
    return sat


def _sgp4_error(el: MeanElements, code: int) -> UserError:
    from sgp4.api import SGP4_ERRORS

    return UserError(f"--prior {el.path}, line {el.line}: SGP4 cannot propagate these "
                     f"elements: {SGP4_ERRORS.get(code, f'error {code}')}")


def sgp4_teme(el: MeanElements, t64) -> np.ndarray:
    """SGP4 states (N, 6), m, m/s, TEME of each epoch, at the epochs ``t64`` (N,)."""
    sat = _satrec(el)
    if sat.error:
        raise _sgp4_error(el, sat.error)
    dt_s = np.atleast_1d(seconds_since(np.atleast_1d(t64), el.epoch)).astype(float)
    out = np.empty((len(dt_s), 6))
    for i, s in enumerate(dt_s):
        code, r, v = sat.sgp4_tsince(s / 60.0)
        if code:
            raise _sgp4_error(el, code)
        out[i] = np.r_[r, v] * 1e3
    return out


def sgp4_eme2000(el: MeanElements, t64) -> np.ndarray:
    """:func:`sgp4_teme` rotated to EME2000 at each epoch (N, 6)."""
    t64 = np.atleast_1d(np.asarray(t64, dtype="datetime64[ns]"))
    x = sgp4_teme(el, t64)
    for i, t in enumerate(t64):
        R = teme_to_eme2000_matrix(t)
        x[i] = np.r_[R @ x[i, :3], R @ x[i, 3:]]
    return x


def propagate_state(x0, t0, t1, centre: str = "earth", P0=None):
    """The state ``x0`` (6,) at ``t0`` carried to ``t1`` by the independent integrator (J2 +
    Sun and Moon; the heliocentric model about the Sun), and ``P0`` with it through the
    state transition matrix by central differences (steps 1 m, 1 mm/s): ``(x1, P1)``."""
    dt = float(seconds_since(np.array([t1]), t0)[0])
    if dt == 0.0:
        return np.asarray(x0, float).copy(), None if P0 is None else np.array(P0, float)
    kw = {"third_body": True, "t0_j2000_s": float(j2000_seconds(np.array([t0]))[0]),
          "centre": centre}
    x1 = integrate_truth(np.asarray(x0, float), np.array([dt]), **kw)[0]
    if P0 is None:
        return x1, None
    Phi = np.empty((6, 6))
    for j, h in enumerate((1.0, 1.0, 1.0, 1e-3, 1e-3, 1e-3)):
        d = np.zeros(6)
        d[j] = h
        xp = integrate_truth(x0 + d, np.array([dt]), **kw)[0]
        xm = integrate_truth(x0 - d, np.array([dt]), **kw)[0]
        Phi[:, j] = (xp - xm) / (2 * h)
    return x1, Phi @ P0 @ Phi.T


def _rtn_to_inertial(P_rtn, x) -> np.ndarray:
    """An RTN covariance (6, 6) as an inertial one: ``A P A^T``, ``A = blkdiag(R, R)`` with
    ``R = rtn_frame(x)^T`` (columns R, T, N of the state ``x``; the rotating frame's rate
    neglected)."""
    R = rtn_frame(x).T
    A = np.zeros((6, 6))
    A[:3, :3] = A[3:, 3:] = R
    return A @ P_rtn @ A.T


def _from_elements(el: MeanElements, t_log):
    x = sgp4_eme2000(el, [t_log])[0]
    P = None
    if el.P_teme is not None:   # the covariance of the SGP4 state at the file's epoch
        R = teme_to_eme2000_matrix(el.epoch)
        A = np.zeros((6, 6))
        A[:3, :3] = A[3:, 3:] = R
        x0 = sgp4_eme2000(el, [el.epoch])[0]
        _, P = propagate_state(x0, el.epoch, t_log, P0=A @ el.P_teme @ A.T)
    return x, P, el.epoch, el.name


def _from_opm(o: OpmData, t_log, centre):
    if o.centre != centre:
        raise UserError(f"--prior {o.path}: CENTER_NAME = {o.centre.upper()}, but the log's "
                        f"positions are about the {centre} (its '# centre:' line)")
    x0 = o.x.copy()
    P0 = o.P
    if P0 is not None and o.cov_frame == "RTN":
        P0 = _rtn_to_inertial(P0, x0)
    if o.frame == "TEME":
        R = teme_to_eme2000_matrix(o.epoch)
        A = np.zeros((6, 6))
        A[:3, :3] = A[3:, 3:] = R
        x0 = A @ x0
        P0 = None if P0 is None else (P0 if o.cov_frame == "RTN" else A @ P0 @ A.T)
    x, P = propagate_state(x0, o.epoch, t_log, centre, P0)
    return x, P, o.epoch, o.name


def _from_oem(path, t_log, centre):
    oem = read_oem(path)
    if str(oem.meta.get("CENTER_NAME", "EARTH")).lower() != centre:
        raise UserError(f"--prior {path}: CENTER_NAME = {oem.meta.get('CENTER_NAME')}, but the "
                        f"log's positions are about the {centre} (its '# centre:' line)")
    t = float(seconds_since(np.array([t_log]), oem.epoch0)[0])
    if not oem.t_s[0] - 1e-6 <= t <= oem.t_s[-1] + 1e-6:
        raise UserError(f"--prior {path}: the ephemeris ({format_utc(oem.epoch0)} + "
                        f"{oem.t_s[0]:.1f}..{oem.t_s[-1]:.1f} s) does not cover the log's first "
                        f"epoch {format_utc(t_log)}")
    t_eph, x_eph = np.asarray(oem.t_s, float), np.asarray(oem.x_eci, float)
    x = truth_at(t_eph, x_eph, np.array([t]))[0]
    P = None
    if oem.cov_P is not None and len(oem.cov_P):   # every block, at any epoch
        j = int(np.argmin(np.abs(np.asarray(oem.cov_t_s, float) - t)))
        P = np.asarray(oem.cov_P[j], float)
        frame = (oem.cov_frame[j] if oem.cov_frame else None) or oem.meta.get("REF_FRAME")
        if str(frame).upper() in ("RTN", "RSW"):
            t_cov = float(np.clip(oem.cov_t_s[j], t_eph[0], t_eph[-1]))
            P = _rtn_to_inertial(P, truth_at(t_eph, x_eph, np.array([t_cov]))[0])
        elif str(frame).upper() not in INERTIAL_FRAMES:
            raise UserError(f"--prior {path}: a covariance in COV_REF_FRAME = {frame}; fgnav "
                            f"reads {', '.join(INERTIAL_FRAMES)}, RTN or RSW")
    return x, P, t_log, str(oem.meta.get("OBJECT_NAME", ""))


def prior_from_file(path, t_log, centre: str = "earth", sigma_position_m=None,
                    sigma_velocity_mps=None) -> PriorState:
    """The prior of the file ``path`` at the log's first epoch ``t_log`` (see the module
    docstring); ``sigma_*`` (SI) replace the file's or the default 1-sigma."""
    kind = source_kind(path)
    if kind == "xml":
        raise UserError(f"--prior {path}: an XML file that is not an OMM (the OPM and OEM are "
                        "read in KVN form)")
    if kind in ("omm", "tle") and centre != "earth":
        raise UserError(f"--prior {path}: SGP4 elements are geocentric, but the log's positions "
                        f"are about the {centre}")
    if kind in ("omm", "tle"):
        x, P, t_file, name = _from_elements(read_omm(path) if kind == "omm" else read_tle(path),
                                            t_log)
    elif kind == "opm":
        x, P, t_file, name = _from_opm(read_opm(path), t_log, centre)
    else:
        x, P, t_file, name = _from_oem(path, t_log, centre)
    s_r, s_v = covering_sigmas(P) if P is not None else DEFAULT_SIGMAS[kind]
    sigma_from = "file" if P is not None else "default"
    if sigma_position_m is not None or sigma_velocity_mps is not None:
        sigma_from = "option"
        s_r = s_r if sigma_position_m is None else float(sigma_position_m)
        s_v = s_v if sigma_velocity_mps is None else float(sigma_velocity_mps)
    return PriorState(kind, str(path), np.datetime64(t_log, "ns"), x, P, float(s_r),
                      float(s_v), sigma_from, np.datetime64(t_file, "ns"), name)


def check_no_prior_rows(log, path) -> None:
    """``UserError`` naming the log, its first prior row's line and the file ``path`` if the
    log has prior rows of its own."""
    own = np.flatnonzero(np.isin(np.asarray(log.kind), (PRIOR_POSITION.kind,
                                                        PRIOR_VELOCITY.kind)))
    if len(own):
        line = int(np.asarray(log.line)[own[0]]) if log.line is not None else 0
        raise UserError(f"--prior {path}: the log {log.path} has prior rows of its own "
                        f"({len(own)}, the first on line {line}); give one prior: remove "
                        f"the rows or leave out --prior")


def with_prior_rows(log, prior: PriorState):
    """``log`` with the prior's ``prior_position`` and ``prior_velocity`` rows at its first
    epoch (placed first, line 0: not from the log's file). A log that has prior rows of its
    own is refused, naming both (two priors on one state would count its information twice)."""
    check_no_prior_rows(log, prior.path)
    kinds = np.asarray(log.kind)
    t0 = float(np.min(log.t_s))
    n = len(log.t_s)
    line = np.zeros(n + 2, dtype=np.asarray(log.line).dtype if log.line is not None else int)
    if log.line is not None:
        line[2:] = log.line
    return replace(
        log, t_s=np.r_[t0, t0, np.asarray(log.t_s, float)],
        kind=np.r_[np.array([PRIOR_POSITION.kind, PRIOR_VELOCITY.kind]), kinds],
        xyz=np.vstack([prior.x_eci[:3], prior.x_eci[3:], np.asarray(log.xyz, float)]),
        sigma=np.r_[prior.sigma_position_m, prior.sigma_velocity_mps,
                    np.asarray(log.sigma, float)],
        extra={k: np.r_[np.full(2, np.nan), np.asarray(v, float)] for k, v in log.extra.items()},
        line=line, warnings=[*log.warnings, f"prior from {prior.source.upper()} {prior.path} "
                             f"({prior.sigma_from} sigmas {prior.sigma_position_m:.4g} m, "
                             f"{prior.sigma_velocity_mps:.4g} m/s; the file's epoch "
                             f"{prior.age_s / 3600.0:.2f} h before the log's first)"])


def prior_for_log(log, path, sigma_position_m=None, sigma_velocity_mps=None):
    """``(log with the prior rows of the file path, PriorState)``: :func:`prior_from_file` at
    the log's first epoch and about its centre, then :func:`with_prior_rows`. A log of several
    spacecraft is refused (one file, one orbit)."""
    if getattr(log, "n_spacecraft", 1) > 1:
        raise UserError(f"--prior {path}: one orbit's prior, but the log {log.path} has "
                        f"{log.n_spacecraft} spacecraft")
    check_no_prior_rows(log, path)
    t_log = add_seconds(log.epoch0, np.array([float(np.min(log.t_s))]))[0]
    prior = prior_from_file(path, t_log, getattr(log, "centre", "earth"), sigma_position_m,
                            sigma_velocity_mps)
    return with_prior_rows(log, prior), prior
