"""Cracked (duplicated-vertex) topology of simplex meshes with fracture facets, in 2D and 3D.

Pure NumPy/SciPy, no MPI; everything runs on the rank that holds the whole mesh (rank 0).

The mesh stays connected: fracture facets are interior facets. The displacement space takes its
dofmap from a second, *cracked* topology, in which every mesh entity in the closure of the
fracture network gets one copy per connected component of its cell star, two cells of the star
being connected when they share a facet that is not a fracture facet (DESIGN.md §3). For
vertices this gives 1 at a tip, 2 inside a fracture, 2 where a fracture meets the boundary, 3
along a T-junction, 4 along an X-line, and 2 at the end of an intersection line (3D).

Cracking *vertices* realizes the rule for every vertex, but in 3D not always for edges: an edge
inside a fracture whose two ends are both single-copy tip vertices (a chord at an acute fracture
corner) keeps one copy although its star has two components. Such *deficient* edges make P2
spaces lose dofs; :func:`deficient_edges` finds them and :func:`bisect_edges` removes them by
splitting the edge at its midpoint (the new vertex lies inside the fracture, so it gets two
copies).

Entity keys are rows of sorted vertex ids made unique with a lexicographic sort, so no packed
integer key can overflow (any number of nodes).
"""

from __future__ import annotations

import basix
import numpy as np
import numpy.typing as npt
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

__all__ = [
    "piece_labels",
    "unblocked_motions",
    "bisect_edges",
    "body_pieces",
    "crack_vertices",
    "deficient_edges",
    "edge_star_copies",
    "edge_table",
    "entity_star_copies",
    "entity_table",
    "facet_table",
    "rule_dof_count",
    "topological_copies",
    "unique_rows",
]

IntArray = npt.NDArray[np.int64]

_CELLS = {3: basix.CellType.triangle, 4: basix.CellType.tetrahedron}


def _cell_type(cell: basix.CellType | int | str) -> basix.CellType:
    """The basix cell of a simplex given as a cell type, a name or its number of vertices."""
    if isinstance(cell, basix.CellType):
        return cell
    if isinstance(cell, str):
        return basix.CellType[cell]
    if cell not in _CELLS:
        raise ValueError(f"simplex cells with 3 or 4 vertices expected, not {cell}")
    return _CELLS[cell]


def entity_table(cell: basix.CellType | int | str, dim: int) -> npt.NDArray[np.int32]:
    """Local vertices of the ``dim``-entities of a reference simplex (basix numbering)."""
    return np.array(basix.topology(_cell_type(cell))[dim], dtype=np.int32)


def facet_table(cell: basix.CellType | int | str) -> npt.NDArray[np.int32]:
    """Local vertices of each facet (facet ``i`` is opposite vertex ``i``), ``(d + 1, d)``."""
    ct = _cell_type(cell)
    return entity_table(ct, len(basix.topology(ct)) - 2)


def edge_table(cell: basix.CellType | int | str) -> npt.NDArray[np.int32]:
    """Local vertices of each edge, basix order (tet: [[2,3],[1,3],[1,2],[0,3],[0,2],[0,1]])."""
    return entity_table(cell, 1)


def unique_rows(rows: npt.ArrayLike) -> tuple[IntArray, int]:
    """Integer id of every row (equal rows get equal ids, numbered in lexicographic order).

    Works for any integer values (no packed key).

    Returns:
        ``(ids, number of distinct rows)``.
    """
    if len(rows) == 0:
        return np.empty(0, dtype=np.int64), 0
    r = np.asarray(rows, dtype=np.int64).reshape(len(rows), -1)
    order = np.lexsort(r.T[::-1])
    s = r[order]
    new = np.concatenate([[True], np.any(s[1:] != s[:-1], axis=1)])
    ids = np.empty(len(r), dtype=np.int64)
    ids[order] = np.cumsum(new) - 1
    return ids, int(new.sum())


