"""pipeline.atomic: a writer that fails midway leaves neither the file nor a temporary behind,
and an existing target keeps its old content."""

import json

import numpy as np
import pytest

from pipeline import atomic, shards


class Boom(RuntimeError):
    pass


def test_file_writer_raising_midway_leaves_nothing(tmp_path):
    target = tmp_path / "sub" / "out.bin"
    with pytest.raises(Boom):
        with atomic.atomic_path(target) as tmp:
            tmp.write_bytes(b"half")
            raise Boom
    assert not target.exists()
    assert list(target.parent.iterdir()) == []   # no temporary left


def test_failed_rewrite_keeps_the_old_file(tmp_path):
    target = atomic.write_text(tmp_path / "out.txt", "old\n")
    with pytest.raises(Boom):
        with atomic.atomic_path(target, suffix=".png") as tmp:
            tmp.write_text("new")
            raise Boom
    assert target.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_json_that_cannot_be_encoded_writes_nothing(tmp_path):
    with pytest.raises(TypeError):
        atomic.write_json(tmp_path / "m.json", {"x": object()})
    assert list(tmp_path.iterdir()) == []
    atomic.write_json(tmp_path / "m.json", {"x": np.float32(0.5), "a": np.arange(2)})
    assert json.loads((tmp_path / "m.json").read_text()) == {"x": 0.5, "a": [0, 1]}


def test_folder_writer_raising_midway_leaves_the_old_folder(tmp_path):
    target = tmp_path / "model"
    target.mkdir()
    (target / "weights").write_text("old")
    with pytest.raises(Boom):
        with atomic.atomic_dir(target) as tmp:
            (tmp / "weights").write_text("new, half")
            raise Boom
    assert (target / "weights").read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["model"]


def test_shard_writers_are_the_atomic_ones(tmp_path):
    assert shards.write_json is atomic.write_json and shards.atomic_path is atomic.atomic_path
    with pytest.raises(Exception):
        shards.write_table(tmp_path / "shard-00000.parquet", [{"a": 1}, {"a": "x"}])  # mixed types: pyarrow raises
    assert list(tmp_path.iterdir()) == []
