"""Main job: reconstruct an executable scene from a real video.

``dynamics infer VIDEO --out DIR [--fps F] [--start S]`` reads a 1 s window of any
OpenCV-readable video (``--fps`` overrides a wrong container rate, e.g. 240 for the PhysTrack
clips; without ``--start`` the window with the most object motion is chosen), cut to the region
of motion at the video's aspect ratio (:mod:`pipeline.observe`), and proposes scenes from two
sources: the model's K samples (when a model is available) and the perception proposals
(:mod:`pipeline.perception`, no training needed). All proposals are re-simulated and scored
together (Best@K), and the best is refined by staged CMA-ES (:mod:`pipeline.search.staged`).
Outputs in DIR:

* ``scene.yaml``: the refined scene (scene language v1, canonical form): the better, by the
  search's fitness, of the search's result and the Best@K pick it started from, each with
  initial overlaps resolved and checked as ``dynamics simulate`` checks it, so that
  ``dynamics simulate scene.yaml`` runs as it is and gives ``masks.npz``;
* ``observation.npz``: the observation the search fitted (issue 36): ``seg (T, H, W) int8``
  pseudo masks at the working size (-1 background), ``crop`` ``[x, y, w, h]`` px of the
  original frame, ``size`` ``[W, H]`` px, ``start`` s and ``fps`` of the window, ``source_fps`` and
  ``source_frames`` ``(T,)`` int64 (the decoded frame, 0-based, behind each window frame);
* ``masks.npz``: the re-simulated masks that were scored (``seg (T, H, W) int8``, -1 =
  background, and ``names``; the layout of ``dynamics simulate``), at the working size;
* ``side_by_side.mp4``: original frames with pseudo ground-truth masks | with re-simulated
  masks | the re-simulated render, panels ``realvideo.panel_height`` px high;
* ``contact_sheet.png``: the same three rows at six instants;
* ``metrics.json``: IoU against *pseudo* ground-truth masks (background subtraction) and EPE
  against the observed flow (same estimator), for the first sample, Best@K and Best@K +
  CMA-ES, and per source (model, perception) the number of proposals, valid ones and the best
  IoU; ``search_gain`` says which scene was written and what the search gained (or that it
  found no gain);
* ``recording.rrd``: rerun recording (observed and re-simulated streams, 3D scene, camera);
* ``tracks.csv``: the observed object tracks in the scene's world frame beside the
  re-simulated ones (:mod:`pipeline.infer_tracks`), so ``dynamics discrepancy DIR`` can ask
  where the re-simulation leaves the video and which effect closes the gap.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from pipeline import infer_tracks, perception, shards, viz
from pipeline.atomic import publish_dir, remove_stale_temps, temp_dir_for
from pipeline.flow import flow_config, flow_of
from pipeline.labels import load_labels, score_against_labels
from pipeline.npz import NpzWriter
from pipeline.metrics import flow_epe, sequence_iou
from pipeline.mjcf import SimOptions
from pipeline.observe import (LEARNED, MASK_METHODS, MIN_WINDOW_FRAMES, observe, original_frames, scene_rate,
                              source_frames, upscale)
from pipeline.params import ParamsError, load_params, path_of, section, typed_section
from pipeline.render import render_scene
from pipeline.sanity import PhysicsError, SanityConfig, check_simulation, resolve_overlaps
from pipeline.scene import Scene, SceneError
from pipeline.search import EvaluatorPool, SearchConfig, best_of_k, simplest_within
from pipeline.search.staged import REFERENCE_WIDTH, score_scene, staged_refine
from pipeline.video import VideoError, read_video
from pipeline.shard_viewer import camera_dict, scene_objects


MAX_WINDOW_FRAMES = 300
"""Most frames of the main job's window (``realvideo.duration * realvideo.fps``; the default is
30). The search scores the whole window at once, so its frames, flow and masks stay in memory
(~2.5 MB per frame at the working size with the side-by-side panels): the limit keeps a run
under ~1 GB and is checked before the video is decoded (issue 35)."""


class RealVideoConfig(BaseModel):
    """Params section ``realvideo``: the main job ``dynamics infer VIDEO``.

    The window (``fps`` frames per s of scene time, ``duration`` s), the observation
    (``mask_method``, one of :data:`pipeline.observe.MASK_METHODS`; ``max_objects`` tracks), the
    staged CMA-ES (``popsize`` and ``iterations`` per stage, ``restarts`` of the first stage,
    ``workers`` scoring processes, fitness ``IoU - lambda_epe * EPE`` with EPE per px at 96 px
    wide, averaged over ``epe_pixels``: ``observed`` foreground pixels by default, so that a
    predicted object away from the motion cannot lower it, :class:`pipeline.search.SearchConfig`;
    ``shape_margin``: Best@K takes the proposal with the fewest shape parameters among those
    of the best one's structure within this fitness of it, :func:`pipeline.search.simplest_within`) and the figures (``panel_height``, ``sheet_height`` in px). The defaults are the
    default profile's (a test checks that params.yaml agrees).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    fps: int = Field(30, ge=1)
    duration: float = Field(1.0, gt=0)
    mask_method: str = "median"
    max_objects: int = Field(4, ge=1)
    popsize: int = Field(10, ge=2)
    iterations: int = Field(8, ge=1)
    restarts: int = Field(2, ge=1)
    workers: int = Field(2, ge=1)
    lambda_epe: float = Field(0.05, ge=0)
    epe_pixels: Literal["union", "observed"] = "observed"
    shape_margin: float = Field(0.02, ge=0)
    panel_height: int = Field(320, ge=16)
    sheet_height: int = Field(180, ge=16)

    @field_validator("mask_method")
    @classmethod
    def _known_method(cls, v: str) -> str:
        if v not in MASK_METHODS:
            raise ValueError(f"must be one of {', '.join(MASK_METHODS)}")
        return v


def realvideo_config(params: dict) -> RealVideoConfig:
    """The ``realvideo`` section of parsed params, typed (one-line :class:`ParamsError`)."""
    return typed_section(params, "realvideo", RealVideoConfig)


def default_model_dir(params: dict) -> Path | None:
    """``paths.model`` when it holds a trained model (after ``dvc repro``), else the shipped
    checkpoint (:data:`pipeline.model.SHIPPED_CHECKPOINT`) if present, else None."""
    from pipeline.model import SHIPPED_CHECKPOINT

    trained = path_of(params, "model")
    if (trained / "config.json").exists():
        return trained
    return SHIPPED_CHECKPOINT if (Path(SHIPPED_CHECKPOINT) / "config.json").exists() else None


def resolve_model_dir(model_dir: str | Path | None, params: dict) -> Path | None:
    """The model folder ``dynamics infer`` will use, checked before any video is decoded.

    Args:
        model_dir: ``--model``; None picks :func:`default_model_dir`.
        params: parsed params.yaml.
    Returns:
        the folder, or None when no model was asked for and none is available.
    Raises:
        ModelError: the folder (given or default) is missing or not a checkpoint this version
            can load (:func:`pipeline.model.check_checkpoint`): one line.
    """
    from pipeline.model.network import check_checkpoint

    mdir = Path(model_dir) if model_dir else default_model_dir(params)
    if mdir is not None:
        check_checkpoint(mdir)
    return mdir


def model_samples(model_dir: Path, frames: np.ndarray, params: dict, k: int | None, seed: int,
                  scene_fps: int, duration: float) -> tuple[list[Scene | None], list[str | None]]:
    """K scenes sampled from a model for a clip (None where a sample is not a valid scene).

    The clip is shown to the model as it was trained: resized to ``render.width x
    render.height`` with the flow estimated at that size.
    """
    import torch

    from pipeline import model as vlm

    W, H = int(section(params, "render")["width"]), int(section(params, "render")["height"])
    fcfg = flow_config(params)
    small = np.stack([cv2.resize(f, (W, H), interpolation=cv2.INTER_AREA) for f in frames])
    flow = flow_of(small, fcfg)
    torch.set_num_threads(1)  # as in stages/predict.py: decoding K samples, 1 thread is as fast
    net, tok = vlm.load_model(model_dir)
    codec, _ = vlm.load_codec(model_dir)
    mcfg = vlm.checkpoint_config(model_dir, vlm.ModelConfig.from_params(params))
    x = vlm.model_input(small, flow, mcfg, fcfg.max_magnitude)
    samples = vlm.generate(net, tok, x, mcfg, codec, k=k or mcfg.k, seed=seed)
    scenes, errors = [], []
    for toks in samples:
        s, err = vlm.to_scene(toks, codec)
        scenes.append(s.replace(fps=scene_fps, duration=duration) if s is not None else None)
        errors.append(err)
    return scenes, errors


def _source_summary(scores: list[dict], sources: list[str], name: str) -> dict:
    mine = [s for s, src in zip(scores, sources) if src == name]
    valid = [s for s in mine if s["valid"]]
    best = max(valid, key=lambda s: s["fitness"]) if valid else None
    return {"proposals": len(mine), "valid": len(valid),
            "best_full_iou": None if best is None else round(best["full_iou"], 4),
            "best_fitness": None if best is None else round(best["fitness"], 4)}


def writable(scene: Scene, sim: SimOptions, sanity: SanityConfig) -> tuple[Scene, list[str], str | None]:
    """The scene as the main job would write it: objects that start interpenetrating moved
    apart (:func:`pipeline.sanity.resolve_overlaps`), rounded to its canonical text, and checked
    as ``dynamics simulate`` checks it (:func:`pipeline.sanity.check_simulation`).

    Returns:
        ``(scene, moves, problem)``: ``problem`` is None when ``dynamics simulate`` accepts the
        scene as it is, else its one-line error (the scene is then the best effort).
    """
    moves: list[str] = []
    try:
        scene, moves = resolve_overlaps(scene, sim, sanity)
    except PhysicsError as exc:
        return scene.rounded(), moves, str(exc)
    scene = scene.rounded()
    try:
        check_simulation(scene, sim, sanity)
    except (PhysicsError, SceneError) as exc:
        return scene, moves, str(exc)
    return scene, moves, None


def choose_output(candidates: list[tuple[str, Scene]], obs_seg: np.ndarray, obs_flow: np.ndarray | None,
                  cfg: SearchConfig, sim: SimOptions, sanity: SanityConfig, pool: EvaluatorPool | None = None
                  ) -> tuple[int, Scene, list[dict]]:
    """Pick the scene the main job writes: of the search's result and the candidate it started
    from (and any other), each made :func:`writable` and scored with the search's fitness
    (``IoU - lambda * EPE`` at the observation's width, :func:`pipeline.search.staged.score_scene`),
    the best that ``dynamics simulate`` accepts; the best of all only if none does. So the
    written scene never scores below the start, and what is written is what is scored
    (issue 35).

    Args:
        candidates: ``[(name, scene), ...]``, e.g. ``[("cmaes", refined), ("best_of_k", start)]``.
        obs_seg: ``(T, H, W)`` int8 observed labels.
        obs_flow: ``(T-1, H, W, 2)`` float observed flow, px, or None.
        cfg: search config (``lambda_epe`` per px at the reference width).
        sim, sanity: simulation options and the checks' thresholds.
        pool: evaluators to reuse.
    Returns:
        ``(index, scene, report)``: the index chosen, its writable scene, and per candidate
        ``{name, fitness, full_iou, strict_iou, epe, simulate_ok, problem, moves}``.
    """
    report, scenes = [], []
    for name, scene in candidates:
        fixed, moves, problem = writable(scene, sim, sanity)
        s = score_scene(fixed, obs_seg, obs_flow, cfg, sim, pool=pool)
        scenes.append(fixed)
        report.append({"name": name, "fitness": round(float(s["fitness"]), 6), "full_iou": round(float(s["full_iou"]), 6),
                       "strict_iou": None if s["strict_iou"] != s["strict_iou"] else round(float(s["strict_iou"]), 6),
                       "epe": round(float(s["epe"]), 6), "simulate_ok": problem is None, "problem": problem,
                       "moves": moves})
    pool_ok = [i for i, r in enumerate(report) if r["simulate_ok"]] or list(range(len(report)))
    i = max(pool_ok, key=lambda k: (report[k]["fitness"], -k))   # ties: the earlier candidate
    return i, scenes[i], report


def reconstruct(video: str | Path, out: str | Path, params: dict, fps: float | None = None,
                start: float | None = None, model_dir: str | Path | None = None, k: int | None = None,
                seed: int = 0, use_model: bool = True, labels: str | Path | None = None) -> dict:
    """Run the main job on one video and write its outputs (see module docstring).

    Args:
        video: video file path.
        out: output folder (created; its files are written into a temporary folder beside it
            and moved in at the end, so a killed run leaves nothing that looks complete).
        params: parsed params.yaml (sections ``render``, ``flow``, ``model``, ``search``, ``sim``,
            ``realvideo``, ``paths``).
        fps: true frame rate of the video, overriding the container's.
        start: start of the 1 s window, s; None chooses it (:func:`pipeline.observe.choose_start`).
        model_dir: trained model folder (default :func:`default_model_dir`).
        k: samples for Best@K (default ``model.k``).
        seed: sampling and CMA-ES seed.
        use_model: False skips the model (perception proposals only).
        labels: hand labels or true masks of the video (:mod:`pipeline.labels`): the
            re-simulation and the observation are also scored against them (``metrics.json``
            ``against_labels``). Read for scoring only; the search fits the observation.
    Returns:
        the metrics dict written to ``metrics.json``.
    Raises:
        VideoError: unreadable video, window past its end, or nothing to reconstruct (no model
            sample and no moving object found).
        ModelError: ``model_dir`` (or the default trained model) is not a usable checkpoint;
            raised before the video is decoded.
    """
    # llvmpipe rasterizing in the calling thread is 5-10 % faster for these small renders
    # (benchmarks/search_eval.py --compare-lp); pixels do not depend on it
    os.environ.setdefault("LP_NUM_THREADS", "0")
    t0 = time.time()
    out = Path(out)
    rv = realvideo_config(params)
    fcfg = flow_config(params)
    scfg = typed_section(params, "search", SearchConfig, required=True)
    scfg = scfg.model_copy(update={"popsize": rv.popsize, "iterations": rv.iterations, "lambda_epe": rv.lambda_epe,
                                   "epe_pixels": rv.epe_pixels})
    sim = typed_section(params, "sim", SimOptions, required=True)
    sanity = typed_section(params, "sanity", SanityConfig)
    scene_fps, duration = rv.fps, rv.duration
    frames = int(round(scene_fps * duration))
    if not 2 <= frames <= MAX_WINDOW_FRAMES:   # before any video is decoded
        raise ParamsError(f"{getattr(params, 'source', 'params.yaml')}: realvideo.duration * realvideo.fps: must give "
                          f"2..{MAX_WINDOW_FRAMES} frames (the main job holds the window's frames, flow and masks "
                          f"in memory, ~2.5 MB per frame), got {frames}")
    max_objects = rv.max_objects

    # the model folder is checked first (milliseconds), before decoding the video (seconds)
    model_note, mdir = None, None
    if use_model:
        mdir = resolve_model_dir(model_dir, params)
        if mdir is None:
            model_note = (f"no trained model at {path_of(params, 'model')} and no shipped checkpoint: using the "
                          "perception proposals only (run `dvc repro` or pass --model)")
            print(f"[infer] {model_note}")
    else:
        model_note = "model not used (--no-model)"

    truth, labels_path = None, labels
    if labels_path is not None:   # read (and checked) before the search, used only after it
        truth = load_labels(labels_path, read_video(video, fps=fps, max_frames=1).original_size)
    if start is None:   # a clip too short for the window at realvideo.fps gets a higher scene rate
        scene_fps = scene_rate(video, fps, scene_fps)
        if scene_fps != rv.fps:
            why = (f"recorded at a lower rate than {rv.fps} fps" if scene_fps < rv.fps else
                   f"too short for {MIN_WINDOW_FRAMES} frames at {rv.fps} fps")
            print(f"[infer] {video}: {why}: the scene runs at {scene_fps} fps")
    obs = observe(video, fps, start, scene_fps, duration, fcfg,
                  rv.mask_method, max_objects)
    duration = obs.duration   # a clip shorter than the window is its own window, and the scene follows it
    W, H = obs.size
    print(f"[infer] {video}: window {obs.start:.3f}-{obs.start + duration:.3f} s"
          f"{' (chosen automatically)' if obs.auto else ''}, {len(obs.frames)} frames at {scene_fps} fps, "
          f"crop {obs.crop} -> {W}x{H} px")

    candidates: list[Scene | None] = []
    sources: list[str] = []
    labels: list[str] = []
    errors: list[str | None] = []
    notes: list[str] = []
    if mdir is not None:
        scenes, errs = model_samples(mdir, obs.frames, params, k, seed, scene_fps, duration)
        candidates += scenes
        sources += ["model"] * len(scenes)
        labels += [f"model sample {i}" for i in range(len(scenes))]
        errors += errs
    proposals = None
    try:
        proposals = perception.propose(obs.seg, obs.flow, scene_fps, duration, max_objects,
                                       still=obs.mask_method in LEARNED)
        candidates += proposals.scenes
        sources += ["perception"] * len(proposals.scenes)
        labels += [f"perception: {l}" for l in proposals.labels]
        errors += [None] * len(proposals.scenes)
        notes = proposals.notes
    except perception.PerceptionError as exc:
        notes = [f"perception: {exc}"]
    if not any(c is not None for c in candidates):
        raise VideoError(f"{video}: nothing to reconstruct: no valid model sample and {notes[0]}")
    print(f"[infer] {sum(s == 'model' for s in sources)} model samples, "
          f"{sum(s == 'perception' for s in sources)} perception proposals")

    lam_cfg = scfg.model_copy(update={"lambda_epe": scfg.lambda_epe * REFERENCE_WIDTH / W})
    with EvaluatorPool(W, H, sim) as pool:
        scores, best = best_of_k(candidates, obs.seg, obs.flow, lam_cfg, sim, pool=pool)
        if best is None:
            raise VideoError(f"{video}: no proposal could be simulated ({scores[0].get('error')})")
        fittest = best   # the paper's Best@K; then the simplest shapes the re-simulation cannot tell apart
        best = simplest_within(candidates, scores, fittest, rv.shape_margin)
        if best != fittest:
            print(f"[infer] Best@K: {labels[best]} (fitness {scores[best]['fitness']:.4f}) over {labels[fittest]} "
                  f"({scores[fittest]['fitness']:.4f}): fewer shape parameters within {rv.shape_margin:g}")
        refined, history = staged_refine(candidates[best], obs.seg, obs.flow, scfg, sim, seed=seed,
                                         restarts=rv.restarts, pool=pool,
                                         workers=rv.workers)
        # what scene.yaml holds is what is scored: the better of the search's result and its
        # start, each as written (overlaps resolved, canonical text) and as `dynamics simulate` checks it
        chosen, refined, choice = choose_output([("cmaes", refined), ("best_of_k", candidates[best])],
                                                obs.seg, obs.flow, scfg, sim, sanity, pool=pool)
    gain = choice[0]["fitness"] - choice[1]["fitness"]
    search_gain = {
        "written": choice[chosen]["name"], "fitness_gain": round(gain, 6),
        "full_iou_gain": round(choice[0]["full_iou"] - choice[1]["full_iou"], 6),
        "candidates": choice,
        "note": ("the search found a gain over its start: its result is written" if chosen == 0 else
                 "the search found no gain over its start (the Best@K pick): the start is written"
                 if choice[0]["simulate_ok"] or not choice[1]["simulate_ok"] else
                 "the search's result fails dynamics simulate's checks: the start is written"),
    }
    if not choice[chosen]["simulate_ok"]:
        search_gain["note"] += f"; dynamics simulate refuses it: {choice[chosen]['problem']}"
    print(f"[infer] {search_gain['note']} (fitness {choice[0]['fitness']:.4f} vs start {choice[1]['fitness']:.4f})")

    def score(scene: Scene) -> tuple[dict, object]:
        trace, fr = render_scene(scene, W, H, options=sim)
        iou = sequence_iou(obs.seg, fr.seg)
        # strict: per observed object over the frames where it or its match is visible (no free
        # credit for frames where both are absent; issue 29 item 7; the search's fitness IoU),
        # reported beside full_iou (docs/design.md §7)
        strict = iou["strict_iou"]
        epe = flow_epe(fr.flow, obs.flow, fr.seg[:-1] >= 0, obs.seg[:-1] >= 0)
        return {"initial_iou": round(iou["initial_iou"], 4), "full_iou": round(iou["full_iou"], 4),
                "strict_full_iou": None if not np.isfinite(strict) else round(float(strict), 4),
                "foreground_iou_full": round(iou["foreground_iou_full"], 4), "epe": round(epe, 4)}, (trace, fr)

    first_i = next(i for i, c in enumerate(candidates) if c is not None)
    m_first, _ = score(candidates[first_i])
    m_best, _ = score(candidates[best])
    m_ref, (trace, fr) = score(refined)

    # every file is written into a temporary folder beside OUT and published at the end
    # (pipeline.atomic.publish_dir): a run killed midway (or out of memory) leaves no OUT that
    # looks complete, only a hidden temporary folder that the next run removes
    final = out
    remove_stale_temps(final)
    out = temp_dir_for(final)
    try:
        shards.write_text(out / "scene.yaml", refined.to_yaml())
        with NpzWriter(out / "masks.npz") as npz:   # the masks that were scored, as `dynamics simulate` writes them
            npz.write("seg", fr.seg)
            npz.write("names", np.asarray(refined.object_names))
        with NpzWriter(out / "observation.npz") as npz:   # what was fitted, to be checked against truth
            for key, value in (("seg", obs.seg.astype(np.int8)), ("crop", np.asarray(obs.crop, dtype=np.int64)),
                               ("size", np.asarray(obs.size, dtype=np.int64)), ("start", np.float64(obs.start)),
                               ("fps", np.float64(scene_fps)), ("source_fps", np.float64(obs.clip.fps)),
                               ("source_frames", source_frames(obs))):
                npz.write(key, value)
        # for people: original frames at panel height, masks drawn over them
        ph = rv.panel_height
        orig = original_frames(obs, video, fps, height=ph)
        psize = (orig.shape[2], orig.shape[1])
        _, big = render_scene(refined, psize[0], psize[1], options=sim)
        obs_overlay = viz.mask_overlay(orig, upscale(obs.seg, psize))
        pred_overlay = viz.mask_overlay(orig, big.seg)
        cols = [obs_overlay, pred_overlay, big.rgb]
        names = ["observed + pseudo-GT masks", "observed + re-simulated masks", "re-simulated"]
        viz.side_by_side_mp4(out / "side_by_side.mp4", cols, names, fps=scene_fps)
        sheet_h = rv.sheet_height  # px per tile: six columns of 320 px tiles make a 6 MB PNG
        small = [np.stack([cv2.resize(f, (max(2, round(f.shape[1] * sheet_h / f.shape[0])), sheet_h),
                                      interpolation=cv2.INTER_AREA) for f in c]) for c in cols]
        viz.contact_sheet(out / "contact_sheet.png", small, names,
                          title=f"{Path(video).name}: full IoU {m_ref['full_iou']:.3f} (pseudo GT), "
                                f"{len(refined.objects)} objects, window {obs.start:.2f}-{obs.start + duration:.2f} s")
        clip = obs.clip
        tracks = proposals.tracks if proposals else []
        metrics = {
            "video": str(video), "fps_used": clip.fps, "container_fps": clip.container_fps,
            "window": {"start_s": round(obs.start, 4), "chosen_automatically": obs.auto, "duration_s": duration,
                       "frames": len(obs.frames), "fps": scene_fps, "crop": list(obs.crop),
                       "width": W, "height": H, "original_size": list(clip.original_size)},
            "ground_truth": "pseudo: masks from background subtraction, flow from the same estimator "
                            f"({obs.flow_method})",
            "objects_found": len(tracks),
            "object_pixels": [round(float(np.median(t.area)), 1) for t in tracks],
            "view": proposals.view if proposals else None,
            "perception_notes": notes, "model_note": model_note,
            "sources": {name: _source_summary(scores, sources, name) for name in ("model", "perception")},
            "proposals": [{"source": src, "label": lab, "valid": s["valid"],
                           "full_iou": None if not s["valid"] else round(s["full_iou"], 4),
                           "fitness": None if not s["valid"] else round(s["fitness"], 4)}
                          for src, lab, s in zip(sources, labels, scores)],
            "sample_errors": [e for e in errors if e][:5],
            "first_sample_source": sources[first_i], "first_sample": m_first,
            "best_of_k_source": sources[best], "best_of_k_label": labels[best], "best_of_k": m_best,
            "best_of_k_fittest_label": labels[fittest],
            "best_of_k_cmaes": m_ref, "search_gain": search_gain,
            "cmaes_evaluations": int(history[-1]["evaluations"]) if history else 0,
            "cmaes_seconds": float(history[-1]["seconds"]) if history else 0.0,
            "seconds": round(time.time() - t0, 1),
        }
        if truth is not None:
            metrics["against_labels"] = {"labels": str(labels_path), **score_against_labels(truth, obs, fr.seg)}
        if tracks:   # observed tracks in the scene's world frame: input of `dynamics discrepancy OUT`
            table = infer_tracks.tracks_table(refined, trace.qpos, tracks, scene_fps, W, H, clip=Path(video).stem)
            infer_tracks.write_tracks(out / "tracks.csv", table)
            gap = infer_tracks.resimulation_gap(table, infer_tracks.observed_axes(refined)) if table["t"] else None
            metrics["tracks"] = {"file": "tracks.csv", "rows": len(table["t"]),
                                 "resimulation_rmse_px": None if gap is None else round(gap["rmse_px"], 3)}
        shards.write_json(out / "metrics.json", metrics)
        viz.record_clip(out / "recording.rrd", rgb=obs.frames, seg=fr.seg, flow=obs.flow,
                        positions=trace.qpos[..., :3], quaternions=trace.qpos[..., 3:],
                        objects=scene_objects(refined), camera=camera_dict(refined, W, H), fps=scene_fps,
                        app_id="dynamics_infer",
                        scalars={"iou/frame": sequence_iou(obs.seg, fr.seg)["per_frame"]})
        publish_dir(out, final)
    finally:
        if out.exists():
            shutil.rmtree(out, ignore_errors=True)
    if truth is not None:
        a = metrics["against_labels"]
        print(f"[infer] against {labels_path} ({a['n_labelled']} labelled frames in the window): re-simulation "
              f"{a['resim_vs_labels']}, observation {a['observation_vs_labels']} (matched IoU)")
    print(f"[infer] wrote {final}: full IoU {m_ref['full_iou']:.3f} (pseudo GT), EPE {m_ref['epe']:.2f} px, "
          f"{len(refined.objects)} objects, best proposal: {labels[best]}, {metrics['seconds']} s")
    return metrics


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("video", help="any OpenCV-readable video file")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--fps", type=float, default=None, help="true frame rate (overrides the container's)")
    p.add_argument("--start", type=float, default=None,
                   help="start of the 1 s window, s (default: the window with the most object motion)")
    p.add_argument("--model", default=None, help="model folder (default: params paths.model if trained, else the shipped "
                   "checkpoint pipeline/checkpoints/dynamics-tiny); a local "
                   "Qwen2.5-VL folder works when params model.pretrained points at it")
    p.add_argument("--no-model", action="store_true", help="perception proposals only")
    p.add_argument("-k", type=int, default=None, help="samples for Best@K (default params model.k)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--labels", default=None,
                   help="hand labels (folder of NNNN.png, 0 background, 1..n objects) or true masks (npz with seg) of "
                        "the video: also score the re-simulation and the observation against them (metrics.json "
                        "against_labels); never used by the search")
    p.add_argument("--mask-method", default=None, choices=MASK_METHODS,
                   help="how the observation's masks are made (default params realvideo.mask_method; "
                        "docs/observation.md)")
    p.add_argument("--flow-method", default=None, choices=("dis", "farneback", "raft"),
                   help="optical flow of the observation and the model input (default params flow.method)")
    p.add_argument("--raft-weights", default=None, metavar="PTH",
                   help="RAFT checkpoint for --flow-method raft: the authors' raft-small.pth / raft-things.pth "
                        "or one trained here (default params flow.raft_weights, else the shipped weights)")
    p.add_argument("--params", default=None, help="params.yaml (default ./params.yaml)")


def main_cli(args: argparse.Namespace) -> int:
    params = load_params(args.params)
    if args.mask_method is not None:
        params.setdefault("realvideo", {})["mask_method"] = args.mask_method
    if args.flow_method is not None:
        params.setdefault("flow", {})["method"] = args.flow_method
    if args.raft_weights is not None:   # a command-line path is relative to the working folder
        params.setdefault("flow", {})["raft_weights"] = str(Path(args.raft_weights).resolve())
    metrics = reconstruct(args.video, args.out, params, fps=args.fps, start=args.start,
                          model_dir=args.model, k=args.k, seed=args.seed, use_model=not args.no_model,
                          labels=args.labels)
    print(json.dumps({k: metrics[k] for k in ("sources", "first_sample", "best_of_k", "best_of_k_cmaes", "against_labels")
                      if k in metrics},
                     indent=1), file=sys.stdout)
    return 0
