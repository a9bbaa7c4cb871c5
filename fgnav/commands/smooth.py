"""``fgnav smooth LOG --method batch|isam2|fixed-lag|ekf --out DIR``."""

import math

from fgnav.commands import _types as T
from fgnav.defaults import DEFAULT_Q_M2_S3

DEFAULT_LAG_S = 300.0
DEFAULT_CHECKPOINT_EVERY = 100


def add_solver_options(p):
    """Options shared by smooth and demo (motion model and noise)."""
    p.add_argument("--process-noise", type=float, metavar="Q",
                   help=f"white-acceleration PSD of the motion prior (m^2/s^3; default {DEFAULT_Q_M2_S3:g}:"
                        " raise it when forces are missing from the model)")
    p.add_argument("--third-body", action="store_true",
                   help="add Sun and Moon point-mass gravity (analytic ephemeris) to the motion model "
                        "(geocentric logs; a heliocentric log, '# centre: sun', always has the "
                        "Sun and the planets)")
    p.add_argument("--gravity", choices=["j2", "point-mass"], default="j2",
                   help="the Earth's gravity in the motion model: j2 (default: central term + J2) "
                        "or point-mass (central term alone: Keplerian motion, e.g. test data "
                        "simulated without J2)")
    p.add_argument("--lag-s", type=float, default=None,
                   help=f"fixed-lag window (s, default {DEFAULT_LAG_S:g}): each state is reported "
                        "smoothed with lag-s to lag-s + 60 s of later data")
    p.add_argument("--robust", choices=["none", "huber", "cauchy"], default="none",
                   help="robust cost on measurements (batch, isam2, fixed-lag): huber is convex, "
                        "cauchy rejects gross outliers (default none)")
    p.add_argument("--robust-k", type=float,
                   help="robust threshold in sigmas (default 1.345 huber, 2.3849 cauchy)")
    p.add_argument("--gate", type=float, metavar="P",
                   help="isam2, fixed-lag, ekf: reject a measurement whose innovation exceeds the chi-square "
                        "quantile P of its dimension (e.g. 0.9999)")
    p.add_argument("--estimate", action="append", default=[], metavar="VARIABLE",
                   help="also estimate this graph variable, per epoch as a random walk (repeatable): "
                        "refraction-bias (the atmosphere model's tangent-height bias, m); attitude "
                        "(R_eci_from_body, a Rot3: attitude rows become its priors and body-frame "
                        "directions factors on orbit and attitude); camera-alignment (a separate "
                        "star camera's mounting, one Rot3 for the pass: star rows in its frame; "
                        "with attitude); written to variables.csv and summary.json 'variables'")
    p.add_argument("--alignment-sigma-arcsec", type=T.number(0.0, 36000.0, lo_open=True,
                                                            unit="arcsec"),
                   metavar="SIGMA",
                   help="with --estimate camera-alignment: 1-sigma per axis of its prior about "
                        "the nominal mounting (arcsec; default 60, a ground alignment good to "
                        "an arcminute)")


# Which methods each method-specific option applies to (the others would ignore it).
OPTION_METHODS = {
    "--gate": ("isam2", "fixed-lag", "ekf"),
    "--robust": ("batch", "isam2", "fixed-lag"),
    "--robust-k": ("batch", "isam2", "fixed-lag"),
    "--lag-s": ("fixed-lag",),
    "--checkpoint": ("isam2",),
    "--checkpoint-every": ("isam2",),
    "--resume": ("isam2",),
}


def _given(args) -> dict:
    """The method-specific options the user gave (option name -> value)."""
    given = {"--gate": args.gate, "--robust": None if args.robust == "none" else args.robust,
             "--robust-k": args.robust_k, "--lag-s": args.lag_s,
             "--checkpoint": getattr(args, "checkpoint", None),
             "--checkpoint-every": getattr(args, "checkpoint_every", None),
             "--resume": getattr(args, "resume", False) or None}
    return {k: v for k, v in given.items() if v is not None}


