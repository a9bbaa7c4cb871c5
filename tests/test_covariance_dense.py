"""The smoothers' covariances against an independent dense computation.

Batch (:mod:`fgnav.solvers.batch` + :mod:`fgnav.solvers.chain`) and iSAM2
(:mod:`fgnav.solvers.incremental`) give marginal covariances by their own routes (GTSAM QR
elimination and an O(N) back-recursion; GTSAM's ``marginalCovariance`` for the online ones),
and iSAM2's final covariances come from batch code. Here the whole least-squares problem of
a short pass is written out densely with numpy from the measurement models of ``factors/``
and the motion model alone: every whitened measurement row and every whitened motion row
``Q_k^{-1/2} [-Phi_k, I]`` in one Jacobian ``J`` over all states, information ``J^T J``, and
the covariance ``(J^T J)^{-1}`` (through the QR factor of ``J``: forming ``J^T J`` would
square a condition number of ~1e9). Smoothed marginals are its diagonal blocks; the
filtered covariance at epoch k is the last block of the same computation over the data up
to epoch k (the information form of the filter: Bierman 1977).
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from factors.altimeter import altitude_residual
from factors.direction import earth_direction_residual
from factors.dynamics import process_noise, propagate
from factors.limb import limb_radius_residual
from fgnav.measurements import build_pass
from fgnav.pipeline import solve
from fgnav.scenarios import SensorSpec, load_scenario
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.solvers.options import SmootherOptions
from fgnav.time import j2000_seconds


@pytest.fixture(scope="module")
def short_pass():
    """40 min of a GTO pass at 60 s with directions, limb radii and altitudes (41 epochs)."""
    scn = load_scenario("gto-transfer").with_options(
        step_s=60.0, duration_h=40 / 60,
        sensors=(SensorSpec("earth_direction", sigma_deg=0.01),
                 SensorSpec("limb_radius", sigma_deg=0.02, period_s=120.0),
                 SensorSpec("altitude", sigma_m=300.0, period_s=180.0)))
    p = build_pass(simulate_pass(scn, seed=4).log)
    assert set(p.families) == {"prior_position", "prior_velocity", "earth_direction",
                               "limb_radius", "altitude"}
    return p


def _measurement_rows(p, X, skip=()):
    """[(k, whitened Jacobian rows (m, 6) on the state of epoch k)] of every measurement
    (except the families in ``skip``)."""
    out = []
    for kind, fam in p.families.items():
        if kind in skip:
            continue
        r = X[fam.k, :3]
        if kind in ("prior_position", "prior_velocity"):
            sl = slice(0, 3) if kind == "prior_position" else slice(3, 6)
            H = np.zeros((len(fam), 3, 6))
            H[:, :, sl] = np.eye(3)
        else:
            if kind == "earth_direction":
                _, H_r = earth_direction_residual(r, fam.values["u_eci"])
            elif kind == "limb_radius":
                _, H_r = limb_radius_residual(r, fam.values["rho_rad"], fam.values["r_limb_m"])
            elif kind == "altitude":
                _, H_r = altitude_residual(r, fam.values["h_m"], fam.values["r_ref_m"])
            else:
                raise AssertionError(f"no dense model for {kind}")
            H = np.concatenate([H_r, np.zeros(H_r.shape[:-1] + (3,))], axis=-1)
        out += [(int(k), H[i] / fam.sigma[i]) for i, k in enumerate(fam.k)]
    return out


def _dense_jacobian(p, X, q_m2_s3, n_states, skip=()):
    """Whitened Jacobian of every factor that involves only states 0 .. n_states-1."""
    model = SmootherOptions(q_m2_s3=q_m2_s3).motion_model()
    t0 = float(j2000_seconds(p.epoch0))
    blocks = []
    for k, Hw in _measurement_rows(p, X, skip):
        if k < n_states:
            row = np.zeros((len(Hw), 6 * n_states))
            row[:, 6 * k:6 * k + 6] = Hw
            blocks.append(row)
    for k in range(n_states - 1):
        dt = p.t_s[k + 1] - p.t_s[k]
        _, Phi = propagate(X[k], dt, model, t0 + p.t_s[k])
        W = np.linalg.cholesky(np.linalg.inv(process_noise(dt, q_m2_s3))).T   # W^T W = Q^-1
        row = np.zeros((6, 6 * n_states))
        row[:, 6 * k:6 * k + 6] = -W @ Phi
        row[:, 6 * k + 6:6 * k + 12] = W
        blocks.append(row)
    return np.vstack(blocks)


def _dense_covariance(J):
    R = np.linalg.qr(J, mode="r")
    Rinv = scipy.linalg.solve_triangular(R, np.eye(len(R)))
    return Rinv @ Rinv.T


def _blocks(P, n):
    return np.stack([P[6 * k:6 * k + 6, 6 * k:6 * k + 6] for k in range(n)])


def _rel_err(P, P_ref):
    """Largest error of P relative to the reference's standard deviations:
    |P_ij - Pref_ij| / sqrt(Pref_ii Pref_jj), over all entries and epochs."""
    s = np.sqrt(np.einsum("...ii->...i", P_ref))
    return float(np.max(np.abs(P - P_ref) / (s[..., :, None] * s[..., None, :])))


@pytest.mark.parametrize("method", ["batch", "isam2"])
def test_smoothed_marginals_equal_the_dense_inverse(short_pass, method):
    p = short_pass
    q = SmootherOptions().q_m2_s3
    sol = solve(p, method)
    assert sol.x_eci.shape == (p.n_epochs, 6)
    J = _dense_jacobian(p, sol.x_eci, q, p.n_epochs)
    assert J.shape[1] == 6 * p.n_epochs and J.shape[0] > J.shape[1]
    P_dense = _blocks(_dense_covariance(J), p.n_epochs)
    # measured: 1.6e-9 for both (in units of sigma_i sigma_j); without the altitudes: 83
    err = _rel_err(sol.P_eci, P_dense)
    assert err < 1e-6
    # the comparison can fail: the same problem without the altitude rows is far off
    P_less = _blocks(_dense_covariance(_dense_jacobian(p, sol.x_eci, q, p.n_epochs,
                                                       skip=("altitude",))), p.n_epochs)
    assert _rel_err(P_less, P_dense) > 1e-2


def test_isam2_online_covariance_equals_the_dense_filtered_one(short_pass):
    """GTSAM's marginalCovariance after the update of epoch k is the covariance of state k
    given the data up to k. iSAM2 linearizes at its online estimates (relinearized only past
    1 km / 1 m/s), the dense problem at the final smoothed states: the difference of
    linearization points bounds the agreement."""
    p = short_pass
    q = SmootherOptions().q_m2_s3
    sol = solve(p, "isam2")
    assert sol.online_P_eci is not None and sol.online_P_eci.shape == (p.n_epochs, 6, 6)
    errs = {}
    for k in (1, 5, 12, p.n_epochs // 2, p.n_epochs - 1):
        J = _dense_jacobian(p, sol.x_eci, q, k + 1)
        P_filt = _dense_covariance(J)[-6:, -6:]
        errs[k] = _rel_err(sol.online_P_eci[k], P_filt)
    assert max(errs.values()) < 1e-3, errs   # measured 5e-5 .. 2.6e-4
    # the comparison can fail: state 12 given one more epoch of data is far off
    P_next = _dense_covariance(_dense_jacobian(p, sol.x_eci, q, 14))[-12:-6, -12:-6]
    assert _rel_err(sol.online_P_eci[12], P_next) > 1e-2
    # the last epoch's filtered covariance is the smoothed one; earlier ones are larger
    assert _rel_err(sol.online_P_eci[-1], sol.P_eci[-1]) < 1e-3
    k = p.n_epochs // 2
    assert np.trace(sol.online_P_eci[k][:3, :3]) > 1.5 * np.trace(sol.P_eci[k][:3, :3])
