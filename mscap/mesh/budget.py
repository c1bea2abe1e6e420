"""How large a mesh will be, before gmsh starts: vertices, tets, unknowns and the peak
memory of a simulation on it, from the scene's numbers alone (arithmetic on a few hundred
floats, under a millisecond, whatever the sizes asked for; nothing of the mesh's size is
allocated).

A mesh whose estimate exceeds the memory this machine has (its physical memory) or the limit ``MSCAP_MAX_MEMORY_GB`` (the command line's
``--max-memory-gb``) is refused with one line naming the scene keys that drive it, instead
of gmsh eating gigabytes and failing with an empty reason, or numpy asking for 10 GiB.

The count. gmsh's Frontal-Delaunay makes triangles of about the local target edge h, so
a sheet takes ``KAPPA ∫ h⁻² dA`` triangles. h depends on the distance d to the nearest
plate outline (the Threshold fields of :mod:`mscap.mesh.triangulate`), so the integral
runs over d with the area at distance d: inside k plates of total area A and perimeter P,
``P − 2πk d`` per unit d until the plates are used up (exact for discs); outside them
``P + 2πk d`` until the rest of the sheet is; beyond the ramp the far edge. gmsh does not
follow a steep ramp: the edges grow at most :data:`MAX_GROWTH` mm per mm. A refinement
zone adds its disc of small edges. The 2D vertices are half the triangles (Euler), the
extrusion multiplies by levels and slabs (3 tets per prism), P2 adds a node per edge.
:data:`KAPPA` and :data:`MAX_GROWTH` are fitted (minimax) on the 44 meshes of the 15 shipped
scenes and of the paper scenes' finer-mesh checks: every tet count within ±28 %
(docs/size_estimate.csv).

The memory: the larger of two straight lines fitted on the shipped scenes
(``benchmarks/size_estimate.py``; docs/performance.md, "Size estimate before meshing"):
the mesh with its quality report (``mscap mesh``), :data:`MESH_BASE_BYTES` +
:data:`BYTES_PER_TET` per tet, which is the larger for P1; and a solve on it,
:data:`BASE_BYTES` (interpreter, numpy, PETSc) + :data:`BYTES_PER_UNKNOWN` per unknown of
its linear system (``mscap capacitance``; the elastic rate is three times the
electrostatic one: a node's row holds three times the entries).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from mscap.errors import MeshError, SceneError
from mscap.geometry import polygons as geometry
from mscap.mesh.triangulate import quality_grading_mm
from mscap.scene.settings import MAX_CAPACITORS

if TYPE_CHECKING:
    from mscap.scene.settings import ElasticSettings, MeshSettings, Sheet

__all__ = ["SizeEstimate", "estimate_mesh", "estimate_electrostatic", "estimate_elastic", "check_meshes",
           "check_fits", "memory_limit", "check_capacitor_count", "MEMORY_ENV", "MAX_CAPACITORS", "KAPPA",
           "BYTES_PER_UNKNOWN", "BASE_BYTES", "BYTES_PER_TET", "MESH_BASE_BYTES", "MAX_GROWTH"]

#: The environment variable that sets the memory limit (GB); ``--max-memory-gb`` sets it.
MEMORY_ENV = "MSCAP_MAX_MEMORY_GB"
#: Triangles per unit of ∫ h⁻² dA; fitted (benchmarks/size_estimate.py). Equilateral
#: triangles of edge h would give 4/√3 = 2.31: gmsh's edges average 0.75 of the target
#: (0.84 before the quality bounds of mscap.mesh.triangulate refined corners and strips:
#: 3.27 then).
KAPPA = 4.10
#: The same inside the refinement zones and strips, which are away from outline corners
#: and narrow strips: equilateral triangles of edge h, 4/√3. With KAPPA there the P2
#: elastic mesh of jobs/quick.toml, refined under its two balls and along its held edges,
#: was estimated 1.40 times its size; with this 0.97 times.
ZONE_KAPPA = 4 / 3 ** 0.5
#: The fastest a Frontal-Delaunay mesh grows its edges away from a fine line (mm per mm):
#: asked for a ramp of 2 (0.075 → 5 mm over 2.5 mm), gmsh keeps edges smaller; fitted with KAPPA.
MAX_GROWTH = 1.1
#: Peak resident bytes of ``mscap mesh`` per tet and on an empty mesh (least squares over
#: the 15 shipped scenes, docs/size_estimate.csv).
BYTES_PER_TET = 1.1e3
MESH_BASE_BYTES = 70e6
#: Peak resident bytes of a solve per unknown of its system, by (problem, element order),
#: and of a solve on an empty mesh (``mscap capacitance``, P1 on the 15 scenes, P2 on the
#: 8 quick ones, docs/size_estimate.csv; elastic: 3 x, assumed, see the module docstring).
#: Electrostatic P2: 2.4e3 covers MUMPS too (-electro_pc_factor_mat_solver_type mumps:
#: 2,408 B refitted on 2026-12-04, CHOLMOD 2.2e3; P1 1,856 B, within 3 % of 1.8e3).
BYTES_PER_UNKNOWN = {("electrostatic", 1): 1.8e3, ("electrostatic", 2): 2.4e3,
                     ("elastic", 1): 5.4e3, ("elastic", 2): 6.6e3}
BASE_BYTES = 140e6
#: Growth of the edge length away from a refinement zone (mm per mm), as in triangulate.ZONE_SLOPE.
_ZONE_SLOPE = 0.5
#: Quadrature points over the distance from the outlines.
_POINTS = 256


@dataclass(frozen=True)
class SizeEstimate:
    """What a mesh will cost. ``problem``: ``"electrostatic"`` or ``"elastic"``;
    counts are floats (an estimate; inf when the sizes overflow); ``memory_bytes``: the
    peak of a simulation on it; ``drivers``: the scene keys and values that set the count,
    the largest contribution first."""

    problem: str
    triangles: float
    vertices: float
    tets: float
    unknowns: float
    memory_bytes: float
    drivers: tuple[str, ...]


def _positive(value, key: str, path: str) -> np.float64:
    """``value`` as a finite positive float64 (overflows to inf, never raises), else the
    one-line error naming ``key``."""
    try:
        number = np.float64(value)
    except (TypeError, ValueError, OverflowError):
        number = np.float64("nan")
    if not (np.isfinite(number) and number > 0):
        raise MeshError(f"{path}: cannot size the mesh: {key} = {value!r} is not a positive finite number")
    return number


def _sizes(d: np.ndarray, near: float, far: float, grading: float, fringe: float, slope: float) -> np.ndarray:
    """The target edge at distance ``d`` from the outlines (triangulate's Threshold fields)."""
    def ramp(start, stop):
        return near + (far - near) * np.clip((d - start) / max(stop - start, 1e-300), 0.0, 1.0)
    if fringe <= 0:
        target = ramp(0.0, grading)
    else:
        steep = (far - near) / grading
        start = fringe * (1.0 - slope / steep) if steep > slope else fringe
        target = np.maximum(ramp(0.0, abs(far - near) / slope), ramp(start, start + grading))
    return np.minimum(target, near + MAX_GROWTH * d)  # no mesh grows faster than MAX_GROWTH


def _band_integral(near, far, grading, fringe, slope, sheet_area, plate_area, perimeter, k) -> tuple[float, float]:
    """``(∫ h⁻² dA over the sheet, the part of it from the ramp near the outlines)``."""
    if fringe > 0:
        steep = (far - near) / grading
        start = fringe * (1.0 - slope / steep) if steep > slope else fringe
        reach = max(abs(far - near) / slope, start + grading)
    else:
        reach = grading
    reach = max(reach, abs(far - near) / MAX_GROWTH)  # where the edge reaches the far edge
    d = np.concatenate([[0.0], np.geomspace(min(near, reach) * 1e-3, reach, _POINTS - 1)])
    h = _sizes(d, near, far, grading, fringe, slope)
    mean_area, mean_perimeter = plate_area / k, perimeter / k
    # Inside: the inner parallel band of a plate, P − 2π d, until the plate's area is used.
    disc = max(mean_perimeter ** 2 - 4 * np.pi * mean_area, 0.0)
    inner_reach = (mean_perimeter - np.sqrt(disc)) / (2 * np.pi)
    inside = np.where(d < inner_reach, perimeter - 2 * np.pi * k * d, 0.0)
    # Outside: P + 2π d, until the rest of the sheet is used.
    outside_area = max(sheet_area - plate_area, 0.0)
    outer_reach = (-perimeter + np.sqrt(perimeter ** 2 + 4 * np.pi * k * outside_area)) / (2 * np.pi * k)
    outside = np.where(d < outer_reach, perimeter + 2 * np.pi * k * d, 0.0)
    density = (inside + outside) / (h * h)
    band = float(np.sum(0.5 * (density[1:] + density[:-1]) * np.diff(d)))
    covered = min(perimeter * min(reach, inner_reach) - np.pi * k * min(reach, inner_reach) ** 2, plate_area) \
        + min(perimeter * reach + np.pi * k * reach ** 2, outside_area)
    return band + max(sheet_area - covered, 0.0) / (far * far), band


def _zone_integral(zones, strips, far: float, outline: np.ndarray, path: str, plates=(), near: float = 0.0,
                   grading: float = 0.0) -> tuple[float, float]:
    """Extra ∫ h⁻² dA of the refinement zones (discs under the balls) and strips (boxes
    along held edges) over the mesh without them, and the smallest zone size. Summed on a
    grid over the sheet's bounding box with h the smallest of them there (each growing at
    ZONE_SLOPE beyond its region), so that zones that overlap each other or reach past
    the sheet are counted once; over the far edge, or with the ``plates``' outlines over
    the ramp from ``near`` at them to ``far`` at ``grading``, which the band integral
    counts already. Disc by disc over the far edge, jobs/quick.toml's two P2 ball zones
    and held-edge strips counted 2.2 times the triangles they add."""
    smallest = math.inf
    for _, _, radius, size in zones:
        _positive(radius, "the radius of a refinement zone ([[poses]] radius_mm)", path)
        smallest = min(smallest, min(_positive(size, "the edge of a refinement zone ([[poses]] radius_mm)", path),
                                     far))
    regions = [size for *_, size in strips if size > 0]
    if not zones and not regions:
        return 0.0, smallest
    lo, hi = outline.min(axis=0), outline.max(axis=0)
    finest = min([smallest, *regions])
    step = max(finest / 2, float(np.prod(hi - lo)) ** 0.5 / 200)  # at most ~40k points
    xs, ys = (np.arange(a + step / 2, b, step) for a, b in zip(lo, hi))
    x, y = np.meshgrid(xs, ys, indexing="ij")
    h = np.full(x.shape, far)
    base = np.full(x.shape, far)
    if len(plates) and grading > 0:
        segments = np.concatenate([geometry.edges(np.asarray(o, dtype=float)) for o in plates])
        points = np.column_stack([x.ravel(), y.ravel()])
        d = np.concatenate([geometry.point_segment_distance(chunk, segments).min(axis=1)
                            for chunk in np.array_split(points, max(1, len(points) * len(segments) // 2 ** 20))])
        base = np.minimum(far, near + (far - near) * d / grading).reshape(x.shape)
    for cx, cy, radius, size in zones:
        beyond = np.clip(np.hypot(x - cx, y - cy) - radius, 0.0, None)
        h = np.minimum(h, min(size, far) + _ZONE_SLOPE * beyond)
    for x0, y0, x1, y1, size in strips:
        beyond = np.hypot(np.clip(np.maximum(x0 - x, x - x1), 0.0, None),
                          np.clip(np.maximum(y0 - y, y - y1), 0.0, None))
        h = np.minimum(h, min(size, far) + _ZONE_SLOPE * beyond)
    inside = geometry.points_in_polygon(np.column_stack([x.ravel(), y.ravel()]), outline).reshape(x.shape)
    extra = np.clip(1.0 / h ** 2 - 1.0 / base ** 2, 0.0, None)
    return float(np.sum(extra[inside]) * step * step), smallest


def estimate_mesh(sheet_outline_mm, plate_area_mm2: float, perimeter_mm: float, n_plates: int,
                  settings: MeshSettings, slabs: int, order: int, problem: str = "electrostatic",
                  path: str = "<scene>", keys: dict[str, str] | None = None, plates=()) -> SizeEstimate:
    """The size of a layered mesh of a sheet with ``n_plates`` plates of total area and
    outline length ``plate_area_mm2``, ``perimeter_mm``, triangulated at ``settings``
    and extruded in ``slabs`` slabs, with ``order`` elements for ``problem``; the
    ``plates``' outlines, when given, place its refinement zones against them.

    ``keys`` maps ``"edge"``, ``"outline"``, ``"grading"``, ``"slabs"``, ``"order"`` to
    the scene keys that set them (for the message).

    Raises
    ------
    MeshError
        When a size is not a positive finite number (NaN, inf, 0, negative).
    """
    keys = {"edge": "[mesh] edge_length_mm", "outline": "[mesh] edge_length_outline_mm",
            "grading": "[mesh] grading_distance_mm", "slabs": "[mesh] elements_per_layer",
            "order": "[mesh] order", **(keys or {})}
    far = _positive(settings.edge_length_mm, keys["edge"], path)
    near = _positive(settings.edge_length_outline_mm, keys["outline"], path)
    grading = _positive(settings.grading_distance_mm, keys["grading"], path)
    grading = quality_grading_mm(settings)  # as triangulate lengthens it for the mesh quality
    slabs = _positive(slabs, keys["slabs"], path)
    fringe = settings.fringe_distance_mm or 0.0
    if fringe != 0:
        fringe = _positive(fringe, "the fringe distance ([mesh] tolerance)", path)
    slope = _positive(settings.fringe_slope or 0.5, "the fringe slope ([mesh] tolerance)", path)
    try:
        return _estimate(sheet_outline_mm, plate_area_mm2, perimeter_mm, n_plates, settings, far, near, grading,
                         slabs, fringe, slope, order, problem, path, keys, plates)
    except (ArithmeticError, ValueError) as exc:  # an overflow numpy's errstate does not cover
        raise MeshError(f"{path}: cannot size the mesh from {keys['edge']} = {far:g}, {keys['outline']} = "
                        f"{near:g}: {exc}") from None


def _estimate(sheet_outline_mm, plate_area_mm2, perimeter_mm, n_plates, settings, far, near, grading, slabs, fringe,
              slope, order, problem, path, keys, plates=()) -> SizeEstimate:
    """:func:`estimate_mesh` past the checks of its arguments."""
    with np.errstate(all="ignore"):
        outline = np.asarray(sheet_outline_mm, dtype=float)
        x, y = outline[:, 0], outline[:, 1]
        sheet_area = abs(0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)))
        width, height = float(np.ptp(x)), float(np.ptp(y))
        _positive(sheet_area, "[sheet] area (mm²)", path)
        n_plates = max(int(n_plates), 1)
        plate_area = _positive(plate_area_mm2, "plate area (mm²)", path)
        perimeter = _positive(perimeter_mm, "plate outline length (mm)", path)
        integral, band = _band_integral(near, far, grading, fringe, slope, sheet_area, plate_area, perimeter, n_plates)
        zones, smallest = _zone_integral(settings.zones, settings.strips, far, outline, path, plates, near, grading)
        triangles = KAPPA * integral + ZONE_KAPPA * zones
        sheet_boundary = float(np.sum(np.hypot(np.diff(x, append=x[:1]), np.diff(y, append=y[:1]))))
        vertices_2d = 0.5 * triangles + 0.5 * sheet_boundary / far
        levels = slabs + 1
        vertices = vertices_2d * levels
        tets = 3.0 * triangles * slabs
        edges_2d = 1.5 * triangles + 0.5 * sheet_boundary / far
        nodes = vertices if order == 1 else vertices + edges_2d * (2 * slabs + 1) + vertices_2d * slabs
        unknowns = nodes * (3 if problem == "elastic" else 1)
        memory = max(MESH_BASE_BYTES + BYTES_PER_TET * tets,
                     BASE_BYTES + BYTES_PER_UNKNOWN[(problem, 2 if order == 2 else 1)] * unknowns)
        far_part = integral - band  # NaN when both overflow: then it is named first
    parts = sorted([(far_part, f"{keys['edge']} = {far:g}"),
                    (band, f"{keys['outline']} = {near:g} over {keys['grading'].split()[-1]} = {grading:g}"),
                    (zones, f"the refinement zones under the poke balls (smallest edge {smallest:g} mm)")],
                   key=lambda p: -p[0] if math.isfinite(p[0]) else -math.inf)
    drivers = [parts[0][1]]
    if slabs > 5:
        drivers.append(keys["slabs"] if "=" in keys["slabs"] else f"{keys['slabs']} ({slabs:g} slabs)")
    if order == 2:
        drivers.append(f"{keys['order']} = 2")
    drivers.append(f"sheet {width:g} x {height:g} mm")
    return SizeEstimate(problem, triangles, vertices, tets, unknowns, memory, tuple(drivers))


def _plates(layout) -> tuple[float, float, int]:
    """Total area and outline length of ``layout``'s plates, and their count."""
    area = perimeter = 0.0
    for o in layout.outlines:
        o = np.asarray(o, dtype=float)
        nxt = np.roll(o, -1, axis=0)
        area += abs(0.5 * float(np.sum(o[:, 0] * nxt[:, 1] - nxt[:, 0] * o[:, 1])))
        perimeter += float(np.sum(np.hypot(*(nxt - o).T)))
    return area, perimeter, len(layout.outlines)


def estimate_electrostatic(sheet: Sheet) -> SizeEstimate:
    """The size of :func:`mscap.mesh.layered.mesh_sheet` ``(sheet)``."""
    from dataclasses import replace

    m = sheet.mesh
    estimate = estimate_mesh(sheet.outline_mm, *_plates(sheet.layout), m, 5 * _count(m.elements_per_layer), m.order,
                             "electrostatic", sheet.path,
                             {"slabs": f"[mesh] elements_per_layer = {m.elements_per_layer!r}"})
    if m.tolerance is None:
        return estimate
    first = f"{estimate.drivers[0]} (sizes from [mesh] tolerance = {m.tolerance:g})"
    return replace(estimate, drivers=(first,) + estimate.drivers[1:])


def estimate_elastic(sheet: Sheet, el: ElasticSettings, poses) -> SizeEstimate | None:
    """The size of :func:`mscap.mesh.layered.mesh_elastic`'s own mesh of ``el``
    (``[elastic]``) beside ``sheet``'s for ``poses`` (``None`` when the elastic problem is
    on the electrostatic mesh)."""
    from dataclasses import replace

    from mscap.mesh.layered import elastic_sizes

    if el.mesh == "shared":
        return None
    h = el.edge_length_mm
    if _finite(h) and h > 0:
        settings = elastic_sizes(sheet, el, poses)
    else:  # the estimate names the bad key
        settings = replace(sheet.mesh, edge_length_mm=h, edge_length_outline_mm=h, fringe_distance_mm=0.0, zones=())
    slabs = el.elements_through_thickness or 5 * _count(sheet.mesh.elements_per_layer)
    keys = {"edge": "[elastic] edge_length_mm", "outline": "[elastic] edge_length_outline_mm",
            "slabs": f"[elastic] elements_through_thickness = {el.elements_through_thickness!r}"
            if el.elements_through_thickness else f"[mesh] elements_per_layer = {sheet.mesh.elements_per_layer!r}",
            "order": "[elastic] order"}
    return estimate_mesh(sheet.outline_mm, *_plates(sheet.layout), settings, slabs, el.order, "elastic", sheet.path,
                         keys, sheet.layout.outlines)


def _finite(value) -> bool:
    try:
        return math.isfinite(float(value))
    except (TypeError, ValueError, OverflowError):
        return False


def _count(value) -> float:
    """An integer scene count as a float (inf for absurd or invalid ones: refused later)."""
    try:
        return float(value)
    except (TypeError, ValueError, OverflowError):
        return float("nan")


def memory_limit() -> tuple[float, str]:
    """The bytes a mesh may ask for, and how to say where that came from:
    ``MSCAP_MAX_MEMORY_GB`` when set, else the machine's physical memory (``os.sysconf``,
    else ``MemTotal`` of /proc/meminfo; else no limit).

    Not ``MemAvailable``: on a shared machine it swings with the neighbours' jobs (it fell
    to 1.4 GB of 25 GB for a moment while this was fitted, refusing jobs/joystick.toml),
    and a run that fits the machine should not fail by the minute it starts."""
    given = os.environ.get(MEMORY_ENV)
    if given not in (None, ""):
        try:
            gb = float(given)
        except ValueError:
            gb = float("nan")
        if not (math.isfinite(gb) and gb > 0):
            raise MeshError(f"{MEMORY_ENV} = {given!r}: expected a positive number of GB")
        return gb * 1e9, f"the limit is {gb:g} GB ({MEMORY_ENV})"
    try:
        total = float(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        total = None
    if not total or total <= 0:
        try:
            with open("/proc/meminfo") as f:
                total = next(float(line.split()[1]) * 1024 for line in f if line.startswith("MemTotal:"))
        except (OSError, StopIteration, ValueError, IndexError):
            return math.inf, "no memory limit is known"
    return total, f"this machine has {_human(total)}"


def _count_text(n: float) -> str:
    """3.1e9 for large counts, 14,280 for small ones."""
    if not math.isfinite(n):
        return "an unbounded number of"
    if n < 1e5:
        return f"{n:,.0f}"
    mantissa, exponent = f"{n:.1e}".split("e")
    return f"{mantissa}e{int(exponent)}"


def _human(n: float) -> str:
    """Bytes as MB, GB or TB, two significant digits (4.6e13 TB beyond a thousand)."""
    if not math.isfinite(n):
        return "unbounded memory"
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if n >= scale or unit == "MB":
            value = n / scale
            if value >= 1e3 and unit == "TB":
                return f"{_count_text(value)} TB"
            return f"{value:.0f} {unit}" if value >= 10 else f"{value:.2g} {unit}"


def check_fits(estimate: SizeEstimate, path: str, limit: tuple[float, str] | None = None) -> SizeEstimate:
    """``estimate`` if its memory is within ``limit`` (default :func:`memory_limit`),
    else the one-line :class:`MeshError` naming the keys that drive it."""
    limit_bytes, where = limit or memory_limit()
    if estimate.memory_bytes <= limit_bytes:
        return estimate
    return _refuse(estimate, path, where)


def _refuse(estimate: SizeEstimate, path: str, where: str):
    drivers = " and ".join(estimate.drivers)
    raise MeshError(f"{path}: the {estimate.problem} mesh would have ~{_count_text(estimate.tets)} tets "
                    f"(~{_human(estimate.memory_bytes)}) from {drivers}; {where}; raise the limit with "
                    f"--max-memory-gb or {MEMORY_ENV}")


def check_meshes(sheet: Sheet, elastic: ElasticSettings, poses) -> tuple[SizeEstimate, SizeEstimate | None]:
    """Both meshes a simulation of ``poses`` builds: ``sheet``'s and, when a pose needs it,
    the elastic one of ``elastic`` (``[elastic]``), each within :func:`memory_limit`. Call
    it first: it refuses an elastic bomb before the electrostatic mesh is built."""
    limit = memory_limit()
    electro = check_fits(estimate_electrostatic(sheet), sheet.path, limit)
    needs = any(getattr(p, "kind", "free") != "free" for p in poses)
    el = estimate_elastic(sheet, elastic, poses) if needs else None
    return electro, check_fits(el, sheet.path, limit) if el is not None else None


def check_capacitor_count(count, path: str, key: str = "capacitors") -> int:
    """``count`` capacitors if a scene may hold that many (1 to :data:`MAX_CAPACITORS`),
    else a :class:`SceneError` naming ``key``. For the loader, before it builds the
    layout (a 2000 x 2000 grid otherwise hangs in the pairwise checks)."""
    try:
        number = int(count)
        whole = number == count
    except (TypeError, ValueError, OverflowError):
        whole = False
    if not whole or not 1 <= number <= MAX_CAPACITORS:
        raise SceneError(path, key, f"{count!r} capacitors; a scene holds 1 to {MAX_CAPACITORS} (the layout "
                                    f"checks are quadratic in the count)")
    return number
