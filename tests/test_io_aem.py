"""CCSDS AEM (fgnav.io.aem) and attitude_covariance.csv (fgnav.io.attitude_covariance): round
trips, the standard's quaternion convention against an independent construction, hand-written
files of both versions, and errors that name the file, line and keyword."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest

from factors.geometry import so3_exp, so3_log
from fgnav.errors import InputFormatError, UserError
from fgnav.io.aem import read_aem, write_aem, write_aem_data
from fgnav.io.attitude_covariance import read_attitude_covariance, write_attitude_covariance
from fgnav.time import add_seconds, parse_utc

EPOCH0 = parse_utc("2024-03-01T00:00:00Z")


def _m_ba(q1, q2, q3, qc):
    """The frame transformation matrix M_BA of CCSDS 504.0-B-2 annex F2.1 (X_B = M_BA X_A),
    typed in from the standard, independent of fgnav's conversions."""
    return np.array([
        [q1**2 - q2**2 - q3**2 + qc**2, 2 * (q1 * q2 + q3 * qc), 2 * (q1 * q3 - q2 * qc)],
        [2 * (q1 * q2 - q3 * qc), -q1**2 + q2**2 - q3**2 + qc**2, 2 * (q2 * q3 + q1 * qc)],
        [2 * (q1 * q3 + q2 * qc), 2 * (q2 * q3 - q1 * qc), -q1**2 - q2**2 + q3**2 + qc**2]])


def _data_lines(path):
    text = path.read_text().splitlines()
    i, j = text.index("DATA_START"), text.index("DATA_STOP")
    return [ln.split() for ln in text[i + 1:j]]


def _random_rotations(n, seed=5):
    rng = np.random.default_rng(seed)
    w = rng.normal(size=(n, 3))
    w *= (rng.uniform(0.0, math.pi, n) / np.linalg.norm(w, axis=1))[:, None]
    return so3_exp(w)


def test_round_trip_rotations_to_1e11_rad_and_exact_epochs(tmp_path):
    R = _random_rotations(40)
    t = np.arange(40) * 10.0 + 0.123456
    p = tmp_path / "a.aem"
    write_aem(p, EPOCH0, t, R, object_name="SAT-1", object_id="2024-001A")
    d = read_aem(p)
    ns_in = (add_seconds(EPOCH0, t) - EPOCH0).astype(np.int64)
    np.testing.assert_array_equal((add_seconds(d.epoch0, d.t_s) - EPOCH0).astype(np.int64), ns_in)
    err = so3_log(np.swapaxes(R, 1, 2) @ d.R_eci_from_body())
    assert np.abs(err).max() < 1e-11
    assert d.meta["OBJECT_NAME"] == "SAT-1" and d.meta["body_frame"] == "SC_BODY_1"
    assert d.meta["CCSDS_AEM_VERS"] == "2.0" and d.meta["ATTITUDE_TYPE"] == "QUATERNION"


