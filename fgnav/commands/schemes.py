"""``fgnav schemes``: the Li et al. 2017 refraction budget, the INS/CNS lecture Sun/Earth/Moon
table and its position surfaces (geometric fixes against the smoother)."""

from fgnav.commands import _types as T


def register(sub):
    p = sub.add_parser("schemes", help="starlight-refraction / Sun-Earth-Moon scheme tables",
                       description="Simulate a built-in scheme and print its table against truth: "
                                   "'refraction' (Li et al. 2017, refraction-leo: error budget by "
                                   "source, direct three-star fix, EKF, smoother) or "
                                   "'sun-earth-moon' (the INS/CNS lecture, leo-sun-earth-moon: direct "
                                   "fix, EKF, smoother) or 'position-surfaces' (the INS/CNS lecture's "
                                   "pure geometric fixes, sextant-leo: the surfaces of each epoch "
                                   "intersected, error and predicted sigma per epoch against the "
                                   "smoother's).")
    p.add_argument("scheme", choices=["refraction", "sun-earth-moon", "position-surfaces"])
    p.add_argument("--seed", type=T.seed, default=0, help="noise seed (default 0)")
    p.add_argument("--duration-h", type=T.pos("h"), help="pass length (h; default: the scenario's)")
    p.add_argument("--process-noise", type=T.number(0.0, unit="m^2/s^3"), metavar="Q",
                   help="white-acceleration PSD of the motion prior (m^2/s^3; default 1e-12 for "
                        "refraction and position-surfaces, 1e-9 for sun-earth-moon)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    p.set_defaults(func=run)


def run(args) -> int:
    import json

    from fgnav.errors import UserError
    from fgnav.analysis import scheme_studies

    if args.duration_h is not None and not args.duration_h > 0:
        raise UserError(f"--duration-h must be > 0 (h), got {args.duration_h}")
    if args.process_noise is not None and not args.process_noise > 0:
        raise UserError(f"--process-noise must be > 0 (m^2/s^3), got {args.process_noise}")
    if args.scheme == "refraction":
        rows = scheme_studies.refraction_study(args.seed, duration_h=args.duration_h,
                                               q_m2_s3=args.process_noise)
        if args.json:
            print(json.dumps({"scheme": "refraction", "seed": args.seed, "rows": rows}))
        else:
            print(scheme_studies.format_refraction_table(rows))
        return 0
    if args.scheme == "position-surfaces":
        r = scheme_studies.surfaces_study(args.seed, duration_h=args.duration_h,
                                          q_m2_s3=args.process_noise)
        if args.json:
            print(json.dumps({"scheme": "position-surfaces", **r}))
        else:
            print(scheme_studies.format_surfaces_table(r))
        return 0
    kw = {} if args.process_noise is None else {"q_m2_s3": args.process_noise}
    r = scheme_studies.sem_study(args.seed, duration_h=args.duration_h, **kw)
    if args.json:
        print(json.dumps({"scheme": "sun-earth-moon", **r}))
    else:
        print(scheme_studies.format_sem_table(r))
    return 0
