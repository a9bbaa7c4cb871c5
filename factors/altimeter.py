"""Altimeter (the INS/CNS lecture: "satellite altimeter gives the height above the Earth surface H",
1 km 3-sigma; direct fix ``r = -(R_e + H) C_b^i L_we^b``).

Spherical Earth: the predicted altitude is ``h = |r| - r_ref`` with a reference radius
``r_ref`` (R_e = 6,378,137 m in the INS/CNS lecture's direct fix). Oblateness is not modelled: the
WGS-84 ellipsoid's radius falls from R_e at the equator to R_e - 21.4 km at the poles, so for an
altimeter that reports height above the ellipsoid the caller supplies a latitude-dependent
``r_ref`` (it may vary per epoch).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from factors.interpret import run
from factors.jit import njit

from factors.adapters import custom_factor, pad_position_jacobian, vector_state

__all__ = ["altitude_residual", "make_altitude_factor", "altitude_kernel"]


@njit(cache=True)
def altitude_kernel(x, data, B, e, H):
    """One measurement (the one definition; the numpy residual and the compiled EKF call it).

    x (>= 3,): position first, m; ``data[0]`` the measured height h (m), ``data[1]`` the
    reference radius r_ref (m); B unused. Writes ``e[0] = |r| - r_ref - h`` and
    ``H[0, :3] = r^T/|r|`` (other columns 0). Returns 1 (rows written).
    """
    n = math.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2])
    e[0] = n - data[1] - data[0]
    for j in range(H.shape[1]):
        H[0, j] = 0.0
    for j in range(3):
        H[0, j] = x[j] / n
    return 1


@njit(cache=True)
def _altitude_many(r, h, r_ref, e, H):
    data = np.empty(2)
    B = np.empty((2, 3))
    for i in range(r.shape[0]):
        data[0] = h[i]
        data[1] = r_ref[i]
        altitude_kernel(r[i], data, B, e[i], H[i])


def altitude_residual(r_eci_m, h_meas_m, r_ref_m):
    """Altitude residual above a sphere of radius ``r_ref_m``.

    ``e = (|r| - r_ref) - h_meas``, ``H_r = r^T/|r|``.

    Parameters
    ----------
    r_eci_m : (N, 3) position, ECI, m; h_meas_m : (N,) measured altitude, m;
    r_ref_m : (N,) or scalar reference radius, m.

    Returns
    -------
    e : (N, 1) m; H_r : (N, 1, 3) dimensionless.
    """
    r = np.ascontiguousarray(np.asarray(r_eci_m, dtype=float).reshape(-1, 3))
    M = len(r)
    h = np.ascontiguousarray(np.broadcast_to(np.asarray(h_meas_m, dtype=float), (M,)))
    rr = np.ascontiguousarray(np.broadcast_to(np.asarray(r_ref_m, dtype=float), (M,)))
    e = np.empty((M, 1))
    H_r = np.empty((M, 1, 3))
    run(_altitude_many, r, h, rr, e, H_r)
    return e, H_r


def _altitude(key_x, h, r_ref, values):
    x = vector_state(values, key_x)
    e, H_r = altitude_residual(x[None, :3], h, r_ref)
    return e[0], [pad_position_jacobian(H_r[0], x.shape[0])]


def make_altitude_factor(key_x, h_meas_m, r_ref_m, sigma_m):
    """CustomFactor on a state key ``[r; v]``: error (1,) m, Jacobian (1, 6); sigma in m
    (the INS/CNS lecture: 1 km 3-sigma, i.e. ``sigma_m = 333.3``)."""
    h = np.array([float(h_meas_m)])
    rr = np.array([float(r_ref_m)])
    return custom_factor([key_x], sigma_m, functools.partial(_altitude, key_x, h, rr), dim=1)