def _facet_ids(cells: IntArray, fracture_facets: npt.ArrayLike) -> tuple[IntArray, IntArray]:
    """Common ids of the cells' facets (row ``(d + 1) c + f``) and of the fracture facets."""
    nv = cells.shape[1]
    rows = np.sort(cells[:, facet_table(nv)], axis=2).reshape(-1, nv - 1)
    frows = np.sort(np.asarray(fracture_facets, dtype=np.int64).reshape(-1, nv - 1), axis=1)
    ids, _ = unique_rows(np.concatenate([rows, frows]))
    return ids[: len(rows)], ids[len(rows):]


def _open_facet_pairs(cells: IntArray, fracture_facets: IntArray):
    """``(c1, f1, c2, f2)``: cells sharing a facet that is not a fracture facet.

    Raises:
        ValueError: A fracture facet is not a facet of the mesh.
    """
    nv = cells.shape[1]
    cid, fid = _facet_ids(cells, fracture_facets)
    missing = ~np.isin(fid, cid)
    if missing.any():
        frows = np.asarray(fracture_facets, dtype=np.int64).reshape(-1, nv - 1)
        raise ValueError(f"fracture facet {np.sort(frows[np.argmax(missing)]).tolist()} is not "
                         "a facet of the mesh")
    order = np.argsort(cid, kind="stable")
    sid = cid[order]
    pair = np.flatnonzero(sid[1:] == sid[:-1])
    keep = ~np.isin(sid[pair], fid)
    first, second = order[pair][keep], order[pair + 1][keep]
    c1, f1 = np.divmod(first, nv)
    c2, f2 = np.divmod(second, nv)
    return c1, f1, c2, f2


def piece_labels(cells: npt.ArrayLike, fracture_facets: npt.ArrayLike) -> IntArray:
    """The piece of every cell (:func:`body_pieces`), pieces numbered by their first cell."""
    cells = np.asarray(cells, dtype=np.int64)
    nc = len(cells)
    c1, _, c2, _ = _open_facet_pairs(cells, np.asarray(fracture_facets))
    graph = coo_matrix((np.ones(len(c1), dtype=np.int8), (c1, c2)), shape=(nc, nc))
    npieces, label = connected_components(graph, directed=False)
    first = np.full(npieces, nc, dtype=np.int64)
    np.minimum.at(first, label, np.arange(nc))
    rank = np.empty(npieces, dtype=np.int64)
    rank[np.argsort(first)] = np.arange(npieces)
    return rank[label]


def unblocked_motions(cells: npt.ArrayLike, x: npt.ArrayLike, fracture_facets: npt.ArrayLike,
                      labels: IntArray | None = None) -> tuple[int, ...]:
    """Per piece, how many of its rigid motions its fracture faces cannot stop by contact.

    A rigid motion ``r(x) = a + ω × x`` (3 in 2D, 6 in 3D) is stopped by a closed fracture
    face only along the face normal; without friction it is undetermined when
    ``r(x_v)·n_f = 0`` at every vertex ``x_v`` of every fracture face of the piece (a block on
    a planar cut slides along it and turns about its normal; a wedge between two cuts at an
    angle is held). Returns the dimension of that space per piece, in :func:`piece_labels`'
    order (``labels``: the pieces' labels when already known).
    """
    cells = np.asarray(cells, dtype=np.int64)
    x = np.asarray(x, dtype=np.float64)
    nv, gdim = cells.shape[1], x.shape[1]
    ndof = 3 if gdim == 2 else 6
    label = piece_labels(cells, fracture_facets) if labels is None else labels
    npieces = int(label.max()) + 1 if len(cells) else 0
    frows = np.asarray(fracture_facets, dtype=np.int64).reshape(-1, nv - 1)
    # the cells on both sides of every fracture facet
    cid, fid = _facet_ids(cells, frows)
    order = np.argsort(cid, kind="stable")
    lo = np.searchsorted(cid[order], fid, "left")
    hi = np.searchsorted(cid[order], fid, "right")
    counts = hi - lo
    facet = np.repeat(np.arange(len(fid)), counts)
    pos = np.repeat(lo, counts) + np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts,
                                                                     counts)
    cell = order[pos] // nv
    pts = x[frows]  # (nf, nv - 1, gdim)
    if gdim == 2:
        t = pts[:, 1] - pts[:, 0]
        normal = np.stack([-t[:, 1], t[:, 0]], axis=1)
    else:
        normal = np.cross(pts[:, 1] - pts[:, 0], pts[:, 2] - pts[:, 0])
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    out = []
    for k in range(npieces):
        mine = facet[label[cell] == k]
        if len(mine) == 0:
            out.append(ndof)
            continue
        # the normal gap at every vertex of every face: a motion keeping them all is free
        n = np.repeat(normal[mine], nv - 1, axis=0)
        r = pts[mine].reshape(-1, gdim)
        r = r - r.mean(axis=0)
        size = max(float(np.abs(r).max()), np.finfo(float).tiny)
        if gdim == 2:
            moment = (r[:, 0] * n[:, 1] - r[:, 1] * n[:, 0])[:, None]
        else:
            moment = np.cross(r, n)
        rows_k = np.hstack([n, moment / size])
        sv = np.linalg.svd(rows_k, compute_uv=False)
        out.append(ndof - int(np.count_nonzero(sv > 1e-8 * sv[0])))
    return tuple(out)


