"""Read and write CCSDS Tracking Data Messages (TDM, CCSDS 503.0-B-2), KVN form: RA/Dec
angle data of the Earth seen from the spacecraft.

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
    PARTICIPANT_1 = EARTH           (required; numbering free)
    PARTICIPANT_2 = <the spacecraft>
    MODE = SEQUENTIAL               (optional; SEQUENTIAL only)
    PATH = 1,2                      (required with angles: the Earth, then the spacecraft)
    ANGLE_TYPE = RADEC              (required when the segment has angles; only RADEC)
    REFERENCE_FRAME = EME2000       (required with RADEC; only EME2000)
    CORRECTION_ANGLE_1 = <deg>      (optional, with CORRECTIONS_APPLIED = YES or NO)
    CORRECTIONS_APPLIED = NO        (NO: the corrections are added to the angles here)
    ... other metadata keywords of table 3-3 are kept in ``meta`` but not used
    META_STOP
    DATA_START
    ANGLE_1 = <epoch> <RA, deg in [-180, 360)>
    ANGLE_2 = <epoch> <Dec, deg in [-90, 90]>
    ... other data keywords (RANGE, DOPPLER_*, ...) are skipped with a warning
    DATA_STOP

Who observes whom (3.3.2, 3.5.4): the signal runs along PATH from its first participant to
its last, so the angles are those of the first participant seen from the last. fgnav reads
them only when the first is a body it models in EME2000 (``EARTH``: the Earth's centre) and
the last is the spacecraft (not a body): a ground telescope's RA/Dec of a satellite (the
annex's ``tdm_e16``, ``tdm_e22``), a geocentric RA/Dec of the spacecraft (``PATH`` the other
way), or no PATH are refused naming ``PATH`` and the participants. Corrections (3.4.15,
table 3-3 item 37: the value "to be added to each data point"): with
``CORRECTIONS_APPLIED = NO``, ``CORRECTION_ANGLE_1/2`` are added to the angles; with YES
the data already has them; a ``CORRECTION_*`` without ``CORRECTIONS_APPLIED`` and an
unapplied ``CORRECTION_ABERRATION_*`` on angles are refused. Unknown metadata keywords are
refused, naming them.

:func:`write_tdm` writes this layout (the sample ``fgnav/data/tdm/gto-transfer.tdm`` was
written so from a simulated pass).

Epochs are CCSDS ASCII time (``YYYY-MM-DDThh:mm:ss[.f]`` or ``YYYY-DDDThh:mm:ss[.f]``,
optional ``Z``).

The 1σ angular noise (rad, per tangent axis) is, in order of precedence: the ``sigma_rad``
argument (``--sigma-deg`` of ``fgnav check`` and ``fgnav smooth``); a ``COMMENT
sigma_deg=<value>`` line inside the segment (metadata or data
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
from fgnav.io.atomic import atomic_writer
from fgnav.io.kvn import (KVN_RE, ccsds_epochs, check_meta_value, epoch_value, header_line,
                          kvn_header, number_value, read_kvn_lines, version_line)
from fgnav.io.log_csv import (EARTH_DIRECTION_KIND, EXTRA_COLUMNS, MeasurementLog, SIGMA_RANGE,
                              _sort_rows)
from fgnav.time import add_seconds, parse_utc, seconds_since

__all__ = ["read_tdm", "write_tdm"]

_META_KEYS = (
    ("TRACK_ID", "DATA_TYPES", "TIME_SYSTEM", "START_TIME", "STOP_TIME")
    + tuple(f"PARTICIPANT_{n}" for n in range(1, 6))
    + ("MODE", "PATH", "PATH_1", "PATH_2")
    + tuple(f"EPHEMERIS_NAME_{n}" for n in range(1, 6))
    + ("TRANSMIT_BAND", "RECEIVE_BAND", "TURNAROUND_NUMERATOR", "TURNAROUND_DENOMINATOR",
       "TIMETAG_REF", "INTEGRATION_INTERVAL", "INTEGRATION_REF", "FREQ_OFFSET", "RANGE_MODE",
       "RANGE_MODULUS", "RANGE_UNITS", "ANGLE_TYPE", "REFERENCE_FRAME", "INTERPOLATION",
       "INTERPOLATION_DEGREE", "DOPPLER_COUNT_BIAS", "DOPPLER_COUNT_SCALE",
       "DOPPLER_COUNT_ROLLOVER")
    + tuple(f"{d}_DELAY_{n}" for d in ("TRANSMIT", "RECEIVE") for n in range(1, 6))
    + ("DATA_QUALITY", "CORRECTION_ANGLE_1", "CORRECTION_ANGLE_2", "CORRECTION_DOPPLER",
       "CORRECTION_MAG", "CORRECTION_RANGE", "CORRECTION_RCS", "CORRECTION_RECEIVE",
       "CORRECTION_TRANSMIT", "CORRECTION_ABERRATION_YEARLY", "CORRECTION_ABERRATION_DIURNAL",
       "CORRECTIONS_APPLIED"))
"""The metadata keywords of TDM 503.0-B-2 (table 3-3); any other is refused, naming it."""
_MODELLED_TARGETS = ("EARTH",)
"""Participants whose direction fgnav models in EME2000 (``earth_direction``: the Earth's
centre)."""
_BODIES = ("EARTH", "SUN", "MOON")
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

    lo, hi, _ = SIGMA_RANGE[EARTH_DIRECTION_KIND]
    if not lo <= math.radians(s) <= hi:
        raise InputFormatError(path, lineno, "sigma_deg", f"a 1-sigma within {math.degrees(lo):.3g}.."
                               f"{math.degrees(hi):.3g} deg (the range of an {EARTH_DIRECTION_KIND})",
                               m.group(1))
    return math.radians(s)


def _new_segment(lineno) -> dict:
    return {"line": lineno, "comments": [], "sigma": None, "pending": {}, "rows": [],
            "n_angles": 0, "keys": {}, "lines": {}, "paired": {}}


def _check_path(path, seg):
    """TDM 503.0-B-2 3.3.2 and 3.5.4: the signal of an angle measurement travels along PATH
    from its first participant (the object seen) to its last (the observer), so the angles
    are those of the first participant seen from the last. fgnav reads them as onboard
    directions only when the observed participant is a body it models in EME2000 (the
    Earth: ``earth_direction``) and the observer is the spacecraft (not a body); anything
    else -- a ground telescope's RA/Dec of a satellite, a geocentric RA/Dec of the
    spacecraft, no PATH -- is refused naming PATH and the participants."""
    keys, lines = seg["keys"], seg["lines"]
    if keys.get("MODE", "SEQUENTIAL") != "SEQUENTIAL" or "PATH" not in keys:
        k = "MODE" if "MODE" in keys and keys["MODE"] != "SEQUENTIAL" else "PATH"
        raise InputFormatError(path, lines.get(k, seg["line"]), k, "MODE = SEQUENTIAL and "
                               "PATH = <observed>,<observer> for angle data (503.0-B-2 3.3.2: "
                               "the angles are those of the path's first participant seen "
                               "from its last)", f"{k} = {keys[k]}" if k in keys else "no PATH")
    text = keys["PATH"]
    try:
        idx = [int(v) for v in text.split(",")]
    except ValueError:
        idx = []
    names = [keys.get(f"PARTICIPANT_{i}") for i in idx]
    if len(idx) < 2 or None in names:
        raise InputFormatError(path, lines["PATH"], "PATH", "PATH = i,j,... of PARTICIPANT_n "
                               "defined in the segment (503.0-B-2 table 3-3)", text)
    seen, observer = names[0].strip().upper(), names[-1].strip().upper()
    if seen not in _MODELLED_TARGETS or observer in _BODIES or idx[0] == idx[-1]:
        raise InputFormatError(
            path, lines["PATH"], "PATH", "angles of a body fgnav models (PARTICIPANT_n = "
            f"{', '.join(_MODELLED_TARGETS)}) seen from the spacecraft: PATH = <the "
            "body's n>,<the spacecraft's n> (fgnav reads onboard directions; ground-based "
            "angles of a spacecraft are not its measurements)",
            f"PATH = {text}: PARTICIPANT_{idx[0]} = {names[0]} seen from "
            f"PARTICIPANT_{idx[-1]} = {names[-1]}")


def _angle_corrections(path, seg) -> dict:
    """The degrees to add to ANGLE_1 and ANGLE_2 (503.0-B-2 table 3-3 and 3.4.15: the
    CORRECTION_* values "have been added to the data or should be added"): with
    CORRECTIONS_APPLIED = NO, CORRECTION_ANGLE_1/2; with YES or none, zero. An aberration
    correction not applied (CORRECTION_ABERRATION_YEARLY/DIURNAL with NO: one number for
    two angles, not defined further) is refused."""
    keys, lines = seg["keys"], seg["lines"]
    if keys.get("CORRECTIONS_APPLIED") != "NO":
        return {"ANGLE_1": 0.0, "ANGLE_2": 0.0}
    for k in ("CORRECTION_ABERRATION_YEARLY", "CORRECTION_ABERRATION_DIURNAL"):
        if k in keys:
            raise InputFormatError(path, lines[k], k, "no aberration correction left to apply "
                                   "to angle data (CORRECTIONS_APPLIED = NO: fgnav applies "
                                   "CORRECTION_ANGLE_1/2 only)", keys[k])
    return {k: float(keys.get(f"CORRECTION_{k}", 0.0)) for k in ("ANGLE_1", "ANGLE_2")}


def read_tdm(path, sigma_rad: float | None = None):
    """Read RA/Dec angles from a TDM (KVN) as ``earth_direction`` rows of a MeasurementLog.

    ``sigma_rad``: 1σ angular noise (rad); if None, taken from ``COMMENT sigma_deg=...``.
    """
    if sigma_rad is not None:
        sigma_rad = float(sigma_rad)
        if not (math.isfinite(sigma_rad) and sigma_rad > 0.0):
            raise UserError(f"read_tdm: sigma_rad must be a finite number > 0, found {sigma_rad}")

    lines = [(n, t.strip()) for n, t in read_kvn_lines(path) if t.strip()]
    n0, version = version_line(path, lines, "TDM", ("1.0", "2.0"), name_found=False)
    lines = [(n, t) for n, t in lines if n >= n0]
    meta: dict = {"CCSDS_TDM_VERS": version, "segments": []}
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
                                   "(header or segment), the --sigma-deg option (fgnav check, "
                                   "fgnav smooth) or read_tdm's sigma_rad", "none")
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
                seg = _new_segment(lineno)
            continue
        if state == "meta":
            if s == "META_STOP":
                for k in ("TIME_SYSTEM", "PARTICIPANT_1"):
                    if k not in seg["keys"]:
                        raise InputFormatError(path, lineno, k, f"metadata keyword {k} before "
                                               "META_STOP", "META_STOP")
                corrections = [k for k in seg["keys"] if k.startswith("CORRECTION_")]
                if corrections and "CORRECTIONS_APPLIED" not in seg["keys"]:
                    raise InputFormatError(path, lineno, "CORRECTIONS_APPLIED", "CORRECTIONS_"
                                           f"APPLIED = YES or NO with {corrections[0]} (line "
                                           f"{seg['lines'][corrections[0]]}; 503.0-B-2 "
                                           "3.4.15.3)", "META_STOP")
                state = "between"
                meta["segments"].append(seg["keys"])
                continue
            m = KVN_RE.match(s)
            if m is None:
                raise InputFormatError(path, lineno, None, "a 'KEYWORD = value' metadata line or "
                                       "META_STOP", s[:60])
            key, val = m.group(1), m.group(2)
            if key not in _META_KEYS:
                raise InputFormatError(path, lineno, key, "a TDM metadata keyword (503.0-B-2 "
                                       "table 3-3)", s[:60])
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
            if key == "CORRECTIONS_APPLIED" and val not in ("YES", "NO"):
                raise InputFormatError(path, lineno, key, "CORRECTIONS_APPLIED = YES or NO "
                                       "(503.0-B-2 3.4.15.3)", val)
            if key.startswith("CORRECTION_") and key not in ("CORRECTION_ABERRATION_YEARLY",
                                                             "CORRECTION_ABERRATION_DIURNAL"):
                number_value(path, lineno, key, val)
            seg["keys"][key] = val
            seg["lines"][key] = lineno
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
            if "correction" not in seg:
                _check_path(path, seg)
                seg["correction"] = _angle_corrections(path, seg)
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
            rec[key] = (math.radians(deg + seg["correction"][key]), lineno)
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
                seg = _new_segment(lineno)
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
    kind = np.array([EARTH_DIRECTION_KIND] * len(ns), dtype=object)
    ns, V, kind, line, w = _sort_rows(ns, V, kind, np.array(rows_line, dtype=np.int64), path)
    if w:
        warnings.append(w)
    epoch0 = np.datetime64(int(ns[0]), "ns")
    return MeasurementLog(
        path=path, epoch0=epoch0, t_s=seconds_since(ns.astype("datetime64[ns]"), epoch0),
        kind=kind.astype(str), xyz=V[:, :3].copy(), sigma=V[:, 3].copy(),
        extra={c: np.full(len(ns), np.nan) for c in EXTRA_COLUMNS}, line=line,
        warnings=warnings, dropped={})


def write_tdm(path, epoch0, t_s, u_eci, sigma_rad=None, *, spacecraft="FGNAV",
              originator="FGNAV", comments=(), creation_date=None) -> None:
    """Write Earth directions as a CCSDS TDM 2.0 KVN file (503.0-B-2), atomically: RA/Dec of
    the Earth's centre seen from the spacecraft, the layout :func:`read_tdm` reads.

    ``epoch0`` datetime64 (UTC) or ISO string; ``t_s`` (N,) s from it, non-decreasing;
    ``u_eci`` (N, 3) unit vectors spacecraft -> Earth centre in EME2000; ``sigma_rad`` (N,)
    or a number, the 1-sigma per axis written as ``COMMENT sigma_deg=`` (one segment per run
    of equal sigmas), or None (no such comment: the reader then needs ``--sigma-deg``).
    ``PARTICIPANT_1 = EARTH``, ``PARTICIPANT_2 = spacecraft``, ``PATH = 1,2`` (the signal
    from the Earth to the spacecraft: the Earth seen from the spacecraft, 3.3.2);
    a = atan2(u_y, u_x) in [0, 360) deg, d = atan2(u_z, hypot(u_x, u_y)) (the inverse of the
    module docstring's u), written as the shortest text that reads back to the same double.
    """
    if isinstance(epoch0, str):
        epoch0 = parse_utc(epoch0)
    t_s = np.asarray(t_s, dtype=float).reshape(-1)
    u = np.asarray(u_eci, dtype=float)
    n = len(t_s)
    if n == 0 or u.shape != (n, 3) or not (np.all(np.isfinite(t_s)) and np.all(np.isfinite(u))):
        raise UserError(f"write_tdm: need finite t_s (N,) and u_eci (N, 3), N >= 1; found "
                        f"{t_s.shape}, {u.shape}")
    norm = np.linalg.norm(u, axis=1)
    if np.any(np.abs(norm - 1.0) > 1e-6) or np.any(np.diff(t_s) < 0):
        raise UserError("write_tdm: u_eci must be unit vectors and t_s non-decreasing")
    sig = (np.full(n, np.nan) if sigma_rad is None else
           np.broadcast_to(np.asarray(sigma_rad, dtype=float), (n,)))
    names = {k: check_meta_value(k, v, "write_tdm") for k, v in (("PARTICIPANT_2", spacecraft),
                                                    ("ORIGINATOR", originator))}
    ep = ccsds_epochs(add_seconds(epoch0, t_s))
    ra = np.degrees(np.arctan2(u[:, 1], u[:, 0])) % 360.0
    dec = np.degrees(np.arctan2(u[:, 2], np.hypot(u[:, 0], u[:, 1])))
    out = kvn_header("CCSDS_TDM_VERS = 2.0", comments, creation_date, names["ORIGINATOR"])
    starts = [0] + [i for i in range(1, n) if not (sig[i] == sig[i - 1] or
                                                  (np.isnan(sig[i]) and np.isnan(sig[i - 1])))]
    for a, b in zip(starts, starts[1:] + [n]):
        out.append("META_START\n")
        if np.isfinite(sig[a]):
            out.append(f"COMMENT sigma_deg={math.degrees(float(sig[a]))!r}\n")
        out += [f"TIME_SYSTEM = UTC\nSTART_TIME = {ep[a]}\nSTOP_TIME = {ep[b - 1]}\n",
                f"PARTICIPANT_1 = EARTH\nPARTICIPANT_2 = {names['PARTICIPANT_2']}\n",
                "MODE = SEQUENTIAL\nPATH = 1,2\nANGLE_TYPE = RADEC\nREFERENCE_FRAME = EME2000\n",
                "META_STOP\n\nDATA_START\n"]
        for i in range(a, b):
            out.append(f"ANGLE_1 = {ep[i]} {float(ra[i])!r}\nANGLE_2 = {ep[i]} {float(dec[i])!r}\n")
        out.append("DATA_STOP\n\n")
    with atomic_writer(path, "wb") as f:
        f.write("".join(out).encode("utf-8"))
