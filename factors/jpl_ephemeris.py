"""JPL DE421: the Sun and the Moon relative to the Earth (and the Moon's pole), for the
cislunar motion model and the near-body measurement models. Metres, seconds, ICRF axes.

Source: DE421 (Folkner, Williams & Boggs 2009, "The Planetary and Lunar Ephemeris DE 421",
IPN Progress Report 42-178), as the ``de421`` package for ``jplephem`` ships it: per body, a
table of Chebyshev records of equal length over JD 2414992.5-2524624.5 TDB (1899-12-04 to
2200-02-01; the ASCII files' span), each record ``(3, n)`` coefficients in km; the Moon is
geocentric (4-day records, 13 coefficients), the Sun and the Earth-Moon barycentre (EMB)
barycentric (16-day records, 11 and 13). The geocentric Sun is
``Sun - EMB + Moon / (1 + EMRAT)`` (the Earth lies ``Moon / (1 + EMRAT)`` behind the EMB;
EMRAT = 81.30057 from the same file). DE421's stated accuracy for the Moon is metres
(lunar laser ranging) and sub-km for the Earth-Sun distance; the analytic series of
:mod:`factors.ephemeris` are off by km to hundreds of km (tests/test_jpl_ephemeris.py).

Why DE421 here and ERFA for the cruise (``factors.planets``): between the Earth and the
Moon the Moon's position enters the forces at ``mu_moon / d^3`` of a spacecraft 10,000 km
away (1e-5 m/s^2 per km of error) and its direction and light time enter the Moon beacon's
measurements; 20 km (moon98) is 0.1 deg from 10,000 km. DE421 is the smallest JPL
ephemeris with a PyPI package (27 MB of arrays) covering the needed span.

Frame: DE421's axes are the ICRF; the frame bias to EME2000 (23 mas, 43 m at the Moon's
distance) is neglected, as everywhere in fgnav (the star catalogue is ICRS). Time:
``t_j2000_s`` seconds since J2000.0 TDB (TT - TDB < 2 ms: 2 m of the Moon's motion).

The kernels read one table (:func:`de421_table`): row 0 a header, row 1 the series'
bookkeeping, then one row per Chebyshev record ``[x_0..x_n-1, y_0.., z_0..]`` in metres,
lowest degree first. Evaluation (Clenshaw-free recurrence ``T_k = 2 tau T_k-1 - T_k-2``,
``tau`` in [-1, 1] over the record; Newhall 1989, the JPL ephemerides'
Chebyshev form) is in :func:`sun_moon_nb` (numba scalar kernel) and :func:`sun_moon_np`
(numpy, many times at once). The Moon's pole: :func:`moon_pole_nb`, the IAU WGCCRE 2009
rotation model (Archinal et al. 2011, Table 2).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from factors.errors import EphemerisSpanError
from factors.jit import njit

__all__ = [
    "DE421_SPAN_J2000_S", "EMRAT", "de421_table", "check_de421_span", "sun_moon_nb",
    "sun_moon_np", "sun_position_de421_m", "moon_position_de421_m", "moon_state_de421",
    "sun_state_de421", "moon_pole_nb", "moon_pole_eci",
]

_DAY_S = 86400.0
_J2000_JD = 2451545.0
_SERIES = ("sun", "moon", "earthmoon")
_WIDTH = 39          # 3 x 13 coefficients: the widest record
_HEAD = 2            # rows before the first record


@functools.lru_cache(maxsize=1)
def _source():
    """The DE421 arrays (km) and constants, via jplephem's package reader."""
    import de421
    from jplephem.ephem import Ephemeris

    eph = Ephemeris(de421)
    return eph, {name: eph.load(name) for name in _SERIES}


@functools.lru_cache(maxsize=1)
def de421_table() -> np.ndarray:
    """The kernels' table (rows, 39), read-only: row 0 ``[t_first_s, t_last_s, -1,
    1/(1 + EMRAT), 0...]``; row 1, for series s = 0 Sun, 1 Moon, 2 EMB, columns 4s..4s+3
    ``[first row, records, coefficients, record length s]``; then the records, metres."""
    eph, arrays = _source()
    t0 = (eph.jalpha - _J2000_JD) * _DAY_S
    t1 = (eph.jomega - _J2000_JD) * _DAY_S
    rows = sum(a.shape[0] for a in arrays.values())
    tab = np.zeros((_HEAD + rows, _WIDTH))
    tab[0, :4] = (t0, t1, -1.0, 1.0 / (1.0 + eph.EMRAT))
    row = _HEAD
    for s, name in enumerate(_SERIES):
        a = arrays[name]
        n_rec, _, n_coef = a.shape
        tab[1, 4 * s:4 * s + 4] = (row, n_rec, n_coef, (t1 - t0) / n_rec)
        tab[row:row + n_rec, :3 * n_coef] = a.reshape(n_rec, 3 * n_coef) * 1e3
        row += n_rec
    tab.setflags(write=False)
    return tab


