"""CCSDS Orbit Parameter Message (OPM, CCSDS 502.0-B-3 sec. 3), KVN form: one state vector,
optionally its covariance.

Read (``read_opm``): versions 1.0-3.0 (``CCSDS_OPM_VERS`` on the first line); the state
``EPOCH``, ``X``, ``Y``, ``Z`` (km), ``X_DOT``, ``Y_DOT``, ``Z_DOT`` (km/s); ``CENTER_NAME``
EARTH or SUN; ``TIME_SYSTEM = UTC``; ``REF_FRAME`` EME2000 / GCRF / ICRF / J2000 (one
inertial frame in fgnav, as in the OEM reader) or TEME (rotated to EME2000 by the reader of
the prior, :mod:`fgnav.prior_sources`); the optional covariance (sec. 3.2.4) in
``COV_REF_FRAME`` equal to ``REF_FRAME`` (the default) or ``RTN`` / ``RSW`` (radial,
transverse, normal of the state). The Keplerian elements and spacecraft parameters are
checked as numbers and not used (the Cartesian state is the message's state). Manoeuvres
(``MAN_*``) and the other frames (body-fixed ITRF, TOD, ...) are refused: an
:class:`~fgnav.errors.InputFormatError` naming the file, the line and the keyword, as for
any malformed line, unknown keyword, wrong unit or missing required keyword.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgnav.errors import InputFormatError
from fgnav.io.odm import COVARIANCE_KEYS, check_known, covariance, epoch, number, read_entries

__all__ = ["OpmData", "read_opm", "OPM_FRAMES"]

OPM_FRAMES = ("EME2000", "GCRF", "ICRF", "J2000", "TEME")
"""Accepted ``REF_FRAME`` values (the first four one inertial frame in fgnav)."""

_HEADER = ("CCSDS_OPM_VERS", "CREATION_DATE", "ORIGINATOR", "MESSAGE_ID", "CLASSIFICATION")
_META = ("OBJECT_NAME", "OBJECT_ID", "CENTER_NAME", "REF_FRAME", "REF_FRAME_EPOCH",
         "TIME_SYSTEM")
_STATE = ("EPOCH", "X", "Y", "Z", "X_DOT", "Y_DOT", "Z_DOT")
_KEPLER = ("SEMI_MAJOR_AXIS", "ECCENTRICITY", "INCLINATION", "RA_OF_ASC_NODE",
           "ARG_OF_PERICENTER", "TRUE_ANOMALY", "MEAN_ANOMALY", "GM")
_KEPLER_UNITS = {"SEMI_MAJOR_AXIS": "km", "ECCENTRICITY": "", "GM": "km**3/s**2"}
_SPACECRAFT = {"MASS": "kg", "SOLAR_RAD_AREA": "m**2", "SOLAR_RAD_COEFF": "",
               "DRAG_AREA": "m**2", "DRAG_COEFF": ""}
_MANOEUVRE = ("MAN_EPOCH_IGNITION", "MAN_DURATION", "MAN_DELTA_MASS", "MAN_REF_FRAME",
              "MAN_DV_1", "MAN_DV_2", "MAN_DV_3")
_KNOWN = (_HEADER + _META + _STATE + _KEPLER + tuple(_SPACECRAFT) + ("COV_REF_FRAME",)
          + COVARIANCE_KEYS + _MANOEUVRE)
_REQUIRED = ("OBJECT_NAME", "CENTER_NAME", "REF_FRAME", "TIME_SYSTEM") + _STATE


@dataclass(frozen=True)
class OpmData:
    """An OPM's state in SI: ``epoch`` (fgnav's time scale), ``x`` (6,) m, m/s in
    ``frame`` about ``centre`` (``"earth"`` / ``"sun"``); ``P`` (6, 6) SI or None, in
    ``cov_frame`` (``frame``, or ``"RTN"``); ``path``, ``line`` (of EPOCH), ``name``."""

    epoch: np.datetime64
    x: np.ndarray
    frame: str
    centre: str
    P: np.ndarray | None
    cov_frame: str
    path: str
    line: int
    name: str


def read_opm(path) -> OpmData:
    """Read a KVN OPM (see the module docstring)."""
    entries, xml = read_entries(path, "an OPM")
    if xml:
        raise InputFormatError(path, 1, None, "an OPM in KVN form (the XML OPM is not read; "
                               "an OMM may be XML)", "XML")
    if not entries or entries[0].key != "CCSDS_OPM_VERS":
        first = entries[0] if entries else None
        raise InputFormatError(path, first.line if first else 1, "CCSDS_OPM_VERS",
                               "CCSDS_OPM_VERS = 1.0 .. 3.0 on the first line",
                               first.key if first else "an empty file")
    by = check_known(path, entries, _KNOWN, "an OPM (CCSDS 502.0-B-3 sec. 3)",
                     repeatable=_MANOEUVRE)
    number(path, by["CCSDS_OPM_VERS"], "", 1.0, 3.0)
    for k in _REQUIRED:
        if k not in by:
            raise InputFormatError(path, entries[-1].line, k, f"the keyword {k}", "end of file")
    man = [k for k in _MANOEUVRE if k in by]
    if man:
        e = by[man[0]]
        raise InputFormatError(path, e.line, e.key, "an OPM without manoeuvres (fgnav takes "
                               "a prior from a coasting state)", e.value)
    centre = by["CENTER_NAME"].value.upper()
    if centre not in ("EARTH", "SUN"):
        e = by["CENTER_NAME"]
        raise InputFormatError(path, e.line, e.key, "EARTH or SUN", e.value)
    frame = by["REF_FRAME"].value.upper()
    if frame not in OPM_FRAMES or (centre == "SUN" and frame == "TEME"):
        e = by["REF_FRAME"]
        raise InputFormatError(path, e.line, e.key, f"an inertial frame: "
                               f"{', '.join(OPM_FRAMES)} (TEME about the Earth only)", e.value)
    if by["TIME_SYSTEM"].value.upper() != "UTC":
        e = by["TIME_SYSTEM"]
        raise InputFormatError(path, e.line, e.key, "UTC", e.value)
    cov_frame = frame
    if "COV_REF_FRAME" in by:
        e = by["COV_REF_FRAME"]
        v = e.value.upper()
        if v in ("RTN", "RSW"):
            cov_frame = "RTN"
        elif v != frame:
            raise InputFormatError(path, e.line, e.key, f"{frame} (the REF_FRAME), RTN or RSW",
                                   e.value)
    for k in _KEPLER:
        if k in by:
            number(path, by[k], _KEPLER_UNITS.get(k, "deg"))
    for k, unit in _SPACECRAFT.items():
        if k in by:
            number(path, by[k], unit)
    x = np.array([number(path, by[k], "km" if i < 3 else "km/s") * 1e3
                  for i, k in enumerate(_STATE[1:])])
    return OpmData(epoch=epoch(path, by["EPOCH"]), x=x, frame=frame, centre=centre.lower(),
                   P=covariance(path, by), cov_frame=cov_frame, path=str(path),
                   line=by["EPOCH"].line, name=by["OBJECT_NAME"].value)
