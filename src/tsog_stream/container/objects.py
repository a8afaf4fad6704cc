"""Containers in object storage: ranged reads, and writes that never leave half an object.

:class:`ObjectSource` is a byte source over one object (a ranged GET per read). ``s3://`` is
written as a multipart upload while it is encoded; its first part (the prefix the header and
index fill at the end) is held and uploaded last, then the upload completed: the object appears
whole or not at all, any failure aborts it (parts of a killed run stay invisible until a bucket
rule, ``AbortIncompleteMultipartUpload``, removes them). Memory held: two parts. Other fsspec
stores get the container built in a local temp file and copied with one ``put_file``.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import tempfile
from collections.abc import Iterator
from typing import Any, cast

from ..errors import SourceError
from ..io.files import check_output
from ..io.objects import ObjectPath, is_object_url, object_at, store_errors
from .ranges import ByteRange
from .sources import ReadStats, counted
from .writer import PayloadWriter, container_file

PART_SIZE = 8 << 20
"""Bytes of the first upload parts (S3 wants at least 5 MiB for every part but the last)."""
MIN_PART_SIZE = 5 << 20
MAX_PARTS = 10_000
"""S3's limit on the parts of one upload."""
PARTS_PER_SIZE = 2_000
"""Parts at one size before it doubles: 484 GiB by part 10000 (8 MiB parts: 78 GiB)."""


