"""Time handling: UTC epochs as ``numpy.datetime64[ns]``, seconds from a pass epoch, J2000 seconds.

Conventions (CONTRIBUTING.md): ``t_s`` is seconds from the pass epoch ``epoch0`` (a
``numpy.datetime64[ns]`` in UTC); files carry ISO-8601 UTC strings ending in ``Z``.

``j2000_seconds`` gives seconds since J2000.0 = 2000-01-01T12:00:00 TT, the argument of the
Sun/Moon ephemeris (``factors.ephemeris``). It uses the approximation TT = UTC + 69.184 s
(TAI - UTC = 37 s, valid since 2017-01-01, plus TT - TAI = 32.184 s) for every date; before
2017 the error is the number of leap seconds since (at most ~5 s for dates after 1999),
which moves the Moon by < 5 km and the Sun by < 150 km along their orbits — far below the
accuracy of the low-precision ephemeris it feeds.
"""

from __future__ import annotations

import re

import numpy as np

__all__ = [
    "TT_MINUS_UTC_S", "J2000_TT", "parse_utc", "format_utc", "seconds_since", "add_seconds",
    "j2000_seconds",
]

TT_MINUS_UTC_S = 69.184
"""TT - UTC used everywhere, s (37 leap seconds + 32.184 s; exact since 2017-01-01)."""

J2000_TT = np.datetime64("2000-01-01T12:00:00", "ns")
"""The J2000.0 epoch, read on the TT scale."""

_ISO_RE = re.compile(
    r"^\s*(\d{4})-(\d{2})-(\d{2})[T ](\d{2}):(\d{2})(?::(\d{2})(?:\.(\d{1,9}))?)?"
    r"\s*(Z|z|\+00:?00|UTC)?\s*$"
)


def parse_utc(s: str) -> np.datetime64:
    """Parse an ISO-8601 UTC string into ``numpy.datetime64[ns]``.

    Accepted: ``YYYY-MM-DDTHH:MM[:SS[.fffffffff]]`` followed by ``Z`` (or ``+00:00``);
    a space may replace ``T``; up to 9 fraction digits (nanoseconds). A missing zone
    designator is read as UTC. Anything else (other offsets, invalid dates, leap second
    60) raises ``ValueError`` quoting the text.
    """
    if not isinstance(s, str):
        raise ValueError(f"expected an ISO-8601 UTC string, found {s!r}")
    m = _ISO_RE.match(s)
    if m is None:
        raise ValueError(f"not an ISO-8601 UTC time (YYYY-MM-DDTHH:MM:SS[.f]Z): {s!r}")
    year, month, day, hh, mm, ss, frac, _zone = m.groups()
    ss = ss or "00"
    text = f"{year}-{month}-{day}T{hh}:{mm}:{ss}"
    try:
        if int(hh) > 23 or int(mm) > 59 or int(ss) > 59:
            raise ValueError
        t = np.datetime64(text, "ns")
    except ValueError:
        raise ValueError(f"not a valid UTC date/time: {s!r}") from None
    if frac:
        t = t + np.timedelta64(int(frac.ljust(9, "0")), "ns")
    return t


def format_utc(t64) -> str | list[str]:
    """Format a ``datetime64`` (UTC) as ``'YYYY-MM-DDTHH:MM:SS.ffffffZ'`` (rounded to 1 µs).

    An array gives a list of strings.
    """
    a = np.asarray(t64).astype("datetime64[ns]")
    if a.ndim:
        return [format_utc(x) for x in a.ravel()]
    ns = a.astype(np.int64)
    us = (int(ns) + 500) // 1000  # round half up to the microsecond
    t_us = np.datetime64(us, "us")
    return np.datetime_as_string(t_us, unit="us") + "Z"


def seconds_since(t64_array, epoch0) -> np.ndarray:
    """Seconds (float64) from ``epoch0`` to each ``datetime64`` in ``t64_array``.

    The difference is taken exactly in integer nanoseconds, then converted.
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
    """Seconds since J2000.0 (2000-01-01T12:00:00 TT) of UTC time(s) ``t64``.

    TT is approximated as UTC + 69.184 s for all dates (see the module docstring).
    Scalar in, float out; array in, float array out.
    """
    t = np.asarray(t64).astype("datetime64[ns]")
    out = (t - J2000_TT).astype(np.int64) / 1e9 + TT_MINUS_UTC_S
    return float(out) if out.ndim == 0 else out
