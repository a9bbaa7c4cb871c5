"""The result every solver returns: states, covariances and diagnostics at each epoch."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Solution:
    """States and covariances of one estimation run (SI, ECI).

    Attributes
    ----------
    method : "batch" | "isam2" | "fixed-lag" | "ekf"
    epoch0 : numpy.datetime64 (UTC) of ``t_s = 0``.
    t_s : (N,) seconds from ``epoch0`` of each estimated state.
    x_eci : (N, 6) states ``[r_eci_m, v_eci_mps]``.
    P_eci : (N, 6, 6) marginal covariances (m^2, m^2/s, m^2/s^2).
    iterations : Gauss-Newton iterations (batch), or updates (incremental/EKF).
    chi2 : sum of squared whitened residuals at the solution.
    wall_s : wall time from the log read to states and covariances ready.
    residuals : per measurement kind, whitened residuals ``(M, dim)`` at the solution.
    online_x_eci, online_P_eci : for incremental methods and the EKF, each epoch's state
        and covariance as estimated when that epoch arrived (N, 6) / (N, 6, 6).
    latency_s : (N,) per-epoch update latency of incremental methods.
    variables : graph variables estimated beside the orbit state (``fgnav.models.variables``):
        name -> (values (N, d), marginal covariances (N, d, d)), e.g. ``refraction_bias``.
    extras : free-form diagnostics written into summary.json.
    P_block : (N, n, n) or None: each epoch's joint marginal covariance of its whole block of
        variables (the pass's layout: orbit state first, then the further variables), with
        the cross-covariances the per-variable entries leave out; set by batch, iSAM2
        (full history) and the numpy EKF (filtered), None where the solver does not have it.
    """

    method: str
    epoch0: np.datetime64
    t_s: np.ndarray
    x_eci: np.ndarray
    P_eci: np.ndarray
    iterations: int = 0
    chi2: float = float("nan")
    wall_s: float = float("nan")
    residuals: dict[str, np.ndarray] = field(default_factory=dict)
    online_x_eci: np.ndarray | None = None
    online_P_eci: np.ndarray | None = None
    latency_s: np.ndarray | None = None
    extras: dict = field(default_factory=dict)
    variables: dict = field(default_factory=dict)
    P_block: np.ndarray | None = None


def latency_summary(latency_s) -> dict:
    """Median, 99th percentile and maximum of per-epoch latencies (s), as summary.json keys."""
    lat = np.asarray(latency_s, dtype=float)
    return {"latency_p50_s": float(np.median(lat)),
            "latency_p99_s": float(np.percentile(lat, 99)),
            "latency_max_s": float(lat.max())}