def test_rotation_about_z_by_90_deg_gives_the_standards_example(tmp_path):
    # Body = EME2000 turned by +90 deg about Z: body X along EME2000 Y (CCSDS 504.0-B-2 F2.2).
    R_eci_from_body = gtsam.Rot3.Rz(math.pi / 2).matrix()
    np.testing.assert_allclose(R_eci_from_body[:, 0], [0.0, 1.0, 0.0], atol=1e-15)
    p = tmp_path / "z90.aem"
    write_aem(p, EPOCH0, [0.0], R_eci_from_body[None])
    (line,) = _data_lines(p)
    q1, q2, q3, qc = (float(v) for v in line[1:])
    s = math.sqrt(0.5)
    assert (q1, q2) == (0.0, 0.0)
    assert q3 == pytest.approx(s, abs=1e-12) and qc == pytest.approx(s, abs=1e-12)  # QC last
    # The standard's matrix: X_A = [1, 0, 0] has coordinates [0, -1, 0] in frame B.
    M = _m_ba(q1, q2, q3, qc)
    np.testing.assert_allclose(M, [[0, 1, 0], [-1, 0, 0], [0, 0, 1]], atol=1e-12)
    np.testing.assert_allclose(M @ [1.0, 0.0, 0.0], [0.0, -1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(read_aem(p).q_wxyz[0], [s, 0.0, 0.0, s], atol=1e-12)


def test_written_quaternions_follow_annex_f_for_any_rotation(tmp_path):
    R = _random_rotations(25, seed=11)
    p = tmp_path / "r.aem"
    write_aem(p, EPOCH0, np.arange(25.0), R)
    for Rk, line in zip(R, _data_lines(p)):
        q = [float(v) for v in line[1:]]
        assert abs(np.linalg.norm(q) - 1.0) < 1e-11
        # M_BA transforms EME2000 coordinates into body coordinates: R_eci_from_body^T
        np.testing.assert_allclose(_m_ba(*q), Rk.T, atol=1e-11)


def test_sign_first_record_qc_nonnegative_then_continuous(tmp_path):
    # a full turn about a tilted axis: QC changes sign half way, the records must not flip
    axis = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    ang = np.linspace(0.1, 2 * math.pi - 0.1, 73)
    R = so3_exp(ang[:, None] * axis)
    p = tmp_path / "turn.aem"
    write_aem(p, EPOCH0, ang * 100.0, R)
    Q = np.array([[float(v) for v in ln[1:]] for ln in _data_lines(p)])
    assert Q[0, 3] >= 0.0
    assert np.all(np.sum(Q[1:] * Q[:-1], axis=1) > 0.0)
    assert Q[-1, 3] < 0.0                                   # past the half turn, continuous
    d = read_aem(p)
    assert np.abs(so3_log(np.swapaxes(R, 1, 2) @ d.R_eci_from_body())).max() < 1e-11


def test_written_layout(tmp_path):
    p = tmp_path / "a.aem"
    write_aem(p, EPOCH0, [0.0, 1.5], so3_exp(np.zeros((2, 3))), comments=["fgnav test"],
              creation_date=parse_utc("2024-03-02T12:00:00Z"))
    lines = [ln for ln in p.read_text().splitlines() if ln.strip()]
    assert lines == [
        "CCSDS_AEM_VERS = 2.0", "COMMENT fgnav test", "CREATION_DATE = 2024-03-02T12:00:00.000000",
        "ORIGINATOR = FGNAV", "META_START", "OBJECT_NAME = FGNAV", "OBJECT_ID = UNKNOWN",
        "CENTER_NAME = EARTH", "REF_FRAME_A = EME2000", "REF_FRAME_B = SC_BODY_1",
        "TIME_SYSTEM = UTC", "START_TIME = 2024-03-01T00:00:00.000000",
        "STOP_TIME = 2024-03-01T00:00:01.500000", "ATTITUDE_TYPE = QUATERNION", "META_STOP",
        "DATA_START",
        "2024-03-01T00:00:00.000000 0.000000000000 0.000000000000 0.000000000000 1.000000000000",
        "2024-03-01T00:00:01.500000 0.000000000000 0.000000000000 0.000000000000 1.000000000000",
        "DATA_STOP"]


def test_writer_refuses_bad_arguments(tmp_path):
    R = so3_exp(np.zeros((2, 3)))
    with pytest.raises(UserError, match="strictly increasing"):
        write_aem(tmp_path / "a.aem", EPOCH0, [1.0, 1.0], R)
    with pytest.raises(UserError, match="proper rotations"):
        write_aem(tmp_path / "a.aem", EPOCH0, [0.0, 1.0], -R)
    with pytest.raises(UserError, match="ref_frame_b"):
        write_aem(tmp_path / "a.aem", EPOCH0, [0.0, 1.0], R, ref_frame_b="ICRF")
    assert not (tmp_path / "a.aem").exists()


# The standard's AEM example (CCSDS 504.0-B-2 figure G-4), its records completed: two segments,
# quaternions scalar last. Its quaternions are given to 5 digits (unit norm within 1e-4).
HAND_WRITTEN_V2 = """\
CCSDS_AEM_VERS = 2.0
CREATION_DATE = 2002-11-04T17:22:31
ORIGINATOR    = NASA/JPL
MESSAGE_ID    = A701523

META_START
COMMENT This file was produced by M.R. Somebody, MSOO NAV/JPL.
OBJECT_NAME       = MARS_GLOBAL_SURVEYOR
OBJECT_ID         = 1996-062A
CENTER_NAME       = MARS BARYCENTER
REF_FRAME_A         = EME2000
REF_FRAME_B         = SC_BODY_1
TIME_SYSTEM       = UTC
START_TIME        = 1996-11-28T21:29:07.2555
USEABLE_START_TIME = 1996-11-28T22:08:02.5555
USEABLE_STOP_TIME  = 1996-11-30T01:18:02.5555
STOP_TIME         = 1996-11-30T01:28:02.5555
ATTITUDE_TYPE     = QUATERNION
INTERPOLATION_METHOD = HERMITE
INTERPOLATION_DEGREE = 7
META_STOP

DATA_START
1996-11-28T21:29:07.2555 0.56748 0.03146 0.45689 0.68427
1996-11-28T22:08:03.5555 0.42319 -0.45697 0.23784 0.74533
1996-11-30T01:28:02.5555 0.74563 -0.45375 0.36875 0.31964
DATA_STOP

META_START
COMMENT This block begins after trajectory correction maneuver TCM-3.
OBJECT_NAME       = mars_global_surveyor
OBJECT_ID         = 1996-062A
REF_FRAME_A         = EME2000
REF_FRAME_B         = SC_BODY_1
TIME_SYSTEM       = UTC
START_TIME        = 1996-353T12:05:00.5555
STOP_TIME         = 1996-12-28T21:28:00.5555
ATTITUDE_TYPE     = QUATERNION
META_STOP

DATA_START
1996-12-18T12:05:00.5555 -0.64585 0.018542 -0.23854 0.72501
1996-12-28T21:28:00.5555 -0.25485 0.58745 -0.36845 0.67394
DATA_STOP
"""


def test_reads_the_standards_example(tmp_path):
    p = tmp_path / "mgs.aem"
    p.write_text(HAND_WRITTEN_V2)
    a = read_aem(p)
    assert a.epoch0 == parse_utc("1996-11-28T21:29:07.2555Z")
    assert len(a.t_s) == 5 and len(a.meta["segments"]) == 2
    assert a.t_s[1] == 38 * 60 + 56.3                    # 22:08:03.5555 - 21:29:07.2555
    assert a.meta["INTERPOLATION_METHOD"] == "HERMITE" and a.meta["MESSAGE_ID"] == "A701523"
    q = np.array([0.56748, 0.03146, 0.45689, 0.68427])
    np.testing.assert_allclose(a.q_wxyz[0], [q[3], q[0], q[1], q[2]] / np.linalg.norm(q),
                               rtol=0, atol=1e-15)
    np.testing.assert_allclose(a.R_eci_from_body()[0].T, _m_ba(*q / np.linalg.norm(q)),
                               atol=1e-12)


def _v1(quaternion_type, attitude_dir, frame_a, frame_b, q_text):
    return f"""\
CCSDS_AEM_VERS = 1.0
CREATION_DATE = 2008-071T17:09:49
ORIGINATOR = GSFC
META_START
OBJECT_NAME = ST5-224
OBJECT_ID = 2006-224A
CENTER_NAME = EARTH
REF_FRAME_A = {frame_a}
REF_FRAME_B = {frame_b}
ATTITUDE_DIR = {attitude_dir}
TIME_SYSTEM = UTC
START_TIME = 2006-090T05:00:00.071
STOP_TIME = 2006-090T05:00:00.071
ATTITUDE_TYPE = QUATERNION
QUATERNION_TYPE = {quaternion_type}
META_STOP
DATA_START
2006-090T05:00:00.071 {q_text}
DATA_STOP
"""


@pytest.mark.parametrize("quaternion_type, attitude_dir, frame_a, frame_b, invert", [
    ("LAST", "A2B", "J2000", "SC_BODY_1", False),
    ("FIRST", "A2B", "J2000", "SC_BODY_1", False),
    ("LAST", "B2A", "J2000", "SC_BODY_1", True),
    ("LAST", "A2B", "SC_BODY_1", "ICRF", True),
    ("FIRST", "B2A", "SC_BODY_1", "EME2000", False),
])
def test_version_1_keywords_and_directions(tmp_path, quaternion_type, attitude_dir, frame_a,
                                           frame_b, invert):
    # Q = 30 deg about (1, 2, 2)/3: the rotation the file states, in its direction
    e, half = np.array([1.0, 2.0, 2.0]) / 3.0, math.radians(15.0)
    vec, qc = e * math.sin(half), math.cos(half)
    vals = [qc, *vec] if quaternion_type == "FIRST" else [*vec, qc]
    p = tmp_path / "v1.aem"
    p.write_text(_v1(quaternion_type, attitude_dir, frame_a, frame_b,
                     " ".join(f"{v:.15f}" for v in vals)))
    a = read_aem(p)
    stated = gtsam.Rot3.AxisAngle(gtsam.Point3(*e), 2 * half).matrix()
    np.testing.assert_allclose(a.R_eci_from_body()[0], stated.T if invert else stated, atol=1e-14)
    assert a.meta["body_frame"] == "SC_BODY_1"
    # written back in the AEM 2.0 form (inertial A, body B, scalar last): the same rotation
    q = tmp_path / "v2.aem"
    write_aem_data(q, a)
    text = q.read_text()
    assert "ATTITUDE_DIR" not in text and "QUATERNION_TYPE" not in text
    assert f"REF_FRAME_A = {frame_a if frame_a != 'SC_BODY_1' else frame_b}" in text
    b = read_aem(q)
    np.testing.assert_array_equal(b.t_s, a.t_s)
    np.testing.assert_allclose(b.q_wxyz, a.q_wxyz, rtol=0, atol=2e-16)


GOOD = HAND_WRITTEN_V2


def _replace(old, new, count=1):
    def edit(text):
        assert old in text
        line = text[:text.index(old)].count("\n") + 1
        return text.replace(old, new, count), line
    return edit


ERRORS = {
    "version_3": (_replace("CCSDS_AEM_VERS = 2.0", "CCSDS_AEM_VERS = 3.0"), "CCSDS_AEM_VERS",
                  "1.0 or 2.0"),
    "not_an_aem": (_replace("CCSDS_AEM_VERS = 2.0", "CCSDS_OEM_VERS = 2.0"), "CCSDS_OEM_VERS",
                   "CCSDS_AEM_VERS"),
    "header_keyword": (_replace("MESSAGE_ID    = A701523", "OBJECT_NAME = X"), "OBJECT_NAME",
                       "header keyword"),
    "time_system": (_replace("TIME_SYSTEM       = UTC", "TIME_SYSTEM       = TAI"),
                    "TIME_SYSTEM", "UTC"),
    "euler": (_replace("ATTITUDE_TYPE     = QUATERNION", "ATTITUDE_TYPE     = EULER_ANGLE"),
              "ATTITUDE_TYPE", "quaternion ATTITUDE_TYPE"),
    "v1_keyword_in_v2": (_replace("ATTITUDE_TYPE     = QUATERNION",
                                  "QUATERNION_TYPE = FIRST"), "QUATERNION_TYPE", "1.0"),
    "unknown_keyword": (_replace("INTERPOLATION_DEGREE = 7", "INTERPOLATION_ORDER = 7"),
                        "INTERPOLATION_ORDER", "metadata keyword"),
    "repeated_keyword": (_replace("CENTER_NAME       = MARS BARYCENTER",
                                  "OBJECT_ID = 1996-062A"), "OBJECT_ID", "once"),
    "missing_type": (lambda s: (s.replace("ATTITUDE_TYPE     = QUATERNION\nINTERPOLATION_METHOD",
                                          "INTERPOLATION_METHOD"), 20),
                     "ATTITUDE_TYPE", "before META_STOP"),
    "two_inertial_frames": (_replace("REF_FRAME_B         = SC_BODY_1", "REF_FRAME_B = ICRF"),
                            "REF_FRAME_B", "inertial"),
    "bad_epoch": (_replace("1996-11-28T22:08:03.5555 ", "1996-11-28T25:08:03.5555 "), "EPOCH",
                  "CCSDS epoch"),
    "bad_number": (_replace("0.42319 -0.45697", "0.42319 -0.4x697"), "Q2", "decimal number"),
    "not_unit": (_replace("0.42319 -0.45697", "0.52319 -0.45697"), "Q1", "unit quaternion"),
    "field_count": (_replace(" 0.23784 0.74533", " 0.23784"), None, "'EPOCH Q1 Q2 Q3 QC'"),
    "epochs_not_increasing": (_replace("1996-11-28T22:08:03.5555", "1996-11-28T21:29:07.2555"),
                              "EPOCH", "increasing"),
    "outside_stop_time": (_replace("1996-11-30T01:28:02.5555 0.74563",
                                   "1996-11-30T01:28:03.5555 0.74563"), "EPOCH", "STOP_TIME"),
    "no_data_start": (lambda s: (s.replace("DATA_START\n1996-11-28", "1996-11-28", 1), 23),
                      "DATA_START", "DATA_START"),
    "other_body_frame": (lambda s: (s[:s.rindex("REF_FRAME_B")] + "REF_FRAME_B = SC_BODY_2" +
                                    s[s.rindex("REF_FRAME_B") + 31:], 34),
                         "REF_FRAME_B", "SC_BODY_1"),
    "segment_before_previous": (lambda s: (s.replace("1996-353T12:05:00.5555", "1996-11-30T01:00:00")
                                           .replace("1996-12-18T12:05:00.5555 -0", "1996-11-30T"
                                                    "01:00:00 -0"), 42), "EPOCH", "time order"),
    "stop_before_start": (_replace("STOP_TIME         = 1996-12-28", "STOP_TIME = 1996-12-01"),
                          "STOP_TIME", "not before START_TIME"),
    "truncated": (lambda s: (s[:s.index("DATA_STOP")], s[:s.index("DATA_STOP")].count("\n") + 1),
                  "DATA_STOP", "DATA_STOP"),
    "text_after_data_stop": (lambda s: (s + "1996-12-28T21:28:00.5555 0 0 0 1\n",
                                        s.count("\n") + 1), None, "META_START"),
    "empty": (lambda s: ("", 1), "CCSDS_AEM_VERS", "CCSDS_AEM_VERS"),
}


@pytest.mark.parametrize("case", sorted(ERRORS))
def test_malformed_aem_names_file_line_and_keyword(tmp_path, case):
    edit, column, phrase = ERRORS[case]
    text, line = edit(GOOD)
    assert text != GOOD
    p = tmp_path / "bad.aem"
    p.write_text(text)
    with pytest.raises(InputFormatError) as ei:
        read_aem(p)
    e = ei.value
    assert (e.line, e.column) == (line, column), str(e)
    assert str(p) in str(e) and f"line {line}" in str(e) and phrase in str(e)


# --- attitude_covariance.csv


def _covariances(n, seed=2):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, 3, 3)) * 1e-5
    return A @ np.swapaxes(A, 1, 2) + 1e-12 * np.eye(3)


