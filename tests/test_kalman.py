"""fgnav.solvers.kalman: the one Kalman update and prediction every filter of fgnav uses.

On linear Gaussian problems the update must be the least-squares (information-form)
answer: ``P+ = (P^-1 + A^T A)^-1``, ``x+ = x + P+ A^T b`` (Bar-Shalom, Li & Kirubarajan
2001, sec. 5.2), its normalized innovations ``nu^T nu = b^T S^-1 b``; rows taken one at a
time must give what all at once give; the prediction is the covariance of ``F x + w``.
"""

from __future__ import annotations

import numpy as np
import pytest

from fgnav.solvers.kalman import innovation_covariance, kalman_update, predict_covariance


def _problem(rng, n, m):
    L = rng.normal(size=(n, n)) * 3.0
    P = L @ L.T + 0.1 * np.eye(n)
    return rng.normal(size=n) * 100.0, P, rng.normal(size=(m, n)), rng.normal(size=m)


@pytest.mark.parametrize("n, m", [(6, 1), (6, 3), (9, 12), (3, 3)])
def test_update_is_the_information_form_answer(n, m):
    rng = np.random.default_rng(n * 100 + m)
    x, P, A, b = _problem(rng, n, m)
    x1, P1, nu = kalman_update(x, P, A, b)
    P_info = np.linalg.inv(np.linalg.inv(P) + A.T @ A)
    np.testing.assert_allclose(P1, P_info, rtol=1e-9, atol=1e-12 * np.abs(P_info).max())
    np.testing.assert_allclose(x1, x + P_info @ A.T @ b, rtol=1e-9, atol=1e-9)
    S = A @ P @ A.T + np.eye(m)
    assert nu.shape == (m,)
    assert nu @ nu == pytest.approx(b @ np.linalg.solve(S, b), rel=1e-10)
    np.testing.assert_allclose(np.linalg.cholesky(S) @ nu, b, rtol=1e-10, atol=1e-10)


def test_rows_one_at_a_time_equal_all_at_once():
    """(``b`` is the rows' residual at ``x``: a row taken later sees it at the updated state.)"""
    rng = np.random.default_rng(7)
    x, P, A, b = _problem(rng, 6, 5)
    xa, Pa, _ = kalman_update(x, P, A, b)
    xs, Ps = x, P
    for i in range(len(b)):   # each row's innovation at the state updated so far
        xs, Ps, _ = kalman_update(xs, Ps, A[i:i + 1], b[i:i + 1] - A[i:i + 1] @ (xs - x))
    np.testing.assert_allclose(xs, xa, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(Ps, Pa, rtol=1e-8, atol=1e-10 * np.abs(Pa).max())


def test_given_innovation_covariance_and_retraction_are_used():
    """The gate's S (the same A P A^T + I) gives the same bits; ``retract`` receives the
    update ``K b`` and its result is the new state."""
    rng = np.random.default_rng(3)
    x, P, A, b = _problem(rng, 6, 2)
    plain = kalman_update(x, P, A, b)
    given = kalman_update(x, P, A, b, S=innovation_covariance(P, A))
    for a, c in zip(plain, given):
        np.testing.assert_array_equal(a, c)
    seen = []
    xr, Pr, _ = kalman_update(x, P, A, b, retract=lambda x0, dx: seen.append(dx) or -x0)
    np.testing.assert_array_equal(xr, -x)
    np.testing.assert_allclose(seen[0], plain[0] - x, rtol=1e-12, atol=1e-9)
    np.testing.assert_array_equal(Pr, plain[1])


def test_prediction_is_the_covariance_of_the_propagated_samples():
    rng = np.random.default_rng(11)
    _, P, _, _ = _problem(rng, 4, 1)
    F = np.eye(4) + 0.3 * rng.normal(size=(4, 4))
    Q = np.diag([1.0, 2.0, 0.5, 0.1])
    X = rng.multivariate_normal(np.zeros(4), P, size=200_000)
    W = rng.multivariate_normal(np.zeros(4), Q, size=len(X))
    empirical = np.cov((X @ F.T + W).T)
    Pp = predict_covariance(P, F, Q)
    np.testing.assert_allclose(empirical, Pp, rtol=0.0, atol=0.03 * np.abs(Pp).max())
