"""The error tree: every TsogError, whatever its constructor, crosses a process boundary whole
(the segmenter encodes in worker processes; an error there must reach the user as its line)."""

from __future__ import annotations

import pickle
from concurrent.futures import ProcessPoolExecutor

import pytest

from tsog_stream import errors
from tsog_stream.server import catalog  # noqa: F401  # defines NotFoundError and BusyError


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
