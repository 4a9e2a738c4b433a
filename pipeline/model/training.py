"""Training: batches, learning-rate schedule, the loop, checkpoints and the training curve.

Batches are built by :func:`pipeline.model.batch.collate` (sequence layout there). The schedule
runs on optimiser steps only (a busy machine changes the time, never the result).
"""

from __future__ import annotations

import csv
import io
import math
import shutil
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from tqdm.auto import tqdm

from pipeline.codec import SceneCodec, composition_of, split_completion
from pipeline.model.batch import collate, to_device
from pipeline.model.config import ModelConfig, ModelError
from pipeline.model.network import (AUX_HEAD_FILE, CompositionHead, VisionTap, build_model, composition_targets,
                                    load_model, n_parameters)
from pipeline.model.sampling import generate_many, load_codec, save_codec, to_scene
from pipeline.model.tokenizer import extend_tokenizer
from pipeline.shards import remove_stale_temps, replace_path, temp_dir_for, write_bytes, write_text

CURVE_FILE = "train_curve.csv"
CURVE_PNG = "train_curve.png"
TRAINER_STATE_FILE = "trainer_state.pt"
CONFIG_FILE = "dynamics_model.json"
CURVE_COLUMNS = ("step", "train_loss", "aux_loss", "val_loss", "val_composition", "val_valid", "lr", "seconds",
                 "examples_per_s")

Example = tuple[np.ndarray, str]
"""One training example: frames ``(n_input_frames, H, W, 3) uint8`` and the target text."""


# ----------------------------------------------------------------------------- batches
def batch_indices(n: int, cfg: ModelConfig, step: int) -> np.ndarray:
    """Indices of the training batch at ``step``: epoch-wise shuffles seeded by ``(seed, epoch)``.

    Every example is seen once per epoch; the draw depends only on ``(cfg.seed, step, n)``, so
    a resumed run sees the same batches.
    """
    start = step * cfg.batch_size
    out = []
    while len(out) < cfg.batch_size:
        epoch, offset = divmod(start + len(out), n)
        perm = np.random.default_rng([cfg.seed, epoch]).permutation(n)
        out.extend(perm[offset: offset + cfg.batch_size - len(out)].tolist())
    return np.asarray(out)


def get_batch(examples: Sequence[Example], tokenizer, cfg: ModelConfig, step: int) -> tuple[dict, list]:
    """Training batch at ``step`` and the compositions of its targets (for the aux loss)."""
    idx = batch_indices(len(examples), cfg, step)
    items = [examples[i] for i in idx]
    return collate(items, tokenizer, cfg), [composition_of(t.split()) for _, t in items]


def resolve_device(cfg: ModelConfig) -> torch.device:
    """The torch device of ``cfg.device`` (``auto``: cuda when torch sees a GPU, else cpu).

    Raises:
        ModelError: ``cuda`` asked for where torch sees no GPU.
    """
    if cfg.device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if cfg.device == "cuda" and not torch.cuda.is_available():
        raise ModelError("model.device: cuda, but torch sees no GPU here (use cpu or auto)")
    return torch.device(cfg.device)


def _autocast(cfg: ModelConfig, device: torch.device | None = None):
    kind = device.type if device is not None else "cpu"
    return torch.autocast(kind, dtype=torch.bfloat16, enabled=cfg.precision == "bf16")


@torch.no_grad()
def estimate_loss(model, examples: Sequence[Example], tokenizer, cfg: ModelConfig) -> float:
    """Mean loss over the first ``cfg.eval_batches * cfg.batch_size`` examples (fixed set).

    Returns:
        Mean token cross-entropy (nats), ``nan`` if ``examples`` is empty.
    """
    if not examples:
        return float("nan")
    was_training = model.training
    model.eval()
    device = next(model.parameters()).device
    n = min(len(examples), cfg.eval_batches * cfg.batch_size)
    losses = []
    for start in range(0, n, cfg.batch_size):
        batch = to_device(collate(examples[start: min(n, start + cfg.batch_size)], tokenizer, cfg), device)
        with _autocast(cfg, device):
            losses.append(model(**batch, use_cache=False).loss.float().item())
    model.train(was_training)
    return float(np.mean(losses))


