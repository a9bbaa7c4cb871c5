"""Online estimation: the same graph grown one epoch at a time with iSAM2.

Each epoch adds the motion factor from the previous state and the epoch's measurement
factors (``gtsam.CustomFactor`` adapters of the ``factors/`` residuals), with the previous
estimate propagated as the new state's initial value. After every update the current state
and its marginal covariance are read: that is what a flight computer would have had
(``Solution.online_*``). Full history (``method="isam2"``) keeps every state, so the last
estimate is the smoothed solution; ``method="fixed-lag"`` marginalizes states older than
``lag_s`` (``IncrementalFixedLagSmoother``) for bounded memory and latency.

QR factorization throughout (Cholesky refuses this problem). Relinearization thresholds per
component in SI units, 1 km and 1 m/s: on gto-transfer at 10 s (1,441 epochs) they cut the
wall time from 25.6 s (1 m / 1 mm/s, skip 10) to 3.9 s and p99 latency from 365 ms to
34 ms, and the final estimate still equals the batch solution to < 0.003 sigma (the models
are nearly linear over 1 km: the second-order term of a direction residual is
(1 km / 7,000 km)^2 = 2e-8 rad, of an altitude residual 1^2 / (2 x 7,000) km = 0.07 m).
Only the variables whose update the back-substitution recomputed are checked
(``enablePartialRelinearizationCheck``): at 1 Hz over 4 h the full check walked all
states every epoch and, when 1,099 early states crossed the threshold at once,
re-eliminated the whole chain (80 ms); with the partial check p50 0.60 -> 0.33 ms, p99
5.8 -> 0.7 ms, max 84 -> 4.6 ms, and the final estimate equals batch to 0.0024 sigma.
The wildfire threshold of the back-substitution is 100 (m, m/s): the newest state (the
root of the chain's Bayes tree) is always solved, older states only when their update is
large, so an update no longer touches the whole history (1,800 epochs at 1 Hz: p50 0.83 ->
0.28 ms, p99 42 -> 11 ms); the final trajectory starts from a full back-substitution
(``calculateBestEstimate``).

Both thresholds make iSAM2's estimate depend on the path it took (which states were
relinearized when), so a run resumed from a checkpoint would end up to 2e-3 sigma away from
an uninterrupted one. The final trajectory is therefore polished by Gauss-Newton over the
whole chain (:func:`polish_chain`, usually two iterations, ~0.4 s each at 14,400
epochs): it is the optimum of the full problem with iSAM2's gating decisions, the same
for a resumed run to < 1e-5 sigma (gto-transfer at 1, 10 and 60 s steps: <= 7.4e-6 sigma,
from 1.3e-4 .. 2.1e-3 sigma without the polish) and equal to the batch solution to the
same order.

Python's cyclic garbage collector is paused during the epoch loop: a full collection scans
every factor closure held by the graph (~100 ms after 10,000 epochs, the largest latency
spikes of full-history iSAM2), and the loop makes no cyclic garbage (a collection after
3,600 epochs finds 7 objects).
"""

from __future__ import annotations

import contextlib
import gc
import hashlib
import io
import os
import time

import gtsam
import numpy as np

from factors.dynamics import process_noise, process_noise_sqrt_information, propagate
from factors.motion import impulse_rows, make_motion_factor, motion_residual
from fgnav.errors import NotObservableError, UserError
from fgnav.graph import (enters, factors_for_rows, initial_block, layout_of, linearize_family,
                         motion_factors, prior_factors, process_factors, process_predict,
                         chain_pair, impulse_estimates, impulses)
from fgnav.models.registry import model as model_of
from fgnav.io.atomic import atomic_writer
from fgnav.robust import RobustKernel, passes_gate
from fgnav.measurements import Pass, rows_by_epoch
from fgnav.solution import Solution, latency_summary
from fgnav.measurements import prior_covariance
from fgnav.solvers.batch import linearize_and_eliminate, robust_counts
from fgnav.solvers.batch import outlier_mask
from fgnav.solvers.chain import back_substitute, chain_marginals
from fgnav.iod.prior import first_state
from fgnav.solvers.options import IncrementalOptions, SmootherOptions
from fgnav.solvers.variables import block_variables
from fgnav.time import j2000_seconds

X = gtsam.symbol_shorthand.X


def _insert_block(values, lay, k, block):
    """Insert epoch ``k``'s variables (block values (n,)) into a ``gtsam.Values`` (a rotation
    as ``gtsam.Rot3`` from its rotation vector)."""
    values.insert(X(k), np.asarray(block[:6], dtype=float))
    for v in lay.extra:
        w = np.asarray(block[lay.slices[v.name]], dtype=float)
        values.insert(v.key(k), v.manifold.to_gtsam(w))


def _read_block(source, lay, k):
    """Epoch ``k``'s block values (n,) from an estimate (``gtsam.Values``) or from iSAM2 / the
    fixed-lag smoother (``calculateEstimate*``); rotations as rotation vectors."""
    get = "at" if isinstance(source, gtsam.Values) else "calculateEstimate"
    vec = getattr(source, get + "Vector")
    if not lay.extra:
        return np.asarray(vec(X(k)), dtype=float)
    return np.concatenate([vec(X(k))] + [
        v.manifold.from_gtsam(getattr(source, get + v.manifold.gtsam_type)(v.key(k)))
        for v in lay.extra])


