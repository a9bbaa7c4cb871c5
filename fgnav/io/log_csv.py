"""The logged-pass measurement file, CSV format v1 (users' scripts depend on it: keep exactly).

Format
------
A UTF-8 CSV file (an initial byte-order mark is ignored). Lines whose first non-blank
character is ``#`` are comments; blank lines are ignored. The first other line is the
header::

    epoch,kind,x,y,z,sigma[,gamma][,sigma_model_m][,star_x,star_y,star_z][,body][,body2]
        [,att_c11,att_c12,att_c13,att_c22,att_c23,att_c33]
        [,spacecraft][,tx_spacecraft][,rx_antenna][,tx_antenna]

The six base columns are required, in this order; the optional extra columns ``gamma`` and
``sigma_model_m`` (used by ``refraction`` rows), ``star_x``, ``star_y``, ``star_z`` (used
by ``star_direction_body`` and the star-angle rows), ``body``, ``body2`` (a near body's
name, one of ``sun``, ``earth``, ``moon``: the angle rows) and ``att_c11``, ``att_c12``,
``att_c13``, ``att_c22``, ``att_c23``, ``att_c33`` (an ``attitude`` row's covariance) may
follow, in any order, each at most once. Every row has exactly as many comma-separated fields as the header; whitespace around
a field is ignored; an empty field is "no value" (read as NaN). ``epoch`` is ISO-8601 UTC
ending in ``Z``: ``YYYY-MM-DDTHH:MM:SS[.fffffffff]Z`` (up to 9 fraction digits; years
1678..2261, the range of ``datetime64[ns]``; second ``60`` at the end of a day with a leap
second, mapped to elapsed SI seconds by :mod:`fgnav.time`). Numbers
are decimal (``1``, ``-2.5``, ``6.4e6``).

Central body: a comment line ``# centre: sun`` before the header declares a heliocentric log
(a cruise): every position and velocity (prior rows, the state the rows observe) is then
relative to the Sun's centre, axes EME2000/ICRF; without it (or with ``# centre: earth``) the
log is geocentric, as every v1 log. Another name is an error naming the line (column
``centre``), and so are two such lines that disagree. Readers that ignore comments read the
rows unchanged, so the line is an extension of v1, not a new version. A heliocentric log
holds only the kinds of :data:`HELIOCENTRIC_KINDS` (the others observe the Earth from a
geocentric state; the attitude rows and a formation's links measure no centre and are
among them); another kind is an error naming its line.

Kinds (all frames EME2000 = ECI unless "body"; all sigmas 1σ)

========================  ===============================================  ==============
kind                      x, y, z (and extra columns)                      sigma
========================  ===============================================  ==============
``prior_position``        a priori position r_eci, m                       per axis, m
``prior_velocity``        a priori velocity v_eci, m/s                     per axis, m/s
``earth_direction``       unit vector spacecraft -> Earth centre, ECI      per tangent
                                                                           axis, rad
``limb_radius``           x = apparent angular radius of the limb rho,     rad
                          rad, in (0, pi/2); y = radius of the limb
                          sphere R_limb, m (> 0); z empty; ``body``
                          (optional: sun, earth, moon) the apparent limb
                          of that body (light time, aberration); empty:
                          the Earth's limb sphere at the frame origin
``earth_direction_body``  unit vector to the Earth's centre in the BODY    per tangent
  (fgnav extension)       frame; needs an attitude (an ``attitude`` row    axis, rad
                          at the same epoch, or an attitude key)
``attitude``              rotation vector (axis * angle, rad) of           per axis, rad
  (fgnav extension)       R_eci_from_body; ``att_c11`` .. ``att_c33``
                          (optional, all six or none) = the upper
                          triangle of its 3x3 covariance, rad^2, body
                          frame, right perturbation (R_meas exp([d]x));
                          when given it replaces sigma (which stays
                          required) in every use of the row
``altitude``              x = altimeter height above the reference         m
  (fgnav extension)       sphere h, m; y = reference radius, m (> 0,
                          and x + y > 0); z empty
``sun_direction_body``    unit vector to the Sun, BODY frame               rad
``moon_direction_body``   unit vector to the Moon, BODY frame              rad
``star_direction_body``   x,y,z = measured unit vector to a star, BODY     per tangent
  (fgnav extension)       frame; ``star_x``, ``star_y``, ``star_z`` =      axis, rad
                          its catalogue unit vector (EME2000, catalogue
                          place at J2000 with proper motion, before
                          aberration; required); needs the attitude
                          estimated (``--estimate attitude``)
``refraction``            x,y,z = catalogue star unit vector, ECI;         refraction
  (fgnav extension)       ``gamma`` = measured refraction angle, rad       angle, rad
                          (required); ``sigma_model_m`` = 1σ of the
                          atmosphere-model height error, m (>= 0,
                          optional)
``body_star_angle``       x = angle at the spacecraft between the centre   rad
  (fgnav extension)       of ``body`` (sun, earth, moon) and a star, rad,
                          in [0, pi]; ``star_x``, ``star_y``, ``star_z``
                          = the star's catalogue unit vector (EME2000);
                          y, z empty
``limb_star_angle``       x = angle between a star and the NEAR limb of    rad
  (fgnav extension)       ``body`` (earth or moon), rad, in [0, pi] (the
                          sextant: centre angle minus the apparent
                          radius asin(y/d)); y = radius of the limb
                          sphere, m (> 0); star columns as above; z empty
``body_body_angle``       x = angle at the spacecraft between the centres  rad
  (fgnav extension)       of ``body`` and ``body2`` (two different near
                          bodies), rad, in [0, pi]; y, z empty
``isl_pseudorange``       x = pseudorange, m (> 0), received by            m
  (fgnav extension)       ``spacecraft`` from ``tx_spacecraft`` (both
                          required), antennas ``rx_antenna``,
                          ``tx_antenna`` (optional); y, z empty
``isl_carrier_phase``     x = carrier phase times wavelength, m, on the    m
  (fgnav extension)       same link (unknown constant ambiguity)
========================  ===============================================  ==============

The ``spacecraft`` column may be given on any kind, the other id columns only on the
inter-satellite kinds; ids, antenna declarations and their checks are defined in
:mod:`fgnav.io.log_spacecraft`.

``body`` and ``body2`` hold a body's name in the file; in memory (``MeasurementLog.extra``)
its index in :data:`BODIES` (a float, NaN where empty), so that every value of a row stays
a number.

Columns a kind does not use must be empty. ``sigma`` is always required, finite and within
the physically meaningful range of its kind (``SIGMA_RANGE``): angles (directions, limb
radius, refraction) 1e-9..1 rad, attitude 1e-9..pi rad, ``prior_position`` 1e-3..1e9 m,
``prior_velocity`` 1e-6..1e5 m/s, ``altitude`` 1e-3..1e7 m. Below the range a measurement
would be trusted beyond any sensor (and beyond double precision in the solvers' whitened
rows); above it, it carries no information. A ``prior_position`` lies outside the Earth
(|r| >= 6,378,137 m, the equatorial radius) and within 1e13 m (``MAX_DISTANCE_M``, which
also bounds radii and heights); a ``prior_velocity`` within 1e6 m/s.

Validation (each case is an :class:`~fgnav.errors.InputFormatError` naming the file, the
1-based line, the column and what was expected, unless stated otherwise)

- header: missing, misnamed or extra columns (only the extra columns above may follow the
  base six), a repeated column;
- empty file, or a header and no rows: "no measurements";
- row-level (``reason`` key used in ``MeasurementLog.dropped``):
  ``field_count`` wrong number of fields; ``truncated`` the last line has too few fields
  and no newline at end of file; ``encoding`` a line that is not UTF-8; ``bad_epoch``
  epoch not ISO-8601 UTC with ``Z``; ``unknown_kind``; ``bad_number`` unparsable number;
  ``not_finite`` NaN or inf; ``missing_value`` a required field empty;
  ``unexpected_value`` a field the kind does not use is filled; ``bad_sigma`` sigma <= 0
  or outside the kind's ``SIGMA_RANGE``; ``bad_covariance`` an ``attitude`` covariance
  (``att_c11`` .. ``att_c33``) that is not positive definite or has an eigenvalue outside
  the squared ``SIGMA_RANGE``;
  ``unknown_body`` a ``body``/``body2`` that is not one of sun, earth, moon, the Sun as a
  limb body, or the same body twice in a ``body_body_angle``;
  ``not_unit`` a direction (x,y,z, or a star's catalogue vector star_x,star_y,star_z)
  with | 1 - |u| | > 1e-6 (deviations in (1e-12, 1e-6] are renormalized with a warning); ``out_of_range`` limb radius outside (0, pi/2), a radius
  <= 0, altitude below the centre, ``sigma_model_m`` < 0, a ``prior_position`` inside the
  Earth; ``epoch_outlier`` an epoch more
  than 30 days from the median epoch of the file; ``bad_id`` a malformed spacecraft or
  antenna name; ``unknown_spacecraft`` an id not in the ``# spacecraft:`` declaration;
  ``same_spacecraft`` a link whose two ends are one spacecraft; ``unknown_antenna`` an
  antenna not declared for its spacecraft;
- declarations (``# spacecraft:``, ``# antenna:``) that are malformed or repeated.
- With ``on_bad_row="drop"`` the row-level errors do not raise: the row is dropped and
  counted per reason in ``dropped``, with one warning per reason quoting the first case.
  If no row is left, "no measurements" is raised.
- exact duplicate rows (same epoch, kind and values): all but the first are dropped with a
  warning (counted as ``dropped["duplicate"]``).
- rows out of time order: stably sorted by epoch with a warning giving the number of rows
  found earlier than a row above them.

``read_log`` returns rows sorted by epoch; ``epoch0`` is the earliest epoch in the file and
``t_s`` the seconds from it. ``write_log`` writes atomically, numbers as the shortest
decimal that round-trips exactly (at most 17 significant digits), epochs to the
microsecond (nanoseconds when needed): read -> write -> read gives identical arrays.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any, Callable, NamedTuple

import numpy as np

from fgnav.errors import InputFormatError, UserError
from fgnav.io.atomic import atomic_writer
from fgnav.io.log_spacecraft import (
    ANTENNA_COLUMNS, ID_COLUMNS, ID_EXPECTED, ID_RE, SPACECRAFT_COLUMNS, Declarations,
    Vocabulary, check_rows, declaration_lines, first_appearance, id_codes, parse_declaration,
)
from fgnav.time import (UtcRangeError, add_seconds, era_shift_ns, format_utc, parse_utc,
                        seconds_since)

__all__ = [
    "BASE_COLUMNS", "EXTRA_COLUMNS", "KINDS", "DIRECTION_KINDS", "MeasurementLog",
    "read_log", "write_log", "log_from_arrays", "EPOCH_OUTLIER_DAYS", "UNIT_TOL", "SIGMA_RANGE",
    "PRIOR_MIN_RADIUS_M", "STAR_COLUMNS", "BODIES", "BODY_COLUMNS", "body_codes", "body_names",
    "ATT_COV_COLUMNS", "attitude_covariances", "CENTRES", "HELIOCENTRIC_KINDS",
    "EARTH_DIRECTION_KIND", "KindSpec", "FORMAT_KINDS", "RowError", "fmt_found",
]

BASE_COLUMNS = ("epoch", "kind", "x", "y", "z", "sigma")
ATT_COV_COLUMNS = ("att_c11", "att_c12", "att_c13", "att_c22", "att_c23", "att_c33")
"""The extra columns of an ``attitude`` row's full 3x3 covariance (upper triangle, rad^2,
body frame, right perturbation ``R_eci_from_body = R_meas exp([d]x)``); empty: the
isotropic ``sigma``."""
EXTRA_COLUMNS = ("gamma", "sigma_model_m", "star_x", "star_y", "star_z", "body",
                 "body2") + ATT_COV_COLUMNS + ID_COLUMNS
STAR_COLUMNS = ("star_x", "star_y", "star_z")
"""The extra columns of a star's catalogue unit vector (``star_direction_body`` rows)."""
BODY_COLUMNS = ("body", "body2")
"""The extra columns naming a near body (the angle rows): text in the file, the body's index
in :data:`BODIES` in memory."""
BODIES = ("sun", "earth", "moon")
"""The near bodies an angle row may name, in the order of their in-memory codes."""
_LIMB_BODIES = ("earth", "moon")
CENTRES = ("earth", "sun")
"""The central bodies a log may declare (``# centre: NAME`` before the header)."""
_CENTRE_LINE = re.compile(r"#\s*centre\s*:\s*(.*?)\s*$", re.IGNORECASE)
_VALUE_COLUMNS = ("x", "y", "z", "sigma") + EXTRA_COLUMNS  # order of the value vector
_USAGE_COLUMNS = ("x", "y", "z") + EXTRA_COLUMNS           # order of a kind's usage

