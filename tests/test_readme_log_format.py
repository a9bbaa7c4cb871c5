"""The README's log-format tables agree with the format's definition (fgnav/io/log_csv.py):
every kind and column documented, nothing documented that the reader does not accept, each
kind's extra columns and sigma unit as the reader uses them. The README cannot drift."""

import re
from pathlib import Path

from fgnav.io import log_csv
from fgnav.models.registry import LOG_SCHEMA

README = Path(__file__).resolve().parents[1] / "README.md"


def _section(title):
    text = README.read_text(encoding="utf-8")
    start = text.index(f"## {title}")
    end = text.find("\n## ", start + 1)
    return text[start:end if end > 0 else None]


def _tables(section):
    """Markdown tables of the section: lists of rows, each a list of cells (header first)."""
    tables, rows = [], []
    for line in section.splitlines() + [""]:
        if line.startswith("|"):
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            if not all(set(c) <= set("-: ") for c in cells):
                rows.append(cells)
        elif rows:
            tables.append(rows)
            rows = []
    return tables


def _code_names(cell):
    return re.findall(r"`([a-z_][a-z_0-9]*)`", cell)


def _log_tables():
    tables = _tables(_section("Logged pass format (v1)"))
    columns = next(t for t in tables if t[0][0] == "column")
    kinds = next(t for t in tables if t[0][0] == "kind")
    return columns[1:], kinds[1:]


def test_every_column_documented():
    columns, _ = _log_tables()
    documented = [name for row in columns for name in _code_names(row[0])]
    assert documented == list(log_csv.BASE_COLUMNS + log_csv.EXTRA_COLUMNS)


def test_every_kind_documented_once():
    _, kinds = _log_tables()
    documented = [_code_names(row[0])[0] for row in kinds]
    assert sorted(documented) == sorted(LOG_SCHEMA)   # the format's kinds and the models' rows
    assert len(documented) == len(set(documented))


def test_each_kind_names_its_extra_columns():
    """A kind's row names exactly the extra columns the reader lets it use."""
    _, kinds = _log_tables()
    spec = LOG_SCHEMA  # the format's one table of kinds and the models' rows (usage per column)
    usage_columns = ("x", "y", "z") + log_csv.EXTRA_COLUMNS
    for row in kinds:
        kind = _code_names(row[0])[0]
        usage = tuple(spec[kind].usage) + ("",) * len(usage_columns)
        used = {c for c, u in zip(usage_columns, usage) if u and c in log_csv.EXTRA_COLUMNS}
        named = set(_code_names(row[1])) & set(log_csv.EXTRA_COLUMNS)
        assert named == used, (kind, named, used)


def test_each_kind_states_its_sigma_unit():
    _, kinds = _log_tables()
    for row in kinds:
        kind = _code_names(row[0])[0]
        unit = LOG_SCHEMA[kind].unit
        units = set(re.findall(r"(?<![\w/])(rad/s|m/s|rad|m)(?![\w/])", row[2]))
        assert units == {unit}, (kind, row[2], unit)


def test_header_line_lists_the_extra_columns():
    section = _section("Logged pass format (v1)")
    assert "`epoch,kind,x,y,z,sigma`" in section
    extra = re.search(r"extra columns ([^)]*)\)", section).group(1)
    assert _code_names(extra) == list(log_csv.EXTRA_COLUMNS)
