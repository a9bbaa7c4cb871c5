"""The orbit from geometric fixes: position surfaces intersected epoch by epoch, the spurious
roots removed with the orbit, and that orbit refined on the rows (a first guess without a
prior, and the geometric baseline of the cruise).

The INS/CNS lecture ("Chapter 6: INS/CNS integrated navigation", sec. 6.3, the Mars-transfer
example) fixes the spacecraft from two Sun-star angles (cones ``r . i_j = -r cos A_j``) and
one Sun-Earth angle (the torus ``r . r_p = r^2 - r |r - r_p| cos A_3``) and removes "the
redundant points with the previous orbit". Here:

1. **Candidates in closed form.** Two cones about star directions ``s_1, s_2`` through the
   same body B fix the unit vector ``w`` from B to the spacecraft by ``w . s_j = -cos A_j``:
   ``w = a s_1 + b s_2 + c (s_1 x s_2)`` with ``a = (c_1 - g c_2)/(1 - g^2)``,
   ``b = (c_2 - g c_1)/(1 - g^2)`` (``c_j = -cos A_j``, ``g = s_1 . s_2``) and
   ``c = +-sqrt(1 - |a s_1 + b s_2|^2) / |s_1 x s_2|``: two mirror directions, the two roots
   of the lecture's figure. An angle ``A`` between B and a second body C (vector
   ``d = p_C - p_B``) then gives the distance by the sine rule in the triangle B,
   spacecraft, C: ``rho = |d| sin(A + beta) / sin A`` with ``beta`` the angle at B between
   ``w`` and ``d`` (valid when ``A + beta < pi``). Each candidate is refined on all the
   epoch's rows by Gauss-Newton (:func:`fgnav.iod.surfaces.intersect_surfaces`),
   which keeps it only if its chi-square is consistent with the noise; its covariance is
   ``(J^T W J)^-1`` from the surfaces' gradients.
   **Searched** where no closed form applies (e.g. star-limb angles alone) and an epoch has
   three or more angle rows: Gauss-Newton from a grid of starts (:func:`search_starts`,
   Fibonacci directions from the central body times log-spaced distances) at one epoch,
   then from those roots at the neighbouring epochs (continuation).
2. **Which root is real.** With a previous orbit, the root nearest it (the lecture). Without
   one (no prior rows), the roots of up to :data:`TRACK_EPOCHS` epochs spread over an arc of
   at most :data:`MAX_TRACK_ARC` of the orbital period (the whole of a cruise's weeks; a few
   minutes of a low orbit) are combined in every way (2^M tracks at most) and a 6-state
   orbit of the motion model is fitted to each track's positions, weighted by their
   covariances; the track of least chi-square is the orbit (a spurious root does not move
   under gravity). It must pass a
   chi-square test (``1 - 1e-6``) and beat the second best by a factor
   :data:`MIN_TRACK_MARGIN`, else the pass is refused with the two figures.
3. **Refinement.** Levenberg-Marquardt on the 6-state at a middle epoch over the rows
   themselves (:func:`fgnav.iod.fit.fit_orbit`, the smoothers' own
   linearizers and propagator); its covariance ``(A^T A)^-1``.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from factors.constants import AU_M
from factors.dynamics import MotionModel, propagate, propagate_many
from fgnav.chi2 import chi2_ppf
from fgnav.errors import UserError
from fgnav.iod.direct_fix import DirectFixes
from fgnav.iod.fit import InitialOrbit, fit_covariance, fit_orbit
from fgnav.iod.surfaces import (epoch_residual, fibonacci_directions, intersect_surfaces,
                                surface_models)
from fgnav.measurements import Family, Pass
from fgnav.models.registry import BODY_BODY_ANGLE, BODY_STAR_ANGLE, LIMB_STAR_ANGLE

__all__ = ["cone_torus_candidates", "epoch_parts", "epoch_roots", "geometric_support",
           "geometric_initial_orbit", "fixes_along", "TRACK_EPOCHS", "MIN_TRACK_MARGIN",
           "MAX_TRACK_ARC"]

TRACK_EPOCHS = 6
"""Epochs whose roots are combined to find the orbit without a prior (2^6 = 64 tracks)."""
MIN_TRACK_MARGIN = 10.0
"""The best track's chi-square must be this many times below the second best's."""
MIN_FIX_EPOCHS = 4
"""Epochs with a closed-form fix needed for an orbit from geometric fixes."""
MAX_TRACK_ARC = 0.125
"""Longest arc (fraction of the orbital period) the tracks of roots are fitted over."""
MAX_TRACKS = 4096
"""Most tracks (combinations of the epochs' roots) fitted; fewer epochs are taken if needed."""
SEARCH_DIRECTIONS = 24
SEARCH_DISTANCES = 10
"""Starts of the root search at an epoch without a closed form: this many Fibonacci
directions from the central body times this many log-spaced distances in
:data:`SEARCH_RANGE_M`."""
SEARCH_ATTEMPTS = 5
"""Epochs (nearest the middle first) the whole search is tried at before the pass is refused."""
SEARCH_RANGE_M = {"earth": (6.5e6, 2.0e9), "sun": (0.2 * AU_M, 6.0 * AU_M)}
"""Distances from the central body (m) the root search covers: low Earth orbit to beyond
the Moon; inside Mercury's orbit to Jupiter's."""
_STAR_KIND = BODY_STAR_ANGLE.kind
_BODY_KIND = BODY_BODY_ANGLE.kind
_ANGLE_KINDS = (BODY_STAR_ANGLE.kind, LIMB_STAR_ANGLE.kind, BODY_BODY_ANGLE.kind)


def epoch_parts(p: Pass) -> dict[int, list]:
    """The position-surface rows of each epoch: ``k -> [(model, family of its rows)]``."""
    by_epoch: dict[int, list] = {}
    for mdl, fam in surface_models(p):
        order = np.argsort(fam.k, kind="stable")
        ks = fam.k[order]
        for grp in np.split(order, np.flatnonzero(np.diff(ks)) + 1):
            if len(grp):
                by_epoch.setdefault(int(fam.k[grp[0]]), []).append((mdl, fam.subset(grp)))
    return by_epoch


def cone_torus_candidates(parts) -> np.ndarray:
    """Closed-form positions (K, 3), m, from two body-star cones through one body and a
    body-body angle with that body among ``parts`` (one epoch's rows), module docstring;
    (0, 3) when the epoch has no such set."""
    fams = {m.kind: f for m, f in parts}
    cones, tori = fams.get(_STAR_KIND), fams.get(_BODY_KIND)
    if cones is None or tori is None or len(cones) < 2:
        return np.zeros((0, 3))
    out = []
    pb = cones.values["p_body_eci_m"]
    for i, j in itertools.combinations(range(len(cones)), 2):
        if np.linalg.norm(pb[i] - pb[j]) > 1.0:   # the two cones' vertex: one body
            continue
        s1, s2 = cones.values["s_eci"][i], cones.values["s_eci"][j]
        c1, c2 = -math.cos(cones.values["a_rad"][i]), -math.cos(cones.values["a_rad"][j])
        g = float(s1 @ s2)
        n = np.cross(s1, s2)
        nn = float(np.linalg.norm(n))
        if nn < 1e-3:
            continue
        a = (c1 - g * c2) / (1.0 - g * g)
        b = (c2 - g * c1) / (1.0 - g * g)
        base = a * s1 + b * s2
        c = math.sqrt(max(1.0 - float(base @ base), 0.0)) / nn
        for sign in (1.0, -1.0):
            w = base + sign * c * n
            w = w / np.linalg.norm(w)
            for t in range(len(tori)):
                p1, p2 = tori.values["p_body_eci_m"][t], tori.values["p_body2_eci_m"][t]
                if np.linalg.norm(p1 - pb[i]) <= 1.0:
                    d = p2 - p1
                elif np.linalg.norm(p2 - pb[i]) <= 1.0:
                    d = p1 - p2
                else:
                    continue
                A = float(tori.values["a_rad"][t])
                dn = float(np.linalg.norm(d))
                beta = math.acos(max(-1.0, min(1.0, float(w @ d) / dn)))
                if A + beta < math.pi and math.sin(A) > 1e-9:
                    out.append(pb[i] + dn * math.sin(A + beta) / math.sin(A) * w)
        break   # the first usable pair of cones; the refinement uses every row
    return np.array(out).reshape(-1, 3)


def search_starts(centre: str = "earth") -> np.ndarray:
    """The root search's starting points (K, 3), m from the central body (module
    docstring, :data:`SEARCH_DIRECTIONS` x :data:`SEARCH_DISTANCES`)."""
    lo, hi = SEARCH_RANGE_M[centre]
    d = np.geomspace(lo, hi, SEARCH_DISTANCES)
    return (d[:, None, None] * fibonacci_directions(SEARCH_DIRECTIONS)[None]).reshape(-1, 3)


def _n_rows(parts) -> int:
    """The epoch's angle rows (the kinds the root search is for: its starts span where a
    spacecraft measuring them can be; other surfaces refine the roots but do not start a
    search: refraction alone, for one, fixes mirror pairs of orbits)."""
    return sum(len(f) * m.dim for m, f in parts if m.kind in _ANGLE_KINDS)


def epoch_roots(parts, v_guess=None, alpha: float = 1e-3, starts=None):
    """The consistent roots of one epoch: a list of ``SurfaceFix``, each refined on all of
    ``parts``, from the closed-form candidates or, where there are none and the epoch has
    three or more angle rows, from ``starts`` (K, 3) (:func:`search_starts`). Roots within three
    sigma of one found before are the same root."""
    roots = []
    residual = epoch_residual(parts, v_guess)
    cands = cone_torus_candidates(parts)
    if not len(cands) and starts is not None and _n_rows(parts) >= 3:
        cands = starts
    for r0 in cands:
        fix = intersect_surfaces(residual, r0, starts=np.zeros((0, 3)), alpha=alpha)
        if fix is None:
            continue
        if not any(np.linalg.norm(fix.r_eci_m - q.r_eci_m)
                   < max(1.0, 3.0 * math.sqrt(np.linalg.eigvalsh(q.P_m2)[-1])) for q in roots):
            roots.append(fix)
    return roots


def geometric_support(p: Pass) -> tuple[bool, str]:
    """Whether the pass has geometric fixes at enough epochs for an orbit: closed-form ones,
    or epochs with three or more angle rows for the root search."""
    parts_by_k = epoch_parts(p)
    n = sum(len(cone_torus_candidates(parts)) > 0 for parts in parts_by_k.values())
    if n >= MIN_FIX_EPOCHS:
        return True, (f"an initial orbit can be computed from geometric fixes (two "
                      f"{_STAR_KIND} cones and a {_BODY_KIND} torus) at {n} epochs")
    n3 = sum(_n_rows(parts) >= 3 for parts in parts_by_k.values())
    if n3 >= MIN_FIX_EPOCHS:
        return True, (f"an initial orbit can be searched from the position surfaces of {n3} "
                      f"epochs with three or more angle rows")
    return False, (f"geometric fixes need three or more angle rows (e.g. two {_STAR_KIND} rows "
                   f"of one body and a {_BODY_KIND} row with it) at {MIN_FIX_EPOCHS} or more "
                   f"epochs ({n3} found)")


SCALE_CHECK_EPOCHS = 3
"""Epochs whose fixes :func:`check_centre_scale` looks at before any long work."""


def check_centre_scale(p: Pass, roots_by_k: dict, centre: str) -> None:
    """``UserError`` when the fixes of :data:`SCALE_CHECK_EPOCHS` epochs all lie beyond the
    range an orbit about ``centre`` is searched in (:data:`SEARCH_RANGE_M`: 2e6 km about the
    Earth, beyond its Hill sphere of 1.5e6 km; 6 AU about the Sun). A heliocentric log read as
    geocentric (its ``# centre: sun`` line missing) puts its fixes ~0.07 AU from the Earth,
    and the track fit then propagated them about the Earth in 5 s steps for hours."""
    if len(roots_by_k) < SCALE_CHECK_EPOCHS:
        return
    hi = SEARCH_RANGE_M[centre][1]
    first = sorted(roots_by_k)[:SCALE_CHECK_EPOCHS]
    near = [min(float(np.linalg.norm(f.r_eci_m)) for f in roots_by_k[k]) for k in first]
    if min(near) > hi:
        hint = ("if the log is heliocentric, its second line must be '# centre: sun' "
                "(fgnav.io.log_csv)" if centre == "earth" else
                "check the log's '# centre:' line and the angles' bodies")
        raise UserError(f"{p.source}: the geometric fixes of the first {len(first)} epochs lie "
                        f"{np.median(near) / AU_M:.3g} AU from the {centre}'s centre, beyond {hi / AU_M:.3g} AU, where no "
                        f"orbit about the {centre} is sought: {hint}")


def first_fixes(p: Pass, n: int = SCALE_CHECK_EPOCHS) -> dict:
    """The closed-form roots at the first ``n`` epochs that have them (``fgnav check``)."""
    out = {}
    for k, parts in sorted(epoch_parts(p).items()):
        roots = epoch_roots(parts)
        if roots:
            out[k] = roots
            if len(out) == n:
                break
    return out


def _track_arc_s(r_m: float, model: MotionModel) -> float:
    """The longest arc the tracks are fitted over, s: :data:`MAX_TRACK_ARC` of the period of
    an orbit of radius ``r_m`` about the central body (Kepler's third law)."""
    return MAX_TRACK_ARC * 2.0 * math.pi * math.sqrt(r_m ** 3 / model.mu)


def _searched_roots(p: Pass, parts_by_k: dict, model: MotionModel) -> dict:
    """Roots found by search (:func:`search_starts`) where there is no closed form: at the
    middle epoch with three or more angle rows first (up to :data:`SEARCH_ATTEMPTS` epochs
    tried; its roots' distance sets the arc, as in
    :func:`_track_epochs`), then at up to twice :data:`TRACK_EPOCHS` epochs of that arc
    around it, each started from the roots of the nearest epoch done (the whole search only
    where none of those converges)."""
    starts = search_starts(model.centre)
    ks = np.array(sorted(k for k, parts in parts_by_k.items() if _n_rows(parts) >= 3))
    if not len(ks):
        return {}
    order = np.argsort(np.abs(p.t_s[ks] - p.t_s[ks[len(ks) // 2]]), kind="stable")
    found = {}
    for k in ks[order][:SEARCH_ATTEMPTS]:
        roots = epoch_roots(parts_by_k[int(k)], starts=starts)
        if roots:
            found[int(k)] = roots
            break
    if not found:
        return found
    k_mid = next(iter(found))
    span = _track_arc_s(np.median([np.linalg.norm(f.r_eci_m) for f in found[k_mid]]), model)
    near = ks[np.abs(p.t_s[ks] - p.t_s[k_mid]) <= 0.5 * span]
    take = near[np.unique(np.linspace(0, len(near) - 1, min(len(near), 2 * TRACK_EPOCHS))
                          .round().astype(int))]
    for k in take[np.argsort(np.abs(p.t_s[take] - p.t_s[k_mid]), kind="stable")]:
        if int(k) in found:
            continue
        # continuation: from the roots of the nearest epoch solved, else the whole search
        k_near = min(found, key=lambda q: abs(p.t_s[q] - p.t_s[k]))
        roots = epoch_roots(parts_by_k[int(k)], starts=np.array([f.r_eci_m for f in found[k_near]]))
        roots = roots or epoch_roots(parts_by_k[int(k)], starts=starts)
        if roots:
            found[int(k)] = roots
    return found


def _fit_tracks(t, R, P, model, t0_j2000_s, i_ref, max_iterations=20):
    """Gauss-Newton fits, all at once, of one 6-state at ``t[i_ref]`` per track to its
    positions ``R`` (C, M, 3) with covariances ``P`` (C, M, 3, 3) at times ``t`` (M,), s:
    ``(x (C, 6), chi2 (C,))`` (one ``propagate_many`` call per iteration for every track)."""
    C, M = R.shape[:2]
    L = np.linalg.cholesky(np.linalg.inv(P))   # W = L L^T: whitened residual L^T e
    i0, i1 = max(i_ref - 1, 0), min(i_ref + 1, M - 1)
    x = np.concatenate([R[:, i_ref], (R[:, i1] - R[:, i0]) / (t[i1] - t[i0])], axis=1)
    dt = np.tile(t - t[i_ref], C)
    chi2 = np.full(C, np.inf)
    for _ in range(max_iterations):
        Xi, Phi = propagate_many(np.repeat(x, M, axis=0), dt, model, t0_j2000_s + t[i_ref])
        e = (Xi[:, :3].reshape(C, M, 3) - R)
        b = np.einsum("cmji,cmj->cmi", L, e).reshape(C, 3 * M)
        A = np.einsum("cmji,cmjk->cmik", L, Phi[:, :3].reshape(C, M, 3, 6)).reshape(C, 3 * M, 6)
        new = np.einsum("ci,ci->c", b, b)
        dx = np.linalg.solve(np.einsum("cri,crj->cij", A, A), -np.einsum("cri,cr->ci", A, b)[..., None])[..., 0]
        x = x + dx
        done = np.all(np.abs(chi2 - new) <= 1e-6 * np.maximum(new, 1.0))
        chi2 = new
        if done:
            break
    return x, chi2


def _track_epochs(p, roots_by_k, model) -> np.ndarray:
    """Up to :data:`TRACK_EPOCHS` epochs with roots, spread over the window of at most
    :data:`MAX_TRACK_ARC` of an orbital period that holds the most of them (the period from
    the median distance of the nearest roots to the central body, Kepler's third law), or
    over the whole pass when that window holds fewer than :data:`MIN_FIX_EPOCHS`. A short
    arc keeps the track fit's start (the velocity from two fixes' difference) near the orbit
    in low orbits, where fixes spread over hours are several revolutions apart; a cruise's
    weeks are a small arc of its year and stay whole."""
    ks = np.array(sorted(roots_by_k))
    span = _track_arc_s(np.median([min(np.linalg.norm(f.r_eci_m) for f in roots_by_k[int(k)])
                                   for k in ks]), model)
    t = p.t_s[ks]
    end = np.searchsorted(t, t + span, side="right")
    i0 = int(np.argmax(end - np.arange(len(t))))
    window = ks[i0:end[i0]] if end[i0] - i0 >= MIN_FIX_EPOCHS else ks
    n = min(len(window), TRACK_EPOCHS)
    while True:
        pick = window[np.unique(np.linspace(0, len(window) - 1, n).round().astype(int))]
        if n <= MIN_FIX_EPOCHS or math.prod(len(roots_by_k[int(k)]) for k in pick) <= MAX_TRACKS:
            return pick
        n -= 1


def _track_orbit(p, roots_by_k, model, t0_j2000_s):
    """The orbit (x at t_ref, t_ref) of the track of least chi-square (module docstring)."""
    pick = _track_epochs(p, roots_by_k, model)
    t = p.t_s[pick]
    i_ref = len(pick) // 2
    combos = list(itertools.product(*[range(len(roots_by_k[int(k)])) for k in pick]))
    R = np.array([[roots_by_k[int(k)][c].r_eci_m for k, c in zip(pick, cb)] for cb in combos])
    P = np.array([[roots_by_k[int(k)][c].P_m2 for k, c in zip(pick, cb)] for cb in combos])
    x, chi2 = _fit_tracks(t, R, P, model, t0_j2000_s, i_ref)
    fits = [(float(c), xx) for c, xx in zip(chi2, x) if np.isfinite(c)]
    fits.sort(key=lambda f: f[0])
    dof = 3 * len(pick) - 6
    if not fits or dof <= 0:
        raise UserError(f"{p.source}: no orbit fits the geometric fixes of {len(pick)} epochs")
    gate = chi2_ppf(1.0 - 1e-6, dof)
    if fits[0][0] > gate:
        raise UserError(f"{p.source}: no track of geometric fixes fits one orbit (best "
                        f"chi-square {fits[0][0]:.3g} over {dof} dof, gate {gate:.3g}): the "
                        f"angles are inconsistent, or add prior rows")
    if len(fits) > 1 and fits[1][0] < MIN_TRACK_MARGIN * max(fits[0][0], 1.0):
        raise UserError(f"{p.source}: two tracks of geometric fixes fit an orbit (chi-square "
                        f"{fits[0][0]:.3g} and {fits[1][0]:.3g}): the spurious roots cannot be "
                        f"told apart over {t[-1] - t[0]:.0f} s; add prior rows or a longer pass")
    return fits[0][1], float(t[i_ref])


def fixes_along(p: Pass, X_ref: np.ndarray, parts_by_k=None):
    """Geometric fixes at every epoch with a closed-form candidate, the root nearest the
    orbit ``X_ref`` (N, 6) kept: ``(DirectFixes, roots (M,))`` as
    :func:`fgnav.iod.surfaces.position_surface_fixes` gives them."""
    parts_by_k = epoch_parts(p) if parts_by_k is None else parts_by_k
    ks, rs, Ps, nroots = [], [], [], []
    for k in sorted(parts_by_k):
        roots = epoch_roots(parts_by_k[k], X_ref[k, 3:])
        if not roots:
            continue
        best = min(roots, key=lambda f: np.linalg.norm(f.r_eci_m - X_ref[k, :3]))
        ks.append(k)
        rs.append(best.r_eci_m)
        Ps.append(best.P_m2)
        nroots.append(len(roots))
    k = np.array(ks, dtype=int)
    return (DirectFixes(k, p.t_s[k] if len(k) else np.zeros(0), np.array(rs).reshape(-1, 3),
                        np.array(Ps).reshape(-1, 3, 3)), np.array(nroots, dtype=int))


def _surface_subpass(p: Pass, k_sub: np.ndarray) -> Pass:
    """The position-surface rows at the epochs ``k_sub`` only, re-indexed 0..len-1."""
    remap = -np.ones(p.n_epochs, dtype=int)
    remap[k_sub] = np.arange(len(k_sub))
    fams = {}
    for mdl, f in surface_models(p):
        rows = np.flatnonzero(remap[f.k] >= 0)
        if len(rows):
            g = f.subset(rows)
            fams[mdl.kind] = Family(k=remap[g.k], values=g.values, sigma=g.sigma, line=g.line)
    return Pass(epoch0=p.epoch0, t_s=p.t_s[k_sub], families=fams, source=p.source)


def geometric_initial_orbit(p: Pass, model: MotionModel, t0_j2000_s: float,
                            near_k: int | None = None, max_epochs: int = 400):
    """The orbit from geometric fixes (module docstring) as an
    :class:`fgnav.iod.fit.InitialOrbit` (method ``"geometric-fixes+lm"``). Raises
    :class:`UserError` when the pass has too few fixes or no track fits one orbit."""
    ok, why = geometric_support(p)
    if not ok:
        raise UserError(f"{p.source}: {why}")
    parts_by_k = epoch_parts(p)
    roots_by_k = {}
    for k, parts in parts_by_k.items():
        roots = epoch_roots(parts)
        if roots:
            roots_by_k[k] = roots
            if len(roots_by_k) == SCALE_CHECK_EPOCHS:   # before the long work
                check_centre_scale(p, roots_by_k, model.centre)
    if len(roots_by_k) < MIN_FIX_EPOCHS:
        roots_by_k = _searched_roots(p, parts_by_k, model)
        check_centre_scale(p, roots_by_k, model.centre)
    if len(roots_by_k) < MIN_FIX_EPOCHS:
        raise UserError(f"{p.source}: geometric fixes at {len(roots_by_k)} epochs only (the "
                        f"angles' surfaces do not cut consistently at the others)")
    x_ref, t_ref = _track_orbit(p, roots_by_k, model, t0_j2000_s)
    # every epoch's root nearest that orbit, then the rows themselves
    ks = np.array(sorted(parts_by_k))
    k_sub = ks[np.unique(np.linspace(0, len(ks) - 1, min(len(ks), max_epochs)).round().astype(int))]
    k_ref = int(k_sub[np.argmin(np.abs(p.t_s[k_sub] - (t_ref if near_k is None else p.t_s[near_k])))])
    x0 = propagate(x_ref, float(p.t_s[k_ref]) - t_ref, model, t0_j2000_s + t_ref, with_stm=False)[0]
    sp = _surface_subpass(p, k_sub)
    fit = fit_orbit(sp, x0, float(p.t_s[k_ref]), model, t0_j2000_s)
    if fit is None:
        raise UserError(f"{p.source}: the orbit of the geometric fixes could not be refined on "
                        f"the rows")
    x, r, A, cost = fit
    rms = math.sqrt(cost / len(r))
    P = fit_covariance(A, rms)
    return InitialOrbit(k_ref=k_ref, x_eci=x, P_eci=P, method="geometric-fixes+lm",
                        n_used=len(k_sub), rms_whitened=rms,
                        t_span_s=(float(p.t_s[k_sub[0]]), float(p.t_s[k_sub[-1]])))
