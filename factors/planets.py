"""Heliocentric planetary ephemeris for a cruise beyond Earth orbit (pyerfa), and the table of
third-body positions the motion kernels read.

Frames and units: heliocentric, axes of the ICRS / EME2000 (the 23 mas frame bias between them
is neglected, as everywhere in fgnav), SI (m, m/s). Time: ``t_j2000_s`` seconds since J2000.0
(2000-01-01T12:00:00), taken as TDB (TT - TDB < 2 ms, 50 m of the Earth's motion).

Sources (pyerfa, the Python binding of ERFA maintained by the Astropy project; no data file):

* the Earth: ``erfa.epv00`` (Bretagnon & Francou 1988 VSOP87 fitted to JPL DE405; ERFA's
  documentation: 4.6 km in position, 1.5 km worst case, 1900-2100), heliocentric;
* the Moon: the Earth plus ``erfa.moon98`` (Meeus 1998, *Astronomical Algorithms*, 2nd ed.,
  ch. 47: ~10 arcsec, ~ 20 km at the Moon's distance);
* Venus, the Earth-Moon barycentre, Mars, Jupiter, Saturn: ``erfa.plan94`` (Simon et al.
  1994, "Numerical expressions for precession formulae and mean elements for the Moon and
  the planets", A&A 282, 663: errors of 0.5-1 arcsec of heliocentric longitude for the
  inner planets over 1800-2050, a few arcsec for Jupiter and Saturn).

Why not a JPL kernel (``jplephem``): the smallest useful DE kernel (de440s.bsp, 1849-2150)
is 32 MB of data to ship for positions better than these by ~1000 km at most; in a cruise
the angles are 1-10 arcsec at 0.1-2 AU, and a planet position error of 1000 km at
0.3 AU is 0.7 arcsec of the Sun-Earth angle, while the Earth (the only planet the angles
name) comes from ``epv00`` to ~5 km (0.004 arcsec). For the perturbing accelerations the
plan94 errors change them by < 1e-5 relative.

The motion kernels (``factors.dynamics``, numba) cannot call pyerfa; they read a table of
positions and velocities of :data:`THIRD_BODIES` at one-day nodes (:func:`third_body_table`)
and interpolate it by cubic Hermite splines: the error, ~h^4 |r''''| / 384, is < 100 m for
Venus and far less for the outer planets at h = 1 day (checked in tests/test_planets.py).
"""

from __future__ import annotations

import functools
import warnings

import numpy as np

from factors.constants import AU_M, MU_EARTH_M3_S2, MU_MOON_M3_S2
from factors.errors import EphemerisSpanError
from factors.jit import njit

__all__ = ["THIRD_BODIES", "MU_THIRD_M3_S2", "TABLE_START_J2000_S", "TABLE_STOP_J2000_S",
           "TABLE_STEP_S", "origin_state_bcrs", "sun_position_geo_m", "moon_position_geo_m",
           "earth_position_helio_m", "moon_position_helio_m",
           "planet_state_helio", "third_body_positions_m", "third_body_table",
           "table_positions_nb", "NO_TABLE", "check_table_span", "SPAN_J2000_S", "check_span"]

_DAY_S = 86400.0
_AU_PER_DAY_TO_MPS = AU_M / _DAY_S
_J2000_JD = 2451545.0

THIRD_BODIES = ("venus", "earth-moon barycentre", "mars", "jupiter", "saturn")
"""The third bodies of the heliocentric motion model (point masses), in table order."""
_PLAN94 = (2, 3, 4, 5, 6)
MU_THIRD_M3_S2 = (3.24858592e14, MU_EARTH_M3_S2 + MU_MOON_M3_S2, 4.282837362e13,
                  1.26712764e17, 3.7940585e16)
"""GM of :data:`THIRD_BODIES`, m^3/s^2: Venus, the Earth + Moon, and the Mars, Jupiter and
Saturn systems (Park et al. 2021, "The JPL Planetary and Lunar Ephemerides DE440 and DE441",
AJ 161, 105, Table 8)."""

