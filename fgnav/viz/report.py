"""Report of a result directory: PNG plots (matplotlib, Agg) plus ``report.md`` and
``report.html`` with the metrics table of ``summary.json``.

A result directory (written by ``fgnav smooth LOG --out DIR``) holds ``trajectory.oem``,
``summary.json``, ``residuals.csv`` (``t_s,kind,component,whitened``), optionally
``online.oem`` (with each epoch's online covariance) and ``latency.csv``
(``t_s,latency_s``), and with an estimated attitude ``attitude.aem`` and
``attitude_covariance.csv``. The truth OEM is found through ``summary.json``'s
``truth_path`` (or given explicitly); the true attitude, where there is one, is the file
``truth_attitude.csv`` beside it (:data:`fgnav.io.truth_params.TRUTH_ATTITUDE_CSV`).

Plots (time in hours since ``epoch0``, errors in m and m/s). What ``trajectory.oem`` holds
depends on the method, and the plots say so (:func:`estimate_label`): the *smoothed*
solution of batch and iSAM2 (after the last epoch), the *fixed-lag smoothed* one, or the
EKF's *filtered* states.

* ``errors_rtn.png`` — position and velocity error (estimate − truth) in RTN with the ±kσ
  envelope of that estimate's own covariance; without truth ``sigma_rtn.png``, the ±kσ
  envelope;
* ``online_errors_rtn.png`` (``online_sigma_rtn.png`` without truth) — for iSAM2 and the
  fixed-lag smoother, each epoch's *online* estimate (as it was when that epoch arrived)
  against the online covariance of the same moment, not against the smoothed one;
* ``residuals_time.png`` — whitened residuals against time per kind, the long gaps of the
  log shaded;
* ``residuals_hist.png`` — whitened-residual histogram per kind against N(0, 1); kinds with
  fewer than :data:`MIN_HISTOGRAM_SAMPLES` values (the priors) are drawn value by value;
* ``attitude_errors.png`` (``attitude_sigma.png`` without a true attitude) — the attitude
  error ``Log(R_true^T R_est)`` about the body axes with the ±kσ of
  ``attitude_covariance.csv``;
* ``orbit_3d.png`` — estimated (and true) orbit in ECI, km, with the Earth;
* ``latency.png`` — per-epoch update latency of incremental methods and the EKF.

Several spacecraft (:func:`report_formation_dir`; ``trajectory-<id>.oem`` per spacecraft,
``relative.csv`` of every pair, :mod:`fgnav.results`; the truth each spacecraft's
``truth-<id>.oem`` in the directory given by ``--truth`` or ``summary.json``'s ``truth_path``):

* ``errors_rtn-<id>.png`` (``sigma_rtn-<id>.png`` without truth) per spacecraft, as above;
* ``relative_lvlh-<pair>.png`` per pair (``<pair>`` the deputy's id for the pairs with the
  reference, ``<chief>-<deputy>`` for the others): the deputy's relative position and
  velocity in the chief's LVLH frame (x radial, y along-track, z normal; m, m/s), the truth
  dashed;
* ``relative_errors_lvlh-<pair>.png`` (``relative_sigma_lvlh-<pair>.png`` without truth):
  the relative state's error with the ±kσ of the relative covariance (the joint solution's
  cross-covariances included);
* ``residuals_time.png``, ``residuals_hist.png`` (links included), ``orbit_3d.png`` (every
  spacecraft's orbit its own curve) and ``report.md``/``report.html`` with each spacecraft's
  and every pair's figures.
"""

from __future__ import annotations

import csv
import html
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from factors.constants import R_EARTH_M
from fgnav.errors import InputFormatError, UserError
from fgnav.io.aem import read_aem
from fgnav.io.atomic import atomic_write_text, atomic_writer
from fgnav.io.attitude_covariance import read_attitude_covariance
from fgnav.io.oem import read_oem
from fgnav.io.outputs import commit_outputs
from fgnav.io.summary import read_summary
from fgnav.frames import relative_state_lvlh
from fgnav.results import truth_path_of
from fgnav.time import format_utc
from fgnav.viz.rerun_log import (ESTIMATE_LABELS, attitude_error_body, error_and_sigma,  # noqa: F401
                                 estimate_label, read_truth_attitude)

RTN_NAMES = ("R (radial)", "T (along-track)", "N (cross-track)")
BODY_AXES = ("x", "y", "z")
_H = 1.0 / 3600.0
_ARCSEC = np.pi / (180.0 * 3600.0)

#: Below this many whitened values a kind gets a strip of its values, not a histogram.
MIN_HISTOGRAM_SAMPLES = 30

#: Long gaps: steps longer than this many times the median step (as ``fgnav smooth`` plans
#: them, :func:`fgnav.measurements.long_gaps`), when ``summary.json`` does not list them.
GAP_FACTOR = 10.0

#: Preferred order of the metrics table; other scalar keys follow alphabetically.
METRIC_ORDER = ("method", "epochs", "duration_s", "iterations", "chi2", "wall_s",
                "position_rms_m", "velocity_rms_mps", "crb_position_rms_m", "nees_mean",
                "final_position_error_m", "final_velocity_error_mps")


@dataclass
class ResultData:
    """Everything a report needs, SI units, ECI (``t_s`` from ``epoch0``)."""

    summary: dict
    epoch0: np.datetime64
    t_s: np.ndarray
    x_eci: np.ndarray
    P_eci: np.ndarray | None
    truth_x_eci: np.ndarray | None = None
    online_x_eci: np.ndarray | None = None
    residuals: dict[str, np.ndarray] = field(default_factory=dict)   # kind -> (M,) whitened
    latency_t_s: np.ndarray | None = None
    latency_s: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)
    online_P_eci: np.ndarray | None = None                    # (N, 6, 6) online covariance
    residual_t_s: dict[str, np.ndarray] = field(default_factory=dict)  # kind -> (M,) s
    residual_component: dict[str, np.ndarray] = field(default_factory=dict)  # kind -> (M,)
    gaps: list[tuple[float, float]] | None = None             # (t_start_s, length_s) each
    attitude_t_s: np.ndarray | None = None                    # (K,) s from epoch0
    attitude_R: np.ndarray | None = None                      # (K, 3, 3) R_eci_from_body
    attitude_P: np.ndarray | None = None                      # (K, 3, 3) rad^2, body frame
    truth_attitude_R: np.ndarray | None = None                # (K, 3, 3) at attitude_t_s

    @property
    def method(self) -> str:
        return str(self.summary.get("method", "?"))


