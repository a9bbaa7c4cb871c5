"""Time handling: UTC epochs, seconds from a pass epoch, J2000 seconds, leap seconds.

Conventions (CONTRIBUTING.md): ``t_s`` is seconds from the pass epoch ``epoch0``; files carry
ISO-8601 UTC strings ending in ``Z``.

Time scale of the ``numpy.datetime64[ns]`` values
--------------------------------------------------
Every epoch inside fgnav is a ``numpy.datetime64[ns]`` counting SI seconds on a *continuous*
scale, TAI - 37 s. Since 2017-01-01 (TAI - UTC = 37 s, the last leap second being
2016-12-31T23:59:60) and until the next leap second (none announced by the IERS), it reads
exactly as the UTC label; before it, the value differs from the UTC label by
``(TAI - UTC) - 37 s``. UTC strings are mapped to it and back only by :func:`parse_utc` and
:func:`format_utc`, with the table of leap seconds :data:`LEAP_SECONDS` (IERS Bulletin C,
1972-2017), so that

* differences of epochs (``seconds_since``) are elapsed SI seconds, continuous across a leap
  second: 2016-12-31T23:59:59Z -> 2017-01-01T00:00:01Z is 3 s;
* a time inside a leap second (``2016-12-31T23:59:60.5Z``) is a distinct instant and is
  written back as ``23:59:60.5``, never merged with 00:00:00 of the next day;
* ``23:59:60`` on a day that did not end with a leap second is rejected.

Before 1972-01-01, UTC had fractional steps and a rate offset; this module reads those
dates with TAI - UTC = 10 s (the 1972 value), an error below 10 s, not modelled.

``j2000_seconds`` gives seconds since J2000.0 = 2000-01-01T12:00:00 TT, the argument of the
Sun/Moon ephemeris (``factors.ephemeris``): TT = TAI + 32.184 s = (TAI - 37 s) + 69.184 s,
exact on this scale for every date since 1972 (the leap-second table supplies TAI - UTC).

Source: IERS Bulletin C (Earth Orientation Center, Paris Observatory), table of
TAI - UTC since 1972; Bulletin C 72 (2026) announces no leap second.
"""

from __future__ import annotations

import bisect
import re

import numpy as np

__all__ = [
    "TT_MINUS_UTC_S", "J2000_TT", "LEAP_SECONDS", "UtcRangeError", "parse_utc", "format_utc",
    "seconds_since", "add_seconds", "j2000_seconds", "tai_minus_utc_s", "era_shift_ns",
]

TT_MINUS_UTC_S = 69.184
"""TT - (TAI - 37 s) = 37 s + 32.184 s: TT minus the internal scale, s (equal to TT - UTC
since 2017-01-01)."""

J2000_TT = np.datetime64("2000-01-01T12:00:00", "ns")
"""The J2000.0 epoch, read on the TT scale."""

LEAP_SECONDS = (
    ("1972-01-01", 10), ("1972-07-01", 11), ("1973-01-01", 12), ("1974-01-01", 13),
    ("1975-01-01", 14), ("1976-01-01", 15), ("1977-01-01", 16), ("1978-01-01", 17),
    ("1979-01-01", 18), ("1980-01-01", 19), ("1981-07-01", 20), ("1982-07-01", 21),
    ("1983-07-01", 22), ("1985-07-01", 23), ("1988-01-01", 24), ("1990-01-01", 25),
    ("1991-01-01", 26), ("1992-07-01", 27), ("1993-07-01", 28), ("1994-07-01", 29),
    ("1996-01-01", 30), ("1997-07-01", 31), ("1999-01-01", 32), ("2006-01-01", 33),
    ("2009-01-01", 34), ("2012-07-01", 35), ("2015-07-01", 36), ("2017-01-01", 37),
)
"""(UTC date, TAI - UTC in s from 00:00:00 of that date). Every entry after the first follows a
positive leap second ``23:59:60`` at the end of the previous day (IERS Bulletin C)."""

