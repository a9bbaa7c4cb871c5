"""First guesses from the a-priori state (no GTSAM: the numba EKF uses them too)."""

from __future__ import annotations

import numpy as np

from factors.dynamics import MotionModel, propagate
from fgnav.measurements import Pass, prior_state


def initial_guess(p: Pass, model: MotionModel, t0_j2000_s: float) -> np.ndarray:
    """First guess of every state (N, 6): the a-priori state propagated through all epochs.

    Uses the first epoch ``k0`` that has both a ``prior_position`` and a ``prior_velocity`` row.
    """
    k0, x0 = prior_state(p)
    Xg = np.empty((p.n_epochs, 6))
    Xg[k0] = x0
    for k in range(k0 + 1, p.n_epochs):
        Xg[k] = propagate(Xg[k - 1], p.t_s[k] - p.t_s[k - 1], model, t0_j2000_s + p.t_s[k - 1],
                          with_stm=False)[0]
    Xg[:k0 + 1] = _back_to_start(p, k0, x0, model, t0_j2000_s)
    return Xg


def first_state(p: Pass, model: MotionModel, t0_j2000_s: float) -> np.ndarray:
    """The state at epoch 0 alone, ``initial_guess(...)[0]`` without the forward pass."""
    k0, x0 = prior_state(p)
    return _back_to_start(p, k0, x0, model, t0_j2000_s)[0]


def _back_to_start(p: Pass, k0: int, x0: np.ndarray, model: MotionModel, t0_j2000_s: float):
    """States (k0 + 1, 6) of epochs 0..k0: ``x0`` at ``k0`` propagated back to epoch 0."""
    out = np.empty((k0 + 1, 6))
    out[k0] = x0
    for k in range(k0 - 1, -1, -1):
        out[k] = propagate(out[k + 1], p.t_s[k] - p.t_s[k + 1], model, t0_j2000_s + p.t_s[k + 1],
                           with_stm=False)[0]
    return out
