"""Semi-smooth Newton for contact problems: a PETSc SNES of type ``python``.

PETSc runs the outer loop (convergence test, monitors, ``-mech_snes_*`` options); poromech's
``step`` computes the generalized Newton direction and applies its own line search, designed
for residuals that are piecewise affine in the unknowns (2D contact with Coulomb friction):

* **Full step first.** The Newton step is taken whole when it decreases the residual norm
  (Armijo, ``‖F(x - Y)‖ <= (1 - c)‖F(x)‖``): near the solution Newton lands exactly on the
  root of the affine piece it linearized.
* **Otherwise a search of the whole ray.** Along the Newton ray ``‖F(x - αY)‖`` is piecewise
  quadratic in ``α``, with a kink wherever a contact point switches state. Backtracking from
  ``α = 1`` stops at the *first* ``α`` that satisfies Armijo, usually just before the nearest
  switch, so that one point (or face) changes state per iteration: the iteration count then
  grows with the number of points that must switch, i.e. with the mesh (pointwise Nitsche
  needed 47 iterations in the first step of the six-fracture scene at 47k cells). Instead the
  norm is sampled at ``α = 1/2, 1/4, … 1/64`` and the best sample is refined by a few
  golden-section steps, so that a step crosses every switch that pays; the best step is taken
  when it satisfies Armijo. Residual evaluations only, each far cheaper than the factorization
  of the iteration (docs/mechanics.md, "Newton iterations against the mesh").
* **Energy merit for displacement-only systems.** For Nitsche the norm is ``‖D^{-1/2}F‖`` with
  ``D = |diag J|`` taken from the first Jacobian of the solve and kept for all its iterations
  (:meth:`_NewtonStep._set_scale`): ``Σ F_i²/J_ii`` is an energy (the residual in the inverse
  of the Jacobi-preconditioned stiffness), so a few dofs at corners and tips, where ``β/h``
  makes residuals large, do not dictate the step of the whole domain, and every trial of every
  iteration is measured with the same merit.
* **A one-sided Jacobian when the ray does not descend (3D).** When no trial satisfies Armijo, some
  contact points sit at (or next to) a switch, and the Jacobian of their current branch is not
  the derivative along the Newton ray. The Jacobian is then assembled a short step ahead,
  ``x - 2⁻ˢY`` (``s`` the samples), where those points are on the branch the ray enters; its
  direction is solved from the same residual and searched the same way, and taken when it
  satisfies Armijo. Face-mean formulations in 3D otherwise cycle through the same three active
  sets for 20 iterations (docs/mechanics3d.md, "Newton iterations"). One assembly and one linear
  solve, only in the iterations that need it (``NewtonRecord.one_sided``); after two such
  steps in a row it is off for the rest of the solve. Off in 2D
  (``one_sided``), where it cost Newton iterations on the coupled six-fracture scene.
* **Full steps on a smooth piece (3D friction).** The projection on the friction disc is not
  affine: where a face slips at a vanishing rate its traction may still have to turn, and a
  Newton step along the tangent of the disc's rim leaves it by ``α |Δθ|²/2``. The merit then
  grows along the ray as ``C α²`` although no contact point switches, and the search creeps in
  steps of a few per cent (``mixed`` P2 on the seven-fracture network at scale 2: 20 steps of
  ``α`` = 0.01-0.3 before a full step, 32 iterations in the compression step). When no trial
  of the search (the full step, the samples, the refinements) switches a contact point, the
  full step is taken even though the merit grows, as long as the merit
  falls below ``(1 - c)`` times its value before the first such step within
  :data:`NONMONOTONE_STEPS` iterations; otherwise the iterate goes back there and takes the
  searched step along that iteration's direction (the watchdog technique of Chamberlain,
  Powell, Lemaréchal and Pedersen 1982), so the merit at those anchors still decreases
  monotonically. Off where the law is piecewise affine (2D, frictionless): a full step without
  a switch lands on the root of its affine piece and is always taken (``nonmonotone``).
* **Watchdog.** When no trial decreases the residual, the best trial is taken anyway (the
  active set usually changes and Newton recovers); five consecutive such steps end the solve
  with ``DIVERGED_LINE_SEARCH``, and a ray on which every residual is NaN or infinite with
  ``DIVERGED_FUNCTION_NANORINF``.

``docs/mechanics/robustness.md`` compares it with PETSc's ``basic`` and ``bt`` searches. With a
PETSc search (``line_search``) PETSc's Newton runs the loop, and its KSP is a ``preonly`` shell
of the same linear strategy (:class:`_LinearShell`).

The direction is solved by a linear strategy (:mod:`poromech.mechanics.linear`): by default a
factorization reused while the assembled Jacobian is bitwise unchanged (``reuse_jacobian``),
with GMRES preconditioned by a stale factorization after few contact-state changes
(``stale_factorization``, options prefix ``mech_stale_``); a Krylov method when the options ask
for one; a ``fallback`` may replace the strategy after its first failed solve (the scenes'
``solver.linear_solver: auto`` hands a failed Krylov solve to MUMPS LU where it fits). When
the contact law says that its Jacobian is a function of the contact states only
(2D friction: piecewise affine), an unchanged active set skips the assembly of the Jacobian
altogether (``states_determine_jacobian``), and a problem without contact terms whose
coefficients are constant in time assembles its Jacobian once (``constant_jacobian``). A
residual evaluated during the line search is not assembled again for the accepted iterate, and
a residual at an iterate that holds the Dirichlet values exactly skips the lifting, which would
add zeros (on the Krylov path the directions keep them: ``exact_dirichlet``).
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import dolfinx_solver  # noqa: F401

import dolfinx
import numpy as np
from dolfinx import cpp as _cpp
from dolfinx import fem
from dolfinx.fem import bcs_by_block, extract_function_spaces, pack_coefficients, pack_constants
from dolfinx.fem.petsc import (
    apply_lifting,
    assemble_vector,
    assign,
    create_matrix,
    create_vector,
    set_bc,
)
from mpi4py import MPI
from petsc4py import PETSc

from poromech.mechanics.linear import (
    SWITCHED_FRACTION,
    LinearStrategy,
    forcing_term,
    linear_strategy,
)
from poromech.petsc_options import PrefixedOptions, reason_name

__all__ = ["ConvergenceError", "NewtonRecord", "SemiSmoothNewton", "DEFAULT_OPTIONS",
           "quoted_history"]

log = logging.getLogger("poromech")

#: Newton iterations within which a run of full steps on a smooth piece (taken against the
#: merit, see the module docstring) must bring the merit below its value before the run, or the
#: iterate goes back. ``mixed`` P2 on configs/network3d.yaml at mesh scale 2 (15k unknowns):
#: the compression step took 14 iterations instead of 32 with two such steps, each paid off at
#: the next iteration (docs/mechanics3d.md, "Full steps on a smooth piece").
NONMONOTONE_STEPS = 3

#: Defaults for the mechanics SNES/KSP (prefix ``mech_``); scene ``solver.petsc`` and the command
#: line override them.
DEFAULT_OPTIONS: dict[str, object] = {
    "snes_type": "python",
    "snes_rtol": 1e-10,
    "snes_atol": 1e-30,
    "snes_stol": 0.0,
    "snes_max_it": 100,
    "snes_linesearch_type": "basic",
    "ksp_type": "preonly",
    "pc_type": "lu",
    "pc_factor_mat_solver_type": "mumps",
}

#: A residual at most ``ROUNDOFF_FLOOR ‖J x‖`` (``J`` the last assembled Jacobian, ``J x`` the
#: forces in balance) is round-off, and the Newton has converged there even above its relative
#: tolerance, which is taken from the largest initial residual so far and so falls with the load
#: increment: a user's inclined crack (2 m at 35° in a 20 m box, nitsche P2) loaded in 1,500
#: steps stalled at |F| = 1.7e-6 against a tolerance of 1.56e-6 at t = 0.47 (‖J x‖ = 1.15e7:
#: 1.5e-13 of it, 670 ε) and every cut failed alike; in 5 or 500 steps it converges. Checked
#: (one product) only within :data:`ROUNDOFF_WINDOW` times the tolerance.
ROUNDOFF_FLOOR = 1e-12
ROUNDOFF_WINDOW = 1e3
#: The residual's round-off grows with the terms it sums, not with the forces they balance:
#: across a stiffness contrast the stiff side's large terms cancel. ``‖diag(J) x‖`` is a lower
#: bound of the summed terms ``‖|J| |x|‖``, so a residual at most ``ROUNDOFF_DIAGONAL`` (about
#: 45 ε) of it is round-off, and a Newton that stalls there (its residual fell by less than
#: :data:`ROUNDOFF_STALL` in the last iteration) within :data:`ROUNDOFF_STALL_WINDOW` times its
#: tolerance has converged. The window keeps out a body that only contact holds under a load
#: beyond its friction: it slides away, and its rigid displacement (1e10 m after 60
#: iterations on the sliding block of configs/sliding_block3d.yaml at 1.1 times its limit)
#: makes ``‖diag(J) x‖`` as large as wanted while the residual stays above the load. A
#: user's layer of E = 1e4 Pa under one of 1e10 Pa, loaded by a traction, reached |F| = 2.7e-5
#: (2.4e-16 ‖diag(J) x‖; ‖J x‖ = 3.3e2) in one full step with `mixed` and then stalled at
#: 7.6e-6 against a tolerance of 3.3e-8 until the line search failed, with every formulation
#: (`nitsche`: 9.9e-5, 8e-17 ‖diag(J) x‖).
ROUNDOFF_DIAGONAL = 1e-14
ROUNDOFF_STALL = 0.5
ROUNDOFF_STALL_WINDOW = 1e4

#: Residuals a failure message quotes at each end of a longer history (the whole history is in
#: the step records of summary.json): 100-300 values made messages of several kB on one line.
QUOTED_RESIDUALS = 4

#: Newton iterations over which :attr:`SemiSmoothNewton.recent_switches` counts the state
#: changes of each contact point: a point that switched twice or more in the last ten iterations
#: of a failed solve cycles between branches (a failure message names the fractures it is on).
RECENT_ITERATIONS = 10


def quoted_history(residuals: Sequence[float]) -> str:
    """``r0, r1, ..., rn`` as a message quotes it: the first and last few of a long history."""
    text = [f"{r:.3e}" for r in residuals]
    k = QUOTED_RESIDUALS
    if len(text) > 2 * k + 1:
        text = [*text[:k], f"... ({len(text) - 2 * k} more) ...", *text[-k:]]
    return ", ".join(text)


class ConvergenceError(RuntimeError):
    """A nonlinear solve that did not converge; carries its :class:`NewtonRecord`."""

    def __init__(self, message: str, record: NewtonRecord):
        super().__init__(message)
        self.record = record


@dataclass
class NewtonRecord:
    """What happened in one nonlinear solve (identical on every rank)."""

    iterations: int = 0
    reason: str = ""
    converged: bool = False
    residuals: list[float] = field(default_factory=list)
    steps: list[float] = field(default_factory=list)
    active_set_changes: list[int] = field(default_factory=list)
    linear_iterations: int = 0
    factorizations: int = 0
    stale_solves: int = 0
    face_iterations: int = 0
    jacobian_reuses: int = 0
    residual_evaluations: int = 0
    time_assembly: float = 0.0
    time_linear: float = 0.0
    time_preconditioner: float = 0.0
    linear_failure: str = ""
    one_sided: int = 0
    nonmonotone_steps: int = 0
    nonmonotone_returns: int = 0
    switched_solves: int = 0

    def as_dict(self) -> dict:
        """JSON-ready summary."""
        return dict(self.__dict__)


@dataclass(frozen=True)
class LineSearchParameters:
    """Constants of the ``contact`` line search.

    Attributes:
        armijo: Sufficient-decrease constant ``c``.
        samples: Halvings ``α = 2⁻ʲ`` sampled when the full step is rejected.
        refinements: Golden-section steps refining the best sample.
        max_watchdog: Consecutive non-decreasing steps allowed before giving up.
        one_sided: Whether a ray without an Armijo step is searched again with the Jacobian
            a short step ahead (:meth:`_NewtonStep._one_sided`).
        nonmonotone: Iterations allowed to a run of full steps that change no contact state
            but increase the merit (a curved contact law; :data:`NONMONOTONE_STEPS`); 0: off.
    """

    armijo: float = 1e-4
    samples: int = 6
    refinements: int = 3
    max_watchdog: int = 5
    one_sided: bool = False
    nonmonotone: int = 0


class SemiSmoothNewton:
    """Owns the SNES, matrices and vectors of one nonlinear block problem (collective).

    Args:
        F: Compiled residual blocks.
        J: Compiled Jacobian blocks.
        unknowns: Functions in block order.
        bcs: Dirichlet conditions.
        prefix: PETSc options prefix (ending in ``_``).
        options: Options merged over :data:`DEFAULT_OPTIONS` (scene values).
        line_search: ``"contact"`` or a PETSc line search type.
        reuse_jacobian: Reuse the factorization while the Jacobian is bitwise unchanged, and
            skip the assembly of a Jacobian the contact states determine.
        stale_factorization: When at most a few contact points changed state since the last
            factorization, first try GMRES preconditioned by that (stale) factorization
            (:class:`~poromech.mechanics.linear.DirectSolver`, prefix ``<prefix>stale_``).
        stale_priced: Stale GMRES is tried whatever the contact states did, within a budget of
            iterations priced from the factorization's flops
            (:meth:`~poromech.mechanics.linear.DirectSolver.price`); 3D.
        states: Callable returning the active-set codes of the owned contact points at the
            current unknowns, or None: the record's ``active_set_changes`` counts the codes that
            change from one iterate to the next. Pass
            :meth:`~poromech.mechanics.model.MechanicsModel.active_set` (quadrature points for
            pointwise Nitsche), so that a count of 0 means an unchanged Jacobian.
        states_determine_jacobian: The Jacobian is a function of the contact states only (the
            contact law's :attr:`~poromech.forms.contact.ContactParameters.piecewise_affine`,
            with coefficients constant in time): an unchanged active set then reuses the
            assembled Jacobian.
        constant_jacobian: The Jacobian never changes (a linear problem whose coefficients are
            constant in time: no contact conditions): with ``reuse_jacobian`` it is assembled
            once, at the first Newton iteration of the first solve.
        constant_bulk: ``J`` as ``(bulk, rest)``: ``bulk`` the displacement block's part that
            never changes (the elastic stiffness, whose coefficients are constant in time),
            ``rest`` the blocks of ``J`` without it. With ``reuse_jacobian`` the bulk is
            assembled once into a matrix of the Jacobian's pattern, and each Jacobian is that
            matrix's copy with ``rest`` added: the same sums in the same order as assembling
            ``J``, at the cost of the contact terms only (the bulk was 70 % of a P1 and 75 % of
            a P2 Jacobian's assembly on the 3D fault scene).
        modes: Computes the rigid-body modes of a displacement-only system
            (:func:`~poromech.mechanics.linear.rigid_body_modes`); called when the options
            configure a Krylov solve, whose matrix then carries them as near-nullspace.
        coarse: Computes the interpolation from P1 into the displacements and the P1
            rigid-body modes, the coarse level of the p-multigrid (``pc_type mg``,
            :mod:`~poromech.mechanics.multigrid`).
        eliminate_faces: A Krylov solve works on the displacement Schur complement, the face
            unknowns (every block after the first) eliminated face by face
            (:class:`~poromech.mechanics.linear.FaceElimination`).
        inexact: A Krylov solve of the direction is only as accurate as the Newton can use
            (:func:`~poromech.mechanics.linear.forcing_term`), and with ``reuse_jacobian`` keeps
            its preconditioner across Jacobians while that pays (``lagged``); False for a linear
            problem, solved in one iteration to the options' ``ksp_rtol``.
        one_sided: A ray without an Armijo step is searched again with the Jacobian a short
            step ahead (:class:`LineSearchParameters`; the 3D contact laws).
        curved: The contact law is not piecewise affine (friction in 3D): a full step that
            switches no contact point may still increase the merit, and is taken within
            :data:`NONMONOTONE_STEPS` iterations (:class:`LineSearchParameters`).
        exact_dirichlet: Set each direction to its exact value on the Dirichlet dofs
            (:meth:`exact_on_dirichlet`; for Krylov solves).
        fallback: Called with the failure message of the first linear solve that fails; returns
            the strategy that solves this and every later direction (e.g. a factorization after
            a Krylov failure), or None to fail as without it (:meth:`solve_direction`).

    Attributes:
        A: The Jacobian matrix.
        x: The unknowns as one block vector.
        linear: The :class:`~poromech.mechanics.linear.LinearStrategy` of the direction.
        condensed: The :class:`~poromech.mechanics.condensed.CondensedContact` that computes
            each solve's start (:meth:`attach_condensation`), or None.
        reference_norm: Largest initial residual norm so far (the relative tolerance's base).
        record: The :class:`NewtonRecord` of the last solve.
    """

    def __init__(
        self,
        F: Sequence[fem.Form],
        J: Sequence[Sequence[fem.Form | None]],
        unknowns: Sequence[fem.Function],
        bcs: Sequence[fem.DirichletBC],
        prefix: str = "mech_",
        options: dict | None = None,
        line_search: str = "contact",
        reuse_jacobian: bool = True,
        stale_factorization: bool = True,
        stale_priced: bool = False,
        states: Callable[[], np.ndarray] | None = None,
        states_determine_jacobian: bool = False,
        constant_jacobian: bool = False,
        constant_bulk: tuple[fem.Form, Sequence[Sequence[fem.Form | None]]] | None = None,
        modes: Callable[[], np.ndarray] | None = None,
        coarse: Callable[[], tuple[PETSc.Mat, np.ndarray]] | None = None,
        eliminate_faces: bool = False,
        inexact: bool = False,
        one_sided: bool = False,
        curved: bool = False,
        exact_dirichlet: bool = False,
        fallback: Callable[[str], LinearStrategy | None] | None = None,
    ):
        self.F, self.J, self.u, self.bcs = list(F), [list(r) for r in J], list(unknowns), list(bcs)
        self.comm = self.u[0].function_space.mesh.comm
        self.A = create_matrix(self.J)
        self.b = create_vector([f.function_space for f in self.u], kind="mpi")
        self.x = create_vector([f.function_space for f in self.u], kind="mpi")
        self._blocks = self.b.getAttr("_blocks")
        self._cache_x = self.x.duplicate()
        self._cache_f = self.b.duplicate()
        self._cache_valid = False
        # the Dirichlet conditions by block, as DOLFINx's assemble_residual arranges them
        self._bcs_rows = bcs_by_block(extract_function_spaces(self.F), self.bcs)
        self._bcs_cols = bcs_by_block(extract_function_spaces(self.J, 1), self.bcs)
        self._bc_gap = self.b.duplicate()  # x - g on the Dirichlet dofs (_dirichlet_exact)
        self._bc_gap.setAttr("_blocks", self._blocks)
        self._reaction_rows = self._dirichlet_rows()
        # this rank's ``Σ R_i²`` over the residual's rows of the Dirichlet dofs before they are
        # set (the reactions, forces in balance): summed over the ranks only where the
        # convergence test needs it (:attr:`reactions`), not at every residual
        self._reactions_local = 0.0
        self._cache_reactions = 0.0
        self._previous_fnorm = np.inf  # the last residual norm the convergence test saw
        self.line_search = line_search
        self.ls = LineSearchParameters(one_sided=one_sided,
                                       nonmonotone=NONMONOTONE_STEPS if curved else 0)
        self.reuse_jacobian = reuse_jacobian
        self.states = states
        self.states_determine_jacobian = states_determine_jacobian
        self.constant_jacobian = constant_jacobian
        self._jacobian_assembled = False  # the matrix holds an assembled Jacobian
        self._bulk = constant_bulk if reuse_jacobian else None
        self._K: PETSc.Mat | None = None  # the assembled bulk (constant_bulk)
        self._index_sets = None  # local index sets of the blocks (constant_bulk)
        self.reference_norm = 0.0
        self._forces_work: PETSc.Vec | None = None
        self._min_iterations = 0
        self._last_states = None  # active set of the current iterate
        # the points that switched at each of the last iterations (recent_switches)
        self._switched: deque[np.ndarray] = deque(maxlen=RECENT_ITERATIONS)
        self.contact_points = 0  # contact points (or faces) of the scene, counted at a solve
        self._jacobian_states = None  # active set of the assembled Jacobian
        self.condensed = None
        self.prefix = prefix
        self._eliminate_faces = eliminate_faces
        self.inexact = inexact
        self.exact_dirichlet = exact_dirichlet
        self.stale_priced = stale_priced
        self._fallback = fallback
        self._retired: list[LinearStrategy] = []  # strategies replaced by the fallback's
        self.snes, self.ksp, self.linear = self._create_snes(prefix, options or {},
                                                             stale_factorization, modes, coarse)
        if inexact and reuse_jacobian and hasattr(self.linear, "lagged"):
            self.linear.lagged = True  # a Krylov solve keeps its preconditioner while it pays
        self._step = self.snes.getPythonContext() if self._is_python() else None
        self.record = NewtonRecord()

    @property
    def petsc_options(self) -> dict:
        """This solver's options without prefix (defaults, formulation, scene)."""
        return dict(self._options.options)

    def attach_condensation(self, condensed) -> None:
        """Start every solve from the condensed solution of ``condensed`` (``mixed``)."""
        self.condensed = condensed

    # -- PETSc objects ----------------------------------------------------------------------
    def _is_python(self) -> bool:
        return self.snes.getType() == PETSc.SNES.Type.PYTHON

    def _create_snes(self, prefix: str, options: dict, stale: bool,
                     modes: Callable[[], np.ndarray] | None,
                     coarse: Callable[[], tuple[PETSc.Mat, np.ndarray]] | None = None,
                     ) -> tuple[PETSc.SNES, PETSc.KSP, LinearStrategy]:
        """The SNES, the linear strategy's KSP and the strategy.

        With poromech's search the strategy's KSP is the SNES's own; with a PETSc search it is
        a KSP of its own, and the SNES's a shell of the strategy (:class:`_LinearShell`).
        """
        snes = PETSc.SNES().create(self.comm)
        snes.setOptionsPrefix(prefix)
        merged = {**DEFAULT_OPTIONS, **options}
        if self.line_search != "contact":
            merged.update(snes_type="newtonls", snes_linesearch_type=self.line_search)
        self._options = PrefixedOptions(prefix, merged)
        with self._options:
            snes.setFunction(self._residual, self.b)
            snes.setJacobian(self._jacobian, self.A, self.A)
            snes.setFromOptions()
            python = snes.getType() == PETSc.SNES.Type.PYTHON
            ksp = snes.getKSP()
            if not python:  # the strategy gets a KSP of its own, with the same options
                ksp = PETSc.KSP().create(self.comm)
                ksp.setOptionsPrefix(prefix)
                ksp.setOperators(self.A, self.A)
                ksp.setFromOptions()
            linear = linear_strategy(ksp, self.A, prefix, reuse=self.reuse_jacobian,
                                     stale=stale, modes=modes, blocks=self._face_blocks(),
                                     coarse=coarse, priced=self.stale_priced)
        if python:
            snes.setPythonContext(_NewtonStep(self))
        else:
            _LinearShell(self).attach(snes.getKSP())
        snes.setConvergenceTest(self._converged)
        snes.setMonitor(self._monitor)
        self.A.setOptionsPrefix(f"{prefix}A_")
        return snes, ksp, linear

    def _face_blocks(self) -> tuple[list[int], list[int]] | None:
        """Owned sizes of the blocks and components per face of the face unknowns, or None."""
        if not self._eliminate_faces or len(self.u) == 1:
            return None
        maps = [(f.function_space.dofmap.index_map, f.function_space.dofmap.index_map_bs)
                for f in self.u]
        return [m.size_local * bs for m, bs in maps], [bs for _, bs in maps[1:]]

    def destroy(self) -> None:
        """Free PETSc objects."""
        if self.condensed is not None:
            self.condensed.destroy()
        if self._step is not None:
            self._step.free()
        self.linear.destroy()
        for strategy in self._retired:
            strategy.destroy()
        own_ksp = None if self._is_python() else self.ksp  # not the SNES's
        for obj in (self.snes, own_ksp, self.A, self.b, self.x, self._cache_x, self._cache_f,
                    self._K, self._bc_gap, self._forces_work):
            if obj is not None:
                obj.destroy()

    # -- callbacks --------------------------------------------------------------------------
    def _residual(self, snes, x, b) -> None:
        t0 = time.perf_counter()
        if self._cache_valid:
            self._cache_x.axpy(-1.0, x)
            same = self._cache_x.norm(PETSc.NormType.NORM_INFINITY) == 0.0
            self._cache_x.axpy(1.0, x)
            if same:
                self._cache_f.copy(b)
                self._reactions_local = self._cache_reactions
                self.record.time_assembly += time.perf_counter() - t0
                return
        self._assemble_residual(x, b)
        x.copy(self._cache_x)
        b.copy(self._cache_f)
        self._cache_reactions = self._reactions_local
        self._cache_valid = True
        self.record.residual_evaluations += 1
        self.record.time_assembly += time.perf_counter() - t0

    def _assemble_residual(self, x: PETSc.Vec, b: PETSc.Vec) -> None:
        """The residual at ``x`` into ``b``: DOLFINx's ``assemble_residual``, no no-op lifting.

        The lifting adds ``J (g - x)`` over the Dirichlet dofs, an assembly of the Jacobian's
        forms over the cells holding them (as long as the residual's own assembly on the
        eleven-fracture network). Where ``x`` equals ``g`` exactly on every Dirichlet dof it adds
        zeros and is skipped: the residual is the same to the last bit.
        """
        dolfinx.la.petsc._ghost_update(x, PETSc.InsertMode.INSERT, PETSc.ScatterMode.FORWARD)
        assign(x, self.u)
        b.setAttr("_blocks", self._blocks)
        x.setAttr("_blocks", self._blocks)
        dolfinx.la.petsc._zero_vector(b)
        assemble_vector(b, self.F)
        if not self._dirichlet_exact(x):
            apply_lifting(b, self.J, bcs=self._bcs_cols, x0=x, alpha=-1.0)
        dolfinx.la.petsc._ghost_update(b, PETSc.InsertMode.ADD, PETSc.ScatterMode.REVERSE)
        owned = b.getArray(readonly=True)[self._reaction_rows]
        self._reactions_local = float(owned @ owned)
        set_bc(b, self._bcs_rows, x0=x, alpha=-1.0)
        dolfinx.la.petsc._ghost_update(b, PETSc.InsertMode.INSERT, PETSc.ScatterMode.FORWARD)

    def _dirichlet_rows(self) -> np.ndarray:
        """The owned rows of the Dirichlet dofs in the block layout (local indices)."""
        marks = [fem.Function(f.function_space) for f in self.u]
        for mark, bcs in zip(marks, self._bcs_rows, strict=True):
            for bc in bcs:
                mark.x.array[bc.dof_indices()[0]] = 1.0
        rows = self.b.duplicate()
        assign(marks, rows)
        out = np.flatnonzero(rows.getArray(readonly=True))
        rows.destroy()
        return out

    def _dirichlet_exact(self, x: PETSc.Vec) -> bool:
        """Whether ``x`` equals the Dirichlet values exactly on every rank (collective)."""
        gap = self._bc_gap
        gap.zeroEntries()
        set_bc(gap, self._bcs_rows, x0=x, alpha=-1.0)
        return gap.norm(PETSc.NormType.NORM_INFINITY) == 0.0

    def exact_on_dirichlet(self, x: PETSc.Vec, y: PETSc.Vec) -> None:
        """Set the direction ``y`` at ``x`` to ``x - g`` on the Dirichlet dofs (if exact_dirichlet).

        That is the exact solution of the Jacobian's identity rows, which a Krylov solve only
        approximates; the other components do not depend on it (the Dirichlet columns are
        zero). A step then keeps ``x = g`` to the bit, and the residual skips its lifting.
        """
        if not self.exact_dirichlet:
            return
        for v in (x, y):
            v.setAttr("_blocks", self._blocks)
        set_bc(y, self._bcs_rows, x0=x, alpha=-1.0)

    def _jacobian(self, snes, x, A, P) -> None:
        """Assemble the Jacobian, unless the active set is that of the assembled one.

        With :attr:`states_determine_jacobian` (the contact law's Jacobian is a function of its
        branches only, and no coefficient of it changes in time) an unchanged active set (the
        codes of ``states``) means an unchanged matrix: this saves the assembly in the many
        solves of a coupled run that start in the last active set. Without
        :attr:`reuse_jacobian` the matrix is always assembled, so that the direct solver
        refactorizes it (PETSc keeps the factors of a matrix that was not modified). A
        :attr:`constant_jacobian` is assembled once.
        """
        if self.reuse_jacobian and ((self.constant_jacobian and self._jacobian_assembled)
                                    or (self.states_determine_jacobian
                                        and self._same_states(self._jacobian_states))):
            self.record.jacobian_reuses += 1
            return
        self._load(x)
        self._assemble_jacobian(A, self._last_states)

    def _load(self, x: PETSc.Vec) -> None:
        """Scatter the ghosts of ``x`` and copy it into the unknowns."""
        dolfinx.la.petsc._ghost_update(x, PETSc.InsertMode.INSERT, PETSc.ScatterMode.FORWARD)
        assign(x, self.u)

    def _assemble_jacobian(self, A: PETSc.Mat, states: np.ndarray | None) -> None:
        """Assemble the Jacobian at the loaded unknowns (:meth:`_load`) into ``A``.

        ``states`` is their active set, kept with the matrix.
        """
        t0 = time.perf_counter()
        if self._bulk is None or self._K is None:
            A.zeroEntries()
            dolfinx.fem.petsc.assemble_matrix(A, self.J, self.bcs, diag=1.0)
            A.assemble()
            if self._bulk is not None:  # the Jacobian's pattern is now final
                self._K = self._assemble_bulk(A)
        else:
            self._K.copy(A, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
            self._assemble_blocks(A, self._bulk[1])
            A.assemble()
        self._jacobian_states = None if states is None else states.copy()
        self.linear.assembled(self._jacobian_states)
        self._jacobian_assembled = True
        self.record.time_assembly += time.perf_counter() - t0

    def _assemble_bulk(self, A: PETSc.Mat) -> PETSc.Mat:
        """The constant bulk in a matrix of ``A``'s pattern (Dirichlet rows: 1 on the diagonal).

        ``A`` must hold an assembled Jacobian: an entry of the pattern that no form sets before
        the first final assembly is dropped from the matrix.
        """
        K = A.duplicate(copy=False)
        K.zeroEntries()
        n = len(self.u)
        self._assemble_blocks(K, [[self._bulk[0] if i == j == 0 else None for j in range(n)]
                                  for i in range(n)])
        K.assemble()
        return K

    def _assemble_blocks(self, A: PETSc.Mat, forms: Sequence[Sequence[fem.Form | None]]) -> None:
        """Add ``forms`` to ``A`` by blocks, without Dirichlet rows and columns (not finalised).

        The diagonal of the Dirichlet rows is set to 1 in the diagonal blocks of a form. What
        DOLFINx does for blocked forms, without its refusal of a diagonal block with no
        form (the displacement block of ``rest`` with multipliers; the rows of ``bulk``).
        """
        if self._index_sets is None:
            maps = [(f.function_space.dofmap.index_map, f.function_space.dofmap.index_map_bs)
                    for f in self.u]
            self._index_sets = _cpp.la.petsc.create_index_sets(maps)
        rows = self._index_sets
        bcs = [bc._cpp_object for bc in self.bcs]
        blocks = [(i, j, a) for i, row in enumerate(forms) for j, a in enumerate(row)
                  if a is not None]
        for i, j, a in blocks:
            sub = A.getLocalSubMatrix(rows[i], rows[j])
            _cpp.fem.petsc.assemble_matrix(sub, a._cpp_object, pack_constants(a),
                                           pack_coefficients(a), bcs, True)
            A.restoreLocalSubMatrix(rows[i], rows[j], sub)
        A.assemble(PETSc.Mat.AssemblyType.FLUSH)
        for i, j, a in blocks:
            if i == j and a.function_spaces[0] is a.function_spaces[1]:
                sub = A.getLocalSubMatrix(rows[i], rows[j])
                _cpp.fem.petsc.insert_diagonal(sub, a.function_spaces[0], bcs, 1.0)
                A.restoreLocalSubMatrix(rows[i], rows[j], sub)

    def solve_direction(self, b: PETSc.Vec, y: PETSc.Vec, states: np.ndarray | None) -> bool:
        """``J y = b`` by the linear strategy; after its first failure, by the fallback's.

        With a ``fallback`` (see the class), the first failed solve hands over to the strategy
        it returns: that one solves the same system at once and every later direction of the
        run (the failed one is kept until :meth:`destroy`). Returns whether ``y`` was solved.
        For the Newton directions, whose failure would end the solve (a one-sided direction
        that fails is only skipped, and does not hand over).
        """
        if self.linear.solve(b, y, self.record, states):
            return True
        fallback, self._fallback = self._fallback, None
        strategy = fallback(self.record.linear_failure) if fallback is not None else None
        if strategy is None:
            return False
        self.hand_over(strategy)
        if not strategy.solve(b, y, self.record, states):
            return False
        self.record.linear_failure = ""
        return True

    def hand_over(self, strategy: LinearStrategy) -> None:
        """``strategy`` solves every later direction (the fallback's, or a restart's).

        The replaced strategy is kept until :meth:`destroy`; no fallback is left.
        """
        self._fallback = None
        self._retired.append(self.linear)
        self.linear = strategy
        strategy.assembled(self._jacobian_states)

    def _same_states(self, reference) -> bool:
        """Whether the current active set equals ``reference`` on every rank (collective)."""
        same = (reference is not None and self._last_states is not None
                and np.array_equal(reference, self._last_states))
        return bool(self.comm.allreduce(same, op=MPI.LAND))

    @property
    def active_set(self) -> np.ndarray | None:
        """Active-set codes of the current iterate (None without states)."""
        return self._last_states

    @property
    def recent_switches(self) -> np.ndarray | None:
        """State changes of each owned contact point in the last solve's last iterations.

        Counted over its last :data:`RECENT_ITERATIONS` iterations, in the order of the
        ``states`` codes; None without states.
        """
        if self._last_states is None:
            return None
        counts = np.zeros(self._last_states.shape, dtype=np.int32)
        for switched in self._switched:
            counts += switched
        return counts

    def set_forcing_term(self) -> None:
        """With :attr:`inexact` and a Krylov strategy, the tolerance of the next direction's solve.

        As accurate as the Newton needs (:func:`~poromech.mechanics.linear.forcing_term`), from
        the residual norms recorded so far.
        """
        if not (self.inexact and hasattr(self.linear, "set_tolerance")):
            return
        res = self.record.residuals
        target = self.snes.getTolerances()[0] * self.reference_norm
        changes = self.record.active_set_changes
        switched = bool(changes) and changes[-1] > SWITCHED_FRACTION * self.contact_points
        self.record.switched_solves += switched
        self.linear.set_tolerance(forcing_term(res[-1], res[-2] if len(res) > 1 else None,
                                               target, self.linear.tightest, switched))

    def _converged(self, snes, it, norms):
        xnorm, ynorm, fnorm = norms
        rtol, atol, stol, max_it = snes.getTolerances()
        forced = None if self._step is None else self._step.forced_reason
        if forced is not None:
            return forced
        if it == 0:
            self.reference_norm = max(self.reference_norm, fnorm)
        stalled = it > 0 and fnorm > ROUNDOFF_STALL * self._previous_fnorm
        self._previous_fnorm = fnorm
        R = PETSc.SNES.ConvergedReason
        if not np.isfinite(fnorm):
            return R.DIVERGED_FUNCTION_NANORINF
        if it < self._min_iterations:
            return R.ITERATING
        if fnorm <= atol:
            return R.CONVERGED_FNORM_ABS
        if fnorm <= rtol * self.reference_norm:
            return R.CONVERGED_FNORM_RELATIVE
        if fnorm <= ROUNDOFF_FLOOR * self.reactions:
            return R.CONVERGED_FNORM_ABS  # at the round-off of the reactions
        if it > 0 and fnorm <= ROUNDOFF_WINDOW * rtol * self.reference_norm \
                and fnorm <= ROUNDOFF_FLOOR * self._forces(snes.getSolution()):
            return R.CONVERGED_FNORM_ABS  # at round-off
        if stalled and fnorm <= ROUNDOFF_STALL_WINDOW * rtol * self.reference_norm \
                and fnorm <= ROUNDOFF_DIAGONAL * self._stiff_terms(snes.getSolution()):
            return R.CONVERGED_FNORM_ABS  # stalled at the round-off of the summed terms
        if it > 0 and stol > 0 and ynorm <= stol * xnorm:
            return R.CONVERGED_SNORM_RELATIVE
        if it >= max_it:
            return R.DIVERGED_MAX_IT
        return R.ITERATING

    @property
    def reactions(self) -> float:
        """``‖R‖`` over the Dirichlet rows of the last residual: the reactions (collective)."""
        return float(np.sqrt(self.comm.allreduce(self._reactions_local)))

    def _stiff_terms(self, x: PETSc.Vec) -> float:
        """``‖diag(J) x‖`` with the last assembled Jacobian, the size of the residual's terms."""
        if not self._jacobian_assembled:
            return 0.0
        work = self._work()
        self.A.getDiagonal(work)
        work.pointwiseMult(work, x)
        return work.norm()

    def _forces(self, x: PETSc.Vec) -> float:
        """``‖J x‖`` with the last assembled Jacobian, the size of the forces in balance."""
        if not self._jacobian_assembled:
            return 0.0
        work = self._work()
        self.A.mult(x, work)
        return work.norm()

    def _work(self) -> PETSc.Vec:
        """A work vector of the residual's layout (created at the first use)."""
        if self._forces_work is None:
            self._forces_work = self.b.duplicate()
        return self._forces_work

    def _monitor(self, snes, it, fnorm) -> None:
        self.record.residuals.append(float(fnorm))
        if self.states is not None:
            self._load(snes.getSolution())
            s = self.states()
            if self._last_states is not None and it > 0:
                switched = s != self._last_states
                self._switched.append(switched)
                self.record.active_set_changes.append(
                    int(self.comm.allreduce(int(np.count_nonzero(switched)))))
            elif it == 0:
                self.contact_points = int(self.comm.allreduce(s.size))
            self._last_states = s
        if log.isEnabledFor(logging.DEBUG):  # with the step taken and the states it switched
            r, extra = self.record, ""
            if it > 0 and r.steps:
                extra = f", step {r.steps[-1]:.3g}"
            if it > 0 and r.active_set_changes:
                extra += f", {r.active_set_changes[-1]} state changes"
            log.debug("%sNewton %d: |F| = %.3e%s", self.prefix, it, fnorm, extra)

    # -- solve ------------------------------------------------------------------------------
    def solve(self, min_iterations: int = 0) -> NewtonRecord:
        """Solve from the current unknowns; update them in place (collective).

        Args:
            min_iterations: Newton steps taken even when the initial residual already meets
                the tolerance (a response to tiny changes of the data, for finite-difference
                Jacobians of the coupling).

        Returns:
            The record of this solve; ``record.converged`` tells whether it converged.
        """
        self.record = NewtonRecord()
        self._last_states = None
        self._switched.clear()
        self._cache_valid = False
        if self._step is not None:
            self._step.reset()
        assign(self.u, self.x)
        self._min_iterations = min_iterations
        if self.condensed is not None and self._condensed_start(min_iterations):
            self._min_iterations = 0  # the face Newton has already responded to the data
        try:
            with self._options:  # the factorization reads its options (mat_mumps_*) at set-up
                self.snes.solve(None, self.x)
        finally:
            self._min_iterations = 0
        self._load(self.x)
        r = self.record
        reason = self.snes.getConvergedReason()
        r.reason = reason_name(reason)
        r.converged = reason > 0
        r.iterations = self.snes.getIterationNumber()
        r.linear_iterations += self.snes.getLinearSolveIterations()
        return r

    def prime_preconditioner(self) -> None:
        """Set the Krylov preconditioner up on the Jacobian at the current unknowns (collective).

        For a restart, at the run's initial unknowns (:meth:`MechanicsPhysics.restore
        <poromech.mechanics.physics.MechanicsPhysics.restore>`): see the linear strategy's
        ``prime``. Nothing with a direct solver. The set-up is not counted in a record.
        """
        prime = getattr(self.linear, "prime", None)
        if prime is None:
            return
        assign(self.u, self.x)
        with self._options:
            self._load(self.x)
            states = self.states() if self.states is not None else None
            self._assemble_jacobian(self.A, states)
            prime(NewtonRecord())

    def merit_here(self) -> float:
        """The line search's merit of the residual at the current unknowns (collective).

        Scaled as in the last solve (:meth:`_NewtonStep._set_scale`), or ``‖F‖`` before the
        first solve and for systems with multipliers or face averages. Not counted in the next
        solve's record (which resets the residual cache).
        """
        assign(self.u, self.x)
        self._cache_valid = False  # the unknowns changed outside the SNES
        self._residual(self.snes, self.x, self.b)
        return self.b.norm() if self._step is None else self._step.merit_as_last(self.b)

    def _condensed_start(self, min_iterations: int) -> bool:
        """Start from the condensed solution (:mod:`~poromech.mechanics.condensed`); True if it did.

        The residual at the current unknowns sets the reference norm exactly as the first
        iteration of the regular Newton would; the face problem is solved to a fraction of the
        regular tolerance (:data:`~poromech.mechanics.condensed.SAFETY`), which the regular Newton
        then checks with an assembled residual; a failed face Newton leaves the unknowns as they
        were.
        """
        t0 = time.perf_counter()
        self._residual(self.snes, self.x, self.b)
        f0 = self.b.norm()
        if not np.isfinite(f0):  # the regular Newton reports it
            return False
        self.reference_norm = max(self.reference_norm, f0)
        t1 = time.perf_counter()
        rtol = self.snes.getTolerances()[0]
        out = self.condensed.solve(self.x, self.b, rtol * self.reference_norm, min_iterations)
        r = self.record
        r.face_iterations += out["iterations"]
        if not out["converged"]:
            log.debug("%scondensed face Newton did not converge (%d iterations, |R| %s); "
                      "regular Newton from the start", self.prefix, out["iterations"],
                      ", ".join(f"{v:.3e}" for v in out["residuals"][-5:]))
        r.time_linear += time.perf_counter() - t1
        r.time_assembly += t1 - t0
        return bool(out["converged"])


class _LinearShell:
    """PETSc's Newton (a PETSc line search, ``newtonls``) solves its directions by the strategy.

    PETSc's ``newtonls`` calls its own KSP; that KSP becomes ``preonly`` with this Python
    preconditioner, whose application is the solver's
    :class:`~poromech.mechanics.linear.LinearStrategy` (a factorization kept while it may be,
    the p-multigrid with its coarse operator and block copy, the face elimination), each with
    its own KSP configured by the same options. A failed solve is the preconditioner's failure,
    which PETSc reports as ``DIVERGED_LINEAR_SOLVE``.
    """

    def __init__(self, solver: SemiSmoothNewton):
        self.s = solver

    def attach(self, ksp: PETSc.KSP) -> None:
        """Make ``ksp`` (the SNES's) a ``preonly`` KSP with this preconditioner."""
        ksp.setType(PETSc.KSP.Type.PREONLY)
        ksp.setErrorIfNotConverged(False)
        pc = ksp.getPC()
        pc.setType(PETSc.PC.Type.PYTHON)
        pc.setPythonContext(self)

    def apply(self, pc, x, y) -> None:
        s = self.s
        t0 = time.perf_counter()
        s.set_forcing_term()
        solved = s.solve_direction(x, y, s.active_set)
        s.record.time_linear += time.perf_counter() - t0
        if not solved:
            s.linear.forget()
            pc.setFailedReason(PETSc.PC.FailedReason.SUBPC_ERROR)


class _NewtonStep:
    """Python context of the SNES: the Newton direction and the line search.

    Owns the line search's state: the watchdog count of non-decreasing steps and the reason it
    forces on the SNES (a failed linear solve, an exhausted watchdog, only non-finite trials).
    """

    def __init__(self, solver: SemiSmoothNewton):
        self.s = solver
        self._trial = solver.x.duplicate()
        self._trial_f = solver.b.duplicate()
        self._direction = solver.x.duplicate()  # the one-sided direction
        # merit scaling of the line search, displacement-only systems (_set_scale)
        single = len(solver.u) == 1
        self.scale = solver.b.duplicate() if single else None
        self._scaled = solver.b.duplicate() if single else None
        self.watchdog = 0
        self.forced_reason = None
        self._scale_set = False
        self._one_sided_run = 0  # consecutive steps taken along one-sided directions
        self._one_sided_off = False
        # the iterate, direction and merit before a run of full steps against the merit
        nonmonotone = solver.ls.nonmonotone > 0
        self._anchor_x = solver.x.duplicate() if nonmonotone else None
        self._anchor_y = solver.x.duplicate() if nonmonotone else None
        self._anchor_f: float | None = None
        self._run = 0  # iterations since the anchor
        self._smooth = False  # no trial of the current search switched a contact point

    def reset(self) -> None:
        """Before a solve: no watchdog count, no forced reason, the merit scale to be set."""
        self.watchdog = 0
        self.forced_reason = None
        self._scale_set = False
        self._one_sided_run = 0
        self._one_sided_off = False
        self._anchor_f = None
        self._run = 0

    def free(self) -> None:
        """Free the work vectors (``destroy`` is PETSc's hook on this context: not used)."""
        for v in (self._trial, self._trial_f, self._direction, self.scale, self._scaled,
                  self._anchor_x, self._anchor_y):
            if v is not None:
                v.destroy()

    def step(self, snes, X, F, Y) -> None:
        s = self.s
        snes.computeJacobian(X, s.A, s.A)
        t0 = time.perf_counter()
        s.set_forcing_term()
        solved = s.solve_direction(F, Y, s.active_set)
        s.record.time_linear += time.perf_counter() - t0
        if not solved:
            self.forced_reason = PETSc.SNES.ConvergedReason.DIVERGED_LINEAR_SOLVE
            s.linear.forget()
            Y.set(0.0)
            return
        s.exact_on_dirichlet(X, Y)
        alpha = self._line_search(snes, X, F, Y)
        s.record.steps.append(alpha)
        if alpha != 1.0:
            Y.scale(alpha)

    def _norm_at(self, snes, X, Y, alpha: float) -> float:
        self._trial.waxpy(-alpha, Y, X)
        snes.computeFunction(self._trial, self._trial_f)
        if self._smooth:  # no trial so far switched a contact point: does this one?
            self._smooth = self._same_states_at_trial()
        return self._merit(self._trial_f)

    def _same_states_at_trial(self) -> bool:
        """Whether every contact point has at the trial the state it has at ``x`` (collective)."""
        self.s._load(self._trial)
        return self.s._same_states(self.s.states())

    def merit_as_last(self, F: PETSc.Vec) -> float:
        """:meth:`_merit` with the scale of the last solve; ``‖F‖`` while none is set."""
        return self._merit(F) if self._scale_set else F.norm()

    def _merit(self, F: PETSc.Vec) -> float:
        """``‖D^{-1/2}F‖`` (displacement-only systems, :meth:`_set_scale`) or ``‖F‖``."""
        if self.scale is None:
            return F.norm()
        self._scaled.pointwiseMult(F, self.scale)
        return self._scaled.norm()

    def _set_scale(self) -> None:
        """``D^{-1/2} = |diag J|^{-1/2}`` from the first Jacobian of the solve (Nitsche).

        The rows of ``F`` are forces and ``J_ii`` stiffnesses, so ``Σ F_i²/J_ii`` is an energy:
        the merit weighs the dofs by energy rather than by force, and the few dofs at corners and
        tips where ``β/h`` makes residuals large no longer dictate the step (they did in the
        six-fracture scene: one dof at the corner of fracture 1 carried 90 % of ``‖F‖²`` after a
        rejected full step). The scale is kept for the whole solve: rescaled at every iteration,
        with the diagonal of the current active set, the merit changed under the line search
        (a step accepted at 7.7e-6 measured 1.7e-5 at the next iteration) and the first step of
        the six-fracture mechanics scene took 16 iterations on a 47k-cell mesh
        (docs/mechanics/newton_scaling.md). With multipliers or face averages the rows have
        different units and the plain norm is kept.
        """
        if self.scale is None or self._scale_set:
            return
        self._scale_set = True
        self.s.A.getDiagonal(self.scale)
        d = np.abs(self.scale.getArray())
        d[d == 0.0] = 1.0
        self.scale.setArray(1.0 / np.sqrt(d))

    def _line_search(self, snes, X, F, Y) -> float:
        """The step length ``α`` (0 when the search gives up); ``Y`` may be replaced."""
        self._set_scale()
        f0 = self._merit(F)
        if self._anchor_f is not None:  # in a run of full steps against the merit
            if f0 <= (1 - self.s.ls.armijo) * self._anchor_f:
                self._anchor_f = None  # it paid off
            elif self._run >= self.s.ls.nonmonotone:
                return self._back_to_anchor(snes, X, Y)
            else:
                self._run += 1
        before = (self.watchdog, self.forced_reason)
        alpha, full = self._choose_step(snes, X, Y, f0, nonmonotone=True)
        if full:
            return alpha
        nan = PETSc.SNES.ConvergedReason.DIVERGED_FUNCTION_NANORINF
        if (self.watchdog == 0 or not self.s.ls.one_sided or self._one_sided_off
                or self.forced_reason == nan):
            self._one_sided_run = 0
            return alpha
        after = (self.watchdog, self.forced_reason)
        Z = self._one_sided(snes, X, F, Y)
        if Z is not None:
            self.watchdog, self.forced_reason = before
            beta = self._choose_step(snes, X, Z, f0)[0]
            if self.watchdog == 0:  # Armijo
                Z.copy(Y)
                self._one_sided_run += 1
                # two in a row: no switch is being crossed, the search creeps (short steps on
                # a fixed active set), and each one-sided direction only adds a factorization
                self._one_sided_off = self._one_sided_run >= 2
                return beta
        self._one_sided_run = 0
        self.watchdog, self.forced_reason = after
        return alpha

    def _one_sided(self, snes, X, F, Y) -> PETSc.Vec | None:
        """The direction of the Jacobian at ``X - 2⁻ˢY`` for the residual at ``X``, or None.

        None when its linear solve fails. The points at a switch along the ray are there on the
        branch the ray enters (a one-sided element of the generalized Jacobian); the matrix is
        kept as the assembled Jacobian, with that point's active set.
        """
        s = self.s
        self._trial.waxpy(-(2.0 ** -s.ls.samples), Y, X)
        s._load(self._trial)
        states = s.states() if s.states is not None else None
        s._assemble_jacobian(s.A, states)
        s.record.one_sided += 1
        t0 = time.perf_counter()
        # not solve_direction: a failed one-sided solve only skips this direction, the run
        # keeps its solver
        solved = s.linear.solve(F, self._direction, s.record, states)
        s.record.time_linear += time.perf_counter() - t0
        if not solved:
            s.linear.forget()
            return None
        s.exact_on_dirichlet(X, self._direction)
        return self._direction

    def _choose_step(self, snes, X, Y, f0: float, nonmonotone: bool = False
                     ) -> tuple[float, bool]:
        """Step length, and whether it is a full step taken against the merit.

        The step length is 0 when the search gives up. The full step is taken when it
        satisfies Armijo's condition; otherwise the best step of a search of ``‖F(x - αY)‖`` on
        ``(0, 1)`` (:meth:`_minimize`), when it satisfies it; with ``nonmonotone``, the full
        step instead when no trial of the search switched a contact point
        (:meth:`_record_full_step`).
        """
        p = self.s.ls
        f1 = self._norm_at(snes, X, Y, 1.0)
        if np.isfinite(f1) and f1 <= (1 - p.armijo) * f0:
            self.watchdog = 0
            return 1.0, False
        self._smooth = nonmonotone and self._may_run() and self._same_states_at_trial()
        fa, alpha = self._minimize(snes, X, Y, f1)
        smooth, self._smooth = self._smooth, False
        if smooth and np.isfinite(f1):
            self._record_full_step(X, Y, f0, f1)
            return 1.0, True
        if fa <= (1 - p.armijo * alpha) * f0:
            self.watchdog = 0
            return alpha, False
        self.watchdog += 1
        if not np.isfinite(fa):  # every trial residual is NaN or infinite
            self.forced_reason = PETSc.SNES.ConvergedReason.DIVERGED_FUNCTION_NANORINF
            return 0.0, False
        if self.watchdog > p.max_watchdog:
            self.forced_reason = PETSc.SNES.ConvergedReason.DIVERGED_LINE_SEARCH
            return 0.0, False
        return alpha, False

    def _may_run(self) -> bool:
        """Whether a full step against the merit is allowed now (see :meth:`_record_full_step`)."""
        s = self.s
        return (s.ls.nonmonotone > 0 and s.states is not None
                and (self._anchor_f is None or self._run < s.ls.nonmonotone))

    def _record_full_step(self, X, Y, f0: float, f1: float) -> None:
        """Record the full step to ``X - Y`` (merit ``f1 > f0``) taken against the merit.

        Only on a curved contact law (``nonmonotone``), within the run's iterations, when no
        trial of the search switched a contact point. The first such step anchors the run at
        ``X``, ``Y`` and ``f0``.
        """
        s = self.s
        if self._anchor_f is None:
            X.copy(self._anchor_x)
            Y.copy(self._anchor_y)
            self._anchor_f, self._run = f0, 1
        s.record.nonmonotone_steps += 1
        log.debug("%sNewton: full step on a smooth piece, merit %.3e -> %.3e", s.prefix, f0, f1)

    def _back_to_anchor(self, snes, X, Y) -> float:
        """End a run of full steps that did not pay off: the searched step from its anchor.

        Sets ``Y`` so that ``X - Y`` is the anchor's iterate moved by the step the search finds
        along the anchor's direction; returns 1 (``Y`` is the whole update).
        """
        f_anchor, self._anchor_f = self._anchor_f, None
        self.s.record.nonmonotone_returns += 1
        alpha = self._choose_step(snes, self._anchor_x, self._anchor_y, f_anchor)[0]
        log.debug("%sNewton: full steps on a smooth piece did not pay off; back to the "
                  "iterate before them, step %.3g along its direction", self.s.prefix, alpha)
        Y.waxpy(-1.0, self._anchor_x, X)
        Y.axpy(alpha, self._anchor_y)
        return 1.0

    def _minimize(self, snes, X, Y, f1: float) -> tuple[float, float]:
        """Approximate minimizer of ``‖F(x - αY)‖`` on ``(0, 1]``: ``(norm, α)``.

        The norm is sampled at ``α = 2⁻ʲ``, ``j = 1 … samples``, and the best sample is refined
        by golden-section steps on ``[α/2, 2α]``. Residual evaluations only; non-finite norms
        count as infinite.
        """
        p = self.s.ls

        def norm(alpha: float) -> float:
            f = self._norm_at(snes, X, Y, alpha)
            return f if np.isfinite(f) else np.inf

        best = (f1 if np.isfinite(f1) else np.inf, 1.0)
        for j in range(1, p.samples + 1):
            best = min(best, (norm(2.0**-j), 2.0**-j))
        lo, hi = 0.5 * best[1], min(1.0, 2.0 * best[1])
        g = 0.5 * (np.sqrt(5.0) - 1.0)
        for _ in range(p.refinements):
            a, b = hi - g * (hi - lo), lo + g * (hi - lo)
            fa, fb = norm(a), norm(b)
            best = min(best, (fa, a), (fb, b))
            lo, hi = (lo, b) if fa < fb else (a, hi)
        return best
