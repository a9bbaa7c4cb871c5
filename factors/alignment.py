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

from factors.adapters import custom_factor, rot3_matrix
from factors.direction import star_direction_residual
from factors.geometry import tangent_basis

__all__ = ["aligned_star_direction_residual", "make_aligned_star_direction_factor"]


def aligned_star_direction_residual(R_eci_from_body, R_body_from_cam, s_eci, u_meas_cam, B=None):
    """Star direction measured by a separately mounted star camera (module docstring).

    Parameters
    ----------
    R_eci_from_body : (N, 3, 3) attitude ``A``; R_body_from_cam : (N, 3, 3) the camera's
    mounting ``M``; s_eci : (N, 3) catalogue unit direction, ECI; u_meas_cam : (N, 3)
    measured unit direction, star-camera frame; B : (N, 2, 3), optional
    ``tangent_basis(u_meas_cam)``.

    Returns
    -------
    e : (N, 2) rad; H_A : (N, 2, 3) rad/rad (attitude); H_M : (N, 2, 3) rad/rad (mounting).
    """
    A = np.asarray(R_eci_from_body, dtype=float)
    M = np.asarray(R_body_from_cam, dtype=float)
    e, H_C = star_direction_residual(A @ M, s_eci, u_meas_cam, B)
    return e, H_C @ np.swapaxes(M, -1, -2), H_C


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
