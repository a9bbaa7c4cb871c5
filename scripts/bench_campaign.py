"""Campaign throughput: overhead per run (scheduling, result transfer, CSV append + fsync,
progress) as a fraction of the run time, for 1 worker (in-process), N local worker processes
and a Dask LocalCluster. Prints one JSON object.

    python scripts/bench_campaign.py [--runs 12] [--step-s 10] [--workers 2]

overhead_fraction = (workers * wall - sum(run_s)) / sum(run_s), where run_s is each run's
wall time measured inside its worker: everything the campaign adds, including worker start-up
(spawn + imports) and idle workers at the end, which are also reported separately
(``startup_s``: wall time until the first result minus that run's own time).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path


def study_text(n_runs: int, step_s: float) -> str:
    return f"""
name = "bench"
task = "navigate"
report = "seed002-noise"
methods = ["batch"]
seeds = {{ start = 0, count = {n_runs} }}
[fixed]
scenario = "gto-transfer"
step_s = {step_s}
duration_h = 4.0
sigma_deg = 0.01
"""


def measure(study, out, workers=1, client=None):
    first = []
    t0 = time.perf_counter()

    def on_result(row):
        if not first:
            first.append((time.perf_counter() - t0, float(row["run_s"])))

    from fgnav.campaign import run_campaign

    res = run_campaign(study, out, workers=workers, client=client, on_result=on_result, report=False)
    wall = time.perf_counter() - t0
    n_par = workers if client is None else sum(client.nthreads().values())
    startup = first[0][0] - first[0][1] if first else 0.0
    return {"workers": n_par, "runs": res.n_ran, "wall_s": wall, "sum_run_s": res.run_s_sum,
            "mean_run_s": res.run_s_sum / max(res.n_ran, 1),
            "overhead_fraction": (n_par * wall - res.run_s_sum) / res.run_s_sum,
            "overhead_per_run_s": (n_par * wall - res.run_s_sum) / max(res.n_ran, 1),
            "startup_s": startup,
            "overhead_fraction_after_startup": (n_par * (wall - startup) - res.run_s_sum) / res.run_s_sum}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=12, help="runs per configuration")
    ap.add_argument("--step-s", type=float, default=10.0, help="gto-transfer sample period (s)")
    ap.add_argument("--workers", type=int, default=2, help="local worker processes / Dask workers")
    args = ap.parse_args(argv)
    from fgnav.campaign import load_study

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        (tmp / "bench.toml").write_text(study_text(args.runs, args.step_s))
        study = load_study(tmp / "bench.toml")
        out = {"study": "gto-transfer batch, 4 h", "step_s": args.step_s, "results": {}}
        out["results"]["in_process"] = measure(study, tmp / "w1", 1)
        out["results"]["processes"] = measure(study, tmp / "wn", args.workers)
        from dask.distributed import Client, LocalCluster

        with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                          dashboard_address=None) as cluster, Client(cluster) as client:
            client.run(lambda: __import__("fgnav.campaign"))
            out["results"]["dask_local_cluster"] = measure(study, tmp / "dask", client=client)
    out["criterion"] = "overhead per run < 5% of the run time"
    out["meets"] = {k: v["overhead_fraction_after_startup"] < 0.05 for k, v in out["results"].items()}
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
