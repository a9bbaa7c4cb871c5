"""Where the smoothers start: the log's prior, or the initial orbit of the measurements alone
(:mod:`fgnav.iod`), and the test of the one against the other.

See :func:`start_point` and the README, "No prior".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from factors.constants import AU_M, R_SUN_M
from factors.dynamics import MotionModel
from factors.geometry import so3_exp
from fgnav.errors import UserError
from fgnav.iod.fit import InitialOrbit
from fgnav.iod.initial import initial_orbit, iod_support, propagate_orbit, trajectory
from fgnav.iod.links import far_field_guess, logged_epoch
from fgnav.graph import initial_block, prior_block_covariance
from fgnav.iod.single_epoch import solve_single_epoch
from fgnav.chi2 import chi2_ppf
from fgnav.iod.prior import has_prior, initial_guess, strip_prior, with_start_prior
from fgnav.io.log_spacecraft import ISL_KINDS, spacecraft_index
from fgnav.measurements import (Family, Pass, covering_sigmas, orbit_columns, prior_covariance,
                                prior_state, spacecraft_pass)
from fgnav.models.model import COLUMN_PREFIX
from fgnav.models.registry import ATTITUDE, PRIOR_POSITION, PRIOR_VELOCITY, prior_kinds
from fgnav.solvers.batch import filtered_guess
from fgnav.time import add_seconds, format_utc

__all__ = ["prior_consistency", "start_point", "Start", "batch_first_guess",
           "formation_start", "link_fixes", "start_covariance", "with_formation_start_priors",
           "PRIOR_GATE_PROBABILITY", "START_INFLATION", "MAX_TEST_RMS"]

PRIOR_GATE_PROBABILITY = 1.0 - 1e-6


def prior_consistency(p: Pass, iod: InitialOrbit, model: MotionModel, t0_j2000_s: float,
                      probability: float = PRIOR_GATE_PROBABILITY) -> dict:
    """Does the log's prior agree with the orbit its measurements give?

    The initial orbit is propagated to the prior's epoch ``k0``; with ``d = x_prior - x_iod``
    and ``S = P_prior + P_iod`` the squared Mahalanobis distance ``d^T S^-1 d`` is
    chi-square with 6 degrees of freedom when both are right (the IOD uses no prior row, so
    the two are independent). The prior contradicts the data when it exceeds the quantile
    ``probability`` (default 1 - 1e-6: one false alarm in a million clean logs). The
    covariance is propagated linearly: use an initial orbit from data beside the prior's
    epoch (``initial_orbit(..., near_k=k0)``; :func:`start_point` does, and does not test a
    prior farther from that data than the data's own span).
    """
    k0, x_prior = prior_state(p)
    P_prior = prior_covariance(p, k0)
    x_iod, P_iod = propagate_orbit(iod, p, model, t0_j2000_s, k0)
    d = x_prior - x_iod
    S = P_prior + P_iod
    s = 1.0 / np.sqrt(np.diag(S))
    m2 = float((d * s) @ np.linalg.solve(S * np.outer(s, s), d * s))
    gate = chi2_ppf(probability, 6)
    return {"prior_mahalanobis": math.sqrt(max(m2, 0.0)), "prior_mahalanobis2": m2,
            "prior_dof": 6, "prior_gate_chi2": gate, "prior_gate_probability": probability,
            "prior_consistent": bool(m2 <= gate),
            "prior_position_offset_m": float(np.linalg.norm(d[:3])),
            "prior_velocity_offset_mps": float(np.linalg.norm(d[3:]))}


# ------------------------------------------------------------------------- the smoothers' start

START_INFLATION = 100.0  # covariance factor of the initial orbit when it starts a filter
MAX_TEST_RMS = 1.5       # the prior is tested only against a fit at the noise level


@dataclass
class Start:
    """Where the smoothers start: the pass they see, the first guess of every state, the
    batch first guess (None: the solver's own from the log's prior) and the summary entry."""

    p: Pass
    x_guess: np.ndarray
    x_init: np.ndarray | None
    info: dict
    synthetic_prior: bool = False
    how: str | None = None
    """How batch starts from ``x_init`` (:func:`batch_first_guess`); None: chosen there."""
    x_start: np.ndarray | None = None
    """The online methods' first block (n,) and its covariance ``P_start`` (n, n) where they
    do not come from the pass's prior rows (a formation's: :func:`formation_start`)."""
    P_start: np.ndarray | None = None

    def finish(self, sol):
        """Record the start in ``sol.extras["initial_orbit"]``; drop the residuals of a
        synthetic start prior (not a measurement of the log)."""
        if self.synthetic_prior:
            for kind in prior_kinds():
                sol.residuals.pop(kind, None)
        sol.extras["initial_orbit"] = self.info
        return sol


def _summary(iod: InitialOrbit, p: Pass) -> dict:
    return {"method": iod.method, "epoch_index": int(iod.k_ref), "t_s": float(p.t_s[iod.k_ref]),
            "position_sigma_m": float(math.sqrt(np.trace(iod.P_eci[:3, :3]))),
            "velocity_sigma_mps": float(math.sqrt(np.trace(iod.P_eci[3:, 3:]))),
            "rms_whitened": float(iod.rms_whitened), "n_used": int(iod.n_used)}


GEOCENTRIC_MAX_PRIOR_RANGE_M = 5.0e9
"""A geocentric log's prior further than this from the Earth (0.033 AU, three Hill-sphere
radii of 1.5e6 km) is refused: no orbit about the Earth is there."""


def check_prior_centre(p: Pass, centre: str) -> None:
    """``UserError`` naming the prior's log line when its position contradicts the log's
    centre: a geocentric prior beyond :data:`GEOCENTRIC_MAX_PRIOR_RANGE_M` (a heliocentric log
    whose ``# centre: sun`` line is missing, misplaced or says earth: solved about the Earth
    at 1 AU, it ran for hours), or a heliocentric one inside the Sun (its iterates reached
    the speed of light)."""
    if not has_prior(p):
        return
    k0, x0 = prior_state(p)
    r = float(np.linalg.norm(x0[:3]))
    fam = p.families[PRIOR_POSITION.kind]   # the line of the position row prior_state uses
    line = int(fam.line[np.flatnonzero(fam.k == k0)[0]])
    if centre == "earth" and r > GEOCENTRIC_MAX_PRIOR_RANGE_M:
        raise UserError(f"{p.source}, line {line}: the prior position lies {r / AU_M:.3g} AU "
                        f"from the Earth, beyond {GEOCENTRIC_MAX_PRIOR_RANGE_M:.3g} m where no "
                        f"orbit about the Earth is: if the log is heliocentric, its second line "
                        f"must be '# centre: sun' (fgnav.io.log_csv)")
    if centre == "sun" and r < R_SUN_M:
        raise UserError(f"{p.source}, line {line}: the prior position lies {r:.4g} m from the "
                        f"Sun's centre, inside the Sun (radius {R_SUN_M:.4g} m): a heliocentric "
                        f"log's positions are about the Sun (is the '# centre: sun' line meant?)")


def start_point(p: Pass, method: str, model: MotionModel, t0_j2000_s: float, *,
                ignore_prior: bool = False, options=None) -> Start:
    """Choose the smoothers' start (see the README, "No prior").

    * Several spacecraft: :func:`formation_start` (each spacecraft's own rows, the links;
      ``options`` for the filtered first guess).
    * The log has a prior (and ``ignore_prior`` is False): the prior starts the solvers;
      when the measurements support an initial orbit, :func:`prior_consistency` tests the
      prior against it, and a prior that contradicts the data no longer starts the solvers:
      batch keeps the prior in its graph but starts Gauss-Newton (and any robust kernel)
      from the initial orbit; the online methods (whose start *is* their prior) start from
      the initial orbit, covariance inflated by ``START_INFLATION``, in place of the prior.
    * No prior rows, or ``ignore_prior``: the initial orbit. Batch uses it as the first
      guess only (no prior factor: the solution is the measurements'); isam2 / fixed-lag /
      ekf start at epoch 0 from it with its covariance inflated by ``START_INFLATION``.
    """
    if len(p.spacecraft) > 1:
        q = replace(p, families=strip_prior(p).families) if ignore_prior else p
        return formation_start(q, method, model, t0_j2000_s, options)
    prior = has_prior(p) and not ignore_prior
    if prior:
        check_prior_centre(p, model.centre)
        x_guess = initial_guess(p, model, t0_j2000_s)
        info = {"prior": "log"}
        ok, why = iod_support(p)
        if not ok:
            info["consistency"] = f"not tested: {why.split(':')[0]}"
            return Start(p, x_guess, None, info)
        try:
            iod = initial_orbit(strip_prior(p), model, t0_j2000_s, near_k=prior_state(p)[0])
        except UserError as exc:  # every failure of the fit is one (initial_orbit)
            info["consistency"] = f"not tested: {exc}"
            return Start(p, x_guess, None, info)
        info.update(_summary(iod, p))
        t_prior = float(p.t_s[prior_state(p)[0]])
        t_a, t_b = iod.t_span_s
        away = max(t_a - t_prior, t_prior - t_b, 0.0)
        if away > t_b - t_a:
            info["consistency"] = (f"not tested: the prior's epoch is {away:.0f} s from the "
                                   f"session of data the initial orbit uses ({t_b - t_a:.0f} s "
                                   f"long), too far for a linear propagation of its covariance")
            return Start(p, x_guess, None, info)
        if iod.rms_whitened > MAX_TEST_RMS:
            info["consistency"] = (f"not tested: the initial orbit fits the data to whitened rms "
                                   f"{iod.rms_whitened:.2f} (> {MAX_TEST_RMS:g}): forces missing "
                                   f"from the motion model, or outliers")
            return Start(p, x_guess, None, info)
        info.update(prior_consistency(p, iod, model, t0_j2000_s))
        if info["prior_consistent"]:
            return Start(p, x_guess, None, info)
        x_iod = trajectory(iod, p, model, t0_j2000_s)
        if method == "batch":
            info["start"] = "initial orbit (the log's prior contradicts the data; it stays in the graph)"
            return Start(p, x_iod, x_iod, info)
        x0, P0 = propagate_orbit(iod, p, model, t0_j2000_s, 0)
        info["prior"] = "initial_orbit"
        info["start"] = (f"initial orbit at epoch 0, covariance inflated x{START_INFLATION:g}, in place "
                         f"of the log's prior, which contradicts the data")
        return Start(with_start_prior(p, x0, START_INFLATION * P0), x_iod, None, info,
                     synthetic_prior=True)
    q = strip_prior(p)
    iod = initial_orbit(q, model, t0_j2000_s)
    info = {"prior": "ignored" if has_prior(p) else "initial_orbit", **_summary(iod, p)}
    x_iod = trajectory(iod, p, model, t0_j2000_s)
    if method == "batch":
        info["start"] = "initial orbit as the first guess; no prior factor"
        return Start(q, x_iod, x_iod, info)
    x0, P0 = propagate_orbit(iod, p, model, t0_j2000_s, 0)
    info["start"] = f"initial orbit at epoch 0, covariance inflated x{START_INFLATION:g}"
    return Start(with_start_prior(q, x0, START_INFLATION * P0), x_iod, None, info,
                 synthetic_prior=True)


def batch_first_guess(start: Start, init: str, robust, short_pass: bool):
    """How batch Gauss-Newton starts from ``start``, chosen here and named, not inside the
    dispatch from the kernels' speed mode: ``(how, x_init)``.

    * ``"initial orbit"``: ``start.x_init`` (the initial orbit, already fitted to the data
      through the full dynamics): Gauss-Newton at the requested process noise at once, the
      continuation if that does not converge.
    * ``"prior, direct"``: a short pass (``short_pass``: the batch passes run as Python,
      :data:`fgnav.pipeline.SHORT_PASS_ROWS`) with no bridged gap, ``init == "auto"`` and
      no robust kernel: the prior propagated (``start.x_guess``), Gauss-Newton at the
      requested process noise first (:func:`fgnav.pipeline._batch_direct`), the
      continuation from the same guess if that gives up.
    * ``"prior"``: the same guess, the continuation only (``init`` other than ``"auto"``,
      or a robust kernel).
    * ``start.how`` where the start chose it (a formation's, :func:`formation_start`:
      ``"initial orbit"`` from every orbit filtered, ``"prior"`` otherwise).
    * ``"filter"``: ``None``: the batch smoother's own first guess (the compiled EKF and
      its RTS smoothing, iterated, :func:`fgnav.solvers.batch.smooth_batch`; the prior
      propagated where the filter does not apply).
    """
    if start.how is not None:
        return start.how, start.x_init
    if start.x_init is not None:
        return "initial orbit", start.x_init
    p = start.p
    if short_pass and not (p.inserted is not None and p.inserted.any()):
        direct = init == "auto" and robust is None
        return ("prior, direct" if direct else "prior"), start.x_guess
    return "filter", None


# ----------------------------------------------------------------- several spacecraft

LINK_FIX_EPOCHS = 24
"""Epochs (spread over the pass) at which :func:`link_fixes` solves the links alone."""


def link_fixes(log, max_epochs: int = LINK_FIX_EPOCHS):
    """The second spacecraft's position relative to the first (ECI, m) from the links alone
    at up to ``max_epochs`` epochs: Xing et al.'s single-epoch least squares on each epoch's
    six antenna-to-antenna pseudoranges (:func:`fgnav.iod.links.logged_epoch`, its
    far-field start on the side the antennas face), turned to ECI with the first
    spacecraft's attitude row. ``(t_s (F,), dr_eci (F, 3))``, or None where the log has no
    such epochs (centre-of-mass links: far apart, the spacecraft's own rows suffice).

    Why: two spacecraft 1 km apart, each started from its own celestial rows (km errors),
    leave the links' range sphere ambiguous, and Gauss-Newton settled in a wrong minimum in 1
    of 2 formation-gto passes (600 m relative error, flagged by the verdict)."""
    kinds = np.asarray(log.kind).astype(str)
    isl = np.flatnonzero(kinds == ISL_KINDS[0])
    if len(log.spacecraft) != 2 or not len(isl) or np.all(np.isnan(log.extra["rx_antenna"][isl])):
        return None
    t_isl, n = np.unique(np.asarray(log.t_s)[isl], return_counts=True)
    cand = t_isl[n == 6]
    if len(cand) < 3:
        return None
    pick = cand[np.unique(np.linspace(0, len(cand) - 1, max_epochs).astype(int))]
    att = np.flatnonzero((kinds == ATTITUDE.kind) & (spacecraft_index(log) == 0))
    t_att = np.asarray(log.t_s)[att]
    ts, dr = [], []
    for t in pick:
        try:
            ep = logged_epoch(log, format_utc(add_seconds(log.epoch0, np.array([t]))[0]))
            x0 = far_field_guess(ep.rho_m, ep.links, ep.face_m)
            sol = solve_single_epoch(ep.rho_m, ep.M21, "cartesian", x0, sigma_m=1.0,
                                     links=ep.links)
        except (UserError, ValueError, ArithmeticError, np.linalg.LinAlgError):
            continue   # (an epoch the links alone do not fix: the others may)
        j = np.flatnonzero(t_att == t)
        if not sol.converged or len(j) != 1:
            continue
        ts.append(float(t))
        dr.append(so3_exp(np.asarray(log.xyz, dtype=float)[att[j[0]]]) @ sol.r_m)
    return (np.array(ts), np.array(dr)) if len(ts) >= 3 else None


def formation_guess(p: Pass, model: MotionModel, t0_j2000_s: float, options=None):
    """Block values (N, n) to start from and whether every orbit was filtered: each
    spacecraft's orbit from its own rows (with ``options``, the filtered trajectory of the
    compiled EKF where it applies, as the one-spacecraft batch starts,
    :func:`fgnav.solvers.batch.filtered_guess`; else its prior propagated, or without a
    prior the orbit its measurements give, :func:`start_point`), the second placed from the
    first by the links where they fix it (``p.link_fixes``, :func:`link_fixes`), clocks and
    ambiguities at their prior mean (the links are linear in them: one Gauss-Newton step
    places them)."""
    lay = p.layout
    X = initial_block(p, np.zeros((p.n_epochs, 6)))[0]   # a measured attitude where one is
    filtered = True
    for s, v in enumerate(lay.orbits):
        sub = spacecraft_pass(p, s)
        if not sub.families:
            raise UserError(f"{p.source}: spacecraft '{p.spacecraft[s]}' has no rows of its own "
                            "(priors or celestial measurements): its orbit cannot be started")
        if s == 1 and p.link_fixes is not None:
            continue   # placed from the first spacecraft by the links (below)
        x = filtered_guess(sub, options) if options is not None and has_prior(sub) else None
        filtered &= x is not None
        if x is None:
            x = (initial_guess(sub, model, t0_j2000_s) if has_prior(sub) else
                 start_point(sub, "batch", model, t0_j2000_s).x_guess)
        X[:, lay.slices[v.name]] = x
    if p.link_fixes is not None:   # the second spacecraft relative to the first, from the links
        t_f, dr = p.link_fixes
        dv = np.gradient(dr, t_f, axis=0)
        s0, s1 = lay.slices[lay.orbits[0].name], lay.slices[lay.orbits[1].name]
        for i in range(3):
            X[:, s1.start + i] = X[:, s0.start + i] + np.interp(p.t_s, t_f, dr[:, i])
            X[:, s1.start + 3 + i] = X[:, s0.start + 3 + i] + np.interp(p.t_s, t_f, dv[:, i])
    return X, filtered


def start_covariance(p: Pass) -> np.ndarray:
    """The first epoch's block covariance (n, n) for the filter: each spacecraft's prior rows
    (:func:`fgnav.measurements.prior_covariance`), each further variable's prior."""
    lay = p.layout
    orbit_covariances = []
    for s, v in enumerate(lay.orbits):
        sub = spacecraft_pass(p, s)
        if not has_prior(sub):
            raise UserError(f"--method ekf: spacecraft '{p.spacecraft[s]}' has no prior rows "
                            "(prior_position, prior_velocity); the filter starts from them")
        orbit_covariances.append(prior_covariance(sub))
    return prior_block_covariance(lay, orbit_covariances)


