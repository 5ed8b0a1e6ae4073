"""Files written by every rank at once: HDF5 datasets by rows, text in rank order (MPI-IO).

No data that grows with the mesh passes through rank 0. Each rank writes the rows it owns of a
global array straight into the file, at their place in a numbering that does not depend on the
partition, so the files are the same on any number of ranks.

The h5py of the pinned stack is built without MPI (``h5py.get_config().mpi`` is False), so
parallel HDF5 is not available from Python. An HDF5 file is therefore written in two phases:
rank 0 creates it with h5py, every dataset *contiguous*, its space allocated at creation and
never filled, and closes it (metadata only: a few kilobytes); every rank then writes its rows
into the datasets' byte ranges with MPI-IO, all datasets in one collective call (a file view
made of the runs of consecutive rows it owns, sorted once: :class:`RowSet`). The result is an
ordinary HDF5 file, read by h5py, ParaView and any HDF5 reader; rows no rank writes read as
zeros (a fresh file has none written). The file is written under a temporary name and renamed
by rank 0 once every rank has closed it.

Text (``fractures.csv``) is written the same way: each rank formats its block of rows and
writes it at the offset given by the sizes of the blocks of the lower ranks (an exclusive scan),
in one collective call. Rows are first sent to the rank holding their block of the global order
(:func:`block_owner`, :func:`exchange`).

The alternatives considered: DOLFINx's ``XDMFFile`` writes in parallel (its C++ HDF5 is
parallel), but a function only on the mesh geometry, which is connected across the fractures:
the duplicated nodes, hence the opening, and the P2 values would be lost. Its ``VTXWriter``
(ADIOS2) writes in parallel too, but Debian's ParaView 5.11 does not read its files (the reason
poromech left it, docs/outputs.md); ``adios4dolfinx`` needs the ``adios2`` Python bindings,
which the pinned stack does not provide. One file per rank with a spatial collection in the
XDMF index would make the files, and what ``open_results`` reads, depend on the number of ranks.

Every function here is collective; an error on any rank is raised on every rank as an
:class:`~poromech.errors.OutputError` naming the file.
"""

from __future__ import annotations

import errno
import os
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import numpy.typing as npt
from mpi4py import MPI
from mpi4py.util.dtlib import from_numpy_dtype

from poromech.errors import OutputError
from poromech.parallel import agree, on_root

__all__ = [
    "RowSet",
    "Rows",
    "block_owner",
    "exchange",
    "rank_keys",
    "reply",
    "write_h5",
    "write_ordered",
]

#: Samples per rank for the splitters of :func:`rank_keys`.
_SAMPLES = 64


class RowSet:
    """The global rows of an array that this rank writes, sorted once for every write.

    Args:
        ids: Global row numbers, ``(n,)``; every row is given by one rank at most.

    Attributes:
        order: The local rows in increasing global number (None: already in that order).
        starts: First global row of each run of consecutive rows.
        lengths: Number of rows of each run.
    """

    def __init__(self, ids: npt.NDArray[np.integer]):
        ids = np.asarray(ids, dtype=np.int64)
        order = np.argsort(ids, kind="stable")
        rows = ids[order]
        if np.any(np.diff(rows) == 0):
            raise ValueError("a row is given twice")
        self.count = len(ids)
        self.last = int(rows[-1]) if len(rows) else -1
        self.order = None if np.array_equal(order, np.arange(len(ids))) else order
        first = np.flatnonzero(np.diff(rows, prepend=rows[0] - 2 if len(rows) else 0) != 1)
        self.starts = rows[first]
        self.lengths = np.diff(np.append(first, len(rows)))

    def sorted(self, values: npt.NDArray) -> npt.NDArray:
        """Values given in the order of ``ids``, in increasing global row (contiguous)."""
        return np.ascontiguousarray(values if self.order is None else values[self.order])


@dataclass(frozen=True)
class Rows:
    """The rows of a global array that this rank writes.

    Attributes:
        ids: Global row numbers (a :class:`RowSet`, or an array sorted at each write).
        values: The rows, ``(n, ...)``, in the order of ``ids``.
        size: Global number of rows (the same on every rank).
    """

    ids: RowSet | npt.NDArray[np.int64]
    values: npt.NDArray
    size: int

    @property
    def rows(self) -> RowSet:
        """The row set."""
        return self.ids if isinstance(self.ids, RowSet) else RowSet(self.ids)


