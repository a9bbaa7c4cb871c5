#!/usr/bin/env python
"""Screenshot of a recording as the Rerun web viewer opens it (its stored blueprint), taken
by headless Chromium: a way to look at what ``fgnav smooth --rerun`` draws on a machine
without a display.

    python scripts/rerun_screenshot.py FILE.rrd OUT.png [--wait-s 35] [--size 1600x1000]

Starts ``rerun FILE.rrd --web-viewer`` (WebGL renderer) on local ports, opens it in
``chromium --headless=new`` (SwiftShader software rendering) and after ``--wait-s`` seconds
of real time (the viewer streams the recording over gRPC; a virtual-time budget does not
wait for that) captures the page over the DevTools protocol (needs ``websocket-client``).
Both processes are stopped afterwards.
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("rrd")
    ap.add_argument("out")
    ap.add_argument("--wait-s", type=float, default=35.0)
    ap.add_argument("--size", default="1600x1000")
    ap.add_argument("--ports", default="19391,19392,19393",
                    help="web viewer, gRPC and DevTools ports")
    args = ap.parse_args(argv)
    import websocket

    web, grpc, devtools = args.ports.split(",")
    browser = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which(
        "google-chrome")
    if browser is None:
        print("no chromium on PATH", file=sys.stderr)
        return 2
    srv = subprocess.Popen([sys.executable, "-m", "rerun", args.rrd, "--web-viewer",
                            "--web-viewer-port", web, "--port", grpc, "--renderer", "webgl"],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                           env=dict(os.environ, BROWSER="true"),   # no browser of its own
                           start_new_session=True)   # the viewer binary is a child of it
    profile = tempfile.mkdtemp(prefix="rerun-shot-")
    br = None
    try:
        time.sleep(5.0)
        url = (f"http://127.0.0.1:{web}?url=rerun%2Bhttp%3A%2F%2Flocalhost%3A{grpc}%2Fproxy"
               "&renderer=webgl")
        br = subprocess.Popen([browser, "--headless=new", "--no-sandbox", "--use-angle=swiftshader",
                               "--enable-unsafe-swiftshader",
                               f"--window-size={args.size.replace('x', ',')}",
                               f"--remote-debugging-port={devtools}", "--remote-allow-origins=*",
                               f"--user-data-dir={profile}", url],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        page = None
        for _ in range(60):
            try:
                tabs = json.load(urllib.request.urlopen(f"http://127.0.0.1:{devtools}/json"))
                page = next(t for t in tabs if t["type"] == "page")
                break
            except (OSError, StopIteration):
                time.sleep(0.5)
        if page is None:
            print("chromium did not open the page", file=sys.stderr)
            return 1
        time.sleep(args.wait_s)
        ws = websocket.create_connection(page["webSocketDebuggerUrl"], timeout=60)
        ws.send(json.dumps({"id": 1, "method": "Page.captureScreenshot",
                            "params": {"format": "png"}}))
        while True:
            msg = json.loads(ws.recv())
            if msg.get("id") == 1:
                break
        with open(args.out, "wb") as f:
            f.write(base64.b64decode(msg["result"]["data"]))
        print(f"wrote {args.out}")
        return 0
    finally:
        if br is not None:
            br.terminate()
            br.wait(10)
        os.killpg(srv.pid, signal.SIGTERM)   # the group of the viewer started here
        srv.wait(10)
        shutil.rmtree(profile, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
