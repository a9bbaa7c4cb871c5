"""``fgnav simulate SCENARIO --out DIR``: truth OEM + measurement log of a scenario."""

from fgnav.commands import _types as T

MAX_EPOCHS = 1_000_000       # = fgnav.scenarios.MAX_EPOCHS (not imported: keeps --help fast)
MAX_DURATION_H = 744.0       # = fgnav.scenarios.MAX_DURATION_H


def register(sub):
    p = sub.add_parser("simulate", help="simulate a scenario: DIR/measurements.csv + DIR/truth.oem",
                       description="Simulate a built-in scenario (e.g. gto-transfer, geo-limb) or a "
                                   "scenario TOML file: truth from an independent DOP853 integrator, "
                                   "measurements with seeded noise. A refraction sensor with "
                                   "an atmosphere-model bias also gives "
                                   "DIR/truth_refraction_bias.csv (epoch,refraction_bias_m); a "
                                   "star camera with a mounting error (sensor key "
                                   "mounting_sigma_arcsec, or --star-mounting-sigma-arcsec) "
                                   "DIR/truth_camera_alignment.csv (epoch,align_x,align_y,align_z). "
                                   "A formation (formation-gto, constellation-leo: several "
                                   "spacecraft and inter-satellite links) writes one "
                                   "DIR/measurements.csv with a spacecraft column, "
                                   "DIR/truth-<id>.oem per spacecraft and DIR/truth_clock.csv "
                                   "(epoch,clock_m).")
    p.add_argument("scenario", nargs="?", help="built-in name or path to a scenario .toml")
    p.add_argument("--out", help="output directory (required unless --list)")
    p.add_argument("--list", action="store_true", dest="list_scenarios",
                   help="print every built-in scenario (name, orbit, sensors) and exit")
    p.add_argument("--seed", type=T.seed, default=0, help="noise seed, an integer >= 0 (default 0)")
    p.add_argument("--step-s", type=T.pos("s"),
                   help="measurement period (s, > 0), overrides the scenario")
    p.add_argument("--duration-h", type=T.pos("h"),
                   help="pass length (h, > 0), overrides the scenario")
    p.add_argument("--max-epochs", type=T.integer(1), default=MAX_EPOCHS, metavar="N",
                   help=f"refuse a pass with more than N sensor epochs, summed over the sensors "
                        f"(default {MAX_EPOCHS:,}; ~13 s and 25 MB of output per 100,000)")
    p.add_argument("--max-duration-h", type=T.pos("h"),
                   default=MAX_DURATION_H, metavar="H",
                   help=f"refuse a pass longer than H hours (default {MAX_DURATION_H:g} h = 31 "
                        "days; the truth integration takes ~8 s per simulated day in LEO)")
    p.add_argument("--raw-stars", action="store_true",
                   help="observe the attitude as raw stars: a zenith star camera (12.85 deg "
                        "field, stars to V 5.5, 5 arcsec) gives star_direction_body rows and "
                        "the scenario's Earth-direction sensors measure in the body frame "
                        "(earth_direction_body rows); solve with `fgnav smooth --estimate "
                        "attitude`")
    p.add_argument("--star-mounting-sigma-arcsec", type=T.number(0.0, 3600.0, unit="arcsec"),
                   metavar="SIGMA",
                   help="with --raw-stars: the star camera is a separate sensor, mounted with an "
                        "error of SIGMA arcsec (1-sigma per axis, drawn once from the seed); its "
                        "rows are then in its own frame (estimate the mounting with `fgnav "
                        "smooth --estimate camera-alignment`; default 0: confocal)")
    p.add_argument("--body-frame", action="store_true",
                   help="a formation's direction sensors measure in each spacecraft's body "
                        "frame (earth_direction_body rows, with attitude rows of each "
                        "spacecraft); solve with `fgnav smooth --estimate attitude`")
    p.add_argument("--gyro", action="store_true", dest="with_gyro",
                   help="each spacecraft of a formation carries a rate gyro: gyro rows (its body "
                        "rate over each interval, a constant bias of 1e-4 rad/s 1-sigma per axis "
                        "drawn per spacecraft, 1e-6 rad/s noise), attitude rows and "
                        "truth_gyro_bias-<id>.csv; solve with `fgnav smooth --estimate "
                        "attitude --estimate gyro-bias`")
    p.add_argument("--gravity", choices=["j2", "point-mass"],
                   help="the Earth's gravity in the truth, overrides the scenario's [truth] j2: "
                        "point-mass (Keplerian; smooth it with --gravity point-mass) or j2 "
                        "(the scenario's other forces are kept)")
    p.add_argument("--manoeuvre", action="append", default=None, metavar="T,DVX,DVY,DVZ[,SIGMA]",
                   help="a declared impulsive manoeuvre (repeatable): at T (hours after the "
                        "pass start, or an ISO-8601 UTC epoch) the truth's velocity changes by "
                        "(DVX, DVY, DVZ) m/s EME2000 plus an execution error of SIGMA m/s "
                        "1-sigma per axis (default 0.01) drawn from the seed; the log carries a "
                        "'manoeuvre' row with the planned delta-v and SIGMA (added to the "
                        "scenario's [[manoeuvres]] tables)")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.add_argument("--images", action="store_true",
                   help="also render the sensor frames (16-bit PNG star field + limb sub-apertures, "
                        "Wu et al.'s confocal sensor, Earth-pointing plan) into DIR/frames/ with "
                        "the index DIR/frames.csv (input of `fgnav extract`)")
    p.add_argument("--image-period-s", type=T.pos("s"),
                   help="image period (s, > 0; default the measurement period, thinned to at "
                        "most 100 image epochs: ~1.8 MB of PNG per epoch)")
    p.add_argument("--stream", action="store_true",
                   help="also write the measurement log to stdout, paced at --speed times real "
                        "time (for fgnav follow -: one pipe); the notes go to stderr")
    p.add_argument("--speed", type=T.number(0.0, 1e9, unit="x real time"), default=None,
                   metavar="X",
                   help="with --stream: X times real time (default 1; 0: as fast as possible)")
    p.set_defaults(func=run, simulate_parser=p)