def _span() -> tuple[float, float]:
    eph, _ = _source()
    return (eph.jalpha - _J2000_JD) * _DAY_S, (eph.jomega - _J2000_JD) * _DAY_S


DE421_SPAN_J2000_S = (-3158136000.0, 6314068800.0)
"""The span of the ``de421`` package's arrays, s after J2000 TDB (JD 2414992.5 to 2524624.5;
checked against the file in tests/test_jpl_ephemeris.py)."""

EMRAT = 81.3005690699153
"""DE421's Earth/Moon mass ratio (its constant EMRAT)."""


def check_de421_span(t_j2000_s) -> None:
    """:class:`EphemerisSpanError` unless every epoch lies in :data:`DE421_SPAN_J2000_S`."""
    t = np.asarray(t_j2000_s, dtype=float)
    if t.size and not (DE421_SPAN_J2000_S[0] <= t.min() and t.max() <= DE421_SPAN_J2000_S[1]):
        bad = t.min() if t.min() < DE421_SPAN_J2000_S[0] else t.max()
        raise EphemerisSpanError(f"DE421 ephemeris outside its span (1899-12-04 to 2200-02-01): an "
                                 f"epoch {bad / (365.25 * _DAY_S):+.1f} years from J2000")


@njit(cache=True)
def _series_nb(eph, s, t, w, out):
    """Add ``w`` times series ``s``'s position at ``t`` (s after J2000) into ``out`` (3,):
    the record holding ``t`` (clamped to the table), ``tau = 2 (t - t_i)/L - 1``."""
    first = int(eph[1, 4 * s])
    n_rec = int(eph[1, 4 * s + 1])
    n = int(eph[1, 4 * s + 2])
    L = eph[1, 4 * s + 3]
    u = (t - eph[0, 0]) / L
    i = int(math.floor(u))
    if i < 0:
        i = 0
    if i > n_rec - 1:
        i = n_rec - 1
    tau = 2.0 * (t - eph[0, 0] - i * L) / L - 1.0
    c = eph[first + i]
    for m in range(3):
        t0 = 1.0
        t1 = tau
        acc = c[m * n] + c[m * n + 1] * tau
        for k in range(2, n):
            t2 = 2.0 * tau * t1 - t0
            acc += c[m * n + k] * t2
            t0 = t1
            t1 = t2
        out[m] += w * acc


@njit(cache=True)
def sun_moon_nb(eph, t, sun, moon):
    """Geocentric Sun and Moon positions (m, ICRF) at ``t`` (s after J2000 TDB) into ``sun``
    and ``moon`` (3,): Moon = series 1, Sun = series 0 - series 2 + Moon / (1 + EMRAT)."""
    for m in range(3):
        sun[m] = 0.0
        moon[m] = 0.0
    _series_nb(eph, 1, t, 1.0, moon)
    _series_nb(eph, 0, t, 1.0, sun)
    _series_nb(eph, 2, t, -1.0, sun)
    k = eph[0, 3]
    for m in range(3):
        sun[m] += k * moon[m]


def _series_np(eph, s, t, derivative=False):
    """Series ``s`` at every time of ``t`` (N,): (N, 3) positions, m, or with ``derivative``
    also (N, 3) velocities, m/s (d/dt = (2/L) d/dtau; dT_k = 2 T_k-1 + 2 tau dT_k-1 - dT_k-2)."""
    first, n_rec, n, L = eph[1, 4 * s:4 * s + 4]
    first, n_rec, n = int(first), int(n_rec), int(n)
    i = np.clip(np.floor((t - eph[0, 0]) / L).astype(np.int64), 0, n_rec - 1)
    tau = 2.0 * (t - eph[0, 0] - i * L) / L - 1.0
    C = eph[first + i, :3 * n].reshape(len(t), 3, n)
    T = np.empty((n, len(t)))
    T[0] = 1.0
    T[1] = tau
    for k in range(2, n):
        T[k] = 2.0 * tau * T[k - 1] - T[k - 2]
    r = np.einsum("nmk,kn->nm", C, T)
    if not derivative:
        return r
    dT = np.empty_like(T)
    dT[0] = 0.0
    dT[1] = 1.0
    for k in range(2, n):
        dT[k] = 2.0 * T[k - 1] + 2.0 * tau * dT[k - 1] - dT[k - 2]
    return r, np.einsum("nmk,kn->nm", C, dT) * (2.0 / L)


def sun_moon_np(eph, t_j2000_s, derivative=False):
    """:func:`sun_moon_nb` at every time of ``t_j2000_s`` (N,) at once: ``(sun, moon)``, each
    (N, 3) m; with ``derivative`` ``((sun, v_sun), (moon, v_moon))``, velocities m/s."""
    t = np.ascontiguousarray(np.asarray(t_j2000_s, dtype=float).reshape(-1))
    k = eph[0, 3]
    if not derivative:
        moon = _series_np(eph, 1, t)
        return _series_np(eph, 0, t) - _series_np(eph, 2, t) + k * moon, moon
    moon, vm = _series_np(eph, 1, t, True)
    s, vs = _series_np(eph, 0, t, True)
    b, vb = _series_np(eph, 2, t, True)
    return (s - b + k * moon, vs - vb + k * vm), (moon, vm)


