"""The kinds of run a study can grid over: one function per kind, its typed parameters and
the typed columns it adds to the runs table.

A run is a pure function of its parameters (the noise seed among them), so it gives the same
numbers in this process, in a worker process or on a Dask worker. The functions run in
workers: they live at module level (picklable by reference) and take one frozen parameter
object.
"""

from __future__ import annotations

import time
from dataclasses import MISSING, dataclass, field, fields
from typing import Callable

from factors.constants import R_LIMB_UV_M
from fgnav.analysis.limb_method_study import direct_position_error_mc, table5 as closed_forms
from fgnav.analysis.visibility import SEED_RING_DEG, ring_sees_limb, visibility_scenario
from fgnav.constants import DEG, R_EARTH_M
from fgnav.diagnostics.consistency import nees, nis_ekf, nis_smoother, nis_summary
from fgnav.diagnostics.crb import cramer_rao_bound
from fgnav.diagnostics.observability import (analyze_observability, observability_matrix,
                                             weakest_directions, window_information)
from fgnav.errors import UserError
from fgnav.io.log_csv import log_from_arrays
from fgnav.measurements import build_pass
from fgnav.iod.angles import DIRECTION_KINDS
from fgnav.models.registry import prior_kinds
from fgnav.pipeline import accuracy_metrics, solve
from fgnav.scenarios import check_size, load_scenario
from fgnav.simulate.pass_sim import simulate_pass
from fgnav.solvers.options import SmootherOptions

__all__ = ["Column", "Task", "TASKS", "RunParams", "NavigateParams", "ObservabilityParams",
           "VisibilityParams", "Table5Params", "TIMING_COLUMNS"]


@dataclass(frozen=True)
class Column:
    """One column of the runs table: its name and the Python type of its cells
    (``str``, ``int``, ``float`` or ``bool``; an empty cell is ``None``)."""
    name: str
    type: type


@dataclass(frozen=True, kw_only=True)
class RunParams:
    """Parameters of one run. Read-only; ``params["name"]`` reads a field like ``params.name``."""
    seed: int = 0

    def __getitem__(self, key: str):
        if key not in {f.name for f in fields(self)}:
            raise KeyError(key)
        return getattr(self, key)


def positive(default=MISSING):
    """A field the study file must give as a finite number > 0."""
    return field(default=default, metadata={"positive": True})


@dataclass(frozen=True, kw_only=True)
class NavigateParams(RunParams):
    """Simulate a pass of a scenario and navigate it with one method (``fgnav.pipeline.solve``).

    ``None`` keeps the scenario's own value. Units: s, h, deg (1-sigma per axis of the
    Earth-direction sensors), m, m/s, m^2/s^3 (process noise spectral density)."""
    method: str
    scenario: str = "gto-transfer"
    step_s: float | None = positive(None)
    duration_h: float | None = positive(None)
    sigma_deg: float | None = positive(None)
    prior_position_sigma_m: float | None = positive(None)
    prior_velocity_sigma_mps: float | None = positive(None)
    prior_mode: str | None = None
    q_m2_s3: float | None = None
    third_body: bool | None = None



@dataclass(frozen=True, kw_only=True)
class ObservabilityParams(RunParams):
    """Observability matrix (``n_samples`` blocks of period ``step_s`` s) at the scenario's
    initial state, and the information over a ``window_h`` h window of ``sigma_deg``
    geocentric directions."""
    step_s: float = positive()
    scenario: str = "gto-transfer"
    n_samples: int = positive(6)
    window_h: float = positive(1.0)
    sigma_deg: float = positive(0.01)



@dataclass(frozen=True, kw_only=True)
class VisibilityParams(RunParams):
    """A limb-ring pass (``fgnav.analysis.visibility.visibility_scenario``) navigated with
    every epoch and with only the epochs at which the ring (full angles ``ring_deg``, deg)
    sees the whole limb."""
    method: str
    orbit: str
    ring_deg: tuple[float, float] | None = None
    q_m2_s3: float | None = None
    third_body: bool | None = None



