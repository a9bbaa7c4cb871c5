"""The heliocentric cruise: the planetary ephemeris (pyerfa), the Sun-centred motion model
against the independent DOP853 truth, the log's ``# centre:`` line, the SUN/ICRF OEM, the
closed-form cone-cone-torus fix of the INS/CNS lecture's Mars-transfer example, and a short
``mars-cruise`` pass smoothed from no prior against the truth and the Cramér–Rao bound."""

from __future__ import annotations

import numpy as np
import pytest

from factors.constants import AU_M
from factors.dynamics import MotionModel, propagate, propagate_many
from factors.interpret import interpreted
from factors.planets import (TABLE_STEP_S, earth_position_helio_m, planet_state_helio,
                             table_positions_nb, third_body_positions_m, third_body_table)
from fgnav.errors import InputFormatError, UserError
from fgnav.io.log_csv import log_from_arrays, read_log, write_log
from fgnav.io.oem import oem_frame, read_oem, write_oem
from fgnav.orbit import integrate_truth
from fgnav.time import j2000_seconds, parse_utc

T0 = float(j2000_seconds(parse_utc("2027-01-16T00:00:00Z")))
X0 = np.array([-71411267196.027, 125952896819.755, 54598746250.093,
               -29785.150028, -10095.289159, -4375.961482])   # the mars-cruise start


def test_two_ephemeris_series_agree_and_the_table_interpolates_them():
    # epv00's Earth and plan94's Earth-Moon barycentre are separate series (VSOP87/DE405 fit
    # and Simon et al. 1994): they differ by the barycentre offset (<= 4,700 km) plus
    # plan94's error (~0.6 arcsec = 450 km at 1 AU)
    t = T0 + np.linspace(0.0, 400.0, 41) * 86400.0
    d = np.linalg.norm(earth_position_helio_m(t) - planet_state_helio(3, t)[0], axis=1)
    assert d.max() < 6.0e6 and d.min() > 1.0e5, (d.min(), d.max())
    assert np.allclose(np.linalg.norm(earth_position_helio_m(t), axis=1) / AU_M, 1.0, atol=0.02)
    # the kernels' one-day Hermite table against plan94 itself, between the nodes
    tab = third_body_table()
    tm = T0 + (np.arange(30) + 0.37) * TABLE_STEP_S
    out = np.empty((5, 3))
    direct = third_body_positions_m(tm)
    err = []
    for n, tt in enumerate(tm):
        table_positions_nb.py_func(tab, tt, out)
        err.append(np.linalg.norm(out - direct[n], axis=1))
    assert np.max(err) < 200.0, np.max(err)       # metres, Venus the worst


def test_heliocentric_rk4_follows_the_independent_dop853_truth():
    t = np.arange(0.0, 10 * 86400.0 + 1.0, 6 * 3600.0)
    X = integrate_truth(X0, t, third_body=True, t0_j2000_s=T0, centre="sun")
    X_sun = integrate_truth(X0, t, third_body=False, t0_j2000_s=T0, centre="sun")
    m = MotionModel.heliocentric()
    x = X0.copy()
    for k in range(1, len(t)):
        x = propagate(x, t[k] - t[k - 1], m, T0 + t[k - 1], with_stm=False)[0]
    assert np.linalg.norm(x[:3] - X[-1, :3]) < 1.0           # m after 10 days
    # the planets are in both: without them the truth is thousands of km elsewhere
    assert np.linalg.norm(X_sun[-1, :3] - X[-1, :3]) > 1.0e6
    # the vectorized (interpreted) and compiled routes of propagate_many agree
    with interpreted():
        Y1, P1 = propagate_many(X[:-1], np.diff(t), m, T0 + t[:-1])
    Y2, P2 = propagate_many(X[:-1], np.diff(t), m, T0 + t[:-1])
    assert np.allclose(Y1, Y2, rtol=0, atol=1e-6) and np.allclose(P1, P2, atol=1e-9)
    # the STM is the derivative of the map (central differences on the position)
    x1, Phi = propagate(X0, 86400.0, m, T0)
    for j in range(3):
        h = np.zeros(6)
        h[j] = 1.0e5   # m: roundoff of a 1.5e11 m state stays below 1e-10 of the derivative
        num = (propagate(X0 + h, 86400.0, m, T0)[0] - propagate(X0 - h, 86400.0, m, T0)[0]) / 2.0e5
        assert np.allclose(num, Phi[:, j], rtol=1e-6, atol=1e-9)


