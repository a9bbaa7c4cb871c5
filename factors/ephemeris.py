"""Low-precision analytic Sun and Moon positions, geocentric, EME2000 (mean equator and
equinox of J2000), metres.

Montenbruck & Gill, *Satellite Orbits* (Springer 2000), sec. 3.3.2, eqs. (3.43)-(3.49)
(the ``SunPos``/``MoonPos`` series, longitudes referred to the J2000 equinox):

- Sun: elliptic-orbit series in mean anomaly, ecliptic latitude neglected, ~1e-4 relative in
  distance. M&G hold the Sun's perigee at its J2000 longitude (282.94 deg, the series'
  mean longitude advancing at the anomalistic rate), so their direction drifts by the
  perigee's sidereal advance, 0.3233 deg per century (11.6 arcsec a year: 5 arcmin by
  2025); that advance is added here (Standish, "Keplerian Elements for Approximate
  Positions of the Major Planets", JPL: the Earth-Moon barycentre's longitude of
  perihelion 102.93768 + 0.32327 T deg, J2000 ecliptic and equinox). Against ERFA
  ``epv00`` the direction is then within 36 arcsec over 1990-2040 (the Earth-Moon
  barycentre's 6 arcsec and the planetary terms the series leaves out), where it was 5-8
  arcmin in 2025-2040.
- Moon: the leading perturbation terms of Brown's theory. Accuracy a few arcmin in
  direction (~0.1 deg) and a few hundred km in distance (M&G); tested here to 0.05 deg /
  500 km against Meeus' full series.

The argument is ``t_j2000_s`` = seconds since J2000.0 (2000-01-01T12:00:00 TT); see
``fgnav.time.j2000_seconds``. Used by the third-body accelerations of ``factors.dynamics``
(point masses; errors of this size change LEO third-body accelerations by < 1e-3 relative).

``sun_position_eci_m_nb`` / ``moon_position_eci_m_nb`` are the numba scalar kernels
(callable from other ``@njit`` code); ``sun_position_eci_m`` / ``moon_position_eci_m`` accept
a scalar ``t`` (-> (3,)) or an array (-> (N, 3)).
"""

from __future__ import annotations

import numpy as np
from factors.jit import njit

from factors.interpret import active, python_body

__all__ = [
    "OBLIQUITY_J2000_RAD", "sun_position_eci_m", "moon_position_eci_m",
    "sun_position_eci_m_nb", "moon_position_eci_m_nb",
]

OBLIQUITY_J2000_RAD = np.deg2rad(23.43929111)
"""Obliquity of the J2000 ecliptic, rad (M&G eq. 3.45)."""

_PERIGEE_ADVANCE_REV_PER_CENTURY = 0.32327364 / 360.0
"""Sidereal advance of the Sun's perigee (the Earth-Moon barycentre's perihelion + 180 deg),
rev per Julian century (Standish, JPL approximate planetary elements)."""
_TWO_PI = 2.0 * np.pi
_ARCSEC_PER_RAD = 206264.80624709636
_S_PER_CENTURY = 86400.0 * 36525.0
_COS_EPS = np.cos(OBLIQUITY_J2000_RAD)
_SIN_EPS = np.sin(OBLIQUITY_J2000_RAD)


@njit(cache=True)
def _frac(x):
    return x - np.floor(x)


@njit(cache=True)
def _ecliptic_to_eme2000(x, y, z):
    """Rotate ecliptic J2000 coordinates to EME2000: R_x(-eps). Scalars -> (3,); as Python
    (``factors.interpret``) arrays (N,) -> (3, N)."""
    return np.array([x, _COS_EPS * y - _SIN_EPS * z, _SIN_EPS * y + _COS_EPS * z])


@njit(cache=True)
def sun_position_eci_m_nb(t_j2000_s):
    """Geocentric Sun position, EME2000, m, at ``t_j2000_s`` (s since J2000 TT). M&G (3.43)-(3.45)."""
    T = t_j2000_s / _S_PER_CENTURY
    M = _TWO_PI * _frac(0.9931267 + 99.9973583 * T)  # mean anomaly, rad
    # perigee longitude 282.9400 deg (M&G) + its sidereal advance (module docstring)
    L = _TWO_PI * _frac(0.7859444 + _PERIGEE_ADVANCE_REV_PER_CENTURY * T + M / _TWO_PI
                        + (6892.0 * np.sin(M) + 72.0 * np.sin(2.0 * M)) / 1296.0e3)
    r = 149.619e9 - 2.499e9 * np.cos(M) - 0.021e9 * np.cos(2.0 * M)
    return _ecliptic_to_eme2000(r * np.cos(L), r * np.sin(L), 0.0)


