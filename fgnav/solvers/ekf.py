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
    # Gauss-Newton on the rows (window_update) where rows relate two orbits (a formation's
    # links, linear across metres only): the compiled EKF, one spacecraft's, does not iterate,
    # and this one gives its numbers where both apply (tests/test_ekf_numba.py)
    iterate = len(lay.orbits) > 1 and chart is None and not between
    window = iterate
    x_start0, P_start0, used_by_epoch, X_win = x, P, [], np.zeros((0, n))
    flows, linear, k0_win = {}, 0, 0
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
        x_pred, P_pred, used = x, P, []
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
                used.append((kind, j))
        used_by_epoch.append(used)
        if window:   # the start: Gauss-Newton on epochs 0..k while they are not linear
            X_win = np.concatenate([X_win, x[None]])
            out = window_update(p, lay, X_win, x_start0, P_start0, used_by_epoch[k0_win:],
                                model, options.q_m2_s3, t0_j2000, T, T_inv, k0=k0_win,
                                flows=flows)
            linear = 0 if out is not None else linear + 1
            window = linear < WINDOW_LINEAR and k + 1 < WINDOW_MAX
            if out is not None:
                x, P, X_win, second = out
                if len(X_win) >= WINDOW_LENGTH:   # the first epoch marginalized
                    (x_start0, P_start0), X_win, k0_win = second, X_win[1:], k0_win + 1
        elif used and iterate:
            out = window_update(p, lay, x[None], x_pred, P_pred, [used], model,
                                options.q_m2_s3, t0_j2000, T, T_inv, k0=k)
            if out is not None:
                x, P = out[:2]
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


ITERATE_ABOVE = 0.1
"""The Gauss-Newton step, in sigmas of the filter's covariance, above which
:func:`window_update` relinearizes the rows (below: the sequential update stands)."""
ITERATE_TOLERANCE = 1e-3
"""The step, in sigmas, at which its Gauss-Newton stops."""
ITERATE_MAX = 10
WINDOW_LENGTH = 30
"""Epochs the start's window holds (:func:`window_update`); the first is marginalized (its
filtered covariance at the window's minimum becomes the next epoch's prior, the
sliding-window filter: Sibley, Matthies & Sukhatme 2010) when the window is full."""
WINDOW_LINEAR = 20
"""Consecutive epochs whose window step is below :data:`ITERATE_ABOVE` that end the start's
window: from there the filter runs recursively (each epoch's update still iterated where
it is not linear)."""
WINDOW_MAX = 200
"""The epoch at which the start's window ends in any case."""


def _epoch_rows(p: Pass, lay, used, x, T_inv):
    """Whitened rows ``A dx ~ b`` of the rows ``used`` ((kind, row)) at the block ``x``, ``A``
    in the filter's coordinates (``dx = T (x' (-) x)``)."""
    by_kind: dict[str, list[int]] = {}
    for kind, j in used:
        by_kind.setdefault(kind, []).append(j)
    As, bs = [np.zeros((0, lay.n))], [np.zeros(0)]
    for kind, js in by_kind.items():
        _, A, b, _ = linearize_family(p, kind, p.families[kind].subset(np.array(js), 0), x[None])
        As.append(A.reshape(-1, lay.n) @ T_inv)
        bs.append(b.reshape(-1))
    return np.concatenate(As), np.concatenate(bs)


def _sigmas(d, P) -> float:
    """``sqrt(d^T P^+ d)``: a step in sigmas of ``P`` (a pseudo-inverse: a covariance that
    rounding left semi-definite, a formation's ambiguities, measures it too)."""
    P = 0.5 * (P + P.T)
    return float(np.sqrt(max(d @ np.linalg.lstsq(P, d, rcond=None)[0], 0.0)))


def _transition(lay, x, dt, model, q_m2_s3, t_j2000_s, T, T_inv):
    """The block at ``t + dt`` from ``x`` and the transition and process noise in the filter's
    coordinates: ``(x, F, Q)`` (one orbit: its flow and STM; several: every orbit's,
    :func:`_propagate_formation`)."""
    x = np.array(x, dtype=float)
    x[:6], Phi6, Q6 = orbit_transition(x[:6], dt, q_m2_s3, model, t_j2000_s)
    if len(lay.orbits) == 1:
        return x, Phi6, Q6
    x, F, Q = _propagate_formation(lay, x, Phi6, Q6, dt, model, t_j2000_s)
    return x, T @ F @ T_inv, T @ Q @ T.T


