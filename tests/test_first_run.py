"""The first-run notice: printed once while cached kernels compile, never on a warm run."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from fgnav.first_run import MESSAGE

ROOT = Path(__file__).resolve().parents[1]

KERNEL = '''
from factors.jit import njit  # as fgnav's kernels: numba imported at the first call

@njit(cache=True)
def twice(x):
    return 2.0 * x

@njit  # not cached: compiled on every run, never announced
def thrice(x):
    return 3.0 * x
'''

RUN = '''
import sys
sys.path.insert(0, sys.argv[1])
from fgnav.first_run import announce_first_compile
announce_first_compile(packages=("kern",))
announce_first_compile(packages=("kern",))   # idempotent: one listener
import kern
print(kern.twice(1.0) + kern.twice(2.0) + kern.thrice(1.0))
'''


def _run(tmp_path, code, *args, cache_dir):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir), PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                          env=env, cwd=str(tmp_path), timeout=600)


def test_notice_on_a_cold_cache_only(tmp_path):
    (tmp_path / "kern.py").write_text(KERNEL)
    cache = tmp_path / "numba-cache"
    cold = _run(tmp_path, RUN, str(tmp_path), cache_dir=cache)
    assert cold.returncode == 0, cold.stderr
    assert cold.stdout.strip() == "9.0"
    assert cold.stderr.count(MESSAGE) == 1
    warm = _run(tmp_path, RUN, str(tmp_path), cache_dir=cache)
    assert warm.returncode == 0, warm.stderr
    assert MESSAGE not in warm.stderr          # the uncached kernel compiled silently


@pytest.mark.slow
def test_smooth_announces_compiling_on_the_first_run_only(tmp_path):
    """``fgnav smooth`` with an empty numba cache: the notice once; again: no notice;
    ``--quiet``: none (first run ~25 s of CPU). The pass (2,881 epochs) is longer than
    ``fgnav.pipeline.SHORT_PASS_ROWS``: shorter ones run no compiled kernel, so never wait
    and never print the notice (checked last)."""
    log = tmp_path / "pass"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"), PYTHONPATH=str(ROOT))
    sim = subprocess.run([sys.executable, "-m", "fgnav", "simulate", "gto-transfer", "--out",
                          str(log), "--step-s", "5", "--quiet"], env=dict(env, NUMBA_CACHE_DIR=str(tmp_path / "c0")),
                         capture_output=True, text=True, cwd=str(ROOT))
    assert sim.returncode == 0, sim.stderr
    cmd = [sys.executable, "-m", "fgnav", "smooth", str(log / "measurements.csv"), "--out"]
    first = subprocess.run(cmd + [str(tmp_path / "o1")], env=env, capture_output=True, text=True,
                           cwd=str(ROOT))
    assert first.returncode == 0, first.stderr
    assert first.stderr.count(MESSAGE) == 1
    second = subprocess.run(cmd + [str(tmp_path / "o2")], env=env, capture_output=True,
                            text=True, cwd=str(ROOT))
    assert second.returncode == 0 and MESSAGE not in second.stderr
    quiet = subprocess.run(cmd + [str(tmp_path / "o3"), "--quiet"],
                           env=dict(env, NUMBA_CACHE_DIR=str(tmp_path / "cache2")),
                           capture_output=True, text=True, cwd=str(ROOT))
    assert quiet.returncode == 0 and MESSAGE not in quiet.stderr
    short = tmp_path / "short"
    sim = subprocess.run([sys.executable, "-m", "fgnav", "simulate", "gto-transfer", "--out",
                          str(short), "--step-s", "60", "--quiet"], env=env, capture_output=True,
                         text=True, cwd=str(ROOT))
    assert sim.returncode == 0, sim.stderr
    cold = subprocess.run([sys.executable, "-m", "fgnav", "smooth", str(short / "measurements.csv"),
                           "--out", str(tmp_path / "o4")],
                          env=dict(env, NUMBA_CACHE_DIR=str(tmp_path / "cache3")),
                          capture_output=True, text=True, cwd=str(ROOT))
    assert cold.returncode == 0 and MESSAGE not in cold.stderr
    assert not any((tmp_path / "cache3").rglob("*.nbi"))   # nothing compiled, nothing cached
