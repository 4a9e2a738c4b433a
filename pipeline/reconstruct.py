"""Main job: reconstruct an executable scene from a real video.

``dynamics infer VIDEO --out DIR [--fps F] [--start S]`` reads a 1 s window of any
OpenCV-readable video (``--fps`` overrides a wrong container rate, e.g. 240 for the PhysTrack
clips), resamples it to the scene frame rate at the model resolution, estimates optical flow,
samples K scenes from the model, keeps the best by re-simulation (Best@K) and refines it with
CMA-ES. Outputs in DIR:

* ``scene.yaml``: the refined scene (scene language v1, canonical form);
* ``side_by_side.mp4``: observed | re-simulated | masks (pseudo ground truth vs re-simulated);
* ``metrics.json``: IoU against *pseudo* ground-truth masks (background subtraction) and EPE
  against the observed flow (same estimator), for the model's first sample, Best@K and
  Best@K + CMA-ES;
* ``recording.rrd``: rerun recording (observed and re-simulated streams, 3D scene, camera).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from pipeline import shards
from pipeline.params import load_params, path_of
from pipeline.scene import Scene, SceneError


def _observe(video: str | Path, fps: float | None, start: float, width: int, height: int,
             scene_fps: int, duration: float, flow_method: str, flow_preset: str,
             mask_method: str, max_objects: int) -> dict:
    """Frames, pseudo masks and observed flow of a video window at the model resolution."""
    from pipeline.flow import estimate_flow
    from pipeline.video import label_objects, pseudo_masks, read_video, resample

    window = read_video(video, fps=fps, start=start, duration=duration + 1.0 / scene_fps, size=(width, height))
    if window.duration + 0.5 / window.fps < duration:
        from pipeline.video import VideoError

        raise VideoError(f"{video}: only {window.duration:.3f} s after start={start:g} s, need {duration:g} s")
    frames = resample(window.frames, window.fps, scene_fps, duration)
    # background model from a longer stretch of the same video (objects rarely rest there)
    context = read_video(video, fps=fps, size=(width, height), max_frames=int(20 * window.fps))
    step = max(1, len(context.frames) // 120)
    masks = pseudo_masks(frames, method=mask_method, background=context.frames[::step])
    seg = label_objects(masks, max_objects=max_objects)
    method = "dis" if flow_method == "gt" else flow_method  # no simulator truth for a real video
    flow = estimate_flow(frames, method=method, preset=flow_preset)
    return {"frames": frames, "seg": seg, "flow": flow, "clip": window, "flow_method": method}


def default_model_dir(params: dict) -> Path:
    """``paths.model`` when it holds a trained model (after ``dvc repro``), else the shipped
    checkpoint (:data:`pipeline.model.SHIPPED_CHECKPOINT`)."""
    from pipeline.model import SHIPPED_CHECKPOINT

    trained = path_of(params, "model")
    return trained if (trained / "config.json").exists() else SHIPPED_CHECKPOINT


def reconstruct(video: str | Path, out: str | Path, params: dict, fps: float | None = None,
                start: float = 0.0, model_dir: str | Path | None = None, k: int | None = None,
                seed: int = 0) -> dict:
    """Run the main job on one video and write its outputs (see module docstring).

    Args:
        video: video file path.
        out: output folder (created; files inside are replaced atomically).
        params: parsed params.yaml (sections ``render``, ``flow``, ``model``, ``search``,
            ``realvideo``, ``paths``).
        fps: true frame rate of the video, overriding the container's.
        start: start of the 1 s window, s.
        model_dir: trained model folder (default :func:`default_model_dir`).
        k: samples for Best@K (default ``model.k``).
    Returns:
        the metrics dict written to ``metrics.json``.
    Raises:
        VideoError: unreadable video or window past its end.
        ModelError: no trained model at ``model_dir``.
    """
    from pipeline import model as vlm
    from pipeline import search, viz
    from pipeline.flow import FlowConfig
    from pipeline.metrics import flow_epe, sequence_iou
    from pipeline.mjcf import SimOptions
    from pipeline.render import render_scene
    from pipeline.view import camera_dict, scene_objects

    t0 = time.time()
    out = Path(out)
    W, H = int(params["render"]["width"]), int(params["render"]["height"])
    rv = params.get("realvideo", {})
    mcfg = vlm.ModelConfig.from_params(params)
    fcfg = FlowConfig(**params["flow"])
    scfg = search.SearchConfig(**params["search"])
    sim = SimOptions(**params["sim"])
    scene_fps, duration = int(rv.get("fps", 30)), float(rv.get("duration", 1.0))

    obs = _observe(video, fps, start, W, H, scene_fps, duration, fcfg.method, fcfg.preset,
                   rv.get("mask_method", "median"), int(rv.get("max_objects", 4)))
    print(f"[infer] {video}: {len(obs['frames'])} frames at {scene_fps} fps ({W}x{H}), "
          f"{int((obs['seg'] >= 0).any(axis=0).sum())} px ever foreground")

    import torch

    torch.set_num_threads(1)  # as in stages/infer.py: decoding K samples, 1 thread is as fast
    model_dir = Path(model_dir) if model_dir else default_model_dir(params)
    net, tok = vlm.load_model(model_dir)
    codec, _ = vlm.load_codec(model_dir)
    mcfg = vlm.checkpoint_config(model_dir, mcfg)
    x = vlm.model_input(obs["frames"], obs["flow"], mcfg, fcfg.max_magnitude)
    samples = vlm.generate(net, tok, x, mcfg, codec, k=k or mcfg.k, seed=seed)
    texts = [" ".join(t) for t in samples]
    candidates, errors = [], []
    for toks in samples:
        s, err = vlm.to_scene(toks, codec)
        candidates.append(s.replace(fps=scene_fps, duration=duration) if s is not None else None)
        errors.append(err)
    n_valid = sum(c is not None for c in candidates)
    print(f"[infer] {len(texts)} samples, {n_valid} valid scenes")
    scores, best = search.best_of_k(candidates, obs["seg"], obs["flow"], scfg, sim) if n_valid else ([], None)
    fallback = best is None
    if fallback:  # no sample parsed or simulated: fall back (honestly flagged) to the trivial baseline
        candidates = [search.baseline_scene(shards.read_table(path_of(params, "configs"))).replace(
            fps=scene_fps, duration=duration)]
        scores, best = search.best_of_k(candidates, obs["seg"], obs["flow"], scfg, sim)
    refined, history = search.cmaes_refine(candidates[best], obs["seg"], obs["flow"], scfg, sim, seed=seed)

    def score(scene: Scene) -> tuple[dict, object]:
        trace, fr = render_scene(scene, W, H, options=sim)
        iou = sequence_iou(obs["seg"], fr.seg)
        epe = flow_epe(fr.flow, obs["flow"], fr.seg[:-1] >= 0, obs["seg"][:-1] >= 0)
        return {"initial_iou": iou["initial_iou"], "full_iou": iou["full_iou"],
                "foreground_iou_full": iou["foreground_iou_full"], "epe": epe}, (trace, fr)

    first = next((c for c in candidates if c is not None), None)
    m_first, _ = score(first)
    m_best, _ = score(candidates[best])
    m_ref, (trace, fr) = score(refined)

    out.mkdir(parents=True, exist_ok=True)
    shards.write_text(out / "scene.yaml", refined.to_yaml())
    pred_overlay = viz.mask_overlay(obs["frames"], fr.seg)
    obs_overlay = viz.mask_overlay(obs["frames"], obs["seg"])
    viz.side_by_side_mp4(out / "side_by_side.mp4", [obs["frames"], fr.rgb, obs_overlay, pred_overlay],
                         ["observed", "re-simulated", "pseudo-GT masks", "re-sim masks"], fps=scene_fps)
    clip = obs["clip"]
    metrics = {
        "video": str(video), "fps_used": clip.fps, "container_fps": clip.container_fps, "start_s": start,
        "window": {"frames": len(obs["frames"]), "fps": scene_fps, "width": W, "height": H},
        "ground_truth": "pseudo: masks from background subtraction, flow from the same estimator "
                        f"({obs['flow_method']}) as the model input",
        "samples": len(texts), "valid_samples": n_valid, "fallback_to_baseline": fallback,
        "sample_errors": [e for e in errors if e][:5],
        "first_sample": m_first, "best_of_k": m_best, "best_of_k_cmaes": m_ref,
        "cmaes_evaluations": int(sum(h.get("evaluations", 0) for h in history[-1:])) if history else 0,
        "seconds": round(time.time() - t0, 1),
    }
    shards.write_json(out / "metrics.json", metrics)
    n = len(refined.objects)
    viz.record_clip(out / "recording.rrd", rgb=obs["frames"], seg=fr.seg, flow=obs["flow"],
                    positions=trace.qpos[..., :3], quaternions=trace.qpos[..., 3:],
                    objects=scene_objects(refined), camera=camera_dict(refined, W, H), fps=scene_fps,
                    app_id="dynamics_infer",
                    scalars={"iou/frame": sequence_iou(obs["seg"], fr.seg)["per_frame"]})
    print(f"[infer] wrote {out}: full IoU {m_ref['full_iou']:.3f} (pseudo GT), EPE {m_ref['epe']:.2f} px, "
          f"{n} objects, {metrics['seconds']} s")
    return metrics


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("video", help="any OpenCV-readable video file")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--fps", type=float, default=None, help="true frame rate (overrides the container's)")
    p.add_argument("--start", type=float, default=0.0, help="start of the 1 s window, s")
    p.add_argument("--model", default=None, help="model folder (default: params paths.model if trained, else the shipped "
                   "checkpoint models/dynamics-tiny); a local "
                   "Qwen2.5-VL folder works when params model.pretrained points at it")
    p.add_argument("-k", type=int, default=None, help="samples for Best@K (default params model.k)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--params", default=None, help="params.yaml (default ./params.yaml)")


def main_cli(args: argparse.Namespace) -> int:
    params = load_params(args.params)
    metrics = reconstruct(args.video, args.out, params, fps=args.fps, start=args.start,
                          model_dir=args.model, k=args.k, seed=args.seed)
    print(json.dumps({k: metrics[k] for k in ("first_sample", "best_of_k", "best_of_k_cmaes")}, indent=1))
    return 0