def check_solver_args(args, methods) -> None:
    """Validate the solver options before any work (``UserError`` naming the option).

    Values: ``--process-noise`` finite and > 0; ``--lag-s`` finite and > 0; ``--robust-k``
    finite and > 0 (and only with ``--robust huber|cauchy``); ``--gate`` a probability in
    (0, 1); ``--checkpoint-every`` >= 1. An option that none of ``methods`` uses is an error,
    not silently ignored (see ``OPTION_METHODS``). Fills the documented defaults of
    ``--lag-s`` (300 s) and ``--checkpoint-every`` (100) afterwards.
    """
    import math

    from fgnav.errors import UserError

    def finite_positive(name, v, unit):
        if v is not None and not (math.isfinite(v) and v > 0):
            raise UserError(f"{name} must be a finite number > 0 ({unit}), got {v}")

    finite_positive("--process-noise", args.process_noise, "m^2/s^3")
    finite_positive("--lag-s", args.lag_s, "s")
    finite_positive("--robust-k", args.robust_k, "sigmas")
    if args.gate is not None and not 0.0 < args.gate < 1.0:
        raise UserError(f"--gate must be a probability in (0, 1), e.g. 0.9999, got {args.gate}")
    if args.gate is not None and args.gate < 0.5:
        # the probability that a good row passes, not a false-alarm rate: below a half the gate
        # rejects most good rows (a 1e-4 gate kept 6 of 1,448 rows of a formation log)
        raise UserError(f"--gate {args.gate:g}: the probability that a good measurement passes "
                        f"(e.g. 0.9999), not the probability of a false rejection; a gate below "
                        f"0.5 rejects most good measurements. Did you mean {1 - args.gate:g}?")
    every = getattr(args, "checkpoint_every", None)
    if every is not None and every < 1:
        raise UserError(f"--checkpoint-every must be an epoch count >= 1, got {every}")
    if args.robust_k is not None and args.robust == "none":
        raise UserError("--robust-k is the threshold of a robust kernel: give --robust huber "
                        "or --robust cauchy with it")
    for name, value in _given(args).items():
        if not set(methods) & set(OPTION_METHODS[name]):
            uses = ", ".join(OPTION_METHODS[name])
            raise UserError(f"{name} does not apply to --method {'/'.join(methods)} (it is used "
                            f"by {uses} only); remove it or choose one of those methods")
    if not getattr(args, "checkpoint", None):
        for name in ("--resume", "--checkpoint-every"):
            if name in _given(args):
                raise UserError(f"{name} needs --checkpoint FILE.npz")
    if args.lag_s is None:
        args.lag_s = DEFAULT_LAG_S
    if hasattr(args, "checkpoint_every") and args.checkpoint_every is None:
        args.checkpoint_every = DEFAULT_CHECKPOINT_EVERY


def estimate_names(names) -> tuple[str, ...]:
    """The ``--estimate`` values as one set: each variable once, in the registry's order,
    spelled as on the command line (``refraction_bias`` and a repeated or reordered
    ``--estimate`` ask for the same variables, so for the same run and checkpoint)."""
    from fgnav.models.registry import VARIABLES, variable

    wanted = {variable(n).name for n in names or ()}   # UserError for an unknown name
    return tuple(v.cli_name for v in VARIABLES.values() if v.name in wanted)