# --------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------
def read_residuals_table(path) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``residuals.csv`` (``t_s,kind,component,whitened``) -> ``kind -> (t_s (M,),
    component (M,), whitened (M,))`` in file order."""
    out: dict[str, list[tuple[float, int, float]]] = {}
    with open(path, encoding="utf-8", newline="") as f:
        rows = csv.reader(f)
        header = next(rows, None)
        if header is None or [h.strip() for h in header] != ["t_s", "kind", "component", "whitened"]:
            raise InputFormatError(path, 1, None, "header 't_s,kind,component,whitened'",
                                   ",".join(header or []))
        for lineno, row in enumerate(rows, start=2):
            if not row or (len(row) == 1 and not row[0].strip()):
                continue
            if len(row) != 4:
                raise InputFormatError(path, lineno, None, "4 fields", f"{len(row)} fields")
            vals = []
            for col, i, conv in (("t_s", 0, float), ("component", 2, int), ("whitened", 3, float)):
                try:
                    vals.append(conv(row[i]))
                except ValueError:
                    what = "an integer" if conv is int else "a number"
                    raise InputFormatError(path, lineno, col, what, row[i]) from None
            out.setdefault(row[1].strip(), []).append(tuple(vals))
    return {k: (np.array([r[0] for r in v], float), np.array([r[1] for r in v], int),
                np.array([r[2] for r in v], float)) for k, v in out.items()}


def read_residuals_csv(path) -> dict[str, np.ndarray]:
    """``residuals.csv`` (``t_s,kind,component,whitened``) -> ``kind -> whitened (M,)``."""
    return {k: w for k, (_, _, w) in read_residuals_table(path).items()}


def read_latency_csv(path) -> tuple[np.ndarray, np.ndarray]:
    """``latency.csv`` (``t_s,latency_s``) -> ``(t_s, latency_s)``."""
    with open(path, encoding="utf-8") as f:
        header = f.readline().strip()
    if [h.strip() for h in header.split(",")] != ["t_s", "latency_s"]:
        raise InputFormatError(path, 1, None, "header 't_s,latency_s'", header)
    try:
        a = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except ValueError as exc:
        raise InputFormatError(path, None, None, "two numeric columns", str(exc)) from None
    if a.size == 0:
        return np.zeros(0), np.zeros(0)
    return a[:, 0], a[:, 1]


def states_at(t_query_s, t_s, x_eci) -> np.ndarray:
    """States (M, 6) at ``t_query_s`` from a tabulated trajectory ``(t_s, x_eci)``.

    Exact where the epochs coincide (|dt| < 1 µs); elsewhere cubic Hermite interpolation of
    position with the velocity as derivative, and a cubic spline of velocity. NaN outside
    the table.
    """
    from scipy.interpolate import CubicHermiteSpline
    from scipy.interpolate import CubicSpline

    t_s = np.asarray(t_s, float)
    x_eci = np.asarray(x_eci, float)
    tq = np.asarray(t_query_s, float)
    out = np.full((len(tq), 6), np.nan)
    j = np.clip(np.searchsorted(t_s, tq), 0, len(t_s) - 1)
    jm = np.clip(j - 1, 0, len(t_s) - 1)
    jn = np.where(np.abs(t_s[jm] - tq) < np.abs(t_s[j] - tq), jm, j)
    exact = np.abs(t_s[jn] - tq) < 1e-6
    out[exact] = x_eci[jn[exact]]
    rest = ~exact & (tq >= t_s[0]) & (tq <= t_s[-1])
    if np.any(rest) and len(t_s) >= 2:
        out[rest, :3] = CubicHermiteSpline(t_s, x_eci[:, :3], x_eci[:, 3:], axis=0)(tq[rest])
        out[rest, 3:] = CubicSpline(t_s, x_eci[:, 3:], axis=0)(tq[rest])
    return out


def residual_gaps(residual_t_s: dict, gap_factor: float = GAP_FACTOR) -> list[tuple[float, float]]:
    """Long gaps ``(t_start_s, length_s)`` of the epochs with residuals: steps longer than
    ``gap_factor`` times their median step (for results whose summary lists none)."""
    ts = [np.asarray(t, float) for t in residual_t_s.values() if len(t)]
    if not ts:
        return []
    t = np.unique(np.concatenate(ts))
    if len(t) < 3:
        return []
    dt = np.diff(t)
    step = float(np.median(dt))
    if step <= 0:
        return []
    return [(float(t[i]), float(dt[i])) for i in np.flatnonzero(dt > gap_factor * step)]


def _find_truth(result_dir: Path, truth_path) -> Path | None:
    p = Path(truth_path)
    for cand in (p, result_dir / p, result_dir / p.name):
        if cand.is_file():
            return cand
    return None


def load_result(result_dir, truth_path=None) -> ResultData:
    """Read a result directory (see module doc). ``truth_path`` overrides the summary's."""
    d = Path(result_dir)
    if not d.is_dir():
        raise UserError(f"{d}: not a result directory")
    for name in ("summary.json", "trajectory.oem"):
        if not (d / name).is_file():
            raise UserError(f"{d}: missing {name} (expected the output of `fgnav smooth --out`)")
    summary = read_summary(d / "summary.json")
    est = read_oem(d / "trajectory.oem")
    t_s = np.asarray(est.t_s, float)
    data = ResultData(summary=summary, epoch0=np.datetime64(est.epoch0, "ns"), t_s=t_s,
                      x_eci=np.asarray(est.x_eci, float),
                      P_eci=None if est.P_eci is None else np.asarray(est.P_eci, float))

    tp = truth_path if truth_path is not None else summary.get("truth_path")
    found = None
    if tp:
        found = _find_truth(d, tp)
        if found is None:
            data.notes.append(f"truth file {tp} not found: plotted without truth")
        else:
            tru = read_oem(found)
            data.truth_x_eci = states_at(t_s, np.asarray(tru.t_s, float) + _shift_s(tru.epoch0, data.epoch0),
                                         tru.x_eci)
            if np.any(np.isnan(data.truth_x_eci)):
                data.notes.append("truth does not cover every estimated epoch (gaps left blank)")
    if (d / "online.oem").is_file():
        onl = read_oem(d / "online.oem")
        shift = _shift_s(onl.epoch0, data.epoch0)
        data.online_x_eci = states_at(t_s, np.asarray(onl.t_s, float) + shift, onl.x_eci)
        if onl.P_eci is not None and len(onl.t_s) == len(t_s) and \
                np.allclose(np.asarray(onl.t_s, float) + shift, t_s, atol=1e-6):
            data.online_P_eci = np.asarray(onl.P_eci, float)
    if (d / "residuals.csv").is_file():
        table = read_residuals_table(d / "residuals.csv")
        data.residuals = {k: w for k, (_, _, w) in table.items()}
        data.residual_t_s = {k: t for k, (t, _, _) in table.items()}
        data.residual_component = {k: c for k, (_, c, _) in table.items()}
    if isinstance(summary.get("gaps"), list):
        data.gaps = [(float(g["t_start_s"]), float(g["length_s"])) for g in summary["gaps"]
                     if isinstance(g, dict) and "t_start_s" in g and "length_s" in g]
    if (d / "latency.csv").is_file():
        data.latency_t_s, data.latency_s = read_latency_csv(d / "latency.csv")
    if (d / "attitude.aem").is_file():
        _load_attitude(d, data, found)
    return data


def _shift_s(epoch0, ref_epoch0) -> float:
    """Seconds from ``ref_epoch0`` to ``epoch0``."""
    return float((np.datetime64(epoch0, "ns") - np.datetime64(ref_epoch0, "ns"))
                 / np.timedelta64(1, "ns")) * 1e-9


