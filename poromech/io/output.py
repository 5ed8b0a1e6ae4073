"""Output meshes, the fracture table and ``summary.json`` (crash-safe, rank-independent).

* The displacement is written at its own nodes on the *duplicated-node* mesh (a P2 field on
  each triangle's four sub-triangles), so "Warp By Vector" in ParaView shows the fractures
  opening and sliding, and the P2 values are written exactly.
* Fracture fields are cell data on the fracture faces, written as separate segments.
* Matrix fields (flow) are cell data on the cells, in the input numbering of gmsh.
* ``fractures.csv`` gets one block of rows per output time, appended in one write.
* ``summary.json`` is rewritten through a temporary file and a rename after every step.

All series use :class:`poromech.io.xdmf.XDMFSeries` (one HDF5 file per step and an atomically
rewritten index), so a killed run leaves readable files for every completed step.
"""

from __future__ import annotations

import csv
import io
import json
import os
from pathlib import Path

import dolfinx_solver  # noqa: F401

import basix
import dolfinx
import numpy as np
import numpy.typing as npt
from dolfinx import fem
from mpi4py import MPI

from poromech.errors import OutputError
from poromech.io.mpiio import block_owner, exchange, rank_keys, write_ordered
from poromech.io.xdmf import MeshPiece, atomic_write_text, root_write
from poromech.mesh.entities import input_cells
from poromech.mesh.fractured import FracturedMesh
from poromech.parallel import on_root

__all__ = [
    "CSV_COLUMNS",
    "FractureTable",
    "displacement_mesh",
    "fracture_mesh",
    "matrix_mesh",
    "owned_blocks",
    "write_summary",
]

#: The format of the time column of ``fractures.csv``.
TIME_FORMAT = ".9g"
#: Significant digits of the coordinate columns of ``fractures.csv`` for a domain whose largest
#: coordinate is at most ten times its extent: 1e-8 of the extent or finer. A domain further
#: from the origin gets a digit more per decade (:func:`coordinate_digits`): a 100 m box at UTM
#: coordinates (y = 4e6 m) printed its face midpoints to 1 cm, and 290 faces shared 82 values
#: of y.
COORDINATE_DIGITS = 9


def coordinate_digits(x: npt.NDArray[np.float64], comm: MPI.Comm) -> int:
    """Significant digits that print the points' coordinates to 1e-8 of their extent (collective).

    ``x`` holds each rank's points, ``(n, gdim)``. The digits are :data:`COORDINATE_DIGITS`,
    and one more per decade by which the largest coordinate exceeds ten times the extent.
    """
    lo, hi = np.empty(x.shape[1]), np.empty(x.shape[1])
    comm.Allreduce(np.ascontiguousarray(x.min(axis=0, initial=np.inf)), lo, op=MPI.MIN)
    comm.Allreduce(np.ascontiguousarray(x.max(axis=0, initial=-np.inf)), hi, op=MPI.MAX)
    extent = float(np.max(hi - lo))
    far = float(np.max(np.maximum(np.abs(lo), np.abs(hi))))
    if not (extent > 0.0 and far > 10.0 * extent):
        return COORDINATE_DIGITS
    return COORDINATE_DIGITS + int(np.ceil(np.log10(far / extent))) - 1
#: The columns every ``fractures.csv`` starts with (a coupled run adds ``p_f`` and ``aperture``).
CSV_COLUMNS = ("time", "fracture", "s", "x", "y", "jump_n", "jump_t", "traction_n", "traction_t",
               "state")

#: The P2 triangle (vertices 0-2, edge midpoints 3 = (1,2), 4 = (0,2), 5 = (0,1)) as four
#: P1 sub-triangles.
_P2_SPLIT = np.array([[0, 5, 4], [5, 1, 3], [4, 3, 2], [5, 3, 4]])
#: The P2 tetrahedron (vertices 0-3, edge midpoints in basix order 4 = (2,3), 5 = (1,3),
#: 6 = (1,2), 7 = (0,3), 8 = (0,2), 9 = (0,1)) as eight P1 sub-tetrahedra: one at each vertex
#: and the inner octahedron cut along its diagonal (0,2)-(1,3), all with the parent's
#: orientation.
_P2_SPLIT_TET = np.array([[0, 9, 8, 7], [9, 1, 6, 5], [8, 6, 2, 4], [7, 5, 4, 3],
                          [9, 8, 7, 5], [9, 6, 8, 5], [8, 7, 5, 4], [8, 6, 4, 5]])


