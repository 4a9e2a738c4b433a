"""Effect library: physical effects beyond the base model (docs/design.md §8).

Adding an effect is one small class: a name, parameters with bounds and units, and how it
edits the model, once on the MJCF tree (:meth:`Effect.apply`, used by ``pipeline.mjcf`` when a
scene has an ``effects:`` block) and once in place on a compiled ``MjModel``
(:meth:`Effect.set_model`, used by fits that compile once and edit fields per evaluation,
through :func:`pipeline.engine.configure_model`).
Both must give the same model; ``tests/test_effects.py`` checks that rollouts agree.

Every effect works through MuJoCo's own mechanism:

============================  =====================================================  =========
effect                        mechanism                                              parameters
============================  =====================================================  =========
``quadratic_drag``            ``option/density`` (ellipsoid blunt drag on spheres)   density kg/m^3
``wind``                      ``option/wind`` (+ ``density`` of air if none is set)  wind_x, wind_y m/s
``restitution``               object geoms' ``solref`` (timeconst, dampratio)       e (1)
``floor_tilt``                direction of ``option/gravity``                        tilt_x, tilt_y deg
``magnus_lift``               geom ``fluidshape="ellipsoid"``, ``fluidcoef[4]``     lift (1)
``torsional_friction``        geom ``friction[1]`` (objects use ``condim=6``)       mu_torsion m
``scale_error`` (nuisance)    measured positions x (1 + scale) (model unchanged)    scale (1)
============================  =====================================================  =========

``scale_error`` is a nuisance term (a length or frame-rate calibration error of measured
data), not a physical effect: the discrepancy workflow fits it only to check that a named
effect gains more than it, and never names it (:data:`EFFECTS` lists the physical ones).

Effects are applied in the order of :data:`REGISTRY` whatever their order in the scene, so a
scene means the same model however its ``effects:`` list is ordered; each effect appears at
most once. Where two effects touch the same MuJoCo field the rule is stated on the class
(``wind`` and ``magnus_lift`` use air density 1.2 kg/m^3 unless ``quadratic_drag`` sets one).

The base model (``pipeline.mjcf``) is the reference for every effect: density 0, wind 0,
gravity along -z, object ``solref`` from ``sim.object_solref`` (critically damped: a ball does
not bounce), ``fluidshape`` none, torsional friction 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping

import mujoco
import numpy as np
from scipy.optimize import brentq

from pipeline.scene import Scene, SceneError

AIR_DENSITY = 1.2
"""kg/m^3, density of air at about 20 °C (used by ``wind`` and ``magnus_lift``)."""

RESTITUTION_CONTACT_STEPS = 10
"""Half-period of a bouncing contact in physics steps (``restitution``): long enough for the
explicit reference acceleration to resolve it (the measured restitution of a 3 m/s impact is
within 0.02 of ``e`` at 10 steps; at 6 steps it drifts by +0.04)."""

SPHERE_ADDED_MASS_LIFT = 0.5
"""Lift of MuJoCo's ellipsoid added-mass term on a spinning sphere, in units of
``rho V (omega x v)``: it pushes *against* the Magnus direction (MuJoCo docs, "Fluid forces",
ellipsoid model example: added mass + Magnus = ``(C_M - 1/2) rho V omega x v`` for a sphere;
measured in ``tests/test_effects.py``)."""


SPHERE_BLUNT_DRAG = 1.2 / math.pi
"""Ellipsoid-model blunt-drag coefficient that reproduces the inertia-box drag of a solid
sphere along a body axis (``1.2 rho R^2 v^2 = C pi R^2 rho v^2``): used by ``quadratic_drag``
and ``wind`` on spheres (isotropic drag) and by ``magnus_lift`` when either is present."""


@dataclass(frozen=True)
class ParamSpec:
    """One effect parameter.

    Attributes:
        low, high: bounds (inclusive), in ``unit``.
        unit: SI unit (or ``1`` for dimensionless, ``deg`` for angles).
        default: value used when a scene omits the parameter.
        scale: typical magnitude, used to normalise the parameter in fits.
        fit: whether the discrepancy workflow fits it (``False``: held at ``default``).
        grid: profile points of the discrepancy workflow (the first value is where the
            effect vanishes or is weakest; the default should be one of them: clips that
            carry no information on the effect are predicted with it).
    """

    low: float
    high: float
    unit: str
    default: float
    scale: float = 1.0
    fit: bool = True
    grid: tuple[float, ...] = ()


class Effect:
    """Base class. Subclasses set ``name``, ``mechanism``, ``parameters`` and implement
    :meth:`apply` (MJCF tree) and :meth:`set_model` (compiled model, in place)."""

    name: ClassVar[str]
    parameters: ClassVar[dict[str, ParamSpec]]
    mechanism: ClassVar[str] = ""
    structural: ClassVar[bool] = False
    """True if the effect changes what the compiler derives (the model must be compiled with
    the effect present before :meth:`set_model` can change its values)."""
    nested: ClassVar[bool] = True
    """True if the model without the effect is the effect at the first value of each fitted
    parameter's ``grid`` (the fits then start from the model without it)."""
    replaces_damping: ClassVar[bool] = False
    """True if the effect is an alternative law for what the base model's free linear
    damping (``material.damping``) stands in for: a one-clip forecast
    (``pipeline.discrepancy.forward_gap``) then also fits the effect *instead of* the
    damping (held at 0) and keeps the variant with the lower BIC on the fitted part."""
    nuisance: ClassVar[bool] = False
    """True for a nuisance term of the discrepancy workflow's mismatch check (a measurement
    error, not a physical effect): never a naming candidate (not in :data:`EFFECTS`)."""

    @classmethod
    def apply(cls, root, params: Mapping[str, float]) -> None:  # root: dm_control mjcf.RootElement
        """Edit the MJCF tree ``root`` (built by ``pipeline.mjcf.build_mjcf``)."""
        raise NotImplementedError

    @classmethod
    def set_model(cls, model: mujoco.MjModel, params: Mapping[str, float], geoms: np.ndarray,
                  base: Any) -> None:
        """Edit a compiled model in place (``geoms``: object geom ids; ``base``: the base
        model's values, a :class:`pipeline.engine.ModelBase` from :func:`pipeline.engine.snapshot`). Called by
        :func:`pipeline.engine.configure_model` after the fields were reset to base."""
        raise NotImplementedError

    @classmethod
    def measure(cls, positions: np.ndarray, params: Mapping[str, float]) -> np.ndarray:
        """How the effect changes what is *measured* of a simulated trajectory: ``positions
        (..., 3)`` m (world) -> the measured ones (default: unchanged; physical effects act on
        the model only)."""
        return positions

    @classmethod
    def defaults(cls) -> dict[str, float]:
        """``{parameter: default}``."""
        return {k: s.default for k, s in cls.parameters.items()}


