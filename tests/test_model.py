"""Tests of pipeline.model: patch layout, inputs, tokenizer, schedule, training, constrained sampling."""

from __future__ import annotations

import ast
import math
import os
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import numpy as np
import pytest
import torch

from pipeline import model as M
from pipeline.codec import SceneCodec, target_tokens, text_of
from pipeline.scene import Scene

SCENE = """\
version: 1
duration: 1.0
fps: 30
gravity: 9.81
camera:
  height: 1.2
  pitch: 35.0
  fov: 45.0
objects:
  - shape: sphere
    size: {radius: 0.1}
    mass: 0.5
    position: [0.1, 0.3, 0.1]
    orientation: [1.0, 0.0, 0.0, 0.0]
    linear_velocity: [0.0, 1.2, 0.0]
    angular_velocity: [0.0, 0.0, -0.35]
    material: {sliding_friction: 0.4, rolling_friction: 0.001, damping: 0.1}
effects: []
"""
BOXES = SCENE.replace("""  - shape: sphere
    size: {radius: 0.1}""", """  - shape: box
    size: {width: 0.2, depth: 0.3, height: 0.1}""")
THINK = "t=0.23 sphere_0 hits floor; t=0.73 sphere_0 stops"
PARAMS: dict = {}  # defaults of every section
CODEC = SceneCodec.from_params(PARAMS)

# A config small enough for the tests: ~190k parameters, 4 frames of 32 x 48 px.
TINY = M.ModelConfig(
    n_frames=4, input="rgb", hidden_size=64, intermediate_size=128, num_layers=2, num_heads=4, num_kv_heads=2,
    vision_depth=2, vision_hidden_size=32, vision_intermediate_size=64, vision_num_heads=2, batch_size=2,
    lr=3e-3, min_lr=1e-3, warmup_steps=5, max_steps=40, eval_interval=20, eval_batches=1, eval_samples=2,
    max_new_tokens=160, k=3, threads=1, init="scratch",
)


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    """Tiny matrices: one torch thread is as fast, and much faster on a busy 2-core machine."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _frames(seed: int, cfg: M.ModelConfig = TINY, h: int = 32, w: int = 48) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (cfg.n_input_frames, h, w, 3), dtype=np.uint8)


def _target(scene_yaml: str, think: str | None = THINK) -> str:
    return text_of(target_tokens(CODEC, Scene.from_yaml(scene_yaml), think))


@pytest.fixture(scope="module")
def tokenizer(tmp_path_factory):
    return M.build_tokenizer(CODEC, M.think_vocab(PARAMS, CODEC.max_objects), tmp_path_factory.mktemp("tok"))


# ----------------------------------------------------------------------------- patches
def test_video_patches_match_transformers_image_processor():
    """A video of two identical frames = one image through transformers' own (PIL-backend)
    Qwen2-VL image processor, which repeats the image over the temporal patch."""
    from transformers.models.qwen2_vl.image_processing_pil_qwen2_vl import Qwen2VLImageProcessorPil

    cfg = M.ModelConfig(n_frames=2, patch_size=4, spatial_merge_size=2, temporal_patch_size=2)
    image = np.random.default_rng(0).integers(0, 256, (16, 24, 3), dtype=np.uint8)
    proc = Qwen2VLImageProcessorPil(patch_size=4, merge_size=2, temporal_patch_size=2)
    ref = proc.preprocess(images=[image], do_resize=False, return_tensors="np")
    ours, grid = M.video_patches(np.stack([image, image]), cfg)
    assert grid.tolist() == [[1, 4, 6]] == ref["image_grid_thw"].tolist()
    assert ours.dtype == np.float32 and ours.shape == ref["pixel_values"].shape == (24, 3 * 2 * 4 * 4)
    np.testing.assert_allclose(ours, ref["pixel_values"], atol=1e-5)


def _transformers_video_patchify():
    """``Qwen2VLVideoProcessor.patchify`` from the installed transformers source (its module
    imports torchvision, which does not import here, so the method is compiled on its own)."""
    import transformers.models.qwen2_vl as pkg

    source = Path(pkg.__path__[0], "video_processing_qwen2_vl.py").read_text()
    cls = next(n for n in ast.parse(source).body if isinstance(n, ast.ClassDef) and n.name == "Qwen2VLVideoProcessor")
    fn = next(n for n in cls.body if isinstance(n, ast.FunctionDef) and n.name == "patchify")
    namespace = {"torch": torch}
    exec(compile(ast.Module(body=[fn], type_ignores=[]), "patchify", "exec"), namespace)
    return namespace["patchify"]


def test_video_patches_match_transformers_video_patchify():
    """Distinct frames, 2 temporal groups: same order as transformers' video ``patchify``."""
    cfg = M.ModelConfig(n_frames=4, patch_size=4, spatial_merge_size=2, temporal_patch_size=2)
    video = np.random.default_rng(1).integers(0, 256, (4, 16, 24, 3), dtype=np.uint8)
    normalised = (video / 255.0 - np.array(M.IMAGE_MEAN)) / np.array(M.IMAGE_STD)
    videos = torch.from_numpy(normalised.transpose(0, 3, 1, 2)[None].astype(np.float32))  # (B, T, C, H, W)
    ref, gt, gh, gw = _transformers_video_patchify()(None, videos, patch_size=4, merge_size=2, temporal_patch_size=2)
    ours, grid = M.video_patches(video, cfg)
    assert grid.tolist() == [[gt, gh, gw]] == [[2, 4, 6]]
    np.testing.assert_allclose(ours, ref[0].numpy(), atol=1e-5)


