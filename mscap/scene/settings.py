"""What a scene holds: the sheet, its layers, capacitors, poses and every settings table,
as frozen dataclasses, and the allowed values of each choice (read by
:mod:`mscap.scene.loader`, which checks them all).

Units. Scene keys carry their unit in the name (``_mm``, ``_MPa``, ``_pF2``); the one
conversion happens here: relative permittivity becomes absolute permittivity in pF/mm.
Inside mscap, lengths are mm, stresses MPa (so energies are N·mm = mJ) and
capacitances pF.

Everything loaded is a frozen dataclass; every bad value raises
:class:`~mscap.errors.SceneError` naming the file, the key and the value.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from mscap.geometry.layout import Layout
from mscap.scene.calibration import MAX_FAMILY_POSES, MAX_NOISE_RUNS, MAX_SEED, CalibrationSettings

__all__ = [
    "EPSILON0_PF_PER_MM", "Material", "Layer", "MeshSettings", "ElasticSettings", "auto_slabs", "OptimizerSettings",
    "MultistartSettings", "FabricationSettings", "CONNECTOR_EDGES", "Sheet", "Scene", "LAYER_KINDS", "POSE_KINDS",
    "HESSIAN_MODES", "ELASTIC_MESHES",
    "SKINNING_METHODS", "DISTANCES", "DESIGN_POSES", "DEFAULT_FAMILY_COUNT", "MAX_STARTS_PER_K",
    "MAX_SCENE_BYTES", "MAX_LENGTH_MM", "MIN_LENGTH_MM", "LAYER_THICKNESS_MM", "YOUNGS_MODULUS_MPA",
    "MAX_RELATIVE_PERMITTIVITY", "STRETCH_RANGE", "MAX_SLABS", "MAX_CAPACITORS", "MAX_OUTLINE_VERTICES",
    "MAX_LOAD_STEPS", "MAX_ITERATIONS", "MAX_CUTS", "MAX_CASCADE_LEVELS", "MAX_FAMILY_POSES", "MAX_NOISE_RUNS",
    "MAX_SEED", "BALL_EDGE_RATIO", "POSE_NAME_PATTERN", "MAX_NAME_LENGTH", "PETSC_TYPES",
]

#: Vacuum permittivity, 8.8541878128e-12 F/m, in pF/mm.
EPSILON0_PF_PER_MM = 8.8541878128e-3

#: The fixed stack, bottom to top (paper §4.1).
LAYER_KINDS = ("dielectric", "conductive", "dielectric", "conductive", "dielectric")
POSE_KINDS = ("free", "stretch", "poke", "glue")
#: How Newton treats an indefinite Hessian (:mod:`mscap.fem.elastic.newton`).
HESSIAN_MODES = ("auto", "exact", "projected")
#: Where the elastic problem lives (``[elastic] mesh``).
ELASTIC_MESHES = ("own", "shared")
#: Skinning weights of the deformer (``[optimizer] skinning``, :mod:`mscap.design.deformer`).
SKINNING_METHODS = ("bbw", "harmonic")
#: ``[optimizer] distance``: how pose capacitance vectors are compared
#: (:func:`mscap.design.objective.capacitance_term`).
DISTANCES = ("pF", "noise", "reconstruction", "readback")
#: ``[optimizer] design_poses`` (:mod:`mscap.design.readback`).
DESIGN_POSES = ("listed", "family", "both")
#: Grid points per calibration parameter when ``family_grid`` is not given.
DEFAULT_FAMILY_COUNT = 2
#: Start indices are 0..999 per k (a start's seed is scene seed · 10⁶ + k · 10³ + index).
MAX_STARTS_PER_K = 1000
#: Noise seeds of a multi-start's in-run calibration: each is a refit-free re-score (cheap),
#: but more than this says nothing the spread of a few does not.
MAX_CALIBRATE_SEEDS = 100

# Physical ranges. A value outside is a unit mistake or asks for what the model does not
# describe; the loader refuses it naming the key, the range and the reason given here.
#: A scene file is a few kB; larger is not a scene (and would be read whole).
MAX_SCENE_BYTES = 16 * 2**20
#: Sheet sizes, coordinates and other lengths: 10 m (the keys are in mm).
MAX_LENGTH_MM = 10_000.0
#: Mesh edges and other lengths from below: 1 µm, thinner than any cast silicone film.
MIN_LENGTH_MM = 1e-3
#: ``[capacitors] min_gap_mm`` when a scene gives none.
DEFAULT_MIN_GAP_MM = 1.0
#: A layer of a stretchable sheet, 1 µm to 10 mm: thicker is a block, which one slab per
#: layer cannot bend.
LAYER_THICKNESS_MM = (1e-3, 10.0)
#: 0.1 kPa (a gel) to 10 GPa (a rigid plastic); elastomers are 0.01-10 MPa.
YOUNGS_MODULUS_MPA = (1e-4, 1e4)
#: εr of the stiffest ceramics (barium titanate) is some thousands.
MAX_RELATIVE_PERMITTIVITY = 1e4
#: Stretch ratios between grips: below 0.5 the sheet does not shorten, it buckles out of
#: plane (λ = 1e-6 converged to a sheet arched 32 mm high), and an elastomer tears long
#: before 10 times its length.
STRETCH_RANGE = (0.5, 10.0)
#: Tet slabs per layer or through the stack: studied settings use 1-2, the tet count
#: grows linearly with it.
MAX_SLABS = 32
#: Capacitors in a layout (and the multi-start's k_max): each costs one electrostatic solve
#: per pose, and the loader's pairwise layout check is quadratic in them (100 plates 7.6 s,
#: 400 plates 131 s on a 2-core Xeon); no sensor here has more than 9.
MAX_CAPACITORS = 100
#: Vertices of one outline, given or generated (a disk has one every outline edge).
MAX_OUTLINE_VERTICES = 100_000
#: Initial load steps of a pose (each a Newton solve).
MAX_LOAD_STEPS = 1000
#: Newton iterations per load step, L-BFGS steps per cascade level.
MAX_ITERATIONS = 100_000
#: Halvings of a load step: 2⁻⁶⁰ of a step is below double precision of the load fraction.
MAX_CUTS = 60
#: Doublings of the control points: 2¹⁰ times the first level's.
MAX_CASCADE_LEVELS = 10
#: A poke's ball must be at least this times the elastic edge under it: a footprint of
#: radius R contains a mesh node only if R exceeds about h/√3 (the centroid of an
#: equilateral triangle of edge h); a smaller ball passes between the nodes (radius 1 mm
#: with 5 mm edges, pushed 3 mm deep: no Newton step, exactly the rest capacitances).
BALL_EDGE_RATIO = 0.5
#: Pose names become file names (``mscap simulate --export DIR`` writes DIR/<pose>.vtu):
#: letters, digits, ``_``, ``-``, ``+``, ``.`` and inner spaces, starting with a letter
#: or digit, at most :data:`MAX_NAME_LENGTH` characters.
POSE_NAME_PATTERN = r"[^\W_]([\w.+ -]*[\w+-])?"
MAX_NAME_LENGTH = 100
#: The KSP, PC and factorisation-package names PETSc 3.18 knows (``[petsc] *ksp_type``,
#: ``*pc_type``, ``*mat_solver_type``); tests/scene/test_checks.py compares them with the
#: installed petsc4py's.
PETSC_TYPES = {
    "ksp_type": ("bcgs", "bcgsl", "bicg", "cg", "cgls", "cgne", "cgs", "chebyshev", "cr", "dgmres", "fbcgs",
                 "fbcgsr", "fcg", "fetidp", "fgmres", "gcr", "gltr", "gmres", "groppcg", "hpddm", "ibcgs", "lcd",
                 "lgmres", "lsqr", "minres", "nash", "none", "pgmres", "pipebcgs", "pipecg", "pipecg2",
                 "pipecgrr", "pipecr", "pipefcg", "pipefgmres", "pipegcr", "pipelcg", "pipeprcg", "preonly",
                 "python", "qcg", "qmrcgs", "richardson", "stcg", "symmlq", "tcqmr", "tfqmr", "tsirm"),
    "pc_type": ("asm", "bddc", "bfbt", "bjacobi", "cholesky", "chowiluviennacl", "composite", "cp", "deflation",
                "eisenstat", "exotic", "fieldsplit", "galerkin", "gamg", "gasm", "h2opus", "hmg", "hpddm", "hypre",
                "icc", "ilu", "jacobi", "kaczmarz", "ksp", "lmvm", "lsc", "lu", "mat", "mg", "ml", "nn", "none",
                "parms", "patch", "pbjacobi", "pfmg", "python", "qr", "redistribute", "redundant",
                "rowscalingviennacl", "saviennacl", "shell", "sor", "spai", "svd", "syspfmg", "telescope", "tfs",
                "vpbjacobi"),
    "mat_solver_type": ("bas", "cholmod", "cuda", "cusparse", "elemental", "essl", "klu", "lusol", "matlab",
                        "mkl_cpardiso", "mkl_pardiso", "mumps", "pastix", "petsc", "scalapack", "sparseelemental",
                        "spqr", "strumpack", "superlu", "superlu_dist", "umfpack"),
}


@dataclass(frozen=True)
class Material:
    """An isotropic silicone: Young's modulus (MPa), Poisson ratio, permittivity."""

    name: str
    youngs_modulus_MPa: float
    poisson_ratio: float
    relative_permittivity: float

    @property
    def permittivity_pF_per_mm(self) -> float:
        """Absolute permittivity ε = εr ε0 in pF/mm."""
        return self.relative_permittivity * EPSILON0_PF_PER_MM

    @property
    def lame_MPa(self) -> tuple[float, float]:
        """Lamé parameters (μ, λ) in MPa."""
        e, nu = self.youngs_modulus_MPa, self.poisson_ratio
        return e / (2 * (1 + nu)), e * nu / ((1 + nu) * (1 - 2 * nu))


