"""A results file opened for writing: which paths may be written, one writer at a time,
and room on the disk before each write (docs/hdf5.md, "Writing safely").

- **Paths** (:func:`check_output_path`): ``mscap run -o`` and ``mscap merge -o`` never
  write through a symbolic link (a dangling one would create its target, ``--force`` would
  overwrite it): a link is refused with its target named, so the user can give that path.
  Missing directories are created.
- **One writer** (:class:`WriteLock`): the file is opened without truncation and locked
  (``flock``, the lock HDF5 itself takes, so HDF5 tools see it too) *before* anything
  decides what to do with its content; a file another process holds is refused, ``--force``
  included, and left untouched.
- **Room first** (:func:`reserve`): HDF5 is not journalled, and a write that fails half
  way (a full disk, ``ulimit -f``, a quota) leaves groups whose headers point past the
  end of the file. So before each run the writer allocates the run's estimated size past
  HDF5's end of file (``posix_fallocate``); if the file system refuses, nothing of the HDF5
  structure was touched and the job stops with the path and the free space.
- **The file** (:class:`ResultsFile`): an ``h5py.File`` that holds its lock, makes room
  before each write and makes each write durable; the multi-start's results file and the
  calibration's cache are both one.
"""

from __future__ import annotations

import errno
import fcntl
import logging
import os
import resource
import shutil
from pathlib import Path

import h5py

from mscap.errors import StoreError, StoreFullError
from mscap.outputs import output_directory, special_kind

__all__ = ["check_output_path", "WriteLock", "ResultsFile", "reserve", "room_text"]

log = logging.getLogger(__name__)

#: Errors of ``flock`` that mean "this file system cannot lock", not "someone holds it".
_NO_LOCKING = {errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL}


def check_output_path(path) -> Path:
    """``path`` as a file mscap may create or overwrite: not a symbolic link (dangling or
    not), a directory, a FIFO, a device or a socket; its missing parent directories are
    created.

    Raises
    ------
    StoreError
        A link or a directory.
    MscapError
        A parent that cannot be created or written (:func:`mscap.outputs.output_directory`).
    """
    path = Path(path)
    if path.is_symlink():
        raise StoreError(f"{path} is a symbolic link (to {os.readlink(path)}); mscap does not write results "
                         "through a link: give the path of the file itself")
    if path.is_dir():
        raise StoreError(f"{path} is a directory; give a file name, e.g. {path / 'results.h5'}")
    special = special_kind(path)
    if special:  # HDF5 would fail on it and the clean-up would then delete it
        raise StoreError(f"{path} is {special}, not a file mscap writes; give the path of a regular file or "
                         "of a new one")
    output_directory(path.parent, f"{path}: its directory")
    return path


class WriteLock:
    """An exclusive lock on the results file ``path`` itself, taken before anything about
    its content is decided and held until :meth:`close`.

    ``created`` says whether this call created the (empty) file; ``empty`` whether the
    file holds nothing (new, or left empty by a writer that failed at its start).

    Raises
    ------
    StoreError
        Another process holds the file (``force`` only changes the wording: it never
        overrides a lock), or the file system cannot lock (then
        ``HDF5_USE_FILE_LOCKING=FALSE`` lets the writer go on unlocked).
    """

    def __init__(self, path, force: bool = False):
        self.path = Path(path)
        for _ in range(3):  # the inode changed under us (a writer that failed removed it): again
            self.fd, self.created = _open_no_follow(self.path)
            if self._lock(force) and self._same_inode():
                break
            os.close(self.fd)
        else:
            raise StoreError(f"{self.path}: the file was replaced while it was being opened; try again")
        self.empty = os.fstat(self.fd).st_size == 0

    def _lock(self, force: bool) -> bool:
        try:
            fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(self.fd)
            raise StoreError(f"{self.path} is open for writing in another process (another mscap run?); it was "
                             "left untouched" + ("; --force never overrides that" if force else "")) from None
        except OSError as exc:
            if exc.errno not in _NO_LOCKING:
                raise
            if os.environ.get("HDF5_USE_FILE_LOCKING", "").upper() != "FALSE":
                self._discard()
                raise StoreError(f"{self.path}: file locking failed ({exc.strerror}); on file systems without "
                                 "locking set HDF5_USE_FILE_LOCKING=FALSE (and run one job per file)") from None
            log.warning("%s: no file locking here (%s); nothing keeps a second job off the file", self.path,
                        exc.strerror)
        return True

    def _same_inode(self) -> bool:
        try:
            return os.stat(self.path, follow_symlinks=False).st_ino == os.fstat(self.fd).st_ino
        except FileNotFoundError:
            return False

    def _discard(self) -> None:
        os.close(self.fd)
        if self.created:
            self.path.unlink(missing_ok=True)

    def sync(self) -> None:
        """Make every write to the file durable (``fsync``)."""
        os.fsync(self.fd)

    def remove(self) -> None:
        """Delete the file (still locked, so no one reopened it in between) and unlock."""
        self.path.unlink(missing_ok=True)
        self.close()

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1