def part_size(number: int, first: int = PART_SIZE) -> int:
    """Bytes of upload part ``number`` (1-based): ``first``, doubled every PARTS_PER_SIZE."""
    return first << min((number - 1) // PARTS_PER_SIZE, 4)


class ObjectSource:
    """A byte source over one stored object: each read is one ranged GET."""

    def __init__(self, url: str | ObjectPath) -> None:
        self.object = object_at(url)
        self.name = str(self.object)
        self.stats = ReadStats()
        self._size: int | None = None

    def _info_size(self) -> int:
        with store_errors(self.name):
            info = self.object.fs.info(self.object.path)
        if info.get("type") != "file":
            raise SourceError("is a prefix (a folder), expected an object", where=self.name)
        return int(info["size"])

    async def size(self) -> int:
        """The object's length (asked once)."""
        if self._size is None:
            self._size = await asyncio.to_thread(self._info_size)
        return self._size

    def _cat(self, span: ByteRange) -> bytes:
        with store_errors(self.name):
            return cast(
                bytes, self.object.fs.cat_file(self.object.path, start=span.start, end=span.end)
            )

    async def read(self, span: ByteRange) -> bytes:
        """The bytes of ``span`` (a SourceError if the object is shorter)."""
        return counted(await asyncio.to_thread(self._cat, span) if span.length else b"", span, self)


class MultipartObject:
    """A container written as an S3 multipart upload whose first part goes up last: a
    :class:`~.writer.Sink` whose seeks back may only land in that part."""

    def __init__(self, target: ObjectPath, part_size: int = PART_SIZE) -> None:
        if part_size < MIN_PART_SIZE:
            raise ValueError(f"parts must be at least {MIN_PART_SIZE} bytes")
        self.target = target
        self.part_size = part_size
        bucket, key, _ = cast(Any, target.fs).split_path(target.path)
        self.bucket: str = bucket
        self.key: str = key
        self.head = bytearray()
        """Part 1, held until the end."""
        self.tail = bytearray()
        """The part being filled."""
        self.length = 0
        self.position = 0
        self.upload_id: str | None = None
        self.parts: list[dict[str, Any]] = []

    def _call(self, method: str, **kwargs: Any) -> dict[str, Any]:
        s3: Any = self.target.fs
        with store_errors(str(self.target), "write"):
            reply = s3.call_s3(method, Bucket=self.bucket, Key=self.key, **kwargs)
        return cast("dict[str, Any]", reply)

    def _upload_part(self, number: int, body: bytes) -> None:
        if self.upload_id is None:
            self.upload_id = cast(str, self._call("create_multipart_upload")["UploadId"])
        done = self._call("upload_part", UploadId=self.upload_id, PartNumber=number, Body=body)
        self.parts.append({"PartNumber": number, "ETag": done["ETag"]})

    def write(self, data: bytes, /) -> int:
        """Patch the first part, or append (a full part goes up at once)."""
        view = memoryview(data)
        if self.position < self.length:
            end = self.position + len(view)
            if end > len(self.head):
                raise SourceError("a container write went back beyond its first part")
            self.head[self.position : end] = view
            self.position = end
            return len(view)
        room = max(0, self.part_size - len(self.head))
        self.head += view[:room]
        self.tail += view[room:]
        self.length += len(view)
        self.position = self.length
        number = len(self.parts) + 2
        if len(self.tail) >= part_size(number, self.part_size):
            if number >= MAX_PARTS:
                raise SourceError(f"over {MAX_PARTS} upload parts: too large for one object")
            self._upload_part(number, bytes(self.tail))
            self.tail = bytearray()
        return len(view)

    def seek(self, offset: int, /) -> int:
        """Go back into the first part, or to the end."""
        if offset != self.length and offset > len(self.head):
            raise SourceError("a container write went back beyond its first part")
        self.position = offset
        return offset

    def truncate(self) -> int:
        """Nothing to cut: the writer truncates only at the end."""
        if self.position != self.length:
            raise SourceError("a container may only be cut at its end")
        return self.length

    def commit(self) -> None:
        """Publish: one PUT for a small object, else the last parts, part 1, and completion."""
        if self.upload_id is None and not self.parts:
            self._call("put_object", Body=bytes(self.head + self.tail))
            return
        if self.tail:
            self._upload_part(len(self.parts) + 2, bytes(self.tail))
        self._upload_part(1, bytes(self.head))
        parts = sorted(self.parts, key=lambda p: int(p["PartNumber"]))
        self._call(
            "complete_multipart_upload",
            UploadId=self.upload_id,
            MultipartUpload={"Parts": parts},
        )

    def abort(self) -> None:
        """Drop the parts uploaded so far (nothing appears at the destination)."""
        if self.upload_id is not None:
            with contextlib.suppress(SourceError):
                self._call("abort_multipart_upload", UploadId=self.upload_id)


def _is_s3(target: ObjectPath) -> bool:
    protocol = cast(Any, target.fs).protocol
    names = (protocol,) if isinstance(protocol, str) else tuple(protocol)
    return "s3" in names or "s3a" in names


@contextlib.contextmanager
def _multipart(target: ObjectPath) -> Iterator[PayloadWriter]:
    upload = MultipartObject(target)
    try:
        yield PayloadWriter(upload)
        upload.commit()
    except BaseException:
        upload.abort()
        raise


@contextlib.contextmanager
def _staged(target: ObjectPath) -> Iterator[PayloadWriter]:
    """Build in a local temp file, then copy it to the store in one go."""
    with tempfile.TemporaryDirectory(prefix=".tsogs-upload-") as folder:
        local = os.path.join(folder, target.name or "container.tsogs")
        with container_file(local) as out:
            yield out
        with store_errors(str(target), "write"):
            target.fs.put_file(local, target.path)


@contextlib.contextmanager
def container_output(target: str | os.PathLike[str]) -> Iterator[PayloadWriter]:
    """A container being written to a path or storage URL: published whole on success,
    nothing at the destination on failure."""
    if not is_object_url(target):
        with container_file(target) as out:
            yield out
        return
    where = object_at(target)
    with _multipart(where) if _is_s3(where) else _staged(where) as out:
        yield out


def put_objects(base: str, files: dict[str, bytes], *, overwrite: bool) -> None:
    """Publish a folder layout under the prefix ``base``: every file but the first named
    (``manifest.json``) first, that one last, so a reader finds either nothing or all of it;
    on failure the objects written are removed."""
    root = object_at(base)
    names = list(files)
    first = names[0]
    check_output(str(root / first), overwrite=overwrite)
    written: list[ObjectPath] = []
    try:
        for name in [*names[1:], first]:
            obj = root / name
            with store_errors(str(obj), "write"):
                root.fs.pipe_file(obj.path, files[name])
            written.append(obj)
    except BaseException:
        for obj in written:
            with contextlib.suppress(Exception):
                root.fs.rm_file(obj.path)
        raise
