"""Scene files: reading a TOML scene into a :class:`~mscap.scene.settings.Scene`, with every
check of every table in one place.

Every bad value raises :class:`~mscap.errors.SceneError` naming the file, the key and
the value. :func:`check_optimizer` and :func:`check_multistart` are also what code
that builds settings itself (tests, a stored scene) calls.
"""

from __future__ import annotations

import difflib
import logging
import math
import re
import tomllib
import typing
import unicodedata
from dataclasses import replace
from pathlib import Path

import numpy as np

from mscap.errors import GeometryError, SceneError
from mscap.infile import read_regular
from mscap.geometry import polygons as geometry
from mscap.geometry.layout import SHAPES, Layout, check_layout, grid_layout
from mscap.scene import sizing
from mscap.scene._toml import Table
from mscap.scene.calibration import CalibrationSettings, read_calibration
from mscap.scene.poses import read_pose
from mscap.scene.settings import (BALL_EDGE_RATIO, DEFAULT_FAMILY_COUNT, DEFAULT_MIN_GAP_MM, DESIGN_POSES,
                                  DISTANCES, ELASTIC_MESHES, HESSIAN_MODES, LAYER_KINDS, LAYER_THICKNESS_MM,
                                  MAX_CAPACITORS, MAX_CASCADE_LEVELS, MAX_CUTS, MAX_ITERATIONS, MAX_LENGTH_MM,
                                  MAX_NAME_LENGTH, MAX_OUTLINE_VERTICES, MAX_RELATIVE_PERMITTIVITY, MAX_SCENE_BYTES,
                                  MAX_CALIBRATE_SEEDS, MAX_SEED, MAX_SLABS, MAX_STARTS_PER_K, MIN_LENGTH_MM,
                                  PETSC_TYPES, POSE_KINDS,
                                  POSE_NAME_PATTERN, SKINNING_METHODS, YOUNGS_MODULUS_MPA, ElasticSettings, Layer,
                                  CONNECTOR_EDGES, FabricationSettings, Material, MeshSettings, MultistartSettings,
                                  OptimizerSettings, Scene, auto_slabs)

__all__ = ["load_scene", "check_optimizer", "check_multistart", "check_fabrication", "routing_grid_mm", "check_designable", "family_grid_counts",
           "read_multistart", "select_poses", "with_overrides"]

log = logging.getLogger(__name__)


def load_scene(path: str | Path, source: str | None = None) -> Scene:
    """Read and validate a scene file (or its text ``source``, e.g. the one a results file
    stores, with ``path`` naming where it came from).

    Raises
    ------
    SceneError
        On any unreadable, unknown, missing, mistyped or out-of-range entry.
    """
    path = str(path)
    source = _read_text(path) if source is None else source
    try:
        data = tomllib.loads(source)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(path, "", f"not valid TOML: {exc}") from None
    root = Table(path, "", data)

    name = root.get("name", str, Path(path).stem)
    description = root.get("description", str, "")
    sheet = _read_sheet(root.table("sheet"))
    materials = _read_materials(root.table("materials"))
    layers = _read_layers(root, materials)
    mesh_table = root.table("mesh", required=False) or Table(path, "mesh", {})
    mesh = _read_mesh(mesh_table, layers, sheet)
    layout, min_gap = _read_capacitors(root.table("capacitors"), sheet, mesh)
    objects = _read_objects(root, path)
    poses = _read_poses(root, objects)
    _check_pose_geometry(path, poses, sheet)
    if mesh.tolerance is not None:  # the ladder for the plates, zones under the balls, glued bends
        mesh = _size_mesh(mesh_table, replace(mesh, zones=sizing.poke_zones(poses),
                                              curvature_edge_mm=sizing.curvature_edge(poses, sheet)),
                          layers, layout)
    elif mesh.signal_tolerance is not None:  # hand-set sizes: the zones the signal needs all the same
        mesh = replace(mesh, zones=sizing.no_finer_than(sizing.poke_zones(poses), mesh.edge_length_outline_mm))
    elastic = _read_dataclass(root.table("elastic", required=False), ElasticSettings)
    _check_elastic_budget(path, elastic)
    if "elements_through_thickness" not in data.get("elastic", {}):
        elastic = replace(elastic, elements_through_thickness=auto_slabs(layers))
    elastic = _elastic_for_signal(mesh, elastic, poses, data.get("elastic", {}))
    if elastic.order not in (1, 2):
        raise SceneError(path, "elastic.order", f"must be 1 or 2, got {elastic.order!r}")
    if elastic.mesh not in ELASTIC_MESHES:
        raise SceneError(path, "elastic.mesh",
                         f"unknown value {elastic.mesh!r}; expected one of {', '.join(ELASTIC_MESHES)}")
    for key in ("edge_length_mm", "edge_length_outline_mm"):
        value = getattr(elastic, key)
        if value is not None and not value > 0:
            raise SceneError(path, f"elastic.{key}", f"must be > 0, got {value!r}")
        if value is not None and not MIN_LENGTH_MM <= value <= MAX_LENGTH_MM:
            raise SceneError(path, f"elastic.{key}", f"must lie in [{MIN_LENGTH_MM:g}, {MAX_LENGTH_MM:g}] mm, "
                             f"got {value!r}")
    _check_balls(path, poses, mesh, elastic)
    if elastic.hessian not in HESSIAN_MODES:
        raise SceneError(path, "elastic.hessian",
                         f"unknown value {elastic.hessian!r}; expected one of {', '.join(HESSIAN_MODES)}")
    optimizer = _read_dataclass(root.table("optimizer", required=False), OptimizerSettings)
    multistart = _read_dataclass(root.table("multistart", required=False), MultistartSettings)
    check_multistart(path, multistart)
    petsc = _read_petsc(root.table("petsc", required=False))
    calibration = read_calibration(root.table("calibration", required=False), poses)
    _check_family_balls(path, poses, mesh, elastic, calibration)
    optimizer = _objective_defaults(optimizer, data.get("optimizer", {}), calibration)
    check_optimizer(path, optimizer, calibration)
    fabrication = _read_dataclass(root.table("fabrication", required=False), FabricationSettings)
    check_fabrication(path, fabrication, sheet)
    root.finish()
    sheet.setflags(write=False)
    return Scene(path=path, name=name, description=description, sheet_outline_mm=sheet,
                 layers=layers, layout=layout, min_gap_mm=min_gap, mesh=mesh, poses=poses, elastic=elastic,
                 optimizer=optimizer, multistart=multistart, petsc_options=petsc, source=source,
                 calibration=calibration, fabrication=fabrication)


