"""Priors from the files users have (fgnav.prior_sources; ``fgnav smooth --prior FILE``):
OMM (KVN, XML), TLE, OPM, OEM.

Authorities: Vallado 2013, Example 3-15 (TEME -> J2000, IAU-76/FK5, without the EOP
nutation corrections); Vallado et al. 2006, the SGP4 verification run of satellite 00005
(tcppver.out); the real GLONASS OMMs CelesTrak wrote (../shared/data/omm-glonass/) against
the independent DOP853 integrator (fgnav.orbit.integrate_truth).
"""

import json
from pathlib import Path

import numpy as np
import pytest

from fgnav.cli import main
from fgnav.errors import InputFormatError, UserError
from fgnav.io.oem import read_oem, write_oem
from fgnav.io.omm import read_omm
from fgnav.io.opm import read_opm
from fgnav.io.tle import read_tle, tle_checksum
from fgnav.orbit import integrate_truth, rtn_frame
from fgnav.prior_sources import (DEFAULT_SIGMAS, prior_from_file, sgp4_eme2000, sgp4_teme,
                                 teme_to_eme2000_matrix)
from fgnav.time import add_seconds, format_utc, j2000_seconds, parse_utc, seconds_since

from shared_data import SHARED_DATA

GLONASS = next((d for d in (SHARED_DATA / "omm-glonass",
                            Path("/work/shared/data/omm-glonass")) if d.is_dir()), None)
needs_glonass = pytest.mark.skipif(GLONASS is None, reason="the GLONASS OMMs of "
                                   "../shared/data/omm-glonass are not beside this checkout")

# Vallado et al. 2006, verification TLE of satellite 00005 and SGP4's TEME positions (km)
TLE_00005 = ("1 00005U 58002B   00179.78495062  .00000023  00000-0  28098-4 0  4753\n"
             "2 00005  34.2682 348.7242 1859667 331.7664  19.3264 10.82419157413667\n")
R_00005_KM = {0.0: (7022.46529266, -1400.08296755, 0.03995155),
              360.0: (-7154.03120202, -3783.17682504, -3536.19412294),
              4320.0: (-9060.47373569, 4658.70952502, 813.68673153)}


def _truth_from(x0, t0, t64):
    """The independent integrator (J2, Sun, Moon) from ``x0`` at ``t0`` to the epochs ``t64``."""
    return integrate_truth(x0, seconds_since(t64, t0), third_body=True,
                           t0_j2000_s=float(j2000_seconds(np.array([t0]))[0]))


def test_teme_to_eme2000_reproduces_vallado_example_3_15():
    # Vallado 2013, Example 3-15: r_TEME, v_TEME at 2004-04-06 07:51:28.386009 UTC give
    # r_J2000 = (5102.5096, 6123.01152, 6378.1363) km, v_J2000 = (-4.7432196, 0.7905366,
    # 5.53375619) km/s without the EOP corrections (printed to 0.1 m, 0.1 mm/s).
    R = teme_to_eme2000_matrix(parse_utc("2004-04-06T07:51:28.386009Z"))
    r = R @ np.array([5094.18016210, 6127.64465950, 6380.34453270])
    v = R @ np.array([-4.746131487, 0.785818041, 5.531931288])
    np.testing.assert_allclose(r, [5102.5096, 6123.01152, 6378.1363], atol=1e-4)
    np.testing.assert_allclose(v, [-4.7432196, 0.7905366, 5.53375619], atol=1e-7)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15)


def test_tle_reader_gives_sgp4_verification_positions(tmp_path):
    path = tmp_path / "00005.tle"
    path.write_text("VANGUARD 1\n" + TLE_00005)
    el = read_tle(path)
    assert el.satnum == 5 and el.name == "VANGUARD 1" and el.e == 0.1859667
    assert format_utc(el.epoch).startswith("2000-06-27T18:50:19.7")
    for minutes, r_km in R_00005_KM.items():
        t = el.epoch + np.timedelta64(int(round(minutes * 60e9)), "ns")
        np.testing.assert_allclose(sgp4_teme(el, [t])[0, :3] / 1e3, r_km, atol=1e-6)


