"""Body-frame Sun / Moon / Earth directions of the INS/CNS lecture scheme (and the LVLH attitude
plan).

The INS/CNS lecture ("基于日地月信息的航天器天文导航"): a Sun sensor, a Moon sensor (UV) and a UV Earth
sensor measure the directions from the spacecraft to the Sun, the Moon and the Earth's
centre in the body frame; an altimeter measures the height (``fgnav.simulate.pass_sim``,
kind ``altitude``). The body is three-axis stabilized, Earth pointing: body = LVLH,
``z_b = -r/|r|`` (nadir), ``y_b = -(r x v)/|r x v|`` (minus orbit normal), ``x_b = y_b x z_b``
(along the velocity for a circular orbit) -- :func:`lvlh_R_eci_from_body`.

Directions are geometric, spacecraft -> body, so the Moon's parallax (up to
``asin(|r|/|r_moon|)`` ~ 1.0 deg in LEO) and the Sun's (~9 arcsec) are in the data; the
preprocessing (``fgnav.sun_earth_moon``) removes them with the INS/CNS lecture's triangle. Noise:
the true unit vector rotated by isotropic tangent-plane noise (``noise.perturb_directions``),
``sigma_deg`` 1σ per axis. Visibility: the Sun is not seen when the Earth's disc (radius
``R_e``) hides it (eclipse); the Moon likewise, and not closer than
``min_sun_elongation_deg`` to the Sun (stray light). Ephemeris: ``factors.ephemeris``
(the estimator's reference vectors come from the same analytic series: the ephemeris
error is not simulated).
"""

from __future__ import annotations

import numpy as np

from factors.constants import DEG, R_EARTH_M
from factors.planets import moon_position_geo_m, sun_position_geo_m
from fgnav.simulate.noise import perturb_directions
from fgnav.time import j2000_seconds

__all__ = ["lvlh_R_eci_from_body", "occulted_by_earth", "simulate_body_direction_rows",
           "earth_centre_target", "sun_target", "moon_target"]


def lvlh_R_eci_from_body(x_eci):
    """Earth-pointing attitude plan: ``R_eci_from_body`` (N, 3, 3) of states ``x_eci`` (N, 6).

    Columns (body axes in ECI): ``x_b = y_b x z_b``, ``y_b = -h/|h|``, ``z_b = -r/|r|``.
    """
    x = np.atleast_2d(np.asarray(x_eci, dtype=float))
    r, v = x[:, :3], x[:, 3:6]
    z = -r / np.linalg.norm(r, axis=1, keepdims=True)
    h = np.cross(r, v)
    y = -h / np.linalg.norm(h, axis=1, keepdims=True)
    xb = np.cross(y, z)
    return np.stack([xb, y, z], axis=-1)


def occulted_by_earth(r_eci_m, p_target_eci_m, r_earth_m=R_EARTH_M):
    """True where the Earth's disc (sphere of radius ``r_earth_m``) hides the target.

    Hidden when the angle between the target and the Earth's centre, seen from ``r``, is
    below the Earth's angular radius ``asin(R/|r|)`` and the target is farther than the limb.
    """
    r = np.asarray(r_eci_m, dtype=float)
    d = np.asarray(p_target_eci_m, dtype=float) - r
    dn = np.linalg.norm(d, axis=1)
    rn = np.linalg.norm(r, axis=1)
    cos_sep = np.sum(d * (-r), axis=1) / (dn * rn)
    rho = np.arcsin(np.clip(r_earth_m / rn, -1.0, 1.0))
    return (np.arccos(np.clip(cos_sep, -1.0, 1.0)) < rho) & (dn > np.sqrt(rn ** 2 - r_earth_m ** 2))


def earth_centre_target(spec, r_eci_m, t_j2000_s):
    """The Earth's centre: position (N, 3) ECI, m (zeros) and always seen."""
    return np.zeros_like(r_eci_m), np.ones(len(r_eci_m), dtype=bool)


def sun_target(spec, r_eci_m, t_j2000_s):
    """The Sun (ERFA ``epv00``, ``factors.planets``), seen unless the Earth hides it
    (eclipse)."""
    p = sun_position_geo_m(t_j2000_s)
    return p, ~occulted_by_earth(r_eci_m, p)


def moon_target(spec, r_eci_m, t_j2000_s):
    """The Moon (ERFA ``moon98``, ``factors.planets``), seen unless the Earth hides it or it
    is closer than ``spec.min_sun_elongation_deg`` to the Sun (stray light)."""
    p = moon_position_geo_m(t_j2000_s)
    s = sun_position_geo_m(t_j2000_s)
    d_m, d_s = p - r_eci_m, s - r_eci_m
    cos_el = np.sum(d_m * d_s, axis=1) / (np.linalg.norm(d_m, axis=1) * np.linalg.norm(d_s, axis=1))
    return p, ~occulted_by_earth(r_eci_m, p) & (cos_el < np.cos(spec.min_sun_elongation_deg * DEG))


def simulate_body_direction_rows(spec, t_s, x_true, epoch0, rng, *, target):
    """Rows ``(kind, t, xyz, sigma)`` of one body-direction sensor (``pass_sim`` protocol).

    ``target(spec, r_eci_m, t_j2000_s) -> (p (N, 3), seen (N,))``: where the observed body is
    (ECI, m) and when the sensor sees it (:func:`earth_centre_target`, :func:`sun_target`,
    :func:`moon_target`; the measurement model chooses it); ``spec.kind`` labels the rows;
    ``spec.sigma_deg`` the 1σ per tangent axis (deg); ``x_true`` (N, 6) the truth at ``t_s``
    (s from ``epoch0``).
    """
    r = x_true[:, :3]
    R = lvlh_R_eci_from_body(x_true)
    t_j = float(j2000_seconds(epoch0)) + np.asarray(t_s, dtype=float)
    p, seen = target(spec, r, t_j)
    d = p - r
    u_body = np.einsum("nji,nj->ni", R, d / np.linalg.norm(d, axis=1, keepdims=True))
    sig = spec.sigma_deg * DEG
    u_meas = perturb_directions(u_body, np.full(len(u_body), sig), rng)
    i = np.flatnonzero(seen)
    return [(spec.kind, np.asarray(t_s, dtype=float)[i], u_meas[i], sig)]
