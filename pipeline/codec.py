"""Scene tokens: the compact target the model writes (Pix2Seq-style quantised numbers).

Scene YAML spelled digit by digit costs ~270 tokens per scene and one wrong digit breaks it.
Here every number is **one token**: a bin index ``<0>`` ... ``<n-1>`` of a uniform grid over
the field's range (Pix2Seq, Chen et al., ICLR 2022: "a sequence of discrete tokens, one per
coordinate, quantised into bins"). The range of each field comes from the sampler's params
(``sample``: extent, mass, friction, speed, camera ...); positions use ``tokens.position``.
Fields that are constant over the dataset (version, duration, fps, gravity, effects) are not
written and are restored from the params when detokenising, so what leaves the model is still
canonical scene-language YAML.

Answer layout (tokens separated by single spaces in the target text)::

    <answer> h pitch fov  <sphere> r  m  x y z  qw qx qy qz  vx vy vz  wx wy wz  mu rho c  ... </answer>

per object: shape token, size (sphere 1: radius; cylinder 2: radius, height; box 3: width,
depth, height), mass, position (3), orientation (4, renormalised after decoding), linear
velocity (3), angular velocity (3), material (sliding, rolling friction, damping): 19-21
tokens. A 4-object scene is at most 2 + 3 + 4 * 21 = 89 answer tokens.

**Ramps** (static geometry, issue 30): a codec made from params with ``sample.p_ramp > 0`` also
writes the scene's ramp, between the camera and the objects, as ``<ramp> angle length width x y
yaw`` (the numbers :func:`pipeline.static.ramp` builds it from: slope and heading in degrees,
length and width in m, ``x y`` the centre of its top face; the thickness is the constant
``sample.ramp_thickness``), at most one, as the sampler draws it::

    <answer> h pitch fov  [<ramp> angle length width x y yaw]  <sphere> ... </answer>

A codec without ramp fields (``p_ramp = 0``, the default, and every checkpoint trained before
ramps) has no ``<ramp>`` token in its vocabulary or grammar and refuses a scene with static
geometry.

Quantisation: value ``v`` in ``[lo, hi]`` with ``n`` bins maps to ``round((v - lo) / step)``
with ``step = (hi - lo) / (n - 1)``, so the bin centres include both ends and the error is at
most ``step / 2`` (values outside the range are clipped; :meth:`SceneCodec.quantisation_error`
reports both against ``scene.decimals``).

The grammar (:meth:`SceneCodec.grammar`) is the same layout in EBNF for ``xgrammar``: any
sample decoded under it detokenises to a valid scene.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable, Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from pipeline.params import typed_section
from pipeline.scene import SHAPES, Decimals, Scene, SceneError
from pipeline.static import ramp, ramp_parameters

THINK, END_THINK = "<think>", "</think>"
ANSWER, END_ANSWER = "<answer>", "</answer>"
SHAPE_TOKENS = {s: f"<{s}>" for s in SHAPES}
"""One token per primitive: ``<sphere>``, ``<cylinder>``, ``<box>``."""
RAMP_TOKEN = "<ramp>"
"""Token that opens a ramp's numbers (codecs with ramp fields only)."""
RAMP_FIELDS = ("ramp.angle", "ramp.length", "ramp.width", "ramp.x", "ramp.y", "ramp.yaw")
"""A ramp's fields in token order (:func:`pipeline.static.ramp`'s arguments: deg, m, m, m, m, deg)."""
SCENE_CONSTANTS = ("duration", "fps", "gravity")
"""Constants restored into every decoded scene (the codec's other constants, such as
``ramp_thickness``, are not scene fields)."""
SIZE_KEYS = {"sphere": ("radius",), "cylinder": ("radius", "height"), "box": ("width", "depth", "height")}
"""Size fields per shape, in schema order."""
EVENT_SEPARATOR = ";"


class CodecError(ValueError):
    """A scene the codec cannot encode, or tokens it cannot decode (one line)."""


def bin_token(i: int) -> str:
    """The token of bin ``i``: ``<i>``."""
    return f"<{i}>"


