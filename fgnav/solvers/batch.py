"""Batch smoothing of a whole pass: our own Gauss–Newton loop around GTSAM's QR elimination.

Each iteration linearizes every factor at once (vectorized residuals from ``factors/``, the
motion factor's propagation and STM in numba), hands GTSAM one pre-whitened
``JacobianFactor`` per epoch on ``(X_k, X_{k+1})`` — the epoch's measurement rows stacked
over the motion rows ``W [-Phi_k, I]`` with ``W^T W = Q_k^-1`` — and eliminates the chain in
time order with ``EliminateQR`` (GTSAM's Cholesky elimination throws on this
ill-conditioned problem). The resulting Bayes net gives the update by back-substitution and
every marginal covariance by the O(N) recursion of :mod:`fgnav.solvers.chain`.

GTSAM's own optimizers call Python factors with a copy of all values, which makes them
O(N^2) on a pass; this loop is O(N) per iteration.

Convergence from a poor first guess uses continuation on the process noise: solve first with
a loose white-acceleration PSD, then tighten by ``continuation_factor`` per stage down to the
requested ``q_m2_s3`` (a continuation method: Allgower & Georg 2003).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np

from factors.dynamics import MotionModel
from factors.errors import ModelDomainError
from fgnav.errors import NotObservableError
from fgnav.graph import (PRIOR_KINDS, PROCESS_CHUNK, chain_pair, impulse_estimates,
                         initial_block, layout_of, linearize_all, step_rows)
from fgnav.robust import DOWNWEIGHTED_BELOW, RobustKernel, chi2_gate
from fgnav.measurements import Pass, directions_in_eci
from fgnav.models.registry import ATTITUDE_RATE, ATTITUDE_VARIABLE, MODELS, ORBIT
from factors import interpret
from fgnav.solvers.ekf import run_ekf
from fgnav.solvers.ekf_numba import numba_supports, run_ekf_numba
from fgnav.solvers.rts import rts_smooth
from fgnav.iod.prior import initial_guess
from fgnav.solvers.options import SmootherOptions
from fgnav.solvers.state_elements import chart_of
from fgnav.solution import Solution
from fgnav.solvers.chain import back_substitute, chain_marginals
from fgnav.solvers.variables import block_variables
from fgnav.time import j2000_seconds

_UNIT = {}


def _unit(dim: int):
    m = _UNIT.get(dim)
    if m is None:
        m = _UNIT[dim] = gtsam.noiseModel.Unit.Create(dim)
    return m


X = gtsam.symbol_shorthand.X


@dataclass
class Linearization:
    R: np.ndarray        # (N,n,n) conditionals (n: the pass's block size, 6 for the orbit alone)
    S: np.ndarray        # (N,n,n)
    d: np.ndarray        # (N,n)
    chi2_meas: float
    chi2_motion: float
    residuals: dict
    weights: dict
    col_norm: np.ndarray | None = None  # (N,n) column norms of the whitened system
    _marginals: np.ndarray | None = field(default=None, repr=False)

    def marginals(self) -> np.ndarray:
        """The marginal covariances (N,n,n) of every state (:func:`chain_marginals` of the
        conditionals), formed at the first call: the convergence test by sigma and the
        solution's covariances use the same ones."""
        if self._marginals is None:
            self._marginals = chain_marginals(self.R, self.S)
        return self._marginals


process_blocks = step_rows
"""Every step's whitened motion and process rows (:func:`fgnav.graph.step_rows`)."""


