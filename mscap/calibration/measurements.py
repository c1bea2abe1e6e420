"""Measured capacitances for ``mscap fit``: a CSV file of readings of a scene's poses.

One reading per row; the columns::

    pose,run,C0,C1,C2,C3
    rest,1,59.7,60.4,53.4,59.5
    poke_0,1,70.2,61.9,54.9,61.0

``pose`` names a pose of the scene; ``C<i>`` is capacitor *i* of the scene's layout (any
subset, in any order; a capacitor not measured is left out, not left blank); ``run``
(optional) labels the readings taken in one session: appendix A's per-run gain is shared
by them, and the fit's standard errors then treat each run as one draw (the readings of a
run are not independent). A pose may be read any number of times. Every cell must hold a
finite number: a blank cell, text or ``nan`` is an error naming the file, line and column.
"""

from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass

import numpy as np

from mscap.errors import CalibrationError
from mscap.infile import read_regular

__all__ = ["Measurements", "read_measurements", "MAX_MEASUREMENT_BYTES"]

#: The largest measurement file read: 100,000 readings of 10 capacitors are about 8 MB.
MAX_MEASUREMENT_BYTES = 16 * 2**20

_CAPACITOR = re.compile(r"^C(\d+)$")


@dataclass(frozen=True)
class Measurements:
    """Readings of some capacitors of a scene in some of its poses.

    Attributes
    ----------
    path
        The CSV file.
    poses
        The poses read, in the scene's order (what the forward simulates).
    pose_of_reading
        Per row, the index into ``poses``.
    capacitors
        The capacitor (index into the scene's layout) of each column.
    values_pF
        ``(readings, len(capacitors))``.
    runs
        Per row, its run label (``None`` without a ``run`` column).
    lines
        Per row, its line in the file (for messages and the residual table).
    """

    path: str
    poses: tuple[str, ...]
    pose_of_reading: np.ndarray
    capacitors: tuple[int, ...]
    values_pF: np.ndarray
    runs: tuple[str, ...] | None
    lines: tuple[int, ...]

    def model(self, capacitance_pF: np.ndarray) -> np.ndarray:
        """What each reading should be, from a ``(len(poses), k)`` simulated table."""
        return capacitance_pF[self.pose_of_reading][:, list(self.capacitors)]


def _fail(path: str, message: str) -> CalibrationError:
    return CalibrationError(f"{path}: {message}")


def read_measurements(path, scene_poses: list[str], k: int) -> Measurements:
    """The readings of ``path`` for a scene with poses ``scene_poses`` and ``k`` capacitors.

    Raises
    ------
    CalibrationError
        One line naming the file (and line and column) for a file that is not a readable
        CSV of at most :data:`MAX_MEASUREMENT_BYTES`, an unknown column or pose, a capacitor
        outside the layout, a repeated column, or a cell that is blank or not a finite number."""
    path = str(path)
    try:
        text = read_regular(path, MAX_MEASUREMENT_BYTES, "a measurement CSV").decode("utf-8")
    except OSError as exc:
        raise _fail(path, f"cannot read the measurements ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise _fail(path, f"not a text file (byte {exc.start} is not UTF-8)") from None
    except ValueError as exc:
        raise _fail(path, str(exc)) from None
    rows = list(csv.reader(io.StringIO(text)))
    numbered = [(i + 1, row) for i, row in enumerate(rows) if any(cell.strip() for cell in row)]
    if not numbered:
        raise _fail(path, "empty: expected a header 'pose,C0,C1,...' and one row per reading")
    header_line, header = numbered[0]
    header = [h.strip() for h in header]
    if "pose" not in header:
        raise _fail(path, f"line {header_line}: no 'pose' column in the header ({','.join(header)})")
    columns: list[tuple[int, int]] = []  # (position in the row, capacitor)
    for at, name in enumerate(header):
        if name in ("pose", "run"):
            if header.count(name) > 1:
                raise _fail(path, f"line {header_line}: column {name!r} given twice")
            continue
        m = _CAPACITOR.match(name)
        if m is None:
            raise _fail(path, f"line {header_line}: unknown column {name!r} (expected pose, run and C0..C{k - 1})")
        capacitor = int(m[1])
        if capacitor >= k:
            raise _fail(path, f"line {header_line}: column {name}: the scene has {k} capacitors (C0..C{k - 1})")
        if capacitor in [c for _, c in columns]:
            raise _fail(path, f"line {header_line}: column {name} given twice")
        columns.append((at, capacitor))
    if not columns:
        raise _fail(path, f"line {header_line}: no capacitor columns (C0..C{k - 1})")
    pose_at, run_at = header.index("pose"), header.index("run") if "run" in header else None
    poses, runs, values, lines = [], [], [], []
    for line, row in numbered[1:]:
        if len(row) != len(header):
            raise _fail(path, f"line {line}: {len(row)} cells, the header has {len(header)}")
        pose = row[pose_at].strip()
        if pose not in scene_poses:
            raise _fail(path, f"line {line}: no pose named {pose!r} in the scene (it has {', '.join(scene_poses)})")
        numbers = []
        for at, capacitor in columns:
            cell = row[at].strip()
            try:
                value = float(cell)
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                what = "blank" if not cell else f"{cell[:20]!r}, not a finite number"
                raise _fail(path, f"line {line}, column {header[at]}: {what} (a capacitor not measured is left "
                                  f"out of the header, not left blank)")
            numbers.append(value)
        if run_at is not None and not row[run_at].strip():
            raise _fail(path, f"line {line}, column run: blank")
        poses.append(pose)
        runs.append(row[run_at].strip() if run_at is not None else "")
        values.append(numbers)
        lines.append(line)
    if not values:
        raise _fail(path, "no readings below the header")
    order = [p for p in scene_poses if p in poses]
    return Measurements(path=path, poses=tuple(order), pose_of_reading=np.array([order.index(p) for p in poses]),
                        capacitors=tuple(c for _, c in columns), values_pF=np.array(values, dtype=float),
                        runs=tuple(runs) if run_at is not None else None, lines=tuple(lines))
