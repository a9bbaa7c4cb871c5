"""Stellar aberration: the apparent direction of a star seen by a moving observer.

Light from a star in the catalogue direction ``u`` (unit, from the observer towards the
star; EME2000, the catalogue place at the epoch, proper motion applied) reaches an observer
moving with velocity ``v`` relative to the barycentric frame (BCRS) from the apparent
direction (special relativity, the Lorentz transformation of a light ray's direction):

    beta = v/c,   g = sqrt(1 - |beta|^2)  (= 1/Lorentz factor),   w = u . beta,
    u' = (g u + (1 + w/(1 + g)) beta) / (1 + w).                                   (1)

Urban & Seidelmann (eds.) 2013, *Explanatory Supplement to the Astronomical Almanac*, 3rd ed.,
sec. 7.2.4.4 ("aberration", eq. 7.40); the same formula is the IAU SOFA / ERFA routine ``ab``
(``iauAb``, "apply aberration to transform natural direction into proper direction"), whose
extra term for the Sun's gravitational light deflection is left out here. ``|u'| = 1``
exactly for unit ``u`` (``|g u + a beta| = 1 + w``).

Which terms and how big (beta <= 1.05e-4: Earth about the Sun 29.8 km/s plus a LEO orbit
7.7 km/s):

- first order, ``u' = u + beta - (u . beta) u``, is the familiar ~20.5 arcsec annual plus the
  ~5-7 arcsec orbital aberration; the formula above is exact in special relativity and
  costs the same, so the second-order term (``~ beta^2``, <= 1.1e-8 rad = 2.3 mas) is kept
  rather than neglected;
- neglected: the Sun's gravitational deflection (``4 G M_sun/(c^2 b)``: 4 mas at 90 deg from
  the Sun, 16 mas at 30 deg; SOFA ``ld``), the Earth's (< 1 mas at the limb), and the
  annual parallax of the nearest stars (< 0.8 arcsec, a catalogue matter).

The observer's barycentric velocity is the Earth's (:func:`earth_velocity_bcrs_mps`) plus
the spacecraft's geocentric velocity (the orbit state's ``v_eci_mps``; the Galilean sum is
exact to ``beta_E beta_sc`` ~ 3e-9 rad, 0.6 mas).

The Earth's velocity: the time derivative (central difference, 60 s step: truncation
~1e-10 relative) of the project's analytic geocentric Sun position
(``factors.ephemeris.sun_position_eci_m``, Montenbruck & Gill 2000, eqs. 3.43-3.45), sign
reversed. That series follows the Earth-Moon barycentre about the Sun (no lunar term) and is
heliocentric; the Earth about the Earth-Moon barycentre (12.5 m/s) and the Sun about the
solar-system barycentre (<= 15 m/s) are left out. Measured against ERFA ``epv00`` (the
barycentric velocity, VSOP2000-based, ~ mm/s; tests/test_aberration.py holds reference
values): the difference is <= 40 m/s, 1.3e-3 of 29.8 km/s, 0.03 arcsec of aberration,
against star-tracker noise of arcseconds, so the analytic model is enough and the project
needs no further dependency.

Jacobian with respect to ``beta`` (for the spacecraft velocity, a graph state): with
``a = 1 + w/(1 + g)``, ``n = g u + a beta``, ``d = 1 + w``,
``dg/dbeta = -beta^T/g``, ``dw/dbeta = u^T``,
``da/dbeta = u^T/(1 + g) + w beta^T/(g (1 + g)^2)``,
``dn/dbeta = u dg/dbeta + beta da/dbeta + a I``, and

    du'/dbeta = dn/dbeta / d - n u^T / d^2,        du'/dv = (du'/dbeta)/c.
"""

from __future__ import annotations

import math

import numpy as np
from factors.jit import njit

from factors.ephemeris import sun_position_eci_m

__all__ = ["SPEED_OF_LIGHT_MPS", "aberrate", "aberrate_row_kernel", "apparent_direction",
           "earth_velocity_bcrs_mps"]

SPEED_OF_LIGHT_MPS = 299_792_458.0
"""Speed of light in vacuum, m/s (exact, SI)."""

_EARTH_VELOCITY_STEP_S = 60.0


