"""Inter-satellite pseudorange / carrier-phase model (factors.pseudorange; Xing et al. eq. (1))."""

import numpy as np
import pytest

from factors.geometry import so3_exp
from factors.pseudorange import (
    ANTENNA_RX_BODY_M, ANTENNA_TX_BODY_M, CLOCK_SIGNS, carrier_residual,
    carrier_residual_spherical, cartesian_to_spherical, link_offsets, m21_from_rpy,
    make_carrier_factor, make_pseudorange_factor, predict_ranges, pseudorange_residual,
    pseudorange_residual_spherical, rotation_xyz, spherical_to_cartesian,
)
from factors.testing import check_jacobians


@pytest.fixture
def point():
    rng = np.random.default_rng(7)
    N = 5
    s = np.column_stack([1000 + 50 * rng.standard_normal(N), 0.3 * rng.standard_normal(N),
                         0.3 * rng.standard_normal(N)])
    r, _ = spherical_to_cartesian(s)
    M = np.array([so3_exp(0.5 * rng.standard_normal(3)) for _ in range(N)])
    cdt = rng.standard_normal(N)
    amb = rng.standard_normal((N, 6))
    z = predict_ranges(r, cdt, M) + 0.01 * rng.standard_normal((N, 6))
    return s, r, M, cdt, amb, z


def test_model_is_seed_equation_1(point):
    """rho_1j = |r + M21 a_20 - a_1j| + c dt, rho_2j = |-r + a_10 - M21 a_2j| - c dt."""
    _, r, M, cdt, _, _ = point
    rho = predict_ranges(r, cdt, M)
    for k in range(r.shape[0]):
        for j in range(3):
            d1 = r[k] + M[k] @ ANTENNA_TX_BODY_M - ANTENNA_RX_BODY_M[j]
            d2 = -r[k] + ANTENNA_TX_BODY_M - M[k] @ ANTENNA_RX_BODY_M[j]
            assert rho[k, j] == pytest.approx(np.linalg.norm(d1) + cdt[k], abs=1e-9)
            assert rho[k, 3 + j] == pytest.approx(np.linalg.norm(d2) - cdt[k], abs=1e-9)
    assert np.array_equal(CLOCK_SIGNS, [1, 1, 1, -1, -1, -1])


def test_zero_residual_at_truth(point):
    s, r, M, cdt, amb, _ = point
    z = predict_ranges(r, cdt, M)
    assert np.abs(pseudorange_residual(r, cdt, z, M)[0]).max() < 1e-9
    assert np.abs(pseudorange_residual_spherical(s, cdt, z, M)[0]).max() < 1e-9
    assert np.abs(carrier_residual(r, cdt, amb, z + amb, M)[0]).max() < 1e-9
    assert np.abs(carrier_residual_spherical(s, cdt, amb, z + amb, M)[0]).max() < 1e-9


def test_jacobians_cartesian_and_spherical(point):
    s, r, M, cdt, amb, z = point
    _, H_r, H_c = pseudorange_residual(r, cdt, z, M)
    check_jacobians(lambda r_, c_: pseudorange_residual(r_, c_[:, 0], z, M),
                    (r, cdt[:, None]), (H_r, H_c), ("vector", "vector"))
    _, H_s, H_c = pseudorange_residual_spherical(s, cdt, z, M)
    # spherical: angles in rad need an absolute step, not 1e-6 * |(R, az, el)| ~ 1e-3
    check_jacobians(lambda s_, c_: pseudorange_residual_spherical(s_, c_[:, 0], z, M),
                    (s, cdt[:, None]), (H_s, H_c), ("vector", "vector"),
                    eps=(1e-6, 1e-6), rtol=1e-5)


def test_jacobians_carrier(point):
    s, r, M, cdt, amb, z = point
    for f, x in ((carrier_residual, r), (carrier_residual_spherical, s)):
        _, H_p, H_c, H_a = f(x, cdt, amb, z, M)
        check_jacobians(lambda p_, c_, a_: f(p_, c_[:, 0], a_, z, M),
                        (x, cdt[:, None], amb), (H_p, H_c, H_a), ("vector",) * 3,
                        eps=(1e-6, 1e-6, 1e-6), rtol=1e-5)


