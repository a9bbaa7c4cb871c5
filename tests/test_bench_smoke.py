"""Smoke test of the benchmark script: ``scripts/bench.py --quick`` runs and prints one JSON
object with the documented keys. Speed itself is never asserted (only with ``-m bench``)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

CASE_KEYS = {"method", "epochs", "wall_s", "solver_s", "epochs_per_s", "peak_rss_mb", "runs"}
LATENCY_KEYS = {"latency_p50_s", "latency_p99_s", "latency_max_s"}


@pytest.mark.bench
def test_bench_quick_prints_one_json_object():
    r = subprocess.run([sys.executable, str(ROOT / "scripts" / "bench.py"), "--quick"],
                       capture_output=True, text=True, timeout=300, cwd=str(ROOT))
    assert r.returncode == 0, r.stderr[-2000:]
    out = json.loads(r.stdout)          # the whole stdout is one JSON object
    assert out["mode"] == "quick" and out["repeat"] == 1
    cases = out["cases"]
    for name in ("ekf_numba_4h", "batch_4h", "batch_24h", "fixed_lag_4h", "isam2_4h"):
        c = cases[name]
        assert "error" not in c, (name, c)
        assert CASE_KEYS <= set(c), (name, sorted(c))
        assert c["epochs"] > 0 and c["solver_s"] > 0 and c["wall_s"] >= c["solver_s"]
        assert c["peak_rss_mb"] > 0
        assert "meets_targets" in c and "targets" in c
    for name in ("ekf_numba_4h", "fixed_lag_4h", "isam2_4h"):
        c = cases[name]
        assert LATENCY_KEYS <= set(c)
        assert c["latency_p50_s"] <= c["latency_p99_s"] <= c["latency_max_s"]
    assert cases["ekf_numba_4h"]["step_s"] > 0
    for name in ("batch_4h", "fixed_lag_4h", "isam2_4h"):
        assert cases[name]["ekf_time_ratio"] > 0
    assert cases["batch_4h"]["marginals"] is True
    cs = cases["cold_start"]
    assert {"help_s", "demo_second_run_recompiled", "demo_second_run_cache_loaded"} <= set(cs)
    assert all(run["returncode"] == 0 for run in cs["demo_runs"])
    assert cs["help_imports_heavy"] == []   # fgnav --help imports no numpy/gtsam/cv2/numba
    assert out["batch_cost_growth"] > 0
    im = cases["images"]
    assert "error" not in im, im
    assert im["frames"] == 62 and 0 < im["frames_mb"] < 200 and im["wall_s"] > 0  # 31 epochs x 2
    assert im["before"]["frames_mb"] > 1000 and "meets_targets" in im
    for name, base in (("batch_att_4h", "batch_4h"), ("isam2_att_4h", "isam2_4h")):
        c = cases[name]
        assert "error" not in c, (name, c)
        assert CASE_KEYS <= set(c) and "meets_targets" in c
        assert c["att_base_case"] == base and c["epochs"] == cases[base]["epochs"]
        assert c["att_ratio"] == pytest.approx(c["solver_s"] / cases[base]["solver_s"])
        assert c["attitude_rms_arcsec"] < 20.0
    assert cases["batch_att_4h"]["targets"] == {"att_ratio_max": 2.5}
    assert LATENCY_KEYS <= set(cases["isam2_att_4h"])
    for name, epochs in (("process_241", 241), ("process_4h", 1441), ("batch_1m", 5000)):
        c = cases[name]
        assert "error" not in c.get("after", {}), (name, c)
        assert c["epochs"] == epochs and "fgnav smooth" in c["command"]
        assert {"wall_s", "cpu_s", "summary_wall_s", "peak_rss_mb"} <= set(c["after"])
        assert c["after"]["wall_s"] >= c["after"]["summary_wall_s"] > 0
        assert "meets_targets" in c


@pytest.mark.bench
def test_bench_process_cases_beside_a_before_tree():
    """``--before-tree``: the same command in another checkout, same session; this checkout
    against itself gives identical trajectories and ratios near 1."""
    r = subprocess.run([sys.executable, str(ROOT / "scripts" / "bench.py"), "--quick",
                        "--cases", "process_241", "--before-tree", str(ROOT)],
                       capture_output=True, text=True, timeout=600, cwd=str(ROOT))
    assert r.returncode == 0, r.stderr[-2000:]
    c = json.loads(r.stdout)["cases"]["process_241"]
    assert c["trajectory_identical"] is True
    assert {"wall_s", "cpu_s", "peak_rss_mb"} <= set(c["after_over_before"])
    assert 0.5 < c["after_over_before"]["peak_rss_mb"] < 2.0


def _bench_module():
    import importlib.util

    spec = importlib.util.spec_from_file_location("fgnav_bench_script", ROOT / "scripts" / "bench.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_attitude_pass_observes_the_attitude_and_solves_it(tmp_path):
    """The pass of the ``*_att_*`` cases: one attitude row and one body-frame Earth direction per
    epoch, the attitude rows within their few arcsec of the LVLH truth, and the worker's batch
    solve with the attitude in the graph recovers it (arcsec)."""
    import pickle

    import numpy as np

    from factors.geometry import so3_exp, so3_log

    bench = _bench_module()
    f = bench.make_pass(0.02, 3, tmp_path, "att")
    with open(f, "rb") as fh:
        p, x_true, R_true = pickle.load(fh)
    assert [v.name for v in p.layout.extra] == ["attitude"]
    assert set(p.families) >= {"attitude", "earth_direction_body"} and "earth_direction" not in p.families
    att = p.families["attitude"]
    assert len(att) == len(p.families["earth_direction_body"]) == p.n_epochs == len(R_true)
    sig = bench.ATT_SIGMA_ARCSEC * np.pi / (180.0 * 3600.0)
    e = so3_log(np.swapaxes(R_true, 1, 2) @ att.values["R_eci_from_body"])
    assert 0.5 * sig < np.sqrt(np.mean(e ** 2)) < 2.0 * sig      # the simulated noise, per axis
    out = bench.worker("batch", str(f))
    assert out["converged"] and out["marginals"]
    assert out["attitude_rms_arcsec"] < 3.0 * bench.ATT_SIGMA_ARCSEC
    assert np.isfinite(out["position_rms_m"])


def test_batch_first_guess_with_the_attitude_in_the_graph_leaves_the_solution_as_it_was(tmp_path):
    """With the attitude estimated, the batch's first guess is the numba EKF on the pass with
    the attitude known (body rows rotated into ECI by the attitude rows); Gauss-Newton then
    solves the whole graph, so the solution is the one continuation from the prior gives."""
    import pickle
    from dataclasses import replace

    import numpy as np

    from factors.geometry import so3_exp, so3_log
    from fgnav.solvers.batch import _orbit_only_pass, smooth_batch
    from fgnav.solvers.ekf_numba import numba_supports
    from fgnav.solvers.options import SmootherOptions

    with open(_bench_module().make_pass(0.1, 1, tmp_path, "att"), "rb") as fh:
        p = pickle.load(fh)[0]
    q = _orbit_only_pass(p)
    assert q is not None and numba_supports(q) and q.layout.n == 6
    assert set(q.families) == {"prior_position", "prior_velocity", "earth_direction"}
    assert np.all(q.families["earth_direction"].values["from_body"])
    assert len(q.families["earth_direction"]) == p.n_epochs
    att = replace(SmootherOptions(), estimate=("attitude",))
    auto, cont = smooth_batch(p, att), smooth_batch(p, replace(att, init="prior"))
    assert auto.extras["converged"] and cont.extras["converged"]
    assert auto.extras["q_stages"] == [att.q_m2_s3] != cont.extras["q_stages"]   # EKF guess taken
    sig = np.sqrt(np.diagonal(cont.P_eci, axis1=1, axis2=2))
    assert np.max(np.abs(auto.x_eci - cont.x_eci) / sig) < 1e-2
    (wa, _), (wc, Pc) = auto.variables["attitude"], cont.variables["attitude"]
    d = so3_log(np.swapaxes(so3_exp(wc), 1, 2) @ so3_exp(wa))
    assert np.max(np.abs(d) / np.sqrt(np.diagonal(Pc, axis1=1, axis2=2))) < 1e-2
