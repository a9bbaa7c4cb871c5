"""Inter-satellite pseudorange (and carrier phase) between two formation satellites.

Measurement model (Xing et al., eq. (1), NASA ST-3
Autonomous Formation Flyer). Two 1 m cubes, each with one transmit antenna ``a_i0`` and
three receive antennas ``a_ij`` (j = 1, 2, 3) on one face, in its own body frame (m)::

    rho_1j = |r + M21 a_20 - a_1j| + c dt      (sat 2 transmits, sat 1 antenna j receives)
    rho_2j = |-r + a_10 - M21 a_2j| - c dt     (sat 1 transmits, sat 2 antenna j receives)

``r`` (m): position of sat 2's centre of mass in sat 1's body frame (Xing et al.'s
"constellation frame"); ``M21`` = Xing et al.'s ``M_BC``, the rotation taking sat-2 body
vectors to sat-1 body vectors (``M_BC = (M_CB)^-1``, ``M_CB = Rx(roll) Ry(pitch) Rz(yaw)``);
``c dt`` (m) the relative clock bias (receiver-1 clock minus receiver-2 clock, times c).
Since ``|-r + a_10 - M21 a_2j| = |r + M21 a_2j - a_10|``, all six links are written
``rho_l = |r + d_l| + s_l c dt`` with the known offsets ``d_l`` (sat-1 body, m) and clock
signs ``s_l = +1, +1, +1, -1, -1, -1`` (:func:`link_offsets`). Xing et al.'s linearized rows
(its eqs. (2)-(3): line-of-sight unit vector, then +1 / -1) agree with this sign
convention; no discrepancy was found.

Two parameterizations of ``r``, one model, two tangent spaces:
- Cartesian ``(x, y, z)`` (m);
- spherical ``(R, az, el)`` (m, rad, rad): ``r = R [cos el cos az, cos el sin az, sin el]``
  (Xing et al. section 2; ``az`` about body z from +x, ``el`` from the x-y plane).

Carrier phase (optional, 10 um in Xing et al.'s ref. [1]): ``phi_l = |r + d_l| + s_l c dt + N_l``
with a float ambiguity ``N_l`` (m) per link, constant while the link stays locked.

Residuals follow the contract of CONTRIBUTING.md: unwhitened error ``e = h(x) - z`` (m) and
analytic Jacobians with respect to each variable.
"""

from __future__ import annotations

import numpy as np

from factors.adapters import custom_factor

__all__ = [
    "ANTENNA_TX_BODY_M", "ANTENNA_RX_BODY_M", "N_LINKS", "CLOCK_SIGNS",
    "rotation_xyz", "m21_from_rpy", "link_offsets",
    "spherical_to_cartesian", "cartesian_to_spherical",
    "predict_ranges", "pseudorange_residual", "pseudorange_residual_spherical",
    "offset_range_residual",
    "carrier_residual", "carrier_residual_spherical",
    "make_pseudorange_factor", "make_carrier_factor",
]

ANTENNA_TX_BODY_M = np.array([0.5, 0.5, -0.5])
"""Transmit antenna a_i0 in each satellite's body frame, m (Xing et al., same on both)."""
ANTENNA_RX_BODY_M = np.array([[0.5, 0.5, 0.5], [0.5, -0.5, 0.5], [0.5, -0.5, -0.5]])
"""Receive antennas a_i1, a_i2, a_i3 in each satellite's body frame, m (Xing et al.)."""
N_LINKS = 6
"""Pseudoranges per epoch: sat 1 receives on 3 antennas, sat 2 on 3."""
CLOCK_SIGNS = np.array([1.0, 1.0, 1.0, -1.0, -1.0, -1.0])
"""Sign of c dt in each link (Xing et al. eq. (1))."""


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_xyz(roll_rad, pitch_rad, yaw_rad):
    """Xing et al.'s ``M_CB = Rx(roll) Ry(pitch) Rz(yaw)`` (sat-1 body -> sat-2 body), (3, 3).

    ``Rx, Ry, Rz`` are coordinate-transformation (passive) elementary rotations, e.g.
    ``Rz(a) = [[cos a, sin a, 0], [-sin a, cos a, 0], [0, 0, 1]]``.
    """
    return _rx(roll_rad) @ _ry(pitch_rad) @ _rz(yaw_rad)


def m21_from_rpy(roll_rad, pitch_rad, yaw_rad):
    """``M21 = M_BC = (M_CB)^T``: sat-2 body vectors -> sat-1 body vectors, (3, 3)."""
    return rotation_xyz(roll_rad, pitch_rad, yaw_rad).T


