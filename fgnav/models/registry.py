"""The measurement models of ``fgnav``, each registered once (see :mod:`fgnav.models.model`).

This module is the one place that maps a log kind to its behaviour: the solvers, the EKFs,
the simulator, the initial-orbit code and the visualization iterate over :data:`MODELS` or
ask :func:`model`. To add a measurement: write its residual, Jacobians and GTSAM adapter in
one file of ``factors/`` (with its Jacobian test), then add one :class:`MeasurementModel`
entry below (CONTRIBUTING.md, "Add a measurement", walks through an example). The log
format's columns and value checks stay in ``fgnav.io.log_csv`` (the format's definition).
"""

from __future__ import annotations

import contextlib
import functools

import numpy as np

from factors.aberration import apparent_direction, earth_velocity_bcrs_mps
from factors.alignment import (aligned_star_direction_apparent_residual,
                               make_aligned_star_direction_apparent_factor)
from factors.altimeter import altitude_kernel, altitude_residual, make_altitude_factor
from factors.celestial_angles import (BODY_BODY, BODY_STAR, apparent_angle_residual,
                                      celestial_angle_kernel, make_celestial_angle_factor,
                                      pack_angle_rows)
from factors.attitude import attitude_residual, make_attitude_prior_factor, triad
from factors.gyro import gyro_residual, make_gyro_factor, make_gyro_factor_without_bias
from factors.direction import (body_direction_residual, earth_direction_residual,
                               earth_direction_row_kernel, make_body_direction_factor,
                               make_earth_direction_factor,
                               make_star_direction_apparent_factor,
                               star_direction_apparent_residual)
from factors.planets import check_span, moon_position_geo_m, sun_position_geo_m
from factors.geometry import so3_exp, so3_log, tangent_basis
from factors.limb import limb_radius_kernel, limb_radius_residual, make_limb_radius_factor
from factors.prior import (POSITION, VELOCITY, make_state_prior_factor, prior_position_kernel,
                           prior_velocity_kernel, state_prior_residual)
from factors.refraction import (make_refraction_bias_factor, make_refraction_factor,
                                refraction_residual, refraction_sigma_m)
from factors.constants import ARCSEC
from factors.errors import EphemerisSpanError
from fgnav.constants import R_EARTH_M
from fgnav.errors import UserError
from fgnav.io.log_csv import BODIES, STAR_COLUMNS, attitude_covariances
from fgnav.models.isl import ISL_CARRIER_PHASE, ISL_PSEUDORANGE
from fgnav.models.model import MeasurementModel
from fgnav.models.variables import ORBIT, ConstantRate, Variable
from fgnav.simulate.celestial_angles import (body_position_eci_m, body_velocity_mps,
                                             frame_velocity_bcrs_mps, simulate_angle_rows)
from fgnav.simulate.body_directions import (earth_centre_target, moon_target,
                                            simulate_body_direction_rows, sun_target)
from fgnav.simulate.refraction_sim import MODEL_BIAS_KEYS, simulate_refraction_rows
from fgnav.simulate.sensors import (altitude_readings, geocentric_direction_readings,
                                    limb_radius_readings)
from fgnav.simulate.star_camera import simulate_star_camera_rows
from fgnav.time import j2000_seconds
from fgnav.vision.attitude import wahba_by_epoch

__all__ = ["MODELS", "VARIABLES", "model", "solved_models", "prior_kinds", "eci_ray_kinds",
           "simulated_kinds", "variable", "REFRACTION_BIAS", "ATTITUDE", "ATTITUDE_VARIABLE",
           "PRIOR_POSITION", "PRIOR_VELOCITY", "EARTH_DIRECTION", "LIMB_RADIUS", "ALTITUDE",
           "REFRACTION", "EARTH_DIRECTION_BODY", "SUN_DIRECTION_BODY", "MOON_DIRECTION_BODY",
           "GYRO", "GYRO_BIAS", "STAR_DIRECTION_BODY", "BODY_STAR_ANGLE", "LIMB_STAR_ANGLE",
           "BODY_BODY_ANGLE", "CAMERA_ALIGNMENT", "ATTITUDE_RATE", "refraction_ray_eci",
           "ISL_PSEUDORANGE", "ISL_CARRIER_PHASE"]


def _xyz(log, i):
    return np.asarray(log.xyz, dtype=float)[i]


def _readings(fn):
    """A simulator entry from a readings function ``(spec, t, x_true, rng) -> (xyz, sigma)``:
    rows of the sensor's own kind (``spec.kind``, the model the simulator dispatched on)."""
    def simulate(spec, t_s, x_true, epoch0, rng):
        xyz, sigma = fn(spec, t_s, x_true, rng)
        return [(spec.kind, t_s, xyz, sigma)]
    return simulate


def _position_model(residual):
    """``residual(fam, v)`` of a model whose residual depends on the position only."""
    def res(fam, v):
        e, H_r = residual(v["orbit"][:, :3], fam)
        return e, {"position": H_r}
    return res


