"""Label-free preference optimisation of the scene writer on videos (issue 37; the paper's
second test-time refinement, beside Best-of-K and CMA-ES).

``dynamics adapt VIDEO_OR_FOLDER... --out MODEL_DIR [--model BASE] [--rounds R] [-k K]``:

1. **Observe** every video exactly as ``dynamics infer`` does
   (:func:`pipeline.reconstruct.observe_window`: window, crop to the region of motion, pseudo
   masks, flow) and show it to the model as the main job does (:func:`pipeline.reconstruct.model_view`).
2. Per round: **sample** K completions per video from the current model (params
   ``preference.temperature`` / ``top_p``, under the scene grammar), **re-simulate** each and
   score it with the search's fitness against the observation (strict IoU - lambda * EPE,
   :func:`pipeline.search.best_of_k`, as Best@K scores; against every observed object, moving or
   at rest, by default: ``preference.target``), **pair** the better against the worse
   (:func:`pipeline.model.preference.make_pairs`) and **optimise** the DPO loss against the
   frozen starting model (:func:`pipeline.model.preference.dpo_epochs`; Rafailov et al. 2023).
3. After every round the **guard** (item 4): greedy first samples on ``preference.guard_scenes``
   synthetic scenes drawn as the test split draws them (params ``sample``, split ``test``; a
   seed of their own), composition and full IoU of their re-simulation against the renders. If
   either drops by more than ``preference.guard_drop`` below the starting model's, the round's
   update is discarded and adaptation stops, saying so.

Only the videos and the re-simulations are read: no truth file, true mask or true scene of a
video is ever opened (the guard's scenes are synthetic, drawn here). ``MODEL_DIR`` is a
checkpoint folder that ``dynamics infer --model MODEL_DIR`` loads like the shipped one; it holds
``adapt_state.json`` (rounds done, the log, the base model) and ``adapt_log.csv`` /
``adapt_curve.png`` (beta, reward margin, KL to the reference, guard, per round), and is
written whole after every round (a temporary folder renamed in), so a killed run resumes at the
last finished round (with a fresh AdamW: its moments are not kept between runs, and every round
draws new pairs anyway).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from tqdm import tqdm

from pipeline.atomic import replace_path, temp_dir_for
from pipeline.errors import UserError
from pipeline.flow import flow_config, flow_of
from pipeline.metrics import sequence_iou
from pipeline.mjcf import SimOptions
from pipeline.params import load_params, section, typed_section
from pipeline.reconstruct import job_settings, model_view, observe_window, resolve_model_dir
from pipeline.render import render_scene
from pipeline.sample_config import SampleConfig, scene_seed
from pipeline.sampler import SceneFilter, sample_scene
from pipeline.scene import Decimals
from pipeline.search import EvaluatorPool, best_of_k
from pipeline.search.staged import at_width
from pipeline.video import VideoError

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg")
"""File endings taken as videos when a folder is given."""
STATE_FILE = "adapt_state.json"
LOG_FILE = "adapt_log.csv"
CURVE_PNG = "adapt_curve.png"
CARD_FILE = "ADAPTED.md"
LOG_COLUMNS = ("round", "videos", "samples", "valid", "pairs", "mean_fitness", "best_fitness", "beta", "lr", "loss",
               "reward_margin", "reward_accuracy", "kl", "guard_composition", "guard_full_iou", "accepted", "seconds")


class AdaptError(UserError):
    """Bad input to ``dynamics adapt`` (no video, unusable base model, a mismatched resume)."""


class PreferenceConfig(BaseModel):
    """Params section ``preference`` (issue 37).

    ``enabled`` turns the ``preference`` DVC stage on (off: the stage passes the fine-tuned model
    through unchanged); ``videos``: files or folders the stage adapts on (no labels needed);
    ``fps``: their true frame rate (None: each container's). Per round: ``k`` samples per video at
    ``temperature`` / ``top_p`` (more varied than Best@K's 0.1 / 0.9, so that samples differ),
    pairs of samples whose fitness differs by ``margin`` (``pairs``: ``best_worst`` or ``all``),
    DPO with ``beta`` at learning rate ``lr`` for ``epochs`` passes of ``batch_pairs`` pairs per
    step. ``target``: the observed objects a sample is scored against, ``all`` (moving and at
    rest, ``Observation.seg``: the model writes whole scenes) or ``moving`` (``Observation.fit_seg``,
    what the main job's Best@K fits before perception adds the objects at rest). ``guard_scenes`` synthetic scenes check composition and full IoU after each round;
    a drop above ``guard_drop`` stops (0 scenes: no guard).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    enabled: bool = False
    videos: list[str] = Field(default_factory=lambda: ["../shared/data/real/video"])
    fps: float | None = Field(None, gt=0)
    rounds: int = Field(2, ge=1)
    k: int = Field(8, ge=2)
    temperature: float = Field(1.0, gt=0)
    top_p: float = Field(0.95, gt=0, le=1)
    beta: float = Field(0.1, gt=0)
    lr: float = Field(2e-5, gt=0)
    epochs: int = Field(2, ge=1)
    batch_pairs: int = Field(4, ge=1)
    margin: float = Field(0.02, ge=0)
    pairs: Literal["best_worst", "all"] = "all"
    target: Literal["all", "moving"] = "all"
    guard_scenes: int = Field(100, ge=0)
    guard_drop: float = Field(0.02, ge=0)
    seed: int = 0


def preference_config(params: dict, **overrides) -> PreferenceConfig:
    """:class:`PreferenceConfig` of params (section optional), with ``overrides`` (None ignored)."""
    return typed_section(params, "preference", PreferenceConfig,
                         overrides={k: v for k, v in overrides.items() if v is not None})


def reward_target(obs, target: str) -> np.ndarray:
    """``(T, H, W)`` int8 observed labels a sample is scored against: all observed objects
    (``target == "all"``) or the moving ones (``"moving"``, :attr:`pipeline.observe.Observation.fit_seg`)."""
    return obs.seg if target == "all" else obs.fit_seg


def collect_videos(paths: list[str | Path]) -> list[Path]:
    """Video files of ``paths``: files as given, folders searched recursively for
    :data:`VIDEO_SUFFIXES` (sorted; nothing else in them is read).

    Raises:
        AdaptError: a path does not exist, or no video is found.
    """
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            out += sorted(f for f in p.rglob("*") if f.is_file() and f.suffix.lower() in VIDEO_SUFFIXES)
        elif p.is_file():
            out.append(p)
        else:
            raise AdaptError(f"{p}: no such video or folder")
    if not out:
        raise AdaptError(f"{', '.join(map(str, paths)) or 'videos'}: no video found ({' '.join(VIDEO_SUFFIXES)})")
    return out


# ----------------------------------------------------------------------------- the guard
@dataclass
class GuardSet:
    """Synthetic scenes for the guard: model inputs, true compositions and true masks."""

    inputs: list[np.ndarray]
    compositions: list[tuple[str, ...]]
    segs: list[np.ndarray]
    scenes: list


def guard_set(params: dict, mcfg, n: int, seed: int) -> GuardSet:
    """``n`` scenes drawn as the test split draws them (params ``sample``, split ``test``,
    :func:`pipeline.sampler.sample_scene`, seeds ``scene_seed(seed, i)``), rendered at the render
    size, their flow estimated as the flow stage does, and shown to the model as in training."""
    from pipeline.model import model_input

    render = section(params, "render")
    W, H = int(render["width"]), int(render["height"])
    cfg = typed_section(params, "sample", SampleConfig, required=True, overrides={"width": W, "height": H})
    sim = typed_section(params, "sim", SimOptions, required=True)
    decimals = typed_section(params, "scene.decimals", Decimals)
    fcfg = flow_config(params)
    out = GuardSet([], [], [], [])
    with SceneFilter(cfg, sim) as filt:
        for i in range(n):
            scene = sample_scene(np.random.default_rng(scene_seed(seed, i)), cfg, "test", filt, decimals)
            _, fr = render_scene(scene, W, H, options=sim)
            out.inputs.append(model_input(fr.rgb, flow_of(fr.rgb, fcfg), mcfg, fcfg.max_magnitude))
            out.compositions.append(tuple(sorted(o.shape for o in scene.objects)))
            out.segs.append(fr.seg)
            out.scenes.append(scene)
    return out


def guard_scores(model, tokenizer, codec, mcfg, gs: GuardSet, params: dict) -> dict[str, float]:
    """Greedy first samples on the guard set: ``{composition, full_iou}`` (fractions / mean IoU
    over all frames against the renders; an invalid or unsimulatable sample scores 0)."""
    import torch

    from pipeline.model import generate_many, to_scene

    if not gs.inputs:
        return {"composition": float("nan"), "full_iou": float("nan")}
    render = section(params, "render")
    W, H = int(render["width"]), int(render["height"])
    sim = typed_section(params, "sim", SimOptions, required=True)
    greedy = mcfg.model_copy(update={"temperature": 0.0})
    comps, ious = [], []
    with torch.no_grad():
        outs = []
        for i in range(0, len(gs.inputs), 8):
            outs += generate_many(model, tokenizer, gs.inputs[i: i + 8], greedy, codec)
    for toks, comp, seg, truth in zip(outs, gs.compositions, gs.segs, gs.scenes):
        scene, _ = to_scene(toks, codec)
        comps.append(scene is not None and tuple(sorted(o.shape for o in scene.objects)) == comp)
        iou = 0.0
        if scene is not None:
            try:
                _, fr = render_scene(scene.replace(fps=truth.fps, duration=truth.duration), W, H, options=sim)
                iou = float(sequence_iou(seg, fr.seg)["full_iou"])
            except Exception:   # noqa: BLE001 - a sample MuJoCo cannot run scores 0, as in Best@K
                iou = 0.0
        ious.append(iou)
    return {"composition": float(np.mean(comps)), "full_iou": float(np.mean(ious))}


# ----------------------------------------------------------------------------- checkpoint
def save_adapted(out: Path, base: Path, model, state: dict, log: list[dict]) -> None:
    """Write the adapted checkpoint whole: the base folder's files (tokenizer, codec, config),
    the new weights, ``adapt_state.json``, ``adapt_log.csv`` and the curve, into a temporary
    sibling folder renamed over ``out`` (:func:`pipeline.shards.replace_path`)."""

    tmp = temp_dir_for(out)
    try:
        shutil.copytree(base, tmp, dirs_exist_ok=True,
                        ignore=shutil.ignore_patterns("trainer_state.pt", "*.safetensors", STATE_FILE, LOG_FILE,
                                                      CURVE_PNG, CARD_FILE))
        model.save_pretrained(str(tmp))
        (tmp / STATE_FILE).write_text(json.dumps(state, indent=1) + "\n")
        buf = io.StringIO(newline="")
        w = csv.DictWriter(buf, fieldnames=LOG_COLUMNS, extrasaction="ignore")
        w.writeheader()
        w.writerows(log)
        (tmp / LOG_FILE).write_text(buf.getvalue())
        plot_log(log, tmp / CURVE_PNG)
        last = log[-1] if log else {}
        (tmp / CARD_FILE).write_text(
            f"# Adapted checkpoint (dynamics adapt, issue 37)\n\nThe weights here are `{base}` after "
            f"{state['rounds_done']} round(s) of label-free DPO on {len(state['videos'])} videos "
            f"(`{STATE_FILE}` lists them; `{LOG_FILE}` and `{CURVE_PNG}` give beta, the reward margin, the KL to "
            f"the reference and the guard per round). The other files (tokenizer, codec, any model card) are the "
            f"base model's.\n\nLast round: {json.dumps(last)}\n"
            + (f"\nStopped: {state['stopped']}\n" if state.get("stopped") else ""))
        replace_path(tmp, out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def plot_log(log: list[dict], png: Path) -> None:
    """Reward margin, KL to the reference and the guard per round (one PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in log if r.get("round", 0) > 0]
    fig, ax = plt.subplots(1, 3, figsize=(11, 3))
    r = [x["round"] for x in rows]
    ax[0].plot(r, [x["reward_margin"] for x in rows], "o-")
    ax[0].set_title("DPO reward margin (nats x beta)")
    ax[1].plot(r, [x["kl"] for x in rows], "o-")
    ax[1].set_title("KL to the reference (nats)")
    g0 = [x for x in log if x.get("round") == 0]
    rr = [x["round"] for x in g0 + rows]
    ax[2].plot(rr, [x["guard_composition"] for x in g0 + rows], "o-", label="composition")
    ax[2].plot(rr, [x["guard_full_iou"] for x in g0 + rows], "s-", label="full IoU")
    ax[2].set_title("guard: synthetic scenes")
    ax[2].legend()
    for a in ax:
        a.set_xlabel("round")
    fig.tight_layout()
    fig.savefig(png, dpi=90)
    plt.close(fig)


def log_markdown(logs: dict[str, list[dict]], stopped: dict[str, str | None]) -> list[str]:
    """Markdown lines of adapt logs (one table, a row per run and round, :data:`LOG_COLUMNS`), then
    each run's stop message."""
    lines = ["| run | round | videos | pairs | mean fitness of the samples | beta | loss | reward margin | accuracy | KL "
             "| guard composition | guard full IoU | kept | s |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]

    def cell(r: dict, key: str, fmt: str = "{:.4f}") -> str:
        v = r.get(key)
        return "" if v is None else (fmt.format(v) if isinstance(v, float) else str(v))

    for run, log in logs.items():
        for r in log:
            lines.append(f"| {run} | {r['round']} | {cell(r, 'videos')} | {cell(r, 'pairs')} | {cell(r, 'mean_fitness')} | "
                         f"{cell(r, 'beta')} | {cell(r, 'loss')} | {cell(r, 'reward_margin')} | "
                         f"{cell(r, 'reward_accuracy', '{:.2f}')} | {cell(r, 'kl')} | "
                         f"{cell(r, 'guard_composition', '{:.3f}')} | {cell(r, 'guard_full_iou', '{:.3f}')} | "
                         f"{cell(r, 'accepted')} | {cell(r, 'seconds', '{:.0f}')} |")
    lines += [f"\n{run}: {st}" for run, st in stopped.items() if st]
    return lines


# ----------------------------------------------------------------------------- the loop
def adapt(videos: list[str | Path], out: str | Path, params: dict, base: str | Path | None = None,
          rounds: int | None = None, k: int | None = None, fps: float | dict[str, float] | None = None,
          progress: bool = True,
          **overrides) -> dict:
    """Adapt a scene writer to videos without labels (module docstring).

    Args:
        videos: files or folders (:func:`collect_videos`).
        out: the adapted checkpoint folder (resumed when it holds ``adapt_state.json`` of the same
            base model and videos).
        params: parsed params.yaml (sections ``realvideo``, ``flow``, ``search``, ``sim``,
            ``model``, ``render``, ``sample``, ``preference``).
        base: the starting model folder (default: the one ``dynamics infer`` uses).
        rounds, k: override ``preference.rounds`` / ``k``; ``overrides``: any other field of
            :class:`PreferenceConfig`.
        fps: the videos' true frame rate (overrides ``preference.fps``), or a mapping from a
            video's path, file name or stem to its rate (others: ``preference.fps``, else the
            container's), for sets shot at different rates.
        progress: tqdm bars.
    Returns:
        the final state: ``{base, videos, rounds_done, stopped, log}`` (``log`` one row per round,
        :data:`LOG_COLUMNS`; row 0 is the starting model's guard).
    Raises:
        AdaptError: no video, no usable video (each unobservable), no base model, a resume of
            another base; ModelError / ParamsError from their readers.
    """
    import torch

    from pipeline import model as vlm
    from pipeline.model.preference import dpo_epochs, kl_to_reference, make_pairs

    t_start = time.time()
    pc = preference_config(params, rounds=rounds, k=k, fps=None if isinstance(fps, dict) else fps, **overrides)
    rates = fps if isinstance(fps, dict) else {}
    files = collect_videos(videos)
    job = job_settings(params)
    base_dir = resolve_model_dir(base, params)
    if base_dir is None:
        raise AdaptError("no model to adapt: pass --model (a checkpoint folder) or run the finetune stage")
    out = Path(out)
    if out.resolve() == Path(base_dir).resolve():
        raise AdaptError(f"{out}: --out must differ from the base model folder")
    torch.set_num_threads(int(section(params, "model").get("threads", 2)))
    torch.manual_seed(pc.seed)

    state = {"base": str(base_dir), "videos": [str(f) for f in files], "rounds_done": 0, "stopped": None,
             "log": [], "config": pc.model_dump()}
    policy_dir = Path(base_dir)
    if (out / STATE_FILE).exists():
        old = json.loads((out / STATE_FILE).read_text())
        if old.get("base") != state["base"] or old.get("videos") != state["videos"]:
            raise AdaptError(f"{out}: holds an adaptation of {old.get('base')} on {len(old.get('videos', []))} "
                             f"videos, not of {base_dir} on these {len(files)}: choose another --out")
        state.update(rounds_done=int(old["rounds_done"]), stopped=old.get("stopped"), log=old["log"])
        policy_dir = out
        print(f"[adapt] resuming {out} after round {state['rounds_done']}")
    if state["stopped"]:
        print(f"[adapt] {out}: stopped before: {state['stopped']}")
        return state
    if state["rounds_done"] >= pc.rounds:
        print(f"[adapt] {out}: all {pc.rounds} rounds done")
        return state

    reference, tok = vlm.load_model(base_dir)
    for p in reference.parameters():
        p.requires_grad_(False)
    policy, _ = vlm.load_model(policy_dir)
    codec, _ = vlm.load_codec(base_dir)
    mcfg = vlm.checkpoint_config(base_dir, vlm.ModelConfig.from_params(params))
    sampling = mcfg.model_copy(update={"temperature": pc.temperature, "top_p": pc.top_p})

    # 1. observe once: the observation does not depend on the model
    observed = []
    for f in tqdm(files, desc="adapt: observe", unit="video", disable=not progress):
        try:
            rate = rates.get(str(f), rates.get(f.name, rates.get(f.stem, pc.fps)))
            obs = observe_window(f, job, fps=rate)
        except VideoError as exc:
            print(f"[adapt] {f}: skipped: {exc}")
            continue
        if not (reward_target(obs, pc.target) >= 0).any():
            print(f"[adapt] {f}: skipped: no {'moving ' if pc.target == 'moving' else ''}object observed "
                  "(nothing to reward against)")
            continue
        observed.append((f, obs, model_view(obs.frames, params, mcfg)))
    if not observed:
        raise AdaptError(f"{len(files)} videos: none could be observed with a moving object")
    inputs = [x for _, _, x in observed]

    gs = guard_set(params, mcfg, pc.guard_scenes, pc.seed + 7919) if pc.guard_scenes else GuardSet([], [], [], [])
    if not state["log"]:
        g0 = guard_scores(reference, tok, codec, mcfg, gs, params)
        state["log"].append({"round": 0, "guard_composition": g0["composition"], "guard_full_iou": g0["full_iou"],
                             "accepted": True, "seconds": round(time.time() - t_start, 1)})
        print(f"[adapt] start: guard composition {g0['composition']:.3f}, full IoU {g0['full_iou']:.3f} "
              f"on {len(gs.inputs)} synthetic scenes")
    g_ref = state["log"][0]
    opt = torch.optim.AdamW(policy.parameters(), lr=pc.lr, weight_decay=0.0)

    for r in range(state["rounds_done"] + 1, pc.rounds + 1):
        t0 = time.time()
        texts: list[tuple[int, str]] = []
        pairs, fits, n_valid = [], [], 0
        threads = torch.get_num_threads()
        for i, (f, obs, x) in enumerate(tqdm(observed, desc=f"adapt round {r}: sample + score", unit="video",
                                             disable=not progress)):
            torch.set_num_threads(1)   # decoding K short sequences (as stages/predict.py)
            try:
                toks = vlm.generate(policy, tok, x, sampling, codec, k=pc.k, seed=pc.seed + 100_003 * r + i)
            finally:
                torch.set_num_threads(threads)
            scenes = []
            for t in toks:
                s, _ = vlm.to_scene(t, codec)
                scenes.append(None if s is None else s.replace(fps=obs.scene_fps, duration=obs.duration))
            with EvaluatorPool(*obs.size, job.sim) as pool:
                scores, _ = best_of_k(scenes, reward_target(obs, pc.target), obs.fit_flow, at_width(job.scfg, obs.size[0]), job.sim,
                                      pool=pool)
            fitness = [float(s["fitness"]) if s.get("valid") else None for s in scores]
            n_valid += sum(v is not None for v in fitness)
            fits += [v for v in fitness if v is not None]
            strs = [" ".join(t) for t in toks]
            texts += [(i, s) for s in strs]
            pairs += make_pairs(i, strs, fitness, pc.margin, pc.pairs)   # unparsable / unsimulatable: rejected
        saved = {k_: v.detach().clone() for k_, v in policy.state_dict().items()}
        n_steps = pc.epochs * -(-len(pairs) // pc.batch_pairs)
        with tqdm(total=n_steps, desc=f"adapt round {r}: DPO", unit="step", disable=not progress) as bar:
            stats = dpo_epochs(policy, reference, inputs, pairs, tok, mcfg, pc.beta, pc.lr, pc.epochs,
                               pc.batch_pairs, pc.seed + r, optimizer=opt, progress=bar)
        kl = kl_to_reference(policy, reference, inputs, texts, tok, mcfg)
        g = guard_scores(policy, tok, codec, mcfg, gs, params)
        drop_c = g_ref["guard_composition"] - g["composition"]
        drop_i = g_ref["guard_full_iou"] - g["full_iou"]
        accepted = not (drop_c > pc.guard_drop or drop_i > pc.guard_drop)
        row = {"round": r, "videos": len(observed), "samples": len(texts), "valid": n_valid, "pairs": len(pairs),
               "mean_fitness": float(np.mean(fits)) if fits else float("nan"),
               "best_fitness": float(np.max(fits)) if fits else float("nan"), "beta": pc.beta, "lr": pc.lr,
               "loss": stats["loss"], "reward_margin": stats["reward_margin"],
               "reward_accuracy": stats["reward_accuracy"], "kl": kl, "guard_composition": g["composition"],
               "guard_full_iou": g["full_iou"], "accepted": accepted, "seconds": round(time.time() - t0, 1)}
        row = {k_: (round(v, 5) if isinstance(v, float) else v) for k_, v in row.items()}
        state["log"].append(row)
        print(f"[adapt] round {r}: {len(pairs)} pairs from {len(texts)} samples of {len(observed)} videos; "
              f"loss {stats['loss']:.4f}, reward margin {stats['reward_margin']:.4f}, accuracy "
              f"{stats['reward_accuracy']:.2f}, KL {kl:.4f}; guard composition {g['composition']:.3f} "
              f"(start {g_ref['guard_composition']:.3f}), full IoU {g['full_iou']:.3f} "
              f"(start {g_ref['guard_full_iou']:.3f}); {row['seconds']:.0f} s")
        if not accepted:
            policy.load_state_dict(saved)
            state["stopped"] = (f"round {r}: the guard dropped (composition {g_ref['guard_composition']:.3f} -> "
                                f"{g['composition']:.3f}, full IoU {g_ref['guard_full_iou']:.3f} -> "
                                f"{g['full_iou']:.3f}; limit {pc.guard_drop}): its update was discarded")
            print(f"[adapt] stopped: {state['stopped']}")
        else:
            state["rounds_done"] = r
        save_adapted(out, Path(base_dir), policy, state, state["log"])
        if not accepted:
            break
    state["seconds"] = round(time.time() - t_start, 1)
    print(f"[adapt] {out}: {state['rounds_done']} rounds kept; `dynamics infer VIDEO --model {out}` uses it")
    return state


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("videos", nargs="+", metavar="VIDEO_OR_FOLDER",
                   help=f"videos, or folders searched for {' '.join(VIDEO_SUFFIXES)} (nothing else in them is read)")
    p.add_argument("--out", required=True, metavar="MODEL_DIR", help="the adapted checkpoint folder (resumed if present)")
    p.add_argument("--model", default=None, metavar="BASE",
                   help="the model to adapt (default: the one `dynamics infer` uses, params realvideo.model)")
    p.add_argument("--rounds", type=int, default=None, help="sample -> rank -> optimise rounds (params preference.rounds)")
    p.add_argument("-k", type=int, default=None, help="samples per video and round (params preference.k)")
    p.add_argument("--fps", type=float, default=None, help="true frame rate of the videos (default: each container's)")
    p.add_argument("--params", default=None, help="params.yaml (default ./params.yaml)")


def main_cli(args: argparse.Namespace) -> int:
    params = load_params(args.params)
    state = adapt(args.videos, args.out, params, base=args.model, rounds=args.rounds, k=args.k, fps=args.fps)
    return 0 if state["rounds_done"] or state["stopped"] else 1


__all__ = ["PreferenceConfig", "preference_config", "collect_videos", "adapt", "guard_set", "guard_scores", "log_markdown",
           "AdaptError"]
