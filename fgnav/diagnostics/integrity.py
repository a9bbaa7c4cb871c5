"""Integrity of a solution: does its covariance tell the truth, or must the user be warned?

A solver always returns numbers; this module decides, from the data alone (no truth), whether
they deserve trust. Every test compares a statistic of the solution with its distribution
under the hypothesis that the log and the models are right (Bar-Shalom, Li & Kirubarajan
2001, ch. 5.4, consistency tests; Teunissen 1990, detection-identification-adaptation):

* **measurement families**: the sum of squared whitened residuals of a family against the
  chi-square distribution of its dimension (post-fit residuals of a smoother have fewer
  degrees of freedom than rows, so the test is conservative; an EKF's innovations are
  normalized by their own covariance ``A P A^T + I`` before the test);
* **motion**: the chi-square of the process-noise rows; large when a force or a manoeuvre
  is missing from the model (the smoother bends the orbit through the process noise);
* **prior**: the Mahalanobis distance of the solution from the log's prior, chi-square with
  6 degrees of freedom per prior epoch, and the initial orbit's verdict on the prior
  (:mod:`fgnav.start`);
* **residual runs**: the largest windowed mean of whitened residuals in time order, over
  windows of 4 to 4,096 measurements, against a Bonferroni threshold for all the windows
  tested (a bias or an unmodelled force shows as a run of same-signed residuals that a
  chi-square over the whole pass dilutes);
* **rejections**: the fraction of each family a robust kernel or a gate threw away; beyond
  :data:`MAX_REJECTED_FRACTION` the answer is not the data's;
* **observability**: the weakest direction of the position covariance.

The verdict is ``ok``, ``suspect`` (a statistic beyond its 1 - 1e-6 quantile but with
covariances at most ~1.5x optimistic in sigma) or ``failed`` (a contradiction that makes the
covariance untrustworthy: a chi-square more than :data:`FAILED_NORMALIZED_CHI2` times its
expectation, a robust solve that rejected too much, a prior the data refute, no
convergence, non-finite numbers).
"""

from __future__ import annotations

import math

import numpy as np

from factors.dynamics import accel_third_body
from factors.ephemeris import moon_position_eci_m, sun_position_eci_m
from fgnav.apparent import aberration_off, with_aberration
from fgnav.chi2 import chi2_isf, chi2_logsf, norm_isf
from fgnav.diagnostics.crb import CHUNK, rows_at_first_state
from fgnav.diagnostics.mirror import range_curvature_test
from fgnav.graph import PRIOR_KINDS, block_values
from fgnav.measurements import slice_pass
from fgnav.models.attitude import ATTITUDE_VARIABLE
from fgnav.time import j2000_seconds


FALSE_ALARM_PROBABILITY = 1e-6
"""Per-test probability of calling a consistent statistic inconsistent."""
SUSPECT_NORMALIZED_CHI2 = 1.5
"""chi2/dof above which (and beyond the quantile) a family is suspect: sigmas ~1.2x optimistic."""
FAILED_NORMALIZED_CHI2 = 4.0
"""chi2/dof above which a family fails: its sigma is at least 2x optimistic."""
MAX_REJECTED_FRACTION = 0.25
"""A robust kernel or gate that rejects more than this fraction of a family fails the run."""
RUN_WINDOWS = (4, 16, 64, 256, 1024, 4096)
RUN_FALSE_ALARM = 1e-4
"""Family-wise false-alarm probability of the residual-run test (Bonferroni over windows)."""
THIRD_BODY_NEES = 24.0
"""Mean NEES of the error an omitted Sun/Moon gravity causes above which the run is suspect:
the omission moves the solution by more than twice its own sigma (RMS over the pass).
Above a quarter of it the summary notes it."""
MAX_MANOEUVRE_FRACTION = 0.1
"""The manoeuvre test covers impulses up to this fraction of the orbital speed: a direction of
``dv`` in which even that could not reach the threshold is not tested (its linear response
is below the rows' linearization error; at the end of a pass the radial ``dv`` barely turns a
geocentric direction, and 144,001 rows made a 10,000 km/s impulse look likely there)."""
WEAK_POSITION_FRACTION = 0.1
"""A position sigma above this fraction of the orbit radius means the orbit is not determined."""

ADVICE = {
    "outliers": "try --robust cauchy, or check the sigma column of that family",
    "force": "try --third-body, a larger --process-noise, or check for a manoeuvre in the pass",
    "prior": "give a better prior, or --ignore-prior to start from the measurements alone",
    "converge": "give a better prior or --ignore-prior; --process-noise helps a poor first guess",
    "rejected": "the model or the first guess is wrong for this family: check its sigma and "
                "units, or try --ignore-prior",
    "observability": "add measurements (limb, altitude) or a longer pass",
    "third_body": "try --third-body",
    "mounting": "try --estimate camera-alignment (the star camera's mounting in the graph)",
    "aberration": "solve without --no-aberration: the correction is the physics, the option is "
                  "for comparison only",
    "mirror": "links through more receive antennas per spacecraft (their lever arms fix the "
              "direction), or a prior on the relative position",
    "mirror_better": "--method batch, which solves again from the geometry that fits better",
    "agreement": "--method batch (every row at once) for this formation",
    "curvature": "links through more receive antennas per spacecraft (their lever arms fix the "
                 "direction across the line of sight), a longer pass, or read the relative "
                 "position as range and directions (--relative spherical)",
}