def test_covariance_csv_round_trip(tmp_path):
    P = _covariances(6)
    P[2] = np.nan
    t = np.array([0.0, 1.0, 2.5, 3.0, 60.0, 61.000001])
    p = tmp_path / "attitude_covariance.csv"
    write_attitude_covariance(p, EPOCH0, t, P, comments=["test"])
    text = p.read_text().splitlines()
    assert text[:2] == ["# test", "epoch,t_s,c11,c12,c13,c22,c23,c33"]
    assert text[4] == "2024-03-01T00:00:02.500000Z,2.500000,,,,,,"
    ep, ts, Q = read_attitude_covariance(p)
    np.testing.assert_array_equal(ep, add_seconds(EPOCH0, t))
    np.testing.assert_array_equal(ts, t)
    assert np.isnan(Q[2]).all()
    keep = [0, 1, 3, 4, 5]
    np.testing.assert_array_equal(Q[keep], P[keep])          # repr: exact
    fields = text[2].split(",")
    assert float(fields[2]) == P[0, 0, 0] and float(fields[3]) == P[0, 0, 1]
    assert float(fields[5]) == P[0, 1, 1] and float(fields[7]) == P[0, 2, 2]


COV_ERRORS = {
    "header": (lambda r: ["epoch,t_s,c11,c12,c13,c22,c23"] + r[1:], 1, None, "the header"),
    "fields": (lambda r: r[:1] + [r[1] + ",1"] + r[2:], 2, None, "8 fields"),
    "epoch": (lambda r: r[:2] + ["2024-13-01T00:00:01Z" + r[2][r[2].index(","):]] + r[3:], 3,
              "epoch", "UTC epoch"),
    "t_s": (lambda r: r[:2] + [r[2].replace(",1.000000,", ",1.500000,")] + r[3:], 3, "t_s",
            "advancing"),
    "negative_variance": (lambda r: r[:1] + [r[1].replace(",1e-10,", ",-1e-10,", 1)] + r[2:], 2,
                          "c11", ">= 0"),
    "one_empty_cell": (lambda r: r[:1] + [r[1].rsplit(",", 1)[0] + ","] + r[2:], 2, "c33",
                       "all six cells empty"),
    "not_psd": (lambda r: r[:1] + [r[1].replace(",0.0,0.0,2e-10", ",1e-9,0.0,2e-10")] + r[2:], 2,
                "c11", "positive semi-definite"),
    "not_increasing": (lambda r: r[:2] + [r[1]], 3, "epoch", "strictly increasing"),
}


