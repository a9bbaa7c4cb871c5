"""A short batch pass (the interpreted route) starts Gauss-Newton at its own process noise from
the prior propagated, and falls back to the continuation when the updates do not shrink
(fgnav.pipeline._batch_direct)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

import fgnav.pipeline as pipeline
from factors.interpret import interpreted
from fgnav.measurements import build_pass
from fgnav.scenarios import load_scenario
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.solvers.batch import smooth_batch
from fgnav.iod.prior import initial_guess
from fgnav.solvers.options import SmootherOptions
from fgnav.time import j2000_seconds


def _pass():
    scn = load_scenario("gto-transfer").with_options(duration_h=4.0, step_s=60.0)
    return build_pass(simulate_pass(scn, seed=0).log)


def _solve(p, options=SmootherOptions()):
    with interpreted():
        return pipeline.solve(p, "batch", options)


def test_a_short_pass_converges_at_its_own_process_noise_to_the_continuations_solution():
    p = _pass()
    direct = _solve(p)
    continued = _solve(p, SmootherOptions(init="prior"))   # the continuation, as before
    assert direct.extras["converged"] and continued.extras["converged"]
    assert direct.extras["q_stages"] == [SmootherOptions().q_m2_s3]
    assert len(continued.extras["q_stages"]) == 3
    assert direct.iterations <= 4 < 7 <= continued.iterations
    sigma = np.sqrt(np.diagonal(direct.P_eci, axis1=1, axis2=2))
    assert np.max(np.abs(direct.x_eci - continued.x_eci) / sigma) < 1e-4
    assert np.abs(direct.x_eci[:, :3] - continued.x_eci[:, :3]).max() < 1e-2
    scale = sigma[:, :, None] * sigma[:, None, :]
    assert np.max(np.abs(direct.P_eci - continued.P_eci) / scale) < 1e-6


def test_updates_that_do_not_shrink_stop_the_try_and_the_continuation_takes_over(monkeypatch):
    p = _pass()
    options = SmootherOptions()
    # min_shrink: the second update must be 1e12 times smaller than the first, which no
    # Gauss-Newton step from 10 km off is: stopped there, not converged
    with interpreted():
        x_guess = initial_guess(p, options.motion_model(), float(j2000_seconds(p.epoch0)))
        stopped = smooth_batch(p, replace(options, q_start_m2_s3=options.q_m2_s3), x_init=x_guess,
                               min_shrink=1e12)
    assert not stopped.extras["converged"] and stopped.iterations == 2
    monkeypatch.setattr(pipeline, "DIRECT_SHRINK", 1e12)
    fallback = _solve(p)
    continued = _solve(p, SmootherOptions(init="prior"))
    # the continuation from the same guess: the same numbers; the two tried updates counted
    assert np.array_equal(fallback.x_eci, continued.x_eci)
    assert fallback.iterations == continued.iterations + 2
    assert fallback.extras["converged"]
