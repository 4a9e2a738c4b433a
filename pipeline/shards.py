"""On-disk layout and atomic Parquet/Zarr/JSON IO (docs/design.md §4).

Every stage writes ``<out_dir>/shard-00000.parquet`` (tables) or ``<out_dir>/shard-00000.zarr``
(arrays) plus a ``meta.json`` describing what it holds. Output directories come from
``params.yaml`` (section ``paths``), never from code. Every write goes to a temporary path
next to the target and is renamed into place when complete, so a crash never leaves a
half-written shard behind.

Example::

    write_table(shard_path(out, 0, "parquet"), rows, metadata={"params": p})
    table = read_table(out)                       # all shards, in order
    for path, group in iter_array_shards(video):  # zarr groups, read-only
        rgb = group["rgb"][0]                     # (T, H, W, 3) uint8
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping, Sequence

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

# atomic writes: pipeline.atomic is the one implementation; its writers stay importable from here
from pipeline.atomic import (AtomicWriter, atomic_dir, atomic_path, json_default, remove_stale_temps,  # noqa: F401
                             replace_path, temp_dir_for, write_bytes, write_json, write_text)
from pipeline.errors import UserError

SHARD_TEMPLATE = "shard-{index:05d}.{ext}"
"""File name of shard ``index``; ``ext`` is ``parquet`` or ``zarr``."""
META_FILE = "meta.json"
SCENE_ID_TEMPLATE = "scene-{index:06d}"


class ShardError(UserError, RuntimeError):
    """A shard is missing, unreadable or inconsistent. ``str(err)`` is one line naming the path."""


def scene_id(index: int) -> str:
    """Scene key used in every table and array shard, e.g. ``scene-000042``."""
    return SCENE_ID_TEMPLATE.format(index=index)


def shard_path(out_dir: str | Path, index: int, ext: str, prefix: str = "shard") -> Path:
    """Path of shard ``index`` in ``out_dir`` (``<prefix>-00000.<ext>``)."""
    name = SHARD_TEMPLATE.format(index=index, ext=ext)
    if prefix != "shard":
        name = prefix + name[len("shard"):]
    return Path(out_dir) / name


def list_shards(path: str | Path, ext: str, prefix: str = "shard") -> list[Path]:
    """Sorted shards of a stage directory, or ``[path]`` if ``path`` is itself a shard.

    Raises:
        ShardError: the path does not exist, holds no shard of that kind, has no ``meta.json``
            (the stage was interrupted) or fewer/more shards than its ``meta.json`` lists.
    """
    path = Path(path)
    if path.suffix == f".{ext}":
        if not path.exists():
            raise ShardError(f"{path}: missing shard")
        return [path]
    if not path.is_dir():
        raise ShardError(f"{path}: missing stage output (run `dvc repro` first)")
    shards = sorted(path.glob(f"{prefix}-*.{ext}"))
    if not shards:
        raise ShardError(f"{path}: no {prefix}-*.{ext} shards")
    if not (path / META_FILE).exists():
        # a stage writes meta.json last: without it the stage was interrupted (killed) and the
        # shards here may be a part of its output
        raise ShardError(f"{path / META_FILE}: missing: the stage that writes {path} did not finish "
                         f"({len(shards)} {prefix} shards found); rerun `dvc repro`")
    meta = read_meta(path, required=False)
    expected = meta.get("shards", {}).get(prefix) if meta else None
    if expected is not None and len(shards) != int(expected):
        raise ShardError(f"{path}: meta.json lists {expected} {prefix} shards, found {len(shards)}")
    return shards


def chunked(n: int, size: int) -> list[range]:
    """Split ``range(n)`` into consecutive ranges of at most ``size`` (shard boundaries)."""
    if size <= 0:
        raise ValueError(f"shard_size must be > 0, got {size}")
    return [range(i, min(n, i + size)) for i in range(0, n, size)]


def write_table(
    path: str | Path,
    rows: pa.Table | Sequence[Mapping[str, Any]],
    metadata: Mapping[str, Any] | None = None,
    schema: pa.Schema | None = None,
) -> Path:
    """Atomically write one Parquet shard.

    Args:
        path: target ``.parquet`` file.
        rows: a ``pyarrow.Table`` or a list of row dicts (same keys in every row).
        metadata: JSON-serialisable dict stored in the Parquet key-value metadata under
            ``dynamics`` (params, seed, units).
        schema: optional explicit schema for row dicts (needed when a column is all-null).
    """
    path = Path(path)
    table = rows if isinstance(rows, pa.Table) else pa.Table.from_pylist(list(rows), schema=schema)
    if metadata is not None:
        meta = dict(table.schema.metadata or {})
        meta[b"dynamics"] = json.dumps(metadata, default=json_default).encode()
        table = table.replace_schema_metadata(meta)
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp)
    return path


def read_table(path: str | Path, prefix: str = "shard", columns: list[str] | None = None) -> pa.Table:
    """Read one Parquet shard or all shards of a stage directory (concatenated in order).

    Raises:
        ShardError: missing or unreadable shard (one line naming the file).
    """
    tables = []
    for shard in list_shards(path, "parquet", prefix):
        try:
            tables.append(pq.read_table(shard, columns=columns))
        except Exception as exc:  # pyarrow raises several types for corrupt files
            raise ShardError(f"{shard}: unreadable Parquet shard: {str(exc).splitlines()[0]}") from None
    return pa.concat_tables(tables) if len(tables) > 1 else tables[0]


def table_metadata(path: str | Path) -> dict:
    """The ``dynamics`` metadata dict of a Parquet shard (``{}`` if none)."""
    meta = pq.read_schema(path).metadata or {}
    raw = meta.get(b"dynamics")
    return json.loads(raw) if raw else {}


class ArrayShardWriter(AtomicWriter):
    """Write a Zarr shard (a directory store, zarr 3 API) scene by scene, so a shard never has
    to be in memory whole.

    The group is made in a temporary folder beside ``path`` (:func:`pipeline.atomic.temp_dir_for`);
    :meth:`close` writes ``scene_id`` and the attributes and renames it onto ``path`` (a folder
    there is swapped whole); :meth:`abort`, or an exception inside ``with``, removes it, so
    ``path`` is the whole shard or untouched. Arrays have the scene axis first and are chunked
    one scene per chunk.

    Example::

        with ArrayShardWriter(shard_path(out, 0, "zarr"), attrs={"fps": 30}) as shard:
            for sid, frames in scenes:
                shard.append({"rgb": frames.rgb, "seg": frames.seg}, scene_id=sid)   # one scene each

    Args:
        path: target ``.zarr`` directory.
        attrs: JSON-serialisable group attributes (units, params, seed); more may be added to
            :attr:`attrs` before :meth:`close`.
    """

    def __init__(self, path: str | Path, attrs: Mapping[str, Any] | None = None) -> None:
        import zarr

        self.path = Path(path)
        self.attrs: dict[str, Any] = dict(attrs or {})
        self.scene_ids: list[str] | None = None
        """Scene keys stored as the array ``scene_id`` by :meth:`close` (None: no such array)."""
        self._tmp = temp_dir_for(self.path)
        self._group = zarr.open_group(str(self._tmp), mode="w")
        self._arrays: dict[str, Any] = {}

    def write(self, name: str, array: np.ndarray) -> None:
        """Write a whole array ``(N, ...)`` (scene axis first; a 0-d or empty one is one chunk).

        Raises:
            ValueError: ``name`` was written or appended already.
        """
        if name in self._arrays:
            raise ValueError(f"{self.path}: {name}: must be written once, got it twice")
        array = np.asarray(array)
        chunks = (1,) + array.shape[1:] if array.ndim >= 1 and array.shape[0] > 0 else array.shape
        z = self._group.create_array(name, shape=array.shape, dtype=array.dtype, chunks=chunks)
        z[...] = array
        self._arrays[name] = z

    def append(self, scene: Mapping[str, np.ndarray], scene_id: str | None = None) -> None:
        """Append one scene: ``scene[name]`` is that scene's array without the scene axis (e.g.
        ``rgb (T, H, W, 3) uint8``), stored at index ``N`` of array ``name (N + 1, ...)``; the
        first scene fixes each array's shape and dtype.

        Args:
            scene: name -> array of this scene (the same names for every scene).
            scene_id: this scene's key (appended to :attr:`scene_ids`).
        Raises:
            ValueError: a name, shape or dtype differs from the first scene's.
        """
        scene = {name: np.asarray(a) for name, a in scene.items()}
        if self._arrays and set(scene) != set(self._arrays):
            raise ValueError(f"{self.path}: scene {scene_id}: arrays must be {sorted(self._arrays)}, "
                             f"got {sorted(scene)}")
        for name, a in scene.items():
            z = self._arrays.get(name)
            if z is None:
                z = self._arrays[name] = self._group.create_array(name, shape=(0, *a.shape), dtype=a.dtype,
                                                                  chunks=(1, *a.shape))
            elif a.shape != z.shape[1:] or a.dtype != z.dtype:
                raise ValueError(f"{self.path}: scene {scene_id}: {name} must be {z.shape[1:]} {z.dtype} like the "
                                 f"first scene's, got {a.shape} {a.dtype}")
            z.append(a[None], axis=0)
        if scene_id is not None:
            self.scene_ids = [*(self.scene_ids or []), str(scene_id)]

    def close(self) -> Path:
        """Write ``scene_id`` and the attributes and rename the shard onto ``path``. Returns ``path``."""
        try:
            if self.scene_ids is not None:
                ids = np.asarray(list(self.scene_ids), dtype=object)
                z = self._group.create_array("scene_id", shape=ids.shape, dtype=str)  # variable-length UTF-8 (zarr v3 spec)
                z[...] = ids
            self._group.attrs.update(json.loads(json.dumps(self.attrs, default=json_default)))
            replace_path(self._tmp, self.path)
        except BaseException:
            self.abort()
            raise
        return self.path

    def abort(self) -> None:
        """Remove the temporary shard; ``path`` stays as it was."""
        shutil.rmtree(self._tmp, ignore_errors=True)


def write_arrays(
    path: str | Path,
    arrays: Mapping[str, np.ndarray],
    attrs: Mapping[str, Any] | None = None,
    scene_ids: Sequence[str] | None = None,
) -> Path:
    """Atomically write a Zarr shard (a directory store) from whole arrays in memory
    (:class:`ArrayShardWriter`; to write scene by scene, use it directly).

    Args:
        path: target ``.zarr`` directory.
        arrays: name -> array with the scene axis first, e.g. ``rgb (N, T, H, W, 3) uint8``;
            chunked one scene per chunk.
        attrs: JSON-serialisable group attributes (units, params, seed).
        scene_ids: ``N`` scene keys, stored as the array ``scene_id``.
    """
    with ArrayShardWriter(path, attrs) as shard:
        for name, arr in arrays.items():
            shard.write(name, arr)
        if scene_ids is not None:
            shard.scene_ids = list(scene_ids)
    return Path(path)


def open_arrays(path: str | Path):
    """Open a Zarr shard read-only (``zarr.Group``).

    Raises:
        ShardError: missing or unreadable shard.
    """
    import zarr

    path = Path(path)
    if not path.exists():
        raise ShardError(f"{path}: missing shard")
    try:
        return zarr.open_group(str(path), mode="r")
    except Exception as exc:
        raise ShardError(f"{path}: unreadable Zarr shard: {str(exc).splitlines()[0]}") from None


def iter_array_shards(path: str | Path, prefix: str = "shard") -> Iterator[tuple[Path, Any]]:
    """Yield ``(shard_path, zarr.Group)`` for every Zarr shard of a stage directory."""
    for shard in list_shards(path, "zarr", prefix):
        yield shard, open_arrays(shard)


def scene_ids_of(group: Any) -> list[str]:
    """The ``scene_id`` array of a Zarr shard as a list of str."""
    return [str(s) for s in np.asarray(group["scene_id"][...])]


def find_scene(path: str | Path, sid: str, prefix: str = "shard") -> tuple[Any, int]:
    """Locate scene ``sid`` in a Zarr stage directory: ``(group, index within the shard)``.

    Raises:
        ShardError: no shard holds that scene.
    """
    for _, group in iter_array_shards(path, prefix):
        ids = scene_ids_of(group)
        if sid in ids:
            return group, ids.index(sid)
    raise ShardError(f"{path}: no scene {sid!r}")


def write_meta(out_dir: str | Path, meta: Mapping[str, Any]) -> Path:
    """Write ``<out_dir>/meta.json`` (features, shapes, units, params, shard counts)."""
    return write_json(Path(out_dir) / META_FILE, dict(meta))


def read_meta(out_dir: str | Path, required: bool = True) -> dict:
    """Read ``<out_dir>/meta.json``.

    Raises:
        ShardError: ``required`` and the file is missing or not valid JSON.
    """
    path = Path(out_dir) / META_FILE
    if not path.exists():
        if required:
            raise ShardError(f"{path}: missing")
        return {}
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ShardError(f"{path}: invalid JSON: {exc.msg}") from None


def reset_dir(out_dir: str | Path) -> Path:
    """Create ``out_dir`` empty (stages own their whole output directory), removing temporary
    leftovers of an interrupted earlier run beside it (:func:`remove_stale_temps`)."""
    out_dir = Path(out_dir)
    remove_stale_temps(out_dir)
    if out_dir.exists():
        shutil.rmtree(out_dir)
    out_dir.mkdir(parents=True)
    return out_dir


def rows_by_scene(table: pa.Table) -> dict[str, dict]:
    """Index a one-row-per-scene table by ``scene_id``."""
    return {r["scene_id"]: r for r in table.to_pylist()}


def concat_rows(tables: Iterable[pa.Table]) -> pa.Table:
    """Concatenate tables with the same schema."""
    return pa.concat_tables(list(tables))
