"""Lost-in-space star identification (tetra3-like geometric hashing), attitude and focal length.

Database (built once per catalogue + parameters, cached as ``.npz`` under
``$FGNAV_CACHE_DIR`` or ``~/.cache/fgnav``):

* pattern stars: catalogue stars (close doubles < 60" merged into their photocentre) with
  V <= ``vmag_max``, density-capped brightest-first: a star is dropped when
  ``round(stars_per_fov pi / 4)`` brighter pattern stars already lie within F/2 of it
  (F: the database field of view) -- at most about ``stars_per_fov`` per F x F field in
  dense regions, every star in sparse ones;
* patterns: every 4-star set of pattern stars whose six pairwise angles are all
  <= ``pattern_max = 0.85 F`` (F: grid value nearest the FOV guess, see
  :func:`database_fov_for`);
* key: the six angles sorted, the five smaller divided by the largest (scale invariant, so
  the unknown focal length does not matter to first order), each quantized in bins of
  ``ratio_bin``; patterns are sorted by key for ``searchsorted`` look-up.

Query: the brightest image stars are turned into rays with the approximate focal length;
every 4-combination (brightest first) whose size is compatible with ``pattern_max`` within
the field-of-view tolerance gives a key; all bins within ``ratio_tol`` are looked up, the
candidates whose ratios agree within ``ratio_tol`` and whose largest angle agrees with the
focal-length tolerance are verified in order:

1. star correspondence: the permutation of the 4 catalogue stars that best matches the
   image angle matrix; focal length from the angle scale ``f = f0 * sum(a_img) / sum(a_cat)``;
2. attitude: Wahba SVD on the 4 pairs (:func:`fgnav.vision.attitude.wahba_svd`);
3. verification: catalogue stars (V <= ``vmag_verify``) are projected into the image and
   matched to detections within a radius; the candidate is accepted when the probability of
   at least that many chance matches (binomial, ``p = N_det pi r^2 / (W H)`` per predicted
   star), times the number of database patterns, is below ``false_match_max``;
4. refinement: Gauss-Newton on the pixel residuals for attitude, focal length (and optionally
   radial distortion k1), :func:`fgnav.vision.attitude.star_pixel_model`, re-matching with a
   tighter radius, then once more without matches whose residual exceeds 5x the median
   residual; covariance ``s0^2 (J^T W J)^-1`` with the a-posteriori variance factor
   ``s0^2 = chi^2 / (2m - p)``.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import time
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from factors.aberration import apparent_direction
from factors.constants import ARCSEC, DEG
from factors.geometry import so3_exp
from fgnav.errors import UserError
from fgnav.vision.attitude import (quat_from_matrix, roll_ra_dec, star_pixel_model, wahba_svd)
from fgnav.vision.camera import PinholeCamera
from fgnav.vision.catalogue import Catalogue, load_catalogue, merge_close_stars

__all__ = ["DatabaseParams", "PatternDatabase", "StarSolution", "StarIdentificationError",
           "cache_dir", "database_fov_for", "get_database", "build_database",
           "solve_lost_in_space", "refine_attitude"]

_DB_VERSION = 4
_MERGE_RAD = 60.0 * ARCSEC  # close doubles seen as one star (1.5 px at 11.4 deg / 1024 px)
_PAIR_I = (0, 0, 0, 1, 1, 2)
_PAIR_J = (1, 2, 3, 2, 3, 3)
_FOV_GRID_BASE_DEG = 10.0
_FOV_GRID_STEP = 1.1


class StarIdentificationError(UserError):
    """No star pattern could be identified and verified in the image."""


def cache_dir() -> Path:
    """Directory for derived caches: ``$FGNAV_CACHE_DIR`` or ``~/.cache/fgnav``."""
    d = os.environ.get("FGNAV_CACHE_DIR")
    return Path(d) if d else Path.home() / ".cache" / "fgnav"


def database_fov_for(fov_deg: float, fov_tolerance: float = 0.1) -> float:
    """Database field of view (deg) for a camera whose horizontal FOV is about ``fov_deg``:
    the nearest value (in log scale) of the grid 10 * 1.1^k, so that a few cached databases
    serve every FOV guess. ``fov_tolerance`` is accepted for symmetry with the solver; the
    database patterns (<= 0.85 F) fit in the field for any FOV within +-10% of F."""
    k = round(math.log(fov_deg / _FOV_GRID_BASE_DEG) / math.log(_FOV_GRID_STEP))
    return round(_FOV_GRID_BASE_DEG * _FOV_GRID_STEP**k, 6)


@dataclass(frozen=True)
class DatabaseParams:
    """Pattern-database parameters. fov_deg: field the database is built for (deg);
    stars_per_fov: target pattern-star density per fov x fov; vmag_max: faintest pattern
    star (mag); pattern_max_frac: largest pattern edge / fov; ratio_bin: key quantization."""

    fov_deg: float = 10.0
    stars_per_fov: float = 10.0
    vmag_max: float = 6.5
    pattern_max_frac: float = 0.85
    ratio_bin: float = 0.01

    @property
    def pattern_max_rad(self) -> float:
        return self.pattern_max_frac * self.fov_deg * DEG

    @property
    def cap_radius_rad(self) -> float:
        """Radius of the density cap: half the database field."""
        return 0.5 * self.fov_deg * DEG

    @property
    def cap_count(self) -> int:
        """Pattern stars allowed within ``cap_radius_rad``: stars_per_fov scaled to the
        disc area (pi/4 of fov x fov)."""
        return max(4, int(round(self.stars_per_fov * math.pi / 4.0)))


@dataclass
class PatternDatabase:
    """Star-pattern hash table. star_hr/star_u_eci: (S,) HR numbers and (S, 3) unit vectors
    of the pattern stars; patterns: (P, 4) indices into them; keys: (P,) sorted int64;
    ratios: (P, 5) edge ratios; max_angle_rad: (P,) largest edge (rad)."""

    params: DatabaseParams
    star_hr: np.ndarray
    star_u_eci: np.ndarray
    patterns: np.ndarray
    keys: np.ndarray
    ratios: np.ndarray
    max_angle_rad: np.ndarray
    build_time_s: float = 0.0
    path: Path | None = None
    loaded_from_cache: bool = False

    def __len__(self) -> int:
        return len(self.keys)


def _n_bins(ratio_bin: float) -> int:
    return int(math.ceil(1.0 / ratio_bin)) + 2


def _pattern_angles(u: np.ndarray) -> np.ndarray:
    """(..., 4, 3) unit vectors -> (..., 6) pairwise angles (rad), pair order 01 02 03 12 13 23."""
    out = np.empty(u.shape[:-2] + (6,))
    for k, (i, j) in enumerate(zip(_PAIR_I, _PAIR_J)):
        d = u[..., i, :] - u[..., j, :]
        out[..., k] = np.einsum("...k,...k->...", d, d)
    return 2.0 * np.arcsin(np.clip(0.5 * np.sqrt(out), 0.0, 1.0))


def _ratios(angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.sort(angles, axis=-1)
    return a[..., :5] / a[..., 5:6], a[..., 5]


def _key(bins: np.ndarray, nb: int) -> np.ndarray:
    k = np.zeros(bins.shape[:-1], np.int64)
    for j in range(bins.shape[-1]):
        k = k * nb + bins[..., j].astype(np.int64)
    return k


def _thin(u: np.ndarray, radius_rad: float, n_max: int) -> np.ndarray:
    """Indices kept by brightest-first density capping (``u`` sorted by brightness): a star
    is kept unless ``n_max`` brighter kept stars already lie within ``radius_rad`` of it.
    Sparse regions keep every star; dense regions keep the locally brightest ones."""
    tree = cKDTree(u)
    nbrs = tree.query_ball_point(u, 2.0 * math.sin(radius_rad / 2.0))
    count = np.zeros(len(u), int)
    keep = []
    for i in range(len(u)):
        if count[i] >= n_max:
            continue
        keep.append(i)
        count[nbrs[i]] += 1
    return np.array(keep, int)


def build_database(params: DatabaseParams = DatabaseParams(), catalogue: Catalogue | None = None) -> PatternDatabase:
    """Build the pattern database (no caching; see :func:`get_database`)."""
    t0 = time.perf_counter()
    cat = catalogue if catalogue is not None else load_catalogue()
    cat = merge_close_stars(cat, _MERGE_RAD).brighter_than(params.vmag_max)
    order = np.argsort(cat.vmag, kind="stable")
    keep = order[_thin(cat.u_eci[order], params.cap_radius_rad, params.cap_count)]
    u = cat.u_eci[keep]
    hr = cat.hr[keep]
    pmax = params.pattern_max_rad
    chord_max = 2.0 * math.sin(pmax / 2.0)
    tree = cKDTree(u)
    nbrs = tree.query_ball_point(u, chord_max)
    combos_cache: dict[int, np.ndarray] = {}
    out = []
    for i in range(len(u)):
        nb = np.array(sorted(j for j in nbrs[i] if j > i), int)
        n = len(nb)
        if n < 3:
            continue
        if n not in combos_cache:
            combos_cache[n] = np.array(list(itertools.combinations(range(n), 3)), int).reshape(-1, 3)
        c = combos_cache[n]
        D = np.linalg.norm(u[nb][:, None, :] - u[nb][None, :, :], axis=-1) <= chord_max
        ok = D[c[:, 0], c[:, 1]] & D[c[:, 0], c[:, 2]] & D[c[:, 1], c[:, 2]]
        c = nb[c[ok]]
        out.append(np.column_stack([np.full(len(c), i), c]))
    patterns = np.concatenate(out).astype(np.int32) if out else np.zeros((0, 4), np.int32)
    ang = _pattern_angles(u[patterns])
    ratios, amax = _ratios(ang)
    nb = _n_bins(params.ratio_bin)
    keys = _key(np.floor(ratios / params.ratio_bin), nb)
    srt = np.argsort(keys, kind="stable")
    return PatternDatabase(params, hr, u, patterns[srt], keys[srt], ratios[srt].astype(np.float32),
                           amax[srt].astype(np.float32), time.perf_counter() - t0)


def _db_path(params: DatabaseParams, catalogue_fingerprint: str) -> Path:
    blob = json.dumps([_DB_VERSION, params.__dict__, catalogue_fingerprint], sort_keys=True)
    h = hashlib.sha256(blob.encode()).hexdigest()[:16]
    return cache_dir() / f"star_patterns_fov{params.fov_deg:g}_{h}.npz"


@lru_cache(maxsize=8)
def get_database(params: DatabaseParams = DatabaseParams(), catalogue_path: str | None = None,
                 rebuild: bool = False) -> PatternDatabase:
    """The pattern database for ``params``: loaded from the on-disk cache, else built once
    (a few seconds) and saved there (atomic write)."""
    cat = load_catalogue(catalogue_path)
    path = _db_path(params, cat.fingerprint.split("@")[0])
    if path.is_file() and not rebuild:
        with np.load(path) as z:
            u, patterns = z["star_u_eci"], z["patterns"].astype(np.int32)
            ratios, amax = _ratios(_pattern_angles(u[patterns]))
            return PatternDatabase(params, z["star_hr"], u, patterns, z["keys"], ratios.astype(np.float32),
                                   amax.astype(np.float32), float(z["build_time_s"]), path, True)
    db = build_database(params, cat)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".tmp{os.getpid()}.npz")
    small = np.int16 if len(db.star_hr) < 32767 else np.int32
    np.savez(tmp, star_hr=db.star_hr, star_u_eci=db.star_u_eci, patterns=db.patterns.astype(small),
             keys=db.keys, build_time_s=db.build_time_s)
    os.replace(tmp, path)
    db.path = path
    return db


@lru_cache(maxsize=8)
def _verify_catalogue(epoch_year: float, vmag_max: float, catalogue_path: str | None):
    cat = merge_close_stars(load_catalogue(catalogue_path, epoch_year=epoch_year), _MERGE_RAD)
    cat = cat.brighter_than(vmag_max)
    return cat, cKDTree(cat.u_eci)


@dataclass
class StarSolution:
    """A verified star-field solution.

    R_eci_from_camera (3x3); camera: the input camera with the fitted focal length (and k1);
    cov_theta_rad2: 3x3 covariance of the attitude right perturbation (camera frame, rad^2,
    roll about +z is the third axis); sigma_f_px: focal-length 1-sigma (px);
    det_index / cat_hr: matched detections (indices into the detections given) and their
    HR numbers; residuals_px: (m, 2) measured - predicted; p_false: probability of the match
    count by chance (database-size corrected); n_predicted: catalogue stars expected.
    """

    R_eci_from_camera: np.ndarray
    camera: PinholeCamera
    cov_theta_rad2: np.ndarray
    sigma_f_px: float
    det_index: np.ndarray
    cat_hr: np.ndarray
    cat_u_eci: np.ndarray
    residuals_px: np.ndarray
    p_false: float
    n_predicted: int
    solve_time_s: float = 0.0
    n_verified: int = 0
    info: dict = field(default_factory=dict)

    @property
    def matched(self) -> int:
        return len(self.det_index)

    @property
    def rmse_px(self) -> float:
        return float(np.sqrt(np.mean(np.sum(self.residuals_px**2, axis=1))))

    @property
    def rmse_arcsec(self) -> float:
        """RMS of the 2-D residuals converted to angle at the fitted focal length (arcsec)."""
        return self.rmse_px / self.camera.f_px / ARCSEC

    @property
    def fov_deg(self) -> float:
        """Fitted horizontal field of view (deg)."""
        return float(np.degrees(self.camera.fov_x_rad))

    @property
    def ra_dec_roll_deg(self) -> tuple[float, float, float]:
        ra, dec, roll = roll_ra_dec(self.R_eci_from_camera)
        return math.degrees(ra), math.degrees(dec), math.degrees(roll)

    @property
    def q_eci_from_camera(self) -> np.ndarray:
        """Scalar-first (w, x, y, z)."""
        return quat_from_matrix(self.R_eci_from_camera)

    def summary(self) -> dict:
        ra, dec, roll = self.ra_dec_roll_deg
        return {"ra_deg": ra, "dec_deg": dec, "roll_deg": roll, "fov_deg": self.fov_deg,
                "matched": self.matched, "rmse_arcsec": self.rmse_arcsec,
                "q_eci_from_camera": [float(x) for x in self.q_eci_from_camera]}


def _log_binom_sf(m: int, n: int, p: float) -> float:
    """log P(X >= m), X ~ Binomial(n, p)."""
    if m <= 0:
        return 0.0
    if m > n or p <= 0.0:
        return -math.inf
    if p >= 1.0:
        return 0.0
    terms = [math.lgamma(n + 1) - math.lgamma(k + 1) - math.lgamma(n - k + 1)
             + k * math.log(p) + (n - k) * math.log1p(-p) for k in range(m, n + 1)]
    t = max(terms)
    return t + math.log(sum(math.exp(x - t) for x in terms))


def _match(uv_pred: np.ndarray, uv_det: np.ndarray, radius_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Mutual-nearest matches within ``radius_px``: (pred indices, det indices)."""
    if len(uv_pred) == 0 or len(uv_det) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    d2 = np.sum((uv_pred[:, None, :] - uv_det[None, :, :]) ** 2, axis=-1)
    jd = np.argmin(d2, axis=1)
    ip = np.argmin(d2, axis=0)
    i = np.arange(len(uv_pred))
    ok = (ip[jd] == i) & (d2[i, jd] <= radius_px**2)
    return i[ok], jd[ok]


