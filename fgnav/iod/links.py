"""The links of one epoch of a formation's log, and the relative position they fix alone.

Xing et al. (ST-3 Autonomous Formation Flyer pseudorange positioning) solve sat 2's position
in sat 1's body frame and the relative clock from the six pseudoranges of one epoch
(:mod:`fgnav.iod.single_epoch`). Here the epoch's rows are read from a measurement log
(format v1 with the ``spacecraft`` column, :mod:`fgnav.io.log_spacecraft`):

* the epoch's ``isl_pseudorange`` rows (six: sat 2's transmit antenna to sat 1's three
  receive antennas and back), between the log's first two spacecraft;
* their antennas' lever arms from the ``# antenna:`` declarations (an empty antenna is the
  centre of mass);
* the relative attitude ``M21 = R_body1_from_body2 = R1^T R2`` from the two spacecraft's
  ``attitude`` rows at that epoch (``R_eci_from_body`` as rotation vectors).

A row received by sat 1 from sat 2 is ``|r + M21 a_tx - a_rx| + c dt``, one received by sat 2
from sat 1 ``|r + M21 a_rx - a_tx| - c dt`` (Xing et al., eq. (1); ``c dt`` = c (dt_1 - dt_2),
the clock of the log's format). The study of one epoch's conditioning is
:mod:`fgnav.formation.logged`; the formation's start uses :func:`far_field_guess` and
:func:`logged_epoch` (:func:`fgnav.start.link_fixes`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from factors.geometry import so3_exp
from fgnav.errors import UserError
from fgnav.iod.single_epoch import LinkGeometry
from fgnav.io.log_csv import MeasurementLog
from fgnav.io.log_spacecraft import ISL_KINDS
from fgnav.models.registry import ATTITUDE
from fgnav.time import add_seconds, format_utc, parse_utc

__all__ = ["LoggedEpoch", "logged_epoch", "far_field_guess", "N_LINKS_LOGGED", "FAR_FIELD_RCOND"]

N_LINKS_LOGGED = 6
"""Rows the study needs at its epoch: Xing et al.'s six links."""
FAR_FIELD_RCOND = 1e-3
"""Singular values of the far-field system below this fraction of the largest are taken as
unobserved (:func:`far_field_guess`)."""


@dataclass
class LoggedEpoch:
    """One epoch's links, SI. ``rho_m``, ``sigma_m`` (L,), ``links`` the offsets and clock
    signs in the sat-1 body frame, ``M21`` (3, 3) sat-2 body -> sat-1 body, ``lines`` the
    rows' file lines, ``labels`` ``rx/rx_antenna <- tx/tx_antenna`` per row."""

    path: str
    epoch: np.datetime64
    ids: tuple
    rho_m: np.ndarray
    sigma_m: np.ndarray
    links: LinkGeometry
    M21: np.ndarray
    lines: np.ndarray
    labels: list = field(default_factory=list)
    face_m: np.ndarray | None = None
    """Sat 1's mean receive-antenna lever arm, body m (the side the partner is on)."""

    @property
    def epoch_utc(self) -> str:
        return format_utc(self.epoch)


def _name(vocab, code) -> str:
    return "" if np.isnan(code) else vocab[int(code)]


