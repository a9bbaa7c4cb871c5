"""Raw star observations (``star_direction_body``: a factor on the attitude, the stellar
aberration by the orbit's velocity; ``factors.direction``, ``factors.alignment``) and the star
camera's mounting variable."""

from __future__ import annotations

import numpy as np

from factors.aberration import earth_velocity_bcrs_mps
from factors.alignment import (aligned_star_direction_apparent_residual,
                               make_aligned_star_direction_apparent_factor)
from factors.constants import ARCSEC
from factors.direction import make_star_direction_apparent_factor, star_direction_apparent_residual
from factors.geometry import so3_log
from fgnav.io.log_csv import STAR_COLUMNS
from fgnav.models.attitude import ATTITUDE_VARIABLE
from fgnav.models.model import MeasurementModel
from fgnav.models.values import xyz_rows
from fgnav.models.variables import Variable
from fgnav.time import j2000_seconds
from fgnav.vision.attitude import wahba_by_epoch

__all__ = ["MEASUREMENT_MODELS", "CAMERA_ALIGNMENT", "STAR_DIRECTION_BODY"]


# A star camera's identified stars, each a factor on the attitude alone (tight coupling: the
# graph solves the attitude from what the camera measures, not from a solved attitude).

def _star_initial(fam):
    """First guess of the attitude at every row: the SVD solution of Wahba's problem of the
    row's epoch (Markley 1988, ``fgnav.vision.attitude.wahba_svd``) where the epoch has >= 2
    non-parallel stars, else the solution of the nearest such epoch; none without any."""
    ep, R, _ = wahba_by_epoch(fam.k, fam.values["u_body"], fam.values["s_eci"], fam.sigma)
    if not len(ep):
        return {}
    j = np.searchsorted(ep, fam.k)                   # first solved epoch at or after
    lo, hi = np.clip(j - 1, 0, len(ep) - 1), np.clip(j, 0, len(ep) - 1)
    pick = np.where(np.abs(ep[lo] - fam.k) <= np.abs(ep[hi] - fam.k), lo, hi)
    return {ATTITUDE_VARIABLE.name: so3_log(R[pick])}


def _star_values(log, i):
    """A star row's ``u_body``, catalogue ``s_eci`` and, for the aberration (the observer's
    barycentric velocity is the Earth's plus the spacecraft's), the Earth's barycentric
    velocity ``v_earth_bcrs_mps`` (M, 3) at the row's epoch and ``aberration`` (M,) True
    (:func:`fgnav.apparent.without_aberration` switches it off for comparison)."""
    t = float(j2000_seconds(log.epoch0)) + np.asarray(log.t_s, dtype=float)[i]
    return {"u_body": xyz_rows(log, i), "s_eci": np.column_stack(
        [np.asarray(log.extra[c], dtype=float)[i] for c in STAR_COLUMNS]),
        "v_earth_bcrs_mps": earth_velocity_bcrs_mps(t), "aberration": np.ones(len(t), bool)}


def _observer_velocity(fam, v):
    """The observer's barycentric velocity (M, 3), m/s, of star rows (zero where the
    aberration is switched off) and the mask ``on`` (M,)."""
    on = fam.values["aberration"]
    return (fam.values["v_earth_bcrs_mps"] + v["orbit"][:, 3:6]) * on[:, None], on


def _velocity_columns(H_v, on):
    H_x = np.zeros(H_v.shape[:-1] + (6,))
    H_x[..., 3:6] = H_v * on[:, None, None]
    return H_x


def _star_residual(fam, v):
    """The apparent direction at the orbit's velocity estimate (stellar aberration, ~20-27
    arcsec); ``H`` on the orbit's velocity columns is ~3e-9 rad per m/s. Through the star
    camera's mounting when it is estimated (:data:`CAMERA_ALIGNMENT`)."""
    v_obs, on = _observer_velocity(fam, v)
    if CAMERA_ALIGNMENT.name in v:
        e, H_A, H_M, H_v = aligned_star_direction_apparent_residual(
            v[ATTITUDE_VARIABLE.name], v[CAMERA_ALIGNMENT.name], fam.values["s_eci"], v_obs,
            fam.values["u_body"])
        return e, {"orbit": _velocity_columns(H_v, on), ATTITUDE_VARIABLE.name: H_A,
                   CAMERA_ALIGNMENT.name: H_M}
    e, H_R, H_v = star_direction_apparent_residual(v[ATTITUDE_VARIABLE.name],
                                                   fam.values["s_eci"], v_obs,
                                                   fam.values["u_body"])
    return e, {"orbit": _velocity_columns(H_v, on), ATTITUDE_VARIABLE.name: H_R}


def _star_factor(fam, j, keys, noise):
    v_earth = fam.values["v_earth_bcrs_mps"][j] if fam.values["aberration"][j] else None
    if CAMERA_ALIGNMENT.name in keys:
        return make_aligned_star_direction_apparent_factor(
            keys["orbit"], keys[ATTITUDE_VARIABLE.name], keys[CAMERA_ALIGNMENT.name],
            fam.values["s_eci"][j], v_earth, fam.values["u_body"][j], noise)
    return make_star_direction_apparent_factor(
        keys["orbit"], keys[ATTITUDE_VARIABLE.name], fam.values["s_eci"][j], v_earth,
        fam.values["u_body"][j], noise)


# A star camera on its own mount (not the Earth camera's detector): its rows are in its own
# frame, b = (A M)^T s with M = R_body_from_starcam (factors.alignment); with
# --estimate camera-alignment M is a graph variable, constant over the pass.
CAMERA_ALIGNMENT = Variable(
    "camera_alignment", "m", 3, "rad", manifold="rot3",
    components=("align_x", "align_y", "align_z"), psd=1e-16, prior_sigma=60.0 * ARCSEC,
    description="star camera mounting R_body_from_starcam as a rotation vector, rad "
                "(constant: random walk of 1e-16 rad^2/s)")
"""The star camera's mounting relative to the Earth camera (the body frame), identity when
the rows are already in the body frame (a confocal sensor, or a calibrated mounting): one
rotation for the pass, held in every epoch's block as a random walk of 1e-16 rad^2/s
(0.4 arcsec in 12 h: constant against its 60 arcsec prior and the 5 arcsec stars, and a
per-step sigma of 8e-8 rad at 60 s that keeps the chain's information within ~1e5 of the
stars', where the constant floor would put 1e7 in iSAM2's Cholesky); prior 60 arcsec per
axis about the nominal mounting (a ground alignment good to an arcminute; Shuster &
Pitone 1991, "Batch estimation of spacecraft sensor alignments I", J. Astronautical
Sciences 39(4))."""


STAR_DIRECTION_BODY = MeasurementModel(
    kind="star_direction_body", dim=2, unit="rad",
    summary="unit vector to a star, body frame; its catalogue unit vector (EME2000)",
    values=_star_values, residual=_star_residual, factor=_star_factor,
    optional_variables=(ATTITUDE_VARIABLE, CAMERA_ALIGNMENT), weak_orbit_dependence=True,
    requires=ATTITUDE_VARIABLE.name, initial=_star_initial,
    )

MEASUREMENT_MODELS = (STAR_DIRECTION_BODY,)
"""This module's measurement models (assembled by :mod:`fgnav.models.registry`)."""
