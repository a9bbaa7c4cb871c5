"""Built-in and user scenarios: TOML files read into frozen dataclasses (data, not code).

A scenario names the orbit (a Cartesian state or classical elements), the truth force model,
the a-priori error, and the sensors; see ``data/scenarios/*.toml``. Every key is checked
on load (:func:`load_scenario`): its type, unit and range are those of :data:`TOP_KEYS`,
:data:`ORBIT_KEYS`, :data:`TRUTH_KEYS`, :data:`PRIOR_KEYS` and :data:`SENSOR_KEYS`; an
unknown key, a key that does not apply to a sensor kind, a wrong type, a value out of
range, NaN or infinity is an :class:`~fgnav.errors.InputFormatError` naming the file, the
line, the key (``sensor[2].sigma_deg``) and what was expected.

Size limits (:func:`check_size`): a simulated pass has at most :data:`MAX_EPOCHS` sensor
epochs (summed over the sensors) and lasts at most :data:`MAX_DURATION_H` hours, unless the
caller raises the limits (``fgnav simulate --max-epochs N --max-duration-h H``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from fgnav.constants import DEG, MU_EARTH_M3_S2, R_EARTH_M, R_SUN_M
from fgnav.errors import InputFormatError, UserError
from fgnav.io.log_csv import BODIES, CENTRES, HELIOCENTRIC_KINDS
from fgnav.io.text import parse_toml, read_utf8_text
from fgnav.io.toml_schema import (TomlSource, check_keys, check_value, expected, keyed,
                                  table_of)
from fgnav.orbit import elements_to_state, mean_to_true_anomaly
from fgnav.paths import data_dir
from fgnav.simulate.refraction_sim import MODEL_BIAS_KEYS
from fgnav.simulate.simulators import SIMULATORS, simulated_kinds
from fgnav.time import parse_utc, seconds_since

SENSOR_KINDS = simulated_kinds()
"""The kinds a ``[[sensor]]`` may simulate: every kind with a simulator
(:data:`fgnav.simulate.simulators.SIMULATORS`)."""

MAX_EPOCHS = 1_000_000
"""Default limit on the sensor epochs of a simulated pass (summed over the sensors): 1e6
epochs take minutes and ~250 MB of files (about 13 s and 25 MB per 100,000 here)."""

MAX_DURATION_H = 744.0
"""Default limit on a simulated pass's length, h (31 days: the truth integrator's cost grows
with the number of orbits, ~8 s per simulated day in LEO with every force)."""


@dataclass(frozen=True)
class SensorSpec:
    """One simulated sensor. ``sigma_deg`` for angles, ``sigma_m`` for the altimeter;
    ``period_s`` defaults to the scenario's step."""

    kind: str
    sigma_deg: float | None = None
    sigma_m: float | None = None
    period_s: float | None = None
    r_limb_km: float = 6375.0
    # refraction sensor (Li et al. 2017; fgnav.simulate.refraction_sim): heads grazing the limb
    gamma_halfwidth_arcsec: float = 1.0    # refraction-angle error, uniform on [-D, D]
    sigma_model_m: float = 100.0           # atmosphere-model error on the tangent height, 1σ
    star_sigma_arcsec: float = 3.0         # centroid 1σ of an unrefracted star (attitude)
    fov_deg: float = 20.0                  # full width of each head's square field
    vmag_max: float = 6.0                  # faintest star used
    # (star_sigma_arcsec, fov_deg, vmag_max are also the star camera's, kind
    # star_direction_body: fgnav.simulate.star_camera, a zenith camera on the LVLH body)
    azimuths_deg: tuple = (0.0, 120.0, 240.0)  # head boresights about nadir, from velocity
    boresight_tangent_km: float = 35.0     # tangent height of the ray at the field centre
    # the real atmosphere's height shift against the refraction model, b(t) (m): b0 + drift t
    # + a seeded random walk (fgnav.simulate.refraction_sim.refraction_bias_path_m); 0 = none
    model_bias_m: float = 0.0              # b at the pass start (t = 0)
    model_bias_drift_m_per_h: float = 0.0  # deterministic drift rate
    model_bias_random_walk_m_per_sqrt_h: float = 0.0  # random-walk diffusion, 1σ after 1 h
    # body-frame directions (the INS/CNS lecture; fgnav.simulate.body_directions): body = LVLH
    min_sun_elongation_deg: float = 30.0   # Moon sensor blinded closer than this to the Sun
    # attitude-free angles (fgnav.simulate.celestial_angles): near bodies by name
    body: str = "earth"                    # the near body of an angle sensor
    body2: str = "moon"                    # the second near body of a body-body angle
    stars_per_epoch: float = 3.0           # stars measured against the body at each epoch
    star_spread: str = "sky"               # "sky": directions spread; "axes": cone axes (s ~ -s)
    # a star camera on its own mount (not the Earth camera's detector): a constant mounting
    # error, 1σ per axis, drawn once per pass (fgnav.simulate.star_camera); 0 = confocal
    mounting_sigma_arcsec: float = 0.0


