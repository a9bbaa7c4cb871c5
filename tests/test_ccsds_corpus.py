"""Every OEM, TDM and AEM of the CCSDS interoperability corpus (../shared/data/ccsds, files
other tools and the standards' authors wrote) is either read -- with the values Orekit's
parser tests assert where it has them, its first data line as the text says, and surviving
read -> write -> read to every printed digit -- or refused with file, line and keyword for
a reason listed in docs/ccsds-corpus.md, whose table this test checks row by row."""

from __future__ import annotations

import math
import re
import tempfile
from pathlib import Path

import numpy as np
import pytest

from fgnav.errors import InputFormatError
from fgnav.io.aem import read_aem, write_aem_data
from fgnav.io.kvn import parse_ccsds_epoch, read_kvn_lines
from fgnav.io.oem import read_oem, write_oem_data
from fgnav.io.tdm import read_tdm, write_tdm

import ccsds_corpus as C

pytestmark = pytest.mark.skipif(C.CORPUS is None, reason="the CCSDS corpus (../shared/data/"
                                "ccsds beside the checkout, or /work/shared) is not here")
FILES = C.corpus_files() if C.CORPUS is not None else []
TABLE = C.parse_table(C.TABLE.read_text()) if C.TABLE.exists() else {}


def test_the_table_lists_every_file_once_and_only_those():
    assert set(TABLE) == {rel for rel, _ in FILES}
    assert all(TABLE[rel]["kind"] == kind for rel, kind in FILES)
    assert {r["reason"] for r in TABLE.values() if r["reason"]} <= set(C.REASONS)


def _digits(token: str) -> int:
    """Significant digits printed in a decimal token."""
    mant = re.sub(r"[eE].*$", "", token.lstrip("+-")).replace(".", "").lstrip("0")
    return max(len(mant), 1)


def _same_to_printed_digits(value: float, token: str) -> bool:
    n = _digits(token)
    return f"{value:.{n - 1}e}" == f"{float(token):.{n - 1}e}"


def _first_data_line(path: Path, fields: tuple[int, ...]):
    """The first line of the file, decompressed, whose first token is a CCSDS epoch and that
    has one of ``fields`` tokens (an independent look at the text)."""
    for _, text in read_kvn_lines(path):
        parts = text.split()
        if len(parts) in fields and "=" not in text:
            try:
                parse_ccsds_epoch(parts[0])
            except ValueError:
                continue
            return parts
    raise AssertionError(f"{path}: no data line")


def _check_oem(path, d):
    parts = _first_data_line(path, (7, 10))
    assert d.epoch0 == parse_ccsds_epoch(parts[0])
    for v, tok in zip(d.x_eci[0] / 1000.0, parts[1:7]):
        assert _same_to_printed_digits(float(v), tok), (v, tok)
    with tempfile.TemporaryDirectory() as tmp:
        q = Path(tmp) / "again.oem"
        write_oem_data(q, d)
        e = read_oem(q)
    assert e.epoch0 == d.epoch0 and e.meta["CCSDS_OEM_VERS"] == d.meta["CCSDS_OEM_VERS"]
    np.testing.assert_array_equal(e.t_s, d.t_s)
    np.testing.assert_array_equal(e.x_eci, d.x_eci)        # exact: the same doubles
    assert (e.a_eci is None) == (d.a_eci is None)
    if d.a_eci is not None:
        np.testing.assert_array_equal(e.a_eci, d.a_eci)
    assert (e.cov_P is None) == (d.cov_P is None)
    if d.cov_P is not None:
        np.testing.assert_array_equal(e.cov_t_s, d.cov_t_s)
        np.testing.assert_array_equal(e.cov_P, d.cov_P)
        assert e.cov_frame == d.cov_frame
    for k in ("OBJECT_NAME", "OBJECT_ID", "CENTER_NAME", "REF_FRAME", "CLASSIFICATION",
              "MESSAGE_ID", "ORIGINATOR"):
        assert e.meta.get(k) == d.meta.get(k), k
    assert len(e.meta["segments"]) == len(d.meta["segments"])