UNIT_TOL = 1e-6
"""A direction with | 1 - |u| | above this is an error; below it (and above 1e-12) renormalized."""
_RENORM_TOL = 1e-12
EPOCH_OUTLIER_DAYS = 30.0
"""An epoch further than this from the median epoch of the file is an error, days."""

PRIOR_MIN_RADIUS_M = 6378137.0
"""A ``prior_position`` closer to the Earth's centre than this (m) is an error."""
MAX_DISTANCE_M = 1e13
"""Largest position, radius or height a row may give (m, ~67 AU): beyond it a value is a
unit or typing error, and its square would overflow the solvers' arithmetic."""
MAX_SPEED_MPS = 1e6
"""Largest ``prior_velocity`` component (m/s)."""


# ---- value checks of a kind beyond its columns, sigma and unit vector (the format's rules) ----

def _check_prior_position(x, y, z, sigma_model):
    if not PRIOR_MIN_RADIUS_M <= math.hypot(x, y, z) <= MAX_DISTANCE_M:
        raise _RowError("out_of_range", "x,y,z", f"a position outside the Earth and within "
                        f"{MAX_DISTANCE_M:g} m ({PRIOR_MIN_RADIUS_M:.0f} m <= |r| <= "
                        f"{MAX_DISTANCE_M:g} m)", f"|r| = {math.hypot(x, y, z)!r} m")


def _check_prior_velocity(x, y, z, sigma_model):
    if not math.hypot(x, y, z) <= MAX_SPEED_MPS:
        raise _RowError("out_of_range", "x,y,z", f"a velocity within {MAX_SPEED_MPS:g} m/s",
                        f"|v| = {math.hypot(x, y, z)!r} m/s")


def _check_distances(x, y):
    if not (abs(x) <= MAX_DISTANCE_M and y <= MAX_DISTANCE_M):
        raise _RowError("out_of_range", "x,y", f"values within {MAX_DISTANCE_M:g} m",
                        f"{_fmt_found(x)}, {_fmt_found(y)}")


def _check_limb_radius(x, y, z, sigma_model):
    _check_distances(x, y)
    if not 0.0 < x < math.pi / 2:
        raise _RowError("out_of_range", "x", "a limb angular radius in (0, pi/2) rad",
                        _fmt_found(x))
    if not y > 0.0:
        raise _RowError("out_of_range", "y", "a limb-sphere radius > 0 m", _fmt_found(y))


def _check_altitude(x, y, z, sigma_model):
    _check_distances(x, y)
    if not y > 0.0:
        raise _RowError("out_of_range", "y", "a reference radius > 0 m", _fmt_found(y))
    if not x + y > 0.0:
        raise _RowError("out_of_range", "x", "a height above the centre (x + y > 0), m",
                        _fmt_found(x))


def _check_refraction(x, y, z, sigma_model):
    if not math.isnan(sigma_model) and not sigma_model >= 0.0:
        raise _RowError("out_of_range", "sigma_model_m", "a model 1-sigma >= 0 m",
                        _fmt_found(sigma_model))


def _check_angle(x, y, z, sigma_model):
    if not 0.0 <= x <= math.pi:
        raise _RowError("out_of_range", "x", "an angle in [0, pi] rad", _fmt_found(x))


def _check_limb_angle(x, y, z, sigma_model):
    _check_angle(x, y, z, sigma_model)
    if not 0.0 < y <= MAX_DISTANCE_M:
        raise _RowError("out_of_range", "y", f"a limb-sphere radius in (0, {MAX_DISTANCE_M:g}] m",
                        _fmt_found(y))


def _check_limb_body(v):
    if BODIES[int(v["body"])] not in _LIMB_BODIES:
        raise _RowError("unknown_body", "body", f"a body with a limb, one of "
                        f"{', '.join(_LIMB_BODIES)}", BODIES[int(v["body"])])


def _check_two_bodies(v):
    if v["body"] == v["body2"]:
        raise _RowError("unknown_body", "body2", "a body other than the column body's",
                        BODIES[int(v["body2"])])


def _check_attitude_covariance(v):
    """An ``attitude`` row's covariance columns: all six empty, or all six filled and the
    symmetric matrix they give positive definite with every 1-sigma (square root of an
    eigenvalue) within the kind's sigma range."""
    c = [v[col] for col in ATT_COV_COLUMNS]
    filled = [not math.isnan(a) for a in c]
    if not any(filled):
        return
    if not all(filled):
        col = ATT_COV_COLUMNS[filled.index(False)]
        raise _RowError("missing_value", col, "all six of " + ",".join(ATT_COV_COLUMNS)
                        + " filled, or none (attitude: the covariance's upper triangle, rad^2)",
                        "empty field")
    w = np.linalg.eigvalsh(_sym3(*c))
    lo, hi = _KIND_SPEC["attitude"].sigma_min, _KIND_SPEC["attitude"].sigma_max
    if not (w[0] > 0.0 and lo * lo <= w[0] and w[-1] <= hi * hi):
        raise _RowError("bad_covariance", ",".join(ATT_COV_COLUMNS),
                        f"a symmetric positive definite covariance, rad^2, with eigenvalues "
                        f"within {lo * lo:g}..{hi * hi:g} (1-sigma {lo:g}..{hi:g} rad)",
                        f"eigenvalues {', '.join(f'{a:.6g}' for a in w)}")


def _sym3(c11, c12, c13, c22, c23, c33) -> np.ndarray:
    return np.array([[c11, c12, c13], [c12, c22, c23], [c13, c23, c33]], dtype=float)


def attitude_covariances(log, rows) -> np.ndarray:
    """The 3x3 covariances (M, 3, 3), rad^2, of the ``attitude`` rows ``rows`` of ``log``:
    from the ``att_c11..att_c33`` columns, NaN-filled where a row gives none (its isotropic
    ``sigma`` applies)."""
    rows = np.asarray(rows, dtype=int)
    extra = log.extra or {}
    c = [np.asarray(extra[col], dtype=float)[rows] if col in extra
         else np.full(len(rows), np.nan) for col in ATT_COV_COLUMNS]
    return np.moveaxis(_sym3(*c), -1, 0) if len(rows) else np.zeros((0, 3, 3))


