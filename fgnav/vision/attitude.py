"""Attitude from star directions: SVD solution of Wahba's problem with its covariance,
and the pixel-level star model used to refine attitude + focal length (+ k1).

Frames: ``b_body`` are measured unit vectors in the sensor/body (camera) frame, ``r_ref``
the matching catalogue unit vectors in ECI; the solution is ``R_ref_from_body`` with
``r_ref ~ R_ref_from_body @ b_body``. Attitude errors are GTSAM right perturbations
``R_true = R_est @ Exp(dtheta)``, ``dtheta`` in the body frame (rad).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factors.geometry import skew

__all__ = ["WahbaSolution", "wahba_svd", "wahba_by_epoch", "quest_covariance", "star_pixel_model",
           "quat_from_matrix", "matrix_from_quat", "roll_ra_dec",
           "rotation_from_ra_dec_roll"]


@dataclass(frozen=True)
class WahbaSolution:
    """R_ref_from_body (3x3); cov_rad2: 3x3 covariance of the right perturbation (body
    frame, rad^2); loss: Wahba loss ``1/2 sum w_i |r_i - R b_i|^2`` (w_i = 1/sigma_i^2)."""

    R_ref_from_body: np.ndarray
    cov_rad2: np.ndarray
    loss: float


def quest_covariance(b_body: np.ndarray, sigma_rad) -> np.ndarray:
    """Attitude covariance under the QUEST measurement model (Shuster & Oh 1981, eq. 83):

    ``P = [sum_i sigma_i^-2 (I - b_i b_i^T)]^-1`` (rad^2), for the body-frame right
    perturbation. Each direction constrains only the two axes perpendicular to it, so for a
    narrow field around the boresight +z the roll variance ``P_zz`` is larger than the
    cross-boresight variances by about (1 / field radius)^2.
    """
    b = np.asarray(b_body, float)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    w = 1.0 / np.broadcast_to(np.asarray(sigma_rad, float), b.shape[:1]) ** 2
    F = np.einsum("i,ij,ik->jk", w, b, b)
    info = np.sum(w) * np.eye(3) - F
    return np.linalg.inv(info)


def wahba_svd(b_body: np.ndarray, r_ref: np.ndarray, sigma_rad=1.0) -> WahbaSolution:
    """Least-squares attitude from >= 2 non-parallel vector pairs (Markley 1988, SVD method).

    ``B = sum_i w_i r_i b_i^T = U S V^T``, ``R = U diag(1, 1, det U det V) V^T``
    maximises ``tr(R^T B)``, i.e. minimises Wahba's loss. ``sigma_rad`` (scalar or (N,)):
    angular 1-sigma of each measured direction. The covariance is :func:`quest_covariance`.
    """
    b = np.asarray(b_body, float)
    r = np.asarray(r_ref, float)
    if b.shape != r.shape or b.ndim != 2 or b.shape[1] != 3 or len(b) < 2:
        raise ValueError(f"wahba_svd needs two (N>=2, 3) arrays, got {b.shape} and {r.shape}")
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    r = r / np.linalg.norm(r, axis=-1, keepdims=True)
    w = 1.0 / np.broadcast_to(np.asarray(sigma_rad, float), (len(b),)) ** 2
    B = np.einsum("i,ij,ik->jk", w, r, b)
    U, _, Vt = np.linalg.svd(B)
    d = np.linalg.det(U) * np.linalg.det(Vt)
    R = U @ np.diag([1.0, 1.0, d]) @ Vt
    res = r - b @ R.T
    return WahbaSolution(R, quest_covariance(b, sigma_rad), 0.5 * float(np.sum(w * np.sum(res**2, axis=1))))


def wahba_by_epoch(k: np.ndarray, b_body: np.ndarray, r_ref: np.ndarray, sigma_rad,
                   min_stars: int = 2):
    """:func:`wahba_svd` of the directions of each epoch: the attitude of every epoch index in
    ``k`` (M,) with at least ``min_stars`` (>= 2) pairs that are not all parallel.

    ``b_body`` (M, 3) measured directions, ``r_ref`` (M, 3) their reference directions,
    ``sigma_rad`` (M,) or scalar their angular 1-sigma. Returns ``(epochs (E,), R (E, 3, 3)
    R_ref_from_body, cov (E, 3, 3) rad^2)``, epochs increasing.
    """
    k = np.asarray(k)
    b = np.asarray(b_body, float)
    r = np.asarray(r_ref, float)
    sig = np.broadcast_to(np.asarray(sigma_rad, float), k.shape)
    order = np.argsort(k, kind="stable")
    bounds = np.flatnonzero(np.diff(k[order])) + 1
    epochs, Rs, covs = [], [], []
    for grp in np.split(order, bounds):
        if len(grp) < max(2, min_stars):
            continue
        bb = b[grp] / np.linalg.norm(b[grp], axis=1, keepdims=True)
        if np.linalg.matrix_rank(np.eye(3) * len(grp) - bb.T @ bb, tol=1e-9 * len(grp)) < 3:
            continue   # all directions parallel: the rotation about them is free
        sol = wahba_svd(bb, r[grp], sig[grp])
        epochs.append(int(k[grp[0]]))
        Rs.append(sol.R_ref_from_body)
        covs.append(sol.cov_rad2)
    return (np.array(epochs, dtype=int), np.array(Rs).reshape(-1, 3, 3),
            np.array(covs).reshape(-1, 3, 3))


def star_pixel_model(R_eci_from_camera: np.ndarray, f_px: float, k1: float, u_eci: np.ndarray,
                     cx: float, cy: float):
    """Predicted pixel positions of catalogue stars and their Jacobians.

    ``v = R^T u_eci`` (camera frame), ``(x, y) = (v_x, v_y) / v_z``, ``d = 1 + k1 (x^2 + y^2)``,
    ``uv = (cx + f x d, cy + f y d)`` (the :mod:`fgnav.vision.camera` model with k2 = 0).
    Jacobians (derivation): with ``R <- R Exp(theta)``, ``dv/dtheta = [v]_x``;
    ``d(x, y)/dv = [[1/z, 0, -x/z], [0, 1/z, -y/z]]``; ``d(xd, yd)/d(x, y) = d I + 2 k1 [x y]^T [x y]``;
    ``duv/df = (x d, y d)``, ``duv/dk1 = f r^2 (x, y)``.

    Returns uv (N, 2) px, H_theta (N, 2, 3) px/rad, H_f (N, 2) px/px, H_k1 (N, 2) px.
    """
    v = np.asarray(u_eci, float) @ np.asarray(R_eci_from_camera, float)
    z = v[:, 2]
    x, y = v[:, 0] / z, v[:, 1] / z
    r2 = x * x + y * y
    d = 1.0 + k1 * r2
    uv = np.stack([cx + f_px * x * d, cy + f_px * y * d], axis=-1)
    dxy_dv = np.zeros((len(v), 2, 3))
    dxy_dv[:, 0, 0] = 1.0 / z
    dxy_dv[:, 0, 2] = -x / z
    dxy_dv[:, 1, 1] = 1.0 / z
    dxy_dv[:, 1, 2] = -y / z
    xy = np.stack([x, y], axis=-1)
    D = d[:, None, None] * np.eye(2) + 2.0 * k1 * xy[:, :, None] * xy[:, None, :]
    H_theta = f_px * D @ dxy_dv @ skew(v)
    H_f = xy * d[:, None]
    H_k1 = f_px * xy * r2[:, None]
    return uv, H_theta, H_f, H_k1


def quat_from_matrix(R: np.ndarray) -> np.ndarray:
    """Rotation matrix -> unit quaternion (w, x, y, z), scalar first, w >= 0 (Shepperd)."""
    R = np.asarray(R, float)
    tr = np.trace(R)
    cands = np.array([1.0 + tr, 1.0 + 2 * R[0, 0] - tr, 1.0 + 2 * R[1, 1] - tr, 1.0 + 2 * R[2, 2] - tr])
    k = int(np.argmax(cands))
    s = np.sqrt(cands[k]) * 2.0  # = 4 |q_k|
    if k == 0:
        q = [s / 4, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif k == 1:
        q = [(R[2, 1] - R[1, 2]) / s, s / 4, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif k == 2:
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, s / 4, (R[1, 2] + R[2, 1]) / s]
    else:
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, s / 4]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def matrix_from_quat(q) -> np.ndarray:
    """Unit quaternion (w, x, y, z) -> rotation matrix."""
    w, x, y, z = np.asarray(q, float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def roll_ra_dec(R_eci_from_camera: np.ndarray) -> tuple[float, float, float]:
    """Pointing of the camera +z axis and roll, all in radians.

    ``ra, dec``: right ascension / declination of the boresight ``b = R[:, 2]``.
    ``roll``: position angle of the image "up" direction (``-y`` camera axis, decreasing v)
    measured from celestial north towards east, in (-pi, pi]: 0 when image up points to
    north, +pi/2 when it points east. (North ``n`` and east ``e = z_eci x b / |.|`` are
    the local sky directions at ``b``.)
    """
    R = np.asarray(R_eci_from_camera, float)
    b = R[:, 2]
    ra = float(np.mod(np.arctan2(b[1], b[0]), 2 * np.pi))
    dec = float(np.arcsin(np.clip(b[2], -1.0, 1.0)))
    east = np.array([-np.sin(ra), np.cos(ra), 0.0])
    north = np.cross(b, east)
    up = -R[:, 1]
    roll = float(np.arctan2(up @ east, up @ north))
    return ra, dec, roll


def rotation_from_ra_dec_roll(ra_rad: float, dec_rad: float, roll_rad: float) -> np.ndarray:
    """Inverse of :func:`roll_ra_dec`: R_eci_from_camera with boresight at (ra, dec) and
    image up at position angle ``roll`` (rad) from north through east."""
    b = np.array([np.cos(dec_rad) * np.cos(ra_rad), np.cos(dec_rad) * np.sin(ra_rad), np.sin(dec_rad)])
    east = np.array([-np.sin(ra_rad), np.cos(ra_rad), 0.0])
    north = np.cross(b, east)
    up = np.cos(roll_rad) * north + np.sin(roll_rad) * east
    y = -up
    x = np.cross(y, b)
    return np.column_stack([x, y, b])

