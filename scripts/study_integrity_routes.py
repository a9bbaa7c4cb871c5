#!/usr/bin/env python
"""Detection and false-alarm rates of the integrity verdict on the routes added last.

    python scripts/study_integrity_routes.py [--seeds 20] [--fault-seeds 10]
        [--routes formation,attitude,cruise,sextant] [--jobs 2] [--out DIR]

The integrity issue asks for the table of docs/integrity.md (there: 1 h gto-transfer,
``scripts/study_integrity.py``) on the formation, attitude (batch, isam2, fixed-lag, EKF;
random-walk and constant-rate), cruise and sextant routes. Each run goes through the command
line as a user's would: ``fgnav simulate`` (seeded), a fault made by editing the log or by a
smoother option, ``fgnav smooth --truth``. Clean runs over ``--seeds`` seeds give the false
alarms (verdict not ``ok``); each fault over ``--fault-seeds`` seeds gives the detections.
A run is *confidently wrong* when its verdict is ``ok`` while its error against the
simulator's truth (DOP853) is far outside its covariance: mean NEES above 3x the state's
dimension (orbit 6, relative 6, attitude 3). Prints a Markdown table and writes
``DIR/integrity_routes.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from fgnav.cli import main as fgnav_main

NEES_LIMIT = {"orbit": 18.0, "relative": 18.0, "attitude": 9.0}
"""Mean NEES above which an ``ok`` verdict is a confident wrong answer (3x the dimension)."""


def _head_rows(lines: list[str]) -> tuple[list[str], list[str]]:
    head = [ln for ln in lines if ln.startswith("#") or ln.startswith("epoch,")]
    return head, [ln for ln in lines if ln and ln not in head]


def only_antenna(antenna: str) -> Callable[[list[str], int], list[str]]:
    """Links received through ``antenna`` only (one link each way per epoch)."""
    others = {"rx1", "rx2", "rx3"} - {antenna}
    return lambda lines, seed: [ln for ln in lines if not any(f",{o}," in ln for o in others)]


def flipped_lever_arm(lines: list[str], seed: int) -> list[str]:
    """``# antenna: sat2 tx0`` with its lever arm's signs flipped (the log's geometry wrong)."""
    out = []
    for ln in lines:
        if ln.startswith("# antenna: sat2 tx0 "):
            xyz = [-float(v) for v in ln.split()[4:7]]
            ln = "# antenna: sat2 tx0 " + " ".join(f"{v:g}" for v in xyz)
        out.append(ln)
    return out


def links_first_epoch_only(lines: list[str], seed: int) -> list[str]:
    """Inter-satellite links at the first epoch only."""
    head, rows = _head_rows(lines)
    link = [r for r in rows if r.split(",")[1].startswith("isl_")]
    t0 = min(r.split(",", 1)[0] for r in link)
    return head + [r for r in rows if not r.split(",")[1].startswith("isl_")
                   or r.split(",", 1)[0] == t0]


def sparse_stars(every: int) -> Callable[[list[str], int], list[str]]:
    """Star rows kept at one epoch in ``every``."""
    def edit(lines, seed):
        head, rows = _head_rows(lines)
        epochs = sorted({r.split(",", 1)[0] for r in rows})
        keep = set(epochs[::every])
        return head + [r for r in rows if r.split(",")[1] != "star_direction_body"
                       or r.split(",", 1)[0] in keep]
    return edit


def outliers(fraction: float, offset_rad: float) -> Callable[[list[str], int], list[str]]:
    """``fraction`` of the angle rows (seeded choice) offset by ``offset_rad``."""
    def edit(lines, seed):
        rng = np.random.default_rng(1000 + seed)
        out = []
        for ln in lines:
            f = ln.split(",")
            if len(f) > 2 and f[1].endswith("_angle") and rng.random() < fraction:
                f[2] = repr(float(f[2]) + offset_rad)
                ln = ",".join(f)
            out.append(ln)
        return out
    return edit


def without_centre_line(lines: list[str], seed: int) -> list[str]:
    """The heliocentric log's ``# centre: sun`` line deleted."""
    return [ln for ln in lines if ln.strip() != "# centre: sun"]


