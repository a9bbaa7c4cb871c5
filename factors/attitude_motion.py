"""Constant-rate attitude motion: the attitude turns at a body rate that is itself a random walk.

Without a gyro the attitude between two measured epochs is only as good as its motion model.
Here the body angular rate ``w`` (rad/s, body frame) is a per-epoch variable driven by white
angular acceleration of spectral density ``q`` (rad^2/s^3), and the attitude
``R = R_eci_from_body`` (right perturbations ``R <- R Exp(d)``) turns at that rate:
``dR/dt = R [w]x``, ``dw/dt = n(t)``, ``E[n(t) n(s)^T] = q I delta(t - s)``. Over a step ``dt``
the residual is

    e = [ Log(Exp(w_0 dt)^T R_0^T R_1) ;  w_1 - w_0 ]        (6,), rad and rad/s,

zero for a constant body rate (``R_1 = R_0 Exp(w_0 dt)``), with the covariance of the
white-noise-on-acceleration prior ``q [[dt^3/3, dt^2/2], [dt^2/2, dt]] (x) I_3`` (Anderson &
Barfoot 2015, "Full STEAM ahead: exactly sparse Gaussian process regression for batch
continuous-time trajectory estimation on SE(3)", IROS, eqs. 19-20, on SO(3) and with the
rotation error written as the gyro factor writes it, ``factors.gyro``). Its square-root
information (upper triangular, ``W^T W = Q^-1``) is

    W = q^-1/2 [[sqrt(12/dt^3) I, -sqrt(3/dt) I], [0, sqrt(1/dt) I]].

Jacobians: the rotation part is the gyro residual with ``omega = w_0`` and no bias, so
``de_R/dR_0``, ``de_R/dR_1`` are the gyro's and ``de_R/dw_0 = -(gyro's de/db)`` =
``-Jr^-1(e) D^T Jr(-phi) dt`` (``D = R_0^T R_1``, ``phi = w_0 dt``); ``de_w/dw_0 = -I``,
``de_w/dw_1 = I``.
"""

from __future__ import annotations

import functools

import numpy as np

from factors.adapters import custom_factor, rot3_matrix, vector_state
from factors.gyro import gyro_residual

__all__ = ["constant_rate_residual", "constant_rate_sqrt_information",
           "make_constant_rate_factor"]


def constant_rate_residual(R0, w0_rad_s, R1, w1_rad_s, dt_s):
    """Unwhitened residual of a constant-rate step (module docstring) and its Jacobians.

    Parameters
    ----------
    R0, R1 : (M, 3, 3) R_eci_from_body at the step's start and end.
    w0_rad_s, w1_rad_s : (M, 3) body rates there, rad/s.
    dt_s : (M,) step length, s.

    Returns
    -------
    e (M, 6); H_R0, H_w0, H_R1, H_w1 (M, 6, 3) (rotations: right perturbations, rad).
    """
    w0 = np.asarray(w0_rad_s, dtype=float)
    w1 = np.asarray(w1_rad_s, dtype=float)
    M = len(w0)
    e_R, H0, H1, Hb = gyro_residual(R0, R1, np.zeros((M, 3)), w0, dt_s)
    eye = np.broadcast_to(np.eye(3), (M, 3, 3))
    zero = np.zeros((M, 3, 3))
    e = np.concatenate([e_R, w1 - w0], axis=1)
    H_R0 = np.concatenate([H0, zero], axis=1)
    H_w0 = np.concatenate([-Hb, -eye], axis=1)
    H_R1 = np.concatenate([H1, zero], axis=1)
    H_w1 = np.concatenate([zero, eye], axis=1)
    return e, H_R0, H_w0, H_R1, H_w1


def constant_rate_sqrt_information(dt_s, q_rad2_s3):
    """``W`` (M, 6, 6), upper triangular, ``W^T W = Q^-1`` of the step's covariance
    ``Q = q [[dt^3/3, dt^2/2], [dt^2/2, dt]] (x) I_3`` (module docstring)."""
    dt = np.atleast_1d(np.asarray(dt_s, dtype=float))
    s = 1.0 / np.sqrt(q_rad2_s3)
    W = np.zeros((len(dt), 6, 6))
    eye = np.eye(3)
    W[:, :3, :3] = (s * np.sqrt(12.0 / dt ** 3))[:, None, None] * eye
    W[:, :3, 3:] = (-s * np.sqrt(3.0 / dt))[:, None, None] * eye
    W[:, 3:, 3:] = (s * np.sqrt(1.0 / dt))[:, None, None] * eye
    return W


def _constant_rate(keys, dt, W, values):
    kR0, kw0, kR1, kw1 = keys
    e, *H = constant_rate_residual(rot3_matrix(values, kR0)[None], vector_state(values, kw0)[None],
                                   rot3_matrix(values, kR1)[None], vector_state(values, kw1)[None],
                                   dt)
    return W @ e[0], [W @ h[0] for h in H]


def make_constant_rate_factor(key_R0, key_w0, key_R1, key_w1, dt_s, q_rad2_s3):
    """CustomFactor on (Rot3 at k-1, rate at k-1, Rot3 at k, rate at k): the whitened
    residual ``W e`` (unit noise; :func:`constant_rate_sqrt_information`), the same rows as
    the batch route's."""
    dt = np.array([float(dt_s)])
    W = constant_rate_sqrt_information(dt, q_rad2_s3)[0]
    keys = tuple(int(k) for k in (key_R0, key_w0, key_R1, key_w1))
    return custom_factor(list(keys), 1.0, functools.partial(_constant_rate, keys, dt, W), dim=6)
