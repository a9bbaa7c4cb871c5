"""Filter/smoother consistency: NEES, NIS and ANEES with chi-square bands.

Definitions (Bar-Shalom, Li & Kirubarajan, *Estimation with Applications to Tracking and
Navigation*, sec. 5.4):

* NEES of epoch k: ``eps_k = e_k^T P_k^-1 e_k`` with ``e_k = x_hat_k - x_true_k`` (6-D,
  SI, ECI); for a consistent estimator ``eps_k ~ chi2(6)``.
* ANEES over R independent runs at one epoch: ``mean_r eps_k^(r)``; ``R * ANEES ~
  chi2(6 R)``, so the two-sided (1 - alpha) band is ``chi2.ppf([a/2, 1 - a/2], 6 R) / R``.
  Epochs of one run are correlated: a time average of one run's NEES has no chi-square
  band; use the per-epoch ANEES curve (and the fraction of epochs inside the band, which
  should be about 1 - alpha) or ANEES at fixed epochs.
* NIS of the EKF: innovation ``nu_k = b_k`` (whitened, at the predicted state) with
  covariance ``S_k = A_k P_k^- A_k^T + I``: ``nu^T S^-1 nu ~ chi2(m_k)``.
* Smoother "NIS" (normalized residuals): the whitened post-fit residual ``r_j`` of a
  measurement on epoch k has covariance ``I - A_j P_k A_j^T`` for a linear-Gaussian model
  (the diagonal block of the residual projector), so ``r^T (I - A P A^T)^-1 r ~ chi2(m)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factors.dynamics import process_noise, propagate
from fgnav.graph import PRIOR_KINDS, enters, orbit_rows
from fgnav.models.registry import model as model_of
from fgnav.time import j2000_seconds


__all__ = ["nees", "chi2_band", "AneesResult", "anees", "nees_curve", "nis_ekf",
           "nis_smoother", "nis_summary"]


def nees(x_est: np.ndarray, P: np.ndarray, x_true: np.ndarray) -> np.ndarray:
    """Per-epoch NEES ``e^T P^-1 e``: x (N,d), P (N,d,d) in consistent SI units -> (N,)."""
    e = np.asarray(x_est, float) - np.asarray(x_true, float)
    sol = np.linalg.solve(np.asarray(P, float), e[..., None])[..., 0]
    return np.einsum("ki,ki->k", e, sol)


def chi2_band(dof: float, n_runs: int, alpha: float = 0.05) -> tuple[float, float]:
    """Two-sided (1 - alpha) band of the mean of ``n_runs`` independent chi2(dof) values."""
    from scipy.stats import chi2

    n = int(n_runs)
    if n < 1 or dof <= 0:
        raise ValueError(f"chi2_band: need n_runs >= 1 and dof > 0, found {n_runs}, {dof}")
    lo, hi = chi2.ppf([alpha / 2.0, 1.0 - alpha / 2.0], dof * n) / n
    return float(lo), float(hi)


@dataclass(frozen=True)
class AneesResult:
    """ANEES of R runs (one value per run, e.g. the NEES at one epoch)."""

    anees: float
    dof: int
    n_runs: int
    alpha: float
    lo: float
    hi: float

    @property
    def inside(self) -> bool:
        return self.lo <= self.anees <= self.hi

    @property
    def ratio(self) -> float:
        """ANEES / dof: 1 for a consistent estimator, > 1 overconfident, < 1 pessimistic."""
        return self.anees / self.dof

    def as_dict(self) -> dict:
        return {"anees": self.anees, "dof": self.dof, "n_runs": self.n_runs, "alpha": self.alpha,
                "band_lo": self.lo, "band_hi": self.hi, "inside": self.inside, "ratio": self.ratio}


def anees(nees_per_run, dof: int = 6, alpha: float = 0.05) -> AneesResult:
    """ANEES of independent runs: ``nees_per_run`` (R,) holds one NEES per run."""
    v = np.asarray(nees_per_run, float).reshape(-1)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        raise ValueError("anees: no finite NEES values")
    lo, hi = chi2_band(dof, len(v), alpha)
    return AneesResult(float(v.mean()), int(dof), len(v), float(alpha), lo, hi)


def nees_curve(nees_runs: np.ndarray, dof: int = 6, alpha: float = 0.05):
    """Per-epoch ANEES over runs: ``nees_runs`` (R, N) -> (curve (N,), lo, hi, fraction of
    epochs whose ANEES lies in the (1 - alpha) band)."""
    a = np.asarray(nees_runs, float)
    if a.ndim != 2:
        raise ValueError(f"nees_curve: expected (runs, epochs), found shape {a.shape}")
    curve = a.mean(axis=0)
    lo, hi = chi2_band(dof, a.shape[0], alpha)
    return curve, lo, hi, float(np.mean((curve >= lo) & (curve <= hi)))


def _family_rows(p, kind, X, variables=None):
    """(k, A (M,m,6), b (M,m)) of one family linearized at the orbit states X (whitened; the
    pass's further variables at ``variables``, a solution's, or their prior mean)."""
    k, A, b, _ = orbit_rows(p, kind, p.families[kind], X, variables)
    m = A.shape[1]
    return np.asarray(k), np.asarray(A).reshape(len(k), m, 6), np.asarray(b).reshape(len(k), m)


def nis_smoother(p, sol) -> tuple[np.ndarray, np.ndarray]:
    """Normalized post-fit residuals of a smoother solution (module doc).

    Returns ``(nis (M,), dof (M,))`` over every non-prior measurement of the pass ``p``
    (a :class:`fgnav.measurements.Pass`), with ``sol.x_eci`` / ``sol.P_eci`` at ``p``'s epochs.
    """
    out, dofs = [], []
    for kind in p.families:
        if kind in PRIOR_KINDS or not enters(p, kind) or model_of(kind).between:
            continue
        k, A, b = _family_rows(p, kind, sol.x_eci, sol.variables)
        r = -b
        S = np.eye(A.shape[1])[None] - np.einsum("mij,mjl,mkl->mik", A, sol.P_eci[k], A)
        out.append(np.einsum("mi,mi->m", r, np.linalg.solve(S, r[..., None])[..., 0]))
        dofs.append(np.full(len(k), A.shape[1]))
    if not out:
        return np.zeros(0), np.zeros(0, int)
    return np.concatenate(out), np.concatenate(dofs)


def nis_ekf(p, sol, options) -> tuple[np.ndarray, np.ndarray]:
    """NIS of an EKF solution, per epoch with measurements (module doc).

    The predicted state of epoch k is the filtered state of k-1 propagated with the same
    motion model and process noise as :func:`fgnav.solvers.ekf.run_ekf` (``options`` is its
    :class:`~fgnav.solvers.options.SmootherOptions`); all of epoch k's measurement rows form one
    joint innovation. Returns ``(nis (K,), dof (K,))`` over epochs 1..N-1 that carry data.
    """
    model = options.motion_model()
    t0 = float(j2000_seconds(p.epoch0))
    N = p.n_epochs
    Xp = np.empty((N, 6))
    Pp = np.empty((N, 6, 6))
    Xp[0], Pp[0] = sol.x_eci[0], sol.P_eci[0]
    for k in range(1, N):
        dt = p.t_s[k] - p.t_s[k - 1]
        x, Phi = propagate(sol.x_eci[k - 1], dt, model, t0 + p.t_s[k - 1])
        Xp[k] = x
        Pp[k] = Phi @ sol.P_eci[k - 1] @ Phi.T + process_noise(dt, options.q_m2_s3)
    A_by_k: dict[int, list] = {}
    b_by_k: dict[int, list] = {}

    for kind in p.families:
        if kind in PRIOR_KINDS or not enters(p, kind) or model_of(kind).between:
            continue
        k, A, b = _family_rows(p, kind, Xp, sol.variables)
        for j in range(len(k)):
            A_by_k.setdefault(int(k[j]), []).append(A[j])
            b_by_k.setdefault(int(k[j]), []).append(b[j])
    nis, dof = [], []
    for k in sorted(A_by_k):
        if k == 0:
            continue
        A = np.concatenate(A_by_k[k])
        b = np.concatenate(b_by_k[k])
        S = A @ Pp[k] @ A.T + np.eye(len(b))
        nis.append(float(b @ np.linalg.solve(S, b)))
        dof.append(len(b))
    return np.asarray(nis), np.asarray(dof, int)


def nis_summary(nis: np.ndarray, dof: np.ndarray, alpha: float = 0.05) -> dict:
    """Mean NIS per degree of freedom and its band: ``sum nis ~ chi2(sum dof)`` if the
    values are independent (true for EKF innovations; approximately for smoother residuals)."""
    nis = np.asarray(nis, float)
    dof = np.asarray(dof, float)
    if len(nis) == 0:
        return {"nis_per_dof": float("nan"), "nis_band_lo": float("nan"),
                "nis_band_hi": float("nan"), "nis_n": 0}
    total = float(dof.sum())
    lo, hi = chi2_band(total, 1, alpha)
    return {"nis_per_dof": float(nis.sum() / total), "nis_band_lo": lo / total,
            "nis_band_hi": hi / total, "nis_n": int(len(nis))}
