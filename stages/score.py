"""DVC stage `score`: the paper-style results table, metrics.json and the search plot.

Scores four predictors on the scenes of ``search.splits`` that have predictions, each
re-simulated on the clip's time base and compared with the observed clip (segmentation =
rendered ground truth, flow = the flow stage's ``flow.method``): the trivial baseline (the
training split's most common composition with its mean parameters per shape slot), the
model's first sample, Best@k of the first k samples for k of :data:`BEST_OF_PREFIXES` below K
(Best@4 beside the paper's Best@32), Best@K and Best@K + CMA-ES, and the baseline refined by CMA-ES
(what the search alone recovers). Reads ``paths.configs``,
``paths.predictions``, ``paths.best_of_k``, ``paths.cmaes``, ``paths.video``, ``paths.flow``;
writes ``<paths.reports>/metrics.json``, ``table.md`` and ``search.png`` (atomically). Means carry
percentile bootstrap 95 % intervals over the scenes, and every method's strict IoU gain over the
first sample is given paired per scene (:func:`paired_gain`).
"""

import json
import math

from tqdm import tqdm

from pipeline import shards
from pipeline.entry import run_stage
from pipeline.metrics import mean_ci95
from pipeline.mjcf import SimOptions
from pipeline.params import load_params, path_of, typed_section
from pipeline.scene import Scene, SceneError
from pipeline.scene_metrics import PARAMETER_UNITS, defined, json_safe, markdown_table, scene_report, summarize
from pipeline.search import (EvaluatorPool, Observations, SearchConfig, at_clip_timing, baseline_scene, best_index,
                             parse_sample, plot_history, samples_by_scene)


BEST_OF_PREFIXES = (4, 8, 16)
"""Best@k rows beside Best@K for these k < K, picked among the first k of the same K samples
(the samples are drawn independently, so the first k are a draw of k): with ``search.k: 32`` the
table has the paper's Best@32 beside Best@4 from one sampling."""


def prefix_picks(scored: list[dict], k: int) -> dict[int, dict[str, int]]:
    """Best@j's pick per scene for each j of :data:`BEST_OF_PREFIXES` below ``k``: ``{j: {scene_id:
    sample}}`` from the best_of_k stage's rows (``scene_id``, ``sample``, ``fitness``; an invalid
    sample has fitness -inf), by :func:`pipeline.search.best_index` over samples ``0..j-1``; a scene
    with no valid sample among them has no pick (it scores as invalid)."""
    by_scene: dict[str, dict[int, float]] = {}
    for r in scored:
        by_scene.setdefault(r["scene_id"], {})[int(r["sample"])] = -math.inf if r["fitness"] is None else r["fitness"]
    out = {}
    for j in (j for j in BEST_OF_PREFIXES if j < k):
        picks = {sid: best_index([fits.get(i, -math.inf) for i in range(j)]) for sid, fits in by_scene.items()}
        out[j] = {sid: pick for sid, pick in picks.items() if pick is not None}
    return out


def paired_gain(rows: list[dict], reference: list[dict], key: str = "strict_full_iou") -> dict:
    """Mean per-scene difference ``rows[i][key] - reference[i][key]`` (the same scenes in the same
    order, from :func:`pipeline.scene_metrics.scene_report`) with its percentile bootstrap 95 %
    interval (:func:`pipeline.metrics.mean_ci95`); scenes where either value is undefined (None or
    NaN) are left out. Paired, so it is tighter than the two methods' own intervals."""
    return mean_ci95([a[key] - b[key] for a, b in zip(rows, reference, strict=True) if defined(a[key]) and defined(b[key])])


