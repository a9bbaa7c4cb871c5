"""The simulated atmosphere-model bias of the refraction sensor (Li et al. 2017's
atmosphere-model error as a drifting bias): its process, that the residual of
``factors.refraction`` sees it with the estimator's sign, and its truth file."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from factors.aberration import apparent_direction, earth_velocity_bcrs_mps
from factors.constants import ARCSEC
from factors.refraction import refraction_residual, refraction_sigma_m
from fgnav.cli import main
from fgnav.errors import InputFormatError
from fgnav.io.truth_params import (TRUTH_REFRACTION_BIAS_CSV, read_truth_params_csv,
                                   write_truth_params_csv)
from fgnav.scenarios import SensorSpec, load_scenario
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.simulate.refraction_sim import has_model_bias, refraction_bias_path_m
from fgnav.time import add_seconds, j2000_seconds, parse_utc


def _spec(b0=0.0, drift=0.0, q=0.0):
    return SensorSpec(kind="refraction", model_bias_m=b0, model_bias_drift_m_per_h=drift,
                      model_bias_random_walk_m_per_sqrt_h=q)


def test_bias_path_constant_plus_drift_is_exact_and_draws_nothing():
    t = np.arange(0.0, 3 * 3600.0 + 1, 10.0)
    rng = np.random.default_rng(5)
    state = rng.bit_generator.state
    b = refraction_bias_path_m(_spec(300.0, -50.0), t, rng)
    np.testing.assert_allclose(b, 300.0 - 50.0 * t / 3600.0, rtol=0, atol=1e-12)
    assert b[-1] == pytest.approx(150.0)
    assert rng.bit_generator.state == state  # no random walk: no draws
    assert not has_model_bias(_spec()) and has_model_bias(_spec(drift=1.0))
    assert has_model_bias(_spec(q=1.0)) and has_model_bias(_spec(b0=-1.0))


def test_bias_random_walk_has_the_documented_increments():
    """w(t_0) = 0 and the increments over unequal steps, divided by q sqrt(dt_h), are N(0, 1)
    (mean within 5/sqrt(n), variance within 4 %); the same generator state gives the same
    path."""
    rng = np.random.default_rng(11)
    t = np.cumsum(np.r_[0.0, rng.uniform(1.0, 60.0, size=40000)])
    q = 30.0
    b = refraction_bias_path_m(_spec(300.0, 20.0, q), t, np.random.default_rng(3))
    assert b[0] == 300.0
    w = b - 300.0 - 20.0 * t / 3600.0
    z = np.diff(w) / (q * np.sqrt(np.diff(t) / 3600.0))
    assert abs(z.mean()) < 5 / math.sqrt(z.size)
    assert z.var() == pytest.approx(1.0, rel=0.04)
    np.testing.assert_array_equal(
        b, refraction_bias_path_m(_spec(300.0, 20.0, q), t, np.random.default_rng(3)))


@pytest.fixture(scope="module")
def bias_pass():
    return simulate_pass(load_scenario("refraction-leo-bias"), seed=3)


def test_builtin_bias_scenario(bias_pass):
    scn = load_scenario("refraction-leo-bias")
    base = load_scenario("refraction-leo")
    s = scn.sensors[0]
    assert (s.model_bias_m, s.model_bias_drift_m_per_h,
            s.model_bias_random_walk_m_per_sqrt_h) == (300.0, -50.0, 30.0)
    # everything but the bias is refraction-leo
    assert dataclasses.replace(s, model_bias_m=0.0, model_bias_drift_m_per_h=0.0,
                               model_bias_random_walk_m_per_sqrt_h=0.0) == base.sensors[0]
    assert (scn.x0_eci, scn.duration_h, scn.step_s) == (base.x0_eci, base.duration_h, base.step_s)
    b = bias_pass.truth_params["refraction_bias_m"]
    assert b.shape == bias_pass.t_s.shape and b[0] == 300.0
    assert 50.0 < 300.0 - b[-1] < 250.0  # drift -150 m over 3 h, random walk 52 m 1σ
    assert simulate_pass(base.with_options(duration_h=0.1), seed=3).truth_params == {}


def test_the_residual_sees_the_simulated_bias(bias_pass):
    """At the true states the refraction residual with b = the simulator's bias has zero mean
    (within 4 sigma/sqrt(n)) and the spread refraction_sigma_m predicts; with b = 0 its mean
    is minus the bias, and it follows the bias over the pass (slope of -e on b ~ 1)."""
    sim = bias_pass
    log = sim.log
    assert log.epoch0 == sim.epoch0
    rows = np.flatnonzero(np.asarray(log.kind) == "refraction")
    k = np.searchsorted(sim.t_s, log.t_s[rows])
    np.testing.assert_array_equal(sim.t_s[k], log.t_s[rows])
    r = sim.x_true[k, :3]
    # the ray's direction: the catalogue one aberrated by the Earth's velocity
    s, _ = apparent_direction(log.xyz[rows], earth_velocity_bcrs_mps(
        float(j2000_seconds(log.epoch0)) + log.t_s[rows]))
    g = log.extra["gamma"][rows]
    b = sim.truth_params["refraction_bias_m"][k]
    n = rows.size
    assert n > 3000
    e0, _ = refraction_residual(r, s, g)
    e, _, H_b = refraction_residual(r, s, g, bias_m=b)
    np.testing.assert_array_equal(H_b, 1.0)
    spec = sim.scenario.sensors[0]
    sig = refraction_sigma_m(g, spec.gamma_halfwidth_arcsec * ARCSEC / math.sqrt(3),
                             spec.sigma_model_m, los_range_m=np.abs(np.sum(r * s, axis=1)))
    sigma = float(np.sqrt(np.mean(sig ** 2)))
    assert abs(e.mean()) < 4 * sigma / math.sqrt(n), (e.mean(), sigma)
    assert np.std(e) == pytest.approx(sigma, rel=0.05)
    assert e0.mean() == pytest.approx(-b.mean(), abs=4 * sigma / math.sqrt(n))
    slope = np.polyfit(b, -e0[:, 0], 1)[0]
    assert slope == pytest.approx(1.0, abs=0.15)


def test_simulate_writes_the_truth_bias_beside_truth_oem(tmp_path, capsys):
    out = tmp_path / "p"
    assert main(["simulate", "refraction-leo-bias", "--seed", "3", "--duration-h", "0.2",
                 "--out", str(out)]) == 0
    assert TRUTH_REFRACTION_BIAS_CSV in capsys.readouterr().out
    lines = (out / TRUTH_REFRACTION_BIAS_CSV).read_text().splitlines()
    assert "epoch,refraction_bias_m" in lines
    epochs, params = read_truth_params_csv(out / TRUTH_REFRACTION_BIAS_CSV)
    sim = simulate_pass(load_scenario("refraction-leo-bias").with_options(duration_h=0.2), seed=3)
    np.testing.assert_array_equal(epochs, add_seconds(sim.epoch0, sim.t_s))
    np.testing.assert_array_equal(params["refraction_bias_m"],
                                  sim.truth_params["refraction_bias_m"])
    # no bias, no file
    assert main(["simulate", "refraction-leo", "--duration-h", "0.05", "--quiet",
                 "--out", str(tmp_path / "q")]) == 0
    assert not (tmp_path / "q" / TRUTH_REFRACTION_BIAS_CSV).exists()


def test_truth_params_csv_round_trip_and_errors(tmp_path):
    path = tmp_path / "t.csv"
    t = np.array([0.0, 10.0, 20.5])
    b = np.array([300.0, 1 / 3, -2e-7])
    epoch0 = parse_utc("2025-03-06T00:00:00Z")
    write_truth_params_csv(path, epoch0, t, {"refraction_bias_m": b}, comments=("x",))
    epochs, params = read_truth_params_csv(path)
    np.testing.assert_array_equal(params["refraction_bias_m"], b)
    np.testing.assert_array_equal(epochs, add_seconds(epoch0, t))
    good = path.read_text()
    bad = {
        "header": (good.replace("epoch,refraction_bias_m", "time,refraction_bias_m"), 3, None),
        "number": (good.replace(",300.0", ",3OO"), 4, "refraction_bias_m"),
        "nan": (good.replace(",300.0", ",nan"), 4, "refraction_bias_m"),
        "epoch": (good.replace("00:00:10.000000Z", "00:00:10"), 5, "epoch"),
        "order": (good.replace("00:00:10.000000Z", "00:00:30.000000Z"), 6, "epoch"),
        "fields": (good.replace(",300.0", ",300.0,1"), 4, None),
        "empty": ("# only a comment\n", None, None),
    }
    for name, (text, line, column) in bad.items():
        path.write_text(text)
        with pytest.raises(InputFormatError) as exc:
            read_truth_params_csv(path)
        assert (exc.value.line, exc.value.column) == (line, column), (name, str(exc.value))


def test_bias_recovered_through_the_gtsam_factor_at_known_states():
    """With the states held at the truth (1 mm priors), the refraction-bias factors plus a
    random walk on b (the simulator's own q) recover the simulator's b(t) over the whole pass:
    errors consistent with the dense covariance (mean squared normalized error 0.3-2.5, every
    |error| < 5 sigma), against ~300 m if the bias were ignored. GTSAM (QR elimination) and a
    dense numpy solve of the same normal equations agree."""
    import gtsam

    from factors.refraction import make_refraction_bias_factor

    sim = simulate_pass(load_scenario("refraction-leo-bias"), seed=4)
    spec = sim.scenario.sensors[0]
    log = sim.log
    rows = np.flatnonzero(np.asarray(log.kind) == "refraction")
    k_row = np.searchsorted(sim.t_s, log.t_s[rows])
    epochs = np.unique(k_row)                     # epochs with refraction rows
    j_row = np.searchsorted(epochs, k_row)        # bias index of each row
    n_b = epochs.size
    s, _ = apparent_direction(log.xyz[rows], earth_velocity_bcrs_mps(   # the rays (aberration)
        float(j2000_seconds(log.epoch0)) + log.t_s[rows]))
    g = log.extra["gamma"][rows]
    r = sim.x_true[k_row, :3]
    sig = refraction_sigma_m(g, spec.gamma_halfwidth_arcsec * ARCSEC / math.sqrt(3),
                             spec.sigma_model_m, los_range_m=np.abs(np.sum(r * s, axis=1)))
    dt_h = np.diff(sim.t_s[epochs]) / 3600.0
    q_sig = spec.model_bias_random_walk_m_per_sqrt_h * np.sqrt(dt_h)

    Xk, Bk = (lambda j: gtsam.symbol("x", j)), (lambda j: gtsam.symbol("b", j))
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for j, k in enumerate(epochs):
        values.insert(Xk(j), sim.x_true[k])
        values.insert(Bk(j), np.zeros(1))
        graph.add(gtsam.PriorFactorVector(Xk(j), sim.x_true[k],
                                          gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
    for i in range(rows.size):
        graph.add(make_refraction_bias_factor(Xk(j_row[i]), Bk(j_row[i]), s[i], g[i], sig[i]))
    for j in range(n_b - 1):
        graph.add(gtsam.BetweenFactorVector(Bk(j), Bk(j + 1), np.zeros(1),
                                            gtsam.noiseModel.Isotropic.Sigma(1, q_sig[j])))
    lin = graph.linearize(values)
    delta = lin.eliminateMultifrontal(gtsam.Ordering.ColamdGaussianFactorGraph(lin),
                                      gtsam.EliminateQR).optimize()
    b_gtsam = np.array([delta.at(Bk(j))[0] for j in range(n_b)])

    # the same problem, dense: b only (the states are known)
    e0, _ = refraction_residual(r, s, g)
    info = np.zeros((n_b, n_b))
    rhs = np.zeros(n_b)
    np.add.at(info, (j_row, j_row), 1.0 / sig ** 2)
    np.add.at(rhs, j_row, -e0[:, 0] / sig ** 2)
    w = 1.0 / q_sig ** 2
    idx = np.arange(n_b - 1)
    info[idx, idx] += w
    info[idx + 1, idx + 1] += w
    info[idx, idx + 1] -= w
    info[idx + 1, idx] -= w
    P = np.linalg.inv(info)
    b_dense = P @ rhs
    np.testing.assert_allclose(b_gtsam, b_dense, rtol=0, atol=1e-3)  # m

    b_true = sim.truth_params["refraction_bias_m"][epochs]
    z = (b_gtsam - b_true) / np.sqrt(np.diag(P))
    assert 0.3 < np.mean(z ** 2) < 2.5, np.mean(z ** 2)
    assert np.max(np.abs(z)) < 5.0
    rms_err_m = float(np.sqrt(np.mean((b_gtsam - b_true) ** 2)))
    assert rms_err_m < 30.0 and np.sqrt(np.mean(b_true ** 2)) > 5 * rms_err_m
