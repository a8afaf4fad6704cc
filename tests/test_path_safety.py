"""Path safety on a real loopback server: never a byte from outside the root.

Requests go out on a raw socket exactly as written here (no client-side normalisation), on
``/files/...`` and on every ``/v1/scenes/{id}/...`` route. Outside the root lie a secret file,
a container and an unpacked scene; inside, symlinks point at them. Every hostile request must
get 400 or 404 (never 200 with outside bytes, never 500) and no body may hold the secret.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import quote

import pytest

from helpers import ThreadedServer
from tsog_stream.client import open_stream
from tsog_stream.model import TimelineType
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.server import make_app
from tsog_stream.server.catalog import open_beneath, safe_path
from tsog_stream.synthetic import small_scene

SECRET = f"SECRET-{uuid.uuid4().hex}".encode()
CHUNK0 = "chunks/000000.sog"


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``base/root`` is served; ``base`` itself holds the secret file, container and scene."""
    base = tmp_path_factory.mktemp("safety")
    root = base / "root"
    (root / "sub").mkdir(parents=True)
    (base / "secret.txt").write_bytes(SECRET)
    (root / "ok.txt").write_bytes(b"inside")
    segment_scene(
        small_scene(TimelineType.CENTER_SCALE, sh_bands=0),
        root / "clip.tsogs",
        SegmentOptions(window_s=0.5),
    )
    with open_stream(root / "clip.tsogs") as reader:
        reader.unpack(base / "outscene")
    (base / "outscene" / CHUNK0).write_bytes(SECRET)  # an outside scene serving the secret
    (base / "outchunks").mkdir()
    (base / "outchunks" / "000000.sog").write_bytes(SECRET)
    shutil.copy(root / "clip.tsogs", base / "evil.tsogs")
    # symlinks leaving the root: file, folder, scene folder, container, chunk, chunk folder
    (root / "leak.txt").symlink_to(base / "secret.txt")
    (root / "leakdir").symlink_to(base)
    (root / "sub" / "up").symlink_to("../..")
    (root / "linked_scene").symlink_to(base / "outscene")
    (root / "linked.tsogs").symlink_to(base / "evil.tsogs")
    for name in ("evil_chunk", "evil_chunkdir", "evil_manifest"):
        shutil.copytree(base / "outscene", root / name)
    (root / "evil_chunk" / CHUNK0).unlink()
    (root / "evil_chunk" / CHUNK0).symlink_to(base / "secret.txt")
    shutil.rmtree(root / "evil_chunkdir" / "chunks")
    (root / "evil_chunkdir" / "chunks").symlink_to(base / "outchunks")
    (root / "evil_manifest" / "manifest.json").unlink()
    (root / "evil_manifest" / "manifest.json").symlink_to(base / "outscene" / "manifest.json")
    (root / "evil_manifest" / CHUNK0).write_bytes(SECRET)
    return base


@pytest.fixture(scope="module")
def port(base: Path) -> Iterator[int]:
    """A server on ``base/root``."""
    server = ThreadedServer(make_app(base / "root"))
    try:
        yield server.port
    finally:
        server.stop()


def raw_get(port: int, target: bytes) -> tuple[int, bytes]:
    """Status and body of ``GET target`` sent byte for byte (read to EOF, at most 10 s)."""
    request = b"GET " + target + b" HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n"
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.sendall(request)
        data = b""
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            block = sock.recv(1 << 16)
            if not block:
                break
            data += block
    head, _, body = data.partition(b"\r\n\r\n")
    return int(head.split(b" ", 2)[1]), body


DOTS = [
    b"..",
    b"%2e%2e",
    b"%2E%2E",
    b".%2e",
    b"%2e.",
    b"%252e%252e",  # double encoding: decoded once it is the literal name "%2e%2e"
    b"%c0%ae%c0%ae",  # overlong UTF-8 for "."
    b"%e0%80%ae%e0%80%ae",
    b"%u002e%u002e",
]
SEPS = [b"/", b"%2f", b"%2F", b"%5c", b"%5C", b"%252f", b"%c0%af", b"\\"]


def traversals(target: bytes) -> list[bytes]:
    """``target`` one and two levels up, from the root and from ``sub``, in every encoding."""
    out = []
    for dots in DOTS:
        for sep in SEPS:
            out.append(dots + sep + target)
            out.append(b"sub" + sep + dots + sep + dots + sep + target)
    return out


