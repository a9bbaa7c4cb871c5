"""CCSDS OEM 2.0 KVN (fgnav.io.oem): round trip, standard layout, hand-written files, errors."""

from __future__ import annotations

import numpy as np
import pytest

from fgnav.errors import InputFormatError
from fgnav.io.oem import format_ccsds_epoch, parse_ccsds_epoch, read_oem, write_oem
from fgnav.time import add_seconds, parse_utc

EPOCH0 = parse_utc("2024-03-01T00:00:00Z")


def _states(seed=3, N=8):
    rng = np.random.default_rng(seed)
    t = np.arange(N) * 60.0 + rng.uniform(0, 1, N).round(6)
    x = rng.normal(size=(N, 6)) * [7e6, 7e6, 7e6, 7.5e3, 7.5e3, 7.5e3]
    A = rng.normal(size=(N, 6, 6))
    D = np.diag([30.0, 30.0, 30.0, 0.03, 0.03, 0.03])  # m, m/s
    P = D @ (A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(6)) @ D
    return t, x, P


def test_round_trip_states_below_1mm_covariance_1e12(tmp_path):
    t, x, P = _states()
    p = tmp_path / "a.oem"
    write_oem(p, EPOCH0, t, x, P, object_name="SAT-1", object_id="2024-001A")
    d = read_oem(p)
    ns_in = (add_seconds(EPOCH0, t) - EPOCH0).astype(np.int64)
    ns_out = (add_seconds(d.epoch0, d.t_s) - EPOCH0).astype(np.int64)
    np.testing.assert_array_equal(ns_out, ns_in)  # microsecond epochs are exact
    assert d.epoch0 == add_seconds(EPOCH0, t[0])  # epoch0 = first epoch
    assert np.abs(d.x_eci[:, :3] - x[:, :3]).max() < 1e-3            # < 1 mm
    assert np.abs(d.x_eci[:, 3:] - x[:, 3:]).max() < 1e-6            # < 1 µm/s
    scale = np.sqrt(np.einsum("nii->ni", P))
    rel = np.abs(d.P_eci - P) / (scale[:, :, None] * scale[:, None, :])
    assert rel.max() < 1e-12
    assert d.meta["OBJECT_NAME"] == "SAT-1" and d.meta["OBJECT_ID"] == "2024-001A"
    assert d.meta["covariance_missing"] == 0


def test_round_trip_without_covariance(tmp_path):
    t, x, _ = _states(N=3)
    write_oem(tmp_path / "a.oem", EPOCH0, t, x, None)
    d = read_oem(tmp_path / "a.oem")
    assert d.P_eci is None
    assert "COVARIANCE" not in (tmp_path / "a.oem").read_text()


def test_epochs_without_finite_covariance_get_no_block(tmp_path):
    t, x, P = _states(N=4)
    P[1] = np.nan
    write_oem(tmp_path / "a.oem", EPOCH0, t, x, P)
    assert (tmp_path / "a.oem").read_text().count("EPOCH =") == 3
    d = read_oem(tmp_path / "a.oem")
    assert np.isnan(d.P_eci[1]).all() and np.isfinite(d.P_eci[[0, 2, 3]]).all()
    assert d.meta["covariance_missing"] == 1
    P[:] = np.nan
    write_oem(tmp_path / "b.oem", EPOCH0, t, x, P)
    assert read_oem(tmp_path / "b.oem").P_eci is None


