"""``tsog serve``: the CLI side of the server (argument parsing only; logic lives in ``app``)."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any

from ..cli.progress import Progress
from ..errors import InputError
from .app import Limits, run_server


def add_serve_command(sub: Any) -> argparse.ArgumentParser:
    """Register ``serve`` on an argparse subparsers object; returns its parser."""
    p: argparse.ArgumentParser = sub.add_parser(
        "serve", help="serve containers and files over HTTP with byte ranges (docs/http.md)"
    )
    p.add_argument("root", help="folder to serve, or one .tsogs file (only that file is served)")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=8080, help="port (default 8080; 0 = any free)")
    p.add_argument("--max-concurrent", type=int, default=256, help="requests at once; more get 503")
    p.add_argument("-q", "--quiet", action="store_true", help="no access log on stderr")
    p.set_defaults(func=cmd_serve)
    return p


def cmd_serve(args: argparse.Namespace, progress: Progress) -> int:
    """Serve until interrupted; returns the exit code."""
    root = Path(args.root)
    if not (root.is_dir() or root.is_file()):
        raise InputError("no such folder or file", where=args.root)
    if not 0 <= args.port <= 65535:
        raise InputError(f"expected a port 0-65535, got {args.port}", where="--port")
    if args.max_concurrent < 1:
        raise InputError("must be at least 1", where="--max-concurrent")
    if not args.quiet:
        logging.basicConfig(level=logging.INFO, format="%(message)s")
    progress.done()
    run_server(root, host=args.host, port=args.port, limits=Limits(args.max_concurrent))
    return 0
