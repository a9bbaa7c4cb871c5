"""Limb angular radius (apparent Earth half-angle).

``sin(rho) = R_limb / |r|``: the angular radius of the limb sphere seen from the spacecraft
gives the range to the Earth centre (Wu et al.: ``r = R / sin(rho)``, R = 6,375 km for the UV
limb, ``factors.constants.R_LIMB_UV_M``). Its information on ``|r|`` falls with altitude.
"""

from __future__ import annotations

import functools

import numpy as np

from factors.adapters import custom_factor, pad_position_jacobian, vector_state
from factors.errors import ModelDomainError

__all__ = ["limb_radius_residual", "make_limb_radius_factor"]


def limb_radius_residual(r_eci_m, rho_meas_rad, r_limb_m):
    """Limb angular-radius residual.

    ``rho_pred = arcsin(R_limb/|r|)``, ``e = rho_pred - rho_meas``;
    ``d rho/d r = -R_limb / (|r| sqrt(|r|^2 - R_limb^2)) * r^T/|r|``.

    Parameters
    ----------
    r_eci_m : (N, 3) spacecraft position, ECI, m.
    rho_meas_rad : (N,) measured angular radius, rad.
    r_limb_m : (N,) (or scalar) radius of the limb sphere, m.

    Returns
    -------
    e : (N, 1) rad; H_r : (N, 1, 3) rad/m.

    Raises
    ------
    ModelDomainError (a ValueError) if ``|r| <= r_limb`` (inside the limb sphere: no limb).
    """
    r = np.asarray(r_eci_m, dtype=float)
    n = np.linalg.norm(r, axis=-1)
    rl = np.broadcast_to(np.asarray(r_limb_m, dtype=float), n.shape)
    if np.any(n <= rl):
        k = int(np.argmax(n <= rl))
        raise ModelDomainError(f"limb radius residual: |r| = {n[k]:.1f} m is not above the limb "
                         f"radius {rl[k]:.1f} m (epoch index {k})")
    rho = np.arcsin(rl / n)
    e = (rho - np.asarray(rho_meas_rad, dtype=float))[:, None]
    g = -rl / (n * np.sqrt(n * n - rl * rl))
    H_r = (g / n)[:, None] * r
    return e, H_r[:, None, :]


def _limb(key_x, rho, r_limb, values):
    x = vector_state(values, key_x)
    e, H_r = limb_radius_residual(x[None, :3], rho, r_limb)
    return e[0], [pad_position_jacobian(H_r[0], x.shape[0])]


def make_limb_radius_factor(key_x, rho_meas_rad, r_limb_m, sigma_rad):
    """CustomFactor on a state key ``[r; v]``: error (1,), Jacobian (1, 6); sigma in rad."""
    rho = np.array([float(rho_meas_rad)])
    rl = np.array([float(r_limb_m)])
    return custom_factor([key_x], sigma_rad, functools.partial(_limb, key_x, rho, rl), dim=1)
