"""Priors on part of the orbit state: an a-priori position or velocity with its 1-sigma.

``e = x[sl] - x_prior`` with ``sl = 0:3`` (position, m) or ``3:6`` (velocity, m/s),
``H = [I 0]`` or ``[0 I]`` (3x6): a direct observation of the state (Tapley, Schutz & Born
2004, "Statistical Orbit Determination", sec. 4.6, the a-priori information).
"""

from __future__ import annotations

import functools

import numpy as np
from factors.jit import njit

from factors.adapters import custom_factor, vector_state

__all__ = ["POSITION", "VELOCITY", "state_prior_residual", "make_state_prior_factor",
           "prior_position_kernel", "prior_velocity_kernel"]

POSITION = slice(0, 3)
VELOCITY = slice(3, 6)


def state_prior_residual(x, mean, sl):
    """``e (M, 3) = x[:, sl] - mean``, ``H (M, 3, 6)`` with the identity in the ``sl`` columns."""
    x = np.asarray(x, dtype=float)
    e = x[:, sl] - np.asarray(mean, dtype=float)
    H = np.zeros((len(x), 3, 6))
    H[:, :, sl] = np.eye(3)
    return e, H


def _prior(key, mean, sl, values):
    x = vector_state(values, key)
    e, H = state_prior_residual(x[None, :6], mean[None], sl)
    Hx = np.zeros((3, x.shape[0]))
    Hx[:, :6] = H[0]
    return e[0], [Hx]


def make_state_prior_factor(key, sl, mean, sigma):
    """CustomFactor on a state key: error (3,) = x[sl] - mean, Jacobian (3, dim x)."""
    return custom_factor([key], sigma, functools.partial(_prior, key, np.array(mean, dtype=float), sl),
                         dim=3)


@njit(cache=True)
def _prior_rows(off, x, data, e, H):
    for i in range(3):
        for j in range(6):
            H[i, j] = 0.0
        H[i, off + i] = 1.0
        e[i] = x[off + i] - data[i]
    return 3


@njit(cache=True)
def prior_position_kernel(x, data, B, e, H):
    """Row kernel (compiled EKF): position prior, ``data[:3]`` the a-priori position; 3 rows."""
    return _prior_rows(0, x, data, e, H)


@njit(cache=True)
def prior_velocity_kernel(x, data, B, e, H):
    """Row kernel (compiled EKF): velocity prior, ``data[:3]`` the a-priori velocity; 3 rows."""
    return _prior_rows(3, x, data, e, H)
