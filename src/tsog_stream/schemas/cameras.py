"""The one camera type (:class:`Camera`), and the 3DGS ``cameras.json`` edge.

Every reader produces a :class:`Camera` (cameras.json, COLMAP, a ``.splatv`` header, the
manifest), framing makes one, and the renderer draws with one (render/camera.py sizes it for a
picture and holds it to what the rasterizer may allocate). It is a pinhole camera as 3DGS's
``cameras.json`` writes it: image size, focal lengths and principal point in pixels, the camera
centre (``position``) and the camera-to-world ``rotation`` (rows of a 3x3 matrix whose columns
are the camera's x right, y down and z forward axes in world coordinates: the COLMAP/OpenCV
convention). See docs/spec.md §9 ("cameras" and "view").
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, StrictInt, ValidationError, model_validator

from ..constants import MAX_CAMERA_SIDE, MAX_CAMERAS
from ..errors import FormatError
from .sog_meta import to_meta_error

Finite = Annotated[float, Field(allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
Side = Annotated[StrictInt, Field(gt=0, le=MAX_CAMERA_SIDE)]
Vec3 = tuple[Finite, Finite, Finite]
ORTHONORMAL_TOLERANCE = 1e-3
"""Largest entry of |R R^T - I| accepted for a rotation (files store 6 to 17 digits)."""
NAME_MAX = 255


class Camera(BaseModel):
    """A pinhole camera: one of the capture, a view chosen for the scene, or one to draw with."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str = Field(default="", max_length=NAME_MAX, description="image name or label")
    width: Side = Field(description="image width in pixels")
    height: Side = Field(description="image height in pixels")
    fx: Positive = Field(description="focal length along x, pixels")
    fy: Positive = Field(description="focal length along y, pixels")
    cx: Finite | None = Field(default=None, description="principal point x; null: width / 2")
    cy: Finite | None = Field(default=None, description="principal point y; null: height / 2")
    position: Vec3 = Field(description="camera centre in scene units")
    rotation: tuple[Vec3, Vec3, Vec3] = Field(
        description="camera-to-world rotation, row by row (columns: x right, y down, z forward)"
    )

    @model_validator(mode="after")
    def _rotation_is_a_rotation(self) -> Camera:
        r = self.rotation
        for i in range(3):
            for j in range(3):
                dot = sum(r[k][i] * r[k][j] for k in range(3))
                if abs(dot - (i == j)) > ORTHONORMAL_TOLERANCE:
                    raise ValueError("rotation is not orthonormal (expected a rotation matrix)")
        if _determinant(r) < 0:
            raise ValueError("rotation is a reflection (determinant -1), not a rotation")
        return self

    @property
    def principal_point(self) -> tuple[float, float]:
        """(cx, cy), the image centre when the file gave none."""
        cx = self.width / 2 if self.cx is None else self.cx
        cy = self.height / 2 if self.cy is None else self.cy
        return cx, cy


class HeaderCamera(Camera):
    """A camera a format's header carries (a ``.splatv``'s): a converter's choice of view,
    not the pose of a captured image, so a viewer trusts it less (framing.opening_view).

    Equal to (and hashed like) the :class:`Camera` with the same fields: the kind is
    where the camera came from, not what it is, and a container stores both alike."""

    @classmethod
    def of(cls, camera: Camera) -> HeaderCamera:
        """``camera`` marked as a header's."""
        return cls.model_validate(camera.model_dump())

    def __eq__(self, other: object) -> bool:
        """Field by field, whatever the kind of either camera."""
        if not isinstance(other, Camera):
            return NotImplemented
        return self.__dict__ == other.__dict__

    __hash__ = Camera.__hash__


def _determinant(r: tuple[Vec3, Vec3, Vec3]) -> float:
    """det of a 3x3 matrix given row by row."""
    return (
        r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1])
        - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
        + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0])
    )


CameraList = Annotated[list[Camera], Field(max_length=MAX_CAMERAS)]


def cameras_from_json(entries: Any, *, where: str) -> list[Camera]:
    """The cameras of a 3DGS ``cameras.json`` list (``id``/``img_name``/``width``/``height``/
    ``position``/``rotation``/``fx``/``fy``; other keys ignored), in file order.

    A list longer than :data:`MAX_CAMERAS` is refused; a bad entry raises a MetaError naming
    it (``[3].rotation``)."""
    if not isinstance(entries, list) or not entries:
        raise FormatError("expected a non-empty JSON list of cameras", where=where)
    if len(entries) > MAX_CAMERAS:
        raise FormatError(
            f"{len(entries)} cameras, more than the {MAX_CAMERAS} a scene may carry", where=where
        )
    return [_json_camera(entry, i, where) for i, entry in enumerate(entries)]


_JSON_KEYS = ("width", "height", "fx", "fy", "cx", "cy", "position", "rotation")


def _json_camera(entry: Any, index: int, where: str) -> Camera:
    """One cameras.json entry as a Camera."""
    if not isinstance(entry, dict):
        raise FormatError(f"camera {index} is not a JSON object", where=where)
    fields = {key: entry[key] for key in _JSON_KEYS if key in entry}
    name = entry.get("img_name", entry.get("id", ""))
    fields["name"] = str(name)[:NAME_MAX] if isinstance(name, str | int) else ""
    for side in ("width", "height"):  # some writers store sizes as 1959.0
        value = fields.get(side)
        if isinstance(value, float) and value.is_integer():
            fields[side] = int(value)
    try:
        return Camera.model_validate(fields)
    except ValidationError as exc:
        raise to_meta_error(exc, prefix=f"[{index}]", where=where) from None