# ---- priors --------------------------------------------------------------------------------

def _prior(kind, sl, kernel, what):
    def res(fam, v):
        e, H = state_prior_residual(v["orbit"], fam.values["xyz"], sl)
        return e, {"orbit": H}

    def data(fam):
        return fam.values["xyz"], None

    return MeasurementModel(
        kind=kind, dim=3, unit="m" if sl == POSITION else "m/s", prior=True,
        summary=f"a priori {what}, EME2000",
        values=lambda log, i: {"xyz": _xyz(log, i)}, residual=res,
        factor=lambda fam, j, keys, noise: make_state_prior_factor(keys["orbit"], sl,
                                                                   fam.values["xyz"][j], noise),
        numba_kernel=kernel, numba_data=data)


PRIOR_POSITION = _prior("prior_position", POSITION, prior_position_kernel, "position, m")
PRIOR_VELOCITY = _prior("prior_velocity", VELOCITY, prior_velocity_kernel, "velocity, m/s")


# ---- geocentric direction ------------------------------------------------------------------

EARTH_DIRECTION = MeasurementModel(
    kind="earth_direction", dim=2, unit="rad", observes_orbit=True,
    summary="unit vector spacecraft -> Earth centre, EME2000",
    values=lambda log, i: {"u_eci": _xyz(log, i)},
    residual=_position_model(lambda r, fam: earth_direction_residual(r, fam.values["u_eci"])),
    factor=lambda fam, j, keys, noise: make_earth_direction_factor(keys["orbit"],
                                                                   fam.values["u_eci"][j], noise),
    numba_kernel=earth_direction_row_kernel,
    numba_data=lambda fam: (fam.values["u_eci"], tangent_basis(fam.values["u_eci"])),
    simulate=_readings(geocentric_direction_readings),
    scenario_keys=("sigma_deg",), eci_ray=True, geocentric_direction=True)


# ---- ranges --------------------------------------------------------------------------------

def _two_columns(name0, name1):
    return lambda log, i: {name0: _xyz(log, i)[:, 0], name1: _xyz(log, i)[:, 1]}


def _columns_data(name0, name1):
    def data(fam):
        d = np.zeros((len(fam), 3))
        d[:, 0], d[:, 1] = fam.values[name0], fam.values[name1]
        return d, None
    return data


LIMB_RADIUS = MeasurementModel(
    kind="limb_radius", dim=1, unit="rad", observes_orbit=True,
    summary="angular radius of the limb sphere (rad) and its radius (m)",
    values=_two_columns("rho_rad", "r_limb_m"),
    residual=_position_model(lambda r, fam: limb_radius_residual(r, fam.values["rho_rad"],
                                                                 fam.values["r_limb_m"])),
    factor=lambda fam, j, keys, noise: make_limb_radius_factor(
        keys["orbit"], fam.values["rho_rad"][j], fam.values["r_limb_m"][j], noise),
    numba_kernel=limb_radius_kernel, numba_data=_columns_data("rho_rad", "r_limb_m"),
    simulate=_readings(limb_radius_readings),
    scenario_keys=("sigma_deg", "r_limb_km"),
    range_m=lambda fam: fam.values["r_limb_m"] / np.sin(fam.values["rho_rad"]))

ALTITUDE = MeasurementModel(
    kind="altitude", dim=1, unit="m", observes_orbit=True,
    summary="height above a sphere (m) and the sphere's radius (m)",
    values=_two_columns("h_m", "r_ref_m"),
    residual=_position_model(lambda r, fam: altitude_residual(r, fam.values["h_m"],
                                                              fam.values["r_ref_m"])),
    factor=lambda fam, j, keys, noise: make_altitude_factor(
        keys["orbit"], fam.values["h_m"][j], fam.values["r_ref_m"][j], noise),
    numba_kernel=altitude_kernel, numba_data=_columns_data("h_m", "r_ref_m"),
    simulate=_readings(altitude_readings), scenario_keys=("sigma_m",),
    range_m=lambda fam: fam.values["h_m"] + fam.values["r_ref_m"])


# ---- starlight refraction ------------------------------------------------------------------

REFRACTION_BIAS = Variable(
    "refraction_bias", "b", 1, "m", components=("refraction_bias_m",),
    psd=1.0, prior_sigma=1000.0,
    description="bias of the atmosphere model's tangent height h(gamma), m (random walk)")
"""The refraction model's tangent-height error shared by every star at an epoch: a random
walk of spectral density 1 m^2/s (60 m in an hour), prior 1 km (see docs/refraction-bias.md)."""


def _refraction_values(log, i):
    extra = log.extra
    sig_model = extra.get("sigma_model_m", np.full(len(log.kind), np.nan))[i]
    t = float(j2000_seconds(log.epoch0)) + np.asarray(log.t_s, dtype=float)[i]
    return {"s_eci": _xyz(log, i), "gamma_rad": extra["gamma"][i],
            "sigma_model_m": np.nan_to_num(sig_model, nan=0.0),
            "v_earth_bcrs_mps": earth_velocity_bcrs_mps(t), "aberration": np.ones(len(t), bool)}


