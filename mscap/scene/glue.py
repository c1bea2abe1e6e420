"""The ``[objects]`` table and the ``[[poses]]`` entries of kind ``"glue"``, read into the
glue model of :mod:`mscap.bodies.glue` (objects, placements, glued poses): the scene reads
its TOML, the bodies do not (docs/architecture.md, the package order).

Scene keys are documented in ``docs/glue.md``, :func:`read_objects` and
:func:`read_glue_pose`.
"""

from __future__ import annotations

import inspect
import logging
import math
from pathlib import Path
from typing import Any

import meshio
import numpy as np

from mscap.bodies.glue import GlueObject, GluePose, Placement, Surface, _grid, _rigid_fit, _vertex_areas
from mscap.bodies.kinematics import ParameterError
from mscap.bodies.registry import GENERATORS, generator_parameters, parameter_kind
from mscap.scene._toml import Table
from mscap.scene.settings import MAX_LENGTH_MM, MIN_LENGTH_MM

__all__ = ["read_objects", "read_glue_pose"]

logger = logging.getLogger(__name__)

#: The largest surface file read (bytes): meshio reads a whole file into memory.
MAX_SURFACE_BYTES = 256 * 2**20


def _read_surface(t: Table, key: str, base: Path) -> tuple[Path, Any]:
    """Read the triangle surface file named by entry ``key`` of ``t`` with meshio."""
    path = base / t.get(key, str)
    if not path.is_file():  # not a directory, device or pipe meshio would wait on
        raise t.error(key, f"cannot read surface file {str(path)!r}: "
                      f"{'no such file' if not path.exists() else 'not a regular file'}")
    if path.stat().st_size > MAX_SURFACE_BYTES:
        raise t.error(key, f"surface file {str(path)!r} has {path.stat().st_size} bytes; at most "
                      f"{MAX_SURFACE_BYTES} are read (a hand's surface is a few MB)")
    try:
        mesh = meshio.read(path)
    except Exception as exc:          # meshio raises many types; name the file in all
        raise t.error(key, f"cannot read surface file {str(path)!r}: {exc}") from None
    kinds = {block.type for block in mesh.cells} - {"vertex", "line", "triangle"}
    if kinds:
        raise t.error(key, f"{str(path)!r} has {', '.join(sorted(kinds))} cells; "
                      "only triangles are supported (triangulate the surface)")
    blocks = [block.data for block in mesh.cells if block.type == "triangle"]
    if not blocks:
        raise t.error(key, f"{str(path)!r} has no triangles")
    points = np.asarray(mesh.points, dtype=float)
    if points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    if not np.isfinite(points).all():
        raise t.error(key, f"{str(path)!r} has non-finite point coordinates")
    return path, (points, np.concatenate(blocks).astype(np.int64), mesh.point_data)


