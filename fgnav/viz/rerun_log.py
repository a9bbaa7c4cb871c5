"""Rerun recordings of a navigation solution (rerun-sdk >= 0.41, columnar API).

``log_solution`` writes one ``.rrd`` file holding

* ``world/...`` (3-D, **km**, ECI): the Earth (WGS-84 ellipsoid), the ECI axes, the truth
  and estimated trajectories (line strips), the current truth/estimated state (a point that
  follows the time cursor), the position covariance ellipsoids (``k sigma`` times a stated
  magnification, in the entity path, e.g. ``world/estimate/covariance_3sigma_x100``) both as
  a trail every ``ellipsoid_every`` epochs and at the cursor, and the measured directions
  (Earth direction, stars) as rays from the spacecraft;
  With an attitude (estimated, or the log's ``attitude`` rows): the body axes at the cursor
  (``world/estimate/body_axes``, x/y/z red/green/blue) and along the trajectory
  (``.../body_axes_trail``);
* ``camera/...`` (the body frame, unit length): the body axes and the log's body-frame rows
  as rays (``camera/star_direction_body/measured``), with an estimated attitude also each
  star's catalogue direction rotated into the body frame (``.../catalogue_in_body``);
* time series on the ``t_s`` timeline (seconds from ``epoch0``; also the ``utc`` timeline):
  ``errors/position_{eci,rtn}_m/<axis>`` and ``errors/velocity_{eci,rtn}_mps/<axis>``, each
  with the series ``<axis> error, <axis> +3σ, <axis> -3σ`` (with truth; each axis its own
  colour, :data:`AXIS_COLORS`), or ``sigma/...`` with ``<axis> +3σ, <axis> -3σ`` (without),
  ``consistency/nees`` (6-dof NEES with its 95 % single-run chi-square band),
  ``residuals/<kind>`` (whitened residual components), ``timing/latency_ms``, and with an
  attitude covariance ``attitude/{error,sigma}_arcsec/<body axis>``.

The stored blueprint (:func:`default_blueprint`) opens with every time plot on the whole
pass and the 3-D camera framing the whole orbit (:func:`orbit_eye`).

Everything is sent with ``rr.send_columns`` (one call per entity), so a 14,400-epoch pass
logs in a fraction of a second (``scripts/bench_rerun.py``).

Rerun quaternions are scalar-last (x, y, z, w); the conversion happens here and only here.

Several spacecraft (a formation's joint solution with its inter-satellite links):
:func:`log_formation` (and :func:`log_formation_result`, through :func:`log_result` of
``fgnav smooth`` for one spacecraft or several) writes one
``.rrd`` file holding

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

import os
import shutil
import subprocess
import sys
from collections.abc import Mapping
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from factors.constants import R_EARTH_M
from fgnav.errors import UserError
from fgnav.io.truth_params import TRUTH_ATTITUDE_COLUMNS, TRUTH_ATTITUDE_CSV, read_truth_params_csv
from fgnav.models.registry import ATTITUDE, ATTITUDE_VARIABLE, eci_ray_kinds
from fgnav.frames import relative_state_lvlh, rtn_frame
from fgnav.io.log_spacecraft import ISL_KINDS
from fgnav.measurements import orbit_columns, spacecraft_states
from fgnav.models.model import COLUMN_PREFIX
from fgnav.orbit import truth_at
from fgnav.pipeline import read_measurements
from fgnav.results import read_formation_truth, relative_rows, residual_times
from fgnav.time import format_utc
from fgnav.time import seconds_since

#: WGS-84 flattening, for the drawn Earth only (the physics uses ``J2``).
_F_WGS84 = 1.0 / 298.257223563
_KM = 1.0e-3
_ARCSEC = np.pi / (180.0 * 3600.0)

#: RTN axis names (radial, along-track/transverse, orbit normal) and ECI axis names.
RTN_AXES = ("R", "T", "N")
ECI_AXES = ("x", "y", "z")

#: What ``trajectory.oem`` / ``Solution.x_eci`` holds for each method (an EKF's states are
#: filtered, not smoothed): the word plots put before "error" and "covariance".
ESTIMATE_LABELS = {"batch": "smoothed", "isam2": "smoothed", "fixed-lag": "fixed-lag smoothed",
                   "ekf": "filtered"}


def estimate_label(method) -> str:
    """"smoothed" / "fixed-lag smoothed" / "filtered" for the final states of ``method``
    ("estimated" for a method not listed)."""
    return ESTIMATE_LABELS.get(str(method), "estimated")


# --------------------------------------------------------------------------------------
# Frame helpers (vectorized)
# --------------------------------------------------------------------------------------
def rtn_rotations(x_eci: np.ndarray) -> np.ndarray:
    """Rotations ``R_rtn_from_eci`` (N, 3, 3), rows R, T, N (``fgnav.frames.rtn_frame``).

    R = r/|r|, N = (r x v)/|r x v|, T = N x R. ``x_eci`` is (N, 6) or (6,).
    """
    with np.errstate(invalid="ignore", divide="ignore"):   # NaN rows (gaps) stay NaN
        return rtn_frame(np.atleast_2d(np.asarray(x_eci, dtype=float)))


def error_and_sigma(x_eci, P_eci, truth_x_eci=None, frame="rtn"):
    """Per-axis state errors and 1-sigma in ECI or RTN.

    Returns ``(err (N,6) or None, sigma (N,6))``: ``err = x_est - x_truth`` rotated into
    the frame (RTN of the *truth* state if given, else of the estimate; velocity errors are
    rotated by the same matrix, not differentiated in the rotating frame), and
    ``sigma = sqrt(diag(T P T^T))`` with ``T = blockdiag(R_rtn_from_eci, R_rtn_from_eci)``.
    Units: m and m/s.
    """
    x_eci = np.asarray(x_eci, dtype=float)
    P_eci = np.asarray(P_eci, dtype=float)
    err = None if truth_x_eci is None else x_eci - np.asarray(truth_x_eci, dtype=float)
    if frame == "eci":
        sig = np.sqrt(np.clip(np.diagonal(P_eci, axis1=1, axis2=2), 0.0, None))
        return err, sig
    if frame != "rtn":
        raise ValueError(f"frame must be 'eci' or 'rtn', got {frame!r}")
    R = rtn_rotations(x_eci if truth_x_eci is None else truth_x_eci)
    if err is not None:
        err = np.concatenate([np.einsum("nij,nj->ni", R, err[:, :3]),
                              np.einsum("nij,nj->ni", R, err[:, 3:])], axis=1)
    T = np.zeros((len(R), 6, 6))
    T[:, :3, :3] = R
    T[:, 3:, 3:] = R
    # diag(T P T^T)_i = sum_jk T_ij P_jk T_ik
    var = np.einsum("nij,njk,nik->ni", T, P_eci, T)
    return err, np.sqrt(np.clip(var, 0.0, None))


def attitude_error_body(R_est, R_true) -> np.ndarray:
    """Attitude error ``Log(R_true^T R_est)`` (N, 3) rad: the rotation vector in the body
    frame, the right perturbation the attitude covariance is of (Sola, Deray & Atchuthan
    2018, "A micro Lie theory for state estimation in robotics", eq. 26); not a difference
    of rotation vectors, which is wrong near a half turn."""
    from scipy.spatial.transform import Rotation

    R_est = np.asarray(R_est, float).reshape(-1, 3, 3)
    R_true = np.asarray(R_true, float).reshape(-1, 3, 3)
    return Rotation.from_matrix(np.swapaxes(R_true, 1, 2) @ R_est).as_rotvec()


def nees(x_eci, P_eci, truth_x_eci) -> np.ndarray:
    """Normalized estimation error squared ``e^T P^-1 e`` per epoch (N,), 6-dof state.

    (Bar-Shalom, Li & Kirubarajan, "Estimation with Applications to Tracking and
    Navigation", eq. 5.4.2-1.) Epochs with a non-finite or singular covariance give NaN.
    """
    e = np.asarray(x_eci, float) - np.asarray(truth_x_eci, float)
    P = np.asarray(P_eci, float)
    out = np.full(len(e), np.nan)
    ok = np.all(np.isfinite(P.reshape(len(P), -1)), axis=1) & np.all(np.isfinite(e), axis=1)
    if np.any(ok):
        # Scale to unit diagonal so m^2 and (m/s)^2 blocks do not ruin the conditioning.
        d = np.sqrt(np.clip(np.diagonal(P[ok], axis1=1, axis2=2), 1e-300, None))
        Pn = P[ok] / (d[:, :, None] * d[:, None, :])
        en = e[ok] / d
        try:
            sol = np.linalg.solve(Pn, en[:, :, None])[:, :, 0]
            out[ok] = np.einsum("ni,ni->n", en, sol)
        except np.linalg.LinAlgError:
            idx = np.flatnonzero(ok)
            for j, k in enumerate(idx):
                try:
                    out[k] = en[j] @ np.linalg.solve(Pn[j], en[j])
                except np.linalg.LinAlgError:
                    pass
    return out


def covariance_ellipsoids(P_pos_m2: np.ndarray, k_sigma: float = 3.0):
    """Principal semi-axes (N, 3) [m] and orientation quaternions (N, 4) scalar-first (w,x,y,z).

    The k-sigma ellipsoid ``{d : d^T P^-1 d = k^2}`` has semi-axes ``k sqrt(lambda_i)`` along
    the eigenvectors of ``P``; the quaternion rotates the ellipsoid frame into ECI.
    """
    from scipy.spatial.transform import Rotation

    P = 0.5 * (P_pos_m2 + np.swapaxes(P_pos_m2, 1, 2))
    lam, V = np.linalg.eigh(P)
    det = np.linalg.det(V)
    V[det < 0, :, 2] *= -1.0                # proper rotation
    half = k_sigma * np.sqrt(np.clip(lam, 0.0, None))
    q_xyzw = Rotation.from_matrix(V).as_quat()
    return half, np.concatenate([q_xyzw[:, 3:], q_xyzw[:, :3]], axis=1)


def auto_magnification(half_m: np.ndarray, r_m: np.ndarray) -> float:
    """A power of ten so the median ellipsoid's largest semi-axis is ~1 % of the orbit size."""
    size = float(np.nanmax(np.linalg.norm(r_m, axis=1)))
    a = float(np.nanmedian(np.nanmax(half_m, axis=1))) if len(half_m) else 0.0
    if not np.isfinite(a) or a <= 0.0:
        return 1.0
    return float(10.0 ** max(0.0, np.floor(np.log10(0.01 * size / a))))


# --------------------------------------------------------------------------------------
# Viewer discovery (shared with ``fgnav view``)
# --------------------------------------------------------------------------------------
def display_available() -> bool:
    """True when a GUI window can be opened (Linux needs ``DISPLAY`` or ``WAYLAND_DISPLAY``)."""
    if sys.platform.startswith("linux") or "bsd" in sys.platform:
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def viewer_command(rrd_path) -> list[str]:
    """The command that opens ``rrd_path`` in the Rerun viewer (``rerun FILE.rrd``)."""
    exe = shutil.which("rerun")
    if exe:
        return [exe, str(rrd_path)]
    return [sys.executable, "-m", "rerun", str(rrd_path)]


def headless_message(rrd_path) -> str:
    """What to do on a machine without a display."""
    import rerun as rr

    p = Path(rrd_path)
    return (
        f"No display available here (DISPLAY/WAYLAND_DISPLAY unset): cannot open a viewer.\n"
        f"Copy {p} to a machine with a display and run:\n"
        f"    rerun {p.name}\n"
        f"(viewer: pip install rerun-sdk=={rr.__version__}), or serve it to a browser from "
        f"here with:\n"
        f"    rerun --web-viewer {p}\n"
        f"and forward the printed port."
    )


def open_viewer(rrd_path) -> tuple[bool, str]:
    """Open ``rrd_path`` in a detached Rerun viewer if possible.

    Returns ``(launched, message)``; never raises for a missing display.
    """
    if not display_available():
        return False, headless_message(rrd_path)
    cmd = viewer_command(rrd_path)
    try:
        subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL, start_new_session=True)
    except OSError as exc:
        return False, f"Could not start the Rerun viewer ({exc}); run: {' '.join(cmd)}"
    return True, f"Opened the Rerun viewer: {' '.join(cmd)}"


