"""The least squares of initial orbit determination: the two small dense fitters and the
6-state fit on a pass's rows that every IOD method ends with.

Two algorithms, kept apart because they are not the same and merging them would change
the numbers they give:

* :func:`levenberg_marquardt`: damped Gauss-Newton on ``min |r(x)|^2`` with the normal
  matrix scaled to unit diagonal, ``(D^-1 N D^-1 + lambda I) D dx = -D^-1 A^T r``
  (Levenberg 1944; Marquardt 1963; Nocedal & Wright 2006, sec. 10.3), ``lambda`` divided
  by 10 after a step that lowers the cost, multiplied by 10 after one that does not. The
  orbit fits (:func:`fit_orbit`) use it: a start from the angles or from Gibbs may be far.
* :func:`gauss_newton_halving`: undamped Gauss-Newton steps, each halved until the cost
  does not grow (Nocedal & Wright 2006, sec. 10.3, with a backtracking line search,
  sec. 3.1), stepping around the models' domains (``ModelDomainError``). The position
  surfaces of one epoch (:mod:`fgnav.iod.surfaces`) use it: three unknowns, many starts.

:func:`fit_orbit` is the refinement of every method (:mod:`fgnav.iod.angles`,
:mod:`fgnav.iod.geometric`): the 6-state at ``t_ref`` fitted to the whitened residuals of a
(sub)pass's rows, through the smoothers' own linearizers (:func:`fgnav.graph.linearize_all`)
and propagator (:func:`factors.dynamics.propagate_through`, with the exact STM).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factors.dynamics import propagate_many, propagate_through
from factors.errors import ModelDomainError
from fgnav.graph import linearize_all
from fgnav.measurements import Pass

__all__ = ["InitialOrbit", "levenberg_marquardt", "gauss_newton_halving", "trajectory_stm",
           "linearize_orbit", "fit_orbit", "fit_covariance"]


@dataclass(frozen=True)
class InitialOrbit:
    """An orbit determined from the measurements alone.

    k_ref : epoch index (in the pass) of the state.
    x_eci : (6,) state ``[r_eci_m, v_eci_mps]`` at ``t_s[k_ref]``.
    P_eci : (6, 6) its covariance (SI), from the fit's information (:func:`fit_covariance`).
    method : how the start was found, e.g. ``"angles-kepler+lm"`` or ``"gibbs+lm"``.
    n_used : epochs of the subsample the fit used.
    rms_whitened : RMS of the whitened residual rows at the fit (about 1 when it fits).
    t_span_s : first and last epoch (s from epoch0) of the session the fit used.
    """

    k_ref: int
    x_eci: np.ndarray
    P_eci: np.ndarray
    method: str
    n_used: int
    rms_whitened: float
    t_span_s: tuple[float, float] = (0.0, 0.0)  # first and last epoch (s) of the data used


def levenberg_marquardt(linearize, x0, max_iterations=60):
    """Least squares ``min |r(x)|^2`` by Levenberg-Marquardt (module docstring).

    ``linearize(x) -> (r (R,), A (R, n))`` the residual and its Jacobian, or None where
    they cannot be formed (the step is then refused). Returns ``(x, r, A, cost)`` at the
    last accepted point, or None when ``x0`` itself cannot be linearized. Stops when no
    damping in 12 tries lowers the cost or the cost falls by less than ``1e-10`` of
    itself.
    """
    lin = linearize(x0)
    if lin is None:
        return None
    x = np.asarray(x0, dtype=float)
    r, A = lin
    cost = float(r @ r)
    eye = np.eye(len(x))
    lam = 1e-3
    for _ in range(max_iterations):
        N = A.T @ A
        g = A.T @ r
        d = np.sqrt(np.maximum(np.diag(N), 1e-300))
        Ns = N / np.outer(d, d)
        improved = False
        for _ in range(12):
            try:
                dx = -np.linalg.solve(Ns + lam * eye, g / d) / d
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            new = linearize(x + dx)
            if new is not None and float(new[0] @ new[0]) < cost:
                x = x + dx
                r, A = new
                old, cost = cost, float(new[0] @ new[0])
                lam = max(lam / 10.0, 1e-12)
                improved = True
                break
            lam *= 10.0
        if not improved or old - cost < 1e-10 * max(old, 1.0):
            break
    return x, r, A, cost


def gauss_newton_halving(residual, x0, max_iter, tol):
    """Gauss-Newton with step halving (module docstring) from ``x0`` (n,).

    ``residual(x) -> (b (m,), A (m, n))``, raising ``ModelDomainError`` outside a model's
    domain (the step is then halved). Stops after ``max_iter`` steps, when a step shorter
    than ``tol`` (the unit of ``x``) is taken, or when no step down to 1e-6 of the full one
    keeps the cost from growing. Returns ``(x, cost, A)``, or None when ``x0`` is outside
    the domain.
    """
    r = np.array(x0, dtype=float)
    try:
        b, A = residual(r)
    except ModelDomainError:
        return None
    cost = float(b @ b)
    for _ in range(max_iter):
        dx, *_ = np.linalg.lstsq(A, -b, rcond=None)
        step = 1.0
        while step > 1e-6:
            try:
                b_new, A_new = residual(r + step * dx)
            except ModelDomainError:
                step *= 0.5
                continue
            if float(b_new @ b_new) <= cost * (1 + 1e-12):
                break
            step *= 0.5
        else:
            break
        r = r + step * dx
        b, A = b_new, A_new
        cost = float(b @ b)
        if np.linalg.norm(step * dx) < tol:
            break
    return r, cost, A


def trajectory_stm(x_ref, t_ref, t_sub, model, t0_j2000_s):
    """States (M,6) at ``t_sub`` (sorted) and their STMs (M,6,6) with respect to x_ref.

    The states are carried from epoch to epoch outward from ``t_ref``
    (:func:`factors.dynamics.propagate_through`), then every step's STM is formed at once
    (:func:`factors.dynamics.propagate_many`) and accumulated: the same steps as one
    :func:`factors.dynamics.propagate` per epoch, but without a Python call per sub-step
    where the kernels run as Python (a short pass's initial orbit: 289 epochs 300 s apart,
    23 trajectories, 20 s -> 0.5 s)."""
    t_sub = np.asarray(t_sub, dtype=float)
    M = len(t_sub)
    i0 = int(np.searchsorted(t_sub, t_ref))
    t_all = np.insert(t_sub, i0, t_ref)   # x_ref's epoch among them, at index i0
    X_all = propagate_through(np.asarray(x_ref, dtype=float), t_all, i0, model, t0_j2000_s)
    # steps outward: forward from i0 to the end, backward from i0 to the start
    fwd, bwd = np.arange(i0, M), np.arange(i0, 0, -1)
    src = np.concatenate([fwd, bwd])
    dst = np.concatenate([fwd + 1, bwd - 1])
    S = propagate_many(X_all[src], t_all[dst] - t_all[src], model, t0_j2000_s + t_all[src])[1]
    F_all = np.empty((M + 1, 6, 6))
    F_all[i0] = np.eye(6)
    for j, (a, b) in enumerate(zip(src.tolist(), dst.tolist())):
        F_all[b] = S[j] @ F_all[a]
    keep = np.arange(M + 1) != i0
    return X_all[keep], F_all[keep]


def linearize_orbit(sp: Pass, x_ref, t_ref, model, t0_j2000_s):
    """Whitened residual (R,) and Jacobian (R,6) of the rows of ``sp`` with respect to the
    6-state ``x_ref`` at ``t_ref``, or None where the orbit or its rows cannot be formed."""
    X, Phi = trajectory_stm(x_ref, t_ref, sp.t_s, model, t0_j2000_s)
    if not np.all(np.isfinite(X)) or np.min(np.linalg.norm(X[:, :3], axis=1)) < 1.0e6:
        return None
    try:
        rows = linearize_all(sp, X)
    except (ValueError, FloatingPointError, ZeroDivisionError):
        return None
    A = np.einsum("ri,rij->rj", rows.A, Phi[rows.k])
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(rows.b))):
        return None
    return -rows.b, A


def fit_orbit(sp: Pass, x0, t_ref, model, t0_j2000_s, max_iterations=60):
    """Least squares of the whitened residuals of ``sp`` over the 6-state at ``t_ref``
    (:func:`levenberg_marquardt` on :func:`linearize_orbit`): ``(x, r, A, cost)`` or None."""
    return levenberg_marquardt(lambda x: linearize_orbit(sp, x, t_ref, model, t0_j2000_s),
                               x0, max_iterations)


def fit_covariance(A, rms):
    """The fit's covariance ``(A^T A)^-1`` (inverted with its diagonal scaled to one),
    symmetrized and scaled by ``rms^2`` when that exceeds 1 (a model that does not fit to
    the noise). Raises ``numpy.linalg.LinAlgError`` when ``A^T A`` is singular."""
    N = A.T @ A
    d = np.sqrt(np.maximum(np.diag(N), 1e-300))
    P = np.linalg.inv(N / np.outer(d, d)) / np.outer(d, d)
    return 0.5 * (P + P.T) * max(1.0, rms ** 2)
