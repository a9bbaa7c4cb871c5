"""Inter-satellite link between two absolute orbit states (factors.isl): the light-time
model, its Jacobians, its GTSAM adapters, its accuracy against an exact light-time solution
on DOP853 truth, and its reduction to Xing et al.'s relative model (factors.pseudorange)."""

import gtsam
import numpy as np
import pytest

from factors.adapters import whiten
from factors.constants import C_LIGHT_M_S, DEG, R_EARTH_M
from factors.isl import (
    isl_attitude_jacobians, isl_carrier_residual, isl_predict_range, isl_range_residual,
    light_time, make_isl_carrier_factor, make_isl_range_factor,
)
from factors.pseudorange import (
    ANTENNA_RX_BODY_M, ANTENNA_TX_BODY_M, CLOCK_SIGNS, m21_from_rpy, predict_ranges,
    pseudorange_residual,
)
from factors.testing import (
    check_jacobians, check_linearization, random_positions_m, random_rotations,
)
from fgnav.frames import deputy_from_relative_lvlh, relative_position_body
from fgnav.orbit import elements_to_state, integrate_truth, rtn_frame, truth_acceleration

LEVER_1_M = np.array([0.6, -0.5, 0.4])
LEVER_2_M = np.array([-0.3, 0.7, -0.8])


@pytest.fixture
def rows():
    """Eight rows: LEO-to-GEO radii, separations 1 km to 3,000 km, speeds to 10 km/s, random
    attitudes and ~1 m lever arms, both clock signs."""
    rng = np.random.default_rng(16)
    M = 8
    r_rx = random_positions_m(rng, M)
    sep = np.geomspace(1e3, 3e6, M)[:, None] * rng.normal(size=(M, 3)) / np.sqrt(3.0)
    x_rx = np.hstack([r_rx, 6e3 * rng.normal(size=(M, 3))])
    x_tx = np.hstack([r_rx + sep, 6e3 * rng.normal(size=(M, 3))])
    R_rx, R_tx = random_rotations(rng, M), random_rotations(rng, M)
    a_rx, a_tx = rng.normal(size=(M, 3)), rng.normal(size=(M, 3))
    clock = 30.0 * rng.normal(size=M)
    sign = np.where(np.arange(M) % 2 == 0, 1.0, -1.0)
    amb = 5.0 * rng.normal(size=M)
    rho = (isl_predict_range(x_rx, x_tx, R_rx, R_tx, a_rx, a_tx) + sign * clock
           + rng.normal(size=M))
    return x_rx, x_tx, R_rx, R_tx, a_rx, a_tx, clock, sign, rho, amb


def test_light_time_solves_the_light_time_equation(rows):
    x_rx, x_tx, R_rx, R_tx, a_rx, a_tx, *_ = rows
    d0 = (x_rx[:, :3] + np.einsum("mij,mj->mi", R_rx, a_rx)
          - x_tx[:, :3] - np.einsum("mij,mj->mi", R_tx, a_tx))
    tau, D, _ = light_time(d0, x_tx[:, 3:])
    # |p_rx - (p_tx - v tau)| = c tau, to the rounding of ranges up to 3,000 km
    assert np.allclose(np.linalg.norm(d0 + x_tx[:, 3:] * tau[:, None], axis=1),
                       C_LIGHT_M_S * tau, rtol=1e-14, atol=1e-9)
    assert np.allclose(D, d0 + x_tx[:, 3:] * tau[:, None], rtol=0, atol=1e-9)
    assert np.all(tau > 0)
    # a transmitter at rest: tau = |d0|/c; receding from the receiver at 7 km/s, it emitted
    # from closer: |d0| - 7e3 tau = c tau; approaching, from farther: |d0| + 7e3 tau = c tau
    tau0, _, _ = light_time(d0, np.zeros_like(d0))
    assert np.allclose(C_LIGHT_M_S * tau0, np.linalg.norm(d0, axis=1), rtol=1e-15)
    u = d0 / np.linalg.norm(d0, axis=1, keepdims=True)
    for sign in (1.0, -1.0):        # -u: away from the receiver, +u: towards it
        tau_v, _, _ = light_time(d0, sign * 7e3 * u)
        assert np.allclose(tau_v, tau0 / (1 - sign * 7e3 / C_LIGHT_M_S), rtol=1e-13)


def _check_state_columns(f, x, H, name):
    """Central differences on the position (0.1 m step) and velocity (10 m/s step: the
    range depends on v through v tau, ~1e-3 s) columns separately."""
    check_jacobians(lambda r: f(np.hstack([r, x[:, 3:]])), (x[:, :3],), (H[:, :, :3],),
                    ("vector",), eps=(0.1,), names=(name + " position",))
    check_jacobians(lambda v: f(np.hstack([x[:, :3], v])), (x[:, 3:],), (H[:, :, 3:],),
                    ("vector",), eps=(10.0,), names=(name + " velocity",))


