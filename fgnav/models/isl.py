"""Inter-satellite links (a formation's log): the ``isl_pseudorange`` and
``isl_carrier_phase`` models, and their rows' values.

Each row binds the orbit of its receiving spacecraft (role ``orbit``), of its transmitting one
(``orbit_tx``), the relative clock of the pair (``clock``,
:func:`fgnav.models.variables.clock_variable`) and, for carrier phase, the link's ambiguity
(``ambiguity``, :func:`fgnav.models.variables.ambiguity_variable`): variables that differ from
row to row, named per row (``values["var:<role>"]``) and turned into block columns by the pass
builder (:func:`fgnav.measurements.build_pass`; then
:meth:`fgnav.models.model.MeasurementModel.evaluate` binds them row by row). Lever arms come
from the log's ``# antenna:`` declarations, the attitudes ``R_eci_from_body`` that turn them
from the spacecraft's ``attitude`` rows at the row's epoch (a link with a lever arm and no
attitude row at its epoch is refused; a centre-of-mass end needs none). The residuals are
``factors.isl``'s: the one-way light-time equation (Montenbruck & Gill 2000, ch. 6) with the
pair's relative clock signed as in Xing et al.'s eq. (1), and the carrier range with its
float ambiguity.
"""

from __future__ import annotations

import numpy as np

from factors.geometry import so3_exp
from factors.isl import (isl_carrier_residual, isl_range_residual, make_isl_carrier_factor,
                         make_isl_range_factor)
from fgnav.errors import UserError
from fgnav.io.log_spacecraft import ISL_KINDS, spacecraft_index
from fgnav.models.attitude import ATTITUDE
from fgnav.models.model import MeasurementModel
from fgnav.models.variables import orbit_variable

__all__ = ["MEASUREMENT_MODELS", "ISL_PSEUDORANGE", "ISL_CARRIER_PHASE", "isl_values", "clock_pair", "pair_ids",
           "ATTITUDE_KIND"]

ATTITUDE_KIND = ATTITUDE.kind
"""The log kind whose rows give a spacecraft's ``R_eci_from_body`` (:data:`fgnav.models.
attitude.ATTITUDE`)."""


def clock_pair(a: int, b: int) -> tuple[int, int, float]:
    """The pair (first, second) of spacecraft indices ``a`` (receiver) and ``b`` and the sign
    ``s`` of its clock in the receiver's pseudorange: +1 when the receiver is the first."""
    return (a, b, 1.0) if a < b else (b, a, -1.0)


def pair_ids(clock_name: str, ids) -> tuple[str, str]:
    """The two spacecraft ids of a clock variable's name ``clock_<a>_<b>``."""
    for a in ids:
        for b in ids:
            if clock_name == f"clock_{a}_{b}":
                return a, b
    raise ValueError(clock_name)


def _attitudes(log, k_of_row):
    """(spacecraft index, epoch index) -> R_eci_from_body (3, 3) from the attitude rows."""
    i = np.flatnonzero(np.asarray(log.kind) == ATTITUDE_KIND)
    sc = spacecraft_index(log)[i]
    R = so3_exp(np.asarray(log.xyz, dtype=float)[i])
    return {(int(s), int(k)): R[j] for j, (s, k) in enumerate(zip(sc, k_of_row[i]))}


def isl_values(log, i, k_of_row=None) -> dict:
    """The values of inter-satellite rows ``i`` of ``log``: ``rho_m`` (M,) the measured range
    (or carrier range), ``sign`` (M,), ``R_rx``, ``R_tx`` (M, 3, 3), ``a_rx``, ``a_tx``
    (M, 3) lever arms (m, body), and the per-row variable names ``var:orbit``,
    ``var:orbit_tx``, ``var:clock`` (and ``var:ambiguity`` for carrier rows)."""
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


def _isl_residual(carrier):
    def residual(fam, v):
        args = (v["orbit"], v["orbit_tx"], fam.values["R_rx"], fam.values["R_tx"],
                fam.values["a_rx"], fam.values["a_tx"], v["clock"][:, 0], fam.values["sign"],
                fam.values["rho_m"])
        if not carrier:
            e, H_rx, H_tx, H_c = isl_range_residual(*args)
            return e, {"orbit": H_rx, "orbit_tx": H_tx, "clock": H_c}
        e, H_rx, H_tx, H_c, H_a = isl_carrier_residual(*args, v["ambiguity"][:, 0])
        return e, {"orbit": H_rx, "orbit_tx": H_tx, "clock": H_c, "ambiguity": H_a}
    return residual


def _isl_model(kind, summary, carrier):
    def factor(fam, j, keys, noise):
        v = fam.values
        args = (keys["orbit"], keys["orbit_tx"], keys["clock"]) + (
            (keys["ambiguity"],) if carrier else ())
        make = make_isl_carrier_factor if carrier else make_isl_range_factor
        return make(*args, v["R_rx"][j], v["R_tx"][j], v["a_rx"][j], v["a_tx"][j], v["sign"][j],
                    v["rho_m"][j], noise)

    return MeasurementModel(kind=kind, dim=1, unit="m", observes_orbit=True, summary=summary,
                            values=isl_values, residual=_isl_residual(carrier), factor=factor,
                            variables=(), range_m=lambda fam: fam.values["rho_m"])


ISL_PSEUDORANGE = _isl_model(ISL_KINDS[0], "one-way inter-satellite pseudorange (m) between "
                             "two spacecraft's antennas, with the pair's clock", carrier=False)
ISL_CARRIER_PHASE = _isl_model(ISL_KINDS[1], "inter-satellite carrier phase times the "
                               "wavelength (m), with the link's float ambiguity", carrier=True)

MEASUREMENT_MODELS = (ISL_PSEUDORANGE, ISL_CARRIER_PHASE)
"""This module's measurement models (assembled by :mod:`fgnav.models.registry`)."""
