"""Tests of factors.ephemeris (Montenbruck & Gill sec. 3.3.2 low-precision Sun and Moon) against
published values: Meeus, *Astronomical Algorithms* (2nd ed.) Examples 25.a (Sun) and 47.a (Moon),
the 2000 March equinox and the 2000 perihelion/aphelion (USNO), and the range of lunar
distances (Meeus ch. 50: perigee >= 356,375 km, apogee <= 406,720 km in 1500-2500)."""

import math

import numpy as np
import pytest

from factors.constants import AU_M
from factors.ephemeris import (
    OBLIQUITY_J2000_RAD, moon_position_eci_m, moon_position_eci_m_nb, sun_position_eci_m,
    sun_position_eci_m_nb,
)
from fgnav.time import j2000_seconds, parse_utc

DAY_S = 86400.0


def _ecliptic_of_date(r_eci, jd_tt):
    """(longitude deg referred to the mean equinox of date, latitude deg, distance m).

    EME2000 -> ecliptic J2000 by R_x(eps), then the general precession in longitude
    p = 5029.0966" T + 1.11113" T^2 (Meeus eq. 21.5 / IAU 1976) to the equinox of date.
    """
    c, s = math.cos(OBLIQUITY_J2000_RAD), math.sin(OBLIQUITY_J2000_RAD)
    x, y, z = r_eci
    ye, ze = c * y + s * z, -s * y + c * z
    T = (jd_tt - 2451545.0) / 36525.0
    lam = math.degrees(math.atan2(ye, x)) + (5029.0966 * T + 1.11113 * T * T) / 3600.0
    return lam % 360.0, math.degrees(math.asin(ze / np.linalg.norm(r_eci))), float(np.linalg.norm(r_eci))


def test_sun_meeus_example_25a():
    """1992 Oct 13.0 TD: true geometric longitude 199.90988 deg (mean equinox of date), R = 0.99766 AU."""
    jd = 2448908.5
    lam, beta, d = _ecliptic_of_date(sun_position_eci_m((jd - 2451545.0) * DAY_S), jd)
    assert abs(lam - 199.90988) < 0.01   # measured 0.0006 deg (0.023 without the perigee advance)
    assert beta == 0.0                   # the series neglects the solar latitude (< 1.2")
    assert abs(d / AU_M - 0.99766) < 1e-4


def test_moon_meeus_example_47a():
    """1992 Apr 12.0 TD: lambda = 133.162655 deg, beta = -3.229126 deg, distance 368,409.7 km."""
    jd = 2448724.5
    lam, beta, d = _ecliptic_of_date(moon_position_eci_m((jd - 2451545.0) * DAY_S), jd)
    assert abs(lam - 133.162655) < 0.05  # measured 0.006 deg
    assert abs(beta - (-3.229126)) < 0.05
    assert abs(d / 1e3 - 368409.7) < 300.0  # measured 51 km


def test_sun_at_the_2000_march_equinox():
    """Equinox 2000-03-20 07:35 UTC: the Sun crosses the equator (declination 0)."""
    r = sun_position_eci_m(j2000_seconds(parse_utc("2000-03-20T07:35:00Z")))
    dec = math.degrees(math.asin(r[2] / np.linalg.norm(r)))
    ra = math.degrees(math.atan2(r[1], r[0]))
    assert abs(dec) < 0.02 and abs(ra) < 0.05
    r_day_later = sun_position_eci_m(j2000_seconds(parse_utc("2000-03-21T07:35:00Z")))
    assert r_day_later[2] > 0 > sun_position_eci_m(j2000_seconds(parse_utc("2000-03-19T07:35:00Z")))[2]


@pytest.mark.parametrize("utc, dist_au", [("2000-01-03T05:18:00Z", 0.98332),
                                          ("2000-07-04T00:50:00Z", 1.01674)])
def test_sun_distance_at_perihelion_and_aphelion_2000(utc, dist_au):
    r = sun_position_eci_m(j2000_seconds(parse_utc(utc)))
    assert abs(np.linalg.norm(r) / AU_M - dist_au) < 2e-4


def test_moon_distance_range_over_two_decades():
    t0 = j2000_seconds(parse_utc("2000-01-01T00:00:00Z"))
    t = t0 + np.arange(0.0, 20 * 365.25 * DAY_S, 3600.0)
    d_km = np.linalg.norm(moon_position_eci_m(t), axis=1) / 1e3
    assert 355_000 < d_km.min() < 358_500   # measured 356,604 km
    assert 405_500 < d_km.max() < 407_500   # measured 406,546 km
    # Moon's orbital plane: inclined ~5 deg to the ecliptic -> declination within +-28.7 deg
    r = moon_position_eci_m(t)
    dec = np.degrees(np.arcsin(r[:, 2] / np.linalg.norm(r, axis=1)))
    assert 18.0 < dec.max() < 29.0 and -29.0 < dec.min() < -18.0


def test_scalar_array_and_numba_kernels_agree():
    t = np.array([-1e8, 0.0, 3.156e8, 7.3e8])
    S, M = sun_position_eci_m(t), moon_position_eci_m(t)
    assert S.shape == (4, 3) and M.shape == (4, 3)
    for k in range(4):
        np.testing.assert_array_equal(S[k], sun_position_eci_m(t[k]))
        np.testing.assert_array_equal(S[k], sun_position_eci_m_nb(t[k]))
        np.testing.assert_array_equal(M[k], moon_position_eci_m_nb(t[k]))
    assert sun_position_eci_m(np.zeros((2, 3))).shape == (2, 3, 3)


def test_sun_direction_against_erfa_over_five_decades():
    """The series' Sun against ERFA ``epv00`` (VSOP87 fitted to JPL DE405), 1990-2040: within
    40 arcsec with the perigee's sidereal advance (Standish, JPL approximate elements);
    Montenbruck & Gill's fixed perigee drifted 11.6 arcsec a year (5 arcmin by 2025)."""
    from factors.planets import earth_position_helio_m

    t = np.linspace(-10.0, 40.0, 2001) * 365.25 * DAY_S
    a, b = sun_position_eci_m(t), -earth_position_helio_m(t)
    cos = np.sum(a * b, axis=1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
    err_arcsec = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))) * 3600.0
    assert err_arcsec.max() < 40.0, err_arcsec.max()   # measured 35.4; 488 before
