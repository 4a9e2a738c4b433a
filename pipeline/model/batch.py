"""Model inputs of a batch: the prompt (vision tokens), the target's ids and labels, and the
padded tensors ``model(**batch)`` takes (used by training and by sampling).

Sequence layout (one example)::

    <|vision_start|> <|video_pad|> x N <|vision_end|> <think> ... </think> <answer> ... </answer> <eos>
    \\________________ prompt: label -100 ______________/ \\_______________ target: labels ___________/

``N = grid_t * grid_h * grid_w / spatial_merge_size**2`` (one token per merged 2x2 patch group).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from pipeline.model.config import ModelConfig, ModelError
from pipeline.model.tokenizer import VIDEO_PAD, VISION_END, VISION_START, token_id
from pipeline.model.vision import n_video_tokens, video_patches

IGNORE_INDEX = -100
"""Label of positions that carry no loss (prompt, padding)."""
VIDEO_TOKEN_TYPE = 2
"""``mm_token_type_ids`` value of video tokens (0 = text, 1 = image), used for 3-D RoPE."""


def prompt_ids(tokenizer, n_video: int) -> list[int]:
    """``<|vision_start|>`` + ``n_video`` x ``<|video_pad|>`` + ``<|vision_end|>`` as ids."""
    return ([token_id(tokenizer, VISION_START)] + [token_id(tokenizer, VIDEO_PAD)] * n_video
            + [token_id(tokenizer, VISION_END)])


def encode_target(tokenizer, target: str) -> list[int]:
    """Ids of a target text plus EOS.

    Raises:
        ModelError: a word of the target is not in the vocabulary (would become ``<|unk|>``).
    """
    ids = tokenizer.encode(target, add_special_tokens=False)
    if tokenizer.unk_token_id is not None and tokenizer.unk_token_id in ids:
        bad = [w for w, i in zip(target.split(), ids) if i == tokenizer.unk_token_id]
        raise ModelError(f"target: word {bad[0]!r} is not in the tokenizer's vocabulary")
    return ids + [tokenizer.eos_token_id]


def collate(items: Sequence[tuple[np.ndarray, str | None]], tokenizer, cfg: ModelConfig) -> dict[str, torch.Tensor]:
    """Build one batch of model inputs (right-padded).

    Args:
        items: ``(frames (n_input_frames, H, W, 3) uint8, target text or None)`` per example;
            ``None`` builds the prompt only (for generation).
        tokenizer: the model's tokenizer.
        cfg: model config (patch geometry).

    Returns:
        Keyword arguments for ``model(**batch)``: ``input_ids (B, L) int64``,
        ``attention_mask (B, L) int64``, ``mm_token_type_ids (B, L) int64``,
        ``pixel_values_videos (sum N_patches, 3*tp*p*p) float32``, ``video_grid_thw (B, 3) int64``
        and, when targets are given, ``labels (B, L) int64`` (-100 on prompt and padding; the
        model shifts them by one internally).
    """
    video_id = token_id(tokenizer, VIDEO_PAD)
    seqs, labels, patches, grids = [], [], [], []
    for frames, target in items:
        pv, grid = video_patches(frames, cfg)
        prompt = prompt_ids(tokenizer, n_video_tokens(grid, cfg))
        ids, lab = list(prompt), [IGNORE_INDEX] * len(prompt)
        if target is not None:
            tgt = encode_target(tokenizer, target)
            ids += tgt
            lab += tgt
        seqs.append(ids)
        labels.append(lab)
        patches.append(pv)
        grids.append(grid)
    length = max(len(s) for s in seqs)
    input_ids = torch.full((len(seqs), length), tokenizer.pad_token_id, dtype=torch.long)
    label_t = torch.full((len(seqs), length), IGNORE_INDEX, dtype=torch.long)
    mask = torch.zeros((len(seqs), length), dtype=torch.long)
    for i, (s, lab) in enumerate(zip(seqs, labels)):
        input_ids[i, : len(s)] = torch.tensor(s)
        label_t[i, : len(s)] = torch.tensor(lab)
        mask[i, : len(s)] = 1
    batch = {
        "input_ids": input_ids,
        "attention_mask": mask,
        "mm_token_type_ids": (input_ids == video_id).long() * VIDEO_TOKEN_TYPE,
        "pixel_values_videos": torch.from_numpy(np.concatenate(patches)),
        "video_grid_thw": torch.from_numpy(np.concatenate(grids)),
    }
    if any(t is not None for _, t in items):
        batch["labels"] = label_t
    return batch


def to_device(batch: dict[str, torch.Tensor], device: torch.device | str) -> dict[str, torch.Tensor]:
    """The batch's tensors on ``device`` (the same dict on the CPU)."""
    device = torch.device(device)
    return batch if device.type == "cpu" else {k: v.to(device, non_blocking=True) for k, v in batch.items()}
