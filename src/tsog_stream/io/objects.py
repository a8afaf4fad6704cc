"""Object storage through fsspec: ``s3://``, ``gs://``, ``memory://`` ... URLs as inputs.

An :class:`ObjectPath` stands where a local :class:`~pathlib.Path` would (the subset the readers
use: name, parent, ``/``, is_dir/is_file/exists, iterdir, glob), so a frame sequence in a bucket
is scanned and read frame by frame like a local folder: only the frames of the window being
encoded are ever in memory. fsspec and its backends (s3fs for ``s3://``: the extra
``tsog-stream[s3]``) are imported on first use; every failure of the store becomes one
:class:`~tsog_stream.errors.SourceError` line naming the URL. Credentials and endpoints come
from the backend's usual settings (for S3: ``AWS_ACCESS_KEY_ID``, ``AWS_ENDPOINT_URL``, ...).
"""

from __future__ import annotations

import contextlib
import os
import re
from collections.abc import Iterator
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Any, BinaryIO, cast

from ..errors import InputError, SourceError, TsogError

if TYPE_CHECKING:
    from fsspec import AbstractFileSystem

EXTRA = "s3"
"""The optional dependency group that brings fsspec and s3fs."""
LOCAL_SCHEMES = frozenset({"", "file", "local"})
WEB_SCHEMES = frozenset({"http", "https"})
"""Read by the project's own HTTP client (client/http_source.py), not through fsspec."""
_SCHEME = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]+)://")


def scheme_of(text: str | os.PathLike[str]) -> str:
    """The URL scheme of ``text`` in lower case ("" for a plain path; a drive letter is none)."""
    m = _SCHEME.match(os.fspath(text)) if isinstance(text, str) else None
    return m.group(1).lower() if m else ""


def is_object_url(text: object) -> bool:
    """True for a URL fsspec reads (``s3://``, ``gs://``, ``memory://`` ...): neither a local
    path nor ``file://`` nor ``http(s)://``."""
    if isinstance(text, ObjectPath):
        return True
    if not isinstance(text, str):
        return False
    scheme = scheme_of(text)
    return scheme not in LOCAL_SCHEMES and scheme not in WEB_SCHEMES


def _import_fsspec() -> Any:
    try:
        import fsspec  # noqa: PLC0415 - optional (extra s3), loaded on first use
    except ImportError:
        raise InputError(
            f"object storage needs the {EXTRA} extra: pip install 'tsog-stream[{EXTRA}]'"
        ) from None
    return fsspec


def filesystem(url: str) -> tuple[AbstractFileSystem, str]:
    """The fsspec filesystem for ``url`` and the path within it, or a one-line error: an
    InputError for a protocol fsspec does not know, whose backend is not installed or that
    needs settings the URL does not give; a SourceError for a store that cannot be reached
    (some backends, such as ftp://, connect as the filesystem is made)."""
    fsspec = _import_fsspec()
    scheme = scheme_of(url) or url.split("::", 1)[0]
    try:
        fsspec.get_filesystem_class(scheme)
        fs, path = fsspec.core.url_to_fs(url)
    except ImportError as exc:
        raise InputError(
            f"{scheme}:// is not available here ({_first_line(exc, named=False)}); "
            f"for s3:// pip install 'tsog-stream[{EXTRA}]'",
            where=url,
        ) from None
    except UnicodeError as exc:  # a ValueError, but sent by a peer that is not the store
        raise store_error(exc, url, "connect") from None
    except (ValueError, TypeError) as exc:
        raise InputError(
            f"not a storage URL fsspec can open: {_first_line(exc)}", where=url
        ) from None
    except TsogError:
        raise
    except Exception as exc:
        raise store_error(exc, url, "connect") from None
    return cast("AbstractFileSystem", fs), cast(str, path)


MAX_REASON = 300
"""Characters of a store's own message kept in an error line (some quote whole requests)."""


def _first_line(exc: BaseException, *, named: bool = True) -> str:
    """The first line of ``exc``'s message (cut at MAX_REASON), after its class name."""
    lines = str(exc).strip().splitlines()
    text = lines[0][:MAX_REASON] if lines else ""
    if not named:
        return text or type(exc).__name__
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def store_error(exc: Exception, where: str, doing: str = "read") -> SourceError:
    """The one-line SourceError for a failure of a store or its transport while ``doing``."""
    if isinstance(exc, FileNotFoundError) and doing == "read":
        return SourceError("no such object", where=where)
    if isinstance(exc, PermissionError):
        return SourceError(f"access denied: {_first_line(exc)}", where=where)
    if isinstance(exc, TimeoutError):
        return SourceError(f"cannot {doing}: timed out ({_first_line(exc)})", where=where)
    return SourceError(f"cannot {doing}: {_first_line(exc)}", where=where)


@contextlib.contextmanager
def store_errors(where: str, doing: str = "read") -> Iterator[None]:
    """Turn whatever a store or its transport raises (OSError, a timeout, botocore's or
    requests' own errors, a backend's ValueError ...) into one SourceError line; the
    project's own errors pass through. Caught here, at the store boundary, because every
    backend has exceptions of its own and a user of any of them is owed one line."""
    try:
        yield
    except TsogError:
        raise
    except Exception as exc:
        raise store_error(exc, where, doing) from None