def test_video_patches_reject_bad_geometry():
    with pytest.raises(M.ModelError, match="multiples of 16"):
        M.video_patches(np.zeros((10, 30, 48, 3), np.uint8), M.ModelConfig())
    with pytest.raises(M.ModelError, match="uint8"):
        M.video_patches(np.zeros((10, 32, 48, 3), np.float32), M.ModelConfig())


# ----------------------------------------------------------------------------- frames
def test_frame_indices_uniform():
    assert M.frame_indices(30, 10).tolist() == [0, 3, 6, 10, 13, 16, 19, 23, 26, 29]
    assert M.frame_indices(29, 10)[[0, -1]].tolist() == [0, 28]
    assert M.frame_indices(5, 5).tolist() == [0, 1, 2, 3, 4]


def test_model_input_rgb_flow_and_both():
    cfg = M.ModelConfig(input="rgb")
    rgb = np.random.default_rng(0).integers(0, 256, (30, 64, 96, 3), dtype=np.uint8)
    out = M.model_input(rgb, None, cfg)
    assert out.shape == (10, 64, 96, 3) and out.dtype == np.uint8
    np.testing.assert_array_equal(out[1], rgb[3])
    # frames off the patch grid are resized to the nearest multiples of 16
    assert M.model_input(rgb[:, :60, :90], None, cfg).shape == (10, 64, 96, 3)
    with pytest.raises(M.ModelError, match="no flow"):
        M.model_input(rgb, None, cfg.model_copy(update={"input": "flow"}))
    pytest.importorskip("pipeline.flow")
    flow = np.random.default_rng(0).normal(size=(29, 64, 96, 2)).astype(np.float16)
    out = M.model_input(None, flow, cfg.model_copy(update={"input": "flow"}), max_magnitude=3.0)
    assert out.shape == (10, 64, 96, 3) and out.dtype == np.uint8
    both = M.model_input(rgb, flow, cfg.model_copy(update={"input": "flow+rgb"}), max_magnitude=3.0)
    assert both.shape == (12, 64, 96, 3) == (M.ModelConfig(input="flow+rgb").n_input_frames, 64, 96, 3)
    np.testing.assert_array_equal(both[0], rgb[0])  # first RGB frame = one temporal patch
    np.testing.assert_array_equal(both[1], rgb[0])
    np.testing.assert_array_equal(both[2:], out)
    with pytest.raises(M.ModelError, match="no rgb"):
        M.model_input(None, flow, cfg.model_copy(update={"input": "flow+rgb"}))


