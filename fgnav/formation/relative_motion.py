"""Relative motion of the deputy (sat 2) about the chief (sat 1) in the chief's LVLH frame.

LVLH (Hill) frame of the chief: x radial (r/|r|), z along the orbit normal h/|h|,
y = z x x (along-track). State ``[r_lvlh_m; v_lvlh_mps]`` with ``v`` the rate seen in the
rotating frame.

- :func:`cw_matrices`: Clohessy–Wiltshire (Hill) linear dynamics for a circular chief,
  ``x'' = 3 n^2 x + 2 n y', y'' = -2 n x', z'' = -n^2 z``, discretized exactly with the
  state transition matrix and the Van Loan process-noise covariance of a white relative
  acceleration of PSD ``q`` (m^2/s^3) per axis.
- :func:`circular_relative_orbit`: the closed CW orbit of constant separation
  ``rho`` (x = rho/2 cos, y = -rho sin, z = sqrt(3)/2 rho cos of ``n t + phase``).
- :func:`two_body_relative_truth`: the check — integrate both satellites' absolute
  two-body orbits (scipy DOP853, rtol 1e-12) and difference them in LVLH.
"""

from __future__ import annotations

import numpy as np

from factors.constants import MU_EARTH_M3_S2, R_EARTH_M
from fgnav.frames import rtn_frame

__all__ = ["mean_motion", "cw_system", "cw_matrices", "circular_relative_orbit",
           "lvlh_from_eci", "chief_circular_state", "two_body_relative_truth"]


def mean_motion(alt_km=500.0, mu=MU_EARTH_M3_S2):
    """Mean motion n (rad/s) of a circular orbit at altitude ``alt_km`` above R_e."""
    a = R_EARTH_M + 1e3 * alt_km
    return float(np.sqrt(mu / a ** 3))


def cw_system(n_rad_s):
    """Continuous CW system matrix F (6, 6): ``d/dt [r; v] = F [r; v]``."""
    n = n_rad_s
    F = np.zeros((6, 6))
    F[:3, 3:] = np.eye(3)
    F[3, 0] = 3 * n * n
    F[3, 4] = 2 * n
    F[4, 3] = -2 * n
    F[5, 2] = -n * n
    return F


def cw_matrices(n_rad_s, dt_s, q_m2_s3):
    """Exact discretization of CW over ``dt_s``: ``(Phi (6, 6), Q (6, 6))``.

    Van Loan: ``expm([[-F, G q G^T], [0, F^T]] dt) = [[., Phi^-1 Q], [0, Phi^T]]``, with
    ``G = [0; I]`` and white acceleration of PSD ``q_m2_s3`` (m^2/s^3) on each axis.
    """
    from scipy.linalg import expm

    F = cw_system(n_rad_s)
    Gq = np.zeros((6, 6))
    Gq[3:, 3:] = q_m2_s3 * np.eye(3)
    M = np.zeros((12, 12))
    M[:6, :6] = -F
    M[:6, 6:] = Gq
    M[6:, 6:] = F.T
    E = expm(M * dt_s)
    Phi = E[6:, 6:].T
    Q = Phi @ E[:6, 6:]
    return Phi, 0.5 * (Q + Q.T)


def circular_relative_orbit(radius_m, n_rad_s, t_s, phase_rad=0.0):
    """Closed CW relative orbit of constant separation ``radius_m``: (N, 6) LVLH states.

    ``r = [rho/2 cos th, -rho sin th, sqrt(3)/2 rho cos th]``, ``th = n t + phase``: a circle
    of radius rho in the plane spanned by ``(1/2, 0, sqrt(3)/2)`` and ``(0, -1, 0)``.
    """
    t = np.asarray(t_s, dtype=float)
    th = n_rad_s * t + phase_rad
    c, s = np.cos(th), np.sin(th)
    rho = radius_m
    r = np.stack([0.5 * rho * c, -rho * s, 0.5 * np.sqrt(3.0) * rho * c], axis=-1)
    v = n_rad_s * np.stack([-0.5 * rho * s, -rho * c, -0.5 * np.sqrt(3.0) * rho * s], axis=-1)
    return np.concatenate([r, v], axis=-1)


def lvlh_from_eci(r_eci_m, v_eci_mps):
    """``R_lvlh_from_eci`` (3, 3) and the frame's angular velocity ``omega`` (rad/s, LVLH)."""
    r = np.asarray(r_eci_m, dtype=float)
    v = np.asarray(v_eci_mps, dtype=float)
    C = rtn_frame(np.concatenate([r, v]))   # (the one writing of the frame: fgnav.frames)
    w = np.array([0.0, 0.0, np.linalg.norm(np.cross(r, v)) / np.dot(r, r)])
    return C, w


def chief_circular_state(alt_km=500.0, inc_deg=97.4, mu=MU_EARTH_M3_S2):
    """ECI state (6,) of a circular chief orbit at ``alt_km``, inclination ``inc_deg``."""
    a = R_EARTH_M + 1e3 * alt_km
    v = np.sqrt(mu / a)
    i = np.deg2rad(inc_deg)
    return np.array([a, 0.0, 0.0, 0.0, v * np.cos(i), v * np.sin(i)])


def two_body_relative_truth(x_chief_eci, x_rel_lvlh0, t_s, mu=MU_EARTH_M3_S2):
    """Relative LVLH states (N, 6) from two independently integrated two-body orbits.

    The deputy's ECI state at ``t_s[0]`` (taken as 0) is ``r_c + C^T r_rel``,
    ``v_c + C^T (v_rel + omega x r_rel)``; both orbits are integrated with scipy DOP853
    (rtol 1e-12, atol 1e-6 m) and differenced: ``r_rel = C (r_d - r_c)``,
    ``v_rel = C (v_d - v_c) - omega x r_rel``.
    """
    from scipy.integrate import solve_ivp

    t = np.asarray(t_s, dtype=float)
    xc = np.asarray(x_chief_eci, dtype=float)
    xr = np.asarray(x_rel_lvlh0, dtype=float)
    C, w = lvlh_from_eci(xc[:3], xc[3:])
    xd = np.concatenate([xc[:3] + C.T @ xr[:3], xc[3:] + C.T @ (xr[3:] + np.cross(w, xr[:3]))])

    def rhs(_, y):
        out = np.empty(12)
        for k in (0, 6):
            r = y[k:k + 3]
            out[k:k + 3] = y[k + 3:k + 6]
            out[k + 3:k + 6] = -mu * r / np.linalg.norm(r) ** 3
        return out

    sol = solve_ivp(rhs, (t[0], t[-1]), np.concatenate([xc, xd]), method="DOP853",
                    t_eval=t, rtol=1e-12, atol=1e-6)
    if not sol.success:  # pragma: no cover
        raise RuntimeError(f"two-body truth integration failed: {sol.message}")
    Y = sol.y.T
    out = np.empty((t.size, 6))
    for k in range(t.size):
        Ck, wk = lvlh_from_eci(Y[k, :3], Y[k, 3:6])
        dr = Ck @ (Y[k, 6:9] - Y[k, :3])
        out[k, :3] = dr
        out[k, 3:] = Ck @ (Y[k, 9:12] - Y[k, 3:6]) - np.cross(wk, dr)
    return out
