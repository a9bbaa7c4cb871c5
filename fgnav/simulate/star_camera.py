"""A star camera in the body frame: raw star observations (``star_direction_body`` rows).

Attitude plan: the body is Earth pointing (LVLH, :func:`fgnav.simulate.body_directions.
lvlh_R_eci_from_body`), the same plan as the body-frame Earth, Sun and Moon sensors, so
every body-frame row of a simulated pass refers to one attitude
(:meth:`fgnav.simulate.pass_sim.SimulatedPass.truth_attitude`). The camera looks at the
zenith: its boresight is ``-z_body`` (away from the Earth), and its field is a square
``spec.fov_deg`` wide about the boresight, edges along ``x_body`` and ``y_body``
(:data:`BORESIGHT_BODY`).

Stars: the project's BSC5 catalogue (``fgnav.vision.catalogue``), V <= ``spec.vmag_max``,
proper motion applied to the pass epoch: the catalogue place ``s`` (EME2000) that the row's
``star_x, star_y, star_z`` carry. The true body-frame direction is the apparent one,
``R_eci_from_body^T s'`` with ``s' = ab(s, v/c)`` the catalogue direction aberrated by the
spacecraft's barycentric velocity ``v`` = the Earth's barycentric velocity
(``factors.aberration.earth_velocity_bcrs_mps``) + the true ``v_eci_mps``: relativistic
stellar aberration (Urban & Seidelmann 2013, *Explanatory Supplement to the Astronomical
Almanac*, eq. 7.40), ~20 arcsec from the Earth's orbit and up to ~7 arcsec from a LEO
orbit's own velocity (the stars' parallax, < 0.8 arcsec, is not simulated); the field
test uses the apparent directions; the measurement is that direction rotated by
isotropic tangent-plane noise of 1σ ``spec.star_sigma_arcsec`` per axis
(:func:`fgnav.simulate.noise.perturb_directions`), the centroid error of a star tracker
mapped to angle (Liebe 2002, "Accuracy performance of star trackers - a tutorial", IEEE
Trans. Aerospace and Electronic Systems 38(2): the error is per star and independent).
Every star in the field is observed; no detection threshold is simulated beyond
``vmag_max``.

Mounting (``spec.mounting_sigma_arcsec`` > 0): a star camera on its own mount, apart from the
Earth camera whose frame is the body frame, measures in its own frame, turned from the body by
``M = R_body_from_starcam = Exp(w)`` (the nominal mounting taken out): ``u_cam = (R M)^T s``
(:mod:`factors.alignment`). ``w`` is drawn once per pass, ``N(0, sigma^2 I)`` per axis, by
the caller (:func:`draw_mounting_rotvec`, from its own seeded stream); the field test stays
in the body frame (a 30 arcsec mounting error moves no star across a 12 deg field edge that
matters).
"""

from __future__ import annotations

import numpy as np

from factors.aberration import apparent_direction, earth_velocity_bcrs_mps
from factors.constants import ARCSEC, DEG
from factors.geometry import so3_exp
from fgnav.simulate.body_directions import lvlh_R_eci_from_body
from fgnav.simulate.noise import perturb_directions
from fgnav.time import j2000_seconds
from fgnav.vision.catalogue import decimal_year, load_catalogue

__all__ = ["BORESIGHT_BODY", "CAMERA_FROM_BODY", "stars_in_field", "simulate_star_camera_rows",
           "draw_mounting_rotvec"]

CAMERA_FROM_BODY = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
"""Rotation taking body-frame vectors into the camera frame (x_cam = x_body, y_cam = -y_body,
z_cam = -z_body): the camera's boresight +z_cam is the zenith of the Earth-pointing body."""
_ABERRATION_MARGIN_DEG = 0.02
"""Extra field width (deg) for the catalogue directions' first cut: aberration moves a star by
< 30 arcsec = 0.008 deg."""
BORESIGHT_BODY = CAMERA_FROM_BODY[2]
"""The camera boresight in the body frame (-z_body, the zenith)."""


