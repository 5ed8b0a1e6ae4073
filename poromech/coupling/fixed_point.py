"""A fixed point ``p = g(p)`` solved by a PETSc SNES on ``F(p) = p - g(p)``, for any callable ``g``.

The SNES has the options prefix ``coupling_`` (a fallback method ``coupling_fallback_``) and
the defaults of its method (:data:`METHOD_OPTIONS`: Anderson, NGMRES, L-BFGS, a composite
Anderson on Picard sweeps, matrix-free Newton-Krylov, plain Picard). Its convergence test stops at
``|F| <= rtol |F₀|`` or ``|F|/√N <= atol``, and, when the iteration stagnates, at the noise of
``g`` (the forward error of its inner solve, supplied by the owner) unless that noise is too large
to trust. A ``g`` that cannot be evaluated raises :class:`EvaluationFailure`: the attempt ends
with ``DIVERGED_FUNCTION_DOMAIN`` and the message is kept.

The physics that owns the fixed point (:mod:`poromech.coupling.poromechanics`) decides what an
attempt starts from, and whether a failed attempt is repeated with the fallback method.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import dolfinx_solver  # noqa: F401

import numpy as np
import numpy.typing as npt
from mpi4py import MPI
from petsc4py import PETSc

from poromech.petsc_options import PrefixedOptions, reason_name
from poromech.scene.schema import Coupling

__all__ = [
    "DIVERGENCE",
    "FALLBACK_OPTIONS",
    "METHOD_OPTIONS",
    "NOISE_LIMIT",
    "STAGNATION",
    "STALL_ITERATIONS",
    "EvaluationFailure",
    "FixedPoint",
    "FixedPointStats",
]

log = logging.getLogger("poromech")

Array = npt.NDArray[np.float64]

#: PETSc defaults of each ``coupling.method`` (prefix ``coupling_``); ``{m}`` is the memory.
#:
#: ``composite`` is Anderson right-preconditioned by a Picard sweep (PETSc's nonlinear
#: preconditioning, ``npc_``: Anderson mixes the sweep's outputs and keeps its history). It was
#: PETSc's ``composite`` of a Picard sweep and Anderson, which runs each for one iteration per
#: outer iteration and so restarts Anderson's history every time: two plain sweeps per
#: iteration, 194 ``g`` on the six-fracture scene (now 146, Anderson alone 99), and on an
#: injection into a kinked fracture 477 ``g`` per step until the fallback took over (now 15-21,
#: Anderson 7-10).
#:
#: ``newtonkrylov`` differences ``g`` with the Dennis-Schnabel step (``mat_mffd_type ds``),
#: ``h = ε max(|pᵀa|, u_min ‖a‖₁)/‖a‖²``, a perturbation relative to the pressures. PETSc's
#: default (``wp``, ``h = ε √(1 + ‖p‖)/‖a‖``) assumes unknowns of order one: with pressures in Pa
#: (``‖p‖`` ~ 5e6 on the six-fracture scene) it perturbs them by ~1e-11 of their size, where
#: the response of ``g`` is round-off of the inner solves. With it Newton needed 32 iterations
#: (247 ``g``) for the first step of that scene and diverged in the second; with ``ds`` 2-3 per
#: step, 161-166 ``g`` for the 20 steps with every formulation (docs/poromechanics.md). Where
#: ``|pᵀa|`` vanishes (pressures that start at zero: an overpressure scene's first step) ``ds``
#: takes ``umin ‖a‖₁`` in its place, so ``umin`` is a pressure: 1 Pa (PETSc's 1e-6 perturbed the
#: injection scene's pressures by ~1e-12 Pa and GMRES did not converge; the six-fracture
#: scene, whose pressures are ~1e5 Pa and more, has the same residual histories with either).
METHOD_OPTIONS: dict[str, dict[str, object]] = {
    "anderson": {"snes_type": "anderson", "snes_anderson_m": "{m}", "snes_anderson_beta": 1.0},
    "ngmres": {"snes_type": "ngmres", "snes_ngmres_m": "{m}"},
    "qn": {"snes_type": "qn", "snes_qn_type": "lbfgs", "snes_qn_m": "{m}",
           "snes_linesearch_type": "basic", "snes_qn_scale_type": "none"},
    "composite": {"snes_type": "anderson", "snes_anderson_m": "{m}", "snes_anderson_beta": 1.0,
                  "npc_snes_type": "nrichardson", "npc_snes_max_it": 1,
                  "npc_snes_linesearch_type": "basic"},
    "newtonkrylov": {"snes_type": "newtonls", "snes_mf": "", "mat_mffd_type": "ds",
                     "mat_mffd_umin": 1.0,
                     "snes_linesearch_type": "basic",
                     "ksp_type": "gmres", "pc_type": "none", "ksp_rtol": 1e-2,
                     "ksp_max_it": 30},
    "picard": {"snes_type": "nrichardson", "snes_linesearch_type": "basic"},
}

#: PETSc options of a fallback method (``coupling.fallback``) over its :data:`METHOD_OPTIONS`:
#: robustness before speed. NGMRES chooses between the combination of its history and the plain
#: iterate by a line search on the residual instead of by fixed criteria (4-5 g per iteration
#: instead of 1-2): on the sealed six-fracture scene (K_m = 1e-20 m², ``stabilized_mixed``) the
#: default selection crept at 0.7 % per iteration after Anderson failed at t = 600 s, and the
#: step failed down to t = 506 s; with the line search the fallback converged that step.
FALLBACK_OPTIONS: dict[str, dict[str, object]] = {
    "ngmres": {"snes_ngmres_select_type": "linesearch"},
}

#: A fixed-point residual this many times its initial value ends the attempt as diverged.
DIVERGENCE = 1e3

#: A fixed-point iteration that does not halve the best residual of the step so far is checked
#: against the noise of ``g`` (:meth:`FixedPoint.estimate_noise`).
STAGNATION = 0.5
#: Largest noise of ``g``, relative to ``|p|``, at which a step may stop at that noise: above
#: it the inner solve is not accurate enough to trust (a sealed, incompressible fracture), and
#: the step goes on to fail with the estimate in its message.
NOISE_LIMIT = 1e-4
#: An attempt whose best residual has not been halved (:data:`STAGNATION`) for this many
#: iterations has stalled and ends there (reason ``DIVERGED_STALLED``): the fallback, then a step
#: cut, follow instead of the rest of ``coupling.max_it``. On the 3D fault scene at 100 L/s
#: (``mean_nitsche``, P1) Anderson's shut-in step wandered between 1.7e5 and 1e6 Pa for 287
#: iterations after reaching 1.7e5; the longest plateau of an attempt that went on to converge,
#: over the robustness cases of docs/poromechanics.md, was 103 iterations.
STALL_ITERATIONS = 150


class EvaluationFailure(RuntimeError):
    """``g`` could not be evaluated (an inner solve failed); the message says why."""


@dataclass
class FixedPointStats:
    """What the iterations of one step did (identical on every rank).

    Attributes:
        iterations: Fixed-point iterations, over every attempt of the step.
        residuals: ``|p - g(p)|`` at every iteration of every attempt.
        noise: Estimates of the noise of ``g``, made at stagnating iterations.
        at_noise: Converged at the noise of ``g`` rather than at the tolerance.
        pnorm: ``|p|`` when the noise was last estimated (``|g(p)|`` where ``p = 0``).
    """

    iterations: int = 0
    residuals: list[float] = field(default_factory=list)
    noise: list[float] = field(default_factory=list)
    at_noise: bool = False
    pnorm: float = np.nan

    @property
    def untrusted(self) -> bool:
        """Whether the last noise estimate exceeded :data:`NOISE_LIMIT` ``|p|``."""
        return bool(self.noise) and not self.noise[-1] <= NOISE_LIMIT * self.pnorm

    @property
    def relative_noise(self) -> str:
        """The last noise estimate relative to ``|p|``, for messages."""
        if not self.noise:
            return "not estimated"
        return f"{self.noise[-1] / self.pnorm:.1e} of |p|" if self.pnorm > 0 else "|p| = 0"


def method_run(method: str, snes: PETSc.SNES) -> str:
    """The name of the method ``snes`` runs, set up for ``coupling.method`` ``method``.

    ``method`` when the SNES has its type; else the method of :data:`METHOD_OPTIONS` with that
    type and no inner solver, or ``snes_type <type>`` for a type no method has.
    """
    kind = snes.getType()
    if kind == METHOD_OPTIONS[method]["snes_type"]:
        return method
    same = [m for m, o in METHOD_OPTIONS.items()
            if o["snes_type"] == kind and "npc_snes_type" not in o]
    return same[0] if same else f"snes_type {kind}"


class FixedPoint:
    """The SNES on ``p - g(p)`` of one coupled problem, and its fallback (collective).

    Args:
        comm: Communicator.
        n_local: Unknowns of ``p`` owned by this rank.
        g: ``g(p)`` on the owned unknowns; raises :class:`EvaluationFailure` when it cannot be
            evaluated.
        noise: The forward error of the last evaluation of ``g`` (a norm over all ranks;
            collective), or None.
        settings: The scene's ``coupling`` section (method, fallback, tolerances, memory,
            PETSc options).

    Attributes:
        method: The method that runs (:func:`method_run`).
        stats: The :class:`FixedPointStats` of the current step (:meth:`start_step`).
        failure: Why ``g`` failed in the current attempt, or None.
        N: Global number of unknowns.
    """

    def __init__(self, comm: MPI.Comm, n_local: int, g: Callable[[Array], Array],
                 noise: Callable[[], float] | None, settings: Coupling):
        self.comm, self._g, self._noise, self.settings = comm, g, noise, settings
        self.P = PETSc.Vec().createMPI((n_local, PETSc.DECIDE), comm=comm)
        self.R = self.P.duplicate()
        self.N = self.P.getSize()
        self._last_eval = self.P.duplicate()
        self.snes, self._options = self._create_snes(settings.method, "coupling_", settings.petsc)
        #: The method that runs: ``coupling.method``, unless a PETSc option chose another SNES
        #: type (``-coupling_snes_type ngmres``: the records named Anderson, and the fallback
        #: NGMRES would have solved a failed step again with the same method).
        self.method = method_run(settings.method, self.snes)
        #: Method a failed step is solved again with (``coupling.fallback``), built on first use.
        self.fallback = None if settings.fallback in ("none", self.method) \
            else settings.fallback
        self._fallback_snes: tuple[PETSc.SNES, PrefixedOptions] | None = None
        self.stats = FixedPointStats()
        self.failure: str | None = None
        #: Iteration at which the current attempt stalled (:data:`STALL_ITERATIONS`), or None.
        self.stalled: int | None = None
        self._f0 = self._best = self._halved = np.nan
        self._halved_at = 0
        self._last_g = np.zeros(n_local)  # g(p) of the last evaluation (owned entries)

    def _create_snes(self, method: str, prefix: str,
                     petsc: dict) -> tuple[PETSc.SNES, PrefixedOptions]:
        """A SNES on ``p - g(p)`` with the defaults of ``method`` (options prefix ``prefix``)."""
        c = self.settings
        snes = PETSc.SNES().create(self.comm)
        snes.setOptionsPrefix(prefix)
        merged = {k: (v.format(m=c.memory) if isinstance(v, str) else v)
                  for k, v in METHOD_OPTIONS[method].items()}
        merged.update({"snes_max_it": c.max_it, "snes_rtol": c.rtol, "snes_stol": 0.0,
                       "snes_atol": c.atol * np.sqrt(self.N)})
        merged.update(petsc)
        options = PrefixedOptions(prefix, merged)
        with options:
            snes.setFunction(self._residual, self.R)
            snes.setFromOptions()
        snes.setConvergenceTest(self._converged)
        snes.setMonitor(self._monitor)
        return snes, options

    # -- one step ------------------------------------------------------------------------------
    def start_step(self) -> None:
        """New statistics and no failure: the first attempt of a step follows."""
        self.stats = FixedPointStats()
        self.failure = None

    def attempt(self, guess: Array, fallback: bool = False) -> int:
        """Solve from ``guess`` with the method (or the fallback); PETSc's converged reason.

        A failure of ``g`` in an earlier attempt is forgotten. The iterations are added to
        :attr:`stats`; the solution is in :attr:`P`.
        """
        self.failure = self.stalled = None
        if fallback:
            if self._fallback_snes is None:
                self._fallback_snes = self._create_snes(
                    self.fallback, "coupling_fallback_", FALLBACK_OPTIONS.get(self.fallback, {}))
            snes, options = self._fallback_snes
        else:
            snes, options = self.snes, self._options
        self.P.getArray()[:] = guess
        with options:  # -snes_mf's operator reads mat_mffd_* at the first set-up
            snes.solve(None, self.P)
        self.stats.iterations += snes.getIterationNumber()
        return snes.getConvergedReason()

    def iterations_of(self, fallback: bool) -> int:
        """Iterations of the last solve of the method (or of the fallback)."""
        snes = self._fallback_snes[0] if fallback else self.snes
        return snes.getIterationNumber()

    def sync(self) -> None:
        """Evaluate ``g`` once more if its last evaluation was not at the final iterate.

        The owner's state (what ``g`` computed on the way) is then that of the solution.
        """
        if self.failure is not None:
            return
        self._last_eval.axpy(-1.0, self.P)
        stale = self._last_eval.norm(PETSc.NormType.NORM_INFINITY) > 0.0
        if stale:
            self._evaluate(self.P.getArray(readonly=True))

    def solution(self) -> Array:
        """The owned entries of the current iterate."""
        return self.P.getArray(readonly=True)

    # -- SNES callbacks ------------------------------------------------------------------------
    def _evaluate(self, p: Array) -> Array | None:
        try:
            return self._g(p)
        except EvaluationFailure as err:
            self.failure = str(err)
            return None

    def _residual(self, snes, x, f) -> None:
        if self.failure is not None:
            f.set(0.0)
            return
        gp = self._evaluate(x.getArray(readonly=True))
        if gp is None:  # a failed g: no change, and the attempt stops at the convergence test
            f.set(0.0)
        else:
            f.getArray()[:] = x.getArray(readonly=True) - gp
            self._last_g = gp
        x.copy(self._last_eval)

    def _converged(self, snes, it, norms):
        xnorm, ynorm, fnorm = norms
        rtol, atol, _, max_it = snes.getTolerances()
        R = PETSc.SNES.ConvergedReason
        if self.comm.allreduce(self.failure is not None, op=MPI.LOR):
            return R.DIVERGED_FUNCTION_DOMAIN
        if it == 0:
            self._f0 = self._best = self._halved = fnorm
            self._halved_at = 0
        if not np.isfinite(fnorm):
            return R.DIVERGED_FUNCTION_NANORINF
        if fnorm <= atol:
            return R.CONVERGED_FNORM_ABS
        if fnorm <= rtol * self._f0:
            return R.CONVERGED_FNORM_RELATIVE
        stagnating = it > 0 and fnorm > STAGNATION * self._best
        self._best = min(self._best, fnorm)
        if stagnating and self._noise is not None:
            noise = self.estimate_noise(snes.getSolution().norm())
            if fnorm <= noise and not self.stats.untrusted:
                self.stats.at_noise = True
                return R.CONVERGED_FNORM_ABS
        if it >= max_it:
            return R.DIVERGED_MAX_IT
        if fnorm <= STAGNATION * self._halved:
            self._halved, self._halved_at = fnorm, it
        elif it - self._halved_at >= STALL_ITERATIONS:
            self.stalled = it
            return R.DIVERGED_MAX_IT
        if fnorm > DIVERGENCE * self._f0:
            return R.DIVERGED_DTOL
        return R.ITERATING

    def reason_name(self, reason: int) -> str:
        """The name of the last attempt's converged reason: ``DIVERGED_STALLED`` if it stalled."""
        return "DIVERGED_STALLED" if self.stalled is not None and reason <= 0 \
            else reason_name(reason)

    def estimate_noise(self, pnorm: float | None = None) -> float:
        """The noise of the last ``g`` (its inner solve's forward error), recorded (collective).

        Round-off makes ``g`` noisy where the inner system is ill-conditioned (a fracture
        permeability contrast of 1e8 gives ~1 Pa RMS on pressures of 1 MPa): the relative
        tolerance may then ask for a residual below what two evaluations of ``g`` at the same
        ``p`` agree to, and the iteration wanders at that level. A stagnating iteration is
        stopped as converged once ``|p - g(p)|`` is within this estimate, unless the estimate
        exceeds :data:`NOISE_LIMIT` ``|p|``: such an inner solve is not to be trusted (a sealed
        fracture with K_m = 1e-20 m² gave estimates of 1e65 on pressures of 1e42).
        """
        noise = self._noise()
        self.stats.noise.append(noise)
        pnorm = self.P.norm() if pnorm is None else pnorm
        if pnorm == 0.0:  # pressures that start at zero (an overpressure scene): |g(p)|
            g = self._last_g
            pnorm = float(np.sqrt(self.comm.allreduce(float(g @ g))))
        self.stats.pnorm = pnorm
        return noise

    def _monitor(self, snes, it, fnorm) -> None:
        self.stats.residuals.append(float(fnorm))
        log.debug("coupling_ %d: |p - g(p)| = %.3e", it, fnorm)

    def destroy(self) -> None:
        """Free the PETSc objects."""
        for obj in (self.snes, self.P, self.R, self._last_eval):
            obj.destroy()
        if self._fallback_snes is not None:
            self._fallback_snes[0].destroy()
