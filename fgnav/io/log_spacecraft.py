"""Several spacecraft in one measurement log (CSV format v1): ids, antennas, link rows.

Part of the format's definition (:mod:`fgnav.io.log_csv` keeps the table of kinds; this
module the parts that concern several spacecraft):

* ``spacecraft`` column (optional, any kind): the id of the spacecraft a row belongs to (for
  an inter-satellite row, the receiving spacecraft). Ids are names of letters, digits,
  ``_``, ``-`` and ``.`` (``A``, ``chief``, ``sc-2``). A log without the column is one
  spacecraft, as every v1 log; with it, every row names its spacecraft.
* ``tx_spacecraft``, ``rx_antenna``, ``tx_antenna`` (inter-satellite rows): the transmitting
  spacecraft, and the antennas at both ends (empty: the spacecraft's centre of mass).
* Declarations in the comment lines above the header::

      # spacecraft: A B            (optional: the ids, in order; others are errors)
      # antenna: A rx1 0.5 0.5 0.5 (spacecraft, antenna, lever arm x y z in its body frame, m)

  Without a ``# spacecraft:`` line the order is that of first appearance in the file
  (columns ``spacecraft`` then ``tx_spacecraft``, line by line). The first spacecraft is
  the reference of the relative state (``relative.csv``).

In memory the id columns hold codes (floats, NaN where empty): ``spacecraft`` and
``tx_spacecraft`` index :attr:`MeasurementLog.spacecraft`, the antenna columns index
:attr:`MeasurementLog.antenna_names`; lever arms are in :attr:`MeasurementLog.antennas`
keyed by ``(spacecraft id, antenna name)``.
"""

from __future__ import annotations

import math
import re

import numpy as np

from fgnav.errors import InputFormatError

__all__ = ["SPACECRAFT_COLUMNS", "ANTENNA_COLUMNS", "ID_COLUMNS", "ISL_KINDS", "Vocabulary",
           "ID_RE", "parse_declaration", "Declarations", "spacecraft_index", "declaration_lines",
           "id_codes"]

SPACECRAFT_COLUMNS = ("spacecraft", "tx_spacecraft")
ANTENNA_COLUMNS = ("rx_antenna", "tx_antenna")
ID_COLUMNS = SPACECRAFT_COLUMNS + ANTENNA_COLUMNS
"""Columns that hold a name in the file and a code in memory."""
ISL_KINDS = ("isl_pseudorange", "isl_carrier_phase")
"""The inter-satellite kinds (rows between two spacecraft)."""
ID_RE = re.compile(r"^[A-Za-z0-9_.\-]{1,64}$")
ID_EXPECTED = "a name of 1-64 letters, digits, '_', '-' or '.'"
_DECL_SC = re.compile(r"^#\s*spacecraft\s*:(.*)$", re.IGNORECASE)
_DECL_ANT = re.compile(r"^#\s*antenna\s*:(.*)$", re.IGNORECASE)
ANTENNA_EXPECTED = ("'# antenna: <spacecraft> <antenna> <x_m> <y_m> <z_m>' (lever arm in the "
                    "spacecraft's body frame, m, each |.| <= 1000)")
MAX_LEVER_ARM_M = 1000.0


class Vocabulary:
    """Names -> codes, in the order first seen (``names``)."""

    def __init__(self, names=()):
        self.index: dict[str, int] = {}
        for n in names:
            self.code(n)

    def code(self, name: str) -> float:
        c = self.index.get(name)
        if c is None:
            c = self.index[name] = len(self.index)
        return float(c)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.index)


class Declarations:
    """The ``# spacecraft:`` and ``# antenna:`` lines of a log's comments."""

    def __init__(self):
        self.spacecraft: tuple[str, ...] | None = None
        self.spacecraft_line = 0
        self.antennas: dict[tuple[str, str], np.ndarray] = {}
        self.antenna_lines: dict[tuple[str, str], int] = {}

    def check_spacecraft_known(self, path):
        """Every antenna is declared on a declared spacecraft (when ids are declared)."""
        if self.spacecraft is None:
            return
        for (sc, ant), line in self.antenna_lines.items():
            if sc not in self.spacecraft:
                raise InputFormatError(path, line, None, f"an antenna of a declared spacecraft "
                                       f"({', '.join(self.spacecraft)}: line "
                                       f"{self.spacecraft_line})", f"spacecraft '{sc}'")


def parse_declaration(path, lineno: int, text: str, decl: Declarations) -> None:
    """Record a ``# spacecraft:`` or ``# antenna:`` comment line in ``decl`` (other comments
    are ignored); a malformed declaration is an :class:`InputFormatError`."""
    s = text.strip()
    m = _DECL_SC.match(s)
    if m:
        ids = [t for t in re.split(r"[\s,]+", m.group(1).strip()) if t]
        bad = [t for t in ids if not ID_RE.match(t)]
        if not ids or bad:
            raise InputFormatError(path, lineno, None, "'# spacecraft: <id> [<id> ...]' with "
                                   f"each id {ID_EXPECTED}", s)
        if len(set(ids)) != len(ids):
            raise InputFormatError(path, lineno, None, "each spacecraft id once", s)
        if decl.spacecraft is not None:
            raise InputFormatError(path, lineno, None, "one '# spacecraft:' line (the first is "
                                   f"line {decl.spacecraft_line})", s)
        decl.spacecraft, decl.spacecraft_line = tuple(ids), lineno
        return
    m = _DECL_ANT.match(s)
    if not m:
        return
    parts = m.group(1).split()
    try:
        if len(parts) != 5 or not (ID_RE.match(parts[0]) and ID_RE.match(parts[1])):
            raise ValueError
        arm = np.array([float(p) for p in parts[2:]])
        if not np.all(np.abs(arm) <= MAX_LEVER_ARM_M):   # also NaN
            raise ValueError
    except ValueError:
        raise InputFormatError(path, lineno, None, ANTENNA_EXPECTED, s) from None
    key = (parts[0], parts[1])
    if key in decl.antennas:
        raise InputFormatError(path, lineno, None, "each antenna declared once (spacecraft "
                               f"'{key[0]}' antenna '{key[1]}' is declared on line "
                               f"{decl.antenna_lines[key]})", s)
    decl.antennas[key] = arm
    decl.antenna_lines[key] = lineno


