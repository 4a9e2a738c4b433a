"""Tests of pipeline.model: patch layout, target text, tokenizer, tiny-model training and sampling."""

from __future__ import annotations

import ast
import os
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import numpy as np
import pytest
import torch

from pipeline import model as M
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
THINK = "t=0.00 s: sphere_0 rolls. t=0.73 s: sphere_0 stops."

# A config small enough for the tests: ~190k parameters, 4 frames of 32 x 48 px.
TINY = M.ModelConfig(
    n_frames=4,
    hidden_size=64,
    intermediate_size=128,
    num_layers=2,
    num_heads=4,
    num_kv_heads=2,
    vision_depth=2,
    vision_hidden_size=32,
    vision_intermediate_size=64,
    vision_num_heads=2,
    batch_size=2,
    lr=3e-3,
    min_lr=1e-3,
    warmup_steps=5,
    max_steps=40,
    max_minutes=5.0,
    eval_interval=20,
    eval_batches=1,
    max_new_tokens=24,
    k=3,
)


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    """Tiny matrices: one torch thread is as fast, and much faster on a busy 2-core machine."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _frames(seed: int, cfg: M.ModelConfig = TINY, h: int = 32, w: int = 48) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (cfg.n_frames, h, w, 3), dtype=np.uint8)


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


def test_model_input_rgb_and_flow():
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


# ----------------------------------------------------------------------------- text
def test_target_parse_round_trip():
    for reasoning in (True, False):
        text = M.target_text(SCENE, THINK, reasoning)
        think, answer = M.parse_output(text)
        assert answer == SCENE
        assert think == (THINK if reasoning else None)
        assert Scene.from_yaml(answer).to_yaml() == SCENE
    assert M.target_text(SCENE, THINK, False) == f"<answer>{SCENE}</answer>"
    assert M.parse_output("<think>a</think><answer>version: 1") == ("a", None)  # cut off
    assert M.parse_output("garbage") == (None, None)


@pytest.fixture(scope="module")
def tokenizer(tmp_path_factory):
    texts = [M.target_text(SCENE, THINK, True), M.target_text(SCENE.replace("0.1]", "0.25]"), THINK, False)] * 4
    return M.train_tokenizer(texts, 512, tmp_path_factory.mktemp("tok"))


def test_tokenizer_round_trips_scene_yaml(tokenizer, tmp_path):
    target = M.target_text(SCENE, THINK, True)
    unseen = SCENE.replace("0.5", "7.25").replace("sphere", "box") + "é ü\t{}"
    for text in (SCENE, target, unseen):
        ids = tokenizer.encode(text, add_special_tokens=False)
        assert tokenizer.decode(ids, skip_special_tokens=False, clean_up_tokenization_spaces=False) == text
    ids = tokenizer.encode(target, add_special_tokens=False)
    for tag in (M.THINK, M.END_THINK, M.ANSWER, M.END_ANSWER):
        assert ids.count(tokenizer.convert_tokens_to_ids(tag)) == 1  # tags are single tokens
    assert [tokenizer.convert_tokens_to_ids(t) for t in M.SPECIAL_TOKENS] == list(range(len(M.SPECIAL_TOKENS)))
    assert M.decode(tokenizer, ids + [tokenizer.eos_token_id, 42, 43]) == target
    tokenizer.save_pretrained(tmp_path)
    again = M.load_tokenizer(tmp_path)
    assert again.encode(target, add_special_tokens=False) == ids


def test_collate_masks_prompt(tokenizer):
    target = M.target_text(SCENE, THINK, True)
    batch = M.collate([(_frames(0), target), (_frames(1), "<answer>x</answer>")], tokenizer, TINY)
    n_video = 2 * 4 * 6 // 4  # grid (4/2, 32/8, 48/8) / merge^2
    assert batch["video_grid_thw"].tolist() == [[2, 4, 6]] * 2
    assert batch["pixel_values_videos"].shape == (2 * 48, 3 * 2 * 8 * 8)
    assert (batch["mm_token_type_ids"] == 2).sum(1).tolist() == [n_video, n_video]
    n_prompt = n_video + 2
    assert (batch["labels"][:, :n_prompt] == M.IGNORE_INDEX).all()
    n_target = len(tokenizer.encode(target, add_special_tokens=False)) + 1  # + eos
    assert (batch["labels"][0] != M.IGNORE_INDEX).sum() == n_target
    assert batch["attention_mask"][1].sum() < batch["attention_mask"][0].sum()  # right padding
    assert (batch["labels"][1][batch["attention_mask"][1] == 0] == M.IGNORE_INDEX).all()


# ----------------------------------------------------------------------------- training
@pytest.fixture(scope="module")
def trained(tokenizer, tmp_path_factory):
    """A tiny model trained on 2 examples (40 steps); returns (out_dir, result, examples)."""
    examples = [
        (_frames(0), M.target_text(SCENE, THINK, True)),
        (_frames(1), M.target_text(SCENE.replace("0.1]", "0.25]"), THINK, False)),
    ]
    out = tmp_path_factory.mktemp("model")
    result = M.train(examples, examples, TINY, out, tokenizer=tokenizer, progress=False)
    return out, result, examples


def test_tiny_model_overfits_two_examples(trained, tokenizer):
    out, result, examples = trained
    curve = M.read_curve(out)
    assert [r["step"] for r in curve] == [20, 40] and result["step"] == 40
    assert list(curve[0]) == list(M.CURVE_COLUMNS)
    # build_model seeds from cfg.seed: this is the model training started from
    initial = M.estimate_loss(M.build_model(TINY, tokenizer), examples, tokenizer, TINY)
    assert initial > 4.5  # ~ln(len(tokenizer)) = ln(~450) for a random init
    assert result["val_loss"] < 0.5 * initial
    assert result["train_loss"] < curve[0]["train_loss"]
    assert {"config.json", "model.safetensors", "tokenizer.json", M.TRAINER_STATE_FILE, M.CONFIG_FILE} <= {
        p.name for p in out.iterdir()
    }


def test_save_load_identical_logits(trained, tokenizer):
    out, _, examples = trained
    model, tok = M.load_model(out)
    assert tok.get_vocab() == tokenizer.get_vocab()
    batch = M.collate(examples, tok, TINY)
    twice = M.load_model(out)[0]
    with torch.no_grad():
        a = model(**batch, use_cache=False).logits
        b = twice(**batch, use_cache=False).logits
    torch.testing.assert_close(a, b, rtol=0, atol=0)
    # and the same as the in-memory model that was saved: re-save and reload
    model.save_pretrained(out / "again")
    tok.save_pretrained(out / "again")
    with torch.no_grad():
        c = M.load_model(out / "again")[0](**batch, use_cache=False).logits
    torch.testing.assert_close(a, c, rtol=0, atol=0)


def test_generate_returns_k_strings(trained):
    out, _, examples = trained
    model, tok = M.load_model(out)
    texts = M.generate(model, tok, examples[0][0], TINY, k=3, seed=0)
    assert len(texts) == 3 and all(isinstance(t, str) for t in texts)
    assert M.generate(model, tok, examples[0][0], TINY, k=3, seed=0) == texts  # seeded
    assert all(t.startswith((M.THINK, M.ANSWER)) for t in texts)  # learned how targets start
    greedy = TINY.model_copy(update={"temperature": 0.0})
    assert len(M.generate(model, tok, examples[0][0], greedy, k=2)) == 2


def test_resume_continues_step_count(tokenizer, tmp_path):
    examples = [(_frames(0), M.target_text(SCENE, THINK, True))]
    cfg = TINY.model_copy(update={"max_steps": 3, "eval_interval": 2})
    first = M.train(examples, [], cfg, tmp_path, tokenizer=tokenizer, progress=False)
    assert first["step"] == 3 and [r["step"] for r in M.read_curve(tmp_path)] == [2, 3]
    state = torch.load(tmp_path / M.TRAINER_STATE_FILE, weights_only=False)
    assert state["step"] == 3 and state["optimizer"]["state"]
    more = cfg.model_copy(update={"max_steps": 5})
    second = M.train(examples, [], more, tmp_path, resume=True, progress=False)
    assert second["step"] == 5
    assert [r["step"] for r in M.read_curve(tmp_path)] == [2, 3, 4, 5]
    assert second["seconds"] >= first["seconds"]
    with pytest.raises(M.ModelError, match="cannot resume: model.lr was"):
        M.train(examples, [], more.model_copy(update={"lr": 1.0}), tmp_path, resume=True, progress=False)
    # resuming a finished run does nothing
    assert M.train(examples, [], more, tmp_path, resume=True, progress=False)["step"] == 5
    # without resume the run starts over
    one = cfg.model_copy(update={"max_steps": 1})
    fresh = M.train(examples, [], one, tmp_path, tokenizer=tokenizer, progress=False)
    assert fresh["step"] == 1


def test_pretrained_folder_is_loaded_offline(trained, tmp_path):
    """``model.pretrained`` with a local folder: weights and tokenizer come from there."""
    out, _, examples = trained
    cfg = TINY.model_copy(update={"pretrained": str(out)})
    tok = M.load_tokenizer(out)
    model = M.build_model(cfg, tok)
    ref, _ = M.load_model(out)
    torch.testing.assert_close(model.lm_head.weight, ref.lm_head.weight)
    with pytest.raises(M.ModelError, match="patch_size: must match the checkpoint"):
        M.build_model(cfg.model_copy(update={"patch_size": 4}), tok)
    with pytest.raises(M.ModelError, match="local folder"):
        M.build_model(cfg.model_copy(update={"pretrained": str(tmp_path / "nope")}), tok)


# ----------------------------------------------------------------------------- stages
def test_stages_tokenize_finetune_infer(tmp_path, monkeypatch):
    """The three DVC stage scripts on 6 synthetic scenes (data contracts of DESIGN §4/§5)."""
    import runpy

    import yaml

    from pipeline import shards

    pytest.importorskip("pipeline.flow")
    stages = Path(__file__).resolve().parents[1] / "stages"
    rng = np.random.default_rng(0)
    splits = ["train", "train", "train", "val", "test", "test_comp"]
    ids = [shards.scene_id(i) for i in range(6)]
    scenes = [SCENE.replace("0.5\n", f"0.{i + 1}\n") for i in range(6)]
    for s in range(2):  # two shards of three scenes
        part = slice(3 * s, 3 * s + 3)
        shards.write_table(shards.shard_path(tmp_path / "configs", s, "parquet"), [
            {"scene_id": i, "split": sp, "seed": 0, "scene": sc, "composition": "sphere"}
            for i, sp, sc in zip(ids[part], splits[part], scenes[part])])
        shards.write_arrays(shards.shard_path(tmp_path / "flow", s, "zarr"),
                            {"flow": rng.normal(size=(3, 8, 32, 48, 2)).astype(np.float16)},
                            scene_ids=ids[part], attrs={"max_magnitude": 2.0})
    shards.write_table(shards.shard_path(tmp_path / "events", 0, "parquet", prefix="think"),
                       [{"scene_id": i, "think": THINK} for i in ids])
    model = TINY.model_dump(exclude={"pretrained", "seed"}) | {"max_steps": 4, "eval_interval": 2, "k": 2}
    paths = {name: str(tmp_path / name) for name in
             ("configs", "events", "flow", "video", "tokenizer", "examples", "model", "predictions")}
    (tmp_path / "params.yaml").write_text(yaml.safe_dump({"seed": 1, "paths": paths, "model": model}))
    monkeypatch.setenv("DYNAMICS_PARAMS", str(tmp_path / "params.yaml"))
    for script in ("tokenize_targets.py", "finetune.py", "infer.py"):
        monkeypatch.setattr("sys.argv", [script])
        runpy.run_path(str(stages / script), run_name="__main__")

    examples = shards.read_table(tmp_path / "examples").to_pylist()
    assert [e["scene_id"] for e in examples] == ids
    assert examples[0]["target"] == M.target_text(scenes[0], THINK, True)
    assert [r["step"] for r in M.read_curve(tmp_path / "model")] == [2, 4]
    preds = shards.read_table(tmp_path / "predictions").to_pylist()
    assert [(p["scene_id"], p["split"], p["sample"]) for p in preds] == [
        (ids[4], "test", 0), (ids[4], "test", 1), (ids[5], "test_comp", 0), (ids[5], "test_comp", 1)]
    assert all((p["scene"] is None) != (p["error"] is None) for p in preds)
