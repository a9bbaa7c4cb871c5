"""The real-limb model (fgnav/vision/real_limb.py) on synthetic limbs whose truth is known:
the flattening at a given attitude, the lit limb, the correlation inflation, the limb-height
and floor terms, and ``fgnav limb`` reading colour images (--channel, --fov-deg)."""

import json

import numpy as np
import pytest

from factors.geometry import tangent_basis
from fgnav.cli import main
from fgnav.errors import UserError
from fgnav.simulate.limb_render import LimbRadiance, LimbScene, render_limb, render_limb_ideal
from fgnav.vision.camera import PinholeCamera
from fgnav.vision.limb import LimbPoints, extract_limb_points, ransac_limb
from fgnav.vision.horizon import horizon_christian_robinson
from fgnav.vision.real_limb import (LimbModel, north_up_R_eci_from_cam, real_limb_fix,
                                    residual_variance_inflation, tangent_sun_cosine)
from fgnav.vision.sensor import CONFOCAL_SUBAPERTURE_CAMERA

CAM = CONFOCAL_SUBAPERTURE_CAMERA
NARROW = PinholeCamera.from_fov(8.0, 600, 600)


def _exact_points(cam, c, U, n=360):
    """Exact horizon points of the limb surface ``U`` seen from the camera, centre ``c``."""
    cp = U @ c
    up = cp / np.linalg.norm(cp)
    rp = np.arcsin(1 / np.linalg.norm(cp))
    B = tangent_basis(up)
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    sp = np.cos(rp) * up + np.sin(rp) * (np.cos(t)[:, None] * B[0] + np.sin(t)[:, None] * B[1])
    uv = cam.project(sp @ np.linalg.inv(U).T)
    nrm = uv - cam.project(c)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return LimbPoints(uv, nrm, np.ones(n), np.ones(n, bool))


def test_flattening_at_the_attitude_recovers_the_range():
    """WGS-84 limb, pole tilted 0.7 rad towards the camera: the model given the attitude
    (R_eci_from_cam = R_cam_from_ecef^T) finds the centre to < 3 km at 26,000 km; the sphere
    of the equatorial radius is off by more than ten times that."""
    th = 0.7
    Rc = np.array([[1, 0, 0], [0, np.cos(th), -np.sin(th)], [0, np.sin(th), np.cos(th)]])
    scene = LimbScene(c_cam_m=np.array([0.0, 0.0, 26_000e3]), ellipsoid=True, limb_height_m=0.0,
                      R_cam_from_ecef=Rc)
    frame = render_limb_ideal(CAM, scene, radiance=LimbRadiance(signal_e=5000.0, scale_height_m=1e3))
    pts = extract_limb_points(frame.ideal_e)
    fix = real_limb_fix(pts, CAM, LimbModel(r_limb_m=scene.axes_m[0], R_eci_from_cam=Rc.T))
    err = np.linalg.norm(fix.r_cam_m + scene.c_cam_m)
    assert err < 3e3
    sph = real_limb_fix(pts, CAM, LimbModel(r_limb_m=scene.axes_m[0], correlated=True))
    assert np.linalg.norm(sph.r_cam_m + scene.c_cam_m) > 10 * err


def test_tangent_point_sun_at_full_phase_is_rho_high():
    """Sun behind the camera (full phase): every tangent point sees it sin(rho) above its
    horizon (the normal there makes 90 deg + rho with the line of sight)."""
    c = np.array([0.02, -0.01, 1.0]) * 40_000e3
    U = np.eye(3) / 6378e3
    pts = _exact_points(NARROW, c, U)
    u = c / np.linalg.norm(c)
    cz = tangent_sun_cosine(pts, NARROW, c, U, -u)
    np.testing.assert_allclose(cz, 6378e3 / np.linalg.norm(c), rtol=1e-6)


def test_lit_limb_drops_the_terminator():
    """Half the limb moved 3 px inward where its tangent point is dark (a terminator seen
    near full phase): with the Sun given those points are dropped and the fix is exact;
    without it the range is biased."""
    c = np.array([0.01, 0.02, 1.0]) * 40_000e3
    R = np.eye(3)
    model_sun = LimbModel(r_limb_m=6378e3, R_eci_from_cam=R, flattening=0.0,
                          sun_eci=np.array([0.3, 0.1, -1.0]))
    U = model_sun.shape_matrix()
    pts = _exact_points(NARROW, c, U)
    dark = tangent_sun_cosine(pts, NARROW, c, U, model_sun.sun_cam()) <= 0
    assert 0.25 < dark.mean() < 0.5          # the tangent points sit rho (9 deg) sunward of the limb circle
    moved = pts.shifted(np.where(dark, -3.0, 0.0))
    fix = real_limb_fix(moved, NARROW, model_sun)
    np.testing.assert_allclose(fix.r_cam_m, -c, rtol=1e-7)
    assert fix.extra["n_unlit"] == int(dark.sum())
    blind = real_limb_fix(moved, NARROW, LimbModel(r_limb_m=6378e3, R_eci_from_cam=R, flattening=0.0,
                                                   min_threshold_px=5.0))
    assert abs(np.linalg.norm(blind.r_cam_m) / np.linalg.norm(c) - 1) > 1e-3