@dataclass(frozen=True)
class Layer:
    """One layer of the stack. In a conductive layer ``material`` is the plate
    material and ``fill`` the material of the rest of the layer."""

    name: str
    kind: str
    thickness_mm: float
    material: Material
    fill: Material | None = None


@dataclass(frozen=True)
class MeshSettings:
    """Target sizes for the 2D triangulation and the extrusion. ``tolerance``: the relative
    capacitance error the sizes were chosen for (:mod:`mscap.scene.sizing`), None when
    the scene set them by hand; ``overrides``, the ``(key, value)`` pairs the scene gave
    beside it, which win over the sizes the tolerance asks for. Within
    ``fringe_distance_mm`` of the outlines the edge length grows no faster than
    ``fringe_slope`` (0: one ramp over ``grading_distance_mm``). ``zones``: ``(x, y,
    radius, size)`` discs (mm) within which no edge is longer than ``size``, growing at 0.5
    mm per mm beyond (under the balls of poke poses, :func:`mscap.scene.sizing.poke_zones`);
    the electrostatic mesh and a P1 elastic mesh follow them. ``strips``: ``(x_min, y_min,
    x_max, y_max, size)`` boxes (mm) likewise (along the held edges of a P2 elastic mesh,
    :func:`mscap.scene.sizing.p2_poke_refinement`). ``curvature_edge_mm``: the
    largest far edge the glued poses' bends allow (:func:`mscap.scene.sizing.curvature_edge`;
    ``None`` without a glued pose), which a tolerance's sizes keep to."""

    edge_length_mm: float
    edge_length_outline_mm: float
    grading_distance_mm: float
    elements_per_layer: int = 1
    order: int = 1
    tolerance: float | None = None
    fringe_distance_mm: float = 0.0
    fringe_slope: float = 0.5
    overrides: tuple[tuple[str, float], ...] = ()
    zones: tuple[tuple[float, float, float, float], ...] = ()
    curvature_edge_mm: float | None = None
    strips: tuple[tuple[float, float, float, float, float], ...] = ()
    #: The relative error the scene accepts on its pose-to-pose gains (``[mesh]
    #: signal_tolerance``); on a poked scene it chooses the elastic order and edge
    #: (:func:`mscap.scene.sizing.elastic_for_signal`). None: the elastic settings as given.
    signal_tolerance: float | None = None
    #: The electrostatic element: ``"tet"`` (three per prism of the extruded mesh, P1 or
    #: P2) or ``"prism"`` (the prism itself, P1: about 3× less error on the same
    #: vertices, :mod:`mscap.fem.wedge`).
    element: str = "tet"


