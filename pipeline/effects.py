"""Effect library: physical effects beyond the base model (DESIGN.md §8).

Adding an effect is one small class: a name, parameters with bounds and units, and how it
edits the MJCF. Scenes name effects in their ``effects:`` block; ``pipeline.mjcf`` calls
:func:`apply_effects` while building the model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from pipeline.scene import Scene, SceneError


@dataclass(frozen=True)
class ParamSpec:
    """One effect parameter: bounds and unit (SI)."""

    low: float
    high: float
    unit: str
    default: float


class Effect:
    """Base class. Subclasses set ``name``, ``parameters`` and implement :meth:`apply`."""

    name: ClassVar[str]
    parameters: ClassVar[dict[str, ParamSpec]]
    mechanism: ClassVar[str] = ""

    @classmethod
    def apply(cls, root, params: dict[str, float]) -> None:  # root: dm_control mjcf.RootElement
        raise NotImplementedError


REGISTRY: dict[str, type[Effect]] = {}


def register(cls: type[Effect]) -> type[Effect]:
    """Class decorator adding an effect to :data:`REGISTRY`."""
    REGISTRY[cls.name] = cls
    return cls


@register
class QuadraticDrag(Effect):
    """Quadratic air drag through MuJoCo's inertia-box fluid model (option ``density``;
    MuJoCo docs, "Fluid forces"): F = -1/2 rho C A |v| v with box-equivalent areas."""

    name = "quadratic_drag"
    mechanism = "option density (inertia-box model)"
    parameters = {"density": ParamSpec(0.0, 50.0, "kg/m^3", 1.2)}

    @classmethod
    def apply(cls, root, params):
        root.option.density = params["density"]


def apply_effects(root, scene: Scene, source: str = "<scene>") -> None:
    """Apply ``scene.effects`` to an MJCF tree in order.

    Raises:
        SceneError: unknown effect name, unknown/missing parameter or value out of bounds
            (``effects[i].parameters.<name>: ...``).
    """
    for i, eff in enumerate(scene.effects):
        cls = REGISTRY.get(eff.effect)
        if cls is None:
            raise SceneError(f"{source}: effects[{i}].effect: unknown effect, must be one of "
                             f"{', '.join(sorted(REGISTRY))}, got {eff.effect!r}")
        params = {}
        for key, value in eff.parameters.items():
            spec = cls.parameters.get(key)
            if spec is None:
                raise SceneError(f"{source}: effects[{i}].parameters.{key}: unknown parameter of {cls.name}")
            if not spec.low <= value <= spec.high:
                raise SceneError(f"{source}: effects[{i}].parameters.{key}: must be in "
                                 f"[{spec.low}, {spec.high}] {spec.unit}, got {value}")
            params[key] = value
        for key, spec in cls.parameters.items():
            params.setdefault(key, spec.default)
        cls.apply(root, params)
