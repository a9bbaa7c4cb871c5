"""True values of simulated model parameters, written beside ``truth.oem``.

``fgnav simulate`` writes :data:`TRUTH_REFRACTION_BIAS_CSV` when the pass has refraction
rows and the scenario's refraction sensor has an atmosphere-model bias (the sensor keys
``model_bias_m``, ``model_bias_drift_m_per_h``, ``model_bias_random_walk_m_per_sqrt_h``;
:func:`fgnav.simulate.refraction_sim.refraction_bias_path_m`), and
:data:`TRUTH_ATTITUDE_CSV` when the pass has body-frame rows (the true ``R_eci_from_body``
of the attitude plan as a rotation vector ``att_x, att_y, att_z`` in rad, the components of
the ``attitude`` graph variable). ``fgnav smooth --truth`` reads ``truth_<variable>.csv``
beside the truth OEM (:func:`fgnav.pipeline.read_truth_variables`); ``fgnav report`` the
attitude one for its attitude error plot.

Format
------
A UTF-8 CSV file. Lines whose first non-blank character is ``#`` are comments; blank lines
are ignored. The first other line is the header ``epoch,<name>[,<name>...]``: ``epoch``
then one column per parameter, each named with its unit (``refraction_bias_m``, metres).
Every row has one field per column: the epoch, ISO-8601 UTC ending in ``Z`` (as in the
measurement log, :mod:`fgnav.io.log_csv`), then finite decimal numbers. Epochs increase
strictly. One row per truth epoch of ``truth.oem``.
"""

from __future__ import annotations

import math
import re

import numpy as np

from fgnav.errors import InputFormatError, UserError
from fgnav.io.atomic import atomic_writer
from fgnav.io.text import csv_records, finite_number, read_utf8_text
from fgnav.time import add_seconds, format_utc, parse_utc

__all__ = ["TRUTH_REFRACTION_BIAS_CSV", "TRUTH_ATTITUDE_CSV", "TRUTH_ATTITUDE_COLUMNS",
           "write_truth_params_csv", "read_truth_params_csv"]

TRUTH_REFRACTION_BIAS_CSV = "truth_refraction_bias.csv"
"""File name of the true atmosphere-model bias, columns ``epoch,refraction_bias_m``."""

TRUTH_ATTITUDE_CSV = "truth_attitude.csv"
"""File name of the true attitude, columns ``epoch,att_x,att_y,att_z``: the rotation vector
(rad) of ``R_eci_from_body``."""

TRUTH_ATTITUDE_COLUMNS = ("att_x", "att_y", "att_z")
"""The columns of :data:`TRUTH_ATTITUDE_CSV` (the ``attitude`` variable's components)."""

_NAME_RE = re.compile(r"^[a-z][a-z0-9_]*$")
_EPOCH_EXPECTED = "an ISO-8601 UTC epoch 'YYYY-MM-DDTHH:MM:SS[.f]Z'"


def write_truth_params_csv(path, epoch0, t_s, params: dict, *, comments=()) -> None:
    """Write ``params`` (name -> (N,) values at ``t_s`` seconds after ``epoch0``) atomically.

    Names must be lower-case identifiers ending in their unit (``refraction_bias_m``);
    values are written as the shortest decimal that round-trips exactly.
    """
    t = np.asarray(t_s, dtype=float)
    cols = {}
    for name, v in params.items():
        v = np.asarray(v, dtype=float).reshape(-1)
        if not _NAME_RE.match(name) or name == "epoch":
            raise UserError(f"write_truth_params_csv: bad column name {name!r}")
        if v.shape != t.shape or not np.all(np.isfinite(v)):
            raise UserError(f"write_truth_params_csv: column {name!r} needs {t.size} finite "
                            f"values, got shape {v.shape}")
        cols[name] = v
    ns = add_seconds(epoch0, t).astype(np.int64)
    out = ["# fgnav truth of simulated model parameters (see fgnav.io.truth_params)\n"]
    out += [f"# {c}\n" for c in comments]
    out.append(",".join(["epoch", *cols]) + "\n")
    for i in range(t.size):
        epoch = format_utc(np.datetime64(int(ns[i]), "ns"), "us" if ns[i] % 1000 == 0 else "ns")
        out.append(",".join([epoch] + [repr(float(v[i])) for v in cols.values()]) + "\n")
    with atomic_writer(path, "w") as f:
        f.write("".join(out))


def read_truth_params_csv(path) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Read a file of :func:`write_truth_params_csv`: ``(epochs datetime64[ns] (N,),
    {name: (N,) float})``. A deviation from the format (module docstring) is an
    :class:`~fgnav.errors.InputFormatError` naming the line and column."""
    text = read_utf8_text(path, "a truth-parameter CSV file")
    header, epochs, rows = None, [], []
    for lineno, s, fields in csv_records(text):
        if header is None:
            if fields[0] != "epoch" or len(fields) < 2 or len(set(fields)) != len(fields) or \
                    not all(_NAME_RE.match(f) for f in fields[1:]):
                raise InputFormatError(path, lineno, None, "a header 'epoch,<name>[,<name>...]' "
                                       "(distinct lower-case names, e.g. refraction_bias_m)", s)
            header = fields
            continue
        if len(fields) != len(header):
            raise InputFormatError(path, lineno, None, f"{len(header)} comma-separated fields "
                                   f"({','.join(header)})", s)
        try:
            if not fields[0].endswith("Z"):
                raise ValueError
            t = parse_utc(fields[0])
        except (ValueError, OverflowError):
            raise InputFormatError(path, lineno, "epoch", _EPOCH_EXPECTED, fields[0]) from None
        if epochs and not t > epochs[-1]:
            raise InputFormatError(path, lineno, "epoch", f"an epoch after the previous row's "
                                   f"{format_utc(epochs[-1])}", fields[0])
        row = []
        for name, f in zip(header[1:], fields[1:]):
            x = finite_number(f)
            if not math.isfinite(x):
                raise InputFormatError(path, lineno, name, "a finite decimal number", f)
            row.append(x)
        epochs.append(t)
        rows.append(row)
    if header is None or not rows:
        raise InputFormatError(path, None, None, "a header 'epoch,<name>...' and at least one "
                               "row", "no rows" if header else "no header")
    values = np.array(rows, dtype=float).reshape(len(rows), len(header) - 1)
    return (np.array(epochs, dtype="datetime64[ns]"),
            {name: values[:, j].copy() for j, name in enumerate(header[1:])})
