"""Helpers the measurement models' ``values`` and residuals share: a log's rows as arrays,
a position-only residual in the models' form, and ephemeris-span errors named by log line."""

from __future__ import annotations

import contextlib

import numpy as np

from factors.errors import EphemerisSpanError
from fgnav.errors import UserError

__all__ = ["xyz_rows", "position_residual", "ephemeris_span"]


def xyz_rows(log, i):
    """The x, y, z values (M, 3) of the log's rows ``i``."""
    return np.asarray(log.xyz, dtype=float)[i]


def position_residual(residual):
    """``residual(fam, v)`` of a model whose residual depends on the position only."""
    def res(fam, v):
        e, H_r = residual(v["orbit"][:, :3], fam)
        return e, {"position": H_r}
    return res


@contextlib.contextmanager
def ephemeris_span(log, i, what):
    """The log's rows ``i`` whose epochs an ERFA ephemeris (``factors.planets``: 1900-2100)
    does not cover are a user error naming their first line."""
    try:
        yield
    except EphemerisSpanError as exc:
        raise UserError(f"{log.path}: the {what} (line {int(np.asarray(log.line)[i][0])} ...): "
                        f"{exc}; expected epochs within 1900-2100") from exc
