"""The misalignment study: one confocal Earth/star sensor against separate Earth and star
cameras, and tight against loose coupling of the stars, on the same simulated passes.

Wu et al.'s confocal Earth/star sensor images the Earth's limb and the stars on one detector:
the stars fix the attitude of the very frame the Earth direction is measured in. Separate
Earth and star cameras add the mounting rotation between them, known only to the ground
alignment; an error there tilts every Earth direction the stars rotate into ECI, and the
orbit with it (30 arcsec is 6 km at GEO). The study (built-in scenario ``geo-limb`` observed
with raw stars, :func:`fgnav.simulate.pass_sim.raw_star_scenario`; the Earth camera is the
body frame) compares, on the same pass and noise (the mounting error comes from its own
seeded stream):

* (a) confocal: no mounting error, the attitude estimated (``--estimate attitude``);
* (b) separate, the mounting error (``MOUNTING_SIGMA_ARCSEC``, 1σ per axis) ignored;
* (c) separate, the mounting estimated in the graph (``--estimate camera-alignment``,
  :mod:`factors.alignment`; Shuster & Pitone 1991, "Batch estimation of spacecraft sensor
  alignments I. Relative alignment estimation", J. Astronautical Sciences 39(4)), its prior
  the mounting tolerance the error is drawn from (``--alignment-sigma-arcsec 30``);

and tight coupling (every star a factor on the attitude, the confocal pass of (a)) against
loose coupling (the same stars solved frame by frame into attitude rows first,
:func:`fgnav.loose_attitude.attitude_rows_from_stars`), with the standard star camera and
with a star camera that sees few stars (:data:`FEW_STARS`: 2-3 per frame).

Metrics, against the truth of the independent DOP853 integrator and the Earth-pointing
attitude plan (:meth:`fgnav.simulate.pass_sim.SimulatedPass.truth_attitude`): RMS of the
position error norm; RMS of the attitude error angle ``|Log(R_true^T R)|`` of the body (Earth
camera) frame; the mean NEES of the 6-dim orbit state (6 expected) and of the attitude
(3 expected), each averaged over the seeds.

The Cramér–Rao bound of each case's joint problem is computed apart from the solvers
(:func:`joint_crb`): the dense Fisher information of every orbit state, every attitude and
the one constant mounting, from the measurement models' Jacobians, the motion factor's
(``factors.dynamics``: the STM and the process noise's square-root information), the
attitude random walk's (``factors.random_walk``) and the priors, at the truth, inverted as
one dense matrix (no GTSAM, no chain elimination). It is the bound of an unbiased estimator
with the models the solver uses (Van Trees 1968, "Detection, Estimation and Modulation
Theory", part I, sec. 2.4); case (b)'s model ignores the mounting, so no bound is given there.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from factors.dynamics import propagate_many
from factors.constants import ARCSEC
from factors.geometry import so3_exp, so3_log
from factors.random_walk import rot3_random_walk_residual
from fgnav.diagnostics.crb import cumulative_stm
from fgnav.graph import linearize_all
from fgnav.diagnostics.integrity import assess
from fgnav.io.log_csv import log_from_arrays
from fgnav.loose_attitude import attitude_rows_from_stars
from fgnav.measurements import build_pass, with_estimates
from fgnav.models.registry import ATTITUDE_VARIABLE, CAMERA_ALIGNMENT, STAR_DIRECTION_BODY
from fgnav.pipeline import accuracy_metrics, solve
from fgnav.scenarios import load_scenario
from fgnav.simulate.body_directions import lvlh_R_eci_from_body
from fgnav.simulate.pass_sim import RAW_STAR_CAMERA, raw_star_scenario, simulate_pass
from fgnav.solvers.options import SmootherOptions
from fgnav.time import j2000_seconds

__all__ = ["MOUNTING_SIGMA_ARCSEC", "FEW_STARS", "few_stars", "CASES", "misalignment_study",
           "joint_crb", "format_misalignment_table"]

MOUNTING_SIGMA_ARCSEC = 30.0
"""The separate star camera's mounting error, 1σ per axis (arcsec)."""

