"""Shared pieces of the CCSDS KVN (keyword = value notation) messages fgnav reads and writes:
OEM (:mod:`fgnav.io.oem`), AEM (:mod:`fgnav.io.aem`) and TDM (:mod:`fgnav.io.tdm`).

KVN is defined in each message's Blue Book (ODM 502.0-B-3 sec. 7, ADM 504.0-B-2 sec. 6,
TDM 503.0-B-2 sec. 4): one ``KEYWORD = value`` per line, ``COMMENT`` lines, blank lines
ignored, epochs in CCSDS ASCII time code A or B (``YYYY-MM-DDThh:mm:ss[.f][Z]`` or
``YYYY-DDDThh:mm:ss[.f][Z]``, CCSDS 301.0-B-4 sec. 3.5). Every malformed value is an
:class:`~fgnav.errors.InputFormatError` naming the file, the line and the keyword.
"""

from __future__ import annotations

import bz2
import gzip
import lzma
import math
import re
import zlib

import numpy as np

from fgnav.errors import InputFormatError, UserError
from fgnav.time import UtcRangeError, format_utc, parse_utc

__all__ = ["KVN_RE", "EPOCH_EXPECTED", "parse_ccsds_epoch", "format_ccsds_epoch",
           "ccsds_epochs", "read_kvn_lines", "split_kvn", "version_line", "epoch_value",
           "number_value",
           "header_line", "kvn_header", "check_meta_value", "HEADER_KEYS"]

HEADER_KEYS = ("CREATION_DATE", "ORIGINATOR", "MESSAGE_ID")
"""The header keywords every message accepts (a message adds its own, e.g. CLASSIFICATION)."""

_EPOCH_RE = re.compile(
    r"^(\d{4})-(?:(\d{2})-(\d{2})|(\d{3}))T(\d{2}):(\d{2}):(\d{2})(?:\.(\d+))?Z?$")
_NUMBER_RE = re.compile(r"^[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?$")
KVN_RE = re.compile(r"^([A-Z][A-Z0-9_]*)\s*=\s*(.*?)\s*$")
"""``KEYWORD = value`` (groups: keyword, value without surrounding blanks)."""
EPOCH_EXPECTED = "a CCSDS epoch YYYY-MM-DDThh:mm:ss[.f] or YYYY-DDDThh:mm:ss[.f]"


def parse_ccsds_epoch(text: str) -> np.datetime64:
    """CCSDS ASCII time (calendar or day-of-year form, optional ``Z``) -> datetime64[ns].

    Fractions beyond nanoseconds are truncated. Raises ``ValueError`` if malformed.
    """
    m = _EPOCH_RE.match(text.strip())
    if m is None:
        raise ValueError(f"not a CCSDS epoch: {text!r}")
    year, month, day, doy, hh, mm, ss, frac = m.groups()
    if doy is not None:
        d = int(doy)
        try:
            base = np.datetime64(f"{year}-01-01", "D")
        except ValueError:
            raise ValueError(f"not a valid date: {text!r}") from None
        date = base + np.timedelta64(d - 1, "D")
        if d < 1 or str(date)[:4] != year:
            raise ValueError(f"day of year out of range: {text!r}")
        day_text = str(date)
    else:
        day_text = f"{year}-{month}-{day}"
    frac_text = f".{frac[:9]}" if frac else ""
    try:  # leap seconds (23:59:60) included, see fgnav.time
        return parse_utc(f"{day_text}T{hh}:{mm}:{ss}{frac_text}Z")
    except (UtcRangeError, OverflowError):  # datetime64[ns] wraps outside 1678..2261
        raise ValueError(f"epoch out of range (years 1678..2261): {text!r}") from None


def format_ccsds_epoch(t64) -> str:
    """datetime64 -> ``YYYY-MM-DDThh:mm:ss.ffffff`` (UTC, microseconds; ns when needed)."""
    t = np.datetime64(t64, "ns")
    return format_utc(t, "us" if int(t.astype(np.int64)) % 1000 == 0 else "ns")[:-1]


def ccsds_epochs(t64) -> list[str]:
    """:func:`format_ccsds_epoch` of every epoch of a datetime64 array, vectorized."""
    ns = np.asarray(t64).astype("datetime64[ns]").astype(np.int64)
    us = ns % 1000 == 0
    out = [""] * len(ns)
    for sel, unit in ((us, "us"), (~us, "ns")):
        idx = np.flatnonzero(sel)
        if len(idx):
            for i, t in zip(idx.tolist(), format_utc(ns[idx].astype("datetime64[ns]"), unit)):
                out[i] = t[:-1]
    return out


def _decompressed(path, data: bytes) -> bytes:
    """``data`` itself, or its content if it is a gzip, bzip2, xz or (by the ``.lzma``
    suffix) legacy LZMA file, recognised by its magic bytes (the ``oem`` package's samples
    include all four)."""
    kind = None
    if data[:2] == b"\x1f\x8b":
        kind, fn = "gzip", gzip.decompress
    elif data[:3] == b"BZh":
        kind, fn = "bzip2", bz2.decompress
    elif data[:6] == b"\xfd7zXZ\x00":
        kind, fn = "xz", lzma.decompress
    elif str(path).lower().endswith(".lzma"):
        kind, fn = "lzma", lambda b: lzma.decompress(b, format=lzma.FORMAT_ALONE)
    if kind is None:
        return data
    try:
        return fn(data)
    except (OSError, EOFError, ValueError, lzma.LZMAError, zlib.error) as exc:
        raise InputFormatError(path, None, None, f"a readable {kind}-compressed file",
                               str(exc) or type(exc).__name__) from None


