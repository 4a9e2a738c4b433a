"""The network: a tiny Qwen2.5-VL built from a config (or real weights), and the auxiliary
composition head on its vision tower.

Auxiliary loss (beyond the paper, issue 8): a decoder trained only on next-token loss can
learn to write the dataset's average scene whatever the video. The :class:`CompositionHead`
reads the vision tower's merged tokens (mean-pooled per video) and predicts how many objects
of each shape the scene has (``max_objects + 1`` classes per shape); its cross-entropy is added
to the language-model loss with weight ``model.aux_weight``, so the vision tokens the decoder
attends to must carry the scene's content. It is used only in training.
"""

from __future__ import annotations

import json
import types
from pathlib import Path
from typing import TYPE_CHECKING

import torch
from pydantic import ValidationError

from pipeline.errors import format_validation_error
from pipeline.codec import SceneCodec
from pipeline.model.config import ModelConfig, ModelError
from pipeline.model.sampling import CODEC_FILE
from pipeline.model.tokenizer import IMAGE_PAD, VIDEO_PAD, VISION_END, VISION_START, load_tokenizer, token_id
from pipeline.scene import SHAPES

if TYPE_CHECKING:  # transformers takes ~3 s to import
    from transformers import Qwen2_5_VLForConditionalGeneration

AUX_HEAD_FILE = "composition_head.pt"


def build_model(cfg: ModelConfig, tokenizer) -> "Qwen2_5_VLForConditionalGeneration":
    """A Qwen2.5-VL for ``cfg``: tiny and random, or ``cfg.pretrained`` loaded offline.

    Args:
        cfg: model config (architecture fields are ignored when ``pretrained`` is set, except
            the patch geometry, which must match the checkpoint).
        tokenizer: its special token ids become the config's token ids; the embedding table
            has ``len(tokenizer)`` rows.

    Returns:
        ``Qwen2_5_VLForConditionalGeneration`` in float32, train mode, SDPA attention.

    Raises:
        ModelError: ``pretrained`` folder missing or its patch geometry differs from ``cfg``.
    """
    from transformers import Qwen2_5_VLConfig, Qwen2_5_VLForConditionalGeneration

    ids = dict(
        video_token_id=token_id(tokenizer, VIDEO_PAD),
        vision_start_token_id=token_id(tokenizer, VISION_START),
        vision_end_token_id=token_id(tokenizer, VISION_END),
    )
    if cfg.pretrained:
        path = Path(cfg.pretrained)
        if not path.is_dir():
            raise ModelError(f"model.pretrained: must be a local folder, got {cfg.pretrained!r}")
        model = Qwen2_5_VLForConditionalGeneration.from_pretrained(str(path), local_files_only=True,
                                                                   dtype=torch.float32)
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
        image_token_id=token_id(tokenizer, IMAGE_PAD) if IMAGE_PAD in tokenizer.get_vocab() else len(tokenizer),
        **ids,
    )
    config._attn_implementation = "sdpa"
    torch.manual_seed(cfg.seed)
    model = Qwen2_5_VLForConditionalGeneration(config)
    model.generation_config.pad_token_id = tokenizer.pad_token_id
    model.generation_config.eos_token_id = tokenizer.eos_token_id
    model.generation_config.bos_token_id = None
    batch_vision_attention(model)
    model.train()
    return model