TABLE_START_J2000_S = 0.0
"""First node of the third-body table: J2000.0 (2000-01-01T12:00 TDB)."""
TABLE_STOP_J2000_S = 100.0 * 365.25 * _DAY_S
"""Last node of the table: 2100-01-01T12:00 TDB (epv00's validity ends in 2100)."""
TABLE_STEP_S = _DAY_S
"""Node spacing of the table, s (module docstring)."""

NO_TABLE = np.zeros((1, 6))
"""The kernels' table argument of a geocentric model (no planet: ``nb = 0`` in the header)."""


SPAN_J2000_S = (-36525.0 * _DAY_S, 36525.0 * _DAY_S)
"""The epochs ERFA's series are valid over (their documentation: 1900-2100), s after J2000."""


def check_span(t_j2000_s) -> None:
    """:class:`EphemerisSpanError` unless every epoch lies in :data:`SPAN_J2000_S` (for what
    needs the span but calls no ERFA series, e.g. a geocentric angle log whose bodies are
    all the Earth: its aberration takes the Earth's velocity from the low-precision series)."""
    t = np.asarray(t_j2000_s, dtype=float)
    if t.size and not (SPAN_J2000_S[0] <= t.min() and t.max() <= SPAN_J2000_S[1]):
        bad = t.min() if t.min() < SPAN_J2000_S[0] else t.max()
        raise EphemerisSpanError(f"planetary ephemeris outside its span: an epoch "
                                 f"{bad / (365.25 * _DAY_S):+.1f} years from J2000")


def _jd2(t_j2000_s):
    return np.asarray(t_j2000_s, dtype=float) / _DAY_S


def _erfa():
    import erfa  # pyerfa: imported on first use (geocentric passes never load it)

    return erfa


def _quiet(fn, *args):
    """An erfa call whose out-of-range ErfaWarning is an error (dates outside 1900-2100)."""
    erfa = _erfa()
    with warnings.catch_warnings():
        warnings.simplefilter("error", erfa.ErfaWarning)
        try:
            return fn(*args)
        except erfa.ErfaWarning as exc:
            raise EphemerisSpanError(f"planetary ephemeris outside its span: {exc}") from None


def earth_position_helio_m(t_j2000_s) -> np.ndarray:
    """Heliocentric position of the Earth's centre, m: scalar -> (3,), (N,) -> (N, 3)
    (``erfa.epv00``)."""
    erfa = _erfa()
    pvh, _ = _quiet(erfa.epv00, _J2000_JD, _jd2(t_j2000_s))
    return np.asarray(pvh["p"]) * AU_M


def origin_state_bcrs(t_j2000_s, centre: str) -> tuple[np.ndarray, np.ndarray]:
    """Barycentric (BCRS, ICRF axes) position (m) and velocity (m/s) of a pass's frame origin,
    the Earth's centre (``centre="earth"``) or the Sun's (``"sun"``), at ``t_j2000_s`` (N,):
    ``erfa.epv00``'s barycentric Earth, less its heliocentric Earth for the Sun. (N, 3) each."""
    erfa = _erfa()
    pvh, pvb = _quiet(erfa.epv00, _J2000_JD, _jd2(np.atleast_1d(t_j2000_s)))
    p, v = np.asarray(pvb["p"]), np.asarray(pvb["v"])
    if centre == "sun":
        p, v = p - np.asarray(pvh["p"]), v - np.asarray(pvh["v"])
    return p * AU_M, v * _AU_PER_DAY_TO_MPS


def sun_position_geo_m(t_j2000_s) -> np.ndarray:
    """Geocentric position of the Sun's centre, m (``erfa.epv00``: minus the heliocentric
    Earth): scalar -> (3,), (N,) -> (N, 3)."""
    return -earth_position_helio_m(t_j2000_s)


def moon_position_geo_m(t_j2000_s) -> np.ndarray:
    """Geocentric position of the Moon's centre, m (``erfa.moon98``): scalar -> (3,),
    (N,) -> (N, 3)."""
    erfa = _erfa()
    pv = _quiet(erfa.moon98, _J2000_JD, _jd2(t_j2000_s))
    return np.asarray(pv["p"]) * AU_M


def moon_position_helio_m(t_j2000_s) -> np.ndarray:
    """Heliocentric position of the Moon's centre, m: the Earth (``epv00``) plus the
    geocentric Moon (``erfa.moon98``)."""
    return earth_position_helio_m(t_j2000_s) + moon_position_geo_m(t_j2000_s)