def _open_no_follow(path: Path) -> tuple[int, bool]:
    """An fd of ``path`` opened for writing without truncating it, never through a link;
    and whether it was created here."""
    flags = os.O_RDWR | os.O_NOFOLLOW | os.O_CLOEXEC
    try:
        return os.open(path, flags | os.O_CREAT | os.O_EXCL, 0o666), True
    except FileExistsError:
        pass
    try:
        return os.open(path, flags), False
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise StoreError(f"{path} is a symbolic link; mscap does not write results through a link") from None
        raise StoreError(f"{path}: cannot open for writing ({exc.strerror})") from None


def reserve(lock: WriteLock, end: int, nbytes: int) -> None:
    """Allocate bytes ``end .. end + nbytes`` of the file (``end``: HDF5's end of the file,
    where its next allocations go), so that the writes that follow cannot run out of room.

    Raises
    ------
    StoreFullError
        The file system or the process's file-size limit refuses, with the free space.
    """
    try:
        os.posix_fallocate(lock.fd, end, nbytes)
    except OSError as exc:
        if exc.errno in (errno.EOPNOTSUPP, errno.EINVAL, errno.ENODEV):
            _zero_fill(lock, end, nbytes)  # no fallocate here: write zeros past the data
            return
        raise StoreFullError(f"{lock.path}: no room to write ({exc.strerror}): needs about "
                             f"{_kib(nbytes)} more; {room_text(lock.path)}") from None


def _zero_fill(lock: WriteLock, end: int, nbytes: int) -> None:
    fd = lock.fd
    size = os.fstat(fd).st_size
    start = max(size, end)
    try:
        if end + nbytes > start:
            os.pwrite(fd, bytes(end + nbytes - start), start)
    except OSError as exc:
        os.ftruncate(fd, size)
        raise StoreFullError(f"{lock.path}: no room to write ({exc.strerror}): needs about {_kib(nbytes)} more; "
                             f"{room_text(lock.path)}") from None


def _kib(nbytes: float) -> str:
    return f"{nbytes / 1024:.0f} KiB"


def room_text(path) -> str:
    """The free space of ``path``'s file system and the process's file-size limit, in words."""
    path = Path(path)
    try:
        free = f"{_kib(shutil.disk_usage(path.parent if path.parent.exists() else '.').free)} free on its file system"
    except OSError:
        free = "free space unknown"
    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    if limit != resource.RLIM_INFINITY:
        free += f", the file-size limit (ulimit -f) is {_kib(limit)}"
    return free


class ResultsFile(h5py.File):
    """A results file open for writing: an ``h5py.File`` that holds the file's
    :class:`WriteLock` (released by ``close``), makes room before
    each write (:meth:`make_room`) and makes each write durable (:meth:`commit`)."""

    def __init__(self, lock: WriteLock, mode: str):
        # Default libver (no "latest"): files not closed cleanly carry no open-for-write
        # flag and reopen without h5clear. HDF5's own locking stays off: ``lock`` holds the
        # same flock on the file for the whole session.
        super().__init__(lock.path, mode, locking=False)
        self.lock = lock
        self.failed = False  # a write failed: closing must not raise over that error

    def make_room(self, nbytes: int) -> None:
        """Allocate ``nbytes`` past HDF5's end of file, or raise
        :class:`~mscap.errors.StoreFullError` with nothing written."""
        reserve(self.lock, int(self.id.get_filesize()), int(nbytes))

    def commit(self) -> None:
        """Flush HDF5's buffers and ``fsync``: what was written survives a crash."""
        self.flush()
        self.lock.sync()

    def close(self) -> None:
        try:
            if self.id.valid:
                super().close()
        except (OSError, RuntimeError):
            if not self.failed:
                raise
        finally:
            self.lock.close()

    def discard(self) -> None:
        """Close and delete the file (a new file whose writing failed)."""
        try:
            super().close()
        except Exception:  # the file goes anyway
            pass
        self.lock.remove()
