"""Typed TOML validation, written once: a parsed TOML table checked key by key against a
schema (each value's type, unit and range), every error an
:class:`~fgnav.errors.InputFormatError` naming the file, the line where the text shows it, the
key and what was expected.

A schema comes in one of two writings, checked by the same scalar tests (:func:`as_number`,
:func:`within`, :func:`unknown_key`):

- **spec tuples**, one per key, ``(type, unit, low, high, low inclusive, high inclusive)``
  with ``type`` one of ``number``, ``bool``, ``str``, ``epoch``, ``choice`` (``low`` holds
  the choices), ``id``, ``table``, ``vec3`` (3 finite numbers) and ``numbers`` (a non-empty
  array of finite numbers): :func:`check_value`, :func:`check_keys`, :func:`keyed`, with
  the source text (:class:`TomlSource`) for line numbers (the scenario files,
  :mod:`fgnav.scenarios`);
- **a frozen dataclass's annotations** (``float``, ``int``, ``str``, ``bool``, tuples,
  unions with ``None``, ``Mapping[float, ...]``; a field's ``metadata={"positive": True}``
  asks for > 0): :func:`typed_value`, :func:`typed_object` (the campaign studies,
  :mod:`fgnav.campaign.spec`).

TOML itself: Tom Preston-Werner et al., "TOML v1.0.0" (toml.io, 2021), read by the standard
library's ``tomllib`` (:mod:`fgnav.io.text`).
"""

from __future__ import annotations

import datetime as _dt
import math
import types
import typing
from collections import abc
from dataclasses import MISSING, fields
from types import MappingProxyType

from fgnav.errors import InputFormatError
from fgnav.io.log_spacecraft import ID_EXPECTED, ID_RE
from fgnav.time import parse_utc

__all__ = ["as_number", "within", "unknown_key", "TomlSource", "expected", "check_value",
           "table_of", "check_keys", "keyed", "describe", "typed_value", "typed_object"]


# ---- the scalar checks both writings share ----------------------------------------------

