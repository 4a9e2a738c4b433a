"""The vision-language model: tokenizer, tiny Qwen2.5-VL, training loop and sampling (DESIGN §5).

The model reads ``n_frames`` video frames (colour-coded optical flow or RGB) and writes the
scene as text: ``<think>motion events</think><answer>scene YAML</answer>`` (reasoning on) or
``<answer>scene YAML</answer>`` (reasoning off).

Sequence layout (one example)::

    <|vision_start|> <|video_pad|> x N <|vision_end|> <think> ... </think><answer> ... </answer> <eos>
    \\________________ prompt: label -100 ______________/ \\_______________ target: labels ______________/

``N = grid_t * grid_h * grid_w / spatial_merge_size**2`` (one token per merged 2x2 patch group).
The video patches are laid out exactly as transformers' Qwen2-VL video processor does it
(without torchvision, which it needs and which does not install here; see DESIGN §10).

By default the model is a ~4M-parameter Qwen2.5-VL built from scratch with a tokenizer trained
on the target texts; ``ModelConfig.pretrained`` names a local folder with real Qwen2.5-VL
weights instead (loaded offline with its own tokenizer).

Example::

    cfg = ModelConfig.from_params(load_params())
    tok = train_tokenizer(texts, cfg.vocab_size, "data/tokenizer")
    frames = model_input(rgb, flow, cfg, max_magnitude=8.0)   # (10, 64, 96, 3) uint8
    result = train([(frames, target), ...], val, cfg, "data/model", tokenizer=tok)
    model, tok = load_model("data/model")
    texts = generate(model, tok, frames, cfg, k=4, seed=0)
    think, answer = parse_output(texts[0])
"""

from __future__ import annotations

import csv
import math
import os
import re
import shutil
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, Literal, Sequence

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

if TYPE_CHECKING:  # heavy imports stay lazy: transformers takes ~3 s to import
    from transformers import Qwen2_5_VLForConditionalGeneration

# ----------------------------------------------------------------------------- constants
PAD = "<|pad|>"
EOS = "<|endoftext|>"
THINK, END_THINK = "<think>", "</think>"
ANSWER, END_ANSWER = "<answer>", "</answer>"
VISION_START, VISION_END = "<|vision_start|>", "<|vision_end|>"
VIDEO_PAD = "<|video_pad|>"
IMAGE_PAD = "<|image_pad|>"  # unused (video only) but the config needs an id of its own
SPECIAL_TOKENS = (PAD, EOS, THINK, END_THINK, ANSWER, END_ANSWER, VISION_START, VISION_END, VIDEO_PAD, IMAGE_PAD)
"""Special tokens of the locally trained tokenizer, in id order (ids 0..9)."""

IMAGE_MEAN = (0.48145466, 0.4578275, 0.40821073)
IMAGE_STD = (0.26862954, 0.26130258, 0.27577711)
"""Per-channel normalisation of Qwen2-VL's processors (``OPENAI_CLIP_MEAN`` / ``_STD``), on [0, 1] RGB."""

IGNORE_INDEX = -100
"""Label of positions that carry no loss (prompt, padding)."""
VIDEO_TOKEN_TYPE = 2
"""``mm_token_type_ids`` value of video tokens (0 = text, 1 = image), used for 3-D RoPE."""

CURVE_FILE = "train_curve.csv"
CURVE_PNG = "train_curve.png"
TRAINER_STATE_FILE = "trainer_state.pt"
CONFIG_FILE = "dynamics_model.json"
CURVE_COLUMNS = ("step", "train_loss", "val_loss", "lr", "seconds")

Example = tuple[np.ndarray, str]
"""One training example: frames ``(n_frames, H, W, 3) uint8`` and the target text."""


class ModelError(ValueError):
    """Bad model config or input. ``str(err)`` is one line naming the field and the bad value."""


