"""What a real limb needs beyond pixel noise: the body's flattening seen at the frame's
attitude, the lit limb, the limb's height, correlated residuals and a model-error floor.

:func:`fgnav.vision.horizon.horizon_christian_robinson` counts only independent pixel noise
and fits a sphere. On real frames (DSCOVR/EPIC, docs/epic.md) that sigma was 11.7 times
smaller than the frame-to-frame scatter. :func:`real_limb_fix` adds, each optional:

1. **Flattening** (Christian & Robinson 2016 and Christian's 2021 tutorial): the limb surface is
   the oblate ellipsoid ``x^T A x = 1``, ``A_body = diag(a^-2, a^-2, b^-2)``,
   ``b = a (1 - f)``, its axis the ECI z axis (the J2000 pole; the precession of the pole
   since J2000, 0.3 deg in 2022, changes the apparent flattening by < 1e-5 of the range);
   in the camera frame ``A_cam = R^T A_body R`` with ``R = R_eci_from_cam``, so
   ``U = diag(1/a, 1/a, 1/b) R`` (``A_cam = U^T U``), which Christian–Robinson takes as is.
2. **The lit limb**: only limb points whose tangent point on the limb surface sees the Sun
   above its horizon (``cos z = n_hat . s_sun > 0``, ``n_hat`` the surface normal there) lie
   on the limb; the others are on the terminator, which seen from near full phase bends up
   to ``R (1 - cos alpha)`` inside the limb (alpha the phase angle; 9 px on EPIC at 12 deg).
   From far away about half the limb is lit at any phase (the terminator and the tangent
   points' circle, nearly a great circle, cross twice).
   The tangent point: in the body's unit-sphere space ``s' = U s / |U s|``, ``c' = U c``,
   the tangent point is ``x' = (s'.c') s'``; the normal is ``U^T (x' - c')``.
3. **Limb height**: the visible limb's height above the reference surface goes into the
   radius given (``r_limb_m``, the equatorial radius of the limb surface); its 1-sigma
   ``limb_height_sigma_m`` is a common radial shift of the whole limb by
   ``f_px * sigma_h / range`` px, added to the covariance.
4. **Correlated residuals**: neighbouring limb points share clouds, compression blocks and
   resampling kernels; the fit's covariance, which assumes independent points, is
   multiplied by the variance inflation ``k = 1 + 2 sum_L (1 - L/N) r_L`` of the normal
   residuals ordered along the limb (``r_L`` their lag-L autocorrelation, summed up to its
   first non-positive lag; Bayley & Hammersley 1946, the effective number of independent
   observations ``N / k``).
5. **Model-error floor** ``floor_px``: a common error of the limb's radius and of its two
   translations, each with this 1-sigma in pixels (what the model leaves out: the image
   product's resampling and compression, the limb's own shape), added to the covariance.

Terms 3 and 5 enter through the fit's linearization: moving every point by ``dt_i`` along
its normal changes the residuals by ``g_i dt_i`` (``g_i`` the residual per pixel,
:func:`fgnav.vision.horizon.cr_point_gains`), so the cone vector moves by
``dn = -(H^T W H)^-1 H^T W (g * dt)`` (``H`` the rays ``s'_i``, ``W = diag(g^-2)``); each
mode adds ``sigma^2 dn dn^T`` to the covariance of ``n``, which the analytic Jacobians of
:func:`fgnav.vision.horizon.cr_jacobians` carry to ``(u, rho)`` and the position.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from factors.constants import R_EARTH_M
from fgnav.errors import UserError
from fgnav.vision.camera import PinholeCamera
from fgnav.vision.horizon import (HorizonFix, cr_jacobians, cr_point_gains, cr_residuals_px,
                                  horizon_christian_robinson)
from fgnav.vision.limb import LimbPoints, edge_curvature_bias_px, ransac_limb

__all__ = ["WGS84_FLATTENING", "LimbModel", "ellipsoid_shape_matrix", "north_up_R_eci_from_cam",
           "tangent_sun_cosine", "residual_variance_inflation", "real_limb_fix"]

WGS84_FLATTENING = 1.0 / 298.257223563
"""Flattening of the WGS-84 ellipsoid (NIMA TR8350.2); its equatorial radius is
:data:`factors.constants.R_EARTH_M`."""


@dataclass(frozen=True)
class LimbModel:
    """The limb model of :func:`real_limb_fix` (module doc; SI units).

    r_limb_m : equatorial radius of the limb surface (reference radius + limb height).
    R_eci_from_cam : camera attitude (3x3) or None (sphere); with it the limb surface is the
    ellipsoid of ``flattening`` about the ECI z axis. sun_eci : Sun direction from the body's
    centre (ECI, any length) or None (every limb point kept); needs the attitude.
    limb_height_sigma_m : 1-sigma of the limb height (common to the whole limb).
    correlated : inflate the covariance by the residuals' correlation along the limb.
    floor_px : model-error floor (px) on the limb radius and centre.
    psf_sigma_px : optics PSF sigma (px) for the edge-curvature correction, or None.
    """

    r_limb_m: float = R_EARTH_M
    R_eci_from_cam: np.ndarray | None = None
    flattening: float = WGS84_FLATTENING
    sun_eci: np.ndarray | None = None
    limb_height_sigma_m: float = 0.0
    correlated: bool = False
    floor_px: float = 0.0
    psf_sigma_px: float | None = None
    k_sigma: float = 3.5
    min_threshold_px: float = 0.5

    def __post_init__(self):
        if not (self.r_limb_m > 0 and math.isfinite(self.r_limb_m)):
            raise UserError(f"limb model: r_limb_m must be finite and > 0, got {self.r_limb_m}")
        if not 0.0 <= self.flattening < 1.0:
            raise UserError(f"limb model: flattening must be in [0, 1), got {self.flattening}")
        if not (self.limb_height_sigma_m >= 0 and self.floor_px >= 0):
            raise UserError("limb model: limb_height_sigma_m and floor_px must be >= 0")
        if self.sun_eci is not None and self.R_eci_from_cam is None:
            raise UserError("limb model: the Sun direction needs the camera attitude (R_eci_from_cam)")
        if self.R_eci_from_cam is not None:
            R = np.asarray(self.R_eci_from_cam, float)
            if R.shape != (3, 3) or not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
                raise UserError("limb model: R_eci_from_cam must be a 3x3 rotation matrix")
        if self.sun_eci is not None and not np.linalg.norm(np.asarray(self.sun_eci, float)) > 0:
            raise UserError("limb model: the Sun direction must be a non-zero vector")

    def shape_matrix(self) -> np.ndarray:
        """``U`` with ``A_cam = U^T U`` (module doc, 1): sphere ``I / r`` without an attitude."""
        if self.R_eci_from_cam is None:
            return np.eye(3) / self.r_limb_m
        return ellipsoid_shape_matrix(np.asarray(self.R_eci_from_cam, float), self.r_limb_m, self.flattening)

    def sun_cam(self) -> np.ndarray | None:
        if self.sun_eci is None:
            return None
        s = np.asarray(self.R_eci_from_cam, float).T @ np.asarray(self.sun_eci, float)
        return s / np.linalg.norm(s)


def ellipsoid_shape_matrix(R_eci_from_cam: np.ndarray, a_m: float, flattening: float) -> np.ndarray:
    """``U = diag(1/a, 1/a, 1/b) R_eci_from_cam``, ``b = a (1 - f)``: the oblate ellipsoid
    about the ECI z axis in the camera frame, ``A_cam = U^T U`` (module doc, 1)."""
    b = a_m * (1.0 - flattening)
    return np.diag([1.0 / a_m, 1.0 / a_m, 1.0 / b]) @ np.asarray(R_eci_from_cam, float)


def north_up_R_eci_from_cam(u_eci_to_body: np.ndarray, pole_eci=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera attitude of a re-centred, north-up product (EPIC level 1B): boresight ``z``
    along ``u_eci_to_body`` (camera -> body centre), image up (``-y``) along the pole's
    projection on the image plane, ``x = y x z`` (east to the right, as seen from outside)."""
    z = np.asarray(u_eci_to_body, float)
    z = z / np.linalg.norm(z)
    k = np.asarray(pole_eci, float)
    kp = k - (k @ z) * z
    if not np.linalg.norm(kp) > 1e-9:
        raise UserError("north-up attitude: the boresight is along the pole (north undefined)")
    y = -kp / np.linalg.norm(kp)
    return np.column_stack([np.cross(y, z), y, z])