def test_variance_inflation_of_white_and_ar1_residuals():
    """White residuals: k ~ 1; AR(1) with phi = 0.6: k ~ (1 + phi) / (1 - phi) = 4."""
    rng = np.random.default_rng(3)
    order = np.arange(4000)
    assert 0.85 < residual_variance_inflation(rng.normal(size=4000), order) < 1.2
    e = rng.normal(size=4000)
    x = np.zeros(4000)
    for i in range(1, 4000):
        x[i] = 0.6 * x[i - 1] + e[i]
    assert residual_variance_inflation(x, order) == pytest.approx(4.0, rel=0.2)
    shuffled = rng.permutation(4000)
    assert residual_variance_inflation(x, shuffled) < 1.3     # the order along the limb matters


def test_floor_and_limb_height_terms_enter_rho():
    """Noise-free points: the floor alone gives sigma_rho = floor cos^2(rho) / f_px (a common
    radial shift of the centred limb), the limb height alone sigma_h cos^2(rho) / range."""
    c = np.array([0.0, 0.0, 40_000e3])
    U = np.eye(3) / 6378e3
    pts = _exact_points(NARROW, c, U)
    rho = np.arcsin(6378e3 / 40_000e3)
    f = real_limb_fix(pts, NARROW, LimbModel(r_limb_m=6378e3, floor_px=0.2))
    assert f.sigma_rho_rad == pytest.approx(0.2 * np.cos(rho) ** 2 / NARROW.f_px, rel=1e-3)
    h = real_limb_fix(pts, NARROW, LimbModel(r_limb_m=6378e3, limb_height_sigma_m=5e3))
    assert h.sigma_rho_rad == pytest.approx(5e3 * np.cos(rho) ** 2 / np.linalg.norm(c), rel=1e-3)
    # the floor also moves the centre: 0.2 px per axis at the limb, 0.2 cos^2(rho) / f_px rad
    assert np.sqrt(np.trace(f.cov_u) / 2) == pytest.approx(0.2 * np.cos(rho) ** 2 / NARROW.f_px, rel=0.01)


def test_correlated_render_noise_is_covered():
    """A noisy render: the inflated sigma is >= the pixel-noise sigma and the fix agrees with
    the plain Christian-Robinson one (same points, same sphere)."""
    scene = LimbScene(c_cam_m=np.array([0.0, 0.0, 26_000e3]), r_limb_m=6378e3)
    frame = render_limb(CAM, scene, np.random.default_rng(2), radiance=LimbRadiance(signal_e=800.0))
    pts = extract_limb_points(frame.image_dn)
    fix = real_limb_fix(pts, CAM, LimbModel(r_limb_m=6378e3, correlated=True))
    plain = horizon_christian_robinson(ransac_limb(pts, CAM), CAM, 6378e3)
    assert fix.extra["variance_inflation"] >= 1.0
    assert fix.sigma_rho_rad >= fix.extra["sigma_rho_pixel_rad"]
    assert abs(fix.rho_rad - plain.rho_rad) < 3 * plain.sigma_rho_rad


def test_limb_model_refuses_bad_input():
    with pytest.raises(UserError, match="attitude"):
        LimbModel(sun_eci=np.array([1.0, 0, 0]))
    with pytest.raises(UserError, match="rotation"):
        LimbModel(R_eci_from_cam=np.ones((3, 3)))
    with pytest.raises(UserError, match="flattening"):
        LimbModel(flattening=1.5)
    with pytest.raises(UserError, match="pole"):
        north_up_R_eci_from_cam(np.array([0.0, 0.0, -1.0]))


