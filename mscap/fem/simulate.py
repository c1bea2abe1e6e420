"""The forward pipeline: scene → mesh → per pose: elastic equilibrium → capacitances.

A scene only builds what its poses need: no elastic problem when every pose is ``free``,
no contact unless a pose pokes, no surfaces unless a pose is glued.
"""

from __future__ import annotations

import ctypes
import gc
import logging
import time
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np
import scipy.sparse as sp

from mscap.errors import ElectrostaticError
from mscap.fem import electrostatic
from mscap.fem.elastic.loading import loading_for
from mscap.fem.elastic.newton import ElasticState, NewtonSettings, factorise_equilibrium, solve_pose
from mscap.fem.elastic.problem import ElasticError, ElasticProblem, build_problem
from mscap.fem.petsc import LinearSolver, Operator
from mscap.mesh.layered import LayeredMesh, extrude_sheet, mesh_elastic, mesh_sheet
from mscap.fem.transfer import interpolation_matrix

__all__ = ["PoseResult", "Simulation", "simulate", "solve_poses", "equilibria", "capacitances", "equilibrium",
           "factorised", "elastic_setup", "elastic_transfer", "electro_vertices", "release_freed_memory", "element_of"]

if TYPE_CHECKING:
    from mscap.scene.settings import ElasticSettings, MeshSettings, Scene, Sheet

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PoseResult:
    """One pose: its equilibrium (``None`` for the rest pose), capacitances and moved
    electrostatic vertices (``None`` when simulated without ``keep_fields``)."""

    name: str
    kind: str
    state: ElasticState | None
    capacitances: electrostatic.Capacitances
    vertices: np.ndarray | None
    elastic_s: float
    electrostatic_s: float

    @property
    def capacitance_pF(self) -> np.ndarray:
        return self.capacitances.capacitance_pF


@dataclass(frozen=True)
class Simulation:
    """Every pose of a scene.

    ``elastic.mesh`` is ``mesh`` itself or the scene's coarser elastic mesh; then
    ``transfer`` maps elastic nodal displacements to the vertices of ``mesh``."""

    scene_name: str
    mesh: LayeredMesh
    elastic: ElasticProblem | None
    electro: electrostatic.ElectrostaticProblem
    poses: tuple[PoseResult, ...]
    times: dict
    transfer: sp.csr_matrix | None = None

    @property
    def capacitance_pF(self) -> np.ndarray:
        """``(n_poses, k)`` capacitances."""
        return np.array([p.capacitance_pF for p in self.poses])

    def vertices(self, nodes: np.ndarray) -> np.ndarray:
        """Electrostatic vertex positions for elastic node positions ``nodes``."""
        return electro_vertices(self.mesh, self.elastic, self.transfer, nodes)


def electro_vertices(mesh: LayeredMesh, problem: ElasticProblem, transfer, nodes: np.ndarray) -> np.ndarray:
    """The electrostatic mesh's vertices moved by the elastic displacement ``nodes − rest``
    (the first ``n_vertices`` nodes on a shared mesh, ``transfer`` otherwise)."""
    if transfer is None:
        return nodes[:len(mesh.points)]
    return mesh.points + transfer @ (nodes - problem.rest)


