"""Range-like rows: the limb's angular radius (``limb_radius``, ``factors.limb``) and the
altimeter's height (``altitude``, ``factors.altimeter``)."""

from __future__ import annotations

import numpy as np

from factors.altimeter import altitude_kernel, altitude_residual, make_altitude_factor
from factors.limb import limb_radius_kernel, limb_radius_residual, make_limb_radius_factor
from fgnav.models.model import MeasurementModel
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


LIMB_RADIUS = MeasurementModel(
    kind="limb_radius", dim=1, unit="rad", observes_orbit=True,
    summary="angular radius of the limb sphere (rad) and its radius (m)",
    values=_two_columns("rho_rad", "r_limb_m"),
    residual=position_residual(lambda r, fam: limb_radius_residual(r, fam.values["rho_rad"],
                                                                 fam.values["r_limb_m"])),
    factor=lambda fam, j, keys, noise: make_limb_radius_factor(
        keys["orbit"], fam.values["rho_rad"][j], fam.values["r_limb_m"][j], noise),
    numba_kernel=limb_radius_kernel, numba_data=_columns_data("rho_rad", "r_limb_m"),
    range_m=lambda fam: fam.values["r_limb_m"] / np.sin(fam.values["rho_rad"]))

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
