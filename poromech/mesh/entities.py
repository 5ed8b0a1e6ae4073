"""Geometry of the owned entities of a simplex mesh (local, vectorized): one home for it.

Cell volumes, centroids, faces with their measures and outward normals (the HFV unknowns'
geometry), facet vertices and coordinates, and the input (gmsh) numbers of the owned cells.

Cell data cover the cells owned by this rank; facet and vertex data cover every local (owned or
ghost) facet and vertex, so that the faces of owned cells are always available.
"""

from __future__ import annotations

from dataclasses import dataclass

import dolfinx_solver  # noqa: F401  (orders MPI before the bindings)

import dolfinx
import numpy as np
import numpy.typing as npt
from mpi4py import MPI

__all__ = [
    "CellGeometry",
    "cell_geometry",
    "domain_box",
    "domain_extent",
    "facet_ridges",
    "facet_vertices",
    "fracture_segments",
    "input_cells",
    "owned_cell_values",
    "ridge_coordinates",
    "vertex_coordinates",
]


@dataclass(frozen=True)
class CellGeometry:
    """Owned cells and their faces (SI units; ``d`` the dimension, ``d + 1`` faces per cell).

    Attributes:
        volume: Cell measures ``|K|`` (areas in 2D, volumes in 3D), ``(n,)``.
        centroid: Cell centres ``x_K``, ``(n, d)``.
        facets: Local facet index of each face, ``(n, d + 1)`` (local facet ``i`` opposite
            vertex ``i``).
        area: Face measures ``|σ|`` (lengths in 2D, areas in 3D), ``(n, d + 1)``.
        normal: Outward unit normals ``n_{K,σ}``, ``(n, d + 1, d)``.
        offset: ``x_σ - x_K``, ``(n, d + 1, d)``.
        facet_midpoint: Barycentres of all local facets, ``(num_facets, d)``.
        facet_length: Measures of all local facets, ``(num_facets,)``.
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
    """Midpoints, measures (length, area) and unit normals (arbitrary sign) of all local facets."""
    tdim, gdim = msh.topology.dim, msh.geometry.dim
    imap = msh.topology.index_map(tdim - 1)
    facets = np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32)
    xg = msh.geometry.x[:, :gdim]
    nodes = dolfinx.mesh.entities_to_geometry(msh, tdim - 1, facets)
    if tdim == 2:
        a, b = xg[nodes[:, 0]], xg[nodes[:, 1]]
        t = b - a
        length = np.linalg.norm(t, axis=1)
        normal = np.column_stack([-t[:, 1], t[:, 0]]) / length[:, None]
        return 0.5 * (a + b), length, normal
    a, b, c = xg[nodes[:, 0]], xg[nodes[:, 1]], xg[nodes[:, 2]]
    cross = np.cross(b - a, c - a)
    twice = np.linalg.norm(cross, axis=1)
    return (a + b + c) / 3.0, 0.5 * twice, cross / twice[:, None]


def _simplex_volumes(xc: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Areas of triangles / volumes of tetrahedra with vertices ``xc`` ``(n, d + 1, d)``."""
    if xc.shape[2] == 2:
        e1, e2 = xc[:, 1] - xc[:, 0], xc[:, 2] - xc[:, 0]
        return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    return np.abs(np.linalg.det(xc[:, 1:] - xc[:, :1])) / 6.0


def cell_geometry(msh: dolfinx.mesh.Mesh) -> CellGeometry:
    """Geometry of the owned simplices of ``msh`` and of their faces (local)."""
    tdim, gdim = msh.topology.dim, msh.geometry.dim
    n = msh.topology.index_map(tdim).size_local
    xc = msh.geometry.x[msh.geometry.dofmaps[0][:n]][:, :, :gdim]
    centroid = xc.mean(axis=1)
    volume = _simplex_volumes(xc)
    c2f = msh.topology.connectivity(tdim, tdim - 1).array.reshape(-1, tdim + 1)[:n]
    mid, measure, unit = _facet_frames(msh)
    offset = mid[c2f] - centroid[:, None, :]
    normal = unit[c2f]
    sign = np.sign(np.einsum("nfi,nfi->nf", offset, normal))
    return CellGeometry(
        volume, centroid, c2f.astype(np.int32), measure[c2f], normal * sign[..., None], offset,
        mid, measure,
    )


