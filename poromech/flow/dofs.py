"""Distributed numbering of the HFV unknowns, derived from the DOLFINx index maps.

Unknowns (DESIGN §5): ``p_K`` per cell, ``p_σ`` per face not on Γ, two traces ``p_{K,σ}`` and
``p_{f,σ}`` per fracture face, ``p_e`` per fracture-network node: the entities of dimension
``d - 2`` of the fracture faces, vertices in 2D and edges in 3D (the faces of the fracture
cells). Ownership follows the mesh:

* cells: the cell index map;
* faces, traces and fracture pressures: the facet index map (the owner of a fracture facet owns
  its three unknowns, ordered ``[trace +, trace -, p_f]``);
* network nodes: the vertex (2D) or edge (3D) index map. An entity is a node when any rank has
  a fracture facet containing it; ranks mark such entities and a reverse scatter tells the
  owners.

Each rank owns one contiguous block of global indices, ordered
``[cells | faces (1 or 3 unknowns each) | nodes]``. Local dof indices put the owned dofs first
(``local = global - start``) and then the ghost dofs this rank's assembly touches.
"""

from __future__ import annotations

from dataclasses import dataclass

import dolfinx_solver  # noqa: F401  (orders MPI before the bindings)

import dolfinx
import numpy as np
import numpy.typing as npt
from mpi4py import MPI

from poromech.mesh.entities import (
    CellGeometry,
    facet_ridges,
    ridge_coordinates,
    vertex_coordinates,
)
from poromech.mesh.fractured import FracturedMesh

__all__ = ["KINDS", "FlowDofs", "number_dofs"]

IntArray = npt.NDArray[np.int64]

#: Kinds of unknowns, in the order of their codes in :attr:`FlowDofs.kind`.
KINDS = ("cell", "face", "trace", "fracture", "node")


@dataclass(frozen=True)
class FlowDofs:
    """Local view of the distributed HFV numbering.

    Attributes:
        num_owned: Number of dofs owned by this rank.
        num_global: Global number of dofs.
        start: Global index of the first owned dof.
        ghosts: Global indices of the ghost dofs (local index ``num_owned + i``), sorted.
        cell: Local dof of each owned cell, ``(nc,)``.
        cell_faces: Local dofs seen by each owned cell through its faces, ``(nc, d + 1)``:
            ``p_σ`` on ordinary faces, the cell's own trace ``p_{K,σ}`` on fracture faces.
        cell_fracture: Local dof of ``p_{f,σ}`` for the fracture faces of each owned cell,
            ``-1`` on ordinary faces, ``(nc, d + 1)``.
        trace: Local dofs of the ``(+, -)`` traces of the owned fracture faces, ``(nf, 2)``.
        fracture: Local dof of ``p_{f,σ}`` of the owned fracture faces, ``(nf,)``.
        node: Local dofs of the nodes of the owned fracture faces, ``(nf, d)``: in 2D the two
            end points, the first nearer to the start of the fracture polyline; in 3D the three
            edges of the triangle.
        node_entity: Local entity (vertex in 2D, edge in 3D) of those nodes, ``(nf, d)``.
        facet_edge: Domain polygon edge of every local facet, ``-1`` if interior.
        kind: Kind of every local dof (:data:`KINDS` index).
        points: Location of every local dof (cell centre, face midpoint, vertex or edge
            midpoint), ``(n, d)``.
        counts: Global numbers of cells, faces, traces, fracture faces and nodes.
    """

    num_owned: int
    num_global: int
    start: int
    ghosts: IntArray
    cell: IntArray
    cell_faces: IntArray
    cell_fracture: IntArray
    trace: IntArray
    fracture: IntArray
    node: IntArray
    node_entity: npt.NDArray[np.int32]
    facet_edge: IntArray
    kind: npt.NDArray[np.int8]
    points: npt.NDArray[np.float64]
    counts: dict[str, int]

    @property
    def num_local(self) -> int:
        """Owned plus ghost dofs."""
        return self.num_owned + len(self.ghosts)

    def local_to_global(self, local: IntArray) -> IntArray:
        """Global indices of local dofs."""
        local = np.asarray(local, dtype=np.int64)
        ghost = local >= self.num_owned
        out = local + self.start
        out[ghost] = self.ghosts[local[ghost] - self.num_owned]
        return out