def formation_start(p: Pass, method: str, model: MotionModel, t0_j2000_s: float,
                    options=None) -> Start:
    """The start of a pass of several spacecraft (:func:`formation_guess`): batch from the
    guessed block values (at the requested process noise at once when every orbit was
    filtered, ``how="initial orbit"``; else the continuation, ``"prior"``); the online
    methods from its first epoch with :func:`start_covariance` (the filter's first covariance,
    the gate's first prediction; the online smoothers' where every spacecraft has prior rows);
    each online method with a start prior on each orbit that has no prior rows (a cruise's,
    or every orbit's with ``--ignore-prior``: :func:`with_formation_start_priors`)."""
    X, filtered = formation_guess(p, model, t0_j2000_s, options)
    info = {"prior": "log" if has_prior(p) else "initial_orbit", "start": ("each spacecraft's own rows"
                                      + (", the links" if p.link_fixes is not None else ""))}
    synthetic = False
    if method != "batch":   # the online methods start from a prior on every orbit (the
        # filter's first covariance too: start_covariance; --ignore-prior leaves none)
        p, started = with_formation_start_priors(p, model, t0_j2000_s)
        if started:
            synthetic = True
            info["start"] += (f"; the initial orbit at epoch 0 of {', '.join(started)}, "
                              f"covariance inflated x{START_INFLATION:g} (no prior rows)")
    # the filter starts from it; iSAM2's gate predicts the first epoch's rows with it
    with_priors = all(has_prior(spacecraft_pass(p, s)) for s in range(len(p.layout.orbits)))
    P0 = start_covariance(p) if method == "ekf" or (method != "batch" and with_priors) else None
    return Start(p, X, X, info, synthetic_prior=synthetic,
                 how="initial orbit" if filtered else "prior", x_start=X[0], P_start=P0)


