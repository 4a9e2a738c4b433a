"""Scene language v1: schema, validation and canonical YAML (docs/design.md §2).

A scene is plain data. Everything downstream (MJCF, simulation, rendering, the model's
target text, the search) takes a validated :class:`Scene`.

Conventions: SI units (m, kg, s, rad/s) except the camera block, whose angles are degrees.
World frame: z up, the floor is the plane z = 0, gravity points along -z.

Example::

    scene = load_scene("ball.yaml")          # raises SceneError with "<file>: <field>: ..."
    text = scene.to_yaml()                   # canonical text, 6 significant digits
    assert Scene.from_yaml(text) == scene.rounded()
    target = scene.to_yaml(Decimals())       # quantised form (fixed decimals): model targets
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from types import SimpleNamespace
from typing import Annotated, Any, Literal, Union

import yaml
from pydantic import (AfterValidator, BaseModel, ConfigDict, Field, ValidationError, field_validator,
                      model_validator)

from pipeline.errors import IDENTIFIER_PATTERN, UserError, format_validation_error

_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml when available: ~10x faster

MAX_SCENE_BYTES = 1_000_000
"""Largest scene file accepted, bytes (a scene of 128 objects is ~60 kB)."""
MAX_YAML_ALIASES = 64
"""Most YAML aliases (``*name``) in a scene file: each can expand a whole subtree (an 8-level
"billion laughs" document of 931 bytes took 44 s and 1.45 GB)."""
MAX_YAML_DEPTH = 32
"""Deepest nesting of YAML collections in a scene file (a scene needs 4: root, objects, an
object, its size); checked on libyaml's event stream before any Python object is built (996
nested lists made the error formatter recurse past Python's limit)."""
MAX_OBJECTS = 127
"""Most objects in a scene: segmentation masks are int8 object ids (-1 = background), so
objects 128 and up would wrap around and never be seen."""
MAX_FRAMES = 10_000
"""Most video frames (``duration * fps``) of a scene: every frame is simulated and rendered
(2 s at 10,000 fps ran for minutes)."""
MIN_MASS = 1e-6
"""Smallest object mass, kg (1 mg): MuJoCo rejects bodies with mass or inertia below
``mjMINVAL`` = 1e-15 at compile time (a 1e-20 kg sphere was a compile-error traceback)."""

MAX_MASS = 1e6
"""Largest object mass, kg (1,000 t): beyond it inertia overflows float64 with large sizes."""
MIN_SIZE, MAX_SIZE = 1e-3, 100.0
"""Object dimensions (radius, height, width, depth), m: at least 1 mm, so that the inertia of a
1 mg object stays above MuJoCo's mjMINVAL (a box 1e-288 m wide was a compile-error traceback);
at most 100 m, the bounding region of ``pipeline.sanity``."""

SIGNIFICANT_DIGITS = 6
"""Significant digits of every float in the canonical text (relative error <= 5e-6). Fixed
decimals (1 mm, 1 cm/s, 0.1 deg) wrote a 2.4 cm ball in 4 % size steps and lost up to 0.06 IoU
of what the search found on real clips (issue 35); six digits re-simulate the same masks
(``tests/test_precision.py``: IoU >= 0.995 from 1 cm to 1 m, 1 cm/s to 10 m/s, cameras 0.2 to
5 m)."""
ZERO_BELOW = 1e-12
"""Magnitudes below this print as 0 in the canonical text (floating-point noise, e.g. a
quaternion component of 1e-17), except in fields that must be > 0."""

SHAPES = ("sphere", "cylinder", "box")
"""Primitive shapes of scene language v1, in canonical order."""


