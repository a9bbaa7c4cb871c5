"""Online navigation from rows as they arrive: the newest state at a cost that does not grow
with the history, the full history smoothed on demand.

The newest state comes from a bounded engine:

- ``isam2`` and ``fixed-lag``: GTSAM's ``IncrementalFixedLagSmoother`` (iSAM2 over the
  recent ``window_s``, resp. ``lag_s``; the states that leave it become a marginal prior on
  the oldest kept one: Dellaert & Kaess 2017, "Factor graphs for robot perception", sec. 5;
  Kaess et al. 2012, "iSAM2", IJRR 31(2)). Full-history iSAM2 grows by ~35 ns per past
  state and update (docs/gtsam-notes, "iSAM2's update cost grows with the history"), so
  the online route does not use it; its QR factorization as in
  :mod:`fgnav.solvers.incremental`;
- ``ekf``: the extended Kalman filter step of :func:`fgnav.solvers.ekf.run_ekf`
  (``P <- Phi P Phi^T + Q``, ``K = P A^T (A P A^T + I)^-1`` on whitened rows, Joseph form:
  :mod:`fgnav.solvers.kalman`, the same functions).

The full history is the batch chain solver over every row received
(:func:`fgnav.pipeline.smooth_log`, method batch): :meth:`Navigator.smoothed` on demand and
:meth:`Navigator.finish` at the end, the same numbers as ``fgnav smooth`` of the same rows.

Integrity live: each epoch's normalized innovation squared (NIS, ``b^T S^-1 b`` with
``S = A P_pred A^T + I``; Bar-Shalom, Li & Kirubarajan 2001, "Estimation with Applications
to Tracking and Navigation", sec. 5.4) is summed over a sliding window of
``integrity_window_s`` and over all data; each sum is tested against the chi-square of its
degrees of freedom: ``suspect`` below a tail probability of 1e-3, ``failed`` below 1e-6.
"""

from __future__ import annotations

import collections
import math
import time
from dataclasses import dataclass, replace

import numpy as np

from factors.errors import ModelDomainError
from fgnav.chi2 import chi2_logsf
from fgnav.errors import NotObservableError, UserError
from fgnav.graph import enters, layout_of, linearize_family, step_factors
from fgnav.io.log_csv import EXTRA_COLUMNS, VALUE_COLUMNS, MeasurementLog
from fgnav.iod.initial import initial_orbit, propagate_orbit
from fgnav.iod.prior import first_state, has_prior, strip_prior
from fgnav.measurements import build_pass, prior_covariance
from fgnav.models.registry import model as model_of
from fgnav.online.stream import Row
from fgnav.pipeline import scheme_preprocessed, smooth_log
from fgnav.robust import RobustKernel, passes_gate
from fgnav.solvers.incremental import isam2_params
from fgnav.solvers.kalman import (innovation_covariance, kalman_update, orbit_transition,
                                  predict_covariance)
from fgnav.solvers.options import IncrementalOptions, SmootherOptions
from fgnav.start import START_INFLATION
from fgnav.sun_earth_moon import preprocess_log, uses_scheme
from fgnav.time import format_utc, j2000_seconds

ONLINE_METHODS = ("isam2", "fixed-lag", "ekf")
DEFAULT_WINDOW_S = 600.0
"""The iSAM2 window of ``method="isam2"`` (s)."""
SUSPECT_LOGP = math.log(1e-3)
FAILED_LOGP = math.log(1e-6)
IOD_EPOCHS = (30, 60, 120, 240, 480, 960, 1920)
"""Without a prior: the epoch counts at which the initial orbit from the data is tried."""


@dataclass
class State:
    """The newest online state: epoch, ``t_s`` (s from the stream's first epoch), state
    ``x`` (6,) [m, m/s] ECI, covariance ``P`` (6, 6), the live verdict, the update latency
    (wall) and its CPU time."""

    ns: int
    t_s: float
    x: np.ndarray
    P: np.ndarray
    verdict: str
    latency_s: float
    k: int
    cpu_s: float = float("nan")

    def as_json(self) -> dict:
        sig = np.sqrt(np.maximum(np.diag(self.P), 0.0))
        return {"event": "epoch", "epoch": format_utc(np.datetime64(self.ns, "ns")),
                "t_s": round(self.t_s, 9), "r_eci_m": self.x[:3].tolist(),
                "v_eci_mps": self.x[3:].tolist(), "sigma_r_m": sig[:3].tolist(),
                "sigma_v_mps": sig[3:].tolist(), "verdict": self.verdict,
                "latency_s": self.latency_s, "cpu_s": self.cpu_s}


