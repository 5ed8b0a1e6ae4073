"""p-multigrid for P2 displacements: the P1 space of the same cracked mesh as the coarse level.

GAMG on a P2 elasticity matrix aggregates vertex and edge dofs alike, and its smoothed
aggregation has to rediscover an interpolation that the discretisation already knows: the P1
functions of the same cracked mesh are P2 functions, interpolated exactly, fracture by fracture
(the two spaces share their cracked topology, so no P1 function couples the two sides of a
fracture either). :class:`PMultigrid` makes the preconditioner of the Newton's Krylov solve a
two-level PCMG:

* fine level, the P2 Jacobian: Chebyshev (degree 2) with point-block Jacobi (:data:`FINE_SMOOTHER`),
  pre- and post-smoothing, on a copy of the Jacobian in d × d blocks (:data:`FINE_FORMAT`),
  which the Krylov method multiplies by too;
* coarse level, the Galerkin operator ``Pᵀ J P`` of the P1 space (about 1/8 of the unknowns and
  a third of the nonzeros per row), solved by one GAMG V-cycle with the rigid-body modes of P1.

Its set-up is a triple product and a GAMG set-up of the P1 operator, a fraction of a GAMG set-up
on P2 (0.5 s against 4.6 s per set-up on the 257k-unknown network of docs/mechanics3d.md), so the
preconditioner is set up for every new Jacobian instead of being lagged. GAMG aggregates and
builds its prolongators at its first set-up only, and later set-ups form the Galerkin products
of the new operator (PETSc keeps the interpolation of a matrix of the same pattern; on the
level-4 network 45 set-ups made one aggregation): the coarse spaces come from the run's first
Jacobian, where a restart builds them too
(:meth:`~poromech.mechanics.linear.IterativeSolver.prime`). The options under
``<prefix>mg_levels_`` (the fine smoother) and ``<prefix>mg_coarse_`` (the P1 solve) override
the defaults (:func:`~poromech.mechanics.linear.iterative_options`).
"""

from __future__ import annotations

import dolfinx_solver  # noqa: F401

import numpy.typing as npt
from dolfinx import fem
from dolfinx.fem.petsc import interpolation_matrix
from petsc4py import PETSc

__all__ = ["FINE_FORMAT", "FINE_SMOOTHER", "PMultigrid", "p1_interpolation"]

#: Storage of the P2 operator of the Krylov method and the fine smoother: a copy of the
#: Jacobian in blocks of d × d (PETSc's BAIJ), whose product is faster than the AIJ Jacobian's
#: (one column index per block): 30–33 ms against 35–43 ms for the 257k-unknown network's
#: Jacobian (21M nonzeros), refreshed at each set-up in 0.15 s. The Galerkin product
#: ``Pᵀ J P`` is formed from the AIJ Jacobian (PETSc has no BAIJ × AIJ product). None: the
#: Jacobian itself.
FINE_FORMAT: str | None = "baij"

#: The fine level's smoother (``<prefix>mg_levels_pc_type`` overrides it): point-block Jacobi,
#: the inverse of each node's 3 × 3 block (d × d), which holds the contact terms' coupling of
#: the components along an inclined fracture. The eleven-fracture network at 257k unknowns
#: (the first two load steps, 1 rank): 398 GMRES iterations in 76 s, point Jacobi 529 in
#: 86–90 s, SOR 242 in 109 s (one Chebyshev iteration instead of two: 294 in 86 s). On the coarse
#: P2 network of tests/test_network3d.py (11k unknowns, the same two steps) point Jacobi took
#: 1,054 GMRES iterations, point-block Jacobi 218, SOR 123. A solve that stalls with it is
#: repeated with SOR, kept for the run (``FALLBACK_IT`` in :mod:`poromech.mechanics.linear`).
FINE_SMOOTHER = "pbjacobi"


def p1_interpolation(V: fem.FunctionSpace, V1: fem.FunctionSpace) -> PETSc.Mat:
    """The interpolation of the P1 space ``V1`` into the P2 space ``V`` (collective).

    Rows: the owned dofs of ``V``; columns: those of ``V1``. Both spaces must be built on the
    same cracked topology (:func:`poromech.mesh.fractured.cracked_space`), so that the
    interpolation is exact and does not couple the two sides of a fracture. The rows of
    displacement-condition dofs are kept: their Jacobian rows are the identity, which the
    smoother solves exactly.
    """
    P = interpolation_matrix(V1, V)
    P.assemble()
    return P