class SceneError(UserError, ValueError):
    """A scene failed to parse or validate. ``str(err)`` is one line: ``<file>: <field>: <rule>``."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


MIN_MAGNITUDE = 1e-300
"""Smallest non-zero magnitude of a number in a scene: MuJoCo's XML reader refuses subnormal
numbers (``5e-324`` as a density, ``1e-320`` as a position: "number is too large")."""


def _not_subnormal(x: float) -> float:
    if x != 0 and abs(x) < MIN_MAGNITUDE:
        raise ValueError(f"must be 0 or of magnitude >= {MIN_MAGNITUDE:g} (MuJoCo reads no subnormal numbers)")
    return x


_Normal = AfterValidator(_not_subnormal)
PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False), _Normal]
NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False), _Normal]
FiniteFloat = Annotated[float, Field(allow_inf_nan=False), _Normal]
Name = Annotated[str, Field(pattern=IDENTIFIER_PATTERN, max_length=64)]
"""An effect or parameter name: an identifier (the library's names are; anything else could not
be written back as plain canonical text)."""
Vec3 = tuple[FiniteFloat, FiniteFloat, FiniteFloat]


class Camera(_Strict):
    """Camera block.

    Paper form (docs/design.md §2): ``{height, pitch, fov}``: camera at (0, -2, height) m looking along
    +y, pitched ``pitch`` degrees below the horizon, no yaw or roll. 6-DoF form (beyond the
    paper): ``{position, yaw, pitch, roll, fov}``. ``fov`` is the vertical field of view in
    degrees. Angles in degrees; ``yaw`` is measured from +y towards -x (counter-clockwise seen
    from above), ``roll`` about the optical axis. ``exposure`` (either form, beyond the paper):
    the time the shutter is open per frame, s, at most the frame interval ``1 / fps``; 0 (the
    default, not written) renders one instant per frame. Masks of moving objects are swept over
    it (motion blur, :mod:`pipeline.exposure`).
    """

    height: PositiveFloat | None = None
    position: Vec3 | None = None
    yaw: FiniteFloat | None = None
    pitch: Annotated[float, Field(ge=-89.0, le=89.0)] = 35.0
    roll: FiniteFloat | None = None
    fov: Annotated[float, Field(ge=1.0, le=179.0)] = 45.0  # closed: a value rounds onto a bound
    exposure: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] = 0.0

    @model_validator(mode="after")
    def _one_form(self) -> "Camera":
        if self.position is None:
            if self.height is None:
                raise ValueError("needs either height (paper form) or position (6-DoF form)")
            if self.yaw is not None or self.roll is not None:
                raise ValueError("yaw/roll need the 6-DoF form (position instead of height)")
        elif self.height is not None:
            raise ValueError("give height or position, not both")
        return self

    @property
    def is_six_dof(self) -> bool:
        return self.position is not None

    @property
    def eye(self) -> tuple[float, float, float]:
        """Camera centre in the world frame, m."""
        if self.position is not None:
            return tuple(self.position)  # type: ignore[return-value]
        return (0.0, -2.0, float(self.height))


ObjectLength = Annotated[float, Field(ge=MIN_SIZE, le=MAX_SIZE, allow_inf_nan=False)]


class SphereSize(_Strict):
    radius: ObjectLength


class CylinderSize(_Strict):
    radius: ObjectLength
    height: ObjectLength


class BoxSize(_Strict):
    width: ObjectLength
    depth: ObjectLength
    height: ObjectLength


class Material(_Strict):
    """Contact and damping parameters of one object.

    ``sliding_friction`` is the effective Coulomb coefficient of an object-floor contact
    (the object's geom has contact priority over the floor, so MuJoCo uses it as is; see
    ``pipeline.mjcf``). ``rolling_friction`` is MuJoCo's rolling coefficient (m).
    ``damping`` is the freejoint velocity damping (N·s/m and N·m·s/rad).
    """

    sliding_friction: NonNegFloat = 0.5
    rolling_friction: NonNegFloat = 0.0
    damping: NonNegFloat = 0.0


def _check_unit_quaternion(q: tuple[float, ...]) -> tuple[float, ...]:
    n = math.sqrt(sum(c * c for c in q))
    if abs(n - 1.0) > 1e-2:
        raise ValueError(f"must be a unit quaternion (w, x, y, z), got norm {n:.4g}")
    return q  # kept as written (canonical text stays stable); MuJoCo normalises on load


class _ObjectBase(_Strict):
    mass: Annotated[float, Field(ge=MIN_MASS, le=MAX_MASS, allow_inf_nan=False)]
    position: Vec3
    orientation: tuple[FiniteFloat, FiniteFloat, FiniteFloat, FiniteFloat] = (1.0, 0.0, 0.0, 0.0)
    linear_velocity: Vec3 = (0.0, 0.0, 0.0)
    angular_velocity: Vec3 = (0.0, 0.0, 0.0)
    material: Material = Material()

    @field_validator("orientation")
    @classmethod
    def _unit_quaternion(cls, q: tuple[float, ...]) -> tuple[float, ...]:
        return _check_unit_quaternion(q)


class Sphere(_ObjectBase):
    shape: Literal["sphere"]
    size: SphereSize


class Cylinder(_ObjectBase):
    shape: Literal["cylinder"]
    size: CylinderSize


class Box(_ObjectBase):
    shape: Literal["box"]
    size: BoxSize


SceneObject = Annotated[Union[Sphere, Cylinder, Box], Field(discriminator="shape")]


STATIC_SHAPES = ("box", "plane")
"""Shapes of static geometry (``static:`` list), in canonical order."""


class PlaneSize(_Strict):
    """Full extents of a static plane's visible rectangle, m (``width`` along its local x,
    ``depth`` along its local y)."""

    width: PositiveFloat
    depth: PositiveFloat


STATIC_RESTITUTION = (0.14, 0.95)
"""Range of a static geom's ``restitution``: that of the ``restitution`` effect's ``e``
(:mod:`pipeline.effects`; 0.14 is MuJoCo's critically damped contact, the base model's)."""


class _StaticBase(_Strict):
    """``restitution`` (beyond the paper; None, the default and not written: contacts use the
    object's material, as the floor's do): a springy stop such as an air track's bumper, whose
    contacts bounce with this coefficient of restitution and no friction, whatever the object's
    material (:func:`pipeline.mjcf.build_mjcf` gives the geom contact priority)."""

    position: Vec3
    orientation: tuple[FiniteFloat, FiniteFloat, FiniteFloat, FiniteFloat] = (1.0, 0.0, 0.0, 0.0)
    restitution: Annotated[float, Field(ge=STATIC_RESTITUTION[0], le=STATIC_RESTITUTION[1],
                                        allow_inf_nan=False)] | None = None

    @field_validator("orientation")
    @classmethod
    def _unit_quaternion(cls, q: tuple[float, ...]) -> tuple[float, ...]:
        return _check_unit_quaternion(q)


class StaticBox(_StaticBase):
    """A fixed box (ramp, wall, table top): ``size`` = full extents (width along the geom's
    local x, depth along y, height along z, m), ``position`` = centre (m, world frame),
    ``orientation`` = unit quaternion (w, x, y, z) of the geom frame. It never moves; contacts
    with objects use the object's material (as the floor does)."""

    shape: Literal["box"]
    size: BoxSize