FEW_STARS = (2, 3)
"""The few-star camera reports 2 or 3 of the stars the standard camera sees in a frame (at
least 2 in every frame of the ``geo-limb`` pass, 12.6 on average), drawn at random per frame:
a tracker that hands over only the first stars it identifies, or a smaller aperture."""

FEW_STARS_STREAM = 3
"""Second entropy word of the stream that picks the few-star camera's stars."""

CASES = ("a confocal", "b separate, ignored", "c separate, estimated",
         "tight", "loose", "tight, few stars", "loose, few stars")
"""Rows of the table (module docstring); "tight" is the confocal pass of row (a)."""

_ESTIMATE = {"c separate, estimated": (ATTITUDE_VARIABLE.name, CAMERA_ALIGNMENT.name)}
"""The graph variables of the cases that estimate more than the attitude (every case does that)."""


def _scenario(duration_h, step_s, mounting_arcsec=0.0):
    cam = dataclasses.replace(RAW_STAR_CAMERA, mounting_sigma_arcsec=mounting_arcsec)
    scn = load_scenario("geo-limb").with_options(duration_h=duration_h, step_s=step_s)
    return raw_star_scenario(scn, cam)


def few_stars(log, seed: int):
    """``log`` with at most 2 or 3 (:data:`FEW_STARS`, drawn per frame) of each frame's
    ``star_direction_body`` rows, chosen at random; the draw is seeded by
    ``[seed, FEW_STARS_STREAM]``."""
    rng = np.random.default_rng([seed, FEW_STARS_STREAM])
    star = log.select(STAR_DIRECTION_BODY.kind)
    keep = np.ones(len(log.t_s), bool)
    keep[star] = False
    t = np.asarray(log.t_s)[star]
    for tk in np.unique(t):
        rows = star[t == tk]
        n = int(rng.integers(FEW_STARS[0], FEW_STARS[1] + 1))
        keep[rng.permutation(rows)[:n]] = True
    extra = {c: np.asarray(v)[keep] for c, v in log.extra.items()}
    return log_from_arrays(log.epoch0, np.asarray(log.t_s)[keep], np.asarray(log.kind)[keep],
                           np.asarray(log.xyz)[keep], np.asarray(log.sigma)[keep], extra,
                           centre=log.centre, schema=log.schema)


def _truth_block(p, sim):
    """Block values (N, n) of ``p``'s layout at the truth: orbit, attitude (the plan) and the
    mounting (the simulated one, or the identity)."""
    x = sim.x_true[np.searchsorted(sim.t_s, p.t_s)]
    X = p.layout.initial(x)
    if p.layout.has(ATTITUDE_VARIABLE.name):
        X[:, p.layout.slices[ATTITUDE_VARIABLE.name]] = so3_log(lvlh_R_eci_from_body(x))
    if p.layout.has(CAMERA_ALIGNMENT.name):
        w = np.array([sim.truth_params.get(c, np.zeros(1))[0] for c in CAMERA_ALIGNMENT.components])
        X[:, p.layout.slices[CAMERA_ALIGNMENT.name]] = w
    return X


