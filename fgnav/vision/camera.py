"""Pinhole camera with radial distortion, OpenCV convention.

Camera frame: +x right, +y down, +z along the boresight. Pixel coordinates (u, v): u to
the right, v down, origin at the centre of the top-left pixel (OpenCV). A direction
``v_cam`` projects to ``u = cx + f_px * x_d``, ``v = cy + f_px * y_d`` with the normalized
coordinates ``(x, y) = (v_x / v_z, v_y / v_z)`` distorted radially:
``x_d = x (1 + k1 r^2 + k2 r^4)`` (Brown–Conrady, radial terms only).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np


@dataclass(frozen=True)
class PinholeCamera:
    """A pinhole camera.

    focal_mm : focal length (mm); pixel_um : pixel pitch (µm); width_px, height_px : image
    size; cx_px, cy_px : principal point (pixels; default the image centre);
    k1, k2 : radial distortion coefficients on normalized coordinates.
    """

    focal_mm: float
    pixel_um: float
    width_px: int
    height_px: int
    cx_px: float | None = None
    cy_px: float | None = None
    k1: float = 0.0
    k2: float = 0.0

    def __post_init__(self):
        if not (self.focal_mm > 0 and self.pixel_um > 0 and self.width_px > 0 and self.height_px > 0):
            raise ValueError(
                f"camera needs focal_mm, pixel_um, width_px, height_px > 0, got {self.focal_mm}, "
                f"{self.pixel_um}, {self.width_px}, {self.height_px}")

    @property
    def f_px(self) -> float:
        """Focal length in pixels."""
        return self.focal_mm * 1e3 / self.pixel_um

    @property
    def cx(self) -> float:
        return (self.width_px - 1) / 2.0 if self.cx_px is None else self.cx_px

    @property
    def cy(self) -> float:
        return (self.height_px - 1) / 2.0 if self.cy_px is None else self.cy_px

    @property
    def fov_x_rad(self) -> float:
        """Full horizontal field of view (rad), distortion ignored."""
        return 2.0 * np.arctan(self.width_px / 2.0 / self.f_px)

    @property
    def fov_diag_rad(self) -> float:
        """Full diagonal field of view (rad), distortion ignored."""
        return 2.0 * np.arctan(np.hypot(self.width_px, self.height_px) / 2.0 / self.f_px)

    @property
    def K(self) -> np.ndarray:
        """OpenCV intrinsic matrix (3x3, pixels)."""
        return np.array([[self.f_px, 0.0, self.cx], [0.0, self.f_px, self.cy], [0.0, 0.0, 1.0]])

    @classmethod
    def from_fov(cls, fov_x_deg: float, width_px: int, height_px: int, pixel_um: float = 1.0, **kw):
        """A camera whose full horizontal field of view is ``fov_x_deg`` (degrees)."""
        f_px = width_px / 2.0 / np.tan(np.radians(fov_x_deg) / 2.0)
        return cls(focal_mm=f_px * pixel_um * 1e-3, pixel_um=pixel_um, width_px=width_px,
                   height_px=height_px, **kw)

    def with_focal_px(self, f_px: float) -> "PinholeCamera":
        return replace(self, focal_mm=f_px * self.pixel_um * 1e-3)

    def _distort(self, xy: np.ndarray) -> np.ndarray:
        r2 = np.sum(xy * xy, axis=-1, keepdims=True)
        return xy * (1.0 + self.k1 * r2 + self.k2 * r2 * r2)

    def _undistort(self, xy_d: np.ndarray, iterations: int = 20) -> np.ndarray:
        xy = xy_d.copy()
        if self.k1 == 0.0 and self.k2 == 0.0:
            return xy
        for _ in range(iterations):  # fixed point: x = x_d / (1 + k1 r^2 + k2 r^4)
            r2 = np.sum(xy * xy, axis=-1, keepdims=True)
            xy = xy_d / (1.0 + self.k1 * r2 + self.k2 * r2 * r2)
        return xy

    def project(self, v_cam: np.ndarray) -> np.ndarray:
        """Directions in the camera frame (..., 3) -> pixel coordinates (..., 2).

        Directions with v_z <= 0 (behind the camera) give NaN.
        """
        v = np.asarray(v_cam, dtype=float)
        z = v[..., 2:3]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = np.where(z > 0, v[..., :2] / z, np.nan)
        xy_d = self._distort(xy)
        return np.stack([self.cx + self.f_px * xy_d[..., 0], self.cy + self.f_px * xy_d[..., 1]], axis=-1)

    def pixel_to_ray(self, uv_px: np.ndarray) -> np.ndarray:
        """Pixel coordinates (..., 2) -> unit directions in the camera frame (..., 3)."""
        uv = np.asarray(uv_px, dtype=float)
        xy_d = np.stack([(uv[..., 0] - self.cx) / self.f_px, (uv[..., 1] - self.cy) / self.f_px], axis=-1)
        xy = self._undistort(xy_d)
        v = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

    def in_image(self, uv_px: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        """True where a pixel coordinate lies inside the image (with a margin)."""
        uv = np.asarray(uv_px, dtype=float)
        return ((uv[..., 0] >= -0.5 + margin_px) & (uv[..., 0] <= self.width_px - 0.5 - margin_px)
                & (uv[..., 1] >= -0.5 + margin_px) & (uv[..., 1] <= self.height_px - 0.5 - margin_px))


CONFOCAL_STAR_CAMERA = PinholeCamera(focal_mm=50.0, pixel_um=11.0, width_px=2048, height_px=2048)
"""Wu et al.'s centre (star) field: f = 50 mm on the 2048x2048, 11 µm detector (FOV ~25.7°
over the full detector; the star field uses the central >= 8° of it)."""

CONFOCAL_LIMB_CAMERA = PinholeCamera(focal_mm=18.0, pixel_um=11.0, width_px=2048, height_px=2048)
"""Wu et al.'s UV limb sub-aperture optics: f = 18 mm, 11 µm pixels (FOV 30.5° per sub-aperture)."""
