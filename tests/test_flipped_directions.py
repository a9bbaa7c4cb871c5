"""Flipped Earth directions (-u logged for u) and a mirrored prior, end to end.

A pass made by ``fgnav simulate gto-transfer`` (independent DOP853 truth), its log edited the
way a sign error in a real pipeline would: the direction residual on the sphere (log map,
``factors.direction``) must show the fault. With the earlier tangent-plane projection both
cases gave a bit-identical or mirror-orbit answer with the clean chi-square (715 on this pass).
"""

from __future__ import annotations

import numpy as np
import pytest

from factors.geometry import tangent_basis, unit_and_jacobian
from fgnav.cli import main
from fgnav.graph import linearize_family
from fgnav.io.log_csv import read_log
from fgnav.measurements import build_pass
from fgnav.io.oem import read_oem
from fgnav.orbit import truth_at
from fgnav.pipeline import accuracy_metrics, solve


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """1 h gto-transfer pass (seed 0, 10 s), its clean batch solution and the truth."""
    d = tmp_path_factory.mktemp("gto")
    assert main(["simulate", "gto-transfer", "--out", str(d), "--duration-h", "1", "--quiet"]) == 0
    log = d / "measurements.csv"
    p = build_pass(read_log(log))
    oem = read_oem(d / "truth.oem")
    assert oem.epoch0 == p.epoch0
    x_true = truth_at(oem.t_s, oem.x_eci, p.t_s)
    return log, p, solve(p, "batch"), x_true


def _edited(src, dst, kind, rows=None):
    """Copy the log with x, y, z negated on the given rows of ``kind`` (all when None);
    returns the indices (among that kind's rows) that were changed."""
    lines = src.read_text().splitlines(keepends=True)
    idx = [i for i, ln in enumerate(lines) if f",{kind}," in ln]
    pick = range(len(idx)) if rows is None else rows
    for j in pick:
        f = lines[idx[j]].rstrip("\n").split(",")
        f[2:5] = [repr(-float(v)) for v in f[2:5]]
        lines[idx[j]] = ",".join(f) + "\n"
    dst.write_text("".join(lines))
    return np.asarray(list(pick))


def test_thirty_percent_flipped_directions_are_seen(clean, tmp_path):
    log, p_clean, sol_clean, x_true = clean
    M = len(p_clean.families["earth_direction"])
    flipped = np.sort(np.random.default_rng(13).choice(M, size=int(0.3 * M), replace=False))
    _edited(log, tmp_path / "flipped.csv", "earth_direction", flipped)
    p = build_pass(read_log(tmp_path / "flipped.csv"))
    fam = p.families["earth_direction"]
    order = np.argsort(p_clean.families["earth_direction"].line)   # rows in file order
    rows = order[flipped]
    # the residual tells: at the clean solution and at the truth, each flipped row is
    # ~pi/sigma whitened; the others are as on the clean pass
    for X in (sol_clean.x_eci, x_true):
        _, _, b, _ = linearize_family(p, "earth_direction", fam, X)
        _, _, b0, _ = linearize_family(p_clean, "earth_direction",
                                       p_clean.families["earth_direction"], X)
        w = np.linalg.norm(b.reshape(M, 2), axis=1)
        np.testing.assert_allclose(w[rows], np.pi / fam.sigma[rows], rtol=1e-3)
        keep = np.setdiff1d(np.arange(M), rows)
        np.testing.assert_array_equal(b.reshape(M, 2)[keep], b0.reshape(M, 2)[keep])
    sol = solve(p, "batch")
    assert not np.array_equal(sol.x_eci, sol_clean.x_eci)
    # no state fits -u at 30 % of the epochs and u at the rest 10 s apart: the chi-square
    # stays far above the clean one (~1e9 against 715), it is not a quiet answer
    assert sol.chi2 > 1e6 * sol_clean.chi2
    assert np.all(np.isfinite(sol.x_eci)) and np.all(np.isfinite(sol.residuals["earth_direction"]))


def test_mirrored_prior_is_not_fitted_with_a_normal_chi2(clean, tmp_path):
    """Clean directions, prior at -r, -v: the mirror orbit predicts -u at every epoch. With
    the tangent-plane residual batch converged to it (28,000 km off) with chi2 715."""
    log, p_clean, sol_clean, x_true = clean
    _edited(log, tmp_path / "prior.csv", "prior_position")
    _edited(tmp_path / "prior.csv", tmp_path / "mirror.csv", "prior_velocity")
    p = build_pass(read_log(tmp_path / "mirror.csv"))
    np.testing.assert_allclose(p.families["prior_position"].values["xyz"],
                               -p_clean.families["prior_position"].values["xyz"])
    sol = solve(p, "batch")
    rms = accuracy_metrics(sol, x_true)["position_rms_m"]
    # either the data win over the weak prior, or the misfit is plain. Measured: started
    # from the initial orbit (the prior contradicts the data), batch converges to the least
    # cost compromise, 313 km RMS with chi2 9.2e7 (1.3e5 x clean, the prior rows' share);
    # from the mirrored prior it stopped unconverged at the mirror, chi2 1.2e11.
    assert rms < 10e3 or sol.chi2 > 1e4 * sol_clean.chi2, (rms, sol.chi2)
    assert sol.extras["initial_orbit"]["prior_consistent"] is False
    # the mirror orbit itself is the farthest point of every direction row
    M = len(p.families["earth_direction"])
    _, _, b, _ = linearize_family(p, "earth_direction", p.families["earth_direction"], -x_true)
    w = np.linalg.norm(b.reshape(M, 2), axis=1) * p.families["earth_direction"].sigma
    assert np.all(w > np.pi - 1e-2)


def _tangent_plane_residual(r_eci_m, u_meas_eci, B=None):
    """The earlier model, kept here as the reference: e = B(u_meas) (-r/|r|), |e| = sin(angle)."""
    u, J = unit_and_jacobian(r_eci_m)
    B = tangent_basis(u_meas_eci) if B is None else B
    return np.einsum("nij,nj->ni", B, -u), -(B @ J)


def test_same_answer_as_the_tangent_plane_residual_on_clean_data(clean, monkeypatch):
    """The two models agree to second order in the angle (e = t (1 + angle^2/6)): on the clean
    pass batch moves by ~1e-7 sigma, position RMS by ~3e-7 relative (the Gauss-Newton loop
    itself stops within 1e-4 sigma; 4 h at 1 Hz: 1.4e-5 relative, 6e-5 sigma)."""
    import fgnav.models.directions

    _, p, sol, x_true = clean
    monkeypatch.setattr(fgnav.models.directions, "earth_direction_residual", _tangent_plane_residual)
    old = solve(p, "batch")
    sigma = np.sqrt(np.diagonal(old.P_eci, axis1=1, axis2=2))
    assert np.max(np.abs(sol.x_eci - old.x_eci) / sigma) < 1e-4
    rms_new = accuracy_metrics(sol, x_true)["position_rms_m"]
    rms_old = accuracy_metrics(old, x_true)["position_rms_m"]
    assert abs(rms_new / rms_old - 1.0) < 1e-5
    assert np.max(np.abs(sol.P_eci - old.P_eci)) < 1e-6 * np.abs(old.P_eci).max()
    assert sol.chi2 == pytest.approx(old.chi2, rel=1e-5)
