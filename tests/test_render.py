"""Fast scene generation keeps its outputs (issue 8, item 5).

* A renderer that reuses one GL context and shared ``MjrContext`` objects across scenes
  (``pipeline.render.shared_gl``) gives exactly the frames of a fresh ``mujoco.Renderer`` per
  scene drawing rgb, segmentation and depth separately (the code before issue 8), for scenes
  with different shapes, object counts and cameras rendered in sequence and revisited.
* The data stages write identical shards with 1 and 2 worker processes.
"""

import pipeline  # noqa: F401  (MUJOCO_GL before mujoco)

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml

from pipeline.mjcf import Appearance, compile_model, to_xml
from pipeline.render import FrameRenderer, GLResources, reference_frames
from pipeline.scene import Scene
from pipeline.scene_look import random_appearance
from pipeline.simulate import rollout

ROOT = Path(__file__).resolve().parents[1]
W, H = 96, 64


def _obj(shape, size, position, velocity=(0.0, 0.0, 0.0), spin=(0.0, 0.0, 0.0)):
    return {"shape": shape, "size": size, "mass": 1.0, "position": list(position),
            "linear_velocity": list(velocity), "angular_velocity": list(spin)}


SCENES = {
    "one_sphere": {"camera": {"height": 1.0, "pitch": 35.0, "fov": 45.0},
                   "objects": [_obj("sphere", {"radius": 0.12}, (0.0, 0.0, 0.12), (0.8, 0.3, 0.0))]},
    "box_and_cylinder": {"camera": {"height": 1.3, "pitch": 45.0, "fov": 40.0},
                         "objects": [_obj("box", {"width": 0.3, "depth": 0.2, "height": 0.25}, (-0.3, 0.1, 0.4),
                                          (0.5, 0.0, 1.0), (1.0, 2.0, 0.5)),
                                     _obj("cylinder", {"radius": 0.1, "height": 0.3}, (0.3, -0.1, 0.15),
                                          (-0.6, 0.2, 0.0))]},
    "four_objects": {"camera": {"height": 0.9, "pitch": 30.0, "fov": 50.0},
                     "objects": [_obj("sphere", {"radius": 0.1}, (-0.45, 0.2, 0.1), (1.0, 0.0, 0.0)),
                                 _obj("box", {"width": 0.2, "depth": 0.2, "height": 0.2}, (-0.1, 0.3, 0.1)),
                                 _obj("cylinder", {"radius": 0.08, "height": 0.2}, (0.2, 0.0, 0.3), (0.0, 0.0, 0.5)),
                                 _obj("sphere", {"radius": 0.14}, (0.5, 0.4, 0.14), (-1.2, -0.2, 0.0))]},
}


def _clip(name):
    scene = Scene.from_dict(SCENES[name])
    model = compile_model(scene)
    trace = rollout(model, len(scene.objects), 12, scene.fps)
    return model, trace.qpos


@pytest.fixture(scope="module")
def clips():
    return {name: _clip(name) for name in SCENES}


@pytest.fixture(scope="module")
def references(clips):
    return {name: reference_frames(*clip, W, H) for name, clip in clips.items()}


def _assert_same(frames, ref, name):
    rgb, seg, depth = ref
    assert frames.rgb.dtype == np.uint8 and np.array_equal(frames.rgb, rgb), name
    assert frames.seg.dtype == np.int8 and np.array_equal(frames.seg, seg), name
    assert frames.depth.dtype == np.float32 and np.array_equal(frames.depth, depth), name


def test_reused_gl_context_gives_the_frames_of_a_fresh_renderer(clips, references):
    order = ["one_sphere", "box_and_cylinder", "four_objects", "one_sphere", "four_objects", "box_and_cylinder"]
    with GLResources() as gl:
        for name in order:  # revisits reuse the contexts made for earlier scenes
            model, qpos = clips[name]
            with FrameRenderer(model, W, H, gl) as r:
                frames = r.render(qpos)
            _assert_same(frames, references[name], name)
            assert np.isfinite(frames.flow).all() and frames.flow.shape == (len(qpos) - 1, H, W, 2)
        # one context per object count (textures differ), single- and multisampled
        assert gl.n_contexts == 2 * 3


