"""Report of a formation's result directory (``fgnav smooth`` on a log of several spacecraft).

The directory holds ``trajectory-<id>.oem`` per spacecraft, ``relative.csv`` (every further
spacecraft's state in the reference's LVLH frame with its 1-sigmas and 6x6 covariance,
:mod:`fgnav.results`), ``residuals.csv`` and ``summary.json`` (``spacecraft`` and
``relative`` objects). The truth is each spacecraft's ``truth-<id>.oem`` in the directory
given by ``--truth`` (or ``summary.json``'s ``truth_path``), as ``fgnav simulate`` writes it.

Plots (time in hours since ``epoch0``; :mod:`fgnav.viz.report` draws each panel):

* ``errors_rtn-<id>.png`` (``sigma_rtn-<id>.png`` without truth) per spacecraft: its absolute
  position and velocity error in its own RTN frame with the ±kσ envelope of its marginal
  covariance;
* ``relative_lvlh-<id>.png`` per further spacecraft: its relative position and velocity in
  the reference's LVLH frame (x radial, y along-track, z normal; m, m/s), the truth dashed;
* ``relative_errors_lvlh-<id>.png`` (``relative_sigma_lvlh-<id>.png`` without truth): the
  relative state's error against the truth's relative state with the ±kσ of the relative
  covariance (cross-covariances of the joint solution included);
* ``residuals_time.png``, ``residuals_hist.png``: the whitened residuals of every kind
  (links included);
* ``orbit_3d.png``: every spacecraft's orbit in ECI (km).
"""

from __future__ import annotations

import csv
import html
from pathlib import Path

import numpy as np

from fgnav.errors import InputFormatError, UserError
from fgnav.io.atomic import atomic_write_text
from fgnav.io.oem import read_oem
from fgnav.io.outputs import commit_outputs
from fgnav.io.summary import read_summary
from fgnav.frames import relative_state_lvlh
from fgnav.results import truth_path_of
from fgnav.time import format_utc
from fgnav.viz.report import (_H, _band_and_error, _figure, _legend_and_title, _save, _shift_s,
                              estimate_label, metrics_rows, plot_orbit_3d,
                              plot_residual_histograms, plot_residuals_time, plot_state_errors,
                              read_residuals_table, residual_gaps, states_at)

__all__ = ["is_formation_dir", "read_relative_csv", "plot_relative_state",
           "plot_relative_errors", "report_formation_dir"]

_LVLH_NAMES = ("x (radial)", "y (along-track)", "z (normal)")
_STATE = ("x", "y", "z", "vx", "vy", "vz")


def is_formation_dir(result_dir) -> bool:
    """A formation's result: ``trajectory-<id>.oem`` files and no ``trajectory.oem``."""
    d = Path(result_dir)
    return (d.is_dir() and not (d / "trajectory.oem").is_file()
            and any(d.glob("trajectory-*.oem")))


def read_relative_csv(path) -> dict[str, dict]:
    """``relative.csv`` -> per further spacecraft ``{"reference", "t_s" (N,), "x" (N, 6)
    LVLH state (m, m/s), "C" (N, 6, 6) its covariance}``."""
    iu = np.triu_indices(6)
    units = ["m"] * 3 + ["mps"] * 3
    want = ["t_s", "reference", "spacecraft"] + [f"lvlh_{c}_{u}" for c, u in zip(_STATE, units)]
    want += [f"lvlh_c{i + 1}{j + 1}" for i, j in zip(*iu)]
    out: dict[str, dict] = {}
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
            d = out.setdefault(row[col["spacecraft"]], {"reference": row[col["reference"]],
                                                         "rows": []})
            d["rows"].append(vals)
    for d in out.values():
        a = np.array(d.pop("rows"), float)
        C = np.zeros((len(a), 6, 6))
        C[:, iu[0], iu[1]] = a[:, 7:]
        C[:, iu[1], iu[0]] = a[:, 7:]
        d.update(t_s=a[:, 0], x=a[:, 1:7], C=C)
    return out


def plot_relative_state(t_s, x_rel, x_true=None, *, title):
    """The relative position (m) and velocity (m/s) in LVLH against time (h), x/y/z in
    their own panels, with the truth's relative state dashed. Returns the Figure."""
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
    """Write the plots (module docstring), ``report.md`` and ``report.html`` of the formation's
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
    for sc, r in rel.items():
        x_true = None
        if ref in truths and sc in truths:

            t_ref = np.asarray(traj[ref].t_s, float)
            t_sc = np.asarray(traj[sc].t_s, float)
            xr = states_at(r["t_s"], t_ref, truths[ref])
            xd = states_at(r["t_s"], t_sc, truths[sc])
            x_true = relative_state_lvlh(xr, xd)[0]
        cap = f"{sc} relative to {r['reference']}: state in the LVLH frame of {r['reference']}"
        figs[f"relative_lvlh-{sc}"] = plot_relative_state(
            r["t_s"], r["x"], x_true, title=cap + (" (truth dashed)" if x_true is not None else ""))
        captions[f"relative_lvlh-{sc}"] = cap
        name = f"relative_{'errors' if x_true is not None else 'sigma'}_lvlh-{sc}"
        cap = (f"{sc} relative to {r['reference']}: {label} relative state error in LVLH with "
               f"±{k_sigma:g}σ (joint covariance)" if x_true is not None else
               f"{sc} relative to {r['reference']}: relative state ±{k_sigma:g}σ in LVLH "
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
    """Every spacecraft's orbit on :func:`fgnav.viz.report.plot_orbit_3d`'s axes."""
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
    from fgnav.viz.report import _fmt, _unit

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
    md = [f"# {title}", "", intro, ""] + [f"> note: {n}" for n in notes] + [""]
    md += _table(["metric", "value", "unit"], [list(r) for r in run_rows]) + [""]
    md += ["## Each spacecraft", ""] + _table(["metric", *ids, "unit"], sc_rows) + [""]
    md += [f"## Relative state ({rel.get('frame', 'LVLH')})", ""]
    md += _table(["metric", "value", "unit"], rel_rows) + [""]
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
    for name, p in images.items():
        h += [f"<h2>{esc(captions[name])}</h2>",
              f"<img src='{esc(p.name)}' alt='{esc(captions[name])}'>"]
    h.append("</body></html>")
    atomic_write_text(out / "report.html", "\n".join(h) + "\n")
    return out / "report.md", out / "report.html"
