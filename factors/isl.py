"""Inter-satellite link (ISL) pseudorange and carrier phase between two absolute orbit states.

Both spacecraft's orbit states are graph variables, ``x = [r_eci_m; v_eci_mps]`` in ECI
(EME2000, inertial), SI. One row is one one-way link at the receive time ``t`` (the row's
epoch, in the system time scale): spacecraft ``tx`` transmits, spacecraft ``rx`` receives.

Model (the one-way light-time equation of a moving transmitter, Montenbruck & Gill 2000,
*Satellite Orbits*, ch. 6 "Satellite tracking and observation models", here between two
spacecraft)::

    rho = c tau + s clock_m                       (pseudorange, m)
    phi = c tau + s clock_m + N                   (carrier phase in metres, float ambiguity N)
    p_rx = r_rx + R_rx a_rx                       (receive antenna at t)
    p_tx(t - tau) ~= r_tx + R_tx a_tx - v_tx tau  (transmit antenna at emission, first order)
    |p_rx - p_tx(t - tau)| = c tau                (light time tau, s)

``R_rx``, ``R_tx``: ``R_eci_from_body`` of each spacecraft at ``t`` (known here);
``a_rx``, ``a_tx``: antenna lever arms in each body frame (m); ``clock_m``: the relative
clock bias variable of the spacecraft pair (m); ``s = +1`` or ``-1`` per row (+1 when the
receiver is the pair's first spacecraft, as in Xing et al.'s eq. (1), factors.pseudorange).
With ``d0 = p_rx - (r_tx + R_tx a_tx)`` and ``v = v_tx`` the light-time condition
``|d0 + v tau|^2 = c^2 tau^2`` is the quadratic

    (c^2 - v.v) tau^2 - 2 (d0.v) tau - d0.d0 = 0,
    tau = (b + S) / A,   A = c^2 - v.v,  b = d0.v,  S = sqrt(b^2 + A d0.d0)   (positive root),

solved in closed form (no iteration; ``S ~ c |d0|`` so neither root form cancels).

Jacobians (implicit differentiation of ``F(tau, d0, v) = A tau^2 - 2 b tau - d0.d0 = 0``):
``dF/dtau = 2 (A tau - b) = 2 S``, ``dF/dd0 = -2 D^T``, ``dF/dv = -2 tau D^T`` with
``D = d0 + v tau`` the light path (``|D| = c tau``), hence

    d(c tau)/d d0 = (c/S) D^T = u^T / (1 - u.v/c),   u = D/|D|,
    d(c tau)/d v_tx = tau (c/S) D^T,

and ``d d0/d r_rx = I``, ``d d0/d r_tx = -I``: ``H_rx = [g^T, 0]``, ``H_tx = [-g^T, tau g^T]``
with ``g = (c/S) D``; ``de/d clock = s``, ``de/dN = 1``. For a right perturbation
``R <- R Exp(w)`` of an attitude, ``d(R a)/dw = -R skew(a)``
(:func:`isl_attitude_jacobians`, for when the attitudes are estimated).

What the first-order emission position neglects (the transmitter's motion over ``tau``
beyond ``v_tx tau``), with numbers:

- its acceleration, ``|u . a_tx| tau^2 / 2``: two LEO spacecraft 2,000 km apart,
  ``tau = 6.7 ms``, ``|a| <= 9 m/s^2`` gives at most ``2.0e-4 m`` along any direction,
  and the line of sight between two near-circular orbits is within ``~15 deg`` of the
  local horizontal (``|u . r_hat| ~ d/(2r) + dh/d <= 0.25`` for ``d = 2,000 km``,
  ``r = 6,900 km``, ``dh <= 200 km``), so ``<= 5e-5 m``; two GTO spacecraft 1 km apart:
  ``tau = 3.3 us``, ``<= 9.4 * (3.3e-6)^2 / 2 = 5e-11 m``;
- the lever arm's rotation, ``|omega x R_tx a_tx| tau``: a 1 m lever arm on an
  Earth-pointing spacecraft (``omega = 1.1e-3 rad/s`` in LEO) gives ``7e-6 m`` at
  2,000 km and ``4e-9 m`` at 1 km; below 1e-4 m for ``omega |a_tx| < 0.015 m/s`` at
  2,000 km;
- nothing else: the quadratic is the exact light time of the linearly moving antenna
  (no ``v/c`` expansion).
Measured against an exact light-time solution on DOP853 truth, Earth-pointing attitudes and
~1 m lever arms (tests/test_isl.py): 3.0e-5 m at most for two LEO spacecraft in different
planes 540-1,970 km apart (the neglected terms above account for it to 1e-9 m), 1.2e-9 m for
two spacecraft 1 km apart near the GTO perigee. Ignoring the light time altogether
(``c tau = |d0|``) errs by ``u . v_tx tau``: 18-32 m in that LEO case (``v tau ~ 50 m``
at 2,000 km), 2.0-2.7 cm for the GTO pair.

Not modelled (below the code noise of the scenarios, named so a carrier-phase user can
judge): the Shapiro delay ``(2 GM/c^2) ln((r_1 + r_2 + d)/(r_1 + r_2 - d))`` (Montenbruck
& Gill 2000, ch. 6): 2.6 mm for two LEO spacecraft 2,000 km apart, 1e-6 m for 1 km
in GTO, slowly varying and largely absorbed by a carrier ambiguity; relativistic clock
terms (absorbed by the relative clock variable); a receive time-tag error ``dt``, which
shifts the range by ``range rate * dt`` (the row's epoch is taken as the true receive time).

Residual contract (CONTRIBUTING.md): unwhitened ``e = h(x) - z`` (m), vectorized over M rows,
analytic Jacobians. Never imports fgnav.
"""

