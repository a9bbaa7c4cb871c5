"""Derive the run-time star catalogue ``fgnav/data/catalogue/bsc5.csv`` from the Yale BSC5 file.

Input: ``../shared/data/stars_bsc5.csv`` beside a checkout (Yale Bright Star Catalogue, 5th revised ed.,
public domain, VizieR V/50; J2000/FK5 positions at epoch J2000, proper motions in mas/yr
with pmra including cos(dec)). Output: the same stars, HR number as an integer, sorted by
HR number, columns ``hr,ra_deg,dec_deg,vmag,pmra_mas_yr,pmdec_mas_yr,hd,name``; stars
fainter than ``--vmag-max`` are dropped (default 7.96 keeps all). Rerun:

    python -m fgnav.vision.catalogue_build [--src PATH] [--out PATH] [--vmag-max V]

(``scripts/build_star_catalogue.py`` runs the same from a checkout.) An installed package
ships the catalogue already; ``--out`` writes another one, which ``FGNAV_DATA`` or a path
given to :func:`fgnav.vision.catalogue.load_catalogue` can then use.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
from pathlib import Path

from fgnav.paths import data_dir

# a checkout: <work>/<checkout>/fgnav/vision/catalogue_build.py beside <work>/shared/data
DEFAULT_SRC = Path(__file__).resolve().parents[3] / "shared" / "data" / "stars_bsc5.csv"
DEFAULT_OUT = data_dir() / "catalogue" / "bsc5.csv"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--src", type=Path, default=DEFAULT_SRC, help="BSC5 CSV (id,ra_deg,dec_deg,vmag,...)")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output CSV")
    ap.add_argument("--vmag-max", type=float, default=99.0, help="faintest V magnitude kept (mag)")
    a = ap.parse_args(argv)
    if not a.src.is_file():
        ap.error(f"--src {a.src}: no such file (the Yale BSC5 CSV: id,ra_deg,dec_deg,vmag,...)")
    rows = []
    with open(a.src, newline="", encoding="utf-8") as fh:
        for r in csv.DictReader(fh):
            if float(r["vmag"]) > a.vmag_max:
                continue
            rows.append([int(r["id"].removeprefix("HR")), f"{float(r['ra_deg']):.6f}",
                         f"{float(r['dec_deg']):.6f}", f"{float(r['vmag']):.2f}", int(r["pmra_mas_yr"]),
                         int(r["pmdec_mas_yr"]), int(r["hd"]), " ".join(r["name"].split())])
    rows.sort(key=lambda r: r[0])
    a.out.parent.mkdir(parents=True, exist_ok=True)
    with open(a.out, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["hr", "ra_deg", "dec_deg", "vmag", "pmra_mas_yr", "pmdec_mas_yr", "hd", "name"])
        w.writerows(rows)
    sha = hashlib.sha256(a.src.read_bytes()).hexdigest()
    print(f"wrote {len(rows)} stars to {a.out} (source sha256 {sha[:16]}...)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