@pytest.mark.parametrize("case", sorted(COV_ERRORS))
def test_covariance_csv_errors_name_line_and_column(tmp_path, case):
    p = tmp_path / "c.csv"
    write_attitude_covariance(p, EPOCH0, [0.0, 1.0], np.tile(np.diag([1e-10, 2e-10, 3e-10]),
                                                             (2, 1, 1)))
    rows = p.read_text().splitlines()
    edit, line, column, phrase = COV_ERRORS[case]
    bad = edit(rows)
    assert bad != rows
    p.write_text("\n".join(bad) + "\n")
    with pytest.raises(InputFormatError) as ei:
        read_attitude_covariance(p)
    e = ei.value
    assert (e.line, e.column) == (line, column), str(e)
    assert phrase in str(e) and str(p) in str(e)


# --- whatever the bytes, a reader ends with the data or with an error naming the file


def _mutations():
    from hypothesis import strategies as st

    token = st.sampled_from(["", " ", "=", "nan", "inf", "-0", "1e999", "META_START", "META_STOP",
                             "DATA_START", "DATA_STOP", "COMMENT", "2016-12-31T23:59:60",
                             "1996-02-30T00:00:00", "\xe9", "\t", "0.5 0.5 0.5 0.5"])
    return st.lists(st.tuples(st.integers(0, 60), st.sampled_from(["replace", "insert",
                                                                     "delete", "token"]),
                              token), min_size=1, max_size=4)