_SCALE_OFFSET_S = 37            # internal = TAI - 37 s
_PRE_1972_S = 10                # TAI - UTC used before 1972-01-01
_NS = 10**9
_LABEL_NS = [int(np.datetime64(d, "ns").astype(np.int64)) for d, _ in LEAP_SECONDS]
_OFFSET_S = [off for _, off in LEAP_SECONDS]
# internal instant at which each era starts (its 00:00:00 UTC)
_START_NS = [lab + (off - _SCALE_OFFSET_S) * _NS for lab, off in zip(_LABEL_NS, _OFFSET_S)]

_ISO_RE = re.compile(
    r"^\s*(\d{4})-(\d{2})-(\d{2})[T ](\d{2}):(\d{2})(?::(\d{2})(?:\.(\d{1,9}))?)?"
    r"\s*(Z|z|\+00:?00|UTC)?\s*$"
)


class UtcRangeError(ValueError):
    """A well-formed UTC time outside the years 1678..2261 (the range of ``datetime64[ns]``)."""


def tai_minus_utc_s(label_ns: int) -> int:
    """TAI - UTC (s) in force at the UTC label ``label_ns`` (ns of the naive calendar time)."""
    k = bisect.bisect_right(_LABEL_NS, label_ns) - 1
    return _OFFSET_S[k] if k >= 0 else _PRE_1972_S


def parse_utc(s: str) -> np.datetime64:
    """Parse an ISO-8601 UTC string into ``numpy.datetime64[ns]`` on the scale of this module.

    Accepted: ``YYYY-MM-DDTHH:MM[:SS[.fffffffff]]`` followed by ``Z`` (or ``+00:00``);
    a space may replace ``T``; up to 9 fraction digits (nanoseconds). A missing zone
    designator is read as UTC. Seconds ``60`` are accepted at ``23:59:60`` of a day ending
    with a leap second (:data:`LEAP_SECONDS`). Anything else (other offsets, invalid dates,
    ``:60`` on other days) raises ``ValueError`` quoting the text; years outside 1678..2261
    raise :class:`UtcRangeError`.
    """
    if not isinstance(s, str):
        raise ValueError(f"expected an ISO-8601 UTC string, found {s!r}")
    m = _ISO_RE.match(s)
    if m is None:
        raise ValueError(f"not an ISO-8601 UTC time (YYYY-MM-DDTHH:MM:SS[.f]Z): {s!r}")
    year, month, day, hh, mm, ss, frac, _zone = m.groups()
    ss = ss or "00"
    if not 1678 <= int(year) <= 2261:
        raise UtcRangeError(f"a UTC time within the years 1678..2261 is expected: {s!r}")
    leap = int(ss) == 60
    try:
        if int(hh) > 23 or int(mm) > 59 or int(ss) > 60 or (leap and (hh, mm) != ("23", "59")):
            raise ValueError
        label = np.datetime64(f"{year}-{month}-{day}T{hh}:{mm}:{'59' if leap else ss}", "ns")
    except ValueError:
        raise ValueError(f"not a valid UTC date/time: {s!r}") from None
    ns = int(label.astype(np.int64)) + (int(frac.ljust(9, "0")) if frac else 0)
    if leap:
        ns += _NS   # the naive reading: 00:00:00.f of the next day
        k = bisect.bisect_left(_LABEL_NS, ns - (ns % (86400 * _NS)))
        if k == 0 or k >= len(_LABEL_NS) or _LABEL_NS[k] != ns - ns % (86400 * _NS):
            raise ValueError(f"not a valid UTC date/time: {s!r} (second 60 exists only at the "
                             "end of a day with a leap second, e.g. 2016-12-31T23:59:60Z)")
        off = _OFFSET_S[k] - 1   # TAI - UTC during the inserted second
    else:
        off = tai_minus_utc_s(ns)
    return np.datetime64(ns + (off - _SCALE_OFFSET_S) * _NS, "ns")


_START_ARR = np.array(_START_NS, dtype=np.int64)
_SHIFT_ARR = np.array([_PRE_1972_S] + _OFFSET_S, dtype=np.int64) - _SCALE_OFFSET_S  # by era