def joint_crb(p, X_true: np.ndarray, options: SmootherOptions) -> dict:
    """The Cramér–Rao bound of the joint problem of ``p`` at the block values ``X_true``
    (N, n): the orbit, every epoch's attitude and the one constant camera alignment, from
    the dense Fisher information (module docstring).

    Parameters: the first orbit state ``x_0`` (the others ``x_k = f(x_0)``, each
    measurement row's orbit Jacobian mapped by the motion model's state transition matrix,
    ``a^T Phi(t_k, t_0)``: deterministic dynamics, as :mod:`fgnav.diagnostics.crb`; the
    ``q_m2_s3`` = 1e-12 m^2/s^3 of the study moves a GEO position by ~2 m in 6 h, three
    orders below the bound, and a dense matrix over every epoch's orbit state would have a
    condition number beyond double precision), the attitude ``A_k`` of every epoch (3 each,
    right perturbations, its random walk's rows between epochs) and the mounting ``M``
    (3, its rows summed over the epochs). Returns ``{"position_rms_m", "attitude_rms_rad",
    "alignment_sigma_rad" (3,) or None}``: square roots of the mean traces of the bounds on
    the epochs' positions and attitudes."""
    lay = p.layout
    N = p.n_epochs
    att = lay.slices.get(ATTITUDE_VARIABLE.name)
    mnt = lay.slices.get(CAMERA_ALIGNMENT.name)
    D = 6 + (3 * N if att is not None else 0) + (3 if mnt is not None else 0)
    t0 = float(j2000_seconds(p.epoch0))
    dt = np.diff(p.t_s)
    if N > 1:
        _, Phi = propagate_many(X_true[:-1, :6], dt, options.motion_model(), t0 + p.t_s[:-1])
        Phik = cumulative_stm(Phi)
    else:
        Phik = np.eye(6)[None]

    def dense(k, A):
        """Whitened rows ``A (R, n)`` at epoch ``k`` in the dense columns."""
        G = np.zeros((len(A), D))
        G[:, :6] = A[:, :6] @ Phik[k]
        if att is not None:
            G[:, 6 + 3 * k:9 + 3 * k] = A[:, att]
        if mnt is not None:
            G[:, -3:] = A[:, mnt]
        return G

    rows = linearize_all(p, X_true)              # the models' whitened Jacobians and priors
    G = [dense(k, rows.A[rows.k == k]) for k in np.unique(rows.k)]
    if att is not None and N > 1:                # the attitude's random walk, w = 1/sqrt(psd dt)
        _, H0, H1 = rot3_random_walk_residual(so3_exp(X_true[:-1, att]), so3_exp(X_true[1:, att]))
        w = 1.0 / ATTITUDE_VARIABLE.step_sigma(dt)
        Gw = np.zeros((N - 1, 3, D))
        for k in range(N - 1):
            Gw[k, :, 6 + 3 * k:9 + 3 * k] = w[k] * H0[k]
            Gw[k, :, 9 + 3 * k:12 + 3 * k] = w[k] * H1[k]
        G.append(Gw.reshape(-1, D))
    G = np.concatenate(G)
    J = G.T @ G
    s = 1.0 / np.sqrt(np.maximum(np.diag(J), 1e-300))
    C = np.linalg.inv(J * s[:, None] * s[None, :]) * s[:, None] * s[None, :]
    P_pos = np.einsum("kij,jl,kml->kim", Phik[:, :3], C[:6, :6], Phik[:, :3])
    out = {"position_rms_m": float(np.sqrt(np.mean(np.trace(P_pos, axis1=1, axis2=2)))),
           "attitude_rms_rad": None, "alignment_sigma_rad": None}
    if att is not None:
        out["attitude_rms_rad"] = float(np.sqrt(np.diag(C)[6:6 + 3 * N].sum() / N))
    if mnt is not None:
        out["alignment_sigma_rad"] = np.sqrt(np.diag(C)[-3:]).tolist()
    return out


def _metrics(sol, p, sim, model) -> dict:
    """Position RMS (m), attitude RMS angle (rad), orbit NEES (6-dim) and attitude NEES
    (3-dim) of a solution against the truth, over the pass's epochs, and whether its
    integrity verdict (:func:`fgnav.diagnostics.integrity.assess`, motion model ``model``) is ``ok``."""
    k = np.searchsorted(sol.t_s, p.t_s)
    x_true = sim.x_true[np.searchsorted(sim.t_s, p.t_s)]
    sol_p = dataclasses.replace(sol, t_s=sol.t_s[k], x_eci=sol.x_eci[k], P_eci=sol.P_eci[k])
    m = accuracy_metrics(sol_p, x_true)
    w, P = sol.variables[ATTITUDE_VARIABLE.name]
    R_true = lvlh_R_eci_from_body(x_true)
    err = so3_log(np.swapaxes(R_true, -1, -2) @ so3_exp(w[k]))
    nees_a = np.einsum("ki,ki->k", err, np.linalg.solve(P[k], err[..., None])[..., 0])
    return {"position_rms_m": m["position_rms_m"], "nees": m["nees_mean"],
            "attitude_rms_rad": float(np.sqrt(np.mean(np.sum(err * err, axis=1)))),
            "attitude_nees": float(np.mean(nees_a)),
            "integrity_ok": float(assess(sol, p, model)["status"] == "ok")}