def _keys(lay, k):
    """Epoch ``k``'s keys."""
    return [X(k)] + [v.key(k) for v in lay.extra]


def _timestamps(lay, k, t):
    """Fixed-lag timestamps of epoch ``k``'s keys."""
    return {X(k): t, **{v.key(k): t for v in lay.extra}}


def _process_factors(lay, k, dt, q, model, t0_j2000_s, impulse=None):
    """The factors from epoch ``k - 1`` to ``k``: every orbit's motion factor (with the
    step's declared impulse, :func:`fgnav.graph.impulses`) and the further variables'
    processes (:func:`fgnav.graph.motion_factors`, :func:`fgnav.graph.process_factors`); at
    ``k = 0`` the further variables' priors (:func:`fgnav.graph.prior_factors`)."""
    if k == 0:
        return prior_factors(lay)
    return (motion_factors(lay, k, dt, q, model, t0_j2000_s, impulse=impulse)
            + process_factors(lay, k, dt))


def isam2_params(opt: IncrementalOptions, lay=None) -> gtsam.ISAM2Params:
    """iSAM2's parameters. The relinearization threshold of a further vector variable
    (``lay``) is its prior sigma: the models that use one so far are linear in it (a bias),
    so its value never asks for relinearization. A rotation (the attitude) is relinearized
    when its update exceeds ``opt.relinearize_rotation_rad`` (0.01 rad): the second-order
    term of a direction residual is then 0.01^2 / 2 = 5e-5 rad, a sixth of a 0.3 mrad Earth
    sensor's sigma. Held at its first linearization (the threshold was its 10 rad prior
    sigma) the attitude an epoch was first linearized at stayed: on a 30 min pass spinning
    at 0.0075 rad/s with attitude rows one epoch in ten and the constant-rate motion, the
    online attitude error was 5.1 mrad RMS (74 mrad max), relinearized 1.2 mrad (23 mrad);
    with a gyro (tests/test_gyro_in_graph.py's pass) 0.45 -> 0.40 mrad; the online orbit
    error does not change (0.01 %)."""
    params = gtsam.ISAM2Params()
    params.setFactorization("QR")
    thresholds = np.array([opt.relinearize_position_m] * 3 + [opt.relinearize_velocity_mps] * 3)
    tmap = gtsam.ISAM2ThresholdMap()
    tmap.insert(("x", thresholds))
    for v in (lay.parameters if lay is not None else ()):   # (a formation's orbits: 'x')
        tmap.insert((v.symbol, np.full(v.dim, v.prior_sigma if v.manifold.additive
                                       else opt.relinearize_rotation_rad)))
    params.setRelinearizeThreshold(tmap)
    params.relinearizeSkip = opt.relinearize_skip
    params.enablePartialRelinearizationCheck = opt.partial_relinearization_check
    gn = gtsam.ISAM2GaussNewtonParams()
    gn.setWildfireThreshold(opt.wildfire_threshold)
    params.setOptimizationParams(gn)
    return params