def _tle_of(el, yy_day: str, elset=" 999", rev="14578"):
    """The two TLE lines of mean elements (the CelesTrak TLE of the same element set)."""
    l1 = (f"1 {el.satnum:05d}U 07052A   {yy_day} -.00000087  00000-0  00000-0 0 {elset}")
    l2 = (f"2 {el.satnum:05d} {el.i_deg:8.4f} {el.raan_deg:8.4f} "
          f"{f'{el.e:.7f}'[2:]} {el.argp_deg:8.4f} {el.M_deg:8.4f} {el.n_rev_day:11.8f}{rev}")
    return [l + str(tle_checksum(l + "0")) for l in (l1, l2)]


@needs_glonass
def test_glonass_omm_kvn_and_xml_agree_and_the_tle_of_the_same_set_too(tmp_path):
    files = sorted((GLONASS / "xml").glob("*.xml"))
    assert len(files) >= 20
    for xml in files:
        a, b = read_omm(xml), read_omm(GLONASS / "kvn" / f"{xml.stem}.omm")
        assert (a.epoch, a.n_rev_day, a.e, a.i_deg, a.raan_deg, a.argp_deg, a.M_deg, a.ndot) == \
               (b.epoch, b.n_rev_day, b.e, b.i_deg, b.raan_deg, b.argp_deg, b.M_deg, b.ndot)
    el = read_omm(GLONASS / "xml" / "32275.xml")     # COSMOS 2433, epoch 2026-07-21T04:06:53.604864
    tle = tmp_path / "32275.tle"
    tle.write_text("COSMOS 2433 (720)\n" + "\n".join(_tle_of(el, "26202.17145376")) + "\n")
    t = add_seconds(el.epoch, np.array([0.0, 3600.0, 86400.0]))
    # the same SGP4 states, but for the eccentricity's 8th digit, which the TLE's 7 columns
    # drop (.00037192 -> 0003719): 0.4 m
    d = sgp4_eme2000(read_tle(tle), t) - sgp4_eme2000(el, t)
    assert np.abs(d[:, :3]).max() < 1.0 and np.abs(d[:, 3:]).max() < 1e-3


@needs_glonass
def test_sgp4_against_a_numerical_orbit_through_the_same_elements():
    # SGP4 (SDP4: GLONASS's 11 h period) against the DOP853 integrator (J2, Sun, Moon) started
    # from SGP4's own state at the elements' epoch, over 7 h: measured on the 28 CelesTrak
    # GLONASS sets 68 m .. 1.24 km (median 240 m) and 0.011 .. 0.14 m/s. The default prior
    # sigma of an element set (10 km, 10 m/s) covers it with room for the sets' fit error.
    worst = []
    for xml in sorted((GLONASS / "xml").glob("*.xml")):
        el = read_omm(xml)
        t64 = add_seconds(el.epoch, np.arange(0.0, 7 * 3600.0 + 1, 300.0))
        d = sgp4_eme2000(el, t64) - _truth_from(sgp4_eme2000(el, [el.epoch])[0], el.epoch, t64)
        worst.append((np.linalg.norm(d[:, :3], axis=1).max(),
                      np.linalg.norm(d[:, 3:], axis=1).max()))
    worst = np.array(worst)
    assert 30.0 < np.median(worst[:, 0]) < 500.0
    assert worst[:, 0].max() < 1500.0 and worst[:, 1].max() < 0.2
    assert worst[:, 0].max() < DEFAULT_SIGMAS["omm"][0] / 5