def check_refused(port: int, targets: list[bytes]) -> None:
    """Every target gets 400 or 404 and no secret; failures are reported together."""
    bad = []
    for target in targets:
        status, body = raw_get(port, target)
        if status not in (400, 404) or SECRET in body:
            bad.append((target[:120], status, body[:80]))
    assert not bad, bad


def test_controls_are_served(port: int, base: Path) -> None:
    """The routes work, so the refusals below are not an accident."""
    assert raw_get(port, b"/files/ok.txt") == (200, b"inside")
    assert raw_get(port, b"/files/sub/up/root/ok.txt") == (200, b"inside")  # stays inside
    status, body = raw_get(port, b"/v1/scenes/clip/chunks/0.sog")
    with open_stream(base / "root" / "clip.tsogs") as reader:
        assert (status, body) == (200, reader.chunk_bytes(0))
    assert raw_get(port, b"/v1/scenes/clip/manifest")[0] == 200


def test_dot_dot_in_every_encoding_on_files(port: int) -> None:
    check_refused(port, [b"/files/" + t for t in traversals(b"secret.txt")])


@pytest.mark.parametrize(
    "route",
    [b"/v1/scenes/%s/manifest", b"/v1/scenes/%s/chunks?t=0", b"/v1/scenes/%s/chunks/0.sog"],
)
def test_dot_dot_in_every_encoding_on_scenes(port: int, route: bytes) -> None:
    targets = traversals(b"outscene") + traversals(b"evil")
    check_refused(port, [route % t for t in targets])


def test_symlinks_leaving_the_root(port: int) -> None:
    check_refused(
        port,
        [
            b"/files/leak.txt",
            b"/files/leakdir/secret.txt",
            b"/files/sub/up/secret.txt",
            b"/files/linked_scene/" + CHUNK0.encode(),
            b"/files/linked_scene/manifest.json",
            b"/files/linked.tsogs",
            b"/files/evil_chunk/" + CHUNK0.encode(),
            b"/files/evil_chunkdir/" + CHUNK0.encode(),
            b"/files/evil_manifest/manifest.json",
            b"/v1/scenes/linked_scene/manifest",
            b"/v1/scenes/linked_scene/chunks/0.sog",
            b"/v1/scenes/linked/manifest",
            b"/v1/scenes/linked/chunks/0.sog",
            b"/v1/scenes/linked/chunks?t=0",
            b"/v1/scenes/leakdir/outscene/manifest",
            b"/v1/scenes/leakdir/evil/chunks/0.sog",
            b"/v1/scenes/sub/up/outscene/chunks/0.sog",
            b"/v1/scenes/evil_chunk/chunks/0.sog",
            b"/v1/scenes/evil_chunkdir/chunks/0.sog",
            b"/v1/scenes/evil_manifest/manifest",
            b"/v1/scenes/evil_manifest/chunks/0.sog",
        ],
    )


def test_scene_list_holds_no_outside_scene(port: int) -> None:
    status, body = raw_get(port, b"/v1/scenes")
    assert status == 200 and SECRET not in body
    assert b"linked" not in body and b"leakdir" not in body and b"outscene" not in body


def test_absolute_paths(port: int, base: Path) -> None:
    secret = str(base / "secret.txt").encode()
    encoded = secret.replace(b"/", b"%2f")
    targets = [b"//etc/passwd", b"%2fetc%2fpasswd", b"file:///etc/passwd", b"file:%2f%2fetc"]
    targets += [b"/" + secret, encoded, b"file://" + secret, b"%2f%2f127.0.0.1" + encoded]
    check_refused(port, [b"/files/" + t for t in targets])
    check_refused(port, [b"/v1/scenes/" + t + b"/manifest" for t in targets])
    check_refused(port, [b"//files/../../secret.txt", b"http://127.0.0.1/files/../secret.txt"])


def test_windows_separators(port: int) -> None:
    targets = [
        b"..\\secret.txt",
        b"sub\\..\\..\\secret.txt",
        b"..%5csecret.txt",
        b"C:\\Windows\\win.ini",
        b"C:%5cWindows%5cwin.ini",
        b"C:/Windows/win.ini",
        b"\\\\127.0.0.1\\share\\secret.txt",
        b"%5c%5c127.0.0.1%5cshare",
        b"ok.txt%5c",
    ]
    check_refused(port, [b"/files/" + t for t in targets])
    check_refused(port, [b"/v1/scenes/" + t + b"/chunks/0.sog" for t in targets])


def test_nul_bytes(port: int) -> None:
    targets = [b"ok.txt%00", b"ok.txt%00.png", b"%00/../secret.txt", b"ok.txt\x00", b"sub%00"]
    check_refused(port, [b"/files/" + t for t in targets])
    check_refused(port, [b"/v1/scenes/clip%00/manifest", b"/v1/scenes/clip\x00/manifest"])
    check_refused(port, [b"/v1/scenes/clip%00.tsogs/chunks/0.sog"])


