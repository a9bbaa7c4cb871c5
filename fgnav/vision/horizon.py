"""Horizon-based fixes from limb points: Wu et al.'s ellipse fit and Christian–Robinson.

Both return a :class:`HorizonFix` in the camera frame (OpenCV: x right, y down, z along
the boresight): unit vector to the Earth's centre ``u_cam``, apparent angular radius
``rho_rad`` of the limb sphere, range ``|c| = R / sin(rho)``, the spacecraft position
relative to the Earth's centre ``r_cam_m = -range * u_cam`` (Wu et al. eq. 12 in the camera
frame), and first-order covariances scaled by the a-posteriori point scatter.

(a) Ellipse fit (Wu et al., eqs. 1-8). Least squares on the conic
``P1 x^2 + P2 xy + P3 y^2 + P4 x + P5 y + P6 = 0`` with the Euclidean-invariant
normalization ``P1 + P3 = 1`` (Gander, Golub & Strebel 1994) on centred, scaled points ->
centre (xc, yc), semi-axes a >= b, major-axis angle phi; ``[xm; ym] = T(phi) [xc; yc]``
(eq. 3); ``rho = (atan((a + xm)/f) + atan((a - xm)/f)) / 2``,
``eta = (atan((a + xm)/f) - atan((a - xm)/f)) / 2`` (eq. 4); Earth centre ``(f tan eta, ym)``
(eq. 5) rotated back to ``(xe, ye)`` (eq. 7).
Sign convention: Wu et al. write ``u_s = [-xe, -ye, f] / sqrt(xe^2 + ye^2 + f^2)`` (eq. 8)
because its (xe, ye) are coordinates on the physical detector, where the real image is
inverted. We work on the virtual (non-inverted) image plane in OpenCV axes,
``(x, y) = f_px * (X/Z, Y/Z)`` of the undistorted ray, so the same direction is
``u_cam = [xe, ye, f] / sqrt(xe^2 + ye^2 + f^2)`` with no minus signs.
Covariance: exact first-order propagation of the per-point normal displacement through
the linear least-squares conic fit (``dq = -(A^T A)^-1 A^T diag(gamma) dt``), then through
the closed-form conic -> (u, rho) map (its 5x4 Jacobian by central differences).

(b) Christian–Robinson (J. A. Christian & S. B. Robinson, "Noniterative horizon-based
optical navigation by Cholesky factorization", JGCD 39(12), 2016; Christian, "A tutorial
on horizon-based optical navigation...", IEEE Access 9, 2021, eqs. 95-119). The limb
surface is ``(x - c)^T A (x - c) = 1`` with ``A = U^T U`` (sphere: ``U = I / R``). Rays
``s_i`` map to ``s'_i = U s_i / |U s_i|`` where the body is the unit sphere; every horizon
ray of the unit sphere satisfies ``s'_i^T n = 1`` with ``n = c' / sqrt(c'^T c' - 1)``,
``c' = U c``. ``n`` by (weighted) least squares, then
``c = U^-1 n / sqrt(n^T n - 1)`` (camera -> centre), ``cos(rho) = 1 / |n|``.
Covariance: ``P_n = sigma^2 (H^T G^-2 H)^-1`` with ``g_i = ds'_i^T n / dt_i`` the residual
per pixel of normal motion of point i, ``sigma`` the a-posteriori normal scatter (px);
propagated with the analytic Jacobians of u, rho, r with respect to n.

Edge-curvature correction (``estimate_horizon(..., psf_sigma_px=...)``): the sub-pixel
edge locator sits inside the true limb by ``(psf_sigma_px^2 + 0.917) / (2 R_px)`` px
(:mod:`fgnav.vision.limb`, step 2), which biases the Christian–Robinson rho low (range
long); with the PSF known, :func:`correct_edge_curvature` moves the points outward by that
amount and refits. Not applied to the ellipse fit (its own outward bias cancels it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from factors.constants import R_LIMB_UV_M
from factors.geometry import tangent_basis
from fgnav.errors import UserError
from fgnav.vision.camera import PinholeCamera
from fgnav.vision.limb import LimbPoints, edge_curvature_bias_px

__all__ = [
    "HorizonFix", "fit_conic", "conic_to_ellipse", "ellipse_to_direction",
    "horizon_ellipse", "horizon_christian_robinson", "cr_jacobians", "estimate_horizon",
    "correct_edge_curvature", "cr_point_gains", "cr_residuals_px", "METHODS",
]

METHODS = ("ellipse", "christian-robinson")


@dataclass
class HorizonFix:
    """A horizon fix in the camera frame (SI units).

    u_cam (3,) unit vector camera -> Earth centre; rho_rad apparent angular radius;
    range_m = R / sin(rho); cov_u (3, 3) covariance of u_cam (rank 2, tangent to the unit
    sphere); sigma_rho_rad; r_cam_m (3,) spacecraft position relative to the Earth's centre
    in the camera frame (= -range_m * u_cam); cov_r_cam_m2 (3, 3); cov_u_rho (4, 4) joint
    covariance of (u_cam, rho); sigma_px a-posteriori normal scatter of the limb points
    (px); n_points used; centre_px projected Earth centre (u, v); method.
    """

    u_cam: np.ndarray
    rho_rad: float
    range_m: float
    cov_u: np.ndarray
    sigma_rho_rad: float
    r_cam_m: np.ndarray
    cov_r_cam_m2: np.ndarray
    cov_u_rho: np.ndarray
    sigma_px: float
    n_points: int
    centre_px: np.ndarray
    method: str
    extra: dict = field(default_factory=dict)

    @property
    def cov_tangent_rad2(self) -> np.ndarray:
        """2x2 covariance of u_cam on ``factors.geometry.tangent_basis(u_cam)`` (rad^2)."""
        B = tangent_basis(self.u_cam)
        return B @ self.cov_u @ B.T

    def to_dict(self) -> dict:
        """JSON-ready dict (SI units; see ``fgnav limb --help`` for the keys)."""
        return {
            "method": self.method,
            "u_cam": self.u_cam.tolist(),
            "rho_rad": float(self.rho_rad),
            "range_m": float(self.range_m),
            "cov_u": self.cov_u.tolist(),
            "cov_tangent_rad2": self.cov_tangent_rad2.tolist(),
            "sigma_rho_rad": float(self.sigma_rho_rad),
            "cov_u_rho": self.cov_u_rho.tolist(),
            "r_cam_m": self.r_cam_m.tolist(),
            "cov_r_cam_m2": self.cov_r_cam_m2.tolist(),
            "centre_px": self.centre_px.tolist(),
            "sigma_px": float(self.sigma_px),
            "n_points": int(self.n_points),
        }


def _focal_plane(camera: PinholeCamera, uv: np.ndarray):
    """Undistorted virtual-image-plane coordinates (px, OpenCV axes) and rays."""
    s = camera.pixel_to_ray(uv)
    xy = camera.f_px * s[:, :2] / s[:, 2:3]
    return xy, s


def _position_from_u_rho(u, rho, R):
    """range, r_cam = -R/sin(rho) u and d r / d(u, rho) (3x4)."""
    rng = R / np.sin(rho)
    r = -rng * u
    J = np.zeros((3, 4))
    J[:, :3] = -rng * np.eye(3)
    J[:, 3] = R * np.cos(rho) / np.sin(rho) ** 2 * u
    return rng, r, J


# ----------------------------------------------------------------------------- ellipse
def fit_conic(xy: np.ndarray):
    """Least-squares conic through points (N, 2) with ``P1 + P3 = 1`` (centred, scaled).

    Returns (P (6,) in the input coordinates, aux) where aux holds the normalized design
    (A, gamma-ready gradient function) needed by the covariance.
    """
    xy = np.asarray(xy, float)
    if xy.shape[0] < 6:
        raise UserError(f"ellipse fit needs >= 6 points, got {xy.shape[0]}")
    m = xy.mean(axis=0)
    sc = np.sqrt(np.mean(np.sum((xy - m) ** 2, axis=1)))
    if not sc > 0:
        raise UserError("ellipse fit: all limb points coincide")
    x, y = ((xy - m) / sc).T
    A = np.column_stack([x * x - y * y, x * y, x, y, np.ones_like(x)])
    b = -y * y
    q, *_ = np.linalg.lstsq(A, b, rcond=None)
    Pn = np.array([q[0], q[1], 1.0 - q[0], q[2], q[3], q[4]])
    P = _denormalize_conic(Pn, m, sc)
    return P, {"A": A, "q": q, "x": x, "y": y, "m": m, "sc": sc, "Pn": Pn}


def _conic_matrix(P):
    a, b, c, d, e, f = P
    return np.array([[a, b / 2, d / 2], [b / 2, c, e / 2], [d / 2, e / 2, f]])


def _denormalize_conic(Pn, m, sc):
    T = np.array([[1 / sc, 0, -m[0] / sc], [0, 1 / sc, -m[1] / sc], [0, 0, 1.0]])
    C = T.T @ _conic_matrix(Pn) @ T
    return np.array([C[0, 0], 2 * C[0, 1], C[1, 1], 2 * C[0, 2], 2 * C[1, 2], C[2, 2]])


def conic_to_ellipse(P):
    """Conic coefficients -> (xc, yc, a, b, phi): centre, semi-axes a >= b, major-axis angle.

    Raises UserError when the conic is not a real ellipse.
    """
    C = _conic_matrix(np.asarray(P, float))
    M2 = C[:2, :2]
    try:
        ctr = np.linalg.solve(M2, -C[:2, 2])
    except np.linalg.LinAlgError as exc:
        raise UserError("ellipse fit: degenerate conic (parabola)") from exc
    F0 = C[2, 2] + C[:2, 2] @ ctr
    lam, vec = np.linalg.eigh(M2)
    if not (lam[0] * lam[1] > 0 and -F0 / lam[0] > 0):
        raise UserError("ellipse fit: the limb points fit a hyperbola, not an ellipse (arc too short or too noisy)")
    ax = np.sqrt(-F0 / lam)                       # semi-axis along each eigenvector
    i = int(np.argmax(ax))
    phi = float(np.arctan2(vec[1, i], vec[0, i]))
    return float(ctr[0]), float(ctr[1]), float(ax[i]), float(ax[1 - i]), phi


def ellipse_to_direction(xc, yc, a, phi, f):
    """Wu et al. eqs. 3-8 on the virtual image plane: (u_cam (3,), rho, eta, (xe, ye))."""
    cp, sp = np.cos(phi), np.sin(phi)
    xm = cp * xc + sp * yc                          # eq. 3
    ym = -sp * xc + cp * yc
    t1, t2 = np.arctan((a + xm) / f), np.arctan((a - xm) / f)
    rho = 0.5 * (t1 + t2)                           # eq. 4
    eta = 0.5 * (t1 - t2)
    xo, yo = f * np.tan(eta), ym                    # eq. 5
    xe = cp * xo - sp * yo                          # eqs. 6-7
    ye = sp * xo + cp * yo
    v = np.array([xe, ye, f])
    return v / np.linalg.norm(v), float(rho), float(eta), (float(xe), float(ye))


def _q_to_u_rho(q, m, sc, f):
    Pn = np.array([q[0], q[1], 1.0 - q[0], q[2], q[3], q[4]])
    xc, yc, a, b, phi = conic_to_ellipse(_denormalize_conic(Pn, m, sc))
    u, rho, _, _ = ellipse_to_direction(xc, yc, a, phi, f)
    return np.concatenate([u, [rho]])


def conic_point_sensitivity(aux, normals_xy):
    """d q / d t_i (5, N): the conic parameters per pixel of normal motion of each point.

    Linear LS ``q = (A^T A)^-1 A^T b``; moving point i by ``t_i`` along its unit normal
    ``m_i`` changes its residual by ``gamma_i t_i``, ``gamma_i = grad Q(p_i) . m_i / sc``
    (Q the normalized conic), hence ``dq = -(A^T A)^-1 A^T diag(gamma) dt``.
    """
    A, q, x, y, sc = aux["A"], aux["q"], aux["x"], aux["y"], aux["sc"]
    Pn = aux["Pn"]
    gx = 2 * Pn[0] * x + Pn[1] * y + Pn[3]
    gy = Pn[1] * x + 2 * Pn[2] * y + Pn[4]
    gamma = (gx * normals_xy[:, 0] + gy * normals_xy[:, 1]) / sc
    AtA_inv_At = np.linalg.solve(A.T @ A, A.T)
    return -AtA_inv_At * gamma[None, :], gamma, np.hypot(gx, gy) / sc


def horizon_ellipse(points: LimbPoints, camera: PinholeCamera, r_limb_m: float = R_LIMB_UV_M) -> HorizonFix:
    """Wu et al.'s ellipse-fit horizon fix from (inlier) limb points (see module doc)."""
    pts = points.inliers() if not np.all(points.inlier) else points
    xy, _ = _focal_plane(camera, pts.uv_px)
    f = camera.f_px
    P, aux = fit_conic(xy)
    xc, yc, a, b, phi = conic_to_ellipse(P)
    u, rho, eta, (xe, ye) = ellipse_to_direction(xc, yc, a, phi, f)
    N = xy.shape[0]
    dq_dt, gamma, gradn = conic_point_sensitivity(aux, pts.normal)
    resid = aux["A"] @ aux["q"] + aux["y"] ** 2          # algebraic residual (normalized)
    geo = resid / gradn                                    # geometric distance (px)
    sigma_px = float(np.sqrt(np.sum(geo ** 2) / max(N - 5, 1)))
    cov_q = sigma_px ** 2 * dq_dt @ dq_dt.T
    # Jacobian of (u, rho) w.r.t. q by central differences of the closed form
    q0, m, sc = aux["q"], aux["m"], aux["sc"]
    J = np.zeros((4, 5))
    for k in range(5):
        h = 1e-7 * max(1.0, abs(q0[k]))
        dq = np.zeros(5)
        dq[k] = h
        J[:, k] = (_q_to_u_rho(q0 + dq, m, sc, f) - _q_to_u_rho(q0 - dq, m, sc, f)) / (2 * h)
    cov4 = J @ cov_q @ J.T
    rng_m, r, Jr = _position_from_u_rho(u, rho, r_limb_m)
    centre = camera.project(u)
    return HorizonFix(u, rho, float(rng_m), cov4[:3, :3], float(np.sqrt(max(cov4[3, 3], 0.0))),
                      r, Jr @ cov4 @ Jr.T, cov4, sigma_px, N, centre, "ellipse",
                      {"conic": P, "ellipse": (xc, yc, a, b, phi), "eta_rad": eta, "xe_ye_px": (xe, ye),
                       "d_urho_dt": J @ dq_dt})


