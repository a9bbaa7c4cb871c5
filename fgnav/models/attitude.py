"""The attitude: its graph variable (``R_eci_from_body`` on SO(3)), the ``attitude`` rows (a
solved attitude, a prior on the variable; ``factors.attitude``) and the body rate of the
constant-rate attitude motion."""

from __future__ import annotations

from factors.attitude import attitude_residual, make_attitude_prior_factor
from factors.geometry import so3_exp, so3_log
from fgnav.io.log_csv import attitude_covariances
from fgnav.models.model import MeasurementModel
from fgnav.models.values import xyz_rows
from fgnav.models.variables import ConstantRate, Variable

__all__ = ["MEASUREMENT_MODELS", "ATTITUDE_VARIABLE", "ATTITUDE", "ATTITUDE_RATE"]


# Without --estimate attitude, attitude rows rotate the body-frame directions into ECI before
# the graph (their variances added); with it, they are priors on a Rot3 variable per epoch and
# the body-frame rows are factors on (orbit, attitude).

ATTITUDE_VARIABLE = Variable(
    "attitude", "a", 3, "rad", manifold="rot3", components=("att_x", "att_y", "att_z"),
    psd=1e-4, prior_sigma=10.0,
    description="R_eci_from_body as a rotation vector, rad (random walk on SO(3))")
"""The spacecraft attitude per epoch: between epochs a random walk on SO(3) of spectral
density 1e-4 rad^2/s (0.03 rad per 10 s: an Earth-pointing LEO body turns 0.011 rad in 10 s
in ECI); no prior worth the name (10 rad): the attitude rows give it."""


def _attitude_residual(fam, v):
    e, H_R = attitude_residual(v[ATTITUDE_VARIABLE.name], fam.values["R_eci_from_body"])
    return e, {ATTITUDE_VARIABLE.name: H_R}


ATTITUDE = MeasurementModel(
    kind="attitude", dim=3, unit="rad",
    summary="rotation vector of R_eci_from_body (a solved attitude)",
    values=lambda log, i: {"R_eci_from_body": so3_exp(xyz_rows(log, i)),
                           "cov_rad2": attitude_covariances(log, i)},
    residual=_attitude_residual, variables=(), optional_variables=(ATTITUDE_VARIABLE,),
    requires=ATTITUDE_VARIABLE.name, covariance=lambda fam: fam.values.get("cov_rad2"),
    initial=lambda fam: {ATTITUDE_VARIABLE.name: so3_log(fam.values["R_eci_from_body"])},
    factor=lambda fam, j, keys, noise: make_attitude_prior_factor(
        keys[ATTITUDE_VARIABLE.name], fam.values["R_eci_from_body"][j], noise))


# ---- attitude motion without a gyro ---------------------------------------------------------

ATTITUDE_RATE = Variable(
    "attitude_rate", "w", 3, "rad/s", components=("rate_x", "rate_y", "rate_z"),
    psd=1e-10, prior_sigma=0.1, process=ConstantRate(turns="attitude"),
    description="body angular rate (body frame) that turns the attitude, rad/s (constant-rate "
                "motion: white angular acceleration of psd 1e-10 rad^2/s^3)")
"""The body rate of the constant-rate attitude motion (``fgnav smooth --attitude-motion
constant-rate``, ``factors.attitude_motion``): between epochs ``R_k = R_{k-1} Exp(w_{k-1} dt)``
with the rate a random walk driven by white angular acceleration of spectral density ``psd``
= 1e-10 rad^2/s^3 (the rate wanders 1e-5 rad/s in a second, 6e-4 rad/s in an hour; the
attitude 6e-6 rad from a constant-rate turn in a second); it replaces the attitude's random
walk. Prior 0.1 rad/s (6 deg/s) at the first epoch. No model's rows touch it: it is a
variable of the attitude's process model (:mod:`fgnav.solvers.process`)."""

MEASUREMENT_MODELS = (ATTITUDE,)
"""This module's measurement models (assembled by :mod:`fgnav.models.registry`)."""
