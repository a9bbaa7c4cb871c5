"""Reports: each study's table (``table.csv``, ``table.md``) and plot (``plot.png``) from its
finished runs, beside the bounds and reference figures the study file gives in ``[reference]``.

A report declares a reference dataclass: the keys of the study's ``[reference]`` table
(validated by :func:`fgnav.campaign.spec.typed_object`). Where the figures are only shown
beside ours (``seed002-noise``, ``seed002-period``, ``observability``, ``seed000-table5``)
the table is optional and its columns are empty without it; ``nees`` and ``visibility``
compute their bands from it and require it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping

from fgnav.analysis.visibility import SEED_RING_DEG, limb_half_angle_rad, visibility_band_m
from fgnav.campaign.storage import RunsTable, csv_line, format_cell, safe_name
from fgnav.campaign.tasks import positive
from fgnav.constants import DEG
from fgnav.diagnostics.consistency import anees, nees_curve
from fgnav.errors import UserError
from fgnav.io.atomic import atomic_write_text, atomic_writer

__all__ = ["Report", "REPORTS", "write_study_report", "NoiseReference", "PeriodReference",
           "ObservabilityReference", "VisibilityReference", "Table5Reference", "NeesReference"]


# ---- reference figures (the [reference] table of a study) -----------------------------

@dataclass(frozen=True)
class NoiseReference:
    """A bound on the final errors: noise <= ``max_sigma_deg`` (deg, 1-sigma per axis) keeps
    the final position error below ``final_position_km`` (km) and the final velocity error
    below ``final_velocity_mps`` (m/s)."""
    max_sigma_deg: float = positive()
    final_position_km: float = positive()
    final_velocity_mps: float = positive()


@dataclass(frozen=True)
class PeriodReference:
    """What the source says of the sample period (text shown in the ``seed_value`` column)."""
    seed_value: str


@dataclass(frozen=True)
class ObservabilityReference:
    """The rank of the observability matrix the source reports at every sample period."""
    rank: int = positive()


@dataclass(frozen=True)
class VisibilityReference:
    """The altitude band (km) the source gives for the ring, and the Earth radii (km) at which
    ours is evaluated (one band row each; the first also draws the plot)."""
    band_km: tuple[float, float] = positive()
    earth_radii_km: tuple[float, ...] = positive()

    def problem(self):
        if not self.band_km[0] < self.band_km[1]:
            return "band_km", "an increasing pair [low, high]", list(self.band_km)
        return None


@dataclass(frozen=True)
class Table5Reference:
    """The source's direct positioning errors (km): ``seed_km`` maps an altitude (km) to one
    figure per angle error of ``angle_errors_deg`` (deg)."""
    angle_errors_deg: tuple[float, ...] = positive()
    seed_km: Mapping[float, tuple[float, ...]] = positive()

    def problem(self):
        n = len(self.angle_errors_deg)
        for alt, v in self.seed_km.items():
            if len(v) != n:
                return f"seed_km.{alt:g}", f"{n} figures (one per angle_errors_deg)", list(v)
        return None

    def figure(self, alt_km: float, angle_error_deg: float) -> float | None:
        row = self.seed_km.get(float(alt_km))
        for j, a in enumerate(self.angle_errors_deg):
            if row is not None and abs(a - angle_error_deg) < 1e-12:
                return row[j]
        return None


@dataclass(frozen=True)
class NeesReference:
    """The consistency test: two-sided chi-square band of probability ``1 - alpha``."""
    alpha: float = positive()

    def problem(self):
        if not self.alpha < 1.0:
            return "alpha", "a probability 0 < alpha < 1", self.alpha
        return None


# ---- table and plot helpers -------------------------------------------------------------

def _group(rows, keys):
    groups: dict[tuple, list] = {}
    for r in rows:
        groups.setdefault(tuple(r.get(k) for k in keys), []).append(r)
    return groups


def _mean(rows, key):
    import numpy as np

    v = np.array([r[key] for r in rows if isinstance(r.get(key), (int, float))], float)
    return float(np.mean(v)) if len(v) else float("nan")


def _write_table(out: Path, rows: list[dict], title: str, notes: list[str]) -> list[Path]:
    cols = list(rows[0]) if rows else []
    text = csv_line(cols) + "".join(csv_line([format_cell(r.get(c)) for c in cols]) for r in rows)
    atomic_write_text(out / "table.csv", text)

    def md(v):
        if isinstance(v, float):
            return "" if v != v else (f"{v:.4g}" if abs(v) < 1e5 else f"{v:.3e}")
        return "" if v is None else str(v)

    lines = [f"# {title}", ""] + [f"{n}" for n in notes] + [""]
    lines.append("| " + " | ".join(cols) + " |")
    lines.append("|" + "---|" * len(cols))
    lines += ["| " + " | ".join(md(r.get(c)) for c in cols) + " |" for r in rows]
    atomic_write_text(out / "table.md", "\n".join(lines) + "\n")
    return [out / "table.csv", out / "table.md"]


def _save_plot(fig, path: Path) -> Path:
    with atomic_writer(path, "wb") as f:
        fig.savefig(f, format="png", dpi=110, bbox_inches="tight")
    import matplotlib.pyplot as plt
    plt.close(fig)
    return path


def _figure(ncols=1):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, ncols, figsize=(6.5 * ncols, 4.5))
    return fig, ax


NO_REFERENCE = "No reference figures: the study file has no [reference] table, so the reference columns are empty."


def _notes(study, *lines: str) -> list[str]:
    """The notes above a table: the study, ``lines``, and whether reference figures were given."""
    return [f"Study `{study.name}`: {study.description}", *lines] + ([NO_REFERENCE] if study.reference is None else [])


def _navigate_table(rows, xkey, seed_cols):
    out = []
    for (x, method), g in sorted(_group(rows, (xkey, "method")).items(), key=lambda kv: (kv[0][0], str(kv[0][1]))):
        r = {xkey: x, "method": method, "runs": len(g),
             "final_position_km": _mean(g, "final_position_error_m") / 1e3,
             "final_velocity_mps": _mean(g, "final_velocity_error_mps"),
             "position_rms_km": _mean(g, "position_rms_m") / 1e3,
             "velocity_rms_mps": _mean(g, "velocity_rms_mps"),
             "sigma_final_position_km": _mean(g, "sigma_final_position_m") / 1e3,
             "nees_mean": _mean(g, "nees_mean"), "solve_s": _mean(g, "solve_s")}
        r.update(seed_cols(x, r))
        out.append(r)
    return out


def _plot_navigate(table, xkey, xlabel, title, path, hline=None):
    fig, axes = _figure(2)
    for method in sorted({r["method"] for r in table}):
        t = [r for r in table if r["method"] == method]
        axes[0].loglog([r[xkey] for r in t], [r["final_position_km"] for r in t], "o-", label=f"{method} final")
        axes[0].loglog([r[xkey] for r in t], [r["position_rms_km"] for r in t], "s--", label=f"{method} RMS")
        axes[1].loglog([r[xkey] for r in t], [r["final_velocity_mps"] for r in t], "o-", label=f"{method} final")
        axes[1].loglog([r[xkey] for r in t], [r["velocity_rms_mps"] for r in t], "s--", label=f"{method} RMS")
    if hline:
        axes[0].axhline(hline[0], color="k", lw=0.8, ls=":", label="Pan & Yao 2017 bound")
        axes[1].axhline(hline[1], color="k", lw=0.8, ls=":", label="Pan & Yao 2017 bound")
    axes[0].set(xlabel=xlabel, ylabel="position error (km)", title=title)
    axes[1].set(xlabel=xlabel, ylabel="velocity error (m/s)")
    for a in axes:
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=8)
    return _save_plot(fig, path)


# ---- the reports ----------------------------------------------------------------------

def report_noise(study, rows, out):
    """Direction noise vs navigation error, with the bound of :class:`NoiseReference`."""
    ref: NoiseReference | None = study.reference

    def seed_cols(sigma, r):
        if ref is not None and sigma <= ref.max_sigma_deg + 1e-12:
            return {"seed_position_bound_km": ref.final_position_km, "seed_velocity_bound_mps": ref.final_velocity_mps,
                    "meets_seed_bound": bool(r["final_position_km"] < ref.final_position_km
                                             and r["final_velocity_mps"] < ref.final_velocity_mps)}
        return {"seed_position_bound_km": None, "seed_velocity_bound_mps": None, "meets_seed_bound": None}

    table = _navigate_table(rows, "sigma_deg", seed_cols)
    bound = ("." if ref is None else
             f"; Pan & Yao 2017 state that noise <= {ref.max_sigma_deg:g} deg keeps errors "
             f"< {ref.final_position_km:g} km and < {ref.final_velocity_mps:g} m/s (bound columns).")
    notes = _notes(study, "Pan & Yao 2017, table 2 (final errors after 4 h): its numbers are not in the source "
                   "text" + bound,
                   f"Fixed parameters: {dict(study.fixed)}; random seeds {list(study.seeds)}. Errors are means "
                   "over the random seeds.")
    files = _write_table(out, table, "Pan & Yao 2017, table 2: direction noise vs navigation error", notes)
    files.append(_plot_navigate(table, "sigma_deg", "direction noise 1-sigma (deg)", "Pan & Yao 2017, table 2",
                                out / "plot.png",
                                hline=None if ref is None else (ref.final_position_km, ref.final_velocity_mps)))
    return files


def report_period(study, rows, out):
    """Sample period vs navigation error, beside :class:`PeriodReference`'s statement."""
    ref: PeriodReference | None = study.reference
    table = _navigate_table(rows, "step_s", lambda x, r: {"seed_value": None if ref is None else ref.seed_value})
    notes = _notes(study, "Pan & Yao 2017, table 3 (sample period 0.1/1/10/100 s, 500 m / 0.05 m/s initial error, "
                   "0.01 deg); seed_value: what they state.",
                   f"Fixed parameters: {dict(study.fixed)}; random seeds {list(study.seeds)}. Errors are means over "
                   "the random seeds.")
    files = _write_table(out, table, "Pan & Yao 2017, table 3: sample period vs navigation error", notes)
    files.append(_plot_navigate(table, "step_s", "sample period (s)", "Pan & Yao 2017, table 3", out / "plot.png"))
    return files


