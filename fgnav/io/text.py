"""Reading users' text files: UTF-8 (a leading byte-order mark is ignored), errors that name
the file, the line and the byte.

Spreadsheet programs save CSV files as UTF-8 with a byte-order mark (EF BB BF) or in a
legacy code page (Latin-1, Windows-1252); the first is read transparently, the second is an
:class:`~fgnav.errors.InputFormatError` naming the line, the column (character) and the
byte offset from the start of the file, so that the user can find and fix it.
"""

from __future__ import annotations

import re
import tomllib

from fgnav.errors import InputFormatError, UserError

__all__ = ["read_utf8_text", "decode_utf8", "load_toml", "parse_toml", "csv_records",
           "finite_number"]

UTF8_BOM = b"\xef\xbb\xbf"


def decode_utf8(path, data: bytes) -> str:
    """``data`` (the bytes of ``path``) as text: BOM dropped, UTF-8 or an InputFormatError."""
    offset = 0
    if data.startswith(UTF8_BOM):
        data, offset = data[len(UTF8_BOM):], len(UTF8_BOM)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line_start = data.rfind(b"\n", 0, exc.start) + 1
        line = data.count(b"\n", 0, exc.start) + 1
        col = len(data[line_start:exc.start].decode("utf-8", errors="replace")) + 1
        raise InputFormatError(
            path, line, None, "UTF-8 text (save the file as UTF-8)",
            f"byte 0x{data[exc.start]:02x} at character {col} (byte offset "
            f"{exc.start + offset} in the file)") from None


def read_utf8_text(path, what: str = "a text file") -> str:
    """The text of ``path`` (UTF-8, BOM ignored, line ends kept); UserError if unreadable."""
    try:
        with open(path, "rb") as f:
            data = f.read()
    except IsADirectoryError:
        raise UserError(f"{path}: is a directory, expected {what}") from None
    except OSError as exc:
        raise UserError(f"{path}: cannot read {what}: {exc.strerror or exc}") from None
    return decode_utf8(path, data)


def load_toml(path, what: str = "a TOML file") -> dict:
    """Read and parse a TOML file (UTF-8, BOM ignored); see :func:`parse_toml`."""
    return parse_toml(path, read_utf8_text(path, what))


def parse_toml(path, text: str) -> dict:
    """Parse the TOML ``text`` of ``path``; a syntax error is an
    :class:`~fgnav.errors.InputFormatError` naming the line and column."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        m = re.search(r"\(at line (\d+), column (\d+)\)", msg)
        line = getattr(exc, "lineno", None) or (int(m.group(1)) if m else None)
        if m:
            msg = msg[:m.start()].rstrip() + f" at column {m.group(2)}"
        elif "end of document" in msg:
            line = line or text.count("\n") + 1
        raise InputFormatError(path, line, None, f"valid TOML ({msg})") from None


def csv_records(text: str):
    """The records of a small CSV ``text``: ``(line number (1-based), the stripped line, its
    stripped comma-separated fields)`` for every line that is neither blank nor a ``#``
    comment, the header included."""
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if line and not line.startswith("#"):
            yield lineno, line, [f.strip() for f in line.split(",")]


def finite_number(field: str) -> float:
    """``field`` as a float, NaN when it is not a decimal number (callers test finiteness)."""
    try:
        return float(field)
    except ValueError:
        return float("nan")
