"""Starlight refraction: indirect horizon sensing (Li et al. 2017).

Li et al. 2017 (CN104236546B, claim 1, step 4): the refraction angle of a star whose light
grazes the atmosphere at tangent height h is ``gamma = 2350.1074 exp(-0.10326788 h)``
(arcsec, h in km); the simulated measurement adds a refraction-angle error (uniform in the
sensor's accuracy band) to gamma, inverts to a tangent height h', then adds the
atmosphere-model error directly to h' to get h''. The two error sources are kept apart
here (:func:`refraction_sigma_m`) so a study can switch each off; a uniform error on
``[-D, D]`` has ``sigma = D / sqrt(3)``.

Measurement geometry (the classic model, Ning & Fang): with star direction ``s`` (unit,
ECI, from the spacecraft towards the star: the direction of the ray before bending, i.e. the
catalogue direction aberrated by the Earth's barycentric velocity, the geocentric apparent
place of ``factors.aberration``, ~20 arcsec off the catalogue's; the caller applies it) and
spacecraft position ``r``, the apparent tangent height is

    h_a = sqrt(|r|^2 - (r.s)^2) + |r.s| tan(gamma) - R_e - a,

(``a``: a small Earth-oblateness correction supplied by the caller). The measured gamma
gives the tangent height through the inverse atmosphere model, ``h_m = h(gamma)``, and the
residual is ``e = h_a - h_m`` (metres): each refracted star constrains the position to a
surface. For a star towards the limb ``r.s < 0``.

Atmosphere-model bias (optional): the real atmosphere differs from the model by a slowly
varying shift of the tangent height, ``gamma_real(h) = gamma_model(h + b)`` (a density
error of a few per cent moves the refraction profile by a few hundred metres). The inverse
model then returns ``h(gamma) = h_true + b``, so the residual with the bias as a variable is
``e = h_a - (h(gamma) - b)``, ``de/db = +1``: ``b`` estimates the model's error on the
tangent height (the simulator's ``dh`` of :mod:`fgnav.simulate.refraction_sim`, same sign).

Models (``model=``), both of the form ``gamma(h) = gamma_ref exp(-(h - h_ref)/H)``:

- ``"exponential-seed004"``: Li et al. 2017's fit, ``gamma_ref`` = 2350.1074 arcsec at
  ``h_ref = 0``, ``H = 1/0.10326788 km = 9.6835 km``.
- ``"exponential-density"``: from the physics of an exponential atmosphere: the bending
  of a ray with tangent radius ``R_t`` is ``gamma = (n(h) - 1) sqrt(2 pi R_t / H_rho)`` with
  the Gladstone–Dale relation ``n - 1 = k rho``, ``k = 2.25e-4 m^3/kg`` (air, ~0.7 um);
  ``rho(h) = rho_ref exp(-(h - h_ref)/H_rho)`` fitted (log-linear least squares) to the
  U.S. Standard Atmosphere 1976 densities at 20, 25, ..., 50 km, ``h_ref = 30 km``
  (``H_rho`` ~ 6.69 km). ``R_t`` is held at ``R_e + h_ref`` (its variation over the band
  changes gamma by < 0.25 %), which keeps the model exponential and its inverse exact.
  The two models differ by up to a factor 4 at 50 km: the choice of model *is* the
  atmosphere-model error Li et al. 2017 describe.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from factors.adapters import custom_factor, pad_position_jacobian, vector_state
from factors.constants import ARCSEC, R_EARTH_M

__all__ = [
    "REFRACTION_VALID_BAND_M", "ExponentialRefractionModel", "REFRACTION_MODELS",
    "refraction_model", "refraction_angle_rad", "tangent_height_from_refraction_m",
    "in_valid_band", "apparent_tangent_height_m", "refraction_residual",
    "refraction_sigma_m", "make_refraction_factor", "make_refraction_bias_factor",
]

REFRACTION_VALID_BAND_M = (20e3, 50e3)
"""Tangent heights (m) where the refraction models are valid (Li et al. 2017: ~20–50 km)."""

GLADSTONE_DALE_M3_KG = 2.25e-4
"""Gladstone–Dale constant of air at ~0.7 um, m^3/kg: n - 1 = k rho."""

US76_DENSITY_KG_M3 = {
    20e3: 8.8910e-2, 25e3: 4.0084e-2, 30e3: 1.8410e-2, 35e3: 8.4634e-3,
    40e3: 3.9957e-3, 45e3: 1.9663e-3, 50e3: 1.0269e-3,
}
"""U.S. Standard Atmosphere 1976 mass density (kg/m^3) at geometric altitude (m)."""


@dataclasses.dataclass(frozen=True)
class ExponentialRefractionModel:
    """``gamma(h) = gamma_ref_rad * exp(-(h_m - h_ref_m) / scale_height_m)``."""

    name: str
    gamma_ref_rad: float
    h_ref_m: float
    scale_height_m: float

    def gamma_rad(self, h_m):
        """Refraction angle (rad) at tangent height ``h_m`` (m)."""
        return self.gamma_ref_rad * np.exp(-(np.asarray(h_m, dtype=float) - self.h_ref_m)
                                           / self.scale_height_m)

    def height_m(self, gamma_rad):
        """Inverse: tangent height (m) from refraction angle (rad, > 0)."""
        g = np.asarray(gamma_rad, dtype=float)
        if np.any(~(g > 0)):
            raise ValueError("refraction angle must be positive (rad)")
        return self.h_ref_m - self.scale_height_m * np.log(g / self.gamma_ref_rad)

    def dheight_dgamma_m_per_rad(self, gamma_rad):
        """``dh/dgamma = -H / gamma`` (m/rad)."""
        return -self.scale_height_m / np.asarray(gamma_rad, dtype=float)


def _density_model():
    h = np.array(sorted(US76_DENSITY_KG_M3))
    rho = np.array([US76_DENSITY_KG_M3[k] for k in h])
    h_ref = 30e3
    slope, intercept = np.polyfit(h - h_ref, np.log(rho), 1)
    H = -1.0 / slope
    rho_ref = np.exp(intercept)
    gamma_ref = GLADSTONE_DALE_M3_KG * rho_ref * np.sqrt(2.0 * np.pi * (R_EARTH_M + h_ref) / H)
    return ExponentialRefractionModel("exponential-density", float(gamma_ref), h_ref, float(H))


REFRACTION_MODELS = {
    "exponential-seed004": ExponentialRefractionModel(
        "exponential-seed004", 2350.1074 * ARCSEC, 0.0, 1e3 / 0.10326788),
    "exponential-density": _density_model(),
}
"""The named refraction models (see the module docstring)."""


def refraction_model(model="exponential-seed004"):
    """The :class:`ExponentialRefractionModel` named ``model`` (or ``model`` itself)."""
    if isinstance(model, ExponentialRefractionModel):
        return model
    try:
        return REFRACTION_MODELS[model]
    except KeyError:
        raise ValueError(f"unknown refraction model {model!r}; expected one of "
                         f"{sorted(REFRACTION_MODELS)}") from None


def refraction_angle_rad(h_m, model="exponential-seed004"):
    """Refraction angle (rad) of starlight with tangent height ``h_m`` (m).

    Li et al. 2017: ``gamma = 2350.1074 exp(-0.10326788 h_km)`` arcsec. Valid in
    :data:`REFRACTION_VALID_BAND_M`; evaluated (not clipped) outside it.
    """
    return refraction_model(model).gamma_rad(h_m)


def tangent_height_from_refraction_m(gamma_rad, model="exponential-seed004"):
    """Inverse model: tangent height (m) from refraction angle (rad, > 0)."""
    return refraction_model(model).height_m(gamma_rad)


def in_valid_band(h_m):
    """Boolean mask: tangent height within :data:`REFRACTION_VALID_BAND_M`."""
    h = np.asarray(h_m, dtype=float)
    return (h >= REFRACTION_VALID_BAND_M[0]) & (h <= REFRACTION_VALID_BAND_M[1])


def apparent_tangent_height_m(r_eci_m, s_eci, gamma_rad, r_earth_m=R_EARTH_M, a_m=0.0):
    """Apparent tangent height from geometry and its position Jacobian.

    ``h_a = sqrt(|r|^2 - p^2) + |p| tan(gamma) - R_e - a`` with ``p = r.s``;
    ``dh_a/dr = (r - p s)^T / sqrt(|r|^2 - p^2) + sign(p) tan(gamma) s^T``.

    Parameters
    ----------
    r_eci_m : (N, 3) m; s_eci : (N, 3) unit star direction (normalized internally), ECI;
    gamma_rad : (N,) refraction angle, rad; r_earth_m, a_m : scalars or (N,), m.

    Returns
    -------
    h_a : (N,) m; H_r : (N, 3) dimensionless.
    """
    r = np.asarray(r_eci_m, dtype=float)
    s = np.asarray(s_eci, dtype=float)
    s = s / np.linalg.norm(s, axis=-1, keepdims=True)
    p = np.sum(r * s, axis=-1)
    q = np.sqrt(np.maximum(np.sum(r * r, axis=-1) - p * p, 0.0))
    t = np.tan(np.asarray(gamma_rad, dtype=float))
    h_a = q + np.abs(p) * t - np.asarray(r_earth_m, dtype=float) - np.asarray(a_m, dtype=float)
    H_r = (r - p[:, None] * s) / q[:, None] + (np.sign(p) * t)[:, None] * s
    return h_a, H_r


def refraction_residual(r_eci_m, s_eci, gamma_meas_rad, r_earth_m=R_EARTH_M, a_m=0.0,
                        model="exponential-seed004", bias_m=None):
    """Starlight-refraction residual (metres of tangent height).

    ``e = h_a(r; s, gamma_meas) - h(gamma_meas)``, with ``h_a`` from
    :func:`apparent_tangent_height_m` and ``h(.)`` the inverse atmosphere model; ``gamma`` is
    the measurement, so only ``r`` is differentiated:
    ``H_r = (r - p s)^T / sqrt(|r|^2 - p^2) + sign(p) tan(gamma) s^T``, ``p = r.s``.

    With the atmosphere-model bias ``b`` (``bias_m``, the height shift of the real atmosphere
    against the model, see the module docstring) the residual is
    ``e = h_a - (h(gamma_meas) - b)`` and its Jacobian ``H_b = de/db = 1``.

    Parameters
    ----------
    r_eci_m : (N, 3) m; s_eci : (N, 3) catalogue star direction (ECI, unit);
    gamma_meas_rad : (N,) measured refraction angle, rad; r_earth_m, a_m : m;
    model : refraction model name (see module docstring);
    bias_m : None (no bias variable), or a scalar or (N,) tangent-height bias ``b``, m.

    Returns
    -------
    e : (N, 1) m; H_r : (N, 1, 3); and, only when ``bias_m`` is given, H_b : (N, 1, 1).
    """
    g = np.asarray(gamma_meas_rad, dtype=float).reshape(-1)
    h_a, H_r = apparent_tangent_height_m(r_eci_m, s_eci, g, r_earth_m, a_m)
    e = h_a - tangent_height_from_refraction_m(g, model)
    if bias_m is None:
        return e[:, None], H_r[:, None, :]
    e = e + np.broadcast_to(np.asarray(bias_m, dtype=float).reshape(-1), e.shape)
    return e[:, None], H_r[:, None, :], np.ones((e.shape[0], 1, 1))


def refraction_sigma_m(gamma_rad, sigma_gamma_rad, sigma_model_m, model="exponential-seed004",
                       los_range_m=0.0):
    """Standard deviation (m) of the refraction residual from its two error sources.

    ``sigma = sqrt((de/dgamma * sigma_gamma)^2 + sigma_model^2)``, Li et al. 2017 step 4: the
    refraction-angle measurement error (``sigma_gamma_rad``, 1-sigma; a uniform error on
    ``[-D, D]`` has ``D/sqrt(3)``) mapped through ``|dh/dgamma| = H/gamma`` of the inverse
    model, and the atmosphere-model error on the tangent height (``sigma_model_m``). Either
    may be 0 (but not both).

    ``los_range_m`` (optional, default 0 = Li et al. 2017's treatment): ``|r.s|``, to include the
    geometric term of the residual, ``d h_a/d gamma = |r.s| sec^2(gamma)``, so that
    ``de/dgamma = |r.s| sec^2(gamma) + H/gamma`` (about +13 % from 500 km altitude at a
    30 km tangent height).
    """
    m = refraction_model(model)
    g = np.asarray(gamma_rad, dtype=float)
    dedg = np.asarray(los_range_m, dtype=float) / np.cos(g) ** 2 - m.dheight_dgamma_m_per_rad(g)
    return np.sqrt((dedg * np.asarray(sigma_gamma_rad, dtype=float)) ** 2
                   + np.asarray(sigma_model_m, dtype=float) ** 2)


def _refraction(key_x, s, gamma, r_earth_m, a_m, model, values):
    x = vector_state(values, key_x)
    e, H_r = refraction_residual(x[None, :3], s, gamma, r_earth_m, a_m, model)
    return e[0], [pad_position_jacobian(H_r[0], x.shape[0])]


def make_refraction_factor(key_x, s_eci, gamma_meas_rad, sigma_m, r_earth_m=R_EARTH_M, a_m=0.0,
                           model="exponential-seed004"):
    """CustomFactor on a state key ``[r; v]``: error (1,) m, Jacobian (1, 6).

    ``sigma_m`` from :func:`refraction_sigma_m`.
    """
    s = np.asarray(s_eci, dtype=float).reshape(1, 3)
    g = np.array([float(gamma_meas_rad)])
    refraction_model(model)  # validate the name now, not inside the optimizer
    return custom_factor([key_x], sigma_m,
                         functools.partial(_refraction, key_x, s, g, float(r_earth_m),
                                           float(a_m), model), dim=1)


def _refraction_bias(key_x, key_b, s, gamma, r_earth_m, a_m, model, values):
    x = vector_state(values, key_x)
    b = vector_state(values, key_b)
    e, H_r, H_b = refraction_residual(x[None, :3], s, gamma, r_earth_m, a_m, model, b[0])
    return e[0], [pad_position_jacobian(H_r[0], x.shape[0]), H_b[0]]


def make_refraction_bias_factor(key_x, key_b, s_eci, gamma_meas_rad, sigma_m, r_earth_m=R_EARTH_M,
                                a_m=0.0, model="exponential-seed004"):
    """CustomFactor on a state key ``[r; v]`` and a Vector1 bias key ``[b]`` (m): error (1,) m
    ``h_a - (h(gamma) - b)``, Jacobians (1, 6) and (1, 1) (:func:`refraction_residual` with
    ``bias_m``).

    ``sigma_m`` from :func:`refraction_sigma_m` (its ``sigma_model_m`` then the white,
    star-to-star part of the model error only; the bias is the variable).
    """
    s = np.asarray(s_eci, dtype=float).reshape(1, 3)
    g = np.array([float(gamma_meas_rad)])
    refraction_model(model)  # validate the name now, not inside the optimizer
    return custom_factor([key_x, key_b], sigma_m,
                         functools.partial(_refraction_bias, key_x, key_b, s, g,
                                           float(r_earth_m), float(a_m), model), dim=1)
