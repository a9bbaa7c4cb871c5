"""``fgnav smooth`` end to end on mutated logs and options (hypothesis).

Whatever the log and the options, the command ends in one of two ways: exit 0 (or 3 with
``--strict``) with a summary.json that carries an integrity verdict, or exit 2 with one
``fgnav: error:`` message. Never a traceback, never a hang.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from fgnav.cli import main
from fgnav.io.log_csv import write_log
from fgnav.simulate import faults as F

KINDS = ["prior_position", "prior_velocity", "earth_direction", "limb_radius", "altitude",
         "attitude", "earth_direction_body", "refraction", "bogus", "star_direction_body",
         "body_star_angle", "limb_star_angle"]


_CLEAN: list[str] = []


def clean_lines(tmp_path) -> list[str]:
    """A short clean GEO log (direction + limb, 31 epochs), as lines; made once."""
    if not _CLEAN:
        log, _, _ = F.clean("geo-limb", duration_h=0.5, step_s=120.0)
        write_log(tmp_path / "clean.csv", log)
        _CLEAN.extend((tmp_path / "clean.csv").read_text().splitlines())
    return list(_CLEAN)


def _mutate_line(line: str, data) -> str:
    if line.startswith("#") or line.startswith("epoch,"):
        return line
    cols = line.split(",")
    if len(cols) < 6:  # a line an earlier mutation already garbled
        return line
    op = data.draw(st.sampled_from(["number", "nan", "empty", "kind", "epoch", "flip", "sigma",
                                    "extra", "garbage"]))
    if op == "number":
        i = data.draw(st.integers(2, len(cols) - 1))
        cols[i] = repr(data.draw(st.floats(allow_nan=False, allow_infinity=True, width=64)))
    elif op == "nan":
        cols[data.draw(st.integers(0, len(cols) - 1))] = "nan"
    elif op == "empty":
        cols[data.draw(st.integers(0, len(cols) - 1))] = ""
    elif op == "kind":
        cols[1] = data.draw(st.sampled_from(KINDS))
    elif op == "epoch":
        cols[0] = data.draw(st.sampled_from(["2025-03-01T00:00:60Z", "2016-12-31T23:59:60Z",
                                             "2025-02-30T00:00:00Z", "yesterday", "2025-03-01",
                                             "2025-03-21T00:00:00.000000Z"]))
    elif op == "flip":
        cols[2:5] = [c[1:] if c.startswith("-") else "-" + c for c in cols[2:5]]
    elif op == "sigma":
        cols[5] = data.draw(st.sampled_from(["0", "-1", "1e-300", "1e-12", "1e300", "inf"]))
    elif op == "extra":
        cols.append("1.0")
    else:
        return data.draw(st.text(max_size=40).filter(lambda s: "\n" not in s and "\r" not in s))
    return ",".join(cols)


METHOD_OPTIONS = {  # options each method uses: two valid values first, then bad ones
    "--robust": (["batch", "isam2", "fixed-lag"], ["huber", "cauchy", "none"]),
    "--gate": (["isam2", "fixed-lag", "ekf"], ["0.9999", "0.99", "1.0", "0", "nan"]),
    "--lag-s": (["fixed-lag"], ["300", "60", "0", "-5", "nan"]),
    "--process-noise": (["batch", "isam2", "fixed-lag", "ekf"], ["1e-12", "1e-8", "0", "inf"]),
}


@st.composite
def options(draw):
    """Mostly options the method uses (so most runs reach the solver), sometimes one it does
    not use or a bad value (which must be refused with exit 2)."""
    method = draw(st.sampled_from(["batch", "isam2", "fixed-lag", "ekf"]))
    opts = ["--method", method]
    for flag, (methods, values) in METHOD_OPTIONS.items():
        if method in methods and draw(st.integers(0, 2)) == 0:
            opts += [flag, draw(st.sampled_from(values[:2] if draw(st.integers(0, 3)) else values))]
        elif method not in methods and draw(st.integers(0, 9)) == 0:
            opts += [flag, values[0]]
    for flag in ("--third-body", "--strict", "--ignore-prior"):
        if draw(st.integers(0, 3)) == 0:
            opts.append(flag)
    return opts


# In CI (CI=true) the examples are derandomized, so a run is reproducible and a red CI names
# a fixed example; locally each run explores new ones (--hypothesis-seed=N to repeat one):
# 120 local runs found the four tracebacks pinned by the tests below.
@settings(max_examples=60, deadline=None, derandomize=os.environ.get("CI") == "true",
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data(), opts=options())
def test_smooth_end_to_end_never_a_traceback(tmp_path, capsys, data, opts):
    text = mutated_text(clean_lines(tmp_path), data)
    log = tmp_path / "log.csv"
    log.write_text(text)
    out = tmp_path / "out"
    rc = main(["smooth", str(log), "--out", str(out), "--quiet", *opts])
    assert_smooth_contract(rc, capsys.readouterr().err, out)


def mutated_text(lines: list[str], data) -> str:
    """The log's lines mutated as a damaged file would be: a block dropped (a gap), a row
    duplicated, up to four lines' values mutated (:func:`_mutate_line`), the text truncated."""
    n = len(lines)
    if data.draw(st.booleans()):
        a = data.draw(st.integers(2, n - 1))
        b = data.draw(st.integers(a, n))
        del lines[a:b]
    if data.draw(st.booleans()) and len(lines) > 3:
        i = data.draw(st.integers(2, len(lines) - 1))
        lines.insert(i, lines[i])
    for _ in range(data.draw(st.integers(0, 4))):
        if len(lines) > 2:
            i = data.draw(st.integers(2, len(lines) - 1))
            lines[i] = _mutate_line(lines[i], data)
    text = "\n".join(lines) + "\n"
    if data.draw(st.booleans()):
        text = text[:data.draw(st.integers(0, len(text)))]
    return text


