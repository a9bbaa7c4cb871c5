"""The Cramér–Rao bound of a formation's joint problem from its dense information matrix.

An independent check of the smoothers' covariances: every whitened row of the pass (the
measurements, the variables' priors, the process rows of every orbit and clock) linearized
at the truth is stacked into one dense Jacobian ``A`` over all epochs' blocks (``N n``
columns), and the bound is ``(A^T A)^-1`` (Kay 1993, *Fundamentals of Statistical Signal
Processing: Estimation Theory*, eq. 3.30, the Fisher information of a Gaussian model; with
the process noise the rows of the random-walk and white-acceleration priors, the bound is
the Bayesian one of Van Trees 1968, *Detection, Estimation and Modulation Theory* I,
sec. 2.4). No chain elimination, no back-substitution: a plain dense inverse, so it is a
check on :mod:`fgnav.solvers.chain`, not a second copy of it. Dense: for passes of up to a
few thousand unknowns (a formation of two spacecraft over an hour at one minute).
"""

from __future__ import annotations

import numpy as np

from fgnav.graph import linearize_all
from fgnav.time import j2000_seconds

__all__ = ["dense_bound"]

MAX_UNKNOWNS = 6000


def dense_bound(p, X_true: np.ndarray, options) -> np.ndarray:
    """Per-epoch bound (N, n, n) of the pass ``p`` (any layout) linearized at the block
    values ``X_true`` (N, n)."""
    from fgnav.solvers.batch import process_blocks

    N, n = X_true.shape
    if N * n > MAX_UNKNOWNS:
        raise ValueError(f"dense_bound: {N * n} unknowns (at most {MAX_UNKNOWNS})")
    rows = linearize_all(p, X_true)
    A0, A1, _ = process_blocks(p, X_true, options.q_m2_s3, options.motion_model(),
                               float(j2000_seconds(p.epoch0)))
    J = np.zeros((N * n, N * n))
    for k in range(N):                       # measurement and prior rows of epoch k
        a = rows.A[rows.k == k]
        J[k * n:(k + 1) * n, k * n:(k + 1) * n] += a.T @ a
    for k in range(N - 1):                   # process rows of step k -> k + 1
        B = np.concatenate([A0[k], A1[k]], axis=1)
        J[k * n:(k + 2) * n, k * n:(k + 2) * n] += B.T @ B
    if rows.steps is not None:
        raise ValueError("dense_bound: rows between epochs are not supported")
    s = 1.0 / np.sqrt(np.maximum(np.diag(J), 1e-300))   # scaled: orbit metres vs clock
    C = np.linalg.inv(J * s[:, None] * s[None, :]) * s[:, None] * s[None, :]
    return np.stack([C[k * n:(k + 1) * n, k * n:(k + 1) * n] for k in range(N)])
