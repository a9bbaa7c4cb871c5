"""Measurements of a near body (the Earth, the Moon, the Sun) by an optical navigation camera:
the apparent angular radius of its limb and the direction of its centre, in EME2000 or in
the body frame, with light time and aberration as the angle kinds model them.

Geometry (state ``x = [r; v]`` in the pass's frame; the body at ``p`` with velocity ``v_b``
in the same frame, from its ephemeris; ``w = p - r``, ``d = |w|``, ``u = w/d``):

* **limb radius** ``rho = asin(R/d) (1 - beta . u)``, ``beta = (v - v_b)/c`` as for the
  direction below (``asin(R/d)`` alone is ``factors.limb`` for the Earth at ``p = 0``): the
  body seen a light time ago is nearer by ``(V_b . u) tau`` (``V_b`` its barycentric
  velocity), ``rho (1 + V_b . u/c)``, and the observer's aberration shrinks a disc ahead of
  it, ``rho (1 - V_o . u/c)`` (the forward bunching of the rays); together, to first order,
  the relative velocity (the frame's own cancels). The remainder is ``~ beta^2 rho``.
  ``d rho/dr = (1 - beta . u) R u^T/(d sqrt(d^2 - R^2)) + asin(R/d) (beta - (beta . u) u)^T/d``,
  ``d rho/dv = -asin(R/d) u^T/c``.
* **direction** ``u' = ab(u, beta)``, ``beta = (v - v_b)/c``: "planetary aberration" (Urban
  & Seidelmann 2013, sec. 7.2.4), the body's light-time displacement (``-v_b tau``) and the
  observer's aberration (``v``) together to first order in ``beta``, exactly as
  ``factors.celestial_angles`` models a near body; the frame origin's own velocity cancels
  between the two. The relativistic ``ab`` and its Jacobians are ``factors.aberration``'s.
  ECI form: ``q = u'``; body form ``q = R^T u'`` (``R = R_eci_from_body``, a ``Rot3`` key).
  Residual ``e = Log_{u_meas}(q)`` (``factors.direction.sphere_log_kernel``), with
  ``de/dr = J Ju (-(I - u u^T)/d)`` (``R^T`` between J and Ju in the body form),
  ``de/dv = J Jb/c``, ``de/dphi = J skew(q)`` (right perturbation ``R Exp(phi)``).

Without the corrections (``data[2] = 0``: light time off; ``data[3] = 0``: aberration off)
the geometric ``d`` and ``u`` are used. Worth (tests/test_near_body.py): the Moon's light
time 1.3 s at the Earth, 1 km of its motion (0.5 arcsec seen from 400,000 km); the
aberration of a 1-3 km/s cislunar velocity 0.7-2 arcsec, of the Sun's 30 km/s 20 arcsec.

One definition per kind: :func:`near_body_limb_kernel` and :func:`near_body_direction_kernel`
(numba) compute one row; the numpy residuals call them. Data packing (as the compiled
EKF's row kernels): ``data = (measured value, R_body (limb), light time 1/0, aberration
1/0)``, ``P = (p_body, v_body)`` (2, 3).

The log kinds' row kernels (the compiled EKF's uniform signature ``(x, data, B, e, H)``):
:func:`limb_radius_body_kernel` (``limb_radius``: ``data[4] = 0``, no ``body``, is
``factors.limb.limb_radius_kernel`` exactly; otherwise the near-body limb, ``B = P``) and
:func:`near_body_direction_row_kernel` (``body_direction``: ``B = (p_body, v_body, b1, b2)``,
the body's state and the tangent basis of the measured direction).
"""

from __future__ import annotations

import math

import numpy as np

from factors.aberration import SPEED_OF_LIGHT_MPS, aberrate_row_kernel
from factors.adapters import noise_model
from factors.direction import sphere_log_kernel, tangent_basis_kernel
from factors.errors import ModelDomainError
from factors.interpret import run
from factors.jit import njit
from factors.limb import limb_radius_kernel

__all__ = [
    "near_body_limb_kernel", "near_body_direction_kernel", "near_body_limb_residual",
    "near_body_direction_residual", "near_body_direction_body_residual",
    "make_near_body_limb_factor", "make_near_body_direction_factor", "limb_radius_body_kernel",
    "near_body_direction_row_kernel",
]

_C = SPEED_OF_LIGHT_MPS


