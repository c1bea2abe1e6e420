"""Solved fields as VTU files for ParaView: the potentials of ``mscap capacitance`` and
every pose of ``mscap simulate`` (displacement, φ per capacitor, J, stress, von Mises).

One convention: every file holds its mesh at rest, and a pose's file the point field
``displacement`` (mm) to its equilibrium, so ParaView's Warp By Vector at scale 1 (pyvista:
``warp_by_vector``) draws the deformed pose and scale 0 the rest layout. ``poses.pvd``
(and ``poses_elastic.pvd`` for an elastic mesh of its own) collects the poses as time
steps 0, 1, ... in the scene's order: open it and step through them. Files are named by
:func:`mscap.outputs.file_stems` of the pose names and written by
:func:`mscap.outputs.replace_file` (a link in the directory is replaced, not followed).
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from mscap.mesh.io import write_mesh
from mscap.outputs import file_stems, output_directory, replace_file

__all__ = ["write_potentials", "write_poses", "write_pose", "write_collection"]


def _field_name(problem, plate: int) -> str:
    k = problem.k
    return f"phi_{plate - k}" if plate >= k else f"phi_bottom_{plate}"


def write_potentials(directory, mesh, problem, caps) -> Path:
    """``directory/potential.vtu``: the potential φ of each excited plate of ``caps``
    (``phi_j`` for the top plate of capacitor j, ``phi_bottom_j`` for a bottom plate)."""
    out = output_directory(directory, "--export")
    phi = caps.vertex_potentials(len(mesh.points))
    data = {_field_name(problem, plate): phi[:, i] for i, plate in enumerate(caps.plates)}
    return replace_file(out / "potential.vtu", lambda path: write_mesh(path, mesh, point_data=data))


def write_poses(directory, sim) -> list[Path]:
    """:func:`write_pose` for every pose of the ``Simulation`` ``sim``, then
    ``poses.pvd`` over the ``<pose>.vtu`` and ``poses_elastic.pvd`` over the
    ``<pose>_elastic.vtu`` files; the files written."""
    out = output_directory(directory, "--export")
    stems = file_stems([result.name for result in sim.poses])
    per_pose = [write_pose(out, sim, result, stem) for result, stem in zip(sim.poses, stems)]
    names = [result.name for result in sim.poses]
    collections = [write_collection(out / collection, names, files)
                   for collection, files in zip(("poses.pvd", "poses_elastic.pvd"), zip(*per_pose))]
    return [path for files in per_pose for path in files] + collections


def write_pose(directory: Path, sim, result, stem: str | None = None) -> list[Path]:
    """``<stem>.vtu`` (``stem``: default the pose name as a file stem,
    :func:`mscap.outputs.file_stem`): the electrostatic mesh at rest with the pose's ``displacement`` and
    φ_j (J and stress too when the elastic problem shares the mesh) and, for an elastic
    problem on its own mesh, ``<pose>_elastic.vtu``: that mesh at rest with its
    ``displacement``, J and stress (without the ``layer`` and ``capacitor`` tags, which
    belong to the electrostatic mesh)."""
    from mscap.fem.elastic.problem import tet_fields

    stem = stem or file_stems([result.name])[0]
    mesh, problem = sim.mesh, sim.elastic
    point_data = {"displacement": result.vertices - mesh.points}
    phi = result.capacitances.top_potentials[:len(mesh.points)]
    for j in range(phi.shape[1]):
        point_data[f"phi_{j}"] = phi[:, j]
    cell_data = {}
    written = []
    if problem is not None:
        nodes = result.state.nodes if result.state else problem.rest
        j, stress = tet_fields(problem, nodes)
        deviator = stress - np.trace(stress, axis1=1, axis2=2)[:, None, None] * np.eye(3) / 3
        fields = {"J": j, "stress": stress.reshape(-1, 9),
                  "von_mises": np.sqrt(1.5 * np.einsum("mij,mij->m", deviator, deviator))}
        if sim.transfer is None:
            cell_data = fields
        else:
            displacement = nodes[:problem.n_vertices] - problem.mesh.points
            written.append(replace_file(directory / f"{stem}_elastic.vtu", lambda path: write_mesh(
                path, problem.mesh, point_data={"displacement": displacement}, cell_data=fields, tags=False)))
    path = replace_file(directory / f"{stem}.vtu",
                        lambda path: write_mesh(path, mesh, point_data=point_data, cell_data=cell_data))
    return [path] + written


def write_collection(path: Path, names: list[str], files: list[Path]) -> Path:
    """The ParaView collection ``path`` (``.pvd``): time step i is ``files[i]``, named
    ``names[i]``, by its path relative to the collection."""
    root = ET.Element("VTKFile", type="Collection", version="0.1", byte_order="LittleEndian")
    collection = ET.SubElement(root, "Collection")
    for step, (name, file) in enumerate(zip(names, files)):
        ET.SubElement(collection, "DataSet", timestep=str(step), group="", part="0", name=name,
                      file=os.path.relpath(file, path.parent))
    ET.indent(root)
    return replace_file(path, lambda temporary: ET.ElementTree(root).write(temporary, encoding="utf-8",
                                                                           xml_declaration=True))
