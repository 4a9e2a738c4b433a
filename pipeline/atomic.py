"""Atomic file and folder writes: the one implementation every writer of the project uses.

A write goes to a temporary sibling of the target (same folder, so the same file system) and is
renamed onto the target only when it is complete, so a crash or an exception midway never
leaves a half-written file, and the temporary is removed on failure. Temporary names are
``.<name>.XXXX.tmp`` (``.<name>.XXXX<suffix>`` when the writer needs a suffix), and a replaced
folder waits as ``.<name>.old`` until the new one is in place; :func:`remove_stale_temps` clears
what a killed process left.

Example::

    write_json("reports/metrics.json", metrics)
    with atomic_path("out/rgb.mp4", suffix=".mp4") as tmp:   # writers that pick the format by name
        write_video(tmp)
    with atomic_dir("models/run") as tmp:                     # a folder, swapped whole
        model.save_pretrained(tmp)
    tmp = temp_dir_for("out"); write_all(tmp); publish_dir(tmp, "out")  # files into a user's folder
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import numpy as np


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def temp_file_for(path: str | Path, suffix: str = ".tmp") -> Path:
    """A new empty file ``.<name>.XXXX<suffix>`` beside ``path`` (its folder is created), with
    the permissions of a normal file (mkstemp makes 0600)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_umask())
    return Path(tmp)


def temp_dir_for(path: str | Path) -> Path:
    """A new empty folder ``.<name>.XXXX.tmp`` beside ``path`` (same file system, so it can be
    renamed onto ``path``), with the permissions of a normal folder (mkdtemp makes 0700)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    os.chmod(tmp, 0o777 & ~_umask())
    return tmp


def replace_path(tmp: str | Path, path: str | Path) -> None:
    """Move ``tmp`` onto ``path`` (file or directory); the old target is removed only after.

    A directory is swapped whole: a reader sees the old folder, the new one, or (killed between
    the two renames) none, never a mix; the old one waits as ``.<name>.old`` until it is removed
    (or until :func:`remove_stale_temps` at the next run)."""
    tmp, path = Path(tmp), Path(path)
    if path.is_dir() and not path.is_symlink():
        old = path.with_name(f".{path.name}.old")
        if old.exists():
            shutil.rmtree(old)
        os.replace(path, old)
        os.replace(tmp, path)
        shutil.rmtree(old)
    else:
        os.replace(tmp, path)


class AtomicWriter:
    """Base of the streaming writers whose target appears whole or not at all
    (``pipeline.viz.Mp4Writer``, ``pipeline.npz.NpzWriter``, ``pipeline.shards.ArrayShardWriter``):
    ``with`` calls :meth:`close` (finish, rename onto the target) when its block completes and
    :meth:`abort` (remove the temporary) when it raises."""

    def close(self) -> Any:
        raise NotImplementedError

    def abort(self) -> None:
        raise NotImplementedError

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def publish_dir(tmp: str | Path, path: str | Path) -> list[Path]:
    """Publish the finished folder ``tmp`` (made by :func:`temp_dir_for`) at ``path`` without
    touching anything else there.

    If ``path`` does not exist, ``tmp`` is renamed onto it (one step: a reader sees no folder or
    the whole one). If it exists, each entry of ``tmp`` is moved into it by rename, replacing an
    entry of the same name (a file by a file, a folder swapped whole, :func:`replace_path`), and
    ``tmp`` is removed; the folder and its other entries are kept (a user's ``--out`` folder is
    never deleted). Killed between two moves, ``path`` holds some new entries beside old ones.

    Returns:
        the published paths inside ``path``.
    Raises:
        FileExistsError: ``path`` exists and is not a folder, or an entry of ``tmp`` that is a
            file would replace a folder in ``path`` (checked before anything is moved).
    """
    tmp, path = Path(tmp), Path(path)
    names = sorted(p.name for p in tmp.iterdir())
    if not path.exists() and not path.is_symlink():
        try:
            os.rename(tmp, path)
            return [path / name for name in names]
        except OSError:          # made meanwhile by someone else: merge into it
            pass
    if not path.is_dir():
        raise FileExistsError(f"{path}: must be a folder (or not exist yet), got a file")
    for name in names:
        if (path / name).is_dir() and not (tmp / name).is_dir():
            raise FileExistsError(f"{path / name}: must be a file (or not exist yet), got a folder")
    for name in names:
        replace_path(tmp / name, path / name)
    shutil.rmtree(tmp, ignore_errors=True)
    return [path / name for name in names]


@contextmanager
def atomic_path(path: str | Path, suffix: str = ".tmp") -> Iterator[Path]:
    """Yield a temporary sibling of ``path`` (ending in ``suffix``, e.g. ``.mp4`` for writers that
    pick the format from the name); it is renamed onto ``path`` only if the block completes,
    and removed if it raises."""
    path = Path(path)
    tmp = temp_file_for(path, suffix)
    try:
        yield tmp
        replace_path(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


@contextmanager
def atomic_dir(path: str | Path) -> Iterator[Path]:
    """Yield a new empty temporary folder beside ``path``; it replaces ``path`` (a folder is
    swapped whole, :func:`replace_path`) only if the block completes, and is removed if it
    raises."""
    tmp = temp_dir_for(path)
    try:
        yield tmp
        replace_path(tmp, path)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Atomically write ``data`` to ``path`` (its folder is created). Returns ``path``."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return path


def write_text(path: str | Path, text: str) -> Path:
    """Atomically write ``text`` (UTF-8) to ``path``. Returns ``path``."""
    return write_bytes(path, text.encode())


def json_default(o: Any) -> Any:
    """``json.dumps(default=...)`` for numpy scalars and arrays and paths.

    Raises:
        TypeError: anything else that JSON cannot hold.
    """
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_json(path: str | Path, obj: Any, indent: int = 2) -> Path:
    """Atomically write ``obj`` as indented JSON plus a newline (numpy scalars/arrays
    converted, :func:`json_default`). Returns ``path``."""
    return write_text(path, json.dumps(obj, indent=indent, default=json_default) + "\n")


def remove_stale_temps(path: str | Path) -> list[Path]:
    """Remove what an interrupted atomic write of ``path`` left beside it: the temporary siblings
    ``.<name>.*.tmp`` (and ``.tmp-*``) and ``.<name>.old`` (see :func:`replace_path`).

    Returns:
        the removed paths.
    """
    path = Path(path)
    if not path.parent.is_dir():
        return []
    stale = sorted({*path.parent.glob(f".{path.name}.*.tmp"), *path.parent.glob(f".{path.name}.*tmp-*"),
                    *path.parent.glob(f".{path.name}.old")})
    for p in stale:
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
    return stale
