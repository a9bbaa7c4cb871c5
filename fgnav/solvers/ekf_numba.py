"""The EKF baseline compiled with numba: the same filter as :mod:`fgnav.solvers.ekf`, ~40x faster.

Same math, step for step (SI, ECI, state ``x = [r_eci_m; v_eci_mps]``):

* predict: ``x <- f(x, dt)`` and ``Phi`` from the RK4 propagator with its exact discrete STM
  (``factors.dynamics.propagate_nb``, called directly), ``P <- Phi P Phi^T + Q(dt)`` with the
  white-acceleration process noise ``Q = q [[dt^3/3 I, dt^2/2 I], [dt^2/2 I, dt I]]``
  (Bar-Shalom eq. 6.2.2-12; ``factors.dynamics.process_noise``);
* update, per epoch, one measurement at a time (relinearized after each, in the order of
  ``fgnav.measurements.rows_by_epoch``), with the whitened rows
  ``A = H/sigma``, ``b = -e/sigma`` of the family's measurement model:
  ``S = A P A^T + I``, ``K = P A^T S^-1``, ``x <- x + K b``,
  ``P <- (I - K A) P (I - K A)^T + K K^T`` (Joseph form).

Residuals ``e`` and Jacobians ``H`` come from the models' row kernels in ``factors/``
(today the priors, the geocentric direction, the limb radius, the altimeter and the
attitude-free celestial angles), the same compiled functions their numpy residuals call. A
model declares its kernel (``numba_kernel``, ``numba_data``) in its own module; the dispatch
table is generated from the registered models (:func:`row_kernels`), and so is the compiled
chain that calls them (:func:`_call_kernel_impl`): no kind is named here. A pass with any other family, or with
graph variables beyond the orbit state, is not handled here: :func:`numba_supports` says so
and :func:`run_ekf_numba` raises ``ValueError`` naming the families, so the caller can fall
back to the numpy EKF (``fgnav.solvers.ekf``). Priors at epoch 0 are skipped (the initial
state is the prior).
The innovation covariance ``S`` is factored with a small in-kernel Cholesky (it is SPD:
``A P A^T + I``).
"""

from __future__ import annotations

import math
import time

import types

import numpy as np
from factors.jit import load_numba, njit, when_numba_loads

from factors.dynamics import process_noise_terms, propagate_nb
from factors.errors import ModelDomainError
from fgnav.graph import layout_of, prior_block_covariance
from fgnav.measurements import prior_covariance
from fgnav.models.registry import MODELS
from fgnav.solution import Solution
from fgnav.iod.prior import first_state
from fgnav.solvers.options import SmootherOptions
from fgnav.time import j2000_seconds

__all__ = ["ROW_KERNELS", "row_kernels", "numba_supports", "run_ekf_numba", "pack_pass", "first_state",
           "prior_covariance"]

def row_kernels(models) -> tuple:
    """The distinct row kernels of ``models``, in their order: the compiled EKF's dispatch
    table, generated from the models' ``numba_kernel`` (a model's code is the index of its
    kernel here). Each is ``kernel(x (6,), data (>= 3,), B (>= 2, 3), e (m,), H (m, 6)) ->
    rows written, or -1`` (the pass's rows are packed to the widest kernel's; each reads its
    own leading entries). Kernels are told apart by their Python function (``py_func``: a
    model built before numba was loaded holds the lazy kernel of :mod:`factors.jit`, a later
    one its numba dispatcher, both wrapping the same function)."""
    out, seen = [], set()
    for mdl in models:
        py = getattr(mdl.numba_kernel, "py_func", None)
        if py is not None and py not in seen:
            seen.add(py)
            out.append(mdl.numba_kernel)
    return tuple(out)


def _fingerprint(kernels) -> str:
    return ";".join(f"{k.__module__}.{k.__qualname__}" for k in kernels)


