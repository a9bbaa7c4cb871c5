"""The checks after a solve (Cramer-Rao bound, manoeuvre and omitted-force tests) form their
per-epoch 6x6 matrices in chunks of epochs, and residuals.csv is written in chunks of rows,
so that a 1,000,000-epoch pass never holds them whole: the chunking must not change a bit."""

from __future__ import annotations

import contextlib
import math

import numpy as np
import pytest

import fgnav.diagnostics.crb as crb
import fgnav.diagnostics.integrity as integrity
from fgnav.measurements import build_pass
from fgnav.pipeline import crb_metrics, prepare_pass, solve, summarize
from fgnav.results import write_residuals_csv
from fgnav.simulate import faults as F
from fgnav.solvers.options import SmootherOptions


@pytest.mark.parametrize("made", [F.manoeuvre(5.0), F.gap(1200.0, 1200.0, duration_h=1.0)],
                         ids=["manoeuvre", "gap"])
def test_chunked_checks_are_bit_identical(made, monkeypatch):
    log, t, x = made
    options = SmootherOptions()
    p = prepare_pass(build_pass(log), options)
    sol = solve(p, "batch", options)
    whole = summarize(sol, p, options)
    bound = crb.cramer_rao_bound(p, sol.x_eci, options.motion_model(), keep_covariance=True)
    # chunks of 7 epochs (rows): boundaries everywhere, a last chunk shorter than the others
    monkeypatch.setattr(crb, "CHUNK", 7)
    monkeypatch.setattr(integrity, "CHUNK", 7)
    chunked = summarize(sol, p, options)
    small = crb.cramer_rao_bound(p, sol.x_eci, options.motion_model(), keep_covariance=True)
    assert p.n_epochs % 7 != 0
    for key in ("manoeuvre_glr", "third_body_omitted"):
        assert key in whole["integrity"]
        assert chunked["integrity"][key] == whole["integrity"][key]
    assert chunked == whole
    assert np.array_equal(small.P_eci, bound.P_eci)
    assert np.array_equal(small.position_var_m2, bound.position_var_m2)
    assert np.array_equal(small.velocity_var_m2s2, bound.velocity_var_m2s2)
    # the traces are formed without the (6, 6) bounds: the same to rounding
    assert np.allclose(small.position_var_m2, np.trace(bound.P_eci[:, :3, :3], axis1=1, axis2=2),
                       rtol=1e-13, atol=0)
    assert math.isclose(crb_metrics(p, sol.x_eci, options)["crb_position_rms_m"],
                        math.sqrt(np.mean(np.trace(bound.P_eci[:, :3, :3], axis1=1, axis2=2))),
                        rel_tol=1e-13)
    # without keep_covariance the (N, 6, 6) bounds are not kept
    assert crb.cramer_rao_bound(p, sol.x_eci, options.motion_model()).P_eci is None


def test_residuals_csv_streamed_in_chunks_is_the_row_by_row_file(tmp_path):
    rng = np.random.default_rng(3)
    res = {"earth_direction": rng.normal(size=(11, 2)) * 10.0 ** rng.integers(-9, 9, (11, 2)),
           "range": rng.normal(size=(5, 1))}
    res["earth_direction"][[2, 7], [1, 0]] = np.nan
    res["range"][4, 0] = np.inf
    times = {"earth_direction": np.arange(11) * 0.1234567, "range": np.arange(5) * 1e5 / 3}
    lines = ["t_s,kind,component,whitened"]
    for kind, r in res.items():
        lines.extend(f"{times[kind][i]:.6f},{kind},{j},{r[i, j]:.6g}"
                     for i in range(len(r)) for j in range(r.shape[1]) if np.isfinite(r[i, j]))
    expected = "\n".join(lines) + "\n"
    for chunk in (1, 3, 65536):
        write_residuals_csv(tmp_path / "r.csv", res, times, chunk=chunk)
        assert (tmp_path / "r.csv").read_text() == expected
    assert len(expected.splitlines()) == 1 + 22 - 2 + 5 - 1


def test_stm_accumulated_in_place_is_the_cumulative_product():
    rng = np.random.default_rng(5)
    steps = np.eye(6) + 0.1 * rng.normal(size=(50, 6, 6))
    Phik = np.empty((51, 6, 6))
    Phik[1:] = steps
    crb.accumulate_stm(Phik)
    assert np.array_equal(Phik, crb.cumulative_stm(steps))


def test_the_bound_and_the_integrity_tests_map_the_rows_once_with_the_same_result(monkeypatch):
    log, t, x = F.manoeuvre(5.0)
    options = SmootherOptions()
    p = prepare_pass(build_pass(log), options)
    sol = solve(p, "batch", options)
    calls = []
    real = crb._rows_at_first_state
    monkeypatch.setattr(crb, "_rows_at_first_state", lambda *a: calls.append(1) or real(*a))
    shared = summarize(sol, p, options)
    n_shared = len(calls)
    calls.clear()
    with monkeypatch.context() as m:   # without the hand-over: each maps its own rows
        m.setattr("fgnav.pipeline.mapping_shared", contextlib.nullcontext)
        alone = summarize(sol, p, options)
    assert n_shared == len(calls) - 1 and len(calls) >= 2
    assert shared == alone
    # outside the block nothing is kept: a call maps again, for other states too
    calls.clear()
    crb.rows_at_first_state(p, sol.x_eci, options.motion_model())
    with crb.mapping_shared():
        a = crb.rows_at_first_state(p, sol.x_eci, options.motion_model())
        b = crb.rows_at_first_state(p, sol.x_eci + 1.0, options.motion_model())
        c = crb.rows_at_first_state(p, sol.x_eci, options.motion_model())
    assert len(calls) == 3 and c is a and b is not a


def test_the_manoeuvre_ratio_at_tested_epochs_is_the_whole_tests():
    """A window computes its ratios at its tested epochs only: they equal the whole test's
    there, and the largest moves when its epoch is left out."""
    log, t, x = F.manoeuvre(5.0)
    options = SmootherOptions()
    p = prepare_pass(build_pass(log), options)
    sol = solve(p, "batch", options)
    m = integrity._Mapped(p, sol, options.motion_model())
    whole = integrity.manoeuvre_glr(m)
    k = whole["epoch_index"]
    tested = np.zeros(p.n_epochs, bool)
    tested[max(k - 20, 1):k + 20] = True
    part = integrity.manoeuvre_glr(m, tested=tested)
    assert part["epoch_index"] == k and math.isclose(part["glr"], whole["glr"], rel_tol=1e-12)
    tested[k] = False
    assert integrity.manoeuvre_glr(m, tested=tested)["glr"] < whole["glr"]
    assert whole["glr"] > whole["threshold"]   # the manoeuvre is found: not a flat statistic
