"""``fgnav follow SOURCE --out DIR``: live online navigation from a measurement stream."""

from fgnav.commands.smooth import DEFAULT_CHECKPOINT_EVERY, add_solver_options

DEFAULT_WINDOW_S = 600.0


def register(sub):
    p = sub.add_parser(
        "follow", help="navigate live from a measurement stream (stdin or a growing file)",
        description="Read a CSV v1 measurement log as it arrives (SOURCE '-' for stdin, or a "
                    "file another process appends to, read from its start as tail -f does) "
                    "and print one JSON line per completed epoch: the newest state, its "
                    "1-sigma, the integrity verdict so far and the update latency. DIR/online.oem "
                    "and DIR/latency.csv grow as it runs; at the end (end of input, "
                    "--idle-timeout, SIGINT, SIGTERM) DIR/trajectory.oem (the whole history "
                    "smoothed by the batch solver), summary.json and residuals.csv as fgnav "
                    "smooth writes them.")
    p.add_argument("source", help="'-' (stdin) or a CSV v1 log file that grows")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--method", default="isam2", choices=["isam2", "fixed-lag", "ekf"],
                   help="the online engine: isam2 (default: iSAM2 over a bounded window, "
                        "--window-s), fixed-lag (the same over --lag-s) or ekf")
    p.add_argument("--window-s", type=float, default=None,
                   help=f"isam2: the window (s, default {DEFAULT_WINDOW_S:g}); older states "
                        "leave it as a marginal prior")
    p.add_argument("--idle-timeout", type=float, default=None, metavar="S",
                   help="end after S seconds without new input (default: never for a file, "
                        "the end of input for stdin)")
    p.add_argument("--reorder-window-s", type=float, default=0.0, metavar="S",
                   help="a row up to S seconds behind the newest epoch is kept for its epoch; "
                        "a later one is reported and dropped (default 0)")
    p.add_argument("--integrity-window-s", type=float, default=600.0, metavar="S",
                   help="the sliding window of the live integrity tests (s, default 600)")
    p.add_argument("--checkpoint", metavar="FILE.npz",
                   help="save the online state atomically every --checkpoint-every epochs")
    p.add_argument("--checkpoint-every", type=int, default=None, metavar="N",
                   help=f"epochs between checkpoints (default {DEFAULT_CHECKPOINT_EVERY})")
    p.add_argument("--resume", action="store_true",
                   help="continue from --checkpoint: give the whole stream again; what was "
                        "done is skipped")
    p.add_argument("--ignore-prior", action="store_true",
                   help="leave the stream's prior rows out and start from the orbit the "
                        "measurements give")
    p.add_argument("--quiet", action="store_true",
                   help="no notes on stderr (the JSON lines and errors stay)")
    p.add_argument("--rerun-serve", action="store_true",
                   help="serve the recording to Rerun's web viewer while it runs (the online "
                        "state, its sigma, latency and verdict per epoch; at the end the smoothed "
                        "history with its covariance and residuals); the address is printed on "
                        "stderr; the server ends with the process")
    p.add_argument("--rerun-web-port", type=int, default=None, metavar="PORT",
                   help="with --rerun-serve: the web viewer's port (default 9090)")
    p.add_argument("--rerun-grpc-port", type=int, default=None, metavar="PORT",
                   help="with --rerun-serve: the recording's gRPC port (default 9876)")
    add_solver_options(p)
    p.set_defaults(func=run)


