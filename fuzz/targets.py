"""Fuzz targets: one function per parser, all behind one verdict wrapper (:func:`outcome`).

A target takes arbitrary bytes and calls one of our parsers on them. :func:`outcome` says
``"decoded"`` or ``"rejected"`` (a :class:`TsogError` with a message); any other exception
escapes and is a crash. Shared by ``scripts/fuzz`` (atheris), ``tests/test_fuzz_parsers.py``
(hypothesis) and ``scripts/make_invalid_corpus.py``; :func:`valid_seeds` builds small valid
inputs to start mutating from.
"""

from __future__ import annotations

import asyncio
import dataclasses
import hashlib
import io
import itertools
import json
import struct
import tempfile
from collections.abc import Callable
from functools import cache
from pathlib import Path
from typing import Final

import numpy as np
import zstandard

from tsog_stream.client import StreamClient
from tsog_stream.codec.bundle import bundle_bytes, read_bundle
from tsog_stream.codec.chunk import decode_chunk, encode_chunk
from tsog_stream.constants import MAX_CAMERAS
from tsog_stream.container.header import HEADER_SIZE, PREFIX_SIZE, Header
from tsog_stream.container.index import decode_index, encode_index
from tsog_stream.container.sources import MemorySource, read_index
from tsog_stream.errors import TsogError
from tsog_stream.io.cameras import (
    parse_cameras_json,
    parse_colmap_cameras_bin,
    parse_colmap_cameras_text,
    parse_colmap_images_bin,
    parse_colmap_images_text,
)
from tsog_stream.io.ply import parse_ply, ply_bytes
from tsog_stream.io.splatv import MAGIC, RECORD, parse_splatv
from tsog_stream.model import Gaussians, TimelineType
from tsog_stream.render import render
from tsog_stream.render.camera import from_capture, stretched
from tsog_stream.schemas.cameras import Camera
from tsog_stream.schemas.manifest import check_layout, dump_manifest, parse_manifest
from tsog_stream.schemas.validate import parse_meta
from tsog_stream.server.conditional import evaluate, if_range_allows
from tsog_stream.server.ranges import Ignore, Serve, Unsatisfiable, parse_range
from tsog_stream.synthetic import SceneSpec, generate_scene, static_gaussians

Target = Callable[[bytes], object]
MAX_CHUNKS_READ: Final = 4
"""The container target decodes at most this many chunks per input (bounded work)."""
ETAG: Final = '"0123456789abcdef"'
MTIME: Final = 1_700_000_000.0


class LieError(AssertionError):
    """A parser answered, but its answer contradicts the input (e.g. a range past the end)."""


def outcome(target: Target, data: bytes) -> str:
    """Run ``target``: "decoded", or "rejected" for a TsogError with a message; else raise."""
    try:
        target(data)
    except TsogError as exc:
        if not str(exc).strip():
            raise LieError(f"{type(exc).__name__} without a message") from exc
        return "rejected"
    return "decoded"


def fuzz_ply(data: bytes) -> object:
    """PLY header and body (plain and PlayCanvas compressed)."""
    contents = parse_ply(data, name="fuzz.ply")
    if len(contents.gaussians) > len(data):
        raise LieError(f"{len(contents.gaussians)} Gaussians from {len(data)} bytes")
    return contents


def fuzz_splatv(data: bytes) -> object:
    """The .splatv reader (preamble, JSON chunk list, records)."""
    loaded = parse_splatv(data, name="fuzz.splatv")
    if len(loaded.scene) * RECORD.itemsize > len(data):
        raise LieError(f"{len(loaded.scene)} records from {len(data)} bytes")
    return loaded


def fuzz_meta(data: bytes) -> object:
    """A SOG/TSOG meta.json."""
    return parse_meta(data, where="fuzz/meta.json")


def fuzz_sog(data: bytes) -> object:
    """A bundled chunk: the zip, its meta.json and every image it lists, decoded."""
    return decode_chunk(read_bundle(data, where="fuzz.sog"), where="fuzz.sog")


def fuzz_chunk(data: bytes) -> object:
    """One member of a valid chunk replaced (first byte: which member), no zip CRC in the way."""
    files = dict(_sog_files())
    if data:
        names = sorted(files)
        files[names[data[0] % len(names)]] = data[1:]
    return decode_chunk(files, where="fuzz-chunk")


