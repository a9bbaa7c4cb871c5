"""Tests of factors.jpl_ephemeris (DE421 through the ``de421`` package): the table against
jplephem's own evaluation of the same file, the numba kernel against the numpy route, the
velocities against the positions, a published Moon (Meeus Example 47.a), the known
difference from the analytic series of factors.ephemeris, and the Moon's pole (IAU 2009)."""

import math

import numpy as np
import pytest

from factors.ephemeris import moon_position_eci_m, sun_position_eci_m
from factors.errors import EphemerisSpanError
from factors.jpl_ephemeris import (
    DE421_SPAN_J2000_S, EMRAT, check_de421_span, de421_table, moon_pole_eci, moon_pole_nb,
    moon_position_de421_m, moon_state_de421, sun_moon_nb, sun_moon_np, sun_position_de421_m,
    sun_state_de421,
)

DAY_S = 86400.0
YEAR_S = 365.25 * DAY_S


@pytest.fixture(scope="module")
def jpl():
    from jplephem.ephem import Ephemeris
    import de421

    return Ephemeris(de421)


def test_span_and_constants_are_the_files(jpl):
    tab = de421_table()
    assert tab[0, 0] == DE421_SPAN_J2000_S[0] == (jpl.jalpha - 2451545.0) * DAY_S
    assert tab[0, 1] == DE421_SPAN_J2000_S[1] == (jpl.jomega - 2451545.0) * DAY_S
    assert EMRAT == jpl.EMRAT
    assert not tab.flags.writeable
    # record lengths 16 d (Sun), 4 d (Moon), 16 d (EMB)
    assert tuple(tab[1, 3::4][:3] / DAY_S) == (16.0, 4.0, 16.0)


def test_against_jplephem_over_the_span(jpl):
    """Same file, two evaluations: the Moon to 1 mm, the Sun to 3 cm (jplephem's times are
    days, whose rounding, ~1e-11 d, moves the barycentric Sun and EMB by ~2 cm), velocities to
    1e-8 m/s."""
    t = np.linspace(DE421_SPAN_J2000_S[0] + 1.0, DE421_SPAN_J2000_S[1] - 1.0, 3001)
    d = t / DAY_S

    def pv(name):
        p, v = jpl.position_and_velocity(name, 2451545.0, d)
        return p.T * 1e3, v.T * 1e3 / DAY_S

    (pm, vm), (ps, vs), (pb, vb) = pv("moon"), pv("sun"), pv("earthmoon")
    k = 1.0 / (1.0 + jpl.EMRAT)
    (s, v_s), (m, v_m) = sun_moon_np(de421_table(), t, derivative=True)
    assert np.abs(m - pm).max() < 2e-3
    assert np.abs(s - (ps - pb + k * pm)).max() < 0.05
    assert np.abs(v_m - vm).max() < 1e-8
    assert np.abs(v_s - (vs - vb + k * vm)).max() < 1e-8
    # the public calls are the same numbers
    assert np.array_equal(moon_position_de421_m(t), m)
    assert np.array_equal(sun_position_de421_m(t), s)


def test_kernel_equals_numpy_route():
    tab = de421_table()
    t = np.random.default_rng(3).uniform(-50 * YEAR_S, 50 * YEAR_S, 200)
    s, m = sun_moon_np(tab, t)
    sn, mn = np.empty(3), np.empty(3)
    for k in range(len(t)):
        sun_moon_nb(tab, t[k], sn, mn)
        assert np.abs(sn - s[k]).max() <= 1e-6 and np.abs(mn - m[k]).max() <= 1e-6


def test_velocity_is_the_derivative_of_the_position_across_records():
    """Central differences (h = 10 s) across record boundaries (every 4 d for the Moon):
    the Chebyshev derivative agrees to 1e-6 m/s, and the position is continuous at a record
    boundary to 1 mm."""
    t = np.arange(0.0, 40 * DAY_S, 0.37 * DAY_S) + 1234.5
    h = 10.0
    r, v = moon_state_de421(t)
    fd = (moon_position_de421_m(t + h) - moon_position_de421_m(t - h)) / (2 * h)
    assert np.abs(fd - v).max() < 1e-6
    rs, vs = sun_state_de421(t)
    fd = (sun_position_de421_m(t + h) - sun_position_de421_m(t - h)) / (2 * h)
    assert np.abs(fd - vs).max() < 1e-5
    b = (2451545.0 - 2414992.5) % 4.0   # a Moon record boundary, days after J2000
    tb = (4.0 - b) * DAY_S
    jump = (moon_position_de421_m(tb + 1e-6) - moon_position_de421_m(tb - 1e-6)
            - 2e-6 * moon_state_de421(tb)[1])
    assert np.linalg.norm(jump) < 1e-3