def body_codes(names) -> np.ndarray:
    """In-memory codes (float array, NaN for None/empty/NaN) of body names (sun, earth,
    moon, any case) or codes; a ValueError names an unknown body."""
    out = []
    for n in np.asarray(names, dtype=object).reshape(-1):
        if n is None or (isinstance(n, float) and math.isnan(n)) or n == "":
            out.append(math.nan)
        elif isinstance(n, str):
            if n.strip().lower() not in BODIES:
                raise ValueError(f"unknown body {n!r}; expected one of {', '.join(BODIES)}")
            out.append(float(BODIES.index(n.strip().lower())))
        else:
            c = float(n)
            if c not in range(len(BODIES)):
                raise ValueError(f"unknown body code {n!r}; expected 0..{len(BODIES) - 1}")
            out.append(c)
    return np.array(out, dtype=float)


def body_names(codes) -> list:
    """Body names of in-memory codes (None where NaN)."""
    return [None if math.isnan(c) else BODIES[int(c)] for c in np.asarray(codes, float).ravel()]


class KindSpec(NamedTuple):
    """One kind of the format (its log schema row): how it uses the value columns, what its
    sigma may be. A measurement model's module may define the row of a kind the format does
    not list (:data:`FORMAT_KINDS`); the readers and writers take the schema,
    ``{kind: KindSpec}``, as an argument (``schema=``, default :data:`FORMAT_KINDS`).

    usage : per column x, y, z, gamma, sigma_model_m (then star_x, star_y, star_z, empty
        when not given): ``"r"`` required, ``"o"`` optional, ``""`` must be empty.
    what : a short description used in messages.
    sigma_min, sigma_max, unit : the accepted 1-sigma range and its unit.
    unit_vector : x, y, z is a unit vector (checked, renormalized within ``UNIT_TOL``).
    check : further value checks ``(x, y, z, sigma_model_m) -> None`` (raise a row error).
    unit_columns : further columns that together are a unit vector (checked and
        renormalized like x, y, z).
    row_check : checks that need the extra columns, ``({column: value}) -> None``.
    heliocentric : the kind may appear in a heliocentric log (``# centre: sun``).
    """

    usage: tuple[str, ...]
    what: str
    sigma_min: float
    sigma_max: float
    unit: str
    unit_vector: bool = False
    check: Callable | None = None
    unit_columns: tuple[str, ...] = ()
    row_check: Callable | None = None
    heliocentric: bool = False


_Kind = KindSpec


def _usage(spec) -> tuple[str, ...]:
    """A kind's usage of every column of ``_USAGE_COLUMNS`` (padded with "" = must be empty);
    the ``spacecraft`` column is optional on every kind unless the kind requires it."""
    u = list(spec.usage) + [""] * (len(_USAGE_COLUMNS) - len(spec.usage))
    j = _USAGE_COLUMNS.index("spacecraft")
    u[j] = u[j] or "o"
    return tuple(u)


def _check_isl_range(x, y, z, sigma_model):
    if not 0.0 < x <= MAX_DISTANCE_M:
        raise _RowError("out_of_range", "x", f"a range in (0, {MAX_DISTANCE_M:g}] m", _fmt_found(x))


def _check_isl_phase(x, y, z, sigma_model):
    if not abs(x) <= MAX_DISTANCE_M:
        raise _RowError("out_of_range", "x", f"a carrier range within {MAX_DISTANCE_M:g} m",
                        _fmt_found(x))


_XYZ = ("r", "r", "r", "", "")
_XY = ("r", "r", "", "", "")
_ANGLE = (1e-9, 1.0, "rad")
_KIND_SPEC: dict[str, _Kind] = {
    "prior_position": _Kind(_XYZ, "a priori position, m, EME2000", 1e-3, 1e9, "m",
                            check=_check_prior_position, heliocentric=True),
    "prior_velocity": _Kind(_XYZ, "a priori velocity, m/s, EME2000", 1e-6, 1e5, "m/s",
                            check=_check_prior_velocity, heliocentric=True),
    "earth_direction": _Kind(_XYZ, "unit vector to Earth centre, EME2000", *_ANGLE,
                             unit_vector=True),
    "limb_radius": _Kind(_XY + ("",) * 3 + ("o",),
                         "x = limb angular radius, rad; y = limb radius, m; body (optional)",
                         *_ANGLE, check=_check_limb_radius),
    "earth_direction_body": _Kind(_XYZ, "unit vector to Earth centre, body", *_ANGLE,
                                  unit_vector=True),
    "attitude": _Kind(_XYZ + ("",) * 5 + ("o",) * len(ATT_COV_COLUMNS),
                      "rotation vector of R_eci_from_body, rad; att_c11..att_c33 = its "
                      "covariance (upper triangle, rad^2, body frame; optional)",
                      1e-9, math.pi, "rad", row_check=_check_attitude_covariance,
                      heliocentric=True),
    "altitude": _Kind(_XY, "x = height above sphere, m; y = sphere radius, m", 1e-3, 1e7, "m",
                      check=_check_altitude),
    "sun_direction_body": _Kind(_XYZ, "unit vector to the Sun, body", *_ANGLE, unit_vector=True),
    "moon_direction_body": _Kind(_XYZ, "unit vector to the Moon, body", *_ANGLE,
                                 unit_vector=True),
    "gyro": _Kind(_XYZ, "body angular rate over the interval since the previous epoch, rad/s",
                  1e-12, 1.0, "rad/s"),
    "refraction": _Kind(("r", "r", "r", "r", "o"),
                        "star unit vector, EME2000; gamma, rad; sigma_model_m, m", *_ANGLE,
                        unit_vector=True, check=_check_refraction),
    "star_direction_body": _Kind(("r", "r", "r", "", "", "r", "r", "r"),
                                 "unit vector to a star, body; star_x,star_y,star_z = its "
                                 "catalogue unit vector, EME2000", *_ANGLE, unit_vector=True,
                                 unit_columns=STAR_COLUMNS),
    "body_star_angle": _Kind(("r", "", "", "", "", "r", "r", "r", "r", ""),
                             "x = angle between the body's centre and a star, rad; star_x,"
                             "star_y,star_z = the star, EME2000; body", *_ANGLE,
                             check=_check_angle, unit_columns=STAR_COLUMNS, heliocentric=True),
    "limb_star_angle": _Kind(("r", "r", "", "", "", "r", "r", "r", "r", ""),
                             "x = angle between the body's near limb and a star, rad; y = limb "
                             "radius, m; star_x,star_y,star_z = the star, EME2000; body", *_ANGLE,
                             check=_check_limb_angle, unit_columns=STAR_COLUMNS,
                             row_check=_check_limb_body, heliocentric=True),
    "body_body_angle": _Kind(("r", "", "", "", "", "", "", "", "r", "r"),
                             "x = angle between the centres of body and body2, rad", *_ANGLE,
                             check=_check_angle, row_check=_check_two_bodies, heliocentric=True),
    "isl_pseudorange": _Kind(("r",) + ("",) * (9 + len(ATT_COV_COLUMNS)) + ("r", "r", "o", "o"),
                             "x = pseudorange from tx_spacecraft's antenna tx_antenna to "
                             "spacecraft's antenna rx_antenna, m", 1e-6, 1e4, "m",
                             check=_check_isl_range, heliocentric=True),
    "isl_carrier_phase": _Kind(("r",) + ("",) * (9 + len(ATT_COV_COLUMNS)) + ("r", "r", "o", "o"),
                               "x = carrier phase times wavelength on the link, m (with an "
                               "unknown constant ambiguity)", 1e-9, 1.0, "m",
                               check=_check_isl_phase, heliocentric=True),
}
"""The kinds of the format, one entry each (the module docstring's table): the one place
that defines a kind's columns and value checks."""
FORMAT_KINDS = _KIND_SPEC
"""The format's own kinds (the default schema of every reader and writer here)."""
KINDS = tuple(_KIND_SPEC)
HELIOCENTRIC_KINDS = tuple(k for k, s in _KIND_SPEC.items() if s.heliocentric)
"""The kinds a heliocentric log (``# centre: sun``) may hold."""
EARTH_DIRECTION_KIND = "earth_direction"
"""The kind of a geocentric direction row (the rows other formats' angles become,
:mod:`fgnav.io.tdm`; its model is ``fgnav.models.registry.EARTH_DIRECTION``)."""
SIGMA_RANGE: dict[str, tuple[float, float, str]] = {
    k: (s.sigma_min, s.sigma_max, s.unit) for k, s in _KIND_SPEC.items()}
"""Per kind: (lowest, highest 1-sigma, unit) accepted (see the module docstring)."""
DIRECTION_KINDS = tuple(k for k, s in _KIND_SPEC.items() if s.unit_vector)
"""Kinds whose x, y, z is a unit vector."""

_NUMBER_RE = re.compile(r"^[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?$")
_NONFINITE_RE = re.compile(r"^[+-]?(?:nan|inf|infinity)$", re.IGNORECASE)
_EPOCH_RE = re.compile(r"^\d{4}-\d{2}-\d{2}T\d{2}:\d{2}:\d{2}(?:\.\d{1,9})?Z$")
_EPOCH_EXPECTED = "an ISO-8601 UTC epoch YYYY-MM-DDTHH:MM:SS[.fffffffff]Z"
_HEADER_TEXT = ("epoch,kind,x,y,z,sigma[,gamma][,sigma_model_m][,star_x,star_y,star_z]"
                "[,body][,body2][,att_c11,...,att_c33][,spacecraft][,tx_spacecraft]"
                "[,rx_antenna][,tx_antenna]")
_NS_PER_DAY = 86400 * 10**9