@dataclass(frozen=True, kw_only=True)
class Table5Params(RunParams):
    """Direct positioning error at altitude ``alt_km`` (km) for a geocentric-vector angle
    error ``angle_error_deg`` (deg): closed forms and a Monte Carlo check."""
    alt_km: float = positive()
    angle_error_deg: float = positive()



# ---- the run functions -----------------------------------------------------------------

def _scenario(name: str, *, step_s=None, duration_h=None, sigma_deg=None, prior_position_sigma_m=None,
              prior_velocity_sigma_mps=None, prior_mode=None):
    """A built-in scenario with options replaced; ``sigma_deg`` sets every Earth-direction sensor."""
    from dataclasses import replace

    scn = load_scenario(name).with_options(step_s=step_s, duration_h=duration_h,
                                           prior_position_sigma_m=prior_position_sigma_m,
                                           prior_velocity_sigma_mps=prior_velocity_sigma_mps,
                                           prior_mode=prior_mode)
    if sigma_deg is not None:
        sensors = tuple(replace(s, sigma_deg=float(sigma_deg))
                        if s.kind in DIRECTION_KINDS else s for s in scn.sensors)
        scn = scn.with_options(sensors=sensors)
    return scn


def _smoother_options(q_m2_s3: float | None, third_body: bool | None):
    kw = {}
    if q_m2_s3 is not None:
        kw["q_m2_s3"] = float(q_m2_s3)
    if third_body is not None:
        kw["third_body"] = bool(third_body)
    return SmootherOptions(**kw)


NAVIGATE_COLUMNS = (
    Column("n_epochs", int), Column("position_rms_m", float), Column("velocity_rms_mps", float),
    Column("final_position_error_m", float), Column("final_velocity_error_mps", float),
    Column("nees_mean", float), Column("nees_final", float), Column("sigma_position_rms_m", float),
    Column("sigma_final_position_m", float), Column("nis_per_dof", float), Column("info_condition", float),
    Column("weakest_sigma_m", float), Column("weakest_direction", str), Column("solve_s", float))


def navigate(p: NavigateParams):
    """Errors against the simulator's truth (independent DOP853 integration), NEES, NIS and
    the Cramer-Rao information of the pass; arrays: per-epoch NEES and NIS."""
    import numpy as np

    scn = _scenario(p.scenario, step_s=p.step_s, duration_h=p.duration_h, sigma_deg=p.sigma_deg,
                    prior_position_sigma_m=p.prior_position_sigma_m,
                    prior_velocity_sigma_mps=p.prior_velocity_sigma_mps, prior_mode=p.prior_mode)
    options = _smoother_options(p.q_m2_s3, p.third_body)
    sim = simulate_pass(scn, seed=p.seed)
    ps = build_pass(sim.log)
    t0 = time.perf_counter()
    sol = solve(ps, p.method, options)
    solve_s = time.perf_counter() - t0
    x_true = sim.x_true[sim.t_s.searchsorted(sol.t_s)]
    m = accuracy_metrics(sol, x_true)
    eps = nees(sol.x_eci, sol.P_eci, x_true)
    if p.method == "ekf":
        nis, dof = nis_ekf(ps, sol, options)
    else:
        nis, dof = nis_smoother(ps, sol)
    J = cramer_rao_bound(ps, x_true, options.motion_model()).J0_measurements
    weak = weakest_directions(J, count=1)[0]
    row = {"n_epochs": int(len(sol.t_s)), **{c.name: m[c.name] for c in NAVIGATE_COLUMNS if c.name in m},
           "nees_final": float(eps[-1]),
           "sigma_final_position_m": float(np.sqrt(np.trace(sol.P_eci[-1, :3, :3]))),
           "nis_per_dof": nis_summary(nis, dof)["nis_per_dof"],
           "info_condition": float(np.linalg.cond(J)), "weakest_sigma_m": weak["sigma_m"],
           "weakest_direction": weak["text"], "solve_s": solve_s}
    arrays = {"t_s": np.asarray(sol.t_s), "nees": eps, "nis": nis, "nis_dof": dof}
    return row, arrays


