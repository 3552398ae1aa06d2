"""`detach-dashboard`: the viser web dashboard over run folders (reads runs/ only)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Sequence

_T0 = time.perf_counter()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="detach-dashboard",
        description="Browse live and finished runs (curves, 3D replay, tables) in a browser.")
    parser.add_argument("--runs", type=Path, default=Path("runs"), help="runs folder (default: runs/)")
    parser.add_argument("--host", default="127.0.0.1", help="bind address (default: loopback)")
    parser.add_argument("--port", type=int, default=8080,
                        help="port (default: 8080; the next free one if taken; 0 = any)")
    parser.add_argument("--expose", action="store_true",
                        help="bind to 0.0.0.0 so that other machines can connect "
                             "(no authentication: trusted networks only)")
    parser.add_argument("--allow-launch", action="store_true",
                        help="show a form that starts detach-run processes on this machine")
    parser.add_argument("--poll", type=float, default=1.0,
                        help="seconds between re-reads of the runs folder (default: 1)")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.poll <= 0:
        print("detach-dashboard: error: --poll must be > 0", file=sys.stderr)
        return 2
    host = "0.0.0.0" if args.expose else args.host
    if args.runs.exists() and not args.runs.is_dir():
        print(f"detach-dashboard: error: --runs {args.runs} is not a folder", file=sys.stderr)
        return 2

    import viser  # after argument parsing, so that --help stays instant

    from server.app import Dashboard

    server = viser.ViserServer(host=host, port=args.port, verbose=False)
    dashboard = Dashboard(server, args.runs, allow_launch=args.allow_launch, poll_s=args.poll)
    dashboard.start()
    shown_host = "127.0.0.1" if host in ("0.0.0.0", "::", "") else host
    url = f"http://{shown_host}:{server.get_port()}"
    waiting = "" if args.runs.is_dir() else " (does not exist yet; waiting for it)"
    print(f"detach-dashboard: {url}  runs: {args.runs.resolve()}{waiting}  "
          f"[ready in {time.perf_counter() - _T0:.2f} s]", flush=True)
    if args.expose:
        print(f"detach-dashboard: listening on all interfaces (port {server.get_port()}); "
              f"anyone who can reach this machine can view the runs"
              + (" and start processes" if args.allow_launch else ""), flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        dashboard.stop()
        server.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
