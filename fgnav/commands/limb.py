"""``fgnav limb``: horizon fix (Earth direction + angular radius) from one limb image."""

from __future__ import annotations

from fgnav.commands import _types as T

HELP = """\
Extract the Earth's limb from IMAGE (an 8/16-bit PNG/TIFF/JPEG or a .npy array: bright
disk on a dark sky), reject outliers (RANSAC on the horizon cone) and estimate the
direction of the Earth's centre and the limb's angular radius in the camera frame (OpenCV:
x right, y down, z along the boresight; principal point at the image centre unless given).
A colour image is reduced to one channel by --channel (default red: OpenCV reads B, G, R;
gray = OpenCV's luma 0.299 R + 0.587 G + 0.114 B); a single-channel image is read as it is.
The camera: --focal-mm with --pixel-um, or --fov-deg (full horizontal field of view).

Real limbs (docs/epic.md): --attitude Q (the camera's attitude, quaternion w,x,y,z of
R_eci_from_cam) makes the limb surface the oblate ellipsoid of --flattening (default
WGS-84's) about the ECI z axis, equatorial radius --r-limb-km (the reference radius plus the
visible limb's height); --sun-eci X,Y,Z (the Sun's direction from the Earth, ECI) keeps
only the lit limb (limb points whose tangent point sees the Sun; the others lie on the
terminator); --correlated-residuals inflates the covariance by the limb residuals'
correlation along the limb; --limb-height-sigma-km and --floor-px add the limb height's
uncertainty and a model-error floor (px, on the limb's radius and centre). Any of these
selects that model (christian-robinson only). Write a vector that starts with a minus sign
as --sun-eci=-1,2,3. EPIC level-1B frames (north-up, re-centred, 1080 px over EPIC's
0.62 deg field):
  fgnav limb epic_1b_*.jpg --fov-deg 0.62 --r-limb-km 6378.137 --attitude Q --sun-eci S
        --correlated-residuals --floor-px 0.05

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
  channel           the channel read from a colour image (null for a single-channel one)
with the real-limb model also:
  n_lit, n_unlit    limb points on the lit limb / on the terminator (all lit without --sun-eci)
  variance_inflation  factor applied for correlated residuals (1 without the option)
  sigma_rho_pixel_rad  1-sigma of rho_rad from the pixel noise alone (rad)
"""


CHANNELS = ("red", "green", "blue", "gray")
CHANNEL_INDEX_BGR = {"blue": 0, "green": 1, "red": 2}
"""OpenCV's channel order: B, G, R (A)."""


