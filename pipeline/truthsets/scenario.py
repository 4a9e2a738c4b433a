"""Engine-neutral scenarios of the truth sets (plain data; no physics here): what a scenario
holds (category, camera, look, objects and their initial states), the camera's view of it
(pinhole projection, :class:`View`) and its random look (floor texture, light, object colours).

A :class:`Scenario` is what both engines (:mod:`pipeline.truthsets.mujoco_scenes`,
:mod:`pipeline.truthsets.pybullet_scenes`) build, simulate and render; each engine has its own
physics, so the same scenario may play out a little differently in each. Scenarios are drawn
by category (:data:`CATEGORIES`, one per clip): objects and their initial states are planned
by :mod:`pipeline.truthsets.planning` (:func:`pipeline.truthsets.planning.sample_scenario`).

Units: SI (m, s, kg, rad) except camera angles (deg), as in the scene language.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pipeline.camera import extrinsics, intrinsics
from pipeline.geometry import bounding_radius
from pipeline.scene import Camera

CATEGORIES = ("moving", "stopping", "at_rest", "entering_leaving", "touching", "occluding")
"""Scene categories; every set of at least six clips holds each of them."""

MIN_PIXELS = 30
"""Fewest pixels of an object in view and unoccluded, at 320x240 (scaled with the image area)."""

REFERENCE_AREA = 320 * 240
"""px: the image area :data:`MIN_PIXELS` refers to."""


@dataclass(frozen=True)
class EngineLimits:
    """What an engine can draw.

    Attributes:
        pitch: (low, high) camera pitch, deg below the horizon (89 is top-down: the scene
            language caps pitch at 89).
        floor_kinds: floor textures and their probabilities.
        p_shadows: probability that the light casts shadows.
    """

    pitch: tuple[float, float]
    floor_kinds: dict[str, float]
    p_shadows: float


@dataclass
class ObjectSpec:
    """One object and its initial state.

    Attributes:
        shape: sphere | cylinder | box.
        size: scene-language size (``radius``; ``radius, height``; ``width, depth, height``), m.
        mass: kg.
        position: (3,) float64 centre, world frame, m.
        quat: (4,) float64 orientation w, x, y, z.
        linear_velocity: (3,) float64 m/s, world frame.
        angular_velocity: (3,) float64 rad/s, world frame.
        friction: sliding (Coulomb) coefficient against the floor and other objects.
        rolling_friction: rolling coefficient, m (resisting torque = coefficient x normal force).
        restitution: coefficient of restitution wanted against the floor (0: no bounce).
        rgb: (3,) colour in [0, 1].
        low_contrast: the colour was drawn close to the floor's mean colour.
        role: how it was planned: still, roll, slide, throw, stop, enter, leave, hit (a mover
            aimed at a ``target``), target, cross (passes in front of or behind a still one).
    """

    shape: str
    size: dict[str, float]
    mass: float
    position: np.ndarray
    quat: np.ndarray
    linear_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    angular_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    friction: float = 0.5
    rolling_friction: float = 0.0
    restitution: float = 0.0
    rgb: tuple[float, float, float] = (0.8, 0.2, 0.2)
    low_contrast: bool = False
    role: str = "still"

    @property
    def radius(self) -> float:
        """Bounding-sphere radius, m."""
        return bounding_radius(self.shape, self.size)

    @property
    def footprint(self) -> float:
        """Radius of a vertical cylinder about the centre that holds the object, m (upper bound
        for any orientation: the bounding radius)."""
        return self.radius

    def to_meta(self) -> dict:
        """JSON-able description (meta.json)."""
        return {"shape": self.shape, "size": {k: round(v, 4) for k, v in self.size.items()},
                "mass": round(self.mass, 4), "rgb": [round(c, 3) for c in self.rgb],
                "low_contrast": self.low_contrast, "role": self.role,
                "friction": round(self.friction, 4), "rolling_friction": round(self.rolling_friction, 5),
                "restitution": round(self.restitution, 3),
                "initial_position": [round(float(c), 4) for c in self.position],
                "initial_quat": [round(float(c), 5) for c in self.quat],
                "initial_linear_velocity": [round(float(c), 4) for c in self.linear_velocity],
                "initial_angular_velocity": [round(float(c), 4) for c in self.angular_velocity]}


@dataclass
class CameraSpec:
    """A fixed camera looking at ``look_at`` from ``distance`` (6-DoF scene-language form).

    Attributes:
        yaw, pitch, fov: deg (pitch below the horizon, fov vertical; yaw as
            :class:`pipeline.scene.Camera`).
        distance: eye to ``look_at``, m.
        look_at: (3,) float64 world point on the optical axis, m.
    """

    yaw: float
    pitch: float
    fov: float
    distance: float
    look_at: np.ndarray

    @property
    def forward(self) -> np.ndarray:
        p, y = math.radians(self.pitch), math.radians(self.yaw)
        return np.array([-math.sin(y) * math.cos(p), math.cos(y) * math.cos(p), -math.sin(p)])

    @property
    def right(self) -> np.ndarray:
        """Horizontal image-right direction (3,), world frame."""
        y = math.radians(self.yaw)
        return np.array([math.cos(y), math.sin(y), 0.0])

    @property
    def eye(self) -> np.ndarray:
        return self.look_at - self.distance * self.forward

    def camera(self) -> Camera:
        """The scene-language camera (6-DoF form, no roll)."""
        return Camera(position=tuple(float(c) for c in self.eye), yaw=float(self.yaw), pitch=float(self.pitch),
                      roll=0.0, fov=float(self.fov))

    def to_meta(self) -> dict:
        return {"position": [round(float(c), 4) for c in self.eye], "yaw_deg": round(self.yaw, 3),
                "pitch_deg": round(self.pitch, 3), "fov_deg": round(self.fov, 3),
                "distance": round(self.distance, 4), "look_at": [round(float(c), 4) for c in self.look_at]}


@dataclass
class Look:
    """Floor, light and object surface (no effect on the physics). Colours RGB in [0, 1].

    Attributes:
        floor_kind: checker | gradient | flat | noise | stripes (``gradient``: MuJoCo's builtin
            texture; ``noise`` and ``stripes``: a generated image, :func:`floor_image`).
        floor_rgb1, floor_rgb2: the texture's two colours (``flat``: ``floor_rgb1``).
        floor_tile: m, floor length of one texture repeat.
        light_dir: (3,) direction the light shines along, world frame (unit).
        light_diffuse, light_ambient, light_specular: intensities of the light, 0-1.
        headlight_ambient, headlight_diffuse: the camera headlight (MuJoCo only), 0-1.
        shadows: the light casts shadows.
        object_checker: objects wear a two-tone checker of their colour (MuJoCo only).
        texture_seed: seed of the generated floor image (:func:`floor_image`).
    """

    floor_kind: str
    floor_rgb1: tuple[float, float, float]
    floor_rgb2: tuple[float, float, float]
    floor_tile: float
    light_dir: np.ndarray
    light_diffuse: float
    light_ambient: float
    light_specular: float
    headlight_ambient: float
    headlight_diffuse: float
    shadows: bool
    object_checker: bool
    texture_seed: int = 0

    @property
    def floor_mean(self) -> np.ndarray:
        return (np.asarray(self.floor_rgb1) + np.asarray(self.floor_rgb2)) / 2.0

    def to_meta(self) -> tuple[dict, dict]:
        """``(floor, light)`` JSON-able descriptions."""
        floor = {"texture": self.floor_kind, "rgb1": [round(c, 3) for c in self.floor_rgb1],
                 "rgb2": [round(c, 3) for c in self.floor_rgb2], "tile_m": round(self.floor_tile, 3),
                 "object_checker": self.object_checker}
        light = {"direction": [round(float(c), 4) for c in self.light_dir], "diffuse": round(self.light_diffuse, 3),
                 "ambient": round(self.light_ambient, 3), "specular": round(self.light_specular, 3),
                 "headlight_ambient": round(self.headlight_ambient, 3),
                 "headlight_diffuse": round(self.headlight_diffuse, 3), "shadows": self.shadows}
        return floor, light


@dataclass
class Scenario:
    """One clip to simulate: category, camera, look, objects and the video format."""

    category: str
    camera: CameraSpec
    look: Look
    objects: list[ObjectSpec]
    width: int
    height: int
    fps: float
    duration: float

    @property
    def n_frames(self) -> int:
        return max(1, int(round(self.duration * self.fps)))

    @property
    def min_pixels(self) -> float:
        """Fewest pixels an unoccluded object in full view must cover at this resolution."""
        return MIN_PIXELS * self.width * self.height / REFERENCE_AREA


# ---------------------------------------------------------------------------------------------
# Projection helper
# ---------------------------------------------------------------------------------------------


def project(points: np.ndarray, K: np.ndarray, E: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points (..., 3) m -> pixels (..., 2) and depth along the optical axis (...) m, through
    intrinsics ``K (3, 3)`` and world-to-camera extrinsics ``E (4, 4)`` (OpenCV frame)."""
    xc = np.asarray(points, dtype=np.float64) @ E[:3, :3].T + E[:3, 3]
    z = xc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([K[0, 0] * xc[..., 0] / z + K[0, 2], K[1, 1] * xc[..., 1] / z + K[1, 2]], axis=-1)
    return uv, z


