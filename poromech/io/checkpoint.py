"""Checkpoints for ``poromech run --restart``: partition-independent state in one HDF5 file.

Every array is stored in a global numbering that does not depend on the MPI partition: rows
keyed by the input (gmsh) cell number for cell-wise data, by the node of the cracked mesh for
the dofs of a Lagrange function (one row per dof block, :class:`NodeRows`), by the global
fracture face number for face-wise data. A run can therefore be continued on any number of
ranks, from the same scene (the mesh is generated again, identically, from the scene stored
next to the outputs).

Every rank writes its own rows (:func:`poromech.io.mpiio.write_h5`) into a temporary file that
rank 0 renames when complete, so a killed run keeps the checkpoint of its last completed step.
On restart each rank reads a block of ``1/p`` of the rows and receives the rows it needs from
the ranks that read them (:class:`StoredRows`). (``adios4dolfinx``,
the FEniCSx checkpoint library, does not install with the pinned stack — it requires a
``fenics-dolfinx`` distribution and the ``adios2`` Python bindings, neither of which the
``dolfinx-solver-real`` wheel provides — and it stores functions on standard dofmaps, not on the
duplicated-node spaces used here.)
"""

from __future__ import annotations

import json
from pathlib import Path

import dolfinx_solver  # noqa: F401

import h5py
import numpy as np
import numpy.typing as npt
from dolfinx import fem
from mpi4py import MPI

from poromech.io.mpiio import Rows, block_owner, exchange, rank_keys, reply, write_h5
from poromech.io.output import node_keys
from poromech.mesh.entities import input_cells
from poromech.mesh.fractured import FracturedMesh
from poromech.physics import Keyed

__all__ = [
    "CHECKPOINT",
    "CheckpointError",
    "Keyed",
    "NodeRows",
    "StoredRows",
    "cell_dof_rows",
    "face_dof_rows",
    "load_checkpoint",
    "read_checkpoint_meta",
    "save_checkpoint",
    "scalar_row",
    "set_cell_dof_rows",
    "set_face_dof_rows",
]

#: File name of the checkpoint in the output directory.
CHECKPOINT = "checkpoint.h5"



def save_checkpoint(comm: MPI.Comm, outdir: Path, meta: dict, arrays: dict[str, Keyed]) -> None:
    """Write the keyed arrays (global row ids, values) and metadata atomically (collective)."""
    names = list(arrays)
    local = np.array([int(np.max(arrays[k][0], initial=-1)) for k in names], dtype=np.int64)
    sizes = np.empty_like(local)
    comm.Allreduce(local, sizes, op=MPI.MAX)
    rows = {k: Rows(np.asarray(arrays[k][0], dtype=np.int64), np.asarray(arrays[k][1]),
                    int(n) + 1) for k, n in zip(names, sizes, strict=True)}
    write_h5(comm, Path(outdir) / CHECKPOINT, rows, {"meta": json.dumps(meta)})


class StoredRows:
    """An array of a checkpoint read by rows on demand: ``rows[keys]`` (collective).

    Each rank reads one contiguous block of the rows, ``1/p`` of them
    (:func:`~poromech.io.mpiio.block_owner`), and the rows each rank asks for are sent to it
    from the blocks that hold them (:func:`~poromech.io.mpiio.exchange`). A rank's cells are
    scattered over the input numbering, so a read of the span of its own rows was a read of
    the whole array on every rank: on 64 ranks each would read 99 % of the rows for the 1.6 %
    it needs.

    Args:
        path: The checkpoint file.
        name: The dataset.
        comm: The ranks that read it together.
    """

    def __init__(self, path: Path, name: str, comm: MPI.Comm):
        self.path, self.name, self.comm = Path(path), name, comm
        #: Rows this rank read from the file at the last access.
        self.rows_read = 0

    @property
    def shape(self) -> tuple[int, ...]:
        """The dataset's shape (local)."""
        with h5py.File(self.path, "r") as f:
            return f[self.name].shape

    def __getitem__(self, index) -> np.ndarray:
        """The rows ``index`` (an integer or an integer array of any shape), on every rank."""
        comm = self.comm
        index = np.asarray(index, dtype=np.int64)
        ids, inverse = np.unique(index.ravel(), return_inverse=True)
        with h5py.File(self.path, "r") as f:
            dset = f[self.name]
            n, shape = dset.shape[0], dset.shape[1:]
            outside = bool(len(ids)) and (ids[0] < 0 or ids[-1] >= n)
            if comm.allreduce(outside, op=MPI.LOR):
                raise CheckpointError(f"{self.path}: dataset {self.name} has {n} rows, fewer "
                                      "than this mesh needs (a checkpoint of another run)")
            lo, hi = (n * comm.rank) // comm.size, (n * (comm.rank + 1)) // comm.size
            block = dset[lo:hi]
        self.rows_read = hi - lo
        owner = block_owner(ids, n, comm.size)
        asked, counts = exchange(comm, owner, ids)
        rows = reply(comm, block[asked - lo], counts, owner)
        return rows[inverse].reshape(index.shape + shape)


class CheckpointError(ValueError):
    """A checkpoint file that cannot be read; the message is one line naming it."""


