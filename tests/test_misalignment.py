"""`fgnav schemes misalignment`: confocal vs separate star camera (mounting error ignored or
estimated), tight vs loose star coupling, and the dense joint Cramér–Rao bound."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fgnav.analysis import misalignment as M
from fgnav.cli import main
from fgnav.measurements import build_pass, with_estimates
from fgnav.pipeline import solve
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.solvers.options import SmootherOptions

ARCSEC = np.radians(1.0 / 3600.0)


@pytest.fixture(scope="module")
def small():
    """The command on a small case: 2 seeds of a 2 h pass, as JSON."""
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(["schemes", "misalignment", "--seeds", "2", "--duration-h", "2", "--json"])
    assert rc == 0
    return json.loads(buf.getvalue())


def test_small_case_shows_what_the_mounting_error_does(small):
    mean, runs = small["mean"], small["runs"]
    assert small["seeds"] == [0, 1] and set(mean) == set(M.CASES)
    a, b, c = (mean[k] for k in M.CASES[:3])
    # ignored, the mounting error makes the orbit and the attitude overconfident by far;
    # estimated, both are honest again
    assert b["nees"] > 10 * a["nees"] and b["attitude_nees"] > 10 * a["attitude_nees"]
    assert c["nees"] < b["nees"] / 5 and c["attitude_nees"] < b["attitude_nees"] / 5
    assert b["attitude_rms_rad"] > 1.5 * a["attitude_rms_rad"]
    assert len(runs["c separate, estimated"]) == 2
    assert a["integrity_ok"] == 1.0 and 0.0 <= b["integrity_ok"] <= 1.0
    # the confocal pass is "tight"; with few stars tight coupling wins on attitude
    assert mean["tight"] == mean["a confocal"]
    assert small["stars_per_frame"]["tight, few stars"] < 4 < small["stars_per_frame"]["tight"]
    assert mean["tight, few stars"]["attitude_rms_rad"] < mean["loose, few stars"]["attitude_rms_rad"]
    for v in small["tight_vs_loose"].values():      # tight's information contains loose's
        assert v["crb_position_not_worse"] and v["crb_attitude_better"]
    # the bounds exist where the model is right, and not for the ignored mounting
    assert "b separate, ignored" not in small["crb"]
    for case, bnd in small["crb"].items():
        assert bnd["position_rms_m"] > 0 and bnd["attitude_rms_rad"] > 0, case


def test_table_text(small):
    text = M.format_misalignment_table(small)
    for case in M.CASES:
        assert case in text
    assert "2 seeds" in text and "30 arcsec" in text


def test_dense_bound_matches_the_batch_covariance():
    """The bound, computed apart from the solver at the truth, against the batch smoother's
    own marginal covariance at its estimate (the same information up to linearization point
    and the process noise the bound leaves out): position, attitude and the mounting."""
    sim = simulate_pass(M._scenario(1.5, 60.0, M.MOUNTING_SIGMA_ARCSEC), seed=4)
    opts = SmootherOptions(q_m2_s3=1e-12, third_body=True,
                           estimate=("attitude", "camera-alignment"))
    p = with_estimates(build_pass(sim.log), opts.estimate)
    bound = M.joint_crb(p, M._truth_block(p, sim), opts)
    sol = solve(p, "batch", opts)
    sig_pos = np.sqrt(np.mean(np.trace(sol.P_eci[:, :3, :3], axis1=1, axis2=2)))
    _, P_att = sol.variables["attitude"]
    sig_att = np.sqrt(np.mean(np.trace(P_att, axis1=1, axis2=2)))
    _, P_m = sol.variables["camera_alignment"]
    assert bound["position_rms_m"] == pytest.approx(sig_pos, rel=0.05)
    assert bound["attitude_rms_rad"] == pytest.approx(sig_att, rel=0.05)
    np.testing.assert_allclose(bound["alignment_sigma_rad"], np.sqrt(np.diagonal(P_m[0])),
                               rtol=0.05)
    # the roll of the mounting about the boresight is seen by nothing but its prior
    assert bound["alignment_sigma_rad"][2] == pytest.approx(60 * ARCSEC, rel=1e-3)


def test_other_schemes_refuse_the_misalignment_options(capsys):
    assert main(["schemes", "refraction", "--seeds", "3"]) == 2
    assert "--seeds and --method apply to the misalignment scheme only" in capsys.readouterr().err


@pytest.mark.slow
def test_ten_seed_table():
    """The table of docs/misalignment.md: 10 seeds of the 6 h pass."""
    r = M.misalignment_study(range(10))
    mean = r["mean"]
    a, b, c = (mean[k] for k in M.CASES[:3])
    assert b["position_rms_m"] > a["position_rms_m"] and c["position_rms_m"] < b["position_rms_m"]
    assert b["nees"] > 30 and c["nees"] < 12 and a["nees"] < 12
    assert a["integrity_ok"] == c["integrity_ok"] == 1.0      # every seed's verdict ok
    for seed_b, seed_c in zip(r["runs"]["b separate, ignored"], r["runs"]["c separate, estimated"]):
        assert seed_c["position_rms_m"] < seed_b["position_rms_m"]
    # tight coupling is not worse on position (the mean paired difference within two of its
    # standard errors, and the bound) and better on attitude (the mean and the bound)
    for label, v in r["tight_vs_loose"].items():
        assert v["position_not_worse"] and v["crb_position_not_worse"], label
        assert v["attitude_better"] and v["crb_attitude_better"], label
    few = r["tight_vs_loose"]["few stars"]
    assert few["attitude_rms_tight_rad"] < 0.8 * few["attitude_rms_loose_rad"]
    print(M.format_misalignment_table(r))
