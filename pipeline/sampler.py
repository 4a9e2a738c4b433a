"""Random scenes for the synthetic dataset, with the paper's filters (docs/design.md §5, stage
``sample_configs``).

A scene is drawn in two steps, so that the accepted scenes follow the configured
distributions of object count and shape exactly:

1. its *composition* (:func:`pipeline.sample_config.sample_composition`): the number of objects
   and their shapes. Splits ``train``/``val``/``test`` never hold a held-out 4-object composition
   (``held_out``, resampled); split ``test_comp`` holds only those.
2. its *layout* (camera, sizes, poses, velocities, materials), redrawn until the scene
   passes the filters (:class:`SceneFilter`):

   * every object covers at least ``min_pixel_fraction`` of the first frame, occlusion
     included (segmentation rendered at ``width`` x ``height``; the paper drops objects under
     8,000 px of 480x320, ~5 %);
   * no initial interpenetration: MuJoCo finds no contact deeper than
     ``overlap_tolerance`` at t = 0 (objects on the floor touch it at distance 0);
   * with ``keep_in_view``: every object's centre stays inside the image for the whole clip.

Layouts are made for motion that is visible for the whole clip: objects stand on the visible
part of the floor (or hang above it, ``p_airborne``, and fall), and are launched towards
another visible floor point. With probability ``p_ramp`` a scene also gets one ramp (a static
box, :func:`pipeline.static.ramp`) on the visible floor, and one of its objects starts on the
ramp's upper half, resting on it (spheres and lying cylinders roll, boxes and standing
cylinders slide or are pushed down the slope). The ramp's random numbers come from a child
generator of the scene's (``rng.spawn``), drawn only when ``p_ramp > 0``: with ``p_ramp = 0``
every scene is exactly what it was before ramps existed. Objects are ordered left to right in
the first frame, so names (``<shape>_<index>``) follow from the video. Every scene has its own seed
(:func:`pipeline.sample_config.scene_seed`), so any one scene can be regenerated alone. The params
(:class:`pipeline.sample_config.SampleConfig`) are :mod:`pipeline.sample_config`.

Example::

    cfg = typed_section(params, "sample", SampleConfig)   # pipeline.params, pipeline.sample_config
    for sid, split, scene in sample_dataset(cfg, seed=0):
        print(sid, split, scene.composition)
"""

from __future__ import annotations

import atexit
import math
from collections import Counter
from dataclasses import dataclass
from typing import Iterator

import mujoco
import numpy as np

from pipeline.camera import project, unproject
from pipeline.engine import set_camera, set_object_size
from pipeline.geometry import bounding_radius
from pipeline.mjcf import SimOptions, compile_model, initial_state
from pipeline.render import FrameRenderer, shared_gl
from pipeline.rotation import quat_mul, quat_to_mat, yaw_quat
from pipeline.sample_config import Range, SampleConfig, sample_composition, scene_seed, split_names
from pipeline.scene import SHAPES, Camera, Decimals, Scene
from pipeline.shards import scene_id
from pipeline.simulate import rollout
from pipeline.static import ramp as make_ramp
from pipeline.static import support_height


class SamplingError(RuntimeError):
    """No layout passed the filters within ``max_tries`` (one line: scene and composition)."""


