"""Params section ``sample`` of the synthetic dataset (docs/design.md §5, stage ``sample_configs``),
and what it fixes before any layout is drawn: the splits, each scene's seed and its composition.

* :class:`SampleConfig`: the distributions of object count and shape, held-out compositions,
  the ranges of sizes, masses, initial states and camera, and the filter settings.
* :func:`split_names`, :func:`scene_seed`: the split of every scene index, and its own seed
  (so any one scene can be regenerated alone).
* :func:`sample_composition`: a scene's number of objects and their shapes. Splits
  ``train``/``val``/``test`` never hold a held-out 4-object composition (``held_out``,
  resampled); split ``test_comp`` holds only those; split ``test_many`` (``n_test_many``, 0 by
  default) holds scenes of 5-6 objects (``many_objects``), more than training shows: the paper's
  generalisation row (issue 30).

Layouts that pass the paper's filters are drawn by :mod:`pipeline.sampler`.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from pipeline.scene import SHAPES

SPLITS = ("train", "val", "test", "test_comp", "test_many")
"""Splits in the order scenes are numbered."""
TEST_SPLITS = ("test", "test_comp", "test_many")
"""The splits the model is evaluated on (``predict``, ``best_of_k``, ``cmaes``, ``score``)."""

Range = tuple[float, float]


class SampleConfig(BaseModel):
    """Params section ``sample``. Ranges are ``[low, high]``, drawn uniformly."""

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)

    n_train: int = Field(300, ge=0)
    n_val: int = Field(20, ge=0)
    n_test: int = Field(20, ge=0)
    n_test_comp: int = Field(20, ge=0)
    n_test_many: int = Field(0, ge=0)      # scenes of many_objects objects (the generalisation row)
    many_objects: tuple[int, int] = (5, 6)  # object counts of test_many, drawn uniformly
    shard_size: int = Field(100, gt=0)
    n_objects: dict[int, float] = {1: 0.35, 2: 0.3, 3: 0.2, 4: 0.15}
    shapes: dict[str, float] = {"sphere": 1 / 3, "cylinder": 1 / 3, "box": 1 / 3}
    held_out: list[tuple[str, str, str, str]] = [("box", "box", "cylinder", "sphere"),
                                                 ("cylinder", "cylinder", "sphere", "sphere")]
    # geometry and physics
    extent: Range = (0.18, 0.4)            # m: sphere/cylinder diameter, cylinder height, box sides
    mass: Range = (0.2, 3.0)               # kg
    sliding_friction: Range = (0.1, 0.6)   # effective Coulomb coefficient against the floor
    rolling_friction: Range = (0.0, 0.002)  # m
    damping: Range = (0.0, 0.1)            # freejoint damping
    # initial state
    p_at_rest: float = Field(0.2, ge=0, le=1)    # object starts with zero velocity
    p_airborne: float = Field(0.3, ge=0, le=1)   # object starts above the floor (falls)
    p_lying: float = Field(0.5, ge=0, le=1)      # a cylinder on the floor lies on its side
    drop_height: Range = (0.05, 0.4)       # m, gap under an airborne object's bounding sphere
    speed: Range = (0.4, 2.0)              # m/s, horizontal launch speed
    vertical_speed: Range = (0.0, 2.0)     # m/s, upwards, airborne objects only
    spin: Range = (0.0, 4.0)               # rad/s, angular speed
    # camera (paper form: eye (0, -2, height))
    camera_height: Range = (0.8, 1.4)      # m
    camera_pitch: Range = (30.0, 50.0)     # deg below the horizon
    camera_fov: Range = (35.0, 50.0)       # deg, vertical
    max_floor_distance: float | None = Field(None, gt=0)  # m from the eye's ground point; null = the horizon
    look: Literal["fixed", "random"] = "fixed"  # random: floor, colours and light drawn per scene (pipeline.scene_look)
    look_shadows: float = Field(0.0, ge=0, le=1)  # random looks: chance of shadows (~15x a frame's RGB time on CPU)
    gravity: float = Field(9.81, ge=0)
    duration: float = Field(1.0, gt=0)
    fps: int = Field(30, gt=0)
    # filters
    width: int = Field(96, gt=0)           # px, size of the visibility check
    height: int = Field(64, gt=0)          # px
    min_pixel_fraction: float = Field(0.025, ge=0, lt=1)
    overlap_tolerance: float = Field(0.001, ge=0)  # m
    keep_in_view: bool = True
    placement_margin: float = Field(0.12, ge=0, lt=0.5)  # image fraction kept clear at the sides
    max_tries: int = Field(300, gt=0)
    many_max_tries: int = Field(3000, gt=0)  # test_many: 5-6 objects that all pass the filters are rarer
    # static geometry (scene language ``static:``); p_ramp = 0 keeps every scene as before
    p_ramp: float = Field(0.0, ge=0, le=1)  # a scene gets one ramp with one object on it
    ramp_angle: Range = (10.0, 30.0)       # deg, slope
    ramp_length: Range = (0.7, 1.1)        # m, along the slope
    ramp_width: Range = (0.45, 0.7)        # m, across the slope
    ramp_thickness: float = Field(0.03, gt=0)  # m

    @field_validator("n_objects", "shapes")
    @classmethod
    def _distribution(cls, v: dict) -> dict:
        if not v or any(p < 0 for p in v.values()) or sum(v.values()) <= 0:
            raise ValueError(f"must be a non-empty mapping of non-negative probabilities, got {v}")
        total = sum(v.values())
        return {k: p / total for k, p in v.items()}

    @field_validator("shapes")
    @classmethod
    def _known_shapes(cls, v: dict) -> dict:
        for k in v:
            if k not in SHAPES:
                raise ValueError(f"unknown shape {k!r}, must be one of {', '.join(SHAPES)}")
        return v

    @field_validator("n_objects")
    @classmethod
    def _counts(cls, v: dict) -> dict:
        for k in v:
            if not 1 <= k <= 6:
                raise ValueError(f"object counts must be in 1..6, got {k}")
        return v

    @field_validator("held_out")
    @classmethod
    def _compositions(cls, v: list) -> list:
        for comp in v:
            for s in comp:
                if s not in SHAPES:
                    raise ValueError(f"unknown shape {s!r} in {list(comp)}")
        return [tuple(sorted(c)) for c in v]

    @model_validator(mode="after")
    def _ranges(self) -> "SampleConfig":
        for name, value in self:
            if isinstance(value, tuple) and len(value) == 2 and all(isinstance(x, (int, float)) for x in value):
                if value[0] > value[1]:
                    raise ValueError(f"{name}: low must be <= high, got {list(value)}")
        if not (0.0 <= self.ramp_angle[0] and self.ramp_angle[1] < 90.0):
            raise ValueError(f"ramp_angle: must be within [0, 90) deg, got {list(self.ramp_angle)}")
        if self.ramp_length[0] <= 0 or self.ramp_width[0] <= 0:
            raise ValueError("ramp_length, ramp_width: must be > 0")
        if not 1 <= self.many_objects[0] <= self.many_objects[1] <= 6:
            raise ValueError(f"many_objects: must be counts low <= high within 1..6, got {list(self.many_objects)}")
        if self.n_test_comp and not self.held_out:
            raise ValueError("n_test_comp > 0 needs at least one held_out composition")
        if self.n_objects.get(4, 0) > 0 and self.held_out:
            free = _free_compositions(self)
            if not free:
                raise ValueError("every 4-object composition is held out, but n_objects allows 4")
        return self

    @property
    def n_scenes(self) -> int:
        return self.n_train + self.n_val + self.n_test + self.n_test_comp + self.n_test_many

    @property
    def min_pixels(self) -> int:
        """Minimum visible pixels per object in the first frame."""
        return int(math.ceil(self.min_pixel_fraction * self.width * self.height))


def _free_compositions(cfg: SampleConfig) -> list[tuple[str, ...]]:
    """4-object compositions with positive probability that are not held out."""
    shapes = sorted(s for s, p in cfg.shapes.items() if p > 0)
    held = set(cfg.held_out)
    out = []
    for a in range(len(shapes)):
        for b in range(a, len(shapes)):
            for c in range(b, len(shapes)):
                for d in range(c, len(shapes)):
                    comp = (shapes[a], shapes[b], shapes[c], shapes[d])
                    if comp not in held:
                        out.append(comp)
    return out


# --------------------------------------------------------------------------- seeds, splits
def split_names(cfg: SampleConfig) -> list[str]:
    """Split of every scene index: train first, then val, test, test_comp, test_many (last, so the
    other scenes keep their indices and seeds whatever ``n_test_many`` is)."""
    return (["train"] * cfg.n_train + ["val"] * cfg.n_val + ["test"] * cfg.n_test
            + ["test_comp"] * cfg.n_test_comp + ["test_many"] * cfg.n_test_many)


def scene_seed(seed: int, index: int) -> int:
    """Seed of scene ``index`` of a dataset drawn with ``seed`` (independent streams:
    ``numpy.random.SeedSequence(seed).spawn``)."""
    child = np.random.SeedSequence(seed, spawn_key=(index,))
    return int(child.generate_state(1, np.uint32)[0])


# --------------------------------------------------------------------------- composition
def sample_composition(rng: np.random.Generator, cfg: SampleConfig, split: str) -> list[str]:
    """Shapes of a scene's objects, in drawing order (not sorted).

    ``test_comp``: one of ``held_out`` (uniformly), shuffled. ``test_many``: a count drawn
    uniformly from ``many_objects``, each shape i.i.d. from ``shapes``. Other splits: the count from
    ``n_objects``, each shape i.i.d. from ``shapes``; a held-out 4-object multiset is drawn again.
    """
    if split not in SPLITS:
        raise ValueError(f"split must be one of {', '.join(SPLITS)}, got {split!r}")
    if split == "test_comp":
        comp = list(cfg.held_out[int(rng.integers(len(cfg.held_out)))])
        rng.shuffle(comp)
        return comp
    names, ps = zip(*sorted(cfg.shapes.items()))
    if split == "test_many":
        n = int(rng.integers(cfg.many_objects[0], cfg.many_objects[1] + 1))
        return [str(x) for x in rng.choice(names, size=n, p=ps)]
    counts, pc = zip(*sorted(cfg.n_objects.items()))
    n = int(rng.choice(counts, p=pc))
    names, ps = zip(*sorted(cfg.shapes.items()))
    held = set(cfg.held_out)
    while True:
        comp = [str(s) for s in rng.choice(names, size=n, p=ps)]
        if n != 4 or tuple(sorted(comp)) not in held:
            return comp
