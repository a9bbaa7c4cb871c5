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
                                 "2024-03-01T24:00:00Z", "2017-12-31T23:59:60Z",
                                 "2016-12-30T23:59:60Z", "2016-12-31T23:58:60Z", "2016-12-31T23:59:61Z",
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
    # J2000.0 = 2000-01-01T12:00:00 TT = 11:58:55.816 UTC (TAI - UTC = 32 s in 2000, TT - TAI
    # = 32.184 s): exact now that the leap-second table gives TAI - UTC at every date.
    assert j2000_seconds(parse_utc("2000-01-01T11:58:55.816Z")) == pytest.approx(0.0, abs=1e-9)
    assert j2000_seconds(parse_utc("2000-01-02T11:58:55.816Z")) == pytest.approx(86400.0, abs=1e-9)
    t = np.array([parse_utc("2024-01-01T00:00:00Z"), parse_utc("2024-01-01T00:01:00Z")])
    j = j2000_seconds(t)
    assert j.shape == (2,) and j[1] - j[0] == pytest.approx(60.0, abs=1e-9)
    # 2024-01-01T00:00:00 UTC: 8766 days - 12 h after J2000 noon, plus TT - UTC = 69.184 s
    assert j[0] == pytest.approx(8766 * 86400.0 - 43200.0 + 69.184, abs=1e-6)
    # and 2024-01-01 minus 2000-01-01T11:58:55.816 UTC is 8766 d - 11:58:55.816 + 5 leap seconds
    # (2005, 2008, 2012, 2015, 2016 ends)
    assert j[0] == pytest.approx(8766 * 86400.0 - (11 * 3600 + 58 * 60 + 55.816) + 5.0, abs=1e-6)


# ------------------------------------------------------------------ leap seconds
def test_leap_second_is_its_own_instant_and_round_trips():
    for s in ("2016-12-31T23:59:60.000000Z", "2016-12-31T23:59:60.500000Z",
              "2015-06-30T23:59:60.999999Z", "1972-06-30T23:59:60.250000Z"):
        assert format_utc(parse_utc(s)) == s
    t59, t60, t00 = (parse_utc(s) for s in ("2016-12-31T23:59:59Z", "2016-12-31T23:59:60Z",
                                            "2017-01-01T00:00:00Z"))
    assert seconds_since(t60, t59) == 1.0 and seconds_since(t00, t60) == 1.0
    assert format_utc(parse_utc("2016-12-31T23:59:60.123456789Z"), "ns") == \
        "2016-12-31T23:59:60.123456789Z"
    # rounding to the microsecond carries into the leap second, and out of it
    assert format_utc(parse_utc("2016-12-31T23:59:59.9999996Z")) == "2016-12-31T23:59:60.000000Z"
    assert format_utc(parse_utc("2016-12-31T23:59:60.9999996Z")) == "2017-01-01T00:00:00.000000Z"


@pytest.mark.parametrize("a, b, elapsed_s", [
    ("2016-12-31T23:59:59Z", "2017-01-01T00:00:01Z", 3.0),     # across the last leap second
    ("2016-12-31T23:59:60.5Z", "2017-01-01T00:00:00Z", 0.5),
    ("2015-06-30T12:00:00Z", "2015-07-01T12:00:00Z", 86401.0),
    ("2016-06-30T12:00:00Z", "2016-07-01T12:00:00Z", 86400.0),  # no leap second that day
    ("1999-01-01T00:00:00Z", "2017-01-01T00:00:00Z",            # 6575 days + 5 leap seconds
     6575 * 86400.0 + 5.0),
    ("1971-01-01T00:00:00Z", "2017-01-01T00:00:00Z", 16802 * 86400.0 + 27.0),
])
def test_elapsed_seconds_count_leap_seconds(a, b, elapsed_s):
    assert seconds_since(parse_utc(b), parse_utc(a)) == elapsed_s


def test_add_seconds_walks_through_the_leap_second():
    e0 = parse_utc("2016-12-31T23:59:58.5Z")
    assert format_utc(add_seconds(e0, np.arange(4.0))) == [
        "2016-12-31T23:59:58.500000Z", "2016-12-31T23:59:59.500000Z",
        "2016-12-31T23:59:60.500000Z", "2017-01-01T00:00:00.500000Z"]


def test_every_table_entry_is_one_second_and_no_other_day_has_second_60():
    from fgnav.time import LEAP_SECONDS

    for (date, off), (_, prev) in zip(LEAP_SECONDS[1:], LEAP_SECONDS[:-1]):
        assert off - prev == 1
        day_before = str(np.datetime64(date, "D") - np.timedelta64(1, "D"))
        t = parse_utc(f"{day_before}T23:59:60Z")
        assert format_utc(t) == f"{day_before}T23:59:60.000000Z"
        assert seconds_since(parse_utc(f"{date}T00:00:00Z"), parse_utc(f"{day_before}T23:59:59Z")) == 2.0
    assert len(LEAP_SECONDS) == 28 and LEAP_SECONDS[-1] == ("2017-01-01", 37)


def test_years_outside_datetime64_range_are_a_range_error():
    from fgnav.time import UtcRangeError

    for s in ("2300-01-01T00:00:00Z", "1600-01-01T00:00:00Z"):
        with pytest.raises(UtcRangeError, match="1678..2261"):
            parse_utc(s)


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from fgnav.time import LEAP_SECONDS  # noqa: E402

_NEAR_LEAPS = [parse_utc(f"{d}T00:00:00Z").astype(np.int64) for d, _ in LEAP_SECONDS]


@settings(max_examples=400, deadline=None)
@given(st.one_of(
    st.integers(int(parse_utc("1960-01-01T00:00:00Z").astype(np.int64)) // 1000,
                int(parse_utc("2100-01-01T00:00:00Z").astype(np.int64)) // 1000),
    st.builds(lambda base, d: int(base) // 1000 + d, st.sampled_from(_NEAR_LEAPS),
              st.integers(-3_000_000, 3_000_000))))
def test_format_parse_round_trip_at_every_microsecond(us):
    """Any instant (1 µs grid), near a leap second or not: format -> parse is the identity,
    and the scalar and array formatters agree."""
    t = np.datetime64(us * 1000, "ns")
    s = format_utc(t)
    assert parse_utc(s) == t
    t1 = t + np.timedelta64(1, "s")
    assert format_utc(np.array([t, t1])) == [s, format_utc(t1)]
    assert format_utc(t, "ns") == s[:-1] + "000Z"