@pytest.fixture(scope="module")
def glonass_pass(tmp_path_factory):
    """A 6 h pass of COSMOS 2433 starting 1 h after its OMM's epoch, simulated with the truth
    the DOP853 integrator gives from the SGP4 state at that epoch (Earth direction and limb
    radius, 0.005 deg, every 60 s), and the TLE of the same element set."""
    if GLONASS is None:
        pytest.skip("the GLONASS OMMs of ../shared/data/omm-glonass are not beside this checkout")
    d = tmp_path_factory.mktemp("glonass")
    omm = GLONASS / "xml" / "32275.xml"
    el = read_omm(omm)
    t0 = add_seconds(el.epoch, np.array([3600.0]))[0]
    x0 = _truth_from(sgp4_eme2000(el, [el.epoch])[0], el.epoch, np.array([t0]))[0]
    r, v = ", ".join(repr(float(a)) for a in x0[:3]), ", ".join(repr(float(a)) for a in x0[3:])
    (d / "scen.toml").write_text(
        f'name = "glonass"\ndescription = "COSMOS 2433 from its OMM"\nepoch = "{format_utc(t0)}"\n'
        f'duration_h = 6.0\nstep_s = 60.0\n[orbit]\nr_eci_m = [{r}]\nv_eci_mps = [{v}]\n'
        '[truth]\nj2 = true\nthird_body = true\n[prior]\nmode = "none"\n'
        '[[sensor]]\nkind = "earth_direction"\nsigma_deg = 0.005\n'
        '[[sensor]]\nkind = "limb_radius"\nsigma_deg = 0.005\nr_limb_km = 6375.0\n')
    assert main(["simulate", str(d / "scen.toml"), "--out", str(d / "sim"), "--quiet"]) == 0
    tle = d / "32275.tle"
    tle.write_text("\n".join(_tle_of(el, "26202.17145376")) + "\n")
    return {"dir": d, "omm": omm, "kvn": GLONASS / "kvn" / "32275.omm", "tle": tle,
            "log": d / "sim" / "measurements.csv", "truth": d / "sim" / "truth.oem", "t0": t0}


@pytest.mark.parametrize("source", ["omm", "kvn", "tle"])
def test_a_pass_started_from_a_real_element_set_is_solved(glonass_pass, source, capsys):
    g = glonass_pass
    truth = read_oem(g["truth"])
    # the prior's error against the truth at the log's first epoch: SGP4's theory error
    # after 1 h (32 m, 0.003 m/s here), far inside its default 10 km, 10 m/s
    prior = prior_from_file(g[source], g["t0"])
    err = prior.x_eci - truth.x_eci[0]
    assert np.linalg.norm(err[:3]) < 100.0 and np.linalg.norm(err[3:]) < 0.02
    assert (prior.sigma_position_m, prior.sigma_velocity_mps, prior.sigma_from) == \
           (10e3, 10.0, "default")
    out = g["dir"] / f"out-{source}"
    rc = main(["smooth", str(g["log"]), "--prior", str(g[source]), "--truth", str(g["truth"]),
               "--third-body", "--out", str(out), "--quiet"])
    assert rc == 0, capsys.readouterr().err
    s = json.loads((out / "summary.json").read_text())
    assert s["integrity"]["status"] == "ok"
    assert s["initial_orbit"]["prior"] == "log"          # started from the file's prior
    assert s["prior_file"]["source"] == ("tle" if source == "tle" else "omm")
    assert s["prior_file"]["age_s"] == pytest.approx(3600.0)
    # the error within its sigma: rms against the reported 1-sigma, and the NEES (6 dof)
    assert s["position_rms_m"] < 1.5 * s["sigma_position_rms_m"]
    assert s["velocity_rms_mps"] < 1.5 * s["crb_velocity_rms_mps"]
    assert s["nees_mean"] < 9.0