@njit(cache=True)
def near_body_limb_kernel(x, data, P, e, H):
    """One limb-radius row: ``e[0] = asin(R/d) (1 - beta . u) - rho_meas`` and ``H[0, :6]``
    (module docstring; further columns 0). ``data = (rho_meas, R, light time, aberration)``
    (``beta`` as :func:`near_body_direction_kernel` forms it), ``P = (p_body, v_body)``.
    Returns 1, or -1 inside the limb sphere (``d <= R``)."""
    w0, w1, w2 = P[0, 0] - x[0], P[0, 1] - x[1], P[0, 2] - x[2]
    d = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    R = data[1]
    if not d > R:
        return -1
    u0, u1, u2 = w0 / d, w1 / d, w2 / d
    lt = data[2] != 0.0
    ab = data[3] != 0.0
    b0 = ((x[3] if ab else 0.0) - (P[1, 0] if lt else 0.0)) / _C
    b1 = ((x[4] if ab else 0.0) - (P[1, 1] if lt else 0.0)) / _C
    b2 = ((x[5] if ab else 0.0) - (P[1, 2] if lt else 0.0)) / _C
    bu = b0 * u0 + b1 * u1 + b2 * u2
    f = 1.0 - bu
    rho0 = math.asin(R / d)
    e[0] = rho0 * f - data[0]
    for j in range(H.shape[1]):
        H[0, j] = 0.0
    # d rho0/dr = R/(d sqrt(d^2 - R^2)) u^T; d f/dr = (beta - (beta . u) u)^T/d
    g = R / (d * math.sqrt(d * d - R * R))
    H[0, 0] = f * g * u0 + rho0 * (b0 - bu * u0) / d
    H[0, 1] = f * g * u1 + rho0 * (b1 - bu * u1) / d
    H[0, 2] = f * g * u2 + rho0 * (b2 - bu * u2) / d
    if ab:   # d f/dv = -u^T/c
        H[0, 3] = -rho0 * u0 / _C
        H[0, 4] = -rho0 * u1 / _C
        H[0, 5] = -rho0 * u2 / _C
    return 1


@njit(cache=True)
def near_body_direction_kernel(x, R, body_frame, data, P, B, e, Hx, HR):
    """One direction row (module docstring): x (6,) the state; R (3, 3) R_eci_from_body
    (used if ``body_frame``); ``data[2]``, ``data[3]`` light time and aberration on/off
    (``beta = (v - v_b)/c``, light time alone ``-v_b/c``, aberration alone ``v/c``); P (2, 3)
    the body's position and velocity; B (2, 3) ``tangent_basis(u_meas)``. Writes e (2,), Hx (2, 6), HR (2, 3) (zero
    in the ECI form). Returns 2, or -1 outside the domain (``d = 0`` or ``|beta| >= 1``)."""
    w0, w1, w2 = P[0, 0] - x[0], P[0, 1] - x[1], P[0, 2] - x[2]
    d = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    if not d > 0.0:
        return -1
    u = np.empty(3)
    u[0], u[1], u[2] = w0 / d, w1 / d, w2 / d
    ua = np.empty(3)
    Ju = np.empty((3, 3))
    Jb = np.empty((3, 3))
    lt = data[2] != 0.0
    ab = data[3] != 0.0
    if lt or ab:
        beta = np.empty(3)
        for i in range(3):
            beta[i] = ((x[3 + i] if ab else 0.0) - (P[1, i] if lt else 0.0)) / _C
        if aberrate_row_kernel(u, beta, ua, Ju, Jb) < 0.0:
            return -1
    else:
        for i in range(3):
            ua[i] = u[i]
            for j in range(3):
                Ju[i, j] = 1.0 if i == j else 0.0
                Jb[i, j] = 0.0
    q = np.empty(3)
    for i in range(3):
        if body_frame:
            q[i] = R[0, i] * ua[0] + R[1, i] * ua[1] + R[2, i] * ua[2]
        else:
            q[i] = ua[i]
    J = np.empty((2, 3))
    sphere_log_kernel(B, q[0], q[1], q[2], True, e, J)
    # M = J (R^T) : de/du'
    M = np.empty((2, 3))
    for i in range(2):
        for j in range(3):
            if body_frame:
                M[i, j] = J[i, 0] * R[j, 0] + J[i, 1] * R[j, 1] + J[i, 2] * R[j, 2]
            else:
                M[i, j] = J[i, j]
    for i in range(2):
        # de/du = M Ju; de/dr = -(de/du) (I - u u^T)/d; de/dv = M Jb / c
        a0 = M[i, 0] * Ju[0, 0] + M[i, 1] * Ju[1, 0] + M[i, 2] * Ju[2, 0]
        a1 = M[i, 0] * Ju[0, 1] + M[i, 1] * Ju[1, 1] + M[i, 2] * Ju[2, 1]
        a2 = M[i, 0] * Ju[0, 2] + M[i, 1] * Ju[1, 2] + M[i, 2] * Ju[2, 2]
        au = a0 * u[0] + a1 * u[1] + a2 * u[2]
        Hx[i, 0] = -(a0 - au * u[0]) / d
        Hx[i, 1] = -(a1 - au * u[1]) / d
        Hx[i, 2] = -(a2 - au * u[2]) / d
        for j in range(3):
            Hx[i, 3 + j] = ((M[i, 0] * Jb[0, j] + M[i, 1] * Jb[1, j] + M[i, 2] * Jb[2, j]) / _C
                            if ab else 0.0)
        if body_frame:
            HR[i, 0] = J[i, 1] * q[2] - J[i, 2] * q[1]
            HR[i, 1] = J[i, 2] * q[0] - J[i, 0] * q[2]
            HR[i, 2] = J[i, 0] * q[1] - J[i, 1] * q[0]
        else:
            HR[i, 0] = 0.0
            HR[i, 1] = 0.0
            HR[i, 2] = 0.0
    return 2


