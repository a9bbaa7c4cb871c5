"""Modified equinoctial orbital elements: the maps to and from the Cartesian state, the
analytic Jacobian of the element-to-Cartesian map, and Gauss's variational equations.

The elements ``E = (p, f, g, h, k, L)`` (Walker, Ireland & Owens 1985, "A set of modified
equinoctial orbit elements", Celestial Mechanics 36, eq. 1):

    p = a (1 - e^2)                  semi-latus rectum (m)
    f = e cos(omega + Omega),  g = e sin(omega + Omega)
    h = tan(i/2) cos(Omega),   k = tan(i/2) sin(Omega)
    L = Omega + omega + nu           true longitude (rad)

are regular for every elliptic, parabolic and hyperbolic orbit except the retrograde
equatorial one (i = 180 deg, h and k infinite): no singularity at e = 0 or i = 0, where the
classical set loses omega or Omega.

Element -> Cartesian (Walker et al. 1985, eq. 3; Betts 2010, "Practical Methods for Optimal
Control and Estimation Using Nonlinear Programming", sec. 6.3.2), with ``s^2 = 1 + h^2 + k^2``
and ``w = 1 + f cos L + g sin L``: the equinoctial basis vectors

    f_hat = [1 - k^2 + h^2, 2 h k, -2 k] / s^2,   g_hat = [2 h k, 1 + k^2 - h^2, 2 h] / s^2,

``r = p / w``, ``X = r cos L``, ``Y = r sin L``, ``X' = -sqrt(mu/p) (g + sin L)``,
``Y' = sqrt(mu/p) (f + cos L)``, and ``r_eci = X f_hat + Y g_hat``, ``v_eci = X' f_hat + Y' g_hat``.
The Jacobian ``dc/dE`` (:func:`cartesian_from_mee`) differentiates these lines term by term
(derivation in the function); the inverse map's Jacobian is its matrix inverse.

Gauss's variational equations (:func:`gauss_variational_equations`) give the osculating
elements' rates under a perturbing acceleration in the radial / transverse / normal frame;
their matrix ``B(E)`` is the velocity block of ``(dc/dE)^-1`` in that frame (an impulse
changes the velocity only), which the tests check.

All arrays are vectorized over leading axes: ``x (..., 6)``, ``E (..., 6)``.
"""

from __future__ import annotations

import numpy as np

from factors.constants import MU_EARTH_M3_S2

__all__ = ["mee_from_cartesian", "cartesian_from_mee", "mee_jacobian_inverse",
           "gauss_variational_equations", "gauss_propagate", "ELEMENT_NAMES", "ELEMENT_UNITS"]

ELEMENT_NAMES = ("p", "f", "g", "h", "k", "L")
ELEMENT_UNITS = ("m", "1", "1", "1", "1", "rad")


def _basis(h, k):
    """Equinoctial basis ``f_hat, g_hat`` (..., 3) and their derivatives with respect to h, k."""
    s2 = 1.0 + h * h + k * k
    one = np.ones_like(h)
    zero = np.zeros_like(h)
    Nf = np.stack([1.0 - k * k + h * h, 2.0 * h * k, -2.0 * k], axis=-1)
    Ng = np.stack([2.0 * h * k, 1.0 + k * k - h * h, 2.0 * h], axis=-1)
    fh = Nf / s2[..., None]
    gh = Ng / s2[..., None]
    # d(N/s2)/dh = (dN/dh - (N/s2) ds2/dh) / s2, ds2/dh = 2h (and 2k for k)
    dNf_dh = np.stack([2.0 * h, 2.0 * k, zero], axis=-1)
    dNf_dk = np.stack([-2.0 * k, 2.0 * h, -2.0 * one], axis=-1)
    dNg_dh = np.stack([2.0 * k, -2.0 * h, 2.0 * one], axis=-1)
    dNg_dk = np.stack([2.0 * h, 2.0 * k, zero], axis=-1)
    inv = (1.0 / s2)[..., None]
    dfh_dh = (dNf_dh - fh * (2.0 * h)[..., None]) * inv
    dfh_dk = (dNf_dk - fh * (2.0 * k)[..., None]) * inv
    dgh_dh = (dNg_dh - gh * (2.0 * h)[..., None]) * inv
    dgh_dk = (dNg_dk - gh * (2.0 * k)[..., None]) * inv
    return fh, gh, dfh_dh, dfh_dk, dgh_dh, dgh_dk


