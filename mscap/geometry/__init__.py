"""Planar geometry of the sheet (mm): polygon kernels, capacitor layouts, initial layouts."""