def smooth_incremental(p: Pass, options: SmootherOptions = SmootherOptions(),
                       inc: IncrementalOptions = IncrementalOptions(), *, method: str = "isam2",
                       progress=None, checkpoint: str | None = None, checkpoint_every: int = 100,
                       resume: bool = False, x_start: np.ndarray | None = None,
                       P_start: np.ndarray | None = None) -> Solution:
    """Run iSAM2 (``method="isam2"``) or the fixed-lag smoother (``"fixed-lag"``) over a pass.

    ``checkpoint``: a file (.npz) written atomically every ``checkpoint_every`` epochs with
    the estimates so far, the online history and the gating decisions (full-history iSAM2
    only). ``resume=True`` restarts from it (after validating it: format, arrays, shapes,
    finite values, and a fingerprint of the log's values and of the options): the graph of
    the processed epochs is rebuilt from the log at the saved estimates in one update, and
    the run continues where it stopped. The final trajectory agrees with an uninterrupted
    run to < 1e-5 sigma (see :func:`polish_chain`); the online estimates after the restart
    are those of the resumed run.

    ``x_start``: the block values (n,) to start from at the first epoch (a formation's: every
    spacecraft's orbit, :func:`fgnav.start.formation_start`); default the prior. ``P_start``
    (n, n): their covariance, which the gate (``options.gate_probability``) predicts the first
    epoch's rows with (default: the prior rows' for the first orbit, each further variable's
    prior).
    """
    t_start = time.perf_counter()
    model = options.motion_model()
    t0_j2000 = float(j2000_seconds(p.epoch0))
    N = p.n_epochs
    lay = layout_of(p)
    per_epoch = rows_by_epoch(p)
    imp = impulses(p)   # declared manoeuvres, by the step they end
    if imp and len(lay.orbits) > 1:
        raise UserError(f"{p.source}: manoeuvre rows with several spacecraft are not yet "
                        "supported (the burn's spacecraft has no impulse of its own here)")
    lagged_pair = {}   # fixed-lag: burn step k -> (x_{k-1}, x_k, joint marginal) of one window
    # The first guess of state 0 comes from the priors (propagated back if they are later).
    x_first = first_state(p, model, t0_j2000) if x_start is None else x_start[:6]
    # further variables: first guesses from the rows that measure them (attitude rows)
    V0, measured = initial_block(p, np.broadcast_to(x_first, (N, 6)))
    if x_start is not None:
        for v in lay.orbits[1:]:
            V0[:, lay.slices[v.name]] = x_start[lay.slices[v.name]]
    x_prev = V0[0].copy()
    fixed_lag = method == "fixed-lag"
    if fixed_lag:
        # The window holds lag_s + harvest_s: the smoothed output is read out a block of
        # harvest_s at a time, outside the latency (see _harvest).
        lag_internal = inc.lag_s + inc.harvest_s
        smoother = gtsam.IncrementalFixedLagSmoother(lag_internal, isam2_params(inc, lay))
    else:
        isam = gtsam.ISAM2(isam2_params(inc, lay))
    # Holding a Python reference to the internal linearization point spares the copy of all
    # values on every CustomFactor call during relinearization (measured: the copy made the latency
    # ~7x).
    held_lp = None
    online_x = np.empty((N, 6))
    online_P = np.empty((N, 6, 6))
    # a formation's further spacecraft as read at each epoch
    online_more = {v.name: (np.full((N, 6), np.nan), np.full((N, 6, 6), np.nan))
                   for v in lay.orbits[1:]}
    online_V = np.zeros((N, lay.n, lay.n))  # the gate: further variables' online marginals
    lagged_x = np.empty((N, lay.n))   # fixed-lag: each state's estimate when it leaves the window
    lagged_P = np.zeros((N, lay.n, lay.n))
    lagged_next = np.full((N, lay.n), np.nan)  # ... and its successor's in that same estimate
    oldest = 0
    latency = np.empty(N)
    kernel = RobustKernel.create(options.robust, options.robust_k)
    gate = options.gate_probability
    rejected_rows = {kind: np.zeros(len(f), bool) for kind, f in p.families.items()}
    if (checkpoint or resume) and fixed_lag:
        raise UserError("checkpoint/resume is available for --method isam2 (full history) only")
    if checkpoint and not (isinstance(checkpoint_every, (int, np.integer)) and checkpoint_every >= 1):
        raise UserError(f"--checkpoint-every must be an epoch count >= 1, got {checkpoint_every}")
    fingerprint = _fingerprint(p, options, inc, method)

    # the models whose rows enter the graph (not, e.g., 'attitude' rows with the attitude known)
    models = {kind: model_of(kind) for kind in p.families if enters(p, kind)}

    def add_epoch_factors(graph, k, guess, kept_only):
        for kind, rows in per_epoch[k]:
            mdl = models.get(kind)
            if mdl is None:
                continue
            if kept_only:
                rows = rows[~rejected_rows[kind][rows]]
            elif gate is not None and not mdl.between:
                # (a row between two epochs is not gated: its prediction needs the joint
                # covariance of both, which the online route does not read)
                if mdl.robust:
                    kept = _gate_rows(p, kind, rows, gated[0], gated[1], gate)
                    rejected_rows[kind][np.setdiff1d(rows, kept)] = True
                    rows = kept
                if not mdl.variables or mdl.weak_orbit_dependence:
                    # rows of further variables alone (attitude rows, stars)
                    gated[:] = _gate_update(p, lay, kind, rows, *gated)
            for f in mdl.factors(p.families[kind], rows, k, lay, kernel, guess[:6], p.t_s):
                graph.add(f)

    k_start = 0
    if resume:
        if not checkpoint:
            raise UserError("resume needs a checkpoint file")
        k_start, x_est, rejected_rows = _load_checkpoint(
            checkpoint, fingerprint, online_x, online_P, latency, rejected_rows, lay.n)
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        for k in range(k_start):
            dt = p.t_s[k] - p.t_s[k - 1] if k > 0 else 0.0
            for f in _process_factors(lay, k, dt, options.q_m2_s3, model,
                                      t0_j2000 + p.t_s[max(k - 1, 0)], imp.get(k)):
                graph.add(f)
            add_epoch_factors(graph, k, x_est[k], kept_only=True)
            _insert_block(values, lay, k, x_est[k])
        isam.update(graph, values)
        held_lp = isam.getLinearizationPoint()
        x_prev = _read_block(isam, lay, k_start - 1)
        for v in lay.orbits[1:]:   # (the checkpoint keeps the first's online states only:
            xo, Po = online_more[v.name]   # the others' as of the checkpoint's estimate)
            for j in range(k_start):
                xo[j] = x_est[j][lay.slices[v.name]]
                Po[j] = isam.marginalCovariance(v.key(j))
        if gate is not None:
            _read_variable_marginals(isam, lay, k_start - 1, online_V)
    _warm_up(p, per_epoch, options, model, t0_j2000, x_prev, kernel)
    held = None if inc.relinearize_window_s is None or fixed_lag else gtsam.KeyList()
    n_held = 0
    with _gc_paused():
        for k in range(k_start, N):
            if fixed_lag and oldest < k and p.t_s[oldest] < p.t_s[k] - lag_internal:
                oldest = _harvest(smoother, p.t_s, oldest, k, p.t_s[k] - inc.lag_s,
                                  lagged_x, lagged_P, lagged_next, lay, imp, lagged_pair)
            t_k0 = time.perf_counter()
            graph = gtsam.NonlinearFactorGraph()
            values = gtsam.Values()
            dt = p.t_s[k] - p.t_s[k - 1] if k > 0 else 0.0
            guess = x_prev.copy()
            Phis = []
            if k > 0:
                guess[:6], Phi_k = propagate(x_prev[:6], dt, model, t0_j2000 + p.t_s[k - 1])
                Phis.append(Phi_k)
                for v in lay.orbits[1:]:   # a formation's further spacecraft (the gate: STMs)
                    sl = lay.slices[v.name]
                    guess[sl], Phi_v = propagate(x_prev[sl], dt, model, t0_j2000 + p.t_s[k - 1],
                                                 with_stm=gate is not None)
                    Phis.append(Phi_v)
            if k in imp:   # a declared burn ends this step: its planned delta-v
                guess[:6] += imp[k][0]
            if k > 0:   # the further variables' means carried on (a rate turns the attitude)
                process_predict(lay, x_prev, guess, dt)
            for i, v in enumerate(lay.extra):
                if measured[k, i]:
                    guess[lay.slices[v.name]] = V0[k, lay.slices[v.name]]
            for f in _process_factors(lay, k, dt, options.q_m2_s3, model,
                                      t0_j2000 + p.t_s[max(k - 1, 0)], imp.get(k)):
                graph.add(f)
            if gate is not None:   # [state, covariance] updated by each family's kept rows
                gated = [guess.copy(), _predicted_covariance(
                    p, lay, k, Phis, online_P, online_V, dt, options.q_m2_s3, P_start)]
                if k in imp:
                    gated[1][:6, :6] += imp[k][1]
            add_epoch_factors(graph, k, guess, kept_only=False)
            _insert_block(values, lay, k, guess)
            try:
                if fixed_lag:
                    smoother.update(graph, values, _timestamps(lay, k, float(p.t_s[k])))
                    if held_lp is None:
                        held_lp = smoother.getISAM2().getLinearizationPoint()
                    x_prev = _read_block(smoother, lay, k)
                    P = smoother.marginalCovariance(X(k))
                else:
                    if held is None:
                        isam.update(graph, values)
                    else:   # the states out of the relinearization window: held
                        while p.t_s[n_held] < p.t_s[k] - inc.relinearize_window_s:
                            for key in _keys(lay, n_held):
                                held.push_back(key)
                            n_held += 1
                        isam.update(graph, values, noRelinKeys=held)
                    if held_lp is None:
                        held_lp = isam.getLinearizationPoint()
                    x_prev = _read_block(isam, lay, k)
                    P = isam.marginalCovariance(X(k))
            except RuntimeError as exc:
                raise NotObservableError(
                    f"{p.source}: {method} could not update at t = {p.t_s[k]:.3f} s ({exc}); "
                    f"the state is not observable from the data so far (a prior is needed at the "
                    f"first epoch)") from exc
            online_x[k] = x_prev[:6]
            online_P[k] = P
            for v in lay.orbits[1:]:
                xo, Po = online_more[v.name]
                xo[k] = x_prev[lay.slices[v.name]]
                Po[k] = (smoother if fixed_lag else isam).marginalCovariance(v.key(k))
            if gate is not None:
                _read_variable_marginals(smoother if fixed_lag else isam, lay, k, online_V)
            latency[k] = time.perf_counter() - t_k0
            if checkpoint and ((k + 1) % checkpoint_every == 0 or k == N - 1):
                est = isam.calculateEstimate()
                _save_checkpoint(checkpoint, fingerprint, k + 1, online_x, online_P, latency,
                                 np.array([_read_block(est, lay, j) for j in range(k + 1)]),
                                 rejected_rows)
            if progress is not None:
                progress(k)
    if fixed_lag:
        _harvest(smoother, p.t_s, oldest, N, np.inf, lagged_x, lagged_P, lagged_next, lay,
                 imp, lagged_pair)
        x_final, P_final = lagged_x, lagged_P
        lin = linearize_and_eliminate(p, x_final, options.q_m2_s3, model, t0_j2000, kernel)
        # The reported states come from different windows (each read when it leaves its
        # window), so the motion residual between neighbours from different windows is not
        # one the smoother ever fitted (1e17 at q = 1e-12): each step's motion residual is
        # taken inside the window estimate its first state was read from.
        lin.chi2_motion = _motion_chi2(p, lagged_x, lagged_next, options.q_m2_s3, model, t0_j2000,
                                       imp)
        polish_iterations = 0
    else:
        est = isam.calculateBestEstimate()  # full back-substitution, whatever the wildfire
        # Gauss-Newton over the whole chain from the iSAM2 estimate: the final trajectory is
        # the fixed point of the full problem (with iSAM2's gating decisions), not of the
        # path iSAM2 took to it, so a resumed run ends where an uninterrupted one does. All
        # marginals in O(N) from the same elimination (isam.marginalCovariance of an old
        # state costs ~0.1-0.25 s each).
        x_final, lin, P_final, polish_iterations = polish_chain(
            p, np.array([_read_block(est, lay, k) for k in range(N)]), options.q_m2_s3, model,
            t0_j2000, kernel, rejected_rows if gate is not None else None)
    row_weights = lin.weights
    if kernel is not None:
        x_final, lin, P_final, row_weights, more = _reject_exposed(
            p, x_final, lin, P_final, options, model, t0_j2000, kernel, rejected_rows,
            refit=not fixed_lag)
        if not fixed_lag:
            polish_iterations += more
    manoeuvres = []
    if imp:   # each burn from its two states' joint marginal (fixed-lag: in one window)
        chain = chain_pair(x_final, lin.R, lin.S, lin.marginals())
        manoeuvres = impulse_estimates(p, options.q_m2_s3, model, t0_j2000,
                                       lambda k: lagged_pair.get(k) or chain(k))
    wall = time.perf_counter() - t_start
    return Solution(method=method, epoch0=p.epoch0, t_s=p.t_s.copy(), x_eci=x_final[:, :6],
                    P_eci=P_final[:, :6, :6], variables=block_variables(lay, x_final, P_final),
                    P_block=None if (fixed_lag and len(lay.orbits) == 1) or not lay.extra
                    else P_final,
                    iterations=N, wall_s=wall,
                    chi2=lin.chi2_meas + lin.chi2_motion,
                    residuals=lin.residuals, online_x_eci=online_x,
                    online_P_eci=online_P, latency_s=latency,
                    extras={"q_m2_s3": options.q_m2_s3,
                            **({"online_variables": online_more} if online_more else {}),
                            "chi2_measurements": lin.chi2_meas, "chi2_motion": lin.chi2_motion,
                            **({"chi2_motion_is": "each step within the window estimate its "
                                                  "first state was read from"} if fixed_lag else {}),
                            **latency_summary(latency),
                            **({"manoeuvres": manoeuvres} if manoeuvres else {}),
                            **({} if fixed_lag else {"final_polish_iterations": polish_iterations}),
                            **({"lag_s": inc.lag_s, "harvest_s": inc.harvest_s} if fixed_lag else {}),
                            **({"gate_probability": gate,
                                "rejected": {kind: int(m.sum()) for kind, m in rejected_rows.items()
                                             if m.any()}} if gate else {}),
                            "row_weights": {kind: np.where(rejected_rows[kind], 0.0, w)
                                            if kind in rejected_rows else w
                                            for kind, w in row_weights.items()},
                            **robust_counts(options, row_weights)})