def _read_text(path: str) -> str:
    """The scene file's text (UTF-8, newlines as ``read_text`` gives them), or a
    :class:`SceneError` saying why not. Only a regular file is read, and at most
    :data:`MAX_SCENE_BYTES` of it: a FIFO would block the open and the read, a device
    (``/dev/zero``) never end."""
    try:
        raw = read_regular(path, MAX_SCENE_BYTES, "a scene file (they are a few kB)")
    except OSError as exc:
        raise SceneError(path, "", f"cannot read scene file ({exc.strerror})") from None
    except ValueError as exc:
        raise SceneError(path, "", str(exc)) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SceneError(path, "", f"not a text file: byte {raw[exc.start]:#04x} at offset {exc.start} "
                         f"is not UTF-8") from None
    return text.replace("\r\n", "\n").replace("\r", "\n")


def _check_points(t: Table, key: str, points: np.ndarray) -> None:
    """At most :data:`MAX_OUTLINE_VERTICES` points, every coordinate within ±``MAX_LENGTH_MM``."""
    if len(points) > MAX_OUTLINE_VERTICES:
        raise SceneError(t.path, key, f"{len(points)} points; at most {MAX_OUTLINE_VERTICES} are taken")
    if len(points) and np.abs(points).max() > MAX_LENGTH_MM:
        raise SceneError(t.path, key, f"coordinate {np.abs(points).max():g} mm is beyond ±{MAX_LENGTH_MM:g} mm "
                         f"(10 m; the keys are in mm)")


def _read_sheet(t: Table) -> np.ndarray:
    if t.has("outline_mm"):
        outline = np.array(t.points("outline_mm"))
        _check_points(t, t.key("outline_mm"), outline)
        if len(outline) < 3:
            raise t.error("outline_mm", f"a polygon needs at least 3 points, got {len(outline)}")
        crossings = geometry.self_intersections(outline)
        if crossings:
            a, b = crossings[0]
            raise t.error("outline_mm", f"the sheet outline intersects itself (edges {a} and {b})")
        if abs(geometry.signed_area(outline)) == 0:
            raise t.error("outline_mm", "the sheet outline has zero area")
    else:
        if not t.has("width_mm") and not t.has("height_mm"):
            raise t.error("outline_mm", "missing: give outline_mm, or width_mm and height_mm")
        w = t.get("width_mm", float, positive=True, maximum=MAX_LENGTH_MM, why="10 m; the keys are in mm")
        h = t.get("height_mm", float, positive=True, maximum=MAX_LENGTH_MM, why="10 m; the keys are in mm")
        outline = np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])
    t.finish()
    return geometry.ccw(outline)


def _read_materials(t: Table) -> dict[str, Material]:
    materials = {}
    for name in t.data:
        m = t.table(name)
        lo, hi = YOUNGS_MODULUS_MPA
        e = m.get("youngs_modulus_MPa", float, positive=True)
        if not lo <= e <= hi:
            raise m.error("youngs_modulus_MPa", f"must lie in [{lo:g}, {hi:g}] MPa, got {e!r} (a gel to a rigid "
                          f"plastic; elastomers are 0.01-10 MPa)")
        nu = m.get("poisson_ratio", float)
        if not -1.0 < nu < 0.5:
            raise m.error("poisson_ratio", f"must lie in (-1, 0.5), got {nu!r}")
        eps_r = m.get("relative_permittivity", float)
        if eps_r < 1.0:
            raise m.error("relative_permittivity", f"must be >= 1, got {eps_r!r}")
        if eps_r > MAX_RELATIVE_PERMITTIVITY:
            raise m.error("relative_permittivity", f"must be <= {MAX_RELATIVE_PERMITTIVITY:g}, got {eps_r!r} "
                          f"(the highest of any ceramic)")
        m.finish()
        materials[name] = Material(name, e, nu, eps_r)
    if not materials:
        raise t.error("", "no materials defined")
    return materials


def _material(t: Table, key: str, materials: dict[str, Material]) -> Material:
    name = t.get(key, str)
    if name not in materials:
        raise t.error(key, f"unknown material {name!r}; defined: {', '.join(sorted(materials))}")
    return materials[name]


def _read_layers(root: Table, materials: dict[str, Material]) -> tuple[Layer, ...]:
    tables = root.tables("layers")
    if len(tables) != len(LAYER_KINDS):
        raise root.error("layers", f"a sensor has exactly 5 layers "
                         f"({', '.join(LAYER_KINDS)}, bottom to top), got {len(tables)}")
    layers = []
    for t, expected in zip(tables, LAYER_KINDS):
        kind = t.get("kind", str)
        if kind != expected:
            raise t.error("kind", f"expected {expected!r} at this position of the stack "
                          f"({', '.join(LAYER_KINDS)}, bottom to top), got {kind!r}")
        thickness = t.get("thickness_mm", float)
        if not thickness > 0:
            raise t.error("thickness_mm", f"must be > 0, got {thickness!r}")
        lo, hi = LAYER_THICKNESS_MM
        if not lo <= thickness <= hi:
            raise t.error("thickness_mm", f"must lie in [{lo:g}, {hi:g}] mm, got {thickness!r} (a layer of a "
                          f"stretchable sheet; one slab per layer cannot bend a block)")
        fill = _material(t, "fill", materials) if kind == "conductive" else None
        layers.append(Layer(t.get("name", str), kind, thickness, _material(t, "material", materials), fill))
        t.finish()
    return tuple(layers)