def report_observability(study, rows, out):
    """Rank and condition numbers vs sample period, beside :class:`ObservabilityReference`."""
    ref: ObservabilityReference | None = study.reference
    table = []
    for r in sorted(rows, key=lambda r: r["step_s"]):
        table.append({"step_s": r["step_s"], "rank": r["rank"], "seed_rank": None if ref is None else ref.rank,
                      "condition_raw": r["condition_raw"], "condition_scaled": r["condition_scaled"],
                      "seed_condition": None,
                      "window_h": r["window_h"], "window_info_condition": r["window_info_condition"],
                      "weakest_sigma_m": r["weakest_sigma_m"], "weakest_direction": r["weakest_direction"]})
    rank = "" if ref is None else f"rank {ref.rank} at every period and "
    notes = _notes(study, f"Pan & Yao 2017, table 4: {rank}a condition number growing with the period "
                   "(seed_rank: theirs; their condition numbers are not in the source text, so seed_condition is "
                   "empty). condition_raw/scaled: their eq. 9 with 6 blocks (window 5 T) at their initial state; "
                   "window_info_*: information of the initial state from all samples over a fixed window (1-sigma "
                   "of the weakest direction, velocity x 1000 s).")
    files = _write_table(out, table, "Pan & Yao 2017, table 4: observability vs sample period", notes)
    fig, axes = _figure(2)
    T = [r["step_s"] for r in table]
    axes[0].loglog(T, [r["condition_raw"] for r in table], "o-", label="cond(M), SI units")
    axes[0].loglog(T, [r["condition_scaled"] for r in table], "s-", label="cond(M), columns scaled")
    axes[0].loglog(T, [r["window_info_condition"] for r in table], "^-", label="cond(J), fixed window")
    axes[0].set(xlabel="sample period (s)", ylabel="condition number", title="Pan & Yao 2017, table 4")
    axes[1].loglog(T, [r["weakest_sigma_m"] for r in table], "o-")
    axes[1].set(xlabel="sample period (s)", ylabel="weakest direction 1-sigma (m)",
                title=f"information over {table[0]['window_h'] if table else ''} h")
    for a in axes:
        a.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    files.append(_save_plot(fig, out / "plot.png"))
    return files