def main() -> None:
    p = load_params()
    cfg, sim = typed_section(p, "search", SearchConfig), typed_section(p, "sim", SimOptions, required=True)
    model_input, flow_method = (p.get("model") or {}).get("input", "flow"), (p.get("flow") or {}).get("method")
    configs = shards.read_table(path_of(p, "configs")).to_pylist()
    preds = samples_by_scene(shards.read_table(path_of(p, "predictions")), cfg.splits)
    scored = shards.read_table(path_of(p, "best_of_k")).to_pylist()
    best = {r["scene_id"]: r["sample"] for r in scored if r["is_best"]}
    cmaes_rows = shards.read_table(path_of(p, "cmaes")).to_pylist()
    cmaes = {r["scene_id"]: r for r in cmaes_rows if r["start"] == "model"}
    cmaes_baseline = {r["scene_id"]: r for r in cmaes_rows if r["start"] == "baseline"}
    truth = {r["scene_id"]: (r["split"], Scene.from_yaml(r["scene"], source=r["scene_id"]))
             for r in configs if r["split"] in cfg.splits and r["scene_id"] in preds}
    baseline = baseline_scene(configs, split="train")
    k = min(cfg.k, max((len(v) for v in preds.values()), default=cfg.k))  # Best@K used the first k samples

    def best_sample(sid: str, picks: dict = best) -> Scene | None:
        return parse_sample(next(r for r in preds[sid] if r["sample"] == picks[sid])) if sid in picks else None

    def refined(sid: str, table: dict = cmaes) -> Scene | None:
        text = (table.get(sid) or {}).get("scene")
        return Scene.from_yaml(text, source=f"{sid} (cmaes)") if text else None

    methods = {  # key: (table label, input, predictor)
        "trivial_baseline": ("Trivial baseline", "–", lambda sid: baseline),
        "trivial_baseline_cmaes": ("Trivial baseline + CMA-ES", "–", lambda sid: refined(sid, cmaes_baseline)),
        "first_sample": ("Model (first sample)", model_input, lambda sid: parse_sample(preds[sid][0])),
        **{f"best_of_{j}": (f"Best@{j}", model_input, lambda sid, picks=picks: best_sample(sid, picks))
           for j, picks in prefix_picks(scored, k).items()},
        "best_of_k": (f"Best@{k}", model_input, best_sample),
        "best_of_k_cmaes": (f"Best@{k} + CMA-ES", model_input, refined),
    }
    rows = {(m, s): [] for m in methods for s in cfg.splits}
    obs = Observations(path_of(p, "video"), path_of(p, "flow"))
    with EvaluatorPool(*obs.frame_size, sim) as pool:
        for sid, (split, true) in tqdm(truth.items(), desc="score", unit="scene"):
            seg, flow, fps = obs.get(sid)
            for m, (_, _, predict) in methods.items():
                pred = predict(sid)
                pred = None if pred is None else at_clip_timing(pred, len(seg), fps)
                try:
                    pseg, pflow = (None, None) if pred is None else pool.evaluate(pred, len(seg))
                except (SceneError, ValueError):  # e.g. an unknown effect: counts as invalid
                    pred, pseg, pflow = None, None, None
                rows[m, split].append(scene_report(true, pred, seg, flow, pseg, pflow))
    splits = [s for s in cfg.splits if rows["trivial_baseline", s]]
    metrics = {
        "observed": {"segmentation": "rendered ground truth (synthetic)", "flow": flow_method},
        "input": model_input, "reasoning": (p.get("model") or {}).get("reasoning"), "k": k,
        "cmaes_budget": {"popsize": cfg.popsize, "iterations": cfg.iterations, "free": list(cfg.free)},
        "units": {"epe": "px at the rendered resolution", "parameter_errors": PARAMETER_UNITS},
        "methods": {m: {s: summarize(rows[m, s]) for s in splits} for m in methods},
        "strict_iou_gain_over_first_sample": {m: {s: paired_gain(rows[m, s], rows["first_sample", s])
                                                  for s in splits} for m in methods if m != "first_sample"},
    }
    reports = path_of(p, "reports")
    shards.write_json(reports / "metrics.json", json_safe(metrics))  # NaN -> null
    labels, inputs = {m: v[0] for m, v in methods.items()}, {m: v[1] for m, v in methods.items()}
    width, height = obs.frame_size
    table = ["# Results", "",
             f"Observed masks: rendered ground truth; observed flow: `{flow_method}`; IoU and EPE on "
             f"{width}x{height} re-simulations (EPE in px). CMA-ES: popsize {cfg.popsize} x {cfg.iterations} "
             f"iterations, free: {', '.join(cfg.free)}. Invalid predictions count as IoU 0 and are left out of EPE.", ""]
    gains = metrics["strict_iou_gain_over_first_sample"]
    for s in splits:
        table += [markdown_table({m: metrics["methods"][m][s] for m in methods}, labels, inputs, s),
                  "Strict IoU minus the first sample's, paired per scene (mean [95 % bootstrap interval]): "
                  + "; ".join(f"{labels[m]} {g[s]['mean']:+.3f} [{g[s]['ci95'][0]:+.3f}, {g[s]['ci95'][1]:+.3f}]"
                              for m, g in gains.items() if g[s]["n"]) + ".", ""]
    shards.write_text(reports / "table.md", "\n".join(table))
    def histories(table: dict) -> list:
        return [h for r in table.values() if r["split"] in splits and (h := json.loads(r["history"] or "[]"))]

    start, hist = ("Best@K", histories(cmaes)) if histories(cmaes) else ("baseline", histories(cmaes_baseline))
    shards.write_bytes(reports / "search.png", plot_history(hist, title=f"CMA-ES from {start} ({', '.join(splits)})"))
    print("\n".join(table))


if __name__ == "__main__":
    run_stage(main)