def _load_attitude(d: Path, data: ResultData, truth_oem: Path | None) -> None:
    """``attitude.aem``, ``attitude_covariance.csv`` and, beside the truth OEM,
    ``truth_attitude.csv`` (:func:`fgnav.viz.rerun_log.read_truth_attitude`) into ``data``."""

    aem = read_aem(d / "attitude.aem")
    data.attitude_t_s = np.asarray(aem.t_s, float) + _shift_s(aem.epoch0, data.epoch0)
    data.attitude_R = aem.R_eci_from_body()
    if (d / "attitude_covariance.csv").is_file():
        _, tc, Pc = read_attitude_covariance(d / "attitude_covariance.csv")
        if len(tc) == len(data.attitude_t_s) and np.allclose(tc, data.attitude_t_s, atol=1e-5):
            data.attitude_P = Pc
        else:
            data.notes.append("attitude_covariance.csv does not match the epochs of attitude.aem: "
                              "attitude plotted without sigma")
    if truth_oem is not None:
        data.truth_attitude_R = read_truth_attitude(truth_oem, data.epoch0, data.attitude_t_s)


# --------------------------------------------------------------------------------------
# Plots (each returns a matplotlib Figure; no pyplot, so no global state and no display)
# --------------------------------------------------------------------------------------
def _figure(figsize):
    from matplotlib.figure import Figure

    return Figure(figsize=figsize, layout="constrained")


def _rtn_err_sigma(x_eci, P_eci, truth_x_eci):
    P = P_eci if P_eci is not None else np.full((len(x_eci), 6, 6), np.nan)
    return error_and_sigma(x_eci, P, truth_x_eci, frame="rtn")


def _shade_gaps(ax, gaps, *, label=True):
    """Shade each long gap ``(t_start_s, length_s)`` of the log (time axis in hours)."""
    for i, (t0, length) in enumerate(gaps or ()):
        ax.axvspan(t0 * _H, (t0 + length) * _H, color="0.55", alpha=0.18, lw=0,
                   label="gap in the log (no measurements)" if label and i == 0 else None)


#: Estimates that start from the prior alone (filtered, online): their first minutes'
#: envelope is the prior's, orders of magnitude wider than the rest.
CAUSAL_LABELS = ("filtered", "online")


def _limit_transient(ax, band, err=None):
    """Keep the first minutes' large envelope of a causal estimate (a wide prior converging)
    from flattening the rest: the y range covers the 90th percentile of the envelope and
    99.5 % of the error; what lies beyond runs off the axes."""
    vals = [np.nanpercentile(band, 90)] if np.any(np.isfinite(band)) else []
    if err is not None and np.any(np.isfinite(err)):
        vals.append(np.nanpercentile(np.abs(err), 99.5))
    lim = 1.15 * max(vals) if vals else np.nan
    if np.isfinite(lim) and lim > 0:
        ax.set_ylim(-lim, lim)


def _band_and_error(ax, t_h, band, err, label, k_sigma):
    """The ±kσ envelope ``band`` (None: none) filled and outlined in red, and the error line
    (None: none) in blue, labelled "<label> error" and "±kσ (<label> covariance)"."""
    if band is not None:
        ax.fill_between(t_h, -band, band, color="tab:red", alpha=0.15, lw=0,
                        label=f"±{k_sigma:g}σ ({label} covariance)")
        ax.plot(t_h, band, color="tab:red", lw=0.8)
        ax.plot(t_h, -band, color="tab:red", lw=0.8)
    if err is not None:
        ax.plot(t_h, err, color="tab:blue", lw=0.9, label=f"{label} error")
    ax.axhline(0.0, color="0.5", lw=0.5)
    ax.grid(True, alpha=0.3)


def _legend_and_title(fig, ax, title):
    """One legend below the panels (the entries of ``ax``) and the title above them."""
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="outside lower center", ncol=len(labels), fontsize=9)
    fig.suptitle(title)
    return fig


def plot_state_errors(t_s, x_eci, P_eci, truth_x_eci=None, *, k_sigma=3.0, label="smoothed",
                      gaps=None, title=None):
    """RTN position (m) and velocity (m/s) errors vs time (h) with the ±kσ envelope of the
    same estimate's covariance.

    ``label`` names the estimate (:func:`estimate_label`: "smoothed", "filtered", "online",
    ...): the error line is "<label> error" and the envelope "±kσ (<label> covariance)".
    Without truth, plots the ±kσ envelope alone. ``gaps`` (``(t_start_s, length_s)`` each)
    are shaded. For a causal estimate (:data:`CAUSAL_LABELS`) with truth the y range leaves
    out the converging start (see :func:`_limit_transient`). Returns the Figure (2 x 3 axes: rows position / velocity, columns R, T, N).
    """
    t_h = np.asarray(t_s, float) * _H
    err, sig = _rtn_err_sigma(x_eci, P_eci, truth_x_eci)
    fig = _figure((13, 6.5))
    axs = fig.subplots(2, 3, sharex=True)
    what = "error" if err is not None else f"±{k_sigma:g}σ"
    for row, (block, unit, off) in enumerate((("position", "m", 0), ("velocity", "m/s", 3))):
        for c in range(3):
            ax = axs[row, c]
            _shade_gaps(ax, gaps)
            b = k_sigma * sig[:, off + c]
            e = None if err is None else err[:, off + c]
            _band_and_error(ax, t_h, b, e, label, k_sigma)
            if e is not None and label in CAUSAL_LABELS:
                _limit_transient(ax, b, e)
            ax.set_ylabel(f"{RTN_NAMES[c].split()[0]} {block} {what} [{unit}]")
            ax.set_title(f"{block} {RTN_NAMES[c]}", fontsize=10)
            if row == 1:
                ax.set_xlabel("time since epoch0 [h]")
    if title is None:
        title = (f"{label.capitalize()} state error (estimate − truth) in RTN with ±{k_sigma:g}σ"
                 if err is not None else
                 f"{label.capitalize()} state uncertainty ±{k_sigma:g}σ in RTN (no truth given)")
    return _legend_and_title(fig, axs[0, 0], title)


def plot_residuals_time(residual_t_s: dict, residuals: dict, residual_component=None, *,
                        gaps=None, clip=6.0, title="Whitened residuals against time"):
    """Whitened residuals (σ) vs time (h), one panel per kind observed at two epochs or more
    (a prior has one), a colour per component, ±3σ lines; values beyond ±``clip`` are drawn
    at the edge as triangles; ``gaps`` (``(t_start_s, length_s)`` each) are shaded. Returns
    the Figure."""
    kinds = [k for k in residuals if k in residual_t_s and np.size(residuals[k])
             and len(np.unique(residual_t_s[k])) >= 2]
    nrow = max(1, len(kinds))
    fig = _figure((12, 1.2 + 2.3 * nrow))
    axs = np.atleast_1d(fig.subplots(nrow, 1, sharex=True)).ravel()
    colors = ("tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:brown", "tab:pink")
    for ax, kind in zip(axs, kinds):
        t_h = np.asarray(residual_t_s[kind], float) * _H
        w = np.asarray(residuals[kind], float)
        comp = (np.zeros(len(w), int) if residual_component is None or kind not in residual_component
                else np.asarray(residual_component[kind], int))
        _shade_gaps(ax, gaps)
        many = len(w) > 20000
        for j in np.unique(comp):
            sel = comp == j
            wj = np.clip(w[sel], -clip, clip)
            ax.plot(t_h[sel], wj, ".", ms=1.0 if many else 2.0, color=colors[j % len(colors)],
                    alpha=0.6, rasterized=many, label=f"component {j}")
            for sgn, marker in ((1.0, "^"), (-1.0, "v")):
                out = sgn * w[sel] > clip
                if np.any(out):
                    ax.plot(t_h[sel][out], wj[out], marker, ms=4, color="k", ls="none")
        for y in (-3.0, 3.0):
            ax.axhline(y, color="tab:red", lw=0.8, ls="--", label="±3σ" if y > 0 else None)
        ax.axhline(0.0, color="0.5", lw=0.5)
        ax.set_ylim(-clip * 1.05, clip * 1.05)
        n_out = int(np.sum(np.abs(w) > clip))
        ax.set_title(f"{kind}: {len(w):,} values" + (f", {n_out} beyond ±{clip:g}σ drawn at the edge"
                                                     if n_out else ""), fontsize=10)
        ax.set_ylabel("whitened residual [σ]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper right", ncol=5, markerscale=4)
    if not kinds:
        axs[0].text(0.5, 0.5, "no residuals observed at two epochs or more", ha="center",
                    va="center", transform=axs[0].transAxes)
    axs[-1].set_xlabel("time since epoch0 [h]")
    if gaps:
        title += f" ({len(gaps)} gap{'s' if len(gaps) > 1 else ''} in the log shaded)"
    fig.suptitle(title)
    return fig


