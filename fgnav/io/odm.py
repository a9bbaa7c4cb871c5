"""What the CCSDS Orbit Data Messages OPM and OMM share (CCSDS 502.0-B-3, "Orbit Data
Messages"): their keyword = value lines (KVN, read with :mod:`fgnav.io.kvn`) or the leaf elements of their XML form as one
list of :class:`Entry` (keyword, value, unit, line), numbers checked against their units,
and the optional 6x6 covariance (sec. 3.2.4 / 4.2.4: ``CX_X`` .. ``CZ_DOT_Z_DOT``, the lower
triangle, km**2, km**2/s, km**2/s**2).

KVN: ``KEYWORD = value [unit]`` per line (the bracketed unit optional), ``COMMENT`` lines
and blank lines skipped; anything else is an :class:`~fgnav.errors.InputFormatError`
naming the file and the line. XML: every element without children (``units`` attribute
as the unit) with its line; more than one ``segment`` is refused (fgnav takes one object's
prior from a file).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from xml.parsers import expat

import numpy as np

from fgnav.errors import InputFormatError
from fgnav.io.kvn import epoch_value, number_value, read_kvn_lines

__all__ = ["Entry", "read_entries", "number", "epoch", "covariance", "COVARIANCE_KEYS",
           "check_known"]

_KVN_UNIT_RE = re.compile(r"^([A-Z][A-Z0-9_]*)\s*=\s*(.*?)\s*(?:\[([^\]]*)\])?\s*$")
"""``KEYWORD = value [unit]``: :data:`fgnav.io.kvn.KVN_RE` with the ODM's optional unit."""

_STATE = ("X", "Y", "Z", "X_DOT", "Y_DOT", "Z_DOT")
COVARIANCE_KEYS = tuple(f"C{_STATE[i]}_{_STATE[j]}" for i in range(6) for j in range(i + 1))
"""The 21 covariance keywords, row by row of the lower triangle (CX_X, CY_X, CY_Y, ...)."""


@dataclass(frozen=True)
class Entry:
    """One keyword of a message: its value text, its unit (``""`` if not given), its line."""

    key: str
    value: str
    unit: str
    line: int


def read_entries(path, what: str) -> tuple[list[Entry], bool]:
    """The entries of a KVN or XML ODM (XML when the first non-blank character is ``<``),
    in file order, and whether it was XML. ``what`` names the message in errors."""
    lines = read_kvn_lines(path)
    text = "\n".join(t for _, t in lines)
    if text.lstrip().startswith("<"):
        return _xml_entries(path, text, what), True
    out = []
    for i, raw in lines:
        s = raw.strip()
        if not s or s == "COMMENT" or s.startswith("COMMENT "):
            continue
        m = _KVN_UNIT_RE.match(s)
        if m is None:
            raise InputFormatError(path, i, None, f"a 'KEYWORD = value [unit]' line of {what}",
                                   s)
        out.append(Entry(m.group(1), m.group(2), (m.group(3) or "").strip(), i))
    return out, False


def _xml_entries(path, text: str, what: str) -> list[Entry]:
    parser = expat.ParserCreate()
    stack, out, segments = [], [], [0]

    def start(tag, attrs):
        if tag == "segment":
            segments[0] += 1
            if segments[0] > 1:
                raise InputFormatError(path, parser.CurrentLineNumber, "segment",
                                       f"one segment ({what} of one object)", "a second segment")
        stack.append([tag, attrs, [], parser.CurrentLineNumber, False])
        if len(stack) > 1:
            stack[-2][4] = True   # the parent has a child: not a leaf

    def end(tag):
        name, attrs, chunks, line, has_child = stack.pop()
        if not has_child and name != "COMMENT":
            out.append(Entry(name, "".join(chunks).strip(), attrs.get("units", "").strip(), line))

    def chars(data):
        if stack:
            stack[-1][2].append(data)

    parser.StartElementHandler, parser.EndElementHandler = start, end
    parser.CharacterDataHandler = chars
    try:
        parser.Parse(text, True)
    except expat.ExpatError as exc:
        raise InputFormatError(path, exc.lineno, None, f"well-formed XML ({what})",
                               expat.errors.messages[exc.code]) from None
    return out