OBSERVABILITY_COLUMNS = (
    Column("rank", int), Column("condition_raw", float), Column("condition_scaled", float),
    Column("window_info_condition", float), Column("weakest_sigma_m", float),
    Column("weakest_direction", str), Column("window_h", float))


def observability(p: ObservabilityParams):
    """Rank and condition number of the observability matrix and of the window information."""
    import numpy as np

    scn = _scenario(p.scenario, step_s=p.step_s, sigma_deg=p.sigma_deg)
    x0 = np.array(scn.x0_eci)
    res = analyze_observability(observability_matrix(x0, p.step_s, p.n_samples))
    J = window_information(x0, p.step_s, p.window_h * 3600.0, p.sigma_deg * DEG)
    weak = weakest_directions(J, count=1)[0]
    row = {"rank": res.rank, "condition_raw": res.condition_raw, "condition_scaled": res.condition_scaled,
           "window_info_condition": float(np.linalg.cond(J)), "weakest_sigma_m": weak["sigma_m"],
           "weakest_direction": weak["text"], "window_h": p.window_h}
    return row, {}


VISIBILITY_COLUMNS = (
    Column("perigee_alt_km", float), Column("apogee_alt_km", float), Column("visible_fraction", float),
    Column("n_epochs_all", int), Column("n_epochs_ring", int), Column("max_gap_min", float),
    Column("position_rms_all_m", float), Column("final_position_all_m", float),
    Column("position_rms_ring_m", float), Column("final_position_ring_m", float), Column("ring_status", str))


def visibility(p: VisibilityParams):
    """Fraction of the pass with the whole limb inside the ring, the longest gap, and the
    navigation errors with every epoch vs with the visible epochs only."""
    import numpy as np

    scn = visibility_scenario(p.orbit)
    options = _smoother_options(p.q_m2_s3, p.third_body)
    sim = simulate_pass(scn, seed=p.seed)
    rn = np.linalg.norm(sim.x_true[:, :3], axis=1)
    vis = ring_sees_limb(sim.x_true[:, :3], tuple(p.ring_deg or SEED_RING_DEG))
    row = {"perigee_alt_km": float((rn.min() - R_EARTH_M) / 1e3),
           "apogee_alt_km": float((rn.max() - R_EARTH_M) / 1e3), "visible_fraction": float(vis.mean())}
    gaps, run = [], 0.0
    dt = np.diff(sim.t_s, prepend=sim.t_s[0])
    for v, d in zip(vis, dt):
        run = 0.0 if v else run + d
        gaps.append(run)
    row["max_gap_min"] = float(max(gaps) / 60.0)

    def metrics(log):
        ps = build_pass(log)
        sol = solve(ps, p.method, options)
        m = accuracy_metrics(sol, sim.x_true[sim.t_s.searchsorted(sol.t_s)])
        return ps.n_epochs, m["position_rms_m"], m["final_position_error_m"]

    row["n_epochs_all"], row["position_rms_all_m"], row["final_position_all_m"] = metrics(sim.log)
    log = sim.log
    prior = np.isin(log.kind, prior_kinds())
    keep = prior | np.isin(log.t_s, sim.t_s[vis])
    row["n_epochs_ring"], row["position_rms_ring_m"], row["final_position_ring_m"] = 0, float("nan"), float("nan")
    if keep.sum() > prior.sum():
        sub = log_from_arrays(log.epoch0, log.t_s[keep], log.kind[keep], log.xyz[keep], log.sigma[keep],
                              {k: v[keep] for k, v in (log.extra or {}).items()},
                              centre=log.centre, schema=log.schema)
        try:
            row["n_epochs_ring"], row["position_rms_ring_m"], row["final_position_ring_m"] = metrics(sub)
            row["ring_status"] = "ok"
        except UserError as exc:
            row["ring_status"] = f"not observable: {str(exc)[:80]}"
    else:
        row["ring_status"] = "limb never inside the ring: no measurement"
    return row, {}