def plot_residual_histograms(residuals: dict, *, clip=6.0, title="Whitened residuals vs N(0, 1)"):
    """One histogram per measurement kind of the whitened residuals (all components pooled)
    with the standard-normal density they should follow. Kinds with fewer than
    :data:`MIN_HISTOGRAM_SAMPLES` values (priors: 3) share one last panel that shows each
    value as a point on its own row, against the ±1/2/3σ lines. Returns the Figure."""
    present = [k for k, v in residuals.items() if np.size(v)]
    kinds = [k for k in present if np.size(residuals[k]) >= MIN_HISTOGRAM_SAMPLES]
    few = [k for k in present if np.size(residuals[k]) < MIN_HISTOGRAM_SAMPLES]
    npanel = len(kinds) + (1 if few else 0)
    ncol = min(3, max(1, npanel))
    nrow = max(1, int(np.ceil(npanel / ncol)))
    fig = _figure((4.6 * ncol, 3.6 * nrow))
    axs = np.atleast_1d(fig.subplots(nrow, ncol)).ravel()
    g = np.linspace(-clip, clip, 400)
    pdf = np.exp(-0.5 * g**2) / np.sqrt(2 * np.pi)
    for ax, kind in zip(axs, kinds):
        w = np.asarray(residuals[kind], float).ravel()
        w = w[np.isfinite(w)]
        out = int(np.sum(np.abs(w) > clip))
        nb = int(np.clip(np.sqrt(len(w)) * 1.5, 12, 96))
        ax.hist(np.clip(w, -clip, clip), bins=np.linspace(-clip, clip, nb + 1), density=True,
                color="tab:blue", alpha=0.6, label="whitened residuals")
        ax.plot(g, pdf, color="k", lw=1.2, label="N(0, 1)")
        ax.set_xlabel("whitened residual [σ]")
        ax.set_ylabel("probability density")
        t = f"{kind}\nn={len(w):,}, mean={np.mean(w):+.2f}, std={np.std(w):.2f}"
        if out:
            t += f", {out} beyond ±{clip:g}σ"
        ax.set_title(t, fontsize=10)
        ax.legend(fontsize=8, loc="upper left")
        ax.grid(True, alpha=0.3)
    if few:
        ax = axs[len(kinds)]
        for i, kind in enumerate(few):
            w = np.asarray(residuals[kind], float).ravel()
            w = w[np.isfinite(w)]
            ax.plot(np.clip(w, -clip, clip), np.full(len(w), i), "o", ms=6, color="tab:blue",
                    alpha=0.7, label="whitened value" if i == 0 else None)
        for y in (1, 2, 3):
            for sgn in (-1, 1):
                ax.axvline(sgn * y, color="tab:red", lw=0.6, ls=(":", "--", "-")[y - 1], alpha=0.7,
                           label=f"±{y}σ" if sgn > 0 else None)
        ax.set_yticks(range(len(few)), [f"{k}\n(n={np.size(residuals[k])})" for k in few], fontsize=8)
        ax.set_ylim(-0.7, len(few) - 0.3)
        ax.set_xlim(-clip, clip)
        ax.set_xlabel("whitened residual [σ]")
        ax.set_title(f"kinds with < {MIN_HISTOGRAM_SAMPLES} values: each value", fontsize=10)
        ax.legend(fontsize=7, loc="upper left", ncol=2)
        ax.grid(True, axis="x", alpha=0.3)
    for ax in axs[npanel:]:
        ax.set_axis_off()
    if not present:
        axs[0].text(0.5, 0.5, "no residuals", ha="center", va="center", transform=axs[0].transAxes)
    fig.suptitle(title)
    return fig


def attitude_unit(sigma_rad) -> tuple[str, float]:
    """("arcsec", rad per arcsec) when the median attitude 1σ is below 0.01 deg, else
    ("deg", rad per deg)."""
    s = np.asarray(sigma_rad, float)
    med = float(np.nanmedian(s)) if np.any(np.isfinite(s)) else np.nan
    if np.isfinite(med) and med < np.radians(0.01):
        return "arcsec", _ARCSEC
    return "deg", np.pi / 180.0


def plot_attitude_errors(t_s, R_eci_from_body, P_rad2=None, truth_R=None, *, k_sigma=3.0,
                         label="smoothed", gaps=None, title=None):
    """Attitude error ``Log(R_true^T R_est)`` (rotation vector in the body frame, the right
    perturbation of ``attitude_covariance.csv``; Sola, Deray & Atchuthan 2018, "A micro Lie
    theory for state estimation in robotics") about body x, y, z vs time (h), with the ±kσ
    of ``P_rad2``; without truth the ±kσ alone. Unit arcsec or deg (:func:`attitude_unit`).
    Returns the Figure (1 x 3 axes)."""
    t_h = np.asarray(t_s, float) * _H
    n = len(t_h)
    sig = (np.full((n, 3), np.nan) if P_rad2 is None else
           np.sqrt(np.clip(np.diagonal(np.asarray(P_rad2, float), axis1=1, axis2=2), 0.0, None)))
    err = None if truth_R is None else attitude_error_body(R_eci_from_body, truth_R)
    unit, scale = attitude_unit(sig if P_rad2 is not None else (np.abs(err) if err is not None
                                                                 else sig))
    fig = _figure((13, 3.9))
    axs = fig.subplots(1, 3, sharex=True)
    what = "error" if err is not None else f"±{k_sigma:g}σ"
    for c, ax in enumerate(axs):
        _shade_gaps(ax, gaps)
        _band_and_error(ax, t_h, None if P_rad2 is None else k_sigma * sig[:, c] / scale,
                        None if err is None else err[:, c] / scale, label, k_sigma)
        ax.set_title(f"rotation about body {BODY_AXES[c]}", fontsize=10)
        ax.set_ylabel(f"attitude {what} about body {BODY_AXES[c]} [{unit}]")
        ax.set_xlabel("time since epoch0 [h]")
    if title is None:
        title = (f"{label.capitalize()} attitude error Log(R_trueᵀ R_est) about the body axes, "
                 f"with ±{k_sigma:g}σ" if err is not None else
                 f"{label.capitalize()} attitude uncertainty ±{k_sigma:g}σ, body frame (no true attitude)")
    return _legend_and_title(fig, axs[0], title)


