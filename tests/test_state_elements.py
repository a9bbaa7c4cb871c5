"""``--state elements`` (fgnav/solvers/state_elements.py): the chart's algebra, the batch
smoother's invariance under the change of coordinates, the EKF's agreement to first order,
and the CLI path."""

import json

import numpy as np
import pytest

from factors.dynamics import process_noise, propagate
from fgnav.api import simulate
from fgnav.cli import main
from fgnav.errors import UserError
from fgnav.io.oem import read_oem
from fgnav.measurements import build_pass
from fgnav.models.variables import Layout
from fgnav.pipeline import accuracy_metrics, prepare_pass, solve
from fgnav.simulate.pass_sim import write_pass_files
from fgnav.solvers.ekf import run_ekf
from fgnav.solvers.options import SmootherOptions
from fgnav.solvers.state_elements import ElementChart

X_GTO = np.array([6509244.371304875, 0.0, 3713244.835519765,
                  -3737.397235776740, 0.0, 8790.602460568101])


def test_retract_is_the_cartesian_step_to_first_order():
    """c(e(x) + J^-1 dx) = x + dx + O(|dx|^2): halving the step quarters the difference."""
    chart = ElementChart()
    J = chart.jacobian(X_GTO)
    dx = np.array([3000.0, -2000.0, 1000.0, 0.5, -0.3, 0.2])
    gaps = []
    for s in (1.0, 0.5, 0.25):
        x1 = chart.retract(Layout(), X_GTO[None], np.linalg.solve(J, s * dx)[None])[0]
        gaps.append(np.linalg.norm((x1 - X_GTO - s * dx)[:3]))
    assert gaps[0] > 1e-3                       # the chart is curved ...
    assert gaps[1] / gaps[0] == pytest.approx(0.25, rel=0.05)   # ... at second order
    assert gaps[2] / gaps[1] == pytest.approx(0.25, rel=0.05)


def test_covariance_and_transition_maps():
    chart = ElementChart()
    rng = np.random.default_rng(3)
    M = rng.standard_normal((8, 8))
    P = M @ M.T                                   # a block: orbit + a 2-d further variable
    X = np.concatenate([X_GTO, [0.1, 0.2]])
    PE = chart.covariance_from_cartesian(X, P)
    np.testing.assert_allclose(chart.covariance_to_cartesian(X, PE), P, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(PE[6:, 6:], P[6:, 6:])   # further variables untouched
    x1, Phi = propagate(X_GTO, 600.0)
    Q = process_noise(600.0, 1e-10)
    PhiE, QE = chart.transition(X_GTO, x1, Phi, Q)
    J0, J1 = chart.jacobian(X_GTO), chart.jacobian(x1)
    np.testing.assert_allclose(J1 @ PhiE, Phi @ J0, rtol=1e-9, atol=1e-9 * np.abs(Phi @ J0).max())
    np.testing.assert_allclose(J1 @ QE @ J1.T, Q, rtol=1e-8, atol=1e-8 * np.abs(Q).max())


def test_unknown_state_and_isam2_are_user_errors():
    with pytest.raises(UserError, match="--state"):
        SmootherOptions(state="keplerian")
    with pytest.raises(UserError, match="isam2"):
        solve(None, "isam2", SmootherOptions(state="elements"))


@pytest.fixture(scope="module")
def gto_pass():
    sim = simulate("gto-transfer", seed=4, step_s=120.0, duration_h=2.0)
    return sim, build_pass(sim.log)


def test_batch_is_invariant_under_the_change_of_coordinates(gto_pass):
    """The smoother's cost is the same function of the trajectory in either chart: the same
    minimum, the same covariance (mapped back), only the path of the iterations differs."""
    sim, p = gto_pass
    cart = solve(p, "batch", SmootherOptions())
    elem = solve(p, "batch", SmootherOptions(state="elements"))
    assert elem.extras["converged"] and cart.extras["converged"]
    np.testing.assert_allclose(elem.x_eci[:, :3], cart.x_eci[:, :3], atol=0.05)   # m
    np.testing.assert_allclose(elem.P_eci, cart.P_eci, rtol=1e-4,
                               atol=1e-6 * np.abs(cart.P_eci).max())
    err = np.linalg.norm(cart.x_eci[:, :3] - sim.x_true[np.searchsorted(sim.t_s, cart.t_s), :3],
                         axis=1)
    assert np.sqrt(np.mean(err ** 2)) < 10e3     # and it is a solution, not two equal failures


def test_ekf_in_elements_agrees_to_first_order(gto_pass):
    """The filters differ only by where the update lands (a straight step in the elements
    is curved in Cartesian space): close on this pass, but not the same numbers."""
    sim, p = gto_pass
    q = prepare_pass(p, SmootherOptions())
    cart = run_ekf(q, SmootherOptions())
    elem = run_ekf(q, SmootherOptions(state="elements"))
    x_true = sim.x_true[np.searchsorted(sim.t_s, cart.t_s)]
    a, b = accuracy_metrics(cart, x_true), accuracy_metrics(elem, x_true)
    assert b["position_rms_m"] == pytest.approx(a["position_rms_m"], rel=0.05)
    assert b["nees_mean"] == pytest.approx(a["nees_mean"], rel=0.1)
    assert np.max(np.abs(elem.x_eci - cart.x_eci)[:, :3]) > 1e-3   # a different filter


def test_cli_smooth_state_elements(tmp_path, gto_pass):
    sim, _ = gto_pass
    (tmp_path / "pass").mkdir()
    write_pass_files(tmp_path / "pass", sim)
    log, truth = tmp_path / "pass" / "measurements.csv", tmp_path / "pass" / "truth.oem"
    for method in ("ekf", "batch"):
        out = tmp_path / method
        rc = main(["smooth", str(log), "--method", method, "--state", "elements", "--out",
                   str(out), "--truth", str(truth), "--quiet"])
        assert rc == 0
        s = json.loads((out / "summary.json").read_text())
        assert s["state"] == "elements" and s["method"] == method
        assert s["position_rms_m"] < 20e3 and 0.5 < s["nees_mean"] < 30
        oem = read_oem(out / "trajectory.oem")
        assert oem.P_eci is not None and len(oem.P_eci) == s["epochs"]   # Cartesian covariances
    rc = main(["smooth", str(log), "--method", "isam2", "--state", "elements", "--out",
               str(tmp_path / "i"), "--quiet"])
    assert rc == 2