REGISTRY: dict[str, type[Effect]] = {}


def register(cls: type[Effect]) -> type[Effect]:
    """Class decorator adding an effect to :data:`REGISTRY` (order = application order)."""
    REGISTRY[cls.name] = cls
    return cls


def _object_geoms(root) -> list:
    """MJCF geoms of the scene's objects (every geom not attached to the world body)."""
    return [g for g in root.find_all("geom") if g.parent is not root.worldbody]


# --------------------------------------------------------------------------- drag and wind
def _sphere_geoms(root) -> list:
    """MJCF sphere geoms of the scene's objects."""
    return [g for g in _object_geoms(root) if g.type == "sphere"]


def _isotropic_drag_mjcf(root) -> None:
    """Give the objects' sphere geoms MuJoCo's ellipsoid fluid model with only the blunt drag
    (:data:`SPHERE_BLUNT_DRAG`) and the Magnus entry that cancels the added-mass lift
    (:data:`SPHERE_ADDED_MASS_LIFT`): the drag of a sphere is then ``-1.2 rho R^2 |v| v`` in
    every direction. (The inertia-box model applies ``-1.2 rho R^2 |v_i| v_i`` per body axis:
    a sphere moving along a body diagonal gets 58 % of that, along a face diagonal 71 %;
    measured in ``tests/test_effects.py``.) Other shapes keep the inertia-box model."""
    for geom in _sphere_geoms(root):
        geom.fluidshape = "ellipsoid"
        geom.fluidcoef = [SPHERE_BLUNT_DRAG, 0.0, 0.0, 0.0, SPHERE_ADDED_MASS_LIFT]