def plot_orbit_3d(x_eci, truth_x_eci=None, *, title="Orbit in ECI"):
    """3-D orbit (km, ECI) with the Earth as a wireframe sphere. Returns the Figure."""
    fig = _figure((7.5, 7))
    ax = fig.add_subplot(projection="3d")
    re_km = R_EARTH_M * 1e-3
    u, v = np.mgrid[0:2 * np.pi:36j, 0:np.pi:18j]
    ax.plot_wireframe(re_km * np.cos(u) * np.sin(v), re_km * np.sin(u) * np.sin(v),
                      re_km * np.cos(v), color="tab:blue", lw=0.3, alpha=0.5)
    r = np.asarray(x_eci, float)[:, :3] * 1e-3
    if truth_x_eci is not None:
        rt = np.asarray(truth_x_eci, float)[:, :3] * 1e-3
        ax.plot(rt[:, 0], rt[:, 1], rt[:, 2], color="0.4", lw=2.5, alpha=0.5, label="truth")
    ax.plot(r[:, 0], r[:, 1], r[:, 2], color="tab:orange", lw=1.0, label="estimate")
    ax.scatter(*r[0], color="tab:green", s=25, label="start")
    ax.scatter(*r[-1], color="tab:red", s=25, label="end")
    lim = float(np.nanmax(np.abs(np.concatenate([r.ravel(), [re_km]]))))
    for setl in (ax.set_xlim, ax.set_ylim, ax.set_zlim):
        setl(-lim, lim)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x ECI [km]")
    ax.set_ylabel("y ECI [km]")
    ax.set_zlabel("z ECI [km]")
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(title)
    return fig


def format_duration_s(seconds: float) -> str:
    """A latency with 3 significant digits in µs, ms or s (never "0.00 ms")."""
    v = float(seconds)
    if not np.isfinite(v):
        return "n/a"
    for limit, scale, unit in ((1e-3, 1e6, "µs"), (1.0, 1e3, "ms")):
        if abs(v) < limit:
            return f"{v * scale:.3g} {unit}"
    return f"{v:.3g} s"


def plot_latency(t_s, latency_s, *, title="Per-epoch update latency"):
    """Update latency vs time (h) in ms, or in µs when the median is below 1 ms (an EKF
    update), on a log scale when it spans more than a factor 30, with its median and 99th
    percentile written to 3 significant digits in a fitting unit."""
    fig = _figure((9, 3.5))
    ax = fig.subplots()
    lat = np.asarray(latency_s, float)
    med = float(np.median(lat)) if len(lat) else 1.0
    unit, scale = ("µs", 1e6) if med < 1e-3 else ("ms", 1e3)
    v = lat * scale
    ax.plot(np.asarray(t_s, float) * _H, v, ".", ms=2, color="tab:purple", label="latency")
    if len(v):
        for q, ls, name in ((50, "--", "median"), (99, ":", "99th percentile")):
            x = float(np.percentile(lat, q))
            ax.axhline(x * scale, color="k", ls=ls, lw=0.8, label=f"{name} {format_duration_s(x)}")
        pos = v[v > 0]
        if len(pos) and pos.max() > 30 * np.percentile(pos, 1):
            ax.set_yscale("log")
    ax.set_xlabel("time since epoch0 [h]")
    ax.set_ylabel(f"update latency [{unit}]")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return fig


# --------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------
def _save(fig, path: Path, dpi=110):
    with atomic_writer(path, "wb") as f:
        fig.savefig(f, format="png", dpi=dpi)


def _unit(key: str) -> str:
    for suf, unit in (("_mps", "m/s"), ("_m", "m"), ("_s", "s"), ("_deg", "deg"), ("_rad", "rad"),
                      ("_km", "km"), ("_h", "h")):
        if key.endswith(suf):
            return unit
    return ""


def _fmt(v) -> str:
    if v is None:
        return "—"
    if isinstance(v, bool) or isinstance(v, str):
        return str(v)
    if isinstance(v, int):
        return f"{v:,}"
    if isinstance(v, float):
        return f"{v:.4g}" if abs(v) < 1e5 else f"{v:.4e}"
    return str(v)


def metrics_rows(summary: dict) -> list[tuple[str, str, str]]:
    """(key, value, unit) rows of the scalar entries of ``summary``, preferred order first."""
    keys = [k for k in METRIC_ORDER if k in summary]
    keys += sorted(k for k, v in summary.items()
                   if k not in keys and (v is None or isinstance(v, (bool, int, float, str))))
    return [(k, _fmt(summary[k]), _unit(k)) for k in keys]


