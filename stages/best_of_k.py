"""DVC stage `best_of_k`: re-simulate every sampled scene and score it against its clip.

Reads ``paths.predictions`` (scene_id, split, sample, text, scene YAML or null, error),
``paths.video`` (observed segmentation = the rendered ground truth) and ``paths.flow``
(observed flow, params ``flow.method``). For each scene of ``search.splits``, the first
``search.k`` samples are re-timed to the clip, simulated and scored with the fitness
``IoU - lambda_epe * EPE`` (pipeline.search; IoU per ``search.fitness_iou``, strict by default).
Writes ``paths.best_of_k``: one Parquet shard per predictions shard with scene_id, split, sample,
valid, initial_iou, full_iou, strict_iou, epe (px), fitness, is_best, error.

Scenes are scored in chunks of :data:`CHUNK` on the ``compute`` backend (``pipeline.parallel``:
local processes or Ray tasks), each chunk with its own evaluators; rows come back in scene
order, so the shards do not depend on the backend or the worker count.
"""

import pyarrow as pa

from pipeline import shards
from pipeline.entry import run_stage
from pipeline.mjcf import SimOptions
from pipeline.parallel import compute_from_params, map_shards
from pipeline.params import load_params, path_of, typed_section
from pipeline.search import (EvaluatorPool, Observations, SearchConfig, at_clip_timing, best_of_k, parse_sample,
                             samples_by_scene)

SCHEMA = pa.schema([("scene_id", pa.string()), ("split", pa.string()), ("sample", pa.int32()),
                    ("valid", pa.bool_()), ("initial_iou", pa.float64()), ("full_iou", pa.float64()),
                    ("strict_iou", pa.float64()), ("epe", pa.float64()), ("fitness", pa.float64()), ("is_best", pa.bool_()),
                    ("error", pa.string())])


CHUNK = 8
"""Scenes per task (K re-simulations each, ~0.1 s per scene at the small profile)."""


def score_chunk(task: tuple[str, str, SearchConfig, SimOptions, list[tuple[str, list[dict]]]]) -> list[dict]:
    """Best@K rows of ``(video dir, flow dir, search config, sim options, [(scene id, its
    prediction rows), ...])``: one row per sample, in the order given (SCHEMA's columns)."""
    video, flow_dir, cfg, sim, scenes = task
    obs = Observations(video, flow_dir)
    rows = []
    with EvaluatorPool(*obs.frame_size, sim) as pool:
        for sid, preds in scenes:
            seg, flow, fps = obs.get(sid)
            cands = [parse_sample(r) for r in preds]  # None: the output did not parse
            cands = [None if c is None else at_clip_timing(c, len(seg), fps) for c in cands]
            scores, best = best_of_k(cands, seg, flow, cfg, sim, pool=pool)
            rows += [{"scene_id": sid, "split": r["split"], "sample": r["sample"], "valid": s["valid"],
                      "initial_iou": s["initial_iou"], "full_iou": s["full_iou"],
                      "strict_iou": s["strict_iou"], "epe": s["epe"],
                      "fitness": s["fitness"], "is_best": j == best, "error": r["error"] or s["error"]}
                     for j, (r, s) in enumerate(zip(preds, scores))]
    return rows


def main() -> None:
    p = load_params()
    cfg, sim = typed_section(p, "search", SearchConfig), typed_section(p, "sim", SimOptions, required=True)
    video, flow_dir = str(path_of(p, "video")), str(path_of(p, "flow"))
    Observations(video, flow_dir)  # fail here, before any task, if an input is missing
    pred_shards = shards.list_shards(path_of(p, "predictions"), "parquet")
    out = shards.reset_dir(path_of(p, "best_of_k"))
    used = ("k", "lambda_epe", "prior_weight", "penalize_extra", "splits")  # the dvc.yaml params of this stage
    meta = {"params": {"search": {k: v for k, v in cfg.model_dump().items() if k in used}, "sim": p["sim"]},
            "units": {"epe": "px (rendered resolution)"},
            "observed": {"seg": "rendered ground truth", "flow": (p.get("flow") or {}).get("method")}}
    groups = (list(samples_by_scene(shards.read_table(shard), cfg.splits, cfg.k).items()) for shard in pred_shards)
    for i, rows in map_shards(score_chunk, groups, lambda i, part: (video, flow_dir, cfg, sim, part), CHUNK,
                              compute_from_params(p), desc="best_of_k"):
        shards.write_table(shards.shard_path(out, i, "parquet"), rows, schema=SCHEMA, metadata=meta)
    shards.write_meta(out, {**meta, "shards": {"shard": len(pred_shards)},
                            "features": {c: str(SCHEMA.field(c).type) for c in SCHEMA.names}})


if __name__ == "__main__":
    run_stage(main)
