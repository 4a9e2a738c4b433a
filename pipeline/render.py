"""Offscreen rendering: RGB, segmentation, depth and exact ground-truth optical flow.

Rendering uses ``mujoco.Renderer`` with ``MUJOCO_GL=egl`` (set in ``pipeline/__init__``).
Create one :class:`FrameRenderer` per compiled model and reuse it (creating a renderer costs
80-150 ms); close it explicitly (or use ``with``) or EGL errors print at exit.

Ground-truth flow (DESIGN §3): for a pixel of object k at frame t with depth d, the world
point ``X = unproject(uv, d)`` moves rigidly with body k, ``X' = R_{t+1} R_t^T (X - p_t) +
p_{t+1}``, and the flow is ``project(X') - uv`` (pixels, forward, (u, v) = (x, y)). The floor
and background are static (flow 0) because the camera is fixed.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

import pipeline  # noqa: F401  (MUJOCO_GL)

BACKGROUND = -1
"""Segmentation label of the floor and background."""


@dataclass
class Frames:
    """Rendered clip. Any field may be None when not requested.

    Attributes:
        rgb: (T, H, W, 3) uint8.
        seg: (T, H, W) int8 object index, -1 = floor/background.
        depth: (T, H, W) float32 distance along the optical axis, m.
        flow: (T-1, H, W, 2) float32 ground-truth forward flow, px.
    """

    rgb: np.ndarray | None = None
    seg: np.ndarray | None = None
    depth: np.ndarray | None = None
    flow: np.ndarray | None = None

    def visible_pixels(self, n_objects: int | None = None) -> np.ndarray:
        """(T, n) int64 pixel count per object per frame (from ``seg``).

        Args:
            n_objects: number of objects n; without it n is inferred from the labels seen,
                which drops trailing objects that are never visible.
        """
        if self.seg is None:
            raise ValueError("segmentation was not rendered")
        n = int(self.seg.max()) + 1 if self.seg.size else 0
        n = n if n_objects is None else n_objects
        return np.stack([(self.seg == k).sum(axis=(1, 2)) for k in range(max(n, 0))], axis=-1) if n else \
            np.zeros((self.seg.shape[0], 0), dtype=np.int64)


def camera_matrices(model: mujoco.MjModel, data: mujoco.MjData, width: int, height: int,
                    camera: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Intrinsics K (3, 3) and OpenCV-frame extrinsics R (3, 3), t (3,) of an MJCF camera.

    Read from ``data.cam_xpos`` / ``data.cam_xmat`` (call ``mj_kinematics`` + ``mj_camlight``
    first) and ``model.cam_fovy``; conventions as in ``pipeline.camera``.
    """
    fy = 0.5 * height / np.tan(np.deg2rad(model.cam_fovy[camera]) / 2.0)
    K = np.array([[fy, 0.0, width / 2.0], [0.0, fy, height / 2.0], [0.0, 0.0, 1.0]])
    axes = data.cam_xmat[camera].reshape(3, 3)  # columns: x right, y up, z backward (world)
    R = np.stack([axes[:, 0], -axes[:, 1], -axes[:, 2]])
    return K, R, -R @ data.cam_xpos[camera]