def test_another_satellites_element_set_is_caught_not_solved_silently(glonass_pass, capsys):
    # COSMOS 2434's OMM for COSMOS 2433's pass: 24,000 km off. The prior test (the initial
    # orbit of the measurements) finds it inconsistent and the verdict fails the run.
    g = glonass_pass
    out = g["dir"] / "out-wrong"
    rc = main(["smooth", str(g["log"]), "--prior", str(GLONASS / "xml" / "32276.xml"),
               "--third-body", "--out", str(out), "--quiet"])
    assert rc == 0, capsys.readouterr().err
    s = json.loads((out / "summary.json").read_text())
    assert s["initial_orbit"]["prior_consistent"] is False
    assert s["integrity"]["status"] != "ok"


def test_opm_state_and_rtn_covariance_are_propagated_to_the_log(tmp_path):
    t_file = parse_utc("2025-03-01T00:00:00Z")
    x_file = np.array([7000e3, 100e3, 200e3, -50.0, 6500.0, 3500.0])
    P_rtn = np.diag([100.0, 400.0, 25.0, 1e-2, 4e-2, 1e-3])   # m^2, (m/s)^2
    cov = "\n".join(f"{k} = {P_rtn[i, j] / 1e6:.17e}" for k, (i, j) in zip(
        [f"C{a}_{b}" for n, a in enumerate(("X", "Y", "Z", "X_DOT", "Y_DOT", "Z_DOT"))
         for b in ("X", "Y", "Z", "X_DOT", "Y_DOT", "Z_DOT")[:n + 1]],
        [(i, j) for i in range(6) for j in range(i + 1)]))
    path = tmp_path / "state.opm"
    path.write_text(
        "CCSDS_OPM_VERS = 2.0\nCREATION_DATE = 2025-03-01T00:00:00\nORIGINATOR = TEST\n"
        "OBJECT_NAME = SAT\nOBJECT_ID = 2025-001A\nCENTER_NAME = EARTH\nREF_FRAME = EME2000\n"
        "TIME_SYSTEM = UTC\nCOMMENT state\nEPOCH = 2025-03-01T00:00:00.000\n"
        + "".join(f"{k} = {float(x_file[i]) / 1e3!r} [{'km' if i < 3 else 'km/s'}]\n"
                  for i, k in enumerate(("X", "Y", "Z", "X_DOT", "Y_DOT", "Z_DOT")))
        + "COV_REF_FRAME = RTN\n" + cov + "\n")
    o = read_opm(path)
    np.testing.assert_allclose(o.x, x_file)
    t_log = add_seconds(t_file, np.array([600.0]))[0]
    prior = prior_from_file(path, t_log)
    np.testing.assert_allclose(prior.x_eci, _truth_from(x_file, t_file, np.array([t_log]))[0],
                               atol=1e-6)
    # the covariance: RTN -> EME2000 at the file's epoch, then Phi P Phi^T; positive definite,
    # grown along track, and the rows' sigma its covering sphere
    A = np.kron(np.eye(2), rtn_frame(x_file).T)
    P0 = A @ P_rtn @ A.T
    assert np.trace(prior.P_eci[:3, :3]) > np.trace(P0[:3, :3])
    assert np.all(np.linalg.eigvalsh(prior.P_eci) > 0)
    assert prior.sigma_from == "file"
    assert prior.sigma_position_m == pytest.approx(
        np.sqrt(np.linalg.eigvalsh(prior.P_eci[:3, :3])[-1]))
    # the options replace the file's sigmas
    p2 = prior_from_file(path, t_log, sigma_position_m=5e3)
    assert (p2.sigma_position_m, p2.sigma_velocity_mps, p2.sigma_from) == \
           (5e3, prior.sigma_velocity_mps, "option")


