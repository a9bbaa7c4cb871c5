"""Gyro rows between epochs in the graph: attitude carried across epochs without attitude rows,
and the gyro bias estimated (batch and iSAM2 agree; the EKF propagates the attitude with the
gyro and ends where the smoothers end).

The pass: 30 min of refraction-leo with a body-frame Earth sensor; the attitude rows (from the
clear stars) are kept at one epoch in six only, and a rate gyro reports at every epoch the
true LVLH body rate over the interval since the previous epoch (from the independent
integrator's truth) plus a 1e-4 rad/s (20 deg/h) bias and 1e-6 rad/s white noise.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from factors.geometry import so3_exp, so3_log
from fgnav.errors import UserError
from fgnav.measurements import build_pass
from fgnav.pipeline import solve
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.solvers.options import SmootherOptions
from attitude_passes import body_earth_scenario, with_gyro

BIAS = np.array([1e-4, -0.5e-4, 0.8e-4])
ESTIMATE = replace(SmootherOptions(), estimate=("attitude", "gyro-bias"))


@pytest.fixture(scope="module")
def gyro_pass():
    sim = simulate_pass(body_earth_scenario(0.5), seed=4)
    merged, R = with_gyro(sim.log, sim.t_s, sim.x_true, BIAS, 1e-6, np.random.default_rng(9))
    return sim, build_pass(merged), R


def _attitude_error(sol, R_true):
    w, P = sol.variables["attitude"]
    err = so3_log(np.swapaxes(R_true, 1, 2) @ so3_exp(w))
    return err, np.sqrt(np.diagonal(P, axis1=1, axis2=2))


def test_gyro_carries_the_attitude_and_the_bias_comes_out(gyro_pass):
    sim, p, R_true = gyro_pass
    sols = {m: solve(p, m, ESTIMATE) for m in ("batch", "isam2")}
    for method, sol in sols.items():
        err, sig = _attitude_error(sol, R_true)
        assert np.sqrt(np.mean(err ** 2)) < 2e-5, method           # a few arcsec everywhere
        nees = np.mean(np.sum(err ** 2 / sig ** 2, axis=1))
        assert 0.5 < nees < 9.0, (method, nees)
        b, Pb = sol.variables["gyro_bias"]
        sb = np.sqrt(np.diagonal(Pb[-1]))
        assert np.all(np.abs(b[-1] - BIAS) < 4 * sb), (method, b[-1], sb)
        assert np.all(sb < 2e-5)                                     # the bias is observed
    wb, wi = sols["batch"].variables["attitude"][0], sols["isam2"].variables["attitude"][0]
    d = so3_log(np.swapaxes(so3_exp(wb), 1, 2) @ so3_exp(wi))
    assert np.max(np.abs(d)) < 1e-8


def test_without_the_bias_variable_the_biased_gyro_shows(gyro_pass):
    sim, p, R_true = gyro_pass
    sol = solve(p, "batch", replace(SmootherOptions(), estimate=("attitude",)))
    chi2 = np.mean(sol.residuals["gyro"] ** 2)
    with_bias = solve(p, "batch", ESTIMATE)
    assert chi2 > 10 * np.mean(with_bias.residuals["gyro"] ** 2)


def test_the_ekf_propagates_with_the_gyro_and_ends_where_batch_ends(gyro_pass):
    """The numpy EKF (the compiled one takes the orbit alone, so ``solve`` picks this one):
    the gyro carries its attitude error state between the attitude rows, the bias is a state.
    Its attitude errors against the truth are consistent with its covariance (NEES over 3
    dof at every epoch), and at the last epoch -- where filter and smoother condition on the
    same data -- attitude and bias equal the batch solution well within their sigmas."""
    sim, p, R_true = gyro_pass
    ekf = solve(p, "ekf", ESTIMATE)
    assert ekf.method == "ekf"
    assert np.all(np.isfinite(ekf.residuals["gyro"]))          # every gyro row was used
    err, sig = _attitude_error(ekf, R_true)
    w, P = ekf.variables["attitude"]
    nees = np.einsum("ni,nij,nj->n", err, np.linalg.inv(P), err)
    assert 1.0 < np.mean(nees) < 6.0, np.mean(nees)
    assert np.mean(nees > 11.34) < 0.05                          # chi2(3) 99 %: rare
    batch = solve(p, "batch", ESTIMATE)
    wb, Pb = batch.variables["attitude"]
    d = so3_log(so3_exp(wb[-1]).T @ so3_exp(w[-1]))
    assert np.all(np.abs(d) < 0.1 * np.sqrt(np.diagonal(Pb[-1]))), d
    b, Pbias = ekf.variables["gyro_bias"]
    bb, Pbb = batch.variables["gyro_bias"]
    assert np.all(np.abs(b[-1] - bb[-1]) < 0.1 * np.sqrt(np.diagonal(Pbb[-1])))
    np.testing.assert_allclose(np.diagonal(Pbias[-1]), np.diagonal(Pbb[-1]), rtol=0.05)
    assert np.all(np.abs(b[-1] - BIAS) < 4 * np.sqrt(np.diagonal(Pbias[-1])))