class View:
    """Pinhole projection of a :class:`CameraSpec` at ``width`` x ``height`` px
    (:mod:`pipeline.camera` conventions)."""

    def __init__(self, cam: CameraSpec, width: int, height: int) -> None:
        self.spec = cam
        self.width, self.height = width, height
        R, t = extrinsics(cam.camera())
        self.E = np.eye(4)
        self.E[:3, :3], self.E[:3, 3] = R, t
        self.K = intrinsics(cam.fov, width, height)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (..., 3) m -> pixels (..., 2) and depth (...) m along the optical axis."""
        return project(points, self.K, self.E)

    def disc(self, point: np.ndarray, radius: float) -> tuple[np.ndarray, float, float]:
        """Projected centre (2,), approximate projected radius (px) and depth (m) of a ball."""
        uv, z = self.project(point)
        r = self.K[1, 1] * radius / z if z > 1e-6 else float("inf")
        return uv, float(r), float(z)

    def inside(self, point: np.ndarray, radius: float, margin: float = 0.0) -> bool:
        """The ball's projected disc lies in the image, ``margin`` px from its border."""
        (u, v), r, z = self.disc(point, radius)
        return bool(z > 0.05 and u - r >= margin and v - r >= margin and u + r <= self.width - margin
                    and v + r <= self.height - margin)

    def outside(self, point: np.ndarray, radius: float) -> bool:
        """The ball's projected disc misses the image entirely (behind the camera counts)."""
        (u, v), r, z = self.disc(point, radius)
        if z <= 0.05:
            return True
        return bool(u + r < 0 or v + r < 0 or u - r > self.width or v - r > self.height)


