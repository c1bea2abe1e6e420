"""Scene parameters by name: read from a scene file and written back into its text.

A parameter is named by its place in the scene file, the way a user reads it:

- ``materials.clear.relative_permittivity``, ``materials.carbon.youngs_modulus_MPa``
- ``layers.dielectric.thickness_mm``: an element of an array of tables (``[[layers]]``,
  ``[[poses]]``) is picked by its ``name``;
- ``poses.*.depth_mm``: ``*`` is every element that has the key, moved together (one
  value; they must start equal);
- ``capacitors.grid.center_mm[0]``: one number of an array;
- ``thickness_scale``: every layer's ``thickness_mm`` times one factor (starts at 1).

:func:`apply` writes values into the file's *text*, line by line, so that comments and
layout stay; it then parses the result and checks that exactly the named values changed
(a place the line editor cannot reach, e.g. a multi-line array, is an error, never a
silently different scene).
"""

from __future__ import annotations

import copy
import math
import re
import tomllib
from dataclasses import dataclass

from mscap.errors import SceneError

__all__ = ["Parameter", "parameter", "apply", "set_places", "format_number"]

#: The tables whose elements are picked by name.
NAMED_ARRAYS = ("layers", "poses")

#: A name that is not a place: what it scales.
SCALES = {"thickness_scale": ("layers", "thickness_mm")}

_INDEX = re.compile(r"^(?P<key>[A-Za-z0-9_]+)\[(?P<i>\d+)\]$")
_HEADER = re.compile(r"^\s*(?P<open>\[\[?)\s*(?P<name>[A-Za-z0-9_.\-]+)\s*\]\]?\s*(#.*)?$")
_KEY = re.compile(r"^(?P<indent>\s*)(?P<key>[A-Za-z0-9_.\-]+)(?P<eq>\s*=\s*)(?P<rest>.*)$")


@dataclass(frozen=True)
class Parameter:
    """One fitted quantity of a scene.

    Attributes
    ----------
    name
        As given (``layers.dielectric.thickness_mm``, ``thickness_scale``).
    places
        Where it lives in the parsed scene: key paths such as ``("layers", 2,
        "thickness_mm")`` or ``("capacitors", "grid", "center_mm", 0)``.
    start
        Its value in the scene (1 for a scale).
    bases
        Each place's value in the scene: a place holds ``value * base`` for a scale, ``value``
        otherwise.
    scale
        Whether the value multiplies the places' own values.
    """

    name: str
    places: tuple[tuple, ...]
    start: float
    bases: tuple[float, ...]
    scale: bool = False

    def values_at(self, value: float) -> list[float]:
        """What each place holds when the parameter is ``value``."""
        return [value * b for b in self.bases] if self.scale else [value] * len(self.places)


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _get(data, place: tuple):
    for step in place:
        data = data[step]
    return data


def parameter(path: str, data: dict, name: str) -> Parameter:
    """The parameter ``name`` of the parsed scene ``data`` (file ``path``, for messages).

    Raises
    ------
    SceneError
        When ``name`` names no number of the scene (the message says what is there)."""
    if name in SCALES:
        table, key = SCALES[name]
        places = tuple((table, i, key) for i, element in enumerate(data.get(table, []))
                       if isinstance(element, dict) and _number(element.get(key)))
        if not places:
            raise SceneError(path, name, f"the scene has no {table} with a {key} to scale")
        return Parameter(name, places, 1.0, tuple(float(_get(data, p)) for p in places), scale=True)
    steps = name.split(".")
    if not all(steps):
        raise SceneError(path, name, "not a parameter name (expected e.g. materials.clear.relative_permittivity, "
                                     f"layers.dielectric.thickness_mm, poses.*.depth_mm or {', '.join(SCALES)})")
    candidates: list[tuple] = [()]
    for depth, step in enumerate(steps):
        index = _INDEX.match(step) if depth == len(steps) - 1 else None
        key = index["key"] if index else step
        found = []
        for place in candidates:
            node = _get(data, place)
            if isinstance(node, list) and place and place[-1] in NAMED_ARRAYS:
                named = [i for i, e in enumerate(node) if isinstance(e, dict) and (key == "*" or e.get("name") == key)]
                found += [place + (i,) for i in named]
            elif isinstance(node, dict) and key in node:
                found.append(place + (key,))
        if not found:
            where = ".".join(steps[:depth]) or "the scene"
            node = _get(data, candidates[0]) if candidates else None
            if isinstance(node, list) and candidates[0] and candidates[0][-1] in NAMED_ARRAYS:
                known = ", ".join(str(e.get("name")) for e in node if isinstance(e, dict))
                raise SceneError(path, name, f"no element named {key!r} in {where} (it has {known}; * for all)")
            known = ", ".join(sorted(node)) if isinstance(node, dict) else "nothing"
            raise SceneError(path, name, f"no key {key!r} in {where} (it has {known}); a parameter must be "
                                         f"written in the file to be fitted")
        if index:
            found = [p + (int(index["i"]),) for p in found
                     if isinstance(_get(data, p), list) and int(index["i"]) < len(_get(data, p))]
            if not found:
                raise SceneError(path, name, f"{key} has no element [{index['i']}]")
        candidates = found
    if "*" in steps:
        candidates = [p for p in candidates if _number(_get(data, p))]
        if not candidates:
            raise SceneError(path, name, "no element * picks holds a number there")
    values = [_get(data, p) for p in candidates]
    if not candidates or not all(_number(v) for v in values):
        raise SceneError(path, name, f"not a number in the scene: {values[0] if values else None!r}")
    if len(set(values)) > 1:
        raise SceneError(path, name, f"the places * picks start at different values ({', '.join(map(str, values))}); "
                                     f"one parameter moves them together, so they must start equal")
    return Parameter(name, tuple(candidates), float(values[0]), tuple(float(v) for v in values))