def node_keys(fm: FracturedMesh, V: fem.FunctionSpace) -> npt.NDArray[np.int64]:
    """A key of every local dof block of a cracked P1 or P2 space that ignores the partition.

    A vertex node is known by its cracked (duplicated) vertex ``v``, an edge node by its edge's
    vertices ``a < b``: the key is ``v·N + v`` or ``a·N + b`` with ``N`` the number of cracked
    vertices (collective: one reduction).

    Returns:
        The keys of the owned and ghost blocks, ``(n,)``.
    """
    comm = V.mesh.comm
    verts = np.asarray(fm.cracked_cells, dtype=np.int64)
    n = int(comm.allreduce(int(verts.max(initial=-1)), op=MPI.MAX)) + 1
    dofs = V.dofmap.list[: len(verts)]
    keys = np.empty(V.dofmap.index_map.size_local + V.dofmap.index_map.num_ghosts, np.int64)
    for j, (a, b) in _node_entities(V):
        lo, hi = np.minimum(verts[:, a], verts[:, b]), np.maximum(verts[:, a], verts[:, b])
        keys[dofs[:, j]] = lo * n + hi
    return keys


def _edges(msh: dolfinx.mesh.Mesh) -> npt.NDArray[np.int64]:
    """The reference cell's edges as pairs of local vertices (basix order)."""
    return np.asarray(basix.topology(msh.basix_cell())[1], dtype=np.int64)


def _node_entities(V: fem.FunctionSpace) -> list[tuple[int, tuple[int, int]]]:
    """Each local dof (block) of a cell of a P1 or P2 space and the cell vertices it sits on.

    ``(j, (a, b))``: dof ``j`` of the cell layout on the edge of local vertices ``a, b``, or
    on vertex ``a`` when ``a == b``.
    """
    layout, cell = V.dofmap.dof_layout, V.mesh.basix_cell()
    nverts = len(basix.topology(cell)[0])
    out = [(j, (v, v)) for v in range(nverts) for j in layout.entity_dofs(0, v)]
    out += [(j, (int(i), int(k))) for e, (i, k) in enumerate(_edges(V.mesh))
            for j in layout.entity_dofs(1, e)]
    if len(out) != layout.num_dofs:
        raise ValueError("output meshes are made for P1 and P2 spaces only")
    return out


def displacement_mesh(fm: FracturedMesh, V: fem.FunctionSpace) -> MeshPiece:
    """The nodes of a (cracked) vector Lagrange space as an output mesh (collective).

    Points are the owned dof blocks, numbered in the order of :func:`node_keys` (by cracked
    vertex, then edge), a numbering that does not depend on the partition. Cells are the owned
    cells, split for P2 into four sub-triangles or eight sub-tetrahedra, numbered by input cell
    and sub-cell.
    """
    msh = V.mesh
    imap = V.dofmap.index_map
    pos, _ = rank_keys(msh.comm, node_keys(fm, V))
    ncells = msh.topology.index_map(msh.topology.dim).size_local
    cell_nodes = pos[V.dofmap.list[:ncells]]
    split = {6: _P2_SPLIT, 10: _P2_SPLIT_TET}.get(cell_nodes.shape[1])
    if split is not None:
        cell_nodes = cell_nodes[:, split].reshape(-1, split.shape[1])
    nsub = 1 if split is None else len(split)
    cell_ids = (input_cells(msh)[:, None] * nsub + np.arange(nsub)).ravel()
    coords = _dof_points(V)[: imap.size_local]
    return MeshPiece(pos[: imap.size_local], coords, cell_ids, cell_nodes.astype(np.int64))


def _dof_points(V: fem.FunctionSpace) -> npt.NDArray[np.float64]:
    """The point of every local dof block of a P1 or P2 space on an affine mesh, exactly.

    A vertex node is the mesh vertex, an edge node the mean of its edge's two vertices: the two
    copies of a node on a fracture, and a node on the boundary, have the coordinates of the
    mesh to the bit. (``tabulate_dof_coordinates`` maps reference points and left the top nodes
    of the six-fracture box at y = 1 - 1.1e-16 and the two sides of a crack 2e-16 apart:
    ParaView's probes found no cell at points on the boundary or on a crack.)
    """
    msh = V.mesh
    gdim = msh.geometry.dim
    ncells = len(V.dofmap.list)
    x = msh.geometry.x[:, :gdim]
    geo = msh.geometry.dofmaps[0][:ncells]
    dofs = V.dofmap.list[:ncells]
    out = np.empty((V.dofmap.index_map.size_local + V.dofmap.index_map.num_ghosts, gdim))
    for j, (a, b) in _node_entities(V):  # a vertex: 0.5 (x + x) = x, exactly
        out[dofs[:, j]] = 0.5 * (x[geo[:, a]] + x[geo[:, b]])
    return out


