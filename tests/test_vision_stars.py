"""Star detection/centroiding, the star-field renderer and the catalogue.

Truth for detection is the renderer's true PSF centres (exact pixel-integrated Gaussian PSF),
independent of the centroiding code.
"""

from pathlib import Path

from shared_data import SHARED_DATA  # noqa: E402
import numpy as np
import pytest

from fgnav.errors import InputFormatError, UserError
from fgnav.simulate.star_render import render_star_field
from fgnav.vision.attitude import rotation_from_ra_dec_roll
from fgnav.vision.camera import PinholeCamera
from fgnav.vision.catalogue import (DEFAULT_CATALOGUE_PATH, decimal_year, load_catalogue,
                                    radec_to_unit, unit_to_radec)
from fgnav.vision.stars import detect_stars, estimate_background

SHARED_BSC5 = SHARED_DATA / "stars_bsc5.csv"
CAM = PinholeCamera.from_fov(11.4, 1024, 768)


@pytest.fixture(scope="module")
def cat():
    return load_catalogue()


def _frame(cat, seed, **kw):
    rng = np.random.default_rng(seed)
    R = rotation_from_ra_dec_roll(rng.uniform(0, 2 * np.pi), np.arcsin(rng.uniform(-1, 1)),
                                  rng.uniform(-np.pi, np.pi))
    img, truth = render_star_field(CAM, R, cat, rng, **kw)
    return R, img, truth


def _associate(truth_uv, det_uv, radius_px=1.5):
    d = np.linalg.norm(truth_uv[:, None, :] - det_uv[None, :, :], axis=-1)
    j = np.argmin(d, axis=1)
    return np.min(d, axis=1) < radius_px, j


# --- catalogue -----------------------------------------------------------------------

def test_catalogue_loads_all_bsc5_stars_as_unit_vectors(cat):
    assert len(cat) == 9096
    assert np.allclose(np.linalg.norm(cat.u_eci, axis=1), 1.0, atol=1e-12)
    ra, dec = unit_to_radec(cat.u_eci)
    assert np.allclose(ra, cat.ra_rad, atol=1e-12) and np.allclose(dec, cat.dec_rad, atol=1e-12)
    assert cat.vmag.min() == pytest.approx(-1.46) and (cat.vmag <= 6.5).sum() > 8000


@pytest.mark.skipif(not SHARED_BSC5.is_file(), reason="shared BSC5 file not present")
def test_derived_catalogue_matches_the_source_file(cat):
    src = np.genfromtxt(SHARED_BSC5, delimiter=",", names=True, dtype=None, encoding="utf-8")
    hr = np.array([int(s[2:]) for s in src["id"]])
    order = np.argsort(hr)
    assert np.array_equal(cat.hr, hr[order])
    assert np.allclose(np.degrees(cat.ra_rad), src["ra_deg"][order], atol=2e-6)
    assert np.allclose(cat.vmag, src["vmag"][order])


def test_proper_motion_moves_stars_by_pm_times_dt():
    c0 = load_catalogue(epoch_year=2000.0)
    c1 = load_catalogue(epoch_year=2100.0)
    raw = np.genfromtxt(DEFAULT_CATALOGUE_PATH, delimiter=",", names=True, dtype=None, encoding="utf-8")
    pm_rad_yr = np.hypot(raw["pmra_mas_yr"], raw["pmdec_mas_yr"]) * np.radians(1 / 3.6e6)
    moved = np.arccos(np.clip(np.sum(c0.u_eci * c1.u_eci, axis=1), -1, 1))
    fast = np.argsort(pm_rad_yr)[-20:]  # arcsec/yr movers (61 Cyg, eps Ind, ...)
    far_from_pole = np.abs(c0.dec_rad[fast]) < np.radians(70)
    assert np.allclose(moved[fast][far_from_pole], 100 * pm_rad_yr[fast][far_from_pole], rtol=0.01)
    # JD 2458693.5 is 2019-07-29 0h UTC; J2000.0 = JD 2451545.0
    jd = 2458693.5 + (20 + 47 / 60 + 26 / 3600) / 24
    assert decimal_year("2019-07-29T20:47:26Z") == pytest.approx(2000 + (jd - 2451545.0) / 365.25, abs=1e-9)


def test_catalogue_errors(tmp_path):
    with pytest.raises(UserError, match="not found"):
        load_catalogue(tmp_path / "none.csv")
    bad = tmp_path / "bad.csv"
    bad.write_text("hr,ra_deg,dec_deg,vmag,pmra_mas_yr,pmdec_mas_yr\n1,2,3,4,5,6\n2,x,3,4,5,6\n")
    with pytest.raises(InputFormatError, match="line 3, column 'ra_deg'"):
        load_catalogue(bad)


