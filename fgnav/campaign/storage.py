"""The runs table (``OUT/runs.csv``): one CSV row per finished run with typed columns.

The columns and their types are declared by the study (its swept parameters) and its task
(its result columns), :func:`fgnav.campaign.spec.run_columns`; nothing is guessed from a
cell's text. Cells: ``""`` is ``None``, booleans are ``true``/``false``, floats are written
with ``repr`` (round trip exact, ``nan`` and ``inf`` included).

Rows are appended and ``fsync``-ed one at a time: a killed campaign loses at most the runs in
flight, and a torn last line (killed mid-write) is discarded when the table is read or
resumed. A run may appear more than once (a failed run retried on resume): the last row wins.
"""

from __future__ import annotations

import csv
import io
import os
import re
from pathlib import Path
from typing import Iterable, Sequence

from fgnav.campaign.tasks import Column
from fgnav.errors import InputFormatError, UserError
from fgnav.io.atomic import atomic_write_text

__all__ = ["RunsTable", "csv_line", "format_cell", "parse_cell", "safe_name"]

RAW_COLUMNS = ("run_id", "status", "error")
"""Kept as written (an empty error is ``""``, not ``None``)."""


def csv_line(values: Iterable) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(values)
    return buf.getvalue()


def format_cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if hasattr(v, "item") and not isinstance(v, (str, bytes)):  # numpy scalar
        v = v.item()
    if isinstance(v, float):
        return repr(float(v))
    return str(v)


def parse_cell(text: str, typ: type):
    """The value of a cell of a column of type ``typ``; ``ValueError`` if it is not one."""
    if text == "":
        return None
    if typ is bool:
        if text not in ("true", "false"):
            raise ValueError(text)
        return text == "true"
    return typ(text)


def safe_name(run_id: str) -> str:
    """A file name for a run id (curves/<name>.npz)."""
    return re.sub(r"[^A-Za-z0-9_.=-]+", "_", run_id)


_TYPE_NAMES = {str: "text", int: "an integer", float: "a number", bool: "true or false"}


class RunsTable:
    """``path`` (a runs.csv) with the typed ``columns``."""

    def __init__(self, path, columns: Sequence[Column]):
        self.path = Path(path)
        self.columns = tuple(columns)
        self.names = [c.name for c in self.columns]

    def exists(self) -> bool:
        return self.path.exists() and self.path.stat().st_size > 0

    def create(self) -> None:
        """A new table holding only the header."""

        atomic_write_text(self.path, csv_line(self.names))

    def drop_torn_line(self) -> None:
        """Cut a last line without its newline (the writer was killed mid-row)."""
        with self.path.open("r+b") as f:
            data = f.read()
            if data and not data.endswith(b"\n"):
                f.truncate(data.rfind(b"\n") + 1)

    def header(self) -> list[str]:
        with self.path.open(encoding="utf-8", newline="") as f:
            return next(csv.reader([f.readline()]), [])

    def check_header(self) -> None:
        if self.header() != self.names:
            raise UserError(f"{self.path}: its columns differ from this study's; use another --out")

    def appender(self) -> "_Appender":
        """A context manager whose ``append(row)`` writes one row durably (flush + fsync)."""
        return _Appender(self)

    def read(self) -> list[dict]:
        """The rows (typed; the last row of each run wins) in the order of first appearance;
        ``[]`` when the table does not exist. A complete row whose cell does not have its
        column's type is an :class:`InputFormatError` naming the line and column."""
        if not self.path.exists():
            return []
        text = self.path.read_text(encoding="utf-8")
        if text and not text.endswith("\n"):
            text = text[: text.rfind("\n") + 1]
        reader = csv.reader(io.StringIO(text))
        header = next(reader, None)
        if header is None:
            return []
        if header != self.names:
            raise InputFormatError(self.path, 1, None, f"the header {','.join(self.names)}", ",".join(header))
        types = [c.type for c in self.columns]
        rows: dict[str, dict] = {}
        for line, cells in enumerate(reader, start=2):
            if len(cells) != len(self.names):
                raise InputFormatError(self.path, line, None, f"{len(self.names)} cells", len(cells))
            row = {}
            for name, typ, cell in zip(self.names, types, cells):
                if name in RAW_COLUMNS:
                    row[name] = cell
                    continue
                try:
                    row[name] = parse_cell(cell, typ)
                except ValueError:
                    raise InputFormatError(self.path, line, name, _TYPE_NAMES[typ], cell) from None
            rows[row["run_id"]] = row
        return list(rows.values())


class _Appender:
    def __init__(self, table: RunsTable):
        self.table = table

    def __enter__(self):
        self.f = self.table.path.open("a", encoding="utf-8", newline="")
        return self

    def __exit__(self, *exc):
        self.f.close()

    def append(self, row: dict) -> None:
        self.f.write(csv_line([format_cell(row.get(c)) for c in self.table.names]))
        self.f.flush()
        os.fsync(self.f.fileno())