def as_number(value, integer: bool = False):
    """``value`` as a finite ``float`` (``int`` with ``integer``: a TOML integer only), or
    None when it is not one (a boolean is no number here, though Python counts it as one)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    if integer and not isinstance(value, int):
        return None
    x = int(value) if integer else float(value)
    return x if math.isfinite(x) else None


def within(x: float, lo=None, hi=None, lo_in: bool = True, hi_in: bool = True) -> bool:
    """``x`` between ``lo`` and ``hi`` (each inclusive or not; None or infinite: no bound)."""
    if lo is not None and not math.isinf(lo) and (x < lo or (x == lo and not lo_in)):
        return False
    if hi is not None and not math.isinf(hi) and (x > hi or (x == hi and not hi_in)):
        return False
    return True


def unknown_key(d: dict, known) -> str | None:
    """The first key of ``d`` (file order) not among ``known``, or None."""
    return next((k for k in d if k not in known), None)


# ---- spec tuples, with line numbers ------------------------------------------------------

class TomlSource:
    """The TOML text, to point errors at the line that defines a key (best effort);
    ``array_tables`` names the ``[[...]]`` arrays of tables (their elements counted)."""

    def __init__(self, path, text: str, array_tables=()):
        self.path = path
        self.lines = text.splitlines()
        self.array_tables = tuple(array_tables)

    def line_of(self, table: str | None, key: str | None, index: int = 0) -> int | None:
        """1-based line of ``key`` in ``[table]`` (or the ``index``-th ``[[table]]``); of the
        table header when ``key`` is None; None if not found (e.g. an inline table)."""
        current, count, header_line = None, -1, None
        for n, raw in enumerate(self.lines, 1):
            s = raw.strip()
            if s.startswith("["):
                name = s.strip("[]").split("]")[0].strip().strip('"')
                if s.startswith("[[") and name == table:
                    count += 1
                current = name
                if current == table and (count == index or not s.startswith("[[")):
                    header_line = n
                    if key is None:
                        return n
                continue
            if key is None or "=" not in s:
                continue
            k = s.split("=", 1)[0].strip().strip('"')
            in_table = (current is None and table is None) or (
                current == table and (table not in self.array_tables or count == index))
            if in_table and k == key:
                return n
        return header_line if key is None else None

    def error(self, table, index, key, expected, found=None, *, label=None) -> InputFormatError:
        return InputFormatError(self.path, self.line_of(table, key, index), label or key,
                                expected, found)


def expected(spec) -> str:
    """What a value of ``spec`` must be, as the error says it."""
    typ, unit, lo, hi, lo_in, hi_in = spec
    u = f" {unit}" if unit else ""
    if typ == "number":
        if lo is not None and math.isinf(lo) and math.isinf(hi):
            return f"a finite number ({unit or 'no unit'})"
        parts = []
        if lo is not None and not math.isinf(lo):
            parts.append(f"{'>=' if lo_in else '>'} {lo:g}{u}")
        if hi is not None and not math.isinf(hi):
            parts.append(f"{'<=' if hi_in else '<'} {hi:g}{u}")
        return "a finite number " + " and ".join(parts) + (f" ({unit})" if unit and not parts else "")
    if typ == "bool":
        return "true or false (a TOML boolean, unquoted)"
    if typ == "str":
        return "a quoted string"
    if typ == "epoch":
        return "an ISO-8601 UTC epoch string 'YYYY-MM-DDTHH:MM:SS[.f]Z'"
    if typ == "choice":
        return "one of " + ", ".join(repr(c) for c in lo)
    if typ == "id":
        return f"a quoted name: {ID_EXPECTED}"
    if typ == "table":
        return "a table"
    if typ == "vec3":
        return f"an array of 3 finite numbers ({unit})"
    return f"a non-empty array of finite numbers ({unit})"


def check_value(src: TomlSource, table, index, key, value, spec, label):
    """Check ``value`` against ``spec``; return it converted (float, tuple, str, bool)."""
    typ, _unit, lo, hi, lo_in, hi_in = spec

    def bad():
        return src.error(table, index, key, expected(spec), value, label=label)

    if typ == "number":
        x = as_number(value)
        if x is None or not within(x, lo, hi, lo_in, hi_in):
            raise bad()
        return x
    if typ == "bool":
        if not isinstance(value, bool):
            raise bad()
        return value
    if typ == "str":
        if not isinstance(value, str):
            raise bad()
        return value
    if typ == "epoch":
        if isinstance(value, _dt.datetime) and value.utcoffset() in (None, _dt.timedelta(0)):
            value = value.replace(tzinfo=None).isoformat() + "Z"
        if not isinstance(value, str):
            raise bad()
        try:
            parse_utc(value)
        except ValueError as exc:
            raise src.error(table, index, key, f"{expected(spec)} ({exc})", value,
                            label=label) from None
        return value
    if typ == "choice":
        if not isinstance(value, str) or value not in lo:
            raise bad()
        return value
    if typ == "id":
        if not isinstance(value, str) or not ID_RE.match(value):
            raise bad()
        return value
    if typ == "table":
        if not isinstance(value, dict):
            raise bad()
        return value
    if not isinstance(value, list) or not value or (typ == "vec3" and len(value) != 3):
        raise bad()
    if any(as_number(v) is None for v in value):
        raise bad()
    return tuple(float(v) for v in value)


def table_of(src: TomlSource, d, name, index=None):
    """The table ``d[name]`` (empty when absent); not a table: an error naming it."""
    t = d.get(name, {})
    label = name if index is None else f"{name}[{index + 1}]"
    if not isinstance(t, dict):
        raise src.error(None, 0, name, f"a table [{name}]" if index is None else
                        f"an array of tables [[{name}]]", t, label=label)
    return t


def check_keys(src: TomlSource, table, index, d: dict, known, label_prefix, what):
    """Refuse the first key of ``d`` not among ``known`` (``what`` names the table)."""
    k = unknown_key(d, known)
    if k is not None:
        raise src.error(table, index, k, f"a key of {what} (known: {', '.join(known)})",
                        k, label=f"{label_prefix}{k}")


def keyed(src: TomlSource, table, i, t, keys, label, required=()):
    """Check the keys of the ``i``-th ``[[table]]`` ``t`` against ``keys`` and return the
    converted values; a missing required key names the table."""
    check_keys(src, table, i, t, tuple(keys), f"{label}.", f"[[{table}]]")
    for k in required:
        if k not in t:
            raise src.error(table, i, None, f"a key '{k}' ({expected(keys[k])})",
                            label=f"{label}.{k}")
    return {k: check_value(src, table, i, k, t[k], keys[k], f"{label}.{k}") for k in t}


# ---- dataclass annotations --------------------------------------------------------------

def describe(tp) -> str:
    """What a value of the annotation ``tp`` must be, as the error says it."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (types.UnionType, typing.Union):
        return " or ".join(describe(a) for a in args if a is not type(None))
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a non-empty list of {describe(args[0]).removeprefix('a ').removeprefix('an ')}s"
        return f"a list of {len(args)} {describe(args[0]).removeprefix('a ').removeprefix('an ')}s"
    if origin in (dict, abc.Mapping):
        return f"a table of {describe(args[1]).removeprefix('a ')} keyed by number"
    return {float: "a number", int: "an integer", str: "a string", bool: "true or false"}[tp]


