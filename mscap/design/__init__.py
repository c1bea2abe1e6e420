"""Layout design: the forward + gradient pipeline, the objective J, the deformer, the optimiser.

Its public names load their module on first use::

    from mscap.design import optimize, start_design
    layout, design = start_design(scene, 3, seed=0, init="lloyd")
    result = optimize(design)                    # L-BFGS, remeshing, control cascade
    result.layout, result.evaluation.J
"""

from mscap._lazy import lazy_names

__all__, __getattr__ = lazy_names(__name__, {
    "build_design": "pipeline",
    "Design": "pipeline",
    "Evaluation": "pipeline",
    "optimize": "optimizer",
    "OptimizeResult": "optimizer",
    "start_layout": "starts",
    "start_design": "starts",
    "layout_objective": "objective",
})
