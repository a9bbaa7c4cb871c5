"""The project's shared Jacobian checker: central differences, on the manifold for rotations.

Every measurement model in ``factors/`` is tested with :func:`check_jacobians`::

    from factors.testing import check_jacobians
    e, H_r = earth_direction_residual(r_eci_m, u_meas_eci)
    check_jacobians(earth_direction_residual, (r_eci_m, u_meas_eci), (H_r, None),
                    kinds=("vector", None))

Conventions
-----------
- Functions are vectorized over epochs: an argument of kind ``"vector"`` has shape
  ``(N, d)`` (or ``(d,)`` for a single point), of kind ``"rot3"`` shape ``(N, 3, 3)`` (or
  ``(3, 3)``); the function returns the error with shape ``(N, m)`` (or ``(m,)``). Epochs
  must be independent (error of epoch k depends only on row k of each argument), which
  lets one perturbation of component j serve all N epochs at once.
- Rotations are perturbed on the right, ``R @ Exp(omega)`` (GTSAM), so a Jacobian with
  respect to a rotation is with respect to ``omega`` (3 columns).
- If the function returns a tuple (as the residual functions do: ``(e, H...)``), its
  first element is taken as the error.
"""

from __future__ import annotations

import numpy as np

from factors.geometry import so3_exp

__all__ = [
    "numerical_jacobian", "numerical_jacobian_rot3", "check_jacobians", "check_linearization",
    "random_positions_m", "random_rotations",
]

_REL_STEP = 1e-6


def _error_of(f, *args):
    out = f(*args)
    if isinstance(out, tuple):
        out = out[0]
    return np.asarray(out, dtype=float)


def _default_step(x):
    """Step per point: 1e-6 times the norm of the point (at least 1e-6), shape (..., 1)."""
    return _REL_STEP * np.maximum(1.0, np.linalg.norm(x, axis=-1, keepdims=True))


def numerical_jacobian(f, x, eps=None):
    """Central-difference Jacobian of ``f`` at ``x`` for a vector argument.

    Parameters
    ----------
    f : callable
        ``f(x)`` with ``x`` of shape ``(..., d)`` returns shape ``(..., m)`` (or a tuple whose
        first element is that), element-wise over the leading axes.
    x : array_like, shape (..., d)
    eps : float or array_like broadcastable to ``(..., 1)``, optional
        Step in the unit of ``x``. Default: ``1e-6 * max(1, |x|)`` per point, which keeps
        both truncation (~eps^2) and round-off (~1e-16/eps) errors near 1e-10 relative.

    Returns
    -------
    J : ndarray, shape ``f(x).shape + (d,)``: ``J[..., i, j] = d f_i / d x_j``.
    """
    x = np.asarray(x, dtype=float)
    h = _default_step(x) if eps is None else np.broadcast_to(
        np.asarray(eps, dtype=float), x.shape[:-1] + (1,))
    d = x.shape[-1]
    cols = []
    for j in range(d):
        dx = np.zeros_like(x)
        dx[..., j:j + 1] = h
        fp = _error_of(f, x + dx)
        fm = _error_of(f, x - dx)
        step = 2.0 * h if fp.ndim == x.ndim else 2.0 * h[..., 0]
        cols.append((fp - fm) / step)
    return np.stack(cols, axis=-1)


def numerical_jacobian_rot3(f, R, eps=1e-6):
    """Central-difference Jacobian of ``f`` with respect to the right perturbation of ``R``.

    ``J[..., :, j] = (f(R Exp(eps e_j)) - f(R Exp(-eps e_j))) / (2 eps)`` (GTSAM convention).

    Parameters
    ----------
    f : callable, ``f(R)`` with ``R`` of shape ``(..., 3, 3)`` returns ``(..., m)``.
    R : array_like, shape (..., 3, 3), rotation matrices.
    eps : float, rad.

    Returns
    -------
    J : ndarray, shape ``f(R).shape + (3,)``.
    """
    R = np.asarray(R, dtype=float)
    cols = []
    for j in range(3):
        w = np.zeros(3)
        w[j] = eps
        fp = _error_of(f, R @ so3_exp(w))
        fm = _error_of(f, R @ so3_exp(-w))
        cols.append((fp - fm) / (2.0 * eps))
    return np.stack(cols, axis=-1)