def logged_epoch(log: MeasurementLog, epoch: str | None = None) -> LoggedEpoch:
    """The links of one epoch of ``log`` (ISO-8601 UTC ``epoch``, default the first epoch
    with ``isl_pseudorange`` rows). A :class:`UserError` names the log, the epoch and what is
    missing: no such epoch, not six links between the first two spacecraft, a link in one
    direction only, an attitude row missing (or repeated) for either spacecraft."""
    path = log.path
    kind = np.asarray(log.kind).astype(str)
    isl = np.flatnonzero(kind == ISL_KINDS[0])
    if not isl.size:
        raise UserError(f"{path}: no {ISL_KINDS[0]} rows (the single-epoch study needs the "
                        f"{N_LINKS_LOGGED} inter-satellite pseudoranges of one epoch)")
    ns = add_seconds(log.epoch0, log.t_s).astype(np.int64)
    if epoch is None:
        t_ns = int(ns[isl[0]])
    else:
        try:
            t_ns = int(parse_utc(epoch).astype("datetime64[ns]").astype(np.int64))
        except ValueError as exc:
            raise UserError(f"--epoch {epoch!r}: expected an ISO-8601 UTC epoch "
                            f"YYYY-MM-DDTHH:MM:SS[.f]Z ({exc})") from None
    when = format_utc(np.datetime64(t_ns, "ns"))
    rows = isl[ns[isl] == t_ns]
    if len(log.spacecraft) < 2:
        raise UserError(f"{path}: one spacecraft; the study needs two (a 'spacecraft' column "
                        "and isl_pseudorange rows between them)")
    ids = log.spacecraft[:2]
    sc, tx = log.extra["spacecraft"], log.extra["tx_spacecraft"]
    if len(rows) != N_LINKS_LOGGED:
        span = (f"the log's {ISL_KINDS[0]} epochs run from "
                f"{format_utc(np.datetime64(int(ns[isl].min()), 'ns'))} to "
                f"{format_utc(np.datetime64(int(ns[isl].max()), 'ns'))}")
        raise UserError(f"{path}: epoch {when}: expected {N_LINKS_LOGGED} {ISL_KINDS[0]} rows "
                        f"(Xing et al.'s six links: three receive antennas on each spacecraft), "
                        f"found {len(rows)}" + (f" (lines {', '.join(str(int(log.line[i])) for i in rows)})"
                                                if len(rows) else f"; {span}"))
    pair = {0.0, 1.0}
    for i in rows:
        if {float(sc[i]), float(tx[i])} != pair:
            raise UserError(f"{path}, line {int(log.line[i])}: a link between "
                            f"{_name(log.spacecraft, sc[i])} and {_name(log.spacecraft, tx[i])}; "
                            f"the study takes the links between the first two spacecraft "
                            f"({ids[0]}, {ids[1]})")
    to1 = sc[rows] == 0.0
    if to1.all() or not to1.any():
        raise UserError(f"{path}: epoch {when}: every link is received by "
                        f"{ids[0] if to1.all() else ids[1]}; the range and the clock separate "
                        "only with links in both directions")
    R = {}
    att = np.flatnonzero((kind == ATTITUDE.kind) & (ns == t_ns))
    for k, name in enumerate(ids):
        mine = att[np.asarray(log.extra["spacecraft"])[att] == float(k)]
        if len(mine) != 1:
            raise UserError(f"{path}: epoch {when}: expected one attitude row of spacecraft "
                            f"{name} (M21 = R1^T R2 needs both attitudes), found {len(mine)}"
                            + (f" (lines {', '.join(str(int(log.line[i])) for i in mine)})"
                               if len(mine) else ""))
        R[k] = so3_exp(log.xyz[mine[0]])
    M21 = R[0].T @ R[1]
    d = np.empty((len(rows), 3))
    signs = np.where(to1, 1.0, -1.0)
    labels, face = [], []
    for n, i in enumerate(rows):
        rx_sc, tx_sc = int(sc[i]), int(tx[i])
        rx_ant = _name(log.antenna_names, log.extra["rx_antenna"][i])
        tx_ant = _name(log.antenna_names, log.extra["tx_antenna"][i])
        a_rx = log.antennas.get((ids[rx_sc], rx_ant), np.zeros(3)) if rx_ant else np.zeros(3)
        a_tx = log.antennas.get((ids[tx_sc], tx_ant), np.zeros(3)) if tx_ant else np.zeros(3)
        # range vector in the sat-1 body frame: r + M21 a_(sat 2) - a_(sat 1)
        d[n] = (M21 @ a_tx - a_rx) if rx_sc == 0 else (M21 @ a_rx - a_tx)
        if rx_sc == 0:
            face.append(a_rx)
        labels.append(f"{ids[rx_sc]}/{rx_ant or 'CoM'} <- {ids[tx_sc]}/{tx_ant or 'CoM'}")
    return LoggedEpoch(path=str(path), epoch=np.datetime64(t_ns, "ns"), ids=ids,
                       rho_m=log.xyz[rows, 0].copy(), sigma_m=log.sigma[rows].copy(),
                       links=LinkGeometry(d, signs), M21=M21,
                       lines=np.asarray(log.line)[rows], labels=labels,
                       face_m=np.mean(face, axis=0))


def far_field_guess(rho_m, links: LinkGeometry, face_m=None) -> np.ndarray:
    """A first guess ``[r (3), c dt]`` (m) for Gauss–Newton from the ranges alone.

    For a separation far beyond the antenna offsets, ``|r + d_l| ~ R + u.d_l``, so
    ``rho_l = R + s_l c dt + u.d_l`` is linear in ``x = (R, c dt, u)``; with ``|u| = 1``.
    Antennas on one face of each spacecraft (Xing et al.'s) leave one direction of ``x``
    unobserved (the offsets have no component along the face normal, or a constant one): the
    ranges are then the same for sat 2 in front of the face and for its mirror image behind
    it. The guess is the least-squares ``x`` moved along that null direction to ``|u| = 1``,
    on the side of ``face_m`` (sat 1's mean receive-antenna lever arm: the antennas face the
    partner). Raises :class:`UserError` when the links leave more unobserved (no lever
    arms: the direction is not measured at all). A direction is unobserved when its singular
    value is below :data:`FAR_FIELD_RCOND` of the largest (offsets that differ by a
    relative attitude's micro-radians do not observe it)."""
    rho = np.asarray(rho_m, dtype=float)
    A = np.column_stack([np.ones(len(rho)), links.signs, links.offsets_m])
    _, sv, Vt = np.linalg.svd(A)
    rank = int(np.sum(sv > FAR_FIELD_RCOND * sv[0]))
    sol = np.linalg.lstsq(A, rho, rcond=FAR_FIELD_RCOND)[0]
    if rank == 5:
        u = sol[2:]
    elif rank == 4:
        v = Vt[-1]
        a, b, c = v[2:] @ v[2:], sol[2:] @ v[2:], sol[2:] @ sol[2:] - 1.0
        disc = b * b - a * c
        face = np.zeros(3) if face_m is None else np.asarray(face_m, dtype=float)
        if not (a > 0 and disc >= 0):
            raise UserError("the links do not fix sat 2's direction (the far-field solution "
                            "has no unit line of sight)")
        roots = [(-b + sg * np.sqrt(disc)) / a for sg in (1.0, -1.0)]
        front = [t for t in roots if (sol[2:] + t * v[2:]) @ face > 0]
        t = front[0] if front else roots[0]
        sol = sol + t * v
        u = sol[2:]
    else:
        raise UserError("the links do not fix sat 2's direction: the antenna offsets span "
                        f"{rank - 2} direction(s), three are needed (are the antennas "
                        "declared with their lever arms?)")
    n = np.linalg.norm(u)
    if not (n > 0 and sol[0] > 0):
        raise UserError("the links do not fix sat 2's position (no positive far-field range)")
    return np.r_[sol[0] * u / n, sol[1]]