def _reject_exposed(p, x, lin, P, options, model, t0_j2000_s, kernel, gated, *, refit):
    """After a robust solve, as the batch route does: the rows the kernel exposed as outliers
    (whitened residual beyond the chi-square quantile ``options.reject_probability`` of their
    dimension) are rejected and, with ``refit`` (iSAM2), the chain is solved again by
    Gauss-Newton with the Gaussian model without them and the ``gated`` rows, so that
    iSAM2 and batch give the same solution. The fixed-lag smoother's windows are gone: its
    states stay, the rows are only marked rejected. Without this an outlier the Cauchy kernel
    had weighted by 1e-9 still entered the integrity chi-square with its full 1e5-sigma
    residual (the verdict failed a right solution that batch called ok).

    Returns ``(x, lin, P, row_weights, iterations)``: ``row_weights`` the kernel's weights,
    0 for the rejected rows."""

    exposed = outlier_mask(lin.residuals, options.reject_probability)
    dropped = {kind: gated[kind] | exposed[kind] if kind in exposed else gated[kind]
               for kind in gated}
    weights = {kind: np.where(dropped[kind], 0.0, w) if kind in dropped else w
               for kind, w in lin.weights.items()}
    iterations = 0
    if refit and any(m.any() for m in dropped.values()):
        x, lin, P, iterations = polish_chain(p, x, options.q_m2_s3, model, t0_j2000_s, None,
                                             dropped)
    return x, lin, P, weights, iterations


