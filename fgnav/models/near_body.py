"""Near bodies imaged by an optical navigation camera (issue 31 item 1): the direction of a
body's centre in EME2000 (``body_direction``) and in the body frame (``body_direction_body``,
on the attitude), with the log's ``body`` column (earth, moon, sun); and the state of the
named body in the pass's frame that these rows and ``limb_radius`` rows with a ``body``
(:mod:`fgnav.models.ranges`) read.

The model is ``factors.near_body``: the body's light time and the observer's aberration to
first order in ``beta = (v - v_b)/c`` (Urban & Seidelmann 2013, sec. 7.2.4, planetary
aberration); the body's position and velocity from DE421 (Folkner, Williams & Boggs 2009;
``factors.jpl_ephemeris``). ``fgnav smooth --no-aberration`` turns the aberration off
(``fgnav.apparent``); the light time stays.
"""

from __future__ import annotations

import numpy as np

from factors.geometry import tangent_basis
from factors.jpl_ephemeris import moon_state_de421, sun_state_de421
from factors.near_body import (make_near_body_direction_factor, near_body_direction_body_residual,
                               near_body_direction_residual, near_body_direction_row_kernel)
from fgnav.io.log_csv import BODIES, KindSpec
from fgnav.models.attitude import ATTITUDE_VARIABLE
from fgnav.models.model import MeasurementModel
from fgnav.models.values import ephemeris_span, xyz_rows
from fgnav.time import j2000_seconds

__all__ = ["MEASUREMENT_MODELS", "LOG_KINDS", "BODY_DIRECTION", "BODY_DIRECTION_BODY",
           "near_body_states", "row_bodies"]


def near_body_states(codes, t_j2000_s, centre: str = "earth"):
    """Position (M, 3), m, and velocity (M, 3), m/s, in the pass's frame (EME2000 axes,
    origin the log's ``centre``: earth or moon) of the bodies with log codes ``codes`` (M,)
    (:data:`fgnav.io.log_csv.BODIES`; NaN: none, zeros) at ``t_j2000_s`` (M,), from DE421."""
    codes = np.asarray(codes, dtype=float).reshape(-1)
    t = np.asarray(t_j2000_s, dtype=float).reshape(-1)
    p, v = np.zeros((len(t), 3)), np.zeros((len(t), 3))
    named = np.isfinite(codes)
    if not np.any(named) and centre == "earth":
        return p, v
    rm, vm = moon_state_de421(t)
    for name, state in (("moon", (rm, vm)), ("sun", sun_state_de421(t) if np.any(
            codes == BODIES.index("sun")) else None)):
        i = np.flatnonzero(codes == BODIES.index(name))
        if len(i):
            p[i], v[i] = state[0][i], state[1][i]
    if centre == "moon":
        p, v = p - rm, v - vm
    elif centre != "earth":
        raise ValueError(f"near body rows: expected a geocentric or Moon-centred log, found "
                         f"centre {centre!r}")
    return p, v


def row_bodies(log, i):
    """The ``body`` codes (M,) of the log's rows ``i`` (NaN where empty), their epochs
    ``t_j2000_s`` (M,) and the named bodies' ``p_body_m``, ``v_body_mps`` (M, 3) in the
    pass's frame (:func:`near_body_states`; zeros where no body is named)."""
    extra = log.extra or {}
    codes = (np.asarray(extra["body"], dtype=float)[i] if "body" in extra
             else np.full(len(i), np.nan))
    tj = float(j2000_seconds(log.epoch0)) + np.asarray(log.t_s, dtype=float)[i]
    with ephemeris_span(log, i, "near-body rows"):
        p, v = near_body_states(codes, tj, getattr(log, "centre", "earth"))
    return {"body": codes, "t_j2000_s": tj, "p_body_m": p, "v_body_mps": v}


def _direction_values(log, i):
    out = {"u_meas": xyz_rows(log, i), **row_bodies(log, i)}
    out["light_time"] = np.ones(len(i), bool)
    out["aberration"] = np.ones(len(i), bool)
    return out