# --------------------------------------------------------------------------- layout
def _random_quat(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def _grid(x: float, step: float) -> float:
    """Round a size to a grid so that half of it prints exactly at 3 decimals."""
    return max(step, round(x / step) * step)


def _size(rng: np.random.Generator, shape: str, extent: Range) -> dict[str, float]:
    e = lambda: float(rng.uniform(*extent))  # noqa: E731
    if shape == "sphere":
        return {"radius": round(_grid(e() / 2, 0.001), 3)}
    if shape == "cylinder":
        return {"radius": round(_grid(e() / 2, 0.001), 3), "height": round(_grid(e(), 0.002), 3)}
    return {"width": round(_grid(e(), 0.002), 3), "depth": round(_grid(e(), 0.002), 3),
            "height": round(_grid(e(), 0.002), 3)}


def _floor_point(cam, u: float, v: float, z: float, width: int, height: int,
                 max_distance: float | None = None) -> np.ndarray | None:
    """World point at height ``z`` seen at pixel (u, v); None above the horizon or, with
    ``max_distance`` (m), farther than that from the eye's ground point."""
    eye = np.asarray(cam.eye, dtype=np.float64)
    ray = unproject(np.array([u, v]), np.array(1.0), cam, width, height) - eye
    if ray[2] >= -1e-6:
        return None
    point = eye + (z - eye[2]) / ray[2] * ray
    if max_distance is not None and math.hypot(*(point - eye)[:2]) > max_distance:
        return None
    return point


def _sample_layout(rng: np.random.Generator, cfg: SampleConfig, shapes: list[str],
                   ramp_rng: np.random.Generator | None = None, decimals: Decimals | None = None) -> dict | None:
    """One candidate scene dict for ``shapes`` (None if a drawn pixel is above the horizon).

    ``ramp_rng``: if given, the scene gets a ramp and one object on it (:func:`_place_on_ramp`),
    drawn from this generator only (``rng`` is used exactly as without a ramp)."""
    W, H = cfg.width, cfg.height
    cam = {"height": round(float(rng.uniform(*cfg.camera_height)), 3),
           "pitch": round(float(rng.uniform(*cfg.camera_pitch)), 1),
           "fov": round(float(rng.uniform(*cfg.camera_fov)), 1)}
    camera = Camera.model_validate(cam)
    m = cfg.placement_margin

    def pixel() -> tuple[float, float]:
        return float(rng.uniform(m, 1 - m)) * W, float(rng.uniform(0.3, 1 - m)) * H

    objects, moving = [], []
    for shape in shapes:
        size = _size(rng, shape, cfg.extent)
        yaw = float(rng.uniform(-math.pi, math.pi))
        airborne = rng.random() < cfg.p_airborne
        rest = rng.random() < cfg.p_at_rest
        if airborne:
            quat = _random_quat(rng)
            z_floor = bounding_radius(shape, size)
            z = z_floor + float(rng.uniform(*cfg.drop_height))
        else:
            quat = yaw_quat(yaw)
            if shape == "sphere":
                z_floor = size["radius"]
            elif shape == "cylinder" and rng.random() < cfg.p_lying:  # on its side
                quat = quat_mul(quat, [math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0])
                z_floor = size["radius"]
            else:
                z_floor = size["height"] / 2
            z = z_floor
        start = _floor_point(camera, *pixel(), z_floor, W, H, cfg.max_floor_distance)
        target = _floor_point(camera, *pixel(), z_floor, W, H, cfg.max_floor_distance)
        if start is None or target is None:
            return None
        vel, omega = np.zeros(3), np.zeros(3)
        moving.append(airborne or not rest)
        if not rest:
            d = (target - start)[:2]
            d = d / max(np.linalg.norm(d), 1e-9)
            vel[:2] = float(rng.uniform(*cfg.speed)) * d
            if airborne:
                vel[2] = float(rng.uniform(*cfg.vertical_speed))
            w = float(rng.uniform(*cfg.spin))
            if airborne:
                axis = rng.normal(size=3)
                omega = w * axis / np.linalg.norm(axis)
            else:
                omega[2] = w * float(rng.choice([-1.0, 1.0]))
        objects.append({
            "shape": shape, "size": size,
            "mass": float(rng.uniform(*cfg.mass)),
            "position": [float(start[0]), float(start[1]), float(z)],
            "orientation": [float(c) for c in quat],
            "linear_velocity": vel.tolist(), "angular_velocity": omega.tolist(),
            "material": {"sliding_friction": float(rng.uniform(*cfg.sliding_friction)),
                         "rolling_friction": float(rng.uniform(*cfg.rolling_friction)),
                         "damping": float(rng.uniform(*cfg.damping))},
        })
    static = []
    if ramp_rng is not None:
        placed = _place_on_ramp(ramp_rng, cfg, camera, objects, decimals or Decimals())
        if placed is None:
            return None
        static, k, moves = placed
        moving[k] = moves
    if not any(moving):  # a still life: launch one object so that every scene has motion
        o = objects[int(rng.integers(len(objects)))]
        ang = float(rng.uniform(0, 2 * math.pi))
        o["linear_velocity"] = [float(rng.uniform(*cfg.speed)) * f for f in (math.cos(ang), math.sin(ang))] + [0.0]
    # names follow the video: objects ordered left to right in the first frame
    uv, _ = project(np.array([o["position"] for o in objects]), camera, W, H)
    objects = [objects[i] for i in np.argsort(uv[:, 0], kind="stable")]
    data = {"version": 1, "duration": cfg.duration, "fps": cfg.fps, "gravity": cfg.gravity,
            "camera": cam, "objects": objects, "effects": []}
    if static:
        data["static"] = static
    return data


def _place_on_ramp(rng: np.random.Generator, cfg: SampleConfig, camera: Camera, objects: list[dict],
                   decimals: Decimals) -> tuple[list[dict], int, bool] | None:
    """Draw a ramp on the visible floor and move one of ``objects`` (changed in place) onto
    its upper half, touching its top surface (2 mm clearance for the rounding of the text).

    Spheres and cylinders lying across the slope roll; a box or a standing cylinder slides by
    itself only when its friction is below tan(angle). An object that moves by itself starts
    at rest with probability ``p_at_rest``; any other is pushed down the slope (half of a
    ``speed`` draw). Returns ``(static list with the ramp dict, object index, True: that object
    moves)``, or None if the ramp's pixel is above the horizon.
    """
    W, H, m = cfg.width, cfg.height, cfg.placement_margin
    angle = float(rng.uniform(*cfg.ramp_angle))
    length = round(_grid(float(rng.uniform(*cfg.ramp_length)), 0.002), 3)
    width = round(_grid(float(rng.uniform(*cfg.ramp_width)), 0.002), 3)
    yaw = float(rng.uniform(-180.0, 180.0))
    th = math.radians(angle)
    u, v = float(rng.uniform(m, 1 - m)) * W, float(rng.uniform(0.3, 1 - m)) * H
    top = _floor_point(camera, u, v, length / 2 * math.sin(th), W, H, cfg.max_floor_distance)
    if top is None:
        return None
    box = make_ramp(angle, length, width, cfg.ramp_thickness, float(top[0]), float(top[1]), yaw)
    # the ramp as the canonical text stores it: the object is placed on that one
    box = box.model_copy(update={
        "position": tuple(round(c, decimals.position) for c in box.position),
        "orientation": tuple(round(c, decimals.orientation) for c in box.orientation)})
    R = quat_to_mat(box.orientation)
    qr = np.asarray(box.orientation, dtype=np.float64) / np.linalg.norm(box.orientation)
    downhill, normal = R[:, 0], R[:, 2]
    k = int(rng.integers(len(objects)))
    o = objects[k]
    shape, size = o["shape"], o["size"]
    # a point on the centre line of the top surface, on the upper half
    s = float(rng.uniform(0.1, 0.35)) * length
    p = np.asarray(box.position) + cfg.ramp_thickness / 2 * normal - s * downhill
    z = support_height(box, float(p[0]), float(p[1]))
    if z is None:  # pragma: no cover (p lies on the top face)
        return None
    p[2] = z
    spin = yaw_quat(float(rng.uniform(-math.pi, math.pi)))
    rolls = shape == "sphere"
    if shape == "sphere":
        quat, lift = quat_mul(qr, spin), size["radius"]
    elif shape == "cylinder" and rng.random() < cfg.p_lying:  # axis across the slope: rolls
        quat, lift, rolls = quat_mul(qr, [math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0]), size["radius"], True
    else:
        quat, lift = quat_mul(qr, spin), size["height"] / 2
    centre = p + (lift + 0.002) * normal
    slides = o["material"]["sliding_friction"] < math.tan(th)
    vel = np.zeros(3)
    if not (rolls or slides) or rng.random() >= cfg.p_at_rest:
        vel = 0.5 * float(rng.uniform(*cfg.speed)) * downhill
    o.update({"position": [float(c) for c in centre], "orientation": [float(c) for c in quat],
              "linear_velocity": vel.tolist(), "angular_velocity": [0.0, 0.0, 0.0]})
    static = [{"shape": "box", "size": box.size.model_dump(), "position": list(box.position),
               "orientation": list(box.orientation)}]
    return static, k, True


# --------------------------------------------------------------------------- filters
class SceneFilter:
    """The paper's filters, with one compiled template model for the first-frame
    segmentation (a renderer per candidate would cost ~100 ms; this costs ~2 ms).

    The template holds 6 bodies of each shape; a candidate scene is shown by editing the
    template's geom sizes (and ``geom_rbound`` / ``geom_aabb``), poses and camera in place;
    unused bodies are parked behind the camera. ``tests/test_sampler.py`` checks that its
    segmentation equals a full render of the compiled scene. A scene with static geometry
    (a ramp) is checked on its own compiled model instead (:meth:`static_first_frame`): the
    template has no static geoms.

    Use as a context manager, or call :meth:`close`.
    """

    MAX_PER_SHAPE = 6

    def __init__(self, cfg: SampleConfig, options: SimOptions | None = None):
        self.cfg = cfg
        self.options = (options or SimOptions()).model_copy(update={"textured": False})
        template = Scene.from_dict({
            "camera": {"height": 1.0},
            "objects": [{"shape": s, "size": {"sphere": {"radius": 0.1}, "cylinder": {"radius": 0.1, "height": 0.1},
                                              "box": {"width": 0.1, "depth": 0.1, "height": 0.1}}[s],
                         "mass": 1.0, "position": [0.0, 0.0, 1.0]}
                        for s in SHAPES for _ in range(self.MAX_PER_SHAPE)]})
        self.model = compile_model(template, self.options)
        self.slots = {s: [i * self.MAX_PER_SHAPE + j for j in range(self.MAX_PER_SHAPE)] for i, s in enumerate(SHAPES)}
        self.geoms = [int(self.model.body_geomadr[b + 1]) for b in range(len(template.objects))]
        self.renderer = FrameRenderer(self.model, cfg.width, cfg.height)
        self.rejected: Counter[str] = Counter()

    def close(self) -> None:
        self.renderer.close()

    def __enter__(self) -> "SceneFilter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ first frame
    def _show(self, scene: Scene) -> np.ndarray:
        """Put the scene's objects and camera into the template (kinematics and camera
        updated); returns the lookup table template object -> scene object index (-1 unused)."""
        m = self.model
        n_slots = len(self.geoms)
        qpos = np.zeros((n_slots, 7))
        qpos[:, 0] = 10.0 * np.arange(n_slots)
        qpos[:, 1:3] = (-1000.0, 100.0)  # parked far behind the camera, clear of the floor
        qpos[:, 3] = 1.0
        lut = np.full(n_slots + 1, -1, dtype=np.int8)  # template object index -> scene index
        free = {s: list(v) for s, v in self.slots.items()}
        for i, obj in enumerate(scene.objects):
            slot = free[obj.shape].pop(0)
            g = self.geoms[slot]
            set_object_size(m, slot + 1, g, obj.shape, obj.size)
            q = np.asarray(obj.orientation, dtype=np.float64)
            qpos[slot] = [*obj.position, *(q / np.linalg.norm(q))]
            lut[slot] = i
        set_camera(m, 0, scene.camera)
        self.renderer.set_pose(qpos)
        return lut

    def first_frame_segmentation(self, scene: Scene) -> np.ndarray:
        """(H, W) int8 segmentation of the scene's first frame (object index, -1 background)."""
        lut = self._show(scene)
        seg = self.renderer.segmentation()
        return lut[seg.astype(np.int64)]  # -1 (background) indexes the last entry, also -1

    def initial_overlap(self, scene: Scene) -> float:
        """Deepest interpenetration at t = 0 (MuJoCo collision detection on the template), m."""
        self._show(scene)
        data = self.renderer.data
        mujoco.mj_collision(self.model, data)
        return _penetration(data)

    # ------------------------------------------------------------------ checks
    def static_first_frame(self, scene: Scene, model: mujoco.MjModel | None = None) -> tuple[np.ndarray, float]:
        """First-frame segmentation ``(H, W) int8`` and deepest initial interpenetration (m) of
        a scene with static geometry, from its compiled model (the template has no static
        geoms): the ramp occludes objects and collides with them as in the full render."""
        model = model or compile_model(scene, self.options)
        qpos, _ = initial_state(scene)
        with FrameRenderer(model, self.cfg.width, self.cfg.height, shared_gl()) as r:
            r.set_pose(qpos.reshape(-1, 7))
            seg = r.segmentation()
        data = mujoco.MjData(model)
        mujoco.mj_resetDataKeyframe(model, data, 0)
        mujoco.mj_forward(model, data)
        return seg, _penetration(data)

    def check(self, scene: Scene) -> str | None:
        """Name of the first failed filter (``small``, ``overlap``, ``leaves_view``,
        ``unstable``), or None if the scene passes all."""
        cfg = self.cfg
        model = None
        if scene.static:
            model = compile_model(scene, self.options)
            seg, overlap = self.static_first_frame(scene, model)
        else:
            seg = self.first_frame_segmentation(scene)
        counts = np.bincount(seg[seg >= 0].astype(np.int64), minlength=len(scene.objects))
        if counts.min() < cfg.min_pixels:
            return "small"
        if (overlap if scene.static else self.initial_overlap(scene)) > cfg.overlap_tolerance:
            return "overlap"
        if cfg.keep_in_view:
            model = model or compile_model(scene, self.options)
            trace = rollout(model, len(scene.objects), scene.n_frames, scene.fps, record_contacts=False)
            pos = trace.position
            if not np.isfinite(pos).all() or np.abs(pos).max() > 100:
                return "unstable"
            uv, depth = project(pos, scene.camera, cfg.width, cfg.height)
            inside = (depth > 0) & (uv[..., 0] >= 0) & (uv[..., 0] <= cfg.width) & (uv[..., 1] >= 0) & (uv[..., 1] <= cfg.height)
            if not inside.all():
                return "leaves_view"
        return None


def initial_overlap(scene: Scene, options: SimOptions | None = None) -> float:
    """Deepest interpenetration at t = 0 according to MuJoCo's collision detection, m
    (0 when nothing penetrates)."""
    model = compile_model(scene, options)
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    mujoco.mj_forward(model, data)
    return _penetration(data)


def _penetration(data: mujoco.MjData) -> float:
    """Deepest penetration among ``data``'s contacts, m (0 if none)."""
    return float(max(0.0, -data.contact.dist[: data.ncon].min())) if data.ncon else 0.0


def _canonical(scene: Scene, decimals: Decimals | None) -> Scene:
    """The scene as its quantised text stores it (fixed decimals, default :class:`Decimals`:
    the model's targets, unchanged by issue 35's significant-digit canonical text)."""
    return scene.rounded(decimals or Decimals())


# --------------------------------------------------------------------------- public API
def sample_scene(rng: np.random.Generator, cfg: SampleConfig, split: str,
                 filt: SceneFilter | None = None, decimals: Decimals | None = None) -> Scene:
    """Draw one scene of ``split`` that passes the filters.

    Args:
        rng: the scene's generator (``np.random.default_rng(scene_seed(seed, index))``).
        cfg: sampling params.
        split: ``train``, ``val``, ``test``, ``test_comp`` or ``test_many``.
        filt: a :class:`SceneFilter` to reuse (one is made and closed if None).
        decimals: rounding of the quantised text (params ``scene.decimals``, default
            :class:`Decimals`); the filters see the scene as that text stores it.
    Returns:
        the scene as its canonical YAML represents it (rounded).
    Raises:
        SamplingError: no layout passed within ``cfg.max_tries`` tries (``cfg.many_max_tries`` for
            ``test_many``: six objects that each show 2.5 % of the frame took up to ~900 tries).
    """
    own = filt is None
    filt = filt or SceneFilter(cfg)
    try:
        shapes = sample_composition(rng, cfg, split)
        ramp_rng = None
        if cfg.p_ramp > 0:  # a child stream: rng's own draws stay as without ramps
            ramp_rng = rng.spawn(1)[0]
            if not ramp_rng.random() < cfg.p_ramp:
                ramp_rng = None
        tries = cfg.many_max_tries if split == "test_many" else cfg.max_tries
        for _ in range(tries):
            data = _sample_layout(rng, cfg, shapes, ramp_rng, decimals)
            if data is None:
                filt.rejected["horizon"] += 1
                continue
            scene = _canonical(Scene.from_dict(data), decimals)
            reason = filt.check(scene)
            if reason is None:
                return scene
            filt.rejected[reason] += 1
        raise SamplingError(f"no layout of {sorted(shapes)} passed the filters in {tries} tries "
                            f"(rejected: {dict(filt.rejected)}); lower sample.min_pixel_fraction or "
                            f"raise sample.extent")
    finally:
        if own:
            filt.close()


def iter_dataset(cfg: SampleConfig, seed: int, filt: SceneFilter | None = None,
                 decimals: Decimals | None = None) -> Iterator[tuple[str, str, Scene]]:
    """Yield ``(scene_id, split, scene)`` for every scene index in order (see
    :func:`sample_dataset`)."""
    own = filt is None
    filt = filt or SceneFilter(cfg)
    try:
        for i, split in enumerate(split_names(cfg)):
            rng = np.random.default_rng(scene_seed(seed, i))
            yield scene_id(i), split, sample_scene(rng, cfg, split, filt, decimals)
    finally:
        if own:
            filt.close()


@dataclass(frozen=True)
class SampleChunk:
    """Scenes ``start <= index < stop`` of the dataset drawn with ``seed`` (a unit of work for
    :func:`sample_chunk` in a process pool)."""

    cfg: SampleConfig
    seed: int
    start: int
    stop: int
    decimals: Decimals | None = None
    options: SimOptions | None = None


_FILTERS: dict[str, SceneFilter] = {}
"""This process's filters, by (sample params, sim options): made once, reused by every chunk."""


def _process_filter(cfg: SampleConfig, options: SimOptions | None) -> SceneFilter:
    key = cfg.model_dump_json() + (options.model_dump_json() if options else "")
    if key not in _FILTERS:
        _FILTERS[key] = SceneFilter(cfg, options)
        if len(_FILTERS) == 1:  # after the filter's GL context: atexit runs this before EGL terminates
            atexit.register(_close_filters)
    return _FILTERS[key]


def _close_filters() -> None:
    for filt in _FILTERS.values():
        filt.close()
    _FILTERS.clear()


def sample_chunk(chunk: SampleChunk) -> tuple[list[tuple[str, str, Scene]], Counter[str]]:
    """Scenes ``chunk.start .. chunk.stop - 1`` exactly as :func:`iter_dataset` yields them,
    with this process's :class:`SceneFilter`.

    The filter keeps no state from one scene to the next (every candidate resets the whole
    template), so a scene does not depend on which scenes the process drew before: the stage
    gives the same configs with any number of workers.

    Returns:
        ``[(scene_id, split, scene)]`` in index order, and the rejected layouts of these
        scenes by filter name (``horizon``, ``small``, ``overlap``, ``leaves_view``, ``unstable``).
    """
    filt = _process_filter(chunk.cfg, chunk.options)
    # count this chunk's rejections apart, keys in order of first occurrence (merged in chunk
    # order they give the same dict, order included, as one sequential pass)
    total, filt.rejected = filt.rejected, Counter()
    splits = split_names(chunk.cfg)
    out = []
    try:
        for i in range(chunk.start, chunk.stop):
            rng = np.random.default_rng(scene_seed(chunk.seed, i))
            out.append((scene_id(i), splits[i], sample_scene(rng, chunk.cfg, splits[i], filt, chunk.decimals)))
    finally:
        rejected, filt.rejected = filt.rejected, total
        total.update(rejected)
    return out, rejected


def sample_dataset(cfg: SampleConfig, seed: int, decimals: Decimals | None = None) -> list[tuple[str, str, Scene]]:
    """All scenes of a dataset: ``[(scene_id, split, scene)]``, train, val, test, test_comp, test_many.

    Scene ``i`` depends only on ``(seed, i)`` (:func:`pipeline.sample_config.scene_seed`).
    """
    return list(iter_dataset(cfg, seed, decimals=decimals))
