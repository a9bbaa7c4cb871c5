"""Each report takes its bounds and reference figures from the study's [reference] table:
change a figure in the study file and the table (and its verdict) changes with it."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

from fgnav.campaign import load_study, run_campaign, write_report
from fgnav.campaign.spec import study_runs
from fgnav.campaign.storage import RunsTable


def _study(tmp_path, name, replace=()):
    text = Path(load_study(name).source).read_text()
    for old, new in replace:
        assert old in text, old
        text = text.replace(old, new)
    path = tmp_path / f"{name}-{abs(hash(replace))}.toml"
    path.write_text(text)
    return load_study(path)


def _report(study, out, rows_for):
    """Write a runs table holding ``rows_for(run)`` for every run of ``study``, then its report."""
    out.mkdir(parents=True, exist_ok=True)
    t = RunsTable(out / "runs.csv", study.columns())
    t.create()
    with t.appender() as f:
        for run in study_runs(study):
            row = {"run_id": run.run_id, "status": "ok", "error": ""}
            row.update({c: run.params[c] for c in t.names if c in ("method", "seed") or c in study.grid})
            row.update(rows_for(run))
            f.append(row)
    write_report(study, out)
    with (out / "table.csv").open() as fh:
        return list(csv.DictReader(fh))


def _navigate_row(final_position_m, final_velocity_mps):
    return lambda run: {"final_position_error_m": final_position_m, "final_velocity_error_mps": final_velocity_mps,
                        "position_rms_m": final_position_m / 2, "velocity_rms_mps": final_velocity_mps / 2,
                        "sigma_final_position_m": final_position_m, "nees_mean": 6.0, "solve_s": 0.1,
                        "nees_final": 6.0}


def test_noise_bound_from_the_study(tmp_path):
    rows = _report(_study(tmp_path, "seed002-noise"), tmp_path / "a", _navigate_row(3000.0, 0.4))
    by = {(r["sigma_deg"], r["method"]): r for r in rows}
    assert by[("0.05", "batch")]["meets_seed_bound"] == "true"
    assert by[("0.05", "batch")]["seed_position_bound_km"] == "4.0"
    assert by[("0.1", "batch")]["meets_seed_bound"] == ""           # above max_sigma_deg: no bound
    tighter = _study(tmp_path, "seed002-noise", (("final_position_km = 4.0", "final_position_km = 2.5"),
                                                 ("max_sigma_deg = 0.05", "max_sigma_deg = 0.1")))
    rows = _report(tighter, tmp_path / "b", _navigate_row(3000.0, 0.4))
    by = {(r["sigma_deg"], r["method"]): r for r in rows}
    assert by[("0.05", "batch")]["meets_seed_bound"] == "false"
    assert by[("0.1", "ekf")]["meets_seed_bound"] == "false" and by[("0.1", "ekf")]["seed_position_bound_km"] == "2.5"
    assert by[("0.2", "ekf")]["meets_seed_bound"] == ""
    assert "< 2.5 km" in (tmp_path / "b" / "table.md").read_text()
    looser = _study(tmp_path, "seed002-noise", (("final_velocity_mps = 0.5", "final_velocity_mps = 0.3"),))
    rows = _report(looser, tmp_path / "c", _navigate_row(3000.0, 0.4))
    assert {r["meets_seed_bound"] for r in rows if r["sigma_deg"] in ("0.01", "0.02", "0.05")} == {"false"}


def test_nees_band_from_the_study(tmp_path):
    """100 runs with final NEES 6.4: their ANEES 6.4 lies inside the 95 % band of chi2(600)/100
    (mean 6, sd 0.35) and outside its 50 % band; the band edges are the chi-square quantiles
    (scipy, independent)."""
    def nees_row(run):
        return {"nees_final": 6.4, "nis_per_dof": 1.0, "position_rms_m": 100.0}

    base = _study(tmp_path, "gto-nees")
    rows = {r["method"]: r for r in _report(base, tmp_path / "a", nees_row)}
    r = rows["batch"]
    assert int(r["runs"]) == 100 and float(r["anees_final"]) == pytest.approx(6.4)
    assert float(r["band_lo"]) == pytest.approx(chi2.ppf(0.025, 600) / 100, rel=1e-9)
    assert float(r["band_hi"]) == pytest.approx(chi2.ppf(0.975, 600) / 100, rel=1e-9)
    assert r["inside_final"] == "true"
    narrow = _study(tmp_path, "gto-nees", (("alpha = 0.05", "alpha = 0.5"),))
    rows = {r["method"]: r for r in _report(narrow, tmp_path / "b", nees_row)}
    assert float(rows["batch"]["band_hi"]) == pytest.approx(chi2.ppf(0.75, 600) / 100, rel=1e-9)
    assert rows["batch"]["inside_final"] == "false"
    assert "50% chi-square band" in (tmp_path / "b" / "table.md").read_text()


def test_observability_rank_from_the_study(tmp_path):
    row = lambda run: {"rank": 6, "condition_raw": 1e10, "condition_scaled": 10.0, "window_info_condition": 1e3,
                       "weakest_sigma_m": 5.0, "weakest_direction": "along-track", "window_h": 1.0}
    rows = _report(_study(tmp_path, "seed002-observability"), tmp_path / "a", row)
    assert {r["seed_rank"] for r in rows} == {"6"}
    rows = _report(_study(tmp_path, "seed002-observability", (("rank = 6", "rank = 5"),)), tmp_path / "b", row)
    assert {r["seed_rank"] for r in rows} == {"5"}


def test_period_statement_from_the_study(tmp_path):
    s = _study(tmp_path, "seed002-period", (("shorter period is better", "shorter is worse"),))
    rows = _report(s, tmp_path / "a", _navigate_row(1000.0, 0.1))
    assert {r["seed_value"] for r in rows} == {"not in the source text; Pan & Yao 2017: shorter is worse"}


def test_visibility_band_from_the_study(tmp_path):
    """Band rows at the study's Earth radii: h = R / sin(80 deg) - R .. R / sin(60 deg) - R
    (written out here), beside the study's band figures."""
    row = lambda run: {"perigee_alt_km": 500.0, "apogee_alt_km": 500.0, "visible_fraction": 1.0, "max_gap_min": 0.0,
                       "n_epochs_all": 10, "n_epochs_ring": 10, "position_rms_all_m": 1.0, "final_position_all_m": 1.0,
                       "position_rms_ring_m": 1.0, "final_position_ring_m": 1.0, "ring_status": "ok"}
    s = _study(tmp_path, "seed002-visibility", (("band_km = [98.3, 985.6]", "band_km = [90.0, 1000.0]"),
                                                ("earth_radii_km = [6371.0, 6375.0]", "earth_radii_km = [6000.0]")))
    rows = _report(s, tmp_path / "a", row)
    band = rows[0]
    assert band["orbit"] == "band (R = 6000 km)" and rows[1]["orbit"] == "leo-500"
    R = 6000.0
    assert float(band["band_min_km"]) == pytest.approx(R / math.sin(math.radians(80)) - R, rel=1e-12)
    assert float(band["band_max_km"]) == pytest.approx(R / math.sin(math.radians(60)) - R, rel=1e-12)
    assert (band["seed_band_min_km"], band["seed_band_max_km"]) == ("90.0", "1000.0")


