"""A study: a TOML file (``data/studies/*.toml``) read into a frozen, validated :class:`Study`.

Keys (anything else is an error naming the file and the key)::

    name = "seed002-noise"
    description = "..."          # one line, shown by `fgnav campaign --list`
    task = "navigate"            # the kind of run (TASKS): navigate | observability | visibility | seed000-table5
    report = "seed002-noise"     # how the runs are summarized (REPORTS)
    methods = ["ekf", "batch"]   # navigate/visibility only: solvers (fgnav.pipeline.METHODS)
    seeds = [0, 1, 2]            # or: seeds = {start = 0, count = 100}
    save_curves = false          # navigate: keep per-epoch NEES/NIS arrays (curves/*.npz)
    [fixed]                      # parameters shared by every run (the task's parameter type)
    scenario = "gto-transfer"
    [grid]                       # parameters swept (cartesian product, in file order)
    sigma_deg = [0.01, 0.02, 0.05]
    [reference]                  # the report's bounds and reference figures (REPORTS)
    max_sigma_deg = 0.05

Every parameter is checked against the task's parameter dataclass (name, type, > 0 where
the field says so); every reference key against the report's reference dataclass
(:func:`fgnav.io.toml_schema.typed_value`, :func:`~fgnav.io.toml_schema.typed_object`: the
one typed-TOML validator, which the scenario files use too).
"""

from __future__ import annotations

import itertools
import types
import typing
from dataclasses import MISSING, dataclass, field, fields, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

from fgnav.campaign.reports import REPORTS
from fgnav.campaign.tasks import TASKS, Column, RunParams
from fgnav.errors import InputFormatError, UserError
from fgnav.io.text import load_toml
from fgnav.io.toml_schema import typed_object, typed_value
from fgnav.paths import data_dir
from fgnav.pipeline import METHODS

__all__ = ["Study", "RunSpec", "load_study", "builtin_studies", "study_runs", "run_columns",
           "typed_value", "typed_object"]

STUDY_KEYS = ("name", "description", "task", "report", "methods", "seeds", "save_curves", "fixed",
              "grid", "reference")
EXAMPLE = "see data/studies/seed002-noise.toml"


def _scalar_type(tp) -> type:
    """The cell type of a parameter column: the annotation without ``None``."""
    args = [a for a in typing.get_args(tp) if a is not type(None)]
    base = args[0] if typing.get_origin(tp) in (types.UnionType, typing.Union) and len(args) == 1 else tp
    return base if base in (str, int, float, bool) else None


# ---- the study -------------------------------------------------------------------------

@dataclass(frozen=True)
class Study:
    """A validated study. ``fixed`` / ``grid`` hold the parameter values already typed
    (floats as float, lists as tuples); ``reference`` is the report's reference dataclass
    (``None`` when the study file has no ``[reference]`` and the report allows it)."""
    name: str
    task: str
    report: str
    description: str = ""
    methods: tuple[str, ...] = ("",)
    seeds: tuple[int, ...] = (0,)
    fixed: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))
    grid: Mapping[str, tuple] = field(default_factory=lambda: MappingProxyType({}))
    save_curves: bool = False
    reference: Any = None
    source: str = ""

    def to_json(self) -> dict:
        """What defines the runs (compared on ``--resume``); ``study.json`` adds ``reference``."""
        return {"name": self.name, "task": self.task, "report": self.report, "description": self.description,
                "methods": list(self.methods), "seeds": list(self.seeds),
                "fixed": {k: list(v) if isinstance(v, tuple) else v for k, v in self.fixed.items()},
                "grid": {k: list(v) for k, v in self.grid.items()}, "save_curves": self.save_curves}

    def reference_json(self) -> dict | None:
        if self.reference is None:
            return None
        return {f.name: _jsonable(getattr(self.reference, f.name)) for f in fields(self.reference)}

    def columns(self) -> tuple[Column, ...]:
        """The runs table's columns, typed (storage.RunsTable)."""
        return run_columns(self.task, tuple(self.grid), self.methods != ("",))


def _jsonable(v):
    if isinstance(v, tuple):
        return [_jsonable(x) for x in v]
    if isinstance(v, Mapping):
        return {repr(k) if isinstance(k, float) else str(k): _jsonable(x) for k, x in v.items()}
    return v


