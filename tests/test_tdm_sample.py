"""The spacecraft TDM shipped in fgnav/data/tdm (written by fgnav.io.tdm.write_tdm from a
simulated pass): `fgnav smooth --sigma-deg` on it, with no prior, gives the accuracy of the
same rows in a CSV log, measured against the independent integrator's truth."""

import json
import math
from importlib.resources import files

import numpy as np
import pytest

from fgnav.cli import main
from fgnav.io.log_csv import read_log
from fgnav.io.tdm import read_tdm, write_tdm

SAMPLE = files("fgnav") / "data" / "tdm" / "gto-transfer.tdm"


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """The pass the sample was made from (its header comment gives the command)."""
    d = tmp_path_factory.mktemp("gto")
    assert main(["simulate", "gto-transfer", "--step-s", "60", "--seed", "0", "--out",
                 str(d / "pass"), "--quiet"]) == 0
    return d / "pass"


def _summary(out):
    return json.loads((out / "summary.json").read_text())


def test_the_sample_holds_the_simulated_earth_directions(simulated):
    tdm = read_tdm(SAMPLE, sigma_rad=math.radians(0.01))
    csv = read_log(simulated / "measurements.csv")
    sel = csv.kind == "earth_direction"
    assert tdm.epoch0 == csv.epoch0 and len(tdm) == sel.sum() == 241
    np.testing.assert_array_equal(tdm.t_s, csv.t_s[sel])
    np.testing.assert_allclose(tdm.xyz, csv.xyz[sel], rtol=0, atol=2e-15)
    np.testing.assert_allclose(tdm.sigma, csv.sigma[sel], rtol=1e-15)


def test_smooth_the_sample_tdm_with_sigma_deg_as_the_csv_rows(simulated, tmp_path, capsys):
    tdm = read_tdm(SAMPLE, sigma_rad=math.radians(0.01))
    rows = [f"{e},earth_direction,{x!r},{y!r},{z!r},{s!r}" for e, (x, y, z), s in zip(
        [str(np.datetime64(int(tdm.epoch0.astype(np.int64) + round(t * 1e9)), "ns")) + "Z"
         for t in tdm.t_s], tdm.xyz.tolist(), tdm.sigma.tolist())]
    log = tmp_path / "same-rows.csv"
    log.write_text("epoch,kind,x,y,z,sigma\n" + "\n".join(rows) + "\n")
    truth = str(simulated / "truth.oem")
    assert main(["smooth", str(SAMPLE), "--sigma-deg", "0.01", "--out", str(tmp_path / "t"),
                 "--truth", truth, "--quiet"]) == 0
    assert main(["smooth", str(log), "--out", str(tmp_path / "c"), "--truth", truth,
                 "--quiet"]) == 0
    a, b = _summary(tmp_path / "t"), _summary(tmp_path / "c")
    assert a["epochs"] == b["epochs"] == 241
    for k in ("position_rms_m", "velocity_rms_mps", "final_position_error_m", "crb_position_rms_m"):
        assert a[k] == pytest.approx(b[k], rel=1e-6), k
    # no prior: the angles-only initial orbit, then batch; within a few CRB sigmas of the truth
    assert a["position_rms_m"] < 3 * a["crb_position_rms_m"] and a["position_rms_m"] < 10e3


def test_sigma_deg_is_needed_for_a_standard_tdm_and_only_for_a_tdm(simulated, tmp_path, capsys):
    assert main(["smooth", str(SAMPLE), "--out", str(tmp_path / "a"), "--quiet"]) == 2
    assert "--sigma-deg" in capsys.readouterr().err
    assert main(["smooth", str(simulated / "measurements.csv"), "--sigma-deg", "0.01", "--out",
                 str(tmp_path / "b"), "--quiet"]) == 2
    assert "TDM" in capsys.readouterr().err
    assert main(["check", str(SAMPLE), "--sigma-deg", "0.01"]) == 0


def test_write_read_round_trip(tmp_path):
    rng = np.random.default_rng(3)
    u = rng.normal(size=(50, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    sig = np.r_[np.full(20, 1e-4), np.full(30, 2e-4)]
    p = tmp_path / "w.tdm"
    write_tdm(p, "2025-03-01T00:00:00Z", np.arange(50) * 10.0, u, sig)
    back = read_tdm(p)
    np.testing.assert_allclose(back.xyz, u, rtol=0, atol=1e-15)
    np.testing.assert_allclose(back.sigma, sig, rtol=1e-15)
    assert p.read_text().count("META_START") == 2
    write_tdm(p, "2025-03-01T00:00:00Z", np.arange(50) * 10.0, back.xyz, back.sigma)
    again = read_tdm(p)   # a second trip: the same directions to 1e-15 (1e-13 deg)
    np.testing.assert_allclose(again.xyz, back.xyz, rtol=0, atol=1e-15)