from __future__ import annotations

import math

import numpy as np

from factors.adapters import custom_factor, vector_state
from factors.constants import C_LIGHT_M_S
from factors.errors import ModelDomainError
from factors.geometry import skew

__all__ = [
    "light_time", "isl_predict_range", "isl_range_residual", "isl_carrier_residual",
    "isl_attitude_jacobians", "make_isl_range_factor", "make_isl_carrier_factor",
]


def light_time(d0_m, v_tx_mps, c_mps=C_LIGHT_M_S):
    """Closed-form light time of the first-order model (module docstring).

    Parameters
    ----------
    d0_m : (M, 3) ``p_rx(t) - p_tx(t)``, receive antenna minus transmit antenna, both at t (m).
    v_tx_mps : (M, 3) transmitter velocity (m/s).
    c_mps : speed of light (m/s).

    Returns
    -------
    tau : (M,) s, positive root of ``(c^2 - v.v) tau^2 - 2 (d0.v) tau - d0.d0 = 0``.
    D : (M, 3) light path ``d0 + v tau`` (m), ``|D| = c tau``.
    S : (M,) ``sqrt((d0.v)^2 + (c^2 - v.v) d0.d0)`` (m^2/s), the implicit-derivative scale.
    """
    d0 = np.asarray(d0_m, dtype=float)
    v = np.asarray(v_tx_mps, dtype=float)
    A = c_mps * c_mps - np.einsum("...i,...i->...", v, v)
    b = np.einsum("...i,...i->...", d0, v)
    C = np.einsum("...i,...i->...", d0, d0)
    disc = b * b + A * C
    bad = ~((A > 0.0) & (disc >= 0.0))
    if np.any(bad):   # a transmitter at or beyond the speed of light: no light time
        k = int(np.flatnonzero(np.ravel(bad))[0])
        speed = math.sqrt(max(c_mps ** 2 - float(np.ravel(A)[k]), 0.0))
        raise ModelDomainError(f"inter-satellite light time undefined at row {k}: the "
                               f"transmitter's speed {speed:.4g} m/s is not below the speed "
                               f"of light", row=k)
    S = np.sqrt(disc)
    tau = (b + S) / A
    D = d0 + v * tau[..., None]
    return tau, D, S


def _geometry(x_rx, x_tx, R_rx, R_tx, a_rx, a_tx):
    x_rx = np.asarray(x_rx, dtype=float)
    x_tx = np.asarray(x_tx, dtype=float)
    # centres first, lever arms then: the lever arms' metres are not rounded at |r| ~ 4e7 m
    lever = (np.einsum("...ij,...j->...i", np.asarray(R_rx, dtype=float),
                       np.asarray(a_rx, dtype=float))
             - np.einsum("...ij,...j->...i", np.asarray(R_tx, dtype=float),
                         np.asarray(a_tx, dtype=float)))
    return light_time((x_rx[..., :3] - x_tx[..., :3]) + lever, x_tx[..., 3:6])