def refraction_ray_eci(fam, rows=slice(None)):
    """The direction of the star's ray before bending, in the geocentric frame: the
    catalogue direction aberrated by the Earth's barycentric velocity (the geocentric
    apparent place, ~20 arcsec; ``factors.aberration``). The spacecraft's own velocity
    changes how the camera sees the ray, not where it passes the atmosphere, and aberrates
    the refracted and the unrefracted star alike, leaving gamma as measured (to
    ``beta gamma`` < 0.1 arcsec); rows with ``aberration`` off keep the catalogue direction.
    ``rows``: a slice or index array of the family's rows (default all)."""
    s = fam.values["s_eci"][rows]
    on = fam.values["aberration"][rows]
    s_app, _ = apparent_direction(s, fam.values["v_earth_bcrs_mps"][rows])
    return np.where(on[:, None], s_app, s)


def _refraction_sigma(fam, x_orbit=None):
    """Tangent-height 1-sigma (m): angle error and model error combined
    (``factors.refraction.refraction_sigma_m``). The residual depends on the measured gamma
    through both terms, ``de/dgamma = |r.s| sec^2(gamma) + H/gamma``: with the orbit states
    ``x_orbit`` (M, 6) the line-of-sight range ``|r.s|`` is taken there (+13 % on the angle
    term in LEO); without (no state at hand) Li et al. 2017's ``H/gamma`` alone."""
    los = 0.0
    if x_orbit is not None:
        los = np.abs(np.sum(np.asarray(x_orbit)[:, :3] * fam.values["s_eci"], axis=1))
    return refraction_sigma_m(fam.values["gamma_rad"], fam.sigma, fam.values["sigma_model_m"],
                              los_range_m=los)


def _refraction_residual(fam, v):
    M = len(fam)
    args = (v["orbit"][:, :3], refraction_ray_eci(fam), fam.values["gamma_rad"],
            np.full(M, R_EARTH_M), np.zeros(M))
    if REFRACTION_BIAS.name not in v:
        e, H_r = refraction_residual(*args)
        return e, {"position": H_r}
    e, H_r, H_b = refraction_residual(*args, bias_m=v[REFRACTION_BIAS.name][:, 0])
    return e, {"position": H_r, REFRACTION_BIAS.name: H_b}


def _refraction_factor(fam, j, keys, noise):
    s, g = refraction_ray_eci(fam, slice(j, j + 1))[0], fam.values["gamma_rad"][j]
    if REFRACTION_BIAS.name in keys:
        return make_refraction_bias_factor(keys["orbit"], keys[REFRACTION_BIAS.name], s, g, noise,
                                           R_EARTH_M, 0.0)
    return make_refraction_factor(keys["orbit"], s, g, noise, R_EARTH_M, 0.0)


REFRACTION = MeasurementModel(
    kind="refraction", dim=1, unit="m", observes_orbit=True,
    summary="refracted star: catalogue unit vector (EME2000), refraction angle gamma (rad)",
    values=_refraction_values, residual=_refraction_residual, factor=_refraction_factor,
    sigma=_refraction_sigma, optional_variables=(REFRACTION_BIAS,),
    simulate=simulate_refraction_rows,
    scenario_keys=("gamma_halfwidth_arcsec", "sigma_model_m", "star_sigma_arcsec", "fov_deg",
                   "vmag_max", "azimuths_deg", "boresight_tangent_km") + MODEL_BIAS_KEYS,
    eci_ray=True)


# ---- attitude and body-frame directions ----------------------------------------------------
# Without --estimate attitude, attitude rows rotate the body-frame directions into ECI before
# the graph (their variances added); with it, they are priors on a Rot3 variable per epoch and
# the body-frame rows are factors on (orbit, attitude).

ATTITUDE_VARIABLE = Variable(
    "attitude", "a", 3, "rad", manifold="rot3", components=("att_x", "att_y", "att_z"),
    psd=1e-4, prior_sigma=10.0,
    description="R_eci_from_body as a rotation vector, rad (random walk on SO(3))")
"""The spacecraft attitude per epoch: between epochs a random walk on SO(3) of spectral
density 1e-4 rad^2/s (0.03 rad per 10 s: an Earth-pointing LEO body turns 0.011 rad in 10 s
in ECI); no prior worth the name (10 rad): the attitude rows give it."""


def _attitude_residual(fam, v):
    e, H_R = attitude_residual(v[ATTITUDE_VARIABLE.name], fam.values["R_eci_from_body"])
    return e, {ATTITUDE_VARIABLE.name: H_R}


