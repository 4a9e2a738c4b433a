"""Motion events of a rollout: collisions, stops, entering and leaving the view (docs/design.md §5).

Events are read from a :class:`pipeline.simulate.Trace` (contacts, velocities) and the
per-frame visible pixel counts of each object (from the rendered segmentation). They become
the model's ``<think>`` text, e.g. ``t=0.23 sphere_0 hits floor; t=0.57 box_1 stops``.

Definitions (thresholds in params section ``events``, :class:`EventConfig`):

* ``collision`` at frame k >= 1: a pair of bodies (object-floor or object-object) is in
  contact during (t_{k-1}, t_k], was not during (t_{k-2}, t_{k-1}], and was approaching at
  t_{k-1} faster than ``min_approach_speed`` (a landing after flight, a bounce, or the start
  of an object-object contact). ``t = t_k``, so an event is reported at most one frame after
  it happened. ``force`` is the peak normal force (N) in frames k and k+1. Contacts present at
  t = 0 and objects that settle onto the floor from rest (an object placed exactly at
  z = half height touches the floor at distance 0, which MuJoCo reports one step later) are
  not collisions. Approach speed: -v_z for the floor; for two objects, the rate at which
  their centres close in.
* ``stop`` at frame k >= 1: the object's speed |v| < ``stop_speed`` and angular speed
  |w| < ``stop_angular_speed`` from frame k to the end of the clip, and not at frame k-1.
* ``enter_view`` / ``leave_view`` at frame k >= 1: the object's visible pixel count crosses
  ``min_visible_px`` upwards / downwards between frames k-1 and k (occlusion counts).

Example::

    events = extract_events(trace, frames.visible_pixels())
    think = events_to_text(events)       # "t=0.43 sphere_0 hits floor; t=0.90 sphere_0 stops"
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from pipeline.simulate import Trace

KINDS = ("collision", "stop", "enter_view", "leave_view")
"""Event kinds, in the order used to sort events of the same frame."""
FLOOR = "floor"
"""Name of the floor in contacts and events."""
NO_EVENTS = "no events"
"""Text of a clip without events."""


class EventConfig(BaseModel):
    """Params section ``events``."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    stop_speed: float = Field(0.05, gt=0, description="m/s")
    stop_angular_speed: float = Field(0.5, gt=0, description="rad/s")
    min_visible_px: int = Field(4, ge=1, description="px at the rendered resolution")
    min_force: float = Field(0.0, ge=0, description="N; weaker collisions are ignored")
    min_approach_speed: float = Field(0.05, ge=0, description="m/s; slower contact starts are not collisions")
    decimals: int = Field(2, ge=0, le=6, description="decimals of t in the text")


@dataclass(frozen=True)
class Event:
    """One event. ``objects``: names in scene order, ``floor`` last; ``force``: peak normal
    force of a collision, N (0 for other kinds)."""

    kind: str
    frame: int
    t: float
    objects: tuple[str, ...]
    force: float = 0.0


def _order(trace: Trace) -> dict[str, int]:
    """Sort key of body names: scene order, ``floor`` last."""
    order = {name: i for i, name in enumerate(trace.names)}
    order[FLOOR] = len(order)
    return order


def approach_speed(trace: Trace, k: int, a: str, b: str) -> float:
    """Speed (m/s) at which bodies ``a`` and ``b`` (object names or ``floor``) close in at frame k."""
    index = {name: i for i, name in enumerate(trace.names)}
    if FLOOR in (a, b):
        return float(-trace.qvel[k, index[b if a == FLOOR else a], 2])
    i, j = index[a], index[b]
    d = trace.qpos[k, i, :3] - trace.qpos[k, j, :3]
    dv = trace.qvel[k, i, :3] - trace.qvel[k, j, :3]
    return float(-(d @ dv) / max(np.linalg.norm(d), 1e-9))


def collision_events(trace: Trace, cfg: EventConfig | None = None) -> list[Event]:
    """Contact starts after frame 0 (see module docstring)."""
    cfg = cfg or EventConfig()
    order = _order(trace)
    pairs = [{(c.a, c.b): c.force for c in frame} for frame in trace.contacts]
    events = []
    for k in range(1, len(pairs)):
        for pair, force in pairs[k].items():
            if pair in pairs[k - 1] or approach_speed(trace, k - 1, *pair) < cfg.min_approach_speed:
                continue
            if k + 1 < len(pairs):
                force = max(force, pairs[k + 1].get(pair, 0.0))
            if force < cfg.min_force:
                continue
            objects = tuple(sorted(pair, key=order.__getitem__))
            events.append(Event("collision", k, float(trace.t[k]), objects, float(force)))
    return events


