"""Observability matrix (Pan & Yao 2017 eq. 9, table 4) and information eigen-directions."""

from __future__ import annotations

import numpy as np
import pytest

from factors.constants import DEG
from factors.dynamics import MotionModel, propagate
from factors.geometry import tangent_basis
from fgnav.diagnostics.observability import (analyze_observability, describe_direction,
                                          observability_matrix, weakest_directions,
                                          window_information)
from fgnav.scenarios import load_scenario

X0 = np.array(load_scenario("gto-transfer").x0_eci)   # Pan & Yao 2017's initial state


def _direction_after(x0, t, u_ref):
    """e_j(x0) = B(u_ref) u(propagate(x0, t)) by the motion model, step by step."""
    x = x0.copy()
    tk = 0.0
    out = []
    for tj, u in zip(t, u_ref):
        if tj > tk:
            x = propagate(x, tj - tk, MotionModel(), tk, with_stm=False)[0]
            tk = tj
        un = -x[:3] / np.linalg.norm(x[:3])
        out.append(tangent_basis(u) @ un)
    return np.concatenate(out)


def test_observability_matrix_matches_central_differences():
    T, n = 60.0, 4
    M = observability_matrix(X0, T, n)
    t = np.arange(n) * T
    # reference directions at the nominal trajectory
    xs = [X0]
    for _ in range(1, n):
        xs.append(propagate(xs[-1], T, MotionModel(), 0.0, with_stm=False)[0])
    u_ref = [-x[:3] / np.linalg.norm(x[:3]) for x in xs]
    steps = np.array([10.0] * 3 + [0.01] * 3)
    fd = np.empty_like(M)
    for i in range(6):
        d = np.zeros(6)
        d[i] = steps[i]
        fd[:, i] = (_direction_after(X0 + d, t, u_ref) - _direction_after(X0 - d, t, u_ref)) / (2 * steps[i])
    np.testing.assert_allclose(M, fd, rtol=1e-5, atol=1e-6 * np.abs(M).max())


def test_pan_yao_table4_rank_six_at_every_period():
    """Pan & Yao 2017, table 4: the system is observable (rank 6) at T = 0.1, 1, 10, 100 s."""
    for T in (0.1, 1.0, 10.0, 100.0):
        assert analyze_observability(observability_matrix(X0, T, 6)).rank == 6
    # two direction samples (4 rows) cannot observe 6 states
    assert analyze_observability(observability_matrix(X0, 10.0, 2)).rank == 4


def test_condition_vs_period_and_fixed_window_information():
    """What we find for Pan & Yao 2017 table 4 (differences explained in the study's notes): cond(M)
    of eq. 9 with 6 blocks *falls* with T (the blocks become alike as Phi -> I); over a fixed
    window the weakest direction's 1-sigma grows with T (shorter periods observe better)."""
    periods = (0.1, 1.0, 10.0, 100.0)
    cond = [analyze_observability(observability_matrix(X0, T, 6)).condition_scaled for T in periods]
    assert all(a > b for a, b in zip(cond, cond[1:]))
    sig = [weakest_directions(window_information(X0, T, 3600.0, 0.01 * DEG))[0]["sigma_m"] for T in periods]
    assert all(a < b for a, b in zip(sig, sig[1:]))
    # information scales with the number of samples: sigma ~ sqrt(T) between 1 s and 10 s
    assert sig[2] / sig[1] == pytest.approx(np.sqrt(10.0), rel=0.05)


def test_window_information_matches_cramer_rao_information():
    from fgnav.diagnostics.crb import cramer_rao_bound
    from fgnav.measurements import build_pass
    from fgnav.simulate.pass_sim import simulate_pass
    from fgnav.time import j2000_seconds

    scn = load_scenario("gto-transfer").with_options(step_s=120.0, duration_h=1.0)
    sim = simulate_pass(scn, 0)
    p = build_pass(sim.log)
    J_crb = cramer_rao_bound(p, sim.x_true, MotionModel()).J0_measurements
    J = window_information(X0, 120.0, 3600.0, 0.01 * DEG, t0_j2000_s=float(j2000_seconds(p.epoch0)))
    np.testing.assert_allclose(J, J_crb, rtol=2e-3, atol=1e-6 * np.abs(J).max())


def test_weakest_directions_and_rank_deficiency():
    J = np.diag([1.0, 4.0, 9.0, 16.0, 25.0, 1e-8])
    w = weakest_directions(J, time_scale_s=1.0, count=2)
    assert w[0]["text"] == "+1.00 vz" and w[0]["sigma_m"] == pytest.approx(1e4)
    assert w[1]["text"] == "+1.00 x"
    M = np.random.default_rng(0).standard_normal((12, 6))
    M[:, 5] = M[:, 0] - 2 * M[:, 1]
    r = analyze_observability(M)
    assert r.rank == 5
    v = r.weakest_direction
    assert abs(v @ np.array([1, -2, 0, 0, 0, -1]) / np.sqrt(6)) == pytest.approx(1.0, abs=1e-8)
    assert describe_direction(-np.array([0.0, 0, 0, 0, 0, 1])) == "+1.00 vz"
