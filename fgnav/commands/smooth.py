"""``fgnav smooth LOG --method batch|isam2|fixed-lag|ekf --out DIR``."""

from fgnav.defaults import DEFAULT_Q_M2_S3


def add_solver_options(p):
    """Options shared by smooth and demo (motion model and noise)."""
    p.add_argument("--process-noise", type=float, metavar="Q",
                   help=f"white-acceleration PSD of the motion prior (m^2/s^3; default {DEFAULT_Q_M2_S3:g}:"
                        " raise it when forces are missing from the model)")
    p.add_argument("--third-body", action="store_true",
                   help="add Sun and Moon point-mass gravity (analytic ephemeris) to the motion model")
    p.add_argument("--lag-s", type=float, default=300.0,
                   help="fixed-lag window (s, default 300): each state is reported smoothed with "
                        "lag-s to lag-s + 60 s of later data")
    p.add_argument("--robust", choices=["none", "huber", "cauchy"], default="none",
                   help="robust cost on measurements (batch, isam2, fixed-lag): huber is convex, "
                        "cauchy rejects gross outliers (default none)")
    p.add_argument("--robust-k", type=float,
                   help="robust threshold in sigmas (default 1.345 huber, 2.3849 cauchy)")
    p.add_argument("--gate", type=float, metavar="P",
                   help="EKF / iSAM2: reject a measurement whose innovation exceeds the chi-square "
                        "quantile P of its dimension (e.g. 0.9999)")


def solver_options(args):
    from fgnav.solvers.batch import SmootherOptions

    kw = {"third_body": bool(args.third_body),
          "robust": None if args.robust == "none" else args.robust, "robust_k": args.robust_k,
          "gate_probability": args.gate}
    if args.process_noise is not None:
        if not args.process_noise > 0:
            from fgnav.errors import UserError
            raise UserError(f"--process-noise must be > 0 (m^2/s^3), got {args.process_noise}")
        kw["q_m2_s3"] = args.process_noise
    return SmootherOptions(**kw)


def register(sub):
    p = sub.add_parser("smooth", help="estimate the orbit from a measurement log",
                       description="Smooth a logged pass (CSV v1 or CCSDS TDM) in batch, online with "
                                   "iSAM2 / a fixed-lag smoother, or filter it with the EKF baseline. "
                                   "Writes DIR/trajectory.oem (CCSDS OEM with covariances) and "
                                   "DIR/summary.json.")
    p.add_argument("log", help="measurement log (.csv, v1 format; or .tdm)")
    p.add_argument("--method", default="batch", choices=["batch", "isam2", "fixed-lag", "ekf"])
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--truth", help="truth OEM: adds errors and NEES to summary.json")
    p.add_argument("--rerun", metavar="FILE.rrd", help="also write a Rerun recording")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors and the "
                                                         "integrity warning")
    p.add_argument("--strict", action="store_true",
                   help="exit 3 when the integrity verdict is not 'ok' (outputs are written)")
    p.add_argument("--checkpoint", metavar="FILE.npz",
                   help="isam2: save the online state every --checkpoint-every epochs")
    p.add_argument("--checkpoint-every", type=int, default=100, metavar="N",
                   help="epochs between checkpoints (default 100)")
    p.add_argument("--resume", action="store_true",
                   help="isam2: continue from --checkpoint (same log and options)")
    p.add_argument("--ignore-prior", action="store_true",
                   help="leave the log's prior_position/prior_velocity rows out and start from the "
                        "orbit the measurements give (angles-only initial orbit determination; "
                        "logs without prior rows, e.g. a CCSDS TDM, always do)")
    add_solver_options(p)
    p.set_defaults(func=run)


class ProgressCallback:
    """The solvers' progress callback drawn as a bar: epochs for the online methods,
    Gauss-Newton iterations (with the largest position update) for batch."""

    def __init__(self, method: str, quiet: bool):
        from fgnav.progress import progress

        self.batch = method == "batch"
        self.bar = progress(desc=f"{method}", unit="iter" if self.batch else "epoch", quiet=quiet)

    def __call__(self, *state):
        if self.batch:
            q, iteration, step_m = state
            self.bar.set_postfix_str(f"q={q:.0e} m2/s3, update {step_m:.3g} m", refresh=False)
        self.bar.update(1)

    def close(self):
        self.bar.close()


def run(args) -> int:
    import json

    from fgnav.pipeline import read_measurements, residual_times, smooth_file, write_outputs

    bar = ProgressCallback(args.method, args.quiet)
    try:
        res, p = smooth_file(args.log, args.method, solver_options(args), truth_path=args.truth,
                             lag_s=args.lag_s, checkpoint=args.checkpoint,
                             checkpoint_every=args.checkpoint_every, resume=args.resume,
                             ignore_prior=args.ignore_prior, progress=bar)
    finally:
        bar.close()
    write_outputs(args.out, res, p)
    if args.rerun:
        from fgnav.viz.rerun_log import log_solution
        log_solution(args.rerun, res.solution, truth_x_eci=res.x_true,
                     measurements=read_measurements(args.log), residual_t_s=residual_times(res, p))
    integrity = res.summary["integrity"]
    if not args.quiet:
        keys = ["method", "epochs", "iterations", "wall_s", "crb_position_rms_m", "position_rms_m",
                "velocity_rms_mps", "nees_mean"]
        brief = {k: res.summary[k] for k in keys if k in res.summary}
        brief["integrity"] = integrity["status"]
        print(json.dumps(brief, indent=1))
    from fgnav.integrity import stderr_line
    line = stderr_line(integrity)
    if line:
        import sys
        print(line, file=sys.stderr)
    return 3 if args.strict and integrity["status"] != "ok" else 0
