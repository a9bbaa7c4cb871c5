"""Measurements of one pass, grouped by epoch and by kind, ready for graph assembly.

A :class:`MeasurementLog` (one row per CSV line) becomes a :class:`Pass`: the sorted unique
epochs ``t_s`` (one state per epoch) and, per measurement family, arrays indexed by the
epoch index ``k``. Body-frame directions are rotated into ECI with the attitude measured at
the same epoch (``u_eci = R_eci_from_body u_body``), their variance increased by the
attitude's (a body-frame direction with a known attitude).

A log of S >= 2 spacecraft (its ``spacecraft`` column, :mod:`fgnav.io.log_spacecraft`)
becomes one pass whose per-epoch block holds one orbit state per spacecraft
(:func:`fgnav.models.variables.orbit_variable`; the first spacecraft's is the usual orbit
state, so every solver's orbit columns are its), then a relative clock bias per linked pair
and a carrier ambiguity per carrier-phase link (:func:`~fgnav.models.variables.clock_variable`,
:func:`~fgnav.models.variables.ambiguity_variable`). Each row is bound to the variables of
its own spacecraft (its ``col:`` values, :meth:`fgnav.models.model.MeasurementModel.evaluate`):
celestial rows to their spacecraft's orbit, a link (:mod:`fgnav.models.isl`) to the orbits of
both ends and to the pair's clock. Between epochs every orbit follows the motion model and
every clock its random walk, so the batch solver's chain (one block per epoch) carries the
whole formation; the links make the blocks' orbits dependent, and the marginal covariance of
a block gives the relative state's covariance with the cross terms (Bar-Shalom, Li &
Kirubarajan 2001, sec. 1.4: the covariance of a linear function of jointly Gaussian states).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from fgnav.errors import UserError
from fgnav.io.log_spacecraft import ISL_KINDS, spacecraft_index
from fgnav.models.isl import isl_values, pair_ids
from fgnav.models.manoeuvres import MANOEUVRE_KIND, manoeuvre_values
from fgnav.models.model import COLUMN_PREFIX
from fgnav.models.registry import (ATTITUDE, ATTITUDE_RATE, ATTITUDE_VARIABLE,
                                   EARTH_DIRECTION_BODY, GYRO, GYRO_BIAS, MODELS, MOON_DIRECTION_BODY,
                                   PRIOR_POSITION, PRIOR_VELOCITY, STAR_DIRECTION_BODY,
                                   SUN_DIRECTION_BODY, VARIABLES, variable)
from fgnav.models.variables import (ORBIT, Layout, ambiguity_variable, clock_variable,
                                    orbit_variable, spacecraft_variable)
from fgnav.vision.attitude import wahba_by_epoch


@dataclass
class Family:
    """One measurement family: rows at epoch indices ``k`` with values and 1σ."""

    k: np.ndarray                 # (M,) epoch index of each row
    values: dict[str, np.ndarray]  # per-family arrays, first axis M
    sigma: np.ndarray             # (M,) 1σ in the family's unit
    line: np.ndarray              # (M,) source line numbers (for messages)

    def __len__(self) -> int:
        return len(self.k)

    def subset(self, rows: np.ndarray, k_new: int | None = None) -> "Family":
        """The given rows only; with ``k_new`` their epoch index is replaced (e.g. by 0 to
        evaluate them on a single state)."""
        k = self.k[rows] if k_new is None else np.full(len(rows), k_new)
        return Family(k=k, values={n: v[rows] for n, v in self.values.items()},
                      sigma=self.sigma[rows], line=self.line[rows])


@dataclass
class Pass:
    """A pass: unique epochs and the measurement families attached to them."""

    epoch0: np.datetime64
    t_s: np.ndarray                              # (N,) unique epochs, seconds from epoch0
    families: dict[str, Family] = field(default_factory=dict)
    source: str = ""
    warnings: list[str] = field(default_factory=list)
    inserted: np.ndarray | None = None           # (N,) bool: epoch added by fill_gaps
    # Arcs (fgnav.solvers.arcs): epoch indices where a new, separately solved arc starts
    # (a gap too long to bridge), each with its a-priori state (6,) and 1-sigma
    # (position m, velocity m/s) predicted across the gap; notes on every long gap.
    breaks: tuple[int, ...] = ()
    arc_priors: list = field(default_factory=list)
    gap_notes: list = field(default_factory=list)
    layout: Layout = field(default_factory=Layout)  # per-epoch graph variables (orbit first)
    # Families that enter the graphs only when a variable they need is estimated (body-frame
    # directions, attitude rows: the attitude); until then they enter through a conversion
    # (body -> ECI with the measured attitude), see build_pass and with_estimates.
    deferred: dict[str, Family] = field(default_factory=dict)
    # body-frame rows at epochs without an attitude row: kind -> their source lines (they
    # enter only with the attitude estimated)
    unconverted: dict[str, np.ndarray] = field(default_factory=dict)
    # a formation's spacecraft ids, in the log's order (empty: one spacecraft); their orbit
    # states are the layout's orbit variables (build_pass)
    spacecraft: tuple[str, ...] = ()
    # a formation's relative positions fixed from one epoch's links alone (t_s (F,), the
    # second spacecraft's position minus the first's, ECI (F, 3), m): its first guess, set by
    # the formation's start (fgnav.start.link_fixes, set by fgnav.pipeline.smooth_log), not by build_pass
    link_fixes: tuple | None = None
    centre: str = "earth"   # the log's central body (its "# centre:" line): the motion model's
    # declared manoeuvres (``manoeuvre`` rows, values ``dv_mps`` (M, 3), sigma m/s): each
    # enters the motion of the step that ends at its epoch (fgnav.graph.impulses); None: none
    manoeuvres: Family | None = None

    @property
    def n_epochs(self) -> int:
        return len(self.t_s)

    def count(self, kind: str) -> int:
        fam = self.families.get(kind)
        return 0 if fam is None else len(fam)

    def counts(self) -> dict[str, int]:
        return {k: len(f) for k, f in self.families.items()}


def rows_by_epoch(p: Pass) -> list[list[tuple[str, np.ndarray]]]:
    """For each epoch, the (kind, row indices) of its measurements."""
    out: list[list[tuple[str, np.ndarray]]] = [[] for _ in range(p.n_epochs)]
    for kind, fam in p.families.items():
        order = np.argsort(fam.k, kind="stable")
        ks = fam.k[order]
        bounds = np.flatnonzero(np.diff(ks)) + 1
        for grp in np.split(order, bounds):
            if len(grp):
                out[int(fam.k[grp[0]])].append((kind, grp))
    return out


def build_pass(log) -> Pass:
    """Group a :class:`fgnav.io.log_csv.MeasurementLog` by epoch into a :class:`Pass`.

    One family per kind that enters the graphs (its model's ``values`` from the log rows),
    plus the ``attitude`` rows; a body-frame kind (``body_frame_of``) joins its ECI family,
    rotated with the attitude measured at the same epoch. A body-frame row at an epoch
    without an attitude row waits (``Pass.unconverted``) for the attitude to be estimated
    (star or attitude rows fix it, gyro rows carry it between them; :func:`check_observable`
    refuses the pass otherwise, naming the rows).

    A log of several spacecraft: one orbit per spacecraft in the block, the links' clocks
    and ambiguities after them (module docstring, :func:`_formation_pass`).
    """
    if getattr(log, "n_spacecraft", 1) > 1:
        return _formation_pass(log)
    t_unique, k_of_row = np.unique(np.asarray(log.t_s, dtype=float), return_inverse=True)
    kinds = np.asarray(log.kind)
    xyz = np.asarray(log.xyz, dtype=float)
    sigma = np.asarray(log.sigma, dtype=float)
    lines = np.asarray(log.line)
    p = Pass(epoch0=log.epoch0, t_s=t_unique, source=str(log.path), warnings=list(log.warnings),
             centre=getattr(log, "centre", "earth"))
    for kind, mdl in MODELS.items():
        i = np.flatnonzero(kinds == kind)
        if mdl.between and len(i) and np.any(k_of_row[i] == 0):
            # a row at the first epoch has no interval before it in the log
            p.warnings.append(f"{kind}: {int(np.sum(k_of_row[i] == 0))} row(s) at the first "
                              f"epoch ignored (no earlier epoch to start the interval)")
            i = i[k_of_row[i] > 0]
        if not len(i):
            continue
        fam = Family(k=k_of_row[i], values=mdl.values(log, i), sigma=sigma[i], line=lines[i])
        if mdl.requires is not None:
            p.deferred[kind] = fam
        elif mdl.solved:
            p.families[kind] = fam
    i = np.flatnonzero(kinds == MANOEUVRE_KIND)
    if len(i):
        if np.any(k_of_row[i] == 0):
            j = i[np.flatnonzero(k_of_row[i] == 0)[0]]
            raise UserError(f"{log.path}: line {int(lines[j])}: a manoeuvre at the first epoch "
                            "of the log has no step before it to enter; expected a manoeuvre "
                            "after the first epoch (the a-priori state is the state after any "
                            "earlier burn)")
        p.manoeuvres = Family(k=k_of_row[i], values=manoeuvre_values(log, i), sigma=sigma[i],
                              line=lines[i])
    att = p.deferred.get(ATTITUDE.kind)
    if att is not None:
        p.families[ATTITUDE.kind] = att   # rows of their own kind (used for body -> ECI)
    for body_kind, mdl in MODELS.items():
        i = np.flatnonzero(kinds == body_kind)
        if mdl.body_frame_of is None or not len(i):
            continue
        body = Family(k=k_of_row[i], values=mdl.values(log, i), sigma=sigma[i], line=lines[i])
        new, missing = _rotated_to_eci(body, att)
        if len(missing):
            p.unconverted[body_kind] = missing
        if len(new):
            p.families[mdl.body_frame_of] = _merged(p.families.get(mdl.body_frame_of), new)
    return p


_PLAIN_REFUSED = "is not yet supported with several spacecraft"


def _check_formation_kinds(log):
    """Refuse the kinds a formation's pass does not yet take (those that need a further
    variable a formation does not bind per spacecraft: star directions, body directions of
    a near body), naming them."""
    kinds = set(np.unique(np.asarray(log.kind).astype(str)).tolist())
    for kind in sorted(kinds):
        if kind in ISL_KINDS or kind in (ATTITUDE.kind, GYRO.kind):
            continue
        if kind == MANOEUVRE_KIND:
            raise UserError(f"{log.path}: 'manoeuvre' rows {_PLAIN_REFUSED}: a burn changes "
                            "one spacecraft's orbit, and a formation's graph does not yet put "
                            "an impulse into one spacecraft's motion (solve each spacecraft's "
                            "rows on their own, or leave the rows out)")
        mdl = MODELS.get(kind)
        if mdl is None or mdl.between or (mdl.requires is not None and mdl.body_frame_of is None):
            raise UserError(f"{log.path}: '{kind}' rows {_PLAIN_REFUSED} (a formation's log "
                            "may hold priors, ECI and body-frame directions, limb, altitude, "
                            "refraction and angle rows per spacecraft, attitude and gyro rows, "
                            "and inter-satellite rows)")


def orbit_columns(lay: Layout) -> np.ndarray:
    """First block column of each spacecraft's orbit state (S,)."""
    return np.array([lay.slices[v.name].start for v in lay.orbits], dtype=int)


