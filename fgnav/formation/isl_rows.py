"""Inter-satellite rows of a formation's log as graph families (:mod:`fgnav.models.isl`).

Each ``isl_pseudorange`` / ``isl_carrier_phase`` row binds the orbit of its receiving
spacecraft (role ``orbit``), of its transmitting one (``orbit_tx``), the relative clock of
the pair (``clock``) and, for carrier phase, the link's ambiguity (``ambiguity``): per-row
variable names (``values["var:<role>"]``) that :func:`fgnav.formation.joint.build_formation_pass`
turns into block columns. Lever arms come from the log's ``# antenna:`` declarations, the
attitudes ``R_eci_from_body`` that turn them from the spacecraft's ``attitude`` rows at the
row's epoch (a link with a lever arm and no attitude row at its epoch is refused; a
centre-of-mass end needs none).
"""

from __future__ import annotations

import numpy as np

from fgnav.io.log_spacecraft import ISL_KINDS
from fgnav.models.isl import clock_pair, isl_values, pair_ids
from fgnav.models.variables import ambiguity_variable, clock_variable

__all__ = ["isl_values", "isl_families", "clock_pair"]   # (the first and last: fgnav.models.isl)


def isl_families(log, k_of_row):
    """The inter-satellite families of a formation's log and the variables they add (the
    pairs' clocks, the carrier links' ambiguities), in a fixed order: ``({kind: Family},
    [Variable, ...])``."""
    from fgnav.measurements import Family

    kinds = np.asarray(log.kind)
    fams, clocks, ambiguities = {}, {}, {}
    for kind in ISL_KINDS:
        i = np.flatnonzero(kinds == kind)
        if not len(i):
            continue
        values = isl_values(log, i, k_of_row)
        for name in values["var:clock"]:
            clocks.setdefault(str(name), None)
        for name in values.get("var:ambiguity", ()):
            ambiguities.setdefault(str(name), None)
        fams[kind] = Family(k=k_of_row[i], values=values,
                            sigma=np.asarray(log.sigma, dtype=float)[i],
                            line=np.asarray(log.line)[i])
    out = []
    for j, name in enumerate(sorted(clocks)):
        a, b = pair_ids(name, log.spacecraft)
        out.append(clock_variable(a, b, j))
    for j, name in enumerate(sorted(ambiguities)):
        out.append(ambiguity_variable(name[len("ambiguity_"):], j))
    return fams, out