def _chi2_test(chi2: float, dof: int) -> dict:
    """chi2 of ``dof`` whitened components: normalized value and the log10 of its tail
    probability under the chi-square distribution (``-inf`` for an impossible value)."""
    dof = max(int(dof), 1)
    logsf = chi2_logsf(chi2, dof) if math.isfinite(chi2) else -math.inf
    return {"chi2": float(chi2), "dof": dof, "normalized": float(chi2) / dof,
            "log10_p": logsf / math.log(10.0)}


def _severity(test: dict, suspect_above: float = SUSPECT_NORMALIZED_CHI2,
              failed_above: float = FAILED_NORMALIZED_CHI2) -> str:
    """ok / suspect / failed for a chi-square test: beyond its 1 - 1e-6 quantile and with
    chi2/dof above ``suspect_above`` (``failed_above``); see the module docstring."""
    if not math.isfinite(test["chi2"]):
        return "failed"
    beyond = test["log10_p"] < math.log10(FALSE_ALARM_PROBABILITY)
    if beyond and test["normalized"] > failed_above:
        return "failed"
    if beyond and test["normalized"] > suspect_above:
        return "suspect"
    return "ok"


def largest_run(t_s: np.ndarray, r: np.ndarray, windows=RUN_WINDOWS) -> dict | None:
    """The largest windowed mean of whitened residuals ``r`` (M, m) in time order.

    For each window of ``w`` consecutive rows and each component, ``z = sum(r) / sqrt(w)``
    is N(0, 1) for white unit residuals. Returns the largest ``|z|``, where it is, and the
    Bonferroni threshold for the number of windows tested (family-wise false-alarm
    probability :data:`RUN_FALSE_ALARM`).
    """
    r = np.asarray(r, dtype=float)
    ok = np.all(np.isfinite(r), axis=1)
    r, t = r[ok], np.asarray(t_s, dtype=float)[ok]
    M = len(r)
    if M < windows[0]:
        return None
    order = np.argsort(t, kind="stable")
    r, t = r[order], t[order]
    c = np.vstack([np.zeros((1, r.shape[1])), np.cumsum(r, axis=0)])
    best = (0.0, 0, 0, 0)
    n_tests = 0
    for w in windows:
        if w > M:
            break
        z = (c[w:] - c[:-w]) / math.sqrt(w)
        n_tests += z.size
        i, j = np.unravel_index(int(np.argmax(np.abs(z))), z.shape)
        if abs(z[i, j]) > abs(best[0]):
            best = (float(z[i, j]), int(i), int(w), int(j))
    z, i, w, j = best
    threshold = norm_isf(RUN_FALSE_ALARM / (2.0 * max(n_tests, 1)))
    return {"z": z, "threshold": threshold, "window": w, "component": j,
            "t_start_s": float(t[i]), "t_end_s": float(t[i + w - 1])}


def weakest_direction(x_eci: np.ndarray, P_eci: np.ndarray) -> dict:
    """The largest position sigma over the pass and its ECI axis (eigenvector of P_rr)."""
    P_rr = np.asarray(P_eci)[:, :3, :3]
    ok = np.all(np.isfinite(P_rr), axis=(1, 2))
    if not ok.any():
        return {"sigma_m": math.inf}
    idx = np.flatnonzero(ok)
    lam, vec = np.linalg.eigh(0.5 * (P_rr[idx] + np.swapaxes(P_rr[idx], 1, 2)))
    k = int(np.argmax(lam[:, -1]))
    sigma = float(np.sqrt(max(lam[k, -1], 0.0)))
    return {"sigma_m": sigma, "epoch_index": int(idx[k]), "axis_eci": vec[k, :, -1].tolist(),
            "radius_m": float(np.linalg.norm(x_eci[idx[k], :3]))}


SEVERITY_RANK = {"ok": 0, "suspect": 1, "failed": 2}


def verdict(reasons: list[tuple[str, str, str | None]]) -> dict:
    """``status``, ``reasons`` and ``advice`` of summary.json's integrity object from the
    tests' reasons ``(severity, text, advice key or None)``: the worst severity, the texts
    worst first (stable), the advice of each key once in that order. Shared by one
    spacecraft's and a formation's tests."""
    ranked = sorted(reasons, key=lambda x: -SEVERITY_RANK[x[0]])
    status = max((s for s, _, _ in reasons), key=SEVERITY_RANK.get, default="ok")
    advice = []
    for _, _, key in ranked:
        if key is not None and ADVICE[key] not in advice:
            advice.append(ADVICE[key])
    return {"status": status, "reasons": [t for _, t, _ in ranked], "advice": advice}