def link_offsets(M21, tx_body_m=ANTENNA_TX_BODY_M, rx_body_m=ANTENNA_RX_BODY_M):
    """Per-link antenna offsets ``d_l`` (sat-1 body, m) so that the range is ``|r + d_l|``.

    Parameters
    ----------
    M21 : (3, 3) or (N, 3, 3), sat-2 body -> sat-1 body.
    tx_body_m : (3,), transmit antenna (same on both satellites), m.
    rx_body_m : (3, 3), receive antennas (rows), m.

    Returns
    -------
    d : (N, 6, 3) (or (6, 3) for one M21): rows 0-2 ``M21 a_20 - a_1j``, rows 3-5
        ``M21 a_2j - a_10``.
    """
    M = np.asarray(M21, dtype=float)
    single = M.ndim == 2
    M = M[None] if single else M
    tx = np.asarray(tx_body_m, dtype=float)
    rx = np.asarray(rx_body_m, dtype=float)
    d = np.empty((M.shape[0], N_LINKS, 3))
    d[:, :3] = (M @ tx)[:, None, :] - rx[None]
    d[:, 3:] = np.einsum("nab,jb->nja", M, rx) - tx
    return d[0] if single else d


def spherical_to_cartesian(s):
    """``r = R [cos el cos az, cos el sin az, sin el]`` and ``J = dr/d(R, az, el)``.

    Parameters
    ----------
    s : (N, 3) or (3,): range R (m), azimuth az (rad), elevation el (rad).

    Returns
    -------
    r : (N, 3) m; J : (N, 3, 3), columns d r/dR (unit), d r/d az (m/rad), d r/d el (m/rad).
    """
    s = np.asarray(s, dtype=float)
    single = s.ndim == 1
    s = np.atleast_2d(s)
    R, az, el = s[:, 0], s[:, 1], s[:, 2]
    ca, sa, ce, se = np.cos(az), np.sin(az), np.cos(el), np.sin(el)
    u = np.stack([ce * ca, ce * sa, se], axis=-1)
    J = np.empty((s.shape[0], 3, 3))
    J[:, :, 0] = u
    J[:, :, 1] = (R[:, None] * np.stack([-ce * sa, ce * ca, np.zeros_like(ce)], axis=-1))
    J[:, :, 2] = (R[:, None] * np.stack([-se * ca, -se * sa, ce], axis=-1))
    r = R[:, None] * u
    return (r[0], J[0]) if single else (r, J)


def cartesian_to_spherical(r):
    """Inverse of :func:`spherical_to_cartesian`: ``(R, az, el)`` (m, rad, rad), az in (-pi, pi]."""
    r = np.asarray(r, dtype=float)
    R = np.linalg.norm(r, axis=-1)
    az = np.arctan2(r[..., 1], r[..., 0])
    el = np.arcsin(np.clip(r[..., 2] / R, -1.0, 1.0))
    return np.stack([R, az, el], axis=-1)


def _as_batch(r, cdt, z, M21):
    r = np.asarray(r, dtype=float)
    single = r.ndim == 1
    r = np.atleast_2d(r)
    n = r.shape[0]
    cdt = np.broadcast_to(np.asarray(cdt, dtype=float).reshape(-1), (n,))
    z = np.broadcast_to(np.asarray(z, dtype=float).reshape(n, N_LINKS), (n, N_LINKS))
    d = link_offsets(M21)
    d = np.broadcast_to(d, (n, N_LINKS, 3)) if d.ndim == 2 else d
    return single, r, cdt, z, d


def predict_ranges(r_m, cdt_m, M21):
    """Predicted pseudoranges ``|r + d_l| + s_l c dt`` (m), shape (N, 6) (or (6,))."""
    r = np.asarray(r_m, dtype=float)
    z = np.zeros(r.shape[:-1] + (N_LINKS,))
    e = pseudorange_residual(r, cdt_m, z, M21)[0]
    return e


def pseudorange_residual(r_m, cdt_m, rho_meas_m, M21):
    """Pseudorange residual with ``r`` Cartesian (Xing et al. eqs. (1)-(3)).

    Parameters
    ----------
    r_m : (N, 3) or (3,), position of sat 2 in sat-1 body frame, m.
    cdt_m : (N,) or scalar, relative clock bias times c, m.
    rho_meas_m : (N, 6) or (6,), measured pseudoranges, m (link order of :func:`link_offsets`).
    M21 : (3, 3) or (N, 3, 3), sat-2 body -> sat-1 body.

    Returns
    -------
    e : (N, 6) m, ``|r + d_l| + s_l c dt - rho_l``.
    H_r : (N, 6, 3), ``de/dr = u_l^T`` with ``u_l = (r + d_l)/|r + d_l|`` (line of sight).
    H_c : (N, 6, 1), ``de/d(c dt) = s_l``.
    (Single-epoch inputs give (6,), (6, 3), (6, 1).)
    """
    single, r, cdt, z, d = _as_batch(r_m, cdt_m, rho_meas_m, M21)
    e, H_r, H_c = offset_range_residual(r, cdt, z, d, CLOCK_SIGNS)
    return (e[0], H_r[0], H_c[0]) if single else (e, H_r, H_c)


