"""The cislunar pieces together, before any log kind exists: a day of the translunar coast
imaged every 30 min (the Earth's and the Moon's limb radius and centre direction from the
independent simulator, with noise), smoothed by GTSAM over the DE421 motion factors and the
near-body factors; the estimate against the DOP853 truth, in its own covariance."""

import numpy as np
import pytest

from factors.constants import MU_EARTH_M3_S2, R_EARTH_M, R_MOON_M
from factors.dynamics import MotionModel
from factors.jpl_ephemeris import moon_state_de421
from factors.motion import make_motion_factor
from factors.near_body import make_near_body_direction_factor, make_near_body_limb_factor
from fgnav.orbit import integrate_truth
from fgnav.simulate.near_bodies import apparent_body

T0 = 8.5e8
ARCSEC = np.pi / 180 / 3600


@pytest.mark.parametrize("seed", [1, 2])
def test_translunar_day_smoothed_within_its_covariance(seed):
    gtsam = pytest.importorskip("gtsam")
    r0 = R_EARTH_M + 185e3
    v0 = np.sqrt(2 * MU_EARTH_M3_S2 / r0) * 0.9955
    x_tli = np.array([r0, 0.0, 0.0, 0.0, v0 * np.cos(0.5), v0 * np.sin(0.5)])
    t = np.arange(0.0, 86400.0 + 1, 1800.0) + 86400.0      # the second day after TLI
    truth = integrate_truth(x_tli, np.concatenate([[43200.0], t]), third_body=True,
                            ephemeris="de421", t0_j2000_s=T0, rtol=1e-13, atol=1e-8)[1:]
    tj = T0 + t
    rng = np.random.default_rng(seed)
    sig_dir, sig_limb = 5.0 * ARCSEC, 2.0 * ARCSEC
    model = MotionModel.cislunar(max_step_s=60.0)
    rm, vm = moon_state_de421(tj)
    bodies = {"earth": (np.zeros_like(rm), np.zeros_like(vm), R_EARTH_M), "moon": (rm, vm, R_MOON_M)}
    graph = gtsam.NonlinearFactorGraph()
    for name, (p, v, radius) in bodies.items():
        u, rho, _ = apparent_body(name, tj, truth, radius)
        for k in range(len(t)):
            n = rng.normal(size=3) * sig_dir
            uk = u[k] + n - (n @ u[k]) * u[k]
            graph.add(make_near_body_direction_factor(k, uk / np.linalg.norm(uk), p[k], v[k], sig_dir))
            graph.add(make_near_body_limb_factor(k, rho[k] + rng.normal() * sig_limb, radius,
                                                 p[k], v[k], sig_limb))
    q = 1e-10   # m^2/s^3: 0.4 m of position per 30 min (tighter leaves LM stuck 70 km off)
    for k in range(len(t) - 1):
        graph.add(make_motion_factor(k, k + 1, t[k + 1] - t[k], q, model, tj[k]))
    prior_sig = np.array([1e7] * 3 + [1e2] * 3)   # nearly uninformative
    graph.add(gtsam.PriorFactorVector(0, truth[0] + rng.normal(size=6) * prior_sig * 0.01,
                                      gtsam.noiseModel.Diagonal.Sigmas(prior_sig)))
    init = gtsam.Values()
    off = rng.normal(size=6) * np.array([2e5] * 3 + [2.0] * 3)    # 200 km, 2 m/s off
    for k in range(len(t)):
        init.insert(k, truth[k] + off)
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(200)
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-10)
    res = gtsam.LevenbergMarquardtOptimizer(graph, init, params).optimize()
    # the covariance from the dense whitened Jacobian at the solution (QR, not the chain's
    # Cholesky: km-level angles against mm-level motion rows)
    order = gtsam.Ordering()
    for k in range(len(t)):
        order.push_back(k)
    A, _ = graph.linearize(res).jacobian(order)
    Rq = np.linalg.qr(A, mode="r")
    Ri = np.linalg.solve(Rq, np.eye(Rq.shape[0]))
    cov = Ri @ Ri.T
    nees, err = [], []
    for k in range(len(t)):
        e = res.atVector(k) - truth[k]
        P = cov[6 * k:6 * k + 6, 6 * k:6 * k + 6]
        nees.append(e @ np.linalg.solve(P, e))
        err.append(np.linalg.norm(e[:3]))
    nees = np.array(nees)
    # the 6-dof error in its covariance (strongly correlated along the arc: each epoch's
    # NEES is chi2(6) at a single draw; 99.9 % of chi2(6) is 22.5)
    assert nees.max() < 22.5, (nees.max(), max(err))
    # and the fit recovers the orbit from 200 km off: a few km (5 arcsec is 4.8 km at
    # 200,000 km), as its covariance says
    assert max(err) < 20e3
