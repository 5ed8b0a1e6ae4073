"""Linear solves of the Newton direction ``J Y = F``: strategies behind one interface.

The semi-smooth Newton (:mod:`poromech.mechanics.newton`) asks its strategy for a direction and
tells it when it assembled a new Jacobian; how the linear system is solved, and what is kept
from one solve to the next, is the strategy's business:

* :class:`DirectSolver` (the default, ``ksp_type preonly`` + ``pc_type lu``): a factorization,
  kept while the assembled Jacobian is bitwise unchanged; when only a few contact points changed
  state since it was computed, GMRES preconditioned by the stale factorization is tried first
  (options prefix ``<prefix>stale_``), within a budget of iterations worth one factorization;
* :class:`IterativeSolver` (any other KSP, e.g. ``ksp_type gmres`` + ``pc_type gamg``): the
  preconditioner is set up again only for a Jacobian that was assembled since the last set-up.

Both are chosen by :func:`linear_strategy` from the PETSc options of the solver's KSP. Every
decision depends on contact states, sizes and iteration counts, never on measured times, so a run
is reproducible.
"""

from __future__ import annotations

from typing import Protocol

import dolfinx_solver  # noqa: F401

import numpy as np
import numpy.typing as npt
from mpi4py import MPI
from petsc4py import PETSc

__all__ = [
    "DirectSolver",
    "IterativeSolver",
    "LinearStrategy",
    "STALE_BUDGET",
    "STALE_MAX_CHANGES",
    "STALE_MAX_IT",
    "STALE_MIN_UNKNOWNS",
    "STALE_RTOL",
    "is_direct",
    "linear_strategy",
]

#: GMRES iterations allowed with a stale factorization before refactorizing: about what one
#: refactorization costs (measured on the six-fracture scene with P2 Nitsche on 2 ranks, one
#: factorization took the time of 7.5, 10 and 12 stale GMRES iterations at 12.5k, 49k and 192k
#: unknowns), so that a failed attempt at most doubles the cost of the iteration.
STALE_MAX_IT = 12
#: Relative true residual of a stale GMRES solve. Tighter is not reachable reliably: with a
#: stale factorization the residual stagnates between 1e-8 and 1e-9 of ``|F|`` on that scene.
#: A direction this accurate lands within 1e-7 ``|F|`` of the root of its affine piece, so it
#: costs at most one more (cheap) Newton iteration.
STALE_RTOL = 1e-7
#: Stale GMRES is tried when at most this many contact points changed state since the last
#: factorization: each changed point changes the Jacobian by a rank of one or two, and GMRES
#: converges in about that rank plus one iteration.
STALE_MAX_CHANGES = 8
#: Stale GMRES iterations allowed in total between two factorizations. Their sum is what the
#: stale factorization has cost so far; once it reaches the price of one factorization
#: (:data:`STALE_MAX_IT` iterations), the next Jacobian that is not the factorized one is
#: factorized (the rent-or-buy rule: at most twice the cost of the best choice in hindsight).
#: Without it a Jacobian that changed by a few points stayed stale for whole time steps: the
#: quiet steps of the coupled six-fracture scene at m = 2 made five GMRES solves of 5-9
#: iterations each, where one factorization and four reuses cost half as much (linear solves
#: of the run 118-125 s without the budget, 97-110 s with it).
STALE_BUDGET = STALE_MAX_IT
#: Stale GMRES is tried only on systems with at least this many unknowns. Below, a
#: factorization is so cheap that GMRES iterations with it cost more (coupled six-fracture
#: scene, P2 Nitsche, contact mechanics seconds for the 20 steps with / without stale solves:
#: 7.9 / 4.4 at 12.5k unknowns on 1 rank, 30.6 / 28.5 at 49k on 2 ranks; 150 with them at 192k
#: on 2 ranks, where 171 was spent with 3.3 times as many factorizations).
STALE_MIN_UNKNOWNS = 100_000


def is_direct(ksp: PETSc.KSP) -> bool:
    """Whether the KSP applies a factorization (preonly + LU/Cholesky)."""
    return ksp.getType() == PETSc.KSP.Type.PREONLY and ksp.getPC().getType() in ("lu", "cholesky")


