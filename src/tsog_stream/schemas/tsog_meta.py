"""Pydantic models of the TSOG ``meta.json`` (docs/spec.md, "meta.json"): :class:`ChunkMeta`,
a SOG v2 meta plus optional ``timeline`` and ``temporal``, and :class:`ShBandsMeta`, the meta
of an SH-band chunk (the higher bands of another chunk).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BeforeValidator, Field, StrictInt, model_validator

from ..constants import (
    MAX_TEMPORAL_ORDER,
    SOG_VERSION,
    STORED_CHANNELS,
    TEMPORAL_CHANNELS,
)
from ..model import TimelineType
from .sog_meta import (
    MAX_COUNT,
    FileName,
    Files2,
    FiniteFloat,
    FrozenModel,
    ShNMeta,
    SogMeta,
    Vec2,
    check_json_value,
    check_ranges,
    describe,
    field_error,
)

PositiveFloat = Annotated[FiniteFloat, Field(gt=0)]
Row = tuple[FiniteFloat, ...]
Rows = Annotated[tuple[Row, ...], Field(min_length=1, max_length=MAX_TEMPORAL_ORDER)]


def _strict_int(value: Any) -> Any:
    """Let only a JSON integer through (no bool, no 2.0, no "2") before enum validation."""
    if isinstance(value, int) and not isinstance(value, bool):
        return value
    raise field_error("", f"expected an integer 0, 1 or 2, found {describe(value)}")


class TimelineMeta(FrozenModel):
    """``timeline``: how each Gaussian's lifespan is stored (R and G channels, 16-bit l/u)."""

    type: Annotated[TimelineType, BeforeValidator(_strict_int)] = Field(
        description="0 = frame id (R); 1 = start (R) + duration (G); 2 = centre (R) + scale (G)."
    )
    fps: PositiveFloat | None = Field(
        default=None,
        description="Frames per second; only for types 0 and 1, whose values are then frames.",
    )
    scene_length: PositiveFloat | None = Field(
        default=None, description="Length of the scene in seconds (any type)."
    )
    mins: Vec2 = Field(description="[R min, G min]; for type 0 G is unused and stores 0.")
    maxs: Vec2 = Field(description="[R max, G max] (>= mins); for type 0 G stores 0.")
    files: Files2 = Field(
        description="[low-byte image, high-byte image], e.g. timeline_l.webp, timeline_u.webp."
    )

    @model_validator(mode="after")
    def _consistent(self) -> TimelineMeta:
        """fps only for frame-based types; type 0 leaves G at 0; mins <= maxs."""
        if self.fps is not None and self.type is TimelineType.CENTER_SCALE:
            found = "expected no fps for type 2 (centre/scale); fps is for 0 and 1"
            raise field_error("fps", found)
        for key, values in (("mins", self.mins), ("maxs", self.maxs)):
            if self.type is TimelineType.FRAME and values[1] != 0.0:
                found = f"expected 0 (G is unused for type 0), found {values[1]!r}"
                raise field_error(f"{key}[1]", found)
        check_ranges(self.mins, self.maxs)
        return self


class TemporalAttributeMeta(FrozenModel):
    """``temporal.<attr>``: ranges and images of polynomial coefficients of orders 1..K."""

    mins: Rows = Field(description="One row per order (ascending), one value per channel.")
    maxs: Rows = Field(description="Same shape as mins; maxs >= mins elementwise.")
    files: tuple[FileName, ...] = Field(
        description="2 per order: order-1 low byte, order-1 high byte, order-2 low byte, ..."
    )

    @model_validator(mode="after")
    def _shapes(self) -> TemporalAttributeMeta:
        """Rows of one width, maxs shaped like mins, two files per order, mins <= maxs."""
        width, orders = len(self.mins[0]), self.orders
        if width == 0:
            raise field_error("mins[0]", "expected at least one channel, found an empty row")
        for k, row in enumerate(self.mins):
            if len(row) != width:
                raise field_error(f"mins[{k}]", f"expected {width} values, found {len(row)}")
        if len(self.maxs) != orders:
            raise field_error("maxs", f"expected {orders} rows like mins, found {len(self.maxs)}")
        for k, row in enumerate(self.maxs):
            if len(row) != width:
                found = f"expected {width} values (like mins[0]), found {len(row)}"
                raise field_error(f"maxs[{k}]", found)
        if len(self.files) != 2 * orders:
            found = f"expected {2 * orders} file names (2 per order), found {len(self.files)}"
            raise field_error("files", found)
        for k in range(self.orders):
            check_ranges(self.mins[k], self.maxs[k], row=f"[{k}]")
        return self

    @property
    def orders(self) -> int:
        """Highest polynomial order K stored (orders 1..K)."""
        return len(self.mins)

    @property
    def channels(self) -> int:
        """Values per order (the attribute's channel count)."""
        return len(self.mins[0])


