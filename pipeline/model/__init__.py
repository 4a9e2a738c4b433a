"""The vision-language model (docs/design.md §5, issue 8), one module per seam.

* :mod:`~pipeline.model.config`: params section ``model`` (:class:`ModelConfig`);
* :mod:`~pipeline.model.tokenizer`: the fixed word-level vocabulary (tags, scene tokens of
  :mod:`pipeline.codec`, event words);
* :mod:`~pipeline.model.vision`: frames the vision tower sees (flow, RGB, flow+RGB) and the
  Qwen2-VL patch layout;
* :mod:`~pipeline.model.network`: tiny Qwen2.5-VL from a config (or real weights) and the
  auxiliary composition head;
* :mod:`~pipeline.model.batch`: the model inputs of a batch (prompt, target ids, labels, padding);
* :mod:`~pipeline.model.training`: batch sampling, step-based schedule, the loop, checkpoints, curve;
* :mod:`~pipeline.model.sampling`: grammar-constrained sampling (xgrammar) and detokenising.

The model reads the video and writes ``<think> event words </think> <answer> scene tokens
</answer>``; :class:`pipeline.codec.SceneCodec` turns the answer back into canonical YAML.

Example::

    cfg = ModelConfig.from_params(params); codec = SceneCodec.from_params(params)
    tok = build_tokenizer(codec, think_vocab(params, codec.max_objects))
    x = model_input(rgb, flow, cfg, max_magnitude=4.0)       # (12, 64, 96, 3) uint8
    train([(x, target), ...], val, cfg, "data/model", tokenizer=tok, codec=codec)
    model, tok = load_model("data/model"); codec, _ = load_codec("data/model")
    scenes = [to_scene(t, codec)[0] for t in generate(model, tok, x, cfg, codec, k=4)]
"""


from pipeline.model.batch import IGNORE_INDEX, collate, encode_target, prompt_ids
from pipeline.model.config import SCRATCH, SHIPPED, SHIPPED_CHECKPOINT, WIDE_CHECKPOINT, ModelConfig, ModelError
from pipeline.model.network import (CompositionHead, build_model, check_checkpoint, checkpoint_config, load_model,
                                    n_parameters)
from pipeline.model.sampling import (CODEC_FILE, compiled_grammar, generate, generate_many, load_codec,
                                     save_codec, to_scene)
from pipeline.model.tokenizer import (EOS, PAD, SPECIAL_TOKENS, VIDEO_PAD, VISION_END, VISION_START,
                                      build_tokenizer, decode_tokens, extend_tokenizer, load_tokenizer,
                                      think_vocab)
from pipeline.model.training import (CURVE_FILE, CURVE_PNG, batch_indices, estimate_loss, evaluate_samples, get_batch,
                                     lr_at, plot_curve, read_curve, save_checkpoint, train)
from pipeline.model.vision import (IMAGE_MEAN, IMAGE_STD, fit_to_grid, frame_indices, model_input,
                                   n_video_tokens, read_inputs, video_patches)


__all__ = [n for n in dir() if not n.startswith("_")]