@njit(cache=True)
def limb_radius_body_kernel(x, data, B, e, H):
    """Row kernel of the ``limb_radius`` kind with its ``body`` column: ``data = (rho_meas,
    R, light time, aberration, has body)``; without a body (``data[4] = 0``) the Earth's limb
    at the frame origin, :func:`factors.limb.limb_radius_kernel` (``asin(R/|r|)``), else
    :func:`near_body_limb_kernel` with ``B[:2] = (p_body, v_body)``."""
    if data.shape[0] < 5 or data[4] == 0.0:   # (a log without a body packs 3 values)
        return limb_radius_kernel(x, data, B, e, H)
    return near_body_limb_kernel(x, data, B, e, H)


@njit(cache=True)
def near_body_direction_row_kernel(x, data, B, e, H):
    """Row kernel of ``body_direction`` (EME2000): :func:`near_body_direction_kernel` with
    ``B[:2] = (p_body, v_body)``, ``B[2:4]`` the tangent basis of the measured direction and
    ``data[2:4]`` the light-time and aberration flags; writes ``e`` (2,), ``H`` (2, 6)."""
    R = np.eye(3)
    HR = np.empty((2, 3))
    return near_body_direction_kernel(x, R, False, data, B[:2], B[2:4], e, H, HR)


@njit(cache=True)
def _limb_rows(X, D, P, E, H):
    for k in range(X.shape[0]):
        if near_body_limb_kernel(X[k], D[k], P[k], E[k], H[k]) < 0:
            return k
    return -1


@njit(cache=True)
def _direction_rows(X, R, body_frame, D, P, U, E, Hx, HR):
    B = np.empty((2, 3))
    for k in range(X.shape[0]):
        tangent_basis_kernel(U[k], B)
        if near_body_direction_kernel(X[k], R[k], body_frame, D[k], P[k], B, E[k], Hx[k],
                                      HR[k]) < 0:
            return k
    return -1


def _rows(a, n, shape):
    return np.ascontiguousarray(np.broadcast_to(np.asarray(a, dtype=float), (n,) + shape))


def _pack(x, p_body, v_body, light_time, aberration, value=0.0, radius=0.0):
    X = np.ascontiguousarray(np.asarray(x, dtype=float).reshape(-1, 6))
    n = len(X)
    P = np.ascontiguousarray(np.stack([_rows(p_body, n, (3,)), _rows(v_body, n, (3,))], axis=1))
    D = np.column_stack([_rows(value, n, ()), _rows(radius, n, ()),
                         np.full(n, 1.0 if light_time else 0.0),
                         np.full(n, 1.0 if aberration else 0.0)])
    return X, P, np.ascontiguousarray(D)


def near_body_limb_residual(x, rho_meas_rad, radius_m, p_body_m, v_body_mps, light_time=True,
                            aberration=True):
    """Limb angular radius of a body: ``e (N, 1)`` rad, ``H_x (N, 1, 6)`` (rad/m, rad s/m).
    ``x`` (N, 6) states; ``p_body_m``, ``v_body_mps`` (N, 3) or (3,), the body in the pass's
    frame; ``radius_m`` its limb sphere. ModelDomainError inside it."""
    X, P, D = _pack(x, p_body_m, v_body_mps, light_time, aberration, rho_meas_rad, radius_m)
    E = np.empty((len(X), 1))
    H = np.empty((len(X), 1, 6))
    k = run(_limb_rows, X, D, P, E, H)
    if k >= 0:
        raise ModelDomainError(f"near-body limb radius: the spacecraft is inside the limb "
                               f"sphere of radius {D[k, 1]:.1f} m (epoch index {k})")
    return E, H