def _isotropic_drag_model(model: mujoco.MjModel, geoms: np.ndarray) -> None:
    """In place: :func:`_isotropic_drag_mjcf`'s coefficients on the object geoms compiled with
    the ellipsoid model (their ``geom_fluid[:, 0] > 0``: the spheres)."""
    ell = geoms[model.geom_fluid[geoms, 0] > 0]
    model.geom_fluid[ell, 1:6] = [SPHERE_BLUNT_DRAG, 0.0, 0.0, 0.0, SPHERE_ADDED_MASS_LIFT]


@register
class QuadraticDrag(Effect):
    """Quadratic air drag ``f = -1.2 rho R^2 |v| v`` on a sphere of radius R (option
    ``density`` = rho), isotropic: MuJoCo's ellipsoid fluid model with only its blunt drag
    (MuJoCo docs, "Fluid forces": ``-rho C_blunt A |v| v`` with the projected area ``A = pi
    R^2`` and ``C_blunt = 1.2 / pi``, :func:`_isotropic_drag_mjcf`). That is the inertia-box
    model's drag of a solid sphere along a body axis (``f_i = -2 rho r_j r_k |v_i| v_i`` with
    ``r = sqrt(3/5) R``), so a smooth sphere (``C_D ~ 0.47``, ``1/2 rho_air C_D pi R^2``) in air
    of 1.2 kg/m^3 corresponds to an effective ``density`` of ``1.2 * 0.47 * pi / 2.4 ~ 0.74``
    kg/m^3. Boxes and cylinders keep the inertia-box model (drag per body axis, which is
    what a box's faces give). Until 2026-11-25 spheres used the inertia-box model too: a ball
    thrown at 45 deg got 71 % of its drag, and data with real (isotropic) drag were fitted
    with a spurious wind (issue 31, independent benchmark).
    """

    name = "quadratic_drag"
    mechanism = "option density (ellipsoid model blunt drag on spheres, inertia-box on other shapes)"
    replaces_damping = True  # air resistance: quadratic in speed instead of linear
    structural = True        # spheres are compiled with the ellipsoid model
    parameters = {"density": ParamSpec(0.0, 50.0, "kg/m^3", AIR_DENSITY, scale=1.0,
                                      grid=(0.0, AIR_DENSITY, 3.0, 8.0, 20.0))}

    @classmethod
    def apply(cls, root, params):
        root.option.density = params["density"]
        _isotropic_drag_mjcf(root)

    @classmethod
    def set_model(cls, model, params, geoms, base):
        model.opt.density = params["density"]
        _isotropic_drag_model(model, geoms)