def test_the_default_model_is_geocentric_and_has_no_table():
    m = MotionModel()
    assert m.centre == "earth" and m.args()[-1].shape == (1, 6) and m.args()[-1][0, 2] == 0
    with pytest.raises(ValueError, match="centre"):
        MotionModel(centre="mars")


def _helio_log(tmp_path, kinds=("body_body_angle",)):
    n = len(kinds)
    extra = {"body": np.array(["sun"] * n, dtype=object), "body2": np.array(["earth"] * n, dtype=object)}
    log = log_from_arrays("2027-01-16T00:00:00Z", np.arange(n) * 60.0, np.array(kinds),
                          np.column_stack([np.full(n, 0.6), np.full((n, 2), np.nan)]),
                          np.full(n, 5e-5), extra, centre="sun")
    path = tmp_path / "m.csv"
    write_log(path, log)
    return path


def test_the_log_declares_its_centre_on_a_comment_line(tmp_path):
    path = _helio_log(tmp_path)
    text = path.read_text()
    assert "# centre: sun\n" in text
    assert read_log(path).centre == "sun"
    # a geocentric log is written as before: no centre line, read as the Earth
    lines = [ln for ln in text.splitlines() if not ln.startswith("# centre")]
    geo = tmp_path / "g.csv"
    geo.write_text("\n".join(lines) + "\n")
    assert read_log(geo).centre == "earth"
    bad = tmp_path / "b.csv"
    bad.write_text(text.replace("# centre: sun", "# centre: mars"))
    with pytest.raises(InputFormatError, match=r"line 2.*centre.*earth, sun.*mars"):
        read_log(bad)
    two = tmp_path / "t.csv"
    two.write_text(text.replace("# centre: sun\n", "# centre: sun\n# centre: earth\n"))
    with pytest.raises(InputFormatError, match=r"line 3.*once"):
        read_log(two)
    # a geocentric kind cannot be in a heliocentric log
    geo_kind = tmp_path / "k.csv"
    geo_kind.write_text(text + "2027-01-16T00:10:00Z,altitude,400000,6371000,,10,,\n")
    with pytest.raises(InputFormatError, match=r"line 5.*kind.*heliocentric.*altitude"):
        read_log(geo_kind)
    with pytest.raises(UserError, match="centre"):
        log_from_arrays("2027-01-16T00:00:00Z", [0.0], ["prior_position"], [[1e11, 0, 0]],
                        [1e3], centre="moon")


def test_oem_centre_and_frame(tmp_path):
    t = np.array([0.0, 60.0])
    write_oem(tmp_path / "s.oem", "2027-01-16T00:00:00Z", t, np.vstack([X0, X0]), **oem_frame("sun"))
    o = read_oem(tmp_path / "s.oem")
    assert o.meta["CENTER_NAME"] == "SUN" and o.meta["REF_FRAME"] == "ICRF"
    assert np.allclose(o.x_eci[0], X0, rtol=1e-12)
    assert oem_frame("earth") == {}
    other = tmp_path / "m.oem"  # read with its centre; --truth checks it against the log's
    other.write_text((tmp_path / "s.oem").read_text().replace("CENTER_NAME = SUN", "CENTER_NAME = MARS"))
    assert read_oem(other).meta["CENTER_NAME"] == "MARS"


def test_the_lecture_example_two_cones_and_a_torus_in_closed_form():
    """Two Sun-star angles and a Sun-Earth angle from the spacecraft (the lecture's
    r . i_j = -r cos A_j and r . r_p = r^2 - r |r - r_p| cos A_3, r from the Sun): the closed
    form gives two roots, one of them the spacecraft, the other its mirror about the stars'
    plane; both satisfy the three equations."""
    from fgnav.iod.geometric import cone_torus_candidates
    from fgnav.models.registry import BODY_BODY_ANGLE, BODY_STAR_ANGLE
    from fgnav.measurements import Family

    r = X0[:3]
    rp = earth_position_helio_m(T0)
    s = np.array([[0.0, 0.0, 1.0], [0.6, 0.8, 0.0]])
    A = np.arccos(-(s @ r) / np.linalg.norm(r))                         # lecture's cones
    A3 = np.arccos((r @ r - r @ rp) / (np.linalg.norm(r) * np.linalg.norm(r - rp)))  # torus
    one = np.zeros(2, dtype=int)
    cones = Family(k=one, values={"a_rad": A, "p_body_eci_m": np.zeros((2, 3)), "s_eci": s},
                   sigma=np.full(2, 5e-5), line=one)
    torus = Family(k=one[:1], values={"a_rad": np.array([A3]), "p_body_eci_m": np.zeros((1, 3)),
                                      "p_body2_eci_m": rp[None]}, sigma=np.full(1, 5e-5), line=one[:1])
    c = cone_torus_candidates([(BODY_STAR_ANGLE, cones), (BODY_BODY_ANGLE, torus)])
    assert len(c) == 2
    assert min(np.linalg.norm(c - r, axis=1)) < 1.0                    # metres
    for q in c:
        n = np.linalg.norm(q)
        assert np.allclose(q @ s.T, -n * np.cos(A), rtol=0, atol=1e-3 * n)
        assert q @ rp == pytest.approx(n * n - n * np.linalg.norm(q - rp) * np.cos(A3), rel=1e-9)


