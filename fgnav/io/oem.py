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
(``YYYY-DDD``) epochs with or without ``Z``; ephemeris lines of 7 fields (or 10, with
accelerations, which are ignored); several segments are concatenated in file order.
Supported: ``TIME_SYSTEM = UTC``, ``CENTER_NAME = EARTH`` or ``SUN`` (a heliocentric cruise;
the same centre in every segment, ``meta["CENTER_NAME"]``), ``REF_FRAME`` EME2000 / GCRF /
ICRF (treated as the same inertial frame, as in the rest of fgnav) and a ``COV_REF_FRAME``
equal to the segment's ``REF_FRAME``; anything else is an
:class:`~fgnav.errors.InputFormatError` naming the line, as is any malformed line, a missing
required keyword, epochs not increasing inside a segment or outside START/STOP_TIME.
Covariance blocks are matched to ephemeris epochs exactly; ``P_eci`` is ``None`` when the
file has none, otherwise (N, 6, 6) with NaN for epochs without one
(``meta["covariance_missing"]`` counts them, ``meta["covariance_unmatched"]`` counts blocks at
epochs with no ephemeris line).

(The PyPI ``oem`` package reads and writes OEM with covariance but pulls in astropy and
lxml and reports errors without line numbers; this small module is used instead.)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fgnav.errors import InputFormatError, UserError
from fgnav.io.atomic import atomic_writer
from fgnav.io.kvn import (ccsds_epochs, check_meta_value, epoch_value, format_ccsds_epoch,
                          header_line, kvn_header, number_value, parse_ccsds_epoch,
                          read_kvn_lines, split_kvn)
from fgnav.io.number_text import render_rows
from fgnav.time import add_seconds, parse_utc, seconds_since

__all__ = ["OemData", "write_oem", "read_oem", "parse_ccsds_epoch", "format_ccsds_epoch", "oem_frame"]