def check_known(path, entries, known, what: str, repeatable=()) -> dict[str, Entry]:
    """The entries by keyword (the first of a ``repeatable`` one); an unknown keyword
    (``USER_DEFINED_*`` aside) or a repeated one is an error naming its line."""
    by_key = {}
    for e in entries:
        if e.key.startswith("USER_DEFINED_"):
            continue
        if e.key not in known:
            raise InputFormatError(path, e.line, e.key, f"a keyword of {what}", e.key)
        if e.key in by_key and e.key in repeatable:
            continue
        if e.key in by_key:
            raise InputFormatError(path, e.line, e.key, "each keyword once",
                                   f"again after line {by_key[e.key].line}")
        by_key[e.key] = e
    return by_key


def _unit_ok(unit: str, expected: str) -> bool:
    norm = lambda u: u.replace(" ", "").lower()   # noqa: E731
    return not unit or norm(unit) in {norm(x) for x in expected.split("|")}


def number(path, e: Entry, unit: str = "", lo: float = -math.inf, hi: float = math.inf,
           lo_open: bool = False) -> float:
    """The value of ``e`` as a finite decimal number in ``[lo, hi]`` (``(lo, hi]`` with
    ``lo_open``), given in ``unit`` (alternatives separated by ``|``; a missing unit is the
    standard's); else an error naming the line and the keyword."""
    if not _unit_ok(e.unit, unit):
        raise InputFormatError(path, e.line, e.key, f"the unit [{unit or 'none'}]", e.unit)
    x = number_value(path, e.line, e.key, e.value)
    bad_lo = x <= lo if lo_open else x < lo
    if not math.isfinite(x) or bad_lo or x > hi:
        rng = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
        raise InputFormatError(path, e.line, e.key, f"a number in {rng} {unit}".rstrip(),
                               e.value)
    return x


def epoch(path, e: Entry) -> np.datetime64:
    """The value of ``e`` as a CCSDS epoch (UTC label -> fgnav's time scale)."""
    return epoch_value(path, e.line, e.key, e.value)


def covariance(path, by_key: dict[str, Entry]) -> np.ndarray | None:
    """The 6x6 covariance of the 21 ``C..`` keywords (SI: m, m/s), or None if there is none;
    some but not all of them, or a matrix that is not symmetric positive semi-definite
    (smallest eigenvalue below -1e-9 of the largest), is an error naming a line."""
    present = [k for k in COVARIANCE_KEYS if k in by_key]
    if not present:
        return None
    missing = [k for k in COVARIANCE_KEYS if k not in by_key]
    if missing:
        first = by_key[present[0]]
        raise InputFormatError(path, first.line, missing[0], "all 21 covariance keywords "
                               "CX_X .. CZ_DOT_Z_DOT", f"{len(present)} of them")
    P = np.zeros((6, 6))
    n = 0
    for i in range(6):
        for j in range(i + 1):
            k = COVARIANCE_KEYS[n]
            unit = ("km**2", "km**2/s", "km**2/s**2")[(i >= 3) + (j >= 3)]
            P[i, j] = P[j, i] = number(path, by_key[k], unit) * 1e6
            n += 1
    w = np.linalg.eigvalsh(P)
    if w[0] < -1e-9 * max(w[-1], 0.0) or w[-1] <= 0.0:
        e = by_key[COVARIANCE_KEYS[0]]
        raise InputFormatError(path, e.line, "CX_X", "a positive semi-definite covariance",
                               f"eigenvalues {w[0]:.3g} .. {w[-1]:.3g} (SI)")
    return P
