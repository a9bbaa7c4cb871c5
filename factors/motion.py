"""Motion factor between consecutive orbit states: x_{k+1} = f(x_k, dt) + w.

f is the RK4 propagator of ``factors.dynamics`` (two-body + J2, optional Sun/Moon), its
Jacobian the exact discrete state-transition matrix Phi; w ~ N(0, Q) is the
white-acceleration process noise (``factors.dynamics.process_noise``; Bar-Shalom, Li & Kirubarajan
2001, eq. 6.2.2-12). States are ECI [r (m); v (m/s)] on ``gtsam`` Vector6 keys.

Residual (unwhitened, SI)::

    e = x1 - f(x0, dt),   d e / d x0 = -Phi,   d e / d x1 = I.
"""

from __future__ import annotations

import functools

import numpy as np

from factors.dynamics import (
    MotionModel, process_noise, propagate_many, propagate_nb,
)

__all__ = ["motion_residual", "make_motion_factor", "impulse_rows", "impulse_sqrt_information"]

_DEFAULT_MODEL = MotionModel()


def motion_residual(x0, x1, dt_s, model: MotionModel = _DEFAULT_MODEL, t0_j2000_s=0.0):
    """Motion-factor residuals for N epoch pairs, vectorized.

    x0, x1: (N,6) ECI states [m, m/s] at t and t + dt; dt_s: (N,) s; t0_j2000_s: (N,) or
    scalar, start times in s since J2000 TT (Sun/Moon positions). Returns
    ``e (N,6) = x1 - f(x0)``, ``H0 = -Phi (N,6,6)``, ``H1 = I (N,6,6)``.
    """
    x0 = np.ascontiguousarray(x0, dtype=float)
    x1 = np.asarray(x1, dtype=float)
    if x0.ndim != 2 or x0.shape[1] != 6 or x1.shape != x0.shape:
        raise ValueError(f"x0 and x1 must both have shape (N, 6), got {x0.shape} and {x1.shape}")
    f, Phi = propagate_many(x0, dt_s, model, t0_j2000_s, with_stm=True)
    N = x0.shape[0]
    H1 = np.broadcast_to(np.eye(6), (N, 6, 6)).copy()
    return x1 - f, -Phi, H1


@functools.lru_cache(maxsize=64)
def _motion_noise(dt_s: float, q_m2_s3: float):
    """The GTSAM noise model of Q(dt, q), shared by every motion factor with the same step.

    Cached: an online smoother builds one motion factor per epoch, nearly always with the
    same dt, and ``process_noise`` costs 28 us of the ~0.3 ms fixed-lag epoch. smart=False:
    with the default smart=True GTSAM tests "is Q diagonal?" with an absolute tolerance
    (~1e-9), so at small q dt^2 it silently drops the position-velocity correlation and
    builds a Diagonal model (wrong by 4x in information at q = 1e-9, dt = 1 s).
    """
    import gtsam

    return gtsam.noiseModel.Gaussian.Covariance(process_noise(dt_s, q_m2_s3), False)


def impulse_rows(x0, x1, dt_s, q_m2_s3, model: MotionModel, t0_j2000_s, mean, cov):
    """Whitened motion rows of one step that ends with an impulse (a declared manoeuvre):
    ``x1 = f(x0, dt) + d + w``, ``d ~ N(mean, cov)`` (6,), (6, 6) (``[0; dv]``: Tapley,
    Schutz & Born 2004, sec. 4.9), ``w ~ N(0, Q)``, so ``e = x1 - f(x0) - mean`` with
    covariance ``C = Q + cov`` (the sum of independent Gaussians). Returns ``A0 = -W Phi``,
    ``A1 = W``, ``b = -W e`` (6, 6), (6, 6), (6,) with ``W = L^-1``, ``C = L L^T``, and
    ``Phi``."""
    f, Phi = propagate_many(np.ascontiguousarray(np.asarray(x0, dtype=float)[None]),
                            np.array([float(dt_s)]), model, np.array([float(t0_j2000_s)]),
                            with_stm=True)
    W = impulse_sqrt_information(dt_s, q_m2_s3, cov)
    e = np.asarray(x1, dtype=float) - f[0] - np.asarray(mean, dtype=float)
    return -W @ Phi[0], W, -W @ e, Phi[0]


