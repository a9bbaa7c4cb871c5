"""The runs table: typed columns declared by the study and task (never guessed from a cell),
round trip, torn last line, last row wins, and resuming a campaign from a partial table."""

from __future__ import annotations

import math

import pytest

from fgnav.campaign import load_study, read_runs, run_campaign
from fgnav.campaign.storage import RunsTable
from fgnav.campaign.tasks import Column
from fgnav.errors import InputFormatError, UserError

COLUMNS = (Column("run_id", str), Column("status", str), Column("error", str), Column("label", str),
           Column("n", int), Column("x", float), Column("flag", bool))


def _table(tmp_path):
    t = RunsTable(tmp_path / "runs.csv", COLUMNS)
    t.create()
    return t


def test_round_trip_keeps_types_and_values(tmp_path):
    t = _table(tmp_path)
    rows = [
        {"run_id": "a=1;seed=0", "status": "ok", "error": "", "label": "123", "n": 7, "x": 0.1 + 0.2,
         "flag": True},
        {"run_id": "a=2;seed=0", "status": "failed", "error": 'ValueError: "x, y"\nsecond line', "label": "007",
         "n": None, "x": float("inf"), "flag": False},
        {"run_id": "a=3;seed=0", "status": "ok", "error": "", "label": "true", "n": -3, "x": float("nan"),
         "flag": None},
    ]
    with t.appender() as f:
        for r in rows:
            f.append(r)
    back = t.read()
    assert [r["run_id"] for r in back] == [r["run_id"] for r in rows]
    # declared types, not guessed: text that looks like a number or a boolean stays text
    assert [r["label"] for r in back] == ["123", "007", "true"]
    assert back[0]["x"] == 0.1 + 0.2 and type(back[0]["n"]) is int and back[0]["flag"] is True
    assert back[1]["n"] is None and back[1]["x"] == math.inf and back[1]["flag"] is False
    assert back[1]["error"] == rows[1]["error"]
    assert math.isnan(back[2]["x"]) and back[2]["flag"] is None and back[0]["error"] == ""


def test_an_integer_written_to_a_float_column_reads_as_float(tmp_path):
    t = _table(tmp_path)
    with t.appender() as f:
        f.append({"run_id": "r", "status": "ok", "x": 3, "n": 2})
    (r,) = t.read()
    assert r["x"] == 3.0 and type(r["x"]) is float and type(r["n"]) is int


def test_torn_line_ignored_and_last_row_wins(tmp_path):
    t = _table(tmp_path)
    with t.appender() as f:
        f.append({"run_id": "r1", "status": "failed", "error": "boom"})
        f.append({"run_id": "r2", "status": "ok", "n": 1})
        f.append({"run_id": "r1", "status": "ok", "n": 2})
    with t.path.open("a") as f:
        f.write("r3,ok,,x,")                       # killed mid-write
    rows = t.read()
    assert [(r["run_id"], r["status"], r["n"]) for r in rows] == [("r1", "ok", 2), ("r2", "ok", 1)]
    t.drop_torn_line()
    assert t.path.read_text().endswith("r1,ok,,,2,,\n")


def test_a_cell_of_the_wrong_type_names_line_and_column(tmp_path):
    t = _table(tmp_path)
    with t.path.open("a") as f:
        f.write("r1,ok,,a,1,0.5,true\nr2,ok,,b,two,0.5,true\n")
    with pytest.raises(InputFormatError, match=r"line 3, column 'n': expected an integer, found 'two'"):
        t.read()
    t.path.write_text("run_id,status,error,label,n,x,flag\nr1,ok,,a,1,0.5,yes\n")
    with pytest.raises(InputFormatError, match=r"line 2, column 'flag'"):
        t.read()
    t.path.write_text("run_id,status,label\n")
    with pytest.raises(InputFormatError, match="line 1"):
        t.read()


TABLE5 = """
name = "t5"
task = "seed000-table5"
report = "seed000-table5"
seeds = [0, 1]
[grid]
alt_km = [4000.0, 36000.0]
angle_error_deg = [0.001, 0.010]
"""


@pytest.fixture(scope="module")
def table5(tmp_path_factory):
    d = tmp_path_factory.mktemp("t5")
    (d / "t5.toml").write_text(TABLE5)
    study = load_study(d / "t5.toml")
    run_campaign(study, d / "full", workers=1)
    return study, d


def test_campaign_runs_table_is_typed_by_the_study(table5):
    study, d = table5
    rows = read_runs(d / "full")
    assert len(rows) == 8
    r = rows[0]
    assert r["run_id"] == "alt_km=4000.0;angle_error_deg=0.001;seed=0"
    assert type(r["alt_km"]) is float and type(r["seed"]) is int and type(r["ours_mc_km"]) is float
    assert r["alt_km"] == 4000.0 and r["angle_error_deg"] == 0.001
    assert read_runs(d / "full", study) == rows      # from study.json or from the study: the same


def test_resume_after_a_partial_table(table5, tmp_path):
    """A table holding two finished runs, one failed run and a torn line: the resume runs the
    other five and the failed one again, and ends with the rows of an uninterrupted run."""
    study, d = table5
    full = {r["run_id"]: r for r in read_runs(d / "full")}
    out = tmp_path / "part"
    with pytest.raises(KeyboardInterrupt):
        run_campaign(study, out, workers=1,
                     on_result=lambda r: (_ for _ in ()).throw(KeyboardInterrupt) if r["seed"] == 1 else None)
    first = [r["run_id"] for r in read_runs(out)]
    assert len(first) == 2
    table = RunsTable(out / "runs.csv", study.columns())
    failed_id = "alt_km=36000.0;angle_error_deg=0.01;seed=1"
    with table.appender() as f:
        f.append({"run_id": failed_id, "status": "failed", "error": "RuntimeError: lost the worker"})
    with table.path.open("a") as f:
        f.write("alt_km=36000.0;angle_error_deg=0.001;seed=0,ok,,36000.0,0.0")   # torn
    ran = []
    res = run_campaign(study, out, workers=1, resume=True, on_result=lambda r: ran.append(r["run_id"]))
    assert res.n_skipped == 2 and res.n_ran == 6 and res.n_failed == 0
    assert failed_id in ran and not set(ran) & set(first)
    strip = lambda r: {k: v for k, v in r.items() if k not in ("run_s", "worker")}
    assert {k: strip(v) for k, v in ((r["run_id"], r) for r in read_runs(out))} == \
        {k: strip(v) for k, v in full.items()}
    assert (out / "table.csv").read_text() == (d / "full" / "table.csv").read_text()


def test_read_runs_needs_study_json(tmp_path):
    (tmp_path / "runs.csv").write_text("run_id,status,error,seed\n")
    with pytest.raises(UserError, match="study.json"):
        read_runs(tmp_path)
    assert read_runs(tmp_path / "nothing-here") == []
