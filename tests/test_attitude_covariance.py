"""An ``attitude`` row's full 3x3 covariance (columns ``att_c11`` .. ``att_c33``): the log
format's checks, the whitening of every consumer (the attitude prior in the graphs, the
known-attitude route that rotates body-frame directions into ECI) and the extractor that
writes it. Rows without it keep their isotropic sigma, bit for bit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factors.geometry import so3_exp, so3_log
from fgnav.errors import InputFormatError
from fgnav.extract import EpochProducts, log_from_products
from fgnav.io.log_csv import ATT_COV_COLUMNS, log_from_arrays, read_log, write_log
from fgnav.measurements import build_pass, with_estimates
from fgnav.models.registry import ATTITUDE, ATTITUDE_VARIABLE

HEADER = "epoch,kind,x,y,z,sigma," + ",".join(ATT_COV_COLUMNS)


def _cov(rng, sig, roll=10.0):
    """A covariance with the per-axis sigmas (sig, sig, roll * sig) about random axes."""
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return Q @ np.diag(np.array([1.0, 1.0, roll * roll]) * sig * sig) @ Q.T


def _att_log(covs, sigma=1e-4, body=None):
    """Attitude rows at t = 0, 10, ... with the covariances ``covs`` (None: empty columns),
    and with ``body`` (M, 3) an Earth direction in the body frame at each epoch."""
    rng = np.random.default_rng(1)
    M = len(covs)
    t = 10.0 * np.arange(M)
    rv = rng.normal(0, 1, (M, 3))
    extra = {c: np.full(M, np.nan) for c in ATT_COV_COLUMNS}
    for i, C in enumerate(covs):
        if C is not None:
            for c, (a, b) in zip(ATT_COV_COLUMNS, zip(*np.triu_indices(3))):
                extra[c][i] = C[a, b]
    kind = ["attitude"] * M
    xyz, sig = list(rv), [sigma] * M
    if body is not None:
        t = np.r_[t, t]
        kind += ["earth_direction_body"] * M
        xyz += list(body)
        sig += [2e-4] * M
        extra = {c: np.r_[v, np.full(M, np.nan)] for c, v in extra.items()}
    return log_from_arrays("2025-03-01T00:00:00Z", t, np.array(kind), np.array(xyz),
                           np.array(sig), extra)


# ---- the format -----------------------------------------------------------------------------

def test_round_trip_keeps_the_covariance(tmp_path):
    rng = np.random.default_rng(0)
    log = _att_log([_cov(rng, 1e-4), None, _cov(rng, 3e-5)])
    write_log(tmp_path / "a.csv", log)
    back = read_log(tmp_path / "a.csv")
    for c in ATT_COV_COLUMNS:
        np.testing.assert_array_equal(back.extra[c], log.extra[c])
    assert ",".join(ATT_COV_COLUMNS) in (tmp_path / "a.csv").read_text()


@pytest.mark.parametrize("fields, column, expected", [
    ("1e-10,0,0,1e-10,0,", "att_c33", "all six of att_c11"),
    ("1e-10,2e-10,0,1e-10,0,1e-10", "att_c11,att_c12,att_c13,att_c22,att_c23,att_c33",
     "symmetric positive definite"),
    ("-1e-10,0,0,1e-10,0,1e-10", "att_c11,att_c12,att_c13,att_c22,att_c23,att_c33",
     "symmetric positive definite"),
    ("1e-10,0,0,1e-10,0,100", "att_c11,att_c12,att_c13,att_c22,att_c23,att_c33",
     "eigenvalues within"),
])
def test_a_bad_covariance_is_an_error_naming_file_line_and_columns(tmp_path, fields, column,
                                                                   expected):
    path = tmp_path / "bad.csv"
    path.write_text(f"{HEADER}\n2025-03-01T00:00:00Z,attitude,0.1,0.2,0.3,1e-4,,,,,,\n"
                    f"2025-03-01T00:00:10Z,attitude,0.1,0.2,0.3,1e-4,{fields}\n")
    with pytest.raises(InputFormatError) as exc:
        read_log(path)
    msg = str(exc.value)
    assert f"{path}" in msg and "line 3" in msg and column in msg and expected in msg, msg
    dropped = read_log(path, on_bad_row="drop")
    assert len(dropped) == 1 and sum(dropped.dropped.values()) == 1


def test_another_kind_may_not_fill_the_covariance(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text(f"{HEADER}\n2025-03-01T00:00:00Z,earth_direction,1,0,0,1e-4,"
                    "1e-10,0,0,1e-10,0,1e-10\n")
    with pytest.raises(InputFormatError, match="line 2.*att_c11.*does not use"):
        read_log(path)


# ---- the graphs: the attitude prior ----------------------------------------------------------

def _attitude_rows(log, estimate=True):
    p = with_estimates(build_pass(log), ("attitude",)) if estimate else build_pass(log)
    fam = p.families["attitude"]
    lay = p.layout
    rng = np.random.default_rng(5)
    X = np.zeros((p.n_epochs, lay.n))
    R_off = so3_exp(rng.normal(0, 3e-4, (len(fam), 3)))
    X[fam.k, lay.slices[ATTITUDE_VARIABLE.name]] = so3_log(fam.values["R_eci_from_body"] @ R_off)
    return fam, X, lay


def test_full_rows_are_whitened_by_the_covariance():
    """``|b|^2 = e^T C^-1 e`` and ``A^T A = H^T C^-1 H`` for a row with a covariance; a row
    without it keeps ``e / sigma`` bit for bit."""
    rng = np.random.default_rng(2)
    covs = [_cov(rng, 1e-4), None, _cov(rng, 2e-5, roll=30.0)]
    fam, X, lay = _attitude_rows(_att_log(covs))
    A, b, e = ATTITUDE.linearize(fam, X, lay)
    _, H = ATTITUDE.evaluate(fam, X, lay)
    for j, C in enumerate(covs):
        if C is None:
            np.testing.assert_array_equal(b[j], -e[j] / fam.sigma[j])
            np.testing.assert_array_equal(A[j], H[j] / fam.sigma[j])
            continue
        Ci = np.linalg.inv(C)
        assert b[j] @ b[j] == pytest.approx(e[j] @ Ci @ e[j], rel=1e-10)
        np.testing.assert_allclose(A[j].T @ A[j], H[j].T @ Ci @ H[j], rtol=1e-9,
                                   atol=1e-9 * np.abs(H[j].T @ Ci @ H[j]).max())
        # and not what the isotropic sigma would give
        assert abs(b[j] @ b[j] - e[j] @ e[j] / fam.sigma[j] ** 2) > 0.1 * (b[j] @ b[j])


def test_isotropic_covariance_equals_the_sigma():
    fam, X, lay = _attitude_rows(_att_log([np.eye(3) * 1e-8] * 3))
    A, b, e = ATTITUDE.linearize(fam, X, lay)
    np.testing.assert_allclose(b, -e / 1e-4, rtol=1e-12)
    np.testing.assert_allclose(A, ATTITUDE.evaluate(fam, X, lay)[1] / 1e-4, rtol=1e-12)


def test_the_gtsam_factor_takes_the_covariance():
    """The iSAM2 route's factor error ``0.5 |W e|^2`` equals the batch route's ``0.5 |b|^2``."""
    import gtsam

    from fgnav.graph import factors_for_rows

    rng = np.random.default_rng(4)
    covs = [_cov(rng, 1e-4), _cov(rng, 5e-5)]
    log = _att_log(covs)
    p = with_estimates(build_pass(log), ("attitude",))
    fam, X, lay = _attitude_rows(log)
    _, b, _ = ATTITUDE.linearize(fam, X, lay)
    for j in range(len(fam)):
        k = int(fam.k[j])
        f, = factors_for_rows(p, "attitude", np.array([j]), k, None, X[k, :6])
        v = gtsam.Values()
        v.insert(ATTITUDE_VARIABLE.key(k), gtsam.Rot3.Expmap(X[k, lay.slices["attitude"]]))
        assert f.error(v) == pytest.approx(0.5 * b[j] @ b[j], rel=1e-9)


# ---- the known-attitude route ----------------------------------------------------------------

def test_known_attitude_adds_the_covariance_across_the_direction():
    """A body-frame direction rotated with a measured attitude gains the attitude error
    across it: none from an error about the direction itself (a roll about the boresight),
    all of it from an error across; a row without a covariance adds its sigma as before."""
    u = np.array([[0.0, 0.0, 1.0]] * 3)
    big, small = 1e-3, 1e-5
    covs = [np.diag([small, small, big]) ** 2,      # roll about u: adds small
            np.diag([big, small, small]) ** 2,      # across u: adds big
            None]                                   # isotropic sigma 1e-4
    log = _att_log(covs, sigma=1e-4, body=u)
    fam = build_pass(log).families["earth_direction"]
    np.testing.assert_allclose(fam.sigma, [math.hypot(2e-4, small), math.hypot(2e-4, big),
                                           math.hypot(2e-4, 1e-4)], rtol=1e-12)
    assert fam.sigma[2] == math.hypot(2e-4, 1e-4)   # bit for bit without a covariance


# ---- the extractor ---------------------------------------------------------------------------

def test_extractor_writes_the_attitude_covariance():
    rng = np.random.default_rng(6)
    P = _cov(rng, 2e-5)
    ep = EpochProducts(epoch=np.datetime64("2025-03-01T00:00:00", "ns"),
                       R_eci_from_body=so3_exp(np.array([0.1, 0.2, 0.3])), P_att_rad2=P,
                       u_body=np.array([0.0, 0.0, 1.0]),
                       C_u_body_rad2=np.diag([1e-8, 1e-8, 0.0]), rho_rad=0.15,
                       sigma_rho_rad=1e-4, r_limb_m=6.4e6)
    log = log_from_products([ep], "body")
    i, = log.select("attitude")
    got = np.array([log.extra[c][i] for c in ATT_COV_COLUMNS])
    np.testing.assert_allclose(got, P[np.triu_indices(3)], rtol=1e-15)
    assert log.sigma[i] == pytest.approx(math.sqrt(np.max(np.diag(P))))
    eci = log_from_products([ep], "eci")
    assert all(np.isnan(eci.extra[c]).all() for c in ATT_COV_COLUMNS)
