"""The classical baseline: an extended Kalman filter over the same models.

Prediction with the motion model's propagation and STM and the white-acceleration
process noise, ``P <- Phi P Phi^T + Q(dt)``; update with the same whitened measurement rows
the smoothers use (the measurement models, ``fgnav.graph.linearize_family``): with whitened
rows ``A dx ~ b`` the measurement noise is the identity, ``K = P A^T (A P A^T + I)^-1``,
Joseph-form covariance (both steps: :mod:`fgnav.solvers.kalman`). Graph variables beyond
the orbit state (a bias, an attitude) augment the state, their prior is the initial
covariance; a rotation's error is its right perturbation ``R = R_hat Exp(delta)`` (the
multiplicative EKF: Markley 2003, "Attitude error representations for Kalman filtering",
JGCD 26(2)). Between epochs they follow their process model (a random walk, Maybeck 1979,
vol. 1, sec. 4.10: mean held, variance ``+ psd dt``) and the rows between two epochs (a
rate-gyro interval), see :func:`propagate_variables`: the gyro propagates the attitude
``R_k = R_{k-1} Exp((omega - b) dt)``, its noise the process noise, its bias part of the
state.
"""

from __future__ import annotations

import time

import numpy as np

from factors.dynamics import propagate
from factors.errors import ModelDomainError
from fgnav.io.log_spacecraft import ISL_KINDS
from fgnav.errors import UserError
from fgnav.graph import (enters, impulses, initial_block, layout_of, linearize_family,
                         prior_block_covariance, process_rows)
from fgnav.measurements import Pass, prior_covariance, rows_by_epoch
from fgnav.models.registry import model as model_of
from fgnav.robust import passes_gate
from fgnav.solution import Solution
from fgnav.iod.prior import first_state
from fgnav.solvers.kalman import kalman_update, orbit_transition, predict_covariance
from fgnav.solvers.options import SmootherOptions
from fgnav.solvers.state_elements import chart_of
from fgnav.solvers.variables import block_variables
from fgnav.time import add_seconds, format_utc, j2000_seconds


class _Burns:
    """The declared manoeuvres' delta-v as further EKF states, carried beside the block:
    their means ``w`` (B, 3), covariances ``Pww`` (B, 3, 3) and cross-covariances with the
    block ``C`` (B, 3, n). A burn joins at its step's prediction with ``w = planned``,
    ``Pww = S``, ``C = S [0 I 0]`` (the impulse is the velocity's added noise); each
    prediction maps ``C <- C F^T``, each update with the block's gain ``K``, rows ``A``,
    innovation covariance ``Sy`` and whitened residual ``b`` gives ``K_w = C A^T Sy^-1``,
    ``w += K_w b``, ``Pww -= K_w Sy K_w^T``, ``C -= K_w A P`` (the augmented-state EKF's
    update restricted to the burns' rows: Bar-Shalom, Li & Kirubarajan 2001, sec. 5.2)."""

    def __init__(self, p: Pass, n: int):
        fam = p.manoeuvres
        self.fam = fam
        self.by_k = {}
        if fam is not None:
            for j, k in enumerate(np.asarray(fam.k, int).tolist()):
                self.by_k.setdefault(k, []).append(j)
        B = 0 if fam is None else len(fam)
        self.w = np.zeros((B, 3))
        self.Pww = np.zeros((B, 3, 3))
        self.C = np.zeros((B, 3, n))
        self.active = np.zeros(B, bool)

    def predict(self, F, k):
        """Map the cross-covariances through the step's transition ``F`` (n, n), then add
        the burns of step ``k - 1 -> k``."""
        if self.active.any():
            self.C[self.active] = self.C[self.active] @ F.T
        for j in self.by_k.get(k, ()):
            Sj = np.eye(3) * float(self.fam.sigma[j]) ** 2
            self.w[j] = self.fam.values["dv_mps"][j]
            self.Pww[j] = Sj
            self.C[j] = 0.0
            self.C[j][:, 3:6] = Sj
            self.active[j] = True

    def update(self, A, b, Sy, P_prior):
        if not self.active.any():
            return
        a = self.active
        Kw = np.linalg.solve(Sy, A @ np.swapaxes(self.C[a], 1, 2)).transpose(0, 2, 1)
        self.w[a] += Kw @ b
        self.Pww[a] -= Kw @ Sy @ np.swapaxes(Kw, 1, 2)
        self.C[a] -= Kw @ (A @ P_prior)

    def summary(self, p: Pass) -> list:
        """summary.json's ``manoeuvres`` (:func:`fgnav.graph.impulse_estimates`' keys)."""
        out = []
        if self.fam is None:
            return out
        for j in np.argsort(np.asarray(self.fam.line), kind="stable").tolist():
            k = int(self.fam.k[j])
            Cov = 0.5 * (self.Pww[j] + self.Pww[j].T)
            out.append({"epoch": format_utc(add_seconds(p.epoch0, float(p.t_s[k]))),
                        "t_s": float(p.t_s[k]), "line": int(self.fam.line[j]),
                        "planned_mps": [float(v) for v in self.fam.values["dv_mps"][j]],
                        "estimated_mps": [float(v) for v in self.w[j]],
                        "sigma_mps": [float(v) for v in np.sqrt(np.maximum(np.diag(Cov), 0))],
                        "covariance_m2_s2": [[float(v) for v in row] for row in Cov]})
        return out


