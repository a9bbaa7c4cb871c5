"""A separate star camera: its seeded mounting error in the simulator, and
`fgnav smooth --estimate camera-alignment` in batch, iSAM2 and the EKF."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from factors.geometry import so3_log
from fgnav.cli import main
from fgnav.models.registry import CAMERA_ALIGNMENT, EARTH_DIRECTION_BODY, STAR_DIRECTION_BODY
from fgnav.scenarios import load_scenario
from fgnav.simulate.pass_sim import RAW_STAR_CAMERA, raw_star_scenario, simulate_pass

ARCSEC = np.radians(1.0 / 3600.0)


def _scenario(mounting_arcsec, duration_h=1.5):
    import dataclasses

    cam = dataclasses.replace(RAW_STAR_CAMERA, mounting_sigma_arcsec=mounting_arcsec)
    return raw_star_scenario(load_scenario("geo-limb").with_options(duration_h=duration_h), cam)


def test_the_mounting_error_turns_the_star_rows_and_nothing_else():
    plain = simulate_pass(_scenario(0.0, 0.5), seed=5)
    sep = simulate_pass(_scenario(30.0, 0.5), seed=5)
    w = np.array([sep.truth_params[c][0] for c in CAMERA_ALIGNMENT.components])
    assert not any(c in plain.truth_params for c in CAMERA_ALIGNMENT.components)
    assert 0 < np.linalg.norm(w) < 6 * 30 * ARCSEC
    assert np.all(sep.truth_params[CAMERA_ALIGNMENT.components[0]] == w[0])
    e = plain.log.select(EARTH_DIRECTION_BODY.kind)
    np.testing.assert_array_equal(sep.log.xyz[e], plain.log.xyz[e])     # the same noise draws
    s = plain.log.select(STAR_DIRECTION_BODY.kind)
    # star rows in the camera frame, u_cam = M^T u_body (the noise drawn alike, in the tangent
    # basis of the turned direction): the rotation that takes the body-frame rows onto them
    # (SVD solution of Wahba's problem) is M^T, to a fraction of an arcsecond
    U, _, Vt = np.linalg.svd(sep.log.xyz[s].T @ plain.log.xyz[s])
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    assert np.linalg.norm(so3_log(R.T) - w) < 1.0 * ARCSEC
    again = simulate_pass(_scenario(30.0, 0.5), seed=5)
    np.testing.assert_array_equal(again.log.xyz, sep.log.xyz)
    other = simulate_pass(_scenario(30.0, 0.5), seed=6)
    assert other.truth_params["align_x"][0] != w[0]


@pytest.fixture(scope="module")
def separate_pass(tmp_path_factory):
    d = tmp_path_factory.mktemp("sep")
    assert main(["simulate", "geo-limb", "--out", str(d), "--raw-stars", "--duration-h", "1.5",
                 "--star-mounting-sigma-arcsec", "30", "--seed", "2", "--quiet"]) == 0
    assert (d / "truth_camera_alignment.csv").exists()
    return d


def _smooth(d, out, *extra):
    rc = main(["smooth", str(d / "measurements.csv"), "--out", str(out), "--attitude", "estimate",
               "--truth", str(d / "truth.oem"), "--third-body", "--quiet", *extra])
    assert rc == 0
    return json.loads((out / "summary.json").read_text())


@pytest.mark.parametrize("method", ["batch", "isam2", "fixed-lag", "ekf"])
def test_smooth_estimates_the_alignment(separate_pass, tmp_path, method):
    s = _smooth(separate_pass, tmp_path, "--estimate", "camera-alignment", "--method", method)
    v = s["variables"][CAMERA_ALIGNMENT.name]
    assert v["components"] == list(CAMERA_ALIGNMENT.components) and v["unit"] == "rad"
    # honest: the error within its sigma; the roll about the boresight (z) sees only its prior
    assert max(v["max_abs_error_over_sigma"]) < 4.0
    assert v["sigma_final"][2] == pytest.approx(60 * ARCSEC, rel=0.01)
    assert v["sigma_final"][0] < 0.9 * 60 * ARCSEC          # the tilt is observed
    with open(tmp_path / "variables.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert {"align_x", "align_x_sigma", "align_z_sigma"} <= set(rows[0])
    # one rotation for the pass: the full smoothers give the same at the first and last epoch
    # (to 0.01 arcsec; the EKF's and the fixed-lag smoother's estimate at an epoch is that of
    # the rows so far, or within the lag)
    for c in CAMERA_ALIGNMENT.components if method in ("batch", "isam2") else ():
        assert abs(float(rows[0][c]) - float(rows[-1][c])) < 0.01 * ARCSEC


def test_batch_and_isam2_agree_and_the_prior_is_an_option(separate_pass, tmp_path):
    b = _smooth(separate_pass, tmp_path / "b", "--estimate", "camera-alignment")
    i = _smooth(separate_pass, tmp_path / "i", "--estimate", "camera-alignment",
                "--method", "isam2")
    vb, vi = b["variables"][CAMERA_ALIGNMENT.name], i["variables"][CAMERA_ALIGNMENT.name]
    np.testing.assert_allclose(vi["mean"], vb["mean"], atol=0.05 * ARCSEC)
    np.testing.assert_allclose(vi["sigma_final"], vb["sigma_final"], rtol=1e-3)
    t = _smooth(separate_pass, tmp_path / "t", "--estimate", "camera-alignment",
                "--alignment-sigma-arcsec", "10")
    vt = t["variables"][CAMERA_ALIGNMENT.name]
    assert vt["sigma_final"][2] == pytest.approx(10 * ARCSEC, rel=0.01)


def test_alignment_needs_the_attitude_and_its_prior_needs_the_alignment(separate_pass, tmp_path,
                                                                       capsys):
    log = str(separate_pass / "measurements.csv")
    assert main(["smooth", log, "--out", str(tmp_path / "x"), "--estimate",
                 "camera-alignment"]) == 2
    err = capsys.readouterr().err
    assert "--estimate camera-alignment" in err and "--estimate attitude" in err
    assert main(["smooth", log, "--out", str(tmp_path / "y"), "--attitude", "estimate",
                 "--alignment-sigma-arcsec", "10"]) == 2
    assert "add --estimate camera-alignment" in capsys.readouterr().err