ROW_KERNELS = row_kernels(MODELS.values())
"""The row kernels of the registered models when this module was imported (the dispatch
table :func:`_rows` compiles in; :func:`row_kernels`)."""
_KERNELS = ROW_KERNELS       # the table _rows reads (numba dispatchers once numba is loaded)
_FINGERPRINT = _fingerprint(ROW_KERNELS)
_MAX_ROWS = 3             # rows of one measurement (the widest model's dim) in one update


def _code(mdl, kernels=None) -> int | None:
    """The kernel code of a model (its kernel's index in ``kernels``, default the registered
    models' table), or None if the compiled EKF has no kernel for it."""
    py = getattr(mdl.numba_kernel, "py_func", None)
    for i, kern in enumerate(row_kernels(MODELS.values()) if kernels is None else kernels):
        if py is not None and getattr(kern, "py_func", None) is py:
            return i
    return None


def _unsupported(p) -> list[str]:
    """The families of ``p`` that enter the graphs but have no row kernel here."""
    return [k for k in p.families
            if k in MODELS and MODELS[k].enters(p.layout) and _code(MODELS[k]) is None]


def numba_supports(p) -> bool:
    """True if every family of the pass has a row kernel here (rows that do not enter the
    graphs, such as ``attitude``, count against it: the callers then use the numpy EKF, as
    they always have), the pass's graph variables are the orbit state alone and it declares
    no manoeuvre (the numpy EKF puts a burn into its prediction, :func:`fgnav.solvers.ekf.run_ekf`)."""
    if getattr(p, "layout", None) is not None and p.layout.n != 6:
        return False
    if getattr(p, "manoeuvres", None) is not None:   # declared burns: the numpy EKF's predict
        return False
    return all(k in MODELS and _code(MODELS[k]) is not None for k in p.families)


# ----------------------------------------------------------------------------- kernel

@njit(cache=True)
def _chol_solve_inplace(S, Y, m, ncol):
    """Overwrite Y[:m, :ncol] with S^-1 Y for SPD S[:m, :m] (Cholesky; S is overwritten)."""
    for j in range(m):
        s = S[j, j]
        for p in range(j):
            s -= S[j, p] * S[j, p]
        if s <= 0.0:
            return False
        d = math.sqrt(s)
        S[j, j] = d
        for i in range(j + 1, m):
            s = S[i, j]
            for p in range(j):
                s -= S[i, p] * S[j, p]
            S[i, j] = s / d
    for c in range(ncol):
        for i in range(m):            # L z = y
            s = Y[i, c]
            for p in range(i):
                s -= S[i, p] * Y[p, c]
            Y[i, c] = s / S[i, i]
        for i in range(m - 1, -1, -1):  # L^T w = z
            s = Y[i, c]
            for p in range(i + 1, m):
                s -= S[p, i] * Y[p, c]
            Y[i, c] = s / S[i, i]
    return True


def _kernel_chain(kernels):
    """A function ``(code, x, data, B, e, H) -> kernels[code](x, data, B, e, H)`` (-1 for a
    code out of range) for numba to compile: one branch per kernel of the table, each a
    direct call of the kernel (a global of the generated function), generated from the
    table rather than written per kind."""
    lines = ["def chain(code, x, data, B, e, H):"]
    for i in range(len(kernels)):
        lines.append(f"    {'if' if i == 0 else 'elif'} code == {i}:\n"
                     f"        return _k{i}(x, data, B, e, H)")
    lines.append("    return -1")
    scope = {f"_k{i}": k for i, k in enumerate(kernels)}
    exec("\n".join(lines), scope)
    return scope["chain"]


def _dispatch_function(kernels=None):
    """A Python stub whose compiled form (a numba ``overload``) is :func:`_kernel_chain` of
    ``kernels`` (None: :data:`_KERNELS` as it is when numba compiles the caller)."""
    def call_kernel(code, x, data, B, e, H):
        raise NotImplementedError("compiled only (numba)")

    def register():
        from numba.extending import overload

        def typed(code, x, data, B, e, H):
            return _kernel_chain(_KERNELS if kernels is None else kernels)
        overload(call_kernel)(typed)
    when_numba_loads(register)
    return call_kernel


