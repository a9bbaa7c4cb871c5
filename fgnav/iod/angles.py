"""Initial orbit determination (IOD) from geocentric directions (and ranges), without an
a-priori state.

A smoother needs a first guess of the orbit. Logs usually carry it as ``prior_position`` /
``prior_velocity`` rows, but a CCSDS TDM never does, and a prior may be wrong. This module
(the angles method of :mod:`fgnav.iod`; :func:`fgnav.iod.initial.initial_orbit` chooses it
when the pass has the directions) computes the orbit from the geocentric directions (``earth_direction`` rows, and
``earth_direction_body`` rows once rotated to ECI, with the attitude row at their epoch even
when the attitude is estimated), adding the range-type rows
(``limb_radius``, ``altitude``) when the log has them.

Why not Gauss or Laplace
------------------------
A direction row measures ``u = -r/|r|``: the observer is, in effect, at the centre of
attraction. The classical angles-only methods (Gauss, Laplace, double-r iteration;
Vallado 2013, sec. 7.3) solve for the range from an observer *displaced* from the centre
(a ground station): here that displacement is zero and their equations degenerate. What
the directions do give is the orbital plane and the in-plane angle of the spacecraft as a
function of time; by Kepler's laws that history fixes the shape (e), the orientation
(argument of the reference direction) and the mean motion n, and the time of flight fixes
the scale through Kepler's third law ``a = (mu / n^2)^(1/3)``.

Method
------
1. *Plane.* The unit positions ``r_hat = -u`` lie on a great circle; its normal ``h_hat`` is
   the right singular vector of the stacked ``r_hat`` with the smallest singular value, its
   sign chosen so that ``sum_i r_hat_i x r_hat_(i+1)`` (the sense of motion) is along
   ``+h_hat``. In-plane basis ``p`` (the first direction projected on the plane) and
   ``q = h_hat x p``; the argument ``theta = atan2(r_hat.q, r_hat.p)``, unwrapped in time.
2. *Angle history.* ``theta(t) = omega + nu(M0 + n (t - t_ref), e)`` with the true anomaly
   ``nu`` from Kepler's equation ``M = E - e sin E`` (Newton's method; Vallado 2013,
   Algorithm 2) and ``tan(nu/2) = sqrt((1+e)/(1-e)) tan(E/2)`` (Vallado 2013, eq. 2-14;
   Curtis 2014, eq. 3.13). The four parameters (n, e, omega, M0) are found by a grid over e
   (0 to 0.9) and n (around the observed mean angular rate; a factor 15 below to 6 above it
   for arcs shorter than a revolution, where an eccentric orbit's rate is far from its mean
   motion), a grid over M0 with omega solved in closed form (the mean residual), then
   Levenberg-Marquardt (scipy ``least_squares``) from the best grid points. The state at
   ``t_ref`` follows from the elements (Curtis 2014, eqs. 2.31, 2.48, 2.49; radial and
   transverse velocity ``sqrt(mu/p) e sin nu`` and ``sqrt(mu/p) (1 + e cos nu)``).
3. *Ranges.* A ``limb_radius`` row gives ``|r| = R_limb / sin(rho)``, an ``altitude`` row
   ``|r| = r_ref + h``; with a direction at the same epoch, a position ``r = |r| r_hat``.
   Three such positions spread over the arc give the velocity by Gibbs' method (Vallado
   2013, Algorithm 54; Curtis 2014, Algorithm 5.1), or by the Herrick-Gibbs formula when
   they span less than 3 deg (Vallado 2013, Algorithm 55): another candidate start.
4. *Refinement.* From each candidate, Levenberg-Marquardt on the 6-state at ``t_ref``
   (:func:`fgnav.iod.fit.fit_orbit`) over the actual whitened residuals of the direction
   and range rows (the same linearizers as the smoothers, :func:`fgnav.graph.linearize_all`) with the project's propagator (RK4
   with its exact state-transition matrix, :func:`factors.dynamics.propagate`), over an
   evenly spaced subsample of at most ``MAX_EPOCHS`` epochs (a 4 h pass at 1 Hz has
   14,401); the candidate of least cost wins. Its covariance is the inverse of the
   Gauss-Newton information ``(A^T A)^-1`` of the subsample, scaled by the fit's
   ``rms^2`` when that exceeds 1 (a model that does not fit to the noise), so it is
   conservative: the subsample holds only part of the data.

Sessions: the angle must be followed in time, so a gap across which it may have turned by
more than 2 rad (the angular rate beside the gap times its length) splits the log, and the
fit uses the longest session (its orbit is then propagated to any other epoch).

Limits: elliptic orbits (e < 0.98); the arc must show curvature in time (a few minutes of
a LEO pass, tens of minutes higher up) or the problem is not observable from the
directions alone, which is reported. Refraction rows and body-frame Moon/Sun directions
cannot start an orbit and are not used here.

References
----------
- D. A. Vallado, *Fundamentals of Astrodynamics and Applications*, 4th ed., Microcosm
  Press, 2013: Kepler's equation (Algorithm 2), true anomaly from the eccentric anomaly
  (eq. 2-14), Gibbs (Algorithm 54), Herrick-Gibbs (Algorithm 55), angles-only IOD (sec. 7.3).
- R. H. Battin, *An Introduction to the Mathematics and Methods of Astrodynamics*, rev. ed.,
  AIAA, 1999: Kepler's equation and the orbital elements (ch. 4), the time of flight.
- H. D. Curtis, *Orbital Mechanics for Engineering Students*, 3rd ed., Butterworth-Heinemann,
  2014: the state from the elements (ch. 2, 4), Gibbs' method (Algorithm 5.1).
- K. Levenberg, "A method for the solution of certain non-linear problems in least
  squares", *Quarterly of Applied Mathematics* 2, 1944; D. W. Marquardt, *SIAM J. Appl.
  Math.* 11, 1963.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from factors.jit import njit

from factors.dynamics import MotionModel, propagate
from fgnav.errors import UserError
from fgnav.iod.fit import InitialOrbit, fit_covariance, fit_orbit
from fgnav.measurements import Family, Pass
from fgnav.models.registry import EARTH_DIRECTION, MODELS, PRIOR_POSITION, PRIOR_VELOCITY

__all__ = ["angles_initial_orbit", "geocentric_directions", "gibbs", "herrick_gibbs",
           "velocity_from_three_positions", "DIRECTION_KINDS", "RANGE_KINDS",
           "BODY_DIRECTION_KINDS", "MIN_DIRECTION_EPOCHS", "MAX_EPOCHS", "PRIOR_ROWS"]

MAX_EPOCHS = 240          # epochs of the subsample the refinement uses
MIN_DIRECTION_EPOCHS = 4  # 6 unknowns, 2 rows per direction: 3 epochs, plus one to check
DIRECTION_KINDS = (EARTH_DIRECTION.kind,)
"""Kinds whose rows are the unit vector spacecraft -> Earth centre in ECI (values ``u_eci``):
the initial orbit's own table of the kinds it reads as geocentric directions (a capability of
this consumer, not a field of every model)."""
RANGE_KINDS = tuple(k for k, m in MODELS.items() if m.range_m is not None)
"""Kinds whose rows give the geocentric distance |r| (the model's ``range_m``)."""
_FIT_KINDS = DIRECTION_KINDS + RANGE_KINDS
BODY_DIRECTION_KINDS = tuple(k for k, m in MODELS.items() if m.body_frame_of in DIRECTION_KINDS)
"""Body-frame kinds that become :data:`DIRECTION_KINDS` rows with the attitude."""
PRIOR_ROWS = f"'{PRIOR_POSITION.kind}' and '{PRIOR_VELOCITY.kind}' rows"
"""The prior rows, as the messages name them."""
_E_GRID = np.array([0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9])
_M0_GRID = np.linspace(-np.pi, np.pi, 24, endpoint=False)




def geocentric_directions(p: Pass) -> tuple[np.ndarray, np.ndarray]:
    """Epoch indices (M,) and unit vectors spacecraft -> Earth centre, ECI (M, 3), of every
    geocentric-direction row of the pass (stably sorted by epoch)."""
    fams = [p.families[k] for k in DIRECTION_KINDS if k in p.families]
    if not fams:
        return np.zeros(0, dtype=int), np.zeros((0, 3))
    k = np.concatenate([f.k for f in fams])
    u = np.concatenate([f.values["u_eci"] for f in fams])
    order = np.argsort(k, kind="stable")
    return k[order], u[order]


# ------------------------------------------------------------------------- Kepler pieces

@njit(cache=True)
def _nu_continuous_nb(M, e, out):
    """Kernel of :func:`_true_anomaly_continuous` over flat arrays (e broadcast by the caller)."""
    for i in range(M.shape[0]):
        ei = e[i]
        Mw = (M[i] + math.pi) % (2.0 * math.pi) - math.pi
        # Kepler's equation M = E - e sin E by Newton's method (Vallado 2013, Algorithm 2)
        # from Danby's start E = M + 0.85 e sign(sin M), which converges for every e < 1
        E = Mw + (0.85 * ei if math.sin(Mw) >= 0.0 else -0.85 * ei)
        for _ in range(50):
            dE = (E - ei * math.sin(E) - Mw) / (1.0 - ei * math.cos(E))
            E -= dE
            if abs(dE) < 1e-13:
                break
        nu = 2.0 * math.atan2(math.sqrt(1.0 + ei) * math.sin(0.5 * E),
                              math.sqrt(1.0 - ei) * math.cos(0.5 * E))
        c = (nu - Mw + math.pi) % (2.0 * math.pi) - math.pi  # the equation of centre
        out[i] = M[i] + c


def _true_anomaly_continuous(M, e):
    """True anomaly (rad) from the mean anomaly M (rad) and eccentricity e, continuous in M
    (unwrapped alongside it): M plus the equation of centre. Broadcasts M and e."""
    M, e = np.broadcast_arrays(np.asarray(M, dtype=float), np.asarray(e, dtype=float))
    out = np.empty(M.size)
    _nu_continuous_nb(np.ascontiguousarray(M).ravel(), np.ascontiguousarray(e).ravel(), out)
    return out.reshape(M.shape)


def _state_from_elements(n, e, omega, M, p_hat, q_hat, h_hat, mu):
    """ECI state from mean motion n (rad/s), e, in-plane angle of perigee omega from p_hat,
    mean anomaly M (Curtis 2014, eqs. 2.31, 2.48, 2.49; a from Kepler's third law)."""
    a = (mu / n ** 2) ** (1.0 / 3.0)
    nu = _true_anomaly_continuous(np.array([M]), e)[0]
    slr = a * (1.0 - e * e)
    r = slr / (1.0 + e * math.cos(nu))
    th = omega + nu
    r_hat = math.cos(th) * p_hat + math.sin(th) * q_hat
    t_hat = np.cross(h_hat, r_hat)
    s = math.sqrt(mu / slr)
    return np.concatenate([r * r_hat, s * e * math.sin(nu) * r_hat + s * (1.0 + e * math.cos(nu)) * t_hat])


# ------------------------------------------------------------------------- plane and angles

def _plane(r_hat):
    """Orbit normal from the unit positions (N,3), signed by the sense of motion; in-plane
    basis (p, q) and the unwrapped angle theta (N,) of each position."""
    _, s, Vt = np.linalg.svd(r_hat, full_matrices=False)
    h = Vt[-1]
    turn = np.sum(np.cross(r_hat[:-1], r_hat[1:]), axis=0)
    if s[1] < 1e-3 * s[0]:
        # an arc too short for the SVD: the plane of the turning directions
        if np.linalg.norm(turn) == 0:
            raise UserError("the directions do not move: no orbit plane from them")
        h = turn / np.linalg.norm(turn)
    if h @ turn < 0:
        h = -h
    p_hat = r_hat[0] - (r_hat[0] @ h) * h
    p_hat /= np.linalg.norm(p_hat)
    q_hat = np.cross(h, p_hat)
    theta = np.unwrap(np.arctan2(r_hat @ q_hat, r_hat @ p_hat))
    return h, p_hat, q_hat, theta


def _session(t, r_hat, t_near=None, max_turn_rad=2.0):
    """The slice of the longest run of directions whose angle can be followed in time (or,
    with ``t_near``, of the run nearest that time): a gap splits the log when the angle it
    may hide (the faster of the angular rates on its two sides times its length) exceeds
    ``max_turn_rad`` (unwrapping needs < pi)."""
    if len(t) < 3:
        return slice(0, len(t))
    dt = np.diff(t)
    ang = np.arccos(np.clip(np.einsum("ij,ij->i", r_hat[:-1], r_hat[1:]), -1.0, 1.0))
    rate = ang / np.where(dt > 0, dt, np.inf)
    # the angular rate beside each step: the larger of its neighbours' (a gap is not its own
    # witness); an isolated first/last step uses its one neighbour
    near = np.maximum(np.concatenate([[0.0], rate[:-1]]), np.concatenate([rate[1:], [0.0]]))
    cut = np.flatnonzero(np.maximum(near, rate) * dt > max_turn_rad)
    bounds = np.concatenate([[0], cut + 1, [len(t)]])
    if t_near is None:
        i = int(np.argmax(np.diff(bounds)))
    else:
        first, last = t[bounds[:-1]], t[bounds[1:] - 1]
        i = int(np.argmin(np.maximum(first - t_near, 0.0) + np.maximum(t_near - last, 0.0)))
    return slice(int(bounds[i]), int(bounds[i + 1]))


def _angle_fit(t, theta, mu):
    """(n, e, omega, M0) candidates, best first, fitted to theta(t) (t from t_ref)."""
    from scipy.optimize import least_squares

    span_t = t[-1] - t[0]
    span_th = theta[-1] - theta[0]
    n_bar = max(span_th / span_t, 1e-9)
    revs = span_th / (2 * np.pi)
    n_max = math.sqrt(mu / 6.0e6 ** 3)
    if revs >= 1.0:
        n_grid = n_bar * np.linspace(revs / (revs + 1.0), (revs + 1.0) / revs, 40)
    else:
        n_grid = n_bar * np.geomspace(1.0 / 15.0, 6.0, 48)
    n_grid = n_grid[n_grid < n_max]
    if len(n_grid) == 0:
        n_grid = np.array([min(n_bar, 0.99 * n_max)])
    # coarse grid on a subsample of the angles: cost with omega in closed form
    g = np.unique(np.linspace(0, len(t) - 1, min(len(t), 48)).round().astype(int))
    tg, thg = t[g], theta[g]
    E_, N_, M_ = np.meshgrid(_E_GRID, n_grid, _M0_GRID, indexing="ij")
    Mall = M_[..., None] + N_[..., None] * tg
    nu = _true_anomaly_continuous(Mall, E_[..., None])
    d = thg - nu
    d -= d.mean(axis=-1, keepdims=True)
    cost = np.sum(d * d, axis=-1)
    order = np.argsort(cost, axis=None)
    f = np.unique(np.linspace(0, len(t) - 1, min(len(t), 400)).round().astype(int))
    t, theta = t[f], theta[f]

    def resid(x):
        n, e, om, M0 = x
        return theta - om - _true_anomaly_continuous(M0 + n * t, e)

    out, seen = [], set()
    for flat in order:
        i, j, l = np.unravel_index(flat, cost.shape)
        key = (i, j)
        if key in seen:
            continue
        seen.add(key)
        n0, e0, M00 = n_grid[j], _E_GRID[i], _M0_GRID[l]
        om0 = float(np.mean(thg - _true_anomaly_continuous(M00 + n0 * tg, e0)))
        try:
            sol = least_squares(resid, [n0, e0, om0, M00], x_scale=[n0, 0.1, 0.1, 0.1],
                                bounds=([n0 * 0.2, 0.0, -np.inf, -np.inf],
                                        [min(n0 * 5.0, n_max), 0.98, np.inf, np.inf]),
                                max_nfev=200)
        except ValueError:
            continue
        out.append((float(np.mean(sol.fun ** 2)), sol.x))
        if len(seen) >= 6:
            break
    out.sort(key=lambda c: c[0])
    return out


# ------------------------------------------------------------------------- ranges and Gibbs

def _range_positions(p: Pass, u_by_k: dict):
    """Epoch indices (M,) and ECI positions (M,3) where a range row and a direction coincide."""
    ks, rs = [], []
    for kind in RANGE_KINDS:
        fam = p.families.get(kind)
        if fam is None:
            continue
        with np.errstate(divide="ignore", invalid="ignore"):   # kept only when finite, > 0
            rng = np.asarray(MODELS[kind].range_m(fam), dtype=float)
        for k, r in zip(fam.k.tolist(), rng.tolist()):
            if k in u_by_k and np.isfinite(r) and r > 0:
                ks.append(k)
                rs.append(-r * u_by_k[k])
    if not ks:
        return np.zeros(0, int), np.zeros((0, 3))
    ks = np.asarray(ks)
    order = np.argsort(ks, kind="stable")
    return ks[order], np.asarray(rs)[order]


def gibbs(r1, r2, r3, mu):
    """Velocity (3,) at ``r2`` from three coplanar positions (3,) by Gibbs' method (Vallado
    2013, Algorithm 54; Curtis 2014, Algorithm 5.1):
    ``v2 = sqrt(mu / (N . D)) (D x r2 / |r2| + S)`` with
    ``N = |r1| r2 x r3 + |r2| r3 x r1 + |r3| r1 x r2``, ``D = r1 x r2 + r2 x r3 + r3 x r1``
    and ``S = r1 (|r2| - |r3|) + r2 (|r3| - |r1|) + r3 (|r1| - |r2|)`` (any consistent
    units, ``mu`` in length^3/time^2); None when ``N . D <= 0`` (no conic through them in
    that order)."""
    n1, n2, n3 = np.linalg.norm(r1), np.linalg.norm(r2), np.linalg.norm(r3)
    N = n1 * np.cross(r2, r3) + n2 * np.cross(r3, r1) + n3 * np.cross(r1, r2)
    D = np.cross(r1, r2) + np.cross(r2, r3) + np.cross(r3, r1)
    S = r1 * (n2 - n3) + r2 * (n3 - n1) + r3 * (n1 - n2)
    nd = N @ D
    if not nd > 0:
        return None
    return math.sqrt(mu / nd) * (np.cross(D, r2) / n2 + S)


def herrick_gibbs(r1, r2, r3, t1, t2, t3, mu):
    """Velocity (3,) at ``r2`` from three closely spaced positions at times ``t1 < t2 < t3``
    by the Herrick-Gibbs formula (Vallado 2013, Algorithm 55, eq. 7-28):
    ``v2 = -dt32 (1/(dt21 dt31) + mu/(12 r1^3)) r1
    + (dt32 - dt21) (1/(dt21 dt32) + mu/(12 r2^3)) r2
    + dt21 (1/(dt32 dt31) + mu/(12 r3^3)) r3``."""
    n1, n2, n3 = np.linalg.norm(r1), np.linalg.norm(r2), np.linalg.norm(r3)
    d21, d31, d32 = t2 - t1, t3 - t1, t3 - t2
    return (-d32 * (1.0 / (d21 * d31) + mu / (12.0 * n1 ** 3)) * r1
            + (d32 - d21) * (1.0 / (d21 * d32) + mu / (12.0 * n2 ** 3)) * r2
            + d21 * (1.0 / (d32 * d31) + mu / (12.0 * n3 ** 3)) * r3)


def velocity_from_three_positions(r1, r2, r3, t1, t2, t3, mu):
    """``(v2, method)``: :func:`gibbs` when both angles between consecutive positions exceed
    3 deg, else :func:`herrick_gibbs` (Vallado 2013, sec. 7.5.2: Gibbs loses accuracy below
    about 1-5 deg); ``v2`` None when Gibbs finds no conic."""
    n1, n2, n3 = np.linalg.norm(r1), np.linalg.norm(r2), np.linalg.norm(r3)
    ang12 = math.acos(np.clip(r1 @ r2 / (n1 * n2), -1, 1))
    ang23 = math.acos(np.clip(r2 @ r3 / (n2 * n3), -1, 1))
    if min(ang12, ang23) > math.radians(3.0):
        return gibbs(r1, r2, r3, mu), "gibbs"
    return herrick_gibbs(r1, r2, r3, t1, t2, t3, mu), "herrick-gibbs"


def _gibbs_start(p: Pass, u_by_k: dict, mu: float):
    """A state at ``k_ref`` from three range-derived positions spread over the arc, the
    ranges smoothed by a running median of 11 rows; None when there are too few."""
    ks, R = _range_positions(p, u_by_k)
    if len(ks) < 3:
        return None
    norms = np.linalg.norm(R, axis=1)
    picks = np.unique(np.clip(np.round(np.array([0.15, 0.5, 0.85]) * (len(ks) - 1)).astype(int),
                              0, len(ks) - 1))
    if len(picks) < 3:
        picks = np.array([0, len(ks) // 2, len(ks) - 1])
    pos = []
    for i in picks:
        lo, hi = max(0, i - 5), min(len(ks), i + 6)
        pos.append(R[i] / norms[i] * np.median(norms[lo:hi]))
    t = p.t_s[ks[picks]]
    if len(np.unique(t)) < 3:
        return None
    v2, how = velocity_from_three_positions(pos[0], pos[1], pos[2], t[0], t[1], t[2], mu)
    if v2 is None or not np.all(np.isfinite(v2)):
        return None
    x = np.concatenate([pos[1], v2])
    return x, int(ks[picks[1]]), how


# ------------------------------------------------------------------------- refinement

def _subpass(p: Pass, k_sub: np.ndarray) -> Pass:
    """The direction and range rows at the epochs ``k_sub`` only, re-indexed 0..len-1."""
    remap = -np.ones(p.n_epochs, dtype=int)
    remap[k_sub] = np.arange(len(k_sub))
    fams = {}
    for kind in _FIT_KINDS:
        f = p.families.get(kind)
        if f is None:
            continue
        rows = np.flatnonzero(remap[f.k] >= 0)
        if len(rows):
            fams[kind] = Family(k=remap[f.k[rows]], values={n: v[rows] for n, v in f.values.items()},
                                sigma=f.sigma[rows], line=f.line[rows])
    return Pass(epoch0=p.epoch0, t_s=p.t_s[k_sub], families=fams, source=p.source)


def angles_initial_orbit(p: Pass, model: MotionModel, t0_j2000_s: float,
                         near_k: int | None = None) -> InitialOrbit:
    """The orbit from the pass's geocentric directions (ECI; body-frame ones rotated first,
    :func:`fgnav.measurements.directions_in_eci`) and range rows, steps 1-4 of the module
    docstring, on the longest session (or the one nearest epoch ``near_k``). Raises
    :class:`UserError` when one session has too few direction epochs or no start converges;
    numerical failures (``ValueError``, ``ArithmeticError``, ``LinAlgError``) propagate."""
    mu = model.mu
    k_dir, u_dir = geocentric_directions(p)
    r_hat = -u_dir
    r_hat = r_hat / np.linalg.norm(r_hat, axis=1)[:, None]
    # one direction per epoch for the geometry (the first, if several)
    first = np.concatenate([[True], np.diff(k_dir) > 0])
    k_dir, r_hat = k_dir[first], r_hat[first]
    seg = _session(p.t_s[k_dir], r_hat, None if near_k is None else float(p.t_s[near_k]))
    k_dir, r_hat = k_dir[seg], r_hat[seg]
    if len(k_dir) < MIN_DIRECTION_EPOCHS:
        raise UserError(f"{p.source}: too few direction epochs in one session for an initial "
                        f"orbit; add {PRIOR_ROWS}")
    u_by_k = {k: -r for k, r in zip(k_dir.tolist(), r_hat)}
    t_dir = p.t_s[k_dir]
    # the epochs of the refinement: an even subsample of those with fit rows in the session
    k_fit = np.unique(np.concatenate([p.families[k].k for k in _FIT_KINDS if k in p.families]))
    k_fit = k_fit[(k_fit >= k_dir[0]) & (k_fit <= k_dir[-1])]
    k_sub = k_fit[np.unique(np.linspace(0, len(k_fit) - 1, min(len(k_fit), MAX_EPOCHS)).round().astype(int))]
    # the reference epoch: the subsample epoch nearest the middle of the arc
    k_ref = int(k_sub[np.argmin(np.abs(p.t_s[k_sub] - 0.5 * (t_dir[0] + t_dir[-1])))])
    t_ref = float(p.t_s[k_ref])
    sp = _subpass(p, k_sub)
    # RK4 sub-steps of up to 20 s: ~0.1 m per hour on the Pan & Yao 2017 transfer orbit and a
    # LEO (error ~ h^4 from the 5 s figures in factors.dynamics), far below the IOD's sigma.
    fit_model = replace(model, max_step_s=max(model.max_step_s, 20.0))

    starts = []
    h_hat, p_hat, q_hat, theta = _plane(r_hat)
    for _, (n, e, om, M0) in _angle_fit(t_dir - t_ref, theta, mu)[:3]:
        starts.append(("angles-kepler", _state_from_elements(n, e, om, M0, p_hat, q_hat, h_hat, mu)))
    g = _gibbs_start(p, u_by_k, mu)
    if g is not None:
        x_g, k_g, how = g
        if k_g != k_ref:
            x_g = propagate(x_g, t_ref - p.t_s[k_g], fit_model, t0_j2000_s + p.t_s[k_g], with_stm=False)[0]
        starts.append((how, x_g))
    # Each start a few iterations, then the best of them to convergence.
    fits = []
    for how, x0 in starts:
        if np.all(np.isfinite(x0)):
            fit = fit_orbit(sp, x0, t_ref, fit_model, t0_j2000_s, max_iterations=4)
            if fit is not None:
                fits.append((fit[3], how, fit[0]))
    best = None
    if fits:
        _, how, x0 = min(fits, key=lambda f: f[0])
        fit = fit_orbit(sp, x0, t_ref, fit_model, t0_j2000_s)
        best = None if fit is None else (how, fit)
    if best is None:
        raise UserError(f"{p.source}: no initial orbit could be fitted to the directions "
                        f"({p.counts()}); add {PRIOR_ROWS}")
    how, (x, r, A, cost) = best
    rms = math.sqrt(cost / len(r))
    try:
        P = fit_covariance(A, rms)
    except np.linalg.LinAlgError:
        P = np.full((6, 6), np.inf)
    if not (np.all(np.isfinite(P)) and np.all(np.linalg.eigvalsh(P) > 0)):
        raise UserError(f"{p.source}: the directions alone do not determine the orbit "
                        f"({p.counts()} over {p.t_s[-1] - p.t_s[0]:.0f} s): add {PRIOR_ROWS}, "
                        f"range-type rows or a longer arc")
    return InitialOrbit(k_ref=k_ref, x_eci=x, P_eci=P, method=f"{how}+lm", n_used=len(k_sub),
                        t_span_s=(float(t_dir[0]), float(t_dir[-1])),
                        rms_whitened=rms)


