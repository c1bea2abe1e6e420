"""The design pipeline on one screen: control q → rest meshes → poses → capacitances → J,
and back: ∂J/∂C → one adjoint per pose → ∂J/∂X → Wᵀ → dJ/dq (paper §5).

A :class:`Design` holds what depends on the rest meshes only: the electrostatic mesh and
problem, the elastic problem on its own (coarser) mesh with the fixed transfer ``T``, and
the skinning deformer. The deformer's weights ``W`` live on the electrostatic 2D mesh; the
elastic mesh's 2D vertices follow the *same* blend, interpolated there,

    X2d_fine(q) = X2d_fine0 + W q,      X2d_el(q) = X2d_el0 + T2d W q,

with ``T2d`` the P1 interpolation of the fine 2D mesh at the elastic 2D vertices
(:func:`mscap.fem.transfer.p1_matrix`). Both meshes embed the outlines and the sheet edge, so an
elastic vertex on an outline stays on the deformed outline and one on the sheet edge
stays put (W vanishes there). Every level of each mesh moves with its 2D vertex.

The gradient is the chain of the objective's pieces:

    ∂J/∂C_i = −∂d/∂C_i                    (per pose, a (k,) weight vector)
    ∂J/∂X   = Σ_i pose_rest_gradient(i)     (one elastic adjoint per pose, mscap.fem.adjoint)
    dJ/dq   = Wᵀ Σ_levels ∂J/∂X_fine,xy + (T2d W)ᵀ Σ_levels ∂J/∂X_el,xy
              + Wᵀ (∂(w_b B + w_s S)/∂outline vertices)

Routed during the optimisation (``[fabrication] route_during_optimisation``), J is taken
at ``C + ΔC``, ΔC the leads' share of every reading at the last route
(:mod:`mscap.fabrication.during`, :attr:`Design.wiring`), held fixed between routes: the
chain above is unchanged, ∂J/∂C taken at ``C + ΔC``.

Each pose's Newton solve starts from its equilibrium at the previous accepted design,
carried to the moved rest nodes with its deformation gradient (:meth:`Design.evaluate`
``warm=``, :meth:`Evaluation.starts_at`), one load step, so an optimisation iteration costs a
few Newton steps per pose; when that fails the pose falls back to its full load path.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Mapping

import numpy as np

from mscap.design.deformer import Deformer, build_deformer
from mscap.design.history import min_pairwise_l1
from mscap.design.objective import LayoutObjective, layout_objective
from mscap.design.readback import DesignPoses, design_poses
from mscap.design.resolution import ErrorModel, error_model
from mscap.errors import DesignError, FabricationError
from mscap.fem.adjoint import moved, pose_rest_gradient
from mscap.fem.elastic.problem import carried_displacement
from mscap.fem.petsc import LinearSolver, Operator
from mscap.fem import electrostatic
from mscap.fem.simulate import Simulation, elastic_setup, element_of, factorised, solve_poses
from mscap.fem.transfer import p1_matrix
from mscap.mesh.layered import mesh_elastic, mesh_sheet
from mscap.scene.settings import ElasticSettings, Scene, Sheet
from mscap.scene.loader import check_designable

__all__ = ["DesignError", "Design", "Evaluation", "build_design", "rest_problems"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Evaluation:
    """J and its parts at one design ``q``.

    ``terms``: the objective's terms, unweighted, by name
    (:class:`mscap.design.objective.LayoutObjective`; by default ``J = −d + w_b · barrier +
    w_s · smoothing`` (+ w_b · ``area``), ``d`` (:func:`mscap.design.objective.capacitance_term`:
    pF², noise units, or −mm for the read-back bound), ``barrier`` and ``smoothing`` (mm²));
    ``capacitance_pF``
    ``(n_poses, k)`` over the design poses; ``sim`` holds the moved meshes, the fields and
    each pose's equilibrium (for :meth:`Design.gradient`, which factorises each pose's
    Hessian there and keeps it, until :meth:`release`; ``None`` once :meth:`detached`);
    ``newton_iterations`` per pose;
    ``error_J`` and ``margin_error_pF``, the estimated discretisation error of J and of
    :attr:`min_l1_pF` (:mod:`mscap.design.resolution`); ``dJ_dC``, ∂J/∂C ``(n_poses, k)``,
    which :meth:`Design.gradient` starts from.
    """

    q: np.ndarray
    J: float
    terms: Mapping[str, float]
    capacitance_pF: np.ndarray
    sim: Simulation | None
    newton_iterations: tuple[int, ...]
    time_s: float
    released: bool = False
    error_J: float = float("nan")
    margin_error_pF: float = float("nan")
    dJ_dC: np.ndarray | None = None
    #: The leads' share in ``capacitance_pF`` (``[fabrication] route_during_optimisation``,
    #: :mod:`mscap.fabrication.during`), ``None``: the plates alone.
    offset_pF: np.ndarray | None = None

    @property
    def min_l1_pF(self) -> float:
        return min_pairwise_l1(self.capacitance_pF)

    def release(self, keep_elastic: bool = False) -> None:
        """Destroy the kept factorisations (PETSc objects) and drop the electrostatic
        fields and moved vertices now: :meth:`Design.gradient` needs them, nothing else
        does (warm starts and remeshing use the elastic equilibria, which stay). Dropping
        the last reference to a factorisation is not enough — the poking scene kept
        ~34 MB of native memory per evaluation alive that way — and the fields of an
        evaluation the optimiser has moved on from stayed alive beside the next one's
        (16 poses × 8 MB on the glove at k = 6). ``keep_elastic`` keeps the elastic
        factorisations for the next design's modified-Newton starts
        (:meth:`factorisations`) until a later ``release()``."""
        if self.sim is None:
            return
        poses = []
        for r in self.sim.poses:
            state = r.state
            if state is not None and state.operator is not None and not keep_elastic:
                state.operator.destroy()
                state = replace(state, operator=None)
            poses.append(replace(r, state=state, capacitances=replace(r.capacitances, potentials=None),
                                 vertices=None))
        object.__setattr__(self, "sim", replace(self.sim, poses=tuple(poses)))
        object.__setattr__(self, "released", True)

    def detached(self, keep_elastic: bool = False) -> "Evaluation":
        """This evaluation's values (q, J and its parts, C) without its simulation, for
        keeping: the meshes and fields of a design the optimiser has remeshed away from
        would otherwise stay alive with it (the initial evaluation kept a whole
        electrostatic problem, 60 MB on poking_cross). This evaluation itself is released
        as by ``release(keep_elastic)``."""
        self.release(keep_elastic)
        return replace(self, sim=None, released=True)

    def factorise(self, i: int, pose, settings) -> None:
        """Factorise pose ``i``'s (``pose``'s, Newton ``settings``) exact Hessian at its equilibrium, unless done
        (:func:`~mscap.fem.simulate.factorised`): the adjoint's, kept until :meth:`release`."""
        result = self.sim.poses[i]
        if result.state is None or result.state.operator is not None:
            return
        state = factorised(self.sim.elastic, pose, settings, result.state)
        poses = list(self.sim.poses)
        poses[i] = replace(result, state=state)
        object.__setattr__(self, "sim", replace(self.sim, poses=tuple(poses)))

    def displacements(self) -> list[np.ndarray | None]:
        """Per pose, the elastic node displacement ``(n_nodes, 3)`` (``None`` if free)."""
        return [None if r.state is None else r.state.nodes - self.sim.elastic.rest for r in self.sim.poses]

    def factorisations(self, problem) -> list | None:
        """Per pose, this evaluation's factorised Hessian at its equilibrium (kept for the
        adjoint, or by ``release(keep_elastic=True)``), for modified-Newton starts of a
        nearby design on the same elastic mesh ``problem``
        (:func:`~mscap.fem.elastic.newton.solve_pose`'s ``stale``); ``None`` on another
        mesh, and ``None`` per pose once destroyed."""
        mine = None if self.sim is None else self.sim.elastic
        if mine is None or problem is None or mine.nodes.shape != problem.nodes.shape or not (
                mine.nodes is problem.nodes or np.array_equal(mine.nodes, problem.nodes)):
            return None
        return [None if r.state is None else r.state.operator for r in self.sim.poses]

    def starts_at(self, rest: np.ndarray) -> list[np.ndarray | None]:
        """Per pose, a Newton start at new rest positions ``rest`` of the same elastic mesh:
        each equilibrium carried with its deformation gradient
        (:func:`~mscap.fem.elastic.problem.carried_displacement`; on jobs/quick.toml 17 %
        fewer warm Newton iterations than keeping the displacement, docs/performance.md §2)."""
        problem = self.sim.elastic
        return [None if r.state is None else carried_displacement(problem, r.state.nodes, rest)
                for r in self.sim.poses]