@dataclass(frozen=True)
class Quantizer:
    """A uniform grid of ``n`` bin centres from ``lo`` to ``hi`` (both included) for one field."""

    name: str
    lo: float
    hi: float
    n: int

    @property
    def step(self) -> float:
        """Distance between bin centres (the quantisation error is at most half of it)."""
        return (self.hi - self.lo) / (self.n - 1)

    def encode(self, value: float) -> int:
        """Nearest bin index of ``value`` (clipped to the range)."""
        return int(np.clip(round((float(value) - self.lo) / self.step), 0, self.n - 1))

    def decode(self, index: int) -> float:
        """Bin centre of ``index`` (``0 <= index < n``)."""
        return self.lo + int(index) * self.step


class TokenConfig(BaseModel):
    """Params section ``tokens``: the quantised scene target.

    ``bins`` bins per field. Ranges come from the sampler (see :meth:`SceneCodec.from_params`)
    except positions (m, world frame), which the camera geometry bounds: ``position_x``,
    ``position_y``, ``position_z``.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    bins: int = Field(256, ge=2, le=4096)
    position_x: tuple[float, float] = (-1.3, 1.3)
    position_y: tuple[float, float] = (-1.8, 0.8)
    position_z: tuple[float, float] = (0.0, 0.8)
    max_objects: int = Field(4, ge=1, le=16)


def _range(values: Any, name: str) -> tuple[float, float]:
    lo, hi = (float(v) for v in values)
    if not hi > lo:
        raise CodecError(f"params.yaml: {name}: must be a range [lo, hi] with hi > lo, got {values}")
    return lo, hi


class SceneCodec:
    """Scene <-> token list, with the per-field quantisers and the constants it restores.

    Args:
        quantizers: field name -> :class:`Quantizer` (names as in :meth:`fields`).
        constants: ``duration`` (s), ``fps``, ``gravity`` (m/s^2) restored on decoding.
        max_objects: most objects a scene may have.
        decimals: rounding of the canonical YAML.
    """

    def __init__(self, quantizers: dict[str, Quantizer], constants: dict[str, float],
                 max_objects: int = 4, decimals: Decimals | None = None):
        self.q = quantizers
        self.constants = dict(constants)
        self.max_objects = max_objects
        self.decimals = decimals or Decimals()

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_params(cls, params: dict[str, Any]) -> "SceneCodec":
        """Codec for a parsed params.yaml: ranges from ``sample`` and ``tokens``.

        Ranges: camera height/pitch/fov = ``sample.camera_*``; sphere/cylinder radius =
        ``sample.extent / 2``; heights, widths, depths = ``sample.extent``; mass =
        ``sample.mass``; material = ``sample.sliding_friction`` / ``rolling_friction`` /
        ``damping``; linear velocity x, y = +-``sample.speed[1]``, z = +-``max(vertical_speed)``
        (plus what gravity adds in one frame); angular velocity = +-``sample.spin[1]``;
        quaternion components in [-1, 1] (w in [0, 1]).

        Raises:
            CodecError: a range with hi <= lo.
        """
        s = params.get("sample") or {}
        t = typed_section(params, "tokens", TokenConfig)
        n = t.bins
        ext = _range(s.get("extent", (0.18, 0.4)), "sample.extent")
        speed = float(_range(s.get("speed", (0.4, 2.0)), "sample.speed")[1])
        vz = float(max(s.get("vertical_speed", (0.0, 2.0))))
        spin = float(max(s.get("spin", (0.0, 4.0))))
        specs = {
            "camera.height": _range(s.get("camera_height", (0.8, 1.4)), "sample.camera_height"),
            "camera.pitch": _range(s.get("camera_pitch", (30.0, 50.0)), "sample.camera_pitch"),
            "camera.fov": _range(s.get("camera_fov", (35.0, 50.0)), "sample.camera_fov"),
            "size.radius": (ext[0] / 2, ext[1] / 2),
            "size.height": ext, "size.width": ext, "size.depth": ext,
            "mass": _range(s.get("mass", (0.2, 3.0)), "sample.mass"),
            "position.x": _range(t.position_x, "tokens.position_x"),
            "position.y": _range(t.position_y, "tokens.position_y"),
            "position.z": _range(t.position_z, "tokens.position_z"),
            "orientation.w": (0.0, 1.0),
            "orientation.x": (-1.0, 1.0), "orientation.y": (-1.0, 1.0), "orientation.z": (-1.0, 1.0),
            "linear_velocity.x": (-speed, speed), "linear_velocity.y": (-speed, speed),
            "linear_velocity.z": (-max(vz, 0.5), max(vz, 0.5)),
            "angular_velocity.x": (-spin, spin), "angular_velocity.y": (-spin, spin),
            "angular_velocity.z": (-spin, spin),
            "material.sliding_friction": _range(s.get("sliding_friction", (0.1, 0.6)), "sample.sliding_friction"),
            "material.rolling_friction": _range(s.get("rolling_friction", (0.0, 0.002)), "sample.rolling_friction"),
            "material.damping": _range(s.get("damping", (0.0, 0.1)), "sample.damping"),
        }
        quantizers = {k: Quantizer(k, lo, hi, n) for k, (lo, hi) in specs.items()}
        constants = {"duration": float(s.get("duration", 1.0)), "fps": int(s.get("fps", 30)),
                     "gravity": float(s.get("gravity", 9.81))}
        if float(s.get("p_ramp", 0.0)) > 0:   # ramps in the token target (the sampler draws them)
            ramp_specs = {"ramp.angle": _range(s.get("ramp_angle", (10.0, 30.0)), "sample.ramp_angle"),
                          "ramp.length": _range(s.get("ramp_length", (0.7, 1.1)), "sample.ramp_length"),
                          "ramp.width": _range(s.get("ramp_width", (0.45, 0.7)), "sample.ramp_width"),
                          "ramp.x": specs["position.x"], "ramp.y": specs["position.y"], "ramp.yaw": (-180.0, 180.0)}
            quantizers.update({k: Quantizer(k, lo, hi, n) for k, (lo, hi) in ramp_specs.items()})
            constants["ramp_thickness"] = float(s.get("ramp_thickness", 0.03))
        many = s.get("many_objects", (5, 6))
        if int(s.get("n_test_many", 0) or 0) > 0 and t.max_objects < int(max(many)):
            raise CodecError(f"params.yaml: tokens.max_objects: must be >= {int(max(many))} for the "
                             f"sample.n_test_many scenes of {list(many)} objects, got {t.max_objects}")
        decimals = typed_section(params, "scene.decimals", Decimals)
        return cls(quantizers, constants, max_objects=t.max_objects, decimals=decimals)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able spec (saved next to a checkpoint as ``codec.json``)."""
        return {"quantizers": {k: [q.lo, q.hi, q.n] for k, q in self.q.items()}, "constants": self.constants,
                "max_objects": self.max_objects, "decimals": self.decimals.model_dump()}

    def extends(self, other: "SceneCodec") -> bool:
        """Whether this codec is ``other`` with room for more objects (``max_objects`` >= other's, every
        token range and constant the same): a model trained under ``other`` keeps the meaning of every
        token under this one, whose grammar only allows longer answers."""
        mine, theirs = self.to_dict(), other.to_dict()
        return (self.max_objects >= other.max_objects
                and {k: v for k, v in mine.items() if k != "max_objects"}
                == {k: v for k, v in theirs.items() if k != "max_objects"})

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "SceneCodec":
        """Inverse of :meth:`to_dict`."""
        q = {k: Quantizer(k, float(lo), float(hi), int(n)) for k, (lo, hi, n) in data["quantizers"].items()}
        return cls(q, data["constants"], int(data["max_objects"]), Decimals(**data.get("decimals", {})))

    @staticmethod
    def object_fields(shape: str) -> list[str]:
        """Field names of one object's numbers in token order (after its shape token)."""
        xyz, wxyz = ("x", "y", "z"), ("w", "x", "y", "z")
        return ([f"size.{k}" for k in SIZE_KEYS[shape]] + ["mass"]
                + [f"position.{a}" for a in xyz] + [f"orientation.{a}" for a in wxyz]
                + [f"linear_velocity.{a}" for a in xyz] + [f"angular_velocity.{a}" for a in xyz]
                + ["material.sliding_friction", "material.rolling_friction", "material.damping"])

    CAMERA_FIELDS = ("camera.height", "camera.pitch", "camera.fov")

    @property
    def has_ramps(self) -> bool:
        """Whether the token target holds a ramp (the codec has the :data:`RAMP_FIELDS`)."""
        return all(f in self.q for f in RAMP_FIELDS)

    @property
    def answer_vocab(self) -> list[str]:
        """Tokens of the answer: tags, shape tokens (and ``<ramp>`` with :attr:`has_ramps`) and the
        bins ``<0>``..``<n-1>``."""
        n = max(q.n for q in self.q.values())
        ramp = [RAMP_TOKEN] if self.has_ramps else []
        return [ANSWER, END_ANSWER, *SHAPE_TOKENS.values(), *ramp, *(bin_token(i) for i in range(n))]

    def max_answer_tokens(self) -> int:
        """Longest answer: tags + camera (+ a ramp) + ``max_objects`` boxes."""
        ramp = 1 + len(RAMP_FIELDS) if self.has_ramps else 0
        return 2 + len(self.CAMERA_FIELDS) + ramp + self.max_objects * (1 + len(self.object_fields("box")))

    # ------------------------------------------------------------------ encode / decode
    def encode(self, scene: Scene) -> list[str]:
        """Answer tokens of a scene (``<answer>`` ... ``</answer>``).

        Raises:
            CodecError: 6-DoF camera, effects, more than ``max_objects`` objects, or static
            geometry other than one ramp of a codec with :attr:`has_ramps` (not representable in
            the compact target).
        """
        if scene.camera.is_six_dof:
            raise CodecError("camera: the token target holds the paper camera (height, pitch, fov), got 6-DoF")
        if scene.effects:
            raise CodecError("effects: the token target holds scenes without effects")
        if scene.static and not self.has_ramps:
            raise CodecError(f"static geometry is not part of this codec's token target (got {len(scene.static)} "
                             f"static geoms): a codec made with sample.p_ramp > 0 writes one ramp")
        if len(scene.static) > 1:
            raise CodecError(f"static: the token target holds at most one ramp, got {len(scene.static)} geoms")
        if len(scene.objects) > self.max_objects:
            raise CodecError(f"objects: at most {self.max_objects} in the token target, got {len(scene.objects)}")
        cam = scene.camera
        out = [ANSWER] + [bin_token(self.q[f].encode(v)) for f, v in
                          zip(self.CAMERA_FIELDS, (cam.height, cam.pitch, cam.fov))]
        for g in scene.static:
            out += [RAMP_TOKEN] + [bin_token(self.q[f].encode(v)) for f, v in zip(RAMP_FIELDS, self._ramp_values(g))]
        for o in scene.objects:
            out.append(SHAPE_TOKENS[o.shape])
            out += [bin_token(self.q[f].encode(v)) for f, v in zip(self.object_fields(o.shape), _object_values(o))]
        return out + [END_ANSWER]

    def _ramp_values(self, geom) -> list[float]:
        """A static geom's numbers in :data:`RAMP_FIELDS` order (:func:`pipeline.static.ramp_parameters`).

        Raises:
            CodecError: not a ramp, or a thickness other than the codec's ``ramp_thickness``.
        """
        try:
            p = ramp_parameters(geom)
        except ValueError as exc:
            raise CodecError(str(exc)) from None
        thickness = self.constants.get("ramp_thickness")
        if thickness is None or abs(p["thickness"] - thickness) > 1e-6:
            raise CodecError(f"static: a ramp of the token target is {thickness} m thick (sample.ramp_thickness), "
                             f"got {p['thickness']}")
        return [p["angle_deg"], p["length"], p["width"], p["x"], p["y"], p["yaw_deg"]]

    def decode(self, tokens: Sequence[str], source: str = "answer") -> Scene:
        """Scene from answer tokens (tags optional); quaternions renormalised.

        Raises:
            CodecError: tokens out of place (one line naming the position).
        """
        toks = [t for t in tokens if t not in (ANSWER, END_ANSWER)]
        pos = 0

        def take(field: str) -> float:
            nonlocal pos
            if pos >= len(toks):
                raise CodecError(f"{source}: token {pos}: expected a bin for {field}, got the end")
            tok = toks[pos]
            pos += 1
            if not (tok.startswith("<") and tok.endswith(">") and tok[1:-1].isdigit()):
                raise CodecError(f"{source}: token {pos - 1}: expected a bin for {field}, got {tok!r}")
            i = int(tok[1:-1])
            if i >= self.q[field].n:
                raise CodecError(f"{source}: token {pos - 1}: bin {i} out of range for {field} (n={self.q[field].n})")
            return self.q[field].decode(i)

        camera = {"height": take("camera.height"), "pitch": take("camera.pitch"), "fov": take("camera.fov")}
        static = []
        if pos < len(toks) and toks[pos] == RAMP_TOKEN:
            if not self.has_ramps:
                raise CodecError(f"{source}: token {pos}: {RAMP_TOKEN} in the answer of a codec without ramps")
            pos += 1
            v = {f: take(f) for f in RAMP_FIELDS}
            g = ramp(v["ramp.angle"], v["ramp.length"], v["ramp.width"], self.constants["ramp_thickness"],
                     v["ramp.x"], v["ramp.y"], v["ramp.yaw"])
            static.append(g.model_dump(mode="json"))
        shapes = {v: k for k, v in SHAPE_TOKENS.items()}
        objects = []
        while pos < len(toks):
            tok = toks[pos]
            if tok not in shapes:
                raise CodecError(f"{source}: token {pos}: expected a shape token, got {tok!r}")
            shape = shapes[tok]
            pos += 1
            vals = {f: take(f) for f in self.object_fields(shape)}
            q = np.array([vals[f"orientation.{a}"] for a in "wxyz"])
            norm = float(np.linalg.norm(q))
            q = q / norm if norm > 1e-6 else np.array([1.0, 0.0, 0.0, 0.0])
            objects.append({
                "shape": shape,
                "size": {k: vals[f"size.{k}"] for k in SIZE_KEYS[shape]},
                "mass": vals["mass"],
                "position": [vals[f"position.{a}"] for a in "xyz"],
                "orientation": q.tolist(),
                "linear_velocity": [vals[f"linear_velocity.{a}"] for a in "xyz"],
                "angular_velocity": [vals[f"angular_velocity.{a}"] for a in "xyz"],
                "material": {k: vals[f"material.{k}"] for k in ("sliding_friction", "rolling_friction", "damping")},
            })
        if not objects:
            raise CodecError(f"{source}: no objects")
        if len(objects) > self.max_objects:
            raise CodecError(f"{source}: at most {self.max_objects} objects, got {len(objects)}")
        data = {"version": 1, **{k: self.constants[k] for k in SCENE_CONSTANTS}, "camera": camera,
                "objects": objects, "effects": []}
        if static:
            data["static"] = static
        try:
            return Scene.from_dict(data, source).rounded(self.decimals)
        except SceneError as exc:
            raise CodecError(str(exc)) from None

    def roundtrip(self, scene: Scene) -> Scene:
        """``decode(encode(scene))``: the scene as the model can write it."""
        return self.decode(self.encode(scene))

    # ------------------------------------------------------------------ quality
    def quantisation_error(self, scenes: Iterable[Scene]) -> dict[str, dict[str, float]]:
        """Per field: max and mean |value - decoded value|, half a bin, the canonical-text step
        (``10**-decimals``) and the fraction of values clipped to the range.

        Returns:
            ``{field: {"max_abs", "mean_abs", "half_bin", "decimals_step", "clipped"}}`` in the
            field's unit (m, kg, m/s, rad/s, deg for the camera angles).
        """
        errs: dict[str, list[float]] = {}
        clipped: dict[str, int] = {}
        for scene in scenes:
            cam = scene.camera
            pairs = list(zip(self.CAMERA_FIELDS, (cam.height, cam.pitch, cam.fov)))
            for o in scene.objects:
                pairs += list(zip(self.object_fields(o.shape), _object_values(o)))
            if self.has_ramps:
                for g in scene.static:
                    pairs += list(zip(RAMP_FIELDS, self._ramp_values(g)))
            for f, v in pairs:
                q = self.q[f]
                errs.setdefault(f, []).append(abs(q.decode(q.encode(v)) - v))
                clipped[f] = clipped.get(f, 0) + int(not (q.lo - 1e-9 <= v <= q.hi + 1e-9))
        steps = {"camera.height": self.decimals.position, "camera.pitch": self.decimals.camera,
                 "camera.fov": self.decimals.camera, "mass": self.decimals.mass,
                 "ramp.angle": self.decimals.camera, "ramp.yaw": self.decimals.camera,
                 **{f"ramp.{k}": self.decimals.position for k in ("length", "width", "x", "y")}}
        out = {}
        for f, e in errs.items():
            group = f.split(".")[0]
            nd = steps.get(f) or {"size": self.decimals.size, "position": self.decimals.position,
                                  "orientation": self.decimals.orientation, "linear_velocity": self.decimals.velocity,
                                  "angular_velocity": self.decimals.velocity}.get(group)
            if nd is None:
                nd = {"material.sliding_friction": self.decimals.friction,
                      "material.rolling_friction": self.decimals.rolling_friction,
                      "material.damping": self.decimals.damping}[f]
            out[f] = {"max_abs": float(np.max(e)), "mean_abs": float(np.mean(e)), "half_bin": self.q[f].step / 2,
                      "decimals_step": 10.0 ** -nd, "clipped": clipped[f] / len(e)}
        return out

    # ------------------------------------------------------------------ grammar
    def grammar(self, think_words: Sequence[str] | None = None, max_events: int = 20) -> str:
        """EBNF (xgrammar dialect) of a completion: ``[<think> events </think>] <answer> ... </answer>``.

        Tokens are matched as their raw strings concatenated without separators (the target
        text's single spaces are the tokenizer's word boundaries, not characters of tokens).

        Args:
            think_words: the words allowed inside ``<think>`` (times ``t=...``, object names,
                and the verbs of :func:`pipeline.events.events_to_text`); ``None`` = no think part.
            max_events: most events in the think part (``<event> ; <event> ...``: at most
                ``6 * max_events`` tokens), so a sample always reaches its answer within
                ``max_new_tokens >= 6 * max_events + max_answer_tokens() + 3``.
        """
        def lit(s: str) -> str:
            return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'

        ns = sorted({q.n for q in self.q.values()})
        rules = [f"bin{n} ::= " + " | ".join(lit(bin_token(i)) for i in range(n)) for n in ns]

        def seq(fields: Iterable[str]) -> str:
            return " ".join(f"bin{self.q[f].n}" for f in fields)

        rules += [f"camera ::= {seq(self.CAMERA_FIELDS)}"]
        ramp = ""
        if self.has_ramps:
            rules += [f"ramp ::= {lit(RAMP_TOKEN)} {seq(RAMP_FIELDS)}"]
            ramp = " (ramp)?"
        rules += [f"{s} ::= {lit(SHAPE_TOKENS[s])} {seq(self.object_fields(s))}" for s in SHAPES]
        rules += ["object ::= " + " | ".join(SHAPES)]
        # objects: 1..max_objects, as nested optionals: object (object (object)?)?
        nested = "object"
        for _ in range(self.max_objects - 1):
            nested = f"object ({nested})?"
        rules += [f"objects ::= {nested}"]
        rules += [f"answer ::= {lit(ANSWER)} camera{ramp} objects {lit(END_ANSWER)}"]
        if think_words is not None:
            times = [w for w in think_words if w.startswith("t=")]
            names = [w for w in think_words if "_" in w and not w.startswith("t=")]
            if not times or not names:
                raise CodecError("grammar: think words need times (t=...) and object names (<shape>_<i>)")
            rules += ["time ::= " + " | ".join(lit(w) for w in times),
                      "name ::= " + " | ".join(lit(w) for w in names),
                      'event ::= time name ("hits" (name | "floor") | "stops" | "enters" "view" | "leaves" "view")']
            nested = "event"
            for _ in range(max(1, max_events) - 1):
                nested = f'event ({lit(EVENT_SEPARATOR)} {nested})?'
            rules += [f'think ::= {lit(THINK)} ("no" "events" | {nested}) {lit(END_THINK)}', "root ::= think answer"]
        else:
            rules += ["root ::= answer"]
        return "\n".join(rules) + "\n"


