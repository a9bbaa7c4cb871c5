"""Tests of fgnav.time: ISO-8601 UTC parsing/formatting, seconds from an epoch, J2000 seconds."""

import numpy as np
import pytest

from fgnav.time import add_seconds, format_utc, j2000_seconds, parse_utc, seconds_since


def test_parse_utc_forms():
    t = parse_utc("2024-03-01T12:34:56.123456789Z")
    assert t.dtype == np.dtype("datetime64[ns]")
    assert t == np.datetime64("2024-03-01T12:34:56.123456789", "ns")
    assert parse_utc("2024-03-01T12:34:56Z") == np.datetime64("2024-03-01T12:34:56", "ns")
    assert parse_utc("2024-03-01 12:34:56.5+00:00") == np.datetime64("2024-03-01T12:34:56.500", "ns")
    assert parse_utc("2024-03-01T12:34Z") == np.datetime64("2024-03-01T12:34:00", "ns")
    assert parse_utc("2024-02-29T00:00:00.1Z") == np.datetime64("2024-02-29T00:00:00.100", "ns")


@pytest.mark.parametrize("bad", ["", "2024-03-01", "2024-13-01T00:00:00Z", "2023-02-29T00:00:00Z",
                                 "2024-03-01T24:00:00Z", "2016-12-31T23:59:60Z",
                                 "2024-03-01T00:00:00+01:00", "yesterday", "2024-03-01T00:00:00.1234567891Z"])
def test_parse_utc_rejects_with_the_text(bad):
    with pytest.raises(ValueError) as exc:
        parse_utc(bad)
    assert repr(bad) in str(exc.value)


def test_format_round_trip_and_rounding():
    s = "2031-12-31T23:59:59.999999Z"
    assert format_utc(parse_utc(s)) == s
    assert format_utc(parse_utc("2024-01-01T00:00:00Z")) == "2024-01-01T00:00:00.000000Z"
    assert format_utc(parse_utc("2024-01-01T00:00:00.0000015Z")) == "2024-01-01T00:00:00.000002Z"
    assert format_utc(parse_utc("2024-12-31T23:59:59.9999996Z")) == "2025-01-01T00:00:00.000000Z"
    arr = np.array([parse_utc("2024-01-01T00:00:00Z"), parse_utc("2024-01-01T00:00:01.5Z")])
    assert format_utc(arr) == ["2024-01-01T00:00:00.000000Z", "2024-01-01T00:00:01.500000Z"]


def test_seconds_since_and_add_seconds_are_inverse():
    e0 = parse_utc("2024-06-30T23:00:00Z")
    t_s = np.array([-0.5, 0.0, 0.1, 3600.0, 86400.0 * 365 + 0.123456789])
    t64 = add_seconds(e0, t_s)
    assert t64.dtype == np.dtype("datetime64[ns]")
    assert t64[3] == parse_utc("2024-07-01T00:00:00Z")
    np.testing.assert_allclose(seconds_since(t64, e0), t_s, rtol=0, atol=1e-9)
    assert seconds_since(parse_utc("2024-07-01T00:00:00.000000001Z"), e0) == pytest.approx(3600.000000001, abs=1e-12)


def test_j2000_seconds():
    # J2000.0 = 2000-01-01T12:00:00 TT = 11:58:55.816 UTC with TT - UTC = 64.184 s in 2000;
    # with the documented fixed TT - UTC = 69.184 s it is 11:58:50.816 UTC.
    assert j2000_seconds(parse_utc("2000-01-01T11:58:50.816Z")) == pytest.approx(0.0, abs=1e-9)
    assert j2000_seconds(parse_utc("2000-01-02T11:58:50.816Z")) == pytest.approx(86400.0, abs=1e-9)
    t = np.array([parse_utc("2024-01-01T00:00:00Z"), parse_utc("2024-01-01T00:01:00Z")])
    j = j2000_seconds(t)
    assert j.shape == (2,) and j[1] - j[0] == pytest.approx(60.0, abs=1e-9)
    # 2024-01-01T00:00:00 UTC: 8766 days - 12 h after J2000 noon, plus 69.184 s
    assert j[0] == pytest.approx(8766 * 86400.0 - 43200.0 + 69.184, abs=1e-6)
