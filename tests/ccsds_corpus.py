"""The CCSDS interoperability corpus in ../shared/data/ccsds (see its README): which files
are OEM, TDM or AEM, what fgnav's readers make of each, and the table of
docs/ccsds-corpus.md. ``python tests/ccsds_corpus.py`` prints that table from the readers'
actual outcomes (the test checks the committed table against them)."""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path

from fgnav.errors import InputFormatError
from fgnav.io.aem import read_aem
from fgnav.io.oem import read_oem
from fgnav.io.tdm import read_tdm

sys.path.insert(0, str(Path(__file__).resolve().parent))
from shared_data import SHARED  # noqa: E402

CANDIDATES = (SHARED, Path(__file__).resolve().parents[2] / "shared", Path("/work/shared"))
CORPUS = next((p / "data" / "ccsds" for p in CANDIDATES if (p / "data" / "ccsds").is_dir()),
              None)
TABLE = Path(__file__).resolve().parents[1] / "docs" / "ccsds-corpus.md"
TDM_SIGMA_RAD = 1e-4   # a TDM carries no noise: the corpus is read as with --sigma-deg

READERS = {"OEM": read_oem, "AEM": read_aem,
           "TDM": lambda p: read_tdm(p, sigma_rad=TDM_SIGMA_RAD)}

# reason id -> what it means (the docs table's legend)
REASONS = {
    "xml": "the XML form: fgnav reads the KVN form of OEM, TDM and AEM (no XML reader)",
    "time-system": "a TIME_SYSTEM other than UTC (TAI, TCG, MRT, unknown): not read",
    "frame": "a non-inertial or other frame (TOD, ITRF, GTOD, a sensor frame): fgnav reads "
             "EME2000/J2000, GCRF, ICRF",
    "attitude-type": "Euler angles or spin states: fgnav reads quaternion AEMs",
    "angle-type": "angles other than RADEC (AZEL, XSYE, XEYN): fgnav reads RA/Dec",
    "no-angles": "no angle data (range, Doppler, frequencies, media...): fgnav reads the "
                 "Earth's direction only",
    "not-onboard": "angles that are not the Earth seen from the spacecraft (a ground "
                   "station's or telescope's, differenced): refused naming PATH or MODE",
    "mixed-fields": "ephemeris lines with and without accelerations in one segment: refused "
                    "as the `oem` package does (an fgnav rule; the standard's 5.2.4 does not "
                    "say)",
    "defect": "a departure from the standard (the clause in the message), often the file's "
              "purpose (the `oem` package's invalid samples, Orekit's negative tests)",
}


def message_type(rel: str) -> str | None:
    """OEM, TDM or AEM by the corpus layout; None for the other messages (OPM, OMM, OCM,
    APM, ACM, CDM, RDM, NDM containers, the lexical tests) and the licences and PDFs."""
    name = rel.rsplit("/", 1)[-1]
    if name.upper().startswith("LICENSE") or name.endswith(".pdf") or name.startswith(
            ("NOTICE", "README")):
        return None
    m = re.match(r"annex-examples/(?:kvn|xml)/(oem|tdm|aem)_", rel)
    if m:
        return m.group(1).upper()
    for prefix, kind in (("oem-samples/", "OEM"), ("orekit/odm/oem/", "OEM"),
                         ("orekit/adm/aem/", "AEM"), ("orekit/tdm/", "TDM")):
        if rel.startswith(prefix):
            return kind
    return None


def corpus_files() -> list[tuple[str, str]]:
    """(path relative to the corpus, message type) of every OEM, TDM and AEM file."""
    out = []
    for root, _, names in os.walk(CORPUS):
        for n in names:
            rel = os.path.relpath(os.path.join(root, n), CORPUS).replace(os.sep, "/")
            kind = message_type(rel)
            if kind:
                out.append((rel, kind))
    return sorted(out)


def reason(e: InputFormatError) -> str:
    """The reason id of a refusal (REASONS)."""
    text = f"{e.expected} {e.found}"
    if "XML form" in e.expected:
        return "xml"
    if e.column == "TIME_SYSTEM" and "UTC" in e.expected:
        return "time-system"
    if e.column in ("REF_FRAME", "REFERENCE_FRAME", "REF_FRAME_A", "REF_FRAME_B") and (
            "inertial" in text or "EME2000" in e.expected):
        return "frame"
    if e.column == "ATTITUDE_TYPE" and "quaternion ATTITUDE_TYPE" in e.expected:
        return "attitude-type"
    if e.column == "ANGLE_TYPE":
        return "angle-type"
    if e.found == "no measurements":
        return "no-angles"
    if e.column in ("PATH", "MODE") and "angle" in e.expected:
        return "not-onboard"
    if "does not mix lines with and without accelerations" in e.expected:
        return "mixed-fields"
    return "defect"


def outcome(rel: str, kind: str):
    """("read", data) or ("refused", InputFormatError) for one corpus file."""
    try:
        return "read", READERS[kind](CORPUS / rel)
    except InputFormatError as e:
        return "refused", e


def _cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def table_rows() -> list[str]:
    rows = []
    for rel, kind in corpus_files():
        what, res = outcome(rel, kind)
        if what == "read":
            n = len(res.t_s)
            segs = len(res.meta.get("segments", [])) or 1
            extra = ""
            if kind == "OEM" and res.cov_P is not None:
                extra = f", {len(res.cov_P)} covariance blocks"
            rows.append(f"| `{rel}` | {kind} | read | | | {n} epochs, {segs} segment"
                        f"{'s' if segs > 1 else ''}{extra} |")
        else:
            r = reason(res)
            detail = f"expected {res.expected}" + (f", found {res.found!r}" if res.found
                                                   is not None else "")
            if len(detail) > 150:
                detail = detail[:147] + "..."
            rows.append(f"| `{rel}` | {kind} | refused | {res.line or ''} | "
                        f"{_cell(res.column or '')} | {r}: {_cell(detail)} |")
    return rows


def parse_table(text: str) -> dict[str, dict]:
    """The committed table: path -> {kind, outcome, line, keyword, reason}."""
    out = {}
    for ln in text.splitlines():
        cells = [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", ln)[1:-1]]
        if len(cells) != 6 or not re.fullmatch(r"`[^`]+`", cells[0]):
            continue
        rel, kind, what, line, key, why = cells
        out[rel.strip("`")] = {"kind": kind, "outcome": what,
                               "line": int(line) if line else None, "keyword": key or None,
                               "reason": why.split(":", 1)[0] if what == "refused" else None}
    return out


if __name__ == "__main__":
    if CORPUS is None:
        sys.exit("no ../shared/data/ccsds beside the checkout")
    print("\n".join(table_rows()))