@register
class Wind(Effect):
    """Steady horizontal wind through MuJoCo's option ``wind`` (subtracted from each body's
    velocity in the fluid model), with the drag law of ``quadratic_drag`` (isotropic on
    spheres). The fluid needs a density: air (``density`` = 1.2 kg/m^3, not fitted) unless
    ``quadratic_drag`` sets one, which then wins."""

    name = "wind"
    mechanism = "option wind, with option density (air unless quadratic_drag sets it)"
    nested = False  # no wind still leaves air drag
    structural = True
    parameters = {
        "wind_x": ParamSpec(-20.0, 20.0, "m/s", 0.0, scale=1.0, grid=(0.0, -5.0, -2.5, 2.5, 5.0)),
        "wind_y": ParamSpec(-20.0, 20.0, "m/s", 0.0, scale=1.0, grid=(0.0, -5.0, -2.5, 2.5, 5.0)),
        "density": ParamSpec(0.0, 50.0, "kg/m^3", AIR_DENSITY, fit=False),
    }

    @classmethod
    def apply(cls, root, params):
        root.option.wind = [params["wind_x"], params["wind_y"], 0.0]
        if not root.option.density:
            root.option.density = params["density"]
        _isotropic_drag_mjcf(root)

    @classmethod
    def set_model(cls, model, params, geoms, base):
        model.opt.wind[:] = [params["wind_x"], params["wind_y"], 0.0]
        if not model.opt.density:
            model.opt.density = params["density"]
        _isotropic_drag_model(model, geoms)


# --------------------------------------------------------------------------- restitution
MIN_RESTITUTION = 0.14
"""Smallest restitution of the linear spring-damper contact (``exp(-2)`` at critical damping)."""


def restitution_of_dampratio(zeta: float) -> float:
    """Coefficient of restitution of a linear spring-damper contact with damping ratio ``zeta``.

    MuJoCo's soft contact with ``solref = (timeconst, dampratio)`` drives the penetration like a
    mass-spring-damper whose damping ratio is ``dampratio`` (MuJoCo docs, "Solver parameters":
    ``b = 2 / (dmax timeconst)``, ``k = d / (dmax^2 timeconst^2 dampratio^2)``, and the
    impedance ``d`` cancels in ``b / (2 sqrt(k))``). The contact is unilateral, so the ball
    leaves when the contact force returns to zero, not when the penetration does; for the
    linear dashpot that gives (Schwager & Pöschel 2008, Phys. Rev. E 78, 051304, eq. 13)::

        e = exp(-zeta / w (pi - atan2(2 zeta w, 1 - 2 zeta^2))),  w = sqrt(1 - zeta^2)

    valid for ``0 <= zeta < 1``; e falls monotonically from 1 to ``exp(-2) ~ 0.135`` at
    critical damping (the base model's contact), so smaller restitutions are out of reach.
    Gravity acting during the contact (about 20 ms here) lowers the measured rebound of slow
    impacts (about -0.1 at 1 m/s for e = 0.32).

    Args:
        zeta: damping ratio in [0, 1).

    Returns:
        e in (0, 1].
    """
    zeta = float(zeta)
    if not 0.0 <= zeta < 1.0:
        raise ValueError(f"zeta: must be in [0, 1), got {zeta}")
    w = math.sqrt(1.0 - zeta * zeta)
    return math.exp(-zeta / w * (math.pi - math.atan2(2.0 * zeta * w, 1.0 - 2.0 * zeta * zeta)))


def dampratio_of_restitution(e: float) -> float:
    """Inverse of :func:`restitution_of_dampratio`: the damping ratio in [0, 0.999] whose
    restitution is ``e`` (``scipy.optimize.brentq``, to 4 ulp; e falls monotonically in zeta).

    Args:
        e: coefficient of restitution in [:data:`MIN_RESTITUTION`, 1].

    Returns:
        zeta in [0, 0.999].

    Raises:
        ValueError: ``e`` outside [MIN_RESTITUTION, 1].
    """
    if not MIN_RESTITUTION <= e <= 1.0:
        raise ValueError(f"e: must be in [{MIN_RESTITUTION}, 1], got {e}")
    return brentq(lambda zeta: restitution_of_dampratio(zeta) - e, 0.0, 0.999, xtol=1e-300, rtol=4 * np.finfo(float).eps,
                  maxiter=200)


