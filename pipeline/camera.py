"""Camera model: intrinsics, extrinsics and projection (docs/design.md §2, §3).

Conventions (checked against MuJoCo renders in tests/test_camera.py):

* Pixels: origin at the top-left corner of the image, u to the right, v down; the centre of
  pixel (column i, row j) is at (i + 0.5, j + 0.5). Square pixels.
* ``fov`` is the vertical field of view in degrees, as MuJoCo's ``fovy``:
  ``fy = fx = (H / 2) / tan(fov / 2)``, principal point ``(W / 2, H / 2)``.
* Extrinsics use the OpenCV camera frame (x right, y down, z forward):
  ``X_cam = R @ X_world + t``. MuJoCo's camera frame is (x right, y up, -z forward); the
  MJCF camera is placed with ``xyaxes = (right, up)``.
* Paper camera: eye (0, -2, height), looking along +y, pitched ``pitch`` degrees below the
  horizon. 6-DoF form: the same, then ``roll`` about the optical axis and ``yaw`` about world
  z (counter-clockwise seen from above, 0 = looking along +y), eye at ``position``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.scene import Camera


@dataclass(frozen=True)
class CameraPose:
    """World-frame camera axes (unit vectors) and centre, m."""

    eye: np.ndarray      # (3,) float64
    right: np.ndarray    # (3,) image +u direction
    up: np.ndarray       # (3,) image -v direction
    forward: np.ndarray  # (3,) optical axis


def camera_pose(cam: Camera) -> CameraPose:
    """Axes of a scene-language camera in the world frame (see module docstring)."""
    p = np.deg2rad(cam.pitch)
    yaw = np.deg2rad(cam.yaw or 0.0)
    roll = np.deg2rad(cam.roll or 0.0)
    f = np.array([0.0, np.cos(p), -np.sin(p)])
    u = np.array([0.0, np.sin(p), np.cos(p)])
    r = np.array([1.0, 0.0, 0.0])
    # roll about the optical axis (positive = image turns counter-clockwise)
    r, u = np.cos(roll) * r + np.sin(roll) * u, -np.sin(roll) * r + np.cos(roll) * u
    rz = np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    return CameraPose(np.asarray(cam.eye, dtype=np.float64), rz @ r, rz @ u, rz @ f)


def intrinsics(fov: float, width: int, height: int) -> np.ndarray:
    """Pinhole intrinsics K (3, 3) float64 for a vertical field of view ``fov`` (deg)."""
    fy = 0.5 * height / np.tan(np.deg2rad(fov) / 2.0)
    return np.array([[fy, 0.0, width / 2.0], [0.0, fy, height / 2.0], [0.0, 0.0, 1.0]])


def extrinsics(cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera rotation R (3, 3) and translation t (3,) (OpenCV frame, m)."""
    pose = camera_pose(cam)
    R = np.stack([pose.right, -pose.up, pose.forward])
    return R, -R @ pose.eye


def project(points: np.ndarray, cam: Camera, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Project world points to pixels.

    Args:
        points: (..., 3) float, world frame, m.
    Returns:
        uv: (..., 2) float64 pixel coordinates (convention above).
        depth: (...,) float64 distance along the optical axis, m (<= 0: behind the camera).
    """
    R, t = extrinsics(cam)
    K = intrinsics(cam.fov, width, height)
    xc = np.asarray(points, dtype=np.float64) @ R.T + t
    z = xc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([K[0, 0] * xc[..., 0] / z + K[0, 2], K[1, 1] * xc[..., 1] / z + K[1, 2]], axis=-1)
    return uv, z


def unproject(uv: np.ndarray, depth: np.ndarray, cam: Camera, width: int, height: int) -> np.ndarray:
    """Inverse of :func:`project`: pixels (..., 2) with depth along the optical axis (...,) m
    -> world points (..., 3) m."""
    R, t = extrinsics(cam)
    K = intrinsics(cam.fov, width, height)
    x = (uv[..., 0] - K[0, 2]) / K[0, 0] * depth
    y = (uv[..., 1] - K[1, 2]) / K[1, 1] * depth
    xc = np.stack([x, y, depth], axis=-1)
    return (xc - t) @ R  # R^T (xc - t)


def pixel_grid(width: int, height: int) -> np.ndarray:
    """Pixel centres (H, W, 2) float64 in the convention above."""
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    return np.stack([u, v], axis=-1)


def pixel_to_surface(uv: np.ndarray, point: np.ndarray, normal: np.ndarray, cam: Camera, width: int,
                     height: int) -> np.ndarray:
    """World points seen at pixels ``uv (..., 2)`` on the plane through ``point (3,)`` m with
    normal ``normal (3,)`` (any length): each pixel's viewing ray met with the plane (a tilted
    ramp; :func:`pixel_to_plane` is the horizontal case).

    Returns:
        (..., 3) float64 world points, m; NaN where the ray is parallel to the plane or meets it
        behind the camera.
    """
    uv = np.asarray(uv, dtype=np.float64)
    eye = np.asarray(cam.eye, dtype=np.float64)
    n = np.asarray(normal, dtype=np.float64)
    ray = unproject(uv, np.ones(uv.shape[:-1]), cam, width, height) - eye
    dn = ray @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        s = ((np.asarray(point, dtype=np.float64) - eye) @ n) / dn
    s = np.where(np.abs(dn) > 1e-9, s, np.nan)
    s = np.where(s > 0, s, np.nan)
    return eye + s[..., None] * ray


def pixel_to_plane(uv: np.ndarray, z: float, cam: Camera, width: int, height: int) -> np.ndarray:
    """World points at height ``z`` (m) seen at pixels ``uv (..., 2)``: the intersection of
    each pixel's viewing ray with the horizontal plane ``Z = z``.

    Returns:
        (..., 3) float64 world points, m; NaN where the ray is parallel to the plane or meets
        it behind the camera (e.g. above the horizon for a plane below the camera).
    """
    return pixel_to_surface(uv, np.array([0.0, 0.0, z]), np.array([0.0, 0.0, 1.0]), cam, width, height)