@dataclass(frozen=True)
class Case:
    route: str
    label: str
    scenario: str
    simulate: tuple[str, ...]
    smooth: tuple[str, ...]
    fault: bool = False
    edit: Callable[[list[str], int], list[str]] | None = None
    states: tuple[str, ...] = ("orbit",)
    seeds_offset: int = 0
    methods: tuple[str, ...] = ("batch",)
    extra: dict = field(default_factory=dict)


FORMATION = ("--duration-h", "1", "--step-s", "60")
RAW_STARS = ("--raw-stars", "--duration-h", "2")
ATT = ("--attitude", "estimate", "--third-body")
CRUISE = ("--duration-h", "168")
SEXTANT = ("--duration-h", "1")
ALL4 = ("batch", "isam2", "fixed-lag", "ekf")

CASES = [
    Case("formation", "clean formation-gto 1 h", "formation-gto", FORMATION, (),
         states=("orbit", "relative"), methods=ALL4),
    Case("formation", "clean formation-gto-3 1 h at 30 s", "formation-gto-3",
         ("--duration-h", "1", "--step-s", "30"), (), states=("orbit", "relative"),
         methods=("batch",)),
    Case("formation", "links through rx1 only", "formation-gto", FORMATION, (), True,
         only_antenna("rx1"), ("orbit", "relative")),
    Case("formation", "links through rx3 only", "formation-gto", FORMATION, (), True,
         only_antenna("rx3"), ("orbit", "relative")),
    Case("formation", "sat2 tx0 lever arm flipped", "formation-gto", FORMATION, (), True,
         flipped_lever_arm, ("orbit", "relative")),
    Case("formation", "links at the first epoch only", "formation-gto", FORMATION, (), True,
         links_first_epoch_only, ("orbit", "relative")),
    Case("attitude", "clean geo-limb raw stars 2 h, random walk", "geo-limb", RAW_STARS, ATT,
         states=("orbit", "attitude"), methods=ALL4),
    Case("attitude", "clean geo-limb raw stars 2 h, constant rate", "geo-limb", RAW_STARS,
         ATT + ("--attitude-motion", "constant-rate"), states=("orbit", "attitude"),
         methods=ALL4),
    Case("attitude", "stars 1 epoch in 20, constant rate", "geo-limb", RAW_STARS,
         ATT + ("--attitude-motion", "constant-rate"), True, sparse_stars(20),
         ("orbit", "attitude"), methods=("batch", "ekf")),
    Case("attitude", "camera mounting 60 arcsec (1 sigma), not estimated", "geo-limb",
         RAW_STARS + ("--star-mounting-sigma-arcsec", "60"), ATT, True, None,
         ("orbit", "attitude")),
    Case("cruise", "clean mars-cruise 1 week", "mars-cruise", CRUISE, (),
         methods=("batch", "isam2", "ekf")),
    Case("cruise", "--no-aberration", "mars-cruise", CRUISE, ("--no-aberration",), True),
    Case("cruise", "'# centre: sun' deleted", "mars-cruise", CRUISE, (), True,
         without_centre_line),
    Case("sextant", "clean sextant-leo 1 h", "sextant-leo", SEXTANT, (), methods=ALL4),
    Case("sextant", "5 % of the angles 0.05 rad off", "sextant-leo", SEXTANT, (), True,
         outliers(0.05, 0.05)),
]


def _nees(summary: dict, state: str) -> float | None:
    if state == "orbit":
        return summary.get("nees_mean")
    if state == "relative":   # the worst pair of three spacecraft or more
        pairs = summary.get("relative_pairs") or [summary.get("relative") or {}]
        values = [d["nees_mean"] for d in pairs if d.get("nees_mean") is not None]
        return max(values) if values else None
    return ((summary.get("variables") or {}).get("attitude") or {}).get("nees_mean")