def format_number(value: float) -> str:
    """``value`` as a TOML float, to 10 significant digits (a fit's standard error is far above that)."""
    text = f"{value:.10g}"
    return text if any(c in text for c in ".eEn") else text + ".0"


def set_places(data: dict, parameters: list[Parameter], values) -> dict:
    """A deep copy of ``data`` with every parameter's places set (to the numbers
    :func:`format_number` writes, so that the text and the data are the same scene)."""
    out = copy.deepcopy(data)
    for p, value in zip(parameters, values):
        for place, v in zip(p.places, p.values_at(float(value))):
            _get(out, place[:-1])[place[-1]] = float(format_number(v))
    return out


def _table_of_lines(lines: list[str]) -> list[tuple]:
    """The table path each line belongs to (array-of-tables elements by index)."""
    counts: dict[tuple, int] = {}
    current: tuple = ()
    owners = []
    for line in lines:
        header = _HEADER.match(line)
        if header:
            parts = tuple(header["name"].split("."))
            if header["open"] == "[[":
                counts[parts] = counts.get(parts, -1) + 1
                current = parts + (counts[parts],)
            else:
                current = parts
        owners.append(current)
    return owners


def apply(path: str, source: str, parameters: list[Parameter], values) -> str:
    """The scene text ``source`` with every parameter set to its value.

    Raises
    ------
    SceneError
        When a place is not on a line of its own (``key = number`` or ``key = [numbers]``),
        or the edited text does not parse to the scene with exactly those values."""
    data = tomllib.loads(source)
    wanted = set_places(data, parameters, values)
    lines = source.splitlines(keepends=True)
    owners = _table_of_lines(lines)
    for p, value in zip(parameters, values):
        for place, v in zip(p.places, p.values_at(float(value))):
            # Only a ``key[i]`` name ends its place with an index (an element of a named
            # array is always followed by its key).
            element = place[-1] if isinstance(place[-1], int) else None
            key_place = place[:-1] if element is not None else place
            at = _line_of(lines, owners, key_place)
            if at is None:
                raise SceneError(path, p.name, f"cannot write {'.'.join(map(str, key_place))} into the file's text "
                                               f"(not on a line 'key = value' of its table)")
            m = _KEY.match(lines[at])
            value_text, sep, comment = m["rest"].partition("#")
            end = "\n" if lines[at].endswith("\n") else ""
            if element is None:
                new = format_number(v)
            else:
                array = _get(wanted, key_place)
                new = "[" + ", ".join(format_number(x) if isinstance(x, float) else str(x) for x in array) + "]"
            trail = value_text[len(value_text.rstrip()):].replace("\n", "")
            lines[at] = (f"{m['indent']}{m['key']}{m['eq']}{new}{trail}" + (sep + comment.rstrip("\n") if sep else "")
                         + end)
    text = "".join(lines)
    try:
        got = tomllib.loads(text)
    except tomllib.TOMLDecodeError:
        got = None
    if got != wanted:
        raise SceneError(path, ", ".join(p.name for p in parameters),
                         "the values could not be written into the file's text (a multi-line array or an inline "
                         "table?); write them as 'key = value' lines")
    return text


def _line_of(lines: list[str], owners: list[tuple], place: tuple) -> int | None:
    """The line holding the key at ``place``: ``key = ...`` in its table, or a dotted
    ``a.key = ...`` in a table above it."""
    for at, (line, owner) in enumerate(zip(lines, owners)):
        m = _KEY.match(line)
        if m is None:  # a header, a comment, a blank line or inside a multi-line value
            continue
        if owner + tuple(m["key"].split(".")) == place:
            value = m["rest"].partition("#")[0].strip()
            if value.startswith("[") and not value.endswith("]"):
                return None  # a multi-line array
            return at
    return None
