"""Scene files: reading a TOML scene into a :class:`~mscap.scene.settings.Scene`, with every
check of every table in one place.

Every bad value raises :class:`~mscap.errors.SceneError` naming the file, the key and
the value. :func:`check_optimizer` and :func:`check_multistart` are also what code
that builds settings itself (tests, a stored scene) calls.
"""

from __future__ import annotations

import logging
import tomllib
import typing
from dataclasses import replace
from pathlib import Path

import numpy as np

from mscap.errors import GeometryError, SceneError
from mscap.geometry import polygons as geometry
from mscap.geometry.layout import SHAPES, Layout, check_layout, grid_layout
from mscap.scene import sizing
from mscap.scene._toml import Table
from mscap.scene.calibration import CalibrationSettings, read_calibration
from mscap.scene.poses import read_pose
from mscap.scene.settings import (DEFAULT_FAMILY_COUNT, DESIGN_POSES, DISTANCES, ELASTIC_MESHES, HESSIAN_MODES,
                                  LAYER_KINDS, MAX_STARTS_PER_K, POSE_KINDS, SKINNING_METHODS, ElasticSettings,
                                  Layer, Material, MeshSettings, MultistartSettings, OptimizerSettings, Scene,
                                  auto_slabs)

__all__ = ["load_scene", "check_optimizer", "check_multistart", "check_designable", "family_grid_counts",
           "read_multistart", "select_poses", "with_overrides"]

log = logging.getLogger(__name__)


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene file.

    Raises
    ------
    SceneError
        On any unreadable, unknown, missing, mistyped or out-of-range entry.
    """
    path = str(path)
    try:
        source = Path(path).read_text()
    except OSError as exc:
        raise SceneError(path, "", f"cannot read scene file ({exc.strerror})") from None
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
    mesh = _read_mesh(mesh_table, layers)
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
    if "elements_through_thickness" not in data.get("elastic", {}):
        elastic = replace(elastic, elements_through_thickness=auto_slabs(layers))
    elastic = _elastic_for_signal(mesh, elastic, poses, data.get("elastic", {}))
    if elastic.order not in (1, 2):
        raise SceneError(path, "elastic.order", f"must be 1 or 2, got {elastic.order!r}")
    if not elastic.tolerance > 0:
        raise SceneError(path, "elastic.tolerance", f"must be > 0, got {elastic.tolerance!r}")
    if elastic.mesh not in ELASTIC_MESHES:
        raise SceneError(path, "elastic.mesh",
                         f"unknown value {elastic.mesh!r}; expected one of {', '.join(ELASTIC_MESHES)}")
    for key in ("edge_length_mm", "edge_length_outline_mm"):
        value = getattr(elastic, key)
        if value is not None and not value > 0:
            raise SceneError(path, f"elastic.{key}", f"must be > 0, got {value!r}")
    if elastic.hessian not in HESSIAN_MODES:
        raise SceneError(path, "elastic.hessian",
                         f"unknown value {elastic.hessian!r}; expected one of {', '.join(HESSIAN_MODES)}")
    optimizer = _read_dataclass(root.table("optimizer", required=False), OptimizerSettings)
    multistart = _read_dataclass(root.table("multistart", required=False), MultistartSettings)
    check_multistart(path, multistart)
    petsc = _read_petsc(root.table("petsc", required=False))
    calibration = read_calibration(root.table("calibration", required=False), poses)
    optimizer = _objective_defaults(optimizer, data.get("optimizer", {}), calibration)
    check_optimizer(path, optimizer, calibration)
    root.finish()
    sheet.setflags(write=False)
    return Scene(path=path, name=name, description=description, sheet_outline_mm=sheet,
                 layers=layers, layout=layout, min_gap_mm=min_gap, mesh=mesh, poses=poses, elastic=elastic,
                 optimizer=optimizer, multistart=multistart, petsc_options=petsc, source=source,
                 calibration=calibration)


def _read_sheet(t: Table) -> np.ndarray:
    if t.has("outline_mm"):
        outline = np.array(t.points("outline_mm"))
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
        w = t.get("width_mm", float, positive=True)
        h = t.get("height_mm", float, positive=True)
        outline = np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])
    t.finish()
    return geometry.ccw(outline)


def _read_materials(t: Table) -> dict[str, Material]:
    materials = {}
    for name in t.data:
        m = t.table(name)
        e = m.get("youngs_modulus_MPa", float, positive=True)
        nu = m.get("poisson_ratio", float)
        if not -1.0 < nu < 0.5:
            raise m.error("poisson_ratio", f"must lie in (-1, 0.5), got {nu!r}")
        eps_r = m.get("relative_permittivity", float)
        if eps_r < 1.0:
            raise m.error("relative_permittivity", f"must be >= 1, got {eps_r!r}")
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
        fill = _material(t, "fill", materials) if kind == "conductive" else None
        layers.append(Layer(t.get("name", str), kind, thickness, _material(t, "material", materials), fill))
        t.finish()
    return tuple(layers)


#: The [mesh] keys that set sizes by hand; a scene that gives all three and no tolerance
#: is meshed as given.
SIZE_KEYS = ("edge_length_mm", "edge_length_outline_mm", "grading_distance_mm")


def _read_mesh(t: Table, layers: tuple[Layer, ...]) -> MeshSettings:
    """``[mesh]`` as given; without all three sizes (or with a ``tolerance``), sized from the
    tolerance later (:func:`_size_mesh`), here with placeholders the given keys replace."""
    by_hand = all(t.has(key) for key in SIZE_KEYS) and not t.has("tolerance")
    tolerance = None
    if not by_hand:
        tolerance = t.get("tolerance", float, sizing.DEFAULT_TOLERANCE, positive=True)
        if not tolerance < 1:
            raise t.error("tolerance", f"a relative capacitance error, must be < 1, got {tolerance!r}")
    gap = layers[2].thickness_mm
    far = t.get("edge_length_mm", float, ... if by_hand else sizing.FAR_EDGE_MM, positive=True)
    near = t.get("edge_length_outline_mm", float, ... if by_hand else min(gap, far), positive=True)
    if near > far:
        raise t.error("edge_length_outline_mm", f"{near!r} exceeds edge_length_mm = {far!r}")
    grading = t.get("grading_distance_mm", float, ... if by_hand else far / sizing.STEEP, positive=True)
    per_layer = t.get("elements_per_layer", int, 1, minimum=1)
    order = t.get("order", int, 1)
    if order not in (1, 2):
        raise t.error("order", f"must be 1 or 2, got {order!r}")
    signal = t.get("signal_tolerance", float, None, positive=True)
    if signal is not None and not signal < 1:
        raise t.error("signal_tolerance", f"a relative error of the pose-to-pose gains, must be < 1, got {signal!r}")
    t.finish()
    return MeshSettings(far, near, grading, per_layer, order, tolerance, signal_tolerance=signal)


def _size_mesh(t: Table, given: MeshSettings, layers: tuple[Layer, ...], layout: Layout) -> MeshSettings:
    """The ladder's cheapest settings for the tolerance on the layout's plates; keys the
    scene gives win over the ladder's."""
    keys = SIZE_KEYS + ("elements_per_layer", "order")
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
    edge the scene's ``[elastic]`` gives wins (an order restricts the choice to its rungs)."""
    if mesh.signal_tolerance is None:
        return elastic
    chosen = sizing.elastic_for_signal(mesh.signal_tolerance, poses, given.get("order"))
    if chosen is None:
        return elastic
    rung, edge = chosen
    log.info("elastic mesh for signal tolerance %g: P%d, %.3g mm (%.3g R; measured gain error %.2g)",
             mesh.signal_tolerance, rung.order, edge, rung.edge_over_radius, rung.gain_error)
    return replace(elastic, order=given.get("order", rung.order), edge_length_mm=given.get("edge_length_mm", edge))


