"""The batch route and the iSAM2 route linearize every measurement family the same way.

Batch hands GTSAM pre-whitened rows built in bulk (``fgnav.graph.LINEARIZERS``); iSAM2 and
the fixed-lag smoother linearize one ``gtsam.CustomFactor`` per row
(``fgnav.graph.factors_for_rows``). Both must give the same whitened Jacobian and right-hand
side for every family, at a state off the truth, or the online and batch answers drift apart.
"""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from fgnav.graph import LINEARIZERS, factors_for_rows
from fgnav.measurements import build_pass
from fgnav.simulate import faults as F
from fgnav.sun_earth_moon import preprocess_log

X = gtsam.symbol_shorthand.X

SCENARIOS = {  # which built-in scenario carries each family
    "gto-transfer": ("prior_position", "prior_velocity", "earth_direction"),
    "geo-limb": ("limb_radius",),
    "leo-sun-earth-moon": ("altitude", "earth_direction"),
    "refraction-leo": ("refraction",),
}


def _cases():
    for scenario, kinds in SCENARIOS.items():
        for kind in kinds:
            yield pytest.param(scenario, kind, id=f"{scenario}-{kind}")


@pytest.mark.parametrize("scenario, kind", _cases())
def test_batch_and_isam2_routes_give_the_same_whitened_rows(scenario, kind):
    log, t, x = F.clean(scenario, duration_h=0.5)
    if len(log.select("sun_direction_body")):  # body-frame rows: to ECI by TRIAD attitude
        log = preprocess_log(log)[0]
    p = build_pass(log)
    fam = p.families[kind]
    rng = np.random.default_rng(7)
    # a state off the truth: 2 km and 1 m/s per axis, so the Jacobians are not evaluated at
    # the zero-residual point
    X_eval = x[np.searchsorted(t, p.t_s)] + rng.normal(0, 1, (p.n_epochs, 6)) * np.array(
        [2e3, 2e3, 2e3, 1.0, 1.0, 1.0])
    k_b, A_b, b_b, _ = LINEARIZERS[kind](fam, X_eval)
    rows = np.unique(np.linspace(0, len(fam) - 1, 6).astype(int))
    for j in rows:
        k = int(fam.k[j])
        factor, = factors_for_rows(kind, fam, np.array([j]), X(k), None, X_eval[k])
        values = gtsam.Values()
        values.insert(X(k), X_eval[k])
        A_i, b_i = factor.linearize(values).jacobian()
        assert int(k_b[j]) == k
        scale = max(1.0, np.abs(A_b[j]).max())
        np.testing.assert_allclose(A_i, A_b[j], rtol=1e-9, atol=1e-12 * scale,
                                   err_msg=f"{kind} row {j}: whitened Jacobian")
        np.testing.assert_allclose(b_i, b_b[j], rtol=1e-9, atol=1e-9,
                                   err_msg=f"{kind} row {j}: whitened right-hand side")
