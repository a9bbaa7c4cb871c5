"""Random-walk process of a slowly varying variable between two epochs.

Vector: ``b_{k+1} = b_k + w``, ``w ~ N(0, psd |dt| I)``: the residual ``e = b_{k+1} - b_k``
with ``H_k = -I``, ``H_{k+1} = I`` and 1-sigma ``sqrt(psd |dt|)`` (Maybeck 1979, "Stochastic
Models, Estimation and Control", vol. 1, sec. 4.10, the random walk as the integral of white
noise).

Rotation (``R_eci_from_body``, right perturbations ``R <- R Exp(w)``): ``R_{k+1} = R_k Exp(w)``,
the residual ``e = Log(R_k^T R_{k+1})`` (GTSAM's ``BetweenFactorRot3`` with an identity
measurement), ``H_{k+1} = Jr^-1(e)``, ``H_k = -Jr^-1(e) R_{k+1}^T R_k`` (Sola, Deray &
Atchuthan 2018, "A micro Lie theory for state estimation in robotics", eqs. 44, 59-60).
"""

from __future__ import annotations

import functools

import numpy as np

from factors.adapters import custom_factor, noise_model, vector_state
from factors.geometry import so3_log, so3_right_jacobian_inv

__all__ = ["random_walk_residual", "make_random_walk_factor", "make_vector_prior_factor",
           "rot3_random_walk_residual", "make_rot3_random_walk_factor", "make_rot3_prior_factor"]


def random_walk_residual(b0, b1):
    """``e (M, d) = b1 - b0``; ``H0 = -I``, ``H1 = I`` (M, d, d)."""
    b0 = np.asarray(b0, dtype=float)
    b1 = np.asarray(b1, dtype=float)
    eye = np.broadcast_to(np.eye(b0.shape[-1]), b0.shape + (b0.shape[-1],))
    return b1 - b0, -eye, eye.copy()


def _rw(key0, key1, values):
    e, H0, H1 = random_walk_residual(vector_state(values, key0)[None], vector_state(values, key1)[None])
    return e[0], [H0[0], H1[0]]


def make_random_walk_factor(key0, key1, sigma, dim):
    """CustomFactor between two vector keys of dimension ``dim``: error ``b1 - b0``;
    ``sigma`` the step's 1-sigma (``sqrt(psd |dt|)``)."""
    return custom_factor([key0, key1], sigma, functools.partial(_rw, key0, key1), dim=dim)


def _vprior(key, mean, values):
    b = vector_state(values, key)
    return b - mean, [np.eye(len(b))]


def make_vector_prior_factor(key, mean, sigma):
    """CustomFactor: a prior ``b ~ N(mean, sigma^2 I)`` on a vector key."""
    mean = np.atleast_1d(np.asarray(mean, dtype=float))
    return custom_factor([key], sigma, functools.partial(_vprior, key, mean), dim=len(mean))


def rot3_random_walk_residual(R0, R1):
    """``e (M, 3) = Log(R0^T R1)``; ``H0 = -Jr^-1(e) R1^T R0``, ``H1 = Jr^-1(e)`` (M, 3, 3)."""
    R0 = np.asarray(R0, dtype=float)
    R1 = np.asarray(R1, dtype=float)
    D = np.swapaxes(R0, -1, -2) @ R1
    e = so3_log(D)
    H1 = so3_right_jacobian_inv(e)
    return e, -H1 @ np.swapaxes(D, -1, -2), H1


def make_rot3_random_walk_factor(key0, key1, sigma):
    """Between two ``Rot3`` keys: GTSAM's ``BetweenFactorRot3`` with an identity
    measurement, error ``Log(R0^T R1)`` (:func:`rot3_random_walk_residual`); ``sigma`` the
    step's 1-sigma per axis (rad)."""
    import gtsam

    return gtsam.BetweenFactorRot3(int(key0), int(key1), gtsam.Rot3(), noise_model(sigma, 3))


def make_rot3_prior_factor(key, R_mean, sigma):
    """A prior ``Log(R_mean^T R) ~ N(0, sigma^2 I)`` on a ``Rot3`` key (``PriorFactorRot3``)."""
    import gtsam

    return gtsam.PriorFactorRot3(int(key), gtsam.Rot3(np.asarray(R_mean, dtype=float)),
                                 noise_model(sigma, 3))
