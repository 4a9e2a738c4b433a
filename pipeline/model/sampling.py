"""Sampling scenes from the model, constrained by the scene-token grammar (xgrammar).

Every sample is decoded under the EBNF grammar of :meth:`pipeline.codec.SceneCodec.grammar`
with xgrammar (Dong et al., "XGrammar", 2024) as a ``transformers`` logits processor: at each
step only tokens that keep the completion inside the grammar can be drawn, so every finished
sample detokenises to a valid scene (shape tokens, the right number of bins per shape, 1 to
``max_objects`` objects; quaternions are renormalised by the codec). ``model.constrained:
false`` samples freely (ablation).
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from pipeline.codec import END_THINK, THINK, CodecError, SceneCodec, split_completion
from pipeline.model.batch import collate, to_device
from pipeline.model.config import ModelConfig, ModelError
from pipeline.model.tokenizer import SPECIAL_TOKENS, decode_tokens
from pipeline.scene import Scene
from pipeline.shards import write_json

CODEC_FILE = "codec.json"


def save_codec(model_dir: str | Path, codec: SceneCodec, think_words: Sequence[str]) -> None:
    """Write ``codec.json`` (quantisers, constants, think words) into a checkpoint folder."""
    write_json(Path(model_dir) / CODEC_FILE, {**codec.to_dict(), "think_words": list(think_words)})


def load_codec(model_dir: str | Path) -> tuple[SceneCodec, list[str]]:
    """``(codec, think words)`` saved with a checkpoint.

    Raises:
        ModelError: the folder has no ``codec.json``.
    """
    path = Path(model_dir) / CODEC_FILE
    if not path.exists():
        raise ModelError(f"{model_dir}: no {CODEC_FILE} (not a checkpoint of this project's finetune stage)")
    data = json.loads(path.read_text())
    return SceneCodec.from_dict(data), list(data.get("think_words", []))


def think_words_of(tokenizer, codec: SceneCodec) -> list[str]:
    """Words of the tokenizer's vocabulary that are neither special nor answer tokens."""
    skip = set(SPECIAL_TOKENS) | set(codec.answer_vocab) | {THINK, END_THINK}
    vocab = tokenizer.get_vocab()
    return [t for t, _ in sorted(vocab.items(), key=lambda kv: kv[1]) if t not in skip]


@lru_cache(maxsize=8)
def _compiled(grammar: str, vocab: tuple[str, ...], eos_id: int, vocab_size: int):
    import xgrammar as xgr

    info = xgr.TokenizerInfo(list(vocab), vocab_type=xgr.VocabType.RAW, vocab_size=vocab_size,
                             stop_token_ids=[eos_id])
    return xgr.GrammarCompiler(info, max_threads=1).compile_grammar(grammar)


def compiled_grammar(tokenizer, codec: SceneCodec, reasoning: bool, vocab_size: int | None = None,
                     max_new_tokens: int = 256):
    """The xgrammar ``CompiledGrammar`` of completions for this tokenizer (cached).

    Tokens are matched by their raw strings (``VocabType.RAW``); EOS ends a completion. The
    think part holds at most ``(max_new_tokens - codec.max_answer_tokens() - 3) // 6`` events,
    so every sample reaches ``</answer>`` within ``max_new_tokens``.

    Raises:
        ModelError: ``max_new_tokens`` too small for the longest answer.
    """
    room = max_new_tokens - codec.max_answer_tokens() - (3 if reasoning else 1)
    if room < (6 if reasoning else 0):
        raise ModelError(f"model.max_new_tokens: must be >= {codec.max_answer_tokens() + (9 if reasoning else 1)} "
                         f"(longest answer), got {max_new_tokens}")
    vocab = tokenizer.get_vocab()
    strings = [""] * max(vocab.values()) + [""]
    for t, i in vocab.items():
        strings[i] = t
    think = think_words_of(tokenizer, codec) if reasoning else None
    return _compiled(codec.grammar(think, max_events=room // 6), tuple(strings), int(tokenizer.eos_token_id),
                     int(vocab_size or len(strings)))


@torch.no_grad()
def generate_many(model, tokenizer, frames: Sequence[np.ndarray], cfg: ModelConfig,
                  codec: SceneCodec | None = None, seed: int = 0) -> list[list[str]]:
    """One completion per video of ``frames``, batched, as token strings.

    Nucleus sampling at ``cfg.temperature`` / ``cfg.top_p`` (greedy if temperature is 0), at
    most ``cfg.max_new_tokens`` tokens, each sample stopping at EOS; under the scene grammar
    when ``cfg.constrained`` (needs ``codec``). The global torch RNG is left untouched.

    Args:
        model: a Qwen2.5-VL from :func:`build_model` or :func:`load_model`.
        tokenizer: its tokenizer.
        frames: videos ``(cfg.n_input_frames, H, W, 3) uint8`` of one size (:func:`model_input`).
        cfg: model config (sampling settings, patch geometry).
        codec: the scene codec (its grammar constrains the samples).
        seed: sampling seed.

    Returns:
        One list of tokens per video (EOS and padding removed).

    Raises:
        ModelError: constrained sampling without a codec.
    """
    from transformers import GenerationConfig, LogitsProcessorList

    batch = to_device(collate([(f, None) for f in frames], tokenizer, cfg), next(model.parameters()).device)
    prompt_len = batch["input_ids"].shape[1]
    sample = cfg.temperature > 0
    gen = GenerationConfig(
        do_sample=sample, temperature=cfg.temperature if sample else None, top_p=cfg.top_p if sample else None,
        top_k=None, max_new_tokens=cfg.max_new_tokens, eos_token_id=tokenizer.eos_token_id,
        pad_token_id=tokenizer.pad_token_id, bos_token_id=None,
    )
    processors = LogitsProcessorList()
    if cfg.constrained:
        if codec is None:
            raise ModelError("generate: constrained sampling needs the scene codec")
        import xgrammar as xgr

        vocab_size = model.get_output_embeddings().weight.shape[0]
        processors.append(xgr.contrib.hf.LogitsProcessor(
            compiled_grammar(tokenizer, codec, cfg.reasoning, vocab_size, cfg.max_new_tokens)))
    was_training = model.training
    model.eval()
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        out = model.generate(**batch, generation_config=gen, logits_processor=processors)
    model.train(was_training)
    return [decode_tokens(tokenizer, row[prompt_len:].tolist()) for row in out]


def generate(model, tokenizer, frames: np.ndarray, cfg: ModelConfig, codec: SceneCodec | None = None,
             k: int | None = None, seed: int = 0) -> list[list[str]]:
    """``k`` samples for one video (:func:`generate_many` on ``k`` copies); default ``cfg.k``."""
    return generate_many(model, tokenizer, [frames] * (k or cfg.k), cfg, codec, seed)


def to_scene(tokens: Sequence[str], codec: SceneCodec) -> tuple[Scene | None, str | None]:
    """``(scene, None)`` or ``(None, one-line error)`` for one completion's tokens."""
    _, answer = split_completion(tokens)
    if answer is None:
        return None, "no complete <answer> ... </answer> in the output"
    try:
        return codec.decode(answer), None
    except CodecError as exc:
        return None, str(exc)
