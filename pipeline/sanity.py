"""Physical sanity of a scene and of its rollout: reported, never silent (issue 12, item 3).

Before a scene is simulated (:func:`check_initial`):

* **work budget**: ``n_frames * steps_per_frame`` physics steps must be at most
  ``max_steps`` (refused before anything runs);
* **initial interpenetration**: after ``mj_forward`` at the ``init`` keyframe no contact may be
  deeper than ``overlap_tolerance`` (MuJoCo contact ``dist < -tol``); the error names the pair
  and the depth. :func:`resolve_overlaps` (``dynamics simulate --resolve-overlaps``) instead
  pushes objects apart along the contact normal, straight up off the floor.

After a rollout (:func:`rollout_problems`, on the frames of a :class:`pipeline.simulate.Trace`):

* ``nonfinite``: a NaN or infinite position or velocity;
* ``energy``: the mechanical energy ``E = sum(m v^2 / 2 + w.I.w / 2 - m g.x)`` (kinetic plus
  gravitational potential, so kinetic energy may grow exactly by what gravity supplies) rises
  above its initial value by more than ``energy_tolerance * S + 1e-3 J``, ``S`` the energy
  scale ``E_kin(0) + sum(m |g| (r_i + z_i(0)))`` (``r_i`` the bounding radius). Contacts,
  friction and damping only remove energy in the base model (MuJoCo's soft contacts return at
  most what they store: on the 360 scenes of the default profile the energy never rose above
  its initial value). Skipped when the model has wind (``option/wind``), which does work on the objects;
* ``region``: an object centre leaves the box ``|x|, |y|, |z| <= region`` m;
* ``penetration``: at a frame an object lies deeper than ``penetration_tolerance`` inside the
  floor, static geometry or another object (sinking; MuJoCo's soft contacts let a resting
  object sink ~1 mm and an impact a few mm);
* ``step_travel``: an object moves farther in one physics step than the smallest half extent
  of any collidable geom (``|v| dt > min half size``): contacts can be missed between steps
  (tunnelling). Discrete collision detection cannot see a contact skipped between two steps,
  so this is a bound on when results can be trusted, not a detection of the event.

``dynamics simulate`` turns any problem into a one-line :class:`PhysicsError` (exit 2); the
``render`` stage keeps every scene (its shards stay those of the sampled configs) and lists the
flagged ones, by scene id and check, with counts per check, under ``sanity`` in the traces
folder's ``meta.json`` (never a silent score, never a dropped scene). Thresholds and the
measured figures: docs/reliability.md, "Simulation".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from pipeline.errors import UserError
from pipeline.geometry import half_extents, smallest_half_extent
from pipeline.mjcf import compile_model, steps_per_frame
from pipeline.rotation import quat_to_mat
from pipeline.simulate import Trace, rollout


class PhysicsError(UserError, ValueError):
    """A scene that cannot be simulated faithfully (one line: ``<file>: <field path>: must be
    <rule>, got <value>``)."""


class SanityConfig(BaseModel):
    """Thresholds of the physical sanity checks (params section ``sanity``, all optional)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    max_steps: int = Field(1_000_000, gt=0, description="most physics steps of one rollout")
    overlap_tolerance: float = Field(1e-3, ge=0, allow_inf_nan=False,
                                     description="m, deepest initial interpenetration (sampler's value)")
    penetration_tolerance: float = Field(0.05, gt=0, allow_inf_nan=False,
                                         description="m, deepest interpenetration at any frame")
    energy_tolerance: float = Field(0.05, ge=0, allow_inf_nan=False,
                                    description="allowed rise of mechanical energy, fraction of the scale S")
    region: float = Field(100.0, gt=0, allow_inf_nan=False, description="m, |x|, |y|, |z| bound of centres")


@dataclass(frozen=True)
class Overlap:
    """One contact deeper than the tolerance: body names (``floor``, ``static_<i>`` or
    ``<shape>_<i>``), depth (m, > 0), unit normal from ``a`` to ``b`` and the geom ids."""

    a: str
    b: str
    depth: float
    normal: tuple[float, float, float]
    body_a: int
    body_b: int


def _geom_name(model: mujoco.MjModel, g: int) -> str:
    body = int(model.geom_bodyid[g])
    if body == 0:
        return mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or "floor"
    return mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, body)


