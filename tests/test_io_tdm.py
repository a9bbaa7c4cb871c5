"""CCSDS TDM (503.0-B-2) KVN RA/Dec angles -> earth_direction rows (fgnav.io.tdm)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgnav.errors import InputFormatError, UserError
from fgnav.io.log_csv import read_log
from fgnav.io.tdm import read_tdm

# Hand-written after the layout of CCSDS 503.0-B-2 (KVN, section 3 and annex examples):
# header, a metadata block, a data block with ANGLE_1/ANGLE_2 records (RA/Dec, deg).
TDM = """\
CCSDS_TDM_VERS = 2.0
COMMENT fgnav test file: RA/Dec of the Earth centre seen from the spacecraft
CREATION_DATE = 2024-061T12:00:00
ORIGINATOR = FGNAV-TEST

META_START
COMMENT sigma_deg=0.01
TIME_SYSTEM = UTC
PARTICIPANT_1 = FGNAV-SAT
PARTICIPANT_2 = EARTH
MODE = SEQUENTIAL
PATH = 2,1
ANGLE_TYPE = RADEC
REFERENCE_FRAME = EME2000
INTEGRATION_INTERVAL = 1.0
INTEGRATION_REF = MIDDLE
META_STOP

DATA_START
ANGLE_1 = 2024-03-01T00:00:00 123.456
ANGLE_2 = 2024-03-01T00:00:00 -12.5
ANGLE_1 = 2024-03-01T00:00:10.5 359.9
ANGLE_2 = 2024-03-01T00:00:10.5 89.0
ANGLE_2 = 2024-061T00:00:20 0.0
ANGLE_1 = 2024-061T00:00:20 -45.0
RANGE = 2024-03-01T00:00:20 1234.5
DATA_STOP
"""

RADEC_DEG = [(123.456, -12.5), (359.9, 89.0), (-45.0, 0.0)]
T_S = [0.0, 10.5, 20.0]


def _u_from_radec(ra_deg, dec_deg):
    """Independent construction: rotate the x axis by Ry(-dec) then Rz(ra)."""
    a, d = math.radians(ra_deg), math.radians(dec_deg)
    Rz = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    Ry = np.array([[math.cos(-d), 0, math.sin(-d)], [0, 1, 0], [-math.sin(-d), 0, math.cos(-d)]])
    return Rz @ Ry @ np.array([1.0, 0.0, 0.0])


def test_tdm_reads_like_the_equivalent_csv_log(tmp_path):
    p = tmp_path / "pass.tdm"
    p.write_text(TDM)
    tdm = read_tdm(p)
    rows = []
    for t, (ra, dec) in zip(T_S, RADEC_DEG):
        u = _u_from_radec(ra, dec)
        rows.append(f"2024-03-01T00:00:{t:09.6f}Z,earth_direction,{float(u[0])!r},{float(u[1])!r},"
                    f"{float(u[2])!r},"
                    f"{math.radians(0.01)!r}")
    c = tmp_path / "pass.csv"
    c.write_text("epoch,kind,x,y,z,sigma\n" + "\n".join(rows) + "\n")
    csv = read_log(c)
    assert tdm.epoch0 == csv.epoch0
    np.testing.assert_array_equal(tdm.t_s, csv.t_s)
    np.testing.assert_array_equal(tdm.kind, csv.kind)
    np.testing.assert_allclose(tdm.xyz, csv.xyz, rtol=0, atol=1e-15)
    np.testing.assert_allclose(tdm.sigma, csv.sigma, rtol=1e-15)
    np.testing.assert_array_equal(tdm.line, [20, 22, 24])
    assert any("RANGE: 1" in w for w in tdm.warnings)


def test_sigma_precedence(tmp_path):
    p = tmp_path / "a.tdm"
    # header comment, no segment comment
    p.write_text(TDM.replace("COMMENT sigma_deg=0.01\n", "").replace(
        "COMMENT fgnav test file", "COMMENT sigma_deg=0.5 fgnav test file"))
    assert read_tdm(p).sigma[0] == pytest.approx(math.radians(0.5), rel=1e-15)
    p.write_text(TDM)  # segment comment overrides nothing here, option overrides it
    assert read_tdm(p, sigma_rad=2e-4).sigma[0] == 2e-4
    p.write_text(TDM.replace("COMMENT sigma_deg=0.01\n", ""))
    with pytest.raises(InputFormatError, match="sigma_deg"):
        read_tdm(p)
    with pytest.raises(UserError, match="sigma_rad"):
        read_tdm(p, sigma_rad=-1.0)


def _line(text, needle):
    return next(i + 1 for i, ln in enumerate(text.splitlines()) if needle in ln)


TDM_ERRORS = {
    "angle_type_azel": (lambda s: s.replace("ANGLE_TYPE = RADEC", "ANGLE_TYPE = AZEL"),
                        "ANGLE_TYPE", "ANGLE_TYPE", "RADEC"),
    "reference_frame_itrf": (lambda s: s.replace("REFERENCE_FRAME = EME2000",
                                                 "REFERENCE_FRAME = ITRF2000"),
                             "REFERENCE_FRAME", "REFERENCE_FRAME", "EME2000"),
    "missing_time_system": (lambda s: s.replace("TIME_SYSTEM = UTC\n", ""), "META_STOP",
                            "TIME_SYSTEM", "TIME_SYSTEM"),
    "time_system_gps": (lambda s: s.replace("TIME_SYSTEM = UTC", "TIME_SYSTEM = GPS"),
                        "TIME_SYSTEM", "TIME_SYSTEM", "UTC"),
    "missing_participant": (lambda s: s.replace("PARTICIPANT_1 = FGNAV-SAT\n", ""), "META_STOP",
                            "PARTICIPANT_1", "PARTICIPANT_1"),
    "missing_angle_type": (lambda s: s.replace("ANGLE_TYPE = RADEC\n", ""),
                           "ANGLE_1 = 2024-03-01T00:00:00 ", "ANGLE_TYPE", "RADEC"),
    "unpaired_angle_1": (lambda s: s.replace("ANGLE_2 = 2024-03-01T00:00:10.5 89.0\n", ""),
                         "ANGLE_1 = 2024-03-01T00:00:10.5", "ANGLE_2", "same epoch"),
    "repeated_angle": (lambda s: s.replace("ANGLE_2 = 2024-061T00:00:20 0.0",
                                           "ANGLE_2 = 2024-03-01T00:00:10.5 1.0"),
                       "ANGLE_2 = 2024-03-01T00:00:10.5 1.0", "ANGLE_2", "one ANGLE_2"),
    "declination_out_of_range": (lambda s: s.replace("89.0", "91.0"), "91.0", "ANGLE_2",
                                 "[-90, 90]"),
    "bad_number": (lambda s: s.replace("123.456", "123,456"), "123,456", "ANGLE_1",
                   "decimal number"),
    "bad_epoch": (lambda s: s.replace("2024-03-01T00:00:10.5 359.9", "2024-03-01T25:00:10.5 "
                                      "359.9"), "T25:", "ANGLE_1", "CCSDS epoch"),
    "bad_data_line": (lambda s: s.replace("RANGE = 2024-03-01T00:00:20 1234.5", "RANGE 1234.5"),
                      "RANGE 1234.5", None, "KEYWORD = epoch value"),
    "missing_data_stop": (lambda s: s.replace("DATA_STOP\n", ""), None, "DATA_STOP",
                          "incomplete"),
    "not_a_tdm": (lambda s: s.replace("CCSDS_TDM_VERS = 2.0", "CCSDS_OEM_VERS = 2.0"),
                  "CCSDS_OEM_VERS", "CCSDS_TDM_VERS", "CCSDS_TDM_VERS"),
    "path_spacecraft_seen_from_earth": (lambda s: s.replace("PATH = 2,1", "PATH = 1,2"),
                                        "PATH = 1,2", "PATH",
                                        "PARTICIPANT_1 = FGNAV-SAT seen from "
                                        "PARTICIPANT_2 = EARTH"),
    "ground_telescope": (lambda s: s.replace("PARTICIPANT_2 = EARTH", "PARTICIPANT_2 = TFRM"),
                         "PATH = 2,1", "PATH", "PARTICIPANT_2 = TFRM seen from"),
    "no_path": (lambda s: s.replace("PATH = 2,1\n", ""), "META_START", "PATH", "no PATH"),
    "path_unknown_participant": (lambda s: s.replace("PATH = 2,1", "PATH = 3,1"), "PATH = 3,1",
                                 "PATH", "defined in the segment"),
    "single_diff_mode": (lambda s: s.replace("MODE = SEQUENTIAL", "MODE = SINGLE_DIFF"),
                         "MODE = SINGLE_DIFF", "MODE", "SEQUENTIAL"),
    "unknown_meta_keyword": (lambda s: s.replace("PATH = 2,1", "PATHS = 2,1"), "PATHS", "PATHS",
                             "table 3-3"),
    "correction_without_applied": (lambda s: s.replace("META_STOP", "CORRECTION_ANGLE_1 = 1.0\n"
                                                       "META_STOP"), "META_STOP",
                                   "CORRECTIONS_APPLIED", "3.4.15.3"),
    "corrections_applied_maybe": (lambda s: s.replace("META_STOP", "CORRECTIONS_APPLIED = MAYBE\n"
                                                      "META_STOP"), "MAYBE",
                                  "CORRECTIONS_APPLIED", "YES or NO"),
    "aberration_not_applied": (lambda s: s.replace("META_STOP", "CORRECTION_ABERRATION_YEARLY = "
                                                   "0.0057\nCORRECTIONS_APPLIED = NO\nMETA_STOP"),
                               "CORRECTION_ABERRATION_YEARLY", "CORRECTION_ABERRATION_YEARLY",
                               "aberration"),
    "xml_form": (lambda s: '<?xml version="1.0"?>\n<tdm id="CCSDS_TDM_VERS" version="2.0"/>\n',
                 "<?xml", "CCSDS_TDM_VERS", "XML"),
    "no_angles": (lambda s: "\n".join(ln for ln in s.splitlines() if not ln.startswith("ANGLE"))
                  + "\n", "DATA_STOP", "ANGLE_1", "no measurements"),
}


@pytest.mark.parametrize("case", sorted(TDM_ERRORS))
def test_malformed_tdm_names_line_and_column(tmp_path, case):
    edit, needle, column, phrase = TDM_ERRORS[case]
    text = edit(TDM)
    assert text != TDM
    p = tmp_path / "bad.tdm"
    p.write_text(text)
    with pytest.raises(InputFormatError) as ei:
        read_tdm(p)
    e = ei.value
    line = len(text.splitlines()) + 1 if needle is None else _line(text, needle)
    assert e.line == line, str(e)
    assert e.column == column, str(e)
    assert str(p) in str(e) and f"line {line}" in str(e) and phrase in str(e)


def test_two_segments_and_out_of_order_rows(tmp_path):
    seg2 = TDM[TDM.index("META_START"):].replace("sigma_deg=0.01", "sigma_deg=0.02").replace(
        "2024-03-01T00:00:", "2024-02-29T23:59:").replace("2024-061T00:00:", "2024-060T23:59:")
    p = tmp_path / "two.tdm"
    p.write_text(TDM + "\n" + seg2)
    log = read_tdm(p)
    assert len(log) == 6
    np.testing.assert_array_equal(log.t_s, [0, 10.5, 20, 60, 70.5, 80])
    np.testing.assert_allclose(log.sigma, np.radians([0.02] * 3 + [0.01] * 3), rtol=1e-15)
    assert any("out of time order" in w for w in log.warnings)


@pytest.mark.parametrize("sigma_deg", ["1e-300", "1e-12", "90"])
def test_a_sigma_outside_the_direction_range_is_refused(tmp_path, sigma_deg):
    p = tmp_path / "t.tdm"
    p.write_text(TDM.replace("sigma_deg=0.01", f"sigma_deg={sigma_deg}"))
    line = TDM.splitlines().index("COMMENT sigma_deg=0.01") + 1
    with pytest.raises(InputFormatError, match=rf"line {line}, column 'sigma_deg'.*within"):
        read_tdm(p)


@pytest.mark.parametrize("applied", ["NO", "YES"])
def test_angle_corrections_not_applied_are_added(tmp_path, applied):
    """503.0-B-2 table 3-3 (item 37) and 3.4.15: CORRECTION_ANGLE_n is the value "to be added
    to each data point"; with CORRECTIONS_APPLIED = NO fgnav adds it, with YES the data
    already has it."""
    p = tmp_path / "c.tdm"
    p.write_text(TDM.replace("META_STOP", "CORRECTION_ANGLE_1 = 1.0\nCORRECTION_ANGLE_2 = "
                             f"-0.5\nCORRECTIONS_APPLIED = {applied}\nMETA_STOP"))
    log = read_tdm(p)
    shift = (1.0, -0.5) if applied == "NO" else (0.0, 0.0)
    want = np.array([_u_from_radec(ra + shift[0], dec + shift[1]) for ra, dec in RADEC_DEG])
    np.testing.assert_allclose(log.xyz, want, rtol=0, atol=1e-15)
    plain = read_tdm(_write(tmp_path / "p.tdm", TDM))
    assert (np.abs(log.xyz - plain.xyz).max() > 1e-3) == (applied == "NO")


def _write(p, text):
    p.write_text(text)
    return p
