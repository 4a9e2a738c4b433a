"""Scene language -> MJCF with ``dm_control.mjcf`` (docs/design.md §3).

One body per object, each with a free joint and one geom, named ``<shape>_<index>``; a floor
plane ``floor``; static geometry (``scene.static``) as world geoms ``static_<index>`` (no
body, no joint: bodies 1..n stay the objects, and the renderer's segmentation shows them as
background, -1); one camera ``main``; a keyframe ``init`` carrying the initial qpos/qvel, so
the MJCF text alone reproduces the scene.

Friction semantics (MuJoCo docs, "Contact parameters"): when two geoms touch, MuJoCo uses the
parameters of the geom with the higher ``priority``; at equal priority it takes the
element-wise maximum of the two friction vectors. Object geoms get ``priority=1`` and the
floor ``priority=0``, so an object-floor contact uses the object's friction exactly: the
scene's ``sliding_friction`` *is* the effective Coulomb coefficient against the floor. Two
objects in contact use the larger of their coefficients. ``condim=6`` enables rolling
friction (MuJoCo's rolling coefficient, m); torsional friction is 0 in the base model.
A frictionless object (``sliding_friction: 0``) gets ``condim=1``: MuJoCo's pyramidal cone
with a zero coefficient and ``condim > 1`` is degenerate and blows up (a box spinning on the
floor was launched metres into the air); with ``condim=1`` it slides and spins freely.
``damping`` is the free joint's ``damping`` (applies to all 6 DoF).
Looks: every scene is drawn with one fixed look (grey checker floor, :data:`OBJECT_COLOURS`, one
light). :class:`Appearance` (an optional argument of :func:`build_mjcf`) replaces it for rendered
benchmark clips (``pipeline.truthsets``): floor texture and colours, object colours, the light and
the headlight. Without it the MJCF text is exactly what it was before it existed.
Static geoms get the floor's contact parameters (``priority=0``, ``condim=3``,
``floor_friction``, ``floor_solref``), so an object on a ramp slides with its own
``sliding_friction`` exactly as on the floor. A static geom with a ``restitution`` (a springy
stop, an air track's bumper) takes over its contacts instead (``priority=2``): frictionless
(``condim=1``), its ``solref`` that of the ``restitution`` effect for its ``e``
(:func:`pipeline.effects.restitution_solref`).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

import pipeline  # noqa: F401  (sets MUJOCO_GL before dm_control is imported)
from dm_control import mjcf
import mujoco

from pipeline.camera import camera_pose
from pipeline.effects import apply_effects, restitution_solref
from pipeline.geometry import geom_size
from pipeline.scene import Scene

STATIC_COLOUR = (0.55, 0.5, 0.45, 1.0)
"""RGBA of static geometry: a neutral warm grey, distinct from the floor and the objects."""

OBJECT_COLOURS = [
    (0.85, 0.25, 0.2), (0.2, 0.45, 0.85), (0.95, 0.75, 0.15), (0.3, 0.7, 0.3),
    (0.7, 0.3, 0.75), (0.2, 0.75, 0.75), (0.9, 0.5, 0.2), (0.6, 0.6, 0.6),
]


DEFAULT_TIMESTEP = 1.0 / 600.0
"""Physics timestep, s: the params value ``sim.timestep`` (1/600 s, 20 steps per 30 fps frame,
10 per 60 fps frame). ``dynamics simulate``, the stages and the library all default to it
(``tests/test_physics.py`` checks that params.yaml agrees)."""


class SimOptions(BaseModel):
    """Simulation options (params section ``sim``).

    ``timestep`` is an upper bound: a scene whose frame interval ``1 / fps`` is not a whole
    number of steps is simulated at the largest smaller timestep that divides it
    (:func:`frame_timestep`), so that every frame is a state at its stamped time.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    timestep: float = Field(DEFAULT_TIMESTEP, gt=0, le=0.1, allow_inf_nan=False, description="s")
    integrator: str = "implicitfast"
    cone: str = Field("pyramidal", pattern="^(pyramidal|elliptic)$",
                      description="MuJoCo friction cone: pyramidal (the default) or elliptic (isotropic Coulomb friction)")
    floor_friction: float = Field(0.5, ge=0)
    floor_solref: tuple[float, float] = (0.02, 1.0)
    object_solref: tuple[float, float] = (0.02, 1.0)
    offscreen_size: int = Field(640, gt=0, description="px, max render width/height")
    textured: bool = True


