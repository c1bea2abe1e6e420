"""Meshes: the 2D triangulation (gmsh), the layered tets, quality, transfer between meshes, io."""