def _shaped(t_j2000_s, rows):
    return rows[0] if np.ndim(t_j2000_s) == 0 else rows.reshape(np.shape(t_j2000_s) + (3,))


def sun_position_de421_m(t_j2000_s) -> np.ndarray:
    """Geocentric Sun position, ICRF, m, from DE421: scalar -> (3,), (N,) -> (N, 3)."""
    check_de421_span(t_j2000_s)
    return _shaped(t_j2000_s, sun_moon_np(de421_table(), t_j2000_s)[0])


def moon_position_de421_m(t_j2000_s) -> np.ndarray:
    """Geocentric Moon position, ICRF, m, from DE421: scalar -> (3,), (N,) -> (N, 3)."""
    check_de421_span(t_j2000_s)
    return _shaped(t_j2000_s, sun_moon_np(de421_table(), t_j2000_s)[1])


def moon_state_de421(t_j2000_s) -> tuple[np.ndarray, np.ndarray]:
    """Geocentric Moon position (m) and velocity (m/s), ICRF, from DE421 (the Chebyshev
    series and its derivative): scalar -> (3,) each, (N,) -> (N, 3) each."""
    check_de421_span(t_j2000_s)
    _, (r, v) = sun_moon_np(de421_table(), t_j2000_s, derivative=True)
    return _shaped(t_j2000_s, r), _shaped(t_j2000_s, v)


def sun_state_de421(t_j2000_s) -> tuple[np.ndarray, np.ndarray]:
    """Geocentric Sun position (m) and velocity (m/s), ICRF, from DE421."""
    check_de421_span(t_j2000_s)
    (r, v), _ = sun_moon_np(de421_table(), t_j2000_s, derivative=True)
    return _shaped(t_j2000_s, r), _shaped(t_j2000_s, v)


# The Moon's pole (IAU WGCCRE 2009; Archinal et al. 2011, Table 2): d days and T Julian
# centuries after J2000 TDB; E_i = E_i0 + E_i1 d (deg); alpha_0, delta_0 (deg).
_E = np.array([  # (E_i0, E_i1, alpha_0 sin coefficient, delta_0 cos coefficient)
    (125.045, -0.0529921, -3.8787, 1.5419),    # E1
    (250.089, -0.1059842, -0.1204, 0.0239),    # E2
    (260.008, 13.0120009, 0.0700, -0.0278),    # E3
    (176.625, 13.3407154, -0.0172, 0.0068),    # E4
    (311.589, 26.4057084, 0.0072, -0.0029),    # E6
    (134.963, 13.0649930, 0.0, 0.0009),        # E7
    (15.134, -0.1589763, -0.0052, 0.0008),     # E10
    (25.053, 12.9590088, 0.0043, -0.0009),     # E13
])
_DEG = math.pi / 180.0


@njit(cache=True)
def moon_pole_nb(t, out):
    """The Moon's north pole (unit vector, ICRF) at ``t`` s after J2000 TDB into ``out`` (3,):
    alpha_0 = 269.9949 + 0.0031 T + sum a_i sin E_i, delta_0 = 66.5392 + 0.0130 T +
    sum b_i cos E_i (deg; Archinal et al. 2011, Table 2)."""
    d = t / 86400.0
    T = d / 36525.0
    a = 269.9949 + 0.0031 * T
    b = 66.5392 + 0.0130 * T
    for i in range(_E.shape[0]):
        e = (_E[i, 0] + _E[i, 1] * d) * _DEG
        a += _E[i, 2] * math.sin(e)
        b += _E[i, 3] * math.cos(e)
    a *= _DEG
    b *= _DEG
    cb = math.cos(b)
    out[0] = cb * math.cos(a)
    out[1] = cb * math.sin(a)
    out[2] = math.sin(b)


def moon_pole_eci(t_j2000_s) -> np.ndarray:
    """The Moon's pole (unit vectors, ICRF) at ``t_j2000_s``: scalar -> (3,), (N,) -> (N, 3)
    (:func:`moon_pole_nb`'s equations on arrays)."""
    t = np.asarray(t_j2000_s, dtype=float)
    d = t / 86400.0
    T = d / 36525.0
    a = 269.9949 + 0.0031 * T
    b = 66.5392 + 0.0130 * T
    for e0, e1, sa, cb in _E:
        e = np.deg2rad(e0 + e1 * d)
        a = a + sa * np.sin(e)
        b = b + cb * np.cos(e)
    a, b = np.deg2rad(a), np.deg2rad(b)
    return np.stack([np.cos(b) * np.cos(a), np.cos(b) * np.sin(a), np.sin(b)], axis=-1)