# ----------------------------------------------------------------------------- config
def test_config_errors_are_one_line():
    with pytest.raises(M.ModelError, match=r"^params.yaml: model.n_frames: must be a multiple of temporal_patch_size"):
        M.ModelConfig.from_params({"model": {"n_frames": 9}})
    with pytest.raises(M.ModelError, match=r"^params.yaml: model.bogus: unknown key$"):
        M.ModelConfig.from_params({"model": {"bogus": 1}})
    with pytest.raises(M.ModelError, match=r"model.input: .*got 'depth'"):
        M.ModelConfig.from_params({"model": {"input": "depth"}})
    assert M.ModelConfig.from_params({}) == M.ModelConfig()
    assert sum(M.ModelConfig().mrope_section) == M.ModelConfig().head_dim // 2
    assert M.ModelConfig().mrope_section == [8, 12, 12]


def test_learning_rate_warmup_then_cosine_over_steps():
    cfg = M.ModelConfig(lr=1e-3, min_lr=1e-4, warmup_steps=10, max_steps=110)
    assert M.lr_at(0, cfg) == pytest.approx(1e-4)           # 1/10 of lr after the first step
    assert M.lr_at(9, cfg) == pytest.approx(1e-3)           # warmup ends at lr
    assert M.lr_at(10, cfg) == pytest.approx(1e-3)          # cosine starts at lr, not lower
    assert M.lr_at(60, cfg) == pytest.approx(0.5 * (1e-3 + 1e-4))  # half way: mean of lr and min_lr
    assert M.lr_at(110, cfg) == pytest.approx(1e-4)
    assert M.lr_at(500, cfg) == pytest.approx(1e-4)
    lrs = [M.lr_at(s, cfg) for s in range(10, 111)]
    assert all(a >= b for a, b in zip(lrs, lrs[1:]))       # monotone decay after warmup
    expected = 1e-4 + 0.5 * (1 + math.cos(math.pi * 0.25)) * 9e-4
    assert M.lr_at(35, cfg) == pytest.approx(expected)


def test_batches_cover_every_example_once_per_epoch():
    cfg = M.ModelConfig(batch_size=4, seed=3)
    seen = np.concatenate([M.batch_indices(10, cfg, s) for s in range(5)])  # 20 draws = 2 epochs
    assert sorted(seen[:10].tolist()) == list(range(10)) and sorted(seen[10:].tolist()) == list(range(10))
    np.testing.assert_array_equal(M.batch_indices(10, cfg, 3), M.batch_indices(10, cfg, 3))


# ----------------------------------------------------------------------------- tokenizer
def test_tokenizer_round_trips_targets(tokenizer, tmp_path):
    target = _target(SCENE)
    ids = tokenizer.encode(target, add_special_tokens=False)
    assert tokenizer.unk_token_id not in ids
    assert tokenizer.decode(ids, skip_special_tokens=False, clean_up_tokenization_spaces=False) == target
    assert len(ids) == len(target.split())  # one token per word: one per number
    assert M.decode_tokens(tokenizer, ids + [tokenizer.eos_token_id, 42, 43]) == target.split()
    assert [tokenizer.convert_tokens_to_ids(t) for t in M.SPECIAL_TOKENS] == list(range(len(M.SPECIAL_TOKENS)))
    tokenizer.save_pretrained(tmp_path)
    assert M.load_tokenizer(tmp_path).encode(target, add_special_tokens=False) == ids
    with pytest.raises(M.ModelError, match="not in the tokenizer"):
        M.encode_target(tokenizer, target + " banana")


def test_collate_masks_prompt(tokenizer):
    target = _target(SCENE)
    batch = M.collate([(_frames(0), target), (_frames(1), _target(SCENE, None))], tokenizer, TINY)
    n_video = 2 * 4 * 6 // 4  # grid (4/2, 32/8, 48/8) / merge^2
    assert batch["video_grid_thw"].tolist() == [[2, 4, 6]] * 2
    assert batch["pixel_values_videos"].shape == (2 * 48, 3 * 2 * 8 * 8)
    assert (batch["mm_token_type_ids"] == 2).sum(1).tolist() == [n_video, n_video]
    n_prompt = n_video + 2
    assert (batch["labels"][:, :n_prompt] == M.IGNORE_INDEX).all()
    assert (batch["labels"][0] != M.IGNORE_INDEX).sum() == len(target.split()) + 1  # + eos
    assert batch["attention_mask"][1].sum() < batch["attention_mask"][0].sum()  # right padding
    assert (batch["labels"][1][batch["attention_mask"][1] == 0] == M.IGNORE_INDEX).all()


