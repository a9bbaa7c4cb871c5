"""``fgnav smooth`` on mutated logs of the attitude-free angle kinds (hypothesis).

The sextant's rows (``limb_star_angle``, ``body_star_angle``, ``body_body_angle``) carry values
the reader checks (an angle in [0, pi], a limb radius, a star's unit vector, body names) and
values only the orbit can refute (an angle no position fits, a limb sphere that encloses the
spacecraft, a star on the body's line of sight). Whatever they hold, with or without the
aberration correction and the prior rows, every route ends as ``fgnav smooth`` promises
(``tests/test_cli_fuzz.py``): exit 0 with an integrity verdict, or exit 2 with one
``fgnav: error:`` line. Never a traceback.
"""

from __future__ import annotations

import math
import os

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fgnav.cli import main
from fgnav.io.log_csv import write_log
from fgnav.scenarios import load_scenario
from fgnav.simulate.pass_sim import simulate_pass
from test_cli_fuzz import assert_smooth_contract

_CLEAN: dict[str, list[str]] = {}
SHORT_H = {"sextant-leo": 1 / 3, "mars-cruise": 72.0}
"""The clean logs mutated: sextant-leo 20 min (21 epochs of limb-star, Moon-star and
Earth-Moon angles and the prior rows); mars-cruise 3 days (19 epochs of Sun-star and
Sun-Earth angles, heliocentric, no prior rows)."""


def clean_lines(tmp_path, name="sextant-leo") -> list[str]:
    """A short clean log of scenario ``name`` (:data:`SHORT_H`), as lines; made once."""
    if name not in _CLEAN:
        sim = simulate_pass(load_scenario(name).with_options(duration_h=SHORT_H[name]), seed=0)
        write_log(tmp_path / "clean.csv", sim.log)
        _CLEAN[name] = (tmp_path / "clean.csv").read_text().splitlines()
    return list(_CLEAN[name])


def _columns(lines):
    return next(line for line in lines if line.startswith("epoch,")).split(",")


def _mutate(cols, names, data):
    """One angle-specific mutation of a row's fields ``cols`` (header ``names``)."""
    at = {n: i for i, n in enumerate(names)}
    op = data.draw(st.sampled_from(["angle", "limb", "star", "star_scale", "body", "kind"]))
    if op == "angle":
        cols[at["x"]] = repr(data.draw(st.sampled_from(
            [0.0, 1e-13, math.pi, math.pi - 1e-13, -1e-9, math.pi + 1e-9, 7.0]) | st.floats(0.0, math.pi)))
    elif op == "limb":
        cols[at["y"]] = repr(data.draw(st.sampled_from([1.0, 6.4e6, 7.2e6, 7.5e6, 1e9, 0.0, -1.0])))
    elif op == "star":   # any direction, e.g. on the body's line of sight
        v = [data.draw(st.floats(-1.0, 1.0)) for _ in range(3)]
        n = math.sqrt(sum(c * c for c in v))
        for c, name in zip(v, ("star_x", "star_y", "star_z")):
            cols[at[name]] = repr(c / n) if n > 1e-3 else "0"
    elif op == "star_scale":
        f = data.draw(st.sampled_from([1.0 + 1e-7, 1.0 + 1e-3, 2.0, 0.0]))
        for name in ("star_x", "star_y", "star_z"):
            if cols[at[name]]:
                cols[at[name]] = repr(float(cols[at[name]]) * f)
    elif op == "body":
        name = data.draw(st.sampled_from(["body", "body2"]))
        cols[at[name]] = data.draw(st.sampled_from(["sun", "earth", "moon", "Moon", "mars", ""]))
    else:
        cols[1] = data.draw(st.sampled_from(["limb_star_angle", "body_star_angle",
                                             "body_body_angle"]))
    return cols


@settings(max_examples=int(os.environ.get("FGNAV_FUZZ_EXAMPLES", 20)), deadline=None,
          derandomize=os.environ.get("CI") == "true",
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data(), name=st.sampled_from(sorted(SHORT_H)))
def test_smooth_on_mutated_angle_logs_never_a_traceback(tmp_path, capsys, data, name):
    lines = clean_lines(tmp_path, name)
    names = _columns(lines)
    rows = [i for i, line in enumerate(lines) if "_angle," in line]
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.sampled_from(rows))
        lines[i] = ",".join(_mutate(lines[i].split(","), names, data))
    if data.draw(st.booleans()):
        lines = [line for line in lines if ",prior_" not in line]
    opts = ["--method", data.draw(st.sampled_from(["batch", "isam2", "fixed-lag", "ekf"]))]
    if data.draw(st.booleans()):
        opts.append("--no-aberration")
    if data.draw(st.integers(0, 3)) == 0:
        opts += ["--state", "elements"]
    (tmp_path / "log.csv").write_text("\n".join(lines) + "\n")
    rc = main(["smooth", str(tmp_path / "log.csv"), "--out", str(tmp_path / "out"), "--quiet",
               *opts])
    assert_smooth_contract(rc, capsys.readouterr().err, tmp_path / "out")


def test_the_compiled_ekf_leaving_a_models_domain_is_a_user_error(tmp_path, capsys):
    """Found by the fuzz test: a Moon-star angle of 0 (the Moon on the star) in a log without
    prior rows sends the compiled EKF's estimate where a line of sight has no angle; it
    raised a bare ValueError traceback where the numpy EKF (``--gate``) gives the user the
    message that the estimate left a model's domain."""
    lines = clean_lines(tmp_path)
    i = [j for j, line in enumerate(lines) if "_angle," in line][4]
    cols = lines[i].split(",")
    assert cols[1] == "body_star_angle"
    cols[2] = "0.0"
    lines[i] = ",".join(cols)
    lines = [line for line in lines if ",prior_" not in line]
    (tmp_path / "log.csv").write_text("\n".join(lines) + "\n")
    rc = main(["smooth", str(tmp_path / "log.csv"), "--out", str(tmp_path / "out"), "--quiet",
               "--method", "ekf"])
    err = capsys.readouterr().err
    # the last line: a first compile in this process may have printed its notice before
    last = err.strip().splitlines()[-1]
    assert rc == 2 and last.startswith("fgnav: error:") and "log line" in last, err


def test_an_element_update_past_the_conics_is_a_user_error(tmp_path, capsys):
    """Found by the fuzz test: a limb-star angle of 0 (a 6,600-sigma outlier) at the first
    epoch makes the element EKF's update (``--state elements``) a negative semi-latus rectum;
    the state became NaN (``sqrt`` of a negative number) and the user was told the orbit had
    zero angular momentum. Now the message says that an update left the elements' domain
    and names the log line of the row whose update did (a later one: the outlier had pulled
    the estimate away)."""
    lines = clean_lines(tmp_path)
    cols = lines[6].split(",")
    assert cols[1] == "limb_star_angle"
    cols[2] = "0.0"
    lines[6] = ",".join(cols)
    (tmp_path / "log.csv").write_text("\n".join(lines) + "\n")
    rc = main(["smooth", str(tmp_path / "log.csv"), "--out", str(tmp_path / "out"), "--quiet",
               "--method", "ekf", "--state", "elements"])
    err = capsys.readouterr().err
    assert rc == 2 and "semi-latus rectum" in err and "limb_star_angle row at log line" in err, err