# -- moving rows between ranks ---------------------------------------------------------------
def exchange(comm: MPI.Comm, dest: npt.NDArray[np.integer],
             values: npt.NDArray) -> tuple[npt.NDArray, npt.NDArray[np.int64]]:
    """Send row ``i`` of ``values`` to rank ``dest[i]`` (collective).

    Returns:
        The rows received, grouped by sending rank (in rank order, each group in the sender's
        order), and the number received from each rank.
    """
    values = np.ascontiguousarray(values)
    order = np.argsort(dest, kind="stable")
    send = values[order]
    counts = np.bincount(np.asarray(dest, dtype=np.int64), minlength=comm.size)
    recv_counts = np.asarray(comm.alltoall(counts.tolist()), dtype=np.int64)
    row = int(np.prod(values.shape[1:], dtype=np.int64))
    recv = np.empty((int(recv_counts.sum()), *values.shape[1:]), dtype=values.dtype)
    mpi_type = from_numpy_dtype(values.dtype)
    comm.Alltoallv([send, (counts * row, None), mpi_type],
                   [recv, (recv_counts * row, None), mpi_type])
    return recv, recv_counts


def reply(comm: MPI.Comm, values: npt.NDArray, recv_counts: npt.NDArray[np.int64],
           dest: npt.NDArray[np.integer]) -> npt.NDArray:
    """Send the answers to rows received by :func:`exchange` back, in the senders' order."""
    back, _ = exchange(comm, np.repeat(np.arange(comm.size), recv_counts), values)
    out = np.empty_like(back)
    out[np.argsort(dest, kind="stable")] = back
    return out


def block_owner(ids: npt.NDArray[np.integer], size: int, nranks: int) -> npt.NDArray[np.int64]:
    """The rank holding each global row in a balanced block distribution of ``size`` rows."""
    bounds = (np.arange(nranks + 1, dtype=np.int64) * size) // nranks
    return np.searchsorted(bounds, np.asarray(ids, dtype=np.int64), side="right") - 1