def _apply(lines, muts, sep=" "):
    lines = list(lines)
    for i, op, tok in muts:
        i %= len(lines) if lines else 1
        if not lines:
            lines = [tok]
        elif op == "replace":
            lines[i] = tok
        elif op == "insert":
            lines.insert(i, tok)
        elif op == "delete":
            del lines[i]
        else:
            parts = lines[i].split(sep)
            parts[len(tok) % len(parts)] = tok
            lines[i] = sep.join(parts)
    return "\n".join(lines) + "\n"


def test_mutated_files_give_data_or_a_format_error(tmp_path):
    from hypothesis import HealthCheck, given, settings

    write_attitude_covariance(tmp_path / "c.csv", EPOCH0, [0.0, 1.0, 2.0], _covariances(3))
    cov_lines = (tmp_path / "c.csv").read_text().splitlines()
    aem_lines = GOOD.splitlines()

    outcomes = {"data": 0, "error": 0}

    @settings(max_examples=150, deadline=None, derandomize=True,
              suppress_health_check=[HealthCheck.function_scoped_fixture])
    @given(_mutations(), _mutations())
    def run(muts_aem, muts_cov):
        for reader, text, name in ((read_aem, _apply(aem_lines, muts_aem), "m.aem"),
                                   (read_attitude_covariance,
                                    _apply(cov_lines, muts_cov, sep=","), "m.csv")):
            p = tmp_path / name
            p.write_bytes(text.encode("latin-1", "replace"))
            try:
                reader(p)
                outcomes["data"] += 1
            except UserError as exc:
                assert str(p) in str(exc)
                outcomes["error"] += 1

    run()
    assert outcomes["error"] > 100 and outcomes["data"] > 10, outcomes