class _Factors:
    """The pass linearized at ``Xs``: its pre-whitened JacobianFactors, one per epoch (epoch
    k's measurement rows over the motion rows of step k -> k + 1), made on demand for a range
    of epochs (:meth:`make`), so that a long pass is never held as one graph."""

    def __init__(self, p: Pass, Xs: np.ndarray, q: float, model: MotionModel, t0_j2000_s: float,
                 robust=None, rejected=None, chart=None):
        N = p.n_epochs
        n = layout_of(p).n
        self.N, self.n = N, n
        self.rows = rows = linearize_all(p, Xs, robust, rejected)
        self.starts = np.searchsorted(rows.k, np.arange(N + 1))
        # the rows on X_k of the motion steps, in parts of 2 PROCESS_CHUNK steps (or one part)
        # that eliminate_in_chunks(release=True) frees once their epochs are eliminated
        self.A0_parts, self.W, self.b_mot = process_blocks(p, Xs, q, model, t0_j2000_s,
                                                           chunked=chart is None)
        if chart is not None:   # the orbit in other coordinates (--state elements)
            J = chart.jacobian(Xs)
            rows.A = chart.chain(rows.A[:, None], J[rows.k])[:, 0]
            self.A0_parts = [chart.chain(self.A0_parts, J[:-1])]   # one array (not chunked)
            self.W = chart.chain(self.W, J[1:])
            if rows.steps is not None:
                sk, sA0, sA1, sb = rows.steps
                rows.steps = (sk, chart.chain(sA0[:, None], J[sk])[:, 0],
                              chart.chain(sA1[:, None], J[sk + 1])[:, 0], sb)
        self.A0_starts = np.cumsum([0] + [len(a) for a in self.A0_parts])
        # rows between epochs k and k + 1 (a gyro interval), stacked under step k's motion rows
        if rows.steps is not None:
            self.s_k, self.s_A0, self.s_A1, self.s_b = rows.steps
            self.s_starts = np.searchsorted(self.s_k, np.arange(N + 1))
        else:
            self.s_k = np.zeros(0, dtype=int)
            self.s_A0 = self.s_A1 = np.zeros((0, n))
            self.s_b = np.zeros(0)
            self.s_starts = np.zeros(N + 1, dtype=int)
        A_rows, b_rows, s_b, s_k = rows.A, rows.b, self.s_b, self.s_k
        self.chi2_meas = float(b_rows @ b_rows + s_b @ s_b)
        self.chi2_motion = float(np.sum(self.b_mot * self.b_mot))
        col2 = np.zeros((N, n))
        np.add.at(col2, rows.k, A_rows * A_rows)
        np.add.at(col2, s_k, self.s_A0 * self.s_A0)
        np.add.at(col2, s_k + 1, self.s_A1 * self.s_A1)
        # per chunk of steps (no (N, n, n) temporaries), the A0 terms first, as one sum would
        for A, shift in ((None, 0), (self.W, 1)):
            for c0 in range(0, N - 1, PROCESS_CHUNK):
                c1 = min(N - 1, c0 + PROCESS_CHUNK)
                Ac = np.ascontiguousarray(A[c0:c1] if A is not None else self._A0_steps(c0, c1))
                col2[c0 + shift:c1 + shift] += np.sum(Ac * Ac, axis=1)
        self.col_norm = np.sqrt(col2)

    def _A0_steps(self, c0: int, c1: int) -> np.ndarray:
        """The motion rows on X_k of steps c0..c1-1 (within one part: a view)."""
        i = int(np.searchsorted(self.A0_starts, c0, side="right")) - 1
        s0 = self.A0_starts[i]
        if c1 <= self.A0_starts[i + 1]:
            return self.A0_parts[i][c0 - s0:c1 - s0]
        return self._A0_take(np.arange(c0, c1))

    def _A0_take(self, km: np.ndarray) -> np.ndarray:
        """The motion rows on X_k of the steps ``km`` (increasing), a copy."""
        part = np.searchsorted(self.A0_starts, km, side="right") - 1
        if part[0] == part[-1]:
            return self.A0_parts[part[0]][km - self.A0_starts[part[0]]]
        return np.concatenate([self.A0_parts[i][km[part == i] - self.A0_starts[i]]
                               for i in range(part[0], part[-1] + 1)])

    def release(self, k: int) -> None:
        """Free the motion rows of the parts whose steps all precede step ``k``."""
        for i, a in enumerate(self.A0_parts):
            if a is not None and self.A0_starts[i + 1] <= k:
                self.A0_parts[i] = None

    def add_to(self, graph, k0: int, k1: int) -> None:
        """Add the factors of epochs k0..k1-1 to ``graph`` in epoch order (none for an epoch
        without one), each made by GTSAM inside ``graph.add`` (one call into GTSAM per factor
        instead of a JacobianFactor made in Python and then pushed: the same factor)."""
        N, n = self.N, self.n
        A_rows, b_rows = self.rows.A, self.rows.b
        starts, s_starts = self.starts[k0:k1 + 1], self.s_starts[k0:k1 + 1]
        # Stack each epoch's measurement rows over its motion rows, grouped by row count so
        # the stacking is one numpy call per group rather than one per epoch (0.45 -> 0.35 s
        # per iteration at 14,400 epochs, same factors in the same order).
        counts, s_counts = np.diff(starts), np.diff(s_starts)
        args = [None] * (k1 - k0)
        x0 = X(0)   # a Symbol key: the character in the top byte, the index below it
        for m, ms in sorted(set(zip(counts.tolist(), s_counts.tolist()))):
            js = np.flatnonzero((counts == m) & (s_counts == ms))
            ks = js + k0
            idx = starts[js][:, None] + np.arange(m)
            Am, bm = A_rows[idx], b_rows[idx]
            mot = ks < N - 1
            km = ks[mot]
            if len(km):
                sidx = s_starts[js[mot]][:, None] + np.arange(ms)
                A0 = np.concatenate([Am[mot], self._A0_take(km), self.s_A0[sidx]], axis=1)
                A1 = np.concatenate([np.zeros((len(km), m, n)), self.W[km], self.s_A1[sidx]],
                                    axis=1)
                b = np.concatenate([bm[mot], self.b_mot[km], self.s_b[sidx]], axis=1)
                unit = _unit(m + n + ms)
                for i, k in enumerate(km.tolist()):
                    args[k - k0] = (x0 + k, A0[i], x0 + k + 1, A1[i], b[i], unit)
            if m and not mot.all():
                args[N - 1 - k0] = (x0 + N - 1, Am[~mot][0], bm[~mot][0], _unit(m))
        add = graph.add
        for a in args:
            if a is not None:
                add(*a)