RGB = tuple[float, float, float]


class Appearance(BaseModel):
    """The look of a rendered scene beyond the scene language (no effect on the physics).

    ``build_mjcf(scene, options)`` without an ``Appearance`` draws the project's fixed look; the
    defaults here are that look, but the MJCF text is only guaranteed unchanged without one.
    Colours are RGB in [0, 1].

    Attributes:
        floor_texture: ``checker`` / ``gradient`` / ``flat`` (MuJoCo builtin textures of
            ``floor_rgb1`` and ``floor_rgb2``), or ``png`` (the image ``floor_png``).
        floor_rgb1, floor_rgb2: the builtin texture's two colours.
        floor_texrepeat: texture repeats over the floor's 20 m x 20 m (MJCF ``texrepeat``).
        floor_png: PNG file contents (``floor_texture: png``), given to MuJoCo as an asset, so
            compile with ``MjModel.from_xml_string(root.to_xml_string(), root.get_assets())``.
        object_rgb: one colour per object (cycled); empty: :data:`OBJECT_COLOURS`.
        object_checker: objects wear a checker of their colour and a darker one (as by
            default, so that rotation shows); False: plain colour.
        light_dir: direction the directional light shines along (world frame, not normalised).
        light_diffuse, light_ambient, light_specular: the light's colours (``None``: MuJoCo's
            default, not written).
        light_castshadow: the light casts shadows (~15x slower per RGB frame, docs/design.md §10).
        headlight_ambient, headlight_diffuse: the camera headlight's colours.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    floor_texture: Literal["checker", "gradient", "flat", "png"] = "checker"
    floor_rgb1: RGB = (0.42, 0.42, 0.45)
    floor_rgb2: RGB = (0.5, 0.5, 0.53)
    floor_texrepeat: tuple[float, float] = (8.0, 8.0)
    floor_png: bytes | None = None
    object_rgb: tuple[RGB, ...] = ()
    object_checker: bool = True
    light_dir: tuple[float, float, float] = (0.0, 0.3, -1.0)
    light_diffuse: RGB = (0.6, 0.6, 0.6)
    light_ambient: RGB | None = None
    light_specular: RGB | None = None
    light_castshadow: bool = False
    headlight_ambient: RGB = (0.45, 0.45, 0.45)
    headlight_diffuse: RGB = (0.5, 0.5, 0.5)

    @model_validator(mode="after")
    def _png_given(self) -> "Appearance":
        if (self.floor_texture == "png") != (self.floor_png is not None):
            raise ValueError("floor_png: must be given exactly when floor_texture is png")
        return self


def _floor_texture(root: mjcf.RootElement, look: Appearance) -> mjcf.Element:
    """Add the floor's texture asset of an :class:`Appearance` (named ``floor_tex``)."""
    if look.floor_texture == "png":
        return root.asset.add("texture", name="floor_tex", type="2d",
                              file=mjcf.Asset(contents=look.floor_png, extension=".png"))
    return root.asset.add("texture", name="floor_tex", type="2d", builtin=look.floor_texture,
                          rgb1=list(look.floor_rgb1), rgb2=list(look.floor_rgb2), width=64, height=64)


def static_geom_size(geom) -> list[float]:
    """MuJoCo geom ``size`` of a static geom, m: a box's half extents; a plane's half width and
    half depth (what is drawn; it collides as an infinite plane) and 0.1 (grid spacing)."""
    s = geom.size
    if geom.shape == "plane":
        return [s.width / 2.0, s.depth / 2.0, 0.1]
    return [s.width / 2.0, s.depth / 2.0, s.height / 2.0]


