"""``fgnav simulate SCENARIO --out DIR``: truth OEM + measurement log of a scenario."""


def register(sub):
    p = sub.add_parser("simulate", help="simulate a scenario: DIR/measurements.csv + DIR/truth.oem",
                       description="Simulate a built-in scenario (e.g. gto-transfer, geo-limb) or a "
                                   "scenario TOML file: truth from an independent DOP853 integrator, "
                                   "measurements with seeded noise.")
    p.add_argument("scenario", help="built-in name or path to a scenario .toml")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    p.add_argument("--step-s", type=float, help="measurement period (s), overrides the scenario")
    p.add_argument("--duration-h", type=float, help="pass length (h), overrides the scenario")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.add_argument("--images", action="store_true",
                   help="also render the sensor frames (16-bit PNG star field + limb sub-apertures, "
                        "seed 000 sensor, Earth-pointing plan) into DIR/frames/ with the index "
                        "DIR/frames.csv (input of `fgnav extract`)")
    p.add_argument("--image-period-s", type=float,
                   help="image period (s; default the measurement period)")
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from fgnav.io.log_csv import write_log
    from fgnav.io.oem import write_oem
    from fgnav.scenarios import load_scenario
    from fgnav.simulate.pass_sim import simulate_pass

    scn = load_scenario(args.scenario).with_options(step_s=args.step_s, duration_h=args.duration_h)
    sim = simulate_pass(scn, seed=args.seed)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_log(out / "measurements.csv", sim.log)
    write_oem(out / "truth.oem", sim.epoch0, sim.t_s, sim.x_true, None,
              object_name=scn.name.upper(),
              comments=(f"fgnav truth for scenario {scn.name}, seed {args.seed}",
                        "scipy DOP853 rtol 1e-12 (independent of the estimator's propagator)"))
    if not args.quiet:
        print(f"{scn.name}: {len(sim.log.t_s)} measurement rows over {len(sim.t_s)} epochs -> "
              f"{out / 'measurements.csv'}, {out / 'truth.oem'}")
    if getattr(args, "images", False):
        from fgnav.simulate.images import ImageConfig, render_pass_frames

        recs = render_pass_frames(sim, out, seed=args.seed, quiet=args.quiet,
                                  config=ImageConfig(period_s=args.image_period_s))
        if not args.quiet:
            n_limb = sum(r.camera_name.startswith("limb") for r in recs)
            print(f"{len(recs)} frames ({len(recs) - n_limb} star, {n_limb} limb) -> "
                  f"{out / 'frames'}/, {out / 'frames.csv'}")
    return 0