ATTITUDE = MeasurementModel(
    kind="attitude", dim=3, unit="rad",
    summary="rotation vector of R_eci_from_body (a solved attitude)",
    values=lambda log, i: {"R_eci_from_body": so3_exp(_xyz(log, i)),
                           "cov_rad2": attitude_covariances(log, i)},
    residual=_attitude_residual, variables=(), optional_variables=(ATTITUDE_VARIABLE,),
    requires=ATTITUDE_VARIABLE.name, covariance=lambda fam: fam.values.get("cov_rad2"),
    initial=lambda fam: {ATTITUDE_VARIABLE.name: so3_log(fam.values["R_eci_from_body"])},
    factor=lambda fam, j, keys, noise: make_attitude_prior_factor(
        keys[ATTITUDE_VARIABLE.name], fam.values["R_eci_from_body"][j], noise))


def _body_residual(fam, v):
    e, H_r, H_R = body_direction_residual(v["orbit"][:, :3], v[ATTITUDE_VARIABLE.name],
                                          fam.values["p_target_eci_m"], fam.values["u_body"])
    return e, {"position": H_r, ATTITUDE_VARIABLE.name: H_R}


def _body_factor(fam, j, keys, noise):
    return make_body_direction_factor(keys["orbit"], keys[ATTITUDE_VARIABLE.name],
                                      fam.values["p_target_eci_m"][j], fam.values["u_body"][j],
                                      noise)


@contextlib.contextmanager
def _ephemeris_span(log, i, what):
    """The log's rows ``i`` whose epochs an ERFA ephemeris (``factors.planets``: 1900-2100)
    does not cover are a user error naming their first line."""
    try:
        yield
    except EphemerisSpanError as exc:
        raise UserError(f"{log.path}: the {what} (line {int(np.asarray(log.line)[i][0])} ...): "
                        f"{exc}; expected epochs within 1900-2100") from exc


def _body_values(ephemeris, partner=None):
    """``values(log, rows)`` of a body-frame direction kind: ``u_body`` (M, 3); the row's epoch
    ``t_j2000_s`` (M,) s after J2000 and the target's ECI position ``p_target_eci_m`` (M, 3), m,
    from ``ephemeris(t_j2000_s)`` (ERFA, ``factors.planets``; None: the Earth centre, the
    origin);
    with ``partner`` (a kind) also ``u_partner_body`` (M, 3), that kind's body-frame direction
    at the row's epoch (NaN where the epoch has none), for the first guess of the attitude."""
    def values(log, i):
        t = np.asarray(log.t_s, dtype=float)[i]
        tj = float(j2000_seconds(log.epoch0)) + t
        with _ephemeris_span(log, i, "rows"):
            p = np.zeros((len(t), 3)) if ephemeris is None else ephemeris(tj).reshape(-1, 3)
        out = {"u_body": _xyz(log, i), "t_j2000_s": tj, "p_target_eci_m": p}
        if partner is not None:
            out["u_partner_body"] = np.full((len(t), 3), np.nan)
            jp = log.select(partner)
            if len(jp):
                tp = np.asarray(log.t_s, dtype=float)[jp]
                order = np.argsort(tp, kind="stable")
                pos = np.clip(np.searchsorted(tp[order], t), 0, len(jp) - 1)
                hit = tp[order][pos] == t
                out["u_partner_body"][hit] = np.asarray(log.xyz, dtype=float)[jp[order][pos[hit]]]
        return out
    return values


def _moon_sun_initial(fam):
    """First guess of the attitude at every Moon row: TRIAD (``factors.attitude.triad``;
    Black 1964, Shuster & Oh 1981) of the body-frame Sun direction of the same epoch (matched
    exactly: the finer sensor) and the Moon direction against their geocentric ECI directions
    from the ephemeris. The Moon's parallax (spacecraft vs Earth centre, <= 1.1 deg in LEO)
    is left in: the solver removes it. A row whose epoch has no Sun row (eclipse) takes the
    guess of the nearest epoch that has, turned by the smallest rotation that puts its own
    Moon direction right. None without any such pair. Epochs without a Moon row get no guess
    from here: the solvers carry the attitude to them (the online ones from the previous
    epoch's estimate, which a guess held over the Moon-less part of an orbit would replace
    with one tens of degrees off)."""
    pair = np.flatnonzero(np.all(np.isfinite(fam.values["u_partner_body"]), axis=1))
    if not len(pair):
        return {}
    m_eci = fam.values["p_target_eci_m"]
    s_eci = sun_position_geo_m(fam.values["t_j2000_s"][pair])
    try:
        R = triad(fam.values["u_partner_body"][pair], fam.values["u_body"][pair], s_eci,
                  m_eci[pair])
    except ValueError:
        return {}                              # Sun and Moon (anti)parallel: no first guess
    ep = fam.k[pair]
    j = np.clip(np.searchsorted(ep, fam.k), 0, len(ep) - 1)
    lo = np.clip(j - 1, 0, len(ep) - 1)
    R = R[np.where(np.abs(ep[lo] - fam.k) <= np.abs(ep[j] - fam.k), lo, j)]
    a = np.einsum("nij,nj->ni", R, fam.values["u_body"])          # Moon as the guess puts it
    b = m_eci / np.linalg.norm(m_eci, axis=1, keepdims=True)
    axis = np.cross(a, b)
    angle = np.arctan2(np.linalg.norm(axis, axis=1), np.sum(a * b, axis=1))
    axis *= (angle / np.maximum(np.linalg.norm(axis, axis=1), 1e-300))[:, None]
    return {ATTITUDE_VARIABLE.name: so3_log(so3_exp(axis) @ R)}