def offset_range_residual(r_m, cdt_m, rho_meas_m, d_m, signs):
    """The same model for any links: ``e_l = |r + d_l| + s_l c dt - rho_l`` (m).

    ``r_m`` (N, 3) sat-2 position in the sat-1 body frame; ``cdt_m`` (N,); ``rho_meas_m``
    (N, L); ``d_m`` (N, L, 3) or (L, 3) the links' antenna offsets in the sat-1 body frame
    (``M21 a_2 - a_1`` for a link that sat 1 receives from sat 2: :func:`link_offsets` for
    Xing et al.'s antennas); ``signs`` (L,) the clock sign ``s_l`` (+1 when sat 1 receives).
    Returns ``e (N, L)``, ``H_r (N, L, 3)`` (line-of-sight unit vectors), ``H_c (N, L, 1)``.
    """
    r = np.asarray(r_m, dtype=float)
    s = np.asarray(signs, dtype=float)
    v = r[:, None, :] + np.asarray(d_m, dtype=float)
    rng = np.linalg.norm(v, axis=-1)
    e = rng + s * np.asarray(cdt_m, dtype=float)[:, None] - np.asarray(rho_meas_m, dtype=float)
    H_r = v / rng[..., None]
    H_c = np.broadcast_to(s[None, :, None], (r.shape[0], s.size, 1)).copy()
    return e, H_r, H_c


def pseudorange_residual_spherical(s, cdt_m, rho_meas_m, M21):
    """Pseudorange residual with ``r`` spherical ``(R m, az rad, el rad)``.

    Same model as :func:`pseudorange_residual` through ``r = r(s)``; chain rule
    ``de/ds = u_l^T J(s)`` (Xing et al. section 2, its matrix A').

    Returns ``e (N, 6)``, ``H_s (N, 6, 3)`` (m/m, m/rad, m/rad), ``H_c (N, 6, 1)``.
    """
    s = np.asarray(s, dtype=float)
    r, J = spherical_to_cartesian(s)
    e, H_r, H_c = pseudorange_residual(r, cdt_m, rho_meas_m, M21)
    return e, H_r @ J, H_c


def carrier_residual(r_m, cdt_m, amb_m, phi_meas_m, M21):
    """Carrier-phase residual ``|r + d_l| + s_l c dt + N_l - phi_l`` (m), Cartesian ``r``.

    Parameters as :func:`pseudorange_residual`, plus ``amb_m`` (6,) or (N, 6): float
    ambiguities (m), one per link. Returns ``e (N, 6)``, ``H_r (N, 6, 3)``, ``H_c (N, 6, 1)``,
    ``H_amb (N, 6, 6)`` (identity).
    """
    single = np.asarray(r_m).ndim == 1
    e, H_r, H_c = pseudorange_residual(r_m, cdt_m, phi_meas_m, M21)
    amb = np.asarray(amb_m, dtype=float)
    e = e + amb
    n = 1 if single else e.shape[0]
    H_a = np.broadcast_to(np.eye(N_LINKS), (n, N_LINKS, N_LINKS)).copy()
    return (e, H_r, H_c, H_a[0]) if single else (e, H_r, H_c, H_a)


def carrier_residual_spherical(s, cdt_m, amb_m, phi_meas_m, M21):
    """Carrier-phase residual with spherical ``r`` (see :func:`carrier_residual`)."""
    r, J = spherical_to_cartesian(np.asarray(s, dtype=float))
    e, H_r, H_c, H_a = carrier_residual(r, cdt_m, amb_m, phi_meas_m, M21)
    return e, H_r @ J, H_c, H_a


def make_pseudorange_factor(key_pos, key_clock, rho_meas_m, M21, sigma_m, param="cartesian"):
    """``gtsam.CustomFactor`` for the six pseudoranges of one epoch.

    ``key_pos``: Vector3 key (Cartesian r m, or spherical (R, az, el)); ``key_clock``:
    Vector1 key (c dt, m); ``sigma_m``: code noise (m), float or (6,).
    """
    res = _residual_for(param, pseudorange_residual, pseudorange_residual_spherical)
    z = np.asarray(rho_meas_m, dtype=float).copy()
    M = np.asarray(M21, dtype=float).copy()

    def residual(values):
        p = np.asarray(values.atVector(key_pos), dtype=float)
        c = float(values.atVector(key_clock)[0])
        e, H_p, H_c = res(p, c, z, M)
        return e, [H_p, H_c]

    return custom_factor([key_pos, key_clock], sigma_m, residual, dim=N_LINKS)


def make_carrier_factor(key_pos, key_clock, key_amb, phi_meas_m, M21, sigma_m, param="cartesian"):
    """``gtsam.CustomFactor`` for the six carrier phases of one epoch (``key_amb``: Vector6, m)."""
    res = _residual_for(param, carrier_residual, carrier_residual_spherical)
    z = np.asarray(phi_meas_m, dtype=float).copy()
    M = np.asarray(M21, dtype=float).copy()

    def residual(values):
        p = np.asarray(values.atVector(key_pos), dtype=float)
        c = float(values.atVector(key_clock)[0])
        a = np.asarray(values.atVector(key_amb), dtype=float)
        e, H_p, H_c, H_a = res(p, c, a, z, M)
        return e, [H_p, H_c, H_a]

    return custom_factor([key_pos, key_clock, key_amb], sigma_m, residual, dim=N_LINKS)


def _residual_for(param, cart, sph):
    if param == "cartesian":
        return cart
    if param == "spherical":
        return sph
    raise ValueError(f"param must be 'cartesian' or 'spherical', got {param!r}")