class RowStore:
    """Every row received, in compact growing arrays (the history the batch smooths)."""

    def __init__(self, width: int):
        self.n = 0
        self.ns = np.zeros(1024, np.int64)
        self.kind = np.zeros(1024, np.int16)
        self.line = np.zeros(1024, np.int64)
        self.V = np.zeros((1024, width))
        self.kinds: list[str] = []

    def add(self, rows) -> None:
        for r in rows:
            if self.n == len(self.ns):
                for name in ("ns", "kind", "line", "V"):
                    a = getattr(self, name)
                    setattr(self, name, np.concatenate([a, np.zeros_like(a)]))
            if r.kind not in self.kinds:
                self.kinds.append(r.kind)
            self.ns[self.n] = r.ns
            self.kind[self.n] = self.kinds.index(r.kind)
            self.line[self.n] = r.line
            self.V[self.n] = r.values
            self.n += 1

    def log(self, source, centre: str = "earth", rows: np.ndarray | None = None):
        """The rows (all, or the indices ``rows``) as a :class:`MeasurementLog`, by epoch
        then input line."""
        i = np.arange(self.n) if rows is None else rows
        order = i[np.lexsort((self.line[i], self.ns[i]))]
        return rows_log(source, self.ns[order], np.array(self.kinds)[self.kind[order]],
                        self.V[order], self.line[order], centre)


def rows_log(source, ns, kinds, V, lines, centre="earth") -> MeasurementLog:
    """A :class:`MeasurementLog` of parsed rows (sorted by epoch), as :func:`read_log` would
    give for them."""
    ns = np.asarray(ns, np.int64)
    epoch0 = np.datetime64(int(ns[0]), "ns")
    kinds = np.asarray(kinds).astype(str)
    width = max(int(np.char.str_len(kinds).max()), 1)
    return MeasurementLog(path=source, epoch0=epoch0, t_s=(ns - ns[0]) / 1e9,
                          kind=kinds.astype(f"<U{width}"), xyz=V[:, :3].copy(),
                          sigma=V[:, 3].copy(),
                          extra={c: V[:, 4 + j].copy() for j, c in enumerate(EXTRA_COLUMNS)},
                          line=np.asarray(lines, np.int64), centre=centre)


class _Integrity:
    """NIS sums over a sliding window and over all data (module docstring)."""

    def __init__(self, window_s: float):
        self.window_ns = int(window_s * 1e9)
        self.recent = collections.deque()
        self.win_nis = self.win_dof = 0.0
        self.all_nis = self.all_dof = 0.0

    def add(self, ns: int, nis: float, dof: int) -> None:
        if dof <= 0:
            return
        self.recent.append((ns, nis, dof))
        self.win_nis += nis
        self.win_dof += dof
        self.all_nis += nis
        self.all_dof += dof
        while self.recent and ns - self.recent[0][0] > self.window_ns:
            _, a, d = self.recent.popleft()
            self.win_nis -= a
            self.win_dof -= d

    @staticmethod
    def _status(nis, dof) -> str:
        if dof <= 0:
            return "ok"
        lp = chi2_logsf(max(nis, 0.0), dof)
        return "failed" if lp < FAILED_LOGP else "suspect" if lp < SUSPECT_LOGP else "ok"

    def verdict(self) -> str:
        order = ("ok", "suspect", "failed")
        return max(self._status(self.win_nis, self.win_dof),
                   self._status(self.all_nis, self.all_dof), key=order.index)

    def as_dict(self) -> dict:
        return {"status": self.verdict(),
                "window": {"nis": self.win_nis, "dof": int(self.win_dof),
                           "status": self._status(self.win_nis, self.win_dof),
                           "window_s": self.window_ns / 1e9},
                "all": {"nis": self.all_nis, "dof": int(self.all_dof),
                        "status": self._status(self.all_nis, self.all_dof)}}

    def state(self) -> dict:
        rec = np.array(self.recent, dtype=float).reshape(-1, 3)
        return {"int_recent": rec, "int_all": np.array([self.all_nis, self.all_dof])}

    def restore(self, d) -> None:
        self.recent = collections.deque((int(a), float(b), int(c)) for a, b, c in d["int_recent"])
        self.win_nis = float(sum(r[1] for r in self.recent))
        self.win_dof = float(sum(r[2] for r in self.recent))
        self.all_nis, self.all_dof = (float(v) for v in d["int_all"])