TABLE5_COLUMNS = (
    Column("seed_km", float), Column("ours_direction_km", float), Column("ours_with_rho_km", float),
    Column("ours_mc_km", float), Column("lower_bound_km", float), Column("seed_over_bound", float))


def table5(p: Table5Params):
    """Direct positioning error from one geocentric vector: the closed forms of
    ``fgnav.analysis.limb_method_study.table5`` and a 2000-draw Monte Carlo of r = -(R / sin rho) u."""
    import numpy as np

    rows = [r for r in closed_forms(alts_km=(p.alt_km,)) if abs(r["angle_error_deg"] - p.angle_error_deg) < 1e-12]
    if not rows:
        rows = closed_forms(alts_km=(p.alt_km,), angle_errors_deg=(p.angle_error_deg,))
    r = dict(rows[0])
    rng = np.random.default_rng(p.seed)
    r_m = R_LIMB_UV_M + p.alt_km * 1e3
    ang = p.angle_error_deg * DEG
    r["ours_mc_km"] = direct_position_error_mc(r_m, ang, ang / 2.0, rng) / 1e3
    return {c.name: r.get(c.name) for c in TABLE5_COLUMNS}, {}


# ---- the registry --------------------------------------------------------------------

# ---- the checks a run passes before any run of its study starts -------------------------

def _check_seed(p: RunParams) -> None:
    if isinstance(p.seed, bool) or not isinstance(p.seed, int) or p.seed < 0:
        raise UserError(f"seed: expected an integer >= 0, found {p.seed!r}")


def check_navigate(p: NavigateParams) -> None:
    """What would stop :func:`navigate` before it solves: the seed, the scenario (known, one
    spacecraft: a formation's runs are not a task here) and the size of its pass."""
    _check_seed(p)
    scn = _scenario(p.scenario, step_s=p.step_s, duration_h=p.duration_h, sigma_deg=p.sigma_deg,
                    prior_position_sigma_m=p.prior_position_sigma_m,
                    prior_velocity_sigma_mps=p.prior_velocity_sigma_mps, prior_mode=p.prior_mode)
    if scn.formation is not None:
        raise UserError(f"scenario '{p.scenario}' is a formation of several spacecraft: the "
                        "navigate task simulates and solves one spacecraft (use fgnav simulate "
                        "and fgnav smooth for a formation)")
    check_size(scn)
    _smoother_options(p.q_m2_s3, p.third_body)


def check_observability(p: ObservabilityParams) -> None:
    _check_seed(p)
    _scenario(p.scenario, step_s=p.step_s, sigma_deg=p.sigma_deg)


def check_visibility(p: VisibilityParams) -> None:
    _check_seed(p)
    check_size(visibility_scenario(p.orbit))
    _smoother_options(p.q_m2_s3, p.third_body)


@dataclass(frozen=True)
class Task:
    """A kind of run: its parameter type, its result columns, its function
    ``run(params) -> (row {column: value}, arrays {name: ndarray})``, and ``check(params)``,
    which raises :class:`UserError` for a run that cannot start, in well under a second, so
    that a study is refused whole before any run."""
    name: str
    params: type
    columns: tuple[Column, ...]
    run: Callable
    takes_method: bool
    check: Callable = _check_seed


TASKS = {t.name: t for t in (
    Task("navigate", NavigateParams, NAVIGATE_COLUMNS, navigate, True, check_navigate),
    Task("observability", ObservabilityParams, OBSERVABILITY_COLUMNS, observability, False,
         check_observability),
    Task("visibility", VisibilityParams, VISIBILITY_COLUMNS, visibility, True, check_visibility),
    Task("seed000-table5", Table5Params, TABLE5_COLUMNS, table5, False),
)}

TIMING_COLUMNS = ("solve_s", "run_s", "worker")
"""Columns that describe the execution, not the result (excluded from reproducibility checks)."""