def test_a_short_cruise_from_no_prior_reaches_the_truth_within_its_bound(tmp_path):
    from fgnav.diagnostics.crb import cramer_rao_bound
    from fgnav.iod.geometric import fixes_along
    from fgnav.measurements import build_pass
    from fgnav.pipeline import accuracy_metrics, smooth_log
    from fgnav.scenarios import load_scenario
    from fgnav.simulate.pass_sim import simulate_pass
    from fgnav.solvers.options import SmootherOptions

    scn = load_scenario("mars-cruise").with_options(duration_h=120.0, step_s=28800.0)
    assert scn.centre == "sun" and scn.prior_mode == "none"
    sim = simulate_pass(scn, seed=3)
    assert sim.log.centre == "sun" and "prior_position" not in set(sim.log.kind)
    res, p = smooth_log(sim.log, truth=(sim.t_s, sim.x_true))
    sol, s = res.solution, res.summary
    assert s["initial_orbit"]["method"] == "geometric-fixes+lm"
    assert s["centre"] == "sun"
    xt = sim.x_true[np.searchsorted(sim.t_s, sol.t_s)]
    crb = cramer_rao_bound(p, xt, SmootherOptions(centre="sun").motion_model())
    m = accuracy_metrics(sol, xt)
    assert m["sigma_position_rms_m"] == pytest.approx(crb.position_rms_m, rel=0.05)
    assert m["position_rms_m"] < 3.0 * crb.position_rms_m, (m, crb.position_rms_m)
    assert m["nees_mean"] < 22.5     # chi-square 6 dof at 1 - 1e-3
    # every epoch's geometric fix against the truth, with its predicted sigma
    fx, _ = fixes_along(build_pass(sim.log), xt)
    z2 = np.einsum("ki,kij,kj->k", fx.r_eci_m - xt[fx.k, :3], np.linalg.inv(fx.P_m2),
                   fx.r_eci_m - xt[fx.k, :3])
    assert len(fx.k) == len(sol.t_s) and np.mean(z2) < 3.0 * 3
    # and the smoother beats a single epoch's fix by a wide margin
    assert m["position_rms_m"] < 0.5 * np.sqrt(np.mean(np.trace(fx.P_m2, axis1=1, axis2=2)))


@pytest.mark.slow
def test_the_cruise_over_20_seeds_reaches_the_bound_with_credible_covariances():
    """scripts/study_mars_cruise.py's study (about 5 min here): the geometric fixes' NEES
    and the smoother's inside their 95 % bands, the smoother at the Cramér–Rao bound."""
    from fgnav.analysis.cruise_study import run_cruise_study

    s = run_cruise_study(range(20))
    lo, hi = s["nees_band_95"]
    assert lo < s["nees_mean"] < hi, s["nees_mean"]
    flo, fhi = s["fix_nees_band_95"]
    assert flo < s["fix_nees"] < fhi, s["fix_nees"]
    assert 0.8 < s["position_rms_m"] / s["crb_position_rms_m"] < 1.25
    assert s["sigma_position_rms_m"] == pytest.approx(s["crb_position_rms_m"], rel=0.02)
    assert all(r["start"] == "geometric-fixes+lm" for r in s["rows"])
    # the angles are apparent (up to 22 arcsec from the geometric ones against a 1 arcsec
    # sensor): not modelled, the smoother is far off and says so
    assert s["no_aberration_position_rms_m"] > 5 * s["position_rms_m"]
    assert s["no_aberration_nees_mean"] > 10 * hi
