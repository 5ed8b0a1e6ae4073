"""The HFV linear system in its symmetric positive definite form, assembled in COO format.

The equations of DESIGN §5 with the sign of the face, trace and node equations flipped are the
gradient of a sum of element energies, so the matrix is a sum of symmetric positive
semi-definite element matrices:

* matrix cell ``K`` on ``[p_K, p_{K,σ_1..3}]``: ``[[1ᵀA1, -(A1)ᵀ], [-A1, A]]`` with ``A = A_K / η``;
* matrix-fracture pair on ``[p_{K,σ}, p_{f,σ}]``: ``|σ| T_f / η · [[1, -1], [-1, 1]]``;
* fracture face on ``[p_{f,σ}, p_e ...]`` (two nodes in 2D, three edges in 3D): the
  cell element of the face matrix ``A_fracture`` (in 2D the diagonal of the two-point
  fluxes ``T*_{σ,e} / η``), half face and, at an intersection, the overlap with the crossed
  fractures (:mod:`poromech.flow.intersections`);
* storage on ``[p_K]``: ``|K| s_K / Δt`` and on ``[p_{f,σ}]``: ``|σ| s_f / Δt`` (zero for
  steady solves).

On fracture faces with a stiff normal coupling the system is solved for
``δ± = p_{K±,σ} - p_{f,σ}`` instead of the traces (see :mod:`poromech.flow.shift`): cell
elements are then assembled on ``[p_K, face unknowns, p_f of the fracture faces]`` as
``E' = Bᵀ E B`` and the pair elements reduce to ``|σ| T_f/η δ²``. The pattern holds the
entries of both variants, so switching a face is a values-only change.

The pattern (global row and column of every element entry) is fixed once; a new set of
coefficients only recomputes the flat value array handed to ``MatSetValuesCOO``. Dirichlet
unknowns keep their (natural) diagonal entry, their other entries are dropped from the pattern
(as are entries of absent ``p_f`` slots), and the right-hand side receives the diagonal times
the value plus the usual lifting.
"""

from __future__ import annotations

from dataclasses import dataclass

import dolfinx_solver  # noqa: F401  (orders MPI before the bindings)

import numpy as np
import numpy.typing as npt
from petsc4py import PETSc

from poromech.flow.dofs import FlowDofs

__all__ = [
    "ElementValues",
    "SystemPattern",
    "cell_elements",
    "pair_elements",
    "shifted_cell_elements",
]

Array = npt.NDArray[np.float64]


def cell_elements(A: Array) -> Array:
    """Element matrices ``[[1ᵀA1, -(A1)ᵀ], [-A1, A]]`` on ``[p_K, face values]``.

    Args:
        A: Cell matrices ``(n, F, F)``.

    Returns:
        ``(n, F + 1, F + 1)``.
    """
    n, nf, _ = A.shape
    r = A.sum(axis=2)
    E = np.empty((n, nf + 1, nf + 1))
    E[:, 0, 0] = r.sum(axis=1)
    E[:, 0, 1:] = -r
    E[:, 1:, 0] = -r
    E[:, 1:, 1:] = A
    return E


def shifted_cell_elements(E: Array, shifted: npt.NDArray[np.bool_]) -> Array:
    """Cell elements in the variables ``[p_K, face unknowns, p_f slots]`` (``Bᵀ E B``).

    Args:
        E: Elements from :func:`cell_elements`, ``(n, F + 1, F + 1)``.
        shifted: ``(n, F)`` mask of the shifted fracture faces (their unknown is ``δ`` and
            their trace is ``δ + p_f``).

    Returns:
        ``(n, 2F + 1, 2F + 1)``.
    """
    n, nf = shifted.shape
    B = np.zeros((n, nf + 1, 2 * nf + 1))
    B[:, np.arange(nf + 1), np.arange(nf + 1)] = 1.0
    B[:, np.arange(1, nf + 1), np.arange(nf + 1, 2 * nf + 1)] = shifted
    return np.einsum("nij,nik,nkl->njl", B, E, B)


def pair_elements(t: Array, shifted: npt.NDArray[np.bool_]) -> Array:
    """Matrix-fracture elements on ``[trace or δ, p_f]``, ``(n, 2, 2)``.

    ``t [[1, -1], [-1, 1]]`` in trace variables, ``[[t, 0], [0, 0]]`` (``t δ²``) when shifted.
    """
    E = t[:, None, None] * np.array([[1.0, -1.0], [-1.0, 1.0]])[None]
    E[shifted] = 0.0
    E[shifted, 0, 0] = t[shifted]
    return E