def _predict(R: np.ndarray, cam: PinholeCamera, vcat, tree) -> tuple[np.ndarray, np.ndarray]:
    """Catalogue stars inside the image: (catalogue indices, predicted uv)."""
    half_diag = 0.5 * cam.fov_diag_rad * 1.05 + 0.01
    idx = np.array(tree.query_ball_point(R[:, 2], 2.0 * math.sin(min(half_diag, 1.5) / 2.0)), int)
    if len(idx) == 0:
        return idx, np.zeros((0, 2))
    uv = cam.project(vcat.u_eci[idx] @ R)
    ok = cam.in_image(uv)
    return idx[ok], uv[ok]


def refine_attitude(R0: np.ndarray, cam: PinholeCamera, uv_meas: np.ndarray, u_eci: np.ndarray,
                    sigma_px, *, fit_f: bool = True, fit_k1: bool = False, iterations: int = 6):
    """Gauss-Newton fit of attitude (right perturbation), focal length and k1 to matched
    stars: minimise ``sum |uv_meas - uv(R, f, k1)|^2 / sigma^2`` (model
    :func:`fgnav.vision.attitude.star_pixel_model`). Returns (R, camera, covariance of
    [theta (3), f, k1] scaled by the a-posteriori variance factor, residuals (m, 2) px)."""
    R = np.asarray(R0, float).copy()
    f, k1 = cam.f_px, cam.k1
    w = 1.0 / np.broadcast_to(np.asarray(sigma_px, float), (len(uv_meas),)) ** 2
    cols = [True, True, True, fit_f, fit_k1]
    for _ in range(iterations):
        uv, Ht, Hf, Hk = star_pixel_model(R, f, k1, u_eci, cam.cx, cam.cy)
        J = np.concatenate([Ht, Hf[:, :, None], Hk[:, :, None]], axis=2)[:, :, cols].reshape(-1, sum(cols))
        e = (uv_meas - uv).reshape(-1)
        W = np.repeat(w, 2)
        N = J.T @ (W[:, None] * J)
        dx = np.linalg.solve(N, J.T @ (W * e))
        R = R @ so3_exp(dx[:3])
        k = 3
        if fit_f:
            f += dx[k]
            k += 1
        if fit_k1:
            k1 += dx[k]
        if np.max(np.abs(dx[:3])) < 1e-10:
            break
    cam2 = cam.with_focal_px(f)
    if fit_k1:
        cam2 = replace(cam2, k1=float(k1))
    uv, Ht, Hf, Hk = star_pixel_model(R, f, k1, u_eci, cam.cx, cam.cy)
    J = np.concatenate([Ht, Hf[:, :, None], Hk[:, :, None]], axis=2)[:, :, cols].reshape(-1, sum(cols))
    res = uv_meas - uv
    W = np.repeat(w, 2)
    dof = max(2 * len(uv_meas) - sum(cols), 1)
    s02 = float(np.sum(W * res.reshape(-1) ** 2)) / dof
    cov = np.linalg.inv(J.T @ (W[:, None] * J)) * s02
    return R, cam2, cov, res


