"""The geocentric direction: the unit vector from the spacecraft to the Earth's centre in ECI
(``earth_direction``, ``factors.direction``)."""

from __future__ import annotations

from factors.direction import (earth_direction_residual, earth_direction_row_kernel,
                               make_earth_direction_factor)
from factors.geometry import tangent_basis
from fgnav.models.model import MeasurementModel
from fgnav.models.values import position_residual, xyz_rows


__all__ = ["MEASUREMENT_MODELS", "EARTH_DIRECTION"]


EARTH_DIRECTION = MeasurementModel(
    kind="earth_direction", dim=2, unit="rad", observes_orbit=True,
    summary="unit vector spacecraft -> Earth centre, EME2000",
    values=lambda log, i: {"u_eci": xyz_rows(log, i)},
    residual=position_residual(lambda r, fam: earth_direction_residual(r, fam.values["u_eci"])),
    factor=lambda fam, j, keys, noise: make_earth_direction_factor(keys["orbit"],
                                                                   fam.values["u_eci"][j], noise),
    numba_kernel=earth_direction_row_kernel,
    numba_data=lambda fam: (fam.values["u_eci"], tangent_basis(fam.values["u_eci"])),
    eci_ray=True)

MEASUREMENT_MODELS = (EARTH_DIRECTION,)
"""This module's measurement models (assembled by :mod:`fgnav.models.registry`)."""
