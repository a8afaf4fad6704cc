"""The architecture, checked where import-linter cannot: the floors and the services'
independence are contracts in pyproject.toml (``lint-imports``, run by scripts/check); here,
what no import graph shows: a sans-I/O format layer that opens no file and loads nothing of
the rest when imported, no two modules importing each other (a package and its own
modules included), and one pinned public API (the PMTiles and httpx habits of
../shared/STYLE.md)."""

from __future__ import annotations

import ast
import subprocess
import sys
import tomllib
from pathlib import Path
from typing import Any

import grimp
import pytest

import tsog_stream

PACKAGE = Path(tsog_stream.__file__).parent
CONTRACTS: dict[str, dict[str, Any]] = {
    c["id"]: c
    for c in tomllib.loads((PACKAGE.parents[1] / "pyproject.toml").read_text())["tool"][
        "importlinter"
    ]["contracts"]
}
"""The import-linter contracts of pyproject.toml, by id: the floors are stated once, there."""


def _layer_names(layer: str) -> list[str]:
    """The modules of one layer of a layers contract (``a | b`` or ``a : b``)."""
    return [name.strip() for name in layer.replace(":", "|").split("|")]


FORMAT_MODULES: list[str] = sorted(CONTRACTS["sans-io"]["source_modules"])
"""Modules (or packages) that turn bytes into values and back and do no I/O themselves."""
FORMAT_LAYER = [
    path.relative_to(PACKAGE).as_posix()
    for module in FORMAT_MODULES
    for tail in [module.removeprefix("tsog_stream.").replace(".", "/")]
    for path in (
        sorted((PACKAGE / tail).glob("*.py"))
        if (PACKAGE / tail).is_dir()
        else [PACKAGE / f"{tail}.py"]
    )
]
"""Every file of the format layer."""
FORMAT_IMPORTS = [
    "tsog_stream." + name.removesuffix(".py").removesuffix("/__init__").replace("/", ".")
    for name in FORMAT_LAYER
]
"""The module name of each file of the format layer."""
OS_ALLOWED = {"register_at_fork", "sched_getaffinity", "cpu_count"}
"""The only names of ``os`` the format layer may use: making new thread pools in a forked
child, and asking the kernel which cores the process may run on to size them (a container's
quota, read from cgroup files, is the caller's to say: webp.use_cores)."""
KNOWN_CIRCLES: set[tuple[str, str]] = set()
"""Pairs of modules that still import each other (also ignored by the contract "no-circles")."""
PUBLIC = [
    "AccessError",
    "FormatError",
    "Gaussians",
    "HttpOptions",
    "InputError",
    "InputOptions",
    "InputReport",
    "IntegrityError",
    "LiveOptions",
    "LiveReport",
    "MetaError",
    "PlyError",
    "ReadOptions",
    "Scene",
    "SegmentOptions",
    "SegmentReport",
    "SogError",
    "SourceError",
    "Stream",
    "StreamClient",
    "Timeline",
    "TimelineType",
    "TsogError",
    "UnsupportedError",
    "__version__",
    "decode_chunk",
    "encode_chunk",
    "load_scene",
    "open_stream",
    "read_chunk",
    "run_live",
    "segment_input",
    "segment_scene",
    "write_ply",
]


def test_the_format_layer_is_found() -> None:
    assert {"codec/chunk.py", "container/header.py", "schemas/manifest.py"} <= set(FORMAT_LAYER)
    assert all((PACKAGE / name).is_file() for name in FORMAT_LAYER)


@pytest.mark.parametrize("name", FORMAT_LAYER)
def test_the_format_layer_opens_no_file(name: str) -> None:
    """What it imports is the contract "sans-io"; what it calls is checked here."""
    tree = ast.parse((PACKAGE / name).read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
            assert node.func.id != "open", f"{name}:{node.lineno} opens a file"
        elif (
            isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name)
            and node.value.id == "os"
        ):
            assert node.attr in OS_ALLOWED, f"{name}:{node.lineno} uses os.{node.attr}"


def test_importing_the_format_layer_loads_no_client_server_or_files() -> None:
    """Imported in a fresh interpreter, the format layer loads neither asyncio nor aiohttp,
    and of this package only the floors below it (the core) and itself: what a contract
    cannot see (the stdlib's own imports, the package face's lazy names)."""
    code = (
        "import sys\n"
        + "".join(f"import {m}\n" for m in FORMAT_IMPORTS)
        + "print('\\n'.join(sorted(sys.modules)))"
    )
    loaded = set(
        subprocess.run(
            [sys.executable, "-c", code], check=True, capture_output=True, text=True
        ).stdout.split()
    )
    assert not {"asyncio", "aiohttp"} & loaded
    layers = CONTRACTS["floors"]["layers"]
    below = [n for layer in layers[layers.index("codec") :] for n in _layer_names(layer)]
    allowed = [*(f"tsog_stream.{n}" for n in below), *FORMAT_MODULES]
    mine = {m for m in loaded if m.startswith("tsog_stream.")}
    assert {m for m in mine if not any(m == a or m.startswith(a + ".") for a in allowed)} <= {
        "tsog_stream.container"
    }


def test_no_two_modules_import_each_other() -> None:
    """Direct circles of two modules, a package and its own modules among them (the contract
    "no-circles" sees circles between siblings only)."""
    graph = grimp.build_graph("tsog_stream", cache_dir=None)
    circles = {
        (a, b)
        for a in graph.modules
        for b in graph.find_modules_directly_imported_by(a)
        if a < b and a in graph.find_modules_directly_imported_by(b)
    }
    assert circles == KNOWN_CIRCLES, "mended circles leave KNOWN_CIRCLES (and the contract)"


def test_the_public_api_is_pinned() -> None:
    assert tsog_stream.__all__ == PUBLIC
    assert sorted(dir(tsog_stream)) == sorted(PUBLIC)
    for name in PUBLIC:
        assert getattr(tsog_stream, name) is not None
    assert issubclass(tsog_stream.AccessError, tsog_stream.SourceError)
    with pytest.raises(AttributeError):
        _ = tsog_stream.StreamReader  # the second reader is gone


def test_a_format_import_does_not_load_the_public_names_it_does_not_use() -> None:
    code = "import sys, tsog_stream.container.header; print('aiohttp' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    assert out.stdout.strip() == "False"