def cartesian_from_mee(E, mu=MU_EARTH_M3_S2, jacobian=True):
    """Cartesian state ``x = [r_eci_m; v_eci_mps]`` (..., 6) from the elements ``E`` (..., 6)
    (Walker et al. 1985, eq. 3), and with ``jacobian`` its Jacobian ``dx/dE`` (..., 6, 6).

    Derivation, with ``c = cos L``, ``s = sin L``, ``w = 1 + f c + g s``, ``r = p/w``:
    ``dr/dp = 1/w``, ``dr/df = -p c/w^2``, ``dr/dg = -p s/w^2``, ``dr/dL = p (f s - g c)/w^2``;
    ``dX = c dr`` (+ ``-r s dL``), ``dY = s dr`` (+ ``r c dL``); with ``q = sqrt(mu/p)``,
    ``dX'/dp = q (g + s)/(2p)``, ``dX'/dg = -q``, ``dX'/dL = -q c``, ``dY'/dp = -q (f + c)/(2p)``,
    ``dY'/df = q``, ``dY'/dL = -q s``; h and k enter through the basis alone,
    ``dr_eci/dh = X df_hat/dh + Y dg_hat/dh`` (and the same for k and for the velocity).
    """
    E = np.asarray(E, dtype=float)
    p, f, g, h, k, L = (E[..., i] for i in range(6))
    fh, gh, dfh_dh, dfh_dk, dgh_dh, dgh_dk = _basis(h, k)
    c, s = np.cos(L), np.sin(L)
    w = 1.0 + f * c + g * s
    r = p / w
    X, Y = r * c, r * s
    q = np.sqrt(mu / p)
    VX, VY = -q * (g + s), q * (f + c)
    x = np.concatenate([X[..., None] * fh + Y[..., None] * gh,
                        VX[..., None] * fh + VY[..., None] * gh], axis=-1)
    if not jacobian:
        return x
    w2 = w * w
    dr = [1.0 / w, -p * c / w2, -p * s / w2, p * (f * s - g * c) / w2]   # p, f, g, L
    dX = [c * d for d in dr]
    dY = [s * d for d in dr]
    dX[3] = dX[3] - r * s
    dY[3] = dY[3] + r * c
    zero = np.zeros_like(p)
    dVX = [q * (g + s) / (2.0 * p), zero, -q, -q * c]
    dVY = [-q * (f + c) / (2.0 * p), q, zero, -q * s]
    J = np.empty(E.shape[:-1] + (6, 6))
    for col, i in zip((0, 1, 2, 5), range(4)):
        J[..., :3, col] = dX[i][..., None] * fh + dY[i][..., None] * gh
        J[..., 3:, col] = dVX[i][..., None] * fh + dVY[i][..., None] * gh
    J[..., :3, 3] = X[..., None] * dfh_dh + Y[..., None] * dgh_dh
    J[..., :3, 4] = X[..., None] * dfh_dk + Y[..., None] * dgh_dk
    J[..., 3:, 3] = VX[..., None] * dfh_dh + VY[..., None] * dgh_dh
    J[..., 3:, 4] = VX[..., None] * dfh_dk + VY[..., None] * dgh_dk
    return x, J


def mee_from_cartesian(x, mu=MU_EARTH_M3_S2):
    """Elements ``E`` (..., 6) of the Cartesian states ``x`` (..., 6) (the inverse of
    :func:`cartesian_from_mee`; Walker et al. 1985, sec. 2): ``p = |r x v|^2 / mu``; from the
    unit angular momentum ``w_hat``, ``h = -w_y/(1 + w_z)``, ``k = w_x/(1 + w_z)``; with the
    eccentricity vector ``e = v x (r x v)/mu - r/|r|``, ``f = e . f_hat``, ``g = e . g_hat``;
    ``L = atan2(r . g_hat, r . f_hat)`` in (-pi, pi]. ``ValueError`` for a retrograde
    equatorial orbit (``w_z = -1``) or a zero angular momentum (rectilinear motion)."""
    x = np.asarray(x, dtype=float)
    r, v = x[..., :3], x[..., 3:6]
    hv = np.cross(r, v)
    hn = np.linalg.norm(hv, axis=-1)
    if np.any(~(hn > 0.0)):
        raise ValueError("orbital elements: zero angular momentum (rectilinear motion)")
    wv = hv / hn[..., None]
    den = 1.0 + wv[..., 2]
    if np.any(~(den > 1e-12)):
        raise ValueError("orbital elements: retrograde equatorial orbit (i = 180 deg), where "
                         "the equinoctial elements h, k are infinite")
    h = -wv[..., 1] / den
    k = wv[..., 0] / den
    fh, gh = _basis(h, k)[:2]
    ev = np.cross(v, hv) / mu - r / np.linalg.norm(r, axis=-1, keepdims=True)
    p = hn * hn / mu
    f = np.sum(ev * fh, axis=-1)
    g = np.sum(ev * gh, axis=-1)
    L = np.arctan2(np.sum(r * gh, axis=-1), np.sum(r * fh, axis=-1))
    return np.stack([p, f, g, h, k, L], axis=-1)


