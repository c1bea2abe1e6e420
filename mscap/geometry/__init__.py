"""Planar geometry of the sheet (mm): polygon kernels, capacitor layouts, initial layouts,
the point locator in triangulations (:mod:`~mscap.geometry.locate`).

Its public names load their module on first use::

    from mscap.geometry import initial_layout, min_gap_mm
    layout = initial_layout(scene, 4, seed=0, init="lloyd")   # four squares at Lloyd centroids
    min_gap_mm(layout.outlines, scene.sheet_outline_mm)
"""

from mscap._lazy import lazy_names

__all__, __getattr__ = lazy_names(__name__, {
    "Layout": "layout",
    "grid_layout": "layout",
    "check_layout": "layout",
    "min_gap_mm": "layout",
    "initial_layout": "initial",
    "TriangleLocator": "locate",
})
