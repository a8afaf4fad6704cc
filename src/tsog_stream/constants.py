"""Constants of the SOG v2 and TSOG formats, defined once (see docs/spec.md)."""

from __future__ import annotations

import os
from typing import Final

# --- SOG v2 -------------------------------------------------------------------------------
BLOCK_BYTES: Final = 2 << 20
"""Bytes of temporaries a blocked loop holds at a time, its one block size (a kernel's rows per
block follow from its row's bytes: ``columns.rows_per_block``): memory bounded and in cache;
no result depends on it (each kernel's test changes it)."""
SOG_VERSION: Final = 2
CODEBOOK_SIZE: Final = 256
"""Entries in every scalar codebook (scales, sh0, shN)."""
WEBP_MAX_SIDE: Final = 16383
"""Largest width or height a WebP image may have."""
IMAGE_ALIGN: Final = 4
"""Per-Gaussian images have width and height that are multiples of this."""
SH_C0: Final = 0.28209479177387814
"""Zeroth spherical-harmonics basis constant: colour = 0.5 + SH_C0 * f_dc."""
SH_COEFFS_BY_BANDS: Final[dict[int, int]] = {0: 0, 1: 3, 2: 8, 3: 15}
"""Coefficients per colour channel beyond DC, by number of SH bands."""
SH_BANDS_BY_COEFFS: Final[dict[int, int]] = {v: k for k, v in SH_COEFFS_BY_BANDS.items()}
SH_PALETTE_MAX: Final = 65536
"""The SH palette is addressed by a 16-bit label."""
SH_CENTROIDS_PER_ROW: Final = 64
"""Palette entries per row of the shN centroid image."""
QUAT_TAG_BASE: Final = 252
"""Alpha of quats.webp = QUAT_TAG_BASE + index of the dropped (largest) component."""
U16_MAX: Final = 65535
INFINITY_SENTINEL_OFFSET: Final = 20.0
"""Codebook slots reserved for -inf/+inf hold finite min - 20 / finite max + 20."""

MEANS_L: Final = "means_l.webp"
MEANS_U: Final = "means_u.webp"
QUATS: Final = "quats.webp"
SCALES: Final = "scales.webp"
SH0: Final = "sh0.webp"
SHN_CENTROIDS: Final = "shN_centroids.webp"
SHN_LABELS: Final = "shN_labels.webp"
META_JSON: Final = "meta.json"
GENERATOR: Final = "tsog-stream"

# --- TSOG ---------------------------------------------------------------------------------
TIMELINE_L: Final = "timeline_l.webp"
TIMELINE_U: Final = "timeline_u.webp"

TEMPORAL_CHANNELS: Final[dict[str, int]] = {
    "means": 3,
    "scales": 3,
    "quats": 4,
    "sh0": 3,
    "opacity": 1,
}
"""Attributes that may carry temporal polynomial coefficients, and their channel counts."""
STORED_CHANNELS: Final[dict[str, tuple[int, ...]]] = {
    "means": (3,),
    "scales": (3,),
    "quats": (4, 3),
    "sh0": (3, 4),
    "opacity": (1,),
}
"""Channel counts a ``temporal.<attr>`` entry of ``meta.json`` may have (docs/spec.md §6), the
first being the one written."""
OPACITY_IN_SH0: Final = 3
"""Channel (A) of a 4-channel ``temporal.sh0`` entry that holds the opacity coefficients."""
MAX_TEMPORAL_ORDER: Final = 8

SCALE_CAP_SPANS: Final = 20.0
"""Type-2 scales are stored clamped to this many scene spans."""

ALPHA_EPS: Final = 1e-6
"""Alpha is clamped to [ALPHA_EPS, 1 - ALPHA_EPS] before taking its logit (see opacity.py)."""

VISIBILITY_THRESHOLD: Final = 1.0 / 255.0
"""Type-2 Gaussians whose temporal opacity factor falls under this are invisible."""


def temporal_file(attr: str, order: int, half: str) -> str:
    """Name of the image holding byte ``half`` ('l' or 'u') of ``attr``'s order-``order`` term."""
    return f"temporal_{attr}_{order}_{half}.webp"


# --- The .tsogs container (docs/spec.md §8) --------------------------------------------------
CONTAINER_MAGIC: Final = b"TSOGS\x00\r\n"
"""First 8 bytes of a container: name, a NUL (not text), CR LF (catches newline translation)."""


def is_container(head: bytes) -> bool:
    """True when ``head`` starts with the container magic."""
    return head[: len(CONTAINER_MAGIC)] == CONTAINER_MAGIC


# --- Limits on untrusted input (docs/reliability.md) ---------------------------------------
DEFAULT_MAX_PIXELS: Final = 4096 * 4096
"""Pixels per image: the segmenter's budget per chunk image, and a reader's by default."""
MAX_PIXELS_ENV: Final = "TSOG_MAX_PIXELS"
"""Environment variable raising (or lowering) the read budget, in pixels per image."""


def pixel_budget() -> int:
    """Largest image (and Gaussian count) a reader decodes, checked before decoding:
    ``$TSOG_MAX_PIXELS`` when a positive integer (at most MAX_IMAGE_PIXELS), else
    DEFAULT_MAX_PIXELS."""
    text = os.environ.get(MAX_PIXELS_ENV, "").strip()
    if text.isdigit() and int(text) > 0:
        return min(int(text), MAX_IMAGE_PIXELS)
    return DEFAULT_MAX_PIXELS


MAX_IMAGE_PIXELS: Final = WEBP_MAX_SIDE * WEBP_MAX_SIDE
"""Largest image any reader decodes; Pillow's decompression-bomb limit is set to this."""
IMAGE_SLACK_TEXELS: Final = 4096
"""A per-Gaussian image may hold at most 2 * count + this many texels."""
MAX_INDEX_RATIO: Final = 256
"""A zstd index may declare at most this many raw bytes per compressed byte (plus 64 KiB)."""
MAX_GAUSSIANS_PER_IMAGE_BYTE: Final = 64
"""A chunk may declare at most this many Gaussians per byte of its WebP files beyond
FREE_GAUSSIANS (trained data never compresses that far)."""
FREE_GAUSSIANS: Final = 65536

RENDER_MAX_SIDE: Final = 16384
"""Largest image side ``render``/``eval`` draw."""
RENDER_MAX_VIEWS: Final = 1000
EVAL_MAX_TIMES: Final = 1000
MAX_CAMERAS: Final = 4096
"""Most capture cameras a scene carries in its index."""
MAX_CAMERA_SIDE: Final = 65536
"""Largest image side a capture camera may declare."""
MAX_CAMERA_FILE_BYTES: Final = 64 * 1024 * 1024
"""Largest cameras.json or COLMAP cameras.txt read (checked before reading)."""

MAX_LAYERS_READ: Final = 16
"""Most quality layers an index may list (writers make at most 8): a reader refuses more."""
MAX_PSNR_DB: Final = 200.0
"""Above any finite PSNR of 8-bit pictures (< 198.1 dB below 10^15 pixels): a writer records an
exact picture's infinite PSNR as this."""

# --- Scene thumbnails (tsog segment writes them; the server's scene list shows them) --------
THUMBNAIL_SUFFIX: Final = ".thumb.png"
"""A container's thumbnail sits beside it: ``clip.tsogs`` -> ``clip.tsogs.thumb.png``."""
THUMBNAIL_SIZE: Final = (320, 180)


def thumbnail_path(container: str) -> str:
    """The thumbnail file of a container (a path or a root-relative name)."""
    return container + THUMBNAIL_SUFFIX
