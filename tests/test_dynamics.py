"""Tests of factors.dynamics: gravity/third-body gradients, RK4 propagation and its exact STM,
accuracy against the independent truth integrator (fgnav.orbit.integrate_truth), process noise."""

import numpy as np
import pytest

from factors.constants import DEG, J2_EARTH, MU_EARTH_M3_S2, MU_MOON_M3_S2, MU_SUN_M3_S2, R_EARTH_M
from factors.dynamics import (
    MotionModel, accel_j2, accel_j2_gradient, accel_third_body, accel_third_body_gradient,
    process_noise, process_noise_sqrt_information, propagate, propagate_many,
)
from factors.ephemeris import moon_position_eci_m, sun_position_eci_m
from factors.testing import check_jacobians, random_positions_m
from fgnav.orbit import elements_to_state, integrate_truth

# Pan & Yao 2017, sec. 3.1: the gto-transfer initial state, ECI, m and m/s.
X_GTO = np.array([6509244.371304875, 0.0, 3713244.835519765,
                  -3737.397235776740, 0.0, 8790.602460568101])
# The INS/CNS lecture: LEO a = R_e + 504 km, e = 0.0011, i = 97 deg, RAAN = 77, argp = 55, nu = 10
# deg.
X_LEO = elements_to_state(R_EARTH_M + 504e3, 0.0011, 97 * DEG, 77 * DEG, 55 * DEG, 10 * DEG)
T_2010 = 3.156e8  # s since J2000 (~2010), for the Sun/Moon positions

# State scaling for finite differences: perturb positions by 1 m and velocities by 1 mm/s.
D_SCALE = np.diag([1.0, 1.0, 1.0, 1e-3, 1e-3, 1e-3])


def test_accel_j2_matches_closed_form_and_two_body_limit():
    r = np.array([7.0e6, 0.0, 0.0])
    a = accel_j2(r)
    # On the equator: a_x = -mu/r^2 (1 + 1.5 J2 (Re/r)^2)
    expected = -MU_EARTH_M3_S2 / 7.0e6 ** 2 * (1.0 + 1.5 * J2_EARTH * (R_EARTH_M / 7.0e6) ** 2)
    assert a[0] == pytest.approx(expected, rel=1e-14)
    assert a[1] == 0.0 and a[2] == 0.0
    # Over the pole: a_z = -mu/r^2 (1 + 1.5 J2 (Re/r)^2 (3 - 5)) = -mu/r^2 (1 - 3 J2 (Re/r)^2)
    az = accel_j2(np.array([0.0, 0.0, 7.0e6]))[2]
    assert az == pytest.approx(-MU_EARTH_M3_S2 / 7.0e6 ** 2 * (1 - 3 * J2_EARTH * (R_EARTH_M / 7.0e6) ** 2), rel=1e-14)
    R = random_positions_m(np.random.default_rng(1), 5)
    np.testing.assert_allclose(accel_j2(R, j2=0.0),
                               -MU_EARTH_M3_S2 * R / np.linalg.norm(R, axis=1, keepdims=True) ** 3, rtol=1e-14)


def test_accel_j2_gradient_vs_central_differences():
    R = random_positions_m(np.random.default_rng(2), 20)
    R = np.vstack([R, X_LEO[:3], X_GTO[:3]])
    G = accel_j2_gradient(R)
    check_jacobians(lambda r: accel_j2(r), (R,), (G,), ("vector",), rtol=1e-6, names=("r",))
    # the J2 part alone (so its gradient is checked at its own scale, not swamped by mu/r^3)
    GJ = G - accel_j2_gradient(R, j2=0.0)
    check_jacobians(lambda r: accel_j2(r) - accel_j2(r, j2=0.0), (R,), (GJ,), ("vector",),
                    rtol=1e-5, names=("r",))
    assert np.allclose(G, np.swapaxes(G, 1, 2), rtol=1e-12, atol=0)  # gradient of a potential


def test_third_body_acceleration_and_gradient():
    R = random_positions_m(np.random.default_rng(3), 10)
    for rb, mub, mag in ((moon_position_eci_m(T_2010), MU_MOON_M3_S2, 2.5e-5),
                         (sun_position_eci_m(T_2010), MU_SUN_M3_S2, 1.2e-5)):
        a = accel_third_body(R, rb, mub)
        # tidal magnitude ~ 2 mu_b |r| / |r_b|^3 at most: bounded, nonzero
        assert np.all(np.linalg.norm(a, axis=1) < mag) and np.all(np.linalg.norm(a, axis=1) > 0)
        G = accel_third_body_gradient(R, rb, mub)
        check_jacobians(lambda r: accel_third_body(r, rb, mub), (R,), (G,), ("vector",),
                        rtol=1e-5, names=("r",))
        # At the geocentre the indirect term cancels the direct one exactly.
        np.testing.assert_allclose(accel_third_body(np.zeros(3), rb, mub), 0.0, atol=1e-20)


