"""Xing et al.'s single-epoch study from a logged epoch (`fgnav formation conditioning --log`).

Xing et al. (ST-3 Autonomous Formation Flyer pseudorange positioning), Table 1 geometry and
its section-3 figures: rcond(A^T A) 1.09e-7 (Cartesian) vs 2.5e-2 (spherical), sigma_R
0.41 cm, clock 1.22 cm, az/el 0.01 rad at 1 cm, and 67.5 % (120 runs) of range errors within
+-1 sigma. The shipped log data/formation/xing-single-epoch.csv holds that geometry; the
same figures must come out of it as out of the built-in geometry (tests/test_formation.py).
On a simulated formation-gto pass the logged epochs are checked against the truth: range
errors consistent with sigma_R, and the light time in the clock estimate (c dt - u.v tau).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from factors.constants import C_LIGHT_M_S
from fgnav.cli import main
from fgnav.errors import UserError
from fgnav.formation.logged import (XING_LOG_NAME, logged_conditioning, logged_epoch,
                                    write_xing_single_epoch_log)
from fgnav.formation.study import conditioning_study
from fgnav.io.log_csv import read_log
from fgnav.paths import data_dir
from fgnav.scenarios import load_scenario
from fgnav.simulate.formation_sim import simulate_formation_pass
from fgnav.time import add_seconds, format_utc

XING = data_dir() / XING_LOG_NAME


@pytest.fixture(scope="module")
def logged():
    return logged_conditioning(logged_epoch(read_log(XING)), runs=5000, seed=0)


def test_shipped_log_is_written_by_its_function(tmp_path):
    write_xing_single_epoch_log(tmp_path / "x.csv")
    assert (tmp_path / "x.csv").read_bytes() == XING.read_bytes()


def test_logged_epoch_gives_xing_rcond(logged):
    """Xing et al.: rcond(A^T A) = 1.09e-7 (Cartesian) vs 2.5e-2 (spherical), m and rad."""
    c, s = logged["cartesian"], logged["spherical"]
    assert 1.0e-7 < c["rcond"] < 1.2e-7 and 1.0e-7 < c["rcond_1norm"] < 1.2e-7
    assert s["rcond_1norm"] < 2.5e-2 < s["rcond"]     # the two norms bracket Xing et al.'s
    assert 1.9e-2 < s["rcond_1norm"] and s["rcond"] < 3.1e-2
    assert logged["rcond_ratio_spherical_over_cartesian"] > 1e4


def test_logged_epoch_gives_xing_sigmas_and_coverage(logged):
    """Xing et al.: sigma_R = 0.41 cm, sigma_az = sigma_el = 0.01 rad, clock 1.22 cm;
    67.5 % of 120 runs within +-1 sigma (here 5,000 runs: 68.27 % +- 2 %)."""
    sR, saz, sel, sc = logged["spherical"]["sigmas"]
    assert sR == pytest.approx(0.0041, abs=0.0001)
    assert sc == pytest.approx(0.0122, abs=0.0001)
    assert saz == pytest.approx(0.01, rel=0.01) and sel == pytest.approx(0.01, rel=0.01)
    assert abs(logged["coverage_1sigma"] - 0.6827) < 0.02
    assert logged["log"]["spacecraft"] == ["sat1", "sat2"] and len(logged["log"]["links"]) == 6
    np.testing.assert_allclose(logged["log"]["M21"], np.eye(3), atol=1e-15)


def test_logged_epoch_equals_the_builtin_geometry(logged):
    """The log holds the built-in study's epoch-1 ranges: the same estimate and sigmas, from
    a different first guess (the far-field solution instead of Xing et al.'s R = 1992 m)."""
    b = conditioning_study(runs=10, seed=0)
    np.testing.assert_allclose(logged["spherical"]["sigmas"], b["spherical"]["sigmas_epoch1"],
                               rtol=1e-8)
    e, be = logged["estimate"], b["spherical"]["estimate_epoch1"]
    assert e["R_m"] == pytest.approx(be["R_m"], abs=1e-9)
    for k in ("az_rad", "el_rad", "cdt_m"):
        assert e[k] == pytest.approx(be[k], abs=1e-9)
    assert logged["cartesian"]["rcond"] == pytest.approx(
        b["cartesian"]["rcond_at_estimate"][0], rel=1e-6)


def test_second_epoch_by_option(capsys, tmp_path):
    out = tmp_path / "c.json"
    assert main(["formation", "conditioning", "--log", str(XING), "--epoch",
                 "2025-01-01T00:00:10Z", "--runs", "200", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "epoch 2025-01-01T00:00:10" in text and "sigma_R = 0.408 cm" in text, text
    assert "rcond(A^T A) = 1.11e-07" in text and "sigma_clock = 1.225 cm" in text, text
    d = json.loads(out.read_text())
    b = conditioning_study(runs=10, seed=0)["spherical"]["estimate_epoch2"]
    assert d["estimate"]["R_m"] == pytest.approx(b["R_m"], abs=1e-9) and d["runs"] == 200


def _edit(tmp_path, old, new, count=1):
    text = XING.read_text()
    assert old in text, old
    p = tmp_path / "edited.csv"
    p.write_text(text.replace(old, new, count))
    return p


@pytest.mark.parametrize("edit,args,words", [
    (None, ["--epoch", "2025-01-01T00:00:05Z"], "expected 6 isl_pseudorange rows"),
    (None, ["--epoch", "yesterday"], "--epoch 'yesterday'"),
    (("2025-01-01T00:00:00.000000Z,isl_pseudorange,999.9289042653824,,,0.01,sat1,sat2,rx3,tx0\n",
      ""), [], "found 5 (lines"),
    (("2025-01-01T00:00:00.000000Z,attitude,0.0,0.0,0.0,4.84813681109536e-06,sat2,,,\n", ""), [],
     "one attitude row of spacecraft sat2"),
    ((",sat2,sat1,rx", ",sat1,sat2,rx", 3), [], "every link is received by sat1"),
    (("sat2,rx3,tx0", "sat2,rx9,tx0"), [], "column 'rx_antenna'"),
    (None, ["--sigma-cm", "2"], "the rows' sigma column"),
])
def test_bad_logged_epoch_is_a_clear_error(tmp_path, capsys, edit, args, words):
    path = XING if edit is None else _edit(tmp_path, *edit)
    assert main(["formation", "conditioning", "--log", str(path), "--runs", "10", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("fgnav: error: ") and words in err and "Traceback" not in err, err


def test_epoch_needs_log_and_one_spacecraft_logs_are_refused(tmp_path, capsys):
    assert main(["formation", "conditioning", "--epoch", "2025-01-01T00:00:00Z"]) == 2
    assert "--epoch needs --log" in capsys.readouterr().err
    assert main(["simulate", "gto-transfer", "--out", str(tmp_path / "g"), "--quiet",
                 "--duration-h", "0.05"]) == 0
    assert main(["formation", "conditioning", "--log", str(tmp_path / "g" / "measurements.csv")]) == 2
    assert "no isl_pseudorange rows" in capsys.readouterr().err
    with pytest.raises(UserError, match="--runs"):
        logged_conditioning(logged_epoch(read_log(XING)), runs=0)


def test_formation_gto_epochs_against_truth():
    """Logged epochs of a simulated pass: range errors consistent with sigma_R (chi-square),
    and the light time in the clock: the instantaneous model of Xing et al. sees the
    transmitter moved by v tau, -u.v tau on the links received by sat 1 and +u.v tau on those
    received by sat 2, which is the clock's pattern: c dt_hat = c dt - u.v R / c (~2 cm)."""
    scn = load_scenario("formation-gto").with_options(duration_h=0.25)
    sim = simulate_formation_pass(scn, seed=11)
    log = sim.log
    zR, zc, zc0 = [], [], []
    for k, t in enumerate(sim.t_link[::3]):
        iso = format_utc(add_seconds(sim.epoch0, np.array([t])))[0]
        d = logged_conditioning(logged_epoch(log, iso), runs=1, seed=0)
        i = int(np.searchsorted(sim.t_s, t))
        x1, x2 = sim.x_true["sat1"][i], sim.x_true["sat2"][i]
        R = np.linalg.norm(x2[:3] - x1[:3])
        u = (x2[:3] - x1[:3]) / R
        bias = -u @ (0.5 * (x1[3:] + x2[3:])) * R / C_LIGHT_M_S
        sR, sc = d["spherical"]["sigmas"][0], d["spherical"]["sigmas"][3]
        clock = sim.clock_m[int(np.searchsorted(sim.t_link, t))]
        zR.append((d["estimate"]["R_m"] - R) / sR)
        zc.append((d["estimate"]["cdt_m"] - clock - bias) / sc)
        zc0.append((d["estimate"]["cdt_m"] - clock) / sc)
    zR, zc, zc0 = map(np.asarray, (zR, zc, zc0))
    n = zR.size
    assert abs(np.sum(zR ** 2) - n) < 5 * math.sqrt(2 * n), zR
    assert abs(np.sum(zc ** 2) - n) < 5 * math.sqrt(2 * n), zc
    assert abs(zc.mean()) < 4 / math.sqrt(n)
    assert abs(zc0.mean()) > 10 / math.sqrt(n), zc0       # without the light time: biased
