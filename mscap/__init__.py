"""mscap: computational design of capacitive stretch sensors.

The pipeline, one subpackage per stage (docs/architecture.md draws it)::

    scene         load_scene(path) -> Scene                 the TOML file, every check
    geometry      initial_layout(scene, k, seed, init)       plate outlines in the sheet plane
    mesh          mesh_sheet(scene.sheet) -> LayeredMesh     gmsh triangulation, layered tets
    fem           simulate(scene) -> Simulation              per pose: Newton, then capacitances
    design        build_design(scene) -> Design;             J(q) and dJ/dq by adjoints,
                  optimize(design) -> OptimizeResult         L-BFGS with remeshing
    service       run_multistart(scene, "out.h5")            starts farmed over MPI, HDF5, k
    calibration   simulate_family / evaluate                 read-back error of chosen designs
    readout       the multiplexed read-out of the array
    viz, cli      figures; the ``mscap`` command

A forward simulation and one design gradient::

    import mscap
    scene = mscap.load_scene("jobs/quick.toml")
    sim = mscap.simulate(scene)                      # sim.capacitance_pF: (poses, k)
    design = mscap.build_design(scene)
    e = design.evaluate(design.deformer.zeros())     # e.J, e.capacitance_pF
    g = design.gradient(e)                           # dJ/dq, one adjoint per pose

The names below load their stage on first use, so ``import mscap`` (and the HDF5 store,
``mscap inspect``) does not pay for PETSc and the FEM stack.
"""

from __future__ import annotations

from mscap._lazy import lazy_names
from mscap.errors import GeometryError, MeshError, MscapError, SceneError  # noqa: F401 (in __all__)

__version__ = "0.1.0"

__all__, __getattr__ = lazy_names(__name__, {
    "load_scene": "mscap.scene.loader",
    "Scene": "mscap.scene.settings",
    "simulate": "mscap.fem.simulate",
    "build_design": "mscap.design.pipeline",
    "optimize": "mscap.design.optimizer",
    "run_multistart": "mscap.service.multistart",
}, eager=("__version__", "MscapError", "SceneError", "GeometryError", "MeshError"))