def test_moon_meeus_example_47a():
    """1992 April 12, 0h TD: Meeus (Astronomical Algorithms, 2nd ed., Example 47.a, his
    abridged ELP-2000/82) gives the geometric longitude 133.162655 deg (mean equinox of
    date), latitude -3.229126 deg, distance 368,409.7 km. DE421: 0.0004 deg, 0.0006 deg and
    4.2 km from it (the abridged series' own error: Meeus quotes ~10" and a few km)."""
    jd = 2448724.5
    r = moon_position_de421_m((jd - 2451545.0) * DAY_S)
    eps = math.radians(23.43929111)
    x, y, z = r
    ye, ze = math.cos(eps) * y + math.sin(eps) * z, -math.sin(eps) * y + math.cos(eps) * z
    T = (jd - 2451545.0) / 36525.0
    lam = math.degrees(math.atan2(ye, x)) + (5029.0966 * T + 1.11113 * T * T) / 3600.0
    beta = math.degrees(math.asin(ze / np.linalg.norm(r)))
    assert abs(lam % 360.0 - 133.162655) < 0.002
    assert abs(beta + 3.229126) < 0.002
    assert abs(np.linalg.norm(r) / 1e3 - 368409.7) < 6.0


def test_known_difference_from_the_analytic_series():
    """The analytic series (M&G sec. 3.3.2) against DE421 over 2000-2040: the Moon off by
    ~180 km (median) and up to ~510 km, ~0.015 deg (up to 0.08 deg) in direction; the Sun
    by ~10,000 km (up to 26,000 km: 1.7e-4 of its distance). These are why the cislunar
    model reads DE421."""
    t = np.linspace(0.0, 40 * YEAR_S, 4001)
    dm = np.linalg.norm(moon_position_de421_m(t) - moon_position_eci_m(t), axis=1)
    assert 100e3 < np.median(dm) < 300e3 and dm.max() < 600e3
    ds = np.linalg.norm(sun_position_de421_m(t) - sun_position_eci_m(t), axis=1)
    assert 3e6 < np.median(ds) < 2e7 and ds.max() < 3e7
    a, b = moon_position_de421_m(t), moon_position_eci_m(t)
    ang = np.degrees(np.arccos(np.clip(np.sum(a * b, 1) / np.linalg.norm(a, axis=1)
                                       / np.linalg.norm(b, axis=1), -1.0, 1.0)))
    assert ang.max() < 0.1


def test_span_is_checked():
    check_de421_span([0.0, 100 * YEAR_S])
    with pytest.raises(EphemerisSpanError, match="DE421"):
        moon_position_de421_m(201 * YEAR_S)
    with pytest.raises(EphemerisSpanError, match="DE421"):
        sun_state_de421(np.array([0.0, -101 * YEAR_S]))


def test_moon_pole():
    """IAU 2009 (Archinal et al. 2011): at J2000, alpha_0 = 269.9949 - 3.8787 sin 125.045 deg
    - ... = 266.86 deg, delta_0 = 65.64 deg; unit vectors; the kernel = the numpy form; the
    pole precesses about the ecliptic pole once in 18.6 years (E1), staying 1.5 deg from
    the ecliptic pole."""
    p = moon_pole_eci(0.0)
    a, d = math.degrees(math.atan2(p[1], p[0])) % 360.0, math.degrees(math.asin(p[2]))
    assert abs(a - 266.857) < 0.01 and abs(d - 65.641) < 0.01
    t = np.linspace(0.0, 18.6 * YEAR_S, 500)
    P = moon_pole_eci(t)
    assert np.allclose(np.linalg.norm(P, axis=1), 1.0, atol=1e-14)
    out = np.empty(3)
    for k in range(0, 500, 25):
        moon_pole_nb(t[k], out)
        assert np.abs(out - P[k]).max() < 1e-14
    eps = math.radians(23.43929111)
    k_ecl = np.array([0.0, -math.sin(eps), math.cos(eps)])
    tilt = np.degrees(np.arccos(P @ k_ecl))
    assert 1.4 < tilt.min() and tilt.max() < 1.7
