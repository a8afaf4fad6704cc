"""Pydantic models of the SOG v2 ``meta.json`` (docs/spec.md), and the schemas' shared parts:
:data:`FiniteFloat`, :data:`FileName`, the JSON-value check of free-form keys, and
:func:`field_error`, with which a validator names a sub-field of the object it checks.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from typing import Annotated, Any, Literal, TypeVar

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    StrictInt,
    StrictStr,
    ValidationError,
    model_validator,
)
from pydantic_core import ErrorDetails, PydanticCustomError

from ..constants import CODEBOOK_SIZE, SH_PALETTE_MAX, SOG_VERSION, WEBP_MAX_SIDE
from ..errors import MetaError

SUFFIX_KEY = "tsog_suffix"
"""Error-context key holding the path of the culprit below the validated object."""
FILE_NAME_MAX_BYTES = 255
"""Longest file name (UTF-8 bytes) accepted: the common file-system limit."""
MAX_COUNT = WEBP_MAX_SIDE * WEBP_MAX_SIDE
"""More Gaussians than this cannot fit in a WebP image."""
DOCUMENT = "<document>"
"""``MetaError.field`` for problems with the document as a whole (encoding, JSON syntax)."""
SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"


def field_error(suffix: str, message: str) -> PydanticCustomError:
    """A validation error about ``suffix`` (e.g. ``mins[1]``; "" for the object itself) below
    the object being checked, with a finished ``message`` (never re-formatted: it may hold
    braces)."""
    # the message last: pydantic substitutes context keys in order
    return PydanticCustomError("tsog_error", "{message}", {SUFFIX_KEY: suffix, "message": message})


def schema_text(model: type[BaseModel], **keys: str) -> str:
    """``model``'s JSON Schema with ``keys`` added, serialised deterministically (sorted keys,
    indent 2, final newline) as docs/schema/ ships it."""
    schema = model.model_json_schema() | keys
    return json.dumps(schema, indent=2, sort_keys=True, ensure_ascii=False) + "\n"


def describe(value: object) -> str:
    """A short JSON-flavoured rendering of ``value`` for "found ..." in error messages."""
    if value is None or isinstance(value, bool):
        return {None: "null", True: "true", False: "false"}[value]
    if isinstance(value, float) and not math.isfinite(value):
        return "NaN" if math.isnan(value) else ("Infinity" if value > 0 else "-Infinity")
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        text = value if len(value) <= 60 else value[:57] + "..."
        return "string " + repr(text)
    if isinstance(value, dict):
        return "an object"
    if isinstance(value, list | tuple):
        return f"an array of {len(value)} item{'s' * (len(value) != 1)}"
    return f"a Python {type(value).__name__}"


def join_path(*parts: str | int) -> str:
    """``("temporal", "quats", "mins", 1, 2)`` -> ``temporal.quats.mins[1][2]``."""
    out = ""
    for part in parts:
        if isinstance(part, int):
            out += f"[{part}]"
        elif part.startswith("[") or not out:
            out += part
        elif part:
            out += "." + part
    return out


def _message(err: ErrorDetails) -> str:
    """What was expected and what was found, from one pydantic error."""
    kind, msg, ctx = err["type"], err["msg"], err.get("ctx") or {}
    if kind.startswith("tsog_"):
        return msg  # our own messages already say expected/found
    if kind == "missing" and isinstance(err["loc"][-1], int):
        return "expected an item here, found too few items"
    if kind == "missing":
        return "expected this key, found it missing"
    if kind == "extra_forbidden":
        return f"expected no key {err['loc'][-1]!r} here (unknown; check the spelling)"
    if kind in ("too_short", "too_long"):
        bound = f"at least {ctx.get('min_length')}" if kind == "too_short" else ""
        bound = bound or f"at most {ctx.get('max_length')}"
        return f"expected {bound} items, found {ctx.get('actual_length')}"
    if msg.startswith("Input should be "):
        msg = "expected " + msg.removeprefix("Input should be ")
    return f"{msg}, found {describe(err['input'])}"


def to_meta_error(exc: ValidationError, *, prefix: str = "", where: str | None = None) -> MetaError:
    """The first pydantic error as a MetaError whose ``field`` is the culprit's full path."""
    err = exc.errors(include_url=False)[0]
    ctx = err.get("ctx") or {}
    parts: list[str | int] = [prefix, *err["loc"]]
    suffix = ctx.get(SUFFIX_KEY)
    if isinstance(suffix, str):
        parts.append(suffix)
    return MetaError(_message(err), field=join_path(*parts) or DOCUMENT, where=where)


