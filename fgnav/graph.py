"""Graph assembly over the measurement-model registry (:mod:`fgnav.models.registry`).

Two routes share the models' residuals:

* bulk (batch Gauss–Newton): :func:`linearize_all` evaluates every family's residual for all
  its rows at once and returns pre-whitened rows ``(k, A, b)`` with ``A`` in the columns of
  the pass's per-epoch block (:class:`fgnav.models.variables.Layout`: the orbit state, then
  e.g. a bias) and ``b = -e/sigma`` (the linear problem is ``|| A dx - b ||^2``);
* incremental (iSAM2, fixed-lag): :func:`factors_for_rows` returns the GTSAM factors of the
  given rows (the models' ``factors/`` adapters) on the epoch's variable keys.

Neither route names a measurement kind: each asks the family's model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factors.attitude import attitude_residual
from factors.geometry import so3_exp
from fgnav.models.registry import model, prior_kinds
from fgnav.models.variables import Layout

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
            vals = mdl.initial(fam).get(v.name)
            if vals is not None:
                k_all.append(fam.k)
                val_all.append(np.asarray(vals, dtype=float).reshape(len(fam), v.dim))
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


def variable_prior_rows(p, X):
    """Priors of the variables after the orbit state at the first epoch,
    ``b_0 ~ N(prior_mean, prior_sigma^2)`` (a rotation: ``Log(R_0) ~ N(0, prior_sigma^2 I)``
    about the identity, ``factors.random_walk.make_rot3_prior_factor``):
    ``(k (R,), A (R, n), b (R,), tags (R,))``."""
    lay = layout_of(p)
    ks, As, bs, tags = [], [], [], []
    for v in lay.parameters:   # an orbit's prior is the log's prior rows
        sl = lay.slices[v.name]
        A = np.zeros((v.dim, lay.n))
        if v.manifold == "rot3":
            e, H = attitude_residual(so3_exp(X[0, sl])[None], np.eye(3)[None])
            A[:, sl] = H[0] / v.prior_sigma
            bs.append(-e[0] / v.prior_sigma)
        else:
            A[:, sl] = np.eye(v.dim) / v.prior_sigma
            bs.append(-(X[0, sl] - v.prior_mean) / v.prior_sigma)
        As.append(A)
        ks.append(np.zeros(v.dim, dtype=int))
        tags.append(np.full(v.dim, f"prior_{v.name}", dtype=object))
    if not As:
        return np.zeros(0, int), np.zeros((0, lay.n)), np.zeros(0), np.zeros(0, object)
    return np.concatenate(ks), np.concatenate(As), np.concatenate(bs), np.concatenate(tags)


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
    kv, Av, bv, tv = variable_prior_rows(p, X)
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