def simulate(scene: Scene, order: int | None = None, elastic_order: int | None = None,
             mesh: LayeredMesh | None = None, keep_factorisation: bool = False, keep_fields: bool = True,
             out_of_core: bool = False, progress: Callable[[str], None] | None = None,
             starts: Callable[[ElasticProblem], Sequence[np.ndarray | None]] | None = None,
             every_plate: bool = True, maxwell: bool = False, elastic_mesh: LayeredMesh | None = None,
             poses: Sequence | None = None, sheet: Sheet | None = None,
             elastic: ElasticSettings | None = None) -> Simulation:
    """Simulate every pose of ``scene`` (or ``poses``: a design's, the calibration family's grid).

    Parameters
    ----------
    scene
        A loaded :class:`~mscap.scene.settings.Scene`.
    sheet, elastic
        The mesh stage's input (a run's layout and mesh sizes,
        :func:`mscap.scene.sizing.sheet_for`) and the ``[elastic]`` settings, in place of
        the scene's own (a finer-mesh check's, :func:`mscap.service.accuracy.finer`).
    order, elastic_order
        Electrostatic and elastic element orders (default: the scene's).
    mesh
        A mesh to use instead of meshing the scene.
    keep_factorisation
        Keep each pose's factorised Hessian (for adjoints).
    keep_fields
        Keep each pose's potentials and moved vertices; without them a pose result holds
        its capacitances only (the finer-mesh check: 220 MB less on the glove's 16 poses).
    out_of_core
        Factorise with MUMPS and keep the factors on disk, elastic and electrostatic (the
        finer-mesh check: 1,116 -> 869 MB on biaxial's, 786 -> 674 MB on pneumatic's,
        docs/performance.md §9).
    progress
        Called with one-line progress messages.
    starts
        Given the elastic problem, each pose's Newton start as a displacement (or
        ``None``): e.g. a coarser mesh's equilibria interpolated (the finer-mesh check,
        :func:`mscap.service.accuracy.estimate_error`); a start that fails falls back to the
        pose's load path (:func:`equilibrium`).
    every_plate
        Require both plates of every capacitor (``False``: a wired sensor's mesh, whose
        nets are the plates, :mod:`mscap.fabrication.wired`).
    maxwell
        Also each pose's Maxwell matrix (``capacitances.maxwell_pF``; twice the solves).
    elastic_mesh
        An elastic mesh to use instead of the scene's (a wired sensor's nets,
        :func:`mscap.fabrication.wired.wired_elastic_mesh`).
    """
    sheet, elastic = sheet or scene.sheet, elastic or scene.elastic
    start = time.perf_counter()
    meshed_here = mesh is None
    mesh = mesh or mesh_sheet(sheet)
    meshed = time.perf_counter()
    electrostatic.check_plates(mesh, every_plate)  # a bad layout fails now, not after the elastic solves
    # The transfer to the electrostatic vertices is built after the elastic phase (35 MB on
    # biaxial's finer-mesh check); the elastic solves do not need it.
    poses = scene.poses if poses is None else tuple(poses)
    problem, _ = elastic_setup(sheet, elastic, mesh, poses, elastic_order, transfer=False, elastic_mesh=elastic_mesh)
    # Out of core (memory over speed), a mesh made here is set aside through the elastic phase
    # when the elastic mesh is another one, and extruded again from its triangulation after it:
    # 1.7 M tets, 79 MB, on biaxial's finer-mesh check, whose elastic phase is its peak.
    mesh2d = None
    if out_of_core and meshed_here and problem is not None and problem.mesh is not mesh:
        mesh2d, mesh = mesh.mesh2d, None
    sim = Simulation(scene.name, mesh, problem, None, (), {}, None)
    # Every equilibrium first, then every capacitance: the elastic factorisation is freed
    # before the electrostatic problem is built, so a simulation's peak memory is the larger
    # of the two phases, not their sum (biaxial's finer-mesh check: P2 elasticity 420 MB).
    operator = Operator(problem, out_of_core=out_of_core) if problem is not None else None
    try:
        warm = starts(problem) if starts is not None and problem is not None else None
        states, elastic_s = equilibria(sim, poses, elastic, operator, warm,
                                       keep_factorisation=keep_factorisation,
                                       progress=progress)
        del warm
    finally:  # PETSc objects free their memory only when destroyed
        if operator is not None:
            operator.destroy()
    release_freed_memory()  # the elastic phase's temporaries, before the larger allocations
    try:
        mesh = mesh if mesh2d is None else extrude_sheet(sheet, mesh2d)
        sim = replace(sim, mesh=mesh, transfer=elastic_transfer(problem, mesh),
                      electro=electrostatic.build_problem(mesh, sheet.layers, *element_of(sheet.mesh, order),
                                                          every_plate=every_plate))
    except BaseException:
        _free(states)
        raise
    solver = LinearSolver("electro_", out_of_core)
    try:
        results = capacitances(sim, poses, states, elastic_s, solver, keep_fields=keep_fields, progress=progress,
                               maxwell=maxwell)
    finally:
        solver.destroy()
    end = time.perf_counter()
    elastic_s = sum(r.elastic_s for r in results)
    split = {key: sum(r.state.times[key] for r in results if r.state) for key in
             ("assembly", "factorisation", "solve", "line_search")}
    split["other"] = elastic_s - sum(split.values())
    electrostatic_s = sum(r.electrostatic_s for r in results)
    times = {"mesh": meshed - start, "setup": (end - meshed) - elastic_s - electrostatic_s,
             "elastic": elastic_s, "electrostatic": electrostatic_s, "total": end - start,
             "elastic_split": split}
    return replace(sim, poses=results, times=times)


