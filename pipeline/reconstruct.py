"""Main job: reconstruct an executable scene from a real video.

``dynamics infer VIDEO --out DIR [--fps F] [--start S]`` reads a 1 s window of any
OpenCV-readable video (``--fps`` overrides a wrong container rate, e.g. 240 for the PhysTrack
clips; without ``--start`` the window with the most object motion is chosen), cut to the region
of motion at the video's aspect ratio (:mod:`pipeline.observe`), and proposes scenes from two
sources: the model's K samples (when a model is available) and the perception proposals
(:mod:`pipeline.perception`, no training needed). All proposals are re-simulated and scored
together (Best@K), and the best is refined by staged CMA-ES (:mod:`pipeline.search.staged`).
:func:`reconstruct` reads as these four steps: observe (:func:`pipeline.observe.observe`) ->
propose (:func:`propose_candidates`: one list of :class:`Candidate`) -> search
(:func:`search_scene`) -> report (:func:`pipeline.infer_report.write_outputs`). Outputs in DIR:

* ``scene.yaml``: the refined scene (scene language v1, canonical form): the better, by the
  search's fitness, of the search's result and the Best@K pick it started from, each with
  initial overlaps resolved and checked as ``dynamics simulate`` checks it, so that
  ``dynamics simulate scene.yaml`` runs as it is and gives ``masks.npz``;
* ``observation.npz``: the observation (issue 36): ``seg (T, H, W) int8``
  pseudo masks at the working size (-1 background), ``crop`` ``[x, y, w, h]`` px of the
  original frame, ``size`` ``[W, H]`` px, ``start`` s and ``fps`` of the window, ``source_fps`` and
  ``source_frames`` ``(T,)`` int64 (the decoded frame, 0-based, behind each window frame), ``times``
  ``(T,)`` float64 s when frames were dropped and the window's were picked by capture time
  (:func:`pipeline.observe.retimed`; absent otherwise: ``k / fps``), and
  ``moving`` ``(K,)`` bool per object id of ``seg``: the search fits the objects that move
  (:attr:`pipeline.observe.Observation.fit_seg`); objects at rest stay in ``seg``;
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
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator
from tqdm import tqdm

from pipeline import infer_report, perception
from pipeline.flow import FlowConfig, flow_config, flow_of
from pipeline.labels import load_labels
from pipeline.mjcf import SimOptions
from pipeline.observe import (LEARNED, MASK_METHODS, MIN_WINDOW_FRAMES, Observation, observe, scene_rate,
                              without_scenery)
from pipeline.params import ParamsError, load_params, path_of, section, typed_section
from pipeline.sanity import PhysicsError, SanityConfig, check_simulation, resolve_overlaps
from pipeline.scene import Scene, SceneError
from pipeline.search import EvaluatorPool, SearchConfig, best_of_k, simplest_within
from pipeline.segmenter import SegmenterError, resolve_weights, shipped
from pipeline.search.staged import at_width, score_scene, staged_refine
from pipeline.video import VideoError, read_video


MAX_WINDOW_FRAMES = 300
"""Most frames of the main job's window (``realvideo.duration * realvideo.fps``; the default is
30). The search scores the whole window at once, so its frames, flow and masks stay in memory
(~2.5 MB per frame at the working size with the side-by-side panels): the limit keeps a run
under ~1 GB and is checked before the video is decoded (issue 35)."""


class RealVideoConfig(BaseModel):
    """Params section ``realvideo``: the main job ``dynamics infer VIDEO``.

    The window (``fps`` frames per s of scene time, ``duration`` s), the observation
    (``mask_method``, one of :data:`pipeline.observe.MASK_METHODS`; ``max_objects`` tracks;
    ``segmenter_weights``: the object segmenter's checkpoint, None = the shipped one, ``wide`` = the
    GPU-trained wider one, or a path, :func:`pipeline.segmenter.resolve_weights`;
    ``rest_segmenter_weights``: a second checkpoint, read the same way, that ``hybrid`` asks for
    objects at rest where the first found nothing (None: none,
    :func:`pipeline.observe.second_opinion_rests`); ``fine_scale``: its
    probabilities fused with the detection pass's where those are finer, :data:`pipeline.observe.FINE_SCALE`;
    ``scenery``: ``keep`` places every object at rest, ``drop`` leaves out those no mover touches,
    :func:`pipeline.observe.without_scenery`), the
    scene writer without ``--model`` (``model``: ``wide``, ``trained`` or a folder,
    :func:`default_model_dir`), the
    staged CMA-ES (``popsize`` and ``iterations`` per stage, ``restarts`` of the first stage,
    ``workers`` scoring processes, fitness ``IoU - lambda_epe * EPE`` with EPE per px at 96 px
    wide, averaged over ``epe_pixels``: ``observed`` foreground pixels by default, so that a
    predicted object away from the motion cannot lower it, :class:`pipeline.search.SearchConfig`;
    ``shape_margin``: among the proposals of the best one's structure within this fitness of it,
    Best@K takes the one with the fewest shape parameters, :func:`pipeline.search.simplest_within`;
    ``shape_tiebreak: silhouette``, opt-in, first the one whose shapes the silhouettes favour,
    :func:`pipeline.perception.silhouette_rank`: measured in docs/realvideo.md, it helped a real
    cube and cost the rendered held-out sets' shapes) and the figures (``panel_height``, ``sheet_height`` in px). The defaults are the
    default profile's (a test checks that params.yaml agrees).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    fps: int = Field(30, ge=1)
    duration: float = Field(1.0, gt=0)
    mask_method: str = "hybrid"
    segmenter_weights: str | None = None
    rest_segmenter_weights: str | None = "wide"
    fine_scale: bool = False
    model: str = "trained"
    max_objects: int = Field(4, ge=1)
    scenery: Literal["keep", "drop"] = "keep"
    popsize: int = Field(10, ge=2)
    iterations: int = Field(8, ge=1)
    restarts: int = Field(2, ge=1)
    workers: int = Field(2, ge=1)
    lambda_epe: float = Field(0.05, ge=0)
    epe_pixels: Literal["union", "observed"] = "observed"
    shape_margin: float = Field(0.02, ge=0)
    shape_tiebreak: Literal["parameters", "silhouette"] = "parameters"
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


@dataclass(frozen=True)
class JobSettings:
    """The main job's settings, read and checked from params before any video is decoded.

    Attributes:
        rv: section ``realvideo``; fcfg: the flow estimator (section ``flow``);
        scfg: the search (section ``search`` with ``realvideo``'s popsize, iterations, lambda_epe
            and epe_pixels); sim, sanity: sections ``sim`` and ``sanity``;
        segmenter: the object segmenter the observation uses (:func:`pipeline.segmenter.shipped`);
        rest_segmenter: the second one for objects at rest, or None.
    """

    rv: RealVideoConfig
    fcfg: FlowConfig
    scfg: SearchConfig
    sim: SimOptions
    sanity: SanityConfig
    segmenter: object
    rest_segmenter: object = None


def job_settings(params: dict) -> JobSettings:
    """:class:`JobSettings` of ``params`` (``dynamics infer``, ``dynamics adapt`` and the benchmarks
    that must observe a video exactly as the main job does share them).

    Raises:
        ParamsError: a section is invalid, the segmenter's weights cannot be loaded, or the window
            (``realvideo.duration * realvideo.fps``) is out of 2..:data:`MAX_WINDOW_FRAMES` frames.
    """
    rv = realvideo_config(params)
    fcfg = flow_config(params)
    scfg = typed_section(params, "search", SearchConfig, required=True)
    scfg = scfg.model_copy(update={"popsize": rv.popsize, "iterations": rv.iterations, "lambda_epe": rv.lambda_epe,
                                   "epe_pixels": rv.epe_pixels})
    sim = typed_section(params, "sim", SimOptions, required=True)
    sanity = typed_section(params, "sanity", SanityConfig)
    segmenter, rest_segmenter = observation_segmenters(params)
    frames = int(round(rv.fps * rv.duration))
    if not 2 <= frames <= MAX_WINDOW_FRAMES:   # before any video is decoded
        raise ParamsError(f"{getattr(params, 'source', 'params.yaml')}: realvideo.duration * realvideo.fps: must give "
                          f"2..{MAX_WINDOW_FRAMES} frames (the main job holds the window's frames, flow and masks "
                          f"in memory, ~2.5 MB per frame), got {frames}")
    return JobSettings(rv, fcfg, scfg, sim, sanity, segmenter, rest_segmenter)


def observation_segmenters(params: dict) -> tuple[object, object]:
    """The observation's segmenters of params ``realvideo``: ``(segmenter, rest_segmenter)``
    (:func:`pipeline.segmenter.shipped` of ``segmenter_weights`` and of
    ``rest_segmenter_weights``, the second None when that is null), loaded before any video is
    decoded.

    Raises:
        ParamsError: a checkpoint is missing or unreadable (one line naming the field).
    """
    rv = realvideo_config(params)
    out = []
    for field in ("segmenter_weights", "rest_segmenter_weights"):
        choice = getattr(rv, field)
        if field == "rest_segmenter_weights" and choice is None:
            out.append(None)
            continue
        try:
            out.append(shipped(resolve_weights(choice, getattr(params, "root", None))))
        except SegmenterError as exc:
            raise ParamsError(f"{getattr(params, 'source', 'params.yaml')}: realvideo.{field}: {exc}") from None
    return out[0], out[1]


def observe_window(video: str | Path, job: JobSettings, fps: float | None = None, start: float | None = None
                   ) -> Observation:
    """Step 1 of the main job: the scene rate (a clip too short for the window at
    ``realvideo.fps`` gets a higher one, :func:`pipeline.observe.scene_rate`), then
    :func:`pipeline.observe.observe` of the window with the main job's settings.

    Args:
        video: video file; fps: its true frame rate (None: the container's); start: window start, s
            (None: chosen, :func:`pipeline.observe.choose_start`).
    Raises:
        VideoError: unreadable video or window past its end.
    """
    rv = job.rv
    scene_fps = rv.fps
    if start is None:   # a clip too short for the window at realvideo.fps gets a higher scene rate
        scene_fps = scene_rate(video, fps, rv.fps)
        if scene_fps != rv.fps:
            why = (f"recorded at a lower rate than {rv.fps} fps" if scene_fps < rv.fps else
                   f"too short for {MIN_WINDOW_FRAMES} frames at {rv.fps} fps")
            print(f"[infer] {video}: {why}: the scene runs at {scene_fps} fps")
    obs = observe(video, fps, start, scene_fps, rv.duration, job.fcfg, rv.mask_method, rv.max_objects, job.segmenter,
                  fine_scale=rv.fine_scale, rest_segmenter=job.rest_segmenter)
    if rv.scenery == "drop":
        obs, dropped = without_scenery(obs)
        if dropped:
            print(f"[infer] {len(dropped)} object(s) at rest that no mover touches left out as scenery "
                  f"(realvideo.scenery: drop)")
    W, H = obs.size
    print(f"[infer] {video}: window {obs.start:.3f}-{obs.start + obs.duration:.3f} s"
          f"{' (chosen automatically)' if obs.auto else ''}, {len(obs.frames)} frames at {obs.scene_fps} fps, "
          f"crop {obs.crop} -> {W}x{H} px")
    return obs


def default_model_dir(params: dict) -> Path | None:
    """The model ``dynamics infer`` uses without ``--model``, by ``realvideo.model``:

    * ``trained`` (default): ``paths.model`` when it holds a trained model (after ``dvc repro``),
      else the shipped checkpoint (:data:`pipeline.model.SHIPPED_CHECKPOINT`) if present, else None;
    * ``wide``: the shipped checkpoint trained on real-looking synthetic scenes
      (:data:`pipeline.model.WIDE_CHECKPOINT`, issue 30), when the package holds it, else as ``trained``;
    * any other value: that folder.
    """
    from pipeline.model import SHIPPED_CHECKPOINT, WIDE_CHECKPOINT

    choice = realvideo_config(params).model
    if choice not in ("wide", "trained"):
        return Path(choice)
    if choice == "wide" and (Path(WIDE_CHECKPOINT) / "config.json").exists():
        return Path(WIDE_CHECKPOINT)
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


def model_view(frames: np.ndarray, params: dict, mcfg) -> np.ndarray:
    """What the model sees of a window, as it was trained: the frames resized to
    ``render.width x render.height`` (area), the flow estimated at that size (params ``flow``),
    and :func:`pipeline.model.vision.model_input` of the two.

    Args:
        frames: ``(T, H, W, 3) uint8`` window at the working size (:class:`pipeline.observe.Observation`).
        mcfg: the model's :class:`pipeline.model.ModelConfig` (:func:`pipeline.model.checkpoint_config`).
    Returns:
        ``(mcfg.n_input_frames, H', W', 3) uint8``.
    """
    from pipeline import model as vlm

    W, H = int(section(params, "render")["width"]), int(section(params, "render")["height"])
    fcfg = flow_config(params)
    small = np.stack([cv2.resize(f, (W, H), interpolation=cv2.INTER_AREA) for f in frames])
    return vlm.model_input(small, flow_of(small, fcfg), mcfg, fcfg.max_magnitude)


def model_samples(model_dir: Path, frames: np.ndarray, params: dict, k: int | None, seed: int,
                  scene_fps: int, duration: float) -> tuple[list[Scene | None], list[str | None]]:
    """K scenes sampled from a model for a clip (None where a sample is not a valid scene).

    The clip is shown to the model as it was trained (:func:`model_view`).
    """
    import torch

    from pipeline import model as vlm

    mcfg = vlm.checkpoint_config(model_dir, vlm.ModelConfig.from_params(params))
    x = model_view(frames, params, mcfg)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as in stages/predict.py: decoding K samples, 1 thread is as fast
    try:   # restored after: the segmenter of a later observation runs on every core
        net, tok = vlm.load_model(model_dir)
        codec, _ = vlm.load_codec(model_dir)
        samples = vlm.generate(net, tok, x, mcfg, codec, k=k or mcfg.k, seed=seed)
    finally:
        torch.set_num_threads(threads)
    scenes, errors = [], []
    for toks in samples:
        s, err = vlm.to_scene(toks, codec)
        scenes.append(s.replace(fps=scene_fps, duration=duration) if s is not None else None)
        errors.append(err)
    return scenes, errors


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


@dataclass
class Candidate:
    """One proposal scored by Best@K.

    Attributes:
        scene: the proposed scene, or None (a model sample that is not a valid scene).
        source: ``"model"`` or ``"perception"``.
        label: a short name for people (``model sample 2``, ``perception: side: sphere``).
        error: why ``scene`` is None (the sample's parse error), else None.
        silhouette_rank: for a perception proposal, how far its shapes are from the
            silhouettes' first choices (:attr:`pipeline.perception.Proposals.silhouette_ranks`);
            None for a model sample.
    """

    scene: Scene | None
    source: str
    label: str
    error: str | None = None
    silhouette_rank: int | None = None


def nothing_seen(obs: Observation) -> str:
    """The one line of a window whose observation holds no object in any frame."""
    return (f"{obs.clip.source}: nothing to reconstruct: no object seen in the window {obs.start:.3f}-"
            f"{obs.start + obs.duration:.3f} s (nothing moves and no object at rest was found; try another window "
            f"with --start)")


def propose_candidates(obs: Observation, mdir: Path | None, params: dict, rv: RealVideoConfig, k: int | None,
                       seed: int) -> tuple[list[Candidate], perception.Proposals | None, list[str]]:
    """Step 2 of the main job: the model's K samples (when ``mdir`` is a model folder) and the
    perception proposals (:func:`pipeline.perception.propose`) for an observation.

    Returns:
        ``(candidates, proposals, notes)``: ``proposals`` is None when perception found no
        object (``notes`` then says why).
    Raises:
        VideoError: the observation holds no object in any frame, moving or at rest (the search
            would score every scene 0, since a frame where nothing is seen gives no credit, so a
            model sample would be written unchecked), or no valid model sample and no object
            found: nothing to reconstruct.
    """
    if not (obs.seg >= 0).any():
        raise VideoError(nothing_seen(obs))
    candidates: list[Candidate] = []
    if mdir is not None:
        scenes, errs = model_samples(mdir, obs.frames, params, k, seed, obs.scene_fps, obs.duration)
        candidates += [Candidate(sc, "model", f"model sample {i}", err) for i, (sc, err) in enumerate(zip(scenes, errs))]
    proposals, notes = None, []
    try:
        fov = perception.crop_fov(obs.crop[3], obs.clip.original_size[1])   # the working image is a crop
        proposals = perception.propose(obs.fit_seg, obs.flow, obs.scene_fps, obs.duration, rv.max_objects,
                                       still=obs.mask_method in LEARNED, fov=fov)
        candidates += [Candidate(sc, "perception", f"perception: {lab}", silhouette_rank=r)
                       for sc, lab, r in zip(proposals.scenes, proposals.labels, proposals.silhouette_ranks)]
        notes = proposals.notes
    except perception.PerceptionError as exc:
        notes = [f"perception: {exc}"]
    if not any(c.scene is not None for c in candidates):
        raise VideoError(f"{obs.clip.source}: nothing to reconstruct: no valid model sample and {notes[0]}")
    print(f"[infer] {sum(c.source == 'model' for c in candidates)} model samples, "
          f"{sum(c.source == 'perception' for c in candidates)} perception proposals")
    return candidates, proposals, notes


@dataclass
class SearchOutcome:
    """What step 3 of the main job found.

    Attributes:
        scores: Best@K's score dict per candidate (:func:`pipeline.search.best_of_k`).
        fittest: index of the fittest candidate (the paper's Best@K).
        best: index of the candidate the search started from (the fittest, or the one with the
            one with the fewest shape parameters within ``realvideo.shape_margin`` of it, or with
            ``realvideo.shape_tiebreak: silhouette`` first the shapes the silhouettes favour).
        written: the scene written to ``scene.yaml``: the better of the staged CMA-ES result and
            its start, made writable (:func:`choose_output`).
        history: the staged CMA-ES history (:func:`pipeline.search.staged.staged_refine`).
        search_gain: for metrics.json: which was written, the gain, the two candidates' scores.
    """

    scores: list[dict]
    fittest: int
    best: int
    written: Scene
    history: list[dict]
    search_gain: dict


def search_scene(candidates: list[Candidate], obs: Observation, scfg: SearchConfig, rv: RealVideoConfig,
                 sim: SimOptions, sanity: SanityConfig, seed: int) -> SearchOutcome:
    """Step 3 of the main job: Best@K over all candidates, the tie-break of shapes the fit cannot
    tell apart (silhouettes, then parsimony: :func:`pipeline.search.simplest_within`), staged CMA-ES from the pick, and the choice of
    what is written (:func:`choose_output`), all with the fitness of ``scfg`` at the
    observation's width (:func:`pipeline.search.staged.at_width`).

    Raises:
        VideoError: no candidate could be simulated.
    """
    W, H = obs.size
    target = obs.fit_seg   # the objects the observation saw move (Observation.fit_seg)
    scenes = [c.scene for c in candidates]
    with EvaluatorPool(W, H, sim) as pool:
        scores, best = best_of_k(scenes, target, obs.fit_flow, at_width(scfg, W), sim, pool=pool)
        if best is None:
            raise VideoError(f"{obs.clip.source}: no proposal could be simulated ({scores[0].get('error')})")
        fittest = best   # the paper's Best@K; then the simplest shapes the re-simulation cannot tell apart
        ranks = [c.silhouette_rank for c in candidates] if rv.shape_tiebreak == "silhouette" else None
        best = simplest_within(scenes, scores, fittest, rv.shape_margin, ranks)
        if best != fittest:
            why = ("shapes the silhouettes favour" if ranks is not None and (candidates[best].silhouette_rank or 0)
                   < (candidates[fittest].silhouette_rank or 0) else "fewer shape parameters")
            print(f"[infer] Best@K: {candidates[best].label} (fitness {scores[best]['fitness']:.4f}) over "
                  f"{candidates[fittest].label} ({scores[fittest]['fitness']:.4f}): {why} within "
                  f"{rv.shape_margin:g}")
        # progress on a terminal only (tqdm's disable=None: off when stderr is not a TTY, so logs and
        # the one-line errors stay clean); updated as each CMA-ES run ends
        with tqdm(desc="[infer] staged CMA-ES", unit="eval", disable=None, leave=False) as bar:
            def progress(entry: dict) -> None:
                bar.update(int(entry["evaluations"]) - bar.n)
                bar.set_postfix(stage=entry["stage"], fitness=f"{entry['best_fitness']:.3f}")

            refined, history = staged_refine(scenes[best], target, obs.fit_flow, scfg, sim, seed=seed,
                                             restarts=rv.restarts, pool=pool, workers=rv.workers, callback=progress)
        # what scene.yaml holds is what is scored: the better of the search's result and its
        # start, each as written (overlaps resolved, canonical text) and as `dynamics simulate` checks it
        chosen, written, choice = choose_output([("cmaes", refined), ("best_of_k", scenes[best])],
                                                target, obs.fit_flow, scfg, sim, sanity, pool=pool)
    gain = choice[0]["fitness"] - choice[1]["fitness"]
    search_gain = {
        "written": choice[chosen]["name"], "fitness_gain": round(gain, 6),
        "full_iou_gain": round(choice[0]["full_iou"] - choice[1]["full_iou"], 6),
        "candidates": choice,
        "note": ("the search found a gain over its start: its result is written" if chosen == 0 and gain > 0 else
                 "the search's result scores as its start: its result is written" if chosen == 0 else
                 "the search found no gain over its start (the Best@K pick): the start is written"
                 if choice[0]["simulate_ok"] or not choice[1]["simulate_ok"] else
                 "the search's result fails dynamics simulate's checks: the start is written"),
    }
    if not choice[chosen]["simulate_ok"]:
        search_gain["note"] += f"; dynamics simulate refuses it: {choice[chosen]['problem']}"
    print(f"[infer] {search_gain['note']} (fitness {choice[0]['fitness']:.4f} vs start {choice[1]['fitness']:.4f})")
    written, search_gain["objects_at_rest"] = add_objects_at_rest(written, obs, scfg, sim, sanity)
    return SearchOutcome(scores, fittest, best, written, history, search_gain)


def add_objects_at_rest(scene: Scene, obs: Observation, scfg: SearchConfig, sim: SimOptions,
                        sanity: SanityConfig) -> tuple[Scene, dict | None]:
    """The observed objects at rest, added to the scene fitted to the movers
    (:func:`pipeline.perception.place_at_rest`) when that scene, made writable, scores better
    against the whole observation (``obs.seg``, movers and objects at rest) with the search's
    fitness and ``dynamics simulate`` accepts it (:func:`choose_output`).

    Returns:
        ``(scene, report)``: the scene to write and, for ``metrics.json``, None when the
        observation has no object at rest, else ``{added, notes, candidates}``.
    """
    flags = obs.moving_flags
    if all(flags) or not any(flags):
        return scene, None
    placed, notes = perception.place_at_rest(scene, obs.seg, flags, *obs.size)
    if placed is scene:
        return scene, {"added": 0, "notes": notes, "candidates": []}
    chosen, out, choice = choose_output([("with_objects_at_rest", placed), ("movers_only", scene)], obs.seg, obs.fit_flow,
                                        scfg, sim, sanity)
    n_placed = len(placed.objects) - len(scene.objects)
    added = n_placed if chosen == 0 else 0
    print(f"[infer] objects at rest: {n_placed} placed, "
          f"{'added' if chosen == 0 else 'not added'} (fitness against the whole observation "
          f"{choice[0]['fitness']:.4f} with them, {choice[1]['fitness']:.4f} without)")
    return (out if chosen == 0 else scene), {"added": added, "notes": notes, "candidates": choice}


def reconstruct(video: str | Path, out: str | Path, params: dict, fps: float | None = None,
                start: float | None = None, model_dir: str | Path | None = None, k: int | None = None,
                seed: int = 0, use_model: bool = True, labels: str | Path | None = None) -> dict:
    """Run the main job on one video and write its outputs (see module docstring): observe
    (:func:`pipeline.observe.observe`) -> propose (:func:`propose_candidates`) -> search
    (:func:`search_scene`) -> report (:func:`pipeline.infer_report.write_outputs`).

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
        VideoError: unreadable video, window past its end, or nothing to reconstruct (no object
            seen in the window: ``out`` then holds ``observation.npz`` and ``metrics.json`` with
            ``error``, no scene; or no model sample and no moving object found).
        ModelError: ``model_dir`` (or the default trained model) is not a usable checkpoint;
            raised before the video is decoded.
        ParamsError: ``k`` is negative (0: no model sample).
    """
    if k is not None and k < 0:
        raise ParamsError(f"k: samples for Best@K must be >= 0 (0: perception proposals only), got {k}")
    # llvmpipe rasterizing in the calling thread is 5-10 % faster for these small renders
    # (benchmarks/search_eval.py --compare-lp); pixels do not depend on it
    os.environ.setdefault("LP_NUM_THREADS", "0")
    t0 = time.time()
    job = job_settings(params)
    rv, scfg, sim, sanity = job.rv, job.scfg, job.sim, job.sanity

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
    truth = None
    if labels is not None:   # read (and checked) before the search, used only after it
        truth = load_labels(labels, read_video(video, fps=fps, max_frames=1).original_size)

    # 1. observe
    obs = observe_window(video, job, fps, start)
    if not (obs.seg >= 0).any():   # no scene to write; the observation is written, for a check against truth
        infer_report.write_nothing_seen(out, video, obs, nothing_seen(obs), started=t0)
        raise VideoError(nothing_seen(obs) + f"; the observation is in {out}/observation.npz")
    # 2. propose
    candidates, proposals, notes = propose_candidates(obs, mdir, params, rv, k, seed)
    # 3. search
    outcome = search_scene(candidates, obs, scfg, rv, sim, sanity, seed)
    # 4. report
    return infer_report.write_outputs(out, video, fps, obs, candidates, outcome, proposals, notes, model_note,
                                      rv, sim, truth=truth, labels_path=labels, started=t0)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("video", help="any OpenCV-readable video file")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--fps", type=float, default=None, help="true frame rate (overrides the container's)")
    p.add_argument("--start", type=float, default=None,
                   help="start of the 1 s window, s (default: the window with the most object motion)")
    p.add_argument("--model", default=None, help="model folder (default: params realvideo.model: trained = params "
                   "paths.model if trained, else the shipped checkpoint pipeline/checkpoints/dynamics-tiny; wide = "
                   "pipeline/checkpoints/dynamics-wide, trained on real-looking scenes); a local "
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
    p.add_argument("--segmenter-weights", default=None, metavar="PT",
                   help="object segmenter checkpoint of the observation: wide (the GPU-trained wider network, "
                        "pipeline/weights/segmenter.md) or a .pt file (default params realvideo.segmenter_weights, "
                        "else the shipped pipeline/weights/segmenter.pt)")
    p.add_argument("--flow-method", default=None, choices=("dis", "farneback", "raft"),
                   help="optical flow of the observation and the model input (default params flow.method)")
    p.add_argument("--raft-weights", default=None, metavar="PTH",
                   help="RAFT checkpoint for --flow-method raft: the authors' raft-small.pth / raft-things.pth "
                        "or one trained here (default params flow.raft_weights, else the shipped weights)")
    p.add_argument("--scenery", default=None, choices=("keep", "drop"),
                   help="objects at rest that no mover touches: keep (placed in the scene) or drop (left out as "
                        "scenery; default params realvideo.scenery)")
    p.add_argument("--params", default=None, help="params.yaml (default ./params.yaml)")


def main_cli(args: argparse.Namespace) -> int:
    params = load_params(args.params)
    if args.mask_method is not None:
        params.setdefault("realvideo", {})["mask_method"] = args.mask_method
    if args.segmenter_weights is not None:   # a command-line path is relative to the working folder
        w = args.segmenter_weights
        params.setdefault("realvideo", {})["segmenter_weights"] = w if w in ("wide", "shipped") else str(Path(w).resolve())
    if args.flow_method is not None:
        params.setdefault("flow", {})["method"] = args.flow_method
    if args.scenery is not None:
        params.setdefault("realvideo", {})["scenery"] = args.scenery
    if args.raft_weights is not None:   # a command-line path is relative to the working folder
        params.setdefault("flow", {})["raft_weights"] = str(Path(args.raft_weights).resolve())
    metrics = reconstruct(args.video, args.out, params, fps=args.fps, start=args.start,
                          model_dir=args.model, k=args.k, seed=args.seed, use_model=not args.no_model,
                          labels=args.labels)
    print(json.dumps({k: metrics[k] for k in ("sources", "first_sample", "best_of_k", "best_of_k_cmaes", "against_labels")
                      if k in metrics},
                     indent=1), file=sys.stdout)
    return 0
