"""Cramér–Rao bound of a pass and observability of its initial state.

With deterministic dynamics, every measurement row ``a_j^T dx_{k(j)}`` (whitened) maps to
the state at the first epoch through the state transition matrix, ``a_j^T Phi(t_k, t_0)``.
The Fisher information of the initial state is

    J_0 = sum_j Phi_k^T a_j a_j^T Phi_k          (priors included as rows),

and the bound on the state at epoch k is ``Phi_k J_0^-1 Phi_k^T``. Evaluated along a
trajectory (the truth when known, else the estimate). The measurement-only part of ``J_0``
(priors left out) tells whether the log observes the orbit at all.
"""

from __future__ import annotations

import threading
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
from factors.jit import njit

from factors.interpret import run

from factors.dynamics import MotionModel, propagate_many
from fgnav.errors import NotObservableError
from fgnav.graph import PRIOR_KINDS, Rows, linearize_all
from fgnav.measurements import Pass, slice_pass
from fgnav.time import j2000_seconds

#: epochs (or rows) per chunk where per-epoch 6x6 matrices are formed: a (CHUNK, 6, 6)
#: float64 array is 19 MB, where the whole of a 1,000,000-epoch pass would be 288 MB each
CHUNK = 65536

@njit(cache=True)
def cumulative_stm(Phi_steps):
    """Phi(t_k, t_0) for every k from the per-step STMs (N-1,6,6) -> (N,6,6)."""
    n = Phi_steps.shape[0] + 1
    out = np.empty((n, 6, 6))
    out[0] = np.eye(6)
    for k in range(1, n):
        out[k] = Phi_steps[k - 1] @ out[k - 1]
    return out


@njit(cache=True)
def accumulate_stm(Phik):
    """:func:`cumulative_stm` in place: ``Phik`` (N,6,6) holds the step STMs at 1..N-1 and
    leaves with Phi(t_k, t_0) at every k (the same products, bit for bit)."""
    Phik[0] = np.eye(6)
    for k in range(1, Phik.shape[0]):
        Phik[k] = Phik[k] @ Phik[k - 1]


@dataclass
class CrbResult:
    P_eci: np.ndarray | None      # (N,6,6) bound on the state at every epoch (keep_covariance)
    position_rms_m: float         # sqrt(mean_k trace(P_rr))
    velocity_rms_mps: float
    final_position_m: float
    final_velocity_mps: float
    J0_measurements: np.ndarray   # (6,6) information of the first state from measurements only
    J0_geometry: np.ndarray | None = None  # (6,6) the same with every row scaled to unit norm
    position_var_m2: np.ndarray | None = None     # (N,) trace of the position block of P
    velocity_var_m2s2: np.ndarray | None = None   # (N,) trace of the velocity block of P


def _scaled_inverse(J: np.ndarray) -> np.ndarray:
    s = 1.0 / np.sqrt(np.maximum(np.diag(J), 1e-300))
    Js = J * s[:, None] * s[None, :]
    return np.linalg.inv(Js) * s[:, None] * s[None, :]


_kept = threading.local()


@contextmanager
def mapping_shared():
    """Within the block, the first :func:`rows_at_first_state` without rejected rows is kept
    and handed, once, to the next call for the same pass, states and model instead of being
    computed again (the Cramer-Rao bound and the integrity tests of one solution map the
    same rows: 1,000,000 epochs, ~1.7 s); dropped at the end of the block."""
    _kept.on, _kept.value = True, None
    try:
        yield
    finally:
        _kept.on, _kept.value = False, None