# ----------------------------------------------------------------------------- config
class ModelConfig(BaseModel):
    """Params section ``model``: architecture, training and sampling settings.

    Geometry: frames are ``H x W`` pixels with ``H, W`` multiples of
    ``patch_size * spatial_merge_size``; ``n_frames`` a multiple of ``temporal_patch_size``.
    Training stops at ``max_steps`` or after ``max_minutes`` of wall-clock time, whichever
    comes first; the cosine learning-rate schedule follows whichever budget is closer to spent.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    # inputs and target
    input: Literal["flow", "rgb"] = "flow"
    reasoning: bool = True
    n_frames: int = Field(10, ge=1)
    # tokenizer
    vocab_size: int = Field(1024, ge=300, le=65536)
    # text decoder
    hidden_size: int = Field(256, ge=8)
    intermediate_size: int = Field(512, ge=8)
    num_layers: int = Field(4, ge=1)
    num_heads: int = Field(4, ge=1)
    num_kv_heads: int = Field(2, ge=1)
    max_position_embeddings: int = Field(4096, ge=64)
    rope_theta: float = Field(1e4, gt=0)
    # vision encoder
    vision_depth: int = Field(2, ge=1)
    vision_hidden_size: int = Field(128, ge=8)
    vision_intermediate_size: int = Field(256, ge=8)
    vision_num_heads: int = Field(4, ge=1)
    patch_size: int = Field(8, ge=1)
    spatial_merge_size: int = Field(2, ge=1)
    temporal_patch_size: int = Field(2, ge=1)
    window_size: int = Field(32, ge=1)
    # training
    batch_size: int = Field(8, ge=1)
    lr: float = Field(1e-3, gt=0)
    min_lr: float = Field(1e-4, ge=0)
    warmup_steps: int = Field(50, ge=0)
    weight_decay: float = Field(0.1, ge=0)
    grad_clip: float = Field(1.0, ge=0)
    max_steps: int = Field(5000, ge=1)
    max_minutes: float = Field(8.0, gt=0)
    eval_interval: int = Field(100, ge=1)
    eval_batches: int = Field(4, ge=1)
    seed: int = 0
    # sampling
    max_new_tokens: int = Field(768, ge=1)  # targets of 4-object scenes: ~500 tokens
    k: int = Field(4, ge=1)
    temperature: float = Field(0.1, ge=0)
    top_p: float = Field(0.9, gt=0, le=1)
    # real weights instead of the tiny model
    pretrained: str | None = None

    @model_validator(mode="after")
    def _consistent(self) -> "ModelConfig":
        if self.n_frames % self.temporal_patch_size:
            raise ValueError(
                f"n_frames: must be a multiple of temporal_patch_size ({self.temporal_patch_size}), got {self.n_frames}"
            )
        if self.hidden_size % self.num_heads:
            raise ValueError(f"hidden_size: must be a multiple of num_heads ({self.num_heads}), got {self.hidden_size}")
        if self.num_heads % self.num_kv_heads:
            raise ValueError(
                f"num_heads: must be a multiple of num_kv_heads ({self.num_kv_heads}), got {self.num_heads}"
            )
        if (self.hidden_size // self.num_heads) % 8:
            raise ValueError(
                f"hidden_size / num_heads: must be a multiple of 8 (3-D RoPE sections), got {self.head_dim}"
            )
        if self.vision_hidden_size % self.vision_num_heads:
            raise ValueError(
                f"vision_hidden_size: must be a multiple of vision_num_heads ({self.vision_num_heads}), "
                f"got {self.vision_hidden_size}"
            )
        if self.min_lr > self.lr:
            raise ValueError(f"min_lr: must be <= lr ({self.lr}), got {self.min_lr}")
        return self

    @classmethod
    def from_params(cls, params: dict[str, Any], source: str = "params.yaml") -> "ModelConfig":
        """Validate section ``model`` of a parsed params.yaml (missing section = defaults).

        ``model.seed`` defaults to the top-level ``seed``.

        Raises:
            ModelError: one line ``<source>: model.<field>: <rule>, got <value>``.
        """
        data = dict(params.get("model") or {})
        if "seed" in params and "seed" not in data:
            data["seed"] = params["seed"]
        try:
            return cls.model_validate(data)
        except ValidationError as exc:
            err = exc.errors()[0]
            loc = ".".join(str(x) for x in err["loc"])
            msg = err["msg"].removeprefix("Value error, ")
            if not loc:  # a cross-field check: its message starts with the field name
                raise ModelError(f"{source}: model.{msg}") from None
            if err["type"] == "extra_forbidden":
                msg = "unknown key"
            elif "input" in err:
                msg += f", got {err['input']!r}"
            raise ModelError(f"{source}: model.{loc}: {msg}") from None

    @property
    def head_dim(self) -> int:
        return self.hidden_size // self.num_heads

    @property
    def mrope_section(self) -> list[int]:
        """3-D RoPE split (t, h, w) of ``head_dim / 2`` as in Qwen2.5-VL (1/4, 3/8, 3/8)."""
        half = self.head_dim // 2
        t = half // 4
        h = (half - t) // 2
        return [t, h, half - t - h]

    @property
    def grid_factor(self) -> int:
        """Frame height and width must be multiples of this (px)."""
        return self.patch_size * self.spatial_merge_size


# ----------------------------------------------------------------------------- target text
def target_text(scene_yaml: str, think: str, reasoning: bool) -> str:
    """The model's target text for one scene.

    Args:
        scene_yaml: canonical scene YAML (``Scene.to_yaml()``).
        think: motion-event text (ignored when ``reasoning`` is off).
        reasoning: put ``<think>{think}</think>`` before the answer.

    Returns:
        ``<think>{think}</think><answer>{scene_yaml}</answer>`` or ``<answer>{scene_yaml}</answer>``.
    """
    answer = f"{ANSWER}{scene_yaml}{END_ANSWER}"
    return f"{THINK}{think}{END_THINK}{answer}" if reasoning else answer


_THINK_RE = re.compile(re.escape(THINK) + r"(.*?)" + re.escape(END_THINK), re.DOTALL)
_ANSWER_RE = re.compile(re.escape(ANSWER) + r"(.*?)" + re.escape(END_ANSWER), re.DOTALL)


def parse_output(text: str) -> tuple[str | None, str | None]:
    """Split a completion into its think and answer parts.

    Args:
        text: decoded completion (special tags kept), e.g. ``target_text(...)``.

    Returns:
        ``(think, answer_yaml)``; either is ``None`` when its opening and closing tags are not
        both there (e.g. a completion cut off by ``max_new_tokens``).
    """
    think = _THINK_RE.search(text)
    answer = _ANSWER_RE.search(text)
    return (think.group(1) if think else None, answer.group(1) if answer else None)


# ----------------------------------------------------------------------------- tokenizer
def train_tokenizer(texts: Iterable[str], vocab_size: int, out_dir: str | Path | None = None):
    """Train a byte-level BPE tokenizer on the target texts.

    Lossless: ``decode(encode(text)) == text`` for any string. Digits are split one per token
    (as Qwen2's tokenizer does) so every number is spelled with the same ten digit tokens;
    the text between digits is not split into words first, so recurring YAML structure such
    as ``"]\n    orientation: ["`` becomes a single token. On scene targets this gives ~40 %
    shorter sequences than GPT-2-style word splitting. The special tokens
    (:data:`SPECIAL_TOKENS`) get ids 0..9 and are never split or merged. The vocabulary can
    end up smaller than ``vocab_size`` when the texts have no more pairs to merge.

    Args:
        texts: training texts (target texts; special tokens inside them are ignored).
        vocab_size: total vocabulary size including the 256 byte tokens and the specials.
        out_dir: if given, ``save_pretrained`` the tokenizer there.

    Returns:
        ``transformers.PreTrainedTokenizerFast`` with ``pad_token`` and ``eos_token`` set.

    Raises:
        ModelError: ``vocab_size`` too small for the byte alphabet and special tokens.
    """
    from tokenizers import Tokenizer, decoders, models, pre_tokenizers, trainers
    from transformers import PreTrainedTokenizerFast

    if vocab_size < 256 + len(SPECIAL_TOKENS):
        raise ModelError(f"vocab_size: must be >= {256 + len(SPECIAL_TOKENS)}, got {vocab_size}")
    specials = re.compile("|".join(re.escape(t) for t in SPECIAL_TOKENS))
    tok = Tokenizer(models.BPE())
    tok.pre_tokenizer = pre_tokenizers.Sequence(
        [
            pre_tokenizers.Digits(individual_digits=True),
            pre_tokenizers.ByteLevel(add_prefix_space=False, use_regex=False),
        ]
    )
    tok.decoder = decoders.ByteLevel()
    trainer = trainers.BpeTrainer(
        vocab_size=vocab_size,
        special_tokens=list(SPECIAL_TOKENS),
        initial_alphabet=pre_tokenizers.ByteLevel.alphabet(),
        min_frequency=2,
        show_progress=False,
    )
    tok.train_from_iterator((piece for t in texts for piece in specials.split(t) if piece), trainer)
    fast = PreTrainedTokenizerFast(
        tokenizer_object=tok,
        pad_token=PAD,
        eos_token=EOS,
        additional_special_tokens=list(SPECIAL_TOKENS[2:]),
        clean_up_tokenization_spaces=False,
        model_max_length=1 << 20,
    )
    if out_dir is not None:
        fast.save_pretrained(str(out_dir))
    return fast


def load_tokenizer(path: str | Path, add_tags: bool = True):
    """Load a tokenizer folder offline (ours or a pretrained Qwen2.5-VL's).

    Args:
        path: folder written by ``save_pretrained``.
        add_tags: add ``<think>``/``</think>``/``<answer>``/``</answer>`` (and a pad token) as
            special tokens if the tokenizer lacks them (pretrained Qwen2.5 tokenizers do).

    Raises:
        ModelError: the folder lacks the vision tokens the model needs.
    """
    from transformers import AutoTokenizer

    tok = AutoTokenizer.from_pretrained(str(path), local_files_only=True)
    if add_tags:
        vocab = tok.get_vocab()
        missing = [t for t in (THINK, END_THINK, ANSWER, END_ANSWER) if t not in vocab]
        if missing:
            tok.add_special_tokens({"additional_special_tokens": missing}, replace_extra_special_tokens=False)
        if tok.pad_token is None:
            tok.pad_token = tok.eos_token
    vocab = tok.get_vocab()
    for t in (VISION_START, VISION_END, VIDEO_PAD):
        if t not in vocab:
            raise ModelError(f"{path}: tokenizer: must have the token {t!r}")
    return tok


def _token_id(tokenizer, token: str) -> int:
    return int(tokenizer.convert_tokens_to_ids(token))


def decode(tokenizer, ids: Sequence[int]) -> str:
    """Decode generated ids up to the first EOS, keeping the think/answer tags.

    Args:
        tokenizer: the model's tokenizer.
        ids: generated token ids (prompt excluded).

    Returns:
        The text with pad and EOS tokens removed.
    """
    ids = list(ids)
    if tokenizer.eos_token_id in ids:
        ids = ids[: ids.index(tokenizer.eos_token_id)]
    ids = [i for i in ids if i != tokenizer.pad_token_id]
    return tokenizer.decode(ids, skip_special_tokens=False, clean_up_tokenization_spaces=False)


# ----------------------------------------------------------------------------- model
def build_model(cfg: ModelConfig, tokenizer) -> "Qwen2_5_VLForConditionalGeneration":
    """A Qwen2.5-VL for ``cfg``: tiny and random, or ``cfg.pretrained`` loaded offline.

    Args:
        cfg: model config (architecture fields are ignored when ``pretrained`` is set, except
            the patch geometry, which must match the checkpoint).
        tokenizer: its special token ids become the config's token ids; the embedding table
            has ``len(tokenizer)`` rows.

    Returns:
        ``Qwen2_5_VLForConditionalGeneration`` in float32, train mode.

    Raises:
        ModelError: ``pretrained`` folder missing or its patch geometry differs from ``cfg``.
    """
    from transformers import Qwen2_5_VLConfig, Qwen2_5_VLForConditionalGeneration

    ids = dict(
        video_token_id=_token_id(tokenizer, VIDEO_PAD),
        vision_start_token_id=_token_id(tokenizer, VISION_START),
        vision_end_token_id=_token_id(tokenizer, VISION_END),
    )
    if cfg.pretrained:
        path = Path(cfg.pretrained)
        if not path.is_dir():
            raise ModelError(f"model.pretrained: must be a local folder, got {cfg.pretrained!r}")
        model = Qwen2_5_VLForConditionalGeneration.from_pretrained(
            str(path), local_files_only=True, dtype=torch.float32
        )
        _check_geometry(model, cfg)
        if len(tokenizer) > model.get_input_embeddings().weight.shape[0]:
            model.resize_token_embeddings(len(tokenizer))
        for key, value in ids.items():
            setattr(model.config, key, value)
        model.train()
        return model

    text_config = dict(
        vocab_size=len(tokenizer),
        hidden_size=cfg.hidden_size,
        intermediate_size=cfg.intermediate_size,
        num_hidden_layers=cfg.num_layers,
        num_attention_heads=cfg.num_heads,
        num_key_value_heads=cfg.num_kv_heads,
        max_position_embeddings=cfg.max_position_embeddings,
        rope_parameters={"rope_type": "default", "rope_theta": cfg.rope_theta, "mrope_section": cfg.mrope_section},
        bos_token_id=None,
        eos_token_id=tokenizer.eos_token_id,
        pad_token_id=tokenizer.pad_token_id,
    )
    vision_config = dict(
        depth=cfg.vision_depth,
        hidden_size=cfg.vision_hidden_size,
        intermediate_size=cfg.vision_intermediate_size,
        num_heads=cfg.vision_num_heads,
        patch_size=cfg.patch_size,
        spatial_merge_size=cfg.spatial_merge_size,
        temporal_patch_size=cfg.temporal_patch_size,
        window_size=cfg.window_size,
        fullatt_block_indexes=[cfg.vision_depth - 1],  # last block sees the whole frame, as in Qwen2.5-VL
        out_hidden_size=cfg.hidden_size,
        tokens_per_second=1,  # one RoPE time step per temporal patch (no second_per_grid_ts passed)
    )
    config = Qwen2_5_VLConfig(
        text_config=text_config,
        vision_config=vision_config,
        image_token_id=_token_id(tokenizer, IMAGE_PAD) if IMAGE_PAD in tokenizer.get_vocab() else len(tokenizer),
        **ids,
    )
    torch.manual_seed(cfg.seed)
    model = Qwen2_5_VLForConditionalGeneration(config)
    model.generation_config.pad_token_id = tokenizer.pad_token_id
    model.generation_config.eos_token_id = tokenizer.eos_token_id
    model.generation_config.bos_token_id = None
    model.train()
    return model


def _check_geometry(model, cfg: ModelConfig) -> None:
    vc = model.config.vision_config
    for ours, theirs in (
        ("patch_size", "patch_size"),
        ("spatial_merge_size", "spatial_merge_size"),
        ("temporal_patch_size", "temporal_patch_size"),
    ):
        if getattr(cfg, ours) != getattr(vc, theirs):
            raise ModelError(
                f"model.{ours}: must match the checkpoint's vision_config.{theirs} "
                f"({getattr(vc, theirs)}), got {getattr(cfg, ours)}"
            )


def load_model(model_dir: str | Path):
    """Load a trained model and its tokenizer from a ``save_pretrained`` folder, offline.

    Args:
        model_dir: folder written by :func:`train` (or any Qwen2.5-VL folder with a tokenizer).

    Returns:
        ``(model, tokenizer)``; the model is in eval mode, float32, on CPU.

    Raises:
        ModelError: the folder is missing.
    """
    from transformers import Qwen2_5_VLForConditionalGeneration

    model_dir = Path(model_dir)
    if not (model_dir / "config.json").exists():
        raise ModelError(f"{model_dir}: no model (config.json missing; run the finetune stage)")
    model = Qwen2_5_VLForConditionalGeneration.from_pretrained(
        str(model_dir), local_files_only=True, dtype=torch.float32
    )
    model.eval()
    return model, load_tokenizer(model_dir)


def n_parameters(model: torch.nn.Module) -> int:
    """Number of parameters."""
    return sum(p.numel() for p in model.parameters())


# ----------------------------------------------------------------------------- frames
def frame_indices(n_total: int, n: int) -> np.ndarray:
    """``n`` uniformly spaced indices into a clip of ``n_total`` frames (first and last included).

    The paper samples 10 frames uniformly from each 1 s clip.

    Args:
        n_total: number of frames in the clip (``T`` for RGB, ``T - 1`` for flow).
        n: number of frames to pick.

    Returns:
        ``(n,) int64`` increasing indices in ``[0, n_total)`` (repeats when ``n > n_total``).

    Raises:
        ModelError: ``n_total < 1`` or ``n < 1``.
    """
    if n_total < 1 or n < 1:
        raise ModelError(f"frame_indices: need n_total >= 1 and n >= 1, got n_total={n_total}, n={n}")
    return np.round(np.linspace(0, n_total - 1, n)).astype(np.int64)


def model_input(
    rgb: np.ndarray | None,
    flow: np.ndarray | None,
    cfg: ModelConfig,
    max_magnitude: float | None = None,
) -> np.ndarray:
    """The frames the model sees for one clip.

    Args:
        rgb: ``(T, H, W, 3) uint8`` video (needed when ``cfg.input == "rgb"``).
        flow: ``(T-1, H, W, 2)`` float forward flow in px (needed when ``cfg.input == "flow"``);
            colour-coded with ``pipeline.flow.flow_to_rgb(flow, max_magnitude)``.
        cfg: model config (``input``, ``n_frames``, patch geometry).
        max_magnitude: flow magnitude (px) mapped to full saturation; ``None`` = per clip.

    Returns:
        ``(cfg.n_frames, H', W', 3) uint8``, frames uniformly sampled over the clip; resized
        (bicubic) to the nearest multiples of ``cfg.grid_factor`` if ``H, W`` are not already.

    Raises:
        ModelError: the input that ``cfg.input`` names is missing or has the wrong shape.
    """
    if cfg.input == "flow":
        if flow is None:
            raise ModelError("model.input is 'flow' but no flow was given")
        flow = np.asarray(flow)
        if flow.ndim != 4 or flow.shape[-1] != 2:
            raise ModelError(f"flow: must have shape (T-1, H, W, 2), got {flow.shape}")
        from pipeline.flow import flow_to_rgb

        idx = frame_indices(len(flow), cfg.n_frames)
        frames = flow_to_rgb(flow[idx].astype(np.float32), max_magnitude)
    else:
        if rgb is None:
            raise ModelError("model.input is 'rgb' but no rgb video was given")
        rgb = np.asarray(rgb)
        if rgb.ndim != 4 or rgb.shape[-1] != 3 or rgb.dtype != np.uint8:
            raise ModelError(f"rgb: must be (T, H, W, 3) uint8, got {rgb.shape} {rgb.dtype}")
        frames = rgb[frame_indices(len(rgb), cfg.n_frames)]
    return fit_to_grid(frames, cfg.grid_factor)


def fit_to_grid(frames: np.ndarray, factor: int) -> np.ndarray:
    """Resize ``(T, H, W, 3) uint8`` frames (bicubic) so that H and W are multiples of ``factor``.

    Each side goes to the nearest multiple (at least ``factor``), as Qwen2-VL's ``smart_resize``
    does for small images. Frames that already fit are returned unchanged.
    """
    _, h, w, _ = frames.shape
    new_h, new_w = max(factor, round(h / factor) * factor), max(factor, round(w / factor) * factor)
    if (new_h, new_w) == (h, w):
        return frames
    from PIL import Image

    return np.stack([np.asarray(Image.fromarray(f).resize((new_w, new_h), Image.BICUBIC)) for f in frames])


def video_patches(frames: np.ndarray, cfg: ModelConfig) -> tuple[np.ndarray, np.ndarray]:
    """Flatten a video into Qwen2-VL vision patches, in transformers' order.

    Same result as ``Qwen2VLVideoProcessor`` with ``do_resize=False`` (rescale to [0, 1],
    normalise with :data:`IMAGE_MEAN` / :data:`IMAGE_STD`, then its ``patchify``): patches are
    ordered (t, h-block, w-block, h-in-block, w-in-block) with ``merge_size`` x ``merge_size``
    blocks, and each patch is flattened (channel, time, row, column).

    Args:
        frames: ``(T, H, W, 3) uint8`` with ``T`` a multiple of ``cfg.temporal_patch_size`` and
            ``H, W`` multiples of ``cfg.patch_size * cfg.spatial_merge_size``.
        cfg: patch geometry (``patch_size``, ``spatial_merge_size``, ``temporal_patch_size``).

    Returns:
        ``pixel_values_videos (T/tp * H/p * W/p, 3 * tp * p * p) float32`` and
        ``video_grid_thw (1, 3) int64`` = ``[[T/tp, H/p, W/p]]``.

    Raises:
        ModelError: wrong dtype or shape, or sizes that do not divide.
    """
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
        raise ModelError(f"frames: must be (T, H, W, 3) uint8, got {frames.shape} {frames.dtype}")
    t, h, w, c = frames.shape
    p, m, tp = cfg.patch_size, cfg.spatial_merge_size, cfg.temporal_patch_size
    if t % tp or h % (p * m) or w % (p * m):
        raise ModelError(
            f"frames: T must be a multiple of {tp} and H, W multiples of {p * m}, got T={t}, H={h}, W={w}"
        )
    x = frames.astype(np.float32) / 255.0
    x = (x - np.asarray(IMAGE_MEAN, np.float32)) / np.asarray(IMAGE_STD, np.float32)
    x = x.transpose(0, 3, 1, 2)  # (T, C, H, W)
    gt, gh, gw = t // tp, h // p, w // p
    x = x.reshape(gt, tp, c, gh // m, m, p, gw // m, m, p)
    # transformers: permute(0, 1, 4, 7, 5, 8, 3, 2, 6, 9) on the same view with a batch axis in front
    x = x.transpose(0, 3, 6, 4, 7, 2, 1, 5, 8)
    patches = np.ascontiguousarray(x.reshape(gt * gh * gw, c * tp * p * p))
    return patches, np.array([[gt, gh, gw]], dtype=np.int64)


def n_video_tokens(grid_thw: np.ndarray, cfg: ModelConfig) -> int:
    """Number of ``<|video_pad|>`` tokens for a video grid: ``t * h * w / merge**2``."""
    return int(np.prod(grid_thw)) // cfg.spatial_merge_size**2


# ----------------------------------------------------------------------------- batches
def prompt_ids(tokenizer, n_video: int) -> list[int]:
    """``<|vision_start|>`` + ``n_video`` x ``<|video_pad|>`` + ``<|vision_end|>`` as ids."""
    return (
        [_token_id(tokenizer, VISION_START)]
        + [_token_id(tokenizer, VIDEO_PAD)] * n_video
        + [_token_id(tokenizer, VISION_END)]
    )


def collate(
    items: Sequence[tuple[np.ndarray, str | None]], tokenizer, cfg: ModelConfig
) -> dict[str, torch.Tensor]:
    """Build one batch of model inputs (right-padded).

    Args:
        items: ``(frames (n_frames, H, W, 3) uint8, target text or None)`` per example;
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
    video_id = _token_id(tokenizer, VIDEO_PAD)
    seqs, labels, patches, grids = [], [], [], []
    for frames, target in items:
        pv, grid = video_patches(frames, cfg)
        prompt = prompt_ids(tokenizer, n_video_tokens(grid, cfg))
        ids = list(prompt)
        lab = [IGNORE_INDEX] * len(prompt)
        if target is not None:
            tgt = tokenizer.encode(target, add_special_tokens=False) + [tokenizer.eos_token_id]
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


def get_batch(examples: Sequence[Example], tokenizer, cfg: ModelConfig, step: int) -> dict[str, torch.Tensor]:
    """A random training batch of ``cfg.batch_size`` examples (drawn with replacement).

    The draw depends only on ``(cfg.seed, step)``, so a resumed run sees the same batches.
    """
    rng = np.random.default_rng([cfg.seed, step])
    idx = rng.integers(0, len(examples), size=cfg.batch_size)
    return collate([examples[i] for i in idx], tokenizer, cfg)


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
    n = min(len(examples), cfg.eval_batches * cfg.batch_size)
    losses = []
    for start in range(0, n, cfg.batch_size):
        batch = collate(examples[start : min(n, start + cfg.batch_size)], tokenizer, cfg)
        losses.append(model(**batch, use_cache=False).loss.item())
    model.train(was_training)
    return float(np.mean(losses))


# ----------------------------------------------------------------------------- training
def lr_at(step: int, progress: float, cfg: ModelConfig) -> float:
    """Learning rate: linear warmup over ``cfg.warmup_steps``, then cosine to ``cfg.min_lr``.

    Args:
        step: optimiser steps done.
        progress: fraction of the budget spent, ``max(step / max_steps, seconds / (max_minutes * 60))``.
    """
    if step < cfg.warmup_steps:
        return cfg.lr * (step + 1) / cfg.warmup_steps
    p = min(1.0, max(0.0, progress))
    return cfg.min_lr + 0.5 * (1.0 + math.cos(math.pi * p)) * (cfg.lr - cfg.min_lr)


def configure_optimizer(model: torch.nn.Module, cfg: ModelConfig) -> torch.optim.AdamW:
    """AdamW with weight decay on matrices only (not on biases and norms), as nanoGPT."""
    params = [p for p in model.parameters() if p.requires_grad]
    groups = [
        {"params": [p for p in params if p.dim() >= 2], "weight_decay": cfg.weight_decay},
        {"params": [p for p in params if p.dim() < 2], "weight_decay": 0.0},
    ]
    return torch.optim.AdamW(groups, lr=cfg.lr, betas=(0.9, 0.95))


def train(
    train_examples: Sequence[Example],
    val_examples: Sequence[Example],
    cfg: ModelConfig,
    out_dir: str | Path,
    tokenizer=None,
    resume: bool = False,
    progress: bool = True,
) -> dict[str, Any]:
    """Train the model; checkpoint into ``out_dir`` at every evaluation and at the end.

    The loop: draw a batch (:func:`get_batch`), set the learning rate (:func:`lr_at`),
    forward/backward, clip gradients, AdamW step; every ``cfg.eval_interval`` steps
    evaluate on ``val_examples`` (:func:`estimate_loss`), append a row to ``train_curve.csv``
    (``train_loss`` is the mean training loss since the previous row) and checkpoint.
    Stops after ``cfg.max_steps`` steps or ``cfg.max_minutes`` of training time.

    Checkpoint (``out_dir``): ``save_pretrained`` model and tokenizer,
    ``trainer_state.pt`` (optimizer state, step, seconds, config), ``dynamics_model.json``
    (the :class:`ModelConfig`), ``train_curve.csv`` (step, train_loss, val_loss, lr, seconds).

    Args:
        train_examples: ``(frames (n_frames, H, W, 3) uint8, target text)`` pairs.
        val_examples: same, for the validation loss (may be empty).
        cfg: model config.
        out_dir: checkpoint folder (created).
        tokenizer: tokenizer of the targets; ``None`` loads it from ``cfg.pretrained`` or, on
            resume, from ``out_dir``.
        resume: continue from the checkpoint in ``out_dir`` if there is one (same step count,
            optimizer state, elapsed time and curve); otherwise start fresh.
        progress: show a tqdm progress bar.

    Returns:
        ``{"step", "seconds", "train_loss", "val_loss", "n_parameters", "s_per_step"}`` of the
        last row of the curve.

    Raises:
        ModelError: no training examples, or no tokenizer to train with.
    """
    from tqdm.auto import tqdm

    if not train_examples:
        raise ModelError("train: no training examples (is the train split empty?)")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    state_path = out_dir / TRAINER_STATE_FILE
    torch.manual_seed(cfg.seed)

    if resume and state_path.exists():
        model, tokenizer = load_model(out_dir)
        model.train()
        state = torch.load(state_path, map_location="cpu", weights_only=False)
        _check_resumable(state["config"], cfg, out_dir)
        optimizer = configure_optimizer(model, cfg)
        optimizer.load_state_dict(state["optimizer"])
        step, seconds = int(state["step"]), float(state["seconds"])
        curve = read_curve(out_dir)
    else:
        if tokenizer is None:
            if not cfg.pretrained:
                raise ModelError("train: no tokenizer given (train one with train_tokenizer)")
            tokenizer = load_tokenizer(cfg.pretrained)
        model = build_model(cfg, tokenizer)
        optimizer = configure_optimizer(model, cfg)
        step, seconds, curve = 0, 0.0, []

    budget_s = cfg.max_minutes * 60.0
    recent: list[float] = []
    bar = tqdm(total=cfg.max_steps, initial=step, disable=not progress, desc="train", unit="step")
    start = time.monotonic() - seconds
    while step < cfg.max_steps and seconds < budget_s:
        lr = lr_at(step, max(step / cfg.max_steps, seconds / budget_s), cfg)
        for group in optimizer.param_groups:
            group["lr"] = lr
        batch = get_batch(train_examples, tokenizer, cfg, step)
        loss = model(**batch, use_cache=False).loss
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if cfg.grad_clip > 0:
            torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
        optimizer.step()
        step += 1
        recent.append(loss.item())
        seconds = time.monotonic() - start
        bar.update(1)
        bar.set_postfix(loss=f"{recent[-1]:.3f}", lr=f"{lr:.2e}")
        done = step >= cfg.max_steps or seconds >= budget_s
        if step % cfg.eval_interval == 0 or done:
            val = estimate_loss(model, val_examples, tokenizer, cfg)
            seconds = time.monotonic() - start
            row = {"step": step, "train_loss": float(np.mean(recent)), "val_loss": val, "lr": lr}
            curve.append(row | {"seconds": round(seconds, 2)})
            recent = []
            bar.write(f"step {step}: train {row['train_loss']:.4f}, val {val:.4f}, {seconds:.0f} s")
            save_checkpoint(out_dir, model, tokenizer, optimizer, step, seconds, cfg, curve)
    bar.close()
    last = curve[-1] if curve else {"train_loss": float("nan"), "val_loss": float("nan")}
    return {
        "step": step,
        "seconds": round(seconds, 2),
        "train_loss": last["train_loss"],
        "val_loss": last["val_loss"],
        "n_parameters": n_parameters(model),
        "s_per_step": round(seconds / step, 4) if step else float("nan"),
    }


RESUMABLE_FIELDS = frozenset(
    {"max_steps", "max_minutes", "eval_interval", "eval_batches", "max_new_tokens", "k", "temperature", "top_p"}
)
"""Config fields that may change between a checkpoint and its resumed run (budget, sampling)."""


def _check_resumable(saved: dict[str, Any], cfg: ModelConfig, out_dir: Path) -> None:
    for key, value in saved.items():
        if key not in RESUMABLE_FIELDS and getattr(cfg, key, value) != value:
            raise ModelError(
                f"{out_dir}: cannot resume: model.{key} was {value!r} in the checkpoint, now "
                f"{getattr(cfg, key)!r} (start over without resume)"
            )


def save_checkpoint(
    out_dir: Path,
    model,
    tokenizer,
    optimizer: torch.optim.Optimizer,
    step: int,
    seconds: float,
    cfg: ModelConfig,
    curve: list[dict[str, float]],
) -> None:
    """Write the model, tokenizer, trainer state, config and curve into ``out_dir``.

    Everything is first written to a temporary sibling folder, then moved in file by file,
    the trainer state last, so an interrupted save never leaves a state newer than the model.
    """
    out_dir = Path(out_dir)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", suffix=".tmp", dir=out_dir.parent))
    try:
        model.save_pretrained(str(tmp))
        tokenizer.save_pretrained(str(tmp))
        (tmp / CONFIG_FILE).write_text(cfg.model_dump_json(indent=2) + "\n")
        _write_curve(tmp / CURVE_FILE, curve)
        torch.save(
            {"optimizer": optimizer.state_dict(), "step": step, "seconds": seconds, "config": cfg.model_dump()},
            tmp / TRAINER_STATE_FILE,
        )
        names = sorted(p.name for p in tmp.iterdir() if p.name != TRAINER_STATE_FILE) + [TRAINER_STATE_FILE]
        for name in names:
            os.replace(tmp / name, out_dir / name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _write_curve(path: Path, curve: list[dict[str, float]]) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=CURVE_COLUMNS)
        writer.writeheader()
        writer.writerows(curve)


def read_curve(model_dir: str | Path) -> list[dict[str, float]]:
    """Rows of ``train_curve.csv`` (step as int, the rest as float); ``[]`` if there is none."""
    path = Path(model_dir) / CURVE_FILE
    if not path.exists():
        return []
    with open(path, newline="") as f:
        return [
            {k: (int(v) if k == "step" else float(v)) for k, v in row.items()} for row in csv.DictReader(f)
        ]


def plot_curve(model_dir: str | Path, png: str | Path | None = None) -> Path | None:
    """Plot train/val loss against step from ``train_curve.csv``.

    Returns:
        The PNG path, or ``None`` if matplotlib is not installed or there is no curve.
    """
    curve = read_curve(model_dir)
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    if not curve:
        return None
    png = Path(png) if png else Path(model_dir) / CURVE_PNG
    steps = [r["step"] for r in curve]
    fig, ax = plt.subplots(figsize=(5, 3.2), dpi=120)
    ax.plot(steps, [r["train_loss"] for r in curve], label="train")
    ax.plot(steps, [r["val_loss"] for r in curve], label="val")
    ax.set_xlabel("step")
    ax.set_ylabel("loss (nats / token)")
    ax.set_yscale("log")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(png)
    plt.close(fig)
    return png


# ----------------------------------------------------------------------------- sampling
@torch.no_grad()
def generate(
    model,
    tokenizer,
    frames: np.ndarray,
    cfg: ModelConfig,
    k: int | None = None,
    seed: int = 0,
) -> list[str]:
    """Sample ``k`` completions for one video, batched.

    Nucleus sampling at ``cfg.temperature`` / ``cfg.top_p`` (greedy if temperature is 0), at
    most ``cfg.max_new_tokens`` tokens, each sample stopping at EOS. The global torch RNG is
    left untouched (sampling runs in a forked RNG seeded with ``seed``).

    Args:
        model: a Qwen2.5-VL from :func:`build_model` or :func:`load_model`.
        tokenizer: its tokenizer.
        frames: ``(n_frames, H, W, 3) uint8`` (from :func:`model_input`).
        cfg: model config (sampling settings, patch geometry).
        k: number of samples (default ``cfg.k``).
        seed: sampling seed.

    Returns:
        ``k`` decoded completions with think/answer tags kept, EOS and padding removed.
    """
    from transformers import GenerationConfig

    k = k or cfg.k
    batch = collate([(frames, None)] * k, tokenizer, cfg)
    prompt_len = batch["input_ids"].shape[1]
    sample = cfg.temperature > 0
    gen = GenerationConfig(
        do_sample=sample,
        temperature=cfg.temperature if sample else None,
        top_p=cfg.top_p if sample else None,
        top_k=None,
        max_new_tokens=cfg.max_new_tokens,
        eos_token_id=tokenizer.eos_token_id,
        pad_token_id=tokenizer.pad_token_id,
        bos_token_id=None,
    )
    was_training = model.training
    model.eval()
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        out = model.generate(**batch, generation_config=gen)
    model.train(was_training)
    return [decode(tokenizer, row[prompt_len:].tolist()) for row in out]


# ----------------------------------------------------------------------------- data
def read_inputs(
    data_dir: str | Path, cfg: ModelConfig, scene_ids: Iterable[str] | None = None
) -> dict[str, np.ndarray]:
    """Model frames for scenes of a flow or video stage directory.

    Args:
        data_dir: the flow stage output (Zarr shards with ``flow (N, T-1, H, W, 2)`` and attribute
            ``max_magnitude`` in px) when ``cfg.input == "flow"``, else the video stage output
            (``rgb (N, T, H, W, 3) uint8``).
        cfg: model config.
        scene_ids: scenes to read (default: all).

    Returns:
        ``scene_id -> (n_frames, H, W, 3) uint8`` (see :func:`model_input`).

    Raises:
        ModelError: a requested scene is in no shard.
        pipeline.shards.ShardError: missing or unreadable shards.
    """
    from pipeline.shards import iter_array_shards, scene_ids_of

    wanted = None if scene_ids is None else set(scene_ids)
    out: dict[str, np.ndarray] = {}
    for _, group in iter_array_shards(data_dir):
        ids = scene_ids_of(group)
        max_magnitude = group.attrs.get("max_magnitude") if cfg.input == "flow" else None
        array = group["flow" if cfg.input == "flow" else "rgb"]
        for i, sid in enumerate(ids):
            if wanted is not None and sid not in wanted:
                continue
            clip = np.asarray(array[i])
            if cfg.input == "flow":
                out[sid] = model_input(None, clip, cfg, max_magnitude)
            else:
                out[sid] = model_input(clip, None, cfg)
    if wanted is not None and (missing := sorted(wanted - out.keys())):
        raise ModelError(f"{data_dir}: no {cfg.input} for {len(missing)} scenes, e.g. {missing[0]!r}")
    return out