@dataclass(frozen=True, eq=False)
class Design:
    """Scene, the run's sheet (its layout and mesh sizes), rest meshes and problems
    (``base``: a :class:`Simulation` without poses), the deformer (weights on the
    electrostatic 2D mesh), ``elastic_weights`` ``T2d W`` on the elastic mesh's 2D
    vertices (``None`` on a shared mesh) and the scene's objective J
    (:func:`mscap.design.objective.layout_objective`, built once)."""

    scene: Scene
    #: The mesh stage's input: the layout the rest meshes were made from and their sizes
    #: (:func:`mscap.scene.sizing.sheet_for`); the scene keeps its own layout.
    sheet: Sheet
    base: Simulation
    deformer: Deformer
    elastic_weights: np.ndarray | None
    objective: LayoutObjective
    #: The poses the design is simulated and judged on and their family (the scene's
    #: listed poses, or its calibration family's grid): :func:`~mscap.design.readback.design_poses`.
    designed: DesignPoses
    #: Solvers reused by every evaluation (same patterns, so PETSc's symbolic
    #: factorisations are kept; a new KSP per evaluation also kept ~15 MB each alive).
    workspace: dict = field(default_factory=dict, repr=False)
    #: The leads' share of every reading at the last route
    #: (:class:`mscap.fabrication.during.WiringOffset`), added to the plates' capacitances
    #: before J; ``None``: the plates alone.
    wiring: object = None

    def close(self) -> None:
        """Destroy the PETSc solvers of :attr:`workspace` (their factorisations) now:
        petsc4py objects free no native memory when garbage-collected, so every design an
        optimisation remeshed away from kept its factorisations (a multi-start worker grew
        to 3 GB on poking_cross). The design stays usable; an evaluation makes new ones."""
        for solver in self.workspace.values():
            if solver is not None:
                solver.destroy()
        self.workspace.clear()

    def _solvers(self):
        if "electro" not in self.workspace:
            self.workspace["electro"] = LinearSolver("electro_")
            self.workspace["elastic"] = None if self.base.elastic is None else Operator(self.base.elastic)
        return self.workspace["electro"], self.workspace["elastic"]

    @property
    def n_controls(self) -> int:
        return self.deformer.n_controls

    @property
    def poses(self) -> tuple:
        """The design poses, the rows of every capacitance table of this design."""
        return self.designed.poses

    # -- the forward map -------------------------------------------------------------
    def rest_points(self, q) -> tuple[np.ndarray, np.ndarray | None]:
        """Rest positions of the electrostatic and the elastic mesh vertices at ``q``."""
        fine = self.deformer.points3d(self.base.mesh, q)
        if self.base.elastic is None or self.elastic_weights is None:
            return fine, None
        mesh = self.base.elastic.mesh
        elastic = np.array(mesh.points, dtype=float)
        shift = self.elastic_weights @ self.deformer._q(q)
        elastic[:, :2] += np.tile(shift, (len(mesh.points) // len(shift), 1))
        return fine, elastic

    def evaluate(self, q, warm: Evaluation | list | None = None) -> Evaluation:
        """J, d, barrier, smoothing and C at ``q``; each pose warm-starts from ``warm``
        (an :class:`Evaluation` of this design, or per-pose displacements)."""
        started = time.perf_counter()
        q = np.array(self.deformer._q(q))
        outlines = self.deformer.outlines(q)
        outline_terms = self.objective.outline_terms(outlines, check=True)
        sim = moved(self.base, *self.rest_points(q))
        starts, stale = warm, None
        if isinstance(warm, Evaluation):
            starts = warm.starts_at(sim.elastic.rest) if sim.elastic is not None else warm.displacements()
            stale = warm.factorisations(sim.elastic)
        solver, operator = self._solvers()
        # No factorisation is kept here: the gradient factorises each pose's Hessian when asked
        # (Evaluation.factorise), so a rejected trial costs none and holds no memory.
        results = solve_poses(sim, self.poses, self.scene.elastic, solver, operator, starts, stale=stale)
        for result in results:
            if not np.isfinite(result.capacitance_pF).all():
                raise DesignError(f"pose {result.name!r}: capacitances {result.capacitance_pF} are not finite")
        sim = replace(sim, poses=results)
        iterations = tuple(0 if r.state is None else r.state.newton_iterations for r in results)
        return self._evaluation(q, sim.capacitance_pF, sim, iterations, outlines, outline_terms, started)

    def _evaluation(self, q, plates_pF: np.ndarray, sim, iterations, outlines, outline_terms,
                    started: float) -> Evaluation:
        """The evaluation of the plates' capacitances ``plates_pF`` at ``q``: the leads'
        share added (:attr:`wiring`), then J, ∂J/∂C and the error estimate."""
        offset = None if self.wiring is None else self.wiring.offset_pF
        if offset is not None and offset.shape != plates_pF.shape:
            raise DesignError(f"the leads' share is {offset.shape} (poses, capacitors), the design's "
                              f"capacitances {plates_pF.shape}")
        capacitance = plates_pF if offset is None else plates_pF + offset
        parts, dJ_dC = self.objective.parts_and_gradient(capacitance, outline_terms)
        if not np.isfinite(parts.J):
            raise DesignError(f"J = {parts.J} is not finite ("
                              + ", ".join(f"{name} = {v}" for name, v in parts.terms.items()) + ")")
        error_J, margin_error = self.errors.estimate(dJ_dC, capacitance, outlines)
        return Evaluation(q, parts.J, parts.terms, capacitance, sim, iterations,
                          time.perf_counter() - started, error_J=error_J, margin_error_pF=margin_error, dJ_dC=dJ_dC,
                          offset_pF=offset)

    def reevaluated(self, e: Evaluation) -> Evaluation:
        """``e`` (an evaluation of this design's meshes) with this design's leads' share in
        place of the one it was evaluated with: no solve, the same simulation."""
        plates = e.capacitance_pF if e.offset_pF is None else e.capacitance_pF - e.offset_pF
        outlines = self.deformer.outlines(e.q)
        return replace(self._evaluation(e.q, plates, e.sim, e.newton_iterations, outlines,
                                        self.objective.outline_terms(outlines, check=True), time.perf_counter()),
                       time_s=e.time_s, released=e.released)

    def rerouted(self, q, progress=None) -> "Design":
        """This design with its leads routed again at ``q`` and their share of every reading
        simulated (:func:`mscap.fabrication.during.wiring_offset`); itself, with a warning,
        when the outlines at ``q`` cannot be routed (J keeps the last route's share)."""
        from mscap.fabrication.during import wiring_offset

        try:
            wiring = wiring_offset(self.scene, self.sheet, self.deformer.outlines(q), progress, poses=self.poses)
        except FabricationError as exc:
            log.warning("routing during the optimisation: %s; J keeps %s", exc,
                        "the plates alone" if self.wiring is None else "the last route's leads")
            return self
        return replace(self, wiring=wiring)

    def gradient(self, q_or_evaluation) -> np.ndarray:
        """``dJ/dq`` ``(c, 2)`` at an :class:`Evaluation` (or at ``q``, evaluated first)."""
        e = q_or_evaluation if isinstance(q_or_evaluation, Evaluation) else self.evaluate(q_or_evaluation)
        if e.released:
            raise DesignError("this evaluation's factorisations were released; evaluate again")
        outlines = self.deformer.outlines(e.q)
        dJ_dC = e.dJ_dC if e.dJ_dC is not None else self.objective.capacitance.gradient(e.capacitance_pF)
        dJ_doutlines = self.objective.geometry.value_and_gradient(outlines)[1]
        # Capacitance part: one elastic adjoint per pose, to both rest meshes.
        g_fine = np.zeros_like(e.sim.mesh.points)
        g_elastic = None if e.sim.elastic is None else np.zeros((e.sim.elastic.n_vertices, 3))
        for i, pose in enumerate(self.poses):
            e.factorise(i, pose, self.scene.elastic)
            part = pose_rest_gradient(e.sim, i, dJ_dC[i], pose)
            g_fine += part.fine
            if g_elastic is not None:
                g_elastic += part.elastic
        grad = self.deformer.vjp(g_fine)
        if g_elastic is not None:
            if self.elastic_weights is None:  # shared mesh: the same positions
                grad += self.deformer.vjp(g_elastic)
            else:
                n2 = len(self.elastic_weights)
                grad += self.elastic_weights.T @ g_elastic.reshape(-1, n2, 3)[:, :, :2].sum(axis=0)
        grad += self.outline_gradient(e.q, dJ_doutlines)
        if not np.isfinite(grad).all():
            raise DesignError(f"dJ/dq is not finite ({int((~np.isfinite(grad)).sum())} entries)")
        return grad

    @cached_property
    def errors(self) -> ErrorModel:
        """The a-priori error model of this design's meshes and poses."""
        return error_model(self.sheet, self.scene.elastic, self.poses)

    def outline_gradient(self, q, dJ_doutlines=None) -> np.ndarray:
        """The outline part of ``dJ/dq`` ``(c, 2)``: ``w_b (B + B_area) + w_s S``
        (:attr:`LayoutObjective.geometry`) through the controls, no simulation; given
        ``dJ_doutlines`` (one ``(n_j, 2)`` per outline), from those."""
        if dJ_doutlines is None:
            dJ_doutlines = self.objective.geometry.value_and_gradient(self.deformer.outlines(q))[1]
        # Outline vertices are fine-mesh vertices.
        g2d = np.zeros((len(self.deformer.rest2d), 2))
        for chain, g in zip(self.deformer.outline_vertices, dJ_doutlines):
            np.add.at(g2d, chain, g)
        return self.deformer.vjp(g2d)

    def refined(self, q) -> "Design":
        """Twice the control points (:meth:`Deformer.refined`) on the geometry at ``q``:
        the rest meshes move there (same numbering, so warm starts carry over) and the new
        design starts at ``q = 0``."""
        fine, elastic = self.rest_points(q)
        base = moved(self.base, fine, elastic)
        deformer = self.deformer.refined(q)
        weights = None
        if base.elastic is not None and base.transfer is not None:
            weights = elastic_weights(deformer, base.elastic.mesh.mesh2d)
        # Same meshes, same patterns: the solvers (and their symbolic factorisations) carry over.
        return Design(self.scene, replace(self.sheet, layout=deformer.layout(deformer.zeros())), base, deformer,
                      weights, self.objective, self.designed, self.workspace, self.wiring)


def elastic_weights(deformer: Deformer, elastic_mesh2d) -> np.ndarray:
    """``T2d W`` ``(n_el2d, c)``: the skinning weights interpolated (P1 on the deformer's
    mesh) at the elastic mesh's 2D vertices."""
    return np.asarray(p1_matrix(deformer.mesh2d, elastic_mesh2d.points) @ deformer.weights)


def build_design(scene: Scene, *, sheet: Sheet | None = None, control_spacing_mm: float | None = None,
                 count=None, method: str | None = None, base: Simulation | None = None,
                 objective: LayoutObjective | None = None, poses: DesignPoses | None = None) -> Design:
    """Mesh ``sheet`` (default the scene's own; a start's, sized for its layout, is
    :func:`mscap.scene.sizing.sheet_for`) and build the design of ``scene``.

    Controls: ``count`` per outline, else ``control_spacing_mm`` (default: the scene's
    ``[optimizer] control_spacing_mm``); ``method``: skinning (default the scene's);
    ``objective``: J (default the scene's, :func:`~mscap.design.objective.layout_objective`;
    a remesh keeps the design's own); ``poses``: the design poses (default the scene's,
    :func:`~mscap.design.readback.design_poses`; a remesh keeps the design's own).
    """
    sheet = sheet or scene.sheet
    # The stages in floor order (docs/architecture.md): the scene's design poses and
    # checks, the meshes, the rest problems on them, then the design's own objects.
    designed = poses or design_poses(scene)
    check_designable(scene, designed.poses)
    if base is None:
        base = rest_problems(sheet, scene.elastic, designed.poses)
    settings = scene.optimizer
    spacing = None if count is not None else (control_spacing_mm or settings.control_spacing_mm)
    deformer = build_deformer(base.mesh.mesh2d, sheet.layout, spacing_mm=spacing, count=count,
                              method=method or settings.skinning)
    weights = None
    if base.elastic is not None and base.transfer is not None:
        weights = elastic_weights(deformer, base.elastic.mesh.mesh2d)
    return Design(scene, sheet, base, deformer, weights, objective or layout_objective(scene, designed=designed),
                  designed)


def rest_problems(sheet: Sheet, elastic: ElasticSettings, poses) -> Simulation:
    """The rest meshes and problems of ``sheet`` and ``elastic`` (``[elastic]``) for
    ``poses`` (a :class:`Simulation` without poses): the electrostatic mesh and the elastic
    one the poses need (the mesh floor), then the electrostatic and elastic problems and
    the transfer between them (the fem floor)."""
    mesh = mesh_sheet(sheet)
    electrostatic.check_plates(mesh)  # a bad layout fails before the elastic mesh is made
    elastic_mesh = None if all(p.kind == "free" for p in poses) else mesh_elastic(sheet, elastic, mesh, poses)
    problem, transfer = elastic_setup(sheet, elastic, mesh, poses, elastic_mesh=elastic_mesh)
    electro = electrostatic.build_problem(mesh, sheet.layers, *element_of(sheet.mesh))
    return Simulation(sheet.name, mesh, problem, electro, (), {}, transfer)