def overlaps(model: mujoco.MjModel, data: mujoco.MjData, tolerance: float) -> list[Overlap]:
    """Contacts of ``data``'s current collision state deeper than ``tolerance`` (m), deepest
    first (call after ``mj_forward`` or ``mj_kinematics`` + ``mj_collision``)."""
    out = []
    for c in range(data.ncon):
        con = data.contact[c]
        if con.dist < -tolerance:
            out.append(Overlap(_geom_name(model, con.geom1), _geom_name(model, con.geom2), float(-con.dist),
                               tuple(float(x) for x in con.frame[:3]),
                               int(model.geom_bodyid[con.geom1]), int(model.geom_bodyid[con.geom2])))
    return sorted(out, key=lambda o: -o.depth)


def initial_overlaps(model: mujoco.MjModel, tolerance: float) -> list[Overlap]:
    """Contacts deeper than ``tolerance`` (m) at the ``init`` keyframe (after ``mj_forward``).

    Raises:
        PhysicsError: MuJoCo cannot even compute the contacts (``mujoco.FatalError``, e.g.
            ``mj_stackAlloc: out of memory`` for 47 boxes at one spot): ``<scene>: objects: ...``.
    """
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    try:
        mujoco.mj_forward(model, data)
    except mujoco.FatalError as exc:
        raise PhysicsError(f"<scene>: objects: must leave MuJoCo's contact solver within its memory at t = 0 "
                           f"(too many objects interpenetrating?), got {' '.join(str(exc).split())[:160]}") from None
    return overlaps(model, data, tolerance)


def centre_inside(scene) -> tuple[int, int] | None:
    """The first pair ``(i, j)`` of objects with the centre of ``j`` inside object ``i`` at
    t = 0 (coincident or nested objects), else None.

    MuJoCo's convex collision (MPR/GJK) reports no contact for two cylinders at exactly the
    same position (they stayed inside each other for the whole clip, issue 35), so this is
    checked geometrically, for every shape: the centre ``c`` of ``j`` in ``i``'s body frame,
    ``d = R_i^T (c - p_i)``, is inside a sphere when ``|d| < r``, a cylinder when
    ``sqrt(dx^2 + dy^2) < r`` and ``|dz| < h / 2``, a box when ``|d_k| < e_k`` for the half
    extents ``e``. One (n, 3) product per object: O(n^2) arithmetic, ~1 ms for 127 objects.

    Args:
        scene: validated :class:`pipeline.scene.Scene`.
    """
    P = np.asarray([o.position for o in scene.objects], dtype=np.float64)     # (n, 3) m
    for i, o in enumerate(scene.objects):
        d = (P - P[i]) @ quat_to_mat(np.asarray(o.orientation, dtype=np.float64) /
                                     np.linalg.norm(o.orientation))            # rows: R_i^T (c - p_i)
        e = half_extents(o.shape, o.size)
        if o.shape == "sphere":
            inside = np.linalg.norm(d, axis=1) < e[0]
        elif o.shape == "cylinder":
            inside = (np.hypot(d[:, 0], d[:, 1]) < e[0]) & (np.abs(d[:, 2]) < e[2])
        else:
            inside = (np.abs(d) < e).all(axis=1)
        inside[i] = False
        if inside.any():
            return i, int(np.argmax(inside))
    return None


def n_steps(n_frames: int, fps: float, timestep: float) -> int:
    """Physics steps of a rollout of ``n_frames`` frames: ``(n_frames - 1) * steps_per_frame``
    (frame 0 is the initial state)."""
    return max(0, n_frames - 1) * steps_per_frame(fps, timestep)


