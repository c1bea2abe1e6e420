"""Where the commands write: output directories and the files in them.

Three rules, each a one-line :class:`~mscap.errors.MscapError` when it cannot hold:

- the directory a user names (``-o DIR``, ``--export DIR``) is created with its parents;
  an existing file there, or a path that cannot be a directory, is refused before any
  work is done (:func:`output_directory`);
- a file mscap names inside it (``mesh.vtu``, ``<pose>.vtu``) is written to a temporary
  file beside it and renamed over it (:func:`replace_file`): a symbolic link of that name
  is replaced, never followed, so a link planted in the directory cannot make mscap
  overwrite the file it points to, and a failed write leaves the old file whole;
- names taken from a scene (pose names) pass :func:`file_stem` first: no separators, no
  leading dot, at most :data:`MAX_STEM` characters.

Also :func:`split_design_spec`: the ``FILE.h5[:RUN]`` by which the commands name a stored
design, and from which ``mscap calibrate`` names its outputs; and :func:`printable`, which
every line the commands print passes through (:class:`EscapedStream`): a name read from a
file that holds ``\x1b[2J`` is shown as those characters, not executed by the terminal.
"""

from __future__ import annotations

import csv
import hashlib
import os
import re
import secrets
from pathlib import Path
from typing import Callable, Iterable, Sequence

from mscap.errors import MscapError

__all__ = ["printable", "EscapedStream", "output_directory", "replace_file", "special_kind", "replace_text",
           "replace_csv", "file_stem", "file_stems", "MAX_STEM", "split_design_spec"]

#: Longest file stem made from a name (file systems allow 255 bytes per component, and a
#: suffix such as ``_elastic.vtu`` and the temporary file's prefix must fit beside it).
MAX_STEM = 100


def output_directory(path: str | Path, option: str) -> Path:
    """``path`` as a directory, created with its parents; ``option`` (e.g. ``"mesh -o"``)
    names the command-line option in the error."""
    out = Path(path)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise MscapError(f"{option} {path}: exists and is not a directory") from None
    except OSError as exc:
        raise MscapError(f"{option} {path}: cannot create the directory ({exc.strerror})") from None
    if not out.is_dir():
        raise MscapError(f"{option} {path}: exists and is not a directory")
    if not os.access(out, os.W_OK | os.X_OK):
        raise MscapError(f"{option} {path}: the directory is not writable")
    return out


def special_kind(path: Path) -> str:
    """What ``path`` itself (a link not followed) is when it is neither missing, a regular
    file, a directory nor a link: "a FIFO", "a socket", ...; else ``""``."""
    import stat

    from mscap.infile import file_kind

    try:
        mode = os.lstat(path).st_mode
    except OSError:
        return ""
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode) or stat.S_ISLNK(mode):
        return ""
    return file_kind(mode)


def replace_file(path: str | Path, write: Callable[[Path], object]) -> Path:
    """Call ``write(temporary)`` on a new file beside ``path`` (same suffix, so writers
    that pick a format by it still do), then rename it to ``path``: a link named ``path``
    is replaced, not followed. Returns ``path``."""
    path = Path(path)
    if path.is_dir() and not path.is_symlink():
        raise MscapError(f"{path}: is a directory, cannot write a file there")
    special = special_kind(path)
    if special:  # a FIFO or a device someone made there is theirs, not an output to replace
        raise MscapError(f"{path}: is {special}; give the path of a regular file or of a new one")
    temporary = path.parent / f".mscap-{os.getpid()}-{secrets.token_hex(4)}{path.suffix}"
    try:  # O_EXCL: a new file (never a link's target), with the umask's permissions
        os.close(os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
    except OSError as exc:
        raise MscapError(f"{path}: cannot write ({exc.strerror})") from None
    try:
        write(Path(temporary))
        os.replace(temporary, path)
    except OSError as exc:
        raise MscapError(f"{path}: cannot write ({exc.strerror or exc})") from None
    finally:
        if os.path.lexists(temporary):
            os.unlink(temporary)
    return path


def replace_text(path: str | Path, text: str) -> Path:
    """:func:`replace_file` with ``text`` as the content."""
    return replace_file(path, lambda temporary: temporary.write_text(text))


def replace_csv(path: str | Path, rows: Iterable[Sequence]) -> Path:
    """:func:`replace_file` with ``rows`` (the header first) as CSV."""
    def write(temporary: Path) -> None:
        with open(temporary, "w", newline="") as f:
            csv.writer(f).writerows(rows)

    return replace_file(path, write)


def file_stem(name: str) -> str:
    """``name`` as a file stem: every character but letters, digits, ``_``, ``-``, ``+``
    and ``.`` becomes ``_``, leading dots go, and a name longer than :data:`MAX_STEM`
    keeps its start and gains 8 hex digits of its hash (so long names stay apart)."""
    stem = re.sub(r"[^\w.+-]", "_", name).lstrip(".") or "_"
    if len(stem) > MAX_STEM:
        stem = stem[:MAX_STEM - 9] + "_" + hashlib.sha256(name.encode()).hexdigest()[:8]
    return stem


def file_stems(names: list[str]) -> list[str]:
    """:func:`file_stem` of each name, made unique (``a/b`` and ``a_b`` would both be
    ``a_b``: the later one gets ``_2``, ...) without regard to case (``A`` and ``a`` are
    one file on some file systems)."""
    stems, seen = [], set()
    for name in names:
        stem = candidate = file_stem(name)
        n = 1
        while candidate.lower() in seen:
            n += 1
            candidate = f"{stem}_{n}"
        seen.add(candidate.lower())
        stems.append(candidate)
    return stems


def split_design_spec(spec: str) -> tuple[str, str | None]:
    """``"results.h5:RUN"`` → ``("results.h5", "RUN")``; ``"results.h5"`` → ``(…, None)``."""
    path, sep, rid = str(spec).rpartition(":")
    if not sep or not path.endswith((".h5", ".hdf5")):
        return str(spec), None
    return path, rid or None


#: What a terminal would act on instead of showing: C0 controls but tab and newline, DEL,
#: C1 controls (``\x9b`` is a one-byte CSI) and the bidirectional overrides and isolates.
_UNSAFE = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f\u202a-\u202e\u2066-\u2069]")


def printable(text: str) -> str:
    """``text`` with every character a terminal would act on written as its escape
    (``\\x1b``, ``\\u202e``): what a file says is shown, never executed."""
    return _UNSAFE.sub(lambda m: f"\\x{ord(m[0]):02x}" if ord(m[0]) < 0x100 else f"\\u{ord(m[0]):04x}", text)


class EscapedStream:
    """A text stream whose writes pass :func:`printable` (the commands' stdout and stderr,
    logging's too); everything else is the wrapped stream's."""

    def __init__(self, stream) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        return self._stream.write(printable(text))

    def __getattr__(self, name):
        return getattr(self._stream, name)