def check_jacobians(f, args, analytic, kinds, rtol=1e-6, atol=None, eps=None, names=None):
    """Compare analytic Jacobians with central differences; raise ``AssertionError`` if off.

    Parameters
    ----------
    f : callable
        ``f(*args)`` returns the error (``(N, m)`` or ``(m,)``) or a tuple starting with it.
    args : sequence
        The point at which to check (all arguments of ``f``).
    analytic : sequence
        One entry per argument: the analytic Jacobian (``(N, m, d)`` for vectors,
        ``(N, m, 3)`` for rotations), or ``None`` for an argument that is not a variable.
    kinds : sequence
        One entry per argument: ``"vector"``, ``"rot3"`` or ``None`` (not checked).
    rtol : float
        Relative tolerance per element, against the numerical value.
    atol : float, optional
        Absolute tolerance per element. Default: ``1e-7 * max |numerical Jacobian|`` of
        that argument (a scale-aware floor, so tiny entries of a large Jacobian do not fail
        on round-off), or 1e-12 when the Jacobian is all zeros.
    eps : sequence or None
        Per-argument step (see :func:`numerical_jacobian`; a float in rad for rotations).
    names : sequence of str, optional
        Argument names for the failure message.

    Returns
    -------
    list of ndarray : the numerical Jacobians (``None`` for skipped arguments).

    Raises
    ------
    AssertionError
        Naming the argument, the largest absolute and relative differences and where
        (epoch, row, column) they occur.
    """
    args = list(args)
    if not (len(analytic) == len(kinds) == len(args)):
        raise ValueError(
            f"check_jacobians: got {len(args)} args, {len(analytic)} analytic Jacobians and "
            f"{len(kinds)} kinds; give one entry per argument (None for constants)")
    numericals = []
    for i, (H, kind) in enumerate(zip(analytic, kinds)):
        name = names[i] if names is not None else f"argument {i}"
        if H is None or kind is None:
            numericals.append(None)
            continue

        def fi(xi, i=i):
            a = list(args)
            a[i] = xi
            return f(*a)

        step = None if eps is None else eps[i]
        if kind == "vector":
            Hn = numerical_jacobian(fi, args[i], step)
        elif kind == "rot3":
            Hn = numerical_jacobian_rot3(fi, args[i], 1e-6 if step is None else step)
        else:
            raise ValueError(f"check_jacobians: kind of {name} must be 'vector', 'rot3' or "
                             f"None, got {kind!r}")
        H = np.asarray(H, dtype=float)
        if H.shape != Hn.shape:
            raise AssertionError(f"Jacobian of {name}: analytic shape {H.shape}, "
                                 f"numerical shape {Hn.shape}")
        scale = float(np.max(np.abs(Hn))) if Hn.size else 0.0
        tol_abs = (1e-7 * scale if scale > 0 else 1e-12) if atol is None else atol
        diff = np.abs(H - Hn)
        bad = diff > tol_abs + rtol * np.abs(Hn)
        if np.any(bad):
            k = np.unravel_index(np.argmax(np.where(bad, diff, -1.0)), diff.shape)
            rel = diff / np.maximum(np.abs(Hn), 1e-300)
            raise AssertionError(
                f"Jacobian of {name} ({kind}) differs from central differences at "
                f"{int(bad.sum())} of {bad.size} entries; worst at index "
                f"{tuple(int(j) for j in k)}: "
                f"analytic {H[k]:.9g}, numerical {Hn[k]:.9g}; max abs diff "
                f"{diff.max():.3g} (atol {tol_abs:.3g}), max rel diff over failing entries "
                f"{rel[bad].max():.3g} (rtol {rtol:.3g})")
        numericals.append(Hn)
    return numericals


def check_linearization(factor, values, A_blocks, b, rtol=1e-9, atol=1e-12):
    """Check that a GTSAM factor linearizes to the given whitened blocks.

    ``factor.linearize(values)`` gives ``||A dx - b||^2`` with ``A = [A_0 A_1 ...]`` in the
    order of the factor's keys. ``A_blocks`` are the expected blocks (from
    :func:`factors.adapters.whiten` of the numpy residual at one epoch), ``b`` the expected
    right-hand side. Raises ``AssertionError`` with the largest difference.
    """
    A_got, b_got = factor.linearize(values).jacobian()
    A_exp = np.hstack([np.atleast_2d(np.asarray(a, dtype=float)) for a in A_blocks])
    b_exp = np.asarray(b, dtype=float).reshape(-1)
    if A_got.shape != A_exp.shape or b_got.shape != b_exp.shape:
        raise AssertionError(f"linearized shapes A {A_got.shape}, b {b_got.shape}; expected "
                             f"A {A_exp.shape}, b {b_exp.shape}")
    for name, got, exp in (("A", A_got, A_exp), ("b", b_got, b_exp)):
        if not np.allclose(got, exp, rtol=rtol, atol=atol):
            raise AssertionError(f"linearized {name} differs: max abs diff "
                                 f"{np.max(np.abs(got - exp)):.3g}\ngot\n{got}\nexpected\n{exp}")


def random_positions_m(rng, n, r_min_m=7.0e6, r_max_m=4.0e7):
    """``n`` positions (m) with isotropic directions and radii uniform in [r_min_m, r_max_m].

    ``rng``: a ``numpy.random.Generator``. Default radii span LEO to beyond GEO (7,000 to
    40,000 km), the range the factor tests use.
    """
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * rng.uniform(r_min_m, r_max_m, size=(n, 1))


def random_rotations(rng, n):
    """``n`` rotation matrices (n, 3, 3), uniform on SO(3) (normalized Gaussian quaternions)."""
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], axis=-2)
