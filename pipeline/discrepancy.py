"""Discrepancy workflow: find -> name -> add -> show (DESIGN.md §8).

Measured trajectories go in; out come the places where the base model (scene language v1,
simulated by MuJoCo) disagrees with them, the missing physical effect(s) named from the
effect library (``pipeline.effects``) with fitted coefficients and confidence intervals, the
extended scenes (``effects:`` block) and a report showing the held-out gap shrink.

1. **Find.** Per clip, the base model's free parameters (each object's initial position,
   orientation, linear and angular velocity, ``material.damping`` and
   ``material.sliding_friction``) are fitted by least squares
   (``scipy.optimize.least_squares``, finite-difference Jacobian over MuJoCo rollouts of a
   model compiled once per clip and edited in place). The measurement noise is estimated from
   the data alone (:func:`estimate_noise`), and residual segments that exceed it are listed
   with the motion phase (flight, contact, sliding, rolling, rest).
2. **Name.** Every candidate effect is fitted jointly over all clips (its coefficients shared,
   the per-clip parameters free), scored in sample by BIC and out of sample by k-fold
   cross-validation over clips (coefficients fitted on the other clips, only the clip's own
   parameters refitted). An effect is named only if it clears both gates (BIC drop and
   held-out chi-square drop above thresholds, i.e. above what the noise floor explains);
   greedy forward selection repeats with the named effects in the model.
3. **Add.** The final joint fit (converged) gives the coefficients, with confidence intervals
   from the profile likelihood (:func:`profile_intervals`; the Gauss-Newton interval
   ``s^2 (J^T J)^-1`` of ``mujoco.sysid.calculate_intervals`` where the profile confirms it,
   open where the data cannot bound a side), and one extended scene per clip.
4. **Show.** ``discrepancy.md`` / ``discrepancy.json``, residual plots before/after (PNG),
   a rerun recording (measured vs base vs extended). The shown gap (:attr:`Result.gap`) is
   the leave-one-clip-out held-out RMSE with >= 2 clips; with one clip there is nothing to
   hold out, so it is a forward split in time (:func:`forward_gap`: fitted on the clip's
   first part, the rest forecast). The in-sample RMSE with the number of fitted parameters
   of each model is always reported beside it (:attr:`Result.in_sample`).

Input: tables with columns ``clip, object, t, x, y, z`` (m, s, z up; CSV or Parquet), optional
``qw, qx, qy, qz`` (measured orientation, e.g. motion capture) and optional object columns
``shape, radius, width, depth, height, mass``; or two-dimensional Tracker exports (header names
the columns ``t`` and two of ``x``/``y``, y up, metres), mapped to x -> x, y -> z (world y is
not observed). Object sizes and masses may also come from an objects mapping
(:func:`parse_objects`). Bad input raises :class:`DiscrepancyInputError` with one line naming
the file and the column.

Example::

    clips = read_trajectories(["data/hidden/trajectories.parquet"])
    result = run_workflow(clips, DiscrepancyConfig())
    write_report(result, "reports")
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import csv
import io
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Iterable, Mapping, Sequence

import mujoco
import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from pipeline.errors import UserError
from pipeline import effects as fx
from pipeline import infer_tracks
from pipeline.parallel import ComputeConfig, available_cores, parallel_map
from pipeline.mjcf import SimOptions, compile_model, initial_state
from pipeline.scene import Decimals, Scene
from pipeline.shards import write_bytes, write_json, write_text
from pipeline.simulate import reset_to_scene

TABLE_COLUMNS = ("clip", "object", "t", "x", "y", "z")
"""Required columns of a trajectory table (m, s; world frame, z up)."""
QUAT_COLUMNS = ("qw", "qx", "qy", "qz")
"""Optional measured orientation (unit quaternion w, x, y, z; world from body)."""
SPEC_COLUMNS = ("shape", "radius", "width", "depth", "height", "mass")
"""Optional per-object columns (constant within an object): shape, size (m), mass (kg)."""
PHASES = ("flight", "contact", "sliding", "rolling", "rest")
MIN_SAMPLES = 5
TWO_D_FLOOR_CLEARANCE = 0.05
"""m. Two-dimensional Tracker exports have an arbitrary vertical origin and no floor (the
ball drops end before the impact): the reader lifts such a clip so that every object's
lowest point stays at least this far above z = 0, i.e. the clip is free flight."""
MAX_ABS_COORDINATE = 100.0
"""m; larger values are taken for pixels (a one-line error names the column)."""
NUISANCE = ("px", "py", "pz", "vx", "vy", "vz", "rx", "ry", "rz", "wx", "wy", "wz",
            "damping", "friction")
"""Per-object base-model parameters fitted per clip: initial position (m), orientation
perturbation (rotation vector, rad, body frame, relative to the reference orientation),
linear velocity (m/s, world), angular velocity (rad/s, world), ``material.damping``
(freejoint damping, N s/m) and ``material.sliding_friction``."""
_P, _V, _R, _W, _D, _F = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), 12, 13
DISCREPANCY_DECIMALS = Decimals(position=4, orientation=4, velocity=3, damping=6, friction=3, mass=6, size=5,
                                effect=4, duration=3)
"""Decimals of the written extended scenes (finer than the model target: they are fits)."""


class DiscrepancyInputError(UserError, ValueError):
    """Bad trajectories or objects input. ``str(err)`` is one line:
    ``<file>: column <name>: <problem>``."""


# =========================================================================== configuration
class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class DefaultObject(_Strict):
    """Object assumed when the input gives no size/mass (flagged in the report)."""

    radius: float = Field(0.02, gt=0, description="m, sphere/cylinder radius")
    width: float = Field(0.1, gt=0, description="m, box")
    depth: float = Field(0.1, gt=0, description="m, box")
    height: float = Field(0.05, gt=0, description="m, box/cylinder")
    mass: float = Field(0.05, gt=0, description="kg")


class DiscrepancyConfig(_Strict):
    """Workflow settings (params section ``discrepancy``).

    Attributes:
        candidates: effect names tried (default: the whole library).
        max_effects: most effects named by greedy forward selection.
        noise_floor_chi2: after naming an effect, stop when every clip's chi2 per residual
            is at most this (the model fits every clip to the noise floor).
        bic_threshold: an effect must lower BIC by at least this much (10 = "very strong"
            evidence, Kass & Raftery 1995).
        heldout_threshold: ... and lower the held-out chi-square (noise-normalised squared
            residuals of clips not used to fit its coefficients) by at least this much.
        segment_p: residuals are flagged where a window's chi-square tail probability under
            the noise model is below this.
        segment_window: samples per window (:func:`residual_segments`).
        min_segment_samples: shortest flagged segment, samples.
        contact_tolerance: m; an object is on the floor when its lowest point is closer.
        rest_speed: m/s; below it an object on the floor is at rest.
        max_nfev: function evaluations per least-squares fit of the base model.
        max_nfev_warm: ... per warm-started fit (profile refits, held-out refits). These two
            caps are for the cheap screening fits (profile points, continuation horizons).
        ftol: relative cost tolerance of the *converged* fits (scipy ``ftol``; ``xtol`` and
            ``gtol`` are set 100x smaller): the base model's last horizon, every candidate's
            joint fit, the final fit and the profile-likelihood points stop on it.
        max_nfev_converged: safety cap (function evaluations) of a converged fit; a fit that
            reaches it reports ``status`` 0 in the report (``optimizer``).
        screen_ftol: relative cost tolerance of the screening fits.
        threads: MuJoCo rollout threads (the joint fits, in the main process).
        workers: processes that fit the clips one by one in parallel (per-clip fits: the base
            fit, every profile point); ``None``: every available core. 1: no pool.
        screen_gain: a candidate gets its full fits only when the linearised screen
            (:func:`screen_candidates`) predicts a chi-square gain of at least this much, or,
            failing that, the clips refitted from the data at one strength of it
            (:func:`_second_chance_point`) gain that much (0: every candidate is fitted).
        rescreen_all: after the first step, try every remaining candidate again (default:
            only those whose profile improved the base model by ``heldout_threshold``).
        horizons: fractions of each clip fitted in turn by the base fit (continuation).
        forward_split: with a single clip (nothing to hold out) the shown gap is a forecast:
            base and base + named effects are fitted on the clip's first ``forward_split``
            of its duration and scored on the samples after it (:func:`forward_gap`).
        hold_damping: hold every object's ``material.damping`` at 0 instead of fitting it
            (the variant of :func:`forward_gap` in which an effect with
            ``Effect.replaces_damping`` stands in for the linear damping).
        diff_step: finite-difference step, in units of each parameter's scale.
        ci_level: confidence level of the coefficient intervals.
        default_object: size and mass assumed when the input has none.
        recording: write the rerun recording.
    """

    candidates: tuple[str, ...] = tuple(fx.REGISTRY)
    max_effects: int = Field(3, ge=0)
    noise_floor_chi2: float = Field(1.3, gt=0)
    bic_threshold: float = Field(10.0, ge=0)
    heldout_threshold: float = Field(10.0, ge=0)
    segment_p: float = Field(1e-3, gt=0, lt=1)
    min_segment_samples: int = Field(2, ge=1)
    segment_window: int = Field(5, ge=1)
    contact_tolerance: float = Field(0.005, gt=0)
    rest_speed: float = Field(0.05, gt=0)
    max_nfev: int = Field(15, ge=2)
    max_nfev_warm: int = Field(10, ge=2)
    ftol: float = Field(1e-6, gt=0, lt=1)
    max_nfev_converged: int = Field(100, ge=2)
    screen_ftol: float = Field(1e-4, gt=0, lt=1)
    threads: int = Field(2, ge=1)
    workers: int | None = Field(None, ge=1)
    rescreen_all: bool = False
    screen_gain: float = Field(10.0, ge=0)
    horizons: tuple[float, ...] = (0.5, 1.0)
    forward_split: float = Field(0.6, gt=0, lt=1)
    hold_damping: bool = False
    diff_step: float = Field(1e-2, gt=0)
    ci_level: float = Field(0.95, gt=0, lt=1)
    default_object: DefaultObject = DefaultObject()
    recording: bool = True

    def model_post_init(self, _ctx: Any) -> None:
        for name in self.candidates:
            if name not in fx.REGISTRY:
                raise ValueError(f"candidates: unknown effect {name!r}, must be one of "
                                 f"{', '.join(fx.REGISTRY)}")


# =========================================================================== input
@dataclass
class ObjectSpec:
    """Known properties of one object: shape, size (scene-language keys, m), mass (kg).

    ``assumed`` lists the properties taken from :class:`DefaultObject`."""

    shape: str
    size: dict[str, float]
    mass: float
    assumed: list[str] = field(default_factory=list)

    def support_height(self, R: np.ndarray) -> np.ndarray:
        """Height (m) of the centre above the lowest point for rotations ``R (..., 3, 3)``."""
        R = np.asarray(R)
        if self.shape == "sphere":
            return np.full(R.shape[:-2], self.size["radius"])
        if self.shape == "box":
            half = np.array([self.size["width"], self.size["depth"], self.size["height"]]) / 2
            return np.abs(R[..., 2, :]) @ half
        c = np.clip(np.abs(R[..., 2, 2]), 0.0, 1.0)  # cylinder axis = body z
        return self.size["radius"] * np.sqrt(1.0 - c * c) + self.size["height"] / 2 * c

    @property
    def bounding_radius(self) -> float:
        """m, radius of the smallest sphere around the object (orientation residual scale)."""
        s = self.size
        if self.shape == "sphere":
            return s["radius"]
        if self.shape == "box":
            return 0.5 * math.sqrt(s["width"] ** 2 + s["depth"] ** 2 + s["height"] ** 2)
        return math.sqrt(s["radius"] ** 2 + (s["height"] / 2) ** 2)

    def scene_dict(self) -> dict[str, Any]:
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
    """

    name: str
    source: str
    tracks: list[Track]
    t0: float = 0.0
    z_offset: float = 0.0

    @property
    def times(self) -> np.ndarray:
        """``(T,)`` sorted union of the tracks' sample times, s."""
        return np.unique(np.concatenate([tr.t for tr in self.tracks]))

    @property
    def has_orientation(self) -> bool:
        return any(tr.quat is not None for tr in self.tracks)

    @property
    def fps(self) -> int:
        """Sample rate (median spacing), rounded to an integer for the scene's ``fps``."""
        return int(max(1, round(1.0 / float(np.median(np.diff(self.times))))))


DT_RANGE = (1e-4, 1.0)
"""s; the median sample spacing of every track must lie in this range (10 kHz to 1 Hz): outside
it the times are in other units (ms, us, ns) and the fit would simulate hours or nothing."""
MAX_GAP_FACTOR = 10.0
"""A spacing longer than this many median spacings is a gap the reader refuses (a few
dropped frames pass; a 1,000 s pause in a 60 Hz track does not)."""
MAX_MEDIAN_ACCELERATION_G = 3.0
"""Upper bound on a track's typical acceleration, in units of g = 9.81 m/s^2. Objects on a
floor under gravity accelerate by g in flight, by at most ~mu g sliding and not at all at
rest; the library's effects (drag, wind, Magnus lift, tilt) stay within ~g. The typical value
is the median over 0.1 s windows of a least-squares parabola's curvature (per axis, the median
vector's norm), robust to bounces (a few windows) and to noise (the fit averages it): 1 mm
noise at 240 fps moves it by ~0.5 m/s^2. Millimetres (x1000) or pixels give 10-1000x g."""
GRAVITY_CHECK = 9.81
"""m/s^2, the g of the plausibility checks (the scenes' default gravity)."""
REST_HEIGHT_TOLERANCE = 0.05
"""m. A 3-D track that keeps its height (range < 1 cm over >= 0.2 s, i.e. not falling) must be
held by the floor or by the other objects: its lowest point may be at most this plus the
other objects' diameters above z = 0."""
ACCELERATION_WINDOW = 0.1
"""s, window of the local parabola fits of the acceleration check (at least 5 samples)."""