MANOEUVRE_SIGMA_MPS = 0.01
"""Default execution error of a declared manoeuvre, 1-sigma per axis (m/s)."""


@dataclass(frozen=True)
class ManoeuvreSpec:
    """A declared impulsive manoeuvre (``[[manoeuvres]]``, ``fgnav simulate --manoeuvre``):
    at ``t_s`` after the pass start the truth's velocity changes by ``dv_mps`` (EME2000,
    m/s) plus an execution error ``N(0, sigma_mps^2 I)`` drawn from the seed, and the log
    carries the declared row (``manoeuvre``: the planned delta-v and ``sigma_mps``)."""

    t_s: float
    dv_mps: tuple
    sigma_mps: float = MANOEUVRE_SIGMA_MPS


@dataclass(frozen=True)
class SpacecraftSpec:
    """One spacecraft of a formation (``[[spacecraft]]``). Its orbit: ``x0_eci`` (its own
    ``[spacecraft.orbit]`` table) or, when None, the scenario's ``[orbit]`` truth ``lead_s``
    seconds later (a leader-follower pair on one orbit: ``lead_s`` > 0 flies ahead). Its
    attitude: the Earth-pointing LVLH plan of its own orbit
    (:func:`fgnav.simulate.body_directions.lvlh_R_eci_from_body`) turned by ``yaw_deg`` about
    the body z axis (nadir)."""

    id: str
    x0_eci: tuple | None = None
    lead_s: float = 0.0
    yaw_deg: float = 0.0


@dataclass(frozen=True)
class LinkSpec:
    """One inter-satellite link (``[[link]]``): ``rx`` receives from ``tx``, antenna to antenna
    (empty name: the centre of mass)."""

    rx: str
    tx: str
    rx_antenna: str = ""
    tx_antenna: str = ""


@dataclass(frozen=True)
class RangingSpec:
    """The links' measurement and clock (``[ranging]``), SI. ``carrier_sigma_m`` 0: no carrier
    rows. The relative clock ``c (dt_1 - dt_2)`` of the first two spacecraft starts at
    ``N(0, clock_sigma0_m^2)`` and random-walks with ``clock_random_walk_m_per_sqrt_s``
    (1-sigma growth per sqrt(s)). ``attitude_sigma_rad`` the noise of the attitude
    rows, written when a link uses an antenna (its lever arm needs the attitude)."""

    sigma_m: float
    period_s: float | None = None
    carrier_sigma_m: float = 0.0
    ambiguity_sigma_m: float = 1.0
    clock_sigma0_m: float = 1.0
    clock_random_walk_m_per_sqrt_s: float = 0.01
    attitude_sigma_rad: float = 4.84813681109536e-06   # 1 arcsec, a star tracker's


@dataclass(frozen=True)
class FormationSpec:
    """Several spacecraft and their links; every spacecraft carries the scenario's
    ``[[sensor]]`` list (its own rows and noise draws)."""

    spacecraft: tuple          # SpacecraftSpec, in order (the first is the reference)
    antennas: tuple            # ((spacecraft id, antenna name, (x, y, z) body m), ...)
    links: tuple               # LinkSpec
    ranging: RangingSpec

    @property
    def ids(self) -> tuple:
        return tuple(s.id for s in self.spacecraft)


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
    prior_mode: str = "random"         # "random" | "fixed" | "none" (no prior rows)
    sensors: tuple = field(default_factory=tuple)
    source: str = ""
    formation: "FormationSpec | None" = None
    """Several spacecraft with inter-satellite links (``[[spacecraft]]``, ``[[antenna]]``,
    ``[[link]]``, ``[ranging]``); None: one spacecraft on ``[orbit]``."""
    centre: str = "earth"              # "earth" | "sun": the centre of x0_eci and of the log
    manoeuvres: tuple = ()             # ManoeuvreSpec, declared impulsive burns

    def with_options(self, **kw) -> "Scenario":
        """A copy with the given fields replaced (``None`` keeps a field); ``step_s`` and
        ``duration_h`` must be finite and > 0 (a :class:`UserError` names the option)."""
        for key in ("step_s", "duration_h"):
            v = kw.get(key)
            if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise UserError(f"{key} (--{key.replace('_', '-')}): expected a finite number "
                                f"> 0, found {v!r}")
        return replace(self, **{k: v for k, v in kw.items() if v is not None})


