"""Meshes: the size estimate before meshing (budget), the 2D triangulation (gmsh), the
layered tets, quality, transfer between meshes, io."""