def _read_capacitors(t: Table, sheet: np.ndarray, mesh: MeshSettings) -> tuple[Layout, float]:
    min_gap = t.get("min_gap_mm", float, 1.0, minimum=0.0)
    if t.has("outlines_mm") == t.has("grid"):
        raise t.error("outlines_mm", "give exactly one of 'outlines_mm' (explicit polygons) "
                      "or a [capacitors.grid] table")
    if t.has("outlines_mm"):
        polygons = t.get("outlines_mm", list)
        if not polygons:
            raise t.error("outlines_mm", "no capacitors given")
        layout = Layout(tuple(np.array(t.points("", p, key=f"{t.key('outlines_mm')}[{j}]"))
                              for j, p in enumerate(polygons)))
        where = lambda j: t.key("outlines_mm") + ("" if j is None else f"[{j}]")  # noqa: E731
    else:
        g = t.table("grid")
        shape = g.get("shape", str)
        if shape not in SHAPES:
            raise g.error("shape", f"unknown shape {shape!r}; expected one of {', '.join(SHAPES)}")
        rows = g.get("rows", int, minimum=1)
        columns = g.get("columns", int, minimum=1)
        size = g.get("size_mm", float, positive=True)
        if isinstance(g.data.get("pitch_mm"), list):
            pitch = tuple(g.get("pitch_mm", list))
            if len(pitch) != 2 or not all(isinstance(p, (int, float)) and p > 0 for p in pitch):
                raise g.error("pitch_mm", f"expected a positive number or [px, py], got {list(pitch)!r}")
        else:
            pitch = (g.get("pitch_mm", float, positive=True),) * 2
        lo, hi = sheet.min(axis=0), sheet.max(axis=0)
        center = g.points("", [g.get("center_mm", list, list(0.5 * (lo + hi)))], key=g.key("center_mm"))[0]
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
    from mscap.bodies.glue import read_objects

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
        if pose.kind == "glue":
            from mscap.bodies.glue import check_covers

            try:
                check_covers(pose, sheet)
            except GeometryError as exc:
                raise SceneError(path, f"poses[{i}]", str(exc)) from None