# ------------------------------------------------------------------------------ schema
# key -> (type, unit, low, high, low inclusive, high inclusive); type "number", "bool",
# "str", "vec3" (3 finite numbers), "numbers" (a non-empty array of finite numbers)
_INF = math.inf
TOP_KEYS = {
    "name": ("str", "", None, None, True, True),
    "description": ("str", "", None, None, True, True),
    "epoch": ("epoch", "", None, None, True, True),
    "duration_h": ("number", "h", 0.0, _INF, False, False),
    "step_s": ("number", "s", 0.0, _INF, False, False),
    "centre": ("choice", "", CENTRES, None, True, True),
}
TOP_TABLES = ("orbit", "truth", "prior", "sensor", "spacecraft", "antenna", "link", "ranging",
              "manoeuvres")
_ARRAY_TABLES = ("sensor", "spacecraft", "antenna", "link", "manoeuvres")
"""The ``[[...]]`` arrays of tables (errors count their elements)."""
ORBIT_KEYS = {
    "r_eci_m": ("vec3", "m", None, None, True, True),
    "v_eci_mps": ("vec3", "m/s", None, None, True, True),
    "a_m": ("number", "m", 0.0, _INF, False, False),
    "e": ("number", "", 0.0, 1.0, True, False),
    "i_deg": ("number", "deg", 0.0, 180.0, True, True),
    "raan_deg": ("number", "deg", -_INF, _INF, False, False),
    "argp_deg": ("number", "deg", -_INF, _INF, False, False),
    "true_anomaly_deg": ("number", "deg", -_INF, _INF, False, False),
    "mean_anomaly_deg": ("number", "deg", -_INF, _INF, False, False),
}
_CARTESIAN = ("r_eci_m", "v_eci_mps")
_ELEMENTS = ("a_m", "e", "i_deg", "raan_deg", "argp_deg")
TRUTH_KEYS = {k: ("bool", "", None, None, True, True) for k in ("j2", "third_body", "drag", "srp")}
PRIOR_KEYS = {
    "position_sigma_m": ("number", "m", 0.0, 1e9, False, True),
    "velocity_sigma_mps": ("number", "m/s", 0.0, 1e5, False, True),
    "mode": ("choice", "", ("random", "fixed", "none"), None, True, True),
}
SENSOR_KEYS = {
    "kind": ("choice", "", SENSOR_KINDS, None, True, True),
    "period_s": ("number", "s", 0.0, _INF, False, False),
    "sigma_deg": ("number", "deg", 0.0, 45.0, False, True),
    "sigma_m": ("number", "m", 0.0, 1e6, False, True),
    "r_limb_km": ("number", "km", 6000.0, 7000.0, True, True),
    "gamma_halfwidth_arcsec": ("number", "arcsec", 0.0, 3600.0, True, True),
    "sigma_model_m": ("number", "m", 0.0, 1e5, True, True),
    "star_sigma_arcsec": ("number", "arcsec", 0.0, 3600.0, False, True),
    "fov_deg": ("number", "deg", 0.0, 90.0, False, True),
    "vmag_max": ("number", "mag", -2.0, 10.0, True, True),
    "azimuths_deg": ("numbers", "deg", None, None, True, True),
    "boresight_tangent_km": ("number", "km", 0.0, 100.0, True, True),
    "model_bias_m": ("number", "m", -1e5, 1e5, True, True),
    "model_bias_drift_m_per_h": ("number", "m/h", -1e5, 1e5, True, True),
    "model_bias_random_walk_m_per_sqrt_h": ("number", "m/sqrt(h)", 0.0, 1e5, True, True),
    "min_sun_elongation_deg": ("number", "deg", 0.0, 180.0, True, True),
    "body": ("choice", "", BODIES, None, True, True),
    "body2": ("choice", "", BODIES, None, True, True),
    "stars_per_epoch": ("number", "", 1.0, 50.0, True, True),
    "star_spread": ("choice", "", ("sky", "axes"), None, True, True),
    "mounting_sigma_arcsec": ("number", "arcsec", 0.0, 3600.0, True, True),
}
MANOEUVRE_KEYS = {
    "t_h": ("number", "h", 0.0, _INF, False, True),
    "dv_mps": ("vec3", "m/s", None, None, True, True),
    "sigma_mps": ("number", "m/s", 1e-6, 1e3, True, True),
}
"""A ``[[manoeuvres]]`` table (:class:`ManoeuvreSpec`): the burn's time ``t_h`` after the
pass start (h, > 0), its planned delta-v ``dv_mps`` (EME2000, m/s) and its execution error
``sigma_mps`` (1-sigma per axis, m/s; default :data:`MANOEUVRE_SIGMA_MPS`)."""

