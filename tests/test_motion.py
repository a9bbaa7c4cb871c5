"""Tests of factors.motion: residual and Jacobians, and the GTSAM CustomFactor adapter's
linearization (-Phi, I) with process-noise whitening."""

import gtsam
import numpy as np
import pytest

from factors.dynamics import MotionModel, process_noise, process_noise_sqrt_information, propagate
from factors.motion import make_motion_factor, motion_residual
from factors.testing import check_jacobians, check_linearization

X_GTO = np.array([6509244.371304875, 0.0, 3713244.835519765,
                  -3737.397235776740, 0.0, 8790.602460568101])
T_2010 = 3.156e8
D_SCALE = np.diag([1.0, 1.0, 1.0, 1e-3, 1e-3, 1e-3])


def _chain(n, dt, model, t0=0.0):
    xs = [X_GTO]
    for k in range(n - 1):
        xs.append(propagate(xs[-1], dt, model, t0 + k * dt, with_stm=False)[0])
    return np.array(xs)


def test_residual_zero_on_the_propagated_chain_and_jacobians():
    model = MotionModel(third_body=True)
    X = _chain(6, 7.5, model, T_2010)
    dt = np.full(5, 7.5)
    t0 = T_2010 + 7.5 * np.arange(5)
    e, H0, H1 = motion_residual(X[:-1], X[1:], dt, model, t0)
    assert e.shape == (5, 6) and H0.shape == (5, 6, 6) and H1.shape == (5, 6, 6)
    np.testing.assert_allclose(e, 0.0, atol=1e-9)
    np.testing.assert_array_equal(H1, np.broadcast_to(np.eye(6), (5, 6, 6)))
    # perturbed point, Jacobians vs central differences in scaled coordinates
    rng = np.random.default_rng(11)
    x0 = X[:-1] + rng.normal(size=(5, 6)) * [100, 100, 100, 0.1, 0.1, 0.1]
    x1 = X[1:] + rng.normal(size=(5, 6)) * [100, 100, 100, 0.1, 0.1, 0.1]
    e, H0, H1 = motion_residual(x0, x1, dt, model, t0)
    assert np.all(np.abs(e) > 0)

    def f(y0, y1):
        return motion_residual(x0 + y0 @ D_SCALE, x1 + y1 @ D_SCALE, dt, model, t0)[0]

    z = np.zeros((5, 6))
    check_jacobians(f, (z, z), (H0 @ D_SCALE, H1 @ D_SCALE), ("vector", "vector"),
                    rtol=1e-6, eps=(1.0, 1.0), names=("x0", "x1"))


def test_residual_shape_errors():
    with pytest.raises(ValueError):
        motion_residual(np.zeros((3, 6)), np.zeros((2, 6)), np.ones(3))


@pytest.mark.parametrize("dt, q, third", [(1.0, 1e-9, False), (0.1, 1e-9, False),
                                          (30.0, 1e-8, True), (-10.0, 1e-9, False)])
def test_custom_factor_linearizes_to_whitened_minus_phi_and_identity(dt, q, third):
    model = MotionModel(third_body=third)
    t0 = T_2010 if third else 0.0
    x0 = X_GTO
    x1 = propagate(x0, dt, model, t0, with_stm=False)[0] + np.array([3.0, -2.0, 1.0, 1e-3, 2e-3, -1e-3])
    k0, k1 = gtsam.symbol("x", 0), gtsam.symbol("x", 1)
    fac = make_motion_factor(k0, k1, dt, q, model, t0)
    v = gtsam.Values()
    v.insert(k0, x0)
    v.insert(k1, x1)
    e, H0, H1 = motion_residual(x0[None], x1[None], np.array([dt]), model, np.array([t0]))
    # GTSAM whitens with its own square root R of Q^-1 (not necessarily our upper W):
    # the linear factor must be || R [H0 H1] dx + R e ||^2, with R^T R = Q^-1 = W^T W.
    Q = process_noise(dt, q)
    R = fac.noiseModel().R()
    W = process_noise_sqrt_information(dt, q)
    np.testing.assert_allclose(R.T @ R, W.T @ W, rtol=1e-8, atol=1e-10 * np.abs(W.T @ W).max())
    np.testing.assert_allclose(R, W, rtol=1e-8, atol=1e-10 * np.abs(W).max())  # same upper Cholesky
    check_linearization(fac, v, (R @ H0[0], R @ H1[0]), -R @ e[0], rtol=1e-6,
                        atol=1e-9 * np.abs(R).max())
    # error = 0.5 e^T Q^-1 e
    assert fac.error(v) == pytest.approx(0.5 * e[0] @ np.linalg.solve(Q, e[0]), rel=1e-8)
    # the A^T A information of the linear factor equals H^T Q^-1 H (independent of the sqrt factor)
    A, b = fac.linearize(v).jacobian()
    Hst = np.hstack([H0[0], H1[0]])
    np.testing.assert_allclose(A.T @ A, Hst.T @ np.linalg.solve(Q, Hst), rtol=1e-6,
                               atol=1e-9 * np.abs(A.T @ A).max())


def test_factor_in_a_graph_recovers_the_propagated_state():
    """Prior on x0 + motion factor: Gauss-Newton (QR) puts x1 on f(x0)."""
    model = MotionModel()
    dt, q = 20.0, 1e-9
    k0, k1 = gtsam.symbol("x", 0), gtsam.symbol("x", 1)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorVector(k0, X_GTO, gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
    graph.add(make_motion_factor(k0, k1, dt, q, model))
    v = gtsam.Values()
    v.insert(k0, X_GTO + np.array([50.0, -20, 10, 0.1, 0, -0.05]))
    v.insert(k1, propagate(X_GTO, dt, model)[0] + np.array([1e3, 1e3, -1e3, 1.0, -1.0, 0.5]))
    params = gtsam.GaussNewtonParams()
    params.setLinearSolverType("MULTIFRONTAL_QR")
    res = gtsam.GaussNewtonOptimizer(graph, v, params).optimize()
    x1 = res.atVector(k1)
    np.testing.assert_allclose(x1, propagate(res.atVector(k0), dt, model)[0], rtol=0, atol=1e-6)
    np.testing.assert_allclose(res.atVector(k0), X_GTO, atol=1e-6)


def test_factor_rejects_zero_dt():
    with pytest.raises(ValueError):
        make_motion_factor(0, 1, 0.0, 1e-9)