def test_oem_prior_is_the_ephemeris_at_the_log_first_epoch(tmp_path):
    t0 = parse_utc("2025-03-01T00:00:00Z")
    x0 = np.array([7000e3, 0.0, 0.0, 0.0, 6000.0, 4500.0])
    t = np.arange(0.0, 1801.0, 60.0)
    x = integrate_truth(x0, t)
    path = tmp_path / "eph.oem"
    write_oem(path, t0, t, x, None)
    t_log = add_seconds(t0, np.array([630.0]))[0]     # between two ephemeris lines
    prior = prior_from_file(path, t_log)
    np.testing.assert_allclose(prior.x_eci[:3], integrate_truth(x0, np.array([630.0]))[0, :3],
                               atol=0.01)
    assert (prior.sigma_position_m, prior.sigma_from) == (DEFAULT_SIGMAS["oem"][0], "default")
    with pytest.raises(UserError, match="does not cover"):
        prior_from_file(path, add_seconds(t0, np.array([4000.0]))[0])
    # with covariances: the block nearest the log's first epoch (600 s), its covering sphere
    P = np.array([np.diag([(100.0 + k) ** 2] * 3 + [0.1 ** 2] * 3) for k in range(len(t))])
    write_oem(path, t0, t, x, P)
    prior = prior_from_file(path, t_log)
    assert prior.sigma_from == "file"
    assert prior.sigma_position_m == pytest.approx(110.0) and \
        prior.sigma_velocity_mps == pytest.approx(0.1)


@needs_glonass
def test_bad_files_name_file_line_and_keyword(tmp_path):
    text = (GLONASS / "kvn" / "32275.omm").read_text()
    cases = {
        "bad_number.omm": (text.replace("ECCENTRICITY   = .00037192", "ECCENTRICITY   = 0.0003x"),
                           "line 14", "ECCENTRICITY"),
        "bad_unit.omm": (text.replace("INCLINATION    = 65.5556", "INCLINATION    = 65.5556 [rad]"),
                         "line 15", "INCLINATION"),
        "unknown.omm": (text.replace("BSTAR          = 0", "BSTAR_X = 0"), "line 25", "BSTAR_X"),
        "theory.omm": (text.replace("SGP/SGP4", "DSST"), "line 10", "MEAN_ELEMENT_THEORY"),
        "missing.omm": (text.replace("MEAN_ANOMALY   = 156.1614\n", ""), "MEAN_ANOMALY", ""),
        "frame.omm": (text.replace("REF_FRAME      = TEME", "REF_FRAME      = EME2000"),
                      "line 8", "REF_FRAME"),
    }
    for name, (body, where, key) in cases.items():
        p = tmp_path / name
        p.write_text(body)
        with pytest.raises(InputFormatError) as exc:
            read_omm(p)
        assert name in str(exc.value) and where in str(exc.value) and key in str(exc.value), \
            str(exc.value)
    xml = (GLONASS / "xml" / "32275.xml").read_text()
    p = tmp_path / "broken.xml"
    p.write_text(xml.replace("</MEAN_MOTION>", "</MEAN_MOTIO>"))
    with pytest.raises(InputFormatError, match="broken.xml, line 3.*well-formed XML"):
        read_omm(p)
    lines = TLE_00005.splitlines()
    p = tmp_path / "checksum.tle"
    p.write_text(lines[0][:-1] + "0\n" + lines[1] + "\n")
    with pytest.raises(InputFormatError, match=r"checksum.tle, line 1, column 'checksum"):
        read_tle(p)
    p = tmp_path / "mixed.tle"
    other = lines[1].replace("2 00005", "2 00006")[:-1]
    p.write_text(lines[0] + "\n" + other + str(tle_checksum(other + "0")) + "\n")
    with pytest.raises(InputFormatError, match="line 2, column 'catalogue number"):
        read_tle(p)