def facet_vertices(msh: dolfinx.mesh.Mesh, facets: npt.NDArray[np.int32]) -> npt.NDArray:
    """Topological vertex indices of facets, ``(n, d)``."""
    tdim = msh.topology.dim
    f2v = msh.topology.connectivity(tdim - 1, 0)
    return f2v.array.reshape(-1, tdim)[facets]


def facet_ridges(msh: dolfinx.mesh.Mesh, facets: npt.NDArray[np.int32]) -> npt.NDArray:
    """Entities of dimension ``d - 2`` of facets, ``(n, d)``: vertices in 2D, edges in 3D."""
    tdim = msh.topology.dim
    if tdim == 2:
        return facet_vertices(msh, facets)
    msh.topology.create_entities(tdim - 2)
    msh.topology.create_connectivity(tdim - 1, tdim - 2)
    f2e = msh.topology.connectivity(tdim - 1, tdim - 2)
    return f2e.array.reshape(-1, tdim)[facets]


def ridge_coordinates(msh: dolfinx.mesh.Mesh, ridges: npt.NDArray[np.int32]) -> npt.NDArray:
    """End points ``(n, d - 1, d)`` of entities of dimension ``d - 2`` (2D: vertices)."""
    tdim, gdim = msh.topology.dim, msh.geometry.dim
    ridges = np.asarray(ridges, dtype=np.int32)
    if len(ridges) == 0:
        return np.empty((0, tdim - 1, gdim))
    if tdim == 2:
        return vertex_coordinates(msh, ridges)[:, None, :]
    msh.topology.create_connectivity(tdim - 2, tdim)
    nodes = dolfinx.mesh.entities_to_geometry(msh, tdim - 2, ridges)
    return msh.geometry.x[nodes][:, :, :gdim]


def vertex_coordinates(msh: dolfinx.mesh.Mesh, vertices: npt.NDArray[np.int32]) -> npt.NDArray:
    """Coordinates ``(n, d)`` of topological vertices."""
    gdim = msh.geometry.dim
    if len(vertices) == 0:
        return np.empty((0, gdim))
    msh.topology.create_connectivity(0, msh.topology.dim)
    nodes = dolfinx.mesh.entities_to_geometry(msh, 0, np.asarray(vertices, dtype=np.int32))
    return msh.geometry.x[nodes[:, 0], :gdim]


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


def fracture_segments(msh: dolfinx.mesh.Mesh, facets: npt.NDArray[np.int32],
                      tangents: npt.NDArray[np.float64] | None = None) -> npt.NDArray:
    """Vertex coordinates of fracture facets, ``(n, d, d)`` (segments in 2D).

    With ``tangents`` ``(n, d)`` (2D: the fracture tangent ``τ``) the two ends of a segment are
    ordered along it, as the flow's node unknowns are.
    """
    tdim, gdim = msh.topology.dim, msh.geometry.dim
    if len(facets) == 0:
        return np.empty((0, tdim, gdim))
    nodes = dolfinx.mesh.entities_to_geometry(msh, tdim - 1, np.asarray(facets, dtype=np.int32))
    x = msh.geometry.x[nodes][:, :, :gdim]
    if tangents is not None and tdim == 2:
        swap = np.einsum("ni,ni->n", x[:, 1] - x[:, 0], tangents) < 0
        x[swap] = x[swap][:, ::-1]
    return x


def domain_box(msh: dolfinx.mesh.Mesh) -> tuple[npt.NDArray, npt.NDArray]:
    """The lowest and highest coordinates of the mesh's points, ``(gdim,)`` each (collective)."""
    x = msh.geometry.x[: msh.geometry.index_map().size_local, : msh.geometry.dim]
    lo, hi = np.empty(x.shape[1]), np.empty(x.shape[1])
    msh.comm.Allreduce(np.ascontiguousarray(x.min(axis=0, initial=np.inf)), lo, op=MPI.MIN)
    msh.comm.Allreduce(np.ascontiguousarray(x.max(axis=0, initial=-np.inf)), hi, op=MPI.MAX)
    return lo, hi


def domain_extent(msh: dolfinx.mesh.Mesh) -> float:
    """The diagonal of the mesh's bounding box (m; collective, the same on every rank)."""
    lo, hi = domain_box(msh)
    return float(np.linalg.norm(hi - lo))