def aberrate(u, beta):
    """Apparent unit direction (eq. 1 of the module docstring) and its Jacobian.

    Parameters
    ----------
    u : (N, 3) catalogue unit directions (normalized here), any inertial frame;
    beta : (N, 3) observer velocity over c (dimensionless), same frame, ``|beta| < 1``.

    Returns
    -------
    u_app : (N, 3) apparent unit directions; J_beta : (N, 3, 3) ``du_app/dbeta``.
    """
    u = np.asarray(u, dtype=float)
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    b = np.broadcast_to(np.asarray(beta, dtype=float), u.shape)
    g = np.sqrt(1.0 - np.sum(b * b, axis=-1))                      # (N,)
    w = np.sum(u * b, axis=-1)
    a = 1.0 + w / (1.0 + g)
    n = g[:, None] * u + a[:, None] * b
    d = 1.0 + w
    u_app = n / d[:, None]
    dg = -b / g[:, None]                                           # (N, 3) row vectors
    da = u / (1.0 + g)[:, None] + (w / (g * (1.0 + g) ** 2))[:, None] * b
    dn = (u[:, :, None] * dg[:, None, :] + b[:, :, None] * da[:, None, :]
          + a[:, None, None] * np.eye(3))
    J = dn / d[:, None, None] - n[:, :, None] * u[:, None, :] / (d * d)[:, None, None]
    return u_app, J


@njit(cache=True)
def aberrate_row_kernel(u, beta, ua, Ju, Jb):
    """:func:`aberrate` of one row, for compiled kernels: the apparent direction ``ua`` (3,)
    of the unit ``u`` (3,) for ``beta`` (3,), ``Jb = dua/dbeta`` (3, 3) as there, and also
    ``Ju = dua/du = (g I + beta beta^T/(1 + g))/d - ua beta^T/d`` (3, 3), ``d = 1 + u.beta``.
    Returns 1.0, or -1.0 (outputs untouched) outside the model's domain ``|beta| < 1``: an
    observer at or beyond the speed of light, as a diverging iterate can be (a prior inside
    the Sun, a geocentric log read as heliocentric)."""
    bb = beta[0] * beta[0] + beta[1] * beta[1] + beta[2] * beta[2]
    if not bb < 1.0:
        return -1.0
    g = math.sqrt(1.0 - bb)
    w = u[0] * beta[0] + u[1] * beta[1] + u[2] * beta[2]
    a = 1.0 + w / (1.0 + g)
    d = 1.0 + w
    for i in range(3):
        ua[i] = (g * u[i] + a * beta[i]) / d
    for i in range(3):
        ni = ua[i] * d
        for j in range(3):
            eye = 1.0 if i == j else 0.0
            Ju[i, j] = (g * eye + beta[i] * beta[j] / (1.0 + g)) / d - ni * beta[j] / (d * d)
            dg = -beta[j] / g
            da = u[j] / (1.0 + g) + w * beta[j] / (g * (1.0 + g) ** 2)
            Jb[i, j] = (u[i] * dg + beta[i] * da + a * eye) / d - ni * u[j] / (d * d)
    return 1.0


def apparent_direction(u, v_observer_bcrs_mps):
    """Apparent direction for an observer moving at ``v_observer_bcrs_mps`` (N, 3) m/s
    (BCRS, the catalogue's frame): ``(u_app (N, 3), du_app/dv (N, 3, 3) in s/m)``."""
    u_app, J = aberrate(u, np.asarray(v_observer_bcrs_mps, dtype=float) / SPEED_OF_LIGHT_MPS)
    return u_app, J / SPEED_OF_LIGHT_MPS


def earth_velocity_bcrs_mps(t_j2000_s):
    """The Earth's velocity about the Sun, EME2000, m/s, at ``t_j2000_s`` (s after J2000 TT;
    scalar -> (3,), (N,) -> (N, 3)): minus the time derivative of the analytic geocentric
    Sun position (module docstring: within 40 m/s of the barycentric velocity)."""
    t = np.asarray(t_j2000_s, dtype=float)
    h = _EARTH_VELOCITY_STEP_S
    return -(sun_position_eci_m(t + h) - sun_position_eci_m(t - h)) / (2.0 * h)