def restitution_solref(e: float, timestep: float) -> tuple[float, float]:
    """``solref = (timeconst, dampratio)`` giving restitution ``e`` (see
    :func:`restitution_of_dampratio`), with the contact's damped half-period fixed at
    :data:`RESTITUTION_CONTACT_STEPS` physics steps: natural frequency
    ``wn = pi / (N dt sqrt(1 - zeta^2))`` and ``timeconst = 1 / (wn zeta)`` (MuJoCo's
    ``k = 1 / (timeconst dampratio)^2`` up to the impedance ``d``).

    Args:
        e: coefficient of restitution in (0, 1).
        timestep: physics timestep, s.

    Returns:
        ``(timeconst s, dampratio)``.
    """
    zeta = max(dampratio_of_restitution(e), 1e-6)
    wn = math.pi / (RESTITUTION_CONTACT_STEPS * timestep * math.sqrt(1.0 - zeta * zeta))
    return 1.0 / (wn * zeta), zeta


@register
class Restitution(Effect):
    """Bouncy contacts: the objects' contact ``solref`` gets a damping ratio below 1
    (:func:`restitution_solref`); objects have contact priority over the floor, so their
    ``solref`` is the one MuJoCo uses. Reported as the coefficient of restitution ``e``."""

    name = "restitution"
    mechanism = "geom solref (timeconst, dampratio) of the objects, dampratio from e"
    nested = False  # e = 0.14 is close to, not equal to, the base contact (critically damped)
    parameters = {"e": ParamSpec(MIN_RESTITUTION, 0.95, "1", 0.5, scale=0.1,
                                grid=(MIN_RESTITUTION, 0.3, 0.5, 0.7, 0.9))}

    @classmethod
    def apply(cls, root, params):
        solref = list(restitution_solref(params["e"], float(root.option.timestep or 0.002)))
        for geom in _object_geoms(root):
            geom.solref = solref

    @classmethod
    def set_model(cls, model, params, geoms, base):
        model.geom_solref[geoms] = restitution_solref(params["e"], float(model.opt.timestep))


# --------------------------------------------------------------------------- tilt
def tilted_gravity(magnitude: float, tilt_x: float, tilt_y: float) -> np.ndarray:
    """Gravity vector ``(3,)`` m/s^2 for a floor whose slope is ``tilt_x`` deg along x and
    ``tilt_y`` deg along y (positive: downhill towards +x / +y); the world keeps the floor as
    z = 0, so the tilt shows as gravity leaning away from -z: direction
    ``normalise(tan tilt_x, tan tilt_y, -1)``."""
    d = np.array([math.tan(math.radians(tilt_x)), math.tan(math.radians(tilt_y)), -1.0])
    return magnitude * d / np.linalg.norm(d)


@register
class FloorTilt(Effect):
    """A floor that is not level (or a camera frame whose z is not vertical): gravity's
    direction tilts by ``tilt_x`` / ``tilt_y`` (option ``gravity``; magnitude kept)."""

    name = "floor_tilt"
    mechanism = "option gravity direction"
    parameters = {
        "tilt_x": ParamSpec(-30.0, 30.0, "deg", 0.0, scale=0.5, grid=(0.0, -4.0, -2.0, 2.0, 4.0)),
        "tilt_y": ParamSpec(-30.0, 30.0, "deg", 0.0, scale=0.5, grid=(0.0, -4.0, -2.0, 2.0, 4.0)),
    }

    @classmethod
    def apply(cls, root, params):
        g = float(np.linalg.norm(np.asarray(root.option.gravity, dtype=float)))
        root.option.gravity = tilted_gravity(g, params["tilt_x"], params["tilt_y"]).tolist()

    @classmethod
    def set_model(cls, model, params, geoms, base):
        model.opt.gravity[:] = tilted_gravity(float(np.linalg.norm(base.gravity)),
                                              params["tilt_x"], params["tilt_y"])