def body_pieces(cells: npt.ArrayLike, fracture_facets: npt.ArrayLike,
                boundary_facets: npt.ArrayLike, boundary_edge: npt.ArrayLike,
                labels: IntArray | None = None) -> tuple[tuple[int, tuple[int, ...]], ...]:
    """The pieces the fractures cut the body into, and the domain boundary each one touches.

    Two cells belong to one piece when a chain of cells sharing non-fracture facets joins them:
    the components of the cracked body, each of which moves rigidly on its own when nothing
    holds it (no displacement condition on its boundary, no contact).

    Args:
        cells: Cell nodes, ``(num_cells, d + 1)``.
        fracture_facets: Nodes of the fracture facets.
        boundary_facets: Nodes of the domain boundary facets.
        boundary_edge: Domain edge (2D) or box face (3D) of each boundary facet.
        labels: The pieces' labels (:func:`piece_labels`) when already known.

    Returns:
        Per piece, in the order of its first cell: its number of cells and the sorted domain
        edges (faces) its boundary facets lie on.
    """
    cells = np.asarray(cells, dtype=np.int64)
    nc, nv = cells.shape
    label = piece_labels(cells, fracture_facets) if labels is None else labels
    npieces = int(label.max()) + 1 if nc else 0
    # the cell of each boundary facet: its row among the sorted facet rows of all cells
    rows = np.sort(cells[:, facet_table(nv)], axis=2).reshape(-1, nv - 1)
    brows = np.sort(np.asarray(boundary_facets, dtype=np.int64).reshape(-1, nv - 1), axis=1)
    ids, _ = unique_rows(np.concatenate([rows, brows]))
    where = np.full(ids.max() + 1 if len(ids) else 0, -1, dtype=np.int64)
    where[ids[: len(rows)]] = np.arange(len(rows)) // nv  # a boundary facet has one cell
    bcell = where[ids[len(rows):]]
    edges = np.asarray(boundary_edge, dtype=np.int64)
    counts = np.bincount(label, minlength=npieces)
    return tuple((int(counts[k]), tuple(int(e) for e in np.unique(edges[label[bcell] == k])))
                 for k in range(npieces))


def _facet_subentities(nv: int, dim: int) -> npt.NDArray[np.int32]:
    """``[f, m]``: local index of the ``m``-th ``dim``-entity of the cell lying in facet ``f``."""
    ft, et = facet_table(nv), entity_table(nv, dim)
    return np.array([[e for e, ev in enumerate(et) if set(ev) <= set(fv)] for fv in ft],
                    dtype=np.int32)