class Navigator:
    """Online navigation: :meth:`add` rows as they arrive, the newest :class:`State` back.

    ``options``: the solver options (:class:`fgnav.solvers.options.SmootherOptions`);
    ``prior``: ``(x0 (6,), P0 (6, 6))`` at the first epoch, else the stream's prior rows,
    else the initial orbit from the data once enough epochs arrived (:data:`IOD_EPOCHS`;
    the states of those epochs are returned together then). ``method``: one of
    :data:`ONLINE_METHODS`; ``window_s`` (isam2) / ``lag_s`` (fixed-lag): the engine's
    window."""

    def __init__(self, options: SmootherOptions = SmootherOptions(), prior=None, *,
                 method: str = "isam2", window_s: float = DEFAULT_WINDOW_S,
                 lag_s: float = 300.0, integrity_window_s: float = 600.0,
                 source: str = "<stream>", centre: str = "earth", ignore_prior: bool = False):
        if method not in ONLINE_METHODS:
            raise UserError(f"unknown online method '{method}'; expected one of "
                            f"{', '.join(ONLINE_METHODS)}")
        if options.estimate or options.state != "cartesian":
            raise UserError("--estimate/--attitude estimate/--state elements: not yet available "
                            "online (fgnav follow estimates the orbit in Cartesian states)")
        if centre != options.centre:
            options = replace(options, centre=centre)
        self.options, self.method, self.source, self.centre = options, method, source, centre
        self.ignore_prior = ignore_prior
        self.prior = None if prior is None else (np.asarray(prior[0], float).reshape(6),
                                                 np.asarray(prior[1], float).reshape(6, 6))
        self.window_s = float(window_s if method == "isam2" else lag_s)
        self.model = options.motion_model()
        self.rows = RowStore(len(VALUE_COLUMNS))
        self.integrity = _Integrity(integrity_window_s)
        self.epoch0_ns: int | None = None
        self.waiting: list[tuple[int, list]] = []   # epochs before the start (no prior)
        self.k = 0                                  # epochs processed online
        self.x = self.P = None
        self.last_ns: int | None = None
        self.skip_until_ns: int | None = None       # resume: epochs done before the crash
        self.latency: list[float] = []
        self.engine = None
        self.window_keys: dict[int, int] = {}       # ns -> k of the epochs in the window
        self.late_rows: list = []
        self.last_verdict = "ok"

    # ---- rows in ----

    def add(self, rows) -> State | None:
        """Rows of one or more epochs (:class:`fgnav.online.stream.Row` or a
        :class:`~fgnav.io.log_csv.MeasurementLog`): the newest state (None while waiting
        for enough data to start without a prior)."""
        states = []
        for ns, group in _by_epoch(rows):
            states += self.add_epoch(ns, group)
        return states[-1] if states else None

    def add_late(self, rows) -> None:
        """Rows of an epoch already processed (within the reorder window): kept for the
        history; the iSAM2 window adds them to their state when it still holds it."""
        self.rows.add(rows)
        if self.engine is not None and self.method != "ekf":
            self.late_rows += [r for r in rows if r.ns in self.window_keys]

    def add_epoch(self, ns: int, rows: list) -> list[State]:
        """One completed epoch's rows: the states this completes (usually one)."""
        if self.epoch0_ns is None:
            self.epoch0_ns = ns
        self.rows.add(rows)
        if self.skip_until_ns is not None and ns <= self.skip_until_ns:
            return []   # done before the checkpoint (resume)
        if self.engine is None:
            self.waiting.append((ns, rows))
            if not self._start():
                return []
            waiting, self.waiting = self.waiting, []
            return [s for s in (self._step(n, r) for n, r in waiting) if s is not None]
        s = self._step(ns, rows)
        return [] if s is None else [s]

    # ---- the start ----

    def _mini_pass(self, rows):
        log = rows_log(self.source, [r.ns for r in rows], [r.kind for r in rows],
                       np.array([r.values for r in rows]), [r.line for r in rows], self.centre)
        if uses_scheme(log):
            log = preprocess_log(log)[0]
        return build_pass(log)

    def _start(self) -> bool:
        """Start the engine at the first waiting epoch when a prior is known or the data give
        one; False to wait for more epochs."""
        ns0, rows0 = self.waiting[0]
        t0 = float(j2000_seconds(np.datetime64(ns0, "ns")))
        if self.prior is not None:
            x0, P0 = self.prior
        else:
            p0 = self._mini_pass(rows0)
            if has_prior(p0) and not self.ignore_prior:
                x0, P0 = first_state(p0, self.model, t0), prior_covariance(p0)
            else:
                if len(self.waiting) not in IOD_EPOCHS:
                    return False
                rows = [r for _, rs in self.waiting for r in rs]
                p = build_pass(self.rows.log(self.source, self.centre,
                                             np.arange(self.rows.n - len(rows), self.rows.n)))
                p = strip_prior(p)
                try:
                    x0, P0 = propagate_orbit(initial_orbit(p, self.model, t0), p, self.model,
                                             t0, 0)
                except (UserError, ModelDomainError):
                    if len(self.waiting) >= IOD_EPOCHS[-1]:
                        raise
                    return False
                P0 = START_INFLATION * np.asarray(P0)
        self.x, self.P = np.array(x0, float), np.array(P0, float)
        self.last_ns = None
        self.engine = _Ekf(self) if self.method == "ekf" else _Window(self)
        return True

    # ---- one epoch ----

    def _step(self, ns: int, rows: list) -> State | None:
        t_wall, t_cpu = time.perf_counter(), time.thread_time()
        p = self._mini_pass(rows)
        t_j2000 = float(j2000_seconds(np.datetime64(ns, "ns")))
        first = self.last_ns is None
        if first:
            Phi, dt = np.eye(6), 0.0
            x_pred, P_pred = self.x.copy(), self.P.copy()
        else:
            dt = (ns - self.last_ns) / 1e9
            x_pred, Phi, Q = orbit_transition(self.x, dt, self.options.q_m2_s3, self.model,
                                              t_j2000 - dt)
            P_pred = predict_covariance(self.P, Phi, Q)
        families = [(kind, fam) for kind, fam in p.families.items()
                    if enters(p, kind) and not model_of(kind).between
                    and not (model_of(kind).prior and (not first or self.prior is not None
                                                       or self.ignore_prior))]
        nis, dof, A_all, b_all, A, b, S = 0.0, 0, [], [], None, None, None
        for kind, fam in families:
            try:
                _, A, b, _ = linearize_family(p, kind, fam, x_pred[None])
            except ModelDomainError:
                continue
            A, b = A.reshape(-1, 6), b.reshape(-1)
            if model_of(kind).prior:
                continue
            if self.options.gate_probability is not None and model_of(kind).robust:
                ok, _ = passes_gate(A, b, P_pred, self.options.gate_probability)
                if not ok:
                    continue
            A_all.append(A)
            b_all.append(b)
        if A_all:
            A, b = np.vstack(A_all), np.concatenate(b_all)
            S = innovation_covariance(P_pred, A)
            nis, dof = float(b @ np.linalg.solve(S, b)), len(b)
        try:
            x, P = self.engine.step(p, families, ns, dt, t_j2000, x_pred, P_pred, first, A, b, S)
        except (RuntimeError, ModelDomainError, np.linalg.LinAlgError) as exc:
            raise NotObservableError(f"{self.source}: the online {self.method} could not update "
                                     f"at {format_utc(np.datetime64(ns, 'ns'))} ({exc})") from exc
        self.x, self.P, self.last_ns = x, P, ns
        self.integrity.add(ns, nis, dof)
        verdict = self.integrity.verdict()
        lat, cpu = time.perf_counter() - t_wall, time.thread_time() - t_cpu
        self.latency.append(lat)
        self.k += 1
        return State(ns, (ns - self.epoch0_ns) / 1e9, x.copy(), P.copy(), verdict, lat,
                     self.k - 1, cpu)

    # ---- the history ----

    def smoothed(self):
        """The full history smoothed by the batch chain solver: a
        :class:`fgnav.solution.Solution` (:meth:`finish` for the summary and pass too)."""
        return self.finish()[0].solution

    def finish(self):
        """``(SmoothResult, Pass)`` of every row received, as ``fgnav smooth`` (batch) gives
        for them (:func:`fgnav.pipeline.smooth_log`)."""
        if not self.rows.n:
            raise UserError(f"{self.source}: no measurement rows received")
        log = scheme_preprocessed(self.rows.log(self.source, self.centre), self.options.estimate)
        return smooth_log(log, "batch", self.options, ignore_prior=self.ignore_prior)

    # ---- checkpoint ----

    def checkpoint_state(self) -> dict:
        """The online state as arrays (a checkpoint; :meth:`restore`)."""
        if self.engine is None:
            return {}
        return {"x": self.x, "P": self.P, "last_ns": np.array(self.last_ns, np.int64),
                "epoch0_ns": np.array(self.epoch0_ns, np.int64), "k": np.array(self.k),
                **self.integrity.state()}

    def restore(self, d) -> None:
        """Continue from :meth:`checkpoint_state`: epochs up to its last are taken into the
        history only (the stream is read again from its start); the engine restarts from the
        saved state and covariance as its prior."""
        self.x, self.P = np.array(d["x"], float), np.array(d["P"], float)
        self.last_ns = int(d["last_ns"])
        self.skip_until_ns = self.last_ns
        self.k = int(d["k"])
        self.integrity.restore(d)
        self.prior = (self.x, self.P)
        self.engine = _Ekf(self) if self.method == "ekf" else _Window(self)


