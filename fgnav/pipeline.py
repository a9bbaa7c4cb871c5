"""The smoothing job as library calls: log in, solution + metrics + files out.

The CLI (``fgnav smooth``/``demo``) is a thin layer over these functions.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from fgnav.diagnostics.alternatives import applies as mounting_applies, camera_mounting_test
from fgnav.diagnostics.crb import check_observability, cramer_rao_bound, mapping_shared
from fgnav.apparent import without_aberration
from factors.errors import ModelDomainError
from fgnav.errors import NotObservableError, UserError
from fgnav.frames import relative_state_lvlh
from fgnav.iod.initial import initial_orbit, propagate_orbit
from fgnav.iod.prior import has_prior, initial_guess, strip_prior
from fgnav.diagnostics.integrity import assess, needs_prior_test
from fgnav.diagnostics.mirror import MIRROR_MARGIN_CHI2, batch_agreement_test, mirror_test
from fgnav.io.log_csv import read_log
from fgnav.io.truth_params import read_truth_params_csv
from fgnav.io.tdm import read_tdm
from fgnav.measurements import (PER_SPACECRAFT, Pass, build_pass, check_formation_estimates,
                                check_observable, covering_sigmas, fill_gaps,
                                spacecraft_pass, spacecraft_states, with_estimates)
from fgnav.models.registry import (ATTITUDE, ATTITUDE_VARIABLE, LOG_SCHEMA, MODELS, VARIABLES,
                                   variable)
from fgnav.models.variables import ORBIT, Layout, spacecraft_variable
from fgnav.orbit import truth_at
from fgnav.prior_sources import prior_for_log
from fgnav.results import (pairs, read_formation_truth, read_truth, relative_rows,
                           sigma_rms, truth_path_of, spherical_position_nees, spherical_summary)
from fgnav.results import write_outputs  # noqa: F401  (the route's last stage, by its old name)
from fgnav.sun_earth_moon import preprocess_log, uses_scheme
from fgnav.solution import Solution
from fgnav.start import (START_INFLATION, Start, batch_first_guess, check_prior_centre,
                         link_fixes, start_point)
from fgnav.solvers.arcs import (arc_priors, arcs_bound, gap_summary, long_gaps, plan_gaps,
                               solve_arcs)
from factors.interpret import active as interpret_active, interpreted
from fgnav.solvers.batch import smooth_batch
from fgnav.solvers.ekf import run_ekf
from fgnav.solvers.ekf_numba import numba_supports, run_ekf_numba
from fgnav.solvers.incremental import smooth_incremental
from fgnav.solvers.options import (IncrementalOptions, SmootherOptions, converging_to_links,
                                   relinearizing_links)
from fgnav.solvers.state_elements import check_state
from fgnav.time import j2000_seconds, seconds_since

METHODS = ("batch", "isam2", "fixed-lag", "ekf")

SHORT_PASS_ROWS = 2000
"""Batch passes of up to this many measurement rows run the numerical kernels as Python
(:mod:`factors.interpret`): quicker than numba's one-off set-up (~0.8 s a process), and the
same solution to the solver's tolerance."""


def _short_passes_interpreted(smooth):
    """``smooth(log, method, ...)`` with the kernels run as Python for a short batch pass."""
    @functools.wraps(smooth)
    def wrapper(log, method: str = "batch", *args, **kw):
        with interpreted(method == "batch" and len(log) <= SHORT_PASS_ROWS):
            return smooth(log, method, *args, **kw)
    return wrapper


