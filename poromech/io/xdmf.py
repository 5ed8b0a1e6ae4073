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

The data are gathered to rank 0, which writes them with h5py in the global numbering given by the
caller, so the files do not depend on the number of MPI ranks.
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
from poromech.parallel import on_root

__all__ = [
    "MeshPiece",
    "Series",
    "XDMFSeries",
    "atomic_h5",
    "atomic_write_text",
    "gather_rows",
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


def gather_rows(comm: MPI.Comm, ids: npt.NDArray[np.int64], values: npt.NDArray,
                size: int | None = None) -> npt.NDArray | None:
    """Assemble rows given by global id on every rank into one array on rank 0 (collective).

    Rows given by several ranks must agree (the last one wins). Returns None on other ranks.
    """
    parts = comm.gather((np.asarray(ids, dtype=np.int64), np.asarray(values)), root=0)
    if comm.rank != 0:
        return None
    n = size if size is not None else max((int(i.max()) + 1 for i, _ in parts if len(i)),
                                          default=0)
    shape = next(v.shape[1:] for _, v in parts)
    dtype = np.result_type(*[v.dtype for _, v in parts])
    out = np.zeros((n, *shape), dtype=dtype)
    for i, v in parts:
        out[i] = v
    return out


@dataclass(frozen=True)
class MeshPiece:
    """This rank's part of an output mesh, in global numbering.

    Attributes:
        point_ids: Global ids of the points this rank knows, ``(n,)``.
        points: Their coordinates, ``(n, 2)`` (m).
        cell_ids: Global ids of the cells this rank writes (each cell on one rank), ``(m,)``.
        cells: Their points as global point ids, ``(m, 2 or 3)``.
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
        self._points = (np.asarray(mesh.point_ids, dtype=np.int64), mesh.point_ids.size)
        self._cells = np.asarray(mesh.cell_ids, dtype=np.int64)
        self.num_points = int(comm.allreduce(int(mesh.point_ids.max(initial=-1)), op=MPI.MAX)) + 1
        self.num_cells = int(comm.allreduce(int(mesh.cell_ids.max(initial=-1)), op=MPI.MAX)) + 1
        self.nodes_per_cell = int(comm.allreduce(mesh.cells.shape[1], op=MPI.MAX))
        self.gdim = int(comm.allreduce(mesh.points.shape[1], op=MPI.MAX))
        pts = gather_rows(comm, mesh.point_ids, mesh.points[:, :self.gdim], self.num_points)
        cells = gather_rows(comm, mesh.cell_ids, mesh.cells, self.num_cells)
        self.entries: list[_Entry] = []
        root_write(comm, self._start, pts, cells, resume_until)

    def _start(self, pts, cells, resume_until: float | None) -> None:
        """Mesh file and (empty or resumed) index (rank 0)."""
        self.steps_dir.mkdir(parents=True, exist_ok=True)
        if resume_until is not None:
            self.entries = self._read_index(resume_until)
        with atomic_h5(self.outdir / f"{self.stem}.h5") as f:
            f["mesh/points"] = np.ascontiguousarray(pts, dtype=np.float64)
            f["mesh/cells"] = np.ascontiguousarray(cells, dtype=np.int64)
        self._write_index()

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
                ``(n,)`` or vector ``(n, 2)``.
            cell_data: Values on this rank's cells (the order of ``mesh.cell_ids``).
        """
        point_data, cell_data = point_data or {}, cell_data or {}
        ids, _ = self._points
        gathered = {
            "point": {k: gather_rows(self.comm, ids, v, self.num_points)
                      for k, v in point_data.items()},
            "cell": {k: gather_rows(self.comm, self._cells, v, self.num_cells)
                     for k, v in cell_data.items()},
        }
        root_write(self.comm, self._write_step, t, gathered)

    def _write_step(self, t: float, gathered: dict) -> None:
        """The step's data file, then the index (rank 0)."""
        name = f"{len(self.entries):06d}.h5"
        entry = _Entry(float(t), f"{self.steps_dir.name}/{name}")
        with atomic_h5(self.steps_dir / name) as f:
            f.attrs["time"] = float(t)
            for center, data in gathered.items():
                for key, arr in data.items():
                    arr = np.asarray(arr, dtype=np.float64)
                    if arr.ndim == 2:  # 2D vectors are padded to 3 components for ParaView
                        arr = np.column_stack([arr, np.zeros(len(arr))])
                    f[key] = arr
                    comps = 1 if arr.ndim == 1 else arr.shape[1]
                    (entry.point_fields if center == "point" else entry.cell_fields)[key] = comps
        self.entries.append(entry)
        self._write_index()

    # -- index ------------------------------------------------------------------------------
    def _write_index(self) -> None:
        """Rewrite ``<stem>.xdmf`` atomically from :attr:`entries` (rank 0)."""
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


@dataclass
class Series:
    """A written series read back: the mesh, the output times and each step's fields."""

    points: npt.NDArray[np.float64]
    cells: npt.NDArray[np.int64]
    times: list[float]
    files: list[Path]

    def fields(self, step: int) -> dict[str, npt.NDArray[np.float64]]:
        """All fields of output step ``step`` (negative counts from the end)."""
        with h5py.File(self.files[step], "r") as f:
            return {k: f[k][()] for k in f.keys()}

    def at(self, t: float) -> dict[str, npt.NDArray[np.float64]]:
        """The fields of the step whose time is nearest to ``t``."""
        return self.fields(int(np.argmin(np.abs(np.asarray(self.times) - t))))


def read_series(outdir: Path, stem: str) -> Series:
    """Read back a series written by :class:`XDMFSeries` (serial, any process)."""
    outdir = Path(outdir)
    with h5py.File(outdir / f"{stem}.h5", "r") as f:
        points, cells = f["mesh/points"][()], f["mesh/cells"][()]
    times, files = [], []
    for grid in ET.parse(outdir / f"{stem}.xdmf").getroot().iter("Grid"):
        if grid.get("GridType") != "Uniform":
            continue
        times.append(float(grid.find("Time").get("Value")))
        item = next(iter(grid.iter("Attribute"))).find("DataItem").text.strip()
        files.append(outdir / item.split(":/")[0])
    return Series(points, cells, times, files)
