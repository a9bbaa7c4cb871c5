"""Attitude estimates as a documented CSV (the attitude counterpart of the OEM output).

Columns (one row per epoch, comments start with ``#``)::

    epoch,qw,qx,qy,qz,sigma_x_rad,sigma_y_rad,sigma_z_rad,cov_xy_rad2,cov_xz_rad2,cov_yz_rad2

``epoch``: ISO-8601 UTC ending in ``Z``. ``q``: unit quaternion of ``R_eci_from_body``,
scalar first (w, x, y, z), ``w >= 0``. The covariance is that of the right perturbation
``R = R_est Exp(omega)`` (body-frame small angles, rad): standard deviations per body axis
and the off-diagonal covariances (rad^2).
"""

from __future__ import annotations

import math

import numpy as np

from fgnav.errors import InputFormatError
from fgnav.io.atomic import atomic_write_text
from fgnav.io.text import csv_records, finite_number, read_utf8_text
from fgnav.time import format_utc, parse_utc

COLUMNS = ("epoch", "qw", "qx", "qy", "qz", "sigma_x_rad", "sigma_y_rad", "sigma_z_rad",
           "cov_xy_rad2", "cov_xz_rad2", "cov_yz_rad2")


def quaternion_wxyz(R: np.ndarray) -> np.ndarray:
    """Rotation matrix (3,3) -> unit quaternion (w, x, y, z) with w >= 0."""
    import gtsam

    q = gtsam.Rot3(np.asarray(R, dtype=float)).toQuaternion()
    out = np.array([q.w(), q.x(), q.y(), q.z()])
    return out if out[0] >= 0 else -out


def write_attitude_csv(path, epochs, R_eci_from_body, P_rad2, comments=()) -> None:
    """Write attitude estimates: epochs (datetime64), (N,3,3) rotations, (N,3,3) covariances."""
    lines = [f"# {c}" for c in comments] + [",".join(COLUMNS)]
    for t, R, P in zip(epochs, R_eci_from_body, P_rad2):
        q = quaternion_wxyz(R)
        s = np.sqrt(np.diag(P))
        lines.append(",".join([format_utc(t)] + [repr(float(v)) for v in
                                                 (*q, *s, P[0, 1], P[0, 2], P[1, 2])]))
    atomic_write_text(path, "\n".join(lines) + "\n")


def read_attitude_csv(path):
    """Read the CSV back: (epochs datetime64[ns] (N,), R (N,3,3), P (N,3,3)).

    UTF-8 (a byte-order mark is ignored); every error is an
    :class:`~fgnav.errors.InputFormatError` naming the line and the column.
    """
    import gtsam

    text = read_utf8_text(path, "an attitude CSV file")  # not UTF-8: the line and the byte
    epochs, Rs, Ps = [], [], []
    header = None
    for lineno, line, fields in csv_records(text):
        if header is None:
            if tuple(fields) != COLUMNS:
                raise InputFormatError(path, lineno, None, "header " + ",".join(COLUMNS), line)
            header = fields
            continue
        if len(fields) != len(COLUMNS):
            raise InputFormatError(path, lineno, None, f"{len(COLUMNS)} fields", f"{len(fields)}")
        try:
            t = parse_utc(fields[0])
        except ValueError as exc:
            raise InputFormatError(path, lineno, "epoch", f"an ISO-8601 UTC epoch ({exc})",
                                   fields[0]) from None
        v = np.empty(len(COLUMNS) - 1)
        for j, (name, f) in enumerate(zip(COLUMNS[1:], fields[1:])):
            v[j] = finite_number(f)
            if not math.isfinite(v[j]) or (name.startswith("sigma") and v[j] < 0):
                raise InputFormatError(path, lineno, name, "a finite number" +
                                       (" >= 0" if name.startswith("sigma") else ""), f)
        qn = float(np.linalg.norm(v[:4]))
        if abs(qn - 1.0) > 1e-4:  # renormalized below
            raise InputFormatError(path, lineno, "qw", "a unit quaternion (w, x, y, z)",
                                   f"norm {qn:.9g}")
        q = v[:4] / qn
        s, c = v[4:7], v[7:]
        P = np.diag(s ** 2)
        P[0, 1] = P[1, 0] = c[0]
        P[0, 2] = P[2, 0] = c[1]
        P[1, 2] = P[2, 1] = c[2]
        epochs.append(t)
        Rs.append(gtsam.Rot3.Quaternion(*q).matrix())
        Ps.append(P)
    if header is None or not epochs:
        raise InputFormatError(path, None, None, "the header " + ",".join(COLUMNS) +
                               " and at least one row", "no rows")
    return np.array(epochs, dtype="datetime64[ns]"), np.array(Rs), np.array(Ps)
