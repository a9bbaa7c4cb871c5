"""The sensor simulators by log kind: what a scenario's ``[[sensor]]`` of each kind produces.

The simulation layer registers its simulators here, by kind, instead of the measurement
models carrying them (the models sit below the simulator; Orekit's measurement builders,
``estimation/measurements/generation``, likewise live beside the measurements they build,
not in them). A :class:`Simulator` holds

* ``simulate(spec, t_s, x_true, epoch0, rng, **kw) -> [chunk, ...]``: rows of the sensor at
  the epochs ``t_s`` (s from ``epoch0``) from the true states ``x_true`` (N, 6), each chunk
  ``(kind, t_s, values (n, 3), sigma[, extra])`` (:func:`fgnav.simulate.pass_sim.chunks_to_log`);
  the keyword arguments a sensor may take are ``bias_m`` (a refraction sensor's atmosphere
  bias path), ``mounting_rotvec`` (a star camera's mounting) and ``centre`` (a heliocentric
  scenario's central body);
* ``scenario_keys``: the keys the ``[[sensor]]`` table takes besides ``kind`` and ``period_s``
  (:data:`fgnav.scenarios.SENSOR_KIND_KEYS`).

To simulate a new kind, add its entry to :data:`SIMULATORS` (or call :func:`register`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable

from fgnav.models.registry import (ALTITUDE, BODY_BODY_ANGLE, BODY_DIRECTION, BODY_DIRECTION_BODY,
                                   BODY_STAR_ANGLE, EARTH_DIRECTION,
                                   EARTH_DIRECTION_BODY, LIMB_RADIUS, LIMB_STAR_ANGLE,
                                   MOON_DIRECTION_BODY, REFRACTION, STAR_DIRECTION_BODY,
                                   SUN_DIRECTION_BODY)
from fgnav.simulate.body_directions import (earth_centre_target, moon_target,
                                            simulate_body_direction_rows, sun_target)
from fgnav.simulate.celestial_angles import simulate_angle_rows
from fgnav.simulate.near_bodies import simulate_near_body_rows
from fgnav.simulate.refraction_sim import MODEL_BIAS_KEYS, simulate_refraction_rows
from fgnav.simulate.sensors import (altitude_readings, geocentric_direction_readings,
                                    limb_radius_readings)
from fgnav.simulate.star_camera import simulate_star_camera_rows

__all__ = ["Simulator", "SIMULATORS", "register", "simulator", "simulated_kinds"]


@dataclass(frozen=True)
class Simulator:
    """How a scenario's sensor of one log kind is simulated (the module docstring)."""

    kind: str
    simulate: Callable
    scenario_keys: tuple[str, ...] = ()


def readings(fn):
    """A simulator from a readings function ``(spec, t, x_true, rng) -> (xyz, sigma)``: rows
    of the sensor's own kind (``spec.kind``, the kind the simulator was chosen by)."""
    def simulate(spec, t_s, x_true, epoch0, rng):
        xyz, sigma = fn(spec, t_s, x_true, rng)
        return [(spec.kind, t_s, xyz, sigma)]
    return simulate


_STAR_KEYS = ("sigma_deg", "body", "stars_per_epoch", "vmag_max", "min_sun_elongation_deg",
              "star_spread")


def _body(seen):
    return functools.partial(simulate_body_direction_rows, target=seen)


def _near(form):
    return functools.partial(simulate_near_body_rows, form=form)


def _limb(spec, t_s, x_true, epoch0, rng, centre="earth"):
    """``limb_radius`` rows: the Earth's limb sphere at the origin as ever (no ``body``
    column; ``body = "earth"``, the default), or the apparent limb of the Moon or the Sun
    (rows with their ``body``: :func:`fgnav.simulate.near_bodies.simulate_near_body_rows`)."""
    if spec.body == "earth":
        return readings(limb_radius_readings)(spec, t_s, x_true, epoch0, rng)
    return simulate_near_body_rows(spec, t_s, x_true, epoch0, rng, form="limb", centre=centre)


def _angle(star, limb):
    return functools.partial(simulate_angle_rows, star=star, limb=limb)


SIMULATORS: dict[str, Simulator] = {s.kind: s for s in (
    Simulator(EARTH_DIRECTION.kind, readings(geocentric_direction_readings), ("sigma_deg",)),
    Simulator(LIMB_RADIUS.kind, _limb, ("sigma_deg", "r_limb_km", "body")),
    Simulator(ALTITUDE.kind, readings(altitude_readings), ("sigma_m",)),
    Simulator(REFRACTION.kind, simulate_refraction_rows,
              ("gamma_halfwidth_arcsec", "sigma_model_m", "star_sigma_arcsec", "fov_deg",
               "vmag_max", "azimuths_deg", "boresight_tangent_km") + MODEL_BIAS_KEYS),
    Simulator(EARTH_DIRECTION_BODY.kind, _body(earth_centre_target), ("sigma_deg",)),
    Simulator(SUN_DIRECTION_BODY.kind, _body(sun_target), ("sigma_deg",)),
    Simulator(MOON_DIRECTION_BODY.kind, _body(moon_target),
              ("sigma_deg", "min_sun_elongation_deg")),
    Simulator(STAR_DIRECTION_BODY.kind, simulate_star_camera_rows,
              ("star_sigma_arcsec", "fov_deg", "vmag_max", "mounting_sigma_arcsec")),
    Simulator(BODY_STAR_ANGLE.kind, _angle(True, False), _STAR_KEYS),
    Simulator(LIMB_STAR_ANGLE.kind, _angle(True, True), _STAR_KEYS + ("r_limb_km",)),
    Simulator(BODY_BODY_ANGLE.kind, _angle(False, False), ("sigma_deg", "body", "body2")),
    Simulator(BODY_DIRECTION.kind, _near("direction"), ("sigma_deg", "body")),
    Simulator(BODY_DIRECTION_BODY.kind, _near("direction_body"), ("sigma_deg", "body")),
)}
"""Every simulated kind's simulator, by kind (in the measurement models' order)."""


def register(sim: Simulator) -> Simulator:
    """Add (or replace) the simulator of ``sim.kind`` (:func:`fgnav.simulate.pass_sim.
    simulate_pass` looks it up per sensor); returns it."""
    SIMULATORS[sim.kind] = sim
    return sim


def simulator(kind: str) -> Simulator:
    """The simulator of a log kind (KeyError for a kind nothing simulates)."""
    return SIMULATORS[kind]


def simulated_kinds() -> tuple[str, ...]:
    """Kinds a scenario's ``[[sensor]]`` may simulate."""
    return tuple(SIMULATORS)