def run_one(case: Case, method: str, seed: int, work: str) -> dict:
    """Simulate, edit, smooth one run in ``work``; its verdict and NEES against truth."""
    sim = Path(work) / f"{case.scenario}-{'-'.join(case.simulate)}-{seed}".replace("--", "")
    if not (sim / "measurements.csv").exists():
        tmp = Path(tempfile.mkdtemp(dir=work))
        rc = fgnav_main(["simulate", case.scenario, "--out", str(tmp), "--seed", str(seed),
                         "--quiet", *case.simulate])
        if rc != 0:
            return {"outcome": "simulate failed", "rc": rc}
        try:
            tmp.rename(sim)
        except OSError:   # another worker made it meanwhile
            shutil.rmtree(tmp, ignore_errors=True)
    lines = (sim / "measurements.csv").read_text().splitlines()
    run = Path(tempfile.mkdtemp(dir=work))
    log = run / "measurements.csv"
    log.write_text("\n".join(case.edit(lines, seed) if case.edit else lines) + "\n")
    truth = str(sim) if "relative" in case.states else str(sim / "truth.oem")
    t0 = time.perf_counter()
    rc = fgnav_main(["smooth", str(log), "--out", str(run / "r"), "--truth", truth, "--method",
                     method, "--quiet", *case.smooth])
    wall = time.perf_counter() - t0
    if rc == 2:
        return {"outcome": "refused", "rc": rc, "wall_s": wall}
    summary_path = run / "r" / "summary.json"
    if not summary_path.exists():
        return {"outcome": "no output", "rc": rc, "wall_s": wall}
    s = json.loads(summary_path.read_text())
    status = s["integrity"]["status"]
    nees = {st: _nees(s, st) for st in case.states}
    wrong = status == "ok" and any(v is not None and v > NEES_LIMIT[st] for st, v in nees.items())
    shutil.rmtree(run, ignore_errors=True)
    return {"outcome": status, "rc": rc, "nees": nees, "confidently_wrong": wrong,
            "wall_s": wall}


def _task(args):
    case_index, method, seed, work = args
    try:
        return case_index, method, seed, run_one(CASES[case_index], method, seed, work)
    except Exception as exc:  # noqa: BLE001 - a traceback is an outcome the study counts
        return case_index, method, seed, {"outcome": "traceback",
                                          "error": f"{type(exc).__name__}: {exc}"[:300]}


def _median(values):
    v = sorted(x for x in values if x is not None)
    return v[len(v) // 2] if v else None


def table(results: list[dict]) -> str:
    rows = ["| route | case | method | runs | not ok | failed | refused (exit 2) | "
            "confidently wrong | tracebacks | median NEES of the 'ok' runs |",
            "|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        runs = r["runs"]
        ok = [x for x in runs if x["outcome"] == "ok"]
        med = {st: _median([x["nees"].get(st) for x in ok]) for st in r["states"]}
        nees = ", ".join(f"{st} {v:.3g}" for st, v in med.items() if v is not None) or "-"
        rows.append(
            f"| {r['route']} | {r['label']} | {r['method']} | {len(runs)} | "
            f"{sum(x['outcome'] in ('suspect', 'failed') for x in runs)} | "
            f"{sum(x['outcome'] == 'failed' for x in runs)} | "
            f"{sum(x['outcome'] == 'refused' for x in runs)} | "
            f"{sum(bool(x.get('confidently_wrong')) for x in runs)} | "
            f"{sum(x['outcome'] in ('traceback', 'no output', 'simulate failed') for x in runs)}"
            f" | {nees} |")
    return "\n".join(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--fault-seeds", type=int, default=10)
    ap.add_argument("--routes", default="formation,attitude,cruise,sextant")
    ap.add_argument("--jobs", type=int, default=max(1, (os.cpu_count() or 1)))
    ap.add_argument("--out", default=".")
    args = ap.parse_args(argv)
    routes = set(args.routes.split(","))
    work = tempfile.mkdtemp(prefix="fgnav-routes-")
    tasks = [(i, m, s, work) for i, c in enumerate(CASES) if c.route in routes
             for m in c.methods for s in range(args.fault_seeds if c.fault else args.seeds)]
    t0 = time.perf_counter()
    out: dict[tuple[int, str], list] = {}
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        for n, (i, m, s, res) in enumerate(pool.map(_task, tasks), 1):
            out.setdefault((i, m), []).append({"seed": s, **res})
            print(f"\r{n}/{len(tasks)} runs, {time.perf_counter() - t0:.0f} s", end="",
                  file=sys.stderr, flush=True)
    print(file=sys.stderr)
    shutil.rmtree(work, ignore_errors=True)
    results = [{"route": CASES[i].route, "label": CASES[i].label, "method": m,
                "fault": CASES[i].fault, "states": list(CASES[i].states), "runs": runs}
               for (i, m), runs in out.items()]
    md = table(results)
    print(md)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / "integrity_routes.json").write_text(json.dumps(
        {"seeds": args.seeds, "fault_seeds": args.fault_seeds,
         "wall_s": time.perf_counter() - t0, "results": results}, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