def _body(kind, target, observes, keys, seen, ephemeris=None, into=None, partner=None,
          initial=None):
    return MeasurementModel(
        kind=kind, dim=2, unit="rad", observes_orbit=observes,
        summary=f"unit vector to the {target}, body frame",
        values=_body_values(ephemeris, partner),
        simulate=functools.partial(simulate_body_direction_rows, target=seen),
        scenario_keys=keys, body_frame_of=into,
        residual=_body_residual, factor=_body_factor, initial=initial,
        optional_variables=(ATTITUDE_VARIABLE,), requires=ATTITUDE_VARIABLE.name)


# Without --estimate attitude the Sun and Moon rows go through the TRIAD preprocessing
# (fgnav.sun_earth_moon.preprocess_log) before the graph; with it they are factors on
# (orbit, attitude), the target at its ephemeris position (parallax included).
EARTH_DIRECTION_BODY = _body("earth_direction_body", "Earth centre", True, ("sigma_deg",),
                             earth_centre_target, into=EARTH_DIRECTION.kind)
SUN_DIRECTION_BODY = _body("sun_direction_body", "Sun", False, ("sigma_deg",), sun_target,
                           ephemeris=sun_position_geo_m)
MOON_DIRECTION_BODY = _body("moon_direction_body", "Moon", False,
                            ("sigma_deg", "min_sun_elongation_deg"), moon_target,
                            ephemeris=moon_position_geo_m, partner=SUN_DIRECTION_BODY.kind,
                            initial=_moon_sun_initial)


# ---- rate gyro (between two epochs) ---------------------------------------------------------

GYRO_BIAS = Variable(
    "gyro_bias", "g", 3, "rad/s", components=("gyro_bias_x", "gyro_bias_y", "gyro_bias_z"),
    psd=1e-14, prior_sigma=1e-3,
    description="rate gyro bias per body axis, rad/s (random walk)")
"""The gyro bias: a random walk of 1e-14 (rad/s)^2/s (bias instability ~0.02 deg/h over an
hour), prior 1e-3 rad/s (200 deg/h: an uncalibrated MEMS gyro) at the first epoch."""


def _gyro_residual(fam, v0, v1, dt):
    bias = v0[GYRO_BIAS.name] if GYRO_BIAS.name in v0 else np.zeros((len(fam), 3))
    e, H0, H1, Hb = gyro_residual(v0[ATTITUDE_VARIABLE.name], v1[ATTITUDE_VARIABLE.name], bias,
                                  fam.values["omega_rad_s"], dt)
    jac0 = {ATTITUDE_VARIABLE.name: H0}
    if GYRO_BIAS.name in v0:
        jac0[GYRO_BIAS.name] = Hb
    return e, jac0, {ATTITUDE_VARIABLE.name: H1}


def _gyro_factor(fam, j, keys0, keys1, noise, dt):
    att = ATTITUDE_VARIABLE.name
    if GYRO_BIAS.name in keys0:
        return make_gyro_factor(keys0[att], keys1[att], keys0[GYRO_BIAS.name],
                                fam.values["omega_rad_s"][j], dt, noise)
    return make_gyro_factor_without_bias(keys0[att], keys1[att], fam.values["omega_rad_s"][j],
                                         dt, noise)


GYRO = MeasurementModel(
    kind="gyro", dim=3, unit="rad",
    summary="body angular rate over the interval since the previous epoch, rad/s",
    values=lambda log, i: {"omega_rad_s": _xyz(log, i)},
    residual=_gyro_residual, factor=_gyro_factor, between=True,
    sigma=lambda fam, dt: np.asarray(fam.sigma, dtype=float) * np.abs(dt),
    variables=(), optional_variables=(ATTITUDE_VARIABLE, GYRO_BIAS),
    requires=ATTITUDE_VARIABLE.name)


# ---- raw star observations -----------------------------------------------------------------
# A star camera's identified stars, each a factor on the attitude alone (tight coupling: the
# graph solves the attitude from what the camera measures, not from a solved attitude).

def _star_initial(fam):
    """First guess of the attitude at every row: the SVD solution of Wahba's problem of the
    row's epoch (Markley 1988, ``fgnav.vision.attitude.wahba_svd``) where the epoch has >= 2
    non-parallel stars, else the solution of the nearest such epoch; none without any."""
    ep, R, _ = wahba_by_epoch(fam.k, fam.values["u_body"], fam.values["s_eci"], fam.sigma)
    if not len(ep):
        return {}
    j = np.searchsorted(ep, fam.k)                   # first solved epoch at or after
    lo, hi = np.clip(j - 1, 0, len(ep) - 1), np.clip(j, 0, len(ep) - 1)
    pick = np.where(np.abs(ep[lo] - fam.k) <= np.abs(ep[hi] - fam.k), lo, hi)
    return {ATTITUDE_VARIABLE.name: so3_log(R[pick])}