def check_args(args) -> None:
    """The options, before any reading (``UserError`` naming the option)."""
    import argparse
    import math

    from fgnav.commands.smooth import check_solver_args
    from fgnav.errors import UserError

    for name, v in (("--window-s", args.window_s), ("--integrity-window-s", args.integrity_window_s)):
        if v is not None and not (math.isfinite(v) and v > 0):
            raise UserError(f"{name} must be a finite number > 0 (s), got {v}")
    if args.idle_timeout is not None and not (math.isfinite(args.idle_timeout)
                                              and args.idle_timeout >= 0):
        raise UserError(f"--idle-timeout must be a finite number >= 0 (s), got {args.idle_timeout}")
    if not (math.isfinite(args.reorder_window_s) and args.reorder_window_s >= 0):
        raise UserError(f"--reorder-window-s must be a finite number >= 0 (s), got "
                        f"{args.reorder_window_s}")
    if args.window_s is not None and args.method != "isam2":
        raise UserError(f"--window-s applies to --method isam2 (fixed-lag: --lag-s), not "
                        f"{args.method}")
    if (args.resume or args.checkpoint_every is not None) and not args.checkpoint:
        raise UserError("--resume/--checkpoint-every need --checkpoint FILE.npz")
    for name, port in (("--rerun-web-port", args.rerun_web_port),
                       ("--rerun-grpc-port", args.rerun_grpc_port)):
        if port is not None and not args.rerun_serve:
            raise UserError(f"{name} is a port of --rerun-serve; give --rerun-serve with it")
        if port is not None and not 1 <= port <= 65535:
            raise UserError(f"{name} must be a port number in 1..65535, got {port}")
    if args.checkpoint_every is not None and args.checkpoint_every < 1:
        raise UserError(f"--checkpoint-every must be an epoch count >= 1, got "
                        f"{args.checkpoint_every}")
    ns = argparse.Namespace(**vars(args))
    ns.checkpoint, ns.checkpoint_every, ns.resume = None, None, False
    check_solver_args(ns, [args.method, "batch"])   # (the history: batch)
    args.lag_s = ns.lag_s
    args.window_s = DEFAULT_WINDOW_S if args.window_s is None else args.window_s
    args.checkpoint_every = args.checkpoint_every or DEFAULT_CHECKPOINT_EVERY
    args.attitude, args.attitude_motion = None, None