@contextlib.contextmanager
def _gc_paused():
    """Pause the cyclic garbage collector (see the module docstring); restore it after."""
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


def _warm_up(p, per_epoch, options, model, t0_j2000, x0, kernel):
    """Load the numba kernels of the first epoch's factors before the clock starts.

    The first call of a cached numba kernel in a process loads it from disk (0.1-0.3 s):
    a flight computer does this at start-up, not inside the first epoch's latency.
    """
    values = gtsam.Values()
    graph = gtsam.NonlinearFactorGraph()
    lay = layout_of(p)
    x0 = np.asarray(x0, dtype=float)
    _insert_block(values, lay, 0, x0 if len(x0) == lay.n else lay.initial(x0[None, :6])[0])
    x0 = x0[:6]
    for kind, rows in per_epoch[0]:
        if enters(p, kind):
            for f in factors_for_rows(p, kind, rows[:1], 0, kernel, x0):
                graph.add(f)
    if p.n_epochs > 1:
        dt = p.t_s[1] - p.t_s[0]
        values.insert(X(1), propagate(x0, dt, model, t0_j2000 + p.t_s[0])[0])
        graph.add(make_motion_factor(X(0), X(1), dt, options.q_m2_s3, model, t0_j2000 + p.t_s[0]))
    graph.linearize(values)