def assess(sol, p, model=None, *, normalized_residuals: dict | None = None) -> dict:
    """The integrity verdict of solution ``sol`` of pass ``p`` (see the module docstring); a
    formation's pass (several spacecraft) gets the joint solution's tests (:func:`_joint_assess`:
    each family's chi-square, every orbit's and clock's process rows, convergence, the mirror
    test of its relative geometry, finite numbers).

    ``model``: the :class:`factors.dynamics.MotionModel` of the solve (enables the
    manoeuvre and omitted-force tests; an EKF solution brings its own normalized innovations).
    ``normalized_residuals``: kind -> (M, m) residuals that are N(0, I) when the model is
    right, where they differ from ``sol.residuals``. Returns the ``"integrity"`` object of
    summary.json.
    """
    if len(getattr(p, "spacecraft", ())) > 1:
        return _joint_assess(sol, p)
    reasons: list[tuple[str, str, str]] = []  # (severity, text, advice key)
    notes: list[str] = []
    res = normalized_residuals
    if res is None and sol.method == "ekf":
        # the filter's own normalized innovations S^-1/2 b, from the covariance it used
        # (Bar-Shalom, Li & Kirubarajan 2001, eq. 5.4.1-1): both EKFs return them
        if "normalized_innovations" not in sol.extras:
            raise ValueError("an EKF solution without its normalized innovations "
                             "(extras['normalized_innovations'])")
        res = {**sol.residuals, **sol.extras["normalized_innovations"]}
    if res is None:
        res = sol.residuals
    families: dict[str, dict] = {}

    finite = bool(np.all(np.isfinite(sol.x_eci)) and np.all(np.isfinite(sol.P_eci)))
    if not finite:
        reasons.append(("failed", "the solution has non-finite states or covariances", "converge"))

    if sol.extras.get("converged") is False:
        reasons.append(("failed", f"the {sol.method} solver did not converge in "
                                  f"{sol.iterations} iterations", "converge"))

    row_weights = sol.extras.get("row_weights") or {}

    worst_run = None
    for kind, r in res.items():
        if kind in PRIOR_KINDS or kind not in p.families:
            continue
        r = np.asarray(r, dtype=float)
        fam = p.families[kind]
        test, keep = _family_test(r, row_weights.get(kind))
        n_rej = test["rejected"]
        sev = _severity(test)
        test["status"] = sev
        families[kind] = test
        if sev != "ok":
            reasons.append((sev, f"{kind}: chi2/dof = {test['normalized']:.3g} over {test['dof']} "
                                 f"components (expected ~1)", "outliers"))
        if test["rejected_fraction"] > MAX_REJECTED_FRACTION:
            reasons.append(("failed", rejected_reason(kind, test), "rejected"))
        elif n_rej:
            notes.append(f"{kind}: {n_rej} of {len(fam)} measurements rejected as outliers")
        run = largest_run(p.t_s[fam.k][keep], r[keep])
        if run is not None:
            run["kind"] = kind
            test["largest_run"] = run
            if worst_run is None or abs(run["z"]) / run["threshold"] > \
                    abs(worst_run["z"]) / worst_run["threshold"]:
                worst_run = run

    if worst_run is not None and abs(worst_run["z"]) > worst_run["threshold"]:
        sev = "failed" if abs(worst_run["z"]) > 2.0 * worst_run["threshold"] else "suspect"
        reasons.append((sev, f"{worst_run['kind']}: a run of {worst_run['window']} residuals "
                             f"({worst_run['t_start_s']:.0f}-{worst_run['t_end_s']:.0f} s) with mean "
                             f"{worst_run['z'] / math.sqrt(worst_run['window']):+.2g} sigma (z = "
                             f"{worst_run['z']:+.1f}, threshold {worst_run['threshold']:.1f}): "
                             f"a bias or an unmodelled force", "force"))

    motion = None
    chi2_motion = sol.extras.get("chi2_motion")
    # Only where the states are the fixed point of the whole chain (batch, iSAM2 after its
    # final polish): a fixed-lag smoother's states come from windows linearized up to its
    # relinearization threshold away (1 km), which alone makes the motion rows ~1 sigma.
    if chi2_motion is not None and p.n_epochs > 1 and sol.method != "fixed-lag":
        motion = _chi2_test(float(chi2_motion), 6 * (p.n_epochs - 1))
        # a smoother's process-noise residuals are far below their dimension on a right
        # model: any chi-square beyond the quantile is suspect
        sev = motion["status"] = _severity(motion, suspect_above=0.0)
        if sev != "ok":
            reasons.append((sev, f"motion: chi2/dof = {motion['normalized']:.3g} over "
                                 f"{motion['dof']} process-noise components: the orbit bends "
                                 f"away from the motion model", "force"))

    prior = None
    pr = [np.asarray(res[k], dtype=float) for k in PRIOR_KINDS if k in res and k in sol.residuals]
    if pr and sol.method != "ekf":
        m2 = float(sum(np.nansum(r * r) for r in pr))
        prior = _chi2_test(m2, sum(r.size for r in pr))
        prior["mahalanobis"] = math.sqrt(m2) if math.isfinite(m2) else math.inf
        # failed when the prior is 4x further (in sigma) than its gate would allow
        prior["status"] = _severity(prior, suspect_above=0.0,
                                    failed_above=FAILED_NORMALIZED_CHI2 ** 2)
        if prior["status"] != "ok":
            reasons.append((prior["status"], f"the prior is {prior['mahalanobis']:.3g} sigma "
                                             f"(Mahalanobis) from the solution", "prior"))
    iod = sol.extras.get("initial_orbit")
    if isinstance(iod, dict) and iod.get("prior_consistent") is False:
        reasons.append(("failed", f"the log's prior contradicts the measurements: "
                                  f"{iod.get('prior_mahalanobis', math.nan):.3g} sigma from the "
                                  f"orbit determined from the data alone", "prior"))

    glr = third = aberration = None
    if getattr(p, "breaks", ()):
        notes.append("manoeuvre and omitted-force tests not run: the log is solved as separate "
                     "arcs")
    elif model is not None and finite and p.n_epochs >= 8:
        try:
            mapped = _Mapped(p, sol, model, row_weights)
        except (np.linalg.LinAlgError, ValueError):
            mapped = None
        if mapped is not None:
            glr = manoeuvre_glr_windowed(p, sol, model, row_weights, mapped)
            third = third_body_sensitivity(mapped, sol, model)
            aberration = aberration_sensitivity(mapped, p, sol, model)
    if glr is not None and glr["glr"] > glr["threshold"]:
        glr["t_s"] = float(p.t_s[glr["epoch_index"]])
        reasons.append(("failed" if glr["glr"] > 4.0 * glr["threshold"] else "suspect",
                        f"the residuals ask for a manoeuvre of the orbit near t = {glr['t_s']:.0f} s "
                        f"(likelihood ratio {glr['glr']:.3g} > {glr['threshold']:.3g})", "force"))
    if third is not None and third["mean_nees"] > 0.25 * THIRD_BODY_NEES:
        text = (f"the motion model omits Sun and Moon gravity ({third['max_accel_mps2']:.2g} "
                f"m/s^2 here), which moves this solution by ~{third['position_rms_m']:.3g} m RMS "
                f"({math.sqrt(third['mean_nees'] / 6):.2g} sigma)")
        if third["mean_nees"] > THIRD_BODY_NEES:
            if third["expected_z"] < norm_isf(FALSE_ALARM_PROBABILITY):
                # a consider warning, not a residual test: the fit absorbs the pull's
                # signature, so the data cannot say whether the spacecraft feels it
                text += (f"; the residuals cannot tell whether they act (z ~ "
                         f"{third['expected_z']:.2g} expected along their signature)")
            reasons.append(("suspect", text, "third_body"))
        else:
            notes.append(text + "; --third-body if the spacecraft feels them")

    if aberration is not None and aberration["mean_nees"] > 0.25 * THIRD_BODY_NEES:
        text = (f"--no-aberration: the stellar aberration left out of "
                f"{', '.join(aberration['kinds'])} (up to {aberration['max_row_shift_sigma']:.3g} "
                f"sigma of a row) moves this solution by ~{aberration['position_rms_m']:.3g} m RMS "
                f"({math.sqrt(aberration['mean_nees'] / 6):.2g} sigma)")
        if aberration["mean_nees"] > THIRD_BODY_NEES:
            # a consider warning: the fit can absorb the shift into the orbit (chi-square 114.3
            # against 113.6 with the correction on a week of mars-cruise), so the residuals
            # need not say it is missing; the physics says it is there
            reasons.append(("suspect", text + " (consider analysis)", "aberration"))
        else:
            notes.append(text)
    mounting = sol.extras.get("camera_mounting_test")
    if mounting is not None and mounting["status"] != "ok":
        reasons.append(("suspect", f"the star rows ask for a camera mounting rotation of "
                                   f"{mounting['mounting_arcsec']:.3g} arcsec (chi-square falls "
                                   f"by {mounting['chi2_drop']:.3g} > {mounting['threshold']:.3g} "
                                   f"with it estimated): the star camera is not aligned with "
                                   f"the body frame", "mounting"))
    if aberration_off(p) and any(v.name.startswith(ATTITUDE_VARIABLE.name) for v in p.layout.extra):
        notes.append("--no-aberration with the attitude estimated: the consider analysis moves "
                     "the orbit's own rows only, not the attitude the star rows fix, whose shift "
                     "turns every body-frame row (docs/integrity.md)")

    weak = weakest_direction(sol.x_eci, sol.P_eci)
    if weak.get("sigma_m", 0.0) > WEAK_POSITION_FRACTION * weak.get("radius_m", math.inf):
        reasons.append(("suspect", f"the position is barely observable: sigma "
                                   f"{weak['sigma_m'] / 1e3:.3g} km along "
                                   f"{np.round(weak['axis_eci'], 3).tolist()} (ECI)",
                        "observability"))

    out = {**verdict(reasons), "notes": notes, "families": families,
           "weakest_direction": weak}
    if motion is not None:
        out["motion"] = motion
    if prior is not None:
        out["prior"] = prior
    if worst_run is not None:
        out["largest_run"] = worst_run
    if glr is not None:
        out["manoeuvre_glr"] = glr
    if third is not None:
        out["third_body_omitted"] = third
    if aberration is not None:
        out["aberration_omitted"] = aberration
    if mounting is not None:
        out["camera_mounting"] = mounting
    return out