def run_columns(task: str, grid_keys: tuple[str, ...], with_method: bool) -> tuple[Column, ...]:
    """``run_id, status, error``, the swept parameters, ``method``, ``seed``, the task's
    result columns, then ``run_s`` and ``worker`` (execution)."""
    t = TASKS[task]
    hints = typing.get_type_hints(t.params)
    params = [Column(k, _scalar_type(hints[k])) for k in grid_keys]
    params += [Column("method", str)] * with_method + [Column("seed", int)]
    names = {c.name for c in t.columns}
    return (Column("run_id", str), Column("status", str), Column("error", str), *params, *t.columns,
            *(c for c in (Column("run_s", float), Column("worker", str)) if c.name not in names))


@dataclass(frozen=True)
class RunSpec:
    """One run: its id (``sigma_deg=0.01;method=ekf;seed=3``) and its typed parameters."""
    run_id: str
    params: RunParams


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

    return study_from_dict(load_toml(path, "a study TOML file"), path)


def _seeds(path, v) -> tuple[int, ...]:
    if isinstance(v, dict):
        extra = set(v) - {"start", "count"}
        if extra:
            raise InputFormatError(path, None, f"seeds.{sorted(extra)[0]}", "only the keys start and count",
                                   sorted(extra)[0])
        start = typed_value(path, "seeds.start", v.get("start", 0), int)
        if start < 0:
            raise InputFormatError(path, None, "seeds.start", "an integer >= 0", start)
        if "count" not in v:
            raise InputFormatError(path, None, "seeds.count", "this key (seeds = {start = .., count = ..})")
        count = typed_value(path, "seeds.count", v["count"], int, positive=True)
        return tuple(range(start, start + count))
    if not isinstance(v, list) or not v or not all(isinstance(s, int) and not isinstance(s, bool) for s in v):
        raise InputFormatError(path, None, "seeds", "a non-empty list of integers or {start = .., count = ..}", v)
    if len(set(v)) != len(v):
        raise InputFormatError(path, None, "seeds", "distinct seeds", v)
    if min(v) < 0:
        raise InputFormatError(path, None, "seeds", "integers >= 0", min(v))
    return tuple(v)


