"""Leap seconds in every UTC epoch we read and write (log CSV, OEM, TDM), and a pass across
the last one (2016-12-31T23:59:60 UTC, IERS Bulletin C) smoothed end to end.

fgnav.time maps UTC labels to elapsed SI seconds with the leap-second table, so an instant
inside the leap second is its own time (printed 23:59:60.f) and a pass spanning it is one
second longer than its labels suggest."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fgnav.cli import main
from fgnav.io.log_csv import read_log, write_log
from fgnav.io.oem import format_ccsds_epoch, parse_ccsds_epoch, read_oem, write_oem
from fgnav.time import format_utc, parse_utc, seconds_since

LEAP_LOG = """\
epoch,kind,x,y,z,sigma
2016-12-31T23:59:59Z,earth_direction,-1,0,0,1e-4
2016-12-31T23:59:60Z,earth_direction,0,-1,0,1e-4
2016-12-31T23:59:60.5Z,earth_direction,0,0,-1,1e-4
2017-01-01T00:00:00Z,earth_direction,-1,0,0,1e-4
2017-01-01T00:00:01Z,earth_direction,0,-1,0,1e-4
"""


def test_log_csv_reads_and_writes_the_leap_second(tmp_path):
    p = tmp_path / "a.csv"
    p.write_text(LEAP_LOG)
    log = read_log(p)
    np.testing.assert_array_equal(log.t_s, [0.0, 1.0, 1.5, 2.0, 3.0])  # 3 s, not 2
    write_log(tmp_path / "b.csv", log)
    text = (tmp_path / "b.csv").read_text()
    assert "2016-12-31T23:59:60.000000Z" in text and "2016-12-31T23:59:60.500000Z" in text
    back = read_log(tmp_path / "b.csv")
    assert back.epoch0 == log.epoch0
    np.testing.assert_array_equal(back.t_s, log.t_s)


@pytest.mark.parametrize("bad", ["2017-12-31T23:59:60Z", "2016-12-31T23:58:60Z",
                                 "2016-12-31T23:59:61Z", "2016-06-30T23:59:60Z"])
def test_log_csv_refuses_a_second_60_that_did_not_exist(bad, tmp_path, capsys):
    p = tmp_path / "a.csv"
    p.write_text(LEAP_LOG.replace("2016-12-31T23:59:60.5Z", bad))
    assert main(["check", str(p)]) == 2
    err = capsys.readouterr().err
    assert f"{p}, line 4, column 'epoch'" in err and bad in err, err


def test_oem_epochs_round_trip_through_the_leap_second(tmp_path):
    e0 = parse_utc("2016-12-31T23:59:58Z")
    t = np.array([0.0, 1.0, 2.0, 2.25, 2.123456789, 3.0, 4.0])
    t.sort()
    x = np.tile([7e6, 0, 0, 0, 7.5e3, 0], (len(t), 1)) + np.arange(len(t))[:, None]
    write_oem(tmp_path / "a.oem", e0, t, x)
    text = (tmp_path / "a.oem").read_text()
    assert "2016-12-31T23:59:60.000000 " in text and "2016-12-31T23:59:60.123456789 " in text
    assert "2017-01-01T00:00:00.000000 " in text
    d = read_oem(tmp_path / "a.oem")
    assert d.epoch0 == e0
    np.testing.assert_allclose(d.t_s, t, rtol=0, atol=1e-9)
    # CCSDS day-of-year form: 2016 has 366 days
    assert parse_ccsds_epoch("2016-366T23:59:60.5") == parse_utc("2016-12-31T23:59:60.5Z")
    assert format_ccsds_epoch(parse_utc("2016-12-31T23:59:60.25Z")) == "2016-12-31T23:59:60.250000"
    with pytest.raises(ValueError):
        parse_ccsds_epoch("2016-365T23:59:60")


def test_tdm_epochs_in_the_leap_second(tmp_path):
    from fgnav.io.tdm import read_tdm

    p = tmp_path / "a.tdm"
    from test_cli_check import TDM

    p.write_text(TDM.replace(
        "ANGLE_1 = 2024-03-01T00:00:00 10.0\nANGLE_2 = 2024-03-01T00:00:00 20.0\n",
        "ANGLE_1 = 2016-12-31T23:59:59.5 10.0\nANGLE_2 = 2016-12-31T23:59:59.5 20.0\n"
        "ANGLE_1 = 2016-12-31T23:59:60.5 11.0\nANGLE_2 = 2016-12-31T23:59:60.5 21.0\n"
        "ANGLE_1 = 2017-001T00:00:00.5 12.0\nANGLE_2 = 2017-001T00:00:00.5 22.0\n"))
    log = read_tdm(p, sigma_rad=1e-4)
    np.testing.assert_array_equal(log.t_s, [0.0, 1.0, 2.0])
    assert format_utc(log.epoch0) == "2016-12-31T23:59:59.500000Z"


def _leap_scenario(epoch: str) -> str:
    """The built-in gto-transfer scenario (Pan & Yao 2017 orbit, direction only), 1 h from
    ``epoch``."""
    from fgnav.paths import data_dir

    text = (data_dir() / "scenarios" / "gto-transfer.toml").read_text()
    for old, new in (('epoch = "2025-03-01T00:00:00Z"', f'epoch = "{epoch}"'),
                     ("duration_h = 4.0", "duration_h = 1.0")):
        assert old in text
        text = text.replace(old, new)
    return text


def test_a_pass_across_the_leap_second_is_smoothed_like_any_other(tmp_path):
    """The same 1 h pass (two-body + J2 truth, independent of the date) simulated from
    2016-12-31T23:30:00Z, whose epoch t = 1800 s is 23:59:60, and from 2025-03-01: the
    files differ only in their epochs, and batch smoothing gives the same trajectory and the
    same accuracy against truth. Merging 23:59:60 with 00:00:00 would put the spacecraft a
    second (several km) off along its orbit for the second half of the pass."""
    res = {}
    for tag, epoch in (("leap", "2016-12-31T23:30:00Z"), ("plain", "2025-03-01T00:00:00Z")):
        scn = tmp_path / f"{tag}.toml"
        scn.write_text(_leap_scenario(epoch))
        d = tmp_path / tag
        assert main(["simulate", str(scn), "--out", str(d / "pass"), "--seed", "7", "--quiet"]) == 0
        assert main(["smooth", str(d / "pass" / "measurements.csv"), "--method", "batch",
                     "--out", str(d / "res"), "--truth", str(d / "pass" / "truth.oem")]) == 0
        res[tag] = (read_log(d / "pass" / "measurements.csv"), read_oem(d / "res" / "trajectory.oem"),
                    json.loads((d / "res" / "summary.json").read_text()),
                    (d / "pass" / "measurements.csv").read_text(), read_oem(d / "pass" / "truth.oem"))
    log_l, traj_l, sum_l, text_l, truth_l = res["leap"]
    log_p, traj_p, sum_p, _, _ = res["plain"]
    assert "2016-12-31T23:59:60.000000Z,earth_direction" in text_l
    assert "2017-01-01T00:00:09.000000Z,earth_direction" in text_l   # 10 s after 23:59:60
    assert "2017-01-01T00:29:59.000000Z,earth_direction" in text_l   # the end, t = 3600 s
    np.testing.assert_array_equal(log_l.t_s, log_p.t_s)        # elapsed seconds
    assert np.all(np.diff(np.unique(log_l.t_s)) == 10.0) and log_l.t_s[-1] == 3600.0
    np.testing.assert_array_equal(log_l.xyz, log_p.xyz)         # same measurements
    np.testing.assert_array_equal(truth_l.t_s, np.unique(log_l.t_s))
    assert "2016-12-31T23:59:60.000000 " in (tmp_path / "leap" / "pass" / "truth.oem").read_text()
    assert seconds_since(parse_utc("2017-01-01T00:30:00Z"), log_l.epoch0) == 3601.0
    np.testing.assert_allclose(traj_l.t_s, traj_p.t_s, rtol=0, atol=1e-9)
    np.testing.assert_allclose(traj_l.x_eci, traj_p.x_eci, rtol=0, atol=1e-3)  # mm (OEM digits)
    assert sum_l["position_rms_m"] == pytest.approx(sum_p["position_rms_m"], rel=1e-6)
    assert sum_l["nees_mean"] == pytest.approx(sum_p["nees_mean"], rel=1e-6)
    assert sum_l["nees_mean"] < 20.0          # consistent (6 expected), not a 1 s time error
