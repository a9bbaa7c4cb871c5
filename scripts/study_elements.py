"""Orbital elements against the Cartesian state (``--state elements``), on the Pan & Yao 2017
transfer orbit (built-in ``gto-transfer``, e = 0.72, geocentric directions 0.01 deg).

    PYTHONPATH=$PWD python scripts/study_elements.py [--quick] [--seeds 10] [--out DIR]

Three tables (:mod:`fgnav.analysis.element_study`):

1. EKF and batch smoother, Cartesian vs elements, at 10, 100 and 1,000 s measurement steps
   over the scenario's 4 h: position RMS and NEES against the truth of the independent
   DOP853 integrator, the Cramér–Rao bound along the truth.
2. The same at 100 and 1,000 s with the a-priori sigmas 10 and 30 times the scenario's
   (10 km, 2 m/s): larger corrections per update, where a chart's curvature shows.
3. The nonlinearity index of one motion step (Junkins, Akella & Alfriend 1996) in each chart,
   at 10 s to 10,000 s, for the transfer orbit, a circular orbit of the same semi-major axis
   and a 500 km LEO, deviations drawn from the scenario's prior (10 km, 2 m/s per axis).
4. The integration error of the motion model after 4 h (two-body + J2) against DOP853: RK4 in
   Cartesian coordinates against RK4 of Gauss's variational equations, sub-steps 5 to 600 s.

``--quick``: 3 seeds, fewer samples (about a minute). Prints markdown and writes
``DIR/elements_study.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from fgnav.analysis.element_study import (STEPS_S, nonlinearity_table, orbit_nonlinearity,
                                          pass_rows, propagation_errors, summary_table)
from fgnav.orbit import elements_to_state

X_GTO = np.array([6509244.371304875, 0.0, 3713244.835519765,
                  -3737.397235776740, 0.0, 8790.602460568101])
P_PRIOR = np.diag([1e4 ** 2] * 3 + [2.0 ** 2] * 3)
ORBITS = {
    "gto-transfer, e = 0.72": X_GTO,
    "circular, a = 26,332 km": elements_to_state(26332437.9, 0.001, np.radians(90.0), 0.0,
                                                 np.radians(13.75), 0.1),
    "LEO 500 km, e = 0.001": elements_to_state(6878137.0, 0.001, np.radians(97.0), 1.0, 1.0, 0.1),
}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="3 seeds, fewer samples")
    ap.add_argument("--seeds", type=int, default=None, help="seeds per configuration (default 10)")
    ap.add_argument("--out", default=None, help="directory for elements_study.json")
    a = ap.parse_args(argv)
    n_seeds = a.seeds or (3 if a.quick else 10)
    seeds = range(1, n_seeds + 1)
    t0 = time.perf_counter()
    rows = [r for step in STEPS_S for seed in seeds for r in pass_rows(step, seed)]
    probe = [r for scale in (10.0, 30.0) for step in (100.0, 1000.0) for seed in seeds
             for r in pass_rows(step, seed, prior_scale=scale, with_crb=False)]
    samples = 100 if a.quick else 400
    nonlin = {name: orbit_nonlinearity(x, P_PRIOR, samples=samples) for name, x in ORBITS.items()}
    prop = {name: propagation_errors(ORBITS[name]) for name in list(ORBITS)[::2]}
    wall = time.perf_counter() - t0
    print(f"## Filter and smoother, gto-transfer, {n_seeds} seeds\n")
    print(summary_table(rows))
    print("\n## Larger a-priori errors (sigmas x10 and x30)\n")
    print(summary_table(probe))
    print(f"\n## Nonlinearity index of one motion step ({samples} draws x 8 starts per orbit)\n")
    print(nonlinearity_table(nonlin))
    print("\n## Integration error after 4 h (m), RK4: Cartesian vs Gauss's equations\n")
    print("| orbit | sub-step (s) | Cartesian RK4 (m) | Gauss's equations RK4 (m) |\n|---|---|---|---|")
    for name, res in prop.items():
        for h, v in res.items():
            print(f"| {name} | {h:g} | {v['cartesian']:.3g} | {v['elements']:.3g} |")
    print(f"\n({wall:.0f} s)")
    if a.out:
        out = Path(a.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "elements_study.json").write_text(json.dumps(
            {"rows": rows, "probe": probe, "nonlinearity": nonlin, "propagation": prop,
             "wall_s": wall}, indent=1))


if __name__ == "__main__":
    main()
