"""Orbit frames, written once: RTN of a state, the chief's LVLH frame and a deputy's state
relative to the chief in it (or in the chief's body frame), with Jacobians and covariances.

RTN / LVLH of a state ``x = [r; v]`` (Vallado 2013, *Fundamentals of Astrodynamics and
Applications*, sec. 3.3, the RSW frame; the Clohessy-Wiltshire / Hill frame, x radial):
``x = r/|r|`` (radial, R), ``z = h/|h|`` with ``h = r x v`` (orbit normal, N), ``y = z x x``
(along-track T, along the velocity for a circular orbit). ``C = R_lvlh_from_eci`` has the rows
``x, y, z`` (:func:`rtn_frame`, :func:`lvlh_axes`). The relative state is position and the
rate seen in the rotating frame
(the Hill frame of Clohessy & Wiltshire 1960, "Terminal guidance system for satellite
rendezvous", *J. Aerospace Sciences* 27(9); the rotating-frame derivative by the transport
theorem, Schaub & Junkins 2018, *Analytical Mechanics of Space Systems*, 4th ed., ch. 14)::

    rho   = C (r_d - r_c)
    rho'  = C (v_d - v_c) - omega x rho,     omega = (0, 0, |h|/|r|^2)   (LVLH, rad/s)

``omega`` is the frame's rate for a Keplerian chief (exact when the chief's acceleration is
radial; a perturbing acceleration ``a_N`` along the normal adds ``r a_N/|h|`` about x, about
1.5e-6 rad/s for J2 in LEO, i.e. 1.5 mm/s on a 1 km separation, which this definition, like
``relative_motion.two_body_relative_truth``, leaves out: it needs no acceleration and is a
function of the two states alone).

Jacobians (derivation; ``dr``, ``dv`` the chief's perturbations, ``D* = d*/d[r_c; v_c]``
(3, 6)): ``Dx = [(I - x x^T)/|r|, 0]``, ``Dh = [-skew(v), skew(r)]``,
``Dz = (I - z z^T)/|h| Dh``, ``Dy = -skew(x) Dz + skew(z) Dx``,
``D omega_z = z^T Dh/|r|^2 - [2 |h| x^T/|r|^3, 0]``; with ``w`` an ECI vector held fixed,
``d(C w) = [w^T Dx; w^T Dy; w^T Dz]``. Then, with ``K = skew(e_z)``::

    d rho/dx_c  = dC(dr_eci) - [C, 0],          d rho/dx_d  = [C, 0]
    d rho'/dx_c = dC(dv_eci) - [0, C] - K rho D omega_z - omega_z K d rho/dx_c
    d rho'/dx_d = [-omega_z K C, C]

In the chief's body frame (``R = R_eci_from_body`` of the chief, ``omega`` its inertial rate
in body axes): ``r_body = R^T (r_d - r_c)`` (Xing et al.'s ``r``, factors.pseudorange) and
``v_body = R^T (v_d - v_c) - omega x r_body`` (:func:`relative_state_body`).

Covariances: the relative covariance of the joint covariance ``P`` of ``[x_c; x_d]`` is
``J P J^T`` with ``J = [J_c, J_d]`` (first-order propagation, exact for the linear map of
the body-frame position and accurate to ``sigma/|r|`` in LVLH).
"""

from __future__ import annotations

import numpy as np

from factors.geometry import skew

__all__ = [
    "rtn_frame", "lvlh_axes", "relative_state_lvlh", "deputy_from_relative_lvlh", "relative_position_body",
    "relative_state_body", "relative_covariance", "relative_covariance_lvlh", "relative_covariance_body",
]

_K = skew(np.array([0.0, 0.0, 1.0]))


def _states(x):
    x = np.asarray(x, dtype=float)
    if x.ndim != 2 or x.shape[1] != 6:
        raise ValueError(f"states must have shape (N, 6), got {x.shape}")
    return x


def rtn_frame(x):
    """Radial/along-track/cross-track frame of ECI state(s): rows R, T, N.

    R = r/|r|, N = (r x v)/|r x v|, T = N x R. ``x`` (6,) -> (3,3) ``R_rtn_from_eci``
    (so ``d_rtn = rtn_frame(x) @ d_eci``); (N,6) -> (N,3,3).
    """
    x = np.asarray(x, dtype=float)
    r, v = x[..., :3], x[..., 3:6]
    R = r / np.linalg.norm(r, axis=-1, keepdims=True)
    h = np.cross(r, v)
    N = h / np.linalg.norm(h, axis=-1, keepdims=True)
    T = np.cross(N, R)
    return np.stack([R, T, N], axis=-2)


def lvlh_axes(x_chief):
    """``C = R_lvlh_from_eci`` (N, 3, 3) (rows x radial, y along-track, z normal) and the
    Keplerian frame rate ``omega_z = |h|/|r|^2`` (N,), rad/s, of chief states (N, 6)."""
    x = _states(x_chief)
    hn = np.linalg.norm(np.cross(x[:, :3], x[:, 3:]), axis=1)
    return rtn_frame(x), hn / np.linalg.norm(x[:, :3], axis=1) ** 2