class LinearStrategy(Protocol):
    """How the Newton direction is solved, and what is kept between solves (collective)."""

    def assembled(self, states: npt.NDArray | None) -> None:
        """A new Jacobian was assembled into the matrix, in the contact states ``states``."""

    def solve(self, F: PETSc.Vec, Y: PETSc.Vec, record, states: npt.NDArray | None) -> bool:
        """``J Y = F``; adds its work to ``record`` (a NewtonRecord); True if it converged."""

    def forget(self) -> None:
        """Drop what is kept (after a failed solve)."""

    def destroy(self) -> None:
        """Free the PETSc objects."""


class _StalePC:
    """Python PC context applying an existing (stale) factorization."""

    def __init__(self, pc: PETSc.PC):
        self.pc = pc

    def apply(self, pc, x, y) -> None:
        self.pc.apply(x, y)


class DirectSolver:
    """A factorization of the Jacobian, reused while it is valid, with stale GMRES in between.

    Args:
        ksp: The Newton's KSP (preonly + LU), whose PC holds the factorization.
        A: The Jacobian matrix.
        prefix: Options prefix of the Newton (the stale GMRES uses ``<prefix>stale_``).
        reuse: Reuse the factorization while the Jacobian is bitwise unchanged.
        stale: Try GMRES preconditioned by the stale factorization after few state changes.

    Attributes:
        stale_min_unknowns: Smallest system on which stale GMRES is tried
            (:data:`STALE_MIN_UNKNOWNS`).
        stale_budget: Stale GMRES iterations allowed between two factorizations
            (:data:`STALE_BUDGET`).
    """

    def __init__(self, ksp: PETSc.KSP, A: PETSc.Mat, prefix: str, *, reuse: bool, stale: bool):
        self.ksp, self.A, self.comm = ksp, A, A.getComm().tompi4py()
        self.reuse = reuse
        self.stale_min_unknowns = STALE_MIN_UNKNOWNS
        self.stale_budget = STALE_BUDGET
        self._values = None  # Jacobian values at the last factorization
        self._assembled = True  # the matrix was assembled since the last factorization
        self._jacobian_states = None  # contact states of the assembled Jacobian
        self._factor_states = None  # contact states of the factorized Jacobian
        self._stale_spent = 0  # stale GMRES iterations since the last factorization
        self._stale_ksp = self._create_stale_ksp(prefix) if stale else None

    def _create_stale_ksp(self, prefix: str) -> PETSc.KSP:
        """GMRES on the Jacobian preconditioned by the (stale) factorization of the Newton's PC.

        Options prefix ``<prefix>stale_`` (``mech_stale_ksp_max_it``, ...); call with the
        Newton's options pushed.
        """
        ksp = PETSc.KSP().create(self.comm)
        ksp.setOptionsPrefix(f"{prefix}stale_")
        ksp.setType(PETSc.KSP.Type.GMRES)
        ksp.setTolerances(rtol=STALE_RTOL, atol=0.0, max_it=STALE_MAX_IT)
        # right preconditioning: the test is on the true residual of the current Jacobian
        ksp.setPCSide(PETSc.PC.Side.RIGHT)
        ksp.setNormType(PETSc.KSP.NormType.UNPRECONDITIONED)
        ksp.getPC().setType(PETSc.PC.Type.PYTHON)
        ksp.getPC().setPythonContext(_StalePC(self.ksp.getPC()))
        ksp.setOperators(self.A, self.A)
        ksp.setFromOptions()
        return ksp

    def assembled(self, states: npt.NDArray | None) -> None:
        """A new Jacobian is in the matrix (its values are compared before refactorizing)."""
        self._assembled = True
        self._jacobian_states = None if states is None else states.copy()

    def unchanged(self) -> bool:
        """True when the Jacobian equals the one last factorized (collective).

        Without an assembly since that factorization (the Jacobian was kept for an unchanged
        active set) it is the same matrix; otherwise the values are compared.
        """
        if not self._assembled:  # the same on every rank: assemblies are collective
            return self._values is not None
        values = self.A.getValuesCSR()[2]
        same = self._values is not None and np.array_equal(values, self._values)
        return self.comm.allreduce(bool(same), op=MPI.LAND)

    def _factorized(self) -> None:
        """Remember the values and the active set of the Jacobian just factorized."""
        self._stale_spent = 0
        self._values = self.A.getValuesCSR()[2].copy() if self.reuse else None
        self._factor_states = self._jacobian_states
        self._assembled = False

    def changes_since_factorization(self, states: npt.NDArray | None) -> int | None:
        """Contact points whose state differs from that of the factorized Jacobian (collective).

        Counted over all ranks; None when unknown (no states, or not recorded).
        """
        known = self._factor_states is not None and states is not None
        if not self.comm.allreduce(known, op=MPI.LAND):
            return None
        return int(self.comm.allreduce(int(np.count_nonzero(states != self._factor_states))))

    def solve(self, F: PETSc.Vec, Y: PETSc.Vec, record, states: npt.NDArray | None) -> bool:
        """Newton direction ``J Y = F`` with the cheapest exact-enough solve.

        Reuse the factorization when ``J`` is unchanged; after few contact-state changes try
        GMRES preconditioned by the stale factorization, while the stale iterations since the
        factorization stay below :attr:`stale_budget`; otherwise refactorize.
        """
        ksp = self.ksp
        has_factor = self._values is not None
        if has_factor and self.unchanged():
            ksp.getPC().setReusePreconditioner(True)
            ksp.solve(F, Y)
            return ksp.getConvergedReason() > 0
        few = False
        if (self._stale_ksp is not None and has_factor and is_direct(ksp)
                and self.A.getSize()[0] >= self.stale_min_unknowns
                and self._stale_spent < self.stale_budget):
            changes = self.changes_since_factorization(states)
            few = changes is not None and changes <= STALE_MAX_CHANGES
        if few:
            ksp.getPC().setReusePreconditioner(True)  # keep the old factors when applied
            stale = self._stale_ksp
            stale.solve(F, Y)
            self._stale_spent += stale.getIterationNumber()
            record.linear_iterations += stale.getIterationNumber()
            if stale.getConvergedReason() > 0:
                record.stale_solves += 1
                return True
        ksp.setOperators(self.A, self.A)
        ksp.getPC().setReusePreconditioner(False)
        ksp.solve(F, Y)
        record.factorizations += 1
        self._factorized()
        return ksp.getConvergedReason() > 0

    def forget(self) -> None:
        """The factorization is no longer trusted (a failed solve): refactorize next time."""
        self._values = None

    def destroy(self) -> None:
        """Free the stale GMRES."""
        if self._stale_ksp is not None:
            self._stale_ksp.destroy()