_call_kernel = _dispatch_function()


@njit(cache=True)
def _compiled_fingerprint():
    """The kernel table's fingerprint as compiled (numba's on-disk cache does not see a
    change of :data:`_KERNELS`, only of this file: :func:`_filter_for` compares)."""
    return _FINGERPRINT


@njit(cache=True)
def _rows(code, x, data, B, sigma, A, b, r0):
    """Whitened rows (A, b) of one measurement starting at row r0, by its model's row kernel
    (:data:`_KERNELS`, through the generated :func:`_kernel_chain`); returns the rows written, or -1 where the residual is undefined
    (limb: |r| <= R_limb)."""
    e = b[r0:]
    H = A[r0:]
    m = _call_kernel(code, x, data, B, e, H)
    if m < 0:
        return -1
    for i in range(m):
        b[r0 + i] = -b[r0 + i] / sigma
        for j in range(6):
            A[r0 + i, j] /= sigma
    return m


@njit(cache=True)
def _sandwich(M, P, T, out):
    """out <- M P M^T for 6x6 matrices (T: 6x6 scratch; out may be P)."""
    for i in range(6):
        for j in range(6):
            s = 0.0
            for p in range(6):
                s += M[i, p] * P[p, j]
            T[i, j] = s
    for i in range(6):
        for j in range(6):
            s = 0.0
            for p in range(6):
                s += T[i, p] * M[j, p]
            out[i, j] = s


