"""CCSDS Orbit Ephemeris Message (OEM), KVN form (CCSDS 502.0-B-3, "Orbit Data Messages").

Written (``write_oem``, atomically)::

    CCSDS_OEM_VERS = 2.0
    COMMENT ...                      (optional, one per comment)
    CREATION_DATE = 2024-03-01T12:00:00.000000
    ORIGINATOR = FGNAV

    META_START
    OBJECT_NAME = FGNAV
    OBJECT_ID = UNKNOWN
    CENTER_NAME = EARTH
    REF_FRAME = EME2000
    TIME_SYSTEM = UTC
    START_TIME = <first epoch>
    STOP_TIME = <last epoch>
    META_STOP

    <epoch> X Y Z X_DOT Y_DOT Z_DOT     km, km/s (one line per epoch)

    COVARIANCE_START                    (only when a covariance is given)
    EPOCH = <epoch>
    COV_REF_FRAME = EME2000
    C_XX                                lower triangle of the 6x6 covariance, one row
    C_YX C_YY                           per line: km**2, km**2/s, km**2/s**2
    ...
    COVARIANCE_STOP

Epochs are CCSDS ASCII time code A, ``YYYY-MM-DDThh:mm:ss.ffffff`` (microseconds, or
nanoseconds when needed), UTC; a leap second is ``23:59:60.f`` and the seconds between
epochs are elapsed SI seconds (:mod:`fgnav.time`). Positions are written with 9 decimals in km (1 µm),
velocities with 12 decimals in km/s, covariance entries with 17 significant digits; the
covariance written is the symmetric part (P + P^T)/2, and an epoch whose covariance is not
finite gets no block.

Read (``read_oem``): versions 1.0-3.0; calendar (``YYYY-MM-DD``) or day-of-year
(``YYYY-DDD``) epochs with or without ``Z``; gzip, bzip2, xz or LZMA compressed files are
decompressed; several segments are concatenated in file order. What ODM 502.0-B-3 allows
and fgnav keeps:

- the header keywords of the version: CREATION_DATE, ORIGINATOR, and in an OEM 3.0 also
  CLASSIFICATION and MESSAGE_ID (table 5-2; each once; in ``meta``);
- any ``CENTER_NAME``, the same in every segment (``meta["CENTER_NAME"]``: ``--truth``
  compares it with the log's centre, EARTH or SUN);
- ``REF_FRAME`` EME2000, GCRF, ICRF or J2000 -- J2000 is the name JPL's and Orekit's files
  give EME2000 (the mean equator and equinox of J2000.0, ODM annex A) and is read as
  EME2000; the three inertial frames are treated as one, as in the rest of fgnav; the value
  written in the file is kept in ``meta``;
- ephemeris lines of 7 fields or 10 (with accelerations: ``a_eci`` (N, 3) m/s**2, or None
  when no line has them; one layout per segment);
- covariance blocks at any epoch and in any ``COV_REF_FRAME`` (5.2.5), all of them in
  ``cov_t_s``/``cov_P``/``cov_frame`` (None: the segment's REF_FRAME) in file order.
  ``P_eci`` is ``None`` when the file has none, otherwise (N, 6, 6) holding the blocks in an
  inertial frame at an epoch of an ephemeris line of their segment, NaN elsewhere
  (``meta["covariance_missing"]`` epochs without one, ``meta["covariance_unmatched"]`` blocks
  at other epochs, ``meta["covariance_other_frame"]`` blocks in another frame, e.g. RTN).

:func:`write_oem_data` writes all of it back (see there). Refused, with an
:class:`~fgnav.errors.InputFormatError` naming the file, the line and the keyword: any
``TIME_SYSTEM`` but UTC, a non-inertial ``REF_FRAME`` (TOD, ITRF...), the XML form, and every
departure from the standard the `oem` package's invalid samples and Orekit's test files
contain: a keyword of another version (CLASSIFICATION or MESSAGE_ID before 3.0,
REF_FRAME_EPOCH, accelerations or covariances in a 1.0), a header keyword twice, an
``INTERPOLATION_DEGREE`` that is not a positive integer or missing beside ``INTERPOLATION``
(table 5-3), ``USEABLE_START_TIME`` without ``USEABLE_STOP_TIME`` (or the reverse), after it
or outside START/STOP_TIME, useable spans of consecutive segments overlapping (5.2.4.4),
lines of 7 and 10 fields mixed in one segment (as the `oem` package reads 5.2.4.1), any
malformed line, a missing required keyword, epochs not increasing inside a segment or
outside START/STOP_TIME. ``docs/ccsds-corpus.md`` lists every corpus file and its outcome.

(The PyPI ``oem`` package reads and writes OEM with covariance but pulls in astropy and
lxml and reports errors without line numbers; this small module is used instead.)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fgnav.errors import InputFormatError, UserError
from fgnav.io.atomic import atomic_writer
from fgnav.io.kvn import (HEADER_KEYS, ccsds_epochs, check_meta_value, epoch_value,
                          format_ccsds_epoch, header_line, kvn_header, number_value,
                          parse_ccsds_epoch, read_kvn_lines, split_kvn, version_line)
from fgnav.io.number_text import render_rows
from fgnav.time import add_seconds, parse_utc, seconds_since

__all__ = ["OemData", "write_oem", "write_oem_data", "read_oem", "parse_ccsds_epoch",
           "format_ccsds_epoch", "oem_frame"]

_M_PER_KM = 1000.0
_INERTIAL_FRAMES = ("EME2000", "J2000", "GCRF", "ICRF")


def oem_frame(centre: str) -> dict:
    """``write_oem``'s centre and frame keywords for a pass's central body (``"earth"``:
    the defaults, EARTH / EME2000; ``"sun"``: SUN / ICRF, the heliocentric frame of a cruise,
    whose axes fgnav takes equal to EME2000's)."""
    return {} if centre == "earth" else {"center_name": "SUN", "ref_frame": "ICRF"}


_META_REQUIRED = ("OBJECT_NAME", "OBJECT_ID", "CENTER_NAME", "REF_FRAME", "TIME_SYSTEM",
                  "START_TIME", "STOP_TIME")
_META_OPTIONAL = ("REF_FRAME_EPOCH", "USEABLE_START_TIME", "USEABLE_STOP_TIME",
                  "INTERPOLATION", "INTERPOLATION_DEGREE")


@dataclass
class OemData:
    """An OEM read back in SI: ``epoch0`` (datetime64[ns] UTC, the first epoch), ``t_s`` (N,)
    s from it, ``x_eci`` (N, 6) [m, m/s], ``P_eci`` (N, 6, 6) SI or None, ``meta``; the
    file's accelerations ``a_eci`` (N, 3) [m/s**2] or None, and every covariance block
    ``cov_t_s`` (K,) s, ``cov_P`` (K, 6, 6) SI, ``cov_frame`` (K COV_REF_FRAMEs, None where
    absent) or None, in file order (see the module docstring)."""

    epoch0: np.datetime64
    t_s: np.ndarray
    x_eci: np.ndarray
    P_eci: np.ndarray | None
    meta: dict = field(default_factory=dict)
    a_eci: np.ndarray | None = None
    cov_t_s: np.ndarray | None = None
    cov_frame: list = field(default_factory=list)
    cov_row: np.ndarray | None = None     # (K,) the row of P_eci holding block k, or -1
    cov_other: np.ndarray | None = None   # the blocks with cov_row -1, in file order

    @property
    def cov_P(self) -> np.ndarray | None:
        """(K, 6, 6) every covariance block in file order, SI (assembled from ``P_eci`` and
        ``cov_other``, so that a file of fgnav's, a block per epoch, is held once)."""
        if self.cov_row is None:
            return None
        out = np.empty((len(self.cov_row), 6, 6))
        mine = self.cov_row >= 0
        out[mine] = self.P_eci[self.cov_row[mine]]
        out[~mine] = self.cov_other
        return out


_STATE_COLS = ("X", "Y", "Z", "X_DOT", "Y_DOT", "Z_DOT", "X_DDOT", "Y_DDOT", "Z_DDOT")
_EPOCH_KEYS = ("START_TIME", "STOP_TIME", "USEABLE_START_TIME", "USEABLE_STOP_TIME",
               "REF_FRAME_EPOCH")
_VERSIONS = ("1.0", "2.0", "3.0")


def _inertial(frame) -> bool:
    """True for the inertial frames fgnav reads as one (EME2000, its alias J2000, GCRF, ICRF)."""
    return frame is None or frame.upper() in _INERTIAL_FRAMES


def _check_segment_meta(path, lineno, segment, version, previous):
    """The rules of ODM 502.0-B-3 table 5-3 that span keywords, at META_STOP: the required
    keywords; USEABLE_START/STOP_TIME both or neither, in order, inside START/STOP_TIME;
    INTERPOLATION_DEGREE with INTERPOLATION; REF_FRAME_EPOCH not in OEM 1.0; the centre of
    the previous segments."""
    for k in _META_REQUIRED:
        if k not in segment:
            raise InputFormatError(path, lineno, k, f"metadata keyword {k} before META_STOP",
                                   "META_STOP")
    if segment["START_TIME_ns"] > segment["STOP_TIME_ns"]:
        raise InputFormatError(path, segment["lines"]["STOP_TIME"], "STOP_TIME", "STOP_TIME "
                               f"not before START_TIME {segment['START_TIME']}",
                               segment["STOP_TIME"])
    have = [k for k in ("USEABLE_START_TIME", "USEABLE_STOP_TIME") if k in segment]
    if len(have) == 1:
        other = ({"USEABLE_START_TIME", "USEABLE_STOP_TIME"} - set(have)).pop()
        raise InputFormatError(path, segment["lines"][have[0]], have[0], f"{have[0]} together "
                               f"with {other} (ODM 502.0-B-3 table 5-3)", f"no {other}")
    if have:
        a, b = segment["USEABLE_START_TIME_ns"], segment["USEABLE_STOP_TIME_ns"]
        if a > b:
            raise InputFormatError(path, segment["lines"]["USEABLE_STOP_TIME"],
                                   "USEABLE_STOP_TIME", "USEABLE_STOP_TIME not before "
                                   f"USEABLE_START_TIME {segment['USEABLE_START_TIME']}",
                                   segment["USEABLE_STOP_TIME"])
        for k, t in (("USEABLE_START_TIME", a), ("USEABLE_STOP_TIME", b)):
            if not segment["START_TIME_ns"] <= t <= segment["STOP_TIME_ns"]:
                raise InputFormatError(path, segment["lines"][k], k, f"{k} between START_TIME "
                                       f"{segment['START_TIME']} and STOP_TIME "
                                       f"{segment['STOP_TIME']}", segment[k])
    if "INTERPOLATION" in segment and "INTERPOLATION_DEGREE" not in segment:
        raise InputFormatError(path, segment["lines"]["INTERPOLATION"], "INTERPOLATION_DEGREE",
                               "INTERPOLATION_DEGREE with INTERPOLATION (ODM 502.0-B-3 "
                               "table 5-3)", "none")
    if version == "1.0" and "REF_FRAME_EPOCH" in segment:
        raise InputFormatError(path, segment["lines"]["REF_FRAME_EPOCH"], "REF_FRAME_EPOCH",
                               "no REF_FRAME_EPOCH in an OEM 1.0 (502.0-B-1 has no such "
                               "keyword; write CCSDS_OEM_VERS = 2.0)", segment["REF_FRAME_EPOCH"])
    for sg in previous:
        if sg["CENTER_NAME"].upper() != segment["CENTER_NAME"].upper():
            raise InputFormatError(path, segment["lines"]["CENTER_NAME"], "CENTER_NAME",
                                   f"the same CENTER_NAME in every segment ({sg['CENTER_NAME']}, "
                                   f"line {sg['lines']['CENTER_NAME']}: fgnav reads the "
                                   "segments as one trajectory)", segment["CENTER_NAME"])


def _useable(segment) -> tuple[str, int, int]:
    """(keyword, start ns, stop ns) of a segment's useable span: USEABLE_START/STOP_TIME, or
    START/STOP_TIME without them."""
    if "USEABLE_START_TIME" in segment:
        return ("USEABLE_START_TIME", segment["USEABLE_START_TIME_ns"],
                segment["USEABLE_STOP_TIME_ns"])
    return "START_TIME", segment["START_TIME_ns"], segment["STOP_TIME_ns"]


def _check_useable_order(path, prev, segment):
    """ODM 502.0-B-3 5.2.4.4: the useable spans of consecutive segments do not overlap (a
    shared end point allowed; the total spans may, for interpolation)."""
    kp, _, stop_prev = _useable(prev)
    key, start, _ = _useable(segment)
    if start < stop_prev:
        kstop = kp.replace("START", "STOP")
        raise InputFormatError(path, segment["lines"][key], key, "a useable span that does "
                               "not overlap the previous segment's (ODM 502.0-B-3 5.2.4.4): "
                               f"{key} not before {kstop} {prev[kstop]} (line "
                               f"{prev['lines'][kstop]})", segment[key])


def read_oem(path) -> OemData:
    """Read an OEM (KVN) file into SI arrays (see the module docstring for what is accepted)."""
    lines = read_kvn_lines(path)
    n0, version = version_line(path, lines, "OEM", _VERSIONS)
    it = iter([(n, t) for n, t in lines if t.strip() and n > n0])
    meta: dict = {"comments": [], "segments": [], "CCSDS_OEM_VERS": version}
    header_keys = HEADER_KEYS + ("CLASSIFICATION",) if version == "3.0" else (
        "CREATION_DATE", "ORIGINATOR")

    epochs: list[int] = []
    states: list[list[float]] = []
    accels: list[list[float]] = []
    covs: list[tuple[int, int, np.ndarray, str | None]] = []  # (epoch ns, line, P SI, frame)
    segment = None
    state = "header"
    last_line = n0
    cov_epoch = cov_line = cov_frame = None
    cov_vals: list[float] = []
    seg_epochs: list[int] = []
    seg_width = [None]  # fields per ephemeris line in the segment (7 or 10)

    def close_segment(lineno):
        if segment is None or "rows" in segment:
            return
        if not seg_epochs:
            raise InputFormatError(path, lineno, None, "at least one ephemeris data line in the "
                                   "segment", "none")
        segment["rows"] = (len(epochs) - len(seg_epochs), len(epochs))

    def finish_cov_block(lineno):
        if cov_epoch is None:
            return
        if len(cov_vals) != 21:
            raise InputFormatError(path, lineno, "covariance", "21 lower-triangular covariance "
                                   "values after EPOCH", f"{len(cov_vals)} values")
        P = np.zeros((6, 6))
        P[np.tril_indices(6)] = cov_vals
        P = P + np.tril(P, -1).T
        covs.append((cov_epoch, cov_line, P, cov_frame))

    def new_segment(lineno):
        return {"comments": [], "line": lineno, "lines": {}}

    for lineno, text in it:
        last_line = lineno
        s = text.strip()
        if s.startswith("COMMENT"):
            if s == "COMMENT" or s[7] in " \t":
                (segment or meta).setdefault("comments", []).append(s[7:].strip())
                continue
        if state == "header":
            if header_line(path, lineno, s, meta, keys=header_keys):
                state = "meta"
                segment = new_segment(lineno)
            continue
        if state == "meta":
            if s == "META_STOP":
                _check_segment_meta(path, lineno, segment, version, meta["segments"])
                prev = meta["segments"][-1] if meta["segments"] else None
                if prev is not None:
                    _check_useable_order(path, prev, segment)
                state = "data"
                seg_epochs = []
                seg_width[0] = None
                meta["segments"].append(segment)
                continue
            key, val = split_kvn(path, lineno, text, "OEM metadata")
            if key not in _META_REQUIRED + _META_OPTIONAL:
                raise InputFormatError(path, lineno, key, "an OEM metadata keyword "
                                       f"({', '.join(_META_REQUIRED + _META_OPTIONAL)})", s)
            if key in segment:
                raise InputFormatError(path, lineno, key, "each metadata keyword once",
                                       f"{key} repeated")
            if key == "TIME_SYSTEM" and val != "UTC":
                raise InputFormatError(path, lineno, key, "TIME_SYSTEM = UTC (the only time "
                                       "system fgnav reads)", val)
            if key == "REF_FRAME" and not _inertial(val):
                raise InputFormatError(path, lineno, key, "REF_FRAME = EME2000 (or J2000, GCRF, "
                                       "ICRF: the inertial frame fgnav reads)", val)
            if key == "INTERPOLATION_DEGREE" and not (val.isdigit() and int(val) >= 1):
                raise InputFormatError(path, lineno, key, "a positive integer (the number of "
                                       "points of the interpolation, ODM 502.0-B-3 table 5-3)",
                                       val)
            if key in _EPOCH_KEYS:
                segment[key + "_ns"] = int(epoch_value(path, lineno, key, val).astype(np.int64))
            segment[key] = val
            segment["lines"][key] = lineno
            continue
        if s == "META_START" and state in ("data", "cov_done"):
            close_segment(lineno)
            state = "meta"
            segment = new_segment(lineno)
            continue
        if state == "data":
            if s == "COVARIANCE_START":
                close_segment(lineno)
                if version == "1.0":
                    raise InputFormatError(path, lineno, "COVARIANCE_START", "no covariance "
                                           "section in an OEM 1.0 (added in 502.0-B-2; write "
                                           "CCSDS_OEM_VERS = 2.0)", s)
                state = "cov"
                cov_epoch = None
                cov_vals = []
                continue
            parts = s.split()
            if len(parts) not in (7, 10):
                raise InputFormatError(path, lineno, None, "an ephemeris line 'epoch X Y Z X_DOT "
                                       "Y_DOT Z_DOT' (7 fields, or 10 with accelerations), "
                                       "META_START or COVARIANCE_START",
                                       f"{len(parts)} fields: {s[:60]!r}")
            if len(parts) == 10 and version == "1.0":
                raise InputFormatError(path, lineno, "X_DDOT", "7 fields in an OEM 1.0 "
                                       "(accelerations were added in 502.0-B-2; write "
                                       "CCSDS_OEM_VERS = 2.0)", f"10 fields: {s[:60]!r}")
            if seg_width[0] is None:
                seg_width[0] = (len(parts), lineno)
            elif seg_width[0][0] != len(parts):
                raise InputFormatError(path, lineno, None, f"{seg_width[0][0]} fields, as on the "
                                       f"segment's first ephemeris line {seg_width[0][1]} (one "
                                       "segment does not mix lines with and without "
                                       "accelerations)", f"{len(parts)} fields: {s[:60]!r}")
            t = int(epoch_value(path, lineno, "epoch", parts[0]).astype(np.int64))
            vals = [number_value(path, lineno, _STATE_COLS[j], p, _M_PER_KM)
                    for j, p in enumerate(parts[1:])]
            if seg_epochs and t <= seg_epochs[-1]:
                raise InputFormatError(path, lineno, "epoch", "epochs increasing within a "
                                       "segment", parts[0])
            if not segment["START_TIME_ns"] <= t <= segment["STOP_TIME_ns"]:
                raise InputFormatError(path, lineno, "epoch", "an epoch between START_TIME "
                                       f"{segment['START_TIME']} and STOP_TIME "
                                       f"{segment['STOP_TIME']}", parts[0])
            seg_epochs.append(t)
            epochs.append(t)
            states.append(vals[:6])
            accels.append(vals[6:] or [np.nan] * 3)
            continue
        if state == "cov":
            if s == "COVARIANCE_STOP":
                finish_cov_block(lineno)
                cov_epoch = None
                state = "cov_done"
                segment["covs"] = (segment.get("covs", (len(covs),))[0], len(covs))
                continue
            segment.setdefault("covs", (len(covs),))
            if "=" in s:
                key, val = split_kvn(path, lineno, text, "OEM covariance section")
                if key == "EPOCH":
                    finish_cov_block(lineno)
                    cov_epoch = int(epoch_value(path, lineno, key, val).astype(np.int64))
                    cov_line = lineno
                    cov_frame = None
                    cov_vals = []
                    continue
                if key == "COV_REF_FRAME":
                    if cov_epoch is None or cov_vals or cov_frame is not None:
                        raise InputFormatError(path, lineno, key, "COV_REF_FRAME once, right "
                                               "after EPOCH", s)
                    cov_frame = val
                    continue
                raise InputFormatError(path, lineno, key, "EPOCH, COV_REF_FRAME, covariance "
                                       "rows or COVARIANCE_STOP", s)
            if cov_epoch is None:
                raise InputFormatError(path, lineno, "EPOCH", "'EPOCH = ...' before covariance "
                                       "rows", s[:60])
            parts = s.split()
            n_before = len(cov_vals)
            # Rows of the lower triangle: after k full rows (k(k+1)/2 values) row k+1 has k+1.
            k = 0
            while k * (k + 1) // 2 < n_before:
                k += 1
            if k * (k + 1) // 2 != n_before or len(parts) != k + 1 or k >= 6:
                raise InputFormatError(path, lineno, f"covariance row {k + 1}",
                                       f"{k + 1} values (row {k + 1} of the lower triangle)"
                                       if k < 6 else "EPOCH or COVARIANCE_STOP after 6 rows",
                                       f"{len(parts)} values")
            for j, p in enumerate(parts):
                cov_vals.append(number_value(path, lineno, f"covariance row {k + 1}, value "
                                             f"{j + 1}", p, _M_PER_KM**2))
            continue
        if state == "cov_done":
            raise InputFormatError(path, lineno, None, "META_START (a new segment) or end of file"
                                   " after COVARIANCE_STOP", s[:60])
        raise AssertionError(state)  # pragma: no cover (all states handled above)

    if state == "header":
        raise InputFormatError(path, last_line + 1, "META_START", "a segment (META_START ... "
                               "META_STOP, then ephemeris lines)", "end of file")
    if state == "meta":
        raise InputFormatError(path, last_line + 1, "META_STOP", "META_STOP closing the "
                               "metadata", "end of file")
    if state == "cov":
        raise InputFormatError(path, last_line + 1, "COVARIANCE_STOP", "COVARIANCE_STOP closing "
                               "the covariance section", "end of file")
    if state == "data":
        close_segment(last_line + 1)

    ns = np.array(epochs, dtype=np.int64)
    X = np.array(states, dtype=float)  # already in m, m/s
    A = np.array(accels, dtype=float)
    epoch0 = np.datetime64(int(ns[0]), "ns")
    t_s = seconds_since(ns.astype("datetime64[ns]"), epoch0)
    P = cov_t = cov_row = cov_other = None
    cov_frames: list = []
    if covs:
        P = np.full((len(ns), 6, 6), np.nan)
        seg_of_cov = np.zeros(len(covs), dtype=int)
        for i, sg in enumerate(meta["segments"]):
            if "covs" in sg:
                seg_of_cov[sg["covs"][0]:sg["covs"][1]] = i
        cov_ns = np.array([c[0] for c in covs], dtype=np.int64)
        inertial = np.array([_inertial(c[3]) for c in covs])
        row = np.full(len(covs), -1)
        for i, sg in enumerate(meta["segments"]):   # epochs increase within a segment
            sel = np.flatnonzero(seg_of_cov == i)
            if not len(sel):
                continue
            i0, i1 = sg["rows"]
            j = np.clip(np.searchsorted(ns[i0:i1], cov_ns[sel]), 0, i1 - i0 - 1)
            hit = ns[i0:i1][j] == cov_ns[sel]
            row[sel[hit]] = i0 + j[hit]
        use = (row >= 0) & inertial
        last = np.zeros(len(covs), dtype=bool)   # of blocks at one epoch the last one counts
        idx = np.flatnonzero(use)
        _, first_rev = np.unique(row[idx][::-1], return_index=True)
        last[idx[::-1][first_rev]] = True
        P[row[last]] = np.array([covs[k][2] for k in np.flatnonzero(last)]).reshape(-1, 6, 6)
        unmatched = int((row < 0).sum())
        other_frame = int(((row >= 0) & ~inertial).sum())
        meta["covariance_missing"] = int(np.isnan(P[:, 0, 0]).sum())
        meta["covariance_unmatched"] = unmatched
        meta["covariance_other_frame"] = other_frame
        cov_t = seconds_since(cov_ns.astype("datetime64[ns]"), epoch0)
        cov_row = np.where(last, row, -1)
        cov_other = np.array([covs[k][2] for k in np.flatnonzero(~last)]).reshape(-1, 6, 6)
        cov_frames = [c[3] for c in covs]
    first_seg = meta["segments"][0]
    for k in _META_REQUIRED + _META_OPTIONAL:
        if k in first_seg:
            meta.setdefault(k, first_seg[k])
    return OemData(epoch0=epoch0, t_s=t_s, x_eci=X, P_eci=P, meta=meta,
                   a_eci=A if np.isfinite(A).any() else None, cov_t_s=cov_t, cov_frame=cov_frames,
                   cov_row=cov_row, cov_other=cov_other)


_CHUNK = 20000
"""Epochs formatted and written at a time by :func:`write_oem` (bounded memory)."""


def _symmetric(P: np.ndarray) -> np.ndarray:
    """0.5 (P + P^T) of (K, 6, 6) covariances."""
    return 0.5 * (P + np.swapaxes(P, 1, 2))


def write_oem(path, epoch0, t_s, x_eci, P_eci=None, *, object_name="FGNAV",
              object_id="UNKNOWN", originator="FGNAV", center_name="EARTH",
              ref_frame="EME2000", time_system="UTC", comments=(), creation_date=None) -> None:
    """Write states (and covariances) as a CCSDS OEM 2.0 KVN file, atomically.

    ``epoch0`` datetime64 (UTC) or ISO string; ``t_s`` (N,) s from ``epoch0``, increasing;
    ``x_eci`` (N, 6) [m, m/s] in ``ref_frame``; ``P_eci`` (N, 6, 6) SI or None; an epoch
    whose covariance has a NaN/inf gets no covariance block (read back as NaN). Written in
    km, km/s, km**2 (see the module docstring). ``creation_date`` (datetime64) defaults to now.
    """
    if isinstance(epoch0, str):
        epoch0 = parse_utc(epoch0)
    t_s = np.asarray(t_s, dtype=float).reshape(-1)
    x = np.asarray(x_eci, dtype=float)
    N = len(t_s)
    if N == 0 or x.shape != (N, 6):
        raise UserError(f"write_oem: need t_s (N,) and x_eci (N, 6) with N >= 1; found "
                        f"{t_s.shape}, {x.shape}")
    if not (np.all(np.isfinite(t_s)) and np.all(np.isfinite(x))):
        raise UserError("write_oem: t_s and x_eci must be finite")
    t64 = add_seconds(epoch0, t_s)
    if np.any(np.diff(t64.astype(np.int64)) <= 0):
        raise UserError("write_oem: epochs must be strictly increasing")
    P = None
    if P_eci is not None:
        P = np.asarray(P_eci, dtype=float)
        if P.shape != (N, 6, 6):
            raise UserError(f"write_oem: P_eci must have shape ({N}, 6, 6), found {P.shape}")
    if time_system != "UTC":
        raise UserError(f"write_oem: only TIME_SYSTEM = UTC is supported, found {time_system!r}")
    names = {"OBJECT_NAME": object_name, "OBJECT_ID": object_id, "CENTER_NAME": center_name,
             "REF_FRAME": ref_frame, "TIME_SYSTEM": time_system, "ORIGINATOR": originator}
    names = {k: check_meta_value(k, v) for k, v in names.items()}
    ep = ccsds_epochs(t64)

    out = kvn_header("CCSDS_OEM_VERS = 2.0", comments, creation_date, names["ORIGINATOR"])
    out.append("META_START\n")
    for k in ("OBJECT_NAME", "OBJECT_ID", "CENTER_NAME", "REF_FRAME", "TIME_SYSTEM"):
        out.append(f"{k} = {names[k]}\n")
    out.append(f"START_TIME = {ep[0]}\nSTOP_TIME = {ep[-1]}\nMETA_STOP\n\n")
    # covariances written symmetrized, 0.5 (P + P^T), formed per chunk of epochs (not two
    # more (N, 6, 6) arrays: 0.6 GB at 1,000,000 epochs)
    has_cov = [] if P is None else np.flatnonzero(np.concatenate(
        [np.all(np.isfinite(_symmetric(P[i0:i0 + _CHUNK])), axis=(1, 2))
         for i0 in range(0, N, _CHUNK)]))
    with atomic_writer(path, "wb") as f:
        f.write("".join(out).encode("utf-8"))
        # streamed in chunks (a 1,000,000-epoch solution is ~0.6 GB of text), each number as
        # "%" writes it (fgnav.io.number_text)
        state = [("f", 9)] * 3 + [("f", 12)] * 3
        for i0 in range(0, N, _CHUNK):
            f.write(render_rows([[e + " " for e in ep[i0:i0 + _CHUNK]]] + [" "] * 5 + ["\n"],
                                x[i0:i0 + _CHUNK] / _M_PER_KM, state))
        if len(has_cov):
            f.write(b"\nCOVARIANCE_START\n")
            head = f"\nCOV_REF_FRAME = {names['REF_FRAME']}\n"
            seps = [" " * (b < a) or "\n" for a in range(6) for b in range(a + 1)]
            lower = np.tril_indices(6)
            for i0 in range(0, len(has_cov), _CHUNK):
                idx = has_cov[i0:i0 + _CHUNK]
                low = (_symmetric(P[idx]) / _M_PER_KM**2)[:, lower[0], lower[1]]
                f.write(render_rows([[f"EPOCH = {ep[i]}{head}" for i in idx.tolist()]] + seps,
                                    low, [("e", 16)] * 21))
            f.write(b"COVARIANCE_STOP\n")



_META_ORDER = ("OBJECT_NAME", "OBJECT_ID", "CENTER_NAME", "REF_FRAME", "REF_FRAME_EPOCH",
               "TIME_SYSTEM", "START_TIME", "USEABLE_START_TIME", "USEABLE_STOP_TIME",
               "STOP_TIME", "INTERPOLATION", "INTERPOLATION_DEGREE")


def write_oem_data(path, data: OemData) -> None:
    """Write an :class:`OemData` as read by :func:`read_oem` back as a KVN OEM, atomically:
    its version, header keywords (CLASSIFICATION, MESSAGE_ID of an OEM 3.0), comments, every
    segment with its metadata as read, its ephemeris lines (with accelerations where the file
    had them) and its covariance blocks at any epoch, each with its COV_REF_FRAME.

    Numbers are written in the file's units (km, km/s, km/s**2, km**2...) as the shortest
    text that reads back to the same double (Python's ``repr``), so a file read and written
    again gives the values of the source to every digit it printed (up to 16 significant
    digits; ODM 502.0-B-3 5.2.4, 5.2.5).
    """
    meta = data.meta
    n = len(data.t_s)
    ep = ccsds_epochs(add_seconds(data.epoch0, np.asarray(data.t_s, dtype=float)))
    segments = meta.get("segments") or [{**{k: meta[k] for k in _META_ORDER if k in meta},
                                         "rows": (0, n)}]
    out = [f"CCSDS_OEM_VERS = {meta.get('CCSDS_OEM_VERS', '2.0')}\n"]
    out += [f"COMMENT {c}\n" for c in meta.get("comments", [])]
    for k in ("CLASSIFICATION", "CREATION_DATE", "ORIGINATOR", "MESSAGE_ID"):
        if k in meta:
            out.append(f"{k} = {meta[k]}\n")
    cov_ep = [] if data.cov_t_s is None else ccsds_epochs(
        add_seconds(data.epoch0, np.asarray(data.cov_t_s, dtype=float)))
    for sg in segments:
        out.append("\nMETA_START\n")
        out += [f"COMMENT {c}\n" for c in sg.get("comments", [])]
        out += [f"{k} = {sg[k]}\n" for k in _META_ORDER if k in sg]
        out.append("META_STOP\n\n")
        i0, i1 = sg["rows"]
        for i in range(i0, i1):
            x = data.x_eci[i] / _M_PER_KM
            line = f"{ep[i]} " + " ".join(map(repr, x.tolist()))
            if data.a_eci is not None and np.all(np.isfinite(data.a_eci[i])):
                line += " " + " ".join(map(repr, (data.a_eci[i] / _M_PER_KM).tolist()))
            out.append(line + "\n")
        if "covs" in sg and sg["covs"][1] > sg["covs"][0]:
            out.append("\nCOVARIANCE_START\n")
            for k in range(*sg["covs"]):
                out.append(f"EPOCH = {cov_ep[k]}\n")
                if data.cov_frame and data.cov_frame[k] is not None:
                    out.append(f"COV_REF_FRAME = {data.cov_frame[k]}\n")
                P = data.cov_P[k] / _M_PER_KM**2
                out += [" ".join(repr(float(P[a, b])) for b in range(a + 1)) + "\n"
                        for a in range(6)]
            out.append("COVARIANCE_STOP\n")
    with atomic_writer(path, "wb") as f:
        f.write("".join(out).encode("utf-8"))