def _formation_pass(log) -> Pass:
    """The pass of a log with several spacecraft (module docstring): celestial and prior rows
    bound to their spacecraft's orbit columns, attitude rows deferred (the links' lever arms,
    the body frame's outputs), the links' per-row variable names turned into block columns."""
    _check_formation_kinds(log)
    ids = tuple(log.spacecraft)
    sc = spacecraft_index(log)
    t_unique, k_of_row = np.unique(np.asarray(log.t_s, dtype=float), return_inverse=True)
    kinds = np.asarray(log.kind)
    sigma = np.asarray(log.sigma, dtype=float)
    lines = np.asarray(log.line)
    orbits = tuple(orbit_variable(i, s) for i, s in enumerate(ids))
    isl, extra_vars = isl_families(log, k_of_row)
    lay = Layout(orbits + tuple(extra_vars))
    start = orbit_columns(lay)
    p = Pass(epoch0=log.epoch0, t_s=t_unique, source=str(log.path), warnings=list(log.warnings),
             layout=lay, spacecraft=ids, centre=getattr(log, "centre", "earth"))
    body_kinds = []
    for kind, mdl in MODELS.items():
        i = np.flatnonzero(kinds == kind)
        if not len(i) or kind in isl:
            continue   # (the links' families: isl_families above)
        if mdl.body_frame_of is not None:
            body_kinds.append((kind, i))
            continue
        if mdl.between and np.any(k_of_row[i] == 0):   # as build_pass: no interval before
            p.warnings.append(f"{kind}: {int(np.sum(k_of_row[i] == 0))} row(s) at the first "
                              f"epoch ignored (no earlier epoch to start the interval)")
            i = i[k_of_row[i] > 0]
            if not len(i):
                continue
        if not mdl.solved or (mdl.requires is not None and mdl not in (ATTITUDE, GYRO)):
            continue
        values = dict(mdl.values(log, i))
        values[COLUMN_PREFIX + "orbit"] = start[sc[i]]
        fam = Family(k=k_of_row[i], values=values, sigma=sigma[i], line=lines[i])
        if mdl is ATTITUDE:   # known attitudes: the links' lever arms, the body frame's outputs
            p.deferred[kind] = fam
        elif mdl is GYRO:   # each spacecraft's gyro: joins with its estimated attitude
            p.deferred[kind] = fam
        else:
            p.families[kind] = fam
    for kind, i in body_kinds:   # per spacecraft as build_pass: to ECI with its attitude rows
        mdl = MODELS[kind]
        values = dict(mdl.values(log, i))
        values[COLUMN_PREFIX + "orbit"] = start[sc[i]]
        body = Family(k=k_of_row[i], values=values, sigma=sigma[i], line=lines[i])
        p.deferred[kind] = body
        att = p.deferred.get(ATTITUDE.kind)
        missing = []
        for col in np.unique(start[sc[i]]):
            own = np.flatnonzero(body.values[COLUMN_PREFIX + "orbit"] == col)
            own_att = None if att is None else _rows_of(att, col)
            new, miss = _rotated_to_eci(body.subset(own), own_att)
            missing.append(miss)
            if len(new):
                new.values[COLUMN_PREFIX + "orbit"] = np.full(len(new), col, dtype=int)
                p.families[mdl.body_frame_of] = _merged_rows(p.families.get(mdl.body_frame_of),
                                                             new)
        missing = np.sort(np.concatenate(missing))
        if len(missing):
            p.unconverted[kind] = missing
    for kind, fam in isl.items():   # per-row variable names ("var:<role>") -> block columns
        for key in [k for k in fam.values if k.startswith("var:")]:
            names = np.asarray(fam.values.pop(key)).astype(str)
            fam.values[COLUMN_PREFIX + key[4:]] = np.array([lay.slices[n].start for n in names],
                                                           dtype=int)
        p.families[kind] = fam
    return p