def _star_values(log, i):
    """A star row's ``u_body``, catalogue ``s_eci`` and, for the aberration (the observer's
    barycentric velocity is the Earth's plus the spacecraft's), the Earth's barycentric
    velocity ``v_earth_bcrs_mps`` (M, 3) at the row's epoch and ``aberration`` (M,) True
    (:func:`fgnav.apparent.without_aberration` switches it off for comparison)."""
    t = float(j2000_seconds(log.epoch0)) + np.asarray(log.t_s, dtype=float)[i]
    return {"u_body": _xyz(log, i), "s_eci": np.column_stack(
        [np.asarray(log.extra[c], dtype=float)[i] for c in STAR_COLUMNS]),
        "v_earth_bcrs_mps": earth_velocity_bcrs_mps(t), "aberration": np.ones(len(t), bool)}


def _observer_velocity(fam, v):
    """The observer's barycentric velocity (M, 3), m/s, of star rows (zero where the
    aberration is switched off) and the mask ``on`` (M,)."""
    on = fam.values["aberration"]
    return (fam.values["v_earth_bcrs_mps"] + v["orbit"][:, 3:6]) * on[:, None], on


def _velocity_columns(H_v, on):
    H_x = np.zeros(H_v.shape[:-1] + (6,))
    H_x[..., 3:6] = H_v * on[:, None, None]
    return H_x


def _star_residual(fam, v):
    """The apparent direction at the orbit's velocity estimate (stellar aberration, ~20-27
    arcsec); ``H`` on the orbit's velocity columns is ~3e-9 rad per m/s. Through the star
    camera's mounting when it is estimated (:data:`CAMERA_ALIGNMENT`)."""
    v_obs, on = _observer_velocity(fam, v)
    if CAMERA_ALIGNMENT.name in v:
        e, H_A, H_M, H_v = aligned_star_direction_apparent_residual(
            v[ATTITUDE_VARIABLE.name], v[CAMERA_ALIGNMENT.name], fam.values["s_eci"], v_obs,
            fam.values["u_body"])
        return e, {"orbit": _velocity_columns(H_v, on), ATTITUDE_VARIABLE.name: H_A,
                   CAMERA_ALIGNMENT.name: H_M}
    e, H_R, H_v = star_direction_apparent_residual(v[ATTITUDE_VARIABLE.name],
                                                   fam.values["s_eci"], v_obs,
                                                   fam.values["u_body"])
    return e, {"orbit": _velocity_columns(H_v, on), ATTITUDE_VARIABLE.name: H_R}


def _star_factor(fam, j, keys, noise):
    v_earth = fam.values["v_earth_bcrs_mps"][j] if fam.values["aberration"][j] else None
    if CAMERA_ALIGNMENT.name in keys:
        return make_aligned_star_direction_apparent_factor(
            keys["orbit"], keys[ATTITUDE_VARIABLE.name], keys[CAMERA_ALIGNMENT.name],
            fam.values["s_eci"][j], v_earth, fam.values["u_body"][j], noise)
    return make_star_direction_apparent_factor(
        keys["orbit"], keys[ATTITUDE_VARIABLE.name], fam.values["s_eci"][j], v_earth,
        fam.values["u_body"][j], noise)


# A star camera on its own mount (not the Earth camera's detector): its rows are in its own
# frame, b = (A M)^T s with M = R_body_from_starcam (factors.alignment); with
# --estimate camera-alignment M is a graph variable, constant over the pass.
CAMERA_ALIGNMENT = Variable(
    "camera_alignment", "m", 3, "rad", manifold="rot3",
    components=("align_x", "align_y", "align_z"), psd=1e-16, prior_sigma=60.0 * ARCSEC,
    description="star camera mounting R_body_from_starcam as a rotation vector, rad "
                "(constant: random walk of 1e-16 rad^2/s)")
"""The star camera's mounting relative to the Earth camera (the body frame), identity when
the rows are already in the body frame (a confocal sensor, or a calibrated mounting): one
rotation for the pass, held in every epoch's block as a random walk of 1e-16 rad^2/s
(0.4 arcsec in 12 h: constant against its 60 arcsec prior and the 5 arcsec stars, and a
per-step sigma of 8e-8 rad at 60 s that keeps the chain's information within ~1e5 of the
stars', where the constant floor would put 1e7 in iSAM2's Cholesky); prior 60 arcsec per
axis about the nominal mounting (a ground alignment good to an arcminute; Shuster &
Pitone 1991, "Batch estimation of spacecraft sensor alignments I", J. Astronautical
Sciences 39(4))."""


