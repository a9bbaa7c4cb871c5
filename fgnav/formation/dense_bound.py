"""The Cramér–Rao bound of a formation's joint problem from its dense information matrix.

An independent check of the smoothers' covariances: every whitened row of the pass (the
measurements, the variables' priors, the process rows of every orbit and clock) linearized
at the truth is stacked into one dense Jacobian ``A`` over all epochs' blocks (``N n``
columns), and the bound is ``(A^T A)^-1`` (from the QR factorization of ``A``) (Kay 1993, *Fundamentals of Statistical Signal
Processing: Estimation Theory*, eq. 3.30, the Fisher information of a Gaussian model; with
the process noise the rows of the random-walk and white-acceleration priors, the bound is
the Bayesian one of Van Trees 1968, *Detection, Estimation and Modulation Theory* I,
sec. 2.4). No chain elimination, no back-substitution: one dense QR factorization, so it
is a check on :mod:`fgnav.solvers.chain`, not a second copy of it. Dense: for passes of up to a
few thousand unknowns (a formation of two spacecraft over an hour at one minute).
"""

from __future__ import annotations

import numpy as np

from fgnav.graph import linearize_all
from fgnav.solvers.batch import process_blocks
from fgnav.time import j2000_seconds

__all__ = ["dense_bound"]

MAX_UNKNOWNS = 6000


def dense_bound(p, X_true: np.ndarray, options) -> np.ndarray:
    """Per-epoch bound (N, n, n) of the pass ``p`` (any layout) linearized at the block
    values ``X_true`` (N, n): every whitened row stacked into one dense ``A`` (columns scaled
    to unit norm), its QR factorization ``A = Q R``, and ``(A^T A)^-1 = R^-1 R^-T``. QR, not
    the normal equations: forming ``A^T A`` squares the condition number, and on an hour of
    formation-gto its inverse gave sigmas up to 1.3x too large (negative variances at 10 s
    steps), where QR agrees with the chain marginals to 0.05 %."""
    import scipy.linalg as sla

    N, n = X_true.shape
    if N * n > MAX_UNKNOWNS:
        raise ValueError(f"dense_bound: {N * n} unknowns (at most {MAX_UNKNOWNS})")
    rows = linearize_all(p, X_true)
    if rows.steps is not None:
        raise ValueError("dense_bound: rows between epochs are not supported")
    A0, A1, _ = process_blocks(p, X_true, options.q_m2_s3, options.motion_model(),
                               float(j2000_seconds(p.epoch0)))
    A = np.zeros((len(rows.A) + (N - 1) * n, N * n))
    i = 0
    for k in range(N):                       # measurement and prior rows of epoch k
        a = rows.A[rows.k == k]
        A[i:i + len(a), k * n:(k + 1) * n] = a
        i += len(a)
    for k in range(N - 1):                   # process rows of step k -> k + 1
        A[i:i + n, k * n:(k + 1) * n] = A0[k]
        A[i:i + n, (k + 1) * n:(k + 2) * n] = A1[k]
        i += n
    s = 1.0 / np.linalg.norm(A, axis=0)
    R = sla.qr(A * s, mode="r", overwrite_a=True)[0][:N * n]
    Ri = sla.solve_triangular(R, np.eye(N * n))
    return np.stack([(Ri[k * n:(k + 1) * n] @ Ri[k * n:(k + 1) * n].T)
                     * np.outer(s[k * n:(k + 1) * n], s[k * n:(k + 1) * n]) for k in range(N)])
