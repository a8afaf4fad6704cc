"""Pydantic models of the TSOG additions to ``meta.json``: ``timeline`` and ``temporal``.

A TSOG chunk's meta is a SOG v2 meta (:class:`~.sog_meta.SogMeta`) plus two optional keys
(docs/spec.md, "meta.json"; paper section 3). :class:`ChunkMeta` is the whole document;
:class:`ShBandsMeta` is the meta of an SH-band chunk (the higher bands of another chunk).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BeforeValidator, Field, StrictInt, model_validator

from ..constants import (
    MAX_TEMPORAL_ORDER,
    SOG_VERSION,
    STORED_CHANNELS,
    TEMPORAL_CHANNELS,
    TIMELINE_L,
    TIMELINE_U,
    temporal_file,
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
    custom_error,
    describe,
    field_error,
    validate_into,
)

PositiveFloat = Annotated[FiniteFloat, Field(gt=0)]
Row = tuple[FiniteFloat, ...]
Rows = Annotated[tuple[Row, ...], Field(min_length=1, max_length=MAX_TEMPORAL_ORDER)]


def _strict_int(value: Any) -> Any:
    """Let only a JSON integer through (no bool, no 2.0, no "2") before enum validation."""
    if isinstance(value, int) and not isinstance(value, bool):
        return value
    raise custom_error(f"expected an integer 0, 1 or 2, found {describe(value)}")


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
            raise field_error(
                "fps", "expected no fps for type 2 (centre/scale); fps is for 0 and 1"
            )
        if self.type is TimelineType.FRAME:
            for key, values in (("mins", self.mins), ("maxs", self.maxs)):
                if values[1] != 0.0:
                    raise field_error(
                        f"{key}[1]", f"expected 0 (G is unused for type 0), found {values[1]!r}"
                    )
        check_ranges(self.mins, self.maxs)
        return self

    @classmethod
    def build(
        cls,
        type: int,
        mins: Sequence[float],
        maxs: Sequence[float],
        *,
        fps: float | None = None,
        scene_length: float | None = None,
        files: tuple[str, str] = (TIMELINE_L, TIMELINE_U),
    ) -> TimelineMeta:
        """A validated ``timeline`` from numbers (numpy scalars welcome); raises MetaError."""
        data = {
            "type": int(type),
            "fps": None if fps is None else float(fps),
            "scene_length": None if scene_length is None else float(scene_length),
            "mins": [float(v) for v in mins],
            "maxs": [float(v) for v in maxs],
            "files": list(files),
        }
        return validate_into(cls, data, prefix="timeline")


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
        width = len(self.mins[0])
        if width == 0:
            raise field_error("mins[0]", "expected at least one channel, found an empty row")
        for k, row in enumerate(self.mins):
            if len(row) != width:
                raise field_error(f"mins[{k}]", f"expected {width} values, found {len(row)}")
        if len(self.maxs) != self.orders:
            raise field_error(
                "maxs", f"expected {self.orders} rows like mins, found {len(self.maxs)}"
            )
        for k, row in enumerate(self.maxs):
            if len(row) != width:
                raise field_error(
                    f"maxs[{k}]", f"expected {width} values (like mins[0]), found {len(row)}"
                )
        if len(self.files) != 2 * self.orders:
            raise field_error(
                "files",
                f"expected {2 * self.orders} file names (2 per order), found {len(self.files)}",
            )
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

    def order_files(self, order: int) -> tuple[str, str]:
        """(low-byte, high-byte) image names of coefficient order ``order`` (1-based)."""
        return self.files[2 * order - 2], self.files[2 * order - 1]

    @classmethod
    def build(
        cls,
        attr: str,
        mins: Sequence[Sequence[float]],
        maxs: Sequence[Sequence[float]],
        *,
        files: Sequence[str] | None = None,
    ) -> TemporalAttributeMeta:
        """A validated ``temporal.<attr>`` from numbers; default names temporal_<attr>_<k>_<l|u>.

        Checks the channel count of ``attr`` too; raises MetaError.
        """
        orders = len(mins)
        if files is None:
            files = [temporal_file(attr, k, h) for k in range(1, orders + 1) for h in "lu"]
        entry = {
            "mins": [[float(v) for v in row] for row in mins],
            "maxs": [[float(v) for v in row] for row in maxs],
            "files": list(files),
        }
        holder = validate_into(_TemporalHolder, {"temporal": {attr: entry}}, prefix="")
        return holder.temporal[attr]


def _known_attributes(value: Any) -> Any:
    """Name the first key of ``temporal`` that is not a dynamic attribute we know."""
    if isinstance(value, Mapping):
        for key in value:
            if key not in TEMPORAL_CHANNELS:
                known = ", ".join(TEMPORAL_CHANNELS)
                raise field_error(
                    str(key), f"expected a temporal attribute ({known}), found {describe(key)}"
                )
    return value


def _channels_and_order(
    value: dict[str, TemporalAttributeMeta],
) -> dict[str, TemporalAttributeMeta]:
    """Each attribute's rows have its channel count; keys come back in TEMPORAL_CHANNELS order."""
    if not value:
        raise field_error(
            "", "expected at least one attribute; omit 'temporal' when none is dynamic"
        )
    for attr, entry in value.items():
        allowed = STORED_CHANNELS[attr]
        if entry.channels not in allowed:
            want = " or ".join(str(c) for c in allowed)
            raise field_error(
                f"{attr}.mins[0]",
                f"expected {want} values ({attr}'s channels), found {entry.channels}",
            )
    sh0 = value.get("sh0")
    if "opacity" in value and sh0 is not None and sh0.channels == 4:
        raise field_error(
            "opacity",
            "expected opacity's coefficients once: they are in sh0's A channel already",
        )
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


