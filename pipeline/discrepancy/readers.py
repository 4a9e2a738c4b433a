"""Reading trajectory tables (CSV, Parquet, Tracker text exports, ``dynamics infer`` folders)
into :class:`~pipeline.discrepancy.trajectories.Clip` objects, with the plausibility checks
that turn wrong units and gaps into one-line :class:`DiscrepancyInputError` messages."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import pyarrow.parquet as pq
import yaml

from pipeline import infer_tracks
from pipeline.discrepancy.config import DefaultObject
from pipeline.discrepancy.noise import local_quadratic
from pipeline.rotation import quat_mul
from pipeline.discrepancy.trajectories import (MIN_SAMPLES, QUAT_COLUMNS, SPEC_COLUMNS, TABLE_COLUMNS, Clip,
                                               DiscrepancyInputError, ObjectSpec, Track)


TWO_D_FLOOR_CLEARANCE = 0.05
"""m. Two-dimensional Tracker exports have an arbitrary vertical origin. Where a track bounces,
the floor goes under the impact (:func:`bounce_floor`); otherwise (a drop that ends before the
impact) the reader lifts the clip so that every object's lowest point stays at least this far
above z = 0, i.e. the clip is free flight."""
MAX_ABS_COORDINATE = 100.0
"""m; larger values are taken for pixels (a one-line error names the column)."""


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


def typical_acceleration(t: np.ndarray, pos: np.ndarray) -> np.ndarray:
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
    acc = typical_acceleration(tt, pos)
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


def _arc(t: np.ndarray, z: np.ndarray, g: float) -> tuple[float, float] | None:
    """``(a, b)`` of the free-flight arc ``z(t) = a + b t - g t^2 / 2`` fitted by least squares
    to the samples ``(t, z)`` (at least 2), else ``None``."""
    if len(t) < 2:
        return None
    A = np.stack([np.ones(len(t)), t], 1)
    coef, *_ = np.linalg.lstsq(A, z + 0.5 * g * t * t, rcond=None)
    return float(coef[0]), float(coef[1])


def bounce_floor(t: np.ndarray, z: np.ndarray, radius: float, g: float = GRAVITY_CHECK,
                 noise: float | None = None) -> float | None:
    """Height of the floor under a vertical track that bounces, in the track's own frame.

    A bounce is where the change of velocity over three steps (``z[j+2] - z[j+1] - z[j] +
    z[j-1]``, the sum of two second differences: an impact between samples spreads over two) is
    largest, when that is positive by more than ``2 g dt^2`` plus 6 of its noise standard
    deviations (``2 sigma``; free flight gives ``-2 g dt^2``, rest 0: only a contact pushes up);
    ``k`` is the lower of its two middle samples, and ``k`` or a neighbour is at the bottom of
    the track (within 6 noise standard deviations and ``g dt^2`` of its lowest
    sample). The impact
    is where the free-flight arcs (gravity ``g`` known) through up to 4 samples before and
    after it meet, or, where the samples after it fit a constant better than an arc (a dead
    ball that stays down), at that resting height; ``k`` goes to the side that fits better.
    The centre is then one ``radius`` above the floor. With one sample after the bounce the lowest sample stands in
    for the impact (a bounce seen in the last frames: the floor is then at most one frame's
    travel too low).

    Args:
        t: ``(T,)`` s, increasing. z: ``(T,)`` m, vertical coordinate, up.
        radius: m, height of the centre above the floor at contact (bounding radius).
        g: m/s^2. noise: m, standard deviation of ``z`` (default: 1.4826 x the median absolute
            residual of local quadratic fits, :func:`pipeline.discrepancy.noise.local_quadratic`).

    Returns:
        The floor height (m, the track's frame), or ``None`` when the track does not bounce.
    """
    T = len(t)
    if T < 3:
        return None
    d2 = np.diff(z, 2)
    dt = float(np.median(np.diff(t)))
    if noise is None:   # robust scale of local quadratic residuals (flight and rest alike)
        _, res, _ = local_quadratic(t, z[:, None])
        noise = 1.4826 * float(np.median(np.abs(res))) if res.size else 0.0
    if T < 4:
        return None
    # the change of velocity over three steps, z[k+2] - z[k+1] - z[k] + z[k-1]: an impact between
    # samples spreads over two second differences (noise 2 sigma; free flight -2 g dt^2)
    dv = d2[:-1] + d2[1:]
    j = int(np.argmax(dv))
    if dv[j] <= 2 * g * dt * dt + 6 * 2.0 * noise:
        return None
    k = j + 1 + int(np.argmin(z[j + 1:j + 3]))     # the lower of its two middle samples
    if k >= T - 1:
        return None
    if float(np.min(z[k - 1:k + 2])) > float(np.min(z)) + 6.0 * noise + g * dt * dt:   # not at the bottom
        return None
    best = None
    for split in (k, k + 1):            # samples [.., split) before the impact, [split, ..) after
        lo, hi = max(0, split - 4), min(T, split + 4)
        tb, zb, ta, za = t[lo:split], z[lo:split], t[split:hi], z[split:hi]
        before, after = _arc(tb - t[k], zb, g), _arc(ta - t[k], za, g)
        if before is None or after is None:
            continue
        res_before = float(np.sum((before[0] + before[1] * (tb - t[k]) - 0.5 * g * (tb - t[k]) ** 2 - zb) ** 2))
        res_after = float(np.sum((after[0] + after[1] * (ta - t[k]) - 0.5 * g * (ta - t[k]) ** 2 - za) ** 2))
        rest = float(np.mean(za))                       # or the object stays down (a dead ball)
        res_rest = float(np.sum((za - rest) ** 2))
        # a rebound arc must fit better per degree of freedom and leave the floor faster than a
        # hop of 6 noise standard deviations (an arc's vertex can fit a bump of noise at rest)
        hop = float(np.sqrt(2.0 * g * 6.0 * noise))
        rises = after[1] - g * (ta[0] - t[k]) > hop
        if not (rises and len(ta) > 2 and res_after / (len(ta) - 2) < res_rest / (len(ta) - 1)):
            # the impact is where the arc before it comes down to the resting height
            a, b = before[0] - rest, before[1]
            disc = b * b + 2.0 * g * a
            if disc < 0:
                continue
            ti = (b + np.sqrt(disc)) / g
            if ti < tb[-1] - t[k] - 1e-9 or ti > t[split] - t[k] + 1e-9:
                continue
            cand = (res_before + res_rest, rest)
        else:
            # impact: where the arcs meet (the same -g t^2/2, so linear in t)
            if abs(after[1] - before[1]) < 1e-9:
                continue
            ti = (before[0] - after[0]) / (after[1] - before[1])
            if not (t[split - 1] - t[k] - 1e-9 <= ti <= t[split] - t[k] + 1e-9):
                continue
            cand = (res_before + res_after, before[0] + before[1] * ti - 0.5 * g * ti * ti)
        if best is None or cand[0] < best[0]:
            best = cand
    contact = float(z[k]) if best is None else min(best[1], float(z[k]))
    return contact - radius


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
                         default: DefaultObject | None = None, scale: float = 1.0, up: str = "z") -> list[Clip]:
    """Read one trajectory file into clips.

    Table files (CSV or Parquet, columns ``clip, object, t, x, y, z`` + optional ``qw..qz``
    and object columns) may hold many clips and objects. Two-dimensional files (header with
    ``t`` and two of ``x``, ``y``, y up; e.g. Tracker exports) hold one clip named after the
    file stem with one object ``sphere_0`` (shape from ``objects`` if given); they map to the
    world frame as x -> x, y -> z, with world y unobserved, shifted by ``Clip.z_offset`` so that
    the floor (unknown in these files) is at z = 0 under a bounce (:func:`bounce_floor`) or,
    without one, out of reach.

    Args:
        path: ``.csv``, ``.parquet``, ``.txt`` or ``.tsv`` file.
        objects: objects mapping (:func:`parse_objects`).
        default: size/mass assumed when neither the file nor ``objects`` gives them.
        scale: metres per unit of the file's coordinates (e.g. 0.001 for millimetres, the
            calibration of a table in pixels); applied before the checks.
        up: the file's vertical axis for 3-D tables: ``z`` (default) or ``y`` (a y-up export,
            right-handed: world x, y, z = file x, -z, y; orientations rotated likewise).
            Two-dimensional files are always y up.

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
    if not (scale > 0 and math.isfinite(scale)):
        raise DiscrepancyInputError(f"{path}: scale: must be a positive number of metres per unit, got {scale!r}")
    if up not in ("z", "y"):
        raise DiscrepancyInputError(f"{path}: up: must be z or y, got {up!r}")
    cols, two_d, first = _load_table(path)
    return _clips_from_columns(path, cols, two_d, first, objects or {}, default or DefaultObject(), scale, up)


