"""Typed, checked access to one TOML table, for the scene loader.

Every read names the dotted key it came from, so that a bad value produces a
:class:`~mscap.errors.SceneError` that says which file, which key and which value.
"""

from __future__ import annotations

import difflib
import math
from typing import Any

from mscap.errors import SceneError

_TYPE_NAMES = {bool: "a boolean", int: "an integer", float: "a number", str: "a string",
               list: "an array", dict: "a table"}


def _describe(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


class Table:
    """A TOML table being read: remembers which keys were used.

    Parameters
    ----------
    path
        The scene file, for messages.
    prefix
        Dotted key of this table (``""`` for the root).
    data
        The parsed table.
    """

    def __init__(self, path: str, prefix: str, data: Any):
        self.path = path
        self.prefix = prefix
        if not isinstance(data, dict):
            raise SceneError(path, prefix, f"expected a table, got {_describe(data)}")
        self.data = data
        self._used: set[str] = set()

    def key(self, name: str) -> str:
        """Dotted name of ``name`` inside this table."""
        return f"{self.prefix}.{name}" if self.prefix else name

    def error(self, name: str, message: str) -> SceneError:
        """A :class:`SceneError` about entry ``name`` of this table."""
        return SceneError(self.path, self.key(name), message)

    def has(self, name: str) -> bool:
        return name in self.data

    def get(self, name: str, kind: type, default: Any = ..., *, positive: bool = False,
            minimum: float | None = None, maximum: float | None = None, why: str = "") -> Any:
        """Read entry ``name`` as ``kind`` (bool, int, float, str, list or dict).

        ``default=...`` makes the key required. Integers are accepted where floats
        are expected; floats must be finite; ``positive`` demands > 0, ``minimum``
        >= minimum and ``maximum`` <= maximum (``why``, the reason for the range, ends
        the message).
        """
        self._used.add(name)
        if name not in self.data:
            if default is ...:
                raise self.error(name, "missing (required)" + self._misspelt(name))
            return default
        value = self.data[name]
        value = self._convert(self.key(name), value, kind)
        if kind in (int, float):
            reason = f" ({why})" if why else ""
            if positive and not value > 0:
                raise self.error(name, f"must be > 0, got {value!r}{reason}")
            if minimum is not None and value < minimum:
                raise self.error(name, f"must be >= {minimum:g}, got {value!r}{reason}")
            if maximum is not None and value > maximum:
                raise self.error(name, f"must be <= {maximum:g}, got {value!r}{reason}")
        return value

    def _misspelt(self, name: str) -> str:
        """``"; did you mean ..."`` when a key of the table nobody has read yet looks like
        the missing ``name`` (``poisson_rato`` for ``poisson_ratio``)."""
        unread = [key for key in self.data if key not in self._used and isinstance(key, str)]
        close = difflib.get_close_matches(name, unread, n=1, cutoff=0.8)
        return f"; is '{close[0]}' a misspelling of it?" if close else ""

    def integers(self, name: str, default: tuple) -> tuple[int, ...]:
        """Entry ``name`` as a tuple of integers: one integer or an array of them."""
        self._used.add(name)
        if name not in self.data:
            return default
        value = self.data[name]
        items = [value] if not isinstance(value, (list, tuple)) else list(value)
        if not items or not all(isinstance(v, int) and not isinstance(v, bool) for v in items):
            raise self.error(name, f"expected an integer or an array of integers, got {_describe(value)}")
        return tuple(items)

    def _convert(self, key: str, value: Any, kind: type) -> Any:
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if (kind is int and isinstance(value, bool)) or not isinstance(value, kind):
            raise SceneError(self.path, key,
                             f"expected {_TYPE_NAMES.get(kind, kind.__name__)}, "
                             f"got {_describe(value)}")
        if kind is float and not math.isfinite(value):
            raise SceneError(self.path, key, f"must be finite, got {value!r}")
        return value

    def table(self, name: str, required: bool = True) -> "Table | None":
        """Sub-table ``name`` (``None`` when absent and not required)."""
        if not required and name not in self.data:
            self._used.add(name)
            return None
        return Table(self.path, self.key(name), self.get(name, dict))

    def tables(self, name: str, required: bool = True) -> list["Table"]:
        """Array of tables ``name`` (``[[name]]`` in TOML)."""
        items = self.get(name, list, ... if required else [])
        return [Table(self.path, f"{self.key(name)}[{i}]", item) for i, item in enumerate(items)]

    def points(self, name: str, value: Any = ..., key: str | None = None) -> list[tuple[float, float]]:
        """Entry ``name`` as a list of 2D points ``[[x, y], ...]`` (mm)."""
        if value is ...:
            value = self.get(name, list)
        key = key or self.key(name)
        out = []
        for i, point in enumerate(value):
            if (not isinstance(point, list) or len(point) != 2
                    or not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in point)):
                raise SceneError(self.path, f"{key}[{i}]",
                                 f"expected a point [x, y] of two numbers, got {_describe(point)}")
            if not all(math.isfinite(c) for c in point):
                raise SceneError(self.path, f"{key}[{i}]", f"must be finite, got {point!r}")
            out.append((float(point[0]), float(point[1])))
        return out

    def finish(self) -> None:
        """Raise on the first key that no reader asked for (with a suggestion)."""
        for name in self.data:
            if name not in self._used:
                close = difflib.get_close_matches(name, sorted(self._used), n=1)
                hint = f"; did you mean '{close[0]}'?" if close else \
                    f"; known keys: {', '.join(sorted(self._used))}"
                raise self.error(name, f"unknown key{hint}")