# ----------------------------------------------------------------- Christian-Robinson
def cr_jacobians(n_vec: np.ndarray, U: np.ndarray):
    """Analytic maps of the CR vector n and their Jacobians (module doc, eqs. 117-119).

    Returns dict: c (camera -> centre, m), dc_dn (3x3); u = c/|c|, du_dn (3x3);
    rho = acos(1/|n|), drho_dn (3,).
    """
    n = np.asarray(n_vec, float)
    nn = n @ n
    k = (nn - 1.0) ** -0.5
    Ui = np.linalg.inv(U)
    c = k * (Ui @ n)
    dk = -(nn - 1.0) ** -1.5 * n                          # d k / d n
    dc = k * Ui + np.outer(Ui @ n, dk)
    cn = np.linalg.norm(c)
    u = c / cn
    du = (np.eye(3) - np.outer(u, u)) / cn @ dc
    nm = np.sqrt(nn)
    rho = float(np.arccos(1.0 / nm))
    drho = n / (nm * nm * np.sqrt(nn - 1.0))              # d acos(1/m)/dm * dm/dn
    return {"c": c, "dc_dn": dc, "u": u, "du_dn": du, "rho": rho, "drho_dn": drho}


def horizon_christian_robinson(points: LimbPoints, camera: PinholeCamera,
                               r_limb_m: float = R_LIMB_UV_M, U: np.ndarray | None = None,
                               reweight: bool = True) -> HorizonFix:
    """Christian–Robinson horizon fix (module doc).

    U : optional 3x3 with ``A_cam = U^T U`` for an ellipsoidal limb surface in the camera
    frame (needs the attitude); default the sphere ``I / r_limb_m``.
    """
    pts = points.inliers() if not np.all(points.inlier) else points
    N = len(pts)
    if N < 6:
        raise UserError(f"Christian-Robinson needs >= 6 limb points, got {N}")
    U = np.eye(3) / r_limb_m if U is None else np.asarray(U, float)
    s = camera.pixel_to_ray(pts.uv_px)
    vn = 1.0 / s[:, 2]
    Us = s @ U.T
    Usn = np.linalg.norm(Us, axis=1)
    sp = Us / Usn[:, None]                                 # s'_i
    n, *_ = np.linalg.lstsq(sp, np.ones(N), rcond=None)
    if not n @ n > 1.0:
        raise UserError("Christian-Robinson: |n| <= 1 (limb points inconsistent with a body in view)")

    def gains(nv):
        # d(s'^T n)/dt = n^T (I - s's'^T) U ds/dt / |U s|
        ds = _ray_derivative(s, vn, pts.normal, camera.f_px)  # (N, 3) ds/dt
        Uds = ds @ U.T
        proj = Uds - sp * np.sum(sp * Uds, axis=1, keepdims=True)
        return (proj @ nv) / Usn

    g = gains(n)
    if reweight:
        w = 1.0 / g ** 2
        Hw = sp * w[:, None]
        n = np.linalg.solve(sp.T @ Hw, Hw.T @ np.ones(N))
        if not n @ n > 1.0:
            raise UserError("Christian-Robinson: |n| <= 1 after reweighting")
        g = gains(n)
    res_px = (sp @ n - 1.0) / g                            # normal residual, px
    sigma_px = float(np.sqrt(np.sum(res_px ** 2) / max(N - 3, 1)))
    Pn = sigma_px ** 2 * np.linalg.inv(sp.T @ (sp / g[:, None] ** 2))
    jac = cr_jacobians(n, U)
    c, u, rho = jac["c"], jac["u"], jac["rho"]
    Ju = np.vstack([jac["du_dn"], jac["drho_dn"][None, :]])  # (4, 3)
    cov4 = Ju @ Pn @ Ju.T
    r = -c
    cov_r = jac["dc_dn"] @ Pn @ jac["dc_dn"].T
    centre = camera.project(u)
    return HorizonFix(u, rho, float(np.linalg.norm(c)), cov4[:3, :3],
                      float(np.sqrt(max(cov4[3, 3], 0.0))), r, cov_r, cov4, sigma_px, N, centre,
                      "christian-robinson", {"n": n, "cov_n": Pn})