def test_range_and_carrier_jacobians(rows):
    x_rx, x_tx, R_rx, R_tx, a_rx, a_tx, clock, sign, rho, amb = rows
    e, H_rx, H_tx, H_c = isl_range_residual(x_rx, x_tx, R_rx, R_tx, a_rx, a_tx, clock, sign,
                                            rho)
    assert e.shape == (8, 1) and H_rx.shape == H_tx.shape == (8, 1, 6)
    assert H_c.shape == (8, 1, 1)
    _check_state_columns(lambda x: isl_range_residual(x, x_tx, R_rx, R_tx, a_rx, a_tx, clock,
                                                      sign, rho), x_rx, H_rx, "receiver")
    _check_state_columns(lambda x: isl_range_residual(x_rx, x, R_rx, R_tx, a_rx, a_tx, clock,
                                                      sign, rho), x_tx, H_tx, "transmitter")
    # the light time makes the range depend on the transmitter's velocity, not the receiver's
    assert np.all(np.abs(H_tx[:, 0, 3:]).max(axis=1) > 1e-6)
    assert np.all(H_rx[:, 0, 3:] == 0.0)
    check_jacobians(lambda c: isl_range_residual(x_rx, x_tx, R_rx, R_tx, a_rx, a_tx, c[:, 0],
                                                 sign, rho),
                    (clock[:, None],), (H_c,), ("vector",), eps=(1e-2,), names=("clock",))

    ec, Hc_rx, Hc_tx, Hc_c, H_a = isl_carrier_residual(x_rx, x_tx, R_rx, R_tx, a_rx, a_tx,
                                                       clock, sign, rho, amb)
    assert np.allclose(ec, e + amb[:, None], rtol=0, atol=1e-9)
    _check_state_columns(lambda x: isl_carrier_residual(x, x_tx, R_rx, R_tx, a_rx, a_tx, clock,
                                                        sign, rho, amb), x_rx, Hc_rx, "rx")
    _check_state_columns(lambda x: isl_carrier_residual(x_rx, x, R_rx, R_tx, a_rx, a_tx, clock,
                                                        sign, rho, amb), x_tx, Hc_tx, "tx")
    check_jacobians(
        lambda c, a: isl_carrier_residual(x_rx, x_tx, R_rx, R_tx, a_rx, a_tx, c[:, 0], sign,
                                          rho, a[:, 0]),
        (clock[:, None], amb[:, None]), (Hc_c, H_a), ("vector", "vector"), eps=(1e-2, 1e-2),
        names=("clock", "ambiguity"))


def test_attitude_jacobians(rows):
    x_rx, x_tx, R_rx, R_tx, a_rx, a_tx, clock, sign, rho, _ = rows
    H_att_rx, H_att_tx = isl_attitude_jacobians(x_rx, x_tx, R_rx, R_tx, a_rx, a_tx)
    # 1e-3 rad: a 1e-6 rad step moves a 1 m lever arm by 1 um, at the rounding of 3,000 km
    check_jacobians(lambda R: isl_range_residual(x_rx, x_tx, R, R_tx, a_rx, a_tx, clock, sign,
                                                 rho),
                    (R_rx,), (H_att_rx,), ("rot3",), eps=(1e-3,), names=("R_rx",))
    check_jacobians(lambda R: isl_range_residual(x_rx, x_tx, R_rx, R, a_rx, a_tx, clock, sign,
                                                 rho),
                    (R_tx,), (H_att_tx,), ("rot3",), eps=(1e-3,), names=("R_tx",))


def _values(x_rx, x_tx, clock=None, amb=None):
    v = gtsam.Values()
    v.insert(1, np.asarray(x_rx, dtype=float))
    v.insert(2, np.asarray(x_tx, dtype=float))
    if clock is not None:
        v.insert(3, np.array([clock]))
    if amb is not None:
        v.insert(4, np.array([amb]))
    return v


