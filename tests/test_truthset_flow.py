"""Ground-truth flow of truth clips (pipeline.truthsets.flow) checked against the rendered frames,
the projected centres, MuJoCo's own depth-based flow and its error messages.

Each engine renders one small clip here (160 x 120 px, 24 frames, no shadows, no specular
light, textured objects): a sphere sliding on a frictionless floor (pure translation), a box
spinning about z on the frictionless floor and a lying cylinder rolling without slip.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from pipeline.truthsets import mujoco_scenes
from pipeline.truthsets.common import TruthClip, motion_labels, speeds, write_clip
from pipeline.truthsets.flow import truth_flow
from pipeline.truthsets.planning import roll, slide
from pipeline.truthsets.scenario import CameraSpec, Look, ObjectSpec, Scenario, project

W, H, FPS, DURATION = 160, 120, 30, 0.8


def _scenario() -> Scenario:
    d = np.array([0.3, 0.2, -1.0])
    look = Look(floor_kind="noise", floor_rgb1=(0.35, 0.4, 0.35), floor_rgb2=(0.65, 0.55, 0.5), floor_tile=0.8,
                light_dir=d / np.linalg.norm(d), light_diffuse=0.6, light_ambient=0.15, light_specular=0.0,
                headlight_ambient=0.3, headlight_diffuse=0.3, shadows=False, object_checker=True, texture_seed=5)
    cam = CameraSpec(yaw=15.0, pitch=40.0, fov=45.0, distance=2.3, look_at=np.array([0.0, 0.1, 0.1]))
    ident = np.array([1.0, 0.0, 0.0, 0.0])
    ball = ObjectSpec("sphere", {"radius": 0.15}, 1.0, np.array([-0.55, -0.25, 0.15]), ident.copy(), friction=0.0,
                      rgb=(0.9, 0.2, 0.2))
    ball.linear_velocity = np.array([0.9, 0.0, 0.0])            # frictionless: slides, never turns
    box = ObjectSpec("box", {"width": 0.32, "depth": 0.18, "height": 0.2}, 1.0, np.array([0.45, 0.45, 0.1]),
                     ident.copy(), friction=0.0, rgb=(0.2, 0.3, 0.9))
    slide(box, np.array([-0.4, 0.0, 0.0]), spin=4.0)
    cyl = ObjectSpec("cylinder", {"radius": 0.1, "height": 0.3}, 1.0, np.array([-0.45, 0.55, 0.1]), ident.copy(),
                     friction=0.5, rgb=(0.2, 0.8, 0.3))
    roll(cyl, np.array([0.6, 0.0, 0.0]))
    return Scenario("moving", cam, look, [ball, box, cyl], W, H, FPS, DURATION)


def _engine(name: str):
    if name == "pybullet":
        pytest.importorskip("pybullet")
        from pipeline.truthsets import pybullet_scenes

        return pybullet_scenes
    return mujoco_scenes


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """``made(engine)``: (folder, TruthClip with lossless rgb, flow, valid, scenario) of one
    engine's clip, rendered once per module."""
    cache = {}

    def get(engine: str):
        if engine not in cache:
            sc = _scenario()
            r = _engine(engine).run(sc)
            motion = motion_labels(r.pos, r.quat, sc.fps)
            speed, _, _ = speeds(r.pos, r.quat, sc.fps)
            n = len(sc.objects)
            truth = TruthClip(seg=r.seg, fps=float(sc.fps), motion=motion, enters=np.zeros(n, bool),
                              leaves=np.zeros(n, bool), pos=r.pos, quat=r.quat, speed=speed, touch=r.touch,
                              intrinsics=r.intrinsics, extrinsics=r.extrinsics, engine=engine,
                              meta={"category": "moving", "tags": ["moving"],
                                    "objects": [o.to_meta() for o in sc.objects]},
                              rgb=r.rgb)
            folder = write_clip(tmp_path_factory.mktemp(engine) / "clip-00000", truth)
            flow, valid = truth_flow(folder)
            cache[engine] = folder, truth, flow, valid, sc
        return cache[engine]

    return get