def test_written_layout_follows_the_standard(tmp_path):
    t = np.array([0.0, 10.0])
    x = np.array([[7000e3, -1e3, 0.5, 1.0, 7500.0, -0.25]] * 2)
    P = np.tile(np.diag([1e2, 4e2, 9e2, 1e-2, 4e-2, 9e-2]), (2, 1, 1))
    P[:, 3, 0] = P[:, 0, 3] = 0.5
    p = tmp_path / "a.oem"
    write_oem(p, EPOCH0, t, x, P, comments=["fgnav test", "two lines"],
              creation_date=parse_utc("2024-03-02T12:00:00Z"))
    lines = [ln for ln in p.read_text().splitlines() if ln.strip()]
    assert lines[:5] == ["CCSDS_OEM_VERS = 2.0", "COMMENT fgnav test", "COMMENT two lines",
                         "CREATION_DATE = 2024-03-02T12:00:00.000000", "ORIGINATOR = FGNAV"]
    assert lines[5:14] == [
        "META_START", "OBJECT_NAME = FGNAV", "OBJECT_ID = UNKNOWN", "CENTER_NAME = EARTH",
        "REF_FRAME = EME2000", "TIME_SYSTEM = UTC", "START_TIME = 2024-03-01T00:00:00.000000",
        "STOP_TIME = 2024-03-01T00:00:10.000000", "META_STOP"]
    f = lines[14].split()
    assert len(f) == 7 and f[0] == "2024-03-01T00:00:00.000000"
    assert [float(v) for v in f[1:]] == [7000.0, -1.0, 0.0005, 0.001, 7.5, -0.00025]  # km, km/s
    assert lines[16] == "COVARIANCE_START" and lines[-1] == "COVARIANCE_STOP"
    assert lines[17] == "EPOCH = 2024-03-01T00:00:00.000000"
    assert lines[18] == "COV_REF_FRAME = EME2000"
    rows = [[float(v) for v in ln.split()] for ln in lines[19:25]]
    assert [len(r) for r in rows] == [1, 2, 3, 4, 5, 6]                  # lower triangle
    assert rows[0][0] == pytest.approx(1e-4)                              # km^2
    assert rows[3][0] == pytest.approx(5e-7)   # km^2/s
    assert rows[3][3] == pytest.approx(1e-8)   # km^2/s^2


HAND_WRITTEN = """\
CCSDS_OEM_VERS = 2.0
COMMENT  hand-written after the KVN example of CCSDS 502.0-B-2 (figure 5-3), EME2000 frame
CREATION_DATE = 1996-11-04T17:22:31
ORIGINATOR = NASA/JPL

META_START
OBJECT_NAME = MARS GLOBAL SURVEYOR
OBJECT_ID = 1996-062A
CENTER_NAME = EARTH
REF_FRAME = EME2000
TIME_SYSTEM = UTC
START_TIME = 1996-12-28T21:29:07.267
USEABLE_START_TIME = 1996-12-28T21:29:07.267
USEABLE_STOP_TIME = 1996-12-28T22:00:02.267
STOP_TIME = 1996-12-28T22:00:02.267
INTERPOLATION = HERMITE
INTERPOLATION_DEGREE = 7
META_STOP

COMMENT  This file was produced by M.R. Somebody, MSOO NAV/JPL, 1996NOV 04.
1996-12-28T21:29:07.267 -2432.166 -063.042 1742.754 7.33702 -3.495867 -1.041945
1996-12-28T21:59:02.267 -2445.234 -878.141 1873.073 1.86043 -3.421256 -0.996366
1996-12-28T22:00:02.267 -2458.079 -683.858 2007.684 6.36786 -3.339563 -0.946654

COVARIANCE_START
EPOCH = 1996-12-28T21:29:07.267
COV_REF_FRAME = EME2000
3.3313494e-04
4.6189273e-04 6.7824216e-04
-3.0700078e-04 -4.2212341e-04 3.2319319e-04
-3.3493650e-07 -4.6860842e-07 2.4849495e-07 4.2960228e-10
-2.2118325e-07 -2.8641868e-07 1.7980986e-07 2.6088992e-10 1.7675147e-10
-3.0413460e-07 -4.9894969e-07 3.5403109e-07 1.8692631e-10 1.0088625e-10 6.2244443e-10
EPOCH = 1996-12-28T22:00:02.267
3.4424505e-04
4.5078162e-04 6.8935327e-04
-3.0600067e-04 -4.1101230e-04 3.3420420e-04
-3.2382549e-07 -4.5750731e-07 2.3738384e-07 4.3071339e-10
-2.1007214e-07 -2.7530757e-07 1.6870875e-07 2.7199103e-10 1.8786258e-10
-3.0302359e-07 -4.8783858e-07 3.4302008e-07 1.7581520e-10 1.0077514e-10 6.2244443e-10
COVARIANCE_STOP

META_START
OBJECT_NAME = MARS GLOBAL SURVEYOR
OBJECT_ID = 1996-062A
CENTER_NAME = EARTH
REF_FRAME = EME2000
TIME_SYSTEM = UTC
START_TIME = 1996-363T22:10:00Z
STOP_TIME = 1996-364T00:00:00Z
META_STOP
1996-363T22:10:00Z -2470.000 -500.000 2100.000 6.0 -3.2 -0.9 0.001 0.002 0.003
1996-364T00:00:00 -2480.000 -400.000 2200.000 5.9 -3.1 -0.8 0.001 0.002 0.003
"""