def with_formation_start_priors(p: Pass, model: MotionModel, t0_j2000_s: float):
    """The pass with start prior rows at epoch 0 for every spacecraft that has none: the
    initial orbit of its own rows (:func:`fgnav.iod.initial.initial_orbit`), propagated to
    epoch 0, covariance inflated by :data:`START_INFLATION` and covered by one sigma per row
    (:func:`fgnav.measurements.covering_sigmas`), as :func:`start_point` starts the online
    methods of one spacecraft; ``(pass, ids of the spacecraft given one)``."""
    cols = orbit_columns(p.layout)
    fams, started = dict(p.families), []
    for s, sc in enumerate(p.spacecraft):
        sub = spacecraft_pass(p, s)
        if has_prior(sub):
            continue
        x0, P0 = propagate_orbit(initial_orbit(sub, model, t0_j2000_s), sub, model, t0_j2000_s, 0)
        sig_r, sig_v = covering_sigmas(START_INFLATION * P0)
        for kind, xyz, sig in ((PRIOR_POSITION.kind, x0[:3], sig_r),
                               (PRIOR_VELOCITY.kind, x0[3:], sig_v)):
            new = {"xyz": np.asarray(xyz, dtype=float)[None].copy(),
                   COLUMN_PREFIX + "orbit": np.array([cols[s]], dtype=int)}
            old = fams.get(kind)
            fams[kind] = Family(
                k=np.zeros(1, dtype=int), values=new, sigma=np.array([sig]),
                line=np.zeros(1, dtype=int)) if old is None else Family(
                k=np.r_[0, old.k], values={n: np.concatenate([new[n], old.values[n]])
                                           for n in old.values},
                sigma=np.r_[sig, old.sigma], line=np.r_[0, old.line])
        started.append(sc)
    return (replace(p, families=fams) if started else p), started
