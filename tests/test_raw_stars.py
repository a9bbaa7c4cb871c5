"""Raw star observations in the graph: ``star_direction_body`` rows (``fgnav simulate --raw-stars``).

A GEO pass (the ``geo-limb`` scenario) whose Earth sensor reports the Earth's direction in
the body frame and whose zenith star camera reports the identified stars one by one: the
attitude is a ``Rot3`` per epoch solved with the orbit (tight coupling). Checked here: the
log format carries the rows; the simulated stars are the truth attitude's view of the
catalogue's apparent (aberrated) directions within their noise; the registry's first guess (Wahba/SVD per frame) is near the
truth; the solution's position is within its sigma of the independent DOP853 truth and its
attitude within its sigma of the simulator's true attitude; against the loosely coupled
route (one solved attitude row per frame from the same stars) the position is no worse;
and the passes that cannot fix the attitude are refused with exit 2.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from factors.aberration import SPEED_OF_LIGHT_MPS, earth_velocity_bcrs_mps
from factors.constants import ARCSEC
from factors.direction import star_direction_residual
from factors.geometry import so3_exp, so3_log
from factors.testing import check_jacobians
from fgnav.cli import main
from fgnav.graph import initial_block
from fgnav.io.log_csv import STAR_COLUMNS, read_log, write_log
from fgnav.loose_attitude import attitude_rows_from_stars
from fgnav.measurements import build_pass, with_estimates
from fgnav.models.registry import (ATTITUDE, ATTITUDE_VARIABLE, EARTH_DIRECTION,
                                   EARTH_DIRECTION_BODY, STAR_DIRECTION_BODY)
from fgnav.pipeline import solve
from fgnav.scenarios import load_scenario
from fgnav.simulate.pass_sim import RAW_STAR_CAMERA, raw_star_scenario, simulate_pass
from fgnav.simulate.star_camera import BORESIGHT_BODY
from fgnav.solvers.options import SmootherOptions
from fgnav.time import j2000_seconds

ATT = replace(SmootherOptions(third_body=True), estimate=(ATTITUDE_VARIABLE.name,))
CHI2_3_999 = 16.27   # 99.9 % point of chi-square with 3 degrees of freedom


def _raw(seed=0, duration_h=2.0):
    return simulate_pass(raw_star_scenario(load_scenario("geo-limb").with_options(
        duration_h=duration_h)), seed=seed)


@pytest.fixture(scope="module")
def sim():
    return _raw()


def _stars(log):
    i = log.select(STAR_DIRECTION_BODY.kind)
    return i, np.column_stack([log.extra[c][i] for c in STAR_COLUMNS])


def _attitude_error(sim, sol):
    """Body-frame rotation error (N, 3) rad and the solution's attitude covariance."""
    idx = np.searchsorted(sim.t_s, sol.t_s)
    w, P = sol.variables[ATTITUDE_VARIABLE.name]
    return so3_log(np.swapaxes(sim.truth_attitude()[idx], 1, 2) @ so3_exp(w)), P


def _position_nees(sim, sol):
    idx = np.searchsorted(sim.t_s, sol.t_s)
    err = sol.x_eci[:, :3] - sim.x_true[idx, :3]
    return np.einsum("ki,ki->k", err, np.linalg.solve(sol.P_eci[:, :3, :3], err[..., None])[..., 0])


def test_raw_star_scenario_swaps_the_eci_earth_sensor_for_a_body_one_and_a_camera():
    scn = load_scenario("geo-limb")
    raw = raw_star_scenario(scn)
    kinds = [s.kind for s in raw.sensors]
    assert EARTH_DIRECTION.kind not in kinds
    assert kinds.count(EARTH_DIRECTION_BODY.kind) == 1 and kinds.count(STAR_DIRECTION_BODY.kind) == 1
    body = raw.sensors[kinds.index(EARTH_DIRECTION_BODY.kind)]
    assert body.sigma_deg == [s for s in scn.sensors if s.kind == EARTH_DIRECTION.kind][0].sigma_deg
    assert raw_star_scenario(raw).sensors == raw.sensors   # idempotent: one camera


