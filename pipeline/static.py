"""Static geometry helpers: build a ramp, find the surface an object rests on.

Scene language (``pipeline.scene``): ``static:`` holds fixed boxes and planes
(:class:`~pipeline.scene.StaticBox`, :class:`~pipeline.scene.StaticPlane`) compiled as world
geoms ``static_<index>`` (``pipeline.mjcf``). This module turns a few intuitive numbers into
such a geom (:func:`ramp`) and answers where the top surface of one is (:func:`support_height`,
:func:`support_normal`), which is what placing an object on it needs.

Units: m, degrees for the angles given to :func:`ramp`. World frame: z up, floor z = 0.

Example (a ball at rest on a 20 degree ramp that descends along +x)::

    r = ramp(20, length=1.0, width=0.4, thickness=0.03, x=0.0, y=0.3)
    z = support_height(r, -0.3, 0.3)                 # top surface height there, m
    n = support_normal(r, -0.3, 0.3)                 # its outward unit normal
    centre = np.array([-0.3, 0.3, z]) + 0.1 * n      # a ball of radius 0.1 touching it
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.rotation import axis_angle_quat, quat_mul, quat_to_mat, yaw_quat
from pipeline.scene import BoxSize, StaticBox, StaticPlane

StaticGeomT = StaticBox | StaticPlane


def ramp(angle_deg: float, length: float, width: float, thickness: float, x: float, y: float,
         yaw_deg: float = 0.0) -> StaticBox:
    """A ramp: a thin box tilted by ``angle_deg`` whose top surface meets the floor.

    Convention: with ``yaw_deg = 0`` the ramp descends along +x: its top surface rises from
    the floor (z = 0) at its downhill edge to ``length * sin(angle)`` at its uphill edge. The
    box's local x runs down the slope (``size.width = length``), local y across it
    (``size.depth = width``), local z along the top surface's normal (``size.height =
    thickness``); the tilt is a rotation by ``+angle`` about the box's local y axis. ``yaw_deg``
    then turns the ramp about the vertical (counter-clockwise seen from above): it descends
    along ``(cos yaw, sin yaw, 0)``. The box reaches below the floor at its downhill end (the
    floor hides that part; world geoms do not collide with each other), so an object slides
    off the ramp onto the floor without a step.

    Args:
        angle_deg: slope, degrees, ``0 <= angle_deg < 90``.
        length: along the slope, m (> 0).
        width: across the slope, m (> 0).
        thickness: of the box, m (> 0).
        x, y: horizontal position of the centre of the top surface, m (world frame); its
            height is ``length / 2 * sin(angle)``.
        yaw_deg: heading of the downhill direction, degrees from +x towards +y.
    Returns:
        the :class:`~pipeline.scene.StaticBox` (not rounded; ``Scene.rounded`` rounds it).
    Raises:
        ValueError: angle outside ``[0, 90)`` or a non-positive length, width or thickness.
    """
    if not 0.0 <= angle_deg < 90.0:
        raise ValueError(f"ramp angle_deg must be in [0, 90), got {angle_deg}")
    for name, v in (("length", length), ("width", width), ("thickness", thickness)):
        if not v > 0:
            raise ValueError(f"ramp {name} must be > 0, got {v}")
    th, yaw = math.radians(angle_deg), math.radians(yaw_deg)
    q = quat_mul(yaw_quat(yaw), axis_angle_quat((0.0, 1.0, 0.0), th))
    normal = quat_to_mat(q)[:, 2]
    top = np.array([x, y, length / 2 * math.sin(th)])
    centre = top - thickness / 2 * normal
    return StaticBox(shape="box", size=BoxSize(width=length, depth=width, height=thickness),
                     position=tuple(float(c) for c in centre), orientation=tuple(float(c) for c in q))


def ramp_parameters(geom: StaticGeomT, tol: float = 2e-3) -> dict[str, float]:
    """The numbers :func:`ramp` was built from, read back from a static box: the inverse of
    :func:`ramp` (the scene-token codec writes a ramp as these numbers, ``pipeline.codec``).

    The box's local y axis (across the slope) must be horizontal, as :func:`ramp` makes it (a
    tilt about local y after a yaw); then the slope is the angle of the top face's normal from
    the vertical, the yaw the heading of the box's local x (downhill), and ``x, y`` the centre of
    the top face.

    Args:
        geom: a static geom (:class:`~pipeline.scene.StaticBox` expected).
        tol: largest vertical component of the box's local y axis accepted (the canonical text
            rounds the quaternion).
    Returns:
        ``{"angle_deg", "length", "width", "thickness", "x", "y", "yaw_deg"}`` (degrees, m).
    Raises:
        ValueError: a plane, or a box that is not a ramp (its local y axis is not horizontal,
            or it tilts the wrong way: the normal points down).
    """
    if geom.shape != "box":
        raise ValueError(f"static: a ramp is a box, got a {geom.shape}")
    R = quat_to_mat(np.asarray(geom.orientation, dtype=np.float64))
    if abs(R[2, 1]) > tol or R[2, 2] <= 0.0:
        raise ValueError("static: not a ramp (a box tilted about its horizontal local y axis, top face up)")
    normal = R[:, 2]
    angle = math.degrees(math.atan2(math.hypot(normal[0], normal[1]), normal[2]))
    yaw = math.degrees(math.atan2(R[1, 0], R[0, 0]))
    top = np.asarray(geom.position, dtype=np.float64) + geom.size.height / 2 * normal
    return {"angle_deg": angle, "length": float(geom.size.width), "width": float(geom.size.depth),
            "thickness": float(geom.size.height), "x": float(top[0]), "y": float(top[1]), "yaw_deg": yaw}


def _support(geom: StaticGeomT, x: float, y: float) -> tuple[float, np.ndarray] | None:
    """(height, outward normal) where the vertical line through (x, y) leaves the geom's top."""
    R = quat_to_mat(geom.orientation)
    c = np.asarray(geom.position, dtype=np.float64)
    o = R.T @ (np.array([x, y, 0.0]) - c)  # line origin (z = 0) in the geom frame
    d = R.T @ np.array([0.0, 0.0, 1.0])    # line direction (+z) in the geom frame
    if geom.shape == "plane":
        half = (geom.size.width / 2, geom.size.depth / 2)
        if abs(d[2]) < 1e-12:
            return None  # vertical plane: no top surface
        t = -o[2] / d[2]
        p = o + t * d
        if abs(p[0]) > half[0] or abs(p[1]) > half[1]:
            return None
        return float(t), R[:, 2].copy()
    half = (geom.size.width / 2, geom.size.depth / 2, geom.size.height / 2)
    lo, hi, face = -math.inf, math.inf, None
    for i in range(3):
        if abs(d[i]) < 1e-12:
            if abs(o[i]) > half[i]:
                return None
            continue
        t1, t2 = (-half[i] - o[i]) / d[i], (half[i] - o[i]) / d[i]
        lo = max(lo, min(t1, t2))
        if max(t1, t2) < hi:
            hi, face = max(t1, t2), i
    if lo > hi or face is None:
        return None
    return float(hi), R[:, face] * math.copysign(1.0, d[face])


def support_height(geom: StaticGeomT, x: float, y: float) -> float | None:
    """Height (m) of the top surface of a static geom above the point (x, y) (world frame, m):
    where the vertical line through (x, y) leaves the box upwards, or meets the plane's
    drawn rectangle. None when the line misses the geom (or the plane is vertical)."""
    s = _support(geom, x, y)
    return None if s is None else s[0]


def support_normal(geom: StaticGeomT, x: float, y: float) -> np.ndarray | None:
    """Outward unit normal ``(3,)`` of the top surface at (x, y) (the face :func:`support_height`
    finds; a plane's local +z), or None where :func:`support_height` is None."""
    s = _support(geom, x, y)
    return None if s is None else s[1]


__all__ = ["ramp", "ramp_parameters", "support_height", "support_normal"]