ROUTES = {   # the routes added last (the integrity issue): a short clean log of each
    "raw-star": ["geo-limb", "--raw-stars", "--duration-h", "0.5", "--step-s", "120"],
    "heliocentric": ["mars-cruise", "--duration-h", "72"],
}
_ROUTE_LINES: dict[str, list[str]] = {}


def route_lines(tmp_path, route: str) -> list[str]:
    """A clean log of ``route`` (:data:`ROUTES`) as lines; simulated once."""
    if route not in _ROUTE_LINES:
        d = tmp_path / route
        assert main(["simulate", *ROUTES[route], "--out", str(d), "--quiet"]) == 0
        _ROUTE_LINES[route] = (d / "measurements.csv").read_text().splitlines()
    return list(_ROUTE_LINES[route])


@st.composite
def route_options(draw, route: str):
    """:func:`options`, with the route's own options: for raw stars the attitude estimated
    (random walk or constant rate) or taken from the stars, for the cruise sometimes
    ``--no-aberration``."""
    opts = draw(options())
    if route == "raw-star" and draw(st.booleans()):
        opts += ["--attitude", "estimate", "--attitude-motion",
                 draw(st.sampled_from(["random-walk", "constant-rate"]))]
    if route == "heliocentric" and draw(st.integers(0, 3)) == 0:
        opts.append("--no-aberration")
    return opts


@pytest.mark.parametrize("route", list(ROUTES))
@settings(max_examples=25, deadline=None, derandomize=os.environ.get("CI") == "true",
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data())
def test_smooth_end_to_end_on_the_routes_added_last(tmp_path, capsys, route, data):
    """The same contract on a raw-star log (star_direction_body rows, attitude from the stars
    or estimated) and on a heliocentric log (# centre: sun, the angle kinds): the integrity
    issue's fuzz, extended to the routes added last (formations: tests/test_formation_fuzz.py)."""
    opts = data.draw(route_options(route))
    text = mutated_text(route_lines(tmp_path, route), data)
    log = tmp_path / "log.csv"
    log.write_text(text)
    out = tmp_path / "out"
    rc = main(["smooth", str(log), "--out", str(out), "--quiet", *opts])
    assert_smooth_contract(rc, capsys.readouterr().err, out)


def assert_smooth_contract(rc: int, err: str, out) -> None:
    """Exit 0 (3 with --strict: the verdict not ok) with a verdict in summary.json, or exit 2
    with one error line; never a traceback."""
    event(f"exit {rc}")
    assert "Traceback" not in err
    assert rc in (0, 2, 3), (rc, err)
    if rc == 2:
        assert err.startswith("fgnav: error:"), err
    else:
        summary = json.loads((out / "summary.json").read_text())
        assert summary["integrity"]["status"] in ("ok", "suspect", "failed")
        assert np.isfinite(summary["epochs"])
        if rc == 3:
            assert summary["integrity"]["status"] != "ok"


@pytest.mark.parametrize("row, column", [
    ("prior_position,1.34e154,0,0,1000", "x,y,z"),   # overflowed the unit-vector Jacobian
    ("prior_velocity,1e200,0,0,1", "x,y,z"),
    ("altitude,1e154,6378137,,100", "x,y"),
])
def test_magnitudes_that_would_overflow_are_refused(tmp_path, capsys, row, column):
    """Values found by the fuzz test: finite, but whose squares overflow in the solvers."""
    lines = clean_lines(tmp_path)
    lines.insert(2, "2025-03-01T00:00:00.000000Z," + row)
    (tmp_path / "log.csv").write_text("\n".join(lines) + "\n")
    rc = main(["smooth", str(tmp_path / "log.csv"), "--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "line 3" in err and f"column '{column}'" in err, err


def test_a_prior_that_sends_the_estimate_inside_the_limb_sphere(tmp_path, capsys):
    """Found by the fuzz test: the prior position flipped (r -> -r) in a direction + limb
    log made a Gauss-Newton iterate cross inside the limb sphere, where the limb model is
    undefined (a ValueError traceback). Now the data's own orbit takes over, or the user is
    told."""
    lines = clean_lines(tmp_path)
    i = next(j for j, line in enumerate(lines) if ",prior_position," in line)
    cols = lines[i].split(",")
    cols[2:5] = [c[1:] if c.startswith("-") else "-" + c for c in cols[2:5]]
    lines[i] = ",".join(cols)
    (tmp_path / "log.csv").write_text("\n".join(lines) + "\n")
    rc = main(["smooth", str(tmp_path / "log.csv"), "--out", str(tmp_path / "out"), "--quiet",
               "--third-body"])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    if rc == 0:
        summary = json.loads((tmp_path / "out" / "summary.json").read_text())
        assert summary["integrity"]["status"] == "failed"  # the log's prior is refuted
    else:
        assert rc == 2 and "--ignore-prior" in err, err


def test_isam2_gate_with_an_attitude_row(tmp_path, capsys):
    """Found by the fuzz test: an 'attitude' row (no factor of its own) reached the iSAM2
    gate, which looked up a linearizer for it (KeyError)."""
    lines = clean_lines(tmp_path)
    lines.insert(3, "2025-03-01T00:00:00.000000Z,attitude,0.1,0.2,0.3,0.001")
    (tmp_path / "log.csv").write_text("\n".join(lines) + "\n")
    rc = main(["smooth", str(tmp_path / "log.csv"), "--out", str(tmp_path / "out"), "--quiet",
               "--method", "isam2", "--gate", "0.9999", "--third-body"])
    assert rc == 0, capsys.readouterr().err
