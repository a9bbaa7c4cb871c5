"""Pan & Yao 2017's limb-ring visibility bound (sec. 1.2, eq. 1, fig. 2).

A UV sensor's annular (ring) field sees directions between half-angles ``theta1`` and
``theta2`` from its Earth-pointing boresight (a 120-160 deg ring: theta1 = 60 deg,
theta2 = 80 deg). The limb of an Earth of radius R seen from geocentric distance ``r``
lies at the half-angle ``rho = arcsin(R / r)`` from nadir; the whole limb is in the ring
when ``theta1 <= rho <= theta2``, i.e. (Pan & Yao 2017, eq. 1)

    R / sin(theta2) - R <= h <= R / sin(theta1) - R,       h = r - R.

Pan & Yao 2017's band (98.3, 985.6) km is reproduced with R = 6,371 km (the mean Earth radius);
R = 6,375 km (its limb radius elsewhere) gives (98.3, 986.2) km.
"""

from __future__ import annotations

import numpy as np

from factors.constants import DEG
from fgnav.constants import MU_EARTH_M3_S2, R_EARTH_M
from fgnav.errors import UserError
from fgnav.models.registry import EARTH_DIRECTION, LIMB_RADIUS
from fgnav.orbit import elements_to_state
from fgnav.scenarios import Scenario, SensorSpec, load_scenario

R_SEED_VISIBILITY_M = 6_371_000.0
"""Earth radius that reproduces Pan & Yao 2017's printed band (98.3-985.6 km)."""
SEED_BAND_KM = (98.3, 985.6)
SEED_RING_DEG = (120.0, 160.0)

__all__ = ["R_SEED_VISIBILITY_M", "SEED_BAND_KM", "SEED_RING_DEG", "VISIBILITY_ORBITS", "visibility_band_m", "visibility_scenario",
           "limb_half_angle_rad", "ring_sees_limb", "ring_needed_deg", "visible_fraction"]


def visibility_band_m(ring_deg=SEED_RING_DEG, r_earth_m: float = R_SEED_VISIBILITY_M) -> tuple[float, float]:
    """(h_min, h_max) in metres for a ring of full angles ``ring_deg`` = (2 theta1, 2 theta2), deg."""
    th1, th2 = ring_deg[0] / 2.0 * DEG, ring_deg[1] / 2.0 * DEG
    if not 0.0 < th1 < th2 <= 90.0 * DEG:
        raise ValueError(f"visibility_band_m: need 0 < ring[0] < ring[1] <= 180 deg, found {ring_deg}")
    return r_earth_m / np.sin(th2) - r_earth_m, r_earth_m / np.sin(th1) - r_earth_m


def limb_half_angle_rad(r_norm_m, r_earth_m: float = R_SEED_VISIBILITY_M) -> np.ndarray:
    """Apparent half-angle of the limb, ``arcsin(R / |r|)`` (rad), for |r| (m)."""
    return np.arcsin(np.clip(r_earth_m / np.asarray(r_norm_m, float), -1.0, 1.0))


def ring_sees_limb(r_eci_m, ring_deg=SEED_RING_DEG, r_earth_m: float = R_SEED_VISIBILITY_M) -> np.ndarray:
    """Boolean (N,): the whole limb falls inside the ring at positions ``r_eci_m`` (N,3) m."""
    rho = limb_half_angle_rad(np.linalg.norm(np.atleast_2d(r_eci_m), axis=1), r_earth_m)
    return (rho >= ring_deg[0] / 2.0 * DEG) & (rho <= ring_deg[1] / 2.0 * DEG)


def ring_needed_deg(h_min_m: float, h_max_m: float, r_earth_m: float = R_SEED_VISIBILITY_M) -> tuple[float, float]:
    """Full ring angles (deg) needed to see the whole limb from h_min to h_max (m): Pan & Yao 2017's
    17-120 deg for 1,000-36,000 km."""
    lo = 2.0 * limb_half_angle_rad(r_earth_m + h_max_m, r_earth_m) / DEG
    hi = 2.0 * limb_half_angle_rad(r_earth_m + h_min_m, r_earth_m) / DEG
    return float(lo), float(hi)


def visible_fraction(r_eci_m, ring_deg=SEED_RING_DEG, r_earth_m: float = R_SEED_VISIBILITY_M) -> float:
    """Fraction of the epochs (rows of ``r_eci_m``) at which the ring sees the whole limb."""
    return float(np.mean(ring_sees_limb(r_eci_m, ring_deg, r_earth_m)))


VISIBILITY_ORBITS = {
    # name: (perigee altitude km, apogee altitude km, inclination deg, duration h)
    "leo-500": (500.0, 500.0, 97.0, 2.0),
    "heo-300x3000": (300.0, 3000.0, 63.4, 4.0),
}
"""Orbits of the visibility study besides ``gto-transfer`` (Pan & Yao 2017's own orbit, whose
perigee, ~995 km, is just above the band: the ring never sees the whole limb)."""


def visibility_scenario(orbit: str, sigma_deg: float = 0.01, step_s: float = 10.0):
    """A scenario whose UV ring gives geocentric direction + limb radius (both ``sigma_deg``)
    every ``step_s``: ``gto-transfer`` or one of :data:`VISIBILITY_ORBITS` (altitudes above
    ``R_EARTH_M``; prior 1 km / 0.1 m/s per axis, random)."""
    sensors = (SensorSpec(EARTH_DIRECTION.kind, sigma_deg=sigma_deg),
               SensorSpec(LIMB_RADIUS.kind, sigma_deg=sigma_deg, r_limb_km=6375.0))
    if orbit == "gto-transfer":
        return load_scenario("gto-transfer").with_options(sensors=sensors, step_s=step_s,
                                                          prior_position_sigma_m=1000.0,
                                                          prior_velocity_sigma_mps=0.1)
    if orbit not in VISIBILITY_ORBITS:
        raise UserError(f"unknown visibility orbit {orbit!r}; expected gto-transfer or "
                        f"{', '.join(VISIBILITY_ORBITS)}")
    hp, ha, inc, dur = VISIBILITY_ORBITS[orbit]
    rp, ra = R_EARTH_M + hp * 1e3, R_EARTH_M + ha * 1e3
    a, e = (rp + ra) / 2.0, (ra - rp) / (ra + rp)
    x0 = elements_to_state(a, e, inc * DEG, 0.0, 30.0 * DEG, 0.0, MU_EARTH_M3_S2)
    return Scenario(name=orbit, description=f"{hp:g} x {ha:g} km, i = {inc:g} deg, UV ring",
                    epoch="2025-03-01T00:00:00Z", duration_h=dur, step_s=step_s,
                    x0_eci=tuple(float(v) for v in x0), prior_position_sigma_m=1000.0,
                    prior_velocity_sigma_mps=0.1, prior_mode="random", sensors=sensors)
