"""``fgnav limb``: horizon fix (Earth direction + angular radius) from one limb image."""

from __future__ import annotations

from fgnav.commands import _types as T

HELP = """\
Extract the Earth's limb from IMAGE (a single-channel 8/16-bit PNG/TIFF or a .npy array:
bright disk on a dark sky), reject outliers (RANSAC on the horizon cone) and estimate the
direction of the Earth's centre and the limb's angular radius in the camera frame (OpenCV:
x right, y down, z along the boresight; principal point at the image centre unless given).

Edge-curvature correction (--psf-px SIGMA): the sub-pixel edge locator finds the edge of
a blurred curved limb inside the true limb by (SIGMA^2 + 0.917) / (2 R_px) px (R_px the
limb radius in the image, 0.917 px^2 the locator's own blur); with the optics PSF sigma
given, the christian-robinson points are moved outward by that amount and refitted
(~0.004 px at GEO with a 1 px PSF, about 2 sigma of rho per frame). Without --psf-px no
correction is made. The ellipse method is never corrected: its conic fit has an outward
bias of about the same size that already cancels the locator's.

--json prints one object with the keys:
  method            "ellipse" (Wu et al. conic fit) or "christian-robinson"
  u_cam             unit vector camera -> Earth centre, camera frame [3]
  rho_rad           apparent angular radius of the limb sphere (rad)
  range_m           distance to the Earth's centre, R_limb / sin(rho) (m)
  cov_u             covariance of u_cam (3x3, rad^2, rank 2)
  cov_tangent_rad2  the same on factors.geometry.tangent_basis(u_cam) (2x2, rad^2)
  sigma_rho_rad     1-sigma of rho_rad (rad)
  cov_u_rho         joint covariance of (u_cam, rho_rad) (4x4)
  r_cam_m           spacecraft position relative to the Earth's centre, camera frame [3] (m)
  cov_r_cam_m2      its covariance (3x3, m^2)
  centre_px         Earth centre projected to the image (u, v) (px)
  sigma_px          a-posteriori scatter of the limb points normal to the limb (px)
  n_points          limb points used (RANSAC inliers)
  n_outliers        limb points rejected
  curvature_correction_px  outward shift applied to the limb points (px; 0 when none)
"""


def register(subparsers) -> None:
    import argparse

    p = subparsers.add_parser("limb", help="horizon fix (Earth direction, angular radius) from a limb image",
                              description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("image", metavar="IMAGE", help="limb image (.png/.tif/.npy, single channel)")
    p.add_argument("--focal-mm", type=T.pos("mm"), required=True, help="focal length (mm)")
    p.add_argument("--pixel-um", type=T.pos("µm"), required=True, help="pixel pitch (µm)")
    p.add_argument("--cx-px", type=T.number(unit="px"), default=None,
                   help="principal point u (px; default image centre)")
    p.add_argument("--cy-px", type=T.number(unit="px"), default=None,
                   help="principal point v (px; default image centre)")
    p.add_argument("--method", choices=("ellipse", "christian-robinson"), default="christian-robinson",
                   help="horizon estimator (default: christian-robinson)")
    p.add_argument("--r-limb-km", type=T.pos("km"), default=6375.0,
                   help="limb sphere radius (km; default 6375, the UV limb of Wu et al.)")
    p.add_argument("--psf-px", type=float, default=None,  # checked in run metavar="SIGMA",
                   help="optics PSF 1-sigma (px): correct the christian-robinson edge-curvature "
                        "bias (see above; default: unknown, no correction)")
    p.add_argument("--seed", type=T.seed, default=0, help="RANSAC random seed (default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(func=run)


def _load_image(path: str):
    import os

    import numpy as np

    from fgnav.errors import UserError

    if not os.path.exists(path):
        raise UserError(f"{path}: no such file")
    if path.lower().endswith(".npy"):
        try:
            img = np.load(path, allow_pickle=False)
        except ValueError as exc:
            raise UserError(f"{path}: not a readable .npy array ({exc})") from exc
    else:
        import cv2

        img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
        if img is None:
            raise UserError(f"{path}: OpenCV cannot read this image")
    if img.ndim == 3 and img.shape[2] in (3, 4):
        raise UserError(f"{path}: expected a single-channel image, found {img.shape[2]} channels")
    if img.ndim != 2:
        raise UserError(f"{path}: expected a 2-D image, found shape {img.shape}")
    return img


def run(args) -> int:
    import json

    import numpy as np

    from fgnav.errors import UserError
    from fgnav.vision.camera import PinholeCamera
    from fgnav.vision.horizon import estimate_horizon
    from fgnav.vision.limb import extract_limb_points, ransac_limb

    if not (args.focal_mm > 0 and args.pixel_um > 0 and args.r_limb_km > 0):
        raise UserError("--focal-mm, --pixel-um and --r-limb-km must be > 0")
    if args.psf_px is not None and not 0 <= args.psf_px < float("inf"):
        raise UserError(f"--psf-px must be finite and >= 0 (px), got {args.psf_px}")
    img = _load_image(args.image)
    cam = PinholeCamera(focal_mm=args.focal_mm, pixel_um=args.pixel_um, width_px=img.shape[1],
                        height_px=img.shape[0], cx_px=args.cx_px, cy_px=args.cy_px)
    pts = ransac_limb(extract_limb_points(img), cam, rng=np.random.default_rng(args.seed))
    fix = estimate_horizon(pts, cam, args.method, args.r_limb_km * 1e3, psf_sigma_px=args.psf_px)
    out = fix.to_dict()
    out["n_outliers"] = int((~pts.inlier).sum())
    out["curvature_correction_px"] = float(fix.extra.get("curvature_correction_px", 0.0))
    if args.json:
        print(json.dumps(out))
    else:
        u = fix.u_cam
        print(f"method        {fix.method}")
        print(f"u_cam         [{u[0]:+.8f}, {u[1]:+.8f}, {u[2]:+.8f}]")
        print(f"rho           {np.degrees(fix.rho_rad):.6f} deg  (1 sigma {np.degrees(fix.sigma_rho_rad):.2e} deg)")
        print(f"direction 1s  {np.degrees(np.sqrt(np.trace(fix.cov_u) / 2)):.2e} deg per axis")
        print(f"range         {fix.range_m / 1e3:.3f} km")
        print(f"centre        ({fix.centre_px[0]:.3f}, {fix.centre_px[1]:.3f}) px")
        print(f"limb points   {fix.n_points} used, {out['n_outliers']} rejected, scatter {fix.sigma_px:.3f} px")
        if "curvature_correction_px" in fix.extra:
            print(f"edge curvature correction  {out['curvature_correction_px']:.5f} px outward")
    return 0