# ----------------------------------------------------------------------------- constrained sampling
def test_untrained_model_constrained_samples_are_valid_scenes(tokenizer):
    """Grammar-constrained decoding of random weights: K/K samples detokenise to scenes."""
    cfg = TINY.model_copy(update={"temperature": 1.0, "top_p": 1.0})
    model = M.build_model(cfg, tokenizer)
    for seed in range(3):
        samples = M.generate(model, tokenizer, _frames(seed), cfg, CODEC, k=4, seed=seed)
        for toks in samples:
            assert len(toks) <= cfg.max_new_tokens
            scene, error = M.to_scene(toks, CODEC)
            assert error is None and 1 <= len(scene.objects) <= 4
            assert Scene.from_yaml(scene.to_yaml()) == scene  # canonical YAML round-trips
    # the same random model without the grammar does not write scenes
    free = M.generate(model, tokenizer, _frames(0), cfg.model_copy(update={"constrained": False}), CODEC, k=4)
    assert all(M.to_scene(t, CODEC)[0] is None for t in free)


def test_untrained_model_with_a_ramp_codec_writes_valid_scenes_with_and_without_ramps():
    """A codec made with sample.p_ramp > 0 (issue 30): its tokenizer holds ``<ramp>``, and every
    grammar-constrained sample of random weights detokenises to a scene, with at most one ramp."""
    codec = SceneCodec.from_params({"sample": {"p_ramp": 0.5}})
    tok = M.build_tokenizer(codec, M.think_vocab(PARAMS, 4))
    assert "<ramp>" in tok.get_vocab()
    cfg = TINY.model_copy(update={"temperature": 1.0, "top_p": 1.0})
    model = M.build_model(cfg, tok)
    ramps = 0
    for seed in range(2):
        for toks in M.generate(model, tok, _frames(seed), cfg, codec, k=8, seed=seed):
            scene, error = M.to_scene(toks, codec)
            assert error is None and len(scene.static) <= 1 and 1 <= len(scene.objects) <= 4
            assert Scene.from_yaml(scene.to_yaml()) == scene
            ramps += len(scene.static)
    assert ramps >= 1   # the grammar lets random weights write a ramp (it is optional at one place)


def test_max_new_tokens_covers_the_longest_target():
    """Defaults: the grammar's think part + the longest answer fit in max_new_tokens."""
    cfg = M.ModelConfig()
    longest_answer = CODEC.max_answer_tokens()
    assert longest_answer == 2 + 3 + 4 * 21
    room = cfg.max_new_tokens - longest_answer - 3
    assert room // 6 >= 12  # twelve events of 6 tokens still fit
    tok = M.build_tokenizer(CODEC, M.think_vocab(PARAMS, 4))
    with pytest.raises(M.ModelError, match="max_new_tokens: must be >= 98"):
        M.compiled_grammar(tok, CODEC, True, max_new_tokens=90)


# ----------------------------------------------------------------------------- training
@pytest.fixture(scope="module")
def trained(tokenizer, tmp_path_factory):
    """A tiny model overfit on 3 examples with different videos and scenes."""
    examples = [(_frames(0), _target(SCENE)), (_frames(1), _target(BOXES, "no events")),
                (_frames(2), _target(SCENE.replace("0.1, 0.3", "-0.4, -0.2"), "t=0.50 sphere_0 stops"))]
    cfg = TINY.model_copy(update={"max_steps": 240, "eval_interval": 120, "lr": 3e-3, "min_lr": 3e-4,
                                  "aux_weight": 0.1, "batch_size": 3})
    out = tmp_path_factory.mktemp("model")
    result = M.train(examples, examples, cfg, out, tokenizer=tokenizer, codec=CODEC,
                     think_words=M.think_vocab(PARAMS, 4), progress=False)
    return out, result, examples, cfg


