"""Shape geometry of the scene primitives (sphere, cylinder, box): the project's one home.

Size conventions (scene language v1, :mod:`pipeline.scene`): a ``size`` maps ``radius`` (sphere),
``radius, height`` (cylinder, axis = body z, full height) or ``width, depth, height`` (box, full
extents along body x, y, z), all in m. MuJoCo's geom ``size`` is in half extents
(:func:`geom_size`; MuJoCo docs, "geom/size").

Every function takes ``shape`` (one of :data:`pipeline.scene.SHAPES`) and ``size``, either a
mapping with the keys above or the scene's size model (``obj.size``), and works for objects of
uniform density as MuJoCo's compiler treats them (MuJoCo docs, "compiler/inertiafromgeom").
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import mujoco
import numpy as np

__all__ = ["geom_size", "half_extents", "extents", "principal_inertia", "min_inertia", "bounding_radius",
           "support_height", "volume", "smallest_half_extent"]


def _dims(size: Any) -> Mapping[str, float]:
    """``size`` as a mapping (a scene size model is dumped)."""
    return size if isinstance(size, Mapping) else size.model_dump()


def _check_shape(shape: str) -> None:
    if shape not in ("sphere", "cylinder", "box"):
        raise ValueError(f"shape: must be one of sphere, cylinder, box, got {shape!r}")


def geom_size(shape: str, size: Any) -> list[float]:
    """MuJoCo geom ``size`` (half extents) of a primitive, m: sphere ``[r]``, cylinder
    ``[r, h / 2]``, box ``[w / 2, d / 2, h / 2]`` (MuJoCo docs, "geom/size").

    Raises:
        ValueError: unknown shape.
    """
    _check_shape(shape)
    s = _dims(size)
    if shape == "sphere":
        return [s["radius"]]
    if shape == "cylinder":
        return [s["radius"], s["height"] / 2.0]
    return [s["width"] / 2.0, s["depth"] / 2.0, s["height"] / 2.0]


def half_extents(shape: str, size: Any) -> np.ndarray:
    """Axis-aligned half extents ``(3,)`` float64 of a primitive in its body frame, m (what
    MuJoCo stores in ``geom_aabb``): sphere ``(r, r, r)``, cylinder ``(r, r, h / 2)``, box
    ``(w / 2, d / 2, h / 2)``.

    Raises:
        ValueError: unknown shape.
    """
    g = geom_size(shape, size)
    if shape == "sphere":
        return np.full(3, g[0])
    if shape == "cylinder":
        return np.array([g[0], g[0], g[1]])
    return np.asarray(g, dtype=np.float64)


def extents(shape: str, size: Any) -> np.ndarray:
    """Full extents ``(3,)`` float64 of a primitive along its body x, y, z axes, m (twice
    :func:`half_extents`)."""
    return 2.0 * half_extents(shape, size)


def principal_inertia(shape: str, size: Any, mass: float) -> np.ndarray:
    """Principal moments of inertia ``(3,)`` float64 of a solid primitive about its body axes,
    kg m^2 (what MuJoCo stores in ``body_inertia`` for a body of one geom).

    Uniform-density solids (MuJoCo compiler, "inertia from geoms"; any mechanics text): sphere
    ``2/5 m r^2``; cylinder ``m (3 r^2 + h^2) / 12`` (x, y) and ``m r^2 / 2`` (z); box of full
    extents (w, d, h): ``m (d^2 + h^2) / 12``, ``m (w^2 + h^2) / 12``, ``m (w^2 + d^2) / 12``.

    Args:
        shape, size: the primitive (module docstring).
        mass: kg.
    Raises:
        ValueError: unknown shape.
    """
    _check_shape(shape)
    m, s = mass, _dims(size)
    if shape == "sphere":
        return np.full(3, 0.4 * m * s["radius"] ** 2)
    if shape == "cylinder":
        ixx = m * (3.0 * s["radius"] ** 2 + s["height"] ** 2) / 12.0
        return np.array([ixx, ixx, 0.5 * m * s["radius"] ** 2])
    w, d, h = s["width"], s["depth"], s["height"]
    return m / 12.0 * np.array([d * d + h * h, w * w + h * h, w * w + d * d])


def min_inertia(shape: str, size: Any, mass: float) -> float:
    """Smallest principal moment of inertia of a solid primitive, kg m^2 (the minimum of
    :func:`principal_inertia`)."""
    return float(principal_inertia(shape, size, mass).min())


def bounding_radius(shape: str, size: Any) -> float:
    """Radius of the smallest sphere about the centre that contains the primitive, m (what
    MuJoCo stores in ``geom_rbound``): sphere ``r``, cylinder ``hypot(r, h / 2)``, box
    ``|(w, d, h)| / 2``.

    Raises:
        ValueError: unknown shape.
    """
    _check_shape(shape)
    s = _dims(size)
    if shape == "sphere":
        return s["radius"]
    if shape == "cylinder":
        return math.hypot(s["radius"], s["height"] / 2)
    return 0.5 * math.sqrt(s["width"] ** 2 + s["depth"] ** 2 + s["height"] ** 2)


def support_height(shape: str, size: Any, R: np.ndarray) -> np.ndarray:
    """Height of the centre above the lowest point of the rotated primitive, m: the centre's
    height when it rests on the plane z = 0.

    With ``a = R[2, :]`` (world z in body axes) and half extents ``e``: sphere ``r``; box
    ``|a| . e``; cylinder ``r sqrt(1 - a_z^2) + (h / 2) |a_z|`` (the rim's lowest point plus
    the axis's drop; the support function of a cylinder).

    Args:
        shape, size: the primitive (module docstring).
        R: ``(..., 3, 3)`` rotation matrices, body to world.
    Returns:
        ``(...)`` float64, m.
    Raises:
        ValueError: unknown shape.
    """
    R = np.asarray(R, dtype=np.float64)
    half = half_extents(shape, size)
    if shape == "sphere":
        return np.full(R.shape[:-2], half[0])
    if shape == "box":
        return np.abs(R[..., 2, :]) @ half
    c = np.abs(R[..., 2, 2])  # cylinder axis = body z
    return half[0] * np.sqrt(np.maximum(0.0, 1.0 - c ** 2)) + c * half[2]


def volume(shape: str, size: Any) -> float:
    """Volume of a primitive, m^3: sphere ``4/3 pi r^3``, cylinder ``pi r^2 h``, box ``w d h``.

    Raises:
        ValueError: unknown shape.
    """
    _check_shape(shape)
    s = _dims(size)
    if shape == "sphere":
        return 4.0 / 3.0 * math.pi * s["radius"] ** 3
    if shape == "cylinder":
        return math.pi * s["radius"] ** 2 * s["height"]
    return s["width"] * s["depth"] * s["height"]


_USED_SIZES = {int(mujoco.mjtGeom.mjGEOM_SPHERE): 1, int(mujoco.mjtGeom.mjGEOM_CAPSULE): 2,
               int(mujoco.mjtGeom.mjGEOM_CYLINDER): 2, int(mujoco.mjtGeom.mjGEOM_BOX): 3,
               int(mujoco.mjtGeom.mjGEOM_ELLIPSOID): 3}
"""Number of ``geom_size`` entries each geom type uses (MuJoCo docs, "geom/size")."""


def smallest_half_extent(model: mujoco.MjModel) -> float:
    """Smallest half extent of any geom of a compiled model but planes and meshes, m (the
    ``geom_size`` entries used by the geom type); ``inf`` if there is none."""
    sizes = [model.geom_size[g, :_USED_SIZES[int(t)]].min() for g, t in enumerate(model.geom_type)
             if int(t) in _USED_SIZES]
    return float(min(sizes)) if sizes else float("inf")