def _stars_per_frame(log) -> float:
    t = np.asarray(log.t_s)[log.select(STAR_DIRECTION_BODY.kind)]
    return float(len(t) / max(len(np.unique(log.t_s)), 1))


def _tight_vs_loose(tight, loose, crb_t, crb_l) -> dict:
    """Tight against loose coupling over the seeds: the paired difference of the position
    RMS (tight - loose, m) with its standard error, the seeds where tight is worse, the mean
    attitude RMS of both (rad), and the bounds (tight's information contains loose's: the
    attitude rows' covering sigma gives at most the stars' information, and loose loses the
    frames with fewer than two stars)."""
    d = np.array([t["position_rms_m"] - lo["position_rms_m"] for t, lo in zip(tight, loose)])
    se = float(np.std(d, ddof=1) / np.sqrt(len(d))) if len(d) > 1 else float("nan")
    out = {"position_diff_mean_m": float(d.mean()), "position_diff_se_m": se,
           "seeds_tight_worse": [t["seed"] for t, x in zip(tight, d) if x > 0],
           "attitude_rms_tight_rad": float(np.mean([t["attitude_rms_rad"] for t in tight])),
           "attitude_rms_loose_rad": float(np.mean([lo["attitude_rms_rad"] for lo in loose]))}
    out["position_not_worse"] = bool(out["position_diff_mean_m"] <= 2.0 * se) if len(d) > 1 \
        else bool(d[0] <= 0)
    out["attitude_better"] = out["attitude_rms_tight_rad"] < out["attitude_rms_loose_rad"]
    if crb_t and crb_l:
        out["crb_position_not_worse"] = crb_t["position_rms_m"] <= crb_l["position_rms_m"]
        out["crb_attitude_better"] = crb_t["attitude_rms_rad"] < crb_l["attitude_rms_rad"]
    return out


def misalignment_study(seeds=range(10), *, duration_h=6.0, step_s=60.0, method="batch",
                       q_m2_s3=1e-12, with_crb=True, progress=None) -> dict:
    """The table's numbers (module docstring): per case, each seed's metrics and their means
    over the seeds, the stars per frame, and the dense Cramér–Rao bound (at seed 0's pass;
    the bound depends on the geometry, not on the noise). ``duration_h``, ``step_s``: the
    pass (``geo-limb`` with raw stars); ``method``: ``batch`` or ``isam2``; ``q_m2_s3``:
    the motion prior's white-acceleration PSD (``--third-body`` motion model)."""
    options = SmootherOptions(q_m2_s3=q_m2_s3, third_body=True,
                              estimate=(ATTITUDE_VARIABLE.name,))
    seeds = [int(s) for s in seeds]
    runs = {c: [] for c in CASES}
    crb = {}
    stars = {}
    for i, seed in enumerate(seeds):
        confocal = simulate_pass(_scenario(duration_h, step_s), seed)
        separate = simulate_pass(_scenario(duration_h, step_s, MOUNTING_SIGMA_ARCSEC), seed)
        few_log = few_stars(confocal.log, seed)
        passes = {"a confocal": (confocal, confocal.log),
                  "b separate, ignored": (separate, separate.log),
                  "c separate, estimated": (separate, separate.log),
                  "tight": (confocal, confocal.log),
                  "loose": (confocal, attitude_rows_from_stars(confocal.log)[0]),
                  "tight, few stars": (confocal, few_log),
                  "loose, few stars": (confocal, attitude_rows_from_stars(few_log)[0])}
        for case in CASES:
            sim, log = passes[case]
            if case == "tight":        # the same run as (a)
                runs[case].append(dict(runs["a confocal"][-1]))
                continue
            opts = dataclasses.replace(options, estimate=_ESTIMATE.get(case, options.estimate))
            p = with_estimates(build_pass(log), opts.estimate)
            if p.layout.has(CAMERA_ALIGNMENT.name):    # its prior: the mounting tolerance
                prior = ((CAMERA_ALIGNMENT.name, MOUNTING_SIGMA_ARCSEC * ARCSEC),)
                opts = dataclasses.replace(opts, prior_sigma=prior)
                p = dataclasses.replace(p, layout=p.layout.with_prior_sigma(*prior[0]))
            sol = solve(p, method, opts)
            runs[case].append({"seed": seed, **_metrics(sol, p, sim, opts.motion_model())})
            if i == 0:
                stars[case] = _stars_per_frame(few_log if "few" in case else sim.log)
                if with_crb and case != "b separate, ignored":
                    crb[case] = joint_crb(p, _truth_block(p, sim), opts)
            if progress is not None:
                progress(f"seed {seed} {case}: {runs[case][-1]['position_rms_m']:.0f} m")
        if i == 0:
            stars["tight"] = stars["a confocal"]
            if "a confocal" in crb:
                crb["tight"] = crb["a confocal"]
    mean = {c: {k: float(np.mean([r[k] for r in runs[c]])) for k in runs[c][0] if k != "seed"}
            for c in CASES}
    tight_vs_loose = {label: _tight_vs_loose(runs[tc], runs[lc], crb.get(tc), crb.get(lc))
                      for label, tc, lc in (("standard", "tight", "loose"),
                                            ("few stars", "tight, few stars", "loose, few stars"))}
    return {"scenario": "geo-limb --raw-stars", "duration_h": duration_h, "step_s": step_s,
            "method": method, "q_m2_s3": q_m2_s3, "seeds": seeds,
            "mounting_sigma_arcsec": MOUNTING_SIGMA_ARCSEC, "few_stars": list(FEW_STARS),
            "stars_per_frame": stars, "mean": mean, "runs": runs, "crb": crb,
            "tight_vs_loose": tight_vs_loose}


