"""Declared manoeuvres (``manoeuvre`` rows, issue 30 item 7): the burn enters the motion of
the step that ends at its epoch in every method, and each burn's delta-v is estimated.

Truth from the independent DOP853 integrator, integrated in arcs with the executed burn
(planned + an execution error drawn from the seed): ``fgnav.simulate.pass_sim``.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from fgnav.cli import main
from fgnav.diagnostics.consistency import chi2_band
from fgnav.errors import InputFormatError, UserError
from fgnav.io.log_csv import log_from_arrays, read_log
from fgnav.models.registry import LOG_SCHEMA
from fgnav.pipeline import smooth_log
from fgnav.scenarios import ManoeuvreSpec, load_scenario, parse_manoeuvre, scenario_from_dict
from fgnav.simulate import faults as F
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.solvers.options import SmootherOptions

METHODS = ("batch", "isam2", "fixed-lag", "ekf")
BURN = ManoeuvreSpec(t_s=7200.0, dv_mps=(0.3, 0.4, 0.0), sigma_mps=0.05)   # |dv| = 0.5 m/s
NEES_BAND = chi2_band(6, 1, alpha=0.01)
"""The NEES averaged over one pass's epochs: one run (its epochs are correlated in time), 99 %."""


@pytest.fixture(scope="module")
def passes():
    """The 4 h gto-transfer pass with the 0.5 m/s burn half way, and without (same seed: the
    same sensor noise)."""
    scn = load_scenario("gto-transfer")
    return simulate_pass(scn.with_options(manoeuvres=(BURN,)), seed=0), simulate_pass(scn, seed=0)


def _smooth(sim, method, log=None):
    res, _ = smooth_log(sim.log if log is None else log, method, SmootherOptions(),
                        truth=(sim.t_s, sim.x_true))
    return res.summary


@pytest.fixture(scope="module")
def summaries(passes):
    with_burn, without = passes
    return {m: (_smooth(with_burn, m), _smooth(without, m)) for m in METHODS}


def test_the_simulated_burn_is_in_the_truth_and_declared_in_the_log(passes):
    sim, plain = passes
    (t_b, dv), = sim.manoeuvres
    assert t_b == BURN.t_s and 0 < np.linalg.norm(dv - BURN.dv_mps) < 5 * BURN.sigma_mps
    k = int(np.searchsorted(sim.t_s, t_b))
    # (the arc before the burn ends there: DOP853's steps differ, by 1e-12 relative)
    np.testing.assert_allclose(sim.x_true[:k + 1, :3], plain.x_true[:k + 1, :3], rtol=1e-9)
    np.testing.assert_allclose(sim.x_true[k, 3:] - plain.x_true[k, 3:], dv, atol=1e-6)
    assert np.linalg.norm(sim.x_true[-1, :3] - plain.x_true[-1, :3]) > 1e3   # 0.5 m/s for 2 h
    row = np.flatnonzero(sim.log.kind == "manoeuvre")
    assert len(row) == 1 and sim.log.t_s[row[0]] == t_b
    np.testing.assert_array_equal(sim.log.xyz[row[0]], BURN.dv_mps)
    assert sim.log.sigma[row[0]] == BURN.sigma_mps


@pytest.mark.parametrize("method", METHODS)
def test_a_declared_half_metre_per_second_burn_is_estimated(passes, summaries, method):
    """Position RMS within 1.5x the pass without a burn, NEES in its band, the delta-v within
    3 sigma of the executed one, the verdict ok."""
    sim, _ = passes
    s, s0 = summaries[method]
    assert s["position_rms_m"] <= 1.5 * s0["position_rms_m"], (s["position_rms_m"],
                                                               s0["position_rms_m"])
    assert NEES_BAND[0] <= s["nees_mean"] <= NEES_BAND[1], s["nees_mean"]
    assert s["integrity"]["status"] == "ok"
    (m,) = s["manoeuvres"]
    (_, executed), = sim.manoeuvres
    assert m["epoch"] == "2025-03-01T02:00:00.000000Z" and m["t_s"] == BURN.t_s
    assert m["planned_mps"] == list(BURN.dv_mps)
    est, sig = np.array(m["estimated_mps"]), np.array(m["sigma_mps"])
    assert np.all(np.abs(est - executed) <= 3 * sig), (est, executed, sig)
    assert np.all(sig <= BURN.sigma_mps * (1 + 1e-9)) and np.all(sig > 0)
    assert np.array(m["covariance_m2_s2"]).shape == (3, 3)
    assert "manoeuvres" not in s0