@pytest.mark.parametrize("x0, dt, model, t0", [
    (X_GTO, 1.0, MotionModel(), 0.0),
    (X_GTO, -1.0, MotionModel(), 0.0),
    (X_GTO, 37.0, MotionModel(), 0.0),          # 8 sub-steps
    (X_LEO, -60.0, MotionModel(), 0.0),         # backward, 12 sub-steps
    (X_LEO, 60.0, MotionModel(third_body=True), T_2010),
    (X_GTO, -23.0, MotionModel(third_body=True, max_step_s=4.0), T_2010),
])
def test_stm_is_the_derivative_of_the_rk4_map(x0, dt, model, t0):
    x1, Phi = propagate(x0, dt, model, t0)

    def f(y):  # y (N,6) scaled perturbations -> propagated states
        return np.array([propagate(x0 + D_SCALE @ yi, dt, model, t0, with_stm=False)[0] for yi in y])

    check_jacobians(f, (np.zeros((1, 6)),), ((Phi @ D_SCALE)[None],), ("vector",),
                    rtol=1e-6, eps=(1.0,), names=("x0",))
    assert not np.allclose(Phi, np.eye(6))


def test_propagate_zero_dt_is_identity():
    x1, Phi = propagate(X_GTO, 0.0)
    np.testing.assert_array_equal(x1, X_GTO)
    np.testing.assert_array_equal(Phi, np.eye(6))


def test_one_hour_gto_against_truth_long_step_and_chain():
    """Pan & Yao 2017's transfer orbit, 1 h from its initial state: RK4 (default 5 s sub-steps) vs
    DOP853."""
    model = MotionModel()
    truth = integrate_truth(X_GTO, np.array([600.0, 3600.0]))
    # one long dt, 720 sub-steps
    x1, _ = propagate(X_GTO, 3600.0, model, with_stm=False)
    assert np.linalg.norm(x1[:3] - truth[1, :3]) < 1e-3
    assert np.linalg.norm(x1[3:] - truth[1, 3:]) < 1e-6
    # a chain of 1 s steps (the 1 Hz batch case): 3600 calls, one sub-step each
    x = X_GTO.copy()
    for k in range(3600):
        x, _ = propagate(x, 1.0, model, with_stm=False)
        if k == 599:
            assert np.linalg.norm(x[:3] - truth[0, :3]) < 1e-3
    assert np.linalg.norm(x[:3] - truth[1, :3]) < 1e-3
    assert np.linalg.norm(x[3:] - truth[1, 3:]) < 1e-6
    # the orbit moved (thousands of km): the comparison is not trivial
    assert np.linalg.norm(truth[1, :3] - X_GTO[:3]) > 1e7


def test_coarse_step_is_detectably_worse():
    """The accuracy test can fail: a 60 s sub-step misses the truth by metres."""
    truth = integrate_truth(X_GTO, np.array([3600.0]))[0]
    x1, _ = propagate(X_GTO, 3600.0, MotionModel(max_step_s=60.0), with_stm=False)
    assert np.linalg.norm(x1[:3] - truth[:3]) > 1.0


def test_third_body_propagation_against_truth_and_effect_size():
    t = np.array([3600.0])
    truth = integrate_truth(X_LEO, t, third_body=True, t0_j2000_s=T_2010)[0]
    x1, _ = propagate(X_LEO, 3600.0, MotionModel(third_body=True), T_2010, with_stm=False)
    assert np.linalg.norm(x1[:3] - truth[:3]) < 1e-3
    x_nb, _ = propagate(X_LEO, 3600.0, MotionModel(), T_2010, with_stm=False)
    assert np.linalg.norm(x_nb[:3] - truth[:3]) > 1.0  # Sun/Moon move a LEO by metres per hour


def test_j2_on_and_off_differ_by_a_lot():
    x_j2, _ = propagate(X_LEO, 3600.0, MotionModel(), with_stm=False)
    x_2b, _ = propagate(X_LEO, 3600.0, MotionModel(j2=0.0), with_stm=False)
    assert np.linalg.norm(x_j2[:3] - x_2b[:3]) > 1e3  # km-level in one LEO hour
    truth_2b = integrate_truth(X_LEO, np.array([3600.0]), j2=False)[0]
    assert np.linalg.norm(x_2b[:3] - truth_2b[:3]) < 1e-3


def test_forward_then_backward_returns_to_start():
    x1, P1 = propagate(X_GTO, 1234.5, MotionModel(third_body=True), T_2010)
    x0, P0 = propagate(x1, -1234.5, MotionModel(third_body=True), T_2010 + 1234.5)
    assert np.linalg.norm(x0[:3] - X_GTO[:3]) < 1e-5
    assert np.linalg.norm(x0[3:] - X_GTO[3:]) < 1e-8
    np.testing.assert_allclose(P0 @ P1, np.eye(6), atol=1e-6)


