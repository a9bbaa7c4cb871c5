"""Built-in and user scenarios: TOML files read into frozen dataclasses (data, not code).

A scenario names the orbit (a Cartesian state or classical elements), the truth force model,
the a-priori error, and the sensors; see ``data/scenarios/*.toml``.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from fgnav.errors import InputFormatError, UserError
from fgnav.paths import data_dir

SENSOR_KINDS = ("earth_direction", "limb_radius", "altitude", "refraction",
                "earth_direction_body", "sun_direction_body", "moon_direction_body")


@dataclass(frozen=True)
class SensorSpec:
    """One simulated sensor. ``sigma_deg`` for angles, ``sigma_m`` for the altimeter;
    ``period_s`` defaults to the scenario's step."""

    kind: str
    sigma_deg: float | None = None
    sigma_m: float | None = None
    period_s: float | None = None
    r_limb_km: float = 6375.0
    # refraction sensor (seed 004; fgnav.simulate.refraction_sim): heads grazing the limb
    gamma_halfwidth_arcsec: float = 1.0    # refraction-angle error, uniform on [-D, D]
    sigma_model_m: float = 100.0           # atmosphere-model error on the tangent height, 1σ
    star_sigma_arcsec: float = 3.0         # centroid 1σ of an unrefracted star (attitude)
    fov_deg: float = 20.0                  # full width of each head's square field
    vmag_max: float = 6.0                  # faintest star used
    azimuths_deg: tuple = (0.0, 120.0, 240.0)  # head boresights about nadir, from velocity
    boresight_tangent_km: float = 35.0     # tangent height of the ray at the field centre
    # body-frame directions (seed 001; fgnav.simulate.sem_sim): body = LVLH
    min_sun_elongation_deg: float = 30.0   # Moon sensor blinded closer than this to the Sun


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    epoch: str                         # ISO-8601 UTC of t = 0
    duration_h: float
    step_s: float
    x0_eci: tuple                      # (6,) truth initial state, SI
    truth_j2: bool = True
    truth_third_body: bool = False
    truth_drag: bool = False
    truth_srp: bool = False
    prior_position_sigma_m: float = 10000.0
    prior_velocity_sigma_mps: float = 2.0
    prior_mode: str = "random"         # "random" | "fixed"
    sensors: tuple = field(default_factory=tuple)
    source: str = ""

    def with_options(self, **kw) -> "Scenario":
        return replace(self, **{k: v for k, v in kw.items() if v is not None})


def builtin_names() -> list[str]:
    return sorted(p.stem for p in (data_dir() / "scenarios").glob("*.toml"))


def _orbit_state(path, orbit: dict) -> tuple:
    if "r_eci_m" in orbit:
        return tuple(float(v) for v in list(orbit["r_eci_m"]) + list(orbit["v_eci_mps"]))
    from fgnav.constants import DEG, MU_EARTH_M3_S2
    from fgnav.orbit import elements_to_state, mean_to_true_anomaly

    try:
        e = float(orbit["e"])
        if "true_anomaly_deg" in orbit:
            nu = orbit["true_anomaly_deg"] * DEG
        else:
            nu = mean_to_true_anomaly(orbit["mean_anomaly_deg"] * DEG, e)
        x = elements_to_state(float(orbit["a_m"]), e, orbit["i_deg"] * DEG, orbit["raan_deg"] * DEG,
                              orbit["argp_deg"] * DEG, nu, MU_EARTH_M3_S2)
    except KeyError as exc:
        raise InputFormatError(path, None, f"orbit.{exc.args[0]}",
                               "either r_eci_m + v_eci_mps, or a_m, e, i_deg, raan_deg, argp_deg "
                               "and true_anomaly_deg or mean_anomaly_deg") from None
    return tuple(float(v) for v in np.asarray(x).ravel())


def load_scenario(name_or_path: str) -> Scenario:
    """A built-in scenario by name (``gto-transfer``) or a TOML file by path."""
    path = Path(name_or_path)
    if not path.suffix:
        path = data_dir() / "scenarios" / f"{name_or_path}.toml"
        if not path.exists():
            raise UserError(f"unknown scenario '{name_or_path}'; built-in: {', '.join(builtin_names())}")
    if not path.exists():
        raise UserError(f"{path}: no such scenario file")
    try:
        d = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise InputFormatError(path, getattr(exc, "lineno", None), None, f"valid TOML ({exc})") from None
    try:
        sensors = []
        for s in d.get("sensor", []):
            if s.get("kind") not in SENSOR_KINDS:
                raise InputFormatError(path, None, "sensor.kind", f"one of {SENSOR_KINDS}", s.get("kind"))
            sensors.append(SensorSpec(**s))
        prior = d.get("prior", {})
        truth = d.get("truth", {})
        scn = Scenario(
            name=d.get("name", path.stem), description=d.get("description", ""),
            epoch=d["epoch"], duration_h=float(d["duration_h"]), step_s=float(d["step_s"]),
            x0_eci=_orbit_state(path, d["orbit"]), truth_j2=bool(truth.get("j2", True)),
            truth_third_body=bool(truth.get("third_body", False)),
            truth_drag=bool(truth.get("drag", False)), truth_srp=bool(truth.get("srp", False)),
            prior_position_sigma_m=float(prior.get("position_sigma_m", 10000.0)),
            prior_velocity_sigma_mps=float(prior.get("velocity_sigma_mps", 2.0)),
            prior_mode=prior.get("mode", "random"), sensors=tuple(sensors), source=str(path))
    except KeyError as exc:
        raise InputFormatError(path, None, exc.args[0], "this key (see data/scenarios/gto-transfer.toml)") from None
    except TypeError as exc:
        raise InputFormatError(path, None, "sensor", f"known sensor keys ({exc})") from None
    if scn.prior_mode not in ("random", "fixed"):
        raise InputFormatError(path, None, "prior.mode", "'random' or 'fixed'", scn.prior_mode)
    if scn.duration_h <= 0 or scn.step_s <= 0:
        raise InputFormatError(path, None, "duration_h/step_s", "positive numbers")
    if not scn.sensors:
        raise InputFormatError(path, None, "sensor", "at least one [[sensor]] table")
    return scn