def owned_blocks(u: fem.Function) -> npt.NDArray[np.float64]:
    """Values of the owned dof blocks of a vector function, ``(n, bs)``."""
    bs = u.function_space.dofmap.index_map_bs
    n = u.function_space.dofmap.index_map.size_local
    return u.x.array.reshape(-1, bs)[:n]


def fracture_mesh(fm: FracturedMesh) -> MeshPiece:
    """The owned fracture faces as separate segments (points ``2i``, ``2i+1`` for face ``i``).

    The first point of a face is the one nearer to the start of its fracture polyline; cell ids
    are the global fracture face numbers (sorted by fracture, then arc length). In 3D separate
    triangles (points ``3i ... 3i+2``), counter-clockwise about ``n⁺`` from the vertex of lowest
    input number (an order independent of the partition).
    """
    faces = fm.fractures
    if fm.msh.topology.dim == 3:
        fm.msh.topology.create_connectivity(2, 0)
        nodes = dolfinx.mesh.entities_to_geometry(fm.msh, 2, faces.facets).reshape(-1, 3)
        x = fm.msh.geometry.x[nodes]
        area = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
        swap = np.einsum("ni,ni->n", area, faces.normal) < 0
        nodes[swap] = nodes[swap][:, ::-1]
        inputs = np.asarray(fm.msh.geometry.input_global_indices, dtype=np.int64)[nodes]
        turn = (np.argmin(inputs, axis=1)[:, None] + np.arange(3)) % 3
        x = fm.msh.geometry.x[np.take_along_axis(nodes, turn, axis=1)]
        ids = faces.index.astype(np.int64)
        points = np.column_stack([3 * ids, 3 * ids + 1, 3 * ids + 2])
        return MeshPiece(points.ravel(), x.reshape(-1, 3), ids, points)
    nodes = dolfinx.mesh.entities_to_geometry(fm.msh, 1, faces.facets)
    x = fm.msh.geometry.x[nodes][:, :, :2] if len(faces.facets) else np.empty((0, 2, 2))
    tangent = faces.tangents[:, 0]
    swap = np.einsum("ni,ni->n", x[:, 1] - x[:, 0], tangent) < 0
    x[swap] = x[swap][:, ::-1]
    ids = faces.index.astype(np.int64)
    points = np.column_stack([2 * ids, 2 * ids + 1])
    return MeshPiece(points.ravel(), x.reshape(-1, 2), ids, points)


def matrix_mesh(fm: FracturedMesh) -> MeshPiece:
    """The owned cells and nodes of the connected mesh in gmsh's input numbering."""
    msh = fm.msh
    cells = input_cells(msh)
    geo = msh.geometry
    nodes = geo.dofmaps[0][: len(cells)]
    inputs = np.asarray(geo.input_global_indices, dtype=np.int64)
    owned = geo.index_map().size_local
    return MeshPiece(inputs[:owned], geo.x[:owned, :geo.dim], cells, inputs[nodes])


