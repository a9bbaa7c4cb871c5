"""The constant-rate attitude motion (``fgnav smooth --attitude-motion constant-rate``).

Without a gyro the attitude between its measured epochs follows the motion model. The pass:
30 min of refraction-leo (refraction rows observe the orbit) flown by a spacecraft spinning
at a constant body rate of 0.0075 rad/s (0.4 deg/s), with attitude rows (0.1 mrad) at one
epoch in ten and Earth directions in the body frame (0.3 mrad) at every epoch, built from
the independent integrator's truth. The turn about the Earth direction is then measured
only at the attitude epochs: between them the random walk holds it, the constant-rate
motion turns it at the estimated rate.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from factors.attitude_motion import (constant_rate_residual, constant_rate_sqrt_information,
                                     make_constant_rate_factor)
from factors.geometry import so3_exp, so3_log
from factors.testing import check_jacobians
from fgnav.errors import UserError
from fgnav.measurements import build_pass, with_estimates
from fgnav.models.registry import ATTITUDE_RATE, ATTITUDE_VARIABLE
from fgnav.pipeline import solve
from fgnav.scenarios import load_scenario
from fgnav.simulate.attitude_profiles import spinning, with_attitude_truth
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.solvers.options import SmootherOptions

OMEGA = np.array([0.004, -0.003, 0.005])          # rad/s, body frame
RANDOM_WALK = replace(SmootherOptions(), estimate=("attitude",))
CONSTANT_RATE = replace(SmootherOptions(), estimate=("attitude", "attitude-rate"))


@pytest.fixture(scope="module")
def spin_pass():
    sim = simulate_pass(load_scenario("refraction-leo").with_options(duration_h=0.5), seed=5)
    t_ep = np.unique(sim.log.t_s)
    R = spinning(t_ep, OMEGA, so3_exp(np.array([0.3, -1.0, 0.5])))
    log = with_attitude_truth(sim.log, sim.t_s, sim.x_true, R, np.random.default_rng(1),
                              attitude_every=10, sigma_attitude_rad=1e-4,
                              earth_body_sigma_rad=3e-4)
    return build_pass(log), R, log


def _errors(sol, R_true):
    w, P = sol.variables["attitude"]
    err = so3_log(np.swapaxes(R_true, 1, 2) @ so3_exp(w))
    return err, np.einsum("ni,nij,nj->n", err, np.linalg.inv(P), err)


def test_constant_rate_jacobians_and_whitening():
    rng = np.random.default_rng(1)
    M = 6
    R0, R1 = so3_exp(rng.normal(0, 1, (M, 3))), so3_exp(rng.normal(0, 1, (M, 3)))
    w0, w1 = rng.normal(0, 0.05, (M, 3)), rng.normal(0, 0.05, (M, 3))
    dt = rng.uniform(0.5, 20.0, M)
    e, *H = constant_rate_residual(R0, w0, R1, w1, dt)
    check_jacobians(constant_rate_residual, [R0, w0, R1, w1, dt], H + [None],
                    ["rot3", "vector", "rot3", "vector", None],
                    names=["R0", "w0", "R1", "w1", "dt"])
    # zero on a constant-rate turn
    e0 = constant_rate_residual(R0, w0, R0 @ so3_exp(w0 * dt[:, None]), w0, dt)[0]
    np.testing.assert_allclose(e0, 0.0, atol=1e-12)
    # W^T W is the inverse of the white-noise-on-acceleration covariance
    q = 1e-10
    W = constant_rate_sqrt_information(dt, q)
    for k in range(M):
        Q = q * np.kron(np.array([[dt[k] ** 3 / 3, dt[k] ** 2 / 2], [dt[k] ** 2 / 2, dt[k]]]),
                        np.eye(3))
        np.testing.assert_allclose(np.linalg.inv(W[k].T @ W[k]), Q, rtol=1e-9)


def test_constant_rate_factor_linearizes_to_the_whitened_residual():
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(2)
    R0, R1 = so3_exp(rng.normal(0, 1, (1, 3))), so3_exp(rng.normal(0, 1, (1, 3)))
    w0, w1 = rng.normal(0, 0.05, (1, 3)), rng.normal(0, 0.05, (1, 3))
    dt, q = 7.0, 1e-9
    keys = [ATTITUDE_VARIABLE.key(3), ATTITUDE_RATE.key(3), ATTITUDE_VARIABLE.key(4),
            ATTITUDE_RATE.key(4)]
    values = gtsam.Values()
    values.insert(keys[0], gtsam.Rot3(R0[0]))
    values.insert(keys[1], w0[0])
    values.insert(keys[2], gtsam.Rot3(R1[0]))
    values.insert(keys[3], w1[0])
    A, b = make_constant_rate_factor(*keys, dt, q).linearize(values).jacobian()
    e, *H = constant_rate_residual(R0, w0, R1, w1, np.array([dt]))
    W = constant_rate_sqrt_information(np.array([dt]), q)[0]
    np.testing.assert_allclose(b, -W @ e[0], rtol=1e-9)
    np.testing.assert_allclose(A, np.hstack([W @ h[0] for h in H]), rtol=1e-8,
                               atol=1e-9 * np.abs(A).max())


def test_constant_rate_beats_the_random_walk_between_attitude_rows(spin_pass):
    p, R, _ = spin_pass
    between = np.arange(p.n_epochs) % 10 != 0
    rw = solve(p, "batch", RANDOM_WALK)
    cr = solve(p, "batch", CONSTANT_RATE)
    err_rw, _ = _errors(rw, R)
    err_cr, nees_cr = _errors(cr, R)
    rms_rw = np.sqrt(np.mean(err_rw[between] ** 2))
    rms_cr = np.sqrt(np.mean(err_cr[between] ** 2))
    assert rms_cr < 0.7 * rms_rw, (rms_cr, rms_rw)
    assert 1.0 < np.mean(nees_cr) < 5.0                       # 3 dof, a conservative model
    w, Pw = cr.variables["attitude_rate"]
    assert np.all(np.abs(w[-1] - OMEGA) < 4 * np.sqrt(np.diagonal(Pw[-1])))
    # the online route: iSAM2 ends on the batch solution, the EKF turns with the rate
    isam = solve(p, "isam2", CONSTANT_RATE)
    d = so3_log(np.swapaxes(so3_exp(cr.variables["attitude"][0]), 1, 2)
                @ so3_exp(isam.variables["attitude"][0]))
    assert np.max(np.abs(d)) < 1e-8
    np.testing.assert_allclose(isam.variables["attitude_rate"][0], w, atol=1e-10)
    ekf_rw, ekf_cr = solve(p, "ekf", RANDOM_WALK), solve(p, "ekf", CONSTANT_RATE)
    e_rw, e_cr = _errors(ekf_rw, R)[0], _errors(ekf_cr, R)[0]
    assert np.sqrt(np.mean(e_cr[between] ** 2)) < 0.1 * np.sqrt(np.mean(e_rw[between] ** 2))


def test_the_rate_needs_the_attitude(spin_pass):
    p, _, _ = spin_pass
    with pytest.raises(UserError, match="add --estimate attitude"):
        with_estimates(p, ("attitude-rate",))


def test_cli_attitude_motion(tmp_path, spin_pass, capsys):
    from fgnav.cli import main
    from fgnav.io.log_csv import write_log

    _, _, log = spin_pass
    path = tmp_path / "spin.csv"
    write_log(path, log)
    assert main(["smooth", str(path), "--out", str(tmp_path / "a"),
                 "--attitude-motion", "constant-rate"]) == 2
    assert "--attitude-motion constant-rate" in capsys.readouterr().err
    assert main(["smooth", str(path), "--out", str(tmp_path / "b"), "--quiet",
                 "--attitude", "estimate", "--attitude-motion", "constant-rate"]) == 0
    header = (tmp_path / "b" / "variables.csv").read_text().splitlines()
    header = next(line for line in header if not line.startswith("#"))
    assert "rate_x" in header and "att_x" in header
