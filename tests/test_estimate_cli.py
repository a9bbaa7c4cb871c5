"""``fgnav smooth --estimate ...`` end to end through the CLI, as a user would misuse it.

A short refraction pass (refraction-leo, 15 min) with an Earth sensor reporting the Earth's
direction in the body frame and an attitude row per epoch, simulated once per module; each
test edits the log the way a user's log could differ (rows missing, attitudes near a half
turn, ...) and checks that the run gives a sound solution or a clear ``fgnav: error:``.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from fgnav.cli import main
from fgnav.paths import data_dir


@pytest.fixture(scope="module")
def att_log(tmp_path_factory):
    """(directory, header lines, data rows split at commas) of the simulated pass."""
    tmp = tmp_path_factory.mktemp("att")
    text = (data_dir() / "scenarios" / "refraction-leo.toml").read_text()
    text = text.replace("duration_h = 3.0", "duration_h = 0.25")
    text += '\n[[sensor]]\nkind = "earth_direction_body"\nsigma_deg = 0.02\n'
    (tmp / "scn.toml").write_text(text)
    assert main(["simulate", str(tmp / "scn.toml"), "--out", str(tmp / "sim"), "--seed", "3",
                 "--quiet"]) == 0
    lines = (tmp / "sim" / "measurements.csv").read_text().splitlines()
    head = [ln for ln in lines if ln.startswith("#") or ln.startswith("epoch")]
    rows = [ln.split(",") for ln in lines if ln not in head]
    return tmp, head, rows


def _write(tmp, name, head, rows):
    path = tmp / name
    path.write_text("\n".join(head + [",".join(r) for r in rows]) + "\n")
    return str(path)


def _smooth(capsys, log, out, *args):
    rc = main(["smooth", log, "--out", str(out), "--quiet", *args])
    err = capsys.readouterr().err
    return rc, err


@pytest.mark.parametrize("method", ["batch", "ekf"])
def test_body_rows_at_epochs_without_attitude_rows(att_log, capsys, tmp_path, method):
    """With --estimate attitude a body-frame row needs no attitude row at its epoch: the
    random walk carries the attitude there from the measured ones. Without it the row cannot
    be rotated into ECI, and the error names the lines."""
    tmp, head, rows = att_log
    n, kept = 0, []
    for r in rows:
        if r[1] == "attitude":
            n += 1
            if n % 3 == 0:
                continue
        kept.append(r)
    log = _write(tmp_path, "some_attitudes.csv", head, kept)
    truth = str(tmp / "sim" / "truth.oem")
    rc, err = _smooth(capsys, log, tmp_path / "plain", "--method", method)
    assert rc == 2 and "fgnav: error:" in err and "need an 'attitude' row" in err
    rc, err = _smooth(capsys, log, tmp_path / "est", "--method", method, "--estimate",
                      "attitude", "--truth", truth)
    assert rc == 0, err
    s = json.loads((tmp_path / "est" / "summary.json").read_text())
    n_body = sum(r[1] == "earth_direction_body" for r in rows)
    assert s["measurements"]["earth_direction_body"] == n_body        # every body row used
    assert s["measurements"]["attitude"] == n - n // 3
    assert s["integrity"]["status"] == "ok"
    # as accurate as with every attitude row (the Earth sensor adds little to refraction)
    rc, err = _smooth(capsys, str(tmp / "sim" / "measurements.csv"), tmp_path / "full",
                      "--method", method, "--estimate", "attitude", "--truth", truth)
    full = json.loads((tmp_path / "full" / "summary.json").read_text())
    assert s["position_rms_m"] == pytest.approx(full["position_rms_m"], rel=0.05)
    assert s["nees_mean"] < 2.0 * full["nees_mean"]


def test_a_checkpoint_belongs_to_the_set_of_variables_not_to_its_spelling(att_log, capsys,
                                                                          tmp_path):
    """A repeated, reordered or underscored --estimate asks for the same variables: it
    resumes the checkpoint; another set of variables is refused with exit 2."""
    tmp, _, _ = att_log
    log, ck = str(tmp / "sim" / "measurements.csv"), str(tmp_path / "ck.npz")
    rc, err = _smooth(capsys, log, tmp_path / "a", "--method", "isam2", "--estimate", "attitude",
                      "--estimate", "refraction-bias", "--checkpoint", ck,
                      "--checkpoint-every", "30")
    assert rc == 0, err
    rc, err = _smooth(capsys, log, tmp_path / "b", "--method", "isam2", "--estimate",
                      "refraction_bias", "--estimate", "attitude", "--estimate", "attitude",
                      "--checkpoint", ck, "--resume")
    assert rc == 0, err
    a = (tmp_path / "a" / "variables.csv").read_text().splitlines()
    b = (tmp_path / "b" / "variables.csv").read_text().splitlines()
    assert a[0] == b[0]          # the same columns in the same order
    for name in ([], ["--estimate", "attitude"]):
        rc, err = _smooth(capsys, log, tmp_path / "c", "--method", "isam2", *name,
                          "--checkpoint", ck, "--resume")
        assert rc == 2 and "fgnav: error:" in err and "belongs to another log or other options" in err


@pytest.fixture(scope="module")
def bias_sim(tmp_path_factory):
    """refraction-leo-bias, 15 min: measurements.csv, truth.oem, truth_refraction_bias.csv."""
    out = tmp_path_factory.mktemp("bias") / "sim"
    assert main(["simulate", "refraction-leo-bias", "--out", str(out), "--seed", "4",
                 "--duration-h", "0.25", "--quiet"]) == 0
    return out


@pytest.mark.parametrize("edit, message", [
    (lambda lines: lines[:10], "does not cover the log's epochs"),
    (lambda lines: [ln.replace("refraction_bias_m", "bias_m") for ln in lines],
     "expected the column(s) refraction_bias_m"),
    (lambda lines: lines[:6] + [lines[6].split(",")[0] + ",nan"] + lines[7:],
     "line 7, column 'refraction_bias_m'"),
])
def test_a_bad_truth_variable_file_is_refused_before_solving(bias_sim, tmp_path, capsys,
                                                             monkeypatch, edit, message):
    """The truth of the bias beside --truth is checked with the truth OEM, before any work,
    and the error names the file (and line)."""
    import fgnav.pipeline
    lines = (bias_sim / "truth_refraction_bias.csv").read_text().splitlines()
    (tmp_path / "truth.oem").write_text((bias_sim / "truth.oem").read_text())
    (tmp_path / "truth_refraction_bias.csv").write_text("\n".join(edit(lines)) + "\n")

    def no_solving(*a, **k):
        raise AssertionError("solved before checking the truth")
    monkeypatch.setattr(fgnav.pipeline, "solve", no_solving)
    rc, err = _smooth(capsys, str(bias_sim / "measurements.csv"), tmp_path / "out",
                      "--estimate", "refraction-bias", "--truth", str(tmp_path / "truth.oem"))
    assert rc == 2 and err.startswith("fgnav: error: ") and "truth_refraction_bias.csv" in err
    assert message in err


@pytest.mark.parametrize("method", ["batch", "isam2"])
def test_no_prior_with_the_attitude_estimated(att_log, capsys, tmp_path, method):
    """--ignore-prior starts from the initial orbit of the Earth directions; with the
    attitude estimated they are body-frame rows, which the initial orbit determination
    rotates with the attitude rows as it does without --estimate (it used to say that the
    log lacked 'earth_direction_body + attitude' rows, which it has)."""
    tmp, _, _ = att_log
    log, truth = str(tmp / "sim" / "measurements.csv"), str(tmp / "sim" / "truth.oem")
    runs = {}
    for name, est in (("known", []), ("estimated", ["--estimate", "attitude"])):
        rc, err = _smooth(capsys, log, tmp_path / name, "--method", method, "--ignore-prior",
                          "--truth", truth, *est)
        assert rc == 0, err
        runs[name] = json.loads((tmp_path / name / "summary.json").read_text())
    known, est = runs["known"], runs["estimated"]
    assert est["initial_orbit"]["prior"] == "ignored"
    assert est["initial_orbit"]["method"] == known["initial_orbit"]["method"]
    assert est["position_rms_m"] == pytest.approx(known["position_rms_m"], rel=0.02)
    assert est["integrity"]["status"] == "ok" and "attitude" in est["variables"]


@pytest.mark.parametrize("method", ["isam2", "fixed-lag"])
def test_the_gate_rejects_body_frame_outliers_with_the_attitude_estimated(att_log, capsys,
                                                                          tmp_path, method):
    """--gate with --estimate attitude: the body-frame rows are gated against the attitude
    of their epoch's attitude rows (it used to be the attitude's 10 rad prior, which let
    every outlier through: 8.5 -> 31 m RMS on a 1 h pass with 18 outliers of ~3 deg)."""
    tmp, head, rows = att_log
    rng = np.random.default_rng(7)
    edited, n, bad = [], 0, 0
    for r in rows:
        r = list(r)
        if r[1] == "earth_direction_body":
            n += 1
            if n % 10 == 0:
                u = np.array([float(c) for c in r[2:5]]) + rng.normal(0.0, 0.05, 3)
                r[2:5] = [repr(float(c)) for c in u / np.linalg.norm(u)]
                bad += 1
        edited.append(r)
    log = _write(tmp_path, "outliers.csv", head, edited)
    truth = str(tmp / "sim" / "truth.oem")
    runs = {}
    for name, est in (("known", []), ("estimated", ["--estimate", "attitude"])):
        rc, err = _smooth(capsys, log, tmp_path / name, "--method", method, "--gate", "0.9999",
                          "--truth", truth, *est)
        assert rc == 0, err
        runs[name] = json.loads((tmp_path / name / "summary.json").read_text())
    assert runs["known"]["rejected"] == {"earth_direction": bad}
    assert runs["estimated"]["rejected"] == {"earth_direction_body": bad}
    assert runs["estimated"]["position_rms_m"] == pytest.approx(
        runs["known"]["position_rms_m"], rel=0.02)
    assert runs["estimated"]["integrity"]["status"] == "ok"


def test_the_gate_rejects_refraction_outliers_with_the_bias_estimated(bias_sim, capsys,
                                                                      tmp_path):
    """--gate with --estimate refraction-bias (isam2): refraction rows are gated against the
    bias's online marginal plus its random walk, not its 1 km prior, which let tangent
    heights ~2 km off (20 sigma) through."""
    lines = (bias_sim / "measurements.csv").read_text().splitlines()
    head = [ln for ln in lines if ln.startswith("#") or ln.startswith("epoch")]
    ig = head[-1].split(",").index("gamma")
    rows, n, bad = [], 0, []
    for ln in lines[len(head):]:
        r = ln.split(",")
        if r[1] == "refraction":
            n += 1
            if n % 25 == 0:
                r[ig] = repr(float(r[ig]) * 1.3)
                bad.append(float(r[0][11:13]) * 3600 + float(r[0][14:16]) * 60 + float(r[0][17:-1]))
        rows.append(r)
    log = _write(tmp_path, "outliers.csv", head, rows)
    rc, err = _smooth(capsys, log, tmp_path / "out", "--method", "isam2", "--gate", "0.9999",
                      "--estimate", "refraction-bias", "--truth", str(bias_sim / "truth.oem"))
    assert rc == 0, err
    s = json.loads((tmp_path / "out" / "summary.json").read_text())
    late = sum(t > 120.0 for t in bad)   # after the first 2 min (the 10 km prior's settling)
    assert s["rejected"]["refraction"] >= late > 0
    assert s["variables"]["refraction_bias"]["error_rms"][0] < 60.0


@pytest.mark.parametrize("method", ["ekf", "batch"])
def test_a_misaligned_attitude_fails_the_verdict_with_the_attitude_estimated(att_log, capsys,
                                                                             tmp_path, method):
    """Attitude rows 0.2 deg off the Earth sensor's frame (a misaligned star tracker):
    the body-frame directions disagree with them by ~10 sigma. The verdict fails with the
    attitude known and estimated alike; the EKF's normalized innovations used to divide the
    body-frame rows by the attitude's random walk instead of the attitude its epoch's rows
    give, and said they fit (chi2/dof 0.006)."""
    from factors.geometry import so3_exp, so3_log
    tmp, head, rows = att_log
    C = so3_exp(np.radians(0.2) * np.array([1.0, 0.0, 0.0]))
    edited = []
    for r in rows:
        r = list(r)
        if r[1] == "attitude":
            w = so3_log(so3_exp(np.array([float(c) for c in r[2:5]])) @ C)
            r[2:5] = [repr(float(c)) for c in w]
        edited.append(r)
    log = _write(tmp_path, "misaligned.csv", head, edited)
    for name, est in (("known", []), ("estimated", ["--estimate", "attitude"])):
        rc, err = _smooth(capsys, log, tmp_path / name, "--method", method, "--strict", *est)
        assert rc == 3, err
        s = json.loads((tmp_path / name / "summary.json").read_text())
        body = "earth_direction_body" if est else "earth_direction"
        assert s["integrity"]["status"] == "failed"
        assert s["integrity"]["families"][body]["status"] == "failed"
    # and no false alarm on the log as simulated
    rc, err = _smooth(capsys, str(tmp / "sim" / "measurements.csv"), tmp_path / "clean",
                      "--method", method, "--strict", "--estimate", "attitude")
    assert rc == 0, err