def test_simulated_stars_are_the_true_attitude_view_of_the_catalogue(sim):
    log = sim.log
    assert not len(log.select(EARTH_DIRECTION.kind)) and len(log.select(ATTITUDE.kind)) == 0
    assert len(log.select(EARTH_DIRECTION_BODY.kind)) == len(sim.t_s)
    i, s = _stars(log)
    np.testing.assert_allclose(np.linalg.norm(s, axis=1), 1.0, atol=1e-12)
    n = np.searchsorted(sim.t_s, log.t_s[i])
    R = sim.truth_attitude()[n]
    # the apparent direction: aberrated by the spacecraft's barycentric velocity (first
    # order here, u + beta - (u.beta) u, independent of factors.aberration; 1e-8 rad off)
    beta = (earth_velocity_bcrs_mps(float(j2000_seconds(log.epoch0)) + log.t_s[i])
            + sim.x_true[n, 3:]) / SPEED_OF_LIGHT_MPS
    s_app = s + beta - np.sum(s * beta, axis=1)[:, None] * s
    s_app /= np.linalg.norm(s_app, axis=1, keepdims=True)
    u_true = np.einsum("nji,nj->ni", R, s_app)
    u_cat = np.einsum("nji,nj->ni", R, s)
    shift = np.arccos(np.clip(np.sum(u_true * u_cat, axis=1), -1.0, 1.0)) / ARCSEC
    assert 5.0 < np.median(shift) < 30.0       # the aberration the rows carry: arcseconds
    # in the camera's 12.85 deg square field about the zenith (body -z)
    assert np.all(u_true @ BORESIGHT_BODY > np.cos(np.radians(6.425 * np.sqrt(2)) + 1e-9))
    ang = np.arccos(np.clip(np.sum(u_true * log.xyz[i], axis=1), -1.0, 1.0))
    sig = RAW_STAR_CAMERA.star_sigma_arcsec * ARCSEC
    np.testing.assert_allclose(log.sigma[i], sig)
    # the angle of 2-D isotropic noise: mean square 2 sigma^2
    assert np.sqrt(np.mean(ang ** 2)) == pytest.approx(np.sqrt(2) * sig, rel=0.05)
    # and the truth's Earth direction in the body frame is nadir (+z body), 0.005 deg noise
    j = log.select(EARTH_DIRECTION_BODY.kind)
    assert np.degrees(np.arccos(np.min(log.xyz[j] @ -BORESIGHT_BODY))) < 0.05


def test_star_residual_jacobian_at_the_cameras_geometry(sim):
    """The registry's residual on the rotation manifold (central differences, right
    perturbation) at simulated stars, the attitude 0.01 rad off the truth."""
    i, s = _stars(sim.log)
    i, s = i[:40], s[:40]
    R = sim.truth_attitude()[np.searchsorted(sim.t_s, sim.log.t_s[i])]
    R = R @ so3_exp(np.random.default_rng(5).normal(0.0, 0.01, (len(i), 3)))
    e, H_R = star_direction_residual(R, s, sim.log.xyz[i])
    assert np.all(np.abs(e) > 0)
    check_jacobians(star_direction_residual, (R, s, sim.log.xyz[i]), (H_R, None, None),
                    ("rot3", None, None), rtol=1e-6)


def test_first_guess_of_the_attitude_is_each_frames_wahba_solution(sim):
    p = with_estimates(build_pass(sim.log), (ATTITUDE_VARIABLE.name,))
    X, measured = initial_block(p, sim.x_true[np.searchsorted(sim.t_s, p.t_s)])
    w = X[:, p.layout.slices[ATTITUDE_VARIABLE.name]]
    err = so3_log(np.swapaxes(sim.truth_attitude()[np.searchsorted(sim.t_s, p.t_s)], 1, 2)
                  @ so3_exp(w))
    assert measured[:, 0].sum() == len(np.unique(sim.log.t_s[sim.log.select(STAR_DIRECTION_BODY.kind)]))
    # arcsecond-class across the boresight, tens of arcsec in roll: far from the identity
    assert np.max(np.linalg.norm(err, axis=1)) < 300 * ARCSEC
    assert np.max(np.linalg.norm(so3_log(so3_exp(w)), axis=1)) > 1.0