def check_initial(scene, model: mujoco.MjModel, cfg: SanityConfig | None = None, source: str = "<scene>") -> None:
    """Refuse a scene before it runs: too many steps, or objects that start interpenetrating.

    Args:
        scene: validated :class:`pipeline.scene.Scene`.
        model: its compiled model (``pipeline.mjcf.compile_model``).
        cfg: thresholds.
        source: file name for the message.
    Raises:
        PhysicsError: ``<file>: duration * fps: must need at most N physics steps, got M`` or
            ``<file>: objects: must not interpenetrate at t = 0 (tolerance 0.001 m), got
            sphere_0 and floor 0.05 m deep``.
    """
    cfg = cfg or SanityConfig()
    steps = n_steps(scene.n_frames, scene.fps, float(model.opt.timestep))
    if steps > cfg.max_steps:
        raise PhysicsError(f"{source}: duration * fps: must need at most {cfg.max_steps} physics steps "
                           f"(sanity.max_steps), got {steps} ({scene.n_frames} frames at "
                           f"{model.opt.timestep:.3g} s)")
    pair = centre_inside(scene)
    if pair is not None:   # before MuJoCo's collision: it misses coincident cylinders, and 47
        i, j = pair        # boxes at one spot exhaust its memory
        names = scene.object_names
        raise PhysicsError(f"{source}: objects: must not interpenetrate at t = 0 (tolerance "
                           f"{cfg.overlap_tolerance:g} m; dynamics simulate --resolve-overlaps separates them), "
                           f"got the centre of {names[j]} inside {names[i]} (coincident or nested objects)")
    try:
        found = initial_overlaps(model, cfg.overlap_tolerance)
    except PhysicsError as exc:
        raise PhysicsError(str(exc).replace("<scene>", source, 1)) from None
    if found:
        o = found[0]
        more = f" (and {len(found) - 1} more contacts)" if len(found) > 1 else ""
        raise PhysicsError(f"{source}: objects: must not interpenetrate at t = 0 (tolerance "
                           f"{cfg.overlap_tolerance:g} m; dynamics simulate --resolve-overlaps separates them), "
                           f"got {o.a} and {o.b} {o.depth:.4g} m deep{more}")


def resolve_overlaps(scene, options=None, cfg: SanityConfig | None = None, max_moves: int = 200):
    """Separate objects that start interpenetrating (``dynamics simulate --resolve-overlaps``).

    Repeatedly takes the deepest contact at t = 0 and moves one object along the contact
    normal by the depth plus ``overlap_tolerance`` (so the canonical text's 1 mm rounding keeps
    them apart): against the floor or static geometry the object moves out along the surface
    normal (straight up off the floor); between two objects the one whose centre is higher
    moves. Velocities and orientations are unchanged.

    Args:
        scene: validated scene.
        options: ``pipeline.mjcf.SimOptions``.
        cfg: thresholds.
        max_moves: most moves before giving up.
    Returns:
        ``(scene, moves)``: the separated scene and one text per move
        (``sphere_1 moved 0.052 m along (0, 0, 1)``); ``scene`` is returned as is if nothing
        overlaps.
    Raises:
        PhysicsError: still overlapping after ``max_moves`` moves.
    """
    cfg = cfg or SanityConfig()
    moves: list[str] = []
    for _ in range(max_moves):
        pair = centre_inside(scene)
        if pair is not None:   # coincident or nested: no contact normal; lift the later one above
            i, j = pair        # every object under it (a stack of 47 boxes at one spot: 46 moves)
            b = scene.objects[j]
            under = [a.position[2] + _top(a) for k, a in enumerate(scene.objects)
                     if k != j and math.dist(a.position[:2], b.position[:2]) < _top(a) + _top(b)]
            lift = max(under) + _top(b) + cfg.overlap_tolerance - b.position[2]
            objects = [ob.model_dump() for ob in scene.objects]
            objects[j]["position"] = [objects[j]["position"][0], objects[j]["position"][1],
                                      float(objects[j]["position"][2] + lift)]
            scene = scene.replace(objects=objects)
            moves.append(f"{scene.object_names[j]} moved {lift:.4g} m along (0, 0, 1) (its centre was inside "
                         f"{scene.object_names[i]})")
            continue
        model = compile_model(scene, options)
        found = initial_overlaps(model, cfg.overlap_tolerance)
        if not found:
            return scene, moves
        o = found[0]
        normal = np.asarray(o.normal)
        if o.body_b > 0 and (o.body_a == 0 or scene.objects[o.body_b - 1].position[2]
                             >= scene.objects[o.body_a - 1].position[2]):
            body, direction = o.body_b, normal           # b moves along the normal a -> b
        else:
            body, direction = o.body_a, -normal
        shift = (o.depth + cfg.overlap_tolerance) * direction
        objects = [ob.model_dump() for ob in scene.objects]
        objects[body - 1]["position"] = [float(p + d) for p, d in zip(objects[body - 1]["position"], shift)]
        scene = scene.replace(objects=objects)
        moves.append(f"{scene.object_names[body - 1]} moved {o.depth + cfg.overlap_tolerance:.4g} m along "
                     f"({', '.join(f'{x:.3g}' for x in direction)})")
    raise PhysicsError(f"<scene>: objects: must be separable by --resolve-overlaps in {max_moves} moves, "
                       f"got overlaps left after {len(moves)}")


