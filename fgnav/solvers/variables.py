"""The solvers' view of the graph variables beyond the orbit state (``fgnav.models.variables``)."""

from __future__ import annotations

import numpy as np


def block_variables(lay, X: np.ndarray, P: np.ndarray) -> dict:
    """The variables after the orbit state in block values ``X`` (N, n) and marginal
    covariances ``P`` (N, n, n): name -> (values (N, d), covariances (N, d, d))."""
    return {v.name: (X[:, lay.slices[v.name]].copy(),
                     P[:, lay.slices[v.name], lay.slices[v.name]].copy()) for v in lay.extra}