def _joint_assess(sol, p) -> dict:
    """The verdict of a formation's joint solution (several spacecraft) from its data alone
    (the chi-square tests above): each family's whitened residuals, the process rows (every orbit's
    motion and the clocks' random walks), convergence and finite numbers."""
    tests, reasons = {}, []

    def worse(s, why, adv):
        if s != "ok":
            reasons.append((s, why, adv))

    weights = sol.extras.get("row_weights") or {}
    # a filter's innovations are tested normalized by their own covariance A P A^T + I
    residuals = sol.extras.get("normalized_innovations") or sol.residuals
    for kind, r in residuals.items():
        test, _ = _family_test(r, weights.get(kind))
        test["status"] = _severity(test)
        tests[kind] = test
        worse(test["status"], f"{kind}: chi2/dof {test['normalized']:.3g} over {test['dof']} "
              f"components (p = 1e{test['log10_p']:.0f})", "outliers")
        if test["rejected_fraction"] > MAX_REJECTED_FRACTION:   # (a gate, a robust kernel)
            worse("failed", rejected_reason(kind, test), "rejected")
    if "chi2_motion" in sol.extras:   # (a filter has no process residuals)
        motion = _chi2_test(float(sol.extras["chi2_motion"]), max(p.n_epochs - 1, 1) * p.layout.n)
        motion["status"] = _severity(motion)
        tests["motion"] = motion
        worse(motion["status"], f"motion: chi2/dof {motion['normalized']:.3g}", "force")
    if not sol.extras.get("converged", True):
        worse("failed", "the solver did not converge", "converge")
    mirror = sol.extras.get("mirror_test")
    if mirror is not None:
        tests["mirror"] = mirror
        if mirror["status"] != "ok":
            better = mirror["chi2_mirrored"] < mirror["chi2"]
            geometry = mirror.get("geometry",
                                  "the relative geometry mirrored through the first spacecraft")
            worse("failed", f"{geometry} "
                  f"{'fits the data better' if better else 'fits the data as well'} "
                  f"(chi-square {mirror['chi2_mirrored']:.6g} against {mirror['chi2']:.6g}, "
                  f"{mirror['largest_difference_m']:.3g} m apart): the links cannot tell the "
                  f"relative position from its mirror image",
                  "mirror_better" if better and sol.method != "batch" else "mirror")
    agreement = sol.extras.get("batch_agreement")
    if agreement is not None and "spacecraft" in agreement:
        tests["batch_agreement"] = agreement
        if agreement["status"] != "ok":
            worse(agreement["status"], f"the {sol.method} relative state of "
                  f"{agreement['spacecraft']} departs from the batch solution's by "
                  f"{agreement['normalized']:.3g} times its own covariance per dimension (up to "
                  f"{agreement['largest_position_difference_m']:.3g} m): its covariance is "
                  f"optimistic", "agreement")
    curvature = range_curvature_test(p, sol)
    tests["range_curvature"] = curvature
    if curvature["status"] != "ok":
        worse(curvature["status"], f"the range from {curvature['reference']} to "
              f"{curvature['spacecraft']} is bent {curvature['bend_m']:.3g} m over the relative "
              f"position's {curvature['sigma_across_m']:.3g} m sigma across the "
              f"{curvature['separation_m']:.4g} m line of sight, {curvature['ratio']:.3g} times "
              f"its {curvature['sigma_along_m']:.3g} m sigma along it: the covariance (linear) "
              f"understates the errors across the line", "curvature")
    if not (np.all(np.isfinite(sol.x_eci)) and np.all(np.isfinite(sol.P_block))):
        worse("failed", "non-finite states or covariances", None)
    return {**verdict(reasons), "tests": tests,
            "false_alarm_probability": FALSE_ALARM_PROBABILITY}