@njit(cache=True)
def ekf_kernel(k_begin, k_end, t_s, t0_j2000, mu, j2, re, third, max_step, mu_sun, mu_moon, eph, q,
               g_ptr, g_code, g_row0, g_nmeas, g_dim, g_prior, m_data, m_B, m_sigma, x, P, xs,
               Ps, innov, innov_norm, x_lin):
    """Filter epochs ``k_begin <= k < k_end`` in place; returns -1, or the failing measurement.

    ``x_lin`` (N, 6), or (0, 6) for the extended filter: a trajectory to linearize the motion
    and the measurements about instead of the filter's own states (the linearized filter of
    an iterated smoother: Bell 1994), ``f(x) ~ f(x_lin) + Phi (x - x_lin)``,
    ``h(x) ~ h(x_lin) + H (x - x_lin)``.

    x (6,), P (6,6): state and covariance after epoch ``k_begin - 1`` (or the prior at 0).
    Groups of epoch k are ``g_ptr[k]:g_ptr[k+1]``; group g holds ``g_nmeas[g]`` measurements
    of the model with kernel code ``g_code[g]`` (``g_dim[g]`` rows each; ``g_prior[g]``: a
    prior, skipped at epoch 0) from packed row ``g_row0[g]``; ``m_data (M,3)`` their values,
    ``m_B (M,2,3)`` tangent bases, ``m_sigma (M,)`` 1-sigma; innovations ``-b`` go to
    ``innov (M,3)``, and, unless ``innov_norm`` is (0, 3), the normalized innovations
    ``L^-1 b`` (``S = L L^T`` the innovation covariance of the whitened rows: N(0, I) for a
    consistent filter; Bar-Shalom, Li & Kirubarajan 2001, eq. 5.4.1-1) to ``innov_norm (M,3)``.
    Writes xs[k], Ps[k].
    """
    x1 = np.empty(6)
    Phi = np.empty((6, 6))
    T = np.empty((6, 6))
    A = np.empty((_MAX_ROWS, 6))
    b = np.empty(_MAX_ROWS)
    AP = np.empty((_MAX_ROWS, 6))
    S = np.empty((_MAX_ROWS, _MAX_ROWS))
    Kt = np.empty((_MAX_ROWS, 6))
    IKA = np.empty((6, 6))
    lin = x_lin.shape[0] > 0
    for k in range(k_begin, k_end):
        if k > 0:
            dt = t_s[k] - t_s[k - 1]
            if lin:   # x <- f(x_lin) + Phi (x - x_lin), Phi at x_lin
                propagate_nb(x_lin[k - 1], dt, mu, j2, re, third, max_step, mu_sun, mu_moon,
                             eph, t0_j2000 + t_s[k - 1], True, x1, Phi)
                for i in range(6):
                    s = x1[i]
                    for j in range(6):
                        s += Phi[i, j] * (x[j] - x_lin[k - 1, j])
                    T[0, i] = s
                for i in range(6):
                    x[i] = T[0, i]
            else:
                propagate_nb(x, dt, mu, j2, re, third, max_step, mu_sun, mu_moon, eph,
                             t0_j2000 + t_s[k - 1], True, x1, Phi)
                for i in range(6):
                    x[i] = x1[i]
            # P <- Phi P Phi^T + Q
            _sandwich(Phi, P, T, P)
            qpp, qpv, qvv = process_noise_terms(dt, q)
            for i in range(3):
                P[i, i] += qpp
                P[i, 3 + i] += qpv
                P[3 + i, i] += qpv
                P[3 + i, 3 + i] += qvv
        for g in range(g_ptr[k], g_ptr[k + 1]):
            code = g_code[g]
            if g_prior[g] and k == 0:
                continue  # the initial state already is this prior
            r0 = g_row0[g]
            dim = g_dim[g]
            for jm in range(g_nmeas[g]):   # one measurement at a time, as the numpy EKF
                if lin:   # rows at x_lin, the innovation at x: b - A (x - x_lin)
                    m = _rows(code, x_lin[k], m_data[r0 + jm], m_B[r0 + jm], m_sigma[r0 + jm],
                              A, b, 0)
                    for i in range(max(m, 0)):
                        for j in range(6):
                            b[i] -= A[i, j] * (x[j] - x_lin[k, j])
                else:
                    m = _rows(code, x, m_data[r0 + jm], m_B[r0 + jm], m_sigma[r0 + jm], A, b, 0)
                if m < 0:
                    return r0 + jm
                # AP = A P ; S = AP A^T + I
                for i in range(m):
                    for j in range(6):
                        s = 0.0
                        for p in range(6):
                            s += A[i, p] * P[p, j]
                        AP[i, j] = s
                        Kt[i, j] = s
                for i in range(m):
                    for j in range(m):
                        s = 0.0
                        for p in range(6):
                            s += AP[i, p] * A[j, p]
                        S[i, j] = s
                    S[i, i] += 1.0
                if not _chol_solve_inplace(S, Kt, m, 6):
                    return r0 + jm
                if innov_norm.shape[0] > 0:   # L z = b with S's Cholesky factor, now in S
                    for i in range(m):
                        s = b[i]
                        for p in range(i):
                            s -= S[i, p] * innov_norm[r0 + jm, p]
                        innov_norm[r0 + jm, i] = s / S[i, i]
                # K = Kt^T (6 x m); x += K b
                for j in range(6):
                    s = 0.0
                    for i in range(m):
                        s += Kt[i, j] * b[i]
                    x[j] += s
                # IKA = I - K A
                for i in range(6):
                    for j in range(6):
                        s = 0.0
                        for p in range(m):
                            s += Kt[p, i] * A[p, j]
                        IKA[i, j] = (1.0 if i == j else 0.0) - s
                # P <- IKA P IKA^T + K K^T
                _sandwich(IKA, P, T, Phi)
                for i in range(6):
                    for j in range(6):
                        for p in range(m):
                            Phi[i, j] += Kt[p, i] * Kt[p, j]
                for i in range(6):
                    for j in range(6):
                        P[i, j] = Phi[i, j]
                for c in range(dim):   # the innovation -b
                    innov[r0 + jm, c] = -b[c]
        for i in range(6):
            xs[k, i] = x[i]
            for j in range(6):
                Ps[k, i, j] = P[i, j]
    return -1


