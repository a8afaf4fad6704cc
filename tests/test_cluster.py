"""Segmenting on a Dask cluster (issue 20): real LocalClusters of worker processes on
loopback, the container byte-identical to the one a single process writes, and one-line errors
for a scheduler that is not there."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest
from distributed import LocalCluster

from tsog_stream.cli.main import main
from tsog_stream.client import open_stream
from tsog_stream.codec.bundle import bundle_bytes
from tsog_stream.codec.chunk import encode_chunk
from tsog_stream.errors import InputError
from tsog_stream.model import Scene
from tsog_stream.schemas.manifest import ChunkEntry
from tsog_stream.segment import engines
from tsog_stream.segment.segmenter import SegmentOptions, segment_scene
from tsog_stream.synthetic import SceneSpec, generate_scene

OPTIONS = SegmentOptions(window_s=1.0, policy="hybrid", max_pixels=64 * 64, layers=2)
"""Chunks of unequal sizes and two layers (SH-band chunks too)."""
LOOPBACK = {"host": "127.0.0.1", "dashboard_address": "127.0.0.1:0"}


@pytest.fixture(scope="module")
def scene() -> Scene:
    return generate_scene(SceneSpec(background=3000, objects=4, per_object=300, sh_bands=1))


@pytest.fixture(scope="module")
def reference(scene: Scene, tmp_path_factory: pytest.TempPathFactory) -> bytes:
    """The container one process writes."""
    path = tmp_path_factory.mktemp("reference") / "one.tsogs"
    report = segment_scene(scene, path, OPTIONS)
    assert report.chunks >= 5 and any(c.sh_of is not None for c in _chunks(path))
    return path.read_bytes()


def _chunks(path: Path) -> list[ChunkEntry]:
    with open_stream(path) as reader:
        return list(reader.index.manifest.chunks)


@pytest.fixture(scope="module")
def scheduler() -> Iterator[str]:
    """A running cluster of two single-threaded worker processes, by its scheduler address."""
    with LocalCluster(  # type: ignore[no-untyped-call]
        n_workers=2, threads_per_worker=1, processes=True, **LOOPBACK
    ) as cluster:
        yield str(cluster.scheduler_address)


def test_cli_segment_on_a_cluster_writes_the_same_container(
    scene: Scene, scheduler: str, tmp_path: Path
) -> None:
    """`--cluster ADDRESS`: the jobs run on that cluster's workers, the container is the one
    a single process writes."""
    source = tmp_path / "scene.sog"
    source.write_bytes(bundle_bytes(encode_chunk(scene)))
    argv = ["segment", str(source), "--window", "1s", "--policy", "hybrid", "-q"]
    argv += ["--max-pixels", str(64 * 64), "--layers", "2"]
    paths = {name: tmp_path / f"{name}.tsogs" for name in ("cluster", "one")}
    assert main([*argv, "-o", str(paths["cluster"]), "--cluster", scheduler]) == 0
    assert main([*argv, "-o", str(paths["one"]), "--workers", "1"]) == 0
    assert paths["cluster"].read_bytes() == paths["one"].read_bytes()


def test_a_local_cluster_is_started_for_the_run(
    scene: Scene, reference: bytes, tmp_path: Path
) -> None:
    """``local``: a LocalCluster of --workers processes (one here: the cheapest start)."""
    path = tmp_path / "local.tsogs"
    segment_scene(scene, path, replace(OPTIONS, cluster="local", workers=1))
    assert path.read_bytes() == reference


@pytest.mark.parametrize("address", ["0", "nan", "http://127.0.0.1:8786", "tcp://host"])
def test_a_malformed_cluster_address_is_one_line_before_any_work(
    address: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["segment", str(tmp_path / "missing.sog"), "-o", str(tmp_path / "o.tsogs")]
    assert main([*argv, "--cluster", address]) != 0
    err = capsys.readouterr().err
    assert "--cluster" in err and "scheduler address" in err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_a_scheduler_that_is_not_there_is_one_line(
    scene: Scene, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(engines, "CONNECT_TIMEOUT_S", 1.0)
    options = replace(OPTIONS, cluster="tcp://127.0.0.1:9")  # the discard port: refused
    with pytest.raises(InputError, match="cannot reach the Dask scheduler"):
        segment_scene(scene, tmp_path / "o.tsogs", options)
    assert list(tmp_path.iterdir()) == []  # nothing half-written