def test_cli_refusals_exit_2_without_traceback(tmp_path, capsys):
    log = tmp_path / "pass.csv"
    log.write_text("epoch,kind,x,y,z,sigma\n"
                   "2025-03-01T00:00:00Z,prior_position,7000000,0,0,1000\n"
                   "2025-03-01T00:00:00Z,prior_velocity,0,7500,0,1\n"
                   "2025-03-01T00:00:00Z,earth_direction,-1,0,0,1e-4\n"
                   "2025-03-01T00:01:00Z,earth_direction,-0.6,-0.8,0,1e-4\n")
    bare = tmp_path / "bare.csv"
    bare.write_text("".join(l + "\n" for l in log.read_text().splitlines() if "prior" not in l))
    tle = tmp_path / "sat.tle"
    tle.write_text(TLE_00005)
    opm = tmp_path / "burn.opm"
    opm.write_text("CCSDS_OPM_VERS = 2.0\nCREATION_DATE = 2025-03-01T00:00:00\nORIGINATOR = X\n"
                   "OBJECT_NAME = S\nOBJECT_ID = 1\nCENTER_NAME = EARTH\nREF_FRAME = EME2000\n"
                   "TIME_SYSTEM = UTC\nEPOCH = 2025-03-01T00:00:00\nX = 7000\nY = 0\nZ = 0\n"
                   "X_DOT = 0\nY_DOT = 7.5\nZ_DOT = 0\nMAN_EPOCH_IGNITION = 2025-03-01T00:10:00\n")
    junk = tmp_path / "junk.txt"
    junk.write_text("hello\n")
    for argv, words in (
            ([str(log), "--prior", str(tle)], ["pass.csv", "sat.tle", "prior rows", "line 2"]),
            ([str(bare), "--prior", str(opm)], ["burn.opm", "line 16", "MAN_EPOCH_IGNITION"]),
            ([str(bare), "--prior", str(junk)], ["junk.txt", "OMM", "TLE"]),
            ([str(log), "--prior", str(tmp_path / "none.omm")], ["none.omm", "no such file"]),
            ([str(log), "--prior", str(tle), "--ignore-prior"], ["--ignore-prior", "--prior"]),
            ([str(log), "--prior-sigma-km", "3"], ["--prior-sigma-km", "--prior FILE"])):
        rc = main(["smooth", *argv, "--out", str(tmp_path / "r")])
        err = capsys.readouterr().err
        assert rc == 2 and "Traceback" not in err, err
        for w in words:
            assert w in err, (w, err)


CCSDS_ANNEX = next((d for d in (SHARED_DATA / "ccsds" / "annex-examples" / "kvn",
                                Path("/work/shared/data/ccsds/annex-examples/kvn")) if d.is_dir()),
                   None)


@pytest.mark.skipif(CCSDS_ANNEX is None, reason="the ODM annex examples of ../shared/data/ccsds "
                    "are not beside this checkout")
def test_omm_covariance_of_the_blue_book_annex_is_used_and_propagated():
    # ODM annex G-8: GOES 9's SGP4 elements with a TEME covariance (km**2 ..., 18-26 m)
    path = CCSDS_ANNEX / "omm_g8.kvn"
    el = read_omm(path)
    at_epoch = prior_from_file(path, el.epoch)
    assert at_epoch.sigma_from == "file" and at_epoch.age_s == 0.0
    # a rotation leaves the covering sphere as it is
    assert at_epoch.sigma_position_m == pytest.approx(
        np.sqrt(np.linalg.eigvalsh(el.P_teme[:3, :3])[-1]), rel=1e-9)
    later = prior_from_file(path, add_seconds(el.epoch, np.array([3600.0]))[0])
    assert later.sigma_position_m > 2 * at_epoch.sigma_position_m   # the velocity's 1 h
    np.testing.assert_allclose(later.P_eci, later.P_eci.T, rtol=1e-9, atol=1e-12)


