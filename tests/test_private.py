"""Private scenes: signed, expiring URLs checked by our server, by nginx (auth_request to our
``/v1/authorize``), and carried transparently by the client; signatures never logged."""

from __future__ import annotations

import hmac
import http.client
import json
import logging
import os
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, quote, urlsplit

import numpy as np
import pytest
from aiohttp import web

from helpers import ThreadedServer, nginx_origin
from tsog_stream import signing
from tsog_stream.cli.main import main
from tsog_stream.client import HttpOptions, open_stream
from tsog_stream.errors import AccessError, InputError
from tsog_stream.model import Gaussians, TimelineType
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.server import private
from tsog_stream.server.app import make_app
from tsog_stream.server.private import Privacy
from tsog_stream.signing import check_signed, covers, redact_url, sign_url
from tsog_stream.synthetic import small_scene

SECRET = b"test-secret-0123456789abcdef"
T = 0.3
FAST = HttpOptions(retries=1, backoff_s=0.01, read_timeout_s=5.0)


def future(seconds: int = 600) -> int:
    return int(time.time()) + seconds


def params(url: str) -> dict[str, str]:
    return {k: v[0] for k, v in parse_qs(urlsplit(url).query).items()}


# -- the scheme itself (sans-I/O) ------------------------------------------------------------


def test_signed_url_round_trip_and_every_tamper_is_refused() -> None:
    url = sign_url("http://h/files/paid/a%20b.tsogs?x=1", SECRET, 2_000_000_000)
    q = params(url)
    assert q["x"] == "1" and q["scope"] == "/files/paid/a b.tsogs" and len(q["signature"]) == 43
    check_signed("/files/paid/a b.tsogs", q, SECRET, now=1_999_999_999)
    other = "B" if q["signature"].endswith("A") else "A"
    cases: dict[str, tuple[dict[str, str | None], int]] = {
        "expired": ({}, 2_000_000_000),
        "bad signature": ({"expires": "2000000001"}, 0),
        "bad signature ": ({"signature": q["signature"][:-1] + other}, 0),
        "does not cover": ({"scope": "/files/other/"}, 0),
        "malformed": ({"expires": "-5"}, 0),
        "required": ({"signature": None}, 0),
    }
    for reason, (change, now) in cases.items():
        tampered = {k: v for k, v in {**q, **change}.items() if v is not None}
        with pytest.raises(AccessError, match=reason.strip()):
            check_signed("/files/paid/a b.tsogs", tampered, SECRET, now=now)
    with pytest.raises(AccessError, match="bad signature"):
        check_signed("/files/paid/a b.tsogs", q, b"another-secret-0123456789", now=0)


def test_scope_prefix_covers_only_paths_below_it() -> None:
    assert covers("/files/paid/", "/files/paid/show/chunks/000001.sog")
    assert covers("/files/paid/x.tsogs", "/files/paid/x.tsogs")
    assert not covers("/files/paid", "/files/paid2/x.tsogs")  # not a folder prefix
    assert not covers("/files/paid/x.tsogs", "/files/paid/x.tsogsX")
    for climbing in ("/files/paid/../free/x", "/files/paid/./x", "/files/paid//x", "/a\\b"):
        assert not covers("/files/paid/", climbing), climbing
    with pytest.raises(InputError, match="scope"):
        sign_url("http://h/files/free/x", SECRET, future(), scope="/files/paid/")


