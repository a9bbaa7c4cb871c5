"""The attitude as a graph variable (``--estimate attitude``): a ``Rot3`` per epoch.

A refraction pass whose clear stars give an attitude row per epoch and whose Earth sensor
reports the Earth's direction in the body frame. With the attitude known (the default) the
body-frame rows are rotated into ECI before the graph; with ``--estimate attitude`` the
attitude rows are priors on a Rot3 variable per epoch (random walk between epochs) and the
body-frame rows factors on (orbit, attitude). Both must give the same orbit (the attitude
rows are arcsecond-class, the Earth sensor 0.02 deg), the attitude must come out within its
own sigma of the simulator's true attitude (LVLH), and batch, iSAM2, fixed-lag and the EKF
must all carry it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from factors.geometry import so3_exp, so3_log
from fgnav.measurements import build_pass
from fgnav.pipeline import accuracy_metrics, solve, summarize
from fgnav.simulate.body_directions import lvlh_R_eci_from_body
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.solvers.options import SmootherOptions
from attitude_passes import body_earth_scenario

ATT = replace(SmootherOptions(), estimate=("attitude",))


@pytest.fixture(scope="module")
def att_pass():
    sim = simulate_pass(body_earth_scenario(0.5), seed=2)
    p = build_pass(sim.log)
    assert {"attitude", "earth_direction_body"} <= set(p.deferred)
    return sim, p


def _attitude_errors(sim, sol):
    idx = np.searchsorted(sim.t_s, sol.t_s)
    w, P = sol.variables["attitude"]
    R_true = lvlh_R_eci_from_body(sim.x_true[idx])
    err = so3_log(np.swapaxes(R_true, 1, 2) @ so3_exp(w))   # body-frame rotation error, rad
    return err, np.sqrt(np.diagonal(P, axis1=1, axis2=2))


@pytest.mark.parametrize("method", ["batch", "isam2", "fixed-lag", "ekf"])
def test_estimated_attitude_matches_truth_and_leaves_the_orbit_as_it_was(att_pass, method):
    sim, p = att_pass
    known = solve(p, method, SmootherOptions())
    est = solve(p, method, ATT)
    idx = np.searchsorted(sim.t_s, est.t_s)
    a_known = accuracy_metrics(known, sim.x_true[idx])
    a_est = accuracy_metrics(est, sim.x_true[idx])
    assert a_est["position_rms_m"] == pytest.approx(a_known["position_rms_m"], rel=0.02)
    err, sig = _attitude_errors(sim, est)
    assert np.sqrt(np.mean(err ** 2)) < 2e-5                 # a few arcsec
    nees = np.mean(np.sum(err ** 2 / sig ** 2, axis=1))       # 3 dof
    assert 1.0 < nees < 6.0
    assert summarize(est, p, ATT)["integrity"]["status"] == "ok"


def test_batch_and_isam2_give_the_same_attitude(att_pass):
    sim, p = att_pass
    b, i = solve(p, "batch", ATT), solve(p, "isam2", ATT)
    wb, Pb = b.variables["attitude"]
    wi, Pi = i.variables["attitude"]
    d = so3_log(np.swapaxes(so3_exp(wb), 1, 2) @ so3_exp(wi))
    assert np.max(np.abs(d) / np.sqrt(np.diagonal(Pb, axis1=1, axis2=2))) < 1e-3
    np.testing.assert_allclose(Pi, Pb, rtol=1e-3, atol=1e-18)