def _forward(imap, owned: IntArray) -> IntArray:
    """Values of the owners for every local (owned and ghost) entity (collective)."""
    owned = np.asarray(owned, dtype=np.int64).reshape(imap.size_local, -1)
    bs = owned.shape[1]
    vec = dolfinx.la.vector(imap, bs, dtype=np.int64)
    vec.array[: owned.size] = owned.ravel()
    vec.scatter_forward()
    return vec.array.reshape(-1, bs).copy()


def _reverse_sum(imap, local: IntArray) -> IntArray:
    """Sum over ranks of local values, on the owned entities (collective)."""
    vec = dolfinx.la.vector(imap, 1, dtype=np.int64)
    vec.array[:] = local
    vec.scatter_reverse(dolfinx.la.InsertMode.add)
    return vec.array[: imap.size_local].copy()


def _owned_nodes(fm: FracturedMesh) -> npt.NDArray[np.int32]:
    """Owned entities of dimension ``d - 2`` that are fracture-network nodes (collective).

    Vertices in 2D (where the fracture network's faces are segments), edges in 3D.
    """
    top = fm.msh.topology
    vmap = top.index_map(top.dim - 2)
    mark = np.zeros(vmap.size_local + vmap.num_ghosts, dtype=np.int64)
    if len(fm.fracture_facets_all):
        mark[np.unique(facet_ridges(fm.msh, fm.fracture_facets_all))] = 1
    return np.flatnonzero(_reverse_sum(vmap, mark) > 0).astype(np.int32)


def _along_fracture(fm: FracturedMesh, verts: npt.NDArray[np.int32]) -> npt.NDArray[np.int32]:
    """End vertices of the owned fracture faces ordered along the fracture's tangent.

    The tangent is ``t = (n⁺_y, -n⁺_x)`` (``n⁺`` is the left normal), so the first node is the
    one nearer to the first point of the polyline, whatever the partition.
    """
    if len(verts) == 0:
        return verts
    x = vertex_coordinates(fm.msh, verts.ravel()).reshape(-1, 2, 2)
    t = fm.fractures.tangents[:, 0]
    swap = np.einsum("ni,ni->n", x[:, 1] - x[:, 0], t) < 0
    verts[swap] = verts[swap][:, ::-1]
    return verts


def _facet_layout(fm: FracturedMesh):
    """Local fracture mask and the owned facets' dof offsets (relative to the facet block)."""
    top = fm.msh.topology
    fmap = top.index_map(top.dim - 1)
    is_frac = np.zeros(fmap.size_local + fmap.num_ghosts, dtype=bool)
    is_frac[fm.fracture_facets_all] = True
    size = np.where(is_frac[: fmap.size_local], 3, 1)
    return is_frac, np.concatenate([[0], np.cumsum(size)])


def _facet_data(fm: FracturedMesh, start: int, nc: int, offset: IntArray) -> IntArray:
    """``[global first dof, global + cell, boundary edge]`` of every local facet (collective)."""
    msh = fm.msh
    tdim = msh.topology.dim
    fmap, cmap = msh.topology.index_map(tdim - 1), msh.topology.index_map(tdim)
    data = np.full((fmap.size_local, 3), -1, dtype=np.int64)
    data[:, 0] = start + nc + offset[:-1]
    plus = fm.fractures.plus[:, 0].astype(np.int32)
    data[fm.fractures.facets, 1] = cmap.local_to_global(plus)
    data[fm.boundary_facets, 2] = fm.boundary_edge
    return _forward(fmap, data)