@njit(cache=True)
def moon_position_eci_m_nb(t_j2000_s):
    """Geocentric Moon position, EME2000, m, at ``t_j2000_s`` (s since J2000 TT). M&G (3.46)-(3.49)."""
    T = t_j2000_s / _S_PER_CENTURY
    L0 = _frac(0.606433 + 1336.851344 * T)            # mean longitude, rev (J2000 equinox)
    l = _TWO_PI * _frac(0.374897 + 1325.552410 * T)   # Moon's mean anomaly
    lp = _TWO_PI * _frac(0.993133 + 99.997361 * T)    # Sun's mean anomaly
    D = _TWO_PI * _frac(0.827361 + 1236.853086 * T)   # mean elongation Moon-Sun
    F = _TWO_PI * _frac(0.259086 + 1342.227825 * T)   # mean argument of latitude
    dL = (22640.0 * np.sin(l) - 4586.0 * np.sin(l - 2.0 * D) + 2370.0 * np.sin(2.0 * D)
          + 769.0 * np.sin(2.0 * l) - 668.0 * np.sin(lp) - 412.0 * np.sin(2.0 * F)
          - 212.0 * np.sin(2.0 * l - 2.0 * D) - 206.0 * np.sin(l + lp - 2.0 * D)
          + 192.0 * np.sin(l + 2.0 * D) - 165.0 * np.sin(lp - 2.0 * D) - 125.0 * np.sin(D)
          - 110.0 * np.sin(l + lp) + 148.0 * np.sin(l - lp) - 55.0 * np.sin(2.0 * F - 2.0 * D))
    L = _TWO_PI * _frac(L0 + dL / 1296.0e3)
    S = F + (dL + 412.0 * np.sin(2.0 * F) + 541.0 * np.sin(lp)) / _ARCSEC_PER_RAD
    h = F - 2.0 * D
    N = (-526.0 * np.sin(h) + 44.0 * np.sin(l + h) - 31.0 * np.sin(-l + h)
         - 23.0 * np.sin(lp + h) + 11.0 * np.sin(-lp + h) - 25.0 * np.sin(-2.0 * l + F)
         + 21.0 * np.sin(-l + F))
    B = (18520.0 * np.sin(S) + N) / _ARCSEC_PER_RAD
    R = (385000e3 - 20905e3 * np.cos(l) - 3699e3 * np.cos(2.0 * D - l) - 2956e3 * np.cos(2.0 * D)
         - 570e3 * np.cos(2.0 * l) + 246e3 * np.cos(2.0 * l - 2.0 * D)
         - 205e3 * np.cos(lp - 2.0 * D) - 171e3 * np.cos(l + 2.0 * D)
         - 152e3 * np.cos(l + lp - 2.0 * D))
    cB = np.cos(B)
    return _ecliptic_to_eme2000(R * np.cos(L) * cB, R * np.sin(L) * cB, R * np.sin(B))


@njit(cache=True)
def _many(t, which):
    out = np.empty((t.shape[0], 3))
    for k in range(t.shape[0]):
        out[k] = sun_position_eci_m_nb(t[k]) if which == 0 else moon_position_eci_m_nb(t[k])
    return out


COMPILED_FROM = 20000
"""Number of times from which the positions are computed by the compiled loop; below, the
kernel's own body runs on all the times at once with numpy (:mod:`factors.interpret`), as
quick at that size and without loading numba. Both give the same numbers."""


def _dispatch(t_j2000_s, which):
    t = np.asarray(t_j2000_s, dtype=float)
    if t.size < COMPILED_FROM or active():
        body = python_body(sun_position_eci_m_nb if which == 0 else moon_position_eci_m_nb, arrays=True)
        return np.moveaxis(body(t), 0, -1)
    return _many(np.ascontiguousarray(t.ravel()), which).reshape(t.shape + (3,))


def sun_position_eci_m(t_j2000_s):
    """Geocentric Sun position, EME2000, m: scalar ``t_j2000_s`` -> (3,), array (N,) -> (N, 3)."""
    return _dispatch(t_j2000_s, 0)


def moon_position_eci_m(t_j2000_s):
    """Geocentric Moon position, EME2000, m: scalar ``t_j2000_s`` -> (3,), array (N,) -> (N, 3)."""
    return _dispatch(t_j2000_s, 1)
