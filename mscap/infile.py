"""Files mscap reads that a user names: regular files only, read with a size cap (issue 48).

A FIFO blocks an ``open`` until a writer comes and a device (``/dev/zero``) never ends, so
a scene file is opened without blocking and read through its descriptor up to a limit
(:func:`read_regular`), and a results file is refused before HDF5 opens it unless it is a
regular file (:func:`check_regular`). An HDF5 dataset is judged by its declared type and
shape before a byte of it is read (:func:`dataset_problem`): a 244 kB gzip file can declare
6 GB.
"""

from __future__ import annotations

import os
import stat

__all__ = ["file_kind", "check_regular", "read_regular", "MAX_DATASET_BYTES", "dataset_problem", "one_line"]

#: The most an honest HDF5 dataset of mscap's declares (shape × item size). The largest is a
#: run's outlines: 100 plates of 1,300 vertices (a 100 mm perimeter at 0.075 mm) are 2 MB,
#: 30 times under it; a calibration cache's family table (10,000 poses × 100 plates) 8 MB.
MAX_DATASET_BYTES = 64 * 2**20

_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def read_regular(path, limit: int, what: str) -> bytes:
    """The bytes of ``path`` if it is a regular file of at most ``limit`` bytes; else a
    ``ValueError`` saying what it is instead (``what``: what it should have been). Opened
    without blocking, so a FIFO with no writer is refused, not waited on; read through the
    open descriptor, so a file swapped for another meanwhile is not read."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise ValueError(f"is {file_kind(info.st_mode)}, not {what}")
        if info.st_size > limit:
            raise ValueError(f"{info.st_size} bytes is not {what}; at most {limit} bytes are read")
        chunks, total = [], 0
        while True:
            chunk = os.read(fd, min(1 << 20, limit + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
            if total > limit:  # it grew while read
                raise ValueError(f"more than {limit} bytes is not {what}")
        return b"".join(chunks)
    finally:
        os.close(fd)


def file_kind(mode: int) -> str:
    """What a ``st_mode`` is, in words: "a FIFO", "a directory", ..."""
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def check_regular(path, what: str, limit: int | None = None) -> None:
    """A ``ValueError`` unless ``path`` (links followed) is a regular file, of at most
    ``limit`` bytes when given; ``OSError`` when it cannot be looked at. A ``stat`` never
    blocks, even on a FIFO."""
    info = os.stat(path)
    if not stat.S_ISREG(info.st_mode):
        raise ValueError(f"is {file_kind(info.st_mode)}, not {what}")
    if limit is not None and info.st_size > limit:
        raise ValueError(f"is {info.st_size} bytes; {what} mscap writes is at most {limit // 2**20} MiB")


def one_line(exc: BaseException) -> str:
    """An h5py/HDF5 error as one line (HDF5's messages span several)."""
    return " ".join(str(exc).split()) or type(exc).__name__


def dataset_problem(obj, name: str, kind: str, ndim: int | None) -> str | None:
    """What is wrong with ``obj`` as dataset ``name`` of dtype ``kind`` (numpy kinds,
    ``"str"``: strings) and ``ndim`` dimensions, from its declared type and shape only;
    ``None`` if nothing."""
    import h5py
    import numpy as np

    if obj is None:
        return f"no dataset {name!r}"
    if not isinstance(obj, h5py.Dataset):
        return f"{name!r} is a {type(obj).__name__.lower()}, not a dataset"
    if ndim is not None and obj.ndim != ndim:
        return f"dataset {name!r} has {obj.ndim} dimensions {obj.shape}, not {ndim}"
    if kind == "str":
        if h5py.check_string_dtype(obj.dtype) is None:
            return f"dataset {name!r} holds {obj.dtype}, not strings"
    elif obj.dtype.kind not in kind:
        names = {"iu": "integers", "b": "booleans"}
        return f"dataset {name!r} holds {obj.dtype}, not {names.get(kind, 'numbers')}"
    size = int(np.prod(obj.shape, dtype=np.float64)) * max(obj.dtype.itemsize, 8 if kind == "str" else 1)
    if size > MAX_DATASET_BYTES:
        return f"dataset {name!r} declares {obj.shape} ({size / 2**20:.0f} MB); at most {MAX_DATASET_BYTES // 2**20} MB"
    return None