def _harvest(smoother, t_s, oldest, k_end, t_due, lagged_x, lagged_P, lagged_next, lay,
             imp=None, lagged_pair=None):
    """Read out the fixed-lag smoothed states from ``oldest`` up to (not including) the first
    at or after ``t_due`` s or ``k_end``; returns the index of the next state to read.

    Called before the update that would marginalize the oldest of them, so every state is
    reported smoothed with lag_s to lag_s + harvest_s of later data. In one block the
    marginals share GTSAM's cached clique shortcuts: 60 states cost ~4 ms, where one
    ``marginalCovariance`` per epoch cost ~3 ms each and, run between updates, doubled the
    latency of the next update (the stale cache is deleted inside the timed update, and the
    CPU caches are cold). The cache is dropped here, outside the latency.
    ``lagged_next[j]`` receives the estimate of state ``j + 1`` in the same window (for the
    motion chi-square, :func:`_motion_chi2`).
    The states are read from a full back-substitution of the window
    (``calculateBestEstimate``): the per-update estimate stops at the wildfire threshold
    (100 m, 100 m/s), so an old state read from it lags its own smoothed value; on a 1 h
    gto-transfer pass at 10 s the motion chi-square of the states read that way was 6e14,
    1e2 from the full back-substitution. Variables beyond the orbit state get their own
    marginal (their cross-covariance with the orbit is not read: block-diagonal here), except
    for several spacecraft, whose relative state needs the cross-covariances of their orbits:
    there the block's joint marginal (:func:`_joint_block`). A state ``j`` whose next step
    ends with a declared burn (``imp``) also leaves, in ``lagged_pair[j + 1]``, both orbit
    states of that window and their joint marginal (the burn's estimate,
    :func:`fgnav.graph.impulse_estimates`).
    """
    isam = smoother.getISAM2()
    est = isam.calculateBestEstimate() if oldest < k_end and t_s[oldest] < t_due else None
    j = oldest
    joint = len(lay.orbits) > 1   # several spacecraft: their relative state needs the joint
    while j < k_end and t_s[j] < t_due:
        lagged_x[j] = _read_block(est, lay, j)
        if joint:
            lagged_P[j] = _joint_block(isam, lay, j)
        else:
            lagged_P[j, :6, :6] = smoother.marginalCovariance(X(j))
            for v in lay.extra:
                sl = lay.slices[v.name]
                lagged_P[j, sl, sl] = smoother.marginalCovariance(v.key(j))
        if j + 1 < k_end:
            lagged_next[j] = _read_block(est, lay, j + 1)
            if imp and j + 1 in imp:
                jm = isam.jointMarginalCovariance(gtsam.KeyVector([X(j), X(j + 1)]))
                Pj = np.block([[jm.at(a, b) for b in (X(j), X(j + 1))] for a in (X(j), X(j + 1))])
                lagged_pair[j + 1] = (lagged_x[j][:6].copy(), lagged_next[j][:6].copy(), Pj)
        j += 1
    isam.deleteCachedShortcuts()
    return j


def _joint_block(isam, lay, k: int) -> np.ndarray:
    """The joint marginal covariance (n, n) of epoch ``k``'s block (every variable's key, in
    the layout's order) from the Bayes tree (``ISAM2.jointMarginalCovariance``)."""
    keys = [X(k)] + [v.key(k) for v in lay.extra]
    jm = isam.jointMarginalCovariance(gtsam.KeyVector(keys))
    return np.block([[jm.at(a, b) for b in keys] for a in keys])


def polish_chain(p: Pass, x: np.ndarray, q_m2_s3: float, model, t0_j2000_s: float, kernel,
                 rejected: dict | None, *, tol_sigma: float = 1e-5, max_iterations: int = 5):
    """Gauss-Newton iterations over the whole chain from ``x`` (N, 6), in SI units.

    Each iteration linearizes every factor at once and eliminates the chain with QR
    (:func:`fgnav.solvers.batch.linearize_and_eliminate`), the square-root information
    smoother of Bierman, "Factorization Methods for Discrete Sequential Estimation" (1977);
    the robust kernel enters as iteratively reweighted least squares and ``rejected``
    (kind -> (M,) bool) drops gated rows. Stops when every update is below ``tol_sigma`` of
    its marginal sigma: the next would be at the numerical floor of the problem (updates of
    1e-7 to 1e-6 sigma, < 1 mm, that no longer shrink: gto-transfer at 1 and 10 s steps).

    Returns ``(x, lin, P, iterations)``: the states, the linearization of the last
    iteration (residuals, chi-square), the marginal covariances (N, 6, 6), the count.
    """
    for it in range(1, max_iterations + 1):
        lin = linearize_and_eliminate(p, x, q_m2_s3, model, t0_j2000_s, kernel, rejected)
        P = chain_marginals(lin.R, lin.S)
        dx = back_substitute(lin.R, lin.S, lin.d)
        if not np.all(np.isfinite(dx)):
            raise NotObservableError(f"{p.source}: the final Gauss-Newton update is not finite")
        x = layout_of(p).retract(x, dx)
        step = float(np.max(np.abs(dx) / np.sqrt(np.diagonal(P, axis1=1, axis2=2))))
        if step < tol_sigma:
            break
    return x, lin, P, it


def _motion_chi2(p, x, x_next, q, model, t0_j2000, imp=None):
    """Chi-square of the motion factors of a fixed-lag run: step k -> k + 1 evaluated at
    ``x[k]`` and ``x_next[k]``, the two states of one window estimate (``x[k + 1]`` where
    ``x_next`` is NaN: the last state, read with its predecessor in the final block); a step
    that ends with a declared burn (``imp``, :func:`fgnav.graph.impulses`) with its rows
    (``factors.motion.impulse_rows``)."""
    if p.n_epochs < 2:
        return 0.0
    nxt = np.where(np.isnan(x_next[:-1, :6]), x[1:, :6], x_next[:-1, :6])
    dt = np.diff(p.t_s)
    e, _, _ = motion_residual(x[:-1, :6], nxt, dt, model, t0_j2000 + p.t_s[:-1])
    w = np.einsum("kij,kj->ki", process_noise_sqrt_information(dt, q), e)
    for k, (mean, cov) in (imp or {}).items():
        w[k - 1] = impulse_rows(x[k - 1, :6], nxt[k - 1], dt[k - 1], q, model,
                                t0_j2000 + p.t_s[k - 1], mean, cov)[2]
    return float(np.sum(w * w))