SPACECRAFT_KEYS = {
    "id": ("id", "", None, None, True, True),
    "lead_s": ("number", "s", -86400.0, 86400.0, True, True),
    "yaw_deg": ("number", "deg", -360.0, 360.0, True, True),
    "orbit": ("table", "", None, None, True, True),
}
ANTENNA_KEYS = {
    "spacecraft": ("id", "", None, None, True, True),
    "name": ("id", "", None, None, True, True),
    "body_m": ("vec3", "m", None, None, True, True),
}
LINK_KEYS = {
    "rx": ("id", "", None, None, True, True),
    "tx": ("id", "", None, None, True, True),
    "rx_antenna": ("id", "", None, None, True, True),
    "tx_antenna": ("id", "", None, None, True, True),
}
RANGING_KEYS = {
    "sigma_m": ("number", "m", 1e-6, 1e4, True, True),
    "period_s": ("number", "s", 0.0, _INF, False, False),
    "carrier_sigma_m": ("number", "m", 0.0, 1.0, True, True),
    "ambiguity_sigma_m": ("number", "m", 0.0, 1e6, True, True),
    "clock_sigma0_m": ("number", "m", 0.0, 1e6, True, True),
    "clock_random_walk_m_per_sqrt_s": ("number", "m/sqrt(s)", 0.0, 1e3, True, True),
    "attitude_sigma_arcsec": ("number", "arcsec", 0.0, 3600.0, False, True),
}
"""The formation tables (:class:`FormationSpec`): ``[[spacecraft]]`` (``id``, then either
``lead_s`` or a ``[spacecraft.orbit]`` table, and ``yaw_deg``), ``[[antenna]]`` (lever arm
``body_m`` of antenna ``name`` on ``spacecraft``, |.| <= 1000 m), ``[[link]]`` and
``[ranging]`` (``sigma_m`` required; ``carrier_sigma_m`` > 0 adds carrier-phase rows)."""
MAX_ANTENNA_ARM_M = 1000.0

SENSOR_KIND_KEYS = {kind: SIMULATORS[kind].scenario_keys for kind in SENSOR_KINDS}
"""Keys each sensor kind takes besides ``kind`` and ``period_s`` (its simulator's
``scenario_keys``, ``fgnav.simulate.simulators``); ``sigma_deg`` and
``sigma_m`` are required where listed."""
_SENSOR_REQUIRED = ("sigma_deg", "sigma_m")



MAX_ORBIT_RADIUS_M = 1e13
"""A scenario's initial position lies within this distance (m) of the centre (as a log's
positions, ``fgnav.io.log_csv.MAX_DISTANCE_M``): 67 au."""

def builtin_names() -> list[str]:
    return sorted(p.stem for p in (data_dir() / "scenarios").glob("*.toml"))


R_SUN_PHOTOSPHERE_M = R_SUN_M
"""A heliocentric orbit stays outside the Sun's photosphere (``factors.constants.R_SUN_M``)."""


def _orbit_state(src: TomlSource, orbit: dict, table: str = "orbit", index: int = 0,
                 label: str = "orbit", centre: str = "earth") -> tuple:
    """The truth state (6,) of an ``[orbit]`` table (or of ``[spacecraft.orbit]``: ``table``,
    ``index`` and ``label`` name it in errors), about the scenario's ``centre``."""
    check_keys(src, table, index, orbit, tuple(ORBIT_KEYS), f"{label}.", f"[{label}]")
    v = {k: check_value(src, table, index, k, orbit[k], ORBIT_KEYS[k], f"{label}.{k}") for k in orbit}
    forms = "either r_eci_m + v_eci_mps, or a_m, e, i_deg, raan_deg, argp_deg and " \
            "true_anomaly_deg or mean_anomaly_deg"
    cart = [k for k in _CARTESIAN if k in v]
    elem = [k for k in ORBIT_KEYS if k in v and k not in _CARTESIAN]
    if cart and elem:
        raise src.error(table, index, elem[0], f"{forms}, not both forms", elem[0],
                        label=f"{label}.{elem[0]}")
    if cart:
        missing = [k for k in _CARTESIAN if k not in v]
        if missing:
            raise src.error(table, index, None, forms, label=f"{label}.{missing[0]}")
        r_m = math.hypot(*v["r_eci_m"])   # (np.linalg.norm overflows on 1e154 components)
        if centre == "sun":
            if not R_SUN_PHOTOSPHERE_M < r_m <= MAX_ORBIT_RADIUS_M:
                raise src.error(table, index, "r_eci_m", f"a position outside the Sun and within "
                                f"{MAX_ORBIT_RADIUS_M:g} m ({R_SUN_PHOTOSPHERE_M:.4g} m < |r| <= "
                                f"{MAX_ORBIT_RADIUS_M:g} m)", f"|r| = {r_m:.6g} m",
                                label=f"{label}.r_eci_m")
            return tuple(float(x) for x in v["r_eci_m"] + v["v_eci_mps"])
        if not R_EARTH_M < r_m <= MAX_ORBIT_RADIUS_M:
            raise src.error(table, index, "r_eci_m", f"a position above the Earth's surface and "
                            f"within {MAX_ORBIT_RADIUS_M:g} m ({R_EARTH_M:.0f} m < |r| <= "
                            f"{MAX_ORBIT_RADIUS_M:g} m)", f"|r| = {r_m:.6g} m",
                            label=f"{label}.r_eci_m")
        return tuple(float(x) for x in v["r_eci_m"] + v["v_eci_mps"])
    if centre == "sun":
        raise src.error("orbit", 0, elem[0] if elem else None, "r_eci_m + v_eci_mps "
                        "(a heliocentric orbit is given as a Cartesian state)", label="orbit")
    missing = [k for k in _ELEMENTS if k not in v]
    n_anom = ("true_anomaly_deg" in v) + ("mean_anomaly_deg" in v)
    if missing or n_anom != 1:
        key = missing[0] if missing else "true_anomaly_deg"
        raise src.error(table, index, None, forms + ("" if n_anom < 2 else
                        " (one anomaly, not both)"), label=f"{label}.{key}")
    e = v["e"]
    if not v["a_m"] * (1.0 - e) > R_EARTH_M:
        raise src.error(table, index, "a_m", f"a perigee above the Earth's surface (a_m (1 - e) > "
                        f"{R_EARTH_M:.0f} m)", f"a_m (1 - e) = {v['a_m'] * (1.0 - e):.6g} m",
                        label=f"{label}.a_m")
    if "true_anomaly_deg" in v:
        nu = v["true_anomaly_deg"] * DEG
    else:
        nu = mean_to_true_anomaly(v["mean_anomaly_deg"] * DEG, e)
    x = elements_to_state(v["a_m"], e, v["i_deg"] * DEG, v["raan_deg"] * DEG,
                          v["argp_deg"] * DEG, float(nu), MU_EARTH_M3_S2)
    return tuple(float(t) for t in np.asarray(x).ravel())