def rows_at_first_state(p: Pass, X_ref: np.ndarray, model: MotionModel, rejected=None):
    """Every whitened row of the pass linearized along ``X_ref`` (N, 6), or block values
    (N, n) with the pass's further variables, and mapped to the
    first state through the cumulative STM, ``G_j = a_j^T Phi(t_k, t_0)``.

    Returns ``(Phik (N,6,6), G (R,6), rows)`` with ``rows`` the
    :class:`fgnav.graph.Rows` (``rejected``: kind -> (M,) bool rows given zero weight).
    A pass with graph variables beyond the orbit (a bias) is bounded with them known: their
    columns and priors are left out, so the bound is the orbit's with a perfectly known bias
    (a lower bound of the bound with the bias estimated). The arrays are not to be written
    to: inside :func:`mapping_shared` a second caller may receive the same ones.
    """
    kept = getattr(_kept, "value", None)
    if kept is not None and rejected is None:
        p_kept, X_kept, model_kept, result = kept
        if p_kept is p and model_kept == model and np.array_equal(X_kept, X_ref):
            _kept.on, _kept.value = False, None   # handed over: nothing more is kept
            return result
    result = _rows_at_first_state(p, X_ref, model, rejected)
    if getattr(_kept, "on", False) and kept is None and rejected is None:
        _kept.value = (p, X_ref, model, result)
    return result


def _rows_at_first_state(p: Pass, X_ref: np.ndarray, model: MotionModel, rejected=None):
    t0 = float(j2000_seconds(p.epoch0))
    if p.n_epochs > 1:
        # the step STMs written into Phik[1:] and accumulated in place: one (N,6,6) array
        Phik = np.empty((p.n_epochs, 6, 6))
        propagate_many(X_ref[:-1, :6], np.diff(p.t_s), model, t0 + p.t_s[:-1],
                       stm_out=Phik[1:])
        run(accumulate_stm, Phik)
    else:
        Phik = np.eye(6)[None]
    rows = linearize_all(p, X_ref, None, rejected)
    if rows.A.shape[1] > 6:
        keep = np.isin(rows.row_kind, [f"prior_{v.name}" for v in p.layout.extra], invert=True)
        rows = Rows(rows.k[keep], rows.A[keep, :6], rows.b[keep], rows.residuals,
                    rows.row_kind[keep], rows.weights)
    # in chunks of rows: Phik[rows.k] of every row at once is (R, 6, 6)
    G = np.empty((len(rows.k), 6))
    for a in range(0, len(rows.k), CHUNK):
        G[a:a + CHUNK] = np.einsum("ri,rij->rj", rows.A[a:a + CHUNK], Phik[rows.k[a:a + CHUNK]])
    return Phik, G, rows


def cramer_rao_bound(p: Pass, X_ref: np.ndarray, model: MotionModel = MotionModel(),
                     keep_covariance: bool = False) -> CrbResult:
    """The bound along ``X_ref`` (N,6), see the module docstring. The (N,6,6) bounds are
    formed in chunks of epochs and kept (``P_eci``) only with ``keep_covariance``; the
    traces of their position (m^2) and velocity (m^2/s^2) blocks always are."""
    Phik, G, rows = rows_at_first_state(p, X_ref, model)
    meas = _measurement_rows(rows)
    del rows   # the rows and G are not needed for the bounds (1,000,000 epochs: ~0.4 GB)
    J0 = G.T @ G
    J0_meas, J0_geom = _measurement_information(G, meas)
    del G
    C0 = _scaled_inverse(J0)
    n = len(Phik)
    P = np.empty((n, 6, 6)) if keep_covariance else None
    var_r, var_v = np.empty(n), np.empty(n)
    for a in range(0, n, CHUNK):
        Ph = Phik[a:a + CHUNK]
        PhC = Ph @ C0
        # the traces of the position and velocity blocks of Phi C0 Phi^T: the rows' dot
        # products of Phi C0 with Phi, without the (6, 6) products
        d = np.sum(PhC * Ph, axis=2)
        var_r[a:a + CHUNK] = d[:, :3].sum(axis=1)
        var_v[a:a + CHUNK] = d[:, 3:].sum(axis=1)
        if P is not None:
            P[a:a + CHUNK] = PhC @ np.swapaxes(Ph, 1, 2)
    del Phik
    return CrbResult(P_eci=P, position_rms_m=float(np.sqrt(var_r.mean())),
                     velocity_rms_mps=float(np.sqrt(var_v.mean())),
                     final_position_m=float(np.sqrt(var_r[-1])),
                     final_velocity_mps=float(np.sqrt(var_v[-1])), J0_measurements=J0_meas,
                     J0_geometry=J0_geom, position_var_m2=var_r, velocity_var_m2s2=var_v)