def _star_components(cells: IntArray, fracture_facets: IntArray, dim: int):
    """Components of the cell stars of all ``dim``-entities (``dim < tdim``).

    Returns:
        ``(entity id per (cell, local entity), number of entities, component label per
        (cell, local entity), number of components)``. Components are numbered in the order of
        their first ``(cell, local entity)`` slot (row-major).
    """
    nc, nv = cells.shape
    et = entity_table(nv, dim)
    ne = len(et)
    if dim == 0:
        ent, nent = cells, -1
    else:
        flat, nent = unique_rows(np.sort(cells[:, et], axis=2).reshape(-1, et.shape[1]))
        ent = flat.reshape(nc, ne)
    c1, f1, c2, _ = _open_facet_pairs(cells, fracture_facets)
    sub = _facet_subentities(nv, dim)
    rows, cols = [], []
    for m in range(sub.shape[1]):
        le1 = sub[f1, m]
        key = ent[c1, le1]
        le2 = np.argmax(ent[c2] == key[:, None], axis=1)
        rows.append(ne * c1 + le1)
        cols.append(ne * c2 + le2)
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(ne * nc,) * 2)
    ncomp, label = connected_components(graph, directed=False)
    # canonical numbering: by first slot
    first = np.full(ncomp, ne * nc, dtype=np.int64)
    np.minimum.at(first, label, np.arange(ne * nc))
    rank = np.empty(ncomp, dtype=np.int64)
    rank[np.argsort(first)] = np.arange(ncomp)
    return ent, nent, rank[label].reshape(nc, ne), ncomp


def crack_vertices(
    cells: npt.ArrayLike, fracture_facets: npt.ArrayLike, num_nodes: int
) -> tuple[IntArray, int]:
    """Split fracture vertices into one copy per connected component of their cell star.

    Triangles or tetrahedra. For triangles the result equals ``poromech.mesh.crack_vertices``.

    Args:
        cells: Cell nodes, ``(num_cells, d + 1)``.
        fracture_facets: Nodes of the fracture facets, ``(num_faces, d)``.
        num_nodes: Number of mesh nodes.

    Returns:
        The cells in cracked vertex numbering and the number of cracked vertices. Copy 0 of a
        node keeps the node number; further copies are numbered from ``num_nodes`` on, in the
        order of (node, first cell corner of the copy's component).
    """
    cells = np.asarray(cells, dtype=np.int64)
    nc, nv = cells.shape
    _, _, label, ncomp = _star_components(cells, np.asarray(fracture_facets), 0)
    first_corner = np.full(ncomp, nv * nc, dtype=np.int64)
    np.minimum.at(first_corner, label.ravel(), np.arange(nv * nc))
    comp_node = cells.ravel()[first_corner]
    order = np.lexsort((np.arange(ncomp), comp_node))
    new_group = np.concatenate([[True], comp_node[order][1:] != comp_node[order][:-1]])
    cracked = np.empty(ncomp, dtype=np.int64)
    cracked[order[new_group]] = comp_node[order][new_group]
    extra = order[~new_group]
    cracked[extra] = num_nodes + np.arange(len(extra))
    return cracked[label], num_nodes + len(extra)


def entity_star_copies(
    cells: npt.ArrayLike, fracture_facets: npt.ArrayLike, dim: int
) -> tuple[IntArray, IntArray, IntArray]:
    """The rule's number of copies of every ``dim``-entity (``0 < dim < tdim``).

    Returns:
        ``(entities, copies, index)``: the entities as sorted node rows ``(m, dim + 1)`` in
        lexicographic order, the number of star components of each, and the entity of every
        ``(cell, local entity)``, ``(num_cells, num local entities)``.
    """
    cells = np.asarray(cells, dtype=np.int64)
    ent, nent, label, _ = _star_components(cells, np.asarray(fracture_facets), dim)
    et = entity_table(cells.shape[1], dim)
    rows = np.sort(cells[:, et], axis=2).reshape(-1, et.shape[1])
    entities = np.empty((nent, et.shape[1]), dtype=np.int64)
    entities[ent.ravel()] = rows
    # distinct (entity, component) pairs
    _, first = np.unique(label.ravel(), return_index=True)
    copies = np.bincount(ent.ravel()[first], minlength=nent)
    return entities, copies, ent


