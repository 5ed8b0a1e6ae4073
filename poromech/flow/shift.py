"""Trace shift: solve for ``δ± = p_{K±,σ} - p_{f,σ}`` on stiffly coupled fracture faces.

With a normal transmissibility much larger than the matrix conductances (open, conductive
fractures) the two traces of a fracture face are tied to ``p_{f,σ}`` by a stiff spring, which
aggregation AMG handles badly: the three unknowns form isolated aggregates. On such faces the
system is solved for ``δ±`` instead of the traces, a congruence ``QᵀAQ`` with a unit triangular
``Q``: the matrix stays SPD and the discrete solution is unchanged. The stiffness then sits on
the diagonal of the ``δ`` rows and ``p_{f,σ}`` couples to the matrix faces directly. Where the
normal coupling is weak (blocking or barely conductive fractures) the traces are kept, since
there the shift would tie ``p_{f,σ}`` to the matrix instead.

A face is shifted when ``|σ| T_f/η >= r (A⁺_σσ + A⁻_σσ)`` (the diagonal entries of both cell
matrices at that face) with ``r`` = :data:`SHIFT_RATIO`. Measured with CG + GAMG (default
options) on the benchmarks of Flemisch et al. (2018), 84k-133k unknowns: case 2 (ratio ~1e6)
needs the shift (24 instead of 210 iterations); case 2 with ``Λ_f,n = 1`` (ratio ~1e2) and
Hydrocoin (ratio ~3e2) converge best without it (25 instead of 97 each), so the switch sits at
``r = 1e3``. The owner of the face decides, from the cell contributions of all ranks (reverse
scatter), and every rank holding the face receives the decision (forward scatter), so the
choice is the same on every partition.
"""

from __future__ import annotations

import dolfinx_solver  # noqa: F401  (orders MPI before the bindings)

import dolfinx
import numpy as np
import numpy.typing as npt

from poromech.flow.dofs import FlowDofs
from poromech.mesh.fractured import FracturedMesh

__all__ = ["SHIFT_RATIO", "TraceShift"]

#: Stiffness ratio (normal transmissibility over matrix conductances) above which a fracture
#: face is solved in shifted variables.
SHIFT_RATIO = 1e3


class TraceShift:
    """Which fracture faces are solved in shifted variables, and the conversions (local data).

    Attributes:
        cell: ``(nc, 3)`` mask of the faces of the owned cells that are shifted.
        pair: ``(nf,)`` mask of the owned fracture faces that are shifted.
    """

    def __init__(self, fm: FracturedMesh, dofs: FlowDofs, cell_facets: npt.NDArray[np.int32],
                 ratio: float = SHIFT_RATIO):
        self.fm, self.dofs, self.ratio = fm, dofs, ratio
        self._cell_facets = cell_facets
        self._on = dofs.cell_fracture >= 0
        trace = np.concatenate([dofs.cell_faces[self._on], dofs.trace[:, 0], dofs.trace[:, 1]])
        frac = np.concatenate([dofs.cell_fracture[self._on], dofs.fracture, dofs.fracture])
        ff = fm.fractures.facets
        facet = np.concatenate([cell_facets[self._on], ff, ff])
        self._trace, first = np.unique(trace, return_index=True)
        self._frac, self._facet = frac[first], facet[first]
        self.cell = np.zeros(cell_facets.shape, dtype=bool)
        self.pair = np.zeros(len(ff), dtype=bool)
        self._facet_flag = np.zeros(0, dtype=bool)

    def update(self, A_cell: npt.NDArray[np.float64], t_pair: npt.NDArray[np.float64]) -> bool:
        """Decide the shifted faces for new coefficients (collective).

        Returns:
            True when the choice changed on any rank.
        """
        top = self.fm.msh.topology
        fmap = top.index_map(top.dim - 1)
        vec = dolfinx.la.vector(fmap, 1, dtype=np.float64)
        diag = np.einsum("nii->ni", A_cell)
        vec.array[:] = 0.0
        np.add.at(vec.array, self._cell_facets[self._on], diag[self._on])
        vec.scatter_reverse(dolfinx.la.InsertMode.add)
        owned = vec.array[: fmap.size_local].copy()
        vec.array[:] = 0.0
        ff = self.fm.fractures.facets
        vec.array[ff] = (t_pair >= self.ratio * owned[ff]).astype(np.float64)
        vec.scatter_forward()
        flag = vec.array > 0.5
        changed = len(flag) != len(self._facet_flag) or bool(np.any(flag != self._facet_flag))
        self._facet_flag = flag
        self.cell = self._on & flag[self._cell_facets]
        self.pair = flag[ff]
        return bool(self.fm.comm.allreduce(changed))

    @property
    def num_shifted(self) -> int:
        """Global number of shifted fracture faces (collective)."""
        return int(self.fm.comm.allreduce(int(self.pair.sum())))

    def to_pressure(self, values: npt.NDArray[np.float64]) -> None:
        """Solved variables to pressures, in place: ``p_trace = δ + p_f`` on shifted faces."""
        on = self._facet_flag[self._facet]
        values[self._trace[on]] += values[self._frac[on]]

    def to_variables(self, values: npt.NDArray[np.float64]) -> None:
        """Pressures to solved variables, in place (inverse of :meth:`to_pressure`)."""
        on = self._facet_flag[self._facet]
        values[self._trace[on]] -= values[self._frac[on]]