def solve(p: Pass, method: str, options: SmootherOptions = SmootherOptions(), *,
          lag_s: float = 300.0, progress=None, gap_factor: float | None = 10.0,
          checkpoint: str | None = None, checkpoint_every: int = 100, resume: bool = False,
          ignore_prior: bool = False) -> Solution:
    """Run one estimator over a pass (after the observability checks).

    Gaps longer than ``gap_factor`` median steps get measurement-free state epochs
    (:func:`fgnav.measurements.fill_gaps`), or, when too long to bridge, separate the log
    into arcs solved one by one (:mod:`fgnav.solvers.arcs`); ``gap_factor=None`` keeps the
    pass as given (already planned, or no gap handling). Without prior rows, or with
    ``ignore_prior``, the solvers start from the orbit the measurements give
    (:func:`fgnav.start.start_point`). With a prior they start from it, and when the
    solution does not fit the data the prior is tested against that orbit and, if the data
    refute it, the solve is repeated from the orbit; ``Solution.extras["initial_orbit"]``
    records the start.

    A formation's pass (several spacecraft, :func:`fgnav.measurements.build_pass`) takes
    the same route as one joint graph, started from each spacecraft's own rows and the links
    (:func:`fgnav.start.formation_start`); its solution carries the mirror test of its
    relative geometry (:func:`fgnav.diagnostics.mirror.mirror_test`,
    ``extras["mirror_test"]``).
    """
    if method not in METHODS:
        raise UserError(f"unknown method '{method}'; expected one of {', '.join(METHODS)}")
    if (checkpoint or resume) and method != "isam2":
        raise UserError(f"checkpoint/resume is available for method isam2 only, not {method}")
    check_state(options.state, method)   # (the options alone: checked before the pass)
    if p.spacecraft:
        refuse_for_formation(options)
    if p.centre != "earth" and options.centre != p.centre:   # a heliocentric log's motion
        options = replace(options, centre=p.centre)
    p = prepare_pass(p, options, gap_factor, ignore_prior)
    if p.manoeuvres is not None and options.state != "cartesian":
        raise UserError(f"{p.source}: manoeuvre rows (line {int(p.manoeuvres.line[0])}, ...) "
                        f"with --state {options.state}: a declared burn enters the Cartesian "
                        "velocity of its step; solve with --state cartesian (the default)")
    from_data = ignore_prior or not has_prior(p)
    if p.breaks:  # gaps too long to bridge: separate arcs (fgnav.solvers.arcs)
        if checkpoint or resume:
            raise UserError("--checkpoint/--resume: this log has gaps too long to bridge and is "
                            "solved as separate arcs, which checkpoints do not support")
        return solve_arcs(p, lambda arc: solve(arc, method, options, lag_s=lag_s,
                                               progress=progress, gap_factor=None,
                                               ignore_prior=ignore_prior), method)
    model = options.motion_model()
    t0_j2000 = float(j2000_seconds(p.epoch0))
    if not from_data:   # a prior that contradicts the log's centre: refused before any work
        check_prior_centre(p, model.centre)
    formation = len(p.spacecraft) > 1

    def run(start: Start) -> Solution:
        try:
            if not formation:
                check_observability(start.p, start.x_guess, model)
        except ModelDomainError as exc:   # a row with no value on the first guess's orbit
            raise NotObservableError(
                f"{p.source}: {exc}, along the first guess's orbit: check that row (a limb "
                f"sphere larger than the spacecraft's distance from the body has no limb), "
                f"or the prior rows") from exc
        except UserError as exc:
            if not from_data:
                raise
            raise type(exc)(f"{exc} Without a prior the orbit comes from the measurements "
                            f"alone: or add 'prior_position' and 'prior_velocity' rows.") from exc
        try:
            sol = _dispatch(start, method, options, lag_s=lag_s, progress=progress,
                            checkpoint=checkpoint, checkpoint_every=checkpoint_every,
                            resume=resume)
            if formation:   # the other minima the links allow (fgnav.diagnostics.mirror)
                sol = _tested_geometry(start.p, sol, method, converging_to_links(start.p, options))
        except ModelDomainError as exc:
            raise NotObservableError(
                f"{p.source}: the {method} estimate left the domain of a measurement model "
                f"({exc}): "
                + ("a row that does not fit the others (an outlier, a unit error) can drive it "
                   "there; check the rows near the epoch where the solution departs from the "
                   "spacecraft's own rows" if formation else
                   "check the row named: it may not fit the other rows, from whose orbit the "
                   "estimate started" if from_data else
                   "the first guess is far from the data's orbit; check the prior rows, or try "
                   "--ignore-prior")) from exc
        return start.finish(sol)

    if from_data or checkpoint or formation:
        return run(start_point(p, method, model, t0_j2000, ignore_prior=ignore_prior,
                               options=options))
    # From the log's prior first; the prior is tested against the orbit of the measurements
    # alone (initial orbit determination, 0.2-0.5 s) only when the solution does not fit the
    # data, and the solve is repeated from that orbit when the data refute the prior.
    try:
        sol = run(Start(p, initial_guess(p, model, t0_j2000), None, {"prior": "log"}))
    except NotObservableError as exc:  # along the prior's orbit; the data's may do
        sol, why, failure = None, "not observable along the prior's orbit", exc
    else:
        why, failure = needs_prior_test(sol, p), None
    if why is None:
        sol.extras["initial_orbit"]["consistency"] = "not tested: the solution fits the data"
        return sol
    start = start_point(p, method, model, t0_j2000)
    start.info["tested_because"] = why
    if start.info.get("prior_consistent") is False:
        return run(start)
    if failure is not None:
        raise failure
    return start.finish(sol)


def refuse_for_formation(options: SmootherOptions) -> None:
    """Refuse what a log of several spacecraft cannot do yet, naming the option: its graph
    holds the orbits, clocks and ambiguities only, in Cartesian states (about the log's
    centre, the Earth or the Sun). (Every method starts a formation without its prior rows:
    :func:`fgnav.start.formation_start`.)"""
    check_formation_estimates(options.estimate)
    if getattr(options, "state", "cartesian") != "cartesian":
        raise UserError(
            f"--state {options.state}: not yet available for a log of several spacecraft: the "
            "element chart (fgnav.solvers.state_elements) maps the block's first six columns, "
            "not each spacecraft's orbit, and the formation EKF filters relative Cartesian "
            "states; the batch minimum is the same in either chart (docs/elements.md): use "
            "--state cartesian")


def _tested_geometry(p: Pass, sol: Solution, method: str, options: SmootherOptions) -> Solution:
    """A formation's solution with its mirror test (:func:`fgnav.diagnostics.mirror.mirror_test`,
    ``extras["mirror_test"]``) and, for an online method, the agreement of its relative
    states with that batch (:func:`fgnav.diagnostics.mirror.batch_agreement_test`,
    ``extras["batch_agreement"]``). Where batch's solution is a wrong minimum (another geometry's
    fits better by more than ``MIRROR_MARGIN_CHI2``), the batch is solved again from that
    minimum, and the better solution kept and tested in its turn; ``mirror_test["restarted"]``
    then names the geometry and the chi-square left (formation-gto-3, 1 h at 30 s: seeds 1-5
    of 9 ended with sat3 270 m or 32 km off; from the better geometry, the truth's minimum)."""
    minima, batch = [], []
    test = mirror_test(p, sol, options, smooth_batch, minima, batch)
    sol.extras["batch_agreement"] = batch_agreement_test(p, sol, batch[0])
    better = [m for m in minima if m[0] < test["chi2"] - MIRROR_MARGIN_CHI2]
    if method == "batch" and better:
        _, geometry, X = min(better, key=lambda m: m[0])
        again = smooth_batch(p, replace(options, q_start_m2_s3=options.q_m2_s3), x_init=X)
        if again.extras.get("converged") and again.chi2 < sol.chi2 - MIRROR_MARGIN_CHI2:
            again.iterations += sol.iterations
            retest = mirror_test(p, again, options, smooth_batch)
            retest["restarted"] = {"geometry": geometry, "chi2_before": float(sol.chi2)}
            again.extras["mirror_test"] = retest
            return again
    sol.extras["mirror_test"] = test
    return sol