@dataclass
class MeasurementLog:
    """Measurements of one pass, one entry per row (sorted by epoch when read from a file).

    ``t_s`` are seconds from ``epoch0`` (``datetime64[ns]``, UTC); ``kind`` a str array;
    ``xyz`` (M, 3) with NaN where a field is empty; ``sigma`` (M,) in the kind's unit;
    ``extra`` maps the extra columns (``gamma``, ``sigma_model_m``, ``star_x``, ``star_y``,
    ``star_z``, ``body``, ``body2``: codes, :data:`BODIES`; ``att_c11`` .. ``att_c33``) to (M,) arrays (NaN where empty); ``line`` the 1-based source line of each row (0 when not from a file);
    ``warnings`` human-readable notes; ``dropped`` rows dropped per reason; ``spacecraft``
    the spacecraft ids (empty for a one-spacecraft log) that the codes of the ``spacecraft``
    and ``tx_spacecraft`` columns index, ``antenna_names`` the antenna names the antenna
    columns' codes index, ``antennas`` the lever arms (3,), m, body frame, by
    (spacecraft id, antenna name) (:mod:`fgnav.io.log_spacecraft`); ``centre`` the central
    body of every position (:data:`CENTRES`; the ``# centre:`` line); ``schema`` the kinds
    it was read or built with (``{kind: KindSpec}``; None: :data:`FORMAT_KINDS`), which a
    log rebuilt from it (a subset, a fault, a preprocessing) and :func:`write_log` reuse.
    """

    path: Any
    epoch0: np.datetime64
    t_s: np.ndarray
    kind: np.ndarray
    xyz: np.ndarray
    sigma: np.ndarray
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    line: np.ndarray = None
    warnings: list[str] = field(default_factory=list)
    dropped: dict[str, int] = field(default_factory=dict)
    spacecraft: tuple[str, ...] = ()
    antenna_names: tuple[str, ...] = ()
    antennas: dict = field(default_factory=dict)
    centre: str = "earth"
    schema: dict | None = field(default=None, repr=False, compare=False)

    @property
    def n_spacecraft(self) -> int:
        """Spacecraft in the log (1 without a ``spacecraft`` column)."""
        return max(len(self.spacecraft), 1)

    def __len__(self) -> int:
        return len(self.t_s)

    def select(self, kind: str) -> np.ndarray:
        """Indices (int array, in row order) of the rows of ``kind``."""
        return np.flatnonzero(self.kind == kind)

    def epochs_unique(self) -> np.ndarray:
        """Sorted unique epochs, seconds from ``epoch0``."""
        return np.unique(self.t_s)

    def epochs_utc(self) -> np.ndarray:
        """Absolute epoch of each row, ``datetime64[ns]`` UTC."""
        return add_seconds(self.epoch0, self.t_s)

    def counts(self) -> dict[str, int]:
        """Number of rows per kind (kinds present only)."""
        kinds, n = np.unique(self.kind, return_counts=True)
        return {str(k): int(c) for k, c in zip(kinds, n)}


class _RowError(Exception):
    """A row-level problem: reason key + the InputFormatError fields."""

    def __init__(self, reason, column, expected, found):
        super().__init__(reason)
        self.reason, self.column, self.expected, self.found = reason, column, expected, found


_WHAT_VALUE = {**{c: "a body name" for c in BODY_COLUMNS},
               **{c: "a spacecraft id" for c in SPACECRAFT_COLUMNS},
               **{c: "an antenna name" for c in ANTENNA_COLUMNS}}


def _fmt_found(v: float, column: str = "") -> str:
    if column in BODY_COLUMNS and float(v) in range(len(BODIES)):
        return BODIES[int(v)]
    if column in ID_COLUMNS:
        return "a name"
    return repr(float(v))


RowError = _RowError
"""A row-level problem a kind's value check raises: ``RowError(reason, column, expected,
found)`` (reason: a ``dropped`` key of the module docstring)."""
fmt_found = _fmt_found
"""How a value is quoted as "found" in a row error."""


def _check_values(kind: str, v: np.ndarray, schema=None) -> tuple[np.ndarray, bool]:
    """Validate the value vector ``v`` = (x, y, z, sigma, *EXTRA_COLUMNS) of ``kind`` by
    its row of ``schema`` (default :data:`FORMAT_KINDS`).

    NaN means "empty". Returns (values, renormalized); raises :class:`_RowError`.
    """
    schema = _KIND_SPEC if schema is None else schema
    spec = schema.get(kind)
    if spec is None:
        raise _RowError("unknown_kind", "kind", f"a kind, one of {', '.join(schema)}", kind)
    what = spec.what
    v = np.asarray(v, dtype=float)
    x, y, z, sigma = (float(a) for a in v[:4])  # Python floats: no overflow warnings below
    sigma_model = float(v[_VALUE_COLUMNS.index("sigma_model_m")])
    for j, col in enumerate(_VALUE_COLUMNS):
        if np.isinf(v[j]):
            raise _RowError("not_finite", col, "a finite number", _fmt_found(v[j]))
    cols_usage = dict(zip(_USAGE_COLUMNS, _usage(spec)))
    for col, use in cols_usage.items():
        j = _VALUE_COLUMNS.index(col)
        if use == "r" and np.isnan(v[j]):
            raise _RowError("missing_value", col, f"{_WHAT_VALUE.get(col, 'a number')} "
                            f"({kind}: {what})", "empty field")
        if use == "" and not np.isnan(v[j]):
            raise _RowError("unexpected_value", col, f"an empty field ({kind} does not use "
                            f"column {col})", _fmt_found(v[j], col))
    if math.isnan(sigma):
        raise _RowError("missing_value", "sigma", "a 1-sigma > 0", "empty field")
    if not sigma > 0.0:
        raise _RowError("bad_sigma", "sigma", "a 1-sigma > 0", _fmt_found(sigma))
    lo, hi, unit = spec.sigma_min, spec.sigma_max, spec.unit
    if not lo <= sigma <= hi:
        raise _RowError("bad_sigma", "sigma", f"a 1-sigma within {lo:g}..{hi:g} {unit} for "
                        f"{kind}", _fmt_found(sigma))
    renorm = False
    if spec.unit_vector:
        n = math.hypot(x, y, z)
        if not abs(1.0 - n) <= UNIT_TOL:
            raise _RowError("not_unit", "x,y,z", f"a unit vector (| |u| - 1 | <= {UNIT_TOL:g})",
                            f"|u| = {n!r}")
        if abs(1.0 - n) > _RENORM_TOL:
            v = v.copy()
            v[:3] /= n
            renorm = True
    if spec.unit_columns:
        j = [_VALUE_COLUMNS.index(c) for c in spec.unit_columns]
        n = math.hypot(*(float(v[i]) for i in j))
        if not abs(1.0 - n) <= UNIT_TOL:
            raise _RowError("not_unit", ",".join(spec.unit_columns),
                            f"a unit vector (| |u| - 1 | <= {UNIT_TOL:g})", f"|u| = {n!r}")
        if abs(1.0 - n) > _RENORM_TOL:
            v = v.copy()
            v[j] /= n
            renorm = True
    if spec.check is not None:
        spec.check(x, y, z, sigma_model)
    for col in BODY_COLUMNS:
        j = _VALUE_COLUMNS.index(col)
        if not (np.isnan(v[j]) or float(v[j]) in range(len(BODIES))):
            raise _RowError("unknown_body", col, f"a body, one of {', '.join(BODIES)}",
                            _fmt_found(v[j]))
    if spec.row_check is not None:
        spec.row_check(dict(zip(_VALUE_COLUMNS, (float(a) for a in v))))
    return v, renorm


def _parse_body(text: str, column: str) -> float:
    if text == "":
        return math.nan
    if text.lower() not in BODIES:
        raise _RowError("unknown_body", column, f"a body, one of {', '.join(BODIES)}", text)
    return float(BODIES.index(text.lower()))


def _parse_id(text: str, column: str, vocab: dict) -> float:
    if not ID_RE.match(text):
        raise _RowError("bad_id", column, ID_EXPECTED, text)
    return vocab["spacecraft" if column in SPACECRAFT_COLUMNS else "antenna"].code(text)


def _parse_number(text: str, column: str, vocab: dict | None = None) -> float:
    if text == "":
        return math.nan
    if column in BODY_COLUMNS:
        return _parse_body(text, column)
    if column in ID_COLUMNS:
        return _parse_id(text, column, vocab)
    if _NUMBER_RE.match(text):
        x = float(text)
        if not math.isfinite(x):
            raise _RowError("not_finite", column, "a finite number", text)
        return x
    if _NONFINITE_RE.match(text):
        raise _RowError("not_finite", column, "a finite number", text)
    raise _RowError("bad_number", column, "a decimal number", text)


def _parse_epoch(text: str) -> np.datetime64:
    if not _EPOCH_RE.match(text):
        raise _RowError("bad_epoch", "epoch", _EPOCH_EXPECTED, text)
    try:
        return parse_utc(text)  # leap seconds (23:59:60) included, see fgnav.time
    except UtcRangeError:  # datetime64[ns] would wrap silently outside 1678..2261
        raise _RowError("bad_epoch", "epoch", "a year within 1678..2261", text) from None
    except (ValueError, OverflowError):
        raise _RowError("bad_epoch", "epoch", _EPOCH_EXPECTED + " (a valid date and time)",
                        text) from None


