"""Sun and Moon directions in the body frame as factors on (orbit, attitude).

Without ``--estimate attitude`` a log of the INS/CNS lecture's scheme (Sun, Moon and Earth
directions in the body frame, altimeter) is preprocessed: TRIAD attitude from the Sun and the
Moon, Earth direction to ECI (``fgnav.sun_earth_moon.preprocess_log``). With it, the raw rows
stay: each is ``factors.direction.body_direction_residual`` with its target at the ephemeris
position of the row's epoch (parallax included), the attitude a Rot3 per epoch. Both routes
must give an orbit of the same class; the tight one an attitude within its own sigma of the
simulator's true attitude (LVLH), with batch and iSAM2 agreeing.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from factors.ephemeris import sun_position_eci_m
from factors.planets import moon_position_geo_m, sun_position_geo_m
from factors.direction import body_direction_residual
from factors.geometry import so3_exp, so3_log
from factors.testing import check_jacobians
from fgnav.errors import UserError
from fgnav.io.log_csv import log_from_arrays, write_log
from fgnav.measurements import build_pass, check_observable, with_estimates
from fgnav.models.registry import (ALTITUDE, ATTITUDE, ATTITUDE_VARIABLE, EARTH_DIRECTION,
                                   EARTH_DIRECTION_BODY, MOON_DIRECTION_BODY,
                                   SUN_DIRECTION_BODY)
from fgnav.pipeline import accuracy_metrics, read_measurements, solve
from fgnav.scenarios import load_scenario
from fgnav.simulate.body_directions import lvlh_R_eci_from_body
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.solvers.options import SmootherOptions
from fgnav.sun_earth_moon import preprocess_log
from fgnav.time import j2000_seconds

ATT = replace(SmootherOptions(), estimate=(ATTITUDE_VARIABLE.name,))


def _sim(duration_h, seed):
    scn = load_scenario("leo-sun-earth-moon").with_options(duration_h=duration_h)
    return simulate_pass(scn, seed=seed)


@pytest.fixture(scope="module")
def sem_hour():
    return _sim(1.0, 0)


def _attitude_errors(sim, sol):
    w, P = sol.variables[ATTITUDE_VARIABLE.name]
    R_true = lvlh_R_eci_from_body(sim.x_true[np.searchsorted(sim.t_s, sol.t_s)])
    err = so3_log(np.swapaxes(R_true, 1, 2) @ so3_exp(w))   # body-frame rotation error, rad
    return err, np.sqrt(np.diagonal(P, axis1=1, axis2=2))


def test_sun_position_jacobian_is_tiny_but_correct():
    """The Sun's parallax: the residual moves with the spacecraft position by 1/|p - r|
    (~7e-12 rad/m), which central differences over 1 km steps resolve."""
    rng = np.random.default_rng(4)
    n = 8
    t = 8.0e8 + rng.uniform(0, 3e7, n)
    p = sun_position_eci_m(t)
    r = rng.normal(0, 1, (n, 3))
    r *= 7.0e6 / np.linalg.norm(r, axis=1, keepdims=True)
    R = so3_exp(rng.normal(0, 1, (n, 3)))
    d = (p - r) / np.linalg.norm(p - r, axis=1, keepdims=True)
    u = np.einsum("nji,nj->ni", R, d) + rng.normal(0, 1e-3, (n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    e, H_r, H_R = body_direction_residual(r, R, p, u)
    check_jacobians(body_direction_residual, (r, R, p, u), (H_r, H_R, None, None),
                    ("vector", "rot3", None, None), rtol=1e-5, eps=(1e3, 1e-6, None, None),
                    names=("r_eci_m", "R_eci_from_body", "p_target_eci_m", "u_meas_body"))
    # largest singular value of the 2x3 position Jacobian: 1/|p - r| (u near the prediction)
    s_max = np.linalg.svd(H_r, compute_uv=False)[:, 0]
    np.testing.assert_allclose(s_max, 1.0 / np.linalg.norm(p - r, axis=1), rtol=2e-3)
    assert np.all(s_max < 1e-11)


def test_sun_and_moon_rows_carry_their_epoch_target_and_a_triad_first_guess(sem_hour):
    sim = sem_hour
    p = with_estimates(build_pass(sim.log), (ATTITUDE_VARIABLE.name,))
    assert {SUN_DIRECTION_BODY.kind, MOON_DIRECTION_BODY.kind,
            EARTH_DIRECTION_BODY.kind, ALTITUDE.kind} <= set(p.families)
    t0 = float(j2000_seconds(sim.log.epoch0))
    for mdl, eph in ((SUN_DIRECTION_BODY, sun_position_geo_m), (MOON_DIRECTION_BODY,
                                                                moon_position_geo_m)):
        fam = p.families[mdl.kind]
        np.testing.assert_allclose(fam.values["t_j2000_s"], t0 + p.t_s[fam.k], rtol=0, atol=1e-6)
        np.testing.assert_allclose(fam.values["p_target_eci_m"], eph(t0 + p.t_s[fam.k]),
                                   rtol=1e-12)
    # the first guess at the Moon rows: TRIAD of Sun and Moon (Moon parallax left in,
    # <= ~1.1 deg in LEO); none at the other epochs (the solvers carry the attitude there)
    fam = p.families[MOON_DIRECTION_BODY.kind]
    assert SUN_DIRECTION_BODY.initial is None
    w = MOON_DIRECTION_BODY.initial(fam)[ATTITUDE_VARIABLE.name]
    R_true = lvlh_R_eci_from_body(sim.x_true[np.searchsorted(sim.t_s, p.t_s[fam.k])])
    err = np.degrees(np.linalg.norm(so3_log(np.swapaxes(R_true, 1, 2) @ so3_exp(w)), axis=1))
    assert np.all(np.isfinite(fam.values["u_partner_body"]))     # no eclipse in this hour
    assert err.max() < 1.5 and err.min() > 0.01                  # a guess, not the truth
    # a Moon row without a Sun row (eclipse): the nearest guess, turned onto its own Moon
    eclipsed = fam.subset(np.arange(len(fam)))
    eclipsed.values["u_partner_body"][: len(fam) // 2] = np.nan
    w2 = MOON_DIRECTION_BODY.initial(eclipsed)[ATTITUDE_VARIABLE.name]
    np.testing.assert_allclose(w2[len(fam) // 2:], w[len(fam) // 2:], rtol=0, atol=1e-12)
    m_eci = fam.values["p_target_eci_m"] / np.linalg.norm(fam.values["p_target_eci_m"], axis=1,
                                                          keepdims=True)
    m_guess = np.einsum("nij,nj->ni", so3_exp(w2), fam.values["u_body"])
    np.testing.assert_allclose(m_guess[: len(fam) // 2], m_eci[: len(fam) // 2], rtol=0,
                               atol=1e-12)
    err2 = np.degrees(np.linalg.norm(so3_log(np.swapaxes(R_true, 1, 2) @ so3_exp(w2)), axis=1))
    assert err2.max() < 10.0                 # held over <= a few minutes of Moon rows
    # no Sun row at all: no guess (nothing pairs with the Moon)
    eclipsed.values["u_partner_body"][:] = np.nan
    assert MOON_DIRECTION_BODY.initial(eclipsed) == {}

def test_read_measurements_keeps_the_raw_rows_only_with_the_attitude_estimated(sem_hour,
                                                                               tmp_path):
    path = tmp_path / "sem.csv"
    write_log(path, sem_hour.log)
    raw = read_measurements(path, (ATTITUDE_VARIABLE.cli_name,))
    assert raw.counts() == sem_hour.log.counts()
    pre = read_measurements(path)
    assert set(pre.counts()) == {"prior_position", "prior_velocity", ALTITUDE.kind,
                                 EARTH_DIRECTION.kind, ATTITUDE.kind}
    assert pre.counts()[EARTH_DIRECTION.kind] == preprocess_log(sem_hour.log)[0].counts()[
        EARTH_DIRECTION.kind]


def test_the_attitude_is_fixed_by_two_body_directions_not_by_one(sem_hour):
    """Sun + Earth (or Sun + Moon) fix a rotation; the Sun alone leaves the roll about it free."""
    log = sem_hour.log
    both = with_estimates(build_pass(log), (ATTITUDE_VARIABLE.name,))
    check_observable(both)
    keep = ~np.isin(log.kind, [EARTH_DIRECTION_BODY.kind, MOON_DIRECTION_BODY.kind])
    sun_only = log_from_arrays(log.epoch0, log.t_s[keep], log.kind[keep], log.xyz[keep],
                               log.sigma[keep])
    with pytest.raises(UserError, match="nothing fixes it"):
        check_observable(with_estimates(build_pass(sun_only), (ATTITUDE_VARIABLE.name,)))


def test_tight_route_orbit_and_attitude_against_truth(sem_hour):
    """One hour, seed 0: the orbit close to the TRIAD route's (within 15 %: 83.5 m against
    76.1 m since the Sun series gained its perigee advance, 5 % before), consistent with its
    own covariance; the attitude within its sigma of the LVLH truth; batch = iSAM2. (Per seed
    the two routes' errors differ either way; the Monte Carlo below compares them over
    seeds.)"""
    sim = sem_hour
    p_raw = build_pass(sim.log)
    p_pre = build_pass(preprocess_log(sim.log)[0])
    triad = solve(p_pre, "batch", SmootherOptions())
    tight = solve(p_raw, "batch", ATT)
    x_true = sim.x_true[np.searchsorted(sim.t_s, tight.t_s)]
    a_triad = accuracy_metrics(triad, sim.x_true[np.searchsorted(sim.t_s, triad.t_s)])
    a_tight = accuracy_metrics(tight, x_true)
    assert a_tight["position_rms_m"] < 1.15 * a_triad["position_rms_m"]
    assert a_tight["position_rms_m"] < 2.0 * a_tight["sigma_position_rms_m"]
    assert a_tight["nees_mean"] < 12.0
    err, sig = _attitude_errors(sim, tight)
    assert np.sqrt(np.mean(err ** 2)) < 2.0e-4                  # ~40 arcsec: arcminute sensors
    nees = np.mean(np.sum(err ** 2 / sig ** 2, axis=1))         # 3 dof
    assert 0.5 * 3 < nees < 1.5 * 3
    assert np.abs(err / sig).max() < 5.0
    isam = solve(p_raw, "isam2", ATT)
    np.testing.assert_allclose(isam.x_eci[:, :3], tight.x_eci[:, :3], rtol=0, atol=1e-2)
    w_b, w_i = tight.variables[ATTITUDE_VARIABLE.name][0], isam.variables[ATTITUDE_VARIABLE.name][0]
    d = so3_log(np.swapaxes(so3_exp(w_b), 1, 2) @ so3_exp(w_i))
    assert np.abs(d).max() < 1e-8


def test_tight_route_beats_triad_over_seeds():
    """Eight one-hour passes: the tight route's position RMS over the seeds is below the
    TRIAD route's (it also uses the epochs without the Moon: Sun + Earth fix the attitude),
    and it is consistent with its own covariance."""
    e_triad, e_tight, s_tight = [], [], []
    for seed in range(1, 9):
        sim = _sim(1.0, seed)
        triad = solve(build_pass(preprocess_log(sim.log)[0]), "batch", SmootherOptions())
        tight = solve(build_pass(sim.log), "batch", ATT)
        for sol, out in ((triad, e_triad), (tight, e_tight)):
            out.append(accuracy_metrics(sol, sim.x_true[np.searchsorted(sim.t_s, sol.t_s)]))
        s_tight.append(e_tight[-1]["sigma_position_rms_m"])
    rms = {name: float(np.sqrt(np.mean([a["position_rms_m"] ** 2 for a in v])))
           for name, v in (("triad", e_triad), ("tight", e_tight))}
    assert rms["tight"] < rms["triad"]
    assert 0.5 < rms["tight"] / float(np.sqrt(np.mean(np.square(s_tight)))) < 1.5


def test_sun_rows_beyond_the_ephemeris_span_are_a_user_error(tmp_path):
    """The Sun and Moon targets come from ERFA (``epv00``, ``moon98``: 1900-2100); a row
    outside is refused naming its line, not a ValueError traceback."""
    from fgnav.io.log_csv import read_log

    path = tmp_path / "log.csv"
    path.write_text("epoch,kind,x,y,z,sigma\n"
                    "2150-03-06T12:00:00Z,sun_direction_body,0.6,0,0.8,3e-4\n", encoding="utf-8")
    with pytest.raises(UserError, match=r"line 2 .*1900-2100"):
        build_pass(read_log(path))