def report_visibility(study, rows, out):
    """The ring's visibility band (eq. 1 of the limb-ring study) at the radii of
    :class:`VisibilityReference` beside its ``band_km``, then the passes' rows."""
    import numpy as np

    ref: VisibilityReference = study.reference
    ring = tuple(study.fixed.get("ring_deg") or SEED_RING_DEG)
    bands = [(r_km, *visibility_band_m(ring, r_earth_m=r_km * 1e3)) for r_km in ref.earth_radii_km]
    table = [{"orbit": f"band (R = {r_km:g} km)", "band_min_km": lo / 1e3, "band_max_km": hi / 1e3,
              "seed_band_min_km": ref.band_km[0], "seed_band_max_km": ref.band_km[1]} for r_km, lo, hi in bands]
    for (orbit, method), g in _group(rows, ("orbit", "method")).items():
        t = {"orbit": orbit, "method": method, "runs": len(g)}
        for k in ("perigee_alt_km", "apogee_alt_km", "visible_fraction", "max_gap_min",
                  "position_rms_all_m", "final_position_all_m", "position_rms_ring_m", "final_position_ring_m"):
            t[k] = _mean(g, k)
        t["ring_status"] = g[0].get("ring_status")
        table.append(t)
    cols = []
    for r in table:
        cols += [k for k in r if k not in cols]
    table = [{c: r.get(c) for c in cols} for r in table]
    notes = _notes(study, f"Pan & Yao 2017, eq. 1: a {ring[0]:g}-{ring[1]:g} deg limb ring sees the whole Earth for "
                   f"R/sin({ring[1] / 2:g} deg) - R <= h <= R/sin({ring[0] / 2:g} deg) - R (seed_band_*: their "
                   "band). Rows after the bands: "
                   "passes navigated with the ring's direction + limb radius at every epoch (all) vs only when the "
                   "limb is inside the ring.")
    files = _write_table(out, table, "Pan & Yao 2017: limb-ring visibility bound", notes)
    r0_km, lo, hi = bands[0]
    fig, ax = _figure(1)
    h = np.linspace(50e3, 40000e3, 600)
    ax.semilogx(h / 1e3, 2 * limb_half_angle_rad(r0_km * 1e3 + h, r0_km * 1e3) / DEG, label="Earth apparent diameter")
    ax.axhspan(ring[0], ring[1], color="g", alpha=0.2, label=f"ring {ring[0]:g}-{ring[1]:g} deg")
    ax.axvspan(lo / 1e3, hi / 1e3, color="b", alpha=0.1, label=f"band {lo/1e3:.1f}-{hi/1e3:.1f} km")
    ax.set(xlabel="altitude (km)", ylabel="apparent diameter (deg)", title="Pan & Yao 2017, visibility bound")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    files.append(_save_plot(fig, out / "plot.png"))
    return files