@pytest.mark.parametrize("with_clock", [True, False])
def test_adapters_match_the_numpy_residual(rows, with_clock):
    x_rx, x_tx, R_rx, R_tx, a_rx, a_tx, clock, sign, rho, amb = rows
    sigma = 0.7
    clock = clock if with_clock else np.zeros_like(clock)
    e, H_rx, H_tx, H_c = isl_range_residual(x_rx, x_tx, R_rx, R_tx, a_rx, a_tx, clock, sign,
                                            rho)
    ec, _, _, _, H_a = isl_carrier_residual(x_rx, x_tx, R_rx, R_tx, a_rx, a_tx, clock, sign,
                                            rho, amb)
    key_c = 3 if with_clock else None
    for k in range(rho.size):
        values = _values(x_rx[k], x_tx[k], clock[k] if with_clock else None, amb[k])
        f = make_isl_range_factor(1, 2, key_c, R_rx[k], R_tx[k], a_rx[k], a_tx[k], sign[k],
                                  rho[k], sigma)
        assert list(f.keys()) == ([1, 2, 3] if with_clock else [1, 2])
        assert f.unwhitenedError(values)[0] == pytest.approx(e[k, 0], abs=1e-9)
        blocks = [H_rx[k:k + 1], H_tx[k:k + 1]] + ([H_c[k:k + 1]] if with_clock else [])
        A, b = whiten(e[k:k + 1], blocks, sigma)
        check_linearization(f, values, [a[0] for a in A], b[0])

        fc = make_isl_carrier_factor(1, 2, key_c, 4, R_rx[k], R_tx[k], a_rx[k], a_tx[k],
                                     sign[k], rho[k], sigma)
        assert list(fc.keys()) == ([1, 2, 3, 4] if with_clock else [1, 2, 4])
        assert fc.unwhitenedError(values)[0] == pytest.approx(ec[k, 0], abs=1e-9)
        A, b = whiten(ec[k:k + 1], blocks + [H_a[k:k + 1]], sigma)
        check_linearization(fc, values, [a[0] for a in A], b[0])


# ------------------------------------------------------------------ against exact light time

def _attitude_rtn(x):
    """Earth-pointing attitude: body axes = radial, along-track, normal (R_eci_from_body)."""
    return np.swapaxes(rtn_frame(x), -1, -2)


def _exact_light_time_ranges(x0_rx, x0_tx, t_s):
    """c tau of |p_rx(t) - p_tx(t - tau)| = c tau, by fixed-point iteration on the
    transmitter re-propagated (DOP853) to each emission time, its antenna on its
    Earth-pointing body at the emission time. Returns (exact c tau, first-order model,
    range ignoring the light time, centre separation), m."""
    x_rx = integrate_truth(x0_rx, t_s)
    x_tx = integrate_truth(x0_tx, t_s)
    R_rx, R_tx = _attitude_rtn(x_rx), _attitude_rtn(x_tx)
    p_rx = x_rx[:, :3] + R_rx @ LEVER_1_M
    tau = np.zeros(t_s.size)
    for _ in range(10):
        # the emission times in the same call as t_s: one DOP853 run, one dense output
        x_em = integrate_truth(x0_tx, np.concatenate([t_s, t_s - tau]))[t_s.size:]
        p_em = x_em[:, :3] + _attitude_rtn(x_em) @ LEVER_2_M
        new = np.linalg.norm(p_rx - p_em, axis=1) / C_LIGHT_M_S
        step_m = C_LIGHT_M_S * np.abs(new - tau).max()
        tau = new
        if step_m < 1e-10:
            break
    else:  # pragma: no cover
        raise AssertionError(f"light-time iteration did not converge ({step_m} m)")
    n = t_s.size
    model = isl_predict_range(x_rx, x_tx, R_rx, R_tx, np.tile(LEVER_1_M, (n, 1)),
                              np.tile(LEVER_2_M, (n, 1)))
    no_light_time = np.linalg.norm(p_rx - x_tx[:, :3] - R_tx @ LEVER_2_M, axis=1)
    sep = np.linalg.norm(x_rx[:, :3] - x_tx[:, :3], axis=1)
    return C_LIGHT_M_S * tau, model, no_light_time, sep


def test_first_order_light_time_in_leo_two_planes():
    """Two LEO spacecraft in planes 16 deg apart in RAAN (700 and 620 km), from 1,965 km
    apart at the equator to 542 km near the pole: the first-order model within 0.1 mm of
    the exact light time (measured 3.0e-5 m), ignoring the light time off by 18-32 m; and
    the difference is what the model neglects, the transmitter's acceleration and its
    antenna's rotation over tau, u . (omega x R_tx a_tx tau - a_tx tau^2/2) (to 1e-8 m)."""
    t = np.arange(60.0, 1381.0, 60.0)
    xa0 = elements_to_state(R_EARTH_M + 700e3, 0.001, 97.4 * DEG, 0.0, 0.0, 0.0)
    xb0 = elements_to_state(R_EARTH_M + 620e3, 0.001, 97.4 * DEG, 16 * DEG, 0.0, 5 * DEG)
    for x0_rx, x0_tx in ((xa0, xb0), (xb0, xa0)):
        exact, model, no_lt, sep = _exact_light_time_ranges(x0_rx, x0_tx, t)
        assert sep.min() < 600e3 and sep.max() > 1900e3
        assert np.abs(model - exact).max() < 1e-4
        assert np.abs(no_lt - exact).min() > 5.0
        # the neglected second-order terms, from the truth's own acceleration
        x_rx, x_tx = integrate_truth(x0_rx, t), integrate_truth(x0_tx, t)
        R_rx, R_tx = _attitude_rtn(x_rx), _attitude_rtn(x_tx)
        acc = np.array([truth_acceleration(x[:3], x[3:]) for x in x_tx])
        d0 = x_rx[:, :3] + R_rx @ LEVER_1_M - x_tx[:, :3] - R_tx @ LEVER_2_M
        tau, D, _ = light_time(d0, x_tx[:, 3:])
        u = D / np.linalg.norm(D, axis=1, keepdims=True)
        # the Earth-pointing body turns with the orbit: omega = (r x v)/|r|^2
        omega = np.cross(x_tx[:, :3], x_tx[:, 3:]) / np.sum(x_tx[:, :3] ** 2, axis=1)[:, None]
        lever_velocity = np.cross(omega, R_tx @ LEVER_2_M)
        second_order = np.sum(u * (lever_velocity * tau[:, None]
                                   - 0.5 * acc * tau[:, None] ** 2), axis=1)
        assert np.abs(second_order).max() > 1e-5
        assert np.abs(exact - model - second_order).max() < 1e-8


