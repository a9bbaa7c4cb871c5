"""Report of a result directory: PNG plots (matplotlib, Agg) plus ``report.md`` and
``report.html`` with the metrics table of ``summary.json``.

A result directory (written by ``fgnav smooth LOG --out DIR``) holds ``trajectory.oem``,
``summary.json``, ``residuals.csv`` (``t_s,kind,component,whitened``), optionally
``online.oem`` and ``latency.csv`` (``t_s,latency_s``). The truth OEM is found through
``summary.json``'s ``truth_path`` (or given explicitly).

Plots (time in hours since ``epoch0``, errors in m and m/s):

* ``errors_rtn.png`` — position and velocity error (estimate − truth) in RTN with the ±kσ
  envelope of the estimated covariance; without truth ``sigma_rtn.png``, the ±kσ envelope;
* ``residuals_hist.png`` — whitened-residual histogram per kind against N(0, 1);
* ``orbit_3d.png`` — estimated (and true) orbit in ECI, km, with the Earth;
* ``latency.png`` — per-epoch update latency of incremental methods (if present).
"""

from __future__ import annotations

import csv
import html
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from factors.constants import R_EARTH_M
from fgnav.errors import InputFormatError, UserError
from fgnav.io.atomic import atomic_write_text, atomic_writer
from fgnav.io.oem import read_oem
from fgnav.io.outputs import commit_outputs
from fgnav.io.summary import read_summary
from fgnav.time import format_utc
from fgnav.viz.rerun_log import error_and_sigma

RTN_NAMES = ("R (radial)", "T (along-track)", "N (cross-track)")
_H = 1.0 / 3600.0

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


# --------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------
def read_residuals_csv(path) -> dict[str, np.ndarray]:
    """``residuals.csv`` (``t_s,kind,component,whitened``) -> ``kind -> whitened (M,)``."""
    out: dict[str, list[float]] = {}
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
            try:
                w = float(row[3])
            except ValueError:
                raise InputFormatError(path, lineno, "whitened", "a number", row[3]) from None
            out.setdefault(row[1].strip(), []).append(w)
    return {k: np.asarray(v, float) for k, v in out.items()}


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
    if tp:
        found = _find_truth(d, tp)
        if found is None:
            data.notes.append(f"truth file {tp} not found: plotted without truth")
        else:
            tru = read_oem(found)
            shift = float((np.datetime64(tru.epoch0, "ns") - data.epoch0) / np.timedelta64(1, "ns")) * 1e-9
            data.truth_x_eci = states_at(t_s, np.asarray(tru.t_s, float) + shift, tru.x_eci)
            if np.any(np.isnan(data.truth_x_eci)):
                data.notes.append("truth does not cover every estimated epoch (gaps left blank)")
    if (d / "online.oem").is_file():
        onl = read_oem(d / "online.oem")
        shift = float((np.datetime64(onl.epoch0, "ns") - data.epoch0) / np.timedelta64(1, "ns")) * 1e-9
        data.online_x_eci = states_at(t_s, np.asarray(onl.t_s, float) + shift, onl.x_eci)
    if (d / "residuals.csv").is_file():
        data.residuals = read_residuals_csv(d / "residuals.csv")
    if (d / "latency.csv").is_file():
        data.latency_t_s, data.latency_s = read_latency_csv(d / "latency.csv")
    return data


# --------------------------------------------------------------------------------------
# Plots (each returns a matplotlib Figure; no pyplot, so no global state and no display)
# --------------------------------------------------------------------------------------
def _figure(figsize):
    from matplotlib.figure import Figure

    return Figure(figsize=figsize, layout="constrained")


def _rtn_err_sigma(x_eci, P_eci, truth_x_eci):
    P = P_eci if P_eci is not None else np.full((len(x_eci), 6, 6), np.nan)
    return error_and_sigma(x_eci, P, truth_x_eci, frame="rtn")