def test_overlong_names(port: int) -> None:
    targets = [
        b"/files/" + b"a" * 10_000,  # over aiohttp's 8190-byte request line: 400
        b"/files/" + b"a" * 300,  # a segment over NAME_MAX (255): 404
        b"/files/sub/" + b"b" * 300 + b"/ok.txt",
        b"/files/" + b"a/" * 3_000 + b"ok.txt",  # deep, over PATH_MAX but under the line limit
        b"/files/" + b"%2e%2e/" * 1_000 + b"secret.txt",
        b"/v1/scenes/" + b"c" * 300 + b"/manifest",
        b"/v1/scenes/" + b"c" * 10_000 + b"/chunks/0.sog",
        b"/v1/scenes/" + b"d/" * 3_000 + b"x/chunks?t=0",
    ]
    check_refused(port, targets)


ODD_NAMES = [b"bad\xff.tsogs", b"new\nline.tsogs", b"tab\there.tsogs", b"esc\x1b[31m.tsogs"]
ODD_FOLDERS = [b"dir\xfe", b"dir\nline", b"del\x7f"]


@pytest.fixture(scope="module")
def odd_port(base: Path) -> Iterator[int]:
    """A server on a root holding ``good.tsogs`` and copies under odd names: undecodable
    bytes and control characters, as files and as folders holding a container."""
    root = base / "odd"
    root.mkdir()
    shutil.copy(base / "root" / "clip.tsogs", root / "good.tsogs")
    top, clip = os.fsencode(root), os.fsencode(base / "root" / "clip.tsogs")
    for name in ODD_NAMES:
        shutil.copy(clip, top + b"/" + name)
    for name in ODD_FOLDERS:
        os.mkdir(top + b"/" + name)
        shutil.copy(clip, top + b"/" + name + b"/inner.tsogs")
    server = ThreadedServer(make_app(root))
    try:
        yield server.port
    finally:
        server.stop()


def test_odd_file_names_are_skipped_never_fatal(odd_port: int) -> None:
    status, body = raw_get(odd_port, b"/v1/scenes")
    assert status == 200
    assert [s["id"] for s in json.loads(body)["scenes"]] == ["good"]
    status, body = raw_get(odd_port, b"/play/")
    assert status == 200 and b"/play/good" in body and body.count(b"<li>") == 1
    escaped = [quote(n, safe=b"").encode() for n in ODD_NAMES]
    check_refused(odd_port, [b"/files/" + n for n in escaped])
    check_refused(odd_port, [b"/v1/scenes/" + n[: -len(b".tsogs")] + b"/manifest" for n in escaped])
    check_refused(
        odd_port, [b"/play/" + quote(n, safe=b"").encode() + b"/inner" for n in ODD_FOLDERS]
    )
    assert raw_get(odd_port, b"/files/good.tsogs")[0] == 200


def test_a_component_swapped_for_a_symlink_after_the_check_is_not_followed(
    tmp_path: Path,
) -> None:
    """The path was checked (resolved, under the root), then a folder on it was replaced by a
    symlink out of the root before the open: the open refuses it instead of leaking."""
    root, outside = (tmp_path / "root").resolve(), (tmp_path / "outside").resolve()
    (root / "scene").mkdir(parents=True)
    (root / "scene" / "clip.bin").write_bytes(b"inside")
    outside.mkdir()
    (outside / "clip.bin").write_bytes(SECRET)
    checked = safe_path(root, "scene/clip.bin")
    with open_beneath(root, checked) as f:
        assert f.read() == b"inside"
    (root / "scene").rename(root / "moved")
    (root / "scene").symlink_to(outside)  # the swap
    with pytest.raises(OSError):
        open_beneath(root, checked).close()
    (root / "scene").unlink()
    (root / "scene").mkdir()
    (root / "scene" / "clip.bin").symlink_to(outside / "clip.bin")  # the file itself swapped
    with pytest.raises(OSError):
        open_beneath(root, checked).close()


def test_non_ascii_and_broken_escapes(port: int) -> None:
    targets = [b"\xc3\xa9", b"%ff%fe", b"%", b"%zz", b"%e2%80%ae.txt", b"\xff/../secret.txt"]
    check_refused(port, [b"/files/" + t for t in targets])
    check_refused(port, [b"/v1/scenes/" + t + b"/manifest" for t in targets])
