"""Star-field renderer for simulation: catalogue + camera + attitude -> 16-bit image + truth.

Signal model (electrons for one exposure): a star of magnitude V gives
``F = flux_v0_e * 10^(-0.4 V)`` electrons spread by a circular Gaussian PSF of 1-sigma
``psf_sigma_px``, integrated exactly over each pixel,
``F [Phi((u+1/2-u0)/s) - Phi((u-1/2-u0)/s)] [Phi((v+1/2-v0)/s) - Phi((v-1/2-v0)/s)]``;
plus a uniform sky background ``background_e`` per pixel. Noise: Poisson shot noise on the
total, Gaussian read noise ``read_noise_e``; then ``ADU = bias_adu + e / gain_e_per_adu``,
rounded and clipped to [0, 65535] (saturation). Star positions: ``camera.project`` of the
catalogue direction in the camera frame, ``v_cam = R_eci_from_camera^T u_eci``, or, with the
camera's barycentric velocity given, of the apparent direction (stellar aberration,
``factors.aberration``; Urban & Seidelmann 2013, eq. 7.40).
Deterministic for a given ``numpy.random.Generator`` state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr

from factors.aberration import apparent_direction
from fgnav.vision.camera import PinholeCamera
from fgnav.vision.catalogue import Catalogue

__all__ = ["StarFieldTruth", "render_star_field"]


@dataclass(frozen=True)
class StarFieldTruth:
    """Stars whose true centroid falls inside the image, sorted by magnitude.

    hr : (N,) catalogue HR numbers; uv_px : (N, 2) true PSF centres (pixels);
    vmag : (N,) magnitudes; flux_e : (N,) total electrons; u_eci : (N, 3) directions."""

    hr: np.ndarray
    uv_px: np.ndarray
    vmag: np.ndarray
    flux_e: np.ndarray
    u_eci: np.ndarray


def render_star_field(camera: PinholeCamera, R_eci_from_camera: np.ndarray, catalogue: Catalogue,
                      rng: np.random.Generator, *, flux_v0_e: float = 3.0e6,
                      psf_sigma_px: float = 1.0, background_e: float = 200.0,
                      read_noise_e: float = 10.0, gain_e_per_adu: float = 1.0,
                      bias_adu: float = 100.0, vmag_max: float | None = None,
                      v_observer_bcrs_mps=None) -> tuple[np.ndarray, StarFieldTruth]:
    """Render one frame (uint16, shape (height_px, width_px)) and its truth list.

    flux_v0_e : electrons from a V = 0 star in the exposure; psf_sigma_px : PSF 1-sigma (px);
    background_e, read_noise_e : per pixel (electrons); vmag_max : faintest star drawn;
    v_observer_bcrs_mps : (3,) m/s, optional: the camera's barycentric velocity (the stars
    drawn at their apparent directions; truth ``u_eci`` stays the catalogue's).
    """
    R = np.asarray(R_eci_from_camera, float)
    cat = catalogue if vmag_max is None else catalogue.brighter_than(vmag_max)
    W, H = camera.width_px, camera.height_px
    half = 0.5 * camera.fov_diag_rad + 0.02
    front = cat.u_eci @ R[:, 2] > np.cos(min(half, 1.5))
    u_seen = cat.u_eci[front]
    if v_observer_bcrs_mps is not None:
        u_seen, _ = apparent_direction(u_seen, np.broadcast_to(
            np.asarray(v_observer_bcrs_mps, float), u_seen.shape))
    v_cam = u_seen @ R
    uv = camera.project(v_cam)
    rad = int(np.ceil(4.0 * psf_sigma_px)) + 1
    near = np.all(np.isfinite(uv), axis=1) & camera.in_image(uv, margin_px=-rad)
    idx = np.flatnonzero(front)[near]
    uv = uv[near]
    flux = flux_v0_e * 10.0 ** (-0.4 * cat.vmag[idx])
    signal = np.full((H, W), background_e, dtype=np.float64)
    offs = np.arange(-rad, rad + 1)
    for (u0, v0), F in zip(uv, flux):
        iu, iv = int(np.rint(u0)), int(np.rint(v0))
        us, vs = iu + offs, iv + offs
        gu = ndtr((us + 0.5 - u0) / psf_sigma_px) - ndtr((us - 0.5 - u0) / psf_sigma_px)
        gv = ndtr((vs + 0.5 - v0) / psf_sigma_px) - ndtr((vs - 0.5 - v0) / psf_sigma_px)
        okv, oku = (vs >= 0) & (vs < H), (us >= 0) & (us < W)
        signal[np.ix_(vs[okv], us[oku])] += F * np.outer(gv[okv], gu[oku])
    electrons = rng.poisson(signal).astype(np.float64) + rng.normal(0.0, read_noise_e, signal.shape)
    adu = np.clip(np.rint(bias_adu + electrons / gain_e_per_adu), 0, 65535).astype(np.uint16)
    inside = camera.in_image(uv)
    order = np.argsort(cat.vmag[idx][inside], kind="stable")
    sel = idx[inside][order]
    truth = StarFieldTruth(cat.hr[sel], uv[inside][order], cat.vmag[sel], flux[inside][order], cat.u_eci[sel])
    return adu, truth
