"""The column-wise reading of a CSV v1 log (``_fast_rows``, Arrow) gives exactly what the
row-by-row reading (``_parse_row``, the reference with its messages) gives: same arrays bit
for bit, same warnings, same drops, same first error."""

from __future__ import annotations

import numpy as np
import pytest

import fgnav.io.log_csv as lc
from fgnav.errors import InputFormatError

HEADER = ("epoch,kind,x,y,z,sigma,gamma,sigma_model_m,star_x,star_y,star_z,"
          "att_c11,att_c12,att_c13,att_c22,att_c23,att_c33")
_ATT_COV = ",,,,,,"  # the six attitude-covariance fields, empty


def _padded(rows):
    """Rows written for the first eleven columns, with the six covariance fields appended
    empty (a row with another field count is kept as it is: a field-count error)."""
    return [r + _ATT_COV if r.count(",") == 10 else r for r in rows]


GOOD = [
    "2025-03-01T00:00:00Z,prior_position,7000000,10,-20.5,100,,,,,",
    "2025-03-01T00:00:00Z,prior_velocity,1,7500,2,0.1,,,,,",
    "2025-03-01T00:00:00Z,earth_direction,0.6,0.8,0,1.7453292519943296e-4,,,,,",
    "2025-03-01T00:00:01.5Z,earth_direction,0.6000001,0.8,0,1e-4,,,,,",          # renormalized
    "2025-03-01T00:00:02.123456789Z,earth_direction, +.6 ,\t.8,-0e-5,1E-4,,,,,",
    "2025-03-01T00:00:03Z,limb_radius,0.3,6.4e6,,1e-4,,,,,",
    "2025-03-01T00:00:03Z,altitude,5e5,6378137,,3,,,,,",
    "2025-03-01T00:00:04Z,refraction,0,0.6,0.8,1e-5,1e-4,200,,,",
    "2025-03-01T00:00:04Z,star_direction_body,0,0,1,1e-5,,,0.6,0.8,0.0000001",
    "2025-03-01T00:00:05Z,attitude,0.1,0.2,0.3,1e-5,,,,,",
    "2025-03-01T00:00:02Z,earth_direction,0,0,1,1e-4,,,,,",                      # out of order
    "2025-03-01T00:00:02Z,earth_direction,0,0,1,1e-4,,,,,",                      # duplicate
]
GOOD = _padded(GOOD) + [  # attitude rows with their full covariance (rad^2)
    "2025-03-01T00:00:05Z,attitude,0.1,0.2,0.4,1e-4,,,,,,1e-10,2e-11,0,1e-10,-1e-11,1e-8",
    "2025-03-01T00:00:06Z,attitude,0.1,0.2,0.5,1e-4,,,,,,4e-10,0,0,4e-10,0,4e-10",
]
BAD = [
    "2025-03-01T00:00:06Z,earth_direction,1,0,0,0,,,,,",
    "2025-03-01T00:00:06Z,foo,1,0,0,1e-4,,,,,",
    "2025-03-01T00:00:6Z,earth_direction,1,0,0,1e-4,,,,,",
    "2025-02-30T00:00:06Z,earth_direction,1,0,0,1e-4,,,,,",
    "2025-03-01T24:00:00Z,earth_direction,1,0,0,1e-4,,,,,",
    "2025-03-01T00:00:06Z,earth_direction,1.01,0,0,1e-4,,,,,",
    "2025-03-01T00:00:06Z,earth_direction,1,0,,1e-4,,,,,",
    "2025-03-01T00:00:06Z,earth_direction,1,0,nan,1e-4,,,,,",
    "2025-03-01T00:00:06Z,earth_direction,1e999,0,0,1e-4,,,,,",
    "2025-03-01T00:00:06Z,earth_direction,1_0,0,0,1e-4,,,,,",
    "2025-03-01T00:00:06Z,earth_direction,1,0,0,1e-4,5,,,,",
    "2025-03-01T00:00:06Z,prior_position,1,0,0,1,,,,,",
    "2025-03-01T00:00:06Z,limb_radius,2,6.4e6,,1e-4,,,,,",
    "2025-03-01T00:00:06Z,refraction,0,0.6,0.8,1e-5,1e-4,-1,,,",
    "2025-03-01T00:00:06Z,earth_direction,1,0,0,1e-4",
    "2016-12-31T23:59:60Z,earth_direction,1,0,0,1e-4,,,,,",
    "2025-06-01T00:00:00Z,earth_direction,1,0,0,1e-4,,,,,",
    "# a comment",
    "",
    "  2025-03-01T00:00:07Z,earth_direction,1,0,0,1e-4,,,,,",
    "2025-03-01T00:00:07Z,earth_direction,1,0\r,0,1e-4,,,,,",
    "2025-03-01T00:00:07Z,earth_\u00e9direction,1,0,0,1e-4,,,,,",
]
BAD = _padded(BAD) + [
    "2025-03-01T00:00:06Z,attitude,0.1,0.2,0.3,1e-4,,,,,,1e-10,0,0,1e-10,0,",    # partial
    "2025-03-01T00:00:06Z,attitude,0.1,0.2,0.3,1e-4,,,,,,1e-10,2e-10,0,1e-10,0,1e-10",  # not PD
    "2025-03-01T00:00:06Z,attitude,0.1,0.2,0.3,1e-4,,,,,,1e-10,0,0,1e-10,0,100",  # > pi^2
    "2025-03-01T00:00:06Z,earth_direction,1,0,0,1e-4,,,,,,1e-10,0,0,1e-10,0,1e-10",  # unused
]


