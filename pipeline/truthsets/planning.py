"""Planning the truth sets' scenarios: objects and their initial states, drawn by category
(plain data; no physics here). The scenario types, the camera view and the looks are
:mod:`pipeline.truthsets.scenario`.

Initial states are *planned* with closed forms (constant deceleration ``mu g`` for a slide,
rolling at constant speed, ballistic flight) so that the category's event is likely to happen in
view; whether it did is decided afterwards from the simulated truth
(:mod:`pipeline.truthsets.common`), and a scenario whose event did not happen is redrawn.

Categories (:data:`pipeline.truthsets.scenario.CATEGORIES`), one per clip:

* ``moving``: objects thrown (airborne start), sliding (low friction) or rolling through the
  view; sometimes a still object beside them.
* ``stopping``: objects that slide (or roll against rolling friction) and come to rest.
* ``at_rest``: still objects on the floor beside movers that keep clear of them.
* ``entering_leaving``: an object rolls or slides into the view from outside, or out of it.
* ``touching``: two objects resting in contact, or a mover that hits a resting object.
* ``occluding``: a mover passes in front of (or behind) a resting object as seen from the
  camera (for steep cameras it is thrown over it).

Units: SI (m, s, kg, rad) except camera angles (deg), as in the scene language.
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.geometry import volume
from pipeline.rotation import quat_mul, yaw_quat
from pipeline.truthsets.scenario import (CATEGORIES, MIN_PIXELS, REFERENCE_AREA, CameraSpec, EngineLimits, Look,
                                         ObjectSpec, Scenario, View, object_colour, sample_look)

GRAVITY = 9.81
"""m/s^2, along -z (both engines)."""

EXTENT = (0.10, 0.50)
"""m: range of object extents (sphere/cylinder diameter, cylinder height, box sides)."""

STILL_ROLLING_FRICTION = 0.003
"""m: rolling friction of objects placed at rest (without it a ball touching another object
crept 8 mm in 2 s in PyBullet, at under 4 mm/s: neither still nor visibly moving)."""


# ---------------------------------------------------------------------------------------------
# Objects and motion planning
# ---------------------------------------------------------------------------------------------


def _extent(rng: np.random.Generator) -> float:
    """m, in :data:`EXTENT`, smaller ones more likely."""
    return float(EXTENT[0] + (EXTENT[1] - EXTENT[0]) * rng.random() ** 1.5)


def _size(rng: np.random.Generator, shape: str) -> dict[str, float]:
    if shape == "sphere":
        return {"radius": round(_extent(rng) / 2, 4)}
    if shape == "cylinder":
        return {"radius": round(_extent(rng) / 2, 4), "height": round(_extent(rng), 4)}
    return {"width": round(_extent(rng), 4), "depth": round(_extent(rng), 4), "height": round(_extent(rng), 4)}


LYING = np.array([math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0])
"""Quaternion turning a cylinder's axis (body z) onto body -y: it lies on its side."""


def new_object(rng: np.random.Generator, look: Look, shape: str, pose: str, yaw: float | None = None,
               p_low_contrast: float = 0.25) -> ObjectSpec:
    """An object resting on the floor at the origin (move it with :func:`place`).

    Args:
        pose: ``upright`` (boxes, spheres, standing cylinders) or ``lying`` (a cylinder on its
            side, axis horizontal along ``yaw``'s -y).
        yaw: rad about z (random when None).
    """
    size = _size(rng, shape)
    yaw = float(rng.uniform(-math.pi, math.pi)) if yaw is None else yaw
    quat = yaw_quat(yaw)
    if shape == "sphere":
        z = size["radius"]
    elif shape == "cylinder" and pose == "lying":
        quat, z = quat_mul(quat, LYING), size["radius"]
    else:
        z = size["height"] / 2
    density = float(rng.uniform(300, 1200))
    low = bool(rng.random() < p_low_contrast)
    return ObjectSpec(shape=shape, size=size, mass=float(np.clip(density * volume(shape, size), 0.02, 100.0)),
                      position=np.array([0.0, 0.0, z]), quat=np.asarray(quat, dtype=np.float64),
                      friction=float(rng.uniform(0.3, 0.8)), rgb=object_colour(rng, look, low), low_contrast=low)


