"""The batch smoother's first guess: the filter's states smoothed backward (Rauch, Tung &
Striebel 1965, fgnav.solvers.rts)."""

from __future__ import annotations

import numpy as np

import fgnav.solvers.batch as batch
from factors.dynamics import MotionModel
from fgnav.measurements import build_pass
from fgnav.pipeline import solve
from fgnav.scenarios import load_scenario
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.solvers.ekf_numba import run_ekf_numba
from fgnav.solvers.options import SmootherOptions
from fgnav.solvers.rts import rts_smooth
from fgnav.time import j2000_seconds


def _pass():
    scn = load_scenario("gto-transfer").with_options(duration_h=2.0, step_s=5.0)
    return build_pass(simulate_pass(scn, seed=4).log)


def test_smoothed_states_are_near_the_batch_solution_and_the_last_is_the_filters():
    p = _pass()
    options = SmootherOptions()
    ekf = run_ekf_numba(p, options)
    x_s = rts_smooth(p.t_s, ekf.x_eci, ekf.P_eci, MotionModel(), options.q_m2_s3,
                     float(j2000_seconds(p.epoch0)))
    sol = solve(p, "batch", options)
    err_f = np.linalg.norm(ekf.x_eci[:, :3] - sol.x_eci[:, :3], axis=1)
    err_s = np.linalg.norm(x_s[:, :3] - sol.x_eci[:, :3], axis=1)
    assert np.array_equal(x_s[-1], ekf.x_eci[-1])
    # the backward pass carries the later measurements back: the filter's early states are
    # kilometres from the smoother's, the smoothed ones metres
    assert np.sqrt(np.mean(err_s ** 2)) < 1e-3 * np.sqrt(np.mean(err_f ** 2))
    assert err_s.max() < 10.0


def test_gauss_newton_from_the_smoothed_guess_saves_an_iteration(monkeypatch):
    p = _pass()
    monkeypatch.setattr(batch, "ITERATED_GUESS", False)
    out = {}
    for rts in (False, True):
        monkeypatch.setattr(batch, "RTS_FIRST_GUESS", rts)
        out[rts] = solve(p, "batch")
    assert out[True].iterations == out[False].iterations - 1
    assert out[True].extras["converged"] and out[False].extras["converged"]
    # the same solution within the convergence test (updates below 1e-4 of sigma): < 1 cm,
    # far below its sigma
    assert np.abs(out[True].x_eci[:, :3] - out[False].x_eci[:, :3]).max() < 1e-2
    sigma = np.sqrt(np.diagonal(out[True].P_eci, axis1=1, axis2=2))[:, :3]
    assert sigma.min() > 1.0


def test_the_filters_sigmas_spare_the_first_updates_marginals_and_change_nothing(monkeypatch):
    """The filter's sigmas bound the smoother's from above: the first update, far beyond
    1e-4 of them, cannot pass the test by sigma, and its marginals are not formed."""
    p = _pass()
    monkeypatch.setattr(batch, "ITERATED_GUESS", False)   # (its first update passes the test)
    formed = []
    real = batch.chain_marginals
    monkeypatch.setattr(batch, "chain_marginals", lambda *a: formed.append(1) or real(*a))
    with_bound = solve(p, "batch")
    n_with = len(formed)
    formed.clear()
    guess = batch._ekf_guess
    monkeypatch.setattr(batch, "_ekf_guess", lambda *a: (guess(*a)[0], None))
    without = solve(p, "batch")
    assert n_with == len(formed) - 1
    assert np.array_equal(with_bound.x_eci, without.x_eci)
    assert np.array_equal(with_bound.P_eci, without.P_eci)
    sigma_f = guess(p, SmootherOptions())[1]
    sigma_s = np.sqrt(np.diagonal(with_bound.P_eci, axis1=1, axis2=2))
    assert sigma_f.shape == sigma_s.shape and np.all(sigma_s <= sigma_f * (1 + 1e-3))


def test_the_iterated_guess_is_a_gauss_newton_step_and_the_batch_needs_one_elimination(monkeypatch):
    """Filtered and smoothed once more, linearized about the smoothed states (Bell 1994), the
    guess is where Gauss-Newton's first step would go: one elimination instead of two, the
    same solution within the convergence test, and the iterated smoother about the
    solution itself stays there (Gauss-Newton's fixed point)."""
    p = _pass()
    one = solve(p, "batch")
    monkeypatch.setattr(batch, "ITERATED_GUESS", False)
    two = solve(p, "batch")
    assert one.iterations == 1 and two.iterations == 2
    assert one.extras["converged"] and two.extras["converged"]
    sigma = np.sqrt(np.diagonal(two.P_eci, axis1=1, axis2=2))
    assert np.max(np.abs(one.x_eci - two.x_eci) / sigma) < 1e-4
    scale = sigma[:, :, None] * sigma[:, None, :]
    assert np.max(np.abs(one.P_eci - two.P_eci) / scale) < 1e-6
    # about the solution: the linearized filter and smoother give the solution back
    options = SmootherOptions()
    f = run_ekf_numba(p, options, x_lin=two.x_eci)
    x_s = rts_smooth(p.t_s, f.x_eci, f.P_eci, MotionModel(), options.q_m2_s3,
                     float(j2000_seconds(p.epoch0)), x_lin=two.x_eci)
    assert np.max(np.abs(x_s - two.x_eci) / sigma) < 1e-4
    # ... while the extended filter's own states are far from it (the test is not empty)
    plain = run_ekf_numba(p, options)
    assert np.max(np.abs(plain.x_eci - two.x_eci) / sigma) > 0.1