class _TemporalHolder(FrozenModel):
    """Wrapper to validate one attribute against its channel count (used by ``build``)."""

    temporal: Temporal


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
        seen: dict[str, str] = {}
        for field, name in self.listed_files():
            if name in seen:
                raise field_error(
                    field,
                    f"expected a distinct file name, found {name!r} again (also {seen[name]})",
                )
            seen[name] = field
        return self

    def listed_files(self) -> list[tuple[str, str]]:
        """(field path, file name) of every image referenced, in the canonical order."""
        return list(_iter_files(self))


def _iter_files(meta: ChunkMeta) -> Iterator[tuple[str, str]]:
    """Images in order: means l/u, quats, scales, sh0, shN, timeline, temporal (by attr, order)."""
    yield "means.files[0]", meta.means.files[0]
    yield "means.files[1]", meta.means.files[1]
    yield "quats.files[0]", meta.quats.files[0]
    yield "scales.files[0]", meta.scales.files[0]
    yield "sh0.files[0]", meta.sh0.files[0]
    if meta.shN is not None:
        yield "shN.files[0]", meta.shN.files[0]
        yield "shN.files[1]", meta.shN.files[1]
    if meta.timeline is not None:
        yield "timeline.files[0]", meta.timeline.files[0]
        yield "timeline.files[1]", meta.timeline.files[1]
    for attr, entry in (meta.temporal or {}).items():
        for i, name in enumerate(entry.files):
            yield f"temporal.{attr}.files[{i}]", name


class ShBandsMeta(FrozenModel):
    """An SH-band chunk's ``meta.json``: the bands beyond DC of the Gaussians of the chunk it
    belongs to (the index's ``sh_of``), texel for texel in that chunk's order. Not a
    standalone SOG: it has no positions; readers add its ``shN`` to its host's Gaussians
    (docs/spec.md, "SH-band chunks")."""

    version: Literal[2] = Field(description=f"Format version; always {SOG_VERSION}.")
    asset: Annotated[dict[str, Any], AfterValidator(check_json_value)] | None = Field(
        default=None, description='Informational, e.g. {"generator": "tsog-stream"}.'
    )
    count: StrictInt = Field(ge=1, le=MAX_COUNT, description="Gaussians of the host chunk.")
    shN: ShNMeta = Field(description="The host's higher SH bands, as a SOG v2 shN.")

    @model_validator(mode="after")
    def _distinct_files(self) -> ShBandsMeta:
        """The centroid and label images are two files."""
        if self.shN.files[0] == self.shN.files[1]:
            raise field_error(
                "shN.files[1]", f"expected a distinct file name, found {self.shN.files[1]!r} again"
            )
        return self

    def listed_files(self) -> list[tuple[str, str]]:
        """(field path, file name) of the centroid and label images."""
        return [("shN.files[0]", self.shN.files[0]), ("shN.files[1]", self.shN.files[1])]
