"""Execute a study's runs in this process, in local worker processes or on a Dask cluster,
streaming each finished run to the runs table (:mod:`fgnav.campaign.storage`).

Output directory:

* ``runs.csv``: one row per finished run, appended and ``fsync``-ed as each run completes;
  ``--resume`` skips the runs already recorded with ``status = ok`` and retries failed ones;
* ``study.json``: the study as run (a resume must use the same study, compared on what
  defines the runs: :meth:`Study.to_json`) and its ``reference`` figures;
* ``curves/<run>.npz``: per-epoch arrays when ``save_curves`` (written before the row);
* ``table.csv``, ``table.md``, ``plot.png``: the study's report, rewritten when all runs are done.
"""

from __future__ import annotations

import json
import os
import socket
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from fgnav.campaign.reports import write_study_report
from fgnav.campaign.spec import RunSpec, Study, run_columns, study_runs
from fgnav.campaign.storage import RunsTable, safe_name
from fgnav.campaign.tasks import TASKS, RunParams
from fgnav.errors import UserError
from fgnav.io.atomic import atomic_write_text, atomic_writer
from fgnav.progress import progress

__all__ = ["CampaignResult", "execute_run", "read_runs", "run_campaign", "write_report"]


def execute_run(task: str, params: RunParams) -> dict:
    """Run one task (in a worker); never raises for a failed run: ``{"status": "failed", "error": ...}``.

    Returns ``{"status", "error", "row": {column: value}, "arrays": {name: ndarray}}``.
    """
    t0 = time.perf_counter()
    try:
        row, arrays = TASKS[task].run(params)
        out = {"status": "ok", "error": "", "row": row, "arrays": arrays}
    except Exception as exc:  # a failed run is recorded, not fatal to the campaign
        out = {"status": "failed", "error": f"{type(exc).__name__}: {exc}"[:500], "row": {}, "arrays": {}}
    out["row"]["run_s"] = time.perf_counter() - t0
    out["row"]["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    return out


def _table(out: Path, study: Study | None = None) -> RunsTable:
    """The runs table of ``out``; its columns from ``study`` or from ``out/study.json``."""
    if study is not None:
        return RunsTable(out / "runs.csv", study.columns())
    spec = out / "study.json"
    if not spec.exists():
        raise UserError(f"{spec}: missing; it declares the columns of {out / 'runs.csv'}")
    try:
        d = json.loads(spec.read_text(encoding="utf-8"))
        columns = run_columns(d["task"], tuple(d["grid"]), list(d["methods"]) != [""])
    except (ValueError, KeyError, TypeError) as exc:
        raise UserError(f"{spec}: not a study written by fgnav campaign ({type(exc).__name__}: {exc})") from None
    return RunsTable(out / "runs.csv", columns)


def read_runs(out_dir, study: Study | None = None) -> list[dict]:
    """The rows of ``out_dir/runs.csv`` (typed by the study's columns; the last row of each
    run wins), in the order of first appearance; ``[]`` when there is no table yet."""
    out = Path(out_dir)
    if not (out / "runs.csv").exists():
        return []
    return _table(out, study).read()


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
    table, spec = _table(out, study), out / "study.json"
    if table.exists():
        if not resume:
            raise UserError(f"{table.path} exists: pass --resume to continue that campaign, or another --out")
        if spec.exists():
            ran = json.loads(spec.read_text(encoding="utf-8"))
            ran.pop("reference", None)
            if ran != study.to_json():
                raise UserError(f"{out}: the campaign there ran a different study ({spec}); use another --out")
        table.drop_torn_line()
        table.check_header()
        done = {r["run_id"] for r in table.read() if r["status"] == "ok"}
    else:
        done = set()
    # the reference figures may change between invocations: the report uses the latest.
    # Written before runs.csv is created, so that whoever finds runs.csv finds its columns
    # (a reader used to see runs.csv a moment before study.json: "study.json: missing").
    atomic_write_text(spec, json.dumps({**study.to_json(), "reference": study.reference_json()}, indent=1) + "\n")
    if not table.exists():
        table.create()
    return done


def _results_local(task, todo, workers):
    """Yield (spec, result) as runs finish: in-process (1 worker) or a process pool."""
    if workers <= 1:
        for spec in todo:
            yield spec, execute_run(task, spec.params)
        return
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    pool = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"))
    try:
        futs = {pool.submit(execute_run, task, s.params): s for s in todo}
        for f in as_completed(futs):
            yield futs[f], f.result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _results_dask(task, todo, scheduler, client):
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
            f = client.submit(execute_run, task, s.params, pure=False, key=f"fgnav-{os.getpid()}-{time.time_ns()}-{i}")
            futs[f.key] = (f, s)
        for f in as_completed([f for f, _ in futs.values()]):
            yield futs[f.key][1], f.result()
    finally:
        client.cancel([f for f, _ in futs.values()])
        if own:
            client.close()


def _save_curves(out: Path, spec: RunSpec, arrays: dict) -> None:
    import numpy as np

    (out / "curves").mkdir(exist_ok=True)
    with atomic_writer(out / "curves" / f"{safe_name(spec.run_id)}.npz", "wb") as g:
        np.savez(g, **arrays)


def write_report(study, out_dir, runs=None) -> list[Path]:
    """Write table.csv, table.md and plot.png of a finished campaign in ``out_dir``; return the
    paths (:func:`fgnav.campaign.reports.write_study_report`, its rows in the order of
    ``runs``, by default the study's own :func:`fgnav.campaign.spec.study_runs`)."""
    runs = study_runs(study) if runs is None else runs
    return write_study_report(study, out_dir, [r.run_id for r in runs])


def run_campaign(study: Study, out_dir, *, workers: int = 1, scheduler: str | None = None,
                 client=None, resume: bool = False, quiet: bool = True, on_result=None,
                 report: bool = True) -> CampaignResult:
    """Run (or resume) a study; see the module docstring for the files written.

    ``workers``: 1 = in this process, N > 1 = N local worker processes; ``scheduler``: a Dask
    scheduler address (``tcp://host:8786``), or ``client``: a ``dask.distributed.Client``
    (takes precedence over ``workers``). ``on_result(row)`` is called after each row is
    durably on disk (a ``KeyboardInterrupt`` raised there stops the campaign like Ctrl-C).
    """

    t_start = time.perf_counter()
    out = Path(out_dir)
    done = _prepare_out(study, out, resume)
    table = _table(out, study)
    runs = study_runs(study)
    todo = [s for s in runs if s.run_id not in done]
    param_columns = [c for c in table.names if c in ("method", "seed") or c in study.grid]
    n_ok = n_failed = 0
    run_s_sum = 0.0
    if todo:
        if scheduler is not None or client is not None:
            results = _results_dask(study.task, todo, scheduler, client)
        else:
            results = _results_local(study.task, todo, min(int(workers), len(todo)))
        bar = progress(total=len(todo), desc=f"{study.name}", unit="run", quiet=quiet)
        try:
            with table.appender() as f:
                for spec, res in results:
                    row = dict(res["row"])
                    row.update(run_id=spec.run_id, status=res["status"], error=res["error"])
                    for k in param_columns:
                        row.setdefault(k, spec.params[k])
                    if res["arrays"] and study.save_curves:
                        _save_curves(out, spec, res["arrays"])
                    f.append(row)
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
    rows = table.read()
    if report and len(rows) == len(runs) and all(r["status"] == "ok" for r in rows):
        files = write_report(study, out, runs)
    return CampaignResult(out, len(runs), len(done), n_ok + n_failed, n_failed,
                          time.perf_counter() - t_start, run_s_sum, files)
