"""Benchmark: limb extraction + RANSAC + horizon fits on a 2048x2048 frame (JSON on stdout).

Target: extraction and fit of a 2048x2048 frame < 50 ms. Frame: Wu et al. limb
optics (f = 18 mm, 11 µm) on the full detector, Earth centre on the boresight at 8,000 km
(limb radius ~826 px), limb signal 2,000 e-, Wu et al.'s detector noise.

Usage: python scripts/bench_vision_limb.py [--repeat N]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=20, help="timed repetitions (default 20)")
    args = ap.parse_args(argv)

    from fgnav.simulate.limb_render import LimbRadiance, render_limb, scene_from_altitude
    from fgnav.vision.camera import CONFOCAL_LIMB_CAMERA as cam
    from fgnav.vision.horizon import horizon_christian_robinson, horizon_ellipse
    from fgnav.vision.limb import extract_limb_points, ransac_limb

    rng = np.random.default_rng(0)
    scene = scene_from_altitude(8000e3, [0.0, 0.0, 1.0])
    t0 = time.perf_counter()
    frame = render_limb(cam, scene, rng, radiance=LimbRadiance(signal_e=2000.0))
    t_render = time.perf_counter() - t0
    img = frame.image_dn
    times = {"extract": [], "ransac": [], "christian_robinson": [], "ellipse": [], "total": []}
    for _ in range(args.repeat + 2):                       # 2 warm-up runs
        t0 = time.perf_counter()
        pts = extract_limb_points(img)
        t1 = time.perf_counter()
        pts = ransac_limb(pts, cam, rng=rng)
        t2 = time.perf_counter()
        fcr = horizon_christian_robinson(pts, cam)
        t3 = time.perf_counter()
        fel = horizon_ellipse(pts, cam)
        t4 = time.perf_counter()
        for k, v in zip(times, (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t3 - t0)):
            times[k].append(v)
    out = {"frame_px": [cam.width_px, cam.height_px], "n_points": int(pts.inlier.sum()),
           "render_s": t_render, "repeat": args.repeat,
           "target_total_ms": 50.0,
           "err_centre_px_cr": float(np.linalg.norm(fcr.centre_px - frame.centre_px)),
           "err_centre_px_ellipse": float(np.linalg.norm(fel.centre_px - frame.centre_px))}
    for k, v in times.items():
        out[f"{k}_ms_median"] = 1e3 * float(np.median(v[2:]))
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