def test_a_geocentric_element_set_for_a_cruise_or_several_spacecraft_is_refused(tmp_path):
    from fgnav.io.log_csv import MeasurementLog
    from fgnav.prior_sources import prior_for_log

    tle = tmp_path / "sat.tle"
    tle.write_text(TLE_00005)
    rows = dict(path="cruise.csv", epoch0=parse_utc("2000-06-28T00:00:00Z"),
                t_s=np.array([0.0, 60.0]), kind=np.array(["earth_direction"] * 2),
                xyz=np.array([[1.0, 0.0, 0.0]] * 2), sigma=np.array([1e-4, 1e-4]),
                line=np.array([2, 3]))
    with pytest.raises(UserError, match="geocentric.*about the sun"):
        prior_for_log(MeasurementLog(**rows, centre="sun"), tle)
    with pytest.raises(UserError, match="2 spacecraft"):
        prior_for_log(MeasurementLog(**rows, spacecraft=("a", "b")), tle)
    log, prior = prior_for_log(MeasurementLog(**rows), tle)
    assert list(log.kind[:2]) == ["prior_position", "prior_velocity"] and len(log.t_s) == 4
    np.testing.assert_array_equal(log.xyz[0], prior.x_eci[:3])
    assert list(log.line) == [0, 0, 2, 3] and log.sigma[0] == DEFAULT_SIGMAS["tle"][0]


def test_a_teme_opm_is_rotated_like_sgp4_states(tmp_path):
    # Vallado 2013, Example 3-15's TEME state as an OPM at its epoch: the prior is its J2000
    # state (age 0, no propagation), to the example's printed 0.1 m and 0.1 mm/s
    path = tmp_path / "teme.opm"
    path.write_text(
        "CCSDS_OPM_VERS = 3.0\nCREATION_DATE = 2004-04-06T00:00:00\nORIGINATOR = TEST\n"
        "OBJECT_NAME = EX3-15\nOBJECT_ID = 2004-000A\nCENTER_NAME = EARTH\nREF_FRAME = TEME\n"
        "TIME_SYSTEM = UTC\nEPOCH = 2004-04-06T07:51:28.386009\n"
        "X = 5094.18016210 [km]\nY = 6127.64465950 [km]\nZ = 6380.34453270 [km]\n"
        "X_DOT = -4.746131487 [km/s]\nY_DOT = 0.785818041 [km/s]\nZ_DOT = 5.531931288 [km/s]\n")
    prior = prior_from_file(path, parse_utc("2004-04-06T07:51:28.386009Z"))
    np.testing.assert_allclose(prior.x_eci[:3] / 1e3, [5102.5096, 6123.01152, 6378.1363],
                               atol=1e-4)
    np.testing.assert_allclose(prior.x_eci[3:] / 1e3, [-4.7432196, 0.7905366, 5.53375619],
                               atol=1e-7)
    assert (prior.sigma_position_m, prior.sigma_from) == (DEFAULT_SIGMAS["opm"][0], "default")


def test_a_ccsds_tdm_starts_from_an_oem_prior(tmp_path, capsys):
    # The shipped spacecraft TDM (gto-transfer, Earth directions only, no prior rows) with the
    # OEM of the pass it was simulated from as --prior: the solvers start from the OEM's
    # state (1 km, 1 m/s by default) instead of the initial orbit determination.
    from importlib.resources import files

    sample = files("fgnav") / "data" / "tdm" / "gto-transfer.tdm"
    if not sample.is_file():
        pytest.skip("no sample TDM in fgnav/data/tdm")
    sim = tmp_path / "pass"
    assert main(["simulate", "gto-transfer", "--step-s", "60", "--seed", "0", "--out", str(sim),
                 "--quiet"]) == 0
    out = tmp_path / "r"
    rc = main(["smooth", str(sample), "--sigma-deg", "0.01", "--prior", str(sim / "truth.oem"),
               "--truth", str(sim / "truth.oem"), "--out", str(out), "--quiet"])
    assert rc == 0, capsys.readouterr().err
    s = json.loads((out / "summary.json").read_text())
    assert s["initial_orbit"]["prior"] == "log" and s["prior_file"]["source"] == "oem"
    assert s["prior_file"]["sigma_from"] == "default" and s["prior_file"]["age_s"] == 0.0
    assert s["integrity"]["status"] == "ok"
    assert s["position_rms_m"] < 2 * s["crb_position_rms_m"]
