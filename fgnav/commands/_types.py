"""argparse ``type=`` converters that validate numeric options: finite, in range, with a
message naming the expected value (argparse adds the option's name and exits with code 2)."""

from __future__ import annotations

import argparse
import math


def number(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
           hi_open: bool = False, unit: str = ""):
    """A float converter: finite, ``lo <= x <= hi`` (strict where ``*_open``)."""
    parts = []
    if lo is not None:
        parts.append(f"{'>' if lo_open else '>='} {lo:g}")
    if hi is not None:
        parts.append(f"{'<' if hi_open else '<='} {hi:g}")
    what = "a finite number" + (" " + " and ".join(parts) if parts else "") + \
        (f" ({unit})" if unit else "")

    def convert(text: str) -> float:
        try:
            x = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, found {text!r}") from None
        if not math.isfinite(x) or (lo is not None and (x < lo or (lo_open and x == lo))) or \
                (hi is not None and (x > hi or (hi_open and x == hi))):
            raise argparse.ArgumentTypeError(f"expected {what}, found {text!r}")
        return x

    convert.__name__ = "number"
    return convert


def integer(lo: int | None = None, hi: int | None = None, *, what: str = "an integer",
            range_text: str | None = None):
    """An int converter: ``lo <= n <= hi`` (``range_text`` describes the range instead)."""
    parts = ([f">= {lo}"] if lo is not None else []) + ([f"<= {hi}"] if hi is not None else [])
    desc = what + " " + (range_text or " and ".join(parts)) if (parts or range_text) else what

    def convert(text: str) -> int:
        try:
            n = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {desc}, found {text!r}") from None
        if (lo is not None and n < lo) or (hi is not None and n > hi):
            raise argparse.ArgumentTypeError(f"expected {desc}, found {text!r}")
        return n

    convert.__name__ = "integer"
    return convert


def pos(unit: str = ""):
    """A finite number > 0 (in ``unit``)."""
    return number(0.0, lo_open=True, unit=unit)


positive = pos()
seed = integer(0, 2**63 - 1, what="a seed, an integer", range_text="in 0..2**63-1")
