"""``tsog serve`` and ``tsog sign``: the CLI side of the server and of URL signing."""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from ..errors import InputError
from ..io.objects import as_location
from ..signing import load_secret, parse_ttl, sign_url
from .common import Integer, Seconds, Subparsers, local_file
from .progress import Progress

SECRET_HELP = (
    "file holding the URL-signing secret (default: $TSOG_URL_SECRET_FILE, else the secret "
    "itself in $TSOG_URL_SECRET); make one with: head -c 32 /dev/urandom | base64 > FILE"
)


def add_serve_command(sub: Subparsers) -> argparse.ArgumentParser:
    """Register ``serve``; returns its parser (its ``func``: :func:`cmd_serve`)."""
    p = sub.add_parser(
        "serve",
        help="serve containers and files over HTTP with byte ranges (docs/http.md)",
        epilog="examples:\n"
        "  tsog serve media/        then open http://127.0.0.1:8080/play/ (the web player)\n"
        "  TSOG_URL_SECRET_FILE=secret.key tsog serve media/ --private 'paid/*'",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "root",
        help="folder to serve, or one .tsogs file (only that file is served); or the same in "
        "object storage: s3://bucket/media/ (needs tsog-stream[s3]; bodies read with ranged GETs)",
    )
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1)")
    p.add_argument(
        "--port", type=Integer(0, 65535), default=8080, help="port (default 8080; 0 = any free)"
    )
    p.add_argument(
        "--max-concurrent",
        type=Integer(1, 1_000_000),
        default=256,
        help="requests at once; more get 503",
    )
    p.add_argument(
        "--max-per-client",
        type=Integer(1, 1_000_000),
        default=32,
        help="requests at once from one client address once the server is half busy (default "
        "32; raise it behind a proxy, where every request comes from one address)",
    )
    p.add_argument(
        "--private",
        action="append",
        default=[],
        metavar="GLOB",
        help="paths under ROOT (files, scene folders, or a folder above them) served only with a "
        "signed URL (tsog sign); '*' crosses '/'; repeatable",
    )
    p.add_argument("--secret-file", type=local_file, help=SECRET_HELP)
    day = Seconds(86400)
    p.add_argument("--keepalive", type=day, default=15.0, help="idle and request-head timeout, s")
    p.add_argument("--send-timeout", type=day, default=60.0, help="deadline to send one body, s")
    p.add_argument(
        "--stall-timeout",
        type=day,
        default=10.0,
        help="drop a client that takes no bytes for this long, s (default 10)",
    )
    p.add_argument(
        "--workers",
        type=Integer(1, 256),
        help="processes sharing the port, each with its own limits and caches (default: one "
        "per core this process may use; 1 = one process)",
    )
    p.add_argument("-q", "--quiet", action="store_true", help="no access log on stderr")
    p.set_defaults(func=cmd_serve)
    return p


def add_sign_command(sub: Subparsers) -> argparse.ArgumentParser:
    """Register ``sign``; returns its parser."""
    p = sub.add_parser(
        "sign",
        help="print a signed, expiring URL for a private scene (docs/http.md)",
        epilog="example: tsog sign http://host:8080/files/paid/show.tsogs --ttl 12h\n"
        "         tsog sign http://host:8080/v1/scenes/paid/show/manifest "
        "--scope /v1/scenes/paid/show/",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("url", help="the URL to sign (its path is what the signature covers)")
    p.add_argument("--ttl", default="1h", help="lifetime: 3600, 90s, 15m, 12h, 7d (default 1h)")
    p.add_argument(
        "--scope",
        help="sign a path prefix ending with '/' instead of the exact path (a folder, or a "
        "scene's /v1/scenes/ID/ URLs)",
    )
    p.add_argument("--secret-file", type=local_file, help=SECRET_HELP)
    p.add_argument("-q", "--quiet", action="store_true", help="no messages on stderr")
    return p


def cmd_serve(args: argparse.Namespace, progress: Progress) -> int:
    """Serve until interrupted; returns the exit code."""
    # the server (aiohttp.web) is loaded by the command that runs it, not by every command
    from ..server import Limits, Privacy, Site, default_workers, run_server, run_workers  # noqa: PLC0415

    found = as_location(args.root)
    if not (found.is_dir() or found.is_file()):
        raise InputError("no such folder or file", where=args.root)
    root = found if isinstance(found, Path) else args.root  # a Site crosses processes: a URL
    privacy = Privacy(tuple(args.private), load_secret(args.secret_file))
    if not args.quiet:
        logging.basicConfig(level=logging.INFO, format="%(message)s")
        for chatty in ("botocore", "aiobotocore", "s3fs", "fsspec"):  # object storage clients
            logging.getLogger(chatty).setLevel(logging.WARNING)
    progress.done()
    limits = Limits(
        args.max_concurrent,
        max_per_client=args.max_per_client,
        send_timeout_s=args.send_timeout,
        stall_timeout_s=args.stall_timeout,
        keepalive_s=args.keepalive,
    )
    workers = args.workers or default_workers()
    if workers > 1:
        run_workers(Site(root, args.host, args.port, limits, privacy), workers)
    else:
        run_server(root, host=args.host, port=args.port, limits=limits, privacy=privacy)
    return 0


def cmd_sign(args: argparse.Namespace, progress: Progress) -> int:
    """Print ``args.url`` signed to expire after ``--ttl``."""
    secret = load_secret(args.secret_file)
    if secret is None:
        raise InputError(
            "no URL secret: pass --secret-file or set $TSOG_URL_SECRET_FILE or $TSOG_URL_SECRET"
        )
    expires = int(time.time()) + parse_ttl(args.ttl)
    progress.done()
    print(sign_url(args.url, secret, expires, args.scope))
    return 0
