"""A formation through the one pipeline (the one-pipeline issue, "Formations through the one
pipeline"): every method and option a single spacecraft has, on a simulated formation-gto
pass, each ending with exit 0 (or 3 with its verdict stated), no traceback, and a relative
position whose error against the simulator's truth is within twice its own 1-sigma.

The default run uses 1 h at 60 s (61 epochs); the 2 h pass at 10 s of the issue, with the
iSAM2 time against batch's, is marked ``slow``."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from fgnav.cli import main
from fgnav.pipeline import smooth_file
from fgnav.solvers.options import SmootherOptions


@pytest.fixture(scope="module")
def formation_hour(tmp_path_factory):
    """formation-gto, 1 h at 60 s: a folder with measurements.csv and truth-<id>.oem."""
    d = tmp_path_factory.mktemp("formation")
    assert main(["simulate", "formation-gto", "--duration-h", "1", "--step-s", "60",
                 "--out", str(d), "--quiet"]) == 0
    return d


def _gap_log(d, tmp_path, start="00:20:00.5", end="00:40:00"):
    """The log of ``d`` with its rows between ``start`` and ``end`` (of 2025-03-01) cut out."""
    lines = (d / "measurements.csv").read_text().splitlines()
    keep = [ln for ln in lines if ln.startswith("#") or ln.startswith("epoch,")
            or not (f"2025-03-01T{start}" < ln.split(",")[0] < f"2025-03-01T{end}")]
    assert len(keep) < len(lines)
    out = tmp_path / "gap.csv"
    out.write_text("\n".join(keep) + "\n")
    return out


def _smooth(log, out, capsys, *args):
    rc = main(["smooth", str(log), "--out", str(out), "--truth", str(log.parent), "--quiet",
               *args])
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    assert rc in (0, 3), err
    summary = json.loads((out / "summary.json").read_text())
    return rc, summary


CASES = {
    "batch": ["--method", "batch"],
    "isam2": ["--method", "isam2"],
    "fixed-lag": ["--method", "fixed-lag"],
    "isam2-gate": ["--method", "isam2", "--gate", "0.999999"],
    "ignore-prior": ["--method", "batch", "--ignore-prior"],
}


@pytest.mark.parametrize("case", list(CASES))
def test_every_method_and_option_gives_an_honest_relative_state(formation_hour, tmp_path,
                                                                capsys, case):
    rc, s = _smooth(formation_hour / "measurements.csv", tmp_path / "r", capsys, *CASES[case])
    rel = s["relative"]
    if case == "fixed-lag":   # 6.2 m of sigma across the 955 m line bend the range 4.9 times
        # its sigma along it: the verdict says so (relative NEES 112 against truth)
        curv = s["integrity"]["tests"]["range_curvature"]
        assert rc == 0 and s["integrity"]["status"] == "suspect", s["integrity"]
        assert curv["status"] == "suspect" and rel["nees_mean"] > 18
    else:
        assert rc == 0 and s["integrity"]["status"] == "ok", s["integrity"]
    assert rel["position_rms_m"] <= 2.0 * rel["sigma_position_rms_m"], rel
    assert set(s["spacecraft"]) == {"sat1", "sat2"}
    for sc, d in s["spacecraft"].items():   # each orbit within its own sigma too
        assert d["position_rms_m"] <= 3.0 * d["sigma_position_rms_m"], (sc, d)
    if case == "ignore-prior":
        assert "prior_position" not in s["measurements"]
    if case in ("isam2", "fixed-lag", "isam2-gate"):   # the online outputs, per spacecraft
        names = {f.name for f in (tmp_path / "r").iterdir()}
        assert {"latency.csv", "online-sat1.oem", "online-sat2.oem"} <= names, names


def test_a_20_minute_gap_is_bridged_for_both_spacecraft(formation_hour, tmp_path, capsys):
    log = _gap_log(formation_hour, tmp_path)
    for truth in formation_hour.glob("truth-*.oem"):
        (tmp_path / truth.name).write_bytes(truth.read_bytes())
    for method in ("batch", "isam2"):
        rc, s = _smooth(log, tmp_path / method, capsys, "--method", method)
        assert rc == 0 and s["integrity"]["status"] == "ok", s["integrity"]
        assert s["epochs"] == 61   # the 19 epochs of the gap inserted again
        rel = s["relative"]
        assert rel["position_rms_m"] <= 2.0 * rel["sigma_position_rms_m"], rel


def test_a_checkpoint_then_resume_ends_where_the_uninterrupted_run_does(formation_hour, tmp_path,
                                                                        capsys):
    log = formation_hour / "measurements.csv"
    ck = tmp_path / "ck.npz"
    _, whole = _smooth(log, tmp_path / "whole", capsys, "--method", "isam2")
    # the checkpoint written every 20 epochs holds the two orbits, clock and ambiguities
    rc, first = _smooth(log, tmp_path / "a", capsys, "--method", "isam2", "--checkpoint", str(ck),
                        "--checkpoint-every", "20")
    assert ck.exists()
    rc, resumed = _smooth(log, tmp_path / "b", capsys, "--method", "isam2", "--checkpoint",
                          str(ck), "--resume")
    assert rc == 0 and resumed["integrity"]["status"] == "ok"
    for key in ("position_rms_m", "sigma_position_rms_m"):
        assert resumed["relative"][key] == pytest.approx(whole["relative"][key], rel=1e-6)


def test_the_ekf_stays_within_its_covariance(formation_hour, tmp_path, capsys):
    """The filter of two km-sigma orbits whose difference the links know to centimetres: its
    covariance kept in relative coordinates (fgnav.solvers.ekf.relative_coordinates, where it
    had lost positive definiteness: LinAlgError), and its rows solved by Gauss-Newton over a
    start window, then iterated per epoch (fgnav.solvers.ekf.window_update). Linearized at the
    prediction, 60 s after a 2 m/s prior, the links' curvature made it diverge: 421 m relative
    error against a 0.5 m sigma, verdict failed (exit 3 with --strict); now within twice its
    own sigma."""
    rc, s = _smooth(formation_hour / "measurements.csv", tmp_path / "r", capsys,
                    "--method", "ekf", "--strict")
    rel, verdict = s["relative"], s["integrity"]
    # (the first epochs' covariance, metres across the line of sight on a 1 km range, is a
    # bent range sphere: the range-curvature test may say so, and the filtered states of the
    # start window depart from the batch solution beyond their covariance: the agreement test
    # may say so; exit 3 under --strict; no other test may fail)
    assert (rc == 0 and verdict["status"] == "ok") or (
        rc == 3 and verdict["status"] == "suspect"
        and all("is bent" in why or "departs from the batch" in why
                for why in verdict["reasons"])), verdict
    assert rel["position_rms_m"] <= 2.0 * rel["sigma_position_rms_m"], rel


def test_the_online_solution_carries_its_latency_and_states(formation_hour):
    """What latency.csv and online.oem are written from: every epoch's latency and online
    state, for the fixed-lag smoother and iSAM2, and the joint marginals (relative state)."""
    for method in ("isam2", "fixed-lag"):
        res, p = smooth_file(formation_hour / "measurements.csv", method, SmootherOptions())
        sol = res.solution
        assert sol.latency_s is not None and len(sol.latency_s) == p.n_epochs
        assert np.all(np.isfinite(sol.online_x_eci)) and sol.online_x_eci.shape == (p.n_epochs, 6)
        assert sol.P_block is not None and sol.P_block.shape == (p.n_epochs, p.layout.n,
                                                                 p.layout.n)
        (x2, P2), = sol.extras["online_variables"].values()   # the second spacecraft's
        assert x2.shape == (p.n_epochs, 6) and np.all(np.isfinite(x2))
        assert np.all(np.linalg.eigvalsh(P2) > 0)


@pytest.mark.slow
def test_two_hours_at_10_s_isam2_within_5x_of_batch(tmp_path, capsys):
    """The issue's pass: isam2 took 72x batch's wall time (every state relinearized at every
    update by the links' fine thresholds); with the states older than the relinearization
    window held (fgnav.solvers.options.relinearizing_links) at most 5x (CPU time, in one
    process, numba warmed up by a first batch)."""
    d = tmp_path / "fg"
    assert main(["simulate", "formation-gto", "--duration-h", "2", "--out", str(d),
                 "--quiet"]) == 0
    log = d / "measurements.csv"
    smooth_file(log, "batch", SmootherOptions())
    cpu = {}
    for method in ("batch", "isam2"):
        t = time.process_time()
        res, _ = smooth_file(log, method, SmootherOptions(), truth_path=d)
        cpu[method] = time.process_time() - t
        rel = res.summary["relative"]
        assert res.summary["integrity"]["status"] == "ok"
        assert rel["position_rms_m"] <= 2.0 * rel["sigma_position_rms_m"], rel
    assert cpu["isam2"] <= 5.0 * cpu["batch"], cpu


@pytest.fixture(scope="module")
def formation_body_hour(tmp_path_factory):
    """formation-gto, 1 h at 60 s, its Earth directions in each spacecraft's body frame
    (``--body-frame``: earth_direction_body rows and attitude rows of both spacecraft)."""
    d = tmp_path_factory.mktemp("formation-body")
    assert main(["simulate", "formation-gto", "--duration-h", "1", "--step-s", "60",
                 "--body-frame", "--out", str(d), "--quiet"]) == 0
    return d


@pytest.mark.parametrize("method", ["batch", "isam2"])
def test_estimate_attitude_gives_each_spacecraft_its_attitude(formation_body_hour, tmp_path,
                                                              capsys, method):
    """``--estimate attitude`` on a formation: one attitude per spacecraft (``attitude``,
    ``attitude_sat2``) bound to its own body-frame and attitude rows; the relative state within
    twice its 1-sigma and each attitude's NEES per component near 1 against the simulator's
    true attitude laws (truth_attitude-<id>.csv)."""
    log = formation_body_hour / "measurements.csv"
    text = log.read_text()
    assert ",earth_direction_body," in text and ",earth_direction," not in text
    rc, s = _smooth(log, tmp_path / "r", capsys, "--method", method, "--estimate", "attitude")
    assert rc == 0 and s["integrity"]["status"] == "ok", s["integrity"]
    assert s["measurements"]["earth_direction_body"] == 2 * 61
    rel = s["relative"]
    assert rel["position_rms_m"] <= 2.0 * rel["sigma_position_rms_m"], rel
    assert set(s["variables"]) == {"attitude", "attitude_sat2"}
    for name, v in s["variables"].items():
        assert 0.3 < v["nees_mean"] < 3.0, (name, v)
        assert max(v["error_rms"]) < 3.0 * max(v["sigma_rms"]), (name, v)
    header = (tmp_path / "r" / "variables.csv").read_text().splitlines()[0].split(",")
    assert {"att_x", "att_x_sat2"} <= set(header)


def test_body_frame_rows_without_estimate_are_turned_with_each_spacecrafts_attitude(
        formation_body_hour, tmp_path, capsys):
    """Without ``--estimate``, each spacecraft's body-frame rows enter as ECI directions turned
    by its own attitude rows (as for one spacecraft): the same relative accuracy."""
    rc, s = _smooth(formation_body_hour / "measurements.csv", tmp_path / "r", capsys)
    assert rc == 0 and s["integrity"]["status"] == "ok", s["integrity"]
    assert s["measurements"]["earth_direction"] == 2 * 61 and "variables" not in s
    rel = s["relative"]
    assert rel["position_rms_m"] <= 2.0 * rel["sigma_position_rms_m"], rel


@pytest.mark.parametrize("args, match", [
    (["--estimate", "refraction-bias"], "each spacecraft's attitude and gyro-bias only"),
    (["--estimate", "gyro-bias"], "add --estimate attitude"),
    (["--estimate", "attitude", "--estimate", "gyro-bias"], "used by gyro rows"),
    (["--state", "elements"], "each spacecraft's orbit"),
])
def test_what_a_formation_refuses_names_the_reason(formation_body_hour, tmp_path, capsys, args,
                                                   match):
    rc = main(["smooth", str(formation_body_hour / "measurements.csv"), "--out",
               str(tmp_path / "r"), "--quiet", *args])
    err = capsys.readouterr().err
    assert rc == 2 and match in err and "Traceback" not in err, err


def test_the_ekf_with_estimated_attitudes_ends_with_a_verdict(formation_body_hour, tmp_path,
                                                              capsys):
    """``--estimate attitude --method ekf``: the filter carries both attitudes; it diverges on
    this pass as it does without them (the first links' linearization error with 10 km priors
    on a 1 km formation, test_the_ekf_ends_with_a_verdict_not_a_traceback), and says so."""
    rc, s = _smooth(formation_body_hour / "measurements.csv", tmp_path / "r", capsys,
                    "--method", "ekf", "--estimate", "attitude", "--strict")
    assert set(s["variables"]) == {"attitude", "attitude_sat2"}
    if s["integrity"]["status"] == "ok":
        rel = s["relative"]
        assert rc == 0 and rel["position_rms_m"] <= 2.0 * rel["sigma_position_rms_m"], rel
    else:
        assert rc == 3 and s["integrity"]["reasons"]


def test_a_gate_that_rejects_most_rows_is_not_an_ok_verdict(formation_hour):
    """The verdict of a formation counts the rows its gate rejected, as one spacecraft's does
    (more than a quarter of a family: failed): an acceptance probability of 1e-4 (a user's
    false-alarm rate given where the acceptance probability is asked, which the command line
    refuses) rejected all but 6 of 1,448 rows and the verdict was ok, with a relative error of
    km. The command line's refusal names the probability meant."""
    res, _ = smooth_file(formation_hour / "measurements.csv", "isam2",
                         SmootherOptions(gate_probability=1e-4), truth_path=formation_hour)
    integrity = res.summary["integrity"]
    assert integrity["status"] == "failed", integrity
    assert any("rejected" in r for r in integrity["reasons"]), integrity["reasons"]


@pytest.fixture(scope="module")
def formation_gyro_hour(tmp_path_factory):
    """formation-gto, 1 h at 60 s, body-frame Earth directions, attitude rows and a rate gyro on
    each spacecraft (``--body-frame --gyro``: gyro rows with a bias of its own per spacecraft,
    truth_gyro_bias-<id>.csv)."""
    d = tmp_path_factory.mktemp("formation-gyro")
    assert main(["simulate", "formation-gto", "--duration-h", "1", "--step-s", "60",
                 "--body-frame", "--gyro", "--out", str(d), "--quiet"]) == 0
    return d


def _bias_truth(d, sc):
    lines = [ln for ln in (d / f"truth_gyro_bias-{sc}.csv").read_text().splitlines()
             if not ln.startswith("#")]
    return np.array([float(v) for v in lines[1].split(",")[1:]])


@pytest.mark.parametrize("method", ["batch", "isam2"])
def test_estimate_gyro_bias_gives_each_spacecraft_its_bias(formation_gyro_hour, tmp_path, capsys,
                                                           method):
    """``--estimate attitude,gyro-bias`` on a formation: each spacecraft's gyro rows on its own
    attitude and its own bias (``gyro_bias``, ``gyro_bias_sat2``); the two true biases differ
    by ~1e-4 rad/s, a hundred of their 1-sigmas, so rows bound to the wrong spacecraft would
    show. Against the simulator's truth: the relative state within twice its 1-sigma, each
    attitude's NEES near 1, each bias's error within its 1-sigma (RMS over the pass) and 3
    sigma at the end."""
    d = formation_gyro_hour
    assert ",gyro," in (d / "measurements.csv").read_text()
    rc, s = _smooth(d / "measurements.csv", tmp_path / "r", capsys, "--method", method,
                    "--estimate", "attitude", "--estimate", "gyro-bias")
    assert rc == 0 and s["integrity"]["status"] == "ok", s["integrity"]
    assert s["measurements"]["gyro"] == 2 * 60
    rel = s["relative"]
    assert rel["position_rms_m"] <= 2.0 * rel["sigma_position_rms_m"], rel
    assert set(s["variables"]) == {"attitude", "attitude_sat2", "gyro_bias", "gyro_bias_sat2"}
    for name in ("attitude", "attitude_sat2"):
        v = s["variables"][name]
        assert 0.3 < v["nees_mean"] < 3.0, (name, v)
    truth = {"gyro_bias": _bias_truth(d, "sat1"), "gyro_bias_sat2": _bias_truth(d, "sat2")}
    assert np.min(np.abs(truth["gyro_bias"] - truth["gyro_bias_sat2"])) > 1e-5
    for name, b in truth.items():
        v = s["variables"][name]
        assert np.all(np.array(v["error_rms"]) <= np.array(v["sigma_rms"])), (name, v)
        assert np.all(np.array(v["sigma_final"]) < 1e-5), (name, v)   # observed: 1e-3 prior
        final = np.array(v["mean"])   # a constant bias: the mean over the pass
        assert np.all(np.abs(final - b) < 3.0 * np.array(v["sigma_final"])), (name, final, b)
    header = (tmp_path / "r" / "variables.csv").read_text().splitlines()[0].split(",")
    assert {"gyro_bias_x", "gyro_bias_x_sat2"} <= set(header)


def test_gyro_rows_with_the_formation_ekf_are_refused_with_the_reason(formation_gyro_hour,
                                                                      tmp_path, capsys):
    rc = main(["smooth", str(formation_gyro_hour / "measurements.csv"), "--out",
               str(tmp_path / "r"), "--quiet", "--method", "ekf", "--estimate", "attitude"])
    err = capsys.readouterr().err
    assert rc == 2 and "rows between two epochs" in err and "Traceback" not in err, err


@pytest.mark.parametrize("method", ["isam2", "fixed-lag", "ekf"])
def test_the_online_methods_start_a_formation_without_its_priors(formation_hour, tmp_path,
                                                                 capsys, method):
    """``--ignore-prior`` with an online method (refused for a formation until 2026-12):
    every orbit starts from the initial orbit of its own rows, placed by the links, under a
    start prior inflated x100 (:func:`fgnav.start.with_formation_start_priors`). iSAM2 ends
    where batch does from the same start; fixed-lag and the EKF stay within twice their
    relative sigma, and their verdict states what their linear covariance understates (as
    with the priors: 1 h at 60 s, seed 0, relative RMS 2.19 / 3.82 / 5.43 m against
    1.34 / 2.19 / 4.33 m)."""
    log = formation_hour / "measurements.csv"
    rc, s = _smooth(log, tmp_path / "r", capsys, "--method", method, "--ignore-prior")
    rel = s["relative"]
    assert rc == 0 and "prior_position" not in s["measurements"]
    assert rel["position_rms_m"] <= 2.0 * rel["sigma_position_rms_m"], rel
    if method == "isam2":
        _, b = _smooth(log, tmp_path / "b", capsys, "--method", "batch", "--ignore-prior")
        assert s["integrity"]["status"] == "ok", s["integrity"]
        assert rel["position_rms_m"] == pytest.approx(b["relative"]["position_rms_m"], rel=0.01)
    else:
        assert s["integrity"]["status"] == "suspect", s["integrity"]
        assert s["integrity"]["tests"]["range_curvature"]["status"] == "suspect"
