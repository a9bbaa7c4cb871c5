"""Short passes without numba: the kernels run as their Python bodies (factors.interpret), numba
is imported at a kernel's first compiled call (factors.jit), and both routes give the same
numbers; a short ``fgnav smooth`` never imports numba."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from factors import dynamics
from factors.direction import sphere_log
from factors.interpret import active, interpreted, python_body
from factors.limb import limb_radius_residual
from fgnav.diagnostics.crb import cumulative_stm
from fgnav.solvers.chain import back_substitute, chain_marginals

ROOT = Path(__file__).resolve().parents[1]


def _states(rng, n):
    r = rng.normal(size=(n, 3))
    r *= (rng.uniform(6.8e6, 4.0e7, n) / np.linalg.norm(r, axis=1))[:, None]
    v = np.cross(r, rng.normal(size=(n, 3)))
    v *= (np.sqrt(3.986e14 / np.linalg.norm(r, axis=1)) / np.linalg.norm(v, axis=1))[:, None]
    return np.hstack([r, v])


def test_propagation_as_python_matches_the_compiled_kernels():
    """The numpy form of propagate_many (all epochs at once, steps of different sub-step counts,
    a zero step, backwards) and the Python body of propagate equal the compiled kernels."""
    rng = np.random.default_rng(3)
    X = _states(rng, 40)
    dt = rng.uniform(-70.0, 70.0, 40)
    dt[5] = 0.0
    t0 = 8.0e8 + 10.0 * np.arange(40)
    for third in (False, True):
        model = dynamics.MotionModel(third_body=third)
        X1, Phi = dynamics.propagate_many(X, dt, model, t0)
        with interpreted():
            Y1, Psi = dynamics.propagate_many(X, dt, model, t0)
            y, psi = dynamics.propagate(X[7], dt[7], model, t0[7])
            z, none = dynamics.propagate(X[7], dt[7], model, t0[7], with_stm=False)
        assert np.allclose(Y1, X1, rtol=1e-13, atol=1e-9) and np.allclose(Psi, Phi, rtol=1e-12, atol=1e-12)
        assert np.allclose(y, X1[7], rtol=1e-13, atol=1e-9) and np.allclose(psi, Phi[7], rtol=1e-12, atol=1e-12)
        assert np.array_equal(z, y) and none is None
        assert np.array_equal(Y1[5], X[5]) and np.array_equal(Psi[5], np.eye(6))
    # the propagation is not a no-op: 70 s moves a LEO state by hundreds of km
    assert np.max(np.abs(X1[:, :3] - X[:, :3])) > 1e5


def test_the_first_guess_chain_in_floats_equals_the_compiled_chain():
    """The interpreted route's first guess (the prior carried through every epoch) is the
    compiled chain's to the last bit, forward and back from a middle epoch, with steps of
    several sub-steps, a zero step, J2 and a point mass; with the third body it runs the
    kernel's own body, which agrees to rounding."""
    rng = np.random.default_rng(8)
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.0, 400.0, 120))])
    t[40] = t[39]
    x0 = _states(rng, 1)[0]
    for model in (dynamics.MotionModel(), dynamics.MotionModel(j2=0.0),
                  dynamics.MotionModel(third_body=True)):
        compiled = dynamics.propagate_through(x0, t, 30, model, 8.0e8)
        with interpreted():
            floats = dynamics.propagate_through(x0, t, 30, model, 8.0e8)
        if model.third_body:
            assert np.allclose(floats, compiled, rtol=1e-12, atol=1e-6)
        else:
            assert np.array_equal(floats, compiled)
        assert np.array_equal(compiled[30], x0) and np.array_equal(compiled[40], compiled[39])
    # the J2 and point-mass chains differ (the field is not ignored): km over 13 h
    assert np.max(np.abs(compiled[:, :3] - x0[:3])) > 1e6