@pytest.fixture(params=["mujoco", "pybullet"])
def clip(request, made):
    return made(request.param)


def test_shapes_and_background(clip):
    _, truth, flow, valid, _ = clip
    T = truth.n_frames
    assert flow.shape == (T - 1, H, W, 2) and flow.dtype == np.float32
    assert valid.shape == (T - 1, H, W) and valid.dtype == bool
    bg = truth.seg[:-1] < 0
    assert valid[bg].all() and not flow[bg].any()            # static floor: flow exactly 0
    assert not flow[~valid].any()
    assert list(truth.motion) == ["moving", "moving", "moving"]


def test_most_object_pixels_hit_their_primitive(clip):
    _, truth, _, valid, _ = clip
    obj = truth.seg[:-1] >= 0
    for k in range(truth.n_objects):
        mk = truth.seg[:-1] == k
        assert valid[mk].mean() > 0.9, f"object {k}: valid fraction {valid[mk].mean():.3f}"
    assert valid[obj].mean() > 0.97


def test_warping_next_frame_back_reproduces_frame(clip):
    # Photometric check: frame t+1 sampled at (x + u, y + v) reproduces frame t on the moving
    # object pixels (lighting is diffuse and the texture moves with the body) far better than
    # zero flow does. Errors left: bilinear sampling of a texture (TinyRenderer does not filter
    # its textures), shading that changes as a surface turns to the light, pixels that another
    # object hides in frame t+1. PyBullet's box is nearly plain (its checker barely shows), so
    # zero flow does well inside its faces: per object the flow need only do better.
    _, truth, flow, valid, _ = clip
    rgb = truth.rgb.astype(np.float32)
    gx, gy = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    errors = np.zeros((truth.n_objects, 3))          # per object: sum |warped - t|, sum |t+1 - t|, pixels
    for t in range(truth.n_frames - 1):
        mx, my = gx + flow[t, ..., 0], gy + flow[t, ..., 1]
        warped = cv2.remap(rgb[t + 1], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        moving = valid[t] & (np.hypot(flow[t, ..., 0], flow[t, ..., 1]) >= 0.5) & \
            (mx >= 0) & (mx <= W - 1) & (my >= 0) & (my <= H - 1)
        for k in range(truth.n_objects):
            m = moving & (truth.seg[t] == k)
            errors[k] += [np.abs(warped - rgb[t])[m].mean(-1).sum(), np.abs(rgb[t + 1] - rgb[t])[m].mean(-1).sum(),
                          m.sum()]
    mae = errors[:, :2] / errors[:, 2:]
    report = ", ".join(f"object {k}: {a:.2f} vs {b:.2f}" for k, (a, b) in enumerate(mae))
    assert (errors[:, 2] > 200).all(), f"moving pixels per object: {errors[:, 2]}"
    assert (mae[:, 0] < 0.8 * mae[:, 1]).all(), f"mean abs error with the flow vs zero flow: {report}"
    total = errors.sum(axis=0)
    assert total[0] < 0.5 * total[1], f"mean abs error with the flow vs zero flow: {report}"


def test_translating_sphere_mean_flow_is_centre_displacement(clip):
    # The sphere slides without turning, so every point of it moves as its centre: the mean flow
    # of its pixels is the centre's projected displacement, up to perspective (points nearer than
    # the centre move more in the image: ~ r / depth of the flow, < 0.15 px here).
    _, truth, flow, valid, _ = clip
    assert np.abs(truth.quat[:, 0] - truth.quat[0, 0]).max() < 1e-3, "the sphere turned: not a translation"
    uv, _ = project(truth.pos[:, 0], truth.intrinsics, truth.extrinsics)
    checked = 0
    for t in range(truth.n_frames - 1):
        m = (truth.seg[t] == 0) & valid[t]
        if m.sum() < 100:
            continue
        mean = flow[t][m].mean(axis=0)
        np.testing.assert_allclose(mean, uv[t + 1] - uv[t], atol=0.3, err_msg=f"frame {t}")
        checked += 1
    assert checked >= 15
    assert np.linalg.norm(uv[-1] - uv[0]) > 20                  # it did move (px)


def test_matches_mujoco_depth_flow_inside_the_masks(made):
    # MuJoCo's renderer computes flow from its depth buffer (pipeline.render.rigid_flow): a
    # different method (drawn, tessellated surface) on the same poses. Inside the masks (away
    # from their edges) both must agree to a small fraction of a pixel.
    folder, truth, flow, valid, sc = made("mujoco")
    from pipeline.render import FrameRenderer

    model = mujoco_scenes.compile_scenario(sc)
    qpos = np.concatenate([truth.pos, truth.quat], axis=-1)
    with FrameRenderer(model, W, H) as renderer:
        frames = renderer.render(qpos, rgb=False, seg=True, depth=True, flow=True)
    assert np.array_equal(frames.seg, truth.seg)
    seg = truth.seg[:-1]
    interior = seg >= 0
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            interior &= np.roll(seg, (dy, dx), axis=(1, 2)) == seg
    interior &= valid
    diff = np.linalg.norm(flow - frames.flow, axis=-1)[interior]
    mag = np.linalg.norm(frames.flow, axis=-1)[interior]
    assert np.median(mag) > 1.0
    assert np.median(diff) < 0.02 and np.percentile(diff, 99) < 0.2, \
        f"median {np.median(diff):.4f} px, p99 {np.percentile(diff, 99):.4f} px"


def test_errors_name_the_file(clip, tmp_path):
    import shutil

    folder = tmp_path / "clip"
    shutil.copytree(clip[0], folder)
    meta = json.loads((folder / "meta.json").read_text())
    meta["objects"][1]["shape"] = "cone"
    (folder / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"meta\.json: objects\[1\]\.shape: must be one of"):
        truth_flow(folder)
    meta["objects"][1]["shape"] = "box"
    del meta["objects"][1]["size"]["depth"]
    (folder / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"meta\.json: objects\[1\]\.size\.depth: must be a positive number"):
        truth_flow(folder)
    shutil.copy(clip[0] / "meta.json", folder / "meta.json")
    data = dict(np.load(folder / "truth.npz"))
    data["quat"] = data["quat"][:, :2]
    np.savez(folder / "truth.npz", **data)
    with pytest.raises(ValueError, match=r"truth\.npz: quat: must be \(T, n, 4\)"):
        truth_flow(folder)
    (folder / "truth.npz").write_bytes(b"not a zip archive")
    with pytest.raises(ValueError, match=r"truth\.npz: cannot be read"):
        truth_flow(folder)
    (folder / "truth.npz").unlink()
    with pytest.raises(FileNotFoundError, match=r"clip/truth\.npz: missing"):
        truth_flow(folder)
    with pytest.raises(FileNotFoundError, match=r"nowhere: must be a clip folder"):
        truth_flow(tmp_path / "nowhere")


def test_backward_flow_of_the_translating_sphere_points_back_to_frame_t(clip):
    # Backward flow of pair t runs from frame t+1 to frame t: the sliding sphere's pixels in frame
    # t+1 move by minus the centre's projected displacement, and the static floor by exactly 0.
    folder, truth, _, _, _ = clip
    back, valid = truth_flow(folder, backward=True)
    T = truth.n_frames
    assert back.shape == (T - 1, H, W, 2) and valid.shape == (T - 1, H, W)
    assert not back[truth.seg[1:] < 0].any()
    uv, _ = project(truth.pos[:, 0], truth.intrinsics, truth.extrinsics)
    checked = 0
    for t in range(T - 1):
        m = (truth.seg[t + 1] == 0) & valid[t]
        if m.sum() < 100:
            continue
        np.testing.assert_allclose(back[t][m].mean(axis=0), uv[t] - uv[t + 1], atol=0.3, err_msg=f"pair {t}")
        checked += 1
    assert checked >= 15