def _transformed_rays(points: LimbPoints, camera: PinholeCamera, U: np.ndarray):
    s = camera.pixel_to_ray(points.uv_px)
    Us = s @ U.T
    Usn = np.linalg.norm(Us, axis=1)
    return s, Us / Usn[:, None], Usn


def cr_point_gains(points: LimbPoints, camera: PinholeCamera, n_vec: np.ndarray, U: np.ndarray) -> np.ndarray:
    """``g_i = d(s'_i^T n)/dt_i`` (N,): the Christian–Robinson residual per pixel of motion of
    each limb point along its normal, ``n^T (I - s' s'^T) U ds/dt / |U s|`` (module doc)."""
    s, sp, Usn = _transformed_rays(points, camera, np.asarray(U, float))
    ds = _ray_derivative(s, 1.0 / s[:, 2], points.normal, camera.f_px)
    Uds = ds @ np.asarray(U, float).T
    proj = Uds - sp * np.sum(sp * Uds, axis=1, keepdims=True)
    return (proj @ np.asarray(n_vec, float)) / Usn


def cr_residuals_px(points: LimbPoints, camera: PinholeCamera, n_vec: np.ndarray, U: np.ndarray) -> np.ndarray:
    """Normal residuals (px, > 0 outside the fitted limb) of limb points against the cone
    ``s'^T n = 1`` of shape matrix ``U``: ``(s'_i^T n - 1) / g_i`` (:func:`cr_point_gains`)."""
    _, sp, _ = _transformed_rays(points, camera, np.asarray(U, float))
    return (sp @ np.asarray(n_vec, float) - 1.0) / cr_point_gains(points, camera, n_vec, U)


