"""``summary.json``: a run's figures as one JSON object (sorted keys, written atomically).

Values are converted to plain JSON: numpy scalars and arrays become numbers and lists,
``datetime64`` becomes an ISO-8601 UTC string ending in ``Z``, tuples become lists, and
NaN / +-inf become ``null`` (JSON has no NaN). Keys must be strings.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

from fgnav.errors import InputFormatError, UserError
from fgnav.io.atomic import atomic_write_text
from fgnav.time import format_utc

__all__ = ["write_summary", "read_summary", "to_jsonable"]


def to_jsonable(obj):
    """Convert ``obj`` recursively to JSON-ready Python values (NaN/inf -> None)."""
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, int):
        return int(obj)
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        out = {}
        for k, v in obj.items():
            if not isinstance(k, str):
                raise UserError(f"summary keys must be strings, found {k!r}")
            out[k] = to_jsonable(v)
        return out
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.datetime64):
        return format_utc(obj)
    if isinstance(obj, np.ndarray):
        if np.issubdtype(obj.dtype, np.datetime64):
            return to_jsonable(list(obj.astype("datetime64[ns]").ravel())) if obj.ndim else \
                to_jsonable(obj[()])
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return to_jsonable(float(obj))
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    raise UserError(f"summary value of type {type(obj).__name__} is not JSON-serializable: {obj!r}")


def write_summary(path, summary: dict) -> None:
    """Write ``summary`` (a dict) to ``path`` as JSON: sorted keys, indent 2, NaN -> null."""
    if not isinstance(summary, dict):
        raise UserError(f"write_summary: expected a dict, found {type(summary).__name__}")
    text = json.dumps(to_jsonable(summary), sort_keys=True, indent=2, allow_nan=False)
    atomic_write_text(path, text + "\n")


def read_summary(path) -> dict:
    """Read a summary written by :func:`write_summary` (``null`` stays ``None``).

    Malformed JSON raises :class:`~fgnav.errors.InputFormatError` naming line and column.
    """
    try:
        with open(path, encoding="utf-8") as f:
            text = f.read()
    except UnicodeDecodeError as exc:
        raise InputFormatError(path, None, None, "UTF-8 JSON text", f"undecodable byte at offset "
                               f"{exc.start}") from None
    except OSError as exc:
        raise UserError(f"{path}: cannot read: {exc.strerror or exc}") from None
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputFormatError(path, exc.lineno, f"char {exc.colno}", "a JSON object",
                               exc.msg) from None
    except RecursionError:
        raise InputFormatError(path, None, None, "a JSON object", "nesting too deep") from None
    if not isinstance(obj, dict):
        raise InputFormatError(path, 1, None, "a JSON object", type(obj).__name__)
    return obj
