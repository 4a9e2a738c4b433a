"""DVC stage `cmaes`: refine each scene's Best@K pick by CMA-ES (object types fixed).

Reads ``paths.best_of_k`` (which sample is best), ``paths.predictions`` (its scene YAML),
``paths.video`` (observed segmentation = rendered ground truth) and ``paths.flow`` (observed
flow), and ``paths.configs`` for the trivial baseline, which is refined too (rows with
``start = baseline``; the model's Best@K pick has ``start = model``): it shows what the search
alone recovers when the model's samples are poor. Params ``search`` set the budget (popsize x iterations), the free fields and the
fitness; ``seed`` plus a hash of the scene id seeds each search. Writes ``paths.cmaes``: one
Parquet shard per best_of_k shard with scene_id, split, sample (the start), scene (refined,
canonical YAML; null when no sample was valid), initial_iou, full_iou, strict_iou, epe (px), fitness of the
written (rounded) scene, start_fitness, evaluations, seconds and history (JSON list of
{iteration, best_fitness, mean_fitness, best_full_iou, best_strict_iou, best_epe, evaluations, seconds}).

Scenes are refined in chunks of :data:`CHUNK` on the ``compute`` backend (``pipeline.parallel``:
local processes or Ray tasks), each chunk with its own evaluators; each search is seeded by
its scene id, so every column but ``seconds`` (and the times in ``history``) is the same on
any backend and worker count.
"""

import json
import math
import zlib

import pyarrow as pa

from pipeline import shards
from pipeline.entry import run_stage
from pipeline.mjcf import SimOptions
from pipeline.parallel import compute_from_params, map_shards
from pipeline.params import load_params, path_of, typed_section
from pipeline.scene import Decimals, Scene
from pipeline.search import (EvaluatorPool, Observations, SearchConfig, at_clip_timing, baseline_scene, cmaes_refine,
                             fitness, parse_sample, samples_by_scene)

SCHEMA = pa.schema([("scene_id", pa.string()), ("split", pa.string()), ("start", pa.string()), ("sample", pa.int32()),
                    ("scene", pa.string()), ("initial_iou", pa.float64()), ("full_iou", pa.float64()),
                    ("strict_iou", pa.float64()), ("epe", pa.float64()), ("fitness", pa.float64()), ("start_fitness", pa.float64()),
                    ("evaluations", pa.int32()), ("seconds", pa.float64()), ("history", pa.string())])


CHUNK = 4
"""Scenes per task (two searches of 1 + popsize x iterations evaluations each)."""


def refine_chunk(task: tuple) -> list[dict]:
    """CMA-ES rows of ``(video dir, flow dir, search config, sim options, seed, decimals,
    baseline scene, [(scene id, split, best sample index or None, its prediction row), ...])``:
    rows ``start = model`` then ``baseline`` per scene, in the order given (SCHEMA's columns)."""
    video, flow_dir, cfg, sim, seed, decimals, baseline, scenes = task
    obs = Observations(video, flow_dir)
    rows = []
    with EvaluatorPool(*obs.frame_size, sim) as pool:
        for sid, split, sample, pred in scenes:
            seg, flow, fps = obs.get(sid)
            starts = {"baseline": (None, baseline)}
            if sample is not None:
                starts["model"] = (sample, parse_sample(pred))
            for start_kind in ("model", "baseline"):
                row = {"scene_id": sid, "split": split, "start": start_kind, "sample": None, "scene": None,
                       "evaluations": 0, "seconds": 0.0, "history": "[]", **dict.fromkeys(
                           ("initial_iou", "full_iou", "strict_iou", "epe", "fitness", "start_fitness"), math.nan)}
                if start_kind in starts:
                    start_sample, start = starts[start_kind]
                    start = at_clip_timing(start, len(seg), fps)
                    refined, history = cmaes_refine(start, seg, flow, cfg, sim, pool=pool,
                                                    seed=seed + zlib.crc32(sid.encode()))
                    final = Scene.from_yaml(refined.to_yaml(decimals))  # score what is written
                    f = fitness(*pool.evaluate(final, len(seg)), seg, flow, cfg)
                    row.update(sample=start_sample, scene=final.to_yaml(decimals),
                               evaluations=history[-1]["evaluations"], seconds=history[-1]["seconds"],
                               start_fitness=history[0]["best_fitness"], history=json.dumps(history),
                               **{k: f[k] for k in ("initial_iou", "full_iou", "strict_iou", "epe", "fitness")})
                rows.append(row)
    return rows


def main() -> None:
    p = load_params()
    cfg, sim = typed_section(p, "search", SearchConfig), typed_section(p, "sim", SimOptions, required=True)
    seed, decimals = int(p.get("seed", 0)), typed_section(p, "scene.decimals", Decimals)
    video, flow_dir = str(path_of(p, "video")), str(path_of(p, "flow"))
    Observations(video, flow_dir)  # fail here, before any task, if an input is missing
    preds = samples_by_scene(shards.read_table(path_of(p, "predictions")), cfg.splits)
    bok_shards = shards.list_shards(path_of(p, "best_of_k"), "parquet")
    baseline = baseline_scene(shards.read_table(path_of(p, "configs")).to_pylist(), split="train")
    out = shards.reset_dir(path_of(p, "cmaes"))
    meta = {"params": {"search": cfg.model_dump(), "sim": p["sim"], "seed": seed},
            "units": {"epe": "px (rendered resolution)"},
            "observed": {"seg": "rendered ground truth", "flow": (p.get("flow") or {}).get("method")}}

    def scenes_of(shard) -> list[tuple]:
        table = shards.read_table(shard).to_pylist()
        best = {r["scene_id"]: r["sample"] for r in table if r["is_best"]}
        split = {r["scene_id"]: r["split"] for r in table}
        return [(sid, split[sid], best.get(sid),
                 next((r for r in preds[sid] if r["sample"] == best[sid]), None) if sid in best else None)
                for sid in split]

    groups = (scenes_of(shard) for shard in bok_shards)
    for i, rows in map_shards(refine_chunk, groups, lambda i, part: (video, flow_dir, cfg, sim, seed, decimals,
                                                                     baseline, part),
                              CHUNK, compute_from_params(p), desc="cmaes"):
        shards.write_table(shards.shard_path(out, i, "parquet"), rows, schema=SCHEMA, metadata=meta)
    shards.write_meta(out, {**meta, "shards": {"shard": len(bok_shards)},
                            "features": {c: str(SCHEMA.field(c).type) for c in SCHEMA.names}})


if __name__ == "__main__":
    run_stage(main)