def fuzz_container(data: bytes) -> object:
    """A .tsogs container in memory: header, index, then a few chunks fetched and decoded."""

    async def run() -> None:
        source = MemorySource(data, "fuzz.tsogs")
        index = await read_index(source)
        client = StreamClient(source, index)
        for chunk in index.manifest.chunks[:MAX_CHUNKS_READ]:
            await client.chunk_scene(chunk.id)

    asyncio.run(run())
    return None


def fuzz_index_json(data: bytes) -> object:
    """Index JSON put into a valid container with a matching SHA-256, then opened and read."""
    return fuzz_container(container_with_index(_container_seed(), data))


def container_with_index(container: bytes, raw: bytes) -> bytes:
    """``container`` with its index replaced by ``raw`` (zstd, correct hash and lengths)."""
    header = Header.unpack(container)
    frame = zstandard.ZstdCompressor(level=3, write_content_size=True).compress(raw)
    payload = container[PREFIX_SIZE:] if header.index_offset < PREFIX_SIZE else b""
    if header.index_offset >= PREFIX_SIZE:
        payload = container[PREFIX_SIZE : header.index_offset]
    inside = HEADER_SIZE + len(frame) <= PREFIX_SIZE
    offset = HEADER_SIZE if inside else PREFIX_SIZE + len(payload)
    total = PREFIX_SIZE + len(payload) + (0 if inside else len(frame))
    new = dataclasses.replace(
        header,
        index_offset=offset,
        index_length=len(frame),
        index_raw_length=len(raw),
        file_length=total,
        index_sha256=hashlib.sha256(raw).digest(),
    )
    prefix = new.pack() + (frame if inside else b"")
    return prefix.ljust(PREFIX_SIZE, b"\0") + payload + (b"" if inside else frame)


def fuzz_index(data: bytes) -> object:
    """The zstd-compressed index: first 8 bytes the declared raw length, the rest the frame."""
    raw_length = int.from_bytes(data[:8], "little")
    return decode_index(data[8:], raw_length, bytes(32), where="fuzz.tsogs")


def fuzz_manifest(data: bytes) -> object:
    """Index JSON (manifest.json) and the chunk layout check."""
    manifest = parse_manifest(data, where="fuzz/manifest.json")
    check_layout(manifest, 16384, 1 << 40, where="fuzz/manifest.json")
    return manifest


def fuzz_cameras_json(data: bytes) -> object:
    """A 3DGS cameras.json (the .splatv header and --cameras read the same entries)."""
    cameras = parse_cameras_json(data, where="fuzz/cameras.json")
    if len(cameras) > MAX_CAMERAS:
        raise LieError(f"{len(cameras)} cameras, over the limit")
    return cameras


def fuzz_colmap_bin(data: bytes) -> object:
    """A COLMAP binary model: 4 bytes giving the length of cameras.bin, then it, then
    images.bin; every pose read, its 2D points skipped."""
    split = 4 + int.from_bytes(data[:4], "little")
    where = "fuzz/sparse/0"
    intrinsics = parse_colmap_cameras_bin(io.BytesIO(data[4:split]), where=where)
    poses = list(parse_colmap_images_bin(io.BytesIO(data[split:]), where=where))
    return [pose.camera(intrinsics, where=where) for pose in poses]


def fuzz_colmap_text(data: bytes) -> object:
    """A COLMAP text model: cameras.txt, a NUL, images.txt."""
    cams, _, imgs = data.partition(b"\0")
    where = "fuzz/sparse/0"
    intrinsics = parse_colmap_cameras_text(cams.decode("utf-8", "replace"), where=where)
    poses = list(parse_colmap_images_text(io.BytesIO(imgs), where=where))
    return [pose.camera(intrinsics, where=where) for pose in poses]


def fuzz_splatv_cameras(data: bytes) -> object:
    """The cameras a .splatv header carries (its records read too: they are few)."""
    return parse_splatv(data, name="fuzz.splatv").cameras


CAMERA_READERS: Final = (fuzz_cameras_json, fuzz_colmap_bin, fuzz_colmap_text, fuzz_splatv_cameras)
"""What the first byte of a ``cameras_render`` input picks (modulo their count)."""
RENDER_BUDGET: Final = 32 * 32
"""Pixels the ``cameras_render`` target draws a camera with (whatever size it declares)."""
MAX_CAMERAS_DRAWN: Final = 4
RENDER_WIDTH: Final = 16
"""A width given alone: the height follows the camera's shape, held to 1:8."""


