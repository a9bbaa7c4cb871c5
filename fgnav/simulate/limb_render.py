"""Earth-limb image renderer (UV limb seen through a pinhole camera), Wu et al. sensor.

Geometry. The limb surface is a sphere of radius ``r_limb_m`` (Wu et al.: 6,375 km) or the
WGS-84 ellipsoid grown by ``limb_height_m`` (polar axis along ECI z). For every pixel ray
``s`` (camera frame, OpenCV: x right, y down, z boresight) the *tangent height* ``h`` is the
height above the limb surface of the ray's closest approach: for the sphere
``h = |c x s| - R`` (``c`` = camera->Earth-centre vector, ``s.c > 0``); for the ellipsoid
the same quantity is taken in the space where the ellipsoid is the unit sphere
(``x' = U x``, ``A = U^T U`` the shape matrix in the camera frame) and scaled back by the
local radius. ``h < 0`` means the ray meets the limb layer (the disk).

Radiance (UV 270-300 nm, Wu et al. sec. 3.1): uniform disk ``S`` (electrons per pixel per
frame) and an exponential fall-off above it with scale height ``H`` (a few km),
``L(h) = S`` for ``h <= -H`` and ``S exp(-(h + H)/H)`` above: the profile is placed so that
the radiance-gradient centroid, ``int h (-dL/dh) dh / S``, is exactly at ``h = 0`` -- the
limb surface is where a gradient-centroid edge detector should find the edge.

Image formation: analytic radiance at ``supersample^2`` sub-pixel samples in the edge band
(area anti-aliasing; default 8 x 8: the fall-off scale height is ~0.25 px at GEO, so a
4 x 4 grid of point samples does not integrate a pixel's area -- with the Earth centred on a
pixel, as in the Earth-pointing image plan, its aliasing adds up around the limb and moved
the noise-free Christian-Robinson limb radius by -4.5e-4 px, against -1.9e-4 px at 8 x 8
and -1.7e-4 px at 16 x 16, while the frame's 1-sigma is 2.3e-3 px: a bias that does not
average out over a pass, since every frame repeats the geometry), Gaussian PSF
(``psf_sigma_px``), field stop / arc mask, then shot (Poisson) + read (Gaussian) noise, ADC
gain and bias, 16-bit. Deterministic by seed.

Wu et al. detector (GSENSE400BSI-UV, sec. 3.2): 90 ke- peak signal, dynamic range > 96 dB,
so the read noise is ``90,000 / 10^(96/20) = 1.43 e-``; 16-bit ADC spanning the full well.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from factors.constants import R_EARTH_M, R_LIMB_UV_M
from fgnav.errors import UserError
from fgnav.vision.camera import PinholeCamera

__all__ = [
    "DetectorModel", "LimbRadiance", "LimbScene", "RenderedLimb", "CONFOCAL_DETECTOR",
    "render_limb_ideal", "add_detector_noise", "render_limb", "scene_from_altitude",
    "WGS84_F",
]

WGS84_F = 1.0 / 298.257223563
"""WGS-84 flattening."""


@dataclass(frozen=True)
class DetectorModel:
    """Detector and optics noise model.

    full_well_e : saturation (e-); read_noise_e : read noise (e-, 1 sigma);
    gain_e_per_dn : ADC gain (e-/DN); bias_dn : offset (DN); psf_sigma_px : Gaussian PSF
    sigma (pixels); dark_e : sky background + dark signal (e- per pixel per frame).
    """

    full_well_e: float = 90_000.0
    read_noise_e: float = 90_000.0 / 10 ** (96.0 / 20.0)
    gain_e_per_dn: float = 90_000.0 / 65_535.0
    bias_dn: float = 100.0
    psf_sigma_px: float = 1.0
    dark_e: float = 0.0


CONFOCAL_DETECTOR = DetectorModel()
"""Wu et al., sec. 3.2: 90 ke- peak, > 96 dB dynamic range (read noise 1.43 e-), 16 bit."""


@dataclass(frozen=True)
class LimbRadiance:
    """Limb radiance profile: disk signal ``signal_e`` (e-/pixel/frame), scale height (m)."""

    signal_e: float = 2_000.0
    scale_height_m: float = 6.0e3


@dataclass(frozen=True)
class LimbScene:
    """Where the Earth is as seen from the camera.

    c_cam_m : vector camera -> Earth centre in the camera frame (m), shape (3,).
    R_cam_from_ecef : rotation taking Earth-fixed (polar axis = z) vectors to the camera
    frame; only used for the ellipsoid. r_limb_m : sphere radius (m) when
    ``ellipsoid=False``; limb_height_m : layer height above WGS-84 when ``ellipsoid=True``.
    """

    c_cam_m: np.ndarray
    r_limb_m: float = R_LIMB_UV_M
    ellipsoid: bool = False
    limb_height_m: float = 0.0
    R_cam_from_ecef: np.ndarray = field(default_factory=lambda: np.eye(3))

    @property
    def axes_m(self) -> np.ndarray:
        """Semi-axes (a, a, c) of the limb surface (m)."""
        if not self.ellipsoid:
            return np.full(3, float(self.r_limb_m))
        a = R_EARTH_M + self.limb_height_m
        c = R_EARTH_M * (1.0 - WGS84_F) + self.limb_height_m
        return np.array([a, a, c])

    def shape_factor(self) -> np.ndarray:
        """U with ``A_cam = U^T U`` (the limb surface is ``(x-c)^T A (x-c) = 1``), 3x3."""
        return np.diag(1.0 / self.axes_m) @ np.asarray(self.R_cam_from_ecef, float).T

    @property
    def u_cam(self) -> np.ndarray:
        """Unit vector camera -> Earth centre, camera frame."""
        c = np.asarray(self.c_cam_m, float)
        return c / np.linalg.norm(c)

    @property
    def rho_rad(self) -> float:
        """Apparent angular radius of the limb sphere (rad), ``asin(R/|c|)`` (sphere only)."""
        return float(np.arcsin(self.axes_m[0] / np.linalg.norm(self.c_cam_m)))


def scene_from_altitude(alt_m: float, u_cam, r_limb_m: float = R_LIMB_UV_M) -> LimbScene:
    """Sphere scene at altitude ``alt_m`` above the limb sphere, Earth centre along ``u_cam``."""
    u = np.asarray(u_cam, float)
    u = u / np.linalg.norm(u)
    return LimbScene(c_cam_m=u * (r_limb_m + alt_m), r_limb_m=r_limb_m)


@dataclass
class RenderedLimb:
    """A rendered frame and its truth.

    image_dn : uint16 (H, W) (``None`` for an ideal render); ideal_e : float32 noiseless
    signal (e-); valid_mask : bool (H, W), pixels inside the field stop / arc mask;
    centre_px : projected Earth centre (u, v); u_cam, rho_rad : truth; detector.
    """

    image_dn: np.ndarray | None
    ideal_e: np.ndarray
    valid_mask: np.ndarray
    scene: LimbScene
    camera: PinholeCamera
    detector: DetectorModel
    centre_px: np.ndarray

    @property
    def u_cam(self) -> np.ndarray:
        return self.scene.u_cam

    @property
    def rho_rad(self) -> float:
        return self.scene.rho_rad


@lru_cache(maxsize=4)
def _pixel_grid(camera: PinholeCamera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, v, rays) of every pixel centre of ``camera`` (float64 (H, W) each, rays (H, W, 3)
    unit vectors): the same for every frame of a camera, so computed once (read-only)."""
    vv, uu = np.mgrid[0:camera.height_px, 0:camera.width_px].astype(np.float64)
    rays = camera.pixel_to_ray(np.stack([uu, vv], axis=-1))
    for a in (uu, vv, rays):
        a.setflags(write=False)
    return uu, vv, rays


