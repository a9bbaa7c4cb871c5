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