def test_table5_figures_from_the_study(tmp_path):
    base = _study(tmp_path, "seed000-table5")
    out = tmp_path / "a"
    run_campaign(base, out, workers=1)
    with (out / "table.csv").open() as fh:
        rows = {(float(r["alt_km"]), float(r["angle_error_deg"])): r for r in csv.DictReader(fh)}
    r = rows[(4000.0, 0.01)]
    assert float(r["seed_km"]) == 1.805
    assert float(r["seed_over_bound"]) == pytest.approx(1.805 / float(r["lower_bound_km"]), rel=1e-12)
    # the same figure edited in the study file: the table follows, the runs do not change
    edited = _study(tmp_path, "seed000-table5", (("1.389, 1.805]", "1.389, 0.5]"),))
    write_report(edited, out)
    with (out / "table.csv").open() as fh:
        rows2 = {(float(r["alt_km"]), float(r["angle_error_deg"])): r for r in csv.DictReader(fh)}
    r2 = rows2[(4000.0, 0.01)]
    assert float(r2["seed_km"]) == 0.5
    assert float(r2["seed_over_bound"]) == pytest.approx(0.5 / float(r["lower_bound_km"]), rel=1e-12)
    assert r2["ours_with_rho_km"] == r["ours_with_rho_km"]
    assert rows2[(8000.0, 0.01)] == rows[(8000.0, 0.01)]


def test_table5_study_figures_are_the_libraries(tmp_path):
    """The study file's figures and fgnav's copy of the same table (used by its own tests)
    agree, so the two cannot drift apart."""
    from fgnav.analysis.limb_method_study import TABLE5_ANGLE_ERRORS_DEG, TABLE5_SEED

    ref = load_study("seed000-table5").reference
    assert ref.angle_errors_deg == tuple(TABLE5_ANGLE_ERRORS_DEG)
    assert {int(k): v for k, v in ref.seed_km.items()} == {k: tuple(v) for k, v in TABLE5_SEED.items()}
    assert np.all(np.isfinite([x for v in ref.seed_km.values() for x in v]))


def test_nees_plot_in_hours_runs_per_method_and_batch_visible(tmp_path):
    """The ANEES plot of 4 seeds x 3 methods says so (not "12 runs"), runs along time in
    hours from the saved curves, and draws batch and iSAM2 (equal curves) so both show."""
    import matplotlib

    matplotlib.use("Agg")
    from fgnav.campaign import reports

    study = _study(tmp_path, "gto-nees", (("count = 100", "count = 4"),))
    out = tmp_path / "n"
    (out / "curves").mkdir(parents=True)
    t_s = np.arange(0.0, 7200.0 + 1, 60.0)
    curve = 6.0 + np.sin(t_s / 900.0)
    for run in study_runs(study):
        np.savez(out / "curves" / f"{run.run_id}.npz", t_s=t_s, nees=curve, nis=curve, nis_dof=2)
    rows = _report(study, out, lambda run: {"nees_final": 6.0, "nis_per_dof": 1.0, "position_rms_m": 1.0})
    assert {r["runs"] for r in rows} == {"4"}
    assert (out / "plot.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    runs = [{"method": m, "seed": s, "run_id": f"{m}-{s}"} for m in ("batch", "isam2", "ekf") for s in range(4)]
    curves = {m: (curve, 3.9, 8.6, 4) for m in ("batch", "isam2", "ekf")}
    fig = reports._plot_anees("gto-nees", runs, curves, {m: t_s for m in curves}, "95%")
    ax = fig.axes[0]
    assert ax.get_title() == "gto-nees: 4 runs x 3 methods (batch, ekf, isam2)"
    assert ax.get_xlabel() == "time since the first epoch (h)"
    lines = {ln.get_label(): ln for ln in ax.lines}
    np.testing.assert_allclose(lines["batch ANEES (4 runs)"].get_xdata(), t_s / 3600.0)
    b, i = lines["batch ANEES (4 runs)"], lines["isam2 ANEES (4 runs)"]
    assert (b.get_linestyle(), b.get_marker()) != (i.get_linestyle(), i.get_marker())
    assert b.get_linewidth() > i.get_linewidth() and b.get_zorder() < i.get_zorder()