ModelT = TypeVar("ModelT", bound=BaseModel)


def validate_into(cls: type[ModelT], data: Any, *, where: str | None = None) -> ModelT:
    """``cls.model_validate(data)`` with pydantic's error translated to :class:`MetaError`."""
    try:
        return cls.model_validate(data)
    except ValidationError as exc:
        raise to_meta_error(exc, where=where) from None


def _check_file_name(name: str) -> str:
    """Only a plain, portable file name inside the chunk folder (no path, no escape)."""
    problem = None
    if name in ("", ".", ".."):
        problem = "a non-empty name other than '.' and '..'"
    elif "/" in name or "\\" in name:
        problem = "a name without '/' or '\\' (no directories, no absolute paths)"
    elif ":" in name:
        problem = "a name without ':' (no drive letters or stream names)"
    elif any(ord(ch) < 0x20 or ord(ch) == 0x7F for ch in name):
        problem = "a name without control characters (NUL included)"
    elif not _utf8(name):
        problem = "a name that is valid Unicode (no lone surrogates)"
    elif (size := len(name.encode("utf-8"))) > FILE_NAME_MAX_BYTES:
        problem = f"a name of at most {FILE_NAME_MAX_BYTES} UTF-8 bytes ({size} here)"
    if problem is not None:
        raise field_error("", f"expected {problem}, found {describe(name)}")
    return name


def _json_problem(value: object, path: str) -> tuple[str, str] | None:
    """(path, what is wrong) for the first non-JSON, non-finite or non-UTF-8 item of ``value``."""
    if isinstance(value, float) and not math.isfinite(value):
        return path, f"a finite number, found {describe(value)}"
    if isinstance(value, str) and not _utf8(value):
        return path, "valid Unicode text, found a lone surrogate"
    if value is None or isinstance(value, int | float | str):
        return None
    if isinstance(value, list | tuple):
        value = {f"[{i}]": item for i, item in enumerate(value)}
    elif isinstance(value, dict):
        for key in value:
            if not isinstance(key, str) or not _utf8(key):
                return path, f"object keys to be valid strings, found {describe(key)}"
        value = {f".{key}": item for key, item in value.items()}
    else:
        return path, f"a JSON value, found {describe(value)}"
    return next(filter(None, (_json_problem(v, path + k) for k, v in value.items())), None)