def format_misalignment_table(r: dict) -> str:
    """The study as text: one row per case, means over the seeds."""
    arcsec = np.degrees(1.0) * 3600.0
    head = (f"{'case':<24} {'stars/fr':>8} {'pos RMS m':>10} {'CRB m':>8} {'att RMS as':>11} "
            f"{'CRB as':>7} {'NEES 6':>7} {'NEES att':>8} {'ok':>5}")
    lines = [head, "-" * len(head)]
    for c in CASES:
        m, b = r["mean"][c], r["crb"].get(c)
        crb_p = f"{b['position_rms_m']:>8.0f}" if b else f"{'-':>8}"
        crb_a = f"{b['attitude_rms_rad'] * arcsec:>7.2f}" if b else f"{'-':>7}"
        lines.append(f"{c:<24} {r['stars_per_frame'].get(c, float('nan')):>8.1f} "
                     f"{m['position_rms_m']:>10.0f} {crb_p} {m['attitude_rms_rad'] * arcsec:>11.2f} "
                     f"{crb_a} {m['nees']:>7.2f} {m['attitude_nees']:>8.2f} "
                     f"{m['integrity_ok']:>5.0%}")
    tl = r["tight_vs_loose"]
    lines.append("")
    lines.append(
        f"{r['scenario']}, {r['duration_h']:g} h at {r['step_s']:g} s, {r['method']}, "
        f"{len(r['seeds'])} seeds (means); mounting error {r['mounting_sigma_arcsec']:g} arcsec "
        f"1-sigma per axis; few stars: {r['few_stars'][0]}-{r['few_stars'][1]} of each frame's stars. NEES 6: orbit state "
        f"(6 expected), NEES att: attitude (3 expected); ok: share of the seeds whose integrity "
        f"verdict is ok. CRB: dense joint bound at the truth.")
    for k, v in tl.items():
        lines.append(
            f"tight - loose, {k}: position {v['position_diff_mean_m']:+.0f} m "
            f"(+/- {v['position_diff_se_m']:.0f} m, tight worse in {len(v['seeds_tight_worse'])} "
            f"of {len(r['seeds'])} seeds), attitude {v['attitude_rms_tight_rad'] * arcsec:.1f} vs "
            f"{v['attitude_rms_loose_rad'] * arcsec:.1f} arcsec; not worse on position "
            f"{v['position_not_worse']}, better on attitude {v['attitude_better']}"
            + (f"; bounds: position not worse {v['crb_position_not_worse']}, attitude better "
               f"{v['crb_attitude_better']}" if "crb_position_not_worse" in v else ""))
    return "\n".join(lines)
