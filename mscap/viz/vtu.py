"""Solved fields as VTU files for ParaView: the potentials of ``mscap capacitance`` and
every pose of ``mscap simulate`` (displacement, φ per capacitor, J, stress, von Mises)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mscap.mesh.io import write_mesh

__all__ = ["write_potentials", "write_poses"]


def _field_name(problem, plate: int) -> str:
    k = problem.k
    return f"phi_{plate - k}" if plate >= k else f"phi_bottom_{plate}"


def write_potentials(directory, mesh, problem, caps) -> Path:
    """``directory/potential.vtu``: the potential φ of each excited plate of ``caps``
    (``phi_j`` for the top plate of capacitor j, ``phi_bottom_j`` for a bottom plate)."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "potential.vtu"
    phi = caps.vertex_potentials(len(mesh.points))
    data = {_field_name(problem, plate): phi[:, i] for i, plate in enumerate(caps.plates)}
    write_mesh(path, mesh, point_data=data)
    return path


def write_poses(directory, sim) -> list[Path]:
    """One :func:`write_pose` per pose of the ``Simulation`` ``sim``; the files written."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    return [path for result in sim.poses for path in write_pose(out, sim, result)]


def write_pose(directory: Path, sim, result) -> list[Path]:
    """``<pose>.vtu`` on the electrostatic mesh (displacement, φ_j; J and stress too when
    the elastic problem shares the mesh) and, for an elastic problem on its own mesh,
    ``<pose>_elastic.vtu`` with its displacement, J and stress."""
    from mscap.fem.elastic.problem import tet_fields

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
            path = directory / f"{result.name}_elastic.vtu"
            vertices = nodes[:problem.n_vertices]
            write_mesh(path, problem.mesh, points=vertices,
                       point_data={"displacement": vertices - problem.mesh.points}, cell_data=fields)
            written.append(path)
    path = directory / f"{result.name}.vtu"
    write_mesh(path, mesh, points=result.vertices, point_data=point_data, cell_data=cell_data)
    return [path] + written

