"""The linear solver of the flow problem: a PETSc KSP with its own options prefix.

One defaults table per solver kind (:data:`ITERATIVE_OPTIONS`, in 3D
:data:`ITERATIVE_OPTIONS_3D`, and :data:`DIRECT_OPTIONS`); the scene's ``flow.petsc`` entries
merge over it (a ``null`` value removes a default); options already in the PETSc database (the
command line, ``-flow_ksp_rtol 1e-8``) win through ``setFromOptions``. The options are in the
database only while the KSP reads them (:class:`~poromech.petsc_options.PrefixedOptions`).
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field

import dolfinx_solver  # noqa: F401  (orders MPI before the bindings)

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from poromech.errors import SolverError
from poromech.petsc_options import PrefixedOptions
from poromech.scene.resources import direct_fallback_fits

log = logging.getLogger("poromech")

__all__ = [
    "DIRECT_OPTIONS",
    "ITERATIVE_OPTIONS",
    "ITERATIVE_OPTIONS_3D",
    "InitialResidualTest",
    "LinearRecord",
    "LinearSolver",
]

#: Conjugate gradients with smoothed-aggregation AMG on the SPD form (DESIGN §5). The residual
#: is measured in CG's natural norm ``√(rᵀBr)`` (≈ the energy norm of the error, i.e. flux
#: times pressure error, whatever the conductance of each row) and ``rtol`` is relative to the
#: initial residual (see :class:`InitialResidualTest`).
ITERATIVE_OPTIONS: dict[str, object] = {
    "ksp_type": "cg",
    "ksp_norm_type": "natural",
    "ksp_rtol": 1e-12,
    "ksp_atol": 1e-50,
    "ksp_max_it": 2000,
    "ksp_initial_guess_nonzero": True,
    "pc_type": "gamg",
    "pc_gamg_threshold": 0.02,
    "mg_levels_ksp_type": "chebyshev",
    "mg_levels_pc_type": "jacobi",
    # The Chebyshev bounds come from the smoothed aggregation's estimate at the first set-up
    # only; a later set-up (a new matrix: another time step size, apertures) has Chebyshev
    # estimate them, with GMRES by default. On the 3D network with a barrier (tangential
    # permeability 1e-18), GMRES put the fine level's largest eigenvalue at 2.25 instead of
    # 2.45 and CG stopped with DIVERGED_INDEFINITE_PC in every step after a change of the step
    # size. CG estimates the SPD operator's bounds to 1e-4 there; the first set-up is unchanged.
    "mg_levels_esteig_ksp_type": "cg",
}

#: Krylov methods that measure the natural norm ``√(rᵀBr)`` (the CG family).
NATURAL_NORM_TYPES = ("cg", "pipecg", "groppcg", "pipecgrr")

#: The changes of :data:`ITERATIVE_OPTIONS` in 3D: aggressive coarsening (the strength graph
#: squared) on the first two levels instead of the first only. On tetrahedral meshes one level
#: coarsens by about 10 and leaves dense middle levels (200-700 nonzeros per row) whose Galerkin
#: products dominate the set-up; with two, the operator complexity falls from 2.4 to 1.6 and
#: the set-up to a quarter to a third at the same CG iterations (``docs/flow/flow3d_scale.md``:
#: 35 at 0.3M and 1.6M unknowns, solve with set-up 53 s → 21 s at 1.6M on 1 rank). 2D keeps one.
ITERATIVE_OPTIONS_3D: dict[str, object] = {**ITERATIVE_OPTIONS,
                                           "pc_gamg_aggressive_coarsening": 2}

#: Sparse LU factorization with MUMPS.
DIRECT_OPTIONS: dict[str, object] = {
    "ksp_type": "preonly",
    "pc_type": "lu",
    "pc_factor_mat_solver_type": "mumps",
}

# ``auto`` (the default of ``flow.linear_solver``): the iterative solver, which a failed Krylov
# solve (its reason, or TRUE_RESIDUAL_DROP) hands to MUMPS LU for the rest of the run where the
# factorization fits (poromech.scene.resources.direct_fallback_fits), as the mechanics'
# ``solver.linear_solver: auto`` does; ``iterative`` keeps the failure.

#: A lagged preconditioner is rebuilt after a solve that took more than ``LAG_GROWTH`` times the
#: iterations of its first solve plus ``LAG_SLACK`` (:attr:`LinearSolver.lagged`): an AMG set-up
#: costs about as much as 10-15 CG iterations on the 3D fault scene.
LAG_GROWTH = 1.5
LAG_SLACK = 2

_REASONS = {v: k for k, v in vars(PETSc.KSP.ConvergedReason).items() if not k.startswith("_")}

#: Residual level, relative to ``‖b‖``, below which a solve counts as converged whatever the
#: initial residual (round-off of ``b - A x`` is a few ``ε ‖b‖``).
ROUNDOFF_FLOOR = 1e-13

#: A Krylov solve that met its tolerance must also have reduced the true residual ``‖b - A x‖``
#: by :data:`TRUE_RESIDUAL_DROP`, or to :data:`TRUE_RESIDUAL_FLOOR` ``‖b‖`` (round-off): the
#: natural norm ``√(rᵀBr)`` that CG measures is the error's only while the preconditioner ``B``
#: approximates ``A⁻¹``. A preconditioner lagged across a large change of the matrix does not:
#: in a coupled injection into a fracture of aperture 1e-9 m, the fracture's conductance grew by
#: 15 decades within a step, CG met its tolerance on the natural norm (1.6e39 → 5.2e26) while
#: the true residual went from 1.05 to 1.02, and the step was accepted with a mass balance of
#: 0.76 of the flow. Such a solve counts as failed: a lagged preconditioner is rebuilt and the
#: solve repeated, else the solve fails. The drop asked is far from the tolerance (the natural
#: and the true residual fall alike only up to the conditioning; a solve to ``rtol`` 1e-4 with
#: Jacobi reduced the true residual by 2e-4): it catches a solve that did not solve. Two
#: matrix products per solve; a solve that met its tolerance at once (no iteration) is taken,
#: and so is a true residual at round-off, :data:`TRUE_RESIDUAL_NOISE` ``‖A‖_∞ ‖x‖_∞`` (the
#: products ``A_ij x_j`` of a row nearly cancel where pressures are large and the fluxes small:
#: an injection's Darcy solve from the last pressures started at 4.8e-16 with ``‖b‖`` 1e-6).
TRUE_RESIDUAL_DROP = 1e-2
TRUE_RESIDUAL_FLOOR = 1e-10
TRUE_RESIDUAL_NOISE = 1e-12


class InitialResidualTest:
    """KSP convergence test relative to the initial residual, floored at round-off.

    Converged when ``‖r‖ <= max(rtol ‖r₀‖, atol, 1e-13 s)`` with ``r₀`` the residual of the
    initial guess (the previous solution) and ``s`` the round-off scale of the norm in use
    (:data:`_SCALE`). The tolerance thus applies to what changed since the last solve (a new
    step, new coefficients), not to ``‖b‖``, which is dominated by the pressure level
    (Dirichlet rows, storage terms ``|K| φⁿ⁻¹/Δt``) and by the stiffest rows (conductive
    fractures). On the transient six-fracture scene (``configs/flow_six_fractures.yaml``), the
    unpreconditioned residual measured against ``‖b‖`` let the relative mass balance drift to
    5e-9 once the flow became nearly steady; the natural norm with this test keeps it below
    4e-11 in every step, with the same iteration counts. ``rtol``, ``atol``, ``dtol`` and
    ``max_it`` are read from the KSP, so ``flow_ksp_rtol`` etc. keep their meaning.
    """

    def __init__(self) -> None:
        self.scale = {"b": 0.0, "x": 0.0, "bx": 0.0}
        self._target = 0.0
        self._r0 = 0.0

    def __call__(self, ksp: PETSc.KSP, its: int, rnorm: float) -> int:
        """The converged reason after ``its`` iterations with residual norm ``rnorm``."""
        reason = PETSc.KSP.ConvergedReason
        rtol, atol, dtol, max_it = ksp.getTolerances()
        if its == 0:
            self._r0 = rnorm
            floor = ROUNDOFF_FLOOR * self.scale[_SCALE.get(ksp.getNormType(), "b")]
            self._target = max(rtol * rnorm, atol, floor)
        if not np.isfinite(rnorm):
            return reason.DIVERGED_NANORINF
        if rnorm <= self._target:
            return reason.CONVERGED_RTOL if rnorm <= rtol * self._r0 else reason.CONVERGED_ATOL
        if its >= max_it:
            return reason.DIVERGED_MAX_IT
        if dtol is not None and rnorm > dtol * self._r0 > 0:
            return reason.DIVERGED_DTOL
        return reason.ITERATING

    def set_scales(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        """Record ``‖b‖``, ``‖x₀‖`` and ``√|b·x₀|`` before a solve (collective)."""
        self.scale = {"b": b.norm(), "x": x.norm(), "bx": float(np.sqrt(abs(b.dot(x))))}


#: Round-off scale of each residual norm: ``‖b‖`` (residual), ``‖x‖`` (``Br`` ≈ error),
#: ``√(b·x)`` (natural norm ``√(rᵀBr)`` ≈ energy norm of the error).
_SCALE = {
    PETSc.KSP.NormType.UNPRECONDITIONED: "b",
    PETSc.KSP.NormType.PRECONDITIONED: "x",
    PETSc.KSP.NormType.NATURAL: "bx",
}


@dataclass
class LinearRecord:
    """One linear solve (identical on every rank).

    Attributes:
        iterations: Krylov iterations.
        reason: PETSc converged reason name.
        residual: Final residual norm (as measured by the KSP).
        seconds: Wall time of the solve, including the preconditioner setup (s).
        setup_seconds: Part of ``seconds`` spent building the preconditioner (zero when it
            was reused because the matrix did not change) (s).
        lagged: The preconditioner was built for an earlier matrix
            (:attr:`LinearSolver.lagged`).
        history: Residual norms, one per iteration.
    """

    iterations: int = 0
    reason: str = ""
    residual: float = 0.0
    seconds: float = 0.0
    setup_seconds: float = 0.0
    lagged: bool = False
    history: list[float] = field(default_factory=list)

    def as_dict(self, history: bool = False) -> dict:
        """JSON-ready summary (without the residual history unless asked)."""
        out = asdict(self)
        if not history:
            out.pop("history")
        return out


def merged_options(kind: str, options: dict | None, dim: int = 2) -> dict[str, object]:
    """The defaults of ``kind`` (``iterative``, ``auto``, ``direct``), ``options`` merged over."""
    if kind in ("iterative", "auto"):
        base = dict(ITERATIVE_OPTIONS_3D if dim == 3 else ITERATIVE_OPTIONS)
    else:
        base = dict(DIRECT_OPTIONS)
    for k, v in (options or {}).items():
        if v is None:
            base.pop(k, None)
        else:
            base[k] = v
    return base


class LinearSolver:
    """Owns the KSP of the flow system.

    Args:
        A: The system matrix (its values may change between solves).
        prefix: Options prefix, ending in ``_`` (``flow_``).
        kind: ``iterative`` (CG + GAMG) or ``direct`` (LU with MUMPS) defaults; ``auto``: the
            iterative ones, and MUMPS for the rest of the run after a failed Krylov solve
            where it fits (:attr:`fallback`).
        options: Options merged over the defaults, without the prefix.
        dim: Dimension of the mesh (the iterative defaults differ in 3D).

    Attributes:
        lagged: A Krylov solve keeps the preconditioner of an earlier matrix when the values
            change (set by the coupling, whose Darcy matrix changes a little with the aperture
            at every fixed-point iterate): the preconditioner is built for a copy of the matrix
            and kept while the iterations stay within :data:`LAG_GROWTH` times those of its
            first solve plus :data:`LAG_SLACK`, or until :meth:`refresh`; a solve that takes
            more rebuilds it for the next, and a solve that fails is repeated with a new one.
            The solution is the same to the solver's tolerance; the AMG set-up is about 40 % of
            a Darcy solve on the 3D fault scene (docs/poromechanics.md).
    """

    def __init__(self, A: PETSc.Mat, prefix: str = "flow_", kind: str = "iterative",
                 options: dict | None = None, dim: int = 2):
        if not prefix.endswith("_"):
            raise ValueError(f"options prefix {prefix!r} must end with '_'")
        self.A = A
        self.prefix = prefix
        self.dim = dim
        self.auto = kind == "auto"
        self.fallback: str | None = None  # "direct" once a failed Krylov solve switched (auto)
        self.ksp = PETSc.KSP().create(A.getComm())
        self.ksp.setOptionsPrefix(prefix)
        self.ksp.setOperators(A)
        self._options = PrefixedOptions(prefix, merged_options(kind, options, dim))
        with self._options:
            self.ksp.setFromOptions()
        given_norm = (options or {}).get("ksp_norm_type") is not None \
            or PETSc.Options().hasName(f"{prefix}ksp_norm_type")
        if kind != "direct" and self.ksp.getType() not in NATURAL_NORM_TYPES \
                and not given_norm:
            # the default natural norm is CG's: another Krylov method (-flow_ksp_type gmres)
            # measures its own default norm instead of stopping at PETSc's set-up error
            self.ksp.setNormType(PETSc.KSP.NormType.DEFAULT)
        self.A.setOptionsPrefix(f"{prefix}A_")
        self.ksp.setConvergenceHistory(length=self.ksp.getTolerances()[3] + 1, reset=True)
        self.test = InitialResidualTest()
        self._work: PETSc.Vec | None = None
        self._r_true = 0.0
        if self.ksp.getType() != PETSc.KSP.Type.PREONLY:
            self.ksp.setConvergenceTest(self.test)
        self._changed = True
        self.lagged = False
        self._P: PETSc.Mat | None = None  # the matrix of a lagged preconditioner
        self._fresh_iterations = 0  # iterations of the first solve after the set-up
        self._refresh = False  # rebuild at the next change
        self._guess: PETSc.Vec | None = None
        self._stale = False  # the preconditioner is that of an earlier matrix

    def operator_changed(self) -> None:
        """Mark the matrix values as changed: a new preconditioner at the next solve (or not).

        With :attr:`lagged` the preconditioner may be kept.
        """
        self._changed = True

    def refresh(self) -> None:
        """Build a new preconditioner at the next solve, when :attr:`lagged`.

        Called at each step's start, so that a run restarted from its checkpoint solves as the
        uninterrupted run did.
        """
        if self._lagging:
            self._refresh = self._changed = True

    @property
    def _lagging(self) -> bool:
        return self.lagged and self.ksp.getType() != PETSc.KSP.Type.PREONLY

    def _set_up(self) -> float:
        """Build the preconditioner for the current matrix (a copy of it when lagging); seconds."""
        t0 = time.perf_counter()
        if self._lagging:
            if self._P is None:
                self._P = self.A.copy()
            else:
                self.A.copy(self._P, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
            self.ksp.setOperators(self.A, self._P)
        else:
            self.ksp.setOperators(self.A)
        self.ksp.setUp()
        self._fresh_iterations = -1
        self._refresh = False
        return time.perf_counter() - t0

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> LinearRecord:
        """Solve ``A x = b`` (collective).

        Raises:
            SolverError: The KSP did not converge; carries the reason and residual history.
        """
        t0 = time.perf_counter()
        setup = 0.0
        with self._options:  # the set-up reads its options (mat_mumps_*, pc_gamg_*) here
            lagged = self._stale  # an unchanged matrix keeps the preconditioner it had
            if self._changed:
                lagged = self._lagging and self._P is not None and not self._refresh
                if not lagged:
                    setup += self._set_up()
                self._changed = False
            if lagged:
                if self._guess is None:
                    self._guess = x.duplicate()
                x.copy(self._guess)
            r0 = self._true_residual(b, x)
            self.test.set_scales(b, x)
            self.ksp.solve(b, x)
            its = self.ksp.getIterationNumber()
            held = self._true_residual_held(b, x, r0)
            if lagged and (self.ksp.getConvergedReason() <= 0 or not held):  # a new set-up
                self._guess.copy(x)
                setup += self._set_up()
                lagged = False
                self.test.set_scales(b, x)
                self.ksp.solve(b, x)
                its += self.ksp.getIterationNumber()
                held = self._true_residual_held(b, x, r0)
            if (self.ksp.getConvergedReason() <= 0 or not held) and self.auto \
                    and self.fallback is None and self.switch_to_direct(its, r0):
                setup += self._set_up()  # LU from a zero guess: x is overwritten
                lagged = False
                self.ksp.solve(b, x)
                its += self.ksp.getIterationNumber()  # the work of both, as for a new set-up
                held = True
        self._stale = lagged
        if self._lagging:
            if not lagged and self._fresh_iterations < 0:
                self._fresh_iterations = its
            elif lagged and its > LAG_GROWTH * self._fresh_iterations + LAG_SLACK:
                self._refresh = True
        comm = x.getComm().tompi4py()
        reason = _REASONS.get(self.ksp.getConvergedReason(), str(self.ksp.getConvergedReason()))
        if self.ksp.getConvergedReason() > 0 and not held:
            reason = "DIVERGED_TRUE_RESIDUAL"
        rec = LinearRecord(
            iterations=int(its),
            reason=reason,
            residual=float(self.ksp.getResidualNorm()),
            seconds=float(comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)),
            setup_seconds=float(comm.allreduce(setup, op=MPI.MAX)),
            lagged=lagged,
            history=[float(h) for h in np.asarray(self.ksp.getConvergenceHistory())],
        )
        if self.ksp.getConvergedReason() <= 0 or not held:
            untrue = "" if held else (
                f" (the Krylov method met its tolerance, but the true residual |b - Ax| went "
                f"only from {r0:.3e} to {self._r_true:.3e}: the preconditioner does not "
                "approximate the matrix)")
            raise SolverError(
                f"flow linear solver ({self.ksp.getType()}/{self.ksp.getPC().getType()}) did not "
                f"converge: {rec.reason} after {rec.iterations} iterations, residual "
                f"{rec.residual:.3e}{untrue}"
                + ("" if self.ksp.getType() == PETSc.KSP.Type.PREONLY else
                   "; flow.linear_solver: direct solves it with MUMPS, memory permitting"),
                reason=rec.reason, history=rec.history, record=rec.as_dict(),
            )
        return rec

    def switch_to_direct(self, its: int = 0, r0: float = 0.0, restart: bool = False) -> bool:
        """Hand the solves to MUMPS LU for the rest of the run, where it fits (collective).

        Said in one warning either way; True when switched. ``restart``: the switch of the run
        being continued (its checkpoint), ``its`` and ``r0`` unused.
        """
        reason = _REASONS.get(self.ksp.getConvergedReason(), "")
        if self.ksp.getConvergedReason() > 0:
            reason = (f"DIVERGED_TRUE_RESIDUAL, the true residual |b - Ax| went only from "
                      f"{r0:.3e} to {self._r_true:.3e}")
        why = ("the run continued here had switched the flow to MUMPS LU after a failed solve"
               if restart else f"the flow's {self.ksp.getType()}/{self.ksp.getPC().getType()} "
               f"solve failed ({reason} after {its} iterations)")
        fits, figures = direct_fallback_fits(self.A.getSize()[0], self.dim,
                                             self.A.getComm().tompi4py())
        log.warning("%s; flow.linear_solver auto: %s (%s)", why,
                    "switching to MUMPS LU for the rest of the run" if fits
                    else "MUMPS LU does not fit and is not tried", figures)
        if not fits:
            return False
        self.fallback = "direct"
        self._options = PrefixedOptions(self.prefix, dict(DIRECT_OPTIONS))
        self.ksp.setType(PETSc.KSP.Type.PREONLY)
        self.ksp.setInitialGuessNonzero(False)
        pc = self.ksp.getPC()
        pc.setType(PETSc.PC.Type.LU)
        pc.setFactorSolverType("mumps")
        self.ksp.setOperators(self.A)
        return True

    def _residual(self, b: PETSc.Vec, x: PETSc.Vec) -> PETSc.Vec:
        """``b - A x`` in a work vector (collective)."""
        if self._work is None:
            self._work = b.duplicate()
        self.A.mult(x, self._work)
        self._work.aypx(-1.0, b)
        return self._work

    def _true_residual(self, b: PETSc.Vec, x: PETSc.Vec) -> float:
        """``‖b - A x‖`` (collective; 0 without a Krylov method, which is not checked)."""
        if self.ksp.getType() == PETSc.KSP.Type.PREONLY:
            return 0.0
        return self._residual(b, x).norm()

    def _true_residual_held(self, b: PETSc.Vec, x: PETSc.Vec, r0: float) -> bool:
        """Whether a solve from the true residual ``r0`` reduced it as its tolerance asks.

        :data:`TRUE_RESIDUAL_DROP`; True for a failed or direct solve (collective).
        """
        if self.ksp.getType() == PETSc.KSP.Type.PREONLY or self.ksp.getConvergedReason() <= 0 \
                or self.ksp.getIterationNumber() == 0:
            return True
        self._r_true = self._true_residual(b, x)
        if self._r_true <= max(TRUE_RESIDUAL_DROP * r0, TRUE_RESIDUAL_FLOOR * b.norm()):
            return True
        noise = TRUE_RESIDUAL_NOISE * self.A.norm(PETSc.NormType.INFINITY) \
            * x.norm(PETSc.NormType.INFINITY)
        return self._r_true <= noise

    def correction(self, b: PETSc.Vec, x: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec:
        """One step of iterative refinement of the last solve: ``out = P⁻¹ (b - A x)`` (collective).

        With a factorization ``P = A`` this is the error of ``x`` to first order, the forward
        error of the solve, which round-off sets when ``A`` is ill-conditioned (permeability
        contrasts); with AMG, an estimate of it. Uses the current preconditioner, no set-up.
        """
        self.ksp.getPC().apply(self._residual(b, x), out)
        return out

    def describe(self) -> dict[str, object]:
        """KSP and PC types and tolerances actually used."""
        rtol, atol, _, max_it = self.ksp.getTolerances()
        out = {"prefix": self.prefix, "ksp_type": self.ksp.getType(),
               "pc_type": self.ksp.getPC().getType(), "rtol": rtol, "atol": atol,
               "max_it": max_it}
        if self.fallback is not None:
            out["fallback"] = self.fallback
        return out

    def destroy(self) -> None:
        """Free the KSP and the lagged preconditioner's matrix."""
        self.ksp.destroy()
        for obj in (self._P, self._guess, self._work):
            if obj is not None:
                obj.destroy()
