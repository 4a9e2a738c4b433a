"""Camera model against MuJoCo's renderer (issue 4, check 6).

Conventions under test (pipeline/camera.py): pixel origin at the top-left corner, u right,
v down, pixel centres at +0.5; ``fov`` is vertical; OpenCV camera frame (x right, y down,
z forward). A small sphere rendered by MuJoCo at a 3D point must have its segmentation
centroid within 0.5 px of the project's projection of that point.
"""

import pipeline  # noqa: F401  (MUJOCO_GL before mujoco)

import numpy as np
import pytest
from numpy.testing import assert_allclose

from pipeline.camera import (camera_pose, extrinsics, intrinsics, pixel_grid, pixel_to_plane, pixel_to_surface, project,
                             unproject)
from pipeline.mjcf import SimOptions, compile_model, initial_state
from pipeline.render import FrameRenderer, camera_matrices
from pipeline.scene import Camera, Scene

W, H = 480, 320
CAMERAS = [
    {"height": 1.2, "pitch": 35.0, "fov": 45.0},
    {"height": 0.6, "pitch": 10.0, "fov": 30.0},
    {"height": 2.5, "pitch": 60.0, "fov": 70.0},
    {"height": 1.5, "pitch": 25.0, "fov": 55.0},
    {"position": [0.5, -1.8, 1.1], "yaw": 20.0, "pitch": 30.0, "roll": 10.0, "fov": 50.0},  # 6-DoF form
]


def _scene(camera, objects=None):
    objects = objects or [{"shape": "sphere", "size": {"radius": 0.05}, "mass": 1.0, "position": [0, 0, 1]}]
    return Scene.from_dict({"camera": camera, "objects": objects})


def _points_in_view(cam, rng, n=4):
    """World points at pixels chosen off the pixel grid, 1.5-3 m deep, above the floor."""
    uv = np.stack([rng.uniform(0.15, 0.85, 4 * n) * W, rng.uniform(0.15, 0.85, 4 * n) * H], -1)
    depth = rng.uniform(1.5, 3.0, 4 * n)
    pts = unproject(uv, depth, cam, W, H)
    return pts[pts[:, 2] > 0.15][:n]


@pytest.mark.parametrize("camera", CAMERAS, ids=lambda c: "-".join(f"{k}{v}" for k, v in c.items()))
def test_projection_matches_rendered_sphere_centroid(camera):
    cam = _scene(camera).camera
    pts = _points_in_view(cam, np.random.default_rng(0))
    f = intrinsics(cam.fov, W, H)[1, 1]
    depth = project(pts, cam, W, H)[1]
    radii = 8.0 * depth / f  # ~8 px radius on screen: small, yet a centroid over ~200 px
    objects = [{"shape": "sphere", "size": {"radius": float(r)}, "mass": 1.0, "position": p.tolist()}
               for p, r in zip(pts, radii)]
    scene = _scene(camera, objects)
    model = compile_model(scene, SimOptions(textured=False))
    with FrameRenderer(model, W, H) as renderer:
        renderer.set_pose(initial_state(scene)[0].reshape(-1, 7))
        seg = renderer.segmentation()
        K, R, t = camera_matrices(model, renderer.data, W, H)
    uv, _ = project(pts, scene.camera, W, H)
    centroids = []
    for k in range(len(pts)):
        v, u = np.nonzero(seg == k)
        assert len(u) > 100, f"sphere {k} not visible"
        centroids.append([u.mean() + 0.5, v.mean() + 0.5])  # pixel centres at +0.5
    # tolerance: 0.5 px (issue 4); perspective shifts a sphere's silhouette centroid by
    # ~f tan(a) (r / d)^2 < 0.1 px here
    assert_allclose(np.asarray(centroids), uv, rtol=0, atol=0.5)
    # the renderer's camera (read back from MuJoCo) equals the scene camera's model
    R_s, t_s = extrinsics(scene.camera)
    assert_allclose(K, intrinsics(scene.camera.fov, W, H), atol=1e-9)
    assert_allclose(R, R_s, atol=1e-6)
    assert_allclose(t, t_s, atol=1e-6)


def test_conventions():
    cam = _scene({"height": 1.0, "pitch": 30.0, "fov": 40.0}).camera
    pose = camera_pose(cam)
    # a point on the optical axis lands on the image centre (principal point W/2, H/2)
    uv, d = project(pose.eye + 2.0 * pose.forward, cam, W, H)
    assert_allclose(uv, [W / 2, H / 2], atol=1e-9)
    assert_allclose(d, 2.0, atol=1e-12)
    # u grows to the right, v grows downwards
    assert project(pose.eye + 2 * pose.forward + 0.1 * pose.right, cam, W, H)[0][0] > W / 2
    assert project(pose.eye + 2 * pose.forward + 0.1 * pose.up, cam, W, H)[0][1] < H / 2
    # fov is vertical: a ray at fov/2 above the axis reaches the top edge v = 0
    a = np.deg2rad(cam.fov / 2)
    assert_allclose(project(pose.eye + np.cos(a) * pose.forward + np.sin(a) * pose.up, cam, W, H)[0][1], 0.0, atol=1e-9)
    # paper camera: eye (0, -2, height), no roll: world +x is image right
    assert_allclose(pose.eye, [0, -2, 1.0])
    assert_allclose(pose.right, [1, 0, 0], atol=1e-12)
    # unproject inverts project at every pixel centre
    grid = pixel_grid(W, H)
    pts = unproject(grid, np.full((H, W), 2.5), cam, W, H)
    assert_allclose(project(pts, cam, W, H)[0], grid, atol=1e-9)


def test_pixel_to_surface_meets_a_tilted_plane_where_the_pixel_looks_and_agrees_with_pixel_to_plane():
    """A pixel's viewing ray met with a ramp's plane (any normal) gives a point on that plane which
    projects back to the pixel; with a vertical normal it is pixel_to_plane's point."""
    cam = Camera(height=0.6, pitch=40.0, fov=45.0)
    uv = np.array([[40.0, 150.0], [160.0, 120.0], [300.0, 200.0]])
    flat = pixel_to_surface(uv, np.array([0.0, 0.0, 0.03]), np.array([0.0, 0.0, 2.0]), cam, 320, 240)
    assert np.allclose(flat, pixel_to_plane(uv, 0.03, cam, 320, 240))
    th = np.radians(12.0)
    normal = np.array([np.sin(th), 0.0, np.cos(th)])
    point = np.array([0.2, -1.2, 0.05])
    p = pixel_to_surface(uv, point, normal, cam, 320, 240)
    assert np.allclose((p - point) @ normal, 0.0, atol=1e-9)
    back, _ = project(p, cam, 320, 240)
    assert np.allclose(back, uv, atol=1e-6)
    # a ray parallel to the plane, or meeting it behind the camera, gives NaN
    behind = pixel_to_surface(uv[:1], np.asarray(cam.eye) + [0.0, 0.0, 1.0], np.array([0.0, 0.0, 1.0]), cam, 320, 240)
    assert np.isnan(behind).all()