def planet_state_helio(number: int, t_j2000_s) -> tuple[np.ndarray, np.ndarray]:
    """Heliocentric position (m) and velocity (m/s) of planet ``number`` of ``erfa.plan94``
    (1 Mercury, 2 Venus, 3 Earth-Moon barycentre, 4 Mars, ... 8 Neptune)."""
    erfa = _erfa()
    pv = _quiet(erfa.plan94, _J2000_JD, _jd2(t_j2000_s), int(number))
    return np.asarray(pv["p"]) * AU_M, np.asarray(pv["v"]) * _AU_PER_DAY_TO_MPS


def third_body_positions_m(t_j2000_s) -> np.ndarray:
    """Heliocentric positions (..., nb, 3), m, of :data:`THIRD_BODIES` at ``t_j2000_s``
    straight from ``plan94`` (the truth integrator's source; the kernels interpolate the
    same numbers from :func:`third_body_table`)."""
    return np.stack([planet_state_helio(n, t_j2000_s)[0] for n in _PLAN94], axis=-2)


@functools.lru_cache(maxsize=1)
def third_body_table() -> np.ndarray:
    """The kernels' table (n + 1, 6 nb): row 0 the header ``[t_first_s, step_s, nb,
    mu_1 .. mu_nb, 0...]``, then one row per node, body j's ``[r (3) m, v (3) m/s]`` in
    columns 6j..6j+5 (nodes every :data:`TABLE_STEP_S` from :data:`TABLE_START_J2000_S` to
    :data:`TABLE_STOP_J2000_S`). Built once per process (~0.5 s, 9 MB)."""
    h = TABLE_STEP_S
    t = np.arange(TABLE_START_J2000_S - 2.0 * h, TABLE_STOP_J2000_S + 2.5 * h, h)  # 2 nodes margin
    nb = len(_PLAN94)
    tab = np.zeros((len(t) - 3, 6 * nb))
    tab[0, :3] = (t[2], h, nb)
    tab[0, 3:3 + nb] = MU_THIRD_M3_S2
    for j, n in enumerate(_PLAN94):
        # plan94's own velocities are not the derivative of its positions (tens of km of
        # Hermite error for Saturn): the five-point derivative of the positions instead
        # (error h^4 |r^(5)| / 30 < 1e-3 m/s for Venus at h = 1 day)
        r = planet_state_helio(n, t)[0]
        tab[1:, 6 * j:6 * j + 3] = r[2:-2]
        tab[1:, 6 * j + 3:6 * j + 6] = (r[:-4] - 8.0 * r[1:-3] + 8.0 * r[3:-1] - r[4:]) / (12.0 * h)
    tab.setflags(write=False)
    return tab


def check_table_span(t_first_j2000_s: float, t_last_j2000_s: float) -> bool:
    """Whether the interval lies inside the table's span (the kernels clamp outside it)."""
    return TABLE_START_J2000_S <= t_first_j2000_s and t_last_j2000_s <= TABLE_STOP_J2000_S


@njit(cache=True)
def table_positions_nb(eph, t, out):
    """Positions of the table's bodies at ``t`` (s since J2000) into ``out`` (nb, 3), m:
    cubic Hermite interpolation between the two nodes around ``t`` from their positions
    and velocities (clamped to the table's span)."""
    t0 = eph[0, 0]
    h = eph[0, 1]
    nb = int(eph[0, 2])
    n = eph.shape[0] - 1
    s = (t - t0) / h
    i = int(np.floor(s))
    if i < 0:
        i = 0
    if i > n - 2:
        i = n - 2
    u = s - i
    u2 = u * u
    u3 = u2 * u
    h00 = 2.0 * u3 - 3.0 * u2 + 1.0
    h10 = (u3 - 2.0 * u2 + u) * h
    h01 = -2.0 * u3 + 3.0 * u2
    h11 = (u3 - u2) * h
    a = eph[1 + i]
    b = eph[2 + i]
    for j in range(nb):
        c = 6 * j
        for m in range(3):
            out[j, m] = h00 * a[c + m] + h10 * a[c + 3 + m] + h01 * b[c + m] + h11 * b[c + 3 + m]