def rank_keys(comm: MPI.Comm,
              keys: npt.NDArray[np.int64]) -> tuple[npt.NDArray[np.int64], int]:
    """Number distinct keys of all ranks in increasing order: a parallel sort (collective).

    Args:
        comm: Communicator.
        keys: This rank's keys (a key may appear on several ranks and repeat).

    Returns:
        The position of each key among the distinct keys of all ranks, and their number.
    """
    keys = np.asarray(keys, dtype=np.int64)
    if comm.size == 1:
        uniq, inverse = np.unique(keys, return_inverse=True)
        return inverse.astype(np.int64), len(uniq)
    # splitters from regular samples of each rank's distinct keys (sample sort)
    mine = np.unique(keys)
    samples = mine[np.linspace(0, len(mine) - 1, min(_SAMPLES, len(mine))).astype(np.int64)]
    pool = np.sort(np.concatenate(comm.allgather(samples)))
    splitters = pool[(np.arange(1, comm.size) * len(pool)) // comm.size] if len(pool) else \
        np.zeros(comm.size - 1, dtype=np.int64)
    dest = np.searchsorted(splitters, keys, side="right")
    got, counts = exchange(comm, dest, keys)
    uniq, inverse = np.unique(got, return_inverse=True)
    first = comm.exscan(len(uniq)) or 0
    total = comm.allreduce(len(uniq))
    return reply(comm, first + inverse.astype(np.int64), counts, dest), int(total)


# -- errors ----------------------------------------------------------------------------------
def _reason(err: Exception) -> str:
    """The system's words for an I/O error (``File too large``, ``No space left on device``)."""
    if isinstance(err, OSError) and err.errno:
        return os.strerror(err.errno)
    text = err.Get_error_string() if isinstance(err, MPI.Exception) else str(err)
    for code in sorted(errno.errorcode):
        words = os.strerror(code)
        if words and words in text and not words.startswith("Unknown error"):
            return words
    return text.strip().splitlines()[0].split(" (")[0]


@contextmanager
def _agreed(comm: MPI.Comm, path: Path) -> Iterator[None]:
    """Turn an I/O error on any rank into the same OutputError on every rank (collective)."""
    error = None
    try:
        yield
    except (OSError, MPI.Exception, ValueError, RuntimeError) as err:
        error = OutputError(f"could not write {path}: {_reason(err)}")
    agree(comm, error)


# -- HDF5 ------------------------------------------------------------------------------------
def _shapes(comm: MPI.Comm, datasets: Mapping[str, Rows]) -> dict[str, tuple]:
    """Global shape and dtype of each dataset, from the ranks that hold rows of it."""
    local = {k: (r.values.shape[1:], np.asarray(r.values).dtype.str) for k, r in datasets.items()
             if len(r.values)}
    found: dict[str, tuple] = {}
    for part in comm.allgather(local):
        for k, v in part.items():
            found.setdefault(k, v)
    out = {}
    for k, r in datasets.items():
        trailing, dtype = found.get(k, (np.asarray(r.values).shape[1:], "<f8"))
        out[k] = ((int(r.size), *trailing), np.dtype(dtype))
    return out


def _create_h5(path: Path, shapes: dict[str, tuple], attrs: dict) -> dict[str, int | None]:
    """The file with its datasets allocated and unfilled; their byte offsets (rank 0)."""
    dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
    dcpl.set_layout(h5py.h5d.CONTIGUOUS)
    dcpl.set_alloc_time(h5py.h5d.ALLOC_TIME_EARLY)
    dcpl.set_fill_time(h5py.h5d.FILL_TIME_NEVER)
    offsets: dict[str, int | None] = {}
    with h5py.File(path, "w") as f:
        for key, value in attrs.items():
            f.attrs[key] = value
        for name, (shape, dtype) in shapes.items():
            parent = f.require_group(name.rsplit("/", 1)[0]) if "/" in name else f
            space = h5py.h5s.create_simple(shape)
            dset = h5py.h5d.create(parent.id, name.rsplit("/", 1)[-1].encode(),
                                   h5py.h5t.py_create(dtype), space, dcpl=dcpl)
            offsets[name] = dset.get_offset() if np.prod(shape) else None
    return offsets


def write_h5(comm: MPI.Comm, path: Path, datasets: Mapping[str, Rows],
             attrs: dict | None = None) -> None:
    """Write an HDF5 file whose datasets' rows come from every rank (collective, atomic).

    Args:
        comm: Communicator.
        path: The file (written as ``.<name>.part`` and renamed when complete).
        datasets: Dataset name (``"u"``, ``"mesh/points"``) to this rank's rows.
        attrs: Attributes of the root group (small values, given on rank 0).

    Raises:
        OutputError: On every rank, when any rank could not write.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.part")
    shapes = _shapes(comm, datasets)
    try:
        offsets = on_root(comm, _create_h5, tmp, shapes, attrs or {})
    except OSError as err:
        on_root(comm, tmp.unlink, missing_ok=True)
        raise OutputError(f"could not write {path}: {_reason(err)}") from None
    try:
        with _agreed(comm, path):
            pieces = [(offsets[k], r.rows, r.values, *shapes[k]) for k, r in datasets.items()
                      if offsets[k] is not None]
            _write_pieces(comm, tmp, sorted(pieces, key=lambda p: p[0]))
        on_root(comm, _rename, tmp, path)
    except OutputError:
        on_root(comm, tmp.unlink, missing_ok=True)
        raise


def _write_pieces(comm: MPI.Comm, path: Path, pieces: list[tuple]) -> None:
    """Write this rank's rows of every dataset in one collective call.

    ``pieces``: (byte offset, row set, values, global shape, dtype) per dataset, by offset.
    """
    blocks, starts, data = [], [], []
    for offset, rows, values, shape, dtype in pieces:
        values = np.asarray(values, dtype=dtype).reshape(rows.count, *shape[1:])
        if rows.count and rows.last >= shape[0]:
            raise ValueError(f"row ids outside 0..{shape[0] - 1}")
        row_bytes = int(np.prod(shape[1:], dtype=np.int64)) * dtype.itemsize
        starts.append(offset + rows.starts * row_bytes)
        blocks.append(rows.lengths * row_bytes)
        data.append(rows.sorted(values).view(np.uint8).reshape(-1))
    buf = np.concatenate(data) if data else np.empty(0, dtype=np.uint8)
    ftype = MPI.BYTE.Create_hindexed(np.concatenate(blocks).tolist() if blocks else [],
                                     np.concatenate(starts).tolist() if starts else []).Commit()
    fh = MPI.File.Open(comm, str(path), MPI.MODE_WRONLY)
    try:
        fh.Set_view(0, MPI.BYTE, ftype)
        fh.Write_all([buf, MPI.BYTE])
    finally:
        fh.Close()
        ftype.Free()


def _rename(tmp: Path, path: Path) -> None:
    try:
        os.replace(tmp, path)
    except OSError as err:
        raise OutputError(f"could not write {path}: {_reason(err)}") from None


# -- text ------------------------------------------------------------------------------------
def write_ordered(comm: MPI.Comm, path: Path, offset: int, data: bytes) -> int:
    """Write each rank's ``data`` at ``offset``, the ranks' blocks one after another (collective).

    Args:
        comm: Communicator.
        path: An existing file.
        offset: Byte offset of rank 0's block (the file's end, to append).
        data: This rank's bytes.

    Returns:
        The offset after the last rank's block (on every rank).

    Raises:
        OutputError: On every rank, when any rank could not write.
    """
    start = offset + (comm.exscan(len(data)) or 0)
    end = offset + comm.allreduce(len(data))
    with _agreed(comm, path):
        fh = MPI.File.Open(comm, str(path), MPI.MODE_WRONLY)
        try:
            fh.Write_at_all(start, [np.frombuffer(data, dtype=np.uint8), MPI.BYTE])
        finally:
            fh.Close()
    return end