class FractureTable:
    """``fractures.csv``: one row per fracture face and output time (collective methods).

    The rows of a time are sorted by global face number and appended by every rank at once:
    each rank sends its faces' rows to the rank holding their block of the face numbering
    (:func:`poromech.io.mpiio.block_owner`), which formats its block and writes it after the
    blocks of the lower ranks (:func:`poromech.io.mpiio.write_ordered`). No rank holds more
    than its block, and the file is the same on any number of ranks.

    Args:
        fm: The fractured mesh.
        path: The CSV file.
        columns: Value columns after ``time, fracture, s, x, y`` (2D) or ``time, fracture, x,
            y, z`` (3D); a column ``state`` holds the codes 0, 1, 2 and is written as a word:
            open, stick or slip.
        resume_until: When continuing a run, keep the rows up to this time; None starts anew.
    """

    STATE_WORDS = ("open", "stick", "slip")

    def __init__(self, fm: FracturedMesh, path: Path, columns: tuple[str, ...],
                 resume_until: float | None = None):
        self.fm, self.path, self.comm = fm, Path(path), fm.comm
        #: Columns locating a face: arc length and midpoint in 2D, the midpoint in 3D.
        self.place = ("s", "x", "y") if fm.msh.topology.dim == 2 else ("x", "y", "z")
        self.columns = ("time", "fracture", *self.place, *columns)
        gdim = fm.msh.geometry.dim
        digits = coordinate_digits(fm.msh.geometry.x[:, :gdim], self.comm)
        #: Formats of the place columns: the arc length ``s`` as 9 digits, coordinates by
        #: :func:`coordinate_digits`.
        self._place_formats = tuple(".9g" if c == "s" else f".{digits}g" for c in self.place)
        self._end = on_root(self.comm, self._start, resume_until)

    def _start(self, resume_until: float | None) -> int:
        """The header, or the rows of an earlier run up to ``resume_until``; the size (rank 0)."""
        if resume_until is not None and self.path.exists():
            try:
                return _cut_after(self.path, resume_until)
            except OSError as err:
                raise OutputError(f"could not write {self.path}: "
                                  f"{os.strerror(err.errno)}") from None
        header = ",".join(self.columns) + "\n"
        atomic_write_text(self.path, header)
        return len(header.encode())

    def write(self, t: float, values: dict[str, npt.NDArray]) -> None:
        """Append the rows of time ``t`` from owned face values (one array per column)."""
        faces = self.fm.fractures
        place = [faces.s, faces.midpoint] if self.place[0] == "s" else [faces.midpoint]
        start = 2 + len(self.place)
        data = np.column_stack([faces.index, faces.fracture, *place,
                                *[np.asarray(values[c], dtype=np.float64)
                                  for c in self.columns[start:]]])
        owner = block_owner(faces.index, self.fm.num_fracture_faces, self.comm.size)
        rows, _ = exchange(self.comm, owner, data.reshape(len(faces.index), len(self.columns)))
        text = self._format(t, rows[np.argsort(rows[:, 0])])
        self._end = write_ordered(self.comm, self.path, self._end, text.encode())

    def _format(self, t: float, rows: npt.NDArray[np.float64]) -> str:
        """The CSV lines of sorted rows (face, fracture, place..., values...)."""
        names = self.fm.geometry.fracture_names
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        state = [i for i, c in enumerate(self.columns) if c == "state"]
        for r in rows:
            cells = [f"{t:{TIME_FORMAT}}", names[int(r[1])],
                     *(f"{v:{f}}" for v, f in zip(r[2:5], self._place_formats, strict=True)),
                     *(f"{v:.9e}" for v in r[5:])]
            for i in state:
                cells[i] = self.STATE_WORDS[int(r[i])]
            w.writerow(cells)
        return buf.getvalue()


def _cut_after(path: Path, until: float) -> int:
    """Cut a table after its last complete row of a time up to ``until``; the new size.

    Rows are in time order, so the first row to cut is found by bisection on byte offsets (a
    few reads whatever the size). A row left incomplete by a killed run is cut too.
    """
    # the time as the rows print it: 66.66666666666667 prints as 66.6666667, above it by 5e-10
    limit = float(f"{until:{TIME_FORMAT}}")
    with open(path, "rb+") as fh:
        lo = len(fh.readline())
        hi = fh.seek(0, os.SEEK_END)
        while lo < hi:  # lines before lo are kept, the line at hi (or the end) is not
            fh.seek((lo + hi) // 2 - 1)
            fh.readline()
            start = fh.tell() if fh.tell() < hi else lo
            fh.seek(start)
            line = fh.readline()
            if _row_after(line, limit):
                hi = start
            else:
                lo = start + len(line)
        fh.truncate(lo)
    return lo


def _row_after(line: bytes, limit: float) -> bool:
    """Whether a table row is of a time after ``limit`` or incomplete."""
    if not line.endswith(b"\n") or b"\0" in line:
        return True
    try:
        return float(line.split(b",", 1)[0]) > limit
    except ValueError:
        return True


def write_summary(comm: MPI.Comm, outdir: Path, summary: dict) -> None:
    """Write ``summary.json`` atomically on rank 0 (collective: an error is raised everywhere)."""
    text = json.dumps(summary, indent=2, default=_json) if comm.rank == 0 else ""
    root_write(comm, atomic_write_text, Path(outdir) / "summary.json", text)


def _json(obj):
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return float(obj)
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"cannot serialize {type(obj)}")