def _top(obj) -> float:
    """Bounding half height of an object (m): the half diagonal of its half extents, an upper
    bound of how far it reaches above or below its centre in any orientation."""
    return float(np.linalg.norm(half_extents(obj.shape, obj.size)))


def check_simulation(scene, options=None, cfg: SanityConfig | None = None, source: str = "<scene>",
                     record_contacts: bool = False) -> tuple[mujoco.MjModel, Trace]:
    """Every check ``dynamics simulate`` makes (it calls this), without rendering:
    :func:`check_initial`, the rollout's stability (a non-finite state, or one of MuJoCo's own
    warnings, ``Trace.warnings``: bad qacc, which makes MuJoCo reset the state silently, contact
    or constraint buffer overflow, ...; MuJoCo docs, "mjtWarning") and :func:`rollout_problems`.
    The main job runs it on the scene it is about to write, so the file it writes is one
    ``dynamics simulate`` accepts as it is (issue 35).

    Args:
        scene: validated scene.
        options: ``pipeline.mjcf.SimOptions``.
        cfg: thresholds.
        source: file name for the message.
        record_contacts: gather the contacts of every step into the trace (for events).
    Returns:
        ``(model, trace)``: the compiled model and the checked rollout.
    Raises:
        PhysicsError: the first failed check (one line), e.g. ``<file>: simulation: must stay
            stable (MuJoCo), got a non-finite state from frame 3``.
    """
    model = compile_model(scene, options)
    check_initial(scene, model, cfg, source)
    trace = rollout(model, len(scene.objects), scene.n_frames, scene.fps, record_contacts=record_contacts)
    unstable = []
    bad = ~np.isfinite(trace.qpos).all(axis=(1, 2))
    if bad.any():
        unstable.append(f"a non-finite state from frame {int(np.argmax(bad))}")
    unstable += [f"MuJoCo warning {w}" for w in trace.warnings]
    if unstable:
        raise PhysicsError(f"{source}: simulation: must stay stable (MuJoCo), got " + "; ".join(unstable))
    raise_problems(rollout_problems(model, trace.qpos, trace.qvel, cfg), source)
    return model, trace


