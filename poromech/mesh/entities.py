"""Geometric data of the HFV unknowns, read from a DOLFINx triangle mesh (local, vectorized).

Cell data cover the cells owned by this rank; facet and vertex data cover every local (owned or
ghost) facet and vertex, so that the faces of owned cells are always available.
"""

from __future__ import annotations

from dataclasses import dataclass

import dolfinx_solver  # noqa: F401  (orders MPI before the bindings)

import dolfinx
import numpy as np
import numpy.typing as npt

from poromech.mesh.fractured import FracturedMesh

__all__ = [
    "CellGeometry",
    "cell_geometry",
    "facet_vertices",
    "input_cells",
    "owned_cell_values",
    "vertex_coordinates",
]


@dataclass(frozen=True)
class CellGeometry:
    """Owned cells and their faces (SI units, m and m²).

    Attributes:
        volume: Cell areas ``|K|``, ``(n,)``.
        centroid: Cell centres ``x_K``, ``(n, 2)``.
        facets: Local facet index of each face, ``(n, 3)`` (local facet ``i`` opposite vertex
            ``i``).
        area: Face lengths ``|σ|``, ``(n, 3)``.
        normal: Outward unit normals ``n_{K,σ}``, ``(n, 3, 2)``.
        offset: ``x_σ - x_K``, ``(n, 3, 2)``.
        facet_midpoint: Midpoints of all local facets, ``(num_facets, 2)``.
        facet_length: Lengths of all local facets, ``(num_facets,)``.
    """

    volume: npt.NDArray[np.float64]
    centroid: npt.NDArray[np.float64]
    facets: npt.NDArray[np.int32]
    area: npt.NDArray[np.float64]
    normal: npt.NDArray[np.float64]
    offset: npt.NDArray[np.float64]
    facet_midpoint: npt.NDArray[np.float64]
    facet_length: npt.NDArray[np.float64]

    @property
    def num_cells(self) -> int:
        """Number of owned cells."""
        return len(self.volume)


def _facet_frames(msh: dolfinx.mesh.Mesh):
    """Midpoints, lengths and unit normals (arbitrary sign) of all local facets."""
    imap = msh.topology.index_map(1)
    facets = np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32)
    xg = msh.geometry.x[:, :2]
    nodes = dolfinx.mesh.entities_to_geometry(msh, 1, facets)
    a, b = xg[nodes[:, 0]], xg[nodes[:, 1]]
    t = b - a
    length = np.linalg.norm(t, axis=1)
    normal = np.column_stack([-t[:, 1], t[:, 0]]) / length[:, None]
    return 0.5 * (a + b), length, normal


def cell_geometry(fm: FracturedMesh) -> CellGeometry:
    """Geometry of the owned triangles of ``fm.msh`` and of their faces (local)."""
    msh = fm.msh
    n = msh.topology.index_map(2).size_local
    xc = msh.geometry.x[msh.geometry.dofmaps[0][:n]][:, :, :2]
    centroid = xc.mean(axis=1)
    e1, e2 = xc[:, 1] - xc[:, 0], xc[:, 2] - xc[:, 0]
    volume = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    c2f = msh.topology.connectivity(2, 1).array.reshape(-1, 3)[:n]
    mid, length, unit = _facet_frames(msh)
    offset = mid[c2f] - centroid[:, None, :]
    normal = unit[c2f]
    sign = np.sign(np.einsum("nfi,nfi->nf", offset, normal))
    return CellGeometry(
        volume, centroid, c2f.astype(np.int32), length[c2f], normal * sign[..., None], offset,
        mid, length,
    )


def facet_vertices(msh: dolfinx.mesh.Mesh, facets: npt.NDArray[np.int32]) -> npt.NDArray:
    """Topological vertex indices of facets, ``(n, 2)``."""
    f2v = msh.topology.connectivity(1, 0)
    return f2v.array.reshape(-1, 2)[facets]


def vertex_coordinates(msh: dolfinx.mesh.Mesh, vertices: npt.NDArray[np.int32]) -> npt.NDArray:
    """Coordinates ``(n, 2)`` of topological vertices."""
    if len(vertices) == 0:
        return np.empty((0, 2))
    msh.topology.create_connectivity(0, msh.topology.dim)
    nodes = dolfinx.mesh.entities_to_geometry(msh, 0, np.asarray(vertices, dtype=np.int32))
    return msh.geometry.x[nodes[:, 0], :2]


def owned_cell_values(f: dolfinx.fem.Function) -> npt.NDArray[np.float64]:
    """Values of a cell-wise (DG0) function on the owned cells, in the order of the flow arrays.

    For a coupled problem: e.g. ``(div u)_K`` projected to DG0, to build ``φ̂_Kⁿ``.
    """
    V = f.function_space
    nc = V.mesh.topology.index_map(V.mesh.topology.dim).size_local
    bs = V.dofmap.index_map_bs
    values = f.x.array.reshape(-1, bs)[V.dofmap.list[:nc, 0]]
    return values[:, 0] if bs == 1 else values


def input_cells(msh: dolfinx.mesh.Mesh, owned: bool = True) -> npt.NDArray[np.int64]:
    """Input (gmsh) numbers of the owned cells (and the ghost cells after them if not ``owned``).

    The partition-independent key of cell data in checkpoints and output files.
    """
    imap = msh.topology.index_map(msh.topology.dim)
    n = imap.size_local + (0 if owned else imap.num_ghosts)
    return np.asarray(msh.topology.original_cell_index, dtype=np.int64)[:n]
