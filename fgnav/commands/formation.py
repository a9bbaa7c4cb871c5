"""``fgnav formation``: inter-satellite pseudorange relative navigation (Xing et al.).

Subcommands:
- ``conditioning``: Cartesian vs spherical conditioning on Xing et al.'s geometry (rcond of
  A^T A, covariance at two epochs, Monte Carlo 1-sigma coverage of the range); with
  ``--log LOG [--epoch ISO]`` on one epoch of a logged formation pass (its six
  isl_pseudorange rows, declared antennas and both attitude rows).
- ``track``: time-series case (a 1 km CW relative orbit in LEO, simulated as a formation and
  solved by the one pipeline, batch or iSAM2); writes ``DIR/trajectory.csv`` and
  ``DIR/summary.json`` (and a Rerun recording when asked). ``--param`` names the coordinates
  the result is reported in: the smoother's minimum does not depend on the chart.
"""

from __future__ import annotations

import json

from fgnav.commands import _types as T

MAX_TRACK_EPOCHS = 1000


def register(subparsers):
    p = subparsers.add_parser("formation", help="formation relative navigation from "
                              "inter-satellite pseudoranges (Xing et al.)",
                              description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="formation_command", metavar="SUBCOMMAND")

    c = sub.add_parser("conditioning", help="Cartesian vs spherical conditioning study",
                       description="Xing et al.'s single-epoch study: rcond of A^T A for "
                                   "Cartesian and spherical unknowns, the 1-sigma of range, "
                                   "angles and clock, and the Monte Carlo coverage of the "
                                   "range; on the built-in geometry, or with --log on one "
                                   "epoch of a logged pass (six isl_pseudorange rows between "
                                   "the first two spacecraft, their declared antennas, and "
                                   "both spacecraft's attitude rows at that epoch).")
    c.add_argument("--log", metavar="LOG.csv",
                   help="a measurement log with a spacecraft column (e.g. from `fgnav "
                        "simulate formation-gto`; the shipped data/formation/"
                        "xing-single-epoch.csv is Xing et al.'s geometry)")
    c.add_argument("--epoch", metavar="ISO",
                   help="with --log: the epoch to study, ISO-8601 UTC (default the first "
                        "epoch with isl_pseudorange rows)")
    c.add_argument("--out", metavar="FILE.json", help="also write the figures as JSON")
    c.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    c.add_argument("--runs", type=int, default=5000,  # checked in run
                   help="Monte Carlo runs for the 1-sigma coverage of R (default 5000)")
    c.add_argument("--seed", type=T.seed, default=0, help="random seed (default 0)")
    c.add_argument("--sigma-cm", type=T.pos("cm"), default=None,
                   help="pseudorange noise, 1 sigma, cm (default 1 cm, Xing et al.; with --log "
                        "the rows' sigma column)")
    c.set_defaults(func=run_conditioning)

    t = sub.add_parser("track", help="time-series relative navigation on a 1 km CW orbit",
                       description="The track case as a formation: a circular LEO chief and a "
                                   "deputy on a closed Clohessy-Wiltshire orbit, simulated with "
                                   "the formation simulator (independent truth; each spacecraft "
                                   "also has its Earth direction, attitude and prior rows) and "
                                   "solved by the one pipeline (both orbits, the relative clock "
                                   "and any ambiguities in one graph). Reports sat 2 in sat 1's "
                                   "body frame, Cartesian and spherical, with 1-sigmas mapped "
                                   "by the Jacobian.")
    t.add_argument("--param", choices=("spherical", "cartesian"), default="spherical",
                   help="coordinates the relative position's NEES is reported in (default "
                        "spherical); the smoother's minimum does not depend on the chart")
    t.add_argument("--solver", choices=("batch", "isam2"), default="batch",
                   help="the pipeline's batch smoother or iSAM2 (default batch)")
    t.add_argument("--out", required=True, metavar="DIR",
                   help="output directory for trajectory.csv and summary.json")
    t.add_argument("--rerun", metavar="FILE.rrd", help="also write a Rerun recording")
    t.add_argument("--carrier", action="store_true",
                   help="add carrier phase (10 um) with a float ambiguity per link")
    t.add_argument("--duration-s", type=T.pos("s"), default=600.0, help="track length, s (default 600)")
    t.add_argument("--step-s", type=T.pos("s"), default=10.0, help="epoch spacing, s (default 10)")
    t.add_argument("--radius-m", type=T.pos("m"), default=1000.0,
                   help="relative orbit radius = separation, m (default 1000)")
    t.add_argument("--alt-km", type=T.number(100.0, 100000.0, unit="km"), default=500.0,
                   help="chief altitude, km (default 500)")
    t.add_argument("--sigma-cm", type=T.pos("cm"), default=1.0, help="pseudorange noise, cm (default 1)")
    t.add_argument("--seed", type=T.seed, default=0, help="random seed (default 0)")
    t.add_argument("--max-epochs", type=T.integer(2), default=MAX_TRACK_EPOCHS, metavar="N",
                   help=f"refuse a track of more than N epochs (duration / step + 1; default "
                        f"{MAX_TRACK_EPOCHS})")
    t.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    t.set_defaults(func=run_track)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def run_conditioning(args) -> int:
    from fgnav.errors import UserError

    if args.runs < 1:
        raise UserError(f"--runs must be >= 1, got {args.runs}")
    sigma_cm = 1.0 if args.sigma_cm is None else args.sigma_cm
    if not sigma_cm > 0:
        raise UserError(f"--sigma-cm must be positive, got {sigma_cm}")
    log_path = getattr(args, "log", None)
    epoch = getattr(args, "epoch", None)
    if epoch is not None and log_path is None:
        raise UserError("--epoch needs --log (the epoch of a logged pass)")
    if log_path is not None:
        from fgnav.formation.logged import logged_conditioning, logged_epoch
        from fgnav.io.log_csv import read_log

        if args.sigma_cm is not None:
            raise UserError("--sigma-cm: with --log the rows' sigma column is the noise")
        ep = logged_epoch(read_log(log_path), epoch)
        out = logged_conditioning(ep, runs=args.runs, seed=args.seed)
    else:
        from fgnav.formation.study import conditioning_study

        out = conditioning_study(runs=args.runs, seed=args.seed, sigma_m=sigma_cm / 100.0)
    if getattr(args, "out", None):
        from fgnav.io.atomic import atomic_writer

        try:
            with atomic_writer(args.out, "w") as fh:
                json.dump(out, fh, indent=2)
        except OSError as exc:
            raise UserError(f"--out {args.out}: cannot write: {exc.strerror or exc}") from None
    if args.json:
        print(json.dumps(out))
        return 0
    if log_path is not None:
        lg = out["log"]
        print(f"{lg['path']}, epoch {lg['epoch']}: {len(lg['links'])} links between "
              f"{' and '.join(lg['spacecraft'])}; estimate R = {out['estimate']['R_m']:.4f} m, "
              f"az = {out['estimate']['az_rad']:.4g} rad, el = {out['estimate']['el_rad']:.4g} "
              f"rad, c dt = {100 * out['estimate']['cdt_m']:.3f} cm")
    for p in ("cartesian", "spherical"):
        d = out[p]
        change = ("" if "covariance" not in d or "relative_change" not in d["covariance"] else
                  f"; covariance change between epochs = "
                  f"{d['covariance']['relative_change']:.3g} (in epoch-1 sigmas)")
        print(f"{p:9s}: rcond(A^T A) = {d['rcond']:.3g} (1-norm {d['rcond_1norm']:.3g}), "
              f"cond = {d['cond']:.3g}{change}")
    s = out["spherical"].get("sigmas_epoch1", out["spherical"].get("sigmas"))
    print(f"sigma_R = {100 * s[0]:.3f} cm, sigma_az = {s[1]:.4f} rad, sigma_el = {s[2]:.4f} rad, "
          f"sigma_clock = {100 * s[3]:.3f} cm")
    print(f"Monte Carlo ({out['runs']} runs): {100 * out['coverage_1sigma']:.1f} % of range "
          f"errors within +-1 sigma (Gaussian 68.3 %)")
    return 0


