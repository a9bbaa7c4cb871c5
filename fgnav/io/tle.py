"""Two-line element sets (TLE), the NORAD format SGP4 reads (Hoots & Roehrich 1980,
Spacetrack Report No. 3; Vallado et al. 2006, "Revisiting Spacetrack Report #3", app. A).

Read (``read_tle``): one element set, as its two 69-column lines, optionally after a name
line (the three-line form CelesTrak writes); blank lines ignored. Each line is checked:
its line number in column 1, the same catalogue number (columns 3-7) on both, the
modulo-10 checksum in column 69 (digits count their value, ``-`` counts 1), and every
field a number where the format has one. Anything else (a second element set, a short
line) is an :class:`~fgnav.errors.InputFormatError` naming the file, the line and the field.
"""

from __future__ import annotations

import datetime as _dt
import re

from fgnav.errors import InputFormatError
from fgnav.io.omm import MeanElements
from fgnav.io.text import read_utf8_text
from fgnav.time import parse_utc

__all__ = ["read_tle", "tle_checksum", "looks_like_tle"]

_FLOAT_RE = re.compile(r"^[+-]?(?:\d+\.?\d*|\.\d+)$")
_EXP_RE = re.compile(r"^([+-]?)(\d{5})([+-]\d)$")   # " 12345-3" = 0.12345e-3 (assumed point)


def tle_checksum(line: str) -> int:
    """Modulo-10 sum of columns 1-68: each digit its value, each ``-`` one."""
    return sum(int(c) if c.isdigit() else (c == "-") for c in line[:68]) % 10


def looks_like_tle(text: str) -> bool:
    """True if the last two non-blank lines of ``text`` begin as TLE lines 1 and 2."""
    lines = [s.rstrip() for s in text.splitlines() if s.strip()]
    return len(lines) in (2, 3) and lines[-2].startswith("1 ") and lines[-1].startswith("2 ")


def _field(path, lineno, line, c0, c1, name, kind="float"):
    """Columns c0..c1 (1-based, inclusive) of a TLE line as a number."""
    s = line[c0 - 1:c1].strip()
    where = f"{name} (columns {c0}-{c1})"
    if kind == "int":
        if not s.isdigit():
            raise InputFormatError(path, lineno, where, "digits", s)
        return int(s)
    if kind == "exp":   # assumed decimal point and a signed exponent digit
        m = _EXP_RE.match(s.replace(" ", "") if s else s) if s else None
        if s in ("", "0", "00000-0", "00000+0", "+00000-0", "-00000-0"):
            return 0.0
        if m is None:
            raise InputFormatError(path, lineno, where, "a TLE exponent field such as "
                                   "' 12345-3' (= 0.12345e-3)", s)
        return float(f"{m.group(1)}0.{m.group(2)}e{m.group(3)}")
    if kind == "point":   # assumed leading decimal point
        if not s.isdigit():
            raise InputFormatError(path, lineno, where, "digits (an assumed leading decimal "
                                   "point)", s)
        return float("0." + s)
    if not _FLOAT_RE.match(s):
        raise InputFormatError(path, lineno, where, "a decimal number", s)
    return float(s)


def read_tle(path) -> MeanElements:
    """Read one TLE (two or three lines) into :class:`~fgnav.io.omm.MeanElements`."""
    text = read_utf8_text(path, "a TLE")
    rows = [(i, s.rstrip()) for i, s in enumerate(text.splitlines(), start=1) if s.strip()]
    if len(rows) not in (2, 3):
        line = rows[3][0] if len(rows) > 3 else (rows[-1][0] if rows else 1)
        raise InputFormatError(path, line, None, "one element set: two TLE lines, optionally "
                               "after a name line", f"{len(rows)} non-blank lines")
    name = rows[0][1].strip() if len(rows) == 3 else ""
    if name.startswith("0 "):
        name = name[2:].strip()
    (n1, l1), (n2, l2) = rows[-2], rows[-1]
    for n, line, digit in ((n1, l1, "1"), (n2, l2, "2")):
        if len(line) != 69:
            raise InputFormatError(path, n, None, f"a TLE line {digit} of 69 columns",
                                   f"{len(line)} columns")
        if line[0] != digit or line[1] != " ":
            raise InputFormatError(path, n, "line number (column 1)", f"'{digit} '", line[:2])
        if not line[68].isdigit() or int(line[68]) != tle_checksum(line):
            raise InputFormatError(path, n, "checksum (column 69)",
                                   f"{tle_checksum(line)} (modulo-10 sum of columns 1-68)",
                                   line[68])
    sat1 = _field(path, n1, l1, 3, 7, "catalogue number", "int")
    sat2 = _field(path, n2, l2, 3, 7, "catalogue number", "int")
    if sat1 != sat2:
        raise InputFormatError(path, n2, "catalogue number (columns 3-7)",
                               f"{sat1}, the number of line 1", sat2)
    yy = _field(path, n1, l1, 19, 20, "epoch year", "int")
    day = _field(path, n1, l1, 21, 32, "epoch day of year")
    year = 1900 + yy if yy >= 57 else 2000 + yy
    if not 1.0 <= day < 367.0:
        raise InputFormatError(path, n1, "epoch day of year (columns 21-32)", "a day of the "
                               "year in [1, 367)", l1[20:32].strip())
    label = _dt.datetime(year, 1, 1) + _dt.timedelta(days=day - 1.0)
    ndot = _field(path, n1, l1, 34, 43, "first derivative of mean motion / 2")
    nddot = _field(path, n1, l1, 45, 52, "second derivative of mean motion / 6", "exp")
    bstar = _field(path, n1, l1, 54, 61, "BSTAR drag term", "exp")
    return MeanElements(
        epoch=parse_utc(label.strftime("%Y-%m-%dT%H:%M:%S.%fZ")),
        n_rev_day=_field(path, n2, l2, 53, 63, "mean motion"),
        e=_field(path, n2, l2, 27, 33, "eccentricity", "point"),
        i_deg=_field(path, n2, l2, 9, 16, "inclination"),
        raan_deg=_field(path, n2, l2, 18, 25, "right ascension of the node"),
        argp_deg=_field(path, n2, l2, 35, 42, "argument of perigee"),
        M_deg=_field(path, n2, l2, 44, 51, "mean anomaly"),
        bstar=bstar, ndot=ndot, nddot=nddot, satnum=sat1, path=str(path), line=n1,
        name=name)