def solver_options(args):
    from fgnav.solvers.options import SmootherOptions

    kw = {"third_body": bool(args.third_body),
          "robust": None if args.robust == "none" else args.robust, "robust_k": args.robust_k,
          "gate_probability": args.gate, "estimate": estimate_names(getattr(args, "estimate", ())),
          "gravity": getattr(args, "gravity", "j2"), "state": getattr(args, "state", "cartesian")}
    sig = getattr(args, "alignment_sigma_arcsec", None)
    if sig is not None:
        from fgnav.models.registry import CAMERA_ALIGNMENT

        if CAMERA_ALIGNMENT.cli_name not in kw["estimate"]:
            from fgnav.errors import UserError
            raise UserError(f"--alignment-sigma-arcsec: the prior of the camera alignment, "
                            f"which is not estimated: add --estimate {CAMERA_ALIGNMENT.cli_name}")
        kw["prior_sigma"] = ((CAMERA_ALIGNMENT.name, sig * math.pi / 648000.0),)
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
                                   "DIR/summary.json (with --attitude estimate also "
                                   "DIR/attitude.aem and DIR/attitude_covariance.csv).")
    p.add_argument("log", help="measurement log (.csv, v1 format; or .tdm)")
    p.add_argument("--method", default="batch", choices=["batch", "isam2", "fixed-lag", "ekf"])
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--truth", help="truth OEM: adds errors and NEES to summary.json (a "
                   "formation: the folder of truth-<id>.oem files)")
    p.add_argument("--relative", choices=("cartesian", "spherical"), default=None,
                   help="a formation's relative position in relative.csv and summary.json: "
                        "LVLH x, y, z (cartesian, the default) or range, azimuth, elevation "
                        "beside them (spherical)")
    p.add_argument("--rerun", metavar="FILE.rrd", help="also write a Rerun recording")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors and the "
                                                         "integrity warning")
    p.add_argument("--strict", action="store_true",
                   help="exit 3 when the integrity verdict is not 'ok' (outputs are written)")
    p.add_argument("--checkpoint", metavar="FILE.npz",
                   help="isam2: save the online state every --checkpoint-every epochs")
    p.add_argument("--checkpoint-every", type=int, default=None, metavar="N",
                   help=f"epochs between checkpoints (default {DEFAULT_CHECKPOINT_EVERY})")
    p.add_argument("--resume", action="store_true",
                   help="isam2: continue from --checkpoint (same log and options)")
    p.add_argument("--sigma-deg", type=T.number(0.0, 45.0, lo_open=True, unit="deg"),
                   default=None, metavar="DEG",
                   help="TDM only: 1-sigma angle noise, deg (default: the file's "
                        "'COMMENT sigma_deg=...')")
    p.add_argument("--ignore-prior", action="store_true",
                   help="leave the log's prior_position/prior_velocity rows out and start from the "
                        "orbit the measurements give (angles-only initial orbit determination; "
                        "logs without prior rows, e.g. a CCSDS TDM, always do)")
    p.add_argument("--prior", metavar="FILE",
                   help="start from the orbit of FILE at the log's first epoch, as the log's "
                        "prior_position/prior_velocity rows would: an OMM (CCSDS KVN or XML, as "
                        "CelesTrak writes them) or a TLE (SGP4, TEME rotated to EME2000), an "
                        "OPM (CCSDS KVN; propagated to the log) or an OEM (CCSDS KVN; "
                        "interpolated). The file's covariance where it has one, else 10 km and "
                        "10 m/s for OMM/TLE (SGP4 element sets carry no accuracy and err by "
                        "km per day of age), 1 km and 1 m/s for OPM/OEM (an orbit "
                        "determination's state of unknown age). A log with prior rows of its "
                        "own is refused (one prior)")
    p.add_argument("--prior-sigma-km", type=T.number(1e-6, 1e6, unit="km"),
                   metavar="SIGMA", help="with --prior: its 1-sigma position per axis (km), "
                                         "replacing the file's or the default")
    p.add_argument("--prior-sigma-mps", type=T.number(1e-6, 1e5, unit="m/s"),
                   metavar="SIGMA", help="with --prior: its 1-sigma velocity per axis (m/s), "
                                         "replacing the file's or the default")
    p.add_argument("--attitude", choices=["known", "estimate"], default=None,
                   help="known (default): rotate body-frame directions into ECI with the log's "
                        "attitude rows before solving; estimate: the attitude is a graph "
                        "variable per epoch (the same as --estimate attitude), written to "
                        "DIR/attitude.aem (CCSDS AEM) and DIR/attitude_covariance.csv")
    p.add_argument("--no-aberration", action="store_true",
                   help="take the catalogue and geometric directions as seen, without the "
                        "aberration correction (star_direction_body, refraction and the angle "
                        "kinds body_star_angle, limb_star_angle, body_body_angle; ~20-27 "
                        "arcsec); for comparison only")
    p.add_argument("--attitude-motion", choices=["random-walk", "constant-rate"], default=None,
                   help="how the estimated attitude moves between epochs (with --attitude "
                        "estimate): random-walk (default): a random walk on SO(3) of spectral "
                        "density 1e-4 rad^2/s; constant-rate: it turns at a body rate estimated "
                        "per epoch (the variable attitude-rate, rad/s, in variables.csv), "
                        "R(k+1) = R(k) Exp(w(k) dt), the rate a random walk driven by white "
                        "angular acceleration of 1e-10 rad^2/s^3 (for a pass without gyro rows: "
                        "the attitude between its measured epochs follows the turn)")
    add_solver_options(p)
    p.add_argument("--state", choices=["cartesian", "elements"], default="cartesian",
                   help="the orbit's coordinates in the solver: cartesian (position and velocity, "
                        "default) or elements (modified equinoctial elements: the same graph, "
                        "linearized in the elements; batch and ekf; outputs stay Cartesian)")
    p.set_defaults(func=run)


def resolve_attitude_option(args) -> None:
    """``--attitude estimate`` adds ``attitude`` to ``--estimate``; ``--attitude known`` with
    ``--estimate attitude`` contradicts it (``UserError`` naming both). ``--attitude-motion
    constant-rate`` adds ``attitude-rate`` (the attitude's body rate, its process variable)."""
    from fgnav.errors import UserError
    from fgnav.models.registry import ATTITUDE_RATE, ATTITUDE_VARIABLE

    mode = args.attitude
    name = ATTITUDE_VARIABLE.name
    if mode == "known" and name in args.estimate:
        raise UserError(f"--attitude known contradicts --estimate {name} (which is "
                        "--attitude estimate); give one of them")
    if mode == "estimate" and name not in args.estimate:
        args.estimate = [*args.estimate, name]
    if getattr(args, "attitude_motion", None) == "constant-rate":
        if mode == "known" or name not in args.estimate:
            raise UserError("--attitude-motion constant-rate: the attitude's motion model needs "
                            "the attitude estimated; add --attitude estimate")
        args.estimate = [*args.estimate, ATTITUDE_RATE.name]


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


