"""Single-epoch formation solution and the Cartesian-vs-spherical conditioning study.

Reproduces Xing et al. (Xing et al., ST-3 AFF pseudorange positioning), Table 1 geometry and its
section-3 figures: rcond(A^T A) 1.09e-7 (Cartesian) vs 2.5e-2 (spherical), sigma_R 0.41 cm,
clock 1.22 cm, az/el 0.01 rad at 1 cm noise, covariance stable (spherical) vs unstable
(Cartesian) between two epochs, and 67.5 % (120 runs) of R errors within +-1 sigma.
"""

import json

import numpy as np
import pytest

from factors.pseudorange import predict_ranges
from fgnav.cli import main
from fgnav.errors import UserError
from fgnav.iod.single_epoch import solve_single_epoch
from fgnav.formation.study import (
    FORMATION_REFERENCE, conditioning_study, coverage_monte_carlo, covariance_change, formation_reference_truth,
)


@pytest.fixture(scope="module")
def study():
    return conditioning_study(runs=5000, seed=0, sigma_m=0.01)


def test_xing_rcond(study):
    """Xing et al.: rcond(A^T A) = 1.09e-7 (Cartesian) vs 2.5e-2 (spherical), m and rad."""
    c, s = study["cartesian"], study["spherical"]
    assert 1.0e-7 < c["rcond"] < 1.2e-7 and 1.0e-7 < c["rcond_1norm"] < 1.2e-7
    # Xing et al.'s 2.5e-2 lies between our 1-norm (2.04e-2) and 2-norm (2.94e-2) figures
    assert s["rcond_1norm"] < 2.5e-2 < s["rcond"]
    assert 1.9e-2 < s["rcond_1norm"] and s["rcond"] < 3.1e-2
    assert s["rcond"] / c["rcond"] > 1e4
    assert c["cond"] == pytest.approx(1 / c["rcond"])


def test_xing_sigmas(study):
    """Xing et al.: sigma_R = 0.41 cm, sigma_az = sigma_el = 0.01 rad, clock 1.22 cm."""
    sR, saz, sel, sc = study["spherical"]["sigmas_epoch1"]
    assert sR == pytest.approx(0.0041, abs=0.0001)
    assert sc == pytest.approx(0.0122, abs=0.0001)
    assert saz == pytest.approx(0.01, rel=0.01) and sel == pytest.approx(0.01, rel=0.01)
    # the cofactor (A'^T A')^-1 Xing et al. print for both epochs
    Q = np.array(study["spherical"]["covariance"]["cofactor_epoch1"])
    Q_seed = np.array([[1 / 6, 0, 0, 0], [0, 1, -0.5, -1], [0, -0.5, 1, 1], [0, -1, 1, 1.5]])
    assert np.abs(Q - Q_seed).max() < 1e-3


def test_covariance_two_epochs(study):
    """Spherical covariance stable between the two epochs, Cartesian not (Xing et al. Table 1).

    The Cartesian x-row moves by many of its own sigmas because the 10 m x 4 mm error
    ellipsoid turns with the estimated direction (0.01 rad between epochs)."""
    c, s = study["cartesian"]["covariance"], study["spherical"]["covariance"]
    assert s["relative_change"] < 1e-2
    assert c["relative_change"] > 1.0
    assert c["relative_change"] > 100 * s["relative_change"]
    # y, z cofactor entries ~ R^2 Q_az = 1e6 (Xing et al. print ~1e9: see the report)
    assert 0.9e6 < c["max_abs_cofactor"] < 1.1e6


def test_solutions_agree_between_parameterizations():
    """Same data, same minimum: the parameterization changes the tangent space, not the fix."""
    rng = np.random.default_rng(5)
    r, cdt, M21 = formation_reference_truth(2)
    z = predict_ranges(r, cdt, M21) + 0.01 * rng.standard_normal(6)
    a = solve_single_epoch(z, M21, "cartesian")
    b = solve_single_epoch(z, M21, "spherical")
    assert a.converged and b.converged
    assert np.allclose(a.r_m, b.r_m, atol=1e-6)
    assert a.cdt_m == pytest.approx(b.cdt_m, abs=1e-8)
    # covariances are the same Gaussian seen in two coordinate systems
    from factors.pseudorange import spherical_to_cartesian
    _, J = spherical_to_cartesian(b.x[:3])
    T = np.eye(4)
    T[:3, :3] = J
    assert np.allclose(T @ b.covariance @ T.T, a.covariance, rtol=1e-5, atol=1e-12)


def test_monte_carlo_coverage(study):
    """5,000 runs: 68.27 % +- 2 % of range errors inside +-1 sigma (Xing et al.: 67.5 %, 120 runs)."""
    assert study["runs"] == 5000
    assert abs(study["coverage_1sigma"] - 0.6827) < 0.02


def test_coverage_detects_wrong_sigma():
    """The coverage check can fail: halving the assumed noise gives ~38 %."""
    frac, err, sig = coverage_monte_carlo(runs=1000, seed=3, sigma_m=0.01)
    assert abs(np.mean(np.abs(err) <= 0.5 * sig) - 0.383) < 0.05
    assert np.std(err) == pytest.approx(np.mean(sig), rel=0.1)


def test_covariance_change_metric():
    P = np.diag([1.0, 4.0])
    assert covariance_change(P, P) == (0.0, 0.0)
    assert covariance_change(P, np.diag([2.0, 4.0]))[0] == pytest.approx(1.0)


def test_cli_conditioning_json(capsys):
    assert main(["formation", "conditioning", "--json", "--runs", "300", "--seed", "2"]) == 0
    out = json.loads(capsys.readouterr().out)
    for p in ("cartesian", "spherical"):
        assert {"rcond", "cond", "covariance"} <= set(out[p])
        cov = out[p]["covariance"]
        assert np.array(cov["epoch1"]).shape == (4, 4) and "relative_change" in cov
    assert 0.55 < out["coverage_1sigma"] < 0.8 and out["runs"] == 300


def test_cli_conditioning_bad_runs(capsys):
    assert main(["formation", "conditioning", "--runs", "0"]) == 2
    assert "--runs" in capsys.readouterr().err


def test_unknown_param_is_user_error():
    with pytest.raises(UserError):
        solve_single_epoch(np.zeros(6), np.eye(3), "polar")


def test_seed_geometry_constants():
    assert FORMATION_REFERENCE["R_m"] == (999.922, 999.891)
    r, cdt, M21 = formation_reference_truth(1)
    assert np.allclose(r, [999.922, 0, 0]) and cdt == 0 and np.array_equal(M21, np.eye(3))
