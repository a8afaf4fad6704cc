"""Plausible values of a 3DGS PLY's float properties: a header naming the wrong byte order (or
a damaged body) is refused at the input, naming the property, instead of its garbage reaching
the encoder. About 40 % of floats read in the wrong byte order land beyond :data:`BOUNDS`: a
property with absurd values in more than :data:`REFUSE_SHARE` of its rows is refused, fewer
are clamped to the bound (noted); non-finite values are kept (``ply_columns.nonfinite_notes``)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

import numpy as np
import numpy.typing as npt

from ..errors import PlyError
from .ply_header import PlyFormat

F32 = npt.NDArray[np.float32]

BOUNDS: Final[dict[str, float]] = {
    "position": 1e9,
    "log scale": 40.0,
    "rotation": 1e4,
    "opacity logit": 100.0,
    "colour": 1e3,
}
"""Largest magnitude of each kind of value a trainer writes, with room to spare: positions
(ECEF coordinates reach 6.4e6 m), log scales (e^-40 m is 4e-18 m; real captures reach -23),
raw quaternion components (about 1), logits (alpha within 4e-44 of 0 or 1 beyond 100; real
ones reach 17) and SH coefficients (real ones within 15)."""
_POSITIONS: Final = frozenset({"x", "y", "z"} | {f"{e}_{a}" for e in ("min", "max") for a in "xyz"})
"""Position properties: a vertex's, and a compressed PLY chunk's bounds."""
REFUSE_SHARE: Final = 0.01
"""Share of a property's rows with absurd values above which the file is refused."""


def kind_of(name: str) -> str:
    """The kind of value a 3DGS vertex (or compressed-PLY chunk) property holds."""
    if "scale" in name:  # scale_0, min_scale_x
        return "log scale"
    if name in _POSITIONS:
        return "position"
    if name.startswith("rot_"):
        return "rotation"
    if name == "opacity":
        return "opacity logit"
    return "colour"


def clamp_absurd(
    matrices: Sequence[F32], names: Sequence[str], fmt: PlyFormat, *, where: str
) -> list[str]:
    """Check the gathered columns (``names`` in order across ``matrices``) against
    :data:`BOUNDS`: refuse the file (PlyError) when a property has absurd values in more
    than :data:`REFUSE_SHARE` of its rows, else clamp them in place and return the note
    counting them (nothing when there are none)."""
    found: list[tuple[str, int]] = []
    column = 0
    for matrix in matrices:
        for j in range(matrix.shape[1]):
            name = names[column + j]
            count = _clamp_column(matrix[:, j], BOUNDS[kind_of(name)])
            if count:
                _refuse_if_many(name, count, len(matrix), fmt, where)
                found.append((name, count))
        column += matrix.shape[1]
    if not found:
        return []
    total = sum(count for _, count in found)
    each = ", ".join(f"{name}: {count}" for name, count in found)
    return [f"clamped {total} absurd values to their kind's bound ({each})"]


def _clamp_column(values: F32, bound: float) -> int:
    """Clamp the finite values of a column beyond +-``bound``; how many there were. A reduction
    first (no copy): most columns hold none."""
    if not len(values):
        return 0
    high, low = np.fmax.reduce(values), np.fmin.reduce(values)
    if -bound <= low and high <= bound:  # NaN-free extremes (fmax/fmin skip NaN) within bounds
        return 0
    absurd = np.isfinite(values) & (np.abs(values) > bound)
    count = int(np.count_nonzero(absurd))
    values[absurd] = np.copysign(np.float32(bound), values[absurd])
    return count


def _refuse_if_many(name: str, count: int, rows: int, fmt: PlyFormat, where: str) -> None:
    """The PlyError of a property with absurd values in more than REFUSE_SHARE of its rows."""
    if count <= REFUSE_SHARE * rows:
        return
    kind = kind_of(name)
    message = (
        f"PLY property {name!r} holds absurd values: {count} of {rows} beyond "
        f"+-{BOUNDS[kind]:g}, the bound of a {kind}"
    )
    if fmt is not PlyFormat.ASCII:
        message += f": is the header's format ({fmt.value}) right?"
    raise PlyError(message, where=where)