def _by_epoch(rows):
    """``(ns, rows)`` per epoch, in time order, of Rows or a MeasurementLog."""
    if isinstance(rows, MeasurementLog):
        ns = (rows.epoch0.astype("datetime64[ns]").astype(np.int64)
              + np.round(np.asarray(rows.t_s) * 1e9).astype(np.int64))
        V = np.column_stack([rows.xyz, rows.sigma] + [
            rows.extra.get(c, np.full(len(rows), np.nan)) for c in VALUE_COLUMNS[4:]])
        lines = rows.line if rows.line is not None else np.zeros(len(rows), np.int64)
        rows = [Row(int(n), str(k), v, int(li)) for n, k, v, li in zip(ns, rows.kind, V, lines)]
    groups: dict[int, list] = {}
    for r in rows:
        groups.setdefault(r.ns, []).append(r)
    return sorted(groups.items())


class _Ekf:
    """The EKF's measurement update of one epoch (:func:`fgnav.solvers.kalman.kalman_update`,
    as :func:`fgnav.solvers.ekf.run_ekf`), all the epoch's kept rows at once, linearized at
    the prediction: ``K = P A^T S^-1``, Joseph form ``P = (I - K A) P (I - K A)^T + K K^T``
    (whitened rows: unit measurement noise)."""

    def __init__(self, nav: Navigator):
        self.nav = nav

    def step(self, p, families, ns, dt, t_j2000, x, P, first, A=None, b=None, S=None):
        if A is None:
            return x, P
        x, P, _ = kalman_update(x, P, A, b, S=S)
        return x, P