class StageLines:
    """The long steps of a big log (reading, solving, writing) as ``fgnav: ...`` lines on
    stderr (:class:`fgnav.progress.stage`): ``stage(what, size)`` for a step on ``size``
    rows or epochs, shown from ``BIG`` up."""

    BIG = 100_000

    def __init__(self, quiet: bool):
        self.quiet = quiet

    def __call__(self, what: str, size: int):
        from fgnav.progress import stage
        return stage(what, self.quiet, show=size >= self.BIG)


def _tdm_with_sigma(args):
    """``smooth_file`` for a TDM read with ``--sigma-deg`` (as ``fgnav check`` reads it)."""
    from pathlib import Path

    from fgnav.errors import UserError
    from fgnav.io.tdm import read_tdm
    from fgnav.pipeline import add_prior_file, smooth_log

    if Path(args.log).suffix.lower() not in (".tdm", ".kvn"):
        raise UserError(f"--sigma-deg applies to a CCSDS TDM (.tdm, .kvn) only; {args.log} is "
                        "read as a CSV log, whose rows carry their own sigma")

    def smooth(log_path, method, options, **kw):
        import time
        from contextlib import nullcontext

        t0 = time.perf_counter()
        stage = kw.get("stage") or (lambda what, size: nullcontext())
        with stage(f"reading {log_path}", 0):
            log = read_tdm(log_path, sigma_rad=math.radians(args.sigma_deg))
        log, prior = add_prior_file(log, kw.pop("prior_path", None),
                                    kw.pop("prior_sigma", (None, None)),
                                    kw.get("ignore_prior", False))
        res, p = smooth_log(log, method, options, t0=t0, **kw)
        if prior is not None:
            res.summary["prior_file"] = prior.summary()
        return res, p
    return smooth


def run(args) -> int:
    import json

    from fgnav.io.outputs import check_output_paths
    from fgnav.pipeline import smooth_file
    from fgnav.results import write_outputs

    # Every option and output path before any solving (the truth in smooth_file).
    resolve_attitude_option(args)
    check_solver_args(args, [args.method])
    prior_sigma = (None if args.prior_sigma_km is None else args.prior_sigma_km * 1e3,
                   args.prior_sigma_mps)
    if args.prior is None and prior_sigma != (None, None):
        from fgnav.errors import UserError
        raise UserError("--prior-sigma-km/--prior-sigma-mps: the 1-sigma of --prior FILE, "
                        "which is not given")
    if args.prior is not None:
        from fgnav.io.outputs import check_readable_file
        check_readable_file(args.prior, "--prior")
    check_output_paths(args.out, rerun=args.rerun, checkpoint=args.checkpoint, resume=args.resume)
    bar = ProgressCallback(args.method, args.quiet)
    smooth = smooth_file if args.sigma_deg is None else _tdm_with_sigma(args)
    try:
        res, p = smooth(args.log, args.method, solver_options(args), truth_path=args.truth,
                             lag_s=args.lag_s, checkpoint=args.checkpoint,
                             checkpoint_every=args.checkpoint_every, resume=args.resume,
                             ignore_prior=args.ignore_prior, progress=bar,
                             prior_path=args.prior, prior_sigma=prior_sigma,
                             aberration=not args.no_aberration,
                             stage=StageLines(args.quiet),
                             **({"relative": args.relative} if args.relative else {}))
    finally:
        bar.close()
    with StageLines(args.quiet)(f"writing {len(res.solution.t_s):,} epochs to {args.out}",
                                len(res.solution.t_s)):
        write_outputs(args.out, res, p)
    if not args.quiet:
        import sys
        for note in p.warnings:
            if "gap" in note:
                print(f"fgnav: note: {note}", file=sys.stderr)
    if args.rerun:   # (a formation's: every orbit, the links, LVLH)
        from fgnav.viz.rerun_log import log_result
        log_result(args.rerun, res, p, log_path=args.log, truth=args.truth)
    integrity = res.summary["integrity"]
    if not args.quiet:
        keys = ["method", "epochs", "iterations", "wall_s", "crb_position_rms_m", "position_rms_m",
                "velocity_rms_mps", "nees_mean"]
        brief = {k: res.summary[k] for k in keys if k in res.summary}
        brief["integrity"] = integrity["status"]
        print(json.dumps(brief, indent=1))
    from fgnav.diagnostics.integrity import stderr_line
    line = stderr_line(integrity)
    if line:
        import sys
        print(line, file=sys.stderr)
    return 3 if args.strict and integrity["status"] != "ok" else 0