def _clips_from_columns(path: Path, cols: Mapping[str, Any], two_d: bool, first: int,
                        objects: Mapping, default: DefaultObject, scale: float = 1.0, up: str = "z") -> list[Clip]:
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
        if up == "y":   # world (x, y, z) = file (x, -z, y)
            xyz = np.stack([xyz[:, 0], -xyz[:, 2], xyz[:, 1]], axis=1)
            file_col = {0: "x", 1: "z", 2: "y"}
    xyz = xyz * scale
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
                                   f"{xyz[big[0], a]:g} at row {rows[big[0]]} (pixels? give the metres per unit: --scale)")
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
        if up == "y":   # the file frame turned +90 deg about x into the world frame
            quat = quat_mul(np.array([math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0]), quat)
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
        if two_d:  # the file's vertical origin is arbitrary: the floor where the object bounces, else none
            floors = [bounce_floor(tr.t, tr.pos[:, 2], tr.spec.bounding_radius) for tr in tracks]
            floors = [f for f in floors if f is not None]
            if floors:
                z_offset = -min(floors)
            else:  # free flight: keep clear of z = 0
                lowest = min(float(np.min(tr.pos[:, 2]) - tr.spec.bounding_radius) for tr in tracks)
                z_offset = max(0.0, TWO_D_FLOOR_CLEARANCE - lowest)
        for tr in tracks:
            tr.t = tr.t - t0
            tr.pos[:, 2] += z_offset
        out.append(Clip(c, str(path), tracks, t0, z_offset))
    return out


