"""Crash-safe XDMF time series: one HDF5 file per output step and an index rewritten atomically.

A series ``<stem>`` in an output directory consists of

* ``<stem>.h5`` — the mesh (``/mesh/points``, ``/mesh/cells``), written once;
* ``<stem>_steps/<k>.h5`` — the fields of output step ``k`` (one dataset per field);
* ``<stem>.xdmf`` — the XDMF 3 index of the completed steps (a temporal collection).

Every file is written under a temporary name and renamed when complete, and the index is
rewritten (temporary file + rename) only after the step's data file is in place. A run killed at
any moment therefore leaves an index that lists exactly the completed steps, each readable by
ParaView's "Xdmf3 Reader T" and by h5py. (One HDF5 file kept open for the whole run is left with
an unreadable object header when the process is killed; closing and reopening it for every step
still leaves the whole file at the mercy of a kill during a step's write.)

The data files are written by every rank at once (:func:`poromech.io.mpiio.write_h5`): each rank
writes the rows of the points and cells it owns, at their place in the global numbering given
by the caller, which does not depend on the partition; nothing that grows with the mesh passes
through rank 0, and the files are the same on any number of ranks. Rank 0 writes only the
index, whose size grows with the number of steps, not with the mesh.
"""

from __future__ import annotations

import contextlib
import os
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np
import numpy.typing as npt
from mpi4py import MPI

from poromech.errors import OutputError
from poromech.io.mpiio import Rows, RowSet, write_h5
from poromech.parallel import on_root

__all__ = [
    "MeshPiece",
    "Series",
    "XDMFSeries",
    "atomic_h5",
    "atomic_write_text",
    "read_series",
    "root_write",
]

#: XDMF topology names of the supported cell types (nodes per cell).
_TOPOLOGY = {3: "Triangle", 2: "Polyline", 4: "Tetrahedron"}


@contextlib.contextmanager
def _atomic(path: Path, opener: Callable) -> Iterator:
    """Write through ``.<name>.part`` and rename; on failure remove it, raise OutputError."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.part")
    try:
        with opener(tmp) as fh:
            yield fh
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        reason = os.strerror(err.errno) if err.errno else str(err).split(" (")[0]
        raise OutputError(f"could not write {path}: {reason}") from None


def atomic_h5(path: Path):
    """An HDF5 file written atomically (context manager yielding the h5py file)."""
    return _atomic(path, lambda p: h5py.File(p, "w"))


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and a rename (local, any rank)."""
    with _atomic(path, lambda p: open(p, "w")) as fh:
        fh.write(text)


def root_write(comm: MPI.Comm, fn: Callable, *args) -> None:
    """Run a write on rank 0; its error is raised on every rank (collective)."""
    on_root(comm, fn, *args)


@dataclass(frozen=True)
class MeshPiece:
    """This rank's part of an output mesh, in a global numbering independent of the partition.

    Attributes:
        point_ids: Global ids of the points this rank writes (each point on one rank), ``(n,)``.
        points: Their coordinates, ``(n, d)`` (m).
        cell_ids: Global ids of the cells this rank writes (each cell on one rank), ``(m,)``.
        cells: Their points as global point ids, ``(m, k)``.
    """

    point_ids: npt.NDArray[np.int64]
    points: npt.NDArray[np.float64]
    cell_ids: npt.NDArray[np.int64]
    cells: npt.NDArray[np.int64]


@dataclass
class _Entry:
    time: float
    file: str
    point_fields: dict[str, int] = field(default_factory=dict)  # name -> components
    cell_fields: dict[str, int] = field(default_factory=dict)