def window_update(p: Pass, lay, X, x_prior, P_prior, used_by_epoch, model, q_m2_s3, t0_j2000_s,
                  T=None, T_inv=None, k0: int = 0, flows=None):
    """The filtered block at the window's last epoch by Gauss-Newton on the window's rows, or
    None where the filter's own update already is the minimum: ``(x, P, X, (x1, P1))``
    (``X``: the window's blocks at the minimum, ``x1, P1``: its second epoch filtered, the
    prior when the first is marginalized) or None.

    ``X`` (W, n): the epochs ``k0 .. k0 + W - 1``, the last one the sequential update of its
    rows (each row linearized where the rows before it left the state), the others their
    filtered blocks; ``x_prior``, ``P_prior``: the prior of epoch ``k0`` (``P`` in the
    filter's coordinates, :func:`relative_coordinates`); ``used_by_epoch[j]``: the rows
    (kind, row) accepted at the window's epoch ``j``; ``flows``: epoch -> (reference, flow,
    transition, noise), kept across calls (the motion over one step is linear to < 0.1 mm
    across the window's steps: its flow is propagated once, then moved by its transition).
    The minimum of prior + motion + rows over the window is Gauss-Newton whose step is the Kalman filter and Rauch-Tung-Striebel smoother of the
    problem linearized about ``X`` (the iterated Kalman smoother, Bell 1994); its last epoch
    is the filter's estimate there. With ``W = 1`` and the prediction as the prior this is
    the iterated EKF update (Bar-Shalom, Li & Kirubarajan 2001, sec. 10.3.2); over epochs
    ``0..k`` it is the filter's start while the state is too uncertain for its rows to be
    linear. Returns None when the first step at the last epoch is below
    :data:`ITERATE_ABOVE` sigma of its covariance: celestial rows over a km prior are linear to far
    less. Links of 1 cm on a 1 km baseline are not: a transverse error ``d`` of the
    linearization point puts ``d^2 / 2R`` (5 cm at 10 m) in each range, and with the prior's
    2 m/s the prediction is tens of metres off; a formation's EKF linearized there diverged
    (2 h formation-gto: relative error 28 times its sigma)."""
    W, n = X.shape
    T = np.eye(n) if T is None else T
    T_inv = np.eye(n) if T_inv is None else T_inv
    X = np.array(X, dtype=float)
    t = p.t_s
    flows = {} if flows is None else flows

    def forward(X):
        d = np.empty((W, n)); P = np.empty((W, n, n))
        d_pred = np.empty((W, n)); P_pred = np.empty((W, n, n)); Fs = np.empty((W, n, n))
        d_pred[0], P_pred[0] = T @ lay.local(X[0], x_prior), P_prior
        for j in range(W):
            if j > 0:
                k = k0 + j
                if k not in flows:   # the flow from the first reference, then its STM
                    flows[k] = (X[j - 1], *_transition(lay, X[j - 1], t[k] - t[k - 1], model,
                                                       q_m2_s3, t0_j2000_s + t[k - 1], T, T_inv))
                x_ref, f, F, Q = flows[k]
                f = lay.retract(f, T_inv @ (F @ (T @ lay.local(x_ref, X[j - 1]))))
                Fs[j] = F
                d_pred[j] = F @ d[j - 1] + T @ lay.local(X[j], f)
                P_pred[j] = predict_covariance(P[j - 1], F, Q)
            A, b = _epoch_rows(p, lay, used_by_epoch[j], X[j], T_inv)
            if not len(b):
                d[j], P[j] = d_pred[j], P_pred[j]
                continue
            d[j], P[j], _ = kalman_update(d_pred[j], P_pred[j], A, b - A @ d_pred[j])
        return d, P, d_pred, P_pred, Fs

    for i in range(ITERATE_MAX):
        d, P, d_pred, P_pred, Fs = forward(X)
        for j in range(W - 2, -1, -1):   # Rauch-Tung-Striebel
            C = np.linalg.solve(P_pred[j + 1], Fs[j + 1] @ P[j]).T
            d[j] = d[j] + C @ (d[j + 1] - d_pred[j + 1])
        size = _sigmas(d[-1], P[-1])
        if i == 0 and size < ITERATE_ABOVE:
            return None      # linear enough: the filter's own update
        if i > 0 and W > 1:  # (the earlier epochs' steps: those of the smoother)
            size = max(size, max(_sigmas(d[j], P[j]) for j in range(W - 1)))
        X = np.stack([lay.retract(X[j], T_inv @ d[j]) for j in range(W)])
        if size < ITERATE_TOLERANCE:
            break
    d, P = forward(X)[:2]
    return (lay.retract(X[-1], T_inv @ d[-1]), P[-1], X,
            (lay.retract(X[min(1, W - 1)], T_inv @ d[min(1, W - 1)]), P[min(1, W - 1)]))


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