def _utf8(text: str) -> bool:
    """True unless ``text`` holds a lone surrogate (no UTF-8 for it)."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def check_json_value(value: Any, path: str = "") -> Any:
    """Reject values JSON cannot carry (NaN, Infinity, sets, ...) anywhere inside ``value``."""
    found = _json_problem(value, path)
    if found is not None:
        raise field_error(found[0].lstrip("."), "expected " + found[1])
    return value


FiniteFloat = Annotated[float, Field(strict=True, allow_inf_nan=False)]
"""A JSON number that is finite (NaN and Infinity parse in Python's json but are not JSON)."""

FileName = Annotated[
    StrictStr,
    AfterValidator(_check_file_name),
    Field(
        description="Plain file name inside the chunk folder: no '/', '\\', ':', control "
        "characters, '.' or '..'; at most 255 UTF-8 bytes.",
        json_schema_extra={"pattern": r"^(?!\.\.?$)[^/\\:\u0000-\u001f\u007f]+$", "minLength": 1},
    ),
]

JsonValue = Annotated[Any, AfterValidator(check_json_value)]
"""Any JSON value with finite numbers and valid Unicode; kept as given."""

Text = Annotated[StrictStr, AfterValidator(check_json_value)]
"""A string that can be written as UTF-8."""

Codebook = Annotated[
    tuple[FiniteFloat, ...], Field(min_length=CODEBOOK_SIZE, max_length=CODEBOOK_SIZE)
]

Vec3 = Annotated[tuple[FiniteFloat, ...], Field(min_length=3, max_length=3)]
"""Exactly three finite floats (one per axis or colour channel)."""
Vec2 = Annotated[tuple[FiniteFloat, ...], Field(min_length=2, max_length=2)]
"""Exactly two finite floats (the timeline's R and G channels)."""
Files1 = Annotated[tuple[FileName, ...], Field(min_length=1, max_length=1)]
Files2 = Annotated[tuple[FileName, ...], Field(min_length=2, max_length=2)]


def check_ranges(mins: Sequence[float], maxs: Sequence[float], row: str = "") -> None:
    """A field error at ``mins{row}[i]`` of the first channel with min > max or a bound past
    float32 (decoded values are float32: ±1e308 would become inf and NaN)."""
    for i, (lo, hi) in enumerate(zip(mins, maxs, strict=False)):
        name = f"mins{row}[{i}]"
        if lo > hi:
            raise field_error(name, f"expected {name} <= maxs{row}[{i}], found {lo!r} > {hi!r}")
        if max(abs(lo), abs(hi)) > FLOAT32_MAX:
            raise field_error(
                name, f"expected bounds within ±{FLOAT32_MAX:.4g} (float32), found [{lo!r}, {hi!r}]"
            )


class FrozenModel(BaseModel):
    """Base of our closed objects: immutable, unknown keys are errors (they catch typos)."""

    model_config = ConfigDict(frozen=True, extra="forbid")


FLOAT32_MAX = 3.4028234663852886e38
"""Largest float32: every decoded value is one."""
MAX_LOG_POSITION = 88.0
"""Largest |sign(v)·ln(1+|v|)| of a position: e^88 - 1 is about 1.65e38, under float32's max."""


class MeansMeta(FrozenModel):
    """``means``: range of the log-transformed positions and the two 16-bit halves."""

    mins: Vec3 = Field(description="Per-axis minimum of sign(v)·ln(1+|v|).")
    maxs: Vec3 = Field(description="Per-axis maximum of sign(v)·ln(1+|v|); >= mins.")
    files: Files2 = Field(description="[low-byte image, high-byte image].")

    @model_validator(mode="after")
    def _ordered(self) -> MeansMeta:
        """mins <= maxs per axis (the writer takes them from the data), and no bound whose
        position, e^|v| - 1, overflows a float32 (the decoded positions' type)."""
        check_ranges(self.mins, self.maxs)
        for key, values in (("mins", self.mins), ("maxs", self.maxs)):
            for i, v in enumerate(values):
                if abs(v) > MAX_LOG_POSITION:
                    found = f"<= {MAX_LOG_POSITION} (a position that fits a float32), found {v!r}"
                    raise field_error(f"{key}[{i}]", f"expected |{key}[{i}]| {found}")
        return self


class ScalesMeta(FrozenModel):
    """``scales``: codebook of ln(sigma) values and the index image."""

    codebook: Codebook = Field(description="256 log-scale values indexed by the image bytes.")
    files: Files1 = Field(description="[scales image].")


class QuatsMeta(FrozenModel):
    """``quats``: the smallest-three rotation image."""

    files: Files1 = Field(description="[quats image].")


class Sh0Meta(FrozenModel):
    """``sh0``: codebook of f_dc values and the colour + opacity image."""

    codebook: Codebook = Field(description="256 f_dc values indexed by the RGB bytes.")
    files: Files1 = Field(description="[sh0 image]; alpha holds the opacity byte.")


class ShNMeta(FrozenModel):
    """``shN``: the spherical-harmonics palette beyond DC (present when bands >= 1)."""

    count: StrictInt = Field(ge=1, le=SH_PALETTE_MAX, description="Palette size K (1..65536).")
    bands: StrictInt = Field(ge=1, le=3, description="SH bands beyond DC: 1, 2 or 3.")
    codebook: Codebook = Field(description="256 f_rest values indexed by the centroid bytes.")
    files: Files2 = Field(description="[centroids image, labels image].")


class SogMeta(BaseModel):
    """A SOG v2 ``meta.json``. Unknown top-level keys are kept (SOG readers ignore them)."""

    model_config = ConfigDict(frozen=True, extra="allow")

    version: Literal[2] = Field(description=f"Format version; always {SOG_VERSION}.")
    asset: Annotated[dict[str, Any], AfterValidator(check_json_value)] | None = Field(
        default=None, description='Informational, e.g. {"generator": "tsog-stream"}.'
    )
    count: StrictInt = Field(ge=0, le=MAX_COUNT, description="Number of Gaussians N.")
    model: Text | None = Field(
        default=None, description='Splat model tag, e.g. "antialiased" or "2dgs"; absent = default.'
    )
    means: MeansMeta = Field(description="Positions.")
    scales: ScalesMeta = Field(description="Scales.")
    quats: QuatsMeta = Field(description="Rotations.")
    sh0: Sh0Meta = Field(description="DC colour and opacity.")
    shN: ShNMeta | None = Field(default=None, description="Higher SH bands; absent when none.")
    extras: JsonValue = Field(default=None, description="Application data, any JSON value.")

    @model_validator(mode="after")
    def _json_extra_keys(self) -> SogMeta:
        """Unknown top-level keys are preserved, so they must be JSON with finite numbers."""
        for key, value in (self.model_extra or {}).items():
            check_json_value({key: value})
        return self