def rejected_reason(kind: str, test: dict) -> str:
    """The reason of a family whose rows were mostly rejected (more than
    :data:`MAX_REJECTED_FRACTION`, by the gate or a robust kernel): its answer is not the
    data's, whatever the chi-square of the rows kept says."""
    return (f"{kind}: {test['rejected']} of {test['rows']} measurements rejected "
            f"({100 * test['rejected_fraction']:.0f} % > {100 * MAX_REJECTED_FRACTION:.0f} %): "
            f"the answer is not the data's")


def _family_test(r: np.ndarray, w) -> tuple[dict, np.ndarray]:
    """The chi-square test of a family's whitened residuals ``r`` (M, m) over its finite rows
    not rejected (``w``: (M,) robust weights / gate decisions, 0 = rejected, or None); the
    test dict gains ``rejected``, ``rejected_fraction``; returns it and the kept-row mask."""
    chi2, dof, n_rej, keep = _family_chi2(r, w)
    test = _chi2_test(chi2, dof)
    test.update(rows=len(keep), rejected=n_rej, rejected_fraction=n_rej / max(len(keep), 1))
    return test, keep


def _family_chi2(r: np.ndarray, w) -> tuple[float, int, int, np.ndarray]:
    """A family's chi-square over its finite rows not rejected, its dimension, the number of
    rejected rows and the kept-row mask (see :func:`_family_test`)."""
    r = np.asarray(r, dtype=float)
    keep = np.all(np.isfinite(r), axis=1)
    n_rej = 0 if w is None else int(np.sum(np.asarray(w) == 0))
    if w is not None:
        keep &= np.asarray(w) > 0
    return float(np.sum(r[keep] ** 2)), int(keep.sum() * r.shape[1]), n_rej, keep


CHI2_TAIL_AT_MEAN_MIN = 0.3173
"""A lower bound of P(X > k) for X ~ chi-square(k), k = 1, 2, ...: erfc(1/sqrt 2) = 0.31731 at
k = 1, growing with k towards 1/2 (the median of a chi-square lies below its mean: Sen, "The
mean-median-mode inequality and noncentral chi square distributions", Sankhya A, 1989);
``tests/test_integrity.py`` checks the bound against scipy for k up to 10^7."""


def _beyond_quantile(chi2: float, dof: int) -> bool:
    """``chi2`` beyond the 1 - :data:`FALSE_ALARM_PROBABILITY` quantile of chi-square(``dof``)
    (the ``log10_p`` of :func:`_chi2_test` below log10 of that probability). A value at most
    its dimension is decided without the tail function: its tail probability is at least
    :data:`CHI2_TAIL_AT_MEAN_MIN`. Same decisions; a solve that fits its data never loads
    ``scipy.special`` (0.2 s, most of a short pass's fixed cost)."""
    if math.isfinite(chi2) and chi2 <= max(int(dof), 1):
        return False
    return _chi2_test(chi2, dof)["log10_p"] < math.log10(FALSE_ALARM_PROBABILITY)