# ---------------------------------------------------------------------------------------------
# Looks
# ---------------------------------------------------------------------------------------------


def _hsv(h: float, s: float, v: float) -> tuple[float, float, float]:
    i = int(h * 6.0) % 6
    f = h * 6.0 - math.floor(h * 6.0)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    return [(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)][i]


def _choice(rng: np.random.Generator, probs: dict[str, float]) -> str:
    keys = list(probs)
    p = np.asarray([probs[k] for k in keys], dtype=np.float64)
    return keys[int(rng.choice(len(keys), p=p / p.sum()))]


def sample_look(rng: np.random.Generator, limits: EngineLimits) -> Look:
    """Random floor texture and colours, light and headlight."""
    kind = _choice(rng, limits.floor_kinds)
    h, s, v = rng.uniform(0, 1), rng.uniform(0.0, 0.6), rng.uniform(0.25, 0.85)
    rgb1 = _hsv(h, s, v)
    if rng.random() < 0.3:   # a second hue
        rgb2 = _hsv(rng.uniform(0, 1), rng.uniform(0.0, 0.6), rng.uniform(0.25, 0.85))
    else:                    # the same hue, lighter or darker
        c = rng.uniform(0.08, 0.45) * rng.choice([-1.0, 1.0])
        rgb2 = tuple(float(np.clip(x * (1 + c), 0, 1)) for x in rgb1)
    el, az = math.radians(rng.uniform(25, 90)), rng.uniform(0, 2 * math.pi)
    light_dir = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), -math.sin(el)])
    return Look(floor_kind=kind, floor_rgb1=tuple(float(x) for x in rgb1), floor_rgb2=tuple(float(x) for x in rgb2),
                floor_tile=float(rng.uniform(0.4, 2.5)), light_dir=light_dir,
                light_diffuse=float(rng.uniform(0.35, 0.8)), light_ambient=float(rng.uniform(0.0, 0.25)),
                light_specular=float(rng.uniform(0.0, 0.3)), headlight_ambient=float(rng.uniform(0.1, 0.45)),
                headlight_diffuse=float(rng.uniform(0.1, 0.45)), shadows=bool(rng.random() < limits.p_shadows),
                object_checker=bool(rng.random() < 0.5), texture_seed=int(rng.integers(2 ** 31)))