def build_linear_graph(p: Pass, Xs: np.ndarray, q: float, model: MotionModel, t0_j2000_s: float,
                       robust=None, rejected=None):
    """The pass linearized at ``Xs`` (N, n): one pre-whitened JacobianFactor per epoch.

    Returns the GaussianFactorGraph, the chi-square of the measurement and process rows, the
    measurement rows (:class:`fgnav.graph.Rows`: residuals and robust weights per kind) and
    the norm of every column of the whitened system (N, n) (for :func:`_check_rank`).
    """
    fs = _Factors(p, Xs, q, model, t0_j2000_s, robust, rejected)
    graph = gtsam.GaussianFactorGraph()
    fs.add_to(graph, 0, fs.N)
    return graph, fs.chi2_meas, fs.chi2_motion, fs.rows, fs.col_norm


def _singular(source, exc):
    return NotObservableError(f"{source}: the linearized system is singular ({exc}); "
                              f"the measurements do not observe every state")


def _conditionals(bn, k0: int, k1: int, N: int, R, S, d) -> None:
    """Copy the conditionals of X_k0..X_{k1-1} (in ``bn``, in that order) into R, S, d.

    Each conditional of X_k (k < N - 1) is read as one matrix ``[R S d]`` (its augmented
    Jacobian, frontal columns then those of its parent X_{k+1}) and the chunk's matrices
    split with numpy: one call into GTSAM per conditional instead of three, the same values
    (40 % less time here)."""
    n = R.shape[1]
    at = bn.at
    k2 = min(k1, N - 1)   # the last state has no parent: read on its own below
    k0_rest = k0
    while k0_rest < k2:   # 2,048 at a time: the list of small arrays stays small (~1.5 MB)
        kb = min(k2, k0_rest + 2048)
        try:
            Ab = np.array([at(k - k0).augmentedJacobianUnweighted()
                           for k in range(k0_rest, kb)])
        except ValueError:   # pragma: no cover (matrices of different shapes)
            break
        if Ab.shape != (kb - k0_rest, n, 2 * n + 1):   # pragma: no cover
            break
        R[k0_rest:kb], S[k0_rest:kb] = Ab[:, :, :n], Ab[:, :, n:2 * n]
        d[k0_rest:kb] = Ab[:, :, 2 * n]
        k0_rest = kb
    for k in range(k0_rest, k1):
        c = at(k - k0)
        R[k] = c.R()
        d[k] = c.d()
        if k < N - 1:
            S[k] = c.S()