def _sensor(src: TomlSource, i: int, s) -> SensorSpec:
    label = f"sensor[{i + 1}]"
    if not isinstance(s, dict):
        raise src.error(None, 0, "sensor", "an array of tables [[sensor]]", s, label="sensor")
    if "kind" not in s:
        raise src.error("sensor", i, None, "a key 'kind' (one of " + ", ".join(SENSOR_KINDS) + ")",
                        label=f"{label}.kind")
    kind = check_value(src, "sensor", i, "kind", s["kind"], SENSOR_KEYS["kind"], f"{label}.kind")
    known = ("kind", "period_s") + SENSOR_KIND_KEYS[kind]
    check_keys(src, "sensor", i, s, known, f"{label}.", f"sensor kind '{kind}'")
    kw = {k: check_value(src, "sensor", i, k, s[k], SENSOR_KEYS[k], f"{label}.{k}") for k in s}
    for k in _SENSOR_REQUIRED:
        if k in SENSOR_KIND_KEYS[kind] and k not in kw:
            raise src.error("sensor", i, None, f"a key '{k}' ({expected(SENSOR_KEYS[k])}) for "
                            f"sensor kind '{kind}'", label=f"{label}.{k}")
    return SensorSpec(**kw)


def _array(src: TomlSource, d: dict, name: str) -> list:
    """The ``[[name]]`` array of tables of ``d`` (empty when absent)."""
    a = d.get(name, [])
    if not isinstance(a, list) or not all(isinstance(t, dict) for t in a):
        raise src.error(None, 0, name, f"an array of tables [[{name}]]", a, label=name)
    return a