@dataclass(frozen=True)
class ElasticSettings:
    """Elastic solver settings (scene table ``[elastic]``); see :mod:`mscap.fem.elastic.newton`.

    ``mesh = "own"`` (default) solves on a mesh of its own (:func:`mscap.mesh.layered.mesh_elastic`):
    the same outlines, ``edge_length_mm`` (outlines: ``edge_length_outline_mm``, default
    half of it) and ``elements_through_thickness`` even slabs through the whole stack (0:
    the electrostatic levels, one slab per layer times ``[mesh] elements_per_layer``).
    ``"shared"`` solves on the electrostatic mesh itself. ``refine_pokes``: a P2 mesh of
    its own is refined under each ball and along the edges a poke holds, when the
    electrostatic mesh refines under the balls too (:func:`mscap.scene.sizing.refines_pokes`;
    ``false``: uniform, as before 2026-12-05).
    The defaults come from benchmarks/elastic_error_vs_time.py (docs/elastic.md); a scene
    file that does not set ``elements_through_thickness`` gets :func:`auto_slabs`."""

    tolerance: float = 1e-8
    step_tolerance: float = 1e-4
    max_iterations: int = 30
    max_cuts: int = 10
    hessian: str = "auto"
    order: int = 1
    mesh: str = "own"
    edge_length_mm: float = 5.0
    edge_length_outline_mm: float | None = None
    elements_through_thickness: int = 1
    refine_pokes: bool = True


