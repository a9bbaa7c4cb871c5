"""Wu et al.'s Earth/star confocal-plane sensor: four UV limb sub-apertures + a star field.

Wu et al. sec. 3.3: one 2048x2048 detector with 11 µm pixels shared by a centre star field
(f = 50 mm, FOV >= 8°, image circle 7 mm) and four identical UV limb sub-apertures
(f = 18 mm, FOV 30.5°, image circle Φ9.8 mm = 891 px) spread evenly around it (fig. 9,
on the diagonals). The star boresight looks away from the Earth; the limb sub-apertures
look towards it, each boresight tilted from the Earth-pointing axis so that the four
30.5° fields together see the limb for Earth diameters 17°–78° (altitudes 36,000–4,000 km).

Tilt: the limb half-angle ``omega = asin((R + d)/(R + H))`` (Wu et al. eq. 14, R = 6,375 km,
d = 0–100 km) spans 8.5°–39°; a sub-aperture whose boresight is tilted by
``(8.5° + 39°)/2 = 23.75°`` from the nadir covers it with its +-15.25° half-field. This
reproduces Wu et al.'s table 2 "lens field" column (limb angle from the sub-aperture
boresight): omega - 23.75° = 14.87° at 4,000 km and -14.96° at 36,000 km.

Body frame (this module's definition): +z_body = star boresight (away from the Earth),
so the nadir is -z_body; sub-aperture k (k = 0..3) is tilted towards azimuth
45° + 90° k in the body x-y plane. Camera frames are OpenCV (x right, y down, z boresight).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factors.constants import DEG, R_LIMB_UV_M
from fgnav.vision.camera import CONFOCAL_STAR_CAMERA, PinholeCamera

__all__ = [
    "CONFOCAL_SUBAPERTURE_CAMERA", "CONFOCAL_STAR_FIELD_CAMERA", "CONFOCAL_LIMB_TILT_RAD",
    "CONFOCAL_LIMB_FOV_RAD", "LimbSubAperture", "confocal_limb_subapertures",
    "limb_half_angle_rad", "earth_apparent_diameter_deg", "CONFOCAL_LIMB_LAYER_M",
]

CONFOCAL_LIMB_FOV_RAD = 30.5 * DEG
"""Full field of one limb sub-aperture (rad)."""
CONFOCAL_SUBAPERTURE_CAMERA = PinholeCamera(focal_mm=18.0, pixel_um=11.0, width_px=891, height_px=891)
"""One limb sub-aperture on its own: f = 18 mm, 11 µm, image circle Φ9.8 mm (891 px) in a
891x891 window, principal point at its centre (Wu et al. eq. 15: f' = 4.9 / tan(15.25°))."""
CONFOCAL_STAR_FIELD_CAMERA = CONFOCAL_STAR_CAMERA
"""Centre star field: f = 50 mm, 11 µm pixels (the central Φ7 mm of the detector)."""
CONFOCAL_LIMB_LAYER_M = (0.0, 100.0e3)
"""UV limb layer heights considered by Wu et al. (d = 0-100 km)."""
CONFOCAL_LIMB_TILT_RAD = 0.25 * (17.0 + 78.0) * DEG
"""Boresight tilt of each limb sub-aperture from the nadir (rad): 23.75°, the middle of the
Wu et al.'s planned Φ17°–Φ78° limb field (its table 2 "lens field" = omega - 23.75°)."""


def limb_half_angle_rad(alt_m, r_limb_m: float = R_LIMB_UV_M, layer_m: float = 0.0):
    """Wu et al. eq. 14: ``omega = asin((R + d) / (R + H))`` (rad); alt_m = H above R."""
    return np.arcsin((r_limb_m + layer_m) / (r_limb_m + np.asarray(alt_m, float)))


def earth_apparent_diameter_deg(alt_km, layer_km: float = 100.0) -> np.ndarray:
    """Wu et al. table 1: Earth apparent diameter (deg) at altitude ``alt_km`` (limb layer d)."""
    return 2.0 * np.degrees(limb_half_angle_rad(np.asarray(alt_km) * 1e3, layer_m=layer_km * 1e3))


@dataclass(frozen=True)
class LimbSubAperture:
    """One limb sub-aperture: its camera and ``R_body_from_cam`` (3x3)."""

    name: str
    camera: PinholeCamera
    R_body_from_cam: np.ndarray

    @property
    def boresight_body(self) -> np.ndarray:
        return self.R_body_from_cam[:, 2]


def _rot_to(z_axis: np.ndarray, x_hint: np.ndarray) -> np.ndarray:
    z = z_axis / np.linalg.norm(z_axis)
    x = x_hint - (x_hint @ z) * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z])


def confocal_limb_subapertures(tilt_rad: float = CONFOCAL_LIMB_TILT_RAD) -> list[LimbSubAperture]:
    """The four limb sub-apertures (module doc): boresight = nadir (-z_body) tilted by
    ``tilt_rad`` towards azimuth 45° + 90° k; camera x axis along the tilt azimuth."""
    out = []
    for k in range(4):
        az = (45.0 + 90.0 * k) * DEG
        h = np.array([np.cos(az), np.sin(az), 0.0])
        bore = np.cos(tilt_rad) * np.array([0.0, 0.0, -1.0]) + np.sin(tilt_rad) * h
        out.append(LimbSubAperture(f"limb{k}", CONFOCAL_SUBAPERTURE_CAMERA, _rot_to(bore, h)))
    return out
