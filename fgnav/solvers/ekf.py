"""The classical baseline: an extended Kalman filter over the same models.

Prediction with the motion model's propagation and STM and the white-acceleration
process noise, ``P <- Phi P Phi^T + Q(dt)``; update with the same whitened measurement rows
the smoothers use (the measurement models, ``fgnav.graph.linearize_family``): with whitened
rows ``A dx ~ b`` the measurement noise is the identity, ``K = P A^T (A P A^T + I)^-1``,
Joseph-form covariance. Graph variables beyond the orbit state (a bias) augment the state:
their mean is held across a step and their variance grows by ``psd dt`` (a random walk;
Maybeck 1979, vol. 1, sec. 4.10), their prior is the initial covariance.
"""

from __future__ import annotations

import time

import numpy as np

from factors.dynamics import process_noise, propagate
from fgnav.errors import UserError
from fgnav.graph import enters, initial_block, layout_of, linearize_family
from fgnav.measurements import Pass, prior_covariance, rows_by_epoch
from fgnav.models.registry import model as model_of
from fgnav.robust import passes_gate
from fgnav.solution import Solution
from fgnav.solvers.first_guess import first_state
from fgnav.solvers.options import SmootherOptions
from fgnav.solvers.variables import block_variables
from fgnav.time import j2000_seconds


def run_ekf(p: Pass, options: SmootherOptions = SmootherOptions(), *, progress=None) -> Solution:
    """Filter the pass forward; ``x_eci``/``P_eci`` are the filtered (a-posteriori) states."""
    t_start = time.perf_counter()
    model = options.motion_model()
    t0_j2000 = float(j2000_seconds(p.epoch0))
    N = p.n_epochs
    per_epoch = rows_by_epoch(p)
    lay = layout_of(p)
    n = lay.n
    between = [kind for kind in p.families if enters(p, kind) and model_of(kind).between]
    if between:
        raise UserError(f"{p.source}: the EKF does not use {', '.join(between)} rows yet (rows "
                        f"between two epochs); solve with --method batch, isam2 or fixed-lag")
    x0 = first_state(p, model, t0_j2000)
    x = initial_block(p, np.broadcast_to(x0, (N, 6)))[0][0]
    P = np.zeros((n, n))
    P[:6, :6] = prior_covariance(p)
    for v in lay.extra:
        P[lay.slices[v.name], lay.slices[v.name]] = np.eye(v.dim) * v.prior_sigma ** 2
    xs = np.empty((N, n))
    Ps = np.empty((N, n, n))
    latency = np.empty(N)
    eye_n = np.eye(n)
    residuals: dict[str, np.ndarray] = {}  # innovations, whitened, in family row order
    rejected: dict[str, int] = {}
    weights: dict[str, np.ndarray] = {}  # kind -> (M,) 0 where the gate rejected the row
    for k in range(N):
        t_k0 = time.perf_counter()
        if k > 0:
            dt = p.t_s[k] - p.t_s[k - 1]
            x = x.copy()
            x[:6], Phi6 = propagate(x[:6], dt, model, t0_j2000 + p.t_s[k - 1])
            Phi = eye_n.copy()
            Phi[:6, :6] = Phi6
            P = Phi @ P @ Phi.T
            P[:6, :6] += process_noise(dt, options.q_m2_s3)
            for v in lay.extra:
                P[lay.slices[v.name], lay.slices[v.name]] += np.eye(v.dim) * v.step_sigma(dt) ** 2
        for kind, rows in per_epoch[k]:
            if not enters(p, kind):
                continue
            mdl = model_of(kind)
            if mdl.prior and k == 0:
                continue  # the initial state already is this prior
            fam = p.families[kind]
            for j in rows:  # one measurement at a time: gating decides each
                _, A, b, _ = linearize_family(p, kind, fam.subset(np.array([j]), 0), x[None])
                A = A.reshape(-1, n)
                b = b.reshape(-1)
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
                    S = A @ P @ A.T + np.eye(len(b))
                K = np.linalg.solve(S, A @ P).T
                x = lay.retract(x, K @ b)
                IKA = eye_n - K @ A
                P = IKA @ P @ IKA.T + K @ K.T
        xs[k] = x
        Ps[k] = P
        latency[k] = time.perf_counter() - t_k0
        if progress is not None:
            progress(k)
    wall = time.perf_counter() - t_start
    res = residuals
    return Solution(method="ekf", epoch0=p.epoch0, t_s=p.t_s.copy(), x_eci=xs[:, :6],
                    P_eci=Ps[:, :6, :6], variables=block_variables(lay, xs, Ps), iterations=N, chi2=float(sum(np.nansum(r * r) for r in res.values())),
                    wall_s=wall, residuals=res, online_x_eci=xs[:, :6].copy(),
                    online_P_eci=Ps[:, :6, :6].copy(),
                    latency_s=latency,
                    extras={"q_m2_s3": options.q_m2_s3, "residuals_are": "innovations (prior)",
                            **({"gate_probability": options.gate_probability, "rejected": rejected,
                                "row_weights": weights}
                               if options.gate_probability is not None else {}),
                            "latency_p50_s": float(np.median(latency))})