def test_random_looks_render_alike_with_a_bounded_context_cache():
    """Scenes that each look different (sample.look: random) need a context each; the cache
    keeps at most max_contexts of them and frees the oldest, and every scene still renders
    exactly as with a renderer of its own."""
    scene = Scene.from_dict(SCENES["box_and_cylinder"])
    models = [compile_model(to_xml(scene, None, random_appearance(0, f"scene-{i:06d}", 2))) for i in range(4)]
    qpos = rollout(models[0], 2, 3, scene.fps).qpos
    refs = [reference_frames(m, qpos, W, H) for m in models]
    assert not np.array_equal(refs[0][0], refs[1][0])   # the looks differ
    with GLResources(max_contexts=2) as gl:
        for m, ref in zip(models + models[:1], refs + refs[:1]):
            with FrameRenderer(m, W, H, gl) as r:
                frames = r.render(qpos)
                assert gl.n_contexts <= 2 + 1   # a renderer holds its two; older ones are freed
            _assert_same(frames, ref, "random look")
        assert gl.n_contexts <= 2


def test_random_look_is_a_function_of_seed_and_scene():
    a, b = random_appearance(0, "scene-000001", 3), random_appearance(0, "scene-000001", 3)
    assert a == b and len(a.object_rgb) == 3 and a.floor_texture in ("checker", "gradient", "flat")
    others = {random_appearance(seed, sid, 3) for seed in (0, 1) for sid in ("scene-000001", "scene-000002")}
    assert len(others) == 4
    with pytest.raises(ValueError, match="PNG floor"):
        to_xml(Scene.from_dict(SCENES["one_sphere"]), None, Appearance(floor_texture="png", floor_png=b"x"))


def test_private_renderer_and_single_outputs_match(clips, references):
    model, qpos = clips["box_and_cylinder"]
    with FrameRenderer(model, W, H) as r:  # its own GL context, as before
        _assert_same(r.render(qpos), references["box_and_cylinder"], "private")
        only_seg = r.render(qpos, rgb=False, depth=False, flow=False)
        assert only_seg.rgb is None and only_seg.depth is None and only_seg.flow is None
        assert np.array_equal(only_seg.seg, references["box_and_cylinder"][1])
        r.set_pose(qpos[3])
        assert np.array_equal(r.segmentation(), references["box_and_cylinder"][1][3])


def _read_all(root: Path) -> dict:
    """Every artifact of a workspace's data/ as comparable Python values."""
    import zarr

    out = {}
    for f in sorted(root.rglob("*")):
        rel = str(f.relative_to(root))
        if f.name == "meta.json":
            out[rel] = f.read_text()
        elif f.suffix == ".parquet":
            table = pq.read_table(f)
            out[rel] = (table.to_pylist(), table.schema.metadata)
        elif f.suffix == ".zarr":
            group = zarr.open_group(str(f), mode="r")
            out[rel] = (dict(group.attrs), {k: group[k][...] for k in sorted(group.array_keys())})
    return out


def _equal(a, b) -> bool:
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_equal(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_equal(x, y) for x, y in zip(a, b))
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b)
    return a == b


def test_data_stages_give_the_same_shards_with_1_and_2_workers(tmp_path):
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    params["sample"].update(n_train=6, n_val=2, n_test=2, n_test_comp=2, shard_size=4)
    env = {**os.environ, "MUJOCO_GL": "egl", "PYTHONPATH": str(ROOT)}
    data = {}
    for workers in (1, 2):
        ws = tmp_path / f"workers{workers}"
        ws.mkdir()
        (ws / "params.yaml").write_text(yaml.safe_dump({**params, "compute": {"workers": workers}}, sort_keys=False))
        for stage in ("sample_configs", "compile_mjcf", "render", "flow", "events"):
            proc = subprocess.run([sys.executable, str(ROOT / "stages" / f"{stage}.py")], cwd=ws, env=env,
                                  capture_output=True, text=True, timeout=600)
            assert proc.returncode == 0, f"{stage} with {workers} workers:\n{proc.stderr[-2000:]}"
            assert "EGLError" not in proc.stderr, proc.stderr[-2000:]
        data[workers] = _read_all(ws / "data")
    # meta.json of configs, mjcf, video, traces, flow, events; 3 shards of each (events: events + think)
    assert len(data[1]) == 6 + 3 * 7
    assert data[1].keys() == data[2].keys()
    for key in data[1]:
        assert _equal(data[1][key], data[2][key]), key
