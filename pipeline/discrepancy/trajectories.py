"""Measured trajectories: objects, tracks and clips as the workflow sees them, and the error
every reader raises (:class:`DiscrepancyInputError`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pipeline import geometry
from pipeline.errors import UserError


TABLE_COLUMNS = ("clip", "object", "t", "x", "y", "z")
"""Required columns of a trajectory table (m, s; world frame, z up)."""
QUAT_COLUMNS = ("qw", "qx", "qy", "qz")
"""Optional measured orientation (unit quaternion w, x, y, z; world from body)."""
SPEC_COLUMNS = ("shape", "radius", "width", "depth", "height", "mass")
"""Optional per-object columns (constant within an object): shape, size (m), mass (kg)."""
MIN_SAMPLES = 5
"""Fewest samples of a track (and of a truncated one, :func:`truncate_clip`): the noise estimate
fits quadratics over windows of 5 samples."""


class DiscrepancyInputError(UserError, ValueError):
    """Bad trajectories or objects input. ``str(err)`` is one line:
    ``<file>: column <name>: <problem>``."""


@dataclass
class ObjectSpec:
    """Known properties of one object: shape, size (scene-language keys, m), mass (kg).

    ``assumed`` lists the properties taken from :class:`DefaultObject`."""

    shape: str
    size: dict[str, float]
    mass: float
    assumed: list[str] = field(default_factory=list)

    def support_height(self, R: np.ndarray) -> np.ndarray:
        """Height (m) of the centre above the lowest point for rotations ``R (..., 3, 3)``
        (:func:`pipeline.geometry.support_height`)."""
        return geometry.support_height(self.shape, self.size, R)

    @property
    def bounding_radius(self) -> float:
        """m, radius of the smallest sphere around the object (orientation residual scale;
        :func:`pipeline.geometry.bounding_radius`)."""
        return geometry.bounding_radius(self.shape, self.size)

    def scene_dict(self) -> dict[str, Any]:
        """``{shape, size, mass}`` of a scene-language object (m, kg)."""
        return {"shape": self.shape, "size": dict(self.size), "mass": self.mass}


@dataclass
class Track:
    """Measured trajectory of one object in one clip.

    Attributes:
        object: object name (``<shape>_<index>`` in the scene language).
        t: ``(T,)`` s, strictly increasing, relative to the clip's first sample.
        pos: ``(T, 3)`` m, world frame (z up); unobserved axes hold 0.
        quat: ``(T, 4)`` unit quaternions (w, x, y, z), or ``None`` if not measured.
        axes: ``(3,)`` bool, which of x, y, z are observed.
        spec: the object's shape, size and mass.
    """

    object: str
    t: np.ndarray
    pos: np.ndarray
    quat: np.ndarray | None
    axes: np.ndarray
    spec: ObjectSpec


@dataclass
class Clip:
    """One recording: one or more objects moving together from a common start.

    Attributes:
        name: clip id.
        source: file it was read from.
        tracks: one per object, in scene order.
        t0: s, absolute time of the first sample (tracks' ``t`` are relative to it).
        z_offset: m added to the file's vertical coordinate (two-dimensional files only, see
            :data:`TWO_D_FLOOR_CLEARANCE`).
        static: fixed geometry besides the floor (ramps, walls, table tops) as scene-language
            ``static:`` entries (dicts of :class:`pipeline.scene.StaticBox` /
            :class:`pipeline.scene.StaticPlane`), from a ``dynamics infer`` scene; simulated in
            every fit.
    """

    name: str
    source: str
    tracks: list[Track]
    t0: float = 0.0
    z_offset: float = 0.0
    static: list[dict[str, Any]] = field(default_factory=list)

    @property
    def times(self) -> np.ndarray:
        """``(T,)`` sorted union of the tracks' sample times, s."""
        return np.unique(np.concatenate([tr.t for tr in self.tracks]))

    @property
    def has_orientation(self) -> bool:
        """Whether any track has measured orientations."""
        return any(tr.quat is not None for tr in self.tracks)

    @property
    def fps(self) -> int:
        """Sample rate (median spacing), rounded to an integer for the scene's ``fps``."""
        return int(max(1, round(1.0 / float(np.median(np.diff(self.times))))))


def truncate_clip(clip: Clip, t_max: float) -> Clip | None:
    """The clip's samples up to ``t_max`` (s), or ``None`` if an object keeps fewer than
    :data:`MIN_SAMPLES`."""
    tracks = []
    for tr in clip.tracks:
        keep = tr.t <= t_max + 1e-9
        if keep.sum() < MIN_SAMPLES:
            return None
        tracks.append(Track(tr.object, tr.t[keep], tr.pos[keep], None if tr.quat is None else tr.quat[keep],
                            tr.axes, tr.spec))
    return Clip(clip.name, clip.source, tracks, clip.t0, clip.z_offset, clip.static)