def _dispatch(start, method: str, options: SmootherOptions, *, lag_s, progress, checkpoint,
              checkpoint_every, resume) -> Solution:
    """The chosen estimator from a start point (:class:`fgnav.start.Start`), its
    Gauss-Newton tolerances and iSAM2 thresholds fine enough for the pass's links
    (:func:`fgnav.solvers.options.converging_to_links`, :func:`relinearizing_links`)."""
    p = start.p
    options = converging_to_links(p, options)
    if method == "batch":
        how, x_init = batch_first_guess(start, options.init, options.robust,
                                        short_pass=interpret_active())
        if how == "initial orbit":
            # Gauss-Newton at the requested process noise at once (continuation if that fails:
            # with a contradicted prior in the graph, a loose process noise would let the
            # first states bend to the prior).
            sol = smooth_batch(p, replace(options, q_start_m2_s3=options.q_m2_s3),
                               x_init=x_init, progress=progress)
            if sol.extras.get("converged"):
                return sol
        spent = 0
        if how == "prior, direct":   # short pass, no bridged gap: the prior propagated, once
            sol, spent = _batch_direct(p, options, x_init, progress)
            if sol is not None:
                return sol
        sol = smooth_batch(p, options, x_init=x_init, progress=progress)
        sol.iterations += spent
        return sol
    if method == "ekf":
        # The numba kernel (same numbers as the numpy EKF to 1e-9, tests/test_ekf_numba.py;
        # 1.1 us/step vs ~500 us) wherever it models every family and no gating is asked.
        if options.gate_probability is None and options.state == "cartesian" and numba_supports(p):
            return run_ekf_numba(p, options, progress=progress)
        return run_ekf(p, options, progress=progress, x_start=start.x_start,
                       P_start=start.P_start)
    return smooth_incremental(p, options, relinearizing_links(p, IncrementalOptions(lag_s=lag_s)),
                              method=method, progress=progress, checkpoint=checkpoint,
                              checkpoint_every=checkpoint_every, resume=resume,
                              x_start=start.x_start, P_start=start.P_start)


DIRECT_ITERATIONS = 8
"""Gauss-Newton iterations a short pass tries at its own process noise before the
continuation (:func:`_batch_direct`)."""
DIRECT_SHRINK = 2.0
"""The factor each update of that try must shrink by (:func:`_batch_direct`)."""


def _batch_direct(p: Pass, options: SmootherOptions, x_init: np.ndarray, progress):
    """Gauss-Newton at the requested process noise straight from ``x_init`` (the prior
    propagated), as from the filter's states on long passes: ``(solution, 0)``, or
    ``(None, iterations spent)`` when it does not converge within
    :data:`DIRECT_ITERATIONS`, an update is not half the one before
    (:data:`DIRECT_SHRINK`: outside the region of fast convergence) or it leaves the
    models' domain; the continuation then starts again from ``x_init``.

    A 4 h gto-transfer pass at 60 s from its 10 km, 2 m/s prior: 3 iterations to the same
    solution (to 3 um) as the continuation's 7. Of 32 short passes of five scenarios, with
    priors up to 1,000 km off, the direct start converged on 28 (to the continuation's
    solution within 1.1 mm, in 3-6 iterations against 6-10) and gave up on 4 at its second
    update."""
    try:
        sol = smooth_batch(p, replace(options, q_start_m2_s3=options.q_m2_s3,
                                      max_iterations=DIRECT_ITERATIONS),
                           x_init=x_init, progress=progress, min_shrink=DIRECT_SHRINK)
    except (NotObservableError, ModelDomainError):
        return None, 0
    if sol.extras.get("converged"):
        return sol, 0
    return None, sol.iterations


