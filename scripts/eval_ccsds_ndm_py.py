"""Weigh `ccsds-ndm-py` (PyPI, MPL-2.0, Rust; Jochim Maene) against fgnav's own readers
(fgnav/io/oem.py, tdm.py, aem.py) on the CCSDS corpus in ../shared/data/ccsds: agreement
and strictness per message type, the precision of its messages, its speed on a large
fgnav-written OEM and what it reads that fgnav does not. The sibling of
scripts/eval_ccsds_libraries.py (`oem`, the GPL `ccsds-ndm`); the decision is in
docs/ccsds.md.

Run in a throwaway environment (ccsds-ndm-py is not a dependency of fgnav)::

    python -m venv /tmp/ndm-venv && . /tmp/ndm-venv/bin/activate
    pip install -e ".[test]" ccsds-ndm-py==0.0.9
    python -m fgnav simulate gto-transfer --step-s 1 --duration-h 4 --out /tmp/ndm/pass --quiet
    python -m fgnav smooth /tmp/ndm/pass/measurements.csv --out /tmp/ndm/res --quiet
    python scripts/eval_ccsds_ndm_py.py /tmp/ndm/res/trajectory.oem [--files]

Prints Markdown tables: per message type, what each reader does with the corpus files
(the categories of tests/ccsds_corpus.py), the largest differences of the numbers where both
read a file, how ccsds-ndm-py's messages locate a defect; then the read time of the large
OEM (median of 3) and the XML it reads. ``--files`` adds one line per file where the two
readers differ (one reads, the other refuses), with ccsds-ndm-py's message.
"""

from __future__ import annotations

import bz2
import gzip
import lzma
import re
import statistics
import subprocess
import sys
import tempfile
import time
from collections import Counter
from importlib.metadata import version
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

import ccsds_ndm  # noqa: E402  (the library weighed; installed only for this script)
from ccsds_corpus import CORPUS, corpus_files, outcome, reason  # noqa: E402

from fgnav.io.aem import read_aem, write_aem  # noqa: E402
from fgnav.io.kvn import parse_ccsds_epoch  # noqa: E402
from fgnav.io.oem import read_oem  # noqa: E402
from fgnav.io.tdm import read_tdm, write_tdm  # noqa: E402
from fgnav.time import seconds_since  # noqa: E402
from fgnav.vision.attitude import matrix_from_quat  # noqa: E402

INERTIAL = {"EME2000", "J2000", "GCRF", "ICRF"}
CLASS = {"OEM": "Oem", "TDM": "Tdm", "AEM": "Aem"}
OUT_OF_SCOPE = {"xml", "time-system", "frame", "attitude-type", "angle-type", "no-angles",
                "not-onboard"}
KEYWORD_RE = re.compile(r"\b[A-Z][A-Z0-9]*(?:_[A-Z0-9]+)+\b|\b[A-Z]{4,}\b")


def _text(path: Path) -> str:
    """The file's text, decompressed as fgnav's readers do (gzip, bzip2, xz, LZMA): the
    library reads plain text only, so it is given the same content fgnav reads."""
    data = path.read_bytes()
    if data[:2] == b"\x1f\x8b":
        data = gzip.decompress(data)
    elif data[:3] == b"BZh":
        data = bz2.decompress(data)
    elif data[:6] == b"\xfd7zXZ\x00":
        data = lzma.decompress(data)
    elif path.suffix.lower() == ".lzma":
        data = lzma.decompress(data, format=lzma.FORMAT_ALONE)
    return data.decode("utf-8", errors="replace")


def ndm_read(path: Path):
    """("read", message) or ("refused", "Type: message"); a Rust panic (pyo3's
    PanicException, a BaseException) counts as a refusal without a message of its own."""
    try:
        msg = ccsds_ndm.from_str(_text(path))
    except Exception as exc:  # the library's own exception types are the point here
        return "refused", f"{type(exc).__name__}: {' '.join(str(exc).split())}"
    except BaseException as exc:  # noqa: B036  a PanicException from the Rust side
        if isinstance(exc, (KeyboardInterrupt, SystemExit)):
            raise
        return "refused", f"{type(exc).__name__} (panic): {' '.join(str(exc).split())}"
    return "read", msg


