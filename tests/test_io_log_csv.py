"""CSV measurement log v1 (fgnav.io.log_csv), atomic writes and summary.json."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

from fgnav.errors import InputFormatError, UserError
from fgnav.io.atomic import atomic_write_text, atomic_writer
from fgnav.io.log_csv import (EXTRA_COLUMNS, KINDS, log_from_arrays, read_log, write_log)
from fgnav.io.log_spacecraft import ISL_KINDS
from fgnav.io.summary import read_summary, write_summary
from fgnav.time import parse_utc

HEADER = "epoch,kind,x,y,z,sigma"

VALID = """\
# a pass logged by hand
epoch,kind,x,y,z,sigma,gamma,sigma_model_m,star_x,star_y,star_z,body,body2
2024-03-01T00:00:00Z,prior_position,7000000,-12.5,3.25e3,1000,,,,,,,
2024-03-01T00:00:00Z,prior_velocity,0,7546.05,1.5,1,,,,,,,
2024-03-01T00:00:00Z,earth_direction,-0.6,0.8,0,1e-4,,,,,,,
2024-03-01T00:00:10.5Z,limb_radius,1.1,6378137,,2e-4,,,,,,,

2024-03-01T00:00:10.5Z,earth_direction_body,0,0,-1,1e-4,,,,,,,
2024-03-01T00:00:10.5Z,attitude,0.1,-0.2,0.3,5e-5,,,,,,,
2024-03-01T00:00:20Z,altitude,621000,6378137,,30,,,,,,,
2024-03-01T00:00:20Z,sun_direction_body,1,0,0,1e-3,,,,,,,
2024-03-01T00:00:20Z,moon_direction_body,0,1,0,1e-3,,,,,,,
2024-03-01T00:00:30Z,refraction,0,0.6,0.8,1e-6,1.5e-4,250,,,,,
2024-03-01T00:00:40Z,refraction,0,0.8,0.6,1e-6,1.1e-4,,,,,,
2024-03-01T00:00:40Z,star_direction_body,0.6,0,-0.8,2.5e-5,,,0.28,-0.96,0,,
2024-03-01T00:00:40Z,gyro,1e-3,-2e-4,0,1e-6,,,,,,,
2024-03-01T00:00:50Z,body_star_angle,0.9,,,3e-5,,,0.6,0,0.8,moon,
2024-03-01T00:00:50Z,limb_star_angle,0.3,6375000,,8e-5,,,0,0.6,0.8,earth,
2024-03-01T00:00:50Z,body_body_angle,2.8,,,8e-5,,,,,,earth,moon
"""


def _write(tmp_path, text, name="log.csv"):
    p = tmp_path / name
    p.write_bytes(text.encode("utf-8") if isinstance(text, str) else text)
    return p


def _csv(*rows, header=HEADER):
    return header + "\n" + "".join(r + "\n" for r in rows)


GOOD = "2024-03-01T00:00:00Z,earth_direction,0,0,1,1e-4"


def test_read_valid_log_all_kinds(tmp_path):
    log = read_log(_write(tmp_path, VALID))
    assert set(log.kind) == set(KINDS) - set(ISL_KINDS)  # tests/test_log_spacecraft.py: those
    assert log.epoch0 == parse_utc("2024-03-01T00:00:00Z")
    assert len(log) == 16
    np.testing.assert_array_equal(log.epochs_unique(), [0.0, 10.5, 20.0, 30.0, 40.0, 50.0])
    i = log.select("prior_position")
    np.testing.assert_array_equal(log.xyz[i], [[7000000.0, -12.5, 3250.0]])
    assert log.sigma[i][0] == 1000.0
    j = log.select("limb_radius")[0]
    assert log.xyz[j, 0] == 1.1 and log.xyz[j, 1] == 6378137.0 and math.isnan(log.xyz[j, 2])
    assert log.t_s[j] == 10.5
    r = log.select("refraction")
    np.testing.assert_array_equal(log.extra["gamma"][r], [1.5e-4, 1.1e-4])
    smm = log.extra["sigma_model_m"][r]
    assert smm[0] == 250.0 and math.isnan(smm[1])
    assert np.all(np.isnan(log.extra["gamma"][log.select("earth_direction")]))
    assert log.line[j] == 6  # 1-based source line (comment and header count)
    assert log.warnings == [] and log.dropped == {}
    assert log.counts()["refraction"] == 2
    st = log.select("star_direction_body")
    np.testing.assert_array_equal(log.xyz[st], [[0.6, 0.0, -0.8]])
    np.testing.assert_array_equal(np.column_stack([log.extra[c][st] for c in
                                                   ("star_x", "star_y", "star_z")]),
                                  [[0.28, -0.96, 0.0]])
    assert np.all(np.isnan(log.extra["star_x"][r]))


def test_round_trip_read_write_read_is_exact(tmp_path):
    a = read_log(_write(tmp_path, VALID))
    write_log(tmp_path / "b.csv", a)
    b = read_log(tmp_path / "b.csv")
    assert a.epoch0 == b.epoch0
    np.testing.assert_array_equal(a.t_s, b.t_s)
    np.testing.assert_array_equal(a.kind, b.kind)
    np.testing.assert_array_equal(a.xyz, b.xyz)  # NaN == NaN in assert_array_equal
    np.testing.assert_array_equal(a.sigma, b.sigma)
    for c in EXTRA_COLUMNS:
        np.testing.assert_array_equal(a.extra[c], b.extra[c])


def test_round_trip_from_arrays_full_precision(tmp_path):
    rng = np.random.default_rng(7)
    M = 200
    u = rng.normal(size=(M, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    t_s = np.sort(rng.uniform(0, 5000, M)).round(6)  # microsecond epochs
    sigma = rng.uniform(1e-6, 1e-3, M)
    epoch0 = parse_utc("2025-01-02T03:04:05.123456Z")
    log = log_from_arrays(epoch0, t_s, ["earth_direction"] * M, u, sigma)
    write_log(tmp_path / "r.csv", log)
    back = read_log(tmp_path / "r.csv")
    np.testing.assert_array_equal(back.xyz, log.xyz)   # 17 significant digits: bit-exact
    np.testing.assert_array_equal(back.sigma, sigma)
    abs_in = (log.epochs_utc() - epoch0).astype(np.int64)
    abs_out = (back.epochs_utc() - epoch0).astype(np.int64)
    np.testing.assert_array_equal(abs_in, abs_out)     # epochs exact to the nanosecond


def test_nanosecond_epochs_round_trip(tmp_path):
    p = _write(tmp_path, _csv("2024-03-01T00:00:00.123456789Z,earth_direction,0,0,1,1e-4",
                              "2024-03-01T00:00:01Z,earth_direction,0,1,0,1e-4"))
    a = read_log(p)
    write_log(tmp_path / "b.csv", a)
    assert "00:00:00.123456789Z" in (tmp_path / "b.csv").read_text()
    b = read_log(tmp_path / "b.csv")
    assert a.epoch0 == b.epoch0
    np.testing.assert_array_equal(a.t_s, b.t_s)


# ---- each bad input: (content, line, column, a phrase of the expectation)
BAD_CASES = {
    "missing_header_column": ("epoch,kind,x,y,z\n" + GOOD + "\n", 1, "sigma", "missing"),
    "misnamed_header_column": ("epoch,kind,x,y,zz,sigma\n" + GOOD + "\n", 1, "z", "column 5"),
    "extra_header_column": (_csv(GOOD + ",", header=HEADER + ",foo"), 1, "foo", "extra columns"),
    "repeated_extra_column": (_csv(GOOD + ",,", header=HEADER + ",gamma,gamma"), 1, "gamma",
                              "each column once"),
    "too_few_fields": (_csv(GOOD, "2024-03-01T00:00:01Z,earth_direction,0,0,1"), 3, "sigma",
                       "6 comma-separated fields"),
    "too_many_fields": (_csv(GOOD + ",7"), 2, "field 7", "6 comma-separated fields"),
    "unparsable_number": (_csv("2024-03-01T00:00:00Z,earth_direction,0,0.0.1,1,1e-4"), 2, "y",
                          "decimal number"),
    "epoch_without_Z": (_csv("2024-03-01T00:00:00,earth_direction,0,0,1,1e-4"), 2, "epoch",
                        "ISO-8601"),
    "epoch_invalid_date": (_csv("2024-02-30T00:00:00Z,earth_direction,0,0,1,1e-4"), 2, "epoch",
                           "valid date"),
    "epoch_year_out_of_datetime64_range": (_csv("2300-03-01T00:00:00Z,earth_direction,0,0,1,"
                                                "1e-4"), 2, "epoch", "year within"),
    "unknown_kind": (_csv(GOOD, "2024-03-01T00:00:00Z,star_direction,0,0,1,1e-4"), 3, "kind",
                     "one of"),
    "nan_value": (_csv("2024-03-01T00:00:00Z,prior_position,7e6,nan,0,1e3"), 2, "y", "finite"),
    "inf_sigma": (_csv("2024-03-01T00:00:00Z,prior_position,7e6,0,0,inf"), 2, "sigma", "finite"),
    "overflow_to_inf": (_csv("2024-03-01T00:00:00Z,prior_position,1e999,0,0,1"), 2, "x",
                        "finite"),
    "sigma_zero": (_csv("2024-03-01T00:00:00Z,earth_direction,0,0,1,0"), 2, "sigma", "> 0"),
    "sigma_negative": (_csv("2024-03-01T00:00:00Z,earth_direction,0,0,1,-1e-4"), 2, "sigma",
                       "> 0"),
    "sigma_empty": (_csv("2024-03-01T00:00:00Z,earth_direction,0,0,1,"), 2, "sigma", "> 0"),
    "direction_not_unit": (_csv(GOOD, "2024-03-01T00:00:01Z,earth_direction,0,0,1.00001,1e-4"),
                           3, "x,y,z", "unit vector"),
    "body_direction_not_unit": (_csv("2024-03-01T00:00:00Z,sun_direction_body,0.5,0,0,1e-3"),
                                2, "x,y,z", "unit vector"),
    "limb_radius_too_large": (_csv("2024-03-01T00:00:00Z,limb_radius,1.6,6378137,,1e-4"), 2,
                              "x", "(0, pi/2)"),
    "limb_radius_zero": (_csv("2024-03-01T00:00:00Z,limb_radius,0,6378137,,1e-4"), 2, "x",
                         "(0, pi/2)"),
    "limb_sphere_radius_negative": (_csv("2024-03-01T00:00:00Z,limb_radius,1,-1,,1e-4"), 2, "y",
                                    "> 0"),
    "required_value_empty": (_csv("2024-03-01T00:00:00Z,earth_direction,0,1,,1e-4"), 2, "z",
                             "a number"),
    "unused_value_filled": (_csv("2024-03-01T00:00:00Z,limb_radius,1,6378137,5,1e-4"), 2, "z",
                            "empty field"),
    "refraction_without_gamma": (_csv("2024-03-01T00:00:00Z,refraction,0,0,1,1e-6,",
                                      header=HEADER + ",gamma"), 2, "gamma", "a number"),
    "negative_model_sigma": (_csv("2024-03-01T00:00:00Z,refraction,0,0,1,1e-6,1e-4,-3",
                                  header=HEADER + ",gamma,sigma_model_m"), 2, "sigma_model_m",
                             ">= 0"),
    "star_catalogue_vector_not_unit": (_csv("2024-03-01T00:00:00Z,star_direction_body,0,0,1,"
                                            "2e-5,0.6,0.8,0.1", header=HEADER + ",star_x,star_y,star_z"), 2,
                                       "star_x,star_y,star_z", "unit vector"),
    "star_measured_vector_not_unit": (_csv("2024-03-01T00:00:00Z,star_direction_body,0,0,0.9,"
                                           "2e-5,0.6,0.8,0", header=HEADER + ",star_x,star_y,star_z"), 2, "x,y,z",
                                      "unit vector"),
    "star_without_catalogue_vector": (_csv("2024-03-01T00:00:00Z,star_direction_body,0,0,1,"
                                           "2e-5,0.6,,0", header=HEADER + ",star_x,star_y,star_z"), 2, "star_y",
                                      "a number"),
    "star_columns_missing_from_header": (_csv("2024-03-01T00:00:00Z,star_direction_body,0,0,1,"
                                              "2e-5"), 2, "star_x", "a number"),
    "star_vector_on_another_kind": (_csv("2024-03-01T00:00:00Z,earth_direction,0,0,1,1e-4,"
                                         "1,0,0", header=HEADER + ",star_x,star_y,star_z"), 2, "star_x",
                                    "empty field"),
    "altitude_below_centre": (_csv("2024-03-01T00:00:00Z,altitude,-7e6,6378137,,30"), 2, "x",
                              "x + y > 0"),
    "epoch_far_from_others": (_csv(GOOD, "2024-03-01T00:01:00Z,earth_direction,0,0,1,1e-4",
                                   "2024-05-01T00:00:00Z,earth_direction,0,0,1,1e-4",
                                   "2024-03-01T00:02:00Z,earth_direction,0,0,1,1e-4"), 4,
                              "epoch", "within 30 days"),
    "empty_file": ("", 1, None, "no measurements"),
    "header_only": ("# comment\n" + HEADER + "\n", 3, None, "no measurements"),
    "comments_only": ("# nothing here\n\n", 2, None, "no measurements"),
    "truncated_last_line": (HEADER + "\n" + GOOD + "\n2024-03-01T00:00:01Z,earth_direction,0,0",
                            3, "z", "truncated"),
    "not_utf8": ((HEADER + "\n" + GOOD + "\n").encode() + b"2024-03-01T00:00:01Z,\xff\xfe\n", 3,
                 None, "UTF-8"),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_bad_input_names_file_line_column(tmp_path, case):
    text, line, column, phrase = BAD_CASES[case]
    p = _write(tmp_path, text)
    with pytest.raises(InputFormatError) as ei:
        read_log(p)
    e = ei.value
    msg = str(e)
    assert e.path == p and str(p) in msg
    assert e.line == line and f"line {line}" in msg
    assert e.column == column
    if column:
        assert f"column '{column}'" in msg
    assert phrase in msg
    assert isinstance(e, ValueError)


def test_out_of_order_rows_stably_sorted_with_count(tmp_path):
    p = _write(tmp_path, _csv(
        "2024-03-01T00:00:20Z,earth_direction,1,0,0,1e-4",    # line 2
        "2024-03-01T00:00:00Z,earth_direction,0,1,0,1e-4",    # line 3 (early)
        "2024-03-01T00:00:20Z,earth_direction,0,0,1,1e-4",    # line 4
        "2024-03-01T00:00:10Z,earth_direction,0,0,-1,1e-4",   # line 5 (early)
        "2024-03-01T00:00:10Z,earth_direction,0,-1,0,1e-4"))  # line 6 (early)
    log = read_log(p)
    np.testing.assert_array_equal(log.t_s, [0, 10, 10, 20, 20])
    np.testing.assert_array_equal(log.line, [3, 5, 6, 2, 4])  # stable among equal epochs
    assert len(log.warnings) == 1
    assert "3 row(s) out of time order" in log.warnings[0] and "line 3" in log.warnings[0]


def test_exact_duplicates_dropped_with_warning(tmp_path):
    row = "2024-03-01T00:00:05Z,limb_radius,1.0,6378137,,1e-4"
    p = _write(tmp_path, _csv(GOOD, row, row, "2024-03-01T00:00:05Z,limb_radius,1.0,6378137,,"
                              "2e-4", row.replace("1.0,", "1,")))
    log = read_log(p)
    # "1" and "1.0" are the same number: an exact duplicate; a different sigma is not.
    assert len(log) == 3 and log.dropped == {"duplicate": 2}
    np.testing.assert_array_equal(log.line, [2, 3, 5])
    assert any("2 exact duplicate" in w and "line 4 repeats line 3" in w for w in log.warnings)


def test_tiny_norm_deviation_renormalized(tmp_path):
    p = _write(tmp_path, _csv("2024-03-01T00:00:00Z,earth_direction,0.6,0.8,0.00001,1e-4"))
    log = read_log(p)
    assert abs(np.linalg.norm(log.xyz[0]) - 1.0) < 1e-15
    assert any("renormalized" in w for w in log.warnings)


def test_drop_bad_rows_counts_per_reason(tmp_path):
    p = _write(tmp_path, _csv(
        GOOD,
        "2024-03-01T00:00:01Z,earth_direction,0,0,2,1e-4",         # not_unit
        "2024-03-01T00:00:02Z,earth_direction,0,0,1,-1",           # bad_sigma
        "2024-03-01T00:00:03Z,earth_direction,0,0,1,-1",           # bad_sigma
        "2024-03-01T00:00:04Z,earthdirection,0,0,1,1e-4",          # unknown_kind
        "2024-03-01T00:00:05Z,earth_direction,0,0,1",              # field_count
        "2024-13-01T00:00:06Z,earth_direction,0,0,1,1e-4",         # bad_epoch
        "2025-03-01T00:00:07Z,earth_direction,0,0,1,1e-4",         # epoch_outlier
        "2024-03-01T00:00:08Z,earth_direction,0,1,0,1e-4"))
    with pytest.raises(InputFormatError):
        read_log(p)
    log = read_log(p, on_bad_row="drop")
    assert log.dropped == {"not_unit": 1, "bad_sigma": 2, "unknown_kind": 1, "field_count": 1,
                           "bad_epoch": 1, "epoch_outlier": 1}
    np.testing.assert_array_equal(log.line, [2, 10])
    np.testing.assert_array_equal(log.t_s, [0.0, 8.0])
    w = [x for x in log.warnings if "(bad_sigma)" in x]
    assert len(w) == 1 and "dropped 2 row(s)" in w[0] and "line 4" in w[0]


def test_drop_mode_all_rows_bad_is_no_measurements(tmp_path):
    p = _write(tmp_path, _csv("2024-03-01T00:00:00Z,earth_direction,0,0,1,0"))
    with pytest.raises(InputFormatError, match="no measurements"):
        read_log(p, on_bad_row="drop")


def test_header_errors_are_not_droppable(tmp_path):
    p = _write(tmp_path, "epoch,kind,x,y,z\n" + GOOD + "\n")
    with pytest.raises(InputFormatError, match="missing"):
        read_log(p, on_bad_row="drop")


def test_crlf_bom_and_last_line_without_newline_are_accepted(tmp_path):
    p = _write(tmp_path, b"\xef\xbb\xbf" + (HEADER + "\r\n" + GOOD + "\r\n" +
                                             GOOD.replace(":00Z", ":01Z")).encode())
    log = read_log(p)
    assert len(log) == 2 and log.t_s[1] == 1.0


def test_missing_file_is_user_error(tmp_path):
    with pytest.raises(UserError, match="cannot read"):
        read_log(tmp_path / "absent.csv")


def test_log_from_arrays_validates_and_sorts():
    e0 = parse_utc("2024-03-01T00:00:00Z")
    with pytest.raises(UserError, match="row 1, column 'sigma'"):
        log_from_arrays(e0, [0, 1], ["earth_direction"] * 2, [[0, 0, 1], [0, 1, 0]], [1e-4, 0])
    with pytest.raises(UserError, match="row 0, column 'kind'"):
        log_from_arrays(e0, [0], ["nope"], [[0, 0, 1]], [1e-4])
    log = log_from_arrays(e0, [5.0, 1.0], ["limb_radius", "earth_direction"],
                          [[1.0, 6.4e6, np.nan], [0, 0, 1]], [1e-4, 1e-4])
    np.testing.assert_array_equal(log.t_s, [1.0, 5.0])
    np.testing.assert_array_equal(log.kind, ["earth_direction", "limb_radius"])
    assert log.warnings and "out of time order" in log.warnings[0]


def test_write_log_refuses_invalid_rows(tmp_path):
    log = read_log(_write(tmp_path, _csv(GOOD)))
    log.sigma[0] = -1.0
    with pytest.raises(UserError, match="sigma"):
        write_log(tmp_path / "out.csv", log)
    assert not (tmp_path / "out.csv").exists()


# ---- atomic writes


def test_atomic_writer_replaces_on_success(tmp_path):
    p = tmp_path / "f.txt"
    atomic_write_text(p, "old\n")
    with atomic_writer(p) as f:
        f.write("new\n")
    assert p.read_text() == "new\n"
    assert os.listdir(tmp_path) == ["f.txt"]


@pytest.mark.parametrize("exc", [RuntimeError, KeyboardInterrupt])
def test_atomic_writer_leaves_old_file_on_exception(tmp_path, exc):
    p = tmp_path / "f.txt"
    atomic_write_text(p, "old\n")
    with pytest.raises(exc):
        with atomic_writer(p) as f:
            f.write("half of the new con")
            raise exc()
    assert p.read_text() == "old\n"
    assert os.listdir(tmp_path) == ["f.txt"]  # temporary file removed


def test_atomic_writer_binary_and_new_file_permissions(tmp_path):
    p = tmp_path / "b.bin"
    with atomic_writer(p, "wb") as f:
        f.write(b"\x00\x01")
    assert p.read_bytes() == b"\x00\x01"
    umask = os.umask(0)
    os.umask(umask)
    assert (os.stat(p).st_mode & 0o777) == (0o666 & ~umask)


# ---- summary.json


def test_summary_round_trip_nan_to_null_sorted(tmp_path):
    p = tmp_path / "summary.json"
    write_summary(p, {"z": 1, "a": np.float64(np.nan), "rms_m": np.array([1.5, np.inf]),
                      "n": np.int64(3), "ok": np.bool_(True),
                      "epoch0": parse_utc("2024-03-01T00:00:00Z"), "nested": {"b": (1, 2.5)}})
    text = p.read_text()
    assert text.index('"a"') < text.index('"epoch0"') < text.index('"z"')
    back = read_summary(p)
    assert back == {"z": 1, "a": None, "rms_m": [1.5, None], "n": 3, "ok": True,
                    "epoch0": "2024-03-01T00:00:00.000000Z", "nested": {"b": [1, 2.5]}}


def test_summary_malformed_names_line(tmp_path):
    p = tmp_path / "s.json"
    p.write_text('{\n  "a": 1,\n  "b": nan\n}\n')
    with pytest.raises(InputFormatError, match="line 3"):
        read_summary(p)