@pytest.mark.parametrize("method", ["batch", "isam2", "ekf"])
def test_orbit_and_attitude_from_raw_stars_match_the_truth(sim, method):
    p = build_pass(sim.log)
    sol = solve(p, method, ATT)
    nees_r = _position_nees(sim, sol)
    assert np.max(nees_r) < CHI2_3_999                      # every epoch within its sigma
    assert 0.3 < np.mean(nees_r) < 9.0
    err, P = _attitude_error(sim, sol)
    nees_a = np.einsum("ki,ki->k", err, np.linalg.solve(P, err[..., None])[..., 0])
    assert 1.0 < np.mean(nees_a) < 6.0                      # 3 dof
    # cross-boresight axes (body x, y) at a few arcsec, roll about the boresight looser
    rms = np.sqrt(np.mean(err ** 2, axis=0))
    assert np.all(rms[:2] < 6 * ARCSEC) and rms[2] < 60 * ARCSEC


def test_tight_coupling_is_no_worse_than_attitude_rows_from_the_same_stars(sim):
    """The loose log's attitude rows summarize the same stars (per-frame Wahba, isotropic
    covering sigma): the tight graph holds at least that information, so its position sigma
    is no larger and its cross-boresight attitude is better; the errors agree with the
    sigmas in both."""
    loose_log, counts = attitude_rows_from_stars(sim.log)
    assert counts["attitude_rows"] == len(np.unique(sim.log.t_s[sim.log.select(
        STAR_DIRECTION_BODY.kind)])) - counts["epochs_without_attitude"]
    tight = solve(build_pass(sim.log), "isam2", ATT)
    loose = solve(build_pass(loose_log), "isam2", ATT)
    sig_t = np.sqrt(np.trace(tight.P_eci[:, :3, :3], axis1=1, axis2=2))
    sig_l = np.sqrt(np.trace(loose.P_eci[:, :3, :3], axis1=1, axis2=2))
    assert np.all(sig_t <= sig_l * (1 + 1e-6))
    for sol in (tight, loose):
        assert np.max(_position_nees(sim, sol)) < CHI2_3_999
    err_t, _ = _attitude_error(sim, tight)
    err_l, _ = _attitude_error(sim, loose)
    assert np.sqrt(np.mean(err_t[:, :2] ** 2)) < 0.5 * np.sqrt(np.mean(err_l[:, :2] ** 2))


@pytest.mark.slow
def test_tight_position_error_no_worse_than_loose_over_ten_seeds():
    """Pooled over 10 seeds (2 h GEO passes), the position RMS error of the tight graph is
    at most the loose route's."""
    sq_t, sq_l = [], []
    for seed in range(10):
        s = _raw(seed)
        for sol, acc in ((solve(build_pass(s.log), "isam2", ATT), sq_t),
                         (solve(build_pass(attitude_rows_from_stars(s.log)[0]), "isam2", ATT), sq_l)):
            idx = np.searchsorted(s.t_s, sol.t_s)
            acc.append(np.mean(np.sum((sol.x_eci[:, :3] - s.x_true[idx, :3]) ** 2, axis=1)))
    assert np.sqrt(np.mean(sq_t)) <= np.sqrt(np.mean(sq_l))


# ---- the command line: the passes that cannot fix the attitude are refused ------------------

@pytest.fixture(scope="module")
def raw_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("raw")
    assert main(["simulate", "geo-limb", "--raw-stars", "--duration-h", "0.5", "--out", str(d),
                 "--quiet"]) == 0
    return d


def test_cli_raw_stars_pass_solves_with_the_attitude_estimated(raw_dir, tmp_path):
    log = read_log(raw_dir / "measurements.csv")
    assert log.counts()[STAR_DIRECTION_BODY.kind] > 0
    assert main(["smooth", str(raw_dir / "measurements.csv"), "--out", str(tmp_path / "r"),
                 "--estimate", "attitude", "--third-body", "--truth", str(raw_dir / "truth.oem"),
                 "--quiet"]) == 0
    assert (tmp_path / "r" / "variables.csv").exists()