@dataclass(frozen=True)
class ElementValues:
    """Element matrices of every block (already divided by the viscosity).

    Attributes:
        cell: ``(n0, d + 2, d + 2)`` elements of the cells without fracture faces.
        fracture_cell: ``(n1, 2d + 3, 2d + 3)`` elements of the cells with fracture faces (see
            :func:`shifted_cell_elements`).
        pair: ``(2 nf, 2, 2)`` matrix-fracture elements, ``+`` sides then ``-`` sides.
        fracture: ``(nf, d + 1, d + 1)`` fracture-face elements.
        storage: ``(nc,)`` storage diagonal ``|K| s_K / Δt``.
        fracture_storage: ``(nf,)`` fracture storage diagonal ``|σ| s_f / Δt``.
    """

    cell: Array
    fracture_cell: Array
    pair: Array
    fracture: Array
    storage: Array
    fracture_storage: Array

    def flat(self) -> Array:
        """All entries in pattern order."""
        return np.concatenate([self.cell.ravel(), self.fracture_cell.ravel(), self.pair.ravel(),
                               self.fracture.ravel(), self.storage, self.fracture_storage])


def _element_dofs(dofs: FlowDofs, split) -> list[npt.NDArray[np.int64]]:
    """Local dofs of each element block, in :class:`ElementValues` order."""
    plain, touching = split
    cell = np.column_stack([dofs.cell, dofs.cell_faces])[plain]
    fcell = np.column_stack([dofs.cell, dofs.cell_faces, dofs.cell_fracture])[touching]
    pair_plus = np.column_stack([dofs.trace[:, 0], dofs.fracture])
    pair_minus = np.column_stack([dofs.trace[:, 1], dofs.fracture])
    pair = np.concatenate([pair_plus, pair_minus])
    frac = np.column_stack([dofs.fracture, dofs.node])
    return [cell, fcell, pair, frac, dofs.cell[:, None], dofs.fracture[:, None]]


class SystemPattern:
    """Fixed COO pattern of the HFV matrix and its right-hand-side helpers (local data).

    Args:
        dofs: The distributed numbering.
        dirichlet: Mask of Dirichlet unknowns over the local dofs.
    """

    def __init__(self, dofs: FlowDofs, dirichlet: npt.NDArray[np.bool_]):
        self.dofs = dofs
        touching = (dofs.cell_fracture >= 0).any(axis=1)
        #: Owned cells without / with a fracture face (the two cell element blocks).
        self.plain_cells = np.flatnonzero(~touching)
        self.fracture_cells = np.flatnonzero(touching)
        rows, cols = [], []
        for el in _element_dofs(dofs, (self.plain_cells, self.fracture_cells)):
            k = el.shape[1]
            rows.append(np.repeat(el, k, axis=1).ravel())
            cols.append(np.tile(el, (1, k)).ravel())
        self.rows, self.cols = np.concatenate(rows), np.concatenate(cols)
        self.dirichlet = dirichlet
        valid = (self.rows >= 0) & (self.cols >= 0)
        dr, dc = dirichlet[self.rows] & valid, dirichlet[self.cols] & valid
        diag = self.rows == self.cols
        self.keep = valid & (diag | ~(dr | dc))
        self.lift = np.flatnonzero(dc & ~dr)
        self.dirichlet_diag = np.flatnonzero(diag & dr)

    def create_matrix(self, comm) -> PETSc.Mat:
        """An AIJ matrix preallocated with this pattern (collective)."""
        d = self.dofs
        g_rows = np.full(len(self.rows), -1, dtype=np.int64)
        g_cols = np.full(len(self.cols), -1, dtype=np.int64)
        g_rows[self.keep] = d.local_to_global(self.rows[self.keep])
        g_cols[self.keep] = d.local_to_global(self.cols[self.keep])
        A = PETSc.Mat().create(comm)
        A.setSizes(((d.num_owned, d.num_global), (d.num_owned, d.num_global)))
        A.setType(PETSc.Mat.Type.AIJ)
        A.setPreallocationCOO(g_rows.astype(PETSc.IntType), g_cols.astype(PETSc.IntType))
        A.setOption(PETSc.Mat.Option.SPD, True)
        return A

    def dirichlet_rhs(self, values: Array, g: Array) -> Array:
        """Local right-hand side of the Dirichlet rows and of the lifting, ``(num_local,)``.

        Args:
            values: Flat element values (pattern order).
            g: Dirichlet values over the local dofs (zero elsewhere).
        """
        n = self.dofs.num_local
        i, j = self.dirichlet_diag, self.lift
        out = np.bincount(self.rows[i], values[i] * g[self.cols[i]], minlength=n)
        out -= np.bincount(self.rows[j], values[j] * g[self.cols[j]], minlength=n)
        return out