def test_first_order_light_time_in_gto_formation():
    """Two spacecraft ~1 km apart near perigee of the Pan & Yao 2017 transfer orbit
    (9.5 km/s): model within 1e-8 m of the exact light time; ignoring it errs by ~2 cm."""
    x_chief = np.array([6509244.371304875, 0.0, 3713244.835519765,
                        -3737.397235776740, 0.0, 8790.602460568101])
    x_dep = deputy_from_relative_lvlh(x_chief[None],
                                      np.array([[300.0, -900.0, 300.0, 0.0, 0.0, 0.0]]))[0]
    t = np.arange(60.0, 601.0, 60.0)
    for x0_rx, x0_tx in ((x_chief, x_dep), (x_dep, x_chief)):
        exact, model, no_lt, sep = _exact_light_time_ranges(x0_rx, x0_tx, t)
        assert sep.min() > 900.0 and sep.max() < 1300.0
        assert np.abs(model - exact).max() < 1e-4
        assert np.abs(model - exact).max() < 1e-8
        assert np.abs(no_lt - exact).max() > 1e-2


# ------------------------------------------------------------------ Xing et al.'s relative model

def test_reduces_to_the_relative_model_of_xing_et_al():
    """With the transmitters at rest (no light-time motion) the absolute model of the six
    links of Xing et al. (sat 1 receives on antennas 1-3 from sat 2, clock +1; sat 2 from
    sat 1, clock -1) equals factors.pseudorange.predict_ranges of the relative position in
    sat 1's body frame, and its position Jacobians are that model's line-of-sight rows
    mapped to ECI."""
    rng = np.random.default_rng(3)
    N = 4
    R1 = random_rotations(rng, N)
    M21 = np.array([m21_from_rpy(*(0.4 * rng.normal(size=3))) for _ in range(N)])
    R2 = R1 @ M21                                # sat-2 body -> sat-1 body -> ECI
    r1 = random_positions_m(rng, N)
    r2 = r1 + 800.0 * rng.normal(size=(N, 3))
    x1 = np.hstack([r1, np.zeros((N, 3))])
    x2 = np.hstack([r2, np.zeros((N, 3))])
    cdt = rng.normal(size=N)
    r_body, _, J_dep, _ = relative_position_body(x1, x2, R1)
    rho_rel = predict_ranges(r_body, cdt, M21)

    for link in range(6):
        j = link % 3
        if link < 3:   # sat 2 transmits, sat 1 antenna j receives
            args = (x1, x2, R1, R2, np.tile(ANTENNA_RX_BODY_M[j], (N, 1)),
                    np.tile(ANTENNA_TX_BODY_M, (N, 1)))
        else:          # sat 1 transmits, sat 2 antenna j receives
            args = (x2, x1, R2, R1, np.tile(ANTENNA_RX_BODY_M[j], (N, 1)),
                    np.tile(ANTENNA_TX_BODY_M, (N, 1)))
        sign = np.full(N, CLOCK_SIGNS[link])
        e, H_rx, H_tx, _ = isl_range_residual(*args, cdt, sign, np.zeros(N))
        assert np.allclose(e[:, 0], rho_rel[:, link], rtol=0, atol=1e-8)
        # d rho/d r2 (ECI) = Xing's d rho/d r (sat-1 body) times d r/d r2 = R1^T
        _, H_r, _ = pseudorange_residual(r_body, cdt, np.zeros((N, 6)), M21)
        H_sat2 = H_tx if link < 3 else H_rx
        assert np.allclose(H_sat2[:, 0, :3],
                           np.einsum("ni,nij->nj", H_r[:, link], J_dep[:, :, :3]), atol=1e-12)