def _rows_of(fam: Family | None, col: int) -> Family | None:
    """The rows of a formation's family bound to the orbit whose first column is ``col``
    (one spacecraft's rows), or None when it has none."""
    if fam is None:
        return None
    rows = np.flatnonzero(np.asarray(fam.values[COLUMN_PREFIX + "orbit"]) == col)
    return fam.subset(rows) if len(rows) else None


def _merged_rows(old: Family | None, new: Family) -> Family:
    """:func:`_merged` for a formation's families, whose rows also carry their variables'
    columns (``col:`` values): every value array concatenated, sorted by epoch."""
    if old is None:
        return new
    order = np.argsort(np.concatenate([old.k, new.k]), kind="stable")
    values = {}
    for key in old.values:
        a = old.values[key]
        if key == "from_body" and key not in new.values:
            values[key] = np.concatenate([a, np.zeros(len(new), bool)])[order]
        else:
            values[key] = np.concatenate([a, new.values[key]])[order]
    if "from_body" not in old.values:
        values["from_body"] = np.concatenate([np.zeros(len(old), bool),
                                              new.values["from_body"]])[order]
    return Family(k=np.concatenate([old.k, new.k])[order], values=values,
                  sigma=np.concatenate([old.sigma, new.sigma])[order],
                  line=np.concatenate([old.line, new.line])[order])


def isl_families(log, k_of_row):
    """The inter-satellite families of a formation's log and the variables they add (the
    pairs' clocks, the carrier links' ambiguities), in a fixed order: ``({kind: Family},
    [Variable, ...])``."""
    kinds = np.asarray(log.kind)
    fams, clocks, ambiguities = {}, {}, {}
    for kind in ISL_KINDS:
        i = np.flatnonzero(kinds == kind)
        if not len(i):
            continue
        values = isl_values(log, i, k_of_row)
        for name in values["var:clock"]:
            clocks.setdefault(str(name), None)
        for name in values.get("var:ambiguity", ()):
            ambiguities.setdefault(str(name), None)
        fams[kind] = Family(k=k_of_row[i], values=values,
                            sigma=np.asarray(log.sigma, dtype=float)[i],
                            line=np.asarray(log.line)[i])
    out = []
    for j, name in enumerate(sorted(clocks)):
        a, b = pair_ids(name, log.spacecraft)
        out.append(clock_variable(a, b, j))
    for j, name in enumerate(sorted(ambiguities)):
        out.append(ambiguity_variable(name[len("ambiguity_"):], j))
    return fams, out