_FRESH: dict = {}


def _filter_for(kernels):
    """The compiled filter (:func:`ekf_kernel`) for the kernel table ``kernels``: the one
    compiled (and cached on disk) with this module when the table is the one it was compiled
    with, else one compiled now for ``kernels`` (a model registered at run time, or an on-disk
    cache older than the models), not cached on disk."""
    global _KERNELS
    load_numba()
    table = tuple(k.dispatcher if hasattr(k, "py_func") and getattr(k, "dispatcher", None)
                  is not None else k for k in kernels)
    fp = _fingerprint(kernels)
    if fp == _FINGERPRINT:
        _KERNELS = table      # read only if _rows compiles now
        if _compiled_fingerprint() == fp:
            return ekf_kernel
    key = tuple(id(getattr(k, "py_func", k)) for k in kernels)   # these very functions
    if key not in _FRESH:
        import numba

        def fresh(dispatcher, **globs):
            f = dispatcher.py_func
            return numba.njit(types.FunctionType(f.__code__, {**f.__globals__, **globs},
                                                 f.__name__, f.__defaults__, f.__closure__))
        _FRESH[key] = fresh(ekf_kernel, _rows=fresh(_rows, _call_kernel=_dispatch_function(table)))
    return _FRESH[key]


# ----------------------------------------------------------------------------- packing

class Packed:
    """A pass flattened for the kernel (see :func:`ekf_kernel` for the array meanings)."""

    def __init__(self, g_ptr, g_code, g_row0, g_nmeas, g_dim, g_prior, m_data, m_B, m_sigma, spans):
        self.g_ptr, self.g_code, self.g_row0, self.g_nmeas = g_ptr, g_code, g_row0, g_nmeas
        self.g_dim, self.g_prior = g_dim, g_prior
        self.m_data, self.m_B, self.m_sigma = m_data, m_B, m_sigma
        self.spans = spans  # kind -> (first packed row, family row order (M_kind,))