def place(obj: ObjectSpec, xy: np.ndarray) -> ObjectSpec:
    """Move ``obj`` to floor point ``xy`` (its height kept)."""
    obj.position = np.array([float(xy[0]), float(xy[1]), float(obj.position[2])])
    return obj


def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / max(float(np.linalg.norm(v)), 1e-12)


def _rotate_xy(d: np.ndarray, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([c * d[0] - s * d[1], s * d[0] + c * d[1], 0.0])


def roll(obj: ObjectSpec, velocity: np.ndarray) -> None:
    """Launch a sphere or lying cylinder rolling without slip: ``w = (z x v) / r``. A lying
    cylinder is first turned so that its axis is perpendicular to ``velocity``."""
    v = np.array([velocity[0], velocity[1], 0.0])
    if obj.shape == "cylinder":   # axis along -y of the yaw frame: yaw the frame so x is along v
        obj.quat = quat_mul(yaw_quat(math.atan2(v[1], v[0])), LYING)
    r = obj.size["radius"]
    obj.linear_velocity = v
    obj.angular_velocity = np.cross([0.0, 0.0, 1.0], v) / r


def slide(obj: ObjectSpec, velocity: np.ndarray, spin: float = 0.0) -> None:
    """Launch a box or standing cylinder sliding, spinning ``spin`` rad/s about z."""
    obj.linear_velocity = np.array([velocity[0], velocity[1], 0.0])
    obj.angular_velocity = np.array([0.0, 0.0, spin])


def rolls(obj: ObjectSpec) -> bool:
    """The object rolls on the floor (sphere or lying cylinder)."""
    return obj.shape == "sphere" or (obj.shape == "cylinder" and abs(quat_to_axis_z(obj.quat)) < 0.5)


def quat_to_axis_z(q: np.ndarray) -> float:
    """World z component of the body z axis of quaternion ``q`` (w, x, y, z)."""
    w, x, y, z = q
    return float(1 - 2 * (x * x + y * y))


def travel(obj: ObjectSpec, t: float) -> float:
    """Planned distance covered by ``t`` s along the launch direction, m (rolling: constant
    speed minus rolling resistance; sliding: deceleration ``mu g``, stopping at rest)."""
    v = float(np.linalg.norm(obj.linear_velocity[:2]))
    if rolls(obj):
        inertia = 0.4 if obj.shape == "sphere" else 0.5
        a = obj.rolling_friction * GRAVITY / ((1 + inertia) * obj.size["radius"])
    else:
        a = obj.friction * GRAVITY
    if a <= 0:
        return v * t
    t = min(t, v / a)
    return v * t - 0.5 * a * t * t


class Planner:
    """Random placement of objects on the visible floor for one scenario."""

    def __init__(self, rng: np.random.Generator, view: View, look: Look, duration: float, min_pixels: float):
        self.rng, self.view, self.look, self.duration = rng, view, look, duration
        self.min_area = 3.0 * min_pixels       # bounding discs overestimate the silhouette
        self.max_area = 0.15 * view.width * view.height
        self.margin = 0.06 * min(view.width, view.height)
        self.objects: list[ObjectSpec] = []
        self.paths: list[tuple[np.ndarray, np.ndarray, float]] = []   # movers' planned segments

    # -- checks
    def sized_ok(self, point: np.ndarray, radius: float) -> bool:
        _, r, _ = self.view.disc(point, radius)
        return self.min_area <= math.pi * r * r <= self.max_area

    def visible(self, point: np.ndarray, radius: float) -> bool:
        return self.view.inside(point, radius, self.margin) and self.sized_ok(point, radius)

    def clear(self, xy: np.ndarray, radius: float, gap: float = 0.05, skip: tuple[int, ...] = ()) -> bool:
        """No placed object and no planned path within ``radius + gap`` of floor point ``xy``."""
        for i, o in enumerate(self.objects):
            if i not in skip and np.linalg.norm(o.position[:2] - xy[:2]) < o.footprint + radius + gap:
                return False
        for a, b, r in self.paths:
            if _segment_distance(xy[:2], a[:2], b[:2]) < r + radius + gap:
                return False
        return True

    def path_clear(self, a: np.ndarray, b: np.ndarray, radius: float, skip: tuple[int, ...] = ()) -> bool:
        """The segment a-b keeps ``radius + 5 cm`` from every placed object not in ``skip``."""
        return all(_segment_distance(o.position[:2], a[:2], b[:2]) >= o.footprint + radius + 0.05
                   for i, o in enumerate(self.objects) if i not in skip)

    # -- sampling
    def floor_point(self, obj: ObjectSpec, tries: int = 200, clear: bool = True) -> np.ndarray | None:
        """A floor point where ``obj`` (at its height) is in view, big enough and clear."""
        cam = self.view.spec
        hfov = 2 * math.atan(math.tan(math.radians(cam.fov) / 2) * self.view.width / self.view.height)
        reach = 1.2 * cam.distance * math.tan(hfov / 2) + 0.3
        centre = cam.look_at[:2]
        for _ in range(tries):
            r, a = reach * math.sqrt(self.rng.random()), self.rng.uniform(0, 2 * math.pi)
            xy = centre + r * np.array([math.cos(a), math.sin(a)])
            p = np.array([xy[0], xy[1], obj.position[2]])
            if self.visible(p, obj.radius) and (not clear or self.clear(p, obj.footprint)):
                return p
        return None

    def add(self, obj: ObjectSpec, path_end: np.ndarray | None = None) -> ObjectSpec:
        self.objects.append(obj)
        if path_end is not None:
            self.paths.append((obj.position.copy(), np.asarray(path_end, dtype=np.float64), obj.footprint))
        return obj

    def shape(self, choices: tuple[str, ...] = ("sphere", "cylinder", "box")) -> str:
        return str(self.rng.choice(choices))

    # -- object kinds
    def still(self, shape: str | None = None) -> ObjectSpec | None:
        """A resting object in view, clear of the others and of the planned paths."""
        shape = shape or self.shape()
        pose = "lying" if shape == "cylinder" and self.rng.random() < 0.3 else "upright"
        obj = new_object(self.rng, self.look, shape, pose)
        obj.role = "still"
        obj.rolling_friction = STILL_ROLLING_FRICTION
        p = self.floor_point(obj)
        return None if p is None else self.add(place(obj, p))

    def mover(self, kind: str, shape: str | None = None, p_out: float = 0.0) -> ObjectSpec | None:
        """A moving object from a visible start towards another visible point.

        Args:
            kind: ``roll`` (sphere or lying cylinder, tiny rolling friction: keeps going),
                ``slide`` (box or standing cylinder, friction 0.01-0.08: keeps going),
                ``stop`` (slides with friction 0.25-0.7, or rolls against rolling friction, and
                rests after 0.3-1.4 s), ``throw`` (starts in the air with a random spin).
            p_out: probability that the planned path may leave the view.
        """
        rng = self.rng
        T = self.duration
        if kind == "roll":
            shape = shape if shape in ("sphere", "cylinder") else self.shape(("sphere", "sphere", "cylinder"))
        elif kind == "slide":
            shape = shape if shape in ("box", "cylinder") else self.shape(("box", "cylinder"))
        shape = shape or self.shape()
        lying = kind == "roll" and shape == "cylinder" or kind == "stop" and shape == "cylinder" and rng.random() < 0.3
        obj = new_object(rng, self.look, shape, "lying" if lying else "upright")
        obj.role = kind
        if kind == "throw":
            return self._throw(obj)
        start = self.floor_point(obj)
        if start is None:
            return None
        place(obj, start)
        for _ in range(40):
            target = self.floor_point(obj, tries=50, clear=False)
            if target is None:
                return None
            d = _unit((target - start) * np.array([1, 1, 0]))
            dist = float(np.linalg.norm((target - start)[:2]))
            if kind == "stop":
                t_stop = rng.uniform(0.3, min(1.4, 0.8 * T))
                if rolls(obj):
                    v = 2 * dist / t_stop
                    inertia = 0.4 if obj.shape == "sphere" else 0.5
                    obj.rolling_friction = float((1 + inertia) * obj.size["radius"] * (v / t_stop) / GRAVITY)
                    roll(obj, v * d)
                else:
                    obj.friction = float(2 * dist / (GRAVITY * t_stop ** 2))
                    if not 0.15 <= obj.friction <= 0.9:
                        continue
                    slide(obj, (2 * dist / t_stop) * d)
            elif rolls(obj):
                obj.rolling_friction = float(rng.uniform(0.0, 2e-4))
                roll(obj, (dist / T) * d)
            else:   # covers dist in T s and still moves at >= 0.1 m/s: dist / T - mu g T / 2 >= 0.1
                mu_max = min(0.08, 2 * (dist / T - 0.1) / (GRAVITY * T))
                if mu_max < 0.01:
                    continue
                obj.friction = float(rng.uniform(0.01, mu_max))
                v = dist / T + 0.5 * obj.friction * GRAVITY * T
                slide(obj, v * d, spin=float(rng.uniform(-2, 2)) if rng.random() < 0.3 else 0.0)
            speed = float(np.linalg.norm(obj.linear_velocity))
            if speed < 0.15 or speed > 4.0:
                continue
            end = start + d * travel(obj, T)
            if rng.random() >= p_out and not self.visible(end, obj.radius):
                continue
            if self.path_clear(start, end, obj.footprint):
                return self.add(obj, end)
        return None

    def _throw(self, obj: ObjectSpec) -> ObjectSpec | None:
        rng = self.rng
        obj.quat = _random_quat(rng)
        r = obj.radius
        obj.position[2] = r
        land = self.floor_point(obj)
        if land is None:
            return None
        z0 = r + rng.uniform(0.05, 0.4)
        vz = rng.uniform(0.3, 2.5)
        # flight time from z0 to r: z0 + vz t - g t^2 / 2 = r
        t_f = (vz + math.sqrt(vz * vz + 2 * GRAVITY * (z0 - r))) / GRAVITY
        vh = rng.uniform(0.3, 1.5)
        d = _unit(_rotate_xy(np.array([1.0, 0, 0]), rng.uniform(0, 2 * math.pi)))
        start = land - d * vh * t_f
        start[2] = z0
        if not self.visible(start, r) or not self.clear(start, r):
            return None
        obj.position = start
        obj.linear_velocity = np.array([vh * d[0], vh * d[1], vz])
        axis = _unit(rng.normal(size=3))
        obj.angular_velocity = axis * rng.uniform(0, 8)
        obj.restitution = float(rng.uniform(0.0, 0.5))
        obj.friction = float(rng.uniform(0.2, 0.7))
        obj.rolling_friction = float(rng.uniform(0.0, 0.002))
        end = land + d * vh * max(self.duration - t_f, 0)
        return self.add(obj, end)

    def offscreen_distance(self, obj: ObjectSpec, through: np.ndarray, d: np.ndarray) -> float | None:
        """Least distance s >= 0 along ``d`` from ``through`` at which ``obj`` is out of view."""
        for s in np.arange(0.0, 8.0, 0.04):
            if self.view.outside(through + s * d, obj.radius):
                return float(s)
        return None

    def crossing(self, kind: str, shape: str | None = None) -> ObjectSpec | None:
        """An object that enters (``enter``) the view from a side or leaves (``leave``) it."""
        rng = self.rng
        shape = shape or self.shape(("sphere", "sphere", "cylinder", "box"))
        lying = shape == "cylinder" and rng.random() < 0.6
        obj = new_object(rng, self.look, shape, "lying" if lying else "upright")
        obj.role = kind
        inside = self.floor_point(obj)
        if inside is None:
            return None
        side = float(rng.choice([-1.0, 1.0]))
        d = _unit(_rotate_xy(side * self.view.spec.right, rng.uniform(-0.45, 0.45)))   # outwards
        out = self.offscreen_distance(obj, inside, d)
        if out is None:
            return None
        out += rng.uniform(0.02, 0.3)
        if kind == "enter":
            start, heading, t_event = inside + d * out, -d, rng.uniform(0.3, 0.9)
        else:
            start, heading, t_event = inside, d, rng.uniform(0.5, 1.6)
        place(obj, start)
        if rolls(obj):
            obj.rolling_friction = float(rng.uniform(0.0, 2e-4))
            roll(obj, (out / t_event) * heading)
        else:
            obj.friction = float(rng.uniform(0.02, 0.08))
            slide(obj, (out / t_event + 0.5 * obj.friction * GRAVITY * t_event) * heading)
        if not 0.2 <= np.linalg.norm(obj.linear_velocity) <= 4.5:
            return None
        end = start + heading * travel(obj, self.duration)
        if not self.clear(start, obj.footprint) or not self.path_clear(start, end, obj.footprint):
            return None
        return self.add(obj, end)

    def touching_pair(self) -> list[ObjectSpec] | None:
        """Two resting objects in contact (side to side, or a ball against a side)."""
        rng = self.rng
        shapes = [self.shape(("sphere", "box", "cylinder")) for _ in range(2)]
        d = _rotate_xy(np.array([1.0, 0, 0]), rng.uniform(0, 2 * math.pi))
        yaw = math.atan2(d[1], d[0])
        a, b = (new_object(rng, self.look, s, "upright", yaw=yaw) for s in shapes)
        for o in (a, b):
            o.role = "still"
            o.rolling_friction = STILL_ROLLING_FRICTION
        p = self.floor_point(a)
        if p is None:
            return None
        place(a, p)

        def reach(o: ObjectSpec) -> float:   # horizontal half extent along d
            return o.size["width"] / 2 if o.shape == "box" else o.size["radius"]

        if a.shape == b.shape == "sphere":
            off = 2 * math.sqrt(a.size["radius"] * b.size["radius"])
        else:
            for s, o in ((a, b), (b, a)):   # a ball touches a side at its own centre height
                if s.shape == "sphere" and o.shape != "sphere" and s.size["radius"] > o.size["height"]:
                    o.size["height"] = round(s.size["radius"] + 0.02, 4)
                    o.position[2] = o.size["height"] / 2
            off = reach(a) + reach(b)
        q = a.position + off * d
        place(b, q)
        if not self.visible(b.position, b.radius) or not self.clear(b.position, b.footprint):
            return None
        self.add(a)
        self.add(b)
        return [a, b]

    def hitter(self, target: ObjectSpec) -> ObjectSpec | None:
        """A mover aimed at ``target``'s centre, reaching it after 0.4-1.0 s."""
        rng = self.rng
        kind = str(rng.choice(["roll", "slide"]))
        shape = self.shape(("sphere", "cylinder")) if kind == "roll" else self.shape(("box", "cylinder"))
        obj = new_object(rng, self.look, shape, "lying" if kind == "roll" and shape == "cylinder" else "upright")
        obj.role = "hit"
        k = self.objects.index(target)
        for _ in range(30):
            d = _rotate_xy(np.array([1.0, 0, 0]), rng.uniform(0, 2 * math.pi))
            gap = target.footprint + obj.footprint
            start = target.position - d * (gap + rng.uniform(0.2, 0.9))
            start[2] = obj.position[2]
            if not self.visible(start, obj.radius) or not self.clear(start, obj.footprint):
                continue
            dist = float(np.linalg.norm((target.position - start)[:2])) - 0.5 * gap
            t_hit = rng.uniform(0.4, 1.0)
            place(obj, start)
            if kind == "roll":
                obj.rolling_friction = float(rng.uniform(0.0, 2e-4))
                roll(obj, (dist / t_hit) * d)
            else:
                obj.friction = float(rng.uniform(0.05, 0.2))
                slide(obj, (dist / t_hit + 0.5 * obj.friction * GRAVITY * t_hit) * d)
            if np.linalg.norm(obj.linear_velocity) > 4.0:
                continue
            if self.path_clear(start, target.position, obj.footprint, skip=(k,)):
                return self.add(obj, target.position)
        return None

    def crosser(self, target: ObjectSpec) -> ObjectSpec | None:
        """A mover passing between the camera and ``target`` (or behind it, low cameras): along
        the floor for pitch < 55 deg, thrown over it for steeper cameras."""
        rng = self.rng
        cam = self.view.spec
        eye = cam.eye
        k = self.objects.index(target)
        towards = _unit((eye - target.position) * np.array([1, 1, 0]))
        side = np.array([-towards[1], towards[0], 0.0]) * rng.choice([-1.0, 1.0])
        if cam.pitch < 55:
            kind = str(rng.choice(["roll", "slide"]))
            shape = self.shape(("sphere", "cylinder")) if kind == "roll" else self.shape(("box", "cylinder"))
            obj = new_object(rng, self.look, shape, "lying" if kind == "roll" and shape == "cylinder" else "upright")
            obj.role = "cross"
            sign = 1.0 if rng.random() < 0.7 else -1.0   # mostly in front
            c = target.position + sign * towards * (target.footprint + obj.footprint + rng.uniform(0.03, 0.25))
            c[2] = obj.position[2]
            t_c = rng.uniform(0.5, 1.2)
            v = rng.uniform(0.3, 1.2)
            if kind == "roll":
                obj.rolling_friction = float(rng.uniform(0.0, 2e-4))
                start = c - side * v * t_c
                place(obj, start)
                roll(obj, v * side)
            else:
                obj.friction = float(rng.uniform(0.02, 0.08))
                a = obj.friction * GRAVITY
                start = c - side * (v * t_c - 0.5 * a * t_c ** 2)
                place(obj, start)
                slide(obj, v * side)
            end = start + side * travel(obj, self.duration)
        else:
            shape = self.shape()
            obj = new_object(rng, self.look, shape, "upright")
            obj.role = "cross"
            obj.quat = _random_quat(rng)
            r = obj.radius
            top = target.position[2] + target.radius + r + rng.uniform(0.03, 0.3)
            s = (top - target.position[2]) / max(eye[2] - target.position[2], 1e-6)
            c = target.position + s * (eye - target.position)     # on the line of sight
            t_c = math.sqrt(2 * max(c[2] - r - 0.02, 0.0) / GRAVITY) * rng.uniform(0.6, 1.0)
            if t_c < 0.15:
                return None
            vz = GRAVITY * t_c            # apex at c
            z0 = c[2] - 0.5 * GRAVITY * t_c ** 2
            vh = rng.uniform(0.3, 1.2)
            start = c - side * vh * t_c
            start[2] = z0
            obj.position = start
            obj.linear_velocity = np.array([vh * side[0], vh * side[1], vz])
            obj.angular_velocity = _unit(rng.normal(size=3)) * rng.uniform(0, 6)
            obj.friction = float(rng.uniform(0.2, 0.7))
            obj.rolling_friction = float(rng.uniform(0.0, 0.002))
            end = c + side * vh * self.duration
            end[2] = r
        (u1, r1, _), (u2, r2, _) = self.view.disc(c, obj.radius), self.view.disc(target.position, target.radius)
        if np.linalg.norm(u1 - u2) > 0.6 * (r1 + r2):
            return None
        if not self.view.inside(obj.position, obj.radius) or not self.sized_ok(obj.position, obj.radius):
            return None
        if not self.clear(obj.position, obj.footprint) or \
                not self.path_clear(obj.position, end, obj.footprint, skip=(k,)):
            return None
        if cam.pitch < 55 and _segment_distance(target.position[:2], obj.position[:2], end[:2]) < \
                target.footprint + obj.footprint + 0.01:
            return None
        return self.add(obj, end)


def _random_quat(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Distance from point ``p`` to segment ``a-b`` (2-D), m."""
    ab = b - a
    t = 0.0 if float(ab @ ab) < 1e-12 else float(np.clip((p - a) @ ab / (ab @ ab), 0, 1))
    return float(np.linalg.norm(p - (a + t * ab)))


# ---------------------------------------------------------------------------------------------
# Scenarios
# ---------------------------------------------------------------------------------------------


def sample_camera(rng: np.random.Generator, limits: EngineLimits, width: int, height: int) -> CameraSpec:
    """Random yaw, pitch (engine range), fov 35-60 deg and a distance that frames 1.4-3.2 m of
    floor across at the look-at point."""
    fov = float(rng.uniform(35, 60))
    pitch = float(rng.uniform(*limits.pitch))
    hfov = 2 * math.atan(math.tan(math.radians(fov) / 2) * width / height)
    across = float(rng.uniform(1.4, 3.2))
    distance = across / (2 * math.tan(hfov / 2))
    return CameraSpec(yaw=float(rng.uniform(-180, 180)), pitch=pitch, fov=fov, distance=distance,
                      look_at=np.array([0.0, 0.0, float(rng.uniform(0.1, 0.25))]))


def _layout(rng: np.random.Generator, category: str, planner: Planner) -> bool:
    """Place the objects of ``category``; False if this draw does not fit (draw again)."""
    p = planner
    if category == "moving":
        n_move = int(rng.choice([1, 2, 3], p=[0.3, 0.4, 0.3]))
        if rng.random() < 0.3 and p.still() is None:
            return False
        for _ in range(n_move):
            if p.mover(str(rng.choice(["roll", "slide", "throw"], p=[0.45, 0.3, 0.25])), p_out=0.2) is None:
                return False
        return True
    if category == "stopping":
        for _ in range(int(rng.choice([1, 2], p=[0.6, 0.4]))):
            if p.mover("stop", shape=p.shape(("box", "box", "cylinder", "sphere"))) is None:
                return False
        if rng.random() < 0.7 and p.mover(str(rng.choice(["roll", "slide"]))) is None:
            return False
        return rng.random() >= 0.15 or p.still() is not None
    if category == "at_rest":
        for _ in range(int(rng.choice([1, 2], p=[0.7, 0.3]))):
            if p.still() is None:
                return False
        for _ in range(int(rng.choice([1, 2], p=[0.5, 0.5]))):
            if p.mover(str(rng.choice(["roll", "slide", "throw"], p=[0.45, 0.35, 0.2]))) is None:
                return False
        return True
    if category == "entering_leaving":
        kinds = [["enter"], ["leave"], ["enter", "leave"]][int(rng.choice(3, p=[0.45, 0.25, 0.3]))]
        for kind in kinds:
            if p.crossing(kind) is None:
                return False
        if rng.random() < 0.3 and p.mover(str(rng.choice(["roll", "slide"]))) is None:
            return False
        return rng.random() >= 0.4 or p.still() is not None
    if category == "touching":
        if rng.random() < 0.5:
            if p.touching_pair() is None:
                return False
            return rng.random() >= 0.6 or p.mover(str(rng.choice(["roll", "slide"]))) is not None
        target = p.still()
        if target is None or p.hitter(target) is None:
            return False
        target.role = "target"
        return rng.random() >= 0.3 or p.mover(str(rng.choice(["roll", "slide"]))) is not None
    if category == "occluding":
        target = p.still()
        if target is None or p.crosser(target) is None:
            return False
        if rng.random() < 0.4 and p.mover(str(rng.choice(["roll", "slide", "throw"]))) is None:
            return False
        return rng.random() >= 0.2 or p.still() is not None
    raise ValueError(f"category: must be one of {', '.join(CATEGORIES)}, got {category!r}")


def sample_scenario(rng: np.random.Generator, category: str, limits: EngineLimits, width: int, height: int,
                    fps: float, duration: float, max_tries: int = 200) -> Scenario:
    """A random scenario of ``category``.

    Raises:
        RuntimeError: no layout fitted in ``max_tries`` draws (a bug or impossible limits).
    """
    look = sample_look(rng, limits)
    min_pixels = MIN_PIXELS * width * height / REFERENCE_AREA
    for _ in range(max_tries):
        cam = sample_camera(rng, limits, width, height)
        planner = Planner(rng, View(cam, width, height), look, duration, min_pixels)
        if _layout(rng, category, planner):
            # objects ordered left to right in the first frame (as pipeline.sampler)
            uv, _ = planner.view.project(np.array([o.position for o in planner.objects]))
            objects = [planner.objects[i] for i in np.argsort(uv[:, 0], kind="stable")]
            return Scenario(category, cam, look, objects, width, height, fps, duration)
    raise RuntimeError(f"{category}: no layout fitted in {max_tries} draws")
