"""The contact-mechanics problem on a fractured mesh: spaces, unknowns, forms, loads, diagnostics.

Only what a scene needs is built: no multiplier or face-average spaces for Nitsche, no tangential
terms without friction, no contact terms at all for open (``formulation: none``) fractures, no
fracture submesh when there are no fractures.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import dolfinx_solver  # noqa: F401

import basix
import basix.ufl
import dolfinx
import dolfinx.fem.petsc
import numpy as np
import numpy.typing as npt
import ufl
from dolfinx import fem
from mpi4py import MPI
from petsc4py import PETSc

from poromech.errors import ConfigError
from poromech.forms import contact as cforms
from poromech.forms.elasticity import (
    biot_stress_form,
    elastic_form,
    epsilon,
    initial_stress_form,
)
from poromech.forms.fracture import (
    FractureKinematics,
    face_max,
    magnitude,
    normal_jump,
    slip,
)
from poromech.mechanics.coercivity import symmetric_nitsche_ratio
from poromech.mesh.entities import domain_extent
from poromech.mesh.fractured import (
    FRACTURE_TAG,
    FracturedMesh,
    cracked_space,
    face_size,
    fracture_measure,
)
from poromech.scene.expressions import Expression
from poromech.scene.schema import NITSCHE_FORMULATIONS, Contact, Scene

__all__ = ["FACE_FIELDS", "FACE_FIELDS_3D", "IMBALANCE_LIMIT", "MechanicsModel", "PressureCoupling",
           "SLIP_TOLERANCE", "STATE_NAMES"]

log = logging.getLogger("poromech")

#: Fracture face fields (DG0 on the fracture mesh), in storage order: face means (over the
#: contact quadrature) of the jumps (m), the contact tractions and the friction bound ``S``
#: (Pa), and the fractions of the face in contact and sliding.
FACE_FIELDS = ("jump_n", "jump_t", "traction_n", "traction_t", "friction_bound",
               "contact_fraction", "slip_fraction")
#: The assembled face means in 3D: the tangential jump and traction as vectors in global
#: coordinates (:meth:`MechanicsModel.face_fields` adds their magnitudes ``jump_t``,
#: ``traction_t``).
#: ``traction_t_mean`` is the face mean of ``|T_τ|``, which the states compare with the friction
#: bound (the magnitude of the mean vector is smaller where the direction turns on a face).
FACE_FIELDS_3D = ("jump_n", "jump_tx", "jump_ty", "jump_tz", "traction_n", "traction_tx",
                  "traction_ty", "traction_tz", "friction_bound", "contact_fraction",
                  "slip_fraction", "traction_t_mean")
#: Contact states written to the output, by code (see :meth:`MechanicsModel.states`).
STATE_NAMES = ("open", "stick", "slip")
#: Relative tolerance of "on the friction bound": a closed face slips when
#: ``|traction_t| >= (1 - SLIP_TOLERANCE) friction_bound``.
SLIP_TOLERANCE = 1e-6
#: Largest imbalance of the initial stress, relative to its load scale, accepted before the
#: first solve: beyond, ``material.initial_stress`` is refused (it would move the body at t = 0).
#: Below it the imbalance is the discretization's (a stress not polynomial in space) and is
#: reported in the summary.
IMBALANCE_LIMIT = 1e-3
#: Ratio of the largest Young's modulus to that of the rock at a fracture face from which a
#: default β⁰ (a multiple of the largest) is reported as too stiff there. Measured on a fracture
#: in rock softer than the 1e11 Pa above it (nitsche P2, Coulomb): 11, 12, 29 Newton iterations
#: at ratios 10, 33, 100, and no convergence at 1000.
SOFT_CONTRAST = 30.0
#: The range of ``β⁰/E_max`` over which docs/mechanics.md ("Robustness on stiff and extreme
#: cases") verifies the Nitsche formulations; a given ``contact.beta_n`` or ``beta_t`` outside
#: it is warned about. A user's inclined crack at β_τ⁰ = 1e-4 E (θ = -1) converged with 15 of
#: its 26 sliding faces called stick; at 1e8 E its Newton stalled at round-off.
BETA_RANGE = (0.1, 1e6)
#: β_n⁰ below this fraction of the largest Young's modulus is reported for pointwise ``nitsche``
#: with Coulomb friction in 3D. configs/network3d.yaml (P1, θ = -1): at β_n⁰ = 0.01 E the
#: compression step crept (steps of about 0.011 for 80 iterations) and failed at every cut; at
#: 0.1 E 5/5/4/5 Newton iterations. At 0.01 E θ = 0, Tresca, frictionless, ``mean_nitsche``
#: and 2D (the six-fracture scene) converge.
SMALL_BETA_COULOMB_3D = 0.1
#: β_τ⁰ below this fraction of β_n⁰ is reported for the Nitsche formulations (``nitsche``,
#: ``mean_nitsche``, ``stabilized_mixed``, θ ≠ 0) with Coulomb friction and P2 displacements in
#: 3D; the defaults' ratio is 10/250. The linearized friction bound couples the tangential rows
#: to the normal jump through ``θ F β_n/β_τ σ_τ(v)``. configs/network3d.yaml (P2, β_n⁰ = 250 E):
#: at β_τ⁰ = 10 E 6/9/8/9 Newton iterations; at 3 E, 2.5 E and E the Krylov solves of
#: ``nitsche`` break down at the first step (at E also those of ``mean_nitsche`` and
#: ``stabilized_mixed``, which converge once MUMPS takes over: docs/mechanics3d.md), and at E
#: ``nitsche``'s Newton does not converge in 100 iterations with MUMPS either; β_n⁰ = 2500 E,
#: β_τ⁰ = 10 E converged in 9/16/18/32. At β_τ⁰ = E converge: θ = 0 (6/17/10/13), β_n⁰ = 25 E
#: (6/8/7/7), and P1 (8/8/6/9).
SMALL_BETA_T_RATIO_3D = 1 / 25
#: Poisson's ratio from which P1 displacements are warned of volumetric locking (the jump error
#: of the inclined crack: 0.04 at ν = 0.25, 0.17 at 0.49, 0.5 at 0.499; docs/mechanics.md).
LOCKING_POISSON = 0.49
#: Poisson's ratio from which pointwise ``nitsche`` with Coulomb friction and θ ≠ 0 is warned
#: that its Newton may cycle: the friction bound ``F [σ_n(u) - β_n [[u]]_n]_-`` takes the normal
#: stress at each point, in which ``λ div u`` weighs ``λ/μ = 2ν/(1 - 2ν)`` times the shear terms
#: (999 at 0.4995). The six-fracture scene (P2, θ = -1, F = 0.5) converges at 0.499 (9 Newton
#: iterations in its first step) and fails from 0.4995 (one point switching between stick and
#: slip at every iteration, steps of about 0.01, also at dt/16); configs/network3d.yaml fails at
#: 0.4999. θ = 0, Tresca, frictionless, ``stabilized_mixed`` and ``mean_nitsche`` converge there
#: up to 0.49999, and ``mixed`` in 2D (condensed); the uncondensed ``mixed`` of 3D fails at
#: 0.4995 and 0.4999 on configs/network3d.yaml (Coulomb), and is warned of from here too
#: (docs/mechanics/incompressible.md).
INCOMPRESSIBLE_FRICTION_POISSON = 0.4995
#: Components of an initial stress by dimension, as ``(i, j)`` in the order of the scene key.
_STRESS_INDEX = {2: ((0, 0), (1, 1), (0, 1)),
                 3: ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))}


def _force_densities(W: fem.FunctionSpace,
                     loads: list[npt.NDArray[np.float64]]) -> list[npt.NDArray[np.float64]]:
    """Force densities: the L² representers of owned load vectors (collective).

    ``z`` with ``M z = b``, ``M`` the mass matrix of ``W``, for each ``b`` of shape ``(n, bs)``.
    """
    u, v = ufl.TrialFunction(W), ufl.TestFunction(W)
    M = dolfinx.fem.petsc.assemble_matrix(fem.form(ufl.inner(u, v) * ufl.dx))
    M.assemble()
    ksp = PETSc.KSP().create(W.mesh.comm)
    ksp.setOperators(M)
    ksp.setType("cg")
    ksp.getPC().setType("jacobi")
    ksp.setTolerances(rtol=1e-10, atol=0.0, max_it=1000)
    b, z = M.createVecRight(), M.createVecLeft()
    out = []
    try:
        for load in loads:
            b.array[:] = np.asarray(load).ravel()
            ksp.solve(b, z)
            out.append(z.array.reshape(np.shape(load)).copy())
    finally:
        for obj in (ksp, M, b, z):
            obj.destroy()
    return out


@dataclass
class _Updater:
    """A time-dependent input: re-interpolate ``target`` from ``expr`` at each time."""

    target: fem.Function | fem.Constant
    exprs: tuple[Expression, ...]

    def __call__(self, t: float) -> None:
        if isinstance(self.target, fem.Constant):
            vals = [e.value(t) for e in self.exprs]
            self.target.value = vals[0] if len(vals) == 1 else np.array(vals)
            return
        exprs = self.exprs  # DOLFINx gives the points as x (3, n)
        self.target.interpolate(
            lambda x: np.vstack([e(x.T, t) for e in exprs]) if len(exprs) > 1
            else exprs[0](x.T, t)
        )
        self.target.x.scatter_forward()


@dataclass(frozen=True)
class PressureCoupling:
    """How fluid pressures enter the mechanics of a coupled (poromechanics) run.

    The model then has a matrix pressure ``p_m`` (DG0 on the cells, when ``biot > 0``) in the
    total stress ``σ(u) - b p_m I`` and a fracture pressure ``p_f`` (DG0 on the fracture faces)
    on both fracture faces, both set by :meth:`MechanicsModel.set_pressures`, and it computes the
    cell means of ``div u`` (:meth:`MechanicsModel.cell_divergence`) for the porosity.

    Attributes:
        biot: Biot coefficient ``b``.
        relative: The Biot term acts on ``p_m - p⁰`` (:meth:`MechanicsModel.set_reference_pressure`)
            instead of ``p_m``: with an initial (total) stress, which already holds the initial
            pressure's share.
    """

    biot: float
    relative: bool = False


def _facet_submesh(fm: FracturedMesh):
    """The fracture faces as a 1D mesh, with its entity map to the parent facets (collective)."""
    tdim = fm.msh.topology.dim
    sub, emap, _, _ = dolfinx.mesh.create_submesh(fm.msh, tdim - 1, fm.fracture_facets_all)
    return sub, emap


@dataclass
class MechanicsModel:
    """Unknowns and compiled forms of the static/quasi-static contact problem.

    Attributes:
        fm: The fractured mesh.
        scene: The scene.
        pressures: The pressure coupling of a poromechanics run, or None.
        V: Displacement space (duplicated nodes across fractures).
        u: Displacement (m).
        unknowns: ``[u, λ?, averages?]`` in block order.
        F: Compiled residual blocks.
        J: Compiled Jacobian blocks (None entries for zero blocks).
        J_split: ``J`` as ``(bulk, rest)`` when it has contact terms: ``bulk`` the elastic
            stiffness (cell integrals of the displacement block, a function of ``E`` and ``ν``
            only), ``rest`` the blocks of ``J`` without it; None for a linear problem.
        bcs: Dirichlet conditions on ``V``.
        linear: True when no term depends nonlinearly on the unknowns (open fractures).
    """

    fm: FracturedMesh
    scene: Scene
    pressures: PressureCoupling | None = None
    V: fem.FunctionSpace = field(init=False)
    u: fem.Function = field(init=False)
    unknowns: list[fem.Function] = field(init=False)
    F: list[fem.Form] = field(init=False)
    J: list[list[fem.Form | None]] = field(init=False)
    J_split: tuple[fem.Form, list[list[fem.Form | None]]] | None = field(init=False)
    bcs: list[fem.DirichletBC] = field(init=False)
    linear: bool = field(init=False)

    def __post_init__(self) -> None:
        scene, fm = self.scene, self.fm
        msh = fm.msh
        self._updaters: list[_Updater] = []
        self.V = cracked_space(fm, scene.degree)
        self.u = fem.Function(self.V, name="u")
        self.has_fractures = fm.num_fracture_faces > 0
        self.params = self._contact_parameters()
        if scene.degree == 1:
            self._check_locking()
        c = self.params
        self.submesh, self.emap = _facet_submesh(fm) if self.has_fractures else (None, None)
        self.entity_maps = [self.emap] if self.emap is not None else []
        Q0 = fem.functionspace(msh, ("DG", 0))
        self.young = self._field(Q0, scene.material.young, "young")
        self.poisson = self._field(Q0, scene.material.poisson, "poisson")
        self.initial_stress = self._initial_stress()
        self.unknowns = [self.u]
        self.lam = self.avg = None
        if c.active and self.has_fractures:
            k = cforms.multiplier_size(c)
            if k:
                self.lam = fem.Function(self._dg0(k), name="lambda")
                self.unknowns.append(self.lam)
            names = cforms.average_names(c)
            if names:
                self.avg = fem.Function(self._dg0(len(names)), name="averages")
                self.unknowns.append(self.avg)
        self.u_prev = fem.Function(self.V, name="u_prev") if self._quasi_static else None
        self._pressure_fields(Q0)
        self.kinematics = self._kinematics()
        self.bcs = self._dirichlet()
        self._build_forms()
        #: The imbalance of the initial stress (``initial_state`` in the summary), or None.
        self.initial_state = self._check_initial_stress() if self.initial_stress is not None \
            else None

    # -- inputs -----------------------------------------------------------------------------
    @property
    def _quasi_static(self) -> bool:
        c = self.scene.contact
        return (self.scene.time is not None and c.formulation != "none"
                and c.friction != "frictionless")

    def _contact_parameters(self) -> cforms.ContactParameters:
        """Contact parameters; ``β⁰`` defaults to multiples of the largest Young's modulus.

        With ``contact.beta_scaling: local`` the Nitsche formulations' ``β`` of a face is
        weighted by ``E_σ/E_max`` (:attr:`beta_weight`, ``E_σ`` the larger modulus of its two
        cells): ``β⁰`` is then the value at the stiffest rock.

        Also sets ``beta0 = (β_n⁰, β_τ⁰)`` (Pa) and ``young_max`` (Pa, at t = 0), and warns when
        θ = 1 is used below its coercivity bound (:mod:`poromech.mechanics.coercivity`), and
        when a 3D scene with Coulomb friction and θ ≠ 0 takes β_n⁰ below
        :data:`SMALL_BETA_COULOMB_3D` times the largest Young's modulus (``nitsche``) or, with
        P2, β_τ⁰ below :data:`SMALL_BETA_T_RATIO_3D` times β_n⁰ (the Nitsche formulations).
        """
        c, msh = self.scene.contact, self.fm.msh
        h = face_size(msh)("+")
        fc = fem.Constant(msh, c.friction_coefficient) if c.friction == "coulomb" else None
        s = None
        if c.friction == "tresca":
            s = fem.Constant(msh, c.slip_bound.value())
            self._updaters.append(_Updater(s, (c.slip_bound,)))
        young = _cell_values(msh, self.scene.material.young)
        self.young_max = msh.comm.allreduce(float(young.max(initial=0.0)), op=MPI.MAX)
        def given_or_default(value: float | None, per_young: float) -> float:
            return value if value is not None else per_young * self.young_max

        self.beta0 = (given_or_default(c.beta_n, Contact.BETA_N_PER_E),
                      given_or_default(c.beta_t, Contact.BETA_T_PER_E))
        formulation = c.formulation if self.fm.num_fracture_faces else "none"
        #: ``(β_n^sm⁰, β_τ^sm⁰)`` (Pa) of ``mixed``, whose complementarity functions take them in
        #: place of Nitsche's ``β`` (they do not change its solution); None otherwise.
        self.beta_sm0 = None
        beta = self.beta0
        if formulation == "mixed":
            self.beta_sm0 = (given_or_default(c.beta_sm_n, Contact.BETA_SM_N_PER_E),
                             given_or_default(c.beta_sm_t, Contact.BETA_SM_T_PER_E))
            beta = self.beta_sm0
        self.warnings: list[str] = []
        self.coercivity_ratio: float | None = None  # of symmetric Nitsche (θ = 1) only
        nitsche_like = formulation in NITSCHE_FORMULATIONS
        #: ``E/E_max`` per local cell (DG0) when ``contact.beta_scaling`` is ``local``, else None.
        self.beta_weight = self._beta_weight(young) if nitsche_like \
            and c.beta_scaling == "local" else None
        if nitsche_like and self.beta_weight is None and (c.beta_n is None or c.beta_t is None):
            self._check_soft_fractures(young)
        if nitsche_like:
            self._check_beta_range()
        if c.theta == 1 and nitsche_like:
            self._check_symmetric_nitsche(young)
        if c.friction == "coulomb" and msh.topology.dim == 3 and c.theta != 0:
            if formulation == "nitsche":
                self._check_small_beta()
            if nitsche_like and self.scene.degree == 2:
                self._check_small_beta_t()
        if c.friction == "coulomb" and c.friction_coefficient > 0 and (
                (formulation == "nitsche" and c.theta != 0)
                or (formulation == "mixed" and msh.topology.dim == 3)):
            self._check_incompressible_friction(formulation)
        beta_n, beta_t = fem.Constant(msh, beta[0]), fem.Constant(msh, beta[1])
        if self.beta_weight is not None:
            beta_n, beta_t = (b * face_max(self.beta_weight) for b in (beta_n, beta_t))
        return cforms.ContactParameters(
            formulation=formulation,
            friction=c.friction,
            theta=c.theta,
            beta_n=beta_n / h,
            beta_t=beta_t / h,
            friction_coefficient=fc,
            slip_bound=s,
            quadrature_degree=cforms.quadrature_degree(self.scene.degree),
            dim=msh.topology.dim,
        )

    def _beta_weight(self, young: npt.NDArray[np.float64]) -> fem.Function:
        """``E/E_max`` on the local cells (DG0), the weight of a ``local`` β (collective)."""
        Q0 = fem.functionspace(self.fm.msh, ("DG", 0))
        w = fem.Function(Q0, name="beta_weight")
        w.x.array[Q0.dofmap.list[:len(young), 0]] = young / self.young_max
        return w

    def warn(self, msg: str) -> None:
        """Log a warning of the scene (set-up or run) and keep it for ``summary.json``."""
        self.warnings.append(msg)
        log.warning(msg)

    def _check_beta_range(self) -> None:
        """Warn when a given β⁰ lies outside :data:`BETA_RANGE` times the largest modulus."""
        c = self.scene.contact
        low, high = BETA_RANGE
        given = [("beta_n", c.beta_n)]
        if c.friction != "frictionless":
            given.append(("beta_t", c.beta_t))
        below = ("below, the Nitsche terms hold contact and stick weakly, and the states can be "
                 "wrong (an inclined crack at 1e-4 times, theta -1, called 15 of its 26 sliding "
                 "faces stick)")
        above = ("above, the residual's round-off grows with beta and the Newton can stall "
                 "above its tolerance")
        for key, value in given:
            if value is None or low * self.young_max <= value <= high * self.young_max:
                continue
            self.warn(f"contact.{key} = {value:.3g} Pa is {value / self.young_max:.2g} times the "
                      f"largest Young's modulus ({self.young_max:.3g} Pa), outside the "
                      f"{low:g}-{high:g} times that docs/mechanics.md verifies: "
                      f"{below if value < low * self.young_max else above}")

    def _check_small_beta(self) -> None:
        """Warn when β_n⁰ is below :data:`SMALL_BETA_COULOMB_3D` times the largest modulus.

        For 3D pointwise ``nitsche`` with Coulomb friction and θ ≠ 0 (the caller checks).
        """
        if self.beta0[0] < SMALL_BETA_COULOMB_3D * self.young_max:
            self.warn(f"contact.beta_n = {self.beta0[0]:.3g} Pa is below "
                       f"{SMALL_BETA_COULOMB_3D:g} times the largest Young's modulus "
                       f"({self.young_max:.3g} Pa): with Coulomb friction in 3D the nitsche "
                       f"contact Newton may creep and fail (configs/network3d.yaml failed at "
                       f"0.01 times, converged at 0.1; docs/mechanics3d.md); the default is "
                       f"{Contact.BETA_N_PER_E:g} times")

    def _check_small_beta_t(self) -> None:
        """Warn when β_τ⁰ is below :data:`SMALL_BETA_T_RATIO_3D` times β_n⁰.

        For the 3D Nitsche formulations with Coulomb friction, θ ≠ 0 and P2 (the caller checks).
        """
        beta_n, beta_t = self.beta0
        if beta_t < SMALL_BETA_T_RATIO_3D * beta_n:
            self.warn(f"contact.beta_t = {beta_t:.3g} Pa is below 1/{1 / SMALL_BETA_T_RATIO_3D:g} "
                       f"of contact.beta_n ({beta_n:.3g} Pa): with Coulomb friction, theta "
                       f"{self.scene.contact.theta:g} and P2 in 3D the contact Newton and its "
                       f"linear solves may fail (configs/network3d.yaml failed at 1/83 and 1/250, "
                       f"converged at 1/25 and with theta 0; docs/mechanics3d.md)")

    def _largest_poisson(self) -> float:
        """The largest Poisson's ratio of the mesh at t = 0 (collective)."""
        nu = _cell_values(self.fm.msh, self.scene.material.poisson)
        return self.fm.msh.comm.allreduce(float(nu.max(initial=0.0)), op=MPI.MAX)

    def _check_locking(self) -> None:
        """Warn of P1 displacements in a nearly incompressible rock (collective)."""
        largest = self._largest_poisson()
        if largest >= LOCKING_POISSON:
            msg = (f"degree 1 with Poisson's ratio up to {largest:g}: P1 displacements lock as ν "
                   "→ 0.5 (jumps too small: error 0.17 at ν = 0.49 and 0.5 at 0.499, against "
                   "0.04 at 0.25, docs/mechanics.md); use degree 2")
            self.warn(msg)

    def _check_incompressible_friction(self, formulation: str) -> None:
        """Warn of a failing Coulomb contact Newton near incompressibility (collective).

        From :data:`INCOMPRESSIBLE_FRICTION_POISSON`: pointwise ``nitsche`` with θ ≠ 0, and the
        uncondensed ``mixed`` of 3D.
        """
        largest = self._largest_poisson()
        if largest < INCOMPRESSIBLE_FRICTION_POISSON:
            return
        if formulation == "mixed":
            cause = ("contact.formulation mixed in 3D and Coulomb friction: its contact Newton "
                     "may fail (configs/network3d.yaml did at 0.4995 and 0.4999, and took 146 "
                     "iterations at 0.499)")
        else:
            cause = (f"contact.formulation nitsche, theta {self.scene.contact.theta:g} and "
                     f"Coulomb friction: the friction bound takes the normal stress at each "
                     f"point, where lambda div u weighs {2 * largest / (1 - 2 * largest):.3g} "
                     f"times mu, and the contact Newton may switch a point between stick and "
                     f"slip at every iteration and fail (the six-fracture scene did from 0.4995)")
        self.warn(f"material.poisson up to {largest:g} with {cause}; contact.theta 0 (nitsche), "
                  f"or contact.formulation stabilized_mixed or mean_nitsche converge there in "
                  f"2D and 3D (docs/mechanics/incompressible.md)")

    def _check_soft_fractures(self, young: npt.NDArray[np.float64]) -> None:
        """Warn when a default β⁰ is far stiffer than the rock at some fracture face (collective).

        β⁰ defaults to multiples of the largest Young's modulus; where a fracture runs in rock
        :data:`SOFT_CONTRAST` or more times softer, its faces are penalized that much harder
        than the rock around them and the Newton slows or stalls (a fracture in 1e8 Pa rock
        below 1e11 Pa: no convergence in 100 iterations, 7 with β⁰ of its own rock). A face's
        rock is the stiffer of its two sides, the ``E_σ`` that ``beta_scaling: local`` scales
        by: a fracture along an interface with stiffer rock keeps that rock's β (the remedy
        would change nothing there; it was advised for a crack between 1e10 and 1e8 Pa rock).
        """
        faces = self.fm.fractures
        sides = np.maximum(young[faces.plus[:, 0]], young[faces.minus[:, 0]])
        softest = self.fm.msh.comm.allreduce(float(sides.min(initial=np.inf)), op=MPI.MIN)
        if softest > 0 and self.young_max >= SOFT_CONTRAST * softest:
            msg = (f"a fracture runs in rock of Young's modulus {softest:.3g} Pa on both sides, "
                   f"{self.young_max / softest:.3g} times softer than the largest "
                   f"({self.young_max:.3g} Pa) that the default beta_n, beta_t are multiples "
                   f"of: the contact Newton may stall there; set contact.beta_scaling: local "
                   f"(each face's beta scaled by its rock's modulus), or give contact.beta_n "
                   f"and contact.beta_t (e.g. {Contact.BETA_N_PER_E:g} and "
                   f"{Contact.BETA_T_PER_E:g} times the rock's modulus at the fractures)")
            self.warn(msg)

    def _check_symmetric_nitsche(self, young: npt.NDArray[np.float64]) -> None:
        """Warn when θ = 1 is not guaranteed coercive: ``ρ >= 1`` (collective).

        ``ρ`` is a sufficient local bound, so runs with ``ρ`` somewhat above 1 may still be
        right; docs/mechanics.md ("Nitsche parameters and symmetric Nitsche") shows where
        they go wrong.
        """
        c = self.scene.contact
        beta_t0 = self.beta0[1] if c.friction != "frictionless" else None
        poisson = _cell_values(self.fm.msh, self.scene.material.poisson)
        rho = symmetric_nitsche_ratio(self.fm, self.scene.degree, young, poisson,
                                      self.beta0[0], beta_t0, c.traction_side,
                                      local=self.beta_weight is not None)
        self.coercivity_ratio = rho
        if rho >= 1.0:
            msg = (f"contact.theta = 1 (symmetric Nitsche) is below its coercivity bound on this "
                   f"mesh: the trace-inverse ratio is {rho:.3g} >= 1 for beta_n = "
                   f"{self.beta0[0]:.3g} Pa, beta_t = {self.beta0[1]:.3g} Pa; the discrete "
                   f"problem may have no solution or a wrong one. Multiply beta_n and beta_t by "
                   f"at least {rho:.2g}, or use theta -1")
            self.warn(msg)

    def _pressure_fields(self, Q0: fem.FunctionSpace) -> None:
        """Matrix and fracture pressures of a poromechanics scene, set by the coupling (Pa).

        ``p_m`` (DG0 on the cells) exists only when the Biot coefficient is positive, ``p_f``
        (DG0 on the fracture faces) only when there are fractures; both are None for
        mechanics-only scenes (their fracture pressure, if any, is a scene expression).
        """
        self.p_m = self.p_f = None
        self.biot = 0.0
        self._reference = None  # p⁰ on the owned cells, subtracted from p_m (relative coupling)
        if self.pressures is None:
            return
        self.biot = self.pressures.biot
        if self.biot > 0:
            self.p_m = fem.Function(Q0, name="p_m")
        if self.has_fractures:
            self.p_f = fem.Function(self._dg0(1), name="p_f")

    def set_pressures(self, p_m: npt.NDArray[np.float64] | None,
                      p_f: npt.NDArray[np.float64] | None) -> None:
        """Set the pressures (Pa; collective).

        ``p_m`` on the owned cells, ``p_f`` on the owned fracture faces in the order of
        ``fm.fractures``.
        """
        if self.p_m is not None and p_m is not None:
            n = len(p_m)
            self.p_m.x.array[self._cell_dofs[:n]] = p_m if self._reference is None \
                else p_m - self._reference
            self.p_m.x.scatter_forward()
        if self.p_f is not None and p_f is not None:
            self.p_f.x.array[self._face_dofs] = p_f
            self.p_f.x.scatter_forward()

    def set_reference_pressure(self, p0: npt.NDArray[np.float64]) -> None:
        """``p⁰`` on the owned cells (Pa): the Biot term then acts on ``p_m - p⁰``.

        Only with a relative :class:`PressureCoupling` (an initial stress).
        """
        if self.pressures is not None and self.pressures.relative:
            self._reference = np.array(p0, dtype=np.float64)

    @property
    def _cell_dofs(self) -> npt.NDArray[np.int32]:
        """DG0 dofs of the local cells (owned first) of the matrix pressure space."""
        return self.p_m.function_space.dofmap.list[:, 0]

    @property
    def _face_dofs(self) -> npt.NDArray[np.int32]:
        """DG0 dofs of the owned fracture faces (order of ``fm.fractures``) on the submesh."""
        cells = self.emap.sub_topology_to_topology(self.fm.fractures.facets, inverse=True)
        return self.p_f.function_space.dofmap.list[cells, 0]

    def _dg0(self, k: int) -> fem.FunctionSpace:
        shape = (k,) if k > 1 else ()
        return fem.functionspace(self.submesh, ("DG", 0, shape))

    def _field(self, space, expr: Expression, name: str):
        """A DG0 (or constant) coefficient from an expression, updated in time if needed."""
        if expr.is_uniform:
            c = fem.Constant(self.fm.msh, expr.value())
            if expr.depends_on_time:
                self._updaters.append(_Updater(c, (expr,)))
            return c
        f = fem.Function(space, name=name)
        upd = _Updater(f, (expr,))
        upd(0.0)
        if expr.depends_on_time:
            self._updaters.append(upd)
        return f

    def _vector_input(self, exprs: tuple[Expression, Expression]):
        """A constant or interpolated vector load (body force, traction)."""
        msh = self.fm.msh
        if all(e.is_uniform for e in exprs):
            c = fem.Constant(msh, np.array([e.value() for e in exprs]))
            if any(e.depends_on_time for e in exprs):
                self._updaters.append(_Updater(c, exprs))
            return c
        f = fem.Function(self.V)
        upd = _Updater(f, exprs)
        upd(0.0)
        if any(e.depends_on_time for e in exprs):
            self._updaters.append(upd)
        return f

    def _kinematics(self) -> FractureKinematics:
        pf = None
        if self.p_f is not None:
            pf = self.p_f("+")
        elif self.scene.fracture_pressure is not None and self.has_fractures:
            expr = self.scene.fracture_pressure
            if expr.is_uniform:
                pf = fem.Constant(self.fm.msh, expr.value())
                if expr.depends_on_time:
                    self._updaters.append(_Updater(pf, (expr,)))
            else:
                pf_fun = fem.Function(self._dg0(1), name="p_f")
                upd = _Updater(pf_fun, (expr,))
                upd(0.0)
                if expr.depends_on_time:
                    self._updaters.append(upd)
                pf = pf_fun("+")
        n = ufl.FacetNormal(self.fm.msh)("+")
        fk = FractureKinematics(
            n=n, young=self.young, poisson=self.poisson, side=self.scene.contact.traction_side,
            fracture_pressure=pf, slip_reference=self.u_prev, matrix_pressure=self.p_m,
            biot=fem.Constant(self.fm.msh, self.biot), initial_stress=self.initial_stress,
            tangents=self._tangent_frame(),
        )
        mean = self._initial_traction_mean(fk)
        return fk if mean is None else replace(fk, initial_traction_mean=mean)

    def _initial_traction_mean(self, fk: FractureKinematics):
        """``π⁰(σ⁰n⁺)`` (DG0 on the fracture faces, global components), or None (collective).

        Built for the facewise formulations with a varying ``σ⁰`` only. The face means use
        the contact quadrature, which integrates ``σ⁰`` (DG of the displacement degree)
        exactly.
        """
        c = self.params
        if (self.initial_stress is None or isinstance(self.initial_stress, fem.Constant)
                or not self.has_fractures
                or not c.active or cforms.pointwise(c)):
            return None
        d = self.fm.msh.geometry.dim
        mean = fem.Function(self._dg0(d), name="initial_traction_mean")
        t0 = fk.initial_traction()
        self._set_face_means(mean, [t0[i] for i in range(d)])
        return mean("+")

    def _set_face_means(self, f: fem.Function, values: list) -> None:
        """Set the DG0 face field ``f`` to the face means of ``values`` (collective).

        ``values``: one UFL expression on the fracture facets per component of ``f``, averaged
        with the contact quadrature.
        """
        q = ufl.TestFunction(f.function_space)("+")
        qs = [q] if len(values) == 1 else [q[i] for i in range(len(values))]
        area = ufl.FacetArea(self.fm.msh)("+")
        dG = cforms.contact_measure(self.params, fracture_measure(self.fm)(FRACTURE_TAG))
        form = fem.form(sum(v * qi for v, qi in zip(values, qs, strict=True)) / area * dG,
                        entity_maps=self.entity_maps or None)
        f.x.array[:] = 0.0
        fem.assemble_vector(f.x.array, form)
        f.x.scatter_reverse(dolfinx.la.InsertMode.add)
        f.x.scatter_forward()

    def start_face_unknowns(self) -> bool:
        """Set the multipliers and face averages consistent with ``u`` (collective).

        Only under an in-situ stress ``σ⁰``: the traction of the initial state is then that of
        the rock at depth, and face unknowns at zero are far from it (the Newton has to find
        the whole traction, ``mixed`` P1 from multipliers that are not inf-sup stable). Without
        ``σ⁰`` the unknowns stay at zero as before. Uses the current inputs (time, pressures).
        Returns whether they were set.
        """
        if self.initial_stress is None or (self.lam is None and self.avg is None):
            return False
        multiplier, averages = cforms.consistent_face_values(self.kinematics, self.params,
                                                             self.u)
        for f, values in ((self.lam, multiplier), (self.avg, averages)):
            if f is not None:
                self._set_face_means(f, values)
        return True

    def _tangent_frame(self) -> tuple | None:
        """The tangents ``(τ_1, τ_2)`` of the fractures in 3D, or None in 2D.

        3D: DG0 on the fracture faces, exactly the geometry's frame; 2D: ``τ = (n_y, -n_x)`` is
        taken from the normal.
        """
        if self.fm.msh.topology.dim == 2 or not self.has_fractures:
            return None
        faces = self.fm.fractures
        sub = self.emap.sub_topology_to_topology(faces.facets, inverse=True)
        frame = []
        for k in range(2):
            t = fem.Function(self._dg0(3), name=f"tangent_{k + 1}")
            dofs = t.function_space.dofmap.list[sub, 0]
            t.x.array.reshape(-1, 3)[dofs] = faces.tangents[:, k, :]
            t.x.scatter_forward()
            frame.append(t("+"))
        return tuple(frame)

    def _initial_stress(self):
        """``σ⁰`` as a symmetric tensor (a constant, or DG of the displacement degree), or None.

        DG of degree ``k`` (at least 1) represents a stress linear in depth exactly, so that a
        lithostatic state is in discrete equilibrium with a constant weight.
        """
        exprs = self.scene.material.initial_stress
        if exprs is None:
            return None
        msh = self.fm.msh
        d = msh.geometry.dim
        index = _STRESS_INDEX[d]
        if all(e.is_uniform for e in exprs):
            values = np.zeros((d, d))
            for (i, j), e in zip(index, exprs, strict=True):
                values[i, j] = values[j, i] = e.value()
            return fem.Constant(msh, values)
        T = fem.functionspace(msh, ("DG", max(1, self.scene.degree), (d, d)))
        sigma0 = fem.Function(T, name="initial_stress")
        order = [index.index((min(i, j), max(i, j))) for i in range(d) for j in range(d)]
        sigma0.interpolate(lambda x: np.vstack([exprs[k](x.T, 0.0) for k in order]))
        sigma0.x.scatter_forward()
        return sigma0

    def _weight(self):
        """The body force ``ρ g`` of gravity (N/m³) as UFL, or None.

        A density that varies is interpolated in DG of the displacement degree, as ``σ⁰`` is:
        a density linear in depth and its quadratic ``σ⁰`` are then in exact discrete
        equilibrium with P2 (DG0 left an imbalance of the order of the cell size times the
        density gradient, refused as such).
        """
        g, rho = self.scene.gravity, self.scene.material.density
        if g is None or rho is None:
            return None
        Q = fem.functionspace(self.fm.msh, ("DG", self.scene.degree))
        return self._field(Q, rho, "density") * fem.Constant(self.fm.msh, np.asarray(g, float))

    def _dirichlet(self) -> list[fem.DirichletBC]:
        geo, fm = self.fm.geometry, self.fm
        bcs, given = [], []
        for index, bc in enumerate(self.scene.boundary_conditions):
            if bc.displacement is None:
                continue
            edges = tuple(i for i, n in enumerate(geo.boundary_names) if n == bc.boundary)
            facets = fm.boundary(edges)
            for k, expr in enumerate(bc.displacement):
                if expr is None:
                    continue
                Vk, _ = self.V.sub(k).collapse()
                dofs = fem.locate_dofs_topological((self.V.sub(k), Vk),
                                                   self.fm.msh.topology.dim - 1, facets)
                g = fem.Function(Vk)
                upd = _Updater(g, (expr,))
                upd(0.0)
                if expr.depends_on_time:
                    self._updaters.append(upd)
                bcs.append(fem.dirichletbc(g, dofs, self.V.sub(k)))
                given.append((index, bc.boundary, k, dofs, upd))
        self._report_conflicting_displacements(given)
        return bcs

    def _report_conflicting_displacements(self, given) -> None:
        """Warn where two displacement conditions set one component to different values.

        Where two boundaries meet (an edge of the box, a corner) both conditions hold on the
        nodes there, and the one listed later wins (DOLFINx sets the conditions in order): a
        shear box with ``u_x = 1 mm`` on the bottom and ``u_x = 0`` on the left changed its
        fracture tractions by 20 % when the two were listed the other way round, silently.
        Compared at ``t = 0`` and, for conditions that vary in time, at the final time; only
        pairs that share nodes are evaluated (collective).
        """
        comm = self.fm.msh.comm
        pairs = []
        for a in range(len(given)):
            for b in range(a + 1, len(given)):
                (_, name_a, k, dofs_a, _), (_, name_b, kb, dofs_b, _) = given[a], given[b]
                if k != kb or name_a == name_b:
                    continue
                shared = np.intersect1d(dofs_a[0], dofs_b[0], return_indices=True)
                pairs.append((a, b, shared[1], shared[2]))
        counts = comm.allreduce(np.array([len(p[2]) for p in pairs], dtype=np.int64))
        pairs = [p for p, n in zip(pairs, counts, strict=True) if n > 0]
        if not pairs:
            return
        moving = any(upd.exprs[0].depends_on_time for *_, upd in given)
        times = [0.0, self.scene.time.end] if moving and self.scene.time is not None else [0.0]
        worst = {(a, b): (0.0, 0.0, 0.0) for a, b, *_ in pairs}
        involved = sorted({a for a, *_ in pairs} | {b for _, b, *_ in pairs})
        for t in times:
            values = {}
            for c in involved:
                upd = given[c][4]
                if t > 0.0 and upd.exprs[0].depends_on_time:
                    upd(t)
                values[c] = upd.target.x.array[given[c][3][1]].copy()
                if t > 0.0 and upd.exprs[0].depends_on_time:
                    upd(0.0)
            # below 1e-9 of the conditions' values: round-off of the node coordinates
            local = np.array([np.abs(values[c]).max(initial=0.0) for c in involved])
            largest = np.empty_like(local)
            comm.Allreduce(local, largest, op=MPI.MAX)
            scale = dict(zip(involved, largest, strict=True))
            for a, b, at_a, at_b in pairs:
                va, vb = values[a][at_a], values[b][at_b]
                gap = np.abs(va - vb) - 1e-9 * max(scale[a], scale[b])
                if gap.size and gap.max() > worst[a, b][0]:
                    m = int(np.argmax(gap))
                    worst[a, b] = (float(gap[m]), float(va[m]), float(vb[m]))
        for a, b, *_ in pairs:
            gap, va, vb = worst[a, b]
            top = comm.allreduce(gap, op=MPI.MAX)
            owner = comm.allreduce(comm.rank if 0.0 < gap == top else comm.size, op=MPI.MIN)
            if owner == comm.size:  # the same values on every shared node
                continue
            va, vb = comm.bcast((va, vb), root=owner)
            (i, name_i, k, *_), (j, name_j, *_) = given[a], given[b]
            log.warning(
                "scene keys 'boundary_conditions.%d.displacement' and "
                "'boundary_conditions.%d.displacement' set u_%s to %.6g and %.6g m where "
                "boundaries '%s' and '%s' meet: the later one, boundary_conditions.%d, "
                "holds there", i, j, "xyz"[k], va, vb, name_i, name_j, j)

    # -- the initial state ------------------------------------------------------------------
    def _check_initial_stress(self) -> dict:
        """The imbalance of ``σ⁰`` with the body force and the boundary tractions at t = 0.

        ``R(v) = ∫ σ⁰:ε(v) - ∫ (f + ρ g)·v - ∫_Γ_N t·v`` on a continuous space of the
        displacement degree (its test functions have no jump, so the fractures, which carry
        ``σ⁰n`` by contact, take no part), with the rows of the imposed displacement components
        left out (they are reactions). It is measured by the force density ``z`` (N/m³) that
        ``R`` represents in L² (``M z = R``, ``M`` the mass matrix), in root mean square over
        the domain: a weight off by ``δ`` everywhere gives ``δ`` on every mesh, where the raw
        residual shrinks with the cells (a density off by several percent at depth passed for
        10⁻³ on coarse meshes); a traction off by ``δt`` on a boundary concentrates as
        ``δt/h`` there and grows under refinement; a density jump inside cells (a layer the
        mesh does not follow) fades as ``h^½``. Collective.

        Returns:
            ``residual`` (the RMS of ``z``, N/m³), ``scale`` (the loads' own force density:
            the larger of the RMS body force ``|f + ρ g|`` and the largest ``|σ⁰|`` over the
            domain's extent, N/m³), ``relative`` (``residual`` over ``scale``) and ``where``
            (the boundary where ``|z|`` is largest, or ``interior``).

        Raises:
            ConfigError: ``relative`` above :data:`IMBALANCE_LIMIT`.
        """
        msh, fm, scene = self.fm.msh, self.fm, self.scene
        d, fdim = msh.geometry.dim, msh.topology.dim - 1
        W = fem.functionspace(msh, ("Lagrange", scene.degree, (d,)))
        v = ufl.TestFunction(W)
        dx = ufl.Measure("dx", domain=msh)
        tags = dolfinx.mesh.meshtags(msh, fdim, np.sort(fm.boundary_facets),
                                     fm.boundary_edge[np.argsort(fm.boundary_facets)] + 1)
        ds = ufl.Measure("ds", domain=msh, subdomain_data=tags)
        internal = ufl.inner(self.initial_stress, epsilon(v)) * dx
        body = ufl.dot(self.weight, v) * dx if self.weight is not None else None
        f = scene.material.body_force or ()
        if not all(e.is_constant and e.value() == 0.0 for e in f):
            given = ufl.dot(self._vector_input(f), v) * dx
            body = given if body is None else body + given
        load = body
        for bc in scene.boundary_conditions:
            if bc.traction is not None:
                edges = [i + 1 for i, n in enumerate(fm.geometry.boundary_names)
                         if n == bc.boundary]
                t = sum(ufl.dot(self._vector_input(bc.traction), v) * ds(e) for e in edges)
                load = t if load is None else load + t

        def assemble(form):
            b = fem.assemble_vector(fem.form(form))
            b.scatter_reverse(dolfinx.la.InsertMode.add)
            return b.array[: W.dofmap.index_map.size_local * d].reshape(-1, d)

        r = assemble(internal)
        if load is not None:
            r -= assemble(load)
        fixed = np.zeros_like(r, dtype=bool)
        for bc in scene.boundary_conditions:
            for k, e in enumerate(bc.displacement or ()):
                if e is not None:
                    facets = fm.boundary(tuple(i for i, n in enumerate(fm.geometry.boundary_names)
                                               if n == bc.boundary))
                    dofs = fem.locate_dofs_topological(W, fdim, facets)
                    dofs = dofs[dofs < len(r)]
                    fixed[dofs, k] = True
        r[fixed] = 0.0
        b = assemble(body) if body is not None else 0.0 * r
        z, zb = _force_densities(W, [r, b])
        comm = msh.comm
        volume = comm.allreduce(fem.assemble_scalar(fem.form(1.0 * dx)), op=MPI.SUM)
        extent = domain_extent(msh)
        s0 = self.initial_stress
        stress = np.abs(s0.value if isinstance(s0, fem.Constant) else s0.x.array)
        sigma = comm.allreduce(float(stress.max(initial=0.0)), op=MPI.MAX)

        def rms(density, load):  # ‖z‖_L² / |Ω|^½, with z^T M z = z^T b
            return float(np.sqrt(max(comm.allreduce(float(np.vdot(density, load))), 0.0)
                                 / volume))

        residual = rms(z, r)
        scale = max(rms(zb, b), sigma / extent if extent > 0 else 0.0)
        relative = residual / scale if scale > 0 else 0.0
        z[fixed] = 0.0
        where = self._largest_entry(W, np.abs(z).max(axis=1, initial=0.0))
        out = {"residual": residual, "scale": scale, "relative": relative, "where": where}
        if scene.contact.formulation == "none" and self.has_fractures:
            self._check_fractures_at_rest(sigma)
        if relative > IMBALANCE_LIMIT:
            if where == "interior":
                place, remedy = "in the interior", (
                    "give the density and gravity that balance div σ⁰, or a σ⁰ whose divergence "
                    "they are; a σ⁰ or density varying on a shorter scale than the cells shows "
                    "here too: refine the mesh")
            else:
                place, remedy = f"on boundary {where!r}", (
                    "give that boundary the traction σ⁰n, a displacement condition, or the "
                    "density and gravity that balance div σ⁰")
            raise ConfigError(
                f"scene key 'material.initial_stress' is not in equilibrium with the body force "
                f"and the boundary tractions at t = 0: the residual is {relative:.2g} of the "
                f"loads ({residual:.3g} N/m³ against {scale:.3g} N/m³), largest {place} "
                f"({remedy})")
        if relative > 1e-8:
            log.warning("the initial stress is in equilibrium to %.1e of the loads only (largest "
                        "%s): the imbalance moves the body at the first solve", relative,
                        "in the interior" if where == "interior" else f"on boundary {where!r}")
        return out

    def _check_fractures_at_rest(self, sigma: float) -> None:
        """Without contact a fracture carries only its fluid pressure: ``σ⁰n⁺ = -p n⁺``.

        The continuous check above leaves the fractures out (contact carries ``σ⁰n``); with
        ``contact.formulation: none`` nothing does, and a compressive ``σ⁰`` drove the faces
        through each other at the first solve (0.57 m in a 1 km box) with every face ``open``.
        ``p`` is ``fracture_pressure`` (mechanics) or ``flow.initial_pressure`` (coupled) at
        t = 0, at the face midpoints; ``sigma``: the largest ``|σ⁰|``. Collective.

        Raises:
            ConfigError: ``|σ⁰n⁺ + p n⁺|`` above :data:`IMBALANCE_LIMIT` ``sigma`` on a face.
        """
        scene, faces, d = self.scene, self.fm.fractures, self.fm.msh.geometry.dim
        pressure = scene.flow.initial_pressure if scene.physics == "poromechanics" \
            else scene.fracture_pressure
        x = faces.midpoint[:, :d]
        stress = np.zeros((len(x), d, d))
        for (i, j), e in zip(_STRESS_INDEX[d], self.scene.material.initial_stress, strict=True):
            stress[:, i, j] = stress[:, j, i] = e(x, 0.0)
        p = pressure(x, 0.0) if pressure is not None else np.zeros(len(x))
        t = np.einsum("fij,fj->fi", stress, faces.normal[:, :d]) + p[:, None] * faces.normal[:, :d]
        size = np.linalg.norm(t, axis=1)
        comm = self.fm.comm
        worst, owner = comm.allreduce((float(size.max(initial=0.0)), comm.rank), op=MPI.MAXLOC)
        if not worst > IMBALANCE_LIMIT * sigma:
            return
        k = int(np.argmax(size)) if len(size) else 0
        at, tn = comm.bcast((int(faces.fracture[k]), float(t[k] @ faces.normal[k, :d]))
                            if comm.rank == owner else None, root=owner)
        name = self.fm.geometry.fracture_names[at]
        where = "fracture_pressure" if scene.physics != "poromechanics" \
            else "flow.initial_pressure"
        raise ConfigError(
            f"scene key 'material.initial_stress' loads fracture {name!r} with a traction of "
            f"{worst:.3g} Pa (normal {tn:.3g} Pa) beyond its fluid pressure ({where}), and "
            "contact.formulation none lets nothing carry it: the faces would pass through each "
            "other at the first solve (allowed: a contact formulation, or a σ⁰ whose traction "
            "on the fractures is -p n)")

    def _largest_entry(self, W: fem.FunctionSpace, values: npt.NDArray[np.float64]) -> str:
        """Where the owned dof ``values`` are largest: a named boundary, or ``interior``.

        A boundary is named when its largest value exceeds twice the largest of the nodes on
        no boundary (a traction mismatch concentrates there as ``δt/h``); an imbalance spread
        through the body is ``interior`` even where it reaches the boundary nodes. Collective;
        the same on every rank.
        """
        fm, fdim = self.fm, self.fm.msh.topology.dim - 1
        names = list(dict.fromkeys(fm.geometry.boundary_names))
        inner = np.ones(len(values), dtype=bool)
        peaks = []
        for name in names:
            facets = fm.boundary(tuple(i for i, n in enumerate(fm.geometry.boundary_names)
                                       if n == name))
            dofs = fem.locate_dofs_topological(W, fdim, facets)
            dofs = dofs[dofs < len(values)]
            inner[dofs] = False
            peaks.append(float(values[dofs].max(initial=0.0)))
        local, peaks = np.asarray(peaks, dtype=float), np.zeros(len(peaks))
        fm.comm.Allreduce(local, peaks, op=MPI.MAX)
        interior = fm.comm.allreduce(float(values[inner].max(initial=0.0)), op=MPI.MAX)
        if len(peaks) and peaks.max() > 2.0 * interior:
            return names[int(np.argmax(peaks))]
        return "interior"

    # -- forms ------------------------------------------------------------------------------
    def _build_forms(self) -> None:
        scene, fm, c = self.scene, self.fm, self.params
        msh = fm.msh
        v = ufl.TestFunction(self.V)
        dx = ufl.Measure("dx", domain=msh)
        tags = dolfinx.mesh.meshtags(
            msh, msh.topology.dim - 1, fm.boundary_facets[np.argsort(fm.boundary_facets)],
            fm.boundary_edge[np.argsort(fm.boundary_facets)] + 1,
        )
        ds = ufl.Measure("ds", domain=msh, subdomain_data=tags)
        F0 = elastic_form(self.u, v, self.young, self.poisson, dx)
        if self.initial_stress is not None:
            F0 += initial_stress_form(self.initial_stress, v, dx)
        if self.p_m is not None:
            F0 += biot_stress_form(self.p_m, v, self.kinematics.biot, dx)
        f = scene.material.body_force or ()
        if not all(e.is_constant and e.value() == 0.0 for e in f):
            F0 -= ufl.dot(self._vector_input(f), v) * dx
        self.weight = self._weight()
        if self.weight is not None:
            F0 -= ufl.dot(self.weight, v) * dx
        for bc in scene.boundary_conditions:
            if bc.traction is None:
                continue
            edges = [i + 1 for i, n in enumerate(fm.geometry.boundary_names) if n == bc.boundary]
            F0 -= sum(ufl.dot(self._vector_input(bc.traction), v) * ds(e) for e in edges)
        dG = fracture_measure(fm)(FRACTURE_TAG)
        self.dG = dG
        residuals = [F0]
        fracture_terms = None
        if self.has_fractures:
            fracture_terms = cforms.displacement_residual(
                self.kinematics, c, self.u, v, dG, _plus(self.lam), _plus(self.avg)
            )
            if fracture_terms is not None:
                residuals[0] = F0 + fracture_terms
        if self.lam is not None:
            mu = ufl.TestFunction(self.lam.function_space)
            residuals.append(
                cforms.multiplier_residual(
                    self.kinematics, c, self.u, self.lam("+"), mu("+"), _plus(self.avg), dG
                )
            )
        if self.avg is not None:
            q = ufl.TestFunction(self.avg.function_space)
            scale = self.young("+") if isinstance(self.young, fem.Function) else self.young
            weight = scale / face_size(msh)("+")
            cp = cforms.ContactParameters(**{**c.__dict__, "average_scale": weight})
            residuals.append(
                cforms.averages_residual(self.kinematics, cp, self.u, self.avg("+"), q("+"), dG)
            )
        self.linear = not (c.active and self.has_fractures)
        jac = [[_derivative(Fi, uj) for uj in self.unknowns] for Fi in residuals]
        rest = None
        if not self.linear:
            # the Jacobian as bulk elasticity + fracture terms: only the latter change with the
            # iterate (the displacement block has none with multipliers)
            rest = [list(row) for row in jac]
            rest[0][0] = None if fracture_terms is None else _derivative(fracture_terms, self.u)
        em = self.entity_maps or None
        self.F = [fem.form(Fi, entity_maps=em) for Fi in residuals]
        self._div_form = self._divergence_form(dx) if self.pressures is not None else None
        self.J = [[fem.form(a, entity_maps=em) if a is not None else None for a in row]
                  for row in jac]
        self.J_split = None
        if rest is not None:
            self.J_split = (
                fem.form(_derivative(F0, self.u)),
                [[fem.form(a, entity_maps=em) if a is not None else None for a in row]
                 for row in rest],
            )
        self._build_diagnostics()

    def _build_diagnostics(self) -> None:
        """Face means of :data:`FACE_FIELDS` and the pointwise active set (:meth:`active_set`).

        Both use the quadrature of the contact terms, so that what is reported is what the
        residual sees (for pointwise Nitsche the Gauss points are the contact points).
        """
        self.faces = self._code_form = None
        if not self.has_fractures:
            return
        names = self.assembled_face_fields
        self.faces = fem.Function(self._dg0(len(names)), name="fracture")
        q = ufl.TestFunction(self.faces.function_space)
        fk, c = self.kinematics, self.params
        jn, jt = normal_jump(self.u, fk.n), slip(self.u, fk.frame)
        zero = 0.0 * jn
        if c.active:
            st = cforms.state_indicators(fk, c, self.u, _plus(self.lam), _plus(self.avg))
            tn, tt, rest = st.traction_n, st.traction_t, (st.bound, st.contact, st.slip)
        else:
            tn, tt, rest = zero, None, (zero,) * 3
        if self.fm.msh.topology.dim == 2:
            values = (jn, jt, tn, zero if tt is None else tt, *rest)
        else:  # tangential vectors in global coordinates: Σ_k (frame component k) τ_k
            def global_vector(comps):
                if comps is None or comps.ufl_shape == ():  # no tangential terms (frictionless)
                    return (zero,) * 3
                vec = sum(comps[k] * t for k, t in enumerate(fk.frame))
                return tuple(vec[i] for i in range(3))
            tt_mean = zero if tt is None or tt.ufl_shape == () else magnitude(tt)
            values = (jn, *global_vector(jt), tn, *global_vector(tt), *rest, tt_mean)
        dG = cforms.contact_measure(c, self.dG)
        area = ufl.FacetArea(self.fm.msh)("+")  # |σ|: the face means are ∫ val / |σ|
        em = self.entity_maps or None
        form = sum(val * q("+")[i] / area for i, val in enumerate(values)) * dG
        self._faces_form = fem.form(form, entity_maps=em)
        if c.active:
            self._build_active_set(dG)

    def _build_active_set(self, dG) -> None:
        """Collocation of the active-set code at the contact points of every face.

        A Lagrange space of degree ``k`` on the fracture faces with its nodes at the ``k + 1``
        Gauss points of the contact quadrature (``gl_warped``) is tested against the code: the
        assembled moment of node ``j`` is ``w_j code(x_j)``. Facewise formulations have one
        state per face (degree 0).
        """
        c = self.params
        k = c.quadrature_degree // 2 if cforms.pointwise(c) else 0
        cell = self.submesh.topology.cell_name()
        if k > 0 and cell != "interval":
            # triangles: no Lagrange nodes at the Gauss points; one dof per quadrature point
            element = basix.ufl.quadrature_element(cell, value_shape=(),
                                                   degree=c.quadrature_degree)
        else:
            element = basix.ufl.element("DG", cell, k,
                                        lagrange_variant=basix.LagrangeVariant.gl_warped)
        self._points = fem.Function(fem.functionspace(self.submesh, element), name="active_set")
        r = ufl.TestFunction(self._points.function_space)("+")
        em = self.entity_maps or None
        code = cforms.active_set_code(self.kinematics, c, self.u, _plus(self.lam), _plus(self.avg))
        self._code_form = fem.form(code * r * dG, entity_maps=em)
        self._point_weights = self._owned_moments(fem.form(r * dG, entity_maps=em))

    def _owned_moments(self, form: fem.Form) -> npt.NDArray[np.float64]:
        """Assembled moments against ``self._points``'s basis, owned entries (collective)."""
        f = self._points
        f.x.array[:] = 0.0
        fem.assemble_vector(f.x.array, form)
        f.x.scatter_reverse(dolfinx.la.InsertMode.add)
        return f.x.array[: f.function_space.dofmap.index_map.size_local].copy()

    def collocate(self, expr) -> npt.NDArray[np.float64]:
        """A scalar UFL expression at the contact points of the owned fracture faces (collective).

        The points are those of :meth:`active_set` (the Gauss points of the contact quadrature
        for pointwise ``nitsche``, one per face otherwise); the values come as
        ``(owned submesh cells, points per face)``. For diagnostics and tests.
        """
        r = ufl.TestFunction(self._points.function_space)("+")
        dG = cforms.contact_measure(self.params, self.dG)
        form = fem.form(expr * r * dG, entity_maps=self.entity_maps or None)
        values = self._owned_moments(form) / self._point_weights
        n = self.submesh.topology.index_map(self.submesh.topology.dim).size_local
        return values[self._points.function_space.dofmap.list[:n]]

    def _divergence_form(self, dx):
        """``∫_K div(u) dx`` per cell (DG0 test function) and the cell areas."""
        Q0 = fem.functionspace(self.fm.msh, ("DG", 0))
        q = ufl.TestFunction(Q0)
        area = fem.assemble_vector(fem.form(q * dx)).array
        self._cell_area = area
        self._div_values = fem.Function(Q0)
        return fem.form(ufl.div(self.u) * q * dx)

    def cell_divergence(self) -> npt.NDArray[np.float64]:
        """Cell means ``(div u)_K`` on the owned cells, in cell order (collective-free, local)."""
        vals = fem.assemble_vector(self._div_form).array
        n = self.fm.msh.topology.index_map(self.fm.msh.topology.dim).size_local
        dofs = self._div_values.function_space.dofmap.list[:n, 0]
        return vals[dofs] / self._cell_area[dofs]

    # -- time and outputs -------------------------------------------------------------------
    def set_time(self, t: float) -> None:
        """Re-evaluate every time-dependent input at ``t`` (loads, boundary data, moduli)."""
        for upd in self._updaters:
            upd(t)

    def accept_step(self) -> None:
        """The solved displacement becomes the reference of the next slip increment."""
        if self.u_prev is not None:
            self.u_prev.x.array[:] = self.u.x.array

    def active_set(self) -> npt.NDArray[np.int8]:
        """Active-set code at every contact point of the owned fracture faces (collective).

        Codes are those of :func:`poromech.forms.contact.active_set_code` (the branches that
        the Jacobian uses); points are the Gauss points of the contact quadrature for pointwise
        ``nitsche`` and one per face otherwise. Empty without contact conditions. Newton counts
        active-set changes with it.
        """
        if self._code_form is None:
            return np.empty(0, dtype=np.int8)
        codes = np.nan_to_num(self._owned_moments(self._code_form) / self._point_weights, nan=-1.0,
                              posinf=-1.0, neginf=-1.0)
        return np.rint(codes).astype(np.int8)

    def point_faces(self) -> npt.NDArray[np.int64]:
        """The owned fracture face (index in ``fm.fractures``) of each :meth:`active_set` point."""
        if self._code_form is None:
            return np.empty(0, dtype=np.int64)
        faces = np.full(self._point_weights.size, -1, dtype=np.int64)
        sub_cells = self.emap.sub_topology_to_topology(self.fm.fractures.facets, inverse=True)
        dofs = self._points.function_space.dofmap.list[sub_cells]
        faces[dofs] = np.arange(len(sub_cells))[:, None]
        return faces

    @property
    def assembled_face_fields(self) -> tuple[str, ...]:
        """:data:`FACE_FIELDS` (2D) or :data:`FACE_FIELDS_3D`."""
        return FACE_FIELDS if self.fm.msh.topology.dim == 2 else FACE_FIELDS_3D

    def face_fields(self) -> dict[str, npt.NDArray[np.float64]]:
        """Owned fracture face values of :data:`FACE_FIELDS`, by name (collective).

        Face means over the contact quadrature, in the order of ``fm.fractures``. In 3D also
        the global components of the tangential jump and traction (:data:`FACE_FIELDS_3D`);
        ``jump_t`` and ``traction_t`` are then the magnitudes of their face means.
        """
        names = self.assembled_face_fields
        if self.faces is None:
            return {name: np.empty(0) for name in (*FACE_FIELDS, *names)}
        self.faces.x.array[:] = 0.0
        fem.assemble_vector(self.faces.x.array, self._faces_form)
        self.faces.x.scatter_reverse(dolfinx.la.InsertMode.add)
        self.faces.x.scatter_forward()
        sub_cells = self.emap.sub_topology_to_topology(self.fm.fractures.facets, inverse=True)
        vals = self.faces.x.array.reshape(-1, len(names))[sub_cells]
        out = {name: vals[:, i] for i, name in enumerate(names)}
        if names is FACE_FIELDS_3D:
            for q in ("jump", "traction"):
                out[f"{q}_t"] = np.linalg.norm(
                    np.column_stack([out[f"{q}_t{c}"] for c in "xyz"]), axis=1)
        return out

    @staticmethod
    def states(values: dict[str, npt.NDArray[np.float64]]) -> npt.NDArray[np.int8]:
        """Contact state per face from the written face means of :meth:`face_fields`.

        0 ``open``: ``traction_n = 0`` (no compressive contact traction anywhere on the face);
        1 ``stick``: ``traction_n < 0`` and ``|traction_t|`` below the friction bound;
        2 ``slip``: ``traction_n < 0`` and ``|traction_t| >= (1 - SLIP_TOLERANCE) S`` with ``S``
        the face mean of the bound (in 3D ``|traction_t|`` is the face mean of ``|T_τ|``,
        ``traction_t_mean``) (``F |traction_n|`` for Coulomb, ``s`` for Tresca, 0 without
        friction: a closed frictionless face slips).
        """
        tn, bound = values["traction_n"], values["friction_bound"]
        # 3D: the face mean of |T_τ| (|mean T_τ| is smaller where the direction turns)
        tt = values["traction_t_mean"] if "traction_t_mean" in values else values["traction_t"]
        sliding = np.abs(tt) >= (1.0 - SLIP_TOLERANCE) * bound
        return np.where(tn < 0.0, np.where(sliding, 2, 1), 0).astype(np.int8)

    def condensation_jacobian(self) -> list[list[fem.Form | None]]:
        """The Jacobian with its multiplier rows replaced by the face mass matrix (``mixed``).

        A constant matrix (:mod:`poromech.mechanics.condensed`); compiled at the first call.
        """
        if getattr(self, "_condensation", None) is None:
            V = self.lam.function_space
            mass = cforms.multiplier_mass(self.params, ufl.TrialFunction(V)("+"),
                                          ufl.TestFunction(V)("+"), self.dG)
            rows = [list(row) for row in self.J]
            rows[1] = [None] * len(rows[1])
            rows[1][1] = fem.form(mass, entity_maps=self.entity_maps or None)
            self._condensation = rows
        return self._condensation

    def dof_count(self) -> int:
        """Global number of unknowns of the nonlinear system."""
        return sum(f.function_space.dofmap.index_map.size_global
                   * f.function_space.dofmap.index_map_bs for f in self.unknowns)


def _derivative(F, u):
    """``dF/du`` as a UFL form, or None when it vanishes identically."""
    a = ufl.derivative(F, u, ufl.TrialFunction(u.function_space))
    a = ufl.algorithms.expand_derivatives(a)
    return None if a.empty() else a


def _cell_values(msh: dolfinx.mesh.Mesh, expr: Expression, t: float = 0.0):
    """``expr`` at the midpoints of the local cells (owned and ghost), as its DG0 field."""
    imap = msh.topology.index_map(msh.topology.dim)
    n = imap.size_local + imap.num_ghosts
    if expr.is_uniform:
        return np.full(n, expr.value(t))
    x = dolfinx.mesh.compute_midpoints(msh, msh.topology.dim, np.arange(n, dtype=np.int32))
    return expr(x, t)


def _plus(f):
    """``f('+')`` for a fracture-face (DG0 submesh) function, None passes through."""
    return f("+") if f is not None else None
