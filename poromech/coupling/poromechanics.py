"""Coupled poromechanics (``physics: poromechanics``): Biot + contact + HFV flow, by fixed point.

The quasi-static model of Beaude et al. (2023, §3), implicit Euler in time. Each step solves the
fixed point ``p = g(p)`` on the matrix cell pressures and fracture face pressures
``p = (p_m, p_f)``:

* contact mechanics at the given pressures (semi-smooth Newton, warm-started): total stress
  ``σ(u) - b p_m I``, fracture pressure ``p_f`` on both faces, contact conditions on the
  effective traction ``T = (σ(u) - b p_m I) n⁺ + p_f n⁺``;
* Darcy (HFV) at the resulting porosity ``φ = φ⁰ + b (div u - div u⁰) + (p_m - p⁰)/M`` and
  aperture ``d_f = d₀ - [[u]]_n`` (conductivity ``d_f³/12`` by default).

:class:`Poromechanics` composes the mechanics physics (:mod:`poromech.mechanics.physics`), the
Darcy problem with its accepted state (:mod:`poromech.flow.state`), the fixed point
(:mod:`poromech.coupling.fixed_point`: Anderson by default, stopped at ``|F| <= rtol |F₀|``, 1e-5
as in the paper), the fixed-stress terms (:mod:`poromech.coupling.fixed_stress`) and the
continuation of failed contact solves (:class:`ContactContinuation`). The initial state is the
mechanical equilibrium under ``p⁰`` and the boundary data at ``t = 0``; ``u⁰`` and ``d(u⁰)`` are
the references of porosity and aperture.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import dolfinx_solver  # noqa: F401

import numpy as np
import numpy.typing as npt
from mpi4py import MPI
from petsc4py import PETSc

from poromech.coupling.fixed_point import STALL_ITERATIONS, EvaluationFailure, FixedPoint
from poromech.coupling.fixed_stress import (
    FixedStress,
    fracture_fixed_stress,
    matrix_fixed_stress,
)
from poromech.errors import SolverError
from poromech.flow.balance import compute_fluxes, mass_balance
from poromech.flow.output import FlowWriter
from poromech.flow.physics import MASS_BALANCE_FAIL, flow_report, pressure_columns
from poromech.flow.problem import TimeStep
from poromech.flow.setup import (
    check_pressure_level,
    flow_properties,
    problem_from_scene,
    time_dependent,
)
from poromech.flow.state import FlowState
from poromech.io.checkpoint import scalar_row
from poromech.mechanics.model import PressureCoupling
from poromech.mechanics.newton import NewtonRecord, quoted_history
from poromech.mechanics.physics import MechanicsPhysics
from poromech.mechanics.predictor import extrapolated
from poromech.mesh.entities import input_cells
from poromech.mesh.fractured import FracturedMesh
from poromech.physics import Keyed, StepResult
from poromech.scene.schema import Scene
from poromech.timing import Timer

__all__ = ["APERTURE_FLOOR", "CONTINUATION_STEPS", "ContactContinuation", "Poromechanics"]

log = logging.getLogger("poromech")

Array = npt.NDArray[np.float64]

#: A contact solve that fails inside ``g`` is solved again from the last pressures it converged
#: at, in this many equal steps of pressure, before ``g`` fails: the extrapolated pressures of
#: an accelerated iterate can open a whole fracture at once, where pointwise Nitsche's Newton
#: stalls (injection scene: the step to 40 s was cut four times and cost 176 g).
CONTINUATION_STEPS = 2

#: Smallest aperture, relative to d₀, kept when ``d₀ - [[u]]_n`` would close a face entirely
#: (interpenetration within the contact tolerance); the faces clamped are counted.
APERTURE_FLOOR = 1e-3


class ContactContinuation:
    """The last converged contact solve, and the contact problem solved again from it.

    Keeps the input pressures and the contact unknowns of the last converged solve inside
    ``g`` (and those of the accepted state). :meth:`solve` restores them and raises the pressures
    to the new ones in :data:`CONTINUATION_STEPS` equal steps, each solve starting from the last,
    stopping at the first that fails. ``g`` is unchanged where the solution is unique: only the
    Newton's start differs.

    Args:
        mech: The mechanics physics whose contact problem is solved.
    """

    def __init__(self, mech: MechanicsPhysics):
        self.mech = mech
        self._start: tuple | None = None
        self._accepted: tuple | None = None

    @property
    def available(self) -> bool:
        """Whether a converged contact solve is known to start from."""
        return self._start is not None

    def remember(self, p_m: Array, p_f: Array) -> None:
        """The contact unknowns were just solved at pressures ``(p_m, p_f)``."""
        self._start = p_m.copy(), p_f.copy(), [f.x.array.copy() for f in self.mech.model.unknowns]

    def accept(self) -> None:
        """The last converged solve belongs to the accepted state."""
        self._accepted = self._start

    def reject(self) -> None:
        """Back to the converged solve of the accepted state."""
        self._start = self._accepted

    def reset(self, p_m: Array, p_f: Array) -> None:
        """Both the current and the accepted start are the unknowns at ``(p_m, p_f)``."""
        self.remember(p_m, p_f)
        self.accept()

    def solve(self, p_m: Array, p_f: Array, min_iterations: int) -> list[NewtonRecord]:
        """Solve the contact problem at ``(p_m, p_f)`` by continuation; the Newton records."""
        q_m, q_f, unknowns = self._start
        log.debug("contact Newton failed inside g: continuation from the last converged "
                  "pressures in %d steps", CONTINUATION_STEPS)
        model = self.mech.model
        for f, a in zip(model.unknowns, unknowns, strict=True):
            f.x.array[:] = a
        recs = []
        for k in range(1, CONTINUATION_STEPS + 1):
            w = k / CONTINUATION_STEPS
            model.set_pressures(q_m + w * (p_m - q_m), q_f + w * (p_f - q_f))
            recs.append(self.mech.solve_contact(min_iterations))
            if not recs[-1].converged:
                break
        return recs


@dataclass
class _Work:
    """What the evaluations of ``g`` did in one step (identical on every rank)."""

    evaluations: int = 0
    newton: list[int] = field(default_factory=list)
    face: int = 0  # iterations of the condensed face Newton (poromech.mechanics.condensed)
    factorizations: int = 0
    stale: int = 0
    darcy_iterations: int = 0
    darcy_solves: int = 0
    mechanics_seconds: float = 0.0
    darcy_seconds: float = 0.0
    clamped: int = 0

    def add_newton(self, *recs: NewtonRecord) -> None:
        """The contact solves of one ``g`` (more than one after a continuation)."""
        self.newton.append(sum(r.iterations for r in recs))
        self.factorizations += sum(r.factorizations for r in recs)
        self.stale += sum(r.stale_solves for r in recs)
        self.face += sum(r.face_iterations for r in recs)


class Poromechanics:
    """The coupled problem of a scene as a :class:`~poromech.physics.Physics` (collective).

    Args:
        scene: The scene (``physics: poromechanics``).
        fm: The fractured mesh.
        timer: Wall-time accounting.
    """

    counters = ("iterations", "g_evaluations", "newton_iterations", "face_iterations",
                "factorizations", "stale_solves", "darcy_iterations", "darcy_solves",
                "mechanics_seconds", "darcy_seconds", "solve_seconds")
    records_section = None

    def __init__(self, scene: Scene, fm: FracturedMesh, timer: Timer):
        self.scene, self.fm, self.timer, self.comm = scene, fm, timer, fm.comm
        self.writes_initial_state = True
        relative = scene.material.initial_stress is not None  # σ⁰ holds p⁰'s share already
        self.mech = MechanicsPhysics(scene, fm, timer,
                                     PressureCoupling(scene.material.biot, relative))
        self.model = self.mech.model
        with timer.phase("flow_setup"):
            self.flow = problem_from_scene(scene, fm)
            self.flow.solver.lagged = True  # the aperture changes the matrix a little per g
        self.accepted = FlowState(self.flow)
        self.biot = scene.material.biot
        self.porosity0 = scene.flow.porosity
        self.nc, self.nf = self.flow.geom.num_cells, len(fm.fractures.facets)
        self.nf_global = self.comm.allreduce(self.nf)
        self._d0_varies = time_dependent(scene)
        self.d0 = self.flow.properties.aperture.copy()
        self.storage = self.flow.properties.storage.copy()  # 1/M, the physical storage
        self.fixed_stress = self._fixed_stress()
        if self.comm.allreduce(self.fixed_stress.active, op=MPI.LOR):
            self.flow.set_properties(replace(self.flow.properties,
                                             storage=self.storage + self.fixed_stress.beta,
                                             fracture_storage=self.fixed_stress.beta_f))
        check_pressure_level(scene, self.flow)
        self.fixed_point = FixedPoint(self.comm, self.nc + self.nf, self.g,
                                      self._darcy_noise, scene.coupling)
        self.continuation = ContactContinuation(self.mech)
        self.writer: FlowWriter | None = None
        self._work = _Work()
        self._step: TimeStep | None = None
        self.t, self.dt = 0.0, None
        self._min_iterations = 0  # of every contact solve in the current attempt
        # the last attempt failed: the next one is a cut sub-step of the same state (a converged
        # attempt clears it, and only converged attempts are accepted)
        self._failed_since_accept = False
        self.history: list[tuple[float, Array]] = []  # accepted (t, p) for extrapolation
        self._warned_balance = False  # a step held the mass balance only to > MASS_BALANCE_FAIL
        self._warned_porosity = False  # an accepted porosity was negative

    # -- set-up --------------------------------------------------------------------------------
    def _moduli(self, x: Array) -> tuple[Array, Array]:
        """Young's modulus (Pa) and Poisson's ratio of the scene at points ``x`` at t = 0."""
        m = self.scene.material
        return m.young(x, 0.0), m.poisson(x, 0.0)

    def _fixed_stress(self) -> FixedStress:
        """The fixed-stress terms of the scene's ``coupling`` (none for a steady scene)."""
        c, steady = self.scene.coupling, self.scene.time is None
        if c.stabilization == 0 or self.biot == 0 or steady:  # steady: no storage
            beta = np.zeros(self.nc)
        else:
            young, nu = self._moduli(self.flow.geom.centroid)
            beta = matrix_fixed_stress(c.stabilization, self.biot, young, nu,
                                       self.fm.msh.geometry.dim)
        fracture = None
        if self.nf_global > 0 and not steady:
            f, geo = self.fm.fractures, self.fm.geometry
            if geo.dim == 3:  # the radius of the disc of the same area
                size = np.sqrt(np.array([fr.area for fr in geo.fractures]) / np.pi)
            else:
                size = 0.5 * geo.fracture_lengths()
            half = size[f.fracture]
            young_f, nu_f = self._moduli(f.midpoint)

            def fracture(factor: float) -> Array:
                return fracture_fixed_stress(factor, half, young_f, nu_f, geo.dim)

        return FixedStress(beta, fracture, c.fracture_stabilization)

    # -- the fixed-point map -------------------------------------------------------------------
    def _split(self, p: Array) -> tuple[Array, Array]:
        return p[: self.nc], p[self.nc:]

    def g(self, p: Array) -> Array:
        """One evaluation of the fixed-point map: mechanics at ``p``, then Darcy (collective).

        Args:
            p: ``(p_m, p_f)`` on the owned cells and fracture faces (Pa), concatenated.

        Returns:
            The new ``(p_m, p_f)``, concatenated.

        Raises:
            EvaluationFailure: The contact or the Darcy solve failed.
        """
        p_m, p_f = self._split(p)
        w = self._work
        w.evaluations += 1
        t0 = time.perf_counter()
        self.model.set_pressures(p_m, p_f)
        recs = [self.mech.solve_contact(self._min_iterations)]
        if not recs[0].converged and self.continuation.available:
            recs += self.continuation.solve(p_m, p_f, self._min_iterations)
        rec = recs[-1]
        w.add_newton(*recs)
        t1 = time.perf_counter()
        w.mechanics_seconds += t1 - t0
        if not rec.converged:
            first = recs[0]
            what = "contact Newton" if self.model.params.active else "mechanics solve"
            linear = f" ({first.linear_failure})" if first.linear_failure else ""
            raise EvaluationFailure(
                f"{what} did not converge inside the fixed point: {first.reason} after "
                f"{first.iterations} iterations{linear}; residual history "
                + quoted_history(first.residuals)
                + (f"; nor by continuation from the last converged pressures ({rec.reason} after "
                   f"{rec.iterations} iterations)" if len(recs) > 1 else ""))
        self.continuation.remember(p_m, p_f)
        self._update_flow(p_m, p_f)
        try:
            with self.timer.phase("flow_solve"):
                lin = self.flow.solve(self.t, self._step)
        except SolverError as err:
            raise EvaluationFailure(f"Darcy solve failed inside the fixed point: {err}") from None
        w.darcy_iterations += lin.iterations
        w.darcy_solves += 1
        w.darcy_seconds += time.perf_counter() - t1
        return np.concatenate([self.flow.cell_pressure, self.flow.fracture_pressure])

    def _aperture(self) -> tuple[Array, int]:
        """The aperture ``d₀ - [[u]]_n``, at least :data:`APERTURE_FLOOR` ``d₀``; faces clamped.

        Collective (the count is global).
        """
        d, floor = self.d0 - self._jump_n(), APERTURE_FLOOR * self.d0
        return np.maximum(d, floor), int(self.comm.allreduce(int(np.count_nonzero(d < floor))))

    def _jump_n(self) -> Array:
        return self.model.face_fields()["jump_n"]  # collective: also on ranks owning no face

    def _update_flow(self, p_in: Array, pf_in: Array) -> None:
        """Aperture and porosity from the current displacement, into the Darcy problem.

        ``p_in`` and ``pf_in`` are the input pressures of ``g``, the centres of the fixed-stress
        terms.
        """
        aperture, self._work.clamped = self._aperture()
        self.flow.set_aperture(aperture)
        fs = self.fixed_stress
        fixed = self.porosity0 + self.biot * (self.model.cell_divergence() - self.div0) \
            - self.storage * self.p0_cells - fs.beta * p_in
        aperture_fixed = None
        if fs.beta_f is not None:
            aperture_fixed = self.flow.properties.aperture - fs.beta_f * pf_in
        self._step = TimeStep(self.dt, self.accepted.porosity, fixed, self.accepted.aperture,
                              aperture_fixed) if self.dt is not None else None

    def _darcy_noise(self) -> float:
        """Forward error of the last Darcy solve (one refinement step), a global norm."""
        e_m, e_f = self.flow.solve_error()
        return float(np.sqrt(self.comm.allreduce(e_m @ e_m + e_f @ e_f)))

    # -- Physics interface -----------------------------------------------------------------
    def describe(self) -> dict:
        """Discretization and sizes, for the summary."""
        return {**self.mech.describe(), "flow_unknowns": self.flow.dofs.num_global,
                "coupling_method": self.fixed_point.method,
                "coupling_unknowns": int(self.fixed_point.N)}

    def initialize(self) -> dict:
        """Mechanical equilibrium under ``p⁰`` at ``t = 0``: the reference state."""
        pb = self.flow
        pb.set_pressure(self.scene.flow.initial_pressure, 0.0)
        self.p0_cells = pb.cell_pressure.copy()
        self.model.set_reference_pressure(self.p0_cells)
        self.mech.begin_step(0.0)
        self.model.set_pressures(pb.cell_pressure, pb.fracture_pressure)
        self.model.start_face_unknowns()
        rec = self.mech.solve_contact()
        if not rec.converged:
            linear = f" ({rec.linear_failure})" if rec.linear_failure else ""
            raise SolverError(
                f"the initial mechanical equilibrium under p⁰ did not converge: {rec.reason} "
                f"after {rec.iterations} iterations{linear}", rec.reason, rec.residuals,
                rec.as_dict())
        self.div0 = self.model.cell_divergence()
        aperture, clamped = self._aperture()
        pb.set_aperture(aperture)
        self._step = None
        self.mech.accept(0.0)
        self.accepted.accept(np.full(self.nc, self.porosity0), aperture)
        self.history = [(0.0, self._pressures())]
        self.continuation.reset(pb.cell_pressure, pb.fracture_pressure)
        # the condensed mixed solve counts its work as face Newton iterations (0 regular ones)
        face = f" (+{rec.face_iterations} face Newton)" if rec.face_iterations else ""
        log.info("initial equilibrium under p0: %d Newton iterations%s%s", rec.iterations, face,
                 f"; {clamped} fracture faces closing below {APERTURE_FLOOR:g} d0 keep that "
                 "aperture" if clamped else "")
        return {"iterations": rec.iterations, "face_iterations": rec.face_iterations,
                "reason": rec.reason, "clamped_apertures": clamped}

    def _pressures(self) -> Array:
        return np.concatenate([self.flow.cell_pressure, self.flow.fracture_pressure])

    def _guess(self, t: float) -> Array:
        """Initial fixed-point iterate: the last pressures, linearly extrapolated in time.

        Not over a step far longer than the last one, nor where the extrapolation is not finite
        (:func:`~poromech.mechanics.predictor.extrapolated`, a collective choice).
        """
        (t1, p1) = self.history[-1]
        if not self.scene.coupling.extrapolate or len(self.history) < 2:
            return p1
        t0, p0 = self.history[-2]
        values = extrapolated(t, (t0, [p0]), (t1, [p1]), self.comm)
        return p1 if values is None else values[0]

    def solve(self, t: float, dt: float | None) -> StepResult:
        """The fixed point of the step ending at ``t``.

        A failed attempt is repeated with the fracture fixed-stress term switched on when the
        Darcy solve was not to be trusted (automatic mode), then with the fallback method
        (once per accepted state; not after a failed inner solve), before the step is cut.
        """
        self.t, self.dt = t, dt
        if self._d0_varies:
            self.d0 = flow_properties(self.scene, self.fm, self.flow.geom, t).aperture
        self.mech.begin_step(t)
        self._work = _Work()
        fp = self.fixed_point
        fp.start_step()
        t0 = time.perf_counter()
        method = fp.method
        reason = self._attempt(t, method, retry=False)
        if reason <= 0 and self._switch_on_fracture_stabilization(t, reason):
            reason = self._attempt(t, method)
        fallback_from = None
        # only for a failure of the iteration itself: not of an inner solve (a step cut answers
        # that), nor of a g made ill-posed by an untrustworthy Darcy solve; and once per accepted
        # state: when the fallback fails too, the cut sub-steps go without it
        if (reason <= 0 and fp.fallback is not None and fp.failure is None
                and not fp.stats.untrusted and not self._failed_since_accept):
            log.warning("the coupled fixed point did not converge at t = %g s with %s (%s after "
                        "%d g evaluations); solving the step again with %s", t, method,
                        fp.reason_name(reason), self._work.evaluations, fp.fallback)
            fallback_from = len(fp.stats.residuals)
            method = fp.fallback
            reason = self._attempt(t, method, fallback=True)
        fp.sync()
        record = self._record(reason, self.comm.allreduce(time.perf_counter() - t0, op=MPI.MAX))
        record["method"] = method
        record["fallback_from"] = fallback_from
        self._failed_since_accept = reason <= 0
        if reason > 0:
            record["mass_balance"] = balance = mass_balance(self.flow, compute_fluxes(self.flow),
                                                            t, self._step)
            if balance["relative_residual"] > MASS_BALANCE_FAIL and not self._warned_balance:
                self._warned_balance = True  # the records keep every step's value
                log.warning(
                    "the step to t = %g s holds the mass balance only to %.3g of the flow (more "
                    "than %g; summary.json has every step's): %s", t,
                    balance["relative_residual"], MASS_BALANCE_FAIL,
                    "it was accepted at the noise of g (the Darcy solves' error), "
                    "coupling.fracture_stabilization or shorter steps may do better"
                    if record.get("converged_at_noise") else "the fixed point's tolerance "
                    "(coupling.rtol, coupling.atol) is looser than the flow needs")
            return StepResult(True, record)
        s = fp.stats
        why = fp.failure or (f"{fp.reason_name(reason)} after "
                             f"{fp.iterations_of(fallback_from is not None)} iterations of "
                             f"{method}")
        if fp.stalled is not None and fp.failure is None:
            why += f" (the best |p - g(p)| was not halved in its last {STALL_ITERATIONS})"
        if s.noise and fp.failure is None:
            why += f" (estimated error of the Darcy solve {s.noise[-1]:.2e}, {s.relative_noise})"
            if s.untrusted and self.scene.coupling.fracture_stabilization == 0:
                why += (" — the Darcy problem in g is nearly singular (sealed fractures?): set "
                        "coupling.fracture_stabilization to null or a factor > 0")
        message = (f"the coupled fixed point did not converge at t = {t:g} s: {why}; "
                   "|p - g(p)| history " + quoted_history(s.residuals))
        return StepResult(False, record, message, fp.reason_name(reason), list(s.residuals))

    def _attempt(self, t: float, method: str, retry: bool = True, fallback: bool = False) -> int:
        """Solve the step's fixed point from the extrapolated pressures; PETSc's reason.

        A ``retry`` first restores the state of the last accepted step.
        """
        if retry:
            self.reject()
        # finite differences of g need u to respond to tiny changes of p: the contact Newton
        # takes at least one step even when its residual is already below the tolerance
        self._min_iterations = int(method == "newtonkrylov")
        self.flow.solver.refresh()  # the Darcy preconditioner is lagged within an attempt only
        return self.fixed_point.attempt(self._guess(t), fallback)

    def _record(self, reason: int, seconds: float) -> dict:
        """The step record: fixed-point statistics and the work of its ``g`` evaluations."""
        s, w = self.fixed_point.stats, self._work
        return {
            # accepted at the estimated error of g: not PETSc's reason (FNORM_ABS), which the
            # tolerance coupling.atol was not reached for
            "reason": ("CONVERGED_AT_NOISE" if reason > 0 and s.at_noise
                       else self.fixed_point.reason_name(reason)),
            "converged": reason > 0,
            "iterations": s.iterations,
            "g_evaluations": w.evaluations,
            "residuals": s.residuals,
            "newton_iterations": int(sum(w.newton)),
            "newton_per_evaluation": w.newton,
            "face_iterations": w.face,
            "factorizations": w.factorizations,
            "stale_solves": w.stale,
            "darcy_iterations": w.darcy_iterations,
            "darcy_solves": w.darcy_solves,
            "mechanics_seconds": w.mechanics_seconds,
            "darcy_seconds": w.darcy_seconds,
            "solve_seconds": seconds,
            "clamped_apertures": w.clamped,
            "g_noise": s.noise,
            "converged_at_noise": s.at_noise,
        }

    def _switch_on_fracture_stabilization(self, t: float, reason: int) -> bool:
        """Switch ``β_f`` on (factor 1) after a failure that the fracture storage explains.

        Only with ``coupling.fracture_stabilization: null``, fractures and time steps, once per
        run, after an attempt that failed (PETSc's ``reason``) either

        * with an untrustworthy Darcy solve: its estimated error in ``g`` exceeds
          :data:`~poromech.coupling.fixed_point.NOISE_LIMIT` ``|p|`` (fractures sealed by a
          nearly impervious matrix: without fracture storage their pressure is nearly
          undetermined); or
        * by divergence (``DIVERGED_DTOL``: ``|p - g(p)|`` grew by
          :data:`~poromech.coupling.fixed_point.DIVERGENCE`): ``g`` is expansive, as where a
          step is so short that the fractures' volume change over it dominates their balance
          (the six-fracture scene with a first step of 1e-6 s went 2.2e5 → 7.2e12 Pa at every
          cut; with ``β_f`` it converges).

        ``β_f`` changes ``g``, not its fixed point (collective).
        """
        fs, fp = self.fixed_stress, self.fixed_point
        if not fs.can_switch_on() or not self.flow.records:
            return False
        s = fp.stats
        if not s.noise:
            fp.estimate_noise()
        diverged = reason == PETSc.SNES.ConvergedReason.DIVERGED_DTOL and fp.failure is None
        if not (s.untrusted or diverged):
            return False
        self._set_fracture_stabilization(t)
        if s.untrusted:
            why = (f"the Darcy solve inside g is not to be trusted at t = {t:g} s (estimated "
                   f"error {s.noise[-1]:.2e}, {s.relative_noise}: fractures sealed by the "
                   "matrix?)")
        else:
            why = (f"|p - g(p)| diverged at t = {t:g} s (g expansive: the fractures' storage "
                   "dominates a short step?)")
        log.warning("%s; switching on the fracture fixed-stress term "
                    "(coupling.fracture_stabilization = 1) for the rest of the run and solving "
                    "the step again", why)
        return True

    def _set_fracture_stabilization(self, t: float) -> None:
        self.fixed_stress.switch_on(t)
        self.flow.set_properties(replace(self.flow.properties,
                                         fracture_storage=self.fixed_stress.beta_f))

    def accept(self, t: float) -> None:
        """The step's porosity, aperture and displacement become the references."""
        self.mech.accept(t)
        pb, step = self.flow, self._step
        porosity = None if step is None else pb.porosity(step)
        self.accepted.accept(porosity, (pb.properties.aperture if step is None
                                        else pb.fracture_volume(step)).copy())
        # without flow.porosity (φ⁰ = 0) the written porosity is its change, negative wherever
        # the rock compacts: nothing to warn of (the storage uses the changes only)
        if (porosity is not None and not self._warned_porosity
                and self.scene.flow.porosity > 0):
            least = self.comm.allreduce(float(porosity.min(initial=np.inf)), op=MPI.MIN)
            if least < 0:
                self._warned_porosity = True
                log.warning("the porosity is negative at t = %g s (%.3g): the linearized "
                            "φ = φ⁰ + b ∇·(u - u⁰) + (p - p⁰)/M has left its physical range "
                            "there (flow.porosity, flow.biot_modulus?)", t, least)
        self.history = [*self.history[-1:], (t, self._pressures())]
        self.continuation.accept()

    def reject(self) -> None:
        """Back to the last accepted state."""
        self.mech.reject()
        self.continuation.reject()
        self.accepted.reject()
        self.flow.set_aperture(self.accepted.aperture)

    def progress(self, k: int, n: int, t: float, result: StepResult) -> str:
        """One line per step: fixed-point and inner iteration counts."""
        r = result.record
        res = r["residuals"] or [float("nan")]
        face = f", face Newton {r['face_iterations']} it" if r["face_iterations"] else ""
        # without contact conditions the mechanics is linear: no contact Newton to speak of
        what = "contact Newton {} it" if self.model.params.active else "mechanics {} solves"
        return (f"step {k + 1}/{n} t={t:g} s: {r['reason']} in {r['iterations']} it, "
                f"{r['g_evaluations']} g evaluations (|p - g(p)| {res[0]:.2e} -> {res[-1]:.2e}"
                f"{', the noise of g' if r['converged_at_noise'] else ''}"
                f"{', by the fallback ' + r['method'] if r['fallback_from'] is not None else ''}); "
                f"{what.format(r['newton_iterations'])}{face}, {r['factorizations']} "
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
        porosity = self.accepted.porosity if self._step is None else pb.porosity(self._step)

        def pressures(probe, sampler) -> dict:
            return {**pressure_columns(pb, probe, sampler), "porosity": sampler.cells(porosity)}

        self.mech.write(t, {"p_f": pb.fracture_pressure, "aperture": pb.properties.aperture},
                        pressures)
        if self.writer is not None:
            with self.timer.phase("output"):
                self.writer.write(t, compute_fluxes(pb), {
                    "overpressure": pb.cell_pressure - self.p0_cells, "porosity": porosity})

    def finish(self, summary: dict, records: list[dict]) -> None:
        """Totals of the fixed point and the flow report."""
        self.mech.finish(summary, records)
        keys = ("g_evaluations", "iterations", "newton_iterations", "face_iterations",
                "factorizations", "darcy_iterations", "darcy_solves")
        done = [r for r in records if "g_evaluations" in r]
        summary["coupling"] = {
            "method": self.fixed_point.method,
            "rtol": self.scene.coupling.rtol,
            **{k: int(sum(r.get(k, 0) for r in done)) for k in keys},
            "mechanics_seconds": float(sum(r["mechanics_seconds"] for r in done)),
            "darcy_seconds": float(sum(r["darcy_seconds"] for r in done)),
            "fracture_stabilization_from": self.fixed_stress.switched_on_at,
        }
        summary["flow"] = flow_report(self.flow, done, iterations="darcy_iterations",
                                      seconds="darcy_seconds")

    # -- checkpoint ------------------------------------------------------------------------
    def state(self) -> dict[str, Keyed]:
        """Displacement, pressures, porosity, aperture and the extrapolation history."""
        out = {**self.mech.state(), **self.accepted.checkpoint()}
        cells = input_cells(self.fm.msh)
        out["divergence0"] = (cells, self.div0)
        if len(self.history) > 1:
            t0, p0 = self.history[-2]
            out["p_cell_previous"] = (cells, p0[: self.nc])
            out["p_fracture_previous"] = (self.fm.fractures.index.astype(np.int64),
                                          p0[self.nc:])
            out["time_previous"] = scalar_row(self.comm, t0)
        out["time_current"] = scalar_row(self.comm, self.history[-1][0])
        if self.fixed_stress.switched_on_at is not None:
            out["fracture_stabilization_from"] = scalar_row(self.comm,
                                                            self.fixed_stress.switched_on_at)
        return out

    def restore(self, arrays: dict, t: float) -> None:
        """Continue after the step ending at ``t`` (the initial state is not solved again)."""
        pb, fm = self.flow, self.fm
        pb.set_pressure(self.scene.flow.initial_pressure, 0.0)
        self.p0_cells = pb.cell_pressure.copy()
        self.model.set_reference_pressure(self.p0_cells)
        self.mech.restore(arrays, t)
        self.accepted.restore(arrays)
        cells = input_cells(fm.msh)
        self.div0 = arrays["divergence0"][cells]
        pb.set_aperture(self.accepted.aperture)
        self.accepted.accept(None, None)  # the pressures as the aperture left them
        self.history = []
        if "time_previous" in arrays:
            previous = np.concatenate([arrays["p_cell_previous"][cells],
                                       arrays["p_fracture_previous"][fm.fractures.index]])
            self.history.append((float(arrays["time_previous"][0]), previous))
        self.history.append((float(arrays["time_current"][0]), self._pressures()))
        # the contact state of the last step (at its output pressures: its input ones are not
        # kept, and differ by the fixed-point tolerance)
        self.continuation.reset(pb.cell_pressure, pb.fracture_pressure)
        if "fracture_stabilization_from" in arrays and self.fixed_stress.can_switch_on():
            self._set_fracture_stabilization(float(arrays["fracture_stabilization_from"][0]))

    def close(self) -> None:
        """Free the PETSc objects."""
        self.fixed_point.destroy()
        self.flow.destroy()
        self.mech.close()
