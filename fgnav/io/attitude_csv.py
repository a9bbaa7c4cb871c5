"""Attitude estimates as a documented CSV (the attitude counterpart of the OEM output).

Columns (one row per epoch, comments start with ``#``)::

    epoch,qw,qx,qy,qz,sigma_x_rad,sigma_y_rad,sigma_z_rad,cov_xy_rad2,cov_xz_rad2,cov_yz_rad2

``epoch``: ISO-8601 UTC ending in ``Z``. ``q``: unit quaternion of ``R_eci_from_body``,
scalar first (w, x, y, z), ``w >= 0``. The covariance is that of the right perturbation
``R = R_est Exp(omega)`` (body-frame small angles, rad): standard deviations per body axis
and the off-diagonal covariances (rad^2).
"""

from __future__ import annotations

import numpy as np

from fgnav.errors import InputFormatError
from fgnav.io.atomic import atomic_write_text
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
    """Read the CSV back: (epochs datetime64[ns] (N,), R (N,3,3), P (N,3,3))."""
    import gtsam

    epochs, Rs, Ps = [], [], []
    header = None
    with open(path, encoding="utf-8") as f:
        for lineno, line in enumerate(f, 1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            fields = line.split(",")
            if header is None:
                if tuple(fields) != COLUMNS:
                    raise InputFormatError(path, lineno, None, "header " + ",".join(COLUMNS), line)
                header = fields
                continue
            if len(fields) != len(COLUMNS):
                raise InputFormatError(path, lineno, None, f"{len(COLUMNS)} fields", line)
            try:
                t = parse_utc(fields[0])
                v = np.array([float(x) for x in fields[1:]])
            except ValueError as exc:
                raise InputFormatError(path, lineno, None, f"an epoch and numbers ({exc})", line) from None
            q = v[:4] / np.linalg.norm(v[:4])
            s, c = v[4:7], v[7:]
            P = np.diag(s ** 2)
            P[0, 1] = P[1, 0] = c[0]
            P[0, 2] = P[2, 0] = c[1]
            P[1, 2] = P[2, 1] = c[2]
            epochs.append(t)
            Rs.append(gtsam.Rot3.Quaternion(*q).matrix())
            Ps.append(P)
    return np.array(epochs, dtype="datetime64[ns]"), np.array(Rs), np.array(Ps)