def number_dofs(fm: FracturedMesh, geom: CellGeometry) -> FlowDofs:
    """Number the HFV unknowns of a fractured mesh (collective).

    Args:
        fm: The fractured mesh (ghosted by shared facet).
        geom: Its cell geometry (for the dof locations).

    Returns:
        The local view of the distributed numbering.
    """
    msh, comm = fm.msh, fm.comm
    tdim = msh.topology.dim
    msh.topology.create_entities(tdim - 2)
    cmap, vmap = msh.topology.index_map(tdim), msh.topology.index_map(tdim - 2)
    nc = cmap.size_local
    is_frac, offset = _facet_layout(fm)
    nodes = _owned_nodes(fm)
    num_owned = int(nc + offset[-1] + len(nodes))
    start = int(comm.exscan(num_owned) or 0)
    facet = _facet_data(fm, start, nc, offset)
    node_owned = np.full(vmap.size_local, -1, dtype=np.int64)
    node_owned[nodes] = start + nc + offset[-1] + np.arange(len(nodes))
    node_global = _forward(vmap, node_owned)[:, 0]

    cell_global = cmap.local_to_global(np.arange(nc, dtype=np.int32))
    minus_side = is_frac[geom.facets] & (facet[geom.facets, 1] != cell_global[:, None])
    cell_faces = facet[geom.facets, 0] + minus_side
    cell_fracture = np.where(is_frac[geom.facets], facet[geom.facets, 0] + 2, -1)
    ff = fm.fractures.facets
    base = facet[ff, 0]
    verts = facet_ridges(msh, ff).astype(np.int32).reshape(-1, tdim)
    if tdim == 2:
        verts = _along_fracture(fm, verts)
    node = node_global[verts]
    if np.any(node < 0):
        raise RuntimeError("a fracture face has an unnumbered network node")
    referenced = np.concatenate([cell_faces.ravel(), cell_fracture[cell_fracture >= 0],
                                 node.ravel()])
    ghosts = np.unique(referenced[(referenced < start) | (referenced >= start + num_owned)])
    local = _Localizer(start, num_owned, ghosts)
    kind, points = _locations(fm, geom, offset, nodes, local, is_frac,
                              (cell_faces, cell_fracture, node_global, verts))
    counts = _global_counts(comm, nc, is_frac, len(offset) - 1, len(nodes))
    return FlowDofs(
        num_owned, int(comm.allreduce(num_owned)), start, ghosts, np.arange(nc, dtype=np.int64),
        local(cell_faces), np.where(cell_fracture >= 0, local(cell_fracture), -1),
        local(np.column_stack([base, base + 1])), local(base + 2),
        local(node), verts, facet[:, 2], kind, points, counts,
    )


@dataclass(frozen=True)
class _Localizer:
    """Global to local dof indices (owned block first, then sorted ghosts)."""

    start: int
    num_owned: int
    ghosts: IntArray

    def __call__(self, g) -> IntArray:
        g = np.asarray(g, dtype=np.int64)
        out = g - self.start
        ext = (g < self.start) | (g >= self.start + self.num_owned)
        out[ext] = self.num_owned + np.searchsorted(self.ghosts, g[ext])
        return out


def _locations(fm, geom, offset, nodes, local, is_frac, refs):
    """Kind code and location of every local dof (owned from entities, ghosts from references)."""
    cell_faces, cell_fracture, node_global, verts = refs
    nc, nfo = geom.num_cells, len(offset) - 1
    n = local.num_owned + len(local.ghosts)
    kind = np.zeros(n, dtype=np.int8)
    points = np.zeros((n, fm.msh.geometry.dim))
    points[:nc] = geom.centroid
    size = np.diff(offset)
    facet_of = np.repeat(np.arange(nfo), size)
    within = np.arange(offset[-1]) - np.repeat(offset[:-1], size)
    owned_faces = slice(nc, nc + offset[-1])
    points[owned_faces] = geom.facet_midpoint[facet_of]
    kind[owned_faces] = np.where(is_frac[facet_of], np.where(within < 2, 2, 3), 1)
    tail = slice(nc + offset[-1], local.num_owned)
    points[tail] = _node_points(fm.msh, nodes)
    kind[tail] = 4
    ghost_faces = local(cell_faces) >= local.num_owned
    idx = local(cell_faces)[ghost_faces]
    points[idx] = geom.facet_midpoint[geom.facets[ghost_faces]]
    kind[idx] = np.where(is_frac[geom.facets[ghost_faces]], 2, 1)
    frac = cell_fracture >= 0
    idx = local(cell_fracture[frac])
    points[idx] = geom.facet_midpoint[geom.facets[frac]]
    kind[idx] = 3
    idx = local(node_global[verts]).ravel()
    points[idx] = _node_points(fm.msh, verts.ravel())
    kind[idx] = 4
    return kind, points


def _node_points(msh, entities) -> npt.NDArray[np.float64]:
    """Locations of node unknowns: the vertex (2D) or the edge midpoint (3D)."""
    return ridge_coordinates(msh, entities).mean(axis=1)


def _global_counts(comm: MPI.Comm, nc: int, is_frac, fmap_size: int, nodes: int) -> dict:
    """Global numbers of each kind of unknown (collective)."""
    nfrac = int(is_frac[:fmap_size].sum())
    local = np.array([nc, fmap_size - nfrac, 2 * nfrac, nfrac, nodes], dtype=np.int64)
    total = comm.allreduce(local, op=MPI.SUM)
    keys = ("cells", "faces", "traces", "fracture_faces", "nodes")
    return {k: int(v) for k, v in zip(keys, total, strict=True)}