#: The [mesh] keys that set sizes by hand; a scene that gives all three and no tolerance
#: is meshed as given.
SIZE_KEYS = ("edge_length_mm", "edge_length_outline_mm", "grading_distance_mm")


def _read_mesh(t: Table, layers: tuple[Layer, ...], sheet: np.ndarray) -> MeshSettings:
    """``[mesh]`` as given; without all three sizes (or with a ``tolerance``), sized from the
    tolerance later (:func:`_size_mesh`), here with placeholders the given keys replace."""
    by_hand = all(t.has(key) for key in SIZE_KEYS) and not t.has("tolerance")
    tolerance = None
    if not by_hand:
        tolerance = t.get("tolerance", float, sizing.DEFAULT_TOLERANCE, positive=True)
        if not tolerance < 1:
            raise t.error("tolerance", f"a relative capacitance error, must be < 1, got {tolerance!r}")
    gap = layers[2].thickness_mm
    lengths = dict(minimum=MIN_LENGTH_MM, maximum=MAX_LENGTH_MM, why="1 µm to 10 m")
    far = t.get("edge_length_mm", float, ... if by_hand else sizing.FAR_EDGE_MM, positive=True, **lengths)
    near = t.get("edge_length_outline_mm", float, ... if by_hand else min(gap, far), positive=True, **lengths)
    if near > far:
        raise t.error("edge_length_outline_mm", f"{near!r} exceeds edge_length_mm = {far!r}")
    diagonal = float(np.hypot(*np.ptp(sheet, axis=0)))
    grading = t.get("grading_distance_mm", float, ... if by_hand else far / sizing.STEEP, positive=True,
                    maximum=max(diagonal, far / sizing.STEEP),
                    why="the sheet's diagonal: beyond it the whole sheet is meshed at the outline edge")
    per_layer = t.get("elements_per_layer", int, 1, minimum=1, maximum=MAX_SLABS,
                      why="tet slabs per layer; studied settings use 1-2")
    order = t.get("order", int, 1)
    if order not in (1, 2):
        raise t.error("order", f"must be 1 or 2, got {order!r}")
    element = t.get("element", str, "tet")
    if element not in ("tet", "prism"):
        raise t.error("element", f"must be \"tet\" or \"prism\", got {element!r}")
    if element == "prism" and order != 1:
        raise t.error("element", f"prisms are P1 only; this [mesh] asks for order = {order}")
    signal = t.get("signal_tolerance", float, None, positive=True)
    if signal is not None and not signal < 1:
        raise t.error("signal_tolerance", f"a relative error of the pose-to-pose gains, must be < 1, got {signal!r}")
    t.finish()
    return MeshSettings(far, near, grading, per_layer, order, tolerance, signal_tolerance=signal, element=element)


def _size_mesh(t: Table, given: MeshSettings, layers: tuple[Layer, ...], layout: Layout) -> MeshSettings:
    """The ladder's cheapest settings for the tolerance on the layout's plates; keys the
    scene gives win over the ladder's."""
    keys = SIZE_KEYS + ("elements_per_layer", "order", "element")
    mesh, worst = sizing.sized(replace(given, overrides=tuple((key, getattr(given, key)) for key in keys if t.has(key))),
                               layers, layout)
    if mesh.edge_length_outline_mm > mesh.edge_length_mm:
        raise t.error("edge_length_mm", f"{mesh.edge_length_mm!r} is below the outline edge "
                      f"{mesh.edge_length_outline_mm!r} the tolerance needs")
    log.info("mesh for tolerance %g: P%d, outline edge %.3g mm, %d per layer (predicted error %.2g)",
             given.tolerance, mesh.order, mesh.edge_length_outline_mm, mesh.elements_per_layer, worst)
    return mesh


def _elastic_for_signal(mesh: MeshSettings, elastic: ElasticSettings, poses, given: dict) -> ElasticSettings:
    """The elastic order and edge a poked scene's ``signal_tolerance`` asks for; an order or
    edge the scene's ``[elastic]`` gives wins (an order restricts the choice to its rungs).
    Without a signal tolerance a scene with pokes or glued poses that gives no order gets
    P2 (:data:`mscap.scene.sizing.BENDING_ELEMENT_ORDER`), and a poke-only scene's refined
    P2 mesh the far edge :data:`~mscap.scene.sizing.POKE_FAR_EDGE_MM`."""
    if mesh.signal_tolerance is None:
        if "order" not in given and any(getattr(p, "kind", None) in ("poke", "glue") for p in poses):
            log.info("elastic: P2 for the poses that bend the sheet (P1 tets lock in the thin stack; "
                     "docs/elastic.md)")
            elastic = replace(elastic, order=sizing.BENDING_ELEMENT_ORDER)
        far = sizing.poke_far_edge(elastic, mesh, poses, given)
        if far is not None:
            log.info("elastic: P2 refined under the balls and along the held edges, %g mm elsewhere", far)
            elastic = replace(elastic, edge_length_mm=far)
        return elastic
    chosen = sizing.elastic_for_signal(mesh.signal_tolerance, poses, given.get("order"))
    if chosen is None:
        return elastic
    rung, edge = chosen
    log.info("elastic mesh for signal tolerance %g: P%d, %.3g mm (%.3g R; measured gain error %.2g)",
             mesh.signal_tolerance, rung.order, edge, rung.edge_over_radius, rung.gain_error)
    return replace(elastic, order=given.get("order", rung.order), edge_length_mm=given.get("edge_length_mm", edge))