class StaticPlane(_StaticBase):
    """A fixed one-sided plane (a wall, a tilted board without thickness): ``size`` = full
    extents of its visible rectangle (m); the plane's normal is its local +z. MuJoCo planes
    collide as if infinite on their front side: ``size`` bounds only what is drawn."""

    shape: Literal["plane"]
    size: PlaneSize


StaticGeom = Annotated[Union[StaticBox, StaticPlane], Field(discriminator="shape")]


class Effect(_Strict):
    """A physical effect beyond the base model (docs/design.md §8), e.g.
    ``{effect: quadratic_drag, parameters: {density: 1.2}}``. Names and parameters are checked
    against the effect library (``pipeline.effects``) when the MJCF is built."""

    effect: Name
    parameters: dict[Name, FiniteFloat] = {}


class Scene(_Strict):
    """One scene of scene language v1 (docs/design.md §2).

    ``static`` (beyond the paper): fixed geometry (ramps, walls, table tops), compiled as
    world geoms ``static_<index>``; optional, and omitted from the canonical text when empty.
    """

    version: Literal[1] = 1
    duration: Annotated[float, Field(gt=0, le=60)] = 1.0
    fps: Annotated[int, Field(gt=0, le=10000)] = 30
    gravity: NonNegFloat = 9.81
    camera: Camera
    objects: Annotated[list[SceneObject], Field(min_length=1, max_length=MAX_OBJECTS)]
    static: list[StaticGeom] = []
    effects: list[Effect] = []

    @model_validator(mode="after")
    def _frame_budget(self) -> "Scene":
        n = int(round(self.duration * self.fps))
        if n > MAX_FRAMES:
            raise ValueError(f"duration * fps: must be at most {MAX_FRAMES} frames, got {n}")
        if self.camera.exposure * self.fps > 1.0 + 1e-9:
            raise ValueError(f"camera.exposure: must be at most one frame interval (1 / fps = {1.0 / self.fps:.6g} s), "
                             f"got {self.camera.exposure:g}")
        return self

    @property
    def exposure_frames(self) -> float:
        """``camera.exposure`` as a fraction of the frame interval (``exposure * fps``, in [0, 1])."""
        return min(1.0, self.camera.exposure * self.fps)

    # ------------------------------------------------------------------ helpers
    @property
    def n_frames(self) -> int:
        """Number of video frames: ``round(duration * fps)``."""
        return max(1, int(round(self.duration * self.fps)))

    @property
    def object_names(self) -> list[str]:
        """``<shape>_<index>`` names, index = position in ``objects`` (docs/design.md §2)."""
        return [f"{o.shape}_{i}" for i, o in enumerate(self.objects)]

    @property
    def static_names(self) -> list[str]:
        """``static_<index>`` names of the static geoms (MJCF geom names), index = position
        in ``static``."""
        return [f"static_{i}" for i in range(len(self.static))]

    @property
    def composition(self) -> tuple[str, ...]:
        """Sorted multiset of shapes, e.g. ``('box', 'sphere', 'sphere')``."""
        return tuple(sorted(o.shape for o in self.objects))

    # ------------------------------------------------------------------ IO
    @classmethod
    def from_dict(cls, data: Any, source: str = "<scene>") -> "Scene":
        """Validate a parsed YAML mapping.

        Raises:
            SceneError: one line ``<source>: <field path>: <message>``.
        """
        if not isinstance(data, dict):
            raise SceneError(f"{source}: <root>: must be a mapping, got {type(data).__name__}")
        try:
            return cls.model_validate(data)
        except ValidationError as exc:
            raise SceneError(format_validation_error(exc, source, tags=SHAPES + STATIC_SHAPES)) from None

    @classmethod
    def from_yaml(cls, text: str, source: str = "<scene>") -> "Scene":
        """Parse and validate scene YAML text.

        Raises:
            SceneError: malformed YAML or a field that fails validation (one line).
        """
        if len(text) > MAX_SCENE_BYTES:
            raise SceneError(f"{source}: <file>: must be at most {MAX_SCENE_BYTES} bytes, got {len(text)}")
        try:
            _check_structure(text, source)   # aliases and depth, before anything is constructed
            data = yaml.load(text, Loader=_LOADER)
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f"line {mark.line + 1}" if mark is not None else "<yaml>"
            problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
            raise SceneError(f"{source}: {where}: must be well-formed YAML, got {problem[:120]}") from None
        except SceneError:
            raise
        except (ValueError, RecursionError) as exc:  # e.g. a 4,301-digit integer; nesting too deep
            first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            if "integer string conversion" in first:
                first = "numbers must have at most 4300 digits"
                raise SceneError(f"{source}: <yaml>: must have numbers of at most 4300 digits, got more") from None
            raise SceneError(f"{source}: <yaml>: cannot be read: {first[:160]}") from None
        try:
            return cls.from_dict(data, source)
        except RecursionError:
            raise SceneError(f"{source}: <root>: nested too deeply") from None

    def to_yaml(self, decimals: "Decimals | None" = None) -> str:
        """Canonical YAML text: keys in schema order, every float to
        :data:`SIGNIFICANT_DIGITS` significant digits (precision that follows the scale: a 2 cm
        ball and a 2 m box keep the same relative precision, so re-reading the text
        re-simulates the same clip; issue 35).

        Args:
            decimals: the *quantised* form instead: fixed decimal places per field (params
                ``scene.decimals``; what the synthetic configs and the model's targets use).
                Fine for the sampler's 20-40 cm objects, lossy for small ones (1 mm steps are
                10 % of a 1 cm ball): never use it for a fitted scene.

        The same scene always prints the same text; ``Scene.from_yaml(s.to_yaml(d))`` equals
        ``s.rounded(d)``, and rounding is idempotent (``s.rounded().rounded() == s.rounded()``).
        """
        return _dump(self, decimals)

    def rounded(self, decimals: "Decimals | None" = None) -> "Scene":
        """The scene as its canonical text represents it (:meth:`to_yaml` with the same
        ``decimals``, read back)."""
        return Scene.from_yaml(self.to_yaml(decimals))

    def replace(self, **changes: Any) -> "Scene":
        """A validated copy with top-level fields replaced."""
        data = self.model_dump()
        data.update({k: (v.model_dump() if isinstance(v, BaseModel) else v) for k, v in changes.items()})
        return Scene.from_dict(data)