_PERMS = np.array(list(itertools.permutations(range(4))), int)


def _best_permutation(ang_img: np.ndarray, u_cat: np.ndarray) -> np.ndarray:
    """Permutation p such that catalogue star p[k] corresponds to image star k."""
    up = u_cat[_PERMS]  # (24, 4, 3)
    a = _pattern_angles(up)
    err = np.max(np.abs(a / a.sum(-1, keepdims=True) - ang_img / ang_img.sum()), axis=-1)
    return _PERMS[int(np.argmin(err))]


def solve_lost_in_space(uv_px: np.ndarray, camera_guess: PinholeCamera, *, sigma_px=None,
                        fov_tolerance: float = 0.1, database: PatternDatabase | None = None,
                        epoch_year: float = 2000.0, n_pattern_stars: int = 14,
                        n_verify_stars: int = 60, vmag_verify: float = 6.5,
                        ratio_tol: float = 0.01, match_radius_frac: float = 0.01,
                        final_radius_px: float = 3.0, min_matches: int = 6,
                        false_match_max: float = 1e-5, fit_k1: bool = False,
                        max_verifications: int = 2000, catalogue_path: str | None = None,
                        v_observer_bcrs_mps=None) -> StarSolution:
    """Identify stars with no attitude prior and the focal length known to +-fov_tolerance.

    uv_px : (N, 2) star centroids sorted by decreasing brightness (pixels, OpenCV convention);
    camera_guess : image size, principal point and the approximate focal length;
    sigma_px : centroid 1-sigma (px), scalar or (N,) (default 0.3 px; only relative weights
    matter for the attitude, the covariance uses the a-posteriori variance factor);
    epoch_year : observation epoch for proper motion (Julian years);
    v_observer_bcrs_mps : (3,) m/s, optional: the camera's barycentric velocity (the Earth's,
    ``factors.aberration.earth_velocity_bcrs_mps``, plus the spacecraft's best known one);
    the attitude is then fitted to the stars' apparent directions (stellar aberration,
    ``factors.aberration``; Urban & Seidelmann 2013, eq. 7.40), not the catalogue's, which
    would turn it by the aberration (~20-27 arcsec; identification tolerates that either way).
    The solution's ``u_eci`` stays the catalogue directions.
    Raises :class:`StarIdentificationError` if no candidate verifies.
    """
    t0 = time.perf_counter()
    uv_all = np.asarray(uv_px, float).reshape(-1, 2)
    sig_all = np.broadcast_to(np.asarray(0.3 if sigma_px is None else sigma_px, float), (len(uv_all),))
    if len(uv_all) < 4:
        raise StarIdentificationError(f"need at least 4 detected stars, got {len(uv_all)}")
    if database is None:
        database = get_database(DatabaseParams(fov_deg=database_fov_for(
            math.degrees(camera_guess.fov_x_rad), fov_tolerance)), catalogue_path)
    db = database
    vcat, vtree = _verify_catalogue(float(epoch_year), float(vmag_verify), catalogue_path)
    u_ref = vcat.u_eci                 # the directions the attitude is fitted to
    if v_observer_bcrs_mps is not None:
        u_ref, _ = apparent_direction(u_ref, np.broadcast_to(
            np.asarray(v_observer_bcrs_mps, float), u_ref.shape))
    nb = _n_bins(db.params.ratio_bin)
    f0 = camera_guess.f_px
    pmax = db.params.pattern_max_rad

    # candidate image patterns from the brightest stars, brightest combinations first
    K = min(n_pattern_stars, len(uv_all))
    rays = camera_guess.pixel_to_ray(uv_all[:K])
    combos = np.array(list(itertools.combinations(range(K), 4)), int)
    combos = combos[np.lexsort((combos.sum(1), combos.max(1)))]
    ang = _pattern_angles(rays[combos])
    r_img, amax_img = _ratios(ang)
    ok = amax_img / (1.0 + fov_tolerance) <= pmax
    combos, ang, r_img, amax_img = combos[ok], ang[ok], r_img[ok], amax_img[ok]
    lo = np.floor((r_img - ratio_tol) / db.params.ratio_bin).astype(np.int64)
    hi = np.floor((r_img + ratio_tol) / db.params.ratio_bin).astype(np.int64)
    span = int(np.max(hi - lo)) + 1 if len(lo) else 1
    offs = np.array(list(itertools.product(range(span), repeat=5)), np.int64)  # (O, 5)
    bins = lo[:, None, :] + offs[None, :, :]
    valid = np.all(bins <= hi[:, None, :], axis=-1)
    keys = _key(bins, nb)
    a = np.searchsorted(db.keys, keys, "left")
    b = np.searchsorted(db.keys, keys, "right")
    cnt = np.where(valid, b - a, 0)
    ci, oi = np.nonzero(cnt)
    if len(ci):
        starts, counts = a[ci, oi], cnt[ci, oi]
        rep_c = np.repeat(ci, counts)
        offs_in = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        pidx = np.repeat(starts, counts) + offs_in
        # ratio and scale consistency
        good = np.all(np.abs(db.ratios[pidx] - r_img[rep_c]) <= ratio_tol, axis=1)
        scale = amax_img[rep_c] / db.max_angle_rad[pidx]  # = f_true / f0 approx
        good &= (scale >= 1.0 - fov_tolerance * 1.05) & (scale <= 1.0 + fov_tolerance * 1.05)
        rep_c, pidx = rep_c[good], pidx[good]
        err = np.max(np.abs(db.ratios[pidx] - r_img[rep_c]), axis=1)
        order = np.lexsort((err, rep_c))
        rep_c, pidx = rep_c[order], pidx[order]
    else:
        rep_c = pidx = np.zeros(0, int)

    uv_v = uv_all[:n_verify_stars]
    W, H = camera_guess.width_px, camera_guess.height_px
    n_verified = 0
    tried = set()
    for c, p in zip(rep_c, pidx):
        if n_verified >= max_verifications:
            break
        if (int(c), int(p)) in tried:
            continue
        tried.add((int(c), int(p)))
        n_verified += 1
        img4 = combos[c]
        cat4 = db.patterns[p]
        perm = _best_permutation(ang[c], db.star_u_eci[cat4])
        u_cat = db.star_u_eci[cat4[perm]]
        a_cat = _pattern_angles(u_cat)
        f1 = f0 * float(np.sum(ang[c]) / np.sum(a_cat))
        cam1 = camera_guess.with_focal_px(f1)
        b_cam = cam1.pixel_to_ray(uv_all[img4])
        sol = wahba_svd(b_cam, u_cat)
        R = sol.R_ref_from_body
        resid = np.max(np.linalg.norm(u_cat - b_cam @ R.T, axis=1))
        if resid > 3.0 * ratio_tol * np.max(a_cat):
            continue
        # verification
        idx, uvp = _predict(R, cam1, vcat, vtree)
        r0 = match_radius_frac * W
        ip, jd = _match(uvp, uv_v, r0)
        if len(ip) < min_matches:
            continue
        R2, cam2, cov, res = refine_attitude(R, cam1, uv_v[jd], u_ref[idx[ip]], sig_all[jd])
        idx, uvp = _predict(R2, cam2, vcat, vtree)
        rfin = max(final_radius_px, 4.0 * float(np.sqrt(np.mean(res**2))))
        ip, jd = _match(uvp, uv_v, rfin)
        n_pred = len(idx)
        p1 = min(1.0, len(uv_v) * math.pi * rfin**2 / (W * H))
        log_pf = _log_binom_sf(len(ip), n_pred, p1) + math.log(max(len(db), 1))
        if len(ip) < min_matches or log_pf > math.log(false_match_max):
            continue
        for _ in range(2):
            R2, cam2, cov, res = refine_attitude(R2, cam2, uv_v[jd], u_ref[idx[ip]], sig_all[jd],
                                                 fit_k1=fit_k1)
            idx, uvp = _predict(R2, cam2, vcat, vtree)
            ip, jd = _match(uvp, uv_v, rfin)
        R2, cam2, cov, res = refine_attitude(R2, cam2, uv_v[jd], u_ref[idx[ip]], sig_all[jd],
                                             fit_k1=fit_k1)
        rn = np.linalg.norm(res, axis=1)
        keep = rn <= 5.0 * np.median(rn)  # outliers: > ~6 sigma for Gaussian residuals
        if not np.all(keep) and keep.sum() >= min_matches:
            ip, jd = ip[keep], jd[keep]
            R2, cam2, cov, res = refine_attitude(R2, cam2, uv_v[jd], u_ref[idx[ip]], sig_all[jd],
                                                 fit_k1=fit_k1)
        log_pf = _log_binom_sf(len(ip), len(idx), p1) + math.log(max(len(db), 1))
        return StarSolution(R2, cam2, cov[:3, :3], float(math.sqrt(cov[3, 3])), jd, vcat.hr[idx[ip]],
                            vcat.u_eci[idx[ip]], res, float(math.exp(min(log_pf, 0.0))), len(idx),
                            time.perf_counter() - t0, n_verified,
                            {"image_pattern": img4.tolist(), "catalogue_pattern_hr": db.star_hr[cat4[perm]].tolist(),
                             "match_radius_px": rfin, "database": str(db.path) if db.path else None})
    raise StarIdentificationError(
        f"no star pattern verified ({len(uv_all)} stars, {n_verified} candidates tried, "
        f"FOV {math.degrees(camera_guess.fov_x_rad):.2f} deg +-{100 * fov_tolerance:.0f}%)")
