"""``fgnav campaign``: run a study (grid of scenarios x seeds x methods) locally or on Dask."""

from fgnav.commands import _types as T


def register(sub):
    p = sub.add_parser(
        "campaign", help="run a study (built-in name or STUDY.toml) to a resumable results table",
        description="Run every run of a study (data/studies/*.toml or a TOML file) in local worker "
                    "processes or on a Dask distributed cluster. Each finished run is appended to "
                    "OUT/runs.csv at once, so an interrupted campaign loses nothing; --resume skips "
                    "the finished runs. When all runs are done the study's table (table.csv, "
                    "table.md) and plot (plot.png) are written to OUT. The study is checked "
                    "whole before any run: a run that cannot start (unknown or formation "
                    "scenario, negative seed, a pass beyond the simulator's limits) refuses "
                    "it (exit 2). Exit 3: some run failed while running (its error is in "
                    "runs.csv).")
    p.add_argument("study", nargs="?", help="built-in study name (e.g. seed002-noise: Pan & Yao 2017, "
                                            "table 2; --list shows all) or a study .toml")
    p.add_argument("--out", help="(required) output directory (runs.csv, table.csv/.md, plot.png)")
    p.add_argument("--workers", type=T.integer(1), default=None,
                   help="local worker processes (default: CPU count; 1 = run in this process)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="Dask scheduler address (e.g. tcp://10.0.0.1:8786): run there instead")
    p.add_argument("--resume", action="store_true", help="continue a campaign in OUT, skipping finished runs")
    p.add_argument("--report-only", action="store_true", help="only rewrite the table and plot from OUT/runs.csv")
    p.add_argument("--list", action="store_true", help="list the built-in studies and exit")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print one JSON object with the outcome")
    p.set_defaults(func=run)


def run(args) -> int:
    import json
    import os

    from fgnav.campaign import builtin_studies, load_study, read_runs, run_campaign, write_report
    from fgnav.errors import UserError

    if args.list:
        for name in builtin_studies():
            print(f"{name:<24} {load_study(name).description}")
        return 0
    if not args.study or not args.out:
        raise UserError("fgnav campaign needs a STUDY (built-in name or .toml; --list shows them) and --out DIR")
    study = load_study(args.study)
    if args.report_only:
        files = write_report(study, args.out)
        if args.json:
            print(json.dumps({"study": study.name, "report_files": [str(f) for f in files]}))
        else:
            print("\n".join(str(f) for f in files))
        return 0
    workers = args.workers if args.workers is not None else (os.cpu_count() or 1)
    if workers < 1:
        raise UserError(f"--workers must be >= 1, found {workers}")
    res = run_campaign(study, args.out, workers=workers, scheduler=args.scheduler,
                       resume=args.resume, quiet=args.quiet)
    failed = [r for r in read_runs(args.out) if r["status"] != "ok"]
    if args.json:
        d = res.as_dict()
        d.update(study=study.name, failed_runs=[r["run_id"] for r in failed])
        print(json.dumps(d))
    else:
        print(f"{study.name}: {res.n_ran} run(s) executed ({res.n_failed} failed), {res.n_skipped} "
              f"already done, of {res.n_runs}; {res.wall_s:.1f} s wall")
        for r in failed[:10]:
            print(f"  failed: {r['run_id']}: {r['error']}")
        for f in res.report_files:
            print(f"  wrote {f}")
        if (res.out_dir / "table.md").exists() and res.report_files:
            print()
            print((res.out_dir / "table.md").read_text())
    return 3 if failed else 0   # results written, not every run done (README, exit codes)
