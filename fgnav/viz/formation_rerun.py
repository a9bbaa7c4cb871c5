"""Rerun recording of a formation's joint solution (several spacecraft, inter-satellite links).

:func:`log_formation` writes one ``.rrd`` file (rerun-sdk >= 0.41, columnar API, as
:mod:`fgnav.viz.rerun_log` does for one spacecraft) holding

* ``world/...`` (3-D, **km**, ECI): the Earth and ECI axes, each spacecraft's estimated
  orbit ``world/<id>/estimate/trajectory`` (a line strip in the spacecraft's named colour,
  :data:`SPACECRAFT_COLORS`) with its state at the time cursor
  (``world/<id>/estimate/state``), with truth ``world/<id>/truth/trajectory`` and ``.../state``
  (a lighter shade of the same colour), and the inter-satellite links at the cursor
  ``world/links/<kind>``: one segment between the two spacecraft per linked pair, coloured by
  the whitened residual (:func:`residual_color`);
* ``lvlh/...`` (3-D, **m**, the reference spacecraft's LVLH frame: x radial, y along-track,
  z orbit normal, :mod:`fgnav.frames`): the reference at the origin, the
  LVLH axes, each further spacecraft's relative trajectory ``lvlh/<id>/estimate/trajectory``
  and position at the cursor, its relative-position covariance ellipsoid at the cursor
  (``lvlh/<id>/covariance_<k>sigma_x<magnification>``), with truth its true relative
  trajectory, and the links at the cursor ``lvlh/links/<kind>`` coloured as in ``world``;
* time series on the ``t_s`` timeline (s from ``epoch0``; also ``utc``), per further
  spacecraft ``<id>``: ``relative/<id>/position_lvlh_m`` (x, y, z of the relative position),
  ``relative/<id>/{errors,sigma}/position_lvlh_m/<axis>`` and ``.../velocity_lvlh_mps/<axis>``
  (with truth the series ``<axis> error, <axis> +kσ, <axis> -kσ``, else ``<axis> +kσ,
  <axis> -kσ``; kσ of the relative covariance with the cross-covariances of the joint
  solution), with truth ``relative/<id>/nees`` (6 dof, with its 95 % band); per spacecraft
  ``spacecraft/<id>/{errors,sigma}/position_rtn_m/<axis>`` and ``.../velocity_rtn_mps/<axis>``
  (its absolute state in its own RTN frame, as the one-spacecraft recording); the whitened
  residuals ``residuals/<kind>/<id>`` (celestial rows per spacecraft) and
  ``residuals/<kind>/<rx>_from_<tx>`` (links, receiver from transmitter).

Link colours (:func:`residual_color`, stated in the recording's ``legend`` document): the
largest ``|whitened residual|`` of that kind's rows on the pair at the epoch (both
directions; for the EKF its innovations normalized by their own covariance, the values its
integrity verdict tests), green at 0, yellow at 1.5, red at 3 (linear in between), magenta beyond 3
(outside the 3-sigma band).

The stored blueprint opens on both 3-D views (ECI orbits framed on the whole orbit, the
LVLH formation framed on the relative trajectory) beside the relative position, its error
(or sigma) and tabs with the relative velocity, each spacecraft's absolute errors, the link
residuals, NEES and the legend; every time plot shows the whole pass.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from factors.constants import R_EARTH_M
from fgnav.frames import relative_state_lvlh
from fgnav.results import relative_rows
from fgnav.viz.rerun_log import (_F_WGS84, AXIS_COLORS, RTN_AXES, _lighter, _safe, _time_index,
                                 auto_magnification, covariance_ellipsoids, error_and_sigma,
                                 nees, orbit_eye, recording_file, spatial_view,
                                 time_series_view, views_blueprint)

__all__ = ["log_formation", "log_formation_result", "residual_color", "SPACECRAFT_COLORS",
           "LVLH_AXES", "link_segments"]

_KM = 1.0e-3

#: Named colours of the spacecraft, in the log's order (the reference first): hues apart
#: from the links' residual scale (green, yellow, red, magenta).
SPACECRAFT_COLORS = (("cyan", [0, 190, 255]), ("violet", [120, 90, 255]),
                     ("teal", [0, 140, 130]), ("grey", [170, 170, 170]),
                     ("navy", [30, 40, 140]), ("brown", [140, 90, 40]))

#: LVLH axis names: x radial, y along-track, z orbit normal.
LVLH_AXES = ("x", "y", "z")
_LVLH_WORDS = ("radial", "along-track", "normal")

#: Anchors of the residual colour scale: (|whitened residual|, RGB).
_SCALE = ((0.0, (44, 160, 44)), (1.5, (255, 210, 0)), (3.0, (214, 39, 40)))
_BEYOND = (200, 0, 200)


def spacecraft_color(s: int) -> tuple[str, list[int]]:
    """(name, RGB) of the ``s``-th spacecraft (0-based; the palette repeats after six)."""
    return SPACECRAFT_COLORS[s % len(SPACECRAFT_COLORS)]


def residual_color(w) -> np.ndarray:
    """RGB (M, 3) uint8 of whitened residual magnitudes ``w`` (M,): green at 0, yellow at 1.5,
    red at 3, linear in between, magenta beyond 3; grey for a non-finite value."""
    a = np.abs(np.asarray(w, float).reshape(-1))
    xs = [s for s, _ in _SCALE]
    out = np.stack([np.interp(a, xs, [c[i] for _, c in _SCALE]) for i in range(3)], axis=1)
    out[a > xs[-1]] = _BEYOND
    out[~np.isfinite(a)] = (128, 128, 128)
    return np.round(out).astype(np.uint8)


def link_segments(sol, p):
    """The links per kind: ``kind -> (k (L,), s_rx (L,), s_tx (L,), |w| (L,))``, one entry per
    epoch ``k`` and unordered pair of spacecraft indices (``s_rx < s_tx`` after ordering),
    ``|w|`` the largest ``|whitened residual|`` of the kind's rows on that pair at that epoch.
    Kinds whose residuals do not match their rows (none logged) are left out."""
    from fgnav.measurements import orbit_columns
    from fgnav.io.log_spacecraft import ISL_KINDS
    from fgnav.models.model import COLUMN_PREFIX

    start = orbit_columns(p.layout)
    sc_of_col = {int(c): s for s, c in enumerate(start)}
    out = {}
    for kind in ISL_KINDS:
        fam = p.families.get(kind)
        r = _tested_residuals(sol).get(kind)
        if fam is None or r is None or len(r) != len(fam.k):
            continue
        a = np.array([sc_of_col[int(c)] for c in fam.values[COLUMN_PREFIX + "orbit"]])
        b = np.array([sc_of_col[int(c)] for c in fam.values[COLUMN_PREFIX + "orbit_tx"]])
        w = np.max(np.abs(np.asarray(r, float).reshape(len(r), -1)), axis=1)
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        key = np.stack([np.asarray(fam.k), lo, hi], axis=1)
        uniq, inv = np.unique(key, axis=0, return_inverse=True)
        wmax = np.full(len(uniq), -np.inf)
        np.maximum.at(wmax, inv.reshape(-1), w)
        out[kind] = (uniq[:, 0], uniq[:, 1], uniq[:, 2], wmax)
    return out


def _tested_residuals(sol) -> dict:
    """The whitened residuals the integrity verdict tests
    (:func:`fgnav.diagnostics.integrity.assess`): a filter's innovations normalized
    by their own covariance, else the solution's whitened residuals."""
    return (sol.extras or {}).get("normalized_innovations") or sol.residuals or {}


