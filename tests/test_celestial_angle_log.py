"""The angle kinds in the log format: body_star_angle, limb_star_angle, body_body_angle and their
``body``/``body2`` columns (fgnav.io.log_csv), read, validated, written back, and the
simulator's rows at the truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fgnav.errors import InputFormatError, UserError
from fgnav.io.log_csv import BODIES, body_names, log_from_arrays, read_log, write_log
from fgnav.measurements import build_pass
from fgnav.models.registry import BODY_BODY_ANGLE, BODY_STAR_ANGLE, LIMB_STAR_ANGLE
from fgnav.scenarios import SensorSpec, load_scenario
from fgnav.simulate.pass_sim import simulate_pass

HEAD = "epoch,kind,x,y,z,sigma,star_x,star_y,star_z,body,body2\n"
ROWS = [
    "2025-03-06T12:00:00Z,body_star_angle,0.9,,,3e-5,0.6,0,0.8,Moon,",
    "2025-03-06T12:00:00Z,limb_star_angle,0.3,6375000,,8e-5,0,0.6,0.8,earth,",
    "2025-03-06T12:01:00Z,body_body_angle,2.8,,,8e-5,,,,earth,moon",
    "2025-03-06T12:01:00Z,body_star_angle,1.9,,,1e-4,0,0,1,sun,",
]


def _write(tmp_path, rows, head=HEAD):
    p = tmp_path / "log.csv"
    p.write_text(head + "\n".join(rows) + "\n", encoding="utf-8")
    return p


def test_the_angle_kinds_are_read_and_written_back(tmp_path):
    log = read_log(_write(tmp_path, ROWS))
    assert list(log.kind) == [BODY_STAR_ANGLE.kind, LIMB_STAR_ANGLE.kind, BODY_BODY_ANGLE.kind,
                              BODY_STAR_ANGLE.kind]
    assert body_names(log.extra["body"]) == ["moon", "earth", "earth", "sun"]
    assert body_names(log.extra["body2"]) == [None, None, "moon", None]
    write_log(tmp_path / "again.csv", log)
    text = (tmp_path / "again.csv").read_text()
    assert ",moon," in text and text.rstrip().endswith(",sun,")
    again = read_log(tmp_path / "again.csv")
    for c in log.extra:
        np.testing.assert_array_equal(again.extra[c], log.extra[c])
    np.testing.assert_array_equal(again.xyz, log.xyz)
    p = build_pass(log)
    fam = p.families[BODY_BODY_ANGLE.kind]
    assert np.linalg.norm(fam.values["p_body2_eci_m"][0]) > 3e8      # the Moon, not the origin
    assert np.all(fam.values["p_body_eci_m"] == 0.0)                  # the Earth


@pytest.mark.parametrize("row, column, what", [
    ("2025-03-06T12:00:00Z,body_star_angle,0.9,,,3e-5,0.6,0,0.8,mars,", "body",
     "a body, one of sun, earth, moon"),
    ("2025-03-06T12:00:00Z,body_star_angle,0.9,,,3e-5,0.6,0,0.8,,", "body", "a body name"),
    ("2025-03-06T12:00:00Z,body_star_angle,0.9,,,3e-5,,,,moon,", "star_x", "a number"),
    ("2025-03-06T12:00:00Z,body_star_angle,0.9,,,3e-5,0.6,0,0.8,moon,sun", "body2",
     "an empty field"),
    ("2025-03-06T12:00:00Z,body_star_angle,3.5,,,3e-5,0.6,0,0.8,moon,", "x",
     "an angle in [0, pi]"),
    ("2025-03-06T12:00:00Z,limb_star_angle,0.3,6375000,,8e-5,0,0.6,0.8,sun,", "body",
     "a body with a limb"),
    ("2025-03-06T12:00:00Z,limb_star_angle,0.3,,,8e-5,0,0.6,0.8,earth,", "y", "a number"),
    ("2025-03-06T12:01:00Z,body_body_angle,2.8,,,8e-5,,,,earth,earth", "body2",
     "a body other than"),
    ("2025-03-06T12:01:00Z,body_body_angle,2.8,,,8e-5,,,,earth,", "body2", "a body name"),
    ("2025-03-06T12:01:00Z,body_star_angle,0.9,,,3e-5,0.6,0,0.9,moon,", "star_x,star_y,star_z",
     "a unit vector"),
])
def test_a_bad_angle_row_names_its_line_column_and_expectation(tmp_path, row, column, what):
    with pytest.raises(InputFormatError) as exc:
        read_log(_write(tmp_path, ROWS[:1] + [row]))
    assert exc.value.line == 3 and exc.value.column == column, str(exc.value)
    assert what in str(exc.value)


def test_the_body_columns_are_needed_in_the_header(tmp_path):
    head = "epoch,kind,x,y,z,sigma,star_x,star_y,star_z\n"
    with pytest.raises(InputFormatError) as exc:
        read_log(_write(tmp_path, ["2025-03-06T12:00:00Z,body_star_angle,0.9,,,3e-5,0.6,0,0.8"],
                        head))
    assert exc.value.column == "body" and "a body name" in str(exc.value)
    with pytest.raises(InputFormatError) as exc:
        read_log(_write(tmp_path, ["2025-03-06T12:00:00Z,body_star_angle,0.9,,,3e-5,0.6,0,0.8,x,y,z"],
                        HEAD.replace("body2", "planet")))
    assert exc.value.column == "planet"


def test_log_from_arrays_takes_body_names_and_refuses_unknown_ones():
    kw = dict(t_s=[0.0], kind=[BODY_BODY_ANGLE.kind], xyz=[[1.0, np.nan, np.nan]], sigma=[1e-4])
    log = log_from_arrays("2025-03-06T12:00:00Z", **kw, extra={"body": ["sun"], "body2": ["moon"]})
    assert log.extra["body"][0] == BODIES.index("sun")
    with pytest.raises(UserError, match="unknown body 'pluto'"):
        log_from_arrays("2025-03-06T12:00:00Z", **kw, extra={"body": ["pluto"], "body2": ["moon"]})


def test_simulated_angles_are_the_true_geometry_plus_noise_of_the_stated_sigma():
    """The sextant-leo pass: every angle row's residual at the truth, divided by its sigma,
    is a standard normal draw (mean ~0, spread ~1)."""
    scn = load_scenario("sextant-leo").with_options(duration_h=1.0)
    sim = simulate_pass(scn, seed=5)
    p = build_pass(sim.log)
    x_true = sim.x_true[np.searchsorted(sim.t_s, p.t_s)]
    for mdl in (LIMB_STAR_ANGLE, BODY_STAR_ANGLE, BODY_BODY_ANGLE):
        fam = p.families[mdl.kind]
        e, _ = mdl.residual(fam, {"orbit": x_true[fam.k]})
        z = np.asarray(e)[:, 0] / fam.sigma
        assert len(z) > 20, mdl.kind
        assert abs(z.mean()) < 4 / np.sqrt(len(z)) and 0.7 < z.std() < 1.3, (mdl.kind, z.mean(),
                                                                              z.std())


_SUN_FROM_LEO = {  # the Sun seen from Earth orbit (moving ~30 km/s in the geocentric frame)
    "duration_h": 1.0,
    "sensors": (SensorSpec("body_star_angle", sigma_deg=0.002, body="sun", stars_per_epoch=2,
                           vmag_max=4.0),
                SensorSpec("body_body_angle", sigma_deg=0.002, body="sun", body2="moon"),
                SensorSpec("limb_star_angle", sigma_deg=0.002, body="moon", stars_per_epoch=2,
                           vmag_max=4.0))}


@pytest.mark.parametrize("name, options", [("sextant-leo", {"duration_h": 1.0}),
                                           ("sextant-leo", _SUN_FROM_LEO),
                                           ("mars-cruise", {"duration_h": 120.0})])
def test_the_model_sees_the_simulators_apparent_angles(name, options):
    """Noise-free, the model's apparent angles (aberration by the relative velocity of each
    body, ``factors.celestial_angles``) equal the simulator's, computed on their own (light
    time iterated on the ephemeris, ERFA ``epv00`` and ``ab``), to 0.1 arcsec; the geometric
    angles differ from them by arcseconds (the Earth's orbital velocity in LEO, the cruise's
    heliocentric velocity)."""
    from fgnav.apparent import without_aberration
    from fgnav.simulate.celestial_angles import apparent_angle
    from fgnav.time import j2000_seconds

    sim = simulate_pass(load_scenario(name).with_options(**options), seed=2)
    p = build_pass(sim.log)
    p_geo = without_aberration(p)
    x_true = sim.x_true[np.searchsorted(sim.t_s, p.t_s)]
    centre = getattr(sim.log, "centre", "earth")
    arcsec = np.pi / 648000
    worst_geo = 0.0
    for mdl in (LIMB_STAR_ANGLE, BODY_STAR_ANGLE, BODY_BODY_ANGLE):
        fam = p.families.get(mdl.kind)
        if fam is None:
            continue
        x = x_true[fam.k]
        tj = float(j2000_seconds(sim.log.epoch0)) + p.t_s[fam.k]
        in_log = np.flatnonzero(np.asarray(sim.log.kind) == mdl.kind)
        assert np.array_equal(np.asarray(sim.log.line)[in_log], fam.line)   # rows in log order
        codes = np.asarray(sim.log.extra["body"], float)[in_log]
        for code in np.unique(codes):
            rows = np.flatnonzero(codes == code)
            body = BODIES[int(code)]
            if mdl is BODY_BODY_ANGLE:
                body2 = BODIES[int(np.asarray(sim.log.extra["body2"], float)[in_log][rows[0]])]
                want = apparent_angle(tj[rows], x[rows], centre, body, body2=body2)
            else:
                r_limb = fam.values["r_limb_m"][rows[0]] if mdl is LIMB_STAR_ANGLE else 0.0
                want = apparent_angle(tj[rows], x[rows], centre, body,
                                      stars=fam.values["s_eci"][rows], r_limb_m=r_limb)
            e, _ = mdl.residual(fam.subset(rows), {"orbit": x[rows]})
            got = e[:, 0] + fam.values["a_rad"][rows]
            assert np.abs(got - want).max() < 0.1 * arcsec, (mdl.kind, body)
            e0, _ = mdl.residual(p_geo.families[mdl.kind].subset(rows), {"orbit": x[rows]})
            worst_geo = max(worst_geo, float(np.abs(e0[:, 0] - e[:, 0]).max()))
    assert worst_geo > 5 * arcsec


def test_a_scenario_with_a_limb_on_the_sun_is_refused_with_the_key(tmp_path, capsys):
    from fgnav.cli import main

    text = (Path(__file__).resolve().parents[1] / "fgnav/data/scenarios/sextant-leo.toml").read_text()
    bad = text.replace('body = "earth"\nstars_per_epoch = 3', 'body = "sun"\nstars_per_epoch = 3')
    assert bad != text
    (tmp_path / "s.toml").write_text(bad)
    assert main(["simulate", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "body = 'sun'" in err and "earth or moon" in err
    text2 = text.replace('body2 = "moon"', 'body2 = "earth"')
    (tmp_path / "t.toml").write_text(text2)
    assert main(["simulate", str(tmp_path / "t.toml"), "--out", str(tmp_path / "o")]) == 2
    assert "two different bodies" in capsys.readouterr().err
    (tmp_path / "u.toml").write_text(text.replace('body2 = "moon"', 'body2 = "mars"'))
    assert main(["simulate", str(tmp_path / "u.toml"), "--out", str(tmp_path / "o")]) == 2
    assert "sensor[3].body2" in capsys.readouterr().err


@pytest.mark.parametrize("scenario, kind, method", [("sextant-leo", "limb_star_angle", "batch"),
                                                    ("sextant-leo", "limb_star_angle", "ekf"),
                                                    ("geo-limb", "limb_radius", "isam2")])
def test_a_limb_sphere_larger_than_the_orbit_is_a_user_error_naming_its_line(
        tmp_path, capsys, scenario, kind, method):
    """A row whose limb sphere (column y) encloses the spacecraft (7,500 km in an 800 km LEO,
    50,000 km at GEO: a unit slip) has no limb to measure; the smoother says which line,
    exit 2, where it had raised a traceback from the observability check."""
    from fgnav.cli import main

    sim = simulate_pass(load_scenario(scenario).with_options(duration_h=0.5), seed=0)
    write_log(tmp_path / "log.csv", sim.log)
    lines = (tmp_path / "log.csv").read_text().splitlines()
    j = [i for i, t in enumerate(lines) if f",{kind}," in t][5]
    f = lines[j].split(",")
    f[3] = "5e7" if scenario == "geo-limb" else "7500000"
    lines[j] = ",".join(f)
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    assert main(["smooth", str(tmp_path / "bad.csv"), "--method", method, "--out",
                 str(tmp_path / "o"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"line {j + 1}" in err and kind in err and "limb" in err, err


def test_no_aberration_reaches_a_formations_angle_rows():
    """``--no-aberration`` on a formation's log (constellation-leo: each spacecraft's sextant
    rows) had no effect at all (the same chi-square to the last digit): the formation route
    built its pass without it. Now the angle rows take the geometric lines of sight there
    too, and the fit to the simulator's apparent angles worsens as on one spacecraft."""
    from fgnav.pipeline import smooth_log
    from fgnav.simulate.formation_sim import simulate_formation_pass

    log = simulate_formation_pass(load_scenario("constellation-leo").with_options(duration_h=0.5),
                                  seed=0).log
    on, _ = smooth_log(log, "batch")
    off, _ = smooth_log(log, "batch", aberration=False)
    assert off.solution.chi2 > 1.5 * on.solution.chi2, (on.solution.chi2, off.solution.chi2)


