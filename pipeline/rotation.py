"""Quaternions and rotations: the project's one implementation (scipy's ``Rotation``).

Convention everywhere in this project (scene language, MJCF, traces): unit quaternions are
``(w, x, y, z)``, scalar first, as MuJoCo stores them (MuJoCo docs, "Clarifications:
quaternions"); rotation vectors are axis * angle in rad; matrices ``R`` map body-frame vectors
to the world frame (columns are the body axes in world coordinates). Every function takes
arrays with any leading batch shape ``(...)`` and returns float64.

All conversions go through :class:`scipy.spatial.transform.Rotation` with
``scalar_first=True`` (scipy >= 1.14); input quaternions are normalised by scipy, as MuJoCo
normalises them on load.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["as_rotation", "quat_mul", "quat_conj", "quat_to_mat", "quat_to_rotvec", "rotvec_to_quat",
           "axis_angle_quat", "yaw_quat", "quat_angle"]


def _batch(q: np.ndarray | Sequence[float], width: int) -> tuple[np.ndarray, tuple[int, ...]]:
    a = np.asarray(q, dtype=np.float64)
    if a.shape[-1:] != (width,):
        raise ValueError(f"expected an array (..., {width}), got shape {a.shape}")
    return a.reshape(-1, width), a.shape[:-1]


def as_rotation(q: np.ndarray | Sequence[float]) -> Rotation:
    """A scipy ``Rotation`` (stacked when batched) of quaternions ``(..., 4)`` (w, x, y, z).

    Raises:
        ValueError: the last axis is not 4 long, or a quaternion has zero norm (scipy).
    """
    flat, _ = _batch(q, 4)
    return Rotation.from_quat(flat, scalar_first=True)


def quat_mul(a: np.ndarray | Sequence[float], b: np.ndarray | Sequence[float]) -> np.ndarray:
    """Hamilton product ``a * b`` of quaternions ``(..., 4)`` (w, x, y, z): rotate by ``b``,
    then by ``a`` (MuJoCo ``mju_mulQuat``). Shapes broadcast; returns ``(..., 4)`` float64.
    The result is not sign-canonicalised (scipy keeps the product's sign)."""
    a_arr, b_arr = np.broadcast_arrays(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    shape = a_arr.shape[:-1]
    out = (as_rotation(a_arr) * as_rotation(b_arr)).as_quat(scalar_first=True)
    return out.reshape(*shape, 4)


def quat_conj(q: np.ndarray | Sequence[float]) -> np.ndarray:
    """Conjugate (= inverse for unit quaternions) ``(..., 4)`` (w, x, y, z)."""
    return np.asarray(q, dtype=np.float64) * np.array([1.0, -1.0, -1.0, -1.0])


def quat_to_mat(q: np.ndarray | Sequence[float]) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of quaternions ``(..., 4)`` (w, x, y, z), normalised
    first (as MuJoCo does on load)."""
    flat, shape = _batch(q, 4)
    return Rotation.from_quat(flat, scalar_first=True).as_matrix().reshape(*shape, 3, 3)


def quat_to_rotvec(q: np.ndarray | Sequence[float]) -> np.ndarray:
    """Rotation vectors ``(..., 3)`` (rad, shortest arc: angle in [0, pi]) of quaternions
    ``(..., 4)`` (w, x, y, z); the quaternion logarithm times two."""
    flat, shape = _batch(q, 4)
    return Rotation.from_quat(flat, scalar_first=True).as_rotvec().reshape(*shape, 3)


def rotvec_to_quat(r: np.ndarray | Sequence[float]) -> np.ndarray:
    """Unit quaternions ``(..., 4)`` (w, x, y, z; w >= 0 for angles <= pi) of rotation vectors
    ``(..., 3)`` (rad); the quaternion exponential of ``r / 2``."""
    flat, shape = _batch(r, 3)
    return Rotation.from_rotvec(flat).as_quat(scalar_first=True).reshape(*shape, 4)


def axis_angle_quat(axis: Sequence[float], angle: float) -> np.ndarray:
    """Unit quaternion ``(4,)`` (w, x, y, z) of a rotation by ``angle`` (rad) about ``axis``
    (normalised here).

    Raises:
        ValueError: ``axis`` has zero length.
    """
    a = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(a)
    if not n > 0:
        raise ValueError(f"axis must have non-zero length, got {a.tolist()}")
    return rotvec_to_quat(a / n * float(angle))


def yaw_quat(yaw: float) -> np.ndarray:
    """Unit quaternion ``(4,)`` (w, x, y, z) of a rotation by ``yaw`` (rad) about world z."""
    return axis_angle_quat((0.0, 0.0, 1.0), yaw)


def quat_angle(q1: np.ndarray | Sequence[float], q2: np.ndarray | Sequence[float]) -> np.ndarray:
    """Geodesic angle (rad, in [0, pi]) between orientations ``(..., 4)`` (w, x, y, z);
    ``q`` and ``-q`` are the same orientation (angle 0)."""
    a_arr, b_arr = np.broadcast_arrays(np.asarray(q1, dtype=np.float64), np.asarray(q2, dtype=np.float64))
    shape = a_arr.shape[:-1]
    return (as_rotation(a_arr).inv() * as_rotation(b_arr)).magnitude().reshape(shape)
