"""Read CCSDS Tracking Data Messages (TDM, CCSDS 503.0-B-2), KVN form: RA/Dec angle data.

Each pair of ``ANGLE_1`` (right ascension a, deg) and ``ANGLE_2`` (declination d, deg)
records at the same epoch becomes one ``earth_direction`` measurement (see
:mod:`fgnav.io.log_csv`): the unit vector spacecraft -> Earth centre in EME2000,

    u = (cos d cos a, cos d sin a, sin d).

Accepted layout (one or more segments)::

    CCSDS_TDM_VERS = 2.0            (1.0 and 2.0 accepted; must be the first line)
    COMMENT ...                     (optional)
    CREATION_DATE = ...             (required)
    ORIGINATOR = ...                (required)
    META_START
    TIME_SYSTEM = UTC               (required; only UTC)
    PARTICIPANT_1 = ...             (required)
    ANGLE_TYPE = RADEC              (required when the segment has angles; only RADEC)
    REFERENCE_FRAME = EME2000       (required with RADEC; only EME2000)
    ... other TDM metadata keywords are kept in ``meta`` but not used
    META_STOP
    DATA_START
    ANGLE_1 = <epoch> <RA, deg in [-180, 360)>
    ANGLE_2 = <epoch> <Dec, deg in [-90, 90]>
    ... other data keywords (RANGE, DOPPLER_*, ...) are skipped with a warning
    DATA_STOP

Epochs are CCSDS ASCII time (``YYYY-MM-DDThh:mm:ss[.f]`` or ``YYYY-DDDThh:mm:ss[.f]``,
optional ``Z``).

The 1σ angular noise (rad, per tangent axis) is, in order of precedence: the ``sigma_rad``
argument; a ``COMMENT sigma_deg=<value>`` line inside the segment (metadata or data
section); such a comment in the file header (applies to every segment). With none, the
read fails. Malformed lines, an ANGLE_1 without its ANGLE_2 (or the reverse), a repeated
record at one epoch, other ANGLE_TYPEs or frames, and missing keywords raise
:class:`~fgnav.errors.InputFormatError` naming the line. Rows are returned sorted by epoch
(a warning if the file was not); ``line`` is the line of each ANGLE_1 record.
"""

from __future__ import annotations

import math
import re

import numpy as np

from fgnav.errors import InputFormatError, UserError
from fgnav.io.log_csv import EXTRA_COLUMNS, MeasurementLog, SIGMA_RANGE, _sort_rows
from fgnav.io.kvn import KVN_RE, epoch_value, header_line, number_value, read_kvn_lines
from fgnav.models.registry import EARTH_DIRECTION
from fgnav.time import seconds_since

__all__ = ["read_tdm"]

_SIGMA_RE = re.compile(r"\bsigma_deg\s*=\s*(\S+)")
_DATA_RE = re.compile(r"^([A-Z][A-Z0-9_]*)\s*=\s*(\S+)\s+(\S+)\s*$")


def _sigma_from_comment(path, lineno, comment):
    m = _SIGMA_RE.search(comment)
    if m is None:
        return None
    try:
        s = number_value(path, lineno, "sigma_deg", m.group(1))
    except InputFormatError:
        raise InputFormatError(path, lineno, "sigma_deg", "COMMENT sigma_deg=<1-sigma in deg, "
                               "a number > 0>", m.group(1)) from None

    lo, hi, _ = SIGMA_RANGE[EARTH_DIRECTION.kind]
    if not lo <= math.radians(s) <= hi:
        raise InputFormatError(path, lineno, "sigma_deg", f"a 1-sigma within {math.degrees(lo):.3g}.."
                               f"{math.degrees(hi):.3g} deg (the range of an {EARTH_DIRECTION.kind})",
                               m.group(1))
    return math.radians(s)