def auto_slabs(layers) -> int:
    """``elements_through_thickness`` for a stack: 1 when every material in it has the
    same Poisson ratio, else 0 (one slab per layer).

    One slab through the stack gives every layer the same thickness stretch. Layers of
    equal ν (hence equal λ/μ) take the same one under any in-plane stretch, whatever
    their E, so one slab is exact for homogeneous stretches; with unequal ν it is not:
    C/C0 of an equibiaxial 1.25 stretch reads 2.06 / 0.69 / 0.22 % low for conductive
    layers of ν = 0.30 / 0.45 / 0.465 against a dielectric of 0.47 (λ/μ = 2ν/(1 − 2ν)
    is steep near 0.5), and the layer-aligned mesh is exact (docs/elastic.md)."""
    ratios = {m.poisson_ratio for layer in layers for m in (layer.material, layer.fill) if m is not None}
    return 1 if max(ratios) - min(ratios) <= 1e-12 else 0


#: Default plateau rule of a level: J gained less than STALL_TOLERANCE · |J| over
#: the last STALL_WINDOW accepted steps (docs/optimize.md, "Cascade").
STALL_WINDOW = 10
STALL_TOLERANCE = 1e-2


@dataclass(frozen=True)
class OptimizerSettings:
    """Design-optimisation settings (scene table ``[optimizer]``; :mod:`mscap.design.optimizer`).

    ``distance`` (``"pF"``, ``"noise"``, ``"reconstruction"`` or ``"readback"``: capacitance
    differences in pF, read-out differences in the noise of the calibration's protocol, the
    Cramér–Rao bound on the read-back error over the family, or that bound ⊕ the noise the
    calibration's own map adds on the grid, :mod:`mscap.design.readback`),
    ``tau_pF2`` / ``tau_noise`` / ``tau_mm`` (the soft minimum's or maximum's temperature
    in those units), ``barrier_weight``, ``smoothing_weight``: the objective
    (:func:`mscap.design.objective.layout_objective`). ``design_poses``: ``"listed"`` (the
    scene's poses), ``"family"`` (a sub-grid of the ``[calibration]`` training family with
    ``family_grid`` points per parameter, one count for all or one each; default 2, and
    the reference pose) or ``"both"``. ``max_plate_area_mm2``: a barrier on the total
    plate area (0: none). A scene with a ``[calibration]`` that names no ``distance``
    gets ``"reconstruction"`` on ``"family"`` (:func:`_objective_defaults`).
    ``max_iterations``: accepted L-BFGS steps per cascade level; ``cascade_levels``:
    doublings of the controls after the first level converges. ``control_spacing_mm``: arc
    length between control points on the outlines; ``skinning``: ``"bbw"`` or ``"harmonic"`` weights. Convergence of a level:
    J falls by less than ``relative_tolerance`` · max(|J|, 1) in a step, or ‖dJ/dq‖ drops
    below ``gradient_tolerance`` times its value at the level's start, or J has fallen by
    less than ``stall_tolerance`` · |J| over the last ``stall_window`` steps on one
    mesh (0: never; a plateau's tail of small steps, docs/optimize.md). Steps:
    steepest-descent steps start at ``first_step_mm`` (largest control displacement) and
    double while accepted whole; no step moves a control more than ``max_step_mm``.
    Remesh when a 2D angle drops below ``remesh_angle_deg`` (or below half the fresh
    mesh's smallest angle, if that is less); ``keep_memory_at_remesh``: the L-BFGS
    curvature pairs carry over to the new mesh (``false``: restart them, the behaviour
    before 2026-12-04). ``min_feature_mm``: the narrowest neck or slot a plate may have
    (0: no limit), a barrier like the gap's between two parts of one outline
    (:class:`mscap.design.objective.SeparationBarrier`). ``screen_trials``: a line-search
    trial whose outline terms alone rise by more than twice what the capacitance term can
    gain to first order is rejected before it is simulated
    (:data:`mscap.design.optimizer.SCREEN_FACTOR`; ``false``: simulate every trial).
    ``resolve_steps``: a trial is accepted only if it also lowers J + δJ, its value plus
    the evaluation's estimated discretisation error (:mod:`mscap.design.resolution`); a
    level whose last line search failed only on that stops as ``"resolved"``
    (``false``: Armijo on J alone, the behaviour before 2026-12-05). ``revive_silent``: a
    plate that reads nothing (leaving it out changes the capacitance term by under 1 %)
    moves, at the start and when a level converges, to where the design poses strain the
    sheet in a way the other plates do not read, if J falls (:mod:`mscap.design.revival`;
    ``false``: never, the behaviour before 2026-12-06)."""

    distance: str = "pF"
    tau_pF2: float = 1.0
    tau_noise: float = 0.05
    tau_mm: float = 0.25
    design_poses: str = "listed"
    family_grid: tuple = ()
    max_plate_area_mm2: float = 0.0
    barrier_weight: float = 1.0
    smoothing_weight: float = 1e-3
    max_iterations: int = 100
    cascade_levels: int = 1
    control_spacing_mm: float = 10.0
    skinning: str = "bbw"
    gradient_tolerance: float = 1e-4
    relative_tolerance: float = 1e-4
    stall_window: int = STALL_WINDOW
    stall_tolerance: float = STALL_TOLERANCE
    first_step_mm: float = 1.0
    max_step_mm: float = 2.0
    remesh_angle_deg: float = 10.0
    keep_memory_at_remesh: bool = True
    min_feature_mm: float = 0.0
    screen_trials: bool = True
    resolve_steps: bool = True
    revive_silent: bool = True