def prepare_pass(p: Pass, options: SmootherOptions, gap_factor: float | None = 10.0,
                 ignore_prior: bool = False) -> Pass:
    """The pass the solvers see: checked for observability, its long gaps planned (bridged
    with measurement-free states or cut into arcs, :func:`fgnav.solvers.arcs.plan_gaps`).

    The gap planning filters the pass; without a prior (or with ``ignore_prior``) that
    filter starts from the initial orbit of the measurements, covariance inflated as for the
    online methods (:func:`fgnav.start.start_point`). A pass already planned is
    returned as is.

    A formation's long gaps: :func:`formation_gaps`.
    """
    from_data = ignore_prior or not has_prior(p)
    estimated = {v.name for v in p.layout.extra if v.name in VARIABLES}   # (not the formation's)
    if estimated != {variable(n).name for n in options.estimate}:
        p = with_estimates(p, options.estimate)   # first: deferred rows may observe the orbit
    for name, sigma in options.prior_sigma:       # priors other than the registry's
        if not p.layout.has(variable(name).name):
            raise UserError(f"a prior sigma for '{variable(name).cli_name}', which is not "
                            f"estimated (--estimate {variable(name).cli_name})")
        p = replace(p, layout=p.layout.with_prior_sigma(variable(name).name, sigma))
    for kind, fam in p.deferred.items():
        mdl = MODELS[kind]
        if mdl.body_frame_of is None and kind != ATTITUDE.kind and not p.layout.has(mdl.requires):
            note = (f"{len(fam)} {kind} rows not used: they enter with --estimate "
                    f"{variable(mdl.requires).cli_name}")
            if note not in p.warnings:
                p.warnings.append(note)
    check_observable(p, require_prior=not from_data)
    if gap_factor is None or p.inserted is not None:
        return p

    start = None
    if from_data and len(long_gaps(p, gap_factor)):
        p = replace(p, families=strip_prior(p).families) if p.spacecraft else strip_prior(p)
        first = spacecraft_pass(p, 0) if p.spacecraft else p   # (the gaps' plan's start)
        start = _plan_start(first, options)
    if len(p.spacecraft) > 1 and len(long_gaps(p, gap_factor)):
        return formation_gaps(p, options, gap_factor, start)
    return plan_gaps(p, options, gap_factor, start=start)


def _plan_start(p: Pass, options: SmootherOptions) -> tuple:
    """The gap planning filter's a-priori state of a pass without prior rows: its initial
    orbit at epoch 0, covariance inflated as for the online methods (``(x, sigma_r,
    sigma_v)``, :func:`fgnav.solvers.arcs.plan_gaps`)."""
    model = options.motion_model()
    t0 = float(j2000_seconds(p.epoch0))
    x0, P0 = propagate_orbit(initial_orbit(p, model, t0), p, model, t0, 0)
    return (x0, *covering_sigmas(START_INFLATION * P0))


def _placed_by_links(p: Pass, k0: int, k1: int):
    """The second spacecraft's state relative to the first (6,) at epoch ``k0`` from the link
    fixes (:func:`fgnav.start.link_fixes`) at the epochs ``k0 <= k < k1`` (an arc's), or None
    where fewer than two fall there: position interpolated (held before the first fix),
    velocity from their differences, as :func:`fgnav.start.formation_guess` places it."""
    if p.link_fixes is None:
        return None
    t_f, dr = p.link_fixes
    keep = (t_f >= p.t_s[k0]) & (t_f <= p.t_s[k1 - 1])
    if keep.sum() < 2:
        return None
    t_a, d_a = t_f[keep], dr[keep]
    dv = np.gradient(d_a, t_a, axis=0)
    t = p.t_s[k0]
    return np.array([np.interp(t, t_a, d_a[:, i]) for i in range(3)]
                    + [np.interp(t, t_a, dv[:, i]) for i in range(3)])


def formation_gaps(p: Pass, options: SmootherOptions, gap_factor: float, start=None) -> Pass:
    """A formation's long gaps planned on its first spacecraft's own rows (whether the orbit's
    prediction across a gap stays linear, :func:`fgnav.solvers.arcs.plan_gaps`: the links
    fix the relative state, not the absolute orbit across the gap) and bridged for every
    spacecraft (:func:`fgnav.measurements.fill_gaps`). A gap too long to bridge separates
    arcs, as for one spacecraft, for every spacecraft at once: each further spacecraft's
    a-priori state of a later arc predicted across the gap from its own rows
    (:func:`fgnav.solvers.arcs.arc_priors`; ``start``: the first's a-priori state of a pass
    without prior rows, the others' from their own initial orbits). The second's mean is
    the first's plus the relative state the later arc's links fix alone, where they do
    (:func:`_placed_by_links`), its sigma the larger of the two: two orbits predicted 100 km
    off each (formation-gto, 2 h, an 8 h gap), independently, put the pair 300 km apart
    against links that say 1 km, and iSAM2, linearized at the prior, ended 28,000 km off."""
    plan = plan_gaps(spacecraft_pass(p, 0), options, gap_factor, start=start)
    if not plan.breaks:
        return fill_gaps(replace(p, gap_notes=plan.gap_notes), gap_factor)
    # (the plan's breaks are renumbered to its filled epochs: the unfilled ones from its notes)
    breaks = tuple(int(np.searchsorted(p.t_s, g["t_end_s"])) for g in plan.gap_notes
                   if not g["bridged"])
    priors = [[prior] for prior in plan.arc_priors]
    for s in range(1, len(p.spacecraft)):
        sub = spacecraft_pass(p, s)
        for j, prior in enumerate(arc_priors(sub, breaks, options,
                                             None if start is None else _plan_start(sub, options))):
            priors[j].append(prior)
    for j, (b, e) in enumerate(zip(breaks, (*breaks[1:], p.n_epochs))):
        placed = _placed_by_links(p, b, e)
        if placed is not None:   # the second's mean: the first's and the links' relative state
            (x1, sr1, sv1), (_, sr2, sv2) = priors[j][:2]
            priors[j][1] = (x1 + placed, max(sr1, sr2), max(sv1, sv2))
    out = fill_gaps(replace(p, breaks=breaks, arc_priors=[tuple(x) for x in priors],
                            gap_notes=plan.gap_notes), gap_factor)
    out.warnings = out.warnings + [w for w in plan.warnings if "too long to bridge" in w]
    return out


