"""``fgnav stars IMAGE --fov-deg F``: lost-in-space star identification on one image.

Prints the pointing of the image centre (RA/Dec of the camera boresight, +z), the roll, the
fitted field of view, the number of matched stars, the RMS residual and the attitude
quaternion ``q_eci_from_camera`` (scalar first). Heavy modules are imported in ``run``.
"""

from __future__ import annotations

import argparse

from fgnav.commands import _types as T

ROLL_HELP = ("roll_deg: position angle of the image 'up' direction (towards decreasing pixel "
             "row v, camera -y) measured from celestial north through east, degrees in "
             "(-180, 180]; 0 = up is north, +90 = up is east.")


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "stars", help="identify stars in an image (lost in space) and solve the camera attitude",
        description="Detect stars in IMAGE, identify them against the BSC5 catalogue with no "
                    "attitude prior and an approximate field of view, and fit attitude + focal "
                    "length. Output: ra_deg, dec_deg (boresight = image centre, J2000, deg), "
                    "roll_deg, fov_deg (fitted horizontal FOV, deg), matched, rmse_arcsec, "
                    "q_eci_from_camera [w, x, y, z]. " + ROLL_HELP,
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("image", metavar="IMAGE", help="image file OpenCV reads (16-bit grey TIFF preferred; 8-bit loses faint stars)")
    p.add_argument("--fov-deg", type=float, required=True,  # checked in run: (0, 120) deg
                   help="approximate full horizontal field of view (deg)")
    p.add_argument("--fov-tolerance", type=T.number(0.0, 1.0, hi_open=True), default=0.1,
                   help="relative uncertainty of --fov-deg (fraction, 0.1 = +-10%%)")
    p.add_argument("--epoch", default=None,
                   help="observation time, ISO-8601 UTC (e.g. 2019-07-29T20:47:26Z), for star "
                        "proper motion; default J2000.0")
    p.add_argument("--k-sigma", type=T.positive, default=5.0,
                   help="detection threshold (multiples of the filtered background noise)")
    p.add_argument("--fit-k1", action="store_true", help="also fit radial distortion k1 (normalized coordinates)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(func=run)


def run(args) -> int:
    import json
    from pathlib import Path

    from fgnav.errors import UserError

    if not (args.fov_deg > 0 and args.fov_deg < 120):
        raise UserError(f"--fov-deg must be in (0, 120) deg, got {args.fov_deg}")
    if not (0 <= args.fov_tolerance < 0.5):
        raise UserError(f"--fov-tolerance must be in [0, 0.5), got {args.fov_tolerance}")
    path = Path(args.image)
    if not path.is_file():
        raise UserError(f"{path}: no such image file")

    import cv2
    import numpy as np

    from fgnav.vision.camera import PinholeCamera
    from fgnav.vision.catalogue import decimal_year
    from fgnav.vision.star_id import solve_lost_in_space
    from fgnav.vision.stars import detect_stars

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise UserError(f"{path}: not an image OpenCV can read")
    if img.ndim == 3:
        img = img.astype(np.float32).mean(axis=2)
    try:
        epoch = 2000.0 if args.epoch is None else decimal_year(args.epoch)
    except ValueError as exc:
        raise UserError(f"--epoch: expected ISO-8601 UTC time, found {args.epoch!r}") from exc
    det = detect_stars(img, k_sigma=args.k_sigma)
    cam = PinholeCamera.from_fov(args.fov_deg, img.shape[1], img.shape[0])
    sol = solve_lost_in_space(det.uv_px, cam, sigma_px=det.sigma_px, fov_tolerance=args.fov_tolerance,
                              epoch_year=epoch, fit_k1=args.fit_k1)
    out = sol.summary()
    out = {k: (v if isinstance(v, list) else (int(v) if k == "matched" else float(v))) for k, v in out.items()}
    if args.json:
        print(json.dumps(out))
    else:
        sig = np.degrees(np.sqrt(np.diag(sol.cov_theta_rad2))) * 3600.0
        print(f"{path.name}: {len(det)} stars detected, {out['matched']} matched "
              f"({sol.solve_time_s * 1e3:.0f} ms)")
        print(f"  boresight  RA {out['ra_deg']:.4f} deg  Dec {out['dec_deg']:+.4f} deg  "
              f"roll {out['roll_deg']:+.3f} deg")
        print(f"  FOV {out['fov_deg']:.4f} deg (f = {sol.camera.f_px:.1f} px)  "
              f"RMS residual {out['rmse_arcsec']:.1f} arcsec")
        print(f"  1-sigma attitude (camera x, y, roll) {sig[0]:.1f}, {sig[1]:.1f}, {sig[2]:.1f} arcsec")
        print("  q_eci_from_camera [w, x, y, z] = " + ", ".join(f"{q:.8f}" for q in out["q_eci_from_camera"]))
    return 0