@dataclass(frozen=True)
class MultistartSettings:
    """Multi-start settings (scene table ``[multistart]``; docs/optimize.md): k from
    ``k_min`` to ``k_max``, ``starts_per_k`` starts each, the first
    ``ceil(lloyd_fraction · starts_per_k)`` of them Lloyd layouts; the plateau rule's
    ``plateau_tol``; ``error_estimate``: re-simulate every run's final design on a mesh
    one level finer (:mod:`mscap.service.accuracy`). Pruning (:mod:`mscap.service.pruning`):
    after ``prune_first_step`` accepted steps, and again after ``prune_eta`` times as many,
    a start whose score (min L1 distance, or read-back bound) is not among the best
    1/``prune_eta`` of the starts of its k at that step stops (status ``"pruned"``);
    ``prune_first_step = 0`` (the default) never prunes. ``prune_rule = "envelope"``
    instead stops a start, every ``prune_first_step`` steps, when even the largest gain a
    finished start made from there would leave it below the best of its k (``prune_eta``
    unused; the safe rule, docs/performance.md §8). ``skip_repeated_starts``: leave
    out the Lloyd starts whose initial layout is an earlier one's of their k, plate for
    plate (:func:`mscap.service.selection.repeated_starts`: the same run bit for bit).
    ``check_all_runs``: run the finer-mesh check on every run; by default a run already
    beaten by a finished run of its k, which can never be the best of its k that the
    selection checks, skips it (:func:`mscap.service.multistart.run_start`).
    In a scene with ``[calibration]``, the end of the multi-start calibrates the best
    ``calibrate_best`` runs of each k (by the objective), with their initial layouts
    (``calibrate_initial``) and the scene's layout as a baseline (``calibrate_scene``),
    under ``calibrate_seeds`` noise seeds, and chooses the design and k on calibrated
    read-back error (:mod:`mscap.service.calibrated`); ``calibrate_best = 0`` chooses by
    the objective alone. ``scene_start``: one more start, from the scene's own layout, at
    its k (a hand-placed layout to improve on; :func:`mscap.service.selection.configurations`).
    ``sensitivity_fraction``: the first ``ceil(sensitivity_fraction · starts_per_k)`` starts
    of each k (before the Lloyd ones) are sensitivity-map starts, plates on the sheet's
    regions that the design poses strain differently (:mod:`mscap.design.starts`).
    ``checkpoint_minutes``: a busy start's optimiser state is stored this often (and when
    the job stops), and a rerun continues it there (:mod:`mscap.service.checkpoints`; 0:
    only when the job stops)."""

    k_min: int = 2
    k_max: int = 6
    starts_per_k: int = 25
    lloyd_fraction: float = 0.2
    sensitivity_fraction: float = 0.0
    plateau_tol: float = 0.05
    seed: int = 0
    error_estimate: bool = True
    prune_first_step: int = 0
    prune_eta: int = 3
    prune_rule: str = "rungs"
    skip_repeated_starts: bool = True
    check_all_runs: bool = False
    checkpoint_minutes: float = 10.0
    calibrate_best: int = 3
    calibrate_initial: bool = True
    calibrate_scene: bool = True
    calibrate_seeds: int = 3
    scene_start: bool = False


