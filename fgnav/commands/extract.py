"""``fgnav extract FRAMES --out measurements.csv``: image frames -> measurement log."""

from __future__ import annotations

from fgnav.commands import _types as T

HELP = """\
Run the image front end over a pass: FRAMES is a frames.csv index (or the directory holding
it, or its frames/ image directory), as written by `fgnav simulate SCENARIO --out DIR
--images`. Star frames -> star detection, lost-in-space identification (BSC5) -> attitude
with covariance; limb frames -> limb points, RANSAC, horizon fix (Earth direction + limb
angular radius). Written rows (CSV v1, see fgnav.io.log_csv):
  earth_direction  u_eci = R_eci_from_body u_body, sigma (rad) = sqrt of the largest
                   eigenvalue of its tangent-plane covariance, attitude error folded in
  limb_radius      rho (rad), R_limb (m), sigma_rho (rad)
  (--rows body: earth_direction_body + attitude rows instead of earth_direction)
  (--raw-stars: every identified star as a star_direction_body row -- star_x, star_y,
   star_z its catalogue unit vector, sigma its centroid 1-sigma (scaled by the frame
   fit's a-posteriori variance factor) in rad per tangent axis --
   plus earth_direction_body rows, instead of one solved attitude; solve with
   `fgnav smooth --estimate attitude`)
  prior_position / prior_velocity copied from --priors (default: measurements.csv beside
  frames.csv, when present).
--json prints one object: frames, epochs, rows (per kind), failures (per reason),
median_sigma_direction_deg, median_sigma_rho_deg, out.
"""


def register(subparsers) -> None:
    import argparse

    p = subparsers.add_parser("extract", help="image frames (frames.csv) -> measurement log",
                              description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("frames", metavar="FRAMES", help="frames.csv, or a directory holding it (or its frames/)")
    p.add_argument("--out", required=True, help="output measurement log (.csv, v1 format)")
    p.add_argument("--method", choices=("ellipse", "christian-robinson"), default="christian-robinson",
                   help="horizon estimator (default: christian-robinson)")
    p.add_argument("--rows", choices=("eci", "body"), default=None,
                   help="eci: earth_direction rows with the attitude error folded in (default); "
                        "body: earth_direction_body + attitude rows")
    p.add_argument("--raw-stars", action="store_true",
                   help="tight coupling: the identified stars of each star frame as "
                        "star_direction_body rows (and earth_direction_body rows) instead of "
                        "one solved attitude")
    p.add_argument("--priors", metavar="LOG", help="measurement log whose prior rows are copied "
                                                   "(default: measurements.csv beside frames.csv)")
    p.add_argument("--edge-floor-px", type=T.number(0.0, unit="px"), default=0.0,
                   help="limb-edge systematic floor added to the direction and rho sigmas "
                        "(px; default 0)")
    p.add_argument("--no-curvature-correction", action="store_true",
                   help="do not correct the limb edge-curvature bias (needs psf_sigma_px in frames.csv)")
    p.add_argument("--seed", type=T.seed, default=0, help="RANSAC random seed (default 0)")
    p.add_argument("--attitude-out", metavar="FILE.csv",
                   help="also write the star-derived attitude per epoch (quaternion w,x,y,z of "
                        "R_eci_from_body and its covariance; columns in fgnav/io/attitude_csv.py)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=run)


def run(args) -> int:
    import json
    from pathlib import Path

    from fgnav.extract import extract_frames
    from fgnav.io.log_csv import write_log

    from fgnav.errors import UserError

    if args.raw_stars and args.rows is not None:
        raise UserError(f"--raw-stars writes star_direction_body and earth_direction_body rows; "
                        f"it cannot be combined with --rows {args.rows}")
    rows = "raw-stars" if args.raw_stars else (args.rows or "eci")
    res = extract_frames(args.frames, method=args.method, rows=rows, priors=args.priors,
                         seed=args.seed, edge_floor_px=args.edge_floor_px,
                         curvature_correction=not args.no_curvature_correction,
                         quiet=args.quiet or args.json)
    out = Path(args.out)
    if out.parent and not out.parent.exists():
        out.parent.mkdir(parents=True, exist_ok=True)
    write_log(out, res.log, comments=(f"fgnav extract {args.frames}: method {args.method}, "
                                      f"rows {rows}, seed {args.seed}",))
    s = res.summary()
    s["out"] = str(out)
    if args.attitude_out:
        from fgnav.io.attitude_csv import write_attitude_csv

        att = [e for e in res.epochs if e.R_eci_from_body is not None]
        write_attitude_csv(args.attitude_out, [e.epoch for e in att],
                           [e.R_eci_from_body for e in att], [e.P_att_rad2 for e in att],
                           comments=(f"fgnav extract {args.frames}: star-derived attitude",))
        s["attitude_out"] = str(args.attitude_out)
    if args.json:
        print(json.dumps(s))
    elif not args.quiet:
        rows = ", ".join(f"{k} {v}" for k, v in s["rows"].items())
        print(f"{s['frames']} frames, {s['epochs']} epochs -> {out} ({rows})")
        if s["median_sigma_direction_deg"] is not None:
            print(f"median 1-sigma: direction {s['median_sigma_direction_deg']:.2e} deg"
                  + (f", rho {s['median_sigma_rho_deg']:.2e} deg" if s["median_sigma_rho_deg"] else ""))
        if s["failures"]:
            print("failures: " + ", ".join(f"{k} {v}" for k, v in s["failures"].items()))
    return 0