def _seconds(epochs, epoch0) -> np.ndarray:
    t64 = np.array([parse_ccsds_epoch(e) for e in epochs], dtype="datetime64[ns]")
    return seconds_since(t64, epoch0)


def compare_oem(ours, msg) -> dict:
    """Largest differences of ccsds-ndm-py's OEM against fgnav's (SI), all segments."""
    epochs, x, cov_epochs, cov = [], [], [], []
    for seg in msg.segments:
        d = seg.data
        epochs += list(d.state_vector_epochs)
        x.append(np.asarray(d.state_vector_numpy, dtype=float))
        ce = list(d.covariance_matrix_epochs)
        if ce:
            cov_epochs += ce
            cov.append(np.asarray(d.covariance_matrix_numpy, dtype=float))
    width = min(a.shape[1] for a in x)
    x = np.concatenate([a[:, :width] for a in x]) * 1e3
    out = {"epochs": len(epochs), "n_fgnav": len(ours.t_s)}
    if len(epochs) != len(ours.t_s):
        return out
    out["dt"] = float(np.abs(_seconds(epochs, ours.epoch0) - ours.t_s).max())
    out["dx"] = float(np.abs(x[:, :6] - ours.x_eci).max())
    if ours.a_eci is not None and width == 9:
        out["da"] = float(np.abs(x[:, 6:9] - ours.a_eci).max())
    n_cov = 0 if ours.cov_P is None else len(ours.cov_P)
    out["cov"], out["cov_fgnav"] = len(cov_epochs), n_cov
    if cov_epochs and len(cov_epochs) == n_cov:
        P = np.concatenate(cov) * 1e6
        out["dP"] = float(np.abs(P - ours.cov_P).max() / np.abs(ours.cov_P).max())
        out["dt_cov"] = float(np.abs(_seconds(cov_epochs, ours.epoch0) - ours.cov_t_s).max())
    return out


def compare_aem(ours, msg) -> dict:
    """Largest differences of ccsds-ndm-py's quaternions against fgnav's: (QC, Q1, Q2, Q3)
    from its file-order Q1 Q2 Q3 QC (AEM 2.0), conjugated when REF_FRAME_A is not inertial
    (fgnav then inverts, ADM 504.0-B-2 annex F), normalized as fgnav does (it accepts a norm
    within 1e-3 of 1 and divides by it: the annex's 5-decimal quaternions), q and -q one
    rotation."""
    epochs, q = [], []
    for seg in msg.segments:
        a = np.asarray(seg.data.attitude_states_numpy, dtype=float)[:, :4]
        qn = np.column_stack([a[:, 3], a[:, 0], a[:, 1], a[:, 2]])
        if seg.metadata.ref_frame_a.upper() not in INERTIAL:
            qn[:, 1:] *= -1.0
        qn /= np.linalg.norm(qn, axis=1)[:, None]
        epochs += list(seg.data.attitude_states_epochs)
        q.append(qn)
    out = {"epochs": len(epochs), "n_fgnav": len(ours.t_s)}
    if len(epochs) != len(ours.t_s):
        return out
    q = np.concatenate(q)
    out["dt"] = float(np.abs(_seconds(epochs, ours.epoch0) - ours.t_s).max())
    out["dq"] = float(np.minimum(np.abs(q - ours.q_wxyz).max(axis=1),
                                 np.abs(q + ours.q_wxyz).max(axis=1)).max())
    return out


def _locates(fg_err, ndm_msg: str) -> tuple[bool, bool, bool]:
    """(names a line, the same line as fgnav's, names fgnav's keyword or any keyword)."""
    lines = [int(n) for n in re.findall(r"\bline (\d+)", ndm_msg)]
    key = (fg_err.column in ndm_msg) if fg_err.column else bool(KEYWORD_RE.search(
        ndm_msg.split(":", 1)[-1]))
    return bool(lines), fg_err.line in lines, key


