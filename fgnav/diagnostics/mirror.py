"""The mirror test of a formation: is the relative geometry the links chose the only one
that fits?

Ranges between two spacecraft whose antenna lever arms barely tell the direction (one link
each way per epoch) allow a second minimum, the relative state reflected through the first
spacecraft (:func:`mirrored`); the batch is solved again from there and the two chi-squares
compared (:func:`mirror_test`; the integrity issue, item 1): a likelihood-ratio test of the
two hypotheses (Willsky & Jones 1976). With three spacecraft or more, each further
spacecraft's ranges to two others stay the same when it is turned about the line through
those two: the reflections through planes containing that line (:func:`turned_about`) are
solved and compared too (formation-gto-3, seed 4: sat3 reflected about the sat1-sat2 line
fitted with chi-square 2,937 against the truth's 1,373, 270 m off on a 0.1 m sigma, `ok`).

A range fixes its spacecraft on a sphere; the covariance, linear, on the sphere's tangent
plane. Where the relative position's uncertainty across the line of sight bends the sphere
away from that plane by more than the range's own sigma (:func:`range_curvature_test`, an
intrinsic-curvature measure of Bates & Watts 1980), the truth lies off the covariance's
ellipsoid though on the data's sphere (formation-gto, links through rx1 only, seed 1: 47 m
across a 508 m line bend the range 2.2 m, 20 times its 0.11 m sigma along the line; relative
NEES 4,287 (1.8 in range and directions), and the verdict said `ok`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from factors.errors import ModelDomainError
from fgnav.errors import NotObservableError
from fgnav.graph import block_values
from fgnav.measurements import Pass

__all__ = ["mirror_test", "mirrored", "turned_about", "alternative_geometries",
           "range_curvature_test", "MIRROR_MAX_ITERATIONS", "MIRROR_MARGIN_CHI2",
           "CURVATURE_LIMIT"]

MIRROR_MAX_ITERATIONS = 10
"""Gauss-Newton iterations of the mirror test's solve (:func:`mirror_test`)."""
MIRROR_MARGIN_CHI2 = 25.0
"""A mirrored relative geometry whose batch chi-square is not this much larger than the
solution's (5 sigma of a one-parameter choice) explains the data as well: the links cannot
tell the two apart."""
RESOLUTION_EPS = float(np.finfo(float).eps)
"""Relative rounding of the block covariance's entries: the relative position's variance
along a line is resolved only above this times the two absolute position variances'
traces (:func:`range_curvature_test`)."""
CURVATURE_LIMIT = 3.0
"""The largest bend of a link's range sphere over the relative position's uncertainty across
the line of sight, in sigmas of the range along it, that the linear covariance still
describes (:func:`range_curvature_test`): beyond, a truth one sigma across the line lies
more than 3 sigma off the covariance along it (its NEES above 9 from that alone)."""


def mirrored(p: Pass, X: np.ndarray) -> np.ndarray:
    """The block values ``X`` (N, n) with every further spacecraft's orbit reflected through
    the first's, ``x_s -> 2 x_1 - x_s`` (relative position and velocity negated): the other
    minimum that ranges between the spacecraft allow when their lever arms barely tell the
    direction (one link each way per epoch)."""
    lay = p.layout
    out = np.array(X, dtype=float, copy=True)
    for v in lay.orbits[1:]:
        sl = lay.slices[v.name]
        out[:, sl] = 2.0 * X[:, :6] - X[:, sl]
    return out


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0.0, n, 1.0)


def turned_about(p: Pass, X: np.ndarray, moved: str, pivot: str, how: str) -> np.ndarray:
    """The block values ``X`` (N, n) with spacecraft ``moved``'s orbit (a layout orbit name)
    reflected, at every epoch, through a plane containing the line from the first spacecraft
    to ``pivot``: ``x -> x_1 + R (x - x_1)`` for position and velocity, ``R = I - 2 n n^T``
    (Householder). Its ranges to the first spacecraft and to ``pivot`` are unchanged. With
    ``a`` the line's direction, ``h`` the first spacecraft's orbit normal (the radial
    direction where ``a`` lies near ``h``), ``u = a x h / |a x h|`` and ``w = a x u``:
    ``how`` = ``"in-plane"`` reflects through the plane of ``a`` and ``h`` (``n = u``),
    ``"out-of-plane"`` through the plane of ``a`` and ``u`` (``n = w``), ``"half-turn"``
    both (a half turn about the line, ``R = 2 a a^T - I``)."""
    lay = p.layout
    out = np.array(X, dtype=float, copy=True)
    r1, v1 = X[:, :3], X[:, 3:6]
    a = _unit(X[:, lay.slices[pivot]][:, :3] - r1)
    h = _unit(np.cross(r1, v1))
    u = np.cross(a, h)
    weak = np.linalg.norm(u, axis=1) < 0.1      # the line near the orbit normal
    u[weak] = np.cross(a[weak], _unit(r1[weak]))
    u = _unit(u)
    w = _unit(np.cross(a, u))
    normals = {"in-plane": (u,), "out-of-plane": (w,), "half-turn": (u, w)}[how]
    sl = lay.slices[moved]
    x = X[:, sl][:, :6] - X[:, :6]
    for n in normals:
        for j in (slice(0, 3), slice(3, 6)):
            x[:, j] -= 2.0 * np.sum(x[:, j] * n, axis=1, keepdims=True) * n
    out[:, sl.start:sl.start + 6] = X[:, :6] + x
    return out