def impulse_sqrt_information(dt_s, q_m2_s3, cov):
    """The upper-triangular ``W`` (6, 6), ``W^T W = C^-1``, of ``C = Q(dt, q) + cov`` (GTSAM's
    ``Gaussian.Covariance`` R: the Cholesky factor is unique). For ``cov`` of the impulses'
    form, ``[0, 0; 0, s2 I]``, per axis in closed form: with ``C_axis = [[a, b], [b, d]]``
    (``a = q T^3/3``, ``b = q dt T/2``, ``d = q T + s2``, ``D = a d - b^2``),
    ``W_axis = [[sqrt(d/D), -b/sqrt(d D)], [0, 1/sqrt(d)]]`` (``s2 = 0``: the process noise's,
    :func:`factors.dynamics.process_noise_sqrt_information`); otherwise the Cholesky factor of
    the inverse."""
    cov = np.asarray(cov, dtype=float)
    s2 = cov[3, 3]
    C = process_noise(float(dt_s), q_m2_s3) + cov
    if not (np.all(cov[:3] == 0) and np.all(cov[:, :3] == 0)
            and np.array_equal(cov[3:, 3:], s2 * np.eye(3))):
        return np.linalg.cholesky(np.linalg.inv(C)).T
    a, b, d = C[0, 0], C[0, 3], C[3, 3]
    D = a * d - b * b
    blk = np.array([[np.sqrt(d / D), -b / np.sqrt(d * D)], [0.0, 1.0 / np.sqrt(d)]])
    return np.kron(blk, np.eye(3))


def make_motion_factor(key0, key1, dt_s, q_m2_s3, model: MotionModel = _DEFAULT_MODEL,
                       t0_j2000_s=0.0, impulse=None):
    """``gtsam.CustomFactor`` for x1 = f(x0, dt) + w on two Vector6 keys.

    key0/key1: keys of the states at t and t + dt_s (s; must be nonzero); q_m2_s3: acceleration
    PSD of the white-acceleration noise (m^2/s^3); noise model
    ``Gaussian.Covariance(process_noise(dt_s, q), smart=False)`` (its R equals
    ``process_noise_sqrt_information``; smart=True would turn it diagonal at small q). The error function calls the numba
    kernel directly (no per-call Python wrapper work beyond reading the two vectors).

    ``impulse = (mean (6,), cov (6, 6))``: the step ends with that impulse (a declared
    manoeuvre, :func:`impulse_rows`): error ``x1 - f(x0) - mean``, noise ``Q + cov`` (its
    square-root information :func:`impulse_sqrt_information`, as the bulk rows').
    """
    import gtsam

    dt = float(dt_s)
    if dt == 0.0:
        raise ValueError("make_motion_factor: dt_s must be nonzero (process noise is singular)")
    if impulse is None:
        noise = _motion_noise(dt, float(q_m2_s3))
        shift = np.zeros(6)
    else:
        shift = np.array(impulse[0], dtype=float)
        noise = gtsam.noiseModel.Gaussian.SqrtInformation(
            impulse_sqrt_information(dt, float(q_m2_s3), impulse[1]), False)
    mu, j2, re, third, hmax, mus, mum, eph = model.args()
    t0 = float(t0_j2000_s)
    k0, k1 = int(key0), int(key1)

    def error(this, values, H):
        x0 = values.atVector(k0)
        x1 = values.atVector(k1)
        f = np.empty(6)
        Phi = np.empty((6, 6))
        want = H is not None
        propagate_nb(x0, dt, mu, j2, re, third, hmax, mus, mum, eph, t0, want, f, Phi)
        if want:
            H[0] = -Phi
            H[1] = np.eye(6)
        return x1 - f - shift

    return gtsam.CustomFactor(noise, [k0, k1], error)
