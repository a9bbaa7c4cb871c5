"""The checks after a solve (Cramer-Rao bound, manoeuvre and omitted-force tests) form their
per-epoch 6x6 matrices in chunks of epochs, and residuals.csv is written in chunks of rows,
so that a 1,000,000-epoch pass never holds them whole: the chunking must not change a bit."""

from __future__ import annotations

import math

import numpy as np
import pytest

import fgnav.analysis.crb as crb
import fgnav.integrity as integrity
from fgnav.measurements import build_pass
from fgnav.pipeline import crb_metrics, prepare_pass, solve, summarize, write_residuals_csv
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
    assert np.array_equal(small.position_var_m2,
                          np.trace(bound.P_eci[:, :3, :3], axis1=1, axis2=2))
    assert crb_metrics(p, sol.x_eci, options)["crb_position_rms_m"] == \
        math.sqrt(np.mean(np.trace(bound.P_eci[:, :3, :3], axis1=1, axis2=2)))
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