@torch.no_grad()
def evaluate_samples(model, examples: Sequence[Example], tokenizer, cfg: ModelConfig,
                     codec: SceneCodec) -> dict[str, float]:
    """Greedy constrained decoding of the first ``cfg.eval_samples`` examples.

    Returns:
        ``{"composition": fraction whose shape multiset equals the target's, "valid": fraction
        that detokenise to a scene}`` (``nan`` without examples).
    """
    ex = list(examples[: cfg.eval_samples])
    if not ex:
        return {"composition": float("nan"), "valid": float("nan")}
    greedy = cfg.model_copy(update={"temperature": 0.0})
    hits = valid = 0
    for start in range(0, len(ex), 8):
        chunk = ex[start: start + 8]
        outs = generate_many(model, tokenizer, [f for f, _ in chunk], greedy, codec)
        for toks, (_, target) in zip(outs, chunk):
            scene, _ = to_scene(toks, codec)
            valid += scene is not None
            _, answer = split_completion(toks)
            hits += answer is not None and composition_of(answer) == composition_of(target.split())
    return {"composition": hits / len(ex), "valid": valid / len(ex)}


# ----------------------------------------------------------------------------- schedule
def lr_at(step: int, cfg: ModelConfig) -> float:
    """Learning rate at optimiser step ``step`` (0-based).

    Linear warmup from ``lr / warmup_steps`` to ``lr`` over ``warmup_steps`` steps, then cosine
    decay from ``lr`` to ``min_lr`` over the remaining ``max_steps - warmup_steps`` steps
    (nanoGPT's schedule; Loshchilov & Hutter, SGDR, 2017).
    """
    if step < cfg.warmup_steps:
        return cfg.lr * (step + 1) / cfg.warmup_steps
    span = max(1, cfg.max_steps - cfg.warmup_steps)
    p = min(1.0, (step - cfg.warmup_steps) / span)
    return cfg.min_lr + 0.5 * (1.0 + math.cos(math.pi * p)) * (cfg.lr - cfg.min_lr)


def configure_optimizer(params: list[torch.nn.Parameter], cfg: ModelConfig) -> torch.optim.AdamW:
    """AdamW with weight decay on matrices only (not on biases and norms), as nanoGPT."""
    params = [p for p in params if p.requires_grad]
    groups = [
        {"params": [p for p in params if p.dim() >= 2], "weight_decay": cfg.weight_decay},
        {"params": [p for p in params if p.dim() < 2], "weight_decay": 0.0},
    ]
    return torch.optim.AdamW(groups, lr=cfg.lr, betas=(0.9, 0.95))


