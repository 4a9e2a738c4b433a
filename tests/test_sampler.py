"""Scene sampler (issue 4, check 9): generated scenes pass the paper's filters, object counts
and shapes follow the configured distribution, held-out 4-object compositions never appear
outside ``test_comp``. Filters are re-checked here with independent, slower means: a full
MuJoCo render of the compiled scene and MuJoCo's collision detection on the compiled scene.
"""

import pipeline  # noqa: F401  (MUJOCO_GL before mujoco)

import itertools
from collections import Counter

import numpy as np
import pytest
from numpy.testing import assert_allclose
from pydantic import ValidationError

from pipeline.camera import project
from pipeline.mjcf import SimOptions, compile_model, initial_state
from pipeline.render import FrameRenderer
from pipeline.sample_config import SampleConfig, sample_composition, scene_seed, split_names
from pipeline.sampler import SceneFilter, _sample_layout, initial_overlap, iter_dataset, sample_scene
from pipeline.scene import Scene
from pipeline.simulate import rollout

CFG = SampleConfig(n_train=10, n_val=2, n_test=2, n_test_comp=4)


@pytest.fixture(scope="module")
def filt():
    with SceneFilter(CFG) as f:
        yield f


@pytest.fixture(scope="module")
def dataset(filt):
    return list(iter_dataset(CFG, seed=7, filt=filt))


def test_splits_ids_and_held_out(dataset):
    assert [s for _, s, _ in dataset] == split_names(CFG)
    assert [sid for sid, _, _ in dataset] == [f"scene-{i:06d}" for i in range(len(dataset))]
    held = set(CFG.held_out)
    for _, split, scene in dataset:
        if split == "test_comp":
            assert len(scene.objects) == 4 and scene.composition in held
        else:
            assert scene.composition not in held


def test_scenes_pass_the_filters(dataset):
    for sid, _, scene in dataset:
        # no initial interpenetration (MuJoCo contacts of the compiled scene at t = 0)
        assert initial_overlap(scene) <= CFG.overlap_tolerance, sid
        model = compile_model(scene)
        # every object visible in the first frame with at least the minimum area (full render)
        with FrameRenderer(model, CFG.width, CFG.height) as r:
            r.set_pose(initial_state(scene)[0].reshape(-1, 7))
            seg = r.segmentation()
        counts = np.bincount(seg[seg >= 0], minlength=len(scene.objects))
        assert counts.min() >= CFG.min_pixel_fraction * CFG.width * CFG.height, (sid, counts)
        # objects stay in view (centres inside the image) for the whole clip
        trace = rollout(model, len(scene.objects), scene.n_frames, scene.fps, record_contacts=False)
        uv, depth = project(trace.position, scene.camera, CFG.width, CFG.height)
        assert (depth > 0).all() and (uv >= 0).all() and (uv[..., 0] <= CFG.width).all() and (uv[..., 1] <= CFG.height).all()
        # names follow the video: objects ordered left to right in the first frame
        assert np.all(np.diff(uv[0, :, 0]) >= 0), sid
        # something moves, and the canonical text round-trips
        assert np.abs(trace.qvel).max() > 0.1
        assert Scene.from_yaml(scene.to_yaml()) == scene


def test_scene_is_reproducible_from_its_seed(dataset, filt):
    for i in (0, len(dataset) - 1):
        sid, split, scene = dataset[i]
        again = sample_scene(np.random.default_rng(scene_seed(7, i)), CFG, split, filt)
        assert again.to_yaml() == scene.to_yaml()


def test_template_filter_equals_full_render_and_collision(filt):
    # The filter edits one template model in place; it must agree with compiling the scene.
    rng = np.random.default_rng(3)
    overlapping = Scene.from_dict({"camera": {"height": 1.0, "pitch": 40.0, "fov": 45.0}, "objects": [
        {"shape": "box", "size": {"width": 0.3, "depth": 0.3, "height": 0.3}, "mass": 1, "position": [0, -0.5, 0.15]},
        {"shape": "sphere", "size": {"radius": 0.15}, "mass": 1, "position": [0.2, -0.5, 0.14]}]})
    scenes = [overlapping]
    while len(scenes) < 10:
        data = _sample_layout(rng, CFG, ["sphere", "cylinder", "box", "cylinder"][: 1 + len(scenes) % 4])
        if data is not None:
            scenes.append(Scene.from_dict(data))
    for scene in scenes:
        model = compile_model(scene, SimOptions(textured=False))
        with FrameRenderer(model, CFG.width, CFG.height) as r:
            r.set_pose(initial_state(scene)[0].reshape(-1, 7))
            full = r.segmentation()
        fast = filt.first_frame_segmentation(scene)
        assert np.array_equal(fast, full), scene.to_yaml()
        assert_allclose(filt.initial_overlap(scene), initial_overlap(scene), atol=1e-9)
    assert initial_overlap(overlapping) > 0.01


def _expected_shape_frequencies(cfg):
    """Exact shape marginals under i.i.d. shapes with held-out 4-multisets redrawn."""
    names, ps = zip(*sorted(cfg.shapes.items()))
    held = set(cfg.held_out)
    freq = Counter()
    for n, pn in cfg.n_objects.items():
        combos = [(c, np.prod([ps[names.index(s)] for s in c])) for c in itertools.product(names, repeat=n)]
        combos = [(c, p) for c, p in combos if n != 4 or tuple(sorted(c)) not in held]
        total = sum(p for _, p in combos)
        for c, p in combos:
            for s in c:
                freq[s] += pn * p / total
    mean_n = sum(n * p for n, p in cfg.n_objects.items())
    return {s: f / mean_n for s, f in freq.items()}