class IterativeSolver:
    """A Krylov solve whose preconditioner is set up again only for a newly assembled Jacobian.

    The KSP, its preconditioner and tolerances come from the Newton's PETSc options (e.g.
    ``mech_ksp_type gmres``, ``mech_pc_type gamg``); a near-nullspace attached to the matrix by
    the owner (rigid-body modes) is used by GAMG. Counts its set-ups as ``factorizations``.

    Args:
        ksp: The Newton's KSP.
        A: The Jacobian matrix.
    """

    def __init__(self, ksp: PETSc.KSP, A: PETSc.Mat):
        self.ksp, self.A = ksp, A
        self._fresh = True  # a Jacobian was assembled since the last set-up

    def assembled(self, states: npt.NDArray | None) -> None:
        """A new Jacobian is in the matrix: the preconditioner is set up at the next solve."""
        self._fresh = True

    def solve(self, F: PETSc.Vec, Y: PETSc.Vec, record, states: npt.NDArray | None) -> bool:
        """``J Y = F`` by the Krylov method, from a zero guess."""
        ksp = self.ksp
        if self._fresh:
            ksp.setOperators(self.A, self.A)
            ksp.getPC().setReusePreconditioner(False)
            record.factorizations += 1
            self._fresh = False
        else:
            ksp.getPC().setReusePreconditioner(True)
        ksp.solve(F, Y)
        record.linear_iterations += ksp.getIterationNumber()
        return ksp.getConvergedReason() > 0

    def forget(self) -> None:
        """Set the preconditioner up again at the next solve."""
        self._fresh = True

    def destroy(self) -> None:
        """Nothing of its own to free (the KSP belongs to the Newton)."""


def linear_strategy(ksp: PETSc.KSP, A: PETSc.Mat, prefix: str, *, reuse: bool,
                    stale: bool) -> LinearStrategy:
    """The strategy for the KSP as its options configured it (call with the options pushed)."""
    if is_direct(ksp):
        return DirectSolver(ksp, A, prefix, reuse=reuse, stale=stale)
    return IterativeSolver(ksp, A)
