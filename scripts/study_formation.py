"""Formations from logged data: absolute and relative accuracy over seeds, against the bound.

    PYTHONPATH=$PWD python scripts/study_formation.py [--seeds 10] [--quick] [--isam2]
                                                      [--out docs/formation.md] [--json FILE]

On both formation scenarios (``formation-gto``: two spacecraft 1 km apart on a transfer
orbit, six 1 cm antenna-to-antenna pseudoranges; ``constellation-leo``: two LEO spacecraft
in planes 10 deg apart, two 1 m centre-to-centre ranges), each seed's pass is simulated
once (:func:`fgnav.simulate.formation_sim.simulate_formation_pass`, truth from the
independent DOP853 integrator) and smoothed (``--method batch``) three ways:

* **celestial alone**: the log without its inter-satellite rows (the joint graph without
  links, whose blocks decouple: each spacecraft's own solution);
* **celestial + links** (pseudoranges);
* **celestial + links + carrier phase** (formation-gto: 10 um carrier rows, a float
  ambiguity per link, drawn after the code rows so the code rows are the same).

Per spacecraft: the position RMS error against truth over the pass, averaged over the
seeds as a root mean square, beside the Cramér–Rao bound of the same problem: the dense
information of every whitened row (measurements, priors, the process rows of every orbit
and clock) linearized at the truth (Kay 1993, *Fundamentals of Statistical Signal
Processing: Estimation Theory*, eq. 3.30; with the process rows the Bayesian bound of
Van Trees 1968, *Detection, Estimation and Modulation Theory* I, sec. 2.4). The bound does
not depend on the seed (the truth, the epochs and the sigmas do not; the links are linear
in the clock and the ambiguities, so their values do not enter). It is computed two ways
from the same rows: :func:`fgnav.formation.dense_bound.dense_bound` (the inverse of the
normal equations ``A^T A``) and here by a dense QR factorization of the stacked ``A``
(``(R^T R)^-1``, Golub & Van Loan 2013, *Matrix Computations*, sec. 5.3: the normal
equations square the condition number, QR does not); the tables give the QR figure and the
ratio of the two, so a disagreement is visible.

Relative state (the second spacecraft in the first's LVLH frame, from the joint marginals):
RMS position error, the RMS of its range component, the mean NEES (6 dof, Cartesian
position and velocity) and the mean spherical position NEES (3 dof, range/azimuth/
elevation: :func:`fgnav.results.spherical_position_nees`), with the 95 % band of
the mean over the seeds taking each pass's mean as one chi-square sample (its epochs are
strongly correlated; the band is then chi2(S d) / S for S seeds, d dof -- the widest
plausible one: outside it the covariance is inconsistent whatever the correlation).

Dense bound size: at most 6000 unknowns, so the passes are formation-gto's full 4 h at a
60 s step (241 epochs x 13 unknowns, 19 with carrier ambiguities) and constellation-leo's
full 6 h at its own 60 s step (361 x 13). ``--quick``: 3 seeds, formation-gto 2 h and
constellation-leo 3 h (the conclusions the slow test asserts hold there too). ``--isam2``:
also ``--method isam2`` on the celestial-alone and pseudorange cases (not on the carrier
case, to bound the study's time: iSAM2 took 130 s on one formation-gto pseudorange pass on
the shared 2-core machine, its links relinearized at 1.4 m,
:func:`fgnav.formation.joint.relinearizing_links`, 45 mm with carrier phase).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from factors.pseudorange import cartesian_to_spherical
from fgnav.formation.dense_bound import dense_bound
from fgnav.results import relative_rows
from fgnav.frames import relative_covariance, relative_state_lvlh
from fgnav.io.log_spacecraft import ISL_KINDS
from fgnav.measurements import build_pass
from fgnav.pipeline import smooth_log, summarize
from fgnav.scenarios import load_scenario
from fgnav.simulate.formation_sim import simulate_formation_pass
from fgnav.solvers.options import SmootherOptions

CARRIER_SIGMA_M = 1e-5
"""Carrier-phase noise (m) switched on for formation-gto (Xing et al.'s ref. [1], 10 um)."""

CASES = {   # scenario -> (duration_h, step_s) full and --quick, carrier phase studied
    "formation-gto": {"full": (4.0, 60.0), "quick": (2.0, 60.0), "carrier": True},
    "constellation-leo": {"full": (6.0, 60.0), "quick": (3.0, 60.0), "carrier": False},
}
LINKS = ("alone", "links", "carrier")
LABEL = {"alone": "celestial alone", "links": "celestial + pseudoranges",
         "carrier": "celestial + pseudoranges + carrier phase"}


def without_links(log):
    """The log without its inter-satellite rows (same spacecraft, same other rows)."""
    keep = ~np.isin(np.asarray(log.kind).astype(str), ISL_KINDS)
    return replace(log, t_s=log.t_s[keep], kind=np.asarray(log.kind)[keep], xyz=log.xyz[keep],
                   sigma=log.sigma[keep], line=np.asarray(log.line)[keep],
                   extra={c: v[keep] for c, v in log.extra.items()})


def with_carrier(scn):
    """The scenario with carrier-phase rows on every link."""
    f = scn.formation
    return replace(scn, formation=replace(f, ranging=replace(f.ranging,
                                                             carrier_sigma_m=CARRIER_SIGMA_M)))


def truth_blocks(p, sim) -> np.ndarray:
    """The pass's block values (N, n) at the truth: each orbit from the simulation, the
    clock and the ambiguities at their prior mean (the rows are linear in them)."""
    lay = p.layout
    idx = np.searchsorted(sim.t_s, p.t_s)
    assert np.allclose(sim.t_s[idx], p.t_s)
    X = lay.initial(sim.x_true[sim.ids[0]][idx])
    for s, v in enumerate(lay.orbits):
        X[:, lay.slices[v.name]] = sim.x_true[sim.ids[s]][idx]
    return X


def qr_bound(p, X_true: np.ndarray, options) -> np.ndarray:
    """Per-epoch bound (N, n, n) from a dense QR factorization of every whitened row of the
    pass at ``X_true`` (:func:`fgnav.formation.dense_bound.dense_bound`)."""
    return dense_bound(p, X_true, options)


def _pos_rms_sigma(C, sl) -> float:
    """RMS over the epochs of the 3-D position sigma of the block slice ``sl``."""
    ms = float(np.mean(np.trace(C[:, sl, sl][:, :3, :3], axis1=1, axis2=2)))
    return float(np.sqrt(ms)) if ms >= 0 else float("nan")   # (a failed inverse: NaN)


def bounds(p, sim, options) -> dict:
    """Per spacecraft and for the relative position: the QR bound and dense_bound's figure
    (RMS 3-D position sigma over the pass, m)."""
    X = truth_blocks(p, sim)
    lay = p.layout
    out = {"unknowns": int(X.size)}
    t = time.perf_counter()
    Cq = qr_bound(p, X, options)
    out["qr_s"] = time.perf_counter() - t
    t = time.perf_counter()
    Cd = dense_bound(p, X, options)
    out["dense_bound_s"] = time.perf_counter() - t
    s0, s1 = lay.slices[lay.orbits[0].name], lay.slices[lay.orbits[1].name]
    _, J_c, J_d = relative_state_lvlh(X[:, s0], X[:, s1])
    for name, C in (("qr", Cq), ("dense_bound", Cd)):
        d = {sim.ids[s]: _pos_rms_sigma(C, lay.slices[v.name]) for s, v in enumerate(lay.orbits)}
        idx = np.r_[np.arange(s0.start, s0.stop), np.arange(s1.start, s1.stop)]
        rel = relative_covariance(J_c, J_d, C[:, idx[:, None], idx[None, :]])
        d["relative"] = _pos_rms_sigma(rel, slice(0, 6))   # LVLH, as the smoother's
        d["negative_variances"] = int(np.sum(np.diagonal(C, axis1=1, axis2=2) < 0))
        out[name] = d
    return out


def relative_metrics(res, p, sim) -> dict:
    """Relative position RMS (LVLH, m), its range component's RMS (m) and the NEES."""
    sol = res.solution
    rel, C, _ = relative_rows(sol, p, 1)
    idx = np.searchsorted(sim.t_s, sol.t_s)
    rel_true = relative_state_lvlh(sim.x_true[sim.ids[0]][idx], sim.x_true[sim.ids[1]][idx])[0]
    err = rel[:, :3] - rel_true[:, :3]
    dr = cartesian_to_spherical(rel[:, :3])[:, 0] - cartesian_to_spherical(rel_true[:, :3])[:, 0]
    return {"position_ms_m2": float(np.mean(np.sum(err ** 2, axis=1))),
            "range_ms_m2": float(np.mean(dr ** 2))}


def run_seed(name, scn, seed, methods, options) -> dict:
    """One seed of one scenario: every link case and method, the summaries' figures."""
    out = {}
    sims = {"links": simulate_formation_pass(scn, seed)}
    sims["alone"] = sims["links"]
    if CASES[name]["carrier"]:
        sims["carrier"] = simulate_formation_pass(with_carrier(scn), seed)
    for case, sim in sims.items():
        log = without_links(sim.log) if case == "alone" else sim.log
        truths = [(sim.t_s, sim.x_true[i]) for i in sim.ids]
        for method in methods:
            if method != "batch" and case == "carrier":
                continue   # (time: module docstring)
            t = time.perf_counter()
            res, p = smooth_log(log, method, options)
            wall = time.perf_counter() - t
            s = summarize(res.solution, p, options, truths=truths)
            d = {"wall_s": wall, "iterations": s["iterations"],
                 "integrity": s["integrity"]["status"], "reasons": s["integrity"]["reasons"],
                 "spacecraft": {i: {k: s["spacecraft"][i][k] for k in
                                    ("position_rms_m", "nees_mean", "sigma_position_rms_m")}
                                for i in sim.ids}}
            if case != "alone":
                d["relative"] = {k: s["relative"][k] for k in
                                 ("position_rms_m", "nees_mean", "nees_position_spherical_mean",
                                  "sigma_position_rms_m")}
                d["relative"].update(relative_metrics(res, p, sim))
            out[f"{case}/{method}"] = d
    return out, sims


def study(seeds, quick=False, methods=("batch",), log=print) -> dict:
    options = SmootherOptions()
    result = {"seeds": list(seeds), "methods": list(methods), "quick": quick,
              "carrier_sigma_m": CARRIER_SIGMA_M, "scenarios": {}}
    for name, case in CASES.items():
        dur, step = case["quick" if quick else "full"]
        scn = load_scenario(name).with_options(duration_h=dur, step_s=step)
        r = {"duration_h": dur, "step_s": step, "ids": None, "runs": [], "bounds": {}}
        for seed in seeds:
            t = time.perf_counter()
            runs, sims = run_seed(name, scn, seed, methods, options)
            r["runs"].append(runs)
            r["ids"] = list(sims["links"].ids)
            log(f"{name} seed {seed}: {time.perf_counter() - t:.0f} s")
            if seed == seeds[0]:   # the bound does not depend on the seed
                for c, sim in sims.items():
                    lg = without_links(sim.log) if c == "alone" else sim.log
                    r["bounds"][c] = bounds(build_pass(lg), sim, options)
                    log(f"{name} bound {c}: {r['bounds'][c]['unknowns']} unknowns, "
                        f"QR {r['bounds'][c]['qr_s']:.0f} s")
        result["scenarios"][name] = r
    return result


def aggregate(result) -> dict:
    """Per scenario, case and method: seed-averaged figures (RMS errors as root mean squares
    over the seeds, NEES as means) and the NEES bands."""
    S = len(result["seeds"])
    out = {}
    for name, r in result["scenarios"].items():
        agg = {}
        for key in r["runs"][0]:
            runs = [run[key] for run in r["runs"]]
            d = {"wall_s_median": float(np.median([x["wall_s"] for x in runs])),
                 "integrity_ok": sum(x["integrity"] == "ok" for x in runs),
                 "spacecraft": {}}
            for i in r["ids"]:
                sc = [x["spacecraft"][i] for x in runs]
                d["spacecraft"][i] = {
                    "position_rms_m": float(np.sqrt(np.mean([x["position_rms_m"] ** 2 for x in sc]))),
                    "sigma_position_rms_m": float(np.sqrt(np.mean([x["sigma_position_rms_m"] ** 2
                                                                   for x in sc]))),
                    "nees_mean": float(np.mean([x["nees_mean"] for x in sc]))}
            if "relative" in runs[0]:
                rel = [x["relative"] for x in runs]
                d["relative"] = {
                    "position_rms_m": float(np.sqrt(np.mean([x["position_ms_m2"] for x in rel]))),
                    "range_rms_m": float(np.sqrt(np.mean([x["range_ms_m2"] for x in rel]))),
                    "sigma_position_rms_m": float(np.sqrt(np.mean([x["sigma_position_rms_m"] ** 2
                                                                   for x in rel]))),
                    "nees_mean": float(np.mean([x["nees_mean"] for x in rel])),
                    "nees_position_spherical_mean": float(np.mean(
                        [x["nees_position_spherical_mean"] for x in rel])),
                    "nees_per_seed": [x["nees_mean"] for x in rel],
                    "nees_spherical_per_seed": [x["nees_position_spherical_mean"] for x in rel]}
            agg[key] = d
        out[name] = agg
    out["nees_band_6"] = nees_band(6, S)
    out["nees_band_3"] = nees_band(3, S)
    return out


def nees_band(dof: int, seeds: int) -> list:
    """95 % band of the mean over ``seeds`` passes of a ``dof``-dof NEES, each pass's mean
    taken as one chi-square sample: chi2(seeds dof) / seeds."""
    return [float(chi2.ppf(q, seeds * dof) / seeds) for q in (0.025, 0.975)]


def _m(x):
    """Metres with a readable unit."""
    if x >= 1:
        return f"{x:,.3g} m" if x < 1000 else f"{x:,.0f} m"
    if x >= 1e-2:
        return f"{x * 100:.3g} cm"
    if x >= 1e-3:
        return f"{x * 1e3:.3g} mm"
    return f"{x * 1e6:.3g} um"


def _ordered(a: dict):
    """(key, figures) in the order celestial alone, links, carrier; methods as given."""
    return sorted(a.items(), key=lambda kv: LINKS.index(kv[0].split("/")[0]))


def markdown(result, agg, command) -> str:
    S = len(result["seeds"])
    methods = result["methods"]
    lines = ["# Formations from logs: what one graph gives", "",
             "Measured by `scripts/study_formation.py` (module docstring: the cases, the bound, "
             "the bands). Reproduce with:", "", "```", command, "```", "",
             f"{S} seeds ({result['seeds'][0]}..{result['seeds'][-1]}), `--method "
             f"{' / '.join(methods)}`, default smoother options (process noise "
             f"{SmootherOptions().q_m2_s3:g} m^2/s^3). Errors against the truth of the "
             "independent DOP853 integrator; RMS over every epoch of the pass and over the "
             "seeds. The bound is the Cramér–Rao bound of the same problem at the truth "
             "(dense information of every whitened row, one for all seeds), as the RMS of "
             "the 3-D position sigma over the pass; `dense_bound / QR` compares "
             "`fgnav.formation.dense_bound` (inverse of the normal equations) with the dense "
             "QR factorization of the same rows."
             + (" `isam2` rows: the final trajectory of `--method isam2` (its chain polished "
                "at the end, so batch's figures wherever both reach the same minimum)."
                if "isam2" in methods else ""), ""]
    for name, r in result["scenarios"].items():
        a = agg[name]
        lines += [f"## {name} ({r['duration_h']:g} h at {r['step_s']:g} s)", "",
                  "### Absolute position, per spacecraft", "",
                  "| rows | method | spacecraft | position RMS | bound (QR) | RMS / bound "
                  "| dense_bound / QR | smoother sigma | NEES (6 dof) | verdict ok |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for key, d in _ordered(a):
            case, method = key.split("/")
            b = r["bounds"][case]
            for i in r["ids"]:
                sc = d["spacecraft"][i]
                ratio = b["dense_bound"][i] / b["qr"][i] if b["dense_bound"][i] == b["dense_bound"][i] \
                    else float("nan")
                neg = b["dense_bound"]["negative_variances"]
                lines.append(f"| {LABEL[case]} | {method} | {i} | {_m(sc['position_rms_m'])} | "
                             f"{_m(b['qr'][i])} | {sc['position_rms_m'] / b['qr'][i]:.2f} | "
                             f"{ratio:.3g}{f' ({neg} negative variances)' if neg else ''} | "
                             f"{_m(sc['sigma_position_rms_m'])} | {sc['nees_mean']:.2f} | "
                             f"{d['integrity_ok']}/{S} |")
        lines += ["", "### Relative state (second spacecraft in the first's LVLH frame)", "",
                  "| rows | method | position RMS | range RMS | bound (QR) | smoother sigma "
                  "| NEES (6 dof) | spherical position NEES (3 dof) |",
                  "|---|---|---|---|---|---|---|---|"]
        for key, d in _ordered(a):
            if "relative" not in d:
                continue
            case, method = key.split("/")
            rel = d["relative"]
            lines.append(f"| {LABEL[case]} | {method} | {_m(rel['position_rms_m'])} | "
                         f"{_m(rel['range_rms_m'])} | {_m(r['bounds'][case]['qr']['relative'])} | "
                         f"{_m(rel['sigma_position_rms_m'])} | {rel['nees_mean']:.2f} | "
                         f"{rel['nees_position_spherical_mean']:.2f} |")
        lines.append("")
    b6, b3 = agg["nees_band_6"], agg["nees_band_3"]
    lines += [f"NEES 95 % bands of the mean over {S} seeds (each pass one chi-square sample): "
              f"6 dof [{b6[0]:.2f}, {b6[1]:.2f}], 3 dof [{b3[0]:.2f}, {b3[1]:.2f}].", "",
              "## What the numbers say (generated from the tables above)", ""]
    lines += [f"- {x}" for x in findings(result, agg)]
    if "wall_s" in result:
        lines += ["", f"Wall time of the study: {result['wall_s']:.0f} s (2 cores shared with "
                  "other jobs)."]
    return "\n".join(lines) + "\n"


CENTIMETRE_M = 0.05
"""Upper end of "centimetre-level" (m) when the findings compare with the issue's words."""
SUB_MILLIMETRE_M = 1e-3


def _band_word(x, band) -> str:
    if x < band[0]:
        return "below the band (conservative covariance)"
    if x > band[1]:
        return "above the band (overconfident covariance)"
    return "inside the band"


def findings(result, agg) -> list:
    """Plain statements of the tables' figures against the issue's expectations: centimetre
    relative position from pseudoranges (read as RMS <= :data:`CENTIMETRE_M`), sub-millimetre
    with carrier phase, NEES in the 95 % band."""
    S = len(result["seeds"])
    out = []
    for name, r in result["scenarios"].items():
        a, ids = agg[name], r["ids"]
        for method in result["methods"]:
            def sc_mean(case, key):
                return float(np.mean([a[f"{case}/{method}"]["spacecraft"][i][key] for i in ids]))

            def bnd(case):
                return float(np.mean([r["bounds"][case]["qr"][i] for i in ids]))

            cases = [c for c in LINKS if f"{c}/{method}" in a]
            parts = [f"{LABEL[c]} {_m(sc_mean(c, 'position_rms_m'))} (bound {_m(bnd(c))})"
                     for c in cases]
            out.append(f"{name}, {method}: absolute position RMS per spacecraft (mean of the two) "
                       + "; ".join(parts) + f": the links shrink the bound "
                       f"{bnd('alone') / bnd('links'):.2f}x.")
            ratios = [a[f"{c}/{method}"]["spacecraft"][i]["position_rms_m"]
                      / r["bounds"][c]["qr"][i] for c in cases for i in ids]
            sig = [a[f"{c}/{method}"]["spacecraft"][i]["sigma_position_rms_m"]
                   / r["bounds"][c]["qr"][i] - 1.0 for c in cases for i in ids]
            out.append(f"{name}, {method}: RMS / bound {min(ratios):.2f} to {max(ratios):.2f} over "
                       f"the cases and spacecraft ({S} seeds); the smoother's sigma is the bound "
                       f"to {100 * max(abs(x) for x in sig):.2g} %.")
            for c in cases:
                d = a[f"{c}/{method}"]
                n6 = [d["spacecraft"][i]["nees_mean"] for i in ids]
                line = (f"{name}, {method}, {LABEL[c]}: absolute NEES (6 dof) "
                        + ", ".join(f"{i} {x:.2f} {_band_word(x, agg['nees_band_6'])}"
                                    for i, x in zip(ids, n6))
                        + f"; integrity verdict ok in {d['integrity_ok']}/{S} passes.")
                if "relative" in d:
                    rel = d["relative"]
                    goal, word = ((SUB_MILLIMETRE_M, "sub-millimetre") if c == "carrier"
                                  else (CENTIMETRE_M, "centimetre-level"))
                    met = rel["position_rms_m"] <= goal
                    line += (f" Relative position RMS {_m(rel['position_rms_m'])} (range component "
                             f"{_m(rel['range_rms_m'])}, bound {_m(r['bounds'][c]['qr']['relative'])})"
                             f": {'meets' if met else 'does NOT meet'} the issue's {word} "
                             f"(<= {_m(goal)}); relative NEES {rel['nees_mean']:.2f} (6 dof, "
                             f"{_band_word(rel['nees_mean'], agg['nees_band_6'])}), spherical "
                             f"position {rel['nees_position_spherical_mean']:.2f} (3 dof, "
                             f"{_band_word(rel['nees_position_spherical_mean'], agg['nees_band_3'])}).")
                out.append(line)
                if "relative" in d:
                    out.append(_wrong_minima(name, method, c, r, S))
    return out


def _wrong_minima(name, method, case, r, S) -> str:
    """How many passes ended far from the truth (relative RMS > 10x its bound), whether the
    verdict flagged them, and the figures of the passes whose verdict is ok."""
    bound = r["bounds"][case]["qr"]["relative"]
    runs = [run[f"{case}/{method}"] for run in r["runs"]]
    rms = np.sqrt([x["relative"]["position_ms_m2"] for x in runs])
    wrong = rms > 10 * bound
    flagged = sum(1 for x, w in zip(runs, wrong) if w and x["integrity"] != "ok")
    ok = [x for x in runs if x["integrity"] == "ok"]
    text = (f"{name}, {method}, {LABEL[case]}: {int(wrong.sum())}/{S} passes ended far from the "
            f"truth (relative RMS > 10x its bound, up to {_m(float(rms.max()))}), "
            f"{flagged} of them flagged by the verdict")
    if ok:
        ok_rms = float(np.sqrt(np.mean([x["relative"]["position_ms_m2"] for x in ok])))
        text += (f"; the {len(ok)} passes with an ok verdict: relative RMS {_m(ok_rms)}, NEES "
                 f"{np.mean([x['relative']['nees_mean'] for x in ok]):.2f} (6 dof), "
                 f"{np.mean([x['relative']['nees_position_spherical_mean'] for x in ok]):.2f} "
                 "(spherical, 3 dof)")
    near = [x for x, w in zip(runs, wrong) if not w and x["integrity"] != "ok"]
    if near:
        near_rms = float(np.sqrt(np.mean([x["relative"]["position_ms_m2"] for x in near])))
        why = sorted({w.split(" (")[0] for x in near for w in x.get("reasons", ())})
        text += (f"; {len(near)} passes near the truth (relative RMS {_m(near_rms)}) with a "
                 f"verdict not ok{(': ' + '; '.join(why)) if why else ''}")
    return text + "."


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=None, help="number of seeds (default 10; "
                    "--quick 3)")
    ap.add_argument("--quick", action="store_true", help="3 seeds, shorter passes")
    ap.add_argument("--isam2", action="store_true", help="also smooth with --method isam2")
    ap.add_argument("--out", default=None, help="markdown file to write (default: print)")
    ap.add_argument("--json", default=None, help="also write the figures as JSON")
    ap.add_argument("--from-json", default=None, help="render the markdown from a JSON this "
                    "script wrote (no new runs)")
    args = ap.parse_args(argv)
    if args.from_json:
        d = json.loads(Path(args.from_json).read_text())
        text = markdown(d["result"], aggregate(d["result"]), d["command"])
        if args.out:
            Path(args.out).write_text(text)
        else:
            print(text)
        return 0
    n = args.seeds if args.seeds is not None else (3 if args.quick else 10)
    methods = ("batch", "isam2") if args.isam2 else ("batch",)
    t = time.perf_counter()
    result = study(list(range(n)), args.quick, methods,
                   log=lambda s: print(s, file=sys.stderr, flush=True))
    agg = aggregate(result)
    cmd = "PYTHONPATH=$PWD python scripts/study_formation.py" + (" --quick" if args.quick else "") \
        + (f" --seeds {n}" if args.seeds is not None else "") + (" --isam2" if args.isam2 else "") \
        + (f" --out {args.out}" if args.out else "")
    result["wall_s"] = time.perf_counter() - t
    text = markdown(result, agg, cmd)
    if args.out:
        Path(args.out).write_text(text)
    else:
        print(text)
    if args.json:
        Path(args.json).write_text(json.dumps({"result": result, "aggregate": agg,
                                               "command": cmd}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