def fuzz_cameras_render(data: bytes) -> object:
    """Camera files reaching the renderer: the first byte picks the reader (cameras.json,
    COLMAP binary, COLMAP text, .splatv header); each camera parsed then draws a tiny scene at
    its own size held to a small pixel budget, stretched 3DGS-style, and 16 pixels wide."""
    if not data:
        return None
    read = CAMERA_READERS[data[0] % len(CAMERA_READERS)]
    cameras: list[Camera] = read(data[1:])  # type: ignore[assignment]
    for camera in cameras[:MAX_CAMERAS_DRAWN]:
        drawn = (
            (from_capture(camera, None, budget=RENDER_BUDGET), RENDER_BUDGET),
            (stretched(camera, None, None, budget=RENDER_BUDGET), RENDER_BUDGET),
            (from_capture(camera, RENDER_WIDTH), RENDER_WIDTH * RENDER_WIDTH * 8),
        )
        for view, most in drawn:
            if view.width * view.height > most:
                raise LieError(f"{view.width}x{view.height} drawn for a {most}-pixel budget")
            image = render(_render_scene(), view, backend="numpy")
            if image.shape != (view.height, view.width, 3):
                raise LieError(f"a {image.shape} image for a {view.width}x{view.height} camera")
    return cameras


@cache
def _render_scene() -> Gaussians:
    """A few dozen Gaussians in front of the seeds' cameras (at z = 2, looking along +z)."""
    scene = static_gaussians(48, sh_bands=1, seed=3)
    means = scene.means - scene.means.mean(axis=0) + np.array([0.5, -1.0, 6.0], np.float32)
    return dataclasses.replace(scene, means=means.astype(np.float32))


def fuzz_range(data: bytes) -> object:
    """A Range header (first 8 bytes: the representation length); must never raise at all."""
    length = int.from_bytes(data[:8], "little") >> (data[0] % 64 if data else 0)
    value = data[8:].decode("latin-1")
    verdict = parse_range(value, length)
    if isinstance(verdict, Serve):
        ends = [(r.start, r.end) for r in verdict.ranges]
        if not ends or any(s >= e or e > length for s, e in ends):
            raise LieError(f"served {ends} of a {length}-byte file")
        if any(a[1] >= b[0] for a, b in itertools.pairwise(ends)):
            raise LieError(f"served ranges overlap or touch: {ends}")
    elif not isinstance(verdict, Ignore | Unsatisfiable):
        raise LieError(f"unexpected verdict {verdict!r}")
    return verdict


def fuzz_conditional(data: bytes) -> object:
    """If-Range / If-Match / If-None-Match / date preconditions; must never raise at all."""
    fields = data.decode("latin-1").split("\n")
    names = ("If-Match", "If-None-Match", "If-Modified-Since", "If-Unmodified-Since")
    headers = {n: v for n, v in zip(names, fields[1:], strict=False)}
    allowed = if_range_allows(fields[0], ETAG, MTIME)
    return allowed, evaluate("GET", headers, ETAG, MTIME), evaluate("PUT", headers, ETAG, MTIME)


TARGETS: Final[dict[str, Target]] = {
    "ply": fuzz_ply,
    "splatv": fuzz_splatv,
    "meta": fuzz_meta,
    "sog": fuzz_sog,
    "container": fuzz_container,
    "index": fuzz_index,
    "index_json": fuzz_index_json,
    "chunk": fuzz_chunk,
    "manifest": fuzz_manifest,
    "range": fuzz_range,
    "conditional": fuzz_conditional,
    "cameras_json": fuzz_cameras_json,
    "colmap_bin": fuzz_colmap_bin,
    "colmap_text": fuzz_colmap_text,
    "cameras_render": fuzz_cameras_render,
}
EXTENSIONS: Final[dict[str, str]] = {
    ".ply": "ply",
    ".splatv": "splatv",
    ".json": "meta",
    ".sog": "sog",
    ".tsogs": "container",
    ".zst": "index",
    ".index": "index_json",
    ".member": "chunk",
    ".manifest": "manifest",
    ".range": "range",
    ".cond": "conditional",
    ".cameras": "cameras_json",
    ".colmapbin": "colmap_bin",
    ".colmaptxt": "colmap_text",
    ".camrender": "cameras_render",
}
"""Which target reads a corpus file, by its extension."""


def target_for(path: Path) -> str:
    """The target name for a corpus file (by extension)."""
    return EXTENSIONS[path.suffix]


# --- valid seeds ------------------------------------------------------------------------


