"""Distributed fractured meshes and the duplicated-node ("cracked") topology.

The mesh stays *connected*: fracture faces are ordinary interior facets, so interior-facet
integrals see both sides of a fracture with matching quadrature points. Displacement
discontinuities come from the function space instead: its dofmap is built on a second, "cracked"
topology with the same cells, in which every vertex on the fracture network is split into one
copy per connected component of its cell star (two cells being connected when they share a
facet that is not a fracture facet). This gives 2 copies along a fracture, 1 at an immersed tip,
2 at a corner, 3 at a T junction, 4 at an X junction, and 2 where a fracture meets the boundary.

Collective functions are marked so; all others are local.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import dolfinx_solver  # noqa: F401  (orders MPI before the bindings)

import basix.ufl
import dolfinx
import dolfinx.cpp as _cpp
import numpy as np
import numpy.typing as npt
import ufl
from dolfinx.io.utils import distribute_entity_data
from mpi4py import MPI

from poromech.geometry.box import BoxGeometry
from poromech.geometry.plane import PlaneGeometry
from poromech.mesh.cracking import (
    body_pieces,
    crack_vertices,
    facet_table,
    piece_labels,
    unblocked_motions,
)
from poromech.mesh.generate import MeshArrays
from poromech.parallel import agree

__all__ = [
    "FRACTURE_TAG",
    "FRACTURE_TAG_OFFSET",
    "FractureFaces",
    "FracturedMesh",
    "crack_vertices",
    "create_fractured_mesh",
    "cracked_space",
    "distribute_mesh",
    "face_size",
    "facet_table",
    "fracture_measure",
]

#: Subdomain id of the fracture network in the interior facet measure.
FRACTURE_TAG = 1

#: Fracture ``j`` alone has subdomain id ``FRACTURE_TAG_OFFSET + j`` (:func:`fracture_measure`).
FRACTURE_TAG_OFFSET = 10

#: DOLFINx cell names by number of vertices of a simplex cell.
_SIMPLEX = {3: "triangle", 4: "tetrahedron"}


def face_size(msh: dolfinx.mesh.Mesh):
    """``h_σ``, the diameter of a facet, as a UFL expression (restrict it on interior facets).

    The facet's length in 2D, its longest edge in 3D.
    """
    if msh.topology.dim == 2:
        return ufl.FacetArea(msh)
    return ufl.MaxFacetEdgeLength(msh)


@dataclass(frozen=True)
class FractureFaces:
    """Fracture faces owned by this rank, with their orientation (local data).

    Attributes:
        facets: Local facet indices.
        index: Global fracture face number (sorted by fracture, then arc length).
        fracture: Fracture index of each face.
        segment: Polyline segment of each face.
        s: Arc length of the face midpoint from the fracture's first point (m).
        midpoint: Face midpoints, ``(n, d)`` (m).
        normal: ``n⁺`` of each face, ``(n, d)``.
        tangents: The tangent frame of each face, ``(n, d - 1, d)``: in 2D ``τ = (n_y, -n_x)``,
            along the polyline; in 3D the two tangents of the face's planar fracture.
        measure: ``|σ|``, the length (2D) or area (3D) of each face (m, m²).
        diameter: ``h_σ``, the diameter of each face (its length in 2D, longest edge in 3D).
        plus: ``(cell, local facet)`` on the ``+`` side (``n⁺`` points out of it), ``(n, 2)``.
        minus: ``(cell, local facet)`` on the ``-`` side, ``(n, 2)``.
    """

    facets: npt.NDArray[np.int32]
    index: npt.NDArray[np.int64]
    fracture: npt.NDArray[np.int32]
    segment: npt.NDArray[np.int32]
    s: npt.NDArray[np.float64]
    midpoint: npt.NDArray[np.float64]
    normal: npt.NDArray[np.float64]
    tangents: npt.NDArray[np.float64]
    measure: npt.NDArray[np.float64]
    diameter: npt.NDArray[np.float64]
    plus: npt.NDArray[np.int32]
    minus: npt.NDArray[np.int32]

    @property
    def integration_entities(self) -> npt.NDArray[np.int32]:
        """``[c⁺, f⁺, c⁻, f⁻]`` per face, the interior-facet integration entities."""
        return np.hstack([self.plus, self.minus]).astype(np.int32)


@dataclass
class FracturedMesh:
    """A connected mesh with fracture faces and the cracked topology of its displacement space.

    Attributes:
        msh: The connected mesh (ghosted by shared facet).
        geometry: The geometry it was built from (plane or box).
        cracked: Topology with duplicated fracture vertices (same local cells as ``msh``); None
            for a mesh built without it (a flow-only scene: :func:`create_fractured_mesh`).
        cracked_cells: Cracked (duplicated) global vertex ids of the local cells, in the vertex
            order of ``msh`` (owned then ghost cells), ``(num_local_cells, d + 1)``; None
            without the cracked topology.
        fractures: Owned fracture faces.
        fracture_facets_all: Owned and ghost fracture facets (local indices), for submeshes.
        boundary_facets: Owned boundary facets (local indices).
        boundary_edge: Domain polygon edge (2D) or box face (3D) of each boundary facet, an
            index into ``geometry.boundary_names``.
        num_fracture_faces: Global number of fracture faces.
        pieces: The pieces the fractures cut the body into (the same on every rank): per piece
            its number of cells and the domain edges (faces) it touches
            (:func:`~poromech.mesh.cracking.body_pieces`).
        unblocked: Per piece, the rigid motions its fracture faces cannot stop without
            friction (:func:`~poromech.mesh.cracking.unblocked_motions`); empty for one piece.
    """

    msh: dolfinx.mesh.Mesh
    geometry: PlaneGeometry | BoxGeometry
    cracked: _cpp.mesh.Topology | None
    cracked_cells: npt.NDArray[np.int64] | None
    fractures: FractureFaces
    fracture_facets_all: npt.NDArray[np.int32]
    boundary_facets: npt.NDArray[np.int32]
    boundary_edge: npt.NDArray[np.int32]
    num_fracture_faces: int
    pieces: tuple[tuple[int, tuple[int, ...]], ...] = ()
    unblocked: tuple[int, ...] = ()

    @property
    def comm(self) -> MPI.Comm:
        """The mesh communicator."""
        return self.msh.comm

    def boundary(self, edges: tuple[int, ...]) -> npt.NDArray[np.int32]:
        """Owned boundary facets on the given domain polygon edges."""
        return self.boundary_facets[np.isin(self.boundary_edge, edges)]


def _owner_partitioner(owner: npt.NDArray[np.int32]) -> Callable:
    """A shared-facet partitioner that sends input cell ``i`` to rank ``owner[i]``.

    Used to place a process boundary exactly where a test wants it (e.g. on a fracture).
    """

    def part(comm, nparts, graph, ghosting):
        offsets = graph.offsets
        local = np.arange(len(offsets) - 1)
        start = comm.exscan(len(local)) or 0
        me = owner[start + local]
        dest, dest_off = [], [0]
        for i in local:
            nbr = owner[graph.array[offsets[i] : offsets[i + 1]]]
            ranks = [me[i]] + sorted(set(nbr.tolist()) - {me[i]})
            dest += ranks
            dest_off.append(len(dest))
        return _cpp.graph.AdjacencyList_int32(
            np.asarray(dest, dtype=np.int32), np.asarray(dest_off, dtype=np.int32)
        )

    return dolfinx.mesh.create_cell_partitioner(part, dolfinx.mesh.GhostMode.shared_facet, 2)


def _local_entities(msh, dim, entities, values):
    """Owned and ghost local entity indices and values of globally numbered input entities."""
    ents, vals = distribute_entity_data(msh, dim, entities, values)
    msh.topology.create_connectivity(dim, msh.topology.dim)
    tags = dolfinx.mesh.meshtags_from_entities(
        msh, dim, dolfinx.graph.adjacencylist(ents.astype(np.int32)), vals.astype(np.int32)
    )
    return tags.indices, tags.values


def _scatter_rows(comm: MPI.Comm, rows: npt.NDArray | None, wanted: npt.NDArray[np.int64]):
    """Give every rank the rows ``wanted`` of an array that lives on rank 0 (collective)."""
    requests = comm.gather(wanted, root=0)
    replies = [rows[r] for r in requests] if comm.rank == 0 else None
    return comm.scatter(replies, root=0)


def _facet_sides(msh, facets, normals):
    """Midpoints, and ``(cell, local facet)`` on the ``+`` and ``-`` side of each facet.

    The ``+`` cell is the one ``n⁺`` points out of (its centroid lies on the ``-n⁺`` side).
    """
    tdim = msh.topology.dim
    f2c = msh.topology.connectivity(tdim - 1, tdim)
    c2f = msh.topology.connectivity(tdim, tdim - 1)
    x = msh.geometry.x[:, :msh.geometry.dim]
    gdofs = msh.geometry.dofmaps[0]
    counts = np.diff(f2c.offsets)[facets]
    # collective, so that every rank raises (one rank raising alone left the others waiting)
    bad = msh.comm.allreduce(int(np.count_nonzero(counts != 2)))
    if bad:
        raise RuntimeError(f"{bad} fracture facet(s) do not have a cell on each side: the mesh "
                           "does not resolve the fractures (a fracture shorter than the "
                           "mesh generator's tolerance?)")
    if len(facets) == 0:
        empty = np.empty((0, 2), dtype=np.int32)
        return np.empty((0, msh.geometry.dim)), empty, empty
    pair = f2c.array[f2c.offsets[facets][:, None] + np.arange(2)]  # (n, 2)
    mid = x[dolfinx.mesh.entities_to_geometry(msh, tdim - 1, facets)].mean(axis=1)
    cent = x[gdofs[pair]].mean(axis=2)  # (n, 2, d)
    side = np.einsum("nki,ni->nk", cent - mid[:, None, :], normals)
    swap = side[:, 0] >= side[:, 1]
    cp = np.where(swap, pair[:, 1], pair[:, 0])
    cm = np.where(swap, pair[:, 0], pair[:, 1])
    cf = c2f.array.reshape(-1, tdim + 1)
    lp = np.argmax(cf[cp] == facets[:, None], axis=1)
    lm = np.argmax(cf[cm] == facets[:, None], axis=1)
    return (mid, np.column_stack([cp, lp]).astype(np.int32),
            np.column_stack([cm, lm]).astype(np.int32))


def _cracked_topology(msh, cracked_rows, orig_cells_rows):
    """Build the cracked topology with the local cells of ``msh`` (collective)."""
    tdim = msh.topology.dim
    imap = msh.topology.index_map(tdim)
    num_local = imap.size_local + imap.num_ghosts
    gnodes = msh.geometry.input_global_indices[msh.geometry.dofmaps[0][:num_local]]
    # Position of each local cell vertex in its input cell row
    pos = np.argmax(orig_cells_rows[:, None, :] == gnodes[:, :, None], axis=2)
    cracked = np.take_along_axis(cracked_rows, pos, axis=1)
    # Process-boundary vertices: those on facets that appear once among owned cells
    owned = cracked[: imap.size_local]
    table = facet_table(msh.topology.cell_name())
    fac = np.sort(owned[:, table].reshape(-1, table.shape[1]), axis=1)
    uniq, counts = np.unique(fac, axis=0, return_counts=True)
    boundary_vertices = np.unique(uniq[counts == 1])
    orig = np.asarray(msh.topology.original_cell_index, dtype=np.int64)[:num_local]
    topo = _cpp.mesh.create_topology(
        msh.comm,
        [msh.topology.cell_type],
        [np.ascontiguousarray(cracked.ravel(), dtype=np.int64)],
        [np.ascontiguousarray(orig)],
        [np.asarray(imap.owners, dtype=np.int32)],
        boundary_vertices.astype(np.int64),
        1,
    )
    return topo, cracked


def create_fractured_mesh(
    comm: MPI.Comm,
    geometry: PlaneGeometry | BoxGeometry,
    arrays: MeshArrays | None,
    owner: npt.NDArray[np.int32] | None = None,
    crack: bool = True,
) -> FracturedMesh:
    """Distribute a fractured mesh and build its cracked topology (collective).

    Args:
        comm: Communicator.
        geometry: The plane geometry (on every rank).
        arrays: The mesh arrays on rank 0 (ignored on other ranks).
        owner: Optional rank of every input cell (rank 0 only), to impose a partition.
        crack: Build the cracked topology of the displacement space and the pieces the
            fractures cut the body into. A flow-only scene needs neither; they are work on
            rank 0 that grows with the mesh (1.9 s of the 7.9 s that the 98k-cell mesh of
            configs/flow3d_network.yaml at size 0.05 took to build, gmsh included, 1 rank).

    Returns:
        The fractured mesh.
    """
    root = comm.rank == 0
    cracked_rows, pieces, unblocked = None, (), ()
    if root:
        face_data = (arrays.fracture_id, arrays.fracture_segment, arrays.fracture_s)
        shape = (arrays.cells.shape[1], arrays.x.shape[1])
        if crack:
            cracked_rows, _ = crack_vertices(arrays.cells, arrays.fracture_facets, len(arrays.x))
            labels = piece_labels(arrays.cells, arrays.fracture_facets)
            pieces = body_pieces(arrays.cells, arrays.fracture_facets, arrays.boundary_facets,
                                 arrays.boundary_edge, labels)
            unblocked = (unblocked_motions(arrays.cells, arrays.x, arrays.fracture_facets,
                                           labels) if len(pieces) > 1 else ())
    else:
        face_data, shape = None, None
    if crack:
        pieces, unblocked = comm.bcast((pieces, unblocked), root=0)
    fid, fseg, fs = comm.bcast(face_data, root=0)
    nv, gdim = comm.bcast(shape, root=0)  # vertices per cell, coordinates per point
    if owner is not None or comm.size > 1:
        owner = comm.bcast(owner if root else None, root=0)
    partitioner = (
        _owner_partitioner(owner)
        if owner is not None
        else dolfinx.mesh.create_cell_partitioner(dolfinx.mesh.GhostMode.shared_facet, 2)
    )
    element = basix.ufl.element("Lagrange", _SIMPLEX[nv], 1, shape=(gdim,))
    cells = arrays.cells if root else np.empty((0, nv), dtype=np.int64)
    x = arrays.x if root else np.empty((0, gdim), dtype=np.float64)
    msh = dolfinx.mesh.create_mesh(comm, cells, ufl.Mesh(element), x, partitioner)
    tdim = msh.topology.dim
    msh.topology.create_entities(tdim - 1)
    msh.topology.create_connectivity(tdim - 1, tdim)
    msh.topology.create_connectivity(tdim, tdim - 1)

    imap = msh.topology.index_map(tdim)
    orig = np.asarray(msh.topology.original_cell_index, dtype=np.int64)
    orig = orig[: imap.size_local + imap.num_ghosts]
    cracked, cracked_cells = None, None
    if crack:
        cracked_local = _scatter_rows(comm, cracked_rows, orig)
        orig_rows = _scatter_rows(comm, arrays.cells if root else None, orig)
        cracked, cracked_cells = _cracked_topology(msh, cracked_local, orig_rows)

    no_facets = np.empty((0, tdim), dtype=np.int64)
    ffacets = arrays.fracture_facets if root else no_facets
    findex = np.arange(len(ffacets), dtype=np.int32)
    facets, index = _local_entities(msh, tdim - 1, ffacets, findex)
    facets_all = np.sort(facets).astype(np.int32)
    num_owned = msh.topology.index_map(tdim - 1).size_local
    own = facets < num_owned
    facets, index = facets[own], index[own].astype(np.int64)
    normals, tangents = geometry.face_frames(fid[index], fseg[index])
    mid, plus, minus = _facet_sides(msh, facets, normals)
    measure, diameter = _facet_sizes(msh, facets)
    faces = FractureFaces(
        facets.astype(np.int32), index, fid[index], fseg[index], fs[index], mid, normals,
        tangents, measure, diameter, plus, minus,
    )

    bf = arrays.boundary_facets if root else no_facets
    be = arrays.boundary_edge if root else np.empty(0, dtype=np.int32)
    bfacets, bedge = _local_entities(msh, tdim - 1, bf, be)
    own = bfacets < num_owned
    return FracturedMesh(
        msh, geometry, cracked, cracked_cells, faces, facets_all,
        bfacets[own].astype(np.int32), bedge[own].astype(np.int32),
        int(len(fid)), pieces, unblocked,
    )


def _facet_sizes(msh, facets) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """``|σ|`` (length or area) and diameter (longest edge) of simplex facets (local)."""
    tdim, gdim = msh.topology.dim, msh.geometry.dim
    if len(facets) == 0:
        return np.empty(0), np.empty(0)
    xg = msh.geometry.x[:, :gdim]
    fv = dolfinx.mesh.entities_to_geometry(msh, tdim - 1, facets)
    if tdim == 2:
        length = np.linalg.norm(xg[fv[:, 1]] - xg[fv[:, 0]], axis=1)
        return length, length
    a, b, c = xg[fv[:, 0]], xg[fv[:, 1]], xg[fv[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    edges = np.stack([b - a, c - b, a - c], axis=1)
    return area, np.linalg.norm(edges, axis=2).max(axis=1)


def distribute_mesh(comm: MPI.Comm, geometry: PlaneGeometry | BoxGeometry,
                    make_arrays: Callable[[], MeshArrays], owner=None,
                    crack: bool = True) -> FracturedMesh:
    """Make the mesh arrays on rank 0 (gmsh, a mesh file) and distribute them (collective).

    Args:
        comm: Communicator.
        geometry: The geometry the arrays refer to (on every rank).
        make_arrays: Called on rank 0 only; an exception it raises is raised on every rank.
        owner: The rank of every input cell (an array given on rank 0), or a callable of the
            cell centroids ``(n, d)`` returning it, to impose a partition (tests that put a
            process boundary on a fracture); None: the default partitioner.
        crack: Build the cracked topology (see :func:`create_fractured_mesh`).
    """
    arrays, ranks, err = None, None, None
    if comm.rank == 0:
        try:
            arrays = make_arrays()
            ranks = owner(arrays.x[arrays.cells].mean(axis=1)) if callable(owner) else owner
        except Exception as e:  # noqa: BLE001  (re-raised on every rank by agree)
            err = e
    agree(comm, err)
    if ranks is not None:
        ranks = np.asarray(ranks, dtype=np.int32)
    return create_fractured_mesh(comm, geometry, arrays, owner=ranks, crack=crack)


def cracked_space(fm: FracturedMesh, degree: int, shape: tuple[int, ...] | None = None):
    """Lagrange space on ``fm.msh`` whose dofs are duplicated across the fractures (collective).

    Args:
        fm: The fractured mesh.
        degree: Polynomial degree (1 or 2).
        shape: Value shape; default ``(d,)``, displacements.

    Returns:
        A :class:`dolfinx.fem.FunctionSpace` with the cracked dofmap.
    """
    msh = fm.msh
    if fm.cracked is None:
        raise ValueError("this mesh was built without its cracked topology (for a flow-only "
                         "scene): build it with crack=True for a displacement space")
    shape = (msh.geometry.dim,) if shape is None else shape
    ufl_e = basix.ufl.element("Lagrange", msh.basix_cell(), degree, shape=shape,
                              dtype=msh.geometry.x.dtype)
    element = dolfinx.fem.finiteelement(msh.topology.cell_type, ufl_e, msh.geometry.x.dtype)
    for d in range(1, msh.topology.dim):
        if element.basix_element.num_entity_dofs[d][0] > 0:
            fm.cracked.create_entities(d)
    dofmap = _cpp.fem.create_dofmap(msh.comm, fm.cracked, element._cpp_object)
    cpp_space = _cpp.fem.FunctionSpace_float64(msh._cpp_object, element._cpp_object, dofmap)
    return dolfinx.fem.FunctionSpace(msh, ufl_e, cpp_space)


def fracture_measure(fm: FracturedMesh, metadata: dict | None = None) -> ufl.Measure:
    """Interior-facet measure over the fracture faces with ``'+'`` the side ``n⁺`` points out of.

    Use as ``dG(FRACTURE_TAG)`` for the whole network, ``dG(FRACTURE_TAG_OFFSET + j)`` for
    fracture ``j``; ``n('+')`` is then ``n⁺`` and ``u('+') - u('-')`` the jump.
    """
    ent = fm.fractures.integration_entities
    data = [(FRACTURE_TAG, ent.ravel())]
    data += [(FRACTURE_TAG_OFFSET + j, ent[fm.fractures.fracture == j].ravel())
             for j in range(len(fm.geometry.fracture_names))]
    return ufl.Measure("dS", domain=fm.msh, subdomain_data=data, metadata=metadata or {})
