"""The one typed-TOML validator (fgnav.io.toml_schema): its scalar checks, both schema
writings (spec tuples with line numbers, dataclass annotations), and that the scenario files
and the campaign studies both go through it."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import pytest

from fgnav.errors import InputFormatError
from fgnav.io import toml_schema as ts


def test_as_number_refuses_booleans_nan_infinity_and_floats_for_integers():
    assert ts.as_number(3) == 3.0 and isinstance(ts.as_number(3), float)
    assert ts.as_number(3, integer=True) == 3 and isinstance(ts.as_number(3, integer=True), int)
    for bad in (True, False, "1", None, [1.0], math.nan, math.inf, -math.inf):
        assert ts.as_number(bad) is None, bad
    assert ts.as_number(2.0, integer=True) is None


@pytest.mark.parametrize("x, ok", [(0.0, False), (1e-12, True), (10.0, True), (10.5, False)])
def test_within_keeps_open_and_closed_ends(x, ok):
    assert ts.within(x, 0.0, 10.0, lo_in=False, hi_in=True) is ok
    assert ts.within(x, -math.inf, math.inf, False, False)


TEXT = """name = "x"
[[sensor]]
kind = "a"
[[sensor]]
kind = "b"
sigma_deg = -1
[ranging]
sigma_m = 0.01
"""


def test_a_spec_error_names_the_line_of_the_key_in_the_right_array_element():
    src = ts.TomlSource("f.toml", TEXT, array_tables=("sensor",))
    spec = ("number", "deg", 0.0, 45.0, False, True)
    with pytest.raises(InputFormatError) as exc:
        ts.check_value(src, "sensor", 1, "sigma_deg", -1, spec, "sensor[2].sigma_deg")
    msg = str(exc.value)
    assert "f.toml" in msg and "6" in msg and "sensor[2].sigma_deg" in msg
    assert "a finite number > 0 deg and <= 45 deg" in msg
    assert src.line_of("ranging", "sigma_m") == 8 and src.line_of("sensor", None, 1) == 4
    with pytest.raises(InputFormatError, match="known: kind, sigma_deg"):
        ts.keyed(src, "sensor", 1, {"kind": "b", "sigma_m": 1.0},
                 {"kind": ("str",) + (None,) * 5, "sigma_deg": spec}, "sensor[2]")


@dataclass(frozen=True)
class _Ref:
    rate_hz: float = field(default=1.0, metadata={"positive": True})
    count: int = 1
    names: tuple[str, ...] = ("a",)


def test_typed_object_checks_keys_in_file_order_types_and_positivity():
    obj = ts.typed_object(_Ref, {"rate_hz": 2, "names": ["x", "y"]}, "s.toml", "reference.")
    assert obj == _Ref(2.0, 1, ("x", "y")) and isinstance(obj.rate_hz, float)
    with pytest.raises(InputFormatError, match=r"reference\.rate_hz.*a number > 0"):
        ts.typed_object(_Ref, {"rate_hz": 0.0}, "s.toml", "reference.")
    with pytest.raises(InputFormatError, match=r"reference\.count.*an integer"):
        ts.typed_object(_Ref, {"count": 1.5, "bogus": 1}, "s.toml", "reference.")
    with pytest.raises(InputFormatError, match=r"reference\.bogus.*one of the keys"):
        ts.typed_object(_Ref, {"bogus": 1, "count": 1.5}, "s.toml", "reference.")


def test_scenarios_and_studies_use_the_one_validator():
    import fgnav.campaign.spec as spec
    import fgnav.scenarios as scenarios

    assert spec.typed_value is ts.typed_value and spec.typed_object is ts.typed_object
    assert scenarios.check_value is ts.check_value and scenarios.TomlSource is ts.TomlSource
