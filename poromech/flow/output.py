"""XDMF output of the flow fields: matrix cells and the fracture-facet submesh (collective).

``flow.xdmf`` holds, per output time, the matrix pressure ``p_m`` (Pa) and Darcy velocity
``u_m`` (m/s), both cell-wise (DG0). ``fractures_flow.xdmf`` holds, on the fracture faces:
``p_f`` (Pa), the traces ``p_plus``/``p_minus`` (Pa), the aperture ``d_f`` (m), the tangential
volumetric flux ``q_f`` (vector, m²/s per unit depth) and the normal fluxes ``u_plus``/
``u_minus`` from each matrix side into the fracture (m/s).
"""

from __future__ import annotations

from pathlib import Path

import dolfinx_solver  # noqa: F401  (orders MPI before the bindings)

import dolfinx
import numpy as np
from dolfinx import fem
from dolfinx.io import XDMFFile

from poromech.flow.balance import Fluxes, cell_velocity
from poromech.flow.problem import DarcyProblem

__all__ = ["FlowWriter"]

#: Scalar fields on the fracture faces, in writing order.
FRACTURE_FIELDS = ("p_f", "p_plus", "p_minus", "d_f", "u_plus", "u_minus")


def _owned_dofs(V: fem.FunctionSpace, cells) -> np.ndarray:
    """DG0 dofs of the given cells, checked to be owned (so a forward scatter keeps them)."""
    dofs = V.dofmap.list[cells, 0]
    if np.any(dofs >= V.dofmap.index_map.size_local):
        raise RuntimeError("flow output: an owned entity maps to a ghost dof")
    return dofs


class FlowWriter:
    """Writes the flow fields of a :class:`DarcyProblem` at each output time.

    Args:
        problem: The flow problem.
        outdir: Output directory (exists).
        matrix_file: File name of the matrix fields.
        fracture_file: File name of the fracture fields.
    """

    def __init__(self, problem: DarcyProblem, outdir: Path, matrix_file: str = "flow.xdmf",
                 fracture_file: str = "fractures_flow.xdmf"):
        self.problem = problem
        fm = problem.fm
        msh, comm = fm.msh, fm.comm
        nc = problem.geom.num_cells
        self.p_m = fem.Function(fem.functionspace(msh, ("DG", 0)), name="p_m")
        self.u_m = fem.Function(fem.functionspace(msh, ("DG", 0, (2,))), name="u_m")
        self._cells = _owned_dofs(self.p_m.function_space, np.arange(nc))
        self.matrix = XDMFFile(comm, str(Path(outdir) / matrix_file), "w")
        self.matrix.write_mesh(msh)
        self.fracture = None
        if fm.num_fracture_faces:
            sub, emap, _, _ = dolfinx.mesh.create_submesh(msh, 1, fm.fracture_facets_all)
            sub.name = "fractures"
            Q = fem.functionspace(sub, ("DG", 0))
            self.fields = {n: fem.Function(Q, name=n) for n in FRACTURE_FIELDS}
            self.q_f = fem.Function(fem.functionspace(sub, ("DG", 0, (2,))), name="q_f")
            cells = emap.sub_topology_to_topology(fm.fractures.facets, inverse=True)
            self._faces = _owned_dofs(Q, cells)
            self.fracture = XDMFFile(comm, str(Path(outdir) / fracture_file), "w")
            self.fracture.write_mesh(sub)

    def write(self, t: float, fluxes: Fluxes) -> None:
        """Write all fields at time ``t`` (collective)."""
        pb = self.problem
        _assign(self.p_m, self._cells, pb.cell_pressure)
        _assign(self.u_m, self._cells, cell_velocity(pb, fluxes))
        self.matrix.write_function(self.p_m, t)
        self.matrix.write_function(self.u_m, t)
        if self.fracture is None:
            return
        length = pb.faces.length
        values = {
            "p_f": pb.fracture_pressure,
            "p_plus": pb.trace_pressure[:, 0],
            "p_minus": pb.trace_pressure[:, 1],
            "d_f": pb.properties.aperture,
            "u_plus": fluxes.pair[:, 0] / length,
            "u_minus": fluxes.pair[:, 1] / length,
        }
        for name, f in self.fields.items():
            _assign(f, self._faces, values[name])
            self.fracture.write_function(f, t)
        along = 0.5 * (fluxes.fracture[:, 1] - fluxes.fracture[:, 0])
        _assign(self.q_f, self._faces, along[:, None] * pb.faces.tangent)
        self.fracture.write_function(self.q_f, t)

    def close(self) -> None:
        """Close the files."""
        self.matrix.close()
        if self.fracture is not None:
            self.fracture.close()


def _assign(f: fem.Function, dofs: np.ndarray, values: np.ndarray) -> None:
    """Set owned DG0 values and update the ghosts."""
    bs = f.function_space.dofmap.index_map_bs
    f.x.array.reshape(-1, bs)[dofs] = np.asarray(values).reshape(len(dofs), bs)
    f.x.scatter_forward()