def pack_pass(p, kernels=None) -> Packed:
    """Flatten the families of a pass into (epoch, family) groups, in the order the numpy
    EKF updates (epoch, then family order in ``p.families``, rows by family order); a
    family's kernel code indexes ``kernels`` (default: :func:`row_kernels` of the registered
    models)."""
    if kernels is None:
        kernels = row_kernels(MODELS.values())
    unsupported = _unsupported(p)
    if unsupported or p.layout.n != 6:
        raise ValueError(f"the numba EKF has no kernel for {', '.join(unsupported) or 'the pass'}"
                         f"{'' if unsupported else ' (graph variables beyond the orbit state)'} "
                         f"(use fgnav.solvers.ekf)")
    N = p.n_epochs
    datas, Bs, sigmas, spans = [], [], [], {}
    g_k, g_fam, g_code, g_row0, g_n, g_dim, g_prior = [], [], [], [], [], [], []
    row = 0
    used = [(fi, kind, fam, MODELS.get(kind)) for fi, (kind, fam) in enumerate(p.families.items())]
    used = [(fi, kind, fam, mdl, mdl.numba_data(fam)) for fi, kind, fam, mdl in used
            if mdl is not None and mdl.enters(p.layout)]
    # one width for every family's packed rows: the widest kernel's (>= (3,), (2, 3))
    n_data = max([3] + [np.asarray(d).reshape(len(fam), -1).shape[1] for *_, fam, _, (d, _) in used])
    n_B = max([2] + [np.asarray(b).shape[1] for *_, (_, b) in used if b is not None])
    for fi, kind, fam, mdl, (d, b) in used:
        code = _code(mdl, kernels)
        M = len(fam)
        order = np.argsort(fam.k, kind="stable")
        ks = fam.k[order]
        data = np.zeros((M, n_data))
        B = np.zeros((M, n_B, 3))
        d = np.asarray(d, dtype=float).reshape(M, -1)[order]
        data[:, :d.shape[1]] = d
        if b is not None:
            b = np.asarray(b, dtype=float)[order]
            B[:, :b.shape[1]] = b
        sig = np.asarray(fam.sigma, dtype=float)[order]
        if np.any(~(sig > 0)):
            raise ValueError(f"{kind}: sigma must be positive")
        uk, first, counts = np.unique(ks, return_index=True, return_counts=True)
        if mdl.dim > _MAX_ROWS:
            raise ValueError(f"{kind}: {mdl.dim} rows per measurement, more than {_MAX_ROWS}")
        g_k.append(uk)
        g_fam.append(np.full(len(uk), fi))
        g_code.append(np.full(len(uk), code))
        g_row0.append(row + first)
        g_n.append(counts)
        g_dim.append(np.full(len(uk), mdl.dim))
        g_prior.append(np.full(len(uk), mdl.prior))
        datas.append(data)
        Bs.append(B)
        sigmas.append(sig)
        spans[kind] = (row, order)
        row += M
    if not g_k:
        raise ValueError("the pass has no measurement the numba EKF can use")
    gk = np.concatenate(g_k)
    o = np.lexsort((np.concatenate(g_fam), gk))
    g_ptr = np.searchsorted(gk[o], np.arange(N + 1)).astype(np.int64)

    def cat(parts, dtype=np.int64):
        return np.concatenate(parts)[o].astype(dtype)

    return Packed(g_ptr, cat(g_code), cat(g_row0), cat(g_n), cat(g_dim), cat(g_prior, np.bool_),
                  np.ascontiguousarray(np.concatenate(datas)), np.ascontiguousarray(np.concatenate(Bs)),
                  np.concatenate(sigmas), spans)


# ----------------------------------------------------------------------------- driver

