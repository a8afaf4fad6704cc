"""The error tree: every TsogError, whatever its constructor, crosses a process boundary whole
(the segmenter encodes in worker processes; an error there must reach the user as its line)."""

from __future__ import annotations

import pickle
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest
from aiohttp import web

from helpers import ThreadedServer
from tsog_stream import errors
from tsog_stream.cli.main import main
from tsog_stream.server import catalog  # noqa: F401  # defines NotFoundError and BusyError
from tsog_stream.server.respond import LIMITS, Limits


def every_error_class() -> list[type[errors.TsogError]]:
    """TsogError and all its subclasses, however deep."""
    found: list[type[errors.TsogError]] = []
    todo: list[type[errors.TsogError]] = [errors.TsogError]
    while todo:
        cls = todo.pop()
        found.append(cls)
        todo.extend(cls.__subclasses__())
    return sorted(found, key=lambda c: c.__name__)


def example(cls: type[errors.TsogError]) -> errors.TsogError:
    """An instance made the way the code raises it."""
    if issubclass(cls, errors.MetaError):
        return cls("expected an integer, got 'x'", field="count", where="scene/meta.json")
    return cls("expected 3 channels, got 2", where="scene.ply byte 104")


def fail(cls: type[errors.TsogError]) -> None:
    """Raise the example error of ``cls`` (in a worker process)."""
    raise example(cls)


def test_the_tree_is_the_documented_one() -> None:
    names = {c.__name__ for c in every_error_class()}
    assert names >= {"InputError", "FormatError", "MetaError", "IntegrityError", "AccessError"}
    documented = [c for c in every_error_class() if c.__module__ == errors.__name__]
    assert all(c.__name__ in (errors.__doc__ or "") for c in documented)


@pytest.mark.parametrize("cls", every_error_class(), ids=lambda c: c.__name__)
def test_every_error_pickles_whole(cls: type[errors.TsogError]) -> None:
    original = example(cls)
    back = pickle.loads(pickle.dumps(original))
    assert type(back) is cls and str(back) == str(original)
    assert (back.message, back.where) == (original.message, original.where)
    assert vars(back) == vars(original)


def test_an_error_raised_in_a_worker_process_reaches_the_parent_whole() -> None:
    with ProcessPoolExecutor(1) as pool:
        for cls in every_error_class():
            with pytest.raises(cls) as caught:
                pool.submit(fail, cls).result(timeout=60)
            assert str(caught.value) == str(example(cls))


def test_messages_are_safe_to_print() -> None:
    hostile = "\x1b[2J\x1b[31mpwned\r\ntsog: error: forged line\x07"
    error = errors.SourceError(hostile, where="name\nwith\tcontrols")
    assert str(error).isprintable() and "\\x1b[2J" in str(error)
    assert error.message.isprintable() and error.where == "name\\nwith\\tcontrols"


def test_a_hostile_servers_403_text_reaches_the_terminal_escaped(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    async def forbidden(request: web.Request) -> web.Response:
        body = {"error": {"status": 403, "message": "\x1b[2Jno\r\ntsog: error: forged"}}
        return web.json_response(body, status=403)

    app = web.Application()
    app[LIMITS] = Limits()
    app.router.add_get("/{path:.*}", forbidden)
    server = ThreadedServer(app)
    try:
        url = f"http://127.0.0.1:{server.port}/clip.tsogs"
        assert main(["fetch", url, "--t", "0", "-o", str(tmp_path / "f.ply"), "-q"]) == 1
    finally:
        server.stop()
    err = capsys.readouterr().err
    assert "\x1b" not in err and len(err.strip().splitlines()) == 1 and "HTTP 403" in err