class _Window:
    """iSAM2 over a bounded window (``gtsam.IncrementalFixedLagSmoother``): the orbit's
    motion factors (:func:`fgnav.graph.step_factors`) and the rows' factors (:meth:`fgnav.models.model.MeasurementModel.factors`),
    the states older than the window marginalized into a prior on the oldest kept one."""

    def __init__(self, nav: Navigator):
        import gtsam

        self.gtsam, self.nav = gtsam, nav
        self.smoother = gtsam.IncrementalFixedLagSmoother(
            nav.window_s, isam2_params(IncrementalOptions()))   # (the orbit's thresholds)
        self.kernel = RobustKernel.create(nav.options.robust, nav.options.robust_k)
        self.held = None
        self.k = None            # the key index of the newest state

    def step(self, p, families, ns, dt, t_j2000, x_pred, P_pred, first, A=None, b=None, S=None):
        gtsam, nav = self.gtsam, self.nav
        X = gtsam.symbol_shorthand.X
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        k = 0 if self.k is None else self.k + 1
        if self.k is None:   # the start (or restart): its prior unless prior rows give it
            if not any(model_of(kd).prior for kd, _ in families):
                graph.add(gtsam.PriorFactorVector(
                    X(k), np.asarray(x_pred, float),
                    gtsam.noiseModel.Gaussian.Covariance(np.asarray(P_pred, float), False)))
        else:
            for f in step_factors(layout_of(p), k, dt, nav.options.q_m2_s3, nav.model,
                                  t_j2000 - dt):
                graph.add(f)
        for kind, fam in families:
            for f in model_of(kind).factors(fam, np.arange(len(fam)), k, p.layout,
                                            self.kernel, x_pred, p.t_s):
                graph.add(f)
        for r in nav.late_rows:   # late rows of an epoch still in the window
            lp = nav._mini_pass([r])
            for kind, fam in lp.families.items():
                if enters(lp, kind) and not model_of(kind).between and not model_of(kind).prior:
                    for f in model_of(kind).factors(fam, np.arange(len(fam)),
                                                    nav.window_keys[r.ns], lp.layout,
                                                    self.kernel, x_pred, None):
                        graph.add(f)
        nav.late_rows = []
        values.insert(X(k), np.asarray(x_pred, float))
        t_rel = (ns - nav.epoch0_ns) / 1e9
        self.smoother.update(graph, values, {X(k): t_rel})
        if self.held is None:
            self.held = self.smoother.getISAM2().getLinearizationPoint()
        self.k = k
        nav.window_keys[ns] = k
        for old in [n for n in nav.window_keys if (ns - n) / 1e9 > nav.window_s * 0.9]:
            del nav.window_keys[old]
        x = np.asarray(self.smoother.calculateEstimateVector(X(k)), float)
        P = np.asarray(self.smoother.marginalCovariance(X(k)), float)
        return x, P
