"""Estimating the atmosphere model's tangent-height bias as a random-walk graph variable.

The simulated atmosphere of ``refraction-leo-bias`` has a 300 m bias drifting over the pass
(truth from the simulator's own atmosphere, ``fgnav.simulate.refraction_sim``). Solved as
before, the bias leaks into the orbit and the integrity verdict says so; with
``--estimate refraction-bias`` the orbit is back near its noise level and the bias comes out
within its own sigma. The block marginals (orbit + bias) are checked against a dense
inverse written here from the ``factors/`` residuals alone.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import scipy.linalg

from factors.dynamics import process_noise, propagate
from factors.refraction import refraction_residual
from fgnav.cli import main
from fgnav.measurements import build_pass, with_estimates
from fgnav.models.registry import REFRACTION_BIAS, model, refraction_ray_eci
from fgnav.pipeline import accuracy_metrics, solve, summarize
from fgnav.scenarios import load_scenario
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.solvers.options import SmootherOptions
from fgnav.time import j2000_seconds

ESTIMATE = replace(SmootherOptions(), estimate=("refraction-bias",))


@pytest.fixture(scope="module")
def bias_pass():
    """1 h of refraction-leo-bias at 10 s (361 epochs, ~1,900 refracted stars)."""
    sim = simulate_pass(load_scenario("refraction-leo-bias").with_options(duration_h=1.0), seed=3)
    return sim, build_pass(sim.log)


@pytest.fixture(scope="module")
def solutions(bias_pass):
    sim, p = bias_pass
    return {(m, est): solve(p, m, ESTIMATE if est else SmootherOptions())
            for m, est in (("batch", False), ("batch", True), ("isam2", True), ("ekf", True))}


def _truth(sim, sol):
    idx = np.searchsorted(sim.t_s, sol.t_s)
    return sim.x_true[idx], sim.truth_params["refraction_bias_m"][idx]


def test_estimating_the_bias_restores_the_orbit_and_recovers_the_bias(bias_pass, solutions):
    sim, p = bias_pass
    plain, est = solutions[("batch", False)], solutions[("batch", True)]
    x_true, b_true = _truth(sim, est)
    rms_plain = accuracy_metrics(plain, x_true)["position_rms_m"]
    acc = accuracy_metrics(est, x_true)
    assert rms_plain > 100.0                       # the bias leaks into the orbit ...
    assert acc["position_rms_m"] < rms_plain / 5   # ... and estimating it takes it out
    assert acc["nees_mean"] < 12.0                 # 6 dof: credible covariances
    b, P = est.variables[REFRACTION_BIAS.name]
    err = b[:, 0] - b_true
    sig = np.sqrt(P[:, 0, 0])
    assert np.sqrt(np.mean(err ** 2)) < 0.1 * np.sqrt(np.mean(b_true ** 2))
    assert np.mean((err / sig) ** 2) < 3.0 and np.max(np.abs(err / sig)) < 5.0
    # the verdict tells the two apart
    assert summarize(plain, p, SmootherOptions())["integrity"]["status"] != "ok"
    assert summarize(est, with_estimates(p, ESTIMATE.estimate), ESTIMATE)["integrity"]["status"] == "ok"


def test_isam2_and_ekf_estimate_the_same_variable(bias_pass, solutions):
    sim, p = bias_pass
    batch, isam2, ekf = (solutions[(m, True)] for m in ("batch", "isam2", "ekf"))
    b_batch, P_batch = batch.variables["refraction_bias"]
    b_isam, P_isam = isam2.variables["refraction_bias"]
    sig = np.sqrt(P_batch[:, 0, 0])
    assert np.max(np.abs(b_isam - b_batch)[:, 0] / sig) < 1e-3
    np.testing.assert_allclose(P_isam, P_batch, rtol=1e-3)
    # the filter: at the end of the pass its bias is within 4 sigma of the truth
    _, b_true = _truth(sim, ekf)
    b_ekf, P_ekf = ekf.variables["refraction_bias"]
    assert abs(b_ekf[-1, 0] - b_true[-1]) < 4 * np.sqrt(P_ekf[-1, 0, 0])
    assert P_ekf[-1, 0, 0] < REFRACTION_BIAS.prior_sigma ** 2 / 100


def test_block_marginals_equal_a_dense_inverse():
    """Orbit + bias marginals of batch against (J^T J)^-1 of the whole problem written
    densely: refraction rows with the bias column, motion rows, random-walk rows, priors."""
    sim = simulate_pass(load_scenario("refraction-leo-bias").with_options(duration_h=0.25,
                                                                         step_s=30.0), seed=5)
    p = with_estimates(build_pass(sim.log), ("refraction-bias",))
    sol = solve(p, "batch", ESTIMATE)
    X = np.column_stack([sol.x_eci, sol.variables["refraction_bias"][0]])
    N, n = p.n_epochs, 7
    opt = SmootherOptions()
    mdl = opt.motion_model()
    t0 = float(j2000_seconds(p.epoch0))
    rows = []
    fam = p.families["refraction"]
    e, H_r, H_b = refraction_residual(X[fam.k, :3], refraction_ray_eci(fam), fam.values["gamma_rad"],
                                      bias_m=X[fam.k, 6])
    sig = model("refraction").noise_sigma(fam, X[fam.k, :6])
    for j in range(len(fam)):
        row = np.zeros(N * n)
        row[fam.k[j] * n:fam.k[j] * n + 3] = H_r[j, 0] / sig[j]
        row[fam.k[j] * n + 6] = H_b[j, 0, 0] / sig[j]
        rows.append(row)
    for kind, sl in (("prior_position", slice(0, 3)), ("prior_velocity", slice(3, 6))):
        f = p.families[kind]
        for i in range(3):
            row = np.zeros(N * n)
            row[f.k[0] * n + sl.start + i] = 1.0 / f.sigma[0]
            rows.append(row)
    row = np.zeros(N * n)
    row[6] = 1.0 / REFRACTION_BIAS.prior_sigma
    rows.append(row)
    for k in range(N - 1):
        dt = p.t_s[k + 1] - p.t_s[k]
        _, Phi = propagate(X[k, :6], dt, mdl, t0 + p.t_s[k])
        W = np.linalg.inv(np.linalg.cholesky(process_noise(dt, opt.q_m2_s3)))
        blk = np.zeros((6, N * n))
        blk[:, k * n:k * n + 6] = -W @ Phi
        blk[:, (k + 1) * n:(k + 1) * n + 6] = W
        rows.extend(blk)
        row = np.zeros(N * n)
        w = 1.0 / np.sqrt(REFRACTION_BIAS.psd * dt)
        row[k * n + 6], row[(k + 1) * n + 6] = -w, w
        rows.append(row)
    J = np.array(rows)
    R = scipy.linalg.qr(J, mode="r")[0][:N * n]
    Rinv = scipy.linalg.solve_triangular(R, np.eye(N * n))
    C = Rinv @ Rinv.T
    for k in (0, N // 2, N - 1):
        blk = C[k * n:(k + 1) * n, k * n:(k + 1) * n]
        s = np.sqrt(np.diag(blk))
        np.testing.assert_allclose(sol.P_eci[k] / np.outer(s[:6], s[:6]),
                                   blk[:6, :6] / np.outer(s[:6], s[:6]), atol=1e-6)
        np.testing.assert_allclose(sol.variables["refraction_bias"][1][k, 0, 0], blk[6, 6],
                                   rtol=1e-6)


def test_cli_writes_the_variable_and_refuses_what_it_cannot_estimate(tmp_path, capsys):
    assert main(["simulate", "refraction-leo-bias", "--duration-h", "0.5", "--seed", "2",
                 "--out", str(tmp_path / "pass")]) == 0
    log = str(tmp_path / "pass" / "measurements.csv")
    assert main(["smooth", log, "--out", str(tmp_path / "r"), "--estimate", "refraction-bias",
                 "--truth", str(tmp_path / "pass" / "truth.oem"), "--quiet"]) == 0
    header = (tmp_path / "r" / "variables.csv").read_text().splitlines()[0]
    assert header == "epoch,t_s,refraction_bias_m,refraction_bias_m_sigma"
    v = json.loads((tmp_path / "r" / "summary.json").read_text())["variables"]["refraction_bias"]
    assert v["error_rms"][0] < 3 * v["sigma_rms"][0]   # truth_refraction_bias.csv was read
    capsys.readouterr()
    assert main(["smooth", log, "--out", str(tmp_path / "r2"), "--estimate", "clock-bias"]) == 2
    assert "unknown variable 'clock-bias'" in capsys.readouterr().err
    assert main(["simulate", "gto-transfer", "--duration-h", "0.2", "--out",
                 str(tmp_path / "gto")]) == 0
    capsys.readouterr()
    assert main(["smooth", str(tmp_path / "gto" / "measurements.csv"), "--out",
                 str(tmp_path / "r3"), "--estimate", "refraction-bias"]) == 2
    err = capsys.readouterr().err
    assert "--estimate refraction-bias" in err and "no rows that depend on it" in err