def _orbit_text(scn) -> str:
    """Centre and perigee/apogee altitude (Earth) or radius (Sun) of the scenario's x0."""
    import numpy as np

    from fgnav.constants import AU_M, MU_EARTH_M3_S2, MU_SUN_M3_S2, R_EARTH_M
    from fgnav.errors import UserError
    from fgnav.orbit import state_to_elements

    x0 = np.asarray(scn.x0_eci, dtype=float)
    try:
        el = state_to_elements(x0, mu=MU_SUN_M3_S2 if scn.centre == "sun" else MU_EARTH_M3_S2)
    except UserError:       # not elliptic
        kind, peri = "escape", float(np.linalg.norm(x0[:3]))
        apo = peri
    else:
        kind = "circular" if el.e < 0.01 else f"e={el.e:.2f}"
        peri, apo = el.a_m * (1.0 - el.e), el.a_m * (1.0 + el.e)
    if scn.centre == "sun":
        return f"sun {kind}, r {peri / AU_M:.2f}-{apo / AU_M:.2f} au"
    return f"earth {kind}, alt {(peri - R_EARTH_M) / 1e3:.0f}-{(apo - R_EARTH_M) / 1e3:.0f} km"


def list_lines() -> list[str]:
    """One line per built-in scenario: name, orbit, sensor kinds (from its TOML)."""
    from fgnav.scenarios import builtin_names, load_scenario

    lines = []
    for name in builtin_names():
        scn = load_scenario(name)
        kinds = list(dict.fromkeys(s.kind for s in scn.sensors))
        if scn.formation is not None:
            kinds.append(f"inter-satellite links ({len(scn.formation.ids)} spacecraft)")
        lines.append(f"{name}  orbit: {_orbit_text(scn)}  sensors: {', '.join(kinds)}")
    return lines