def run_ekf_numba(p, options=None, *, progress=None, step_latency: bool = False,
                  x_lin: np.ndarray | None = None, normalized: bool | None = None) -> Solution:
    """Filter the pass forward with the numba kernel; the same :class:`Solution` as
    ``fgnav.solvers.ekf.run_ekf`` (filtered states/covariances, innovations as residuals).

    options : ``fgnav.solvers.options.SmootherOptions`` (q_m2_s3, motion model); default one.
    progress : optional callable(k); when given the kernel runs in chunks of ~1 % of the pass.
    step_latency : time every epoch separately (one kernel call per epoch from Python, so
        ``latency_s`` includes the call overhead a Python host loop would pay); otherwise
        the pass runs in one call and ``latency_s`` is the mean step time at every epoch.
    x_lin : (N, 6) a trajectory to linearize about (the linearized filter, :func:`ekf_kernel`).
    normalized : keep the normalized innovations (``extras["normalized_innovations"]``, for
        the verdict); default: when the filter runs as a method (``x_lin`` None).
    """
    if options is None:
        options = SmootherOptions()
    t_start = time.perf_counter()
    model = options.motion_model()
    t0_j2000 = float(j2000_seconds(p.epoch0))
    N = p.n_epochs
    kernels = row_kernels(MODELS.values())
    kern = _filter_for(kernels)
    pk = pack_pass(p, kernels)
    x = np.array(first_state(p, model, t0_j2000), dtype=float)
    P = prior_block_covariance(layout_of(p), [prior_covariance(p)])   # the orbit alone
    xs = np.empty((N, 6))
    Ps = np.empty((N, 6, 6))
    innov = np.full((len(pk.m_sigma), 3), np.nan)
    if normalized is None:
        normalized = x_lin is None
    innov_norm = np.full((len(pk.m_sigma) if normalized else 0, 3), np.nan)
    mu, j2, re, third, hmax, mus, mum, eph = model.args()
    t_s = np.ascontiguousarray(p.t_s, dtype=float)
    q = float(options.q_m2_s3)
    if not q > 0.0:
        raise ValueError(f"q_m2_s3 must be positive (m^2/s^3), got {q!r}")
    args = (t_s, t0_j2000, mu, j2, re, third, hmax, mus, mum, eph, q, pk.g_ptr, pk.g_code,
            pk.g_row0, pk.g_nmeas, pk.g_dim, pk.g_prior, pk.m_data, pk.m_B, pk.m_sigma, x, P, xs, Ps, innov,
            innov_norm, np.zeros((0, 6)) if x_lin is None else np.ascontiguousarray(x_lin[:, :6], dtype=float))
    latency = np.empty(N)
    t_load = time.perf_counter()
    kern(0, 0, *args)   # an empty range: loads (or compiles) the kernel outside the timing
    load_s = time.perf_counter() - t_load
    if step_latency:
        bounds = np.arange(N + 1)
    elif progress is not None:
        bounds = np.unique(np.r_[np.arange(0, N, max(1, N // 100)), N])
    else:
        bounds = np.array([0, N])
    t_run = time.perf_counter()
    for a, bnd in zip(bounds[:-1], bounds[1:]):
        t_a = time.perf_counter()
        bad = kern(int(a), int(bnd), *args)
        if bad >= 0:
            kind = next(kd for kd, (r0, order) in pk.spans.items() if r0 <= bad < r0 + len(order))
            r0, order = pk.spans[kind]
            row = int(order[bad - r0])
            # a ModelDomainError (a ValueError): the solvers' callers tell the user, as for
            # the numpy EKF's undefined residuals
            raise ModelDomainError(
                f"numba EKF: {kind} row {row} at log line {int(p.families[kind].line[row])} "
                f"(t = {p.t_s[p.families[kind].k[row]]:.3f} s) has no defined residual or a "
                f"singular innovation covariance")
        latency[a:bnd] = (time.perf_counter() - t_a) / (bnd - a)
        if progress is not None:
            progress(int(bnd) - 1)
    run_s = time.perf_counter() - t_run
    residuals: dict[str, np.ndarray] = {}
    for kind, (r0, order) in pk.spans.items():
        dim = MODELS[kind].dim
        r = np.full((len(order), dim), np.nan)
        r[order] = innov[r0:r0 + len(order), :dim]
        if MODELS[kind].prior and np.all(np.isnan(r)):
            continue  # only the epoch-0 prior: never an update (as in run_ekf)
        residuals[kind] = r
    normalized_innovations = {}
    if normalized:
        for kind in residuals:
            r0, order = pk.spans[kind]
            z = np.full((len(order), MODELS[kind].dim), np.nan)
            z[order] = innov_norm[r0:r0 + len(order), :MODELS[kind].dim]
            normalized_innovations[kind] = z
    wall = time.perf_counter() - t_start
    return Solution(method="ekf", epoch0=p.epoch0, t_s=p.t_s.copy(), x_eci=xs, P_eci=Ps,
                    iterations=N, chi2=float(sum(np.nansum(r * r) for r in residuals.values())),
                    wall_s=wall, residuals=residuals, online_x_eci=xs.copy(), online_P_eci=Ps.copy(),
                    latency_s=latency,
                    extras={"q_m2_s3": options.q_m2_s3, "residuals_are": "innovations (prior)",
                            "latency_p50_s": float(np.median(latency)),
                            "ekf_kernel": "numba", "ekf_step_mean_s": run_s / max(N, 1),
                            "ekf_kernel_load_s": load_s,
                            "latency_is": "per step" if step_latency else "mean of the run",
                            **({"normalized_innovations": normalized_innovations}
                               if normalized else {})})