def _labels(ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Internal ns (int64 array) -> (naive UTC label ns, inside a leap second). In a leap
    second the label is that of 23:59:59.f, to be printed as 23:59:60.f."""
    k = np.searchsorted(_START_ARR, ns, side="right")          # era index + 1
    label = ns - _SHIFT_ARR[k] * _NS
    nxt = np.minimum(k, len(_START_ARR) - 1)
    leap = (k >= 1) & (k < len(_START_ARR)) & (ns >= _START_ARR[nxt] - _NS)
    return np.where(leap, label - _NS, label), leap


def format_utc(t64, unit: str = "us") -> str | list[str]:
    """Format a ``datetime64`` of this module's scale as ``'YYYY-MM-DDTHH:MM:SS.ffffffZ'``.

    ``unit="us"`` rounds to 1 µs (half up); ``unit="ns"`` prints 9 digits. An instant inside
    a leap second prints as ``23:59:60.f``. An array gives a list of strings.
    """
    if unit not in ("us", "ns"):
        raise ValueError(f"unit must be 'us' or 'ns', found {unit!r}")
    a = np.asarray(t64).astype("datetime64[ns]")
    if a.ndim == 0:  # scalar fast path (write_log, OEM lines): bisect on Python ints
        ns = int(a.astype(np.int64))
        if unit == "us":
            ns = (ns + 500) // 1000 * 1000
        k = bisect.bisect_right(_START_NS, ns)
        lab = ns - int(_SHIFT_ARR[k]) * _NS
        if 1 <= k < len(_START_NS) and ns >= _START_NS[k] - _NS:
            t = np.datetime_as_string(np.datetime64(lab - _NS, "ns"), unit=unit)
            return t[:17] + "60" + t[19:] + "Z"
        return np.datetime_as_string(np.datetime64(lab, "ns"), unit=unit) + "Z"
    ns = a.ravel().astype(np.int64)
    if unit == "us":
        ns = (ns + 500) // 1000 * 1000  # round half up to the microsecond
    lab, leap = _labels(ns)
    text = np.datetime_as_string(lab.astype("datetime64[ns]"), unit=unit)
    return [t[:17] + "60" + t[19:] + "Z" if lp else t + "Z" for t, lp in zip(text.tolist(), leap)]


def seconds_since(t64_array, epoch0) -> np.ndarray:
    """Seconds (float64) from ``epoch0`` to each ``datetime64`` in ``t64_array``.

    The difference is taken exactly in integer nanoseconds, then converted; elapsed SI
    seconds, leap seconds included (see the module docstring).
    """
    t = np.asarray(t64_array).astype("datetime64[ns]")
    e = np.datetime64(epoch0, "ns")
    return (t - e).astype(np.int64) / 1e9


def add_seconds(epoch0, t_s) -> np.ndarray:
    """``epoch0 + t_s`` as ``datetime64[ns]`` (``t_s`` in s, scalar or array; rounded to 1 ns)."""
    e = np.datetime64(epoch0, "ns")
    dt_ns = np.rint(np.asarray(t_s, dtype=float) * 1e9).astype(np.int64)
    return e + dt_ns.astype("timedelta64[ns]")


def j2000_seconds(t64):
    """Seconds since J2000.0 (2000-01-01T12:00:00 TT) of time(s) ``t64`` (this module's scale).

    TT = internal + 69.184 s, exact since 1972 (module docstring).
    Scalar in, float out; array in, float array out.
    """
    t = np.asarray(t64).astype("datetime64[ns]")
    out = (t - J2000_TT).astype(np.int64) / 1e9 + TT_MINUS_UTC_S
    return float(out) if out.ndim == 0 else out


def era_shift_ns(label_ns: np.ndarray) -> np.ndarray:
    """(TAI - UTC in force at each naive UTC label - 37 s) in ns, as :func:`parse_utc` adds it
    (outside a leap second): the vectorised form the log reader uses for many rows at once."""
    k = np.searchsorted(np.array(_LABEL_NS, dtype=np.int64), label_ns, side="right") - 1
    off = np.where(k >= 0, np.array(_OFFSET_S, dtype=np.int64)[np.maximum(k, 0)], _PRE_1972_S)
    return (off - _SCALE_OFFSET_S) * 10**9