def relative_state_lvlh(x_chief, x_deputy):
    """The deputy's ``[rho m; rho' m/s]`` in the chief's LVLH frame (module docstring).

    Parameters
    ----------
    x_chief, x_deputy : (N, 6) ECI states ``[r m; v m/s]``.

    Returns
    -------
    rel : (N, 6) ``[C (r_d - r_c); C (v_d - v_c) - omega x rho]``, LVLH, m and m/s.
    J_chief : (N, 6, 6) ``d rel/d x_chief``.
    J_deputy : (N, 6, 6) ``d rel/d x_deputy``.
    """
    xc = _states(x_chief)
    xd = _states(x_deputy)
    n = xc.shape[0]
    r, v = xc[:, :3], xc[:, 3:]
    C, wz = lvlh_axes(xc)
    ex, ey, ez = C[:, 0], C[:, 1], C[:, 2]
    rn = np.linalg.norm(r, axis=1)
    h = np.cross(r, v)
    hn = np.linalg.norm(h, axis=1)
    dr = xd[:, :3] - r
    dv = xd[:, 3:] - v
    rho = np.einsum("nij,nj->ni", C, dr)
    rhod = np.einsum("nij,nj->ni", C, dv) - wz[:, None] * (rho @ _K.T)

    eye = np.eye(3)
    Dx = np.zeros((n, 3, 6))
    Dx[:, :, :3] = (eye - ex[:, :, None] * ex[:, None, :]) / rn[:, None, None]
    Dh = np.concatenate([-skew(v), skew(r)], axis=2)
    Dz = np.einsum("nij,njk->nik", (eye - ez[:, :, None] * ez[:, None, :]) / hn[:, None, None],
                   Dh)
    Dy = -np.einsum("nij,njk->nik", skew(ex), Dz) + np.einsum("nij,njk->nik", skew(ez), Dx)
    Dw = np.einsum("ni,nik->nk", ez, Dh) / rn[:, None] ** 2
    Dw[:, :3] -= 2.0 * (hn / rn ** 3)[:, None] * ex

    def dC(w):  # d(C w)/dx_c for a fixed ECI vector w, (n, 3, 6)
        return np.stack([np.einsum("ni,nik->nk", w, D) for D in (Dx, Dy, Dz)], axis=1)

    J_c = np.zeros((n, 6, 6))
    J_c[:, :3] = dC(dr)
    J_c[:, :3, :3] -= C
    J_c[:, 3:] = dC(dv)
    J_c[:, 3:, 3:] -= C
    J_c[:, 3:] -= (rho @ _K.T)[:, :, None] * Dw[:, None, :]
    J_c[:, 3:] -= wz[:, None, None] * np.einsum("ij,njk->nik", _K, J_c[:, :3])

    J_d = np.zeros((n, 6, 6))
    J_d[:, :3, :3] = C
    J_d[:, 3:, 3:] = C
    J_d[:, 3:, :3] = -wz[:, None, None] * np.einsum("ij,njk->nik", _K, C)
    return np.concatenate([rho, rhod], axis=1), J_c, J_d


def deputy_from_relative_lvlh(x_chief, rel_lvlh):
    """Inverse of :func:`relative_state_lvlh`: the deputy's ECI states (N, 6).

    ``r_d = r_c + C^T rho``, ``v_d = v_c + C^T (rho' + omega x rho)``.
    """
    xc = _states(x_chief)
    rel = _states(rel_lvlh)
    C, wz = lvlh_axes(xc)
    rho, rhod = rel[:, :3], rel[:, 3:]
    w_x_rho = wz[:, None] * (rho @ _K.T)
    r_d = xc[:, :3] + np.einsum("nji,nj->ni", C, rho)
    v_d = xc[:, 3:] + np.einsum("nji,nj->ni", C, rhod + w_x_rho)
    return np.concatenate([r_d, v_d], axis=1)


def relative_position_body(x_chief, x_deputy, R_eci_from_body_chief):
    """The deputy's position in the chief's body frame, ``r_body = R^T (r_d - r_c)`` (m).

    Parameters
    ----------
    x_chief, x_deputy : (N, 6) ECI states.
    R_eci_from_body_chief : (N, 3, 3) the chief's attitude ``R_eci_from_body``.

    Returns
    -------
    r_body : (N, 3) m (Xing et al.'s ``r``, sat 2 in sat 1's body frame, factors.pseudorange).
    J_chief : (N, 3, 6) ``[-R^T, 0]``.
    J_deputy : (N, 3, 6) ``[R^T, 0]``.
    J_attitude : (N, 3, 3) ``skew(r_body)``, with respect to the right perturbation
        ``R <- R Exp(w)`` (``Exp(-w) R^T d ~ R^T d + skew(R^T d) w``), m/rad.
    """
    xc = _states(x_chief)
    xd = _states(x_deputy)
    R = np.asarray(R_eci_from_body_chief, dtype=float)
    Rt = np.swapaxes(R, -1, -2)
    r_body = np.einsum("nij,nj->ni", Rt, xd[:, :3] - xc[:, :3])
    n = xc.shape[0]
    J_c = np.zeros((n, 3, 6))
    J_d = np.zeros((n, 3, 6))
    J_c[:, :, :3] = -Rt
    J_d[:, :, :3] = Rt
    return r_body, J_c, J_d, skew(r_body)