def test_other_kernels_as_python_match_the_compiled_ones():
    rng = np.random.default_rng(4)
    n = 30
    A = rng.normal(size=(n, 6, 6)) + 6 * np.eye(6)
    R = np.triu(A)
    S = rng.normal(size=(n, 6, 6))
    S[-1] = 0.0
    d = rng.normal(size=(n, 6))
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    w = u + 0.01 * rng.normal(size=(n, 3))
    w /= np.linalg.norm(w, axis=1)[:, None]
    r = _states(rng, n)[:, :3]
    rho = np.arcsin(6.4e6 / np.linalg.norm(r, axis=1)) + 1e-4
    Phi = dynamics.propagate_many(_states(rng, n), np.full(n, 30.0))[1]
    compiled = (back_substitute(R, S, d), chain_marginals(R, S), sphere_log(u, w),
                limb_radius_residual(r, rho, 6.4e6), dynamics.accel_j2_gradient(r),
                dynamics.process_noise(np.full(n, 2.0), 1e-9), python_body(cumulative_stm)(Phi))
    with interpreted():
        assert active()
        python = (back_substitute(R, S, d), chain_marginals(R, S), sphere_log(u, w),
                  limb_radius_residual(r, rho, 6.4e6), dynamics.accel_j2_gradient(r),
                  dynamics.process_noise(np.full(n, 2.0), 1e-9), cumulative_stm(Phi))
    assert not active()
    for a, b in zip(python, compiled):
        for x, y in zip(a if isinstance(a, tuple) else (a,), b if isinstance(b, tuple) else (b,)):
            assert np.allclose(x, y, rtol=1e-12, atol=1e-15)


def test_a_short_smooth_never_imports_numba(tmp_path):
    """``fgnav smooth`` of a 61-epoch pass runs without numba (the numba set-up alone costs more
    than the solve) and writes the same trajectory as the compiled route to far below its sigma."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    sim = subprocess.run([sys.executable, "-m", "fgnav", "simulate", "gto-transfer", "--out",
                          str(tmp_path / "s"), "--step-s", "60", "--duration-h", "1"],
                         capture_output=True, text=True, env=env, cwd=str(ROOT), timeout=600)
    assert sim.returncode == 0, sim.stderr
    code = (
        "import sys\n"
        "from fgnav.cli import main\n"
        f"rc = main(['smooth', {str(tmp_path / 's' / 'measurements.csv')!r}, '--out', {str(tmp_path / 'r')!r}, '--quiet'])\n"
        "print(rc, 'numba' in sys.modules)\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                         cwd=str(ROOT), timeout=600)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == ["0", "False"]
    from fgnav import pipeline

    short, _ = pipeline.smooth_file(tmp_path / "s" / "measurements.csv")
    saved = pipeline.SHORT_PASS_ROWS
    pipeline.SHORT_PASS_ROWS = 0
    try:
        compiled, _ = pipeline.smooth_file(tmp_path / "s" / "measurements.csv")
    finally:
        pipeline.SHORT_PASS_ROWS = saved
    sigma = np.sqrt(np.diagonal(compiled.solution.P_eci, axis1=1, axis2=2))
    assert np.max(np.abs(short.solution.x_eci - compiled.solution.x_eci) / sigma) < 1e-6
    scale = sigma[:, :, None] * sigma[:, None, :]   # covariances relative to sigma_i sigma_j
    assert np.max(np.abs(short.solution.P_eci - compiled.solution.P_eci) / scale) < 1e-6


def test_numba_is_imported_at_the_first_compiled_call():
    code = ("import sys, numpy as np\n"
            "import fgnav.pipeline, factors.dynamics as d\n"
            "before = 'numba' in sys.modules\n"
            "x1, Phi = d.propagate_many(np.array([[7e6, 0, 0, 0, 7.5e3, 0.0]]), 10.0)\n"
            "print(before, 'numba' in sys.modules, type(d.propagate_nb).__name__)\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=dict(os.environ, PYTHONPATH=str(ROOT)), cwd=str(ROOT), timeout=600)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == ["False", "True", "CPUDispatcher"]


def test_the_compiled_ekf_finds_every_row_kernel_whichever_side_numba_loaded_first():
    """A model built before numba was loaded holds its lazy kernel, the compiled EKF's table
    may hold the numba dispatcher (or the other way round): the kernel is found either way.
    (Compared by identity, a 4 h pass lost its compiled-EKF first guess once numba had been
    loaded before the solve: 7 Gauss-Newton iterations instead of 3.)"""
    from dataclasses import replace

    from factors.jit import load_numba
    from fgnav.models.registry import MODELS
    from fgnav.solvers import ekf_numba

    load_numba()
    with_kernel = [m for m in MODELS.values() if m.numba_kernel is not None]
    assert len(with_kernel) >= 5
    for m in with_kernel:
        code = ekf_numba._code(m)
        assert code is not None, m.kind
        kern = m.numba_kernel
        for other in (getattr(kern, "dispatcher", None), kern):
            if other is not None:
                assert ekf_numba._code(replace(m, numba_kernel=other)) == code, m.kind
