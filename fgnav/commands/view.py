"""``fgnav view FILE.rrd``: open a Rerun recording in the viewer, or say how on a headless
machine."""

from __future__ import annotations


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "view",
        help="open a Rerun recording (.rrd) in the Rerun viewer",
        description=(
            "Open FILE.rrd (a Rerun recording written by fgnav) in the Rerun viewer. "
            "On a machine without a display, print the command to run elsewhere "
            "(exit 0); exit 2 if the file is missing or not a recording."
        ),
    )
    p.add_argument("file", metavar="FILE.rrd", help="Rerun recording to open")
    p.add_argument("--print-command", action="store_true",
                   help="only print the viewer command, do not start it")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object (file, entities, launched, command, message)")
    p.set_defaults(func=run)


def run(args) -> int:
    import json
    from pathlib import Path

    from fgnav.errors import UserError
    from fgnav.viz import rerun_log

    path = Path(args.file)
    if not path.is_file():
        raise UserError(f"{path}: no such recording file")
    n_entities = _check_recording(path)

    cmd = rerun_log.viewer_command(path)
    if args.print_command:
        launched, msg = False, " ".join(cmd)
    else:
        launched, msg = rerun_log.open_viewer(path)
    if args.json:
        print(json.dumps({"file": str(path), "entities": n_entities, "launched": launched,
                          "command": cmd, "message": msg}))
    else:
        print(msg)
    return 0


def _check_recording(path) -> int:
    """Number of entities in the recording; ``UserError`` if it is not a readable .rrd."""
    from fgnav.errors import UserError

    try:
        import rerun as rr

        reader = rr.chunk.RrdReader(str(path))
        if not reader.recordings():
            raise UserError(f"{path}: the file holds no Rerun recording")
        return len({c.entity_path for c in reader.stream().to_chunks()})
    except UserError:
        raise
    except Exception as exc:  # the reader raises assorted errors on non-rrd bytes
        raise UserError(f"{path}: not a readable Rerun .rrd file ({exc})") from None