def run_ekf(p: Pass, options: SmootherOptions = SmootherOptions(), *, progress=None,
            x_start: np.ndarray | None = None, P_start: np.ndarray | None = None) -> Solution:
    """Filter the pass forward; ``x_eci``/``P_eci`` are the filtered (a-posteriori) states.

    ``x_start`` (n,), ``P_start`` (n, n): the first epoch's block and covariance (a
    formation's: every spacecraft's prior, :func:`fgnav.start.start_covariance`); default the
    log's prior and the further variables' priors."""
    t_start = time.perf_counter()
    model = options.motion_model()
    t0_j2000 = float(j2000_seconds(p.epoch0))
    N = p.n_epochs
    per_epoch = rows_by_epoch(p)
    if len(p.layout.orbits) > 1:   # the links first: see relative_coordinates
        per_epoch = [sorted(rows, key=lambda kr: kr[0] not in ISL_KINDS) for rows in per_epoch]
    lay = layout_of(p)
    n = lay.n
    between = {kind for kind in p.families if enters(p, kind) and model_of(kind).between}
    if between and not lay.extra:
        raise UserError(f"{p.source}: {', '.join(sorted(between))} rows join two epochs through "
                        f"further variables, and none is estimated")
    if x_start is not None:
        x, P = np.array(x_start, dtype=float), np.array(P_start, dtype=float)
    else:
        x0 = first_state(p, model, t0_j2000)
        x = initial_block(p, np.broadcast_to(x0, (N, 6)))[0][0]
        P = prior_block_covariance(lay, [prior_covariance(p)])
    chart = chart_of(options)   # the orbit's coordinates when not Cartesian (--state elements)
    if chart is not None:
        chart.check_filter_start(x)
        P = chart.covariance_from_cartesian(x, P)
    imp = impulses(p)
    if imp and (chart is not None or len(lay.orbits) > 1):
        raise UserError(f"{p.source}: manoeuvre rows with "
                        + ("--state elements" if chart is not None else "several spacecraft")
                        + ": the EKF puts a burn into the Cartesian orbit of one spacecraft")
    burns = _Burns(p, n)
    T, T_inv = relative_coordinates(lay)
    if T is not None:   # several spacecraft: P of (x_1, x_s - x_1), see relative_coordinates
        P = T @ P @ T.T
    xs = np.empty((N, n))
    Ps = np.empty((N, n, n))
    latency = np.empty(N)
    x_prev = x

    def retract(x, dx):   # an update in the filter's coordinates applied to the block
        dx = dx if T is None else T_inv @ dx
        return lay.retract(x, dx) if chart is None else chart.retract(lay, x, dx)

    residuals: dict[str, np.ndarray] = {}  # innovations, whitened, in family row order
    rejected: dict[str, int] = {}
    weights: dict[str, np.ndarray] = {}  # kind -> (M,) 0 where the gate rejected the row
    normalized: dict[str, np.ndarray] = {}  # innovations whitened by their covariance L^-1 b
    for k in range(N):
        t_k0 = time.perf_counter()
        if k > 0:
            dt = p.t_s[k] - p.t_s[k - 1]
            x = x.copy()
            x[:6], Phi6, Q6 = orbit_transition(x[:6], dt, options.q_m2_s3, model,
                                               t0_j2000 + p.t_s[k - 1])
            if chart is not None:
                Phi6, Q6 = chart.transition(x_prev[:6], x[:6], Phi6, Q6)
            if len(lay.orbits) > 1:   # a formation: every orbit, the clocks, the ambiguities
                x, F, Q = _propagate_formation(lay, x, Phi6, Q6, dt, model,
                                               t0_j2000 + p.t_s[k - 1])
                F = T @ F @ T_inv
                P = predict_covariance(P, F, T @ Q @ T.T)
            elif lay.extra:
                rows_k = [(kind, rows) for kind, rows in per_epoch[k] if kind in between]
                if burns.active.any():   # (the burns' cross-covariance: orbit and held variables)
                    F = np.eye(n)
                    F[:6, :6] = Phi6
                    burns.predict(F, -1)
                x, P, r_between = propagate_variables(p, lay, x_prev, x, P, Phi6, Q6, dt, rows_k)
                for kind, j, r in r_between:
                    if kind not in residuals:
                        residuals[kind] = np.full((len(p.families[kind]), r.shape[1]), np.nan)
                    residuals[kind][j] = r
            else:
                P = predict_covariance(P, Phi6, Q6)
                burns.predict(Phi6, -1)
            if k in imp:   # a declared burn ends this step: x += [0; dv], P += [0, 0; 0, S]
                mean, cov = imp[k]
                x[:6] += mean
                P[:6, :6] += cov
                burns.predict(np.eye(n), k)
        for kind, rows in per_epoch[k]:
            if not enters(p, kind) or kind in between:
                continue   # (rows between two epochs: in the propagation above)
            mdl = model_of(kind)
            if mdl.prior and k == 0:
                continue  # the initial state already is this prior
            fam = p.families[kind]
            for j in rows:  # one measurement at a time: gating decides each
                _, A, b, _ = linearize_family(p, kind, fam.subset(np.array([j]), 0), x[None])
                A = A.reshape(-1, n)
                b = b.reshape(-1)
                if chart is not None:
                    A = chart.chain(A, chart.jacobian(x))
                if T is not None:
                    A = A @ T_inv
                if kind not in residuals:
                    residuals[kind] = np.full((len(fam), len(b)), np.nan)
                residuals[kind][j] = -b
                if options.gate_probability is not None and mdl.robust:
                    ok, S = passes_gate(A, b, P, options.gate_probability)
                    if not ok:
                        rejected[kind] = rejected.get(kind, 0) + 1
                        weights.setdefault(kind, np.ones(len(fam)))[j] = 0.0
                        continue
                else:
                    S = None
                if burns.active.any():   # (before the update: the prior P and S)
                    burns.update(A, b, A @ P @ A.T + np.eye(len(b)) if S is None else S, P)
                try:
                    x, P, nu = kalman_update(x, P, A, b, S=S, retract=retract)
                except ModelDomainError as exc:   # the element chart's (--state elements)
                    raise ModelDomainError(f"{kind} row at log line {int(fam.line[j])}: "
                                           f"{exc}") from exc
                if kind not in normalized:
                    normalized[kind] = np.full((len(fam), len(b)), np.nan)
                normalized[kind][j] = nu
        xs[k] = x
        Ps[k] = P if chart is None else chart.covariance_to_cartesian(x, P)
        if T is not None:
            Ps[k] = T_inv @ P @ T_inv.T
        x_prev = x
        latency[k] = time.perf_counter() - t_k0
        if progress is not None:
            progress(k)
    wall = time.perf_counter() - t_start
    res = residuals
    return Solution(method="ekf", epoch0=p.epoch0, t_s=p.t_s.copy(), x_eci=xs[:, :6],
                    P_eci=Ps[:, :6, :6], variables=block_variables(lay, xs, Ps),
                    P_block=Ps if lay.extra else None, iterations=N, chi2=float(sum(np.nansum(r * r) for r in res.values())),
                    wall_s=wall, residuals=res, online_x_eci=xs[:, :6].copy(),
                    online_P_eci=Ps[:, :6, :6].copy(),
                    latency_s=latency,
                    extras={"q_m2_s3": options.q_m2_s3, "residuals_are": "innovations (prior)",
                            **({"online_variables": {
                                v.name: (xs[:, lay.slices[v.name]].copy(),
                                         Ps[:, lay.slices[v.name], lay.slices[v.name]].copy())
                                for v in lay.orbits[1:]}} if len(lay.orbits) > 1 else {}),
                            "normalized_innovations": normalized,
                            **({"manoeuvres": burns.summary(p)} if imp else {}),
                            **({"gate_probability": options.gate_probability, "rejected": rejected,
                                "row_weights": weights}
                               if options.gate_probability is not None else {}),
                            "latency_p50_s": float(np.median(latency))})


