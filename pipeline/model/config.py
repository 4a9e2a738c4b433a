"""Params section ``model``: architecture, input, training and sampling settings."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from pipeline.errors import UserError
from pipeline.params import typed_section


class ModelError(UserError, ValueError):
    """Bad model config or input. ``str(err)`` is one line naming the field and the bad value."""


SCRATCH = "scratch"
"""``model.init`` value that trains from random weights."""
SHIPPED = "shipped"
"""``model.init`` value that starts from :data:`SHIPPED_CHECKPOINT`, wherever the package is installed."""
SHIPPED_CHECKPOINT = Path(__file__).resolve().parents[1] / "checkpoints" / "dynamics-tiny"
"""The checkpoint that ships inside the package (package data; see its README.md model card): the
``model.init: shipped`` of the small profile's finetune stage and the default of ``dynamics infer``,
trained on paper-like synthetic scenes."""
WIDE_CHECKPOINT = Path(__file__).resolve().parents[1] / "checkpoints" / "dynamics-wide"
"""The shipped checkpoint for real clips (issue 30; ``profiles/pretrain_wide.yaml``): trained on
synthetic scenes that cover what real clips show (cameras from side to top-down, small objects,
random floors, colours and light). ``dynamics infer`` uses it with ``realvideo.model: wide``."""


class ModelConfig(BaseModel):
    """Params section ``model``.

    Inputs: ``input`` = ``flow`` (``n_frames`` colour-coded optical-flow frames), ``rgb``
    (``n_frames`` RGB frames) or ``flow+rgb`` (the first RGB frame as one temporal patch,
    then ``n_frames`` flow frames: appearance shows objects that never move). Geometry: frames
    are ``H x W`` pixels with ``H, W`` multiples of ``patch_size * spatial_merge_size``;
    ``n_frames`` a multiple of ``temporal_patch_size``.

    Training is measured in optimiser steps: linear warmup over ``warmup_steps``, then cosine
    decay to ``min_lr`` at ``max_steps``. ``max_minutes`` is only a safety cap on wall-clock
    time (``null`` = none); when it stops a run early the run's result says so.

    ``init_new_codec``: start from ``init``'s weights although its codec (the token ranges of
    ``sample`` and ``tokens``) differs from the params': every bin token keeps its embedding and
    takes the params' meaning, which training re-learns; missing words are added to the
    tokenizer. Off, such an init is refused.

    ``device``: where training runs: ``cpu`` (the default profile's 2 cores), ``cuda`` (one GPU;
    bf16 autocast there too) or ``auto`` (cuda when torch sees one). Checkpoints are the same
    files on either; sampling (``dynamics infer``) always runs where the model was loaded.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    # inputs and target
    input: Literal["flow", "rgb", "flow+rgb"] = "flow+rgb"
    reasoning: bool = True
    n_frames: int = Field(10, ge=1)
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
    init: str = SHIPPED
    init_new_codec: bool = False
    batch_size: int = Field(8, ge=1)
    lr: float = Field(2e-4, gt=0)
    min_lr: float = Field(2e-5, ge=0)
    warmup_steps: int = Field(20, ge=0)
    weight_decay: float = Field(0.1, ge=0)
    grad_clip: float = Field(1.0, ge=0)
    max_steps: int = Field(200, ge=1)
    max_minutes: float | None = Field(30.0, gt=0)
    aux_weight: float = Field(0.5, ge=0)
    precision: Literal["bf16", "fp32"] = "bf16"
    threads: int = Field(2, ge=1)
    device: Literal["cpu", "cuda", "auto"] = "cpu"
    eval_interval: int = Field(100, ge=1)
    eval_batches: int = Field(2, ge=1)
    eval_samples: int = Field(16, ge=0)
    seed: int = 0
    # sampling
    max_new_tokens: int = Field(256, ge=1)
    k: int = Field(4, ge=1)
    temperature: float = Field(0.1, ge=0)
    top_p: float = Field(0.9, gt=0, le=1)
    constrained: bool = True
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
    def from_params(cls, params: dict[str, Any], source: str | None = None) -> "ModelConfig":
        """Validate section ``model`` of a parsed params.yaml (missing section = defaults).

        ``model.seed`` defaults to the top-level ``seed``.

        Raises:
            ModelError: one line ``<source>: model.<field>: <rule>, got <value>``.
        """
        defaults = {"seed": params["seed"]} if "seed" in params else None
        return typed_section(params, "model", cls, source, defaults=defaults, error=ModelError, unknown="unknown key")

    @property
    def init_dir(self) -> Path | None:
        """The checkpoint folder ``init`` names: :data:`SHIPPED_CHECKPOINT` for ``shipped``, None for
        ``scratch``, else the path as given (relative to the working folder)."""
        if self.init == SCRATCH:
            return None
        return SHIPPED_CHECKPOINT if self.init == SHIPPED else Path(self.init)

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

    @property
    def n_input_frames(self) -> int:
        """Frames the vision tower sees: ``n_frames``, plus one temporal patch of RGB for ``flow+rgb``."""
        return self.n_frames + (self.temporal_patch_size if self.input == "flow+rgb" else 0)