STAR_DIRECTION_BODY = MeasurementModel(
    kind="star_direction_body", dim=2, unit="rad",
    summary="unit vector to a star, body frame; its catalogue unit vector (EME2000)",
    values=_star_values, residual=_star_residual, factor=_star_factor,
    optional_variables=(ATTITUDE_VARIABLE, CAMERA_ALIGNMENT), weak_orbit_dependence=True,
    requires=ATTITUDE_VARIABLE.name, initial=_star_initial,
    simulate=simulate_star_camera_rows,
    scenario_keys=("star_sigma_arcsec", "fov_deg", "vmag_max", "mounting_sigma_arcsec"))


# ---- attitude-free angles (the INS/CNS lecture's position surfaces) ----------------------------
# A sextant-like instrument measures the angle between two lines of sight: near body - star
# (a cone), near body's limb - star (the sextant), near body - near body (a torus). No
# attitude enters (factors/celestial_angles.py).
# The limb form is a kind of its own rather than a flag on body_star_angle: it carries a
# further value (the limb sphere's radius, column y, as limb_radius rows do) and another
# residual, and a reader that ignored a flag would take a limb angle for a centre angle
# silently (wrong by the apparent radius, ~60 deg in LEO), where an unknown kind is refused.

def _bodies_at(codes, t_j2000_s, centre="earth", of=body_position_eci_m):
    """Centres (M, 3), m, of the bodies with log codes ``codes`` (M,) at the rows' epochs,
    relative to the log's ``centre`` (EME2000 axes); ``of=body_velocity_mps``: their
    velocities, m/s."""
    out = np.zeros((len(codes), 3))
    for c in np.unique(codes):
        i = np.flatnonzero(codes == c)
        out[i] = of(BODIES[int(c)], t_j2000_s[i], centre)
    return out


def _angle_values(star, limb):
    """``values(log, rows)`` of an angle kind: ``a_rad`` (M,) the measured angle; the body's
    centre ``p_body_eci_m`` (M, 3) and velocity ``v_body_mps`` at the row's epoch; the star
    ``s_eci`` (M, 3) or the second body ``p_body2_eci_m``, ``v_body2_mps``; ``r_limb_m``
    (limb form); the frame's barycentric velocity ``v_frame_bcrs_mps``; ``aberration`` (M,)
    bool, apparent lines of sight (``fgnav smooth --no-aberration`` turns it off); and the
    rows packed for the kernel, ``data`` (M, 4) and ``B`` (M, 5, 3)
    (``factors.celestial_angles.pack_angle_rows``)."""
    def values(log, i):
        with _ephemeris_span(log, i, "angle rows"):
            return rows(log, i)

    def rows(log, i):
        xyz = _xyz(log, i)
        tj = float(j2000_seconds(log.epoch0)) + np.asarray(log.t_s, dtype=float)[i]
        check_span(tj)   # also where every body is the Earth (no ERFA call below)
        centre = getattr(log, "centre", "earth")
        codes = np.asarray(log.extra["body"], float)[i]
        out = {"a_rad": xyz[:, 0], "p_body_eci_m": _bodies_at(codes, tj, centre),
               "v_body_mps": _bodies_at(codes, tj, centre, body_velocity_mps),
               "v_frame_bcrs_mps": frame_velocity_bcrs_mps(tj, centre),
               "aberration": np.ones(len(tj), bool)}
        if star:
            out["s_eci"] = np.column_stack([np.asarray(log.extra[c], dtype=float)[i]
                                            for c in STAR_COLUMNS])
            out["r_limb_m"] = xyz[:, 1] if limb else np.zeros(len(tj))
        else:
            codes2 = np.asarray(log.extra["body2"], float)[i]
            out["p_body2_eci_m"] = _bodies_at(codes2, tj, centre)
            out["v_body2_mps"] = _bodies_at(codes2, tj, centre, body_velocity_mps)
        out["data"], out["B"] = pack_angle_rows(
            out["a_rad"], out["r_limb_m"] if star else 0.0, BODY_STAR if star else BODY_BODY,
            out["p_body_eci_m"], out["s_eci"] if star else out["p_body2_eci_m"],
            v_body_mps=out["v_body_mps"], v_body2_mps=0.0 if star else out["v_body2_mps"],
            v_frame_bcrs_mps=out["v_frame_bcrs_mps"], aberration=True)
        return out
    return values


def _angle_packed(fam, rows=slice(None)):
    """The family's rows ``rows`` packed for ``factors.celestial_angles`` (``data``, ``B``:
    packed once by the values), with the aberration flag as the family holds it now
    (``fgnav.apparent.without_aberration`` turns the ``aberration`` value off)."""
    v = fam.values
    data, on = v["data"][rows], v["aberration"][rows]
    if np.any((data[:, 3] != 0.0) != on):
        data = data.copy()
        data[:, 3] = on
    return data, v["B"][rows]


def _angle_residual(fam, v):
    data, B = _angle_packed(fam)
    e, H = apparent_angle_residual(v["orbit"], data, B)
    return e, {"orbit": H}


