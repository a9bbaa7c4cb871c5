"""Several spacecraft in one log (fgnav.io.log_spacecraft): the ``spacecraft`` column, the
inter-satellite kinds, antenna declarations, and what a user is told when they are wrong."""

from __future__ import annotations

import numpy as np
import pytest

from fgnav.errors import InputFormatError, UserError
from fgnav.io.log_csv import COLUMN_WISE_MIN_ROWS, EXTRA_COLUMNS, log_from_arrays, read_log, write_log
from fgnav.io.log_spacecraft import spacecraft_index

HEAD = """\
# spacecraft: A B
# antenna: A rx1 0.5 0.5 0.5
# antenna: B tx0 0.5 0.5 -0.5
epoch,kind,x,y,z,sigma,spacecraft,tx_spacecraft,rx_antenna,tx_antenna
"""
ROWS = """\
2025-01-01T00:00:00Z,prior_position,7000000,0,0,100,A,,,
2025-01-01T00:00:00Z,prior_position,7000000,1000,0,100,B,,,
2025-01-01T00:00:00Z,earth_direction,-1,0,0,1e-4,B,,,
2025-01-01T00:00:00Z,isl_pseudorange,1000.2,,,0.01,A,B,rx1,tx0
2025-01-01T00:00:10Z,isl_carrier_phase,-3.25,,,1e-5,A,B,,
"""


def _read(tmp_path, text, **kw):
    p = tmp_path / "log.csv"
    p.write_text(text)
    return read_log(p, **kw)


def test_spacecraft_ids_codes_and_lever_arms(tmp_path):
    log = _read(tmp_path, HEAD + ROWS)
    assert log.spacecraft == ("A", "B") and log.n_spacecraft == 2
    np.testing.assert_array_equal(spacecraft_index(log), [0, 1, 1, 0, 0])
    isl = log.select("isl_pseudorange")[0]
    assert log.extra["tx_spacecraft"][isl] == 1
    assert log.antenna_names[int(log.extra["rx_antenna"][isl])] == "rx1"
    np.testing.assert_array_equal(log.antennas[("B", "tx0")], [0.5, 0.5, -0.5])
    assert np.isnan(log.extra["rx_antenna"][log.select("isl_carrier_phase")[0]])


def test_one_spacecraft_log_is_unchanged(tmp_path):
    log = _read(tmp_path, "epoch,kind,x,y,z,sigma\n2025-01-01T00:00:00Z,earth_direction,0,0,1,1e-4\n")
    assert log.spacecraft == () and log.n_spacecraft == 1
    assert np.isnan(log.extra["spacecraft"]).all()
    np.testing.assert_array_equal(spacecraft_index(log), [0])


def test_order_of_first_appearance_without_declaration(tmp_path):
    text = ("epoch,kind,x,y,z,sigma,spacecraft,tx_spacecraft\n"
            "2025-01-01T00:00:10Z,isl_pseudorange,1000,,,0.01,zeta,alpha\n"
            "2025-01-01T00:00:00Z,earth_direction,0,0,1,1e-4,alpha,\n")
    log = _read(tmp_path, text)
    assert log.spacecraft == ("zeta", "alpha")   # file order, not time order or alphabet
    np.testing.assert_array_equal(spacecraft_index(log), [1, 0])   # rows sorted by epoch


def test_round_trip_keeps_ids_and_declarations(tmp_path):
    a = _read(tmp_path, HEAD + ROWS)
    write_log(tmp_path / "b.csv", a)
    b = read_log(tmp_path / "b.csv")
    assert b.spacecraft == a.spacecraft and b.antenna_names == a.antenna_names
    assert b.antennas.keys() == a.antennas.keys()
    for c in EXTRA_COLUMNS:
        np.testing.assert_array_equal(a.extra[c], b.extra[c])