def tangent_sun_cosine(points: LimbPoints, camera: PinholeCamera, c_cam_m: np.ndarray,
                       U: np.ndarray, sun_cam: np.ndarray) -> np.ndarray:
    """``cos z`` of the Sun at the tangent point of each limb point's ray (module doc, 2).

    c_cam_m : camera -> body centre (camera frame, m); U : shape matrix; sun_cam : unit Sun
    direction in the camera frame. Returns (N,).
    """
    s = camera.pixel_to_ray(points.uv_px)
    sp = s @ U.T
    sp /= np.linalg.norm(sp, axis=1, keepdims=True)
    cp = U @ np.asarray(c_cam_m, float)
    xp = (sp @ cp)[:, None] * sp
    nrm = (xp - cp) @ U                                   # U^T (x' - c'), row-wise
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return nrm @ sun_cam


def residual_variance_inflation(res_px: np.ndarray, order: np.ndarray) -> float:
    """Variance inflation ``k >= 1`` of a fit to residuals correlated along the limb
    (module doc, 4): ``1 + 2 sum_{L=1}^{Lc} (1 - L/N) r_L``, ``r_L`` the lag-L
    autocorrelation of ``res_px[order]``, ``Lc`` the lag before the first ``r_L <= 0``
    (at most N/4)."""
    r = np.asarray(res_px, float)[order]
    r = r - r.mean()
    n = r.size
    v = float(r @ r) / n
    if n < 8 or not v > 0:
        return 1.0
    k = 1.0
    for lag in range(1, max(n // 4, 1) + 1):
        rho = float(r[:-lag] @ r[lag:]) / n / v
        if rho <= 0:
            break
        k += 2.0 * (1.0 - lag / n) * rho
    return max(k, 1.0)


def _mode_dn(sp, g, dt):
    """Cone-vector change for normal point motions ``dt`` (module doc, last paragraph)."""
    w = 1.0 / g ** 2
    N = sp.T @ (sp * w[:, None])
    return -np.linalg.solve(N, sp.T @ (w * g * dt))


def real_limb_fix(points: LimbPoints, camera: PinholeCamera, model: LimbModel, *,
                  rng: np.random.Generator | None = None, iterations: int = 4) -> HorizonFix:
    """Christian–Robinson fix of raw limb points with the real-limb model (module doc).

    points : limb points from :func:`fgnav.vision.limb.extract_limb_points` (before RANSAC).
    Outliers: RANSAC on the circular cone, then ``iterations`` rounds of: fit on the kept
    points, residuals of all points against that fit, keep the lit points within
    ``max(min_threshold_px, k_sigma * MAD sigma)`` of it. ``extra`` records each term:
    ``n_lit`` / ``n_unlit``, ``variance_inflation``, ``sigma_rho_pixel_rad`` (pixel noise
    only), ``sigma_rho_rad`` with every term, ``curvature_correction_px``.
    """
    U = model.shape_matrix()
    sun = model.sun_cam()
    pts0 = points
    curv = 0.0
    kept = ransac_limb(points, camera, rng=rng).inlier
    if kept.sum() < 6:
        raise UserError(f"real limb: only {int(kept.sum())} limb points after RANSAC (need >= 6)")
    if model.psf_sigma_px is not None:
        first = horizon_christian_robinson(LimbPoints(points.uv_px, points.normal, points.contrast, kept),
                                           camera, model.r_limb_m, U=U)
        curv = edge_curvature_bias_px(camera.f_px * math.tan(first.rho_rad), model.psf_sigma_px)
        pts0 = points.shifted(curv)
    sel = LimbPoints(pts0.uv_px, pts0.normal, pts0.contrast, kept)
    fix = horizon_christian_robinson(sel, camera, model.r_limb_m, U=U)
    lit = np.ones(len(pts0), bool)
    for _ in range(iterations):
        res = cr_residuals_px(pts0, camera, fix.extra["n"], U)
        if sun is not None:
            lit = tangent_sun_cosine(pts0, camera, -fix.r_cam_m, U, sun) > 0.0
            if lit.sum() < 6:
                raise UserError(f"real limb: only {int(lit.sum())} limb points on the lit limb (need >= 6)")
        sig = 1.4826 * np.median(np.abs(res[lit]))
        keep = lit & (np.abs(res) <= max(model.min_threshold_px, model.k_sigma * sig))
        if keep.sum() < 6:
            raise UserError(f"real limb: only {int(keep.sum())} limb points fit the limb model (need >= 6)")
        fix = horizon_christian_robinson(LimbPoints(pts0.uv_px, pts0.normal, pts0.contrast, keep),
                                         camera, model.r_limb_m, U=U)
    used = LimbPoints(pts0.uv_px[keep], pts0.normal[keep], pts0.contrast[keep], np.ones(int(keep.sum()), bool))
    n = fix.extra["n"]
    Pn_pixel = fix.extra["cov_n"]
    res = cr_residuals_px(used, camera, n, U)
    ctr = fix.centre_px
    order = np.argsort(np.arctan2(used.uv_px[:, 1] - ctr[1], used.uv_px[:, 0] - ctr[0]))
    k = residual_variance_inflation(res, order) if model.correlated else 1.0
    Pn = k * Pn_pixel
    s = camera.pixel_to_ray(used.uv_px)
    sp = s @ U.T
    sp /= np.linalg.norm(sp, axis=1, keepdims=True)
    g = cr_point_gains(used, camera, n, U)
    rng_m = float(fix.range_m)
    radial = np.ones(len(used))
    modes = []
    sig_h_px = camera.f_px * model.limb_height_sigma_m / rng_m
    if sig_h_px > 0:
        modes.append(sig_h_px * _mode_dn(sp, g, radial))
    if model.floor_px > 0:
        for dt in (radial, used.normal[:, 0], used.normal[:, 1]):
            modes.append(model.floor_px * _mode_dn(sp, g, dt))
    for dn in modes:
        Pn = Pn + np.outer(dn, dn)
    jac = cr_jacobians(n, U)
    Ju = np.vstack([jac["du_dn"], jac["drho_dn"][None, :]])
    cov4 = Ju @ Pn @ Ju.T
    cov_r = jac["dc_dn"] @ Pn @ jac["dc_dn"].T
    extra = dict(fix.extra)
    extra.update(cov_n=Pn, n_lit=int(lit.sum()), n_unlit=int((~lit).sum()), variance_inflation=float(k),
                 sigma_rho_pixel_rad=float(np.sqrt(max((Ju @ Pn_pixel @ Ju.T)[3, 3], 0.0))),
                 curvature_correction_px=float(curv), limb_model=True)
    return replace(fix, cov_u=cov4[:3, :3], sigma_rho_rad=float(np.sqrt(max(cov4[3, 3], 0.0))),
                   cov_u_rho=cov4, cov_r_cam_m2=cov_r, n_points=int(keep.sum()), extra=extra)
