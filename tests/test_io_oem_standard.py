"""OEM content the standard allows beyond what fgnav writes (CCSDS 502.0-B-3): covariance
blocks at epochs without an ephemeris line and in other frames, kept and written back; the
OEM 3.0 header; REF_FRAME = J2000 read as EME2000, also as ``fgnav smooth --truth``."""

import json

import numpy as np
import pytest

from fgnav.cli import main
from fgnav.errors import InputFormatError
from fgnav.io.oem import read_oem, write_oem, write_oem_data
from fgnav.orbit import integrate_truth
from fgnav.time import parse_utc

from test_cli_smooth import hand_written_log

ROW = ["3.3313494e-04", "4.6189273e-04 6.7824216e-04",
       "-3.0700078e-04 -4.2212341e-04 3.2319319e-04",
       "-3.3493650e-07 -4.6860842e-07 2.4849495e-07 4.2960228e-10",
       "-2.2118325e-07 -2.8641868e-07 1.7980986e-07 2.6088992e-10 1.7675147e-10",
       "-3.0413460e-07 -4.9894969e-07 3.5403109e-07 1.8692631e-10 1.0088625e-10 6.2244443e-10"]

TEXT = """\
CCSDS_OEM_VERS = 3.0
CLASSIFICATION = public, test-data
CREATION_DATE = 1996-11-04T17:22:31
ORIGINATOR = NASA/JPL
MESSAGE_ID = OEM 201113719185

META_START
OBJECT_NAME = MARS GLOBAL SURVEYOR
OBJECT_ID = 1996-062A
CENTER_NAME = EARTH
REF_FRAME = J2000
TIME_SYSTEM = UTC
START_TIME = 1996-12-28T21:29:07.267
STOP_TIME = 1996-12-28T22:00:02.267
META_STOP
1996-12-28T21:29:07.267 -2432.166 -063.042 1742.754 7.33702 -3.495867 -1.041945
1996-12-28T22:00:02.267 -2458.079 -683.858 2007.684 6.36786 -3.339563 -0.946654

COVARIANCE_START
EPOCH = 1996-12-28T21:29:07.267
{rows}
EPOCH = 1996-12-28T21:40:00
COV_REF_FRAME = EME2000
{rows}
EPOCH = 1996-12-28T22:00:02.267
COV_REF_FRAME = RTN
{rows}
COVARIANCE_STOP
""".replace("{rows}", "\n".join(ROW))


def test_covariances_at_any_epoch_and_frame_are_kept_and_written_back(tmp_path):
    p = tmp_path / "a.oem"
    p.write_text(TEXT)
    d = read_oem(p)
    assert d.meta["CCSDS_OEM_VERS"] == "3.0" and d.meta["CLASSIFICATION"] == "public, test-data"
    assert d.meta["MESSAGE_ID"] == "OEM 201113719185" and d.meta["REF_FRAME"] == "J2000"
    # three blocks kept in file order: at the first line, between lines, at the last (RTN)
    np.testing.assert_array_equal(d.cov_t_s, [0.0, 652.733, 1855.0])
    assert d.cov_frame == [None, "EME2000", "RTN"]
    assert d.cov_P[1, 0, 0] == pytest.approx(333.13494, rel=1e-15)  # km**2 -> m**2
    assert d.cov_P[1, 5, 0] == d.cov_P[1, 0, 5] == pytest.approx(-0.3041346, rel=1e-15)
    # P_eci holds the inertial block at an ephemeris epoch; the RTN one is not put there
    assert d.P_eci[0, 0, 0] == pytest.approx(333.13494) and np.isnan(d.P_eci[1]).all()
    assert d.meta["covariance_unmatched"] == 1 and d.meta["covariance_other_frame"] == 1
    q = tmp_path / "b.oem"
    write_oem_data(q, d)
    text = q.read_text()
    assert text.startswith("CCSDS_OEM_VERS = 3.0\nCLASSIFICATION = public, test-data\n")
    assert "REF_FRAME = J2000" in text and "COV_REF_FRAME = RTN" in text
    e = read_oem(q)
    for a, b in ((d.t_s, e.t_s), (d.x_eci, e.x_eci), (d.cov_t_s, e.cov_t_s), (d.cov_P, e.cov_P)):
        np.testing.assert_array_equal(a, b)
    assert e.cov_frame == d.cov_frame and e.meta["MESSAGE_ID"] == d.meta["MESSAGE_ID"]


