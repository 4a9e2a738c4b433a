"""Step 4 of the main job (:mod:`pipeline.reconstruct`): the outputs of ``dynamics infer``.

:func:`write_outputs` scores the first sample, the Best@K pick and the written scene against the
observation, renders the figures and writes every file of the output folder (listed in
:mod:`pipeline.reconstruct`'s docstring) into a temporary folder beside it, published at the end
(:func:`pipeline.atomic.publish_dir`): a run killed midway leaves no folder that looks complete.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np

from pipeline import infer_tracks, shards, viz
from pipeline.atomic import publish_dir, remove_stale_temps, temp_dir_for
from pipeline.labels import score_against_labels
from pipeline.metrics import flow_epe, sequence_iou
from pipeline.mjcf import SimOptions
from pipeline.npz import NpzWriter
from pipeline.observe import Observation, original_frames, source_frames, upscale
from pipeline.render import render_scene
from pipeline.scene import Scene
from pipeline.shard_viewer import camera_dict, scene_objects


VIEW_BINS = (22.5, 67.5)
"""deg: a written camera pitch below the first is a side view, above the second a top-down view, and
an oblique view between (halfway between the views' canonical 0, 45 and 90 deg)."""


def view_of_pitch(pitch: float) -> str:
    """``"side"``, ``"oblique"`` or ``"top"`` for a camera pitch in deg (:data:`VIEW_BINS`)."""
    return "side" if pitch < VIEW_BINS[0] else "top" if pitch > VIEW_BINS[1] else "oblique"


def scene_scores(scene: Scene, obs: Observation, sim: SimOptions) -> tuple[dict, tuple]:
    """Re-simulate ``scene`` at the observation's working size and score it against what the
    search fits (``obs.fit_seg``: the observed objects that move, docs/design.md §7).

    Returns:
        ``({initial_iou, full_iou, strict_full_iou, foreground_iou_full, epe}, (trace, frames))``:
        IoUs in [0, 1] (``strict_full_iou`` None when no observed object is visible: no free
        credit, issue 29 item 7), EPE in px over the union of foregrounds; the render for reuse.
    """
    W, H = obs.size
    trace, fr = render_scene(scene, W, H, options=sim)
    iou = sequence_iou(obs.fit_seg, fr.seg)
    strict = iou["strict_iou"]
    epe = flow_epe(fr.flow, obs.flow, fr.seg[:-1] >= 0, obs.fit_seg[:-1] >= 0)
    return {"initial_iou": round(iou["initial_iou"], 4), "full_iou": round(iou["full_iou"], 4),
            "strict_full_iou": None if not np.isfinite(strict) else round(float(strict), 4),
            "foreground_iou_full": round(iou["foreground_iou_full"], 4), "epe": round(epe, 4)}, (trace, fr)


def source_summary(candidates: Sequence[Any], scores: list[dict], source: str) -> dict:
    """Per proposal source (``model``, ``perception``) of the main job's candidates
    (:class:`pipeline.reconstruct.Candidate`): how many, how many valid, and the best one's full
    IoU, strict IoU and fitness (None when none is valid; strict IoU None when no observed object
    is visible)."""
    mine = [s for c, s in zip(candidates, scores) if c.source == source]
    valid = [s for s in mine if s["valid"]]
    best = max(valid, key=lambda s: s["fitness"]) if valid else None
    strict = None if best is None else best.get("strict_iou")
    return {"proposals": len(mine), "valid": len(valid),
            "best_full_iou": None if best is None else round(best["full_iou"], 4),
            "best_strict_iou": None if strict is None or not np.isfinite(strict) else round(float(strict), 4),
            "best_fitness": None if best is None else round(best["fitness"], 4)}


def write_observation(path: Path, obs: Observation) -> None:
    """``observation.npz``: ``seg (T, H, W)`` int8 object ids at the working size (-1 background),
    ``crop [x, y, w, h]`` and ``size [W, H]`` int64 px, ``start`` s, ``fps`` (the scene's) and
    ``source_fps`` float64, ``source_frames (T,)`` int64, ``moving (n,)`` bool, and ``times (T,)``
    s where dropped frames were repaired (the design's observation artifact, issue 36)."""
    with NpzWriter(path) as npz:
        for key, value in (("seg", obs.seg.astype(np.int8)), ("crop", np.asarray(obs.crop, dtype=np.int64)),
                           ("size", np.asarray(obs.size, dtype=np.int64)), ("start", np.float64(obs.start)),
                           ("fps", np.float64(obs.scene_fps)), ("source_fps", np.float64(obs.clip.fps)),
                           ("source_frames", source_frames(obs)),
                           ("moving", np.asarray(obs.moving_flags, dtype=bool))):
            npz.write(key, value)
        if getattr(obs, "frame_times", None) is not None:   # frames picked by capture time (drops repaired)
            npz.write("times", np.asarray(obs.frame_times, dtype=np.float64))


def write_nothing_seen(out: str | Path, video: str | Path, obs: Observation, reason: str,
                       started: float | None = None) -> None:
    """The output folder of a window in which nothing was seen: ``observation.npz`` (every frame
    background; what a check against the truth reads) and ``metrics.json`` with ``error`` and the
    window, and no scene (there is nothing to fit it to). Written like :func:`write_outputs`:
    staged beside ``out`` and moved in as a whole."""
    started = time.time() if started is None else started
    final = Path(out)
    remove_stale_temps(final)
    out = temp_dir_for(final)
    try:
        write_observation(out / "observation.npz", obs)
        clip = obs.clip
        shards.write_json(out / "metrics.json", {
            "video": str(video), "error": reason, "fps_used": clip.fps, "container_fps": clip.container_fps,
            "window": {"start_s": round(obs.start, 4), "chosen_automatically": obs.auto, "duration_s": obs.duration,
                       "frames": len(obs.frames), "fps": obs.scene_fps, "crop": list(obs.crop),
                       "width": obs.size[0], "height": obs.size[1], "original_size": list(clip.original_size)},
            "objects_observed": {"moving": 0, "at_rest": 0}, "seconds": round(time.time() - started, 1)})
        publish_dir(out, final)
    finally:
        if out.exists():
            shutil.rmtree(out, ignore_errors=True)


def write_outputs(out: str | Path, video: str | Path, fps: float | None, obs: Observation,
                  candidates: Sequence[Any], outcome: Any, proposals: Any, notes: list[str],
                  model_note: str | None, rv: Any, sim: SimOptions, truth: np.ndarray | None = None,
                  labels_path: str | Path | None = None, started: float | None = None) -> dict:
    """Write the main job's output folder and return its metrics.

    Args:
        out: output folder (replaced as a whole at the end).
        video: the video file; fps: its true frame rate (overrides the container's), or None.
        obs: the observation the search fitted.
        candidates, outcome: the proposals (:class:`pipeline.reconstruct.Candidate`) and what the
            search made of them (:class:`pipeline.reconstruct.SearchOutcome`; this module does
            not import the main job's module, which imports it).
        proposals, notes, model_note: perception's result (:class:`pipeline.perception.Proposals`
            or None) and notes, the model's note.
        rv: the ``realvideo`` section (:class:`pipeline.reconstruct.RealVideoConfig`: figure sizes).
        sim: simulation options.
        truth: hand labels of the video (:func:`pipeline.labels.load_labels`), or None;
            ``labels_path`` where they came from.
        started: ``time.time()`` when the job started (for ``seconds``).
    Returns:
        the metrics dict written to ``metrics.json``.
    """
    started = time.time() if started is None else started
    scores, best, written = outcome.scores, outcome.best, outcome.written
    W, H = obs.size
    scene_fps, duration = obs.scene_fps, obs.duration
    first_i = next(i for i, c in enumerate(candidates) if c.scene is not None)
    m_first, _ = scene_scores(candidates[first_i].scene, obs, sim)
    m_best, _ = scene_scores(candidates[best].scene, obs, sim)
    m_ref, (trace, fr) = scene_scores(written, obs, sim)
    history = outcome.history

    final = Path(out)
    remove_stale_temps(final)
    out = temp_dir_for(final)
    try:
        shards.write_text(out / "scene.yaml", written.to_yaml())
        with NpzWriter(out / "masks.npz") as npz:   # the masks that were scored, as `dynamics simulate` writes them
            npz.write("seg", fr.seg)
            npz.write("names", np.asarray(written.object_names))
        write_observation(out / "observation.npz", obs)   # what was fitted, to be checked against truth
        # for people: original frames at panel height, masks drawn over them
        orig = original_frames(obs, video, fps, height=rv.panel_height)
        psize = (orig.shape[2], orig.shape[1])
        _, big = render_scene(written, psize[0], psize[1], options=sim)
        cols = [viz.mask_overlay(orig, upscale(obs.seg, psize)), viz.mask_overlay(orig, big.seg), big.rgb]
        names = ["observed + pseudo-GT masks", "observed + re-simulated masks", "re-simulated"]
        viz.side_by_side_mp4(out / "side_by_side.mp4", cols, names, fps=scene_fps)
        sheet_h = rv.sheet_height  # px per tile: six columns of 320 px tiles make a 6 MB PNG
        small = [np.stack([cv2.resize(f, (max(2, round(f.shape[1] * sheet_h / f.shape[0])), sheet_h),
                                      interpolation=cv2.INTER_AREA) for f in c]) for c in cols]
        viz.contact_sheet(out / "contact_sheet.png", small, names,
                          title=f"{Path(video).name}: full IoU {m_ref['full_iou']:.3f} (pseudo GT), "
                                f"{len(written.objects)} objects, window {obs.start:.2f}-{obs.start + duration:.2f} s")
        clip = obs.clip
        tracks = proposals.tracks if proposals else []
        metrics = {
            "video": str(video), "fps_used": clip.fps, "container_fps": clip.container_fps,
            "window": {"start_s": round(obs.start, 4), "chosen_automatically": obs.auto, "duration_s": duration,
                       "frames": len(obs.frames), "fps": scene_fps, "crop": list(obs.crop),
                       "width": W, "height": H, "original_size": list(clip.original_size),
                       "dropped_frames_repaired": getattr(obs, "frame_index", None) is not None},
            "ground_truth": f"pseudo: the observation's masks (realvideo.mask_method {obs.mask_method}; the "
                            "search fits its moving objects), flow from the same estimator "
                            f"({obs.flow_method})",
            "objects_found": len(tracks),
            "objects_observed": {"moving": int(sum(obs.moving_flags)),
                                 "at_rest": sum(not m for m in obs.moving_flags)},
            "object_pixels": [round(float(np.median(t.area)), 1) for t in tracks],
            "view": proposals.view if proposals else None,
            "view_written": view_of_pitch(written.camera.pitch),
            "perception_notes": notes, "model_note": model_note,
            "sources": {name: source_summary(candidates, scores, name) for name in ("model", "perception")},
            "proposals": [{"source": c.source, "label": c.label, "valid": s["valid"],
                           "full_iou": None if not s["valid"] else round(s["full_iou"], 4),
                           "fitness": None if not s["valid"] else round(s["fitness"], 4),
                           "silhouette_rank": c.silhouette_rank}
                          for c, s in zip(candidates, scores)],
            "sample_errors": [c.error for c in candidates if c.error][:5],
            "first_sample_source": candidates[first_i].source, "first_sample": m_first,
            "best_of_k_source": candidates[best].source, "best_of_k_label": candidates[best].label,
            "best_of_k": m_best, "best_of_k_fittest_label": candidates[outcome.fittest].label,
            "shape_tiebreak": rv.shape_tiebreak,
            "best_of_k_cmaes": m_ref, "search_gain": outcome.search_gain,
            "cmaes_evaluations": int(history[-1]["evaluations"]) if history else 0,
            "cmaes_seconds": float(history[-1]["seconds"]) if history else 0.0,
            "seconds": round(time.time() - started, 1),
        }
        if truth is not None:
            metrics["against_labels"] = {"labels": str(labels_path), **score_against_labels(truth, obs, fr.seg)}
        if tracks:   # observed tracks in the scene's world frame: input of `dynamics discrepancy OUT`
            table = infer_tracks.tracks_table(written, trace.qpos, tracks, scene_fps, W, H, clip=Path(video).stem)
            infer_tracks.write_tracks(out / "tracks.csv", table)
            gap = infer_tracks.resimulation_gap(table, infer_tracks.observed_axes(written)) if table["t"] else None
            metrics["tracks"] = {"file": "tracks.csv", "rows": len(table["t"]),
                                 "resimulation_rmse_px": None if gap is None else round(gap["rmse_px"], 3)}
        shards.write_json(out / "metrics.json", metrics)
        viz.record_clip(out / "recording.rrd", rgb=obs.frames, seg=fr.seg, flow=obs.flow,
                        positions=trace.qpos[..., :3], quaternions=trace.qpos[..., 3:],
                        objects=scene_objects(written), camera=camera_dict(written, W, H), fps=scene_fps,
                        app_id="dynamics_infer",
                        scalars={"iou/frame": sequence_iou(obs.fit_seg, fr.seg)["per_frame"]})
        publish_dir(out, final)
    finally:
        if out.exists():
            shutil.rmtree(out, ignore_errors=True)
    if truth is not None:
        a = metrics["against_labels"]
        print(f"[infer] against {labels_path} ({a['n_labelled']} labelled frames in the window): re-simulation "
              f"{a['resim_vs_labels']}, observation {a['observation_vs_labels']} (matched IoU)")
    print(f"[infer] wrote {final}: full IoU {m_ref['full_iou']:.3f} (pseudo GT), EPE {m_ref['epe']:.2f} px, "
          f"{len(written.objects)} objects, best proposal: {candidates[best].label}, {metrics['seconds']} s")
    return metrics