def needs_prior_test(sol, p) -> str | None:
    """Why a solution started from the log's prior should have that prior tested against
    the measurements' own orbit, or None when it fits the data: no convergence, non-finite
    numbers, a measurement family beyond the suspect chi-square (its rejected rows left out)
    or mostly rejected, or the prior itself beyond its gate. Cheap: residuals only."""
    if sol.extras.get("converged") is False:
        return "no convergence"
    if not (np.all(np.isfinite(sol.x_eci)) and np.all(np.isfinite(sol.P_eci))):
        return "non-finite solution"
    row_weights = sol.extras.get("row_weights") or {}
    prior_chi2, prior_dof = 0.0, 0
    for kind, r in sol.residuals.items():
        r = np.asarray(r, dtype=float)
        keep = np.all(np.isfinite(r), axis=1)
        if kind in PRIOR_KINDS:
            prior_chi2 += float(np.sum(r[keep] ** 2))
            prior_dof += int(keep.sum() * r.shape[1])
            continue
        # _severity(_family_test(...)) != "ok", with the tail probability only when needed
        chi2, dof, n_rej, _ = _family_chi2(r, row_weights.get(kind))
        if n_rej / max(len(r), 1) > MAX_REJECTED_FRACTION:
            return f"{kind}: most rows rejected"
        if not math.isfinite(chi2) or (chi2 / max(dof, 1) > SUSPECT_NORMALIZED_CHI2
                                       and _beyond_quantile(chi2, dof)):
            return f"{kind}: residuals beyond their noise"
    if prior_dof and _beyond_quantile(prior_chi2, prior_dof):
        return "the prior is far from the solution"
    return None


def stderr_line(integrity: dict) -> str | None:
    """One line for stderr when the verdict is not ``ok``: what is wrong, what to try."""
    if integrity["status"] == "ok":
        return None
    first = integrity["reasons"][0] if integrity["reasons"] else "see summary.json"
    more = len(integrity["reasons"]) - 1
    tail = f" (+{more} more in summary.json)" if more > 0 else ""
    advice = f"; {integrity['advice'][0]}" if integrity["advice"] else ""
    return f"fgnav: integrity {integrity['status']}: {first}{tail}{advice}"


# ---- tests of the motion model along the solution (linearized, deterministic dynamics) --

class _Mapped:
    """Every whitened measurement row mapped to the first state: ``H_j = a_j^T Phi(t_k, t_0)``.

    With deterministic dynamics the pass is a linear model in the first state ``dx_0``; the
    columns are scaled to unit norm (``dx_0 = s * dz``) so the 6x6 algebra is well
    conditioned whatever the units.
    """

    def __init__(self, p, sol, model, row_weights=None):
        self.t0_j2000_s = float(j2000_seconds(p.epoch0))
        rejected = {k: np.asarray(w) == 0 for k, w in (row_weights or {}).items()
                    if k not in PRIOR_KINDS}
        rejected = {k: r for k, r in rejected.items() if r.any()}   # none: the bound's rows
        self.X = block_values(p, sol.x_eci, sol.variables)
        self.rejected = rejected or None
        self.Phik, H, rows = rows_at_first_state(p, self.X, model, self.rejected)
        live = self.live = np.any(rows.A != 0, axis=1)
        H = H[live]
        norm = np.sqrt(np.sum(H * H, axis=0))
        self.s = 1.0 / np.where(norm > 0, norm, 1.0)
        self.H = H * self.s
        self.b = rows.b[live]
        self.k = rows.k[live]
        self.J = self.H.T @ self.H
        self.N = p.n_epochs
        self.speed_mps = np.linalg.norm(np.asarray(sol.x_eci)[:, 3:6], axis=1)


