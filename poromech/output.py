"""Output of a mechanics run: XDMF/VTX for ParaView, ``fractures.csv``, ``summary.json``.

The displacement is written on a *duplicated-node* P1 mesh (the cracked topology), so a
"Warp By Vector" in ParaView shows the fractures opening and sliding. Fracture fields are cell
data on the fracture mesh. Everything is written as soon as a step converges, so a run that
fails later keeps what it already wrote.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import dolfinx_solver  # noqa: F401

import basix.ufl
import dolfinx
import numpy as np
import numpy.typing as npt
import ufl
from dolfinx import fem
from dolfinx.io import VTXWriter, XDMFFile
from mpi4py import MPI

from poromech.mechanics import FACE_FIELDS, STATE_NAMES, MechanicsModel
from poromech.mesh import FracturedMesh

__all__ = ["CSV_COLUMNS", "MechanicsOutput", "duplicated_node_mesh", "write_summary"]

CSV_COLUMNS = ("time", "fracture", "s", "x", "y", "jump_n", "jump_t", "traction_n", "traction_t",
               "state")


def _keep_local_partitioner():
    """Partitioner that leaves every cell on the rank that passes it (no ghosts)."""

    def part(comm, nparts, graph, ghosting):
        n = len(graph.offsets) - 1
        return dolfinx.cpp.graph.AdjacencyList_int32(
            np.full(n, comm.rank, dtype=np.int32), np.arange(n + 1, dtype=np.int32)
        )

    return dolfinx.mesh.create_cell_partitioner(part, dolfinx.mesh.GhostMode.none, 2)


def duplicated_node_mesh(fm: FracturedMesh) -> tuple[dolfinx.mesh.Mesh, npt.NDArray[np.int32]]:
    """P1 mesh of the cracked topology, with the same owned cells per rank (collective).

    Returns:
        The mesh and, for each of its local cells, the local cell of ``fm.msh`` it copies.
    """
    comm, msh = fm.comm, fm.msh
    nloc = msh.topology.index_map(2).size_local
    cells = np.ascontiguousarray(fm.cracked_cells[:nloc])
    x = msh.geometry.x[msh.geometry.dofmaps[0][:nloc]][:, :, :2].reshape(-1, 2)
    num = comm.allreduce(int(cells.max()) + 1 if len(cells) else 0, op=MPI.MAX)
    gathered = comm.gather((cells.ravel(), x), root=0)
    coords = np.zeros((num, 2)) if comm.rank == 0 else np.empty((0, 2))
    if comm.rank == 0:
        for ids, xs in gathered:
            coords[ids] = xs
    element = basix.ufl.element("Lagrange", "triangle", 1, shape=(2,))
    out = dolfinx.mesh.create_mesh(comm, cells, ufl.Mesh(element), coords,
                                   _keep_local_partitioner())
    offset = comm.exscan(nloc) or 0
    nout = out.topology.index_map(2).size_local
    source = np.asarray(out.topology.original_cell_index[:nout], dtype=np.int64) - offset
    return out, source.astype(np.int32)


class _DisplacementTransfer:
    """Copies vertex values of the displacement onto the duplicated-node P1 output mesh."""

    def __init__(self, fm: FracturedMesh, u: fem.Function):
        self.mesh, source = duplicated_node_mesh(fm)
        self.W = fem.functionspace(self.mesh, ("Lagrange", 1, (2,)))
        self.w = fem.Function(self.W, name="u")
        geo = self.mesh.geometry
        out_ids = geo.input_global_indices[geo.dofmaps[0][: len(source)]]
        in_ids = fm.cracked_cells[source]
        # position in the fm.msh cell of each output vertex
        pos = np.argmax(out_ids[:, :, None] == in_ids[:, None, :], axis=2)
        vdofs = u.function_space.dofmap.list[source]  # vertex dofs come first in Lagrange
        self.u_dofs = np.take_along_axis(vdofs, pos, axis=1).ravel()
        self.w_dofs = self.W.dofmap.list[: len(source), :3].ravel()
        self.u = u

    def __call__(self) -> fem.Function:
        src = self.u.x.array.reshape(-1, 2)
        self.w.x.array.reshape(-1, 2)[self.w_dofs] = src[self.u_dofs]
        self.w.x.scatter_forward()
        return self.w


class MechanicsOutput:
    """Writers of one mechanics run (collective constructor and methods).

    Args:
        model: The mechanics model.
        outdir: Output directory (created by the caller).
        xdmf: Write XDMF files.
        vtx: Write a VTX file of a P2 displacement.
        csv_file: Write ``fractures.csv``.
    """

    def __init__(self, model: MechanicsModel, outdir: Path, xdmf: bool = True, vtx: bool = True,
                 csv_file: bool = True):
        self.model, self.outdir, fm = model, Path(outdir), model.fm
        self.comm = fm.comm
        self._files = []
        self.transfer = None
        if xdmf:
            self.transfer = _DisplacementTransfer(fm, model.u)
            self.u_file = XDMFFile(self.comm, str(self.outdir / "displacement.xdmf"), "w")
            self.u_file.write_mesh(self.transfer.mesh)
            self._files.append(self.u_file)
        self.vtx = None
        if vtx and model.scene.degree > 1:
            self.vtx = VTXWriter(self.comm, str(self.outdir / "displacement_p2.bp"), [model.u],
                                 engine="BP4")
            self._files.append(self.vtx)
        self.fracture_file = None
        if xdmf and model.faces is not None:
            Q = fem.functionspace(model.submesh, ("DG", 0))
            self.face_functions = {name: fem.Function(Q, name=name)
                                   for name in (*FACE_FIELDS[:4], "state")}
            self.fracture_file = XDMFFile(self.comm, str(self.outdir / "fractures.xdmf"), "w")
            self.fracture_file.write_mesh(model.submesh)
            self._files.append(self.fracture_file)
            self._sub_cells = model.emap.sub_topology_to_topology(fm.fractures.facets, inverse=True)
        self.csv_path = self.outdir / "fractures.csv" if csv_file and model.faces is not None \
            else None
        if self.csv_path is not None and self.comm.rank == 0:
            with open(self.csv_path, "w", newline="") as fh:
                csv.writer(fh).writerow(CSV_COLUMNS)

    def write(self, t: float, values: npt.NDArray[np.float64],
              states: npt.NDArray[np.int8]) -> None:
        """Write all outputs at time ``t`` from the owned face values and states."""
        if self.transfer is not None:
            self.u_file.write_function(self.transfer(), t)
        if self.vtx is not None:
            self.vtx.write(t)
        if self.fracture_file is not None:
            for k, name in enumerate(FACE_FIELDS[:4]):
                f = self.face_functions[name]
                f.x.array[self._sub_cells] = values[:, k]
                f.x.scatter_forward()
                self.fracture_file.write_function(f, t)
            f = self.face_functions["state"]
            f.x.array[self._sub_cells] = states
            f.x.scatter_forward()
            self.fracture_file.write_function(f, t)
        if self.csv_path is not None:
            self._append_csv(t, values, states)

    def _append_csv(self, t, values, states) -> None:
        faces = self.model.fm.fractures
        names = self.model.fm.geometry.fracture_names
        rows = np.column_stack([faces.index, faces.fracture, faces.s, faces.midpoint,
                                values[:, :4], states])
        gathered = self.comm.gather(rows, root=0)
        if self.comm.rank != 0:
            return
        rows = np.concatenate(gathered)
        rows = rows[np.argsort(rows[:, 0])]
        with open(self.csv_path, "a", newline="") as fh:
            w = csv.writer(fh)
            for r in rows:
                w.writerow([f"{t:.9g}", names[int(r[1])], f"{r[2]:.9g}", f"{r[3]:.9g}",
                            f"{r[4]:.9g}", *(f"{v:.9e}" for v in r[5:9]),
                            STATE_NAMES[int(r[9])]])

    def close(self) -> None:
        """Close the files."""
        for f in self._files:
            f.close()
        self._files = []


def write_summary(comm: MPI.Comm, outdir: Path, summary: dict) -> None:
    """Write ``summary.json`` on rank 0."""
    if comm.rank == 0:
        (Path(outdir) / "summary.json").write_text(json.dumps(summary, indent=2, default=_json))


def _json(obj):
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return float(obj)
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"cannot serialize {type(obj)}")