def mee_jacobian_inverse(x, mu=MU_EARTH_M3_S2):
    """``dE/dx`` (..., 6, 6) at the Cartesian states ``x``: the inverse of the analytic
    ``dx/dE`` (:func:`cartesian_from_mee`) at ``E = mee_from_cartesian(x)`` (the inverse
    function theorem), and ``E`` itself."""
    E = mee_from_cartesian(x, mu)
    _, J = cartesian_from_mee(E, mu)
    return np.linalg.inv(J), E


def gauss_variational_equations(E, mu=MU_EARTH_M3_S2):
    """Gauss's variational equations in modified equinoctial elements,
    ``dE/dt = A(E) + B(E) a_rtn`` (Walker et al. 1985, eq. 9, as corrected in Betts 2010,
    eq. 6.35), ``a_rtn`` (m/s^2) the perturbing acceleration in the radial / transverse
    (along ``w_hat x r_hat``) / normal (angular momentum) frame. With ``w = 1 + f cos L +
    g sin L``, ``s^2 = 1 + h^2 + k^2``, ``q = sqrt(p/mu)``, ``u = h sin L - k cos L``:

        dp/dt = 2 p q / w a_t
        df/dt = q [ a_r sin L + ((w + 1) cos L + f) a_t / w - u g a_n / w ]
        dg/dt = q [-a_r cos L + ((w + 1) sin L + g) a_t / w + u f a_n / w ]
        dh/dt = q s^2 cos L a_n / (2 w),   dk/dt = q s^2 sin L a_n / (2 w)
        dL/dt = sqrt(mu p) (w / p)^2 + q u a_n / w

    Returns ``A`` (..., 6) (only L moves on a Keplerian orbit) and ``B`` (..., 6, 3).
    """
    E = np.asarray(E, dtype=float)
    p, f, g, h, k, L = (E[..., i] for i in range(6))
    c, s = np.cos(L), np.sin(L)
    w = 1.0 + f * c + g * s
    s2 = 1.0 + h * h + k * k
    q = np.sqrt(p / mu)
    u = h * s - k * c
    zero = np.zeros_like(p)
    B = np.zeros(E.shape[:-1] + (6, 3))
    B[..., 0, 1] = 2.0 * p * q / w
    B[..., 1, :] = np.stack([q * s, q * ((w + 1.0) * c + f) / w, -q * u * g / w], axis=-1)
    B[..., 2, :] = np.stack([-q * c, q * ((w + 1.0) * s + g) / w, q * u * f / w], axis=-1)
    B[..., 3, 2] = q * s2 * c / (2.0 * w)
    B[..., 4, 2] = q * s2 * s / (2.0 * w)
    B[..., 5, 2] = q * u / w
    A = np.stack([zero, zero, zero, zero, zero, np.sqrt(mu * p) * (w / p) ** 2], axis=-1)
    return A, B


def gauss_propagate(E0, dt_s, n_steps, perturbation, mu=MU_EARTH_M3_S2):
    """The elements ``E0`` (..., 6) after ``dt_s`` (s): ``n_steps`` classical fourth-order
    Runge-Kutta steps of Gauss's variational equations (:func:`gauss_variational_equations`),
    the Keplerian rate plus the perturbing acceleration ``perturbation(r_eci_m) -> (..., 3)``
    (m/s^2, ECI: e.g. the J2 term) turned into the radial / transverse / normal frame of the
    osculating state. The lecture's formulation of the motion model (the mean only: a
    transition matrix of this map equals ``(dc/dE_1)^-1 Phi (dc/dE_0)`` of the Cartesian
    flow up to the integration error, because both integrate the same flow)."""
    E = np.array(E0, dtype=float)
    h = float(dt_s) / int(n_steps)

    def rate(E):
        x = cartesian_from_mee(E, mu, jacobian=False)
        r, v = x[..., :3], x[..., 3:]
        rh = r / np.linalg.norm(r, axis=-1, keepdims=True)
        w = np.cross(r, v)
        nh = w / np.linalg.norm(w, axis=-1, keepdims=True)
        th = np.cross(nh, rh)
        a = np.asarray(perturbation(r), dtype=float)
        a_rtn = np.stack([np.sum(a * rh, -1), np.sum(a * th, -1), np.sum(a * nh, -1)], -1)
        A, B = gauss_variational_equations(E, mu)
        return A + np.einsum("...ij,...j->...i", B, a_rtn)

    for _ in range(int(n_steps)):
        k1 = rate(E)
        k2 = rate(E + 0.5 * h * k1)
        k3 = rate(E + 0.5 * h * k2)
        k4 = rate(E + h * k3)
        E = E + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return E