def _tiny_scene_spec() -> SceneSpec:
    """A type-2 scene of a few dozen Gaussians with SH and moving means (every image kind)."""
    return SceneSpec(
        timeline_type=TimelineType.CENTER_SCALE,
        background=24,
        objects=2,
        per_object=12,
        duration=1.0,
        fps=5.0,
        sh_bands=1,
        dynamic=("means",),
        seed=5,
    )


def _splatv_seed(n: int = 6) -> bytes:
    """A small valid .splatv: n moving Gaussians."""
    records = np.zeros(n, RECORD)
    rng = np.random.default_rng(1)
    records["position"] = rng.normal(size=(n, 3))
    records["rotation"] = (1, 0, 0, 0)
    records["scale"] = 0.1
    records["rgba"] = rng.integers(1, 255, (n, 4))
    records["motion"] = rng.normal(0, 0.1, (n, 9))
    records["trbf_center"] = 0.5
    records["trbf_scale"] = 0.3
    header = json.dumps([{"type": "splat", "size": n * RECORD.itemsize}]).encode()
    return struct.pack("<II", MAGIC, len(header)) + header + records.tobytes()


@cache
def _container_seed() -> bytes:
    """A small valid container (a few chunks, index in the prefix)."""
    from tsog_stream.segment.segmenter import SegmentOptions, segment_scene  # noqa: PLC0415

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "seed.tsogs"
        options = SegmentOptions(window_s=0.5, policy="duplicate", max_pixels=16 * 16)
        segment_scene(generate_scene(_tiny_scene_spec()), path, options)
        return path.read_bytes()


@cache
def _sog_files() -> dict[str, bytes]:
    """Files of one small TSOG chunk."""
    return encode_chunk(generate_scene(_tiny_scene_spec()))


def _index_seed(container: bytes) -> bytes:
    """The index frame of ``container`` prefixed with its declared raw length."""
    manifest = asyncio.run(read_index(MemorySource(container))).manifest
    frame, _sha, raw_length = encode_index(manifest)
    return raw_length.to_bytes(8, "little") + frame


@cache
def valid_seeds(target: str) -> dict[str, bytes]:
    """Small valid inputs for ``target`` (file name -> bytes), deterministic."""
    if target == "ply":
        return {"static.ply": ply_bytes(static_gaussians(8, sh_bands=1))}
    if target == "splatv":
        return {"moving.splatv": _splatv_seed()}
    if target == "meta":
        return {"meta.json": _sog_files()["meta.json"]}
    if target == "sog":
        return {"chunk.sog": bundle_bytes(_sog_files())}
    if target == "container":
        return {"small.tsogs": _container_seed()}
    if target == "index":
        return {"index.zst": _index_seed(_container_seed())}
    if target == "manifest":
        manifest = asyncio.run(read_index(MemorySource(_container_seed()))).manifest
        return {"index.manifest": dump_manifest(manifest)}
    if target == "index_json":
        manifest = asyncio.run(read_index(MemorySource(_container_seed()))).manifest
        return {"small.index": dump_manifest(manifest)}
    if target == "chunk":
        names = sorted(_sog_files())
        return {f"{n}.member": bytes([i]) + _sog_files()[n] for i, n in enumerate(names)}
    if target == "range":
        prefix = (1000).to_bytes(8, "little")
        return {f"r{i}.range": prefix + v for i, v in enumerate(RANGE_SEEDS)}
    if target == "conditional":
        return {f"c{i}.cond": v for i, v in enumerate(CONDITIONAL_SEEDS)}
    if target == "cameras_json":
        return {"cameras.cameras": json.dumps(CAMERA_ENTRIES).encode()}
    if target == "colmap_bin":
        return {"model.colmapbin": _colmap_bin_seed()}
    if target == "colmap_text":
        return {"model.colmaptxt": COLMAP_TEXT_SEED}
    if target == "cameras_render":
        return _cameras_render_seeds()
    raise KeyError(target)


CAMERA_ENTRIES: Final = [
    {
        "id": 0,
        "img_name": "00001",
        "width": 64,
        "height": 48,
        "position": [0.5, -1.0, 2.0],
        "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
        "fx": 60.0,
        "fy": 61.0,
    }
]
COLMAP_TEXT_SEED: Final = (
    b"# cameras\n1 PINHOLE 64 48 60 61 32 24\n2 SIMPLE_RADIAL 64 48 60 32 24 0.01\n\0"
    b"# images\n1 1 0 0 0 0.5 -1 2 1 a.png\n3.5 4.5 -1 10 12 7\n"
    b"2 0.7071 0 0.7071 0 1 0 0 2 b.png\n\n"
)


