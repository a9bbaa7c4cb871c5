"""Inter-satellite rows of a formation's log as graph families (``factors.isl`` models).

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

from factors.geometry import so3_exp
from fgnav.errors import UserError
from fgnav.io.log_spacecraft import ISL_KINDS, spacecraft_index

__all__ = ["isl_values", "isl_families", "clock_pair"]


def clock_pair(a: int, b: int) -> tuple[int, int, float]:
    """The pair (first, second) of spacecraft indices ``a`` (receiver) and ``b`` and the sign
    ``s`` of its clock in the receiver's pseudorange: +1 when the receiver is the first."""
    return (a, b, 1.0) if a < b else (b, a, -1.0)


def _attitudes(log, k_of_row):
    """(spacecraft index, epoch index) -> R_eci_from_body (3, 3) from the attitude rows."""
    from fgnav.models.registry import ATTITUDE

    i = np.flatnonzero(np.asarray(log.kind) == ATTITUDE.kind)
    sc = spacecraft_index(log)[i]
    R = so3_exp(np.asarray(log.xyz, dtype=float)[i])
    return {(int(s), int(k)): R[j] for j, (s, k) in enumerate(zip(sc, k_of_row[i]))}


def isl_values(log, i, k_of_row=None) -> dict:
    """The values of inter-satellite rows ``i`` of ``log``: ``rho_m`` (M,) the measured range
    (or carrier range), ``sign`` (M,), ``R_rx``, ``R_tx`` (M, 3, 3), ``a_rx``, ``a_tx``
    (M, 3) lever arms (m, body), and the per-row variable names ``var:orbit``,
    ``var:orbit_tx``, ``var:clock`` (and ``var:ambiguity`` for carrier rows)."""
    from fgnav.models.variables import orbit_variable

    i = np.asarray(i, dtype=int)
    if k_of_row is None:
        k_of_row = np.unique(np.asarray(log.t_s, dtype=float), return_inverse=True)[1]
    ids = log.spacecraft
    sc = spacecraft_index(log)
    rx = sc[i]
    tx = np.asarray(log.extra["tx_spacecraft"], dtype=float)[i].astype(int)
    att = _attitudes(log, k_of_row)
    M = len(i)
    out = {"rho_m": np.asarray(log.xyz, dtype=float)[i, 0], "sign": np.empty(M),
           "R_rx": np.tile(np.eye(3), (M, 1, 1)), "R_tx": np.tile(np.eye(3), (M, 1, 1)),
           "a_rx": np.zeros((M, 3)), "a_tx": np.zeros((M, 3))}
    names = {"clock": [], "ambiguity": []}
    orbit_names = np.array([orbit_variable(s, name).name for s, name in enumerate(ids)])
    carrier = np.asarray(log.kind)[i] == ISL_KINDS[1]
    for j, row in enumerate(i.tolist()):
        a, b, s = clock_pair(int(rx[j]), int(tx[j]))
        out["sign"][j] = s
        names["clock"].append(f"clock_{ids[a]}_{ids[b]}")
        ends = []
        for end, s_idx, col in (("rx", int(rx[j]), "rx_antenna"), ("tx", int(tx[j]), "tx_antenna")):
            code = log.extra[col][row]
            ant = "" if np.isnan(code) else log.antenna_names[int(code)]
            ends.append(f"{ids[s_idx]}-{ant or 'cm'}")
            if not ant:
                continue
            arm = log.antennas[(ids[s_idx], ant)]
            out[f"a_{end}"][j] = arm
            R = att.get((s_idx, int(k_of_row[row])))
            if R is None:
                if np.any(arm != 0):
                    raise UserError(
                        f"{log.path}, line {int(log.line[row])}: the link's {col} '{ant}' has a "
                        f"lever arm, but spacecraft '{ids[s_idx]}' has no attitude row at this "
                        f"epoch: add an 'attitude' row for it at the same epoch")
                continue
            out[f"R_{end}"][j] = R
        names["ambiguity"].append(f"{ends[1]}_to_{ends[0]}" if carrier[j] else "")
    out["var:orbit"] = orbit_names[rx]
    out["var:orbit_tx"] = orbit_names[tx]
    out["var:clock"] = np.array(names["clock"])
    if carrier.all():
        out["var:ambiguity"] = np.array([f"ambiguity_{n}" for n in names["ambiguity"]])
    return out


def isl_families(log, k_of_row):
    """The inter-satellite families of a formation's log and the variables they add (the
    pairs' clocks, the carrier links' ambiguities), in a fixed order: ``({kind: Family},
    [Variable, ...])``."""
    from fgnav.formation.joint import ambiguity_variable, clock_variable
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
        a, b = _pair_ids(name, log.spacecraft)
        out.append(clock_variable(a, b, j))
    for j, name in enumerate(sorted(ambiguities)):
        out.append(ambiguity_variable(name[len("ambiguity_"):], j))
    return fams, out


def _pair_ids(clock_name: str, ids) -> tuple[str, str]:
    """The two spacecraft ids of a clock variable's name ``clock_<a>_<b>``."""
    for a in ids:
        for b in ids:
            if clock_name == f"clock_{a}_{b}":
                return a, b
    raise ValueError(clock_name)