def _check_aem(path, a):
    parts = _first_data_line(path, (5, 8, 9))
    assert a.epoch0 == parse_ccsds_epoch(parts[0])
    with tempfile.TemporaryDirectory() as tmp:
        q = Path(tmp) / "again.aem"
        write_aem_data(q, a)
        b = read_aem(q)
    assert b.epoch0 == a.epoch0 and len(b.meta["segments"]) == len(a.meta["segments"])
    np.testing.assert_array_equal(b.t_s, a.t_s)
    # written with 17 digits and read back normalized: the same rotation to 2 ulp
    np.testing.assert_allclose(b.q_wxyz, a.q_wxyz, rtol=0, atol=2.3e-16)


def _check_tdm(path, log):
    with tempfile.TemporaryDirectory() as tmp:
        q = Path(tmp) / "again.tdm"
        write_tdm(q, log.epoch0, log.t_s, log.xyz, log.sigma)
        back = read_tdm(q)
    np.testing.assert_array_equal(back.t_s, log.t_s)
    np.testing.assert_allclose(back.xyz, log.xyz, rtol=0, atol=1e-15)


CHECK = {"OEM": _check_oem, "AEM": _check_aem, "TDM": _check_tdm}


@pytest.mark.parametrize("rel, kind", FILES, ids=[rel for rel, _ in FILES])
def test_each_file_is_read_or_refused_as_the_table_says(rel, kind):
    row = TABLE.get(rel)
    assert row is not None, f"{rel} is not in {C.TABLE.name}"
    what, res = C.outcome(rel, kind)
    if what == "refused":
        e = res
        assert row["outcome"] == "refused", f"{rel}: refused ({e}), the table says read"
        assert str(C.CORPUS / rel) in str(e) and f"line {e.line}" in str(e)
        assert (e.line, e.column, C.reason(e)) == (row["line"], row["keyword"], row["reason"]), \
            str(e)
        return
    assert row["outcome"] == "read", f"{rel}: read, the table says refused"
    CHECK[kind](C.CORPUS / rel, res)


# --- what Orekit's own parser tests assert about the files fgnav reads -------------------
# (CS-SI/Orekit fe4aee84, src/test/java/org/orekit/files/ccsds/ndm/: AEMParserTest
# testParseAEM1 / testParseAEM4, OemParserTest testEmptyComments / testLowerCaseValue)

def _same_rotation(q_wxyz, orekit_q0123, tol=1e-5):
    """Orekit's Rotation(q0, q1, q2, q3) from EME2000 to the body is fgnav's (w, x, y, z) of
    R_eci_from_body (docs/ccsds.md, conventions), up to the sign of q."""
    want = np.asarray(orekit_q0123, float)
    want /= np.linalg.norm(want)
    return min(np.abs(q_wxyz - want).max(), np.abs(q_wxyz + want).max()) < tol


def _t(a, text):
    return float((parse_ccsds_epoch(text) - a.epoch0) / np.timedelta64(1, "ns")) * 1e-9