def corpus(show_files: bool) -> None:
    rows: dict[str, Counter] = {k: Counter() for k in CLASS}
    worst: dict[str, dict[str, float]] = {k: {} for k in CLASS}
    diffs: list[str] = []
    xml_rows: list[tuple] = []
    for rel, kind in corpus_files():
        what, res = outcome(rel, kind)
        nd, msg = ndm_read(CORPUS / rel)
        c = rows[kind]
        c["files"] += 1
        if nd == "read" and type(msg).__name__ != CLASS[kind]:
            nd, msg = "refused", f"read as {type(msg).__name__}, not {CLASS[kind]}"
        if what == "read":
            c["fgnav reads"] += 1
            if nd == "read":
                cmp = (compare_oem if kind == "OEM" else compare_aem)(res, msg) \
                    if kind != "TDM" else {}
                same_n = cmp.get("epochs") == cmp.get("n_fgnav") and \
                    cmp.get("cov", 0) == cmp.get("cov_fgnav", 0)
                c["both read"] += 1
                c["both read, same counts"] += same_n
                for k, v in cmp.items():
                    if k in ("dt", "dx", "da", "dP", "dt_cov", "dq"):
                        worst[kind][k] = max(worst[kind].get(k, 0.0), v)
                if not same_n:
                    diffs.append(f"| `{rel}` | {kind} | read | read, other counts: {cmp} |")
            else:
                c["fgnav reads, ndm refuses"] += 1
                # ODM 502.0-B-3 7.4.7: white space before the end of line is not significant;
                # 7.3.5: blank lines may be used at any position
                lines = [ln.rstrip() for ln in _text(CORPUS / rel).splitlines()]
                why = ""
                for what_, text in (("trailing blanks", lines),
                                    ("trailing blanks and blank lines", [x for x in lines if x])):
                    try:
                        ccsds_ndm.from_str("\n".join(text) + "\n")
                    except Exception:  # the library's own exception types: still refused
                        continue
                    c[f"fgnav reads, ndm refuses; reads without {what_}"] += 1
                    why = f"; read once the {what_} are removed"
                    break
                diffs.append(f"| `{rel}` | {kind} | read | refused: {msg[:160]}{why} |")
            continue
        r = reason(res)
        if r == "xml":
            xml_rows.append((rel, kind, nd, msg))
        group = "defect" if r == "defect" else ("fgnav rule" if r == "mixed-fields"
                                                 else "out of scope")
        c[f"fgnav refuses: {group}"] += 1
        if nd == "read":
            c[f"fgnav refuses: {group}; ndm reads"] += 1
            if group != "out of scope":
                diffs.append(f"| `{rel}` | {kind} | refused ({r}, line {res.line}) | "
                             f"**accepted** |")
            else:
                c[f"out of scope ({r}); ndm reads"] += 1
        else:
            c[f"fgnav refuses: {group}; ndm refuses"] += 1
            if group != "out of scope":
                has_line, same_line, key = _locates(res, msg)
                c[f"{group}: ndm names a line"] += has_line
                c[f"{group}: ndm names fgnav's line"] += same_line
                c[f"{group}: ndm names fgnav's keyword (any, where fgnav names none)"] += key
                if show_files:
                    diffs.append(f"| `{rel}` | {kind} | refused line {res.line} "
                                 f"`{res.column or ''}` | refused: {msg[:160]} |")

    print("## The corpus, per message type\n")
    keys = ["files", "fgnav reads", "both read", "both read, same counts",
            "fgnav reads, ndm refuses", "fgnav reads, ndm refuses; reads without trailing blanks",
            "fgnav reads, ndm refuses; reads without trailing blanks and blank lines",
            "fgnav refuses: defect", "fgnav refuses: defect; ndm refuses",
            "fgnav refuses: defect; ndm reads", "defect: ndm names a line",
            "defect: ndm names fgnav's line",
            "defect: ndm names fgnav's keyword (any, where fgnav names none)",
            "fgnav refuses: fgnav rule", "fgnav refuses: fgnav rule; ndm refuses",
            "fgnav refuses: fgnav rule; ndm reads",
            "fgnav refuses: out of scope", "fgnav refuses: out of scope; ndm reads"]
    print("| | " + " | ".join(CLASS) + " |\n|---|" + "---:|" * len(CLASS))
    for k in keys:
        print(f"| {k} | " + " | ".join(str(rows[m][k]) for m in CLASS) + " |")
    print("\nOut of scope for fgnav, read by ccsds-ndm-py, by reason:")
    for m in CLASS:
        got = {k: v for k, v in rows[m].items() if k.startswith("out of scope (")}
        print(f"- {m}: {got or 'none'}")
    print("\nLargest differences where both read (fgnav's units: s, m and m/s, m/s**2, "
          "relative for covariances, quaternion components):")
    for m in CLASS:
        print(f"- {m}: " + (", ".join(f"{k} {v:.3g}" for k, v in worst[m].items())
                            or "no file read by both"))
    if diffs:
        print("\n| file | message | fgnav | ccsds-ndm-py |\n|---|---|---|---|")
        print("\n".join(diffs))
    bad = CORPUS / "orekit/odm/oem/OEM-wrong-keyword.txt"
    try:
        ccsds_ndm.from_file(str(bad))
        said = "accepted"
    except Exception as exc:  # the library's own exception type is the point here
        said = " ".join(str(exc).split())
    print(f"\nccsds_ndm.from_file on {bad.name}: {said!r}; names the file: "
          f"{bad.name in said}")
    print("\n## The XML files (fgnav has no XML reader)\n")
    print("| file | message | ccsds-ndm-py |\n|---|---|---|")
    for rel, kind, nd, msg in xml_rows:
        print(f"| `{rel}` | {kind} | {nd}" + (f": {msg[:140]}" if nd != "read" else
                                               f", {_count(msg)}") + " |")