def _tangent_height_m(rays: np.ndarray, scene: LimbScene) -> np.ndarray:
    """Tangent height (m) of unit rays (..., 3) over the limb surface (see module doc)."""
    c = np.asarray(scene.c_cam_m, float)
    if not scene.ellipsoid:
        # sphere: the scaled space is a uniform scaling, so the closest approach of a unit
        # ray is at t = s.c and the miss distance is sqrt(|c|^2 - t^2)
        R = float(scene.r_limb_m)
        t = rays @ c
        h = np.sqrt(np.maximum(c @ c - t * t, 0.0)) - R
        return np.where(t <= 0.0, np.linalg.norm(c) * 10.0, h)
    U = scene.shape_factor()
    cp = U @ c
    sp = rays @ U.T
    sp_n = np.linalg.norm(sp, axis=-1, keepdims=True)
    sp = sp / sp_n
    t = sp @ cp                                     # along-ray distance to closest approach
    d2 = np.maximum(cp @ cp - t * t, 0.0)
    d = np.sqrt(d2)                                 # scaled miss distance (1 = tangent)
    if not scene.ellipsoid:
        h = (d - 1.0) * scene.r_limb_m
    else:
        # local radius: the closest-approach point in scaled space, mapped back
        p_scaled = (t[..., None] * sp - cp) / np.maximum(d, 1e-12)[..., None]
        Uinv = np.linalg.inv(U)
        rloc = np.linalg.norm(p_scaled @ Uinv.T, axis=-1)
        h = (d - 1.0) * rloc
    behind = t <= 0.0                               # ray points away from the Earth
    return np.where(behind, np.linalg.norm(c) * 10.0, h)


