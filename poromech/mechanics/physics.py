"""The contact-mechanics physics behind the time loop (``physics: mechanics``).

:class:`MechanicsPhysics` owns the :class:`~poromech.mechanics.model.MechanicsModel`, its
semi-smooth Newton, the step predictor and the writers of the displacement and fracture fields.
It is run on its own, and inside the coupled poromechanics physics, which hands it the pressure
coupling (:class:`~poromech.mechanics.model.PressureCoupling`) and calls :meth:`begin_step` and
:meth:`solve_contact` from its fixed point.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import dolfinx_solver  # noqa: F401

import numpy as np
from dolfinx import fem
from dolfinx.fem.petsc import assign
from mpi4py import MPI
from petsc4py import PETSc

from poromech.errors import ConfigError
from poromech.io.checkpoint import NodeRows, face_dof_rows, scalar_row, set_face_dof_rows
from poromech.io.output import FractureTable, displacement_mesh, fracture_mesh, owned_blocks
from poromech.io.probes import fracture_sides, open_probes
from poromech.io.xdmf import XDMFSeries
from poromech.mechanics.linear import (
    DirectSolver,
    is_direct,
    iterative_options,
    rigid_body_modes,
)
from poromech.mechanics.model import MechanicsModel, PressureCoupling
from poromech.mechanics.multigrid import p1_interpolation
from poromech.mechanics.newton import (
    RECENT_ITERATIONS,
    NewtonRecord,
    SemiSmoothNewton,
    quoted_history,
)
from poromech.mechanics.predictor import START_NAMES, StepPredictor, start_rule
from poromech.mesh.entities import domain_extent, fracture_segments
from poromech.mesh.fractured import FracturedMesh, cracked_space
from poromech.physics import Keyed, StepResult
from poromech.scene.resources import (
    ELIMINATED_FORMULATIONS,
    direct_fallback_fits,
    mechanics_solver,
)
from poromech.scene.schema import Scene, step_times
from poromech.timing import Timer

__all__ = ["MechanicsPhysics", "check_pieces", "floating_pieces", "formulation_options",
           "linear_solver_options"]

log = logging.getLogger("poromech")

#: Face fields written to ``fractures.xdmf`` and ``fractures.csv`` (besides ``state``).
WRITTEN_FACE_FIELDS = ("jump_n", "jump_t", "traction_n", "traction_t")
#: In 3D: the magnitudes and the global components of the tangential jump and traction.
WRITTEN_FACE_FIELDS_3D = ("jump_n", "jump_t", "jump_tx", "jump_ty", "jump_tz", "traction_n",
                          "traction_t", "traction_tx", "traction_ty", "traction_tz")
#: Face fields written to ``fractures.xdmf`` only: the fractions of the face in contact and
#: sliding (they differ from 0 and 1 only where pointwise Nitsche switches inside a face).
XDMF_ONLY_FACE_FIELDS = ("contact_fraction", "slip_fraction")
#: Fractures a failure message names where the contact states cycle (the most faces first).
CYCLING_NAMED = 4
#: Largest displacement, as a fraction of the domain's extent (its bounding box's diagonal),
#: beyond which a run warns once that the small-strain model no longer describes it: a penny
#: crack of radius 1 m in rock of E = 1 kPa opened by 2.3 km, written as converged.
LARGE_DISPLACEMENT = 0.05


def linear_solver_options(kind: str, formulation: str, degree: int = 1) -> dict:
    """PETSc defaults of the linear solver ``kind`` (``direct``: the Newton's own, MUMPS).

    ``iterative``: CG + GAMG for open fractures (a symmetric positive definite Jacobian), GMRES
    for contact (:func:`~poromech.mechanics.linear.iterative_options`), preconditioned by GAMG
    for P1 displacements and by the p-multigrid for P2 (:mod:`poromech.mechanics.multigrid`).
    """
    if kind == "direct":
        return {}
    return iterative_options(symmetric=formulation == "none", p_multigrid=degree == 2)


def p1_coarse(fm: FracturedMesh, V) -> tuple[PETSc.Mat, np.ndarray]:
    """The p-multigrid's coarse level for the displacement space ``V`` (collective).

    Returns:
        The interpolation from the P1 space of the same cracked mesh into ``V``, and the P1
        rigid-body modes.
    """
    V1 = cracked_space(fm, 1)
    return p1_interpolation(V, V1), rigid_body_modes(V1)


def floating_pieces(scene: Scene, fm: FracturedMesh) -> dict[int, tuple[str, bool]]:
    """The pieces of the cracked body that no displacement condition holds, described.

    A piece (:attr:`~poromech.mesh.fractured.FracturedMesh.pieces`) is held when the
    displacement conditions on the boundaries it touches fix every component somewhere, the
    check the scene makes for the whole body (necessary, not sufficient, against rigid motion).
    The rigid-body modes given to GAMG are global; on a cracked space the pieces do not share
    dofs, so GAMG's aggregates never straddle a fracture and every piece's own rigid motions are
    in its coarse space all the same.

    Returns:
        Per such piece (by index): its description, and whether no component of it is held.
    """
    names, d = fm.geometry.boundary_names, fm.msh.geometry.dim
    out = {}
    for k, (cells, edges) in enumerate(fm.pieces):
        fixed = [False] * d
        touched = {names[e] for e in edges}
        for bc in scene.boundary_conditions:
            if bc.displacement is not None and bc.boundary in touched:
                fixed = [f or c is not None for f, c in zip(fixed, bc.displacement, strict=True)]
        if not all(fixed):
            free = "".join(c for c, f in zip("xyz", fixed, strict=False) if not f)
            where = ", ".join(sorted(touched)) or "no boundary"
            out[k] = (f"piece {k + 1} of {len(fm.pieces)} ({cells} cells, on {where}) has no "
                      f"displacement condition in {free}", not any(fixed))
    return out


def check_pieces(scene: Scene, fm: FracturedMesh) -> list[str]:
    """Refuse a piece held by nothing; warn of one held only by contact.

    Returns:
        The pieces held only by contact with friction, as "piece k of n (free in xyz)" (the
        components no displacement condition holds): a load beyond what their friction can
        hold has no equilibrium, which the message of a Newton that fails then says.

    Raises:
        ConfigError: Open fractures (``contact.formulation`` none) and a floating piece: its
            rigid motions make the elastic operator singular. Or frictionless contact and a
            piece no displacement condition holds whose fracture faces leave a rigid motion
            free (:attr:`~poromech.mesh.fractured.FracturedMesh.unblocked`): its position is
            not determined.
    """
    floating = floating_pieces(scene, fm)
    if not floating:
        return []
    if scene.contact.formulation == "none":
        raise ConfigError(f"scene key 'boundary_conditions': the fractures cut the body into "
                          f"{len(fm.pieces)} pieces and {next(iter(floating.values()))[0]}: "
                          "with contact.formulation none nothing holds it (rigid-body motion); "
                          "add a displacement condition on a boundary it touches")
    c = scene.contact
    frictionless = (c.friction == "frictionless"
                    or (c.friction == "coulomb" and c.friction_coefficient == 0)
                    or (c.friction == "tresca" and c.slip_bound is not None
                        and c.slip_bound.is_constant and c.slip_bound.value() == 0))
    held = []
    for k, (text, unheld) in floating.items():
        free = fm.unblocked[k] if k < len(fm.unblocked) else 0
        if frictionless and unheld and free:  # a block on a frictionless cut slid 3 µm - 3.6 mm
            raise ConfigError(
                f"scene key 'contact.friction': {text} and only frictionless contact holds it, "
                f"which leaves {free} of its rigid motions free (it can slide or turn along its "
                "fractures): its position is not determined; hold it by a displacement "
                "condition or give friction")
        if frictionless:
            log.warning("%s: only frictionless contact holds it, which cannot stop it sliding "
                        "along its fractures where their normals leave it free (its slide is "
                        "then not determined); hold it by a displacement condition or give "
                        "friction", text)
        else:
            hint = ("" if c.formulation != "nitsche" else
                    "; pointwise nitsche's Newton creeps there (87 iterations for a block on a "
                    "fault at 0.8 of its limit load, P2), mean_nitsche, stabilized_mixed and "
                    "mixed with degree 2 take 17-19 (docs/mechanics3d.md)")
            log.warning("%s: only contact holds it%s", text, hint)
            held.append(f"{text.split(' (', 1)[0]} (free in {text.rsplit(' ', 1)[1]})")
    return held


def formulation_options(formulation: str, dim: int = 2) -> dict:
    """PETSc defaults that depend on the formulation (and the dimension).

    The mixed method with P1 displacements is not inf-sup stable: when every face of a fracture
    sticks there are more facewise constraints than jump dofs and the Jacobian is singular (the
    displacement is unique, the multipliers are not). MUMPS null-pivot detection
    (ICNTL(24) = 1) then returns one of the solutions instead of failing. In 3D a triangulated
    fracture has about two faces per node, so P1 has six multipliers per three jump dofs: the
    null pivots are many, and their delayed pivoting overflows MUMPS's default workspace
    (INFOG(1) = -9 on the penny crack under shear with friction); ICNTL(14) = 100 allows it.
    """
    if formulation != "mixed":
        return {}
    return {"mat_mumps_icntl_24": 1} if dim == 2 else {"mat_mumps_icntl_24": 1,
                                                       "mat_mumps_icntl_14": 100}


class MechanicsPhysics:
    """The contact problem of a scene as a :class:`~poromech.physics.Physics` (collective).

    Args:
        scene: The scene.
        fm: The fractured mesh.
        timer: Wall-time accounting.
        pressures: How matrix and fracture pressures enter (coupled runs), or None.

    Attributes:
        model: The :class:`~poromech.mechanics.model.MechanicsModel` (holds the current unknowns).
        solver: The :class:`~poromech.mechanics.newton.SemiSmoothNewton`.
        predictor: The :class:`~poromech.mechanics.predictor.StepPredictor` of each step's start.
    """

    counters = ("iterations", "face_iterations", "linear_iterations", "factorizations",
                "stale_solves", "jacobian_reuses", "residual_evaluations", "time_assembly",
                "time_linear", "time_preconditioner")
    records_section = None

    def __init__(self, scene: Scene, fm: FracturedMesh, timer: Timer,
                 pressures: PressureCoupling | None = None):
        self.scene, self.timer, self.fm = scene, timer, fm
        self._numberings: dict[int, tuple] = {}  # _node_rows
        self.writes_initial_state = False
        self._held_by_friction = check_pieces(scene, fm)
        singular = scene.contact.formulation == "mixed" and scene.degree == 1
        if singular:
            log.warning("mixed with P1 displacements is not inf-sup stable: multipliers are not "
                        "unique and Newton may not converge; prefer degree 2 or stabilized_mixed")
        material = scene.material
        with timer.phase("setup"):
            self.model = model = MechanicsModel(fm, scene, pressures)
            # the Jacobian is a function of the contact branches when the contact law is
            # piecewise affine and no other coefficient of it (E, ν) changes in time
            constant = not (material.young.depends_on_time or material.poisson.depends_on_time)
            self.linear_solver = mechanics_solver(scene, model.dof_count())
            eliminate = (self.linear_solver == "iterative"
                         and model.params.formulation in ELIMINATED_FORMULATIONS)
            options = linear_solver_options(self.linear_solver, model.params.formulation,
                                            scene.degree)
            self.solver = SemiSmoothNewton(
                model.F, model.J, model.unknowns, model.bcs, prefix="mech_",
                options={**options,
                         **formulation_options(model.params.formulation, fm.msh.topology.dim),
                         **scene.solver.petsc},
                line_search=scene.solver.line_search,
                reuse_jacobian=scene.solver.reuse_jacobian,
                # a stale factorization of a singular Jacobian is no preconditioner
                stale_factorization=scene.solver.stale_factorization and not singular,
                # 2D keeps the counted budget its scenes and reference outputs were built with
                stale_priced=fm.msh.topology.dim == 3,
                states=model.active_set if model.faces is not None else None,
                states_determine_jacobian=constant and model.params.piecewise_affine,
                constant_jacobian=constant and model.linear,
                constant_bulk=model.J_split if constant else None,
                modes=(lambda: rigid_body_modes(model.V)) if (len(model.unknowns) == 1
                                                               or eliminate) else None,
                coarse=(lambda: p1_coarse(fm, model.V)) if scene.degree == 2 else None,
                eliminate_faces=eliminate,
                inexact=not model.linear,
                # 3D: face-mean formulations cycle between active sets without it; in 2D it
                # costs Newton iterations on the coupled six-fracture scene (docs/mechanics3d.md)
                one_sided=fm.msh.topology.dim == 3,
                curved=not model.params.piecewise_affine,
                exact_dirichlet=self.linear_solver == "iterative",
                fallback=(self._direct_fallback if scene.solver.linear_solver == "auto"
                          and self.linear_solver == "iterative" else None),
            )
        #: ``"direct"`` once a failed Krylov solve handed the run to MUMPS LU
        #: (:meth:`_direct_fallback`), else None.
        self.fallback: str | None = None
        self._log_linear_solver()
        self.linear_totals = {"krylov_iterations": 0, "preconditioner_setups": 0,
                              "time_preconditioner": 0.0}
        condensed = self._condensed()
        if condensed is not None:
            self.solver.attach_condensation(condensed)
        if model.initial_state is not None:
            # an initial stress in equilibrium is the solution at rest: its residual is
            # round-off, and the relative tolerance is taken from the forces in balance instead
            self.solver.reference_norm = model.initial_state["scale"]
        rule = start_rule(scene.solver.predictor, fm.msh.topology.dim, pressures is not None,
                          scene.contact.formulation)
        self.predictor = StepPredictor(model.unknowns, fm.comm, rule != "last",
                                       self._start_merit if rule == "lower_residual" else None)
        if scene.time is not None:
            what = "contact Newton" if not model.linear else "linear solve (initial guess)"
            log.info("each step's %s starts from the %s (solver.predictor %s)", what,
                     START_NAMES[rule], scene.solver.predictor)
        self._saved = [f.x.array.copy() for f in model.unknowns]
        self._extent = domain_extent(fm.msh)
        self._warned_large = False
        self._series: dict[str, XDMFSeries] = {}
        self._table: FractureTable | None = None
        self._probes: list[tuple] = []

    def _direct_fallback(self, failure: str, restart: bool = False) -> DirectSolver | None:
        """MUMPS LU for the rest of the run, after the first failed Krylov solve (``auto``).

        Only where the factorization fits (:func:`~poromech.scene.resources.direct_fallback_fits`);
        otherwise None, and the Newton fails as before. Said in one warning (kept for
        ``summary.json``) either way (collective). ``restart``: the switch of the run
        being continued (:meth:`restore`), ``failure`` unused.
        """
        fits, figures = direct_fallback_fits(self.model.dof_count(), 3, self.fm.comm)
        what = ("solver.linear_solver auto: the mechanics switches to MUMPS LU for the rest of "
                "the run" if fits else "MUMPS LU is not tried")
        why = ("the run continued here had switched to MUMPS LU after a failed iterative solve"
               if restart else f"the iterative linear solve failed ({failure})")
        self.model.warn(f"{why}; {what} ({figures})")
        if not fits:
            return None
        self.fallback = "direct"
        A = self.solver.A
        ksp = PETSc.KSP().create(self.fm.comm)
        ksp.setOptionsPrefix("mech_fallback_")
        ksp.setType(PETSc.KSP.Type.PREONLY)
        ksp.getPC().setType(PETSc.PC.Type.LU)
        ksp.getPC().setFactorSolverType("mumps")
        ksp.setOperators(A, A)
        ksp.setFromOptions()
        return DirectSolver(ksp, A, self.solver.prefix, reuse=self.scene.solver.reuse_jacobian,
                            stale=self.scene.solver.stale_factorization, priced=True,
                            owns_ksp=True)

    def _log_linear_solver(self) -> None:
        """Say once which linear solver the mechanics runs, and why (rank 0 logs)."""
        choice = self.scene.solver.linear_solver
        ksp = self.solver.ksp
        why = (f"solver.linear_solver {choice}" if choice != "auto" else
               f"auto: {self.fm.msh.topology.dim}D, {self.model.dof_count()} unknowns")
        k = self.solver.linear.near_nullspace_size
        modes = f", near-nullspace of {k} rigid-body modes" if k else ""
        pc = ksp.getPC().getType()
        multigrid = getattr(self.solver.linear, "multigrid", None)
        if multigrid is not None:
            stored = f" ({multigrid.fine_format} copy)" if multigrid.fine_format else ""
            pc = (f"p-multigrid: {multigrid.smoother} on P2{stored}, GAMG on the P1 Galerkin "
                  f"operator of {multigrid.coarse_size} unknowns")
        log.info("mechanics linear solver: %s (%s + %s%s; %s)", self.linear_solver,
                 ksp.getType(), pc, modes, why)

    def _condensed(self):
        """A :class:`~poromech.mechanics.condensed.CondensedContact` where it applies, else None."""
        from poromech.mechanics.condensed import MAX_FACE_UNKNOWNS, CondensedContact, applicable

        m, scene, ksp = self.model, self.scene, self.solver.ksp
        if (scene.solver.condensation and m.lam is not None and self.fm.msh.topology.dim == 3
                and applicable(m.params.formulation, scene.degree, scene.contact.friction)):
            log.info("the mixed contact problem is not condensed in 3D: its dense face problem "
                     "on one rank grows as the square of the fracture faces and was slower than "
                     "the regular Newton already on the penny crack (docs/mechanics3d.md)")
            return None
        if not (scene.solver.condensation and m.lam is not None
                and applicable(m.params.formulation, scene.degree, scene.contact.friction)
                and self.solver.states_determine_jacobian):
            return None
        if not (is_direct(ksp) and ksp.getPC().getFactorSolverType() == "mumps"):
            # the face Schur complement is MUMPS' (ICNTL 19): a scene that chose another
            # solver, e.g. SuperLU_DIST for bitwise repeatable runs, is told what it gives up
            solver = (ksp.getPC().getFactorSolverType() if is_direct(ksp)
                      else f"{ksp.getType()} + {ksp.getPC().getType()}")
            log.info("the mixed contact problem is not condensed: its face problem is formed by "
                     "a MUMPS factorization, and the mechanics solver is %s", solver)
            return None
        V = m.lam.function_space
        n = V.dofmap.index_map.size_global * V.dofmap.index_map_bs
        if n > MAX_FACE_UNKNOWNS:
            log.info("%d multiplier unknowns: more than %d, the contact problem is not condensed",
                     n, MAX_FACE_UNKNOWNS)
            return None
        try:
            with self.timer.phase("setup"):
                return CondensedContact(m, self.solver)
        except (RuntimeError, PETSc.Error) as err:
            log.warning("the contact problem is not condensed: %s", err)
            return None

    def describe(self) -> dict:
        """Formulation, degree and size, for the summary."""
        out = {
            "formulation": self.model.params.formulation,
            "friction": self.scene.contact.friction,
            "theta": self.scene.contact.theta,
            "degree": self.scene.degree,
            "dofs": self.model.dof_count(),
            "beta_n": self.model.beta0[0],
            "beta_t": self.model.beta0[1],
            "beta_scaling": "local" if self.model.beta_weight is not None else "largest",
        }
        if self.model.beta_sm0 is not None:
            out["beta_sm_n"], out["beta_sm_t"] = self.model.beta_sm0
        ksp = self.solver.ksp
        out["linear_solver"] = {"kind": self.linear_solver,
                                "choice": self.scene.solver.linear_solver,
                                "ksp_type": ksp.getType(), "pc_type": ksp.getPC().getType()}
        c = self.solver.condensed
        out["condensed"] = None if c is None else c.describe()
        if self.model.coercivity_ratio is not None:
            out["coercivity_ratio"] = self.model.coercivity_ratio
        if self.model.initial_state is not None:
            out["initial_stress_imbalance"] = self.model.initial_state
        if self.model.warnings:
            out["warnings"] = list(self.model.warnings)
        return out

    # -- the contact solve, also called by the coupled physics --------------------------------
    def _start_merit(self) -> float:
        """The Newton's merit at the current unknowns, to choose a step's start (collective)."""
        t0 = time.perf_counter()
        merit = self.solver.merit_here()
        self.timer.add("assembly", time.perf_counter() - t0)
        return merit

    def begin_step(self, t: float) -> None:
        """Inputs at time ``t`` and the predicted unknowns (the start of the step's Newton)."""
        self.model.set_time(t)
        self.predictor.predict(t)

    def solve_contact(self, min_iterations: int = 0) -> NewtonRecord:
        """The semi-smooth Newton from the current unknowns (collective); its record.

        Args:
            min_iterations: Newton steps taken even when the initial residual already meets the
                tolerance (finite-difference Jacobians of the coupling).
        """
        rec = self.solver.solve(min_iterations)
        self.timer.add("assembly", rec.time_assembly)
        self.timer.add("linear_solve", rec.time_linear)
        self.linear_totals["krylov_iterations"] += rec.linear_iterations
        self.linear_totals["preconditioner_setups"] += rec.factorizations
        self.linear_totals["time_preconditioner"] += rec.time_preconditioner
        return rec

    # -- Physics interface -----------------------------------------------------------------
    def initialize(self) -> dict | None:
        """Nothing to solve: the displacement starts at zero.

        The face unknowns start consistent with it
        (:meth:`~poromech.mechanics.model.MechanicsModel.start_face_unknowns`, under an in-situ
        stress only), and that is then the accepted state at ``t = 0``: the first step's
        predictor and a cut of the first step start from it. Otherwise the predictor takes zero
        unknowns as that state (:class:`~poromech.mechanics.predictor.StepPredictor`).
        """
        if self.model.start_face_unknowns():
            self._keep_unknowns()
        return None

    def solve(self, t: float, dt: float | None) -> StepResult:
        """Semi-smooth Newton at time ``t`` from the predicted unknowns."""
        self.begin_step(t)
        rec = self.solve_contact()
        record = rec.as_dict()
        record["start"] = self.predictor.start
        message = ""
        if not rec.converged:
            linear = f" ({rec.linear_failure})" if rec.linear_failure else ""
            message = (f"Newton did not converge at t = {t:g} s: {rec.reason} after "
                       f"{rec.iterations} iterations{linear}; residual history "
                       + quoted_history(rec.residuals))
            if self._held_by_friction:
                message += (f"; only contact holds {', '.join(self._held_by_friction)}: a load "
                            "beyond what its friction can hold has no equilibrium")
            message += self._cycling()
        return StepResult(rec.converged, record, message, rec.reason, rec.residuals)

    def _cycling(self) -> str:
        """Where the contact states cycled in the last iterations of a failed Newton (collective).

        The fractures with faces holding a contact point that switched state at least twice in
        the last :data:`~poromech.mechanics.newton.RECENT_ITERATIONS` iterations, most such
        faces first; with Coulomb friction above 1, that the incremental problem may have no
        solution or several. Empty when no point cycles.
        """
        switches = self.solver.recent_switches
        if switches is None:
            return ""
        names = self.fm.geometry.fracture_names
        faces = self.model.point_faces()
        cycling = np.unique(faces[(switches >= 2) & (faces >= 0)])
        counts = np.bincount(self.fm.fractures.fracture[cycling], minlength=len(names))
        counts = self.fm.msh.comm.allreduce(counts, op=MPI.SUM)
        if not counts.any():
            return ""
        order = sorted((k for k in range(len(names)) if counts[k]), key=lambda k: -counts[k])
        where = ", ".join(f"{names[k]} {counts[k]}" for k in order[:CYCLING_NAMED])
        if len(order) > CYCLING_NAMED:
            where += f" and {len(order) - CYCLING_NAMED} more fracture(s)"
        n = int(counts.sum())
        text = (f"; contact states cycle (switched twice or more in the last {RECENT_ITERATIONS} "
                f"iterations) on {n} face{'s' if n > 1 else ''}: {where}")
        c = self.scene.contact
        if c.friction == "coulomb" and c.friction_coefficient > 1:
            text += (f"; with contact.friction_coefficient {c.friction_coefficient:g} > 1 the "
                     "step's Coulomb problem may have several solutions or none (Klarbring "
                     "1990)")
        return text

    def accept(self, t: float) -> None:
        """The solved displacement becomes the reference of the next slip increment."""
        self.model.accept_step()
        self._keep_unknowns()
        self._check_small_displacements(t)

    def _check_small_displacements(self, t: float) -> None:
        """Warn once when the displacement leaves the small-strain model (collective)."""
        if self._warned_large:
            return
        big = self.fm.comm.allreduce(float(np.abs(self.model.u.x.array).max(initial=0.0)),
                                     op=MPI.MAX)
        if big > LARGE_DISPLACEMENT * self._extent:
            self._warned_large = True
            text = (f"at t = {t:g} s the displacement reaches {big:.3g} m, {big / self._extent:.2g}"
                    f" of the domain's extent ({self._extent:.3g} m): linear elasticity assumes "
                    "small displacements and strains, and describes nothing physical this far "
                    "(loads too large, or material.young too small?)")
            log.warning(text)
            self.model.warnings.append(text)

    def _keep_unknowns(self) -> None:
        """The current unknowns are the accepted ones: the predictor's and a step cut's."""
        self.predictor.accept()
        for saved, f in zip(self._saved, self.model.unknowns, strict=True):
            saved[:] = f.x.array

    def reject(self) -> None:
        """Back to the unknowns of the last accepted step."""
        for saved, f in zip(self._saved, self.model.unknowns, strict=True):
            f.x.array[:] = saved

    def progress(self, k: int, n: int, t: float, result: StepResult) -> str:
        """One line per step: Newton iterations, residuals, active-set changes."""
        rec = result.record
        changes = ",".join(str(c) for c in rec["active_set_changes"]) or "-"
        res = rec["residuals"] or [float("nan")]
        face = f" (+{rec['face_iterations']} face Newton)" if rec.get("face_iterations") else ""
        # without contact conditions the problem is linear: one solve, no Newton to speak of
        what = "Newton it" if self.model.params.active else "linear solve"
        if is_direct(self.solver.ksp):
            work = f"{rec['factorizations']} factorizations"
        else:
            work = (f"{rec['factorizations']} preconditioner set-ups "
                    f"({rec['time_preconditioner']:.2f} s), "
                    f"{rec['linear_iterations']} Krylov iterations")
        return (f"step {k + 1}/{n} t={t:g} s: {rec['reason']} in {rec['iterations']} {what}"
                f"{face} "
                f"(|F| {res[0]:.2e} -> {res[-1]:.2e}), active-set changes {changes}, {work}")

    # -- output ------------------------------------------------------------------------------
    def open_output(self, outdir: Path, resume_until: float | None = None,
                    fracture_columns: tuple[str, ...] = ()) -> None:
        """Create the writers selected by ``scene.output`` (collective).

        Args:
            outdir: Output directory.
            resume_until: Continue the series of an earlier run up to this time.
            fracture_columns: Extra face fields (written by a coupled run).
        """
        out = self.scene.output
        comm = self.fm.comm
        with self.timer.phase("output"):
            if out.xdmf:
                self._series["u"] = XDMFSeries(comm, outdir, "displacement",
                                               displacement_mesh(self.fm, self.model.V), "u",
                                               resume_until)
                if self.model.faces is not None:
                    self._series["fractures"] = XDMFSeries(comm, outdir, "fractures",
                                                           fracture_mesh(self.fm), "fractures",
                                                           resume_until)
            if out.fractures_csv and self.model.faces is not None:
                columns = (*self.written_face_fields, "state", *fracture_columns)
                self._table = FractureTable(self.fm, Path(outdir) / "fractures.csv", columns,
                                            resume_until)
            faces = self.fm.fractures
            segments = (fracture_segments(self.fm.msh, faces.facets, faces.tangents[:, 0]),
                        faces.index.astype(np.float64))
            self._probes = open_probes(self.fm.msh, self.scene.probes, outdir, segments,
                                       resume_until, fracture_sides(self.fm))

    @property
    def written_face_fields(self) -> tuple[str, ...]:
        """The face fields of ``fractures.csv`` and ``fractures.xdmf`` in this dimension."""
        return WRITTEN_FACE_FIELDS if self.fm.msh.topology.dim == 2 else WRITTEN_FACE_FIELDS_3D

    def probe_columns(self, sampler, faces: dict[str, np.ndarray] | None) -> dict:
        """Displacement components and, along fractures, the written face fields (rank 0)."""
        u = sampler.function(self.model.u)
        d = self.fm.msh.geometry.dim
        out = {f"u_{c}": None if u is None else u[:, k] for k, c in enumerate("xyz"[:d])}
        if faces is not None:
            for name in self.written_face_fields:
                out[name] = sampler.faces(faces[name])
        return out

    def face_output(self) -> dict[str, np.ndarray]:
        """The written face fields and states of the owned fracture faces (collective)."""
        values = self.model.face_fields()
        out = {name: values[name] for name in (*self.written_face_fields,
                                               *XDMF_ONLY_FACE_FIELDS)}
        out["state"] = self.model.states(values)
        return out

    def write(self, t: float, extra_faces: dict[str, np.ndarray] | None = None,
              extra_probes=None) -> None:
        """Write the displacement, the fracture fields, the fracture table and the probes at ``t``.

        Args:
            t: Time (s).
            extra_faces: More face fields (a coupled run's ``p_f``, ``aperture``).
            extra_probes: ``f(probe, sampler) -> columns`` adding probe columns (rank 0 values).
        """
        with self.timer.phase("output"):
            faces = None
            if "u" in self._series:
                self._series["u"].write(t, point_data={"u": owned_blocks(self.model.u)})
            if self.model.faces is not None and (self._table or "fractures" in self._series
                                                 or self._probes):
                faces = {**self.face_output(), **(extra_faces or {})}
            if "fractures" in self._series:
                self._series["fractures"].write(t, cell_data=faces)
            if self._table is not None:
                self._table.write(t, {k: v for k, v in faces.items()
                                      if k not in XDMF_ONLY_FACE_FIELDS})
            for probe, table in self._probes:
                columns = self.probe_columns(table.sampler, faces)
                if extra_probes is not None:
                    columns.update(extra_probes(probe, table.sampler))
                table.write(t, columns)

    # -- checkpoint ----------------------------------------------------------------------
    def _rows(self, f, values: np.ndarray) -> Keyed:
        """Values in the layout of function ``f``, keyed independently of the partition.

        By input cell (displacements) or by fracture face (multipliers, averages).
        """
        m = self.model
        V = f.function_space
        if m.submesh is not None and V.mesh is m.submesh:
            return face_dof_rows(self.fm, V, values, m.emap)
        return self._node_rows(V).rows(values)

    def _set_rows(self, f, rows) -> None:
        m = self.model
        if m.submesh is not None and f.function_space.mesh is m.submesh:
            set_face_dof_rows(self.fm, f, m.emap, rows)
        else:
            self._node_rows(f.function_space).set(f, rows)

    def _node_rows(self, V) -> NodeRows:
        """The partition-independent numbering of ``V``'s dof blocks, made once (collective)."""
        key = id(V)
        if key not in self._numberings:
            self._numberings[key] = (V, NodeRows(self.fm, V))  # V kept: its id stays unique
        return self._numberings[key][1]

    def state(self) -> dict[str, Keyed]:
        """Unknowns, slip reference and the predictor's previous step, partition-independent."""
        m = self.model
        out = {f.name: self._rows(f, f.x.array) for f in m.unknowns}
        if m.u_prev is not None:
            out["u_prev"] = self._rows(m.u_prev, m.u_prev.x.array)
        out["reference_norm"] = scalar_row(self.fm.comm, self.solver.reference_norm)
        # what the linear solver chose so far, for a restart to go on with
        if self.fallback is not None:
            out["linear_direct"] = scalar_row(self.fm.comm, 1.0)
        choices = getattr(self.solver.linear, "choices", None)
        for name, value in (choices() if choices is not None else {}).items():
            out[f"linear_{name}"] = scalar_row(self.fm.comm, value)
        previous = self.predictor.previous
        if previous is not None:
            t0, arrays = previous
            for f, a in zip(m.unknowns, arrays, strict=True):
                out[f"previous_{f.name}"] = self._rows(f, a)
            out["previous_time"] = scalar_row(self.fm.comm, t0)
        out.update(self._condensed_base())
        return out

    def _condensed_base(self) -> dict[str, Keyed]:
        """Where the condensed solve's kept face inverse was taken, if it has one (collective).

        A restart that inverted the face Jacobian anew at its first solve would take other
        round-off than the uninterrupted run, whose Woodbury updates start from an older base.
        """
        condensed = self.solver.condensed
        if condensed is None:
            return {}
        v = self.solver.x.duplicate()
        law = condensed.base_unknowns(v)
        out = {}
        if law is not None:
            v.ghostUpdate(PETSc.InsertMode.INSERT, PETSc.ScatterMode.FORWARD)
            faces = [fem.Function(f.function_space) for f in self.model.unknowns]
            assign(v, faces)
            for f, g in zip(self.model.unknowns[1:], faces[1:], strict=True):
                out[f"condensed_base_{f.name}"] = self._rows(f, g.x.array)
            out["condensed_base_coefficient"] = scalar_row(self.fm.comm, law[0])
            out["condensed_base_bound"] = scalar_row(self.fm.comm, law[1])
        v.destroy()
        return out

    def _restore_condensed_base(self, arrays: dict) -> None:
        """Rebuild the condensed solve's face inverse where the continued run had it."""
        condensed = self.solver.condensed
        if condensed is None or "condensed_base_coefficient" not in arrays:
            return
        m = self.model
        for f in m.unknowns[1:]:
            self._set_rows(f, arrays[f"condensed_base_{f.name}"])
        v = self.solver.x.duplicate()
        assign(m.unknowns, v)
        condensed.set_base(v, (float(arrays["condensed_base_coefficient"][0]),
                               float(arrays["condensed_base_bound"][0])))
        v.destroy()

    def restore(self, arrays: dict, t: float) -> None:
        """Set the unknowns of the step ending at ``t`` from checkpoint arrays; accept them.

        Before they are set, a Krylov solver's preconditioner is built once on the Jacobian of
        the initial unknowns at the first step's time (:meth:`_prime_linear_solver`).
        """
        m = self.model
        self._restore_linear_choices(arrays)
        self._prime_linear_solver()
        self._restore_condensed_base(arrays)
        previous = None
        if "previous_time" in arrays:
            for f in m.unknowns:
                self._set_rows(f, arrays[f"previous_{f.name}"])
            previous = (float(arrays["previous_time"][0]), [f.x.array.copy() for f in m.unknowns])
        for f in m.unknowns:
            self._set_rows(f, arrays[f.name])
        if m.u_prev is not None:
            self._set_rows(m.u_prev, arrays["u_prev"])
        self.solver.reference_norm = float(arrays["reference_norm"][0])
        self.predictor.restore(t, previous)
        for saved, f in zip(self._saved, m.unknowns, strict=True):
            saved[:] = f.x.array

    def _prime_linear_solver(self) -> None:
        """Build a Krylov preconditioner's coarse spaces where the run being continued did.

        GAMG (on the Jacobian, on the Schur complement, or on the p-multigrid's P1 level) keeps
        the aggregates and prolongators of its first set-up (until a change of its level smoother)
        (:meth:`~poromech.mechanics.linear.IterativeSolver.prime`), and the first Jacobian of a
        run is that of its initial unknowns at the first step's time. A restart sets the
        preconditioner up there first, from the still initial unknowns (one assembly and one
        set-up, timed as a linear solve). Without it the restart coarsened the Jacobian where
        it resumed: the network's P2 p-multigrid continued after step 1 took 385 GMRES
        iterations in step 2 against the uninterrupted run's 176 (docs/outputs.md).
        """
        if not hasattr(self.solver.linear, "prime"):
            return
        t0 = time.perf_counter()
        times = step_times(self.scene)
        if times:
            self.model.set_time(times[0])
        self.solver.prime_preconditioner()
        self.timer.add("linear_solve", time.perf_counter() - t0)

    def _restore_linear_choices(self, arrays: dict) -> None:
        """The linear solver goes on as the run being continued had left it (collective).

        After its switch to MUMPS LU (``solver.linear_solver auto``), with MUMPS again (said in
        a warning, or why not); a Krylov solver with its P2 smoother fallback and GAMG's level
        smoother choice (:meth:`~poromech.mechanics.linear.IterativeSolver.restore_choices`).
        Checkpoints written before these were kept hold none of them: the run then starts the
        linear solver afresh, as it did.
        """
        if ("linear_direct" in arrays and self.fallback is None
                and self.linear_solver == "iterative"):
            strategy = self._direct_fallback("", restart=True)
            if strategy is not None:
                self.solver.hand_over(strategy)
            return
        restore = getattr(self.solver.linear, "restore_choices", None)
        prefix = "linear_"
        choices = {k[len(prefix):]: float(arrays[k][0]) for k in arrays if k.startswith(prefix)}
        if restore is not None and choices:
            restore(choices)

    def finish(self, summary: dict, records: list[dict]) -> None:
        """The linear solver's work over every solve, and the condensed solve's, if any."""
        totals = dict(self.linear_totals)
        totals["time_preconditioner"] = self.fm.comm.allreduce(totals["time_preconditioner"],
                                                               op=MPI.MAX)
        smoother = getattr(self.solver.linear, "smoother", None)
        if smoother is not None:  # chosen by the solver (IterativeSolver)
            totals["level_smoother"] = smoother
        multigrid = getattr(self.solver.linear, "multigrid", None)
        if multigrid is not None:
            totals["p_multigrid"] = {"fine_smoother": multigrid.smoother,
                                     "fine_format": multigrid.fine_format or "aij",
                                     "coarse_unknowns": multigrid.coarse_size}
        if self.fallback is not None:
            totals["fallback"] = self.fallback
        summary.setdefault("linear_solver", {}).update(totals)
        if self.model.warnings:  # with those of the run (a solver's fallback)
            kept = summary.setdefault("warnings", [])
            kept.extend(w for w in self.model.warnings if w not in kept)
        if self.solver.condensed is not None:
            summary["condensed"] = self.solver.condensed.describe()

    def close(self) -> None:
        """Free the PETSc objects."""
        self.solver.destroy()
