"""Stage outputs read back: an interrupted stage is an error, not a silent subset (issue 12)."""

from __future__ import annotations

import pytest

from pipeline import shards


def _stage(tmp_path, n_shards: int, meta: bool):
    out = tmp_path / "render"
    for s in range(n_shards):
        shards.write_table(shards.shard_path(out, s, "parquet"),
                           [{"scene_id": shards.scene_id(100 * s + i), "x": float(i)} for i in range(100)])
    if meta:
        shards.write_meta(out, {"shards": {"shard": 4}})
    return out


def test_reader_refuses_an_interrupted_stage(tmp_path):
    """After `kill -9` in the middle of render, 1 of 4 shards was there and no meta.json:
    readers saw 100 of 360 rows without an error."""
    out = _stage(tmp_path, 1, meta=False)
    with pytest.raises(shards.ShardError, match=r"meta.json: missing: the stage .* did not finish \(1 shard"):
        shards.read_table(out)


def test_reader_checks_the_shard_count(tmp_path):
    out = _stage(tmp_path, 2, meta=True)
    with pytest.raises(shards.ShardError, match="meta.json lists 4 shard shards, found 2"):
        shards.read_table(out)
    out4 = _stage(tmp_path / "b", 4, meta=True)
    assert shards.read_table(out4).num_rows == 400
