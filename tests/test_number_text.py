"""The compiled number writer (fgnav.io.number_text) writes exactly what Python's ``%`` writes:
every style the outputs use, ties, powers of ten, extremes, non-finite numbers, and whole
OEM files."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fgnav.io import number_text
from fgnav.io.number_text import format_numbers, render_rows

STYLES = [("f", 9), ("f", 12), ("f", 6), ("f", 0), ("f", 17), ("e", 16), ("e", 3), ("e", 0),
          ("g", 6), ("g", 9), ("g", 1), ("g", 0), ("g", 17)]


def _python(values, style, precision):
    return [f"%.{precision}{style}" % v for v in np.asarray(values, float).tolist()]


def _hard_values(rng) -> np.ndarray:
    """Numbers where correct rounding is hardest: exact ties of %.9f (odd multiples of 2**-10)
    and of %.0f/%.6f, powers of ten and their neighbours (the exponent of "e" and "g" and
    their carry, e.g. 9.9999999999999998e-20 for the double nearest 1e-19), integers, and
    the extremes that the kernel leaves to Python."""
    k = rng.integers(-30, 30, 20_000)
    p10 = 10.0 ** k
    return np.concatenate([
        rng.integers(-10**7, 10**7, 20_000) / 1024.0,          # ties of %.9f
        rng.integers(-10**7, 10**7, 20_000) / 2.0,             # ties of %.0f
        rng.integers(-10**9, 10**9, 20_000) / 128.0,           # ties of %.6f
        p10, np.nextafter(p10, 0.0), np.nextafter(p10, np.inf),
        9.5 * p10, 0.95 * p10, 99999.95 * p10,
        rng.integers(-2**53, 2**53, 2_000).astype(float),
        rng.standard_normal(50_000) * 10.0 ** rng.integers(-25, 25, 50_000),
        [0.0, -0.0, 5e-324, -1e-310, 2.2e-308, 1e-281, 1e-279, 1e279, 1e281, 1.7e308,
         -1.7e308, 2.0**62, 2.0**62 / 1e9, 4.6e9, 5e18, 0.5, 1.5, 2.5, -0.5, 0.125,
         123456.5, 999999.5, 9.9999999999999995, 0.0001, 9.99999e-5, 1e16, 1e17,
         np.nan, -np.nan, np.inf, -np.inf],
    ])


@pytest.mark.parametrize("style,precision", STYLES)
def test_the_kernel_writes_what_python_writes_on_hard_numbers(style, precision):
    values = _hard_values(np.random.default_rng(precision + 100 * ord(style)))
    got = format_numbers(values, style, precision, compiled=True)
    want = _python(values, style, precision)
    bad = [(v, g, w) for v, g, w in zip(values.tolist(), got, want) if g != w]
    assert not bad, f"{len(bad)} of {len(values)} differ, e.g. {bad[:3]}"


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=True),
                min_size=1, max_size=40),
       st.sampled_from(STYLES))
def test_the_kernel_writes_what_python_writes_on_any_float(values, style):
    assert format_numbers(values, *style, compiled=True) == _python(values, *style)


def test_rows_with_constant_per_row_and_indexed_texts_match_a_join():
    rng = np.random.default_rng(3)
    N = 257
    values = rng.standard_normal((N, 3)) * 10.0 ** rng.integers(-8, 8, (N, 3))
    per_row = [f"E{i:05d} " for i in range(N)]
    table, index = [",a,", ",bb,", ",ccc,"], rng.integers(0, 3, N)
    styles = [("f", 9), ("e", 16), ("g", 6)]
    texts = [per_row, (table, index), " ", "\n"]
    want = "".join(f"{per_row[i]}{values[i, 0]:.9f}{table[index[i]]}{values[i, 1]:.16e} "
                   f"{values[i, 2]:.6g}\n" for i in range(N)).encode()
    assert render_rows(texts, values, styles, compiled=True) == want
    assert render_rows(texts, values, styles, compiled=False) == want
    assert render_rows(["a", ([""], []), " ", "\n"], values[:0], styles, compiled=True) == b""


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match="2 columns need 3 texts"):
        render_rows(["", ""], np.zeros((2, 2)), [("f", 3)] * 2)
    with pytest.raises(ValueError, match="has 1 rows, the values 2"):
        render_rows([["a"], "\n"], np.zeros((2, 1)), [("f", 3)])
    with pytest.raises(ValueError, match="needs 2 indices into its 1 strings"):
        render_rows([(["a"], [0, 1]), "\n"], np.zeros((2, 1)), [("f", 3)])


def test_an_oem_written_by_the_kernel_equals_one_written_by_python(tmp_path, monkeypatch):
    """Whole files: the states (%.9f, %.12f) and covariances (%.16e) of a written OEM are the
    same text whichever writes them."""
    from fgnav.io.oem import write_oem

    rng = np.random.default_rng(5)
    N = 300
    t_s = np.arange(N) * 1.5
    x = rng.standard_normal((N, 6)) * [4e7, 4e7, 4e7, 3e3, 3e3, 3e3]
    A = rng.standard_normal((N, 6, 6)) * 10.0 ** rng.integers(-6, 4, (N, 1, 1))
    P = A @ np.swapaxes(A, 1, 2)
    P[7] = np.nan   # an epoch without covariance
    texts = {}
    for compiled in (True, False):
        monkeypatch.setattr(number_text, "_PYTHON_BELOW", 0 if compiled else 10**12)
        monkeypatch.setattr(number_text, "numba_loaded", lambda: compiled)
        path = tmp_path / f"{compiled}.oem"
        write_oem(path, "2025-03-01T00:00:00Z", t_s, x, P,
                  creation_date=np.datetime64("2025-03-02T00:00:00"))
        texts[compiled] = path.read_bytes()
    assert texts[True] == texts[False]
    assert b"COV_REF_FRAME = EME2000" in texts[True] and texts[True].count(b"EPOCH =") == N - 1