def manoeuvre_glr(m: _Mapped, n_tests: int | None = None, tested=None) -> dict | None:
    """Generalized likelihood ratio for an impulsive manoeuvre ``dv`` (3,) at each epoch.

    A ``dv`` at ``tau`` adds the columns ``H_j Phi(t_0, tau) [0; I]`` to the rows after
    ``tau`` (Willsky & Jones 1976). With ``h_tau = sum_{t_j >= tau} H_j^T b_j`` and
    ``J_tau = sum_{t_j >= tau} H_j^T H_j`` the chi-square reduction it buys is
    ``u^T M^+ u``, ``u = C^T (h_tau - J_tau J^-1 h)``, ``M = C^T (J_tau - J_tau J^-1 J_tau) C``,
    ``C = Phi(t_k, t_0)^-1 [0; I]``: chi-square with 3 degrees of freedom without a
    manoeuvre; the largest over the epochs is tested against the Bonferroni threshold
    (over ``n_tests`` epochs: default the pass's; a window's tests count the whole pass's).
    ``tested``: (N,) bool, the epochs whose ratio counts (default all).
    """
    N = m.N
    if N < 8 or len(m.b) < 12:
        return None
    hk = np.zeros((N, 6))
    np.add.at(hk, m.k, m.H * m.b[:, None])
    h_tau = np.cumsum(hk[::-1], axis=0)[::-1]
    try:
        Jinv = np.linalg.inv(m.J)
    except np.linalg.LinAlgError:
        return None
    h = h_tau[0]
    threshold = chi2_isf(RUN_FALSE_ALARM / max((n_tests or N) - 2, 1), 3)
    dv_max = MAX_MANOEUVRE_FRACTION * m.speed_mps
    # The (N, 6, 6) sums J_tau in chunks of epochs from the last one back, carrying the sum
    # of the later epochs (prepended to each chunk's cumulative sum: the same additions in
    # the same order as one cumulative sum over the pass).
    order = np.argsort(m.k, kind="stable")     # rows of an epoch keep their order
    k_sorted = m.k[order]
    stat = np.zeros(N)
    carry = np.zeros((1, 6, 6))
    Jinv_h = Jinv @ h
    for a in range(((N - 1) // CHUNK) * CHUNK, -1, -CHUNK):
        b = min(a + CHUNK, N)
        lo, hi = np.searchsorted(k_sorted, [a, b])
        Hc = m.H[order[lo:hi]]
        # each epoch's sum of H_j^T H_j: its rows are consecutive in k_sorted
        Jk = np.zeros((b - a, 6, 6))
        kc = k_sorted[lo:hi]
        if len(kc):
            first = np.concatenate([[0], np.flatnonzero(np.diff(kc)) + 1])
            ks = kc[first]
            Jk[ks - a] = np.add.reduceat(Hc[:, :, None] * Hc[:, None, :], first, axis=0)
        J_tau = np.cumsum(np.concatenate([carry, Jk[::-1]]), axis=0)[1:][::-1]
        carry = J_tau[:1].copy()
        # the ratio at the tested epochs only (a window's middle span)
        e = np.arange(a, b) if tested is None else a + np.flatnonzero(tested[a:b])
        if not len(e):
            continue
        J_e = J_tau[e - a]
        try:
            C = np.linalg.solve(m.Phik[e], np.broadcast_to(np.eye(6)[:, 3:], (len(e), 6, 3))) \
                / m.s[None, :, None]
        except np.linalg.LinAlgError:
            return None
        Ct = np.swapaxes(C, 1, 2)
        u = (Ct @ (h_tau[e] - J_e @ Jinv_h)[:, :, None])[:, :, 0]
        M = Ct @ (J_e - J_e @ Jinv @ J_e) @ C
        # u^T M^+ u by eigen-decomposition (M is singular where no row follows the epoch),
        # over the directions where an impulse within MAX_MANOEUVRE_FRACTION of the orbital
        # speed could reach the threshold: w dv^2 is the chi-square an impulse dv buys
        w, V = np.linalg.eigh(0.5 * (M + np.swapaxes(M, 1, 2)))
        keep = (w > 1e-9 * np.maximum(w[:, -1:], 1e-300)) & \
            (w * dv_max[e, None] ** 2 > threshold)
        proj = (np.swapaxes(V, 1, 2) @ u[:, :, None])[:, :, 0]
        stat[e] = np.sum(np.where(keep, proj * proj / np.where(keep, w, 1.0), 0.0), axis=1)
    stat[[0, -1]] = 0.0  # a manoeuvre before the first or after the last row is no test
    k = int(np.argmax(stat))
    return {"glr": float(stat[k]), "threshold": threshold, "epoch_index": k}


MAPPING_GROWTH_MAX = 1e10
"""``|Phi(t_k, t_0)|_F^2`` above which the manoeuvre test maps rows to a later state than
the first (:func:`manoeuvre_glr_windowed`)."""


def window_span(t_s: np.ndarray, growth: np.ndarray) -> float:
    """The span (s) of the manoeuvre test's windows: the time the pass took to reach
    ``|Phi|_F^2 =`` :data:`MAPPING_GROWTH_MAX` (``growth`` (N,) per epoch at ``t_s`` (N,) s),
    but at least the pass's first :data:`WINDOW_STEPS_MIN` steps. Where one step already
    passes the limit (``Phi``'s position-velocity block is the step in seconds: a step of
    16 h or more, as a heliocentric cruise's daily fix) the limit cannot be kept by any
    window; a span of zero made ~1e15 windows (the verdict never returned), and a window two
    spans long needs ~8 epochs for the test to run at all."""
    k = int(np.argmax(growth > MAPPING_GROWTH_MAX))
    floor = t_s[min(WINDOW_STEPS_MIN, len(t_s) - 1)] - t_s[0]
    return float(max(t_s[max(k - 1, 0)] - t_s[0], floor, 1e-9))


WINDOW_STEPS_MIN = 4
"""Steps a window's span covers at least (:func:`window_span`)."""


def manoeuvre_glr_windowed(p, sol, model, row_weights, whole: _Mapped) -> dict | None:
    """:func:`manoeuvre_glr` in windows of the pass short enough for the mapping to their
    first state to keep its digits.

    A symplectic ``Phi`` has condition number ``|Phi|_2^2 <= |Phi|_F^2``, and the mapped
    rows lose that factor in their weakest directions. Measured on gto-transfer at 1 Hz with
    two solutions 16 um apart: the largest ratio agreed to 1e-9 over 4 h (``|Phi|_F^2``
    2.5e9) and was 88 against 16 over 12 h (6e11), 255 against 154 over 24 h, up to 3,153
    over 278 h (threshold ~50): noise, and false alarms. Beyond :data:`MAPPING_GROWTH_MAX`
    the test runs in windows two spans long, a span apart (a span: the time the pass's
    start took to reach the limit), each mapped to its own first state and counting the
    ratios of its middle span only, so that every epoch is tested with at least half a span
    of rows on either side (the rows before pin the orbit a manoeuvre would change). The
    largest ratio over all windows is tested against the threshold of the whole pass's
    epochs; ``"windows"`` in the result says how many there were.
    """
    from types import SimpleNamespace

    growth = np.sum(whole.Phik * whole.Phik, axis=(1, 2))
    if growth.max() <= MAPPING_GROWTH_MAX:
        return manoeuvre_glr(whole)
    N, t = p.n_epochs, p.t_s
    span = window_span(t, growth)
    best, n_windows = None, 0
    for j in range(int(np.ceil((t[-1] - t[0]) / span))):
        s0, s1 = np.searchsorted(t, t[0] + span * np.array([j - 0.5, j + 1.5]))
        mid = (t[s0:s1] >= t[0] + span * j) & (t[s0:s1] < t[0] + span * (j + 1))
        if s1 - s0 < 8 or not mid.any():
            continue
        sub, rows_of = slice_pass(p, s0, s1)
        part = SimpleNamespace(
            x_eci=np.asarray(sol.x_eci)[s0:s1],
            variables={k: (x[s0:s1], P[s0:s1]) for k, (x, P) in (sol.variables or {}).items()})
        weights = {k: np.asarray(w)[rows_of[k]] for k, w in row_weights.items() if k in rows_of}
        try:
            g = manoeuvre_glr(_Mapped(sub, part, model, weights), n_tests=N, tested=mid)
        except (np.linalg.LinAlgError, ValueError):
            g = None
        n_windows += 1
        if g is not None and (best is None or g["glr"] > best["glr"]):
            best = dict(g, epoch_index=g["epoch_index"] + int(s0))
    if best is not None:
        best["windows"] = n_windows
    return best


def aberration_sensitivity(m: _Mapped, p, sol, model) -> dict | None:
    """How far the stellar aberration a ``--no-aberration`` solve leaves out moves the
    solution (consider analysis, as :func:`third_body_sensitivity`).

    Along the solution, applying the correction (Urban & Seidelmann 2013, eq. 7.40) changes
    the whitened rows by ``db = b_on - b_off``; the fit through the first state absorbs
    ``dz_0 = J^-1 H^T db``, which moves the trajectory by ``e_k = Phi_k (s dz_0)`` (Tapley,
    Schutz & Born 2004, ch. 6). Returned as its mean Mahalanobis size against the solution's
    covariances, with the largest shift of a row in its own sigma (``max |db|``); None when every
    row has its correction.
    """
    kinds = aberration_off(p)
    if not kinds:
        return None
    _, _, rows_on = rows_at_first_state(with_aberration(p), m.X, model, m.rejected)
    if rows_on.b.shape != m.live.shape:
        return None
    db = rows_on.b[m.live] - m.b
    try:
        dz0 = np.linalg.solve(m.J, m.H.T @ db)
        e = np.einsum("kij,j->ki", m.Phik, dz0 * m.s)
        nees = np.einsum("ki,ki->k", e, np.linalg.solve(sol.P_eci, e[..., None])[..., 0])
    except np.linalg.LinAlgError:
        return None
    return {"kinds": kinds, "mean_nees": float(np.mean(nees)),
            "position_rms_m": float(np.sqrt(np.mean(np.sum(e[:, :3] ** 2, axis=1)))),
            "max_row_shift_sigma": float(np.max(np.abs(db))) if db.size else 0.0}


def third_body_sensitivity(m: _Mapped, sol, model) -> dict | None:
    """How far the omitted Sun and Moon gravity moves the solution (consider analysis).

    The omitted acceleration ``a_3b(t)`` displaces the trajectory by
    ``dx(t_k) = sum_s Phi(t_k, t_s) [0; a_3b(t_s)] dt`` (linear response along the solution);
    the least-squares fit absorbs part of it through the first state,
    ``dx_0 = -J^-1 H^T (A dx)``; what remains, ``e_k = dx(t_k) + Phi_k dx_0``, is the error
    the omission causes (Tapley, Schutz & Born 2004, ch. 6, consider covariance). Returned as
    its mean Mahalanobis size against the solution's covariances. ``expected_z``: the norm of
    what the fit leaves of the omission's residual signature (the size, in sigma, of a score
    test along it if the spacecraft feels the pull); ``z``: the residuals' projection on that
    signature, N(0, 1) without the pull and N(expected_z, 1) with it.
    """
    if model.third_body or m.N < 3:
        return None
    t = sol.t_s
    tj = m.t0_j2000_s + t
    r = sol.x_eci[:, :3]
    a = (accel_third_body(r, sun_position_eci_m(tj), model.mu_sun) +
         accel_third_body(r, moon_position_eci_m(tj), model.mu_moon))
    # dx(t_k) = Phi_k sum_{s<k} Phi_s^-1 [0; a_s] dt_s  (rectangle rule per step)
    dt = np.diff(t)
    try:
        g = np.linalg.solve(m.Phik[:-1], np.concatenate([np.zeros((m.N - 1, 3)), a[:-1]], axis=1)
                            [..., None])[..., 0] * dt[:, None]
    except np.linalg.LinAlgError:
        return None
    z = np.vstack([np.zeros((1, 6)), np.cumsum(g, axis=0)])      # Phi_k^-1 dx(t_k)
    # predicted whitened residual change of each row: H_j (unscaled) z_k = (H_j / s) z_k
    db = np.einsum("rj,rj->r", m.H, z[m.k] / m.s[None, :])
    dz0 = -np.linalg.solve(m.J, m.H.T @ db)
    e = np.einsum("kij,kj->ki", m.Phik, z + (dz0 * m.s)[None, :])
    try:
        nees = np.einsum("ki,ki->k", e, np.linalg.solve(sol.P_eci, e[..., None])[..., 0])
    except np.linalg.LinAlgError:
        return None
    # what the fit leaves of the force's signature in the residuals, and the residuals'
    # projection on it (a score test of one known signal; Kay 1998, vol. II, ch. 3)
    db_perp = db + m.H @ dz0
    norm = float(np.linalg.norm(db_perp))
    z = float(m.b @ db_perp) / norm if norm > 0 else 0.0
    return {"mean_nees": float(np.mean(nees)), "expected_z": norm, "z": z,
            "position_rms_m": float(np.sqrt(np.mean(np.sum(e[:, :3] ** 2, axis=1)))),
            "max_accel_mps2": float(np.max(np.linalg.norm(a, axis=1)))}
