"""Three spacecraft through the one pipeline (formation-gto-3: a triangle, every pair linked
both ways): simulated, smoothed and reported like one spacecraft, with every pair's relative
state in relative.csv and summary.json, checked against the truth of the independent
integrator (scipy DOP853, fgnav.orbit.integrate_truth)."""

from __future__ import annotations

import csv
from dataclasses import replace

import numpy as np
import pytest

from fgnav.cli import main
from fgnav.frames import relative_state_lvlh
from fgnav.io.oem import read_oem
from fgnav.io.summary import read_summary
from fgnav.orbit import truth_at
from fgnav.pipeline import SmoothResult, smooth_file
from fgnav.results import pairs, write_outputs

PAIRS = [("sat1", "sat2"), ("sat1", "sat3"), ("sat2", "sat3")]


@pytest.fixture(scope="module")
def three(tmp_path_factory):
    """``fgnav simulate formation-gto-3 --duration-h 2 --step-s 20``, smoothed with its truth
    as ``fgnav smooth --truth`` does: (pass folder, result folder, result, pass)."""
    d = tmp_path_factory.mktemp("three")
    p, r = d / "p", d / "r"
    assert main(["simulate", "formation-gto-3", "--duration-h", "2", "--step-s", "20",
                 "--out", str(p), "--quiet"]) == 0
    res, ps = smooth_file(p / "measurements.csv", "batch", truth_path=p)
    write_outputs(r, res, ps)
    return p, r, res, ps


def _relative_csv(path):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    out = {}
    for row in rows:
        out.setdefault((row["reference"], row["spacecraft"]), []).append(row)
    return out


def test_pairs_order():
    assert pairs(2) == [(0, 1)]
    assert pairs(3) == [(0, 1), (0, 2), (1, 2)]
    assert pairs(4) == [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]


def test_every_pair_is_within_twice_its_sigma_of_the_truth(three):
    """Each pair's relative position, from relative.csv, against the truth's relative state in
    the chief's LVLH frame: RMS within 2x its own 1-sigma RMS (and the summary says the same
    figures); each spacecraft's trajectory file; verdict ok."""
    p, r, _, _ = three
    names = sorted(f.name for f in r.iterdir() if not f.name.startswith("."))
    assert names == ["relative.csv", "residuals.csv", "summary.json", "trajectory-sat1.oem",
                     "trajectory-sat2.oem", "trajectory-sat3.oem", "variables.csv"]
    s = read_summary(r / "summary.json")
    assert s["integrity"]["status"] == "ok"
    assert list(s["spacecraft"]) == ["sat1", "sat2", "sat3"]
    assert [(d["reference"], d["spacecraft"]) for d in s["relative_pairs"]] == PAIRS
    assert set(s["relative_by_spacecraft"]) == {"sat2", "sat3"}
    assert s["relative"]["position_rms_m"] == s["relative_pairs"][0]["position_rms_m"]
    rel = _relative_csv(r / "relative.csv")
    assert list(rel) == PAIRS
    truth = {sc: read_oem(p / f"truth-{sc}.oem") for sc in ("sat1", "sat2", "sat3")}
    for (c, d), summary in zip(PAIRS, s["relative_pairs"]):
        rows = rel[c, d]
        t = np.array([float(x["t_s"]) for x in rows])
        est = np.array([[float(x[f"lvlh_{k}_m"]) for k in "xyz"] for x in rows])
        sig = np.array([[float(x[f"lvlh_{k}_sigma_m"]) for k in "xyz"] for x in rows])
        true = relative_state_lvlh(truth_at(truth[c].t_s, truth[c].x_eci, t),
                                   truth_at(truth[d].t_s, truth[d].x_eci, t))[0][:, :3]
        rms = float(np.sqrt(np.mean(np.sum((est - true) ** 2, axis=1))))
        sigma_rms = float(np.sqrt(np.mean(np.sum(sig ** 2, axis=1))))
        assert rms < 2.0 * sigma_rms, (c, d, rms, sigma_rms)
        assert summary["position_rms_m"] == pytest.approx(rms, rel=1e-3)   # (9 digits in the files)
        assert summary["sigma_position_rms_m"] == pytest.approx(sigma_rms, rel=1e-3)
        assert rms > 1e-4   # (an estimate, not the truth copied)


def test_the_report_draws_every_pair_and_every_orbit(three):
    """fgnav report on the result: each pair's relative figures, each orbit its own curve."""
    from fgnav.viz.report import report_result_dir

    p, r, _, _ = three
    res = report_result_dir(r, r / "report", truth_path=p)
    for key in ("sat2", "sat3", "sat2-sat3"):
        assert f"relative_errors_lvlh-{key}" in res["images"]
        assert res["images"][f"relative_errors_lvlh-{key}"].is_file()
    labels = [ln.get_label() for ln in res["figures"]["orbit_3d"].axes[0].get_lines()]
    for sc in ("sat1", "sat2", "sat3"):
        assert f"{sc} estimate" in labels and f"{sc} truth" in labels
    md = (r / "report" / "report.md").read_text()
    assert "sat3 from sat2" in md


def test_an_online_formation_writes_its_online_states_per_spacecraft(three, tmp_path):
    """write_outputs with a formation solution carrying online states (the reference's in
    Solution.online_*, the others' in extras['online_variables']): online-<id>.oem per
    spacecraft and latency.csv, their states as given."""
    _, _, res, ps = three
    sol = res.solution
    n = len(sol.t_s)
    shift = np.array([1.0, 2.0, 3.0, 0.0, 0.0, 0.0])
    online = {v.name: (sol.variables[v.name][0] + shift, sol.variables[v.name][1])
              for v in ps.layout.orbits[1:]}
    sol = replace(sol, method="isam2", online_x_eci=sol.x_eci + shift, online_P_eci=sol.P_eci,
                  latency_s=np.full(n, 1e-3), extras={**sol.extras, "online_variables": online})
    write_outputs(tmp_path / "out", SmoothResult(sol, res.summary, None), ps)
    names = sorted(f.name for f in (tmp_path / "out").iterdir() if not f.name.startswith("."))
    assert {"online-sat1.oem", "online-sat2.oem", "online-sat3.oem", "latency.csv"} <= set(names)
    assert "online.oem" not in names
    for s, sc in enumerate(("sat1", "sat2", "sat3")):
        o = read_oem(tmp_path / "out" / f"online-{sc}.oem")
        x = sol.online_x_eci if s == 0 else online[ps.layout.orbits[s].name][0]
        np.testing.assert_allclose(o.x_eci, x, rtol=1e-12, atol=1e-6)
