"""Render the sensor frames of a simulated pass: star-field and limb sub-aperture images.

Sensor: Wu et al.'s confocal Earth/star sensor (``fgnav.vision.sensor``). Body frame as
there: +z_body = star boresight, the four UV limb sub-apertures tilted 23.75° from -z_body.
The centre star field is rendered as its own frame (``star``), each limb sub-aperture that
sees the whole limb as its own frame (``limb0`` .. ``limb3``), all 16-bit PNG.

Attitude plan ("earth-pointing", known to the simulator, never given to the extractor):
limb sub-aperture ``point_limb`` (default 0) has its boresight on the Earth's centre and
the orbit normal ``h = r x v`` is along the body vector ``b2 = b_limb x z_body / |.|``::

    R_eci_from_body = [n, h, n x h] [b_limb, b2, b_limb x b2]^T,  n = -r/|r|   (TRIAD)

so the star boresight looks 156.25° away from the nadir. A limb frame is rendered only
when the whole limb circle (angular radius ``rho = asin(R_limb/|r|)``) lies inside the
sub-aperture's field stop with ``margin_deg`` to spare: ``theta + rho <= half_field -
margin`` (``theta`` = boresight-to-Earth-centre angle). With the default plan this holds for
|r| >= ~26,000 km (e.g. the whole ``geo-limb`` scenario; the outer part of a transfer orbit).

Index ``frames.csv`` (beside the ``frames/`` directory), one row per image: see
:data:`FRAME_COLUMNS`. Camera intrinsics and ``q_body_from_cam`` (scalar-first) are the
sensor calibration the extractor uses; the ``truth_*`` columns (true position, true
attitude, and for limb frames the true Earth direction / angular radius in the camera
frame) are for evaluation only.

Noise is deterministic by seed: frame ``k`` of camera ``c`` draws from
``numpy.random.default_rng([seed, k, c])``, independent of which other frames exist.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from factors.aberration import earth_velocity_bcrs_mps
from factors.constants import DEG, R_LIMB_UV_M
from fgnav.errors import UserError
from fgnav.io.atomic import atomic_writer
from fgnav.io.log_csv import log_from_arrays
from fgnav.models.registry import EARTH_DIRECTION, LIMB_RADIUS, prior_kinds
from fgnav.orbit import truth_at
from fgnav.progress import progress
from fgnav.simulate.limb_render import LimbScene, render_limb
from fgnav.simulate.noise import perturb_directions
from fgnav.simulate.pass_sim import sensor_epochs
from fgnav.simulate.star_render import render_star_field
from fgnav.time import add_seconds, format_utc, j2000_seconds, seconds_since
from fgnav.vision.attitude import quat_from_matrix
from fgnav.vision.camera import PinholeCamera
from fgnav.vision.catalogue import decimal_year, load_catalogue
from fgnav.vision.sensor import confocal_limb_subapertures

__all__ = ["ImageConfig", "FrameRecord", "FRAME_COLUMNS", "STAR_FIELD_1024_CAMERA",
           "earth_pointing_attitude", "limb_in_field", "frame_epochs", "default_image_period_s",
           "DEFAULT_MAX_IMAGE_EPOCHS", "render_pass_frames",
           "write_frames_index", "ideal_log_like"]

STAR_FIELD_1024_CAMERA = PinholeCamera(focal_mm=50.0, pixel_um=11.0, width_px=1024, height_px=1024)
"""Wu et al.'s star optics (f = 50 mm, 11 µm) on a 1024x1024 window: FOV 12.85° (Wu et al. ask
>= 8°; the wider window keeps lost-in-space identification reliable with BSC5 to V 6.5)."""

FRAME_COLUMNS = (
    "epoch", "file", "camera", "focal_mm", "pixel_um", "width_px", "height_px", "cx_px", "cy_px",
    "field_radius_px", "q_body_from_cam_w", "q_body_from_cam_x", "q_body_from_cam_y",
    "q_body_from_cam_z", "r_limb_m", "psf_sigma_px",
    "truth_r_eci_x_m", "truth_r_eci_y_m", "truth_r_eci_z_m",
    "truth_q_eci_from_body_w", "truth_q_eci_from_body_x", "truth_q_eci_from_body_y",
    "truth_q_eci_from_body_z", "truth_u_cam_x", "truth_u_cam_y", "truth_u_cam_z", "truth_rho_rad",
)
"""Columns of ``frames.csv``. camera: ``star`` or ``limbK``; field_radius_px empty when the
frame has no field stop; r_limb_m (limb sphere radius, m), psf_sigma_px (optics PSF 1σ,
px: calibration) and the truth_u_cam / truth_rho columns are empty for star frames."""


@dataclass(frozen=True)
class ImageConfig:
    """What to render. Units SI unless named.

    star_camera : star-field camera (body frame = its frame, R_body_from_cam = I);
    point_limb : index of the limb sub-aperture put on the Earth's centre;
    margin_deg : required clearance of the limb circle inside the field stop (deg);
    period_s : image period (s; default :func:`default_image_period_s`, the scenario's step
    thinned to at most :data:`DEFAULT_MAX_IMAGE_EPOCHS` epochs);
    vmag_max : faintest star rendered; r_limb_m : limb sphere radius (default: the
    scenario's limb sensor, else 6,375 km); star_flux_v0_e : electrons of a V = 0 star.
    """

    star_camera: PinholeCamera = STAR_FIELD_1024_CAMERA
    point_limb: int = 0
    margin_deg: float = 0.5
    period_s: float | None = None
    vmag_max: float = 7.0
    r_limb_m: float | None = None
    star_flux_v0_e: float = 3.0e6
    png_compression: int = 1
    limb_kwargs: dict = field(default_factory=dict)


@dataclass
class FrameRecord:
    """One row of ``frames.csv`` (module doc)."""

    epoch: np.datetime64
    file: str
    camera_name: str
    camera: PinholeCamera
    field_radius_px: float | None
    R_body_from_cam: np.ndarray
    r_limb_m: float | None
    truth_r_eci_m: np.ndarray
    truth_R_eci_from_body: np.ndarray
    truth_u_cam: np.ndarray | None = None
    truth_rho_rad: float | None = None
    psf_sigma_px: float | None = None

    def to_row(self) -> list[str]:
        def f(x):
            return "" if x is None else repr(float(x))

        c = self.camera
        qb = quat_from_matrix(self.R_body_from_cam)
        qt = quat_from_matrix(self.truth_R_eci_from_body)
        u = [None] * 3 if self.truth_u_cam is None else list(self.truth_u_cam)
        return ([format_utc(self.epoch), self.file, self.camera_name, f(c.focal_mm), f(c.pixel_um),
                 str(int(c.width_px)), str(int(c.height_px)), f(c.cx), f(c.cy), f(self.field_radius_px)]
                + [f(x) for x in qb] + [f(self.r_limb_m), f(self.psf_sigma_px)] + [f(x) for x in self.truth_r_eci_m]
                + [f(x) for x in qt] + [f(x) for x in u] + [f(self.truth_rho_rad)])


def earth_pointing_attitude(r_eci_m: np.ndarray, v_eci_mps: np.ndarray, b_point_body: np.ndarray,
                            b_normal_body: np.ndarray) -> np.ndarray:
    """R_eci_from_body (N, 3, 3) putting body vector ``b_point_body`` on the nadir ``-r/|r|``
    and ``b_normal_body`` (made orthogonal to it) on the orbit normal ``r x v`` (TRIAD)."""
    r = np.atleast_2d(np.asarray(r_eci_m, float))
    v = np.atleast_2d(np.asarray(v_eci_mps, float))
    n = -r / np.linalg.norm(r, axis=1, keepdims=True)
    h = np.cross(r, v)
    h = h - np.sum(h * n, axis=1, keepdims=True) * n
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    A = np.stack([n, h, np.cross(n, h)], axis=2)                      # (N, 3, 3) columns
    b1 = np.asarray(b_point_body, float) / np.linalg.norm(b_point_body)
    b2 = np.asarray(b_normal_body, float)
    b2 = b2 - (b2 @ b1) * b1
    b2 /= np.linalg.norm(b2)
    Bm = np.column_stack([b1, b2, np.cross(b1, b2)])
    return A @ Bm.T


def limb_in_field(u_cam: np.ndarray, rho_rad: float, half_field_rad: float, margin_rad: float) -> bool:
    """True when the whole limb circle (centre ``u_cam``, angular radius ``rho_rad``) lies in
    the circular field of half-angle ``half_field_rad`` with ``margin_rad`` to spare."""
    theta = math.acos(max(-1.0, min(1.0, float(u_cam[2]) / float(np.linalg.norm(u_cam)))))
    return theta + rho_rad <= half_field_rad - margin_rad


DEFAULT_MAX_IMAGE_EPOCHS = 100
"""Image epochs of a pass when no image period is given (:func:`frame_epochs`): at ~1.8 MB
and ~0.3 s per epoch (a 1024x1024 star frame and an 891x891 limb frame, 16-bit PNG of
shot/read noise, which no lossless coder packs below ~6 and ~4 bits a pixel) this bounds a
default pass to ~180 MB and well under 90 s, whatever its length."""


def default_image_period_s(scenario, max_epochs: int = DEFAULT_MAX_IMAGE_EPOCHS) -> float:
    """The scenario step times the smallest integer ``m`` for which the pass has at most
    ``max_epochs`` image epochs (``m = 1`` for a short pass: every measurement epoch)."""
    n = len(sensor_epochs(scenario, None))
    return float(scenario.step_s) * max(1, math.ceil((n - 1) / (max_epochs - 1)))


def frame_epochs(scenario, period_s: float | None) -> np.ndarray:
    """Image epochs (s from the pass epoch): every ``period_s`` (default
    :func:`default_image_period_s`: the scenario step, thinned to at most
    :data:`DEFAULT_MAX_IMAGE_EPOCHS` epochs)."""
    if period_s is not None and not period_s > 0:
        raise UserError(f"image period must be > 0 s, got {period_s}")
    return sensor_epochs(scenario, default_image_period_s(scenario) if period_s is None else period_s)


def _r_limb_of(scenario, cfg: ImageConfig) -> float:
    if cfg.r_limb_m is not None:
        return float(cfg.r_limb_m)
    for s in scenario.sensors:
        if s.kind == LIMB_RADIUS.kind:
            return float(s.r_limb_km) * 1e3
    return float(R_LIMB_UV_M)


def write_frames_index(path, records: list[FrameRecord], comments=()) -> None:
    """Write ``frames.csv`` atomically (module doc)."""
    lines = ["# fgnav image index (fgnav.simulate.images): one row per 16-bit PNG frame\n",
             "# q_body_from_cam: scalar-first quaternion of R_body_from_cam (sensor calibration)\n",
             "# truth_*: true position (ECI, m), attitude, Earth direction/angular radius (camera\n",
             "#   frame, OpenCV axes) -- for evaluation only, never used by fgnav extract\n"]
    lines += [f"# {c}\n" for c in comments]
    lines.append(",".join(FRAME_COLUMNS) + "\n")
    lines += [",".join(r.to_row()) + "\n" for r in records]
    with atomic_writer(path) as fh:
        fh.writelines(lines)


def render_pass_frames(sim, out_dir, *, seed: int = 0, config: ImageConfig = ImageConfig(),
                       quiet: bool = True) -> list[FrameRecord]:
    """Render the frames of a simulated pass into ``out_dir/frames/`` and write
    ``out_dir/frames.csv``; returns the index rows.

    ``sim`` : :class:`fgnav.simulate.pass_sim.SimulatedPass` (truth from DOP853). Per image
    epoch: the attitude plan (module doc), one star frame, and one frame per limb
    sub-aperture that sees the whole limb. Epochs where no sub-aperture sees the limb get
    the star frame only.
    """
    import cv2

    cfg = config
    subs = confocal_limb_subapertures()
    if not 0 <= cfg.point_limb < len(subs):
        raise UserError(f"point_limb must be in 0..{len(subs) - 1}, got {cfg.point_limb}")
    t = frame_epochs(sim.scenario, cfg.period_s)
    t = t[t <= sim.t_s[-1] + 1e-9]
    x = truth_at(sim.t_s, sim.x_true, t)
    b_point = subs[cfg.point_limb].boresight_body
    R_all = earth_pointing_attitude(x[:, :3], x[:, 3:], b_point, np.cross(b_point, [0.0, 0.0, 1.0]))
    r_limb = _r_limb_of(sim.scenario, cfg)
    epochs = add_seconds(sim.epoch0, t)
    v_earth = earth_velocity_bcrs_mps(float(j2000_seconds(sim.epoch0)) + t)
    cat = load_catalogue(epoch_year=decimal_year(format_utc(epochs[0])))
    out = Path(out_dir)
    fdir = out / "frames"
    fdir.mkdir(parents=True, exist_ok=True)
    png = [cv2.IMWRITE_PNG_COMPRESSION, int(cfg.png_compression)]
    records: list[FrameRecord] = []
    star_cam = cfg.star_camera
    for k in progress(range(len(t)), desc="rendering frames", unit="epoch", quiet=quiet):
        R = R_all[k]
        r = x[k, :3]
        # star field: camera = body frame
        img, _ = render_star_field(star_cam, R, cat, np.random.default_rng([seed, k, 0]),
                                   flux_v0_e=cfg.star_flux_v0_e, vmag_max=cfg.vmag_max,
                                   v_observer_bcrs_mps=v_earth[k] + x[k, 3:])  # aberration
        name = f"{k:06d}_star.png"
        if not cv2.imwrite(str(fdir / name), img, png):
            raise UserError(f"{fdir / name}: cannot write the image")
        records.append(FrameRecord(epochs[k], f"frames/{name}", "star", star_cam, None, np.eye(3),
                                   None, r.copy(), R.copy()))
        for j, sub in enumerate(subs):
            R_cam_from_eci = (R @ sub.R_body_from_cam).T
            c_cam = R_cam_from_eci @ (-r)
            rho = math.asin(r_limb / float(np.linalg.norm(r)))
            cam = sub.camera
            field_r = 0.5 * (cam.width_px - 1)
            half_field = math.atan(field_r / cam.f_px)
            if not limb_in_field(c_cam, rho, half_field, cfg.margin_deg * DEG):
                continue
            scene = LimbScene(c_cam_m=c_cam, r_limb_m=r_limb)
            ren = render_limb(cam, scene, np.random.default_rng([seed, k, 1 + j]),
                              field_radius_px=field_r, **cfg.limb_kwargs)
            name = f"{k:06d}_{sub.name}.png"
            if not cv2.imwrite(str(fdir / name), ren.image_dn, png):
                raise UserError(f"{fdir / name}: cannot write the image")
            records.append(FrameRecord(epochs[k], f"frames/{name}", sub.name, cam, field_r,
                                       sub.R_body_from_cam.copy(), r_limb, r.copy(), R.copy(),
                                       scene.u_cam, scene.rho_rad, ren.detector.psf_sigma_px))
    write_frames_index(out / "frames.csv", records,
                       comments=(f"scenario {sim.scenario.name}, seed {seed}, "
                                 f"{len(t)} epochs, attitude plan: limb{cfg.point_limb} on the Earth",))
    return records


def ideal_log_like(log, epoch0, t_truth_s: np.ndarray, x_truth: np.ndarray, seed: int = 0):
    """The comparison log: same rows, epochs and per-row sigmas as ``log`` (e.g. one
    extracted from images), but measurements drawn from the truth with exactly that noise:
    ``earth_direction`` = true ``-r/|r|`` rotated by tangent-plane noise of 1σ ``sigma``
    (:func:`fgnav.simulate.noise.perturb_directions`), ``limb_radius`` =
    ``asin(R_limb/|r|) + sigma n``; prior rows are copied. ``t_truth_s`` are seconds from
    ``epoch0``; truth is interpolated with :func:`fgnav.orbit.truth_at`."""
    rng = np.random.default_rng(seed)
    t = np.asarray(seconds_since(log.epochs_utc(), epoch0), float)
    r = truth_at(np.asarray(t_truth_s, float), np.asarray(x_truth, float), t)[:, :3]
    rn = np.linalg.norm(r, axis=1)
    xyz = np.array(log.xyz, float)
    d = np.flatnonzero(log.kind == EARTH_DIRECTION.kind)
    if len(d):
        xyz[d] = perturb_directions(-r[d] / rn[d, None], log.sigma[d], rng)
    lr = np.flatnonzero(log.kind == LIMB_RADIUS.kind)
    if len(lr):
        xyz[lr, 0] = np.arcsin(xyz[lr, 1] / rn[lr]) + log.sigma[lr] * rng.standard_normal(len(lr))
    other = set(np.unique(log.kind)) - {EARTH_DIRECTION.kind, LIMB_RADIUS.kind, *prior_kinds()}
    if other:
        raise UserError(f"ideal_log_like: kinds {sorted(other)} are not supported")
    return log_from_arrays(log.epoch0, log.t_s, log.kind, xyz, log.sigma, path="<ideal>",
                           centre=log.centre, schema=log.schema)
