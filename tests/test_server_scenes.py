"""The scene list (``/v1/scenes`` and ``/play/``) in every serving mode: each thumbnail it
shows answers, as ``image/png``, at exactly the URL it gives; counts say what one frame shows;
an assumed length is marked. Real samples, segmented here."""

from __future__ import annotations

import asyncio
import html
import io
import itertools
import json
import re
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from PIL import Image

from helpers import ThreadedServer, fetch, loopback_s3
from tsog_stream.cli.main import main
from tsog_stream.constants import THUMBNAIL_SIZE
from tsog_stream.container.sources import FileSource, read_index
from tsog_stream.container.stream_index import StreamIndex
from tsog_stream.io.readers import load_scene
from tsog_stream.model import TimelineType
from tsog_stream.schemas.manifest import Policy
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.server import Privacy, make_app
from tsog_stream.server.player import _scene_item
from tsog_stream.server.shown import gaussians_per_frame
from tsog_stream.synthetic import small_scene

MONKEY = "4d/pc_flipbook_monkey"
"""A real SOG flipbook: 3 frames of 31,658 Gaussians (94,974 in all)."""
SPLATV = "4d/splatv/tztechno_hanabi2_synthetic.splatv"
"""A real .splatv, which does not carry its length: read as 1 s without --duration-s."""
STATIC = "3dgs/gs3d_pr477_lod4_tile_0.ply"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
BUCKET = "scenes"
SECRET = b"0123456789abcdef0123456789abcdef"


def _segment(*args: str) -> None:
    assert main(["segment", *args, "-q"]) == 0