def read_kvn_lines(path) -> list[tuple[int, str]]:
    """(line number, text without line end) of every line; UTF-8 (ASCII in practice).
    A gzip, bzip2, xz or LZMA file is decompressed first (line numbers are its content's)."""
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as exc:
        raise UserError(f"{path}: cannot read: {exc.strerror or exc}") from None
    data = _decompressed(path, data)
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    out = []
    for i, raw in enumerate(data.split(b"\n")):
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise InputFormatError(path, i + 1, None, "ASCII/UTF-8 text",
                                   f"byte 0x{raw[exc.start]:02x}") from None
        out.append((i + 1, text.rstrip("\r")))
    return out


def split_kvn(path, lineno, text, context):
    """Split ``KEY = value``; raise naming the line if it is not one."""
    m = KVN_RE.match(text.strip())
    if m is None:
        raise InputFormatError(path, lineno, None, f"a 'KEYWORD = value' line ({context})",
                               text.strip())
    return m.group(1), m.group(2)


def epoch_value(path, lineno, column, text):
    """:func:`parse_ccsds_epoch`, or an error naming the file, line and ``column``."""
    try:
        return parse_ccsds_epoch(text)
    except ValueError:
        raise InputFormatError(path, lineno, column, EPOCH_EXPECTED, text) from None


def number_value(path, lineno, column, text, scale=1.0):
    """Parse a decimal number and multiply by ``scale`` (unit conversion); finite or raise."""
    if not _NUMBER_RE.match(text):
        raise InputFormatError(path, lineno, column, "a decimal number", text)
    x = float(text) * scale  # Python floats: overflow gives inf, no warning
    if not math.isfinite(x):
        raise InputFormatError(path, lineno, column, "a finite number (in range for SI units)",
                               text)
    return x


def version_line(path, lines, message: str, versions, name_found=True) -> tuple[int, str]:
    """The first non-blank line of a KVN message, ``CCSDS_<message>_VERS = v`` with ``v`` in
    ``versions``: (line number, v). An XML message (``<?xml ...``), an empty file or another
    first line is an error naming the file, the line and the keyword (another first keyword:
    that one if ``name_found``, else the one expected)."""
    key = f"CCSDS_{message}_VERS"
    first = next(((n, t.strip()) for n, t in lines if t.strip()), None)
    if first is None:
        raise InputFormatError(path, 1, key, f"an {message} starting with '{key} = "
                               f"{versions[-1]}'", "empty file")
    n0, t0 = first
    if t0.startswith("<"):
        raise InputFormatError(path, n0, key, f"a KVN {message} starting with '{key} = ...' "
                               "(fgnav reads the KVN form of CCSDS messages, not the XML form)",
                               t0[:60])
    m = KVN_RE.match(t0)
    if m is None or m.group(1) != key:
        raise InputFormatError(path, n0, m.group(1) if m and name_found else key,
                               f"{key} = {versions[-1]} as the first line", t0[:60])
    if m.group(2) not in versions:
        raise InputFormatError(path, n0, key, f"version {', '.join(versions[:-1])} or "
                               f"{versions[-1]}" if len(versions) > 1 else
                               f"version {versions[0]}", m.group(2))
    return n0, m.group(2)


def header_line(path, lineno, s, meta, keys=HEADER_KEYS) -> bool:
    """One line of a CCSDS KVN message header (OEM, TDM, AEM) before the first META_START.

    Stores the header keywords ``keys`` (CREATION_DATE / ORIGINATOR / MESSAGE_ID, and for an
    AEM or an OEM 3.0 also CLASSIFICATION) in ``meta`` (CREATION_DATE checked as an epoch;
    each keyword at most once); at META_START checks that the required keywords came first
    and returns True.
    """
    if s == "META_START":
        for k in ("CREATION_DATE", "ORIGINATOR"):
            if k not in meta:
                raise InputFormatError(path, lineno, k, f"header keyword {k} before "
                                       "META_START", "META_START")
        return True
    m = KVN_RE.match(s)
    if m is None or m.group(1) not in keys:
        raise InputFormatError(path, lineno, m.group(1) if m else None,
                               f"a header keyword ({', '.join(keys)}, COMMENT) or META_START", s)
    if m.group(1) in meta:
        raise InputFormatError(path, lineno, m.group(1), "each header keyword once",
                               f"{m.group(1)} repeated")
    if m.group(1) == "CREATION_DATE":
        epoch_value(path, lineno, "CREATION_DATE", m.group(2))
    meta[m.group(1)] = m.group(2)
    return False


def check_meta_value(name, value, writer="write_oem"):
    """A keyword value to write: non-empty, one line, no ``=``; stripped. UserError (naming
    the ``writer`` and the keyword) if not."""
    value = str(value)
    if not value.strip() or any(c in value for c in "\r\n="):
        raise UserError(f"{writer}: {name} must be a non-empty single-line value without "
                        f"'=', found {value!r}")
    return value.strip()


def kvn_header(version_line, comments, creation_date, originator) -> list[str]:
    """The header of a CCSDS KVN message (OEM, AEM) as lines: the version, one ``COMMENT``
    line per comment line, ``CREATION_DATE`` (``None``: now) and ``ORIGINATOR``, a blank line."""
    if creation_date is None:
        creation_date = np.datetime64("now", "us")
    out = [version_line + "\n"]
    for c in comments:
        for part in str(c).splitlines() or [""]:
            out.append(f"COMMENT {part}\n")
    out.append(f"CREATION_DATE = {format_ccsds_epoch(creation_date)}\n")
    out.append(f"ORIGINATOR = {originator}\n\n")
    return out
