"""summary.json carries the solution's own RMS 1-sigma with or without a truth (issue 32 item
4: a user without a truth must still read how good the solution claims to be)."""
import json

import numpy as np
import pytest

from fgnav.cli import main
from fgnav.io.oem import read_oem


@pytest.fixture(scope="module")
def short_pass(tmp_path_factory):
    d = tmp_path_factory.mktemp("pass")
    assert main(["simulate", "gto-transfer", "--out", str(d), "--duration-h", "0.5",
                 "--step-s", "60", "--seed", "3"]) == 0
    return d


@pytest.mark.parametrize("method", ["batch", "ekf"])
def test_sigma_is_in_the_summary_without_a_truth(short_pass, tmp_path, method):
    out, out_t = tmp_path / "r", tmp_path / "rt"
    log = str(short_pass / "measurements.csv")
    assert main(["smooth", log, "--out", str(out), "--method", method]) == 0
    assert main(["smooth", log, "--out", str(out_t), "--method", method,
                 "--truth", str(short_pass / "truth.oem")]) == 0
    s = json.loads((out / "summary.json").read_text())
    st = json.loads((out_t / "summary.json").read_text())
    assert "position_rms_m" not in s and "position_rms_m" in st
    # the same figure with and without the truth, and it is the OEM covariances' RMS sigma
    assert s["sigma_position_rms_m"] == pytest.approx(st["sigma_position_rms_m"], rel=1e-12)
    oem = read_oem(out / "trajectory.oem")
    P = oem.P_eci[:, :3, :3]   # (SI)
    sigma = float(np.sqrt(np.mean(np.trace(P, axis1=1, axis2=2))))
    assert s["sigma_position_rms_m"] == pytest.approx(sigma, rel=1e-6)
    assert s["sigma_velocity_rms_mps"] > 0