def log_formation_result(rrd_path, res, p, *, truth=None, sigma_scale=3.0) -> dict:
    """:func:`log_formation` of ``fgnav smooth``'s formation result (``res``, ``p``); with
    ``truth`` (the ``--truth`` directory) each spacecraft's ``truth-<id>.oem``."""
    from fgnav.pipeline import read_formation_truth
    from fgnav.orbit import truth_at

    truths = None
    if truth is not None:
        truths = [truth_at(t, x, res.solution.t_s) for t, x in read_formation_truth(truth, p)]
    return log_formation(rrd_path, res.solution, p, truths=truths, sigma_scale=sigma_scale)


def log_formation(rrd_path, sol, p, *, truths=None, sigma_scale=3.0,
                  application_id="fgnav") -> dict:
    """Write the Rerun recording of a formation's solution ``sol`` of the pass ``p`` (module
    docstring). ``truths``: None or per spacecraft (N, 6) true ECI states at ``sol.t_s``
    (m, m/s). Returns ``{"path", "entities", "epochs", "magnification"}``."""
    import rerun as rr

    from fgnav.measurements import spacecraft_states

    t_s = np.asarray(sol.t_s, float)
    n = len(t_s)
    ids = tuple(p.spacecraft)
    states = spacecraft_states(sol, p.layout)
    k = float(sigma_scale)
    rel = {}
    for j in range(1, len(ids)):
        x_rel, C, _ = relative_rows(sol, p, j)
        x_true = None if truths is None else relative_state_lvlh(truths[0], truths[j])[0]
        rel[ids[j]] = (x_rel, C, x_true)
    links = link_segments(sol, p)
    path = Path(rrd_path)
    path.parent.mkdir(parents=True, exist_ok=True)
    x0 = states[0][0]
    fin = np.all(np.isfinite(x0), axis=1)
    eye, up = orbit_eye(x0[fin, :3], x0[fin, 3:])
    blueprint = formation_blueprint(ids, has_truth=truths is not None, links=sorted(links),
                                    t_range_s=(t_s[0], t_s[-1]) if n else None, eye_km=eye,
                                    eye_up=up, lvlh_eye=_lvlh_eye(rel))
    with recording_file(path, blueprint, application_id) as rec:
        log = _Logger(rec, rr, sol.epoch0, t_s)
        log.scene(ids, states, truths)
        mag = log.lvlh(ids, rel, k)
        log.links(ids, states, rel, links)
        log.series(ids, states, truths, rel, k)
        log.residuals(sol, p)
        log.static("legend", rr.TextDocument(legend_text(ids, k, mag, truths is not None),
                                             media_type="text/markdown"))
    return {"path": str(path), "entities": log.entities, "epochs": n, "magnification": mag}


