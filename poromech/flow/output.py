"""Output fields of the flow problem on the matrix cells and the fracture faces (collective).

``flow.xdmf`` holds, per output time, the matrix pressure ``p_m`` (Pa) and Darcy velocity
``u_m`` (m/s), both cell-wise; a coupled run adds the overpressure ``p_m - p⁰`` and the porosity.
``fractures_flow.xdmf`` (flow-only runs; a coupled run writes these fields into
``fractures.xdmf``) holds, on the fracture faces: ``p_f`` (Pa), the traces ``p_plus``/``p_minus``
(Pa), the aperture ``d_f`` (m), the tangential volumetric flux ``q_f`` (vector, m²/s: per
unit depth in 2D, per unit width of the fracture in 3D) and the normal fluxes
``u_plus``/``u_minus`` from each matrix side into the fracture (m/s). The series are
crash-safe (:mod:`poromech.io.xdmf`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from poromech.flow.balance import Fluxes, cell_velocity
from poromech.flow.problem import DarcyProblem
from poromech.io.output import fracture_mesh, matrix_mesh
from poromech.io.xdmf import XDMFSeries

__all__ = ["FlowWriter", "fracture_fields", "matrix_fields"]


def matrix_fields(problem: DarcyProblem, fluxes: Fluxes) -> dict[str, np.ndarray]:
    """``p_m`` and ``u_m`` on the owned cells."""
    return {"p_m": problem.cell_pressure, "u_m": cell_velocity(problem, fluxes)}


def fracture_fields(problem: DarcyProblem, fluxes: Fluxes) -> dict[str, np.ndarray]:
    """Pressures, aperture and fluxes on the owned fracture faces."""
    length = problem.faces.measure
    if problem.face_direction is None:  # 3D: (1/|σ|) Σ_e F_{σ,e} (x_e - x_σ), exact if constant
        offset = problem.dofs.points[problem.dofs.node] - problem.faces.midpoint[:, None]
        q_f = np.einsum("ne,nei->ni", fluxes.fracture, offset) / length[:, None]
    else:
        q_f = 0.5 * (fluxes.fracture[:, 1] - fluxes.fracture[:, 0])[:, None] \
            * problem.face_direction
    return {
        "p_f": problem.fracture_pressure,
        "p_plus": problem.trace_pressure[:, 0],
        "p_minus": problem.trace_pressure[:, 1],
        "d_f": problem.properties.aperture,
        "u_plus": fluxes.pair[:, 0] / length,
        "u_minus": fluxes.pair[:, 1] / length,
        "q_f": q_f,
    }


class FlowWriter:
    """Writes the flow fields of a :class:`DarcyProblem` at each output time.

    Args:
        problem: The flow problem.
        outdir: Output directory (exists).
        matrix_file: File stem of the matrix fields.
        fracture_file: File stem of the fracture fields (None: not written).
        resume_until: Continue the series of an earlier run up to this time.
    """

    def __init__(self, problem: DarcyProblem, outdir: Path, matrix_file: str = "flow",
                 fracture_file: str | None = "fractures_flow",
                 resume_until: float | None = None):
        self.problem = problem
        fm = problem.fm
        self.matrix = XDMFSeries(fm.comm, outdir, matrix_file, matrix_mesh(fm), "matrix",
                                 resume_until)
        self.fracture = None
        if fracture_file and fm.num_fracture_faces:
            self.fracture = XDMFSeries(fm.comm, outdir, fracture_file, fracture_mesh(fm),
                                       "fractures", resume_until)

    def write(self, t: float, fluxes: Fluxes, extra_cells: dict | None = None) -> None:
        """Write all fields at time ``t`` (collective)."""
        pb = self.problem
        self.matrix.write(t, cell_data={**matrix_fields(pb, fluxes), **(extra_cells or {})})
        if self.fracture is not None:
            self.fracture.write(t, cell_data=fracture_fields(pb, fluxes))

    def close(self) -> None:
        """Nothing stays open between steps."""
