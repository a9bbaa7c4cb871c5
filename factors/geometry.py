"""Small geometric building blocks shared by the measurement models.

Everything is vectorized over leading axes (``(..., 3)`` vectors, ``(..., 3, 3)`` matrices)
and uses plain numpy. Rotations follow GTSAM: a perturbation of a rotation ``R`` is the
*right* perturbation ``R @ Exp(omega)``, ``omega`` in the frame ``R`` maps from.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "cross", "skew", "tangent_basis", "unit_and_jacobian", "so3_exp", "so3_log",
    "so3_right_jacobian_inv",
]

_SMALL_ANGLE_RAD = 1e-8


def cross(a, b):
    """Cross product over the last axis, broadcasting leading axes.

    Same result as ``numpy.cross`` for 3-vectors, several times faster on small arrays
    (the single-epoch path of every GTSAM adapter).
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def skew(v):
    """Cross-product matrix: ``skew(a) @ b == cross(a, b)``.

    Parameters
    ----------
    v : array_like, shape (..., 3)

    Returns
    -------
    ndarray, shape (..., 3, 3)
    """
    v = np.asarray(v, dtype=float)
    S = np.zeros(v.shape[:-1] + (3, 3))
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    S[..., 0, 1] = -z
    S[..., 0, 2] = y
    S[..., 1, 0] = z
    S[..., 1, 2] = -x
    S[..., 2, 0] = -y
    S[..., 2, 1] = x
    return S


def tangent_basis(u):
    """Orthonormal basis of the plane tangent to the unit sphere at ``u``.

    Construction (deterministic, smooth wherever the choice of axis does not change):
    ``k = argmin_i |u_i|``, ``b1 = normalize(e_k - u_k u)``, ``b2 = u x b1``. The axis of
    smallest ``|u_i|`` keeps ``|e_k - u_k u| >= sqrt(2/3)``, so the basis is well conditioned
    for every direction. ``(b1, b2, u)`` is right-handed.

    Parameters
    ----------
    u : array_like, shape (..., 3)
        Direction (normalized internally; a unit vector is expected).

    Returns
    -------
    B : ndarray, shape (..., 2, 3)
        Rows ``b1``, ``b2``: orthonormal and orthogonal to ``u``. A direction residual is
        the log map written in this basis (``factors.direction.sphere_log``).
    """
    u = np.asarray(u, dtype=float)
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    k = np.argmin(np.abs(u), axis=-1)
    ek = (np.arange(3) == k[..., None]).astype(float)
    uk = np.sum(u * ek, axis=-1, keepdims=True)
    b1 = ek - uk * u
    b1 /= np.linalg.norm(b1, axis=-1, keepdims=True)
    b2 = cross(u, b1)
    return np.stack([b1, b2], axis=-2)


def unit_and_jacobian(r):
    """Unit vector of ``r`` and its Jacobian.

    ``u = r / |r|``, ``du/dr = (I - u u^T) / |r|``.

    Parameters
    ----------
    r : array_like, shape (..., 3)  (any unit; must be non-zero)

    Returns
    -------
    u : ndarray, shape (..., 3)
    J : ndarray, shape (..., 3, 3), in 1/[unit of r]
    """
    r = np.asarray(r, dtype=float)
    n = np.sqrt(np.sum(r * r, axis=-1, keepdims=True))
    u = r / n
    J = (np.eye(3) - u[..., :, None] * u[..., None, :]) / n[..., None]
    return u, J


def so3_exp(omega):
    """Rotation matrix ``Exp(omega)`` (Rodrigues' formula), ``omega`` in rad, shape (..., 3)."""
    omega = np.asarray(omega, dtype=float)
    theta = np.linalg.norm(omega, axis=-1)[..., None, None]
    W = skew(omega)
    W2 = W @ W
    small = theta < _SMALL_ANGLE_RAD
    t = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(t) / t)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(t)) / t**2)
    return np.eye(3) + a * W + b * W2


def so3_log(R):
    """Rotation vector ``Log(R)`` in rad, shape (..., 3), for any rotation (angle in [0, pi]).

    ``theta = atan2(|v|/2, (tr R - 1)/2)`` with ``v = vee(R - R^T) = 2 sin(theta) a``; below
    ``pi - 1e-3`` the vector is ``theta v / (2 sin theta)`` (series ``1/2 + theta^2/12`` near 0).
    Near pi ``v`` vanishes and carries no axis: the axis comes from the symmetric part,
    ``(R + R^T)/2 - cos(theta) I = (1 - cos theta) a a^T`` (its largest diagonal's column),
    with the sign of ``v`` (Markley & Crassidis 2014, "Fundamentals of Spacecraft Attitude
    Determination and Control", sec. 2.9.3). Exact to rounding at any angle: at
    ``pi - 1e-8`` the quotient form alone was off by 2e8 rad.
    """
    R = np.asarray(R, dtype=float)
    tr = np.trace(R, axis1=-2, axis2=-1)
    v = np.stack([R[..., 2, 1] - R[..., 1, 2],
                  R[..., 0, 2] - R[..., 2, 0],
                  R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    sin2 = np.linalg.norm(v, axis=-1)              # 2 sin(theta)
    cos_t = np.clip((tr - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arctan2(sin2 / 2.0, cos_t)
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    scale = np.where(small, 0.5 + theta**2 / 12.0, t / np.where(sin2 > 0, sin2, 1.0))
    w = scale[..., None] * v
    near_pi = theta > np.pi - 1e-3
    if np.any(near_pi):
        Rn, vn, tn = R[near_pi], v[near_pi], theta[near_pi]
        Bs = 0.5 * (Rn + np.swapaxes(Rn, -1, -2)) - np.cos(tn)[:, None, None] * np.eye(3)
        j = np.argmax(np.diagonal(Bs, axis1=-2, axis2=-1), axis=-1)
        col = Bs[np.arange(len(j)), :, j]
        axis = col / np.linalg.norm(col, axis=-1, keepdims=True)
        sign = np.where(np.sum(axis * vn, axis=-1) < 0, -1.0, 1.0)
        w[near_pi] = (sign * tn)[:, None] * axis
    return w


def so3_right_jacobian_inv(omega):
    """Inverse right Jacobian of SO(3): ``Log(Exp(w) Exp(d)) ~ w + Jr^-1(w) d``.

    ``Jr^-1(w) = I + W/2 + (1/t^2 - (1 + cos t) / (2 t sin t)) W^2``, ``W = skew(w)``, ``t = |w|``
    (Chirikjian; Forster et al. 2017, eq. 8).
    """
    omega = np.asarray(omega, dtype=float)
    theta = np.linalg.norm(omega, axis=-1)[..., None, None]
    W = skew(omega)
    small = theta < 1e-5
    t = np.where(small, 1.0, theta)
    c = np.where(small, 1.0 / 12.0 + theta**2 / 720.0,
                 1.0 / t**2 - (1.0 + np.cos(t)) / (2.0 * t * np.sin(t)))
    return np.eye(3) + 0.5 * W + c * (W @ W)