def _read_capacitors(t: Table, sheet: np.ndarray, mesh: MeshSettings) -> tuple[Layout, float]:
    min_gap = t.get("min_gap_mm", float, DEFAULT_MIN_GAP_MM, minimum=0.0, maximum=MAX_LENGTH_MM)
    if t.has("outlines_mm") == t.has("grid"):
        raise t.error("outlines_mm", "give exactly one of 'outlines_mm' (explicit polygons) "
                      "or a [capacitors.grid] table")
    if t.has("outlines_mm"):
        polygons = t.get("outlines_mm", list)
        if not polygons:
            raise t.error("outlines_mm", "no capacitors given")
        if len(polygons) > MAX_CAPACITORS:
            raise t.error("outlines_mm", f"{len(polygons)} capacitors; at most {MAX_CAPACITORS} (each costs "
                          f"one electrostatic solve per pose)")
        outlines = []
        for j, p in enumerate(polygons):
            key = f"{t.key('outlines_mm')}[{j}]"
            if not isinstance(p, list):
                raise SceneError(t.path, key, f"expected an outline [[x, y], ...], got {p!r:.60}")
            outlines.append(np.array(t.points("", p, key=key)).reshape(-1, 2))
            _check_points(t, key, outlines[-1])
            if len(outlines[-1]) < 3:
                raise SceneError(t.path, key, f"a polygon needs at least 3 points, got {len(outlines[-1])}")
        layout = Layout(tuple(outlines))
        where = lambda j: t.key("outlines_mm") + ("" if j is None else f"[{j}]")  # noqa: E731
    else:
        g = t.table("grid")
        shape = g.get("shape", str)
        if shape not in SHAPES:
            raise g.error("shape", f"unknown shape {shape!r}; expected one of {', '.join(SHAPES)}")
        rows = g.get("rows", int, minimum=1, maximum=MAX_CAPACITORS)
        columns = g.get("columns", int, minimum=1, maximum=MAX_CAPACITORS)
        if rows * columns > MAX_CAPACITORS:
            raise g.error("rows", f"{rows} x {columns} = {rows * columns} capacitors; at most {MAX_CAPACITORS} "
                          f"(each costs one electrostatic solve per pose)")
        size = g.get("size_mm", float, positive=True, maximum=MAX_LENGTH_MM)
        if shape != "square" and math.pi * size / mesh.edge_length_outline_mm > MAX_OUTLINE_VERTICES:
            raise g.error("size_mm", f"a {shape} of {size:g} mm with a vertex every {mesh.edge_length_outline_mm:g} mm "
                          f"(mesh.edge_length_outline_mm) needs more than {MAX_OUTLINE_VERTICES} vertices")
        if isinstance(g.data.get("pitch_mm"), list):
            pitch = tuple(g.get("pitch_mm", list))
            if len(pitch) != 2 or not all(isinstance(p, (int, float)) and not isinstance(p, bool)
                                          and 0 < p <= MAX_LENGTH_MM for p in pitch):
                raise g.error("pitch_mm", f"expected a number in (0, {MAX_LENGTH_MM:g}] or [px, py], "
                              f"got {list(pitch)!r}")
        else:
            pitch = (g.get("pitch_mm", float, positive=True, maximum=MAX_LENGTH_MM),) * 2
        lo, hi = sheet.min(axis=0), sheet.max(axis=0)
        center = g.points("", [g.get("center_mm", list, list(0.5 * (lo + hi)))], key=g.key("center_mm"))[0]
        _check_points(g, g.key("center_mm"), np.array([center]))
        radius = 0.0
        if shape == "rounded_square":
            radius = g.get("corner_radius_mm", float, positive=True)
            if radius > 0.5 * size:
                raise g.error("corner_radius_mm", f"{radius!r} exceeds half the size ({0.5 * size!r})")
        g.finish()
        layout = grid_layout(shape, rows, columns, size, pitch, center,
                             mesh.edge_length_outline_mm, radius)
        where = lambda j: g.prefix  # noqa: E731
    t.finish()
    try:
        check_layout(layout, sheet, min_gap)
    except GeometryError as exc:
        raise SceneError(t.path, where(exc.capacitor), str(exc)) from None
    return layout, min_gap


def _read_objects(root: Table, path: str) -> dict:
    """Glue objects (``[objects.*]``), read only when a scene has them."""
    t = root.table("objects", required=False)
    if t is None:
        return {}
    from mscap.scene.glue import read_objects

    return read_objects(t, path)


def _check_pose_geometry(path: str, poses: tuple, sheet: np.ndarray) -> None:
    """Every glued pose's object must cover the whole placed sheet; every ball must be
    centred over the sheet."""
    for i, pose in enumerate(poses):
        if pose.kind == "poke":
            lo, hi = sheet.min(axis=0), sheet.max(axis=0)
            x, y = pose.center_mm
            if not (lo[0] < x < hi[0] and lo[1] < y < hi[1]):
                raise SceneError(path, f"poses[{i}].center_mm",
                                 f"({x:g}, {y:g}) mm lies outside the sheet "
                                 f"[{lo[0]:g}, {hi[0]:g}] × [{lo[1]:g}, {hi[1]:g}] mm")
            diagonal = float(np.hypot(*(hi - lo)))
            if pose.depth_mm > diagonal:
                raise SceneError(path, f"poses[{i}].depth_mm", f"pose {pose.name!r}: {pose.depth_mm:g} mm is deeper "
                                 f"than the sheet's diagonal ({diagonal:g} mm)")
            if pose.radius_mm > MAX_LENGTH_MM:
                raise SceneError(path, f"poses[{i}].radius_mm", f"pose {pose.name!r}: must be <= "
                                 f"{MAX_LENGTH_MM:g} mm, got {pose.radius_mm!r}")
        if pose.kind == "glue":
            from mscap.bodies.glue import check_covers

            try:
                check_covers(pose, sheet)
            except GeometryError as exc:
                raise SceneError(path, f"poses[{i}]", str(exc)) from None


