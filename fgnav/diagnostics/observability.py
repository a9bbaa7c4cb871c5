"""Observability of the linearized orbit system over a window (Pan & Yao 2017, sec. 3.3).

Pan & Yao 2017 treats the nonlinear time-varying system as piecewise linear time-invariant
and forms the observability matrix (their eq. 9)

    M = [H_0; H_1 Phi(t_1, t_0); ...; H_{n-1} Phi(t_{n-1}, t_0)],   t_j = t_0 + j T,

declaring the system observable when rank M = 6 and taking cond(M) as the degree of
observability (table 4: condition number vs sample period T). Here ``H_j`` is the
geocentric-direction Jacobian on the tangent plane (2 x 6, rad per m; the factor's
residual, CONTRIBUTING.md) at the state propagated from ``x0`` (two-body + J2), and
``Phi`` the state transition matrix of the same motion model. With ``n`` = 6 samples
(the classical PWCS choice) the window is ``5 T`` long.

``cond(M)`` depends on the units of the state: the raw SI value (metres and m/s, as the
paper computed it presumably) is reported with the unit-free value of the column-scaled
matrix (every column normalized, Jacobi scaling). Rank is decided on the scaled matrix.

The information matrix ``J = M^T M / sigma^2`` of a window and its eigen-decomposition
give the weakest-observed state directions; :func:`weakest_directions` reports them in a
scaled state (position in m, velocity times a time scale in s, so both are metres).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factors.direction import earth_direction_residual
from factors.dynamics import MotionModel, propagate

STATE_NAMES = ("x", "y", "z", "vx", "vy", "vz")

__all__ = ["observability_matrix", "ObservabilityResult", "analyze_observability",
           "window_information", "weakest_directions", "describe_direction"]


def _trajectory_stm(x0_eci, t_s, model, t0_j2000_s):
    """States (n,6) and Phi(t_j, t_0) (n,6,6) at ``t_s`` (t_s[0] = 0) by the motion model."""
    n = len(t_s)
    X = np.empty((n, 6))
    Phi = np.empty((n, 6, 6))
    X[0] = x0_eci
    Phi[0] = np.eye(6)
    for j in range(1, n):
        X[j], F = propagate(X[j - 1], t_s[j] - t_s[j - 1], model, t0_j2000_s + t_s[j - 1])
        Phi[j] = F @ Phi[j - 1]
    return X, Phi


def observability_matrix(x0_eci, period_s: float, n_samples: int = 6, model=None,
                         t0_j2000_s: float = 0.0) -> np.ndarray:
    """Pan & Yao 2017, eq. 9, for geocentric-direction measurements: (2 n, 6), rad per SI state unit.

    ``x0_eci`` (6,) [m, m/s] is the linearization point (Pan & Yao 2017 use the initial state),
    ``period_s`` the sample period T, ``n_samples`` the number of blocks.
    """
    if period_s <= 0 or n_samples < 1:
        raise ValueError(f"observability_matrix: need period_s > 0 and n_samples >= 1, "
                         f"found {period_s}, {n_samples}")
    model = MotionModel() if model is None else model
    t = np.arange(n_samples) * float(period_s)
    X, Phi = _trajectory_stm(np.asarray(x0_eci, float), t, model, t0_j2000_s)
    r = X[:, :3]
    u = -r / np.linalg.norm(r, axis=1, keepdims=True)
    _, H_r = earth_direction_residual(r, u)
    H = np.zeros((n_samples, 2, 6))
    H[:, :, :3] = H_r
    return np.einsum("nij,njk->nik", H, Phi).reshape(-1, 6)


@dataclass
class ObservabilityResult:
    rank: int
    condition_raw: float          # cond(M) in SI units (m, m/s)
    condition_scaled: float       # cond(M D), D = 1/column norms
    singular_values: np.ndarray   # of the scaled matrix, descending
    weakest_direction: np.ndarray  # (6,) unit, in SI state units, of the smallest scaled s.v.

    def as_dict(self) -> dict:
        return {"rank": self.rank, "condition_raw": self.condition_raw,
                "condition_scaled": self.condition_scaled,
                "weakest_direction": describe_direction(self.weakest_direction)}


def analyze_observability(M: np.ndarray, rtol: float | None = None) -> ObservabilityResult:
    """Rank (on the column-scaled matrix, tolerance ``rtol * s_max``, default
    ``max(shape) * eps``), raw and scaled condition numbers, and the weakest direction."""
    M = np.asarray(M, float)
    s_raw = np.linalg.svd(M, compute_uv=False)
    cn = np.linalg.norm(M, axis=0)
    d = 1.0 / np.where(cn > 0, cn, 1.0)
    _, s, Vt = np.linalg.svd(M * d[None, :])
    tol = (max(M.shape) * np.finfo(float).eps if rtol is None else rtol) * s[0]
    rank = int(np.sum(s > tol))
    w = Vt[-1] * d
    w /= np.linalg.norm(w)
    cond_raw = float(s_raw[0] / s_raw[-1]) if s_raw[-1] > 0 else float("inf")
    cond_s = float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
    return ObservabilityResult(rank, cond_raw, cond_s, s, w)


def window_information(x0_eci, period_s: float, duration_s: float, sigma_rad: float,
                       model=None, t0_j2000_s: float = 0.0) -> np.ndarray:
    """Fisher information (6,6) of the initial state from direction measurements every
    ``period_s`` over ``duration_s`` (noise ``sigma_rad`` per axis): ``sum Phi^T H^T H Phi
    / sigma^2`` in SI (1/m^2, 1/(m m/s), ...)."""
    n = int(np.floor(duration_s / period_s + 1e-9)) + 1
    M = observability_matrix(x0_eci, period_s, n, model, t0_j2000_s)
    return M.T @ M / sigma_rad ** 2


def weakest_directions(J: np.ndarray, time_scale_s: float = 1000.0, count: int = 2) -> list[dict]:
    """The ``count`` least-informed state directions of an information matrix ``J`` (6,6, SI).

    The state is scaled to metres (velocity times ``time_scale_s``) so that eigenvalues are
    comparable; each entry gives ``sigma_m`` = 1/sqrt(eigenvalue) (the 1-sigma extent of that
    direction, m or m per time scale) and the unit direction in the scaled state.
    """
    D = np.diag([1.0, 1.0, 1.0, 1.0 / time_scale_s, 1.0 / time_scale_s, 1.0 / time_scale_s])
    Js = D @ np.asarray(J, float) @ D
    w, V = np.linalg.eigh(0.5 * (Js + Js.T))
    out = []
    for i in range(min(count, 6)):
        lam = float(w[i])
        out.append({"eigenvalue": lam, "sigma_m": float(1.0 / np.sqrt(lam)) if lam > 0 else float("inf"),
                    "direction": V[:, i].copy(), "text": describe_direction(V[:, i])})
    return out


def describe_direction(v: np.ndarray, threshold: float = 0.2) -> str:
    """A unit 6-vector as text, components above ``threshold`` (e.g. '+0.71 x -0.70 vz')."""
    v = np.asarray(v, float)
    v = v / np.linalg.norm(v)
    if v[np.argmax(np.abs(v))] < 0:
        v = -v
    return " ".join(f"{c:+.2f} {n}" for c, n in zip(v, STATE_NAMES) if abs(c) >= threshold)
