"""Random walks of slowly varying variables: vector and rotation residuals, Jacobians and
their GTSAM factors (``factors/random_walk.py``)."""

from __future__ import annotations

import gtsam
import numpy as np

from factors.adapters import whiten
from factors.geometry import so3_exp
from factors.random_walk import (make_random_walk_factor, make_rot3_prior_factor,
                                 make_rot3_random_walk_factor, make_vector_prior_factor,
                                 random_walk_residual, rot3_random_walk_residual)
from factors.testing import check_jacobians, check_linearization, random_rotations


def test_vector_random_walk_jacobians_and_factor():
    rng = np.random.default_rng(1)
    b0, b1 = rng.normal(size=(5, 2)), rng.normal(size=(5, 2))
    e, H0, H1 = random_walk_residual(b0, b1)
    np.testing.assert_allclose(e, b1 - b0)
    check_jacobians(random_walk_residual, (b0, b1), (H0, H1), ("vector", "vector"))
    f = make_random_walk_factor(7, 8, 0.5, 2)
    v = gtsam.Values()
    v.insert(7, b0[0])
    v.insert(8, b1[0])
    A, b = whiten(e[:1], [H0[:1], H1[:1]], np.array([0.5]))
    check_linearization(f, v, [A[0][0], A[1][0]], b[0])
    p = make_vector_prior_factor(7, [1.0, 2.0], 3.0)
    np.testing.assert_allclose(p.unwhitenedError(v), b0[0] - [1.0, 2.0])


def test_rot3_random_walk_jacobians_and_gtsam_between():
    rng = np.random.default_rng(2)
    R0 = random_rotations(rng, 6)
    R1 = R0 @ so3_exp(rng.normal(size=(6, 3)) * 0.7)   # steps up to ~2 rad
    e, H0, H1 = rot3_random_walk_residual(R0, R1)
    check_jacobians(rot3_random_walk_residual, (R0, R1), (H0, H1), ("rot3", "rot3"))
    f = make_rot3_random_walk_factor(1, 2, 0.01)
    for i in range(6):
        v = gtsam.Values()
        v.insert(1, gtsam.Rot3(R0[i]))
        v.insert(2, gtsam.Rot3(R1[i]))
        np.testing.assert_allclose(f.unwhitenedError(v), e[i], atol=1e-12)
        A, b = whiten(e[i:i + 1], [H0[i:i + 1], H1[i:i + 1]], np.array([0.01]))
        check_linearization(f, v, [A[0][0], A[1][0]], b[0], rtol=1e-7, atol=1e-7)
    prior = make_rot3_prior_factor(1, R1[0], 0.1)
    v = gtsam.Values()
    v.insert(1, gtsam.Rot3(R1[0]))
    np.testing.assert_allclose(prior.unwhitenedError(v), 0.0, atol=1e-12)