def _check_header(path, lineno: int, text: str) -> list[str]:
    cols = [c.strip() for c in text.split(",")]
    expected = f"the header '{_HEADER_TEXT}'"
    for i, name in enumerate(BASE_COLUMNS):
        if i >= len(cols):
            raise InputFormatError(path, lineno, name, f"{expected}: column '{name}' is missing",
                                   text)
        if cols[i] != name:
            raise InputFormatError(path, lineno, name, f"{expected}: column {i + 1} named "
                                   f"'{name}'", cols[i])
    seen = set()
    for j in range(len(BASE_COLUMNS), len(cols)):
        c = cols[j]
        if c not in EXTRA_COLUMNS:
            raise InputFormatError(path, lineno, c or f"column {j + 1}",
                                   f"{expected}: extra columns only from "
                                   f"{', '.join(EXTRA_COLUMNS)}",
                                   c)
        if c in seen:
            raise InputFormatError(path, lineno, c, f"{expected}: each column once",
                                   f"'{c}' repeated")
        seen.add(c)
    return cols


def _no_measurements(path, lineno, what):
    return InputFormatError(path, lineno, None, "at least one measurement row "
                            f"(header '{_HEADER_TEXT}' then rows)", f"no measurements ({what})")


def read_log(path, *, on_bad_row: str = "error", schema=None) -> MeasurementLog:
    """Read and validate a measurement log (CSV v1, see the module docstring).

    ``on_bad_row="error"`` raises :class:`~fgnav.errors.InputFormatError` at the first bad
    row; ``"drop"`` drops bad rows (counts per reason in ``dropped``, a warning each).
    ``schema``: the kinds read, ``{kind: KindSpec}`` (default :data:`FORMAT_KINDS`; the
    measurement models' schema, with kinds the format does not list, is
    ``fgnav.models.registry.LOG_SCHEMA``).
    """
    if on_bad_row not in ("error", "drop"):
        raise UserError(f"on_bad_row must be 'error' or 'drop', found {on_bad_row!r}")
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as exc:
        raise UserError(f"{path}: cannot read the measurement log: {exc.strerror or exc}") \
            from None
    return _parse_log_bytes(path, data, on_bad_row, schema)


