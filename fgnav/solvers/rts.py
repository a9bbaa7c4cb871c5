"""The Rauch-Tung-Striebel backward pass over an extended Kalman filter's states: the batch
smoother's first guess.

The filter's state at t_k has seen the measurements up to t_k only; the backward pass
(Rauch, Tung & Striebel 1965) brings in the later ones,

    x_k^s = x_k + C_k (x_{k+1}^s - f(x_k)),   C_k = P_k Phi_k^T (Phi_k P_k Phi_k^T + Q_k)^-1,

with ``f`` and ``Phi_k`` the motion model's flow and transition matrix from the filtered
``x_k`` and ``Q_k`` its process noise. It is linearized about the filtered states, so it is
not the batch solution, but close to it: Gauss-Newton from the smoothed states takes one
iteration fewer than from the filtered ones (their error is quadratic in the distance).
Filtered and smoothed again with the motion and the measurements linearized about the
smoothed states (``x_lin``), the pass is the iterated smoother, whose step is a
Gauss-Newton step (Bell 1994): from there the batch smoother's first update already passes
its convergence test (one elimination in GTSAM instead of two).
Worked backward in chunks of epochs: no (N, 6, 6) array beyond the filter's own covariances.
"""

from __future__ import annotations

import numpy as np

from factors.dynamics import MotionModel, process_noise, propagate_many
from factors.interpret import run
from factors.jit import njit

__all__ = ["rts_smooth"]

CHUNK = 65_536
"""Steps whose gains are formed at a time."""


@njit(cache=True)
def _backward(x_f, f_pred, C, k0, x_s):
    """x_s[k] = x_f[k] + C[k - k0] (x_s[k + 1] - f_pred[k - k0]) for k from k0 + len(C) - 1
    down to k0 (x_s[k0 + len(C)] already smoothed)."""
    for j in range(C.shape[0] - 1, -1, -1):
        k = k0 + j
        for a in range(6):
            acc = x_f[k, a]
            for b in range(6):
                acc += C[j, a, b] * (x_s[k + 1, b] - f_pred[j, b])
            x_s[k, a] = acc


def rts_smooth(t_s: np.ndarray, x_f: np.ndarray, P_f: np.ndarray, model: MotionModel,
               q_m2_s3: float, t0_j2000_s: float,
               x_lin: np.ndarray | None = None) -> np.ndarray | None:
    """Smoothed states (N, 6) from the filtered ``x_f`` (N, 6) and ``P_f`` (N, 6, 6) at
    ``t_s`` (s from the epoch at ``t0_j2000_s``), or None where a gain is not finite.
    ``x_lin`` (N, 6): the motion linearized about it, ``f(x) ~ f(x_lin) + Phi (x - x_lin)``,
    as the filter was (:func:`fgnav.solvers.ekf_numba.ekf_kernel`)."""
    N = len(t_s)
    x_s = np.array(x_f, dtype=float)
    dt = np.diff(np.asarray(t_s, dtype=float))
    for k1 in range(N - 1, 0, -CHUNK):   # steps k0..k1-1, the last chunk first
        k0 = max(0, k1 - CHUNK)
        if x_lin is None:
            f_pred, Phi = propagate_many(x_f[k0:k1], dt[k0:k1], model, t0_j2000_s + t_s[k0:k1])
        else:
            f_pred, Phi = propagate_many(x_lin[k0:k1, :6], dt[k0:k1], model,
                                         t0_j2000_s + t_s[k0:k1])
            f_pred += np.einsum("kij,kj->ki", Phi, x_f[k0:k1] - x_lin[k0:k1, :6])
        PPhiT = P_f[k0:k1] @ np.swapaxes(Phi, 1, 2)
        P_pred = Phi @ PPhiT + process_noise(dt[k0:k1], q_m2_s3)
        # C = P Phi^T P_pred^-1, from P_pred C^T = Phi P (P_pred and P symmetric)
        C = np.swapaxes(np.linalg.solve(P_pred, np.swapaxes(PPhiT, 1, 2)), 1, 2)
        if not np.all(np.isfinite(C)):
            return None
        run(_backward, x_f, f_pred, np.ascontiguousarray(C), k0, x_s)
    return x_s if np.all(np.isfinite(x_s)) else None