def _count(msg) -> str:
    """What a read message holds: epochs (OEM, AEM) or observations (TDM)."""
    if type(msg).__name__ == "Tdm":
        return f"{sum(len(s.data.observations) for s in msg.segments)} observations"
    if type(msg).__name__ == "Oem":
        return f"{sum(len(s.data.state_vector_epochs) for s in msg.segments)} states"
    return f"{sum(len(s.data.attitude_states_epochs) for s in msg.segments)} attitudes"


def _median_time(f, n=3):
    ts, r = [], None
    for _ in range(n):
        t = time.perf_counter()
        r = f()
        ts.append(time.perf_counter() - t)
    return r, statistics.median(ts), ts


def speed(big: Path) -> None:
    ours, t_f, ts_f = _median_time(lambda: read_oem(big))
    msg, t_n, ts_n = _median_time(lambda: ccsds_ndm.Oem.from_file(str(big)))
    cmp = compare_oem(ours, msg)

    def arrays():  # what fgnav's read returns: SI arrays and epochs as datetime64
        d = ccsds_ndm.Oem.from_file(str(big)).segments[0].data
        return (np.asarray(d.state_vector_numpy) * 1e3, np.asarray(d.covariance_matrix_numpy)
                * 1e6, np.array(d.state_vector_epochs, dtype="datetime64[ns]"))
    _, t_a, ts_a = _median_time(arrays)
    print(f"\n## Speed: {big} ({big.stat().st_size / 1e6:.1f} MB, {len(ours.t_s)} states, "
          f"{0 if ours.cov_P is None else len(ours.cov_P)} covariances)\n")
    print("| read (median of 3) | fgnav | ccsds-ndm-py |\n|---|---:|---:|")
    print(f"| KVN | {t_f:.2f} s ({', '.join(f'{t:.2f}' for t in ts_f)}) | "
          f"{t_n:.2f} s ({', '.join(f'{t:.2f}' for t in ts_n)}) |")
    print(f"| KVN, and the numbers as SI arrays, epochs as datetime64 | (as above) | "
          f"{t_a:.2f} s ({', '.join(f'{t:.2f}' for t in ts_a)}) |")
    with tempfile.TemporaryDirectory() as tmp:
        xml = Path(tmp) / "big.xml"
        _, t_w, _ = _median_time(lambda: msg.to_file(str(xml), "xml"), n=1)
        back, t_x, _ = _median_time(lambda: ccsds_ndm.Oem.from_file(str(xml)))
        kvn = Path(tmp) / "big.oem"
        _, t_wk, _ = _median_time(lambda: msg.to_file(str(kvn), "kvn"), n=1)
        again = read_oem(kvn)
        xml_mb = xml.stat().st_size / 1e6
    print(f"| XML written by ccsds-ndm-py ({xml_mb:.1f} MB; written in {t_w:.2f} s) | "
          f"(no XML reader) | {t_x:.2f} s |")
    print(f"\nccsds-ndm-py's read against fgnav's: {cmp}")
    print(f"its XML read back, against fgnav's KVN read: {compare_oem(ours, back)}")
    d = {"dx": float(np.abs(again.x_eci - ours.x_eci).max()),
         "dP": float(np.abs(again.cov_P - ours.cov_P).max() / np.abs(ours.cov_P).max())}
    print(f"its KVN written in {t_wk:.2f} s, read back by fgnav: {d}")
    imp = subprocess.run([sys.executable, "-X", "importtime", "-c", "import ccsds_ndm"],
                         capture_output=True, text=True).stderr.strip().splitlines()[-1]
    print(f"import ccsds_ndm (-X importtime, last line, us): {imp}")