def test_other_centres_are_read_and_kept(tmp_path):
    """A Mars-centred OEM (the standard's own examples) is read with its CENTER_NAME; the
    consumers that need an Earth- or Sun-centred file (--truth) check the centre."""
    p = tmp_path / "m.oem"
    p.write_text(TEXT.replace("CENTER_NAME = EARTH", "CENTER_NAME = MARS BARYCENTER"))
    assert read_oem(p).meta["CENTER_NAME"] == "MARS BARYCENTER"
    two = TEXT.split("\nCOVARIANCE_START")[0] + "\n" + TEXT[TEXT.index("META_START"):].split(
        "\nCOVARIANCE_START")[0].replace("EARTH", "SUN").replace(
        "1996-12-28T2", "1996-12-29T2") + "\n"
    p.write_text(two)
    with pytest.raises(InputFormatError, match="CENTER_NAME.*same CENTER_NAME in every segment"):
        read_oem(p)


def test_overlapping_useable_spans_are_refused(tmp_path):
    """ODM 502.0-B-3 5.2.4.4: consecutive segments' useable spans do not overlap."""
    seg = TEXT[TEXT.index("META_START"):].split("\nCOVARIANCE_START")[0] + "\n"
    p = tmp_path / "o.oem"
    text = TEXT.split("\nCOVARIANCE_START")[0] + "\n" + seg
    p.write_text(text)
    with pytest.raises(InputFormatError) as ei:
        read_oem(p)
    assert ei.value.column == "START_TIME" and "5.2.4.4" in str(ei.value)
    lines = [i + 1 for i, ln in enumerate(text.splitlines()) if ln.startswith("START_TIME")]
    assert ei.value.line == lines[1]


@pytest.mark.parametrize("edit", ["oem3_classification", "j2000"])
def test_oem_3_and_j2000_are_accepted_as_truth(tmp_path, edit):
    """`fgnav smooth --truth` with an OEM 3.0 carrying CLASSIFICATION and MESSAGE_ID, and with
    REF_FRAME = J2000: the same errors as with fgnav's own OEM 2.0 truth."""
    t_dir = np.arange(0, 1800, 30.0)
    log, truth = hand_written_log(tmp_path, t_dir)
    text = truth.read_text()
    if edit == "j2000":
        new = text.replace("REF_FRAME = EME2000", "REF_FRAME = J2000")
    else:
        new = text.replace("CCSDS_OEM_VERS = 2.0\n", "CCSDS_OEM_VERS = 3.0\nCLASSIFICATION = "
                           "public, test-data\n").replace("ORIGINATOR = FGNAV\n", "ORIGINATOR = "
                                                          "FGNAV\nMESSAGE_ID = T-1\n")
    assert new != text
    other = tmp_path / "truth2.oem"
    other.write_text(new)
    errors = []
    for i, path in enumerate((truth, other)):
        out = tmp_path / f"r{i}"
        assert main(["smooth", str(log), "--out", str(out), "--truth", str(path), "--quiet"]) == 0
        s = json.loads((out / "summary.json").read_text())
        errors.append((s["position_rms_m"], s["final_position_error_m"]))
    assert errors[0] == errors[1] and np.isfinite(errors[0][0])


def test_a_truth_about_another_centre_is_refused(tmp_path, capsys):
    log, truth = hand_written_log(tmp_path, np.arange(0, 600, 60.0))
    mars = tmp_path / "mars.oem"
    mars.write_text(truth.read_text().replace("CENTER_NAME = EARTH", "CENTER_NAME = MARS"))
    assert main(["smooth", str(log), "--out", str(tmp_path / "r"), "--truth", str(mars),
                 "--quiet"]) == 2
    assert "CENTER_NAME = MARS" in capsys.readouterr().err
