"""Streamed ``.npz`` archives: what ``np.savez_compressed`` writes, one chunk at a time.

An ``.npz`` file is a ZIP archive with one ``<name>.npy`` member per array (NumPy's ``.npy``
format: a header giving dtype and shape, then the raw C-order bytes). :class:`NpzWriter` writes
the same archive with :mod:`zipfile` (``ZIP_DEFLATED``, ``force_zip64=True``, as NumPy) and
:mod:`numpy.lib.format` (the header), but lets one array arrive in chunks along its first axis,
so a ``(T, H, W)`` mask video never has to be in memory whole. ``np.load`` reads it back exactly
as it reads ``np.savez_compressed``'s.

The archive is written to a temporary sibling of the target and renamed onto it only when
complete (:mod:`pipeline.atomic`); an exception inside ``with`` removes the temporary.

Example::

    with NpzWriter("out/masks.npz") as npz:
        with npz.stream("seg", (T, H, W), np.int8) as seg:
            for a in range(0, T, 32):
                seg.write(render(a, a + 32))            # (k, H, W) int8
        npz.write("names", np.asarray(names))
    np.load("out/masks.npz")["seg"]                     # (T, H, W) int8
"""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import IO, Sequence

import numpy as np
from numpy.lib import format as npy_format

from pipeline.atomic import AtomicWriter, replace_path, temp_file_for


class ArrayStream(AtomicWriter):
    """One ``.npy`` member of an :class:`NpzWriter` being written chunk by chunk along axis 0.

    Made by :meth:`NpzWriter.stream`; use it as a context manager. Leaving the ``with`` block
    normally checks that exactly ``shape[0]`` rows were written.
    """

    def __init__(self, member: IO[bytes], name: str, shape: tuple[int, ...], dtype: np.dtype) -> None:
        self._member = member
        self.name = name
        self.shape = shape
        self.dtype = dtype
        self.rows = 0
        """Rows (entries along axis 0) written so far."""

    def write(self, chunk: np.ndarray) -> None:
        """Append ``chunk (k, *shape[1:])`` of the stream's dtype (k may be 0).

        Raises:
            ValueError: wrong trailing shape or dtype, or more rows than ``shape[0]``.
        """
        chunk = np.asarray(chunk)
        if chunk.dtype != self.dtype or chunk.shape[1:] != self.shape[1:] or chunk.ndim != len(self.shape):
            raise ValueError(f"{self.name}: a chunk must be (k, {', '.join(map(str, self.shape[1:]))}) {self.dtype}, "
                             f"got {chunk.shape} {chunk.dtype}")
        if self.rows + chunk.shape[0] > self.shape[0]:
            raise ValueError(f"{self.name}: must have {self.shape[0]} rows, got {self.rows + chunk.shape[0]}")
        self._member.write(np.ascontiguousarray(chunk).reshape(-1).view(np.uint8).data)  # C-order bytes
        self.rows += chunk.shape[0]

    def close(self) -> None:
        """End the member.

        Raises:
            ValueError: fewer rows were written than ``shape[0]``.
        """
        self._member.close()
        if self.rows != self.shape[0]:
            raise ValueError(f"{self.name}: must have {self.shape[0]} rows, got {self.rows}")

    def abort(self) -> None:
        """End the member as it is (the archive is then dropped by :meth:`NpzWriter.abort`)."""
        self._member.close()


class NpzWriter(AtomicWriter):
    """Write an ``.npz`` archive as ``np.savez_compressed`` (or ``np.savez``) does, array by
    array, one of them possibly streamed in chunks (:meth:`stream`).

    Members are written one after the other (a ZIP archive takes one open member at a time):
    finish a stream before writing the next array.

    Args:
        path: target ``.npz`` file; its folder is created.
        compress: ``ZIP_DEFLATED`` (``np.savez_compressed``) or ``ZIP_STORED`` (``np.savez``).
    """

    def __init__(self, path: str | Path, compress: bool = True) -> None:
        self.path = Path(path)
        self._tmp = temp_file_for(self.path, suffix=".npz")
        self._zip = zipfile.ZipFile(self._tmp, mode="w", allowZip64=True,
                                    compression=zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED)
        self.names: list[str] = []
        """Arrays written so far, in order."""

    def _member(self, name: str) -> IO[bytes]:
        if name in self.names:
            raise ValueError(f"{self.path}: {name}: must be written once, got it twice")
        self.names.append(name)
        return self._zip.open(name + ".npy", mode="w", force_zip64=True)  # as numpy (gh-10776)

    def write(self, name: str, array: np.ndarray) -> None:
        """Write a whole array as member ``<name>.npy`` (any dtype but object)."""
        with self._member(name) as member:
            npy_format.write_array(member, np.asanyarray(array), allow_pickle=False)

    def stream(self, name: str, shape: Sequence[int], dtype: np.dtype | str) -> ArrayStream:
        """Start member ``<name>.npy`` of ``shape`` (C order) and ``dtype``, to be filled along
        axis 0 by :meth:`ArrayStream.write`.

        Raises:
            ValueError: an empty ``shape``, an object dtype, or a name already written.
        """
        shape, dtype = tuple(int(n) for n in shape), np.dtype(dtype)
        if not shape:
            raise ValueError(f"{name}: shape must have at least one axis, got ()")
        if dtype.hasobject:
            raise ValueError(f"{name}: dtype must not hold Python objects, got {dtype}")
        member = self._member(name)
        header = {"descr": npy_format.dtype_to_descr(dtype), "fortran_order": False, "shape": shape}
        try:
            npy_format.write_array_header_1_0(member, header)
        except ValueError:   # a header over 64 KiB
            npy_format.write_array_header_2_0(member, header)
        return ArrayStream(member, name, shape, dtype)

    def close(self) -> Path:
        """Finish the archive and rename it onto ``path``. Returns ``path``."""
        self._zip.close()
        replace_path(self._tmp, self.path)
        return self.path

    def abort(self) -> None:
        """Drop the archive; ``path`` stays as it was."""
        try:
            self._zip.close()
        except ValueError:   # a member still open for writing
            if self._zip.fp is not None:
                self._zip.fp.close()
        finally:
            self._tmp.unlink(missing_ok=True)