def test_column_wise_and_row_wise_reading_agree(tmp_path):
    """A long log goes through Arrow, a short one row by row: the same codes."""
    rows = [f"2025-01-01T{k // 3600:02d}:{k // 60 % 60:02d}:{k % 60:02d}Z,isl_pseudorange,"
            f"{1000 + k * 1e-3!r},,,0.01,{'AB'[k % 2]},{'BA'[k % 2]},"
            f"{'rx1' if k % 2 == 0 else ''},{'tx0' if k % 2 == 0 else ''}"
            for k in range(COLUMN_WISE_MIN_ROWS + 10)]
    long = _read(tmp_path, HEAD + "\n".join(rows) + "\n")
    p = tmp_path / "short.csv"
    p.write_text(HEAD + "\n".join(rows[:50]) + "\n")
    short = read_log(p)
    for c in ("spacecraft", "tx_spacecraft", "rx_antenna", "tx_antenna"):
        np.testing.assert_array_equal(long.extra[c][:50], short.extra[c])
    assert long.spacecraft == short.spacecraft == ("A", "B")


@pytest.mark.parametrize("old,new,line,column,words", [
    (",A,B,rx1,tx0", ",A,A,rx1,tx0", 8, "tx_spacecraft", "other than the receiving"),
    ("rx1,tx0", "rx9,tx0", 8, "rx_antenna", "antenna declared for spacecraft 'A'"),
    ("rx1,tx0", "rx1,tx1", 8, "tx_antenna", "antenna declared for spacecraft 'B'"),
    ("100,B,,,", "100,C,,,", 6, "spacecraft", "declared in '# spacecraft:' (A, B)"),
    ("100,B,,,", "100,,,,", 6, "spacecraft", "every row names its spacecraft"),
    ("0.01,A,B,rx1", "0.01,A,,rx1", 8, "tx_spacecraft", "a spacecraft id"),
    ("100,B,,,", "100,B b,,,", 6, "spacecraft", "letters, digits"),
])
def test_bad_rows_name_line_column_and_expectation(tmp_path, old, new, line, column, words):
    with pytest.raises(InputFormatError) as e:
        _read(tmp_path, HEAD + ROWS.replace(old, new, 1))
    msg = str(e.value)
    assert f"line {line}" in msg and f"column '{column}'" in msg and words in msg, msg


def test_bad_rows_can_be_dropped_with_a_count(tmp_path):
    log = _read(tmp_path, HEAD + ROWS.replace("rx1,tx0", "rx9,tx0"), on_bad_row="drop")
    assert log.dropped == {"unknown_antenna": 1} and len(log) == 4


@pytest.mark.parametrize("decl,words", [
    ("# antenna: A rx1 0.5 0.5\n", "<x_m> <y_m> <z_m>"),
    ("# antenna: A rx1 0.5 0.5 nan\n", "<x_m> <y_m> <z_m>"),
    ("# antenna: C rx1 0 0 0\n", "declared spacecraft"),
    ("# antenna: A rx1 0 0 0\n", "declared once"),
    ("# spacecraft: A A\n", "each spacecraft id once"),
])
def test_bad_declarations(tmp_path, decl, words):
    with pytest.raises(InputFormatError) as e:
        _read(tmp_path, decl + HEAD + ROWS)
    assert words in str(e.value)


def test_isl_rows_need_the_spacecraft_column(tmp_path):
    with pytest.raises(InputFormatError) as e:
        _read(tmp_path, "epoch,kind,x,y,z,sigma\n2025-01-01T00:00:00Z,isl_pseudorange,1000,,,0.01\n")
    assert "column 'spacecraft'" in str(e.value)


def test_log_from_arrays_names_and_errors():
    kw = dict(kind=["earth_direction", "isl_pseudorange"], xyz=[[0, 0, 1], [1000, np.nan, np.nan]],
              sigma=[1e-4, 0.01])
    log = log_from_arrays("2025-01-01T00:00:00Z", [0, 0], extra={
        "spacecraft": ["S1", "S2"], "tx_spacecraft": [None, "S1"]}, **kw)
    assert log.spacecraft == ("S1", "S2")
    with pytest.raises(UserError, match="other than the receiving"):
        log_from_arrays("2025-01-01T00:00:00Z", [0, 0], extra={
            "spacecraft": ["S1", "S1"], "tx_spacecraft": [None, "S1"]}, **kw)
    with pytest.raises(UserError, match="antenna declared"):
        log_from_arrays("2025-01-01T00:00:00Z", [0, 0], extra={
            "spacecraft": ["S1", "S2"], "tx_spacecraft": [None, "S1"],
            "rx_antenna": [None, "a1"]}, **kw)
