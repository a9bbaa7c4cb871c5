"""Random-walk process of a slowly varying parameter between two epochs.

``b_{k+1} = b_k + w``, ``w ~ N(0, psd |dt| I)``: the residual ``e = b_{k+1} - b_k`` with
``H_k = -I``, ``H_{k+1} = I`` and 1-sigma ``sqrt(psd |dt|)`` (Maybeck 1979, "Stochastic Models,
Estimation and Control", vol. 1, sec. 4.10, the random walk as the integral of white noise).
"""

from __future__ import annotations

import functools

import numpy as np

from factors.adapters import custom_factor, vector_state

__all__ = ["random_walk_residual", "make_random_walk_factor", "make_vector_prior_factor"]


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
