"""Splat files of formats this version does not read are refused by name, with the way to one
it reads, whichever command meets them; what only looks like one still gets the generic error.
The files are made here, a few bytes of each format's header (the real ones: ../shared/data's
fixtures and pc_biker.spz, gsplat's .npz files)."""

from __future__ import annotations

import gzip
import io
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest

from tsog_stream import TsogError, UnsupportedError, load_scene
from tsog_stream.cli.main import main

SPZ_HEADER = b"NGSP" + struct.pack("<IIBBBB", 2, 4, 0, 12, 0, 0)
"""An SPZ header: magic, version, count 4, SH degree 0, fractional bits 12, flags, reserved."""


def _npz(arrays: dict[str, np.ndarray]) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)  # type: ignore[arg-type]
    return buffer.getvalue()


FOREIGN = {
    "scan.spz": (gzip.compress(SPZ_HEADER + bytes(64)), "Niantic .spz"),
    "scan_v4.spz": (SPZ_HEADER.replace(b"\x02", b"\x04", 1) + bytes(64), "Niantic .spz"),
    "scene.glb": (b"glTF" + struct.pack("<II", 2, 20) + bytes(8), "glTF binary"),
    "scene.splat": (bytes(32 * 4), "antimatter15 .splat"),
    "scene.KSPLAT": (bytes(4096), "GaussianSplats3D .ksplat"),
    "scene.lcc": (b'{"version": "1"}', "XGRIDS .lcc"),
    "ckpt.npz": (
        _npz({"means3d": np.zeros((4, 3), np.float32), "colors": np.zeros((4, 3), np.uint8)}),
        "NumPy .npz (colors, means3d), not a FreeTimeGS checkpoint",
    ),
}
"""File name -> (bytes, what the error must call it)."""


@pytest.mark.parametrize("name", sorted(FOREIGN))
def test_a_foreign_format_is_refused_by_name_with_the_way_on(name: str, tmp_path: Path) -> None:
    data, called = FOREIGN[name]
    path = tmp_path / name
    path.write_bytes(data)
    with pytest.raises(UnsupportedError) as refused:
        load_scene(path)
    said = str(refused.value)
    assert called in said and str(path) in said
    stem = name.rsplit(".", 1)[0]
    if not name.endswith((".glb", ".npz")):  # splat-transform reads the rest
        assert f"splat-transform {name} {stem}.ply" in said, said
    else:
        assert "PLY" in said


def test_the_command_line_says_it_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "scan.spz"
    path.write_bytes(FOREIGN["scan.spz"][0])
    for argv in (["info", str(path)], ["encode", str(path), str(tmp_path / "o.sog")]):
        assert main([*argv, "-q"]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [err[0]] and err[0].startswith("tsog: error:") and "Niantic .spz" in err[0]
    assert not (tmp_path / "o.sog").exists()


@pytest.mark.parametrize(
    "name, data",
    [
        ("noise.bin", b"\x00\x01garbage" * 8),
        ("zeros.gz", gzip.compress(bytes(64 << 20))),  # a gzip bomb is never inflated past 4 B
        ("broken.gz", b"\x1f\x8b" + b"\xff" * 30),
        ("photo.splat.bak", bytes(32)),
    ],
)
def test_what_only_looks_foreign_gets_the_generic_error(
    name: str, data: bytes, tmp_path: Path
) -> None:
    path = tmp_path / name
    path.write_bytes(data)
    with pytest.raises(UnsupportedError, match="unknown magic bytes"):
        load_scene(path)


def test_a_zip_of_arrays_and_more_is_still_read_as_a_sog_bundle(tmp_path: Path) -> None:
    path = tmp_path / "odd.sog"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("means.npy", b"")
        archive.writestr("notes.txt", b"")
    with pytest.raises(TsogError, match=r"meta\.json"):
        load_scene(path)