def fgnav_written() -> None:
    """fgnav's own AEM and TDM (the corpus has no TDM fgnav reads): ccsds-ndm-py's numbers."""
    print("\n## fgnav-written AEM 2.0 and TDM 2.0\n")
    rng = np.random.default_rng(7)
    n = 50
    t_s = np.arange(n) * 10.0
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    R = np.array([matrix_from_quat(qi) for qi in q]).reshape(-1, 3, 3)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    with tempfile.TemporaryDirectory() as tmp:
        aem, tdm = Path(tmp) / "a.aem", Path(tmp) / "a.tdm"
        write_aem(aem, "2025-03-01T00:00:00", t_s, R)
        write_tdm(tdm, "2025-03-01T00:00:00", t_s, u, 1e-4)
        a_ours = read_aem(aem)
        what, msg = ndm_read(aem)
        print(f"- AEM, {n} quaternions: ccsds-ndm-py {what}"
              + (f", {compare_aem(a_ours, msg)}" if what == "read" else f": {msg}"))
        t_ours = read_tdm(tdm)
        what, msg = ndm_read(tdm)
        if what != "read":
            print(f"- TDM, {n} RA/Dec pairs: ccsds-ndm-py {what}: {msg}")
            tdm.write_text("".join(ln for ln in tdm.read_text().splitlines(True) if ln.strip()))
            what, msg = ndm_read(tdm)
            print(f"  the same file without its blank lines (503.0-B-2 4.2.10 allows them "
                  f"anywhere): {what}" + ("" if what == "read" else f": {msg}"))
            if what != "read":
                return
        obs = [o for s in msg.segments for o in s.data.observations]
        ra = np.radians([o.value for o in obs if o.keyword == "ANGLE_1"])
        dec = np.radians([o.value for o in obs if o.keyword == "ANGLE_2"])
        ep = [o.epoch for o in obs if o.keyword == "ANGLE_1"]
        un = np.column_stack([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)])
        ang = np.linalg.norm(un - t_ours.xyz, axis=1).max()   # the chord: arccos floors at 2e-8
        print(f"- TDM, {n} RA/Dec pairs: ccsds-ndm-py read, {len(ra)} pairs, max |dt| "
              f"{np.abs(_seconds(ep, t_ours.epoch0) - t_ours.t_s).max():.3g} s, max angle "
              f"between the directions {ang:.3g} rad")


if __name__ == "__main__":
    if len(sys.argv) < 2 or CORPUS is None:
        sys.exit(__doc__)
    print(f"ccsds-ndm-py {version('ccsds-ndm-py')}, "
          f"corpus {CORPUS}\n")
    corpus("--files" in sys.argv[2:])
    fgnav_written()
    speed(Path(sys.argv[1]))
