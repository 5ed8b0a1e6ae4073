"""Linear solves of the Newton direction ``J Y = F``: strategies behind one interface.

The semi-smooth Newton (:mod:`poromech.mechanics.newton`) asks its strategy for a direction and
tells it when it assembled a new Jacobian; how the linear system is solved, and what is kept
from one solve to the next, is the strategy's business:

* :class:`DirectSolver` (the default, ``ksp_type preonly`` + ``pc_type lu``): a factorization,
  kept while the assembled Jacobian is bitwise unchanged; when only a few contact points changed
  state since it was computed, GMRES preconditioned by the stale factorization is tried first
  (options prefix ``<prefix>stale_``), within a budget of iterations worth one factorization;
* :class:`IterativeSolver` (any other KSP, e.g. ``ksp_type cg`` + ``pc_type gamg``): the
  preconditioner is set up again only when the assembled Jacobian differs from the one it was
  set up for (a fingerprint ``A z`` with a fixed random ``z``); the rigid-body modes of the
  displacement space (:func:`rigid_body_modes`) are attached to the matrix as the near-nullspace
  that GAMG's aggregation interpolates. On a contact Jacobian whose options name no level
  smoother, GAMG's smoother is chosen at each set-up by the iteration counts of SOR and Jacobi
  on the same system (:data:`SWITCH_GAIN`).

Both are chosen by :func:`linear_strategy` from the PETSc options of the solver's KSP, whose
defaults for ``solver.linear_solver: iterative`` are :func:`iterative_options`. Every decision
depends on contact states, sizes and iteration counts, never on measured times, so a run is
reproducible.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Protocol

import dolfinx_solver  # noqa: F401

import numpy as np
import numpy.typing as npt
from dolfinx import fem
from mpi4py import MPI
from petsc4py import PETSc

from poromech.mechanics.multigrid import PMultigrid, smoother_name
from poromech.petsc_options import PrefixedOptions, ksp_reason_name

log = logging.getLogger("poromech")

__all__ = [
    "DirectSolver",
    "FaceElimination",
    "HISTORY_QUOTED",
    "ITERATIVE_OPTIONS",
    "IterativeSolver",
    "JACOBI_COST",
    "LinearStrategy",
    "P_MULTIGRID_OPTIONS",
    "STALE_BUDGET",
    "STALE_MAX_CHANGES",
    "STALE_MAX_IT",
    "SOLVE_SLOWDOWN",
    "STALE_BACKOFF",
    "STALE_MIN_UNKNOWNS",
    "STALE_RTOL",
    "SWITCH_GAIN",
    "failure_message",
    "forcing_term",
    "is_direct",
    "iterative_options",
    "linear_strategy",
    "near_nullspace",
    "rigid_body_modes",
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
#: How many times more slowly a triangular solve with MUMPS' factors runs than the factorization,
#: per flop (memory-bound substitutions against dense BLAS-3 fronts), for the priced budget of
#: :meth:`DirectSolver.price`. Measured on the 3D fault scene's medium mesh (``mixed`` P2,
#: 119k unknowns, 2 ranks): the factorization's 5.6e11 flops took 10.5 s, a stale GMRES
#: iteration (4 flops per factor entry, 2.3e8 entries, and a product with the Jacobian's
#: 1.9e7 nonzeros) 0.24 s: 581 iterations' worth of flops, 44 of time.
SOLVE_SLOWDOWN = 14.0
#: Priced stale GMRES after ``k`` failed attempts in a row (each followed by a factorization;
#: an attempt that had fewer than :data:`STALE_MAX_IT` iterations of the budget left does not
#: count) skips the next ``STALE_BACKOFF**k - 1`` opportunities: where the Jacobian moves too far
#: between iterations for the old factors to precondition it (``mixed`` P2 on the sheared
#: seven-fracture network: 24 of 31 attempts failed, with as few as 0-2 state changes, the
#: slip directions having turned), the loss stays a few attempts per run; where it works (the
#: fault scene, 4 of 42 failed) a lone failure costs little.
STALE_BACKOFF = 4


#: Defaults of ``solver.linear_solver: iterative`` for a symmetric positive definite Jacobian
#: (open fractures: linear elasticity), merged over the Newton's defaults (prefix ``mech_``);
#: the scene's ``solver.petsc`` and the command line override each of them.
#:
#: * CG measures the *unpreconditioned* residual ``‖F - J Y‖``, the norm the Newton tests;
#:   ``ksp_rtol`` one decade below the Newton's ``snes_rtol`` (1e-10) ends a linear problem in
#:   one Newton iteration with room for the drift of CG's recursive residual from the true one.
#:   It is far tighter than the agreement with MUMPS asks for: on P2 penny cracks of 16k-192k
#:   unknowns ``max |u_cg - u_lu| / max |u_lu|`` was 1-3e-12 (docs/mechanics3d/solvers.md).
#: * GAMG, smoothed aggregation (one prolongator smoothing step) with the rigid-body modes as
#:   near-nullspace: 40-47 CG iterations from 16k to 1.0M unknowns. On one 192k Jacobian
#:   (docs/mechanics3d/gamg_options.md, CPU seconds of set-up + solve): these defaults 45
#:   iterations, 9.8 s; unsmoothed aggregation 68 iterations, 8.0 s (a 3.5 times cheaper
#:   set-up, more iterations); a threshold of 0.01 / 0.05: 44 / 31 iterations, 10.8 / 24 s;
#:   Chebyshev degree 3: 36 iterations, 10.4 s; no aggressive coarsening of the first level:
#:   32 iterations, 45 s (set-up 7 times longer); coarse_eq_limit 100: 10.1 s.
#: * Chebyshev (degree 2) with Jacobi on every level; at most 1000 equations on the coarsest
#:   level, factorized on one rank.
ITERATIVE_OPTIONS: dict[str, object] = {
    "ksp_type": "cg",
    "ksp_norm_type": "unpreconditioned",
    "ksp_rtol": 1e-11,
    "ksp_atol": 0.0,
    "ksp_max_it": 1000,
    "pc_type": "gamg",
    "pc_gamg_agg_nsmooths": 1,
    "pc_gamg_threshold": 0.0,
    "pc_gamg_coarse_eq_limit": 1000,
    "mg_levels_ksp_type": "chebyshev",
    "mg_levels_pc_type": "jacobi",
    "pc_factor_mat_solver_type": None,  # the direct default, removed
}


#: Largest relative tolerance of a Krylov solve of the Newton direction (the first iteration,
#: and any iteration far from the solution, i.e. more than three decades above the Newton's
#: tolerance): an inexact Newton (Eisenstat and Walker 1996, choice 2) solves the direction
#: only as accurately as the nonlinear residual's next decrease can use; the scene's
#: ``ksp_rtol`` (default 1e-11) is the tightest it asks for. Not looser:
#: with 1e-2 the inexact first direction of the sheared penny (35k unknowns, frictionless, every
#: point in contact) moved contact points near the rim across their switch, and Newton took 6
#: iterations instead of 2 (1 with an exact solve); 1e-4 takes 2 with 38 GMRES iterations
#: against 1 with 74.
FORCING_MAX = 1e-4
#: ``η_k = γ (‖F_k‖ / ‖F_{k-1}‖)²``: the tolerance follows the observed convergence rate.
FORCING_GAMMA = 0.9
#: A direction is never solved beyond ``FORCING_MARGIN`` times what the Newton tolerance needs:
#: at a root of the affine piece the next residual is the linear one, ``η_k ‖F_k‖``. This
#: bound also loosens the solve beyond :data:`FORCING_MAX` near the target: in the 3D fault
#: scene's quiet steps the second Newton iteration of a ``g`` only has to take ``‖F‖`` from
#: ~1e3 to below ~1e2, and was made to gain four decades (P1 on the ``local2`` mesh, 1 rank:
#: 2,022 GMRES iterations against 2,422 and 92 s against 100 s, the same 157 Newton
#: iterations).
FORCING_MARGIN = 0.1
#: Largest relative tolerance of a direction taken right after a step that switched the state of
#: more than :data:`SWITCHED_FRACTION` of the contact points: the switches have just shown that
#: the linear model of the active set does not hold over a Newton step, so the direction is
#: solved only as far as ``γ (‖F_k‖/‖F_{k-1}‖)²`` asks, up to this bound, instead of
#: :data:`FORCING_MAX`. Such steps are the damped ones of a shear step, where the search takes
#: ``α`` of 0.1–0.5 of a direction solved to 1e-4. Eleven-fracture network, ``nitsche`` P2: at
#: 1.02M unknowns (2 ranks, 5 steps) 1,199 s against 1,516 s, 1,635 GMRES iterations against
#: 2,169, Newton 10/16/11/14/22 against 10/16/11/11/23; on the level-2 mesh (257k, 2 steps)
#: 442 against 597 and 170 s against 211 s, the same Newton 10/15. A bound of 0.1 took as long
#: at 1.02M (1,197 s, 1,544 GMRES iterations) with more Newton iterations (11/16/13/16/22),
#: although it was faster on the smaller meshes (level 2: 380 GMRES iterations, 151 s).
FORCING_SWITCHED = 1e-2
#: Fraction of the contact points (or faces) whose switch at the last step loosens the next
#: direction to :data:`FORCING_SWITCHED`. Near the solution a step switches a handful of points
#: and the direction keeps :data:`FORCING_MAX`: loosened after any switch, the level-4 network
#: (4,920 contact points) took 6/13/6/9/11 Newton iterations instead of 6/12/6/9/10 (a last
#: iteration more in two steps; 477 GMRES iterations); after a switch of more than 0.1 % or
#: 0.2 % of its points 6/12/6/9/10 (487 and 495 GMRES iterations; 702 with :data:`FORCING_MAX`
#: throughout). 0.2 %: the points of a switching front grow slower than all the points.
SWITCHED_FRACTION = 2e-3


#: A lagged preconditioner (:class:`IterativeSolver`) is kept while the Krylov method converges
#: within ``LAG_FACTOR`` times the iterations per decade of the solve that followed its set-up
#: (plus :data:`LAG_EXTRA`): beyond, a new set-up costs less than the extra iterations.
LAG_FACTOR = 1.5
LAG_EXTRA = 5


#: The level smoother of GAMG on a contact Jacobian (GMRES) whose options name none
#: (``mg_levels_pc_type``) is chosen at set-ups of the preconditioner (:data:`TRIAL_BACKOFF`
#: says at which): the system is solved
#: with the current smoother (SOR at first), then with the other one within the iterations at
#: which its solve costs less than 1/:data:`SWITCH_GAIN` of the current one's, and the other
#: is kept if it converges there. ``JACOBI_COST`` is the cost of a GMRES iteration with Jacobi
#: (Chebyshev(2) on each level) relative to one with SOR (symmetric local sweeps): 0.059 s
#: against 0.139 s on the 3D fault scene's uniform fine P2 mesh (245k unknowns, 2 ranks),
#: 0.026 s against 0.069 s on the level-4 mesh of the eleven-fracture network (P2, 1 rank).
JACOBI_COST = 0.4
#: How much cheaper the other smoother's solve must be for a switch (see :data:`JACOBI_COST`):
#: Jacobi replaces SOR below 1.56 times SOR's iterations, SOR replaces Jacobi below 1/4 of
#: Jacobi's. A switch also changes the hierarchy the later Jacobians lag on, which one solve
#: does not measure: on the fault scene's ``local2`` mesh (P2, 2 ranks) Jacobi won the first,
#: stuck Jacobian (53 against 28 iterations, within twice), lost the slipping ones, and the
#: run took 726 s against 718 s with SOR alone; on ``local4`` 324 s against 296 s. Which wins
#: depends on the system: on the fault scene's uniform fine mesh Jacobi (45 against 70; the
#: run 506 s against 1,399 s with SOR alone), on the network SOR (707 GMRES iterations against
#: 3,417 with Jacobi throughout; docs/mechanics3d.md, "Contact Jacobians").
SWITCH_GAIN = 1.6
#: A trial that keeps the smoother makes the next ones rarer: after the k-th such trial in a
#: row, the next ``TRIAL_BACKOFF**k - 1`` set-ups keep the smoother without a trial (a switch,
#: or a failed solve, makes the next set-up try again). Which smoother wins is a property of the
#: system's class more than of one Jacobian, and a lost trial costs its solve (up to 0.625 of the
#: kept smoother's) and two set-ups. Tried at every set-up, the lost trials took the 1.02M-
#: unknown network to 1,936 s and 9 set-ups (2,818 GMRES iterations); with this rule 1,516 s
#: and 4 (2,169), the same Newton iterations (docs/mechanics3d.md, "A million unknowns").
#: The trials of a run grow with the logarithm of its set-ups.
TRIAL_BACKOFF = 4
#: The level smoothers chosen between, the first one first.
SMOOTHERS = ("sor", "jacobi")
#: A p-multigrid solve (:mod:`poromech.mechanics.multigrid`) that has not converged in
#: ``FALLBACK_IT`` GMRES iterations with point-block Jacobi on P2 is repeated with the next
#: smoother of ``FALLBACK_SMOOTHERS`` (the P2 level's KSP and PC types), kept for the rest of
#: the run, and so on down the list; the last one solves with the options' iteration limit.
#: Point-block Jacobi took 10-60 iterations per solve wherever it converged, and stalled on the
#: 3D fault scene's coarse uniform P2 mesh (1,000 iterations from 9e7 to 4e6 at its first step,
#: exact coarse solve or not), where Chebyshev with SOR converges on 1 rank (12 iterations). On
#: 2 ranks (SOR local to each rank) Chebyshev with SOR stalled too (1,000 iterations from 1.1e9
#: to 6.6e7, with an exact coarse solve or 30 eigenvalue-estimate steps as well), where plain
#: SOR sweeps (Richardson), which need no spectrum estimate, converge in 17 and 9 iterations.
FALLBACK_IT = 200
FALLBACK_SMOOTHERS = (("chebyshev", "sor"), ("richardson", "sor"))


def _other_smoother(smoother: str) -> str:
    """The level smoother of :data:`SMOOTHERS` that is not ``smoother``."""
    return next(s for s in SMOOTHERS if s != smoother)


def _set_tolerances(ksp: PETSc.KSP, rtol: float | None = None, max_it: int | None = None) -> None:
    """Change the relative tolerance and/or the iteration limit of ``ksp``, keep the others."""
    rt, atol, dtol, it = ksp.getTolerances()
    ksp.setTolerances(rtol=rt if rtol is None else rtol, atol=atol, divtol=dtol,
                      max_it=it if max_it is None else max_it)


def _decades(rtol: float) -> float:
    """Decades of residual reduction a relative tolerance asks for (at least 1)."""
    return max(1.0, -np.log10(max(rtol, 1e-300)))


def forcing_term(fnorm: float, previous: float | None, target: float, floor: float,
                 switched: bool = False) -> float:
    """Relative tolerance of the Krylov solve of a Newton direction (inexact Newton).

    Args:
        fnorm: ``‖F_k‖`` at the current iterate.
        previous: ``‖F_{k-1}‖`` (None at the first iteration).
        target: The absolute residual the Newton must reach (``snes_rtol`` times its base).
        floor: The tightest tolerance (the scene's ``ksp_rtol``).
        switched: The last step switched more than :data:`SWITCHED_FRACTION` of the contact
            points: the bound is :data:`FORCING_SWITCHED` instead of :data:`FORCING_MAX`.

    Returns:
        ``η_k = max(min(FORCING_MAX, γ (‖F_k‖/‖F_{k-1}‖)²), FORCING_MARGIN target/‖F_k‖)``
        (``FORCING_SWITCHED`` in the place of ``FORCING_MAX`` after a switching step), at
        least ``floor``. The margin term exceeds :data:`FORCING_MAX` within three decades
        of the target (at most ``FORCING_MARGIN``): the last direction is solved only as far as
        the tolerance needs. An iteration below the target (a Newton made to take a step)
        keeps at most :data:`FORCING_MAX`.
    """
    bound = FORCING_SWITCHED if switched else FORCING_MAX
    eta = FORCING_MAX if not previous else min(bound, FORCING_GAMMA * (fnorm / previous) ** 2)
    if fnorm > target:
        eta = max(eta, FORCING_MARGIN * target / fnorm)
    return float(max(eta, floor))


#: The coarse (P1) solve of the p-multigrid (:mod:`poromech.mechanics.multigrid`), options
#: under ``mg_coarse_``: one V-cycle of GAMG as in :data:`ITERATIVE_OPTIONS`, SOR on its levels
#: (Jacobi there took 942 GMRES iterations and 123 s against 529 and 86 s on the 257k-unknown
#: network, the first two load steps, both with point Jacobi on P2).
P_MULTIGRID_OPTIONS: dict[str, object] = {
    "pc_type": "mg",
    "mg_coarse_ksp_type": "preonly",
    "mg_coarse_pc_type": "gamg",
    "mg_coarse_pc_gamg_agg_nsmooths": 1,
    "mg_coarse_pc_gamg_threshold": 0.0,
    "mg_coarse_pc_gamg_coarse_eq_limit": 1000,
    "mg_coarse_mg_levels_ksp_type": "chebyshev",
    "mg_coarse_mg_levels_pc_type": "sor",
}


def iterative_options(symmetric: bool, p_multigrid: bool = False) -> dict[str, object]:
    """PETSc defaults of the iterative solve: CG, or GMRES for a non-symmetric Jacobian.

    Args:
        symmetric: The Jacobian is symmetric (open fractures); the semi-smooth Jacobian of
            Nitsche contact in general is not (``θ ≠ 1``, friction).
        p_multigrid: Precondition a non-symmetric (contact) Jacobian of P2 displacements by
            the p-multigrid (:data:`P_MULTIGRID_OPTIONS`) instead of GAMG on P2.
    """
    if symmetric:
        return dict(ITERATIVE_OPTIONS)
    # right preconditioning: GMRES then measures the unpreconditioned residual, as CG does;
    # no level smoother: IterativeSolver chooses SOR or Jacobi at each set-up (SWITCH_GAIN),
    # unless the scene or the command line names one; the p-multigrid's fine level has its own
    # default (multigrid.FINE_SMOOTHER)
    gmres = {**ITERATIVE_OPTIONS, "ksp_type": "gmres", "ksp_pc_side": "right",
             "ksp_gmres_restart": 200, "mg_levels_pc_type": None}
    return {**gmres, **P_MULTIGRID_OPTIONS} if p_multigrid else gmres


def rigid_body_modes(V: fem.FunctionSpace) -> npt.NDArray[np.float64]:
    """Rigid-body displacements at the owned dofs of ``V``, orthonormal (collective).

    The translations ``e_i`` and rotations ``e_k × (x - x̄)`` (3 modes in 2D, 6 in 3D), at the
    coordinates of the owned dof nodes of the (cracked) vector space, in its blocked layout
    ``x₀, y₀, (z₀,) x₁, ...``: the layout of the owned rows of a one-block Jacobian. On a cracked
    space the copies of a node on either side of a fracture get the same values: these modes are
    the kernel of the elastic operator without Dirichlet conditions. The coordinates are centred
    on their mean (rotations about the body, not about a far origin) and the modes
    orthonormalized (Cholesky QR, twice), so that their conditioning does not depend on where
    the domain lies.

    Returns:
        ``(k, n)``: ``k`` modes, ``n`` owned dofs (owned nodes times ``d``).
    """
    comm = V.mesh.comm
    d = V.dofmap.index_map_bs
    n = V.dofmap.index_map.size_local
    x = V.tabulate_dof_coordinates()[:n, :d]
    count = comm.allreduce(n)
    x = x - comm.allreduce(x.sum(axis=0)) / max(count, 1)
    rotations = ((0, 1),) if d == 2 else ((1, 2), (2, 0), (0, 1))
    modes = np.zeros((d + len(rotations), n, d))
    for k in range(d):
        modes[k, :, k] = 1.0
    for m, (i, j) in enumerate(rotations):  # rotation about the axis normal to (e_i, e_j)
        modes[d + m, :, i] = -x[:, j]
        modes[d + m, :, j] = x[:, i]
    modes = modes.reshape(len(modes), n * d)
    for _ in range(2):
        gram = comm.allreduce(modes @ modes.T)
        modes = np.linalg.solve(np.linalg.cholesky(gram), modes)
    return modes


def near_nullspace(A: PETSc.Mat, modes: npt.NDArray[np.float64]) -> PETSc.NullSpace:
    """Attach ``modes`` (one per row, owned rows of ``A``) as the near-nullspace of ``A``.

    Sets the block size of ``A`` to the number of translations (the dofs per node), which
    GAMG reads to aggregate nodes rather than single dofs. Collective.

    Returns:
        The null space object (owned by the caller, who destroys it).
    """
    k = modes.shape[0]
    bs = 2 if k == 3 else 3
    if A.getLocalSize()[0] != modes.shape[1]:
        raise ValueError(f"{modes.shape[1]} owned dofs in the modes, {A.getLocalSize()[0]} rows "
                         "of the matrix: rigid-body modes need a displacement-only Jacobian")
    A.setBlockSize(bs)
    vectors = []
    for mode in modes:
        v = A.createVecLeft()
        v.setBlockSize(bs)
        v.getArray()[:] = mode
        vectors.append(v)
    space = PETSc.NullSpace().create(vectors=vectors, comm=A.getComm())
    A.setNearNullSpace(space)
    for v in vectors:
        v.destroy()
    return space


def is_direct(ksp: PETSc.KSP) -> bool:
    """Whether the KSP applies a factorization (preonly + LU/Cholesky)."""
    return ksp.getType() == PETSc.KSP.Type.PREONLY and ksp.getPC().getType() in ("lu", "cholesky")


#: Residuals of a failed Krylov solve quoted in its message (evenly spread over its history).
HISTORY_QUOTED = 8


def _history(ksp: PETSc.KSP, b: float) -> str:
    """The Krylov residual history relative to ``b``, a few iterations of it (empty if none)."""
    h = np.asarray(ksp.getConvergenceHistory(), dtype=float)
    if len(h) == 0 or b <= 0:
        return ""
    quoted = np.unique(np.linspace(0, len(h) - 1, min(len(h), HISTORY_QUOTED)).round())
    return "; relative residual at iteration " + ", ".join(
        f"{int(i)}: {h[int(i)] / b:.1e}" for i in quoted)


def failure_message(ksp: PETSc.KSP, F: PETSc.Vec) -> str:
    """Why a linear solve of ``J Y = F`` failed: KSP and PC, reason, iterations, residual.

    For a Krylov solve (zero initial guess) also the residual history, relative to ``‖F‖``, at
    :data:`HISTORY_QUOTED` iterations. Collective (a norm).
    """
    b = F.norm()
    its = ksp.getIterationNumber()
    text = (f"the linear solve ({ksp.getType()} + {ksp.getPC().getType()}) did not converge: "
            f"{ksp_reason_name(ksp.getConvergedReason())} after {its} iterations")
    if ksp.getType() != PETSc.KSP.Type.PREONLY and b > 0:
        text += (f", residual {ksp.getResidualNorm() / b:.2e} of the initial (ksp_rtol "
                 f"{ksp.getTolerances()[0]:.0e}, ksp_max_it {ksp.getTolerances()[3]})")
        text += _history(ksp, b)
        text += "; solver.linear_solver: direct solves it with MUMPS, memory permitting"
    return text


class LinearStrategy(Protocol):
    """How the Newton direction is solved, and what is kept between solves (collective)."""

    #: Number of near-nullspace vectors attached to the matrix (0: none).
    near_nullspace_size: int

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
        priced: Try it after any change, within a budget priced at each factorization
            (:meth:`price`) instead of :data:`STALE_BUDGET`, with no smallest size (3D: the
            friction Jacobian changes with the slip directions while no state changes, and a
            factorization costs tens of stale iterations already at 50k unknowns).
        owns_ksp: :meth:`destroy` frees ``ksp`` too (a KSP created for this solver, not the
            Newton's).

    Attributes:
        stale_min_unknowns: Smallest system on which stale GMRES is tried
            (:data:`STALE_MIN_UNKNOWNS`).
        stale_budget: Stale GMRES iterations allowed between two factorizations
            (:data:`STALE_BUDGET`).
    """

    def __init__(self, ksp: PETSc.KSP, A: PETSc.Mat, prefix: str, *, reuse: bool, stale: bool,
                 priced: bool = False, owns_ksp: bool = False):
        self.ksp, self.A, self.comm = ksp, A, A.getComm().tompi4py()
        self.owns_ksp = owns_ksp
        self.reuse = reuse
        self.priced = priced
        self.stale_min_unknowns = STALE_MIN_UNKNOWNS
        self.stale_budget = STALE_BUDGET
        self.near_nullspace_size = 0
        self._values = None  # Jacobian values at the last factorization
        self._assembled = True  # the matrix was assembled since the last factorization
        self._jacobian_states = None  # contact states of the assembled Jacobian
        self._factor_states = None  # contact states of the factorized Jacobian
        self._stale_spent = 0  # stale GMRES iterations since the last factorization
        self._stale_misses = 0  # priced: failed stale attempts in a row
        self._stale_skip = 0  # priced: stale opportunities still to skip after a miss
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
        if self.priced and self._stale_ksp is not None:
            self.stale_budget = self.price()

    def price(self) -> int:
        """Stale GMRES iterations worth the factorization just computed (collective).

        Its flops (MUMPS' RINFOG(3)) over an iteration's (4 per factor entry, INFOG(29), for
        the two substitutions and 2 per nonzero of the Jacobian), divided by
        :data:`SOLVE_SLOWDOWN`. From counts, not timings, so a run repeats its choices.
        :data:`STALE_BUDGET` for another factorization package.
        """
        pc = self.ksp.getPC()
        if pc.getFactorSolverType() != "mumps":
            return STALE_BUDGET
        F = pc.getFactorMatrix()
        entries = F.getMumpsInfog(29)
        entries = float(entries) if entries >= 0 else -1e6 * entries  # < 0: millions
        nnz = self.A.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"]
        work = SOLVE_SLOWDOWN * (4.0 * entries + 2.0 * nnz)
        return int(F.getMumpsRinfog(3) / work) if work > 0 else STALE_BUDGET

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
                and (self.priced or self.A.getSize()[0] >= self.stale_min_unknowns)
                and self._stale_spent < self.stale_budget):
            if self.priced:  # whatever the states did: the budget bounds the loss
                few = self._stale_skip == 0
                self._stale_skip = max(0, self._stale_skip - 1)
            else:
                changes = self.changes_since_factorization(states)
                few = changes is not None and changes <= STALE_MAX_CHANGES
        if few:
            ksp.getPC().setReusePreconditioner(True)  # keep the old factors when applied
            stale = self._stale_ksp
            available = self.stale_budget - self._stale_spent
            if self.priced:  # the rest of the budget, at most: rent or buy
                stale.setTolerances(max_it=available)
            stale.solve(F, Y)
            self._stale_spent += stale.getIterationNumber()
            record.linear_iterations += stale.getIterationNumber()
            if stale.getConvergedReason() > 0:
                record.stale_solves += 1
                self._stale_misses = 0
                return True
            if available >= min(STALE_MAX_IT, self.stale_budget):  # not just the budget's end
                self._stale_misses += 1
                self._stale_skip = STALE_BACKOFF**self._stale_misses - 1
        ksp.setOperators(self.A, self.A)
        ksp.getPC().setReusePreconditioner(False)
        t0 = time.perf_counter()
        ksp.setUp()  # the factorization (the solve would do it): timed on its own
        record.time_preconditioner += time.perf_counter() - t0
        ksp.solve(F, Y)
        record.factorizations += 1
        self._factorized()
        if ksp.getConvergedReason() > 0:
            return True
        record.linear_failure = failure_message(ksp, F)
        return False

    def forget(self) -> None:
        """The factorization is no longer trusted (a failed solve): refactorize next time."""
        self._values = None

    def destroy(self) -> None:
        """Free the stale GMRES (and the KSP, when it owns it)."""
        if self._stale_ksp is not None:
            self._stale_ksp.destroy()
        if self.owns_ksp:
            self.ksp.destroy()