def first_appearance(codes_by_column: list[np.ndarray], line: np.ndarray) -> np.ndarray:
    """The provisional codes in order of first appearance, by file line and then column:
    returns ``order`` with ``order[new] = old``."""
    rows = np.argsort(line, kind="stable")
    seq = np.column_stack([c[rows] for c in codes_by_column]).ravel()
    seq = seq[~np.isnan(seq)].astype(int)
    _, first = np.unique(seq, return_index=True)
    return seq[np.sort(first)]


def spacecraft_index(log) -> np.ndarray:
    """Per row, the index of its spacecraft in ``log.spacecraft`` (0 for a one-spacecraft
    log), int array."""
    c = np.asarray((log.extra or {}).get("spacecraft", np.full(len(log), np.nan)), dtype=float)
    return np.where(np.isnan(c), 0, c).astype(int)


def check_rows(log_kind, V_ids: dict, spacecraft: tuple[str, ...], antenna_names, antennas,
               n_declared: int | None, has_column: bool):
    """Cross-row checks of the id columns (after the codes are final): yields
    ``(row index, reason, column, expected, found)`` for every bad row.

    ``V_ids``: column -> (M,) codes; ``n_declared``: how many of ``spacecraft`` a
    ``# spacecraft:`` line declared (None: no such line). Checks: with the ``spacecraft`` column present, every
    row names one; a declared id list admits no others; a link's two ends differ; an antenna
    named on a row is declared for its spacecraft."""
    sc = V_ids["spacecraft"]
    tx = V_ids["tx_spacecraft"]
    if has_column:
        for i in np.flatnonzero(np.isnan(sc)):
            yield (int(i), "missing_value", "spacecraft", "a spacecraft id (the log has a "
                   "spacecraft column: every row names its spacecraft)", "empty field")
    if n_declared is not None:
        for col in SPACECRAFT_COLUMNS:
            for i in np.flatnonzero(V_ids[col] >= n_declared):
                yield (int(i), "unknown_spacecraft", col, "a spacecraft declared in '# "
                       f"spacecraft:' ({', '.join(spacecraft[:n_declared])})",
                       spacecraft[int(V_ids[col][i])])
    isl = np.isin(np.asarray(log_kind).astype(str), ISL_KINDS)
    for i in np.flatnonzero(isl & (sc == tx)):
        yield (int(i), "same_spacecraft", "tx_spacecraft", "a transmitting spacecraft other "
               "than the receiving one (column spacecraft)", spacecraft[int(sc[i])])
    for col, sc_col in (("rx_antenna", sc), ("tx_antenna", tx)):
        a = V_ids[col]
        for i in np.flatnonzero(isl & ~np.isnan(a)):
            if np.isnan(sc_col[i]):
                continue
            key = (spacecraft[int(sc_col[i])], antenna_names[int(a[i])])
            if key not in antennas:
                yield (int(i), "unknown_antenna", col,
                       f"an antenna declared for spacecraft '{key[0]}' in the header comments "
                       f"({ANTENNA_EXPECTED})", key[1])


def declaration_lines(spacecraft, antennas) -> list[str]:
    """The comment lines (without ``# ``) that declare ``spacecraft`` (ids in order) and
    ``antennas`` ((spacecraft, antenna) -> lever arm (3,), m) in a written log."""
    out = [f"spacecraft: {' '.join(spacecraft)}"] if spacecraft else []
    out += [f"antenna: {sc} {ant} {' '.join(repr(float(a)) for a in arm)}"
            for (sc, ant), arm in antennas.items()]
    return out


def id_codes(values, names: list, column: str) -> np.ndarray:
    """Codes (M,) of an id column given as names (str; appended to ``names`` when new) or as
    codes (floats into ``names``); NaN/None/empty -> NaN. ValueError for a malformed name
    or a code outside ``names``."""
    out = []
    for v in np.asarray(values, dtype=object).reshape(-1):
        if v is None or v == "" or (isinstance(v, float) and math.isnan(v)):
            out.append(math.nan)
        elif isinstance(v, str):
            if not ID_RE.match(v):
                raise ValueError(f"{column}: {v!r} is not {ID_EXPECTED}")
            if v not in names:
                names.append(v)
            out.append(float(names.index(v)))
        else:
            c = float(v)
            if c not in range(len(names)):
                raise ValueError(f"{column}: code {v!r} outside 0..{len(names) - 1}")
            out.append(c)
    return np.array(out, dtype=float)