def _known_attributes(value: Any) -> Any:
    """Name the first key of ``temporal`` that is not a dynamic attribute we know."""
    for key in value if isinstance(value, Mapping) else ():
        if key not in TEMPORAL_CHANNELS:
            known = ", ".join(TEMPORAL_CHANNELS)
            found = f"expected a temporal attribute ({known}), found {describe(key)}"
            raise field_error(str(key), found)
    return value


def _channels_and_order(
    value: dict[str, TemporalAttributeMeta],
) -> dict[str, TemporalAttributeMeta]:
    """Each attribute's rows have its channel count; keys come back in TEMPORAL_CHANNELS order."""
    if not value:
        found = "expected at least one attribute; omit 'temporal' when none is dynamic"
        raise field_error("", found)
    for attr, entry in value.items():
        if entry.channels not in STORED_CHANNELS[attr]:
            want = " or ".join(str(c) for c in STORED_CHANNELS[attr])
            found = f"expected {want} values ({attr}'s channels), found {entry.channels}"
            raise field_error(f"{attr}.mins[0]", found)
    sh0 = value.get("sh0")
    if "opacity" in value and sh0 is not None and sh0.channels == 4:
        found = "expected opacity's coefficients once: they are in sh0's A channel already"
        raise field_error("opacity", found)
    return {attr: value[attr] for attr in TEMPORAL_CHANNELS if attr in value}


Temporal = Annotated[
    dict[str, TemporalAttributeMeta],
    BeforeValidator(_known_attributes),
    AfterValidator(_channels_and_order),
    Field(
        json_schema_extra={
            "propertyNames": {"enum": list(TEMPORAL_CHANNELS)},
            "minProperties": 1,
        },
    ),
]


class ChunkMeta(SogMeta):
    """A TSOG chunk's ``meta.json``: SOG v2 plus optional ``timeline`` and ``temporal``.

    Without ``timeline`` it is a plain SOG v2 meta. Unknown top-level keys are preserved.
    """

    timeline: TimelineMeta | None = Field(
        default=None, description="Per-Gaussian lifespans; absent for a static chunk."
    )
    temporal: Temporal | None = Field(
        default=None,
        description="Polynomial coefficients of dynamic attributes, keyed by attribute, with "
        "their channels: "
        + ", ".join(f"{k} ({' or '.join(map(str, v))})" for k, v in STORED_CHANNELS.items())
        + ". Opacity's coefficients are written in sh0's A channel (4 channels); a separate "
        "opacity is read. Requires timeline.",
    )

    @model_validator(mode="after")
    def _tsog_rules(self) -> ChunkMeta:
        """``temporal`` needs a timeline; no image is listed twice."""
        if self.temporal is not None and self.timeline is None:
            raise field_error(
                "temporal", "expected a 'timeline' key alongside 'temporal', found none"
            )
        _refuse_repeated(self.listed_files())
        return self

    def listed_files(self) -> list[tuple[str, str]]:
        """(field path, file name) of every image, in the canonical order: means l/u, quats,
        scales, sh0, shN, timeline, temporal (by attribute, order, l before u)."""
        keys = ("means", "quats", "scales", "sh0", "shN", "timeline")
        parts: list[tuple[str, Any]] = [(key, getattr(self, key)) for key in keys]
        parts += [(f"temporal.{attr}", entry) for attr, entry in (self.temporal or {}).items()]
        return [
            (f"{key}.files[{i}]", name)
            for key, part in parts
            if part is not None
            for i, name in enumerate(part.files)
        ]


def _refuse_repeated(files: list[tuple[str, str]]) -> None:
    """A field error at the second listing of any file name."""
    seen: dict[str, str] = {}
    for field, name in files:
        if name in seen:
            found = f"found {name!r} again (also {seen[name]})"
            raise field_error(field, f"expected a distinct file name, {found}")
        seen[name] = field


class ShBandsMeta(FrozenModel):
    """An SH-band chunk's ``meta.json``: the bands beyond DC of its host chunk's Gaussians (the
    index's ``sh_of``), texel for texel; no positions, so no standalone SOG (docs/spec.md)."""

    version: Literal[2] = Field(description=f"Format version; always {SOG_VERSION}.")
    asset: Annotated[dict[str, Any], AfterValidator(check_json_value)] | None = Field(
        default=None, description='Informational, e.g. {"generator": "tsog-stream"}.'
    )
    count: StrictInt = Field(ge=1, le=MAX_COUNT, description="Gaussians of the host chunk.")
    shN: ShNMeta = Field(description="The host's higher SH bands, as a SOG v2 shN.")

    @model_validator(mode="after")
    def _distinct_files(self) -> ShBandsMeta:
        """The centroid and label images are two files."""
        _refuse_repeated(self.listed_files())
        return self

    def listed_files(self) -> list[tuple[str, str]]:
        """(field path, file name) of the centroid and label images."""
        return [(f"shN.files[{i}]", name) for i, name in enumerate(self.shN.files)]