def _formation(src: TomlSource, d: dict, centre: str = "earth") -> FormationSpec | None:
    """The formation tables of a scenario (:data:`RANGING_KEYS`), or None without them; a
    spacecraft's own orbit about the scenario's ``centre``."""
    present = [k for k in ("spacecraft", "antenna", "link", "ranging") if k in d]
    if not present:
        return None
    sc_tables = _array(src, d, "spacecraft")
    if len(sc_tables) < 2:
        raise src.error("spacecraft", 0, None, "at least two [[spacecraft]] tables (a formation; "
                        f"the scenario has {present[0]!r})", label="spacecraft")
    spacecraft, ids = [], []
    for i, t in enumerate(sc_tables):
        label = f"spacecraft[{i + 1}]"
        v = keyed(src, "spacecraft", i, t, SPACECRAFT_KEYS, label, required=("id",))
        if v["id"] in ids:
            raise src.error("spacecraft", i, "id", "a spacecraft id not used before", v["id"],
                            label=f"{label}.id")
        if "orbit" in v and "lead_s" in v:
            raise src.error("spacecraft", i, "lead_s", "either lead_s (along the scenario's "
                            "[orbit]) or an own [spacecraft.orbit] table, not both", "both",
                            label=f"{label}.lead_s")
        x0 = (None if "orbit" not in v else
              _orbit_state(src, v["orbit"], "spacecraft", i, f"{label}.orbit", centre))
        ids.append(v["id"])
        spacecraft.append(SpacecraftSpec(id=v["id"], x0_eci=x0, lead_s=v.get("lead_s", 0.0),
                                         yaw_deg=v.get("yaw_deg", 0.0)))

    def known(table, i, key, value, label):
        if value not in ids:
            raise src.error(table, i, key, "a spacecraft id of [[spacecraft]] ("
                            + ", ".join(ids) + ")", value, label=f"{label}.{key}")

    antennas = {}
    for i, t in enumerate(_array(src, d, "antenna")):
        label = f"antenna[{i + 1}]"
        v = keyed(src, "antenna", i, t, ANTENNA_KEYS, label, required=tuple(ANTENNA_KEYS))
        known("antenna", i, "spacecraft", v["spacecraft"], label)
        key = (v["spacecraft"], v["name"])
        if key in antennas:
            raise src.error("antenna", i, "name", f"each antenna of spacecraft '{key[0]}' once",
                            v["name"], label=f"{label}.name")
        if not all(abs(a) <= MAX_ANTENNA_ARM_M for a in v["body_m"]):
            raise src.error("antenna", i, "body_m", f"a lever arm within {MAX_ANTENNA_ARM_M:g} m "
                            "per axis", v["body_m"], label=f"{label}.body_m")
        antennas[key] = v["body_m"]
    links = []
    link_tables = _array(src, d, "link")
    if not link_tables:
        raise InputFormatError(src.path, None, "link", "at least one [[link]] table (rx, tx, "
                               "optional rx_antenna, tx_antenna) in a formation scenario")
    for i, t in enumerate(link_tables):
        label = f"link[{i + 1}]"
        v = keyed(src, "link", i, t, LINK_KEYS, label, required=("rx", "tx"))
        for k in ("rx", "tx"):
            known("link", i, k, v[k], label)
        if v["rx"] == v["tx"]:
            raise src.error("link", i, "tx", "a transmitting spacecraft other than rx",
                            v["tx"], label=f"{label}.tx")
        for end in ("rx", "tx"):
            ant = v.get(f"{end}_antenna", "")
            if ant and (v[end], ant) not in antennas:
                raise src.error("link", i, f"{end}_antenna", f"an [[antenna]] of spacecraft "
                                f"'{v[end]}'", ant, label=f"{label}.{end}_antenna")
        links.append(LinkSpec(rx=v["rx"], tx=v["tx"], rx_antenna=v.get("rx_antenna", ""),
                              tx_antenna=v.get("tx_antenna", "")))
    if "ranging" not in d:
        raise InputFormatError(src.path, None, "ranging", "a table [ranging] (sigma_m, the "
                               "pseudorange 1-sigma, m) in a formation scenario")
    r = table_of(src, d, "ranging")
    check_keys(src, "ranging", 0, r, tuple(RANGING_KEYS), "ranging.", "[ranging]")
    if "sigma_m" not in r:
        raise src.error("ranging", 0, None, f"a key 'sigma_m' ({expected(RANGING_KEYS['sigma_m'])})",
                        label="ranging.sigma_m")
    rv = {k: check_value(src, "ranging", 0, k, r[k], RANGING_KEYS[k], f"ranging.{k}") for k in r}
    arcsec = math.pi / (180.0 * 3600.0)
    ranging = RangingSpec(
        sigma_m=rv["sigma_m"], period_s=rv.get("period_s"),
        carrier_sigma_m=rv.get("carrier_sigma_m", 0.0),
        ambiguity_sigma_m=rv.get("ambiguity_sigma_m", 1.0),
        clock_sigma0_m=rv.get("clock_sigma0_m", 1.0),
        clock_random_walk_m_per_sqrt_s=rv.get("clock_random_walk_m_per_sqrt_s", 0.01),
        attitude_sigma_rad=rv.get("attitude_sigma_arcsec", 1.0) * arcsec)
    if 0.0 < ranging.carrier_sigma_m < 1e-9:
        raise src.error("ranging", 0, "carrier_sigma_m", "0 (no carrier) or >= 1e-9 m",
                        ranging.carrier_sigma_m, label="ranging.carrier_sigma_m")
    return FormationSpec(spacecraft=tuple(spacecraft),
                         antennas=tuple((a, b, arm) for (a, b), arm in antennas.items()),
                         links=tuple(links), ranging=ranging)


def load_scenario(name_or_path: str) -> Scenario:
    """A built-in scenario by name (``gto-transfer``) or a TOML file by path; every key is
    validated (module docstring)."""
    path = Path(name_or_path)
    if not path.suffix:
        path = data_dir() / "scenarios" / f"{name_or_path}.toml"
        if not path.exists():
            raise UserError(f"unknown scenario '{name_or_path}'; built-in: {', '.join(builtin_names())}")
    if not path.is_file():
        raise UserError(f"{path}: no such scenario file")

    text = read_utf8_text(path, "a scenario TOML file")
    d = parse_toml(path, text)
    return scenario_from_dict(d, path, text)


