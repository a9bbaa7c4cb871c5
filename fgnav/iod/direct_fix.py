"""Direct (single-epoch, geometric) position fixes: the classical baselines beside the smoother.

Li et al. 2017 (CN104236546B, claim 1 step 5): position from three refracted stars.
51) The three catalogue directions ``s_i`` are generators of a cone with apex at the
    spacecraft; its axis ``c`` (``O_b E``) is the normal of the plane through the three unit
    vectors, ``c = (s2 - s1) x (s3 - s1)/|.|`` (sign: ``c . s_i > 0``), half-angle
    ``eta = acos(c . s1)``.
52) Frame ``F_d``: ``Z_d = c`` and ``X_d, Y_d`` completing it (Li et al. 2017's rotations
    ``R_Y(delta_c - 90 deg) R_Z(-alpha_c)``; any completion gives the same fix); star ``i``
    has azimuth ``alpha_i`` in ``F_d``.
53) Unknowns ``zeta, xi, alpha``: ``zeta^2 + xi^2 - 2 zeta xi cos(alpha - alpha_i) = a_i^2``,
    ``a_i = (R_e + h_i)/cos(eta)`` (``h_i`` the star's tangent height). With
    ``w = zeta^2 + xi^2``, ``(u, v) = zeta xi (cos alpha, sin alpha)`` the three equations are
    linear, ``w - 2 u cos(alpha_i) - 2 v sin(alpha_i) = a_i^2``; then ``zeta xi = |(u, v)|``
    and ``zeta^2, xi^2`` are the roots of ``t^2 - w t + (zeta xi)^2`` (two candidates).
54) Earth centre ``e_d = zeta (cos alpha X_d + sin alpha Y_d) + xi cot(eta) Z_d``;
55-56) rotated back, ``r = -e``.
Geometry (derived here): the distance from ``e`` to the line of star ``i`` is exactly
``d_i^2 = cos^2(eta) a_i^2 + zeta^2 sin^2(eta) sin^2(alpha - alpha_i)``, so step 53 is exact
when the Earth centre lies on the cone axis (``zeta = 0``) and a first-order
approximation otherwise; ``d_i`` itself is ``R_e + h_i - |r.s_i| tan(gamma_i)`` in the
refraction model. The closed form is therefore refined by Gauss-Newton on the refraction
residuals of ``factors.refraction`` (3 equations, 3 unknowns), from each candidate; the
candidate closest to a reference position (e.g. the a-priori orbit: Li et al. 2017's "remove the
redundant points with the previous orbit") is kept. With more than three stars in view the
triple of smallest position DOP at the reference is used.

The INS/CNS lecture's direct fix, ``r = -(R_e + H) C_b^i L_we``, is :mod:`fgnav.sun_earth_moon`;
here :func:`sem_direct_fixes` runs it over a log.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from factors.constants import R_EARTH_M
from factors.refraction import (refraction_residual, refraction_sigma_m,
                                tangent_height_from_refraction_m)
from fgnav.models.registry import REFRACTION, refraction_ray_eci
from fgnav.sun_earth_moon import preprocess_log

__all__ = ["cone_axis", "cone_fix_candidates", "refine_refraction_fix", "refraction_direct_fix",
           "DirectFixes", "refraction_direct_fixes", "sem_direct_fixes"]


def cone_axis(s_eci):
    """Axis (3,) and half-angle (rad) of the cone through three unit directions (3, 3)."""
    s = np.asarray(s_eci, dtype=float)
    s = s / np.linalg.norm(s, axis=1, keepdims=True)
    c = np.cross(s[1] - s[0], s[2] - s[0])
    c = c / np.linalg.norm(c)
    if c @ s[0] < 0:
        c = -c
    return c, float(np.arccos(np.clip(c @ s[0], -1.0, 1.0)))


def cone_fix_candidates(s_eci, d_m):
    """Li et al. 2017, steps 51-56: the (up to two) positions (K, 3) m, ECI, whose Earth centre
    is at distance ``a_i cos(eta) = d_i`` (m, (3,)) from each star line (module docstring)."""
    s = np.asarray(s_eci, dtype=float)
    s = s / np.linalg.norm(s, axis=1, keepdims=True)
    c, eta = cone_axis(s)
    x = np.cross(c, [1.0, 0.0, 0.0] if abs(c[0]) < 0.9 else [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    F = np.column_stack([x, np.cross(c, x), c])       # F_d axes in ECI
    sd = s @ F
    al = np.arctan2(sd[:, 1], sd[:, 0])
    a2 = (np.asarray(d_m, dtype=float) / np.cos(eta)) ** 2
    M = np.column_stack([np.ones(3), -2 * np.cos(al), -2 * np.sin(al)])
    try:
        w, u, v = np.linalg.solve(M, a2)
    except np.linalg.LinAlgError:
        return np.zeros((0, 3))
    P = np.hypot(u, v)
    alpha = np.arctan2(v, u)
    disc = w * w - 4 * P * P
    if disc < 0 or w <= 0:
        disc = max(disc, 0.0)
    t1, t2 = 0.5 * (w + np.sqrt(disc)), 0.5 * (w - np.sqrt(disc))
    out = []
    for zeta2, xi2 in ((t2, t1), (t1, t2)):
        zeta, xi = np.sqrt(max(zeta2, 0.0)), np.sqrt(max(xi2, 0.0))
        e_d = np.array([zeta * np.cos(alpha), zeta * np.sin(alpha), xi / np.tan(eta)])
        out.append(-(F @ e_d))
    return np.array(out)


def refine_refraction_fix(r0_eci_m, s_eci, gamma_rad, sigma_h_m=None, iters=20,
                          model="exponential-seed004"):
    """Gauss-Newton on the refraction residuals of one epoch: position (3,) m, and its
    covariance (3, 3) m^2 from ``sigma_h_m`` (n,) (None: unit weights, no covariance)."""
    r = np.asarray(r0_eci_m, dtype=float).copy()
    n = len(gamma_rad)
    w = np.ones(n) if sigma_h_m is None else 1.0 / np.asarray(sigma_h_m, dtype=float)
    for _ in range(iters):
        e, H = refraction_residual(np.tile(r, (n, 1)), s_eci, gamma_rad, model=model)
        A = H[:, 0, :] * w[:, None]
        b = -e[:, 0] * w
        dx, *_ = np.linalg.lstsq(A, b, rcond=None)
        r += dx
        if np.linalg.norm(dx) < 1e-4:
            break
    e, H = refraction_residual(np.tile(r, (n, 1)), s_eci, gamma_rad, model=model)
    A = H[:, 0, :] * w[:, None]
    P = np.linalg.inv(A.T @ A) if sigma_h_m is not None else None
    return r, P


def _sigma_h(r, s, gamma, sigma_gamma_rad, sigma_model_m, model):
    los = np.abs(s @ r)
    return refraction_sigma_m(gamma, sigma_gamma_rad, sigma_model_m, model, los_range_m=los)


def refraction_direct_fix(s_eci, gamma_rad, sigma_gamma_rad, sigma_model_m, r_ref_eci_m,
                          model="exponential-seed004"):
    """Li et al. 2017's three-star fix at one epoch.

    ``s_eci`` (n, 3) catalogue directions of the refracted stars (n >= 3), ``gamma_rad``
    (n,) measured angles, their 1σ ``sigma_gamma_rad`` and model 1σ ``sigma_model_m``
    (scalars or (n,)); ``r_ref_eci_m`` (3,) a reference position (a priori; picks the triple
    and the candidate). Returns ``(r (3,), P (3, 3), triple (3,))`` or None.
    """
    s = np.asarray(s_eci, dtype=float)
    g = np.asarray(gamma_rad, dtype=float)
    n = len(g)
    if n < 3:
        return None
    sg = np.broadcast_to(np.asarray(sigma_gamma_rad, dtype=float), (n,))
    sm = np.broadcast_to(np.asarray(sigma_model_m, dtype=float), (n,))
    r_ref = np.asarray(r_ref_eci_m, dtype=float)
    sh = _sigma_h(r_ref, s, g, sg, sm, model)
    _, H = refraction_residual(np.tile(r_ref, (n, 1)), s, g, model=model)
    Hw = H[:, 0, :] / sh[:, None]
    best, best_dop = None, np.inf
    for tri in itertools.combinations(range(n), 3):
        A = Hw[list(tri)]
        try:
            tr = np.trace(np.linalg.inv(A.T @ A))
        except np.linalg.LinAlgError:
            continue
        if not (np.isfinite(tr) and tr > 0.0):   # a near-singular triple: rounding left no DOP
            continue
        dop = np.sqrt(tr)
        if dop < best_dop:
            best, best_dop = tri, dop
    if best is None:
        return None
    tri = np.array(best)
    st, gt = s[tri], g[tri]
    h = tangent_height_from_refraction_m(gt, model)
    los = np.sqrt(np.maximum(r_ref @ r_ref - (R_EARTH_M + h) ** 2, 0.0))
    d = R_EARTH_M + h - los * np.tan(gt)
    cands = cone_fix_candidates(st, d)
    sols = []
    for r0 in cands:
        if not np.all(np.isfinite(r0)):
            continue
        try:
            r, _ = refine_refraction_fix(r0, st, gt, None, model=model)
        except np.linalg.LinAlgError:
            continue
        e, _ = refraction_residual(np.tile(r, (3, 1)), st, gt, model=model)
        if np.all(np.isfinite(r)) and np.max(np.abs(e)) < 1.0:
            sols.append(r)
    if not sols:
        return None
    r = min(sols, key=lambda x: np.linalg.norm(x - r_ref))
    try:
        _, P = refine_refraction_fix(r, st, gt, _sigma_h(r, st, gt, sg[tri], sm[tri], model),
                                     iters=0, model=model)
    except np.linalg.LinAlgError:
        return None
    return r, P, tri


@dataclass
class DirectFixes:
    """Direct fixes of a pass: epoch index ``k`` (M,) into ``t_s``, positions ``r_eci_m``
    (M, 3), covariances ``P_m2`` (M, 3, 3)."""

    k: np.ndarray
    t_s: np.ndarray
    r_eci_m: np.ndarray
    P_m2: np.ndarray

    def errors_m(self, x_true_at_k):
        """|r_fix - r_true| (M,) for the truth states (M, 6 or 3) at the fix epochs."""
        return np.linalg.norm(self.r_eci_m - np.asarray(x_true_at_k)[:, :3], axis=1)


def refraction_direct_fixes(p, x_ref, model="exponential-seed004"):
    """Li et al. 2017 fixes at every epoch of the pass ``p`` with >= 3 refraction rows;
    ``x_ref`` (N, 6) reference states (e.g. ``fgnav.solvers.batch.initial_guess``)."""
    fam = p.families.get(REFRACTION.kind)
    ks, rs, Ps = [], [], []
    if fam is not None:
        s_ray = refraction_ray_eci(fam)     # the geocentric apparent directions (aberration)
        order = np.argsort(fam.k, kind="stable")
        kk = fam.k[order]
        bounds = np.flatnonzero(np.diff(kk)) + 1
        for rows in np.split(order, bounds):
            if len(rows) < 3:
                continue
            k = int(fam.k[rows[0]])
            out = refraction_direct_fix(s_ray[rows], fam.values["gamma_rad"][rows],
                                        fam.sigma[rows], fam.values["sigma_model_m"][rows],
                                        x_ref[k, :3], model)
            if out is None:
                continue
            ks.append(k)
            rs.append(out[0])
            Ps.append(out[1])
    k = np.array(ks, dtype=int)
    return DirectFixes(k, p.t_s[k] if len(k) else np.zeros(0), np.array(rs).reshape(-1, 3),
                       np.array(Ps).reshape(-1, 3, 3))


def sem_direct_fixes(log, first="sun"):
    """The INS/CNS lecture's direct fixes ``r = -(R_e + H) C_b^i L_we`` of a raw Sun/Earth/Moon log
    (:func:`fgnav.sun_earth_moon.preprocess_log`); ``k`` indexes the fix epochs themselves."""
    _, ep = preprocess_log(log, first=first)
    return DirectFixes(np.arange(len(ep.t_s)), ep.t_s, ep.r_fix_eci_m, ep.P_fix_m2)