def _angle_model(kind, summary, star, limb, keys):
    return MeasurementModel(
        kind=kind, dim=1, unit="rad", observes_orbit=True, summary=summary,
        values=_angle_values(star, limb), residual=_angle_residual,
        factor=lambda fam, j, keys_, noise: make_celestial_angle_factor(
            keys_["orbit"], *(a[0] for a in _angle_packed(fam, slice(j, j + 1))), noise),
        numba_kernel=celestial_angle_kernel, numba_data=_angle_packed,
        simulate=functools.partial(simulate_angle_rows, star=star, limb=limb),
        scenario_keys=keys)


_STAR_KEYS = ("sigma_deg", "body", "stars_per_epoch", "vmag_max", "min_sun_elongation_deg",
              "star_spread")
BODY_STAR_ANGLE = _angle_model(
    "body_star_angle", "angle between a near body's centre and a star (rad)",
    star=True, limb=False, keys=_STAR_KEYS)
LIMB_STAR_ANGLE = _angle_model(
    "limb_star_angle", "angle between a near body's limb and a star (rad): the sextant",
    star=True, limb=True, keys=_STAR_KEYS + ("r_limb_km",))
BODY_BODY_ANGLE = _angle_model(
    "body_body_angle", "angle between two near bodies' centres (rad)",
    star=False, limb=False, keys=("sigma_deg", "body", "body2"))


# (the inter-satellite links, ISL_PSEUDORANGE and ISL_CARRIER_PHASE: fgnav.models.isl)


# ---- attitude motion without a gyro ---------------------------------------------------------

ATTITUDE_RATE = Variable(
    "attitude_rate", "w", 3, "rad/s", components=("rate_x", "rate_y", "rate_z"),
    psd=1e-10, prior_sigma=0.1, process=ConstantRate(turns="attitude"),
    description="body angular rate (body frame) that turns the attitude, rad/s (constant-rate "
                "motion: white angular acceleration of psd 1e-10 rad^2/s^3)")
"""The body rate of the constant-rate attitude motion (``fgnav smooth --attitude-motion
constant-rate``, ``factors.attitude_motion``): between epochs ``R_k = R_{k-1} Exp(w_{k-1} dt)``
with the rate a random walk driven by white angular acceleration of spectral density ``psd``
= 1e-10 rad^2/s^3 (the rate wanders 1e-5 rad/s in a second, 6e-4 rad/s in an hour; the
attitude 6e-6 rad from a constant-rate turn in a second); it replaces the attitude's random
walk. Prior 0.1 rad/s (6 deg/s) at the first epoch. No model's rows touch it: it is a
variable of the attitude's process model (:mod:`fgnav.solvers.process`)."""

MODELS: dict[str, MeasurementModel] = {m.kind: m for m in (
    PRIOR_POSITION, PRIOR_VELOCITY, EARTH_DIRECTION, LIMB_RADIUS, ALTITUDE, REFRACTION,
    ATTITUDE, EARTH_DIRECTION_BODY, SUN_DIRECTION_BODY, MOON_DIRECTION_BODY, GYRO,
    STAR_DIRECTION_BODY, BODY_STAR_ANGLE, LIMB_STAR_ANGLE, BODY_BODY_ANGLE, ISL_PSEUDORANGE,
    ISL_CARRIER_PHASE)}
"""Every log kind the project reads, by kind."""

VARIABLES: dict[str, Variable] = {ORBIT.name: ORBIT, **{
    v.name: v for m in MODELS.values() for v in m.optional_variables}}
VARIABLES[ATTITUDE_RATE.name] = ATTITUDE_RATE
"""Every graph variable a model declares, by name (the orbit state first), and the attitude's
rate (its process model's variable)."""


def model(kind: str) -> MeasurementModel:
    """The model of a log kind (KeyError for a kind the registry does not know)."""
    return MODELS[kind]


def solved_models(kinds) -> list[MeasurementModel]:
    """The models among ``kinds`` that enter the graphs, in the given order."""
    return [MODELS[k] for k in kinds if k in MODELS and MODELS[k].solved]


def prior_kinds() -> tuple[str, ...]:
    return tuple(k for k, m in MODELS.items() if m.prior)


def eci_ray_kinds() -> tuple[str, ...]:
    """Kinds whose x, y, z is a unit direction in ECI (drawn as rays)."""
    return tuple(k for k, m in MODELS.items() if m.eci_ray)


def simulated_kinds() -> tuple[str, ...]:
    """Kinds a scenario's ``[[sensor]]`` may simulate."""
    return tuple(k for k, m in MODELS.items() if m.simulate is not None)


def variable(name: str) -> Variable:
    """A declared variable by name (dashes allowed, as on the command line)."""
    key = str(name).replace("-", "_")
    if key not in VARIABLES or key == ORBIT.name:
        raise UserError(f"--estimate: unknown variable '{name}'; variables that can be "
                        f"estimated: {', '.join(v.cli_name for v in VARIABLES.values() if v is not ORBIT)}")
    return VARIABLES[key]
