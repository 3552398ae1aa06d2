"""`detach-dashboard`: the viser web dashboard over run folders (reads runs/ only)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Sequence


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="detach-dashboard",
        description="Browse live and finished runs (curves, 3D replay, tables) in a browser.")
    parser.add_argument("--runs", type=Path, default=Path("runs"), help="runs folder (default: runs/)")
    parser.add_argument("--host", default="127.0.0.1", help="bind address (default: loopback)")
    parser.add_argument("--port", type=int, default=8080, help="port (default: 8080)")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    build_parser().parse_args(argv)
    print("detach-dashboard: error: the dashboard is not available in this version yet",
          file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