# --------------------------------------------------------------------------- Magnus lift
def magnus_fluidcoef(lift: float, density: float, drag: bool) -> list[float]:
    """``fluidcoef`` (blunt, slender, angular, Kutta, Magnus) for a lift coefficient.

    The lift force is ``lift * 1.2 kg/m^3 * V * (omega x v)`` (Magnus force of MuJoCo's
    ellipsoid model, MuJoCo docs "Fluid forces", at air density); the Magnus entry is scaled
    by ``1.2 / density`` when another effect sets the fluid density, and offset by
    :data:`SPHERE_ADDED_MASS_LIFT` to cancel the added-mass lift of a sphere.
    """
    magnus = lift * AIR_DENSITY / density + SPHERE_ADDED_MASS_LIFT
    return [SPHERE_BLUNT_DRAG if drag else 0.0, 0.0, 0.0, 0.0, magnus]


@register
class MagnusLift(Effect):
    """Magnus lift on spinning objects through MuJoCo's ellipsoid fluid model: each object
    geom gets ``fluidshape="ellipsoid"`` with only the Magnus coefficient set
    (:func:`magnus_fluidcoef`). The ellipsoid model replaces the inertia-box model for the
    body, so when ``quadratic_drag``/``wind`` are present the drag is the ellipsoid's
    blunt-drag term (:data:`SPHERE_BLUNT_DRAG`, as those effects use on spheres). The
    added-mass correction is exact for spheres only."""

    name = "magnus_lift"
    mechanism = "geom fluidshape=ellipsoid, fluidcoef Magnus entry"
    structural = True
    parameters = {
        "lift": ParamSpec(0.0, 10.0, "1", 1.0, scale=0.2, grid=(0.0, 0.5, 1.0, 2.0, 4.0)),
        "density": ParamSpec(0.0, 50.0, "kg/m^3", AIR_DENSITY, fit=False),
    }

    @classmethod
    def apply(cls, root, params):
        drag = bool(root.option.density)
        if not drag:
            root.option.density = params["density"]
        coef = magnus_fluidcoef(params["lift"], float(root.option.density), drag)
        for geom in _object_geoms(root):
            geom.fluidshape = "ellipsoid"
            geom.fluidcoef = coef

    @classmethod
    def set_model(cls, model, params, geoms, base):
        if not np.all(model.geom_fluid[geoms, 0] > 0):
            raise ValueError("magnus_lift: model must be compiled with fluidshape=ellipsoid "
                             "on the object geoms (structural effect)")
        drag = bool(model.opt.density)
        if not drag:
            model.opt.density = params["density"]
        model.geom_fluid[geoms, 1:6] = magnus_fluidcoef(params["lift"], float(model.opt.density), drag)


# --------------------------------------------------------------------------- torsion
@register
class TorsionalFriction(Effect):
    """Friction torque against spin about the contact normal: geom ``friction[1]`` (m) of
    the objects, active because object geoms use ``condim=6`` (objects with zero sliding
    friction use ``condim=1`` and have no torsional friction either)."""

    name = "torsional_friction"
    mechanism = "geom friction[1] (torsional, condim 6)"
    parameters = {"mu_torsion": ParamSpec(0.0, 0.2, "m", 0.01, scale=0.005,
                                         grid=(0.0, 0.005, 0.01, 0.02, 0.04))}

    @classmethod
    def apply(cls, root, params):
        for geom in _object_geoms(root):
            friction = list(geom.friction if geom.friction is not None else [1.0, 0.005, 0.0001])
            friction[1] = params["mu_torsion"]
            geom.friction = friction

    @classmethod
    def set_model(cls, model, params, geoms, base):
        model.geom_friction[geoms, 1] = params["mu_torsion"]


