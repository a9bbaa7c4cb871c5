"""Campaign runner: determinism across executors, streaming + resume after interruption."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest

from fgnav.campaign import (TIMING_COLUMNS, builtin_studies, load_study, read_runs, run_campaign,
                            study_runs)
from fgnav.errors import InputFormatError, UserError

TINY = """
name = "tiny"
task = "navigate"
report = "seed002-noise"
methods = ["batch", "ekf"]
seeds = [0, 1]
save_curves = true
[fixed]
scenario = "gto-transfer"
step_s = 120.0
duration_h = 1.0
[grid]
sigma_deg = [0.01, 0.05]
"""


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    path = tmp_path_factory.mktemp("study") / "tiny.toml"
    path.write_text(TINY)
    return load_study(path)


@pytest.fixture(scope="module")
def reference(tiny, tmp_path_factory):
    out = tmp_path_factory.mktemp("ref")
    res = run_campaign(tiny, out, workers=1)
    return out, res


def _results(out):
    return {r["run_id"]: {k: v for k, v in r.items() if k not in TIMING_COLUMNS} for r in read_runs(out)}


def test_builtin_studies_load_and_expand():
    names = builtin_studies()
    for required in ("seed002-noise", "seed002-period", "seed002-observability", "seed002-visibility",
                     "seed000-table5", "gto-nees"):
        assert required in names
    s = load_study("seed002-noise")
    runs = study_runs(s)
    assert len(runs) == 5 * 2 * 5
    assert len({r.run_id for r in runs}) == len(runs)
    assert {r.params["sigma_deg"] for r in runs} == {0.01, 0.02, 0.05, 0.1, 0.2}
    assert len(study_runs(load_study("gto-nees"))) == 300


def test_bad_study_files(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(TINY.replace('task = "navigate"', 'task = "juggle"'))
    with pytest.raises(InputFormatError, match="task"):
        load_study(bad)
    bad.write_text(TINY.replace("sigma_deg = [0.01, 0.05]", "colour = [1]"))
    with pytest.raises(InputFormatError, match="colour"):
        load_study(bad)
    bad.write_text(TINY.replace('methods = ["batch", "ekf"]', 'methods = ["magic"]'))
    with pytest.raises(InputFormatError, match="methods"):
        load_study(bad)
    with pytest.raises(UserError, match="unknown study"):
        load_study("no-such-study")


def test_reference_run_writes_table_and_curves(tiny, reference):
    out, res = reference
    assert res.n_runs == 8 and res.n_ran == 8 and res.n_failed == 0 and res.n_skipped == 0
    rows = read_runs(out)
    assert len(rows) == 8 and all(r["status"] == "ok" for r in rows)
    for name in ("table.csv", "table.md", "plot.png", "study.json"):
        assert (out / name).stat().st_size > 0
    assert len(list((out / "curves").glob("*.npz"))) == 8
    # the smaller noise navigates better (the trend of Pan & Yao 2017, table 2), for both methods
    by = {(r["sigma_deg"], r["method"], r["seed"]): r for r in rows}
    for m in ("batch", "ekf"):
        small = sum(by[(0.01, m, s)]["position_rms_m"] for s in (0, 1))
        large = sum(by[(0.05, m, s)]["position_rms_m"] for s in (0, 1))
        assert small < large


def test_same_numbers_with_two_workers_and_dask(tiny, reference, tmp_path):
    ref = _results(reference[0])
    run_campaign(tiny, tmp_path / "w2", workers=2)
    assert _results(tmp_path / "w2") == ref
    from dask.distributed import Client, LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        res = run_campaign(tiny, tmp_path / "dask", client=client)
    assert res.n_ran == 8 and res.n_failed == 0
    assert _results(tmp_path / "dask") == ref
    t_ref = (reference[0] / "table.csv").read_text().splitlines()
    t_dask = (tmp_path / "dask" / "table.csv").read_text().splitlines()
    col = t_ref[0].split(",").index("solve_s")
    strip = lambda lines: [",".join(c for i, c in enumerate(line.split(",")) if i != col) for line in lines]
    assert strip(t_ref) == strip(t_dask)


def test_interrupt_then_resume_completes_without_rerunning(tiny, reference, tmp_path):
    out = tmp_path / "c"
    seen = []

    def stop_after_three(row):
        seen.append(row["run_id"])
        if len(seen) == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_campaign(tiny, out, workers=1, on_result=stop_after_three)
    assert [r["run_id"] for r in read_runs(out)] == seen
    assert not (out / "table.csv").exists()
    with pytest.raises(UserError, match="--resume"):
        run_campaign(tiny, out, workers=1)
    second = []
    res = run_campaign(tiny, out, workers=1, resume=True, on_result=lambda r: second.append(r["run_id"]))
    assert res.n_skipped == 3 and res.n_ran == 5
    assert not set(second) & set(seen)
    assert _results(out) == _results(reference[0])
    assert (out / "table.md").exists()
    # nothing left: a second resume runs nothing
    assert run_campaign(tiny, out, workers=1, resume=True).n_ran == 0


def test_torn_last_line_is_dropped_on_resume(tiny, reference, tmp_path):
    out = tmp_path / "t"
    with pytest.raises(KeyboardInterrupt):
        run_campaign(tiny, out, workers=1, on_result=lambda r: (_ for _ in ()).throw(KeyboardInterrupt))
    with (out / "runs.csv").open("a") as f:
        f.write("sigma_deg=0.05;method=ekf;seed=1,ok,,0.05,ek")   # killed mid-write
    assert len(read_runs(out)) == 1
    res = run_campaign(tiny, out, workers=1, resume=True)
    assert res.n_ran == 7
    assert _results(out) == _results(reference[0])


def test_resume_refuses_a_different_study(tiny, reference, tmp_path):
    other = tmp_path / "other.toml"
    other.write_text(TINY.replace("seeds = [0, 1]", "seeds = [5]"))
    with pytest.raises(UserError, match="different study"):
        run_campaign(load_study(other), reference[0], resume=True)


def test_killed_subprocess_resumes(tiny, reference, tmp_path):
    study = tmp_path / "tiny.toml"
    study.write_text(TINY)
    out = tmp_path / "k"
    proc = subprocess.Popen([sys.executable, "-m", "fgnav", "campaign", str(study), "--out", str(out),
                             "--workers", "1", "--quiet"], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 60
        while time.time() < deadline and len(read_runs(out)) < 2 and proc.poll() is None:
            time.sleep(0.05)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    done_before = {r["run_id"] for r in read_runs(out) if r["status"] == "ok"}
    assert 2 <= len(done_before) < 8
    second = []
    res = run_campaign(tiny, out, workers=1, resume=True, on_result=lambda r: second.append(r["run_id"]))
    assert not set(second) & done_before and res.n_ran == 8 - len(done_before)
    assert _results(out) == _results(reference[0])


def test_a_study_whose_runs_cannot_start_is_refused_whole(tmp_path, capsys):
    """Unknown scenario, formation scenario, a pass beyond the simulator's limits, a negative
    seed: exit 2 before any run, the file and the failing runs named, even with --quiet, and
    nothing written (the integrity issue's campaign defect)."""
    from fgnav.cli import main

    base = TINY.replace("seeds = [0, 1]", "seeds = [0]").replace('["batch", "ekf"]', '["ekf"]')
    cases = {
        "unknown": (base.replace('scenario = "gto-transfer"\n', "").replace(
            "sigma_deg = [0.01, 0.05]",
            'sigma_deg = [0.01]\nscenario = ["gto-transfer", "no-such-scenario"]'),
            "scenario=no-such-scenario;method=ekf: unknown scenario 'no-such-scenario'"),
        "formation": (base.replace('scenario = "gto-transfer"', 'scenario = "formation-gto"'),
                      "is a formation of several spacecraft"),
        "too long": (base.replace("duration_h = 1.0", "duration_h = 1e6"),
                     "exceeds the limit of 744 h"),
        "seed": (base.replace("seeds = [0]", "seeds = { start = -2, count = 3 }"),
                 "seeds.start': expected an integer >= 0, found -2"),
    }
    for name, (text, message) in cases.items():
        study = tmp_path / f"{name.replace(' ', '_')}.toml"
        study.write_text(text)
        out = tmp_path / f"o_{study.stem}"
        rc = main(["campaign", str(study), "--out", str(out), "--workers", "1", "--quiet"])
        err = capsys.readouterr().err
        assert rc == 2, name
        assert str(study) in err and message in err, (name, err)
        assert not (out / "runs.csv").exists(), name


def test_failed_runs_are_recorded_and_cli_json(tmp_path, capsys, monkeypatch):
    """A run that fails while it runs (past the checks) is recorded with its error, the others
    go on, and the command exits 3 (results written, not all runs done)."""
    from fgnav.campaign import tasks
    from fgnav.cli import main

    navigate = tasks.TASKS["navigate"]

    def fails_at_0_05(p):
        if p.sigma_deg == 0.05:
            raise FloatingPointError("a numerical failure of this run")
        return navigate.run(p)

    monkeypatch.setitem(tasks.TASKS, "navigate", replace(navigate, run=fails_at_0_05))
    study = tmp_path / "f.toml"
    study.write_text(TINY.replace("seeds = [0, 1]", "seeds = [0]").replace('["batch", "ekf"]', '["ekf"]'))
    rc = main(["campaign", str(study), "--out", str(tmp_path / "o"), "--workers", "1", "--json", "--quiet"])
    out = capsys.readouterr().out
    d = json.loads(out)
    assert rc == 3 and d["n_ran"] == 2 and d["n_failed"] == 1
    assert d["failed_runs"] == ["sigma_deg=0.05;method=ekf;seed=0"]
    rows = {r["run_id"]: r for r in read_runs(tmp_path / "o")}
    assert "a numerical failure of this run" in rows[d["failed_runs"][0]]["error"]
    assert rows["sigma_deg=0.01;method=ekf;seed=0"]["status"] == "ok"
    assert not (tmp_path / "o" / "table.csv").exists()


def test_help_is_fast_and_has_units():
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "fgnav", "campaign", "--help"], capture_output=True,
                       text=True, env={**os.environ})
    assert r.returncode == 0 and "--scheduler" in r.stdout and "--resume" in r.stdout
    assert time.perf_counter() - t0 < 10  # generous; the 1 s target is checked by the CLI tests