def smoother_name(ksp_type: str, pc_type: str) -> str:
    """A fine-level smoother's name: its PC type with Chebyshev, else ``KSP/PC``."""
    return pc_type if ksp_type == PETSc.KSP.Type.CHEBYSHEV else f"{ksp_type}/{pc_type}"


class PMultigrid:
    """A two-level PCMG on a KSP: P2 smoothing, GAMG on the P1 Galerkin operator.

    Configure with the options of the Newton pushed (``PrefixedOptions``): the smoother and the
    coarse KSP read theirs here.

    Args:
        ksp: The Newton's KSP, whose preconditioner becomes the PCMG.
        P: The interpolation from the coarse (P1) to the fine (P2) space
            (:func:`p1_interpolation`).
        coarse_modes: The rigid-body modes of the P1 space
            (:func:`~poromech.mechanics.linear.rigid_body_modes`), the coarse GAMG's
            near-nullspace.
        near_nullspace: Builds the near-nullspace of a matrix from modes
            (:func:`~poromech.mechanics.linear.near_nullspace`).

    Attributes:
        fine_format: PETSc storage of the P2 operator's copy (:data:`FINE_FORMAT`), or None.
    """

    def __init__(self, ksp: PETSc.KSP, P: PETSc.Mat, coarse_modes: npt.NDArray,
                 near_nullspace):
        self.P = P
        self._modes, self._near_nullspace = coarse_modes, near_nullspace
        self.coarse_size = P.getSize()[1]
        pc = ksp.getPC()
        pc.setType(PETSc.PC.Type.MG)
        pc.setMGLevels(2)
        pc.setMGType(PETSc.PC.MGType.MULTIPLICATIVE)
        pc.setMGInterpolation(1, P)
        smoother = pc.getMGSmoother(1)
        smoother.setType(PETSc.KSP.Type.CHEBYSHEV)
        smoother.getPC().setType(FINE_SMOOTHER)
        smoother.setFromOptions()
        coarse = pc.getMGCoarseSolve()
        coarse.setType(PETSc.KSP.Type.PREONLY)
        coarse.getPC().setType(PETSc.PC.Type.GAMG)
        coarse.setFromOptions()
        self.pc = pc
        self.A_coarse: PETSc.Mat | None = None
        self.fine_format = FINE_FORMAT
        self.A_fine: PETSc.Mat | None = None  # the fine_format copy of the Jacobian
        self._nullspace = None

    @property
    def level_smoother(self) -> tuple[str, str]:
        """The fine level's KSP and PC types."""
        smoother = self.pc.getMGSmoother(1)
        return smoother.getType(), smoother.getPC().getType()

    @property
    def smoother(self) -> str:
        """The fine level's smoother: its PC type, ``richardson/PC`` for plain sweeps."""
        return smoother_name(*self.level_smoother)

    def set_smoother(self, smoother: str, ksp_type: str = PETSc.KSP.Type.CHEBYSHEV) -> None:
        """Make ``smoother`` (a PC type) with ``ksp_type`` the P2 level's (built at set-up)."""
        level = self.pc.getMGSmoother(1)
        level.setType(ksp_type)
        level.getPC().setType(smoother)

    def set_up(self, A: PETSc.Mat) -> PETSc.Mat:
        """The levels' operators of the Jacobian ``A`` (collective); the KSP's operator.

        The coarse operator is ``Pᵀ A P``; the fine one, and the returned operator of the
        Krylov method, ``A`` stored as :attr:`fine_format` (:data:`FINE_FORMAT`). The KSP's
        own ``setUp`` then sets the smoother and the coarse GAMG up.
        """
        if self.A_coarse is None:
            self.A_coarse = A.ptap(self.P)
            self._nullspace = self._near_nullspace(self.A_coarse, self._modes)
        else:
            A.ptap(self.P, result=self.A_coarse)
        coarse = self.pc.getMGCoarseSolve()
        coarse.setOperators(self.A_coarse, self.A_coarse)
        coarse.getPC().setReusePreconditioner(False)
        fine = A
        if self.fine_format is not None:
            if self.A_fine is None:
                self.A_fine = A.convert(self.fine_format, PETSc.Mat())
            else:
                A.convert(self.fine_format, self.A_fine)
            fine = self.A_fine
        self.pc.getMGSmoother(1).setOperators(fine, fine)
        return fine

    def destroy(self) -> None:
        """Free the interpolation, the coarse operator, its near-nullspace and the fine copy."""
        for obj in (self.P, self.A_coarse, self.A_fine, self._nullspace):
            if obj is not None:
                obj.destroy()