def test_signature_is_compared_in_constant_time(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[tuple[bytes, bytes]] = []
    real = hmac.compare_digest

    def spy(a: bytes, b: bytes) -> bool:
        calls.append((a, b))
        return real(a, b)

    monkeypatch.setattr(hmac, "compare_digest", spy)  # the module signing compares with
    q = params(sign_url("http://h/files/x", SECRET, future()))
    check_signed("/files/x", q, SECRET, time.time())
    assert len(calls) == 1 and calls[0][0] == q["signature"].encode()


def test_redaction_hides_only_the_signature() -> None:
    url = sign_url("http://h/files/x?t=1", SECRET, 123)
    red = redact_url(url)
    assert params(url)["signature"] not in red
    assert "signature=REDACTED" in red and "expires=123" in red and "t=1" in red


def test_secret_from_file_and_environment(tmp_path: Path) -> None:
    key = tmp_path / "key"
    key.write_bytes(b"x" * 32 + b"\n")
    assert signing.load_secret(key, {}) == b"x" * 32
    assert signing.load_secret(None, {signing.SECRET_FILE_ENV: str(key)}) == b"x" * 32
    assert signing.load_secret(None, {signing.SECRET_ENV: "y" * 20}) == b"y" * 20
    assert signing.load_secret(None, {}) is None
    with pytest.raises(InputError, match="16-4096 bytes"):
        signing.load_secret(None, {signing.SECRET_ENV: "short"})
    with pytest.raises(InputError, match="cannot read"):
        signing.load_secret(tmp_path / "missing", {})
    with pytest.raises(InputError, match="URL secret"):
        Privacy(("paid/*",), None)


# -- our server ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``free.tsogs``, ``paid/show.tsogs``, its unpacked ``paid/folder/``, a scene below the
    first one's id (``paid/show/bonus.tsogs``), and a public symlink ``free/alias.tsogs``
    pointing at the private container."""
    root = tmp_path_factory.mktemp("private-site")
    scene = small_scene(TimelineType.CENTER_SCALE, sh_bands=0, dynamic=("means",))
    options = SegmentOptions(window_s=0.5, policy="duplicate")
    segment_scene(scene, root / "free.tsogs", options)
    (root / "paid").mkdir()
    segment_scene(scene, root / "paid" / "show.tsogs", options)
    with open_stream(root / "paid" / "show.tsogs") as reader:
        reader.unpack(root / "paid" / "folder")
    (root / "paid" / "show").mkdir()
    segment_scene(scene, root / "paid" / "show" / "bonus.tsogs", options)
    (root / "free").mkdir()
    os.symlink(root / "paid" / "show.tsogs", root / "free" / "alias.tsogs")
    return root


@pytest.fixture(scope="module")
def expected(site: Path) -> Gaussians:
    with open_stream(site / "paid" / "show.tsogs") as reader:
        return reader.frame_at(T)


@pytest.fixture(scope="module")
def server(site: Path) -> Iterator[ThreadedServer]:
    srv = ThreadedServer(make_app(site, privacy=Privacy(("paid",), SECRET)))
    try:
        yield srv
    finally:
        srv.stop()


def get(
    port: int, target: str, headers: dict[str, str] | None = None
) -> tuple[int, dict[str, str], bytes]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        conn.request("GET", target, headers=headers or {})
        resp = conn.getresponse()
        return resp.status, dict(resp.getheaders()), resp.read()
    finally:
        conn.close()


def signed(target: str, seconds: int = 600, scope: str | None = None) -> str:
    """A signed request target (path and query) for our server."""
    url = sign_url(f"http://127.0.0.1{target}", SECRET, future(seconds), scope)
    parts = urlsplit(url)
    return f"{parts.path}?{parts.query}"


def test_unsigned_private_paths_are_403_whether_or_not_they_exist(server: ThreadedServer) -> None:
    for target in (
        "/files/paid/show.tsogs",
        "/files/paid/missing.tsogs",
        "/files/paid/folder/manifest.json",
        "/v1/scenes/paid/show/manifest",
        "/v1/scenes/paid/nothing/manifest",
        "/files/free/alias.tsogs",  # public name, private file behind the symlink
    ):
        status, headers, body = get(server.port, target)
        assert status == 403, target
        assert headers["Cache-Control"] == "no-store"
        assert b"signed URL" in body and b"show.tsogs\x00" not in body
    assert get(server.port, "/files/free.tsogs", {"Range": "bytes=0-9"})[0] == 206


def test_signed_requests_get_the_bytes_privately_cached(server: ThreadedServer, site: Path) -> None:
    data = (site / "paid" / "show.tsogs").read_bytes()
    status, headers, body = get(
        server.port, signed("/files/paid/show.tsogs"), {"Range": "bytes=5-104"}
    )
    assert status == 206 and body == data[5:105]
    assert headers["Cache-Control"].startswith("private")
    for bad in (signed("/files/paid/show.tsogs", seconds=-1), signed("/files/free.tsogs")):
        target = bad.replace("/files/free.tsogs?", "/files/paid/show.tsogs?")
        status, _, body = get(server.port, target)
        assert status == 403, target
        assert b"expired" in body or b"does not cover" in body


def test_private_scenes_are_not_listed(server: ThreadedServer) -> None:
    status, _, body = get(server.port, "/v1/scenes")
    ids = [s["id"] for s in json.loads(body)["scenes"]]
    assert status == 200 and ids == ["free"]  # not paid/show, paid/folder nor the alias


def test_chunk_list_carries_the_signature_to_chunk_urls(server: ThreadedServer, site: Path) -> None:
    scope = "/v1/scenes/paid/show/"
    status, _, body = get(server.port, signed(f"{scope}chunks", scope=scope) + f"&t={T}")
    assert status == 200
    chunks = json.loads(body)["chunks"]
    assert chunks
    data = (site / "paid" / "show.tsogs").read_bytes()
    for c in chunks:
        assert "signature=" in c["url"]
        status, headers, got = get(server.port, c["url"])
        assert status == 200 and got == data[c["offset"] : c["offset"] + c["length"]]
        assert headers["Cache-Control"] == "private, max-age=31536000, immutable"
        unsigned = c["url"].split("&")[0]
        assert get(server.port, unsigned)[0] == 403


def test_each_request_is_decided_once(
    server: ThreadedServer, monkeypatch: pytest.MonkeyPatch
) -> None:
    """One privacy decision a request, and one signature check when a private path is asked
    for, whatever route and answer: public, private, signed, missing, a public symlink."""
    decided: list[str] = []
    checked: list[str] = []
    real_admit, real_check = Privacy.admit, check_signed

    def admit(self: Privacy, request: web.Request, rels: Iterable[str]) -> None:
        decided.append(request.path)
        real_admit(self, request, rels)

    def check(path: str, *args: Any) -> None:
        checked.append(path)
        real_check(path, *args)

    monkeypatch.setattr(Privacy, "admit", admit)
    monkeypatch.setattr(private, "check_signed", check)
    scope = "/v1/scenes/paid/show/"
    cases = {
        f"/v1/scenes/free/chunks?t={T}": (200, 0),
        f"/v1/scenes/paid/show/chunks?t={T}": (403, 1),
        signed(f"{scope}chunks", scope=scope) + f"&t={T}": (200, 1),
        "/v1/scenes/paid/nothing/chunks?t=0": (403, 1),
        signed("/files/paid/show.tsogs"): (200, 1),
        "/files/free/alias.tsogs": (403, 1),
        "/files/free.tsogs": (200, 0),
        "/files/missing.tsogs": (404, 0),
    }
    for target, (status, checks) in cases.items():
        decided.clear()
        checked.clear()
        assert get(server.port, target)[0] == status, target
        assert (len(decided), len(checked)) == (1, checks), target


def test_a_scene_scope_opens_that_scene_and_no_scene_below_its_id(server: ThreadedServer) -> None:
    scope = "/v1/scenes/paid/show/"  # what the signed player page of paid/show hands out
    assert get(server.port, signed(f"{scope}manifest", scope=scope))[0] == 200
    bonus = "/v1/scenes/paid/show/bonus/"
    for path in ("manifest", "chunks?t=0.1", "chunks/0.sog"):
        target = signed(bonus + path.split("?")[0], scope=scope)
        query = "&" + path.split("?")[1] if "?" in path else ""
        status, _, body = get(server.port, target + query)
        assert status == 403 and b"covers the scene paid/show only" in body
    folder = "/v1/scenes/paid/"  # a folder of scenes, not a scene: every scene below it
    assert get(server.port, signed(f"{bonus}manifest", scope=folder))[0] == 200
    assert get(server.port, signed(f"{scope}manifest", scope=folder))[0] == 200


def test_access_log_never_holds_the_signature(
    server: ThreadedServer, caplog: pytest.LogCaptureFixture
) -> None:
    target = signed("/files/paid/show.tsogs")
    sig = params("http://h" + target)["signature"]
    with caplog.at_level(logging.INFO, logger="aiohttp.access"):
        assert get(server.port, target, {"Range": "bytes=0-9"})[0] == 206
        assert get(server.port, target.replace("signature=", "signature=x"))[0] == 403
        deadline = time.monotonic() + 5
        while len([r for r in caplog.records if r.name == "aiohttp.access"]) < 2:
            assert time.monotonic() < deadline, "no access log lines"
            time.sleep(0.05)
    lines = [r.getMessage() for r in caplog.records if r.name == "aiohttp.access"]
    assert any('" 206 ' in line and "signature=REDACTED" in line for line in lines)
    assert all(sig not in line for line in caplog.text.splitlines() + lines)


def test_client_reads_signed_urls_transparently(
    server: ThreadedServer, expected: Gaussians
) -> None:
    base = f"http://127.0.0.1:{server.port}"
    packed = sign_url(f"{base}/files/paid/show.tsogs", SECRET, future())
    folder = sign_url(
        f"{base}/files/paid/folder/manifest.json", SECRET, future(), scope="/files/paid/folder/"
    )
    for url in (packed, folder):
        with open_stream(url, http=FAST) as sync:
            got = sync.frame_at(T)
            assert np.array_equal(got.means, expected.means)
            assert np.array_equal(got.sh0, expected.sh0)
    stale = sign_url(f"{base}/files/paid/show.tsogs", SECRET, future(-5))
    with pytest.raises(AccessError, match="expired") as info:
        open_stream(stale, http=FAST)
    assert params(stale)["signature"] not in str(info.value)


def test_cli_sign_and_serve_refuse_without_secret(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.delenv(signing.SECRET_ENV, raising=False)
    monkeypatch.delenv(signing.SECRET_FILE_ENV, raising=False)
    assert main(["sign", "http://h/files/x.tsogs"]) == 1
    assert "no URL secret" in capsys.readouterr().err
    assert main(["serve", str(tmp_path), "--private", "x"]) == 1
    assert "need a URL secret" in capsys.readouterr().err
    key = tmp_path / "key"
    key.write_bytes(SECRET)
    assert main(["sign", "http://h/files/x.tsogs", "--ttl", "2h", "--secret-file", str(key)]) == 0
    url = capsys.readouterr().out.strip()
    q = params(url)
    assert 7100 < int(q["expires"]) - time.time() <= 7200
    check_signed("/files/x.tsogs", q, SECRET, time.time())


# -- nginx in front: auth_request to /v1/authorize -----------------------------------------


@pytest.mark.nginx
def test_nginx_enforces_the_same_scheme_through_auth_request(
    site: Path, tmp_path: Path, expected: Gaussians
) -> None:
    authorizer = ThreadedServer(make_app(tmp_path, privacy=Privacy((), SECRET)))
    prefix = tmp_path / "nginx"
    http_extra = "log_format no_query '$remote_addr \"$request_method $uri\" $status';"
    server_extra = f"""
        location /paid/ {{
            auth_request /_tsog_auth;
            access_log {prefix}/logs/paid.log no_query;
        }}
        location = /_tsog_auth {{
            internal;
            proxy_pass http://127.0.0.1:{authorizer.port}/v1/authorize;
            proxy_pass_request_body off;
            proxy_set_header Content-Length "";
            proxy_set_header X-Original-URI $request_uri;
        }}"""
    try:
        with nginx_origin(site, prefix, http_extra=http_extra, server_extra=server_extra) as base:
            port = int(urlsplit(base).port or 0)
            assert get(port, "/paid/show.tsogs")[0] == 403
            assert get(port, "/free.tsogs", {"Range": "bytes=0-9"})[0] == 206
            url = sign_url(base + "paid/show.tsogs", SECRET, future())
            with open_stream(url, http=FAST) as sync:
                assert np.array_equal(sync.frame_at(T).means, expected.means)
            climb = signed("/free/", scope="/free/").replace("/free/?", "/free/../paid/show.tsogs?")
            assert get(port, quote(climb, safe="/?=&"))[0] in (400, 403)
            with pytest.raises(AccessError):
                open_stream(sign_url(base + "paid/show.tsogs", SECRET, future(-1)), http=FAST)
        log = (prefix / "logs" / "paid.log").read_text()
        assert "/paid/show.tsogs" in log and "signature" not in log
    finally:
        authorizer.stop()
