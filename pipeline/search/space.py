"""The normalised CMA-ES search vector of a scene (:class:`SearchSpace`)."""

from __future__ import annotations

import copy
import math
from typing import Iterable

import numpy as np

from pipeline.effects import REGISTRY
from pipeline.geometry import support_height
from pipeline.rotation import quat_mul, quat_to_mat, yaw_quat
from pipeline.scene import Scene
from pipeline.search.config import FREE_FIELDS, SearchRanges


class SearchSpace:
    """Normalised search vector of a scene: each free parameter mapped to [0, 1].

    Parameter ``p`` with bounds ``[lo, hi]`` around the start value is ``x = (p − lo) / (hi −
    lo)``; sizes and masses are searched in log space; yaw is a rotation of the starting
    orientation about world z (deg); the camera's exposure over its whole range, 0 to one frame
    interval (s). Bounds are clipped to what the scene language accepts
    (pitch in [-89, 89], fov in (1, 179), friction/damping >= 0) and z to at least the
    object's floor contact height (:func:`floor_height`; no start inside the floor), so every
    vector decodes to a valid scene. :meth:`decode` also lifts an object whose decoded size or
    orientation would put it inside the floor onto it (the size stage grew a ball resting on
    the floor into it: ``dynamics simulate`` refused the main job's scene on 6 of 12 real clips,
    issue 35). Parameters with an empty range are left out.

    Args:
        scene: the starting scene (its structure stays fixed).
        free: field groups to search (see :data:`FREE_FIELDS`).
        ranges: half-widths of the box.
    """

    def __init__(self, scene: Scene, free: Iterable[str], ranges: SearchRanges):
        self.scene = scene
        self._base = scene.model_dump()
        self.names: list[str] = []
        self._path: list[tuple] = []
        self._kind: list[str] = []
        lo, hi, x0 = [], [], []
        free = set(free)
        bad = free - set(FREE_FIELDS)
        if bad:
            raise ValueError(f"search.free: unknown field(s) {sorted(bad)}, must be among {FREE_FIELDS}")

        def add(name: str, path: tuple, value: float, low: float, high: float, kind: str = "lin") -> None:
            if kind == "log":
                value, low, high = math.log(value), math.log(low), math.log(high)
            if not high > low:
                return
            self.names.append(name)
            self._path.append(path)
            self._kind.append(kind)
            lo.append(low)
            hi.append(high)
            x0.append((value - low) / (high - low))

        r = ranges
        for i, o in enumerate(scene.objects):
            pre = f"objects[{i}]"
            if "position" in free:
                for k, axis in enumerate("xyz"):
                    v = o.position[k]
                    # z: not below the floor contact height (an object starts on or above the floor)
                    low = min(max(v - r.position, floor_height(o)), v) if axis == "z" else v - r.position
                    add(f"{pre}.position.{axis}", ("objects", i, "position", k), v, low, v + r.position)
            if "linear_velocity" in free:
                for k, axis in enumerate("xyz"):
                    v = o.linear_velocity[k]
                    add(f"{pre}.linear_velocity.{axis}", ("objects", i, "linear_velocity", k), v,
                        v - r.linear_velocity, v + r.linear_velocity)
            if "angular_velocity" in free:
                for k, axis in enumerate("xyz"):
                    v = o.angular_velocity[k]
                    add(f"{pre}.angular_velocity.{axis}", ("objects", i, "angular_velocity", k), v,
                        v - r.angular_velocity, v + r.angular_velocity)
            if "yaw" in free:
                add(f"{pre}.yaw", ("objects", i, "yaw"), 0.0, -r.yaw, r.yaw, "yaw")
            if "size" in free:
                for key, v in o.size.model_dump().items():
                    add(f"{pre}.size.{key}", ("objects", i, "size", key), v, v / r.size_factor,
                        v * r.size_factor, "log")
            if "mass" in free:
                add(f"{pre}.mass", ("objects", i, "mass"), o.mass, o.mass / r.mass_factor,
                    o.mass * r.mass_factor, "log")
            if "friction" in free:
                v = o.material.sliding_friction
                add(f"{pre}.material.sliding_friction", ("objects", i, "material", "sliding_friction"), v,
                    max(0.0, v - r.friction), v + r.friction)
            if "damping" in free:
                v = o.material.damping
                add(f"{pre}.material.damping", ("objects", i, "material", "damping"), v,
                    max(0.0, v - r.damping), v + r.damping)
        if "camera" in free:
            cam = scene.camera
            if cam.is_six_dof:
                for k, axis in enumerate("xyz"):
                    v = cam.position[k]
                    add(f"camera.position.{axis}", ("camera", "position", k), v, v - r.camera_position,
                        v + r.camera_position)
                for key in ("yaw", "roll"):
                    v = getattr(cam, key) or 0.0
                    add(f"camera.{key}", ("camera", key), v, v - r.camera_angle, v + r.camera_angle)
            else:
                v = cam.height
                add("camera.height", ("camera", "height"), v, max(0.05, v - r.camera_height), v + r.camera_height)
            v = cam.pitch
            add("camera.pitch", ("camera", "pitch"), v, max(-89.0, v - r.camera_angle), min(89.0, v + r.camera_angle))
            v = cam.fov
            add("camera.fov", ("camera", "fov"), v, max(1.5, v - r.fov), min(178.5, v + r.fov))
        if "exposure" in free:   # the shutter time, s: from instantaneous to one frame interval (pipeline.exposure)
            add("camera.exposure", ("camera", "exposure"), scene.camera.exposure, 0.0, 1.0 / scene.fps)
        if "restitution" in free:   # written into the compiled model per candidate (SceneEvaluator)
            spec = REGISTRY["restitution"].parameters["e"]
            for j, fx in enumerate(scene.effects):
                if fx.effect == "restitution":
                    v = float(fx.parameters.get("e", spec.default))
                    add(f"effects[{j}].e", ("effects", j, "parameters", "e"), v,
                        max(spec.low, v - r.restitution), min(spec.high, v + r.restitution))
            for j, g in enumerate(scene.static):   # a springy stop's own bounce (a bumper)
                if g.restitution is not None:
                    add(f"static[{j}].restitution", ("static", j, "restitution"), g.restitution,
                        max(spec.low, g.restitution - r.restitution), min(spec.high, g.restitution + r.restitution))
        self.lo, self.hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
        self.x0 = np.clip(np.asarray(x0, dtype=np.float64), 0.0, 1.0)

    @property
    def dim(self) -> int:
        return len(self.names)

    def decode(self, x: np.ndarray) -> Scene:
        """The scene of a normalised vector ``x (dim,)`` in [0, 1] (clipped).

        Raises:
            SceneError: only if the starting scene itself was invalid.
        """
        x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
        values = self.lo + x * (self.hi - self.lo)
        d = copy.deepcopy(self._base)
        for path, kind, v in zip(self._path, self._kind, values):
            if kind == "log":
                v = math.exp(v)
            if kind == "yaw":
                obj = d[path[0]][path[1]]
                obj["orientation"] = tuple(quat_mul(yaw_quat(math.radians(v)), obj["orientation"]))
                continue
            target = d
            for key in path[:-1]:
                target = target[key]
            if isinstance(target, tuple):  # vectors are tuples in model_dump
                parent = d
                for key in path[:-2]:
                    parent = parent[key]
                lst = list(target)
                lst[path[-1]] = float(v)
                parent[path[-2]] = tuple(lst)
            else:
                target[path[-1]] = float(v)
        scene = Scene.from_dict(d, source="<search>")
        lifted = False
        for i, o in enumerate(scene.objects):  # a larger size or a tilt must not sink it into the floor
            low = floor_height(o)
            if o.position[2] < low:
                d["objects"][i]["position"] = (o.position[0], o.position[1], low)
                lifted = True
        return Scene.from_dict(d, source="<search>") if lifted else scene

    def prior(self, x: np.ndarray) -> float:
        """Mean squared normalised distance of ``x`` to the starting vector."""
        return float(np.mean((np.asarray(x) - self.x0) ** 2)) if self.dim else 0.0


def floor_height(obj) -> float:
    """Height (m) of an object's centre when its lowest point touches the floor z = 0, for its
    orientation (:func:`pipeline.geometry.support_height`)."""
    return float(support_height(obj.shape, obj.size, quat_to_mat(obj.orientation)))
