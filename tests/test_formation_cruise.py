"""A heliocentric formation (issue 27, item 1: "a heliocentric formation"): the built-in
formation-cruise scenario, two spacecraft 1 km apart on the mars-cruise transfer about the
Sun, each with its Sun-star and Sun-Earth angles and no prior rows, linked by six 1 cm
pseudoranges every 4 h. One week (43 epochs) simulated; batch and iSAM2 end with exit 0, the
verdict ok, and the relative position within twice its own 1-sigma of the simulator's truth
(the independent DOP853 integrator's orbits, truth-<id>.oem)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fgnav.cli import main
from fgnav.io.log_csv import read_log
from fgnav.io.oem import read_oem
from fgnav.scenarios import load_scenario


@pytest.fixture(scope="module")
def cruise_week(tmp_path_factory):
    """formation-cruise, 1 week: a folder with measurements.csv and truth-<id>.oem."""
    d = tmp_path_factory.mktemp("cruise")
    assert main(["simulate", "formation-cruise", "--duration-h", "168", "--out", str(d),
                 "--quiet"]) == 0
    return d


def test_the_simulated_log_and_truth_are_heliocentric(cruise_week):
    """The log says '# centre: sun' and holds the links and attitude rows; each truth OEM is
    about the Sun; the pair is 1 km apart at the epoch (0.0315 s along the orbit)."""
    log = read_log(cruise_week / "measurements.csv")
    assert log.centre == "sun" and log.n_spacecraft == 2
    assert {"isl_pseudorange", "attitude", "body_star_angle"} <= set(np.asarray(log.kind).astype(str))
    states = []
    for sc in ("sat1", "sat2"):
        oem = read_oem(cruise_week / f"truth-{sc}.oem")
        assert str(oem.meta["CENTER_NAME"]).upper() == "SUN"
        states.append(np.asarray(oem.x_eci)[0])
    assert np.linalg.norm(states[0][:3]) > 1.0e11            # ~1 AU from the Sun
    assert np.linalg.norm(states[1][:3] - states[0][:3]) == pytest.approx(1000.0, rel=0.01)
    assert load_scenario("formation-cruise").centre == "sun"


@pytest.mark.parametrize("method", ["batch", "isam2"])
def test_batch_and_isam2_give_an_honest_relative_state_about_the_sun(cruise_week, tmp_path,
                                                                    capsys, method):
    out = tmp_path / method
    rc = main(["smooth", str(cruise_week / "measurements.csv"), "--out", str(out), "--truth",
               str(cruise_week), "--method", method, "--quiet"])
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    assert rc == 0, err
    s = json.loads((out / "summary.json").read_text())
    assert s["integrity"]["status"] == "ok", s["integrity"]
    rel = s["relative"]
    assert rel["position_rms_m"] <= 2.0 * rel["sigma_position_rms_m"], rel
    assert rel["position_rms_m"] < 50.0, rel          # the links fix the pair to metres ...
    for sc, d in s["spacecraft"].items():              # ... the angles each orbit to 1e3 km
        assert d["position_rms_m"] <= 2.0 * d["sigma_position_rms_m"], (sc, d)
    names = {f.name for f in out.iterdir()}
    assert {"trajectory-sat1.oem", "trajectory-sat2.oem", "relative.csv"} <= names, names
    assert "CENTER_NAME = SUN" in (out / "trajectory-sat2.oem").read_text()