class Decimals(_Strict):
    """Decimal places per field of the *quantised* scene text (params ``scene.decimals``):
    the synthetic configs of the ``sample_configs`` stage, i.e. the model's targets, are
    rounded to these. The canonical text of any other scene keeps :data:`SIGNIFICANT_DIGITS`
    significant digits instead (:meth:`Scene.to_yaml`)."""

    duration: int = 3
    gravity: int = 2
    camera: int = 1
    size: int = 3
    mass: int = 3
    position: int = 3
    orientation: int = 3
    velocity: int = 2
    friction: int = 3
    rolling_friction: int = 4
    damping: int = 3
    effect: int = 4


_SIGNIFICANT = SimpleNamespace(**{name: None for name in Decimals.model_fields})
"""Every field at :data:`SIGNIFICANT_DIGITS` significant digits (the canonical text)."""


def json_schema() -> dict[str, Any]:
    """JSON Schema (draft 2020-12) of a scene file, from the pydantic model (``dynamics schema``;
    a copy is committed as ``docs/scene.schema.json`` for editors)."""
    schema = Scene.model_json_schema()
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **schema}


def json_schema_text() -> str:
    """:func:`json_schema` as the text of ``docs/scene.schema.json`` (2-space indent, newline)."""
    return json.dumps(json_schema(), indent=2) + "\n"


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene YAML file.

    Raises:
        SceneError: unreadable file, malformed YAML or invalid field (one line naming the file).
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise SceneError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if len(raw) > MAX_SCENE_BYTES:
        raise SceneError(f"{path}: <file>: must be at most {MAX_SCENE_BYTES} bytes, got {len(raw)}")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SceneError(f"{path}: <file>: must be UTF-8 text, got byte 0x{raw[exc.start]:02x} at offset "
                         f"{exc.start}") from None
    return Scene.from_yaml(text, source=str(path))


