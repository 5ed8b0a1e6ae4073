"""The accepted state of a Darcy problem: what the next step starts from and what a restart needs.

Shared by the flow-only physics (:mod:`poromech.flow.physics`) and the coupled one
(:mod:`poromech.coupling.poromechanics`): the pressures of the last accepted step (the initial
guess of a retried step), the porosity and fracture volume of that step (the references of the
next step's storage terms), and their partition-independent checkpoint arrays.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from poromech.flow.problem import DarcyProblem
from poromech.io.checkpoint import scalar_row
from poromech.mesh.entities import input_cells
from poromech.physics import Keyed

__all__ = ["FlowState"]

Array = npt.NDArray[np.float64]


class FlowState:
    """The accepted pressures, porosity and fracture volume of a Darcy problem.

    Args:
        problem: The Darcy problem whose unknowns are kept.

    Attributes:
        porosity: Matrix porosity of the accepted step on the owned cells, or None (steady).
        aperture: Fracture volume per area of the accepted step on the owned fracture faces
            (m), or None (steady).
    """

    def __init__(self, problem: DarcyProblem):
        self.problem = problem
        self.porosity: Array | None = None
        self.aperture: Array | None = None
        self._pressure = problem.p.copy()

    def accept(self, porosity: Array | None, aperture: Array | None) -> None:
        """The solved pressures are accepted, with the step's porosity and fracture volume."""
        if porosity is not None:
            self.porosity = porosity
        if aperture is not None:
            self.aperture = aperture
        self._pressure = self.problem.p.copy()

    def reject(self) -> None:
        """Back to the accepted pressures (the initial guess of the retried step; collective)."""
        self.problem.set_unknowns(self._pressure)

    def checkpoint(self) -> dict[str, Keyed]:
        """Cell and fracture pressures, porosity and aperture, keyed by input cell / global face."""
        pb = self.problem
        cells = input_cells(pb.fm.msh)
        faces = pb.fm.fractures.index.astype(np.int64)
        out = {"p_cell": (cells, pb.cell_pressure), "p_fracture": (faces, pb.fracture_pressure)}
        if self.porosity is not None:
            out["porosity"] = (cells, self.porosity)
        if self.aperture is not None:
            out["aperture"] = (faces, self.aperture)
        if pb.solver.fallback is not None:  # the run continued solves with MUMPS from here
            out["flow_linear_direct"] = scalar_row(pb.fm.msh.comm, 1.0)
        return out

    def restore(self, arrays: dict[str, npt.NDArray]) -> None:
        """Pressures (other unknowns keep their guess), porosity and aperture from a checkpoint.

        Collective; the restored pressures are the accepted ones.
        """
        pb = self.problem
        fm, d = pb.fm, pb.dofs
        cells = input_cells(fm.msh)
        p = pb.p.copy()
        p[d.cell] = arrays["p_cell"][cells]
        p[d.fracture] = arrays["p_fracture"][fm.fractures.index]  # collective: on every rank
        pb.set_unknowns(p)
        if "porosity" in arrays:
            self.porosity = arrays["porosity"][cells]
        if "aperture" in arrays:
            self.aperture = arrays["aperture"][fm.fractures.index]
        if "flow_linear_direct" in arrays and pb.solver.fallback is None:
            pb.solver.switch_to_direct(restart=True)
        self._pressure = pb.p.copy()
