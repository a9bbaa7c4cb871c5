"""The star front end's attitude sigma on a real frame from a second camera (OreSat star
tracker, ../shared/data/star_images_oresat/, ~17 deg, Bayer, hot pixels; no attitude truth),
through ``scripts/study_oresat_attitude.py`` (docs/epic.md): split-half chi-squares.

Measured: 39 stars matched, RMS residual 26.5 arcsec against a centroid sigma of 2.5 arcsec;
the a-posteriori-scaled sigma (2.7, 2.7, 26 arcsec) covers the random part (random halves:
mean chi2 2.94 of 3, 4 % of 200 splits above the 95 % point); halves split top/bottom
differ by 171 arcsec in roll against a sigma of 61 (chi2 8.5, 9.3 with k1): a
field-dependent error the covariance does not contain."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from shared_data import SHARED_DATA

ROOT = Path(__file__).resolve().parents[1]


def _study_module():
    spec = importlib.util.spec_from_file_location("study_oresat_attitude",
                                                  ROOT / "scripts" / "study_oresat_attitude.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


STUDY = _study_module()
IMAGE = STUDY.find_image(str(SHARED_DATA / "star_images_oresat" / "capture-2022-09-25-09-40-25.png")) \
    or STUDY.find_image()
pytestmark = pytest.mark.skipif(IMAGE is None, reason="OreSat frame not present (../shared/data)")


@pytest.fixture(scope="module")
def result():
    return STUDY.study(IMAGE, splits=60)


def test_solved_and_random_error_covered(result):
    for m in result["models"]:
        assert m["matched"] >= 30 and m["rmse_arcsec"] < 40.0
        assert abs(m["fov_deg"] - 17.15) < 0.1
        # the centroid sigma alone is ~10x too small: the a-posteriori scaling covers it
        assert m["rmse_arcsec"] > 5 * m["centroid_sigma_arcsec"]
        assert 1.8 < m["random_split_mean_chi2"] < 4.5
        assert m["random_split_frac_over_95"] < 0.15


def test_field_dependent_error_is_measured(result):
    """Spatial halves: bounded, and the top/bottom split is beyond the 95 % point of chi2(3)
    (7.8) -- the finding docs/epic.md states; a change that models it updates both."""
    for m in result["models"]:
        chi = {k: v["chi2"] for k, v in m["spatial"].items()}
        assert max(chi.values()) < 20.0
        assert chi["top/bottom"] > 7.8
