"""Meshes: the size estimate before meshing (budget), the 2D triangulation (gmsh), the
layered tets, quality, io. (Interpolation between meshes is :mod:`mscap.fem.transfer`: it
evaluates finite-element shape functions.)

Its public names load their module on first use::

    from mscap.mesh import mesh_sheet, mesh_report
    mesh = mesh_sheet(scene.sheet)               # gmsh, extruded into layered tets
    mesh_report(mesh)
"""

from mscap._lazy import lazy_names

__all__, __getattr__ = lazy_names(__name__, {
    "mesh_sheet": "layered",
    "mesh_elastic": "layered",
    "LayeredMesh": "layered",
    "extrude": "layered",
    "TriMesh": "triangulate",
    "mesh_report": "quality",
})