# --------------------------------------------------------------------------- scale error
@register
class ScaleError(Effect):
    """Nuisance term, not a physical effect: the measured lengths are off by the factor
    ``1 + scale`` (a ruler or camera scale calibrated wrong), so every measured position is
    ``(1 + scale)`` times the simulated one (world origin fixed: the floor stays at z = 0);
    object sizes, spin and the physics are unchanged (:meth:`measure`; :meth:`apply` and
    :meth:`set_model` change nothing). In flight this is gravity scaled by ``1 + scale``; on
    the floor a rolling ball then shows ``v = (1 + scale) omega r``. The discrepancy
    workflow's mismatch check (``pipeline.discrepancy.workflow``) asks every named effect to
    gain more than this term; it is never named (:data:`EFFECTS`)."""

    name = "scale_error"
    mechanism = "measured positions x (1 + scale)"
    nuisance = True
    parameters = {"scale": ParamSpec(-0.3, 0.3, "1", 0.0, scale=0.01,
                                     grid=(0.0, -0.04, -0.02, 0.02, 0.04))}

    @classmethod
    def apply(cls, root, params):
        """Nothing: the term acts on the measurement, not on the model."""

    @classmethod
    def set_model(cls, model, params, geoms, base):
        """Nothing: the term acts on the measurement, not on the model."""

    @classmethod
    def measure(cls, positions, params):
        return (1.0 + params["scale"]) * positions


EFFECTS: tuple[str, ...] = tuple(n for n, c in REGISTRY.items() if not c.nuisance)
"""The physical effects of the library (:data:`REGISTRY` without nuisance terms): the
discrepancy workflow's naming candidates and the hidden-effect benchmarks' effects."""


# --------------------------------------------------------------------------- application
def resolve_params(effect: str, parameters: Mapping[str, float], where: str) -> dict[str, float]:
    """Check one effect's parameters against the library and fill defaults.

    Args:
        effect: effect name.
        parameters: given values (a subset of the effect's parameters).
        where: prefix for error messages, e.g. ``"scene.yaml: effects[0]"``.

    Returns:
        All parameters of the effect, ``{name: value}``.

    Raises:
        SceneError: unknown effect, unknown parameter or value out of bounds (one line).
    """
    cls = REGISTRY.get(effect)
    if cls is None:
        raise SceneError(f"{where}.effect: unknown effect, must be one of "
                         f"{', '.join(REGISTRY)}, got {effect!r}")
    params = {}
    for key, value in parameters.items():
        spec = cls.parameters.get(key)
        if spec is None:
            raise SceneError(f"{where}.parameters.{key}: unknown parameter of {cls.name}, "
                             f"must be one of {', '.join(cls.parameters)}")
        if not spec.low <= value <= spec.high:
            raise SceneError(f"{where}.parameters.{key}: must be in "
                             f"[{spec.low}, {spec.high}] {spec.unit}, got {value}")
        params[key] = float(value)
    for key, spec in cls.parameters.items():
        params.setdefault(key, spec.default)
    return params


def scene_effects(scene: Scene, source: str = "<scene>") -> dict[str, dict[str, float]]:
    """The scene's effects as ``{name: full parameters}`` in :data:`REGISTRY` order.

    Raises:
        SceneError: unknown or repeated effect, bad parameter (``effects[i]...``).
    """
    found: dict[str, dict[str, float]] = {}
    for i, eff in enumerate(scene.effects):
        where = f"{source}: effects[{i}]"
        params = resolve_params(eff.effect, eff.parameters, where)
        if eff.effect in found:
            raise SceneError(f"{where}.effect: {eff.effect!r} appears twice")
        found[eff.effect] = params
    return {name: found[name] for name in REGISTRY if name in found}


def apply_effects(root, scene: Scene, source: str = "<scene>") -> None:
    """Apply ``scene.effects`` to an MJCF tree, in :data:`REGISTRY` order.

    Raises:
        SceneError: unknown or repeated effect, unknown/missing parameter or value out of
            bounds (``effects[i].parameters.<name>: ...``).
    """
    for name, params in scene_effects(scene, source).items():
        REGISTRY[name].apply(root, params)
