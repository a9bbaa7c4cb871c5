"""Starlight refraction (``refraction``, Li et al. 2017; ``factors.refraction``) and the
atmosphere model's tangent-height bias variable."""

from __future__ import annotations

import numpy as np

from factors.aberration import apparent_direction, earth_velocity_bcrs_mps
from factors.refraction import (make_refraction_bias_factor, make_refraction_factor,
                                refraction_residual, refraction_sigma_m)
from fgnav.constants import R_EARTH_M
from fgnav.models.model import MeasurementModel
from fgnav.models.values import xyz_rows
from fgnav.models.variables import Variable
from fgnav.time import j2000_seconds

__all__ = ["MEASUREMENT_MODELS", "REFRACTION_BIAS", "REFRACTION", "refraction_ray_eci"]


REFRACTION_BIAS = Variable(
    "refraction_bias", "b", 1, "m", components=("refraction_bias_m",),
    psd=1.0, prior_sigma=1000.0,
    description="bias of the atmosphere model's tangent height h(gamma), m (random walk)")
"""The refraction model's tangent-height error shared by every star at an epoch: a random
walk of spectral density 1 m^2/s (60 m in an hour), prior 1 km (see docs/refraction-bias.md)."""


def _refraction_values(log, i):
    extra = log.extra
    sig_model = extra.get("sigma_model_m", np.full(len(log.kind), np.nan))[i]
    t = float(j2000_seconds(log.epoch0)) + np.asarray(log.t_s, dtype=float)[i]
    return {"s_eci": xyz_rows(log, i), "gamma_rad": extra["gamma"][i],
            "sigma_model_m": np.nan_to_num(sig_model, nan=0.0),
            "v_earth_bcrs_mps": earth_velocity_bcrs_mps(t), "aberration": np.ones(len(t), bool)}


def refraction_ray_eci(fam, rows=slice(None)):
    """The direction of the star's ray before bending, in the geocentric frame: the
    catalogue direction aberrated by the Earth's barycentric velocity (the geocentric
    apparent place, ~20 arcsec; ``factors.aberration``). The spacecraft's own velocity
    changes how the camera sees the ray, not where it passes the atmosphere, and aberrates
    the refracted and the unrefracted star alike, leaving gamma as measured (to
    ``beta gamma`` < 0.1 arcsec); rows with ``aberration`` off keep the catalogue direction.
    ``rows``: a slice or index array of the family's rows (default all)."""
    s = fam.values["s_eci"][rows]
    on = fam.values["aberration"][rows]
    s_app, _ = apparent_direction(s, fam.values["v_earth_bcrs_mps"][rows])
    return np.where(on[:, None], s_app, s)


def _refraction_sigma(fam, x_orbit=None):
    """Tangent-height 1-sigma (m): angle error and model error combined
    (``factors.refraction.refraction_sigma_m``). The residual depends on the measured gamma
    through both terms, ``de/dgamma = |r.s| sec^2(gamma) + H/gamma``: with the orbit states
    ``x_orbit`` (M, 6) the line-of-sight range ``|r.s|`` is taken there (+13 % on the angle
    term in LEO); without (no state at hand) Li et al. 2017's ``H/gamma`` alone."""
    los = 0.0
    if x_orbit is not None:
        los = np.abs(np.sum(np.asarray(x_orbit)[:, :3] * fam.values["s_eci"], axis=1))
    return refraction_sigma_m(fam.values["gamma_rad"], fam.sigma, fam.values["sigma_model_m"],
                              los_range_m=los)


def _refraction_residual(fam, v):
    M = len(fam)
    args = (v["orbit"][:, :3], refraction_ray_eci(fam), fam.values["gamma_rad"],
            np.full(M, R_EARTH_M), np.zeros(M))
    if REFRACTION_BIAS.name not in v:
        e, H_r = refraction_residual(*args)
        return e, {"position": H_r}
    e, H_r, H_b = refraction_residual(*args, bias_m=v[REFRACTION_BIAS.name][:, 0])
    return e, {"position": H_r, REFRACTION_BIAS.name: H_b}


def _refraction_factor(fam, j, keys, noise):
    s, g = refraction_ray_eci(fam, slice(j, j + 1))[0], fam.values["gamma_rad"][j]
    if REFRACTION_BIAS.name in keys:
        return make_refraction_bias_factor(keys["orbit"], keys[REFRACTION_BIAS.name], s, g, noise,
                                           R_EARTH_M, 0.0)
    return make_refraction_factor(keys["orbit"], s, g, noise, R_EARTH_M, 0.0)


REFRACTION = MeasurementModel(
    kind="refraction", dim=1, unit="m", observes_orbit=True,
    summary="refracted star: catalogue unit vector (EME2000), refraction angle gamma (rad)",
    values=_refraction_values, residual=_refraction_residual, factor=_refraction_factor,
    sigma=_refraction_sigma, optional_variables=(REFRACTION_BIAS,),
   
    eci_ray=True)

MEASUREMENT_MODELS = (REFRACTION,)
"""This module's measurement models (assembled by :mod:`fgnav.models.registry`)."""