def test_overfit_greedy_decoding_reproduces_targets(trained, tokenizer):
    """Each video's greedy sample is exactly its own target (so the output depends on the input)."""
    out, result, examples, cfg = trained
    curve = M.read_curve(out)
    assert [r["step"] for r in curve] == [120, 240] and result["stopped_by"] == "max_steps"
    assert result["train_loss"] < 0.05, result
    greedy = cfg.model_copy(update={"temperature": 0.0})
    model, tok = M.load_model(out)
    outs = M.generate_many(model, tok, [f for f, _ in examples], greedy, CODEC)
    for toks, (_, target) in zip(outs, examples):
        assert " ".join(toks) == target
        scene, error = M.to_scene(toks, CODEC)
        assert error is None and Scene.from_yaml(scene.to_yaml()) == scene
    assert len({" ".join(t) for t in outs}) == 3  # different videos, different scenes
    assert curve[-1]["val_composition"] == 1.0 and curve[-1]["val_valid"] == 1.0


def test_save_load_identical_logits_and_codec(trained):
    out, _, examples, cfg = trained
    model, tok = M.load_model(out)
    batch = M.collate(examples, tok, cfg)
    with torch.no_grad():
        a = model(**batch, use_cache=False).logits
        b = M.load_model(out)[0](**batch, use_cache=False).logits
    torch.testing.assert_close(a, b, rtol=0, atol=0)
    codec, words = M.load_codec(out)
    assert codec.to_dict() == CODEC.to_dict() and "t=0.50" in words
    saved = M.checkpoint_config(out, M.ModelConfig(k=7, input="flow"))
    assert saved.input == "rgb" and saved.n_frames == 4 and saved.k == 7  # input from the checkpoint


def test_init_from_checkpoint_and_resume(trained, tokenizer, tmp_path):
    out, _, examples, cfg = trained
    start = cfg.model_copy(update={"init": str(out), "max_steps": 3, "eval_interval": 2, "eval_samples": 0})
    first = M.train(examples, [], start, tmp_path, codec=CODEC, progress=False)
    assert first["step"] == 3 and [r["step"] for r in M.read_curve(tmp_path)] == [2, 3]
    assert first["train_loss"] < 0.1  # started from the overfit weights, not from scratch
    more = start.model_copy(update={"max_steps": 5})
    second = M.train(examples, [], more, tmp_path, resume=True, progress=False)
    assert second["step"] == 5 and [r["step"] for r in M.read_curve(tmp_path)] == [2, 3, 4, 5]
    with pytest.raises(M.ModelError, match="cannot resume: model.lr was"):
        M.train(examples, [], more.model_copy(update={"lr": 1.0}), tmp_path, resume=True, progress=False)
    other = SceneCodec.from_params({"tokens": {"bins": 128}})
    with pytest.raises(M.ModelError, match="codec.json differs"):
        M.train(examples, [], start, tmp_path / "x", codec=other, progress=False)


def test_max_minutes_is_a_reported_safety_cap(tokenizer, tmp_path):
    cfg = TINY.model_copy(update={"max_steps": 10_000, "max_minutes": 0.001, "eval_samples": 0})
    result = M.train([(_frames(0), _target(SCENE))], [], cfg, tmp_path, tokenizer=tokenizer, codec=CODEC,
                     progress=False)
    assert result["stopped_by"] == "max_minutes" and result["step"] < 10_000


def test_pretrained_folder_is_loaded_offline(trained, tmp_path):
    """``model.pretrained`` with a local folder: weights and tokenizer come from there."""
    out, _, _, cfg = trained
    cfg = cfg.model_copy(update={"pretrained": str(out)})
    tok = M.load_tokenizer(out)
    model = M.build_model(cfg, tok)
    ref, _ = M.load_model(out)
    torch.testing.assert_close(model.lm_head.weight, ref.lm_head.weight)
    with pytest.raises(M.ModelError, match="patch_size: must match the checkpoint"):
        M.build_model(cfg.model_copy(update={"patch_size": 4}), tok)
    with pytest.raises(M.ModelError, match="local folder"):
        M.build_model(cfg.model_copy(update={"pretrained": str(tmp_path / "nope")}), tok)