def equilibrium(problem: ElasticProblem, pose, settings: NewtonSettings, operator: Operator | None = None,
                start: np.ndarray | None = None, keep_factorisation: bool = False,
                progress: Callable[[str], None] | None = None, stale: Operator | None = None) -> ElasticState:
    """One pose's elastic equilibrium on ``problem``.

    With ``start`` (a displacement ``(n_nodes, 3)``, e.g. the pose's at nearby rest
    positions) Newton starts from ``rest + start`` in one load step, first as modified
    Newton on ``stale`` when given (the pose's factorised Hessian at that nearby design,
    :func:`~mscap.fem.elastic.newton.solve_pose`); when that fails, or without ``start``,
    it follows the pose's full load path."""
    loading = loading_for(problem, pose)
    if start is not None:
        warm = problem.rest + start
        try:
            return solve_pose(problem, replace(loading, load_steps=1, guess=lambda x, t: warm), settings,
                              operator, keep_factorisation=keep_factorisation, progress=progress, stale=stale)
        except ElasticError as exc:
            log.warning("pose %s: warm start failed (%s); solving along the full load path", pose.name, exc)
    return solve_pose(problem, loading, settings, operator, keep_factorisation=keep_factorisation,
                      progress=progress)


def factorised(problem: ElasticProblem, pose, settings: NewtonSettings, state: ElasticState) -> ElasticState:
    """``state`` (one pose's equilibrium on ``problem``, solved without
    ``keep_factorisation``) with its exact Hessian factorised, as ``keep_factorisation``
    would have kept it: the same values, assembled again at the equilibrium. Asked for
    when the adjoint needs it, a factorisation costs nothing on an evaluation whose
    gradient is never taken (a rejected line-search trial)."""
    if state.operator is not None:
        return state
    return replace(state, operator=factorise_equilibrium(problem, loading_for(problem, pose), settings, state.nodes))


def solve_poses(sim: Simulation, poses: Sequence, settings: NewtonSettings, solver: LinearSolver,
                operator: Operator | None, starts: Sequence[np.ndarray | None] | None = None,
                keep_factorisation: bool = False, keep_fields: bool = True,
                progress: Callable[[str], None] | None = None,
                stale: Sequence[Operator | None] | None = None) -> tuple[PoseResult, ...]:
    """The forward loop: every pose of ``poses`` on ``sim``'s meshes (its own poses are
    ignored) with the Newton ``settings`` (a scene's ``[elastic]``): :func:`equilibria`
    (warm from ``starts[i]`` when given, on ``stale[i]`` too), then :func:`capacitances`.

    ``solver`` (electrostatic) and ``operator`` (elastic, ``None`` if every pose is free)
    are reused across poses; the caller owns and destroys them."""
    states, elastic_s = equilibria(sim, poses, settings, operator, starts, keep_factorisation, progress, stale)
    return capacitances(sim, poses, states, elastic_s, solver, keep_fields, progress)