def edge_star_copies(
    cells: npt.ArrayLike, fracture_facets: npt.ArrayLike
) -> tuple[IntArray, IntArray, IntArray]:
    """The rule's number of copies of every edge: :func:`entity_star_copies` with ``dim = 1``.

    Returns:
        ``(edges (m, 2) sorted node pairs in lexicographic order, copies (m,), edge index of
        every (cell, local edge))``.
    """
    return entity_star_copies(cells, fracture_facets, 1)


def topological_copies(cracked_cells: npt.ArrayLike, index: IntArray, dim: int,
                       num_entities: int) -> IntArray:
    """Copies of each ``dim``-entity that the cracked topology has (what ``create_dofmap`` sees).

    Args:
        cracked_cells: Cells in cracked vertex numbering.
        index: Entity of every ``(cell, local entity)`` (from :func:`entity_star_copies`).
        dim: Entity dimension.
        num_entities: Number of entities.

    Returns:
        The number of distinct cracked vertex rows of each entity.
    """
    cc = np.asarray(cracked_cells, dtype=np.int64)
    et = entity_table(cc.shape[1], dim)
    rows = np.sort(cc[:, et], axis=2).reshape(-1, et.shape[1])
    ids, _ = unique_rows(rows)
    _, first = np.unique(ids, return_index=True)
    return np.bincount(index.ravel()[first], minlength=num_entities)


def deficient_edges(
    cells: npt.ArrayLike, fracture_facets: npt.ArrayLike, num_nodes: int,
    cracked_cells: npt.ArrayLike,
) -> IntArray:
    """Edges that the vertex-cracked topology gives fewer copies than the rule.

    Args:
        cells: Cell nodes.
        fracture_facets: Fracture facet nodes.
        num_nodes: Number of mesh nodes.
        cracked_cells: Output of :func:`crack_vertices`.

    Returns:
        The deficient edges as sorted node pairs ``(m, 2)``.
    """
    cells = np.asarray(cells, dtype=np.int64)
    ff = np.asarray(fracture_facets, dtype=np.int64)
    # Only edges of fracture facets can have several copies. The whole star of an edge with
    # both ends on the fractures is among the cells with at least two fracture nodes.
    on_fracture = np.zeros(num_nodes, dtype=bool)
    on_fracture[ff.ravel()] = True
    near = np.count_nonzero(on_fracture[cells], axis=1) >= 2
    edges, copies, index = edge_star_copies(cells[near], ff)
    topo = topological_copies(np.asarray(cracked_cells)[near], index, 1, len(edges))
    complete = on_fracture[edges].all(axis=1)
    return edges[complete & (topo < copies)]


def rule_dof_count(cells: npt.ArrayLike, fracture_facets: npt.ArrayLike, num_nodes: int,
                   degree: int, block_size: int = 1) -> int:
    """Number of dofs of the cracked Lagrange space of ``degree`` according to the rule.

    Each entity's dofs (per basix) times the entity's number of star components: cracked
    vertices, edge copies, facet copies (2 on a fracture, else 1) and cells.
    """
    cells = np.asarray(cells, dtype=np.int64)
    nv = cells.shape[1]
    tdim = nv - 1
    element = basix.create_element(basix.ElementFamily.P, _cell_type(nv), degree,
                                   basix.LagrangeVariant.equispaced)
    per = [d[0] for d in element.num_entity_dofs]
    _, total = crack_vertices(cells, fracture_facets, num_nodes)
    total *= per[0]
    for dim in range(1, tdim):
        if per[dim]:
            total += per[dim] * int(entity_star_copies(cells, fracture_facets, dim)[1].sum())
    total += per[tdim] * len(cells)
    return block_size * total


