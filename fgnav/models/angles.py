"""Attitude-free angles between lines of sight (``body_star_angle``, ``limb_star_angle``,
``body_body_angle``; ``factors.celestial_angles``)."""

from __future__ import annotations

import numpy as np

from factors.celestial_angles import (BODY_BODY, BODY_STAR, apparent_angle_residual,
                                      celestial_angle_kernel, make_celestial_angle_factor,
                                      pack_angle_rows)
from factors.planets import check_span
from fgnav.io.log_csv import BODIES, STAR_COLUMNS
from fgnav.models.bodies import body_position_eci_m, body_velocity_mps, frame_velocity_bcrs_mps
from fgnav.models.model import MeasurementModel
from fgnav.models.values import ephemeris_span, xyz_rows
from fgnav.time import j2000_seconds

__all__ = ["MEASUREMENT_MODELS", "BODY_STAR_ANGLE", "LIMB_STAR_ANGLE", "BODY_BODY_ANGLE"]


# A sextant-like instrument measures the angle between two lines of sight: near body - star
# (a cone), near body's limb - star (the sextant), near body - near body (a torus). No
# attitude enters (factors/celestial_angles.py).
# The limb form is a kind of its own rather than a flag on body_star_angle: it carries a
# further value (the limb sphere's radius, column y, as limb_radius rows do) and another
# residual, and a reader that ignored a flag would take a limb angle for a centre angle
# silently (wrong by the apparent radius, ~60 deg in LEO), where an unknown kind is refused.

def _bodies_at(codes, t_j2000_s, centre="earth", of=body_position_eci_m):
    """Centres (M, 3), m, of the bodies with log codes ``codes`` (M,) at the rows' epochs,
    relative to the log's ``centre`` (EME2000 axes); ``of=body_velocity_mps``: their
    velocities, m/s."""
    out = np.zeros((len(codes), 3))
    for c in np.unique(codes):
        i = np.flatnonzero(codes == c)
        out[i] = of(BODIES[int(c)], t_j2000_s[i], centre)
    return out


def _angle_values(star, limb):
    """``values(log, rows)`` of an angle kind: ``a_rad`` (M,) the measured angle; the body's
    centre ``p_body_eci_m`` (M, 3) and velocity ``v_body_mps`` at the row's epoch; the star
    ``s_eci`` (M, 3) or the second body ``p_body2_eci_m``, ``v_body2_mps``; ``r_limb_m``
    (limb form); the frame's barycentric velocity ``v_frame_bcrs_mps``; ``aberration`` (M,)
    bool, apparent lines of sight (``fgnav smooth --no-aberration`` turns it off); and the
    rows packed for the kernel, ``data`` (M, 4) and ``B`` (M, 5, 3)
    (``factors.celestial_angles.pack_angle_rows``)."""
    def values(log, i):
        with ephemeris_span(log, i, "angle rows"):
            return rows(log, i)

    def rows(log, i):
        xyz = xyz_rows(log, i)
        tj = float(j2000_seconds(log.epoch0)) + np.asarray(log.t_s, dtype=float)[i]
        check_span(tj)   # also where every body is the Earth (no ERFA call below)
        centre = getattr(log, "centre", "earth")
        codes = np.asarray(log.extra["body"], float)[i]
        out = {"a_rad": xyz[:, 0], "p_body_eci_m": _bodies_at(codes, tj, centre),
               "v_body_mps": _bodies_at(codes, tj, centre, body_velocity_mps),
               "v_frame_bcrs_mps": frame_velocity_bcrs_mps(tj, centre),
               "aberration": np.ones(len(tj), bool)}
        if star:
            out["s_eci"] = np.column_stack([np.asarray(log.extra[c], dtype=float)[i]
                                            for c in STAR_COLUMNS])
            out["r_limb_m"] = xyz[:, 1] if limb else np.zeros(len(tj))
        else:
            codes2 = np.asarray(log.extra["body2"], float)[i]
            out["p_body2_eci_m"] = _bodies_at(codes2, tj, centre)
            out["v_body2_mps"] = _bodies_at(codes2, tj, centre, body_velocity_mps)
        out["data"], out["B"] = pack_angle_rows(
            out["a_rad"], out["r_limb_m"] if star else 0.0, BODY_STAR if star else BODY_BODY,
            out["p_body_eci_m"], out["s_eci"] if star else out["p_body2_eci_m"],
            v_body_mps=out["v_body_mps"], v_body2_mps=0.0 if star else out["v_body2_mps"],
            v_frame_bcrs_mps=out["v_frame_bcrs_mps"], aberration=True)
        return out
    return values


def _angle_packed(fam, rows=slice(None)):
    """The family's rows ``rows`` packed for ``factors.celestial_angles`` (``data``, ``B``:
    packed once by the values), with the aberration flag as the family holds it now
    (``fgnav.apparent.without_aberration`` turns the ``aberration`` value off)."""
    v = fam.values
    data, on = v["data"][rows], v["aberration"][rows]
    if np.any((data[:, 3] != 0.0) != on):
        data = data.copy()
        data[:, 3] = on
    return data, v["B"][rows]


def _angle_residual(fam, v):
    data, B = _angle_packed(fam)
    e, H = apparent_angle_residual(v["orbit"], data, B)
    return e, {"orbit": H}


def _angle_model(kind, summary, star, limb):
    return MeasurementModel(
        kind=kind, dim=1, unit="rad", observes_orbit=True, summary=summary,
        values=_angle_values(star, limb), residual=_angle_residual,
        factor=lambda fam, j, keys_, noise: make_celestial_angle_factor(
            keys_["orbit"], *(a[0] for a in _angle_packed(fam, slice(j, j + 1))), noise),
        numba_kernel=celestial_angle_kernel, numba_data=_angle_packed)


BODY_STAR_ANGLE = _angle_model(
    "body_star_angle", "angle between a near body's centre and a star (rad)",
    star=True, limb=False)
LIMB_STAR_ANGLE = _angle_model(
    "limb_star_angle", "angle between a near body's limb and a star (rad): the sextant",
    star=True, limb=True)
BODY_BODY_ANGLE = _angle_model(
    "body_body_angle", "angle between two near bodies' centres (rad)",
    star=False, limb=False)

MEASUREMENT_MODELS = (BODY_STAR_ANGLE, LIMB_STAR_ANGLE, BODY_BODY_ANGLE)
"""This module's measurement models (assembled by :mod:`fgnav.models.registry`)."""