#: ``[fabrication] connector_edge``: the sheet side the pads sit on (of its bounding box);
#: ``"auto"`` tries each and keeps the cheapest routing (:mod:`mscap.fabrication.router`).
CONNECTOR_EDGES = ("auto", "bottom", "left", "right", "top")


@dataclass(frozen=True)
class FabricationSettings:
    """Design rules of the stencils (scene table ``[fabrication]``; docs/fabrication.md),
    in mm. Defaults a desktop stencil cutter makes in 0.1 mm Mylar: leads
    ``trace_width_mm`` wide, ``clearance_mm`` from every other net of their layer,
    ``edge_distance_mm`` from the sheet edge, bends and junctions filleted with at least
    ``min_radius_mm`` (≤ half the trace width). The connector: ``pad_width_mm`` ×
    ``pad_length_mm`` pads every ``pad_pitch_mm`` (0.1 inch) on ``connector_edge``, each
    masked by a square ``mask_margin_mm`` larger on every side. ``rows``/``columns``: the
    array (0: :func:`mscap.readout.array.grid_array`'s); ``assignments``: slot
    assignments the router tries; ``grid_mm``: the routing grid (0: a fifth of the pad
    pitch, at most half the trace width). ``route_during_optimisation``: the optimiser's
    capacitances are the routed sensor's, re-routed at every remesh
    (:mod:`mscap.fabrication.during`)."""

    trace_width_mm: float = 1.0
    clearance_mm: float = 1.0
    edge_distance_mm: float = 1.0
    min_radius_mm: float = 0.25
    pad_width_mm: float = 1.27
    pad_length_mm: float = 3.0
    pad_pitch_mm: float = 2.54
    mask_margin_mm: float = 0.5
    connector_edge: str = "auto"
    rows: int = 0
    columns: int = 0
    assignments: int = 24
    grid_mm: float = 0.0
    route_during_optimisation: bool = False


@dataclass(frozen=True)
class Sheet:
    """What the mesh stage takes: the sheet's outline, its layers, the plates on it and
    the mesh settings sized for those plates, with the scene file and name that messages
    name. A scene's own is :attr:`Scene.sheet`; a run's, whose plates are its layout, is
    :func:`mscap.scene.sizing.sheet_for` (a design carries it: the scene itself is never
    rebuilt around a run's layout)."""

    path: str
    name: str
    outline_mm: np.ndarray
    layers: tuple[Layer, ...]
    layout: Layout
    mesh: MeshSettings

    @property
    def thicknesses_mm(self) -> list[float]:
        return [layer.thickness_mm for layer in self.layers]


@dataclass(frozen=True)
class Scene:
    """A loaded, validated scene: the sensor (sheet, layers, the file's own plates) and its
    poses, with the settings each stage takes."""

    path: str
    name: str
    description: str
    sheet_outline_mm: np.ndarray
    layers: tuple[Layer, ...]
    layout: Layout
    min_gap_mm: float
    mesh: MeshSettings
    poses: tuple
    elastic: ElasticSettings
    optimizer: OptimizerSettings
    multistart: MultistartSettings
    petsc_options: tuple[tuple[str, str], ...]
    source: str
    calibration: CalibrationSettings | None = None
    fabrication: FabricationSettings = FabricationSettings()

    @property
    def thickness_mm(self) -> float:
        """Total sheet thickness."""
        return sum(layer.thickness_mm for layer in self.layers)

    @property
    def sheet(self) -> Sheet:
        """The mesh stage's input for the scene's own layout."""
        return Sheet(self.path, self.name, self.sheet_outline_mm, self.layers, self.layout, self.mesh)

    @property
    def sha256(self) -> str:
        """Hash of the scene file's text (identifies results of this scene)."""
        return hashlib.sha256(self.source.encode()).hexdigest()