def write_report(data: ResultData, out_dir, *, k_sigma=3.0, title=None) -> dict:
    """Write the PNGs, ``report.md`` and ``report.html`` for ``data`` into ``out_dir``.

    Returns ``{"markdown": path, "html": path, "images": {name: path}, "figures":
    {name: Figure}}`` (the figures let callers and tests inspect axes).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    has_truth = data.truth_x_eci is not None
    label = estimate_label(data.method)
    gaps = data.gaps if data.gaps is not None else residual_gaps(data.residual_t_s)
    figs = {}
    figs["errors_rtn" if has_truth else "sigma_rtn"] = plot_state_errors(
        data.t_s, data.x_eci, data.P_eci, data.truth_x_eci, k_sigma=k_sigma, label=label,
        gaps=gaps)
    online = data.online_x_eci is not None and data.method != "ekf"
    if online:
        if data.online_P_eci is None:
            data.notes.append("online.oem has no covariance at every epoch: the online error is "
                              "drawn without its sigma")
        figs["online_errors_rtn" if has_truth else "online_sigma_rtn"] = plot_state_errors(
            data.t_s, data.online_x_eci, data.online_P_eci, data.truth_x_eci, k_sigma=k_sigma,
            label="online", gaps=gaps)
    if data.residuals:
        if data.residual_t_s:
            figs["residuals_time"] = plot_residuals_time(
                data.residual_t_s, data.residuals, data.residual_component, gaps=gaps)
        figs["residuals_hist"] = plot_residual_histograms(data.residuals)
    att_truth = data.truth_attitude_R is not None
    if data.attitude_R is not None and (att_truth or data.attitude_P is not None):
        figs["attitude_errors" if att_truth else "attitude_sigma"] = plot_attitude_errors(
            data.attitude_t_s, data.attitude_R, data.attitude_P, data.truth_attitude_R,
            k_sigma=k_sigma, label=label, gaps=gaps)
    figs["orbit_3d"] = plot_orbit_3d(data.x_eci, data.truth_x_eci)
    if data.latency_s is not None and len(data.latency_s):
        figs["latency"] = plot_latency(data.latency_t_s, data.latency_s)
    images = {}
    for name, fig in figs.items():
        images[name] = out / f"{name}.png"
        _save(fig, images[name])

    method = data.method
    title = title or f"fgnav report — {method}"

    e0 = format_utc(data.epoch0)[:-4] + "Z"  # ms; leap seconds print as 23:59:60
    span_h = (data.t_s[-1] - data.t_s[0]) * _H if len(data.t_s) else 0.0
    L = label.capitalize()
    captions = {
        "errors_rtn": f"{L} position and velocity error (estimate − truth) in RTN with ±{k_sigma:g}σ",
        "sigma_rtn": f"{L} position and velocity ±{k_sigma:g}σ in RTN (no truth available)",
        "online_errors_rtn": f"Online position and velocity error (each epoch as estimated when it "
                             f"arrived) in RTN with the online ±{k_sigma:g}σ",
        "online_sigma_rtn": f"Online position and velocity ±{k_sigma:g}σ in RTN (no truth available)",
        "residuals_time": "Whitened residuals against time (long gaps shaded)",
        "residuals_hist": "Whitened residuals per measurement kind against N(0, 1)",
        "attitude_errors": f"{L} attitude error about the body axes with ±{k_sigma:g}σ",
        "attitude_sigma": f"{L} attitude ±{k_sigma:g}σ about the body axes (no true attitude)",
        "orbit_3d": "Orbit in ECI (km)",
        "latency": "Per-epoch update latency",
    }
    rows = metrics_rows(data.summary)
    md = [f"# {title}", "",
          f"Epoch0 {e0}, {len(data.t_s):,} epochs over {span_h:.3g} h. "
          f"Truth: {'yes' if has_truth else 'no'}.", ""]
    md += [f"> note: {n}" for n in data.notes]
    md += ["", "| metric | value | unit |", "|---|---:|---|"]
    md += [f"| {k} | {v} | {u} |" for k, v, u in rows]
    md.append("")
    for name, p in images.items():
        md += [f"## {captions[name]}", "", f"![{captions[name]}]({p.name})", ""]
    atomic_write_text(out / "report.md", "\n".join(md))

    esc = html.escape
    h = ["<!DOCTYPE html>", "<html><head><meta charset='utf-8'>", f"<title>{esc(title)}</title>",
         "<style>body{font-family:sans-serif;max-width:1200px;margin:2em auto;}"
         "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 8px}"
         "td.v{text-align:right}img{max-width:100%}.note{color:#a50}</style></head><body>",
         f"<h1>{esc(title)}</h1>",
         f"<p>Epoch0 {esc(e0)}, {len(data.t_s):,} epochs over {span_h:.3g} h. "
         f"Truth: {'yes' if has_truth else 'no'}.</p>"]
    h += [f"<p class='note'>note: {esc(n)}</p>" for n in data.notes]
    h.append("<table><tr><th>metric</th><th>value</th><th>unit</th></tr>")
    h += [f"<tr><td>{esc(k)}</td><td class='v'>{esc(v)}</td><td>{esc(u)}</td></tr>" for k, v, u in rows]
    h.append("</table>")
    for name, p in images.items():
        h += [f"<h2>{esc(captions[name])}</h2>", f"<img src='{esc(p.name)}' alt='{esc(captions[name])}'>"]
    h.append("</body></html>")
    atomic_write_text(out / "report.html", "\n".join(h) + "\n")

    commit_outputs(out, None, [p.name for p in images.values()] + ["report.md", "report.html"],
                   "report", replaces=("report",))
    return {"markdown": out / "report.md", "html": out / "report.html", "images": images,
            "figures": figs}


# ---------------------------------------------------------------- several spacecraft
# A formation's result directory: trajectory-<id>.oem per spacecraft, relative.csv of every
# pair (fgnav.results), residuals.csv, summary.json with "spacecraft" and "relative".

_LVLH_NAMES = ("x (radial)", "y (along-track)", "z (normal)")
_STATE = ("x", "y", "z", "vx", "vy", "vz")


def is_formation_dir(result_dir) -> bool:
    """A formation's result: ``trajectory-<id>.oem`` files and no ``trajectory.oem``."""
    d = Path(result_dir)
    return (d.is_dir() and not (d / "trajectory.oem").is_file()
            and any(d.glob("trajectory-*.oem")))


def read_relative_csv(path) -> dict[str, dict]:
    """``relative.csv`` -> per pair ``{"reference", "spacecraft", "t_s" (N,), "x" (N, 6)
    LVLH state (m, m/s), "C" (N, 6, 6) its covariance}``, keyed by the deputy's id for the
    pairs with the first reference of the file and by ``<reference>-<spacecraft>`` for the
    others (three or more spacecraft, :func:`fgnav.results.pairs`)."""
    iu = np.triu_indices(6)
    units = ["m"] * 3 + ["mps"] * 3
    want = ["t_s", "reference", "spacecraft"] + [f"lvlh_{c}_{u}" for c, u in zip(_STATE, units)]
    want += [f"lvlh_c{i + 1}{j + 1}" for i, j in zip(*iu)]
    out: dict[str, dict] = {}
    first = None
    with open(path, encoding="utf-8", newline="") as f:
        rows = csv.reader(f)
        header = [h.strip() for h in next(rows, [])]
        missing = [c for c in want if c not in header]
        if missing:
            raise InputFormatError(path, 1, missing[0], "the columns of fgnav's relative.csv",
                                   ",".join(header[:6]) + ",...")
        col = {c: header.index(c) for c in want}
        for lineno, row in enumerate(rows, start=2):
            if not row:
                continue
            try:
                vals = [float(row[col[c]]) for c in want if c not in ("reference", "spacecraft")]
            except (ValueError, IndexError):
                raise InputFormatError(path, lineno, None, f"{len(header)} fields of numbers",
                                       ",".join(row[:4]) + ",...") from None
            ref, sc = row[col["reference"]], row[col["spacecraft"]]
            first = ref if first is None else first
            d = out.setdefault(sc if ref == first else f"{ref}-{sc}",
                               {"reference": ref, "spacecraft": sc, "rows": []})
            d["rows"].append(vals)
    for d in out.values():
        a = np.array(d.pop("rows"), float)
        C = np.zeros((len(a), 6, 6))
        C[:, iu[0], iu[1]] = a[:, 7:]
        C[:, iu[1], iu[0]] = a[:, 7:]
        d.update(t_s=a[:, 0], x=a[:, 1:7], C=C)
    return out


def plot_relative_state(t_s, x_rel, x_true=None, *, title):
    """The relative position (m) and velocity (m/s) in LVLH (:mod:`fgnav.frames`; Clohessy &
    Wiltshire 1960's Hill frame) against time (h), x/y/z in their own panels, with the truth's relative state dashed. Returns the Figure."""
    t_h = np.asarray(t_s, float) * _H
    fig = _figure((13, 6.5))
    axs = fig.subplots(2, 3, sharex=True)
    for row, (block, unit, off) in enumerate((("position", "m", 0), ("velocity", "m/s", 3))):
        for c in range(3):
            ax = axs[row, c]
            ax.plot(t_h, x_rel[:, off + c], color="tab:blue", lw=1.2, label="estimate")
            if x_true is not None:
                ax.plot(t_h, x_true[:, off + c], color="k", lw=0.9, ls="--", label="truth")
            ax.grid(True, alpha=0.3)
            ax.set_title(f"{block} {_LVLH_NAMES[c]}", fontsize=10)
            ax.set_ylabel(f"{_LVLH_NAMES[c].split()[0]} {block} [{unit}]")
            if row == 1:
                ax.set_xlabel("time since epoch0 [h]")
    return _legend_and_title(fig, axs[0, 0], title)


