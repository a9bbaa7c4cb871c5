"""False-alarm and detection rates of the integrity verdict, over many seeds.

    python scripts/study_integrity.py [--seeds 50] [--fault-seeds 10] [--out DIR]

Clean 1 h gto-transfer passes (10 s) are smoothed with every method over ``--seeds`` seeds:
the false-alarm rate is the fraction whose verdict is not ``ok``. Each fault of
:mod:`fgnav.simulate.faults` is run over ``--fault-seeds`` seeds with batch: the detection
rate is the fraction whose verdict is not ``ok``; where the verdict is ``ok`` the table also
shows the NEES against truth, so an undetected fault that matters is visible. Prints a
markdown table and writes ``DIR/integrity_study.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from fgnav.measurements import build_pass
from fgnav.orbit import truth_at
from fgnav.pipeline import accuracy_metrics, prepare_pass, solve, summarize
from fgnav.simulate import faults as F
from fgnav.solvers.options import SmootherOptions

ONE_HOUR = {"duration_h": 1.0}
DAY_S = 86400.0


def two_sessions(seed, **_):
    """Two 1 h sessions of the same orbit 20 days apart (one log)."""
    log, t, x = F.clean(seed=seed, duration_h=20 * 24 + 1, step_s=60.0)
    keep = (log.t_s < 3600.0) | (log.t_s >= 20 * DAY_S)
    return F.with_rows(log, keep=keep), t, x


FAULTS = {
    "5 % outliers": lambda s: F.outliers(0.05, seed=s, **ONE_HOUR),
    "5 % outliers, --robust cauchy": (lambda s: F.outliers(0.05, seed=s, **ONE_HOUR),
                                      SmootherOptions(robust="cauchy")),
    "30 % mirrored directions": lambda s: F.mirrored(0.3, seed=s, **ONE_HOUR),
    "all directions mirrored": lambda s: F.mirrored(1.0, seed=s, **ONE_HOUR),
    "prior 100,000 km off (10 km sigma)": lambda s: F.wrong_prior(1e8, 1e4, seed=s, **ONE_HOUR),
    "no prior": lambda s: F.without_prior(seed=s, **ONE_HOUR),
    "gap 20 min": lambda s: F.gap(1200.0, 1200.0, seed=s, **ONE_HOUR),
    "gap 1 h (4 h pass)": lambda s: F.gap(3600.0, 3600.0, seed=s),
    "sessions 20 days apart": two_sessions,
    "manoeuvre 0.5 m/s (4 h)": lambda s: F.manoeuvre(0.5, seed=s),
    "manoeuvre 5 m/s (4 h)": lambda s: F.manoeuvre(5.0, seed=s),
    "GEO without --third-body": lambda s: F.clean("geo-limb", seed=s),
}


def run_case(made, method="batch", options=SmootherOptions()):
    log, t, x = made
    try:
        p = prepare_pass(build_pass(log), options)
        sol = solve(p, method, options)
    except Exception as exc:  # noqa: BLE001 - a study records every outcome
        return {"status": "refused", "error": f"{type(exc).__name__}: {exc}"[:200]}
    s = summarize(sol, p, options)
    a = accuracy_metrics(sol, truth_at(t, x, sol.t_s))
    return {"status": s["integrity"]["status"], "reasons": s["integrity"]["reasons"],
            "position_rms_m": a["position_rms_m"], "nees_mean": a["nees_mean"]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--fault-seeds", type=int, default=10)
    ap.add_argument("--methods", default="batch,isam2,fixed-lag,ekf")
    ap.add_argument("--out", default=".")
    args = ap.parse_args(argv)
    results = {"clean": {}, "faults": {}}
    t0 = time.perf_counter()
    for method in args.methods.split(","):
        rows = [run_case(F.clean(seed=s, **ONE_HOUR), method) for s in range(args.seeds)]
        results["clean"][method] = rows
        print(f"clean {method}: {sum(r['status'] != 'ok' for r in rows)} alarms / {len(rows)}"
              f" ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    for name, spec in FAULTS.items():
        make, options = spec if isinstance(spec, tuple) else (spec, SmootherOptions())
        rows = [run_case(make(s), "batch", options) for s in range(args.fault_seeds)]
        results["faults"][name] = rows
        print(f"{name}: {[r['status'] for r in rows]} ({time.perf_counter() - t0:.0f} s)",
              file=sys.stderr)
    print("| case | method | runs | not ok | failed | refused (exit 2) | median NEES of the 'ok' runs |")
    print("|---|---|---|---|---|---|---|")
    for group, table in (("clean", results["clean"]), ("fault", results["faults"])):
        for name, rows in table.items():
            method = name if group == "clean" else "batch"
            label = "clean 1 h gto-transfer" if group == "clean" else name
            st = [r["status"] for r in rows]
            ok_nees = [r["nees_mean"] for r in rows if r["status"] == "ok"]
            med = f"{np.median(ok_nees):.3g}" if ok_nees else "-"
            print(f"| {label} | {method} | {len(rows)} | {sum(s != 'ok' for s in st)} | "
                  f"{st.count('failed')} | {st.count('refused')} | {med} |")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "integrity_study.json").write_text(json.dumps(results, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