def plot_state_errors(t_s, x_eci, P_eci, truth_x_eci=None, *, k_sigma=3.0, online_x_eci=None,
                      title=None):
    """RTN position (m) and velocity (m/s) errors vs time (h) with the ±kσ envelope.

    Without truth, plots the ±kσ envelope alone. Returns the Figure (2 x 3 axes:
    rows position / velocity, columns R, T, N).
    """
    t_h = np.asarray(t_s, float) * _H
    err, sig = _rtn_err_sigma(x_eci, P_eci, truth_x_eci)
    on_err = None
    if err is not None and online_x_eci is not None:
        on_err, _ = _rtn_err_sigma(online_x_eci, None, truth_x_eci)
    fig = _figure((13, 6.5))
    axs = fig.subplots(2, 3, sharex=True)
    what = "error" if err is not None else f"±{k_sigma:g}σ"
    for row, (block, unit, off) in enumerate((("position", "m", 0), ("velocity", "m/s", 3))):
        for c in range(3):
            ax = axs[row, c]
            b = k_sigma * sig[:, off + c]
            ax.fill_between(t_h, -b, b, color="tab:red", alpha=0.15, lw=0,
                            label=f"±{k_sigma:g}σ (estimated covariance)")
            ax.plot(t_h, b, color="tab:red", lw=0.8)
            ax.plot(t_h, -b, color="tab:red", lw=0.8)
            if on_err is not None:
                ax.plot(t_h, on_err[:, off + c], color="tab:orange", lw=0.6, alpha=0.7,
                        label="online (filtered) error")
            if err is not None:
                ax.plot(t_h, err[:, off + c], color="tab:blue", lw=0.9, label="smoothed error")
                if on_err is not None:
                    # keep the smoothed error readable: limit the axis to it and its envelope
                    lim = 1.2 * np.nanmax(np.abs(np.concatenate([err[:, off + c], b])))
                    if np.isfinite(lim) and lim > 0:
                        ax.set_ylim(-lim, lim)
            ax.axhline(0.0, color="0.5", lw=0.5)
            ax.set_ylabel(f"{RTN_NAMES[c].split()[0]} {block} {what} [{unit}]")
            ax.set_title(f"{block} {RTN_NAMES[c]}", fontsize=10)
            ax.grid(True, alpha=0.3)
            if row == 1:
                ax.set_xlabel("time since epoch0 [h]")
    handles, labels = axs[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=len(labels), fontsize=9)
    if title is None:
        title = ("State error (estimate − truth) in RTN with ±%gσ" % k_sigma if err is not None
                 else "State uncertainty ±%gσ in RTN (no truth given)" % k_sigma)
    fig.suptitle(title)
    return fig


def plot_residual_histograms(residuals: dict, *, clip=6.0, title="Whitened residuals vs N(0, 1)"):
    """One histogram per measurement kind of the whitened residuals (all components pooled)
    with the standard-normal density they should follow. Returns the Figure."""
    kinds = [k for k, v in residuals.items() if np.size(v)]
    ncol = min(3, max(1, len(kinds)))
    nrow = max(1, int(np.ceil(len(kinds) / ncol)))
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
    for ax in axs[len(kinds):]:
        ax.set_axis_off()
    if not kinds:
        axs[0].text(0.5, 0.5, "no residuals", ha="center", va="center", transform=axs[0].transAxes)
    fig.suptitle(title)
    return fig


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


def plot_latency(t_s, latency_s, *, title="Per-epoch update latency"):
    """Update latency (ms) vs time (h), with its median and 99th percentile."""
    fig = _figure((9, 3.5))
    ax = fig.subplots()
    ms = np.asarray(latency_s, float) * 1e3
    ax.plot(np.asarray(t_s, float) * _H, ms, ".", ms=2, color="tab:purple", label="latency")
    if len(ms):
        for q, ls in ((50, "--"), (99, ":")):
            ax.axhline(np.percentile(ms, q), color="k", ls=ls, lw=0.8,
                       label=f"{'median' if q == 50 else '99th percentile'} {np.percentile(ms, q):.2f} ms")
    ax.set_xlabel("time since epoch0 [h]")
    ax.set_ylabel("update latency [ms]")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
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
    figs = {}
    figs["errors_rtn" if has_truth else "sigma_rtn"] = plot_state_errors(
        data.t_s, data.x_eci, data.P_eci, data.truth_x_eci, k_sigma=k_sigma,
        online_x_eci=data.online_x_eci)
    if data.residuals:
        figs["residuals_hist"] = plot_residual_histograms(data.residuals)
    figs["orbit_3d"] = plot_orbit_3d(data.x_eci, data.truth_x_eci)
    if data.latency_s is not None and len(data.latency_s):
        figs["latency"] = plot_latency(data.latency_t_s, data.latency_s)
    images = {}
    for name, fig in figs.items():
        images[name] = out / f"{name}.png"
        _save(fig, images[name])

    method = data.summary.get("method", "?")
    title = title or f"fgnav report — {method}"

    e0 = format_utc(data.epoch0)[:-4] + "Z"  # ms; leap seconds print as 23:59:60
    span_h = (data.t_s[-1] - data.t_s[0]) * _H if len(data.t_s) else 0.0
    captions = {
        "errors_rtn": f"Position and velocity error (estimate − truth) in RTN with ±{k_sigma:g}σ",
        "sigma_rtn": f"Position and velocity ±{k_sigma:g}σ in RTN (no truth available)",
        "residuals_hist": "Whitened residuals per measurement kind against N(0, 1)",
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


def report_result_dir(result_dir, out_dir=None, *, truth_path=None, k_sigma=3.0) -> dict:
    """``load_result`` + ``write_report`` (into ``result_dir`` unless ``out_dir``)."""
    data = load_result(result_dir, truth_path=truth_path)
    res = write_report(data, out_dir if out_dir is not None else result_dir, k_sigma=k_sigma)
    res["notes"] = list(data.notes)
    return res


__all__ = ["ResultData", "load_result", "read_residuals_csv", "read_latency_csv", "states_at",
           "plot_state_errors", "plot_residual_histograms", "plot_orbit_3d", "plot_latency",
           "metrics_rows", "write_report", "report_result_dir"]

