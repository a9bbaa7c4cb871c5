"""`fgnav smooth` on logs written by hand in the v1 format, exactly as the README documents."""

import json

import numpy as np
import pytest

from fgnav.cli import main
from fgnav.constants import DEG
from fgnav.io.oem import read_oem, write_oem
from fgnav.orbit import integrate_truth
from fgnav.time import format_utc, parse_utc

EPOCH0 = "2025-03-01T00:00:00Z"
X0 = np.array([6509244.371304875, 0.0, 3713244.835519765, -3737.397235776740, 0.0, 8790.602460568101])


def hand_written_log(tmp_path, t_dir, with_limb=True, with_priors=True):
    """A log typed the way a user would: comments, uneven epochs, rows sharing an epoch."""
    rng = np.random.default_rng(5)
    t_all = np.unique(np.concatenate([[0.0], t_dir]))
    x = integrate_truth(X0, t_all)
    e0 = parse_utc(EPOCH0)
    lines = ["# hand-written pass: Earth direction (0.01 deg) and the limb radius",
             "epoch,kind,x,y,z,sigma"]
    if with_priors:
        p = x[0, :3] + np.array([4000.0, -3000.0, 2000.0])
        v = x[0, 3:] + np.array([0.5, -0.4, 0.3])
        lines.append(f"{EPOCH0},prior_position,{p[0]:.6f},{p[1]:.6f},{p[2]:.6f},10000")
        lines.append(f"{EPOCH0},prior_velocity,{v[0]:.6f},{v[1]:.6f},{v[2]:.6f},2")
    for t in t_dir:
        r = x[np.searchsorted(t_all, t), :3]
        u = -r / np.linalg.norm(r) + rng.normal(0, 0.01 * DEG, 3)
        u /= np.linalg.norm(u)
        ep = format_utc(e0 + np.timedelta64(int(round(t * 1e9)), "ns"))
        lines.append(f"{ep},earth_direction,{u[0]:.12f},{u[1]:.12f},{u[2]:.12f},{0.01 * DEG:.10e}")
        if with_limb:
            rho = np.arcsin(6375e3 / np.linalg.norm(r)) + rng.normal(0, 0.02 * DEG)
            lines.append(f"{ep},limb_radius,{rho:.12f},6375000,,{0.02 * DEG:.10e}")
    log = tmp_path / "pass.csv"
    log.write_text("\n".join(lines) + "\n")
    truth = tmp_path / "truth.oem"
    write_oem(truth, e0, t_all, x, None)
    return log, truth


@pytest.mark.parametrize("method", ["batch", "isam2", "ekf"])
def test_smooth_a_hand_written_log(tmp_path, method, capsys):
    t_dir = np.concatenate([np.arange(0, 3600, 30.0), np.arange(3600, 7200, 120.0)])  # uneven
    log, truth = hand_written_log(tmp_path, t_dir)
    out = tmp_path / "result"
    rc = main(["smooth", str(log), "--method", method, "--out", str(out), "--truth", str(truth), "--quiet"])
    assert rc == 0
    s = json.loads((out / "summary.json").read_text())
    for key in ("method", "epochs", "iterations", "wall_s", "chi2", "crb_position_rms_m",
                "crb_velocity_rms_mps", "position_rms_m", "velocity_rms_mps",
                "final_position_error_m", "final_velocity_error_mps", "nees_mean"):
        assert key in s, key
    assert s["method"] == method and s["epochs"] == len(t_dir)
    oem = read_oem(out / "trajectory.oem")
    assert len(oem.t_s) == len(t_dir) and oem.P_eci is not None
    assert str(oem.epoch0).startswith("2025-03-01T00:00:00")
    text = (out / "trajectory.oem").read_text()
    assert "CCSDS_OEM_VERS = 2.0" in text and "COVARIANCE_START" in text and "EME2000" in text
    # the smoothers recover the orbit to within a few sigma of their covariance
    if method != "ekf":
        assert s["position_rms_m"] < 4 * s["crb_position_rms_m"]
        assert s["nees_mean"] < 20
    if method == "isam2":
        assert (out / "online.oem").exists()
        assert len(read_oem(out / "online.oem").t_s) == len(t_dir)


def test_log_without_direction_data_is_a_clear_error(tmp_path, capsys):
    log = tmp_path / "priors.csv"
    log.write_text("epoch,kind,x,y,z,sigma\n"
                   f"{EPOCH0},prior_position,6509244,0,3713244,10000\n"
                   f"{EPOCH0},prior_velocity,-3737,0,8790,2\n")
    rc = main(["smooth", str(log), "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert rc == 2
    assert "priors.csv" in err and "no measurement that observes the orbit" in err
    assert "Traceback" not in err
    assert not (tmp_path / "r" / "trajectory.oem").exists()


def test_too_few_epochs_to_observe_the_orbit_is_a_clear_error(tmp_path, capsys):
    log, _ = hand_written_log(tmp_path, np.array([0.0, 60.0]), with_limb=False)
    rc = main(["smooth", str(log), "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert rc == 2
    assert "do not observe the orbit" in err and "weakest direction" in err


def test_direction_rows_without_priors_start_from_the_initial_orbit(tmp_path, capsys):
    # No prior rows: the orbit comes from the directions and limb ranges alone
    # (fgnav.iod, fgnav.start); the answer is checked against the DOP853 truth.
    log, truth = hand_written_log(tmp_path, np.arange(0, 600, 60.0), with_priors=False)
    out = tmp_path / "r"
    rc = main(["smooth", str(log), "--out", str(out), "--truth", str(truth), "--quiet"])
    assert rc == 0, capsys.readouterr().err
    s = json.loads((out / "summary.json").read_text())
    assert s["initial_orbit"]["prior"] == "initial_orbit"
    assert s["position_rms_m"] < 3 * s["crb_position_rms_m"] and s["nees_mean"] < 20


def test_without_priors_and_without_directions_asks_for_a_prior(tmp_path, capsys):
    log, _ = hand_written_log(tmp_path, np.arange(0, 600, 60.0), with_priors=False)
    log.write_text("".join(l + "\n" for l in log.read_text().splitlines() if "earth_direction" not in l))
    rc = main(["smooth", str(log), "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err
    assert "limb_radius" in err and "earth_direction" in err and "prior_position" in err


def test_simulate_then_smooth_round_trip(tmp_path):
    sim = tmp_path / "pass"
    assert main(["simulate", "gto-transfer", "--out", str(sim), "--step-s", "120", "--quiet"]) == 0
    assert (sim / "measurements.csv").exists() and (sim / "truth.oem").exists()
    out = tmp_path / "result"
    assert main(["smooth", str(sim / "measurements.csv"), "--out", str(out), "--truth",
                 str(sim / "truth.oem"), "--quiet"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["epochs"] == 121
    assert s["nees_mean"] < 15