def accuracy_metrics(sol: Solution, x_true: np.ndarray) -> dict:
    """RMS / final errors and NEES of a solution against truth at its epochs (SI)."""
    return state_errors(sol.x_eci, sol.P_eci, x_true)


def state_errors(x: np.ndarray, P: np.ndarray, x_true: np.ndarray) -> dict:
    """RMS / final errors and mean NEES of states ``x`` (N, 6) with covariances ``P``
    (N, 6, 6) against ``x_true`` (N, 6), and the RMS position sigma (SI)."""
    err = x - x_true
    er, ev = np.linalg.norm(err[:, :3], axis=1), np.linalg.norm(err[:, 3:], axis=1)
    nees = np.einsum("ki,ki->k", err, np.linalg.solve(P, err[..., None])[..., 0])
    return {"position_rms_m": float(np.sqrt(np.mean(er ** 2))),
            "velocity_rms_mps": float(np.sqrt(np.mean(ev ** 2))),
            "final_position_error_m": float(er[-1]), "final_velocity_error_mps": float(ev[-1]),
            "nees_mean": float(np.mean(nees)),
            "sigma_position_rms_m": sigma_rms(P)["sigma_position_rms_m"]}


def crb_metrics(p: Pass, x_ref: np.ndarray, options: SmootherOptions,
                t_ref: np.ndarray | None = None) -> dict:
    """The Cramér–Rao bound of ``p`` along ``x_ref``; with ``t_ref`` (the epochs of
    ``x_ref``, a superset of ``p.t_s``, e.g. a solution with gap-filling epochs) only the
    states at the pass's own epochs are used."""
    if len(x_ref) != p.n_epochs:
        if t_ref is None:
            raise ValueError(f"crb_metrics: {len(x_ref)} states for a pass of {p.n_epochs} epochs")
        x_ref = x_ref[np.searchsorted(t_ref, p.t_s)]
    if p.breaks:  # separate arcs: the bound of each, pooled over all epochs
        c = arcs_bound(p, x_ref, options.motion_model())
    else:
        c = cramer_rao_bound(p, x_ref, options.motion_model())
    return {"crb_position_rms_m": c.position_rms_m, "crb_velocity_rms_mps": c.velocity_rms_mps,
            "crb_final_position_m": c.final_position_m, "crb_final_velocity_mps": c.final_velocity_mps}


@dataclass
class SmoothResult:
    solution: Solution
    summary: dict
    x_true: np.ndarray | None


def smooth_file(log_path: str | Path, method: str = "batch", options: SmootherOptions = SmootherOptions(),
                *, truth_path: str | Path | None = None, lag_s: float = 300.0,
                progress=None, ignore_prior: bool = False, aberration: bool = True,
                stage=None, prior_path: str | Path | None = None,
                prior_sigma: tuple[float | None, float | None] = (None, None),
                **solve_kw) -> tuple[SmoothResult, Pass]:
    """Read a log (CSV v1 or CCSDS TDM), solve, and compute the summary (with truth if given).

    ``ignore_prior``: start from the measurements' own orbit, leaving the log's prior rows
    out of the solution and of the Cramer-Rao bound (:func:`solve`). ``aberration=False``:
    the star models take the catalogue directions as seen, without the stellar-aberration
    correction (:func:`fgnav.apparent.without_aberration`; for comparison only). ``stage``:
    optional ``stage(what, size)`` returning a context manager around each long step
    (reading the log, solving and summarizing), e.g. to print it (``fgnav smooth``).
    ``prior_path``: an OMM, TLE, OPM or OEM whose state at the log's first epoch becomes its
    prior rows, ``prior_sigma`` = (position m, velocity m/s) replacing the file's or the
    default 1-sigma (:mod:`fgnav.prior_sources`; summary.json ``prior_file``).
    """
    from contextlib import nullcontext

    stage = stage or (lambda what, size: nullcontext())
    t0 = time.perf_counter()
    size_mb = Path(log_path).stat().st_size / 1e6 if Path(log_path).is_file() else 0.0
    with stage(f"reading {log_path} ({size_mb:.0f} MB)", int(size_mb * 1e6 / 130)):
        log = read_measurements(log_path, options.estimate)
    log, prior = add_prior_file(log, prior_path, prior_sigma, ignore_prior)
    res, p = smooth_log(log, method, options, truth_path=truth_path, lag_s=lag_s,
                        progress=progress, ignore_prior=ignore_prior, aberration=aberration,
                        stage=stage, t0=t0, **solve_kw)
    if prior is not None:
        res.summary["prior_file"] = prior.summary()
    return res, p


def add_prior_file(log, prior_path=None, prior_sigma=(None, None), ignore_prior=False):
    """``(log, prior)``: the log with the prior rows of the file ``prior_path`` and its
    :class:`~fgnav.prior_sources.PriorState` (summary.json ``prior_file``), or ``(log, None)``
    without a file; ``ignore_prior`` with a file is an error naming both options."""
    if prior_path is None:
        return log, None
    if ignore_prior:
        raise UserError(f"--prior {prior_path} contradicts --ignore-prior; give one of them")
    return prior_for_log(log, prior_path, *prior_sigma)


