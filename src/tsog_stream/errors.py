"""The one error tree of tsog-stream.

Every bad input, broken file or failed transfer surfaces as a :class:`TsogError`;
lower-level exceptions (``struct.error``, Pillow's ``OSError``, ``zipfile.BadZipFile``,
pydantic's ``ValidationError``) are translated where they are raised::

    TsogError
    ├── InputError          a caller passed an invalid argument or an impossible option
    ├── FormatError         bytes that do not follow a format (PLY, SOG, TSOG, zip, WebP)
    │   ├── PlyError
    │   ├── SogError
    │   │   └── MetaError   meta.json that fails its schema (names the field)
    │   └── UnsupportedError  a valid file using a feature we do not implement
    ├── IntegrityError      content that contradicts itself (sizes, hashes, counts)
    └── SourceError         a file or remote source could not be read or written
        └── AccessError     a private scene asked for without a valid signed URL (HTTP 403)
"""

from __future__ import annotations

from typing import Any


class TsogError(Exception):
    """Base of every error tsog-stream raises on purpose; ``where`` names the file (and the
    field or byte offset) so a message says what was expected, what was found, and where."""

    def __init__(self, message: str, *, where: str | None = None) -> None:
        self.message = printable(message)
        self.where = None if where is None else printable(where)
        super().__init__(f"{self.where}: {self.message}" if where else self.message)

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickle by state, not by constructor arguments: an error raised in a worker process
        reaches the parent whole."""
        return (_rebuild, (type(self), self.args, self.__dict__))


def printable(text: str) -> str:
    """``text`` with non-printable characters as ``\\xNN`` escapes: messages quote hostile text
    (a server's error body, a file name), which must not reach a terminal or a log raw."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else ascii(c)[1:-1] for c in text)


def _rebuild(cls: type[TsogError], args: tuple[Any, ...], state: dict[str, Any]) -> TsogError:
    """A TsogError of class ``cls`` with the given args and attributes."""
    error = cls.__new__(cls)
    error.args = args
    error.__dict__.update(state)
    return error


class InputError(TsogError):
    """An argument or option that cannot be honoured (bad time, bad budget, wrong shape)."""


class FormatError(TsogError):
    """Bytes that do not follow the format they claim to be."""


class PlyError(FormatError):
    """A PLY header or body that cannot be read."""


class SogError(FormatError):
    """A SOG/TSOG chunk (zip, images, meta.json) that cannot be read."""


class MetaError(SogError):
    """A meta.json that fails schema validation; ``field`` is the dotted path of the culprit."""

    def __init__(self, message: str, *, field: str, where: str | None = None) -> None:
        self.field = field
        super().__init__(f"field '{field}': {message}", where=where)


class UnsupportedError(FormatError):
    """A well-formed file that uses a feature this version does not support."""


class IntegrityError(TsogError):
    """Content that contradicts itself: sizes, counts or hashes that do not agree."""


class SourceError(TsogError):
    """A file, folder or remote source that could not be read or written."""


class AccessError(SourceError):
    """A private resource asked for without a valid, unexpired signed URL (HTTP 403)."""


__all__ = [
    "AccessError",
    "FormatError",
    "InputError",
    "IntegrityError",
    "MetaError",
    "PlyError",
    "SogError",
    "SourceError",
    "TsogError",
    "UnsupportedError",
]