def _measurement_rows(rows: Rows) -> np.ndarray:
    """(R,) bool: the rows of measurements (not of priors)."""
    return ~np.isin(rows.row_kind, PRIOR_KINDS)


def _measurement_information(G: np.ndarray, meas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The information (6,6) of the first state from the measurement rows ``meas`` of ``G``
    (R,6), and the same with every row scaled to unit norm (its geometry)."""
    Gm = G[meas]
    J0_meas = Gm.T @ Gm
    norm = np.linalg.norm(Gm, axis=1)
    Gu = Gm[norm > 0]
    del Gm
    Gu /= norm[norm > 0, None]
    return J0_meas, Gu.T @ Gu


OBSERVABILITY_HEAD = 4096
"""Epochs at the start of a long pass tried first by :func:`check_observability`."""


def check_observability(p: Pass, X_ref: np.ndarray, model: MotionModel = MotionModel(),
                        max_condition: float = 1e12) -> float:
    """Raise NotObservableError when the measurements alone leave a direction of the first
    state unobserved; return the (scaled) condition number of their information.

    The test is on the geometry of the rows, each scaled to unit norm: whether the rows span
    the six directions does not depend on their weights, and weights that differ by 1e12
    (one measurement with sigma 1e-12) would otherwise make a well-observed orbit look
    singular. A long pass is tried on its first :data:`OBSERVABILITY_HEAD` epochs first:
    information only grows with rows, so rows that span the six directions there span them
    in the whole pass (returned: the condition number of the head's rows); only a head that
    does not observe the orbit costs the whole pass's test (2.5 s of 1,000,000 epochs)."""
    if p.n_epochs > OBSERVABILITY_HEAD:
        head = slice_pass(p, 0, OBSERVABILITY_HEAD)[0]
        try:
            return check_observability(head, X_ref[:OBSERVABILITY_HEAD], model, max_condition)
        except NotObservableError:
            pass
    # the geometry of the measurement rows only: not the bounds at every epoch (on a
    # 1,000,000-epoch pass their (N,6,6) products took ~2 s here, then again in the summary)
    G, rows = rows_at_first_state(p, X_ref, model)[1:]   # the STMs (N,6,6) freed at once
    meas = _measurement_rows(rows)
    del rows
    J = _measurement_information(G, meas)[1]
    del G
    s = 1.0 / np.sqrt(np.maximum(np.diag(J), 1e-300))
    w, V = np.linalg.eigh(J * s[:, None] * s[None, :])
    cond = float(w[-1] / max(w[0], 1e-300)) if w[-1] > 0 else np.inf
    if not np.isfinite(cond) or cond > max_condition:
        weakest = V[:, 0] * s
        weakest /= np.linalg.norm(weakest)
        names = ["x", "y", "z", "vx", "vy", "vz"]
        parts = ", ".join(f"{c:+.2f} {n}" for c, n in zip(weakest, names) if abs(c) > 0.1)
        raise NotObservableError(
            f"{p.source}: the measurements ({p.counts()}) over {p.n_epochs} epochs "
            f"({p.t_s[-1] - p.t_s[0]:.0f} s) do not observe the orbit: the information of the "
            f"initial state has condition number {cond:.2e}; weakest direction ~ {parts}. "
            f"Add measurements (more epochs, a longer arc, range-type data).")
    return cond