def relative_coordinates(lay):
    """``(T, T^-1)`` (n, n) taking a formation's block to the coordinates the filter's
    covariance is kept in: the first orbit ``x_1`` and every further one relative to it,
    ``x_s - x_1`` (the rest unchanged); ``(None, None)`` for one spacecraft. Km-sigma
    absolute orbits whose difference the links know to centimetres make ``P`` of the
    absolute states nearly singular: a link row's ``A P A^T`` is then a difference of
    terms 1e10 times its value and lost positive definiteness to rounding (a 2 h
    formation-gto pass: ``LinAlgError`` in the Cholesky factor of the innovation
    covariance). In these coordinates a link's Jacobian ``A T^-1`` has no absolute part:
    the same filter (a linear change of variables, Bar-Shalom, Li & Kirubarajan 2001), its
    covariance well conditioned."""
    if len(lay.orbits) < 2:
        return None, None
    T, T_inv = np.eye(lay.n), np.eye(lay.n)
    s0 = lay.slices[lay.orbits[0].name]
    for v in lay.orbits[1:]:
        sl = lay.slices[v.name]
        T[sl, s0] = -np.eye(6)
        T_inv[sl, s0] = np.eye(6)
    return T, T_inv


def _propagate_formation(lay, x, Phi6, Q6, dt, model, t_j2000_s):
    """A formation's prediction step: each further spacecraft's orbit propagated with its
    STM and the same white-acceleration noise as the first's (``x[:6]``, already propagated
    with ``Phi6``), every other variable a random walk (variance ``+ psd dt``): ``(x, F, Q)``,
    the block's transition and process noise (``P -> F P F^T + Q``)."""
    n = lay.n
    F = np.eye(n)
    Q = np.zeros((n, n))
    F[:6, :6], Q[:6, :6] = Phi6, Q6
    for v in lay.orbits[1:]:
        sl = lay.slices[v.name]
        x[sl], F[sl, sl] = propagate(x[sl], dt, model, t_j2000_s)
        Q[sl, sl] = Q6
    for v in lay.parameters:
        sl = lay.slices[v.name]
        Q[sl, sl] = v.process.step_covariance(v, dt)
    return x, F, Q