def test_spherical_round_trip_and_jacobian():
    s = np.array([[999.9, 0.2, -0.4], [10.0, -3.0, 1.2]])
    r, J = spherical_to_cartesian(s)
    assert np.allclose(cartesian_to_spherical(r), s)
    check_jacobians(lambda x: spherical_to_cartesian(x)[0], (s,), (J,), ("vector",),
                    eps=(1e-6,), rtol=1e-6)


def test_rotation_convention():
    """M_CB = Rx Ry Rz (passive); M21 = M_CB^T; a pure yaw of 90 deg maps body-2 x to body-1 y."""
    assert np.allclose(rotation_xyz(0.1, 0.2, 0.3) @ m21_from_rpy(0.1, 0.2, 0.3), np.eye(3))
    assert np.allclose(m21_from_rpy(0, 0, np.pi / 2) @ [1, 0, 0], [0, 1, 0])
    d = link_offsets(np.eye(3))
    assert np.allclose(d[0], [0, 0, -1]) and np.allclose(d[3], [0, 0, 1])


def test_xing_printed_design_matrix():
    """Xing et al. print A (Cartesian) and A' (spherical) at their epoch-1 estimate
    (R = 999.917 m, az = -0.00519 rad, el = 0.014 rad, M21 = I); ours match to their rounding."""
    A_seed = np.array([[.9999, -.005, .0129, 1], [.9999, -.004, .0129, 1],
                       [.9999, -.004, .0139, 1], [.9999, -.005, .0149, -1],
                       [.9999, -.006, .0149, -1], [.9999, -.006, .0139, -1]])
    Ap_seed = np.array([[1, 0, -.9999, 1], [1, .9999, -.9998, 1], [1, .9999, .0001, 1],
                        [1, 0, .9999, -1], [1, -.9999, .9998, -1], [1, -.9999, -.0001, -1]])
    s = np.array([999.917, -0.00519, 0.014])
    r, _ = spherical_to_cartesian(s)
    _, H_r, H_c = pseudorange_residual(r, 0.0, np.zeros(6), np.eye(3))
    assert np.abs(np.hstack([H_r, H_c]) - A_seed).max() < 6e-4
    _, H_s, H_c = pseudorange_residual_spherical(s, 0.0, np.zeros(6), np.eye(3))
    assert np.abs(np.hstack([H_s, H_c]) - Ap_seed).max() < 6e-4


@pytest.mark.parametrize("param", ["cartesian", "spherical"])
def test_custom_factors_match_numpy(point, param):
    import gtsam

    s, r, M, cdt, amb, z = point
    p = r[0] if param == "cartesian" else s[0]
    kp, kc, kn = gtsam.symbol("p", 0), gtsam.symbol("c", 0), gtsam.symbol("n", 0)
    vals = gtsam.Values()
    vals.insert(kp, p)
    vals.insert(kc, np.array([cdt[0]]))
    vals.insert(kn, amb[0])
    f = make_pseudorange_factor(kp, kc, z[0], M[0], 0.01, param)
    res = pseudorange_residual if param == "cartesian" else pseudorange_residual_spherical
    e, H_p, H_c = res(p, cdt[0], z[0], M[0])
    assert f.error(vals) == pytest.approx(0.5 * np.sum((e / 0.01) ** 2), rel=1e-10)
    lin = f.linearize(vals)
    A, b = lin.jacobian()
    assert np.allclose(A, np.hstack([H_p, H_c]) / 0.01)
    assert np.allclose(b, -e / 0.01)
    g = make_carrier_factor(kp, kc, kn, z[0] + amb[0], M[0], 1e-5, param)
    assert g.error(vals) == pytest.approx(0.5 * np.sum((e / 1e-5) ** 2), rel=1e-8)
    A, _ = g.linearize(vals).jacobian()
    assert A.shape == (6, 10)


def test_bad_param_rejected():
    with pytest.raises(ValueError):
        make_pseudorange_factor(1, 2, np.zeros(6), np.eye(3), 0.01, "polar")