def test_the_filter_and_the_smoother_estimate_the_same_delta_v(summaries):
    """The EKF carries the burn as a constant state to the end of the pass: its estimate from
    all the data is the smoothed one (linear-Gaussian), here to 1 % of its sigma."""
    b, e = summaries["batch"][0]["manoeuvres"][0], summaries["ekf"][0]["manoeuvres"][0]
    sig = np.array(b["sigma_mps"])
    assert np.all(np.abs(np.subtract(b["estimated_mps"], e["estimated_mps"])) < 0.01 * sig)
    np.testing.assert_allclose(e["sigma_mps"], sig, rtol=1e-3)
    i = summaries["isam2"][0]["manoeuvres"][0]
    assert np.all(np.abs(np.subtract(b["estimated_mps"], i["estimated_mps"])) < 0.01 * sig)


@pytest.mark.parametrize("method", ("batch", "ekf"))
def test_without_the_declared_row_the_answer_is_worse(passes, summaries, method):
    """The counter-test: the same log with the manoeuvre row removed. Direction-only data
    leave the undeclared burn no evidence in the residuals (the verdict stays ok, as the
    README says), but the answer is worse: the position RMS more than 1.5x and the NEES out
    of its band."""
    sim, _ = passes
    keep = sim.log.kind != "manoeuvre"
    s = _smooth(sim, method, F.with_rows(sim.log, keep=keep))
    declared = summaries[method][0]
    assert "manoeuvres" not in s
    assert s["position_rms_m"] > 1.5 * declared["position_rms_m"]
    assert s["nees_mean"] > NEES_BAND[1], s["nees_mean"]


def test_several_burns_one_between_sensor_epochs():
    """Two burns in a 1 h pass, one on a sensor epoch and one between two (its row makes an
    epoch of its own, where the trajectory has the state just after it); each estimated
    within 3 sigma, batch and iSAM2 alike."""
    burns = (ManoeuvreSpec(1200.0, (0.0, 0.2, -0.1), 0.03),
             ManoeuvreSpec(2405.0, (0.15, 0.0, 0.05), 0.03))
    sim = simulate_pass(load_scenario("gto-transfer").with_options(duration_h=1.0,
                                                                    manoeuvres=burns), seed=2)
    assert 2405.0 in sim.t_s and 2400.0 in sim.t_s and 2410.0 in sim.t_s
    for method in ("batch", "isam2"):
        res, p = smooth_log(sim.log, method, truth=(sim.t_s, sim.x_true))
        assert 2405.0 in res.solution.t_s
        ms = res.summary["manoeuvres"]
        assert [m["t_s"] for m in ms] == [1200.0, 2405.0]
        for m, (_, executed) in zip(ms, sim.manoeuvres):
            assert np.all(np.abs(np.array(m["estimated_mps"]) - executed)
                          <= 3 * np.array(m["sigma_mps"]))
        assert NEES_BAND[0] <= res.summary["nees_mean"] <= NEES_BAND[1]


def test_fgnav_simulate_and_smooth_a_declared_manoeuvre(tmp_path):
    out = tmp_path / "sim"
    assert main(["simulate", "gto-transfer", "--out", str(out), "--duration-h", "1",
                 "--manoeuvre", "2025-03-01T00:30:00Z,0.1,0.2,0.0,0.02", "--quiet"]) == 0
    text = (out / "measurements.csv").read_text()
    assert "2025-03-01T00:30:00.000000Z,manoeuvre,0.1,0.2,0.0,0.02" in text
    assert (out / "truth_manoeuvres.csv").exists()
    log = read_log(out / "measurements.csv", schema=LOG_SCHEMA)
    assert list(log.kind).count("manoeuvre") == 1
    assert main(["smooth", str(out / "measurements.csv"), "--out", str(tmp_path / "r"),
                 "--truth", str(out / "truth.oem"), "--quiet"]) == 0
    s = json.loads((tmp_path / "r" / "summary.json").read_text())
    (m,) = s["manoeuvres"]
    assert set(m) >= {"epoch", "planned_mps", "estimated_mps", "sigma_mps"}
    assert m["epoch"] == "2025-03-01T00:30:00.000000Z" and m["planned_mps"] == [0.1, 0.2, 0.0]