def run(args) -> int:
    import tempfile
    from pathlib import Path

    from fgnav.errors import UserError
    from fgnav.scenarios import check_size, load_scenario
    from fgnav.simulate.pass_sim import raw_star_scenario, simulate_pass, write_pass_files

    if getattr(args, "list_scenarios", False):
        print("\n".join(list_lines()))
        return 0
    if args.scenario is None or args.out is None:
        missing = [n for n, v in (("scenario", args.scenario), ("--out", args.out)) if v is None]
        msg = "the following arguments are required: " + ", ".join(missing)
        parser = getattr(args, "simulate_parser", None)
        if parser is not None:
            parser.error(msg)   # exit 2, as before --list
        raise UserError(msg)
    stream = getattr(args, "stream", False)
    if getattr(args, "speed", None) is not None and not stream:
        raise UserError("--speed paces --stream; give --stream with it")
    mounting = getattr(args, "star_mounting_sigma_arcsec", None)
    if mounting is not None and not getattr(args, "raw_stars", False):
        raise UserError("--star-mounting-sigma-arcsec needs --raw-stars (the star camera it "
                        "mounts)")
    gravity = getattr(args, "gravity", None)
    scn = load_scenario(args.scenario).with_options(
        step_s=args.step_s, duration_h=args.duration_h,
        truth_j2=None if gravity is None else gravity == "j2")
    if getattr(args, "manoeuvre", None):
        from fgnav.scenarios import parse_manoeuvre

        scn = scn.with_options(manoeuvres=tuple(sorted(
            scn.manoeuvres + tuple(parse_manoeuvre(text, scn) for text in args.manoeuvre),
            key=lambda m: m.t_s)))
    if getattr(args, "raw_stars", False):
        camera = None
        if mounting is not None:
            from dataclasses import replace

            from fgnav.simulate.pass_sim import RAW_STAR_CAMERA

            camera = replace(RAW_STAR_CAMERA, mounting_sigma_arcsec=mounting)
        scn = raw_star_scenario(scn) if camera is None else raw_star_scenario(scn, camera)
    if getattr(args, "body_frame", False) and scn.formation is None:
        raise UserError(f"--body-frame: scenario {scn.name} has one spacecraft (use --raw-stars "
                        "for body-frame rows of one spacecraft)")
    if getattr(args, "with_gyro", False) and scn.formation is None:
        raise UserError(f"--gyro: scenario {scn.name} has one spacecraft; --gyro simulates the "
                        "gyros of a formation's spacecraft")
    if scn.formation is not None:
        for opt, on in (("--stream", stream), ("--raw-stars", getattr(args, "raw_stars", False)),
                        ("--images", getattr(args, "images", False))):
            if on:
                raise UserError(f"{opt}: scenario {scn.name} has several spacecraft; {opt} "
                                "simulates one (use a one-spacecraft scenario)")
    check_size(scn, args.max_epochs, args.max_duration_h)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out}: exists and is not a directory")
    try:  # before the simulation: an unusable --out must not cost the whole run
        out.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=out).close()
    except OSError as exc:
        raise UserError(f"--out {out}: cannot write there: {exc.strerror or exc}") from None
    if scn.formation is not None:   # several spacecraft: one log, truth-<id>.oem each
        from fgnav.simulate.formation_sim import simulate_formation_pass, write_formation_files

        fsim = simulate_formation_pass(scn, seed=args.seed, max_epochs=args.max_epochs,
                                       max_duration_h=args.max_duration_h,
                                       body_frame=getattr(args, "body_frame", False),
                                       gyro=getattr(args, "with_gyro", False))
        written = write_formation_files(out, fsim)
        if not args.quiet:
            print(f"{scn.name}: {len(fsim.ids)} spacecraft ({', '.join(fsim.ids)}), "
                  f"{len(fsim.log.t_s)} measurement rows over {len(fsim.t_s)} epochs -> "
                  + ", ".join(str(w) for w in written))
        return 0
    sim = simulate_pass(scn, seed=args.seed, max_epochs=args.max_epochs,
                        max_duration_h=args.max_duration_h)
    written = write_pass_files(out, sim)
    if not args.quiet:
        import sys
        print(f"{scn.name}: {len(sim.log.t_s)} measurement rows over {len(sim.t_s)} epochs -> "
              + ", ".join(str(w) for w in written), file=sys.stderr if stream else sys.stdout)
    if getattr(args, "images", False):
        from fgnav.simulate.images import ImageConfig, render_pass_frames

        recs = render_pass_frames(sim, out, seed=args.seed, quiet=args.quiet,
                                  config=ImageConfig(period_s=args.image_period_s))
        if not args.quiet:
            n_limb = sum(r.camera_name.startswith("limb") for r in recs)
            print(f"{len(recs)} frames ({len(recs) - n_limb} star, {n_limb} limb) -> "
                  f"{out / 'frames'}/, {out / 'frames.csv'}")
    if stream:
        from fgnav.online.stream import pace_log
        pace_log(out / "measurements.csv", 1.0 if args.speed is None else args.speed)
    return 0
