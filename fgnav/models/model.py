"""A measurement model: everything the project knows about one log kind, in one object.

The solvers, the EKF, the simulator, the log reader's consumers and the visualization ask
the model (through :mod:`fgnav.models.registry`) instead of testing kind strings. A model
gives:

* ``kind``, ``dim``, ``unit``: its log kind, residual rows per measurement, the residual's unit;
* ``values(log, rows)``: the family's arrays from the log's x, y, z and extra columns;
* ``residual(fam, v)``: the one vectorized definition, ``(e (M, m), {variable: H})`` at the
  values ``v`` (variable name -> (M, d)) of the variables it touches, ``H`` of shape
  (M, m, d); ``"position"`` stands for the orbit state's first three columns;
* ``factor(fam, j, keys, noise)``: its GTSAM factor (``factors/`` adapter) for row ``j``;
* ``numba_kernel``/``numba_data``: the per-row numba kernel the compiled EKF dispatches on
  (``fgnav.solvers.ekf_numba``) and the packed data it reads;
* flags for the consumers: ``prior``, ``observes_orbit``, ``eci_ray``, ``range_m`` (a
  consumer's own capability lives with it: the initial orbit's geocentric directions are
  ``fgnav.iod.angles.DIRECTION_KINDS``, the simulators ``fgnav.simulate.simulators``); ``requires`` (a variable without which the rows stay out of the
  graphs: an attitude row is a prior on the attitude variable) and ``body_frame_of`` (the
  ECI kind its rows become, with the measured attitude, until then);
* ``initial(fam)``: first guesses of further variables from the rows (variable name ->
  (M, d) block values, e.g. a measured attitude), used where a row exists at an epoch;
* ``weak_orbit_dependence``: the rows touch the orbit state only through a correction far
  below their noise (a star's aberration by the spacecraft's velocity, ~3e-9 rad per m/s):
  the online gate and the integrity tests treat them like rows of the further variables
  alone (an epoch's star rows tighten the attitude its body-frame rows are gated with);
* ``between``: a row at epoch k relates the variables of epochs k - 1 and k (a gyro interval):
  then ``residual(fam, v0, v1, dt_s) -> (e, {variable: H0}, {variable: H1})``,
  ``sigma(fam, dt_s)`` and ``factor(fam, j, keys0, keys1, noise, dt_s)``, with ``dt_s`` the
  interval ``t_k - t_(k-1)`` of each row.

In a formation's pass (several spacecraft, :func:`fgnav.measurements.build_pass`) a row's
variables depend on the row: ``"orbit"`` is the orbit of the row's spacecraft and an
inter-satellite row also names ``"orbit_tx"``, ``"clock"`` (and ``"ambiguity"``); each family then carries
the block column of every such role per row (``values["col:<role>"]``), and ``evaluate``,
``keys`` and ``factors`` bind row by row. The residual functions do not change.

Whitening follows GTSAM's convention (``factors.adapters.whiten``): rows ``A = H/sigma``,
``b = -e/sigma`` minimize ``|A dx - b|^2``. A model whose rows may carry a full covariance
(``covariance(fam) -> (M, m, m)`` or None, NaN for a row that has none and keeps its
isotropic sigma) whitens those rows with the square-root information ``W`` (``W^T W = C^-1``,
:func:`sqrt_information`): ``A = W H``, ``b = -W e``; its GTSAM factors take the same ``W``
(``noiseModel.Gaussian.SqrtInformation``), so both routes whiten alike.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable

import numpy as np

from factors.adapters import whiten
from factors.errors import ModelDomainError
from fgnav.models.variables import Layout, Variable

__all__ = ["MeasurementModel", "sqrt_information", "COLUMN_PREFIX", "ROLE_DIMS"]

COLUMN_PREFIX = "col:"
"""``fam.values[COLUMN_PREFIX + role]`` (M,): per row, the first block column of the variable
that plays ``role`` for the row (a formation's rows, :meth:`MeasurementModel.evaluate`)."""
ROLE_DIMS = {"orbit": 6, "orbit_tx": 6}
"""Tangent dimension of each per-row variable role (others: 1, a clock or an ambiguity)."""


def sqrt_information(C) -> np.ndarray:
    """Square-root information ``W`` (..., m, m) of covariances ``C`` (..., m, m):
    ``W = L^-1`` with ``C = L L^T`` (Cholesky), so ``W^T W = C^-1`` and ``W e`` is the
    whitened error (the Mahalanobis norm ``|W e|^2 = e^T C^-1 e``)."""
    L = np.linalg.cholesky(np.asarray(C, dtype=float))
    return np.linalg.inv(L)


@functools.lru_cache(maxsize=256)
def _touched(mdl, layout: Layout) -> tuple[Variable, ...]:
    """The variables of ``layout`` that ``mdl`` touches, in the layout's order (cached: the
    online route asks at every epoch)."""
    names = mdl.variables_in(layout)
    return tuple(v for v in layout.variables if v.name in names)


@functools.lru_cache(maxsize=64)
def _variables_by_start(layout: Layout) -> dict:
    """The layout's variables by their first block column."""
    return {layout.slices[v.name].start: v for v in layout.variables}


def _row_values(fam, X: np.ndarray, k: np.ndarray, layout: Layout, roles=None) -> dict:
    """The values of each row's variables at epochs ``k`` (M,) of the block values ``X``, by
    role, for rows that bind their variables row by row (``values["col:<role>"]``: the first
    block column of the row's variable; ``roles``: those roles only, all by default). A role's
    variables share a dimension and manifold (a spacecraft's attitude: Rot3, whose values
    reach the residual as matrices, as :meth:`Layout.values_at` gives them)."""
    M = len(fam)
    vals = {}
    for key, start in fam.values.items():
        if not key.startswith(COLUMN_PREFIX):
            continue
        name = key[len(COLUMN_PREFIX):]
        if roles is not None and name not in roles:
            continue
        v = _variables_by_start(layout).get(int(start[0])) if M else None
        d = ROLE_DIMS.get(name, 1) if v is None else v.dim
        vals[name] = X[k[:, None], np.asarray(start)[:, None] + np.arange(d)]
        if v is not None and not v.manifold.additive:
            vals[name] = v.manifold.exp(vals[name])
    return vals


def _place_per_row(H: np.ndarray, fam, jac: dict) -> None:
    """Write the Jacobians ``jac`` (role -> (M, m, d); ``"position"``: the orbit's first three
    columns) into ``H`` (M, m, n) at each row's own columns (``values["col:<role>"]``)."""
    M, m = H.shape[:2]
    rows = np.arange(M)
    for name, h in jac.items():
        role = "orbit" if name == "position" else name
        cols = np.asarray(fam.values[COLUMN_PREFIX + role])[:, None] + np.arange(h.shape[-1])
        H[rows[:, None, None], np.arange(m)[None, :, None], cols[:, None, :]] = h


@dataclass(frozen=True, eq=False)
class MeasurementModel:
    kind: str
    dim: int
    unit: str
    summary: str
    values: Callable
    residual: Callable | None = None
    factor: Callable | None = None
    sigma: Callable | None = None
    variables: tuple[str, ...] = ("orbit",)
    optional_variables: tuple[Variable, ...] = ()
    prior: bool = False
    observes_orbit: bool = False
    numba_kernel: Callable | None = None
    numba_data: Callable | None = None
    eci_ray: bool = False
    range_m: Callable | None = None
    body_frame_of: str | None = None
    requires: str | None = None
    initial: Callable | None = None
    between: bool = False
    weak_orbit_dependence: bool = False
    covariance: Callable | None = None

    @property
    def solved(self) -> bool:
        """True when the model can enter the graphs (has a residual)."""
        return self.residual is not None

    def enters(self, layout: Layout) -> bool:
        """True when the model's rows enter the graphs of a pass solved with ``layout``: it
        has a residual, and the variable it ``requires`` (if any) is estimated."""
        return self.residual is not None and (self.requires is None or layout.has(self.requires))

    @property
    def robust(self) -> bool:
        """Robust kernels and gates apply to measurements, never to priors."""
        return not self.prior

    def variables_in(self, layout: Layout) -> tuple[str, ...]:
        """The variables this model touches in a pass solved with ``layout``."""
        return self.variables + tuple(v.name for v in self.optional_variables if layout.has(v.name))

    def noise_sigma(self, fam, x_orbit=None) -> np.ndarray:
        """1-sigma of each row (the residual's unit); ``x_orbit`` (M, 6) at the family's rows
        for models whose noise depends on geometry (None: without the geometric term)."""
        if self.sigma is None:
            return np.asarray(fam.sigma, dtype=float)
        return self.sigma(fam, x_orbit)

    def evaluate(self, fam, X: np.ndarray, layout: Layout):
        """Residuals and Jacobians of every row at the block values ``X`` (N, n):
        ``e (M, m)`` unwhitened and ``H (M, m, n)`` in the layout's columns."""
        if COLUMN_PREFIX + "orbit" in fam.values:
            return self._evaluate_per_row(fam, X, layout)
        vals_all = layout.values_at(X, fam.k)
        vals = {name: vals_all[name] for name in self.variables_in(layout)}
        try:
            e, jac = self.residual(fam, vals)
        except ModelDomainError as exc:
            raise self._domain_error(fam, vals, exc) from exc
        e = np.asarray(e, dtype=float).reshape(len(fam), self.dim)
        H = np.zeros((len(fam), self.dim, layout.n))
        for name, h in jac.items():
            sl = slice(0, 3) if name == "position" else layout.slices[name]
            H[..., sl] = h
        return e, H

    def _domain_error(self, fam, vals, exc) -> ModelDomainError:
        """``exc`` with the log line of the first row outside the model's domain (rows
        evaluated one by one: on this error path only), for the user's message."""
        for j in range(len(fam)):
            try:
                self.residual(fam.subset(np.array([j])), {n: v[j:j + 1] for n, v in vals.items()})
            except ModelDomainError as row_exc:
                return ModelDomainError(f"{self.kind} row at log line {int(fam.line[j])}: {row_exc}")
        return exc

    def _evaluate_per_row(self, fam, X: np.ndarray, layout: Layout):
        """:meth:`evaluate` for rows whose variables differ from row to row (a formation: the
        orbit of the row's spacecraft, a link's two orbits and its clock): ``fam.values``
        holds, per variable role ``name``, the first column of that row's variable in the
        block, ``values["col:<name>"]`` (M,) (:func:`fgnav.measurements.build_pass`)."""
        M, m = len(fam), self.dim
        vals = _row_values(fam, X, np.asarray(fam.k), layout)
        try:
            e, jac = self.residual(fam, vals)
        except ModelDomainError as exc:   # name the row's log line
            if exc.row is None:
                raise
            raise ModelDomainError(f"{self.kind} row at log line {int(fam.line[exc.row])}: "
                                   f"{exc}", row=exc.row) from exc
        e = np.asarray(e, dtype=float).reshape(M, m)
        H = np.zeros((M, m, layout.n))
        _place_per_row(H, fam, jac)
        return e, H

    def evaluate_between(self, fam, X: np.ndarray, layout: Layout, t_s: np.ndarray):
        """A between model's residuals and Jacobians at the block values ``X`` (N, n):
        ``e (M, m)``, ``H0``, ``H1`` (M, m, n) on the blocks of epochs ``k - 1`` and ``k``,
        and the intervals ``dt_s`` (M,)."""
        dt = np.asarray(t_s, dtype=float)[fam.k] - np.asarray(t_s, dtype=float)[fam.k - 1]
        if COLUMN_PREFIX + "orbit" in fam.values:   # a formation's: each row its own variables
            names = self._bound_roles(fam)
            v0 = _row_values(fam, X, np.asarray(fam.k) - 1, layout, names)
            v1 = _row_values(fam, X, np.asarray(fam.k), layout, names)
        else:
            names = self.variables_in(layout)
            v0 = layout.values_at(X, fam.k - 1)
            v1 = layout.values_at(X, fam.k)
        e, jac0, jac1 = self.residual(fam, {n: v0[n] for n in names}, {n: v1[n] for n in names}, dt)
        e = np.asarray(e, dtype=float).reshape(len(fam), self.dim)
        H0 = np.zeros((len(fam), self.dim, layout.n))
        H1 = np.zeros_like(H0)
        for H, jac in ((H0, jac0), (H1, jac1)):
            if COLUMN_PREFIX + "orbit" in fam.values:
                _place_per_row(H, fam, jac)
                continue
            for name, h in jac.items():
                H[..., layout.slices[name]] = h
        return e, H0, H1, dt

    def _bound_roles(self, fam) -> tuple[str, ...]:
        """The variable roles a formation's row of this model binds (its ``col:`` values among
        the model's variables and optional variables: ``attitude``, ``gyro_bias``)."""
        known = set(self.variables) | {v.name for v in self.optional_variables}
        return tuple(key[len(COLUMN_PREFIX):] for key in fam.values
                     if key.startswith(COLUMN_PREFIX) and key[len(COLUMN_PREFIX):] in known)

    def linearize_between(self, fam, X: np.ndarray, layout: Layout, t_s: np.ndarray):
        """Whitened rows of a between model: ``A0, A1 (M, m, n)``, ``b (M, m)``, and ``e``."""
        e, H0, H1, dt = self.evaluate_between(fam, X, layout, t_s)
        (A0, A1), b = whiten(e, [H0, H1], self.sigma(fam, dt))
        return A0, A1, b, e

    def linearize(self, fam, X: np.ndarray, layout: Layout):
        """Whitened rows of every measurement: ``A (M, m, n)``, ``b (M, m)``, and ``e``."""
        e, H = self.evaluate(fam, X, layout)
        A, b = whiten(e, H, self.noise_sigma(fam, X[fam.k, :6]))
        full = self._full_rows(fam)
        if full is not None:   # rows with a full covariance: A = W H, b = -W e
            rows, W = full
            A[rows] = W @ H[rows]
            b[rows] = -np.einsum("mij,mj->mi", W, e[rows])
        return A, b, e

    def _full_rows(self, fam, rows=None):
        """``(row indices, W (R, m, m))`` of the rows (among ``rows``, all by default) that
        carry a full covariance, or None when none does."""
        if self.covariance is None:
            return None
        C = self.covariance(fam)
        if C is None:
            return None
        C = np.asarray(C, dtype=float)
        if rows is not None:
            C = C[rows]
        full = np.flatnonzero(np.all(np.isfinite(C), axis=(1, 2)))
        if not len(full):
            return None
        return full, sqrt_information(C[full])

    def keys(self, layout: Layout, k: int, fam=None, j: int | None = None) -> dict[str, int]:
        """GTSAM keys of the variables this model touches at epoch ``k`` (for a family whose
        rows bind their own variables, a formation's, those of row ``j``: role -> key)."""
        if fam is not None and COLUMN_PREFIX + "orbit" in fam.values:
            by_start = _variables_by_start(layout)
            return {key[len(COLUMN_PREFIX):]: by_start[int(cols[j])].key(k)
                    for key, cols in fam.values.items() if key.startswith(COLUMN_PREFIX)}
        return {v.name: v.key(k) for v in _touched(self, layout)}

    def _noise(self, sigma: float, robust, W=None):
        """The noise of one row's factor: its 1-sigma (or, given, its square-root information
        ``W`` (m, m)), wrapped by the robust kernel for a measurement (never for a prior)."""
        if W is None and (robust is None or not self.robust):
            return sigma
        import gtsam  # the EKF baseline imports this module without GTSAM

        base = (gtsam.noiseModel.Isotropic.Sigma(self.dim, float(sigma)) if W is None else
                gtsam.noiseModel.Gaussian.SqrtInformation(np.asarray(W, dtype=float), False))
        return base if robust is None or not self.robust else robust.gtsam_noise(base)

    def factors(self, fam, rows, k: int, layout: Layout, robust=None, x_guess=None,
                t_s=None) -> list:
        """GTSAM factors (iSAM2 route) of the given rows at epoch ``k``.

        ``robust``: a :class:`fgnav.robust.RobustKernel` wrapping every measurement's noise
        (not the priors'); ``x_guess`` (6,): the orbit state's first guess, for noise that
        depends on geometry (as in the batch route); ``t_s``: the pass's epochs (a between
        model's rows join epochs ``k - 1`` and ``k``).
        """
        keys = self.keys(layout, k)
        rows = np.asarray(rows, dtype=int)
        if self.between:
            keys0 = self.keys(layout, k - 1)
            dt = float(t_s[k] - t_s[k - 1])
            sigmas = np.asarray(self.sigma(fam.subset(rows, k), np.full(len(rows), dt)), float)
            if COLUMN_PREFIX + "orbit" in fam.values:   # each row its own variables
                return [self.factor(fam, j, self.keys(layout, k - 1, fam, j),
                                    self.keys(layout, k, fam, j), self._noise(sig, robust), dt)
                        for j, sig in zip(rows.tolist(), sigmas.tolist())]
            return [self.factor(fam, j, keys0, keys, self._noise(sig, robust), dt)
                    for j, sig in zip(rows.tolist(), sigmas.tolist())]
        if self.sigma is None:   # the online route's hot path: no per-row family copies
            sigmas = np.asarray(fam.sigma, dtype=float)[rows]
        else:
            x = None if x_guess is None else np.broadcast_to(
                np.asarray(x_guess, dtype=float)[:6], (len(rows), 6))
            sigmas = self.noise_sigma(fam.subset(rows, 0), x)
        Ws = [None] * len(rows)
        full = self._full_rows(fam, rows)
        if full is not None:
            for r, W in zip(*full):
                Ws[r] = W
        if COLUMN_PREFIX + "orbit" in fam.values:   # variables bound row by row
            return [self.factor(fam, j, self.keys(layout, k, fam, j), self._noise(sig, robust, W))
                    for j, sig, W in zip(rows.tolist(), sigmas.tolist(), Ws)]
        return [self.factor(fam, j, keys, self._noise(sig, robust, W))
                for j, sig, W in zip(rows.tolist(), sigmas.tolist(), Ws)]
