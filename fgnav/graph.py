"""Graph assembly over the measurement-model registry (:mod:`fgnav.models.registry`).

Two routes share the models' residuals:

* bulk (batch Gauss–Newton): :func:`linearize_all` evaluates every family's residual for all
  its rows at once and returns pre-whitened rows ``(k, A, b)`` with ``A`` in the columns of
  the pass's per-epoch block (:class:`fgnav.models.variables.Layout`: the orbit state, then
  e.g. a bias) and ``b = -e/sigma`` (the linear problem is ``|| A dx - b ||^2``);
* incremental (iSAM2, fixed-lag): :func:`factors_for_rows` returns the GTSAM factors of the
  given rows (the models' ``factors/`` adapters) on the epoch's variable keys.

Neither route names a measurement kind: each asks the family's model. The other factor
families are built here too, each with both adapters (``tests/test_routes_agree.py`` holds
them equal):

* orbit motion (``factors.motion``): :func:`motion_rows` / :func:`motion_factors`, with the
  pass's declared impulses (manoeuvres) in the steps that end at their epochs
  (:func:`impulses`);
* the further variables' process (``Variable.process``: random walk, constant rate):
  :func:`process_rows` / :func:`process_factors` (:func:`step_rows`: both families' rows of
  every step, as the batch solver stacks them);
* the further variables' priors at the first epoch (``Variable.prior_rows``):
  :func:`prior_rows` / :func:`prior_factors`, and a filter's initial covariance
  :func:`prior_block_covariance`.

None of them names a variable or a manifold: each asks the variable's objects
(:mod:`fgnav.models.variables`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factors.dynamics import MotionModel, process_noise_sqrt_information, propagate_many
from factors.motion import impulse_rows, make_motion_factor
from fgnav.models.model import COLUMN_PREFIX
from fgnav.models.registry import model, prior_kinds
from fgnav.models.variables import Layout
from fgnav.time import add_seconds, format_utc

PRIOR_KINDS = prior_kinds()


def layout_of(p) -> Layout:
    """The per-epoch variables of a pass (its ``layout``; the orbit state alone by default)."""
    return getattr(p, "layout", None) or Layout()


def enters(p, kind: str) -> bool:
    """True for the families of ``p`` whose rows enter its graphs (not, e.g., ``attitude``
    rows unless the attitude is estimated: :meth:`MeasurementModel.enters`)."""
    try:
        return model(kind).enters(layout_of(p))
    except KeyError:
        return False


def initial_block(p, x_orbit) -> tuple[np.ndarray, np.ndarray]:
    """First guesses of the block values (N, n) from orbit states (N, 6): each further variable
    from the rows that measure it (``MeasurementModel.initial``, e.g. attitude rows) at their
    epochs, held from the last such epoch in between (and back to the first epoch), else its
    prior mean. Also returns ``measured`` (N, len(extra)) bool: epochs with such a row."""
    lay = layout_of(p)
    X = lay.initial(np.asarray(x_orbit, dtype=float)[..., :6])
    measured = np.zeros((len(X), len(lay.extra)), bool)
    for i, v in enumerate(lay.extra):
        sl = lay.slices[v.name]
        k_all, val_all = [], []
        for kind, fam in p.families.items():
            mdl = model(kind)
            if mdl.initial is None or not mdl.enters(lay):
                continue
            for role, vals in mdl.initial(fam).items():
                cols = fam.values.get(COLUMN_PREFIX + role)   # a formation's: row by row
                rows = (np.flatnonzero(np.asarray(cols) == sl.start) if cols is not None else
                        np.arange(len(fam)) if role == v.name else ())
                if len(rows):
                    k_all.append(fam.k[rows])
                    val_all.append(np.asarray(vals, dtype=float).reshape(len(fam), v.dim)[rows])
        if not k_all:
            continue
        k_all, val_all = np.concatenate(k_all), np.concatenate(val_all)
        order = np.argsort(k_all, kind="stable")
        k_all, val_all = k_all[order], val_all[order]
        last = np.searchsorted(k_all, np.arange(len(X)), side="right") - 1   # last row at or before
        X[:, sl] = val_all[np.maximum(last, 0)]
        measured[np.unique(k_all), i] = True
    return X, measured


def linearize_family(p, kind, fam, X):
    """Whitened rows of one family at the block values ``X`` (N, n): ``(k, A (M, m, n),
    b (M, m), e (M, m))`` (``fam`` may be a subset of the pass's family)."""
    A, b, e = model(kind).linearize(fam, _block(p, X), layout_of(p))
    return fam.k, A, b, e


def _block(p, X):
    """``X`` as block values of the pass's layout (orbit-only (N, 6) states of every epoch get
    the further variables' first guesses, :func:`initial_block`)."""
    lay = layout_of(p)
    X = np.asarray(X, dtype=float)
    if X.shape[-1] == lay.n:
        return X
    if X.ndim == 2 and len(X) == p.n_epochs:
        return initial_block(p, X)[0]
    return lay.initial(X[..., :6])


@dataclass
class Rows:
    """All whitened measurement rows of a pass, as scalar rows sorted by epoch."""

    k: np.ndarray            # (R,) epoch index of each row
    A: np.ndarray            # (R, n) whitened Jacobian rows (robust weights applied)
    b: np.ndarray            # (R,) whitened right-hand side, -e/sigma (weights applied)
    residuals: dict          # kind -> (M, m) whitened residuals e/sigma (no weights)
    row_kind: np.ndarray     # (R,) kind of each row ('prior_<variable>' for variable priors)
    weights: dict            # kind -> (M,) robust weight of each measurement (1 without)
    # rows of between models (a row at epoch k on the blocks of k - 1 and k), by step k - 1:
    # (k_step (S,), A0 (S, n), A1 (S, n), b (S,)), sorted by step
    steps: tuple | None = None


def prior_rows(p, X):
    """Priors of the variables after the orbit state at the first epoch,
    ``b_0 ~ N(prior_mean, prior_sigma^2)`` (a rotation: ``Log(R_0) ~ N(0, prior_sigma^2 I)``
    about the identity, ``factors.random_walk.make_rot3_prior_factor``; each variable's
    :meth:`Variable.prior_rows`): ``(k (R,), A (R, n), b (R,), tags (R,))``."""
    lay = layout_of(p)
    ks, As, bs, tags = [], [], [], []
    for v in lay.parameters:   # an orbit's prior is the log's prior rows
        sl = lay.slices[v.name]
        A = np.zeros((v.dim, lay.n))
        A[:, sl], b = v.prior_rows(X[0, sl])
        As.append(A)
        bs.append(b)
        ks.append(np.zeros(v.dim, dtype=int))
        tags.append(np.full(v.dim, f"prior_{v.name}", dtype=object))
    if not As:
        return np.zeros(0, int), np.zeros((0, lay.n)), np.zeros(0), np.zeros(0, object)
    return np.concatenate(ks), np.concatenate(As), np.concatenate(bs), np.concatenate(tags)


variable_prior_rows = prior_rows   # (its earlier name)


def prior_factors(lay) -> list:
    """The GTSAM factors of the same priors (:meth:`Variable.prior_factor`) on epoch 0's keys."""
    return [v.prior_factor() for v in lay.parameters]


def prior_block_covariance(lay, orbit_covariances=()) -> np.ndarray:
    """A filter's first covariance of the block (n, n): the orbits' (6, 6) prior covariances
    ``orbit_covariances`` (from the log's prior rows, in the layout's order of the orbits),
    every other variable its prior's, ``prior_sigma^2 I`` (:meth:`Variable.prior_covariance`),
    uncorrelated."""
    P = np.zeros((lay.n, lay.n))
    given = dict(zip((v.name for v in lay.orbits), orbit_covariances))
    for v in lay.variables:
        sl = lay.slices[v.name]
        P[sl, sl] = given[v.name] if v.name in given else v.prior_covariance()
    return P


def process_rows(lay, X0: np.ndarray, X1: np.ndarray, dt_s: np.ndarray):
    """Whitened process rows of the further variables over the steps ``X0 -> X1``.

    ``X0``, ``X1`` (S, n): block values of the layout ``lay`` at the start and end of each
    step; ``dt_s`` (S,) the steps, s. Returns ``A0, A1`` (S, n, n) and ``b`` (S, n): step s's
    rows are ``|A0[s] dx_0 + A1[s] dx_1 - b[s]|^2`` with the orbits' rows zero (their motion:
    :func:`motion_rows`), each process's rows in its variables' slices: ``W H0``, ``W H1``,
    ``b = -W e`` of the process's residual (``Variable.process``): a vector's random walk
    ``w [-I, I]``, ``b = -w (b_1 - b_0)``; a rotation's ``w [H_0, H_1]``,
    ``b = -w Log(R_0^T R_1)`` (``factors.random_walk``), ``w = 1/sqrt(psd dt)``; a rate and
    the rotation it turns ``W e`` together (``factors.attitude_motion``).
    """
    X0 = np.asarray(X0, dtype=float)
    X1 = np.asarray(X1, dtype=float)
    S, n = X0.shape
    A0 = np.zeros((S, n, n))
    A1 = np.zeros_like(A0)
    b = np.zeros((S, n))
    dt = np.asarray(dt_s, dtype=float)
    for owner, names in lay.groups:
        e, H0, H1, W = owner.process.residual(lay, names, X0, X1, dt)
        if len(names) == 1:
            sl = lay.slices[names[0]]
            A0[:, sl, sl] = W[:, None, None] * H0
            A1[:, sl, sl] = W[:, None, None] * H1
            b[:, sl] = -W[:, None] * e
            continue
        cols = np.concatenate([np.arange(n)[lay.slices[m]] for m in names])
        A0[:, cols[:, None], cols] = W @ H0
        A1[:, cols[:, None], cols] = W @ H1
        b[:, cols] = -np.einsum("kij,kj->ki", W, e)
    return A0, A1, b


def process_factors(lay, k: int, dt: float) -> list:
    """The GTSAM factors of the same processes over the step ``k - 1 -> k`` of ``dt`` s."""
    return [owner.process.factor(lay, names, k, dt) for owner, names in lay.groups]


def process_predict(lay, x_prev: np.ndarray, guess: np.ndarray, dt: float) -> np.ndarray:
    """``guess`` (n,) with the further variables' means carried ``dt`` s on from ``x_prev``
    by their processes (a random walk holds; a rate turns its rotation), in place."""
    for owner, names in lay.groups:
        owner.process.predict(lay, names, x_prev, guess, dt)
    return guess


def impulses(p) -> dict:
    """The declared impulses of a pass (``Pass.manoeuvres``: a delta-v ``dv`` planned at an
    epoch, 1-sigma ``sigma`` per axis), by the step they end: ``{k: (mean (6,), cov (6, 6))}``
    for the step ``k - 1 -> k``, ``mean = [0; sum dv]``, ``cov = [0, 0; 0, sum sigma^2 I]``
    (several at one epoch add: independent Gaussians). Empty without manoeuvres."""
    fam = getattr(p, "manoeuvres", None)
    out = {}
    if fam is None:
        return out
    for j, k in enumerate(np.asarray(fam.k, dtype=int).tolist()):
        mean, cov = out.get(k, (np.zeros(6), np.zeros((6, 6))))
        mean = mean.copy()
        cov = cov.copy()
        mean[3:] += fam.values["dv_mps"][j]
        cov[3:, 3:] += np.eye(3) * float(fam.sigma[j]) ** 2
        out[k] = (mean, cov)
    return out


def impulse_estimates(p, q: float, model: MotionModel, t0_j2000_s: float, pair) -> list:
    """Each declared manoeuvre's delta-v estimate and 1-sigma, from the solution's two states
    around it and their joint marginal: ``pair(k) -> (x_{k-1} (6,), x_k (6,), Pj (12, 12))``
    (the orbit states of epochs ``k - 1`` and ``k`` and their joint covariance; a chain's:
    :func:`chain_pair`).

    The step ``x_k = f(x_{k-1}) + G d + w`` (``G = [0; I]``, ``d = sum dv_j``, each
    ``dv_j ~ N(planned_j, S_j)``, ``w ~ N(0, Q)``) gives, for the residual
    ``r = x_k - f(x_{k-1}) - G sum planned``, the Gaussian conditional (Bar-Shalom, Li &
    Kirubarajan 2001, sec. 1.4: conditional mean and covariance of jointly Gaussian vectors)
    ``E[dv_j | r] = planned_j + K_j r``, ``K_j = S_j G^T C^-1``, ``C = Q + G (sum S) G^T``,
    ``Cov[dv_j | r] = S_j - K_j G S_j``; with ``r`` itself uncertain,
    ``r ~ N(r_hat, J Pj J^T)``, ``J = [-Phi, I]``:
    ``Cov = S_j - K_j G S_j + K_j J Pj J^T K_j^T`` (the covariance of a linear function,
    ibid.). Returns one dict per manoeuvre row (in log order): ``epoch``, ``t_s``, ``line``,
    ``planned_mps``, ``estimated_mps``, ``sigma_mps``, ``covariance_m2_s2``."""
    fam = getattr(p, "manoeuvres", None)
    if fam is None or not len(fam):
        return []
    imp = impulses(p)
    G = np.zeros((6, 3))
    G[3:] = np.eye(3)
    out = []
    for j in np.argsort(np.asarray(fam.line), kind="stable").tolist():
        k = int(fam.k[j])
        s = k - 1
        mean, cov = imp[k]
        x0, x1, Pj = pair(k)
        dt = float(p.t_s[k] - p.t_s[s])
        _, W, b, Phi = impulse_rows(x0, x1, dt, q, model, t0_j2000_s + p.t_s[s], mean, cov)
        r = -np.linalg.solve(W, b)
        Sj = np.eye(3) * float(fam.sigma[j]) ** 2
        K = Sj @ G.T @ (W.T @ W)
        dv = fam.values["dv_mps"][j]
        est = dv + K @ r
        J = np.hstack([-Phi, np.eye(6)])
        Cov = Sj - K @ G @ Sj + K @ J @ Pj @ J.T @ K.T
        Cov = 0.5 * (Cov + Cov.T)
        out.append({"epoch": format_utc(add_seconds(p.epoch0, float(p.t_s[k]))),
                    "t_s": float(p.t_s[k]), "line": int(fam.line[j]),
                    "planned_mps": [float(v) for v in dv],
                    "estimated_mps": [float(v) for v in est],
                    "sigma_mps": [float(v) for v in np.sqrt(np.maximum(np.diag(Cov), 0.0))],
                    "covariance_m2_s2": [[float(v) for v in row] for row in Cov]})
    return out


def chain_pair(X, R, S, P):
    """``pair(k)`` of :func:`impulse_estimates` for a chain solution: the states ``X``
    (N, >= 6) and the joint marginal of epochs ``k - 1`` and ``k`` from the chain's
    conditionals ``R_k dx_k + S_k dx_{k+1} = d_k`` (:mod:`fgnav.solvers.chain`) and marginals
    ``P`` (N, n, n): ``dx_{k-1} = R^-1 (d - S dx_k + w)`` gives
    ``Cov(dx_{k-1}, dx_k) = -R_{k-1}^-1 S_{k-1} P_k``."""
    def pair(k):
        Pj = np.zeros((12, 12))
        Pj[:6, :6] = P[k - 1][:6, :6]
        Pj[6:, 6:] = P[k][:6, :6]
        Pj[:6, 6:] = -np.linalg.solve(R[k - 1], S[k - 1] @ P[k])[:6, :6]
        Pj[6:, :6] = Pj[:6, 6:].T
        return np.asarray(X[k - 1, :6], float), np.asarray(X[k, :6], float), Pj
    return pair


PROCESS_CHUNK = 65_536
"""Steps whose motion rows :func:`motion_rows` forms at a time: the state transition matrices
and the products with them live per chunk (30 MB), not for the whole pass (3 x 288 MB at
1,000,000 epochs). Each step's rows depend on that step alone: any chunk gives the same bits."""


def motion_rows(p, Xs: np.ndarray, q: float, model: MotionModel, t0_j2000_s: float,
                chunked: bool = False):
    """The whitened motion rows of every orbit (a formation's: each spacecraft's, the same
    motion model) over every step k -> k + 1 on the block ``(X_k, X_{k+1})``: ``A0, A1``
    (N-1, n, n) and ``b`` (N-1, n), step k's rows ``|A0 dx_k + A1 dx_{k+1} - b|^2``, the
    further variables' rows zero (theirs: :func:`process_rows`).

    Orbit rows ``W [-Phi_k, I]``, ``b = -W (x_{k+1} - f(x_k))`` with ``W^T W = Q_k^-1`` (the
    motion factor, ``factors.motion``). With the orbit alone and steps of one length, ``A1``
    is that step's ``W`` broadcast (read-only, no memory per step). A step that ends with a
    declared impulse (:func:`impulses`, the first orbit's) has the rows of
    ``factors.motion.impulse_rows`` instead: ``b = -W (x_{k+1} - f(x_k) - mean)``,
    ``W^T W = (Q_k + cov)^-1``.

    ``chunked``: ``A0`` as a list of arrays of ``2 * PROCESS_CHUNK`` steps each (the same
    chunks of the computation, so the same values), so that its parts can be freed as they
    are used (the batch solver's ``_Factors``); with further variables than one orbit, a list
    of the one array. A part (37.7 MB) is above the size from which the C allocator (glibc)
    always maps memory of its own, so that a freed part goes back to the system at once
    (parts of one chunk, 19 MB, were placed in the heap and, freed, kept by the process).
    """
    lay = layout_of(p)
    N, n = p.n_epochs, lay.n
    b = np.zeros((max(N - 1, 0), n))
    if N < 2:
        A0 = np.zeros((0, n, n))
        return ([A0] if chunked else A0), np.zeros_like(A0), b
    dt = np.diff(p.t_s)
    W = _step_sqrt_information(dt, q)
    imp = impulses(p)
    if chunked and n == 6:   # the orbit alone
        A0, part = [], 2 * PROCESS_CHUNK
        for c0 in range(0, N - 1, part):
            c1 = min(N - 1, c0 + part)
            A0.append(np.zeros((c1 - c0, n, n)))
            _orbit_rows(Xs[c0:c1, :6], Xs[c0 + 1:c1 + 1, :6], dt[c0:c1],
                        t0_j2000_s + p.t_s[c0:c1], W[c0:c1], model, A0[-1], b[c0:c1])
        if imp:
            W = np.array(W)   # (a broadcast view: the impulses' steps differ)
            for k, (mean, cov) in imp.items():
                s = k - 1
                A0[s // part][s % part], W[s], b[s] = impulse_rows(
                    Xs[s, :6], Xs[k, :6], dt[s], q, model, t0_j2000_s + p.t_s[s], mean, cov)[:3]
        return A0, W, b
    A0 = np.zeros((N - 1, n, n))
    _orbit_rows(Xs[:-1, :6], Xs[1:, :6], dt, t0_j2000_s + p.t_s[:-1], W, model,
                A0[:, :6, :6], b[:, :6])
    if n == 6:
        A1 = W   # the orbit alone: its rows on X_{k+1} are W itself
    else:
        A1 = np.zeros_like(A0)
        A1[:, :6, :6] = W
    for v in lay.orbits[1:]:   # a formation's further spacecraft: the same motion model
        sl = lay.slices[v.name]
        _orbit_rows(Xs[:-1, sl], Xs[1:, sl], dt, t0_j2000_s + p.t_s[:-1], W, model,
                    A0[:, sl, sl], b[:, sl])
        A1[:, sl, sl] = W
    if imp:
        if A1 is W:
            A1 = np.array(W)   # (a broadcast view: the impulses' steps differ)
        for k, (mean, cov) in imp.items():
            s = k - 1
            A0[s, :6, :6], A1[s, :6, :6], b[s, :6] = impulse_rows(
                Xs[s, :6], Xs[k, :6], dt[s], q, model, t0_j2000_s + p.t_s[s], mean, cov)[:3]
    return ([A0] if chunked else A0), A1, b


def motion_factors(lay, k: int, dt: float, q: float, model: MotionModel,
                   t0_j2000_s: float, impulse=None) -> list:
    """The GTSAM motion factors of every orbit over the step ``k - 1 -> k`` of ``dt`` s from
    ``t0_j2000_s`` (``factors.motion.make_motion_factor``); ``impulse``: the step's
    ``(mean, cov)`` of :func:`impulses` (the first orbit's), or None."""
    return [make_motion_factor(v.key(k - 1), v.key(k), dt, q, model, t0_j2000_s,
                               impulse=impulse if i == 0 else None)
            for i, v in enumerate(lay.orbits)]


def step_rows(p, Xs: np.ndarray, q: float, model: MotionModel, t0_j2000_s: float,
              chunked: bool = False):
    """Every step's rows as the batch solver stacks them: :func:`motion_rows` with the
    further variables' :func:`process_rows` in their columns (same shapes and ``chunked``)."""
    A0, A1, b = motion_rows(p, Xs, q, model, t0_j2000_s, chunked)
    lay = layout_of(p)
    if lay.extra and p.n_epochs >= 2:
        V0, V1, bv = process_rows(lay, Xs[:-1], Xs[1:], np.diff(p.t_s))
        extra = np.concatenate([np.arange(lay.slices[v.name].start, lay.slices[v.name].stop)
                                for v in lay.parameters] or [np.zeros(0, int)])
        A0_ = A0[0] if chunked else A0
        A0_[:, extra], A1[:, extra], b[:, extra] = V0[:, extra], V1[:, extra], bv[:, extra]
    return A0, A1, b


def _step_sqrt_information(dt: np.ndarray, q: float) -> np.ndarray:
    """``process_noise_sqrt_information(dt, q)`` (K, 6, 6); when every step has the same length,
    that one block broadcast to (K, 6, 6) (read-only; 288 MB less at 1,000,000 epochs)."""
    if len(dt) and np.all(dt == dt[0]):
        return np.broadcast_to(process_noise_sqrt_information(dt[:1], q), (len(dt), 6, 6))
    return process_noise_sqrt_information(dt, q)


def _orbit_rows(x_from: np.ndarray, x_to: np.ndarray, dt: np.ndarray, t_j2000_s: np.ndarray,
                W: np.ndarray, model: MotionModel, A0_out: np.ndarray, b_out: np.ndarray) -> None:
    """The whitened motion rows of the orbit steps ``x_from[k] -> x_to[k]`` (K, 6) of ``dt[k]``
    seconds from ``t_j2000_s[k]``: ``A0_out[k] = -W_k Phi_k`` (K, 6, 6) and
    ``b_out[k] = -W_k (x_to[k] - f(x_from[k]))`` (K, 6), written in place,
    :data:`PROCESS_CHUNK` steps at a time into one reused STM buffer."""
    K = len(dt)
    Phi = np.empty((min(PROCESS_CHUNK, K), 6, 6))
    for c0 in range(0, K, PROCESS_CHUNK):
        c1 = min(K, c0 + PROCESS_CHUNK)
        F, Ph = propagate_many(x_from[c0:c1], dt[c0:c1], model, t_j2000_s[c0:c1],
                               stm_out=Phi[:c1 - c0])
        Wc = np.ascontiguousarray(W[c0:c1])   # the layout einsum had before: the same sums
        A0_out[c0:c1] = -np.einsum("kij,kjl->kil", Wc, Ph)
        b_out[c0:c1] = -np.einsum("kij,kj->ki", Wc, x_to[c0:c1] - F)


def linearize_all(p, X, robust=None, rejected=None) -> Rows:
    """Linearize every measurement family of a pass at the block values ``X`` (N, n).

    ``robust``: a :class:`fgnav.robust.RobustKernel` applied to every measurement except
    the priors (IRLS: rows scaled by sqrt(w) of the measurement's whitened norm).
    ``rejected``: kind -> (M,) bool, measurements given zero weight (outliers).
    """
    X = _block(p, X)
    n = layout_of(p).n
    ks, As, bs, res, tags, wts = [], [], [], {}, [], {}
    st_k, st_A0, st_A1, st_b = [], [], [], []
    for kind, fam in p.families.items():
        if not enters(p, kind):
            continue
        mdl = model(kind)
        m = mdl.dim
        if mdl.between:
            A0, A1, b, _ = mdl.linearize_between(fam, X, layout_of(p), p.t_s)
            res[kind] = -b.reshape(len(fam), m)
            w = np.ones(len(fam))
            if robust is not None and mdl.robust:
                w = robust.weights(np.linalg.norm(b.reshape(len(fam), m), axis=1))
            if rejected is not None and kind in rejected:
                w = np.where(rejected[kind], 0.0, w)
            sw = np.sqrt(w)
            wts[kind] = w
            st_k.append(np.repeat(fam.k - 1, m))
            st_A0.append((A0 * sw[:, None, None]).reshape(-1, n))
            st_A1.append((A1 * sw[:, None, None]).reshape(-1, n))
            st_b.append((b * sw[:, None]).reshape(-1))
            continue
        A, b, _ = mdl.linearize(fam, X, layout_of(p))
        res[kind] = -b.reshape(len(fam), m)  # whitened residual e/sigma
        if robust is not None and mdl.robust:
            w = robust.weights(np.linalg.norm(b.reshape(len(fam), m), axis=1))
            sw = np.sqrt(w)
            A = A * sw[:, None, None]
            b = b * sw[:, None]
        else:
            w = np.ones(len(fam))
        if rejected is not None and kind in rejected:
            w = np.where(rejected[kind], 0.0, w)
            keep = (~rejected[kind]).astype(float)
            A = A * keep[:, None, None]
            b = b * keep[:, None]
        wts[kind] = w
        ks.append(np.repeat(fam.k, m))
        As.append(A.reshape(-1, n))
        bs.append(b.reshape(-1))
        tags.append(np.full(len(fam) * m, kind, dtype=object))
    kv, Av, bv, tv = prior_rows(p, X)
    ks.append(kv)
    As.append(Av)
    bs.append(bv)
    tags.append(tv)
    k = np.concatenate(ks)
    order = np.argsort(k, kind="stable")
    steps = None
    if st_k:
        sk = np.concatenate(st_k)
        so = np.argsort(sk, kind="stable")
        steps = (sk[so], np.concatenate(st_A0)[so], np.concatenate(st_A1)[so],
                 np.concatenate(st_b)[so])
    return Rows(k[order], np.concatenate(As)[order], np.concatenate(bs)[order], res,
                np.concatenate(tags)[order], wts, steps)


def factors_for_rows(p, kind, rows, k, robust=None, x_guess=None):
    """GTSAM factors (iSAM2 route) of the given rows of a family, on epoch ``k``'s keys.

    ``robust``: a :class:`fgnav.robust.RobustKernel` wrapping the noise model of every
    measurement but the priors. ``x_guess``: the orbit state's first guess (6,), for noise
    that depends on geometry (as in the batch route).
    """
    return model(kind).factors(p.families[kind], rows, k, layout_of(p), robust, x_guess, p.t_s)


def orbit_rows(p, kind, fam, x_orbit, variables=None):
    """Whitened rows of a family on the orbit state alone: ``(k, A (M, m, 6), b, e)`` at the
    orbit states ``x_orbit`` (N, 6), with the pass's further variables held at ``variables``
    (a solution's ``variables``: name -> (values (N, d), covariances)) or their prior mean.
    For the analyses that work with the orbit marginals (consistency, integrity)."""
    k, A, b, e = linearize_family(p, kind, fam, block_values(p, x_orbit, variables))
    return k, A[..., :6], b, e


def block_values(p, x_orbit, variables=None) -> np.ndarray:
    """The pass's block values (N, n) from orbit states (N, 6) and a solution's ``variables``
    (name -> (values (N, d), covariances)); variables not given at their prior mean."""
    lay = layout_of(p)
    X = lay.initial(np.asarray(x_orbit, dtype=float)[..., :6])
    for name, (vals, _) in (variables or {}).items():
        if lay.has(name) and len(vals) == len(X):
            X[:, lay.slices[name]] = vals
    return X
