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
                                   "DIR/truth_refraction_bias.csv (epoch,refraction_bias_m).")
    p.add_argument("scenario", help="built-in name or path to a scenario .toml")
    p.add_argument("--out", required=True, help="output directory")
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
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.add_argument("--images", action="store_true",
                   help="also render the sensor frames (16-bit PNG star field + limb sub-apertures, "
                        "Wu et al.'s confocal sensor, Earth-pointing plan) into DIR/frames/ with "
                        "the index DIR/frames.csv (input of `fgnav extract`)")
    p.add_argument("--image-period-s", type=T.pos("s"),
                   help="image period (s, > 0; default the measurement period)")
    p.set_defaults(func=run)


def run(args) -> int:
    import tempfile
    from pathlib import Path

    from fgnav.errors import UserError
    from fgnav.io.log_csv import write_log
    from fgnav.io.oem import write_oem
    from fgnav.scenarios import check_size, load_scenario
    from fgnav.simulate.pass_sim import raw_star_scenario, simulate_pass

    scn = load_scenario(args.scenario).with_options(step_s=args.step_s, duration_h=args.duration_h)
    if getattr(args, "raw_stars", False):
        scn = raw_star_scenario(scn)
    check_size(scn, args.max_epochs, args.max_duration_h)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out}: exists and is not a directory")
    try:  # before the simulation: an unusable --out must not cost the whole run
        out.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=out).close()
    except OSError as exc:
        raise UserError(f"--out {out}: cannot write there: {exc.strerror or exc}") from None
    sim = simulate_pass(scn, seed=args.seed, max_epochs=args.max_epochs,
                        max_duration_h=args.max_duration_h)
    try:
        write_log(out / "measurements.csv", sim.log)
        write_oem(out / "truth.oem", sim.epoch0, sim.t_s, sim.x_true, None,
                  object_name=scn.name.upper(),
                  comments=(f"fgnav truth for scenario {scn.name}, seed {args.seed}",
                            "scipy DOP853 rtol 1e-12 (independent of the estimator's propagator)"))
        written = [out / "measurements.csv", out / "truth.oem"]
        if "refraction_bias_m" in sim.truth_params:
            from fgnav.io.truth_params import TRUTH_REFRACTION_BIAS_CSV, write_truth_params_csv

            written.append(out / TRUTH_REFRACTION_BIAS_CSV)
            write_truth_params_csv(
                written[-1], sim.epoch0, sim.t_s,
                {"refraction_bias_m": sim.truth_params["refraction_bias_m"]},
                comments=(f"scenario {scn.name}, seed {args.seed}: the real atmosphere's "
                          "tangent-height shift against the refraction model, m",))
        if any(str(k).endswith("_body") for k in set(sim.log.kind)):
            from factors.geometry import so3_log
            from fgnav.io.truth_params import (TRUTH_ATTITUDE_COLUMNS, TRUTH_ATTITUDE_CSV,
                                               write_truth_params_csv)

            written.append(out / TRUTH_ATTITUDE_CSV)
            w = so3_log(sim.truth_attitude())
            write_truth_params_csv(
                written[-1], sim.epoch0, sim.t_s, dict(zip(TRUTH_ATTITUDE_COLUMNS, w.T)),
                comments=(f"scenario {scn.name}, seed {args.seed}: the attitude plan's "
                          "R_eci_from_body (body-frame rows refer to it) as a rotation vector, rad",))
    except OSError as exc:
        raise UserError(f"--out {out}: cannot write: {exc.strerror or exc}") from None
    if not args.quiet:
        print(f"{scn.name}: {len(sim.log.t_s)} measurement rows over {len(sim.t_s)} epochs -> "
              + ", ".join(str(w) for w in written))
    if getattr(args, "images", False):
        from fgnav.simulate.images import ImageConfig, render_pass_frames

        recs = render_pass_frames(sim, out, seed=args.seed, quiet=args.quiet,
                                  config=ImageConfig(period_s=args.image_period_s))
        if not args.quiet:
            n_limb = sum(r.camera_name.startswith("limb") for r in recs)
            print(f"{len(recs)} frames ({len(recs) - n_limb} star, {n_limb} limb) -> "
                  f"{out / 'frames'}/, {out / 'frames.csv'}")
    return 0