def _typical_acceleration(t: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """Median over windows of the fitted acceleration of one track.

    Args:
        t: ``(T,)`` strictly increasing times, s, ``T >= 5``.
        pos: ``(T, 3)`` positions, m.
    Returns:
        ``(3,)`` median (over windows of :data:`ACCELERATION_WINDOW` s, at least 5 samples, half
        overlapping) of ``2 c`` of the least-squares fit ``p(t) = a + b t + c t^2`` per axis, m/s^2.
    """
    dt = float(np.median(np.diff(t)))
    w = int(min(len(t), max(5, round(ACCELERATION_WINDOW / dt) + 1)))
    starts = range(0, len(t) - w + 1, max(1, w // 2))
    acc = []
    for s in starts:
        tt = t[s:s + w] - t[s:s + w].mean()
        coef = np.polynomial.polynomial.polyfit(tt, pos[s:s + w], 2)   # (3, 3): rows 1, t, t^2
        acc.append(2.0 * coef[2])
    return np.median(np.asarray(acc), axis=0)


def _check_plausible(path: Path, c: str, o: str, tt: np.ndarray, pos: np.ndarray, rows: np.ndarray,
                     file_col: Mapping[int, str]) -> None:
    """Time units, gaps and position units of one track (see the constants above)."""
    step = np.diff(tt)
    med = float(np.median(step))
    if not DT_RANGE[0] <= med <= DT_RANGE[1]:
        hint = "milliseconds?" if med > DT_RANGE[1] else "micro- or nanoseconds?"
        raise _err(path, "t", f"clip {c!r}, object {o!r}: median sample spacing must be in "
                              f"[{DT_RANGE[0]:g}, {DT_RANGE[1]:g}] s, got {med:.4g} s (times in {hint})")
    k = int(np.argmax(step))
    if step[k] > MAX_GAP_FACTOR * med:
        raise _err(path, "t", f"clip {c!r}, object {o!r}: gaps must be <= {MAX_GAP_FACTOR:g}x the median "
                              f"spacing ({med:.4g} s), got {step[k]:.4g} s from {tt[k]:g} to {tt[k + 1]:g} "
                              f"at row {rows[k + 1]} (split the clip)")
    acc = _typical_acceleration(tt, pos)
    g = GRAVITY_CHECK
    if np.linalg.norm(acc) > MAX_MEDIAN_ACCELERATION_G * g:
        a = max(file_col, key=lambda i: abs(acc[i]))
        raise _err(path, file_col[a], f"clip {c!r}, object {o!r}: typical acceleration must be <= "
                                      f"{MAX_MEDIAN_ACCELERATION_G:g} g ({MAX_MEDIAN_ACCELERATION_G * g:.1f} m/s^2) "
                                      f"for metres, got {np.linalg.norm(acc):.4g} m/s^2 "
                                      f"(positions in millimetres or pixels?)")


def _check_supported(path: Path, c: str, tracks: Sequence["Track"], rows_of: Mapping[str, np.ndarray]) -> None:
    """A 3-D track that does not fall must rest on the floor (z = 0) or on the other objects."""
    reach = sum(2 * tr.spec.bounding_radius for tr in tracks)
    for tr in tracks:
        z = tr.pos[:, 2]
        if tr.t[-1] - tr.t[0] < 0.2 or np.ptp(z) >= 0.01:
            continue
        height = float(np.min(z)) - tr.spec.bounding_radius
        support = reach - 2 * tr.spec.bounding_radius + REST_HEIGHT_TOLERANCE
        if height > support:
            i = int(np.argmin(z))
            raise _err(path, "z", f"clip {c!r}, object {tr.object!r}: an object that does not fall must rest on the "
                                  f"floor (z = 0) or on the other objects (lowest point <= {support:.3g} m), got "
                                  f"{height:.4g} m above the floor for {tr.t[-1] - tr.t[0]:.3g} s at row "
                                  f"{rows_of[tr.object][i]} (positions in millimetres, or the floor not at z = 0?)")


def _err(path: Any, column: str, message: str) -> DiscrepancyInputError:
    return DiscrepancyInputError(f"{path}: column {column}: {message}")


def _read_text_rows(path: Path) -> tuple[list[str], list[list[str]]]:
    """Header and rows of a delimited text file (tab, comma, semicolon or whitespace)."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise DiscrepancyInputError(f"{path}: cannot read: {getattr(exc, 'strerror', None) or exc}") from None
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise DiscrepancyInputError(f"{path}: no header line (empty file)")
    head = lines[0]
    delim = next((d for d in ("\t", ",", ";") if d in head), None)
    if delim is None:
        rows = [ln.split() for ln in lines]
    else:
        rows = list(csv.reader(lines, delimiter=delim))
    header = [h.strip() for h in rows[0]]
    keep = [i for i, h in enumerate(header) if h]       # trailing empty columns ("t,x,y,,")
    header = [header[i] for i in keep]
    body = [[(r[i].strip() if i < len(r) else "") for i in keep] for r in rows[1:]]
    return header, body


def _column_floats(path: Path, name: str, values: Sequence[Any], first_row: int = 2) -> np.ndarray:
    """Parse a numeric column; ``first_row`` is the file row of ``values[0]`` (1-based)."""
    out = np.empty(len(values))
    for i, v in enumerate(values):
        try:
            out[i] = float(v) if v is not None and v != "" else math.nan
        except (TypeError, ValueError):
            raise _err(path, name, f"must be numeric, got {v!r} at row {i + first_row}") from None
    return out


def _load_table(path: Path) -> tuple[dict[str, list | np.ndarray], bool, int]:
    """Columns of a CSV/Parquet/text file, whether it is two-dimensional, and the file row of
    the first data row (for messages)."""
    if path.suffix.lower() == ".parquet":
        import pyarrow.parquet as pq

        try:
            table = pq.read_table(path)
        except Exception as exc:                               # pyarrow raises several types
            raise DiscrepancyInputError(f"{path}: cannot read Parquet: {str(exc).splitlines()[0]}") from None
        cols = {name: table.column(name).to_pylist() for name in table.column_names}
        first = 0
    else:
        header, body = _read_text_rows(path)
        cols = {h: [r[i] for r in body] for i, h in enumerate(header)}
        first = 2
    names = set(cols)
    two_d = "z" not in names and "clip" not in names and "object" not in names and "t" in names
    return cols, two_d, first


def _check_required(path: Path, cols: Mapping[str, Any], required: Sequence[str]) -> None:
    for name in required:
        if name not in cols:
            have = ", ".join(cols) or "none"
            raise _err(path, name, f"required column missing (have: {have})")


def _object_spec(name: str, given: Mapping[str, Any], default: DefaultObject, where: str) -> ObjectSpec:
    """Object spec from given keys (shape, radius/width/depth/height, mass), the object's
    name prefix (``sphere_0`` -> sphere) and the defaults."""
    shape = given.get("shape") or name.split("_")[0]
    if shape not in ("sphere", "cylinder", "box"):
        shape_src = "shape" if given.get("shape") else "object"
        raise DiscrepancyInputError(f"{where}: column {shape_src}: shape must be sphere, cylinder or box "
                                    f"(or an object named <shape>_<i>), got {given.get('shape') or name!r}")
    keys = {"sphere": ("radius",), "cylinder": ("radius", "height"), "box": ("width", "depth", "height")}[shape]
    size, assumed = {}, []
    for key in keys + ("mass",):
        value = given.get(key)
        if value is None or (isinstance(value, float) and math.isnan(value)):
            value = getattr(default, key)
            assumed.append(key)
        try:
            value = float(value)
        except (TypeError, ValueError):
            raise DiscrepancyInputError(f"{where}: column {key}: must be a number, got {value!r}") from None
        if not value > 0 or not math.isfinite(value):
            raise DiscrepancyInputError(f"{where}: column {key}: must be > 0, got {value}")
        if key != "mass":
            size[key] = value
    mass = float(given.get("mass") if "mass" not in assumed else default.mass)
    return ObjectSpec(shape, size, mass, assumed)


def parse_objects(value: str | Path | Mapping | None) -> dict[str, dict[str, dict[str, Any]]]:
    """Objects mapping ``{clip: {object: {shape, radius | width, depth, height, mass}}}``.

    ``clip`` or ``object`` may be ``"*"`` (any). ``value`` is a mapping, a YAML/JSON file
    path, or inline YAML text (e.g. ``'{pingpong: {sphere_0: {radius: 0.02, mass: 0.0027}}}'``).

    Raises:
        DiscrepancyInputError: unreadable file or not a two-level mapping (one line).
    """
    if value is None:
        return {}
    source = "--objects"
    if not isinstance(value, Mapping):
        text = str(value)
        path = Path(text)
        if path.suffix.lower() in (".yaml", ".yml", ".json") or path.exists():
            source = str(path)
            try:
                text = path.read_text()
            except OSError as exc:
                raise DiscrepancyInputError(f"{path}: cannot read: {exc.strerror or exc}") from None
        try:
            value = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise DiscrepancyInputError(f"{source}: malformed YAML: {str(exc).splitlines()[0]}") from None
    if not isinstance(value, Mapping) or not all(isinstance(v, Mapping) for v in value.values()) or \
            not all(isinstance(o, Mapping) for v in value.values() for o in v.values()):
        raise DiscrepancyInputError(f"{source}: must map clip -> object -> {{shape, radius, ..., mass}}")
    return {str(c): {str(o): dict(s) for o, s in v.items()} for c, v in value.items()}


def _lookup_object(objects: Mapping[str, Mapping[str, Mapping]], clip: str, obj: str) -> dict:
    out: dict[str, Any] = {}
    for c in ("*", clip):
        for o in ("*", obj):
            out.update(objects.get(c, {}).get(o, {}))
    return out


def _quat_norm_check(path: Path, q: np.ndarray, rows: np.ndarray) -> None:
    n = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(np.abs(n - 1.0) > 0.05)
    if bad.size:
        raise _err(path, "qw", f"(qw, qx, qy, qz) must be a unit quaternion, got norm {n[bad[0]]:.3g} "
                               f"at row {rows[bad[0]]}")


def read_trajectory_file(path: str | Path, objects: Mapping | None = None,
                         default: DefaultObject | None = None) -> list[Clip]:
    """Read one trajectory file into clips.

    Table files (CSV or Parquet, columns ``clip, object, t, x, y, z`` + optional ``qw..qz``
    and object columns) may hold many clips and objects. Two-dimensional files (header with
    ``t`` and two of ``x``, ``y``, y up; e.g. Tracker exports) hold one clip named after the
    file stem with one object ``sphere_0`` (shape from ``objects`` if given); they map to the
    world frame as x -> x, y -> z, with world y unobserved, lifted by ``Clip.z_offset`` so that
    the floor (unknown in these files) stays out of reach.

    Args:
        path: ``.csv``, ``.parquet``, ``.txt`` or ``.tsv`` file.
        objects: objects mapping (:func:`parse_objects`).
        default: size/mass assumed when neither the file nor ``objects`` gives them.

    Returns:
        Clips in order of first appearance.

    Raises:
        DiscrepancyInputError: ``<file>: column <name>: <problem>`` for a missing column, a
            non-numeric value, NaN, time not strictly increasing within an object, fewer than
            5 samples, coordinates that look like pixels, or a non-unit quaternion; for times
            in other units than s (median spacing outside :data:`DT_RANGE`), a gap over
            :data:`MAX_GAP_FACTOR` median spacings, a typical acceleration over
            :data:`MAX_MEDIAN_ACCELERATION_G` g (millimetres, pixels), or, in 3-D tables, an
            object that neither falls nor rests on the floor or the other objects.
    """
    path = Path(path)
    if not path.is_file():
        raise DiscrepancyInputError(f"{path}: cannot read: no such file")
    cols, two_d, first = _load_table(path)
    return _clips_from_columns(path, cols, two_d, first, objects or {}, default or DefaultObject())


def _clips_from_columns(path: Path, cols: Mapping[str, Any], two_d: bool, first: int,
                        objects: Mapping, default: DefaultObject) -> list[Clip]:
    """Validate table columns and group them into clips (see :func:`read_trajectory_file`)."""
    if two_d:
        _check_required(path, cols, ("t", "x", "y"))
        n = len(cols["t"])
        clip_ids = [path.stem] * n
        obj_ids = ["sphere_0"] * n
        if objects:
            names = [o for o in objects.get(path.stem, {}) if o != "*"]
            if names:
                obj_ids = [names[0]] * n
        t = _column_floats(path, "t", cols["t"], first)
        xs = _column_floats(path, "x", cols["x"], first)
        ys = _column_floats(path, "y", cols["y"], first)
        xyz = np.stack([xs, np.zeros(n), ys], axis=1)
        axes = np.array([True, False, True])
        # messages name the file's columns: world z is the file's y
        file_col = {0: "x", 2: "y"}
    else:
        _check_required(path, cols, TABLE_COLUMNS)
        n = len(cols["t"])
        clip_ids = [str(c) for c in cols["clip"]]
        obj_ids = [str(o) for o in cols["object"]]
        for name in ("clip", "object"):
            for i, v in enumerate(cols[name]):
                if v is None or str(v).strip() == "" or str(v).lower() == "nan":
                    raise _err(path, name, f"must be a non-empty id, got {v!r} at row {i + first}")
        t = _column_floats(path, "t", cols["t"], first)
        xyz = np.stack([_column_floats(path, c, cols[c], first) for c in "xyz"], axis=1)
        axes = np.array([True, True, True])
        file_col = {0: "x", 1: "y", 2: "z"}
    if n == 0:
        raise _err(path, "t", "no rows")
    rows = np.arange(n) + first
    for name, values in [("t", t)] + [(file_col[a], xyz[:, a]) for a in file_col]:
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise _err(path, name, f"NaN or missing value at row {rows[bad[0]]}")
    for a, name in file_col.items():
        big = np.flatnonzero(np.abs(xyz[:, a]) > MAX_ABS_COORDINATE)
        if big.size:
            raise _err(path, name, f"must be metres (|value| <= {MAX_ABS_COORDINATE:g}), got "
                                   f"{xyz[big[0], a]:g} at row {rows[big[0]]} (pixels?)")
    quat = None
    present = [c for c in QUAT_COLUMNS if c in cols]
    if present and not two_d:
        if len(present) != 4:
            missing = [c for c in QUAT_COLUMNS if c not in cols][0]
            raise _err(path, missing, "required with the other orientation columns (qw, qx, qy, qz)")
        quat = np.stack([_column_floats(path, c, cols[c], first) for c in QUAT_COLUMNS], axis=1)
        for j, c in enumerate(QUAT_COLUMNS):
            bad = np.flatnonzero(~np.isfinite(quat[:, j]))
            if bad.size:
                raise _err(path, c, f"NaN or missing value at row {rows[bad[0]]}")
        _quat_norm_check(path, quat, rows)
        quat = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    spec_cols = {c: cols[c] for c in SPEC_COLUMNS if c in cols and not two_d}

    clips: dict[str, dict[str, np.ndarray]] = {}
    for i, (c, o) in enumerate(zip(clip_ids, obj_ids)):
        clips.setdefault(c, {}).setdefault(o, []).append(i)
    out = []
    for c, objs in clips.items():
        tracks = []
        for o, idx in objs.items():
            idx = np.asarray(idx)
            tt = t[idx]
            if len(idx) < MIN_SAMPLES:
                raise _err(path, "t", f"clip {c!r}, object {o!r}: needs at least {MIN_SAMPLES} samples, "
                                      f"got {len(idx)}")
            step = np.diff(tt)
            bad = np.flatnonzero(step <= 0)
            if bad.size:
                k = bad[0] + 1
                raise _err(path, "t", f"must increase strictly within clip {c!r}, object {o!r}: "
                                      f"{tt[k]:g} after {tt[k - 1]:g} at row {rows[idx[k]]}")
            _check_plausible(path, c, o, tt, xyz[idx], rows[idx], file_col)
            given = {}
            for key, values in spec_cols.items():
                vals = {values[j] for j in idx if values[j] is not None and not
                        (isinstance(values[j], float) and math.isnan(values[j])) and values[j] != ""}
                if len(vals) > 1:
                    raise _err(path, key, f"must be constant within clip {c!r}, object {o!r}, got {sorted(map(str, vals))[:3]}")
                if vals:
                    v = vals.pop()
                    given[key] = v if key == "shape" else float(_column_floats(path, key, [v])[0])
            given.update(_lookup_object(objects, c, o))
            spec = _object_spec(o, given, default, f"{path}: clip {c!r}, object {o!r}")
            tracks.append(Track(o, tt, xyz[idx], None if quat is None else quat[idx], axes.copy(), spec))
        if not two_d:   # 2-D files have no floor: their height is arbitrary
            _check_supported(path, c, tracks, {o: rows[np.asarray(idx)] for o, idx in objs.items()})
        t0 = min(float(tr.t[0]) for tr in tracks)
        z_offset = 0.0
        if two_d:  # the file's vertical origin is arbitrary and has no floor: keep clear of z = 0
            lowest = min(float(np.min(tr.pos[:, 2]) - tr.spec.bounding_radius) for tr in tracks)
            z_offset = max(0.0, TWO_D_FLOOR_CLEARANCE - lowest)
        for tr in tracks:
            tr.t = tr.t - t0
            tr.pos[:, 2] += z_offset
        out.append(Clip(c, str(path), tracks, t0, z_offset))
    return out


def read_trajectories(paths: Sequence[str | Path] | str | Path, objects: Any = None,
                      default: DefaultObject | None = None) -> list[Clip]:
    """Read trajectory files and/or directories (``*.parquet``, ``*.csv``, ``*.txt``,
    ``*.tsv``, sorted by name) into clips; see :func:`read_trajectory_file`.

    Raises:
        DiscrepancyInputError: a missing path, an empty directory, bad content, or the same
            clip id in two files.
    """
    if isinstance(paths, (str, Path)):
        paths = [paths]
    objects = parse_objects(objects)
    files: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(f for f in p.iterdir() if f.suffix.lower() in (".parquet", ".csv", ".txt", ".tsv"))
            if not found:
                raise DiscrepancyInputError(f"{p}: no trajectory files (*.parquet, *.csv, *.txt, *.tsv)")
            files += found
        elif p.exists():
            files.append(p)
        else:
            raise DiscrepancyInputError(f"{p}: cannot read: no such file or directory")
    clips: list[Clip] = []
    seen: dict[str, str] = {}
    for f in files:
        for clip in read_trajectory_file(f, objects, default):
            if clip.name in seen:
                raise _err(f, "clip", f"clip id {clip.name!r} also in {seen[clip.name]}")
            seen[clip.name] = str(f)
            clips.append(clip)
    return clips


# =========================================================================== quaternions
def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternion arrays ``(..., 4)`` (w, x, y, z)."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], -1)


def _qconj(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def _qlog(q: np.ndarray) -> np.ndarray:
    """Rotation vector ``(..., 3)`` (rad) of unit quaternions ``(..., 4)`` (shortest arc)."""
    q = np.where(q[..., :1] < 0, -q, q)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    return np.where(s > 1e-12, v * angle / np.maximum(s, 1e-300), 2.0 * v)


def _qexp(r: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(..., 4)`` of rotation vectors ``(..., 3)`` (rad)."""
    r = np.asarray(r, dtype=float)
    a = np.linalg.norm(r, axis=-1, keepdims=True)
    k = np.where(a > 1e-12, np.sin(a / 2) / np.maximum(a, 1e-300), 0.5)
    return np.concatenate([np.cos(a / 2), r * k], -1)


def _qmat(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions ``(..., 4)``."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


# =========================================================================== noise
def _local_quadratic(t: np.ndarray, y: np.ndarray, half: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre-sample residuals of quadratic fits over sliding windows of ``2 half + 1`` samples.

    Args:
        t: ``(T,)`` s. y: ``(T, d)`` values.

    Returns:
        ``(centres (K,), scaled residuals (K, d), slopes (K, d))``: residual of the centre
        sample divided by ``sqrt(1 - h)`` (``h``: its hat-matrix diagonal), so that its
        variance is the noise variance for any smooth signal; slope = fitted derivative.
    """
    T = len(t)
    w = 2 * half + 1
    if T < w:
        return np.zeros(0, int), np.zeros((0, y.shape[1])), np.zeros((0, y.shape[1]))
    centres = np.arange(half, T - half)
    res = np.empty((len(centres), y.shape[1]))
    slope = np.empty_like(res)
    for j, k in enumerate(centres):
        tt = t[k - half:k + half + 1] - t[k]
        A = np.stack([np.ones(w), tt, tt * tt], 1)
        pinv = np.linalg.pinv(A)
        coef = pinv @ y[k - half:k + half + 1]
        h = float((A @ pinv)[half, half])
        res[j] = (y[k] - coef[0]) / math.sqrt(max(1.0 - h, 1e-9))
        slope[j] = coef[1]
    return centres, res, slope


@dataclass
class Noise:
    """Measurement noise of one clip, estimated from the data alone.

    Attributes:
        position: m, standard deviation per observed coordinate.
        angle: rad, standard deviation per rotation-vector component (``None``: no
            orientation data).
        n_position, n_angle: number of values the estimates rest on.
    """

    position: float
    angle: float | None
    n_position: int
    n_angle: int


def estimate_noise(clip: Clip, floor_position: float = 1e-5, floor_angle: float = 1e-4) -> Noise:
    """Estimate the measurement noise of a clip without any model.

    Position: residual of each sample from a quadratic fitted to it and its 4 neighbours
    (scaled by ``1/sqrt(1-h)``), pooled over observed coordinates and objects; sigma =
    1.4826 * median absolute residual (a robust scale: impacts spoil only a few windows).
    Orientation (measured ``q exp(n)``, ``n`` per body axis): the differences of consecutive
    body-frame rotation increments ``log(q_k^-1 q_k+1)`` equal ``n_k+2 - 2 n_k+1 + n_k`` (to
    first order) plus angular acceleration times dt^2, so sigma = 1.4826 * MAD / sqrt(6).

    Args:
        clip: the clip.
        floor_position: m, smallest value returned (noise-free synthetic data).
        floor_angle: rad, likewise.

    Returns:
        :class:`Noise`.
    """
    pos_res, ang_res = [], []
    for tr in clip.tracks:
        _, res, _ = _local_quadratic(tr.t, tr.pos[:, tr.axes])
        pos_res.append(res.ravel())
        if tr.quat is not None and len(tr.t) >= 3:
            inc = _qlog(_qmul(_qconj(tr.quat[:-1]), tr.quat[1:]))
            ang_res.append(((inc[1:] - inc[:-1]) / math.sqrt(6.0)).ravel())
    pr = np.concatenate(pos_res) if pos_res else np.zeros(0)
    sp = 1.4826 * float(np.median(np.abs(pr))) if pr.size else floor_position
    sa, na = None, 0
    if ang_res:
        ar = np.concatenate(ang_res)
        na = ar.size
        sa = max(1.4826 * float(np.median(np.abs(ar - np.median(ar)))), floor_angle)
    return Noise(max(sp, floor_position), sa, int(pr.size), na)


# =========================================================================== simulation
def _sample_rollout(model: mujoco.MjModel, data: mujoco.MjData, n: int, times: np.ndarray) -> np.ndarray:
    """Simulate from the model's ``init`` keyframe and sample ``qpos (T, n, 7)`` at ``times``
    (s, from 0), interpolating linearly between the two physics steps around each time
    (quaternions: normalised lerp). Same stepping as ``pipeline.simulate.rollout``."""
    reset_to_scene(model, data)
    dt = float(model.opt.timestep)
    out = np.empty((len(times), n, 7))
    prev = data.qpos[: 7 * n].copy()
    cur = prev
    step = 0
    qpos = data.qpos
    for k, t in enumerate(times):
        s = t / dt
        target = int(math.ceil(s - 1e-9))
        if step < target:
            while step < target - 1:
                mujoco.mj_step(model, data)
                step += 1
            prev = qpos[: 7 * n].copy()
            mujoco.mj_step(model, data)
            step += 1
            cur = qpos[: 7 * n].copy()
        frac = 1.0 - (step - s) if step > 0 else 1.0
        frac = min(max(frac, 0.0), 1.0)
        q = (prev + frac * (cur - prev)).reshape(n, 7) if frac < 1.0 else cur.reshape(n, 7)
        qa, qb = prev.reshape(n, 7)[:, 3:], cur.reshape(n, 7)[:, 3:]
        if frac < 1.0:
            sign = np.where(np.sum(qa * qb, 1, keepdims=True) < 0, -1.0, 1.0)
            qq = (1 - frac) * qa + frac * sign * qb
            q = q.copy()
            q[:, 3:] = qq / np.linalg.norm(qq, axis=1, keepdims=True)
        out[k] = q
    return out


def _clip_scene(clip: Clip, nuis: np.ndarray | None = None, effects: Mapping[str, Mapping[str, float]] | None = None,
                qref: np.ndarray | None = None) -> Scene:
    """Scene of a clip: its objects with the initial state and material of ``nuis (n, 14)``
    (placeholders if ``None``) and the given effects."""
    objs = []
    for i, tr in enumerate(clip.tracks):
        if nuis is None:
            pos = [0.0, 0.0, 1.0 + 0.5 * i]
            q, v, w, damping, friction = (1.0, 0.0, 0.0, 0.0), [0.0] * 3, [0.0] * 3, 0.0, 0.5
        else:
            x = nuis[i]
            pos = x[_P].tolist()
            q = tuple(_qmul(qref[i], _qexp(x[_R])).tolist())
            v, w = x[_V].tolist(), x[_W].tolist()
            damping, friction = float(x[_D]), float(x[_F])
        objs.append({**tr.spec.scene_dict(), "position": pos, "orientation": q,
                     "linear_velocity": v, "angular_velocity": w,
                     "material": {"sliding_friction": friction, "rolling_friction": 0.0, "damping": damping}})
    duration = float(min(max(clip.times[-1], 1e-3), 60.0))
    data = {"duration": duration, "fps": min(clip.fps, 10000), "gravity": 9.81,
            "camera": {"height": 1.2, "pitch": 35.0, "fov": 45.0}, "objects": objs,
            "effects": [{"effect": k, "parameters": dict(v)} for k, v in (effects or {}).items()]}
    return Scene.from_dict(data, source=f"clip {clip.name}")


_ROLLOUTS: dict[int, Any] = {}


def _rollout_runner(nthread: int):
    """A persistent ``mujoco.rollout.Rollout`` with ``nthread`` threads (0: calling thread)."""
    from mujoco import rollout as mj_rollout

    if nthread not in _ROLLOUTS:
        _ROLLOUTS[nthread] = mj_rollout.Rollout(nthread=nthread)
    return _ROLLOUTS[nthread]


class ClipModel:
    """A clip's scene compiled once for a set of effects; every evaluation edits copies of the
    model in place (effect values via :func:`pipeline.effects.configure_model`, per-object
    damping and friction) and rolls them out from the initial state with
    ``mujoco.rollout`` (many variants per call, e.g. a finite-difference Jacobian, on
    ``threads`` threads). Positions are interpolated linearly between the two physics steps
    around each sample time (quaternions: normalised lerp).

    Args:
        clip: the clip.
        effects: names of the effects present (values are set per call).
        options: simulation options (params ``sim``).
        gravity: m/s^2.
        threads: rollout threads (1: the calling thread).
    """

    def __init__(self, clip: Clip, effects: Sequence[str], options: SimOptions, gravity: float = 9.81,
                 threads: int = 1):
        self.clip = clip
        self.effects = tuple(effects)
        scene = _clip_scene(clip).replace(gravity=gravity)
        self.model, self.base, self.geoms = fx.compile_for_fit(scene, self.effects, options)
        self.threads = max(1, int(threads))
        self.datas = [mujoco.MjData(self.model) for _ in range(self.threads)]
        self.pool: list[mujoco.MjModel] = [self.model]
        self.n = len(clip.tracks)
        self.times = clip.times
        self.qref = np.array([tr.quat[0] if tr.quat is not None else np.array([1.0, 0, 0, 0])
                              for tr in clip.tracks])
        dt = float(self.model.opt.timestep)
        s = self.times / dt
        self._k = np.ceil(s - 1e-9).astype(int)                 # steps to the sample (or just past)
        self._frac = np.clip(1.0 - (self._k - s), 0.0, 1.0)
        self._frac[self._k == 0] = 1.0
        self.nstep = int(self._k.max())
        self._spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        self._nstate = mujoco.mj_stateSize(self.model, self._spec)

    def _configure(self, m: mujoco.MjModel, nuis: np.ndarray, effect_values: Mapping[str, Mapping[str, float]]) -> None:
        fx.configure_model(m, self.base, self.geoms, effect_values)
        m.geom_friction[self.geoms, 0] = nuis[:, _F]
        m.dof_damping[: 6 * self.n] = np.repeat(nuis[:, _D], 6)

    def initial(self, nuis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """MuJoCo ``qpos (7n,)``, ``qvel (6n,)`` of per-object parameters ``nuis (n, 14)``
        (angular velocity converted to the body frame by ``pipeline.mjcf.initial_state``)."""
        objs = [SimpleNamespace(position=x[_P], orientation=_qmul(self.qref[i], _qexp(x[_R])),
                                linear_velocity=x[_V], angular_velocity=x[_W]) for i, x in enumerate(nuis)]
        return initial_state(SimpleNamespace(objects=objs))

    def run(self, nuis_list: Sequence[np.ndarray], effects_list: Sequence[Mapping[str, Mapping[str, float]]]
            ) -> tuple[np.ndarray, np.ndarray]:
        """Roll out variants: per variant ``(n, 14)`` parameters and effect values.

        Returns:
            ``(qpos (B, nstep+1, nq), qvel (B, nstep+1, nv))`` after 0..nstep physics steps.
        """
        B = len(nuis_list)
        while len(self.pool) < B:
            self.pool.append(copy.copy(self.model))
        models, init = [], np.zeros((B, self._nstate))
        d = self.datas[0]
        for b, (nuis, eff) in enumerate(zip(nuis_list, effects_list)):
            m = self.pool[b]
            self._configure(m, nuis, eff)
            models.append(m)
            qpos, qvel = self.initial(nuis)
            mujoco.mj_resetData(m, d)
            d.qpos[: 7 * self.n], d.qvel[: 6 * self.n] = qpos, qvel
            mujoco.mj_getState(m, d, init[b], self._spec)
        runner = _rollout_runner(self.threads if self.threads > 1 else 0)
        state, _ = runner.rollout(models, self.datas, init, nstep=max(self.nstep, 1))
        nq, nv = self.model.nq, self.model.nv
        full = np.concatenate([init[:, None], state], 1)
        return full[..., 1:1 + nq], full[..., 1 + nq:1 + nq + nv]

    def sample(self, qpos: np.ndarray) -> np.ndarray:
        """``(B, nstep+1, nq)`` per-step qpos -> ``(B, T, n, 7)`` at the sample times."""
        B = qpos.shape[0]
        cur = qpos[:, self._k].reshape(B, len(self.times), -1, 7)[:, :, : self.n]
        prev = qpos[:, np.maximum(self._k - 1, 0)].reshape(B, len(self.times), -1, 7)[:, :, : self.n]
        f = self._frac[None, :, None, None]
        out = prev + f * (cur - prev)
        qa, qb = prev[..., 3:], cur[..., 3:]
        sign = np.where(np.sum(qa * qb, -1, keepdims=True) < 0, -1.0, 1.0)
        qq = (1 - f) * qa + f * sign * qb
        out[..., 3:] = qq / np.linalg.norm(qq, axis=-1, keepdims=True)
        return out

    def simulate_many(self, nuis_list: Sequence[np.ndarray],
                      effects_list: Sequence[Mapping[str, Mapping[str, float]]]) -> np.ndarray:
        """``qpos (B, T, n, 7)`` at the clip's sample times for B variants."""
        return self.sample(self.run(nuis_list, effects_list)[0])

    def simulate(self, nuis: np.ndarray, effect_values: Mapping[str, Mapping[str, float]]) -> np.ndarray:
        """``qpos (T, n, 7)`` at the clip's sample times for per-object parameters
        ``nuis (n, 14)`` (:data:`NUISANCE`) and effect values ``{name: parameters}``."""
        return self.simulate_many([nuis], [effect_values])[0]

    def trace(self, nuis: np.ndarray, effect_values: Mapping[str, Mapping[str, float]]
              ) -> tuple[np.ndarray, np.ndarray]:
        """World-frame angular velocity ``(T, n, 3)`` (rad/s, at the physics step nearest each
        sample) and ``qpos (T, n, 7)`` at the sample times."""
        qpos, qvel = self.run([nuis], [effect_values])
        steps = np.rint(self.times / float(self.model.opt.timestep)).astype(int)
        q = qpos[0, steps, : 7 * self.n].reshape(len(steps), self.n, 7)[..., 3:]
        w_body = qvel[0, steps, : 6 * self.n].reshape(len(steps), self.n, 6)[..., 3:]
        omega = np.einsum("tnij,tnj->tni", _qmat(q), w_body)
        return omega, self.sample(qpos)[0]


@dataclass
class Weights:
    """Noise model of a clip: residuals are divided by these (m, rad)."""

    position: float
    angle: float | None


def clip_residuals(clip: Clip, qpos: np.ndarray, weights: Weights) -> tuple[np.ndarray, np.ndarray]:
    """Noise-normalised residuals of a clip and its raw position residuals.

    Args:
        clip: measured clip.
        qpos: ``(T, n, 7)`` simulated at ``clip.times``.
        weights: noise standard deviations.

    Returns:
        ``(r, d)``: ``r`` flat vector (observed position coordinates / sigma_p, then
        orientation rotation-vector error / sigma_angle where measured); ``d`` flat raw
        position residuals (m) of the observed coordinates.
    """
    parts, raw = [], []
    for i, tr in enumerate(clip.tracks):
        idx = np.searchsorted(clip.times, tr.t)
        diff = (qpos[idx, i, :3] - tr.pos)[:, tr.axes]
        raw.append(diff.ravel())
        parts.append(diff.ravel() / weights.position)
        if tr.quat is not None and weights.angle:
            err = _qlog(_qmul(_qconj(qpos[idx, i, 3:]), tr.quat))
            parts.append(err.ravel() / weights.angle)
    return np.concatenate(parts), np.concatenate(raw)


# =========================================================================== fitting
@contextlib.contextmanager
def single_threaded_blas():
    """Run the block with every loaded OpenBLAS (numpy's and scipy's) on one thread, restoring
    the previous counts after. The fits make thousands of small SVDs (scipy's trust region):
    on a loaded 2-core machine a threaded SVD of an 880 x 45 Jacobian took 606 ms instead of
    1.2 ms. (What ``threadpoolctl`` does, without the dependency; no-op where the libraries
    or ``/proc/self/maps`` are missing.)"""
    import ctypes

    restore = []
    try:
        paths = sorted({ln.split()[-1] for ln in open("/proc/self/maps") if "openblas" in ln.lower()})
    except OSError:
        paths = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for get, put in (("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
                         ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
                         ("openblas_get_num_threads", "openblas_set_num_threads")):
            if hasattr(lib, get) and hasattr(lib, put):
                before = int(getattr(lib, get)())
                getattr(lib, put)(1)
                restore.append((getattr(lib, put), before))
                break
    try:
        yield
    finally:
        for put, before in restore:
            put(before)


def _nuisance_scales(clip: Clip) -> np.ndarray:
    """``(n, 14)`` typical magnitudes of the per-object parameters (normalisation)."""
    out = []
    for tr in clip.tracks:
        # The free joint's damping acts on all 6 DoF: its decay rate is b/m on linear and
        # b/I on angular velocity; scale it by the faster (0.01 s^-1 per unit).
        inertia = _min_inertia(tr.spec)
        s = np.array([0.01] * 3 + [0.1] * 3 + [0.1] * 3 + [1.0] * 3 + [0.01 * min(tr.spec.mass, inertia), 0.1])
        out.append(s)
    return np.array(out)


def _min_inertia(spec: ObjectSpec) -> float:
    """Smallest principal moment of inertia (kg m^2) of a solid primitive (as MuJoCo computes
    it from the geom's volume and mass)."""
    s, m = spec.size, spec.mass
    if spec.shape == "sphere":
        return 0.4 * m * s["radius"] ** 2
    if spec.shape == "box":
        w, d, h = s["width"], s["depth"], s["height"]
        return m / 12.0 * min(d * d + h * h, w * w + h * h, w * w + d * d)
    r, h = s["radius"], s["height"]
    return min(0.5 * m * r * r, m * (3 * r * r + h * h) / 12.0)


def _nuisance_bounds(clip: Clip) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the per-object parameters: only damping (>= 0) and friction ([0.01, 3]: a
    zero coefficient switches MuJoCo to condim 1) are bounded; far artificial bounds on the
    others would distort scipy's reflective trust region (Coleman-Li scaling)."""
    inf = math.inf
    lo = [[-inf] * 12 + [0.0, 0.01] for _ in clip.tracks]
    hi = [[inf] * 12 + [inf, 3.0] for _ in clip.tracks]
    return np.array(lo), np.array(hi)


def _near_floor(tr: Track, tol: float) -> bool:
    """Whether the measured object ever comes within ``tol`` of the floor (contacts possible)."""
    if not tr.axes[2]:
        return False
    R = _qmat(tr.quat) if tr.quat is not None else np.eye(3)[None].repeat(len(tr.t), 0)
    h = tr.pos[:, 2] - tr.spec.support_height(R)
    return bool(np.min(h) < max(tol, 0.02))


def free_mask(clip: Clip, effects: Sequence[str], cfg: DiscrepancyConfig) -> np.ndarray:
    """``(n, 14)`` bool: which base parameters are fitted for this clip.

    Frozen: the damping when ``cfg.hold_damping``; position/velocity of unobserved axes; for
    objects that never come near the floor
    the friction (no contact), and, without measured orientation, the orientation and the
    angular velocity (held at 0): they cannot change the measured positions, except through
    ``magnus_lift``, whose lift multiplies the spin; with the spin unobserved the two are not
    separately identifiable, so Magnus lift cannot be named from positions of a free flight.
    """
    masks = []
    for tr in clip.tracks:
        m = np.ones(len(NUISANCE), bool)
        m[_P] = tr.axes
        m[_V] = tr.axes
        contact = _near_floor(tr, cfg.contact_tolerance) or len(clip.tracks) > 1
        if not contact:
            m[_F] = False
        if cfg.hold_damping:
            m[_D] = False
        if tr.quat is None:
            if not contact or tr.spec.shape == "sphere":
                m[_R] = False
            if not contact:  # spin unobserved: held at 0 (so magnus_lift cannot act either)
                m[_W] = False
        masks.append(m)
    return np.array(masks)


def initial_nuisance(clip: Clip) -> np.ndarray:
    """``(n, 14)`` starting values from the data: position and velocity from a quadratic over
    the first 6 samples (an object starting on the floor: vertical velocity 0), orientation =
    first measured sample, angular velocity = slope of the world-frame rotation over the
    first 6 samples, no damping, friction 0.5."""
    out = []
    for tr in clip.tracks:
        x = np.zeros(len(NUISANCE))
        k = min(len(tr.t), 6)
        tt = tr.t[:k] - tr.t[0]
        A = np.stack([np.ones(k), tt, tt * tt], 1)
        coef = np.linalg.lstsq(A, tr.pos[:k], rcond=None)[0]
        x[_P] = np.where(tr.axes, coef[0], 0.0)
        x[_V] = np.where(tr.axes, coef[1], 0.0)
        if tr.quat is not None:  # slope of the accumulated world-frame rotation increments
            inc = _qlog(_qmul(tr.quat[1:k], _qconj(tr.quat[:k - 1])))
            rv = np.concatenate([np.zeros((1, 3)), np.cumsum(inc, 0)])
            x[_W] = np.linalg.lstsq(tt[:, None], rv, rcond=None)[0][0]
        if tr.axes[2]:  # starting on the floor: no vertical velocity, not below its support
            R = _qmat(tr.quat[0]) if tr.quat is not None else np.eye(3)
            hc = float(tr.spec.support_height(R))
            if x[2] - hc < 0.005:
                x[2], x[5] = max(x[2], hc), 0.0
        x[_F] = 0.5
        out.append(x)
    return np.array(out)


@dataclass
class Fit:
    """Result of a least-squares fit over clips.

    Attributes:
        effects: ``{name: all parameter values}`` of the model's effects.
        nuisance: per clip ``(n, 14)`` fitted base parameters.
        chi2: per clip sum of squared noise-normalised residuals.
        sq_pos: per clip sum of squared position residuals, m^2.
        n_res: per clip number of residual scalars; n_pos: of position residuals.
        k: number of fitted parameters.
        theta_keys: ``(effect, parameter)`` of the fitted effect coefficients.
        ci: ``{effect: {parameter: [low, high]}}`` confidence intervals (joint fits only).
        nfev: function evaluations (each = one rollout per clip).
        status: scipy ``least_squares`` status of the last optimiser run (0: the evaluation
            cap was reached; 1-4: a tolerance was met; -2: no free parameter / not run).
        iterations: the optimiser's function evaluations (``sol.nfev``; Jacobians not counted).
        converged: fitted with the converged settings (``cfg.ftol``) and stopped on a tolerance.
        start: which start the fit came from (candidates: ``profile`` or ``base optimum``).
        ci_gn: Gauss-Newton intervals (unclipped, may pass the search bounds).
        ci_method: ``{effect: {parameter: how its interval was found}}``.
    """

    effects: dict[str, dict[str, float]]
    nuisance: list[np.ndarray]
    chi2: list[float]
    sq_pos: list[float]
    n_res: list[int]
    n_pos: list[int]
    k: int
    theta_keys: list[tuple[str, str]] = field(default_factory=list)
    ci: dict[str, dict[str, list[float]]] = field(default_factory=dict)
    nfev: int = 0
    status: int = -2
    iterations: int = 0
    converged: bool = False
    start: str = ""
    ci_gn: dict[str, dict[str, list[float | None]]] = field(default_factory=dict)
    ci_method: dict[str, dict[str, str]] = field(default_factory=dict)

    def optimizer(self) -> dict[str, Any]:
        """``{status, iterations, rollouts, converged, start}`` of the fit (report)."""
        return {"status": int(self.status), "iterations": int(self.iterations), "rollouts": int(self.nfev),
                "converged": bool(self.converged), "start": self.start}

    @property
    def n(self) -> int:
        return int(sum(self.n_res))

    @property
    def rss(self) -> float:
        return float(sum(self.chi2))

    @property
    def rmse(self) -> float:
        """m, position RMSE over all clips."""
        return math.sqrt(sum(self.sq_pos) / max(sum(self.n_pos), 1))

    @property
    def bic(self) -> float:
        """Gaussian BIC with the noise scale profiled out: ``n ln(RSS/n) + k ln n``
        (Schwarz 1978; RSS of noise-normalised residuals)."""
        n = self.n
        return n * math.log(max(self.rss, 1e-300) / n) + self.k * math.log(n)


def _theta_keys(effects: Sequence[str]) -> list[tuple[str, str]]:
    return [(e, p) for e in fx.REGISTRY if e in effects for p, s in fx.REGISTRY[e].parameters.items() if s.fit]


def _effect_values(start: Mapping[str, Mapping[str, float]], keys: Sequence[tuple[str, str]],
                   theta: np.ndarray) -> dict[str, dict[str, float]]:
    vals = {e: dict(p) for e, p in start.items()}
    for (e, p), v in zip(keys, theta):
        vals[e][p] = float(v)
    return vals


def fit_clips(clips: Sequence[Clip], models: Sequence[ClipModel], weights: Sequence[Weights],
              start_nuisance: Sequence[np.ndarray], start_effects: Mapping[str, Mapping[str, float]],
              cfg: DiscrepancyConfig, fit_effects: bool = True, with_ci: bool = False,
              max_nfev: int | None = None, converge: bool = False,
              fixed: Sequence[tuple[str, str]] = ()) -> Fit:
    """Least-squares fit of the clips' base parameters, and (``fit_effects``) the effects'
    shared coefficients, to the measured trajectories.

    The Jacobian is computed by forward differences clip by clip (a clip's residuals depend
    only on its own parameters and the shared coefficients), so one Jacobian costs one
    rollout per free parameter of each clip plus one rollout of every clip per coefficient.
    Parameters are normalised by their scale (:func:`_nuisance_scales`, ``ParamSpec.scale``).

    Args:
        clips, models, weights: per clip, aligned.
        start_nuisance: per clip ``(n, 14)`` starting values.
        start_effects: ``{effect: all parameters}`` starting (or fixed) values.
        cfg: settings (``max_nfev``, ``diff_step``, ``ci_level``).
        fit_effects: fit the effects' coefficients (else they stay at ``start_effects``).
        with_ci: compute confidence intervals of the coefficients.
        max_nfev: overrides ``cfg.max_nfev`` (``cfg.max_nfev_converged`` if ``converge``).
        converge: stop on the tolerance ``cfg.ftol`` (``xtol``, ``gtol`` 100x smaller) with
            ``cfg.max_nfev_converged`` as a safety cap only; else the screening settings
            (``cfg.screen_ftol``, ``max_nfev``).
        fixed: ``(effect, parameter)`` coefficients held at ``start_effects`` (profile
            likelihood).

    Returns:
        :class:`Fit`.
    """
    from scipy.optimize import least_squares

    effects = list(start_effects)
    keys = [k for k in _theta_keys(effects) if k not in set(fixed)] if fit_effects else []
    masks = [free_mask(c, effects, cfg) for c in clips]
    scales = [_nuisance_scales(c) for c in clips]
    bounds = [_nuisance_bounds(c) for c in clips]
    starts = [np.clip(s.copy(), b[0], b[1]) for s, b in zip(start_nuisance, bounds)]
    for s0, sc, m in zip(starts, scales, masks):  # off the damping bound: trf stalls on an active bound
        s0[:, _D] = np.where(m[:, _D], np.maximum(s0[:, _D], 1e-3 * sc[:, _D]), s0[:, _D])
    n_theta = len(keys)
    th_spec = [fx.REGISTRY[e].parameters[p] for e, p in keys]
    th_scale = np.array([s.scale for s in th_spec])
    th_lo = np.array([s.low for s in th_spec])
    th_hi = np.array([s.high for s in th_spec])
    th0 = np.array([start_effects[e][p] for e, p in keys])
    th0 = np.clip(th0, th_lo + 1e-3 * th_scale, th_hi - 1e-3 * th_scale) if n_theta else th0  # off bounds

    sizes = [int(m.sum()) for m in masks]
    offs = np.concatenate([[0], np.cumsum(sizes)]).astype(int)

    # Normalised coordinates relative to the start: u = (x - x_start) / scale, so the trust
    # region starts at radius 1 (one typical magnitude) and scipy's xtol test, relative to
    # |u|, cannot stop the fit at its first rejected steps.
    x_start = np.concatenate([starts[c][masks[c]] for c in range(len(clips))] + [th0])
    x_scale = np.concatenate([scales[c][masks[c]] for c in range(len(clips))] + [th_scale])
    x_lo = np.concatenate([bounds[c][0][masks[c]] for c in range(len(clips))] + [th_lo])
    x_hi = np.concatenate([bounds[c][1][masks[c]] for c in range(len(clips))] + [th_hi])

    def unpack(u: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
        xs = x_start + u * x_scale
        nuis = []
        for c in range(len(clips)):
            x = starts[c].copy()
            x[masks[c]] = xs[offs[c]:offs[c + 1]]
            nuis.append(x)
        return nuis, xs[offs[-1]:]

    u0 = np.zeros(len(x_start))
    lo, hi = (x_lo - x_start) / x_scale, (x_hi - x_start) / x_scale
    counter = {"nfev": 0}

    def clip_res(c: int, nuis_c: np.ndarray, theta: np.ndarray) -> np.ndarray:
        counter["nfev"] += 1
        qpos = models[c].simulate(nuis_c, _effect_values(start_effects, keys, theta))
        return clip_residuals(clips[c], qpos, weights[c])[0]

    cache: dict[bytes, list[np.ndarray]] = {}

    def all_res(u: np.ndarray) -> list[np.ndarray]:
        key = u.tobytes()
        if key not in cache:
            nuis, theta = unpack(u)
            cache.clear()
            cache[key] = [clip_res(c, nuis[c], theta) for c in range(len(clips))]
        return cache[key]

    def fun(u: np.ndarray) -> np.ndarray:
        return np.concatenate(all_res(u))

    rows = np.concatenate([[0], np.cumsum([len(r) for r in all_res(u0)])]).astype(int)
    h = cfg.diff_step

    def jac(u: np.ndarray) -> np.ndarray:
        base = all_res(u)
        nuis, theta = unpack(u)
        values = _effect_values(start_effects, keys, theta)
        J = np.zeros((rows[-1], len(u)))
        th_steps = [h if u[offs[-1] + j] + h <= hi[offs[-1] + j] else -h for j in range(n_theta)]
        th_values = []
        for j in range(n_theta):
            th = theta.copy()
            th[j] += th_steps[j] * th_scale[j]
            th_values.append(_effect_values(start_effects, keys, th))
        for c in range(len(clips)):  # one batched rollout per clip: its columns + the coefficients
            free = np.flatnonzero(masks[c].ravel())
            variants, steps = [], []
            for j, flat in enumerate(free):
                col = offs[c] + j
                step = h if u[col] + h <= hi[col] else -h
                x = nuis[c].copy().ravel()
                x[flat] += step * scales[c].ravel()[flat]
                variants.append(x.reshape(nuis[c].shape))
                steps.append(step)
            effs = [values] * len(variants) + th_values
            variants += [nuis[c]] * n_theta
            if not variants:
                continue
            counter["nfev"] += len(variants)
            qs = models[c].simulate_many(variants, effs)
            cols = [offs[c] + j for j in range(len(free))] + [offs[-1] + j for j in range(n_theta)]
            for q, col, step in zip(qs, cols, steps + th_steps):
                J[rows[c]:rows[c + 1], col] = (clip_residuals(clips[c], q, weights[c])[0] - base[c]) / step
        return J

    status, iterations = -2, 0
    if len(u0):
        if converge:
            cap, ftol = max_nfev or cfg.max_nfev_converged, cfg.ftol
        else:
            cap, ftol = max_nfev or cfg.max_nfev, cfg.screen_ftol
        sol = least_squares(fun, u0, jac=jac, bounds=(lo, hi), method="trf", x_scale=1.0,
                            max_nfev=cap, ftol=ftol, xtol=min(1e-8, ftol * 1e-2), gtol=min(1e-8, ftol * 1e-2))
        u, status, iterations = sol.x, int(sol.status), int(sol.nfev)
    else:
        u = u0
    nuis, theta = unpack(u)
    values = _effect_values(start_effects, keys, theta)
    chi2, sq, n_res, n_pos = [], [], [], []
    for c in range(len(clips)):
        qpos = models[c].simulate(nuis[c], values)
        r, d = clip_residuals(clips[c], qpos, weights[c])
        chi2.append(float(r @ r))
        sq.append(float(d @ d))
        n_res.append(int(r.size))
        n_pos.append(int(d.size))
    fit = Fit(values, nuis, chi2, sq, n_res, n_pos, k=len(u), theta_keys=keys, nfev=counter["nfev"],
              status=status, iterations=iterations, converged=bool(converge and status > 0))
    if with_ci and n_theta:
        fit.ci_gn = _intervals(jac(u), fun(u), keys, th_scale, theta, offs[-1], cfg.ci_level)
        fit.ci = {e: {p: list(v) for p, v in d.items()} for e, d in fit.ci_gn.items()}
        fit.ci_method = {e: {p: "gauss-newton" for p in d} for e, d in fit.ci_gn.items()}
    return fit


def _intervals(J: np.ndarray, r: np.ndarray, keys: Sequence[tuple[str, str]], th_scale: np.ndarray,
               theta: np.ndarray, first: int, level: float) -> dict[str, dict[str, list[float]]]:
    """Confidence intervals of the coefficients from the Jacobian at the optimum:
    covariance ``s^2 (J^T J)^-1`` with ``s^2 = RSS / (n - p)`` (nuisance parameters
    marginalised by the full inverse), half-width ``t_{n-p}(1 - alpha/2) sqrt(diag)``;
    computed by ``mujoco.sysid.calculate_intervals`` (falls back to the same formula with a
    pseudo-inverse where that is not finite). Not clipped to the search bounds (``None`` where
    not finite); :func:`profile_intervals` checks them against the profile."""
    alpha = 1.0 - level
    Jp = J.copy()
    Jp[:, first:] = Jp[:, first:] / th_scale  # normalised -> physical units
    half = np.full(len(keys), np.nan)
    try:
        from mujoco import sysid

        _, half = sysid.calculate_intervals([r], Jp, alpha=alpha)
        half = np.asarray(half)[first:]
    except (ImportError, AttributeError):  # pragma: no cover - sysid is an optional extra
        pass
    if not np.all(np.isfinite(half)):
        # e.g. a parameter without effect on the data (spin of a sphere in free flight) makes
        # J^T J singular and sysid's inverse non-finite: pseudo-inverse (the same formula)
        from scipy import stats

        dof = max(len(r) - J.shape[1], 1)
        cov = float(r @ r) / dof * np.linalg.pinv(Jp.T @ Jp)
        half = np.sqrt(np.maximum(np.diag(cov)[first:], 0)) * stats.t.ppf(1 - alpha / 2, dof)
    out: dict[str, dict[str, list[float | None]]] = {}
    for (e, p), v, hw in zip(keys, theta, half):   # not clipped to the search bounds
        out.setdefault(e, {})[p] = [float(v - hw), float(v + hw)] if np.isfinite(hw) else [None, None]
    return out


# =========================================================================== find
def _velocities(tr: Track) -> np.ndarray:
    """``(T, 3)`` m/s velocity from local quadratic fits (ends: nearest window)."""
    centres, _, slope = _local_quadratic(tr.t, tr.pos)
    if not len(centres):
        return np.gradient(tr.pos, tr.t, axis=0)
    v = np.empty_like(tr.pos)
    idx = np.clip(np.arange(len(tr.t)), centres[0], centres[-1]) - centres[0]
    v[:] = slope[idx]
    return v


def _measured_omega(tr: Track) -> np.ndarray:
    """``(T, 3)`` rad/s world-frame angular velocity from measured orientations."""
    inc = _qlog(_qmul(tr.quat[1:], _qconj(tr.quat[:-1]))) / np.diff(tr.t)[:, None]
    w = np.empty((len(tr.t), 3))
    w[0], w[-1] = inc[0], inc[-1]
    w[1:-1] = 0.5 * (inc[1:] + inc[:-1])
    return w


def motion_phases(clip: Clip, sim_qpos: np.ndarray, sim_omega: np.ndarray, noise: Noise,
                  cfg: DiscrepancyConfig) -> list[np.ndarray]:
    """Motion phase of every measured sample: flight, contact, sliding, rolling or rest.

    On the floor = the object's lowest point (measured centre minus its support height for
    the measured orientation, or the fitted base model's where none is measured) within
    ``max(contact_tolerance, 3 sigma)`` of z = 0. Contact = an impact: arriving on the floor,
    or a minimum of height where the vertical velocity turns from down to up (bounces shorter
    than a frame), plus the samples on either side. Rest = on the floor slower than
    ``rest_speed``. Rolling = on the floor with the contact point's slip speed
    ``|v + omega x (-h z)|`` below ``max(rest_speed, 0.2 |v|)`` (omega measured, else from the
    fitted base model); sliding otherwise. Flight = not on the floor.

    Args:
        clip: measured clip.
        sim_qpos: ``(T, n, 7)`` base-model states at ``clip.times``.
        sim_omega: ``(T, n, 3)`` base-model angular velocities, rad/s.
        noise: the clip's noise estimate.
        cfg: thresholds.

    Returns:
        Per track an array ``(T_i,)`` of phase names.
    """
    out = []
    tol = max(cfg.contact_tolerance, 3.0 * noise.position)
    for i, tr in enumerate(clip.tracks):
        idx = np.searchsorted(clip.times, tr.t)
        quat = tr.quat if tr.quat is not None else sim_qpos[idx, i, 3:]
        omega = _measured_omega(tr) if tr.quat is not None else sim_omega[idx, i]
        hc = tr.spec.support_height(_qmat(quat))
        z = tr.pos[:, 2] if tr.axes[2] else sim_qpos[idx, i, 2]
        h = z - hc
        v = _velocities(tr)
        on = h < tol
        speed = np.linalg.norm(v[:, tr.axes], axis=1)
        slip_v = v + np.cross(omega, np.stack([np.zeros_like(hc), np.zeros_like(hc), -hc], 1))
        slip = np.linalg.norm(slip_v[:, :2], axis=1)
        phase = np.where(~on, "flight", np.where(speed < cfg.rest_speed, "rest",
                         np.where(slip < np.maximum(cfg.rest_speed, 0.2 * speed), "rolling", "sliding")))
        phase = phase.astype(object)
        T = len(tr.t)
        for k in range(1, T):
            arrive = on[k] and not on[k - 1]
            bounce = (0 < k < T - 1 and h[k] <= h[k - 1] and h[k] <= h[k + 1] and v[k - 1, 2] < -cfg.rest_speed
                      and v[k + 1, 2] > cfg.rest_speed
                      and h[k] < tol + abs(v[k - 1, 2]) * (tr.t[k] - tr.t[k - 1]))
            if arrive or bounce:
                phase[max(k - 1, 0):min(k + 2, T)] = "contact"
        out.append(phase.astype(str))
    return out


def residual_segments(clip: Clip, qpos: np.ndarray, noise: Noise, phases: Sequence[np.ndarray],
                      cfg: DiscrepancyConfig) -> list[dict[str, Any]]:
    """Time ranges where the model's residual exceeds the measurement noise.

    Samples are flagged in windows of ``segment_window`` consecutive samples whose summed
    squared residual over sigma^2 exceeds the chi-square quantile ``1 - segment_p`` (degrees
    of freedom: window length times observed coordinates, or 3 for orientation), so both
    single outliers and small systematic offsets that persist are found; runs of flagged
    samples of at least ``min_segment_samples`` form a segment. ``threshold`` is the RMS
    residual at which a window is flagged.

    Args:
        clip: measured clip.
        qpos: ``(T, n, 7)`` model states at ``clip.times``.
        noise: the clip's noise.
        phases: per track phase names (:func:`motion_phases`).
        cfg: thresholds.

    Returns:
        Dicts ``{clip, object, channel ('position' | 'orientation'), t_start, t_end (s, clip
        time), n_samples, phase (most frequent), phases ({phase: count}), max (m or deg),
        rms (m or deg), threshold (m or deg)}``.
    """
    from scipy.stats import chi2

    segs = []
    for i, tr in enumerate(clip.tracks):
        idx = np.searchsorted(clip.times, tr.t)
        chans = [("position", np.linalg.norm((qpos[idx, i, :3] - tr.pos)[:, tr.axes], axis=1),
                  noise.position, int(tr.axes.sum()), 1.0)]
        if tr.quat is not None and noise.angle:
            err = np.linalg.norm(_qlog(_qmul(_qconj(qpos[idx, i, 3:]), tr.quat)), axis=1)
            chans.append(("orientation", err, noise.angle, 3, 180.0 / math.pi))
        for name, e, sigma, dof, unit in chans:
            w = min(cfg.segment_window, len(e))
            thr = sigma * math.sqrt(chi2.isf(cfg.segment_p, w * dof) / w)
            flag = np.zeros(len(e), bool)
            z = (e / sigma) ** 2
            for k in range(len(e) - w + 1):
                if z[k:k + w].sum() > chi2.isf(cfg.segment_p, w * dof):
                    flag[k:k + w] = True
            k = 0
            while k < len(flag):
                if not flag[k]:
                    k += 1
                    continue
                j = k
                while j + 1 < len(flag) and flag[j + 1]:
                    j += 1
                if j - k + 1 >= cfg.min_segment_samples:
                    ph, counts = np.unique(phases[i][k:j + 1], return_counts=True)
                    segs.append({"clip": clip.name, "object": tr.object, "channel": name,
                                 "t_start": round(float(tr.t[k] + clip.t0), 4),
                                 "t_end": round(float(tr.t[j] + clip.t0), 4), "n_samples": int(j - k + 1),
                                 "phase": str(ph[np.argmax(counts)]),
                                 "phases": {str(p): int(c) for p, c in zip(ph, counts)},
                                 "max": float(e[k:j + 1].max() * unit),
                                 "rms": float(np.sqrt(np.mean(e[k:j + 1] ** 2)) * unit),
                                 "threshold": float(thr * unit)})
                k = j + 1
    return segs


# =========================================================================== name
@dataclass
class HeldOut:
    """Cross-validated scores of a model: per clip, chi-square / squared position residual /
    counts when the effects' coefficients come from the other clips (leave one clip out)."""

    chi2: list[float]
    sq_pos: list[float]
    n_res: list[int]
    n_pos: list[int]
    theta: list[dict[str, dict[str, float]]] = field(default_factory=list)

    @property
    def total_chi2(self) -> float:
        return float(sum(self.chi2))

    @property
    def rmse(self) -> float:
        """m, held-out position RMSE over all clips."""
        return math.sqrt(sum(self.sq_pos) / max(sum(self.n_pos), 1))

    def clip_rmse(self, c: int) -> float:
        return math.sqrt(self.sq_pos[c] / max(self.n_pos[c], 1))


FRICTION_GRID = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.8, 1.0, 1.4)
"""Sliding-friction values tried before a base fit's least squares (the residual is not
convex in friction: a wrong start can leave it in a basin where the spin compensates)."""


def _scan_friction(clip: Clip, model: ClipModel, weights: Weights, nuis: np.ndarray,
                   effects: Mapping[str, Mapping[str, float]], cfg: DiscrepancyConfig) -> np.ndarray:
    """Start values with each object's friction set, in turn, to the best of
    :data:`FRICTION_GRID` and the current value (others held); unchanged where friction is
    not fitted."""
    mask = free_mask(clip, tuple(effects), cfg)
    nuis = nuis.copy()
    for i in range(len(clip.tracks)):
        if not mask[i, _F]:
            continue
        grid = (nuis[i, _F],) + FRICTION_GRID
        variants = []
        for mu in grid:
            x = nuis.copy()
            x[i, _F] = mu
            variants.append(x)
        qs = model.simulate_many(variants, [effects] * len(grid))
        chi = [float(r @ r) for r in (clip_residuals(clip, q, weights)[0] for q in qs)]
        nuis[i, _F] = grid[int(np.argmin(chi))]
    return nuis


def _truncate(clip: Clip, t_max: float) -> Clip | None:
    """The clip's samples up to ``t_max`` (s), or ``None`` if an object keeps fewer than
    :data:`MIN_SAMPLES`."""
    tracks = []
    for tr in clip.tracks:
        keep = tr.t <= t_max + 1e-9
        if keep.sum() < MIN_SAMPLES:
            return None
        tracks.append(Track(tr.object, tr.t[keep], tr.pos[keep], None if tr.quat is None else tr.quat[keep],
                            tr.axes, tr.spec))
    return Clip(clip.name, clip.source, tracks, clip.t0, clip.z_offset)


class Workspace:
    """Clips, noise weights and compiled models (one per clip and effect set, cached)."""

    def __init__(self, clips: Sequence[Clip], cfg: DiscrepancyConfig, options: SimOptions, gravity: float = 9.81):
        self.clips = list(clips)
        self.cfg = cfg
        self.options = options
        self.gravity = gravity
        self.noise = [estimate_noise(c) for c in self.clips]
        self.weights = [Weights(n.position, n.angle) for n in self.noise]
        self._models: dict[tuple[int, tuple[str, ...]], ClipModel] = {}
        self._pool = None

    def model(self, c: int, effects: Iterable[str]) -> ClipModel:
        key = (c, tuple(e for e in fx.REGISTRY if e in set(effects)))
        if key not in self._models:
            self._models[key] = ClipModel(self.clips[c], key[1], self.options, self.gravity, self.cfg.threads)
        return self._models[key]

    def fit(self, idx: Sequence[int], starts: Sequence[np.ndarray], effects: Mapping[str, Mapping[str, float]],
            fit_effects: bool = True, with_ci: bool = False, max_nfev: int | None = None,
            converge: bool = False, fixed: Sequence[tuple[str, str]] = ()) -> Fit:
        """:func:`fit_clips` on the clips ``idx``."""
        return fit_clips([self.clips[c] for c in idx], [self.model(c, effects) for c in idx],
                         [self.weights[c] for c in idx], starts, effects, self.cfg, fit_effects, with_ci, max_nfev,
                         converge, fixed)

    def fit_each(self, idx: Sequence[int], starts: Sequence[np.ndarray],
                 effects: Mapping[str, Mapping[str, float]], max_nfev: int | None = None,
                 converge: bool = False) -> Fit:
        """Fit every clip on its own with the effects' values held (no shared parameters),
        merged into one :class:`Fit` (k counts every clip's parameters).

        Each clip is fitted by continuation over the time horizon (:meth:`fit_clip`). The
        clips are independent, so with a worker pool (:meth:`start_pool`) they are fitted in
        parallel; the result is the same to the last bit (each clip's fit runs the same
        arithmetic in whichever process)."""
        jobs = [(c, start, {e: dict(p) for e, p in effects.items()}, max_nfev, converge)
                for c, start in zip(idx, starts)]
        if self._pool is not None and len(jobs) > 1:
            parts = list(self._pool.map(_pool_fit_clip, jobs))
        else:
            parts = [self.fit_clip(*job) for job in jobs]
        return Fit({e: dict(p) for e, p in effects.items()}, [p.nuisance[0] for p in parts],
                   [p.chi2[0] for p in parts], [p.sq_pos[0] for p in parts], [p.n_res[0] for p in parts],
                   [p.n_pos[0] for p in parts], k=sum(p.k for p in parts), nfev=sum(p.nfev for p in parts),
                   status=min((p.status for p in parts), default=-2),
                   iterations=sum(p.iterations for p in parts),
                   converged=bool(parts) and all(p.converged or p.status == -2 for p in parts))

    def fit_clip(self, c: int, start: np.ndarray, effects: Mapping[str, Mapping[str, float]],
                 max_nfev: int | None = None, converge: bool = False) -> Fit:
        """Fit clip ``c`` alone (effects held) by continuation over the time horizon
        (``cfg.horizons``: first the opening fraction of the clip, then longer, warm-starting
        each from the last), so that late contacts do not pull the initial state into a wrong
        basin. With ``converge`` the last horizon (the whole clip) runs to the tolerance
        ``cfg.ftol``.

        Args:
            c: clip index. start: ``(n, 14)`` starting values (:data:`NUISANCE`).
            effects: ``{effect: parameters}`` held. max_nfev: screening cap.

        Returns:
            a one-clip :class:`Fit` (the last horizon's)."""
        clip = self.clips[c]
        part = None
        for frac in self.cfg.horizons:
            sub = _truncate(clip, frac * float(clip.times[-1])) if frac < 1.0 else clip
            if sub is None:
                continue
            model = ClipModel(sub, tuple(effects), self.options, self.gravity, self.cfg.threads) if frac < 1.0 \
                else self.model(c, effects)
            start = _scan_friction(sub, model, self.weights[c], start, effects, self.cfg)
            last = frac >= self.cfg.horizons[-1]
            part = fit_clips([sub], [model], [self.weights[c]], [start], effects, self.cfg,
                             fit_effects=False, max_nfev=None if (converge and last) else max_nfev,
                             converge=converge and last)
            start = part.nuisance[0]
        assert part is not None  # the last horizon is the whole clip (cfg.horizons ends at 1)
        return part

    def refit_each(self, idx: Sequence[int], starts: Sequence[np.ndarray],
                   effects: Mapping[str, Mapping[str, float]], max_nfev: int | None = None,
                   converge: bool = False) -> list[Fit]:
        """Warm-started fits of each clip alone from ``starts`` (effects held; one horizon,
        no friction scan): ``[ws.fit([c], [start], effects, fit_effects=False, ...)]`` for the
        clips ``idx``, in parallel when a pool is running (same result to the last bit)."""
        jobs = [(c, start, {e: dict(p) for e, p in effects.items()}, max_nfev, converge)
                for c, start in zip(idx, starts)]
        if self._pool is not None and len(jobs) > 1:
            return list(self._pool.map(_pool_refit_clip, jobs))
        return [self.fit([c], [start], eff, fit_effects=False, max_nfev=m, converge=cv)
                for c, start, eff, m, cv in jobs]

    def start_pool(self, workers: int) -> None:
        """Fit clips in ``workers`` processes (:meth:`fit_each`); each worker holds its own
        copy of this workspace with one rollout thread, made once. No-op for ``workers`` < 2,
        fewer than two clips, or inside a daemonic process (a multiprocessing pool's worker,
        which may not have children). Pair with :meth:`close`."""
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        if workers < 2 or len(self.clips) < 2 or self._pool is not None:
            return
        if multiprocessing.current_process().daemon:   # a pool worker itself: no children allowed
            return

        cfg = self.cfg.model_copy(update={"threads": 1, "workers": 1})
        self._pool = ProcessPoolExecutor(min(workers, len(self.clips)), mp_context=multiprocessing.get_context("spawn"),
                                         initializer=_pool_init,
                                         initargs=(self.clips, cfg, self.options, self.gravity))

    def close(self) -> None:
        """Shut the worker pool down (if any)."""
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
            self._pool = None


_POOL_WS: "Workspace | None" = None


def _pool_init(clips: Sequence[Clip], cfg: DiscrepancyConfig, options: SimOptions, gravity: float) -> None:
    """Worker start: its own :class:`Workspace` (models compiled on first use, then cached)."""
    global _POOL_WS
    _POOL_WS = Workspace(clips, cfg, options, gravity)


def _pool_fit_clip(job: tuple) -> Fit:
    with single_threaded_blas():
        return _POOL_WS.fit_clip(*job)


def _pool_refit_clip(job: tuple) -> Fit:
    c, start, effects, max_nfev, converge = job
    with single_threaded_blas():
        return _POOL_WS.fit([c], [start], effects, fit_effects=False, max_nfev=max_nfev, converge=converge)


def _scan_effect(ws: "Workspace", idx: Sequence[int], nuisance: Sequence[np.ndarray],
                 effects: Mapping[str, Mapping[str, float]], name: str, exclude_null: bool = False
                 ) -> dict[str, float]:
    """Start values of effect ``name``: the best point of its parameters' grids
    (``ParamSpec.grid``, full product; without the all-null point if ``exclude_null``) with
    the clips' parameters and the other effects held."""
    import itertools

    cls = fx.REGISTRY[name]
    params = cls.defaults()
    keys = [p for p, s in cls.parameters.items() if s.fit and s.grid]
    if not keys:
        return params
    others = {k: dict(v) for k, v in effects.items() if k != name}
    grids = [cls.parameters[p].grid for p in keys]
    cands = [{**params, **dict(zip(keys, values))} for values in itertools.product(*grids)
             if not (exclude_null and all(v == g[0] for v, g in zip(values, grids)))]
    trials = [{**others, name: cand} for cand in cands]
    total = np.zeros(len(cands))
    for c in idx:
        qs = ws.model(c, trials[0]).simulate_many([nuisance[c]] * len(trials), trials)
        total += [float(r @ r) for r in (clip_residuals(ws.clips[c], q, ws.weights[c])[0] for q in qs)]
    return dict(cands[int(np.argmin(total))])


def screen_candidates(ws: "Workspace", idx: Sequence[int], current: Fit, names: Sequence[str]
                      ) -> dict[str, dict[str, Any]]:
    """Cheap screen of candidate effects before their full fits: the chi-square each one could
    gain, predicted by linearising the clips' own parameters at the current optimum.

    Per clip ``c``, with the current parameters ``x_c`` and the Jacobian ``J_c`` of its
    residuals with respect to its free parameters (forward differences, one batched rollout),
    the effect at each point ``s`` of its grid (``ParamSpec.grid``, full product without the
    null point) gives residuals ``r_c(s)``; re-fitting ``x_c`` to first order leaves
    ``|(I - J_c J_c^+) r_c(s)|^2`` (variable projection, Golub & Pereyra 1973). The predicted
    gain is that sum over clips at the null point minus its minimum over the grid, computed
    twice: over all residuals, and over the position residuals alone (orientation errors of a
    fast spin wrap around and are far from linear in the parameters: an effect that slows the
    spin, like drag, would otherwise look harmful). The larger of the two is reported. Costs
    one rollout per free parameter of each clip once, plus one per grid point and clip per
    candidate; a full candidate fit costs hundreds of times more.

    Args:
        ws: workspace. idx: clips. current: the converged current model.
        names: candidate effects (not in ``current.effects``).

    Returns:
        ``{name: {"predicted_gain": float (chi-square) or None (no grid), "position_gain",
        "full_gain", "best": {parameter: value}}}``.
    """
    import itertools

    h = ws.cfg.diff_step
    proj: list[list[np.ndarray]] = []
    rows_pos: list[np.ndarray] = []
    null = np.zeros(2)

    def leftover(r: np.ndarray, Qs: Sequence[np.ndarray], pos: np.ndarray) -> np.ndarray:
        full = r - Qs[0] @ (Qs[0].T @ r)
        rp = r[pos]
        part = rp - Qs[1] @ (Qs[1].T @ rp)
        return np.array([float(full @ full), float(part @ part)])

    def basis(J: np.ndarray) -> np.ndarray:
        if not J.size:
            return np.zeros((J.shape[0], 0))
        U, sv, _ = np.linalg.svd(J, full_matrices=False)
        return U[:, sv > sv[0] * 1e-9] if sv[0] > 0 else np.zeros((J.shape[0], 0))

    for c in idx:
        clip, nuis, w = ws.clips[c], current.nuisance[c], ws.weights[c]
        model = ws.model(c, current.effects)
        mask = free_mask(clip, tuple(current.effects), ws.cfg)
        scale = _nuisance_scales(clip)
        lo, hi = _nuisance_bounds(clip)
        variants, steps = [], []
        for flat in np.flatnonzero(mask.ravel()):
            x = nuis.copy().ravel()
            step = h * scale.ravel()[flat]
            step = step if x[flat] + step <= hi.ravel()[flat] else -step
            x[flat] += step
            variants.append(x.reshape(nuis.shape))
            steps.append(step)
        qs = model.simulate_many([nuis] + variants, [current.effects] * (1 + len(variants)))
        r0 = clip_residuals(clip, qs[0], w)[0]
        J = np.stack([(clip_residuals(clip, q, w)[0] - r0) / st for q, st in zip(qs[1:], steps)], 1) \
            if variants else np.zeros((len(r0), 0))
        pos = _position_rows(clip, w)
        Qs = [basis(J), basis(J[pos])]
        proj.append(Qs)
        rows_pos.append(pos)
        null += leftover(r0, Qs, pos)
    out: dict[str, dict[str, Any]] = {}
    for name in names:
        cls = fx.REGISTRY[name]
        keys = [k for k, sp in cls.parameters.items() if sp.fit and sp.grid]
        if not keys:
            out[name] = {"predicted_gain": None, "best": cls.defaults()}   # nothing to screen on
            continue
        grids = [cls.parameters[k].grid for k in keys]
        points = [{**cls.defaults(), **dict(zip(keys, v))} for v in itertools.product(*grids)
                  if not all(a == g[0] for a, g in zip(v, grids))]
        effs = [{**current.effects, name: pt} for pt in points]
        total = np.zeros((len(points), 2))
        for c, Qs, pos in zip(idx, proj, rows_pos):
            qs = ws.model(c, effs[0]).simulate_many([current.nuisance[c]] * len(points), effs)
            for j, q in enumerate(qs):
                total[j] += leftover(clip_residuals(ws.clips[c], q, ws.weights[c])[0], Qs, pos)
        gains = null[None, :] - total
        b = int(np.argmax(gains.max(1)))
        out[name] = {"predicted_gain": float(gains.max()), "full_gain": float(gains[:, 0].max()),
                     "position_gain": float(gains[:, 1].max()), "best": points[b]}
    return out


def _second_chance_point(name: str, best: Mapping[str, float]) -> dict[str, float]:
    """Strength at which a candidate the linearised screen rejected is refitted from the data:
    for one fitted parameter the middle of its non-null grid (``(len - 1) // 2``, e.g. drag
    density 3 kg/m^3, Magnus lift 1, restitution 0.5), for several the screen's best grid point
    (its direction)."""
    cls = fx.REGISTRY[name]
    keys = [k for k, sp in cls.parameters.items() if sp.fit and sp.grid]
    if len(keys) != 1:
        return dict(best)
    grid = [v for v in cls.parameters[keys[0]].grid[1:]]
    return {**cls.defaults(), keys[0]: float(sorted(grid, key=abs)[(len(grid) - 1) // 2])}


def _position_rows(clip: Clip, weights: Weights) -> np.ndarray:
    """Indices of the position rows of :func:`clip_residuals` (per object: positions first,
    then orientation rows where measured and weighted)."""
    rows, at = [], 0
    for tr in clip.tracks:
        k = len(tr.t) * int(np.sum(tr.axes))
        rows.append(np.arange(at, at + k))
        at += k
        if tr.quat is not None and weights.angle:
            at += 3 * len(tr.t)
    return np.concatenate(rows) if rows else np.zeros(0, int)


@dataclass
class Profile:
    """An effect's profile: at each point along one coordinate ``s`` (its strength, along a
    fixed direction for multi-parameter effects) every clip's own parameters are fitted with
    the effect held (per-clip continuation from the data), so ``chi2[p, c]`` is clip ``c``'s
    best chi-square at point ``p``."""

    s: list[float]
    params: list[dict[str, float]]
    chi2: list[list[float]]
    sq: list[list[float]]
    nuis: list[list[np.ndarray]]

    def add(self, s: float, params: dict[str, float], fits: Fit) -> None:
        self.s.append(float(s))
        self.params.append(params)
        self.chi2.append(list(fits.chi2))
        self.sq.append(list(fits.sq_pos))
        self.nuis.append(list(fits.nuisance))

    def total(self, without: int | None = None) -> np.ndarray:
        """``(P,)`` summed chi-square over clips (leaving clip ``without`` out)."""
        chi = np.array(self.chi2)
        if without is not None:
            chi = np.delete(chi, without, axis=1)
        return chi.sum(axis=1)


CHI2_1_95 = 3.841
"""95 % quantile of chi-square with one degree of freedom (profile-likelihood interval)."""


def _fit_rows(prof: "Profile", p: int) -> Fit:
    """Profile row ``p`` as a :class:`Fit` (per-clip values only)."""
    n = len(prof.chi2[p])
    return Fit({}, list(prof.nuis[p]), list(prof.chi2[p]), list(prof.sq[p]), [0] * n, [0] * n, 0)


def _parabola_min(s: Sequence[float], y: np.ndarray) -> float:
    """Coordinate of the minimum of ``y(s)``: the vertex of the parabola through the best
    point and its neighbours (sorted by ``s``), or the best point at an edge."""
    order = np.argsort(s)
    ss, yy = np.asarray(s)[order], np.asarray(y)[order]
    b = int(np.argmin(yy))
    if b == 0 or b == len(ss) - 1:
        return float(ss[b])
    x0, x1, x2 = ss[b - 1:b + 2]
    y0, y1, y2 = yy[b - 1:b + 2]
    den = (x0 - x1) * (x0 - x2) * (x1 - x2)
    A = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / den
    B = (x2 * x2 * (y0 - y1) + x1 * x1 * (y2 - y0) + x0 * x0 * (y1 - y2)) / den
    if A <= 0:
        return float(x1)
    return float(np.clip(-B / (2 * A), x0, x2))


def _vanishes(ws: "Workspace", c: int, current: Fit, name: str, params: Mapping[str, float]) -> bool:
    """Whether adding effect ``name`` with ``params`` leaves the current model unchanged
    (same rollout of clip ``c``), e.g. no drag density while wind is present does not."""
    if not fx.REGISTRY[name].nested:
        return False
    with_effect = {**current.effects, name: dict(params)}
    a = ws.model(c, current.effects).simulate(current.nuisance[c], current.effects)
    b = ws.model(c, with_effect).simulate(current.nuisance[c], with_effect)
    return bool(np.allclose(a, b, rtol=0, atol=1e-9))


def _refit_from_data(ws: "Workspace", idx: Sequence[int], fit: Fit) -> Fit:
    """``fit`` with each clip's parameters replaced by a per-clip continuation fit from the data
    (effects held) where that is better, so that a model and its extensions are compared at
    equally good optima (otherwise re-fitting alone can pass for an effect)."""
    again = ws.fit_each(idx, [initial_nuisance(ws.clips[c]) for c in idx], fit.effects)
    out = Fit({k: dict(v) for k, v in fit.effects.items()}, list(fit.nuisance), list(fit.chi2), list(fit.sq_pos),
              list(fit.n_res), list(fit.n_pos), fit.k, list(fit.theta_keys), dict(fit.ci), fit.nfev)
    for c in range(len(idx)):
        if again.chi2[c] < out.chi2[c]:
            out.nuisance[c], out.chi2[c], out.sq_pos[c] = again.nuisance[c], again.chi2[c], again.sq_pos[c]
    return out


def _profile_axis(ws: "Workspace", idx: Sequence[int], current: Fit, name: str
                  ) -> tuple[list[float], Any]:
    """Profile coordinates and the map ``s -> parameters`` of effect ``name``.

    One fitted parameter: ``s`` is the parameter and the points are its grid. Several: a
    direction from the best non-zero grid point with the clips' parameters held
    (:func:`_scan_effect`), and magnitudes ``(0, 1/4, 1/2, 1, 1.6) x`` the grids' largest
    value along it."""
    cls = fx.REGISTRY[name]
    keys = [p for p, sp in cls.parameters.items() if sp.fit]
    defaults = cls.defaults()
    if len(keys) == 1:
        key = keys[0]
        return list(cls.parameters[key].grid), lambda v: {**defaults, key: float(v)}
    best = _scan_effect(ws, idx, current.nuisance, current.effects, name, exclude_null=True)
    d = np.array([best[k] for k in keys], dtype=float)
    d = d / (np.linalg.norm(d) or 1.0)
    top = max(max(abs(g) for g in cls.parameters[k].grid) for k in keys)
    mags = [0.0, 0.25 * top, 0.5 * top, top, 1.6 * top]
    return mags, lambda v: {**defaults, **{k: float(v * dk) for k, dk in zip(keys, d)}}


def _profile_candidate(ws: "Workspace", idx: Sequence[int], current: Fit, name: str,
                       baseline: Fit | None = None) -> tuple[Fit, HeldOut, Profile]:
    """Fit the current model plus effect ``name`` and score it out of sample.

    1. Profile: at each point of :func:`_profile_axis` (the first is where the effect
       vanishes, i.e. the current model), every clip's parameters are fitted by continuation
       from the data (:meth:`Workspace.fit_each`); the summed minimum is refined by a
       parabola step. Fitting from the data at every strength avoids the basin in which the
       current model compensated for the missing effect (warm-starting from it left a ball
       with air drag at chi2/n 3-6 instead of 0.8).
    2. Joint fit: from the best point, the coefficients and all clips' parameters together.
    3. Held-out (leave one clip out): the strength that minimises the other clips' profile,
       refined by a parabola step; but the effect's default value (a profile point, e.g. air
       for drag), else no effect, where that lies within the others' 95 % profile interval
       (clips that carry no information on the effect do not set it); the left-out clip
       refitted there.

    ``current`` is the converged current model (start of the joint fit, :func:`_joint_fit`);
    ``baseline`` (default ``current``) the current model fitted like the profile points (per
    clip from the data, screening budget), used as the profile's first point where the effect
    vanishes, so that the profile compares like with like.

    Returns:
        ``(joint fit, held-out scores, profile)``.
    """
    baseline = baseline or current
    s_pts, to_params = _profile_axis(ws, idx, current, name)
    prof = Profile([], [], [], [], [])
    others = {k: dict(v) for k, v in current.effects.items()}

    def evaluate(v: float) -> None:
        eff = {**others, name: to_params(v)}
        prof.add(v, eff[name], ws.fit_each(idx, [initial_nuisance(ws.clips[c]) for c in idx], eff))

    # The first point is the current model itself (the effect vanishes there); then outwards
    # until the summed chi-square has risen at two points in a row (the profile is taken as
    # unimodal), so an effect the data do not want costs two or three points.
    at_current = _vanishes(ws, idx[0], current, name, to_params(s_pts[0]))
    if at_current:
        prof.add(s_pts[0], to_params(s_pts[0]), baseline)
    else:
        evaluate(s_pts[0])
    rises = 0
    for v in s_pts[1:]:
        evaluate(v)
        rises = rises + 1 if prof.total()[-1] > prof.total()[:-1].min() else 0
        if rises >= 2:
            break
    star = _parabola_min(prof.s, prof.total())
    if all(abs(star - v) > 1e-9 for v in prof.s):
        evaluate(star)
    b = int(np.argmin(prof.total()))
    joint = _joint_fit(ws, idx, current, name, others, prof.nuis[b], prof.params[b],
                       prof.params[0] if at_current else None, b == 0)

    keys = [p for p, sp in fx.REGISTRY[name].parameters.items() if sp.fit]
    theta = np.array([joint.effects[name][k] for k in keys])
    if len(keys) > 1 and b > 0 and np.linalg.norm(theta) > 0:
        # The first axis was a grid direction (45 degree steps); profile again along the
        # jointly fitted direction, so that held-out clips are predicted along the right one.
        first = prof
        prof = Profile([], [], [], [], [])
        prof.add(0.0, first.params[0], _fit_rows(first, 0))
        norm = float(np.linalg.norm(theta))
        to_params = lambda v: {**fx.REGISTRY[name].defaults(),  # noqa: E731
                               **{k: float(v * t / norm) for k, t in zip(keys, theta)}}
        for v in (0.5 * norm, 0.8 * norm, norm, 1.25 * norm, 1.6 * norm):
            evaluate(v)

    n = len(idx)
    ho = HeldOut([0.0] * n, [0.0] * n, list(joint.n_res), list(joint.n_pos), [{}] * n)
    s2 = max(1.0, current.rss / max(current.n - current.k, 1))   # misfit inflates the noise
    defaults = fx.REGISTRY[name].defaults()
    prior = next((p for p, params in enumerate(prof.params)
                  if p > 0 and all(abs(params[k] - defaults[k]) < 1e-12 for k in defaults)), None)
    refit: list[tuple[int, int, dict]] = []
    for c in range(n):
        others_total = prof.total(without=c)
        v = _parabola_min(prof.s, others_total)
        if n > 1:  # where the other clips do not call for another value: the prior, or none
            tol = others_total.min() + CHI2_1_95 * s2
            if prior is not None and others_total[prior] <= tol:
                v = prof.s[prior]
            elif others_total[0] <= tol:
                v = prof.s[0]
        near = int(np.argmin(np.abs(np.array(prof.s) - v)))
        eff = {**others, name: to_params(v)}
        if abs(prof.s[near] - v) < 1e-9:
            ho.chi2[c], ho.sq_pos[c] = prof.chi2[near][c], prof.sq[near][c]
        else:
            refit.append((c, near, eff))
        ho.theta[c] = eff
    # the left-out clips refitted at their strengths (independent fits: in parallel when a pool runs)
    by_eff: dict[str, list[tuple[int, int, dict]]] = {}
    for c, near, eff in refit:
        by_eff.setdefault(json.dumps(eff, sort_keys=True), []).append((c, near, eff))
    for group in by_eff.values():
        parts = ws.refit_each([idx[c] for c, _, _ in group], [prof.nuis[near][c] for c, near, _ in group],
                              group[0][2], max_nfev=ws.cfg.max_nfev_warm)
        for (c, near, _), part in zip(group, parts):
            ho.chi2[c], ho.sq_pos[c] = min(part.chi2[0], prof.chi2[near][c]), part.sq_pos[0]
    return joint, ho, prof


def _joint_fit(ws: "Workspace", idx: Sequence[int], current: Fit, name: str,
               others: Mapping[str, Mapping[str, float]], nuis: Sequence[np.ndarray], params: Mapping[str, float],
               null: Mapping[str, float] | None, best_is_null: bool) -> Fit:
    """Converged joint fit of the current model + effect ``name`` (coefficients shared, every
    clip's parameters free), the best of several starts:

    - ``profile``: the profile's best point (``nuis``, ``params``; per-clip fits from the data);
    - ``base optimum``: for a nested effect (``null`` = its parameters where it vanishes, the
      model then being the current one), the current model's optimum with the effect at
      ``null``; the start point itself is kept as a candidate too (a trust-region method only
      accepts decreasing steps, but the fit must start 1e-3 scale off a bound), so the extended
      fit is never worse than the current model (nested models).

    Each start runs to the tolerance ``cfg.ftol`` (:func:`fit_clips` ``converge``). The fits'
    ``start`` attribute says which start won."""
    fits = []
    f = ws.fit(idx, nuis, {**others, name: dict(params)}, converge=True)
    f.start = "profile"
    fits.append(f)
    if null is not None:
        eff = {**others, name: dict(null)}
        if not best_is_null:   # else the profile start already is the base optimum
            f = ws.fit(idx, current.nuisance, eff, converge=True)
            f.start = "base optimum"
            fits.append(f)
        n_theta = len(_theta_keys([name]))
        fits.append(Fit({k: dict(v) for k, v in eff.items()}, list(current.nuisance), list(current.chi2),
                        list(current.sq_pos), list(current.n_res), list(current.n_pos), current.k + n_theta,
                        _theta_keys(list(eff)), nfev=0, status=current.status, iterations=0,
                        converged=current.converged, start="base optimum (effect at its null value, not moved)"))
    best = min(fits, key=lambda g: g.rss)
    best.nfev = sum(g.nfev for g in fits)
    best.iterations = sum(g.iterations for g in fits)
    return best


PROFILE_ACCEPT_GN = 0.25
"""The Gauss-Newton end of an interval is accepted when the profile's rise there is within
this fraction of the threshold (the profile is quadratic enough)."""
PROFILE_GROW = 3.0
"""Outward step factor when the profile has not yet risen to the threshold."""
PROFILE_BISECT = 6
"""Most interpolation steps (Illinois regula falsi on the square root of the rise) to locate
a crossing (stops earlier when the rise is within 5 % of the threshold)."""


def profile_intervals(ws: "Workspace", idx: Sequence[int], fit: Fit, log=None
                      ) -> tuple[dict[str, dict[str, list[float | None]]], dict[str, dict[str, str]]]:
    """Profile-likelihood intervals of the fitted coefficients of ``fit`` (a converged joint fit
    with Gauss-Newton intervals ``fit.ci_gn``).

    The threshold is ``Δχ² = q s²``: ``q`` the chi-square(1) quantile at ``cfg.ci_level``
    (3.84 for 95 %), ``s² = χ²/dof`` of the fit (the residual variance factor; 1 when the
    noise model is right). A profile point fixes the coefficient, refits every other parameter
    (all clips' parameters and the other coefficients) from the optimum to the tolerance, and
    its rise is ``χ²(point) − χ²(optimum)`` (with one coefficient the clips separate and are
    refitted one by one: small, well-conditioned fits). Each side of each coefficient:

    1. the Gauss-Newton end is checked with one profile point: a rise within
       :data:`PROFILE_ACCEPT_GN` of the threshold accepts it (``gauss-newton``);
    2. else the crossing is bracketed (outwards by :data:`PROFILE_GROW` up to the search
       bound) and located by Illinois regula falsi on the square root of the rise (exact for a
       quadratic profile; at most :data:`PROFILE_BISECT` steps) (``profile``);
    3. where the profile has not risen by the threshold at the search bound, the data cannot
       bound the coefficient on that side: it is ``None`` (open), never the bound (``open``).

    Returns:
        ``(ci, method)``: ``{effect: {parameter: [low|None, high|None]}}`` and
        ``{effect: {parameter: "low method / high method"}}``.
    """
    from scipy.stats import chi2 as chi2_dist

    cfg = ws.cfg
    dof = max(fit.n - fit.k, 1)
    s2 = fit.rss / dof
    thr = float(chi2_dist.ppf(cfg.ci_level, 1)) * s2
    ci: dict[str, dict[str, list[float | None]]] = {}
    method: dict[str, dict[str, str]] = {}
    for e, p in fit.theta_keys:
        spec = fx.REGISTRY[e].parameters[p]
        v = float(fit.effects[e][p])
        gn = (fit.ci_gn.get(e) or {}).get(p) or [None, None]
        cache: dict[float, float] = {}

        def rise(x: float) -> float:
            x = float(x)
            if x not in cache:
                eff = {k: dict(d) for k, d in fit.effects.items()}
                eff[e][p] = x
                if len(fit.theta_keys) == 1:   # nothing else shared: the clips separate
                    total = sum(f.rss for f in ws.refit_each(idx, fit.nuisance, eff, converge=True))
                else:
                    total = ws.fit(idx, fit.nuisance, eff, converge=True, fixed=[(e, p)]).rss
                cache[x] = max(total - fit.rss, 0.0)
            return cache[x]

        ends, how = [], []
        for sign, bound, g in ((-1.0, spec.low, gn[0]), (1.0, spec.high, gn[1])):
            room = sign * (bound - v)
            if room <= 1e-9 * spec.scale:        # at the search bound: nothing beyond it to test
                ends.append(None)
                how.append("open (at the search bound)")
                continue
            step = abs(g - v) if g is not None and np.isfinite(g) and abs(g - v) > 0 else spec.scale
            x = v + sign * min(step, room)
            r = rise(x)
            if abs(x - bound) > 1e-12 and abs(r - thr) <= PROFILE_ACCEPT_GN * thr and g is not None:
                ends.append(float(x))
                how.append("gauss-newton (profile-checked)")
                continue
            inner, r_in = v, 0.0
            while r < thr and abs(x - bound) > 1e-12:
                inner, r_in = x, r
                x = v + sign * min(PROFILE_GROW * abs(x - v), room)
                r = rise(x)
            if r < thr:                           # never rose by the threshold before the bound
                ends.append(None)
                how.append(f"open (profile rise {r:.3g} < {thr:.3g} at the search bound {bound:g})")
                continue
            outer, r_out = x, r
            # Illinois regula falsi on g = sqrt(rise) - sqrt(threshold) (linear for a quadratic
            # profile); the end kept twice in a row has its g halved, so a steep far end (a
            # bound of another parameter becoming active) cannot stall it.
            g_in, g_out, kept = math.sqrt(r_in) - math.sqrt(thr), math.sqrt(r_out) - math.sqrt(thr), 0
            for _ in range(PROFILE_BISECT):
                xm = inner + (outer - inner) * (-g_in) / (g_out - g_in) if g_out > g_in else 0.5 * (inner + outer)
                rm = rise(xm)
                gm = math.sqrt(rm) - math.sqrt(thr)
                if abs(rm - thr) <= 0.05 * thr:
                    inner = outer = xm
                    break
                if gm < 0:
                    inner, g_in = xm, gm
                    kept = kept + 1 if kept > 0 else 1
                    if kept >= 2:
                        g_out *= 0.5
                else:
                    outer, g_out = xm, gm
                    kept = kept - 1 if kept < 0 else -1
                    if kept <= -2:
                        g_in *= 0.5
            t = (-g_in) / (g_out - g_in) if g_out > g_in else 0.5
            ends.append(float(inner + min(max(t, 0.0), 1.0) * (outer - inner)))
            how.append("profile")
        ci.setdefault(e, {})[p] = ends
        method.setdefault(e, {})[p] = " / ".join(how)
        if log:
            log(f"interval {e}.{p} = {v:.4g}: {_fmt_interval(ends)} (Gauss-Newton {_fmt_interval(gn)}; "
                f"{len(cache)} profile fits; {method[e][p]})")
    return ci, method


def _fmt_interval(ci: Sequence[float | None] | None, nd: int = 4) -> str:
    """``[lo, hi]`` with an open side shown as ``(open`` / ``open)``."""
    if not ci:
        return "fixed"
    lo, hi = ci
    left = "(open" if lo is None else f"[{lo:.{nd}g}"
    right = "open)" if hi is None else f"{hi:.{nd}g}]"
    return f"{left}, {right}"


def _gate(cand: dict[str, Any], cfg: DiscrepancyConfig) -> tuple[bool, str]:
    """Whether a scored candidate may be named, and why not."""
    if cand["delta_bic"] > -cfg.bic_threshold:
        return False, f"BIC drop {-cand['delta_bic']:.1f} < {cfg.bic_threshold:g}"
    if cand["profile_gain"] < cfg.heldout_threshold:
        return False, (f"refitting every clip from the data with the effect gains only "
                       f"{cand['profile_gain']:.1f} < {cfg.heldout_threshold:g} in chi2")
    if cand.get("heldout_delta_chi2") is None:
        return True, "no held-out clips (BIC only)"
    if cand["heldout_delta_chi2"] < cfg.heldout_threshold:
        return False, f"held-out chi2 drop {cand['heldout_delta_chi2']:.1f} < {cfg.heldout_threshold:g}"
    if cand["heldout_rmse"] >= cand["heldout_rmse_before"]:
        return False, "held-out RMSE does not shrink"
    return True, "clears BIC and held-out gates"


@dataclass
class Result:
    """Everything the workflow found (see :func:`run_workflow`)."""

    clips: list[Clip]
    noise: list[Noise]
    base: Fit
    base_heldout: HeldOut
    final: Fit
    final_heldout: HeldOut
    steps: list[dict[str, Any]]
    named: list[dict[str, Any]]
    segments: list[dict[str, Any]]
    segments_after: list[dict[str, Any]]
    phases: list[list[np.ndarray]]
    base_qpos: list[np.ndarray]
    final_qpos: list[np.ndarray]
    config: DiscrepancyConfig
    runtime_s: float = 0.0
    forward: dict[str, Any] | None = None
    """Single clip: the forward split (:func:`forward_gap`), or ``None``."""

    @property
    def gap(self) -> dict[str, Any]:
        """The shown gap: position RMSE (m) before (base) and after (named effects), its
        relative shrink, and the same for the part beyond the measurement noise
        (``excess = sqrt(max(RMSE^2 - sigma^2, 0))``, sigma = pooled noise estimate): the RMSE
        cannot fall below sigma, so an effect that starts near the noise floor (e.g.
        torsional friction, which shows mostly in orientation) shrinks the raw RMSE little.

        Which gap (``kind``, ``label``, ``why``): with >= 2 clips the leave-one-clip-out
        held-out RMSE; with one clip the forward gap (fitted on the clip's first part, scored
        on the rest, :func:`forward_gap`); with one clip too short to split, in sample."""
        sigma = float(np.sqrt(np.mean([n.position ** 2 for n in self.noise])))
        extra: dict[str, Any] = {}
        if len(self.clips) >= 2:
            before, after = self.base_heldout.rmse, self.final_heldout.rmse
            extra = {"kind": "leave_one_clip_out", "label": "held-out gap (leave one clip out)",
                     "why": f"{len(self.clips)} clips (>= 2): leave one clip out"}
        elif self.forward is not None:
            before, after = self.forward["before"], self.forward["after"]
            extra = {"kind": "forward", "why": "1 clip: nothing to hold out, so a forward split in time",
                     **{k: v for k, v in self.forward.items() if k not in ("before", "after")}}
        else:
            before, after = self.base.rmse, self.final.rmse
            extra = {"kind": "in_sample", "label": "in-sample gap",
                     "why": "1 clip too short to split in time (fewer than "
                            f"{MIN_SAMPLES} samples before the split or none after it): in sample"}
        eb, ea = math.sqrt(max(before ** 2 - sigma ** 2, 0.0)), math.sqrt(max(after ** 2 - sigma ** 2, 0.0))
        return {"before": before, "after": after, "shrink": 1.0 - after / before if before > 0 else 0.0,
                "noise": sigma, "excess_before": eb, "excess_after": ea,
                "excess_shrink": 1.0 - ea / eb if eb > 0 else 0.0, **extra}

    @property
    def in_sample(self) -> dict[str, Any]:
        """In-sample position RMSE (m) of the base and the final model over all clips, with
        the number of fitted parameters ``k`` of each."""
        return {"before": self.base.rmse, "k_before": int(self.base.k),
                "after": self.final.rmse, "k_after": int(self.final.k),
                "effects": [n["effect"] for n in self.named]}


def _late_sq(clip: Clip, qpos: np.ndarray, t_split: float) -> tuple[float, int]:
    """Sum of squared position residuals (m^2) and their count over the observed coordinates
    of the samples after ``t_split`` (s); ``qpos (T, n, 7)`` at ``clip.times``."""
    sq, n = 0.0, 0
    for i, tr in enumerate(clip.tracks):
        late = tr.t > t_split + 1e-9
        idx = np.searchsorted(clip.times, tr.t[late])
        d = (qpos[idx, i, :3] - tr.pos[late])[:, tr.axes]
        sq += float(np.sum(d * d))
        n += int(d.size)
    return sq, n


def forward_gap(ws: "Workspace", c: int, effects: Sequence[str], log=None) -> dict[str, Any] | None:
    """Forward gap of clip ``c``: fit on its first part, forecast the rest.

    The clip is cut at ``cfg.forward_split`` of its duration (:func:`_truncate`). On the first
    part the base model is fitted (:meth:`Workspace.fit_each`, per-clip continuation from the
    data), then each of ``effects`` is added in the order named, with its coefficients
    fitted on the first part alone (:func:`_profile_candidate` from the effect's grid, then
    :func:`_refit_from_data`), so nothing of the later part enters. The prediction simulates
    the *whole* clip from the fitted initial state with the fitted parameters (one
    :class:`ClipModel` rollout of the full clip); the samples after the split are a true
    forecast (the same as simulating from the model's own state at the split) and only they
    are scored. The noise weights are those of the whole clip (:func:`estimate_noise`).

    An effect with ``Effect.replaces_damping`` (quadratic drag) is fitted twice on the first
    part: added to the base model (damping still fitted) and in place of the damping (held
    at 0, one parameter fewer per object); the variant with the lower BIC on the first part
    is kept (``variants`` says which and why). Both are honest forecasts: the choice uses
    the first part only.

    Returns:
        ``{before, after, k_before, k_after, t_split, fit_s, predict_s, n_fit, n_predicted,
        effects, variants, label}`` (RMSE in m over the predicted samples' observed
        coordinates), or
        ``None`` if the first part keeps fewer than :data:`MIN_SAMPLES` samples of an object or
        nothing is left after it.
    """
    clip = ws.clips[c]
    duration = float(clip.times[-1])
    t_split = ws.cfg.forward_split * duration
    first = _truncate(clip, t_split)
    if first is None or not np.any(clip.times > t_split + 1e-9):
        return None
    part = Workspace([first], ws.cfg, ws.options, ws.gravity)
    part.noise, part.weights = [ws.noise[c]], [ws.weights[c]]
    base = part.fit_each([0], [initial_nuisance(first)], {}, converge=True)
    current = base
    held: Workspace | None = None   # the same first part with every damping held at 0
    variants: list[dict[str, Any]] = []
    for e in effects:
        joint, _, _ = _profile_candidate(part, [0], current, e)
        cand = _refit_from_data(part, [0], joint)
        if fx.REGISTRY[e].replaces_damping and not ws.cfg.hold_damping:
            # The effect instead of the base model's linear damping: on a short first part the
            # two are nearly collinear (quadratic vs linear in speed), so fitted together the
            # coefficient is poorly fixed and the forecast inherits that; fitted alone it
            # carries the law. The lower BIC on the first part decides (nothing after the split).
            if held is None:
                held = Workspace([first], ws.cfg.model_copy(update={"hold_damping": True}), ws.options, ws.gravity)
                held.noise, held.weights = part.noise, part.weights
            start = current.nuisance[0].copy()
            start[:, _D] = 0.0
            cur_held = held.fit([0], [start], current.effects, converge=True)
            j2, _, _ = _profile_candidate(held, [0], cur_held, e)
            alt = _refit_from_data(held, [0], j2)
            use = alt.bic < cand.bic
            variants.append({"effect": e, "damping": "held at 0" if use else "fitted",
                             "bic_fitted": round(float(cand.bic), 3), "bic_held": round(float(alt.bic), 3)})
            if log:
                log(f"forward gap: {e} with the damping fitted (BIC {cand.bic:.1f}) or held at 0 "
                    f"(BIC {alt.bic:.1f}): {variants[-1]['damping']}")
            if use:
                cand = alt
        current = cand
    out: dict[str, Any] = {"variants": variants}
    for key, fit in (("before", base), ("after", current)):
        qpos = ws.model(c, fit.effects).simulate(fit.nuisance[0], fit.effects)
        sq, n = _late_sq(clip, qpos, t_split)
        out[key] = math.sqrt(sq / max(n, 1))
        out[f"k_{key}"] = int(fit.k)            # free per-clip parameters + effect coefficients
    t_last_fit = float(first.times[-1])
    n_pred = int(np.sum(clip.times > t_split + 1e-9))
    out.update(t_split=t_split, fit_s=t_last_fit, predict_s=duration - t_last_fit, n_fit=int(len(first.times)),
               n_predicted=n_pred, effects={k: dict(v) for k, v in current.effects.items()},
               label=f"forward gap (fit on the first {t_last_fit:.3g} s, predict the last "
                     f"{duration - t_last_fit:.3g} s)")
    if log:
        log(f"forward gap: fit on {t_last_fit:.3f} s, predict {n_pred} samples: "
            f"{out['before'] * 1e3:.2f} -> {out['after'] * 1e3:.2f} mm")
    return out


def run_workflow(clips: Sequence[Clip], cfg: DiscrepancyConfig | None = None,
                 options: SimOptions | None = None, gravity: float = 9.81, log=None) -> Result:
    """Find, name and add missing effects (DESIGN §8).

    1. Fit the base model to each clip; estimate the noise; list residual segments.
    2. Greedy forward selection: fit each remaining candidate jointly over all clips (shared
       coefficients, per-clip parameters warm-started from the current model); candidates
       whose BIC drops by at least ``bic_threshold`` get k-fold held-out scores; a candidate
       is eligible when its held-out chi-square drops by at least ``heldout_threshold`` and
       its held-out RMSE shrinks; the eligible one with the lowest BIC is named. Stop when
       none is eligible or ``max_effects`` are named.
    3. Refit the final model with confidence intervals.

    Args:
        clips: measured clips (:func:`read_trajectories`).
        cfg: settings.
        options: simulation options (params ``sim``).
        gravity: m/s^2.
        log: optional ``print``-like callable for progress lines.

    Returns:
        :class:`Result`.
    """
    with single_threaded_blas():
        return _run_workflow(clips, cfg, options, gravity, log)


def _run_workflow(clips: Sequence[Clip], cfg: DiscrepancyConfig | None, options: SimOptions | None,
                  gravity: float, log) -> Result:
    cfg = cfg or DiscrepancyConfig()
    options = (options or SimOptions()).model_copy(update={"textured": False})
    say = log or (lambda *a, **k: None)
    t_start = time.perf_counter()
    ws = Workspace(clips, cfg, options, gravity)
    try:
        ws.start_pool(cfg.workers or available_cores())
        return _select(ws, cfg, say, t_start)
    finally:
        ws.close()


def _select(ws: "Workspace", cfg: DiscrepancyConfig, say, t_start: float) -> Result:
    n = len(ws.clips)
    idx = list(range(n))
    base = ws.fit_each(idx, [initial_nuisance(c) for c in ws.clips], {}, converge=True)
    base.start = "data (per-clip continuation)"
    base_ho = HeldOut(list(base.chi2), list(base.sq_pos), list(base.n_res), list(base.n_pos))
    say(f"base model: RMSE {base.rmse * 1e3:.2f} mm over {n} clips "
        f"(noise {np.median([z.position for z in ws.noise]) * 1e3:.2f} mm)")

    current, cur_ho, steps = base, base_ho, []
    screen = ws.fit_each(idx, [initial_nuisance(c) for c in ws.clips], {})
    base_ho = cur_ho = HeldOut(list(screen.chi2), list(screen.sq_pos), list(screen.n_res), list(screen.n_pos))
    named_order: list[str] = []
    for step in range(1, cfg.max_effects + 1):
        remaining = [e for e in cfg.candidates if e not in named_order]
        if steps and not cfg.rescreen_all:  # screening: only effects that helped at step 1
            remaining = [e for e in remaining
                         if any(cd["effect"] == e and cd["profile_gain"] >= cfg.heldout_threshold
                                for cd in steps[0]["candidates"])]
        if step > 1 and remaining:   # the current model fitted like the profile points (from the data)
            screen = ws.fit_each(idx, [initial_nuisance(c) for c in ws.clips], current.effects)
        screened: dict[str, dict[str, Any]] = {}
        if remaining and cfg.screen_gain > 0:   # cheap screen before the full fits
            screened = screen_candidates(ws, idx, current, remaining)
            for e in remaining:
                g = screened[e]["predicted_gain"]
                passed = g is None or g >= cfg.screen_gain
                if not passed:
                    # Second chance, not linearised: the clips refitted from the data (like a
                    # profile point) at one strength. The current optimum may sit in a basin
                    # that compensates for the missing effect (a spin that mimics Magnus lift),
                    # where the linearisation predicts a loss.
                    point = _second_chance_point(e, screened[e]["best"])
                    trial = ws.fit_each(idx, [initial_nuisance(c) for c in ws.clips], {**current.effects, e: point})
                    screened[e]["refit_point"], screened[e]["refit_gain"] = point, float(screen.rss - trial.rss)
                    passed = screened[e]["refit_gain"] >= cfg.screen_gain
                screened[e]["passed"] = bool(passed)
                if not passed:
                    say(f"step {step}: {e:18s} screened out: predicted chi2 gain {g:.1f}, refitted from the data "
                        f"{screened[e]['refit_gain']:.1f} < {cfg.screen_gain:g}")
            remaining = [e for e in remaining if screened[e]["passed"]]
        if not remaining:
            if screened:
                steps.append({"step": step, "model": list(named_order), "candidates": [], "named": None,
                              "screen": screened})
            break
        scored = []
        for e in remaining:
            f, ho, prof = _profile_candidate(ws, idx, current, e, screen)
            # Out-of-sample comparison at equal footing: the current model's per-clip fits (its
            # own coefficients fitted on all clips, like the candidate's profile rows) against
            # the candidate with its strength taken from the other clips.
            before = HeldOut(list(screen.chi2), list(screen.sq_pos), list(screen.n_res), list(screen.n_pos))
            chi = np.array(prof.chi2)
            cand = {"effect": e, "parameters": {p: f.effects[e][p] for _, p in _theta_keys([e])},
                    "rmse": f.rmse, "fit_gain": current.rmse - f.rmse,
                    "chi2": f.rss, "chi2_before": current.rss, "fit_gain_chi2": current.rss - f.rss,
                    "optimizer": f.optimizer(), "nested": bool(fx.REGISTRY[e].nested),
                    "fit_gain_pct": 100.0 * (current.rmse - f.rmse) / current.rmse if current.rmse else 0.0,
                    "delta_bic": f.bic - current.bic, "profile_gain": float(screen.rss - chi.sum(1).min()),
                    "heldout_rmse_before": before.rmse, "heldout_rmse": None, "heldout_delta_chi2": None,
                    "heldout_gain": None,
                    "profile": {"s": prof.s, "chi2": [float(x) for x in prof.total()]},
                    "per_clip_gain": {ws.clips[c].name: float(screen.chi2[c] - chi[:, c].min()) for c in idx}}
            if n >= 2:
                cand.update(heldout_rmse=ho.rmse, heldout_gain=before.rmse - ho.rmse,
                            heldout_delta_chi2=before.total_chi2 - ho.total_chi2)
            else:
                ho = None
            scored.append((cand, f, ho))
        for cand, f, ho in scored:
            cand["eligible"], cand["reason"] = _gate(cand, cfg)
            say(f"step {step}: {cand['effect']:18s} dBIC {cand['delta_bic']:10.1f}  fit gain "
                f"{cand['fit_gain'] * 1e3:7.2f} mm" + (f"  held-out {ho.rmse * 1e3:.2f} mm" if ho else "")
                + f"  {cand['reason']}")
        eligible = [s for s in scored if s[0]["eligible"]]
        winner = min(eligible, key=lambda s: s[0]["delta_bic"]) if eligible else None
        for s in scored:
            s[0]["named"] = s is winner
        steps.append({"step": step, "model": list(named_order), "candidates": [s[0] for s in scored],
                      "named": winner[0]["effect"] if winner else None, "screen": screened})
        if winner is None:
            break
        named_order.append(winner[0]["effect"])
        current, cur_ho = _refit_from_data(ws, idx, winner[1]), (winner[2] or cur_ho)
        if all(c2 / nr <= cfg.noise_floor_chi2 for c2, nr in zip(current.chi2, current.n_res)):
            say(f"noise floor reached: chi2/n <= {cfg.noise_floor_chi2:g} in every clip")
            break

    final = current
    if named_order:
        final = ws.fit(idx, current.nuisance, current.effects, with_ci=True, converge=True)
        if final.rss > current.rss:   # the converged refit never loses the model it starts from
            kept = final
            final = Fit({k: dict(v) for k, v in current.effects.items()}, list(current.nuisance), list(current.chi2),
                        list(current.sq_pos), list(current.n_res), list(current.n_pos), current.k,
                        list(kept.theta_keys), ci=kept.ci, nfev=kept.nfev, status=kept.status,
                        iterations=kept.iterations, converged=kept.converged, start="selection fit (kept)",
                        ci_gn=kept.ci_gn, ci_method=kept.ci_method)
        else:
            final.start = "selection fit"
        say(f"final fit: chi2 {final.rss:.1f}, optimiser status {final.status}, {final.iterations} evaluations")
        final.ci, final.ci_method = profile_intervals(ws, idx, final, log=say)
    named = []
    for e in named_order:
        cls = fx.REGISTRY[e]
        named.append({"effect": e, "parameters": dict(final.effects[e]), "ci": final.ci.get(e, {}),
                      "ci_gauss_newton": final.ci_gn.get(e, {}), "ci_method": final.ci_method.get(e, {}),
                      "units": {p: s.unit for p, s in cls.parameters.items()},
                      "fitted": [p for p, s in cls.parameters.items() if s.fit], "mechanism": cls.mechanism})

    base_qpos, final_qpos, phases, segs, segs_after = [], [], [], [], []
    for c in idx:
        m0 = ws.model(c, {})
        omega, q0 = m0.trace(base.nuisance[c], {})
        q1 = ws.model(c, final.effects).simulate(final.nuisance[c], final.effects)
        ph = motion_phases(ws.clips[c], q0, omega, ws.noise[c], cfg)
        base_qpos.append(q0)
        final_qpos.append(q1)
        phases.append(ph)
        segs += residual_segments(ws.clips[c], q0, ws.noise[c], ph, cfg)
        segs_after += residual_segments(ws.clips[c], q1, ws.noise[c], ph, cfg)
    forward = forward_gap(ws, 0, named_order, say) if n == 1 else None
    return Result(ws.clips, ws.noise, base, base_ho, final, cur_ho, steps, named, segs, segs_after, phases,
                  base_qpos, final_qpos, cfg, time.perf_counter() - t_start, forward)


# =========================================================================== hidden-effect data
HIDDEN_KINDS = ("throw", "spin_slide", "throw", "roll")
"""Clip kinds of hidden-effect data, cycled: a light spinning sphere thrown so it flies, lands
and rolls; a heavier sphere pushed along the floor, sliding and spinning about the vertical;
a sphere rolling with some spin about the vertical."""


class HiddenConfig(_Strict):
    """Hidden-effect data (params section ``measure_hidden``).

    Attributes:
        effect: ``random`` (uniform over the library and ``none``), ``none`` or an effect name.
        n_clips: clips per data set (kinds cycle through ``kinds``).
        kinds: clip kinds, from ``throw``, ``spin_slide``, ``roll`` (:data:`HIDDEN_KINDS`).
        duration: s per clip. fps: samples per second.
        noise_position: m, Gaussian noise on each coordinate.
        noise_angle: deg, Gaussian noise on each rotation-vector component of the orientation.
        orientation: write measured orientations (``qw..qz``).
        strengths: per effect, per parameter ``[low, high]`` of the uniform draw; for
            ``wind`` and ``floor_tilt`` the range is the magnitude (``speed`` m/s, ``tilt``
            deg) and the direction is uniform.
    """

    effect: str = "random"
    n_clips: int = Field(3, ge=1)
    duration: float = Field(0.8, gt=0, le=10)
    fps: int = Field(60, ge=5, le=1000)
    noise_position: float = Field(0.001, ge=0)
    noise_angle: float = Field(1.0, ge=0)
    orientation: bool = True
    kinds: tuple[str, ...] = HIDDEN_KINDS
    strengths: dict[str, dict[str, tuple[float, float]]] = {
        "quadratic_drag": {"density": (3.0, 12.0)},
        "wind": {"speed": (2.0, 5.0)},
        "restitution": {"e": (0.4, 0.85)},
        "floor_tilt": {"tilt": (1.5, 5.0)},
        "magnus_lift": {"lift": (0.6, 2.0)},
        "torsional_friction": {"mu_torsion": (0.005, 0.03)},
    }

    def model_post_init(self, _ctx: Any) -> None:
        if not self.kinds or any(k not in ("throw", "spin_slide", "roll") for k in self.kinds):
            raise ValueError(f"kinds: each must be throw, spin_slide or roll, got {list(self.kinds)}")
        if self.effect not in ("random", "none") and self.effect not in fx.REGISTRY:
            raise ValueError(f"effect: must be random, none or one of {', '.join(fx.REGISTRY)}, got {self.effect!r}")


def draw_effect(rng: np.random.Generator, cfg: HiddenConfig, effect: str | None = None
                ) -> tuple[str | None, dict[str, float]]:
    """Draw the hidden effect and its strength: ``(name or None, parameters)``."""
    name = effect or cfg.effect
    if name == "random":
        name = str(rng.choice(["none", *fx.REGISTRY]))
    if name == "none":
        return None, {}
    ranges = cfg.strengths.get(name, {})
    if name == "wind":
        speed, ang = rng.uniform(*ranges.get("speed", (2.0, 5.0))), rng.uniform(0, 2 * math.pi)
        return name, {"wind_x": speed * math.cos(ang), "wind_y": speed * math.sin(ang)}
    if name == "floor_tilt":
        tilt, ang = rng.uniform(*ranges.get("tilt", (1.5, 5.0))), rng.uniform(0, 2 * math.pi)
        return name, {"tilt_x": tilt * math.cos(ang), "tilt_y": tilt * math.sin(ang)}
    params = {}
    for p, spec in fx.REGISTRY[name].parameters.items():
        if spec.fit:
            lo, hi = ranges.get(p, (spec.default, spec.default))
            params[p] = float(rng.uniform(lo, hi))
    return name, params


def _hidden_object(rng: np.random.Generator, kind: str, index: int) -> dict[str, Any]:
    """Scene object (dict) of a hidden-effect clip of ``kind``."""
    u = rng.uniform
    heading = u(0, 2 * math.pi)
    hdir = np.array([math.cos(heading), math.sin(heading), 0.0])
    if kind == "throw":
        r = u(0.02, 0.035)
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        v = hdir * u(1.0, 2.5) + np.array([0, 0, u(0.5, 2.5)])
        return {"shape": "sphere", "size": {"radius": r}, "mass": u(0.004, 0.02),
                "position": [u(-0.3, 0.3), u(-0.3, 0.3), u(0.3, 0.7)], "linear_velocity": v.tolist(),
                "angular_velocity": (axis * u(30, 80)).tolist(),
                "material": {"sliding_friction": u(0.3, 0.7), "rolling_friction": 0.0, "damping": 0.0}}
    if kind == "roll":
        r = u(0.02, 0.04)
        v = hdir * u(0.5, 1.5)
        w = np.cross([0, 0, 1.0], v) / r + np.array([0, 0, u(-30, 30)])
        return {"shape": "sphere", "size": {"radius": r}, "mass": u(0.005, 0.05),
                "position": [u(-0.3, 0.3), u(-0.3, 0.3), r], "linear_velocity": v.tolist(),
                "angular_velocity": w.tolist(),
                "material": {"sliding_friction": u(0.3, 0.7), "rolling_friction": 0.0, "damping": 0.0}}
    # spin_slide: a sphere pushed along the floor without rolling, spinning about the vertical.
    # (Not a box or cylinder: MuJoCo's flat-face contacts make a sliding, spinning box or
    # cylinder ill-conditioned: a 1e-5 m change of its initial height or a 1e-4 change of its
    # friction moved it by up to 10 mm within 1 s, so no fit reaches the noise.)
    r = u(0.025, 0.045)
    return {"shape": "sphere", "size": {"radius": r}, "mass": u(0.03, 0.2), "position": [u(-0.3, 0.3), u(-0.3, 0.3), r],
            "linear_velocity": (hdir * u(1.0, 2.0)).tolist(),
            "angular_velocity": [0.0, 0.0, float(u(20, 50) * rng.choice([-1, 1]))],
            "material": {"sliding_friction": u(0.15, 0.4), "rolling_friction": 0.0, "damping": 0.0}}


def generate_hidden(seed: int, cfg: HiddenConfig | None = None, options: SimOptions | None = None,
                    effect: str | None = None) -> tuple[dict[str, list], dict[str, Any]]:
    """Measured trajectories generated with one hidden effect (or none) plus noise.

    Every clip is simulated by the same MuJoCo bridge as the workflow (scene -> MJCF ->
    MuJoCo) with the drawn effect at the drawn strength, sampled at ``fps``, and corrupted by
    Gaussian position noise and orientation noise (``q exp(n)``, ``n`` per axis).

    Args:
        seed: random seed (clips, effect, strength, noise).
        cfg: settings.
        options: simulation options (params ``sim``).
        effect: overrides ``cfg.effect`` (``none``, a name, or ``random``).

    Returns:
        ``(columns, truth)``: ``columns`` maps each table column (:data:`TABLE_COLUMNS`,
        :data:`QUAT_COLUMNS` if ``orientation``, :data:`SPEC_COLUMNS`) to a list of values;
        ``truth`` is ``{seed, effect, parameters, clips: [{clip, kind, scene}]}`` and must be
        stored apart from the measurements.
    """
    cfg = cfg or HiddenConfig()
    options = (options or SimOptions()).model_copy(update={"textured": False})
    rng = np.random.default_rng(seed)
    name, params = draw_effect(rng, cfg, effect)
    cols: dict[str, list] = {c: [] for c in TABLE_COLUMNS + (QUAT_COLUMNS if cfg.orientation else ()) + SPEC_COLUMNS}
    truth: dict[str, Any] = {"seed": seed, "effect": name, "parameters": params, "clips": []}
    times = np.arange(int(round(cfg.duration * cfg.fps)) + 1) / cfg.fps
    for c in range(cfg.n_clips):
        kind = cfg.kinds[c % len(cfg.kinds)]
        obj = _hidden_object(rng, kind, c)
        scene = Scene.from_dict({"duration": cfg.duration, "fps": cfg.fps, "camera": {"height": 1.2},
                                 "objects": [obj],
                                 "effects": [{"effect": name, "parameters": params}] if name else []})
        model = compile_model(scene, options)
        qpos = _sample_rollout(model, mujoco.MjData(model), 1, times)[:, 0]
        clip_id = f"clip_{c:02d}_{kind}"
        obj_name = f"{obj['shape']}_0"
        pos = qpos[:, :3] + rng.normal(0.0, cfg.noise_position, (len(times), 3))
        quat = _qmul(qpos[:, 3:], _qexp(rng.normal(0.0, math.radians(cfg.noise_angle), (len(times), 3))))
        for k, t in enumerate(times):
            cols["clip"].append(clip_id)
            cols["object"].append(obj_name)
            cols["t"].append(float(t))
            for j, a in enumerate("xyz"):
                cols[a].append(float(pos[k, j]))
            if cfg.orientation:
                for j, a in enumerate(QUAT_COLUMNS):
                    cols[a].append(float(quat[k, j]))
            cols["shape"].append(obj["shape"])
            for key in ("radius", "width", "depth", "height"):
                cols[key].append(obj["size"].get(key))
            cols["mass"].append(float(obj["mass"]))
        truth["clips"].append({"clip": clip_id, "kind": kind, "object": obj,
                               "scene": scene.to_yaml(DISCREPANCY_DECIMALS)})
    return cols, truth


def clips_from_columns(cols: Mapping[str, Sequence], source: str = "<table>", objects: Any = None,
                       default: DefaultObject | None = None) -> list[Clip]:
    """Clips from in-memory table columns (same checks as :func:`read_trajectory_file`)."""
    return _clips_from_columns(Path(source), {k: list(v) for k, v in cols.items()}, False, 0,
                               parse_objects(objects), default or DefaultObject())


def clips_from_infer_dir(path: str | Path, default: DefaultObject | None = None
                         ) -> tuple[list[Clip], dict[str, Any], float]:
    """Clips from a ``dynamics infer`` output folder (``scene.yaml`` + ``tracks.csv``,
    :mod:`pipeline.infer_tracks`): the observed tracks in the scene's world frame, objects
    (shape, size, mass) from the scene, only the axes the camera sees face-on observed.

    Returns:
        ``(clips, video, gravity)``: ``video`` = ``{folder, camera_axes, resimulation_gap}``
        (the gap the re-simulated scene leaves, m and px), ``gravity`` = the scene's, m/s^2.

    Raises:
        DiscrepancyInputError: a missing or malformed file (one line naming it).
    """
    try:
        scene, cols, axes = infer_tracks.read_infer_dir(path)
    except infer_tracks.InferTracksError as exc:
        raise DiscrepancyInputError(str(exc)) from None
    clips = clips_from_columns({c: cols[c] for c in TABLE_COLUMNS + SPEC_COLUMNS}, str(Path(path) / "tracks.csv"),
                               default=default)
    for clip in clips:
        for tr in clip.tracks:
            tr.axes = axes.copy()
    video = {"folder": str(path), "camera_axes": "".join(a for a, on in zip("xyz", axes) if on),
             "resimulation_gap": infer_tracks.resimulation_gap(cols, axes)}
    return clips, video, float(scene.gravity)


# =========================================================================== add
def extended_scenes(result: Result) -> dict[str, Scene]:
    """One scene per clip: the final fit's initial state and material for every object and
    the named effects' ``effects:`` block (all parameters, fixed ones included)."""
    out = {}
    for c, clip in enumerate(result.clips):
        qref = np.array([tr.quat[0] if tr.quat is not None else np.array([1.0, 0, 0, 0]) for tr in clip.tracks])
        effects = {n["effect"]: n["parameters"] for n in result.named}
        out[clip.name] = _clip_scene(clip, result.final.nuisance[c], effects, qref)
    return out


def _safe_name(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name) or "clip"


# =========================================================================== show
def _fmt(x: float | None, scale: float = 1.0, nd: int = 2) -> str:
    return "—" if x is None else f"{x * scale:.{nd}f}"


def report_dict(result: Result, files: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The JSON report (see ``docs/discrepancy.md`` for the fields). Lengths in m, angles in
    deg; ``gap`` is the shown gap, position RMSE before (base model) and after (named
    effects): leave-one-clip-out held-out with >= 2 clips, forward in time with one
    (``gap.kind``, ``gap.label``, ``gap.why``, :attr:`Result.gap`); ``in_sample`` is the
    in-sample RMSE before/after with the number of fitted parameters ``k`` of each."""
    clips = []
    for c, clip in enumerate(result.clips):
        nz = result.noise[c]
        clips.append({
            "clip": clip.name, "source": clip.source, "t0": clip.t0, "z_offset": clip.z_offset,
            "n_samples": int(len(clip.times)),
            "duration": float(clip.times[-1]), "orientation_measured": clip.has_orientation,
            "objects": [{"object": tr.object, "shape": tr.spec.shape, "size": tr.spec.size, "mass": tr.spec.mass,
                         "assumed": tr.spec.assumed, "observed_axes": "".join(a for a, o in zip("xyz", tr.axes) if o)}
                        for tr in clip.tracks],
            "noise": {"position": nz.position, "angle_deg": None if nz.angle is None else math.degrees(nz.angle)},
            "rmse_base": math.sqrt(result.base.sq_pos[c] / max(result.base.n_pos[c], 1)),
            "rmse_final": math.sqrt(result.final.sq_pos[c] / max(result.final.n_pos[c], 1)),
            # one clip: nothing held out (the shown gap is the forward gap, ``gap``)
            "heldout_rmse_before": result.base_heldout.clip_rmse(c) if len(result.clips) >= 2 else None,
            "heldout_rmse_after": result.final_heldout.clip_rmse(c) if len(result.clips) >= 2 else None,
        })
    noise_floor = float(np.sqrt(np.mean([n.position ** 2 for n in result.noise])))
    return {
        "workflow": "discrepancy (DESIGN.md §8)",
        "inputs": sorted({c.source for c in result.clips}),
        "clips": clips,
        "noise_floor": noise_floor,
        "base": {"rmse": result.base.rmse, "bic": result.base.bic, "chi2": result.base.rss,
                 "chi2_per_residual": result.base.rss / result.base.n, "optimizer": result.base.optimizer()},
        "segments": result.segments,
        "segments_after": result.segments_after,
        "steps": result.steps,
        "named": [{"effect": n["effect"], "parameters": n["parameters"], "ci": n["ci"],
                   "ci_gauss_newton": n.get("ci_gauss_newton", {}), "ci_method": n.get("ci_method", {}),
                   "units": n["units"],
                   "fitted": n["fitted"], "mechanism": n["mechanism"]} for n in result.named],
        "gap": result.gap,
        "in_sample": result.in_sample,
        "final": {"rmse": result.final.rmse, "bic": result.final.bic, "chi2": result.final.rss,
                  "chi2_per_residual": result.final.rss / result.final.n, "optimizer": result.final.optimizer()},
        "config": json.loads(result.config.model_dump_json()),
        "runtime_s": result.runtime_s,
        "files": dict(files or {}),
    }


def _gap_lines(rep: Mapping[str, Any]) -> list[str]:
    """Markdown lines of the shown gap (which one and why) and the in-sample fit."""
    mm, g = 1e3, rep["gap"]
    kind = g.get("kind", "leave_one_clip_out")
    label = g.get("label", "held-out gap (leave one clip out)")
    after = ", ".join(n["effect"] for n in rep["named"]) or "nothing named"
    how = {"leave_one_clip_out": "Held-out: the effects' coefficients are fitted on the other clips (leave one clip "
                                 "out, from the effect's profile); only the clip's own initial state, damping and "
                                 "friction are refitted.",
           "forward": f"Forward: the base model and the base model + {after} are fitted (initial state, damping, "
                      f"friction and the effects' coefficients) on the samples up to {g.get('fit_s', 0):.3g} s "
                      f"({g.get('n_fit', 0)} samples, {100 * rep['config'].get('forward_split', 0.6):.0f} % of the "
                      f"clip), the whole clip is simulated from the fitted initial state, and only the "
                      f"{g.get('n_predicted', 0)} samples after the split are scored (a forecast).",
           "in_sample": "In sample: the models are fitted to the whole clip (no data left to forecast)."}[kind]
    lines = [f"## Gap: {label}", "", f"Which gap and why: {g.get('why', '>= 2 clips: leave one clip out')}.", "",
             "| | RMSE (mm) |", "|---|---|",
             f"| before (base model) | {_fmt(g['before'], mm)} |",
             f"| after ({after}) | {_fmt(g['after'], mm)} |",
             f"| noise floor (measurement sigma) | {_fmt(rep['noise_floor'], mm)} |", "",
             f"Shrink: {100 * g['shrink']:.1f} % (of the part above the noise, "
             f"sqrt(RMSE² − σ²): {mm * g['excess_before']:.2f} → {mm * g['excess_after']:.2f} mm, "
             f"{100 * g['excess_shrink']:.1f} %). {how}", ""]
    ins = rep.get("in_sample")
    if ins:
        lines += ["In-sample fit (all samples, every clip), for comparison: it always improves with more "
                  "parameters, so it is not the evidence.", "",
                  "| model | in-sample RMSE (mm) | fitted parameters k |", "|---|---|---|",
                  f"| base | {_fmt(ins['before'], mm)} | {ins['k_before']} |",
                  f"| base + {after} | {_fmt(ins['after'], mm)} | {ins['k_after']} |", ""]
        if kind == "forward":
            lines += [f"Forward fits: k = {g['k_before']} (base) and {g['k_after']} (with the effects).", ""]
    for v in g.get("variants") or []:
        lines += [f"Forward fit of {v['effect']}: fitted with the base model's linear damping (BIC "
                  f"{v['bic_fitted']:.1f} on the first part) and instead of it (damping held at 0, BIC "
                  f"{v['bic_held']:.1f}): kept with the damping {v['damping']} (lower BIC; the two laws are "
                  f"nearly collinear over a short first part).", ""]
    return lines


def _video_lines(rep: Mapping[str, Any]) -> list[str]:
    """Report lines for a `dynamics infer` input: the gap its re-simulated scene leaves."""
    v = rep.get("video")
    if not v:
        return []
    g = v["resimulation_gap"]
    lines = ["## Video reconstruction", "",
             f"Input: the `dynamics infer` output `{v['folder']}`. Observed tracks (mask centroids) are placed in the "
             f"scene's world frame at the re-simulated object's depth; observed axes: {v['camera_axes']}. "
             f"The re-simulated scene (`scene.yaml`) leaves the observed motion at "
             f"{_fmt(g['rmse_m'], 1e3)} mm ({_fmt(g['rmse_px'], 1, 1)} px) RMSE:", "",
             "| object | samples | RMSE (mm) | RMSE (px) |", "|---|---|---|---|"]
    for name, o in g["per_object"].items():
        lines.append(f"| {name} | {o['samples']} | {o['rmse_m'] * 1e3:.2f} | {o['rmse_px']:.1f} |")
    return lines + ["", "The base model below is refitted to the tracks; the named effects close what it leaves.", ""]


def report_markdown(rep: Mapping[str, Any]) -> str:
    """Human-readable report (Markdown) from :func:`report_dict`."""
    mm = 1e3
    lines = ["# Discrepancy report", "",
             "Workflow of DESIGN.md §8: fit the base model (scene language v1 in MuJoCo) per clip, find where it "
             "disagrees with the measurements beyond their noise, name the missing effect(s) from the library, add "
             "them and show the gap shrink (held-out with >= 2 clips, forward in time with one).", "",
             f"Inputs: {', '.join(rep['inputs'])}", "",
             *_video_lines(rep),
             *_gap_lines(rep),
             "## Named effects", ""]
    if rep["named"]:
        lines += ["| effect | mechanism | parameter | value | 95 % CI | unit |", "|---|---|---|---|---|---|"]
        for n in rep["named"]:
            for p, v in n["parameters"].items():
                cis = _fmt_interval(n["ci"].get(p))
                lines.append(f"| {n['effect']} | {n['mechanism']} | {p} | {v:.4g} | {cis} | {n['units'].get(p, '')} |")
    else:
        lines.append("None: no candidate cleared the noise floor (BIC and held-out gates).")
    lines += ["", "## Candidates", ""]
    for st in rep["steps"]:
        model = " + ".join(["base"] + st["model"])
        lines += [f"### Step {st['step']}: {model} + candidate -> named: {st['named'] or 'none'}", "",
                  "| candidate | fit gain (mm) | fit gain (%) | ΔBIC | profile Δχ² | held-out RMSE (mm) | held-out gain (mm) | held-out Δχ² | named? |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for cd in sorted(st["candidates"], key=lambda d: d["delta_bic"]):
            params = ", ".join(f"{k}={v:.3g}" for k, v in cd["parameters"].items())
            lines.append(f"| {cd['effect']} ({params}) | {_fmt(cd['fit_gain'], mm)} | {cd['fit_gain_pct']:.1f} | "
                         f"{cd['delta_bic']:.1f} | {cd['profile_gain']:.1f} | {_fmt(cd['heldout_rmse'], mm)} | {_fmt(cd['heldout_gain'], mm)} | "
                         f"{_fmt(cd['heldout_delta_chi2'], 1, 1)} | {'yes' if cd['named'] else 'no: ' + cd['reason'] if not cd['eligible'] else 'eligible'} |")
        out = {e: v for e, v in (st.get("screen") or {}).items() if not v.get("passed", True)}
        if out:
            lines.append("")
            lines.append("Screened out before the full fits (linearised prediction of the χ² gain below "
                         "`screen_gain`): " + ", ".join(f"{e} ({v['predicted_gain']:.1f})" for e, v in out.items()) + ".")
        lines.append("")
        clip_names = list(st["candidates"][0].get("per_clip_gain", {})) if st["candidates"] else []
        if clip_names:
            lines += ["Per-clip evidence: χ² drop when the effect's strength is chosen for each clip alone "
                      "(profile minimum; about 4 is the 95 % level for one parameter).", "",
                      "| candidate | " + " | ".join(clip_names) + " |", "|---|" + "---|" * len(clip_names)]
            for cd in st["candidates"]:
                lines.append(f"| {cd['effect']} | " + " | ".join(f"{cd['per_clip_gain'][c]:.1f}" for c in clip_names) + " |")
            lines.append("")
    lines += ["## Clips", "", "| clip | objects | samples | noise (mm) | noise (deg) | base RMSE (mm) | extended RMSE (mm) | held-out before / after (mm) |",
              "|---|---|---|---|---|---|---|---|"]
    for c in rep["clips"]:
        objs = ", ".join(f"{o['object']} ({o['shape']}, {o['mass'] * 1e3:.3g} g{', assumed ' + '/'.join(o['assumed']) if o['assumed'] else ''})"
                         for o in c["objects"])
        lines.append(f"| {c['clip']} | {objs} | {c['n_samples']} | {_fmt(c['noise']['position'], mm, 3)} | "
                     f"{_fmt(c['noise']['angle_deg'])} | {_fmt(c['rmse_base'], mm)} | {_fmt(c['rmse_final'], mm)} | "
                     f"{_fmt(c['heldout_rmse_before'], mm)} / {_fmt(c['heldout_rmse_after'], mm)} |")
    lines += ["", "## Where the base model disagrees (residual segments above the noise)", ""]
    if rep["segments"]:
        lines += ["| clip | object | channel | time (s) | phase | samples | max | threshold |", "|---|---|---|---|---|---|---|---|"]
        for s in rep["segments"][:60]:
            unit, k = ("mm", mm) if s["channel"] == "position" else ("deg", 1.0)
            lines.append(f"| {s['clip']} | {s['object']} | {s['channel']} | {s['t_start']:.3f}–{s['t_end']:.3f} | "
                         f"{s['phase']} | {s['n_samples']} | {s['max'] * k:.2f} {unit} | {s['threshold'] * k:.2f} {unit} |")
        if len(rep["segments"]) > 60:
            lines.append(f"| … {len(rep['segments']) - 60} more in discrepancy.json | | | | | | | |")
    else:
        lines.append("None: the base model fits every clip within the noise.")
    lines += ["", f"After adding the named effects: {len(rep['segments_after'])} segments remain "
              f"(base model: {len(rep['segments'])}).", ""]
    files = rep.get("files") or {}
    if files:
        lines += ["## Files", ""] + [f"- {k}: `{v}`" for k, v in files.items() if v] + [""]
    lines += ["## Method", "",
              "- Base model: scene language v1 in MuJoCo; per clip and object the initial position, orientation, linear "
              "and angular velocity, `material.damping` (linear, i.e. viscous drag is part of the base model) and "
              "`material.sliding_friction` are fitted by least squares (finite-difference Jacobian over rollouts; "
              "continuation over the clip's length).",
              "- Noise: from the data alone (residuals of local quadratic fits; orientation from differences of "
              "rotation increments), robust scale 1.4826·MAD. Residuals are divided by it.",
              f"- Naming: ΔBIC ≤ −{rep['config']['bic_threshold']:g}, profile Δχ² (every clip refitted from the data "
              f"with the effect vs. without) ≥ {rep['config']['heldout_threshold']:g}, held-out Δχ² ≥ "
              f"{rep['config']['heldout_threshold']:g} and a smaller held-out RMSE; among eligible candidates the lowest "
              "BIC is named; greedy forward selection until nothing is eligible or every clip is at the noise floor.",
              "- Confidence intervals: profile likelihood (the coefficient fixed, everything else refitted; threshold "
              "χ²₁ quantile × χ²/dof), where the Gauss-Newton interval s²(JᵀJ)⁻¹ (Student-t, "
              "`mujoco.sysid.calculate_intervals`) is accepted when the profile confirms its ends within 25 %; a side "
              "the data cannot bound before the search bound is shown open.",
              f"- Runtime: {rep['runtime_s']:.0f} s."]
    return "\n".join(lines) + "\n"


_PHASE_COLOURS = {"flight": "#ffffff", "contact": "#d62728", "sliding": "#ff7f0e", "rolling": "#2ca02c", "rest": "#7f7f7f"}


def plot_residuals(result: Result, path: str | Path, max_clips: int = 8) -> Path:
    """PNG: per clip, position residual norm (mm) over time for the base model (before) and
    the extended model (after), the flagging threshold, and the measured motion phase as a
    colour band."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from scipy.stats import chi2

    clips = result.clips[:max_clips]
    fig = Figure(figsize=(9, 2.2 * len(clips) + 0.6), dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(clips), 1, squeeze=False)[:, 0]
    label = " + ".join(n["effect"] for n in result.named) or "nothing named"
    for c, (ax, clip) in enumerate(zip(axes, clips)):
        for i, tr in enumerate(clip.tracks):
            idx = np.searchsorted(clip.times, tr.t)
            e0 = np.linalg.norm((result.base_qpos[c][idx, i, :3] - tr.pos)[:, tr.axes], axis=1) * 1e3
            e1 = np.linalg.norm((result.final_qpos[c][idx, i, :3] - tr.pos)[:, tr.axes], axis=1) * 1e3
            ax.plot(tr.t, e0, color="#d62728", lw=1.2, label=f"{tr.object}: base" if c == 0 else None)
            ax.plot(tr.t, e1, color="#1f77b4", lw=1.2, label=f"{tr.object}: + {label}" if c == 0 else None)
            w, dof = min(result.config.segment_window, len(tr.t)), int(tr.axes.sum())
            thr = result.noise[c].position * math.sqrt(chi2.isf(result.config.segment_p, w * dof) / w) * 1e3
            ax.axhline(thr, color="k", ls="--", lw=0.8,
                       label=f"noise threshold (RMS over {w} samples)" if c == 0 and i == 0 else None)
            top = max(float(np.max(e0)), thr) * 1.1
            ph = result.phases[c][i]
            for k in range(len(tr.t)):
                t1 = tr.t[k + 1] if k + 1 < len(tr.t) else tr.t[k] + (tr.t[k] - tr.t[k - 1])
                ax.axvspan(tr.t[k], t1, ymin=0, ymax=0.04, color=_PHASE_COLOURS[ph[k]], lw=0)
            ax.set_ylim(0, top)
        ax.set_title(f"{clip.name}", fontsize=9)
        ax.set_ylabel("|residual| (mm)")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("t (s)   band: phase (white flight, red contact, orange sliding, green rolling, grey rest)")
    fig.legend(loc="upper right", fontsize=8)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return write_bytes(path, buf.getvalue())


def plot_trajectories(result: Result, path: str | Path, max_clips: int = 8) -> Path:
    """PNG: measured positions (dots) against the base and extended models (lines), one row
    per clip, one column per observed coordinate."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    clips = result.clips[:max_clips]
    fig = Figure(figsize=(10, 2.2 * len(clips) + 0.6), dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(clips), 3, squeeze=False)
    for c, clip in enumerate(clips):
        for i, tr in enumerate(clip.tracks):
            idx = np.searchsorted(clip.times, tr.t)
            for a, name in enumerate("xyz"):
                ax = axes[c, a]
                if not tr.axes[a]:
                    ax.text(0.5, 0.5, "not observed", ha="center", transform=ax.transAxes)
                    continue
                ax.plot(tr.t, tr.pos[:, a], ".", ms=3, color="k", label="measured" if c == a == 0 else None)
                ax.plot(clip.times, result.base_qpos[c][:, i, a], color="#d62728", lw=1, label="base" if c == a == 0 else None)
                ax.plot(clip.times, result.final_qpos[c][:, i, a], color="#1f77b4", lw=1,
                        label="extended" if c == a == 0 else None)
                ax.set_ylabel(f"{name} (m)")
                ax.grid(alpha=0.3)
        axes[c, 0].set_title(clip.name, fontsize=9, loc="left")
    for a in range(3):
        axes[-1, a].set_xlabel("t (s)")
    fig.legend(loc="upper right", fontsize=8)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return write_bytes(path, buf.getvalue())


def record(result: Result, path: str | Path) -> Path:
    """Rerun recording: every clip's objects as measured, as the base model and as the
    extended model fits them (clips side by side, 1 m apart along y), on a common frame
    timeline, with residual norms as scalars (``metrics/<clip>/base|extended``, m)."""
    from pipeline.viz import record_clip

    T = max(len(c.times) for c in result.clips)
    objs, pos, quat, scalars = [], [], [], {}
    for c, clip in enumerate(result.clips):
        offset = np.array([0.0, 1.0 * c, 0.0])
        for i, tr in enumerate(clip.tracks):
            idx = np.searchsorted(clip.times, tr.t)
            meas_q = tr.quat if tr.quat is not None else result.base_qpos[c][idx, i, 3:]
            for kind, p, q in (("measured", tr.pos, meas_q),
                               ("base", result.base_qpos[c][idx, i, :3], result.base_qpos[c][idx, i, 3:]),
                               ("extended", result.final_qpos[c][idx, i, :3], result.final_qpos[c][idx, i, 3:])):
                pad = T - len(p)
                pp = np.concatenate([p, np.repeat(p[-1:], pad, 0)]) + offset
                qq = np.concatenate([q, np.repeat(q[-1:], pad, 0)])
                objs.append({"name": f"{_safe_name(clip.name)}/{tr.object}/{kind}", "shape": tr.spec.shape,
                             "size": tr.spec.size})
                pos.append(pp)
                quat.append(qq)
            for kind, q in (("base", result.base_qpos[c]), ("extended", result.final_qpos[c])):
                e = np.linalg.norm((q[idx, i, :3] - tr.pos)[:, tr.axes], axis=1)
                scalars[f"{_safe_name(clip.name)}/{tr.object}/{kind}"] = np.concatenate([e, np.full(T - len(e), np.nan)])
    return record_clip(path, positions=np.stack(pos, 1), quaternions=np.stack(quat, 1), objects=objs,
                       scalars=scalars, fps=float(result.clips[0].fps), app_id="dynamics_discrepancy")


def write_report(result: Result, report_dir: str | Path, artifacts_dir: str | Path | None = None,
                 decimals: Decimals | None = None, video: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Write the report and the extended model.

    ``report_dir``: ``discrepancy.md``, ``discrepancy.json``, ``discrepancy_residuals.png``,
    ``discrepancy_trajectories.png``. ``artifacts_dir`` (default: ``report_dir``):
    ``scenes/<clip>.yaml`` (extended scenes), ``effects.yaml`` (the named effects' block),
    ``discrepancy.rrd`` (rerun). Every file is written atomically.

    Returns:
        The JSON report dict.
    """
    report_dir = Path(report_dir)
    art = Path(artifacts_dir) if artifacts_dir is not None else report_dir
    files: dict[str, Any] = {}
    scenes = extended_scenes(result)
    paths = []
    for name, scene in scenes.items():
        p = art / "scenes" / f"{_safe_name(name)}.yaml"
        write_text(p, scene.to_yaml(decimals or DISCREPANCY_DECIMALS))
        paths.append(str(p))
    files["extended_scenes"] = str(art / "scenes")
    eff = {"effects": [{"effect": n["effect"], "parameters": {k: round(v, 6) for k, v in n["parameters"].items()}}
                       for n in result.named]}
    files["effects_yaml"] = str(write_text(art / "effects.yaml", yaml.safe_dump(eff, sort_keys=False)))
    files["residual_plot"] = str(plot_residuals(result, report_dir / "discrepancy_residuals.png"))
    files["trajectory_plot"] = str(plot_trajectories(result, report_dir / "discrepancy_trajectories.png"))
    if result.config.recording:
        files["recording"] = str(record(result, art / "discrepancy.rrd"))
    rep = report_dict(result, files)
    if video:   # input was a `dynamics infer` folder: the gap its re-simulation left
        rep["video"] = dict(video)
    write_json(report_dir / "discrepancy.json", rep)
    write_text(report_dir / "discrepancy.md", report_markdown(rep))
    return rep


# =========================================================================== benchmark
def run_trial(seed: int, effect: str, cfg: DiscrepancyConfig | None = None, hidden: HiddenConfig | None = None,
              options: SimOptions | None = None) -> dict[str, Any]:
    """One hidden-effect trial: generate data with ``effect`` (``none`` or a name) at a
    random strength, run the workflow on the measurements only, compare with the truth.

    Returns:
        ``{seed, truth, truth_parameters, named, named_parameters, correct, gap_before,
        gap_after, shrink, runtime_s}``.
    """
    t0 = time.perf_counter()
    cols, truth = generate_hidden(seed, hidden, options, effect=effect)
    clips = clips_from_columns(cols, f"<hidden seed {seed}>")
    result = run_workflow(clips, cfg, options)                  # never sees ``truth``
    named = [n["effect"] for n in result.named]
    expected = [truth["effect"]] if truth["effect"] else []
    gap = result.gap
    return {"seed": seed, "truth": truth["effect"], "truth_parameters": truth["parameters"], "named": named,
            "named_parameters": {n["effect"]: n["parameters"] for n in result.named},
            "named_ci": {n["effect"]: n["ci"] for n in result.named},
            "correct": named == expected, "gap_before": gap["before"], "gap_after": gap["after"],
            "shrink": gap["shrink"], "noise": gap["noise"], "excess_shrink": gap["excess_shrink"],
            "runtime_s": time.perf_counter() - t0}


def _trial_job(args: tuple) -> dict[str, Any]:
    seed, effect, cfg, hidden, options = args
    return run_trial(seed, effect, cfg, hidden, options)


def run_benchmark(trials: int, null_trials: int, seed: int = 1000, jobs: int | ComputeConfig = 1,
                  cfg: DiscrepancyConfig | None = None, hidden: HiddenConfig | None = None,
                  options: SimOptions | None = None, log=None, single_trials: int = 0,
                  single_duration: float = 1.5) -> dict[str, Any]:
    """Naming accuracy over hidden-effect trials and false-positive rate over no-effect trials.

    Effect trials cycle through the library (so each effect gets ``trials / 6`` trials), each
    with a fresh seed (``seed + i``) and a random strength; no-effect trials use seeds after
    them.

    Args:
        trials: number of trials with a hidden effect.
        null_trials: number of trials without one.
        seed: first seed.
        jobs: local worker processes, or a :class:`pipeline.parallel.ComputeConfig` (e.g. Ray).
        cfg, hidden, options: workflow, data and simulation settings.
        log: optional ``print``-like callable (one line per finished trial).
        single_trials: further trials with a hidden effect (cycling the library) on ONE clip
            of ``single_duration`` s (the shown gap is then the forward gap), seeds after the
            no-effect trials; scored apart (``summary["single"]``, ``per_effect_single``).

    Naming is scored as the exact set: a trial is correct when the named effects are exactly
    the hidden one (or none), so an extra effect is a miss. ``gap_within_1p5_noise`` is the
    fraction of effect trials whose shown gap after naming is at most 1.5x the noise floor
    (the pooled noise estimate).

    Returns:
        ``{summary: {...}, per_effect: {...}, per_effect_single: {...}, trials: [...]}``
        (each trial has ``group``: ``effect``, ``null`` or ``single``).
    """
    names = list(fx.REGISTRY)
    hidden = hidden or HiddenConfig()
    single = hidden.model_copy(update={"n_clips": 1, "duration": single_duration})
    plan = [(seed + i, names[i % len(names)], hidden) for i in range(trials)]
    plan += [(seed + trials + i, "none", hidden) for i in range(null_trials)]
    plan += [(seed + trials + null_trials + i, names[i % len(names)], single) for i in range(single_trials)]
    cfg = cfg or DiscrepancyConfig()
    compute = jobs if isinstance(jobs, ComputeConfig) else ComputeConfig(workers=jobs)
    if compute.backend == "ray" or compute.n_workers > 1:  # one rollout thread per worker process
        cfg = cfg.model_copy(update={"threads": 1, "workers": 1})
    args = [(s, e, cfg, h, options) for s, e, h in plan]
    t0 = time.perf_counter()
    results = []
    for r in parallel_map(_trial_job, args, compute):  # one trial per task: each takes seconds
        results.append(r)
        if log:
            log(f"[{len(results)}/{len(args)}] seed {r['seed']}: truth {r['truth']}, named {r['named']}, "
                f"gap {r['gap_before'] * 1e3:.2f} -> {r['gap_after'] * 1e3:.2f} mm")
    results.sort(key=lambda r: r["seed"])
    first_single = seed + trials + null_trials
    for r in results:
        r["group"] = "single" if r["seed"] >= first_single else ("effect" if r["truth"] else "null")
    eff = [r for r in results if r["group"] == "effect"]
    null = [r for r in results if r["group"] == "null"]
    one = [r for r in results if r["group"] == "single"]
    summary = {**_bench_summary(eff), "effect_trials": len(eff), "null_trials": len(null),
               "false_positive_rate": sum(bool(r["named"]) for r in null) / len(null) if null else None,
               "runtime_s": time.perf_counter() - t0, "jobs": jobs if isinstance(jobs, int) else compute.model_dump(),
               "first_seed": seed,
               "single": {**_bench_summary(one), "trials": len(one), "duration_s": single_duration}}
    return {"summary": summary, "per_effect": _per_effect(eff, names), "per_effect_single": _per_effect(one, names),
            "trials": results, "config": json.loads(cfg.model_dump_json()),
            "hidden": json.loads(hidden.model_dump_json())}


def _bench_summary(rs: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Accuracy (exact set), gap-shrink figures and the fraction of trials whose shown gap after
    naming is within 1.5x the noise floor, over trials ``rs`` (``None`` where empty)."""
    if not rs:
        return {"naming_accuracy": None, "shrink_at_least_50pct": None, "median_shrink": None,
                "excess_shrink_at_least_50pct": None, "median_excess_shrink": None, "gap_within_1p5_noise": None}
    n = len(rs)
    return {"naming_accuracy": sum(r["correct"] for r in rs) / n,
            "shrink_at_least_50pct": sum(r["shrink"] >= 0.5 for r in rs) / n,
            "median_shrink": float(np.median([r["shrink"] for r in rs])),
            "excess_shrink_at_least_50pct": sum(r["excess_shrink"] >= 0.5 for r in rs) / n,
            "median_excess_shrink": float(np.median([r["excess_shrink"] for r in rs])),
            "gap_within_1p5_noise": sum(r["gap_after"] <= 1.5 * r["noise"] for r in rs) / n}


def _per_effect(rs: Sequence[Mapping[str, Any]], names: Sequence[str]) -> dict[str, dict[str, Any]]:
    per = {}
    for name in names:
        sub = [r for r in rs if r["truth"] == name]
        if sub:
            per[name] = {"trials": len(sub), "correct": sum(r["correct"] for r in sub),
                         "accuracy": sum(r["correct"] for r in sub) / len(sub),
                         "median_shrink": float(np.median([r["shrink"] for r in sub])),
                         "min_shrink": float(np.min([r["shrink"] for r in sub])),
                         "gap_within_1p5_noise": sum(r["gap_after"] <= 1.5 * r["noise"] for r in sub) / len(sub)}
    return per


def benchmark_markdown(bench: Mapping[str, Any], command: str = "") -> str:
    """Markdown summary of :func:`run_benchmark`."""
    s = bench["summary"]
    pct = lambda x: "—" if x is None else f"{100 * x:.1f} %"  # noqa: E731
    lines = ["# Discrepancy workflow: hidden-effect benchmark", "",
             f"Each trial generates measured trajectories ({bench['hidden']['n_clips']} clips of {bench['hidden']['duration']:g} s, "
             f"noise {bench['hidden']['noise_position'] * 1e3:g} mm / {bench['hidden']['noise_angle']:g}°) with one effect from the library "
             "at a random strength (or none), runs the workflow without telling it, and checks what it names.", ""]
    if command:
        lines += ["```", command, "```", ""]
    lines += ["| metric | value |", "|---|---|",
              f"| naming accuracy ({s['effect_trials']} trials with a hidden effect) | {pct(s['naming_accuracy'])} |",
              f"| false-positive rate ({s['null_trials']} trials without) | {pct(s['false_positive_rate'])} |",
              f"| held-out gap shrink >= 50 % (effect trials) | {pct(s['shrink_at_least_50pct'])} |",
              f"| held-out gap above the noise shrink >= 50 % | {pct(s.get('excess_shrink_at_least_50pct'))} |",
              f"| median held-out gap shrink | {pct(s['median_shrink'])} |",
              f"| median shrink of the gap above the noise | {pct(s.get('median_excess_shrink'))} |",
              f"| held-out gap after naming within 1.5x the noise floor | {pct(s.get('gap_within_1p5_noise'))} |"]
    one = s.get("single") or {}
    if one.get("trials"):
        lines += [f"| single clip ({one['trials']} trials, 1 clip of {one['duration_s']:g} s, forward gap): naming accuracy | "
                  f"{pct(one['naming_accuracy'])} |",
                  f"| single clip: median forward-gap shrink / above the noise | {pct(one['median_shrink'])} / "
                  f"{pct(one['median_excess_shrink'])} |",
                  f"| single clip: forward gap after naming within 1.5x the noise floor | {pct(one['gap_within_1p5_noise'])} |"]
    lines += [f"| runtime | {s['runtime_s'] / 60:.1f} min ({s['jobs']} jobs) |", "",
              "Naming is scored as the exact set of named effects (an extra effect is a miss).", ""]
    for title, per in (("", bench["per_effect"]), ("single clip ", bench.get("per_effect_single") or {})):
        if not per:
            continue
        lines += [f"| {title}effect | trials | correct | accuracy | median shrink | min shrink | gap ≤ 1.5x noise |",
                  "|---|---|---|---|---|---|---|"]
        for name, p in per.items():
            lines.append(f"| {name} | {p['trials']} | {p['correct']} | {pct(p['accuracy'])} | {pct(p['median_shrink'])} | "
                         f"{pct(p['min_shrink'])} | {pct(p.get('gap_within_1p5_noise'))} |")
        lines.append("")
    wrong = [r for r in bench["trials"] if not r["correct"]]
    if wrong:
        lines += ["", "Misnamed trials:", "", "| seed | group | truth | named | gap before → after (mm) |", "|---|---|---|---|---|"]
        for r in wrong:
            lines.append(f"| {r['seed']} | {r.get('group', '')} | {r['truth'] or 'none'} | {', '.join(r['named']) or 'none'} | "
                         f"{r['gap_before'] * 1e3:.2f} → {r['gap_after'] * 1e3:.2f} |")
    return "\n".join(lines) + "\n"


# =========================================================================== command line
def load_config(params: Mapping[str, Any] | None) -> tuple[DiscrepancyConfig, HiddenConfig, SimOptions]:
    """Typed configs from a params dict (sections ``discrepancy``, ``measure_hidden``,
    ``sim``; missing sections take the defaults).

    Raises:
        DiscrepancyInputError: a section fails validation (one line naming the key).
    """
    params = params or {}
    out = []
    for key, cls in (("discrepancy", DiscrepancyConfig), ("measure_hidden", HiddenConfig), ("sim", SimOptions)):
        try:
            out.append(cls(**(params.get(key) or {})))
        except (ValidationError, ValueError) as exc:
            msg = str(exc).splitlines()
            if isinstance(exc, ValidationError):
                err = exc.errors()[0]
                msg = [f"{'.'.join(map(str, err['loc']))}: {err['msg']}"]
            raise DiscrepancyInputError(f"params.yaml: {key}: {msg[0]}") from None
    return out[0], out[1], out[2]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``dynamics discrepancy``."""
    parser.add_argument("trajectories", nargs="+", metavar="TRAJECTORIES",
                        help="trajectory files (CSV/Parquet with clip, object, t, x, y, z [m, s, z up]; or 2-D Tracker "
                             "exports with t and x, y [y up]) or directories of them; or ONE output folder of "
                             "`dynamics infer` (scene.yaml + tracks.csv): where does its re-simulation leave the video")
    parser.add_argument("--out", required=True, help="output directory (report, plots, extended scenes, .rrd)")
    parser.add_argument("--objects", default=None,
                        help="object sizes/masses: YAML/JSON file or inline YAML "
                             "'{CLIP: {OBJECT: {shape: sphere, radius: 0.02, mass: 0.0027}}}' ('*' = any)")
    parser.add_argument("--candidates", default=None,
                        help=f"comma-separated effects to try (default: all: {','.join(fx.REGISTRY)})")
    parser.add_argument("--max-effects", type=int, default=None, help="most effects named (greedy forward selection)")
    parser.add_argument("--bic-threshold", type=float, default=None, help="BIC drop needed to name an effect")
    parser.add_argument("--heldout-threshold", type=float, default=None, help="held-out chi-square drop needed")
    parser.add_argument("--params", default=None,
                        help="params.yaml to read sections discrepancy and sim from (default: ./params.yaml if present)")
    parser.add_argument("--no-recording", action="store_true", help="skip the rerun recording")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")


def _config_from_args(args: argparse.Namespace) -> tuple[DiscrepancyConfig, HiddenConfig, SimOptions]:
    from pipeline.params import load_params

    path = getattr(args, "params", None)
    params = {}
    if path or Path("params.yaml").exists():
        params = load_params(path or "params.yaml")
    cfg, hidden, sim = load_config(params)
    update: dict[str, Any] = {}
    if getattr(args, "candidates", None):
        update["candidates"] = tuple(c.strip() for c in args.candidates.split(",") if c.strip())
    for key in ("max_effects", "bic_threshold", "heldout_threshold"):
        if getattr(args, key, None) is not None:
            update[key] = getattr(args, key)
    if getattr(args, "no_recording", False):
        update["recording"] = False
    if update:
        try:
            cfg = DiscrepancyConfig(**{**cfg.model_dump(), **update})
        except ValidationError as exc:
            err = exc.errors()[0]
            field = str(err["loc"][0]) if err.get("loc") else "candidates"
            msg = str(err.get("msg", "invalid")).removeprefix("Value error, ").removeprefix(f"{field}: ")
            raise DiscrepancyInputError(f"--{field.replace('_', '-')}: {msg}") from None
        except ValueError as exc:
            raise DiscrepancyInputError(f"--candidates: {str(exc).splitlines()[0].strip()}") from None
    return cfg, hidden, sim


def main_cli(args: argparse.Namespace) -> int:
    """``dynamics discrepancy TRAJECTORIES... --out DIR``: run the workflow and write the report.

    Raises:
        DiscrepancyInputError: bad trajectories, objects or options (the CLI prints it, exit 2).
    """
    cfg, _, sim = _config_from_args(args)
    say = None if args.quiet else (lambda m: print(m, file=sys.stderr, flush=True))
    video, gravity = None, 9.81
    if any(infer_tracks.is_infer_dir(t) for t in args.trajectories):
        if len(args.trajectories) != 1:
            raise DiscrepancyInputError(f"{args.trajectories[0]}: a `dynamics infer` folder must be the only input")
        clips, video, gravity = clips_from_infer_dir(args.trajectories[0], cfg.default_object)
        g = video["resimulation_gap"]
        print(f"video reconstruction {args.trajectories[0]}: the re-simulated scene leaves "
              f"{g['rmse_m'] * 1e3:.2f} mm ({g['rmse_px']:.1f} px) RMSE on the observed tracks "
              f"(axes {video['camera_axes']})")
    else:
        clips = read_trajectories(args.trajectories, args.objects, cfg.default_object)
    result = run_workflow(clips, cfg, sim, gravity=gravity, log=say)
    rep = write_report(result, args.out, video=video)
    named = ", ".join(f"{n['effect']} ({', '.join(f'{k}={v:.4g}' for k, v in n['parameters'].items())})"
                      for n in rep["named"]) or "none"
    print(f"named: {named}")
    g = rep["gap"]
    print(f"{g.get('label', 'held-out gap')}: {g['before'] * 1e3:.2f} mm -> {g['after'] * 1e3:.2f} mm "
          f"(noise floor {rep['noise_floor'] * 1e3:.2f} mm; above the noise {g['excess_before'] * 1e3:.2f} -> "
          f"{g['excess_after'] * 1e3:.2f} mm, shrink {100 * g['excess_shrink']:.0f} %; {g.get('why', '')})")
    ins = rep["in_sample"]
    print(f"in-sample RMSE: {ins['before'] * 1e3:.2f} mm (k={ins['k_before']}) -> {ins['after'] * 1e3:.2f} mm "
          f"(k={ins['k_after']})")
    print(f"report: {Path(args.out) / 'discrepancy.md'}")
    return 0


def _main(argv: Sequence[str] | None = None) -> int:
    """``python -m pipeline.discrepancy {run,benchmark} ...``."""
    parser = argparse.ArgumentParser(prog="python -m pipeline.discrepancy", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    add_arguments(sub.add_parser("run", help="the workflow on trajectories (same as `dynamics discrepancy`)"))
    b = sub.add_parser("benchmark", help="naming accuracy on hidden-effect data")
    b.add_argument("--trials", type=int, default=60, help="trials with a hidden effect (cycling the library)")
    b.add_argument("--null-trials", type=int, default=12, help="trials without an effect")
    b.add_argument("--single-trials", type=int, default=12,
                   help="trials with a hidden effect on ONE clip (forward gap), scored apart")
    b.add_argument("--single-duration", type=float, default=1.5, help="s, length of the single clip")
    b.add_argument("--seed", type=int, default=1000, help="first seed")
    b.add_argument("--jobs", type=int, default=1, help="worker processes (Ray: tasks in flight)")
    b.add_argument("--backend", choices=("local", "ray"), default="local", help="pipeline.parallel backend")
    b.add_argument("--address", default=None, help="Ray address (auto, ray://host:port); default: local Ray")
    b.add_argument("--out", default="reports/discrepancy_benchmark.json", help="JSON output (.md written beside it)")
    b.add_argument("--params", default=None, help="params.yaml (sections discrepancy, measure_hidden, sim)")
    args = parser.parse_args(argv)
    try:
        if args.command == "run":
            return main_cli(args)
        cfg, hidden, sim = _config_from_args(args)
        jobs = args.jobs if args.backend == "local" else ComputeConfig(backend="ray", address=args.address,
                                                                            workers=args.jobs)
        bench = run_benchmark(args.trials, args.null_trials, args.seed, jobs, cfg, hidden, sim,
                              log=lambda m: print(m, flush=True), single_trials=args.single_trials,
                              single_duration=args.single_duration)
        out = Path(args.out)
        command = "python -m pipeline.discrepancy benchmark " + " ".join(
            f"--{k.replace('_', '-')} {v}" for k, v in (("trials", args.trials), ("null_trials", args.null_trials),
                                                       ("single_trials", args.single_trials),
                                                       ("single_duration", args.single_duration),
                                                       ("seed", args.seed), ("jobs", args.jobs), ("out", args.out)))
        bench["command"] = command
        write_json(out, bench)
        write_text(out.with_suffix(".md"), benchmark_markdown(bench, command))
        s = bench["summary"]
        print(f"naming accuracy {s['naming_accuracy']:.3f} over {s['effect_trials']} trials; false-positive rate "
              f"{s['false_positive_rate']:.3f} over {s['null_trials']}; wrote {out}")
        return 0
    except DiscrepancyInputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(_main())