def object_colour(rng: np.random.Generator, look: Look, low_contrast: bool) -> tuple[float, float, float]:
    """An object colour: saturated and random, or (``low_contrast``) within ~0.04-0.12 per
    channel of the floor's mean colour."""
    if not low_contrast:
        return tuple(float(c) for c in _hsv(rng.uniform(0, 1), rng.uniform(0.3, 1.0), rng.uniform(0.35, 1.0)))
    base = look.floor_mean
    for _ in range(20):
        c = np.clip(base + rng.uniform(-0.12, 0.12, size=3), 0, 1)
        if np.abs(c - base).mean() >= 0.04:
            break
    return tuple(float(x) for x in c)


def _periodic_noise(rng: np.random.Generator, size: int, cycles: float) -> np.ndarray:
    """(size, size) float64 smooth noise in [0, 1] that tiles seamlessly (white noise low-passed
    in Fourier space; ``cycles`` = features per tile)."""
    f = np.fft.fftfreq(size) * size
    r2 = f[:, None] ** 2 + f[None, :] ** 2
    spec = np.fft.fft2(rng.normal(size=(size, size))) * np.exp(-r2 / (2 * cycles ** 2))
    n = np.real(np.fft.ifft2(spec))
    return (n - n.min()) / max(n.max() - n.min(), 1e-12)


def floor_image(look: Look, size: int = 256) -> np.ndarray:
    """(size, size, 3) uint8 RGB image of one floor tile that repeats seamlessly, drawn from
    ``look.texture_seed``.

    Kinds: ``checker`` (2-8 squares a side), ``noise`` (smooth blobs plus fine grain),
    ``stripes`` (wood-like: wavy stripes), ``flat``/``gradient`` (a flat colour / a linear ramp)."""
    rng = np.random.default_rng(look.texture_seed)
    a, b = np.asarray(look.floor_rgb1), np.asarray(look.floor_rgb2)
    y, x = np.mgrid[0:size, 0:size] / size
    kind = look.floor_kind
    if kind == "checker":
        k = int(rng.integers(1, 5)) * 2
        w = ((np.floor(x * k) + np.floor(y * k)) % 2).astype(np.float64)
    elif kind == "noise":
        w = 0.75 * _periodic_noise(rng, size, rng.uniform(2, 10)) + 0.25 * rng.random((size, size))
    elif kind == "stripes":
        k = int(rng.integers(4, 14))
        warp = _periodic_noise(rng, size, 3.0) - 0.5
        w = 0.5 + 0.5 * np.sin(2 * math.pi * (k * y + rng.uniform(0.5, 2.0) * warp))
        w = w ** rng.uniform(0.5, 2.0)
    elif kind == "gradient":
        w = 0.5 - 0.5 * np.cos(2 * math.pi * x)   # periodic ramp
    else:
        w = np.zeros((size, size))
    img = a[None, None] + (b - a)[None, None] * w[..., None]
    return np.clip(np.round(img * 255), 0, 255).astype(np.uint8)