class _Logger:
    """Sends the entities of one recording and remembers their paths."""

    def __init__(self, rec, rr, epoch0, t_s):
        self.rec, self.rr, self.epoch0, self.t_s = rec, rr, epoch0, t_s
        self.entities: list[str] = []

    def static(self, entity, archetype):
        self.rec.log(entity, archetype, static=True)
        self.entities.append(entity)

    def send(self, entity, times, columns):
        self.rec.send_columns(entity, indexes=_time_index(self.rr, self.epoch0, times),
                              columns=columns)
        self.entities.append(entity)

    def points(self, entity, pos, color, radius=5.0):
        n = len(pos)
        self.send(entity, self.t_s, self.rr.Points3D.columns(
            positions=pos, colors=np.repeat([color], n, axis=0),
            radii=np.full(n, -radius)).partition(np.ones(n, int)))

    def line(self, entity, pos, color, label, width):
        ok = np.all(np.isfinite(pos), axis=1)
        self.static(entity, self.rr.LineStrips3D([pos[ok]], colors=[color], labels=[label],
                                                 show_labels=False,
                                                 radii=[self.rr.Radius.ui_points(width)]))

    def plot(self, entity, values, names, colors, widths):
        rr = self.rr
        self.static(entity, rr.SeriesLines(names=names, colors=colors, widths=widths))
        self.rec.send_columns(entity, indexes=_time_index(rr, self.epoch0, self.t_s),
                              columns=rr.Scalars.columns(scalars=np.asarray(values, float)))

    def error_series(self, root, block, axes, err, sig, k):
        """``<root>/{errors,sigma}/<block>/<axis>``: error and ±kσ (or ±kσ alone)."""
        for i, ax in enumerate(axes):
            col, light = AXIS_COLORS[i], _lighter(AXIS_COLORS[i])
            b = k * sig[:, i]
            if err is not None:
                self.plot(f"{root}/errors/{block}/{ax}", np.stack([err[:, i], b, -b], axis=1),
                          [f"{ax} error", f"{ax} +{k:g}σ", f"{ax} -{k:g}σ"], [col, light, light],
                          [2.0, 1.0, 1.0])
            else:
                self.plot(f"{root}/sigma/{block}/{ax}", np.stack([b, -b], axis=1),
                          [f"{ax} +{k:g}σ", f"{ax} -{k:g}σ"], [col, col], [1.5, 1.5])

    # ---- ECI scene (km) --------------------------------------------------------------
    def scene(self, ids, states, truths):
        rr = self.rr
        self.static("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP)
        re_km = R_EARTH_M * _KM
        self.static("world/earth", rr.Ellipsoids3D(
            half_sizes=[[re_km, re_km, re_km * (1.0 - _F_WGS84)]], colors=[[40, 90, 170]],
            fill_mode="solid", labels=["Earth (WGS-84)"], show_labels=False))
        self.static("world/eci_axes", rr.Arrows3D(
            origins=np.zeros((3, 3)), vectors=np.eye(3) * 1.5 * re_km,
            colors=[[230, 60, 60], [60, 200, 60], [80, 120, 255]],
            labels=["X_eci", "Y_eci", "Z_eci"]))
        for s, (sc, (x, _)) in enumerate(zip(ids, states)):
            name, col = spacecraft_color(s)
            r_km = np.asarray(x, float)[:, :3] * _KM
            self.line(f"world/{_safe(sc)}/estimate/trajectory", r_km, col,
                      f"{sc} estimate ({name})", 1.5)
            self.points(f"world/{_safe(sc)}/estimate/state", r_km, col)
            if truths is not None:
                rt_km = np.asarray(truths[s], float)[:, :3] * _KM
                self.line(f"world/{_safe(sc)}/truth/trajectory", rt_km, _lighter(col, 0.6),
                          f"{sc} truth", 1.0)
                self.points(f"world/{_safe(sc)}/truth/state", rt_km, _lighter(col, 0.6), 3.0)

    # ---- LVLH scene (m) --------------------------------------------------------------
    def lvlh(self, ids, rel, k) -> float:
        """The reference's LVLH frame; returns the covariance ellipsoids' magnification."""
        rr = self.rr
        self.static("lvlh", rr.ViewCoordinates.RIGHT_HAND_Z_UP)
        size = _lvlh_size(rel)
        self.static("lvlh/axes", rr.Arrows3D(
            origins=np.zeros((3, 3)), vectors=np.eye(3) * 0.3 * size,
            colors=[[230, 60, 60], [60, 200, 60], [80, 120, 255]],
            labels=[f"x {_LVLH_WORDS[0]}", f"y {_LVLH_WORDS[1]}", f"z {_LVLH_WORDS[2]}"]))
        name, col = spacecraft_color(0)
        self.static(f"lvlh/{_safe(ids[0])}", rr.Points3D(
            [[0.0, 0.0, 0.0]], colors=[col], radii=[-6.0], labels=[f"{ids[0]} (reference)"]))
        mags = []
        for j, sc in enumerate(ids[1:], start=1):
            x_rel, C, x_true = rel[sc]
            _, col = spacecraft_color(j)
            r = x_rel[:, :3]
            self.line(f"lvlh/{_safe(sc)}/estimate/trajectory", r, col, f"{sc} estimate", 1.5)
            self.points(f"lvlh/{_safe(sc)}/estimate/state", r, col, 6.0)
            if x_true is not None:
                self.line(f"lvlh/{_safe(sc)}/truth/trajectory", x_true[:, :3], _lighter(col, 0.6),
                          f"{sc} truth", 1.0)
            ok = np.all(np.isfinite(C[:, :3, :3].reshape(len(C), -1)), axis=1) & \
                np.all(np.isfinite(r), axis=1)
            if not np.any(ok):
                continue
            half, q_wxyz = covariance_ellipsoids(C[ok, :3, :3], k)
            mag = auto_magnification(half, np.full((1, 3), size))
            mags.append(mag)
            q_xyzw = np.concatenate([q_wxyz[:, 1:], q_wxyz[:, :1]], axis=1)
            m = int(ok.sum())
            self.send(f"lvlh/{_safe(sc)}/covariance_{k:g}sigma_x{mag:g}".replace(".", "p"),
                      self.t_s[ok], rr.Ellipsoids3D.columns(
                          centers=r[ok], half_sizes=half * mag, quaternions=q_xyzw,
                          colors=np.repeat([col + [110]], m, axis=0)).partition(np.ones(m, int)))
        return mags[0] if mags else 1.0

    # ---- links -----------------------------------------------------------------------
    def links(self, ids, states, rel, links):
        rr = self.rr
        pos_lvlh = [np.zeros((len(self.t_s), 3))] + [rel[sc][0][:, :3] for sc in ids[1:]]
        for kind, (kk, a, b, w) in links.items():
            colors = residual_color(w)
            tu, counts = np.unique(kk, return_counts=True)
            labels = [f"{ids[i]}–{ids[j]}: |w| {v:.2f}" for i, j, v in zip(a, b, w)]
            for root, pos, scale in (("world", [x for x, _ in states], _KM), ("lvlh", pos_lvlh, 1.0)):
                strips = [np.stack([pos[i][t, :3], pos[j][t, :3]]) * scale
                          for t, i, j in zip(kk, a, b)]
                self.send(f"{root}/links/{_safe(kind)}", self.t_s[tu], rr.LineStrips3D.columns(
                    strips=strips, colors=colors, labels=labels, show_labels=np.zeros(len(strips), bool),
                    radii=np.full(len(strips), -3.0)).partition(counts))

    # ---- time series -----------------------------------------------------------------
    def series(self, ids, states, truths, rel, k):
        from scipy.stats import chi2 as chi2_dist

        for sc in ids[1:]:
            x_rel, C, x_true = rel[sc]
            root = f"relative/{_safe(sc)}"
            self.plot(f"{root}/position_lvlh_m", x_rel[:, :3],
                      [f"{a} {w}" for a, w in zip(LVLH_AXES, _LVLH_WORDS)],
                      [list(c) for c in AXIS_COLORS], [2.0] * 3)
            sig = np.sqrt(np.clip(np.diagonal(C, axis1=1, axis2=2), 0.0, None))
            err = None if x_true is None else x_rel - x_true
            for block, off in (("position_lvlh_m", 0), ("velocity_lvlh_mps", 3)):
                self.error_series(root, block, LVLH_AXES, None if err is None else err[:, off:off + 3],
                                  sig[:, off:off + 3], k)
            if x_true is not None:
                lo, hi = chi2_dist.ppf([0.025, 0.975], 6)
                nv = nees(x_rel, C, x_true)
                self.plot(f"{root}/nees", np.stack([nv, np.full_like(nv, 6.0), np.full_like(nv, lo),
                                                    np.full_like(nv, hi)], axis=1),
                          ["NEES", "expected (6)", "2.5 %", "97.5 %"],
                          [[31, 119, 180], [44, 160, 44], [150, 150, 150], [150, 150, 150]],
                          [1.5, 1.0, 1.0, 1.0])
        for s, (sc, (x, P)) in enumerate(zip(ids, states)):
            err, sig = error_and_sigma(x, P, None if truths is None else truths[s], frame="rtn")
            for block, off in (("position_rtn_m", 0), ("velocity_rtn_mps", 3)):
                self.error_series(f"spacecraft/{_safe(sc)}", block, RTN_AXES,
                                  None if err is None else err[:, off:off + 3],
                                  sig[:, off:off + 3], k)

    def residuals(self, sol, p):
        """Whitened residuals per kind: celestial rows per spacecraft, links per direction."""
        from fgnav.measurements import orbit_columns
        from fgnav.io.log_spacecraft import ISL_KINDS
        from fgnav.models.model import COLUMN_PREFIX

        rr = self.rr
        sc_of_col = {int(c): s for s, c in enumerate(orbit_columns(p.layout))}
        ids = p.spacecraft
        for kind, r in (sol.residuals or {}).items():
            fam = p.families.get(kind)
            r = np.asarray(r, float)
            if fam is None or len(r) != len(fam.k) or not len(r):
                continue
            r = r.reshape(len(r), -1)
            rx = np.array([sc_of_col[int(c)] for c in fam.values[COLUMN_PREFIX + "orbit"]])
            tx = (np.array([sc_of_col[int(c)] for c in fam.values[COLUMN_PREFIX + "orbit_tx"]])
                  if kind in ISL_KINDS else None)
            groups = {}
            for i in range(len(r)):
                name = ids[rx[i]] if tx is None else f"{ids[rx[i]]}_from_{ids[tx[i]]}"
                groups.setdefault(name, []).append(i)
            for name, rows in groups.items():
                rows = np.array(rows)
                ent = f"residuals/{_safe(kind)}/{_safe(name)}"
                names = [f"{name} {kind}[{c}]" for c in range(r.shape[1])]
                self.static(ent, rr.SeriesPoints(names=names, marker_sizes=[2.0] * len(names)))
                self.rec.send_columns(ent, indexes=_time_index(rr, self.epoch0,
                                                               self.t_s[np.asarray(fam.k)[rows]]),
                                      columns=rr.Scalars.columns(scalars=r[rows]))


def _lvlh_size(rel) -> float:
    """The largest relative distance of the pass (m), at least 1 m."""
    sizes = [np.nanmax(np.linalg.norm(x[:, :3], axis=1)) for x, _, _ in rel.values() if len(x)]
    return float(max([1.0] + [s for s in sizes if np.isfinite(s)]))


def _lvlh_eye(rel):
    """Camera of the LVLH view: ``(position, look target, up)`` in m, looking at the middle
    of the relative trajectories (and the reference at the origin) from 1.6 times their
    extent, from as close to the orbit normal (z) as keeps the trajectories' main direction
    across the view (the Hill-frame plot of radial against along-track when the motion is in
    that plane), radial up."""
    pts = [np.zeros((1, 3))] + [x[:, :3][np.all(np.isfinite(x[:, :3]), axis=1)]
                                for x, _, _ in rel.values()]
    pts = np.concatenate(pts)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    c = 0.5 * (lo + hi)
    ext = max(float(np.linalg.norm(hi - lo)), 1.0)
    v1 = np.linalg.svd(pts - pts.mean(axis=0), full_matrices=False)[2][0]
    d = np.array([0.0, 0.0, 1.0]) - v1[2] * v1
    d = d / np.linalg.norm(d) if np.linalg.norm(d) > 1e-6 else np.array([1.0, 0.0, 0.0])
    up = np.array([1.0, 0.0, 0.0]) - d[0] * d
    up = up / np.linalg.norm(up) if np.linalg.norm(up) > 1e-6 else np.array([0.0, 1.0, 0.0])
    return c + 1.6 * ext * d, c, up


def formation_blueprint(ids, *, has_truth, links=(), t_range_s=None, eye_km=None, eye_up=None,
                        lvlh_eye=None):
    """The default layout (module docstring)."""
    import rerun.blueprint as rrb

    what = "error" if has_truth else "±3σ"
    root = "errors" if has_truth else "sigma"
    ref = ids[0]
    right, tabs = [], []
    for sc in ids[1:]:
        r = f"relative/{_safe(sc)}"
        right.append(time_series_view(f"{r}/position_lvlh_m", f"{sc} relative to {ref}: "
                                      "position in LVLH x/y/z [m]", t_range_s))
        right.append(time_series_view(f"{r}/{root}/position_lvlh_m", f"{sc} relative position "
                                      f"{what} LVLH x/y/z [m]", t_range_s))
        tabs.append(time_series_view(f"{r}/{root}/velocity_lvlh_mps", f"{sc} relative velocity "
                                     f"{what} LVLH x/y/z [m/s]", t_range_s))
        if has_truth:
            tabs.append(time_series_view(f"{r}/nees", f"{sc} relative NEES (6 dof)", t_range_s))
    for sc in ids:
        tabs.append(time_series_view(f"spacecraft/{_safe(sc)}/{root}/position_rtn_m",
                                     f"{sc} position {what} R/T/N [m]", t_range_s))
    if links:
        tabs.append(time_series_view("residuals", "whitened residuals [-]", t_range_s))
    tabs.append(rrb.TextDocumentView(origin="legend", name="legend"))
    right.append(rrb.Tabs(*tabs))
    world = spatial_view("world", "orbits (ECI, km)", eye_km, (0.0, 0.0, 0.0), eye_up)
    lvlh = spatial_view("lvlh", f"formation in the LVLH frame of {ref} (m)",
                        *(lvlh_eye if lvlh_eye is not None else ()))
    return views_blueprint(rrb.Vertical(world, lvlh, row_shares=[1, 1]), rrb.Vertical(*right))


def legend_text(ids, k, mag, has_truth) -> str:
    """The recording's ``legend`` document (markdown)."""
    sc = ", ".join(f"**{s}** {spacecraft_color(i)[0]}" for i, s in enumerate(ids))
    return "\n".join([
        f"# fgnav — formation of {len(ids)} spacecraft",
        f"- spacecraft colours: {sc}; truth in a lighter shade of the same colour.",
        "- `world`: ECI, **km**; Earth = WGS-84 ellipsoid (not rotated).",
        f"- `lvlh`: the LVLH frame of **{ids[0]}** (the reference, at the origin), **m**: "
        "x radial (red axis), y along-track (green), z orbit normal (blue); relative-position "
        f"ellipsoids **{k:g}σ x {mag:g}** (magnified {mag:g} times).",
        "- links (segments between the two spacecraft at the time cursor), colour = the "
        "largest |whitened residual| of the kind's rows on that pair at that epoch:",
        "  - 0 green → 1.5 yellow → 3 red (linear in between)",
        "  - above 3 (outside the 3σ band): magenta",
        f"- time series: {'errors (estimate − truth)' if has_truth else 'sigmas'} with "
        f"±{k:g}σ; the relative state's σ from the joint covariance (cross terms included); "
        "each spacecraft's absolute state in its own RTN frame.",
        "- residuals: whitened (expected standard normal); links as receiver_from_transmitter.",
    ])
