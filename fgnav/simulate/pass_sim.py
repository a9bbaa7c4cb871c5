"""Simulate a pass: truth from the independent integrator, measurements with seeded noise.

Truth comes from ``fgnav.orbit.integrate_truth`` (scipy DOP853, its own force model), never
from the estimator's propagator. Each ``[[sensor]]`` is simulated by its kind's simulator
(``fgnav.simulate.simulators.SIMULATORS[kind].simulate``, called in the scenario's sensor
order with one shared seeded Generator, so a seed gives the same log). Noise:

* direction, limb angular radius, altimeter: :mod:`fgnav.simulate.sensors`;
* body-frame Sun / Moon / Earth directions: :mod:`fgnav.simulate.body_directions`;
* attitude-free angles (body - star, limb - star, body - body):
  :mod:`fgnav.simulate.celestial_angles`;
* refraction: :mod:`fgnav.simulate.refraction_sim`; an atmosphere-model bias path ``b(t)``
  (:func:`~fgnav.simulate.refraction_sim.refraction_bias_path_m`) draws its random walk
  from its own stream, ``numpy.random.default_rng([seed, REFRACTION_BIAS_STREAM])``, so
  switching it on leaves the other draws' sequence as it was; the path, at every truth
  epoch, is ``SimulatedPass.truth_params["refraction_bias_m"]`` when refraction rows exist;
* prior: ``x_prior = x_true + e``, ``e ~ N(0, diag(sigma^2))`` ("random") or ``e = sigma``
  per axis ("fixed", Pan & Yao 2017's setting);
* declared manoeuvres (``Scenario.manoeuvres``): the truth is integrated in arcs between
  the burns, each burn adding its planned delta-v plus an execution error
  ``N(0, sigma^2 I)`` drawn from its own stream,
  ``numpy.random.default_rng([seed, MANOEUVRE_STREAM])`` (the other draws unchanged); the
  truth at a burn's epoch is the state just after it; the log carries each burn's declared
  ``manoeuvre`` row (planned delta-v, sigma), ``SimulatedPass.manoeuvres`` the executed ones.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from factors.geometry import so3_log
from fgnav.errors import UserError
from fgnav.io.log_csv import EXTRA_COLUMNS, MeasurementLog, log_from_arrays
from fgnav.io.log_csv import write_log
from fgnav.io.log_spacecraft import ID_COLUMNS
from fgnav.io.oem import oem_frame, write_oem
from fgnav.io.truth_params import (TRUTH_ATTITUDE_COLUMNS, TRUTH_ATTITUDE_CSV,
                                   TRUTH_REFRACTION_BIAS_CSV, write_truth_params_csv)
from fgnav.models.manoeuvres import MANOEUVRE_KIND
from fgnav.models.registry import (CAMERA_ALIGNMENT, EARTH_DIRECTION, EARTH_DIRECTION_BODY, LOG_SCHEMA, PRIOR_POSITION,
                                   PRIOR_VELOCITY, REFRACTION_BIAS, STAR_DIRECTION_BODY)
from fgnav.orbit import integrate_truth
from fgnav.scenarios import MAX_DURATION_H, MAX_EPOCHS, Scenario, SensorSpec, check_size
from fgnav.simulate.body_directions import lvlh_R_eci_from_body
from fgnav.simulate.refraction_sim import has_model_bias, refraction_bias_path_m
from fgnav.simulate.simulators import SIMULATORS
from fgnav.simulate.star_camera import draw_mounting_rotvec
from fgnav.time import j2000_seconds, parse_utc


@dataclass
class SimulatedPass:
    scenario: Scenario
    seed: int
    epoch0: np.datetime64
    t_s: np.ndarray          # (N,) truth epochs (every measurement epoch)
    x_true: np.ndarray       # (N,6)
    log: MeasurementLog
    truth_params: dict = field(default_factory=dict)
    """True values of model parameters at ``t_s``, name -> (N,) array; today
    ``"refraction_bias_m"`` (m), the atmosphere-model bias of a refraction sensor that has
    one (:func:`~fgnav.simulate.refraction_sim.refraction_bias_path_m`); ``"align_x"``,
    ``"align_y"``, ``"align_z"`` (rad, constant), the rotation vector of a star camera's
    mounting error (``mounting_sigma_arcsec``; the last such camera's)."""
    manoeuvres: tuple = ()
    """The executed burns: ``(t_s, dv_mps (3,))`` each, the planned delta-v plus the drawn
    execution error (the log's ``manoeuvre`` rows carry the planned one)."""

    def truth_attitude(self) -> np.ndarray:
        """The true attitude ``R_eci_from_body`` (N, 3, 3) at ``t_s``: the Earth-pointing
        (LVLH) plan every body-frame simulator observes in
        (:func:`fgnav.simulate.body_directions.lvlh_R_eci_from_body`)."""
        return lvlh_R_eci_from_body(self.x_true)


RAW_STAR_CAMERA = SensorSpec(STAR_DIRECTION_BODY.kind, star_sigma_arcsec=5.0, fov_deg=12.85,
                             vmag_max=5.5)
"""The star camera ``--raw-stars`` adds: Wu et al.'s star optics (f = 50 mm, 11 um pixels on
1024 x 1024: a 12.85 deg field), stars to V 5.5, 5 arcsec centroid 1-sigma per axis; looking
at the zenith of the Earth-pointing body (:mod:`fgnav.simulate.star_camera`)."""


def raw_star_scenario(scn: Scenario, camera: SensorSpec = RAW_STAR_CAMERA) -> Scenario:
    """``scn`` observed with raw stars (``fgnav simulate --raw-stars``): its ECI Earth-direction
    sensors measure in the body frame instead (same noise and period), and a star camera
    (``camera``, at the scenario's step) gives the attitude as raw star observations, so the
    attitude and the orbit are solved in one graph (``fgnav smooth --estimate attitude``).
    A scenario that already has a star camera keeps it (and gets no second one)."""
    sensors = [replace(s, kind=EARTH_DIRECTION_BODY.kind) if s.kind == EARTH_DIRECTION.kind
               else s for s in scn.sensors]
    if not any(s.kind == STAR_DIRECTION_BODY.kind for s in sensors):
        sensors.append(camera)
    return scn.with_options(sensors=tuple(sensors))


REFRACTION_BIAS_STREAM = 1
"""Second entropy word of the random-walk stream of the atmosphere-model bias."""
MANOEUVRE_STREAM = 3
"""Second entropy word of the stream of the manoeuvres' execution errors."""
MOUNTING_STREAM = 2
"""Second entropy word of the stream of the star camera's mounting error (drawn there, so a
mounting error leaves every other draw of the seed as it was: the same noise with and
without it)."""


def sensor_epochs(scn: Scenario, period_s: float | None) -> np.ndarray:
    period = scn.step_s if period_s is None else period_s
    n = int(np.floor(scn.duration_h * 3600.0 / period + 1e-9))
    return np.arange(n + 1) * period


def simulate_pass(scn: Scenario, seed: int = 0, *, max_epochs: int = MAX_EPOCHS,
                  max_duration_h: float = MAX_DURATION_H) -> SimulatedPass:
    """Truth and a measurement log for ``scn``; the same seed gives the same numbers.

    ``seed`` is an integer >= 0. A pass beyond ``max_epochs`` sensor epochs or
    ``max_duration_h`` hours is refused (:func:`fgnav.scenarios.check_size`). A formation
    scenario (``scn.formation``) is simulated by
    :func:`fgnav.simulate.formation_sim.simulate_formation_pass`.
    """
    check_seed(seed)
    if scn.formation is not None:
        raise UserError(f"scenario {scn.name}: several spacecraft; simulate it with "
                        "fgnav.simulate.formation_sim.simulate_formation_pass")
    check_size(scn, max_epochs, max_duration_h)
    epoch0 = parse_utc(scn.epoch)
    burns = executed_manoeuvres(scn, (seed,))
    t_all = truth_epochs(scn, [t for t, _ in burns])
    x_true = integrate_scenario_truth(scn, np.array(scn.x0_eci), t_all, burns)
    chunks, truth_params = sensor_chunks(scn, t_all, x_true, epoch0, (seed,))
    for m in scn.manoeuvres:   # the declared rows: the planned delta-v and its sigma
        chunks.append((MANOEUVRE_KIND, np.array([m.t_s]), np.array(m.dv_mps, float)[None],
                       m.sigma_mps))
    log = chunks_to_log(epoch0, chunks, centre=scn.centre)
    return SimulatedPass(scenario=scn, seed=seed, epoch0=epoch0, t_s=t_all, x_true=x_true, log=log,
                         truth_params=truth_params, manoeuvres=tuple(burns))


def executed_manoeuvres(scn: Scenario, words: tuple) -> list:
    """The scenario's burns as executed: ``[(t_s, planned + e)]``, ``e ~ N(0, sigma^2 I)``
    from the stream ``default_rng([*words, MANOEUVRE_STREAM])``; a burn outside the pass
    ``(0, duration]`` is a :class:`UserError`."""
    rng = np.random.default_rng([*words, MANOEUVRE_STREAM])
    out = []
    for i, m in enumerate(scn.manoeuvres):
        if not 0.0 < m.t_s <= scn.duration_h * 3600.0 + 1e-9:
            raise UserError(f"scenario {scn.name}: manoeuvre {i + 1} at t = {m.t_s / 3600:g} h: "
                            f"expected a time after the start and within the pass "
                            f"(0 < t <= {scn.duration_h:g} h)")
        out.append((float(m.t_s), np.array(m.dv_mps, float)
                    + m.sigma_mps * rng.standard_normal(3)))
    return out


def check_seed(seed) -> None:
    """A simulation seed is an integer >= 0 (:class:`UserError` otherwise)."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise UserError(f"seed: expected an integer >= 0, found {seed!r}")


def truth_epochs(scn: Scenario, *more) -> np.ndarray:
    """The truth epochs of a pass, s: t = 0, every sensor epoch and the epochs ``more``."""
    return np.unique(np.concatenate([[0.0], *[sensor_epochs(scn, s.period_s)
                                               for s in scn.sensors], *more]))


def integrate_scenario_truth(scn: Scenario, x0_eci, t_s, burns=()) -> np.ndarray:
    """The truth states (N, 6) at ``t_s`` from ``x0_eci`` at t = 0 under the scenario's force
    model (:func:`fgnav.orbit.integrate_truth`, scipy DOP853). ``burns``: impulsive burns
    ``(t_b, dv (3,))`` (each ``t_b`` one of ``t_s``, > 0): the truth is integrated in arcs
    between them, the velocity changed by ``dv`` at ``t_b`` (the state there: after it)."""
    t_s = np.asarray(t_s, dtype=float)
    t0 = float(j2000_seconds(parse_utc(scn.epoch)))

    def arc(x, t_from, t):
        return integrate_truth(np.asarray(x, dtype=float), t - t_from, j2=scn.truth_j2,
                               third_body=scn.truth_third_body, t0_j2000_s=t0 + t_from,
                               drag=scn.truth_drag or None, srp=scn.truth_srp or None,
                               centre=scn.centre)
    if not len(burns):
        return arc(x0_eci, 0.0, t_s)
    out = np.empty((len(t_s), 6))
    x, t_from = np.asarray(x0_eci, dtype=float), 0.0
    for t_b, dv in sorted(burns, key=lambda b: b[0]):
        sel = (t_s >= t_from) & (t_s <= t_b)
        if t_from == 0.0:
            sel |= t_s < 0.0
        out[sel] = arc(x, t_from, t_s[sel])
        x = arc(x, t_from, np.array([t_b]))[0]
        x[3:] += dv
        out[t_s == t_b] = x
        t_from = t_b
    sel = t_s > t_from
    out[sel] = arc(x, t_from, t_s[sel])
    return out


def sensor_chunks(scn: Scenario, t_all, x_true, epoch0, words: tuple):
    """The prior rows and every ``[[sensor]]``'s rows of one spacecraft with truth ``x_true``
    at ``t_all`` (which holds every sensor epoch), as chunks ``(kind, t_s, values, sigma,
    extra)``, and the truth of model parameters (``SimulatedPass.truth_params``).

    Random draws: ``numpy.random.default_rng(list(words))`` in sensor order; the bias and
    mounting streams append their stream number to ``words`` (``(seed,)`` for a pass of one
    spacecraft, the same numbers as ``default_rng(seed)``)."""
    rng = np.random.default_rng(list(words))
    chunks, truth_params = [], {}
    sp, sv = scn.prior_position_sigma_m, scn.prior_velocity_sigma_mps
    if scn.prior_mode != "none":   # "none": no prior rows (the orbit from the data alone)
        if scn.prior_mode == "random":
            err = rng.standard_normal(6) * np.array([sp] * 3 + [sv] * 3)
        else:
            err = np.array([sp] * 3 + [sv] * 3)
        chunks.append((PRIOR_POSITION.kind, np.array([0.0]), (x_true[0, :3] + err[:3])[None], sp))
        chunks.append((PRIOR_VELOCITY.kind, np.array([0.0]), (x_true[0, 3:] + err[3:])[None], sv))
    centre = {} if scn.centre == "earth" else {"centre": scn.centre}
    mounting_rng = np.random.default_rng([*words, MOUNTING_STREAM])
    for spec in scn.sensors:
        t = sensor_epochs(scn, spec.period_s)
        idx = np.searchsorted(t_all, t)
        bias = {}
        if has_model_bias(spec):   # only a refraction sensor takes the bias keys
            b_all = refraction_bias_path_m(
                spec, t_all, np.random.default_rng([*words, REFRACTION_BIAS_STREAM]))
            bias = {"bias_m": b_all[idx]}
        mount = {}
        if spec.kind == STAR_DIRECTION_BODY.kind:
            w = draw_mounting_rotvec(spec, mounting_rng)
            if w is not None:
                mount = {"mounting_rotvec": w}
                truth_params.update({c: np.full(len(t_all), w[i])
                                     for i, c in enumerate(CAMERA_ALIGNMENT.components)})
        got = SIMULATORS[spec.kind].simulate(spec, t, x_true[idx], epoch0, rng, **bias, **mount,
                                          **centre)
        if bias and any(c[0] == spec.kind for c in got):
            truth_params[REFRACTION_BIAS.components[0]] = b_all
        chunks.extend(got)
    return chunks, truth_params


def chunks_to_log(epoch0, chunks, *, spacecraft=(), antennas=None,
                  centre: str = "earth") -> MeasurementLog:
    """One log of chunks ``(kind, t_s, values (n, 3), sigma, extra dict or None)``, rows
    stably sorted by epoch (chunk order within an epoch). Id columns (``spacecraft``, ...)
    hold names (:func:`fgnav.io.log_csv.log_from_arrays`)."""
    kinds, ts, xyz, sig, extras = [], [], [], [], []
    for chunk in chunks:
        kind, t, values, sigma = chunk[:4]
        extra = chunk[4] if len(chunk) > 4 else None
        kinds.extend([kind] * len(t))
        ts.append(t)
        xyz.append(values)
        sig.append(np.broadcast_to(sigma, (len(t),)).astype(float))
        extras.append((len(t), extra))
    t_cat = np.concatenate(ts)
    order = np.argsort(t_cat, kind="stable")
    extra = None
    if any(e is not None for _, e in extras):  # extra columns (refraction, star, id rows) only
        extra = {}
        for c in EXTRA_COLUMNS:
            if c in ID_COLUMNS:
                if any(e is not None and c in e for _, e in extras):
                    extra[c] = np.concatenate([np.full(n, None, dtype=object) if e is None or c not in e
                                               else np.asarray(e[c], dtype=object)
                                               for n, e in extras])[order]
                continue
            extra[c] = np.concatenate([np.full(n, np.nan) if e is None or c not in e
                                       else np.asarray(e[c], dtype=float) for n, e in extras])[order]
    return log_from_arrays(epoch0, t_cat[order], np.array(kinds, dtype=object)[order],
                           np.concatenate(xyz)[order], np.concatenate(sig)[order], extra,
                           spacecraft=spacecraft, antennas=antennas, centre=centre,
                           schema=LOG_SCHEMA)


def write_pass_files(out_dir, sim: SimulatedPass) -> list:
    """Write a simulated pass as ``fgnav simulate`` does: ``measurements.csv`` (log format
    v1), ``truth.oem`` (the truth states, CCSDS OEM) and, for a refraction sensor with an
    atmosphere-model bias, ``truth_refraction_bias.csv`` and, for a separately mounted star
    camera, ``truth_camera_alignment.csv`` and, for body-frame rows, ``truth_attitude.csv``
    (the attitude plan), into the existing directory
    ``out_dir``. Returns the paths written; an unwritable directory is a :class:`UserError`."""
    from pathlib import Path

    out, scn = Path(out_dir), sim.scenario
    try:
        write_log(out / "measurements.csv", sim.log, schema=LOG_SCHEMA)
        write_oem(out / "truth.oem", sim.epoch0, sim.t_s, sim.x_true, None,
                  object_name=scn.name.upper(), **oem_frame(scn.centre),
                  comments=(f"fgnav truth for scenario {scn.name}, seed {sim.seed}",
                            "scipy DOP853 rtol 1e-12 (independent of the estimator's propagator)"))
        written = [out / "measurements.csv", out / "truth.oem"]
        if "refraction_bias_m" in sim.truth_params:
            written.append(out / TRUTH_REFRACTION_BIAS_CSV)
            write_truth_params_csv(
                written[-1], sim.epoch0, sim.t_s,
                {"refraction_bias_m": sim.truth_params["refraction_bias_m"]},
                comments=(f"scenario {scn.name}, seed {sim.seed}: the real atmosphere's "
                          "tangent-height shift against the refraction model, m",))
        align = ("align_x", "align_y", "align_z")   # = registry.CAMERA_ALIGNMENT.components
        if align[0] in sim.truth_params:
            written.append(out / "truth_camera_alignment.csv")
            write_truth_params_csv(
                written[-1], sim.epoch0, sim.t_s, {c: sim.truth_params[c] for c in align},
                comments=(f"scenario {scn.name}, seed {sim.seed}: the star camera's mounting "
                          "R_body_from_starcam as a rotation vector, rad (constant)",))
        if sim.manoeuvres:
            written.append(out / "truth_manoeuvres.csv")
            t_b = np.array([t for t, _ in sim.manoeuvres])
            dv = np.array([d for _, d in sim.manoeuvres])
            write_truth_params_csv(
                written[-1], sim.epoch0, t_b,
                {f"dv_{c}_mps": dv[:, i] for i, c in enumerate("xyz")},
                comments=(f"scenario {scn.name}, seed {sim.seed}: the executed delta-v of each "
                          "declared manoeuvre (planned + execution error), m/s, EME2000",))
        if any(str(k).endswith("_body") for k in set(sim.log.kind)):
            written.append(out / TRUTH_ATTITUDE_CSV)
            w = so3_log(sim.truth_attitude())
            write_truth_params_csv(
                written[-1], sim.epoch0, sim.t_s, dict(zip(TRUTH_ATTITUDE_COLUMNS, w.T)),
                comments=(f"scenario {scn.name}, seed {sim.seed}: the attitude plan's "
                          "R_eci_from_body (body-frame rows refer to it) as a rotation vector, rad",))
    except OSError as exc:
        raise UserError(f"--out {out}: cannot write: {exc.strerror or exc}") from None
    return written
