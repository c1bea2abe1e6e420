"""Reading and writing meshes and fields (meshio, VTU)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mscap.errors import MscapError
from mscap.mesh.layered import LayeredMesh

__all__ = ["write_mesh", "read_mesh", "TetData"]


@dataclass(frozen=True)
class TetData:
    """A tet mesh as stored on disk, with its integer cell tags."""

    points: np.ndarray
    tets: np.ndarray
    layer: np.ndarray
    capacitor: np.ndarray


def write_mesh(path: str | Path, mesh: LayeredMesh, points: np.ndarray | None = None,
               point_data: dict[str, np.ndarray] | None = None,
               cell_data: dict[str, np.ndarray] | None = None, tags: bool = True) -> None:
    """Write ``mesh`` (optionally at deformed ``points``) to a VTU file.

    Cell data ``layer`` (0..4, bottom to top) and ``capacitor`` (index or -1) unless
    ``tags`` is false (an elastic mesh's are not the stack's), plus any ``cell_data``
    given (one row per tet).
    """
    import meshio

    cells = [("tetra", np.asarray(mesh.tets, dtype=np.int64))]
    tag_data = {"layer": [mesh.layer_of_tet.astype(np.int32)],
                "capacitor": [mesh.capacitor_of_tet.astype(np.int32)]} if tags else {}
    meshio.write(
        str(path),
        meshio.Mesh(
            np.asarray(mesh.points if points is None else points, dtype=float),
            cells,
            point_data=dict(point_data or {}),
            cell_data={**tag_data, **{name: [np.asarray(value)] for name, value in (cell_data or {}).items()}},
        ),
        binary=True,
    )


def read_mesh(path: str | Path) -> TetData:
    """Read a VTU written by :func:`write_mesh`."""
    import meshio

    try:
        data = meshio.read(str(path))
    except Exception as exc:  # meshio raises assorted types for unreadable files
        raise MscapError(f"{path}: cannot read mesh ({exc})") from exc
    blocks = [i for i, block in enumerate(data.cells) if block.type == "tetra"]
    if not blocks:
        raise MscapError(f"{path}: no tetra cells")
    tets = np.concatenate([data.cells[i].data for i in blocks])
    tags = {}
    for name in ("layer", "capacitor"):
        if name not in data.cell_data:
            raise MscapError(f"{path}: missing cell data '{name}'")
        tags[name] = np.concatenate([data.cell_data[name][i] for i in blocks]).astype(np.int64)
    return TetData(data.points, tets.astype(np.int64), tags["layer"], tags["capacitor"])