def test_counts_and_shapes_follow_the_configured_distribution():
    cfg = SampleConfig()
    draws = [sample_composition(np.random.default_rng(scene_seed(1, i)), cfg, "train") for i in range(6000)]
    counts = Counter(len(c) for c in draws)
    # 6000 draws: binomial standard deviation <= 0.0065; tolerance 0.025 (~4 sigma)
    for n, p in cfg.n_objects.items():
        assert_allclose(counts[n] / len(draws), p, atol=0.025)
    shapes = Counter(s for c in draws for s in c)
    total = sum(shapes.values())
    for s, p in _expected_shape_frequencies(cfg).items():
        assert_allclose(shapes[s] / total, p, atol=0.02)
    assert not any(len(c) == 4 and tuple(sorted(c)) in set(cfg.held_out) for c in draws)
    comp = Counter(tuple(sorted(sample_composition(np.random.default_rng(i), cfg, "test_comp"))) for i in range(200))
    assert set(comp) == set(cfg.held_out)


def test_config_is_validated():
    with pytest.raises(ValidationError, match="extra"):
        SampleConfig(n_trian=5)
    with pytest.raises(ValidationError, match="unknown shape"):
        SampleConfig(held_out=[["box", "box", "cone", "sphere"]])
    with pytest.raises(ValidationError, match="low must be <= high"):
        SampleConfig(mass=(2.0, 1.0))
    with pytest.raises(ValidationError, match="non-negative"):
        SampleConfig(n_objects={1: -0.5, 2: 1.0})
    assert SampleConfig(shapes={"box": 2, "sphere": 2}).shapes == {"box": 0.5, "sphere": 0.5}
    assert SampleConfig(held_out=[["sphere", "box", "box", "cylinder"]]).held_out == [("box", "box", "cylinder", "sphere")]


def test_wide_profile_keeps_objects_within_max_floor_distance_and_in_the_frame():
    """The pretrain profile's wide cameras (pitch 10-85 deg, height 0.3-1.6 m) with small objects:
    every object starts within max_floor_distance of the eye's ground point, passes the size
    filter, and 5-6 object scenes can be drawn (the generalisation split)."""
    cfg = SampleConfig(n_train=8, n_val=0, n_test=0, n_test_comp=0, extent=(0.05, 0.4), camera_height=(0.3, 1.6),
                       camera_pitch=(10.0, 85.0), camera_fov=(30.0, 60.0), min_pixel_fraction=0.006,
                       max_floor_distance=2.0, n_objects={5: 0.5, 6: 0.5})
    with SceneFilter(cfg) as f:
        scenes = [scene for _, _, scene in iter_dataset(cfg, seed=3, filt=f)]
        assert {len(s.objects) for s in scenes} <= {5, 6} and len(scenes) == 8
        for s in scenes:
            eye = np.asarray(s.camera.eye)
            for o in s.objects:
                assert np.hypot(*(np.asarray(o.position)[:2] - eye[:2])) <= 2.0 + 1e-6
            seg = f.first_frame_segmentation(s)
            assert all((seg == k).sum() >= 0.006 * seg.size for k in range(len(s.objects)))
    with pytest.raises(ValidationError, match="1..6"):
        SampleConfig(n_objects={7: 1.0})


# ----------------------------------------------------------------------------- test_many (issue 30)
def test_test_many_split_holds_five_or_six_objects_and_leaves_the_other_scenes_alone():
    """The generalisation row's split: scenes of 5-6 objects (more than training's 1-4), numbered
    last, so every other scene keeps its index, seed and layout; they pass the paper's filters, and a
    codec with room for 6 objects writes them (one with 4 refuses the params)."""
    from pipeline.codec import CodecError, SceneCodec
    base = SampleConfig(n_train=3, n_val=1, n_test=2, n_test_comp=1, width=96, height=64)
    many = base.model_copy(update={"n_test_many": 4})
    assert split_names(many) == split_names(base) + ["test_many"] * 4
    a = list(iter_dataset(base, 7))
    b = list(iter_dataset(many, 7))
    assert [(i, s, x.to_yaml()) for i, s, x in a] == [(i, s, x.to_yaml()) for i, s, x in b[: len(a)]]
    extra = [x for _, s, x in b if s == "test_many"]
    assert len(extra) == 4 and all(5 <= len(x.objects) <= 6 for x in extra)
    assert {len(x.objects) for x in extra} <= {5, 6}
    params = {"sample": {"n_test_many": 4}, "tokens": {"max_objects": 6}}
    codec = SceneCodec.from_params(params)
    for x in extra:
        assert codec.decode(codec.encode(x)).composition == x.composition
    with pytest.raises(CodecError, match="tokens.max_objects: must be >= 6"):
        SceneCodec.from_params({"sample": {"n_test_many": 4}})
    with pytest.raises(ValidationError, match="many_objects"):
        SampleConfig(many_objects=(6, 5))
