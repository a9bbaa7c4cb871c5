"""The attitude covariance per epoch as a documented CSV, ``attitude_covariance.csv``.

One row per epoch of the solution (the epochs of ``attitude.aem``); lines starting with ``#``
are comments::

    epoch,t_s,c11,c12,c13,c22,c23,c33

``epoch``: ISO-8601 UTC ending in ``Z``; ``t_s``: seconds from the pass epoch (the first
epoch of the log), 6 decimals; ``cij``: the upper triangle of the symmetric 3x3 covariance
(rad^2, 17 significant digits) of the attitude error as a right perturbation, i.e. of the
body-frame rotation vector ``dtheta`` in ``R_eci_from_body = R_est Exp(dtheta)`` (index 1, 2,
3 = body x, y, z): ``sqrt(c11)`` is the 1-sigma rotation about the body x axis. This is the
tangent space of GTSAM's ``Rot3.retract`` and so of its marginals (Sola, Deray & Atchuthan
2018, "A micro Lie theory for state estimation in robotics", right-plus operator and
covariances on the tangent space). An epoch whose covariance is not finite has empty
``cij`` cells (read back as NaN).
"""

from __future__ import annotations

import math

import numpy as np

from fgnav.errors import InputFormatError, UserError
from fgnav.io.atomic import atomic_write_text
from fgnav.io.text import csv_records, finite_number, read_utf8_text
from fgnav.time import add_seconds, format_utc, parse_utc, seconds_since

__all__ = ["COLUMNS", "write_attitude_covariance", "read_attitude_covariance"]

COLUMNS = ("epoch", "t_s", "c11", "c12", "c13", "c22", "c23", "c33")
_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
_T_TOL_S = 2e-6  # t_s is written with 6 decimals


def write_attitude_covariance(path, epoch0, t_s, P_rad2, comments=()) -> None:
    """Write ``attitude_covariance.csv`` (see the module docstring): ``epoch0`` datetime64 UTC,
    ``t_s`` (N,) s from it, ``P_rad2`` (N, 3, 3) body-frame attitude covariances (rad^2); the
    symmetric part (P + P^T)/2 is written."""
    t_s = np.asarray(t_s, dtype=float).reshape(-1)
    P = np.asarray(P_rad2, dtype=float)
    if P.shape != (len(t_s), 3, 3):
        raise UserError(f"write_attitude_covariance: need t_s (N,) and P_rad2 (N, 3, 3); found "
                        f"{t_s.shape}, {P.shape}")
    P = 0.5 * (P + np.swapaxes(P, 1, 2))
    epochs = add_seconds(epoch0, t_s)
    lines = [f"# {c}" for c in comments] + [",".join(COLUMNS)]
    for k in range(len(t_s)):
        cells = ([repr(float(P[k][i, j])) for i, j in _UPPER] if np.all(np.isfinite(P[k]))
                 else [""] * 6)
        lines.append(",".join([format_utc(epochs[k]), f"{t_s[k]:.6f}"] + cells))
    atomic_write_text(path, "\n".join(lines) + "\n")


def read_attitude_covariance(path):
    """Read ``attitude_covariance.csv`` back: ``(epochs datetime64[ns] (N,), t_s (N,),
    P (N, 3, 3) rad^2)``.

    Checked: the header, 8 fields per row, the epoch, epochs strictly increasing and ``t_s``
    advancing with them (within 2 µs), finite covariance cells (all six, or all empty for an
    epoch without one) forming a positive semi-definite matrix. Every error is an
    :class:`~fgnav.errors.InputFormatError` naming the file, the line and the column.
    """
    text = read_utf8_text(path, "an attitude covariance CSV file")
    header = None
    epochs, ts, Ps = [], [], []
    for lineno, line, fields in csv_records(text):
        if header is None:
            if tuple(fields) != COLUMNS:
                raise InputFormatError(path, lineno, None, "the header " + ",".join(COLUMNS),
                                       line)
            header = fields
            continue
        if len(fields) != len(COLUMNS):
            raise InputFormatError(path, lineno, None, f"{len(COLUMNS)} fields",
                                   f"{len(fields)} fields")
        try:
            t64 = parse_utc(fields[0])
        except ValueError as exc:
            raise InputFormatError(path, lineno, "epoch", f"an ISO-8601 UTC epoch ({exc})",
                                   fields[0]) from None
        t = finite_number(fields[1])
        if not math.isfinite(t):
            raise InputFormatError(path, lineno, "t_s", "a finite number of seconds", fields[1])
        if epochs:
            if t64 <= epochs[-1]:
                raise InputFormatError(path, lineno, "epoch", "epochs strictly increasing",
                                       fields[0])
            d_epoch = float(seconds_since(t64, epochs[-1]))
            if abs((t - ts[-1]) - d_epoch) > _T_TOL_S:
                raise InputFormatError(path, lineno, "t_s", f"t_s advancing with the epochs "
                                       f"({ts[-1] + d_epoch:.6f})", fields[1])
        P = np.full((3, 3), np.nan)
        if any(fields[2:]):
            for (i, j), name, f in zip(_UPPER, COLUMNS[2:], fields[2:]):
                v = finite_number(f)
                if not math.isfinite(v) or (i == j and v < 0):
                    raise InputFormatError(path, lineno, name, "a finite number" +
                                           (" >= 0 (a variance" if i == j else " (a covariance")
                                           + ", rad^2), or all six cells empty for an epoch "
                                           "without a covariance", f)
                P[i, j] = P[j, i] = v
            scale = max(float(np.trace(P)), 1e-300)
            if np.linalg.eigvalsh(P).min() < -1e-9 * scale:
                raise InputFormatError(path, lineno, "c11", "a positive semi-definite "
                                       "covariance", ",".join(fields[2:]))
        epochs.append(t64)
        ts.append(t)
        Ps.append(P)
    if header is None or not epochs:
        raise InputFormatError(path, None, None, "the header " + ",".join(COLUMNS) +
                               " and at least one row", "no rows")
    return np.array(epochs, dtype="datetime64[ns]"), np.array(ts), np.array(Ps)
