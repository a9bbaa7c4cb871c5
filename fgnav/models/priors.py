"""A priori position and velocity rows (``prior_position``, ``prior_velocity``): state priors,
EME2000 (``factors.prior``)."""

from __future__ import annotations

from factors.prior import (POSITION, VELOCITY, make_state_prior_factor, prior_position_kernel,
                           prior_velocity_kernel, state_prior_residual)
from fgnav.models.model import MeasurementModel
from fgnav.models.values import xyz_rows

__all__ = ["MEASUREMENT_MODELS", "PRIOR_POSITION", "PRIOR_VELOCITY"]


def _prior(kind, sl, kernel, what):
    def res(fam, v):
        e, H = state_prior_residual(v["orbit"], fam.values["xyz"], sl)
        return e, {"orbit": H}

    def data(fam):
        return fam.values["xyz"], None

    return MeasurementModel(
        kind=kind, dim=3, unit="m" if sl == POSITION else "m/s", prior=True,
        summary=f"a priori {what}, EME2000",
        values=lambda log, i: {"xyz": xyz_rows(log, i)}, residual=res,
        factor=lambda fam, j, keys, noise: make_state_prior_factor(keys["orbit"], sl,
                                                                   fam.values["xyz"][j], noise),
        numba_kernel=kernel, numba_data=data)


PRIOR_POSITION = _prior("prior_position", POSITION, prior_position_kernel, "position, m")
PRIOR_VELOCITY = _prior("prior_velocity", VELOCITY, prior_velocity_kernel, "velocity, m/s")

MEASUREMENT_MODELS = (PRIOR_POSITION, PRIOR_VELOCITY)
"""This module's measurement models (assembled by :mod:`fgnav.models.registry`)."""
