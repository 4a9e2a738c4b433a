"""The model's word-level tokenizer: one token per scene number, event word or tag.

The vocabulary is fixed by the params (no training): special tokens, the ``<think>`` /
``<answer>`` tags, shape tokens, bin tokens ``<0>``..``<n-1>`` (:mod:`pipeline.codec`) and the
words of the motion-event text (times ``t=0.00``..``t=<duration>``, object names, verbs). A
target text is its tokens joined by single spaces, so ``decode(encode(text)) == text``.
Because the vocabulary depends only on the params, a checkpoint trained on one data profile
keeps working on another with the same ranges (the shipped checkpoint and ``model.init``).
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any, Sequence

from tokenizers import Tokenizer, models, pre_tokenizers

from pipeline.codec import END_THINK, THINK, SceneCodec
from pipeline.model.config import ModelError
from pipeline.scene import SHAPES
from pipeline.shards import replace_path, temp_dir_for

PAD = "<|pad|>"
EOS = "<|endoftext|>"
UNK = "<|unk|>"
VISION_START, VISION_END = "<|vision_start|>", "<|vision_end|>"
VIDEO_PAD = "<|video_pad|>"
IMAGE_PAD = "<|image_pad|>"  # unused (video only) but the config needs an id of its own
SPECIAL_TOKENS = (PAD, EOS, UNK, VISION_START, VISION_END, VIDEO_PAD, IMAGE_PAD)
"""Special tokens, ids 0..6 (never produced by the grammar except EOS)."""

EVENT_WORDS = ("hits", "floor", "stops", "enters", "leaves", "view", ";", "no", "events")
"""Words of :func:`pipeline.events.events_to_text` besides times and object names."""


def think_vocab(params: dict[str, Any], max_objects: int) -> list[str]:
    """Every word an events text can contain for these params.

    Times ``t=0.00`` .. ``t=<duration>`` at ``events.decimals``, names ``<shape>_<i>`` for
    ``i < max_objects``, and :data:`EVENT_WORDS`.
    """
    nd = int((params.get("events") or {}).get("decimals", 2))
    duration = float((params.get("sample") or {}).get("duration", 1.0))
    n = int(round(duration * 10**nd))
    times = [f"t={i / 10**nd:.{nd}f}" for i in range(n + 1)]
    names = [f"{s}_{i}" for s in SHAPES for i in range(max_objects)]
    return times + names + list(EVENT_WORDS)


def build_tokenizer(codec: SceneCodec, think_words: Sequence[str], out_dir: str | Path | None = None):
    """The word-level tokenizer of a codec and an events vocabulary.

    Args:
        codec: gives the answer vocabulary (tags, shapes, bins).
        think_words: words of the ``<think>`` part (:func:`think_vocab`).
        out_dir: if given, ``save_pretrained`` the tokenizer there.

    Returns:
        ``transformers.PreTrainedTokenizerFast`` (``WordLevel`` model, whitespace split, no
        decoder: decoding joins tokens with single spaces) with pad, eos and unk set.
    """
    from transformers import PreTrainedTokenizerFast

    vocab: dict[str, int] = {}
    for t in [*SPECIAL_TOKENS, THINK, END_THINK, *codec.answer_vocab, *think_words]:
        vocab.setdefault(t, len(vocab))
    tok = Tokenizer(models.WordLevel(vocab=vocab, unk_token=UNK))
    tok.pre_tokenizer = pre_tokenizers.WhitespaceSplit()
    fast = PreTrainedTokenizerFast(
        tokenizer_object=tok, pad_token=PAD, eos_token=EOS, unk_token=UNK,
        additional_special_tokens=list(SPECIAL_TOKENS[3:]),
        clean_up_tokenization_spaces=False, model_max_length=1 << 20,
    )
    if out_dir is not None:   # into a temporary sibling, swapped in whole (no half-written folder)

        out_dir = Path(out_dir)
        tmp = temp_dir_for(out_dir)
        try:
            fast.save_pretrained(str(tmp))
            replace_path(tmp, out_dir)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    return fast


def load_tokenizer(path: str | Path):
    """Load a tokenizer folder offline (ours, or a pretrained Qwen2.5-VL's).

    Raises:
        ModelError: the folder lacks the vision tokens the model needs.
    """
    from transformers import AutoTokenizer

    tok = AutoTokenizer.from_pretrained(str(path), local_files_only=True)
    vocab = tok.get_vocab()
    for t in (VISION_START, VISION_END, VIDEO_PAD):
        if t not in vocab:
            raise ModelError(f"{path}: tokenizer: must have the token {t!r}")
    if tok.pad_token is None:
        tok.pad_token = tok.eos_token
    return tok


def extend_tokenizer(tok, codec: SceneCodec, think_words: Sequence[str]) -> int:
    """Add the codec and think vocabulary to a pretrained tokenizer (real Qwen2.5-VL weights).

    Returns:
        Number of tokens added (the model's embeddings must be resized to ``len(tok)``).
    """
    vocab = tok.get_vocab()
    new = [t for t in dict.fromkeys([THINK, END_THINK, *codec.answer_vocab, *think_words]) if t not in vocab]
    return tok.add_tokens(new)


def token_id(tokenizer, token: str) -> int:
    return int(tokenizer.convert_tokens_to_ids(token))


def decode_tokens(tokenizer, ids: Sequence[int]) -> list[str]:
    """Generated ids (prompt excluded) -> token strings up to the first EOS, padding dropped."""
    ids = list(ids)
    if tokenizer.eos_token_id in ids:
        ids = ids[: ids.index(tokenizer.eos_token_id)]
    return [t for t in tokenizer.convert_ids_to_tokens([i for i in ids if i != tokenizer.pad_token_id])]