# ----------------------------------------------------------------------------- loop
def train(
    train_examples: Sequence[Example],
    val_examples: Sequence[Example],
    cfg: ModelConfig,
    out_dir: str | Path,
    tokenizer=None,
    codec: SceneCodec | None = None,
    think_words: Sequence[str] = (),
    resume: bool = False,
    progress: bool = True,
) -> dict[str, Any]:
    """Train the model for ``cfg.max_steps`` optimiser steps; checkpoint at every evaluation.

    The loop: batch (:func:`get_batch`), learning rate (:func:`lr_at`), forward under bf16
    autocast (``cfg.precision``), loss = LM loss + ``cfg.aux_weight`` x composition loss
    (:class:`CompositionHead`), backward, clip, AdamW. Every ``cfg.eval_interval`` steps: the
    validation loss (:func:`estimate_loss`), greedy constrained samples' composition accuracy
    (:func:`evaluate_samples`), a row of ``train_curve.csv`` and a checkpoint.
    ``cfg.init`` names a checkpoint folder to start from (``scratch`` = random weights).

    Args:
        train_examples: ``(frames, target text)`` pairs.
        val_examples: same, for validation (may be empty).
        cfg: model config (``cfg.threads`` torch threads).
        out_dir: checkpoint folder (created).
        tokenizer: the word-level tokenizer of the targets (ignored when starting from
            ``cfg.init`` or resuming: the checkpoint's is used).
        codec: scene codec (saved with the checkpoint; needed for validation samples).
        think_words: the think vocabulary (saved with the codec for the grammar).
        resume: continue from the checkpoint in ``out_dir`` if there is one.
        progress: show a tqdm progress bar.

    Returns:
        ``{"step", "seconds", "train_loss", "val_loss", "val_composition", "n_parameters",
        "examples_per_s", "stopped_by"}``; ``stopped_by`` is ``max_steps`` or ``max_minutes``.

    Raises:
        ModelError: no training examples, no tokenizer, or an init checkpoint whose codec
        differs from ``codec``.
    """
    if not train_examples:
        raise ModelError("train: no training examples (is the train split empty?)")
    torch.set_num_threads(cfg.threads)
    out_dir = Path(out_dir)

    remove_stale_temps(out_dir)              # leftovers of a killed save (resume keeps out_dir itself)
    out_dir.mkdir(parents=True, exist_ok=True)
    state_path = out_dir / TRAINER_STATE_FILE
    torch.manual_seed(cfg.seed)
    head = None
    if resume and state_path.exists():
        model, tokenizer = load_model(out_dir)
        state = torch.load(state_path, map_location="cpu", weights_only=False)
        _check_resumable(state["config"], cfg, out_dir)
        step, seconds, curve = int(state["step"]), float(state["seconds"]), read_curve(out_dir)
        codec, think_words = load_codec(out_dir)
    else:
        if cfg.init_dir is not None:
            model, tokenizer = load_model(cfg.init_dir)
            init_codec, init_words = load_codec(cfg.init_dir)
            if codec is not None and init_codec.to_dict() != codec.to_dict():
                if not cfg.init_new_codec and not codec.extends(init_codec):  # more objects only: same tokens
                    raise ModelError(f"model.init: {cfg.init}: its codec.json differs from params (tokens/sample "
                                     f"ranges); use model.init: scratch, the same ranges, or model.init_new_codec")
                # the init's weights, the params' codec: bins keep their tokens and change meaning
                if extend_tokenizer(tokenizer, codec, think_words):
                    model.resize_token_embeddings(len(tokenizer))
            else:
                codec, think_words = init_codec, init_words
            if (cfg.init_dir / AUX_HEAD_FILE).exists():   # its targets are clipped to its own max_objects
                head = torch.load(cfg.init_dir / AUX_HEAD_FILE, map_location="cpu", weights_only=False)
        else:
            if tokenizer is None:
                raise ModelError("train: no tokenizer given (build one with build_tokenizer)")
            model = build_model(cfg, tokenizer)
        step, seconds, curve, state = 0, 0.0, [], None
    model.train()
    if codec is None:
        raise ModelError("train: no scene codec given")
    save_codec(out_dir, codec, think_words)
    if head is None:
        head = (torch.load(out_dir / AUX_HEAD_FILE, map_location="cpu", weights_only=False)
                if state is not None and (out_dir / AUX_HEAD_FILE).exists()
                else CompositionHead(model.config.text_config.hidden_size, codec.max_objects))
    device = resolve_device(cfg)
    model.to(device)
    head.to(device)
    head.train()
    tap = VisionTap(model)
    optimizer = configure_optimizer(list(model.parameters()) + list(head.parameters()), cfg)
    if state is not None:
        optimizer.load_state_dict(state["optimizer"])

    budget_s = cfg.max_minutes * 60.0 if cfg.max_minutes else float("inf")
    recent: list[float] = []
    recent_aux: list[float] = []
    bar = tqdm(total=cfg.max_steps, initial=step, disable=not progress, desc="train", unit="step")
    start = time.monotonic() - seconds
    window_t, window_steps = time.monotonic(), 0
    stopped_by = "max_steps"
    while step < cfg.max_steps:
        if seconds >= budget_s:
            stopped_by = "max_minutes"
            break
        lr = lr_at(step, cfg)
        for group in optimizer.param_groups:
            group["lr"] = lr
        batch, comps = get_batch(train_examples, tokenizer, cfg, step)
        batch = to_device(batch, device)
        with _autocast(cfg, device):
            lm_loss = model(**batch, use_cache=False).loss.float()
            aux = torch.zeros((), device=device)
            if cfg.aux_weight > 0:
                logits = head(tap.pooled(batch["video_grid_thw"])).float()
                aux = torch.nn.functional.cross_entropy(
                    logits.flatten(0, 1), composition_targets(comps, head.max_objects).to(device).flatten())
        loss = lm_loss + cfg.aux_weight * aux
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if cfg.grad_clip > 0:
            torch.nn.utils.clip_grad_norm_(list(model.parameters()) + list(head.parameters()), cfg.grad_clip)
        optimizer.step()
        step += 1
        window_steps += 1
        recent.append(lm_loss.item())
        recent_aux.append(float(aux.item()))
        seconds = time.monotonic() - start
        bar.update(1)
        bar.set_postfix(loss=f"{recent[-1]:.3f}", aux=f"{recent_aux[-1]:.3f}", lr=f"{lr:.1e}")
        done = step >= cfg.max_steps or seconds >= budget_s
        if step % cfg.eval_interval == 0 or done:
            rate = window_steps * cfg.batch_size / max(1e-9, time.monotonic() - window_t)
            val = estimate_loss(model, val_examples, tokenizer, cfg)
            samples = evaluate_samples(model, val_examples, tokenizer, cfg, codec) if cfg.eval_samples else {}
            row = {"step": step, "train_loss": float(np.mean(recent)), "aux_loss": float(np.mean(recent_aux)),
                   "val_loss": val, "val_composition": samples.get("composition", float("nan")),
                   "val_valid": samples.get("valid", float("nan")), "lr": lr,
                   "seconds": round(time.monotonic() - start, 2), "examples_per_s": round(rate, 2)}
            curve.append(row)
            recent, recent_aux = [], []
            bar.write(f"step {step}: train {row['train_loss']:.4f} aux {row['aux_loss']:.3f} val {val:.4f} "
                      f"comp {row['val_composition']:.2f} valid {row['val_valid']:.2f} ({rate:.1f} ex/s)")
            save_checkpoint(out_dir, model, tokenizer, head, optimizer, step, time.monotonic() - start, cfg, curve)
            seconds = time.monotonic() - start
            window_t, window_steps = time.monotonic(), 0
    bar.close()
    tap.remove()
    last = curve[-1] if curve else {}
    return {
        "step": step, "seconds": round(seconds, 2), "train_loss": last.get("train_loss", float("nan")),
        "val_loss": last.get("val_loss", float("nan")), "val_composition": last.get("val_composition", float("nan")),
        "n_parameters": n_parameters(model), "examples_per_s": round(step * cfg.batch_size / max(seconds, 1e-9), 2),
        "stopped_by": stopped_by,
    }