def stop_events(trace: Trace, cfg: EventConfig | None = None) -> list[Event]:
    """Objects that come to rest and stay at rest until the end of the clip."""
    cfg = cfg or EventConfig()
    speed = np.linalg.norm(trace.qvel[..., :3], axis=-1)
    spin = np.linalg.norm(trace.qvel[..., 3:], axis=-1)
    still = (speed < cfg.stop_speed) & (spin < cfg.stop_angular_speed)  # (T, n)
    events = []
    for i, name in enumerate(trace.names):
        # first frame from which the object stays still: suffix-AND of `still`
        stays = np.logical_and.accumulate(still[::-1, i])[::-1]
        if not stays.any() or stays[0]:
            continue  # never stops, or never moves
        k = int(np.argmax(stays))
        events.append(Event("stop", k, float(trace.t[k]), (name,)))
    return events


def view_events(t: np.ndarray, visible: np.ndarray, names: Sequence[str],
                cfg: EventConfig | None = None) -> list[Event]:
    """``enter_view`` / ``leave_view`` from visible pixel counts ``visible (T, n)``."""
    cfg = cfg or EventConfig()
    seen = np.asarray(visible) >= cfg.min_visible_px
    events = []
    for k, i in zip(*np.nonzero(seen[1:] != seen[:-1])):
        kind = "enter_view" if seen[k + 1, i] else "leave_view"
        events.append(Event(kind, int(k + 1), float(t[k + 1]), (names[i],)))
    return events


def extract_events(trace: Trace, visible: np.ndarray | None = None,
                   cfg: EventConfig | None = None) -> list[Event]:
    """All events of a rollout, sorted by frame, kind (:data:`KINDS` order) and objects.

    Args:
        trace: rollout (``pipeline.simulate.rollout``), with contacts recorded.
        visible: optional (T, n) visible pixel counts per frame and object
            (``Frames.visible_pixels()``); without it there are no view events.
        cfg: thresholds.
    """
    cfg = cfg or EventConfig()
    events = collision_events(trace, cfg) + stop_events(trace, cfg)
    if visible is not None:
        visible = np.asarray(visible)
        if visible.shape != (len(trace.t), len(trace.names)):
            raise ValueError(f"visible must have shape (T, n) = ({len(trace.t)}, {len(trace.names)}), "
                             f"got {visible.shape}")
        events += view_events(trace.t, visible, trace.names, cfg)
    order = _order(trace)
    return sorted(events, key=lambda e: (e.frame, KINDS.index(e.kind), [order[o] for o in e.objects]))


def _phrase(event: Event) -> str:
    if event.kind == "collision":
        a, b = event.objects
        return f"{a} hits {b}"
    verb = {"stop": "stops", "enter_view": "enters view", "leave_view": "leaves view"}[event.kind]
    return f"{event.objects[0]} {verb}"


def events_to_text(events: Sequence[Event], names: Sequence[str] | None = None, decimals: int = 2) -> str:
    """Compact deterministic text of events (the model's ``<think>`` content).

    Args:
        events: events in order (:func:`extract_events`).
        names: optional object names of the scene; when given, an event naming another
            object raises ``ValueError`` (catches events joined to the wrong scene).
        decimals: decimals of the times.
    Returns:
        ``"t=0.23 sphere_0 hits floor; t=0.57 box_1 stops"``, or :data:`NO_EVENTS`.
    """
    if names is not None:
        known = set(names) | {FLOOR}
        for e in events:
            unknown = [o for o in e.objects if o not in known]
            if unknown:
                raise ValueError(f"event at t={e.t:.3f} names {unknown[0]!r}, not one of {', '.join(names)}")
    if not events:
        return NO_EVENTS
    return "; ".join(f"t={e.t:.{decimals}f} {_phrase(e)}" for e in events)


# --------------------------------------------------------------------------- table IO
def events_to_rows(scene_id: str, events: Iterable[Event]) -> list[dict[str, Any]]:
    """Rows of the ``events`` table: scene_id, t, frame, kind, objects (comma-joined), force."""
    return [{"scene_id": scene_id, "t": e.t, "frame": e.frame, "kind": e.kind,
             "objects": ",".join(e.objects), "force": e.force} for e in events]


def events_from_rows(rows: Iterable[Mapping[str, Any]]) -> list[Event]:
    """Inverse of :func:`events_to_rows` (rows of one scene, in order)."""
    return [Event(r["kind"], int(r["frame"]), float(r["t"]), tuple(r["objects"].split(",")), float(r["force"]))
            for r in rows]


def events_to_json(events: Iterable[Event]) -> list[dict[str, Any]]:
    """JSON-ready list of events (``objects`` as a list)."""
    return [{**asdict(e), "objects": list(e.objects)} for e in events]