class XDMFSeries:
    """A time series of point and cell fields on a fixed mesh (collective methods).

    Args:
        comm: Communicator.
        outdir: Output directory (exists).
        stem: File stem (``displacement`` gives ``displacement.xdmf``).
        mesh: This rank's part of the mesh.
        name: Grid name shown by ParaView.
        resume_until: When continuing a run, keep the steps already indexed up to this time
            (the others are removed); None starts a new series.
    """

    def __init__(self, comm: MPI.Comm, outdir: Path, stem: str, mesh: MeshPiece,
                 name: str = "mesh", resume_until: float | None = None):
        self.comm, self.outdir, self.stem, self.name = comm, Path(outdir), stem, name
        self._point_rows, self._cell_rows = RowSet(mesh.point_ids), RowSet(mesh.cell_ids)
        self.num_points = int(comm.allreduce(self._point_rows.last, op=MPI.MAX)) + 1
        self.num_cells = int(comm.allreduce(self._cell_rows.last, op=MPI.MAX)) + 1
        self.nodes_per_cell = int(comm.allreduce(mesh.cells.shape[1], op=MPI.MAX))
        self.gdim = int(comm.allreduce(mesh.points.shape[1], op=MPI.MAX))
        self.entries: list[_Entry] = []
        write_h5(comm, self.outdir / f"{self.stem}.h5", {
            "mesh/points": self._points(np.asarray(mesh.points, dtype=np.float64)[:, :self.gdim]),
            "mesh/cells": self._cells(np.asarray(mesh.cells, dtype=np.int64)),
        })
        root_write(comm, self._start, resume_until)

    def _start(self, resume_until: float | None) -> None:
        """The steps directory and the (empty or resumed) index (rank 0)."""
        self.steps_dir.mkdir(parents=True, exist_ok=True)
        if resume_until is not None:
            self.entries = self._read_index(resume_until)
        self._write_index()

    def _points(self, values: npt.NDArray) -> Rows:
        return Rows(self._point_rows, values, self.num_points)

    def _cells(self, values: npt.NDArray) -> Rows:
        return Rows(self._cell_rows, values, self.num_cells)

    @property
    def steps_dir(self) -> Path:
        """Directory of the per-step data files."""
        return self.outdir / f"{self.stem}_steps"

    @property
    def count(self) -> int:
        """Number of completed steps in the series (rank 0; 0 elsewhere)."""
        return len(self.entries)

    def write(self, t: float, point_data: dict[str, npt.NDArray] | None = None,
              cell_data: dict[str, npt.NDArray] | None = None) -> None:
        """Write one output step at time ``t`` (collective).

        Args:
            t: Time (s).
            point_data: Values on this rank's points (the order of ``mesh.point_ids``), scalar
                ``(n,)`` or vector ``(n, 2 or 3)``; 2D vectors get a third, zero, component.
            cell_data: Values on this rank's cells (the order of ``mesh.cell_ids``).
        """
        point_data, cell_data = point_data or {}, cell_data or {}
        rows = {**{k: self._points(_padded(v)) for k, v in point_data.items()},
                **{k: self._cells(_padded(v)) for k, v in cell_data.items()}}
        comps = {k: int(self.comm.allreduce(1 if r.values.ndim == 1 else r.values.shape[1],
                                            op=MPI.MAX)) for k, r in rows.items()}
        name = f"{len(self.entries) if self.comm.rank == 0 else 0:06d}.h5"
        name = self.comm.bcast(name, root=0)
        write_h5(self.comm, self.steps_dir / name, rows, {"time": float(t)})
        entry = _Entry(float(t), f"{self.steps_dir.name}/{name}",
                       {k: comps[k] for k in point_data}, {k: comps[k] for k in cell_data})
        root_write(self.comm, self._add, entry)

    def _add(self, entry: _Entry) -> None:
        """Index a step whose data file is complete (rank 0)."""
        self.entries.append(entry)
        self._write_index()

    # -- index ------------------------------------------------------------------------------
    def _write_index(self) -> None:
        """Rewrite ``<stem>.xdmf`` atomically from :attr:`entries` (rank 0).

        Without entries there is no index: a temporal collection with no grid made VTK's XDMF
        reader (ParaView's "XDMF Reader") fail and crash on a run that stopped before its first
        output step.
        """
        if not self.entries:
            (self.outdir / f"{self.stem}.xdmf").unlink(missing_ok=True)
            return
        root = ET.Element("Xdmf", Version="3.0")
        domain = ET.SubElement(root, "Domain")
        series = ET.SubElement(domain, "Grid", Name=self.name, GridType="Collection",
                               CollectionType="Temporal")
        for e in self.entries:
            grid = ET.SubElement(series, "Grid", Name=self.name, GridType="Uniform")
            ET.SubElement(grid, "Time", Value=repr(e.time))
            topo = ET.SubElement(grid, "Topology", TopologyType=_TOPOLOGY[self.nodes_per_cell],
                                 NumberOfElements=str(self.num_cells),
                                 NodesPerElement=str(self.nodes_per_cell))
            self._item(topo, f"{self.stem}.h5:/mesh/cells",
                       (self.num_cells, self.nodes_per_cell), "Int")
            geo = ET.SubElement(grid, "Geometry", GeometryType="XY" if self.gdim == 2 else "XYZ")
            self._item(geo, f"{self.stem}.h5:/mesh/points", (self.num_points, self.gdim),
                       "Float")
            for center, fields, n in (("Node", e.point_fields, self.num_points),
                                      ("Cell", e.cell_fields, self.num_cells)):
                for key, comps in fields.items():
                    kind = "Scalar" if comps == 1 else "Vector"
                    att = ET.SubElement(grid, "Attribute", Name=key, AttributeType=kind,
                                        Center=center)
                    dims = (n,) if comps == 1 else (n, comps)
                    self._item(att, f"{e.file}:/{key}", dims, "Float")
        ET.indent(root)
        text = '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
        atomic_write_text(self.outdir / f"{self.stem}.xdmf", text)

    @staticmethod
    def _item(parent, ref: str, dims: tuple[int, ...], kind: str) -> None:
        item = ET.SubElement(parent, "DataItem", Dimensions=" ".join(map(str, dims)),
                             NumberType=kind, Precision="8", Format="HDF")
        item.text = ref

    def _read_index(self, until: float) -> list[_Entry]:
        """Steps of an existing index up to time ``until``; later step files are removed."""
        index = self.outdir / f"{self.stem}.xdmf"
        kept: list[_Entry] = []
        if index.exists():
            for grid in ET.parse(index).getroot().iter("Grid"):
                if grid.get("GridType") != "Uniform":
                    continue
                t = float(grid.find("Time").get("Value"))
                entry = _Entry(t, "")
                for att in grid.iter("Attribute"):
                    ref = att.find("DataItem").text.strip()
                    entry.file = ref.split(":/")[0]
                    dims = att.find("DataItem").get("Dimensions").split()
                    comps = 1 if len(dims) == 1 else int(dims[1])
                    target = entry.point_fields if att.get("Center") == "Node" else \
                        entry.cell_fields
                    target[att.get("Name")] = comps
                if t <= until * (1 + 1e-12) + 1e-300:
                    kept.append(entry)
        keep = {self.outdir / e.file for e in kept}
        for f in self.steps_dir.glob("*.h5"):
            if f not in keep:
                f.unlink()
        return kept