def propagate_variables(p: Pass, lay, x0, x1, P0, Phi6, Q6, dt, rows_k, iterations=4):
    """One step of the augmented filter from epoch ``k - 1`` to ``k``.

    ``x0`` (n,) and ``P0`` (n, n): the filtered block and covariance at ``k - 1``; ``x1``
    (n,): the block at ``k`` with the orbit already propagated (``Phi6``, ``Q6``: its STM and
    process noise); ``rows_k``: (kind, rows) of the between-epoch families whose rows end
    at ``k`` (a gyro interval). Returns ``(x1, P1, residuals)``, ``residuals`` a list of
    ``(kind, rows, whitened residual (M, m))`` at the propagated block.

    The further variables' process rows (:func:`fgnav.graph.process_rows`,
    the same as the smoothers') and the between rows, whitened as ``A0 d0 + A1 d1 - b ~
    N(0, I)`` in the tangent errors ``d0`` (epoch ``k - 1``) and ``d1`` (the further
    variables at ``k``), are first solved for the variables' mean at ``k`` (Gauss-Newton,
    ``d0 = 0``: a gyro row gives ``R_k = R_{k-1} Exp((omega - b) dt)``), then triangularized
    with ``d1`` first (QR of ``[A1 | A0 | b]``, the square-root information filter's time
    update: Bierman 1977, "Factorization Methods for Discrete Sequential Estimation",
    ch. VI; Dellaert & Kaess 2017, "Factor Graphs for Robot Perception", sec. 3.3):
    ``R1 d1 + S d0 = d + n`` is the transition, ``d1 = F d0 + u`` with ``F = -R1^-1 S`` and
    the process noise ``R1^-1 R1^-T`` (for a gyro row: the Jacobians of
    ``factors.gyro.gyro_residual``, ``F = Exp(-phi)`` on the attitude, ``-Jr(phi) dt`` on the
    bias, the noise ``(sigma_omega dt)^2`` per axis); the rows left below, on ``d0`` alone
    (where a gyro and the random walk disagree), update epoch ``k - 1`` first. Without
    between rows this is the random walk: mean held, covariance ``+ psd dt``. The result is
    the graph's own information, so the filter's last epoch is the smoother's up to the
    linearization points.
    """
    n = lay.n
    x1 = np.array(x1, dtype=float)
    t2 = np.array([0.0, dt])
    fams = [(kind, rows, p.families[kind].subset(np.asarray(rows), 1)) for kind, rows in rows_k]

    def stacked(x0, x1):
        X2 = np.stack([x0, x1])
        V0, V1, bv = process_rows(lay, X2[:1], X2[1:], t2[1:])
        A0s, A1s, bs, res = [V0[0, 6:]], [V1[0, 6:]], [bv[0, 6:]], []
        for kind, rows, fam in fams:
            A0, A1, b, _ = model_of(kind).linearize_between(fam, X2, lay, t2)
            A1 = A1.reshape(-1, n)
            if np.any(A1[:, :6]):
                raise UserError(f"{p.source}: the EKF cannot use {kind} rows: they relate the "
                                f"orbit states of two epochs")
            A0s.append(A0.reshape(-1, n))
            A1s.append(A1)
            bs.append(b.reshape(-1))
            res.append((kind, rows, -b))
        return np.concatenate(A0s), np.concatenate(A1s)[:, 6:], np.concatenate(bs), res

    for _ in range(iterations if fams else 0):     # the variables' mean at k (d0 = 0)
        _, A1, b, _ = stacked(x0, x1)
        d1 = np.linalg.lstsq(A1, b, rcond=None)[0]
        x1 = lay.retract(x1, np.concatenate([np.zeros(6), d1]))
        if np.max(np.abs(d1)) < 1e-15:
            break
    A0, A1, b, res = stacked(x0, x1)
    m = n - 6
    R = np.linalg.qr(np.column_stack([A1, A0, b]), mode="r")
    R1, S, d = R[:m, :m], R[:m, m:m + n], R[:m, -1]
    Ac, dc = R[m:, m:m + n], R[m:, -1]
    if len(dc) and np.any(Ac):                         # rows on epoch k - 1 alone
        d0, P0, _ = kalman_update(np.zeros(n), P0, Ac, dc)
    else:
        d0 = np.zeros(n)
    F = np.zeros((n, n))
    F[:6, :6] = Phi6
    R1inv = np.linalg.inv(R1)
    F[6:] = -R1inv @ S
    Q = np.zeros((n, n))
    Q[:6, :6] = Q6
    Q[6:, 6:] = R1inv @ R1inv.T
    dx1 = F @ d0
    dx1[6:] += R1inv @ d
    x1 = lay.retract(x1, dx1)
    P1 = predict_covariance(P0, F, Q)
    return x1, 0.5 * (P1 + P1.T), res