def read_objects(t: Table | None, scene_path: str) -> dict[str, GlueObject]:
    """Read the scene's ``[objects]`` table.

    Each ``[objects.NAME]`` is either generated or read from a file:

    ``generator`` (string)
        a name in :data:`GENERATORS` (``"cylinder"``, ``"dome"``, ...). The rest
        surface is the flat rectangle ``width_mm`` × ``height_mm`` (numbers > 0) with
        its lower-left corner at ``corner_mm`` (``[u, v]``, default ``[0, 0]``),
        triangulated with edges of ``edge_length_mm`` (> 0, default 1); its points are
        (u, v, 0). It must cover the sheet's placement in the parameter plane.
    ``rest`` (string)
        a triangle surface file meshio reads, relative to the scene file's directory;
        ``uv_field`` (string, optional) names the point data holding each vertex's
        parameter coordinates (mm, 2 columns, or more with zeros after the second);
        without it the parameter coordinates are the file's (x, y).

    Raises
    ------
    SceneError
        Naming the key and value: both or neither of ``generator``/``rest``, an unknown
        generator, an unreadable or non-triangle file, a missing or malformed uv field,
        and parameter-plane triangulations with duplicate or unused points, zero-area
        triangles, non-manifold edges or folds.
    """
    if t is None:
        return {}
    base = Path(scene_path).parent
    objects = {}
    for name in t.data:
        o = t.table(name)
        if o.has("generator") == o.has("rest"):
            raise o.error("generator", "give exactly one of 'generator' (a generated flat "
                          "object) or 'rest' (a surface file)")
        if o.has("generator"):
            generator = o.get("generator", str)
            if generator not in GENERATORS:
                raise o.error("generator", f"unknown generator {generator!r}; known: "
                              f"{', '.join(sorted(GENERATORS))}")
            width = o.get("width_mm", float, positive=True, maximum=MAX_LENGTH_MM, why="10 m; the keys are in mm")
            height = o.get("height_mm", float, positive=True, maximum=MAX_LENGTH_MM, why="10 m; the keys are in mm")
            corner = _point(o, "corner_mm", [0.0, 0.0])
            edge = o.get("edge_length_mm", float, 1.0, positive=True, minimum=MIN_LENGTH_MM, why="1 µm")
            cells = math.ceil(width / edge) * math.ceil(height / edge)
            if cells > 1_000_000:
                raise o.error("edge_length_mm", f"{edge!r} mm makes {cells} cells on a "
                              f"{width:g} x {height:g} mm object (limit 1000000)")
            rest, key, source = _grid(width, height, corner, edge), "edge_length_mm", None
        else:
            generator = None
            path, (points, triangles, point_data) = _read_surface(o, "rest", base)
            uv, key = points[:, :2], "rest"
            field_name = o.get("uv_field", str, None)
            if field_name is not None:
                uv, key = _uv_field(o, field_name, path, point_data, len(points)), "uv_field"
            rest, source = Surface(points, triangles, uv), str(path)
        o.finish()
        try:
            objects[name] = GlueObject(name, rest, generator, source)
        except ValueError as exc:
            where = f"{source!r}: " if source else ""
            raise o.error(key, f"{where}unusable parameter-plane triangulation: {exc}") from None
        logger.info("object %r: %d vertices, %d triangles, uv extent %s mm", name,
                    len(rest.uv), len(rest.triangles), np.ptp(rest.uv, axis=0).round(3).tolist())
    return objects


def _point(t: Table, key: str, default: Any = ...) -> tuple[float, float] | None:
    """Entry ``key`` as one point ``[x, y]`` (``default`` when absent)."""
    value = t.get(key, list, default)
    if value is None:
        return None
    return t.points("", [value], key=t.key(key))[0]


def _uv_field(t: Table, name: str, path: Path, point_data: dict, n: int) -> np.ndarray:
    if name not in point_data:
        known = ", ".join(sorted(point_data)) or "none"
        raise t.error("uv_field", f"{str(path)!r} has no point data {name!r} "
                      f"(it has: {known})")
    uv = np.asarray(point_data[name], dtype=float)
    if uv.ndim != 2 or uv.shape[0] != n or uv.shape[1] < 2 or np.any(uv[:, 2:] != 0):
        raise t.error("uv_field", f"point data {name!r} of {str(path)!r} must hold 2 "
                      f"coordinates per point (mm), got shape {uv.shape}")
    if not np.isfinite(uv).all():
        raise t.error("uv_field", f"point data {name!r} of {str(path)!r} is not finite")
    return uv[:, :2]


