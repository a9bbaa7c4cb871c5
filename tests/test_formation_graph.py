"""Several spacecraft in one graph (fgnav.formation.joint): the joint solution against the
separate ones, the links against truth from the independent integrator, the outputs and
what a user is told (tests/formation_data.py builds the pass)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from formation_data import formation_log
from fgnav.errors import UserError
from fgnav.formation.joint import spacecraft_pass, spacecraft_states
from fgnav.formation.outputs import relative_rows, spherical_position_nees
from fgnav.formation.relative_state import relative_state_lvlh
from fgnav.io.log_csv import write_log
from fgnav.io.oem import read_oem, write_oem
from fgnav.measurements import build_pass
from fgnav.pipeline import smooth_log
from fgnav.solvers.batch import smooth_batch
from fgnav.solvers.options import SmootherOptions
from fgnav.time import parse_utc


def _relative_errors(res, p, truth):
    """RMS relative position error (m, LVLH) and the mean spherical position NEES."""
    rel, C, _ = relative_rows(res.solution, p, 1)
    rel_true = relative_state_lvlh(truth["A"][1], truth["B"][1])[0]
    err = rel - rel_true
    nees = spherical_position_nees(rel[:, :3], C[:, :3, :3], rel_true[:, :3])
    return np.sqrt(np.mean(np.sum(err[:, :3] ** 2, axis=1))), nees


def test_joint_graph_without_links_is_the_separate_solutions():
    """Two spacecraft with no link: the joint graph's blocks decouple, so each orbit and its
    covariance equal the one-spacecraft solution of its own rows."""
    log, _ = formation_log(3, links=False)
    res, p = smooth_log(log, "batch", SmootherOptions())
    assert p.layout.names == ("orbit", "orbit_B")
    for s, (x, P) in enumerate(spacecraft_states(res.solution, p.layout)):
        alone = smooth_batch(spacecraft_pass(p, s), SmootherOptions())
        np.testing.assert_allclose(x[:, :3], alone.x_eci[:, :3], atol=5e-3)
        np.testing.assert_allclose(np.sqrt(np.diagonal(P, axis1=1, axis2=2)),
                                   np.sqrt(np.diagonal(alone.P_eci, axis1=1, axis2=2)),
                                   rtol=1e-6)


def test_links_give_the_relative_state_consistently_over_seeds():
    """Pseudoranges (1 cm) shrink the relative error from hundreds of metres (celestial alone)
    to metres, with a relative position NEES in range, azimuth and elevation (3 dof, the pass
    and 10 seeds averaged) no larger than its 95 % band allows (measured 1.4: conservative;
    in Cartesian coordinates the chord error of a metre along the range sphere makes it ~20,
    see fgnav.formation.outputs.spherical_position_nees); carrier phase (10 um) to
    centimetres."""
    rms_alone, rms_links, nees = [], [], []
    for seed in range(10):
        log, truth = formation_log(seed, links=False)
        rms_alone.append(_relative_errors(*smooth_log(log, "batch", SmootherOptions()), truth)[0])
        log, truth = formation_log(seed)
        res, p = smooth_log(log, "batch", SmootherOptions())
        assert res.summary["integrity"]["status"] == "ok"
        r, n = _relative_errors(res, p, truth)
        rms_links.append(r)
        nees.append(n)
    assert np.median(rms_links) < 0.05 * np.median(rms_alone)
    # one correlated sample per seed and pass: the mean over 10 seeds of a chi2(3) quantity,
    # 95 % band of chi2(30)/10 = [1.70, 4.70]; below it the covariance is conservative
    assert 0.5 < np.mean(nees) < 4.70, nees
    log, truth = formation_log(0, carrier=True)
    res, p = smooth_log(log, "batch", SmootherOptions())
    assert res.summary["integrity"]["status"] == "ok"
    assert _relative_errors(res, p, truth)[0] < 0.5


def test_lever_arms_with_attitude_rows_match_the_centre_of_mass_case():
    """Antennas half a metre off the centre of mass, turned by the attitude rows: the same
    relative accuracy as centre-of-mass links (the lever arms are modelled, not ignored)."""
    log, truth = formation_log(2, lever_arms=True)
    res, p = smooth_log(log, "batch", SmootherOptions())
    assert res.summary["integrity"]["status"] == "ok"
    log0, _ = formation_log(2)
    res0, p0 = smooth_log(log0, "batch", SmootherOptions())
    assert abs(_relative_errors(res, p, truth)[0] - _relative_errors(res0, p0, truth)[0]) < 1.0


def test_a_wrong_link_sigma_is_flagged():
    """Ranges logged with a sigma 10x too small: the verdict is not ok."""
    log, _ = formation_log(4)
    isl = log.kind == "isl_pseudorange"
    log.sigma[isl] = 0.001
    res, _ = smooth_log(log, "batch", SmootherOptions())
    assert res.summary["integrity"]["status"] != "ok"
    assert "isl_pseudorange" in res.summary["integrity"]["reasons"][0]


def test_errors_a_user_can_act_on():
    log, _ = formation_log(5)
    with pytest.raises(UserError, match="--method batch"):
        smooth_log(log, "isam2", SmootherOptions())
    with pytest.raises(UserError, match="--estimate"):
        smooth_log(log, "batch", SmootherOptions(estimate=("attitude",)))
    log, _ = formation_log(5, lever_arms=True)
    keep = ~((log.kind == "attitude") & (log.t_s == log.t_s.max()))
    for name in ("t_s", "kind", "xyz", "sigma", "line"):
        setattr(log, name, getattr(log, name)[keep])
    log.extra = {c: v[keep] for c, v in log.extra.items()}
    with pytest.raises(UserError, match="no attitude row at this epoch"):
        build_pass(log)


def test_cli_writes_one_trajectory_per_spacecraft_and_the_relative_state(tmp_path):
    log, truth = formation_log(6, lever_arms=True)
    write_log(tmp_path / "pass.csv", log)
    for sc in "AB":
        write_oem(tmp_path / f"truth-{sc}.oem", parse_utc("2025-03-01T00:00:00Z"), truth[sc][0],
                  truth[sc][1])
    out = tmp_path / "result"
    r = subprocess.run([sys.executable, "-m", "fgnav", "smooth", str(tmp_path / "pass.csv"),
                        "--out", str(out), "--truth", str(tmp_path), "--quiet"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    names = sorted(f.name for f in out.iterdir())
    assert {"trajectory-A.oem", "trajectory-B.oem", "relative.csv", "summary.json",
            "residuals.csv", "variables.csv"} <= set(names)
    s = json.loads((out / "summary.json").read_text())
    assert set(s["spacecraft"]) == {"A", "B"}
    for sc in "AB":
        assert {"position_rms_m", "velocity_rms_mps", "nees_mean",
                "sigma_position_rms_m"} <= set(s["spacecraft"][sc])
        assert s["spacecraft"][sc]["position_rms_m"] < 1000
    assert {"position_rms_m", "velocity_rms_mps", "nees_mean"} <= set(s["relative"])
    oem = read_oem(out / "trajectory-B.oem")
    np.testing.assert_allclose(oem.x_eci[:, :3], truth["B"][1][:, :3], atol=1000)
    header = (out / "relative.csv").read_text().splitlines()[0].split(",")
    assert header[:6] == ["epoch", "t_s", "reference", "spacecraft", "lvlh_x_m", "lvlh_y_m"]
    rows = (out / "relative.csv").read_text().splitlines()[1:]
    assert len(rows) == len(truth["A"][0])
    body = rows[0].split(",")[header.index("body_x_m")]
    assert body != ""     # the reference's attitude rows give the body frame


def test_one_spacecraft_named_in_the_column_solves_as_before(tmp_path):
    """A log whose spacecraft column names one spacecraft is the one-spacecraft pass: the
    same numbers bit for bit as without the column."""
    log, _ = formation_log(7, links=False)
    a = log.extra["spacecraft"] == 0
    keep = np.flatnonzero(a)
    from fgnav.io.log_csv import log_from_arrays
    kw = dict(t_s=log.t_s[keep], kind=log.kind[keep], xyz=log.xyz[keep], sigma=log.sigma[keep])
    with_col = log_from_arrays(log.epoch0, extra={"spacecraft": ["A"] * len(keep)}, **kw)
    without = log_from_arrays(log.epoch0, **kw)
    r1, _ = smooth_log(with_col, "batch", SmootherOptions())
    r2, _ = smooth_log(without, "batch", SmootherOptions())
    np.testing.assert_array_equal(r1.solution.x_eci, r2.solution.x_eci)
    np.testing.assert_array_equal(r1.solution.P_eci, r2.solution.P_eci)