def scenario_from_dict(d: dict, path, text: str = "") -> Scenario:
    """Validate a parsed scenario TOML ``d`` (read from ``path``, source ``text`` for line
    numbers) and build the :class:`Scenario`."""
    src = TomlSource(path, text, _ARRAY_TABLES)
    if not d:
        raise InputFormatError(path, 1, None, "a scenario (keys " + ", ".join(TOP_KEYS)
                               + ", tables [orbit], [[sensor]], optional [truth], [prior])",
                               "an empty file")
    check_keys(src, None, 0, d, tuple(TOP_KEYS) + TOP_TABLES, "", "the scenario")
    for k in ("epoch", "duration_h", "step_s", "orbit", "sensor"):
        if k not in d:
            what = {"orbit": "a table [orbit]", "sensor": "at least one [[sensor]] table"}.get(
                k, f"a key '{k}' ({expected(TOP_KEYS.get(k, ('str',) + (None,) * 5))})")
            raise InputFormatError(path, None, k, what)
    top = {k: check_value(src, None, 0, k, d[k], TOP_KEYS[k], k) for k in TOP_KEYS if k in d}
    orbit = table_of(src, d, "orbit")
    truth = table_of(src, d, "truth")
    prior = table_of(src, d, "prior")
    check_keys(src, "truth", 0, truth, tuple(TRUTH_KEYS), "truth.", "[truth]")
    check_keys(src, "prior", 0, prior, tuple(PRIOR_KEYS), "prior.", "[prior]")
    tv = {k: check_value(src, "truth", 0, k, truth[k], TRUTH_KEYS[k], f"truth.{k}") for k in truth}
    pv = {k: check_value(src, "prior", 0, k, prior[k], PRIOR_KEYS[k], f"prior.{k}") for k in prior}
    sensors = d["sensor"]
    if not isinstance(sensors, list) or not sensors:
        raise src.error(None, 0, "sensor", "at least one [[sensor]] table (an array of tables)",
                        sensors if not isinstance(sensors, list) else None, label="sensor")
    specs = tuple(_sensor(src, i, s) for i, s in enumerate(sensors))
    centre = top.get("centre", "earth")
    if centre != "earth":
        helio = [k for k in HELIOCENTRIC_KINDS if k in SENSOR_KINDS]   # (not priors, links)
        for i, spec in enumerate(specs):
            if spec.kind not in helio:
                raise src.error("sensor", i, "kind", f"a kind a heliocentric pass can hold "
                                f"(centre = {centre!r}): {', '.join(helio)}",
                                spec.kind, label=f"sensor[{i + 1}].kind")
        for k in ("drag", "srp"):
            if tv.get(k):
                raise src.error("truth", 0, k, f"false: the heliocentric truth has the Sun "
                                f"and the planets only (centre = {centre!r})", True,
                                label=f"truth.{k}")
    # the pass has one true bias (SimulatedPass.truth_params["refraction_bias_m"])
    biased = [i for i, s in enumerate(sensors) if any(k in s for k in MODEL_BIAS_KEYS)]
    if len(biased) > 1:
        i = biased[1]
        key = next(k for k in MODEL_BIAS_KEYS if k in sensors[i])
        raise src.error("sensor", i, key, f"the atmosphere-model bias keys on one refraction "
                        f"sensor only (already on sensor[{biased[0] + 1}])", key,
                        label=f"sensor[{i + 1}].{key}")
    return Scenario(
        name=top.get("name", Path(path).stem), description=top.get("description", ""),
        epoch=top["epoch"], duration_h=top["duration_h"], step_s=top["step_s"],
        x0_eci=_orbit_state(src, orbit, centre=centre), truth_j2=tv.get("j2", True),
        truth_third_body=tv.get("third_body", False), truth_drag=tv.get("drag", False),
        truth_srp=tv.get("srp", False),
        prior_position_sigma_m=pv.get("position_sigma_m", 10000.0),
        prior_velocity_sigma_mps=pv.get("velocity_sigma_mps", 2.0),
        prior_mode=pv.get("mode", "random"), sensors=specs, source=str(path),
        formation=_formation(src, d, centre), centre=centre, manoeuvres=_manoeuvres(src, d))