def _radiance_e(h_m: np.ndarray, rad: LimbRadiance) -> np.ndarray:
    H = rad.scale_height_m
    x = np.maximum((h_m + H) / H, 0.0)
    return (rad.signal_e * np.exp(-np.minimum(x, 80.0))).astype(np.float32)


def _arc_mask(camera: PinholeCamera, centre_px: np.ndarray, arcs_deg) -> np.ndarray:
    """True where the position angle about ``centre_px`` lies in one of the arcs.

    Position angle: atan2(v - v_c, u - u_c) in degrees, image axes (u right, v down).
    """
    vv, uu = np.mgrid[0:camera.height_px, 0:camera.width_px]
    ang = np.degrees(np.arctan2(vv - centre_px[1], uu - centre_px[0])) % 360.0
    m = np.zeros(ang.shape, bool)
    for a0, a1 in arcs_deg:
        a0 %= 360.0
        span = (a1 - a0) % 360.0 if (a1 - a0) % 360.0 != 0 else 360.0
        m |= ((ang - a0) % 360.0) <= span
    return m


def render_limb_ideal(camera: PinholeCamera, scene: LimbScene, *,
                      radiance: LimbRadiance = LimbRadiance(),
                      detector: DetectorModel = CONFOCAL_DETECTOR,
                      arcs_deg=None, field_radius_px: float | None = None,
                      supersample: int = 8) -> RenderedLimb:
    """Noiseless limb image (e-, float32) with anti-aliasing, PSF and masks.

    arcs_deg : optional list of ``(start, end)`` position angles (deg, about the projected
    Earth centre, measured from +u towards +v) where the limb is visible; elsewhere the
    field is masked (dark). field_radius_px : optional circular field stop about the
    principal point (the image circle of Wu et al.'s sub-aperture). supersample : sub-samples per
    axis in the edge band.
    """
    import cv2

    if supersample < 1:
        raise UserError(f"supersample must be >= 1, got {supersample}")
    H_px, W_px = camera.height_px, camera.width_px
    uu, vv, rays = _pixel_grid(camera)
    h = _tangent_height_m(rays, scene)
    img = _radiance_e(h, radiance)
    if supersample > 1:
        # edge band: |h| within 2 pixels' worth of tangent-height change + 12 scale heights
        gy, gx = np.gradient(h)
        dh = np.hypot(gx, gy)
        band = np.abs(h) < 2.0 * dh + 12.0 * radiance.scale_height_m
        iv, iu = np.nonzero(band)
        if iv.size:
            off = (np.arange(supersample) + 0.5) / supersample - 0.5
            ou, ov = np.meshgrid(off, off)
            sub = np.stack([iu[:, None] + ou.ravel()[None, :], iv[:, None] + ov.ravel()[None, :]], -1)
            hs = _tangent_height_m(camera.pixel_to_ray(sub), scene)
            img[iv, iu] = _radiance_e(hs, radiance).mean(axis=1)
    if detector.psf_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), detector.psf_sigma_px, borderType=cv2.BORDER_REPLICATE)
    centre = camera.project(np.asarray(scene.c_cam_m, float))
    valid = np.ones((H_px, W_px), bool)
    if field_radius_px is not None:
        valid &= np.hypot(uu - camera.cx, vv - camera.cy) <= field_radius_px
    if arcs_deg is not None:
        valid &= _arc_mask(camera, centre, arcs_deg)
    img = np.where(valid, img, 0.0).astype(np.float32) + np.float32(detector.dark_e)
    return RenderedLimb(None, img, valid, scene, camera, detector, centre)


def add_detector_noise(ideal_e: np.ndarray, detector: DetectorModel,
                       rng: np.random.Generator) -> np.ndarray:
    """Shot (Poisson) + read (Gaussian) noise, gain, bias, saturation -> uint16 DN."""
    sig = np.minimum(ideal_e, detector.full_well_e)
    e = rng.poisson(sig).astype(np.float32)
    e += rng.standard_normal(ideal_e.shape, dtype=np.float32) * np.float32(detector.read_noise_e)
    e = np.minimum(e, detector.full_well_e)
    dn = np.rint(e / detector.gain_e_per_dn + detector.bias_dn)
    return np.clip(dn, 0, 65535).astype(np.uint16)


def render_limb(camera: PinholeCamera, scene: LimbScene, rng: np.random.Generator, **kw) -> RenderedLimb:
    """Render a noisy 16-bit frame (see :func:`render_limb_ideal` for the options)."""
    out = render_limb_ideal(camera, scene, **kw)
    out.image_dn = add_detector_noise(out.ideal_e, out.detector, rng)
    return out
