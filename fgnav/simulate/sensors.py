"""Simulated readings of the state-only sensors: geocentric direction, limb radius, altimeter.

Each function takes a sensor spec (``fgnav.scenarios.SensorSpec``), the sensor's epochs
``t_s`` (M,), the true states there ``x_true`` (M, 6), and a seeded numpy Generator, and
returns ``(xyz (M, 3), sigma)``: the log's x, y, z columns (NaN where unused) and the 1-sigma.
Noise:

* direction: the true unit vector rotated by a random angle, ``u = cos(t) u0 + sin(t) d``,
  tangent-plane components ``n ~ N(0, sigma^2 I_2)``, ``t = |n|``, ``d = B^T n / t``
  (``fgnav.simulate.noise.perturb_directions``);
* limb angular radius: ``rho = arcsin(R_limb/|r|) + sigma n``;
* altimeter: ``h = |r| - R_ref + sigma n`` (R_ref = R_e).
"""

from __future__ import annotations

import numpy as np

from fgnav.constants import DEG, R_EARTH_M
from fgnav.simulate.noise import perturb_directions

__all__ = ["geocentric_direction_readings", "limb_radius_readings", "altitude_readings"]


def geocentric_direction_readings(spec, t_s, x_true, rng):
    """Unit vectors spacecraft -> Earth centre, ECI, with angular noise ``spec.sigma_deg``."""
    r = x_true[:, :3]
    s = spec.sigma_deg * DEG
    u = perturb_directions(-r / np.linalg.norm(r, axis=1)[:, None], np.full(len(t_s), s), rng)
    return u, s


def limb_radius_readings(spec, t_s, x_true, rng):
    """x = limb angular radius (rad) with noise ``spec.sigma_deg``, y = limb radius (m)."""
    rn = np.linalg.norm(x_true[:, :3], axis=1)
    s = spec.sigma_deg * DEG
    r_limb = spec.r_limb_km * 1e3
    rho = np.arcsin(r_limb / rn) + s * rng.standard_normal(len(t_s))
    return np.column_stack([rho, np.full(len(t_s), r_limb), np.full(len(t_s), np.nan)]), s


def altitude_readings(spec, t_s, x_true, rng):
    """x = height above the sphere R_e (m) with noise ``spec.sigma_m``, y = R_e."""
    rn = np.linalg.norm(x_true[:, :3], axis=1)
    h = rn - R_EARTH_M + spec.sigma_m * rng.standard_normal(len(t_s))
    return np.column_stack([h, np.full(len(t_s), R_EARTH_M), np.full(len(t_s), np.nan)]), spec.sigma_m