RESUMABLE_FIELDS = frozenset({"max_steps", "max_minutes", "eval_interval", "eval_batches", "eval_samples",
                              "max_new_tokens", "k", "temperature", "top_p", "threads", "constrained", "init",
                              "device"})
"""Config fields that may change between a checkpoint and its resumed run (budget, sampling)."""


def _check_resumable(saved: dict[str, Any], cfg: ModelConfig, out_dir: Path) -> None:
    for key, value in saved.items():
        if key not in RESUMABLE_FIELDS and getattr(cfg, key, value) != value:
            raise ModelError(f"{out_dir}: cannot resume: model.{key} was {value!r} in the checkpoint, now "
                             f"{getattr(cfg, key)!r} (start over without resume)")


def save_checkpoint(out_dir: Path, model, tokenizer, head: torch.nn.Module, optimizer: torch.optim.Optimizer,
                    step: int, seconds: float, cfg: ModelConfig, curve: list[dict[str, float]]) -> None:
    """Write model, tokenizer, aux head, trainer state, config and curve into ``out_dir``.

    Everything is written to a temporary sibling folder, with the other files of ``out_dir``
    (e.g. ``codec.json``) copied in, and the folder is swapped in whole
    (:func:`pipeline.shards.replace_path`): after ``kill -9`` at any point ``out_dir`` holds the
    previous checkpoint or the new one, never a mix.
    """
    out_dir = Path(out_dir)
    tmp = temp_dir_for(out_dir)
    try:
        model.save_pretrained(str(tmp))
        tokenizer.save_pretrained(str(tmp))
        torch.save(head, tmp / AUX_HEAD_FILE)
        (tmp / CONFIG_FILE).write_text(cfg.model_dump_json(indent=2) + "\n")
        _write_curve(tmp / CURVE_FILE, curve)
        torch.save({"optimizer": optimizer.state_dict(), "step": step, "seconds": seconds,
                    "config": cfg.model_dump()}, tmp / TRAINER_STATE_FILE)
        if out_dir.is_dir():
            for old in out_dir.iterdir():
                if not (tmp / old.name).exists():
                    (shutil.copytree if old.is_dir() else shutil.copy2)(old, tmp / old.name)
        replace_path(tmp, out_dir)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _write_curve(path: Path, curve: list[dict[str, float]]) -> None:
    buf = io.StringIO(newline="")
    writer = csv.DictWriter(buf, fieldnames=CURVE_COLUMNS)
    writer.writeheader()
    writer.writerows(curve)
    write_text(path, buf.getvalue())