def _colmap_bin_seed() -> bytes:
    """Two cameras (PINHOLE, OPENCV) and two images with a few 2D points each."""
    cams = struct.pack("<Q", 2)
    cams += struct.pack("<iiQQ4d", 1, 1, 64, 48, 60.0, 61.0, 32.0, 24.0)
    cams += struct.pack("<iiQQ8d", 2, 4, 64, 48, 60.0, 61.0, 32.0, 24.0, 0.1, 0, 0, 0)
    imgs = struct.pack("<Q", 2)
    for image_id, q, cam, name in (
        (1, (1, 0, 0, 0), 1, b"a.png"),
        (2, (0.5, 0.5, 0.5, 0.5), 2, b"b"),
    ):
        imgs += struct.pack("<i7di", image_id, *q, 0.5, -1.0, 2.0, cam) + name + b"\0"
        imgs += struct.pack("<Q", 2) + struct.pack("<ddq", 1.0, 2.0, -1) * 2
    return len(cams).to_bytes(4, "little") + cams + imgs


HOSTILE_CAMERA_SHAPES: Final[dict[str, dict[str, object]]] = {
    "tall-200x65536": {"width": 200, "height": 65536},
    "line-1x65536": {"width": 1, "height": 65536},
    "wide-65536x1": {"width": 65536, "height": 1},
    "huge-65536x65536": {"width": 65536, "height": 65536},
    "dot-1x1": {"width": 1, "height": 1},
    "focal-1e-30": {"fx": 1e-30, "fy": 1e-30},
    "focal-1e30": {"fx": 1e30, "fy": 1e30},
    "focal-mixed": {"fx": 1e-30, "fy": 1e30},
    "principal-point-1e300": {"cx": 1e300, "cy": -1e300},
}
"""Camera shapes a file may declare that the renderer must bound (valid per the schema)."""


def hostile_camera_entry(name: str) -> dict[str, object]:
    """:data:`CAMERA_ENTRIES`' camera with the shape ``name`` of HOSTILE_CAMERA_SHAPES."""
    return {**CAMERA_ENTRIES[0], **HOSTILE_CAMERA_SHAPES[name]}


def _splatv_with_cameras(entries: list[dict[str, object]]) -> bytes:
    """:func:`_splatv_seed`'s records under a header carrying ``entries`` as its cameras."""
    seed = _splatv_seed()
    length = struct.unpack_from("<I", seed, 4)[0]
    chunks = json.loads(seed[8 : 8 + length])
    chunks[0]["cameras"] = entries
    header = json.dumps(chunks).encode()
    return struct.pack("<II", MAGIC, len(header)) + header + seed[8 + length :]


def _cameras_render_seeds() -> dict[str, bytes]:
    """Each reader's valid seed behind its selector byte, and the hostile shapes as a
    cameras.json and as a .splatv header."""
    seeds = {
        "json.camrender": b"\0" + json.dumps(CAMERA_ENTRIES).encode(),
        "colmapbin.camrender": b"\1" + _colmap_bin_seed(),
        "colmaptxt.camrender": b"\2" + COLMAP_TEXT_SEED,
        "splatv.camrender": b"\3" + _splatv_with_cameras(CAMERA_ENTRIES),
    }
    for name in HOSTILE_CAMERA_SHAPES:
        entry = hostile_camera_entry(name)
        seeds[f"json-{name}.camrender"] = b"\0" + json.dumps([entry]).encode()
        seeds[f"splatv-{name}.camrender"] = b"\3" + _splatv_with_cameras([entry])
    return seeds


RANGE_SEEDS: Final = (
    b"bytes=0-99",
    b"bytes=-500,0-0,100-",
    b"bytes=5-1,7-9",
    b"Bytes = 1-2 , 4-5",
)
CONDITIONAL_SEEDS: Final = (
    b'"0123456789abcdef"\n"x", W/"0123456789abcdef"\n*',
    b"Tue, 14 Nov 2023 22:13:20 GMT\n*\n\nSun, 06 Nov 1994 08:49:37 GMT\n",
    b'W/"a"\n\n"0123456789abcdef"\nSunday, 06-Nov-94 08:49:37 GMT\nSun Nov  6 08:49:37 1994',
    b"Mon, 01 Jan 99999999999999999999 00:00:00 GMT\n\n\nMon, 01 Jan 0001 00:00:00 +0100",
)


def digest(data: bytes) -> str:
    """Short hex name of an input (for crash files)."""
    return hashlib.sha256(data).hexdigest()[:16]