def _elastic_edge_under(pose_index: int, poses: tuple, mesh: MeshSettings, elastic: ElasticSettings
                        ) -> tuple[float, str]:
    """The largest elastic node spacing (mm) under poke ``poses[pose_index]``'s ball and the
    key that sets it: the elastic far edge, or the refinement zone's size where the zones
    reach the elastic mesh (the shared mesh, or an own P1 mesh); half of it for P2 (nodes
    on the edge midpoints)."""
    shared = elastic.mesh == "shared"
    edge, key = (mesh.edge_length_mm, "mesh.edge_length_mm") if shared else (elastic.edge_length_mm,
                                                                            "elastic.edge_length_mm")
    if mesh.zones and (shared or elastic.order == 1):
        pokes = [j for j, p in enumerate(poses) if p.kind == "poke"]
        zone = mesh.zones[pokes.index(pose_index)]
        if zone[3] < edge:
            edge, key = zone[3], "the refinement zone under the ball"
    return (edge / 2 if elastic.order == 2 else edge), key


def _check_balls(path: str, poses: tuple, mesh: MeshSettings, elastic: ElasticSettings) -> None:
    """Every poke's ball at least :data:`BALL_EDGE_RATIO` times the elastic node spacing
    under it: a smaller one passes between the nodes and leaves the sheet at rest."""
    for i, pose in enumerate(poses):
        if pose.kind == "poke":
            _check_ball(path, f"poses[{i}].radius_mm", pose.name, pose.radius_mm,
                        *_elastic_edge_under(i, poses, mesh, elastic))


def _check_ball(path: str, key: str, name: str, radius: float, spacing: float, source: str) -> None:
    if radius < BALL_EDGE_RATIO * spacing:
        largest = radius / BALL_EDGE_RATIO
        raise SceneError(path, key, f"pose {name!r}: a ball of radius {radius:g} mm passes between the elastic "
                         f"mesh's nodes, {spacing:g} mm apart under it ({source}); the radius must be at least "
                         f"{BALL_EDGE_RATIO:g} of that: refine the elastic mesh to a spacing of at most "
                         f"{largest:.3g} mm there, or set [mesh] signal_tolerance")


def _check_family_balls(path: str, poses: tuple, mesh: MeshSettings, elastic: ElasticSettings,
                        calibration: CalibrationSettings | None) -> None:
    """The ball check of :func:`_check_balls` on the smallest radius of a calibration
    family that varies a poke's ``radius_mm``."""
    if calibration is None or "radius_mm" not in calibration.parameters:
        return
    index = next(j for j, p in enumerate(poses) if p.name == calibration.pose)
    column = calibration.parameters.index("radius_mm")
    smallest = float(min(calibration.training[:, column].min(), calibration.sequence[:, column].min()))
    spacing, source = _elastic_edge_under(index, poses, mesh, elastic)
    _check_ball(path, "calibration.training.radius_mm", f"{calibration.pose} (family)", smallest, spacing, source)


def _check_elastic_budget(path: str, elastic: ElasticSettings) -> None:
    """``[elastic]`` counts: at least one Newton iteration, bounded cuts and slabs."""
    if not 1 <= elastic.max_iterations <= MAX_ITERATIONS:
        raise SceneError(path, "elastic.max_iterations", f"must lie in 1..{MAX_ITERATIONS}, got "
                         f"{elastic.max_iterations!r} (Newton iterations per load step; 0 could solve nothing)")
    if elastic.max_cuts > MAX_CUTS:
        raise SceneError(path, "elastic.max_cuts", f"must be <= {MAX_CUTS}, got {elastic.max_cuts!r} "
                         f"(2^-{MAX_CUTS} of a load step is below double precision)")
    if elastic.elements_through_thickness > MAX_SLABS:
        raise SceneError(path, "elastic.elements_through_thickness", f"must be <= {MAX_SLABS}, got "
                         f"{elastic.elements_through_thickness!r} (studied settings use 0-2)")
    for key in ("tolerance", "step_tolerance"):
        value = getattr(elastic, key)
        if not 0 < value < 1:
            raise SceneError(path, f"elastic.{key}", f"must lie in (0, 1), got {value!r} (a residual stress "
                             f"over μ: at 1 a load step converges with the residual as large as the stiffness)")


def _read_poses(root: Table, objects: dict) -> tuple:
    """The ``[[poses]]``. A name is taken in Unicode's composed form (NFC: ``café`` typed
    decomposed is the same name) and may not differ from another only by case: on a
    case-insensitive file system ``Stretch.vtu`` and ``stretch.vtu`` are one file."""
    poses, seen = [], {}
    for t in root.tables("poses", required=False):
        name = unicodedata.normalize("NFC", t.get("name", str))
        if len(name) > MAX_NAME_LENGTH or not re.fullmatch(POSE_NAME_PATTERN, name):
            raise t.error("name", f"{name!r:.80} cannot name a file (mscap simulate --export writes <pose>.vtu): "
                          f"use letters, digits, '_', '-', '+', '.' and inner spaces, starting with a letter "
                          f"or digit, at most {MAX_NAME_LENGTH} characters")
        if name in seen.values():
            raise t.error("name", f"duplicate pose name {name!r}")
        if name.casefold() in seen:
            raise t.error("name", f"pose name {name!r} differs from {seen[name.casefold()]!r} only by case: their "
                          f"files (mscap simulate --export) are one on a case-insensitive file system")
        seen[name.casefold()] = name
        kind = t.get("kind", str)
        if kind not in POSE_KINDS:
            raise t.error("kind", f"unknown pose kind {kind!r}; expected one of {', '.join(POSE_KINDS)}")
        pose = read_pose(t, objects)
        poses.append(pose if pose.name == name else replace(pose, name=name))
    return tuple(poses)