def _containing(simplices: IntArray, edges: IntArray) -> tuple[IntArray, IntArray]:
    """``(simplex, edge)`` index pairs: the simplices containing each (sorted, unique) edge."""
    k = simplices.shape[1]
    pairs = np.array([(i, j) for i in range(k) for j in range(i + 1, k)], dtype=np.int64)
    rows = np.sort(simplices[:, pairs], axis=2).reshape(-1, 2)
    ids, _ = unique_rows(np.concatenate([rows, edges]))
    sid, qid = ids[: len(rows)], ids[len(rows):]
    order = np.argsort(qid)
    hit = np.flatnonzero(np.isin(sid, qid))
    return hit // len(pairs), order[np.searchsorted(qid[order], sid[hit])]


def _batch(cells: IntArray, edges: IntArray) -> IntArray:
    """Indices of edges to bisect together: no cell contains two of them (greedy, in order)."""
    cell, edge = _containing(cells, edges)
    taken: set[int] = set()
    chosen = []
    for e in range(len(edges)):
        cs = set(cell[edge == e].tolist())
        if not cs & taken:
            taken |= cs
            chosen.append(e)
    return np.array(chosen, dtype=np.int64)


def _split(simplices: IntArray, edges: IntArray, new_node: IntArray) -> tuple[IntArray, IntArray]:
    """Split every simplex containing one of ``edges`` (at most one each) at its midpoint node.

    Child 1 (the edge's second node replaced by the midpoint) keeps the simplex's index, child 2
    (the first node replaced) is appended. Returns the simplices and each one's parent index.
    """
    s, e = _containing(simplices, edges)
    rows = simplices[s]
    child1 = np.where(rows == edges[e, 1:2], new_node[e, None], rows)
    child2 = np.where(rows == edges[e, 0:1], new_node[e, None], rows)
    out = simplices.copy()
    out[s] = child1
    return np.concatenate([out, child2]), np.concatenate([np.arange(len(simplices)), s])


def bisect_edges(
    x: npt.ArrayLike, cells: npt.ArrayLike, fracture_facets: npt.ArrayLike,
    boundary_facets: npt.ArrayLike, edges: npt.ArrayLike,
) -> tuple[npt.NDArray[np.float64], IntArray, IntArray, IntArray, IntArray, IntArray]:
    """Bisect edges: split every cell, fracture facet and boundary facet around each edge.

    Replacing one end of an edge by its midpoint keeps a cell's orientation. Edges sharing a
    cell are done in successive batches. Facet data stay aligned through the returned parent
    indices (``fracture_id[fracture_parent]`` classifies the new fracture facets).

    Args:
        x: Node coordinates ``(n, gdim)`` (m).
        cells: Cell nodes.
        fracture_facets: Fracture facet nodes.
        boundary_facets: Boundary facet nodes.
        edges: Node pairs to bisect ``(m, 2)``.

    Returns:
        ``(x, cells, fracture_facets, fracture_parent, boundary_facets, boundary_parent)``: new
        nodes are appended to ``x`` in the order of ``edges``; the parents index the input facets.
    """
    x = np.asarray(x, dtype=np.float64)
    cells = np.asarray(cells, dtype=np.int64)
    ff = np.asarray(fracture_facets, dtype=np.int64)
    bf = np.asarray(boundary_facets, dtype=np.int64)
    todo = np.unique(np.sort(np.asarray(edges, dtype=np.int64).reshape(-1, 2), axis=1), axis=0)
    fpar, bpar = np.arange(len(ff)), np.arange(len(bf))
    while len(todo):
        chosen = _batch(cells, todo)
        e = todo[chosen]
        new = len(x) + np.arange(len(e))
        x = np.concatenate([x, 0.5 * (x[e[:, 0]] + x[e[:, 1]])])
        cells, _ = _split(cells, e, new)
        ff, p = _split(ff, e, new)
        fpar = fpar[p]
        bf, p = _split(bf, e, new)
        bpar = bpar[p]
        todo = np.delete(todo, chosen, axis=0)
    return x, cells, ff, fpar, bf, bpar
