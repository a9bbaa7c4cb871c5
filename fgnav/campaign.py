"""Campaigns: a grid of runs (scenarios x parameters x seeds x methods) executed in-process,
in local worker processes or on a Dask distributed cluster, streamed to a resumable table.

A study is a TOML file (``data/studies/*.toml``)::

    name = "seed002-noise"
    task = "navigate"            # navigate | observability | visibility | seed000-table5
    report = "seed002-noise"     # how the runs are summarized (REPORTS)
    methods = ["ekf", "batch"]   # navigate/visibility only
    seeds = [0, 1, 2]            # or: seeds = {start = 0, count = 100}
    save_curves = false          # navigate: keep per-epoch NEES/NIS arrays (curves/*.npz)
    [fixed]                      # parameters shared by every run
    scenario = "gto-transfer"
    [grid]                       # parameters swept (cartesian product, in file order)
    sigma_deg = [0.01, 0.02, 0.05]

Runs are independent and deterministic: a run is a pure function of its parameters (the
noise seed among them), so 1 worker, N workers and a Dask cluster give the same numbers.

Output directory:

* ``runs.csv``: one row per finished run, appended and ``fsync``-ed as each run completes
  (a killed campaign loses at most the runs in flight; a torn last line is discarded on
  resume); ``--resume`` skips the runs already recorded with ``status = ok`` and retries
  failed ones (the last row of a run wins);
* ``study.json``: the study as run (a resume must use the same study);
* ``curves/<run>.npz``: per-epoch arrays when ``save_curves`` (written before the row);
* ``table.csv``, ``table.md``, ``plot.png``: the study's report, rewritten when all runs are done.
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import os
import re
import socket
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from fgnav.errors import InputFormatError, UserError
from fgnav.paths import data_dir

TASKS = ("navigate", "observability", "visibility", "seed000-table5")

NAVIGATE_PARAMS = ("scenario", "step_s", "duration_h", "sigma_deg", "prior_position_sigma_m",
                   "prior_velocity_sigma_mps", "prior_mode", "q_m2_s3", "third_body")

TASK_COLUMNS = {
    "navigate": ("n_epochs", "position_rms_m", "velocity_rms_mps", "final_position_error_m",
                 "final_velocity_error_mps", "nees_mean", "nees_final", "sigma_position_rms_m",
                 "sigma_final_position_m", "nis_per_dof", "info_condition", "weakest_sigma_m",
                 "weakest_direction", "solve_s"),
    "observability": ("rank", "condition_raw", "condition_scaled", "window_info_condition",
                      "weakest_sigma_m", "weakest_direction", "window_h"),
    "visibility": ("perigee_alt_km", "apogee_alt_km", "visible_fraction", "n_epochs_all",
                   "n_epochs_ring", "max_gap_min", "position_rms_all_m", "final_position_all_m",
                   "position_rms_ring_m", "final_position_ring_m", "ring_status"),
    "seed000-table5": ("seed_km", "ours_direction_km", "ours_with_rho_km", "ours_mc_km",
                       "lower_bound_km", "seed_over_bound"),
}
TIMING_COLUMNS = ("solve_s", "run_s", "worker")
"""Columns that describe the execution, not the result (excluded from reproducibility checks)."""

__all__ = ["Study", "RunSpec", "CampaignResult", "load_study", "builtin_studies", "study_runs",
           "run_campaign", "read_runs", "execute_run", "write_report", "TASKS", "TIMING_COLUMNS"]


# ---- study ----------------------------------------------------------------------------

@dataclass(frozen=True)
class Study:
    name: str
    task: str
    report: str
    description: str = ""
    methods: tuple = ("",)
    seeds: tuple = (0,)
    fixed: dict = field(default_factory=dict)
    grid: dict = field(default_factory=dict)       # name -> tuple of values (file order)
    save_curves: bool = False
    source: str = ""

    def to_json(self) -> dict:
        d = asdict(self)
        d.pop("source")
        d["methods"], d["seeds"] = list(self.methods), list(self.seeds)
        d["grid"] = {k: list(v) for k, v in self.grid.items()}
        return d


@dataclass(frozen=True)
class RunSpec:
    run_id: str
    params: dict


def builtin_studies() -> list[str]:
    return sorted(p.stem for p in (data_dir() / "studies").glob("*.toml"))


def load_study(name_or_path) -> Study:
    """A built-in study by name (``seed002-noise``) or a study TOML by path."""
    path = Path(name_or_path)
    if path.suffix.lower() != ".toml":
        path = data_dir() / "studies" / f"{name_or_path}.toml"
        if not path.exists():
            raise UserError(f"unknown study '{name_or_path}'; built-in: {', '.join(builtin_studies())}")
    if not path.exists():
        raise UserError(f"{path}: no such study file")
    from fgnav.io.text import load_toml

    d = load_toml(path, "a study TOML file")  # UTF-8 (BOM ignored), syntax errors with line
    for key in ("name", "task", "report"):
        if key not in d:
            raise InputFormatError(path, None, key, "this key (see data/studies/seed002-noise.toml)")
    if d["task"] not in TASKS:
        raise InputFormatError(path, None, "task", f"one of {TASKS}", d["task"])
    if d["report"] not in REPORTS:
        raise InputFormatError(path, None, "report", f"one of {tuple(REPORTS)}", d["report"])
    seeds = d.get("seeds", [0])
    if isinstance(seeds, dict):
        try:
            seeds = list(range(int(seeds.get("start", 0)), int(seeds.get("start", 0)) + int(seeds["count"])))
        except (KeyError, TypeError, ValueError):
            raise InputFormatError(path, None, "seeds", "a list of integers or {start = .., count = ..}",
                                   d.get("seeds")) from None
    if not isinstance(seeds, list) or not seeds or not all(isinstance(s, int) for s in seeds):
        raise InputFormatError(path, None, "seeds", "a non-empty list of integers", seeds)
    methods = d.get("methods", [""])
    if d["task"] in ("navigate", "visibility"):
        from fgnav.pipeline import METHODS
        if not methods or any(m not in METHODS for m in methods):
            raise InputFormatError(path, None, "methods", f"a list of {METHODS}", methods)
    grid = d.get("grid", {})
    for k, v in grid.items():
        if not isinstance(v, list) or not v:
            raise InputFormatError(path, None, f"grid.{k}", "a non-empty list of values", v)
    fixed = d.get("fixed", {})
    if d["task"] == "navigate":
        for k in list(grid) + list(fixed):
            if k not in NAVIGATE_PARAMS:
                raise InputFormatError(path, None, k, f"a navigate parameter {NAVIGATE_PARAMS}", k)
    overlap = set(grid) & set(fixed)
    if overlap:
        raise InputFormatError(path, None, "grid", "parameters not also in [fixed]", sorted(overlap))
    return Study(name=str(d["name"]), task=d["task"], report=d["report"],
                 description=str(d.get("description", "")), methods=tuple(methods),
                 seeds=tuple(seeds), fixed=dict(fixed), grid={k: tuple(v) for k, v in grid.items()},
                 save_curves=bool(d.get("save_curves", False)), source=str(path))


def _fmt(v) -> str:
    return repr(float(v)) if isinstance(v, float) else str(v)


def study_runs(study: Study) -> list[RunSpec]:
    """Every run of the study in a fixed order: grid (file order) x methods x seeds."""
    keys = list(study.grid)
    runs = []
    for combo in itertools.product(*(study.grid[k] for k in keys)):
        for method in study.methods:
            for seed in study.seeds:
                params = dict(study.fixed)
                params.update(zip(keys, combo))
                parts = [f"{k}={_fmt(v)}" for k, v in zip(keys, combo)]
                if method:
                    params["method"] = method
                    parts.append(f"method={method}")
                params["seed"] = seed
                parts.append(f"seed={seed}")
                runs.append(RunSpec(";".join(parts), params))
    return runs


def _columns(study: Study) -> list[str]:
    params = list(study.grid) + (["method"] if study.methods != ("",) else []) + ["seed"]
    return ["run_id", "status", "error"] + params + list(TASK_COLUMNS[study.task]) + \
        [c for c in ("run_s", "worker") if c not in TASK_COLUMNS[study.task]]


# ---- the runs (executed in workers: module-level, picklable, lazy heavy imports) -------

def execute_run(task: str, params: dict) -> dict:
    """Run one task; never raises for a failed run: ``{"status": "failed", "error": ...}``.

    Returns ``{"status", "error", "row": {column: value}, "arrays": {name: ndarray}}``.
    """
    t0 = time.perf_counter()
    try:
        row, arrays = _TASK_FUNCS[task](dict(params))
        out = {"status": "ok", "error": "", "row": row, "arrays": arrays}
    except Exception as exc:  # a failed run is recorded, not fatal to the campaign
        out = {"status": "failed", "error": f"{type(exc).__name__}: {exc}"[:500], "row": {}, "arrays": {}}
    out["row"]["run_s"] = time.perf_counter() - t0
    out["row"]["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    return out


def _scenario_for(params):
    from fgnav.scenarios import load_scenario

    scn = load_scenario(params.get("scenario", "gto-transfer"))
    scn = scn.with_options(step_s=params.get("step_s"), duration_h=params.get("duration_h"),
                           prior_position_sigma_m=params.get("prior_position_sigma_m"),
                           prior_velocity_sigma_mps=params.get("prior_velocity_sigma_mps"),
                           prior_mode=params.get("prior_mode"))
    if params.get("sigma_deg") is not None:
        from dataclasses import replace
        sensors = tuple(replace(s, sigma_deg=float(params["sigma_deg"])) if s.kind == "earth_direction"
                        else s for s in scn.sensors)
        scn = scn.with_options(sensors=sensors)
    return scn


def _options_for(params):
    from fgnav.solvers.options import SmootherOptions

    kw = {}
    if params.get("q_m2_s3") is not None:
        kw["q_m2_s3"] = float(params["q_m2_s3"])
    if params.get("third_body") is not None:
        kw["third_body"] = bool(params["third_body"])
    return SmootherOptions(**kw)


def _task_navigate(params):
    import numpy as np

    from fgnav.analysis.consistency import nees, nis_ekf, nis_smoother, nis_summary
    from fgnav.analysis.crb import cramer_rao_bound
    from fgnav.analysis.observability import weakest_directions
    from fgnav.measurements import build_pass
    from fgnav.pipeline import accuracy_metrics, solve
    from fgnav.simulate.pass_sim import simulate_pass

    scn = _scenario_for(params)
    options = _options_for(params)
    sim = simulate_pass(scn, seed=int(params["seed"]))
    p = build_pass(sim.log)
    t0 = time.perf_counter()
    sol = solve(p, params["method"], options)
    solve_s = time.perf_counter() - t0
    x_true = sim.x_true[sim.t_s.searchsorted(sol.t_s)]
    m = accuracy_metrics(sol, x_true)
    eps = nees(sol.x_eci, sol.P_eci, x_true)
    if params["method"] == "ekf":
        nis, dof = nis_ekf(p, sol, options)
    else:
        nis, dof = nis_smoother(p, sol)
    J = cramer_rao_bound(p, x_true, options.motion_model()).J0_measurements
    weak = weakest_directions(J, count=1)[0]
    row = {"n_epochs": int(len(sol.t_s)), **{k: m[k] for k in TASK_COLUMNS["navigate"] if k in m},
           "nees_final": float(eps[-1]),
           "sigma_final_position_m": float(np.sqrt(np.trace(sol.P_eci[-1, :3, :3]))),
           "nis_per_dof": nis_summary(nis, dof)["nis_per_dof"],
           "info_condition": float(np.linalg.cond(J)), "weakest_sigma_m": weak["sigma_m"],
           "weakest_direction": weak["text"], "solve_s": solve_s}
    arrays = {"t_s": np.asarray(sol.t_s), "nees": eps, "nis": nis, "nis_dof": dof}
    return row, arrays


def _task_observability(params):
    import numpy as np

    from fgnav.analysis.observability import (analyze_observability, observability_matrix,
                                              weakest_directions, window_information)
    from fgnav.constants import DEG

    scn = _scenario_for(params)
    x0 = np.array(scn.x0_eci)
    T = float(params["step_s"])
    res = analyze_observability(observability_matrix(x0, T, int(params.get("n_samples", 6))))
    window_h = float(params.get("window_h", 1.0))
    sigma = float(params.get("sigma_deg", 0.01)) * DEG
    J = window_information(x0, T, window_h * 3600.0, sigma)
    weak = weakest_directions(J, count=1)[0]
    row = {"rank": res.rank, "condition_raw": res.condition_raw, "condition_scaled": res.condition_scaled,
           "window_info_condition": float(np.linalg.cond(J)), "weakest_sigma_m": weak["sigma_m"],
           "weakest_direction": weak["text"], "window_h": window_h}
    return row, {}


def _task_visibility(params):
    import numpy as np

    from fgnav.analysis.visibility import SEED_RING_DEG, ring_sees_limb, visibility_scenario
    from fgnav.errors import UserError as _UE
    from fgnav.io.log_csv import log_from_arrays
    from fgnav.measurements import build_pass
    from fgnav.pipeline import accuracy_metrics, solve
    from fgnav.simulate.pass_sim import simulate_pass

    scn = visibility_scenario(params["orbit"])
    options = _options_for(params)
    sim = simulate_pass(scn, seed=int(params["seed"]))
    rn = np.linalg.norm(sim.x_true[:, :3], axis=1)
    ring = tuple(params.get("ring_deg", SEED_RING_DEG))
    vis = ring_sees_limb(sim.x_true[:, :3], ring)
    from fgnav.constants import R_EARTH_M
    row = {"perigee_alt_km": float((rn.min() - R_EARTH_M) / 1e3),
           "apogee_alt_km": float((rn.max() - R_EARTH_M) / 1e3), "visible_fraction": float(vis.mean())}
    gaps, run = [], 0.0
    dt = np.diff(sim.t_s, prepend=sim.t_s[0])
    for v, d in zip(vis, dt):
        run = 0.0 if v else run + d
        gaps.append(run)
    row["max_gap_min"] = float(max(gaps) / 60.0)

    def metrics(log):
        p = build_pass(log)
        sol = solve(p, params["method"], options)
        m = accuracy_metrics(sol, sim.x_true[sim.t_s.searchsorted(sol.t_s)])
        return p.n_epochs, m["position_rms_m"], m["final_position_error_m"]

    row["n_epochs_all"], row["position_rms_all_m"], row["final_position_all_m"] = metrics(sim.log)
    log = sim.log
    t_vis = sim.t_s[vis]
    keep = np.isin(log.kind, ("prior_position", "prior_velocity")) | np.isin(log.t_s, t_vis)
    row["n_epochs_ring"], row["position_rms_ring_m"], row["final_position_ring_m"] = 0, float("nan"), float("nan")
    if keep.sum() > np.isin(log.kind, ("prior_position", "prior_velocity")).sum():
        sub = log_from_arrays(log.epoch0, log.t_s[keep], log.kind[keep], log.xyz[keep], log.sigma[keep],
                              {k: v[keep] for k, v in (log.extra or {}).items()})
        try:
            row["n_epochs_ring"], row["position_rms_ring_m"], row["final_position_ring_m"] = metrics(sub)
            row["ring_status"] = "ok"
        except _UE as exc:
            row["ring_status"] = f"not observable: {str(exc)[:80]}"
    else:
        row["ring_status"] = "limb never inside the ring: no measurement"
    return row, {}


def _task_seed000_table5(params):
    import numpy as np

    from factors.constants import DEG, R_LIMB_UV_M
    from fgnav.analysis.limb_method_study import direct_position_error_mc, table5

    alt, ang = float(params["alt_km"]), float(params["angle_error_deg"])
    rows = [r for r in table5(alts_km=(alt,)) if abs(r["angle_error_deg"] - ang) < 1e-12]
    if not rows:
        rows = table5(alts_km=(alt,), angle_errors_deg=(ang,))
    r = dict(rows[0])
    rng = np.random.default_rng(int(params["seed"]))
    r_m = R_LIMB_UV_M + alt * 1e3
    r["ours_mc_km"] = direct_position_error_mc(r_m, ang * DEG, ang * DEG / 2.0, rng) / 1e3
    return {k: r.get(k) for k in TASK_COLUMNS["seed000-table5"]}, {}


_TASK_FUNCS = {"navigate": _task_navigate, "observability": _task_observability,
               "visibility": _task_visibility, "seed000-table5": _task_seed000_table5}


# ---- the runs table -------------------------------------------------------------------

def _csv_line(values) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(values)
    return buf.getvalue()


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if hasattr(v, "item") and not isinstance(v, (str, bytes)):  # numpy scalar
        v = v.item()
    if isinstance(v, float):
        return repr(float(v))
    return str(v)


def _parse(v: str):
    if v == "":
        return None
    if v in ("true", "false"):
        return v == "true"
    try:
        return int(v)
    except ValueError:
        pass
    try:
        return float(v)
    except ValueError:
        return v


def read_runs(out_dir) -> list[dict]:
    """The rows of ``out_dir/runs.csv`` (values parsed; the last row of each run wins),
    in the order of first appearance."""
    path = Path(out_dir) / "runs.csv"
    if not path.exists():
        return []
    text = path.read_text()
    if text and not text.endswith("\n"):
        text = text[: text.rfind("\n") + 1]
    rows: dict[str, dict] = {}
    for r in csv.DictReader(io.StringIO(text)):
        rows[r["run_id"]] = {k: (_parse(v) if k not in ("run_id", "error") else v) for k, v in r.items()}
    return list(rows.values())


def _safe_name(run_id: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.=-]+", "_", run_id)


@dataclass
class CampaignResult:
    out_dir: Path
    n_runs: int          # in the study
    n_skipped: int       # already finished (resume)
    n_ran: int           # executed now
    n_failed: int        # executed now and failed
    wall_s: float        # wall time of this invocation (runs + I/O + report)
    run_s_sum: float     # sum of the executed runs' own wall times (inside the workers)
    report_files: list = field(default_factory=list)

    def as_dict(self) -> dict:
        d = asdict(self)
        d["out_dir"] = str(self.out_dir)
        d["report_files"] = [str(p) for p in self.report_files]
        return d


def _prepare_out(study: Study, out: Path, resume: bool) -> set:
    """Create/validate the output directory; return the run ids already finished."""
    out.mkdir(parents=True, exist_ok=True)
    from fgnav.io.atomic import atomic_write_text

    runs_csv, spec = out / "runs.csv", out / "study.json"
    cols = _columns(study)
    if runs_csv.exists() and runs_csv.stat().st_size > 0:
        if not resume:
            raise UserError(f"{runs_csv} exists: pass --resume to continue that campaign, or another --out")
        if spec.exists() and json.loads(spec.read_text()) != study.to_json():
            raise UserError(f"{out}: the campaign there ran a different study ({spec}); use another --out")
        with runs_csv.open("r+b") as f:           # drop a torn last line (killed mid-write)
            data = f.read()
            if not data.endswith(b"\n"):
                f.truncate(data.rfind(b"\n") + 1)
        header = runs_csv.read_text().split("\n", 1)[0]
        if next(csv.reader([header])) != cols:
            raise UserError(f"{runs_csv}: its columns differ from this study's; use another --out")
        return {r["run_id"] for r in read_runs(out) if r["status"] == "ok"}
    atomic_write_text(spec, json.dumps(study.to_json(), indent=1) + "\n")
    atomic_write_text(runs_csv, _csv_line(cols))
    return set()


def _results_local(todo, workers):
    """Yield (spec, result) as runs finish: in-process (1 worker) or a process pool."""
    if workers <= 1:
        for spec in todo:
            yield spec, execute_run(spec.task, spec.params)
        return
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    pool = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"))
    try:
        futs = {pool.submit(execute_run, s.task, s.params): s for s in todo}
        for f in as_completed(futs):
            yield futs[f], f.result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _results_dask(todo, scheduler, client):
    from dask.distributed import Client, as_completed

    own = client is None
    if own:
        try:
            client = Client(scheduler, timeout=30)
        except OSError as exc:
            raise UserError(f"cannot reach the Dask scheduler at {scheduler!r}: {exc}") from None
    futs = {}
    try:
        for i, s in enumerate(todo):
            f = client.submit(execute_run, s.task, s.params, pure=False, key=f"fgnav-{os.getpid()}-{time.time_ns()}-{i}")
            futs[f.key] = (f, s)
        for f in as_completed([f for f, _ in futs.values()]):
            yield futs[f.key][1], f.result()
    finally:
        client.cancel([f for f, _ in futs.values()])
        if own:
            client.close()


@dataclass(frozen=True)
class _Todo:
    run_id: str
    task: str
    params: dict


def run_campaign(study: Study, out_dir, *, workers: int = 1, scheduler: str | None = None,
                 client=None, resume: bool = False, quiet: bool = True, on_result=None,
                 report: bool = True) -> CampaignResult:
    """Run (or resume) a study; see the module docstring for the files written.

    ``workers``: 1 = in this process, N > 1 = N local worker processes; ``scheduler``: a Dask
    scheduler address (``tcp://host:8786``), or ``client``: a ``dask.distributed.Client``
    (takes precedence over ``workers``). ``on_result(row)`` is called after each row is
    durably on disk (a ``KeyboardInterrupt`` raised there stops the campaign like Ctrl-C).
    """
    from fgnav.progress import progress

    t_start = time.perf_counter()
    out = Path(out_dir)
    done = _prepare_out(study, out, resume)
    runs = study_runs(study)
    todo = [_Todo(s.run_id, study.task, s.params) for s in runs if s.run_id not in done]
    cols = _columns(study)
    n_ok = n_failed = 0
    run_s_sum = 0.0
    if todo:
        if scheduler is not None or client is not None:
            results = _results_dask(todo, scheduler, client)
        else:
            results = _results_local(todo, min(int(workers), len(todo)))
        bar = progress(total=len(todo), desc=f"{study.name}", unit="run", quiet=quiet)
        try:
            with (out / "runs.csv").open("a", encoding="utf-8", newline="") as f:
                for spec, res in results:
                    row = dict(res["row"])
                    row.update(run_id=spec.run_id, status=res["status"], error=res["error"])
                    for k in cols:
                        if k in spec.params and k not in row:
                            row[k] = spec.params[k]
                    if res["arrays"] and study.save_curves:
                        import numpy as np

                        from fgnav.io.atomic import atomic_writer
                        (out / "curves").mkdir(exist_ok=True)
                        with atomic_writer(out / "curves" / f"{_safe_name(spec.run_id)}.npz", "wb") as g:
                            np.savez(g, **res["arrays"])
                    f.write(_csv_line([_cell(row.get(c)) for c in cols]))
                    f.flush()
                    os.fsync(f.fileno())
                    run_s_sum += float(row.get("run_s") or 0.0)
                    if res["status"] == "ok":
                        n_ok += 1
                    else:
                        n_failed += 1
                    bar.update(1)
                    bar.set_postfix(done=n_ok, failed=n_failed, remaining=len(todo) - n_ok - n_failed)
                    if on_result is not None:
                        on_result(row)
        finally:
            bar.close()
            if hasattr(results, "close"):
                results.close()
    files = []
    if report and all(r["status"] == "ok" for r in read_runs(out)) and len(read_runs(out)) == len(runs):
        files = write_report(study, out)
    return CampaignResult(out, len(runs), len(done), n_ok + n_failed, n_failed,
                          time.perf_counter() - t_start, run_s_sum, files)


# ---- reports --------------------------------------------------------------------------

def _group(rows, keys):
    groups: dict[tuple, list] = {}
    for r in rows:
        groups.setdefault(tuple(r.get(k) for k in keys), []).append(r)
    return groups


def _mean(rows, key):
    import numpy as np

    v = np.array([r[key] for r in rows if isinstance(r.get(key), (int, float))], float)
    return float(np.mean(v)) if len(v) else float("nan")


def _write_table(out: Path, rows: list[dict], title: str, notes: list[str]) -> list[Path]:
    from fgnav.io.atomic import atomic_write_text

    cols = list(rows[0]) if rows else []
    text = _csv_line(cols) + "".join(_csv_line([_cell(r.get(c)) for c in cols]) for r in rows)
    atomic_write_text(out / "table.csv", text)

    def md(v):
        if isinstance(v, float):
            return "" if v != v else (f"{v:.4g}" if abs(v) < 1e5 else f"{v:.3e}")
        return "" if v is None else str(v)

    lines = [f"# {title}", ""] + [f"{n}" for n in notes] + [""]
    lines.append("| " + " | ".join(cols) + " |")
    lines.append("|" + "---|" * len(cols))
    lines += ["| " + " | ".join(md(r.get(c)) for c in cols) + " |" for r in rows]
    atomic_write_text(out / "table.md", "\n".join(lines) + "\n")
    return [out / "table.csv", out / "table.md"]


def _save_plot(fig, path: Path) -> Path:
    from fgnav.io.atomic import atomic_writer

    with atomic_writer(path, "wb") as f:
        fig.savefig(f, format="png", dpi=110, bbox_inches="tight")
    import matplotlib.pyplot as plt
    plt.close(fig)
    return path


def _figure(ncols=1):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, ncols, figsize=(6.5 * ncols, 4.5))
    return fig, ax


def _navigate_table(study, rows, xkey, seed_cols):
    out = []
    for (x, method), g in sorted(_group(rows, (xkey, "method")).items(), key=lambda kv: (kv[0][0], str(kv[0][1]))):
        r = {xkey: x, "method": method, "runs": len(g),
             "final_position_km": _mean(g, "final_position_error_m") / 1e3,
             "final_velocity_mps": _mean(g, "final_velocity_error_mps"),
             "position_rms_km": _mean(g, "position_rms_m") / 1e3,
             "velocity_rms_mps": _mean(g, "velocity_rms_mps"),
             "sigma_final_position_km": _mean(g, "sigma_final_position_m") / 1e3,
             "nees_mean": _mean(g, "nees_mean"), "solve_s": _mean(g, "solve_s")}
        r.update(seed_cols(x, r))
        out.append(r)
    return out


def _plot_navigate(table, xkey, xlabel, title, path, hline=None):
    fig, axes = _figure(2)
    for method in sorted({r["method"] for r in table}):
        t = [r for r in table if r["method"] == method]
        axes[0].loglog([r[xkey] for r in t], [r["final_position_km"] for r in t], "o-", label=f"{method} final")
        axes[0].loglog([r[xkey] for r in t], [r["position_rms_km"] for r in t], "s--", label=f"{method} RMS")
        axes[1].loglog([r[xkey] for r in t], [r["final_velocity_mps"] for r in t], "o-", label=f"{method} final")
        axes[1].loglog([r[xkey] for r in t], [r["velocity_rms_mps"] for r in t], "s--", label=f"{method} RMS")
    if hline:
        axes[0].axhline(hline[0], color="k", lw=0.8, ls=":", label="seed bound")
        axes[1].axhline(hline[1], color="k", lw=0.8, ls=":", label="seed bound")
    axes[0].set(xlabel=xlabel, ylabel="position error (km)", title=title)
    axes[1].set(xlabel=xlabel, ylabel="velocity error (m/s)")
    for a in axes:
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=8)
    return _save_plot(fig, path)


def _report_seed002_noise(study, rows, out):
    def seed_cols(sigma, r):
        if sigma <= 0.05 + 1e-12:
            return {"seed_position_bound_km": 4.0, "seed_velocity_bound_mps": 0.5,
                    "meets_seed_bound": bool(r["final_position_km"] < 4.0 and r["final_velocity_mps"] < 0.5)}
        return {"seed_position_bound_km": None, "seed_velocity_bound_mps": None, "meets_seed_bound": None}

    table = _navigate_table(study, rows, "sigma_deg", seed_cols)
    notes = [f"Study `{study.name}`: {study.description}",
             "Seed 002 table 2 (final errors after 4 h): its numbers are not in the source text; the "
             "seed states that noise <= 0.05 deg keeps errors < 4 km and < 0.5 m/s (bound columns).",
             f"Fixed parameters: {study.fixed}; seeds {list(study.seeds)}. Errors are means over seeds."]
    files = _write_table(out, table, "Seed 002 table 2: direction noise vs navigation error", notes)
    files.append(_plot_navigate(table, "sigma_deg", "direction noise 1-sigma (deg)",
                                "seed 002 table 2", out / "plot.png", hline=(4.0, 0.5)))
    return files


def _report_seed002_period(study, rows, out):
    table = _navigate_table(study, rows, "step_s", lambda x, r: {
        "seed_value": "not in source text; seed: shorter period is better"})
    notes = [f"Study `{study.name}`: {study.description}",
             "Seed 002 table 3 (sample period 0.1/1/10/100 s, 500 m / 0.05 m/s initial error, 0.01 deg).",
             f"Fixed parameters: {study.fixed}; seeds {list(study.seeds)}. Errors are means over seeds."]
    files = _write_table(out, table, "Seed 002 table 3: sample period vs navigation error", notes)
    files.append(_plot_navigate(table, "step_s", "sample period (s)", "seed 002 table 3", out / "plot.png"))
    return files


def _report_observability(study, rows, out):
    table = []
    for r in sorted(rows, key=lambda r: r["step_s"]):
        table.append({"step_s": r["step_s"], "rank": r["rank"], "seed_rank": 6,
                      "condition_raw": r["condition_raw"], "condition_scaled": r["condition_scaled"],
                      "seed_condition": None,
                      "window_h": r["window_h"], "window_info_condition": r["window_info_condition"],
                      "weakest_sigma_m": r["weakest_sigma_m"], "weakest_direction": r["weakest_direction"]})
    notes = [f"Study `{study.name}`: {study.description}",
             "Seed 002 table 4: rank 6 at every period and a condition number growing with the period "
             "(its numbers are not in the source text). condition_raw/scaled: eq. 9 with 6 blocks "
             "(window 5 T) at the seed's initial state; window_info_*: information of the initial state "
             "from all samples over a fixed window (1-sigma of the weakest direction, velocity x 1000 s)."]
    files = _write_table(out, table, "Seed 002 table 4: observability vs sample period", notes)
    fig, axes = _figure(2)
    T = [r["step_s"] for r in table]
    axes[0].loglog(T, [r["condition_raw"] for r in table], "o-", label="cond(M), SI units")
    axes[0].loglog(T, [r["condition_scaled"] for r in table], "s-", label="cond(M), columns scaled")
    axes[0].loglog(T, [r["window_info_condition"] for r in table], "^-", label="cond(J), fixed window")
    axes[0].set(xlabel="sample period (s)", ylabel="condition number", title="seed 002 table 4")
    axes[1].loglog(T, [r["weakest_sigma_m"] for r in table], "o-")
    axes[1].set(xlabel="sample period (s)", ylabel="weakest direction 1-sigma (m)",
                title=f"information over {table[0]['window_h'] if table else ''} h")
    for a in axes:
        a.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    files.append(_save_plot(fig, out / "plot.png"))
    return files


def _report_visibility(study, rows, out):
    import numpy as np

    from fgnav.analysis.visibility import SEED_BAND_KM, limb_half_angle_rad, visibility_band_m
    from fgnav.constants import DEG

    lo, hi = visibility_band_m()
    lo5, hi5 = visibility_band_m(r_earth_m=6_375_000.0)
    table = [{"orbit": "band (R = 6371 km)", "band_min_km": lo / 1e3, "band_max_km": hi / 1e3,
              "seed_band_min_km": SEED_BAND_KM[0], "seed_band_max_km": SEED_BAND_KM[1]},
             {"orbit": "band (R = 6375 km)", "band_min_km": lo5 / 1e3, "band_max_km": hi5 / 1e3,
              "seed_band_min_km": SEED_BAND_KM[0], "seed_band_max_km": SEED_BAND_KM[1]}]
    for (orbit, method), g in _group(rows, ("orbit", "method")).items():
        t = {"orbit": orbit, "method": method, "runs": len(g)}
        for k in ("perigee_alt_km", "apogee_alt_km", "visible_fraction", "max_gap_min",
                  "position_rms_all_m", "final_position_all_m", "position_rms_ring_m", "final_position_ring_m"):
            t[k] = _mean(g, k)
        t["ring_status"] = g[0].get("ring_status")
        table.append(t)
    cols = []
    for r in table:
        cols += [k for k in r if k not in cols]
    table = [{c: r.get(c) for c in cols} for r in table]
    notes = [f"Study `{study.name}`: {study.description}",
             "Seed 002 eq. 1: a 120-160 deg limb ring sees the whole Earth for "
             "R/sin(80 deg) - R <= h <= R/sin(60 deg) - R. Rows after the bands: passes navigated with the "
             "ring's direction + limb radius at every epoch (all) vs only when the limb is inside the ring."]
    files = _write_table(out, table, "Seed 002: limb-ring visibility bound", notes)
    fig, ax = _figure(1)
    h = np.linspace(50e3, 40000e3, 600)
    ax.semilogx(h / 1e3, 2 * limb_half_angle_rad(6_371_000.0 + h) / DEG, label="Earth apparent diameter")
    ax.axhspan(120, 160, color="g", alpha=0.2, label="ring 120-160 deg")
    ax.axvspan(lo / 1e3, hi / 1e3, color="b", alpha=0.1, label=f"band {lo/1e3:.1f}-{hi/1e3:.1f} km")
    ax.set(xlabel="altitude (km)", ylabel="apparent diameter (deg)", title="seed 002 visibility bound")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    files.append(_save_plot(fig, out / "plot.png"))
    return files


def _report_seed000_table5(study, rows, out):
    table = sorted(({k: r.get(k) for k in ("alt_km", "angle_error_deg") + TASK_COLUMNS["seed000-table5"]}
                    for r in rows), key=lambda r: (r["alt_km"], r["angle_error_deg"]))
    notes = [f"Study `{study.name}`: {study.description}",
             "Seed 000 table 5 via fgnav.analysis.limb_method_study.table5 (definitions in its docstring); "
             "ours_mc_km: Monte Carlo of r = -(R/sin rho) u with the same errors (2000 draws)."]
    files = _write_table(out, table, "Seed 000 table 5: direct positioning error", notes)
    fig, ax = _figure(1)
    for alt in sorted({r["alt_km"] for r in table}):
        t = [r for r in table if r["alt_km"] == alt]
        line, = ax.plot([r["angle_error_deg"] for r in t], [r["ours_with_rho_km"] for r in t], "o-",
                        label=f"{alt:g} km ours")
        ax.plot([r["angle_error_deg"] for r in t], [r["seed_km"] for r in t], "x:", color=line.get_color())
    ax.set(xlabel="angle error (deg)", ylabel="direct positioning error (km)",
           title="seed 000 table 5 (x: seed)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    files.append(_save_plot(fig, out / "plot.png"))
    return files


def _report_nees(study, rows, out):
    import numpy as np

    from fgnav.analysis.consistency import anees, nees_curve

    table, curves = [], {}
    for method, g in sorted(_group(rows, ("method",)).items()):
        method = method[0]
        a_final = anees([r["nees_final"] for r in g])
        r = {"method": method, "runs": len(g), "anees_final": a_final.anees,
             "band_lo": a_final.lo, "band_hi": a_final.hi, "inside_final": a_final.inside,
             "anees_over_dof": a_final.ratio}
        arrs = []
        for rr in g:
            f = out / "curves" / f"{_safe_name(rr['run_id'])}.npz"
            if f.exists():
                with np.load(f) as z:
                    arrs.append(z["nees"])
        if arrs and len({len(a) for a in arrs}) == 1:
            curve, lo, hi, frac = nees_curve(np.array(arrs))
            curves[method] = (curve, lo, hi)
            mid = anees(np.array(arrs)[:, len(curve) // 2])
            r.update(anees_mid=mid.anees, inside_mid=mid.inside, epochs_inside_band=frac,
                     anees_time_mean=float(curve.mean()))
        r.update(nis_per_dof=_mean(g, "nis_per_dof"), position_rms_m=_mean(g, "position_rms_m"),
                 seed_value=None)
        table.append(r)
    notes = [f"Study `{study.name}`: {study.description}",
             "NEES of the 6-D state against truth (independent DOP853); ANEES over runs at the final and "
             "middle epochs with the two-sided 95% chi-square band chi2(6R)/R; epochs_inside_band: "
             "fraction of epochs whose ANEES lies in that band (about 0.95 if consistent; epochs of one run "
             "are correlated). EKF rows are the filtered (causal) estimates. No seed value exists (the seeds "
             "give no consistency test)."]
    files = _write_table(out, table, "NEES / ANEES consistency", notes)
    fig, ax = _figure(1)
    lo = hi = None
    for method, (curve, lo, hi) in curves.items():
        ax.semilogy(np.arange(len(curve)), curve, label=f"{method} ANEES")
    if curves:
        ax.axhspan(lo, hi, color="g", alpha=0.2, label="95% band")
    ax.axhline(6.0, color="k", lw=0.8)
    ax.set(xlabel="epoch index", ylabel="ANEES (dof 6)", title=f"{study.name}: {len(rows)} runs")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    files.append(_save_plot(fig, out / "plot.png"))
    return files


REPORTS = {"seed002-noise": _report_seed002_noise, "seed002-period": _report_seed002_period,
           "observability": _report_observability, "visibility": _report_visibility,
           "seed000-table5": _report_seed000_table5, "nees": _report_nees}


def write_report(study: Study, out_dir) -> list[Path]:
    """Write table.csv, table.md and plot.png of a finished campaign; return the paths."""
    out = Path(out_dir)
    rows = [r for r in read_runs(out) if r["status"] == "ok"]
    if not rows:
        raise UserError(f"{out}: no finished runs to report")
    return REPORTS[study.report](study, rows, out)