def test_reads_hand_written_standard_file(tmp_path):
    p = tmp_path / "mgs.oem"
    p.write_text(HAND_WRITTEN)
    d = read_oem(p)
    assert d.epoch0 == parse_utc("1996-12-28T21:29:07.267Z")
    assert len(d.t_s) == 5
    np.testing.assert_allclose(d.t_s[:3], [0.0, 1795.0, 1855.0], atol=0, rtol=0)
    # Day-of-year epochs of the second segment: 1996 is a leap year, day 363 = Dec 28.
    assert d.t_s[3] == 1855.0 + 10 * 60 - 2.267
    assert d.t_s[4] == d.t_s[3] + 110 * 60
    np.testing.assert_allclose(d.x_eci[0], [-2432166.0, -63042.0, 1742754.0, 7337.02,
                                            -3495.867, -1041.945], rtol=1e-15)
    np.testing.assert_allclose(d.x_eci[4, :3], [-2480e3, -400e3, 2200e3], rtol=1e-15)
    assert d.P_eci.shape == (5, 6, 6)
    assert d.P_eci[0, 0, 0] == pytest.approx(333.13494, rel=1e-12)      # km^2 -> m^2
    assert d.P_eci[0, 0, 5] == d.P_eci[0, 5, 0] == pytest.approx(-0.3041346, rel=1e-12)
    assert d.P_eci[2, 5, 5] == pytest.approx(6.2244443e-4, rel=1e-12)
    assert np.isnan(d.P_eci[1]).all() and np.isnan(d.P_eci[3]).all()
    assert d.meta["covariance_missing"] == 3 and d.meta["covariance_unmatched"] == 0
    assert d.meta["ORIGINATOR"] == "NASA/JPL" and len(d.meta["segments"]) == 2
    assert d.meta["INTERPOLATION"] == "HERMITE"


def test_ccsds_epoch_forms():
    assert parse_ccsds_epoch("2024-061T00:00:00") == parse_utc("2024-03-01T00:00:00Z")
    assert parse_ccsds_epoch("2023-060T12:00:00.5Z") == parse_utc("2023-03-01T12:00:00.5Z")
    t = parse_utc("2024-03-01T00:00:00.123456789Z")
    assert parse_ccsds_epoch(format_ccsds_epoch(t)) == t
    for bad in ("2023-366T00:00:00", "2024-000T00:00:00", "2024-02-30T00:00:00",
                "2024-03-01 00:00:00", "2024-03-01T24:00:00", "9999-001T00:00:00",
                "0001-01-01T00:00:00"):  # (datetime64[ns] would wrap these silently)
        with pytest.raises(ValueError):
            parse_ccsds_epoch(bad)


def _good_text(tmp_path):
    t, x, P = _states(N=3)
    p = tmp_path / "g.oem"
    write_oem(p, EPOCH0, t, x, P, creation_date=parse_utc("2024-03-02T00:00:00Z"))
    return p.read_text()


def _data_lines(lines):
    return [i for i, ln in enumerate(lines) if ln[:4] == "2024" and len(ln.split()) == 7]


