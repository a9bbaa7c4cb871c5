"""CCSDS Orbit Mean-Elements Message (OMM, CCSDS 502.0-B-3 sec. 4), KVN or XML, as
CelesTrak writes them: the SGP4 mean elements of one object.

Read (``read_omm``): versions 1.0-3.0 (``CCSDS_OMM_VERS``, or the XML root ``omm``); one
segment; ``CENTER_NAME = EARTH``, ``REF_FRAME = TEME``, ``TIME_SYSTEM = UTC`` and
``MEAN_ELEMENT_THEORY`` SGP4 (``SGP4`` or ``SGP/SGP4``: the only theory whose mean elements
fgnav can turn into a state, through the ``sgp4`` package); ``EPOCH``, ``MEAN_MOTION``
(rev/day), ``ECCENTRICITY``, ``INCLINATION``, ``RA_OF_ASC_NODE``, ``ARG_OF_PERICENTER``,
``MEAN_ANOMALY`` (deg) required; the TLE parameters ``BSTAR`` (1/ER), ``MEAN_MOTION_DOT``
(rev/day**2), ``MEAN_MOTION_DDOT`` (rev/day**3) zero when absent, ``NORAD_CAT_ID`` 0 when
absent; an optional covariance (sec. 4.2.4), in ``COV_REF_FRAME`` TEME (the default: the
frame of the mean elements). Header values may be empty (CelesTrak leaves
``CREATION_DATE`` and ``ORIGINATOR`` so). Any other keyword, value, unit or frame is an
:class:`~fgnav.errors.InputFormatError` naming the file, the line and the keyword.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgnav.errors import InputFormatError
from fgnav.io.odm import COVARIANCE_KEYS, check_known, covariance, epoch, number, read_entries

__all__ = ["MeanElements", "read_omm", "SGP4_THEORIES"]

SGP4_THEORIES = ("SGP4", "SGP/SGP4")

_HEADER = ("CCSDS_OMM_VERS", "CREATION_DATE", "ORIGINATOR", "MESSAGE_ID", "CLASSIFICATION")
_META = ("OBJECT_NAME", "OBJECT_ID", "CENTER_NAME", "REF_FRAME", "REF_FRAME_EPOCH",
         "TIME_SYSTEM", "MEAN_ELEMENT_THEORY")
_ELEMENTS = ("EPOCH", "SEMI_MAJOR_AXIS", "MEAN_MOTION", "ECCENTRICITY", "INCLINATION",
             "RA_OF_ASC_NODE", "ARG_OF_PERICENTER", "MEAN_ANOMALY", "GM")
_SPACECRAFT = ("MASS", "SOLAR_RAD_AREA", "SOLAR_RAD_COEFF", "DRAG_AREA", "DRAG_COEFF")
_TLE = ("EPHEMERIS_TYPE", "CLASSIFICATION_TYPE", "NORAD_CAT_ID", "ELEMENT_SET_NO",
        "REV_AT_EPOCH", "BSTAR", "BTERM", "MEAN_MOTION_DOT", "MEAN_MOTION_DDOT", "AGOM")
_KNOWN = _HEADER + _META + _ELEMENTS + _SPACECRAFT + _TLE + ("COV_REF_FRAME",) + COVARIANCE_KEYS
_REQUIRED = ("OBJECT_NAME", "CENTER_NAME", "REF_FRAME", "TIME_SYSTEM", "MEAN_ELEMENT_THEORY",
             "EPOCH", "MEAN_MOTION", "ECCENTRICITY", "INCLINATION", "RA_OF_ASC_NODE",
             "ARG_OF_PERICENTER", "MEAN_ANOMALY")
_XML_ONLY = ("omm", "header", "body", "segment", "metadata", "data")


@dataclass(frozen=True)
class MeanElements:
    """SGP4 mean elements of one object, from an OMM or a TLE: ``epoch`` (fgnav's time scale,
    UTC), ``n_rev_day`` (Kozai mean motion), ``e``, ``i_deg``, ``raan_deg``, ``argp_deg``,
    ``M_deg``, ``bstar`` (1/earth radii), ``ndot`` (rev/day**2), ``nddot`` (rev/day**3),
    ``satnum``; ``P_teme`` an optional covariance (6, 6, SI, TEME at the epoch); ``path``,
    ``line`` (of EPOCH / the first TLE line) and ``name`` for messages."""

    epoch: np.datetime64
    n_rev_day: float
    e: float
    i_deg: float
    raan_deg: float
    argp_deg: float
    M_deg: float
    bstar: float = 0.0
    ndot: float = 0.0
    nddot: float = 0.0
    satnum: int = 0
    P_teme: np.ndarray | None = None
    path: str = ""
    line: int = 0
    name: str = ""


def _fixed(path, e, allowed, what):
    if e.value.upper() not in allowed:
        raise InputFormatError(path, e.line, e.key, f"{' or '.join(allowed)} ({what})", e.value)


def read_omm(path) -> MeanElements:
    """Read an OMM (KVN or XML) into :class:`MeanElements` (see the module docstring)."""
    entries, xml = read_entries(path, "an OMM")
    if xml:
        entries = [e for e in entries if e.key not in _XML_ONLY]
    elif not entries or entries[0].key != "CCSDS_OMM_VERS":
        first = entries[0] if entries else None
        raise InputFormatError(path, first.line if first else 1, "CCSDS_OMM_VERS",
                               "CCSDS_OMM_VERS = 1.0 .. 3.0 on the first line",
                               first.key if first else "an empty file")
    by = check_known(path, entries, _KNOWN, "an OMM (CCSDS 502.0-B-3 sec. 4)")
    if "CCSDS_OMM_VERS" in by:
        number(path, by["CCSDS_OMM_VERS"], "", 1.0, 3.0)
    for k in _REQUIRED:
        if k not in by:
            last = entries[-1].line if entries else 1
            raise InputFormatError(path, last, k, f"the keyword {k} (required by fgnav's "
                                   "SGP4 prior)", "end of file")
    _fixed(path, by["CENTER_NAME"], ("EARTH",), "a geocentric orbit")
    _fixed(path, by["REF_FRAME"], ("TEME",), "the frame of SGP4 mean elements")
    _fixed(path, by["TIME_SYSTEM"], ("UTC",), "the time system fgnav reads")
    _fixed(path, by["MEAN_ELEMENT_THEORY"], SGP4_THEORIES,
           "the mean-element theory fgnav propagates")
    if "COV_REF_FRAME" in by:
        _fixed(path, by["COV_REF_FRAME"], ("TEME",), "the covariance frame fgnav reads")
    if "BTERM" in by or "AGOM" in by:
        e = by.get("BTERM") or by["AGOM"]
        raise InputFormatError(path, e.line, e.key, "BSTAR (SGP4's drag term; BTERM and AGOM "
                               "belong to SGP4-XP)", e.value)
    opt = lambda k, unit, lo=-np.inf, hi=np.inf: (   # noqa: E731
        number(path, by[k], unit, lo, hi) if k in by else 0.0)
    satnum = 0
    if "NORAD_CAT_ID" in by:
        e = by["NORAD_CAT_ID"]
        if not e.value.isdigit() or int(e.value) > 999_999_999:
            raise InputFormatError(path, e.line, e.key, "a catalogue number (digits)", e.value)
        satnum = int(e.value)
    if "EPHEMERIS_TYPE" in by and by["EPHEMERIS_TYPE"].value not in ("0", "2"):
        e = by["EPHEMERIS_TYPE"]
        raise InputFormatError(path, e.line, e.key, "0 or 2 (SGP4)", e.value)
    return MeanElements(
        epoch=epoch(path, by["EPOCH"]),
        n_rev_day=number(path, by["MEAN_MOTION"], "rev/day", 0.0, 100.0, lo_open=True),
        e=number(path, by["ECCENTRICITY"], "", 0.0, 1.0, lo_open=False),
        i_deg=number(path, by["INCLINATION"], "deg", 0.0, 180.0),
        raan_deg=number(path, by["RA_OF_ASC_NODE"], "deg", -360.0, 360.0),
        argp_deg=number(path, by["ARG_OF_PERICENTER"], "deg", -360.0, 360.0),
        M_deg=number(path, by["MEAN_ANOMALY"], "deg", -360.0, 360.0),
        bstar=opt("BSTAR", "1/ER"), ndot=opt("MEAN_MOTION_DOT", "rev/day**2"),
        nddot=opt("MEAN_MOTION_DDOT", "rev/day**3"), satnum=satnum,
        P_teme=covariance(path, by), path=str(path), line=by["EPOCH"].line,
        name=by["OBJECT_NAME"].value)