def study_from_dict(d: dict, path) -> Study:
    """Validate the parsed TOML ``d`` of the study file ``path`` (module doc)."""
    for k in d:
        if k not in STUDY_KEYS:
            raise InputFormatError(path, None, k, f"one of the keys {STUDY_KEYS} ({EXAMPLE})", k)
    for key in ("name", "task", "report"):
        if key not in d:
            raise InputFormatError(path, None, key, f"this key ({EXAMPLE})")
    name = typed_value(path, "name", d["name"], str)
    description = d.get("description", "")
    if not isinstance(description, str):
        raise InputFormatError(path, None, "description", "a string", description)
    if d["task"] not in TASKS:
        raise InputFormatError(path, None, "task", f"one of {tuple(TASKS)}", d["task"])
    task = TASKS[d["task"]]
    if d["report"] not in REPORTS:
        raise InputFormatError(path, None, "report", f"one of {tuple(REPORTS)}", d["report"])
    report = REPORTS[d["report"]]
    if task.name not in report.tasks:
        raise InputFormatError(path, None, "report", f"a report of task '{task.name}' "
                               f"({tuple(r for r in REPORTS if task.name in REPORTS[r].tasks)})", d["report"])
    seeds = _seeds(path, d.get("seeds", [0]))
    if task.takes_method:
        methods = d.get("methods")
        if (not isinstance(methods, list) or not methods or any(m not in METHODS for m in methods)
                or len(set(methods)) != len(methods)):
            raise InputFormatError(path, None, "methods", f"a non-empty list of distinct {METHODS}", methods)
        methods = tuple(methods)
    else:
        if "methods" in d:
            raise InputFormatError(path, None, "methods", f"no methods: task '{task.name}' runs no solver",
                                   d["methods"])
        methods = ("",)
    save_curves = typed_value(path, "save_curves", d.get("save_curves", False), bool)
    fixed_d, grid_d = d.get("fixed", {}), d.get("grid", {})
    for key, table in (("fixed", fixed_d), ("grid", grid_d)):
        if not isinstance(table, dict):
            raise InputFormatError(path, None, key, "a table of parameters", table)
    hints = typing.get_type_hints(task.params)
    pfields = {f.name: f for f in fields(task.params) if f.name not in ("seed", "method")}

    def param(prefix, key, v):
        k = key.split("[")[0]
        if k not in pfields:
            raise InputFormatError(path, None, f"{prefix}{k}",
                                   f"a parameter of task '{task.name}' {tuple(pfields)}", k)
        return typed_value(path, f"{prefix}{key}", v, hints[k], pfields[k].metadata.get("positive", False))

    fixed = {k: param("fixed.", k, v) for k, v in fixed_d.items()}
    grid = {}
    for k, v in grid_d.items():
        if not isinstance(v, list) or not v:
            raise InputFormatError(path, None, f"grid.{k}", "a non-empty list of values", v)
        if k not in pfields:
            param("grid.", k, v)  # raises: not a parameter of the task
        if _scalar_type(hints[k]) is None:
            raise InputFormatError(path, None, f"grid.{k}", "a scalar parameter (a list-valued one goes in [fixed])", v)
        grid[k] = tuple(param("grid.", f"{k}[{i}]", x) for i, x in enumerate(v))
        if len(set(grid[k])) != len(grid[k]):
            raise InputFormatError(path, None, f"grid.{k}", "distinct values", v)
    overlap = set(grid) & set(fixed)
    if overlap:
        raise InputFormatError(path, None, "grid", "parameters not also in [fixed]", sorted(overlap))
    given = set(fixed) | set(grid)
    for k, f in pfields.items():
        if f.default is MISSING and k not in given:
            raise InputFormatError(path, None, f"fixed.{k}", f"this parameter of task '{task.name}' "
                                   "(in [fixed] or [grid])")
    if "reference" in d:
        if report.reference is None:
            raise InputFormatError(path, None, "reference", f"no [reference]: report '{report.name}' uses none")
        if not isinstance(d["reference"], dict):
            raise InputFormatError(path, None, "reference", "a table", d["reference"])
        reference = typed_object(report.reference, d["reference"], path, "reference.")
    elif report.reference is not None and report.reference_required:
        raise InputFormatError(path, None, "reference", f"a [reference] table (report '{report.name}': "
                               f"keys {tuple(f.name for f in fields(report.reference))})")
    else:
        reference = None
    study = Study(name=name, task=task.name, report=report.name, description=description,
                  methods=methods, seeds=seeds, fixed=MappingProxyType(fixed),
                  grid=MappingProxyType(grid), save_curves=save_curves, reference=reference,
                  source=str(path))
    check_runs(study)
    return study


def check_runs(study: Study, shown: int = 10) -> None:
    """Refuse a study whole, before any run, when one of its runs cannot start (an unknown
    scenario, a formation, a pass beyond the simulator's limits, ...): ``task.check`` on each
    grid point and method (the seeds were checked with the file). ``UserError`` naming the
    study file and the first ``shown`` runs with their reasons."""
    task = TASKS[study.task]
    points = study_runs(replace(study, seeds=study.seeds[:1]))   # each with every seed
    bad = []
    for run in points:
        try:
            task.check(run.params)
        except UserError as exc:
            where = ";".join(x for x in run.run_id.split(";") if not x.startswith("seed="))
            bad.append(f"{where or 'every run'}: {exc}")
    if bad:
        n = len(study.seeds)
        lines = "\n".join(f"  {b}" for b in bad[:shown])
        more = f"\n  ... and {len(bad) - shown} more" if len(bad) > shown else ""
        raise UserError(f"{study.source}: {len(bad) * n} of {len(points) * n} run(s) cannot "
                        f"start, so none was started:\n{lines}{more}")


def _fmt(v) -> str:
    return repr(float(v)) if isinstance(v, float) else str(v)


def study_runs(study: Study) -> list[RunSpec]:
    """Every run of the study in a fixed order: grid (file order) x methods x seeds."""
    task = TASKS[study.task]
    keys = list(study.grid)
    runs = []
    for combo in itertools.product(*(study.grid[k] for k in keys)):
        for method in study.methods:
            for seed in study.seeds:
                kw = dict(study.fixed)
                kw.update(zip(keys, combo))
                parts = [f"{k}={_fmt(v)}" for k, v in zip(keys, combo)]
                if method:
                    kw["method"] = method
                    parts.append(f"method={method}")
                kw["seed"] = seed
                parts.append(f"seed={seed}")
                runs.append(RunSpec(";".join(parts), task.params(**kw)))
    return runs