class IterativeSolver:
    """A Krylov solve whose preconditioner is set up again only when the Jacobian changed.

    The KSP, its preconditioner and tolerances come from the Newton's PETSc options (e.g.
    ``mech_ksp_type cg``, ``mech_pc_type gamg``, :data:`ITERATIVE_OPTIONS`). A Jacobian
    assembled since the last set-up is compared with the one the preconditioner was built from
    by a fingerprint, ``A z`` for a fixed random ``z`` (one product; bitwise equal for an equal
    matrix): a linear problem, or a contact problem in an unchanged active set, then keeps its
    AMG hierarchy from one Newton iteration and one time step to the next. A false match (a
    change invisible in ``A z``) would only leave the preconditioner stale; the Krylov method
    always solves with the current matrix. Counts its set-ups as ``factorizations``.

    Args:
        ksp: The Newton's KSP.
        A: The Jacobian matrix.
        modes: Rigid-body modes of a displacement-only Jacobian (:func:`rigid_body_modes`),
            attached as its near-nullspace; None: none.
        reuse: Keep the preconditioner for an assembled Jacobian equal to the set-up one
            (``solver.reuse_jacobian``); False: set it up for every assembled Jacobian.
        choose_smoother: Choose GAMG's level smoother between :data:`SMOOTHERS` at the
            set-ups (:data:`SWITCH_GAIN`, fewer after trials that kept it:
            :data:`TRIAL_BACKOFF`), and switch to the other one when a solve after a set-up
            fails; False: the options' smoother.
        multigrid: The p-multigrid configured on the KSP
            (:class:`~poromech.mechanics.multigrid.PMultigrid`): its coarse operator is formed
            at each set-up, and a changed Jacobian always gets a new set-up (never
            :attr:`lagged`: a set-up costs three or four GMRES iterations).
    """

    def __init__(self, ksp: PETSc.KSP, A: PETSc.Mat,
                 modes: npt.NDArray[np.float64] | None = None, reuse: bool = True,
                 choose_smoother: bool = False, multigrid: PMultigrid | None = None):
        self.ksp, self.A, self.comm = ksp, A, A.getComm().tompi4py()
        self.reuse = reuse
        self.multigrid = multigrid
        choose_smoother = choose_smoother and ksp.getPC().getType() == PETSc.PC.Type.GAMG
        #: GAMG's level smoother held at each set-up (None: the options'); see :meth:`solve`.
        self.smoother: str | None = SMOOTHERS[0] if choose_smoother else None
        self._chosen = 0  # choices made (the first is logged)
        self._kept = 0  # trials in a row that kept the smoother (TRIAL_BACKOFF)
        self._untried = 0  # set-ups left that keep the smoother without a trial
        self._restored_p2: tuple[str, str] | None = None  # a restart's P2 smoother, to be set
        self.nullspace = None if modes is None else near_nullspace(A, modes)
        self.near_nullspace_size = 0 if modes is None else len(modes)
        self._fresh = True  # a Jacobian was assembled since the last set-up
        self._probe = A.createVecRight()
        rng = np.random.default_rng(self.comm.rank)
        self._probe.getArray()[:] = rng.random(self._probe.getLocalSize())
        self._fingerprint = None  # A z of the Jacobian of the last set-up
        self._rtol = ksp.getTolerances()[0]
        self._lagged = False
        self._rate = None  # Krylov iterations per decade of the solve after the last set-up
        # residual norms of each solve (reset per solve), quoted when one fails
        ksp.setConvergenceHistory(length=ksp.getTolerances()[3] + 1, reset=True)

    def assembled(self, states: npt.NDArray | None) -> None:
        """A new Jacobian is in the matrix: compared with the set-up one at the next solve."""
        self._fresh = True

    @property
    def lagged(self) -> bool:
        """Solve a changed Jacobian with the last preconditioner first (see :meth:`solve`).

        Never with the p-multigrid, whose set-up is cheap: on the 257k-unknown network (first
        two load steps) lagging it took 124 s against 86 s.
        """
        return self._lagged

    @lagged.setter
    def lagged(self, value: bool) -> None:
        self._lagged = value and self.multigrid is None

    @property
    def tightest(self) -> float:
        """The relative tolerance of the options (``ksp_rtol``): the tightest solve."""
        return self._rtol

    def set_tolerance(self, rtol: float) -> None:
        """Relative tolerance of the next solve (:func:`forcing_term`)."""
        _set_tolerances(self.ksp, rtol=rtol)

    def _unchanged(self) -> bool:
        """Whether the fingerprint of the matrix equals that of the last set-up (collective)."""
        y = self.A.createVecLeft()
        self.A.mult(self._probe, y)
        same = self._fingerprint is not None and np.array_equal(y.getArray(),
                                                                self._fingerprint.getArray())
        same = self.comm.allreduce(bool(same), op=MPI.LAND)
        if same:
            y.destroy()
        else:
            if self._fingerprint is not None:
                self._fingerprint.destroy()
            self._fingerprint = y
        return same

    def solve(self, F: PETSc.Vec, Y: PETSc.Vec, record, states: npt.NDArray | None) -> bool:
        """``J Y = F`` by the Krylov method, from a zero guess.

        A changed Jacobian is first solved with the preconditioner of an earlier one (when
        :attr:`lagged`), within :data:`LAG_FACTOR` times the iterations per decade of the
        solve that followed its set-up; if that does not converge, the preconditioner is set up
        for the current Jacobian and the solve starts again. On failure the record's
        ``linear_failure`` says why (KSP reason, iterations, residual).
        """
        ksp, pc = self.ksp, self.ksp.getPC()
        changed = self._fresh and not (self.reuse and self._unchanged())
        self._fresh = False
        if changed and self.lagged and self._rate is not None:
            ksp.setOperators(self.A, self.A)
            pc.setReusePreconditioner(True)
            cap = int(np.ceil(LAG_FACTOR * self._rate * _decades(ksp.getTolerances()[0])))
            if self._counted_solve(F, Y, record, cap + LAG_EXTRA)[1]:
                record.stale_solves += 1
                return True
        if changed:
            self._set_up(record)
        else:
            pc.setReusePreconditioner(True)
        if self._fallback_open():
            its, converged = self._solve_or_fall_back(F, Y, record)
        else:
            its, converged = self._counted_solve(F, Y, record)
        if changed and self.smoother is not None:  # chosen at set-ups (SWITCH_GAIN)
            if converged and self._untried > 0:
                self._untried -= 1
            elif converged:
                its = self._choose(F, Y, its, record)  # the kept smoother's solve converged
            else:
                its, converged = self._switch(F, Y, record)
        if converged:
            if changed:
                self._rate = max(its, 1) / _decades(ksp.getTolerances()[0])
            return True
        record.linear_failure = failure_message(ksp, F)
        return False

    def prime(self, record) -> None:
        """Set the preconditioner up on the current matrix without solving (collective).

        GAMG aggregates the unknowns and builds its prolongators at its first set-up only, and
        keeps them for the later Jacobians (PETSc reuses the interpolation of a matrix of the
        same pattern: a set-up then forms the Galerkin products; only a change of GAMG's level
        smoother builds them again): the coarse spaces of a run come from its first Jacobian.
        A restart primes the solver with the Jacobian of the run's initial unknowns, so that it
        coarsens the matrix the run it continues coarsened; the next solve compares its
        Jacobian with this one and sets up, lags or reuses as usual.
        """
        self._unchanged()  # the fingerprint of this Jacobian
        self._set_up(record)
        self._fresh = True

    def _counted_solve(self, F: PETSc.Vec, Y: PETSc.Vec, record,
                       max_it: int | None = None) -> tuple[int, bool]:
        """One Krylov solve, within ``max_it`` iterations if given (at most the options').

        Returns:
            Its iterations (added to the record's), and whether it converged.
        """
        ksp = self.ksp
        limit = ksp.getTolerances()[3]
        if max_it is not None:
            _set_tolerances(ksp, max_it=min(max_it, limit))
        ksp.solve(F, Y)
        if max_it is not None:
            _set_tolerances(ksp, max_it=limit)
        its = ksp.getIterationNumber()
        record.linear_iterations += its
        return its, ksp.getConvergedReason() > 0

    def choices(self) -> dict[str, float]:
        """What the run has chosen for this solver so far, for a restart to go on with.

        ``p2_smoother``: the index in :data:`FALLBACK_SMOOTHERS` of the p-multigrid's P2
        smoother after a fallback; ``level_smoother``, ``trials_kept``, ``untried``: GAMG's
        chosen level smoother (index in :data:`SMOOTHERS`) and its trial back-off
        (:data:`TRIAL_BACKOFF`); ``lag_rate``: the iterations per decade after the last set-up
        of a :attr:`lagged` preconditioner. Empty when nothing was chosen (see
        :meth:`restore_choices`).
        """
        out: dict[str, float] = {}
        if self.multigrid is not None and self.multigrid.level_smoother in FALLBACK_SMOOTHERS:
            out["p2_smoother"] = FALLBACK_SMOOTHERS.index(self.multigrid.level_smoother)
        if self.smoother is not None:
            out.update(level_smoother=SMOOTHERS.index(self.smoother), trials_kept=self._kept,
                       untried=self._untried)
        if self.lagged and self._rate is not None:
            out["lag_rate"] = self._rate
        return out

    def restore_choices(self, choices: dict[str, float]) -> None:
        """Go on with the :meth:`choices` of an earlier run (a restart), before the first solve.

        A run that fell back to another P2 smoother, or chose GAMG's level smoother, keeps it
        for the rest of the run; continued, it would otherwise start again from the first ones
        (and repeat the failed solves of a fallback). A lagged preconditioner's rate lets the
        first solve after the restart lag on the preconditioner of :meth:`prime`, as the run
        continued would have lagged on its last one.
        """
        if "lag_rate" in choices:
            self._rate = float(choices["lag_rate"])
        if "p2_smoother" in choices and self.multigrid is not None:
            self._restored_p2 = FALLBACK_SMOOTHERS[int(choices["p2_smoother"])]
            if self.comm.rank == 0:
                log.info("p-multigrid P2 smoother: %s, the fallback of the run continued",
                         smoother_name(*self._restored_p2))
        if "level_smoother" in choices and self.smoother is not None:
            self.smoother = SMOOTHERS[int(choices["level_smoother"])]
            self._kept = int(choices.get("trials_kept", 0))
            self._untried = int(choices.get("untried", 0))

    def _fallbacks(self) -> tuple[tuple[str, str], ...]:
        """The P2 smoothers (KSP, PC) a failed p-multigrid solve would still fall back to."""
        if self.multigrid is None:
            return ()
        current = self.multigrid.level_smoother
        if current in FALLBACK_SMOOTHERS:
            return FALLBACK_SMOOTHERS[FALLBACK_SMOOTHERS.index(current) + 1:]
        return FALLBACK_SMOOTHERS

    def _fallback_open(self) -> bool:
        """Whether a failed solve would still switch the p-multigrid's P2 smoother."""
        return bool(self._fallbacks())

    def _solve_or_fall_back(self, F: PETSc.Vec, Y: PETSc.Vec, record) -> tuple[int, bool]:
        """A p-multigrid solve within :data:`FALLBACK_IT` iterations, else the next smoother's.

        Down :data:`FALLBACK_SMOOTHERS` (collective): each smoother that does not converge there
        (or breaks down) is replaced by the next one for the rest of the run, and the solve
        repeated; the last one solves with the options' iteration limit.

        Returns:
            The iterations of the last solve, and whether it converged.
        """
        its, converged = self._counted_solve(F, Y, record, FALLBACK_IT)
        fallbacks = self._fallbacks()
        for k, (ksp_type, pc_type) in enumerate(fallbacks):
            if converged:
                break
            failed = self.multigrid.smoother
            self.multigrid.set_smoother(pc_type, ksp_type)
            if self.comm.rank == 0:
                log.info("p-multigrid P2 smoother: %s (%s did not converge in %d GMRES "
                         "iterations: %s)", self.multigrid.smoother, failed, its,
                         ksp_reason_name(self.ksp.getConvergedReason()))
            self._set_up(record, rebuild=True)
            last = k == len(fallbacks) - 1
            its, converged = self._counted_solve(F, Y, record, None if last else FALLBACK_IT)
        return its, converged

    def _set_up(self, record, rebuild: bool = False) -> None:
        """Set the preconditioner up for the current matrix, with :attr:`smoother`.

        Args:
            record: The Newton's record (set-up count and time).
            rebuild: Build the preconditioner anew (a new level smoother for the same matrix:
                GAMG's choice, or the p-multigrid's fallback).
        """
        ksp, pc = self.ksp, self.ksp.getPC()
        t0 = time.perf_counter()
        # the levels read their smoother at every set-up; when it is chosen here, no option
        # names it (linear_strategy), so it is pushed for the set-up and removed after
        with PrefixedOptions(ksp.getOptionsPrefix() or "", {"mg_levels_pc_type": self.smoother}):
            operator = self.A
            if self.multigrid is not None:
                operator = self.multigrid.set_up(self.A)
                if rebuild:  # the same matrix, another smoother: PETSc keeps the levels' set-up
                    operator.stateIncrease()  # of an unchanged matrix otherwise
            elif rebuild:  # GAMG keeps its smoothers and their eigenvalue estimates otherwise
                pc.setType(PETSc.PC.Type.NONE)
                pc.setType(PETSc.PC.Type.GAMG)
                pc.setFromOptions()
            ksp.setOperators(operator, operator)
            pc.setReusePreconditioner(False)
            ksp.setUp()
        record.time_preconditioner += time.perf_counter() - t0
        record.factorizations += 1
        if self._restored_p2 is not None:
            # the first set-up gives the P2 level the options' smoother: the restored one is
            # put in its place with a second set-up (once per restart)
            ksp_type, pc_type = self._restored_p2
            self._restored_p2 = None
            self.multigrid.set_smoother(pc_type, ksp_type)
            self._set_up(record, rebuild=True)

    def _choose(self, F: PETSc.Vec, Y: PETSc.Vec, its: int, record) -> int:
        """Choose the level smoother on the system just solved after a set-up (collective).

        The system, solved in ``its`` iterations with :attr:`smoother`, is solved again with the
        other one of :data:`SMOOTHERS` within the iterations at which it costs less than
        1/:data:`SWITCH_GAIN` of the first solve; the other one is kept if it converges there.
        A lost trial builds the current smoother's preconditioner again. Building the trial's
        beside it instead (and putting the current one back) saved no measurable time on the
        1.02M-unknown network (1,532 s against 1,516 s) and held both hierarchies at once
        (peak 9.2 GB against 7.5).

        Returns:
            The iterations of the kept smoother's solve (its direction is in ``Y``).
        """
        current = self.smoother
        other = _other_smoother(current)
        cost = {"sor": 1.0, "jacobi": JACOBI_COST}
        cap = int(its * cost[current] / (cost[other] * SWITCH_GAIN))
        if cap < 1:
            return its
        kept = Y.copy()
        self.smoother = other
        self._set_up(record, rebuild=True)
        trial, won = self._counted_solve(F, Y, record, cap)
        self._chosen += 1
        if self.comm.rank == 0:
            (log.info if self._chosen == 1 or won else log.debug)(
                "GAMG level smoother: %s (a new preconditioner solved in %s GMRES iterations "
                "with %s, %d with %s; taken within %d)", other if won else current,
                trial if won else f"more than {trial}", other, its, current, cap)
        if won:
            self._kept = self._untried = 0
            kept.destroy()
            return trial
        self._kept += 1
        self._untried = TRIAL_BACKOFF**self._kept - 1
        kept.copy(Y)
        kept.destroy()
        self.smoother = current
        self._set_up(record, rebuild=True)
        return its

    def _switch(self, F: PETSc.Vec, Y: PETSc.Vec, record) -> tuple[int, bool]:
        """A solve after a set-up failed: the solve repeated with the other smoother.

        Returns:
            Its iterations, and whether it converged.
        """
        failed = self.smoother
        self.smoother = _other_smoother(failed)
        self._kept = self._untried = 0
        if self.comm.rank == 0:
            log.info("GAMG level smoother: %s (the solve with %s failed: %s)",
                     self.smoother, failed, ksp_reason_name(self.ksp.getConvergedReason()))
        self._set_up(record, rebuild=True)
        return self._counted_solve(F, Y, record)

    def forget(self) -> None:
        """Set the preconditioner up again at the next solve."""
        self._fresh = True
        if self._fingerprint is not None:
            self._fingerprint.destroy()
        self._fingerprint = None

    def destroy(self) -> None:
        """Free the fingerprint vectors, the near-nullspace and the p-multigrid's matrices."""
        for obj in (self._probe, self._fingerprint, self.nullspace, self.multigrid):
            if obj is not None:
                obj.destroy()


