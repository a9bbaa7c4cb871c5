"""Scenario TOMLs and `fgnav simulate` options: every bad value is exit 2 with a message naming
the file and the key (or the option) and what was expected, never a traceback."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest

from fgnav.cli import main
from fgnav.errors import InputFormatError
from fgnav.paths import data_dir

BASE = """\
name = "t"
description = "test scenario"
epoch = "2025-03-01T00:00:00Z"
duration_h = 0.05
step_s = 60.0

[orbit]
r_eci_m = [6509244.371304875, 0.0, 3713244.835519765]
v_eci_mps = [-3737.397235776740, 0.0, 8790.602460568101]

[truth]
j2 = true
third_body = false

[prior]
position_sigma_m = 10000.0
velocity_sigma_mps = 2.0
mode = "random"

[[sensor]]
kind = "earth_direction"
sigma_deg = 0.01

[[sensor]]
kind = "limb_radius"
sigma_deg = 0.02
r_limb_km = 6375.0
period_s = 120.0
"""

ELEMENTS = BASE.replace(
    "r_eci_m = [6509244.371304875, 0.0, 3713244.835519765]\n"
    "v_eci_mps = [-3737.397235776740, 0.0, 8790.602460568101]\n",
    "a_m = 26332437.9\ne = 0.72\ni_deg = 90.0\nraan_deg = 0.0\nargp_deg = 13.75\n"
    "mean_anomaly_deg = 1.89\n")


def sub(old, new, base=BASE):
    assert old in base, old
    return base.replace(old, new, 1)


# case -> (TOML text, key the message must name, a word of what was expected)
BAD = {
    "empty_file": ("", None, "empty file"),
    "only_comment": ("# nothing\n", None, "empty file"),
    "syntax_unclosed_string": (sub('name = "t"', 'name = "t'), None, "valid TOML"),
    "syntax_missing_value": (sub("step_s = 60.0", "step_s ="), None, "valid TOML"),
    "syntax_duplicate_key": (sub("step_s = 60.0", "step_s = 60.0\nstep_s = 30.0"), None, "valid TOML"),
    "unknown_top_key": (sub("step_s = 60.0", "step_s = 60.0\nstep = 3"), "step", "known: name"),
    "missing_epoch": (sub('epoch = "2025-03-01T00:00:00Z"\n', ""), "epoch", "epoch"),
    "missing_duration": (sub("duration_h = 0.05\n", ""), "duration_h", "duration_h"),
    "missing_orbit": (BASE.split("[orbit]")[0] + "[[sensor]]\nkind = \"earth_direction\"\n"
                      "sigma_deg = 0.01\n", "orbit", "[orbit]"),
    "missing_sensor": (BASE.split("[[sensor]]")[0], "sensor", "[[sensor]]"),
    "epoch_not_a_date": (sub("2025-03-01T00:00:00Z", "yesterday"), "epoch", "ISO-8601"),
    "epoch_number": (sub('"2025-03-01T00:00:00Z"', "20250301"), "epoch", "ISO-8601"),
    "epoch_bad_leap_second": (sub("2025-03-01T00:00:00Z", "2017-12-31T23:59:60Z"), "epoch",
                              "second 60"),
    "duration_string": (sub("duration_h = 0.05", 'duration_h = "1"'), "duration_h", "finite number"),
    "duration_zero": (sub("duration_h = 0.05", "duration_h = 0"), "duration_h", "> 0"),
    "duration_negative": (sub("duration_h = 0.05", "duration_h = -1.0"), "duration_h", "> 0"),
    "duration_nan": (sub("duration_h = 0.05", "duration_h = nan"), "duration_h", "finite"),
    "duration_inf": (sub("duration_h = 0.05", "duration_h = inf"), "duration_h", "finite"),
    "step_bool": (sub("step_s = 60.0", "step_s = true"), "step_s", "finite number"),
    "step_negative": (sub("step_s = 60.0", "step_s = -60.0"), "step_s", "> 0"),
    "orbit_r_two_components": (sub("[6509244.371304875, 0.0, 3713244.835519765]", "[1.0, 2.0]"),
                               "orbit.r_eci_m", "3 finite numbers"),
    "orbit_r_nan": (sub("[6509244.371304875, 0.0,", "[nan, 0.0,"), "orbit.r_eci_m", "finite"),
    "orbit_r_strings": (sub("[6509244.371304875, 0.0, 3713244.835519765]", '["a", "b", "c"]'),
                        "orbit.r_eci_m", "3 finite numbers"),
    "orbit_inside_earth": (sub("[6509244.371304875, 0.0, 3713244.835519765]", "[0.0, 0.0, 0.0]"),
                           "orbit.r_eci_m", "above the Earth"),
    "orbit_missing_velocity": (sub("v_eci_mps = [-3737.397235776740, 0.0, 8790.602460568101]\n", ""),
                               "orbit.v_eci_mps", "r_eci_m + v_eci_mps"),
    "orbit_unknown_key": (sub("[orbit]\n", "[orbit]\nalt_km = 500\n"), "orbit.alt_km", "known: r_eci_m"),
    "orbit_both_forms": (sub("[orbit]\n", "[orbit]\na_m = 7e6\n"), "orbit.a_m", "not both"),
    "elements_e_one": (sub("e = 0.72", "e = 1.0", ELEMENTS), "orbit.e", "< 1"),
    "elements_e_negative": (sub("e = 0.72", "e = -0.1", ELEMENTS), "orbit.e", ">= 0"),
    "elements_a_negative": (sub("a_m = 26332437.9", "a_m = -7e6", ELEMENTS), "orbit.a_m", "> 0"),
    "elements_perigee_underground": (sub("a_m = 26332437.9", "a_m = 7e6", ELEMENTS), "orbit.a_m",
                                     "perigee"),
    "elements_inclination_200": (sub("i_deg = 90.0", "i_deg = 200.0", ELEMENTS), "orbit.i_deg", "<= 180"),
    "elements_missing_raan": (sub("raan_deg = 0.0\n", "", ELEMENTS), "orbit.raan_deg", "raan_deg"),
    "elements_two_anomalies": (sub("mean_anomaly_deg = 1.89", "mean_anomaly_deg = 1.89\n"
                                   "true_anomaly_deg = 3.0", ELEMENTS), "orbit.true_anomaly_deg",
                               "not both"),
    "truth_not_bool": (sub("j2 = true", 'j2 = "yes"'), "truth.j2", "true or false"),
    "truth_unknown": (sub("third_body = false", "third_body = false\nsolar_wind = true"),
                      "truth.solar_wind", "known: j2"),
    "prior_sigma_zero": (sub("position_sigma_m = 10000.0", "position_sigma_m = 0.0"),
                         "prior.position_sigma_m", "> 0"),
    "prior_sigma_inf": (sub("velocity_sigma_mps = 2.0", "velocity_sigma_mps = inf"),
                        "prior.velocity_sigma_mps", "finite"),
    "prior_mode": (sub('mode = "random"', 'mode = "gaussian"'), "prior.mode", "'random', 'fixed'"),
    "prior_not_a_table": (sub("[prior]\nposition_sigma_m = 10000.0\nvelocity_sigma_mps = 2.0\n"
                              'mode = "random"\n', "").replace('step_s = 60.0', 'step_s = 60.0\nprior = 3'),
                          "prior", "a table"),
    "sensor_unknown_kind": (sub('kind = "earth_direction"', 'kind = "gnss"'), "sensor[1].kind",
                            "earth_direction"),
    "sensor_missing_kind": (sub('kind = "earth_direction"\n', ""), "sensor[1].kind", "kind"),
    "sensor_missing_sigma": (sub("sigma_deg = 0.01\n", ""), "sensor[1].sigma_deg", "sigma_deg"),
    "sensor_sigma_negative": (sub("sigma_deg = 0.01", "sigma_deg = -0.01"), "sensor[1].sigma_deg", "> 0"),
    "sensor_sigma_nan": (sub("sigma_deg = 0.02", "sigma_deg = nan"), "sensor[2].sigma_deg", "finite"),
    "sensor_sigma_string": (sub("sigma_deg = 0.01", 'sigma_deg = "0.01"'), "sensor[1].sigma_deg",
                            "finite number"),
    "sensor_period_zero": (sub("period_s = 120.0", "period_s = 0.0"), "sensor[2].period_s", "> 0"),
    "sensor_key_of_another_kind": (sub("sigma_deg = 0.01", "sigma_deg = 0.01\nsigma_m = 3.0"),
                                   "sensor[1].sigma_m", "known: kind, period_s, sigma_deg"),
    "sensor_typo_key": (sub("r_limb_km = 6375.0", "r_limb_m = 6375000.0"), "sensor[2].r_limb_m",
                        "r_limb_km"),
    "sensor_r_limb_metres": (sub("r_limb_km = 6375.0", "r_limb_km = 6375000.0"),
                             "sensor[2].r_limb_km", "<= 7000 km"),
    "sensor_not_array_of_tables": (sub("step_s = 60.0", 'step_s = 60.0\nsensor = "earth_direction"',
                                       BASE.split("[[sensor]]")[0]), "sensor", "[[sensor]]"),
    "sensor_altitude_without_sigma_m": (BASE + '\n[[sensor]]\nkind = "altitude"\n',
                                        "sensor[3].sigma_m", "sigma_m"),
    "refraction_empty_azimuths": (BASE + '\n[[sensor]]\nkind = "refraction"\nazimuths_deg = []\n',
                                  "sensor[3].azimuths_deg", "non-empty array"),
    "refraction_fov_180": (BASE + '\n[[sensor]]\nkind = "refraction"\nfov_deg = 180.0\n',
                           "sensor[3].fov_deg", "<= 90"),
    "bias_on_a_direction_sensor": (sub("sigma_deg = 0.01", "sigma_deg = 0.01\nmodel_bias_m = 300.0"),
                                   "sensor[1].model_bias_m", "known: kind, period_s, sigma_deg"),
    "bias_random_walk_negative": (BASE + '\n[[sensor]]\nkind = "refraction"\n'
                                  'model_bias_random_walk_m_per_sqrt_h = -1.0\n',
                                  "sensor[3].model_bias_random_walk_m_per_sqrt_h", ">= 0 m/sqrt(h)"),
    "bias_drift_nan": (BASE + '\n[[sensor]]\nkind = "refraction"\nmodel_bias_drift_m_per_h = nan\n',
                       "sensor[3].model_bias_drift_m_per_h", "finite"),
    "bias_string": (BASE + '\n[[sensor]]\nkind = "refraction"\nmodel_bias_m = "300 m"\n',
                    "sensor[3].model_bias_m", "finite number"),
    "bias_on_two_refraction_sensors": (
        BASE + '\n[[sensor]]\nkind = "refraction"\nmodel_bias_m = 300.0\n'
        '\n[[sensor]]\nkind = "refraction"\nmodel_bias_drift_m_per_h = 10.0\n',
        "sensor[4].model_bias_drift_m_per_h", "one refraction sensor only"),
}


# formation scenarios: [[spacecraft]], [[antenna]], [[link]], [ranging] (fgnav.scenarios)
FORMATION = (data_dir() / "scenarios" / "formation-gto.toml").read_text()


def _bad(old, new, count=1):
    assert old in FORMATION, old
    return FORMATION.replace(old, new, count)


FORMATION_BAD = {
    "one_spacecraft": (_bad('[[spacecraft]]\nid = "sat1"\n', ""), "spacecraft", "at least two"),
    "duplicate_id": (_bad('id = "sat2"', 'id = "sat1"'), "spacecraft[2].id", "not used before"),
    "bad_id": (_bad('id = "sat2"', 'id = "sat 2"'), "spacecraft[2].id", "letters, digits"),
    "unknown_spacecraft_key": (_bad("lead_s = 0.1", "lead_s = 0.1\nlead_m = 1000.0"),
                               "spacecraft[2].lead_m", "known: id, lead_s"),
    "lead_and_orbit": (_bad("yaw_deg = 180.0", "yaw_deg = 180.0\n[spacecraft.orbit]\n"
                            "a_m = 7e6\ne = 0.0\ni_deg = 0.0\nraan_deg = 0.0\nargp_deg = 0.0\n"
                            "true_anomaly_deg = 0.0"), "spacecraft[2].lead_s", "not both"),
    "own_orbit_bad": (_bad("lead_s = 0.1\nyaw_deg = 180.0", "yaw_deg = 180.0\n[spacecraft.orbit]\n"
                           "a_m = 7e6\ne = 1.5"),
                      "spacecraft[2].orbit.e", "< 1"),
    "antenna_of_unknown_spacecraft": (_bad('spacecraft = "sat2"\nname = "rx3"',
                                           'spacecraft = "sat3"\nname = "rx3"'),
                                      "antenna[8].spacecraft", "sat1, sat2"),
    "antenna_twice": (_bad('name = "rx3"', 'name = "rx2"'), "antenna[4].name", "once"),
    "antenna_arm_far": (_bad("body_m = [0.5, 0.5, -0.5]", "body_m = [5000.0, 0.5, -0.5]"),
                        "antenna[1].body_m", "within 1000 m"),
    "link_to_itself": (_bad('rx = "sat1"\nrx_antenna = "rx1"\ntx = "sat2"',
                            'rx = "sat1"\nrx_antenna = "rx1"\ntx = "sat1"'), "link[1].tx",
                       "other than rx"),
    "link_undeclared_antenna": (_bad('rx_antenna = "rx2"', 'rx_antenna = "rx9"'),
                                "link[2].rx_antenna", "an [[antenna]] of spacecraft 'sat1'"),
    "link_unknown_spacecraft": (_bad('rx = "sat2"', 'rx = "sat9"'), "link[4].rx", "sat1, sat2"),
    "ranging_missing": (FORMATION.split("\n[ranging]\n")[0], "ranging", "[ranging]"),
    "ranging_sigma_missing": (_bad("sigma_m = 0.01\n", ""), "ranging.sigma_m", "sigma_m"),
    "ranging_sigma_negative": (_bad("sigma_m = 0.01", "sigma_m = -0.01"), "ranging.sigma_m",
                               ">= 1e-06"),
    "ranging_unknown_key": (_bad("sigma_m = 0.01", "sigma_m = 0.01\nsigma_cm = 1.0"),
                            "ranging.sigma_cm", "known: sigma_m"),
    "attitude_sigma_zero": (_bad("attitude_sigma_arcsec = 1.0", "attitude_sigma_arcsec = 0.0"),
                            "ranging.attitude_sigma_arcsec", "> 0"),
}
BAD.update({f"formation_{k}": v for k, v in FORMATION_BAD.items()})

@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_scenario_toml_is_exit_2_naming_the_key(case, tmp_path, capsys):
    text, key, expected = BAD[case]
    path = tmp_path / "bad.toml"
    path.write_text(text)
    rc = main(["simulate", str(path), "--out", str(tmp_path / "out"), "--quiet"])
    out, err = capsys.readouterr()
    assert rc == 2, (case, out, err)
    assert "Traceback" not in out + err
    assert err.startswith("fgnav: error: ") and str(path) in err, err
    if key is not None:
        assert f"'{key}'" in err, err
    assert expected in err, err
    assert not (tmp_path / "out").exists()      # refused before any output


def test_the_message_points_at_the_line_of_the_key(tmp_path):
    from fgnav.scenarios import load_scenario

    path = tmp_path / "bad.toml"
    path.write_text(sub("sigma_deg = 0.02", "sigma_deg = -1.0"))
    with pytest.raises(InputFormatError) as exc:
        load_scenario(str(path))
    line = next(i + 1 for i, ln in enumerate(BASE.splitlines()) if "sigma_deg = 0.02" in ln)
    assert exc.value.line == line and exc.value.column == "sensor[2].sigma_deg"
    path.write_text(sub("step_s = 60.0", "step_s = 60.0\nstep_s = 3"))   # TOML syntax
    with pytest.raises(InputFormatError) as exc:
        load_scenario(str(path))
    assert exc.value.line == 6


def test_good_variants_load(tmp_path):
    from fgnav.scenarios import load_scenario

    path = tmp_path / "ok.toml"
    for text in (BASE, ELEMENTS, sub('epoch = "2025-03-01T00:00:00Z"', "epoch = 2025-03-01T00:00:00Z"),
                 sub("2025-03-01T00:00:00Z", "2016-12-31T23:59:60Z"),
                 "\ufeff" + BASE, sub("duration_h = 0.05", "duration_h = 1")):
        path.write_text(text, encoding="utf-8")
        scn = load_scenario(str(path))
        assert len(scn.sensors) == 2 and scn.step_s == 60.0
    el = load_scenario(str(tmp_path / "ok.toml"))
    assert el.duration_h == 1.0 and isinstance(el.duration_h, float)


def test_builtin_scenarios_load_unchanged():
    from fgnav.scenarios import builtin_names, load_scenario

    assert builtin_names() == ["constellation-leo", "formation-cruise", "formation-gto",
                               "formation-gto-3", "geo-limb",
                               "gto-transfer",
                               "leo-sun-earth-moon", "mars-cruise", "refraction-leo",
                               "refraction-leo-bias", "sextant-leo"]
    gto = load_scenario("gto-transfer")
    assert gto.x0_eci == (6509244.371304875, 0.0, 3713244.835519765,
                          -3737.397235776740, 0.0, 8790.602460568101)
    assert load_scenario("refraction-leo").sensors[0].azimuths_deg == (0.0, 120.0, 240.0)
    for name in builtin_names():
        load_scenario(name)


def test_non_utf8_scenario_names_the_line_and_byte(tmp_path, capsys):
    path = tmp_path / "latin1.toml"
    text = sub('description = "test scenario"', 'description = "d\xe9part"')
    path.write_bytes(text.encode("latin-1"))
    assert main(["simulate", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    offset = text.index("\xe9")           # one byte per character before it
    assert f"{path}, line 2" in err and "0xe9 at character 17" in err, err
    assert f"byte offset {offset} in the file" in err, err


def test_missing_and_unknown_scenario(tmp_path, capsys):
    assert main(["simulate", str(tmp_path / "none.toml"), "--out", str(tmp_path / "o")]) == 2
    assert "no such scenario file" in capsys.readouterr().err
    assert main(["simulate", "no-such-builtin", "--out", str(tmp_path / "o")]) == 2
    assert "gto-transfer" in capsys.readouterr().err
    assert main(["simulate", str(tmp_path), "--out", str(tmp_path / "o")]) == 2


# ------------------------------------------------------------------ options
@pytest.mark.parametrize("option, value", [
    ("--step-s", "0"), ("--step-s", "nan"), ("--step-s", "-1"), ("--step-s", "inf"),
    ("--step-s", "ten"), ("--seed", "-1"), ("--seed", "1.5"), ("--duration-h", "0"),
    ("--duration-h", "-1"), ("--duration-h", "nan"), ("--duration-h", "inf"),
    ("--image-period-s", "0"), ("--image-period-s", "nan"), ("--max-epochs", "0"),
    ("--max-duration-h", "-5"),
])
def test_bad_simulate_option_is_exit_2_naming_it(option, value, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["simulate", "gto-transfer", "--out", str(tmp_path / "o"), option, value])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {option}: expected" in err and repr(value) in err, err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("extra, limit_text, how", [
    (["--duration-h", "1e6"], "limit of 744 h", "--max-duration-h"),
    (["--step-s", "1e-6"], "limit of 1,000,000", "--max-epochs"),
    (["--duration-h", "2", "--max-epochs", "100"], "limit of 100", "--max-epochs"),
])
def test_a_pass_beyond_the_limits_is_refused_at_once(extra, limit_text, how, tmp_path, capsys):
    rc = main(["simulate", "gto-transfer", "--out", str(tmp_path / "o"), *extra])
    err = capsys.readouterr().err
    assert rc == 2 and limit_text in err and how in err, err
    assert not (tmp_path / "o").exists()


def test_the_limits_are_stated_in_help_and_raisable(tmp_path, capsys):
    from fgnav import scenarios
    from fgnav.commands import simulate

    assert (simulate.MAX_EPOCHS, simulate.MAX_DURATION_H) == (scenarios.MAX_EPOCHS,
                                                             scenarios.MAX_DURATION_H)
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    out = capsys.readouterr().out
    assert "1,000,000" in out and "744" in out
    # the same pass is accepted once the limit is raised
    assert main(["simulate", "gto-transfer", "--out", str(tmp_path / "o"), "--duration-h", "0.05",
                 "--step-s", "1", "--max-epochs", "180", "--quiet"]) == 2   # 181 epochs
    capsys.readouterr()
    assert main(["simulate", "gto-transfer", "--out", str(tmp_path / "o"), "--duration-h", "0.05",
                 "--step-s", "1", "--max-epochs", "181", "--quiet"]) == 0


def test_library_refuses_bad_seed_and_size():
    from fgnav.errors import UserError
    from fgnav.scenarios import load_scenario
    from fgnav.simulate.pass_sim import simulate_pass

    scn = load_scenario("gto-transfer")
    with pytest.raises(UserError, match="seed"):
        simulate_pass(scn, seed=-1)
    with pytest.raises(UserError, match="--max-epochs"):
        simulate_pass(scn.with_options(step_s=1e-3))
    with pytest.raises(UserError, match="step_s"):
        scn.with_options(step_s=math.nan)


def test_subprocess_no_traceback(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(sub("sigma_deg = 0.01", "sigma_deg = nan"))
    for args in (["simulate", str(bad), "--out", str(tmp_path / "o")],
                 ["simulate", "gto-transfer", "--out", str(tmp_path / "o"), "--step-s", "nan"]):
        r = subprocess.run([sys.executable, "-m", "fgnav", *args], capture_output=True, text=True)
        assert r.returncode == 2 and "Traceback" not in r.stderr and "error" in r.stderr, r.stderr


# ------------------------------------------------------------------ hypothesis: mutated values
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


def _key_lines(text):
    """(line index, label) of every 'key = value' line of ``text``."""
    out, table, n_sensor = [], None, 0
    for i, ln in enumerate(text.splitlines()):
        s = ln.strip()
        if s.startswith("[["):
            n_sensor += 1
            table = f"sensor[{n_sensor}]"
        elif s.startswith("["):
            table = s.strip("[]")
        elif "=" in s and not s.startswith("#"):
            key = s.split("=", 1)[0].strip()
            out.append((i, key if table is None else f"{table}.{key}"))
    return out


_SCALARS = st.one_of(
    st.integers(-10**12, 10**12).map(str),
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
    st.sampled_from(["nan", "inf", "-inf", "+nan", "0", "-0.0", "1e308", "1e-320", "true",
                     "false", '""', '"random"', '"earth_direction"', "2025-03-01T00:00:00Z",
                     '"2016-12-31T23:59:60Z"', "{}", "{ a = 1 }", "[]"]),
    st.text(alphabet=st.characters(codec="utf-8", exclude_categories=("Cs", "Cc")),
            max_size=12).map(lambda t: '"' + t.replace("\\", "\\\\").replace('"', '\\"') + '"'),
)
_VALUES = st.one_of(_SCALARS, st.lists(_SCALARS, max_size=4).map(lambda v: "[" + ", ".join(v) + "]"))
_LINES = _key_lines(BASE) + _key_lines(ELEMENTS)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(base=st.sampled_from(["cart", "elem"]), which=st.integers(0, 10**6), value=_VALUES,
       action=st.sampled_from(["replace", "replace", "replace", "delete", "rename"]))
def test_mutated_scenario_is_valid_or_names_the_key(base, which, value, action, tmp_path_factory):
    """Each mutation of one key (new value, deleted, renamed) either loads a scenario whose
    numbers are all usable, or is an InputFormatError naming that key (or, for TOML syntax,
    the line)."""
    from fgnav.scenarios import load_scenario

    text = BASE if base == "cart" else ELEMENTS
    keys = _key_lines(text)
    i, label = keys[which % len(keys)]
    lines = text.splitlines()
    key = lines[i].split("=", 1)[0].strip()
    if action == "replace":
        lines[i] = f"{key} = {value}"
    elif action == "delete":
        del lines[i]
    else:
        lines[i] = lines[i].replace(key, key + "_x", 1)
    path = tmp_path_factory.mktemp("mut") / "m.toml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    try:
        scn = load_scenario(str(path))
    except InputFormatError as exc:
        msg = str(exc)
        if "valid TOML" in msg:
            assert exc.line is not None
            return
        renamed = label + "_x"
        assert f"'{label}'" in msg or f"'{renamed}'" in msg or (
            label.startswith("orbit.") and "'orbit." in msg) or (
            label.endswith(".kind") and "sensor[" in msg), (label, msg)
        return
    nums = [scn.duration_h, scn.step_s, scn.prior_position_sigma_m, scn.prior_velocity_sigma_mps,
            *scn.x0_eci]
    assert all(isinstance(v, float) and math.isfinite(v) for v in nums)
    assert scn.duration_h > 0 and scn.step_s > 0 and scn.prior_position_sigma_m > 0
    for s in scn.sensors:
        assert s.period_s is None or (math.isfinite(s.period_s) and s.period_s > 0)
        assert (s.sigma_deg or 0) >= 0 and s.kind in ("earth_direction", "limb_radius")
        assert s.sigma_deg is not None and 0 < s.sigma_deg <= 45


def test_unusable_out_is_refused_before_simulating(tmp_path, capsys):
    f = tmp_path / "a_file"
    f.write_text("x")
    for out in (f, f / "sub"):
        assert main(["simulate", "gto-transfer", "--out", str(out), "--quiet"]) == 2
        err = capsys.readouterr().err
        assert f"--out {out}" in err and "Traceback" not in err, err


def test_a_pass_ending_after_2261_is_refused(tmp_path, capsys):
    path = tmp_path / "late.toml"
    path.write_text(sub("2025-03-01T00:00:00Z", "2261-12-31T23:00:00Z"))
    assert main(["simulate", str(path), "--out", str(tmp_path / "o"), "--duration-h", "2"]) == 2
    assert "2261" in capsys.readouterr().err
    assert main(["simulate", str(path), "--out", str(tmp_path / "o"), "--quiet"]) == 0


def test_a_heliocentric_scenario_is_checked_against_its_centre(tmp_path):
    from fgnav.scenarios import load_scenario

    from fgnav.paths import data_dir

    text = (data_dir() / "scenarios" / "mars-cruise.toml").read_text()
    scn = load_scenario("mars-cruise")
    assert scn.centre == "sun" and scn.prior_mode == "none" and scn.truth_third_body
    path = tmp_path / "c.toml"
    cases = [
        (text.replace('centre = "sun"', 'centre = "mars"'), "centre", "one of 'earth', 'sun'"),
        (text.replace('kind = "body_body_angle"', 'kind = "altitude"\nsigma_m = 10.0')
         .replace('body = "sun"\nbody2 = "earth"\nsigma_deg = 0.0031056', ''),
         "sensor[2].kind", "heliocentric"),
        (text.replace("third_body = true", "third_body = true\nsrp = true"), "truth.srp", "Sun and"),
        (text.replace("r_eci_m = [-71411267196.027, 125952896819.755, 54598746250.093]",
                      "r_eci_m = [1.0e8, 0.0, 0.0]"), "orbit.r_eci_m", "outside the Sun"),
    ]
    for bad, column, expected in cases:
        path.write_text(bad)
        with pytest.raises(InputFormatError) as exc:
            load_scenario(str(path))
        assert exc.value.column == column and expected in str(exc.value), str(exc.value)