def _object_values(o) -> list[float]:
    """Numbers of one object in :meth:`SceneCodec.object_fields` order."""
    m = o.material
    return ([getattr(o.size, k) for k in SIZE_KEYS[o.shape]] + [o.mass] + list(o.position)
            + list(_canonical_quat(o.orientation)) + list(o.linear_velocity) + list(o.angular_velocity)
            + [m.sliding_friction, m.rolling_friction, m.damping])


def _canonical_quat(q: Sequence[float]) -> tuple[float, ...]:
    """Unit quaternion with w >= 0 (q and -q are the same rotation)."""
    q = np.asarray(q, dtype=float)
    q = q / max(float(np.linalg.norm(q)), 1e-12)
    return tuple(-q if q[0] < 0 else q)


def think_tokens(think: str) -> list[str]:
    """Words of a ``<think>`` text (events text): whitespace-split, ``;`` its own word.

    ``"t=0.23 sphere_0 hits floor; t=0.57 box_1 stops"`` ->
    ``["t=0.23", "sphere_0", "hits", "floor", ";", "t=0.57", "box_1", "stops"]``.
    """
    return think.replace(EVENT_SEPARATOR, f" {EVENT_SEPARATOR} ").split()


def target_tokens(codec: SceneCodec, scene: Scene, think: str | None) -> list[str]:
    """Full target: ``<think> words </think>`` (if ``think`` is not None) + answer tokens."""
    head = [THINK, *think_tokens(think), END_THINK] if think is not None else []
    return head + codec.encode(scene)