def spacecraft_pass(p: Pass, s: int) -> Pass:
    """The one-spacecraft pass of spacecraft ``s`` (0-based): its own celestial and prior rows,
    without the links, on the formation's epochs (epochs without its rows are free states)."""
    start = orbit_columns(p.layout)[s]
    own = tuple(v for v in PER_SPACECRAFT
                if p.layout.has(spacecraft_variable(v, s, p.spacecraft[s]).name))
    fams = {}
    for kind, fam in p.families.items():
        if kind in ISL_KINDS:
            continue
        rows = np.flatnonzero(np.asarray(fam.values[COLUMN_PREFIX + "orbit"]) == start)
        if not len(rows):
            continue
        sub = fam.subset(rows)
        sub.values = {n: v for n, v in sub.values.items() if not n.startswith(COLUMN_PREFIX)}
        fams[kind] = sub
    return dataclasses.replace(p, families=fams, layout=Layout((ORBIT,) + own), spacecraft=(),
                               warnings=[],
                               deferred={}, unconverted={},
                               source=f"{p.source} (spacecraft {p.spacecraft[s]})")


def spacecraft_states(sol, lay: Layout) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each spacecraft's states (N, 6) and marginal covariances (N, 6, 6) from a solution of
    a formation pass (the first spacecraft's are ``sol.x_eci``/``P_eci``)."""
    out = [(sol.x_eci, sol.P_eci)]
    for v in lay.orbits[1:]:
        out.append(sol.variables[v.name])
    return out


def _rotated_to_eci(body: Family, att: Family | None) -> tuple[Family, np.ndarray]:
    """Body-frame direction rows (values ``u_body``) rotated into ECI with the attitude row
    at their epoch, ``u_eci = R_eci_from_body u_body``, their variance increased by the
    attitude's: the rotated rows (marked ``from_body``) of the rows that have an attitude
    row, and the source lines of those that have none."""
    att_at = {} if att is None else {int(kk): j for j, kk in enumerate(att.k)}
    has = np.array([int(kk) in att_at for kk in body.k], dtype=bool)
    rows = np.flatnonzero(has)
    ja = np.array([att_at[int(kk)] for kk in body.k[rows]], dtype=int)
    R = att.values["R_eci_from_body"][ja] if len(rows) else np.zeros((0, 3, 3))
    u_eci = np.einsum("mij,mj->mi", R, body.values["u_body"][rows])
    sig = np.hypot(body.sigma[rows], _attitude_sigma_on(att, ja, body.values["u_body"][rows])) \
        if len(rows) else np.zeros(0)
    new = Family(k=body.k[rows], values={"u_eci": u_eci, "from_body": np.ones(len(rows), bool)},
                 sigma=sig, line=body.line[rows])
    return new, body.line[~has]


def _attitude_sigma_on(att: Family, ja: np.ndarray, u_body: np.ndarray) -> np.ndarray:
    """1-sigma (rad, per tangent axis) that the attitude rows ``ja`` add to the body-frame
    directions ``u_body`` (M, 3) rotated into ECI: the row's ``sigma``, or, for a row with a
    full covariance ``P`` (body frame, right perturbation), the square root of the largest
    eigenvalue of ``[u]x P [u]x^T`` (``R exp([d]x) u = R (u - [u]x d)``: the attitude error
    about ``u`` itself does not move the direction), so that the row's isotropic sigma covers
    its tangent-plane covariance (the small-angle attitude error model: Markley and
    Crassidis, "Fundamentals of Spacecraft Attitude Determination and Control", 2014)."""
    sig = np.asarray(att.sigma, dtype=float)[ja]
    C = att.values.get("cov_rad2")
    if C is None:
        return sig
    C = np.asarray(C, dtype=float)[ja]
    full = np.flatnonzero(np.all(np.isfinite(C), axis=(1, 2)))
    if len(full):
        u = np.asarray(u_body, dtype=float)[full]
        K = np.zeros((len(full), 3, 3))
        K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -u[:, 2], u[:, 1], -u[:, 0]
        K -= np.transpose(K, (0, 2, 1))
        sig = sig.copy()
        w = np.linalg.eigvalsh(K @ C[full] @ np.transpose(K, (0, 2, 1)))[:, -1]
        sig[full] = np.sqrt(np.maximum(w, 0.0))
    return sig


def _merged(old: Family | None, new: Family) -> Family:
    """The rows of an ECI direction family and of rows rotated into it, sorted by epoch."""
    if old is None:
        return new
    order = np.argsort(np.concatenate([old.k, new.k]), kind="stable")
    was = old.values.get("from_body", np.zeros(len(old), bool))
    return Family(k=np.concatenate([old.k, new.k])[order],
                  values={"u_eci": np.concatenate([old.values["u_eci"], new.values["u_eci"]])[order],
                          "from_body": np.concatenate([was, new.values["from_body"]])[order]},
                  sigma=np.concatenate([old.sigma, new.sigma])[order],
                  line=np.concatenate([old.line, new.line])[order])


def directions_in_eci(p: Pass) -> Pass:
    """The pass with its body-frame direction families (there when the attitude is a graph
    variable) rotated into their ECI family with the attitude rows at their epochs, as
    :func:`build_pass` does without the variable: for the orbit-only computations (initial
    orbit determination). Rows at epochs without an attitude row are left out."""
    body = [k for k in p.families if MODELS[k].body_frame_of is not None]
    if not body:
        return p
    fams = dict(p.families)
    att = _with_star_attitudes(p.families.get(ATTITUDE.kind),
                               p.families.get(STAR_DIRECTION_BODY.kind)
                               or p.deferred.get(STAR_DIRECTION_BODY.kind))
    for kind in body:
        new, _ = _rotated_to_eci(fams.pop(kind), att)
        if len(new):
            into = MODELS[kind].body_frame_of
            fams[into] = _merged(fams.get(into), new)
    return dataclasses.replace(p, families=fams, layout=Layout())


def _with_star_attitudes(att: Family | None, stars: Family | None) -> Family | None:
    """The attitude rows, and at the epochs without one, the attitude each epoch's own stars
    give (Wahba's problem by SVD, Markley 1988: >= 2 stars not all parallel; the catalogue
    directions, the star camera taken as the body frame), so that a raw-star log without
    attitude rows can be started by the initial orbit (the integrity issue, item 8)."""
    if stars is None:
        return att
    ep, R, cov = wahba_by_epoch(stars.k, stars.values["u_body"], stars.values["s_eci"],
                                stars.sigma)
    have = set() if att is None else {int(kk) for kk in att.k}
    new = np.array([int(e) not in have for e in ep], dtype=bool)
    if not new.any():
        return att
    first_line = {int(kk): int(ln) for kk, ln in zip(stars.k[::-1], stars.line[::-1])}
    from_stars = Family(k=np.asarray(ep)[new],
                        values={"R_eci_from_body": R[new], "cov_rad2": cov[new]},
                        sigma=np.sqrt(np.linalg.eigvalsh(cov[new])[:, -1]),
                        line=np.array([first_line[int(e)] for e in np.asarray(ep)[new]]))
    if att is None:
        return from_stars
    cov_att = att.values.get("cov_rad2")
    if cov_att is None:   # rows with a sigma only: isotropic, as _attitude_sigma_on reads them
        cov_att = np.asarray(att.sigma, dtype=float)[:, None, None] ** 2 * np.eye(3)
    merged = {"R_eci_from_body": (att.values["R_eci_from_body"], R[new]),
              "cov_rad2": (cov_att, cov[new])}
    order = np.argsort(np.concatenate([att.k, from_stars.k]), kind="stable")
    return Family(k=np.concatenate([att.k, from_stars.k])[order],
                  values={key: np.concatenate(pair)[order] for key, pair in merged.items()},
                  sigma=np.concatenate([att.sigma, from_stars.sigma])[order],
                  line=np.concatenate([att.line, from_stars.line])[order])


def _without_body_rows(fam: Family) -> Family | None:
    """The family without its rows converted from the body frame (None if nothing is left)."""
    keep = np.flatnonzero(~fam.values.get("from_body", np.zeros(len(fam), bool)))
    return fam.subset(keep) if len(keep) else None


def _with_variable(p: Pass, name: str) -> Pass:
    """The deferred families that need the variable ``name`` join the graphs, and the rows
    that stood in for them (body-frame rows converted to ECI) leave."""
    fams = dict(p.families)
    deferred = dict(p.deferred)
    for kind, fam in p.deferred.items():
        mdl = MODELS[kind]
        if mdl.requires != name:
            continue
        if mdl.body_frame_of and mdl.body_frame_of in fams:
            rest = _without_body_rows(fams[mdl.body_frame_of])
            if rest is None:
                fams.pop(mdl.body_frame_of)
            else:
                fams[mdl.body_frame_of] = rest
        fams[kind] = fam
        deferred.pop(kind)
    order = {k: i for i, k in enumerate(MODELS)}
    fams = dict(sorted(fams.items(), key=lambda kv: order.get(kv[0], len(order))))
    return dataclasses.replace(p, families=fams, deferred=deferred)


def with_estimates(p: Pass, estimate=()) -> Pass:
    """The pass with the graph variables named in ``estimate`` (e.g. ``refraction-bias``)
    added to every epoch's block; each must be declared by a model with rows in the pass."""
    if p.spacecraft:
        return _formation_estimates(p, estimate)
    requested = [variable(name) for name in estimate or ()]
    for v in requested:
        if any(MODELS[k].requires == v.name for k in p.deferred):
            p = _with_variable(p, v.name)
    # the registry's order, whatever the order of the options
    variables = [ORBIT] + [v for v in VARIABLES.values() if v in requested and v != ORBIT]
    for v in variables[1:]:
        if v is ATTITUDE_RATE:   # the attitude's process variable (constant-rate motion)
            if ATTITUDE_VARIABLE not in variables:
                raise UserError(f"--attitude-motion constant-rate (--estimate {v.cli_name}): the "
                                f"body rate turns the estimated attitude; add --estimate "
                                f"{ATTITUDE_VARIABLE.cli_name}")
            continue
        users = [k for k in p.families if v in MODELS[k].optional_variables]
        if not users:
            declared = [k for k, m in MODELS.items() if v in m.optional_variables]
            needs = sorted({f"--estimate {VARIABLES[MODELS[k].requires].cli_name}"
                            for k in declared if k in p.deferred and MODELS[k].requires})
            raise UserError(f"--estimate {v.cli_name}: {p.source} has no rows that depend on it "
                            f"(it is used by {', '.join(declared)})"
                            + (f"; its rows there enter with {' and '.join(needs)}" if needs else ""))
    return dataclasses.replace(p, layout=Layout(tuple(variables)))


PER_SPACECRAFT = (ATTITUDE_VARIABLE, GYRO_BIAS)
"""The further variables a formation estimates per spacecraft (``--estimate``), each
spacecraft's own copy (:func:`fgnav.models.variables.spacecraft_variable`) bound to its rows."""


def check_formation_estimates(estimate=()) -> None:
    """Refuse, before any work, a variable a formation does not estimate per spacecraft."""
    for v in (variable(name) for name in estimate or ()):
        if v not in PER_SPACECRAFT:
            raise UserError(
                f"--estimate {v.cli_name}: a log of several spacecraft estimates, beside the "
                f"orbits, clocks and ambiguities, each spacecraft's "
                f"{' and '.join(u.cli_name for u in PER_SPACECRAFT)} only (the {v.cli_name} "
                f"rows are not yet bound per spacecraft)")


def _spacecraft_with_rows(p: Pass, kinds) -> list[int]:
    """The spacecraft (0-based, sorted) that have rows of the families ``kinds``."""
    cols = orbit_columns(p.layout)
    return sorted({int(np.searchsorted(cols, c)) for k in kinds
                   for c in np.unique(p.families[k].values[COLUMN_PREFIX + "orbit"])})


def _users_per_spacecraft(p: Pass, v, rows_name: str, used_by: str):
    """The families whose rows use the variable ``v`` and the spacecraft that have them
    (:func:`_spacecraft_with_rows`), refusing ``--estimate`` of ``v`` where no row uses it or
    the first spacecraft (whose copy is ``v`` itself) has none."""
    users = [k for k in p.families if v in MODELS[k].optional_variables]
    if not users:
        raise UserError(f"--estimate {v.cli_name}: {p.source} has no rows that depend on it "
                        f"({used_by})")
    have = _spacecraft_with_rows(p, users)
    if have[0] != 0:
        raise UserError(f"--estimate {v.cli_name}: {p.source} has {rows_name} rows of spacecraft "
                        f"{', '.join(p.spacecraft[s] for s in have)} but none of the first, "
                        f"'{p.spacecraft[0]}': give its rows too")
    return users, have


def _bound_per_spacecraft(p: Pass, v, users, have) -> Pass:
    """The pass with spacecraft ``have``'s own copies of the variable ``v`` after the block's
    variables (their columns stay) and the rows of the families ``users`` bound to their
    spacecraft's copy (``col:<v.name>``)."""
    cols = orbit_columns(p.layout)
    own = tuple(spacecraft_variable(v, s, p.spacecraft[s]) for s in have)
    lay = Layout(p.layout.variables + own)
    col = {int(cols[s]): lay.slices[u.name].start for s, u in zip(have, own)}
    fams = dict(p.families)
    for k in users:
        fam = fams[k]
        values = dict(fam.values)
        values[COLUMN_PREFIX + v.name] = np.array(
            [col[int(c)] for c in values[COLUMN_PREFIX + "orbit"]], dtype=int)
        fams[k] = Family(k=fam.k, values=values, sigma=fam.sigma, line=fam.line)
    return dataclasses.replace(p, families=fams, layout=lay)


def _formation_estimates(p: Pass, estimate=()) -> Pass:
    """:func:`with_estimates` for a formation: each spacecraft with rows that need the
    attitude (its attitude rows, its body-frame directions, its gyro rows) gets its own
    attitude variable, after the orbits, clocks and ambiguities (their columns stay), and
    those rows join the graphs bound to it (``col:attitude``); the rows converted to ECI with
    the measured attitude leave, as for one spacecraft. With ``gyro-bias`` each spacecraft
    with gyro rows gets its own bias after the attitudes, its gyro rows bound to it
    (``col:gyro_bias``). The links keep the measured attitude rows for their lever arms
    (:mod:`fgnav.models.isl`: 1 arcsec on a 0.9 m arm is 4 um, far below a link's noise)."""
    check_formation_estimates(estimate)
    requested = {variable(name).name for name in estimate or ()}
    if not requested or any(v.name == ATTITUDE_VARIABLE.name for v in p.layout.extra):
        return p
    if ATTITUDE_VARIABLE.name not in requested:
        raise UserError(f"--estimate {GYRO_BIAS.cli_name}: {p.source}: the gyro rows, which "
                        f"observe the bias, enter with each spacecraft's attitude: add "
                        f"--estimate {ATTITUDE_VARIABLE.cli_name}")
    p = _with_variable(p, ATTITUDE_VARIABLE.name)
    cols = orbit_columns(p.layout)
    users, have = _users_per_spacecraft(p, ATTITUDE_VARIABLE, "attitude or body-frame",
                                        "attitude or body-frame rows")
    for s in have:   # a gyro carries the attitude from epoch to epoch, it does not fix it
        own = [k for k in users if not MODELS[k].between
               and np.any(p.families[k].values[COLUMN_PREFIX + "orbit"] == cols[s])]
        if ATTITUDE.kind not in own and len(own) < 2:
            raise UserError(
                f"{p.source}: --estimate {ATTITUDE_VARIABLE.cli_name}: spacecraft "
                f"'{p.spacecraft[s]}''s {', '.join(own) or 'gyro'} rows need its attitude, and "
                f"nothing fixes it: no '{ATTITUDE.kind}' row of it, nor a second body-frame "
                f"direction")
    p = _bound_per_spacecraft(p, ATTITUDE_VARIABLE, users, have)
    if GYRO_BIAS.name not in requested:
        return p
    gyros, have = _users_per_spacecraft(p, GYRO_BIAS, GYRO.kind,
                                        f"it is used by {GYRO.kind} rows")
    return _bound_per_spacecraft(p, GYRO_BIAS, gyros, have)


def check_attitude(p: Pass) -> None:
    """Refuse a pass whose star rows would be left out of the graphs: ``star_direction_body``
    rows observe the attitude only, so without ``--estimate attitude`` they (and the
    body-frame rows at epochs without an ``attitude`` row) would be dropped in silence.
    And refuse an estimated attitude that nothing fixes: with neither ``attitude`` nor star
    rows, nor Sun or Moon directions with a second body-frame direction (Sun, Moon or Earth:
    two directions fix a rotation), the rotation about each measured direction is free (gyro
    rows carry the attitude from epoch to epoch, they do not fix it)."""
    body_kinds = [k for k in (EARTH_DIRECTION_BODY.kind, SUN_DIRECTION_BODY.kind,
                              MOON_DIRECTION_BODY.kind) if p.count(k)]
    if p.layout.has(ATTITUDE_VARIABLE.name) and not (
            p.count(ATTITUDE.kind) or p.count(STAR_DIRECTION_BODY.kind)
            or len(body_kinds) >= 2):
        users = [k for k in p.families if ATTITUDE_VARIABLE in MODELS[k].optional_variables
                 and k != ATTITUDE.kind] or ["no"]
        raise UserError(
            f"{p.source}: --estimate {ATTITUDE_VARIABLE.cli_name}: the {', '.join(users)} rows "
            f"need the attitude, and nothing fixes it: no '{ATTITUDE.kind}' row and no "
            f"'{STAR_DIRECTION_BODY.kind}' rows, nor Sun or Moon directions with a second "
            f"body-frame direction (found: {p.counts()})")
    if STAR_DIRECTION_BODY.kind in p.deferred:
        raise UserError(
            f"{p.source}: '{STAR_DIRECTION_BODY.kind}' rows observe the attitude, which is not "
            f"estimated: add --estimate {ATTITUDE_VARIABLE.cli_name} (the attitude then is a "
            f"graph variable per epoch, solved with the orbit from the stars and the "
            f"body-frame rows)")


def check_observable(p: Pass, require_prior: bool = True) -> None:
    """Refuse passes that cannot determine an orbit, with a message that says why.

    ``require_prior=False``: the orbit will start from the measurements
    (:mod:`fgnav.start`), so only the measurements are checked here. The attitude
    rows are checked first (:func:`check_attitude`).
    """
    check_attitude(p)
    for kind, lines in p.unconverted.items():
        if not p.layout.has(MODELS[kind].requires or ""):
            raise UserError(
                f"{p.source}: {kind} rows need an '{ATTITUDE.kind}' row at the same epoch, or "
                f"the attitude estimated (--estimate {ATTITUDE_VARIABLE.cli_name}, with "
                f"'{STAR_DIRECTION_BODY.kind}' or '{ATTITUDE.kind}' rows to fix it and gyro rows to "
                f"carry it); none for line(s) {list(map(int, lines[:5]))}"
                f"{' ...' if len(lines) > 5 else ''}")
    observing = [k for k in p.families if k in MODELS and MODELS[k].observes_orbit]
    n_obs = sum(p.count(k) for k in observing)
    if not require_prior and n_obs == 0:
        raise UserError(f"{p.source}: no measurements that observe the orbit "
                        f"(found only: {p.counts() or 'nothing'})")
    if not require_prior:
        return
    if p.count(PRIOR_POSITION.kind) == 0 or p.count(PRIOR_VELOCITY.kind) == 0:
        if n_obs == 0:
            raise UserError(f"{p.source}: no measurements that observe the orbit "
                            f"(found only: {p.counts() or 'nothing'})")
        raise UserError(
            f"{p.source}: a first guess of the orbit is needed: add 'prior_position' and "
            f"'prior_velocity' rows (a priori state with its 1-sigma) at some epoch")
    if n_obs == 0:
        raise UserError(
            f"{p.source}: the log has priors but no measurement that observes the orbit "
            f"({', '.join(k for k, m in MODELS.items() if m.observes_orbit and m.solved)}); "
            f"counts: {p.counts()}")
    n_range = sum(p.count(k) for k in observing if MODELS[k].range_m is not None)
    if n_obs == n_range and n_range < 6:
        raise UserError(f"{p.source}: no direction data and fewer than 6 range-type "
                        f"measurements: the orbit is not observable from this log")


MAX_INSERTED_PER_GAP = 200
"""At most this many measurement-free state epochs are inserted into one gap (see
:func:`fill_gaps`): enough to draw the trajectory and its covariance through the gap, and
the solvers' cost stays bounded whatever the gap's length (20 days at 1 s sampling would
otherwise be 1.7 million states)."""


def fill_gaps(p: Pass, gap_factor: float = 10.0,
              max_per_gap: int = MAX_INSERTED_PER_GAP) -> Pass:
    """Insert measurement-free epochs across long gaps so the solution covers them.

    A gap is a step longer than ``gap_factor`` times the median step. It receives
    ``n = min(ceil(gap / median) - 1, max_per_gap)`` epochs evenly spaced across it: at the
    median step while that needs at most ``max_per_gap`` epochs (a 1 h gap at 60 s gets the
    59 epochs a gap-free log would have), at the wider spacing ``gap / (max_per_gap + 1)``
    beyond (a 20-day gap: 200 epochs 2.4 h apart). The motion factor sub-steps any step at
    ``MotionModel.max_step_s``, so the spacing changes only where the solution is reported,
    not the dynamics. The smoothers then propagate through the gap (motion factors only)
    and report a covariance that grows into the gap and shrinks when measurements return.

    ``Pass.inserted`` marks the epochs added here; a pass already filled is returned as is.
    The gaps before the epochs in ``p.breaks`` (arcs solved separately) are not filled;
    ``breaks`` are renumbered to the new epochs.
    """
    if p.inserted is not None:
        return p
    unchanged = dataclasses.replace(p, inserted=np.zeros(p.n_epochs, bool))
    if p.n_epochs < 3:
        return unchanged
    dt = np.diff(p.t_s)
    step = float(np.median(dt))
    gaps = np.array([i for i in long_gaps(p, gap_factor) if i + 1 not in p.breaks], dtype=int)
    if step <= 0 or not len(gaps):
        return unchanged
    extra = []
    for i in gaps:
        n = int(min(np.ceil(dt[i] / step - 1e-9) - 1, max_per_gap))
        extra.append(p.t_s[i] + dt[i] * np.arange(1, n + 1) / (n + 1))
    t_new = np.unique(np.concatenate([p.t_s, *extra]))
    remap = np.searchsorted(t_new, p.t_s)
    inserted = np.ones(len(t_new), bool)
    inserted[remap] = False
    fams, deferred = ({kind: Family(k=remap[f.k], values=f.values, sigma=f.sigma, line=f.line)
                       for kind, f in group.items()} for group in (p.families, p.deferred))
    n_ins = len(t_new) - p.n_epochs
    longest = float(dt[gaps].max())
    man = p.manoeuvres
    if man is not None:
        man = Family(k=remap[man.k], values=man.values, sigma=man.sigma, line=man.line)
    return dataclasses.replace(
        p, t_s=t_new, families=fams, deferred=deferred, inserted=inserted, manoeuvres=man,
        breaks=tuple(int(remap[b]) for b in p.breaks),
        warnings=p.warnings + [f"{n_ins} state epochs inserted across {len(gaps)} gap(s) "
                               f"longer than {gap_factor * step:g} s (longest "
                               f"{format_duration(longest)}; at most {max_per_gap} per gap)"])


def long_gaps(p: Pass, gap_factor: float) -> np.ndarray:
    """Indices ``i`` of the steps ``t_s[i] -> t_s[i + 1]`` longer than ``gap_factor`` times
    the median step (the gaps :func:`fill_gaps` fills)."""
    if p.n_epochs < 3:
        return np.zeros(0, dtype=int)
    dt = np.diff(p.t_s)
    step = float(np.median(dt))
    return np.flatnonzero(dt > gap_factor * step) if step > 0 else np.zeros(0, dtype=int)


def slice_pass(p: Pass, k0: int, k1: int, prior: tuple | None = None) -> tuple[Pass, dict]:
    """Epochs ``k0 <= k < k1`` of a pass as a pass of their own (same ``epoch0`` and times),
    and for each family the indices of its rows in ``p`` (-1 for added rows).

    ``prior = (x (6,), sigma_position_m, sigma_velocity_mps)`` adds ``prior_position`` /
    ``prior_velocity`` rows at the first epoch (placed first in their families); a
    formation's ``prior`` is one such tuple per spacecraft (rows bound to its orbit). A
    formation's arc keeps its spacecraft, centre and the link fixes within its epochs.
    """
    fams, rows_of, deferred = {}, {}, {}
    for kind, f in p.families.items():
        rows = np.flatnonzero((f.k >= k0) & (f.k < k1))
        if len(rows):
            fams[kind] = f.subset(rows)
            fams[kind].k = fams[kind].k - k0
            rows_of[kind] = rows
    for kind, f in p.deferred.items():
        rows = np.flatnonzero((f.k >= k0) & (f.k < k1))
        if len(rows):
            deferred[kind] = f.subset(rows, None)
            deferred[kind].k = deferred[kind].k - k0
    if prior is not None:
        per = list(prior) if p.spacecraft else [prior]   # one (x, s_r, s_v) per spacecraft
        cols = orbit_columns(p.layout) if p.spacecraft else None
        for j, kind in enumerate((PRIOR_POSITION.kind, PRIOR_VELOCITY.kind)):
            values = {"xyz": np.array([np.asarray(x, float)[3 * j:3 * j + 3] for x, *_ in per])}
            if cols is not None:
                values[COLUMN_PREFIX + "orbit"] = cols[:len(per)].copy()
            n = len(per)
            new = Family(k=np.zeros(n, dtype=int), values=values,
                         sigma=np.array([float(sig[j]) for _, *sig in per]),
                         line=np.zeros(n, dtype=int))
            old = fams.get(kind)
            if old is not None:
                new = Family(k=np.r_[new.k, old.k],
                             values={c: np.concatenate([new.values[c], old.values[c]])
                                     for c in new.values},
                             sigma=np.r_[new.sigma, old.sigma], line=np.r_[new.line, old.line])
            fams[kind] = new
            rows_of[kind] = np.r_[np.full(n, -1), rows_of.get(kind, np.zeros(0, dtype=int))]
    man = None
    if p.manoeuvres is not None:   # a burn on an arc's first epoch: before its prior, left out
        rows = np.flatnonzero((p.manoeuvres.k > k0) & (p.manoeuvres.k < k1))
        if len(rows):
            man = p.manoeuvres.subset(rows)
            man.k = man.k - k0
    formation = {}
    if p.spacecraft:
        fixes = None
        if p.link_fixes is not None:   # (the arc's own: the start places sat2 from them)
            t_f, dr = p.link_fixes
            keep = (t_f >= p.t_s[k0]) & (t_f <= p.t_s[k1 - 1])
            fixes = (t_f[keep], dr[keep]) if keep.sum() >= 2 else None
        formation = {"spacecraft": p.spacecraft, "centre": p.centre, "link_fixes": fixes}
    sub = Pass(epoch0=p.epoch0, t_s=p.t_s[k0:k1], families=fams, source=p.source, layout=p.layout,
               deferred=deferred, manoeuvres=man,
               inserted=None if p.inserted is None else p.inserted[k0:k1], **formation)
    return sub, rows_of


def format_duration(s: float) -> str:
    """A length of time for messages: seconds, minutes, hours or days."""
    for unit, size in (("d", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if s >= 2 * size:
            return f"{s / size:.1f} {unit}"
    return f"{s:.0f} s"


def prior_covariance(p: Pass, k0: int = 0) -> np.ndarray:
    """Initial covariance (diagonal, SI) from the prior rows at epoch ``k0`` (else the first)."""
    P = np.zeros((6, 6))
    for kind, sl in ((PRIOR_POSITION.kind, slice(0, 3)), (PRIOR_VELOCITY.kind, slice(3, 6))):
        fam = p.families[kind]
        j = np.flatnonzero(fam.k == k0)
        sig = fam.sigma[j[0]] if len(j) else fam.sigma[0]
        P[sl, sl] = np.eye(3) * sig ** 2
    return P


def covering_sigmas(P: np.ndarray) -> tuple[float, float]:
    """Isotropic 1-sigma (position m, velocity m/s) that cover a state covariance ``P``
    (6, 6): the square root of the largest eigenvalue of each 3x3 block (prior rows carry one
    sigma per row, so the ellipsoid is covered by its sphere)."""
    return (math.sqrt(float(np.linalg.eigvalsh(P[:3, :3])[-1])),
            math.sqrt(float(np.linalg.eigvalsh(P[3:, 3:])[-1])))


def prior_state(p: Pass) -> tuple[int, np.ndarray]:
    """The a-priori state (6,) and its epoch index: the first epoch that has both a
    ``prior_position`` and a ``prior_velocity`` row."""
    pp, pv = p.families.get(PRIOR_POSITION.kind), p.families.get(PRIOR_VELOCITY.kind)
    if pp is None or pv is None:
        raise UserError(f"{p.source}: a first guess needs 'prior_position' and 'prior_velocity' rows")
    common = np.intersect1d(pp.k, pv.k)
    if len(common) == 0:
        raise UserError(f"{p.source}: 'prior_position' and 'prior_velocity' must share an epoch")
    k0 = int(common[0])
    return k0, np.concatenate([pp.values["xyz"][np.flatnonzero(pp.k == k0)[0]],
                               pv.values["xyz"][np.flatnonzero(pv.k == k0)[0]]])