@_short_passes_interpreted
def smooth_log(log, method: str = "batch", options: SmootherOptions = SmootherOptions(), *,
               truth_path: str | Path | None = None, truth: tuple | None = None,
               lag_s: float = 300.0, progress=None, ignore_prior: bool = False,
               aberration: bool = True, stage=None, t0: float | None = None,
               **solve_kw) -> tuple[SmoothResult, Pass]:
    """:func:`smooth_file` on a log already in memory (a
    :class:`~fgnav.io.log_csv.MeasurementLog`). The truth comes from the OEM ``truth_path``
    or as ``truth = (t_s, x_eci)``: seconds from ``log.epoch0`` (covering the log's epochs)
    and (N, 6) states, SI. ``t0`` is the ``time.perf_counter()`` the wall time counts from
    (default: now). A log of several spacecraft takes the same route (its truth:
    ``truth-<id>.oem`` per spacecraft beside ``truth_path``, :func:`read_formation_truth`;
    ``relative="spherical"`` adds the relative position's spherical form), with its start
    from the links (:func:`fgnav.start.link_fixes`)."""
    from contextlib import nullcontext

    stage = stage or (lambda what, size: nullcontext())
    t0 = time.perf_counter() if t0 is None else t0
    centre = getattr(log, "centre", "earth")   # the log's "# centre:" line: the motion model's
    if centre != options.centre:
        options = replace(options, centre=centre)
    relative = solve_kw.pop("relative", None)
    formation = getattr(log, "n_spacecraft", 1) > 1   # one graph, every spacecraft
    if formation:   # refused before any work
        if truth is not None:
            raise UserError("a formation's truth comes from truth-<id>.oem files (--truth DIR)")
        refuse_for_formation(options)
    elif relative is not None:
        raise UserError(f"--relative {relative}: for a log of several spacecraft (this log has "
                        "one)")
    p = build_pass(log)
    if formation:   # its start: the second spacecraft placed from the first by the links
        p.link_fixes = link_fixes(log)
    if not aberration:
        p = without_aberration(p)
    gap_factor = solve_kw.pop("gap_factor", 10.0)
    if formation:
        truths = None if truth_path is None else read_formation_truth(truth_path, p)
    elif truth is None and truth_path is not None:
        truth = read_truth(truth_path, p, centre)  # checked before solving
    truth_vars = None if truth_path is None or formation else read_truth_variables(
        truth_path, p, options.estimate)
    # the pass the solvers see (gaps planned): the summary uses it
    what = f"{p.n_epochs:,} epochs" + (f" of {len(p.spacecraft)} spacecraft" if formation else "")
    with stage(f"solving {what} ({method})", p.n_epochs):
        p = prepare_pass(p, options, gap_factor, ignore_prior)
        sol = solve(p, method, options, lag_s=lag_s, progress=progress,
                    ignore_prior=ignore_prior, **solve_kw)
    if formation:
        if ignore_prior:   # (the summary's counts and tests: the rows the solution used)
            p = replace(p, families=strip_prior(p).families)
        if centre != "earth":   # the outputs' frame (write_outputs)
            sol.extras["centre"] = centre
        sol.wall_s = time.perf_counter() - t0
        summary = summarize(sol, p, options, truths=truths, relative=relative or "cartesian",
                            truth_vars=None if truth_path is None else
                            read_formation_truth_variables(truth_path, p))
        sol.extras["relative_parameterization"] = relative or "cartesian"
        if truth_path is not None:
            summary["truth_path"] = str(truth_path)
        return SmoothResult(sol, summary, None), p
    if ignore_prior:
        p = strip_prior(p)
    if centre != "earth":   # the outputs' frame (write_outputs)
        sol.extras["centre"] = centre
    sol.wall_s = time.perf_counter() - t0
    with stage("checking the solution (Cramer-Rao bound, integrity tests)", p.n_epochs):
        if mounting_applies(p) and not p.breaks:   # do the stars ask for a mounting rotation?
            sol.extras["camera_mounting_test"] = camera_mounting_test(p, sol, options,
                                                                      smooth_batch)
        summary = summarize(sol, p, options)
    x_true = None
    if truth is not None:
        x_true = truth_at(*truth, sol.t_s)
        summary.update(accuracy_metrics(sol, x_true))
        if truth_path is not None:
            summary["truth_path"] = str(truth_path)
        if sol.variables:
            summary["variables"] = variable_summary(sol, truth_variables(truth_vars or {}, sol))
    return SmoothResult(sol, summary, x_true), p


def read_truth_variables(truth_path: str | Path, p: Pass, estimate=()) -> dict:
    """True values of the further variables in ``estimate`` from the files
    ``truth_<variable>.csv`` beside the truth OEM (``fgnav simulate`` writes them; columns
    ``epoch`` and the variable's components), read and checked against the pass's epochs
    before any solving: name -> ``(t_s (M,), values (M, d))`` on the pass's time axis;
    variables without a file are left out."""
    out = {}
    for name in estimate or ():
        v = variable(name)
        path = Path(truth_path).parent / f"truth_{v.name}.csv"
        if not path.exists():
            continue
        epochs, cols = read_truth_params_csv(path)
        t = np.asarray(seconds_since(epochs, p.epoch0), dtype=float)
        missing = [c for c in v.components if c not in cols]
        if missing:
            raise UserError(f"{path}: expected the column(s) {', '.join(missing)}")
        if t[0] > p.t_s[0] + 1e-6 or t[-1] < p.t_s[-1] - 1e-6:
            raise UserError(f"{path}: does not cover the log's epochs ({t[0]:.1f}..{t[-1]:.1f} s "
                            f"vs {p.t_s[0]:.1f}..{p.t_s[-1]:.1f} s from {p.epoch0}Z)")
        out[v.name] = (t, np.column_stack([cols[c] for c in v.components]))
    return out


