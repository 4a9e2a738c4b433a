"""DVC stage `events`: motion events of every clip and the `<think>` text made from them.

Reads ``paths.traces`` (contacts, velocities and per-frame visible pixel counts, which the
render stage took from the segmentation) and params ``events``
(:class:`pipeline.events.EventConfig`). Writes ``paths.events``: ``events-00000.parquet``
(scene_id, t, frame, kind, objects, force) and ``think-00000.parquet`` (scene_id, split, think),
one of each per traces shard. Shards are processed on the ``compute`` backend
(``pipeline.parallel``), one task per shard.
"""

import pyarrow as pa
from tqdm import tqdm

from pipeline import shards
from pipeline.entry import run_stage
from pipeline.events import EventConfig, events_to_rows, events_to_text, extract_events
from pipeline.parallel import compute_from_params, parallel_map
from pipeline.params import load_params, path_of, typed_section
from pipeline.traces import trace_from_row

EVENTS_SCHEMA = pa.schema([("scene_id", pa.string()), ("t", pa.float64()), ("frame", pa.int32()),
                           ("kind", pa.string()), ("objects", pa.string()), ("force", pa.float64())])


def events_shard(task: tuple[str, EventConfig]) -> tuple[list[dict], list[dict]]:
    """Events rows and think rows of one traces shard."""
    shard, cfg = task
    events, think = [], []
    for row in shards.read_table(shard).to_pylist():
        trace, visible = trace_from_row(row)
        found = extract_events(trace, visible, cfg)
        events += events_to_rows(row["scene_id"], found)
        think.append({"scene_id": row["scene_id"], "split": row["split"],
                      "think": events_to_text(found, trace.names, cfg.decimals)})
    return events, think


def main() -> None:
    p = load_params()
    cfg = typed_section(p, "events", EventConfig)
    out = shards.reset_dir(path_of(p, "events"))
    trace_shards = shards.list_shards(path_of(p, "traces"), "parquet")
    meta = {"params": cfg.model_dump(), "units": {"t": "s", "force": "N (peak normal force)"}}
    # ~0.3 ms per scene: a pool pays off only for many shards
    compute = compute_from_params(p) if len(trace_shards) >= 8 else 1
    results = parallel_map(events_shard, [(str(s), cfg) for s in trace_shards], compute)
    for i, (events, think) in enumerate(tqdm(results, total=len(trace_shards), desc="events", unit="shard")):
        shards.write_table(shards.shard_path(out, i, "parquet", prefix="events"), events, meta, EVENTS_SCHEMA)
        shards.write_table(shards.shard_path(out, i, "parquet", prefix="think"), think, meta)
    shards.write_meta(out, {**meta, "shards": {"events": len(trace_shards), "think": len(trace_shards)}})


if __name__ == "__main__":
    run_stage(main)