def _ray_derivative(s, vnorm, normal_uv, f_px):
    """ds/dt (N, 3) for unit rays s under a 1-px move of the pixel along ``normal_uv``."""
    dv = np.concatenate([normal_uv / f_px, np.zeros((normal_uv.shape[0], 1))], axis=1)
    return (dv - s * np.sum(s * dv, axis=1, keepdims=True)) / vnorm[:, None]


def estimate_horizon(points: LimbPoints, camera: PinholeCamera, method: str = "christian-robinson",
                     r_limb_m: float = R_LIMB_UV_M, *, psf_sigma_px: float | None = None) -> HorizonFix:
    """Dispatch on ``method`` (one of :data:`METHODS`).

    psf_sigma_px : optics PSF sigma (px) of the frame, or None (no correction). When given
    and ``method == "christian-robinson"``, the edge-curvature bias of the limb edge locator
    is removed (:func:`correct_edge_curvature`). The ``ellipse`` method is never corrected:
    its algebraic conic fit has an outward bias of about the same size that already cancels
    the locator's (GEO image pass, seed 3: mean rho error -0.06 sigma uncorrected, +0.89
    corrected).
    """
    if psf_sigma_px is not None and not psf_sigma_px >= 0:
        raise UserError(f"psf_sigma_px must be >= 0 px, got {psf_sigma_px}")
    if method == "ellipse":
        return horizon_ellipse(points, camera, r_limb_m)
    if method == "christian-robinson":
        fix = horizon_christian_robinson(points, camera, r_limb_m)
        if psf_sigma_px is not None:
            fix = correct_edge_curvature(points, camera, fix, psf_sigma_px, r_limb_m)
        return fix
    raise UserError(f"unknown horizon method {method!r}; expected one of {', '.join(METHODS)}")