def stars_in_field(u_body: np.ndarray, fov_deg: float) -> np.ndarray:
    """Mask (M,) of the body-frame unit vectors (M, 3) inside the camera's square field
    ``fov_deg`` wide (full width) about :data:`BORESIGHT_BODY`."""
    c = np.asarray(u_body, dtype=float) @ CAMERA_FROM_BODY.T
    lim = np.tan(0.5 * fov_deg * DEG) * c[:, 2]
    return (c[:, 2] > 0) & (np.abs(c[:, 0]) <= lim) & (np.abs(c[:, 1]) <= lim)


def draw_mounting_rotvec(spec, rng) -> np.ndarray | None:
    """The star camera's mounting error ``w`` (3,) rad, ``N(0, sigma^2)`` per axis with
    ``sigma = spec.mounting_sigma_arcsec`` (module docstring); None for a confocal camera
    (sigma 0), which draws nothing from ``rng``."""
    sig = float(getattr(spec, "mounting_sigma_arcsec", 0.0) or 0.0)
    return None if sig <= 0 else rng.standard_normal(3) * sig * ARCSEC


def simulate_star_camera_rows(spec, t_s, x_true, epoch0, rng, catalogue=None,
                              mounting_rotvec=None):
    """Rows of the star camera ``spec`` at epochs ``t_s`` (``pass_sim`` protocol): one chunk
    ``(spec.kind, t, u_meas (M, 3), sigma_rad, {"star_x", "star_y", "star_z"})`` with a
    row per star in the field at each epoch (module docstring). ``x_true`` (N, 6) the truth
    at ``t_s`` (s from ``epoch0``); ``rng`` a numpy Generator; ``catalogue`` (optional) a
    :class:`fgnav.vision.catalogue.Catalogue` instead of BSC5 to ``spec.vmag_max``;
    ``mounting_rotvec`` (3,) rad (optional): the camera's mounting error ``w``, rows then in
    the camera frame ``(R Exp(w))^T s`` (None: the body frame)."""
    if catalogue is None:
        catalogue = load_catalogue(epoch_year=decimal_year(epoch0), vmag_max=spec.vmag_max)
    S = catalogue.u_eci
    R = lvlh_R_eci_from_body(x_true)
    t_out, s_out, u_out = [], [], []
    t_s = np.asarray(t_s, dtype=float)
    v_obs = earth_velocity_bcrs_mps(float(j2000_seconds(epoch0)) + t_s) + np.asarray(x_true)[:, 3:6]
    for n, t in enumerate(t_s):
        near = np.flatnonzero(stars_in_field(S @ R[n], spec.fov_deg + _ABERRATION_MARGIN_DEG))
        s_app, _ = apparent_direction(S[near], np.broadcast_to(v_obs[n], (len(near), 3)))
        u_body = s_app @ R[n]                          # R^T s' for the stars near the field
        i = np.flatnonzero(stars_in_field(u_body, spec.fov_deg))
        t_out.append(np.full(len(i), t))
        s_out.append(S[near[i]])
        u_out.append(u_body[i])
    t_all = np.concatenate(t_out)
    sig = spec.star_sigma_arcsec * ARCSEC
    s_all = np.concatenate(s_out).reshape(-1, 3)
    u_true = np.concatenate(u_out).reshape(-1, 3)
    if mounting_rotvec is not None:            # u_cam = M^T R^T s (rows: u_body @ M)
        u_true = u_true @ so3_exp(np.asarray(mounting_rotvec, dtype=float))
    u_meas = perturb_directions(u_true, np.full(len(t_all), sig), rng)
    extra = {"star_x": s_all[:, 0], "star_y": s_all[:, 1], "star_z": s_all[:, 2]}
    return [(spec.kind, t_all, u_meas, sig, extra)]
