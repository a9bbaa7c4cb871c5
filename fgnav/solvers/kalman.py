"""The Kalman filter's two steps, the one copy every filter of fgnav uses.

The EKF (:func:`fgnav.solvers.ekf.run_ekf`, its augmented step
:func:`fgnav.solvers.ekf.propagate_variables`), the online navigator's EKF
(:mod:`fgnav.online.navigator`) and the online gate of iSAM2 / the fixed-lag smoother
(:mod:`fgnav.solvers.incremental`) predict and update with these. The compiled EKF
(:mod:`fgnav.solvers.ekf_numba`) keeps its own compiled copy of the same equations.

Rows are whitened (``A dx ~ b``, unit measurement noise), as the graph builds them
(:func:`fgnav.graph.linearize_family`): Bar-Shalom, Li & Kirubarajan 2001, "Estimation with
Applications to Tracking and Navigation", sec. 5.2 (the filter), 5.4 (normalized
innovations); the Joseph form of the covariance update, ibid. sec. 5.2.
"""

from __future__ import annotations

import numpy as np

from factors.dynamics import process_noise, propagate


def orbit_transition(x: np.ndarray, dt: float, q: float, model, t_j2000_s: float):
    """The orbit's step of ``dt`` s from ``t_j2000_s``: ``(f(x), Phi, Q)``, the propagated
    state (6,), its state transition matrix and the white-acceleration process noise
    ``Q(dt)`` (``factors.dynamics.propagate``, ``process_noise``)."""
    x1, Phi = propagate(x, dt, model, t_j2000_s)
    return x1, Phi, process_noise(dt, q)


def predict_covariance(P: np.ndarray, F: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """The predicted covariance ``P <- F P F^T + Q`` (Bar-Shalom et al. 2001, sec. 5.2)."""
    return F @ P @ F.T + Q


def innovation_covariance(P: np.ndarray, A: np.ndarray) -> np.ndarray:
    """``S = A P A^T + I`` of whitened rows ``A`` (m, n) (ibid.)."""
    return A @ P @ A.T + np.eye(len(A))


def kalman_update(x: np.ndarray, P: np.ndarray, A: np.ndarray, b: np.ndarray, *, S=None,
                  retract=None):
    """The measurement update with whitened rows ``A dx ~ b`` (m, n), (m,) at ``(x, P)``.

    ``K = P A^T S^-1`` with ``S = A P A^T + I`` (``S`` may be given: the gate's,
    :func:`fgnav.robust.passes_gate`), ``x <- x (+) K b`` (``retract(x, dx)``, default
    ``x + dx``: a manifold's, a change of coordinates), the Joseph form
    ``P <- (I - K A) P (I - K A)^T + K K^T`` (Bar-Shalom et al. 2001, sec. 5.2).
    Returns ``(x, P, nu)``, ``nu = L^-1 b`` (``S = L L^T``) the normalized innovations
    (ibid. sec. 5.4: ``nu^T nu`` is the NIS)."""
    if S is None:
        S = innovation_covariance(P, A)
    nu = np.linalg.solve(np.linalg.cholesky(S), b)
    K = np.linalg.solve(S, A @ P).T
    dx = K @ b
    x = x + dx if retract is None else retract(x, dx)
    IKA = np.eye(len(P)) - K @ A
    return x, IKA @ P @ IKA.T + K @ K.T, nu
