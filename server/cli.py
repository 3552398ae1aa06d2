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
                        help="bind to 0.0.0.0 so that other machines can connect; a token printed "
                             "at start-up is then required")
    parser.add_argument("--allow-launch", action="store_true",
                        help="show a form that starts detach-run processes on this machine")
    parser.add_argument("--launch-limit", type=int, default=None,
                        help="runs started from the form that may run at once (default: 2)")
    parser.add_argument("--poll", type=float, default=1.0,
                        help="seconds between re-reads of the runs folder (default: 1)")
    return parser


def _error(message: str) -> int:
    print(f"detach-dashboard: error: {message}", file=sys.stderr)
    return 2


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.poll <= 0:
        return _error(f"--poll {args.poll} must be > 0 (seconds)")
    if args.launch_limit is not None and args.launch_limit < 1:
        return _error(f"--launch-limit {args.launch_limit} must be at least 1")
    if not 0 <= args.port <= 65535:
        return _error(f"--port {args.port} must be 0..65535")
    host = "0.0.0.0" if args.expose else args.host
    if args.runs.exists() and not args.runs.is_dir():
        return _error(f"--runs {args.runs} is not a folder")

    from server.access import AccessPolicy, is_loopback, new_token, serve

    exposed = args.expose or not is_loopback(host)
    policy = AccessPolicy(expose=exposed, token=new_token() if exposed else None)
    server = serve(host, args.port, policy)
    shown_host = "127.0.0.1" if host in ("0.0.0.0", "::", "") else host
    url = f"http://{shown_host}:{server.get_port()}"
    if policy.token:
        url += f"/?token={policy.token}"
    waiting = "" if args.runs.is_dir() else " (does not exist yet; waiting for it)"
    # The page is served from here on; browsers that connect before the panels exist get
    # them when the dashboard registers (viser replays its connect callback for them).
    print(f"detach-dashboard: {url}  runs: {args.runs.resolve()}{waiting}  "
          f"[ready in {time.perf_counter() - _T0:.2f} s]", flush=True)
    if exposed:
        print(f"detach-dashboard: listening on {host} (port {server.get_port()}); browsers need "
              f"the token in the URL above (other machines: replace {shown_host} by this "
              f"machine's address); anyone with it can view the runs"
              + (" and start processes" if args.allow_launch else ""), flush=True)

    from server.app import Dashboard
    from server.launch import DEFAULT_LIMIT, Launcher, LaunchOptions

    launcher = None
    if args.allow_launch:
        options = LaunchOptions.find()
        launcher = Launcher(options, args.runs, args.launch_limit or DEFAULT_LIMIT) \
            if options is not None else None
    dashboard = Dashboard(server, args.runs, launcher=launcher, allow_launch=args.allow_launch,
                          poll_s=args.poll)
    dashboard.start()
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
