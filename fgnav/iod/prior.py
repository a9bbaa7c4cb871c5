"""The log's a-priori state: first guesses from it (no GTSAM: the numba EKF uses them too),
whether a pass has one, the pass without it, and a pass with a start prior in its place.

``has_prior``, ``strip_prior`` and ``with_start_prior`` sit here, below the diagnostics and
the solvers, rather than in the start policy (:mod:`fgnav.start`, which imports the whole IOD
and serves the pipeline) because the verdict (:mod:`fgnav.diagnostics.integrity`) needs
``has_prior`` too.
"""

from __future__ import annotations

import numpy as np

from factors.dynamics import MotionModel, propagate_through
from fgnav.measurements import Family, Pass, covering_sigmas, prior_state
from fgnav.models.registry import PRIOR_POSITION, PRIOR_VELOCITY, prior_kinds

__all__ = ["initial_guess", "first_state", "has_prior", "strip_prior", "with_start_prior"]


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


def has_prior(p: Pass) -> bool:
    """Whether the pass has both ``prior_position`` and ``prior_velocity`` rows."""
    return p.count(PRIOR_POSITION.kind) > 0 and p.count(PRIOR_VELOCITY.kind) > 0


def strip_prior(p: Pass) -> Pass:
    """The pass without its ``prior_position`` / ``prior_velocity`` rows."""
    fams = {k: f for k, f in p.families.items() if k not in prior_kinds()}
    return Pass(epoch0=p.epoch0, t_s=p.t_s, families=fams, source=p.source,
                warnings=list(p.warnings), layout=p.layout)


def with_start_prior(p: Pass, x0: np.ndarray, P0: np.ndarray) -> Pass:
    """The pass (priors stripped) with prior rows at epoch 0 of mean ``x0`` and isotropic
    1-sigma the square root of the largest eigenvalue of each 3x3 block of ``P0`` (the
    rows' format has one sigma per row, so the ellipsoid is covered by its sphere)."""
    q = strip_prior(p)
    sig_r, sig_v = covering_sigmas(P0)
    one = np.zeros(1, dtype=int)
    q.families = {PRIOR_POSITION.kind: Family(k=one, values={"xyz": x0[None, :3].copy()},
                                           sigma=np.array([sig_r]), line=np.zeros(1, dtype=int)),
                  PRIOR_VELOCITY.kind: Family(k=one, values={"xyz": x0[None, 3:].copy()},
                                           sigma=np.array([sig_v]), line=np.zeros(1, dtype=int)),
                  **q.families}
    return q