def _parse_log_bytes(path, data: bytes, on_bad_row: str, schema=None) -> MeasurementLog:
    schema = _KIND_SPEC if schema is None else schema
    drop = on_bad_row == "drop"
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    raw_lines = data.split(b"\n")
    terminated = True
    if raw_lines and raw_lines[-1] == b"":
        raw_lines.pop()
    elif raw_lines:
        terminated = False
    n_lines = len(raw_lines)

    dropped: dict[str, int] = {}
    first_msg: dict[str, str] = {}
    warnings: list[str] = []

    def bad(lineno, err: _RowError):
        exc = InputFormatError(path, lineno, err.column, err.expected, err.found)
        if not drop:
            raise exc
        dropped[err.reason] = dropped.get(err.reason, 0) + 1
        first_msg.setdefault(err.reason, str(exc))

    # The header: the first line that is neither blank nor a comment; the comments above it
    # may declare spacecraft and antennas (fgnav.io.log_spacecraft) and the central body
    # ("# centre: sun").
    header = None
    centre = None
    i_body = n_lines
    decl = Declarations()
    for i, raw in enumerate(raw_lines):
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise InputFormatError(path, i + 1, None, "UTF-8 text",
                                   f"byte 0x{raw[exc.start]:02x} at character {exc.start + 1}"
                                   ) from None
        if text.endswith("\r"):
            text = text[:-1]
        stripped = text.strip()
        declared = _CENTRE_LINE.fullmatch(stripped)
        if declared:
            name = declared.group(1).lower()
            if name not in CENTRES or (centre is not None and name != centre):
                raise InputFormatError(path, i + 1, "centre", f"one of {', '.join(CENTRES)}"
                                       + ("" if centre is None else f", once (already {centre})"),
                                       declared.group(1))
            centre = name
        if stripped.startswith("#"):
            parse_declaration(path, i + 1, stripped, decl)
        if not stripped or stripped.startswith("#"):
            continue
        header = _check_header(path, i + 1, text)
        i_body = i + 1
        break
    if header is None:
        raise _no_measurements(path, max(n_lines, 1), "empty file" if not n_lines
                               else "no header line")

    # The rows: column-wise (_fast_rows) where a row is plainly well formed, row by row
    # (_parse_row, the reference reading with its precise messages) for the other lines;
    # both give the same values for a valid row.
    decl.check_spacecraft_known(path)
    vocab = {"spacecraft": Vocabulary(decl.spacecraft or ()), "antenna": Vocabulary()}
    if n_lines - i_body >= COLUMN_WISE_MIN_ROWS:
        fast_i, ns_f, kind_f, V_f, renorm_f, slow_i = _fast_rows(raw_lines, i_body, header,
                                                                 vocab, schema)
    else:  # a short log: row by row is quicker than loading Arrow
        fast_i, ns_f, kind_f, V_f, renorm_f = (np.zeros(0, dtype=np.int64),
                                               np.zeros(0, dtype=np.int64),
                                               np.zeros(0, dtype="<U1"),
                                               np.zeros((0, len(_VALUE_COLUMNS))), 0)
        slow_i = range(i_body, n_lines)
    epochs: list[int] = []
    kinds: list[str] = []
    values: list[np.ndarray] = []
    lines: list[int] = []
    n_renorm = int(renorm_f)
    for i in slow_i:
        lineno = i + 1
        try:
            row = _parse_row(raw_lines[i], header, (not terminated) and i == n_lines - 1, vocab,
                             schema)
        except _RowError as err:
            bad(lineno, err)
            continue
        if row is None:  # blank or comment
            continue
        t, kind, v, renorm = row
        n_renorm += renorm
        epochs.append(int(t.astype(np.int64)))
        kinds.append(kind)
        values.append(v)
        lines.append(lineno)
    if not len(fast_i) and not epochs:
        what = "header only" if not dropped else f"all {sum(dropped.values())} rows dropped"
        raise _no_measurements(path, n_lines + 1, what)
    ns = np.concatenate([ns_f, np.array(epochs, dtype=np.int64)])
    V = np.concatenate([V_f, np.array(values, dtype=float).reshape(-1, len(_VALUE_COLUMNS))])
    kind_arr = np.concatenate([kind_f, np.array(kinds, dtype=str)]) if kinds else kind_f
    line_arr = np.concatenate([np.asarray(fast_i, dtype=np.int64) + 1,
                               np.array(lines, dtype=np.int64)])
    if len(lines) and len(fast_i):  # back into file order
        order = np.argsort(line_arr, kind="stable")
        ns, V, kind_arr, line_arr = ns[order], V[order], kind_arr[order], line_arr[order]

    # Several spacecraft: final codes, then the checks across columns (fgnav.io.log_spacecraft)
    spacecraft, antenna_names, antennas = (), (), {}
    if any(c in header for c in ID_COLUMNS):
        V, spacecraft, antenna_names, antennas, keep = _spacecraft_codes(
            V, kind_arr, line_arr, vocab, decl, "spacecraft" in header, bad)
        ns, V, kind_arr, line_arr = ns[keep], V[keep], kind_arr[keep], line_arr[keep]
        if not len(ns):
            raise _no_measurements(path, n_lines + 1, f"all {sum(dropped.values())} rows dropped")

    # Epochs far from the others (median) are errors (a mistyped date).
    med = int(np.sort(ns)[(len(ns) - 1) // 2])
    far = np.abs(ns.astype(float) - float(med)) > EPOCH_OUTLIER_DAYS * _NS_PER_DAY  # no overflow
    if far.any():
        for j in np.flatnonzero(far):
            days = (int(ns[j]) - med) / _NS_PER_DAY
            bad(int(line_arr[j]), _RowError(
                "epoch_outlier", "epoch", f"an epoch within {EPOCH_OUTLIER_DAYS:g} days of the "
                f"other epochs (median {format_utc(np.datetime64(med, 'ns'))})",
                f"{format_utc(np.datetime64(int(ns[j]), 'ns'))} ({days:+.1f} days)"))
        keep = ~far
        ns, V, kind_arr, line_arr = ns[keep], V[keep], kind_arr[keep], line_arr[keep]
        if not len(ns):
            raise _no_measurements(path, n_lines + 1, f"all {sum(dropped.values())} rows dropped")

    for reason, n in dropped.items():
        warnings.append(f"dropped {n} row(s) ({reason}); first: {first_msg[reason]}")
    if n_renorm:
        warnings.append(f"{path}: {n_renorm} direction(s) with | |u| - 1 | in ({_RENORM_TOL:g}, "
                        f"{UNIT_TOL:g}] renormalized")

    # Exact duplicate rows: keep the first.
    dup, first_dup = _duplicates(ns, kind_arr, V, line_arr)
    if dup.any():
        n = int(dup.sum())
        dropped["duplicate"] = dropped.get("duplicate", 0) + n
        warnings.append(f"{path}: dropped {n} exact duplicate row(s) (first: line {first_dup[0]} "
                        f"repeats line {first_dup[1]})")
        keep = ~dup
        ns, V, kind_arr, line_arr = ns[keep], V[keep], kind_arr[keep], line_arr[keep]

    ns, V, kind_arr, line_arr, w = _sort_rows(ns, V, kind_arr, line_arr, path)
    if w:
        warnings.append(w)

    epoch0 = np.datetime64(int(ns[0]), "ns")
    t_s = seconds_since(ns.astype("datetime64[ns]"), epoch0)
    width = max(int(np.char.str_len(kind_arr.astype(str)).max()), 1)  # as wide as the kinds kept
    _check_centre_kinds(centre or "earth", kind_arr,
                        lambda i, what: InputFormatError(path, int(line_arr[i]), "kind", *what),
                        schema)
    return MeasurementLog(
        path=path, epoch0=epoch0, t_s=t_s, kind=kind_arr.astype(f"<U{width}"), xyz=V[:, :3].copy(),
        sigma=V[:, 3].copy(), extra={c: V[:, 4 + j].copy() for j, c in enumerate(EXTRA_COLUMNS)},
        line=line_arr, warnings=warnings, dropped=dropped, spacecraft=spacecraft,
        antenna_names=antenna_names, antennas=antennas,
        centre=centre or "earth", schema=schema)


def _check_centre_kinds(centre, kind_arr, error, schema=None):
    """Refuse a kind a log of this centre cannot hold: raise ``error(row, (expected, found))``."""
    if centre == "earth":
        return
    helio = tuple(k for k, s in (_KIND_SPEC if schema is None else schema).items()
                  if s.heliocentric)
    bad = np.flatnonzero(~np.isin(np.asarray(kind_arr).astype(str), helio))
    if len(bad):
        raise error(int(bad[0]), (f"a kind of a heliocentric log (centre: {centre}): "
                                  f"{', '.join(helio)}", str(kind_arr[bad[0]])))


def _spacecraft_codes(V, kind_arr, line_arr, vocab, decl, has_column, bad):
    """The id columns' final codes (spacecraft in declared order, or of first appearance),
    the rows' cross-column checks (``bad(line, _RowError)`` for each bad row): returns
    ``(V, spacecraft ids, antenna names, antennas, keep mask)``."""
    j = {c: 4 + EXTRA_COLUMNS.index(c) for c in ID_COLUMNS}
    V = V.copy()
    names = vocab["spacecraft"].names
    if decl.spacecraft is not None:
        order = np.arange(len(names))      # declared first, in order; others after
    else:
        order = first_appearance([V[:, j[c]] for c in SPACECRAFT_COLUMNS], line_arr)
    new_of = np.full(len(names), np.nan)
    new_of[order] = np.arange(len(order))
    for c in SPACECRAFT_COLUMNS:
        col = V[:, j[c]]
        ok = ~np.isnan(col)
        col[ok] = new_of[col[ok].astype(int)]
    spacecraft = tuple(names[i] for i in order)
    antenna_names = vocab["antenna"].names
    ids = {c: V[:, j[c]] for c in ID_COLUMNS}
    keep = np.ones(len(V), dtype=bool)
    for i, reason, col, expected, found in check_rows(
            kind_arr, ids, spacecraft, antenna_names, decl.antennas,
            None if decl.spacecraft is None else len(decl.spacecraft), has_column):
        if keep[i]:
            bad(int(line_arr[i]), _RowError(reason, col, expected, found))
            keep[i] = False
    declared = spacecraft[:len(decl.spacecraft)] if decl.spacecraft is not None else spacecraft
    antennas = {k: a for k, a in decl.antennas.items() if k[0] in declared}
    return V, declared, antenna_names, antennas, keep


def _duplicates(ns, kind_arr, V, line_arr):
    """Rows equal to an earlier row in epoch, kind and every value bit (NaN included):
    (mask, (line of the first such row, line of the row it repeats) or None)."""
    dup = np.zeros(len(ns), dtype=bool)
    if len(ns) < 2:
        return dup, None
    _, code = np.unique(np.asarray(kind_arr, dtype=str), return_inverse=True)
    key = np.empty((len(ns), 2 + V.shape[1]), dtype=np.int64)
    key[:, 0] = ns
    key[:, 1] = code.reshape(-1)
    key[:, 2:] = np.ascontiguousarray(V, dtype=float).view(np.int64)
    # cheap screen first: only rows sharing an epoch and kind with another row can repeat one
    pair = key[:, :2]
    order = np.lexsort((pair[:, 1], pair[:, 0]))
    same = np.all(pair[order[1:]] == pair[order[:-1]], axis=1)
    if not same.any():
        return dup, None
    cand = np.zeros(len(ns), dtype=bool)
    cand[order[1:][same]] = True
    cand[order[:-1][same]] = True
    idx = np.flatnonzero(cand)
    rows = np.ascontiguousarray(key[idx]).view(np.dtype((np.void, key.shape[1] * 8))).ravel()
    _, first, inv = np.unique(rows, return_index=True, return_inverse=True)
    first_of = idx[first[inv.reshape(-1)]]            # first row with the same bits
    dup[idx] = first_of != idx
    if not dup.any():
        return dup, None
    j = int(np.flatnonzero(dup)[0])
    return dup, (int(line_arr[j]), int(line_arr[first_of[np.searchsorted(idx, j)]]))


def _parse_row(raw: bytes, header: list[str], is_last_unterminated: bool, vocab: dict,
               schema=None):
    """One line after the header, the reference reading: ``None`` for a blank or comment
    line, else ``(epoch, kind, values, renormalized)``; raises :class:`_RowError`."""
    ncol = len(header)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise _RowError("encoding", None, "UTF-8 text",
                        f"byte 0x{raw[exc.start]:02x} at character {exc.start + 1}") from None
    if text.endswith("\r"):
        text = text[:-1]
    stripped = text.strip()
    if not stripped or stripped.startswith("#"):
        return None
    fields = [s.strip() for s in text.split(",")]
    if len(fields) != ncol:
        if len(fields) < ncol:
            col = header[len(fields)]
            if is_last_unterminated:
                raise _RowError("truncated", col, f"{ncol} fields ({','.join(header)}); "
                                "the last line is truncated (no newline at end of file)",
                                f"{len(fields)} fields")
        else:
            col = f"field {ncol + 1}"
        raise _RowError("field_count", col, f"{ncol} comma-separated fields "
                        f"({','.join(header)})", f"{len(fields)} fields")
    t = _parse_epoch(fields[0])
    kind = fields[1]
    schema = _KIND_SPEC if schema is None else schema
    if kind not in schema:
        raise _RowError("unknown_kind", "kind", f"a kind, one of {', '.join(schema)}", kind)
    col_index = {c: j for j, c in enumerate(header)}
    v = np.full(len(_VALUE_COLUMNS), np.nan)
    for j, col in enumerate(_VALUE_COLUMNS):
        k = col_index.get(col)
        if k is not None:
            v[j] = _parse_number(fields[k], col, vocab)
    v, renorm = _check_values(kind, v, schema)
    return t, kind, v, renorm


COLUMN_WISE_MIN_ROWS = 2000
"""Logs with at least this many lines after the header are read column-wise (Arrow); shorter
ones row by row (importing Arrow, ~0.3 s, costs more than reading them). Same result."""
_FAST_NUMBER = r"^[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?$"
_FAST_EPOCH = r"^\d{4}-\d{2}-\d{2}T\d{2}:\d{2}:\d{2}(?:\.\d{1,9})?Z$"


def _regular_lines(raw_lines, start: int, ncol: int) -> tuple[np.ndarray, bytes]:
    """Indices (into ``raw_lines``, from ``start``) of the lines that may be read
    column-wise: ASCII, exactly ``ncol - 1`` commas, not starting with ``#`` or blank space
    (comments, blank lines and anything unusual are read row by row); and the lines from
    ``start`` joined (each ended by a newline)."""
    n = len(raw_lines) - start
    if n <= 0:
        return np.zeros(0, dtype=np.int64), b""
    body = b"\n".join(raw_lines[start:]) + b"\n"
    buf = np.frombuffer(body, dtype=np.uint8)
    ends = np.flatnonzero(buf == 10)                      # one per line
    begins = np.concatenate([[0], ends[:-1] + 1])
    commas = np.flatnonzero(buf == 44)
    n_commas = np.diff(np.searchsorted(commas, np.concatenate([[0], ends])))
    high = np.flatnonzero(buf >= 128)
    n_high = np.diff(np.searchsorted(high, np.concatenate([[0], ends])))
    cr = np.flatnonzero(buf == 13)
    n_cr = np.diff(np.searchsorted(cr, np.concatenate([[0], ends])))
    cr_last = buf[np.maximum(ends - 1, 0)] == 13                # a CRLF line end
    first = np.where(begins < ends, buf[np.minimum(begins, len(buf) - 1)], 10)
    ok = (n_commas == ncol - 1) & (n_high == 0) & (first != ord("#")) & (first != ord(" ")) \
        & (first != ord("\t")) & (first != 10) & (first != 13) \
        & ((n_cr == 0) | ((n_cr == 1) & cr_last))
    return np.flatnonzero(ok) + start, body


def _arrow_text_table(pa, pcsv, body: bytes, names: list[str]):
    """``body`` (lines of ``len(names)`` comma-separated fields) as Arrow text columns:
    no quoting, no escapes, every field kept as written."""
    return pcsv.read_csv(
        pa.py_buffer(body),
        read_options=pcsv.ReadOptions(column_names=names, block_size=1 << 24),
        parse_options=pcsv.ParseOptions(quote_char=False, double_quote=False,
                                        escape_char=False, newlines_in_values=False,
                                        ignore_empty_lines=False),
        convert_options=pcsv.ConvertOptions(column_types={c: pa.string() for c in names},
                                            strings_can_be_null=False))


def _fast_rows(raw_lines, start: int, header: list[str], vocab: dict | None = None,
               schema=None):
    """The plainly well-formed rows among ``raw_lines[start:]``, read column-wise.

    The regular lines (:func:`_regular_lines`) are parsed by Arrow's CSV reader as text
    columns; a row is kept here when every field matches the format (an ISO epoch, a kind,
    a decimal number or an empty field, blanks and tabs around it) and its values pass the
    kind's checks, done on whole columns with the same arithmetic as :func:`_check_values`
    (``math.hypot`` norms, one division per component). Numbers are converted by Arrow
    (correctly rounded, as Python's ``float``: the same bits). Every other line (comments,
    blank lines, errors, leap seconds, epochs outside 1678..2261, values needing a per-row
    check) is left to :func:`_parse_row`. Without ``pyarrow`` every line is. Returns (line
    indices read here, epochs ns, kinds, values (n, 9), directions renormalized, line
    indices left).
    """
    n_val = len(_VALUE_COLUMNS)
    vocab = vocab or {"spacecraft": Vocabulary(), "antenna": Vocabulary()}
    all_lines = list(range(start, len(raw_lines)))
    none = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0, dtype="<U1"),
            np.zeros((0, n_val)), 0, all_lines)
    try:
        import pyarrow as pa
        import pyarrow.compute as pc
        import pyarrow.csv as pcsv
    except ImportError:  # pragma: no cover (a dependency; row by row without it)
        return none
    ncol = len(header)
    reg, body = _regular_lines(raw_lines, start, ncol)
    if not len(reg):
        return none
    if len(reg) < len(raw_lines) - start:  # only the regular lines (Arrow reads CRLF as a line end)
        body = b"\n".join([raw_lines[i] for i in reg.tolist()]) + b"\n"
    names = [f"c{j}" for j in range(ncol)]
    try:
        table = _arrow_text_table(pa, pcsv, body, names)
    except pa.ArrowInvalid:  # pragma: no cover (regular lines are one row each)
        return none
    del body
    n = table.num_rows
    if n != len(reg):  # pragma: no cover (one row per regular line by construction)
        return none

    def text(j, last=False):
        return pc.utf8_trim(table.column(j), " \t\r" if last else " \t")

    def as_bool(a):
        return np.asarray(a.to_numpy(zero_copy_only=False), dtype=bool)

    # epoch: calendar label from numpy (exact in ns), then TAI - UTC of its era (fgnav.time)
    ep = text(0, ncol == 1)
    good = as_bool(pc.match_substring_regex(ep, _FAST_EPOCH))
    ep = np.asarray(pc.utf8_slice_codeunits(ep, 0, 29).to_numpy(zero_copy_only=False)
                    ).astype("S")
    ep[~good] = b"2000-01-01T00:00:00"
    digits = np.frombuffer(np.ascontiguousarray(ep).tobytes(), dtype=np.uint8).reshape(
        n, ep.dtype.itemsize)[:, :19].astype(np.int64) - 48
    year = digits[:, 0] * 1000 + digits[:, 1] * 100 + digits[:, 2] * 10 + digits[:, 3]
    hh, mm, ss = (digits[:, k] * 10 + digits[:, k + 1] for k in (11, 14, 17))
    good &= (year >= 1678) & (year <= 2261) & (hh <= 23) & (mm <= 59) & (ss <= 59)
    ep = np.char.rstrip(ep, b"Z")
    ep[~good] = b"2000-01-01T00:00:00"
    try:
        label = ep.astype("datetime64[ns]").astype(np.int64)
    except ValueError:  # an invalid date somewhere: find it row by row
        label = np.zeros(n, dtype=np.int64)
        for i in np.flatnonzero(good):
            try:
                label[i] = np.datetime64(ep[i].decode(), "ns").astype(np.int64)
            except ValueError:
                good[i] = False
    del ep, digits
    ns = label + era_shift_ns(label)
    kinds = np.asarray(text(1, ncol == 2).to_numpy(zero_copy_only=False)).astype(str)
    schema = _KIND_SPEC if schema is None else schema
    good &= np.isin(kinds, tuple(schema))
    col_at = {c: j for j, c in enumerate(header)}
    V = np.full((n, n_val), np.nan)
    for j, c in enumerate(_VALUE_COLUMNS):
        k = col_at.get(c)
        if k is None:
            continue
        t = text(k, k == ncol - 1)
        filled = as_bool(pc.not_equal(t, ""))
        if c in ID_COLUMNS:   # names -> codes of the vocabulary (fgnav.io.log_spacecraft)
            V[:, j] = _fast_ids(t, filled, c, vocab, good)
            continue
        good &= ~filled | as_bool(pc.match_substring_regex(t, _FAST_NUMBER))
        t = pc.if_else(pa.array(filled & good), t, "nan")
        V[:, j] = np.asarray(pc.cast(t, pa.float64()).to_numpy(zero_copy_only=False))
    del table
    good &= np.all(~np.isinf(V), axis=1)
    renorm = np.zeros(n, dtype=bool)
    for kind in np.unique(kinds[good]):
        rows = np.flatnonzero((kinds == kind) & good)
        spec = schema[str(kind)]
        Vk = V[rows]
        for col, use in zip(_USAGE_COLUMNS, _usage(spec)):
            nan = np.isnan(Vk[:, _VALUE_COLUMNS.index(col)])
            good[rows] &= ~nan if use == "r" else (nan if use == "" else True)
        if spec.check is not None:  # on the values as read (before any renormalization)
            sm = _VALUE_COLUMNS.index("sigma_model_m")
            for r in np.flatnonzero(good[rows]):
                try:
                    spec.check(*(float(Vk[r, j]) for j in (0, 1, 2, sm)))
                except _RowError:
                    good[rows[r]] = False
        if spec.row_check is not None:  # checks that need the extra columns, row by row
            for r in np.flatnonzero(good[rows]):
                try:
                    spec.row_check(dict(zip(_VALUE_COLUMNS, map(float, Vk[r]))))
                except _RowError:
                    good[rows[r]] = False
        sig = Vk[:, 3]
        good[rows] &= (sig > 0.0) & (sig >= spec.sigma_min) & (sig <= spec.sigma_max)
        for cj in ([[0, 1, 2]] if spec.unit_vector else []) + (
                [[_VALUE_COLUMNS.index(c) for c in spec.unit_columns]]
                if spec.unit_columns else []):
            a, b, c = (Vk[:, j].tolist() for j in cj)
            norm = np.array(list(map(math.hypot, a, b, c)))
            dev = np.abs(1.0 - norm)
            good[rows] &= dev <= UNIT_TOL
            fix = dev > _RENORM_TOL
            if fix.any():
                for j in cj:
                    Vk[fix, j] = Vk[fix, j] / norm[fix]
                renorm[rows[fix]] = True
        V[rows] = Vk
    kept = reg[good]
    slow = np.setdiff1d(np.arange(start, len(raw_lines)), kept, assume_unique=True)
    return kept, ns[good], kinds[good], V[good], int(renorm[good].sum()), slow.tolist()


