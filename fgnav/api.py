"""fgnav as Python calls: what ``fgnav simulate``, ``smooth`` and ``report`` do on the command line.

A handful of functions over the library the CLI itself runs (:mod:`fgnav.pipeline`,
:mod:`fgnav.simulate.pass_sim`, :mod:`fgnav.viz.report`); ``docs/api.md`` walks through
them with a worked example::

    import fgnav.api as fg

    sim = fg.simulate("gto-transfer", duration_h=1.0, out="pass/")  # measurements.csv, truth.oem
    log = fg.read_log("pass/measurements.csv")                      # a log of yours the same way
    result = fg.smooth(log, method="batch", truth="pass/truth.oem")
    print(result.summary["position_rms_m"], result.summary["integrity"]["status"])
    fg.write_outputs(result, "result/")       # trajectory.oem, summary.json, residuals.csv, ...
    fg.report("result/")                      # PNG plots + report.md/html

Units are SI and frames ECI (EME2000) throughout, as in the rest of the library
(CONTRIBUTING.md, "Naming convention"). Every input error raises
:class:`fgnav.errors.UserError` with the message the CLI would print.

Importing this module is cheap: each function imports what it runs (NumPy, GTSAM, numba
kernels, matplotlib) when first called.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["Result", "simulate", "read_log", "options", "smooth", "write_outputs", "report",
           "plot_errors", "METHODS"]

METHODS = ("batch", "isam2", "fixed-lag", "ekf")
"""The estimators (``fgnav smooth --method``): batch smoother, iSAM2, fixed-lag smoother, EKF."""


@dataclass
class Result:
    """One estimator's answer on one pass.

    solution : :class:`fgnav.solution.Solution` -- ``t_s`` (N,) s from ``epoch0``, ``x_eci``
        (N, 6) [m, m/s], ``P_eci`` (N, 6, 6) marginal covariances (SI), residuals, and for
        online methods the online states.
    summary : the ``summary.json`` dictionary (accuracy against truth when a truth was
        given; always the integrity verdict under ``"integrity"``).
    x_true : (N, 6) true states at the solution's epochs, or None without truth.
    pass_ : the :class:`fgnav.measurements.Pass` the estimator saw (rows grouped by epoch,
        gaps planned); :func:`write_outputs` needs it for the residuals' epochs.
    """

    solution: Any
    summary: dict
    x_true: Any
    pass_: Any


def simulate(scenario: str = "gto-transfer", *, seed: int = 0, step_s: float | None = None,
             duration_h: float | None = None, gravity: str | None = None,
             out: str | Path | None = None):
    """Simulate a scenario (``fgnav simulate``) and return its
    :class:`~fgnav.simulate.pass_sim.SimulatedPass`: ``log`` (the measurement log),
    ``epoch0``, ``t_s`` (s) and ``x_true`` (N, 6) truth from the independent DOP853
    integrator.

    scenario : a built-in name (``fgnav simulate --help`` lists them) or a scenario TOML path.
    seed : noise seed, integer >= 0 (the same seed gives the same numbers).
    step_s, duration_h : override the scenario's measurement period (s) and length (h).
    gravity : ``"point-mass"`` or ``"j2"`` overrides the truth's Earth field
        (``[truth] j2`` of the scenario).
    out : also write the pass into this directory (created) as ``fgnav simulate --out``:
        ``measurements.csv`` and ``truth.oem``.
    """
    from fgnav.errors import UserError
    from fgnav.scenarios import load_scenario
    from fgnav.simulate.pass_sim import simulate_pass, write_pass_files
    from fgnav.solvers.options import GRAVITY_MODELS

    if gravity is not None and gravity not in GRAVITY_MODELS:
        raise UserError(f"gravity: expected one of {', '.join(GRAVITY_MODELS)}, found {gravity!r}")
    scn = load_scenario(scenario).with_options(
        step_s=step_s, duration_h=duration_h,
        truth_j2=None if gravity is None else gravity == "j2")
    sim = simulate_pass(scn, seed=seed)
    if out is not None:
        try:
            Path(out).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UserError(f"out {out}: cannot create the directory: "
                            f"{exc.strerror or exc}") from None
        write_pass_files(out, sim)
    return sim


def read_log(path: str | Path, *, estimate=()):
    """Read a measurement log: CSV v1 (README, "Logged pass format") or a CCSDS TDM
    (``.tdm``/``.kvn``), validated row by row. Returns a
    :class:`~fgnav.io.log_csv.MeasurementLog` (``t_s``, ``kind``, ``xyz``, ``sigma``,
    ``extra`` columns; ``counts()`` rows per kind).

    estimate : the graph variables that will be estimated (as :func:`smooth`'s
        ``estimate``): with the attitude among them, body-frame Sun/Moon rows stay raw
        instead of being turned into a TRIAD attitude.
    """
    from fgnav.pipeline import read_measurements

    return read_measurements(path, _estimate_names(estimate))


def options(**kw):
    """The estimator options, :class:`~fgnav.solvers.options.SmootherOptions` (SI units):
    e.g. ``q_m2_s3`` (process noise, m^2/s^3, ``--process-noise``), ``third_body``,
    ``gravity`` (``"j2"`` | ``"point-mass"``), ``robust`` (``"huber"`` | ``"cauchy"``),
    ``gate_probability``, ``estimate`` (the further graph variables, as ``--estimate``).
    Unknown names raise :class:`TypeError`."""
    from fgnav.solvers.options import SmootherOptions

    if "estimate" in kw:
        kw["estimate"] = _estimate_names(kw["estimate"])
    return SmootherOptions(**kw)


def smooth(log, method: str = "batch", *, truth=None, opts=None, lag_s: float = 300.0,
           ignore_prior: bool = False, **option_kw) -> Result:
    """Estimate the orbit (and any further variables) of a pass (``fgnav smooth``).

    log : a :class:`~fgnav.io.log_csv.MeasurementLog` (from :func:`read_log` or
        :func:`simulate`'s ``.log``) or a log file path.
    method : one of :data:`METHODS`.
    truth : optional: a truth OEM path, or the :class:`SimulatedPass` the log came from;
        adds errors, RMS and NEES to the summary.
    opts : :func:`options` (default options), or give the options as keywords here
        (``smooth(log, gravity="point-mass", q_m2_s3=1e-10)``), not both.
    lag_s : fixed-lag window (s). ignore_prior : start from the measurements' own orbit.
    """
    from fgnav.errors import UserError
    from fgnav.pipeline import read_measurements, smooth_log

    if opts is not None and option_kw:
        raise UserError("smooth: give the options either as opts=... or as keywords, not both")
    opts = options(**option_kw) if opts is None else opts
    if method not in METHODS:
        raise UserError(f"method: expected one of {', '.join(METHODS)}, found {method!r}")
    if isinstance(log, (str, Path)):
        log = read_measurements(log, opts.estimate)
    kw = {}
    if isinstance(truth, (str, Path)):
        kw["truth_path"] = truth
    elif truth is not None:
        kw["truth"] = _simulated_truth(truth, log)
    res, p = smooth_log(log, method, opts, lag_s=lag_s, ignore_prior=ignore_prior, **kw)
    return Result(res.solution, res.summary, res.x_true, p)


def write_outputs(result: Result, out_dir: str | Path) -> list[Path]:
    """Write ``fgnav smooth --out``'s files into ``out_dir`` (README, "Outputs"):
    trajectory.oem, summary.json, residuals.csv and what the method adds; the set replaces
    the directory's previous outputs only once complete. Returns the paths written."""
    from fgnav.pipeline import SmoothResult
    from fgnav.pipeline import write_outputs as _write

    return _write(out_dir, SmoothResult(result.solution, result.summary, result.x_true),
                  result.pass_)


def report(result_dir: str | Path, out_dir: str | Path | None = None, *, truth=None,
           k_sigma: float = 3.0) -> dict:
    """Plots and report of a result directory (``fgnav report``): PNG files (RTN errors or
    sigmas with the ±k_sigma band, residual histograms, the orbit in 3-D, latency),
    report.md and report.html. Returns ``{"markdown", "html", "images": {name: path},
    "notes", "figures"}``. Draws off screen (matplotlib's Agg backend)."""
    import matplotlib

    matplotlib.use("Agg")
    from fgnav.viz.report import report_result_dir

    return report_result_dir(result_dir, out_dir, truth_path=truth, k_sigma=k_sigma)


def plot_errors(result: Result, *, k_sigma: float = 3.0):
    """A matplotlib Figure of the RTN position/velocity errors against the truth with the
    ±k_sigma band (without truth: the sigmas alone), for notebooks; ``fig.savefig(path)``
    writes it."""
    from fgnav.viz.report import estimate_label, plot_state_errors

    sol = result.solution
    return plot_state_errors(sol.t_s, sol.x_eci, sol.P_eci, result.x_true, k_sigma=k_sigma,
                             label=estimate_label(sol.method))


def _estimate_names(names) -> tuple[str, ...]:
    from fgnav.commands.smooth import estimate_names

    return estimate_names(names)


def _simulated_truth(sim, log):
    """(t_s from ``log.epoch0``, x_eci) of a :class:`SimulatedPass`."""
    import numpy as np

    from fgnav.errors import UserError
    from fgnav.time import add_seconds, seconds_since

    if not (hasattr(sim, "x_true") and hasattr(sim, "epoch0")):
        raise UserError(f"truth: expected a truth OEM path or a SimulatedPass, found "
                        f"{type(sim).__name__}")
    t = np.asarray(seconds_since(add_seconds(sim.epoch0, sim.t_s), log.epoch0), dtype=float)
    t_log = np.asarray(log.t_s, dtype=float)
    if t[0] > t_log.min() + 1e-6 or t[-1] < t_log.max() - 1e-6:
        raise UserError("truth: the simulated pass does not cover the log's epochs")
    return t, np.asarray(sim.x_true, dtype=float)
