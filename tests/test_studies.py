"""Built-in studies: Pan & Yao 2017 tables 2-4 and visibility bound, Wu et al. table 5, NEES study.

The quick studies run in the default suite; the Monte Carlo ones are ``slow``
(``pytest -m slow tests/test_studies.py``, or ``fgnav campaign NAME --out DIR``).
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from fgnav.analysis.visibility import (SEED_BAND_KM, ring_needed_deg, ring_sees_limb,
                                       visibility_band_m, visibility_scenario, visible_fraction)
from fgnav.campaign import load_study, read_runs, run_campaign
from fgnav.cli import main


def _table(out: Path) -> list[dict]:
    with (out / "table.csv").open() as f:
        return list(csv.DictReader(f))


def test_pan_yao_visibility_band():
    """Pan & Yao 2017, eq. 1 (sec. 1.2): a 120-160 deg ring sees the whole Earth for 98.3-985.6 km,
    and 1,000-36,000 km needs a 17-120 deg ring."""
    lo, hi = visibility_band_m()
    assert lo / 1e3 == pytest.approx(SEED_BAND_KM[0], abs=0.05)
    assert hi / 1e3 == pytest.approx(SEED_BAND_KM[1], abs=0.05)
    a, b = ring_needed_deg(1000e3, 36000e3)
    assert round(a) == 17 and round(b) == 120
    R = 6_371_000.0
    r = np.array([[R + h, 0.0, 0.0] for h in (90e3, 100e3, 500e3, 980e3, 990e3, 20000e3)])
    assert list(ring_sees_limb(r)) == [False, True, True, True, False, False]


def test_gto_transfer_never_in_band_and_leo_always():
    from fgnav.orbit import integrate_truth

    for orbit, expected in (("gto-transfer", 0.0), ("leo-500", 1.0)):
        scn = visibility_scenario(orbit, step_s=60.0)
        t = np.arange(0.0, scn.duration_h * 3600.0 + 1, 60.0)
        x = integrate_truth(np.array(scn.x0_eci), t)
        assert visible_fraction(x[:, :3]) == expected


def test_wu_table5_study(tmp_path):
    """Wu et al.'s table 5 via fgnav.analysis.limb_method_study (one command, the table beside
    theirs)."""
    out = tmp_path / "t5"
    assert main(["campaign", "seed000-table5", "--out", str(out), "--workers", "1", "--quiet"]) == 0
    rows = _table(out)
    assert len(rows) == 24 and (out / "plot.png").stat().st_size > 0
    r = next(r for r in rows if float(r["alt_km"]) == 4000 and float(r["angle_error_deg"]) == 0.01)
    assert float(r["seed_km"]) == 1.805
    # the Monte Carlo check agrees with the closed form to its sampling error
    for r in rows:
        assert float(r["ours_mc_km"]) == pytest.approx(float(r["ours_with_rho_km"]), rel=0.05)


def test_pan_yao_observability_study(tmp_path):
    """Pan & Yao 2017, table 4: rank 6 at every sample period (their column, seed_rank, beside ours)."""
    out = tmp_path / "obs"
    assert main(["campaign", "seed002-observability", "--out", str(out), "--workers", "1", "--quiet"]) == 0
    rows = _table(out)
    assert [float(r["step_s"]) for r in rows] == [0.1, 1.0, 10.0, 100.0]
    assert all(r["rank"] == r["seed_rank"] == "6" for r in rows)
    assert "table 4" in (out / "table.md").read_text()


# ---- slow: the Monte Carlo studies ----------------------------------------------------

@pytest.mark.slow
def test_gto_nees_study_smoother_consistent(tmp_path):
    """ANEES of the batch smoother and iSAM2 over 100 runs of gto-transfer inside the 95% band
    (final and middle epochs); the EKF's ratio is reported in the table."""
    out = tmp_path / "nees"
    run_campaign(load_study("gto-nees"), out, workers=2)
    rows = {r["method"]: r for r in _table(out)}
    for m in ("batch", "isam2"):
        assert int(rows[m]["runs"]) == 100
        assert rows[m]["inside_final"] == "true" and rows[m]["inside_mid"] == "true", rows[m]
        assert float(rows[m]["epochs_inside_band"]) > 0.8
    assert "ekf" in rows


@pytest.mark.slow
def test_pan_yao_table2_noise_study(tmp_path):
    """Pan & Yao 2017, table 2: errors grow with the noise; the smoother beats the EKF's RMS."""
    out = tmp_path / "noise"
    run_campaign(load_study("seed002-noise"), out, workers=2)
    rows = _table(out)
    for m in ("batch", "ekf"):
        rms = [float(r["position_rms_km"]) for r in rows if r["method"] == m]
        assert rms == sorted(rms)
    by = {(r["sigma_deg"], r["method"]): r for r in rows}
    for s in ("0.01", "0.02", "0.05", "0.1", "0.2"):
        assert float(by[(s, "batch")]["position_rms_km"]) < float(by[(s, "ekf")]["position_rms_km"])
    for s in ("0.01", "0.02", "0.05"):
        assert by[(s, "batch")]["meets_seed_bound"] == "true"


@pytest.mark.slow
def test_pan_yao_table3_period_study(tmp_path):
    """Pan & Yao 2017, table 3: the shorter the sample period, the smaller the error."""
    out = tmp_path / "period"
    run_campaign(load_study("seed002-period"), out, workers=2)
    rows = _table(out)
    for m in ("batch", "ekf"):
        rms = [float(r["position_rms_km"]) for r in sorted((r for r in rows if r["method"] == m),
                                                           key=lambda r: float(r["step_s"]))]
        assert rms == sorted(rms)


@pytest.mark.slow
def test_pan_yao_visibility_study(tmp_path):
    out = tmp_path / "vis"
    run_campaign(load_study("seed002-visibility"), out, workers=2)
    runs = read_runs(out)
    gto = [r for r in runs if r["orbit"] == "gto-transfer"]
    assert all(r["visible_fraction"] == 0.0 and r["n_epochs_ring"] == 0 for r in gto)
    leo = [r for r in runs if r["orbit"] == "leo-500"]
    assert all(r["visible_fraction"] == 1.0 for r in leo)
    assert all(r["position_rms_ring_m"] == pytest.approx(r["position_rms_all_m"]) for r in leo)
    heo = [r for r in runs if r["orbit"] == "heo-300x3000"]
    assert all(0.0 < r["visible_fraction"] < 1.0 for r in heo)