def read_checkpoint_meta(path: Path) -> tuple[dict, list[str]]:
    """The metadata and the array names of the checkpoint file ``path`` (local).

    Raises:
        CheckpointError: The file is not an HDF5 file with poromech's metadata (truncated,
            overwritten, or another file).
    """
    try:
        with h5py.File(path, "r") as f:
            return json.loads(f.attrs["meta"]), list(f.keys())
    except (OSError, KeyError, ValueError) as err:  # h5py, a missing attribute, bad JSON
        why = " ".join(str(err).split()) or type(err).__name__
        raise CheckpointError(f"{path} cannot be read as a poromech checkpoint ({why})") from None


def load_checkpoint(comm: MPI.Comm, outdir: Path) -> tuple[dict, dict[str, StoredRows]]:
    """The metadata and the arrays of a checkpoint, read by rows on demand (collective)."""
    path = Path(outdir) / CHECKPOINT
    meta, names = read_checkpoint_meta(path)
    return meta, {k: StoredRows(path, k, comm) for k in names}


def scalar_row(comm: MPI.Comm, value: float) -> Keyed:
    """A scalar as a keyed checkpoint array (one row, given by rank 0)."""
    ids = np.zeros(1 if comm.rank == 0 else 0, dtype=np.int64)
    return ids, np.full(len(ids), float(value))


class NodeRows:
    """The dof blocks of a (cracked) Lagrange space in a numbering independent of the partition.

    Blocks are numbered in the order of their keys (:func:`poromech.io.output.node_keys`: by
    cracked vertex, then edge), the numbering of the displacement output's points: a checkpoint
    row per block, once. (Until 2026-11-29 a row per cell held the values of all its dofs:
    P2 tetrahedra repeat each block about 7 times, and the penny crack's checkpoint of 509k
    unknowns took 57.9 MB for 8.1 MB of values.) Collective construction: a parallel sort.

    Args:
        fm: The fractured mesh.
        V: A P1 or P2 space on ``fm.msh`` (cracked or not).
    """

    def __init__(self, fm: FracturedMesh, V: fem.FunctionSpace):
        self.fm = fm
        #: Global number of each local (owned, then ghost) block.
        self.positions = rank_keys(fm.comm, node_keys(fm, V))[0]
        self.bs = V.dofmap.index_map_bs
        self.owned = V.dofmap.index_map.size_local

    def rows(self, values: npt.NDArray) -> Keyed:
        """The owned blocks of ``values`` (in the layout of a function of the space), keyed."""
        return self.positions[: self.owned], values.reshape(-1, self.bs)[: self.owned]

    def set(self, f: fem.Function, rows) -> None:
        """Inverse of :meth:`rows` on owned and ghost blocks (collective).

        A checkpoint written before the node rows holds a row per cell (its width is not the
        block size): it is read as such (:func:`set_cell_dof_rows`).
        """
        if len(rows.shape) != 2 or rows.shape[1] != self.bs:
            set_cell_dof_rows(self.fm, f, rows)
            return
        f.x.array.reshape(-1, self.bs)[:] = rows[self.positions]


def cell_dof_rows(fm: FracturedMesh, V: fem.FunctionSpace, values: npt.NDArray) -> Keyed:
    """Dof values of every owned cell, keyed by input cell.

    ``values`` are in the layout of a function of ``V`` (a space on ``fm.msh``). Partition-
    independent comparisons of whole functions use it; checkpoints use :class:`NodeRows`.
    """
    keys = input_cells(fm.msh)
    bs = V.dofmap.index_map_bs
    dofs = V.dofmap.list[: len(keys)]
    return keys, values.reshape(-1, bs)[dofs].reshape(len(keys), -1)


def set_cell_dof_rows(fm: FracturedMesh, f: fem.Function, rows: np.ndarray) -> None:
    """Inverse of :func:`cell_dof_rows` (rows indexed by input cell), on owned and ghost cells."""
    keys = input_cells(fm.msh, owned=False)
    bs = f.function_space.dofmap.index_map_bs
    dofs = f.function_space.dofmap.list[: len(keys)]
    f.x.array.reshape(-1, bs)[dofs] = rows[keys].reshape(len(keys), dofs.shape[1], bs)
    f.x.scatter_forward()


def _face_dofs(fm: FracturedMesh, V: fem.FunctionSpace, emap) -> npt.NDArray[np.int32]:
    cells = emap.sub_topology_to_topology(fm.fractures.facets, inverse=True)
    return V.dofmap.list[cells, 0]


def face_dof_rows(fm: FracturedMesh, V: fem.FunctionSpace, values: npt.NDArray, emap) -> Keyed:
    """Values of a DG0 function of ``V`` (on the fracture submesh) keyed by global fracture face."""
    bs = V.dofmap.index_map_bs
    return fm.fractures.index.astype(np.int64), values.reshape(-1, bs)[_face_dofs(fm, V, emap)]


def set_face_dof_rows(fm: FracturedMesh, f: fem.Function, emap, rows: np.ndarray) -> None:
    """Inverse of :func:`face_dof_rows` (owned faces, then a ghost update)."""
    bs = f.function_space.dofmap.index_map_bs
    dofs = _face_dofs(fm, f.function_space, emap)
    f.x.array.reshape(-1, bs)[dofs] = rows[fm.fractures.index].reshape(-1, bs)
    f.x.scatter_forward()
