"""Star catalogue: load the derived BSC5 file, apply proper motion, give ECI unit vectors.

The catalogue lives at ``fgnav/data/catalogue/bsc5.csv``, inside the package (``data/`` at
the top of a checkout links to it; see its README for provenance).
Positions are J2000/FK5 (taken as the ECI/EME2000 frame) at epoch J2000.0; proper motion is
applied linearly in (RA, Dec):
``ra(t) = ra0 + pmra* / cos(dec0) * dt``, ``dec(t) = dec0 + pmdec * dt``, dt in Julian years
from J2000.0 (pmra* includes cos(dec)). Unit vectors:
``u_eci = [cos(dec) cos(ra), cos(dec) sin(ra), sin(dec)]``.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from fgnav.errors import InputFormatError, UserError
from fgnav.paths import data_dir
from fgnav.time import parse_utc

__all__ = ["Catalogue", "DATA_DIR", "DEFAULT_CATALOGUE_PATH", "load_catalogue", "radec_to_unit",
           "unit_to_radec", "decimal_year", "merge_close_stars"]

DATA_DIR = data_dir()
DEFAULT_CATALOGUE_PATH = DATA_DIR / "catalogue" / "bsc5.csv"
_MAS = np.pi / 180.0 / 3600.0e3
_COLUMNS = ["hr", "ra_deg", "dec_deg", "vmag", "pmra_mas_yr", "pmdec_mas_yr"]


def radec_to_unit(ra_rad, dec_rad) -> np.ndarray:
    """(RA, Dec) in radians -> unit vectors (..., 3) in the same (equatorial) frame."""
    ra, dec = np.asarray(ra_rad, float), np.asarray(dec_rad, float)
    cd = np.cos(dec)
    return np.stack([cd * np.cos(ra), cd * np.sin(ra), np.sin(dec)], axis=-1)


def unit_to_radec(u) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors (..., 3) -> (RA in [0, 2 pi), Dec in [-pi/2, pi/2]) in radians."""
    u = np.asarray(u, float)
    ra = np.mod(np.arctan2(u[..., 1], u[..., 0]), 2 * np.pi)
    dec = np.arcsin(np.clip(u[..., 2] / np.linalg.norm(u, axis=-1), -1.0, 1.0))
    return ra, dec


def decimal_year(t) -> float:
    """A ``numpy.datetime64`` / ISO string (UTC) -> Julian-year epoch (J2000.0 = 2000.0)."""
    t64 = parse_utc(t) if isinstance(t, str) else np.datetime64(t, "ns")  # 23:59:60 too
    days = (t64 - np.datetime64("2000-01-01T12:00:00", "ns")) / np.timedelta64(1, "D")
    return 2000.0 + float(days) / 365.25


@dataclass(frozen=True)
class Catalogue:
    """Stars at one epoch. hr : (N,) HR numbers; ra_rad, dec_rad : (N,) at ``epoch_year``;
    vmag : (N,) V magnitude; u_eci : (N, 3) unit vectors (J2000 equatorial = ECI);
    fingerprint : sha256 prefix of the source file + epoch (keys derived caches)."""

    hr: np.ndarray
    ra_rad: np.ndarray
    dec_rad: np.ndarray
    vmag: np.ndarray
    u_eci: np.ndarray
    epoch_year: float
    fingerprint: str

    def __len__(self) -> int:
        return len(self.hr)

    def subset(self, mask_or_index) -> "Catalogue":
        i = np.asarray(mask_or_index)
        return Catalogue(self.hr[i], self.ra_rad[i], self.dec_rad[i], self.vmag[i], self.u_eci[i],
                         self.epoch_year, self.fingerprint)

    def brighter_than(self, vmag_max: float) -> "Catalogue":
        return self.subset(self.vmag <= vmag_max)


@lru_cache(maxsize=8)
def _read(path: str) -> tuple[np.ndarray, str]:
    p = Path(path)
    if not p.is_file():
        raise UserError(f"star catalogue not found: {p} (build one with: python -m "
                        f"fgnav.vision.catalogue_build --src <Yale BSC5 CSV> --out {p})")
    raw = p.read_bytes()
    lines = raw.decode("utf-8").splitlines()
    header = lines[0].split(",")
    missing = [c for c in _COLUMNS if c not in header]
    if missing:
        raise InputFormatError(p, 1, missing[0], f"header with columns {_COLUMNS}", lines[0])
    col = [header.index(c) for c in _COLUMNS]
    out = np.empty((len(lines) - 1, len(_COLUMNS)))
    for k, line in enumerate(lines[1:]):
        f = line.split(",")
        for j, c in enumerate(col):
            try:
                out[k, j] = float(f[c])
            except (ValueError, IndexError):
                raise InputFormatError(p, k + 2, _COLUMNS[j], "a number",
                                       f[c] if c < len(f) else "") from None
    return out, hashlib.sha256(raw).hexdigest()[:16]


def load_catalogue(path: str | Path | None = None, *, epoch_year: float = 2000.0,
                   vmag_max: float | None = None) -> Catalogue:
    """Load the star catalogue (default ``data/catalogue/bsc5.csv``) at ``epoch_year``
    (Julian years, e.g. ``decimal_year('2019-07-29T20:47:26Z')``), optionally only stars
    with V <= ``vmag_max``. Proper motion applied linearly (module docstring)."""
    arr, sha = _read(str(Path(path) if path is not None else DEFAULT_CATALOGUE_PATH))
    if vmag_max is not None:
        arr = arr[arr[:, 3] <= vmag_max]
    dt = epoch_year - 2000.0
    dec0 = np.radians(arr[:, 2])
    dec = dec0 + arr[:, 5] * _MAS * dt
    ra = np.mod(np.radians(arr[:, 1]) + arr[:, 4] * _MAS * dt / np.maximum(np.cos(dec0), 1e-9), 2 * np.pi)
    return Catalogue(arr[:, 0].astype(np.int64), ra, dec, arr[:, 3].copy(), radec_to_unit(ra, dec),
                     float(epoch_year), f"{sha}@{epoch_year:.3f}")


def merge_close_stars(cat: Catalogue, radius_rad: float) -> Catalogue:
    """Merge stars closer than ``radius_rad`` (e.g. BSC5's separate entries for the two
    components of a close double, which a camera sees as one blob) into one entry per
    group: direction = flux-weighted mean (the photocentre), ``V = -2.5 log10(sum 10^(-0.4 V_i))``,
    HR number and RA/Dec order of the brightest member. Other stars are unchanged."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pairs = cKDTree(cat.u_eci).query_pairs(2.0 * np.sin(radius_rad / 2.0), output_type="ndarray")
    if len(pairs) == 0:
        return cat
    n = len(cat)
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, lab = connected_components(g, directed=False)
    flux = 10.0 ** (-0.4 * cat.vmag)
    u_sum = np.zeros((lab.max() + 1, 3))
    np.add.at(u_sum, lab, flux[:, None] * cat.u_eci)
    f_sum = np.bincount(lab, flux)
    # representative of each group: its brightest member
    order = np.lexsort((cat.vmag, lab))
    first = order[np.r_[True, lab[order][1:] != lab[order][:-1]]]
    first = np.sort(first)
    g_of = lab[first]
    u = u_sum[g_of] / np.linalg.norm(u_sum[g_of], axis=1, keepdims=True)
    ra, dec = unit_to_radec(u)
    return Catalogue(cat.hr[first], ra, dec, -2.5 * np.log10(f_sum[g_of]), u, cat.epoch_year,
                     cat.fingerprint + f"+merge{radius_rad:.3g}")