TABLE5_COLUMNS = ("alt_km", "angle_error_deg", "seed_km", "ours_direction_km", "ours_with_rho_km", "ours_mc_km",
                  "lower_bound_km", "seed_over_bound")


def report_table5(study, rows, out):
    """Direct positioning error vs altitude and angle error; ``seed_km`` from
    :class:`Table5Reference` and ``seed_over_bound`` = seed_km / lower_bound_km."""
    ref: Table5Reference | None = study.reference
    table = []
    for r in rows:
        t = {k: r.get(k) for k in TABLE5_COLUMNS}
        seed = None if ref is None else ref.figure(t["alt_km"], t["angle_error_deg"])
        t["seed_km"] = seed
        t["seed_over_bound"] = None if seed is None else float(seed / t["lower_bound_km"])
        table.append(t)
    table.sort(key=lambda r: (r["alt_km"], r["angle_error_deg"]))
    notes = _notes(study, "Wu et al., table 5 via fgnav.analysis.limb_method_study.table5 (definitions in its "
                   "docstring); seed_km: their figures; ours_mc_km: Monte Carlo of r = -(R/sin rho) u with the "
                   "same errors (2000 draws).")
    files = _write_table(out, table, "Wu et al., table 5: direct positioning error", notes)
    fig, ax = _figure(1)
    for alt in sorted({r["alt_km"] for r in table}):
        t = [r for r in table if r["alt_km"] == alt]
        line, = ax.plot([r["angle_error_deg"] for r in t], [r["ours_with_rho_km"] for r in t], "o-",
                        label=f"{alt:g} km ours")
        s = [r for r in t if r["seed_km"] is not None]
        ax.plot([r["angle_error_deg"] for r in s], [r["seed_km"] for r in s], "x:", color=line.get_color())
    ax.set(xlabel="angle error (deg)", ylabel="direct positioning error (km)",
           title="Wu et al., table 5 (x: their figures)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    files.append(_save_plot(fig, out / "plot.png"))
    return files


STATE_DOF = 6
"""NEES degrees of freedom: the 6-D orbit state (position, velocity)."""


def report_nees(study, rows, out):
    """ANEES over runs at the final and middle epochs and per epoch, with the two-sided
    chi-square band of :class:`NeesReference` (Bar-Shalom, Li, Kirubarajan, "Estimation with
    Applications to Tracking and Navigation", 2001, ch. 5.4)."""
    import numpy as np

    ref: NeesReference = study.reference
    table, curves, curve_t_s = [], {}, {}
    for method, g in sorted(_group(rows, ("method",)).items()):
        method = method[0]
        a_final = anees([r["nees_final"] for r in g], STATE_DOF, ref.alpha)
        r = {"method": method, "runs": len(g), "anees_final": a_final.anees,
             "band_lo": a_final.lo, "band_hi": a_final.hi, "inside_final": a_final.inside,
             "anees_over_dof": a_final.ratio}
        arrs, times = [], []
        for rr in g:
            f = out / "curves" / f"{safe_name(rr['run_id'])}.npz"
            if f.exists():
                with np.load(f) as z:
                    arrs.append(z["nees"])
                    times.append(z["t_s"] if "t_s" in z.files else None)
        if arrs and len({len(a) for a in arrs}) == 1:
            curve, lo, hi, frac = nees_curve(np.array(arrs), STATE_DOF, ref.alpha)
            curves[method] = (curve, lo, hi, len(arrs))
            if times[0] is not None and len(times[0]) == len(curve):
                curve_t_s[method] = np.asarray(times[0], float)
            mid = anees(np.array(arrs)[:, len(curve) // 2], STATE_DOF, ref.alpha)
            r.update(anees_mid=mid.anees, inside_mid=mid.inside, epochs_inside_band=frac,
                     anees_time_mean=float(curve.mean()))
        r.update(nis_per_dof=_mean(g, "nis_per_dof"), position_rms_m=_mean(g, "position_rms_m"),
                 seed_value=None)
        table.append(r)
    pct = f"{(1.0 - ref.alpha) * 100:g}%"
    notes = _notes(study, "NEES of the 6-D state against truth (independent DOP853); ANEES over runs at the final and "
                   f"middle epochs with the two-sided {pct} chi-square band chi2(6R)/R; epochs_inside_band: "
                   f"fraction of epochs whose ANEES lies in that band (about {1.0 - ref.alpha:g} if consistent; "
                   "epochs of one run are correlated). EKF rows are the filtered (causal) estimates. seed_value is "
                   "empty: the source studies give no consistency test.")
    files = _write_table(out, table, "NEES / ANEES consistency", notes)
    files.append(_save_plot(_plot_anees(study.name, rows, curves, curve_t_s, pct), out / "plot.png"))
    return files


#: How each method's ANEES curve is drawn so that none hides another where they coincide
#: (a batch smoother and iSAM2 after its last epoch give the same ANEES): line style, marker,
#: line width, drawing order (higher on top).
_METHOD_STYLE = {"batch": ("-", None, 2.6, 1), "isam2": ("--", "o", 1.3, 2),
                 "fixed-lag": (":", "s", 1.3, 3), "ekf": ("-", None, 1.0, 4)}


def _plot_anees(name, rows, curves, curve_t_s, pct):
    """ANEES per epoch and method against time (h) when the curves carry their times (epoch
    index otherwise), with the band of ``pct``; the title states runs = seeds x methods."""
    import numpy as np

    fig, ax = _figure(1)
    lo = hi = None
    in_hours = bool(curves) and all(m in curve_t_s for m in curves)
    for method, (curve, lo, hi, n_runs) in curves.items():
        ls, marker, lw, z = _METHOD_STYLE.get(method, ("-", None, 1.2, 5))
        x = curve_t_s[method] / 3600.0 if in_hours else np.arange(len(curve))
        ax.semilogy(x, curve, ls=ls, marker=marker, markevery=max(1, len(curve) // 25), ms=4,
                    lw=lw, zorder=z, label=f"{method} ANEES ({n_runs} runs)")
    if curves:
        ax.axhspan(lo, hi, color="g", alpha=0.2, label=f"{pct} band")
    ax.axhline(float(STATE_DOF), color="k", lw=0.8)
    methods = sorted({str(r.get("method")) for r in rows})
    seeds = len({r.get("seed", r.get("run_id")) for r in rows})
    runs = (f"{seeds} runs x {len(methods)} methods ({', '.join(methods)})"
            if len(rows) == seeds * len(methods) else f"{len(rows)} runs ({', '.join(methods)})")
    ax.set(xlabel="time since the first epoch (h)" if in_hours else "epoch index",
           ylabel=f"ANEES (dof {STATE_DOF})", title=f"{name}: {runs}")
    from matplotlib.ticker import LogLocator, ScalarFormatter

    ax.yaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
    ax.yaxis.set_major_formatter(ScalarFormatter())
    ax.yaxis.set_minor_formatter("")
    ax.grid(True, which="both", alpha=0.3)
    if curves:  # no curves saved (save_curves = false): nothing to label
        ax.legend(fontsize=8)
    return fig


# ---- the registry ---------------------------------------------------------------------

@dataclass(frozen=True)
class Report:
    """How a study's runs are summarized: the tasks whose rows it reads, its reference
    dataclass (``[reference]`` keys; ``None``: takes none) and whether the table is required."""
    name: str
    tasks: tuple[str, ...]
    write: Callable
    reference: type | None
    reference_required: bool


REPORTS = {r.name: r for r in (
    Report("seed002-noise", ("navigate",), report_noise, NoiseReference, False),
    Report("seed002-period", ("navigate",), report_period, PeriodReference, False),
    Report("observability", ("observability",), report_observability, ObservabilityReference, False),
    Report("visibility", ("visibility",), report_visibility, VisibilityReference, True),
    Report("seed000-table5", ("seed000-table5",), report_table5, Table5Reference, False),
    Report("nees", ("navigate",), report_nees, NeesReference, True),
)}


def write_study_report(study, out_dir, run_ids) -> list[Path]:
    """Write table.csv, table.md and plot.png of a finished campaign; return the paths.

    The rows are taken in the study's run order ``run_ids`` (:func:`fgnav.campaign.spec.study_runs`),
    not in the order the runs finished, so a resumed or parallel campaign reports the same
    numbers (means summed in the same order)."""
    out = Path(out_dir)
    rows = [r for r in RunsTable(out / "runs.csv", study.columns()).read() if r["status"] == "ok"]
    if not rows:
        raise UserError(f"{out}: no finished runs to report")
    order = {run_id: i for i, run_id in enumerate(run_ids)}
    rows.sort(key=lambda r: order.get(r["run_id"], len(order)))
    return REPORTS[study.report].write(study, rows, out)
