"""Linear algebra of a state chain: back-substitution and O(N) marginals from the Bayes net.

Eliminating the linearized chain ``X0, X1, ..., X_{N-1}`` in order with QR (GTSAM's
``EliminateQR``) leaves one Gaussian conditional per state,

    R_k dx_k + S_k dx_{k+1} = d_k      (unit noise; S_{N-1} = 0),

a square-root information smoother. Back-substitution gives the update, and the marginal
covariances follow from the backward recursion (the RTS smoother in square-root form)

    Sigma_{N-1} = R^-1 R^-T,
    Sigma_k     = R_k^-1 (I + S_k Sigma_{k+1} S_k^T) R_k^-T,

because ``dx_k = R_k^-1 (d_k - S_k dx_{k+1} + w_k)`` with ``w_k ~ N(0, I)`` independent of
``dx_{k+1}``. Cost O(N); checked against a dense inverse in ``tests/test_batch.py``.
"""

from __future__ import annotations

import numpy as np
from factors.jit import njit

from factors.interpret import run


def back_substitute(R, S, d):
    """Solve the chain's triangular system; R, S (N,n,n), d (N,n) -> dx (N,n)."""
    return run(_back_substitute_nb, R, S, d)


def chain_marginals(R, S):
    """Marginal covariances (N,n,n) of every state from the chain's conditionals."""
    return run(_chain_marginals_nb, R, S)


@njit(cache=True)
def _back_substitute_nb(R, S, d):
    N, n = d.shape
    dx = np.empty((N, n))
    dx[N - 1] = np.linalg.solve(R[N - 1], d[N - 1])
    for k in range(N - 2, -1, -1):
        dx[k] = np.linalg.solve(R[k], d[k] - S[k] @ dx[k + 1])
    return dx


@njit(cache=True)
def _chain_marginals_nb(R, S):
    N, n, _ = R.shape
    P = np.empty((N, n, n))
    eye = np.eye(n)
    Rinv = np.linalg.solve(R[N - 1], eye)
    P[N - 1] = Rinv @ Rinv.T
    for k in range(N - 2, -1, -1):
        Rinv = np.linalg.solve(R[k], eye)
        M = eye + S[k] @ P[k + 1] @ S[k].T
        Pk = Rinv @ M @ Rinv.T
        P[k] = 0.5 * (Pk + Pk.T)
    return P
