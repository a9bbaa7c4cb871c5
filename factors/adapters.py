"""Glue between the numpy residuals and GTSAM.

Two routes use the same residual function (see CONTRIBUTING.md, "Residual contract"):

- per factor: :func:`custom_factor` wraps a single-epoch residual into a
  ``gtsam.CustomFactor`` (iSAM2, fixed-lag smoothing, tests);
- in bulk: :func:`whiten` turns ``(e, H)`` for all N epochs into the Gauss–Newton blocks
  ``(A, b)`` and :func:`jacobian_factors` into pre-whitened ``gtsam.JacobianFactor`` objects
  with a unit noise model (batch solver).

GTSAM convention: a linearized factor minimizes ``||A dx - b||^2`` with ``A = H / sigma`` and
``b = -e / sigma`` (``e`` the unwhitened error at the linearization point).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "STATE_DIM", "vector_state", "rot3_matrix", "pad_position_jacobian", "noise_model",
    "whiten", "custom_factor", "jacobian_factors",
]

STATE_DIM = 6
"""Dimension of the orbit state key ``x = [r_eci_m; v_eci_mps]``."""


def vector_state(values, key):
    """The state vector stored at ``key`` in a ``gtsam.Values``, shape (d,), float."""
    return np.asarray(values.atVector(key), dtype=float)


def rot3_matrix(values, key):
    """The ``Rot3`` stored at ``key`` as a (3, 3) matrix (``R_eci_from_body`` by convention)."""
    return np.asarray(values.atRot3(key).matrix(), dtype=float)


def pad_position_jacobian(H_r, state_dim=STATE_DIM):
    """Pad a position Jacobian ``(..., m, 3)`` to a state Jacobian ``(..., m, state_dim)``.

    The state is ``[r; v; ...]``: the position block comes first, the rest are zeros (a
    measurement of position alone does not depend on velocity).
    """
    H_r = np.asarray(H_r, dtype=float)
    H = np.zeros(H_r.shape[:-1] + (state_dim,))
    H[..., :3] = H_r
    return H


def noise_model(sigma, dim):
    """A GTSAM noise model for a ``dim``-row error from ``sigma``.

    ``sigma``: a float (isotropic, the error's unit), a (dim,) array of per-row sigmas
    (diagonal), a (dim, dim) covariance, or an existing ``gtsam.noiseModel`` (returned
    as is).
    """
    import gtsam

    if isinstance(sigma, gtsam.noiseModel.Base):
        return sigma
    s = np.asarray(sigma, dtype=float)
    if s.ndim == 0:
        if not s > 0:
            raise ValueError(f"sigma must be positive, got {float(s)}")
        return gtsam.noiseModel.Isotropic.Sigma(dim, float(s))
    if s.shape == (dim,):
        if not np.all(s > 0):
            raise ValueError(f"sigmas must be positive, got {s}")
        return gtsam.noiseModel.Diagonal.Sigmas(s)
    if s.shape == (dim, dim):
        return gtsam.noiseModel.Gaussian.Covariance(s)
    raise ValueError(f"sigma must be a float, a ({dim},) array or a ({dim},{dim}) "
                     f"covariance, got shape {s.shape}")


def whiten(e, H, sigma):
    """Whiten errors and Jacobians of N epochs for a Gauss–Newton step.

    Parameters
    ----------
    e : array_like, shape (N, m), unwhitened error.
    H : array_like (N, m, d), or a sequence of them (one per variable).
    sigma : float, (N,) or (N, m): standard deviation of the error, same unit as ``e``.

    Returns
    -------
    A : ndarray (N, m, d) (or a tuple, one per Jacobian given): ``H / sigma``.
    b : ndarray (N, m): ``-e / sigma``.
    """
    e = np.asarray(e, dtype=float)
    s = np.asarray(sigma, dtype=float)
    if s.ndim == 0:
        s = np.full(e.shape, float(s))
    elif s.ndim == 1:
        s = np.broadcast_to(s[:, None], e.shape)
    elif s.shape != e.shape:
        raise ValueError(f"sigma shape {s.shape} does not match error shape {e.shape}")
    if np.any(s <= 0):
        raise ValueError("sigma must be positive")
    b = -e / s
    if isinstance(H, (list, tuple)):
        return tuple(np.asarray(h, dtype=float) / s[..., None] for h in H), b
    return np.asarray(H, dtype=float) / s[..., None], b


def custom_factor(keys, sigma, residual, dim=None):
    """Wrap a single-epoch residual into a ``gtsam.CustomFactor``.

    Parameters
    ----------
    keys : sequence of int
        GTSAM keys of the variables, in the order of the Jacobians ``residual`` returns.
    sigma : float, (m,) array, (m, m) covariance or gtsam noise model (see :func:`noise_model`).
    residual : callable
        ``residual(values) -> (e, [H_0, H_1, ...])`` with ``e`` of shape (m,) (unwhitened)
        and ``H_i`` of shape ``(m, dim(key_i))``.
    dim : int, optional
        Error dimension m; required when ``sigma`` is a float.

    The error function follows the CONTRIBUTING.md contract: it returns the unwhitened
    error and, when GTSAM passes a Jacobian list, assigns ``H[i]`` with the exact shape
    for every key (never rebinding or appending; a wrong write segfaults GTSAM).
    """
    import gtsam

    keys = [int(k) for k in keys]
    n_keys = len(keys)
    if dim is None and not isinstance(sigma, gtsam.noiseModel.Base):
        s = np.asarray(sigma, dtype=float)
        if s.ndim == 0:
            raise ValueError("custom_factor: give dim with a scalar sigma")
        dim = s.shape[0]
    model = noise_model(sigma, dim)

    def error_fn(this, values, H):
        e, jacobians = residual(values)
        e = np.asarray(e, dtype=float).reshape(-1)
        if H is not None:
            if len(jacobians) != n_keys:
                raise RuntimeError(f"residual returned {len(jacobians)} Jacobians for "
                                   f"{n_keys} keys")
            for i, J in enumerate(jacobians):
                J = np.asarray(J, dtype=float)
                H[i] = np.ascontiguousarray(J.reshape(e.shape[0], J.shape[-1]))
        return e

    return gtsam.CustomFactor(model, keys, error_fn)


def jacobian_factors(keys, A, b):
    """Pre-whitened ``gtsam.JacobianFactor`` objects for N epochs (unit noise model).

    Parameters
    ----------
    keys : sequence of int arrays, one (N,) array of keys per variable (1 to 3 variables).
    A : sequence of (N, m, d_i) whitened Jacobians, one per variable (see :func:`whiten`).
    b : (N, m) whitened right-hand side.

    Returns
    -------
    list of gtsam.JacobianFactor, factor k minimizing ``||sum_i A_i[k] dx_i - b[k]||^2``.
    """
    import gtsam

    if isinstance(A, np.ndarray):
        A = (A,)
    keys = [np.asarray(k).reshape(-1) for k in keys]
    if len(keys) != len(A) or not 1 <= len(keys) <= 3:
        raise ValueError("jacobian_factors: give 1 to 3 variables, one key array per Jacobian")
    b = np.asarray(b, dtype=float)
    m = b.shape[1]
    unit = gtsam.noiseModel.Unit.Create(m)
    out = []
    for k in range(b.shape[0]):
        parts = []
        for kk, Ai in zip(keys, A):
            parts += [int(kk[k]), np.ascontiguousarray(Ai[k], dtype=float)]
        out.append(gtsam.JacobianFactor(*parts, np.ascontiguousarray(b[k]), unit))
    return out