def test_radec_unit_roundtrip():
    rng = np.random.default_rng(3)
    ra, dec = rng.uniform(0, 2 * np.pi, 50), np.arcsin(rng.uniform(-1, 1, 50))
    ra2, dec2 = unit_to_radec(radec_to_unit(ra, dec))
    assert np.allclose(ra2, ra) and np.allclose(dec2, dec)


# --- renderer --------------------------------------------------------------------------

def test_render_is_deterministic_by_seed_and_truth_projects(cat):
    R, img1, t1 = _frame(cat, 11)
    _, img2, t2 = _frame(cat, 11)
    _, img3, _ = _frame(cat, 12)
    assert img1.dtype == np.uint16 and img1.shape == (768, 1024)
    assert np.array_equal(img1, img2) and np.array_equal(t1.hr, t2.hr)
    assert not np.array_equal(img1, img3)
    # truth pixel positions are the camera projection of the catalogue directions
    rays = CAM.pixel_to_ray(t1.uv_px) @ R.T
    assert np.allclose(rays, t1.u_eci, atol=1e-10)
    assert np.all(np.diff(t1.vmag) >= 0)


def test_render_flux_follows_magnitude(cat):
    R, img, truth = _frame(cat, 5, background_e=0.0, read_noise_e=0.0, bias_adu=0.0, flux_v0_e=2e5)
    det = detect_stars(img)
    ok, j = _associate(truth.uv_px, det.uv_px)
    assert ok.sum() >= 5
    # measured flux ratio follows 10^(-0.4 dV) (Poisson noise only)
    dm = -2.5 * np.log10(det.flux_adu[j[ok]] / truth.flux_e[ok])
    assert np.std(dm) < 0.05 and abs(np.median(dm)) < 0.05


# --- detection + centroiding ---------------------------------------------------------------

def test_centroids_subpixel_and_sigma_estimate(cat):
    errs, zs, n_bright, n_bright_found = [], [], 0, 0
    for seed in range(6):
        _, img, truth = _frame(cat, seed)
        det = detect_stars(img)
        assert np.all(np.diff(det.flux_adu) <= 0)
        ok, j = _associate(truth.uv_px, det.uv_px)
        e = det.uv_px[j[ok]] - truth.uv_px[ok]
        errs.append(e)
        zs.append(e / det.sigma_px[j[ok], None])
        # clearly detectable, not saturated, not touching the border
        unsat = (truth.flux_e < 30000) & (truth.vmag < 6.0) & CAM.in_image(truth.uv_px, margin_px=8)
        n_bright += unsat.sum()
        n_bright_found += (ok & unsat).sum()
    e, z = np.concatenate(errs), np.concatenate(zs)
    assert n_bright_found == n_bright
    rms = np.sqrt(np.mean(e**2, axis=0))
    assert np.all(rms < 0.1), rms  # sub-pixel: PSF sigma 1 px
    assert np.all(np.abs(e.mean(axis=0)) < 0.02)
    # the reported centroid sigma is the right size (conservative by at most ~2x)
    assert 0.2 < np.mean(z**2) < 1.5


def test_background_follows_gradient_and_noise():
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:384, 0:512]
    bg_true = 1000 + 2.0 * xx + 1.0 * yy
    img = bg_true + rng.normal(0, 20, bg_true.shape)
    bg, sig = estimate_background(img)
    assert np.max(np.abs(bg - bg_true)[32:-32, 32:-32]) < 8
    assert np.median(sig) == pytest.approx(20, rel=0.1)


def test_rejects_hot_pixels_saturated_and_edge_blobs(cat):
    rng = np.random.default_rng(7)
    img = rng.normal(1000, 10, (200, 300))
    y, x = np.mgrid[0:200, 0:300]

    def star(u, v, F, s=1.2):
        return F / (2 * np.pi * s * s) * np.exp(-((x - u) ** 2 + (y - v) ** 2) / (2 * s * s))

    img += star(100.3, 80.7, 20000) + star(200.6, 120.2, 15000)
    img += star(150.0, 50.0, 3e6)  # saturated
    img += star(1.0, 100.0, 20000)  # on the edge
    img[30, 40] += 5000  # hot pixels
    img[170, 250] += 8000
    img16 = np.clip(img, 0, 65535).astype(np.uint16)
    det = detect_stars(img16)
    assert len(det) == 2
    assert np.allclose(det.uv_px, [[100.3, 80.7], [200.6, 120.2]], atol=0.05)
    # without the rejections the extra blobs are found
    loose = detect_stars(img16, max_peak_fraction=1.0, edge_margin_px=0, saturation_adu=1e9)
    assert len(loose) == 6


def test_detect_stars_rejects_bad_input():
    with pytest.raises(ValueError):
        detect_stars(np.zeros((3, 4, 5)))
    assert len(detect_stars(np.full((64, 64), 100, np.uint16))) == 0