def _fast_ids(t, filled, column, vocab, good):
    """Codes (n,) of an id column's text ``t`` (Arrow), NaN where empty; rows with a
    malformed name are marked not ``good`` (read row by row, for the message)."""
    names = np.asarray(t.to_numpy(zero_copy_only=False)).astype(str)
    out = np.full(len(names), np.nan)
    uniq, first, inv = np.unique(names[filled], return_index=True, return_inverse=True)
    voc = vocab["spacecraft" if column in SPACECRAFT_COLUMNS else "antenna"]
    codes = np.full(len(uniq), np.nan)
    for u in np.argsort(first):       # in order of appearance
        if ID_RE.match(uniq[u]):
            codes[u] = voc.code(str(uniq[u]))
    out[filled] = codes[inv.reshape(-1)]
    good &= ~(filled & np.isnan(out))
    return out


def _sort_rows(ns, V, kind_arr, line_arr, path):
    """Stable sort by epoch; returns the arrays and a warning (or None)."""
    if len(ns) < 2 or np.all(np.diff(ns) >= 0):
        return ns, V, kind_arr, line_arr, None
    running_max = np.maximum.accumulate(ns)
    late = ns[1:] < running_max[:-1]
    n = int(late.sum())
    first = int(line_arr[1:][late][0])
    order = np.argsort(ns, kind="stable")
    msg = (f"{path}: {n} row(s) out of time order (first at line {first}); rows stably "
           "sorted by epoch")
    return ns[order], V[order], kind_arr[order], line_arr[order], msg