def _time_order(k0: int, k1: int):
    """The elimination ordering X_k0, ..., X_{k1-1}, made from the key list in one call."""
    x0 = X(0)   # a Symbol key: the character in the top byte, the index below it
    return gtsam.Ordering(range(x0 + k0, x0 + k1))


def eliminate_chain(graph, N: int, source: str = "", n: int = 6):
    """Eliminate X0..X_{N-1} (blocks of n) in time order with QR; the conditionals (R, S, d)."""
    ordering = _time_order(0, N)
    try:
        bn = graph.eliminateSequential(ordering, gtsam.EliminateQR)
    except RuntimeError as exc:  # IndeterminantLinearSystemException and kin
        raise _singular(source, exc) from exc
    R = np.empty((N, n, n))
    S = np.zeros((N, n, n))
    d = np.empty((N, n))
    _conditionals(bn, 0, N, N, R, S, d)
    return R, S, d


ELIMINATION_CHUNK = 20_000
"""Epochs eliminated at a time by :func:`eliminate_in_chunks`."""


def eliminate_in_chunks(fs: _Factors, source: str = "", chunk: int | None = None,
                        release: bool = False):
    """:func:`eliminate_chain` of the factors ``fs`` without building the whole graph: epochs
    ``chunk`` at a time, each chunk's graph holding its factors and, last, the factor on its
    first state left by eliminating the chunk before (GTSAM's partial sequential
    elimination). A chain's elimination gathers, for state k, its own factor and then the
    factor left by state k - 1, in that order, whether the graph is whole or cut: the
    conditionals are the same bit for bit (``tests/test_batch.py``), in bounded memory.
    ``release``: free the motion rows of ``fs`` as their epochs are eliminated (``fs`` cannot
    be eliminated again): they and the conditionals are not all held at once (1,000,000
    epochs: 288 MB less at the peak)."""
    N, n = fs.N, fs.n
    chunk = int(chunk or ELIMINATION_CHUNK)
    R = np.empty((N, n, n))
    S = np.zeros((N, n, n))
    d = np.empty((N, n))
    carried = None
    for k0 in range(0, N, chunk):
        k1 = min(N, k0 + chunk)
        graph = gtsam.GaussianFactorGraph()
        fs.add_to(graph, k0, k1)
        if carried is not None:
            graph.push_back(carried)
        ordering = _time_order(k0, k1)
        try:
            bn, rest = graph.eliminatePartialSequential(ordering, gtsam.EliminateQR)
        except RuntimeError as exc:  # IndeterminantLinearSystemException and kin
            raise _singular(source, exc) from exc
        _conditionals(bn, k0, k1, N, R, S, d)
        carried = rest.at(0) if k1 < N and rest.size() else None
        del graph, bn, rest
        if release:
            fs.release(k1)
    return R, S, d


def linearize_and_eliminate(p: Pass, Xs: np.ndarray, q: float, model: MotionModel,
                            t0_j2000_s: float, robust=None, rejected=None,
                            chart=None) -> Linearization:
    """Linearize the whole pass at ``Xs`` and eliminate it with GTSAM (QR), in chunks of
    epochs (:func:`eliminate_in_chunks`); ``chart``: the orbit's coordinates when not
    Cartesian (:mod:`fgnav.solvers.state_elements`)."""
    fs = _Factors(p, Xs, q, model, t0_j2000_s, robust, rejected, chart)
    R, S, d = eliminate_in_chunks(fs, p.source, release=True)
    return Linearization(R, S, d, fs.chi2_meas, fs.chi2_motion, fs.rows.residuals,
                         fs.rows.weights, fs.col_norm)