# ----------------------------------------------------------------------------- stages
def test_stages_tokenize_finetune_predict(tmp_path, monkeypatch):
    """The three DVC stage scripts on 6 synthetic scenes (data contracts of docs/design.md §4/§5)."""
    import runpy

    import yaml

    from conftest import write_model_inputs
    from pipeline import shards

    pytest.importorskip("pipeline.flow")
    stages = Path(__file__).resolve().parents[1] / "stages"
    scenes = [SCENE.replace("0.5\n", f"0.{i + 1}\n") for i in range(6)]
    ids = write_model_inputs(tmp_path, scenes, THINK)
    model = TINY.model_dump(exclude={"pretrained", "seed"}) | {"max_steps": 4, "eval_interval": 2, "k": 2,
                                                               "input": "flow+rgb"}
    paths = {name: str(tmp_path / name) for name in
             ("configs", "events", "flow", "video", "tokenizer", "examples", "model", "predictions", "reports")}
    (tmp_path / "params.yaml").write_text(yaml.safe_dump({"seed": 1, "paths": paths, "model": model}))
    monkeypatch.setenv("DYNAMICS_PARAMS", str(tmp_path / "params.yaml"))
    for script in ("tokenize_targets.py", "finetune.py", "predict.py"):
        monkeypatch.setattr("sys.argv", [script, "--no-progress"] if script == "finetune.py" else [script])
        runpy.run_path(str(stages / script), run_name="__main__")

    examples = shards.read_table(tmp_path / "examples").to_pylist()
    assert [e["scene_id"] for e in examples] == ids
    assert examples[0]["target"] == _target(scenes[0])
    meta = shards.read_meta(tmp_path / "examples")
    assert meta["quantisation_error"]["position.x"]["max_abs"] <= CODEC.q["position.x"].step / 2 + 1e-9
    assert [r["step"] for r in M.read_curve(tmp_path / "model")] == [2, 4]
    assert (tmp_path / "reports" / "train_curve.png").exists()
    preds = shards.read_table(tmp_path / "predictions").to_pylist()
    assert [(p["scene_id"], p["split"], p["sample"]) for p in preds] == [
        (ids[4], "test", 0), (ids[4], "test", 1), (ids[5], "test_comp", 0), (ids[5], "test_comp", 1)]
    assert all(p["scene"] is not None and p["error"] is None for p in preds)  # constrained: always valid


def test_think_vocab_covers_every_event_phrase():
    """Every word events_to_text can write for a 1 s clip of <= 4 objects is in the vocabulary."""
    from pipeline.codec import think_tokens
    from pipeline.events import FLOOR, NO_EVENTS, Event, events_to_text

    vocab = set(M.think_vocab(PARAMS, 4))
    events = [Event("collision", 3, 0.1, ("box_3", FLOOR)), Event("collision", 4, 0.999, ("sphere_0", "cylinder_2")),
              Event("stop", 30, 1.0, ("cylinder_1",)), Event("enter_view", 5, 0.0, ("box_0",)),
              Event("leave_view", 6, 0.5, ("sphere_3",))]
    for text in (events_to_text(events), NO_EVENTS):
        assert set(think_tokens(text)) <= vocab, set(think_tokens(text)) - vocab


def _vision_attention_modules(model):
    from transformers.models.qwen2_5_vl.modeling_qwen2_5_vl import Qwen2_5_VLVisionAttention
    return [m for m in model.modules() if isinstance(m, Qwen2_5_VLVisionAttention)]