def register(subparsers) -> None:
    import argparse

    p = subparsers.add_parser("limb", help="horizon fix (Earth direction, angular radius) from a limb image",
                              description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("image", metavar="IMAGE", help="limb image (.png/.tif/.jpg/.npy)")
    p.add_argument("--channel", choices=CHANNELS, default="red",
                   help="channel of a colour image (default red; gray = luma); "
                        "single-channel images are read as they are")
    p.add_argument("--focal-mm", type=T.pos("mm"), default=None, help="focal length (mm; with --pixel-um)")
    p.add_argument("--pixel-um", type=T.pos("µm"), default=None, help="pixel pitch (µm; with --focal-mm)")
    p.add_argument("--fov-deg", type=T.number(0.0, 180.0, lo_open=True, hi_open=True, unit="deg"),
                   default=None, help="full horizontal field of view (deg), instead of --focal-mm/--pixel-um")
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
    p.add_argument("--attitude", type=_vector(4, "a quaternion w,x,y,z"), default=None, metavar="W,X,Y,Z",
                   help="camera attitude, R_eci_from_cam as a scalar-first quaternion: "
                        "the limb surface becomes the oblate ellipsoid (see above)")
    p.add_argument("--flattening", type=T.number(0.0, 1.0, hi_open=True), default=None,
                   help="flattening of the limb ellipsoid with --attitude (default WGS-84, 1/298.257223563)")
    p.add_argument("--sun-eci", type=_vector(3, "a vector x,y,z"), default=None, metavar="X,Y,Z",
                   help="Sun direction from the Earth (ECI, any length; needs --attitude): lit limb only")
    p.add_argument("--correlated-residuals", action="store_true",
                   help="inflate the covariance by the residuals' correlation along the limb")
    p.add_argument("--limb-height-sigma-km", type=T.number(0.0, unit="km"), default=0.0,
                   help="1-sigma of the limb's height, common to the whole limb (km; default 0)")
    p.add_argument("--floor-px", type=T.number(0.0, unit="px"), default=0.0,
                   help="model-error floor on the limb's radius and centre (px, 1-sigma; default 0)")
    p.add_argument("--seed", type=T.seed, default=0, help="RANSAC random seed (default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(func=run)


def _load_image(path: str, channel_name: str = "red"):
    """(2-D image, channel read or None): a colour image reduced to ``channel_name``."""
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
    channel = None
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    elif img.ndim == 3 and img.shape[2] in (3, 4):
        if path.lower().endswith(".npy"):
            raise UserError(f"{path}: a .npy array must be 2-D (one channel), found shape {img.shape}")
        channel = channel_name
        if channel == "gray":
            import cv2

            code = cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
            img = cv2.cvtColor(img, code)
        else:
            img = img[:, :, CHANNEL_INDEX_BGR[channel]]
    if img.ndim != 2:
        raise UserError(f"{path}: expected a 2-D image or a colour image (3 or 4 channels), "
                        f"found shape {img.shape}")
    return np.ascontiguousarray(img), channel


def _vector(n: int, what: str):
    """argparse converter: ``n`` comma-separated finite numbers."""
    import argparse
    import math

    def convert(text: str):
        try:
            v = [float(x) for x in text.split(",")]
        except ValueError:
            v = []
        if len(v) != n or not all(math.isfinite(x) for x in v):
            raise argparse.ArgumentTypeError(f"expected {what} ({n} comma-separated numbers), found {text!r}")
        return v

    convert.__name__ = "vector"
    return convert


def run(args) -> int:
    import json

    import numpy as np

    from fgnav.errors import UserError
    from fgnav.vision.attitude import matrix_from_quat
    from fgnav.vision.camera import PinholeCamera
    from fgnav.vision.horizon import estimate_horizon
    from fgnav.vision.limb import extract_limb_points, ransac_limb
    from fgnav.vision.real_limb import WGS84_FLATTENING, LimbModel, real_limb_fix

    if args.fov_deg is None and (args.focal_mm is None or args.pixel_um is None):
        raise UserError("the camera needs --focal-mm and --pixel-um, or --fov-deg")
    if args.fov_deg is not None and (args.focal_mm is not None or args.pixel_um is not None):
        raise UserError("give the camera either as --fov-deg or as --focal-mm with --pixel-um, not both")
    if not args.r_limb_km > 0:
        raise UserError("--r-limb-km must be > 0")
    if args.psf_px is not None and not 0 <= args.psf_px < float("inf"):
        raise UserError(f"--psf-px must be finite and >= 0 (px), got {args.psf_px}")
    real = (args.attitude is not None or args.sun_eci is not None or args.correlated_residuals
            or args.limb_height_sigma_km > 0 or args.floor_px > 0 or args.flattening is not None)
    if real and args.method != "christian-robinson":
        raise UserError("--attitude, --sun-eci, --flattening, --correlated-residuals, "
                        "--limb-height-sigma-km and --floor-px need --method christian-robinson")
    if args.flattening is not None and args.attitude is None:
        raise UserError("--flattening needs --attitude (the ellipsoid's axis in the camera frame)")
    if args.sun_eci is not None and args.attitude is None:
        raise UserError("--sun-eci needs --attitude (the Sun's direction in the camera frame)")
    if args.attitude is not None and not np.linalg.norm(args.attitude) > 0:
        raise UserError("--attitude: the quaternion must be non-zero")
    img, channel = _load_image(args.image, args.channel)
    if args.fov_deg is not None:
        cam = PinholeCamera.from_fov(args.fov_deg, img.shape[1], img.shape[0],
                                     cx_px=args.cx_px, cy_px=args.cy_px)
    else:
        cam = PinholeCamera(focal_mm=args.focal_mm, pixel_um=args.pixel_um, width_px=img.shape[1],
                            height_px=img.shape[0], cx_px=args.cx_px, cy_px=args.cy_px)
    rng = np.random.default_rng(args.seed)
    raw = extract_limb_points(img)
    if real:
        model = LimbModel(
            r_limb_m=args.r_limb_km * 1e3,
            R_eci_from_cam=None if args.attitude is None else matrix_from_quat(args.attitude),
            flattening=WGS84_FLATTENING if args.flattening is None else args.flattening,
            sun_eci=None if args.sun_eci is None else np.array(args.sun_eci),
            limb_height_sigma_m=args.limb_height_sigma_km * 1e3, correlated=args.correlated_residuals,
            floor_px=args.floor_px, psf_sigma_px=args.psf_px)
        fix = real_limb_fix(raw, cam, model, rng=rng)
        n_out = len(raw) - fix.n_points
    else:
        pts = ransac_limb(raw, cam, rng=rng)
        fix = estimate_horizon(pts, cam, args.method, args.r_limb_km * 1e3, psf_sigma_px=args.psf_px)
        n_out = int((~pts.inlier).sum())
    out = fix.to_dict()
    out["n_outliers"] = n_out
    out["curvature_correction_px"] = float(fix.extra.get("curvature_correction_px", 0.0))
    out["channel"] = channel
    if real:
        for key in ("n_lit", "n_unlit", "variance_inflation", "sigma_rho_pixel_rad"):
            out[key] = fix.extra[key]
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
        if channel is not None:
            print(f"channel       {channel}")
        if real:
            print(f"lit limb      {out['n_lit']} points lit, {out['n_unlit']} on the terminator; "
                  f"variance inflation {out['variance_inflation']:.2f}")
        if fix.extra.get("curvature_correction_px"):
            print(f"edge curvature correction  {out['curvature_correction_px']:.5f} px outward")
    return 0