def equilibria(sim: Simulation, poses: Sequence, settings: NewtonSettings, operator: Operator | None,
               starts: Sequence[np.ndarray | None] | None = None, keep_factorisation: bool = False,
               progress: Callable[[str], None] | None = None,
               stale: Sequence[Operator | None] | None = None) -> tuple[list, list]:
    """Every pose's elastic equilibrium (``None`` for a free pose) and its seconds, with the
    Newton ``settings``, warm from ``starts[i]`` (on ``stale[i]``, :func:`equilibrium`) when
    given. On a failure the factorisations kept so far are freed before the error propagates."""
    say = progress or (lambda message: None)
    starts = starts if starts is not None else [None] * len(poses)
    stale = stale if stale is not None else [None] * len(poses)
    states, seconds = [], []
    try:
        for i, pose in enumerate(poses):
            t0 = time.perf_counter()
            state = None
            if pose.kind != "free":
                state = equilibrium(sim.elastic, pose, settings, operator, starts[i],
                                    keep_factorisation=keep_factorisation, progress=progress, stale=stale[i])
                say(f"pose {i + 1}/{len(poses)} {pose.name}: equilibrium in {state.load_steps} load steps, "
                    f"{state.newton_iterations} Newton iterations ({time.perf_counter() - t0:.2f} s)")
            states.append(state)
            seconds.append(time.perf_counter() - t0)
    except BaseException:
        _free(states)
        raise
    return states, seconds


def capacitances(sim: Simulation, poses: Sequence, states: Sequence[ElasticState | None], elastic_s: Sequence[float],
                 solver: LinearSolver, keep_fields: bool = True,
                 progress: Callable[[str], None] | None = None, maxwell: bool = False) -> tuple[PoseResult, ...]:
    """Every pose's capacitances (of ``poses``) on ``sim.electro`` at the equilibria ``states`` (from
    :func:`equilibria`). Without ``keep_fields`` a result's ``capacitances.potentials`` and
    ``vertices`` are ``None``. On a failure (e.g. an inverted tet at a rejected line-search
    trial) the factorisations ``states`` kept are freed before the error propagates."""
    say = progress or (lambda message: None)
    results = []
    try:
        for i, (pose, state) in enumerate(zip(poses, states)):
            vertices = sim.mesh.points if state is None else sim.vertices(state.nodes)
            t1 = time.perf_counter()
            try:
                caps = electrostatic.solve(sim.electro, vertices, maxwell=maxwell, solver=solver)
            except ElectrostaticError as exc:
                raise type(exc)(f"pose {pose.name!r}: {exc}") from exc  # InvertedMeshError stays one
            t2 = time.perf_counter()
            if not keep_fields:
                caps, vertices = replace(caps, potentials=None), None
            results.append(PoseResult(pose.name, pose.kind, state, caps, vertices, elastic_s[i], t2 - t1))
            say(f"pose {i + 1}/{len(poses)} {pose.name}: C = "
                f"{np.array2string(caps.capacitance_pF, precision=3)} pF "
                f"(elastic {elastic_s[i]:.2f} s, electrostatic {t2 - t1:.2f} s)")
    except BaseException:
        _free(states)
        raise
    return tuple(results)


def _free(states) -> None:
    """Destroy the factorisations ``states`` kept (petsc4py frees native memory only then)."""
    for state in states:
        if state is not None and state.operator is not None:
            state.operator.destroy()


def element_of(settings: MeshSettings, order: int | None = None) -> tuple[int, str]:
    """The electrostatic element order and shape of a scene's ``[mesh]`` ``settings``
    (``order`` overriding its ``order``): its ``element``, except that P2 is tets only."""
    order = order or settings.order
    return order, settings.element if order == 1 else "tet"


