"""`fgnav simulate` writes the true attitude of a pass with body-frame rows
(truth_attitude.csv beside truth.oem): the rotation that carries each star's catalogue
direction onto its measured body-frame direction."""

from __future__ import annotations

import numpy as np

from factors.geometry import so3_exp
from fgnav.io.log_csv import read_log
from fgnav.io.truth_params import TRUTH_ATTITUDE_COLUMNS, TRUTH_ATTITUDE_CSV, read_truth_params_csv
from fgnav.models.registry import ATTITUDE_VARIABLE
from fgnav.time import seconds_since


def test_simulated_truth_attitude_explains_the_star_rows(tmp_path):
    from fgnav.cli import main

    out = tmp_path / "pass"
    assert main(["simulate", "geo-limb", "--raw-stars", "--duration-h", "0.25", "--out", str(out),
                 "--quiet"]) == 0
    assert TRUTH_ATTITUDE_COLUMNS == ATTITUDE_VARIABLE.components   # what fgnav smooth reads
    epochs, cols = read_truth_params_csv(out / TRUTH_ATTITUDE_CSV)
    log = read_log(out / "measurements.csv")
    t_truth = np.asarray(seconds_since(epochs, log.epoch0), float)
    R = so3_exp(np.column_stack([cols[c] for c in TRUTH_ATTITUDE_COLUMNS]))
    sel = log.select("star_direction_body")
    assert len(sel) > 50
    k = np.searchsorted(t_truth, log.t_s[sel])
    np.testing.assert_allclose(t_truth[k], log.t_s[sel], atol=1e-6)  # one truth row per epoch
    s = np.column_stack([log.extra[c][sel] for c in ("star_x", "star_y", "star_z")])
    u_pred = np.einsum("nji,nj->ni", R[k], s)                        # R^T s: body frame
    ang_arcsec = np.degrees(np.arccos(np.clip(np.einsum("ni,ni->n", u_pred, log.xyz[sel]), -1, 1))) * 3600
    # 5 arcsec centroid noise (plus at most ~30 arcsec of aberration if the simulator applies it)
    assert np.median(ang_arcsec) < 40.0 and np.max(ang_arcsec) < 120.0
    # a pass without body-frame rows has no attitude truth
    assert main(["simulate", "gto-transfer", "--duration-h", "0.2", "--out", str(tmp_path / "g"),
                 "--quiet"]) == 0
    assert not (tmp_path / "g" / TRUTH_ATTITUDE_CSV).exists()