# ---------------------------------------------------------------------- internals
def _check_structure(text: str, source: str) -> None:
    """Bound YAML alias use and nesting depth on libyaml's event stream (C, no objects built):
    at most :data:`MAX_YAML_ALIASES` aliases and :data:`MAX_YAML_DEPTH` nested collections.

    Raises:
        SceneError: one line naming the bound; ``yaml.YAMLError`` for malformed text.
    """
    depth = n_alias = 0
    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
    for event in yaml.parse(text, Loader=loader):
        if isinstance(event, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
            depth += 1
            if depth > MAX_YAML_DEPTH:
                line = event.start_mark.line + 1 if event.start_mark else "?"
                raise SceneError(f"{source}: line {line}: must nest at most {MAX_YAML_DEPTH} levels of "
                                 f"lists/mappings, got more")
        elif isinstance(event, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
            depth -= 1
        elif isinstance(event, yaml.AliasEvent):
            n_alias += 1
            if n_alias > MAX_YAML_ALIASES:
                raise SceneError(f"{source}: <yaml>: must use at most {MAX_YAML_ALIASES} aliases (*name), "
                                 f"got more")


def _yaml_float(v: float) -> str:
    """``repr(v)`` spelled so that YAML 1.1 (PyYAML) reads it back as a float: an exponent
    needs a dot in its mantissa (``1e-05`` is read as the *string* "1e-05"; ``1.0e-05`` as the
    number)."""
    text = repr(float(v))
    if "e" in text and "." not in text.split("e")[0]:
        text = text.replace("e", ".0e", 1)
    return text


def _num(x: float, nd: int | None = None, positive: bool = False) -> str:
    """One number of the canonical text.

    ``nd`` None (the canonical text): :data:`SIGNIFICANT_DIGITS` significant digits, so the
    relative error is at most 5e-6 whatever the scale (a 1 cm ball keeps 0.05 um, a 1 cm/s
    speed 0.05 um/s); magnitudes below :data:`ZERO_BELOW` print as 0 (floating-point noise
    such as a quaternion component of 1e-17), except in fields that must be > 0.

    ``nd`` an int (the quantised form of :class:`Decimals`, e.g. the model's targets in the
    ``sample_configs`` stage): ``nd`` decimal places; ``positive`` (masses, sizes): a value
    that would round to 0 keeps 3 significant digits instead, so that 0.0004 kg does not print
    as 0.0 and then fail validation on re-reading.
    """
    x = float(x)
    if nd is None:
        if x == 0 or (abs(x) < ZERO_BELOW and not positive):
            return "0.0"   # no "-0.0"
        return _yaml_float(float(f"{x:.{SIGNIFICANT_DIGITS}g}"))
    v = round(x, nd)
    if positive and v == 0 and x != 0:
        return _yaml_float(float(f"{x:.3g}"))
    if v == 0:
        v = 0.0  # no "-0.0"
    return _yaml_float(v)


_YAML_WORDS = {"null", "true", "false", "yes", "no", "on", "off", "y", "n", "~"}


def _name(text: str) -> str:
    """A name (effect, parameter) as canonical YAML: bare when it is a plain identifier that YAML
    reads back as the same string (``quadratic_drag``), else a double-quoted JSON string (a key
    ``null`` was read back as None, a control character was refused)."""
    if re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", text) and text.lower() not in _YAML_WORDS:
        return text
    return json.dumps(text)


def _vec(xs: Any, nd: int | None) -> str:
    return "[" + ", ".join(_num(x, nd) for x in xs) + "]"


def _dump(scene: Scene, decimals: "Decimals | None") -> str:
    d = decimals or _SIGNIFICANT
    lines = [
        f"version: {scene.version}",
        f"duration: {_num(scene.duration, d.duration, positive=True)}",
        f"fps: {scene.fps}",
        f"gravity: {_num(scene.gravity, d.gravity)}",
        "camera:",
    ]
    cam = scene.camera
    if cam.is_six_dof:
        lines += [
            f"  position: {_vec(cam.position, d.position)}",
            f"  yaw: {_num(cam.yaw or 0.0, d.camera)}",
            f"  pitch: {_num(cam.pitch, d.camera)}",
            f"  roll: {_num(cam.roll or 0.0, d.camera)}",
        ]
    else:
        lines += [f"  height: {_num(cam.height, d.position, positive=True)}", f"  pitch: {_num(cam.pitch, d.camera)}"]
    lines.append(f"  fov: {_num(cam.fov, d.camera)}")
    if cam.exposure > 0:
        lines.append(f"  exposure: {_num(cam.exposure)}")
    lines.append("objects:")
    for o in scene.objects:
        size = ", ".join(f"{k}: {_num(v, d.size, positive=True)}" for k, v in o.size.model_dump().items())
        m = o.material
        lines += [
            f"  - shape: {o.shape}",
            f"    size: {{{size}}}",
            f"    mass: {_num(o.mass, d.mass, positive=True)}",
            f"    position: {_vec(o.position, d.position)}",
            f"    orientation: {_vec(o.orientation, d.orientation)}",
            f"    linear_velocity: {_vec(o.linear_velocity, d.velocity)}",
            f"    angular_velocity: {_vec(o.angular_velocity, d.velocity)}",
            f"    material: {{sliding_friction: {_num(m.sliding_friction, d.friction)}, "
            f"rolling_friction: {_num(m.rolling_friction, d.rolling_friction)}, "
            f"damping: {_num(m.damping, d.damping)}}}",
        ]
    if scene.static:  # omitted when empty: scenes without static geometry print as before
        lines.append("static:")
        for g in scene.static:
            size = ", ".join(f"{k}: {_num(v, d.size, positive=True)}" for k, v in g.size.model_dump().items())
            lines += [
                f"  - shape: {g.shape}",
                f"    size: {{{size}}}",
                f"    position: {_vec(g.position, d.position)}",
                f"    orientation: {_vec(g.orientation, d.orientation)}",
            ]
            if g.restitution is not None:
                lines.append(f"    restitution: {_num(g.restitution, d.effect)}")
    if scene.effects:
        lines.append("effects:")
        for e in scene.effects:
            params = ", ".join(f"{_name(k)}: {_num(v, d.effect)}" for k, v in e.parameters.items())
            lines.append(f"  - {{effect: {_name(e.effect)}, parameters: {{{params}}}}}")
    else:
        lines.append("effects: []")
    return "\n".join(lines) + "\n"