@pytest.fixture(scope="module")
def media(samples: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A root with the monkey flipbook, the .splatv and a static capture as containers (each
    with the thumbnail tsog segment drew) and the flipbook unpacked (its thumbnail copied
    beside its manifest, as segmenting into a folder would leave it)."""
    root = tmp_path_factory.mktemp("media")
    _segment(str(samples / MONKEY), "-o", str(root / "monkey.tsogs"))
    _segment(str(samples / SPLATV), "-o", str(root / "fire.tsogs"))
    _segment(str(samples / STATIC), "-o", str(root / "still.tsogs"))
    assert main(["unpack", str(root / "monkey.tsogs"), "-o", str(root / "loose"), "-q"]) == 0
    shutil.copy(root / "monkey.tsogs.thumb.png", root / "loose" / "manifest.json.thumb.png")
    return root


def _listed(port: int) -> dict[str, dict[str, Any]]:
    """The scene list, by id."""
    r = fetch(port, "/v1/scenes")
    assert r.status == 200
    return {s["id"]: s for s in json.loads(r.body)["scenes"]}


def _page_images(port: int) -> list[str]:
    """Every image URL the list page shows."""
    r = fetch(port, "/play/")
    assert r.status == 200
    return [html.unescape(u) for u in re.findall(r'<img src="([^"]*)"', r.body.decode())]


def _check_png(port: int, url: str, expected: bytes) -> None:
    """``url`` answers GET and HEAD with the PNG ``expected``, as image/png, and it decodes."""
    got = fetch(port, url)
    assert (got.status, got.headers["Content-Type"]) == (200, "image/png"), url
    assert got.body == expected and got.body.startswith(PNG_SIGNATURE)
    with Image.open(io.BytesIO(got.body)) as image:
        image.load()
        assert image.size == THUMBNAIL_SIZE
    head = fetch(port, url, method="HEAD")
    assert (head.status, head.headers["Content-Type"]) == (200, "image/png")
    assert head.headers["Content-Length"] == str(len(expected)) and head.body == b""


def _check_list_thumbnails(port: int, thumbnails: dict[str, bytes]) -> None:
    """The list gives every scene of ``thumbnails`` (id -> PNG) its thumbnail URL, the page
    shows exactly those URLs, and each answers with the PNG."""
    listed = _listed(port)
    assert sorted(listed) == sorted(thumbnails)
    urls = {sid: listed[sid]["thumbnail"] for sid in thumbnails}
    assert all(urls.values()), urls
    assert sorted(_page_images(port)) == sorted(urls.values())
    for sid, url in urls.items():
        _check_png(port, url, thumbnails[sid])


def _thumbnails(root: Path, ids: list[str]) -> dict[str, bytes]:
    """The PNG beside each scene of ``ids`` under ``root``."""
    out = {}
    for sid in ids:
        container = root / f"{sid}.tsogs"
        beside = container if container.is_file() else root / sid / "manifest.json"
        out[sid] = Path(f"{beside}.thumb.png").read_bytes()
    return out


def test_a_folder_lists_thumbnails_that_answer_as_png(media: Path) -> None:
    server = ThreadedServer(make_app(media))
    try:
        thumbnails = _thumbnails(media, ["fire", "loose", "monkey", "still"])
        _check_list_thumbnails(server.port, thumbnails)
        for _ in range(2):  # the first computes the ETag, the second finds it known
            _check_png(server.port, "/files/monkey.tsogs.thumb.png", thumbnails["monkey"])
    finally:
        server.stop()


def test_one_container_lists_its_thumbnail_and_exposes_no_sibling(media: Path) -> None:
    """tsog serve FILE.tsogs (and tsog view, which serves one container so): its thumbnail
    is the scene's and answers; the siblings' files stay 404."""
    server = ThreadedServer(make_app(media / "monkey.tsogs"))
    try:
        _check_list_thumbnails(server.port, _thumbnails(media, ["monkey"]))
        for _ in range(2):
            expected = (media / "monkey.tsogs.thumb.png").read_bytes()
            _check_png(server.port, "/files/monkey.tsogs.thumb.png", expected)
        for hidden in (
            "/files/fire.tsogs",
            "/files/fire.tsogs.thumb.png",
            "/files/loose/manifest.json.thumb.png",
            "/v1/scenes/fire/thumbnail",
            "/files/monkey.tsogs.thumb.png.x",
        ):
            assert fetch(server.port, hidden).status == 404, hidden
    finally:
        server.stop()


def test_a_private_scenes_thumbnail_needs_a_signed_url(media: Path) -> None:
    """A glob naming a container makes its thumbnail private too, on every route."""
    privacy = Privacy(("monkey.tsogs",), SECRET)
    server = ThreadedServer(make_app(media, privacy=privacy))
    try:
        assert "monkey" not in _listed(server.port)
        for url in ("/files/monkey.tsogs.thumb.png", "/v1/scenes/monkey/thumbnail"):
            for _ in range(2):  # refused alike with the file's ETag known
                assert fetch(server.port, url).status == 403, url
        assert fetch(server.port, "/files/fire.tsogs.thumb.png").status == 200
    finally:
        server.stop()


def test_the_list_counts_what_one_frame_shows(media: Path, samples: Path) -> None:
    frame = load_scene(str(samples / MONKEY / "monkey_0001.sog")).scene
    still = load_scene(str(samples / STATIC)).scene
    server = ThreadedServer(make_app(media))
    try:
        listed = _listed(server.port)
        page = fetch(server.port, "/play/").body.decode()
    finally:
        server.stop()
    monkey, loose, fire = listed["monkey"], listed["loose"], listed["fire"]
    assert monkey["gaussians"] == 3 * len(frame) == 94974
    assert monkey["gaussians_per_frame"] == loose["gaussians_per_frame"] == len(frame) == 31658
    assert listed["still"]["gaussians_per_frame"] == listed["still"]["gaussians"] == len(still)
    assert fire["gaussians_per_frame"] == _most_held(_index(media / "fire.tsogs"))
    assert fire["gaussians_per_frame"] < fire["gaussians"]
    assert (monkey["duration_assumed"], fire["duration_assumed"]) == (False, True)
    assert [listed[k]["static"] for k in ("monkey", "fire", "still")] == [False, False, True]
    items = {_item_id(li): li for li in re.findall(r"<li>.*?</li>", page)}
    assert "31,658 Gaussians per frame" in items["monkey"] and "94,974" not in page
    assert "0.10 s &middot;" in items["monkey"] and "(assumed)" not in items["monkey"]
    assert "1.00 s (assumed) &middot;" in items["fire"]
    assert f"still &middot; {len(still):,} Gaussians &middot;" in items["still"]


def _item_id(li: str) -> str:
    match = re.search(r'<span class="name">([^<]*)</span>', li)
    assert match is not None
    return html.unescape(match[1])


def _index(path: Path) -> StreamIndex:
    return asyncio.run(read_index(FileSource(path)))


def _most_held(index: StreamIndex) -> int:
    """The most Gaussians the reader's own chunk choice (``chunks_for``) gives at one time,
    tried between every two consecutive chunk or node edges (and at the start of a static
    scene): the brute-force count :func:`gaussians_per_frame` must equal."""
    m = index.manifest
    edges = {m.scene.start_s, m.scene.end_s}
    edges |= {t for c in m.chunks for t in (c.start_s, c.end_s)}
    edges |= {t for n in m.nodes for t in (n.start_s, n.end_s)}
    times = sorted(edges)
    probes = [(a + b) / 2 for a, b in itertools.pairwise(times)]
    inside = [t for t in probes if m.scene.start_s <= t <= m.scene.end_s] or [m.scene.start_s]
    return max(sum(c.count for c in index.chunks_for(t) if c.holds_gaussians) for t in inside)


@pytest.mark.parametrize(
    ("kind", "policy"),
    [
        (TimelineType.CENTER_SCALE, "duplicate"),
        (TimelineType.CENTER_SCALE, "hierarchy"),
        (TimelineType.START_DURATION, "hybrid"),
        (TimelineType.FRAME, "hierarchy"),
    ],
)
def test_per_frame_is_what_the_reader_holds_at_its_fullest(
    tmp_path: Path, kind: TimelineType, policy: Policy
) -> None:
    """Every policy, two quality layers and SH-band chunks: the count from the index alone
    equals the most the reader's chunk choice holds at any time."""
    path = tmp_path / "clip.tsogs"
    options = SegmentOptions(window_s=0.5, policy=policy, layers=2)
    segment_scene(small_scene(kind, sh_bands=1), path, options)
    index = _index(path)
    assert any(c.sh_of is not None for c in index.manifest.chunks)
    assert any(c.layer == 1 for c in index.manifest.chunks)
    assert gaussians_per_frame(index.manifest) == _most_held(index) > 0


def test_the_page_marks_an_assumed_length_and_a_per_frame_count() -> None:
    item = {
        "id": "a<b",
        "thumbnail": None,
        "duration_s": 2.5,
        "duration_assumed": True,
        "static": False,
        "gaussians": 10,
        "gaussians_per_frame": 4,
        "bytes": 2_000_000,
    }
    assert "2.50 s (assumed) &middot; 4 Gaussians per frame &middot; 2.0 MB" in _scene_item(item)
    item |= {"duration_assumed": False, "gaussians_per_frame": 10}
    shown = _scene_item(item)
    assert "2.50 s &middot; 10 Gaussians &middot;" in shown and "a&lt;b" in shown
    assert "still &middot; 10 Gaussians &middot;" in _scene_item(item | {"static": True})


# --- object storage ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def bucket(media: Path) -> Iterator[Callable[[str], str]]:
    """The media root copied to a bucket on a loopback S3 server (moto); yields the URL of a
    key in it."""
    with loopback_s3(BUCKET) as fs:
        for path in sorted(media.rglob("*")):
            if path.is_file():
                fs.pipe_file(f"{BUCKET}/media/{path.relative_to(media)}", path.read_bytes())
        yield lambda key: f"s3://{BUCKET}/media/{key}"


def test_a_bucket_prefix_lists_thumbnails_that_answer_as_png(
    media: Path, bucket: Callable[[str], str]
) -> None:
    server = ThreadedServer(make_app(bucket("")))
    try:
        _check_list_thumbnails(
            server.port, _thumbnails(media, ["fire", "loose", "monkey", "still"])
        )
        assert _listed(server.port)["monkey"]["gaussians_per_frame"] == 31658
    finally:
        server.stop()


def test_one_stored_container_lists_its_thumbnail(
    media: Path, bucket: Callable[[str], str]
) -> None:
    server = ThreadedServer(make_app(bucket("monkey.tsogs")))
    try:
        _check_list_thumbnails(server.port, _thumbnails(media, ["monkey"]))
        assert fetch(server.port, "/files/fire.tsogs.thumb.png").status == 404
    finally:
        server.stop()