def _check_rank(p: Pass, lin: Linearization, rel_tol: float = 1e-13) -> None:
    """Refuse a rank-deficient linearization: a QR pivot below ``rel_tol`` times the norm of
    its own column of the whitened system (the column is then a combination of the columns
    eliminated before it, to rounding). Relative to each column rather than to the largest
    pivot, because the rows' scales legitimately differ by many orders of magnitude (two
    epochs 1 ms apart: motion rows ~1e11; a prior of sigma 1e-12 m: rows 1e12) while a
    well-observed state's smallest pivot is ~1e-3 (Golub & Van Loan, *Matrix Computations*,
    2013, sec. 5.4.1: rank from QR with the pivot judged against its column)."""
    diag = np.abs(np.diagonal(lin.R, axis1=1, axis2=2))
    scale = lin.col_norm if lin.col_norm is not None else np.full_like(diag, diag.max())
    bad = np.argwhere(~(diag >= rel_tol * scale))
    if len(bad):
        k, i = bad[0]
        comp = layout_of(p).component_names()[i]
        raise NotObservableError(
            f"{p.source}: state component {comp} at t = {p.t_s[k]:.3f} s is not observable "
            f"(zero pivot in the QR elimination); add measurements or a prior")


def smooth_batch(p: Pass, options: SmootherOptions = SmootherOptions(),
                 x_init: np.ndarray | None = None, *, progress=None,
                 min_shrink: float | None = None) -> Solution:
    """Smooth a whole pass; states and marginal covariances at every epoch.

    progress : optional callable(stage_q, iteration, max_update_m) for progress display.
    min_shrink : stop, not converged, at an update not at least this many times smaller than
        the one before (a start outside Gauss-Newton's region of fast convergence, where
        the steps shrink quadratically: Nocedal & Wright 2006, sec. 10.3).
    """
    t_start = time.perf_counter()
    model = options.motion_model()
    t0_j2000 = float(j2000_seconds(p.epoch0))
    Xs = None
    lay = layout_of(p)
    q_stages = []
    q = max(options.q_start_m2_s3, options.q_m2_s3)
    while q > options.q_m2_s3 * (1 + 1e-9):
        q_stages.append(q)
        q /= options.continuation_factor
    q_stages.append(options.q_m2_s3)
    kernel = RobustKernel.create(options.robust, options.robust_k)
    iterations = 0
    chart = chart_of(options)

    def converge(q, stage_kernel, rejected, tol_scale, max_iterations=options.max_iterations,
                 sigma_above=None):
        nonlocal Xs, iterations
        lin = None
        chi2_prev = step_prev = None
        for it in range(max_iterations):
            lin = None   # the previous linearization is not needed: free it first (memory)
            lin = linearize_and_eliminate(p, Xs, q, model, t0_j2000, stage_kernel, rejected,
                                          chart)
            _check_rank(p, lin)
            dx = back_substitute(lin.R, lin.S, lin.d)
            if not np.all(np.isfinite(dx)):
                raise NotObservableError(f"{p.source}: the Gauss-Newton update is not finite")
            X_old, Xs = Xs, (lay.retract(Xs, dx) if chart is None else chart.retract(lay, Xs, dx))
            dx_m = dx if chart is None else Xs[:, :6] - X_old[:, :6]   # the step in m, m/s
            del X_old
            iterations += 1
            step_r, step_v = (_orbit_steps(lay, dx) if chart is None else
                              (float(np.max(np.abs(dx_m[:, :3]))),
                               float(np.max(np.abs(dx_m[:, 3:6])))))
            if progress is not None:
                progress(q, iterations, step_r)
            if step_r < options.tol_position_m * tol_scale and step_v < options.tol_velocity_mps * tol_scale:
                return lin, True
            if min_shrink is not None and step_prev is not None and step_r * min_shrink > step_prev:
                return lin, False
            step_prev = step_r
            # At a tiny process noise the solution is only determined numerically to a small
            # fraction of its sigma (steps oscillate at ~0.1 m when sigma is ~3 km): converged
            # when every update is below tol_sigma of its own marginal sigma. On the first
            # update from the filter's states, sigma_above (N, 6) bounds the orbit's sigmas
            # from above: an update beyond tol_sigma of twice that bound cannot pass the
            # test, and its marginals (1,000,000 epochs: ~2 s) are not formed. (Not from the
            # iterated guess, whose first update passes the test.)
            tol = options.tol_sigma * tol_scale
            if not (it == 0 and sigma_above is not None and chart is None
                    and np.max(np.abs(dx[:, :6]) / (2.0 * sigma_above)) >= tol):
                sigma = np.sqrt(np.diagonal(lin.marginals(), axis1=1, axis2=2))
                if np.max(np.abs(dx) / sigma) < tol:
                    return lin, True
                del sigma
            del dx, dx_m   # (N, n) each: not held through the next linearization
            # ... or the cost no longer moves (a formation's carrier phase: relative states
            # known to microns beside absolute ones known to kilometres, whose steps keep a
            # numerical jitter far above the microns)
            chi2 = lin.chi2_meas + lin.chi2_motion
            if (options.tol_chi2_relative is not None and chi2_prev is not None
                    and abs(chi2_prev - chi2) <= options.tol_chi2_relative * chi2):
                return lin, True
            chi2_prev = chi2
        return lin, False

    converged = False
    guess = _ekf_guess(p, options) if x_init is None and kernel is None else None
    x_ekf, sigma_ekf = (None, None) if guess is None else guess
    del guess
    if x_ekf is not None:
        # The filtered trajectory, smoothed backward, is a first guess close enough for
        # Gauss-Newton at the target process noise: 1 iteration (smoothed once: 2; filtered
        # only: 3; from the prior: 7) on gto-transfer, the same solution to 0.6 mm at 14,401
        # epochs (1 Hz, 4 h).
        # Continuation from the prior if it fails.
        Xs = initial_block(p, x_ekf)[0]
        x_ekf = None   # not needed past the first guess (48 MB at 1,000,000 epochs)
        try:
            lin, converged = converge(options.q_m2_s3, None, None, 1.0, max_iterations=15,
                                      sigma_above=sigma_ekf)
        except (NotObservableError, ModelDomainError):
            converged = False
        if converged:
            q_stages = [options.q_m2_s3]
    if not converged:
        Xs = initial_block(p, initial_guess(p, model, t0_j2000))[0] if x_init is None else \
            _as_block(p, x_init)
        for stage, q in enumerate(q_stages):
            final = stage == len(q_stages) - 1
            # A redescending kernel (Cauchy) needs a good guess: Huber (convex) until the last
            # stage.
            stage_kernel = kernel
            if kernel is not None and kernel.name == "cauchy" and not final:
                stage_kernel = RobustKernel.create("huber")
            lin, converged = converge(q, stage_kernel, None, 1.0 if final else 100.0)
    rejected = None
    if kernel is not None:
        # Reject what the kernel exposed as outliers (beyond the chi-square gate of
        # probability 1 - 1e-6 for its dimension) and refit the rest with the Gaussian model:
        # the efficiency an M-estimator loses on good data comes back.
        weights_robust = lin.weights
        rejected = outlier_mask(lin.residuals, options.reject_probability)
        lin, converged = converge(q_stages[-1], None, rejected, 1.0)
        lin.weights = {k: np.where(rejected[k], 0.0, weights_robust[k]) if k in rejected else w
                       for k, w in weights_robust.items()}
    P = lin.marginals()
    manoeuvres = impulse_estimates(p, options.q_m2_s3, model, t0_j2000,
                                   chain_pair(Xs, lin.R, lin.S, P))
    if chart is not None:
        P = chart.covariance_to_cartesian(Xs, P)
    wall = time.perf_counter() - t_start
    return Solution(method="batch", epoch0=p.epoch0, t_s=p.t_s.copy(), x_eci=Xs[:, :6],
                    P_eci=P[:, :6, :6], variables=block_variables(lay, Xs, P),
                    P_block=P if lay.extra else None, iterations=iterations, chi2=lin.chi2_meas + lin.chi2_motion, wall_s=wall,
                    residuals=lin.residuals,
                    extras={"converged": bool(converged), "q_m2_s3": options.q_m2_s3,
                            "q_stages": q_stages, "chi2_measurements": lin.chi2_meas,
                            "chi2_motion": lin.chi2_motion,
                            "n_measurement_rows": int(sum(v.size for v in lin.residuals.values())),
                            "row_weights": lin.weights,
                            **({"manoeuvres": manoeuvres} if manoeuvres else {}),
                            **robust_counts(options, lin.weights)})