def alternative_geometries(p: Pass, X: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """The other relative geometries the links may allow, each as (description, block values
    (N, n)): the mirror through the first spacecraft (:func:`mirrored`) and, with three
    spacecraft or more, every further spacecraft turned about the line from the first to
    each other further one (:func:`turned_about`, three ways)."""
    lay = p.layout
    names = {v.name: sc for v, sc in zip(lay.orbits, p.spacecraft)}
    first = p.spacecraft[0]
    out = [(f"the relative geometry mirrored through {first}", mirrored(p, X))]
    for v in lay.orbits[1:]:
        for t in lay.orbits[1:]:
            if t.name == v.name:
                continue
            for how in ("in-plane", "out-of-plane", "half-turn"):
                out.append((f"{names[v.name]} reflected about the {first}-{names[t.name]} line "
                            f"({how})", turned_about(p, X, v.name, t.name, how)))
    return out


def mirror_test(p: Pass, sol, options, smooth_batch) -> dict:
    """The batch from the solution and from each other relative geometry the links may allow
    (:func:`alternative_geometries`: the mirror through the first spacecraft; with three
    spacecraft or more, each further one turned about a line through two others), compared
    by chi-square (the integrity issue, item 1: links through one antenna each way put sat2
    950 m behind sat1 instead of ahead, relative NEES 3e11, and the verdict said ok).
    ``status`` is ``failed`` when another geometry's minimum fits better (the solution is the
    wrong minimum) or within :data:`MIRROR_MARGIN_CHI2` (the data cannot choose), else
    ``ok``; ``geometry`` names it. ``chi2_mirrored``, ``mirror_converged``,
    ``distinct_minimum`` and ``largest_difference_m`` are the mirror's (the first
    alternative), or the failing alternative's; ``alternatives`` lists each.
    ``smooth_batch(p, options, x_init=X)``: the batch smoother
    (:func:`fgnav.solvers.batch.smooth_batch`, given by the pipeline: the diagnostics sit
    below the solvers)."""

    # at the requested process noise at once, and at most MIRROR_MAX_ITERATIONS: a mirror the
    # lever arms refute stays far above the solution's chi-square (formation-gto with every
    # link: 1.4e6 against 593), and Gauss-Newton walking it back reaches the same minimum
    quick = replace(options, q_start_m2_s3=options.q_m2_s3, max_iterations=MIRROR_MAX_ITERATIONS)
    X = block_values(p, sol.x_eci, sol.variables)
    # (iSAM2's final trajectory is Gauss-Newton's over the whole chain: the batch optimum)
    here = sol if sol.method in ("batch", "isam2") else smooth_batch(p, quick, x_init=X)
    chi2 = float(here.chi2)
    X_here = block_values(p, here.x_eci, here.variables)
    alternatives = []
    for geometry, X_alt in alternative_geometries(p, X_here):
        try:
            there = smooth_batch(p, quick, x_init=X_alt)
        except (ModelDomainError, NotObservableError):   # it leaves the models' domain
            there = None
        alt = _alternative(p, here, there)
        alt["geometry"] = geometry
        alt["status"] = ("failed" if alt["distinct_minimum"]
                         and alt["chi2_mirrored"] < chi2 + MIRROR_MARGIN_CHI2 else "ok")
        alternatives.append(alt)
    failing = [a for a in alternatives if a["status"] == "failed"]
    pick = min(failing, key=lambda a: a["chi2_mirrored"]) if failing else alternatives[0]
    out = {"status": pick["status"], "chi2": chi2,
           **{k: pick[k] for k in ("chi2_mirrored", "mirror_converged", "distinct_minimum",
                                   "largest_difference_m", "geometry")}}
    if len(alternatives) > 1:
        out["alternatives"] = alternatives
    return out


def _alternative(p: Pass, here, there) -> dict:
    """One alternative's minimum against the solution ``here``: its chi-square, and whether
    it is another minimum, not the same one reached again (some further spacecraft's
    relative position differs by more than 1 % of its separation, and 1 m)."""
    if there is None:   # the alternative leaves the models' domain
        return {"chi2_mirrored": math.inf, "mirror_converged": False,
                "distinct_minimum": True, "largest_difference_m": 0.0}
    moved, distinct = [], False
    for v in p.layout.orbits[1:]:
        if v.name in here.variables and v.name in there.variables:
            rel_here = here.variables[v.name][0][:, :3] - here.x_eci[:, :3]
            rel_there = there.variables[v.name][0][:, :3] - there.x_eci[:, :3]
            d = float(np.max(np.linalg.norm(rel_there - rel_here, axis=1)))
            moved.append(d)
            distinct |= d > max(1.0, 0.01 * float(np.median(np.linalg.norm(rel_here, axis=1))))
    return {"chi2_mirrored": float(there.chi2),
            "mirror_converged": bool(there.extras.get("converged", False)),
            "distinct_minimum": bool(distinct),
            "largest_difference_m": max(moved) if moved else 0.0}


def range_curvature_test(p: Pass, sol) -> dict:
    """Does the linear covariance of each pair of spacecraft's relative position describe
    its range? With ``d = r_j - r_c`` (ECI), ``u = d/|d|``, ``P`` the covariance of ``d``
    (from the joint block covariance) and ``P_perp = (I - u u^T) P (I - u u^T)``, a cross-line
    excursion of one sigma moves the range by ``b = tr(P_perp) / (2 |d|)`` (the sphere's
    second-order term, ``|d + e| = |d| + u.e + |e_perp|^2 / (2 |d|)``: the intrinsic
    curvature of Bates & Watts 1980 for one range), which the covariance along the line,
    ``s = sqrt(u^T P u)``, must cover.
    ``status`` is ``suspect`` when the largest ``b / s`` over pairs and epochs exceeds
    :data:`CURVATURE_LIMIT`: the errors are then bent about the data's spheres and the
    Cartesian covariance understates them (a NEES far above its dimension)."""
    lay, P = p.layout, sol.P_block
    worst = {"status": "ok", "ratio": 0.0}
    if P is None or len(lay.orbits) < 2:
        return worst
    names = {v.name: sc for v, sc in zip(lay.orbits, p.spacecraft)}
    X = block_values(p, sol.x_eci, sol.variables)
    for i, c in enumerate(lay.orbits):
        for j in lay.orbits[i + 1:]:
            a, b = lay.slices[c.name].start, lay.slices[j.name].start
            d = X[:, b:b + 3] - X[:, a:a + 3]
            Pd = (P[:, b:b + 3, b:b + 3] + P[:, a:a + 3, a:a + 3]
                  - P[:, b:b + 3, a:a + 3] - P[:, a:a + 3, b:b + 3])
            r = np.linalg.norm(d, axis=1)
            u = d / r[:, None]
            along = np.einsum("ni,nij,nj->n", u, Pd, u)
            across = np.trace(Pd, axis1=1, axis2=2) - along
            bend = across / (2.0 * r)
            # the difference of two absolute covariances resolves the relative one only to
            # their rounding: a heliocentric pair (1e13 m^2 each) to ~1e-2 m^2, above a 1 cm
            # link's along-line variance, which came out 0 (ratio 1e148); below that floor
            # the along-line sigma is not known, and the floor is used (along_resolved)
            floor = RESOLUTION_EPS * (np.trace(P[:, a:a + 3, a:a + 3], axis1=1, axis2=2)
                                      + np.trace(P[:, b:b + 3, b:b + 3], axis1=1, axis2=2))
            resolved = along >= floor
            along = np.maximum(along, floor)
            ratio = bend / np.sqrt(np.maximum(along, 1e-300))
            k = int(np.argmax(ratio))
            if ratio[k] > worst["ratio"]:
                worst = {"status": "suspect" if ratio[k] > CURVATURE_LIMIT else "ok",
                         "ratio": float(ratio[k]), "reference": names[c.name],
                         "spacecraft": names[j.name], "epoch_index": k,
                         "separation_m": float(r[k]), "bend_m": float(bend[k]),
                         "sigma_along_m": float(np.sqrt(max(along[k], 0.0))),
                         "sigma_across_m": float(np.sqrt(max(across[k], 0.0))),
                         "along_resolved": bool(resolved[k])}
    return worst