def typed_value(path, key: str, value, tp, positive: bool = False):
    """``value`` (as parsed from TOML) checked against the annotation ``tp`` and converted
    (int -> float for a float, list -> tuple, table keys -> float); an
    :class:`InputFormatError` naming ``path`` and ``key`` otherwise."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    what = describe(tp) + (" > 0" if positive else "")

    def bad():
        return InputFormatError(path, None, key, what, value)

    if origin in (types.UnionType, typing.Union):
        for a in (a for a in args if a is not type(None)):
            try:
                return typed_value(path, key, value, a, positive)
            except InputFormatError:
                pass
        raise bad()
    if origin is tuple:
        n = None if (len(args) == 2 and args[1] is Ellipsis) else len(args)
        if not isinstance(value, list) or not value or (n is not None and len(value) != n):
            raise bad()
        return tuple(typed_value(path, f"{key}[{i}]", v, args[0], positive) for i, v in enumerate(value))
    if origin in (dict, abc.Mapping):
        if not isinstance(value, dict) or not value:
            raise bad()
        out = {}
        for k, v in value.items():
            try:
                kf = float(k)
            except ValueError:
                raise InputFormatError(path, None, f"{key}.{k}", "a number as the key", k) from None
            out[kf] = typed_value(path, f"{key}.{k}", v, args[1], positive)
        return MappingProxyType(out)
    if tp is bool:
        if not isinstance(value, bool):
            raise bad()
        return value
    if tp is str:
        if not isinstance(value, str) or not value:
            raise bad()
        return value
    if tp in (int, float):
        x = as_number(value, integer=tp is int)
        if x is None:
            raise bad()
        if not within(x, 0.0 if positive else None, None, lo_in=False):
            raise InputFormatError(path, None, key, what, x)   # (found: the converted value)
        return x
    raise TypeError(f"typed_value: unsupported annotation {tp!r}")


def typed_object(cls, d: dict, path, prefix: str, *, defaults: dict | None = None):
    """An instance of the frozen dataclass ``cls`` from the TOML table ``d``: every key must
    be a field (the error names ``prefix.key`` and the fields), every field without a default
    must be given, every value has the field's type; ``obj.problem()``, if defined, returns
    ``None`` or ``(key, expected, found)`` for a rule across keys."""
    hints = typing.get_type_hints(cls)
    names = [f.name for f in fields(cls)]
    kw = dict(defaults or {})
    for k, v in d.items():   # (file order: an unknown key or a bad value, whichever is first)
        if unknown_key({k: v}, names) is not None:
            raise InputFormatError(path, None, f"{prefix}{k}", f"one of the keys {tuple(names)}", k)
        f = cls.__dataclass_fields__[k]
        kw[k] = typed_value(path, f"{prefix}{k}", v, hints[k], f.metadata.get("positive", False))
    for f in fields(cls):
        if f.name not in kw and f.default is MISSING and f.default_factory is MISSING:
            raise InputFormatError(path, None, f"{prefix}{f.name}", "this key (required)")
    obj = cls(**kw)
    problem = obj.problem() if hasattr(obj, "problem") else None  # a rule across keys
    if problem is not None:
        key, found_expected, found = problem
        raise InputFormatError(path, None, f"{prefix}{key}", found_expected, found)
    return obj
