"""Limb angular radius (apparent Earth half-angle).

``sin(rho) = R_limb / |r|``: the angular radius of the limb sphere seen from the spacecraft
gives the range to the Earth centre (Wu et al.: ``r = R / sin(rho)``, R = 6,375 km for the UV
limb, ``factors.constants.R_LIMB_UV_M``). Its information on ``|r|`` falls with altitude.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from factors.interpret import run
from factors.jit import njit

from factors.adapters import custom_factor, pad_position_jacobian, vector_state
from factors.errors import ModelDomainError

__all__ = ["limb_radius_residual", "make_limb_radius_factor", "limb_radius_kernel"]


@njit(cache=True)
def limb_radius_kernel(x, data, B, e, H):
    """One measurement (the one definition; the numpy residual and the compiled EKF call it).

    x (>= 3,): position first, m; ``data[0]`` the measured angular radius rho (rad),
    ``data[1]`` the limb radius R_limb (m); B unused. Writes ``e[0] = arcsin(R_limb/|r|) - rho``
    and ``H[0, :3] = -R_limb / (|r| sqrt(|r|^2 - R_limb^2)) r^T/|r|`` (other columns 0).
    Returns 1 (rows written), or -1 if ``|r| <= R_limb`` (no limb).
    """
    n = math.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2])
    rl = data[1]
    if not n > rl:
        return -1
    e[0] = math.asin(rl / n) - data[0]
    g = -rl / (n * math.sqrt(n * n - rl * rl)) / n
    for j in range(H.shape[1]):
        H[0, j] = 0.0
    for j in range(3):
        H[0, j] = g * x[j]
    return 1


@njit(cache=True)
def _limb_many(r, rho, rl, e, H):
    data = np.empty(2)
    B = np.empty((2, 3))
    for i in range(r.shape[0]):
        data[0] = rho[i]
        data[1] = rl[i]
        if limb_radius_kernel(r[i], data, B, e[i], H[i]) < 0:
            return i
    return -1


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
    r = np.ascontiguousarray(np.asarray(r_eci_m, dtype=float).reshape(-1, 3))
    M = len(r)
    rl = np.ascontiguousarray(np.broadcast_to(np.asarray(r_limb_m, dtype=float), (M,)))
    rho = np.ascontiguousarray(np.broadcast_to(np.asarray(rho_meas_rad, dtype=float), (M,)))
    e = np.empty((M, 1))
    H_r = np.empty((M, 1, 3))
    k = run(_limb_many, r, rho, rl, e, H_r)
    if k >= 0:
        n = float(np.linalg.norm(r[k]))
        raise ModelDomainError(f"limb radius residual: |r| = {n:.1f} m is not above the limb "
                               f"radius {rl[k]:.1f} m (epoch index {k})")
    return e, H_r


def _limb(key_x, rho, r_limb, values):
    x = vector_state(values, key_x)
    e, H_r = limb_radius_residual(x[None, :3], rho, r_limb)
    return e[0], [pad_position_jacobian(H_r[0], x.shape[0])]


def make_limb_radius_factor(key_x, rho_meas_rad, r_limb_m, sigma_rad):
    """CustomFactor on a state key ``[r; v]``: error (1,), Jacobian (1, 6); sigma in rad."""
    rho = np.array([float(rho_meas_rad)])
    rl = np.array([float(r_limb_m)])
    return custom_factor([key_x], sigma_rad, functools.partial(_limb, key_x, rho, rl), dim=1)