@pytest.mark.parametrize("sizes", [[(32, 48)] * 3, [(32, 48), (64, 96)]], ids=["one size", "two sizes"])
def test_batched_vision_attention_equals_the_library_loop(tokenizer, sizes):
    """One SDPA call over all windows gives the logits of transformers' per-window loop, and
    windows of different lengths (two frame sizes in one batch) fall back to that loop."""
    model = M.build_model(TINY.model_copy(update={"window_size": 16}), tokenizer).eval()
    mods = _vision_attention_modules(model)
    assert mods and all("forward" in m.__dict__ for m in mods)   # patched by build_model
    items = [(_frames(i, h=h, w=w), _target(SCENE)) for i, (h, w) in enumerate(sizes)]
    batch = M.collate(items, tokenizer, TINY)
    with torch.no_grad():
        batched = model(**batch, use_cache=False).logits
        for m in mods:
            del m.forward
        loop = model(**batch, use_cache=False).logits
    torch.testing.assert_close(batched, loop, rtol=1e-4, atol=1e-5)


def test_init_new_codec_keeps_the_weights_and_takes_the_params_codec(trained, tmp_path):
    """A checkpoint whose token ranges differ is refused, unless model.init_new_codec: then its
    weights are the start, the params' codec is saved, and missing words join the tokenizer."""
    out, _, examples, cfg = trained
    wide = SceneCodec.from_params({"sample": {"camera_pitch": [5.0, 85.0]}, "tokens": {"max_objects": 6}})
    start = cfg.model_copy(update={"init": str(out), "max_steps": 2, "eval_interval": 2, "eval_samples": 0})
    with pytest.raises(M.ModelError, match="init_new_codec"):
        M.train(examples, [], start, tmp_path / "refused", codec=wide, progress=False)
    words = M.think_vocab(PARAMS, 6)
    result = M.train(examples, [], start.model_copy(update={"init_new_codec": True}), tmp_path / "new",
                     codec=wide, think_words=words, progress=False)
    assert result["step"] == 2 and math.isfinite(result["train_loss"])
    assert result["train_loss"] < 1.0   # the overfit weights, not random ones (~6 nats)
    codec, _ = M.load_codec(tmp_path / "new")
    assert codec.to_dict() == wide.to_dict() and codec.to_dict() != CODEC.to_dict()
    model, tok = M.load_model(tmp_path / "new")
    assert set(words) <= set(tok.get_vocab())
    assert all("forward" in m.__dict__ for m in _vision_attention_modules(model))   # load_model batches too


def test_more_objects_only_extends_the_init_codec_without_init_new_codec(trained, tmp_path):
    """A params codec that only allows more objects (tokens.max_objects 6, for the 5-6-object test
    row) keeps every token's meaning: fine-tuning starts from the checkpoint without
    model.init_new_codec, saves the wider codec, and its grammar then admits 6 objects."""
    out, _, examples, cfg = trained
    init_codec, _ = M.load_codec(out)
    more = SceneCodec.from_dict({**init_codec.to_dict(), "max_objects": 6})
    assert more.extends(init_codec) and not init_codec.extends(more)
    ranges = SceneCodec.from_params({"sample": {"camera_pitch": [5.0, 85.0]}, "tokens": {"max_objects": 6}})
    assert not ranges.extends(init_codec)                     # other token ranges: not an extension
    start = cfg.model_copy(update={"init": str(out), "max_steps": 2, "eval_interval": 2, "eval_samples": 0})
    result = M.train(examples, [], start, tmp_path / "more", codec=more, think_words=M.think_vocab(PARAMS, 6),
                     progress=False)
    assert result["step"] == 2 and result["train_loss"] < 1.0   # the overfit weights, not random ones
    codec, _ = M.load_codec(tmp_path / "more")
    assert codec.max_objects == 6 and codec.max_answer_tokens() > init_codec.max_answer_tokens()


def test_device_is_checked():
    from pipeline.model.training import resolve_device
    assert resolve_device(TINY.model_copy(update={"device": "auto"})).type == ("cuda" if torch.cuda.is_available()
                                                                                 else "cpu")
    if not torch.cuda.is_available():
        with pytest.raises(M.ModelError, match="model.device: cuda"):
            resolve_device(TINY.model_copy(update={"device": "cuda"}))
