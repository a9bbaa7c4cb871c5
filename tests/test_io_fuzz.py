"""Fuzz the readers: random bytes and corruptions of valid CSV / OEM / TDM files.

The contract: a reader either returns a valid result or raises
:class:`fgnav.errors.InputFormatError` (documented warnings allowed); never any other
exception, never a hang (hypothesis deadline). A successful read must satisfy the
format's invariants (finite values, sigma > 0, unit directions, sorted epochs).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fgnav.errors import InputFormatError
from fgnav.io.log_csv import DIRECTION_KINDS, read_log
from fgnav.io.oem import read_oem, write_oem
from fgnav.io.tdm import read_tdm
from fgnav.time import parse_utc

FUZZ = settings(max_examples=300, deadline=1000,
                suppress_health_check=[HealthCheck.too_slow])

CSV = b"""\
# fuzz base
epoch,kind,x,y,z,sigma,gamma,sigma_model_m
2024-03-01T00:00:00Z,prior_position,7000000,-12.5,3250,1000,,
2024-03-01T00:00:00Z,prior_velocity,0,7546.05,1.5,1,,
2024-03-01T00:00:00Z,earth_direction,-0.6,0.8,0,1e-4,,
2024-03-01T00:00:10.5Z,limb_radius,1.1,6378137,,2e-4,,
2024-03-01T00:00:10.5Z,earth_direction_body,0,0,-1,1e-4,,
2024-03-01T00:00:10.5Z,attitude,0.1,-0.2,0.3,5e-5,,
2024-03-01T00:00:20Z,altitude,621000,6378137,,30,,
2024-03-01T00:00:20Z,sun_direction_body,1,0,0,1e-3,,
2024-03-01T00:00:30Z,refraction,0,0.6,0.8,1e-6,1.5e-4,250
"""

TDM = b"""\
CCSDS_TDM_VERS = 2.0
CREATION_DATE = 2024-061T12:00:00
ORIGINATOR = FGNAV-TEST
META_START
COMMENT sigma_deg=0.01
TIME_SYSTEM = UTC
PARTICIPANT_1 = FGNAV-SAT
PARTICIPANT_2 = EARTH
PATH = 2,1
ANGLE_TYPE = RADEC
REFERENCE_FRAME = EME2000
META_STOP
DATA_START
ANGLE_1 = 2024-03-01T00:00:00 123.456
ANGLE_2 = 2024-03-01T00:00:00 -12.5
ANGLE_1 = 2024-03-01T00:00:10.5 359.9
ANGLE_2 = 2024-03-01T00:00:10.5 89.0
DATA_STOP
"""


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


@pytest.fixture(scope="module")
def oem_bytes(fuzz_dir):
    rng = np.random.default_rng(11)
    t = np.arange(3) * 60.0
    x = rng.normal(size=(3, 6)) * [7e6, 7e6, 7e6, 7e3, 7e3, 7e3]
    A = rng.normal(size=(3, 6, 6))
    P = A @ np.swapaxes(A, 1, 2)
    p = fuzz_dir / "base.oem"
    write_oem(p, parse_utc("2024-03-01T00:00:00Z"), t, x, P,
              creation_date=parse_utc("2024-03-02T00:00:00Z"))
    return p.read_bytes()


@st.composite
def corrupted(draw, base: bytes):
    """One corruption of ``base``: a byte changed, a line dropped / duplicated, truncation."""
    lines = base.split(b"\n")
    how = draw(st.sampled_from(["byte", "char", "drop", "dup", "truncate", "swap"]))
    if how == "byte":
        i = draw(st.integers(0, len(base) - 1))
        return base[:i] + bytes([draw(st.integers(0, 255))]) + base[i + 1:]
    if how == "char":  # characters that matter to the formats
        i = draw(st.integers(0, len(base) - 1))
        c = draw(st.sampled_from(list(b",.-+eE0123456789TZ:= \n\r#_xn")))
        return base[:i] + bytes([c]) + base[i + 1:]
    k = draw(st.integers(0, len(lines) - 1))
    if how == "drop":
        return b"\n".join(lines[:k] + lines[k + 1:])
    if how == "dup":
        return b"\n".join(lines[:k + 1] + lines[k:])
    if how == "swap":
        j = draw(st.integers(0, len(lines) - 1))
        lines[k], lines[j] = lines[j], lines[k]
        return b"\n".join(lines)
    return base[:draw(st.integers(0, len(base)))]


def _check_log_invariants(log):
    M = len(log.t_s)
    assert M >= 1
    assert log.xyz.shape == (M, 3) and log.sigma.shape == (M,) and log.line.shape == (M,)
    assert np.all(np.isfinite(log.t_s)) and np.all(np.diff(log.t_s) >= 0)
    assert np.all(np.isfinite(log.sigma)) and np.all(log.sigma > 0)
    assert not np.any(np.isinf(log.xyz))
    for kind in DIRECTION_KINDS:
        i = log.select(kind)
        if len(i):
            assert np.all(np.abs(np.linalg.norm(log.xyz[i], axis=1) - 1.0) <= 1e-12)


def _read(reader, path, data, **kw):
    path.write_bytes(data)
    try:
        return reader(path, **kw)
    except InputFormatError as e:
        assert str(path) in str(e)
        return None


@FUZZ
@given(data=st.binary(max_size=1500))
def test_random_bytes_csv(fuzz_dir, data):
    log = _read(read_log, fuzz_dir / "r.csv", data)
    if log is not None:
        _check_log_invariants(log)


@FUZZ
@given(text=st.text(alphabet="epochkindxyzsigma,._-+0123456789TZ:#\n ", max_size=400))
def test_random_csv_like_text(fuzz_dir, text):
    data = ("epoch,kind,x,y,z,sigma\n" + text).encode()
    for mode in ("error", "drop"):
        log = _read(read_log, fuzz_dir / "t.csv", data, on_bad_row=mode)
        if log is not None:
            _check_log_invariants(log)


@FUZZ
@given(data=corrupted(CSV), mode=st.sampled_from(["error", "drop"]))
def test_corrupted_csv(fuzz_dir, data, mode):
    log = _read(read_log, fuzz_dir / "c.csv", data, on_bad_row=mode)
    if log is not None:
        _check_log_invariants(log)


@FUZZ
@given(data=st.data())
def test_corrupted_oem(fuzz_dir, oem_bytes, data):
    d = _read(read_oem, fuzz_dir / "c.oem", data.draw(corrupted(oem_bytes)))
    if d is not None:
        N = len(d.t_s)
        assert N >= 1 and d.x_eci.shape == (N, 6) and np.all(np.isfinite(d.x_eci))
        assert d.P_eci is None or d.P_eci.shape == (N, 6, 6)


@FUZZ
@given(data=st.binary(max_size=1500))
def test_random_bytes_oem_tdm(fuzz_dir, data):
    _read(read_oem, fuzz_dir / "r.oem", data)
    log = _read(read_tdm, fuzz_dir / "r.tdm", data)
    if log is not None:
        _check_log_invariants(log)


@FUZZ
@given(data=corrupted(TDM))
def test_corrupted_tdm(fuzz_dir, data):
    log = _read(read_tdm, fuzz_dir / "c.tdm", data)
    if log is not None:
        _check_log_invariants(log)
        assert math.isclose(log.sigma[0], math.radians(0.01)) or log.sigma[0] > 0


def test_bases_are_valid(fuzz_dir, oem_bytes):
    """The corruptions start from valid files (else the fuzz tests would test nothing)."""
    (fuzz_dir / "b.csv").write_bytes(CSV)
    assert len(read_log(fuzz_dir / "b.csv")) == 9
    (fuzz_dir / "b.tdm").write_bytes(TDM)
    assert len(read_tdm(fuzz_dir / "b.tdm")) == 2
    (fuzz_dir / "b.oem").write_bytes(oem_bytes)
    assert read_oem(fuzz_dir / "b.oem").P_eci.shape == (3, 6, 6)


def test_pinned_regressions(fuzz_dir, oem_bytes):
    """Cases the fuzzers found: overflow on unit conversion / norms (a RuntimeWarning, an
    error under ``filterwarnings = error``) and years that datetime64[ns] wraps silently."""
    lines = oem_bytes.decode().splitlines()
    i = lines.index("COV_REF_FRAME = EME2000") + 2
    lines[i] = lines[i].split()[0] + " 8.2e306"                         # km^2 -> m^2 overflows
    assert _read(read_oem, fuzz_dir / "p.oem", ("\n".join(lines) + "\n").encode()) is None
    head = b"epoch,kind,x,y,z,sigma\n"
    for row, valid in ((b"2024-03-01T00:00:00Z,earth_direction,1e200,1e200,0,1e-4", False),
                       # absurd: refused beyond 1e13 m (its square overflows in the solvers)
                       (b"2024-03-01T00:00:00Z,altitude,1.7e308,1.7e308,,1", False),
                       (b"2300-03-01T00:00:00Z,earth_direction,0,0,1,1e-4", False)):
        assert (_read(read_log, fuzz_dir / "p.csv", head + row + b"\n") is not None) == valid