def read_curve(model_dir: str | Path) -> list[dict[str, float]]:
    """Rows of ``train_curve.csv`` (step as int, the rest as float); ``[]`` if there is none."""
    path = Path(model_dir) / CURVE_FILE
    if not path.exists():
        return []
    with open(path, newline="") as f:
        return [{k: (int(v) if k == "step" else float(v)) for k, v in row.items() if v not in (None, "")}
                for row in csv.DictReader(f)]


def plot_curve(model_dir: str | Path, png: str | Path | None = None) -> Path | None:
    """Plot train/val loss and validation composition accuracy against step.

    Returns:
        The PNG path, or ``None`` if there is no curve.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curve = read_curve(model_dir)
    if not curve:
        return None
    png = Path(png) if png else Path(model_dir) / CURVE_PNG
    steps = [r["step"] for r in curve]
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(9, 3.2), dpi=120)
    marker = "o" if len(curve) < 3 else None
    ax.plot(steps, [r["train_loss"] for r in curve], label="train", marker=marker)
    ax.plot(steps, [r["val_loss"] for r in curve], label="val", marker=marker)
    ax.set_xlabel("optimiser step")
    ax.set_ylabel("loss (nats / token)")
    ax.set_yscale("log")
    ax.legend()
    ax.grid(alpha=0.3)
    ax2.plot(steps, [r.get("val_composition", float("nan")) for r in curve], marker=marker or ".", label="composition")
    ax2.plot(steps, [r.get("val_valid", float("nan")) for r in curve], marker=marker or ".", label="valid")
    ax2.set_ylim(-0.02, 1.02)
    ax2.set_xlabel("optimiser step")
    ax2.set_ylabel("val accuracy (greedy, constrained)")
    ax2.legend()
    ax2.grid(alpha=0.3)
    fig.tight_layout()

    buf = io.BytesIO()
    fig.savefig(buf, format="png")          # temp-then-rename: a killed run leaves no half PNG
    plt.close(fig)
    write_bytes(png, buf.getvalue())
    return png