def _as_block(p, x):
    """Block values (N, n) from ``x`` given as (N, n) or as orbit states (N, 6)."""
    x = np.array(x, dtype=float)
    return x if x.shape[-1] == layout_of(p).n else initial_block(p, x)[0]


def _orbit_steps(lay, dx: np.ndarray) -> tuple[float, float]:
    """The largest position (m) and velocity (m/s) update of any orbit state in ``dx``."""
    cols = np.concatenate([np.arange(lay.slices[v.name].start, lay.slices[v.name].start + 6)
                           for v in lay.orbits]).reshape(-1, 6)
    return float(np.max(np.abs(dx[:, cols[:, :3]]))), float(np.max(np.abs(dx[:, cols[:, 3:]])))


RTS_FIRST_GUESS = True
"""Smooth the filter's states backward (:mod:`fgnav.solvers.rts`) before Gauss-Newton."""
ITERATED_GUESS = True
"""Filter and smooth once more, linearized about the smoothed states (compiled route)."""


def filtered_guess(p: Pass, options: SmootherOptions):
    """The numba EKF's states, smoothed backward (:mod:`fgnav.solvers.rts`) and, on the
    compiled route, filtered and smoothed once more about them (the iterated smoother), as a
    first guess, or None where it does not apply (measurement kinds it does not model,
    ``init="prior"``, or a filter that fails). See :func:`_ekf_guess`."""
    guess = _ekf_guess(p, options)
    return None if guess is None else guess[0]