def split_completion(tokens: Sequence[str]) -> tuple[list[str] | None, list[str] | None]:
    """``(think words, answer tokens)`` of a completion; ``None`` where tags are missing."""
    toks = list(tokens)
    think = None
    if THINK in toks and END_THINK in toks[toks.index(THINK):]:
        a = toks.index(THINK)
        think = toks[a + 1: toks.index(END_THINK, a)]
    answer = None
    if ANSWER in toks and END_ANSWER in toks[toks.index(ANSWER):]:
        a = toks.index(ANSWER)
        answer = toks[a: toks.index(END_ANSWER, a) + 1]
    return think, answer


def text_of(tokens: Sequence[str]) -> str:
    """Target text: tokens joined with single spaces (what the word-level tokenizer splits)."""
    return " ".join(tokens)


def composition_of(tokens: Sequence[str]) -> tuple[str, ...]:
    """Sorted shapes named by the shape tokens of an answer."""
    inv = {v: k for k, v in SHAPE_TOKENS.items()}
    return tuple(sorted(inv[t] for t in tokens if t in inv))


__all__ = ["SceneCodec", "TokenConfig", "Quantizer", "CodecError", "think_tokens", "target_tokens",
           "split_completion", "text_of", "composition_of", "bin_token", "SHAPE_TOKENS", "SIZE_KEYS", "RAMP_TOKEN",
           "RAMP_FIELDS",
           "THINK", "END_THINK", "ANSWER", "END_ANSWER"]
