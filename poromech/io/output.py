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

import dolfinx
import numpy as np
import numpy.typing as npt
from dolfinx import fem
from mpi4py import MPI

from poromech.errors import OutputError
from poromech.io.xdmf import MeshPiece, atomic_write_text, root_write
from poromech.mesh.entities import input_cells
from poromech.mesh.fractured import FracturedMesh

__all__ = [
    "CSV_COLUMNS",
    "FractureTable",
    "displacement_mesh",
    "fracture_mesh",
    "matrix_mesh",
    "owned_blocks",
    "write_summary",
]

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


def displacement_mesh(V: fem.FunctionSpace) -> MeshPiece:
    """The nodes of a (cracked) vector Lagrange space as an output mesh (local data).

    Points are the owned dof blocks (global block numbers); cells are the owned cells, split
    into four sub-triangles for P2.
    """
    msh = V.mesh
    imap = V.dofmap.index_map
    nown = imap.size_local
    blocks = np.arange(nown, dtype=np.int32)
    ncells = msh.topology.index_map(msh.topology.dim).size_local
    cell_blocks = imap.local_to_global(V.dofmap.list[:ncells].ravel()).reshape(ncells, -1)
    if cell_blocks.shape[1] == 6:
        cells = cell_blocks[:, _P2_SPLIT].reshape(-1, 3)
    elif cell_blocks.shape[1] == 10:
        cells = cell_blocks[:, _P2_SPLIT_TET].reshape(-1, 4)
    else:
        cells = cell_blocks
    first_cell = msh.comm.exscan(len(cells)) or 0
    coords = V.tabulate_dof_coordinates()[:nown, :msh.geometry.dim]
    return MeshPiece(imap.local_to_global(blocks), coords,
                     first_cell + np.arange(len(cells), dtype=np.int64), cells.astype(np.int64))


def owned_blocks(u: fem.Function) -> npt.NDArray[np.float64]:
    """Values of the owned dof blocks of a vector function, ``(n, bs)``."""
    bs = u.function_space.dofmap.index_map_bs
    n = u.function_space.dofmap.index_map.size_local
    return u.x.array.reshape(-1, bs)[:n]


def fracture_mesh(fm: FracturedMesh) -> MeshPiece:
    """The owned fracture faces as separate segments (points ``2i``, ``2i+1`` for face ``i``).

    The first point of a face is the one nearer to the start of its fracture polyline; cell ids
    are the global fracture face numbers (sorted by fracture, then arc length). In 3D separate
    triangles (points ``3i ... 3i+2``), counter-clockwise about ``n⁺``.
    """
    faces = fm.fractures
    if fm.msh.topology.dim == 3:
        fm.msh.topology.create_connectivity(2, 0)
        nodes = dolfinx.mesh.entities_to_geometry(fm.msh, 2, faces.facets)
        x = fm.msh.geometry.x[nodes] if len(faces.facets) else np.empty((0, 3, 3))
        area = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
        swap = np.einsum("ni,ni->n", area, faces.normal) < 0
        x[swap] = x[swap][:, ::-1]
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
    """The owned cells of the connected mesh in gmsh's input numbering (cells and nodes)."""
    msh = fm.msh
    cells = input_cells(msh)
    geo = msh.geometry
    nodes = geo.dofmaps[0][: len(cells)]
    inputs = np.asarray(geo.input_global_indices, dtype=np.int64)
    used = np.unique(nodes)
    return MeshPiece(inputs[used], geo.x[used, :geo.dim], cells, inputs[nodes])


class FractureTable:
    """``fractures.csv``: one row per fracture face and output time (collective ``write``).

    Args:
        fm: The fractured mesh.
        path: The CSV file.
        columns: Value columns after ``time, fracture, s, x, y``; a column ``state`` holds
            the codes 0, 1, 2 and is written as a word: open, stick or slip.
        resume_until: When continuing a run, keep the rows up to this time; None starts anew.
    """

    STATE_WORDS = ("open", "stick", "slip")

    def __init__(self, fm: FracturedMesh, path: Path, columns: tuple[str, ...],
                 resume_until: float | None = None):
        self.fm, self.path, self.comm = fm, Path(path), fm.comm
        #: Columns locating a face: arc length and midpoint in 2D, the midpoint in 3D.
        self.place = ("s", "x", "y") if fm.msh.topology.dim == 2 else ("x", "y", "z")
        self.columns = ("time", "fracture", *self.place, *columns)
        root_write(self.comm, self._start, resume_until)

    def _start(self, resume_until: float | None) -> None:
        """The header, and the rows of an earlier run up to ``resume_until`` (rank 0)."""
        keep = ""
        if resume_until is not None and self.path.exists():
            keep = "".join(line for line in self.path.read_text().splitlines(True)[1:]
                           if float(line.split(",", 1)[0]) <= resume_until * (1 + 1e-12))
        atomic_write_text(self.path, ",".join(self.columns) + "\n" + keep)

    def write(self, t: float, values: dict[str, npt.NDArray]) -> None:
        """Append the rows of time ``t`` from owned face values (one array per column)."""
        faces = self.fm.fractures
        place = [faces.s, faces.midpoint] if len(self.place) == 3 and self.place[0] == "s" \
            else [faces.midpoint]
        start = 2 + len(self.place)
        data = np.column_stack([faces.index, faces.fracture, *place,
                                *[np.asarray(values[c], dtype=np.float64)
                                  for c in self.columns[start:]]])
        gathered = self.comm.gather(data, root=0)
        root_write(self.comm, self._append, t, gathered)

    def _append(self, t: float, gathered: list) -> None:
        """Append the rows of one time in one write (rank 0)."""
        rows = np.concatenate(gathered)
        rows = rows[np.argsort(rows[:, 0])]
        names = self.fm.geometry.fracture_names
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        state = [i for i, c in enumerate(self.columns) if c == "state"]
        for r in rows:
            cells = [f"{t:.9g}", names[int(r[1])], f"{r[2]:.9g}", f"{r[3]:.9g}", f"{r[4]:.9g}",
                     *(f"{v:.9e}" for v in r[5:])]
            for i in state:
                cells[i] = self.STATE_WORDS[int(r[i])]
            w.writerow(cells)
        try:
            with open(self.path, "a") as fh:
                fh.write(buf.getvalue())
        except OSError as err:
            raise OutputError(f"could not write {self.path}: {os.strerror(err.errno)}") from None


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