def relative_state_body(x_chief, x_deputy, R_eci_from_body_chief, omega_body_rad_s=None):
    """The deputy's ``[r_body m; v_body m/s]`` in the chief's body frame, as seen rotating
    with the body (transport theorem, as for LVLH)::

        r_body = R^T (r_d - r_c),     v_body = R^T (v_d - v_c) - omega x r_body

    Parameters
    ----------
    x_chief, x_deputy : (N, 6) ECI states.
    R_eci_from_body_chief : (N, 3, 3) the chief's attitude.
    omega_body_rad_s : (N, 3) the chief's inertial angular velocity in its body frame (rad/s);
        None: zero (``v_body`` is then the ECI relative velocity in body axes).

    Returns
    -------
    rel : (N, 6); J_chief, J_deputy : (N, 6, 6);
    J_attitude : (N, 6, 3) for the right perturbation of ``R``
        (``[skew(r_body); skew(R^T dv) - skew(omega) skew(r_body)]``);
    J_omega : (N, 6, 3) ``[0; skew(r_body)]``.
    """
    r_body, J_cp, J_dp, J_att_p = relative_position_body(x_chief, x_deputy,
                                                        R_eci_from_body_chief)
    xc = _states(x_chief)
    xd = _states(x_deputy)
    n = xc.shape[0]
    w = (np.zeros((n, 3)) if omega_body_rad_s is None
         else np.broadcast_to(np.asarray(omega_body_rad_s, dtype=float), (n, 3)))
    Rt = -J_cp[:, :, :3]
    W = skew(w)
    v_rot = np.einsum("nij,nj->ni", Rt, xd[:, 3:] - xc[:, 3:])
    v_body = v_rot - np.cross(w, r_body)
    WRt = np.einsum("nij,njk->nik", W, Rt)
    J_c = np.zeros((n, 6, 6))
    J_d = np.zeros((n, 6, 6))
    J_c[:, :3] = J_cp
    J_d[:, :3] = J_dp
    J_c[:, 3:, :3] = WRt
    J_c[:, 3:, 3:] = -Rt
    J_d[:, 3:, :3] = -WRt
    J_d[:, 3:, 3:] = Rt
    J_att = np.concatenate([J_att_p, skew(v_rot) - np.einsum("nij,njk->nik", W, J_att_p)],
                           axis=1)
    J_w = np.concatenate([np.zeros((n, 3, 3)), skew(r_body)], axis=1)
    return np.concatenate([r_body, v_body], axis=1), J_c, J_d, J_att, J_w


def relative_covariance(J_chief, J_deputy, P_joint):
    """``J P J^T`` with ``J = [J_chief, J_deputy]`` (N, m, 12): the (N, m, m) covariance of a
    relative quantity from the joint (N, 12, 12) covariance of ``[x_chief; x_deputy]``
    (symmetrized)."""
    J = np.concatenate([np.asarray(J_chief, dtype=float), np.asarray(J_deputy, dtype=float)],
                       axis=2)
    P = np.asarray(P_joint, dtype=float)
    if P.shape[-2:] != (J.shape[2], J.shape[2]):
        raise ValueError(f"joint covariance must be (N, {J.shape[2]}, {J.shape[2]}), "
                         f"got {P.shape}")
    out = np.einsum("nij,njk,nlk->nil", J, P, J)
    return 0.5 * (out + np.swapaxes(out, -1, -2))


def relative_covariance_lvlh(x_chief, x_deputy, P_joint):
    """(N, 6, 6) covariance of :func:`relative_state_lvlh` from the joint (N, 12, 12)
    covariance of ``[x_chief; x_deputy]`` (SI)."""
    _, J_c, J_d = relative_state_lvlh(x_chief, x_deputy)
    return relative_covariance(J_c, J_d, P_joint)


def relative_covariance_body(x_chief, x_deputy, R_eci_from_body_chief, P_joint,
                             omega_body_rad_s=None):
    """(N, 6, 6) covariance of :func:`relative_state_body` (known attitude and rate) from the
    joint (N, 12, 12) covariance of ``[x_chief; x_deputy]`` (SI); its upper-left (N, 3, 3)
    block is the covariance of :func:`relative_position_body`."""
    _, J_c, J_d, _, _ = relative_state_body(x_chief, x_deputy, R_eci_from_body_chief,
                                            omega_body_rad_s)
    return relative_covariance(J_c, J_d, P_joint)
