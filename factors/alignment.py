"""A star camera mounted apart from the Earth (limb) camera: star directions through a
constant camera alignment.

The body frame is the Earth camera's frame (the frame the body-frame Earth, Sun and Moon
directions are measured in) and the attitude variable ``A = R_eci_from_body``. A star camera
on its own mount measures its stars in its own frame, turned from the body by the mounting
rotation ``M = R_body_from_starcam`` (close to a nominal rotation, wrong by the mounting
misalignment of a few tens of arcseconds). A star of catalogue direction ``s`` (ECI) is then
seen at

    u_cam = (A M)^T s,

the star-direction model of :func:`factors.direction.star_direction_residual` with the
rotation ``C = A M = R_eci_from_starcam`` (Shuster & Pitone 1991, "Batch estimation of
spacecraft sensor alignments I. Relative alignment estimation", J. Astronautical Sciences
39(4): a sensor's observation in its own frame through the alignment matrix).

Jacobians (right perturbations, ``R <- R Exp(w)``): with ``H_C`` the star residual's
Jacobian with respect to ``C``,

* alignment: ``A M Exp(w_M) = C Exp(w_M)``, so ``H_M = H_C``;
* attitude: ``A Exp(w_A) M = A M Exp(M^T w_A)`` (``Exp(w) M = M Exp(M^T w)``, the adjoint
  of SO(3); Sola, Deray & Atchuthan 2018, "A micro Lie theory for state estimation in
  robotics", sec. on the adjoint: Ad_M = M on SO(3)), so ``H_A = H_C M^T``.
"""

from __future__ import annotations

import functools

import numpy as np

from factors.adapters import custom_factor, rot3_matrix, vector_state
from factors.direction import star_direction_apparent_residual
from factors.geometry import tangent_basis

__all__ = ["aligned_star_direction_residual", "aligned_star_direction_apparent_residual",
           "make_aligned_star_direction_factor", "make_aligned_star_direction_apparent_factor"]


def aligned_star_direction_apparent_residual(R_eci_from_body, R_body_from_cam, s_eci,
                                             v_observer_bcrs_mps, u_meas_cam, B=None):
    """Star direction measured by a separately mounted star camera (module docstring), the
    catalogue direction first aberrated by the observer's velocity
    (:func:`factors.direction.star_direction_apparent_residual` with ``C = A M``).

    Parameters
    ----------
    R_eci_from_body : (N, 3, 3) attitude ``A``; R_body_from_cam : (N, 3, 3) the camera's
    mounting ``M``; s_eci : (N, 3) catalogue unit direction, ECI; v_observer_bcrs_mps : (N, 3)
    the observer's barycentric velocity, m/s, or None (no aberration); u_meas_cam : (N, 3)
    measured unit direction, star-camera frame; B : (N, 2, 3), optional
    ``tangent_basis(u_meas_cam)``.

    Returns
    -------
    e : (N, 2) rad; H_A : (N, 2, 3) rad/rad (attitude); H_M : (N, 2, 3) rad/rad (mounting);
    H_v : (N, 2, 3) rad/(m/s) (the observer's velocity).
    """
    A = np.asarray(R_eci_from_body, dtype=float)
    M = np.asarray(R_body_from_cam, dtype=float)
    e, H_C, H_v = star_direction_apparent_residual(A @ M, s_eci, v_observer_bcrs_mps,
                                                   u_meas_cam, B)
    return e, H_C @ np.swapaxes(M, -1, -2), H_C, H_v


def aligned_star_direction_residual(R_eci_from_body, R_body_from_cam, s_eci, u_meas_cam, B=None):
    """:func:`aligned_star_direction_apparent_residual` without aberration (the catalogue
    direction taken as seen): ``e, H_A, H_M``."""
    e, H_A, H_M, _ = aligned_star_direction_apparent_residual(
        R_eci_from_body, R_body_from_cam, s_eci, None, u_meas_cam, B)
    return e, H_A, H_M


def _aligned_star(key_A, key_M, s, u_meas, B, values):
    A, M = rot3_matrix(values, key_A), rot3_matrix(values, key_M)
    e, H_A, H_M = aligned_star_direction_residual(A[None], M[None], s, u_meas, B)
    return e[0], [H_A[0], H_M[0]]


def make_aligned_star_direction_factor(key_A, key_M, s_eci, u_meas_cam, sigma_rad):
    """CustomFactor on two ``Rot3`` keys, the attitude ``A`` (R_eci_from_body) and the star
    camera's mounting ``M`` (R_body_from_cam): Jacobians (2, 3) each.

    ``s_eci``: (3,) catalogue direction in ECI; ``u_meas_cam``: (3,) measured, camera frame.
    """
    s = np.asarray(s_eci, dtype=float).reshape(1, 3)
    u = np.asarray(u_meas_cam, dtype=float).reshape(1, 3)
    return custom_factor([key_A, key_M], sigma_rad,
                         functools.partial(_aligned_star, int(key_A), int(key_M), s, u,
                                           tangent_basis(u)), dim=2)


def _aligned_star_apparent(key_x, key_A, key_M, s, v_earth, u_meas, B, values):
    x = vector_state(values, key_x)
    A, M = rot3_matrix(values, key_A), rot3_matrix(values, key_M)
    v_obs = None if v_earth is None else v_earth + x[None, 3:6]
    e, H_A, H_M, H_v = aligned_star_direction_apparent_residual(A[None], M[None], s, v_obs,
                                                                u_meas, B)
    H_x = np.zeros((2, x.shape[0]))
    H_x[:, 3:6] = H_v[0]
    return e[0], [H_x, H_A[0], H_M[0]]


def make_aligned_star_direction_apparent_factor(key_x, key_A, key_M, s_eci, v_earth_bcrs_mps,
                                                u_meas_cam, sigma_rad):
    """CustomFactor on the state ``[r; v]``, the attitude ``A`` and the mounting ``M``: the
    star seen through the mounting, aberrated by the observer's velocity
    ``v_earth_bcrs_mps + v`` (:func:`aligned_star_direction_apparent_residual`; ``None``: no
    aberration). Jacobians (2, 6) (velocity columns only), (2, 3), (2, 3)."""
    s = np.asarray(s_eci, dtype=float).reshape(1, 3)
    u = np.asarray(u_meas_cam, dtype=float).reshape(1, 3)
    v = None if v_earth_bcrs_mps is None else np.asarray(v_earth_bcrs_mps, float).reshape(1, 3)
    return custom_factor([key_x, key_A, key_M], sigma_rad,
                         functools.partial(_aligned_star_apparent, int(key_x), int(key_A),
                                           int(key_M), s, v, u, tangent_basis(u)), dim=2)
