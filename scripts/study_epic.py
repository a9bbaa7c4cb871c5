#!/usr/bin/env python
"""Range from the limb on twelve real DSCOVR/EPIC frames against NASA's metadata (docs/epic.md).

    PYTHONPATH=$PWD python scripts/study_epic.py [--data DIR] [--json OUT] [--markdown]

Each frame (``epic_1b_*.jpg``, 1080x1080 level-1B natural colour, north-up and re-centred)
is solved by ``fgnav limb`` itself (in-process, ``--json``) with EPIC's nominal camera
(:data:`FOV_DEG` over the product's 1080 px) and compared with
``|dscovr_j2000_position|`` of its metadata file (``2022-MM-10.txt``). The attitude of a
north-up re-centred product (:func:`fgnav.vision.real_limb.north_up_R_eci_from_cam`) takes
the direction to the Earth from the metadata, never its distance; the Sun direction is the
metadata's ``sun_j2000_position``.

The limb model is built up one effect at a time (:data:`STEPS`), each run on all twelve
frames: the sphere (what ``fgnav limb`` did before), the flattening at each frame's
attitude, the lit limb, correlated residuals, the model-error floor; then the final model
with the limb raised by :data:`HEIGHT_PROBE_KM` and on the other channels. Per step: the
mean range error (the common bias), the frame-to-frame scatter (sample standard deviation)
and the RMS of (error - mean) over each frame's reported 1-sigma. Prints JSON (or Markdown).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fgnav.cli import main as cli_main  # noqa: E402
from fgnav.vision.attitude import quat_from_matrix  # noqa: E402
from fgnav.vision.real_limb import north_up_R_eci_from_cam  # noqa: E402

FOV_DEG = 0.62
"""EPIC's full field of view (NASA GSFC, "EPIC: Earth Polychromatic Imaging Camera",
epic.gsfc.nasa.gov/about/epic: 0.62 deg on the 2048x2048 CCD behind a 30-cm Cassegrain);
the 1080-px level-1B JPEGs span the same field (docs/references.md)."""

R_LIMB_KM = 6378.137
"""Limb radius: the WGS-84 equatorial radius, limb height 0 (docs/epic.md: the level-1B
product is redrawn from NASA's Earth model; its sky is exactly 0)."""

FLOOR_PX = 0.05
"""Model-error floor (px) on the limb's radius and centre (docs/epic.md)."""

HEIGHT_PROBE_KM = 10.0
"""A limb 10 km higher: what a cloud-top limb would move (docs/epic.md)."""

STEPS = (
    ("sphere", []),
    ("+ flattening", ["--attitude"]),
    ("+ lit limb", ["--attitude", "--sun-eci"]),
    ("+ correlated residuals", ["--attitude", "--sun-eci", "--correlated-residuals"]),
    ("+ floor", ["--attitude", "--sun-eci", "--correlated-residuals", "--floor-px"]),
)
"""Cumulative limb-model steps: name -> the options added (values filled per frame)."""

DEFAULT_DATA = [ROOT.parent / "shared" / "data" / "epic", Path("/work/shared/data/epic")]


def find_data(explicit: str | None = None) -> Path | None:
    """The EPIC frame directory: ``explicit``, else ../shared/data/epic, else /work/shared/data/epic."""
    for d in ([Path(explicit)] if explicit else DEFAULT_DATA):
        if d.is_dir() and any(d.glob("epic_1b_*.jpg")):
            return d
    return None


def frames(data: Path) -> list[dict]:
    """One dict per frame: name, image path, NASA range (m), R_eci_from_cam, Sun (ECI)."""
    out = []
    for meta in sorted(data.glob("2022-*.txt")):
        d = json.loads(meta.read_text())
        p = d["dscovr_j2000_position"]
        s = d["sun_j2000_position"]
        r_m = np.array([p["x"], p["y"], p["z"]]) * 1e3
        sun = np.array([s["x"], s["y"], s["z"]]) * 1e3
        image = data / (d["image"] + ".jpg")
        if not image.is_file():
            raise FileNotFoundError(f"{meta}: its image {image.name} is missing")
        R = north_up_R_eci_from_cam(-r_m)
        phase = float(np.degrees(np.arccos(r_m @ sun / np.linalg.norm(r_m) / np.linalg.norm(sun))))
        out.append({"name": meta.stem, "image": image, "range_nasa_m": float(np.linalg.norm(r_m)),
                    "R": R, "sun_eci": sun, "phase_deg": phase,
                    "sub_lat_deg": float(np.degrees(np.arcsin(r_m[2] / np.linalg.norm(r_m))))})
    return out


def limb_args(frame: dict, options: list[str], *, channel: str = "red", r_limb_km: float = R_LIMB_KM,
              floor_px: float = FLOOR_PX) -> list[str]:
    """The ``fgnav limb`` command line of one frame with the given option names."""
    argv = ["limb", str(frame["image"]), "--fov-deg", f"{FOV_DEG:g}", "--channel", channel,
            "--r-limb-km", f"{r_limb_km:.3f}", "--json"]
    for opt in options:
        if opt == "--attitude":
            argv.append(opt + "=" + ",".join(f"{q:.12f}" for q in quat_from_matrix(frame["R"])))
        elif opt == "--sun-eci":
            argv.append(opt + "=" + ",".join(f"{x:.6e}" for x in frame["sun_eci"]))
        elif opt == "--floor-px":
            argv += [opt, f"{floor_px:g}"]
        else:
            argv.append(opt)
    return argv


def solve(frame: dict, options: list[str], **kw) -> dict:
    """Run ``fgnav limb`` on one frame; its JSON plus range error and 1-sigma (fractions)."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = cli_main(limb_args(frame, options, **kw))
    if rc != 0:
        raise RuntimeError(f"fgnav limb failed on {frame['image']} (exit {rc})")
    out = json.loads(buf.getvalue())
    r = np.array(out["r_cam_m"])
    u = r / np.linalg.norm(r)
    rng = float(np.linalg.norm(r))
    sigma = float(np.sqrt(u @ np.array(out["cov_r_cam_m2"]) @ u)) / rng
    pix = out.get("sigma_rho_pixel_rad", out["sigma_rho_rad"]) / np.tan(out["rho_rad"])
    return {"range_m": rng, "error": rng / frame["range_nasa_m"] - 1.0, "sigma": sigma,
            "sigma_pixel": float(pix), "n_points": out["n_points"], "n_unlit": out.get("n_unlit", 0),
            "variance_inflation": out.get("variance_inflation", 1.0), "sigma_px": out["sigma_px"]}


def summarize(rows: list[dict]) -> dict:
    """Common bias, frame-to-frame scatter and RMS of (error - bias) / sigma."""
    e = np.array([r["error"] for r in rows])
    s = np.array([r["sigma"] for r in rows])
    bias = float(e.mean())
    return {"mean_error": bias, "max_abs_error": float(np.abs(e).max()), "scatter": float(e.std(ddof=1)),
            "rms_norm": float(np.sqrt(np.mean(((e - bias) / s) ** 2))), "median_sigma": float(np.median(s))}


def study(data: Path) -> dict:
    """Every step of :data:`STEPS` on every frame, the height probe and the channels."""
    fr = frames(data)
    out = {"fov_deg": FOV_DEG, "r_limb_km": R_LIMB_KM, "floor_px": FLOOR_PX, "steps": [], "frames": []}
    final_opts = STEPS[-1][1]
    per_step = []
    for name, opts in STEPS:
        rows = [solve(f, opts) for f in fr]
        per_step.append(rows)
        out["steps"].append({"step": name, "options": opts, **summarize(rows)})
    final = per_step[-1]
    for f, r in zip(fr, final):
        out["frames"].append({"frame": f["name"], "range_nasa_km": f["range_nasa_m"] / 1e3,
                              "range_fgnav_km": r["range_m"] / 1e3, "error": r["error"], "sigma": r["sigma"],
                              "sigma_pixel": r["sigma_pixel"], "phase_deg": f["phase_deg"],
                              "sub_lat_deg": f["sub_lat_deg"], "n_points": r["n_points"],
                              "n_unlit": r["n_unlit"], "variance_inflation": r["variance_inflation"]})
    for i, row in enumerate(out["frames"]):
        e = [rows[i]["error"] for rows in per_step]
        row["error_by_step"] = dict(zip([n for n, _ in STEPS], e))
        row["d_flattening"] = e[1] - e[0]            # what each effect moves the range by
        row["d_lit_limb"] = e[2] - e[1]
    b = out["steps"][-1]["mean_error"]
    for row in out["frames"]:
        row["norm"] = (row["error"] - b) / row["sigma"]
    rows = [solve(f, final_opts, r_limb_km=R_LIMB_KM + HEIGHT_PROBE_KM) for f in fr]
    out["height_probe"] = {"height_km": HEIGHT_PROBE_KM, **summarize(rows)}
    out["channels"] = {}
    for ch in ("green", "blue", "gray"):
        out["channels"][ch] = summarize([solve(f, final_opts, channel=ch) for f in fr])
    return out


def markdown(res: dict) -> str:
    """The tables of docs/epic.md."""
    lines = ["| frame | phase (deg) | sub-lat (deg) | NASA range (km) | fgnav range (km) | error (%) "
             "| reported 1-sigma (%) | pixel-noise 1-sigma (%) | (error - bias) / sigma "
             "| sphere error (%) | flattening (%) | lit limb (%) | inflation k |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in res["frames"]:
        lines.append(f"| {r['frame']} | {r['phase_deg']:.1f} | {r['sub_lat_deg']:+.1f} | {r['range_nasa_km']:,.0f} "
                     f"| {r['range_fgnav_km']:,.0f} | {100 * r['error']:+.3f} | {100 * r['sigma']:.4f} "
                     f"| {100 * r['sigma_pixel']:.4f} | {r['norm']:+.2f} "
                     f"| {100 * r['error_by_step']['sphere']:+.3f} | {100 * r['d_flattening']:+.3f} "
                     f"| {100 * r['d_lit_limb']:+.3f} | {r['variance_inflation']:.1f} |")
    lines += ["", "| limb model | mean error (%) | scatter (%) | RMS (error - bias) / sigma | median 1-sigma (%) |",
              "|---|---|---|---|---|"]
    for s in res["steps"]:
        lines.append(f"| {s['step']} | {100 * s['mean_error']:+.3f} | {100 * s['scatter']:.3f} "
                     f"| {s['rms_norm']:.2f} | {100 * s['median_sigma']:.4f} |")
    h = res["height_probe"]
    lines.append(f"| final, limb +{h['height_km']:g} km | {100 * h['mean_error']:+.3f} | {100 * h['scatter']:.3f} "
                 f"| {h['rms_norm']:.2f} | {100 * h['median_sigma']:.4f} |")
    for ch, s in res["channels"].items():
        lines.append(f"| final, {ch} channel | {100 * s['mean_error']:+.3f} | {100 * s['scatter']:.3f} "
                     f"| {s['rms_norm']:.2f} | {100 * s['median_sigma']:.4f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None, help="EPIC frame directory (default ../shared/data/epic)")
    ap.add_argument("--json", default=None, help="also write the JSON here")
    ap.add_argument("--markdown", action="store_true", help="print the docs/epic.md tables")
    a = ap.parse_args(argv)
    data = find_data(a.data)
    if data is None:
        print("study_epic: no EPIC frames found (../shared/data/epic)", file=sys.stderr)
        return 2
    res = study(data)
    text = json.dumps(res, indent=1, default=str)
    if a.json:
        Path(a.json).write_text(text + "\n")
    print(markdown(res) if a.markdown else text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