def _objective_defaults(optimizer: OptimizerSettings, given: dict, calibration) -> OptimizerSettings:
    """A scene with a ``[calibration]`` designs for read-back unless its ``[optimizer]``
    says otherwise: ``distance = "reconstruction"`` on ``design_poses = "family"``
    (docs/results.md, "Designing for read-back", measured it against the paper's pF
    objective on every calibrated scene). Without one, the paper's ``"pF"`` on the
    listed poses."""
    if calibration is None or "distance" in given or given.get("design_poses") == "listed":
        return optimizer
    return replace(optimizer, distance="reconstruction",
                   design_poses=given.get("design_poses", "family"))


def _read_dataclass(t: Table | None, cls):
    if t is None:
        return cls()
    values = {}
    hints = typing.get_type_hints(cls)
    for field, default in cls().__dict__.items():
        kind = type(default) if default is not None else typing.get_args(hints[field])[0]
        if kind is tuple:
            values[field] = t.integers(field, default)
            continue
        values[field] = t.get(field, kind, default, minimum=0 if kind in (int, float) else None)
    t.finish()
    return cls(**values)


def _read_petsc(t: Table | None) -> tuple[tuple[str, str], ...]:
    if t is None:
        return ()
    options = []
    for key, value in t.data.items():
        if isinstance(value, bool):
            value = "true" if value else "false"
        elif isinstance(value, (int, float, str)):
            value = str(value)
        else:
            raise t.error(key, f"expected a string, number or boolean, got {value!r}")
        option = key.lstrip("-")
        kind = next((kind for kind in PETSC_TYPES if option == kind or option.endswith("_" + kind)), None)
        if kind is not None and value not in PETSC_TYPES[kind]:
            close = difflib.get_close_matches(value, PETSC_TYPES[kind], n=1, cutoff=0.75)
            hint = f"did you mean {close[0]!r}?" if close else f"PETSc knows {', '.join(PETSC_TYPES[kind])}"
            raise t.error(key, f"unknown {kind.replace('_', ' ')} {value!r}; {hint}")
        options.append((option, value))
    return tuple(options)


def _one_of(path: str, key: str, value, allowed: tuple) -> None:
    if value not in allowed:
        raise SceneError(path, key, f"unknown value {value!r}; expected one of {', '.join(allowed)}")


def check_optimizer(path: str, optimizer: OptimizerSettings, calibration: CalibrationSettings | None) -> None:
    """Check ``[optimizer]`` against itself and the scene's ``[calibration]``."""
    _one_of(path, "optimizer.skinning", optimizer.skinning, SKINNING_METHODS)
    _one_of(path, "optimizer.distance", optimizer.distance, DISTANCES)
    for key in ("control_spacing_mm", "first_step_mm", "max_step_mm", "tau_pF2", "tau_noise", "tau_mm"):
        if not getattr(optimizer, key) > 0:
            raise SceneError(path, f"optimizer.{key}", f"must be > 0, got {getattr(optimizer, key)!r}")
    for key, lo, hi, why in (("max_iterations", 1, MAX_ITERATIONS, "L-BFGS steps per level; 0 designs nothing"),
                             ("cascade_levels", 0, MAX_CASCADE_LEVELS, "each doubles the control points"),
                             ("control_spacing_mm", MIN_LENGTH_MM, MAX_LENGTH_MM, "1 µm to 10 m"),
                             ("remesh_angle_deg", 0, 60, "no triangle has a smallest angle above 60°"),
                             ("min_feature_mm", 0, MAX_LENGTH_MM, "a plate's narrowest neck or slot; 0: no limit"),
                             ("stall_window", 0, MAX_ITERATIONS, "accepted steps; 0 turns the plateau rule off")):
        value = getattr(optimizer, key)
        if not lo <= value <= hi:
            raise SceneError(path, f"optimizer.{key}", f"must lie in [{lo:g}, {hi:g}], got {value!r} ({why})")
    mode = optimizer.design_poses
    _one_of(path, "optimizer.design_poses", mode, DESIGN_POSES)
    if mode != "listed":
        if calibration is None:
            raise SceneError(path, "optimizer.design_poses",
                             f"{mode!r} takes poses from the [calibration] family, and this scene has none")
        family_grid_counts(path, optimizer, calibration)
    elif optimizer.distance in ("reconstruction", "readback"):
        raise SceneError(path, "optimizer.design_poses",
                         f'distance = "{optimizer.distance}" needs poses from the calibration family: '
                         'set design_poses = "family" or "both"')
    if optimizer.distance == "readback" and calibration is not None and calibration.kernel != "thin_plate_spline":
        raise SceneError(path, "optimizer.distance",
                         f'"readback" differentiates the calibration map\'s noise for the thin-plate spline only; '
                         f'[calibration] kernel is {calibration.kernel!r} (use "reconstruction", or that kernel)')