def _direction(x, R, body_frame, u_meas, p_body_m, v_body_mps, light_time, aberration):
    X, P, D = _pack(x, p_body_m, v_body_mps, light_time, aberration)
    n = len(X)
    U = _rows(u_meas, n, (3,))
    Rm = _rows(np.eye(3) if R is None else R, n, (3, 3))
    E, Hx, HR = np.empty((n, 2)), np.empty((n, 2, 6)), np.empty((n, 2, 3))
    k = run(_direction_rows, X, Rm, body_frame, D, P, U, E, Hx, HR)
    if k >= 0:
        raise ModelDomainError(f"near-body direction: no direction at epoch index {k} "
                               "(the spacecraft at the body's centre, or |beta| >= 1)")
    return E, Hx, HR


def near_body_direction_residual(x, u_meas_eci, p_body_m, v_body_mps, light_time=True,
                                 aberration=True):
    """Direction of a body's centre in EME2000: ``e (N, 2)`` rad (sphere log map),
    ``H_x (N, 2, 6)`` (position and, through the aberration, velocity)."""
    E, Hx, _ = _direction(x, None, False, u_meas_eci, p_body_m, v_body_mps, light_time,
                          aberration)
    return E, Hx


def near_body_direction_body_residual(x, R_eci_from_body, u_meas_body, p_body_m, v_body_mps,
                                      light_time=True, aberration=True):
    """Direction of a body's centre in the body frame: ``e (N, 2)``, ``H_x (N, 2, 6)``,
    ``H_R (N, 2, 3)`` (right perturbation of ``R_eci_from_body``)."""
    return _direction(x, R_eci_from_body, True, u_meas_body, p_body_m, v_body_mps, light_time,
                      aberration)


def _row_data(p_body_m, v_body_mps, light_time, aberration, value=0.0, radius=0.0):
    P = np.ascontiguousarray(np.stack([np.asarray(p_body_m, dtype=float).reshape(3),
                                       np.asarray(v_body_mps, dtype=float).reshape(3)]))
    D = np.array([float(value), float(radius), 1.0 if light_time else 0.0,
                  1.0 if aberration else 0.0])
    return P, D


def make_near_body_limb_factor(key_x, rho_meas_rad, radius_m, p_body_m, v_body_mps, sigma_rad,
                               light_time=True, aberration=True):
    """CustomFactor on a state key ``[r; v]``: the limb radius row of
    :func:`near_body_limb_kernel` (error (1,) rad, Jacobian (1, 6)); the body's position and
    velocity (3,) in the pass's frame at the row's epoch."""
    import gtsam

    P, D = _row_data(p_body_m, v_body_mps, light_time, aberration, rho_meas_rad, radius_m)
    k = int(key_x)

    def error(this, values, H):
        x = np.asarray(values.atVector(k), dtype=float)
        e = np.empty(1)
        Hx = np.empty((1, x.shape[0]))
        if near_body_limb_kernel(x, D, P, e, Hx) < 0:
            raise ModelDomainError(f"near-body limb radius: r = {x[:3].tolist()} m is inside "
                                   f"the limb sphere of radius {radius_m:.1f} m")
        if H is not None:
            H[0] = Hx
        return e

    return gtsam.CustomFactor(noise_model(sigma_rad, 1), [k], error)


def make_near_body_direction_factor(key_x, u_meas, p_body_m, v_body_mps, sigma_rad, key_R=None,
                                    light_time=True, aberration=True):
    """CustomFactor for a body's centre direction: on the state key alone (``u_meas`` in
    EME2000) or, with ``key_R``, on (state, ``Rot3`` R_eci_from_body) for ``u_meas`` in the
    body frame. Error (2,) rad; Jacobians (2, 6) and (2, 3)."""
    import gtsam

    P, D = _row_data(p_body_m, v_body_mps, light_time, aberration)
    B = np.empty((2, 3))
    tangent_basis_kernel(np.asarray(u_meas, dtype=float).reshape(3), B)
    kx = int(key_x)
    body = key_R is not None
    eye = np.eye(3)

    def error(this, values, H):
        x = np.asarray(values.atVector(kx), dtype=float)
        R = values.atRot3(int(key_R)).matrix() if body else eye
        e = np.empty(2)
        Hx = np.empty((2, x.shape[0]))
        HR = np.empty((2, 3))
        if near_body_direction_kernel(x, R, body, D, P, B, e, Hx, HR) < 0:
            raise ModelDomainError(f"near-body direction undefined at r = {x[:3].tolist()} m")
        if H is not None:
            H[0] = Hx
            if body:
                H[1] = HR
        return e

    keys = [kx, int(key_R)] if body else [kx]
    return gtsam.CustomFactor(noise_model(sigma_rad, 2), keys, error)
