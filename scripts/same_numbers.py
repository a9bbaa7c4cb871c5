#!/usr/bin/env python
"""Same numbers before and after a restructuring: every built-in scenario x every method.

    python scripts/same_numbers.py --before DIR_A --after DIR_B [--out table.md]
                                   [--cases gto-transfer/batch,...] [--rtol 1e-9]

``DIR_A`` and ``DIR_B`` are checkouts (e.g. ``git worktree add /tmp/before 35fdd05``). Each
case is simulated and smoothed by each tree's own code (``python -m fgnav`` with the tree first
on ``PYTHONPATH``), one case after the other, in one run. A case is the *same* when
``trajectory.oem`` (or each ``trajectory-<id>.oem`` of a formation) is identical apart from
``CREATION_DATE``; otherwise it is *close* when position RMS, NEES, bound and chi-square of
``summary.json`` agree within ``--rtol`` relative; the verdict and the exit code must be
identical in every case. Prints a Markdown table (also to ``--out``) and exits 1 when any case
differs beyond the tolerance.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# (scenario, simulate arguments, [(method label, smooth arguments)])
_SHORT = ["--duration-h", "1"]
_METHODS = [("batch", ["--method", "batch"]), ("isam2", ["--method", "isam2"]),
            ("fixed-lag", ["--method", "fixed-lag"]), ("ekf", ["--method", "ekf"])]
CASES = [
    ("gto-transfer", _SHORT, _METHODS),
    ("geo-limb", ["--duration-h", "2"], _METHODS),
    ("leo-sun-earth-moon", _SHORT, _METHODS),
    ("refraction-leo", _SHORT, _METHODS),
    ("refraction-leo-bias", _SHORT,
     _METHODS + [("batch-bias", ["--method", "batch", "--estimate", "refraction-bias"])]),
    ("sextant-leo", ["--duration-h", "2"], _METHODS),
    ("mars-cruise", ["--duration-h", "168"], _METHODS),
    ("geo-limb-raw", ["--duration-h", "1", "--raw-stars"],
     [(m, a + ["--estimate", "attitude", "--third-body"]) for m, a in _METHODS]),
    ("formation-gto", ["--duration-h", "1", "--step-s", "60"], _METHODS),
    ("constellation-leo", ["--duration-h", "1"], _METHODS),
    ("formation-cruise", ["--duration-h", "168"], _METHODS[:3]),   # (ekf: no prior rows)
]
SCENARIO_OF = {"geo-limb-raw": "geo-limb"}
# summary.json figures compared when the trajectories are not byte-identical
FIGURES = ("position_rms_m", "nees_mean", "crb_position_rms_m", "sigma_position_rms_m",
           "chi2", "chi2_dof")


def _run(tree: Path, args: list[str], cwd: Path, log: Path) -> int:
    env = dict(os.environ, PYTHONPATH=str(tree), PYTHONHASHSEED="0")
    with open(log, "ab") as f:
        f.write(("$ fgnav " + " ".join(args) + "\n").encode())
        return subprocess.run([sys.executable, "-m", "fgnav", *args], cwd=cwd, env=env,
                              stdout=f, stderr=subprocess.STDOUT, timeout=3600).returncode


def _trajectories(result: Path) -> dict[str, str]:
    out = {}
    for p in sorted(result.glob("trajectory*.oem")):
        text = re.sub(r"^CREATION_DATE\s*=.*$", "", p.read_text(), flags=re.M)
        out[p.name] = text
    return out


def _figures(summary: dict, prefix: str = "") -> dict[str, float]:
    """Every numeric leaf whose key names one of FIGURES (nested keys joined by '.')."""
    out = {}
    for k, v in summary.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_figures(v, name + "."))
        elif isinstance(v, (int, float)) and not isinstance(v, bool) and \
                any(f in k for f in FIGURES):
            out[name] = float(v)
    return out


def _verdict(summary: dict) -> str | None:
    integ = summary.get("integrity")
    return integ.get("status") if isinstance(integ, dict) else summary.get("verdict")


def _case(tree: Path, work: Path, scen: str, sim: list[str], label: str, smooth: list[str],
          log: Path) -> dict:
    name = SCENARIO_OF.get(scen, scen)
    pdir = work / scen / "pass"
    if not pdir.exists():
        rc = _run(tree, ["simulate", name, "--out", str(pdir), "--quiet", *sim], work, log)
        if rc != 0:
            return {"simulate_rc": rc}
    rdir = work / scen / label
    truth = sorted(pdir.glob("truth*.oem"))
    # a formation's truth is the folder of its truth-<id>.oem files
    targs = ["--truth", str(truth[0] if len(truth) == 1 else pdir)] if truth else []
    t0 = time.perf_counter()
    rc = _run(tree, ["smooth", str(pdir / "measurements.csv"), "--out", str(rdir), *targs,
                     *smooth], work, log)
    wall = time.perf_counter() - t0
    summary = {}
    if (rdir / "summary.json").exists():
        summary = json.loads((rdir / "summary.json").read_text())
    return {"rc": rc, "wall_s": wall, "traj": _trajectories(rdir), "figures": _figures(summary),
            "verdict": _verdict(summary),
            "measurements": (pdir / "measurements.csv").read_bytes()
            if (pdir / "measurements.csv").exists() else b""}


def _compare(a: dict, b: dict, rtol: float) -> tuple[str, str]:
    if a.get("simulate_rc") or b.get("simulate_rc"):
        same = a.get("simulate_rc") == b.get("simulate_rc")
        return ("same" if same else "DIFFERENT"), f"simulate exit {a.get('simulate_rc')} / " \
                                                  f"{b.get('simulate_rc')}"
    notes = []
    if a["measurements"] != b["measurements"]:
        return "DIFFERENT", "simulated logs differ"
    if a["rc"] != b["rc"]:
        return "DIFFERENT", f"exit {a['rc']} / {b['rc']}"
    if a["verdict"] != b["verdict"]:
        return "DIFFERENT", f"verdict {a['verdict']} / {b['verdict']}"
    if a["traj"] and a["traj"] == b["traj"]:
        return "same", "trajectory identical"
    if a["traj"].keys() != b["traj"].keys():
        return "DIFFERENT", f"outputs {sorted(a['traj'])} / {sorted(b['traj'])}"
    worst = 0.0
    for k in sorted(set(a["figures"]) | set(b["figures"])):
        x, y = a["figures"].get(k), b["figures"].get(k)
        if x is None or y is None:
            return "DIFFERENT", f"{k} missing on one side"
        if math.isnan(x) and math.isnan(y):
            continue
        rel = abs(x - y) / max(abs(x), abs(y), 1e-300)
        worst = max(worst, rel)
        if rel > rtol:
            notes.append(f"{k} {x:.12g} / {y:.12g}")
    if notes:
        return "DIFFERENT", "; ".join(notes[:3])
    return "close", f"figures within {worst:.1e} relative"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", required=True, type=Path)
    ap.add_argument("--after", required=True, type=Path)
    ap.add_argument("--cases", help="comma-separated scenario/method (default: all)")
    ap.add_argument("--rtol", type=float, default=1e-9)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--keep", type=Path, help="keep the outputs under this directory")
    args = ap.parse_args(argv)
    wanted = set(args.cases.split(",")) if args.cases else None
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="same-numbers-"))
    trees = {"before": args.before.resolve(), "after": args.after.resolve()}
    rows, bad = [], 0
    for scen, sim, methods in CASES:
        for label, smooth in methods:
            if wanted and f"{scen}/{label}" not in wanted and scen not in wanted:
                continue
            res = {}
            for side, tree in trees.items():
                work = root / side
                work.mkdir(parents=True, exist_ok=True)
                res[side] = _case(tree, work, scen, sim, label, smooth, root / f"{side}.log")
            status, note = _compare(res["before"], res["after"], args.rtol)
            bad += status == "DIFFERENT"
            a, b = res["before"], res["after"]
            row = (f"| {scen} | {label} | {a.get('rc', '-')} / {b.get('rc', '-')} | "
                   f"{a.get('verdict')} / {b.get('verdict')} | "
                   f"{a.get('wall_s', 0):.1f} / {b.get('wall_s', 0):.1f} | {status} | {note} |")
            print(row, flush=True)
            rows.append(row)
    table = ["| scenario | method | exit | verdict | wall s | result | detail |",
             "|---|---|---|---|---|---|---|", *rows]
    text = "\n".join(table) + f"\n\n{len(rows) - bad} of {len(rows)} cases the same or close " \
                              f"(rtol {args.rtol:g}).\n"
    print(text)
    if args.out:
        args.out.write_text(text)
    if not args.keep:
        shutil.rmtree(root, ignore_errors=True)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
