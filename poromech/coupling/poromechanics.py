"""Coupled poromechanics (``physics: poromechanics``): Biot + contact + HFV flow, by fixed point.

The quasi-static model of Beaude et al. (2023, §3), implicit Euler in time. Each step solves the
fixed point ``p = g(p)`` on the matrix cell pressures and fracture face pressures
``p = (p_m, p_f)``:

* contact mechanics at the given pressures (semi-smooth Newton, warm-started): total stress
  ``σ(u) - b p_m I``, fracture pressure ``p_f`` on both faces, contact conditions on the
  effective traction ``T = (σ(u) - b p_m I) n⁺ + p_f n⁺``;
* Darcy (HFV) at the resulting porosity ``φ = φ⁰ + b (div u - div u⁰) + (p_m - p⁰)/M`` and
  aperture ``d_f = d₀ - [[u]]_n`` (conductivity ``d_f³/12`` by default).

The fixed point is a PETSc SNES on ``F(p) = p - g(p)`` with options prefix ``coupling_``
(``coupling.method``: Anderson by default, NGMRES, L-BFGS, a composite Picard/Anderson sweep,
matrix-free Newton-Krylov, or plain Picard), stopped at ``|F| <= rtol |F₀|`` (1e-5, the paper's)
or ``|F|/√N <= atol``. The initial state is the mechanical equilibrium under ``p⁰`` and the
boundary data at ``t = 0``; ``u⁰`` and ``d(u⁰)`` are the references of porosity and aperture.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from pathlib import Path

import dolfinx_solver  # noqa: F401

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from poromech.errors import SolverError
from poromech.flow.balance import compute_fluxes, mass_balance
from poromech.flow.output import FlowWriter
from poromech.flow.physics import flow_report, flow_state, restore_pressure
from poromech.flow.problem import TimeStep
from poromech.flow.setup import flow_properties, problem_from_scene, time_dependent
from poromech.mechanics.physics import MechanicsSimulation, scalar_row
from poromech.mesh.fractured import FracturedMesh
from poromech.petsc_options import PrefixedOptions
from poromech.scene.schema import Scene
from poromech.stepping import StepResult
from poromech.timing import Timer

__all__ = ["METHOD_OPTIONS", "PoromechanicsSimulation"]

log = logging.getLogger("poromech")

#: PETSc defaults of each ``coupling.method`` (prefix ``coupling_``); ``{m}`` is the memory.
#:
#: ``newtonkrylov`` differences ``g`` with the Dennis-Schnabel step (``mat_mffd_type ds``),
#: ``h = ε max(|pᵀa|, u_min ‖a‖₁)/‖a‖²``, a perturbation relative to the pressures. PETSc's
#: default (``wp``, ``h = ε √(1 + ‖p‖)/‖a‖``) assumes unknowns of order one: with pressures in Pa
#: (``‖p‖`` ~ 5e6 on the six-fracture scene) it perturbs them by ~1e-11 of their size, where
#: the response of ``g`` is round-off of the inner solves. With it Newton needed 32 iterations
#: (247 ``g``) for the first step of that scene and diverged in the second; with ``ds`` 2-3 per
#: step, 161-166 ``g`` for the 20 steps with every formulation (docs/poromechanics.md).
METHOD_OPTIONS: dict[str, dict[str, object]] = {
    "anderson": {"snes_type": "anderson", "snes_anderson_m": "{m}", "snes_anderson_beta": 1.0},
    "ngmres": {"snes_type": "ngmres", "snes_ngmres_m": "{m}"},
    "qn": {"snes_type": "qn", "snes_qn_type": "lbfgs", "snes_qn_m": "{m}",
           "snes_linesearch_type": "basic", "snes_qn_scale_type": "none"},
    "composite": {"snes_type": "composite", "snes_composite_type": "multiplicative",
                  "snes_composite_sneses": "nrichardson,anderson",
                  "sub_0_snes_linesearch_type": "basic", "sub_1_snes_anderson_m": "{m}"},
    "newtonkrylov": {"snes_type": "newtonls", "snes_mf": "", "mat_mffd_type": "ds",
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

#: A fixed-point residual this many times its initial value ends the step as diverged.
DIVERGENCE = 1e3

#: A fixed-point iteration that does not halve the best residual of the step so far is checked
#: against the noise of ``g`` (:meth:`PoromechanicsSimulation._estimate_noise`).
STAGNATION = 0.5
#: Largest noise of ``g``, relative to ``|p|``, at which a step may stop at that noise: above
#: it the Darcy solve is not accurate enough to trust (a sealed, incompressible fracture), and
#: the step goes on to fail with the estimate in its message.
NOISE_LIMIT = 1e-4

#: A contact solve that fails inside ``g`` is solved again from the last pressures it converged
#: at, in this many equal steps of pressure, before ``g`` fails: the extrapolated pressures of
#: an accelerated iterate can open a whole fracture at once, where pointwise Nitsche's Newton
#: stalls (injection scene: the step to 40 s was cut four times and cost 176 g).
CONTINUATION_STEPS = 2

#: Smallest aperture, relative to d₀, kept when ``d₀ - [[u]]_n`` would close a face entirely
#: (interpenetration within the contact tolerance); the faces clamped are counted.
APERTURE_FLOOR = 1e-3


def _owned_cells(fm: FracturedMesh) -> int:
    return fm.msh.topology.index_map(2).size_local


class PoromechanicsSimulation:
    """The coupled problem of a scene as a :class:`~poromech.stepping.Physics` (collective).

    Args:
        scene: The scene (``physics: poromechanics``).
        fm: The fractured mesh.
        timer: Wall-time accounting.
    """

    counters = ("iterations", "g_evaluations", "newton_iterations", "face_iterations",
                "factorizations", "stale_solves", "darcy_iterations", "darcy_solves",
                "mechanics_seconds", "darcy_seconds", "solve_seconds")

    def __init__(self, scene: Scene, fm: FracturedMesh, timer: Timer):
        self.scene, self.fm, self.timer, self.comm = scene, fm, timer, fm.comm
        self.mech = MechanicsSimulation(scene, fm, timer)
        with timer.phase("flow_setup"):
            self.flow = problem_from_scene(scene, fm)
        self.model = self.mech.model
        flow = scene.flow
        self.biot = scene.material.biot
        self.porosity0 = flow.porosity
        self.nc, self.nf = _owned_cells(fm), len(fm.fractures.facets)
        self.nf_global = self.comm.allreduce(self.nf)
        self._d0_varies = time_dependent(scene)
        self.d0 = self.flow.properties.aperture.copy()
        self.storage = self.flow.properties.storage.copy()  # 1/M, the physical storage
        self.beta = self._fixed_stress(scene.coupling.stabilization)
        factor = scene.coupling.fracture_stabilization
        self._auto_fracture_stabilization = factor is None
        self.fracture_stabilization_from: float | None = None  # when "auto" switched it on
        self.beta_f = self._fracture_fixed_stress(factor or 0.0)
        if np.any(self.beta > 0) or self.beta_f is not None:
            self.flow.set_properties(replace(self.flow.properties,
                                             storage=self.storage + self.beta,
                                             fracture_storage=self.beta_f))
        self.records: list[dict] = []
        self.has_initial_output = True
        self.writer: FlowWriter | None = None
        self._build_snes()
        self._stats = _Counters()
        self._step: TimeStep | None = None
        self.t, self.dt = 0.0, None
        self.history: list[tuple[float, np.ndarray]] = []  # accepted (t, p) for extrapolation
        # the last converged contact solve: its input pressures and unknowns (the start of a
        # continuation), and that of the accepted state
        self._contact_start: tuple | None = None
        self._accepted_start: tuple | None = None

    # -- the fixed point -----------------------------------------------------------------------
    def _build_snes(self) -> None:
        comm, n = self.comm, self.nc + self.nf
        self.P = PETSc.Vec().createMPI((n, PETSc.DECIDE), comm=comm)
        self.R = self.P.duplicate()
        self.N = self.P.getSize()
        self._last_eval = self.P.duplicate()
        c = self.scene.coupling
        self.snes, self._options = self._create_snes(c.method, "coupling_", c.petsc)
        #: Method a failed step is solved again with (``coupling.fallback``), built on first use.
        self.fallback = None if c.fallback in ("none", c.method) else c.fallback
        self._fallback_snes: tuple[PETSc.SNES, PrefixedOptions] | None = None
        # the last attempt failed: the next one is a cut sub-step of the same state (a converged
        # attempt clears it, and only converged attempts are accepted)
        self._failed_since_accept = False
        self._failure: str | None = None

    def _create_snes(self, method: str, prefix: str,
                     petsc: dict) -> tuple[PETSc.SNES, PrefixedOptions]:
        """A SNES on ``p - g(p)`` with the defaults of ``method`` (options prefix ``prefix``)."""
        c = self.scene.coupling
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

    def _split(self, x: PETSc.Vec) -> tuple[np.ndarray, np.ndarray]:
        a = x.getArray(readonly=True)
        return a[: self.nc], a[self.nc:]

    def g(self, p_m: np.ndarray, p_f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One evaluation of the fixed-point map: mechanics at ``p``, then Darcy (collective).

        Returns:
            The new ``(p_m, p_f)`` on the owned cells and fracture faces (Pa).
        """
        s = self._stats
        s.evaluations += 1
        t0 = time.perf_counter()
        self.model.set_pressures(p_m, p_f)
        recs = [self.mech.solver.solve()]
        if not recs[0].converged and self._contact_start is not None:
            recs += self._continuation(p_m, p_f)
        rec = recs[-1]
        s.add_newton(*recs)
        for r in recs:
            self.timer.add("assembly", r.time_assembly)
            self.timer.add("linear_solve", r.time_linear)
        t1 = time.perf_counter()
        s.mechanics_seconds += t1 - t0
        if not rec.converged:
            first = recs[0]
            self._failure = (f"contact Newton did not converge inside the fixed point: "
                             f"{first.reason} after {first.iterations} iterations; residual "
                             "history " + ", ".join(f"{r:.3e}" for r in first.residuals)
                             + (f"; nor by continuation from the last converged pressures "
                                f"({rec.reason} after {rec.iterations} iterations)"
                                if len(recs) > 1 else ""))
            return p_m, p_f
        self._contact_start = self._contact_state(p_m, p_f)
        self._update_flow(p_m, p_f)
        try:
            with self.timer.phase("flow_solve"):
                lin = self.flow.solve(self.t, self._step)
        except SolverError as err:
            self._failure = f"Darcy solve failed inside the fixed point: {err}"
            return p_m, p_f
        s.darcy_iterations += lin.iterations
        s.darcy_solves += 1
        s.darcy_seconds += time.perf_counter() - t1
        return self.flow.cell_pressure, self.flow.fracture_pressure

    def _contact_state(self, p_m: np.ndarray, p_f: np.ndarray) -> tuple:
        """Pressures and a copy of the contact unknowns solved at them (a continuation start)."""
        return p_m.copy(), p_f.copy(), [f.x.array.copy() for f in self.model.unknowns]

    def _continuation(self, p_m: np.ndarray, p_f: np.ndarray) -> list:
        """The contact problem at ``p`` solved again from the last pressures it converged at.

        The unknowns of that solve are restored and the pressures raised to ``p`` in
        :data:`CONTINUATION_STEPS` equal steps, each solve starting from the last; stops at the
        first that fails. ``g`` is unchanged where the solution is unique: only the Newton's
        start differs. Returns the Newton records (collective).
        """
        q_m, q_f, unknowns = self._contact_start
        log.debug("contact Newton failed inside g: continuation from the last converged "
                  "pressures in %d steps", CONTINUATION_STEPS)
        for f, a in zip(self.model.unknowns, unknowns, strict=True):
            f.x.array[:] = a
        recs = []
        for k in range(1, CONTINUATION_STEPS + 1):
            w = k / CONTINUATION_STEPS
            self.model.set_pressures(q_m + w * (p_m - q_m), q_f + w * (p_f - q_f))
            recs.append(self.mech.solver.solve())
            if not recs[-1].converged:
                break
        return recs

    def _moduli(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Young's modulus (Pa) and Poisson's ratio of the scene at points ``x`` at t = 0."""
        m = self.scene.material
        return m.young(x[:, 0], x[:, 1], 0.0), m.poisson(x[:, 0], x[:, 1], 0.0)

    def _fixed_stress(self, factor: float) -> np.ndarray:
        """``β_K = factor · b² / K_dr`` per owned cell (1/Pa), ``K_dr = λ + μ`` (plane strain).

        Added to the storage of the Darcy solve inside ``g`` as ``β (p - p_in)``, with ``p_in``
        the input pressure: ``g`` changes, its fixed point does not (Kim, Tchelepi & Juanes
        2011, fixed-stress split).
        """
        if factor == 0 or self.biot == 0 or self.scene.time is None:  # steady: no storage
            return np.zeros(self.nc)
        young, nu = self._moduli(self.flow.geom.centroid)
        lam = young * nu / ((1 + nu) * (1 - 2 * nu))
        mu = young / (2 * (1 + nu))
        return factor * self.biot**2 / (lam + mu)

    def _fracture_fixed_stress(self, factor: float) -> np.ndarray | None:
        """``β_f = factor · π (1 - ν²) a / E`` per owned fracture face (m/Pa), or None.

        ``π (1 - ν²) a / E`` is the mean opening per unit pressure of a pressurized crack of
        half-length ``a`` (plane strain), ``a`` that of the face's fracture, ``E`` and ``ν`` at
        the face midpoint. Added to the fracture volume balance of the Darcy solve inside ``g``
        as ``β_f (p_f - p_f,in)``, like the matrix term: it changes ``g`` but not its fixed
        point, and gives the fracture pressure a response to the volume change where the
        matrix cannot drain the fractures (an impervious matrix seals them).
        """
        if factor == 0 or self.nf == 0 or self.scene.time is None:
            return None
        f = self.fm.fractures
        a = 0.5 * self.fm.geometry.fracture_lengths()[f.fracture]
        young, nu = self._moduli(f.midpoint)
        return factor * np.pi * (1 - nu**2) * a / young

    def _update_flow(self, p_in: np.ndarray, pf_in: np.ndarray) -> None:
        """Aperture and porosity from the current displacement, into the Darcy problem.

        ``p_in`` and ``pf_in`` are the input pressures of ``g``, the centres of the fixed-stress
        terms.
        """
        jn = self.model.face_fields()[:, 0] if self.nf else np.empty(0)
        d = self.d0 - jn
        floor = APERTURE_FLOOR * self.d0
        self._stats.clamped = int(self.comm.allreduce(int(np.count_nonzero(d < floor))))
        self.flow.set_aperture(np.maximum(d, floor))
        fixed = self.porosity0 + self.biot * (self.model.cell_divergence() - self.div0) \
            - self.storage * self.p0_cells - self.beta * p_in
        aperture_fixed = None
        if self.beta_f is not None:
            aperture_fixed = self.flow.properties.aperture - self.beta_f * pf_in
        self._step = TimeStep(self.dt, self.porosity_prev, fixed, self.aperture_prev,
                              aperture_fixed) if self.dt is not None else None

    def _residual(self, snes, x, f) -> None:
        if self._failure is not None:
            f.set(0.0)
            return
        p_m, p_f = self.g(*self._split(x))
        out = f.getArray()
        xa = x.getArray(readonly=True)
        out[: self.nc] = xa[: self.nc] - p_m
        out[self.nc:] = xa[self.nc:] - p_f
        x.copy(self._last_eval)

    def _converged(self, snes, it, norms):
        xnorm, ynorm, fnorm = norms
        rtol, atol, _, max_it = snes.getTolerances()
        R = PETSc.SNES.ConvergedReason
        if self.comm.allreduce(self._failure is not None, op=MPI.LOR):
            return R.DIVERGED_FUNCTION_DOMAIN
        if it == 0:
            self._f0 = self._best = fnorm
        if not np.isfinite(fnorm):
            return R.DIVERGED_FUNCTION_NANORINF
        if fnorm <= atol:
            return R.CONVERGED_FNORM_ABS
        if fnorm <= rtol * self._f0:
            return R.CONVERGED_FNORM_RELATIVE
        stagnating = it > 0 and fnorm > STAGNATION * self._best
        self._best = min(self._best, fnorm)
        if stagnating:
            noise = self._estimate_noise(snes.getSolution().norm())
            if fnorm <= noise and not self._stats.untrusted:
                self._stats.at_noise = True
                return R.CONVERGED_FNORM_ABS
        if it >= max_it:
            return R.DIVERGED_MAX_IT
        if fnorm > DIVERGENCE * self._f0:
            return R.DIVERGED_DTOL
        return R.ITERATING

    def _estimate_noise(self, pnorm: float) -> float:
        """The accuracy of the last ``g``: the forward error of its Darcy solve, in ``|p - g(p)|``.

        Round-off makes ``g`` noisy where the Darcy system is ill-conditioned (a fracture
        permeability contrast of 1e8 gives ~1 Pa RMS on pressures of 1 MPa, against u and the
        apertures reproduced to 1e-18 m): the relative tolerance may then ask for a residual
        below what two evaluations of ``g`` at the same ``p`` agree to, and the iteration
        wanders at that level. A stagnating iteration is stopped as converged once
        ``|p - g(p)|`` is within this estimate (one refinement step of the last Darcy solve),
        unless the estimate exceeds :data:`NOISE_LIMIT` ``|p|``: such a Darcy solve is not to be
        trusted (a sealed fracture with K_m = 1e-20 m² gave estimates of 1e65 on pressures of
        1e42), and the step then fails with the estimate in its message.
        """
        e_m, e_f = self.flow.solve_error()
        noise = float(np.sqrt(self.comm.allreduce(e_m @ e_m + e_f @ e_f)))
        self._stats.noise.append(noise)
        self._stats.pnorm = pnorm
        return noise

    def _monitor(self, snes, it, fnorm) -> None:
        self._stats.residuals.append(float(fnorm))
        log.debug("coupling_ %d: |p - g(p)| = %.3e", it, fnorm)

    # -- Physics interface -----------------------------------------------------------------
    def describe(self) -> dict:
        """Discretization and sizes, for the summary."""
        return {**self.mech.describe(), "flow_unknowns": self.flow.dofs.num_global,
                "coupling_method": self.scene.coupling.method,
                "coupling_unknowns": int(self.N)}

    def initialize(self) -> dict:
        """Mechanical equilibrium under ``p⁰`` at ``t = 0``: the reference state."""
        flow, pb = self.scene.flow, self.flow
        pb.set_pressure(flow.initial_pressure, 0.0)
        self.p0_cells = pb.cell_pressure.copy()
        self.model.set_time(0.0)
        self.model.set_pressures(pb.cell_pressure, pb.fracture_pressure)
        rec = self.mech.solver.solve()
        self.timer.add("assembly", rec.time_assembly)
        self.timer.add("linear_solve", rec.time_linear)
        if not rec.converged:
            raise SolverError(
                f"the initial mechanical equilibrium under p⁰ did not converge: {rec.reason} "
                f"after {rec.iterations} iterations", rec.reason, rec.residuals, rec.as_dict())
        self.div0 = self.model.cell_divergence()
        jn = self.model.face_fields()[:, 0] if self.nf else np.empty(0)
        self.aperture_prev = np.maximum(self.d0 - jn, APERTURE_FLOOR * self.d0)
        pb.set_aperture(self.aperture_prev)
        self.porosity_prev = np.full(self.nc, self.porosity0)
        self._step = None
        self.mech.accept(0.0)
        self._accepted_p = pb.p.copy()
        self.history = [(0.0, self._pressures())]
        self._contact_start = self._accepted_start = self._contact_state(
            pb.cell_pressure, pb.fracture_pressure)
        log.info("initial equilibrium under p0: %d Newton iterations", rec.iterations)
        return {"iterations": rec.iterations, "reason": rec.reason}

    def _pressures(self) -> np.ndarray:
        return np.concatenate([self.flow.cell_pressure, self.flow.fracture_pressure])

    def _guess(self, t: float) -> np.ndarray:
        """Initial fixed-point iterate: the last pressures, linearly extrapolated in time."""
        (t1, p1) = self.history[-1]
        if not self.scene.coupling.extrapolate or len(self.history) < 2:
            return p1
        t0, p0 = self.history[-2]
        return p1 + (t - t1) / (t1 - t0) * (p1 - p0)

    def solve(self, t: float, dt: float | None) -> StepResult:
        """The fixed point of the step ending at ``t``."""
        self.t, self.dt = t, dt
        if self._d0_varies:
            self.d0 = flow_properties(self.scene, self.fm, self.flow.geom, t).aperture
        self.model.set_time(t)
        self._stats = _Counters()
        self._failure = None
        t0 = time.perf_counter()
        snes, method = self.snes, self.scene.coupling.method
        reason = self._attempt(t, snes, self._options, method, retry=False)
        if reason <= 0 and self._switch_on_fracture_stabilization(t):
            reason = self._attempt(t, snes, self._options, method)
        fallback_from = None
        # only for a failure of the iteration itself: not of an inner solve (a step cut answers
        # that), nor of a g made ill-posed by an untrustworthy Darcy solve; and once per accepted
        # state: when the fallback fails too, the cut sub-steps go without it
        if (reason <= 0 and self.fallback is not None and self._failure is None
                and not self._stats.untrusted and not self._failed_since_accept):
            log.warning("the coupled fixed point did not converge at t = %g s with %s (%s after "
                        "%d g evaluations); solving the step again with %s", t, method,
                        _REASONS.get(reason, str(reason)), self._stats.evaluations, self.fallback)
            if self._fallback_snes is None:
                self._fallback_snes = self._create_snes(self.fallback, "coupling_fallback_",
                                                   FALLBACK_OPTIONS.get(self.fallback, {}))
            fallback_from = len(self._stats.residuals)
            snes, method = self._fallback_snes[0], self.fallback
            reason = self._attempt(t, snes, self._fallback_snes[1], method)
        self._sync_state()
        s = self._stats
        name = _REASONS.get(reason, str(reason))
        record = s.record(name, reason > 0, s.iterations,
                          self.comm.allreduce(time.perf_counter() - t0, op=MPI.MAX))
        record["method"] = method
        record["fallback_from"] = fallback_from
        self._failed_since_accept = reason <= 0
        if reason > 0:
            record["mass_balance"] = mass_balance(self.flow, compute_fluxes(self.flow), t,
                                                  self._step)
            return StepResult(True, record)
        why = self._failure or f"{name} after {snes.getIterationNumber()} iterations of {method}"
        if s.noise and self._failure is None:
            why += (f" (estimated error of the Darcy solve {s.noise[-1]:.2e}, "
                    f"{s.noise[-1] / s.pnorm:.1e} of |p|)")
            if s.untrusted and self.scene.coupling.fracture_stabilization == 0:
                why += (" — the Darcy problem in g is nearly singular (sealed fractures?): set "
                        "coupling.fracture_stabilization to null or a factor > 0")
        message = (f"the coupled fixed point did not converge at t = {t:g} s: {why}; "
                   "|p - g(p)| history " + ", ".join(f"{r:.3e}" for r in s.residuals))
        return StepResult(False, record, message, name, list(s.residuals))

    def _attempt(self, t: float, snes: PETSc.SNES, options: PrefixedOptions, method: str,
                 retry: bool = True) -> int:
        """Solve the step's fixed point with ``snes`` from the extrapolated pressures.

        A ``retry`` first restores the state of the last accepted step. Returns PETSc's
        converged reason; the iterations are added to the step's counters.
        """
        if retry:
            self.reject()
            self._failure = None
        # finite differences of g need u to respond to tiny changes of p: the contact Newton
        # takes at least one step even when its residual is already below the tolerance
        self.mech.solver.min_iterations = int(method == "newtonkrylov")
        self.P.getArray()[:] = self._guess(t)
        with options:  # -snes_mf's operator reads mat_mffd_* at the first set-up
            snes.solve(None, self.P)
        self._stats.iterations += snes.getIterationNumber()
        return snes.getConvergedReason()

    def _switch_on_fracture_stabilization(self, t: float) -> bool:
        """Switch ``β_f`` on (factor 1) after a failure with an untrustworthy Darcy solve.

        Only with ``coupling.fracture_stabilization: null``, fractures and time steps, once per
        run. Untrustworthy: the estimated error of the last Darcy solve in ``g`` exceeds
        :data:`NOISE_LIMIT` ``|p|`` (fractures sealed by a nearly impervious matrix: without
        fracture storage their pressure is nearly undetermined). ``β_f`` changes ``g``, not its
        fixed point (collective).
        """
        if (not self._auto_fracture_stabilization or self.fracture_stabilization_from is not None
                or self.nf_global == 0 or self.scene.time is None
                or not self.flow.records):
            return False
        s = self._stats
        if not s.noise:
            self._estimate_noise(self.P.norm())
        if not s.untrusted:
            return False
        self._set_fracture_stabilization(1.0)
        self.fracture_stabilization_from = t
        log.warning("the Darcy solve inside g is not to be trusted at t = %g s (estimated error "
                    "%.2e, %.1e of |p|: fractures sealed by the matrix?); switching on the "
                    "fracture fixed-stress term (coupling.fracture_stabilization = 1) for the "
                    "rest of the run and solving the step again", t, s.noise[-1],
                    s.noise[-1] / s.pnorm)
        return True

    def _set_fracture_stabilization(self, factor: float) -> None:
        self.beta_f = self._fracture_fixed_stress(factor)
        self.flow.set_properties(replace(self.flow.properties, fracture_storage=self.beta_f))

    def _sync_state(self) -> None:
        """Make u and the Darcy state those of ``g`` at the final iterate (one more g if not)."""
        if self._failure is not None:
            return
        self._last_eval.axpy(-1.0, self.P)
        stale = self._last_eval.norm(PETSc.NormType.NORM_INFINITY) > 0.0
        if stale:
            self.g(*self._split(self.P))

    def accept(self, t: float) -> None:
        """The step's porosity, aperture and displacement become the references."""
        self.mech.accept(t)
        if self._step is not None:
            self.porosity_prev = self.flow.porosity(self._step)
        self.aperture_prev = (self.flow.properties.aperture if self._step is None
                              else self.flow.fracture_volume(self._step)).copy()
        self._accepted_p = self.flow.p.copy()
        self.history = [*self.history[-1:], (t, self._pressures())]
        self._accepted_start = self._contact_start

    def reject(self) -> None:
        """Back to the last accepted state."""
        self.mech.reject()
        self._contact_start = self._accepted_start
        self.flow.p[:] = self._accepted_p
        self.flow._write_guess()
        self.flow.set_aperture(self.aperture_prev)

    def progress(self, k: int, n: int, t: float, result: StepResult) -> str:
        """One line per step: fixed-point and inner iteration counts."""
        r = result.record
        res = r["residuals"] or [float("nan")]
        face = f", face Newton {r['face_iterations']} it" if r["face_iterations"] else ""
        return (f"step {k + 1}/{n} t={t:g} s: {r['reason']} in {r['iterations']} it, "
                f"{r['g_evaluations']} g evaluations (|p - g(p)| {res[0]:.2e} -> {res[-1]:.2e}"
                f"{', the noise of g' if r['converged_at_noise'] else ''}"
                f"{', by the fallback ' + r['method'] if r['fallback_from'] is not None else ''}); "
                f"contact Newton {r['newton_iterations']} it{face}, {r['factorizations']} "
                f"factorizations; Darcy {r['darcy_iterations']} it")

    # -- output ----------------------------------------------------------------------------
    def open_output(self, outdir: Path, resume_until: float | None = None) -> None:
        """Mechanics writers (with ``p_f`` and ``aperture`` on the fractures) and flow.xdmf."""
        self.mech.open_output(outdir, resume_until, fracture_columns=("p_f", "aperture"))
        if self.scene.output.xdmf:
            with self.timer.phase("output"):
                self.writer = FlowWriter(self.flow, Path(outdir), fracture_file=None,
                                         resume_until=resume_until)

    def write(self, t: float) -> None:
        """Displacement, fracture fields with pressure and aperture, matrix flow fields."""
        pb = self.flow
        self.mech.write(t, {"p_f": pb.fracture_pressure, "aperture": pb.properties.aperture})
        if self.writer is not None:
            porosity = self.porosity_prev if self._step is None else pb.porosity(self._step)
            with self.timer.phase("output"):
                self.writer.write(t, compute_fluxes(pb), {
                    "overpressure": pb.cell_pressure - self.p0_cells, "porosity": porosity})

    def finish(self, summary: dict) -> None:
        """Totals of the fixed point and the flow report."""
        self.mech.finish(summary)
        keys = ("g_evaluations", "iterations", "newton_iterations", "face_iterations",
                "factorizations", "darcy_iterations", "darcy_solves")
        done = [r for r in self.records if "g_evaluations" in r]
        summary["coupling"] = {
            "method": self.scene.coupling.method,
            "rtol": self.scene.coupling.rtol,
            **{k: int(sum(r.get(k, 0) for r in done)) for k in keys},
            "mechanics_seconds": float(sum(r["mechanics_seconds"] for r in done)),
            "darcy_seconds": float(sum(r["darcy_seconds"] for r in done)),
            "fracture_stabilization_from": self.fracture_stabilization_from,
        }
        summary["flow"] = flow_report(self.flow, [])

    # -- checkpoint ------------------------------------------------------------------------
    def state(self) -> dict:
        """Displacement, pressures, porosity, aperture and the extrapolation history."""
        out = {**self.mech.state(), **flow_state(self.flow, self.porosity_prev,
                                                  self.aperture_prev)}
        cells = flow_state(self.flow, None, None)["p_cell"][0]
        out["divergence0"] = (cells, self.div0)
        if len(self.history) > 1:
            t0, p0 = self.history[-2]
            out["p_cell_previous"] = (cells, p0[: self.nc])
            out["p_fracture_previous"] = (self.fm.fractures.index.astype(np.int64),
                                          p0[self.nc:])
            out["time_previous"] = scalar_row(self.comm, t0)
        out["time_current"] = scalar_row(self.comm, self.history[-1][0])
        if self.fracture_stabilization_from is not None:
            out["fracture_stabilization_from"] = scalar_row(self.comm,
                                                            self.fracture_stabilization_from)
        return out

    def restore(self, arrays: dict, t: float) -> None:
        """Continue after the step ending at ``t`` (the initial state is not solved again)."""
        pb, fm = self.flow, self.fm
        pb.set_pressure(self.scene.flow.initial_pressure, 0.0)
        self.p0_cells = pb.cell_pressure.copy()
        self.mech.restore(arrays, t)
        restore_pressure(pb, arrays)
        cells = flow_state(pb, None, None)["p_cell"][0]
        self.div0 = arrays["divergence0"][cells]
        self.porosity_prev = arrays["porosity"][cells]
        self.aperture_prev = arrays["aperture"][fm.fractures.index]
        pb.set_aperture(self.aperture_prev)
        self._accepted_p = pb.p.copy()
        self.history = []
        if "time_previous" in arrays:
            previous = np.concatenate([arrays["p_cell_previous"][cells],
                                       arrays["p_fracture_previous"][fm.fractures.index]])
            self.history.append((float(arrays["time_previous"][0]), previous))
        self.history.append((float(arrays["time_current"][0]), self._pressures()))
        # the contact state of the last step (at its output pressures: its input ones are not
        # kept, and differ by the fixed-point tolerance)
        self._contact_start = self._accepted_start = self._contact_state(
            pb.cell_pressure, pb.fracture_pressure)
        if "fracture_stabilization_from" in arrays and self._auto_fracture_stabilization:
            self._set_fracture_stabilization(1.0)
            self.fracture_stabilization_from = float(arrays["fracture_stabilization_from"][0])

    def close(self) -> None:
        """Free the PETSc objects."""
        for obj in (self.snes, self.P, self.R, self._last_eval):
            obj.destroy()
        if self._fallback_snes is not None:
            self._fallback_snes[0].destroy()
        self.flow.destroy()
        self.mech.close()


_REASONS = {v: k for k, v in vars(PETSc.SNES.ConvergedReason).items() if not k.startswith("_")}


class _Counters:
    """Work done in one step of the fixed point (identical on every rank)."""

    def __init__(self) -> None:
        self.evaluations = 0
        self.iterations = 0  # fixed-point iterations, over every attempt of the step
        self.newton = []
        self.face = 0  # iterations of the condensed face Newton (poromech.mechanics.condensed)
        self.factorizations = 0
        self.stale = 0
        self.darcy_iterations = 0
        self.darcy_solves = 0
        self.mechanics_seconds = 0.0
        self.darcy_seconds = 0.0
        self.residuals: list[float] = []
        self.noise: list[float] = []  # estimates of the noise of g, at stagnating iterations
        self.at_noise = False  # converged at the noise of g rather than at the tolerance
        self.pnorm = np.nan  # |p| when the noise was last estimated
        self.clamped = 0

    @property
    def untrusted(self) -> bool:
        """Whether the last noise estimate exceeded :data:`NOISE_LIMIT` ``|p|``."""
        return bool(self.noise) and not self.noise[-1] <= NOISE_LIMIT * self.pnorm

    def add_newton(self, *recs) -> None:
        """The contact solves of one ``g`` (more than one after a continuation)."""
        self.newton.append(sum(r.iterations for r in recs))
        self.factorizations += sum(r.factorizations for r in recs)
        self.stale += sum(r.stale_solves for r in recs)
        self.face += sum(r.face_iterations for r in recs)

    def record(self, reason: str, converged: bool, iterations: int, seconds: float) -> dict:
        return {
            "reason": reason,
            "converged": converged,
            "iterations": iterations,
            "g_evaluations": self.evaluations,
            "residuals": self.residuals,
            "newton_iterations": int(sum(self.newton)),
            "newton_per_evaluation": self.newton,
            "face_iterations": self.face,
            "factorizations": self.factorizations,
            "stale_solves": self.stale,
            "darcy_iterations": self.darcy_iterations,
            "darcy_solves": self.darcy_solves,
            "mechanics_seconds": self.mechanics_seconds,
            "darcy_seconds": self.darcy_seconds,
            "solve_seconds": seconds,
            "clamped_apertures": self.clamped,
            "g_noise": self.noise,
            "converged_at_noise": self.at_noise,
        }