# --------------------------------------------------------------------------------------
# Recording
# --------------------------------------------------------------------------------------
#: Colours of the R, T, N (and x, y, z) series: each axis its own hue, the error line full
#: and its ±kσ bounds a lighter shade of it (Tableau 10: blue, orange, green).
AXIS_COLORS = ([31, 119, 180], [255, 127, 14], [44, 160, 44])


def _lighter(rgb, f=0.55):
    return [int(round(c + (255 - c) * f)) for c in rgb]


def orbit_eye(r_m: np.ndarray, v_m: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A 3-D camera that frames the whole orbit: ``(eye position, up)`` in km, looking at the
    Earth's centre from 2.4 times the largest radius, 35 deg above the orbit plane (the mean
    orbit normal), so the Earth and the full trajectory are in view whatever the orbit."""
    r = np.asarray(r_m, float)
    ok = np.all(np.isfinite(r), axis=1)
    r = r[ok]
    rmax_km = float(np.max(np.linalg.norm(r, axis=1))) * _KM if len(r) else R_EARTH_M * _KM
    n = np.array([0.0, 0.0, 1.0])
    if v_m is not None and len(r):
        h = np.cross(r, np.asarray(v_m, float)[ok])
        hs = h.sum(axis=0)
        if np.linalg.norm(hs) > 0:
            n = hs / np.linalg.norm(hs)
    # in-plane direction: from the Earth to the middle of the arc flown
    c = r.mean(axis=0) if len(r) else np.array([1.0, 0.0, 0.0])
    c = c - (c @ n) * n
    if np.linalg.norm(c) < 1e-9 * max(1.0, rmax_km):
        c = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    c = c / np.linalg.norm(c)
    el = np.radians(35.0)
    eye = 2.4 * max(rmax_km, R_EARTH_M * _KM) * (np.cos(el) * c + np.sin(el) * n)
    return eye, n


def time_series_view(origin, name, t_range_s=None):
    """A time plot of the entities under ``origin`` with its legend, showing the whole pass
    ``t_range_s`` (s on the ``t_s`` timeline) rather than a window around the time cursor."""
    import rerun.blueprint as rrb

    kw = {}
    if t_range_s is not None:
        t0, t1 = (float(t) for t in t_range_s)
        kw["axis_x"] = rrb.TimeAxis(view_range=rrb.TimeRange(
            start=rrb.TimeRangeBoundary.absolute(seconds=t0),
            end=rrb.TimeRangeBoundary.absolute(seconds=t1 if t1 > t0 else t0 + 1.0)))
    return rrb.TimeSeriesView(
        origin=origin, name=name, plot_legend=rrb.PlotLegend(visible=True),
        time_ranges=rrb.VisibleTimeRange("t_s", start=rrb.TimeRangeBoundary.infinite(),
                                         end=rrb.TimeRangeBoundary.infinite()), **kw)


def default_blueprint(*, has_truth: bool, residual_kinds=(), has_latency=False, t_range_s=None,
                      eye_km=None, eye_up=None, has_attitude=False, has_camera=False,
                      boresight_body=None):
    """Default layout: the 3-D orbit view framed on the whole orbit (``eye_km``, ``eye_up``,
    :func:`orbit_eye`) and, with body-frame rows, the star camera's view (body frame, seen
    from behind the camera along ``boresight_body``) below it; on the right the
    position/velocity RTN errors (or sigmas), the attitude error (or sigma) when there is an
    attitude covariance, and tabs of residuals, NEES and latency. Every time plot shows the
    whole pass ``t_range_s`` (s on the ``t_s`` timeline), not a window around the time
    cursor. The blueprint and selection panels start collapsed, leaving the room to the
    views."""
    import rerun.blueprint as rrb

    def series_view(origin, name):
        return time_series_view(origin, name, t_range_s)

    root = "errors" if has_truth else "sigma"
    unit = "error" if has_truth else "3σ"
    series = [
        series_view(f"{root}/position_rtn_m", f"position {unit} R/T/N [m]"),
        series_view(f"{root}/velocity_rtn_mps", f"velocity {unit} R/T/N [m/s]"),
    ]
    if has_attitude:
        series.append(series_view(ATTITUDE_ROOT, f"attitude {unit} about body x/y/z [arcsec]"))
    tabs = []
    if residual_kinds:
        tabs.append(series_view("residuals", "whitened residuals [-]"))
    if has_truth:
        tabs.append(series_view("consistency", "NEES (6 dof)"))
    if has_latency:
        tabs.append(series_view("timing", "update latency [ms]"))
    tabs.append(rrb.TextDocumentView(origin="about", name="about"))
    series.append(rrb.Tabs(*tabs))
    world = spatial_view("world", "orbit (ECI, km)", eye_km, (0.0, 0.0, 0.0), eye_up)
    if has_camera:
        b = np.array([0.0, 0.0, 1.0]) if boresight_body is None else np.asarray(boresight_body, float)
        b = b / np.linalg.norm(b)
        side = np.cross(b, [1.0, 0.0, 0.0] if abs(b[0]) < 0.9 else [0.0, 1.0, 0.0])
        side /= np.linalg.norm(side)
        left = rrb.Vertical(world, rrb.Spatial3DView(
            origin="camera", name="star camera: rays in the body frame",
            eye_controls=rrb.EyeControls3D(
                kind=rrb.Eye3DKind.Orbital, position=[float(v) for v in -0.5 * b + 0.7 * side],
                look_target=[float(v) for v in 0.6 * b], eye_up=[float(v) for v in b])),
            row_shares=[3, 2])
    else:
        left = world
    return views_blueprint(left, rrb.Vertical(*series))


def spatial_view(origin, name, eye=None, target=(0.0, 0.0, 0.0), up=None):
    """A 3-D view of the entities under ``origin`` whose orbital camera starts at ``eye``
    looking at ``target`` with ``up`` upwards (default z; no ``eye``: Rerun's own framing)."""
    import rerun.blueprint as rrb

    kw = {}
    if eye is not None:
        kw["eye_controls"] = rrb.EyeControls3D(
            kind=rrb.Eye3DKind.Orbital, position=[float(v) for v in eye],
            look_target=[float(v) for v in target],
            eye_up=[float(v) for v in (up if up is not None else (0.0, 0.0, 1.0))])
    return rrb.Spatial3DView(origin=origin, name=name, **kw)


def views_blueprint(left, right):
    """The blueprint of ``left`` (3 shares) beside ``right`` (2 shares), the blueprint,
    selection and time panels collapsed (the time panel on ``t_s``)."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Horizontal(left, right, column_shares=[3, 2]),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(timeline="t_s", state="collapsed"),
        collapse_panels=False,
    )


def _time_index(rr, epoch0, times):
    """The ``t_s`` (duration, s from ``epoch0``) and ``utc`` (timestamp) time columns."""
    times = np.asarray(times, float)
    return [rr.TimeColumn("t_s", duration=times),
            rr.TimeColumn("utc", timestamp=_as_datetime_ns(epoch0, times))]


def _as_datetime_ns(epoch0, t_s):
    e0 = np.datetime64(epoch0, "ns")
    return e0 + np.round(np.asarray(t_s) * 1e9).astype("timedelta64[ns]")


#: Log kinds whose x, y, z is a unit direction in ECI (drawn as rays): the registered
#: models flagged ``eci_ray`` (``fgnav.models.registry.eci_ray_kinds``).
ECI_DIRECTION_KINDS = eci_ray_kinds()


def _direction_measurements(measurements, epoch0=None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Normalize ``measurements`` to ``kind -> (t_s (M,), u_eci (M, 3))``.

    Accepts a ``fgnav.io.log_csv.MeasurementLog`` (its ECI direction kinds, times shifted
    to the solution's ``epoch0``), or a mapping ``kind -> (t_s, u_eci)`` /
    ``kind -> {"t_s": ..., "u_eci": ...}``.
    """
    out = {}
    if measurements is None:
        return out
    if hasattr(measurements, "kind") and hasattr(measurements, "xyz"):
        log = measurements
        shift = 0.0
        if epoch0 is not None:
            shift = float((np.datetime64(log.epoch0, "ns") - np.datetime64(epoch0, "ns"))
                          / np.timedelta64(1, "ns")) * 1e-9
        for kind in ECI_DIRECTION_KINDS:
            sel = log.select(kind)
            if len(sel):
                out[kind] = (np.asarray(log.t_s, float)[sel] + shift, np.asarray(log.xyz, float)[sel])
        return out
    for kind, m in dict(measurements).items():
        if isinstance(m, Mapping):
            t, u = m.get("t_s"), m.get("u_eci")
        else:
            t, u = m
        if t is None or u is None:
            continue
        t = np.asarray(t, float).reshape(-1)
        u = np.asarray(u, float).reshape(-1, 3)
        if len(t) != len(u):
            raise ValueError(f"measurements[{kind!r}]: {len(t)} times but {len(u)} directions")
        out[str(kind)] = (t, u)
    return out


def log_solution(rrd_path, solution, *, truth_x_eci=None, measurements=None, spawn=False,
                 sigma_scale=3.0, ellipsoid_every=None, magnification=None,
                 residual_t_s=None, application_id="fgnav", truth_attitude_R=None) -> dict:
    """Write a Rerun recording of ``solution`` to ``rrd_path`` (``.rrd``).

    Parameters
    ----------
    solution : ``fgnav.solution.Solution`` (SI, ECI).
    truth_x_eci : optional (N, 6) true states at ``solution.t_s`` [m, m/s].
    measurements : optional ``MeasurementLog`` (its ``earth_direction`` and ``refraction``
        rows), or ``kind -> (t_s (M,), u_eci (M, 3))`` (or a mapping with keys
        ``t_s`` and ``u_eci``): measured unit directions in ECI, drawn as rays from the
        spacecraft (interpolated estimated position) — the Earth direction reaches the
        Earth centre (length ``|r|``), other kinds (stars) are drawn 0.25 ``|r|`` long.
        Several rows at one time are shown together.
    spawn : open a viewer on the file afterwards when a display is available (else print
        how to open it).
    sigma_scale : k of the k-sigma ellipsoids and bounds.
    ellipsoid_every : epochs between ellipsoids of the static trail (default ~60 ellipsoids).
    magnification : ellipsoid magnification (default: a power of ten so they are visible).
    residual_t_s : optional ``kind -> (M,)`` times of ``solution.residuals[kind]`` rows
        (default ``solution.extras["residual_t_s"]``, else ``solution.t_s`` when the
        counts match, else a ``residual_index`` sequence timeline).
    truth_attitude_R : optional (N, 3, 3) true ``R_eci_from_body`` at ``solution.t_s``
        (:func:`read_truth_attitude`): the attitude error is plotted against its ±kσ.

    The attitude (``solution.variables`` of the attitude variable when estimated, else the log's
    ``attitude`` rows when it is known) draws the body axes along the trajectory; the log's
    body-frame rows (``star_direction_body``, ``earth_direction_body``, ...) are drawn as
    rays in the ``camera`` view (the body frame; with an estimated attitude also each star's
    catalogue direction rotated into the body frame, where the measured ray should fall).

    Returns a dict: ``path``, ``entities`` (list of entity paths logged), ``magnification``,
    ``epochs``.
    """
    import rerun as rr

    t_s = np.asarray(solution.t_s, float)
    x = np.asarray(solution.x_eci, float)
    P = np.asarray(solution.P_eci, float)
    n = len(t_s)
    if x.shape != (n, 6) or P.shape != (n, 6, 6):
        raise ValueError(f"solution shapes: t_s {t_s.shape}, x_eci {x.shape}, P_eci {P.shape}")
    truth = None if truth_x_eci is None else np.asarray(truth_x_eci, float)
    if truth is not None and truth.shape != (n, 6):
        raise UserError(f"truth states must be ({n}, 6) at the solution epochs, got {truth.shape}")
    k = float(sigma_scale)
    ks = f"{k:g}".replace(".", "p")
    path = Path(rrd_path)
    path.parent.mkdir(parents=True, exist_ok=True)

    has_latency = solution.latency_s is not None and len(solution.latency_s) == n
    rkinds = [kk for kk, v in (solution.residuals or {}).items() if np.size(v)]
    att = _attitude_of(solution, measurements)
    body_rows = _body_measurements(measurements, solution.epoch0)
    fin = np.all(np.isfinite(x), axis=1)
    eye, up = orbit_eye(x[fin, :3], x[fin, 3:])
    blueprint = default_blueprint(has_truth=truth is not None, residual_kinds=rkinds,
                                  has_latency=has_latency,
                                  t_range_s=(t_s[0], t_s[-1]) if n else None, eye_km=eye, eye_up=up,
                                  has_attitude=att is not None and att[2] is not None,
                                  has_camera=bool(body_rows), boresight_body=_boresight(body_rows))

    with recording_file(path, blueprint, application_id) as rec:
        entities = _log_all(rec, rr, solution, t_s, x, P, truth, measurements, k, ks,
                            ellipsoid_every, magnification, residual_t_s, rkinds, has_latency)
        entities[0].extend(_log_attitude(rec, rr, solution.epoch0, t_s, x, att, body_rows, k,
                                         truth_attitude_R))
    entities, mag = entities
    result = {"path": str(path), "entities": entities, "magnification": mag, "epochs": n}
    if spawn:
        launched, msg = open_viewer(path)
        print(msg, file=sys.stderr)
        result["viewer"] = launched
    return result


def log_solution_to(rec, solution, *, measurements=None, sigma_scale=3.0,
                    residual_t_s=None) -> list[str]:
    """The entities of :func:`log_solution` (trajectory, covariance ellipsoids, errors'
    sigmas, residuals, measurement rays) logged into an open recording stream ``rec`` (e.g.
    one served live, :mod:`fgnav.viz.rerun_live`) instead of a file; returns the entity
    paths."""
    import rerun as rr

    t_s = np.asarray(solution.t_s, float)
    x, P = np.asarray(solution.x_eci, float), np.asarray(solution.P_eci, float)
    k = float(sigma_scale)
    has_latency = solution.latency_s is not None and len(solution.latency_s) == len(t_s)
    rkinds = [kk for kk, v in (solution.residuals or {}).items() if np.size(v)]
    return _log_all(rec, rr, solution, t_s, x, P, None, measurements, k,
                    f"{k:g}".replace(".", "p"), None, None, residual_t_s, rkinds, has_latency)[0]


@contextmanager
def recording_file(path, blueprint, application_id="fgnav"):
    """A recording stream saved to ``path`` with ``blueprint`` as its default layout. It is
    written to a temporary file in the same directory and renamed when the ``with`` block
    completes, so an interrupted run never leaves a half-written recording under the final
    name (the temporary file is removed)."""
    import rerun as rr

    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    rec = rr.RecordingStream(application_id)
    rec.save(str(tmp), default_blueprint=blueprint)
    try:
        yield rec
        rec.flush()
        rec.disconnect()
        os.replace(tmp, path)
    except BaseException:
        rec.disconnect()
        tmp.unlink(missing_ok=True)
        raise


def _log_all(rec, rr, solution, t_s, x, P, truth, measurements, k, ks, ellipsoid_every,
             magnification, residual_t_s, rkinds, has_latency):
    """Log every entity of ``log_solution``; returns (entity paths, magnification)."""
    from scipy.stats import chi2 as chi2_dist

    n = len(t_s)
    entities: list[str] = []

    def idx(times):
        return _time_index(rr, solution.epoch0, times)

    def send(entity, times, columns):
        rec.send_columns(entity, indexes=idx(times), columns=columns)
        entities.append(entity)

    def static(entity, archetype):
        rec.log(entity, archetype, static=True)
        entities.append(entity)

    def series(entity, values, names, colors, widths=None):
        values = np.asarray(values, float)
        if values.ndim == 1:
            values = values[:, None]
        static(entity, rr.SeriesLines(names=names, colors=colors,
                                      widths=widths or [1.5] * len(names)))
        rec.send_columns(entity, indexes=idx(t_s), columns=rr.Scalars.columns(scalars=values))

    # ---- 3-D scene (km) --------------------------------------------------------------
    static("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP)
    re_km = R_EARTH_M * _KM
    static("world/earth", rr.Ellipsoids3D(
        half_sizes=[[re_km, re_km, re_km * (1.0 - _F_WGS84)]], colors=[[40, 90, 170]],
        fill_mode="solid", labels=["Earth (WGS-84)"], show_labels=False))
    axis_len = 1.5 * re_km
    static("world/eci_axes", rr.Arrows3D(
        origins=np.zeros((3, 3)), vectors=np.eye(3) * axis_len,
        colors=[[230, 60, 60], [60, 200, 60], [80, 120, 255]], labels=["X_eci", "Y_eci", "Z_eci"]))

    r_km = x[:, :3] * _KM
    finite = np.all(np.isfinite(r_km), axis=1)
    static("world/estimate/trajectory", rr.LineStrips3D([r_km[finite]], colors=[[255, 170, 0]],
                                                        radii=[rr.Radius.ui_points(1.5)],
                                                        labels=["estimate"]))
    send("world/estimate/state", t_s, rr.Points3D.columns(positions=r_km).partition(np.ones(n, int)))
    if truth is not None:
        rt_km = truth[:, :3] * _KM
        static("world/truth/trajectory", rr.LineStrips3D([rt_km], colors=[[220, 220, 220]],
                                                         radii=[rr.Radius.ui_points(1.0)],
                                                         labels=["truth"]))
        send("world/truth/state", t_s, rr.Points3D.columns(positions=rt_km).partition(np.ones(n, int)))

    # covariance ellipsoids (position block)
    okP = np.all(np.isfinite(P[:, :3, :3].reshape(n, -1)), axis=1) & finite
    mag = 1.0
    if np.any(okP):
        half_m, q_wxyz = covariance_ellipsoids(P[okP, :3, :3], k)
        mag = float(magnification) if magnification else auto_magnification(half_m, x[okP, :3])
        mags = f"{mag:g}".replace("+", "")
        ell = f"world/estimate/covariance_{ks}sigma_x{mags}"
        q_xyzw = np.concatenate([q_wxyz[:, 1:], q_wxyz[:, :1]], axis=1)
        half_km = half_m * mag * _KM
        centers = r_km[okP]
        send(ell + "/current", t_s[okP], rr.Ellipsoids3D.columns(
            centers=centers, half_sizes=half_km, quaternions=q_xyzw).partition(np.ones(int(okP.sum()), int)))
        m = int(okP.sum())
        every = int(ellipsoid_every) if ellipsoid_every else max(1, m // 60)
        sel = np.arange(0, m, every)
        static(ell + "/trail", rr.Ellipsoids3D(
            centers=centers[sel], half_sizes=half_km[sel], quaternions=q_xyzw[sel],
            colors=[[255, 170, 0, 90]], fill_mode="majorwireframe"))

    # measurement rays
    for kind, (tm, u) in _direction_measurements(measurements, solution.epoch0).items():
        order = np.argsort(tm, kind="stable")
        tm, u = tm[order], u[order]
        u = u / np.linalg.norm(u, axis=1, keepdims=True)
        origin_km = np.stack([np.interp(tm, t_s[finite], r_km[finite, i]) for i in range(3)], axis=1)
        is_earth = "earth" in kind.lower()
        length = np.linalg.norm(origin_km, axis=1, keepdims=True) * (1.0 if is_earth else 0.25)
        tu, counts = np.unique(tm, return_counts=True)
        color = [[80, 200, 255]] if is_earth else [[255, 255, 160]]
        send(f"world/measurements/{_safe(kind)}", tu, rr.Arrows3D.columns(
            origins=origin_km, vectors=u * length,
            colors=np.repeat(color, len(tm), axis=0)).partition(counts))

    # ---- time series -----------------------------------------------------------------
    for frame, axes in (("rtn", RTN_AXES), ("eci", ECI_AXES)):
        err, sig = error_and_sigma(x, P, truth, frame=frame)
        for block, unit, off in (("position", "m", 0), ("velocity", "mps", 3)):
            for i, ax in enumerate(axes):
                b = k * sig[:, off + i]
                col, light = AXIS_COLORS[i], _lighter(AXIS_COLORS[i])
                if err is not None:
                    series(f"errors/{block}_{frame}_{unit}/{ax}",
                           np.stack([err[:, off + i], b, -b], axis=1),
                           [f"{ax} error", f"{ax} +{k:g}σ", f"{ax} -{k:g}σ"], [col, light, light],
                           [2.0, 1.0, 1.0])
                else:
                    series(f"sigma/{block}_{frame}_{unit}/{ax}", np.stack([b, -b], axis=1),
                           [f"{ax} +{k:g}σ", f"{ax} -{k:g}σ"], [col, col])
    if truth is not None:
        e_norm = np.linalg.norm(x[:, :3] - truth[:, :3], axis=1)
        vals, names = [e_norm], [estimate_label(solution.method)]
        if (solution.online_x_eci is not None and solution.method != "ekf"
                and np.shape(solution.online_x_eci) == (n, 6)):
            vals.append(np.linalg.norm(np.asarray(solution.online_x_eci)[:, :3] - truth[:, :3], axis=1))
            names.append("online")
        series("errors/position_norm_m", np.stack(vals, axis=1), names,
               [[31, 119, 180], [255, 127, 14]][: len(names)])
        lo, hi = chi2_dist.ppf([0.025, 0.975], 6)
        nv = nees(x, P, truth)
        series("consistency/nees", np.stack([nv, np.full(n, 6.0), np.full(n, lo), np.full(n, hi)], axis=1),
               ["NEES", "expected (6)", "2.5 %", "97.5 %"],
               [[31, 119, 180], [44, 160, 44], [150, 150, 150], [150, 150, 150]])

    if has_latency:
        series("timing/latency_ms", np.asarray(solution.latency_s, float) * 1e3, ["latency"],
               [[148, 103, 189]])

    rtimes = residual_t_s if residual_t_s is not None else (solution.extras or {}).get("residual_t_s", {})
    for kind in rkinds:
        res = np.asarray(solution.residuals[kind], float)
        res = res.reshape(len(res), -1)
        ent = f"residuals/{_safe(kind)}"
        names = [f"{kind}[{j}]" for j in range(res.shape[1])]
        tr = None
        if rtimes and kind in rtimes and len(rtimes[kind]) == len(res):
            tr = np.asarray(rtimes[kind], float)
        elif len(res) == n:
            tr = t_s
        static(ent, rr.SeriesPoints(names=names, marker_sizes=[1.5] * len(names)))
        if tr is not None:
            rec.send_columns(ent, indexes=idx(tr), columns=rr.Scalars.columns(scalars=res))
        else:
            rec.send_columns(ent, indexes=[rr.TimeColumn("residual_index", sequence=np.arange(len(res)))],
                             columns=rr.Scalars.columns(scalars=res))

    static("about", rr.TextDocument(_about_text(solution, truth is not None, k, mag), media_type="text/markdown"))
    return entities, mag


def read_truth_attitude(truth_oem_path, epoch0, t_s) -> np.ndarray | None:
    """The true ``R_eci_from_body`` (N, 3, 3) at ``t_s`` (s from ``epoch0``) from
    ``truth_attitude.csv`` beside the truth OEM (:data:`fgnav.io.truth_params.TRUTH_ATTITUDE_CSV`,
    spherical linear interpolation between its epochs); None when there is no such file or
    it does not cover ``t_s``."""
    from scipy.spatial.transform import Rotation, Slerp

    path = Path(truth_oem_path).parent / TRUTH_ATTITUDE_CSV
    if not path.is_file():
        return None
    epochs, cols = read_truth_params_csv(path)
    missing = [c for c in TRUTH_ATTITUDE_COLUMNS if c not in cols]
    if missing:
        raise UserError(f"{path}: expected the column(s) {', '.join(missing)}")
    tt = np.asarray(seconds_since(epochs, np.datetime64(epoch0, "ns")), dtype=float)
    t = np.asarray(t_s, float)
    if len(tt) < 2 or t.min() < tt[0] - 1e-6 or t.max() > tt[-1] + 1e-6:
        return None
    rot = Rotation.from_rotvec(np.column_stack([cols[c] for c in TRUTH_ATTITUDE_COLUMNS]))
    return Slerp(tt, rot)(np.clip(t, tt[0], tt[-1])).as_matrix()


def _attitude_of(solution, measurements):
    """``(t_s (K,), R_eci_from_body (K, 3, 3), P (K, 3, 3) rad^2 or None)`` of the estimated
    attitude, else of the log's ``attitude`` rows (a known attitude; no covariance drawn),
    else None."""
    from scipy.spatial.transform import Rotation

    v = (solution.variables or {}).get(ATTITUDE_VARIABLE.name)
    if v is not None:
        w, Pa = v
        return (np.asarray(solution.t_s, float), Rotation.from_rotvec(np.asarray(w, float)).as_matrix(),
                np.asarray(Pa, float))
    if measurements is not None and hasattr(measurements, "select"):
        sel = measurements.select(ATTITUDE.kind)
        if len(sel):
            shift = float((np.datetime64(measurements.epoch0, "ns") - np.datetime64(solution.epoch0, "ns"))
                          / np.timedelta64(1, "ns")) * 1e-9
            t = np.asarray(measurements.t_s, float)[sel] + shift
            return t, Rotation.from_rotvec(np.asarray(measurements.xyz, float)[sel]).as_matrix(), None
    return None


def _body_measurements(measurements, epoch0) -> dict:
    """The log's body-frame direction rows: kind -> ``(t_s (M,), u_body (M, 3), s_eci (M, 3)
    or None)`` (``s_eci``: a star's catalogue direction, ``star_x/y/z``)."""
    out = {}
    if measurements is None or not hasattr(measurements, "select"):
        return out
    shift = float((np.datetime64(measurements.epoch0, "ns") - np.datetime64(epoch0, "ns"))
                  / np.timedelta64(1, "ns")) * 1e-9
    for kind in sorted({str(k) for k in measurements.kind if str(k).endswith("_direction_body")}):
        sel = measurements.select(kind)
        u = np.asarray(measurements.xyz, float)[sel]
        s_eci = None
        if all(c in (measurements.extra or {}) for c in ("star_x", "star_y", "star_z")):
            s_eci = np.column_stack([np.asarray(measurements.extra[c], float)[sel]
                                     for c in ("star_x", "star_y", "star_z")])
            if not np.all(np.isfinite(s_eci)):
                s_eci = None
        out[kind] = (np.asarray(measurements.t_s, float)[sel] + shift, u, s_eci)
    return out


def _boresight(body_rows) -> np.ndarray | None:
    """Mean measured star direction in the body frame (the star camera's boresight), else
    the mean of the other body-frame rays; None without body-frame rows."""
    for want_star in (True, False):
        us = [u for kind, (_, u, _) in body_rows.items() if kind.startswith("star") == want_star]
        if us:
            m = np.nanmean(np.concatenate(us), axis=0)
            if np.all(np.isfinite(m)) and np.linalg.norm(m) > 0:
                return m / np.linalg.norm(m)
    return None


#: Entity root of the attitude error / sigma time series (arcsec about the body axes): the
#: attitude variable's name.
ATTITUDE_ROOT = ATTITUDE_VARIABLE.name

#: Colours of the body axes x, y, z (red, green, blue, as the ECI axes).
_BODY_AXIS_COLORS = np.array([[230, 60, 60], [60, 200, 60], [80, 120, 255]])


def _log_attitude(rec, rr, epoch0, t_s, x, att, body_rows, k, truth_R) -> list[str]:
    """The body axes along the trajectory (a trail, and at the cursor), the attitude error /
    ±kσ series (arcsec) and the body-frame rays of the ``camera`` view; returns the entity
    paths logged."""
    entities = []

    def idx(times):
        return _time_index(rr, epoch0, times)

    r_km = x[:, :3] * _KM
    fin = np.all(np.isfinite(r_km), axis=1)
    if not np.any(fin):
        return entities
    size_km = float(np.max(np.linalg.norm(r_km[fin], axis=1)))
    R_of = None
    if att is not None:
        ta, Ra, Pa = att
        inside = (ta >= t_s[fin][0] - 1e-6) & (ta <= t_s[fin][-1] + 1e-6)
        ta, Ra = ta[inside], Ra[inside]
        Pa = None if Pa is None else Pa[inside]
        if len(ta):
            origin = np.stack([np.interp(ta, t_s[fin], r_km[fin, i]) for i in range(3)], axis=1)
            L = 0.08 * size_km
            vec = np.swapaxes(Ra, 1, 2).reshape(-1, 3) * L        # rows: body x, y, z in ECI
            cols = np.tile(_BODY_AXIS_COLORS, (len(ta), 1))
            ent = "world/estimate/body_axes"
            rec.send_columns(ent, indexes=idx(ta), columns=rr.Arrows3D.columns(
                origins=np.repeat(origin, 3, axis=0), vectors=vec, colors=cols).partition(np.full(len(ta), 3)))
            entities.append(ent)
            sel = np.arange(0, len(ta), max(1, len(ta) // 40))
            ent = "world/estimate/body_axes_trail"
            rec.log(ent, rr.Arrows3D(origins=np.repeat(origin[sel], 3, axis=0),
                                     vectors=np.swapaxes(Ra[sel], 1, 2).reshape(-1, 3) * 0.6 * L,
                                     colors=np.tile(_BODY_AXIS_COLORS, (len(sel), 1)),
                                     radii=[rr.Radius.ui_points(1.0)]), static=True)
            entities.append(ent)
            if Pa is not None:
                sig = np.sqrt(np.clip(np.diagonal(Pa, axis1=1, axis2=2), 0.0, None)) * k / _ARCSEC
                err = None
                if truth_R is not None and len(truth_R) == len(t_s) and len(ta) == len(t_s):
                    err = attitude_error_body(Ra, truth_R) / _ARCSEC
                for i, axn in enumerate(ECI_AXES):
                    col, light = AXIS_COLORS[i], _lighter(AXIS_COLORS[i])
                    if err is not None:
                        ent, vals = f"{ATTITUDE_ROOT}/error_arcsec/{axn}", np.stack([err[:, i], sig[:, i], -sig[:, i]], 1)
                        names, colors = [f"{axn} error", f"{axn} +{k:g}σ", f"{axn} -{k:g}σ"], [col, light, light]
                    else:
                        ent, vals = f"{ATTITUDE_ROOT}/sigma_arcsec/{axn}", np.stack([sig[:, i], -sig[:, i]], 1)
                        names, colors = [f"{axn} +{k:g}σ", f"{axn} -{k:g}σ"], [col, col]
                    rec.log(ent, rr.SeriesLines(names=names, colors=colors, widths=[1.5] * len(names)),
                            static=True)
                    rec.send_columns(ent, indexes=idx(ta), columns=rr.Scalars.columns(scalars=vals))
                    entities.append(ent)
            if len(ta) >= 2:
                from scipy.spatial.transform import Rotation, Slerp
                R_of = Slerp(ta, Rotation.from_matrix(Ra))
    if body_rows:
        rec.log("camera", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        rec.log("camera/body_axes", rr.Arrows3D(
            origins=np.zeros((3, 3)), vectors=np.eye(3) * 0.5, colors=_BODY_AXIS_COLORS,
            labels=["x_body", "y_body", "z_body"]), static=True)
        entities += ["camera", "camera/body_axes"]
    for kind, (tm, u, s_eci) in body_rows.items():
        order = np.argsort(tm, kind="stable")
        tm, u = tm[order], u[order]
        u = u / np.linalg.norm(u, axis=1, keepdims=True)
        tu, counts = np.unique(tm, return_counts=True)
        is_star = kind.startswith("star")
        color = [255, 230, 90] if is_star else [80, 200, 255]
        ent = f"camera/{_safe(kind)}/measured"
        rec.send_columns(ent, indexes=idx(tu), columns=rr.Arrows3D.columns(
            origins=np.zeros_like(u), vectors=u, colors=np.repeat([color], len(u), axis=0)).partition(counts))
        entities.append(ent)
        if s_eci is not None and R_of is not None:
            s_eci = s_eci[order]
            ok = (tm >= R_of.times[0]) & (tm <= R_of.times[-1])
            if np.any(ok):
                Rm = R_of(tm[ok]).as_matrix()
                pred = np.einsum("nji,nj->ni", Rm, s_eci[ok])          # R^T s: body frame
                tu2, c2 = np.unique(tm[ok], return_counts=True)
                ent = f"camera/{_safe(kind)}/catalogue_in_body"
                rec.send_columns(ent, indexes=idx(tu2), columns=rr.Points3D.columns(
                    positions=pred, colors=np.repeat([[255, 90, 200]], len(pred), axis=0),
                    radii=np.full(len(pred), -3.0)).partition(c2))
                entities.append(ent)
    return entities


def _safe(name: str) -> str:
    return "".join(c if (c.isalnum() or c in "_-") else "_" for c in str(name))


def _about_text(solution, has_truth, k, mag) -> str:
    return "\n".join([
        f"# fgnav — {solution.method}",
        f"- epoch0 (t_s = 0): {format_utc(solution.epoch0)[:-4]}Z",  # ms, leap-second aware
        f"- epochs: {len(solution.t_s)}, iterations: {solution.iterations}, chi2: {solution.chi2:.6g}",
        "- 3-D view: ECI, **km**; Earth = WGS-84 ellipsoid (not rotated with the Earth).",
        f"- covariance ellipsoids: position **{k:g}σ x {mag:g}** (magnified {mag:g} times).",
        f"- time series: {'errors (estimate - truth)' if has_truth else 'sigmas'} with ±{k:g}σ, "
        "m and m/s; RTN = radial / along-track / orbit-normal of the "
        f"{'truth' if has_truth else 'estimated'} state.",
        "- residuals: whitened (expected standard normal).",
        "- attitude (when estimated or known): body axes x/y/z = red/green/blue along the "
        "trajectory; the star camera view shows the body-frame rays (yellow: measured; "
        "magenta dots: catalogue direction rotated by the estimated attitude).",
    ])


# --------------------------------------------------------------------------------------
# Several spacecraft (a formation's joint solution, the links): log_formation
# --------------------------------------------------------------------------------------
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


def log_result(rrd_path, res, p, *, log_path=None, truth=None, sigma_scale=3.0) -> dict:
    """The recording of ``fgnav smooth``'s result (``res``, of the pass ``p``) for S >= 1
    spacecraft: a formation's :func:`log_formation_result`; one spacecraft's
    :func:`log_solution` with the measurements of the log ``log_path``, the residuals at
    their rows' times and, with ``truth`` (the ``--truth`` directory), the true states and
    the true attitude where the attitude is estimated."""
    if p.spacecraft:
        return log_formation_result(rrd_path, res, p, truth=truth, sigma_scale=sigma_scale)
    sol = res.solution
    truth_R = (read_truth_attitude(truth, sol.epoch0, sol.t_s)
               if truth and ATTITUDE_VARIABLE.name in sol.variables else None)
    return log_solution(rrd_path, sol, truth_x_eci=res.x_true,
                        measurements=None if log_path is None else read_measurements(log_path),
                        residual_t_s=residual_times(res, p), truth_attitude_R=truth_R,
                        sigma_scale=sigma_scale)


def log_formation_result(rrd_path, res, p, *, truth=None, sigma_scale=3.0) -> dict:
    """:func:`log_formation` of ``fgnav smooth``'s formation result (``res``, ``p``); with
    ``truth`` (the ``--truth`` directory) each spacecraft's ``truth-<id>.oem``."""
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