CHECKPOINT_FORMAT = "fgnav isam2 checkpoint 2"


def _fingerprint(p: Pass, options: SmootherOptions, inc: IncrementalOptions, method: str) -> str:
    """Identifies the run a checkpoint belongs to: the pass's epochs and every value of every
    row (not only epochs and sigmas: two logs with the same epochs differ in their values),
    and every option that changes the answer."""
    h = hashlib.sha256()
    h.update(str(np.datetime64(p.epoch0, "ns")).encode())
    h.update(np.ascontiguousarray(p.t_s, dtype=float).tobytes())
    for kind, fam in sorted(p.families.items()):
        h.update(kind.encode())
        h.update(np.ascontiguousarray(fam.k, dtype=np.int64).tobytes())
        h.update(np.ascontiguousarray(fam.sigma, dtype=float).tobytes())
        for name, v in sorted(fam.values.items()):
            h.update(name.encode())
            v = np.ascontiguousarray(v)
            h.update(str((v.dtype.str, v.shape)).encode())
            h.update(v.tobytes())
    if p.manoeuvres is not None:   # declared burns change the motion
        h.update(b"manoeuvre")
        h.update(np.ascontiguousarray(p.manoeuvres.k, dtype=np.int64).tobytes())
        h.update(np.ascontiguousarray(p.manoeuvres.sigma, dtype=float).tobytes())
        h.update(np.ascontiguousarray(p.manoeuvres.values["dv_mps"], dtype=float).tobytes())
    h.update(repr((CHECKPOINT_FORMAT, method, options, inc, p.layout.names)).encode())
    return h.hexdigest()


def _save_checkpoint(path, fingerprint, k_next, online_x, online_P, latency, x_est, rejected_rows):
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)  # e.g. inside --out
    buf = io.BytesIO()
    np.savez(buf, format=CHECKPOINT_FORMAT, fingerprint=fingerprint, k_next=k_next,
             online_x=online_x[:k_next], online_P=online_P[:k_next], latency=latency[:k_next],
             x_est=x_est, **{f"rejected_rows/{kind}": m for kind, m in rejected_rows.items()})
    with atomic_writer(path, "wb") as f:
        f.write(buf.getvalue())


def _foreign_checkpoint(path) -> UserError:
    return UserError(f"{path}: the checkpoint belongs to another log or other options "
                     f"(its fingerprint of the log's values and the options differs)")


def _load_checkpoint(path, fingerprint, online_x, online_P, latency, rejected_rows, n_block=6):
    """Read and validate a checkpoint written by :func:`_save_checkpoint` for this run.

    Anything else -- a missing, empty, truncated or foreign file, a pickle, missing or
    extra arrays, wrong shapes or dtypes, non-finite values, an epoch count out of range,
    another log or other options -- is a :class:`UserError` that says what is wrong.
    Fills ``online_x``, ``online_P``, ``latency`` up to the saved epoch; returns
    ``(k_next, x_est, rejected_rows)``; ``x_est`` (k_next, n_block) the block values.
    """
    N = len(online_x)

    def bad(what):
        return UserError(f"{path}: not a usable fgnav checkpoint ({what}); delete it, or run "
                         f"without --resume to start from the first epoch")

    if not os.path.exists(path):
        raise UserError(f"{path}: no checkpoint to resume from")
    if os.path.isdir(path):
        raise UserError(f"{path}: the checkpoint is a directory, expected a file")
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        raise UserError(f"{path}: cannot read the checkpoint: {exc.strerror or exc}") from None
    if not data:
        raise bad("the file is empty")
    if not data.startswith(b"PK"):
        raise bad("not an .npz archive")
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            arrays = {name: z[name] for name in z.files}
    except Exception as exc:  # noqa: BLE001 - any failure to parse a foreign file: zipfile,
        # zlib, struct, EOF, pickle refusal (ValueError) ... means "not a checkpoint"
        raise bad(f"unreadable: {type(exc).__name__}: {exc}") from None
    expected = {"format", "fingerprint", "k_next", "online_x", "online_P", "latency", "x_est"}
    expected |= {f"rejected_rows/{kind}" for kind in rejected_rows}
    missing, extra = sorted(expected - set(arrays)), sorted(set(arrays) - expected)
    if "format" in arrays and arrays["format"].dtype.kind == "U" and arrays["format"].shape == () \
            and str(arrays["format"]) != CHECKPOINT_FORMAT:
        raise bad(f"format '{arrays['format']}', this version reads '{CHECKPOINT_FORMAT}'")
    fp = arrays.get("fingerprint")
    if fp is not None and fp.shape == () and fp.dtype.kind == "U" and str(fp) != fingerprint:
        # before the per-family arrays: another set of options (e.g. --estimate) has other
        # families, and a sound checkpoint of another run is not "unusable"
        raise _foreign_checkpoint(path)
    if missing:
        raise bad(f"missing arrays: {', '.join(missing)}")
    if extra:
        raise bad(f"unexpected arrays: {', '.join(extra)}")
    for name in ("format", "fingerprint"):
        a = arrays[name]
        if a.shape != () or a.dtype.kind != "U":
            raise bad(f"'{name}' must be a string, found dtype {a.dtype} shape {a.shape}")
    if str(arrays["format"]) != CHECKPOINT_FORMAT:
        raise bad(f"format '{arrays['format']}', this version reads '{CHECKPOINT_FORMAT}'")
    kk = arrays["k_next"]
    if kk.shape != () or kk.dtype.kind not in "iu":
        raise bad(f"'k_next' must be an integer, found dtype {kk.dtype} shape {kk.shape}")
    k = int(kk)
    if not 1 <= k <= N:
        raise bad(f"'k_next' = {k} outside 1..{N}, the epochs of this log")
    for name, shape in (("online_x", (k, 6)), ("online_P", (k, 6, 6)), ("latency", (k,)),
                        ("x_est", (k, n_block))):
        a = arrays[name]
        if a.shape != shape or a.dtype != np.float64:
            raise bad(f"'{name}' must be float64 of shape {shape}, found {a.dtype} {a.shape}")
        if not np.all(np.isfinite(a)):
            raise bad(f"'{name}' holds NaN or infinite values")
    rows = {}
    for kind, m in rejected_rows.items():
        a = arrays[f"rejected_rows/{kind}"]
        if a.shape != m.shape or a.dtype != np.bool_:
            raise bad(f"'rejected_rows/{kind}' must be bool of shape {m.shape}, found "
                      f"{a.dtype} {a.shape}")
        rows[kind] = a.copy()
    online_x[:k], online_P[:k], latency[:k] = arrays["online_x"], arrays["online_P"], arrays["latency"]
    return k, arrays["x_est"], rows