def _padded(values: npt.NDArray) -> npt.NDArray[np.float64]:
    """Field values as float64; 2D vectors padded to 3 components for ParaView."""
    values = np.asarray(values, dtype=np.float64)
    if values.ndim == 2 and values.shape[1] == 2:
        values = np.column_stack([values, np.zeros(len(values))])
    return values


@dataclass
class Series:
    """A written series read back: the mesh, the output times and each step's fields."""

    points: npt.NDArray[np.float64]
    cells: npt.NDArray[np.int64]
    times: list[float]
    files: list[Path]

    def fields(self, step: int) -> dict[str, npt.NDArray[np.float64]]:
        """All fields of output step ``step`` (negative counts from the end)."""
        with _open_h5(self.files[step]) as f:
            return {k: f[k][()] for k in f.keys()}

    def at(self, t: float) -> dict[str, npt.NDArray[np.float64]]:
        """The fields of the step whose time is nearest to ``t``."""
        return self.fields(int(np.argmin(np.abs(np.asarray(self.times) - t))))


def _open_h5(path: Path) -> h5py.File:
    """Open an HDF5 file for reading; an unreadable one raises an OSError that names it."""
    try:
        return h5py.File(path, "r")
    except OSError as err:
        if isinstance(err, FileNotFoundError):
            raise
        raise OSError(f"{path} cannot be read as HDF5 ({' '.join(str(err).split())})") from None


def read_series(outdir: Path, stem: str) -> Series:
    """Read back a series written by :class:`XDMFSeries` (serial, any process)."""
    outdir = Path(outdir)
    with _open_h5(outdir / f"{stem}.h5") as f:
        points, cells = f["mesh/points"][()], f["mesh/cells"][()]
    times, files = [], []
    try:
        root = ET.parse(outdir / f"{stem}.xdmf").getroot()
    except ET.ParseError as err:
        raise ValueError(f"{outdir / f'{stem}.xdmf'} cannot be read as XML ({err})") from None
    for grid in root.iter("Grid"):
        if grid.get("GridType") != "Uniform":
            continue
        times.append(float(grid.find("Time").get("Value")))
        item = next(iter(grid.iter("Attribute"))).find("DataItem").text.strip()
        files.append(outdir / item.split(":/")[0])
    return Series(points, cells, times, files)
