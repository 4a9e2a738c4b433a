"""Ground-truth optical flow (issue 4, check 7).

Warping the foreground of frame t by the ground-truth flow must reproduce the foreground of
frame t+1 (mask IoU >= 0.95, every frame) for a translating and for a spinning object, and
the flow of the static floor is exactly 0.

Rendered at the paper's 480x320 with objects of ~5 % of the frame (the paper's size
filter): the IoU of a warped mask is limited by its boundary pixels (about perimeter / area)
and by surfaces that a rotation uncovers between frames, which no forward warp can show.
Forward warp: every foreground pixel centre of frame t moves by its flow and is splatted
bilinearly; a pixel of t+1 is covered when it receives a weight >= 0.5.
"""

import pipeline  # noqa: F401  (MUJOCO_GL before mujoco)

import numpy as np
import pytest
from scipy.ndimage import binary_dilation

from pipeline.render import render_scene
from pipeline.scene import Scene

W, H = 480, 320
CAMERA = {"height": 1.2, "pitch": 30.0, "fov": 50.0}
CASES = {
    # box translating through the air (no gravity), seen in perspective
    "translating_box": (0.0, {"shape": "box", "size": {"width": 0.6, "depth": 0.4, "height": 0.4}, "mass": 1.0,
                              "position": [-0.5, 0.3, 0.5], "linear_velocity": [1.5, 0.5, 0.5],
                              "material": {"sliding_friction": 0.0}}),
    # box spinning about the vertical on a frictionless floor, gravity on
    "spinning_box": (9.81, {"shape": "box", "size": {"width": 0.8, "depth": 0.4, "height": 0.3}, "mass": 1.0,
                            "position": [0.0, 0.3, 0.15], "angular_velocity": [0.0, 0.0, 3.0],
                            "material": {"sliding_friction": 0.0}}),
    # cylinder tumbling about a tilted axis in the air
    "tumbling_cylinder": (0.0, {"shape": "cylinder", "size": {"radius": 0.25, "height": 0.6}, "mass": 1.0,
                                "position": [0.0, 0.3, 0.5], "angular_velocity": [2.0, 1.0, 1.5],
                                "material": {"sliding_friction": 0.0}}),
}


def warp_foreground(seg: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """Forward-warp the foreground mask of one frame by its flow (bilinear splat, >= 0.5)."""
    v, u = np.nonzero(seg >= 0)
    x, y = u + flow[v, u, 0], v + flow[v, u, 1]  # pixel centres at +0.5 on both sides cancel
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    acc = np.zeros(seg.shape)
    for dx, dy, w in [(0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)]:
        xi, yi = x0 + dx, y0 + dy
        ok = (xi >= 0) & (xi < seg.shape[1]) & (yi >= 0) & (yi < seg.shape[0])
        np.add.at(acc, (yi[ok], xi[ok]), w[ok])
    return acc >= 0.5


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


@pytest.fixture(scope="module", params=list(CASES))
def clip(request):
    gravity, obj = CASES[request.param]
    scene = Scene.from_dict({"duration": 0.5, "gravity": gravity, "camera": CAMERA, "objects": [obj]})
    trace, frames = render_scene(scene, W, H)
    return request.param, trace, frames


def test_warped_foreground_matches_next_frame(clip):
    name, trace, frames = clip
    fg = frames.seg >= 0
    assert fg[0].mean() > 0.04, "object should cover ~5 % of the frame"
    ious = [iou(warp_foreground(frames.seg[k], frames.flow[k]), fg[k + 1]) for k in range(len(frames.flow))]
    assert np.abs(frames.flow[fg[:-1]]).max() > 0.5, "the object must move"
    assert min(ious) >= 0.95, f"{name}: per-frame IoU {np.round(ious, 3).tolist()}"


def test_floor_depth_lies_on_the_floor_and_static_pixels_do_not_change(clip):
    """The floor's flow is 0 by construction (it is no body), so check what the flow rests on:
    the rendered depth of the floor's pixels, back-projected with the *scene* camera model
    (pipeline.camera, not the renderer's MuJoCo camera), lies on the plane z = 0; and the
    camera is static, so floor pixels away from objects keep their colour."""
    from pipeline.camera import pixel_grid, unproject

    name, _, frames = clip
    scene = Scene.from_dict({"duration": 0.5, "gravity": CASES[name][0], "camera": CAMERA, "objects": [CASES[name][1]]})
    floor0 = (frames.seg[0] < 0) & np.isfinite(frames.depth[0]) & (frames.depth[0] < 20.0)
    assert floor0.mean() > 0.5
    world = unproject(pixel_grid(W, H)[floor0], frames.depth[0][floor0].astype(np.float64), scene.camera, W, H)
    # float16/32 depth over 1-5 m: < 2 mm; a wrong fov, pitch, pixel-centre or depth convention is cm off
    np.testing.assert_allclose(world[:, 2], 0.0, atol=2e-3)
    # the camera is static: the floor's pixels are identical wherever no object is in either
    # frame, away from the 2 px band that anti-aliasing blends with object edges
    near = binary_dilation(frames.seg >= 0, structure=np.ones((1, 5, 5), bool))
    floor = ~near[:-1] & ~near[1:]
    assert floor.mean() > 0.5
    assert np.array_equal(frames.rgb[:-1][floor], frames.rgb[1:][floor])


def test_translating_box_flow_equals_the_scene_camera_projection():
    """Known answer for a pure translation: flow = project(X + dp) - uv with X back-projected from
    the rendered depth and dp the body's displacement between frames, computed with the scene
    camera model (pipeline.camera) instead of the renderer's MuJoCo camera matrices."""
    from pipeline.camera import pixel_grid, project, unproject

    gravity, obj = CASES["translating_box"]
    scene = Scene.from_dict({"duration": 0.2, "gravity": gravity, "camera": CAMERA, "objects": [obj]})
    trace, frames = render_scene(scene, W, H)
    grid = pixel_grid(W, H)
    for k in range(len(frames.flow)):
        on = frames.seg[k] == 0
        dp = trace.qpos[k + 1, 0, :3] - trace.qpos[k, 0, :3]
        assert np.linalg.norm(dp) > 0.03   # the box moves several px per frame
        X = unproject(grid[on], frames.depth[k][on].astype(np.float64), scene.camera, W, H)
        uv1, _ = project(X + dp, scene.camera, W, H)
        np.testing.assert_allclose(frames.flow[k][on], uv1 - grid[on], atol=0.02)