def _ekf_guess(p: Pass, options: SmootherOptions):
    """``(x (N, 6), sigma (N, 6) or None)``: :func:`filtered_guess`'s states and the
    filter's standard deviations, float32, where they bound the smoother's from above (the
    filter has seen only the earlier measurements: Rauch, Tung & Striebel 1965) because it
    estimates the same variables (not with the attitude known); or None.

    Across a bridged gap (epochs inserted by :func:`fgnav.measurements.fill_gaps`) the numpy
    EKF gives the guess where the numba one does not apply: the prior propagated across the
    gap is off by its velocity error times the gap and more (refraction-leo, 1.5 h of data, a
    24 h gap, 1.5 h more: Gauss-Newton from there did not converge in 180 iterations, 40,000
    km RMS, while the filter's states are 0.6 km off and converge in a few iterations)."""
    if options.init != "auto":
        return None
    p_orbit = _orbit_only_pass(p)
    if p_orbit is None:
        return None
    try:
        sol_compiled = numba_supports(p_orbit) and not interpret.active()
        if sol_compiled:  # compiled: long passes
            sol = run_ekf_numba(p_orbit, options, normalized=False)
        elif (p.inserted is not None and p.inserted.any()) or p.manoeuvres is not None:
            # (declared manoeuvres: the numpy EKF puts the burns into its prediction)
            sol = run_ekf(p_orbit, replace(options, gate_probability=None, robust=None))
        else:
            return None
        x, P = sol.x_eci, sol.P_eci
        del sol   # its online copies (0.3 GB at 1,000,000 epochs)
        if not np.all(np.isfinite(x)):
            return None
        sigma = None
        if p_orbit is p and not (ITERATED_GUESS and sol_compiled):   # (see converge)
            sigma = np.sqrt(np.diagonal(P, axis1=1, axis2=2)).astype(np.float32)
        t0_j2000 = float(j2000_seconds(p.epoch0))
        if RTS_FIRST_GUESS and p.manoeuvres is None:   # (its backward pass has no burns)
            x = rts_smooth(p.t_s, x, P, options.motion_model(), options.q_m2_s3, t0_j2000)
        del P
        if ITERATED_GUESS and x is not None and sol_compiled:
            # once more, linearized about the smoothed states: the iterated smoother's step
            # is a Gauss-Newton step (Bell 1994), taken by the filter's kernel instead of
            # GTSAM's elimination (4 h at 1 Hz: ~0.05 s against ~0.2 s), after which the
            # batch's first update is below its test by sigma
            f = run_ekf_numba(p_orbit, options, x_lin=x)
            x_f, P_f = f.x_eci, f.P_eci
            del f
            x2 = rts_smooth(p.t_s, x_f, P_f, options.motion_model(), options.q_m2_s3, t0_j2000,
                            x_lin=x) if np.all(np.isfinite(x_f)) else None
            del x_f, P_f
            if x2 is not None:
                x = x2
    except (ValueError, ZeroDivisionError, np.linalg.LinAlgError, ModelDomainError):
        return None
    return None if x is None else (x, sigma)