def run(args) -> int:
    import json
    import signal
    import sys
    from pathlib import Path

    from fgnav.commands.smooth import solver_options
    from fgnav.io.outputs import check_output_paths, commit_outputs
    from fgnav.online.live_files import (LiveFiles, fingerprint, load_checkpoint,
                                         save_checkpoint)
    from fgnav.online.navigator import Navigator
    from fgnav.online.stream import LineSource, StreamReader
    from fgnav.results import write_outputs

    check_args(args)
    options = solver_options(args)
    check_output_paths(args.out, checkpoint=args.checkpoint, resume=args.resume)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    def note(msg):
        if not args.quiet:
            print(msg, file=sys.stderr, flush=True)

    def emit(obj):
        sys.stdout.write(json.dumps(obj) + "\n")
        sys.stdout.flush()

    live = None
    if args.rerun_serve:
        from fgnav.viz.rerun_live import LiveRecording
        live = LiveRecording()
        print(f"fgnav: Rerun web viewer: {live.serve(args.rerun_grpc_port, args.rerun_web_port)}",
              file=sys.stderr, flush=True)
    src = LineSource(args.source, args.idle_timeout)
    reader = StreamReader(src.name, reorder_window_s=args.reorder_window_s,
                          report=lambda m: note(f"fgnav: {m}"))
    handlers = {}

    def stop(signum, frame):
        src.stop()
        for s, h in handlers.items():   # a second signal ends at once
            signal.signal(s, h)

    for s in (signal.SIGINT, signal.SIGTERM):
        handlers[s] = signal.signal(s, stop)

    nav = files = None
    ident = None
    resumed = None
    done = 0
    try:
        lines = src.lines()
        for raw in lines:   # the preamble and header: the navigator needs the centre
            reader.feed(raw)
            if reader.header is not None:
                break
        if reader.header is None:
            reader.end()   # InputFormatError: no header
        nav = Navigator(options, method=args.method, window_s=args.window_s, lag_s=args.lag_s,
                        integrity_window_s=args.integrity_window_s, source=src.name,
                        centre=reader.centre, ignore_prior=args.ignore_prior)
        ident = fingerprint(method=args.method, window_s=args.window_s, lag_s=args.lag_s,
                            options=repr(options), header=reader.header, centre=reader.centre,
                            ignore_prior=args.ignore_prior)
        sizes = None
        if args.resume:
            if not Path(args.checkpoint).exists():
                raise_missing(args.checkpoint)
            state, sizes = load_checkpoint(args.checkpoint, ident)
            nav.restore(state)
            resumed = int(state["k"])
            note(f"fgnav: resuming after {resumed} epochs")
        # the live files belong to this command's output group (fgnav.io.outputs)
        files = LiveFiles(out, reader.centre, args.method, sizes)
        commit_outputs(out, None, ["online.oem", "latency.csv"], "follow",
                       replaces=("follow", "smooth", "report"))
        last_verdict = "ok"

        def handle(events):
            nonlocal last_verdict, done
            for ev, ns, rows in events:
                if ev == "late":
                    nav.add_late(rows)
                    continue
                for st in nav.add_epoch(ns, rows):
                    emit(st.as_json())
                    files.add(st)
                    if live is not None:
                        live.epoch(st)
                    done += 1
                    if st.verdict != last_verdict:
                        live_int = nav.integrity.as_dict()
                        event = {"event": "integrity", "epoch": st.as_json()["epoch"],
                                 "from": last_verdict, "to": st.verdict, **live_int}
                        emit(event)
                        if live is not None:
                            live.verdict(st, event)
                        note(f"fgnav: integrity {last_verdict} -> {st.verdict} at "
                             f"{st.as_json()['epoch']} (window NIS "
                             f"{live_int['window']['nis']:.1f} / {live_int['window']['dof']} "
                             f"dof, all {live_int['all']['nis']:.1f} / "
                             f"{live_int['all']['dof']} dof)")
                        last_verdict = st.verdict
                    if args.checkpoint and nav.k % args.checkpoint_every == 0:
                        files.flush()
                        save_checkpoint(args.checkpoint, ident, nav.checkpoint_state(),
                                        files.sizes(), nav.k)

        for raw in lines:
            handle(reader.feed(raw))
        handle(reader.end())
    finally:
        if files is not None:
            files.close()
        for s, h in handlers.items():
            signal.signal(s, h)
    if args.checkpoint and nav.engine is not None:
        save_checkpoint(args.checkpoint, ident, nav.checkpoint_state(), files.sizes(), nav.k)
    res, p = nav.finish()
    counts = reader.counts.as_dict()
    lat = sorted(nav.latency)
    res.summary["online"] = {
        "method": args.method, "epochs": nav.k, "epochs_this_run": done,
        **({"resumed_after_epochs": resumed} if resumed is not None else {}),
        "window_s": args.window_s if args.method == "isam2" else
        (args.lag_s if args.method == "fixed-lag" else None),
        "latency_p50_s": lat[len(lat) // 2] if lat else None,
        "latency_p99_s": lat[min(len(lat) - 1, int(0.99 * len(lat)))] if lat else None,
        "integrity_live": nav.integrity.as_dict(), "stream": counts}
    write_outputs(out, res, p)
    commit_outputs(out, None, ["online.oem", "latency.csv"], "follow", replaces=("follow",))
    if live is not None:
        from fgnav.results import residual_times
        live.final(res.solution, residual_t_s=residual_times(res, p))
        live.close()
    integrity = res.summary["integrity"]
    emit({"event": "end", "epochs": nav.k, "rows": counts["rows"], "skipped": counts["skipped"],
          "duplicates": counts["duplicates"], "late_kept": counts["late_kept"],
          "late_dropped": counts["late_dropped"], "integrity": integrity["status"],
          "trajectory": str(out / "trajectory.oem")})
    if counts["skipped"] or counts["duplicates"] or counts["late_dropped"]:
        note(f"fgnav: {src.name}: {sum(counts['skipped'].values())} line(s) skipped "
             f"{counts['skipped']}, {counts['duplicates']} duplicate(s) ignored, "
             f"{counts['late_dropped']} late row(s) dropped")
    from fgnav.diagnostics.integrity import stderr_line
    line = stderr_line(integrity)
    if line:
        print(line, file=sys.stderr)
    return 0


def raise_missing(path):
    from fgnav.errors import UserError
    raise UserError(f"--resume: the checkpoint {path} does not exist (run without --resume "
                    "first, with --checkpoint)")
