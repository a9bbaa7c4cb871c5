"""Horizon estimators (Wu et al. ellipse fit, Christian–Robinson): exactness on ideal limb
points, analytic Jacobians vs central differences, covariance vs Monte Carlo scatter."""

import numpy as np
import pytest

from factors.constants import R_LIMB_UV_M
from factors.geometry import tangent_basis
from factors.testing import numerical_jacobian
from fgnav.errors import UserError
from fgnav.vision.camera import PinholeCamera
from fgnav.vision.horizon import (cr_jacobians, estimate_horizon, horizon_christian_robinson,
                                  horizon_ellipse)
from fgnav.vision.limb import LimbPoints, cone_point_gain

CAM = PinholeCamera(focal_mm=18.0, pixel_um=11.0, width_px=2048, height_px=2048)


def limb_points(c_cam_m, r_limb_m=R_LIMB_UV_M, n=400, arc=(0.0, 2 * np.pi), cam=CAM):
    """Exact limb points: rays on the cone of half-angle rho about c, projected; outward
    image normals from the projected cone (independent of the estimators)."""
    c = np.asarray(c_cam_m, float)
    u = c / np.linalg.norm(c)
    rho = np.arcsin(r_limb_m / np.linalg.norm(c))
    B = tangent_basis(u)
    t = np.linspace(*arc, n, endpoint=arc[1] - arc[0] < 2 * np.pi - 1e-9)
    rays = np.cos(rho) * u + np.sin(rho) * (np.cos(t)[:, None] * B[0] + np.sin(t)[:, None] * B[1])
    uv = cam.project(rays)
    out = cam.project(np.cos(rho + 1e-6) * u + np.sin(rho + 1e-6) * (np.cos(t)[:, None] * B[0] + np.sin(t)[:, None] * B[1]))
    nrm = out - uv
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return LimbPoints(uv, nrm, np.ones(n), np.ones(n, bool)), u, rho


C_OFFAXIS = np.array([0.35, -0.2, 1.0]) / np.linalg.norm([0.35, -0.2, 1.0]) * (R_LIMB_UV_M + 12_000e3)


@pytest.mark.parametrize("method", ["ellipse", "christian-robinson"])
def test_exact_on_ideal_limb(method):
    """Noise-free points on an off-axis limb (a true ellipse in the image): exact answer."""
    pts, u, rho = limb_points(C_OFFAXIS)
    fix = estimate_horizon(pts, CAM, method)
    # The angle from atan2(|a x b|, a.b): arccos of a dot product near 1 cannot resolve
    # angles below ~1.5e-8 rad (8.5e-7 deg) in double precision.
    angle_rad = np.arctan2(np.linalg.norm(np.cross(fix.u_cam, u)), fix.u_cam @ u)
    assert np.degrees(angle_rad) < 1e-7
    assert abs(fix.rho_rad - rho) < 1e-9
    assert fix.range_m == pytest.approx(np.linalg.norm(C_OFFAXIS), rel=1e-8)
    np.testing.assert_allclose(fix.r_cam_m, -C_OFFAXIS, rtol=0, atol=1e-2 * np.linalg.norm(C_OFFAXIS) * 1e-6)
    np.testing.assert_allclose(fix.centre_px, CAM.project(u), atol=1e-5)


def test_ellipse_sign_convention_and_geometry():
    """Wu et al.'s eqs. 3-8 on the virtual image plane: u_cam = [xe, ye, f]/norm points to the
    pixel where the Earth centre projects (OpenCV axes, no minus signs)."""
    pts, u, rho = limb_points(C_OFFAXIS)
    fix = horizon_ellipse(pts, CAM)
    xe, ye = fix.extra["xe_ye_px"]
    np.testing.assert_allclose([CAM.cx + xe, CAM.cy + ye], CAM.project(u), atol=1e-6)
    xc, yc, a, b, phi = fix.extra["ellipse"]
    # major axis points from the principal point towards the Earth centre image
    d = np.array([xe, ye]) / np.hypot(xe, ye)
    assert abs(abs(d @ [np.cos(phi), np.sin(phi)]) - 1.0) < 1e-9
    assert a > b
    # eta = off-boresight angle of the Earth centre
    assert fix.extra["eta_rad"] == pytest.approx(np.arccos(u[2]) * np.sign(fix.extra["eta_rad"]), abs=1e-9)


def test_christian_robinson_ellipsoid_shape_matrix():
    """With an oblate limb surface (A = U^T U), CR recovers the centre exactly."""
    a, c_ax = 6378e3, 6357e3
    Rot = np.array([[1, 0, 0], [0, np.cos(0.4), -np.sin(0.4)], [0, np.sin(0.4), np.cos(0.4)]])
    U = np.diag([1 / a, 1 / a, 1 / c_ax]) @ Rot.T
    c = C_OFFAXIS
    # exact horizon rays: in scaled space, unit-sphere cone about c' = U c
    cp = U @ c
    up = cp / np.linalg.norm(cp)
    rp = np.arcsin(1 / np.linalg.norm(cp))
    B = tangent_basis(up)
    t = np.linspace(0, 2 * np.pi, 300, endpoint=False)
    sp = np.cos(rp) * up + np.sin(rp) * (np.cos(t)[:, None] * B[0] + np.sin(t)[:, None] * B[1])
    s = sp @ np.linalg.inv(U).T
    uv = CAM.project(s)
    nrm = uv - CAM.project(c)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    pts = LimbPoints(uv, nrm, np.ones(300), np.ones(300, bool))
    fix = horizon_christian_robinson(pts, CAM, U=U)
    np.testing.assert_allclose(fix.r_cam_m, -c, rtol=1e-8)