def test_north_up_attitude():
    """Boresight along the direction given, image up towards the pole, east to the right."""
    u = np.array([-0.15, 0.86, 0.48])
    R = north_up_R_eci_from_cam(u)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R[:, 2], u / np.linalg.norm(u))
    assert (-R[:, 1]) @ [0, 0, 1] > 0 and abs(R[:, 0] @ [0, 0, 1]) < 1e-12
    east = np.cross([0, 0, 1.0], -u)                     # east at the sub-camera point
    assert R[:, 0] @ east > 0


def _colour_render(tmp_path, channel_index):
    import cv2

    scene = LimbScene(c_cam_m=np.array([0.0, 0.0, 26_000e3]), r_limb_m=6378e3)
    frame = render_limb(CAM, scene, np.random.default_rng(9), radiance=LimbRadiance(signal_e=800.0))
    one = np.clip(frame.image_dn.astype(float) / max(frame.image_dn.max(), 1) * 250, 0, 255).astype(np.uint8)
    img = np.zeros(one.shape + (3,), np.uint8)
    img[:, :, channel_index] = one
    path = tmp_path / "colour.png"
    assert cv2.imwrite(str(path), img)
    return path, scene


def test_cli_limb_reads_the_red_channel_of_a_colour_image(tmp_path, capsys):
    """The limb drawn in the red channel only (OpenCV index 2): the default channel finds it,
    --channel blue sees a black frame and is refused with exit 2."""
    path, scene = _colour_render(tmp_path, 2)
    argv = ["limb", str(path), "--focal-mm", "18", "--pixel-um", "11", "--r-limb-km", "6378", "--json"]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["channel"] == "red"
    assert abs(out["rho_rad"] - scene.rho_rad) < 1e-4
    assert main(argv + ["--channel", "gray"]) == 0
    assert json.loads(capsys.readouterr().out)["channel"] == "gray"
    assert main(argv + ["--channel", "blue"]) == 2
    assert "error" in capsys.readouterr().err


def test_cli_limb_fov_and_real_limb_options(tmp_path, capsys):
    path, scene = _colour_render(tmp_path, 2)
    fov = float(np.degrees(CAM.fov_x_rad))
    base = ["limb", str(path), "--r-limb-km", "6378", "--json"]
    assert main(base + ["--fov-deg", f"{fov:.9f}"]) == 0
    a = json.loads(capsys.readouterr().out)
    assert main(base + ["--focal-mm", "18", "--pixel-um", "11"]) == 0
    b = json.loads(capsys.readouterr().out)
    assert a["rho_rad"] == pytest.approx(b["rho_rad"], rel=1e-7)
    assert main(base + ["--fov-deg", f"{fov:.9f}", "--attitude=1,0,0,0", "--sun-eci=0,0,-1",
                        "--correlated-residuals", "--floor-px", "0.05"]) == 0
    c = json.loads(capsys.readouterr().out)
    assert c["variance_inflation"] >= 1.0 and c["sigma_rho_rad"] > c["sigma_rho_pixel_rad"]
    assert c["n_lit"] > 100
    for bad in (["--focal-mm", "18"],                                  # no pixel pitch
                ["--fov-deg", "30", "--focal-mm", "18", "--pixel-um", "11"],
                ["--fov-deg", "30", "--sun-eci=0,0,-1"],                 # Sun without attitude
                ["--fov-deg", "30", "--flattening", "0.003"],
                ["--fov-deg", "30", "--attitude=1,0,0,0", "--method", "ellipse"],
                ["--fov-deg", "30", "--attitude=0,0,0,0"]):
        assert main(base + bad) == 2, bad
        assert "error" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:                                # argparse's own check
        main(base + ["--fov-deg", "30", "--attitude=1,0,0"])
    assert exc.value.code == 2
    assert "4 comma-separated numbers" in capsys.readouterr().err


def test_psf_correction_moves_the_points_outward():
    """With the PSF given, the points move outward by the edge locator's curvature bias of
    the limb's image radius (fgnav.vision.limb.edge_curvature_bias_px), as in the plain path."""
    from fgnav.vision.limb import edge_curvature_bias_px

    c = np.array([0.0, 0.0, 40_000e3])
    U = np.eye(3) / 6378e3
    pts = _exact_points(NARROW, c, U)
    fix = real_limb_fix(pts, NARROW, LimbModel(r_limb_m=6378e3, psf_sigma_px=1.0))
    r_px = NARROW.f_px * np.tan(np.arcsin(6378e3 / 40_000e3))
    assert fix.extra["curvature_correction_px"] == pytest.approx(edge_curvature_bias_px(r_px, 1.0), rel=1e-6)
    assert fix.rho_rad > np.arcsin(6378e3 / 40_000e3)      # exact points moved out: a larger disk
