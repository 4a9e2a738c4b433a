"""DVC stage `cmaes`: refine each scene's Best@K pick by CMA-ES (object types fixed).

Reads ``paths.best_of_k`` (which sample is best), ``paths.predictions`` (its scene YAML),
``paths.video`` (observed segmentation = rendered ground truth) and ``paths.flow`` (observed
flow), and ``paths.configs`` for the trivial baseline, which is refined too (rows with
``start = baseline``; the model's Best@K pick has ``start = model``): it shows what the search
alone recovers when the model's samples are poor. Params ``search`` set the budget (popsize x iterations), the free fields and the
fitness; ``seed`` plus a hash of the scene id seeds each search. Writes ``paths.cmaes``: one
Parquet shard per best_of_k shard with scene_id, split, sample (the start), scene (refined,
canonical YAML; null when no sample was valid), initial_iou, full_iou, epe (px), fitness of the
written (rounded) scene, start_fitness, evaluations, seconds and history (JSON list of
{iteration, best_fitness, mean_fitness, best_full_iou, best_epe, evaluations, seconds}).
"""

import json
import math
import zlib

import pyarrow as pa
from tqdm import tqdm

from pipeline import shards
from pipeline.mjcf import SimOptions
from pipeline.params import load_params, path_of
from pipeline.scene import Decimals, Scene
from pipeline.search import (EvaluatorPool, Observations, SearchConfig, at_clip_timing, baseline_scene, cmaes_refine,
                             fitness, parse_sample, samples_by_scene)

SCHEMA = pa.schema([("scene_id", pa.string()), ("split", pa.string()), ("start", pa.string()), ("sample", pa.int32()),
                    ("scene", pa.string()), ("initial_iou", pa.float64()), ("full_iou", pa.float64()),
                    ("epe", pa.float64()), ("fitness", pa.float64()), ("start_fitness", pa.float64()),
                    ("evaluations", pa.int32()), ("seconds", pa.float64()), ("history", pa.string())])


def main() -> None:
    p = load_params()
    cfg, sim, seed = SearchConfig(**(p.get("search") or {})), SimOptions(**p["sim"]), int(p.get("seed", 0))
    decimals = Decimals(**(p.get("scene") or {}).get("decimals", {}))
    obs = Observations(path_of(p, "video"), path_of(p, "flow"))
    preds = samples_by_scene(shards.read_table(path_of(p, "predictions")), cfg.splits)
    bok_shards = shards.list_shards(path_of(p, "best_of_k"), "parquet")
    baseline = baseline_scene(shards.read_table(path_of(p, "configs")).to_pylist(), split="train")
    out = shards.reset_dir(path_of(p, "cmaes"))
    meta = {"params": {"search": cfg.model_dump(), "sim": p["sim"], "seed": seed},
            "units": {"epe": "px (rendered resolution)"},
            "observed": {"seg": "rendered ground truth", "flow": (p.get("flow") or {}).get("method")}}
    with EvaluatorPool(*obs.frame_size, sim) as pool:
        for i, shard in enumerate(bok_shards):
            table = shards.read_table(shard).to_pylist()
            best = {r["scene_id"]: r for r in table if r["is_best"]}
            split = {r["scene_id"]: r["split"] for r in table}
            rows, bar = [], tqdm(list(split), desc=f"cmaes shard {i}", unit="scene")
            for sid in bar:
                seg, flow, fps = obs.get(sid)
                starts = {"baseline": (None, baseline)}
                if sid in best:
                    sample = best[sid]["sample"]
                    starts["model"] = (sample, parse_sample(next(r for r in preds[sid] if r["sample"] == sample)))
                for start_kind in ("model", "baseline"):
                    row = {"scene_id": sid, "split": split[sid], "start": start_kind, "sample": None, "scene": None,
                           "evaluations": 0, "seconds": 0.0, "history": "[]", **dict.fromkeys(
                               ("initial_iou", "full_iou", "epe", "fitness", "start_fitness"), math.nan)}
                    if start_kind in starts:
                        sample, start = starts[start_kind]
                        start = at_clip_timing(start, len(seg), fps)
                        refined, history = cmaes_refine(start, seg, flow, cfg, sim, pool=pool,
                                                        seed=seed + zlib.crc32(sid.encode()))
                        final = Scene.from_yaml(refined.to_yaml(decimals))  # score what is written
                        f = fitness(*pool.evaluate(final, len(seg)), seg, flow, cfg)
                        row.update(sample=sample, scene=final.to_yaml(decimals),
                                   evaluations=history[-1]["evaluations"], seconds=history[-1]["seconds"],
                                   start_fitness=history[0]["best_fitness"], history=json.dumps(history),
                                   **{k: f[k] for k in ("initial_iou", "full_iou", "epe", "fitness")})
                        bar.set_postfix({start_kind: f"{history[0]['best_full_iou']:.2f}->{f['full_iou']:.2f}"})
                    rows.append(row)
            shards.write_table(shards.shard_path(out, i, "parquet"), rows, schema=SCHEMA, metadata=meta)
    shards.write_meta(out, {**meta, "shards": {"shard": len(bok_shards)},
                            "features": {c: str(SCHEMA.field(c).type) for c in SCHEMA.names}})


if __name__ == "__main__":
    main()