def test_a_scenario_declares_manoeuvres_in_a_toml_table(tmp_path):
    d = {"epoch": "2025-03-01T00:00:00Z", "duration_h": 1.0, "step_s": 60.0,
         "orbit": {"r_eci_m": [7e6, 0.0, 0.0], "v_eci_mps": [0.0, 7546.0, 0.0]},
         "sensor": [{"kind": "earth_direction", "sigma_deg": 0.01}],
         "manoeuvres": [{"t_h": 0.5, "dv_mps": [0.1, 0.0, 0.0], "sigma_mps": 0.02},
                        {"t_h": 0.25, "dv_mps": [0.0, 0.1, 0.0]}]}
    scn = scenario_from_dict(d, tmp_path / "s.toml")
    assert [m.t_s for m in scn.manoeuvres] == [900.0, 1800.0]
    assert scn.manoeuvres[0].sigma_mps == 0.01 and scn.manoeuvres[1].sigma_mps == 0.02
    d["manoeuvres"][0]["dv"] = [1.0, 0.0, 0.0]
    with pytest.raises(InputFormatError, match="manoeuvres"):
        scenario_from_dict(d, tmp_path / "s.toml")


@pytest.mark.parametrize("text, why", [
    ("2,0.1,0.2", "expected T,DVX"), ("x,0.1,0.2,0.3", "neither a number"),
    ("9,0.1,0.2,0.3", "within the pass"), ("1,0.1,0.2,0.3,0", "SIGMA"),
    ("0,0.1,0.2,0.3", "after the start")])
def test_a_bad_manoeuvre_option_is_refused_with_the_reason(text, why, tmp_path, capsys):
    with pytest.raises(UserError, match=why):
        parse_manoeuvre(text, load_scenario("gto-transfer"))
    assert main(["simulate", "gto-transfer", "--out", str(tmp_path), "--manoeuvre", text]) == 2
    assert why in capsys.readouterr().err


def test_what_a_manoeuvre_does_not_yet_take_is_refused_with_the_reason(passes, tmp_path):
    sim, _ = passes
    with pytest.raises(UserError, match="--state elements"):
        smooth_log(sim.log, "batch", SmootherOptions(state="elements"))
    log = sim.log
    first = log_from_arrays(log.epoch0, np.where(log.kind == "manoeuvre", 0.0, log.t_s),
                            log.kind, log.xyz, log.sigma, schema=LOG_SCHEMA)
    with pytest.raises(UserError, match="first epoch"):
        smooth_log(first, "batch")
    with pytest.raises(UserError, match="several spacecraft"):
        simulate_pass_formation()


def simulate_pass_formation():
    from fgnav.simulate.formation_sim import simulate_formation_pass

    scn = load_scenario("formation-gto").with_options(manoeuvres=(BURN,), duration_h=0.1)
    return simulate_formation_pass(scn)


def test_a_formations_log_with_a_manoeuvre_row_is_refused_with_the_reason(tmp_path, capsys):
    from formation_data import formation_log
    from fgnav.io.log_csv import write_log

    log, _ = formation_log(2)
    path = tmp_path / "formation.csv"
    write_log(path, log, schema=LOG_SCHEMA)
    lines = path.read_text().splitlines()
    header = next(line for line in lines if line.startswith("epoch,")).split(",")
    row = dict.fromkeys(header, "")
    row.update(epoch="2025-03-01T00:10:00Z", kind="manoeuvre", x="0.1", y="0", z="0",
               sigma="0.01", spacecraft="B")
    path.write_text("\n".join(lines + [",".join(row[c] for c in header)]) + "\n")
    assert main(["smooth", str(path), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert "manoeuvre" in err and "several spacecraft" in err and "Traceback" not in err


def test_fgnav_follow_skips_a_declared_manoeuvre_and_says_so():
    """Live (``fgnav follow``) a burn is not yet applied: the row is skipped, counted and
    reported by line, never silently taken nor fatal."""
    from fgnav.online.stream import StreamReader

    said = []
    reader = StreamReader("<stdin>", report=said.append)
    reader.feed(b"epoch,kind,x,y,z,sigma\n")
    assert reader.feed(b"2025-03-01T00:10:00Z,manoeuvre,0.1,0.2,0.0,0.01\n") == []
    assert reader.counts.skipped == {"manoeuvre": 1}
    assert said and "line 2" in said[0] and "manoeuvre" in said[0]
