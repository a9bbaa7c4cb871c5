"""Directions to the Earth, Sun and Moon in the body frame (``earth_direction_body``,
``sun_direction_body``, ``moon_direction_body``): factors on the orbit and the attitude
(``factors.direction``), or, without the attitude estimated, rotated into ECI by the measured
attitude before the graph (``fgnav.sun_earth_moon``)."""

from __future__ import annotations

import numpy as np

from factors.attitude import triad
from factors.direction import body_direction_residual, make_body_direction_factor
from factors.geometry import so3_exp, so3_log
from factors.planets import moon_position_geo_m, sun_position_geo_m
from fgnav.models.attitude import ATTITUDE_VARIABLE
from fgnav.models.directions import EARTH_DIRECTION
from fgnav.models.model import MeasurementModel
from fgnav.models.values import ephemeris_span, xyz_rows
from fgnav.time import j2000_seconds

__all__ = ["MEASUREMENT_MODELS", "EARTH_DIRECTION_BODY", "SUN_DIRECTION_BODY", "MOON_DIRECTION_BODY"]


def _body_residual(fam, v):
    e, H_r, H_R = body_direction_residual(v["orbit"][:, :3], v[ATTITUDE_VARIABLE.name],
                                          fam.values["p_target_eci_m"], fam.values["u_body"])
    return e, {"position": H_r, ATTITUDE_VARIABLE.name: H_R}


def _body_factor(fam, j, keys, noise):
    return make_body_direction_factor(keys["orbit"], keys[ATTITUDE_VARIABLE.name],
                                      fam.values["p_target_eci_m"][j], fam.values["u_body"][j],
                                      noise)


def _body_values(ephemeris, partner=None):
    """``values(log, rows)`` of a body-frame direction kind: ``u_body`` (M, 3); the row's epoch
    ``t_j2000_s`` (M,) s after J2000 and the target's ECI position ``p_target_eci_m`` (M, 3), m,
    from ``ephemeris(t_j2000_s)`` (ERFA, ``factors.planets``; None: the Earth centre, the
    origin);
    with ``partner`` (a kind) also ``u_partner_body`` (M, 3), that kind's body-frame direction
    at the row's epoch (NaN where the epoch has none), for the first guess of the attitude."""
    def values(log, i):
        t = np.asarray(log.t_s, dtype=float)[i]
        tj = float(j2000_seconds(log.epoch0)) + t
        with ephemeris_span(log, i, "rows"):
            p = np.zeros((len(t), 3)) if ephemeris is None else ephemeris(tj).reshape(-1, 3)
        out = {"u_body": xyz_rows(log, i), "t_j2000_s": tj, "p_target_eci_m": p}
        if partner is not None:
            out["u_partner_body"] = np.full((len(t), 3), np.nan)
            jp = log.select(partner)
            if len(jp):
                tp = np.asarray(log.t_s, dtype=float)[jp]
                order = np.argsort(tp, kind="stable")
                pos = np.clip(np.searchsorted(tp[order], t), 0, len(jp) - 1)
                hit = tp[order][pos] == t
                out["u_partner_body"][hit] = np.asarray(log.xyz, dtype=float)[jp[order][pos[hit]]]
        return out
    return values


def _moon_sun_initial(fam):
    """First guess of the attitude at every Moon row: TRIAD (``factors.attitude.triad``;
    Black 1964, Shuster & Oh 1981) of the body-frame Sun direction of the same epoch (matched
    exactly: the finer sensor) and the Moon direction against their geocentric ECI directions
    from the ephemeris. The Moon's parallax (spacecraft vs Earth centre, <= 1.1 deg in LEO)
    is left in: the solver removes it. A row whose epoch has no Sun row (eclipse) takes the
    guess of the nearest epoch that has, turned by the smallest rotation that puts its own
    Moon direction right. None without any such pair. Epochs without a Moon row get no guess
    from here: the solvers carry the attitude to them (the online ones from the previous
    epoch's estimate, which a guess held over the Moon-less part of an orbit would replace
    with one tens of degrees off)."""
    pair = np.flatnonzero(np.all(np.isfinite(fam.values["u_partner_body"]), axis=1))
    if not len(pair):
        return {}
    m_eci = fam.values["p_target_eci_m"]
    s_eci = sun_position_geo_m(fam.values["t_j2000_s"][pair])
    try:
        R = triad(fam.values["u_partner_body"][pair], fam.values["u_body"][pair], s_eci,
                  m_eci[pair])
    except ValueError:
        return {}                              # Sun and Moon (anti)parallel: no first guess
    ep = fam.k[pair]
    j = np.clip(np.searchsorted(ep, fam.k), 0, len(ep) - 1)
    lo = np.clip(j - 1, 0, len(ep) - 1)
    R = R[np.where(np.abs(ep[lo] - fam.k) <= np.abs(ep[j] - fam.k), lo, j)]
    a = np.einsum("nij,nj->ni", R, fam.values["u_body"])          # Moon as the guess puts it
    b = m_eci / np.linalg.norm(m_eci, axis=1, keepdims=True)
    axis = np.cross(a, b)
    angle = np.arctan2(np.linalg.norm(axis, axis=1), np.sum(a * b, axis=1))
    axis *= (angle / np.maximum(np.linalg.norm(axis, axis=1), 1e-300))[:, None]
    return {ATTITUDE_VARIABLE.name: so3_log(so3_exp(axis) @ R)}


def _body(kind, target, observes, ephemeris=None, into=None, partner=None, initial=None):
    return MeasurementModel(
        kind=kind, dim=2, unit="rad", observes_orbit=observes,
        summary=f"unit vector to the {target}, body frame",
        values=_body_values(ephemeris, partner),
        body_frame_of=into,
        residual=_body_residual, factor=_body_factor, initial=initial,
        optional_variables=(ATTITUDE_VARIABLE,), requires=ATTITUDE_VARIABLE.name)


# Without --estimate attitude the Sun and Moon rows go through the TRIAD preprocessing
# (fgnav.sun_earth_moon.preprocess_log) before the graph; with it they are factors on
# (orbit, attitude), the target at its ephemeris position (parallax included).
EARTH_DIRECTION_BODY = _body("earth_direction_body", "Earth centre", True,
                             into=EARTH_DIRECTION.kind)
SUN_DIRECTION_BODY = _body("sun_direction_body", "Sun", False, ephemeris=sun_position_geo_m)
MOON_DIRECTION_BODY = _body("moon_direction_body", "Moon", False, ephemeris=moon_position_geo_m,
                            partner=SUN_DIRECTION_BODY.kind, initial=_moon_sun_initial)


MEASUREMENT_MODELS = (EARTH_DIRECTION_BODY, SUN_DIRECTION_BODY, MOON_DIRECTION_BODY)
"""This module's measurement models (assembled by :mod:`fgnav.models.registry`)."""