def parse_manoeuvre(text: str, scn: Scenario) -> ManoeuvreSpec:
    """``fgnav simulate --manoeuvre "T,dvx,dvy,dvz[,sigma]"``: T in hours after the pass
    start or an ISO-8601 UTC epoch, the planned delta-v in m/s (EME2000), sigma its 1-sigma
    execution error per axis (m/s, default :data:`MANOEUVRE_SIGMA_MPS`)."""
    what = ("T,DVX,DVY,DVZ[,SIGMA] (T: hours after the pass start or an ISO-8601 UTC "
            "epoch; delta-v in m/s; SIGMA in m/s)")
    parts = [x.strip() for x in str(text).split(",")]
    if len(parts) not in (4, 5):
        raise UserError(f"--manoeuvre {text!r}: expected {what}")
    try:
        t_s = float(parts[0]) * 3600.0
    except ValueError:
        try:
            t_s = float(seconds_since(parse_utc(parts[0]), parse_utc(scn.epoch)))
        except (ValueError, UserError):
            raise UserError(f"--manoeuvre {text!r}: the time {parts[0]!r} is neither a number "
                            f"of hours nor an ISO-8601 UTC epoch; expected {what}") from None
    try:
        vals = [float(x) for x in parts[1:]]
    except ValueError:
        raise UserError(f"--manoeuvre {text!r}: expected numbers after the time; "
                        f"expected {what}") from None
    sigma = vals[3] if len(vals) == 4 else MANOEUVRE_SIGMA_MPS
    if not all(math.isfinite(v) for v in vals) or not 1e-6 <= sigma <= 1e3:
        raise UserError(f"--manoeuvre {text!r}: expected finite numbers and 1e-6 <= SIGMA <= "
                        f"1e3 m/s")
    if not 0.0 < t_s <= scn.duration_h * 3600.0 + 1e-9:
        raise UserError(f"--manoeuvre {text!r}: at t = {t_s / 3600.0:g} h; expected a time "
                        f"after the start and within the pass (0 < T <= {scn.duration_h:g} h)")
    return ManoeuvreSpec(t_s=t_s, dv_mps=tuple(vals[:3]), sigma_mps=sigma)


def _manoeuvres(src: TomlSource, d: dict) -> tuple:
    """The ``[[manoeuvres]]`` tables of a scenario (:data:`MANOEUVRE_KEYS`), in time order."""
    out = []
    for i, t in enumerate(_array(src, d, "manoeuvres")):
        kw = keyed(src, "manoeuvres", i, t, MANOEUVRE_KEYS, f"manoeuvres[{i + 1}]",
                   required=("t_h", "dv_mps"))
        out.append(ManoeuvreSpec(t_s=float(kw["t_h"]) * 3600.0,
                                 dv_mps=tuple(float(v) for v in kw["dv_mps"]),
                                 sigma_mps=float(kw.get("sigma_mps", MANOEUVRE_SIGMA_MPS))))
    return tuple(sorted(out, key=lambda m: m.t_s))


def sensor_epoch_count(scn: Scenario) -> int:
    """Sensor epochs of a simulated pass, summed over the sensors (``pass_sim.sensor_epochs``);
    a formation's counts each spacecraft's sensors and the link epochs."""
    def epochs(period_s):
        period = scn.step_s if period_s is None else period_s
        return int(min(math.floor(scn.duration_h * 3600.0 / period + 1e-9), 10**15)) + 1

    n = sum(epochs(s.period_s) for s in scn.sensors)
    if scn.formation is not None:
        n = n * len(scn.formation.spacecraft) + epochs(scn.formation.ranging.period_s)
    return n


def check_size(scn: Scenario, max_epochs: int = MAX_EPOCHS,
               max_duration_h: float = MAX_DURATION_H) -> None:
    """Refuse a pass beyond the limits (module docstring) before any work, saying how to get
    more: raise :class:`UserError`."""
    if scn.duration_h > max_duration_h:
        raise UserError(
            f"scenario {scn.name}: duration_h = {scn.duration_h:g} h exceeds the limit of "
            f"{max_duration_h:g} h of one simulated pass; shorten it (--duration-h) or raise the "
            f"limit with --max-duration-h H (the truth integration takes ~8 s per simulated day "
            f"in LEO with every force)")

    if scn.duration_h * 3600.0 > seconds_since(parse_utc("2261-12-31T23:59:59Z"),
                                               parse_utc(scn.epoch)):  # datetime64[ns] range
        raise UserError(f"scenario {scn.name}: epoch {scn.epoch} + duration_h {scn.duration_h:g} h "
                        "ends after the year 2261 (the range of the time scale); start earlier")
    n = sensor_epoch_count(scn)
    if n > max_epochs:
        raise UserError(
            f"scenario {scn.name}: {n:,} sensor epochs (duration_h x 3600 / step_s or period_s, "
            f"summed over {len(scn.sensors)} sensor(s)) exceed the limit of {max_epochs:,}; "
            f"lengthen --step-s, shorten --duration-h, or raise the limit with --max-epochs N "
            f"(about 13 s and 25 MB of output per 100,000 epochs)")