def read_tdm(path, sigma_rad: float | None = None):
    """Read RA/Dec angles from a TDM (KVN) as ``earth_direction`` rows of a MeasurementLog.

    ``sigma_rad``: 1σ angular noise (rad); if None, taken from ``COMMENT sigma_deg=...``.
    """
    if sigma_rad is not None:
        sigma_rad = float(sigma_rad)
        if not (math.isfinite(sigma_rad) and sigma_rad > 0.0):
            raise UserError(f"read_tdm: sigma_rad must be a finite number > 0, found {sigma_rad}")

    lines = [(n, t.strip()) for n, t in read_kvn_lines(path) if t.strip()]
    if not lines:
        raise InputFormatError(path, 1, "CCSDS_TDM_VERS", "a TDM starting with "
                               "'CCSDS_TDM_VERS = 2.0'", "empty file")
    n0, t0 = lines[0]
    m = KVN_RE.match(t0)
    if m is None or m.group(1) != "CCSDS_TDM_VERS":
        raise InputFormatError(path, n0, "CCSDS_TDM_VERS", "'CCSDS_TDM_VERS = 2.0' as the first "
                               "line", t0[:60])
    if m.group(2) not in ("1.0", "2.0"):
        raise InputFormatError(path, n0, "CCSDS_TDM_VERS", "version 1.0 or 2.0", m.group(2))

    meta: dict = {"CCSDS_TDM_VERS": m.group(2), "segments": []}
    header_sigma = None
    state = "header"
    seg: dict | None = None
    rows_ns: list[int] = []
    rows_u: list[np.ndarray] = []
    rows_sigma: list[float] = []
    rows_line: list[int] = []
    skipped: dict[str, int] = {}
    last = n0

    def close_data(lineno):
        pend = seg["pending"]
        if pend:
            t, rec = next(iter(pend.items()))
            have = next(iter(rec))
            need = "ANGLE_2" if have == "ANGLE_1" else "ANGLE_1"
            raise InputFormatError(path, rec[have][1], need, f"an {need} record at the same "
                                   f"epoch as this {have} (before DATA_STOP, line {lineno})",
                                   "none")
        sig = sigma_rad if sigma_rad is not None else (seg["sigma"] or header_sigma)
        if seg["n_angles"] and sig is None:
            raise InputFormatError(path, seg["line"], "sigma_deg",
                                   "the angle noise: a 'COMMENT sigma_deg=<1-sigma, deg>' line "
                                   "(header or segment) or the sigma_rad option", "none")
        for j in seg["rows"]:
            rows_sigma[j] = sig

    for lineno, s in lines[1:]:
        last = lineno
        if s.startswith("COMMENT") and (s == "COMMENT" or s[7] in " \t"):
            text = s[7:].strip()
            sig = _sigma_from_comment(path, lineno, text)
            if state == "header":
                meta.setdefault("comments", []).append(text)
                if sig is not None:
                    header_sigma = sig
            elif state in ("meta", "data"):
                seg["comments"].append(text)
                if sig is not None:
                    seg["sigma"] = sig
            else:  # between segments: the standard allows none here; keep it but do not use it
                meta.setdefault("comments", []).append(text)
            continue
        if state == "header":
            if header_line(path, lineno, s, meta):
                state = "meta"
                seg = {"line": lineno, "comments": [], "sigma": None, "pending": {},
                       "rows": [], "n_angles": 0, "keys": {}, "paired": {}}
            continue
        if state == "meta":
            if s == "META_STOP":
                for k in ("TIME_SYSTEM", "PARTICIPANT_1"):
                    if k not in seg["keys"]:
                        raise InputFormatError(path, lineno, k, f"metadata keyword {k} before "
                                               "META_STOP", "META_STOP")
                state = "between"
                meta["segments"].append(seg["keys"])
                continue
            m = KVN_RE.match(s)
            if m is None:
                raise InputFormatError(path, lineno, None, "a 'KEYWORD = value' metadata line or "
                                       "META_STOP", s[:60])
            key, val = m.group(1), m.group(2)
            if key in seg["keys"]:
                raise InputFormatError(path, lineno, key, "each metadata keyword once",
                                       f"{key} repeated")
            if key == "TIME_SYSTEM" and val != "UTC":
                raise InputFormatError(path, lineno, key, "TIME_SYSTEM = UTC (the only time "
                                       "system fgnav reads)", val)
            if key == "ANGLE_TYPE" and val != "RADEC":
                raise InputFormatError(path, lineno, key, "ANGLE_TYPE = RADEC (right ascension "
                                       "and declination; other angle types are not supported)",
                                       val)
            if key == "REFERENCE_FRAME" and val != "EME2000":
                raise InputFormatError(path, lineno, key, "REFERENCE_FRAME = EME2000", val)
            seg["keys"][key] = val
            continue
        if state == "between":
            if s == "DATA_START":
                state = "data"
                continue
            raise InputFormatError(path, lineno, "DATA_START", "DATA_START after META_STOP",
                                   s[:60])
        if state == "data":
            if s == "DATA_STOP":
                close_data(lineno)
                state = "done"
                continue
            m = _DATA_RE.match(s)
            if m is None:
                raise InputFormatError(path, lineno, None, "a data line 'KEYWORD = epoch value' "
                                       "or DATA_STOP", s[:60])
            key, ep, val = m.groups()
            if key not in ("ANGLE_1", "ANGLE_2"):
                skipped[key] = skipped.get(key, 0) + 1
                epoch_value(path, lineno, key, ep)
                continue
            for k, want in (("ANGLE_TYPE", "RADEC"), ("REFERENCE_FRAME", "EME2000")):
                if k not in seg["keys"]:
                    raise InputFormatError(path, lineno, k, f"metadata keyword {k} = {want} in "
                                           f"this segment (line {seg['line']}) for {key} data",
                                           "missing")
            t = int(epoch_value(path, lineno, key, ep).astype(np.int64))
            deg = number_value(path, lineno, key, val)
            lo, hi = (-180.0, 360.0) if key == "ANGLE_1" else (-90.0, 90.0)
            if not (lo <= deg < hi or (key == "ANGLE_2" and deg == hi)):
                raise InputFormatError(path, lineno, key, f"an angle in [{lo:g}, {hi:g}"
                                       f"{']' if key == 'ANGLE_2' else ')'} deg", val)
            done = seg["paired"].get(t)
            rec = seg["pending"].setdefault(t, {}) if done is None else done
            if key in rec:
                raise InputFormatError(path, lineno, key, f"one {key} record per epoch",
                                       f"a second one at {ep} (first at line {rec[key][1]})")
            rec[key] = (math.radians(deg), lineno)
            seg["n_angles"] += 1
            if len(rec) == 2:
                a, d = rec["ANGLE_1"][0], rec["ANGLE_2"][0]
                cd = math.cos(d)
                u = np.array([cd * math.cos(a), cd * math.sin(a), math.sin(d)])
                seg["rows"].append(len(rows_ns))
                rows_ns.append(t)
                rows_u.append(u)
                rows_sigma.append(math.nan)
                rows_line.append(min(rec["ANGLE_1"][1], rec["ANGLE_2"][1]))
                seg["paired"][t] = seg["pending"].pop(t)
            continue
        if state == "done":
            if s == "META_START":
                state = "meta"
                seg = {"line": lineno, "comments": [], "sigma": None, "pending": {},
                       "rows": [], "n_angles": 0, "keys": {}, "paired": {}}
                continue
            raise InputFormatError(path, lineno, None, "META_START (a new segment) or end of "
                                   "file after DATA_STOP", s[:60])
    if state != "done":
        want = {"header": "META_START", "meta": "META_STOP", "between": "DATA_START",
                "data": "DATA_STOP"}[state]
        raise InputFormatError(path, last + 1, want, f"{want} (the TDM is incomplete)",
                               "end of file")
    if not rows_ns:
        raise InputFormatError(path, last, "ANGLE_1", "at least one ANGLE_1/ANGLE_2 pair "
                               "(RADEC)", "no measurements")

    warnings: list[str] = []
    if skipped:
        what = ", ".join(f"{k}: {n}" for k, n in sorted(skipped.items()))
        warnings.append(f"{path}: skipped data records of other types ({what})")
    ns = np.array(rows_ns, dtype=np.int64)
    V = np.full((len(ns), 6), np.nan)
    V[:, :3] = np.array(rows_u)
    V[:, 3] = rows_sigma
    kind = np.array([EARTH_DIRECTION.kind] * len(ns), dtype=object)
    ns, V, kind, line, w = _sort_rows(ns, V, kind, np.array(rows_line, dtype=np.int64), path)
    if w:
        warnings.append(w)
    epoch0 = np.datetime64(int(ns[0]), "ns")
    return MeasurementLog(
        path=path, epoch0=epoch0, t_s=seconds_since(ns.astype("datetime64[ns]"), epoch0),
        kind=kind.astype(str), xyz=V[:, :3].copy(), sigma=V[:, 3].copy(),
        extra={c: np.full(len(ns), np.nan) for c in EXTRA_COLUMNS}, line=line,
        warnings=warnings, dropped={})
