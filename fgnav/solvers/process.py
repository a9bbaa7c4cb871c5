"""The process model of the graph variables beyond the orbit state, between two epochs.

Each further variable follows a random walk between consecutive epochs
(``factors.random_walk``): a vector ``b_{k+1} = b_k + w``, a rotation
``R_{k+1} = R_k Exp(w)``, ``w ~ N(0, psd dt I)`` (Maybeck 1979, "Stochastic Models,
Estimation and Control", vol. 1, sec. 4.10) -- except the attitude when its body rate is
estimated too (``registry.ATTITUDE_RATE``, ``fgnav smooth --attitude-motion constant-rate``):
then attitude and rate follow the constant-rate motion of ``factors.attitude_motion``
(white angular acceleration of the rate's ``psd``), one 6-row factor per step. The batch solver stacks these whitened rows
under each step's motion rows; the EKF eliminates them together with the rows of the
between-epoch measurements (a gyro interval) to propagate the variables. One definition,
both solvers (no GTSAM here: the EKF baseline runs without it).
"""

from __future__ import annotations

import numpy as np

from factors.geometry import so3_exp
from fgnav.models.variables import CONSTANT_PSD_FLOOR
from factors.attitude_motion import constant_rate_residual, constant_rate_sqrt_information
from factors.random_walk import random_walk_residual, rot3_random_walk_residual
from fgnav.models.registry import ATTITUDE_RATE, ATTITUDE_VARIABLE

__all__ = ["variable_step_rows", "constant_rate"]


def constant_rate(lay) -> bool:
    """True when the layout's attitude follows the constant-rate motion (its rate is estimated)."""
    return lay.has(ATTITUDE_RATE.name) and lay.has(ATTITUDE_VARIABLE.name)


def variable_step_rows(lay, X0: np.ndarray, X1: np.ndarray, dt_s: np.ndarray):
    """Whitened process rows of the further variables over the steps ``X0 -> X1``.

    ``X0``, ``X1`` (S, n): block values of the pass's layout ``lay`` at the start and end of
    each step; ``dt_s`` (S,) the steps, s. Returns ``A0, A1`` (S, n, n) and ``b`` (S, n):
    step s's rows are ``|A0[s] dx_0 + A1[s] dx_1 - b[s]|^2`` with the rows of the orbit
    (the first six) zero, each further variable's rows in its own slice: a vector
    ``w [-I, I]``, ``b = -w (b_1 - b_0)``; a rotation ``w [H_0, H_1]``,
    ``b = -w Log(R_0^T R_1)`` (``factors.random_walk.rot3_random_walk_residual``), with
    ``w = 1/sqrt(psd dt)``; with the constant-rate motion the attitude's and the rate's
    rows together ``W e`` (``factors.attitude_motion``).
    """
    X0 = np.asarray(X0, dtype=float)
    X1 = np.asarray(X1, dtype=float)
    S, n = X0.shape
    A0 = np.zeros((S, n, n))
    A1 = np.zeros_like(A0)
    b = np.zeros((S, n))
    dt = np.asarray(dt_s, dtype=float)
    coupled = constant_rate(lay)
    if coupled:
        sa, sw = lay.slices[ATTITUDE_VARIABLE.name], lay.slices[ATTITUDE_RATE.name]
        e, H_R0, H_w0, H_R1, H_w1 = constant_rate_residual(
            so3_exp(X0[:, sa]), X0[:, sw], so3_exp(X1[:, sa]), X1[:, sw], dt)
        W = constant_rate_sqrt_information(dt, max(ATTITUDE_RATE.psd, CONSTANT_PSD_FLOOR))
        for rows, Wr in ((sa, W[:, :3]), (sw, W[:, 3:])):
            A0[:, rows, sa] = Wr @ H_R0
            A0[:, rows, sw] = Wr @ H_w0
            A1[:, rows, sa] = Wr @ H_R1
            A1[:, rows, sw] = Wr @ H_w1
            b[:, rows] = -np.einsum("kij,kj->ki", Wr, e)
    for v in lay.extra:
        if v.orbit or (coupled and v.name in (ATTITUDE_VARIABLE.name, ATTITUDE_RATE.name)):
            continue   # a formation's further orbits follow the motion model (the caller's)
        sl = lay.slices[v.name]
        if v.manifold == "rot3":
            e, H0, H1 = rot3_random_walk_residual(so3_exp(X0[:, sl]), so3_exp(X1[:, sl]))
        else:
            e, H0, H1 = random_walk_residual(X0[:, sl], X1[:, sl])
        w = 1.0 / v.step_sigma(dt)
        A0[:, sl, sl] = w[:, None, None] * H0
        A1[:, sl, sl] = w[:, None, None] * H1
        b[:, sl] = -w[:, None] * e
    return A0, A1, b