def isl_predict_range(x_rx, x_tx, R_rx, R_tx, a_rx_body_m, a_tx_body_m):
    """Geometric range ``c tau`` (m), shape (M,), of the first-order light-time model."""
    tau, _, _ = _geometry(x_rx, x_tx, R_rx, R_tx, a_rx_body_m, a_tx_body_m)
    return C_LIGHT_M_S * tau


def isl_range_residual(x_rx, x_tx, R_rx, R_tx, a_rx_body_m, a_tx_body_m, clock_m, clock_sign,
                       rho_m):
    """One-way ISL pseudorange residual ``e = c tau + s clock_m - rho`` (module docstring).

    Parameters
    ----------
    x_rx, x_tx : (M, 6) receiver / transmitter ECI states ``[r m; v m/s]`` at the receive time.
    R_rx, R_tx : (M, 3, 3) ``R_eci_from_body`` of receiver / transmitter.
    a_rx_body_m, a_tx_body_m : (M, 3) antenna lever arms in each body frame (m).
    clock_m : (M,) relative clock bias of the pair (m).
    clock_sign : (M,) +1 or -1 (+1 when the receiver is the pair's first spacecraft).
    rho_m : (M,) measured pseudorange (m).

    Returns
    -------
    e : (M, 1) m.
    H_rx : (M, 1, 6) ``de/dx_rx = [g^T, 0]``.
    H_tx : (M, 1, 6) ``de/dx_tx = [-g^T, tau g^T]`` (light time: the velocity columns).
    H_clock : (M, 1, 1) ``s``.
    """
    tau, D, S = _geometry(x_rx, x_tx, R_rx, R_tx, a_rx_body_m, a_tx_body_m)
    sign = np.broadcast_to(np.asarray(clock_sign, dtype=float), tau.shape)
    e = C_LIGHT_M_S * tau + sign * np.asarray(clock_m, dtype=float) - np.asarray(rho_m,
                                                                               dtype=float)
    g = (C_LIGHT_M_S / S)[..., None] * D
    M = tau.shape[0]
    H_rx = np.zeros((M, 1, 6))
    H_tx = np.zeros((M, 1, 6))
    H_rx[:, 0, :3] = g
    H_tx[:, 0, :3] = -g
    H_tx[:, 0, 3:] = tau[:, None] * g
    H_clock = sign.reshape(M, 1, 1).copy()
    return e.reshape(M, 1), H_rx, H_tx, H_clock


def isl_carrier_residual(x_rx, x_tx, R_rx, R_tx, a_rx_body_m, a_tx_body_m, clock_m, clock_sign,
                         phi_m, ambiguity_m):
    """ISL carrier phase (m) residual ``e = c tau + s clock_m + N - phi``.

    Parameters as :func:`isl_range_residual` (``phi_m`` (M,) the measured phase times the
    wavelength, m) plus ``ambiguity_m`` (M,): the link's float ambiguity ``N`` (m), constant
    while the link stays locked. Returns ``e (M, 1)``, ``H_rx (M, 1, 6)``, ``H_tx (M, 1, 6)``,
    ``H_clock (M, 1, 1)``, ``H_amb (M, 1, 1)`` (ones).
    """
    e, H_rx, H_tx, H_c = isl_range_residual(x_rx, x_tx, R_rx, R_tx, a_rx_body_m, a_tx_body_m,
                                            clock_m, clock_sign, phi_m)
    e = e + np.asarray(ambiguity_m, dtype=float).reshape(-1, 1)
    return e, H_rx, H_tx, H_c, np.ones((e.shape[0], 1, 1))


