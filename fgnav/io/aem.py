"""CCSDS Attitude Ephemeris Message (AEM), KVN form (CCSDS 504.0-B-2, "Attitude Data Messages",
Blue Book issue 2, 2024).

Written (``write_aem``, atomically)::

    CCSDS_AEM_VERS = 2.0
    COMMENT ...                      (optional, one per comment)
    CREATION_DATE = 2024-03-01T12:00:00.000000
    ORIGINATOR = FGNAV

    META_START
    OBJECT_NAME = FGNAV
    OBJECT_ID = UNKNOWN
    CENTER_NAME = EARTH
    REF_FRAME_A = EME2000
    REF_FRAME_B = SC_BODY_1
    TIME_SYSTEM = UTC
    START_TIME = <first epoch>
    STOP_TIME = <last epoch>
    ATTITUDE_TYPE = QUATERNION
    META_STOP

    DATA_START
    <epoch> Q1 Q2 Q3 QC              (one line per epoch, dimensionless, 12 decimals)
    DATA_STOP

Quaternion convention (CCSDS 504.0-B-2, table 4-4 and annex F2). The quaternion "from frame
A to frame B" is that of the rotation which carries the basis vectors of A onto those of B:
``Q1, Q2, Q3 = e sin(phi/2)``, ``QC = cos(phi/2)`` (rotation axis ``e``, angle ``phi``), and
coordinates transform as ``X_B = M_BA X_A`` with ``M_BA`` the matrix of annex F2.1. In AEM
2.0 the order on a data line is fixed, the scalar LAST: ``EPOCH Q1 Q2 Q3 QC`` (the keywords
``QUATERNION_TYPE`` and ``ATTITUDE_DIR`` of AEM 1.0 were removed). With A = EME2000 and B =
the spacecraft body, the body axes are the images of the EME2000 axes, i.e. the columns of
``R_eci_from_body``; so ``(QC, Q1, Q2, Q3)`` is exactly fgnav's scalar-first quaternion
``(w, x, y, z)`` of ``R_eci_from_body`` (as ``gtsam.Rot3.Quaternion``), and ``M_BA =
R_eci_from_body^T``. The standard's own example (annex F2.2): body = EME2000 turned by +90 deg
about Z (body X along EME2000 Y) is ``Q1 = 0, Q2 = 0, Q3 = 0.7071, QC = 0.7071``. The
conversion happens only here, at the file boundary.

Sign: ``q`` and ``-q`` are the same rotation. The first record is written with ``QC >= 0``
and every later one with the sign that makes it continuous with the previous record
(non-negative dot product), so that the component-wise interpolation the standard names
(LAGRANGE, HERMITE) is meaningful across a half turn.

Epochs are CCSDS ASCII time code A, UTC (:func:`fgnav.io.oem.format_ccsds_epoch`: leap
seconds written as ``23:59:60.f``, elapsed SI seconds between epochs, :mod:`fgnav.time`).

Read (``read_aem``): versions 1.0 (CCSDS 504.0-B-1, 2008) and 2.0; calendar or day-of-year
epochs; several segments are concatenated in file order (a segment may not start before the
previous one ends). Supported: ``TIME_SYSTEM = UTC``; ``ATTITUDE_TYPE`` QUATERNION,
QUATERNION/DERIVATIVE, QUATERNION/ANGVEL (2.0) or QUATERNION/RATE (1.0) -- the quaternion is
read, further columns are checked as numbers and ignored; one of ``REF_FRAME_A`` /
``REF_FRAME_B`` inertial (EME2000, GCRF, ICRF, J2000: the same inertial frame in fgnav) and
the other the body frame, the same body frame in every segment (a body-to-inertial quaternion
is inverted). In 1.0 files ``ATTITUDE_DIR`` (A2B / B2A) is required and ``QUATERNION_TYPE``
(FIRST / LAST) says where the scalar is; in 2.0 files both keywords are errors, since the
standard fixed their meaning. Quaternions must have unit norm within 1e-3 (they are then
normalized). Anything else -- a malformed line, an unknown or missing keyword, epochs not
increasing inside a segment or outside START/STOP_TIME -- is an
:class:`~fgnav.errors.InputFormatError` naming the file, the line and the keyword.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fgnav.errors import InputFormatError, UserError
from fgnav.io.atomic import atomic_writer
from fgnav.io.kvn import (check_meta_value, epoch_value, format_ccsds_epoch, header_line,
                          kvn_header, number_value, read_kvn_lines, split_kvn, version_line)
from fgnav.time import add_seconds, parse_utc, seconds_since
from fgnav.vision.attitude import matrix_from_quat, quat_from_matrix

__all__ = ["AemData", "write_aem", "write_aem_data", "read_aem", "aem_quaternions",
           "INERTIAL_FRAMES"]

INERTIAL_FRAMES = ("EME2000", "GCRF", "ICRF", "J2000")
_HEADER_KEYS = ("CREATION_DATE", "ORIGINATOR", "MESSAGE_ID", "CLASSIFICATION")
_META_REQUIRED = ("OBJECT_NAME", "OBJECT_ID", "REF_FRAME_A", "REF_FRAME_B", "TIME_SYSTEM",
                  "START_TIME", "STOP_TIME", "ATTITUDE_TYPE")
_META_OPTIONAL = ("CENTER_NAME", "USEABLE_START_TIME", "USEABLE_STOP_TIME", "EULER_ROT_SEQ",
                  "ANGVEL_FRAME", "RATE_FRAME", "INTERPOLATION_METHOD", "INTERPOLATION_DEGREE")
_META_V1_ONLY = ("ATTITUDE_DIR", "QUATERNION_TYPE")
_EPOCH_KEYS = ("START_TIME", "STOP_TIME", "USEABLE_START_TIME", "USEABLE_STOP_TIME")
# ATTITUDE_TYPE -> number of values after the epoch (quaternion first, then ignored rates)
_TYPES = {"2.0": {"QUATERNION": 4, "QUATERNION/DERIVATIVE": 8, "QUATERNION/ANGVEL": 7},
          "1.0": {"QUATERNION": 4, "QUATERNION/DERIVATIVE": 8, "QUATERNION/RATE": 7}}
_NORM_TOL = 1e-3
_DIGITS = 12


@dataclass
class AemData:
    """An AEM read back: ``epoch0`` (datetime64[ns] UTC, the first epoch), ``t_s`` (N,) s from
    it, ``q_wxyz`` (N, 4) unit quaternions of ``R_eci_from_body``, scalar first (fgnav's
    convention, converted from the file's), ``meta`` (header and first segment's keywords,
    ``body_frame``, ``segments``, ``comments``)."""

    epoch0: np.datetime64
    t_s: np.ndarray
    q_wxyz: np.ndarray
    meta: dict = field(default_factory=dict)

    def R_eci_from_body(self) -> np.ndarray:
        """(N, 3, 3) rotation matrices of the quaternions."""
        return np.array([matrix_from_quat(q) for q in self.q_wxyz]).reshape(-1, 3, 3)


def aem_quaternions(R_eci_from_body) -> np.ndarray:
    """(N, 3, 3) ``R_eci_from_body`` -> (N, 4) AEM quaternions ``Q1, Q2, Q3, QC`` from EME2000 to
    the body, scalar last (see the module docstring), the first with ``QC >= 0`` and each later
    one sign-continuous with the one before."""
    R = np.asarray(R_eci_from_body, dtype=float).reshape(-1, 3, 3)
    q = np.array([quat_from_matrix(Rk) for Rk in R]).reshape(-1, 4)  # (w, x, y, z), w >= 0
    for k in range(1, len(q)):
        if q[k] @ q[k - 1] < 0.0:
            q[k] = -q[k]
    return q[:, [1, 2, 3, 0]]


def write_aem(path, epoch0, t_s, R_eci_from_body, *, object_name="FGNAV", object_id="UNKNOWN",
              originator="FGNAV", center_name="EARTH", ref_frame_a="EME2000",
              ref_frame_b="SC_BODY_1", comments=(), creation_date=None) -> None:
    """Write attitudes as a CCSDS AEM 2.0 KVN file (one segment, quaternions), atomically.

    ``epoch0`` datetime64 (UTC) or ISO string; ``t_s`` (N,) s from ``epoch0``, strictly
    increasing; ``R_eci_from_body`` (N, 3, 3) proper rotations from the body frame
    ``ref_frame_b`` to the inertial ``ref_frame_a``. ``creation_date`` (datetime64) defaults
    to now. Invalid arguments raise :class:`~fgnav.errors.UserError`.
    """
    if isinstance(epoch0, str):
        epoch0 = parse_utc(epoch0)
    t_s = np.asarray(t_s, dtype=float).reshape(-1)
    R = np.asarray(R_eci_from_body, dtype=float)
    N = len(t_s)
    if N == 0 or R.shape != (N, 3, 3):
        raise UserError(f"write_aem: need t_s (N,) and R_eci_from_body (N, 3, 3) with N >= 1; "
                        f"found {t_s.shape}, {R.shape}")
    if not (np.all(np.isfinite(t_s)) and np.all(np.isfinite(R))):
        raise UserError("write_aem: t_s and R_eci_from_body must be finite")
    orth = np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max()
    if orth > 1e-6 or np.any(np.linalg.det(R) < 0):
        raise UserError(f"write_aem: R_eci_from_body must be proper rotations (|R R^T - I| = "
                        f"{orth:.3g}, det {np.linalg.det(R).min():.3g})")
    t64 = add_seconds(epoch0, t_s)
    if np.any(np.diff(t64.astype(np.int64)) <= 0):
        raise UserError("write_aem: epochs must be strictly increasing")
    if ref_frame_a not in INERTIAL_FRAMES:
        raise UserError(f"write_aem: ref_frame_a must be an inertial frame "
                        f"({', '.join(INERTIAL_FRAMES)}), found {ref_frame_a!r}")
    names = {"OBJECT_NAME": object_name, "OBJECT_ID": object_id, "CENTER_NAME": center_name,
             "REF_FRAME_A": ref_frame_a, "REF_FRAME_B": ref_frame_b, "ORIGINATOR": originator}
    names = {k: check_meta_value(k, v, "write_aem") for k, v in names.items()}
    if names["REF_FRAME_B"] in INERTIAL_FRAMES:
        raise UserError(f"write_aem: ref_frame_b is the body frame (e.g. SC_BODY_1), found "
                        f"{ref_frame_b!r}")
    ep = [format_ccsds_epoch(t) for t in t64]
    Q = aem_quaternions(R)

    out = kvn_header("CCSDS_AEM_VERS = 2.0", comments, creation_date, names["ORIGINATOR"])
    out.append("META_START\n")
    for k in ("OBJECT_NAME", "OBJECT_ID", "CENTER_NAME", "REF_FRAME_A", "REF_FRAME_B"):
        out.append(f"{k} = {names[k]}\n")
    out.append("TIME_SYSTEM = UTC\n")
    out.append(f"START_TIME = {ep[0]}\nSTOP_TIME = {ep[-1]}\n")
    out.append("ATTITUDE_TYPE = QUATERNION\nMETA_STOP\n\nDATA_START\n")
    out.extend(f"{e} " + " ".join(f"{v:.{_DIGITS}f}" for v in q) + "\n" for e, q in zip(ep, Q))
    out.append("DATA_STOP\n")
    with atomic_writer(path) as f:
        f.write("".join(out))


def _segment_meta(path, lineno, key, val, segment, version):
    """Check one metadata keyword of a segment and store it in ``segment``."""
    allowed = _META_REQUIRED + _META_OPTIONAL + (_META_V1_ONLY if version == "1.0" else ())
    if key in _META_V1_ONLY and version != "1.0":
        raise InputFormatError(path, lineno, key, f"no {key} in an AEM {version} (CCSDS "
                               "504.0-B-2 fixed its meaning: quaternion from REF_FRAME_A to "
                               "REF_FRAME_B, scalar QC last); use CCSDS_AEM_VERS = 1.0 for a "
                               f"file that needs {key}", f"{key} = {val}")
    if key not in allowed:
        raise InputFormatError(path, lineno, key, f"an AEM {version} metadata keyword "
                               f"({', '.join(allowed)})", f"{key} = {val}")
    if key in segment:
        raise InputFormatError(path, lineno, key, "each metadata keyword once", f"{key} repeated")
    if key == "TIME_SYSTEM" and val != "UTC":
        raise InputFormatError(path, lineno, key, "TIME_SYSTEM = UTC (the only time system "
                               "fgnav reads)", val)
    if key == "ATTITUDE_TYPE" and val not in _TYPES[version]:
        raise InputFormatError(path, lineno, key, "a quaternion ATTITUDE_TYPE (" +
                               ", ".join(_TYPES[version]) + "; Euler angles and spin are not "
                               "read)", val)
    if key == "ATTITUDE_DIR" and val not in ("A2B", "B2A"):
        raise InputFormatError(path, lineno, key, "ATTITUDE_DIR = A2B or B2A", val)
    if key == "QUATERNION_TYPE" and val not in ("FIRST", "LAST"):
        raise InputFormatError(path, lineno, key, "QUATERNION_TYPE = FIRST or LAST", val)
    if key in _EPOCH_KEYS:
        segment[key + "_ns"] = int(epoch_value(path, lineno, key, val).astype(np.int64))
    segment[key] = val
    segment["lines"][key] = lineno


def _close_meta(path, lineno, segment, version, meta):
    """At META_STOP: required keywords present, frames usable; sets the segment's conversion
    (``scalar_first``, ``invert``) and the body frame."""
    required = _META_REQUIRED + (("ATTITUDE_DIR", "QUATERNION_TYPE") if version == "1.0" else ())
    for k in required:
        if k not in segment:
            raise InputFormatError(path, lineno, k, f"metadata keyword {k} before META_STOP",
                                   "META_STOP")
    a, b = segment["REF_FRAME_A"], segment["REF_FRAME_B"]
    where = segment["lines"]
    if (a in INERTIAL_FRAMES) == (b in INERTIAL_FRAMES):
        raise InputFormatError(path, where["REF_FRAME_B"], "REF_FRAME_B", "one of REF_FRAME_A / "
                               f"REF_FRAME_B inertial ({', '.join(INERTIAL_FRAMES)}) and the other "
                               "the spacecraft body frame", f"REF_FRAME_A = {a}, REF_FRAME_B = {b}")
    body = b if a in INERTIAL_FRAMES else a
    if meta.setdefault("body_frame", body) != body:
        key = "REF_FRAME_A" if body == a else "REF_FRAME_B"
        raise InputFormatError(path, where[key], key, "the body frame of the first segment, "
                               f"{meta['body_frame']}", body)
    if segment["START_TIME_ns"] > segment["STOP_TIME_ns"]:
        raise InputFormatError(path, where["STOP_TIME"], "STOP_TIME", "STOP_TIME not before START_TIME",
                               segment["STOP_TIME"])
    # the quaternion in the file rotates the file's "from" frame into its "to" frame; fgnav
    # wants the one from the inertial frame to the body (R_eci_from_body)
    invert = a not in INERTIAL_FRAMES
    if segment.get("ATTITUDE_DIR") == "B2A":
        invert = not invert
    segment["invert"] = invert
    segment["scalar_first"] = segment.get("QUATERNION_TYPE") == "FIRST"
    segment["n_values"] = _TYPES[version][segment["ATTITUDE_TYPE"]]


def read_aem(path) -> AemData:
    """Read an AEM (KVN) file (see the module docstring for what is accepted)."""
    lines = read_kvn_lines(path)
    n0, version = version_line(path, lines, "AEM", tuple(sorted(_TYPES)))
    it = iter([(n, t) for n, t in lines if t.strip() and n > n0])
    meta: dict = {"comments": [], "segments": []}
    meta["CCSDS_AEM_VERS"] = version

    epochs: list[int] = []
    quats: list[np.ndarray] = []
    segment: dict | None = None
    seg_epochs: list[int] = []
    state = "header"
    last_line = n0
    for lineno, text in it:
        last_line = lineno
        s = text.strip()
        if s.startswith("COMMENT") and (s == "COMMENT" or s[7] in " \t"):
            (segment or meta)["comments"].append(s[7:].strip())
            continue
        if state == "header":
            if header_line(path, lineno, s, meta, keys=_HEADER_KEYS):
                state = "meta"
                segment = {"comments": [], "line": lineno, "lines": {}}
            continue
        if state == "meta":
            if s == "META_STOP":
                _close_meta(path, lineno, segment, version, meta)
                meta["segments"].append(segment)
                state = "before_data"
                continue
            key, val = split_kvn(path, lineno, text, "AEM metadata")
            _segment_meta(path, lineno, key, val, segment, version)
            continue
        if state == "before_data":
            if s != "DATA_START":
                raise InputFormatError(path, lineno, "DATA_START", "DATA_START after META_STOP",
                                       s[:60])
            state = "data"
            seg_epochs = []
            continue
        if state == "data":
            if s == "DATA_STOP":
                if not seg_epochs:
                    raise InputFormatError(path, lineno, "DATA_STOP", "at least one attitude "
                                           "data line between DATA_START and DATA_STOP", s)
                state = "after_data"
                segment["rows"] = (len(epochs) - len(seg_epochs), len(epochs))
                continue
            quats.append(_data_line(path, lineno, s, segment))
            t = int(epoch_value(path, lineno, "EPOCH", s.split()[0]).astype(np.int64))
            if seg_epochs and t <= seg_epochs[-1]:
                raise InputFormatError(path, lineno, "EPOCH", "epochs increasing within a "
                                       "segment (no repeats)", s.split()[0])
            if not segment["START_TIME_ns"] <= t <= segment["STOP_TIME_ns"]:
                raise InputFormatError(path, lineno, "EPOCH", "an epoch between START_TIME "
                                       f"{segment['START_TIME']} and STOP_TIME "
                                       f"{segment['STOP_TIME']}", s.split()[0])
            if not seg_epochs and epochs and t < epochs[-1]:
                raise InputFormatError(path, lineno, "EPOCH", "segments in time order (this "
                                       "segment starts before the previous one ends)",
                                       s.split()[0])
            seg_epochs.append(t)
            epochs.append(t)
            continue
        if state == "after_data":
            if s != "META_START":
                raise InputFormatError(path, lineno, None, "META_START (a new segment) or end "
                                       "of file after DATA_STOP", s[:60])
            state = "meta"
            segment = {"comments": [], "line": lineno, "lines": {}}
            continue
        raise AssertionError(state)  # pragma: no cover (all states handled above)

    ends = {"header": ("META_START", "a segment (META_START ... META_STOP, DATA_START ... "
                       "DATA_STOP)"),
            "meta": ("META_STOP", "META_STOP closing the metadata"),
            "before_data": ("DATA_START", "DATA_START after META_STOP"),
            "data": ("DATA_STOP", "DATA_STOP closing the attitude data")}
    if state in ends:
        raise InputFormatError(path, last_line + 1, ends[state][0], ends[state][1], "end of file")

    ns = np.array(epochs, dtype=np.int64)
    epoch0 = np.datetime64(int(ns[0]), "ns")
    first_seg = meta["segments"][0]
    for k in _META_REQUIRED + _META_OPTIONAL + _META_V1_ONLY:
        if k in first_seg:
            meta.setdefault(k, first_seg[k])
    return AemData(epoch0=epoch0, t_s=seconds_since(ns.astype("datetime64[ns]"), epoch0),
                   q_wxyz=np.array(quats).reshape(-1, 4), meta=meta)


def _data_line(path, lineno, s, segment) -> np.ndarray:
    """One attitude data line -> unit quaternion (w, x, y, z) of R_eci_from_body."""
    parts = s.split()
    n = segment["n_values"]
    order = ("QC", "Q1", "Q2", "Q3") if segment["scalar_first"] else ("Q1", "Q2", "Q3", "QC")
    if len(parts) != n + 1:
        raise InputFormatError(path, lineno, None, f"an attitude data line 'EPOCH "
                               f"{' '.join(order)}' with {n} values for ATTITUDE_TYPE = "
                               f"{segment['ATTITUDE_TYPE']}, or DATA_STOP",
                               f"{len(parts)} fields: {s[:60]!r}")
    vals = [number_value(path, lineno, order[j] if j < 4 else f"value {j + 1}", p)
            for j, p in enumerate(parts[1:])]
    q = dict(zip(order, vals[:4]))
    wxyz = np.array([q["QC"], q["Q1"], q["Q2"], q["Q3"]])
    norm = float(np.linalg.norm(wxyz))
    if abs(norm - 1.0) > _NORM_TOL:
        raise InputFormatError(path, lineno, "Q1", f"a unit quaternion (norm 1 within "
                               f"{_NORM_TOL:g})", f"norm {norm:.6g}")
    wxyz /= norm
    if segment["invert"]:
        wxyz[1:] = -wxyz[1:]
    return wxyz


_META_ORDER = ("OBJECT_NAME", "OBJECT_ID", "CENTER_NAME", "REF_FRAME_A", "REF_FRAME_B",
               "TIME_SYSTEM", "START_TIME", "USEABLE_START_TIME", "USEABLE_STOP_TIME",
               "STOP_TIME", "ATTITUDE_TYPE", "INTERPOLATION_METHOD", "INTERPOLATION_DEGREE")


def write_aem_data(path, data: AemData) -> None:
    """Write an :class:`AemData` as read by :func:`read_aem` back as an AEM 2.0 KVN file,
    atomically: its header keywords and comments, every segment with its metadata, in the
    AEM 2.0 form of the module docstring -- ``REF_FRAME_A`` the segment's inertial frame,
    ``REF_FRAME_B`` its body frame, ``ATTITUDE_TYPE = QUATERNION``, ``EPOCH Q1 Q2 Q3 QC``
    with the quaternion as read (an AEM 1.0's ATTITUDE_DIR / QUATERNION_TYPE and a body-to-
    inertial quaternion already resolved; rates, which fgnav does not read, are not written).
    Numbers as the shortest text that reads back to the same double (``repr``)."""
    meta = data.meta
    ep = [format_ccsds_epoch(t) for t in add_seconds(data.epoch0, np.asarray(data.t_s, float))]
    out = ["CCSDS_AEM_VERS = 2.0\n"] + [f"COMMENT {c}\n" for c in meta.get("comments", [])]
    for k in ("CLASSIFICATION", "CREATION_DATE", "ORIGINATOR", "MESSAGE_ID"):
        if k in meta:
            out.append(f"{k} = {meta[k]}\n")
    for sg in meta["segments"]:
        a, b = sg["REF_FRAME_A"], sg["REF_FRAME_B"]
        inertial, body = (a, b) if a in INERTIAL_FRAMES else (b, a)
        keys = {**sg, "REF_FRAME_A": inertial, "REF_FRAME_B": body,
                "ATTITUDE_TYPE": "QUATERNION"}
        out.append("\nMETA_START\n")
        out += [f"COMMENT {c}\n" for c in sg.get("comments", [])]
        out += [f"{k} = {keys[k]}\n" for k in _META_ORDER if k in keys]
        out.append("META_STOP\n\nDATA_START\n")
        for i in range(*sg["rows"]):
            w, x, y, z = data.q_wxyz[i].tolist()
            out.append(f"{ep[i]} {x!r} {y!r} {z!r} {w!r}\n")
        out.append("DATA_STOP\n")
    with atomic_writer(path) as f:
        f.write("".join(out))