_M_PER_KM = 1000.0
_INERTIAL_FRAMES = ("EME2000", "GCRF", "ICRF")
_CENTERS = ("EARTH", "SUN")


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
    s from it, ``x_eci`` (N, 6) [m, m/s], ``P_eci`` (N, 6, 6) SI or None, ``meta``."""

    epoch0: np.datetime64
    t_s: np.ndarray
    x_eci: np.ndarray
    P_eci: np.ndarray | None
    meta: dict = field(default_factory=dict)


_STATE_COLS = ("X", "Y", "Z", "X_DOT", "Y_DOT", "Z_DOT", "X_DDOT", "Y_DDOT", "Z_DDOT")


def read_oem(path) -> OemData:
    """Read an OEM (KVN) file into SI arrays (see the module docstring for what is accepted)."""
    lines = read_kvn_lines(path)
    it = iter([(n, t) for n, t in lines if t.strip()])
    meta: dict = {"comments": [], "segments": []}

    # --- header
    first = next(it, None)
    if first is None:
        raise InputFormatError(path, 1, "CCSDS_OEM_VERS", "an OEM starting with "
                               "'CCSDS_OEM_VERS = 2.0'", "empty file")
    n0, t0 = first
    key, val = split_kvn(path, n0, t0, "the first line is CCSDS_OEM_VERS = 2.0")
    if key != "CCSDS_OEM_VERS":
        raise InputFormatError(path, n0, key, "CCSDS_OEM_VERS = 2.0 as the first line", t0.strip())
    if val not in ("1.0", "2.0", "3.0"):
        raise InputFormatError(path, n0, "CCSDS_OEM_VERS", "version 1.0, 2.0 or 3.0", val)
    meta["CCSDS_OEM_VERS"] = val

    epochs: list[int] = []
    states: list[list[float]] = []
    covs: list[tuple[int, int, np.ndarray]] = []  # (epoch ns, line, P in SI)
    segment = None
    state = "header"
    last_line = n0
    cov_epoch = cov_line = None
    cov_vals: list[float] = []
    seg_epochs: list[int] = []

    def close_segment(lineno):
        if segment is None:
            return
        if not seg_epochs:
            raise InputFormatError(path, lineno, None, "at least one ephemeris data line in the "
                                   "segment", "none")

    def finish_cov_block(lineno):
        if cov_epoch is None:
            return
        if len(cov_vals) != 21:
            raise InputFormatError(path, lineno, "covariance", "21 lower-triangular covariance "
                                   "values after EPOCH", f"{len(cov_vals)} values")
        P = np.zeros((6, 6))
        P[np.tril_indices(6)] = cov_vals
        P = P + np.tril(P, -1).T
        covs.append((cov_epoch, cov_line, P))

    for lineno, text in it:
        last_line = lineno
        s = text.strip()
        if s.startswith("COMMENT"):
            if s == "COMMENT" or s[7] in " \t":
                (segment or meta).setdefault("comments", []).append(s[7:].strip())
                continue
        if state == "header":
            if header_line(path, lineno, s, meta):
                state = "meta"
                segment = {"comments": [], "line": lineno}
            continue
        if state == "meta":
            if s == "META_STOP":
                for k in _META_REQUIRED:
                    if k not in segment:
                        raise InputFormatError(path, lineno, k, f"metadata keyword {k} before "
                                               "META_STOP", "META_STOP")
                state = "data"
                seg_epochs = []
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
            if key == "CENTER_NAME" and (val.upper() not in _CENTERS or any(
                    sg.get("CENTER_NAME", val).upper() != val.upper() for sg in meta["segments"])):
                raise InputFormatError(path, lineno, key, "CENTER_NAME = EARTH or SUN, the "
                                       "same in every segment", val)
            if key == "REF_FRAME" and val not in _INERTIAL_FRAMES:
                raise InputFormatError(path, lineno, key, "REF_FRAME = EME2000 (or GCRF, ICRF)",
                                       val)
            if key in ("START_TIME", "STOP_TIME", "USEABLE_START_TIME", "USEABLE_STOP_TIME",
                       "REF_FRAME_EPOCH"):
                segment[key + "_ns"] = int(epoch_value(path, lineno, key, val).astype(np.int64))
            segment[key] = val
            continue
        if s == "META_START" and state in ("data", "cov_done"):
            close_segment(lineno)
            state = "meta"
            segment = {"comments": [], "line": lineno}
            continue
        if state == "data":
            if s == "COVARIANCE_START":
                close_segment(lineno)
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
            continue
        if state == "cov":
            if s == "COVARIANCE_STOP":
                finish_cov_block(lineno)
                cov_epoch = None
                state = "cov_done"
                continue
            if "=" in s:
                key, val = split_kvn(path, lineno, text, "OEM covariance section")
                if key == "EPOCH":
                    finish_cov_block(lineno)
                    cov_epoch = int(epoch_value(path, lineno, key, val).astype(np.int64))
                    cov_line = lineno
                    cov_vals = []
                    continue
                if key == "COV_REF_FRAME":
                    if cov_epoch is None or cov_vals:
                        raise InputFormatError(path, lineno, key, "COV_REF_FRAME right after "
                                               "EPOCH", s)
                    if val != segment["REF_FRAME"]:
                        raise InputFormatError(path, lineno, key, "COV_REF_FRAME equal to the "
                                               f"segment's REF_FRAME {segment['REF_FRAME']} "
                                               "(other covariance frames are not supported)", val)
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
                cov_vals.append(number_value(path, lineno, f"covariance row {k + 1}, value {j + 1}", p,
                                        _M_PER_KM**2))
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
    epoch0 = np.datetime64(int(ns[0]), "ns")
    t_s = seconds_since(ns.astype("datetime64[ns]"), epoch0)
    P = None
    if covs:
        P = np.full((len(ns), 6, 6), np.nan)
        index = {}
        for j, t in enumerate(ns.tolist()):
            index.setdefault(t, []).append(j)
        unmatched = 0
        for t, _line, Pk in covs:
            js = index.get(t)
            if js is None:
                unmatched += 1
                continue
            for j in js:
                P[j] = Pk  # already in m**2, m**2/s, m**2/s**2
        meta["covariance_missing"] = int(np.isnan(P[:, 0, 0]).sum())
        meta["covariance_unmatched"] = unmatched
    first_seg = meta["segments"][0]
    for k in _META_REQUIRED + _META_OPTIONAL:
        if k in first_seg:
            meta.setdefault(k, first_seg[k])
    return OemData(epoch0=epoch0, t_s=t_s, x_eci=X, P_eci=P, meta=meta)


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