def isl_attitude_jacobians(x_rx, x_tx, R_rx, R_tx, a_rx_body_m, a_tx_body_m):
    """Jacobians of ``c tau`` with respect to right perturbations of ``R_rx`` and ``R_tx``.

    ``R <- R Exp(w)`` moves the antenna by ``-R skew(a) w``: ``H_att_rx = -g^T R_rx skew(a_rx)``,
    ``H_att_tx = +g^T R_tx skew(a_tx)`` (transmitter attitude at t; its rotation over ``tau``
    is neglected, module docstring). Returns ``(H_att_rx (M, 1, 3), H_att_tx (M, 1, 3))``,
    m/rad; the same for pseudorange and carrier phase.
    """
    R_rx = np.asarray(R_rx, dtype=float)
    R_tx = np.asarray(R_tx, dtype=float)
    tau, D, S = _geometry(x_rx, x_tx, R_rx, R_tx, a_rx_body_m, a_tx_body_m)
    g = (C_LIGHT_M_S / S)[..., None] * D
    gR_rx = np.einsum("mi,mij->mj", g, R_rx)
    gR_tx = np.einsum("mi,mij->mj", g, R_tx)
    H_rx = -np.einsum("mj,mjk->mk", gR_rx, skew(np.asarray(a_rx_body_m, dtype=float)))
    H_tx = np.einsum("mj,mjk->mk", gR_tx, skew(np.asarray(a_tx_body_m, dtype=float)))
    return H_rx[:, None, :], H_tx[:, None, :]


def _isl_factor(key_rx, key_tx, key_clock, key_amb, R_rx, R_tx, a_rx, a_tx, sign, z, noise):
    """One row's CustomFactor: pseudorange without ``key_amb``, carrier phase with it; keys
    ``rx, tx, [clock], [amb]``."""
    R_rx, R_tx, a_rx, a_tx = (np.array(a, dtype=float).copy() for a in (R_rx, R_tx, a_rx, a_tx))
    s = np.array([float(sign)])
    z = np.array([float(z)])
    extra = ([] if key_clock is None else [key_clock]) + ([] if key_amb is None else [key_amb])

    def residual(values):
        x_rx = vector_state(values, key_rx)[None, :6]
        x_tx = vector_state(values, key_tx)[None, :6]
        clock = np.array([0.0 if key_clock is None else float(values.atVector(key_clock)[0])])
        args = (x_rx, x_tx, R_rx[None], R_tx[None], a_rx[None], a_tx[None], clock, s, z)
        if key_amb is None:
            e, H_rx, H_tx, H_c = isl_range_residual(*args)
            H_extra = [] if key_clock is None else [H_c[0]]
        else:
            amb = np.array([float(values.atVector(key_amb)[0])])
            e, H_rx, H_tx, H_c, H_a = isl_carrier_residual(*args, amb)
            H_extra = ([] if key_clock is None else [H_c[0]]) + [H_a[0]]
        return e[0], [H_rx[0], H_tx[0]] + H_extra

    return custom_factor([key_rx, key_tx] + extra, noise, residual, dim=1)


def make_isl_range_factor(key_rx, key_tx, key_clock, R_rx, R_tx, a_rx, a_tx, sign, rho, noise):
    """``gtsam.CustomFactor`` for one ISL pseudorange row (:func:`isl_range_residual`).

    ``key_rx``, ``key_tx``: Vector6 orbit keys ``[r; v]``; ``key_clock``: Vector1 relative
    clock key (m), or ``None`` for a link without a clock variable (two-way or synchronised:
    the clock term is zero and the factor has the two orbit keys only). ``R_rx``, ``R_tx``
    (3, 3) ``R_eci_from_body``; ``a_rx``, ``a_tx`` (3,) lever arms (m); ``sign`` +1/-1;
    ``rho`` (m); ``noise``: sigma (m) or a gtsam noise model.
    """
    return _isl_factor(key_rx, key_tx, key_clock, None, R_rx, R_tx, a_rx, a_tx, sign, rho,
                       noise)


def make_isl_carrier_factor(key_rx, key_tx, key_clock, key_amb, R_rx, R_tx, a_rx, a_tx, sign,
                            phi, noise):
    """``gtsam.CustomFactor`` for one ISL carrier-phase row (:func:`isl_carrier_residual`).

    As :func:`make_isl_range_factor` plus ``key_amb``: Vector1 float ambiguity of the link (m);
    ``phi``: measured carrier phase (m). Keys in order ``rx, tx, [clock], amb``.
    """
    return _isl_factor(key_rx, key_tx, key_clock, key_amb, R_rx, R_tx, a_rx, a_tx, sign, phi,
                       noise)
