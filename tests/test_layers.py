"""The architecture, checked: floors that no import runs up, a sans-I/O format layer, and one
pinned public API (the zarr/PMTiles and httpx habits of ../shared/STYLE.md)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

import tsog_stream

PACKAGE = Path(tsog_stream.__file__).parent

FLOORS: dict[str, int] = {
    # the core: constants, errors, the in-memory model and its pure numeric helpers
    **dict.fromkeys(
        (
            "_version",
            "constants",
            "errors",
            "machine",
            "morton",
            "columns",
            "inplace",
            "model",
            "temporal",
            "opacity",
            "quantize",
            "sh_palette",
            "signing",
            "schemas",
            "compare",
            "synthetic",
            "framing",
        ),
        0,
    ),
    "codec": 1,  # bytes <-> scenes, sans-I/O
    "summary": 2,
    "io": 2,  # files of every format
    "container": 3,  # the .tsogs format (sans-I/O), byte sources, the writer
    "merge": 4,
    "render": 4,  # the CPU renderer: segment measures its layers with it
    # services: none of them imports another
    "segment": 5,
    "client": 5,
    "server": 5,
    "inputs": 6,  # any input as a scene at time t (io + client)
    "throttled_play": 6,  # a playback over a shaped link (server + client + render)
    "demo": 6,
    "cli": 7,
}
"""Floor of each top-level module or package of tsog_stream: a module imports only from its
own floor or below, and services (floor 5) import no other service."""

FORMAT_LAYER = (
    "container/header.py",
    "container/index.py",
    "container/ranges.py",
    "container/stream_index.py",
    *(f"codec/{p.name}" for p in sorted((PACKAGE / "codec").glob("*.py"))),
    *(f"schemas/{p.name}" for p in sorted((PACKAGE / "schemas").glob("*.py"))),
)
"""Modules that turn bytes into values and back and must do no I/O themselves."""
IO_MODULES = {"pathlib", "asyncio", "aiohttp", "socket", "shutil", "tempfile", "subprocess"}
OS_ALLOWED = {"register_at_fork"}
"""The only name of ``os`` the format layer may use (making new thread pools in a forked child;
it sizes them by machine.usable_cores)."""
PUBLIC = [
    "AccessError",
    "FormatError",
    "Gaussians",
    "HttpOptions",
    "InputError",
    "IntegrityError",
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
    "segment_scene",
    "write_ply",
]


def _top(module: str) -> str:
    """The top-level module or package of a dotted name under tsog_stream."""
    return module.split(".", maxsplit=1)[0] or "__init__"


def _internal_imports(path: Path) -> list[tuple[int, str]]:
    """(line, absolute name under tsog_stream) of every relative import in a module."""
    rel = path.relative_to(PACKAGE).with_suffix("")
    package = list(rel.parts[:-1])
    tree = ast.parse(path.read_text())
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level > 0:
            base = package[: len(package) - (node.level - 1)]
            target = ".".join([*base, *(node.module.split(".") if node.module else [])])
            found.append((node.lineno, target))
    return found


def test_no_import_runs_up_a_floor() -> None:
    wrong = []
    for path in sorted(PACKAGE.rglob("*.py")):
        here = _top(".".join(path.relative_to(PACKAGE).with_suffix("").parts))
        if here == "__init__":
            continue  # the public face: its imports are lazy (PEP 562)
        for line, target in _internal_imports(path):
            there = _top(target)
            if there in ("", "__init__") or there == here:
                continue
            up = FLOORS[there] > FLOORS[here]
            sideways = FLOORS[there] == FLOORS[here] == 5
            if up or sideways:
                wrong.append(f"{path.relative_to(PACKAGE)}:{line} imports {target}")
    assert not wrong, "imports that run up (or across services):\n" + "\n".join(wrong)


def test_every_module_has_a_floor() -> None:
    tops = {
        p.stem if p.parent == PACKAGE else p.relative_to(PACKAGE).parts[0]
        for p in PACKAGE.rglob("*.py")
    }
    assert tops - {"__init__"} == set(FLOORS)


@pytest.mark.parametrize("name", FORMAT_LAYER)
def test_the_format_layer_does_no_io(name: str) -> None:
    tree = ast.parse((PACKAGE / name).read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            assert not {a.name.split(".")[0] for a in node.names} & IO_MODULES, name
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            assert node.module.split(".")[0] not in IO_MODULES, name
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
            assert node.func.id != "open", f"{name}:{node.lineno} opens a file"
        elif (
            isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name)
            and node.value.id == "os"
        ):
            assert node.attr in OS_ALLOWED, f"{name}:{node.lineno} uses os.{node.attr}"


def test_importing_the_format_layer_loads_no_client_server_or_files() -> None:
    modules = [f"tsog_stream.{m[:-3].replace('/', '.')}" for m in FORMAT_LAYER]
    code = (
        "import sys\n"
        + "".join(f"import {m}\n" for m in modules)
        + "print('\\n'.join(sorted(sys.modules)))"
    )
    loaded = set(
        subprocess.run(
            [sys.executable, "-c", code], check=True, capture_output=True, text=True
        ).stdout.split()
    )
    assert not {"asyncio", "aiohttp"} & loaded
    mine = {m for m in loaded if m.startswith("tsog_stream.")}
    allowed = {"tsog_stream._version", *(f"tsog_stream.{k}" for k, v in FLOORS.items() if v < 2)}
    assert {m for m in mine if not any(m == a or m.startswith(a + ".") for a in allowed)} <= {
        "tsog_stream.container",
        *modules,
    }


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