def read_formation_truth_variables(truth: str | Path, p: Pass) -> dict:
    """Each spacecraft's true further variables where they are estimated (its attitude, its
    gyro bias), from ``truth_<variable>-<id>.csv`` beside its ``truth-<id>.oem`` (``fgnav
    simulate --body-frame`` and ``--gyro`` write them), as :func:`read_truth_variables` reads
    one spacecraft's; spacecraft without a file are left out."""
    out = {}
    for u in PER_SPACECRAFT:
        for s, sc in enumerate(p.spacecraft):
            v = spacecraft_variable(u, s, sc)
            path = truth_path_of(truth, sc).parent / f"truth_{u.name}-{sc}.csv"
            if not p.layout.has(v.name) or not path.exists():
                continue
            epochs, cols = read_truth_params_csv(path)
            missing = [c for c in u.components if c not in cols]
            if missing:
                raise UserError(f"{path}: expected the column(s) {', '.join(missing)}")
            t = np.asarray(seconds_since(epochs, p.epoch0), dtype=float)
            if t[0] > p.t_s[0] + 1e-6 or t[-1] < p.t_s[-1] - 1e-6:
                raise UserError(f"{path}: does not cover the log's epochs ({t[0]:.1f}..{t[-1]:.1f}"
                                f" s vs {p.t_s[0]:.1f}..{p.t_s[-1]:.1f} s from {p.epoch0}Z)")
            out[v.name] = (t, np.column_stack([cols[c] for c in u.components]))
    return out


def truth_variables(truth: dict, sol: Solution) -> dict:
    """The true values of :func:`read_truth_variables` at the solution's epochs (linear
    interpolation): name -> (N, d)."""
    return {name: np.column_stack([np.interp(sol.t_s, t, x[:, i]) for i in range(x.shape[1])])
            for name, (t, x) in truth.items() if name in sol.variables}


def read_measurements(path: str | Path, estimate=()):
    """A measurement log from a CSV v1 file, or a CCSDS TDM (``.tdm`` / ``.kvn``).

    Body-frame Sun and Moon directions go through the INS/CNS lecture's preprocessing (TRIAD
    attitude, Earth direction to ECI: :func:`fgnav.sun_earth_moon.preprocess_log`) unless
    the attitude is among the variables to ``estimate``: then the raw rows stay, factors on
    (orbit, attitude)."""
    path = Path(path)
    if not path.exists():
        raise UserError(f"{path}: no such file")
    if path.suffix.lower() in (".tdm", ".kvn"):
        return read_tdm(path)
    return scheme_preprocessed(read_log(path, schema=LOG_SCHEMA), estimate)


def scheme_preprocessed(log, estimate=()):
    """The log as the smoothers read it: body-frame Sun and Moon directions through the
    INS/CNS lecture's scheme (TRIAD attitude from the Sun and Moon, Earth direction to ECI:
    :func:`fgnav.sun_earth_moon.preprocess_log`) unless the attitude is among the variables
    to ``estimate`` (then the raw rows stay, factors on (orbit, attitude))."""
    if uses_scheme(log) and ATTITUDE_VARIABLE.name not in {variable(n).name for n in estimate}:
        log = preprocess_log(log)[0]
    return log


def summarize(sol: Solution, p: Pass, options: SmootherOptions, *, truths=None,
              relative: str = "cartesian", truth_vars=None) -> dict:
    """summary.json of a solution of S >= 1 spacecraft: the keys every method shares, the
    Cramer-Rao bound and the integrity verdict (:func:`fgnav.diagnostics.integrity.assess`;
    ``p`` is given the solution's further variables if it lacks them, so the integrity
    tests evaluate the rows with them). Several spacecraft: per spacecraft its sigmas (and
    errors against ``truths``: per spacecraft ``(t_s, x_eci)`` or None) and the relative
    states of :func:`relative_summary`, instead of the one orbit's bound."""
    formation = len(p.spacecraft) > 1
    missing = [name for name in sol.variables if not p.layout.has(name)]
    if missing and not formation:
        p = with_estimates(p, tuple(v.name for v in p.layout.extra) + tuple(missing))
    s = {"method": sol.method, "epochs": int(len(sol.t_s)), "iterations": int(sol.iterations),
         "wall_s": float(sol.wall_s), "chi2": float(sol.chi2),
         "measurements": p.counts(), "process_noise_m2_s3": options.q_m2_s3,
         "third_body": options.third_body, "gravity": options.gravity, "source": p.source}
    if formation:
        s["converged"] = sol.extras.get("converged")
        s.update(relative_summary(sol, p, truths, relative))
        names = {spacecraft_variable(u, i, sc).name for u in PER_SPACECRAFT
                 for i, sc in enumerate(p.spacecraft)}
        own = [v for v in p.layout.parameters if v.name in names and v.name in sol.variables]
        if own:   # each spacecraft's attitude (not the clocks and ambiguities: relative.csv)
            s["variables"] = variable_summary(
                sol, truth_variables(truth_vars or {}, sol), layout=Layout(
                    (ORBIT,) + tuple(own)))
        if p.inserted is not None and p.inserted.any():   # (the gaps, as one spacecraft's)
            s["inserted_epochs"] = int(p.inserted.sum())
        if p.gap_notes:
            s["gaps"] = gap_summary(p)
        if p.breaks:
            s["arcs"] = len(p.breaks) + 1
        if p.warnings:
            s["warnings"] = list(p.warnings)
        s["integrity"] = assess(sol, p, options.motion_model())
        return s
    if options.state != "cartesian":
        s["state"] = options.state   # the orbit's coordinates in the solver (--state)
    s.update(sigma_rms(sol.P_eci))   # the solution's own 1-sigma, with or without a truth
    with mapping_shared():   # the bound and the integrity tests map the same rows
        s.update(crb_metrics(p, sol.x_eci, options, sol.t_s))
        if p.inserted is not None and p.inserted.any():
            s["inserted_epochs"] = int(p.inserted.sum())
        if p.gap_notes:
            s["gaps"] = gap_summary(p)
        if p.warnings:
            s["warnings"] = list(p.warnings)
        for k, v in sol.extras.items():
            if _is_plain(v):
                s.setdefault(k, v)
        if sol.variables:
            s["variables"] = variable_summary(sol)
        s["integrity"] = assess(sol, p, options.motion_model())
    return s