def run_track(args) -> int:
    from fgnav.errors import UserError
    from fgnav.formation.study import FormationScenario, run_track as _run

    if not args.sigma_cm > 0:
        raise UserError(f"--sigma-cm must be positive, got {args.sigma_cm}")
    n = int(min(args.duration_s / args.step_s, 1e15)) + 1
    if n > args.max_epochs:
        raise UserError(f"--duration-s {args.duration_s:g} / --step-s {args.step_s:g}: {n:,} epochs "
                        f"exceed the limit of {args.max_epochs:,}; lengthen --step-s, shorten "
                        "--duration-s, or raise the limit with --max-epochs N")
    sc = FormationScenario(alt_km=args.alt_km, radius_m=args.radius_m, duration_s=args.duration_s,
                           step_s=args.step_s, sigma_code_m=args.sigma_cm / 100.0,
                           carrier=args.carrier)
    summary = _run(sc, args.param, args.solver, args.seed, args.out, args.rerun)
    if args.json:
        print(json.dumps(summary))
    else:
        e, s = summary["rms_error"], summary["mean_sigma"]
        print(f"{args.param} / {args.solver}: {summary['n_epochs']} epochs; RMS error R "
              f"{1e3 * e['R_m']:.3f} mm (sigma {1e3 * s['R_m']:.3f}), az {e['az_rad']:.3g} rad "
              f"(sigma {s['az_rad']:.3g}), el {e['el_rad']:.3g} rad (sigma {s['el_rad']:.3g}); "
              f"mean position NEES {summary['mean_nees_position']:.2f} (3 expected); "
              f"wrote {args.out}/trajectory.csv, summary.json")
    verdict = summary["info"].get("integrity", "ok")
    if verdict != "ok":   # the pipeline's verdict: the numbers above are not to be trusted
        import sys

        reasons = "; ".join(summary["info"].get("integrity_reasons", [])) or "no reason given"
        print(f"fgnav formation track: integrity verdict '{verdict}': {reasons} (the solution "
              "does not fit the rows; measured: batch on tracks of 3000 s and more settles in "
              "a wrong minimum, --solver isam2 does not)", file=sys.stderr)
    return 0
