"""Limb point extraction: coarse disk contour (OpenCV), sub-pixel edges, RANSAC.

Pipeline (Wu et al., fig. 11 "limb image processing"; Christian, JSR 2017 for the
sub-pixel step):

1. Coarse: block-average the frame by ``coarse_factor`` (``cv2.resize`` INTER_AREA),
   smooth, Otsu threshold, keep the largest bright component, trace its outer contour
   (``cv2.findContours``), drop contour points next to masked / out-of-field pixels, and
   resample the contour every ``spacing_px`` pixels. The outward normal comes from the
   smoothed coarse gradient.
2. Fine: along each normal, a brightness profile (bilinear, ``cv2.remap``; three parallel
   lines 1 px apart averaged) is differentiated; the edge is the *centroid of the radiance
   drop* in a window of ``+-half_window_px`` re-centred on the estimate three times, its
   denominator the running median of the drop along the limb (the point's own noisy sum
   would bias the ratio: the shot noise is larger on the disk side). For a
   symmetric PSF the centroid of ``-dL/dt`` sits where the radiance-gradient centroid of
   the limb profile is, i.e. on the limb surface as the renderer defines it (no bias from
   the blur, unlike a max-gradient pick on a skewed profile) -- for a *straight* edge.
   On a curved edge every blur moves the centroid towards the centre of curvature:
   convolving a disk of radius ``R`` with an isotropic kernel of variance ``s^2`` per axis
   shifts its edge inward by ``s^2 / (2 R)`` to first order (the kernel sees
   ``R + x - y^2/(2R)``). The locator's own blur adds :data:`EDGE_LOCATOR_VAR_PX2` to the
   optics PSF: pixel area (box, 1/12), bilinear profile sampling (triangle, 1/6) and the
   profile lines at tangential offsets ``w`` (:data:`PROFILE_LINE_OFFSETS_PX`), each of
   which meets the curved edge ``w^2 / (2R)`` further in (mean of ``w^2``: 2/3).
   :func:`edge_curvature_bias_px` gives the total inward offset
   ``(psf_sigma_px^2 + EDGE_LOCATOR_VAR_PX2) / (2 R_px)``; measured on noise-free renders
   at GEO (R_px = 250, :mod:`fgnav.simulate.limb_render`): PSF 0.5 / 1.0 / 1.5 px ->
   -0.0022 / -0.0040 / -0.0070 px vs -0.0023 / -0.0038 / -0.0063 predicted.
   :func:`fgnav.vision.horizon.estimate_horizon` (``psf_sigma_px``) applies it.
3. Outliers: RANSAC with a least-median-of-squares score (no noise level needed) on the
   horizon-cone model ``s_i^T n = 1`` (rays ``s_i`` through the camera; a sphere's limb
   rays form a circular cone) or, without a camera, on a circle in the image; then
   inliers within 3.5 robust sigmas.

Pixel coordinates: (u, v), OpenCV, origin at the centre of the top-left pixel.
Points are spaced >= 3 px so that the noise of neighbouring points is independent (their
bilinear footprints do not overlap), which the horizon covariances assume.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fgnav.errors import UserError
from fgnav.vision.camera import PinholeCamera

__all__ = ["LimbPoints", "extract_limb_points", "ransac_limb", "cone_point_gain",
           "PROFILE_LINE_OFFSETS_PX", "EDGE_LOCATOR_VAR_PX2", "edge_curvature_bias_px"]

PROFILE_LINE_OFFSETS_PX = (-1.0, 0.0, 1.0)
"""Tangential offsets (px) of the parallel profile lines averaged by the sub-pixel step."""

MIN_LIMB_CONTRAST = 1.0
"""A limb's radiance step: the mean over a band just inside the circle fitted to its points
minus the mean just outside, over the bands' pooled standard deviation
(:func:`limb_contrast`), must exceed this. Measured: Wu et al.'s table-3 frames (the faintest
rendered here, 3.7 DN on 2 DN of noise) 2.26-2.32, simulated geo-limb frames 61, DSCOVR/EPIC
frames (red channel) 4.5-6.7; frames without a limb: Gaussian, Poisson, uniform,
salt-and-pepper noise and noise blurred by 1-8 px -0.05 to 0.16, a noisy sky gradient (whose
Otsu edge is a straight line across the ramp) up to 0.67. Their blobs gave a limb fix with
an 80 arcsec sigma before this test."""

EDGE_LOCATOR_VAR_PX2 = (1.0 / 12.0 + 1.0 / 6.0
                        + sum(w * w for w in PROFILE_LINE_OFFSETS_PX) / len(PROFILE_LINE_OFFSETS_PX))
"""Blur variance (px^2) the sub-pixel edge locator adds to the optics PSF (module doc,
step 2): pixel area 1/12 + bilinear sampling 1/6 + mean squared offset of the averaged
profile lines (2/3 for :data:`PROFILE_LINE_OFFSETS_PX`) = 0.917."""


def edge_curvature_bias_px(radius_px: float, psf_sigma_px: float) -> float:
    """Inward offset (px, > 0) of the located edge of a limb with radius of curvature
    ``radius_px`` (px) under a Gaussian optics PSF of sigma ``psf_sigma_px`` (px):
    ``(psf_sigma_px^2 + EDGE_LOCATOR_VAR_PX2) / (2 radius_px)`` (module doc, step 2)."""
    if not radius_px > 0:
        raise UserError(f"edge curvature bias: limb radius must be > 0 px, got {radius_px}")
    if not psf_sigma_px >= 0:
        raise UserError(f"edge curvature bias: PSF sigma must be >= 0 px, got {psf_sigma_px}")
    return (psf_sigma_px ** 2 + EDGE_LOCATOR_VAR_PX2) / (2.0 * radius_px)


@dataclass
class LimbPoints:
    """Sub-pixel limb points.

    uv_px : (N, 2) pixel coordinates; normal : (N, 2) unit outward normals (disk -> space,
    image axes); contrast : (N,) radiance drop across the edge (image units);
    inlier : (N,) bool, RANSAC verdict (all True before RANSAC).
    """

    uv_px: np.ndarray
    normal: np.ndarray
    contrast: np.ndarray
    inlier: np.ndarray

    def __len__(self) -> int:
        return int(self.uv_px.shape[0])

    def inliers(self) -> "LimbPoints":
        m = self.inlier
        return LimbPoints(self.uv_px[m], self.normal[m], self.contrast[m], np.ones(int(m.sum()), bool))

    def shifted(self, d_px) -> "LimbPoints":
        """Copy with every point moved by ``d_px`` (px, scalar or (N,)) along its outward normal."""
        d = np.asarray(d_px, float)
        d = d[:, None] if d.ndim == 1 else d
        return LimbPoints(self.uv_px + d * self.normal, self.normal, self.contrast, self.inlier)


def _coarse_contour(img: np.ndarray, valid: np.ndarray | None, k: int):
    import cv2

    H, W = img.shape
    hs, ws = max(H // k, 8), max(W // k, 8)
    small = cv2.resize(img, (ws, hs), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), 1.0)
    if valid is not None:
        vsmall = cv2.resize(valid.astype(np.float32), (ws, hs), interpolation=cv2.INTER_AREA) > 0.999
        vals = small[vsmall]
    else:
        vsmall = np.ones_like(small, bool)
        vals = small.ravel()
    if vals.size < 16:
        raise UserError("limb extraction: the valid field is too small")
    lo, hi = np.percentile(vals, [0.5, 99.5])
    if not hi > lo:
        raise UserError("limb extraction: the image is flat (no limb)")
    s8 = np.clip((small - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)
    _, binary = cv2.threshold(s8, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    binary[~vsmall] = 0
    binary = cv2.morphologyEx(binary, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n_lab, labels, stats, _ = cv2.connectedComponentsWithStats(binary, connectivity=8)
    if n_lab < 2:
        raise UserError("limb extraction: no bright disk found")
    areas = stats[1:, cv2.CC_STAT_AREA]
    keep_lab = 1 + np.nonzero(areas >= max(0.05 * areas.max(), 4))[0]   # disk pieces (arcs)
    disk = np.isin(labels, keep_lab).astype(np.uint8)
    contours, _ = cv2.findContours(disk, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    contours = [c[:, 0, :].astype(np.float64) for c in contours if len(c) >= 8]
    # concatenate the closed contours; a large jump marks a piece boundary
    cont = np.concatenate(contours, axis=0)                          # (M, 2) x, y (coarse)
    small2 = cv2.GaussianBlur(small, (0, 0), 1.5)
    gx = cv2.Sobel(small2, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(small2, cv2.CV_32F, 0, 1, ksize=3)
    ci = cont.astype(int)
    g = np.stack([gx[ci[:, 1], ci[:, 0]], gy[ci[:, 1], ci[:, 0]]], -1).astype(np.float64)
    # keep points away from masked pixels and the frame border
    keep_mask = cv2.erode(vsmall.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    keep_mask[:2, :] = keep_mask[-2:, :] = False
    keep_mask[:, :2] = keep_mask[:, -2:] = False
    keep = keep_mask[ci[:, 1], ci[:, 0]]
    return cont, g, keep


def _sample_profiles(img, p, n, t_offsets, widths=PROFILE_LINE_OFFSETS_PX):
    """Mean of bilinear profiles along normals: p (N,2), n (N,2), t_offsets (N,M) -> (N,M)."""
    import cv2

    tau = np.stack([-n[:, 1], n[:, 0]], -1)
    acc = None
    for w in widths:
        mx = (p[:, 0:1] + t_offsets * n[:, 0:1] + w * tau[:, 0:1]).astype(np.float32)
        my = (p[:, 1:2] + t_offsets * n[:, 1:2] + w * tau[:, 1:2]).astype(np.float32)
        prof = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        acc = prof if acc is None else acc + prof
    return acc / len(widths)


def limb_contrast(img: np.ndarray, uv_px: np.ndarray, valid: np.ndarray | None = None,
                  band_px: tuple[float, float] = (2.0, 12.0)) -> float:
    """The radiance step across the limb points ``uv_px`` (N, 2), in standard deviations: the
    circle through them by the algebraic least-squares fit (Kasa 1976), then the mean of the
    pixels ``band_px`` inside it minus the mean of those as far outside, over the bands'
    pooled standard deviation (valid pixels only). Points on the edges of noise blobs lie on
    no circle, and the two bands of the circle fitted to them have the same mean; the test
    is not fooled by spatially correlated noise, which a neighbour-difference noise estimate
    is. Returns 0.0 where a band is (nearly) empty."""
    f = np.asarray(img, dtype=np.float64)
    uv = np.asarray(uv_px, dtype=np.float64)
    A = np.column_stack([uv[:, 0], uv[:, 1], np.ones(len(uv))])
    (D, E, F), *_ = np.linalg.lstsq(A, -(uv ** 2).sum(axis=1), rcond=None)
    cx, cy = -0.5 * D, -0.5 * E
    r = math.sqrt(max(cx * cx + cy * cy - F, 0.0))
    yy, xx = np.ogrid[:f.shape[0], :f.shape[1]]
    d2 = (xx - cx) ** 2 + (yy - cy) ** 2   # squared distances: no index grids, no square roots

    def ring(lo, hi):   # lo < |p - c| < hi
        return (d2 > (lo * lo if lo > 0 else -1.0)) & (d2 < (hi * hi if hi > 0 else -1.0))

    inner = ring(r - band_px[1], r - band_px[0])
    outer = ring(r + band_px[0], r + band_px[1])
    if valid is not None:
        inner &= valid
        outer &= valid
    if inner.sum() < 10 or outer.sum() < 10:
        return 0.0
    a, o = f[inner], f[outer]
    s = math.sqrt(0.5 * (a.var() + o.var()))
    return float((a.mean() - o.mean()) / s) if s > 0 else math.inf


def extract_limb_points(image: np.ndarray, *, valid_mask: np.ndarray | None = None,
                        spacing_px: float = 4.0, half_window_px: int = 4,
                        coarse_factor: int = 4, min_contrast_ratio: float = 0.5) -> LimbPoints:
    """Sub-pixel limb points of a 2-D frame (any dtype; bright disk on a dark sky).

    valid_mask : optional bool (H, W), False where the field is stopped / masked; points
    within ~2 coarse pixels of a masked pixel are dropped (their edge would be the mask's).
    spacing_px : spacing of the points along the limb (px, >= 3 keeps their noise
    independent). half_window_px : centroid half-window (px). coarse_factor : block size of
    the coarse stage. min_contrast_ratio : points whose radiance drop is below this
    fraction of the median drop are rejected (mask corners, stray edges).
    """
    from scipy.ndimage import median_filter

    img = np.ascontiguousarray(image, dtype=np.float32)
    if img.ndim != 2:
        raise UserError(f"limb extraction needs a 2-D single-channel image, got shape {img.shape}")
    if spacing_px < 1.0:
        raise UserError(f"spacing_px must be >= 1, got {spacing_px}")
    k = int(coarse_factor)
    cont, g, keep = _coarse_contour(img, valid_mask, k)
    # resample along the contour every spacing_px (full-resolution units)
    seg = np.linalg.norm(np.diff(cont, axis=0, append=cont[:1]), axis=1) * k
    s = np.concatenate([[0.0], np.cumsum(seg)[:-1]])
    idx = np.nonzero(np.diff(np.floor(s / spacing_px), prepend=-1.0) > 0)[0]
    idx = idx[keep[idx]]
    if idx.size < 6:
        raise UserError(f"limb extraction: only {idx.size} usable limb points (need >= 6)")
    # normals: smoothed coarse gradient, pointing bright -> dark
    gs = g[idx]
    gn = np.linalg.norm(gs, axis=1)
    ok = gn > 0
    idx, gs, gn = idx[ok], gs[ok], gn[ok]
    n = -gs / gn[:, None]
    p = (cont[idx] + 0.5) * k - 0.5
    # pass 1: wide profile, strongest smoothed drop
    T = k + 4
    t = np.arange(-T, T + 1, dtype=np.float64)
    prof = _sample_profiles(img, p, n, np.broadcast_to(t, (p.shape[0], t.size)))
    d = -(prof[:, 1:] - prof[:, :-1])
    ds = d.copy()
    ds[:, 1:-1] = 0.25 * d[:, :-2] + 0.5 * d[:, 1:-1] + 0.25 * d[:, 2:]
    tc = 0.5 * (t[1:] + t[:-1])[np.argmax(ds, axis=1)]
    # passes 2-3: centroid of the drop in a window re-centred on the estimate
    W = int(half_window_px)
    j = np.arange(-W, W + 2, dtype=np.float64) - 0.5          # samples; midpoints at -W..W
    jm = np.arange(-W, W + 1, dtype=np.float64)

    for _ in range(3):
        prof = _sample_profiles(img, p, n, tc[:, None] + j[None, :])
        d = -(prof[:, 1:] - prof[:, :-1])
        contrast = d.sum(axis=1)
        # denominator: running median of the drop along the limb (15 points), not the
        # point's own noisy sum -- a ratio of two correlated noisy sums is biased when the
        # noise differs on the two sides of the edge (shot noise on the disk only)
        c_ref = median_filter(contrast, size=min(15, contrast.size), mode="wrap")
        with np.errstate(divide="ignore", invalid="ignore"):
            delta = (d * jm).sum(axis=1) / c_ref
        delta = np.where(np.isfinite(delta), np.clip(delta, -W, W), 0.0)
        tc = tc + delta
    uv = p + tc[:, None] * n
    good = contrast > min_contrast_ratio * np.median(contrast)
    good &= (uv[:, 0] > 1) & (uv[:, 1] > 1) & (uv[:, 0] < img.shape[1] - 2) & (uv[:, 1] < img.shape[0] - 2)
    if valid_mask is not None:
        ui = np.clip(np.rint(uv).astype(int), 0, [img.shape[1] - 1, img.shape[0] - 1])
        good &= valid_mask[ui[:, 1], ui[:, 0]]
    if good.sum() < 6:
        raise UserError(f"limb extraction: only {int(good.sum())} limb points with contrast (need >= 6)")
    step = limb_contrast(img, uv[good], valid_mask)
    if not step > MIN_LIMB_CONTRAST:
        raise UserError(f"limb extraction: no limb in the frame: across the circle through its "
                        f"{int(good.sum())} edge points the radiance steps by {step:.2g} "
                        f"standard deviations; a limb needs more than {MIN_LIMB_CONTRAST:g} "
                        f"(frames without a limb: below 0.7)")
    return LimbPoints(uv[good], n[good], contrast[good], np.ones(int(good.sum()), bool))


def cone_point_gain(s_cam: np.ndarray, vnorm: np.ndarray, normal_uv: np.ndarray,
                    n_vec: np.ndarray, f_px: float) -> np.ndarray:
    """``g_i = d(s_i^T n)/dt_i``: change of the horizon-cone residual per pixel of normal motion.

    s_cam (N,3) unit rays; vnorm (N,) = |(x, y, 1)| of the undistorted normalized point;
    normal_uv (N,2) unit image normals; n_vec (3,) cone vector; f_px focal (px). Derivation:
    s = v/|v|, v = ((u - cx)/f, (v - cy)/f, 1) => ds/duv = (I - s s^T)/|v| [[1/f, 0], [0, 1/f], [0, 0]].
    """
    dv = np.concatenate([normal_uv / f_px, np.zeros((normal_uv.shape[0], 1))], axis=1)
    ds = (dv - s_cam * np.sum(s_cam * dv, axis=1, keepdims=True)) / vnorm[:, None]
    return ds @ n_vec


def _model_residuals_px(uv, normals, camera):
    """Vectorized model: returns (fit(idx (K, m)) -> params (K, p), resid(params) -> (K, N) px, m)."""
    N = uv.shape[0]
    if camera is not None:
        s = camera.pixel_to_ray(uv)
        vn = 1.0 / s[:, 2]
        dv = np.concatenate([normals / camera.f_px, np.zeros((N, 1))], axis=1)
        D = (dv - s * np.sum(s * dv, axis=1, keepdims=True)) / vn[:, None]   # ds/dt, (N, 3)

        def fit(idx):
            S3 = s[idx]                                            # (K, m, 3)
            StS = np.einsum("kmi,kmj->kij", S3, S3)
            rhs = S3.sum(axis=1)
            ok = np.abs(np.linalg.det(StS)) > 1e-30
            out = np.full((idx.shape[0], 3), np.nan)
            out[ok] = np.linalg.solve(StS[ok], rhs[ok][..., None])[..., 0]
            return out

        def resid(nv):
            with np.errstate(divide="ignore", invalid="ignore"):
                r = (nv @ s.T - 1.0) / (nv @ D.T)
            bad = ~(np.sum(nv * nv, axis=1) > 1.0)
            r[bad] = np.inf
            return r
    else:
        x = uv

        def fit(idx):
            X = x[idx]                                             # (K, m, 2)
            A = np.concatenate([X, np.ones(X.shape[:2] + (1,))], axis=2)
            b = -(X ** 2).sum(axis=2)
            AtA = np.einsum("kmi,kmj->kij", A, A)
            ok = np.abs(np.linalg.det(AtA)) > 1e-12
            out = np.full((idx.shape[0], 3), np.nan)
            out[ok] = np.linalg.solve(AtA[ok], np.einsum("kmi,km->ki", A[ok], b[ok])[..., None])[..., 0]
            return out

        def resid(c):
            xc, yc = -c[:, 0:1] / 2, -c[:, 1:2] / 2
            r2 = xc * xc + yc * yc - c[:, 2:3]
            with np.errstate(invalid="ignore"):
                r = np.hypot(x[None, :, 0] - xc, x[None, :, 1] - yc) - np.sqrt(r2)
            r[~(r2[:, 0] > 0)] = np.inf
            return r
    return fit, resid, 3


def ransac_limb(points: LimbPoints, camera: PinholeCamera | None = None, *,
                rng: np.random.Generator | None = None, iterations: int = 128,
                min_threshold_px: float = 0.5, k_sigma: float = 3.5) -> LimbPoints:
    """Mark outliers by RANSAC (LMedS score) on the horizon cone (with a camera) or a circle.

    Minimal samples of 3 points give candidate models (cone vector n with ``s^T n = 1``, or
    a circle), all scored at once by the median squared normal residual (px); the best one
    is refined by least squares on its inliers twice. Returns a copy with ``inlier`` set:
    |residual| <= max(min_threshold_px, k_sigma * robust sigma).
    """
    rng = np.random.default_rng(0) if rng is None else rng
    uv = points.uv_px
    N = uv.shape[0]
    if N < 6:
        raise UserError(f"RANSAC needs >= 6 limb points, got {N}")
    fit, resid, m = _model_residuals_px(uv, points.normal, camera)
    idx = np.argsort(rng.random((iterations, N)), axis=1)[:, :m] if N < 64 else \
        rng.integers(0, N, size=(iterations, m))
    idx = idx[(idx[:, 0] != idx[:, 1]) & (idx[:, 1] != idx[:, 2]) & (idx[:, 0] != idx[:, 2])]
    if idx.shape[0] == 0:
        raise UserError("RANSAC: no valid minimal sample")
    R = resid(fit(idx))
    R[~np.isfinite(R)] = np.inf
    score = np.median(R * R, axis=1)
    best = int(np.argmin(score))
    if not np.isfinite(score[best]):
        raise UserError("RANSAC found no limb model (degenerate limb points)")
    r = R[best]
    inl = np.ones(N, bool)
    for _ in range(2):
        sigma = 1.4826 * np.median(np.abs(r)) * (1 + 5.0 / max(N - m, 1))
        inl = np.abs(r) <= max(min_threshold_px, k_sigma * sigma)
        if inl.sum() < 6:
            break
        sel = np.nonzero(inl)[0]
        if camera is not None:
            s = camera.pixel_to_ray(uv[sel])
            nv = np.linalg.lstsq(s, np.ones(sel.size), rcond=None)[0][None, :]
        else:
            nv = fit(sel[None, :])
        rr = resid(nv)[0]
        if not np.all(np.isfinite(rr)):
            break
        r = rr
    sigma = 1.4826 * np.median(np.abs(r[inl]))
    inl = np.abs(r) <= max(min_threshold_px, k_sigma * sigma)
    return LimbPoints(points.uv_px, points.normal, points.contrast, inl)