def test_cr_jacobians_central_differences():
    n = np.array([0.4, -0.3, 1.9])
    U = np.diag([1 / 6.4e6, 1 / 6.4e6, 1 / 6.35e6]) @ np.array([[0.8, -0.6, 0], [0.6, 0.8, 0], [0, 0, 1.0]])
    jac = cr_jacobians(n, U)
    for key, dkey in (("c", "dc_dn"), ("u", "du_dn")):
        num = numerical_jacobian(lambda x: cr_jacobians(x, U)[key], n)
        np.testing.assert_allclose(jac[dkey], num, rtol=1e-6, atol=1e-9 * np.abs(num).max())
    num = numerical_jacobian(lambda x: np.array([cr_jacobians(x, U)["rho"]]), n)[0]
    np.testing.assert_allclose(jac["drho_dn"], num, rtol=1e-6)


def test_cone_point_gain_central_differences():
    pts, u, rho = limb_points(C_OFFAXIS, n=20)
    n_vec = u / np.cos(rho)          # the true cone vector: s^T n = 1 on the limb
    s = CAM.pixel_to_ray(pts.uv_px)
    g = cone_point_gain(s, 1.0 / s[:, 2], pts.normal, n_vec, CAM.f_px)
    h = 1e-4
    sp = CAM.pixel_to_ray(pts.uv_px + h * pts.normal)
    sm = CAM.pixel_to_ray(pts.uv_px - h * pts.normal)
    np.testing.assert_allclose(g, (sp @ n_vec - sm @ n_vec) / (2 * h), rtol=1e-6)
    # on the limb the residual is zero
    np.testing.assert_allclose(s @ n_vec, 1.0, atol=1e-12)


def test_ellipse_point_sensitivity_central_differences():
    """d(u, rho)/dt_i (normal motion of limb point i): analytic LS sensitivity chained with
    the conic -> (u, rho) map, against central differences of the whole ellipse pipeline."""
    pts, u, rho = limb_points(C_OFFAXIS, n=40, arc=(0.3, 4.0))
    J = horizon_ellipse(pts, CAM).extra["d_urho_dt"]
    h = 1e-4

    def urho(uv):
        f = horizon_ellipse(LimbPoints(uv, pts.normal, pts.contrast, pts.inlier), CAM)
        return np.r_[f.u_cam, f.rho_rad]
    for i in (0, 7, 39):
        dp = np.zeros_like(pts.uv_px)
        dp[i] = h * pts.normal[i]
        num = (urho(pts.uv_px + dp) - urho(pts.uv_px - dp)) / (2 * h)
        np.testing.assert_allclose(J[:, i], num, rtol=1e-4, atol=1e-6 * np.abs(J).max())


@pytest.mark.parametrize("method,arc", [("ellipse", (0.0, 2 * np.pi)), ("christian-robinson", (0.0, 2 * np.pi)),
                                        ("ellipse", (0.2, 0.2 + 4.2)), ("christian-robinson", (0.2, 0.2 + 2.1))])
def test_covariance_matches_monte_carlo(method, arc):
    """Normalized direction / rho errors over 300 noisy point sets have unit variance (±20%)."""
    rng = np.random.default_rng(11)
    pts0, u, rho = limb_points(C_OFFAXIS, n=150, arc=arc)
    B = tangent_basis(u)
    zu, zr = [], []
    for _ in range(300):
        uv = pts0.uv_px + (0.5 * rng.standard_normal(150))[:, None] * pts0.normal
        fix = estimate_horizon(LimbPoints(uv, pts0.normal, pts0.contrast, pts0.inlier), CAM, method)
        L = np.linalg.cholesky(B @ fix.cov_u @ B.T)
        zu.append(np.linalg.solve(L, B @ fix.u_cam))
        zr.append((fix.rho_rad - rho) / fix.sigma_rho_rad)
    assert 0.8 < np.mean(np.square(zu)) < 1.2
    assert 0.8 < np.mean(np.square(zr)) < 1.2


def test_cr_no_worse_than_ellipse_on_short_arc():
    rng = np.random.default_rng(5)
    pts0, u, rho = limb_points(C_OFFAXIS, n=120, arc=(0.0, 2 * np.pi / 3))
    err = {"ellipse": [], "christian-robinson": []}
    for _ in range(100):
        uv = pts0.uv_px + (0.5 * rng.standard_normal(120))[:, None] * pts0.normal
        p = LimbPoints(uv, pts0.normal, pts0.contrast, pts0.inlier)
        for m in err:
            err[m].append(np.arccos(min(1.0, estimate_horizon(p, CAM, m).u_cam @ u)))
    assert np.sqrt(np.mean(np.square(err["christian-robinson"]))) < np.sqrt(np.mean(np.square(err["ellipse"])))


def test_user_errors():
    pts, _, _ = limb_points(C_OFFAXIS, n=5)
    for m in ("ellipse", "christian-robinson"):
        with pytest.raises(UserError):
            estimate_horizon(pts, CAM, m)
    pts, _, _ = limb_points(C_OFFAXIS, n=50)
    with pytest.raises(UserError, match="unknown horizon method"):
        estimate_horizon(pts, CAM, "hough")