def _fields(log):
    return (log.epoch0, log.t_s, log.kind, log.xyz, log.sigma, log.extra, log.line,
            log.warnings, log.dropped)


def _same(a, b):
    for u, v in zip(_fields(a), _fields(b)):
        if isinstance(u, dict):
            assert u.keys() == v.keys()
            for k in u:
                _same_value(u[k], v[k])
        else:
            _same_value(u, v)


def _same_value(u, v):
    if isinstance(u, np.ndarray):
        assert u.dtype == v.dtype and u.shape == v.shape
        if u.dtype.kind == "f":
            np.testing.assert_array_equal(u.view(np.int64), v.view(np.int64))
        else:
            np.testing.assert_array_equal(u, v)
    else:
        assert u == v


def _row_by_row(monkeypatch, path, mode):
    with monkeypatch.context() as m:
        m.setattr(lc, "_regular_lines", lambda raw, start, ncol: (np.zeros(0, dtype=np.int64), b""))
        try:
            return lc.read_log(path, on_bad_row=mode)
        except InputFormatError as exc:
            return str(exc)


@pytest.mark.parametrize("seed", range(12))
def test_columns_and_rows_read_the_same(tmp_path, monkeypatch, seed):
    monkeypatch.setattr(lc, "COLUMN_WISE_MIN_ROWS", 0)
    rng = np.random.default_rng(seed)
    rows = list(GOOD) + [GOOD[2 + k % 3].replace("00:00:0", f"00:01:{10 + k}.") for k in range(30)]
    for _ in range(int(rng.integers(0, 5))):
        rows.insert(int(rng.integers(0, len(rows) + 1)), BAD[int(rng.integers(0, len(BAD)))])
    text = HEADER + "\n" + "\n".join(rows) + ("\n" if seed % 3 else "")
    if seed % 4 == 1:
        text = text.replace("\n", "\r\n")
    path = tmp_path / "log.csv"
    path.write_text(text, newline="")
    for mode in ("drop", "error"):
        ref = _row_by_row(monkeypatch, path, mode)
        try:
            got = lc.read_log(path, on_bad_row=mode)
        except InputFormatError as exc:
            got = str(exc)
        if isinstance(ref, str) or isinstance(got, str):
            assert got == ref
        else:
            _same(got, ref)


def test_a_clean_log_is_read_column_wise(tmp_path):
    path = tmp_path / "log.csv"
    path.write_text(HEADER + "\n" + "\n".join(GOOD) + "\n")
    raw = path.read_bytes().split(b"\n")[:-1]
    kept, *_, slow = lc._fast_rows(raw, 1, HEADER.split(","))
    assert len(kept) == len(GOOD) and slow == []