def _orbit_only_pass(p: Pass) -> Pass | None:
    """The pass the numba EKF's first guess runs on: ``p`` itself, or, with the attitude as the
    only graph variable beside the orbit, ``p`` with the attitude known: its body-frame
    directions rotated into ECI with the attitude rows at their epochs
    (:func:`fgnav.measurements.directions_in_eci`) and the rows that need the attitude left
    out. None (no first guess) where a body-frame row has no attitude row at its epoch or
    another variable than the attitude (and its rate) is estimated. The guess is only a
    starting point: Gauss-Newton then solves the whole graph, so the solution is the same, in 3 iterations instead of 7 (orbit
    and attitude, 4 h of gto-transfer at 1 Hz)."""
    lay = layout_of(p)
    if not lay.extra:
        return p
    if lay.names not in ((ORBIT.name, ATTITUDE_VARIABLE.name),
                         (ORBIT.name, ATTITUDE_VARIABLE.name, ATTITUDE_RATE.name)):
        return None
    q = directions_in_eci(p)
    n_body = sum(len(f) for k, f in p.families.items() if MODELS[k].body_frame_of is not None)
    n_rotated = sum(int(np.sum(f.values.get("from_body", np.zeros(len(f), bool))))
                    for f in q.families.values())
    if n_rotated != n_body:
        return None
    fams = {k: f for k, f in q.families.items() if MODELS[k].enters(q.layout)}
    return replace(q, families=fams)


def outlier_mask(residuals: dict, probability: float) -> dict:
    """kind -> (M,) bool: measurements whose whitened squared norm exceeds the chi-square
    quantile ``probability`` of their dimension (priors never)."""
    out = {}
    for kind, r in residuals.items():
        if kind in PRIOR_KINDS:
            continue
        out[kind] = np.sum(r * r, axis=1) > chi2_gate(r.shape[1], probability)
    return out


def robust_counts(options: SmootherOptions, weights: dict) -> dict:
    """Summary entries: how many measurements the robust kernel down-weighted (weight below
    0.5) and how many were rejected (weight 0), by kind."""
    if options.robust is None:
        return {}
    meas = {k: w for k, w in weights.items() if k not in PRIOR_KINDS}
    return {"robust": options.robust,
            "downweighted": {k: int(np.sum((w < DOWNWEIGHTED_BELOW) & (w > 0))) for k, w in meas.items()},
            "rejected": {k: int(np.sum(w == 0)) for k, w in meas.items()}}
