"""Modified equinoctial elements (factors/elements.py): the maps, the analytic Jacobian
against central differences, and Gauss's variational equations against the inverse Jacobian
(Walker, Ireland & Owens 1985; Betts 2010)."""

import numpy as np
import pytest

from factors.constants import MU_EARTH_M3_S2 as MU
from factors.elements import (cartesian_from_mee, gauss_variational_equations,
                              mee_from_cartesian, mee_jacobian_inverse)
from factors.testing import numerical_jacobian
from fgnav.orbit import elements_to_state, rtn_frame

# GTO (e = 0.72, i = 90 deg: h = 1), a near-circular near-equatorial LEO (where the classical
# set is singular), a retrograde inclined orbit and a hyperbola
STATES = np.array([
    [6509244.371304875, 0.0, 3713244.835519765, -3737.397235776740, 0.0, 8790.602460568101],
    elements_to_state(7.0e6, 1e-4, np.radians(0.01), 0.3, 0.2, 1.0),
    elements_to_state(2.0e7, 0.3, np.radians(150.0), 2.0, -1.0, 2.5),
    [7.0e6, 1.0e6, 2.0e5, 300.0, 11000.0, 5000.0],
])


def test_round_trip_and_classical_values():
    E = mee_from_cartesian(STATES)
    np.testing.assert_allclose(cartesian_from_mee(E, jacobian=False), STATES, rtol=1e-12,
                               atol=1e-6)
    # the definition against the classical elements of a chosen orbit
    a, e, i, raan, argp, nu = 2.0e7, 0.3, np.radians(150.0), 2.0, -1.0, 2.5
    p, f, g, h, k, L = E[2]
    assert p == pytest.approx(a * (1 - e * e), rel=1e-12)
    assert (f, g) == pytest.approx((e * np.cos(argp + raan), e * np.sin(argp + raan)), abs=1e-12)
    t = np.tan(i / 2)
    assert (h, k) == pytest.approx((t * np.cos(raan), t * np.sin(raan)), rel=1e-10)
    assert np.angle(np.exp(1j * (L - (raan + argp + nu)))) == pytest.approx(0.0, abs=1e-12)


def test_jacobian_central_differences():
    E = mee_from_cartesian(STATES)
    _, J = cartesian_from_mee(E)
    eps = np.array([1e-3, 1e-8, 1e-8, 1e-8, 1e-8, 1e-8]) * np.maximum(1, np.abs(E))
    for j in range(6):
        d = np.zeros(6)
        d[j] = 1.0
        num = (cartesian_from_mee(E + eps[:, j:j + 1] * d, jacobian=False)
               - cartesian_from_mee(E - eps[:, j:j + 1] * d, jacobian=False)) / (2 * eps[:, j:j + 1])
        np.testing.assert_allclose(J[:, :, j], num, rtol=1e-6, atol=1e-6 * np.abs(J).max())
    # and the inverse map's Jacobian against differences of mee_from_cartesian
    Jinv, _ = mee_jacobian_inverse(STATES[:3])
    num = numerical_jacobian(mee_from_cartesian, STATES[:3])
    np.testing.assert_allclose(Jinv, num, rtol=1e-5, atol=1e-9 * np.abs(Jinv).max())


def test_gauss_equations_are_the_inverse_jacobian():
    """An impulse changes the velocity only: B = (dE/dv) [r_hat t_hat n_hat]; on a Keplerian
    orbit dE/dt = (dE/dx) [v; -mu r/|r|^3] = A (only L moves)."""
    Jinv, E = mee_jacobian_inverse(STATES)
    A, B = gauss_variational_equations(E)
    for n in range(len(STATES)):
        R = rtn_frame(STATES[n])   # rows: radial, transverse, normal
        R = R if R.shape == (3, 3) else R[0]
        np.testing.assert_allclose(B[n], Jinv[n][:, 3:] @ R.T, rtol=1e-9,
                                   atol=1e-12 * np.abs(B[n]).max())
        r, v = STATES[n, :3], STATES[n, 3:]
        xdot = np.concatenate([v, -MU * r / np.linalg.norm(r) ** 3])
        scale = np.abs(Jinv[n]) @ np.abs(xdot)   # rounding of each rate's terms
        np.testing.assert_allclose(A[n], Jinv[n] @ xdot, rtol=1e-9, atol=1e-12 * scale.max())
        assert np.all(np.abs(A[n] - Jinv[n] @ xdot) <= 1e-10 * scale + 1e-15)


def test_retrograde_equatorial_is_refused():
    x = elements_to_state(7e6, 0.01, np.pi, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="retrograde"):
        mee_from_cartesian(x)


def test_gauss_propagation_is_the_cartesian_flow():
    """RK4 of Gauss's equations with the J2 term and the independent DOP853 integrator
    reach the same state after 2 h of the transfer orbit (to the RK4 error at 10 s steps)."""
    from factors.dynamics import accel_j2
    from factors.elements import gauss_propagate
    from fgnav.orbit import integrate_truth

    x0 = STATES[0]
    x_true = integrate_truth(x0, np.array([0.0, 7200.0]))[-1]

    def j2_only(r):
        return accel_j2(r.reshape(-1, 3)).reshape(r.shape) + MU * r / np.linalg.norm(
            r, axis=-1, keepdims=True) ** 3

    E1 = gauss_propagate(mee_from_cartesian(x0), 7200.0, 720, j2_only)
    x1 = cartesian_from_mee(E1, jacobian=False)
    assert np.linalg.norm(x1[:3] - x_true[:3]) < 1.0           # m, after 2 h
    E1_kepler = gauss_propagate(mee_from_cartesian(x0), 7200.0, 720, lambda r: 0.0 * r)
    assert np.linalg.norm(cartesian_from_mee(E1_kepler, jacobian=False)[:3] - x_true[:3]) > 1e3