def _edit(text, find, fn):
    """Apply ``fn`` to the first line for which ``find(index, line, lines)`` holds; return the
    new text and that line's 1-based number."""
    lines = text.splitlines()
    i = next(i for i, ln in enumerate(lines) if find(i, ln, lines))
    new = fn(lines[i], lines)
    if new is None:
        del lines[i]
    else:
        lines[i] = new
    return "\n".join(lines) + "\n", i + 1


def _key(k):
    return lambda i, ln, lines: ln.startswith(k)


def _second_data(i, ln, lines):
    return i == _data_lines(lines)[1]


def _first_data(i, ln, lines):
    return i == _data_lines(lines)[0]


def _cov_row2(i, ln, lines):
    return i == lines.index("COV_REF_FRAME = EME2000") + 2


# name -> (edit(text) -> (text, line expected in the error), column, phrase of the expectation)
ERRORS = {
    "first_line_not_version": (lambda s: _edit(s, _key("CCSDS_OEM_VERS"), lambda ln, _: ln.replace(
        "OEM", "OPM")), "CCSDS_OPM_VERS", "first line"),
    "bad_version": (lambda s: _edit(s, _key("CCSDS_OEM_VERS"), lambda ln, _: ln.replace(
        "2.0", "9.9")), "CCSDS_OEM_VERS", "version"),
    "missing_meta_key": (lambda s: (s.replace("CENTER_NAME = EARTH\n", ""),
                                    s.splitlines().index("META_STOP")), "CENTER_NAME",
                         "before META_STOP"),
    "time_system_tai": (lambda s: _edit(s, _key("TIME_SYSTEM"), lambda ln, _: ln.replace(
        "UTC", "TAI")), "TIME_SYSTEM", "UTC"),
    "other_ref_frame": (lambda s: _edit(s, _key("REF_FRAME"), lambda ln, _: ln.replace(
        "EME2000", "ITRF2000")), "REF_FRAME", "EME2000"),
    "unknown_meta_key": (lambda s: _edit(s, _key("OBJECT_ID"), lambda ln, _: ln.replace(
        "OBJECT_ID", "OBJECT_IDENT")), "OBJECT_IDENT", "metadata keyword"),
    "repeated_meta_key": (lambda s: _edit(s, _key("OBJECT_ID"), lambda ln, _: "OBJECT_NAME = X"),
                          "OBJECT_NAME", "once"),
    "bad_number": (lambda s: _edit(s, _first_data, lambda ln, _: " ".join(
        [ln.split()[0], "1.2.3"] + ln.split()[2:])), "X", "decimal number"),
    "nan_value": (lambda s: _edit(s, _first_data, lambda ln, _: " ".join(ln.split()[:6] + ["nan"])),
                  "Z_DOT", "decimal number"),
    "field_count": (lambda s: _edit(s, _second_data, lambda ln, _: ln.rsplit(" ", 1)[0]),
                    None, "7 fields"),
    "epochs_not_increasing": (lambda s: _edit(s, _second_data, lambda ln, lines: " ".join(
        [lines[_data_lines(lines)[0]].split()[0]] + ln.split()[1:])), "epoch", "increasing"),
    "epoch_after_stop_time": (lambda s: (_edit(s, _key("STOP_TIME"), lambda ln, _: ln[:-8] +
                                               "0.000000")[0], _data_lines(s.splitlines())[-1] + 1),
                              "epoch", "STOP_TIME"),
    "cov_ref_frame_twice": (lambda s: _edit(s, _key("COV_REF_FRAME"), lambda ln, _: ln + "\n" +
                                            ln)[0:1] + (s.splitlines().index(
                                                "COV_REF_FRAME = EME2000") + 2,),
                            "COV_REF_FRAME", "once"),
    "header_keyword_twice": (lambda s: _edit(s, _key("ORIGINATOR"), lambda ln, _: ln +
                                             "\nORIGINATOR = B")[0:1] + (s.splitlines().index(
                                                 "ORIGINATOR = FGNAV") + 2,),
                             "ORIGINATOR", "once"),
    "interpolation_degree_not_integer": (lambda s: _edit(s, _key("STOP_TIME"), lambda ln, _: ln +
                                         "\nINTERPOLATION = HERMITE\nINTERPOLATION_DEGREE = 7.1")
                                         [0:1] + (s.splitlines().index("META_STOP") + 2,),
                                         "INTERPOLATION_DEGREE", "integer"),
    "interpolation_without_degree": (lambda s: _edit(s, _key("STOP_TIME"), lambda ln, _: ln +
                                     "\nINTERPOLATION = HERMITE")[0:1] + (
                                         s.splitlines().index("META_STOP") + 1,),
                                     "INTERPOLATION_DEGREE", "with INTERPOLATION"),
    "useable_start_alone": (lambda s: _edit(s, _key("STOP_TIME"), lambda ln, _: ln.replace(
        "STOP_TIME", "USEABLE_START_TIME") + "\n" + ln)[0:1] + (
            s.splitlines().index("META_STOP"),), "USEABLE_START_TIME", "together"),
    "useable_start_after_stop": (lambda s: _edit(s, _key("STOP_TIME"), lambda ln, lines: ln.replace(
        "STOP_TIME", "USEABLE_START_TIME") + "\n" + next(x for x in lines if x.startswith(
            "START_TIME")).replace("START_TIME", "USEABLE_STOP_TIME") + "\n" + ln)[0:1] + (
            s.splitlines().index("META_STOP") + 1,), "USEABLE_STOP_TIME", "not before"),
    "classification_in_2_0": (lambda s: _edit(s, _key("ORIGINATOR"), lambda ln, _: ln +
                              "\nCLASSIFICATION = public")[0:1] + (
                                  s.splitlines().index("ORIGINATOR = FGNAV") + 2,),
                              "CLASSIFICATION", "header keyword"),
    "accelerations_mixed": (lambda s: _edit(s, _second_data, lambda ln, _: ln + " 0.1 0.2 0.3"),
                            None, "mix"),
    "accelerations_in_1_0": (lambda s: _edit(s.replace("CCSDS_OEM_VERS = 2.0", "CCSDS_OEM_VERS"
                                                       " = 1.0").replace("\nCOVARIANCE_START",
                                                                        "\nCOVARIANCE_STAR"),
                                             _first_data, lambda ln, _: ln + " 0.1 0.2 0.3"),
                             "X_DDOT", "OEM 1.0"),
    "covariance_in_1_0": (lambda s: (s.replace("CCSDS_OEM_VERS = 2.0", "CCSDS_OEM_VERS = 1.0"),
                                     s.splitlines().index("COVARIANCE_START") + 1),
                          "COVARIANCE_START", "OEM 1.0"),
    "xml_form": (lambda s: ('<?xml version="1.0" encoding="UTF-8"?>\n<oem id="CCSDS_OEM_VERS" '
                            'version="2.0"/>\n', 1), "CCSDS_OEM_VERS", "XML"),
    "cov_row_too_long": (lambda s: _edit(s, _cov_row2, lambda ln, _: ln + " 1.0"),
                         "covariance row 2", "2 values"),
    "cov_row_missing": (lambda s: _edit(s, _cov_row2, lambda ln, _: None), "covariance row 2",
                        "2 values"),
    "truncated_before_cov_stop": (lambda s: (s[:s.index("COVARIANCE_STOP")],
                                             s[:s.index("COVARIANCE_STOP")].count("\n") + 1),
                                  "COVARIANCE_STOP", "COVARIANCE_STOP"),
    "empty_file": (lambda s: ("", 1), "CCSDS_OEM_VERS", "CCSDS_OEM_VERS"),
}


@pytest.mark.parametrize("case", sorted(ERRORS))
def test_malformed_oem_names_line_and_column(tmp_path, case):
    edit, column, phrase = ERRORS[case]
    good = _good_text(tmp_path)
    text, line = edit(good)
    assert text != good
    p = tmp_path / "bad.oem"
    p.write_text(text)
    with pytest.raises(InputFormatError) as ei:
        read_oem(p)
    e = ei.value
    assert e.line == line, str(e)
    assert e.column == column, str(e)
    assert str(p) in str(e) and f"line {line}" in str(e) and phrase in str(e)