def relative_summary(sol: Solution, p: Pass, truths=None, relative: str = "cartesian") -> dict:
    """The formation keys of summary.json: ``reference_spacecraft``; ``spacecraft`` (per id
    its sigmas, and its errors against ``truths``); ``relative``, the second spacecraft's
    state relative to the first in the first's LVLH frame (sigmas, and errors and NEES
    against truth, :mod:`fgnav.results`); with three or more spacecraft
    ``relative_by_spacecraft`` (each further spacecraft relative to the first) and
    ``relative_pairs`` (every pair of :func:`fgnav.results.pairs`, named by ``reference``
    and ``spacecraft``). ``relative="spherical"`` adds the relative position's range,
    azimuth and elevation sigmas (and errors)."""
    s = {"reference_spacecraft": p.spacecraft[0], "spacecraft": {}}
    states = spacecraft_states(sol, p.layout)
    x_true = [None] * len(states) if truths is None else [truth_at(*t, sol.t_s) for t in truths]
    for sc, (x, P), xt in zip(p.spacecraft, states, x_true):
        d = sigma_rms(P)
        if xt is not None:
            d.update(state_errors(x, P, xt))
        s["spacecraft"][sc] = d
    by_pair = {}
    for c, j in pairs(len(states)):
        rel, C, _ = relative_rows(sol, p, j, c)
        d = sigma_rms(C)
        rel_true = None if x_true[c] is None else relative_state_lvlh(x_true[c], x_true[j])[0]
        if rel_true is not None:
            d.update(state_errors(rel, C, rel_true))
            d["nees_position_spherical_mean"] = spherical_position_nees(rel[:, :3], C[:, :3, :3],
                                                                        rel_true[:, :3])
        if relative == "spherical":
            d.update(spherical_summary(rel, C, rel_true))
        by_pair[c, j] = d
    s["relative"] = by_pair[0, 1]
    s["relative"]["frame"] = f"LVLH of spacecraft {p.spacecraft[0]}"
    if len(states) > 2:
        s["relative_by_spacecraft"] = {p.spacecraft[j]: by_pair[0, j]
                                       for j in range(1, len(states))}
        s["relative_pairs"] = [{"reference": p.spacecraft[c], "spacecraft": p.spacecraft[j],
                                "frame": f"LVLH of spacecraft {p.spacecraft[c]}",
                                **{k: v for k, v in d.items() if k != "frame"}}
                               for (c, j), d in by_pair.items()]
    return s


def variable_summary(sol: Solution, truth: dict | None = None, layout=None) -> dict:
    """summary.json's ``variables``: per estimated variable (beside the orbit), its unit, mean
    and RMS value, and the RMS and final 1-sigma of each component; with ``truth``
    (name -> (N, d) true values at the solution's epochs) the RMS error, the largest
    |error|/sigma and the mean normalized squared error (NEES per component). A rotation's
    error is ``Log(R_true^T R)`` (body frame, the right perturbation its covariance is of),
    not a difference of rotation vectors (which is wrong near a half turn)."""
    out = {}
    for name, (x, P) in sol.variables.items():
        if layout is not None and not layout.has(name):
            continue
        v = layout.variable(name) if layout is not None else variable(name)
        sig = np.sqrt(np.diagonal(P, axis1=1, axis2=2))
        d = {"unit": v.unit, "components": list(v.components), "mean": x.mean(axis=0).tolist(),
             "rms": np.sqrt(np.mean(x * x, axis=0)).tolist(),
             "sigma_rms": np.sqrt(np.mean(sig * sig, axis=0)).tolist(),
             "sigma_final": sig[-1].tolist()}
        if truth is not None and name in truth:
            err = v.manifold.local(truth[name], x)
            d["error_rms"] = np.sqrt(np.mean(err * err, axis=0)).tolist()
            d["max_abs_error_over_sigma"] = np.max(np.abs(err) / sig, axis=0).tolist()
            d["nees_mean"] = float(np.mean(np.sum(err * err / (sig * sig), axis=1)) / x.shape[1])
        out[name] = d
    return out


def _is_plain(v) -> bool:
    """A value summary.json takes as it is: numbers, strings, lists and dicts of them
    (per-row arrays such as ``row_weights`` stay out)."""
    if isinstance(v, dict):
        return all(_is_plain(x) for x in v.values())
    if isinstance(v, list):
        return all(_is_plain(x) for x in v)
    return isinstance(v, (int, float, str, bool)) or v is None
