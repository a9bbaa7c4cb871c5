#!/usr/bin/env python
"""Time ``fgnav.viz.rerun_log.log_solution`` on a long pass (default 14,400 epochs = 4 h at
1 s) with truth, Earth-direction rays, residuals and latency; print one JSON object.

    python scripts/bench_rerun.py [--epochs 14400] [--dt 1.0] [--seed 0] [--keep out.rrd]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def synthetic_pass(n, dt_s, seed):
    """The transfer orbit of Pan & Yao 2017, RTN-diagonal covariance, estimate = truth + draw."""
    from fgnav.solution import Solution
    from fgnav.viz.rerun_log import rtn_rotations

    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt_s
    from fgnav.orbit import kepler_states

    truth = kepler_states(t, 26_332_437.9, 0.72, np.radians(90.0), 0.0, np.radians(13.75),
                          np.radians(1.89))
    R = rtn_rotations(truth)
    T = np.zeros((n, 6, 6))
    T[:, :3, :3] = R
    T[:, 3:, 3:] = R
    D = np.diag(np.square([60.0, 300.0, 40.0, 0.05, 0.02, 0.01]))
    P = np.einsum("nji,jk,nkl->nil", T, D, T)
    x = truth + np.einsum("nij,nj->ni", np.linalg.cholesky(P), rng.standard_normal((n, 6)))
    u = -truth[:, :3] / np.linalg.norm(truth[:, :3], axis=1, keepdims=True)
    sol = Solution(method="isam2", epoch0=np.datetime64("2024-01-01T00:00:00", "ns"), t_s=t,
                   x_eci=x, P_eci=P, residuals={"earth_dir": rng.standard_normal((n, 2))},
                   online_x_eci=x, online_P_eci=P, latency_s=np.abs(rng.normal(2e-3, 5e-4, n)))
    return sol, truth, {"earth_dir": (t, u)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--epochs", type=int, default=14_400, help="number of epochs")
    ap.add_argument("--dt", type=float, default=1.0, help="epoch spacing [s]")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=3, help="timed runs (best is reported)")
    ap.add_argument("--keep", type=Path, default=None, help="keep the .rrd at this path")
    args = ap.parse_args(argv)

    from fgnav.viz.rerun_log import log_solution

    sol, truth, meas = synthetic_pass(args.epochs, args.dt, args.seed)
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        path = args.keep or Path(tmp) / "bench.rrd"
        for _ in range(max(1, args.repeat)):
            t0 = time.perf_counter()
            out = log_solution(path, sol, truth_x_eci=truth, measurements=meas)
            times.append(time.perf_counter() - t0)
        size = Path(out["path"]).stat().st_size
    print(json.dumps({"epochs": args.epochs, "log_s": min(times), "log_s_runs": times,
                      "entities": len(out["entities"]), "file_bytes": size,
                      "magnification": out["magnification"]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