class FaceElimination:
    """A Krylov solve of the displacement Schur complement, the face unknowns eliminated exactly.

    For the facewise formulations whose face block is invertible (``mean_nitsche``: face
    averages; ``stabilized_mixed``: multipliers and averages), the Jacobian

    .. code-block:: text

        J = [A_uu  A_uf]      A_ff block diagonal: one small dense block per fracture face
            [A_fu  A_ff]      (its multiplier and average components)

    is solved through ``S = A_uu - A_uf A_ff⁻¹ A_fu``, a sparse displacement operator (the face
    blocks couple the dofs of the two cells of each face only): ``S Y_u = F_u - A_uf A_ff⁻¹ F_f``
    by the wrapped :class:`IterativeSolver` (GAMG with the rigid-body modes on ``S``), then
    ``Y_f = A_ff⁻¹ (F_f - A_fu Y_u)``. Exact: ``A_ff⁻¹`` is computed face by face (batched dense
    inverses of at most ``(2d + d)²`` entries), so the direction is that of the full system to
    the Krylov tolerance. The face unknowns of a face are owned by the rank that owns the face,
    so the inversion needs no communication. ``mixed`` cannot be eliminated this way: its
    multiplier rows have no ``λ`` derivative on faces in contact (its face block is singular).

    Args:
        ksp: The Newton's KSP (configured from its options: GMRES + GAMG), solving with ``S``.
        A: The Jacobian matrix (blocked: the owned rows of ``u``, then of each face unknown).
        sizes: Owned entries of each block in order (``u`` first).
        face_block_sizes: Components per face of each face unknown (e.g. ``(3, 6)``).
        modes: Rigid-body modes of the displacement space (:func:`rigid_body_modes`).
        reuse, choose_smoother, multigrid: See :class:`IterativeSolver` (the p-multigrid's
            interpolation is that of the displacements, the rows of ``S``).
    """

    def __init__(self, ksp: PETSc.KSP, A: PETSc.Mat, sizes: list[int],
                 face_block_sizes: list[int], modes: npt.NDArray[np.float64], reuse: bool = True,
                 choose_smoother: bool = False, multigrid: PMultigrid | None = None):
        self.A, self.comm = A, A.getComm().tompi4py()
        start = A.getOwnershipRange()[0]
        nu, nf = sizes[0], sum(sizes[1:])
        comm = A.getComm()
        self.is_u = PETSc.IS().createStride(nu, first=start, step=1, comm=comm)
        self.is_f = PETSc.IS().createStride(nf, first=start + nu, step=1, comm=comm)
        # the rows of each face in the local face numbering: [unknown 1 comps, unknown 2 ...]
        faces = sizes[1] // face_block_sizes[0]
        offsets = np.cumsum([0, *sizes[1:]])[:-1]
        self._rows = np.hstack([off + np.arange(faces)[:, None] * k + np.arange(k)
                                for off, k in zip(offsets, face_block_sizes, strict=True)])
        self._faces, self._block = faces, self._rows.shape[1]
        # local face row -> its face and its position in the face's block
        self._face_of = np.empty(nf, dtype=np.int64)
        self._pos_of = np.empty(nf, dtype=np.int64)
        self._face_of[self._rows] = np.arange(faces)[:, None]
        self._pos_of[self._rows] = np.arange(self._block)[None, :]
        self._sub = {}  # the four blocks of J, extracted again after each assembly
        self._inv = None  # A_ff⁻¹
        self._T = self._P = self.S = None  # A_ff⁻¹ A_fu, A_uf A_ff⁻¹ A_fu, S
        self._fresh = True
        self._vecs = None
        self._ksp, self._reuse, self._modes = ksp, reuse, modes
        self._choose_smoother = choose_smoother
        self.multigrid = multigrid
        self._rtol = ksp.getTolerances()[0]
        #: Passed to the :class:`IterativeSolver` of ``S``.
        self.lagged = False
        self.inner: IterativeSolver | None = None
        self._choices: dict[str, float] = {}  # a restart's, for the solver of S when built
        self.near_nullspace_size = len(modes)

    def _extract(self) -> None:
        """The blocks of the assembled Jacobian, ``A_ff⁻¹`` and ``S`` (collective)."""
        for name, (r, c) in {"uu": (self.is_u, self.is_u), "uf": (self.is_u, self.is_f),
                             "fu": (self.is_f, self.is_u), "ff": (self.is_f, self.is_f)}.items():
            self._sub[name] = self.A.createSubMatrix(r, c, submat=self._sub.get(name))
        self._invert_faces(self._sub["ff"])
        self._T = self._inv.matMult(self._sub["fu"], result=self._T)
        self._P = self._sub["uf"].matMult(self._T, result=self._P)
        if self.S is None:
            self.S = self._sub["uu"].duplicate(copy=True)
            self.S.axpy(-1.0, self._P, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
            self.inner = IterativeSolver(self._ksp, self.S, self._modes, reuse=self._reuse,
                                         choose_smoother=self._choose_smoother,
                                         multigrid=self.multigrid)
            self.inner.lagged = self.lagged
            if self._choices:
                self.inner.restore_choices(self._choices)
        else:
            self.S.zeroEntries()
            self.S.axpy(1.0, self._sub["uu"], structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
            self.S.axpy(-1.0, self._P, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)

    def _invert_faces(self, F: PETSc.Mat) -> None:
        """``A_ff⁻¹`` by batched dense inverses of the face blocks (local: no communication)."""
        indptr, cols, vals = F.getValuesCSR()
        start = F.getOwnershipRange()[0]  # the face block's own numbering
        n, b = self._faces, self._block
        face_of, pos_of = self._face_of, self._pos_of
        rows = np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
        local = cols - start
        if np.any((local < 0) | (local >= n * b)) or np.any(face_of[local] != face_of[rows]):
            raise RuntimeError("the face block of the Jacobian couples different faces")
        blocks = np.zeros((n, b, b))
        blocks[face_of[rows], pos_of[rows], pos_of[local]] = vals
        inv = np.linalg.inv(blocks)
        # local row r is face face_of[r] at position pos_of[r]: its entries are that row of the
        # face's inverse, in the columns of the face's rows
        r = np.arange(n * b)
        csr = (np.arange(0, n * b * b + 1, b, dtype=PETSc.IntType),
               (self._rows[face_of[r]] + start).ravel().astype(PETSc.IntType),
               inv[face_of[r], pos_of[r], :].ravel())
        if self._inv is None:
            self._inv = PETSc.Mat().createAIJ(size=((n * b, None), (n * b, None)), csr=csr,
                                              comm=self.A.getComm())
        else:
            self._inv.setValuesCSR(*csr)
        self._inv.assemble()

    def assembled(self, states: npt.NDArray | None) -> None:
        """A new Jacobian is in the matrix: its blocks and ``S`` are formed at the next solve."""
        self._fresh = True

    def choices(self) -> dict[str, float]:
        """The solver of ``S``'s :meth:`IterativeSolver.choices` (none before it is built)."""
        return {} if self.inner is None else self.inner.choices()

    def restore_choices(self, choices: dict[str, float]) -> None:
        """:meth:`IterativeSolver.restore_choices`, handed to the solver of ``S`` when built."""
        if self.inner is not None:
            self.inner.restore_choices(choices)
        else:
            self._choices = dict(choices)

    def prime(self, record) -> None:
        """:meth:`IterativeSolver.prime` on ``S`` of the assembled Jacobian (collective)."""
        self._extract()
        self.inner.prime(record)
        self._fresh = True

    def solve(self, F: PETSc.Vec, Y: PETSc.Vec, record, states: npt.NDArray | None) -> bool:
        """``J Y = F`` through the Schur complement (see the class docstring)."""
        if self._fresh:
            self._extract()
            self.inner.assembled(states)
            self._fresh = False
        Fu, Ff = F.getSubVector(self.is_u), F.getSubVector(self.is_f)
        Yu, Yf = Y.getSubVector(self.is_u), Y.getSubVector(self.is_f)
        if self._vecs is None:
            self._vecs = (self._inv.createVecLeft(), self.S.createVecLeft())
        w, g = self._vecs
        self._inv.mult(Ff, w)  # A_ff⁻¹ F_f
        self._sub["uf"].mult(w, g)
        g.aypx(-1.0, Fu)  # F_u - A_uf A_ff⁻¹ F_f
        ok = self.inner.solve(g, Yu, record, states)
        self._sub["fu"].mult(Yu, w)
        w.aypx(-1.0, Ff)  # F_f - A_fu Y_u
        self._inv.mult(w, Yf)
        F.restoreSubVector(self.is_u, Fu)
        F.restoreSubVector(self.is_f, Ff)
        Y.restoreSubVector(self.is_u, Yu)
        Y.restoreSubVector(self.is_f, Yf)
        return ok

    @property
    def tightest(self) -> float:
        """The relative tolerance of the options (``ksp_rtol``)."""
        return self._rtol

    @property
    def smoother(self) -> str | None:
        """GAMG's level smoother chosen for ``S`` (:attr:`IterativeSolver.smoother`)."""
        return None if self.inner is None else self.inner.smoother

    def set_tolerance(self, rtol: float) -> None:
        """Relative tolerance of the next solve of ``S`` (:func:`forcing_term`)."""
        _set_tolerances(self._ksp, rtol=rtol)

    def forget(self) -> None:
        """Set the preconditioner up again at the next solve."""
        if self.inner is not None:
            self.inner.forget()

    def destroy(self) -> None:
        """Free the blocks, ``S``, the work vectors and the index sets."""
        if self.inner is not None:
            self.inner.destroy()
        elif self.multigrid is not None:
            self.multigrid.destroy()
        objs = [*self._sub.values(), self._inv, self._T, self._P, self.S, self.is_u, self.is_f,
                *(self._vecs or ())]
        for obj in objs:
            if obj is not None:
                obj.destroy()


def linear_strategy(ksp: PETSc.KSP, A: PETSc.Mat, prefix: str, *, reuse: bool, stale: bool,
                    modes: Callable[[], npt.NDArray[np.float64]] | None = None,
                    blocks: tuple[list[int], list[int]] | None = None,
                    coarse: Callable[[], tuple[PETSc.Mat, npt.NDArray[np.float64]]] | None = None,
                    priced: bool = False) -> LinearStrategy:
    """The strategy for the KSP as its options configured it (call with the options pushed).

    Args:
        ksp: The Newton's KSP, configured (``setFromOptions``).
        A: The Jacobian matrix.
        prefix: Options prefix of the Newton.
        reuse: Reuse a factorization or preconditioner while the Jacobian is unchanged.
        stale: Try stale-factorization GMRES (direct).
        priced: Its budget priced from each factorization (:class:`DirectSolver`).
        modes: Computes the rigid-body modes of the displacements; called for a Krylov KSP
            only, whose preconditioner may use them (GAMG).
        blocks: For a Jacobian with face unknowns: the owned entries of each block (``u``
            first) and the components per face of each face unknown; a Krylov KSP then solves
            the displacement Schur complement (:class:`FaceElimination`).
        coarse: Computes the interpolation from the P1 space into the displacements and the
            P1 rigid-body modes; called when the options name ``pc_type mg``, the p-multigrid
            (:class:`~poromech.mechanics.multigrid.PMultigrid`).
    """
    if is_direct(ksp):
        return DirectSolver(ksp, A, prefix, reuse=reuse, stale=stale, priced=priced)
    # the level smoother is chosen by the solver unless the options name one
    choose = not PETSc.Options().hasName(f"{prefix}mg_levels_pc_type")
    multigrid = None
    if ksp.getPC().getType() == PETSc.PC.Type.MG:
        if coarse is None:
            raise ValueError(f"{prefix}pc_type mg (the p-multigrid) needs degree 2 displacements: "
                             "use gamg, or degree 2")
        multigrid = PMultigrid(ksp, *coarse(), near_nullspace)
    if blocks is not None:
        return FaceElimination(ksp, A, blocks[0], blocks[1], modes(), reuse=reuse,
                               choose_smoother=choose, multigrid=multigrid)
    return IterativeSolver(ksp, A, None if modes is None else modes(), reuse=reuse,
                           choose_smoother=choose, multigrid=multigrid)
