#!/usr/bin/env python
"""Consistency of the image route over seeds: simulate -> render -> extract -> smooth.

    PYTHONPATH=$PWD python scripts/study_image_nees.py [--seeds 10] [--first 0] [--duration-h 2]
        [--step-s 120] [--runs-dir DIR] [--summarize] [--out study.json]

Per seed: ``fgnav simulate geo-limb --images`` (truth from the DOP853 integrator), ONE
extraction of the frames (:func:`fgnav.extract.extract_frames`), written as three logs of
the same front-end output (:meth:`fgnav.extract.ExtractionResult.log_as`):

* ``eci``   -- earth_direction rows with the star attitude's error folded in + limb_radius;
* ``loose`` -- earth_direction_body + one solved ``attitude`` row per star frame with its
  full 3x3 covariance (the attitude known to the smoother, its variance across each
  direction added);
* ``tight`` -- every identified star a ``star_direction_body`` row + earth_direction_body,
  the attitude a graph variable (``--attitude estimate``);

each smoothed in batch with the third-body forces. Consistency (Bar-Shalom, Li &
Kirubarajan 2001, sec. 5.4): the 6-D NEES of each epoch, averaged over the R runs (ANEES),
against the two-sided 95 % band ``chi2.ppf([0.025, 0.975], 6 R) / R``; reported at the
middle and the final epoch, as the fraction of epochs whose ANEES lies in the band, and as
the time mean of the ANEES curve. Also per route the position RMS over runs, and over all
frames the mean normalized limb-radius error (a bias every frame repeats is what no
per-frame covariance can absorb). Prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROUTES = {"eci": ("eci", ()), "loose": ("body", ()), "tight": ("raw-stars", ("attitude",))}
"""route -> (extract row mode, variables estimated beyond the orbit)."""


def run_seed(seed: int, duration_h: float, step_s: float, work: Path) -> dict:
    """One seed: per route the per-epoch NEES (N,) and position RMS; the limb-radius z's."""
    import csv

    from fgnav.cli import main
    from fgnav.extract import extract_frames
    from fgnav.io.log_csv import write_log
    from fgnav.pipeline import smooth_file
    from fgnav.solvers.options import SmootherOptions
    from fgnav.diagnostics.consistency import nees

    d = work / f"seed{seed}"
    rc = main(["simulate", "geo-limb", "--out", str(d), "--duration-h", str(duration_h),
               "--step-s", str(step_s), "--seed", str(seed), "--images", "--quiet"])
    if rc != 0:
        raise RuntimeError(f"simulate failed for seed {seed}")
    res = extract_frames(d, rows="eci", seed=seed)
    truth_rho = [float(r["truth_rho_rad"]) for r in csv.DictReader(
        ln for ln in (d / "frames.csv").read_text().splitlines() if not ln.startswith("#"))
        if r["camera"] == "limb0"]
    z_rho = [(e.rho_rad - t) / e.sigma_rho_rad for e, t in zip(res.epochs, truth_rho)
             if e.rho_rad is not None]
    out = {"seed": seed, "epochs": len(res.epochs), "failures": res.failures, "z_rho": z_rho,
           "routes": {}}
    for route, (rows, est) in ROUTES.items():
        path = d / f"{route}.csv"
        write_log(path, res.log_as(rows))
        r, _ = smooth_file(path, "batch", SmootherOptions(third_body=True, estimate=est),
                           truth_path=d / "truth.oem")
        sol = r.solution
        out["routes"][route] = {"nees": nees(sol.x_eci, sol.P_eci, r.x_true).tolist(),
                                "position_rms_m": r.summary["position_rms_m"],
                                "sigma_position_rms_m": r.summary["sigma_position_rms_m"]}
    return out


def summarize(runs: list[dict]) -> dict:
    """ANEES table of the routes over the runs (module doc)."""
    from fgnav.diagnostics.consistency import anees, chi2_band

    R = len(runs)
    lo, hi = chi2_band(6, R)
    table = {}
    for route in ROUTES:
        N = min(len(r["routes"][route]["nees"]) for r in runs)
        E = np.array([r["routes"][route]["nees"][:N] for r in runs])        # (R, N)
        curve = E.mean(axis=0)
        rms = np.array([r["routes"][route]["position_rms_m"] for r in runs])
        sig = np.array([r["routes"][route]["sigma_position_rms_m"] for r in runs])
        table[route] = {
            "anees_mid": anees(E[:, N // 2], 6).as_dict(),
            "anees_final": anees(E[:, -1], 6).as_dict(),
            "fraction_of_epochs_in_band": float(np.mean((curve >= lo) & (curve <= hi))),
            "anees_time_mean": float(curve.mean()),
            "position_rms_m_mean": float(np.sqrt(np.mean(rms ** 2))),
            "sigma_position_rms_m_mean": float(np.sqrt(np.mean(sig ** 2)))}
    z = np.concatenate([r["z_rho"] for r in runs])
    return {"runs": R, "band_95": [lo, hi], "routes": table,
            "limb_radius_z": {"n": int(len(z)), "mean": float(z.mean()),
                              "se": float(z.std() / np.sqrt(len(z))), "std": float(z.std())}}


def study(seeds, duration_h: float, step_s: float, runs_dir: Path | None = None) -> dict:
    """Run the seeds (each run also written to ``runs_dir/seed<k>.json`` when given) and
    summarize them together with any other runs already in ``runs_dir`` (so seeds can be
    split over processes: ``--first``/``--seeds`` per process, then ``--summarize``)."""
    with tempfile.TemporaryDirectory(prefix="fgnav-image-nees-") as td:
        runs = []
        for s in seeds:
            runs.append(run_seed(s, duration_h, step_s, Path(td)))
            if runs_dir is not None:
                Path(runs_dir).mkdir(parents=True, exist_ok=True)
                (Path(runs_dir) / f"seed{s}.json").write_text(json.dumps(runs[-1]))
    if runs_dir is not None:
        runs = load_runs(runs_dir)
    out = summarize(runs)
    out.update(scenario="geo-limb", duration_h=duration_h, step_s=step_s,
               seeds=[r["seed"] for r in runs])
    return out


def load_runs(runs_dir) -> list[dict]:
    """The runs written by :func:`study` into ``runs_dir``, by seed."""
    runs = [json.loads(p.read_text()) for p in Path(runs_dir).glob("seed*.json")]
    return sorted(runs, key=lambda r: r["seed"])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=10, help="number of seeds (default 10)")
    ap.add_argument("--first", type=int, default=0, help="first seed (default 0)")
    ap.add_argument("--runs-dir", help="also keep each run as DIR/seed<k>.json and summarize "
                                       "every run found there")
    ap.add_argument("--summarize", action="store_true",
                    help="run nothing: summarize the runs in --runs-dir")
    ap.add_argument("--duration-h", type=float, default=2.0, help="pass length (h; default 2)")
    ap.add_argument("--step-s", type=float, default=120.0, help="image period (s; default 120)")
    ap.add_argument("--out", help="also write the JSON object to this file")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    if args.summarize:
        if not args.runs_dir:
            ap.error("--summarize needs --runs-dir")
        runs = load_runs(args.runs_dir)
        out = summarize(runs)
        out.update(scenario="geo-limb", seeds=[r["seed"] for r in runs])
    else:
        out = study(range(args.first, args.first + args.seeds), args.duration_h, args.step_s,
                    Path(args.runs_dir) if args.runs_dir else None)
    out["wall_s"] = time.perf_counter() - t0
    text = json.dumps(out, indent=1)
    if args.out:
        Path(args.out).write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
