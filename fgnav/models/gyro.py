"""The rate gyro (``gyro``: a between row of two epochs' attitudes, ``factors.gyro``) and its
bias variable."""

from __future__ import annotations

import numpy as np

from factors.gyro import gyro_residual, make_gyro_factor, make_gyro_factor_without_bias
from fgnav.models.attitude import ATTITUDE_VARIABLE
from fgnav.models.model import MeasurementModel
from fgnav.models.values import xyz_rows
from fgnav.models.variables import Variable

__all__ = ["MEASUREMENT_MODELS", "GYRO_BIAS", "GYRO"]


GYRO_BIAS = Variable(
    "gyro_bias", "g", 3, "rad/s", components=("gyro_bias_x", "gyro_bias_y", "gyro_bias_z"),
    psd=1e-14, prior_sigma=1e-3,
    description="rate gyro bias per body axis, rad/s (random walk)")
"""The gyro bias: a random walk of 1e-14 (rad/s)^2/s (bias instability ~0.02 deg/h over an
hour), prior 1e-3 rad/s (200 deg/h: an uncalibrated MEMS gyro) at the first epoch."""


def _gyro_residual(fam, v0, v1, dt):
    bias = v0[GYRO_BIAS.name] if GYRO_BIAS.name in v0 else np.zeros((len(fam), 3))
    e, H0, H1, Hb = gyro_residual(v0[ATTITUDE_VARIABLE.name], v1[ATTITUDE_VARIABLE.name], bias,
                                  fam.values["omega_rad_s"], dt)
    jac0 = {ATTITUDE_VARIABLE.name: H0}
    if GYRO_BIAS.name in v0:
        jac0[GYRO_BIAS.name] = Hb
    return e, jac0, {ATTITUDE_VARIABLE.name: H1}


def _gyro_factor(fam, j, keys0, keys1, noise, dt):
    att = ATTITUDE_VARIABLE.name
    if GYRO_BIAS.name in keys0:
        return make_gyro_factor(keys0[att], keys1[att], keys0[GYRO_BIAS.name],
                                fam.values["omega_rad_s"][j], dt, noise)
    return make_gyro_factor_without_bias(keys0[att], keys1[att], fam.values["omega_rad_s"][j],
                                         dt, noise)


GYRO = MeasurementModel(
    kind="gyro", dim=3, unit="rad",
    summary="body angular rate over the interval since the previous epoch, rad/s",
    values=lambda log, i: {"omega_rad_s": xyz_rows(log, i)},
    residual=_gyro_residual, factor=_gyro_factor, between=True,
    sigma=lambda fam, dt: np.asarray(fam.sigma, dtype=float) * np.abs(dt),
    variables=(), optional_variables=(ATTITUDE_VARIABLE, GYRO_BIAS),
    requires=ATTITUDE_VARIABLE.name)

MEASUREMENT_MODELS = (GYRO,)
"""This module's measurement models (assembled by :mod:`fgnav.models.registry`)."""
