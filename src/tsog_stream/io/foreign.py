"""Gaussian-splat files this version does not read, named in the error with the way to one
it does: a user holding a ``.spz`` or a gsplat ``.npz`` learns what it is and what to run,
not that its magic bytes are unknown or that a zip lacks ``meta.json``."""

from __future__ import annotations

import zlib
from collections.abc import Collection
from pathlib import PurePosixPath

SPZ_MAGIC = b"NGSP"
"""Niantic SPZ's header magic (version 4 files start with it, earlier ones inside gzip)."""
GZIP_MAGIC = b"\x1f\x8b"
GLTF_MAGIC = b"glTF"
NPY_SUFFIX = ".npy"

CONVERTIBLE_BY_SUFFIX = {
    ".splat": "an antimatter15 .splat file",
    ".ksplat": "a GaussianSplats3D .ksplat file",
    ".lcc": "an XGRIDS .lcc file",
}
"""Formats without magic bytes, known by their name's suffix; splat-transform reads each."""


def _convert_hint(name: str) -> str:
    """How to turn the file ``name`` into a PLY this version reads."""
    path = PurePosixPath(name.replace("\\", "/"))
    command = f"npx @playcanvas/splat-transform {path.name} {path.stem}.ply"
    return f"convert it to PLY first (`{command}`)"


def _gunzipped_prefix(head: bytes, size: int) -> bytes:
    """At most ``size`` bytes of what a gzip stream starting ``head`` holds (never more
    inflated, whatever the stream claims); empty when it is not gzip."""
    try:
        return zlib.decompressobj(16 + zlib.MAX_WBITS).decompress(head, size)
    except zlib.error:
        return b""


def foreign_format(head: bytes, name: str) -> str | None:
    """Why a file whose first bytes are ``head`` is not read, naming its format and the way
    on; None when it is none of the formats known here."""
    spz = head.startswith(SPZ_MAGIC) or (
        head.startswith(GZIP_MAGIC) and _gunzipped_prefix(head, len(SPZ_MAGIC)) == SPZ_MAGIC
    )
    if spz:
        return f"a Niantic .spz file, not read by tsog: {_convert_hint(name)}"
    if head.startswith(GLTF_MAGIC):
        return "a glTF binary (.glb), not read by tsog: export its splats as PLY"
    kind = CONVERTIBLE_BY_SUFFIX.get(PurePosixPath(name).suffix.lower())
    if kind is not None:
        return f"{kind}, not read by tsog: {_convert_hint(name)}"
    return None


def foreign_npz(members: Collection[str]) -> str | None:
    """Why a zip of NumPy arrays (``members``) that is not a FreeTimeGS checkpoint is not
    read, naming its arrays; None when it holds something else too (then a SOG bundle)."""
    if not members or not all(m.endswith(NPY_SUFFIX) for m in members):
        return None
    arrays = ", ".join(sorted(m.removesuffix(NPY_SUFFIX) for m in members))
    return (
        f"a NumPy .npz ({arrays}), not a FreeTimeGS checkpoint (means, times, durations, ...), "
        "the only .npz tsog reads: save its Gaussians as PLY"
    )
