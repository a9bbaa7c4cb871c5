"""Attitude measurements: a star-tracker / TRIAD attitude as a ``Rot3`` prior.

The INS/CNS lecture ("定姿计算：双矢量定姿", the two-vector
attitude from the Sun and Moon directions). Attitudes are ``R_eci_from_body`` (body -> ECI);
perturbations are on the right, ``R <- R Exp(w)``, ``w`` in the body frame, rad.
"""

from __future__ import annotations

import numpy as np

from factors.adapters import noise_model
from factors.geometry import cross, so3_log, so3_right_jacobian_inv

__all__ = ["attitude_residual", "make_attitude_prior_factor", "triad", "triad_covariance"]

_MIN_SIN_ANGLE = 1e-6


def attitude_residual(R_eci_from_body, R_eci_from_body_meas):
    """Attitude error, identical to ``gtsam.PriorFactorRot3``'s: ``e = Log(R_meas^T R)``.

    ``H_R = Jr^-1(e)`` (right perturbation: ``Log(R_meas^T R Exp(w)) ~ e + Jr^-1(e) w``).

    Parameters
    ----------
    R_eci_from_body : (N, 3, 3) attitude variable; R_eci_from_body_meas : (N, 3, 3) measured.

    Returns
    -------
    e : (N, 3) rad, body frame; H_R : (N, 3, 3).
    """
    R = np.asarray(R_eci_from_body, dtype=float)
    Rm = np.asarray(R_eci_from_body_meas, dtype=float)
    e = so3_log(np.swapaxes(Rm, -1, -2) @ R)
    return e, so3_right_jacobian_inv(e)


def make_attitude_prior_factor(key_R, R_eci_from_body_meas, sigma_rad):
    """Attitude measurement on a ``Rot3`` key: GTSAM's built-in ``PriorFactorRot3``.

    Its error is ``Logmap(R_meas^-1 R)`` (3 components, rad, body frame; the same as
    :func:`attitude_residual`), so ``sigma_rad`` is the per-axis attitude noise about the
    body axes: a float, a (3,) array, or a (3, 3) covariance (e.g. :func:`triad_covariance`).

    Parameters
    ----------
    key_R : int; R_eci_from_body_meas : (3, 3) rotation matrix or ``gtsam.Rot3``.
    """
    import gtsam

    Rm = R_eci_from_body_meas
    if not isinstance(Rm, gtsam.Rot3):
        Rm = gtsam.Rot3(np.asarray(Rm, dtype=float))
    return gtsam.PriorFactorRot3(int(key_R), Rm, noise_model(sigma_rad, 3))


def _triad_frame(v1, v2, what):
    v1 = np.asarray(v1, dtype=float)
    v2 = np.asarray(v2, dtype=float)
    n1 = v1 / np.linalg.norm(v1, axis=-1, keepdims=True)
    c = cross(v1, v2)
    nc = np.linalg.norm(c, axis=-1, keepdims=True)
    sin_angle = nc / (np.linalg.norm(v1, axis=-1, keepdims=True)
                      * np.linalg.norm(v2, axis=-1, keepdims=True))
    if np.any(sin_angle < _MIN_SIN_ANGLE):
        raise ValueError(f"TRIAD: the two {what} vectors are (anti)parallel (sin of angle "
                         f"{float(np.min(sin_angle)):.2e}); attitude is undetermined")
    n2 = c / nc
    n3 = cross(n1, n2)
    return np.stack([n1, n2, n3], axis=-1)


def triad(v1_body, v2_body, v1_ref, v2_ref):
    """Two-vector (TRIAD) attitude, the INS/CNS lecture: ``C_b^i = P_N Q_M^T``.

    ``N1 = v1_ref/|v1_ref|``, ``N2 = (v1_ref x v2_ref)/|v1_ref x v2_ref|``,
    ``N3 = N1 x N2``; ``M1..M3`` likewise from the body vectors; ``P_N = [N1 N2 N3]``,
    ``Q_M = [M1 M2 M3]``. The first vector is matched exactly (use the more accurate one).

    Parameters
    ----------
    v1_body, v2_body : (..., 3) directions measured in the body frame (any length).
    v1_ref, v2_ref : (..., 3) the same directions in the reference frame (e.g. ECI).

    Returns
    -------
    R_ref_from_body : (..., 3, 3), ``v_ref = R_ref_from_body @ v_body``.

    Raises
    ------
    ValueError if either pair is (anti)parallel.
    """
    P = _triad_frame(v1_ref, v2_ref, "reference")
    Q = _triad_frame(v1_body, v2_body, "body")
    return P @ np.swapaxes(Q, -1, -2)


def triad_covariance(v1_body, v2_body, sigma1_rad, sigma2_rad):
    """Covariance of the TRIAD attitude error (Shuster & Oh 1981, J. Guid. Control 4(1),
    the TRIAD covariance ``P_TRIAD``).

    Error model: each measured unit vector is ``b_i + db_i`` with ``db_i`` perpendicular to
    ``b_i``, covariance ``sigma_i^2 (I - b_i b_i^T)`` (``sigma_i`` per tangent axis, rad). The
    attitude error is the right perturbation ``R_hat = R_true Exp(phi)`` of
    ``R_ref_from_body`` (``phi`` in the body frame, the error of ``PriorFactorRot3``).
    Linearizing the TRIAD constraints (``b1`` matched exactly; ``b2`` kept in the plane of
    ``b1, b2``) gives ``phi = -b1 x db1 + alpha b1`` with
    ``alpha = -(n . db2 - (b2 x n) . (b1 x db1)) / s``, ``n = b1 x b2 / s``, and

    ``P = sigma1^2 I + s^-2 [ (sigma2^2 - sigma1^2) b1 b1^T + sigma1^2 c (b1 b2^T + b2 b1^T) ]``

    with ``c = b1 . b2``, ``s = |b1 x b2|``: Shuster & Oh's result (derived here, checked
    against Monte Carlo in the tests).

    Parameters
    ----------
    v1_body, v2_body : (..., 3) body-frame directions (normalized internally).
    sigma1_rad, sigma2_rad : float or (...,), per-axis noise of each direction, rad.

    Returns
    -------
    P : (..., 3, 3) rad^2, body frame.
    """
    b1 = np.asarray(v1_body, dtype=float)
    b2 = np.asarray(v2_body, dtype=float)
    b1 = b1 / np.linalg.norm(b1, axis=-1, keepdims=True)
    b2 = b2 / np.linalg.norm(b2, axis=-1, keepdims=True)
    c = np.sum(b1 * b2, axis=-1)[..., None, None]
    s2 = np.sum(cross(b1, b2) ** 2, axis=-1)[..., None, None]
    if np.any(s2 < _MIN_SIN_ANGLE**2):
        raise ValueError("triad_covariance: the two vectors are (anti)parallel")
    v1 = np.asarray(sigma1_rad, dtype=float)[..., None, None] ** 2
    v2 = np.asarray(sigma2_rad, dtype=float)[..., None, None] ** 2
    b1b1 = b1[..., :, None] * b1[..., None, :]
    b1b2 = b1[..., :, None] * b2[..., None, :]
    sym = b1b2 + np.swapaxes(b1b2, -1, -2)
    return v1 * np.eye(3) + ((v2 - v1) * b1b1 + v1 * c * sym) / s2