def elastic_setup(sheet: Sheet, elastic: ElasticSettings, mesh: LayeredMesh, poses: Sequence,
                  order: int | None = None, transfer: bool = True, elastic_mesh: LayeredMesh | None = None):
    """The elastic problem ``poses`` need (``None`` if every pose is free) on the elastic
    mesh of ``elastic`` (``[elastic]``) beside ``mesh``, ``sheet``'s (or on
    ``elastic_mesh``), and the transfer to ``mesh``'s vertices (``None`` when shared or not
    asked for: :func:`elastic_transfer` builds it later)."""
    if all(p.kind == "free" for p in poses):
        return None, None
    order = order or elastic.order
    _warn_p1_clamped_stretch(sheet.path, order, poses)
    _warn_p1_bending(sheet.path, sheet.name, order, poses, elastic)
    problem = build_problem(elastic_mesh or mesh_elastic(sheet, elastic, mesh, poses), sheet.layers, order)
    return problem, elastic_transfer(problem, mesh) if transfer else None


def elastic_transfer(problem: ElasticProblem | None, mesh: LayeredMesh):
    """The interpolation from ``problem``'s nodes to ``mesh``'s vertices (``None`` when
    there is no problem or it is on ``mesh`` itself)."""
    if problem is None or problem.mesh is mesh:
        return None
    return interpolation_matrix(problem, mesh.points)


_P1_WARNED: set[tuple[str, str]] = set()


def _warn_p1_clamped_stretch(path: str, order: int, poses) -> None:
    """P1 tets stiffen clamped large stretches (locking): say so instead of staying
    silent, once per scene file ``path`` and pose in a process (an optimisation rebuilds it often)."""
    if order != 1:
        return
    for pose in poses:
        if getattr(pose, "grips", None) == "clamp" and max(abs(s - 1.0) for s in pose.stretch) >= 0.3:
            if (path, pose.name) in _P1_WARNED:
                continue
            _P1_WARNED.add((path, pose.name))
            log.warning("pose %s: P1 elements overestimate the capacitance of a clamped stretch "
                        "this large (grid3x3 at 100 %%: +8 %% at 5 mm, +1.3 %% at 1.5 mm elastic edges); "
                        "consider [elastic] order = 2 (docs/elastic.md)", pose.name, extra={"advice": True})


#: Glued poses on an own P1 elastic mesh with edges this fine are not warned about: on the
#: glued paper scenes (2.5 mm, 1.25 mm on the outlines) P1 reads every pose-to-pose signal
#: within 3.3 % of P2 on the same meshes, at 3-13x less wall; at 3.5 mm the glove's worst
#: pair differs by 4.3 % (docs/elastic.md, "The glued paper scenes stay P1").
GLUED_P1_EDGE_MM = 2.5


def _warn_p1_bending(path: str, name: str, order: int, poses, elastic) -> None:
    """P1 tets lock in a thin stack bent by a ball or glued onto a curved object: the
    pose-to-pose gains read high (poke) or low (bend). Say so once per scene file ``path``
    (scene ``name``) in a process; glued poses only on an elastic mesh (``[elastic]``
    settings ``elastic``) coarser than :data:`GLUED_P1_EDGE_MM`."""
    if order != 1 or (path, "bending") in _P1_WARNED:
        return
    fine = elastic.mesh == "own" and elastic.edge_length_mm <= GLUED_P1_EDGE_MM
    bending = [p.name for p in poses if p.kind == "poke" or (p.kind == "glue" and not fine)]
    if bending:
        _P1_WARNED.add((path, "bending"))
        log.warning("%s: P1 elements lock where the sheet bends (poses %s): a 5 mm ball's gain reads +22-48 %% "
                    "and a glued 15 mm cylinder's -7-11 %% at nu = 0.47-0.49 with 5 mm elements, P2 (refined under "
                    "the ball and along the held edges) +1-3 %% (+8-16 %% against +2 %% on jobs/poking.toml); "
                    "consider [elastic] order = 2 (docs/elastic.md)",
                    name, ", ".join(bending), extra={"advice": True})


def release_freed_memory() -> None:
    """Collect garbage and hand the heap's free pages back to the system (glibc's
    ``malloc_trim``; nothing elsewhere). Freed numpy and PETSc memory stays in the process
    otherwise: after a poking start (k = 6) the worker held 713 MB, of which trimming
    returned 544 MB, and the finer-mesh check then grew from there."""
    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc
        pass