def log_from_arrays(epoch0, t_s, kind, xyz, sigma, extra=None, *,
                    path="<arrays>", spacecraft=(), antennas=None,
                    centre="earth", schema=None) -> MeasurementLog:
    """Build a validated :class:`MeasurementLog` from arrays (same rules as :func:`read_log`).

    ``epoch0`` datetime64 (UTC) or ISO string; ``t_s`` (M,) s from ``epoch0``; ``kind`` (M,)
    str; ``xyz`` (M, 3) with NaN for unused fields; ``sigma`` (M,); ``extra`` optional dict
    of (M,) arrays for the extra columns (``gamma``, ``sigma_model_m``, ``star_x``, ...). Rows are stably sorted by epoch and
    directions with tiny norm errors renormalized; ``epoch0`` is kept as given. A bad row
    raises :class:`~fgnav.errors.UserError` naming its index, column and the expectation.
    ``centre``: the central body of the positions (:data:`CENTRES`); ``schema``: the kinds
    (:func:`read_log`).
    Several spacecraft (:mod:`fgnav.io.log_spacecraft`): ``extra["spacecraft"]`` etc. as
    names (or codes into ``spacecraft``, the ids in order), ``antennas`` the lever arms by
    (spacecraft id, antenna name).
    """
    if centre not in CENTRES:
        raise UserError(f"log_from_arrays: centre: expected one of {', '.join(CENTRES)}, "
                        f"found {centre!r}")
    if isinstance(epoch0, str):
        epoch0 = parse_utc(epoch0)
    epoch0 = np.datetime64(epoch0, "ns")
    t_s = np.asarray(t_s, dtype=float).reshape(-1)
    M = len(t_s)
    kind_arr = np.asarray(kind).astype(str).reshape(-1)
    xyz = np.asarray(xyz, dtype=float)
    sigma = np.asarray(sigma, dtype=float).reshape(-1)
    if kind_arr.shape != (M,) or xyz.shape != (M, 3) or sigma.shape != (M,):
        raise UserError(f"log_from_arrays: shapes must be t_s (M,), kind (M,), xyz (M, 3), "
                        f"sigma (M,); found {t_s.shape}, {kind_arr.shape}, {xyz.shape}, "
                        f"{sigma.shape}")
    if M == 0:
        raise UserError("log_from_arrays: no measurements")
    if not np.all(np.abs(t_s) < 1e9):  # also rejects NaN / inf
        raise UserError("log_from_arrays: t_s must be finite and within 1e9 s of epoch0")
    extra = dict(extra or {})
    for c in ID_COLUMNS:   # an id column with no value is no column (one spacecraft)
        if c in extra and all(v is None or v == "" or (isinstance(v, float) and math.isnan(v))
                              for v in np.asarray(extra[c], dtype=object).reshape(-1)):
            del extra[c]
    unknown = set(extra) - set(EXTRA_COLUMNS)
    if unknown:
        raise UserError(f"log_from_arrays: unknown extra column(s) {sorted(unknown)}; "
                        f"expected only {EXTRA_COLUMNS}")
    E = np.full((M, len(EXTRA_COLUMNS)), np.nan)
    names = {"spacecraft": list(spacecraft), "antenna": []}
    for j, c in enumerate(EXTRA_COLUMNS):
        if c in extra:
            if c in ID_COLUMNS:
                try:
                    a = id_codes(extra[c], names["spacecraft" if c in SPACECRAFT_COLUMNS
                                                 else "antenna"], c)
                except ValueError as exc:
                    raise UserError(f"log_from_arrays: extra[{c!r}]: {exc}") from None
            elif c in BODY_COLUMNS:
                try:
                    a = body_codes(extra[c])
                except ValueError as exc:
                    raise UserError(f"log_from_arrays: extra[{c!r}]: {exc}") from None
            else:
                a = np.asarray(extra[c], dtype=float).reshape(-1)
            if a.shape != (M,):
                raise UserError(f"log_from_arrays: extra[{c!r}] must have shape ({M},), "
                                f"found {a.shape}")
            E[:, j] = a
    V = np.concatenate([xyz, sigma[:, None], E], axis=1)
    for i in range(M):
        try:
            V[i], _ = _check_values(str(kind_arr[i]), V[i], schema)
        except _RowError as err:
            found = "" if err.found is None else f", found {err.found!r}"
            raise UserError(f"log_from_arrays: row {i}, column '{err.column}': expected "
                            f"{err.expected}{found}") from None

    _check_centre_kinds(centre, kind_arr, lambda i, what: UserError(
        f"log_from_arrays: row {i}, column 'kind': expected {what[0]}, found {what[1]!r}"),
        schema)
    antennas = {(str(a), str(b)): np.asarray(arm, dtype=float).reshape(3)
                for (a, b), arm in (antennas or {}).items()}
    if any(c in extra for c in ID_COLUMNS):
        ids = {c: E[:, EXTRA_COLUMNS.index(c)] for c in ID_COLUMNS}
        for i, reason, col, expected, found in check_rows(
                kind_arr, ids, tuple(names["spacecraft"]), tuple(names["antenna"]), antennas,
                len(spacecraft) if spacecraft else None, "spacecraft" in extra):
            raise UserError(f"log_from_arrays: row {i}, column '{col}': expected {expected}, "
                            f"found {found!r}")
    ns = add_seconds(epoch0, t_s).astype(np.int64)
    line = np.zeros(M, dtype=np.int64)
    order = np.argsort(ns, kind="stable")
    warnings = []
    if np.any(np.diff(ns) < 0):
        warnings.append(f"{path}: rows out of time order; stably sorted by epoch")
    V = V[order]
    return MeasurementLog(
        path=path, epoch0=epoch0, t_s=t_s[order], kind=kind_arr[order], xyz=V[:, :3].copy(),
        sigma=V[:, 3].copy(), extra={c: V[:, 4 + j].copy() for j, c in enumerate(EXTRA_COLUMNS)},
        line=line, warnings=warnings, dropped={},
        spacecraft=tuple(names["spacecraft"]) if any(c in extra for c in SPACECRAFT_COLUMNS)
        else (), antenna_names=tuple(names["antenna"]), antennas=antennas, centre=centre,
        schema=schema)


def _fmt(v: float, column: str = "", names=None) -> str:
    if math.isnan(v):
        return ""
    if column in ID_COLUMNS:
        return names["spacecraft" if column in SPACECRAFT_COLUMNS else "antenna"][int(v)]
    return BODIES[int(v)] if column in BODY_COLUMNS else repr(float(v))


def _fmt_epoch(ns: int) -> str:
    return format_utc(np.datetime64(int(ns), "ns"), "us" if ns % 1000 == 0 else "ns")


def write_log(path, log: MeasurementLog, *, comments=(), schema=None) -> None:
    """Write ``log`` to ``path`` (CSV v1) atomically; rows in the log's order.

    The extra columns are written only when some row uses them. Each row is validated
    first, by its kind's row of ``schema`` (:func:`read_log`; default the log's own
    schema): a log that cannot be read back is never written.
    """
    if schema is None:
        schema = log.schema
    M = len(log.t_s)
    kind = np.asarray(log.kind).astype(str)
    xyz = np.asarray(log.xyz, dtype=float)
    sigma = np.asarray(log.sigma, dtype=float)
    extra = {c: body_codes(log.extra[c]) if c in BODY_COLUMNS else
             np.asarray(log.extra[c], dtype=float) for c in EXTRA_COLUMNS
             if c in (log.extra or {}) and c not in ID_COLUMNS}
    names = {"spacecraft": list(getattr(log, "spacecraft", ()) or ()),
             "antenna": list(getattr(log, "antenna_names", ()) or ())}
    for c in ID_COLUMNS:
        if c in (log.extra or {}):
            try:
                extra[c] = id_codes(log.extra[c], names["spacecraft" if c in SPACECRAFT_COLUMNS
                                                        else "antenna"], c)
            except ValueError as exc:
                raise UserError(f"write_log: {exc}") from None
    unknown = set(log.extra or {}) - set(EXTRA_COLUMNS)
    if unknown:
        raise UserError(f"write_log: unknown extra column(s) {sorted(unknown)}")
    used = [c for c in EXTRA_COLUMNS if c in extra and np.any(~np.isnan(extra[c]))]
    ns = add_seconds(log.epoch0, log.t_s).astype(np.int64)
    header = list(BASE_COLUMNS) + used
    out = ["# fgnav measurement log, CSV format v1 (see fgnav.io.log_csv)\n"]
    if getattr(log, "centre", "earth") != "earth":
        out.append(f"# centre: {log.centre}\n")
    out += [f"# {c}\n" for c in comments]
    if any(c in used for c in ID_COLUMNS):
        out += [f"# {c}\n" for c in declaration_lines(names["spacecraft"],
                                                       getattr(log, "antennas", {}) or {})]
    out.append(",".join(header) + "\n")
    for i in range(M):
        v = np.array([*xyz[i], sigma[i]] + [extra[c][i] if c in extra else np.nan
                                            for c in EXTRA_COLUMNS])
        try:
            _check_values(str(kind[i]), v, schema)
        except _RowError as err:
            raise UserError(f"write_log: row {i}, column '{err.column}': expected "
                            f"{err.expected}, found {err.found!r}") from None
        row = [_fmt_epoch(int(ns[i])), str(kind[i]), _fmt(xyz[i, 0]), _fmt(xyz[i, 1]),
               _fmt(xyz[i, 2]), _fmt(sigma[i])] + [_fmt(extra[c][i], c, names) for c in used]
        out.append(",".join(row) + "\n")
    with atomic_writer(path, "w") as f:
        f.write("".join(out))


# ---- one line at a time (a live stream: fgnav.online.stream) ----

CENTRE_LINE = _CENTRE_LINE
"""A ``# centre: NAME`` comment line (group 1: the name)."""


def check_header(path, lineno: int, text: str) -> list[str]:
    """The column names of a header line (the module docstring's rules), or
    :class:`~fgnav.errors.InputFormatError` naming ``path``, ``lineno`` and the column."""
    return _check_header(path, lineno, text)


def parse_line(path, lineno: int, raw: bytes, header: list[str], *, last_unterminated=False,
               vocab: dict | None = None, schema=None):
    """One line after the header by the same rules as :func:`read_log`: ``None`` for a blank
    or comment line, else ``(epoch ns (int), kind, values (len(VALUE_COLUMNS),), reason)``
    with ``reason`` None; a bad line raises :class:`~fgnav.errors.InputFormatError` naming
    ``path`` and ``lineno``, with the row-level reason key as its ``reason`` attribute.
    ``schema``: the kinds (:func:`read_log`)."""
    vocab = vocab or {"spacecraft": Vocabulary(()), "antenna": Vocabulary()}
    try:
        row = _parse_row(raw, header, last_unterminated, vocab, schema)
    except _RowError as err:
        exc = InputFormatError(path, lineno, err.column, err.expected, err.found)
        exc.reason = err.reason
        raise exc from None
    if row is None:
        return None
    t, kind, v, _ = row
    return int(t.astype(np.int64)), kind, v


VALUE_COLUMNS = _VALUE_COLUMNS
"""The order of :func:`parse_line`'s values: x, y, z, sigma, then :data:`EXTRA_COLUMNS`."""