def _groups(fam):
    """Row groups with one (light time, aberration) setting (one group in practice:
    ``--no-aberration`` switches a whole family)."""
    key = 2 * np.asarray(fam.values["light_time"], int) + np.asarray(fam.values["aberration"], int)
    for k in np.unique(key):
        yield np.flatnonzero(key == k), bool(k // 2), bool(k % 2)


def _direction_residual(fam, v):
    x = v["orbit"]
    e, Hx = np.zeros((len(fam), 2)), np.zeros((len(fam), 2, 6))
    for i, lt, ab in _groups(fam):
        e[i], Hx[i] = near_body_direction_residual(
            x[i], fam.values["u_meas"][i], fam.values["p_body_m"][i],
            fam.values["v_body_mps"][i], light_time=lt, aberration=ab)
    return e, {"orbit": Hx}


def _direction_body_residual(fam, v):
    x, R = v["orbit"], v[ATTITUDE_VARIABLE.name]
    e, Hx, HR = np.zeros((len(fam), 2)), np.zeros((len(fam), 2, 6)), np.zeros((len(fam), 2, 3))
    for i, lt, ab in _groups(fam):
        e[i], Hx[i], HR[i] = near_body_direction_body_residual(
            x[i], R[i], fam.values["u_meas"][i], fam.values["p_body_m"][i],
            fam.values["v_body_mps"][i], light_time=lt, aberration=ab)
    return e, {"orbit": Hx, ATTITUDE_VARIABLE.name: HR}


def _direction_factor(body_frame):
    def factor(fam, j, keys, noise):
        val = fam.values
        return make_near_body_direction_factor(
            keys["orbit"], val["u_meas"][j], val["p_body_m"][j], val["v_body_mps"][j], noise,
            key_R=keys[ATTITUDE_VARIABLE.name] if body_frame else None,
            light_time=bool(val["light_time"][j]), aberration=bool(val["aberration"][j]))
    return factor


def _direction_data(fam):
    """Packed rows of :func:`factors.near_body.near_body_direction_row_kernel`: ``data`` (M, 4)
    ``(0, 0, light time, aberration)``, ``B`` (M, 4, 3) ``(p_body, v_body, b1, b2)``."""
    val = fam.values
    d = np.zeros((len(fam), 4))
    d[:, 2], d[:, 3] = val["light_time"], val["aberration"]
    B = np.concatenate([val["p_body_m"][:, None], val["v_body_mps"][:, None],
                        tangent_basis(val["u_meas"])], axis=1)
    return d, B


BODY_DIRECTION = MeasurementModel(
    kind="body_direction", dim=2, unit="rad", observes_orbit=True,
    summary="unit vector to a near body's centre (body column), EME2000, apparent",
    values=_direction_values, residual=_direction_residual, factor=_direction_factor(False),
    numba_kernel=near_body_direction_row_kernel, numba_data=_direction_data)

BODY_DIRECTION_BODY = MeasurementModel(
    kind="body_direction_body", dim=2, unit="rad", observes_orbit=True,
    summary="unit vector to a near body's centre (body column), body frame, apparent",
    values=_direction_values, residual=_direction_body_residual,
    factor=_direction_factor(True),
    optional_variables=(ATTITUDE_VARIABLE,), requires=ATTITUDE_VARIABLE.name)

MEASUREMENT_MODELS = (BODY_DIRECTION, BODY_DIRECTION_BODY)
"""This module's measurement models (assembled by :mod:`fgnav.models.registry`)."""

_BODY_REQUIRED = ("r", "r", "r", "", "", "", "", "", "r")
LOG_KINDS = {
    BODY_DIRECTION.kind: KindSpec(
        _BODY_REQUIRED, "unit vector to the centre of body (sun, earth, moon), EME2000, "
        "apparent", 1e-9, 1.0, "rad", unit_vector=True),
    BODY_DIRECTION_BODY.kind: KindSpec(
        _BODY_REQUIRED, "unit vector to the centre of body (sun, earth, moon), body frame, "
        "apparent", 1e-9, 1.0, "rad", unit_vector=True),
}
"""The log schema rows of the kinds the CSV format does not list (README's table)."""