def _batched_vision_attention(self, hidden_states: torch.Tensor, cu_seqlens: torch.Tensor,
                              position_embeddings: tuple[torch.Tensor, torch.Tensor] | None = None,
                              max_seqlen: int | None = None, **kwargs) -> torch.Tensor:
    """``Qwen2_5_VLVisionAttention.forward`` with every window (or frame) of one length attended
    in one batched SDPA call; other inputs go through the library's own forward."""
    from transformers.models.qwen2_5_vl.modeling_qwen2_5_vl import apply_rotary_pos_emb_vision

    lengths = cu_seqlens[1:] - cu_seqlens[:-1]
    n_tokens = hidden_states.shape[0]
    size = int(lengths[0]) if len(lengths) else 0
    if size == 0 or n_tokens % size or not bool((lengths == size).all()):
        return type(self).forward(self, hidden_states, cu_seqlens, position_embeddings, max_seqlen, **kwargs)
    q, k, v = self.qkv(hidden_states).reshape(n_tokens, 3, self.num_heads, -1).permute(1, 0, 2, 3).unbind(0)
    cos, sin = position_embeddings
    q, k = apply_rotary_pos_emb_vision(q, k, cos, sin)
    shape = (n_tokens // size, size, self.num_heads, -1)
    q, k, v = (x.reshape(shape).transpose(1, 2) for x in (q, k, v))   # (windows, heads, size, head_dim)
    out = torch.nn.functional.scaled_dot_product_attention(
        q, k, v.to(q.dtype), dropout_p=self.attention_dropout if self.training else 0.0, scale=self.scaling)
    return self.proj(out.transpose(1, 2).reshape(n_tokens, -1))


def batch_vision_attention(model) -> None:
    """Make the vision tower attend all windows of a batch at once (in place).

    transformers' Qwen2.5-VL vision attention (SDPA and eager) loops in Python over the windows
    and frames of ``cu_seqlens``: ~2,700 SDPA calls per block for a batch of 128 clips. On a GPU
    that loop, not the arithmetic, bounded a training step (0.69 steps/s at batch 128 on an H200,
    ``scripts/pretrain_gpu.py``). Here the windows of this project's inputs are all of one
    length, so one batched call gives the same result (``tests/test_model.py``); inputs whose
    windows differ in length fall back to the library's loop.
    """
    from transformers.models.qwen2_5_vl.modeling_qwen2_5_vl import Qwen2_5_VLVisionAttention

    for module in model.modules():
        if isinstance(module, Qwen2_5_VLVisionAttention):
            module.forward = types.MethodType(_batched_vision_attention, module)


def _check_geometry(model, cfg: ModelConfig) -> None:
    vc = model.config.vision_config
    for name in ("patch_size", "spatial_merge_size", "temporal_patch_size"):
        if getattr(cfg, name) != getattr(vc, name):
            raise ModelError(f"model.{name}: must match the checkpoint's vision_config.{name} "
                             f"({getattr(vc, name)}), got {getattr(cfg, name)}")


MODEL_TYPE = "qwen2_5_vl"
"""``config.json`` ``model_type`` of every checkpoint this version loads."""


def check_checkpoint(model_dir: str | Path, need_codec: bool = True) -> None:
    """Check, without loading weights (milliseconds), that a folder holds a checkpoint this
    version of the project can use, so a caller can refuse it before any expensive work.

    Checked: ``config.json`` exists, is JSON and names ``model_type`` :data:`MODEL_TYPE`;
    ``tokenizer.json`` and a weights file exist; ``codec.json`` (when ``need_codec``) parses into
    a :class:`pipeline.codec.SceneCodec`; ``dynamics_model.json`` (this project's checkpoints)
    holds every field of :class:`ModelConfig` and validates (no unknown or missing fields: a
    folder written by another version fails here).

    Raises:
        ModelError: one line ``<folder>: <file>: <problem>``.
    """
    model_dir = Path(model_dir)
    if not model_dir.is_dir():
        raise ModelError(f"{model_dir}: no such model folder (run `dvc repro` or point --model at a checkpoint folder)")
    if not (model_dir / "config.json").exists():
        raise ModelError(f"{model_dir}: no model (config.json missing; run the finetune stage "
                         f"or point --model at a checkpoint folder)")

    def read_json(name: str) -> dict:
        try:
            data = json.loads((model_dir / name).read_text())
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise ModelError(f"{model_dir}: {name}: must be a JSON object, got unreadable text "
                             f"({type(exc).__name__})") from None
        if not isinstance(data, dict):
            raise ModelError(f"{model_dir}: {name}: must be a JSON object, got {type(data).__name__}")
        return data

    kind = read_json("config.json").get("model_type")
    if kind != MODEL_TYPE:
        raise ModelError(f"{model_dir}: config.json: model_type: must be {MODEL_TYPE!r} (this version), "
                         f"got {str(kind)[:40]!r}")
    if not (model_dir / "tokenizer.json").exists():
        raise ModelError(f"{model_dir}: tokenizer.json: missing (not a checkpoint of this project)")
    if not any(model_dir.glob("*.safetensors")) and not any(model_dir.glob("*.bin")):
        raise ModelError(f"{model_dir}: no weights (*.safetensors) in the folder")
    if need_codec:
        if not (model_dir / CODEC_FILE).exists():
            raise ModelError(f"{model_dir}: no {CODEC_FILE} (not a checkpoint of this project's finetune stage)")
        try:
            SceneCodec.from_dict(read_json(CODEC_FILE))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ModelError(f"{model_dir}: {CODEC_FILE}: written by another version of the project "
                             f"(cannot read it: {type(exc).__name__} {str(exc)[:80]})") from None
    if (model_dir / "dynamics_model.json").exists():
        saved = read_json("dynamics_model.json")
        missing = sorted(set(ModelConfig.model_fields) - set(saved))
        if missing:   # a default would silently stand in for what the checkpoint was trained with
            raise ModelError(f"{model_dir}: dynamics_model.json: written by another version of the project "
                             f"(model.{missing[0]}: missing)")
        try:
            ModelConfig.model_validate(saved)
        except ValidationError as exc:
            what = format_validation_error(exc, prefix=("model",), unknown="extra inputs are not permitted")
            raise ModelError(f"{model_dir}: dynamics_model.json: written by another version of the project "
                             f"({what})") from None


def load_model(model_dir: str | Path):
    """Load a trained model and its tokenizer from a ``save_pretrained`` folder, offline.

    Returns:
        ``(model, tokenizer)``; the model is in eval mode, float32, on CPU.

    Raises:
        ModelError: the folder is missing or holds no model.
    """
    from transformers import Qwen2_5_VLForConditionalGeneration

    model_dir = Path(model_dir)
    if not (model_dir / "config.json").exists():
        raise ModelError(f"{model_dir}: no model (config.json missing; run the finetune stage "
                         f"or point --model at a checkpoint folder)")
    model = Qwen2_5_VLForConditionalGeneration.from_pretrained(str(model_dir), local_files_only=True,
                                                               dtype=torch.float32)
    batch_vision_attention(model)
    model.eval()
    return model, load_tokenizer(model_dir)


def n_parameters(model: torch.nn.Module) -> int:
    """Number of parameters."""
    return sum(p.numel() for p in model.parameters())


class CompositionHead(torch.nn.Module):
    """Object counts per shape from the vision tokens of one video.

    Input: pooled vision features ``(B, hidden) float``; output: logits
    ``(B, len(SHAPES), max_objects + 1)`` (class ``c`` = ``c`` objects of that shape).
    """

    def __init__(self, hidden: int, max_objects: int):
        super().__init__()
        self.max_objects = max_objects
        self.net = torch.nn.Sequential(torch.nn.Linear(2 * hidden, hidden), torch.nn.GELU(),
                                       torch.nn.Linear(hidden, len(SHAPES) * (max_objects + 1)))

    def forward(self, pooled: torch.Tensor) -> torch.Tensor:
        return self.net(pooled).view(len(pooled), len(SHAPES), self.max_objects + 1)


def composition_targets(compositions: list[tuple[str, ...]], max_objects: int) -> torch.Tensor:
    """``(B, len(SHAPES)) int64`` counts per shape (clipped to ``max_objects``)."""
    return torch.tensor([[min(c.count(s), max_objects) for s in SHAPES] for c in compositions], dtype=torch.long)


class VisionTap:
    """Forward hook on the vision tower that keeps its merged output tokens for the aux loss.

    ``pooled(grid_thw)`` returns ``(B, 2 * hidden)``: mean and max over each video's tokens.
    """

    def __init__(self, model):
        self.output: torch.Tensor | None = None
        self.merge = model.model.visual.spatial_merge_size
        self.handle = model.model.visual.register_forward_hook(self._hook)

    def _hook(self, module, args, output) -> None:
        self.output = output.pooler_output if hasattr(output, "pooler_output") else output

    def pooled(self, grid_thw: torch.Tensor) -> torch.Tensor:
        if self.output is None:
            raise ModelError("vision tap: the vision tower has not run")
        sizes = (grid_thw.prod(-1) // self.merge**2).tolist()
        parts = torch.split(self.output.float(), sizes)
        return torch.stack([torch.cat([p.mean(0), p.amax(0)]) for p in parts])

    def remove(self) -> None:
        self.handle.remove()


SAMPLING_FIELDS = ("max_new_tokens", "k", "temperature", "top_p", "constrained", "threads")
"""Config fields a user may change at inference time; everything else comes from the checkpoint."""


def checkpoint_config(model_dir: str | Path, cfg: ModelConfig) -> ModelConfig:
    """The config a checkpoint was trained with, with the sampling fields of ``cfg``.

    Input kind, frame count, reasoning and geometry must match what the model learned, whatever
    params.yaml says now; ``k``, temperature, top-p, ``max_new_tokens`` come from ``cfg``.
    Folders without ``dynamics_model.json`` (real Qwen2.5-VL weights) keep ``cfg``.
    """
    path = Path(model_dir) / "dynamics_model.json"
    if not path.exists():
        return cfg
    saved = ModelConfig.model_validate_json(path.read_text())
    return saved.model_copy(update={f: getattr(cfg, f) for f in SAMPLING_FIELDS})