def plot_relative_errors(t_s, x_rel, C, x_true=None, *, k_sigma=3.0, label="smoothed", title):
    """The relative state's error (estimate − truth's relative state) in LVLH with the ±kσ
    of the relative covariance ``C`` (N, 6, 6); without truth the ±kσ alone."""
    t_h = np.asarray(t_s, float) * _H
    sig = np.sqrt(np.clip(np.diagonal(C, axis1=1, axis2=2), 0.0, None))
    err = None if x_true is None else x_rel - x_true
    what = "error" if err is not None else f"±{k_sigma:g}σ"
    fig = _figure((13, 6.5))
    axs = fig.subplots(2, 3, sharex=True)
    for row, (block, unit, off) in enumerate((("position", "m", 0), ("velocity", "m/s", 3))):
        for c in range(3):
            ax = axs[row, c]
            _band_and_error(ax, t_h, k_sigma * sig[:, off + c],
                            None if err is None else err[:, off + c], label, k_sigma)
            ax.set_title(f"relative {block} {_LVLH_NAMES[c]}", fontsize=10)
            ax.set_ylabel(f"{_LVLH_NAMES[c].split()[0]} {block} {what} [{unit}]")
            if row == 1:
                ax.set_xlabel("time since epoch0 [h]")
    return _legend_and_title(fig, axs[0, 0], title)


def _truth_dir(d: Path, summary: dict, truth_path, notes) -> Path | None:
    tp = truth_path if truth_path is not None else summary.get("truth_path")
    if not tp:
        return None
    p = Path(tp)
    for cand in (p, d / p):
        if cand.is_dir():
            return cand
        if cand.is_file():
            return cand.parent
    if truth_path is not None:
        raise UserError(f"--truth {truth_path}: expected the directory of the formation's "
                        "truth-<id>.oem files")
    notes.append(f"truth directory {tp} not found: plotted without truth")
    return None


def report_formation_dir(result_dir, out_dir=None, *, truth_path=None, k_sigma=3.0) -> dict:
    """Write the plots (module docstring, several spacecraft), ``report.md`` and ``report.html`` of the formation's
    result directory ``result_dir`` into ``out_dir`` (default ``result_dir``). Returns
    ``{"markdown", "html", "images": {name: path}, "figures": {name: Figure}, "notes"}``."""

    d = Path(result_dir)
    out = Path(out_dir) if out_dir is not None else d
    for name in ("summary.json", "relative.csv"):
        if not (d / name).is_file():
            raise UserError(f"{d}: missing {name} (expected the output of `fgnav smooth --out` "
                            "on a formation's log)")
    summary = read_summary(d / "summary.json")
    if not isinstance(summary.get("spacecraft"), dict) or not summary["spacecraft"]:
        raise UserError(f"{d / 'summary.json'}: expected a 'spacecraft' object (a formation's "
                        "summary)")
    ids = list(summary["spacecraft"])
    notes: list[str] = []
    tdir = _truth_dir(d, summary, truth_path, notes)
    label = estimate_label(summary.get("method"))
    traj, truths = {}, {}
    for sc in ids:
        path = d / f"trajectory-{sc}.oem"
        if not path.is_file():
            raise UserError(f"{d}: missing {path.name} (summary.json lists spacecraft '{sc}')")
        traj[sc] = read_oem(path)
    epoch0 = np.datetime64(traj[ids[0]].epoch0, "ns")
    for sc in ids:
        tp = None if tdir is None else truth_path_of(tdir, sc)
        if tp is not None and tp.is_file():
            tru = read_oem(tp)
            t = np.asarray(traj[sc].t_s, float) + _shift_s(traj[sc].epoch0, epoch0)
            truths[sc] = states_at(t, np.asarray(tru.t_s, float) + _shift_s(tru.epoch0, epoch0),
                                   tru.x_eci)
        elif tp is not None:
            notes.append(f"{tp} not found: spacecraft {sc} plotted without truth")
    rel = read_relative_csv(d / "relative.csv")
    table = read_residuals_table(d / "residuals.csv") if (d / "residuals.csv").is_file() else {}
    res_t = {k: t for k, (t, _, _) in table.items()}
    gaps = residual_gaps(res_t)

    figs, captions = {}, {}
    for sc in ids:
        o = traj[sc]
        xt = truths.get(sc)
        name = f"{'errors' if xt is not None else 'sigma'}_rtn-{sc}"
        cap = (f"Spacecraft {sc}: {label} state error (estimate − truth) in RTN with "
               f"±{k_sigma:g}σ" if xt is not None else
               f"Spacecraft {sc}: {label} state ±{k_sigma:g}σ in RTN (no truth given)")
        figs[name] = plot_state_errors(o.t_s, o.x_eci, o.P_eci, xt, k_sigma=k_sigma, label=label,
                                       gaps=gaps, title=cap)
        captions[name] = cap
    ref = ids[0]
    for key, r in rel.items():
        x_true = None
        c, sc = r["reference"], r["spacecraft"]
        if c in truths and sc in truths and c in traj and sc in traj:
            xr = states_at(r["t_s"], np.asarray(traj[c].t_s, float), truths[c])
            xd = states_at(r["t_s"], np.asarray(traj[sc].t_s, float), truths[sc])
            x_true = relative_state_lvlh(xr, xd)[0]
        cap = f"{sc} relative to {c}: state in the LVLH frame of {c}"
        figs[f"relative_lvlh-{key}"] = plot_relative_state(
            r["t_s"], r["x"], x_true, title=cap + (" (truth dashed)" if x_true is not None else ""))
        captions[f"relative_lvlh-{key}"] = cap
        name = f"relative_{'errors' if x_true is not None else 'sigma'}_lvlh-{key}"
        cap = (f"{sc} relative to {c}: {label} relative state error in LVLH with "
               f"±{k_sigma:g}σ (joint covariance)" if x_true is not None else
               f"{sc} relative to {c}: relative state ±{k_sigma:g}σ in LVLH "
               "(no truth given)")
        figs[name] = plot_relative_errors(r["t_s"], r["x"], r["C"], x_true, k_sigma=k_sigma,
                                          label=label, title=cap)
        captions[name] = cap
    if table:
        residuals = {k: w for k, (_, _, w) in table.items()}
        figs["residuals_time"] = plot_residuals_time(
            res_t, residuals, {k: c for k, (_, c, _) in table.items()}, gaps=gaps)
        captions["residuals_time"] = "Whitened residuals against time (links included)"
        figs["residuals_hist"] = plot_residual_histograms(residuals)
        captions["residuals_hist"] = "Whitened residuals per measurement kind against N(0, 1)"
    figs["orbit_3d"] = _orbits_3d(ids, traj, truths)
    captions["orbit_3d"] = "Orbits in ECI (km)"

    out.mkdir(parents=True, exist_ok=True)
    images = {}
    for name, fig in figs.items():
        images[name] = out / f"{name}.png"
        _save(fig, images[name])
    md_path, html_path = _write_documents(out, summary, ids, traj[ref], images, captions,
                                          notes, bool(truths))
    commit_outputs(out, None, [p.name for p in images.values()] + ["report.md", "report.html"],
                   "report", replaces=("report",))
    return {"markdown": md_path, "html": html_path, "images": images, "figures": figs,
            "notes": notes}


