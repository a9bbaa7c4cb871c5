"""Loose coupling of a star camera: its raw star rows replaced by one solved attitude per frame.

The tightly coupled route puts every identified star in the graph (``star_direction_body``
rows, factors on the attitude variable). The loosely coupled route, what a star tracker
that reports a solved attitude gives, first solves each frame's attitude alone: the SVD
solution of Wahba's problem (Markley 1988, "Attitude determination using vector
observations and the singular value decomposition", J. Astronautical Sciences 36(3);
:func:`fgnav.vision.attitude.wahba_by_epoch`) with the QUEST covariance (Shuster & Oh 1981,
"Three-axis attitude determination from vector observations", J. Guidance and Control
4(1), eq. 83). The log format's ``attitude`` row carries one 1-sigma for all three axes, so
the row's sigma is the covering one, the square root of the covariance's largest
eigenvalue (the roll about the boresight for a narrow field): the row never claims more
than the frame gives. Frames with fewer than two (non-parallel) stars give no attitude; the
body-frame rows at those epochs have no attitude to be rotated with and are left out (the
tightly coupled graph still uses them, through the attitude's random walk).
"""

from __future__ import annotations

import numpy as np

from factors.aberration import apparent_direction, earth_velocity_bcrs_mps
from factors.geometry import so3_log
from fgnav.io.log_csv import EXTRA_COLUMNS, MeasurementLog, STAR_COLUMNS, log_from_arrays
from fgnav.models.registry import ATTITUDE, MODELS, STAR_DIRECTION_BODY
from fgnav.time import j2000_seconds
from fgnav.vision.attitude import wahba_by_epoch

__all__ = ["attitude_rows_from_stars"]


def attitude_rows_from_stars(log: MeasurementLog, v_eci_mps=None,
                             aberration: bool = True) -> tuple[MeasurementLog, dict]:
    """``log`` with its ``star_direction_body`` rows replaced by one ``attitude`` row per epoch
    with >= 2 stars (module docstring), and without the body-frame rows (``body_frame_of``
    kinds) at epochs left without an attitude. Returns the new log and counts
    ``{"attitude_rows", "epochs_without_attitude", "body_rows_dropped"}``.

    The reference directions are the stars' apparent directions (the catalogue aberrated by
    the observer's barycentric velocity, ``factors.aberration``; Urban & Seidelmann 2013,
    eq. 7.40): the Earth's velocity at the row's epoch plus ``v_eci_mps(t_s)`` ((M,) s from
    the log's epoch -> (M, 3) m/s), the best known spacecraft velocity, when given. Without
    it the spacecraft's own aberration (up to ~7 arcsec in LEO, 2 arcsec in GEO) stays in
    the attitude; ``aberration=False``: the catalogue directions as seen (for comparison)."""
    kinds = np.asarray(log.kind).astype(str)
    star = kinds == STAR_DIRECTION_BODY.kind
    t_star = np.asarray(log.t_s, dtype=float)[star]
    t_u, k = np.unique(t_star, return_inverse=True)
    s_eci = np.column_stack([log.extra[c][star] for c in STAR_COLUMNS])
    if aberration and len(t_star):
        v_obs = earth_velocity_bcrs_mps(float(j2000_seconds(log.epoch0)) + t_star)
        if v_eci_mps is not None:
            v_obs = v_obs + np.asarray(v_eci_mps(t_star), dtype=float)
        s_eci, _ = apparent_direction(s_eci, v_obs)
    ep, R, cov = wahba_by_epoch(k, log.xyz[star], s_eci, log.sigma[star])
    t_att = t_u[ep]
    sig_att = np.sqrt(np.linalg.eigvalsh(cov)[:, -1])
    body = np.isin(kinds, [kd for kd, m in MODELS.items() if m.body_frame_of])
    orphan = body & ~np.isin(log.t_s, t_att)
    keep = ~star & ~orphan
    extra = {c: np.concatenate([log.extra[c][keep], np.full(len(ep), np.nan)])
             for c in EXTRA_COLUMNS}
    new = log_from_arrays(log.epoch0, np.concatenate([log.t_s[keep], t_att]),
                          np.concatenate([kinds[keep], np.full(len(ep), ATTITUDE.kind)]),
                          np.concatenate([log.xyz[keep], so3_log(R).reshape(-1, 3)]),
                          np.concatenate([log.sigma[keep], sig_att]), extra, path=log.path,
                          centre=log.centre, schema=log.schema)
    return new, {"attitude_rows": len(ep), "epochs_without_attitude": len(t_u) - len(ep),
                 "body_rows_dropped": int(orphan.sum())}