def _predicted_covariance(p, lay, k, Phis, online_P, online_V, dt, q, P_start=None):
    """The covariance of epoch ``k``'s block predicted from the online estimate of ``k - 1``
    (for the gate): orbit ``Phi P Phi^T + Q``. With further variables, from their joint
    online marginal with the orbit at ``k - 1`` (``online_V``; a bias and the radial
    position are strongly correlated, so their separate marginals would overstate the
    spread of the tangent height they predict) plus each one's random-walk step
    ``psd dt``, each further orbit (a formation's) by its own ``Phis`` (the orbits' state
    transition matrices, in the layout's order) and ``Q``; at the first epoch ``P_start``
    when given (every spacecraft's prior rows), else the prior rows' and their priors."""
    if k == 0 and P_start is not None:
        return np.array(P_start, dtype=float)
    P = np.zeros((lay.n, lay.n))
    if k == 0 or not lay.extra:
        P[:6, :6] = (prior_covariance(p) if k == 0 else
                     Phis[0] @ online_P[k - 1] @ Phis[0].T + process_noise(dt, q))
        for v in lay.extra:
            sl = lay.slices[v.name]
            P[sl, sl] = np.eye(v.dim) * v.prior_sigma ** 2
        return P
    F = np.eye(lay.n)
    for v, Phi in zip(lay.orbits, Phis):
        F[lay.slices[v.name], lay.slices[v.name]] = Phi
    P = F @ online_V[k - 1] @ F.T
    Q = process_noise(dt, q)
    for v in lay.variables:
        sl = lay.slices[v.name]
        P[sl, sl] += Q if v.orbit else np.eye(v.dim) * float(v.step_sigma(dt)) ** 2
    return P


def _read_variable_marginals(estimator, lay, k, online_V):
    """Epoch ``k``'s block's joint marginal covariance (orbit and further variables) from
    iSAM2 / the fixed-lag smoother into ``online_V[k]`` (for the next epoch's gate)."""
    if not lay.extra:
        return
    isam = estimator.getISAM2() if hasattr(estimator, "getISAM2") else estimator
    J = isam.jointMarginalCovariance([v.key(k) for v in lay.variables])
    for a in lay.variables:
        for b in lay.variables:
            online_V[k][lay.slices[a.name], lay.slices[b.name]] = J.at(a.key(k), b.key(k))


def _gate_update(p, lay, kind, rows, x, P):
    """The gate's state and covariance after the kept ``rows`` of a family that measures
    further variables alone (attitude rows) at an epoch: a Kalman update, as the EKF's
    sequential processing of an epoch's families does, so that the epoch's attitude rows
    tighten the attitude its body-frame rows are gated with (without it the attitude's
    predicted spread let 3-degree outliers through). ``(x, P)`` unchanged without rows."""
    if not len(rows):
        return x, P
    fam = p.families[kind]
    _, A, b, _ = linearize_family(p, kind, fam.subset(np.asarray(rows), 0), x[None])
    A = A.reshape(-1, lay.n)
    b = b.reshape(-1)
    S = A @ P @ A.T + np.eye(len(b))
    K = np.linalg.solve(S, A @ P).T
    P = P - K @ A @ P
    return lay.retract(x, K @ b), 0.5 * (P + P.T)


def _gate_rows(p, kind, rows, x_pred, P_pred, probability):
    """The rows whose innovation at the predicted block passes the chi-square gate."""
    fam = p.families[kind]
    keep = []
    for j in rows:
        _, A, b, _ = linearize_family(p, kind, fam.subset(np.array([j]), 0), x_pred[None])
        b = b.reshape(-1)
        if passes_gate(A.reshape(len(b), -1), b, P_pred, probability)[0]:
            keep.append(j)
    return np.array(keep, dtype=int)