def quat_to_mat(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from unit quaternions (..., 4) w, x, y, z."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def rigid_flow(seg: np.ndarray, depth: np.ndarray, qpos0: np.ndarray, qpos1: np.ndarray,
               K: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Exact forward flow of rigid bodies between two frames seen by a static camera.

    Args:
        seg: (H, W) int object index at frame t (-1 = static background).
        depth: (H, W) float depth along the optical axis at frame t, m.
        qpos0, qpos1: (n, 7) float body poses (x, y, z, qw, qx, qy, qz) at t and t+1.
        K, R, t: camera intrinsics and world-to-camera extrinsics (OpenCV frame).
    Returns:
        (H, W, 2) float32 flow in pixels; 0 on the background.
    """
    H, W = seg.shape
    flow = np.zeros((H, W, 2), dtype=np.float32)
    fg = seg >= 0
    if not fg.any():
        return flow
    v, u = np.nonzero(fg)
    uv = np.stack([u + 0.5, v + 0.5], -1)
    d = depth[v, u].astype(np.float64)
    xc = np.stack([(uv[:, 0] - K[0, 2]) / K[0, 0] * d, (uv[:, 1] - K[1, 2]) / K[1, 1] * d, d], -1)
    X = (xc - t) @ R
    k = seg[v, u].astype(np.int64)
    R0, R1 = quat_to_mat(qpos0[:, 3:]), quat_to_mat(qpos1[:, 3:])
    local = np.einsum("nji,nj->ni", R0[k], X - qpos0[k, :3])
    X1 = np.einsum("nij,nj->ni", R1[k], local) + qpos1[k, :3]
    xc1 = X1 @ R.T + t
    uv1 = np.stack([K[0, 0] * xc1[:, 0] / xc1[:, 2] + K[0, 2], K[1, 1] * xc1[:, 1] / xc1[:, 2] + K[1, 2]], -1)
    flow[v, u] = (uv1 - uv).astype(np.float32)
    return flow


class FrameRenderer:
    """Renders frames of one compiled model from its camera ``main``.

    Args:
        model: compiled scene model (objects are bodies 1..n, one geom each).
        width, height: image size, px (at most the model's offscreen buffer).
    """

    def __init__(self, model: mujoco.MjModel, width: int, height: int):
        self.model = model
        self.width, self.height = width, height
        self.data = mujoco.MjData(model)
        self._renderer = mujoco.Renderer(model, height=height, width=width)
        # geom id -> object index (-1 for the floor / world geoms)
        self.geom_object = np.full(model.ngeom, BACKGROUND, dtype=np.int16)
        for g in range(model.ngeom):
            b = model.geom_bodyid[g]
            if b > 0:
                self.geom_object[g] = b - 1
        self.n_objects = model.nbody - 1

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __enter__(self) -> "FrameRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def set_pose(self, qpos: np.ndarray) -> None:
        """Place the objects at ``qpos (n, 7)`` and update kinematics and the camera."""
        self.data.qpos[: 7 * self.n_objects] = np.asarray(qpos, dtype=np.float64).reshape(-1)
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)  # mj_kinematics alone does not move cameras

    def _render(self, kind: str) -> np.ndarray:
        r = self._renderer
        if kind == "seg":
            r.enable_segmentation_rendering()
        elif kind == "depth":
            r.enable_depth_rendering()
        r.update_scene(self.data, camera="main")
        out = r.render()
        if kind == "seg":
            r.disable_segmentation_rendering()
        elif kind == "depth":
            r.disable_depth_rendering()
        return out

    def segmentation(self) -> np.ndarray:
        """(H, W) int8 object index of the current pose (-1 background)."""
        ids = self._render("seg")
        geom = ids[..., 0]
        is_geom = (ids[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)) & (geom >= 0)
        seg = np.full(geom.shape, BACKGROUND, dtype=np.int8)
        seg[is_geom] = self.geom_object[geom[is_geom]]
        return seg

    def render(self, qpos: np.ndarray, rgb: bool = True, seg: bool = True, depth: bool = True,
               flow: bool = True, progress: bool = False) -> Frames:
        """Render a pose sequence.

        Args:
            qpos: (T, n, 7) float body poses per frame (``Trace.qpos``).
            rgb, seg, depth, flow: which outputs to produce (flow needs seg and depth, which
                are then rendered even if not returned).
        Returns:
            :class:`Frames`.
        """
        qpos = np.asarray(qpos, dtype=np.float64)
        T = qpos.shape[0]
        need_seg, need_depth = seg or flow, depth or flow
        out = {k: [] for k in ("rgb", "seg", "depth")}
        K = R = t = None
        for k in range(T):
            self.set_pose(qpos[k])
            if k == 0 and flow:
                K, R, t = camera_matrices(self.model, self.data, self.width, self.height)
            if rgb:
                out["rgb"].append(self._render("rgb").copy())
            if need_seg:
                out["seg"].append(self.segmentation())
            if need_depth:
                out["depth"].append(self._render("depth").astype(np.float32))
        frames = Frames(
            rgb=np.stack(out["rgb"]) if rgb else None,
            seg=np.stack(out["seg"]) if need_seg else None,
            depth=np.stack(out["depth"]) if need_depth else None,
        )
        if flow:
            frames.flow = np.stack([
                rigid_flow(frames.seg[k], frames.depth[k], qpos[k], qpos[k + 1], K, R, t) for k in range(T - 1)
            ]) if T > 1 else np.zeros((0, self.height, self.width, 2), np.float32)
        if not seg:
            frames.seg = None
        if not depth:
            frames.depth = None
        return frames


def render_scene(scene, width: int, height: int, options=None, **kwargs) -> tuple["Trace", Frames]:
    """Simulate and render a scene in one call (convenience for tests and the CLI).

    Returns:
        (trace, frames): the :class:`pipeline.simulate.Trace` and rendered :class:`Frames`.
    """
    from pipeline.simulate import simulate

    model, trace = simulate(scene, options)
    with FrameRenderer(model, width, height) as r:
        return trace, r.render(trace.qpos, **kwargs)
