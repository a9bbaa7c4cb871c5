"""Geometric fixes: the position surfaces of one epoch intersected (the INS/CNS lecture's "pure
celestial geometric" positioning), beside the smoother.

The INS/CNS lecture ("Chapter 6: INS/CNS integrated navigation", sec. 6.3) fixes a Mars-bound
cruise from three angles measured at one instant: two Sun-star angles (cones
``r . i_1 = -r cos A_1``, ``r . i_2 = -r cos A_2``) and one Sun-Earth angle (the torus
``r . r_p = r^2 - r |r - r_p| cos A_3``); "the intersection of the two cones and the torus,
the redundant points removed with the previous orbit". Every orbit-only measurement of a
log is such a surface ``e_j(r) = 0``: the attitude-free angles (cones, tori, the sextant's
limb-star angles), the geocentric direction (a line through the Earth's centre), the limb's
angular radius and the altimeter (spheres), starlight refraction (a surface of tangent
height). Here all of them at one epoch are intersected at once:

* **Least squares**: ``r* = argmin sum_j (e_j(r)/sigma_j)^2`` by Gauss-Newton with step
  halving (:func:`fgnav.iod.fit.gauss_newton_halving`), on the models' own residuals and
  Jacobians (``fgnav.models.registry``). With three surfaces the solutions are the
  intersection points; with more, the least-squares point.
* **Spurious roots**: the surfaces cut in several points (two cones and a torus in up to
  eight). Gauss-Newton is started from the prior position (the previous orbit propagated)
  and from ``n_starts`` points spread over the sphere of the prior's radius (a Fibonacci
  lattice: Gonzalez 2010, "Measurement of areas on a sphere using Fibonacci and
  latitude-longitude lattices", Math. Geosciences 42); every converged point whose
  chi-square is consistent with the noise (``chi2.ppf(1 - alpha, max(m - 3, 1))``, plus
  the prior's margin for an exact fit) is a root, and the root nearest the prior position
  is kept, as the lecture prescribes.
* **Covariance** from the surfaces' gradients at the fix: ``P = (J^T W J)^-1`` with ``J``
  the rows' position Jacobians and ``W = diag(1/sigma_j^2)`` (first order; a fix whose
  surfaces cut at grazing angles has a large ``P``, and ``J^T W J`` singular means the
  epoch does not fix the position: no fix).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgnav.chi2 import chi2_ppf
from fgnav.iod.direct_fix import DirectFixes
from fgnav.iod.fit import gauss_newton_halving
from fgnav.models.registry import MODELS
from fgnav.models.variables import Layout

__all__ = ["fibonacci_directions", "intersect_surfaces", "SurfaceFix", "surface_models",
           "epoch_residual", "position_surface_fixes"]


def fibonacci_directions(n: int) -> np.ndarray:
    """``n`` unit vectors (n, 3) spread evenly over the sphere (Fibonacci lattice, Gonzalez 2010)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5 ** 0.5) * i
    rho = np.sqrt(1.0 - z * z)
    return np.column_stack([rho * np.cos(phi), rho * np.sin(phi), z])


@dataclass
class SurfaceFix:
    """One epoch's intersection: ``r_eci_m`` (3,), its covariance ``P_m2`` (3, 3), the
    whitened cost ``chi2`` at the fix, the rows ``m``, and every root found ``roots`` (K, 3)
    (the kept one first)."""

    r_eci_m: np.ndarray
    P_m2: np.ndarray
    chi2: float
    m: int
    roots: np.ndarray