def correct_edge_curvature(points: LimbPoints, camera: PinholeCamera, fix: HorizonFix,
                           psf_sigma_px: float, r_limb_m: float = R_LIMB_UV_M) -> HorizonFix:
    """Christian–Robinson refit with the limb points moved outward by the edge locator's
    curvature bias :func:`fgnav.vision.limb.edge_curvature_bias_px` (``(psf_sigma_px^2 +
    0.917) / (2 R_px)`` px), ``R_px = f_px tan(rho)`` the image limb radius of the first
    ``fix`` (exact for a limb centred on the boresight; off-axis the image ellipse's local
    curvature differs by O(tan^2) of the offset angle, a second-order change of a
    ~1e-3 px correction). The shift is recorded in ``extra["curvature_correction_px"]``.
    Christian–Robinson only (see :func:`estimate_horizon`).
    """
    if fix.method != "christian-robinson":
        raise UserError(f"the edge-curvature correction applies to christian-robinson fixes only, got {fix.method!r}")
    r_px = camera.f_px * math.tan(fix.rho_rad)
    d_px = edge_curvature_bias_px(r_px, psf_sigma_px)
    out = horizon_christian_robinson(points.shifted(d_px), camera, r_limb_m)
    out.extra["curvature_correction_px"] = d_px
    return out