def test_the_geocentric_sun_and_moon_of_the_angles_are_erfas():
    """The near bodies of a geocentric angle row come from ERFA, as a heliocentric pass's do
    (``factors.planets``): the Sun from ``epv00`` (Bretagnon & Francou 1988, km-class), the
    Moon from ``moon98`` (Meeus 1998, ch. 47, ~10 arcsec). The low-precision series of
    ``factors.ephemeris`` (Montenbruck & Gill 2000, eqs. 3.43-3.49) had been used: their Moon
    is up to 2.3 arcmin off, 19x the 7.2-arcsec sigma of sextant-leo's Moon-star angle and
    ten times the aberration the angles correct for; their Sun was 4.5-5 arcmin off in 2025
    (a perigee held fixed since J2000; within ~36 arcsec since its advance was added)."""
    import erfa

    from fgnav.simulate.celestial_angles import body_position_eci_m
    from fgnav.time import j2000_seconds

    t = float(j2000_seconds(np.datetime64("2025-03-06T12:00:00"))) + np.linspace(0, 3e7, 40)
    jd = 2451545.0 + t / 86400.0
    pvh, _ = erfa.epv00(np.floor(jd), jd - np.floor(jd))
    sun = -pvh["p"] * 1.495978707e11
    moon = erfa.moon98(np.floor(jd), jd - np.floor(jd))["p"] * 1.495978707e11

    def arcsec(a, b):
        c = np.sum(a * b, 1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
        return np.degrees(np.arccos(np.clip(c, -1.0, 1.0))) * 3600.0

    assert arcsec(body_position_eci_m("sun", t), sun).max() < 0.01
    assert arcsec(body_position_eci_m("moon", t), moon).max() < 0.01
    assert np.abs(np.linalg.norm(body_position_eci_m("moon", t), axis=1)
                  - np.linalg.norm(moon, axis=1)).max() < 1.0


def test_angle_rows_beyond_the_ephemeris_span_are_a_user_error(tmp_path):
    """ERFA's ``epv00`` (the Sun of a geocentric row, every body of a heliocentric one)
    covers 1900-2100; a row outside is refused naming the line, not a ValueError traceback."""
    rows = [r.replace("2025-", "2150-") for r in ROWS]
    with pytest.raises(UserError, match=r"line 2 .*1900-2100"):
        build_pass(read_log(_write(tmp_path, rows)))
