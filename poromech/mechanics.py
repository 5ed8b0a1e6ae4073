"""The contact-mechanics problem on a fractured mesh: spaces, unknowns, forms, loads, diagnostics.

Only what a scene needs is built: no multiplier or face-average spaces for Nitsche, no tangential
terms without friction, no contact terms at all for open (``formulation: none``) fractures, no
fracture submesh when there are no fractures.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import dolfinx_solver  # noqa: F401

import dolfinx
import numpy as np
import numpy.typing as npt
import ufl
from dolfinx import fem

from poromech.expressions import Expression
from poromech.forms import contact as cforms
from poromech.forms.elasticity import elastic_form
from poromech.forms.fracture import FractureKinematics, normal_jump, slip
from poromech.mesh import FRACTURE_TAG, FracturedMesh, cracked_space, fracture_measure
from poromech.scene import Scene

__all__ = ["FACE_FIELDS", "MechanicsModel", "STATE_NAMES"]

#: Fracture face fields (DG0 on the fracture mesh), in storage order.
FACE_FIELDS = ("jump_n", "jump_t", "traction_n", "traction_t", "contact", "slip")
#: Contact states written to the output, by code.
STATE_NAMES = ("open", "stick", "slip")


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
        exprs = self.exprs
        self.target.interpolate(
            lambda x: np.vstack([e(x[0], x[1], t) for e in exprs]) if len(exprs) > 1
            else exprs[0](x[0], x[1], t)
        )
        self.target.x.scatter_forward()


def _facet_submesh(fm: FracturedMesh):
    """The fracture faces as a 1D mesh, with its entity map to the parent facets (collective)."""
    sub, emap, _, _ = dolfinx.mesh.create_submesh(fm.msh, 1, fm.fracture_facets_all)
    return sub, emap


@dataclass
class MechanicsModel:
    """Unknowns and compiled forms of the static/quasi-static contact problem.

    Attributes:
        fm: The fractured mesh.
        scene: The scene.
        V: Displacement space (duplicated nodes across fractures).
        u: Displacement (m).
        unknowns: ``[u, λ?, averages?]`` in block order.
        F: Compiled residual blocks.
        J: Compiled Jacobian blocks (None entries for zero blocks).
        bcs: Dirichlet conditions on ``V``.
        linear: True when no term depends nonlinearly on the unknowns (open fractures).
    """

    fm: FracturedMesh
    scene: Scene
    V: fem.FunctionSpace = field(init=False)
    u: fem.Function = field(init=False)
    unknowns: list[fem.Function] = field(init=False)
    F: list[fem.Form] = field(init=False)
    J: list[list[fem.Form | None]] = field(init=False)
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
        c = self.params
        self.submesh, self.emap = _facet_submesh(fm) if self.has_fractures else (None, None)
        self.entity_maps = [self.emap] if self.emap is not None else []
        Q0 = fem.functionspace(msh, ("DG", 0))
        self.young = self._field(Q0, scene.material.young, "young")
        self.poisson = self._field(Q0, scene.material.poisson, "poisson")
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
        self.kinematics = self._kinematics()
        self.bcs = self._dirichlet()
        self._build_forms()

    # -- inputs -----------------------------------------------------------------------------
    @property
    def _quasi_static(self) -> bool:
        c = self.scene.contact
        return (self.scene.time is not None and c.formulation != "none"
                and c.friction != "frictionless")

    def _contact_parameters(self) -> cforms.ContactParameters:
        c, msh = self.scene.contact, self.fm.msh
        h = ufl.FacetArea(msh)("+")
        fc = fem.Constant(msh, c.friction_coefficient) if c.friction == "coulomb" else None
        s = None
        if c.friction == "tresca":
            s = fem.Constant(msh, c.slip_bound.value())
            self._updaters.append(_Updater(s, (c.slip_bound,)))
        return cforms.ContactParameters(
            formulation=c.formulation if self.fm.num_fracture_faces else "none",
            friction=c.friction,
            theta=c.theta,
            beta_n=fem.Constant(msh, c.beta_n) / h,
            beta_t=fem.Constant(msh, c.beta_t) / h,
            friction_coefficient=fc,
            slip_bound=s,
        )

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
        if self.scene.fracture_pressure is not None and self.has_fractures:
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
        young = self.young if isinstance(self.young, fem.Function) else self.young
        return FractureKinematics(
            n=n, young=young, poisson=self.poisson, side=self.scene.contact.traction_side,
            fracture_pressure=pf, slip_reference=self.u_prev,
        )

    def _dirichlet(self) -> list[fem.DirichletBC]:
        geo, fm = self.fm.geometry, self.fm
        bcs = []
        for bc in self.scene.boundary_conditions:
            if bc.displacement is None:
                continue
            edges = tuple(i for i, n in enumerate(geo.boundary_names) if n == bc.boundary)
            facets = fm.boundary(edges)
            for k, expr in enumerate(bc.displacement):
                if expr is None:
                    continue
                Vk, _ = self.V.sub(k).collapse()
                dofs = fem.locate_dofs_topological((self.V.sub(k), Vk), 1, facets)
                g = fem.Function(Vk)
                upd = _Updater(g, (expr,))
                upd(0.0)
                if expr.depends_on_time:
                    self._updaters.append(upd)
                bcs.append(fem.dirichletbc(g, dofs, self.V.sub(k)))
        return bcs

    # -- forms ------------------------------------------------------------------------------
    def _build_forms(self) -> None:
        scene, fm, c = self.scene, self.fm, self.params
        msh = fm.msh
        v = ufl.TestFunction(self.V)
        dx = ufl.Measure("dx", domain=msh)
        tags = dolfinx.mesh.meshtags(
            msh, 1, fm.boundary_facets[np.argsort(fm.boundary_facets)],
            fm.boundary_edge[np.argsort(fm.boundary_facets)] + 1,
        )
        ds = ufl.Measure("ds", domain=msh, subdomain_data=tags)
        F0 = elastic_form(self.u, v, self.young, self.poisson, dx)
        f = scene.material.body_force
        if not all(e.is_constant and e.value() == 0.0 for e in f):
            F0 -= ufl.dot(self._vector_input(f), v) * dx
        for bc in scene.boundary_conditions:
            if bc.traction is None:
                continue
            edges = [i + 1 for i, n in enumerate(fm.geometry.boundary_names) if n == bc.boundary]
            F0 -= sum(ufl.dot(self._vector_input(bc.traction), v) * ds(e) for e in edges)
        dG = fracture_measure(fm)(FRACTURE_TAG)
        self.dG = dG
        residuals = [F0]
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
            weight = scale / ufl.FacetArea(msh)("+")
            cp = cforms.ContactParameters(**{**c.__dict__, "average_scale": weight})
            residuals.append(
                cforms.averages_residual(self.kinematics, cp, self.u, self.avg("+"), q("+"), dG)
            )
        self.linear = not (c.active and self.has_fractures)
        jac = [[_derivative(Fi, uj) for uj in self.unknowns] for Fi in residuals]
        em = self.entity_maps or None
        self.F = [fem.form(Fi, entity_maps=em) for Fi in residuals]
        self.J = [[fem.form(a, entity_maps=em) if a is not None else None for a in row]
                  for row in jac]
        self._build_diagnostics()

    def _build_diagnostics(self) -> None:
        """Face averages of jumps, tractions and contact indicators (see :data:`FACE_FIELDS`)."""
        if not self.has_fractures:
            self.faces = None
            return
        self.faces = fem.Function(self._dg0(len(FACE_FIELDS)), name="fracture")
        q = ufl.TestFunction(self.faces.function_space)
        fk, c = self.kinematics, self.params
        jn, jt = normal_jump(self.u, fk.n), slip(self.u, fk.n)
        if c.active:
            contact, sliding, tn, tt = cforms.state_indicators(
                fk, c, self.u, _plus(self.lam), _plus(self.avg)
            )
        elif fk.fracture_pressure is not None:
            contact, sliding, tn, tt = 0.0, 0.0, 0.0 * jn, 0.0 * jn
        else:
            contact, sliding, tn, tt = 0.0, 0.0, 0.0 * jn, 0.0 * jn
        values = (jn, jt, tn, tt, contact, sliding)
        h = ufl.FacetArea(self.fm.msh)("+")
        form = sum(val * q("+")[i] / h for i, val in enumerate(values)) * self.dG
        self._faces_form = fem.form(form, entity_maps=self.entity_maps or None)

    # -- time and outputs -------------------------------------------------------------------
    def set_time(self, t: float) -> None:
        """Re-evaluate every time-dependent load, boundary value and parameter."""
        for upd in self._updaters:
            upd(t)

    def accept_step(self) -> None:
        """Store the converged displacement as the reference of the next slip increment."""
        if self.u_prev is not None:
            self.u_prev.x.array[:] = self.u.x.array

    def face_fields(self) -> npt.NDArray[np.float64]:
        """Owned fracture face values of :data:`FACE_FIELDS`, ``(faces, 6)`` (collective)."""
        if self.faces is None:
            return np.empty((0, len(FACE_FIELDS)))
        self.faces.x.array[:] = 0.0
        fem.assemble_vector(self.faces.x.array, self._faces_form)
        self.faces.x.scatter_reverse(dolfinx.la.InsertMode.add)
        self.faces.x.scatter_forward()
        sub_cells = self.emap.sub_topology_to_topology(self.fm.fractures.facets, inverse=True)
        vals = self.faces.x.array.reshape(-1, len(FACE_FIELDS))
        return vals[sub_cells]

    @staticmethod
    def states(values: npt.NDArray[np.float64]) -> npt.NDArray[np.int8]:
        """Contact state code per face (0 open, 1 stick, 2 slip) from :meth:`face_fields`."""
        contact, sliding = values[:, 4], values[:, 5]
        state = np.where(contact > 0.5, 1, 0).astype(np.int8)
        state[(contact > 0.5) & (sliding > 0.5 * contact)] = 2
        return state

    def dof_count(self) -> int:
        """Global number of unknowns of the nonlinear system."""
        return sum(f.function_space.dofmap.index_map.size_global
                   * f.function_space.dofmap.index_map_bs for f in self.unknowns)


def _derivative(F, u):
    """``dF/du`` as a UFL form, or None when it vanishes identically."""
    a = ufl.derivative(F, u, ufl.TrialFunction(u.function_space))
    a = ufl.algorithms.expand_derivatives(a)
    return None if a.empty() else a


def _plus(f):
    """``f('+')`` for a fracture-face (DG0 submesh) function, None passes through."""
    return f("+") if f is not None else None