class ObjectPath:
    """An object or prefix in a store, with the Path methods the readers use."""

    def __init__(self, fs: AbstractFileSystem, path: str, url: str) -> None:
        self.fs = fs
        self.path = path.rstrip("/")
        self.url = url.rstrip("/") if self.path.strip("/") else url

    @classmethod
    def from_url(cls, url: str) -> ObjectPath:
        """The object (or prefix) named by ``url``."""
        fs, path = filesystem(url)
        return cls(fs, path, url)

    def __str__(self) -> str:
        return self.url

    def __repr__(self) -> str:
        return f"ObjectPath({self.url!r})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, ObjectPath) and other.url == self.url

    def __hash__(self) -> int:
        return hash(self.url)

    def _child(self, path: str) -> ObjectPath:
        """The entry at store path ``path`` (the URL rebuilt with the same scheme)."""
        return ObjectPath(self.fs, path, f"{scheme_of(self.url)}://{path.lstrip('/')}")

    def __truediv__(self, name: str) -> ObjectPath:
        return ObjectPath(self.fs, f"{self.path}/{name}", f"{self.url}/{name}")

    name = property(lambda self: PurePosixPath(self.path).name, doc="The last part of the path.")
    stem = property(lambda self: PurePosixPath(self.path).stem, doc="The name without its suffix.")
    suffix = property(lambda self: PurePosixPath(self.path).suffix, doc="The name's last suffix.")

    @property
    def parent(self) -> ObjectPath:
        """The prefix holding this entry."""
        cut = self.url.rsplit("/", 1)[0] if "/" in self.url.split("://", 1)[-1] else self.url
        return ObjectPath(self.fs, str(PurePosixPath(self.path).parent), cut)

    def _kind(self) -> str | None:
        """ "file", "directory" or None when nothing is there."""
        with store_errors(self.url):
            try:
                return cast(str, self.fs.info(self.path).get("type"))
            except FileNotFoundError:
                return None

    def exists(self) -> bool:
        """Whether an object or a non-empty prefix is there."""
        return self._kind() is not None

    def is_dir(self) -> bool:
        """Whether this is a prefix holding objects."""
        return self._kind() == "directory"

    def is_file(self) -> bool:
        """Whether this is one object."""
        return self._kind() == "file"

    def total_bytes(self) -> int:
        """The object's size, or the sum of the sizes under a prefix."""
        with store_errors(self.url, "list"):
            return int(self.fs.du(self.path, total=True))

    def iterdir(self) -> Iterator[ObjectPath]:
        """The entries directly under this prefix."""
        with store_errors(self.url, "list"):
            names = cast(list[str], self.fs.ls(self.path, detail=False))
        for name in names:
            if name.rstrip("/") != self.path:
                yield self._child(name)

    def glob(self, pattern: str) -> list[ObjectPath]:
        """The objects matching a glob ``pattern`` given as a URL (fsspec's glob rules)."""
        _, path = filesystem(pattern)
        with store_errors(pattern, "list"):
            return [self._child(name) for name in cast(list[str], self.fs.glob(path))]

    def open(self) -> BinaryIO:
        """The object opened for reading (seekable, read ahead in blocks)."""
        with store_errors(self.url):
            if self.fs.isdir(self.path):
                raise SourceError("is a folder (a prefix), expected an object", where=self.url)
            return cast(BinaryIO, self.fs.open(self.path, "rb"))

    def read_head(self, limit: int) -> bytes:
        """At most ``limit`` first bytes (all of them for -1)."""
        with store_errors(self.url):
            if limit < 0:
                return cast(bytes, self.fs.cat_file(self.path))
            return cast(bytes, self.fs.cat_file(self.path, start=0, end=limit))


Location = Path | ObjectPath
"""Where an input lives: a local path or an object in a store."""


def as_location(path: str | os.PathLike[str] | ObjectPath) -> Location:
    """A local Path, or an ObjectPath for a storage URL (``file://`` URLs become Paths)."""
    if isinstance(path, ObjectPath):
        return path
    if is_object_url(path):
        return ObjectPath.from_url(cast(str, path))
    text = os.fspath(path)
    if scheme_of(text) in ("file", "local"):
        text = text.split("://", 1)[1]
    return Path(text)


def size_of(location: Location) -> int:
    """Bytes of a local file or of a stored object (or of everything under a prefix)."""
    if isinstance(location, ObjectPath):
        return location.total_bytes()
    return location.stat().st_size


def object_at(path: object) -> ObjectPath:
    """The ObjectPath for a storage URL or ObjectPath (check with :func:`is_object_url`)."""
    if isinstance(path, ObjectPath):
        return path
    if not is_object_url(path):
        raise InputError("not a storage URL", where=str(path))
    return ObjectPath.from_url(cast(str, path))


def check_destination(url: str) -> None:
    """Refuse, before any work, a destination whose bucket (first path part) is missing."""
    target = object_at(url)
    bucket = target.path.strip("/").split("/", 1)[0]
    if "/" not in target.path.strip("/"):
        raise InputError("expected bucket/name after the scheme", where=url)
    with store_errors(url, "write"):  # not fs.exists: it answers False for a store it cannot reach
        try:
            target.fs.info(bucket)
        except FileNotFoundError:
            raise SourceError(f"no bucket {bucket!r} (or no access to it)", where=url) from None


def put_object(url: str, data: bytes) -> None:
    """Store ``data`` as one object in one request (a store publishes it whole or not)."""
    target = object_at(url)
    with store_errors(url, "write"):
        target.fs.pipe_file(target.path, data)


def glob_objects(pattern: str) -> list[ObjectPath]:
    """The objects matching a glob URL such as ``s3://bucket/frames/frame_*.ply``."""
    return ObjectPath.from_url(pattern).glob(pattern)


__all__ = [
    "EXTRA",
    "Location",
    "ObjectPath",
    "as_location",
    "check_destination",
    "filesystem",
    "glob_objects",
    "is_object_url",
    "object_at",
    "put_object",
    "scheme_of",
    "size_of",
    "store_error",
    "store_errors",
]
