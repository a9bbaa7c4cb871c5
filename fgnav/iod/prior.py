"""First guesses from the a-priori state (no GTSAM: the numba EKF uses them too)."""

from __future__ import annotations

import numpy as np

from factors.dynamics import MotionModel, propagate_through
from fgnav.measurements import Pass, prior_state


def initial_guess(p: Pass, model: MotionModel, t0_j2000_s: float) -> np.ndarray:
    """First guess of every state (N, 6): the a-priori state propagated through all epochs.

    Uses the first epoch ``k0`` that has both a ``prior_position`` and a ``prior_velocity`` row.
    """
    k0, x0 = prior_state(p)
    return propagate_through(x0, p.t_s, k0, model, t0_j2000_s)


def first_state(p: Pass, model: MotionModel, t0_j2000_s: float) -> np.ndarray:
    """The state at epoch 0 alone, ``initial_guess(...)[0]`` without the forward pass."""
    k0, x0 = prior_state(p)
    return propagate_through(x0, p.t_s[:k0 + 1], k0, model, t0_j2000_s)[0]
