"""Write tests/data/invalid/: small hand-made bad files, each named for what is wrong.

Deterministic: the same code writes the same bytes. ``--check`` verifies that the committed
files (and ``expected.tsv``, which gives each file's error class and defect) are up to date.
The reader of a file follows from its extension (``fuzz/targets.py`` EXTENSIONS).
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import struct
import sys
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import zstandard

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tsog_stream.codec.bundle import bundle_bytes  # noqa: E402
from tsog_stream.codec.webp import encode_webp  # noqa: E402
from tsog_stream.container.header import (  # noqa: E402
    HEADER_SIZE,
    INDEX_ZSTD,
    PREFIX_SIZE,
    VERSION_MAJOR,
    Header,
)
from tsog_stream.io.splatv import MAGIC as SPLATV_MAGIC  # noqa: E402
from tsog_stream.io.splatv import RECORD  # noqa: E402

OUT = ROOT / "tests" / "data" / "invalid"
EXPECTED = "expected.tsv"
Case = tuple[str, str, bytes]
"""(error class name, what is wrong, bytes)."""

# --- PLY ----------------------------------------------------------------------------------

PLY_PROPS: tuple[str, ...] = ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity")
PLY_PROPS += ("scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")


def ply(count: int | str, body: bytes = b"", fmt: str = "binary_little_endian", **kw: str) -> bytes:
    """A 3DGS-style PLY header (overridable lines) and ``body``."""
    props = kw.get("props", "".join(f"property float {p}\n" for p in PLY_PROPS))
    end = kw.get("end", "end_header\n")
    head = f"ply\nformat {fmt} 1.0\nelement vertex {count}\n{props}{end}"
    return head.encode("latin-1") + body


def compressed_ply(chunks: int, body: bytes, fmt: str = "binary_little_endian") -> bytes:
    """A PlayCanvas compressed PLY header of ``chunks`` chunk rows and one vertex, then ``body``."""
    return (
        f"ply\nformat {fmt} 1.0\nelement chunk {chunks}\n"
        + "".join(f"property float {e}_{a}\n" for e in ("min", "max") for a in ("x", "y", "z"))
        + "".join(f"property float {e}_scale_{a}\n" for e in ("min", "max") for a in "xyz")
        + "element vertex 1\n"
        + "".join(f"property uint packed_{p}\n" for p in ("position", "rotation", "scale", "color"))
        + "end_header\n"
    ).encode() + body


def gaussian_rows(count: int, dtype: str) -> bytes:
    """``count`` rows of PLY_PROPS with values a trainer writes (seeded), as ``dtype``."""
    rng = np.random.default_rng(55)
    columns = [
        rng.normal(0.0, 2.0, (count, 3)),  # x y z
        rng.normal(0.0, 1.0, (count, 3)),  # f_dc
        rng.normal(0.0, 3.0, (count, 1)),  # opacity
        rng.normal(-5.0, 1.5, (count, 3)),  # log scales
        rng.normal(0.0, 0.6, (count, 4)),  # rotation
    ]
    return np.concatenate(columns, axis=1).astype(dtype).tobytes()


def ply_cases() -> dict[str, Case]:
    """Broken PLY files."""
    row = np.arange(len(PLY_PROPS), dtype="<f4").tobytes()
    compressed = compressed_ply(0, bytes(16))
    bounds = np.array([[-1.37, -1.52, -0.93, 1.41, 1.18, 1.66, -7.3, -6.9, -7.1, -3.2, -2.8, -3.3]])
    return {
        "ply-big-endian-header-little-data.ply": (
            "PlyError",
            "binary_big_endian header over little-endian rows (was numpy warnings, then an "
            "output check blamed on the output)",
            ply(24, gaussian_rows(24, "<f4"), fmt="binary_big_endian"),
        ),
        "ply-little-endian-header-big-data.ply": (
            "PlyError",
            "binary_little_endian header over big-endian rows",
            ply(24, gaussian_rows(24, ">f4")),
        ),
        "ply-compressed-big-endian-header.ply": (
            "PlyError",
            "compressed PLY whose big-endian header is over little-endian chunk bounds",
            compressed_ply(1, bounds.astype("<f4").tobytes() + bytes(16), fmt="binary_big_endian"),
        ),
        "ply-count-exceeds-body.ply": (
            "PlyError",
            "declares 10^9 vertices, holds 2 rows",
            ply(10**9, row * 2),
        ),
        "ply-header-no-end.ply": ("PlyError", "no end_header line", ply(1, row, end="")),
        "ply-bad-magic.ply": ("PlyError", "first line is not 'ply'", b"plx\n" + ply(1, row)[4:]),
        "ply-ascii-not-a-number.ply": (
            "PlyError",
            "ASCII body holds a word",
            ply(1, b"0 1 2 3 4 5 6 7 8 9 ten 11 12 13\n", fmt="ascii"),
        ),
        "ply-ascii-count-exceeds-body.ply": (
            "PlyError",
            "ASCII body with 10^12 declared rows",
            ply(10**12, b"1 2 3\n", fmt="ascii"),
        ),
        "ply-missing-rotation.ply": (
            "PlyError",
            "no rot_* properties",
            ply(1, bytes(40), props="".join(f"property float {p}\n" for p in PLY_PROPS[:10])),
        ),
        "ply-unknown-type.ply": (
            "PlyError",
            "property of type float128",
            ply(1, row, props="property float128 x\n"),
        ),
        "ply-count-not-a-number.ply": ("PlyError", "element count is -1", ply("-1", row)),
        "ply-count-5000-digits.ply": (
            "PlyError",
            "a 5000-digit element count (was a ValueError from int())",
            ply("9" * 5000, row),
        ),
        "ply-version-2.ply": (
            "UnsupportedError",
            "format version 2.0",
            ply(1, row).replace(b" 1.0", b" 2.0", 1),
        ),
        "ply-non-ascii-header.ply": (
            "PlyError",
            "a Latin-1 byte in a comment",
            ply(1, row).replace(b"element", "comment caf\xe9\nelement".encode("latin-1"), 1),
        ),
        "ply-compressed-too-few-chunks.ply": (
            "PlyError",
            "compressed PLY with 1 vertex and 0 chunk rows",
            compressed,
        ),
    }


# --- splatv -------------------------------------------------------------------------------


def splatv(header: object | bytes, body: bytes = b"", length: int | None = None) -> bytes:
    """Magic, JSON length (default: the real one), JSON, body."""
    text = header if isinstance(header, bytes) else json.dumps(header).encode()
    size = len(text) if length is None else length
    return struct.pack("<II", SPLATV_MAGIC, size) + text + body


def splatv_cases() -> dict[str, Case]:
    """Broken .splatv files."""
    one = np.zeros(1, RECORD).tobytes()
    splat = [{"type": "splat", "size": 64}]
    return {
        "splatv-negative-length.splatv": (
            "FormatError",
            "JSON length 0xFFFFFFFF (-1 as int32)",
            splatv(splat, one, length=0xFFFFFFFF),
        ),
        "splatv-bad-magic.splatv": (
            "FormatError",
            "magic 0x674C",
            b"\x4c\x67" + splatv(splat, one)[2:],
        ),
        "splatv-json-too-deep.splatv": (
            "FormatError",
            "JSON nested 5000 deep (was a RecursionError)",
            splatv(b"[" * 5000 + b"]" * 5000),
        ),
        "splatv-size-negative.splatv": (
            "FormatError",
            "splat chunk of size -64",
            splatv([{"type": "splat", "size": -64}], one),
        ),
        "splatv-size-not-multiple.splatv": (
            "FormatError",
            "splat chunk of 65 bytes",
            splatv([{"type": "splat", "size": 65}], one + b"\0"),
        ),
        "splatv-no-splat-chunk.splatv": (
            "FormatError",
            "no chunk of type splat",
            splatv([{"type": "other", "size": 64}], one),
        ),
        "splatv-truncated-record.splatv": (
            "FormatError",
            "file ends inside a record",
            splatv([{"type": "splat", "size": 128}], one + bytes(10)),
        ),
        "splatv-chunk-before-splat-past-eof.splatv": (
            "FormatError",
            "a chunk before the splat chunk ends past the file",
            splatv([{"type": "x", "size": 10**12}, *splat], one),
        ),
        "splatv-not-json.splatv": ("FormatError", "header is not JSON", splatv(b"{splat}", one)),
    }


# --- meta.json and .sog chunks -----------------------------------------------------------


def meta(count: int = 16, **changes: object) -> dict[str, object]:
    """A compact valid SOG v2 meta.json document for ``count`` Gaussians (then ``changes``)."""
    codebook = [float(i) / 16 - 8 for i in range(256)]
    doc: dict[str, object] = {
        "version": 2,
        "count": count,
        "means": {"mins": [-1.0] * 3, "maxs": [1.0] * 3, "files": ["means_l.webp", "means_u.webp"]},
        "scales": {"codebook": codebook, "files": ["scales.webp"]},
        "quats": {"files": ["quats.webp"]},
        "sh0": {"codebook": codebook, "files": ["sh0.webp"]},
    }
    doc.update(changes)
    return {k: v for k, v in doc.items() if v is not None}


def meta_bytes(doc: object) -> bytes:
    """Compact JSON."""
    return json.dumps(doc, separators=(",", ":")).encode()


def meta_cases() -> dict[str, Case]:
    """Broken meta.json files."""
    timeline = {"type": "2", "mins": [0, 0], "maxs": [1, 1], "files": ["a.webp", "b.webp"]}
    return {
        "meta-timeline-bad-type.json": (
            "MetaError",
            "timeline.type is a string",
            meta_bytes(meta(timeline=timeline)),
        ),
        "meta-missing-means.json": ("MetaError", "no means key", meta_bytes(meta(means=None))),
        "meta-count-negative.json": ("MetaError", "count -1", meta_bytes(meta(count=-1))),
        "meta-count-too-large.json": (
            "MetaError",
            "count over 16383^2",
            meta_bytes(meta(count=16383 * 16383 + 1)),
        ),
        "meta-not-utf8.json": ("MetaError", "a 0xff byte", b'{"version":2,"count":\xff}'),
        "meta-not-json.json": ("MetaError", "truncated JSON", meta_bytes(meta())[:-7]),
        "meta-nested-too-deep.json": ("MetaError", "nested 5000 deep", b"[" * 5000),
        "meta-version-1.json": (
            "MetaError",
            "no version key (SOG v1)",
            meta_bytes(meta(version=None)),
        ),
        "meta-nan-min.json": (
            "MetaError",
            "NaN in means.mins",
            meta_bytes(meta()).replace(b"[-1.0,-1.0,-1.0]", b"[NaN,-1.0,-1.0]", 1),
        ),
        "meta-huge-integer.json": (
            "MetaError",
            "a 5000-digit count",
            b'{"version":2,"count":' + b"9" * 5000 + b"}",
        ),
    }


def webp_header(kind: bytes, width: int, height: int, flags: int = 0) -> bytes:
    """A WebP whose first chunk declares ``width`` x ``height`` and holds nothing else."""
    if kind == b"VP8X":
        size = (width - 1).to_bytes(3, "little") + (height - 1).to_bytes(3, "little")
        payload = bytes([flags, 0, 0, 0]) + size
    elif kind == b"VP8 ":  # a key frame's tag, start code, 14-bit sides
        size = width.to_bytes(2, "little") + height.to_bytes(2, "little")
        payload = b"\x10\x02\x00\x9d\x01\x2a" + size
    else:  # VP8L
        bits = (width - 1) | (height - 1) << 14
        payload = b"\x2f" + bits.to_bytes(4, "little") + bytes(5)
    return riff(kind + len(payload).to_bytes(4, "little") + payload)


def riff(chunks: bytes, size: int | None = None) -> bytes:
    """A WebP file of ``chunks``, its RIFF size field ``size`` (default: the true one)."""
    size = 4 + len(chunks) if size is None else size
    return b"RIFF" + size.to_bytes(4, "little") + b"WEBP" + chunks


def canvas_around(image: bytes, width: int, height: int, flags: int = 0) -> bytes:
    """``image`` (a whole WebP file) behind a VP8X chunk declaring a ``width`` x ``height``
    canvas (with ``flags``)."""
    vp8x = webp_header(b"VP8X", width, height, flags)[12:]
    return riff(vp8x + image[12:])


def sog_files(count: int = 16) -> dict[str, bytes]:
    """A valid chunk of ``count`` Gaussians (4x4 images) as files."""
    image = encode_webp(np.full((4, 4, 4), 128, np.uint8))
    names = ("means_l.webp", "means_u.webp", "scales.webp", "quats.webp", "sh0.webp")
    return {**dict.fromkeys(names, image), "meta.json": meta_bytes(meta(count))}


def zip_with(entries: list[tuple[str, bytes]], method: int = zipfile.ZIP_STORED) -> bytes:
    """A deterministic zip of ``entries``."""
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", method) as archive:
        for name, data in entries:
            archive.writestr(zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0)), data)
    return out.getvalue()


def deflated_zip(entries: list[tuple[str, bytes]]) -> bytes:
    """A deterministic zip of ``entries``, every one deflated."""
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as archive:
        for name, data in entries:
            info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            archive.writestr(info, data)
    return out.getvalue()


def bomb_cases() -> dict[str, Case]:
    """.sog chunks whose members inflate past what their meta.json allows, and WebP images
    whose headers declare more (or otherwise) than they hold."""
    files = sog_files()
    image = files["quats.webp"]
    big = meta_bytes(meta(60000))
    with_member = {**files, "means_l.webp": image + bytes(8 << 20)}
    ratio = {**files, "meta.json": big, "means_l.webp": image + bytes(1 << 20)}
    padded_meta = {**files, "meta.json": files["meta.json"] + b" " * (8 << 20)}
    other_size = encode_webp(np.full((8, 8, 4), 128, np.uint8))

    def one(name: str, data: bytes) -> bytes:
        return bundle_bytes({**files, name: data})

    return {
        "sog-member-inflates-8mib.sog": (
            "SogError",
            "means_l.webp inflates to 8 MiB for 16 Gaussians",
            deflated_zip(sorted(with_member.items())),
        ),
        "sog-meta-inflates-8mib.sog": (
            "SogError",
            "meta.json inflates to 8 MiB (padded with spaces)",
            deflated_zip(sorted(padded_meta.items())),
        ),
        "sog-member-deflate-ratio-1000.sog": (
            "SogError",
            "means_l.webp inflates 1 MiB from 1 KiB, within 60000 Gaussians' budget",
            deflated_zip(sorted(ratio.items())),
        ),
        "sog-webp-vp8x-canvas-4096-image-4.sog": (
            "SogError",
            "VP8X canvas of 4096x4096 around a 4x4 image",
            one("means_l.webp", canvas_around(image, 4096, 4096)),
        ),
        "sog-webp-vp8x-no-image.sog": (
            "SogError",
            "VP8X canvas of 16383x16383 and no image (was a Pillow traceback in tsog info)",
            one("means_l.webp", webp_header(b"VP8X", 16383, 16383)),
        ),
        "sog-webp-vp8x-animated.sog": (
            "SogError",
            "VP8X with the animation flag",
            one("means_l.webp", canvas_around(image, 4, 4, flags=0x02)),
        ),
        "sog-webp-vp8-16383px.sog": (
            "MetaError",
            "lossy VP8 header declaring 16383x16383 for 16 Gaussians",
            one("means_l.webp", webp_header(b"VP8 ", 16383, 16383)),
        ),
        "sog-webp-riff-size-1gib.sog": (
            "SogError",
            "RIFF size says 1 GiB",
            one("sh0.webp", riff(image[12:], size=1 << 30)),
        ),
        "sog-webp-riff-size-short.sog": (
            "SogError",
            "RIFF size ends 16 bytes before the image does",
            one("sh0.webp", riff(image[12:] + bytes(16), size=len(image) - 8)),
        ),
        "sog-webp-chunk-past-end.sog": (
            "SogError",
            "VP8L chunk size past the end of the file",
            one("sh0.webp", riff(image[12:16] + (1 << 20).to_bytes(4, "little") + image[20:])),
        ),
        "sog-webp-sizes-differ.sog": (
            "MetaError",
            "quats.webp is 8x8, the other images 4x4",
            one("quats.webp", other_size),
        ),
    }


def sog_cases() -> dict[str, Case]:
    """Broken .sog chunks."""
    files = sog_files()
    big = {**files, "means_l.webp": webp_header(b"VP8X", 60000, 60000)}
    padded = {name: webp_header(b"VP8L", 16383, 16383) for name in files if name != "meta.json"}
    no_means = {**files, "meta.json": meta_bytes(meta(means=None))}
    deflated = zip_with([("meta.json", b"{}" * 200)], zipfile.ZIP_DEFLATED)
    body = deflated.index(b"meta.json") + len("meta.json")
    broken = (
        deflated[:body] + bytes(b ^ 0x5A for b in deflated[body : body + 6]) + deflated[body + 6 :]
    )
    liar = bytearray(zip_with(sorted(files.items())))
    central = liar.rfind(b"PK\x01\x02")  # last entry's central record: uncompressed size field
    liar[central + 24 : central + 28] = (2**32 - 2).to_bytes(4, "little")
    truncated = {**files, "sh0.webp": files["sh0.webp"][:-9]}
    return {
        "sog-meta-missing-means.sog": (
            "MetaError",
            "meta.json has no means",
            bundle_bytes(no_means),
        ),
        "sog-image-60000px.sog": (
            "SogError",
            "means_l.webp declares a 60000x60000 canvas",
            bundle_bytes(big),
        ),
        "sog-images-16383px-for-16.sog": (
            "MetaError",
            "16383x16383 images for 16 Gaussians",
            bundle_bytes({**padded, "meta.json": files["meta.json"]}),
        ),
        "sog-webp-truncated.sog": ("SogError", "sh0.webp cut short", bundle_bytes(truncated)),
        "sog-image-missing.sog": (
            "SogError",
            "quats.webp listed but absent",
            bundle_bytes({k: v for k, v in files.items() if k != "quats.webp"}),
        ),
        "zip-member-size-lies.sog": ("SogError", "member claims 4 GiB uncompressed", bytes(liar)),
        "zip-corrupt-deflate.sog": (
            "SogError",
            "damaged deflate stream (was a zlib.error)",
            broken,
        ),
        "zip-no-meta.sog": ("SogError", "no meta.json", zip_with([("a.webp", b"RIFF")])),
        "zip-truncated.sog": ("SogError", "archive cut in half", bundle_bytes(files)[:300]),
    }


# --- containers ---------------------------------------------------------------------------


def container(
    raw: bytes, frame: bytes | None = None, size: int | None = None, **changes: int | bytes
) -> bytes:
    """A container of ``size`` bytes (default: header and index only) whose index is ``raw``
    (zstd unless ``frame`` is given), with header fields changed."""
    frame = zstandard.ZstdCompressor(level=3).compress(raw) if frame is None else frame
    size = HEADER_SIZE + len(frame) if size is None else size
    fields: dict[str, int | bytes] = {
        "version_major": VERSION_MAJOR,
        "version_minor": 0,
        "required_flags": 0,
        "optional_flags": 0,
        "index_codec": INDEX_ZSTD,
        "index_offset": HEADER_SIZE,
        "index_length": len(frame),
        "index_raw_length": len(raw),
        "file_length": size,
        "index_sha256": hashlib.sha256(raw).digest(),
    }
    fields.update(changes)
    head = Header(**fields).pack()  # type: ignore[arg-type]
    return (head + frame).ljust(size, b"\0")


def manifest(chunks: list[dict[str, object]] | None = None) -> bytes:
    """Index JSON of an empty scene (or with ``chunks``)."""
    box = {"min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 1.0]}
    doc = {
        "format": "tsogs",
        "version": 1,
        "generator": "corpus",
        "policy": "duplicate",
        "window_s": 1.0,
        "max_pixels": 256,
        "scene": {
            "gaussians": 0,
            "stored": 0,
            "start_s": 0.0,
            "end_s": 1.0,
            "fps": None,
            "timeline_type": None,
            "temporal": {},
            "sh_bands": 0,
            "bbox": box,
        },
        "nodes": [],
        "chunks": chunks or [],
        "payload_bytes": 0,
    }
    return json.dumps(doc, separators=(",", ":")).encode()


def chunk_entry(i: int, offset: int, length: int) -> dict[str, object]:
    """One chunk entry of the index."""
    box = {"min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 1.0]}
    return {
        "id": i,
        "file": f"chunks/{i:06d}.sog",
        "offset": offset,
        "length": length,
        "sha256": "0" * 64,
        "count": 1,
        "level": 0,
        "node": 0,
        "start_s": 0.0,
        "end_s": 1.0,
        "bbox": box,
    }


def container_cases() -> dict[str, Case]:
    """Broken .tsogs containers (and index frames)."""
    raw = manifest()
    bomb = zstandard.ZstdCompressor(level=3).compress(b"\0" * 4096)
    four_gib = 4 * 1024**3
    # Same blocks behind a frame header declaring 4 GiB: descriptor 0xE0 = single segment,
    # 8-byte content size.
    start = zstandard.frame_header_size(bomb)
    declared = bomb[:4] + b"\xe0" + four_gib.to_bytes(8, "little") + bomb[start:]
    assert zstandard.frame_content_size(declared) == four_gib
    overlapping = manifest(
        [chunk_entry(0, PREFIX_SIZE, 100), chunk_entry(1, PREFIX_SIZE + 50, 100)]
    )
    return {
        "tsogs-bad-magic.tsogs": (
            "FormatError",
            "magic TSOGX",
            b"TSOGX" + container(raw)[5:HEADER_SIZE],
        ),
        "tsogs-truncated-header.tsogs": ("FormatError", "file of 100 bytes", container(raw)[:100]),
        "tsogs-index-length-past-eof.tsogs": (
            "FormatError",
            "index extends past the end of the file",
            container(raw, index_length=PREFIX_SIZE + 999),
        ),
        "tsogs-file-length-lies.tsogs": (
            "IntegrityError",
            "header says 1 TiB",
            container(raw, file_length=1 << 40),
        ),
        "tsogs-version-9.tsogs": (
            "UnsupportedError",
            "major version 9",
            container(raw, version_major=9),
        ),
        "tsogs-unknown-required-flag.tsogs": (
            "UnsupportedError",
            "required flag bit 0 set",
            container(raw, required_flags=1),
        ),
        "tsogs-index-hash-mismatch.tsogs": (
            "IntegrityError",
            "index SHA-256 of another text",
            container(raw, index_sha256=hashlib.sha256(b"other").digest()),
        ),
        "tsogs-index-frame-4gib.tsogs": (
            "FormatError",
            "zstd frame and header claim 4 GiB of index",
            container(raw, declared, index_raw_length=four_gib),
        ),
        "tsogs-index-not-zstd.tsogs": (
            "FormatError",
            "index bytes are not zstd",
            container(raw, raw),
        ),
        "tsogs-chunks-overlap.tsogs": (
            "IntegrityError",
            "two chunks share bytes",
            container(overlapping, size=PREFIX_SIZE + 150),
        ),
        "tsogs-index-bad-json.tsogs": ("MetaError", "index is not JSON", container(b"{not json")),
        "index-frame-declares-4gib.zst": (
            "FormatError",
            "frame declares 4 GiB (8-byte prefix: raw length)",
            four_gib.to_bytes(8, "little") + declared,
        ),
        "manifest-chunk-id-gap.manifest": (
            "MetaError",
            "chunks[0] has id 5",
            manifest([chunk_entry(5, PREFIX_SIZE, 10)]),
        ),
    }


def cameras_cases() -> dict[str, Case]:
    """Broken 3DGS cameras.json files."""
    return {
        "cameras-4097-empty-objects.cameras": (
            "FormatError",
            "4097 empty objects: refused at the 4097th, before the rest is parsed",
            b"[" + b"{}," * 4096 + b"{}]",
        ),
    }


MAKERS: tuple[Callable[[], dict[str, Case]], ...] = (
    ply_cases,
    splatv_cases,
    meta_cases,
    sog_cases,
    bomb_cases,
    container_cases,
    cameras_cases,
)


def corpus() -> dict[str, bytes]:
    """Every corpus file by name, ``expected.tsv`` included."""
    cases = {name: case for make in MAKERS for name, case in make().items()}
    files = {name: data for name, (_, _, data) in cases.items()}
    lines = ["file\terror\twhat is wrong"]
    lines += [f"{name}\t{error}\t{what}" for name, (error, what, _) in sorted(cases.items())]
    files[EXPECTED] = ("\n".join(lines) + "\n").encode()
    return files


def main(argv: list[str] | None = None) -> int:
    """Write the corpus, or with ``--check`` report files that are missing, stale or extra."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--check", action="store_true", help="verify, do not write")
    args = parser.parse_args(argv)
    files = corpus()
    present = {p.name for p in OUT.glob("*")} if OUT.is_dir() else set()
    stale = [n for n, d in files.items() if not (OUT / n).is_file() or (OUT / n).read_bytes() != d]
    extra = sorted(present - set(files))
    if args.check:
        for name in [*stale, *extra]:
            print(f"out of date: tests/data/invalid/{name}", file=sys.stderr)
        if stale or extra:
            print("run scripts/make_invalid_corpus.py", file=sys.stderr)
        return 1 if stale or extra else 0
    OUT.mkdir(parents=True, exist_ok=True)
    for name in extra:
        (OUT / name).unlink()
    for name, data in files.items():
        (OUT / name).write_bytes(data)
    total = sum(len(d) for d in files.values())
    print(f"wrote {len(files)} files ({total} bytes) to {OUT.relative_to(ROOT)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