def read_glue_pose(t: Table, objects: dict[str, GlueObject]) -> GluePose:
    """Read one ``[[poses]]`` entry of kind ``"glue"``.

    Keys: ``object`` (a name defined under ``[objects]``); the placement ``origin_mm``
    (``[u, v]``, default ``[0, 0]``: the parameter point under the sheet's origin) and
    ``rotation_deg`` (default 0); then for a generated object its generator's parameters
    (``cylinder`` and ``dome``: ``radius_mm`` > 0, ``center_mm`` = ``[u, v]``, default
    the centre of the object), or for a file object ``surface`` (the posed surface file,
    relative to the scene file, same triangles as the rest file) and ``align`` (boolean,
    default true: fit K_i rigidly to the flat sheet before blending).

    Raises
    ------
    SceneError
        Naming the key and value: a kind other than glue, an unknown object, generator
        parameters missing or out of range, a surface given for a generated object (or
        missing for a file object), an unreadable surface, a posed surface whose points
        or triangles differ from the rest surface's, and unknown keys.
    """
    name = t.get("name", str)
    kind = t.get("kind", str)
    if kind != "glue":
        raise t.error("kind", f"expected 'glue', got {kind!r}")
    object_name = t.get("object", str)
    if object_name not in objects:
        defined = ", ".join(sorted(objects)) or "none; add an [objects.NAME] table"
        raise t.error("object", f"unknown object {object_name!r}; defined: {defined}")
    obj = objects[object_name]
    origin = _point(t, "origin_mm", [0.0, 0.0])
    placement = Placement(origin, t.get("rotation_deg", float, 0.0))
    if obj.generator is not None:
        if t.has("surface") or t.has("align"):
            key = "surface" if t.has("surface") else "align"
            raise t.error(key, f"object {object_name!r} is generated by {obj.generator!r}; "
                          "give its parameters instead of a posed surface")
        pose = GluePose(name, object=obj, placement=placement,
                        generator_parameters=_read_parameters(t, obj))
    else:
        base = Path(t.path).parent
        path, (points, triangles, _) = _read_surface(t, "surface", base)
        rest = obj.rest
        if len(points) != len(rest.points) or len(triangles) != len(rest.triangles):
            raise t.error("surface", f"{str(path)!r} has {len(points)} points and "
                          f"{len(triangles)} triangles; the rest surface {obj.source!r} has "
                          f"{len(rest.points)} and {len(rest.triangles)}")
        differ = np.flatnonzero(np.any(triangles != rest.triangles, axis=1))
        if len(differ):
            i = differ[0]
            raise t.error("surface", f"{str(path)!r} has the rest surface's counts but "
                          f"different triangles ({len(differ)} differ; first: triangle {i} "
                          f"is {triangles[i].tolist()}, in the rest surface "
                          f"{rest.triangles[i].tolist()})")
        posed = Surface(points, triangles, rest.uv)
        alignment = np.eye(4)
        if t.get("align", bool, True):
            alignment = _rigid_fit(points, obj.flat_points, _vertex_areas(rest))
        pose = GluePose(name, object=obj, placement=placement, posed=posed, alignment=alignment)
    t.finish()
    return pose


def _read_parameters(t: Table, obj: GlueObject) -> tuple[tuple[str, Any], ...]:
    """The generator's keyword parameters from the pose table, checked by one call."""
    function = GENERATORS[obj.generator]
    values = {}
    for parameter in generator_parameters(function):
        default = ... if parameter.default is inspect.Parameter.empty else parameter.default
        if parameter_kind(parameter) == "point":
            values[parameter.name] = _point(t, parameter.name, default)
        else:
            values[parameter.name] = t.get(parameter.name, float, default)
    uv = obj.rest.uv
    try:
        posed = np.asarray(function(uv, 1.0, **values), dtype=float)
        flat = np.asarray(function(uv, 0.0, **values), dtype=float)
    except ParameterError as exc:
        raise t.error(exc.parameter, str(exc)) from None
    scale = max(1.0, float(np.abs(uv).max()))
    if posed.shape != (len(uv), 3) or not np.isfinite(posed).all():
        raise t.error("object", f"generator {obj.generator!r} returned shape {posed.shape} "
                      f"or non-finite values for {len(uv)} vertices")
    if flat.shape != posed.shape or np.abs(flat - obj.flat_points).max() > 1e-12 * scale:
        raise t.error("object", f"generator {obj.generator!r} does not return the flat "
                      "sheet (u, v, 0) at load fraction 0")
    return tuple(values.items())