def family_grid_counts(path: str, optimizer: OptimizerSettings, calibration: CalibrationSettings) -> tuple[int, ...]:
    """Grid points per calibration parameter of the design family (``family_grid``: one
    count for all parameters or one each, default :data:`DEFAULT_FAMILY_COUNT`), each
    at least 2 and at most the points of that parameter's training axis."""
    n = len(calibration.parameters)
    counts = optimizer.family_grid or (DEFAULT_FAMILY_COUNT,) * n
    if len(counts) == 1:
        counts = counts * n
    if len(counts) != n or not all(isinstance(c, int) and c >= 2 for c in counts):
        raise SceneError(path, "optimizer.family_grid",
                         f"expected one count >= 2, or one per calibration parameter "
                         f"({', '.join(calibration.parameters)}), got {list(optimizer.family_grid)!r}")
    training = np.asarray(calibration.training)
    for i, (name, count) in enumerate(zip(calibration.parameters, counts)):
        size = len(np.unique(training[:, i]))
        if count > size:
            raise SceneError(path, "optimizer.family_grid",
                             f"{count} points along {name!r}, whose training axis has only {size}")
    return tuple(counts)


#: ``[multistart] prune_rule``: successive halving on ranks, or the envelope of finished paths.
PRUNE_RULES = ("rungs", "envelope")
#: Steps between the envelope rule's checkpoints for ``--prune envelope``.
ENVELOPE_EVERY = 5


#: Cells of a routing grid (``[fabrication] grid_mm``): 4 million bytes per boolean mask; the
#: quick scenes route on 10-30 thousand.
MAX_GRID_CELLS = 4_000_000


def routing_grid_mm(fabrication: FabricationSettings) -> float:
    """The routing grid's cell (mm): ``grid_mm``, or the pad pitch over the smallest
    whole number, at least 5, that makes it at most half the trace width (so the pad axes
    fall on cell centres: 2.54 / 6 = 0.423 mm by default)."""
    if fabrication.grid_mm > 0:
        return fabrication.grid_mm
    return fabrication.pad_pitch_mm / max(5, math.ceil(fabrication.pad_pitch_mm / (fabrication.trace_width_mm / 2)))


def check_fabrication(path: str, fabrication: FabricationSettings, sheet: np.ndarray) -> None:
    """Check ``[fabrication]``: lengths within [1 µm, 10 m] (the optional ones may be 0),
    a fillet a lead can hold, pads wider than their leads and apart by the clearance, a
    routing grid the machine can hold (:data:`MAX_GRID_CELLS`)."""
    f = fabrication
    for key in ("trace_width_mm", "clearance_mm", "edge_distance_mm", "pad_width_mm", "pad_length_mm",
                "pad_pitch_mm", "min_radius_mm", "mask_margin_mm", "grid_mm"):
        value = getattr(f, key)
        optional = key in ("min_radius_mm", "mask_margin_mm", "grid_mm")
        if optional and value == 0:
            continue
        if not MIN_LENGTH_MM <= value <= MAX_LENGTH_MM:
            raise SceneError(path, f"fabrication.{key}", f"must lie in [{MIN_LENGTH_MM:g}, {MAX_LENGTH_MM:g}] mm"
                             f"{' (or 0)' if optional else ''}, got {value!r}")
    if f.min_radius_mm > f.trace_width_mm / 2:
        raise SceneError(path, "fabrication.min_radius_mm", f"must be at most half the trace width "
                         f"({f.trace_width_mm / 2:g} mm): a lead {f.trace_width_mm:g} mm wide cannot bend with a "
                         f"{f.min_radius_mm:g} mm fillet on both sides, got {f.min_radius_mm!r}")
    if f.pad_width_mm < f.trace_width_mm:
        raise SceneError(path, "fabrication.pad_width_mm", f"must be at least the trace width "
                         f"({f.trace_width_mm:g} mm), got {f.pad_width_mm!r}")
    if f.pad_pitch_mm < f.pad_width_mm + f.clearance_mm:
        raise SceneError(path, "fabrication.pad_pitch_mm", f"must be at least pad_width_mm + clearance_mm "
                         f"= {f.pad_width_mm + f.clearance_mm:g} mm (neighbouring pads are other nets), "
                         f"got {f.pad_pitch_mm!r}")
    _one_of(path, "fabrication.connector_edge", f.connector_edge, CONNECTOR_EDGES)
    if not 1 <= f.assignments <= MAX_STARTS_PER_K:
        raise SceneError(path, "fabrication.assignments",
                         f"must be in 1..{MAX_STARTS_PER_K} (slot assignments to route), got {f.assignments!r}")
    for key in ("rows", "columns"):
        if getattr(f, key) > MAX_CAPACITORS:
            raise SceneError(path, f"fabrication.{key}", f"must be in 0..{MAX_CAPACITORS}, got {getattr(f, key)!r}")
    h = routing_grid_mm(f)
    if f.grid_mm > f.trace_width_mm / 2:
        raise SceneError(path, "fabrication.grid_mm", f"must be at most half the trace width "
                         f"({f.trace_width_mm / 2:g} mm), got {f.grid_mm!r}")
    extent = np.ptp(sheet, axis=0)
    cells = float(np.prod(np.ceil(extent / h) + 1))
    if cells > MAX_GRID_CELLS:
        key = "fabrication.grid_mm" if f.grid_mm else "fabrication.trace_width_mm"
        raise SceneError(path, key, f"a {h:g} mm routing grid over the {extent[0]:g} x {extent[1]:g} mm sheet has "
                         f"{cells:.3g} cells, more than {MAX_GRID_CELLS:,}; set a coarser fabrication.grid_mm")


