"""Gyro-integrated attitude between two epochs, with a gyro bias.

A rate gyro reports the body angular rate ``omega`` (rad/s, body frame) averaged over the
interval ``dt`` that ends at epoch k; its bias ``b`` (rad/s) is a slowly varying variable.
With the attitude ``R = R_eci_from_body`` (right perturbations ``R <- R Exp(w)``), the
measured increment is ``Exp(phi)``, ``phi = (omega - b) dt``, and the residual is

    e = Log(Exp(phi)^T R_{k-1}^T R_k)        (3,), rad, body frame at k,

zero when the attitude moved as the gyro says (the zero-order-hold discretization of
``dR/dt = R [omega - b]x``; Forster, Carlone, Dellaert & Scaramuzza 2017, "On-manifold
preintegration for real-time visual-inertial odometry", eq. 26 for a single interval).
Its 1-sigma is ``sigma_omega dt`` per axis (the rate noise integrated over the interval).

Jacobians (``D = R_{k-1}^T R_k``, ``E = Exp(-phi)``, ``e = Log(E D)``; right Jacobians
``Jr``; Sola, Deray & Atchuthan 2018, "A micro Lie theory for state estimation in robotics",
eqs. 44, 59-60, 143):

    de/dR_k     = Jr^-1(e),
    de/dR_{k-1} = -Jr^-1(e) (E D)^T E,       (the perturbation of R_{k-1} acts on D from the left)
    de/db       = Jr^-1(e) D^T Jr(-phi) dt,   (since Exp(-phi - d) ~ Exp(-phi) Exp(-Jr(-phi) d)).
"""

from __future__ import annotations

import functools

import numpy as np

from factors.adapters import custom_factor, rot3_matrix, vector_state
from factors.geometry import skew, so3_exp, so3_log, so3_right_jacobian_inv

__all__ = ["so3_right_jacobian", "gyro_residual", "make_gyro_factor",
           "make_gyro_factor_without_bias"]


def so3_right_jacobian(omega):
    """Right Jacobian of SO(3): ``Exp(w + d) ~ Exp(w) Exp(Jr(w) d)``,
    ``Jr(w) = I - (1 - cos t)/t^2 W + (t - sin t)/t^3 W^2`` (``W = skew(w)``, ``t = |w|``)."""
    omega = np.asarray(omega, dtype=float)
    theta = np.linalg.norm(omega, axis=-1)[..., None, None]
    W = skew(omega)
    small = theta < 1e-5
    t = np.where(small, 1.0, theta)
    a = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(t)) / t**2)
    b = np.where(small, 1.0 / 6.0 - theta**2 / 120.0, (t - np.sin(t)) / t**3)
    return np.eye(3) - a * W + b * (W @ W)


def gyro_residual(R0, R1, bias_rad_s, omega_rad_s, dt_s):
    """Residual of a gyro interval (module docstring) and its Jacobians.

    Parameters
    ----------
    R0, R1 : (M, 3, 3) attitudes R_eci_from_body at the interval's start and end.
    bias_rad_s : (M, 3) gyro bias, rad/s; omega_rad_s : (M, 3) measured mean rate, rad/s;
    dt_s : (M,) interval length, s.

    Returns
    -------
    e (M, 3) rad; H0, H1 (M, 3, 3) rad/rad; Hb (M, 3, 3) rad per rad/s.
    """
    R0 = np.asarray(R0, dtype=float)
    R1 = np.asarray(R1, dtype=float)
    dt = np.asarray(dt_s, dtype=float)[..., None]
    phi = (np.asarray(omega_rad_s, dtype=float) - np.asarray(bias_rad_s, dtype=float)) * dt
    E = so3_exp(-phi)
    D = np.swapaxes(R0, -1, -2) @ R1
    ED = E @ D
    e = so3_log(ED)
    Jinv = so3_right_jacobian_inv(e)
    H1 = Jinv
    H0 = -Jinv @ np.swapaxes(ED, -1, -2) @ E
    Hb = Jinv @ np.swapaxes(D, -1, -2) @ so3_right_jacobian(-phi) * dt[..., None]
    return e, H0, H1, Hb


def _gyro(key0, key1, key_b, omega, dt, values):
    R0 = rot3_matrix(values, key0)[None]
    R1 = rot3_matrix(values, key1)[None]
    b = vector_state(values, key_b)[None]
    e, H0, H1, Hb = gyro_residual(R0, R1, b, omega, dt)
    return e[0], [H0[0], H1[0], Hb[0]]


def make_gyro_factor(key0, key1, key_b, omega_rad_s, dt_s, sigma_rad):
    """CustomFactor on (Rot3 at k-1, Rot3 at k, Vector3 gyro bias): error (3,) rad;
    ``sigma_rad`` per axis, e.g. ``sigma_omega dt``."""
    omega = np.asarray(omega_rad_s, dtype=float).reshape(1, 3)
    dt = np.array([float(dt_s)])
    return custom_factor([key0, key1, key_b], sigma_rad,
                         functools.partial(_gyro, int(key0), int(key1), int(key_b), omega, dt), dim=3)


def _gyro_nobias(key0, key1, omega, dt, values):
    R0 = rot3_matrix(values, key0)[None]
    R1 = rot3_matrix(values, key1)[None]
    e, H0, H1, _ = gyro_residual(R0, R1, np.zeros((1, 3)), omega, dt)
    return e[0], [H0[0], H1[0]]


def make_gyro_factor_without_bias(key0, key1, omega_rad_s, dt_s, sigma_rad):
    """The gyro factor with the bias known to be zero (a calibrated gyro): on two Rot3 keys."""
    omega = np.asarray(omega_rad_s, dtype=float).reshape(1, 3)
    dt = np.array([float(dt_s)])
    return custom_factor([key0, key1], sigma_rad,
                         functools.partial(_gyro_nobias, int(key0), int(key1), omega, dt), dim=3)
