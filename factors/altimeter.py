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

import numpy as np

from factors.adapters import custom_factor, pad_position_jacobian, vector_state
from factors.geometry import unit_and_jacobian

__all__ = ["altitude_residual", "make_altitude_factor"]


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
    r = np.asarray(r_eci_m, dtype=float)
    u, _ = unit_and_jacobian(r)
    n = np.linalg.norm(r, axis=-1)
    e = n - np.asarray(r_ref_m, dtype=float) - np.asarray(h_meas_m, dtype=float)
    return np.asarray(e, dtype=float).reshape(-1, 1), u[:, None, :]


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