# --------------------------------------------------------------------------- rollout checks
def mechanical_energy(model: mujoco.MjModel, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
    """Kinetic plus gravitational potential energy per frame, J.

    ``E = sum_i m_i |v_i|^2 / 2 + w_i^T I_i w_i / 2 - m_i g . x_i`` with ``g`` the model's
    gravity vector (so a tilted gravity counts), ``I_i`` the body's inertia in the world frame
    (principal moments ``body_inertia`` rotated by the body orientation and ``body_iquat``).

    Args:
        model: compiled scene (bodies 1..n the objects).
        qpos: (T, n, 7) positions (m) and quaternions w, x, y, z.
        qvel: (T, n, 6) world-frame linear (m/s) and angular (rad/s) velocities.
    Returns:
        (T,) float64 energy, J.
    """
    n = qpos.shape[1]
    m = model.body_mass[1:n + 1]
    I = model.body_inertia[1:n + 1]                       # (n, 3) principal moments
    R = quat_to_mat(qpos[..., 3:]) @ quat_to_mat(model.body_iquat[1:n + 1])   # (T, n, 3, 3) inertial -> world
    w_local = np.einsum("tnji,tnj->tni", R, qvel[..., 3:])  # R^T w
    rot = 0.5 * (I * w_local**2).sum(-1)
    kin = 0.5 * m * (qvel[..., :3] ** 2).sum(-1)
    pot = -m * (qpos[..., :3] @ model.opt.gravity)
    return (kin + rot + pot).sum(-1)


def rollout_problems(model: mujoco.MjModel, qpos: np.ndarray, qvel: np.ndarray,
                     cfg: SanityConfig | None = None) -> dict[str, str]:
    """Check a rollout's frames; returns ``{check: one-line description}`` (empty: all pass).

    Checks (module docstring): ``nonfinite``, ``step_travel``, ``energy``, ``penetration``,
    ``region``, in this order (causes before symptoms: a tunnelling sphere also leaves the
    region). Tolerances from ``cfg``.

    Args:
        model: compiled scene the frames come from.
        qpos: (T, n, 7) frame positions and quaternions.
        qvel: (T, n, 6) world-frame velocities.
    Returns:
        check name -> ``must ..., got ...`` text, in the order above.
    """
    cfg = cfg or SanityConfig()
    problems: dict[str, str] = {}
    finite = np.isfinite(qpos).all(axis=(1, 2)) & np.isfinite(qvel).all(axis=(1, 2))
    if not finite.all():
        k = int(np.argmax(~finite))
        problems["nonfinite"] = f"must stay finite, got NaN/inf from frame {k}"
    T = int(np.argmax(~finite)) if not finite.all() else len(qpos)
    qpos, qvel = qpos[:T], qvel[:T]
    if T == 0:
        return problems
    n = qpos.shape[1]
    with np.errstate(over="ignore", invalid="ignore"):
        if not np.any(model.opt.wind):
            E = mechanical_energy(model, qpos, qvel)
            g = float(np.linalg.norm(model.opt.gravity))
            m = model.body_mass[1:n + 1]
            r = model.geom_rbound[model.body_geomadr[1:n + 1]]
            scale = float(E[0] - (-m * (qpos[0, :, :3] @ model.opt.gravity)).sum()
                          + (m * g * (r + np.abs(qpos[0, :, 2]))).sum())
            rise = E - E[0]
            allowed = cfg.energy_tolerance * scale + 1e-3
            if not np.isfinite(rise).all() or rise.max() > allowed:
                k = int(np.nanargmax(np.where(np.isfinite(rise), rise, np.inf)))
                problems["energy"] = (f"must not gain energy beyond what gravity supplies (tolerance {allowed:.3g} J), "
                                      f"got {E[0]:.4g} J -> {E[k]:.4g} J at frame {k}")
        far = np.abs(qpos[..., :3]).max(axis=(1, 2))
        if (far > cfg.region).any():
            k = int(np.argmax(far > cfg.region))
            i = int(np.argmax(np.abs(qpos[k, :, :3]).max(-1)))
            problems["region"] = (f"must stay within {cfg.region:g} m of the origin (sanity.region), got "
                                  f"object {i} at ({', '.join(f'{x:.3g}' for x in qpos[k, i, :3])}) m at frame {k}")
        deepest, where = 0.0, None
        data = mujoco.MjData(model)
        for k in range(T):
            data.qpos[: 7 * n] = qpos[k].reshape(-1)
            mujoco.mj_kinematics(model, data)
            mujoco.mj_collision(model, data)
            found = overlaps(model, data, cfg.penetration_tolerance)
            if found and found[0].depth > deepest:
                deepest, where = found[0].depth, (k, found[0])
        if where is not None:
            k, o = where
            problems["penetration"] = (f"must not sink more than {cfg.penetration_tolerance:g} m into the floor or another "
                                       f"body, got {o.a} and {o.b} {o.depth:.3g} m deep at frame {k}")
        speed = np.linalg.norm(qvel[..., :3], axis=-1)
        travel = speed * float(model.opt.timestep)
        half = smallest_half_extent(model)
        if travel.max() > half:
            k, i = np.unravel_index(int(np.argmax(travel)), travel.shape)
            problems["step_travel"] = (f"must move less than the smallest half size ({half:.3g} m) per physics step "
                                       f"(else contacts are missed: tunnelling), got object {int(i)} at "
                                       f"{speed[k, i]:.4g} m/s, {travel[k, i]:.3g} m per step at frame {int(k)}")
    order = ("nonfinite", "step_travel", "energy", "penetration", "region")  # causes before symptoms
    return {k: problems[k] for k in order if k in problems}


def raise_problems(problems: dict[str, str], source: str = "<scene>") -> None:
    """Raise the first problem of :func:`rollout_problems` as a one-line :class:`PhysicsError`
    ``<file>: simulation.<check>: must ..., got ...`` (the others counted)."""
    if problems:
        name, text = next(iter(problems.items()))
        more = f" (also: {', '.join(list(problems)[1:])})" if len(problems) > 1 else ""
        raise PhysicsError(f"{source}: simulation.{name}: {text}{more}")
