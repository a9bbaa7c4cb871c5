"""``fgnav report RESULT_DIR``: PNG plots plus report.md / report.html of a result directory."""

from __future__ import annotations

from fgnav.commands import _types as T


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "report",
        help="write plots (PNG) and report.md/report.html for a result directory",
        description=(
            "Read RESULT_DIR (from `fgnav smooth LOG --out DIR`: trajectory.oem, summary.json, "
            "residuals.csv, optional online.oem, latency.csv, attitude.aem, "
            "attitude_covariance.csv; a formation's folder: trajectory-<id>.oem per spacecraft and "
            "relative.csv, reported per spacecraft as errors_rtn-<id>.png / sigma_rtn-<id>.png "
            "and for the relative state in the reference's LVLH frame as relative_lvlh-<id>.png "
            "and relative_errors_lvlh-<id>.png / relative_sigma_lvlh-<id>.png) and write errors_rtn.png (or sigma_rtn.png without truth; "
            "m and m/s vs hours, RTN, ±3σ of the same estimate, labelled smoothed / filtered by "
            "method), online_errors_rtn.png (iSAM2, fixed-lag: the online error against the "
            "online ±3σ), residuals_time.png (gaps shaded), residuals_hist.png, "
            "attitude_errors.png (or attitude_sigma.png without truth_attitude.csv beside the "
            "truth OEM), orbit_3d.png (km), latency.png, report.md and report.html. Plots of an "
            "earlier report that this one does not write are removed."
        ),
    )
    p.add_argument("result_dir", metavar="RESULT_DIR", help="result directory of `fgnav smooth`")
    p.add_argument("--out", metavar="DIR", default=None,
                   help="where to write the report (default: RESULT_DIR)")
    p.add_argument("--truth", metavar="TRUTH.oem", default=None,
                   help="truth OEM, or for a formation the directory of its truth-<id>.oem files "
                        "(default: summary.json's truth_path, if any)")
    p.add_argument("--sigma", type=T.positive, default=3.0, metavar="K",
                   help="envelope width in standard deviations (default 3)")
    p.add_argument("--json", action="store_true", help="print one JSON object with the files written")
    p.set_defaults(func=run)


def run(args) -> int:
    import json

    import matplotlib

    matplotlib.use("Agg")
    from fgnav.errors import UserError
    from fgnav.io.outputs import check_output_paths
    from fgnav.viz.report import report_result_dir

    if not args.sigma > 0:
        raise UserError(f"--sigma must be > 0, found {args.sigma}")
    if args.out is not None:   # before any plot: an existing file or an unwritable folder
        check_output_paths(args.out)
    res = report_result_dir(args.result_dir, args.out, truth_path=args.truth, k_sigma=args.sigma)
    info = {"markdown": str(res["markdown"]), "html": str(res["html"]),
            "images": {k: str(v) for k, v in res["images"].items()}, "notes": res["notes"]}
    if args.json:
        print(json.dumps(info))
    else:
        for note in res["notes"]:
            print(f"note: {note}")
        print(f"wrote {info['markdown']}, {info['html']} and {len(info['images'])} plots:")
        for p in info["images"].values():
            print(f"  {p}")
    return 0