def test_orekit_aem_example_1():
    a = read_aem(C.CORPUS / "orekit/adm/aem/AEMExample01.txt")
    assert a.meta["CCSDS_AEM_VERS"] == "1.0" and a.meta["ORIGINATOR"] == "NASA/JPL"
    assert parse_ccsds_epoch(a.meta["CREATION_DATE"]) == parse_ccsds_epoch("2002-11-04T17:22:31")
    s0, s1 = a.meta["segments"]
    assert (s0["OBJECT_NAME"], s0["OBJECT_ID"], s0["CENTER_NAME"]) == (
        "MARS GLOBAL SURVEYOR", "1996-062A", "MARS BARYCENTER")
    assert s0["START_TIME_ns"] == parse_ccsds_epoch("1996-11-28T21:29:07.2555").astype(int)
    assert s0["STOP_TIME_ns"] == parse_ccsds_epoch("1996-11-30T01:28:02.5555").astype(int)
    assert s0["USEABLE_START_TIME_ns"] == parse_ccsds_epoch("1996-11-28T22:08:02.5555").astype(int)
    assert s0["INTERPOLATION_METHOD"] == "HERMITE" and s0["INTERPOLATION_DEGREE"] == "7"
    assert s0["REF_FRAME_A"] == "EME2000" and a.meta["body_frame"] == "SC_BODY_1"
    assert s1["START_TIME_ns"] == parse_ccsds_epoch("1996-12-18T12:05:00.5555").astype(int)
    expect = [("1996-11-28T21:29:07.2555", (0.68427, 0.56748, 0.03146, 0.45689)),
              ("1996-11-28T22:08:03.5555", (0.74533, 0.42319, -0.45697, 0.23784)),
              ("1996-11-28T22:08:04.5555", (0.45652, -0.84532, 0.26974, -0.06532))]
    for i, (ep, q) in enumerate(expect):
        assert a.t_s[i] == pytest.approx(_t(a, ep), abs=1e-9) and _same_rotation(a.q_wxyz[i], q)
    i1 = s1["rows"][0]
    expect = [("1996-12-18T12:05:00.5555", (0.72501, -0.64585, 0.018542, -0.23854)),
              ("1996-12-18T12:10:05.5555", (-0.16767, 0.87451, -0.43475, 0.13458)),
              ("1996-12-18T12:10:10.5555", (-0.71418, 0.03125, -0.65874, 0.23458))]
    for i, (ep, q) in enumerate(expect):
        assert a.t_s[i1 + i] == pytest.approx(_t(a, ep), abs=1e-9)
        assert _same_rotation(a.q_wxyz[i1 + i], q)
    assert s1["comments"] == ["This block begins after trajectory correction maneuver TCM-3."]


def test_orekit_aem_example_4():
    a = read_aem(C.CORPUS / "orekit/adm/aem/AEMExample04.txt")
    assert a.meta["ORIGINATOR"] == "CS GROUP" and a.meta["OBJECT_NAME"] == "COPIHUE"
    assert a.meta["OBJECT_ID"] == "2100-017F" and a.meta["ATTITUDE_TYPE"] == "QUATERNION/DERIVATIVE"
    assert a.meta["INTERPOLATION_DEGREE"] == "3" and len(a.t_s) == 13
    for k, ep in (("START_TIME", "2021-12-31T00:00:00.000"), ("STOP_TIME", "2021-12-31T00:00:06"),
                  ("USEABLE_START_TIME", "2021-12-31T00:00:00.500"),
                  ("USEABLE_STOP_TIME", "2021-12-31T00:00:05.500")):
        assert a.meta["segments"][0][k + "_ns"] == parse_ccsds_epoch(ep).astype(int), k


def test_orekit_iss_oem_and_lower_case_centre():
    iss = read_oem(C.CORPUS / "orekit/odm/oem/ISS.resampled.truncated.txt")
    assert iss.meta["OBJECT_ID"] == "1998-067-A" and len(iss.t_s) == 25
    assert np.all(np.diff(iss.t_s) == 3600.0)
    low = read_oem(C.CORPUS / "orekit/odm/oem/oemLowerCaseValue.oem")
    assert low.meta["CENTER_NAME"].upper() == "EARTH"


def test_the_ground_telescope_tdms_are_refused_naming_the_participants():
    for name in ("tdm_e16.kvn", "tdm_e22.kvn"):
        with pytest.raises(InputFormatError) as ei:
            read_tdm(C.CORPUS / "annex-examples/kvn" / name, sigma_rad=1e-4)
        assert ei.value.column == "PATH" and "PARTICIPANT_2" in str(ei.value), str(ei.value)
        assert "seen from PARTICIPANT_1" in str(ei.value)
        assert math.isfinite(ei.value.line)