def _read_poses(root: Table, objects: dict) -> tuple:
    poses, seen = [], set()
    for t in root.tables("poses", required=False):
        name = t.get("name", str)
        if name in seen:
            raise t.error("name", f"duplicate pose name {name!r}")
        seen.add(name)
        kind = t.get("kind", str)
        if kind not in POSE_KINDS:
            raise t.error("kind", f"unknown pose kind {kind!r}; expected one of {', '.join(POSE_KINDS)}")
        poses.append(read_pose(t, objects))
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
        options.append((key.lstrip("-"), value))
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
    mode = optimizer.design_poses
    _one_of(path, "optimizer.design_poses", mode, DESIGN_POSES)
    if mode != "listed":
        if calibration is None:
            raise SceneError(path, "optimizer.design_poses",
                             f"{mode!r} takes poses from the [calibration] family, and this scene has none")
        family_grid_counts(path, optimizer, calibration)
    elif optimizer.distance == "reconstruction":
        raise SceneError(path, "optimizer.design_poses",
                         'distance = "reconstruction" needs poses from the calibration family: '
                         'set design_poses = "family" or "both"')


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


def check_multistart(path: str, multistart: MultistartSettings) -> None:
    """Check ``[multistart]``: k_min ≤ k_max, starts per k within the seed scheme, a
    pruning ratio of at least 2."""
    if multistart.k_min > multistart.k_max:
        raise SceneError(path, "multistart.k_min", f"k_min = {multistart.k_min} exceeds k_max = {multistart.k_max}")
    if not 0 <= multistart.starts_per_k < MAX_STARTS_PER_K:
        raise SceneError(path, "multistart.starts_per_k",
                         f"must be in 0..{MAX_STARTS_PER_K - 1}, got {multistart.starts_per_k!r}")
    if multistart.prune_first_step > 0 and multistart.prune_eta < 2:
        raise SceneError(path, "multistart.prune_eta",
                         f"must be at least 2 when prune_first_step > 0 (keep the best 1/eta), "
                         f"got {multistart.prune_eta!r}")


def read_multistart(data: dict, path: str) -> MultistartSettings:
    """``[multistart]`` from its TOML table ``data`` (e.g. a stored scene's), checked."""
    multistart = _read_dataclass(Table(path, "multistart", data), MultistartSettings)
    check_multistart(path, multistart)
    return multistart


def check_designable(scene: Scene) -> None:
    """What designing a scene needs beyond loading it: valid ``[optimizer]`` settings
    (also for a scene whose settings were replaced in code) and at least two poses."""
    check_optimizer(scene.path, scene.optimizer, scene.calibration)
    if len(scene.poses) < 2:
        raise SceneError(scene.path, "poses", f"the design objective compares poses: need at least 2, "
                         f"got {len(scene.poses)}")


def select_poses(scene: Scene, names: list[str]) -> Scene:
    """``scene`` with only the poses named (in the scene's order); an unknown name is a
    :class:`SceneError` listing the scene's poses."""
    known = [p.name for p in scene.poses]
    unknown = [name for name in names if name not in known]
    if unknown:
        raise SceneError(scene.path, "poses", f"no pose named {unknown[0]!r}; the scene has {', '.join(known)}")
    return replace(scene, poses=tuple(p for p in scene.poses if p.name in names))


def with_overrides(scene: Scene, starts_per_k: int | None = None, prune: str | None = None,
                   keep_repeated_starts: bool = False) -> Scene:
    """``scene`` with ``[multistart]`` values from the command line (``mscap run
    --starts-per-k N --prune STEP:ETA --keep-repeated-starts``), checked like the file's."""
    changes = {}
    if keep_repeated_starts:
        changes["skip_repeated_starts"] = False
    if starts_per_k is not None:
        changes["starts_per_k"] = starts_per_k
    if prune is not None:
        first, _, eta = prune.partition(":")
        try:
            changes["prune_first_step"] = int(first)
            if eta:
                changes["prune_eta"] = int(eta)
        except ValueError:
            raise SceneError(scene.path, "multistart.prune_first_step",
                             f"--prune expects STEP or STEP:ETA (integers), got {prune!r}") from None
        if changes["prune_first_step"] < 0:
            raise SceneError(scene.path, "multistart.prune_first_step", f"must be >= 0, got {first!r}")
    if not changes:
        return scene
    multistart = replace(scene.multistart, **changes)
    check_multistart(scene.path, multistart)
    return replace(scene, multistart=multistart)
