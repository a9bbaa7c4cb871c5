"""``fgnav smooth --attitude estimate`` end to end: a simulated refraction pass whose Earth
sensor reports body-frame directions, written as a CSV log, smoothed by the CLI; the
attitude read back from DIR/attitude.aem must match the simulator's true (LVLH) attitude
within its own sigma from DIR/attitude_covariance.csv, and ``--attitude known`` must write
no attitude files (and remove those of an earlier run in the same directory)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from factors.geometry import so3_exp, so3_log
from fgnav.cli import main
from fgnav.io.aem import read_aem
from fgnav.io.attitude_covariance import read_attitude_covariance
from fgnav.io.log_csv import write_log
from fgnav.io.oem import read_oem, write_oem
from fgnav.scenarios import SensorSpec, load_scenario
from fgnav.simulate.body_directions import lvlh_R_eci_from_body
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.time import add_seconds, seconds_since


@pytest.fixture(scope="module")
def att_log(tmp_path_factory):
    base = load_scenario("refraction-leo")
    scn = base.with_options(duration_h=0.25, sensors=(
        base.sensors[0], SensorSpec("earth_direction_body", sigma_deg=0.02)))
    sim = simulate_pass(scn, seed=4)
    d = tmp_path_factory.mktemp("att")
    write_log(d / "measurements.csv", sim.log)
    write_oem(d / "truth.oem", sim.epoch0, sim.t_s, sim.x_true, None)
    return sim, d


def _truth_rows(sim, epoch0, t_s):
    """Indices of the simulator's epochs at the file's epochs (exact to 1 µs)."""
    t = seconds_since(add_seconds(epoch0, t_s), sim.epoch0)
    idx = np.searchsorted(sim.t_s, t - 1e-6)
    np.testing.assert_allclose(sim.t_s[idx], t, atol=1e-6, rtol=0)
    return idx


@pytest.mark.parametrize("method", ["batch", "isam2", "fixed-lag", "ekf"])
def test_attitude_aem_matches_the_true_attitude_within_its_sigma(att_log, method, capsys):
    sim, d = att_log
    out = d / f"R-{method}"
    rc = main(["smooth", str(d / "measurements.csv"), "--attitude", "estimate", "--method",
               method, "--out", str(out), "--quiet"])
    assert rc == 0, capsys.readouterr().err
    aem = read_aem(out / "attitude.aem")
    epochs, t_s, P = read_attitude_covariance(out / "attitude_covariance.csv")
    traj = read_oem(out / "trajectory.oem")
    # one attitude and one covariance at every epoch of the trajectory
    np.testing.assert_array_equal(add_seconds(aem.epoch0, aem.t_s), add_seconds(traj.epoch0,
                                                                               traj.t_s))
    np.testing.assert_array_equal(epochs, add_seconds(aem.epoch0, aem.t_s))
    assert len(aem.t_s) >= 80 and np.isfinite(P).all()
    idx = _truth_rows(sim, aem.epoch0, aem.t_s)
    R_true = lvlh_R_eci_from_body(sim.x_true[idx])
    err = so3_log(np.swapaxes(R_true, 1, 2) @ aem.R_eci_from_body())   # body frame, rad
    sig = np.sqrt(np.diagonal(P, axis1=1, axis2=2))
    assert np.all(sig > 0) and np.all(sig < 1e-4)                       # arcsecond class
    assert np.max(np.abs(err) / sig) < 4.5                              # a few sigma
    nees = np.mean(np.einsum("ni,nij,nj->n", err, np.linalg.inv(P), err))  # 3 dof
    assert 1.5 < nees < 4.5
    # the files say what the solver has: variables.csv's rotation vector and sigmas
    summary = json.loads((out / "summary.json").read_text())
    assert "attitude" in summary["variables"]
    lines = (out / "variables.csv").read_text().splitlines()
    cols = lines[0].split(",")
    vals = np.array([[float(v) for v in ln.split(",")[2:]] for ln in lines[1:]])
    w = vals[:, [cols.index(c) - 2 for c in ("att_x", "att_y", "att_z")]]
    d_rot = so3_log(np.swapaxes(so3_exp(w), 1, 2) @ aem.R_eci_from_body())
    assert np.abs(d_rot).max() < 1e-8


def test_attitude_known_writes_no_attitude_files_and_removes_stale_ones(att_log, capsys):
    sim, d = att_log
    out = d / "R-switch"
    log = str(d / "measurements.csv")
    assert main(["smooth", log, "--estimate", "attitude", "--out", str(out), "--quiet"]) == 0
    assert (out / "attitude.aem").is_file() and (out / "attitude_covariance.csv").is_file()
    assert main(["smooth", log, "--attitude", "known", "--out", str(out), "--quiet"]) == 0
    assert not (out / "attitude.aem").exists()
    assert not (out / "attitude_covariance.csv").exists()
    assert (out / "trajectory.oem").is_file()


def test_attitude_known_with_estimate_attitude_is_an_error(att_log, capsys):
    sim, d = att_log
    rc = main(["smooth", str(d / "measurements.csv"), "--attitude", "known", "--estimate",
               "attitude", "--out", str(d / "R-bad")])
    assert rc == 2
    err = capsys.readouterr().err
    assert "fgnav: error:" in err and "--attitude known" in err and "--estimate attitude" in err
    assert "Traceback" not in err and not (d / "R-bad").exists()
