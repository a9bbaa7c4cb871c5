"""The near bodies' ephemerides in a pass's frame: centres, velocities and the frame's own
barycentric velocity, as the measurement models of near bodies read them (the angle rows,
:mod:`fgnav.models.registry`) and the simulator draws them (:mod:`fgnav.simulate.celestial_angles`).

Positions from pyerfa (``factors.planets``: ``epv00``, ``moon98``); the frame origin's
barycentric velocity from ``factors.aberration`` (Urban & Seidelmann 2013, sec. 7.2).
"""

from __future__ import annotations

import numpy as np

from factors.aberration import earth_velocity_bcrs_mps
from factors.planets import (earth_position_helio_m, moon_position_geo_m,
                             moon_position_helio_m, sun_position_geo_m)

__all__ = ["body_position_eci_m", "body_velocity_mps", "frame_velocity_bcrs_mps"]


def body_position_eci_m(name: str, t_j2000_s, centre: str = "earth") -> np.ndarray:
    """Centre of a near body (one of ``fgnav.io.log_csv.BODIES``), m, (N, 3) at the epochs
    ``t_j2000_s`` (N,), relative to the pass's ``centre`` (EME2000 axes), from pyerfa
    (``factors.planets``): heliocentric (``centre="sun"``), the Sun at the origin, the Earth
    from ``epv00`` and the Moon from ``moon98``; geocentric, the Earth at the origin, the Sun
    from ``epv00`` (km-class) and the Moon from ``moon98`` (~10 arcsec). Not the
    low-precision series of ``factors.ephemeris`` (Montenbruck & Gill 2000, eqs. 3.43-3.49),
    whose Sun is within ~36 arcsec and Moon up to ~2 arcmin off: many sigmas of an arcsecond
    angle sensor, and more than the aberration the angles correct for."""
    t = np.atleast_1d(np.asarray(t_j2000_s, dtype=float))
    if centre == "sun":
        if name == "earth":
            return earth_position_helio_m(t)
        if name == "moon":
            return moon_position_helio_m(t)
        return np.zeros((len(t), 3))
    if name == "sun":
        return sun_position_geo_m(t)
    if name == "moon":
        return moon_position_geo_m(t)
    return np.zeros((len(t), 3))


_VELOCITY_STEP_S = 60.0


def body_velocity_mps(name: str, t_j2000_s, centre: str = "earth") -> np.ndarray:
    """Velocity (N, 3), m/s, of a near body in the pass's frame (:func:`body_position_eci_m`):
    its central difference over +-60 s (truncation ~4e-9 relative for the Moon)."""
    t = np.atleast_1d(np.asarray(t_j2000_s, dtype=float))
    h = _VELOCITY_STEP_S
    return (body_position_eci_m(name, t + h, centre)
            - body_position_eci_m(name, t - h, centre)) / (2.0 * h)


def frame_velocity_bcrs_mps(t_j2000_s, centre: str = "earth") -> np.ndarray:
    """The model's barycentric velocity (N, 3), m/s, of the pass's frame origin: the Earth's
    (``factors.aberration.earth_velocity_bcrs_mps``, within 70 m/s of ERFA) for a geocentric
    pass; zero for a heliocentric one (the Sun moves <= 15 m/s about the barycentre:
    0.01 arcsec of aberration)."""
    t = np.atleast_1d(np.asarray(t_j2000_s, dtype=float))
    if centre == "sun":
        return np.zeros((len(t), 3))
    return earth_velocity_bcrs_mps(t).reshape(len(t), 3)