def check_multistart(path: str, multistart: MultistartSettings) -> None:
    """Check ``[multistart]``: k_min ≤ k_max, starts per k within the seed scheme, a
    pruning ratio of at least 2."""
    if multistart.k_min < 2:
        raise SceneError(path, "multistart.k_min", f"must be >= 2, got {multistart.k_min!r} (the multi-start "
                         f"designs arrays of capacitors; k = 0 has no layout to start from)")
    if multistart.k_min > multistart.k_max:
        raise SceneError(path, "multistart.k_min", f"k_min = {multistart.k_min} exceeds k_max = {multistart.k_max}")
    if multistart.k_max > MAX_CAPACITORS:
        raise SceneError(path, "multistart.k_max", f"must be <= {MAX_CAPACITORS}, got {multistart.k_max!r} "
                         f"(each capacitor costs one electrostatic solve per pose)")
    if not 1 <= multistart.starts_per_k < MAX_STARTS_PER_K:
        raise SceneError(path, "multistart.starts_per_k",
                         f"must be in 1..{MAX_STARTS_PER_K - 1}, got {multistart.starts_per_k!r}")
    if not 0 <= multistart.lloyd_fraction <= 1:
        raise SceneError(path, "multistart.lloyd_fraction", f"must lie in [0, 1], got {multistart.lloyd_fraction!r}")
    if not 0 <= multistart.sensitivity_fraction <= 1:
        raise SceneError(path, "multistart.sensitivity_fraction",
                         f"must lie in [0, 1], got {multistart.sensitivity_fraction!r}")
    if not 0 <= multistart.checkpoint_minutes <= 10080:
        raise SceneError(path, "multistart.checkpoint_minutes", f"must lie in [0, 10080] (minutes between two "
                         f"stored states of a busy start; 0: only when the job stops), got "
                         f"{multistart.checkpoint_minutes!r}")
    if multistart.seed > MAX_SEED:
        raise SceneError(path, "multistart.seed", f"must be <= {MAX_SEED}, got {multistart.seed!r}")
    if multistart.prune_rule not in PRUNE_RULES:
        raise SceneError(path, "multistart.prune_rule",
                         f"must be one of {', '.join(map(repr, PRUNE_RULES))}, got {multistart.prune_rule!r}")
    if multistart.calibrate_best > MAX_STARTS_PER_K:
        raise SceneError(path, "multistart.calibrate_best", f"must be in 0..{MAX_STARTS_PER_K} (runs per k to "
                         f"calibrate; 0: choose by the objective alone), got {multistart.calibrate_best!r}")
    if not 1 <= multistart.calibrate_seeds <= MAX_CALIBRATE_SEEDS:
        raise SceneError(path, "multistart.calibrate_seeds", f"must be in 1..{MAX_CALIBRATE_SEEDS} (noise seeds "
                         f"of the in-run calibration), got {multistart.calibrate_seeds!r}")
    if multistart.prune_first_step > 0 and multistart.prune_rule == "rungs" and multistart.prune_eta < 2:
        raise SceneError(path, "multistart.prune_eta",
                         f"must be at least 2 when prune_first_step > 0 (keep the best 1/eta), "
                         f"got {multistart.prune_eta!r}")


def read_multistart(data: dict, path: str) -> MultistartSettings:
    """``[multistart]`` from its TOML table ``data`` (e.g. a stored scene's), checked."""
    multistart = _read_dataclass(Table(path, "multistart", data), MultistartSettings)
    check_multistart(path, multistart)
    return multistart


def check_designable(scene: Scene, poses=None) -> None:
    """What designing a scene needs beyond loading it: valid ``[optimizer]`` settings
    (also for a scene whose settings were replaced in code) and at least two design poses
    (``poses``, default the scene's)."""
    check_optimizer(scene.path, scene.optimizer, scene.calibration)
    poses = scene.poses if poses is None else poses
    if len(poses) < 2:
        raise SceneError(scene.path, "poses", f"the design objective compares poses: need at least 2, "
                         f"got {len(poses)}")


def select_poses(scene: Scene, names: list[str]) -> Scene:
    """``scene`` with only the poses named (in the scene's order); an unknown name is a
    :class:`SceneError` listing the scene's poses."""
    known = [p.name for p in scene.poses]
    unknown = [name for name in names if name not in known]
    if unknown:
        raise SceneError(scene.path, "poses", f"no pose named {unknown[0]!r}; the scene has {', '.join(known)}")
    return replace(scene, poses=tuple(p for p in scene.poses if p.name in names))


def with_overrides(scene: Scene, starts_per_k: int | None = None, prune: str | None = None,
                   keep_repeated_starts: bool = False, check_all_runs: bool = False,
                   calibrate_best: int | None = None) -> Scene:
    """``scene`` with ``[multistart]`` values from the command line (``mscap run
    --starts-per-k N --prune STEP:ETA --keep-repeated-starts --check-all-runs
    --calibrate-best N``; ``--prune envelope[:EVERY]`` for the envelope rule), checked like
    the file's."""
    changes = {}
    if calibrate_best is not None:
        if calibrate_best < 0:
            raise SceneError(scene.path, "multistart.calibrate_best",
                             f"must be >= 0, got {calibrate_best} (--calibrate-best)")
        changes["calibrate_best"] = calibrate_best
    if keep_repeated_starts:
        changes["skip_repeated_starts"] = False
    if check_all_runs:
        changes["check_all_runs"] = True
    if starts_per_k is not None:
        changes["starts_per_k"] = starts_per_k
    if prune is not None:
        first, _, eta = prune.partition(":")
        try:
            if first == "envelope":
                changes["prune_rule"] = "envelope"
                changes["prune_first_step"] = int(eta) if eta else ENVELOPE_EVERY
            else:
                changes["prune_rule"] = "rungs"
                changes["prune_first_step"] = int(first)
                if eta:
                    changes["prune_eta"] = int(eta)
        except ValueError:
            raise SceneError(scene.path, "multistart.prune_first_step",
                             f"--prune expects STEP, STEP:ETA or envelope:EVERY (integers), got {prune!r}") from None
        if changes["prune_first_step"] < 0:
            raise SceneError(scene.path, "multistart.prune_first_step",
                             f"must be >= 0, got {changes['prune_first_step']} (--prune {prune})")
    if not changes:
        return scene
    multistart = replace(scene.multistart, **changes)
    check_multistart(scene.path, multistart)
    return replace(scene, multistart=multistart)