def test_cli_refuses_star_rows_without_the_attitude_estimated(raw_dir, tmp_path, capsys):
    assert main(["smooth", str(raw_dir / "measurements.csv"), "--out", str(tmp_path / "r"),
                 "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "fgnav: error:" in err and STAR_DIRECTION_BODY.kind in err
    assert "--estimate attitude" in err


@pytest.mark.parametrize("estimate", [(), ("--estimate", "attitude")])
def test_cli_refuses_body_rows_with_nothing_to_fix_the_attitude(raw_dir, tmp_path, capsys,
                                                                 estimate):
    log = read_log(raw_dir / "measurements.csv")
    keep = log.kind != STAR_DIRECTION_BODY.kind
    log = replace(log, t_s=log.t_s[keep], kind=log.kind[keep], xyz=log.xyz[keep],
                  sigma=log.sigma[keep], line=log.line[keep],
                  extra={c: v[keep] for c, v in log.extra.items()})
    write_log(tmp_path / "m.csv", log)
    assert main(["smooth", str(tmp_path / "m.csv"), "--out", str(tmp_path / "r"), "--quiet",
                 *estimate]) == 2
    err = capsys.readouterr().err
    assert EARTH_DIRECTION_BODY.kind in err and f"'{ATTITUDE.kind}' row" in err
    assert STAR_DIRECTION_BODY.kind in err


def test_loose_route_leaves_out_frames_with_fewer_than_two_stars(sim):
    """A frame with one star gives no attitude row; the body-frame row of its epoch then has
    no attitude to be rotated with and leaves the loose log (the tight graph keeps both)."""
    i, _ = _stars(sim.log)
    t_star = sim.log.t_s[i]
    t1, t2 = np.unique(t_star)[[3, 7]]
    drop = np.zeros(len(sim.log), bool)
    drop[i[t_star == t1][1:]] = True          # epoch t1: one star left
    drop[i[t_star == t2]] = True              # epoch t2: no star at all
    keep = ~drop
    log = replace(sim.log, t_s=sim.log.t_s[keep], kind=sim.log.kind[keep],
                  xyz=sim.log.xyz[keep], sigma=sim.log.sigma[keep], line=sim.log.line[keep],
                  extra={c: v[keep] for c, v in sim.log.extra.items()})
    loose, counts = attitude_rows_from_stars(log)
    n_frames = len(np.unique(sim.log.t_s[i]))
    assert counts == {"attitude_rows": n_frames - 2, "epochs_without_attitude": 1,
                      "body_rows_dropped": 2}
    t_att = loose.t_s[loose.select(ATTITUDE.kind)]
    t_body = loose.t_s[loose.select(EARTH_DIRECTION_BODY.kind)]
    assert t1 not in t_att and t2 not in t_att and t1 not in t_body and t2 not in t_body
    assert not len(loose.select(STAR_DIRECTION_BODY.kind))
    # each attitude row is its frame's Wahba solution, within the covering sigma of the truth
    R_true = sim.truth_attitude()[np.searchsorted(sim.t_s, t_att)]
    w = loose.xyz[loose.select(ATTITUDE.kind)]
    err = np.linalg.norm(so3_log(np.swapaxes(R_true, 1, 2) @ so3_exp(w)), axis=1)
    sig = loose.sigma[loose.select(ATTITUDE.kind)]
    assert np.all(err < 5 * np.sqrt(3) * sig) and np.all(sig > 5 * ARCSEC)
    # the loose pass is solvable as it is (attitude known) and with the attitude estimated
    for opts in (SmootherOptions(third_body=True), ATT):
        assert np.all(np.isfinite(solve(build_pass(loose), "isam2", opts).x_eci))


def test_wahba_by_epoch_skips_frames_of_parallel_directions():
    from fgnav.vision.attitude import wahba_by_epoch

    rng = np.random.default_rng(3)
    R = so3_exp(rng.normal(size=(1, 3)))[0]
    b = rng.normal(size=(5, 3))
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    b[3:] = b[2]                                   # epoch 1: two copies of one direction
    k = np.array([0, 0, 0, 1, 1])
    r = b @ R.T
    ep, Rs, cov = wahba_by_epoch(k, b, r, 1e-5)
    np.testing.assert_array_equal(ep, [0])
    np.testing.assert_allclose(Rs[0], R, atol=1e-12)
    assert cov.shape == (1, 3, 3) and np.all(np.linalg.eigvalsh(cov[0]) > 0)
