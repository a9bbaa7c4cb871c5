#!/usr/bin/env python
"""Does the star front end's attitude sigma cover the real error? The OreSat frame (docs/epic.md).

    PYTHONPATH=$PWD python scripts/study_oresat_attitude.py [--image PNG] [--splits 200] [--markdown]

The real frame (``../shared/data/star_images_oresat/``, AR0130, ~17 deg, Bayer colour, hot
pixels; no attitude truth) is solved as ``fgnav stars`` solves it (channel mean, detection,
lost-in-space identification, Gauss-Newton attitude + focal length, covariance scaled by
the a-posteriori variance factor). Without truth, the test is internal: the matched stars
are split into two halves, each half refitted alone (:func:`fgnav.vision.star_id.refine_attitude`,
started from the full solution), and the two attitudes' difference
``d = Log(R_a^T R_b)`` compared with the sum of their reported covariances:
``chi2 = d^T (P_a + P_b)^-1 d`` is chi-square with 3 degrees of freedom when the sigma is
honest and the halves' errors independent (Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4).
Random halves (mean over ``--splits`` splits, seed 0) test the random part; halves split
by position in the image (left/right, top/bottom, centre/edge) test field-dependent errors
(distortion beyond the model, detector effects) that random splits average out.
Prints JSON (or Markdown).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from factors.geometry import so3_log  # noqa: E402
from fgnav.vision.camera import PinholeCamera  # noqa: E402
from fgnav.vision.star_id import refine_attitude, solve_lost_in_space  # noqa: E402
from fgnav.vision.stars import detect_stars  # noqa: E402

FOV_DEG = 17.0
"""The OreSat star tracker's field of view as stated with the frame (../shared/data/README.md)."""

FOV_TOLERANCE = 0.15
DEFAULT_IMAGES = [ROOT.parent / "shared" / "data" / "star_images_oresat" / "capture-2022-09-25-09-40-25.png",
                  Path("/work/shared/data/star_images_oresat/capture-2022-09-25-09-40-25.png")]
ARCSEC = np.pi / 180 / 3600


def find_image(explicit: str | None = None) -> Path | None:
    for p in ([Path(explicit)] if explicit else DEFAULT_IMAGES):
        if p.is_file():
            return p
    return None


def split_chi2(sol, uv, u_eci, sigma, a, b, fit_k1):
    """chi2 of the attitude difference of the halves ``a``, ``b`` (index arrays) and the
    difference and its predicted sigma per axis (arcsec; camera x, y, roll)."""
    fits = [refine_attitude(sol.R_eci_from_camera, sol.camera, uv[s], u_eci[s], sigma[s],
                            fit_f=True, fit_k1=fit_k1) for s in (a, b)]
    (Ra, _, Ca, _), (Rb, _, Cb, _) = fits
    d = so3_log(Ra.T @ Rb)
    P = Ca[:3, :3] + Cb[:3, :3]
    return float(d @ np.linalg.solve(P, d)), d / ARCSEC, np.sqrt(np.diag(P)) / ARCSEC


def study(image: Path, splits: int = 200) -> dict:
    """Solve the frame with and without k1; random and spatial split-half chi-squares."""
    import cv2

    img = cv2.imread(str(image), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise FileNotFoundError(f"{image}: not an image OpenCV can read")
    if img.ndim == 3:
        img = img.astype(np.float32).mean(axis=2)            # as fgnav stars reads it
    det = detect_stars(img, k_sigma=5.0)
    cam = PinholeCamera.from_fov(FOV_DEG, img.shape[1], img.shape[0])
    out = {"image": image.name, "fov_deg_given": FOV_DEG, "n_detected": len(det), "models": []}
    for fit_k1 in (False, True):
        sol = solve_lost_in_space(det.uv_px, cam, sigma_px=det.sigma_px, fov_tolerance=FOV_TOLERANCE,
                                  fit_k1=fit_k1)
        idx = sol.det_index
        uv, u = det.uv_px[idx], sol.cat_u_eci
        sigma = np.broadcast_to(np.asarray(det.sigma_px, float), (len(det.uv_px),))[idx]
        m = len(idx)
        rng = np.random.default_rng(0)
        chis = []
        for _ in range(splits):
            p = rng.permutation(m)
            chis.append(split_chi2(sol, uv, u, sigma, p[: m // 2], p[m // 2:], fit_k1)[0])
        spatial = {}
        r = np.hypot(uv[:, 0] - cam.cx, uv[:, 1] - cam.cy)
        for name, key in (("left/right", uv[:, 0]), ("top/bottom", uv[:, 1]), ("centre/edge", r)):
            o = np.argsort(key)
            c2, d, s = split_chi2(sol, uv, u, sigma, o[: m // 2], o[m // 2:], fit_k1)
            spatial[name] = {"chi2": c2, "diff_arcsec": d.tolist(), "sigma_arcsec": s.tolist()}
        out["models"].append({
            "fit_k1": fit_k1, "matched": sol.matched, "rmse_arcsec": sol.rmse_arcsec,
            "fov_deg": sol.fov_deg, "k1": float(sol.camera.k1),
            "sigma_arcsec": (np.sqrt(np.diag(sol.cov_theta_rad2)) / ARCSEC).tolist(),
            "centroid_sigma_arcsec": float(np.median(sigma) / sol.camera.f_px / ARCSEC),
            "random_split_mean_chi2": float(np.mean(chis)), "random_splits": splits,
            "random_split_frac_over_95": float(np.mean(np.array(chis) > 7.815)),
            "spatial": spatial})
    return out


def markdown(res: dict) -> str:
    lines = ["| model | matched | RMS residual (arcsec) | reported 1-sigma x, y, roll (arcsec) "
             "| random halves: mean chi2 (3 = honest) | left/right chi2 | top/bottom chi2 | centre/edge chi2 |",
             "|---|---|---|---|---|---|---|---|"]
    for m in res["models"]:
        s = m["sigma_arcsec"]
        sp = m["spatial"]
        lines.append(f"| {'f + k1' if m['fit_k1'] else 'f'} | {m['matched']} | {m['rmse_arcsec']:.1f} "
                     f"| {s[0]:.1f}, {s[1]:.1f}, {s[2]:.1f} | {m['random_split_mean_chi2']:.2f} "
                     f"| {sp['left/right']['chi2']:.1f} | {sp['top/bottom']['chi2']:.1f} "
                     f"| {sp['centre/edge']['chi2']:.1f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--image", default=None, help="the OreSat frame (default ../shared/data/star_images_oresat/)")
    ap.add_argument("--splits", type=int, default=200, help="random split-half trials (default 200)")
    ap.add_argument("--markdown", action="store_true", help="print the docs/epic.md table")
    a = ap.parse_args(argv)
    image = find_image(a.image)
    if image is None:
        print("study_oresat_attitude: the OreSat frame is not present", file=sys.stderr)
        return 2
    res = study(image, a.splits)
    print(markdown(res) if a.markdown else json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