def _orbits_3d(ids, traj, truths):
    """Every spacecraft's orbit on :func:`plot_orbit_3d`'s axes, each its own curve."""
    ref = ids[0]
    fig = plot_orbit_3d(traj[ref].x_eci, truths.get(ref),
                        title=f"Orbits of {', '.join(ids)} in ECI")
    ax = fig.axes[0]
    for line in ax.get_lines():
        if line.get_label() in ("estimate", "truth"):
            line.set_label(f"{ref} {line.get_label()}")
    colors = ("tab:purple", "tab:cyan", "tab:olive", "tab:pink", "tab:brown")
    for i, sc in enumerate(ids[1:]):
        r = np.asarray(traj[sc].x_eci, float)[:, :3] * 1e-3
        col = colors[i % len(colors)]
        if sc in truths:
            rt = np.asarray(truths[sc], float)[:, :3] * 1e-3
            ax.plot(rt[:, 0], rt[:, 1], rt[:, 2], color=col, lw=2.5, alpha=0.3,
                    label=f"{sc} truth")
        ax.plot(r[:, 0], r[:, 1], r[:, 2], color=col, lw=1.0, ls="--", label=f"{sc} estimate")
    ax.legend(loc="upper left", fontsize=8)
    return fig


def _table(header, rows):
    return ([f"| {' | '.join(header)} |", "|" + "---|" * len(header)]
            + [f"| {' | '.join(r)} |" for r in rows])


def _write_documents(out, summary, ids, ref_oem, images, captions, notes, has_truth):
    """``report.md`` and ``report.html``: the run's metrics, a table of each spacecraft's and
    the relative state's figures, and the plots."""
    title = f"fgnav report — formation of {len(ids)} spacecraft ({summary.get('method', '?')})"
    t = np.asarray(ref_oem.t_s, float)
    e0 = format_utc(np.datetime64(ref_oem.epoch0, "ns"))[:-4] + "Z"
    span_h = (t[-1] - t[0]) * _H if len(t) else 0.0
    intro = (f"Epoch0 {e0}, {len(t):,} epochs over {span_h:.3g} h; spacecraft {', '.join(ids)} "
             f"(reference {ids[0]}). Truth: {'yes' if has_truth else 'no'}. Integrity: "
             f"{(summary.get('integrity') or {}).get('status', '?')}.")
    run_rows = [(k, v, u) for k, v, u in metrics_rows(summary)]
    per = {sc: summary["spacecraft"][sc] for sc in ids}
    rel = dict(summary.get("relative") or {})
    keys = sorted({k for v in per.values() for k in v if isinstance(v[k], (int, float))})
    sc_rows = [[k] + [_fmt(per[sc].get(k)) for sc in ids] + [_unit(k)] for k in keys]
    rel_rows = [[k, _fmt(v), _unit(k)] for k, v in sorted(rel.items())
                if isinstance(v, (int, float, str))]
    pairs = summary.get("relative_pairs") or []   # three or more spacecraft
    pair_names = [f"{d.get('spacecraft')} from {d.get('reference')}" for d in pairs]
    pair_keys = sorted({k for d in pairs for k, v in d.items()
                        if isinstance(v, (int, float)) and not isinstance(v, bool)})
    pair_rows = [[k] + [_fmt(d.get(k)) for d in pairs] + [_unit(k)] for k in pair_keys]
    md = [f"# {title}", "", intro, ""] + [f"> note: {n}" for n in notes] + [""]
    md += _table(["metric", "value", "unit"], [list(r) for r in run_rows]) + [""]
    md += ["## Each spacecraft", ""] + _table(["metric", *ids, "unit"], sc_rows) + [""]
    md += [f"## Relative state ({rel.get('frame', 'LVLH')})", ""]
    md += _table(["metric", "value", "unit"], rel_rows) + [""]
    if pair_rows:
        md += ["## Every pair's relative state", ""]
        md += _table(["metric", *pair_names, "unit"], pair_rows) + [""]
    for name, p in images.items():
        md += [f"## {captions[name]}", "", f"![{captions[name]}]({p.name})", ""]
    atomic_write_text(out / "report.md", "\n".join(md))

    esc = html.escape

    def table(header, rows):
        h = "<tr>" + "".join(f"<th>{esc(c)}</th>" for c in header) + "</tr>"
        return [f"<table>{h}"] + ["<tr>" + "".join(f"<td>{esc(str(c))}</td>" for c in r) + "</tr>"
                                  for r in rows] + ["</table>"]

    h = ["<!DOCTYPE html>", "<html><head><meta charset='utf-8'>", f"<title>{esc(title)}</title>",
         "<style>body{font-family:sans-serif;max-width:1200px;margin:2em auto;}"
         "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 8px}"
         "img{max-width:100%}.note{color:#a50}</style></head><body>",
         f"<h1>{esc(title)}</h1>", f"<p>{esc(intro)}</p>"]
    h += [f"<p class='note'>note: {esc(n)}</p>" for n in notes]
    h += table(["metric", "value", "unit"], run_rows)
    h += ["<h2>Each spacecraft</h2>"] + table(["metric", *ids, "unit"], sc_rows)
    h += [f"<h2>Relative state ({esc(str(rel.get('frame', 'LVLH')))})</h2>"]
    h += table(["metric", "value", "unit"], rel_rows)
    if pair_rows:
        h += ["<h2>Every pair's relative state</h2>"]
        h += table(["metric", *pair_names, "unit"], pair_rows)
    for name, p in images.items():
        h += [f"<h2>{esc(captions[name])}</h2>",
              f"<img src='{esc(p.name)}' alt='{esc(captions[name])}'>"]
    h.append("</body></html>")
    atomic_write_text(out / "report.html", "\n".join(h) + "\n")
    return out / "report.md", out / "report.html"


def report_result_dir(result_dir, out_dir=None, *, truth_path=None, k_sigma=3.0) -> dict:
    """``load_result`` + ``write_report`` (into ``result_dir`` unless ``out_dir``); a
    formation's result directory (``trajectory-<id>.oem`` per spacecraft) by
    :func:`report_formation_dir`."""
    if is_formation_dir(result_dir):
        return report_formation_dir(result_dir, out_dir, truth_path=truth_path, k_sigma=k_sigma)
    data = load_result(result_dir, truth_path=truth_path)
    res = write_report(data, out_dir if out_dir is not None else result_dir, k_sigma=k_sigma)
    res["notes"] = list(data.notes)
    return res


__all__ = ["ResultData", "load_result", "read_residuals_csv", "read_residuals_table",
           "read_latency_csv", "states_at", "estimate_label", "residual_gaps",
           "plot_state_errors", "plot_residuals_time", "plot_residual_histograms",
           "plot_attitude_errors", "plot_orbit_3d", "plot_latency", "format_duration_s",
           "metrics_rows", "write_report", "report_result_dir", "is_formation_dir",
           "read_relative_csv", "plot_relative_state", "plot_relative_errors",
           "report_formation_dir"]