def intersect_surfaces(residual, r_prior, *, starts=None, n_starts=24, alpha=1e-3,
                       max_iter=50, tol_m=1e-3, merge_m=1.0):
    """Intersect position surfaces by least squares; the root nearest ``r_prior`` is kept.

    ``residual(r (3,)) -> (b (m,), A (m, 3))``: whitened residuals ``e/sigma`` and their
    position Jacobians (raises ``ModelDomainError`` outside a surface's domain);
    ``r_prior`` (3,) the prior position (the previous orbit); ``starts`` (S, 3) further
    starting points (default: ``n_starts`` Fibonacci directions at the prior's radius).
    Returns a :class:`SurfaceFix`, or None if no start converges to a consistent root or
    the surfaces do not fix the position (module docstring).
    """
    r_prior = np.asarray(r_prior, dtype=float)
    if starts is None:
        starts = np.linalg.norm(r_prior) * fibonacci_directions(n_starts)
    cand = [r_prior] + list(np.asarray(starts, dtype=float).reshape(-1, 3))
    roots = []
    m = None
    for r0 in cand:
        out = gauss_newton_halving(residual, r0, max_iter, tol_m)
        if out is None:
            continue
        r, cost, A = out
        m = A.shape[0]
        gate = chi2_ppf(1.0 - alpha, max(m - 3, 1))
        if not (np.all(np.isfinite(r)) and cost <= gate):
            continue
        if any(np.linalg.norm(r - q[0]) < merge_m for q in roots):
            continue
        roots.append((r, cost, A))
    if not roots:
        return None
    roots.sort(key=lambda q: np.linalg.norm(q[0] - r_prior))
    r, cost, A = roots[0]
    N = A.T @ A
    if np.linalg.cond(N) > 1e14:
        return None
    return SurfaceFix(r_eci_m=r, P_m2=np.linalg.inv(N), chi2=cost, m=int(A.shape[0]),
                      roots=np.array([q[0] for q in roots]))


def surface_models(p):
    """The families of pass ``p`` that are position surfaces: measurements (not priors) of the
    orbit state alone (no further variable), as ``[(model, family)]``."""
    lay = Layout()
    return [(MODELS[k], fam) for k, fam in p.families.items()
            if k in MODELS and MODELS[k].enters(lay) and not MODELS[k].prior
            and MODELS[k].observes_orbit and MODELS[k].variables_in(lay) == ("orbit",)]


def epoch_residual(parts, v_guess=None):
    """``residual(r)`` (see :func:`intersect_surfaces`) of the rows ``parts`` = ``[(model,
    family subset)]`` of one epoch: each model's residual at ``[r, v_guess]``, whitened by
    its sigma. The velocity ``v_guess`` (3,) m/s enters the angle kinds' aberration (apparent
    lines of sight move by ``|v|/c``): zero (the default) biases a cruise's fix by ~1e-4 rad
    times the distance (mars-cruise: ~15,000 km, about the fix's sigma), a guess within
    1 km/s by under 1 arcsec."""
    v = np.zeros(3) if v_guess is None else np.asarray(v_guess, dtype=float)

    def residual(r):
        bs, As = [], []
        for mdl, fam in parts:
            x = np.tile(np.concatenate([r, v]), (len(fam), 1))
            e, jac = mdl.residual(fam, {"orbit": x})
            H = jac["position"] if "position" in jac else jac["orbit"][..., :3]
            sig = np.asarray(mdl.noise_sigma(fam, x), dtype=float).reshape(len(fam), -1)
            bs.append((np.asarray(e).reshape(len(fam), -1) / sig).ravel())
            As.append((np.asarray(H) / sig[..., None]).reshape(-1, 3))
        return np.concatenate(bs), np.concatenate(As)
    return residual


def position_surface_fixes(p, x_ref, *, n_starts=24, min_rows=3, alpha=1e-3):
    """Geometric fixes at every epoch of ``p`` with at least ``min_rows`` surface rows
    (:func:`surface_models`); ``x_ref`` (N, 6) the prior orbit (e.g. the a-priori state
    propagated, ``fgnav.iod.prior.initial_guess``): the start and the choice among
    roots. Returns ``(DirectFixes, roots (M,))``: the fixes and the number of distinct roots
    found at each."""
    fams = surface_models(p)
    ks, rs, Ps, nroots = [], [], [], []
    by_epoch = {}
    for mdl, fam in fams:
        for k in np.unique(fam.k):
            by_epoch.setdefault(int(k), []).append((mdl, fam.subset(np.flatnonzero(fam.k == k), 0)))
    for k in sorted(by_epoch):
        parts = by_epoch[k]
        if sum(len(f) * m.dim for m, f in parts) < min_rows:
            continue
        fix = intersect_surfaces(epoch_residual(parts, x_ref[k, 3:6]), x_ref[k, :3],
                                 n_starts=n_starts, alpha=alpha)
        if fix is None:
            continue
        ks.append(k)
        rs.append(fix.r_eci_m)
        Ps.append(fix.P_m2)
        nroots.append(len(fix.roots))
    k = np.array(ks, dtype=int)
    return (DirectFixes(k, p.t_s[k] if len(k) else np.zeros(0), np.array(rs).reshape(-1, 3),
                        np.array(Ps).reshape(-1, 3, 3)), np.array(nroots, dtype=int))
