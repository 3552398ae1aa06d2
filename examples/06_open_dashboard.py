"""Open the dashboard

The dashboard is a viser server over a runs folder: runs, curves, 3D replay and tables, one
view per browser. Open the printed URL; Ctrl-C stops it (`--seconds` stops it by itself).

    python examples/06_open_dashboard.py [--runs runs] [--port 8080] [--seconds 0]
"""

import argparse
import time
from pathlib import Path

from server.access import AccessPolicy, serve
from server.app import Dashboard


def main(runs: Path, port: int, seconds: float) -> None:
    server = serve("127.0.0.1", port, AccessPolicy(expose=False, token=None))
    dashboard = Dashboard(server, runs)
    dashboard.start()
    print(f"dashboard: http://127.0.0.1:{server.get_port()}  runs: {runs.resolve()}", flush=True)
    try:
        deadline = time.monotonic() + seconds if seconds > 0 else float("inf")
        while time.monotonic() < deadline:
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        dashboard.stop()
        server.stop()


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--runs", type=Path, default=Path("runs"))
    parser.add_argument("--port", type=int, default=8080)
    parser.add_argument("--seconds", type=float, default=0, help="stop after this long (0: until Ctrl-C)")
    args = parser.parse_args()
    main(args.runs, args.port, args.seconds)
