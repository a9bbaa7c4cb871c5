"""``fgnav smooth`` on mutated formation logs (hypothesis): the same contract as one
spacecraft's (tests/test_cli_fuzz.py) -- exit 0 (3 with ``--strict``) with a verdict in
summary.json, or exit 2 with one ``fgnav: error:`` line; never a traceback -- under the
mutations a formation's log invites: ids renamed or undeclared, declarations dropped or
garbled, a link from a spacecraft to itself, a spacecraft's rows removed, attitude rows
(the lever arms' frames) removed."""

from __future__ import annotations

import os

from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from formation_data import formation_log
from fgnav.cli import main
from fgnav.io.log_csv import write_log
from test_cli_fuzz import _mutate_line, assert_smooth_contract

_CLEAN: list[str] = []


def clean_lines(tmp_path) -> list[str]:
    if not _CLEAN:
        log, _ = formation_log(11, duration_s=900.0, carrier=True, lever_arms=True)
        write_log(tmp_path / "clean.csv", log)
        _CLEAN.extend((tmp_path / "clean.csv").read_text().splitlines())
    return list(_CLEAN)


def _formation_mutation(lines, data):
    op = data.draw(st.sampled_from(["none", "drop_attitude", "rename", "undeclared",
                                    "drop_declaration", "garble_decl", "self_link",
                                    "drop_spacecraft", "none", "none"]))
    event(op)
    body = [i for i, line in enumerate(lines) if line[:1].isdigit()]
    if op == "rename" and body:
        i = data.draw(st.sampled_from(body))
        lines[i] = lines[i].replace(",B,", ",B2,", 1)
    elif op == "undeclared" and body:
        i = data.draw(st.sampled_from(body))
        lines[i] = lines[i].replace(",A,", ",Z,", 1)
    elif op == "drop_declaration":
        decl = [i for i, line in enumerate(lines) if line.startswith("# antenna:")
                or line.startswith("# spacecraft:")]
        if decl:
            del lines[data.draw(st.sampled_from(decl))]
    elif op == "garble_decl":
        decl = [i for i, line in enumerate(lines) if line.startswith("# antenna:")]
        if decl:
            i = data.draw(st.sampled_from(decl))
            lines[i] = lines[i].rsplit(" ", 1)[0] + " " + data.draw(
                st.sampled_from(["nan", "1e9", "x", ""]))
    elif op == "self_link":
        links = [i for i in body if ",isl_" in lines[i]]
        if links:
            i = data.draw(st.sampled_from(links))
            lines[i] = lines[i].replace(",A,B,", ",A,A,", 1)
    elif op == "drop_spacecraft":
        sc = data.draw(st.sampled_from(["A", "B"]))
        lines[:] = [line for line in lines if f",{sc}," not in line or ",isl_" in line]
    elif op == "drop_attitude":
        lines[:] = [line for line in lines if ",attitude," not in line
                    or data.draw(st.booleans())]


@st.composite
def options(draw):
    """The methods a formation takes, with options they use (sometimes a bad value)."""
    opts = ["--method", draw(st.sampled_from(["batch", "isam2", "ekf"]))]
    if draw(st.booleans()):
        opts += ["--process-noise", draw(st.sampled_from(["1e-12", "1e-10", "0", "inf"]))]
    if opts[1] != "ekf" and draw(st.integers(0, 3)) == 0:
        opts += ["--robust", draw(st.sampled_from(["huber", "cauchy"]))]
    for flag in ("--third-body", "--strict"):
        if draw(st.integers(0, 3)) == 0:
            opts.append(flag)
    return opts


@settings(max_examples=30, deadline=None, derandomize=os.environ.get("CI") == "true",
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data(), opts=options())
def test_formation_smooth_never_a_traceback(tmp_path, capsys, data, opts):
    lines = clean_lines(tmp_path)
    _formation_mutation(lines, data)
    for _ in range(data.draw(st.integers(0, 2))):
        i = data.draw(st.integers(2, len(lines) - 1))
        lines[i] = _mutate_line(lines[i], data)
    (tmp_path / "log.csv").write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    rc = main(["smooth", str(tmp_path / "log.csv"), "--out", str(out), "--quiet", *opts])
    assert_smooth_contract(rc, capsys.readouterr().err, out)
