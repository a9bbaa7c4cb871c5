"""The batch route and the iSAM2 route linearize every registered measurement model the same way.

Batch hands GTSAM pre-whitened rows built in bulk (``fgnav.graph.linearize_all`` over the
models' vectorized residuals); iSAM2 and the fixed-lag smoother linearize one GTSAM factor per
row (``fgnav.graph.factors_for_rows``, the models' ``factors/`` adapters). Both must give the
same whitened Jacobian and right-hand side for every model that enters the graphs, on every
variable it touches (the refraction bias too), at a state off the truth, or the online and
batch answers drift apart.
"""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from fgnav.graph import factors_for_rows, linearize_family
from fgnav.measurements import build_pass, with_estimates
from fgnav.models.registry import MODELS
from fgnav.simulate import faults as F
from fgnav.sun_earth_moon import preprocess_log

SCENARIOS = {  # which built-in scenario carries each family
    "gto-transfer": ("prior_position", "prior_velocity", "earth_direction"),
    "geo-limb": ("limb_radius",),
    "leo-sun-earth-moon": ("altitude", "earth_direction"),
    "refraction-leo": ("refraction",),
}
ESTIMATES = {"refraction-leo": ("refraction-bias",)}  # graph variables beyond the orbit state


def test_every_model_that_enters_the_graphs_is_covered():
    covered = {k for kinds in SCENARIOS.values() for k in kinds}
    solved = {k for k, m in MODELS.items() if m.solved}
    assert solved <= covered, f"add a scenario carrying {sorted(solved - covered)} to SCENARIOS"


def _cases():
    for scenario, kinds in SCENARIOS.items():
        for kind in kinds:
            yield pytest.param(scenario, kind, (), id=f"{scenario}-{kind}")
            for est in ESTIMATES.get(scenario, ()):
                yield pytest.param(scenario, kind, (est,), id=f"{scenario}-{kind}-{est}")


@pytest.mark.parametrize("scenario, kind, estimate", _cases())
def test_batch_and_isam2_routes_give_the_same_whitened_rows(scenario, kind, estimate):
    log, t, x = F.clean(scenario, duration_h=0.5)
    if len(log.select("sun_direction_body")):  # body-frame rows: to ECI by TRIAD attitude
        log = preprocess_log(log)[0]
    p = with_estimates(build_pass(log), estimate)
    lay = p.layout
    fam = p.families[kind]
    rng = np.random.default_rng(7)
    # a state off the truth: 2 km and 1 m/s per axis (and 50 units on any further variable),
    # so the Jacobians are not evaluated at the zero-residual point
    X_eval = lay.initial(x[np.searchsorted(t, p.t_s)])
    X_eval += rng.normal(0, 1, X_eval.shape) * np.array([2e3] * 3 + [1.0] * 3 + [50.0] * (lay.n - 6))
    k_b, A_b, b_b, _ = linearize_family(p, kind, fam, X_eval)
    rows = np.unique(np.linspace(0, len(fam) - 1, 6).astype(int))
    for j in rows:
        k = int(fam.k[j])
        factor, = factors_for_rows(p, kind, np.array([j]), k, None, X_eval[k, :6])
        values = gtsam.Values()
        for v in lay.variables:
            values.insert(v.key(k), X_eval[k, lay.slices[v.name]])
        lin = factor.linearize(values)
        A_i, b_i = lin.jacobian()
        # the factor's columns in the layout's order (GTSAM orders them by key)
        cols = {int(key): i for i, key in enumerate(lin.keys())}
        A_layout = np.zeros((A_i.shape[0], lay.n))
        off = np.cumsum([0] + [len(values.atVector(int(key))) for key in lin.keys()])
        for v in lay.variables:
            if v.key(k) in cols:
                i = cols[v.key(k)]
                A_layout[:, lay.slices[v.name]] = A_i[:, off[i]:off[i + 1]]
        assert int(k_b[j]) == k
        scale = max(1.0, np.abs(A_b[j]).max())
        np.testing.assert_allclose(A_layout, A_b[j], rtol=1e-9, atol=1e-12 * scale,
                                   err_msg=f"{kind} row {j}: whitened Jacobian")
        np.testing.assert_allclose(b_i, b_b[j], rtol=1e-9, atol=1e-9,
                                   err_msg=f"{kind} row {j}: whitened right-hand side")