def test_propagate_many_equals_single_calls():
    rng = np.random.default_rng(7)
    N = 17
    X = np.tile(X_GTO, (N, 1)) + rng.normal(size=(N, 6)) * [1e4, 1e4, 1e4, 1.0, 1.0, 1.0]
    X[::2] = X_LEO + rng.normal(size=(9, 6)) * 10.0
    dt = rng.uniform(-30.0, 30.0, N)
    t0 = T_2010 + rng.uniform(0, 1e5, N)
    model = MotionModel(third_body=True)
    X1, Phi = propagate_many(X, dt, model, t0)
    X1b, none = propagate_many(X, dt, model, t0, with_stm=False)
    assert none is None
    for k in range(N):
        x1, P = propagate(X[k], dt[k], model, t0[k])
        np.testing.assert_array_equal(X1[k], x1)
        np.testing.assert_array_equal(Phi[k], P)
        np.testing.assert_array_equal(X1b[k], x1)


def test_bad_inputs_raise():
    with pytest.raises(ValueError):
        MotionModel(max_step_s=0.0)
    with pytest.raises(ValueError):
        propagate(np.zeros(5), 1.0)
    with pytest.raises(ValueError):
        process_noise(1.0, -1e-9)
    with pytest.raises(ValueError):
        process_noise_sqrt_information(0.0, 1e-9)


@pytest.mark.parametrize("dt", [0.1, 1.0, 60.0, -5.0])
def test_process_noise_spd_and_sqrt_information(dt):
    q = 1e-9
    Q = process_noise(dt, q)
    T = abs(dt)
    np.testing.assert_allclose(Q[0, 0], q * T ** 3 / 3, rtol=1e-14)
    np.testing.assert_allclose(Q[0, 3], q * dt * T / 2, rtol=1e-14)
    np.testing.assert_allclose(Q[3, 3], q * T, rtol=1e-14)
    np.testing.assert_allclose(Q, Q.T, rtol=0, atol=0)
    assert np.all(np.linalg.eigvalsh(Q) > 0)
    W = process_noise_sqrt_information(dt, q)
    assert np.allclose(np.tril(W, -1), 0.0)
    np.testing.assert_allclose(W.T @ W @ Q, np.eye(6), atol=1e-9)
    # W whitens Q: W Q W^T = I (unit noise after pre-whitening)
    np.testing.assert_allclose(W @ Q @ W.T, np.eye(6), atol=1e-9)


def test_process_noise_vectorized():
    dt = np.array([0.1, 1.0, 10.0, -3.0])
    Q = process_noise(dt, 2e-8)
    W = process_noise_sqrt_information(dt, 2e-8)
    assert Q.shape == (4, 6, 6) and W.shape == (4, 6, 6)
    for k in range(4):
        np.testing.assert_array_equal(Q[k], process_noise(dt[k], 2e-8))
        np.testing.assert_allclose(W[k], process_noise_sqrt_information(dt[k], 2e-8), rtol=1e-15)


@pytest.mark.bench
def test_bench_propagate():
    """Speed report (never asserted): µs per propagate with/without STM, propagate_many rate."""
    import time
    for stm in (True, False):
        propagate(X_GTO, 1.0, with_stm=stm)
        t = time.perf_counter()
        for _ in range(20000):
            propagate(X_GTO, 1.0, with_stm=stm)
        print(f"propagate dt=1 s stm={stm}: {(time.perf_counter() - t) / 20000 * 1e6:.2f} us")
    N = 14400
    X = np.tile(X_GTO, (N, 1))
    propagate_many(X, np.ones(N))
    t = time.perf_counter()
    propagate_many(X, np.ones(N))
    el = time.perf_counter() - t
    print(f"propagate_many N={N}: {el * 1e3:.2f} ms, {el / N * 1e6:.3f} us/epoch")


def test_propagate_through_is_a_call_of_propagate_per_epoch_bit_for_bit():
    """The compiled chain (the first guess of every epoch) steps as one call of ``propagate``
    per epoch does, forward and back from a middle epoch, uneven steps, Sun and Moon on,
    compiled and as Python."""
    from factors.dynamics import MotionModel, propagate, propagate_through
    from factors.interpret import interpreted

    model = MotionModel(third_body=True)
    t_s = np.cumsum(np.r_[0.0, np.tile([30.0, 45.5, 600.0], 20)])
    t0, k = 8.0e8, 25
    x_k = np.array([6.9e6, 1.2e5, -3.0e4, -150.0, 7.4e3, 1.1e3])
    Y = np.empty((len(t_s), 6))
    Y[k] = x_k
    for j in range(k + 1, len(t_s)):
        Y[j] = propagate(Y[j - 1], t_s[j] - t_s[j - 1], model, t0 + t_s[j - 1], with_stm=False)[0]
    for j in range(k - 1, -1, -1):
        Y[j] = propagate(Y[j + 1], t_s[j] - t_s[j + 1], model, t0 + t_s[j + 1], with_stm=False)[0]
    for as_python in (False, True):
        with interpreted(as_python):
            X = propagate_through(x_k, t_s, k, model, t0)
        np.testing.assert_array_equal(X.view(np.int64), Y.view(np.int64))
    np.testing.assert_array_equal(propagate_through(x_k, t_s[:1], 0, model, t0), x_k[None])