def initial_state(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Initial ``qpos (7n,)`` and ``qvel (6n,)`` float64 of the scene's free joints.

    MuJoCo's free joint stores the linear velocity in the world frame and the angular
    velocity in the body frame (MuJoCo docs, "Floating objects"); the scene language gives
    both in the world frame, so ``w_body = R(q)^T w_world``.
    """
    qpos, qvel = [], []
    for o in scene.objects:
        q = np.asarray(o.orientation, dtype=np.float64)
        q = q / np.linalg.norm(q)
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, q)
        w_body = R.reshape(3, 3).T @ np.asarray(o.angular_velocity, dtype=np.float64)
        qpos += [*o.position, *q]
        qvel += [*o.linear_velocity, *w_body]
    return np.asarray(qpos, dtype=np.float64), np.asarray(qvel, dtype=np.float64)


def steps_per_frame(fps: float, timestep: float) -> int:
    """Physics steps per video frame: ``ceil(1 / (fps * timestep))`` (a ratio within 1e-6 of an
    integer counts as that integer, so 30 fps at 1/600 s gives 20)."""
    ratio = 1.0 / (float(fps) * float(timestep))
    return max(1, math.ceil(ratio - 1e-6))


def frame_timestep(fps: float, timestep: float) -> float:
    """The timestep a scene at ``fps`` is simulated with, s (time stamps that match states).

    Frame k is the state after ``k * steps_per_frame(fps, timestep)`` steps, so its time stamp
    ``k / fps`` is exact only if the frame interval is a whole number of steps. When it is
    (within 1e-6 relative), ``timestep`` is returned unchanged, bit for bit (30 and 60 fps at
    the default 1/600 s); otherwise the timestep is lowered to ``1 / (fps * n)`` with
    ``n = steps_per_frame(fps, timestep)``, the largest timestep not above the configured one
    that divides the frame interval (e.g. 25 fps at 1/600 s: 1/625 s; 240 fps: 1/720 s). A
    smaller step never makes the integrator less stable.

    Args:
        fps: frames per second, > 0.
        timestep: configured physics timestep (params ``sim.timestep``), s.
    Returns:
        the timestep to simulate with, s.
    """
    n = steps_per_frame(fps, timestep)
    if abs(n * float(fps) * float(timestep) - 1.0) <= 1e-6:
        return float(timestep)
    return 1.0 / (float(fps) * n)


def build_mjcf(scene: Scene, options: SimOptions | None = None,
               appearance: Appearance | None = None) -> mjcf.RootElement:
    """Build the MJCF element tree of a validated scene.

    The MJCF ``timestep`` is :func:`frame_timestep` of the scene's fps and ``options.timestep``.
    ``appearance`` replaces the fixed look (floor, colours, light); None keeps it, byte for byte.

    Raises:
        SceneError: an effect in ``scene.effects`` is unknown or has bad parameters.
    """
    opt = options or SimOptions()
    root = mjcf.RootElement(model="scene")
    root.compiler.angle = "radian"
    root.option.timestep = frame_timestep(scene.fps, opt.timestep)  # frames fall on steps
    root.option.integrator = opt.integrator
    if opt.cone != "pyramidal":   # the default stays out of the MJCF text
        root.option.cone = opt.cone
    root.option.gravity = [0.0, 0.0, -scene.gravity]
    glob = getattr(root.visual, "global")
    glob.offwidth = opt.offscreen_size
    glob.offheight = opt.offscreen_size
    look = appearance or Appearance()
    root.visual.headlight.ambient = list(look.headlight_ambient)
    root.visual.headlight.diffuse = list(look.headlight_diffuse)

    floor_mat = None
    if opt.textured:
        tex = _floor_texture(root, look)
        repeat = [8, 8] if appearance is None else list(look.floor_texrepeat)
        floor_mat = root.asset.add("material", name="floor_mat", texture=tex, texrepeat=repeat)
    light = {} if appearance is None else {"ambient": look.light_ambient, "specular": look.light_specular}
    root.worldbody.add("light", name="sun", pos=[0, 0, 4], dir=list(look.light_dir), directional=True,
                       castshadow=look.light_castshadow, diffuse=list(look.light_diffuse),
                       **{k: list(v) for k, v in light.items() if v is not None})
    root.worldbody.add("geom", name="floor", type="plane", size=[10, 10, 0.1], material=floor_mat,
                       rgba=None if floor_mat else [0.45, 0.45, 0.48, 1],
                       friction=[opt.floor_friction, 0.0, 0.0], solref=list(opt.floor_solref),
                       priority=0, condim=3)
    for g, name in zip(scene.static, scene.static_names):
        q = np.asarray(g.orientation, dtype=np.float64)
        contact = dict(friction=[opt.floor_friction, 0.0, 0.0], solref=list(opt.floor_solref), priority=0, condim=3)
        if g.restitution is not None:   # a springy stop: its own bounce, frictionless, over the object's material
            contact = dict(friction=[0.0, 0.0, 0.0], priority=2, condim=1,
                           solref=list(restitution_solref(g.restitution, float(root.option.timestep))))
        root.worldbody.add("geom", name=name, type=g.shape, size=static_geom_size(g), pos=list(g.position),
                           quat=(q / np.linalg.norm(q)).tolist(), rgba=list(STATIC_COLOUR), **contact)

    pose = camera_pose(scene.camera)
    root.worldbody.add("camera", name="main", pos=pose.eye.tolist(),
                       xyaxes=[*pose.right.tolist(), *pose.up.tolist()], fovy=scene.camera.fov)

    colours = list(look.object_rgb) or OBJECT_COLOURS
    for i, (obj, name) in enumerate(zip(scene.objects, scene.object_names)):
        colour = colours[i % len(colours)]
        mat = None
        if opt.textured and look.object_checker:
            dark = [c * 0.55 for c in colour]
            tex = root.asset.add("texture", name=f"{name}_tex", type="2d", builtin="checker",
                                 rgb1=list(colour), rgb2=dark, width=32, height=32)
            mat = root.asset.add("material", name=f"{name}_mat", texture=tex, texrepeat=[2, 2],
                                 texuniform=False)
        q = np.asarray(obj.orientation, dtype=np.float64)
        body = root.worldbody.add("body", name=name, pos=list(obj.position), quat=(q / np.linalg.norm(q)).tolist())
        body.add("joint", name=f"{name}_joint", type="free", damping=obj.material.damping)
        body.add("geom", name=f"{name}_geom", type=obj.shape, size=geom_size(obj.shape, obj.size), mass=obj.mass,
                 material=mat, rgba=None if mat else [*colour, 1.0],
                 friction=[obj.material.sliding_friction, 0.0, obj.material.rolling_friction],
                 condim=6 if obj.material.sliding_friction > 0 else 1, priority=1,
                 solref=list(opt.object_solref))

    qpos, qvel = initial_state(scene)
    root.keyframe.add("key", name="init", qpos=qpos.tolist(), qvel=qvel.tolist())

    if scene.effects:
        apply_effects(root, scene)
    return root


def to_xml(scene: Scene, options: SimOptions | None = None, appearance: Appearance | None = None) -> str:
    """MJCF XML text of a scene (what the ``compile_mjcf`` stage stores).

    Raises:
        ValueError: ``appearance`` has a PNG floor (an asset, which plain XML text cannot hold).
    """
    if appearance is not None and appearance.floor_png is not None:
        raise ValueError("appearance: a PNG floor is an asset; to_xml holds builtin textures only")
    return build_mjcf(scene, options, appearance).to_xml_string()


def compile_model(scene_or_xml: Scene | str, options: SimOptions | None = None) -> mujoco.MjModel:
    """Compile a scene (or MJCF text) to an ``MjModel``.

    Raises:
        ValueError: MuJoCo rejects the XML (message from the compiler, one line).
    """
    xml = scene_or_xml if isinstance(scene_or_xml, str) else to_xml(scene_or_xml, options)
    try:
        return mujoco.MjModel.from_xml_string(xml)
    except ValueError as exc:
        raise ValueError(f"MJCF compile error: {str(exc).splitlines()[0]}") from None


def object_ids(model: mujoco.MjModel, n_objects: int) -> tuple[np.ndarray, np.ndarray]:
    """Body ids (n,) and geom ids (n,) int of objects ``0..n-1`` (bodies in scene order)."""
    bodies, geoms = [], []
    for b in range(1, model.nbody):
        bodies.append(b)
        geoms.append(int(model.body_geomadr[b]))
    if len(bodies) != n_objects:
        raise ValueError(f"model has {len(bodies)} bodies, scene has {n_objects} objects")
    return np.asarray(bodies), np.asarray(geoms)
