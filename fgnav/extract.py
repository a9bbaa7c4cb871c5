"""Frames -> measurement log: the image front end run over a whole pass (``fgnav extract``).

Input: a ``frames.csv`` index (:mod:`fgnav.simulate.images`, :data:`REQUIRED_COLUMNS`) of
16-bit single-channel images with, per frame, the camera intrinsics, the field-stop radius
and ``q_body_from_cam`` (sensor calibration). The ``truth_*`` columns are never read here.

Per epoch:

1. star frame -> :func:`fgnav.vision.stars.detect_stars` -> lost-in-space identification
   (:func:`fgnav.vision.star_id.solve_lost_in_space`, BSC5 at the frame's epoch) ->
   ``R_eci_from_cam`` and its covariance ``P_cam`` (right perturbation, camera frame, rad^2);
   ``R_eci_from_body = R_eci_from_cam R_body_from_cam^T`` and, as
   ``R_eci_from_cam Exp(th) R_cam_from_body = R_eci_from_body Exp(R_body_from_cam th)``,
   ``P_att = R_body_from_cam P_cam R_body_from_cam^T`` (body frame).
2. limb frame(s) -> :func:`fgnav.vision.limb.extract_limb_points` (field-stop mask) ->
   RANSAC -> :func:`fgnav.vision.horizon.estimate_horizon` (``ellipse`` or
   ``christian-robinson``) -> ``u_cam``, ``rho`` and their joint covariance; rotated to
   the body frame. Edge-curvature correction: a gradient-centroid edge locator on a
   blurred disk of radius ``R_px`` finds the edge inside the true limb by
   ``(s_psf^2 + s_loc^2) / (2 R_px)`` px (the blurred edge of a curved boundary moves towards
   its centre of curvature; ``s_loc^2`` = :data:`fgnav.vision.limb.EDGE_LOCATOR_VAR_PX2`);
   with the calibrated ``psf_sigma_px`` of the frame, the points are moved outward by that
   amount (``R_px = f_px tan(rho)`` from a first fit) and refitted
   (``estimate_horizon(..., psf_sigma_px=...)``,
   :func:`fgnav.vision.horizon.correct_edge_curvature`). Measured on noise-free Wu et al. renders at
   GEO (R_px = 250): bias -0.0040 px (PSF 1 px) vs -0.0038 predicted; without it the
   Christian-Robinson limb radius of a GEO pass is biased by ~1.9 of its per-frame sigma (range +0.7
   km). Applied to ``christian-robinson`` only: the ``ellipse`` method's algebraic conic fit has an
   outward bias of about the same size (measured on the same pass: mean rho error -0.06 sigma
   without the correction, +0.89 with it). Several limb frames at one epoch are fused by information
   weighting of ``(B u, rho)`` on the tangent plane of the first one.
3. rows (``rows="eci"``, default): ``earth_direction`` ``u_eci = R_eci_from_body u_body``
   with covariance ``R ([u]x P_att [u]x^T + C_u) R^T`` (``R Exp(phi) u = R (u - [u]x phi)``;
   cf. :mod:`fgnav.sun_earth_moon`); the log carries one isotropic sigma per direction row: the
   square root of the largest eigenvalue of its 2x2 tangent-plane covariance (conservative).
   ``limb_radius`` ``(rho, R_limb)`` with ``sigma_rho`` (attitude-free). With
   ``rows="body"``: ``earth_direction_body`` (largest eigenvalue of ``C_u``) and
   ``attitude`` rows (rotation vector of ``R_eci_from_body``; ``P_att`` in full in the
   columns ``att_c11`` .. ``att_c33``, sigma = its largest per-axis sigma for readers that
   take one) instead of the ECI direction.
   With ``rows="raw-stars"`` (tight coupling): every identified star of the star frame
   becomes a ``star_direction_body`` row (x, y, z = its measured direction, body frame;
   star_x, star_y, star_z = its catalogue unit vector; sigma = the centroid 1-sigma scaled
   by the frame fit's a-posteriori variance factor, :func:`star_sigma_px`, mapped to
   angles, :func:`pixel_sigma_to_angle_rad`) instead of one solved attitude, and the
   limb gives ``earth_direction_body`` rows, also at epochs whose star field failed (the
   graph's attitude random walk carries the attitude there).
   ``edge_floor_px`` adds ``(edge_floor_px / f_px)^2`` to the direction and rho variances: a
   floor for the limb edge locator's systematic error (a few 1e-3 px, inward, growing with
   the PSF width -- the per-frame covariance of the horizon fit does not contain it).
   The (u, rho) correlation of a fix is dropped (the log has independent rows); for a full
   limb circle it is ~0 by symmetry.
4. priors: the ``prior_position`` / ``prior_velocity`` rows of a measurement log (by
   default ``measurements.csv`` beside ``frames.csv``) are copied unchanged.

Epochs whose star field fails identification keep their ``limb_radius`` row only (ECI
rows) and are counted in ``failures``; limb frames whose extraction fails are counted too.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from factors.aberration import earth_velocity_bcrs_mps
from factors.geometry import skew, so3_log, tangent_basis
from fgnav.errors import InputFormatError, UserError
from fgnav.io.log_csv import log_from_arrays, read_log
from fgnav.io.text import read_utf8_text
from fgnav.io.log_csv import ATT_COV_COLUMNS, STAR_COLUMNS
from fgnav.models.registry import (ATTITUDE, EARTH_DIRECTION, EARTH_DIRECTION_BODY, LIMB_RADIUS,
                                   PRIOR_POSITION, PRIOR_VELOCITY, STAR_DIRECTION_BODY,
                                   prior_kinds)
from fgnav.orbit import integrate_truth
from fgnav.progress import progress
from fgnav.time import format_utc, j2000_seconds, parse_utc, seconds_since
from fgnav.vision.attitude import matrix_from_quat
from fgnav.vision.camera import PinholeCamera
from fgnav.vision.catalogue import decimal_year
from fgnav.vision.horizon import METHODS, estimate_horizon
from fgnav.vision.limb import extract_limb_points, ransac_limb
from fgnav.vision.star_id import solve_lost_in_space
from fgnav.vision.stars import detect_stars

__all__ = ["REQUIRED_COLUMNS", "FrameEntry", "EpochProducts", "ExtractionResult",
           "find_frames_index", "read_frames_index", "log_from_products", "StarFrameRows", "star_rows_from_frame",
           "pixel_sigma_to_angle_rad", "star_sigma_px", "attitude_from_star_frame",
           "horizon_from_limb_frame", "fuse_horizons", "earth_direction_eci", "extract_frames"]

REQUIRED_COLUMNS = ("epoch", "file", "camera", "focal_mm", "pixel_um", "width_px", "height_px",
                    "cx_px", "cy_px", "field_radius_px", "q_body_from_cam_w", "q_body_from_cam_x",
                    "q_body_from_cam_y", "q_body_from_cam_z", "r_limb_m")
ROW_MODES = ("eci", "body", "raw-stars")


@dataclass
class FrameEntry:
    """One frame of the index: epoch (datetime64[ns] UTC), absolute image path, camera
    name (``star`` or ``limb*``), intrinsics, field-stop radius (px or None),
    R_body_from_cam, limb sphere radius (m, limb frames), source line."""

    epoch: np.datetime64
    path: Path
    camera_name: str
    camera: object
    field_radius_px: float | None
    R_body_from_cam: np.ndarray
    r_limb_m: float | None
    line: int
    psf_sigma_px: float | None = None

    @property
    def is_star(self) -> bool:
        return self.camera_name.startswith("star")


@dataclass
class EpochProducts:
    """Per-epoch front-end products (SI; body frame = sensor body frame).

    R_eci_from_body / P_att_rad2 (None without a star solution); u_body, C_u_body_rad2
    (3x3, rank 2), rho_rad, sigma_rho_rad (None without a limb fix); u_eci, C_eci_rad2
    (2x2 on tangent_basis(u_eci)), sigma_dir_rad (isotropic, row sigma); star/limb details;
    stars: the identified stars of the star frame (:class:`StarFrameRows`).
    """

    epoch: np.datetime64
    R_eci_from_body: np.ndarray | None = None
    P_att_rad2: np.ndarray | None = None
    stars_matched: int = 0
    u_body: np.ndarray | None = None
    C_u_body_rad2: np.ndarray | None = None
    rho_rad: float | None = None
    sigma_rho_rad: float | None = None
    r_limb_m: float | None = None
    limb_points: int = 0
    u_eci: np.ndarray | None = None
    C_eci_rad2: np.ndarray | None = None
    sigma_dir_rad: float | None = None
    stars: "StarFrameRows | None" = None


@dataclass
class ExtractionResult:
    """The log, the per-epoch products, failures counted per reason, the frame count and
    the copied prior rows (``(log, row indices)`` or None)."""

    log: object
    epochs: list[EpochProducts]
    failures: dict = field(default_factory=dict)
    n_frames: int = 0
    priors: tuple | None = None

    def log_as(self, rows: str):
        """The same products as a log in another row mode (:func:`log_from_products`)."""
        return log_from_products(self.epochs, rows, self.priors, str(self.log.path))

    def summary(self) -> dict:
        d = [e.sigma_dir_rad for e in self.epochs if e.sigma_dir_rad is not None]
        r = [e.sigma_rho_rad for e in self.epochs if e.sigma_rho_rad is not None]
        return {"frames": self.n_frames, "epochs": len(self.epochs), "rows": self.log.counts(),
                "failures": dict(self.failures),
                "median_sigma_direction_deg": float(np.degrees(np.median(d))) if d else None,
                "median_sigma_rho_deg": float(np.degrees(np.median(r))) if r else None}


# ----------------------------------------------------------------------------- index
def find_frames_index(path) -> Path:
    """``frames.csv`` from a path: the file itself, ``DIR/frames.csv``, or, for the
    ``frames/`` image directory, ``DIR/../frames.csv``."""
    p = Path(path)
    if p.is_file():
        return p
    if p.is_dir():
        for cand in (p / "frames.csv", p.parent / "frames.csv"):
            if cand.is_file():
                return cand
        raise UserError(f"{p}: no frames.csv in this directory or its parent "
                        "(write one with `fgnav simulate SCENARIO --out DIR --images`)")
    raise UserError(f"{p}: no such file or directory")


def _num(path, lineno, col, text, *, optional=False, positive=False):
    t = text.strip()
    if t == "":
        if optional:
            return None
        raise InputFormatError(path, lineno, col, "a number", text)
    try:
        v = float(t)
    except ValueError:
        raise InputFormatError(path, lineno, col, "a number", text) from None
    if not math.isfinite(v) or (positive and not v > 0):
        raise InputFormatError(path, lineno, col, "a finite number" + (" > 0" if positive else ""), text)
    return v


def read_frames_index(path) -> list[FrameEntry]:
    """Parse and validate ``frames.csv`` (comment lines ``#``; image paths relative to it)."""
    path = find_frames_index(path)
    base = path.parent
    entries: list[FrameEntry] = []

    text = read_utf8_text(path, "a frames.csv index")  # BOM ignored; not UTF-8: line and byte
    lines = [(i + 1, ln) for i, ln in enumerate(text.splitlines())
             if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise InputFormatError(path, 1, None, "a header line " + ",".join(REQUIRED_COLUMNS[:4]) + ",...",
                               "an empty file")
    hline, htext = lines[0]
    header = [h.strip() for h in next(csv.reader([htext]))]
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    if missing:
        raise InputFormatError(path, hline, missing[0], "the frames.csv columns " + ",".join(REQUIRED_COLUMNS),
                               htext[:80])
    col = {c: header.index(c) for c in header}
    for lineno, text in lines[1:]:
        f = next(csv.reader([text]))
        if len(f) != len(header):
            raise InputFormatError(path, lineno, None, f"{len(header)} comma-separated fields",
                                   f"{len(f)} fields")

        def g(c):
            return f[col[c]]

        try:
            epoch = parse_utc(g("epoch").strip())
        except ValueError:
            raise InputFormatError(path, lineno, "epoch", "an ISO-8601 UTC epoch ending in Z",
                                   g("epoch")) from None
        name = g("camera").strip()
        if not (name.startswith("star") or name.startswith("limb")):
            raise InputFormatError(path, lineno, "camera", "a camera name starting with 'star' or 'limb'", name)
        rel = g("file").strip()
        if not rel:
            raise InputFormatError(path, lineno, "file", "an image file name", rel)
        w = _num(path, lineno, "width_px", g("width_px"), positive=True)
        h = _num(path, lineno, "height_px", g("height_px"), positive=True)
        if w != int(w) or h != int(h):
            raise InputFormatError(path, lineno, "width_px", "integer image sizes", f"{w} x {h}")
        cam = PinholeCamera(focal_mm=_num(path, lineno, "focal_mm", g("focal_mm"), positive=True),
                            pixel_um=_num(path, lineno, "pixel_um", g("pixel_um"), positive=True),
                            width_px=int(w), height_px=int(h),
                            cx_px=_num(path, lineno, "cx_px", g("cx_px"), optional=True),
                            cy_px=_num(path, lineno, "cy_px", g("cy_px"), optional=True))
        q = np.array([_num(path, lineno, c, g(c)) for c in
                      ("q_body_from_cam_w", "q_body_from_cam_x", "q_body_from_cam_y", "q_body_from_cam_z")])
        if abs(np.linalg.norm(q) - 1.0) > 1e-6:
            raise InputFormatError(path, lineno, "q_body_from_cam_w", "a unit quaternion (w, x, y, z)",
                                   f"norm {np.linalg.norm(q):.9g}")
        r_limb = _num(path, lineno, "r_limb_m", g("r_limb_m"), optional=True, positive=True)
        if name.startswith("limb") and r_limb is None:
            raise InputFormatError(path, lineno, "r_limb_m", "the limb sphere radius (m) for a limb frame", "")
        entries.append(FrameEntry(epoch, base / rel, name, cam,
                                  _num(path, lineno, "field_radius_px", g("field_radius_px"),
                                       optional=True, positive=True),
                                  matrix_from_quat(q), r_limb, lineno,
                                  _num(path, lineno, "psf_sigma_px", g("psf_sigma_px"), optional=True)
                                  if "psf_sigma_px" in col else None))
    if not entries:
        raise InputFormatError(path, hline + 1, None, "at least one frame row", "header only")
    return entries


def _load_image(e: FrameEntry) -> np.ndarray:
    import cv2

    if not e.path.is_file():
        raise UserError(f"{e.path}: image listed in frames.csv (line {e.line}) does not exist")
    img = cv2.imread(str(e.path), cv2.IMREAD_UNCHANGED)
    if img is None or img.ndim != 2:
        raise UserError(f"{e.path}: not a single-channel image OpenCV can read")
    if img.shape != (e.camera.height_px, e.camera.width_px):
        raise UserError(f"{e.path}: image is {img.shape[1]}x{img.shape[0]} px, frames.csv line "
                        f"{e.line} says {e.camera.width_px}x{e.camera.height_px}")
    return img


# ------------------------------------------------------------------------ front ends
@dataclass
class StarFrameRows:
    """The identified stars of one star frame, as ``star_direction_body`` rows.

    u_body (m, 3): measured unit directions, body frame; s_eci (m, 3): their catalogue unit
    vectors (EME2000, catalogue place with proper motion to the frame's epoch); sigma_rad
    (m,): 1-sigma per tangent axis (rad); uv_px (m, 2): the centroids; R_eci_from_body,
    P_att_rad2: the frame's own attitude solution (lost-in-space refinement) and its
    covariance (body frame, right perturbation, rad^2).
    """

    u_body: np.ndarray
    s_eci: np.ndarray
    sigma_rad: np.ndarray
    uv_px: np.ndarray
    R_eci_from_body: np.ndarray
    P_att_rad2: np.ndarray

    @property
    def matched(self) -> int:
        return len(self.sigma_rad)


def pixel_sigma_to_angle_rad(camera: PinholeCamera, uv_px: np.ndarray, sigma_px) -> np.ndarray:
    """Isotropic centroid 1-sigma (px) -> 1-sigma per tangent axis of the ray (rad).

    The ray ``s(u, v) = camera.pixel_to_ray`` maps the centroid covariance ``sigma_px^2 I``
    to ``sigma_px^2 J J^T`` on the tangent plane (``J`` = 2x2 Jacobian of the tangent-plane
    coordinates of ``s`` with respect to (u, v), central differences of 0.5 px); the row
    carries the square root of its largest eigenvalue (for a pinhole: ``sigma_px cos(a) /
    f_px`` across and ``sigma_px cos^2(a) / f_px`` along the radial direction at an angle
    ``a`` off the boresight), so it never claims more than the centroid gives.
    """
    uv = np.asarray(uv_px, float).reshape(-1, 2)
    s0 = camera.pixel_to_ray(uv)
    B = tangent_basis(s0)                                           # (m, 2, 3)
    J = np.empty((len(uv), 2, 2))
    for k in range(2):
        d = np.zeros(2)
        d[k] = 0.5
        ds = camera.pixel_to_ray(uv + d) - camera.pixel_to_ray(uv - d)
        J[:, :, k] = np.einsum("nij,nj->ni", B, ds)
    lam = np.linalg.eigvalsh(J @ np.swapaxes(J, 1, 2))[:, -1]
    return np.broadcast_to(np.asarray(sigma_px, float), (len(uv),)) * np.sqrt(lam)


def star_sigma_px(sol, sigma_px: np.ndarray) -> np.ndarray:
    """Centroid 1-sigma (px) of the identified stars of a frame, scaled by the a-posteriori
    variance factor of the frame's own attitude fit (Mikhail & Ackermann 1976, "Observations
    and least squares", ch. 4): ``s0^2 = sum |r_i|^2 / sigma_i^2 / (2 m - p)`` over its m
    stars' pixel residuals ``r_i``, ``p`` = 4 fitted parameters (attitude, focal length; 5
    with k1). The detector's per-star sigma (background MAD, clipped weights, a 0.02 px
    floor) is a relative weight, not a calibrated noise: on simulated GEO frames its
    squared normalized errors average 0.4 per axis; the residuals of the frame calibrate it,
    exactly as the solved attitude's covariance (the loose route) already is."""
    sig = np.asarray(sigma_px, float)
    r = np.asarray(sol.residuals_px, float)
    p = 4 + (sol.camera.k1 != 0.0)
    dof = 2 * len(sig) - p
    if dof < 1:
        return sig
    return sig * math.sqrt(float(np.sum(r * r / sig[:, None] ** 2)) / dof)


def star_rows_from_frame(img: np.ndarray, e: FrameEntry, epoch_year: float,
                         v_observer_bcrs_mps=None) -> StarFrameRows:
    """Detect, identify (lost in space) and convert the stars of one star frame
    (:class:`StarFrameRows`). The measured directions use the camera the identification
    fitted (focal length refined on the frame's own stars); the per-star sigma is the
    detector's centroid 1-sigma scaled by the fit's a-posteriori variance factor
    (:func:`star_sigma_px`) and mapped to angles (:func:`pixel_sigma_to_angle_rad`).
    ``v_observer_bcrs_mps`` (3,) m/s: the camera's barycentric velocity, for the stars'
    apparent directions (:func:`fgnav.vision.star_id.solve_lost_in_space`)."""
    det = detect_stars(img)
    sol = solve_lost_in_space(det.uv_px, e.camera, sigma_px=det.sigma_px, epoch_year=epoch_year,
                              v_observer_bcrs_mps=v_observer_bcrs_mps)
    Rbc = e.R_body_from_cam
    uv = det.uv_px[sol.det_index]
    u_body = sol.camera.pixel_to_ray(uv) @ Rbc.T
    sig = pixel_sigma_to_angle_rad(sol.camera, uv, star_sigma_px(sol, det.sigma_px[sol.det_index]))
    return StarFrameRows(u_body, np.asarray(sol.cat_u_eci, float), sig, uv,
                         sol.R_eci_from_camera @ Rbc.T, Rbc @ sol.cov_theta_rad2 @ Rbc.T)


def attitude_from_star_frame(img: np.ndarray, e: FrameEntry, epoch_year: float,
                             v_observer_bcrs_mps=None):
    """(R_eci_from_body, P_att_rad2 (body frame, right perturbation), matched stars)
    (:func:`star_rows_from_frame`)."""
    st = star_rows_from_frame(img, e, epoch_year, v_observer_bcrs_mps)
    return st.R_eci_from_body, st.P_att_rad2, st.matched


def horizon_from_limb_frame(img: np.ndarray, e: FrameEntry, method: str, seed,
                            curvature_correction: bool = True):
    """Horizon fix of one limb frame (camera frame), field stop applied as a mask; ``seed``
    (int or sequence) seeds the RANSAC generator."""
    cam = e.camera
    mask = None
    if e.field_radius_px is not None:
        vv, uu = np.mgrid[0:cam.height_px, 0:cam.width_px]
        mask = np.hypot(uu - cam.cx, vv - cam.cy) <= e.field_radius_px
    pts = ransac_limb(extract_limb_points(img, valid_mask=mask), cam, rng=np.random.default_rng(seed))
    # edge-curvature correction (module doc, step 2): christian-robinson only, done by the
    # front end (fgnav.vision.horizon.correct_edge_curvature)
    psf = e.psf_sigma_px if curvature_correction else None
    return estimate_horizon(pts, cam, method, e.r_limb_m, psf_sigma_px=psf)


def fuse_horizons(fixes_body: list[tuple[np.ndarray, np.ndarray, float]]):
    """Fuse horizon fixes given as (u_body (3,), cov_u_rho_body (4x4), rho) by information
    weighting of ``(B u, rho)``, ``B = tangent_basis(u_first)``. Returns (u, C_u (3x3), rho,
    sigma_rho)."""
    u0 = fixes_body[0][0]
    B = tangent_basis(u0)
    T = np.zeros((3, 4))
    T[:2, :3] = B
    T[2, 3] = 1.0
    Lam = np.zeros((3, 3))
    eta = np.zeros(3)
    for u, C4, rho in fixes_body:
        L = np.linalg.inv(T @ C4 @ T.T)
        Lam += L
        eta += L @ np.array([*(B @ u), rho])
    P = np.linalg.inv(Lam)
    x = P @ eta
    u = u0 + B.T @ x[:2]
    u /= np.linalg.norm(u)
    return u, B.T @ P[:2, :2] @ B, float(x[2]), float(math.sqrt(P[2, 2]))


def earth_direction_eci(R_eci_from_body, P_att_rad2, u_body, C_u_body_rad2):
    """ECI Earth direction and its 2x2 tangent-plane covariance (module doc, step 3):
    ``C = R ([u]x P_att [u]x^T + C_u) R^T`` projected on ``tangent_basis(u_eci)``."""
    K = skew(u_body)
    u = R_eci_from_body @ u_body
    C3 = R_eci_from_body @ (K @ P_att_rad2 @ K.T + C_u_body_rad2) @ R_eci_from_body.T
    B = tangent_basis(u)
    return u, B @ C3 @ B.T


# ------------------------------------------------------------------------------ pass
def _priors_log(priors_path, index_path: Path):
    p = Path(priors_path) if priors_path is not None else index_path.parent / "measurements.csv"
    if not p.is_file():
        if priors_path is None:
            return None
        raise UserError(f"{p}: no such priors log")
    log = read_log(p)
    idx = np.concatenate([log.select(kind) for kind in prior_kinds()])
    if priors_path is not None and not len(idx):
        raise UserError(f"{p}: no {' / '.join(prior_kinds())} rows")
    return log, np.sort(idx)


def _prior_velocities(pri, epochs) -> np.ndarray | None:
    """The spacecraft's best known velocity (N, 3) m/s ECI at the datetime64 ``epochs``: the
    priors log's first ``prior_position`` + ``prior_velocity`` pair propagated (two-body + J2,
    ``fgnav.orbit.integrate_truth``: a prior good to km and m/s gives the velocity to ~m/s,
    the aberration to ~1 mas); None without such a pair."""
    if pri is None:
        return None
    plog, idx = pri
    kinds = np.asarray(plog.kind).astype(str)[idx]
    pos = idx[kinds == PRIOR_POSITION.kind]
    vel = {float(plog.t_s[i]): i for i in idx[kinds == PRIOR_VELOCITY.kind]}
    for i in pos:
        j = vel.get(float(plog.t_s[i]))
        if j is None:
            continue
        t0 = plog.epoch0 + np.timedelta64(int(round(plog.t_s[i] * 1e9)), "ns")
        x0 = np.concatenate([plog.xyz[i], plog.xyz[j]]).astype(float)
        dt = np.asarray(seconds_since(np.asarray(epochs), t0), float)
        return integrate_truth(x0, dt, t0_j2000_s=float(j2000_seconds(t0)))[:, 3:]
    return None


class _NoRows(UserError):
    """No row at all (the caller says why)."""


def log_from_products(products: list[EpochProducts], rows: str = "eci", priors=None,
                      path: str = "<extracted>"):
    """The measurement log of per-epoch front-end products in one row mode (module doc,
    step 3; ``rows`` one of :data:`ROW_MODES`): one extraction gives the loosely and the
    tightly coupled logs alike. ``priors``: ``(log, row indices)`` of prior rows to copy."""
    if rows not in ROW_MODES:
        raise UserError(f"rows must be one of {ROW_MODES}, got {rows!r}")
    pri = priors
    epoch0 = min(p.epoch for p in products)
    nan = np.nan
    kinds, ts, xyz, sig, star, att_cov = [], [], [], [], [], []

    def add(kind, t64, v, s, s_eci=(nan, nan, nan), cov=(nan,) * len(ATT_COV_COLUMNS)):
        kinds.append(kind)
        ts.append(float(seconds_since(t64, epoch0)))
        xyz.append(np.asarray(v, float))
        sig.append(float(s))
        star.append(s_eci)
        att_cov.append(cov)

    if pri is not None:
        plog, idx = pri
        epoch0 = min(epoch0, plog.epoch0 + np.timedelta64(int(round(plog.t_s[idx].min() * 1e9)), "ns")) \
            if len(idx) else epoch0
        for i in idx:
            add(str(plog.kind[i]), plog.epoch0 + np.timedelta64(int(round(plog.t_s[i] * 1e9)), "ns"),
                plog.xyz[i], plog.sigma[i])
    for ep in products:
        if rows == "eci" and ep.u_eci is not None:
            add(EARTH_DIRECTION.kind, ep.epoch, ep.u_eci, ep.sigma_dir_rad)
        if rows != "eci" and ep.u_body is not None and (rows == "raw-stars" or ep.R_eci_from_body is not None):
            w = np.linalg.eigvalsh(tangent_basis(ep.u_body) @ ep.C_u_body_rad2 @ tangent_basis(ep.u_body).T)
            add(EARTH_DIRECTION_BODY.kind, ep.epoch, ep.u_body, math.sqrt(w[-1]))
        if rows == "body" and ep.u_body is not None and ep.R_eci_from_body is not None:
            P = 0.5 * (ep.P_att_rad2 + ep.P_att_rad2.T)  # its full covariance (att_c11..33)
            add(ATTITUDE.kind, ep.epoch, so3_log(ep.R_eci_from_body),
                math.sqrt(np.max(np.diag(P))), cov=tuple(P[np.triu_indices(3)]))
        if rows == "raw-stars" and ep.stars is not None:
            for u, s_eci, sg in zip(ep.stars.u_body, ep.stars.s_eci, ep.stars.sigma_rad):
                add(STAR_DIRECTION_BODY.kind, ep.epoch, u, sg, tuple(s_eci))
        if ep.rho_rad is not None:
            add(LIMB_RADIUS.kind, ep.epoch, [ep.rho_rad, ep.r_limb_m, nan], ep.sigma_rho_rad)
    if not kinds:
        raise _NoRows(f"{path}: no measurement rows")
    extra = None
    if rows == "raw-stars":
        st = np.array(star, float).reshape(-1, 3)
        extra = {c: st[:, k] for k, c in enumerate(STAR_COLUMNS)}
    if rows == "body":
        ac = np.array(att_cov, float).reshape(-1, len(ATT_COV_COLUMNS))
        extra = {c: ac[:, k] for k, c in enumerate(ATT_COV_COLUMNS)}
    log = log_from_arrays(epoch0, np.array(ts), np.array(kinds, dtype=object), np.array(xyz),
                          np.array(sig), extra, path=path)
    return log


def extract_frames(frames_path, *, method: str = "christian-robinson", rows: str = "eci",
                   priors=None, seed: int = 0, edge_floor_px: float = 0.0,
                   curvature_correction: bool = True, quiet: bool = True) -> ExtractionResult:
    """Run the front end over every frame of a ``frames.csv`` index (module doc).

    method : horizon estimator (``ellipse`` | ``christian-robinson``); rows : ``eci`` |
    ``body`` | ``raw-stars`` (module doc, step 3); priors : measurement log to copy the prior rows from (default
    ``measurements.csv`` beside ``frames.csv``, if present); seed : RANSAC seed (limb frame j
    of epoch k uses ``default_rng([seed, k, j])``); edge_floor_px : limb-edge systematic floor (px);
    curvature_correction : apply the edge-curvature correction (module doc, step 2).
    """
    if method not in METHODS:
        raise UserError(f"unknown horizon method {method!r}; expected one of {', '.join(METHODS)}")
    if rows not in ROW_MODES:
        raise UserError(f"rows must be one of {ROW_MODES}, got {rows!r}")
    if not edge_floor_px >= 0:
        raise UserError(f"edge_floor_px must be >= 0 px, got {edge_floor_px}")
    index_path = find_frames_index(frames_path)
    entries = read_frames_index(index_path)
    pri = _priors_log(priors, index_path)
    by_epoch: dict[int, list[FrameEntry]] = {}
    for e in entries:
        by_epoch.setdefault(int(np.datetime64(e.epoch, "ns").astype(np.int64)), []).append(e)
    epoch_year = decimal_year(format_utc(entries[0].epoch))
    # the camera's barycentric velocity for the stars' apparent directions (aberration):
    # the Earth's at each epoch plus the spacecraft's where the priors give an orbit
    ns_all = sorted(by_epoch)
    v_obs = earth_velocity_bcrs_mps(np.array([float(j2000_seconds(np.datetime64(n, "ns")))
                                              for n in ns_all]))
    v_sc = _prior_velocities(pri, np.array(ns_all, dtype="datetime64[ns]"))
    if v_sc is not None:
        v_obs = v_obs + v_sc
    failures: dict[str, int] = {}
    products: list[EpochProducts] = []

    def fail(reason):
        failures[reason] = failures.get(reason, 0) + 1

    for k, ns in enumerate(progress(sorted(by_epoch), desc="extracting", unit="epoch", quiet=quiet)):
        ep = EpochProducts(np.datetime64(ns, "ns"))
        stars = [e for e in by_epoch[ns] if e.is_star]
        limbs = [e for e in by_epoch[ns] if not e.is_star]
        if stars:
            img = _load_image(stars[0])
            try:
                ep.stars = star_rows_from_frame(img, stars[0], epoch_year, v_obs[k])
                ep.R_eci_from_body, ep.P_att_rad2 = ep.stars.R_eci_from_body, ep.stars.P_att_rad2
                ep.stars_matched = ep.stars.matched
            except UserError:
                fail("star_identification")
        fixes = []
        for j, e in enumerate(limbs):
            img = _load_image(e)
            try:
                fix = horizon_from_limb_frame(img, e, method, [seed, k, j], curvature_correction)
            except UserError:
                fail("limb_extraction")
                continue
            R = e.R_body_from_cam
            T = np.zeros((4, 4))
            T[:3, :3] = R
            T[3, 3] = 1.0
            f_floor = (edge_floor_px / e.camera.f_px) ** 2
            C4 = T @ fix.cov_u_rho @ T.T
            u_b = R @ fix.u_cam
            C4[:3, :3] += f_floor * (np.eye(3) - np.outer(u_b, u_b))
            C4[3, 3] += f_floor
            fixes.append((u_b, C4, fix.rho_rad, fix.n_points, e.r_limb_m))
        if fixes:
            if len({f[4] for f in fixes}) > 1:
                raise UserError(f"limb frames at {format_utc(ep.epoch)} disagree on r_limb_m")
            ep.u_body, ep.C_u_body_rad2, ep.rho_rad, ep.sigma_rho_rad = fuse_horizons(
                [(f[0], f[1], f[2]) for f in fixes])
            ep.r_limb_m = fixes[0][4]
            ep.limb_points = sum(f[3] for f in fixes)
        if ep.u_body is not None and ep.R_eci_from_body is not None:
            ep.u_eci, ep.C_eci_rad2 = earth_direction_eci(ep.R_eci_from_body, ep.P_att_rad2,
                                                          ep.u_body, ep.C_u_body_rad2)
            ep.sigma_dir_rad = float(math.sqrt(np.linalg.eigvalsh(ep.C_eci_rad2)[-1]))
        elif ep.u_body is not None and rows != "raw-stars":
            fail("direction_without_attitude")
        products.append(ep)

    try:
        log = log_from_products(products, rows, pri, str(index_path))
    except _NoRows:
        raise UserError(f"{index_path}: no measurement could be extracted from {len(entries)} frames "
                        f"(failures: {failures})") from None
    return ExtractionResult(log, products, failures, len(entries), pri)
