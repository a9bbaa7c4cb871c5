"""Range-like rows: the limb's angular radius (``limb_radius``, ``factors.limb``; with a
``body`` column, the apparent limb of that near body, ``factors.near_body``) and the
altimeter's height (``altitude``, ``factors.altimeter``)."""

from __future__ import annotations

import numpy as np

from factors.altimeter import altitude_kernel, altitude_residual, make_altitude_factor
from factors.limb import limb_radius_residual, make_limb_radius_factor
from factors.near_body import (limb_radius_body_kernel, make_near_body_limb_factor,
                               near_body_limb_residual)
from fgnav.models.model import MeasurementModel
from fgnav.models.near_body import row_bodies
from fgnav.models.values import position_residual, xyz_rows

__all__ = ["MEASUREMENT_MODELS", "LIMB_RADIUS", "ALTITUDE"]


def _two_columns(name0, name1):
    return lambda log, i: {name0: xyz_rows(log, i)[:, 0], name1: xyz_rows(log, i)[:, 1]}


def _columns_data(name0, name1):
    def data(fam):
        d = np.zeros((len(fam), 3))
        d[:, 0], d[:, 1] = fam.values[name0], fam.values[name1]
        return d, None
    return data


def _limb_values(log, i):
    """``rho_rad``, ``r_limb_m``; where a row names a ``body``, also ``has_body`` (M,) and
    the body's state and flags of :mod:`fgnav.models.near_body` (``p_body_m``,
    ``v_body_mps``, ``light_time``, ``aberration``). Rows without a body: the Earth's limb at
    the frame origin, as before the column (the values, and so the numbers, unchanged)."""
    out = _two_columns("rho_rad", "r_limb_m")(log, i)
    extra = log.extra or {}
    if "body" in extra and np.any(np.isfinite(np.asarray(extra["body"], dtype=float)[i])):
        out.update(row_bodies(log, i))
        out["has_body"] = np.isfinite(out["body"])
        out["light_time"] = out["has_body"].copy()
        out["aberration"] = out["has_body"].copy()
    return out


_earth_limb = position_residual(lambda r, fam: limb_radius_residual(r, fam.values["rho_rad"],
                                                                    fam.values["r_limb_m"]))


def _limb_residual(fam, v):
    has = fam.values.get("has_body")
    if has is None:
        return _earth_limb(fam, v)
    e, H = np.zeros((len(fam), 1)), np.zeros((len(fam), 1, 6))
    plain = np.flatnonzero(~has)
    if len(plain):
        e[plain], H[plain, :, :3] = limb_radius_residual(
            v["orbit"][plain, :3], fam.values["rho_rad"][plain], fam.values["r_limb_m"][plain])
    val = fam.values
    for lt in (False, True):
        for ab in (False, True):
            i = np.flatnonzero(has & (val["light_time"] == lt) & (val["aberration"] == ab))
            if len(i):
                e[i], H[i] = near_body_limb_residual(
                    v["orbit"][i], val["rho_rad"][i], val["r_limb_m"][i], val["p_body_m"][i],
                    val["v_body_mps"][i], light_time=lt, aberration=ab)
    return e, {"orbit": H}


def _limb_factor(fam, j, keys, noise):
    val = fam.values
    if "has_body" in val and val["has_body"][j]:
        return make_near_body_limb_factor(
            keys["orbit"], val["rho_rad"][j], val["r_limb_m"][j], val["p_body_m"][j],
            val["v_body_mps"][j], noise, light_time=bool(val["light_time"][j]),
            aberration=bool(val["aberration"][j]))
    return make_limb_radius_factor(keys["orbit"], val["rho_rad"][j], val["r_limb_m"][j], noise)


def _limb_data(fam):
    """Packed rows of :func:`factors.near_body.limb_radius_body_kernel`: ``(rho, R, 0)`` as
    before without a body; with bodies ``(rho, R, light time, aberration, has body)`` and
    ``B = (p_body, v_body)``."""
    val = fam.values
    if "has_body" not in val:
        return _columns_data("rho_rad", "r_limb_m")(fam)
    d = np.column_stack([val["rho_rad"], val["r_limb_m"], val["light_time"], val["aberration"],
                         val["has_body"]]).astype(float)
    return d, np.stack([val["p_body_m"], val["v_body_mps"]], axis=1)


def _limb_range(fam):
    """|r| from the Earth's limb rows (NaN for a named body's: its distance is not |r|)."""
    r = fam.values["r_limb_m"] / np.sin(fam.values["rho_rad"])
    return np.where(fam.values["has_body"], np.nan, r) if "has_body" in fam.values else r


LIMB_RADIUS = MeasurementModel(
    kind="limb_radius", dim=1, unit="rad", observes_orbit=True,
    summary="angular radius of the limb sphere (rad) and its radius (m); body: the near body's",
    values=_limb_values, residual=_limb_residual, factor=_limb_factor,
    numba_kernel=limb_radius_body_kernel, numba_data=_limb_data, range_m=_limb_range)

ALTITUDE = MeasurementModel(
    kind="altitude", dim=1, unit="m", observes_orbit=True,
    summary="height above a sphere (m) and the sphere's radius (m)",
    values=_two_columns("h_m", "r_ref_m"),
    residual=position_residual(lambda r, fam: altitude_residual(r, fam.values["h_m"],
                                                              fam.values["r_ref_m"])),
    factor=lambda fam, j, keys, noise: make_altitude_factor(
        keys["orbit"], fam.values["h_m"][j], fam.values["r_ref_m"][j], noise),
    numba_kernel=altitude_kernel, numba_data=_columns_data("h_m", "r_ref_m"),
    range_m=lambda fam: fam.values["h_m"] + fam.values["r_ref_m"])

MEASUREMENT_MODELS = (LIMB_RADIUS, ALTITUDE)
"""This module's measurement models (assembled by :mod:`fgnav.models.registry`)."""