def read_trajectories(paths: Sequence[str | Path] | str | Path, objects: Any = None,
                      default: DefaultObject | None = None, scale: float = 1.0, up: str = "z") -> list[Clip]:
    """Read trajectory files and/or directories (``*.parquet``, ``*.csv``, ``*.txt``,
    ``*.tsv``, sorted by name) into clips; see :func:`read_trajectory_file` (``scale``, ``up``).

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
        for clip in read_trajectory_file(f, objects, default, scale, up):
            if clip.name in seen:
                raise _err(f, "clip", f"clip id {clip.name!r} also in {seen[clip.name]}")
            seen[clip.name] = str(f)
            clips.append(clip)
    return clips


def clips_from_columns(cols: Mapping[str, Sequence], source: str = "<table>", objects: Any = None,
                       default: DefaultObject | None = None) -> list[Clip]:
    """Clips from in-memory table columns (same checks as :func:`read_trajectory_file`).

    Args:
        cols: ``{column: values}`` with :data:`TABLE_COLUMNS` (m, s, z up) and optionally
            :data:`QUAT_COLUMNS` and :data:`SPEC_COLUMNS` (e.g. :func:`generate_hidden`'s).
        source: name used for ``Clip.source`` and in messages.
        objects: objects mapping (:func:`parse_objects`). default: size/mass assumed.

    Raises:
        DiscrepancyInputError: as :func:`read_trajectory_file`, naming ``source``.
    """
    return _clips_from_columns(Path(source), {k: list(v) for k, v in cols.items()}, False, 0,
                               parse_objects(objects), default or DefaultObject())


def clips_from_infer_dir(path: str | Path, default: DefaultObject | None = None
                         ) -> tuple[list[Clip], dict[str, Any], float]:
    """Clips from a ``dynamics infer`` output folder (``scene.yaml`` + ``tracks.csv``,
    :mod:`pipeline.infer_tracks`): the observed tracks in the scene's world frame, objects
    (shape, size, mass) and static geometry (ramps, ``Clip.static``) from the scene, only the
    axes the camera sees face-on observed.

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
    static = [g.model_dump(mode="json") for g in scene.static]   # ramps: simulated in the fits
    for clip in clips:
        clip.static = static
        for tr in clip.tracks:
            tr.axes = axes.copy()
    video = {"folder": str(path), "camera_axes": "".join(a for a, on in zip("xyz", axes) if on),
             "resimulation_gap": infer_tracks.resimulation_gap(cols, axes)}
    return clips, video, float(scene.gravity)
