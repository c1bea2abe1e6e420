"""Figures and field files for viewing: :mod:`~mscap.viz.layouts` (a results file's best
layout per k, and the layout drawing every figure shares), :mod:`~mscap.viz.optimize` (one
start, before and after), :mod:`~mscap.viz.calibration` (reconstruction error per pose),
:mod:`~mscap.viz.vtu` (solved fields as VTU files for ParaView).

matplotlib is imported inside the drawing functions (Agg backend), never on import.

Its public names load their module on first use.
"""

from mscap._lazy import lazy_names

__all__, __getattr__ = lazy_names(__name__, {
    "plot_results": "layouts",
    "draw_layout": "layouts",
    "optimize_figure": "optimize",
    "error_figure": "calibration",
    "plot_routing": "fabrication",
    "write_poses": "vtu",
})
