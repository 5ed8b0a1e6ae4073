"""Exact solutions and error norms for verifying the HFV flow module (tests and benchmarks).

* :class:`JumpSolution`: the manufactured solution with pressure jumps of DESIGN §5 on
  ``Ω = (-1, 1) × (0, 1)`` with the fracture ``{x = 0}``;
* :class:`Diffusion1D`: decay of a sine mode with storage, ``s ∂p/∂t = (k/η) ∂²p/∂x²``;
* discrete L² norms over owned cells and fracture faces, reduced over the communicator;
* the blocking-intersection scenes (``configs/flow_barrier_conduit*.yaml``): a
  barrier crossed by a conduit, the conduit cut short of it, the barrier alone
  (:data:`BARRIER_VARIANTS`, :func:`barrier_metrics`).
"""

from __future__ import annotations

import importlib.resources
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from mpi4py import MPI

from poromech.flow.balance import boundary_fluxes, compute_fluxes, mass_balance
from poromech.flow.boundary import FlowBoundary
from poromech.flow.hfv import cell_gradients, isotropic_tensor
from poromech.flow.problem import DarcyProblem, FlowProperties, TimeStep
from poromech.flow.setup import problem_from_scene
from poromech.geometry.box import BoxGeometry, Fracture3D
from poromech.geometry.plane import PlaneGeometry
from poromech.io.probes import LineSampler
from poromech.mesh.fractured import FracturedMesh, distribute_mesh
from poromech.mesh.generate import MeshSizes, generate_mesh
from poromech.scene.geometry import mesh_sizes, scene_geometry
from poromech.scene.loading import load_scene
from poromech.scene.schema import Scene

__all__ = [
    "BARRIER_VARIANTS",
    "Diffusion1D",
    "JumpSolution",
    "barrier_metrics",
    "barrier_scene",
    "line_pressure",
    "observed_orders",
    "rectangle",
    "solve_scene",
    "uniform_mesh",
]

Array = npt.NDArray[np.float64]


def rectangle(x0: float, y0: float, x1: float, y1: float, fractures=()) -> PlaneGeometry:
    """A rectangle with edges bottom, right, top, left and the given fracture polylines."""
    boundary = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)
    fr = tuple(np.asarray(f, dtype=float) for f in fractures)
    return PlaneGeometry(boundary, ("bottom", "right", "top", "left"), fr,
                         tuple(f"f{i}" for i in range(len(fr))))


def uniform_mesh(comm: MPI.Comm, geo: PlaneGeometry | BoxGeometry, size: float, refinement: int = 0,
                 owner=None) -> FracturedMesh:
    """Mesh ``geo`` with a uniform target size and ``refinement`` splits (collective).

    Args:
        comm: Communicator.
        geo: Geometry.
        size: Element size everywhere (m).
        refinement: Uniform refinement level.
        owner: Optional callable ``owner(centroids) -> ranks`` imposing the partition.
    """
    sizes = MeshSizes(size, size, size, size, refinement)
    if geo.dim == 3:
        from poromech.mesh.generate3d import generate_mesh_3d

        return distribute_mesh(comm, geo, lambda: generate_mesh_3d(geo, sizes), owner)
    return distribute_mesh(comm, geo, lambda: generate_mesh(geo, sizes), owner)


def l2(comm: MPI.Comm, weights: Array, values: Array) -> float:
    """``sqrt(Σ w v²)`` over all ranks (collective)."""
    return float(np.sqrt(comm.allreduce(float(np.sum(weights * values**2)))))


def observed_orders(h: Array, errors: Array) -> Array:
    """``log(e_i/e_{i+1}) / log(h_i/h_{i+1})`` for successive meshes."""
    h, e = np.asarray(h, float), np.asarray(errors, float)
    return np.log(e[:-1] / e[1:]) / np.log(h[:-1] / h[1:])


@dataclass(frozen=True)
class JumpSolution:
    """Manufactured solution with pressure jumps (DESIGN §5), ``K = I``, ``η = 1``.

    ``p_f = g``, ``p_m = g (a - T_f (a-1) x + x²)`` for ``x < 0`` and
    ``p_m = g (c + T_f (c-1) x + x²)`` for ``x > 0``, ``g = cos(π y)``. The fracture runs from
    ``(0, 0)`` to ``(0, 1)``, so its ``+`` side is ``x > 0``. Fracture ends are impervious
    (``g' = 0`` at ``y = 0, 1``).

    With ``dim = 3`` the domain is ``(-1, 1) × (0, 1)²``, the fracture the square ``{x = 0}``
    (``+`` side ``x > 0``) and ``g = cos(π y) cos(π z)``; its edges on the box are impervious.

    Attributes:
        a: Trace factor on the ``-`` side (``x < 0``).
        c: Trace factor on the ``+`` side (``x > 0``).
        T_f: Normal transmissibility ``2 Λ_f,n / d_f`` (m).
        C_f: Fracture conductivity (m³).
        aperture: Aperture used to express ``T_f`` (m).
        dim: Space dimension, 2 or 3.
    """

    a: float = 2.0
    c: float = 0.5
    T_f: float = 3.0
    C_f: float = 1.0
    aperture: float = 0.02
    dim: int = 2

    def geometry(self) -> PlaneGeometry | BoxGeometry:
        """``(-1, 1) × (0, 1)`` (3D: ``× (0, 1)``) with the fracture ``{x = 0}``."""
        if self.dim == 3:
            square = [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 1.0], [0.0, 1.0, 0.0]]
            return BoxGeometry((-1.0, 0.0, 0.0, 1.0, 1.0, 1.0),
                               (Fracture3D.polygon("f0", square),))
        return rectangle(-1.0, 0.0, 1.0, 1.0, [[[0.0, 0.0], [0.0, 1.0]]])

    def g(self, points) -> Array:
        """``cos(π y)`` (3D: ``cos(π y) cos(π z)``)."""
        out = np.cos(np.pi * points[:, 1])
        if self.dim == 3:
            out = out * np.cos(np.pi * points[:, 2])
        return out

    def p_m(self, points, t=0.0):
        """Matrix pressure (Pa) at points ``(n, d)``."""
        x = points[:, 0]
        left = self.a - self.T_f * (self.a - 1) * x + x**2
        right = self.c + self.T_f * (self.c - 1) * x + x**2
        return self.g(points) * np.where(x < 0, left, right)

    def p_f(self, points, t=0.0):
        """Fracture pressure (Pa) at points ``(n, d)``."""
        return self.g(points)

    def source(self, points, t=0.0):
        """``q = -Δp_m`` (1/s)."""
        return (self.dim - 1) * np.pi**2 * self.p_m(points) - 2.0 * self.g(points)

    def fracture_source(self, points, t=0.0):
        """``q_f = -C_f Δ_τ p_f - T_f (p⁺ - p_f) - T_f (p⁻ - p_f)`` (m/s)."""
        g = self.g(points)
        return (self.dim - 1) * self.C_f * np.pi**2 * g - self.T_f * g * (self.a + self.c - 2.0)

    def problem(self, fm: FracturedMesh, **kwargs) -> DarcyProblem:
        """The HFV problem of this solution on ``fm`` (collective)."""
        nc = fm.msh.topology.index_map(fm.msh.topology.dim).size_local
        nf = len(fm.fractures.facets)
        nan = np.full(nf, np.nan)
        props = FlowProperties(
            permeability=isotropic_tensor(np.ones(nc), self.dim), viscosity=1.0,
            aperture=np.full(nf, self.aperture), fracture_permeability=nan,
            normal_permeability=np.full(nf, 0.5 * self.T_f * self.aperture),
            conductivity=np.full(nf, self.C_f), storage=np.zeros(nc),
        )
        sides, ends = ((1, 3), (0, 2)) if self.dim == 2 else ((0, 1), (2, 3, 4, 5))
        bcs = [FlowBoundary("sides", sides, "pressure", self.p_m),
               FlowBoundary("ends", ends, "pressure", self.p_m, "no_flow")]
        return DarcyProblem(fm, props, bcs, self.source, self.fracture_source, **kwargs)

    def errors(self, problem: DarcyProblem) -> dict[str, float]:
        """Discrete L² errors of cell, trace, fracture and node pressures (collective)."""
        comm, g, f = problem.comm, problem.geom, problem.faces
        g_mid = self.g(f.midpoint)
        exact_traces = np.column_stack([self.c * g_mid, self.a * g_mid])
        ends = problem.dofs.points[problem.dofs.node]
        nv = ends.shape[1]
        weight = f.measure[:, None] / nv
        return {
            "cell": l2(comm, g.volume, problem.cell_pressure - self.p_m(g.centroid)),
            "trace": l2(comm, f.measure[:, None], problem.trace_pressure - exact_traces),
            "fracture": l2(comm, f.measure, problem.fracture_pressure - self.p_f(f.midpoint)),
            "node": l2(comm, weight, problem.node_pressure
                       - self.p_f(ends.reshape(-1, self.dim)).reshape(-1, nv)),
        }


@dataclass(frozen=True)
class Diffusion1D:
    """``p = P exp(-λ t) sin(π x / L)``, ``λ = k π² / (η s L²)``, on ``(0, L) × (0, H)``.

    Zero pressure on the left and right, no flow on top and bottom, no fractures.

    Attributes:
        length: ``L`` (m).
        height: ``H`` (m).
        mobility: ``k/η`` (m²/(Pa·s)).
        storage: ``s = 1/M`` (1/Pa).
        amplitude: ``P`` (Pa).
    """

    length: float = 1.0
    height: float = 0.1
    mobility: float = 1.0
    storage: float = 1.0
    amplitude: float = 1.0

    @property
    def rate(self) -> float:
        """Decay rate ``λ`` (1/s)."""
        return self.mobility * np.pi**2 / (self.storage * self.length**2)

    def pressure(self, points, t=0.0):
        """The exact pressure (Pa) at points ``(n, 2)``."""
        return self.amplitude * np.exp(-self.rate * t) * np.sin(np.pi * points[:, 0] / self.length)

    def geometry(self) -> PlaneGeometry:
        """The strip ``(0, L) × (0, H)``."""
        return rectangle(0.0, 0.0, self.length, self.height)

    def problem(self, fm: FracturedMesh, **kwargs) -> DarcyProblem:
        """The HFV problem with storage on ``fm`` (collective)."""
        nc = fm.msh.topology.index_map(fm.msh.topology.dim).size_local
        empty = np.zeros(0)
        props = FlowProperties(
            permeability=isotropic_tensor(np.full(nc, self.mobility)), viscosity=1.0,
            aperture=empty, fracture_permeability=empty, normal_permeability=empty,
            conductivity=empty, storage=np.full(nc, self.storage),
        )
        zero = FlowBoundary("ends", (1, 3), "pressure", lambda x, t: np.zeros(len(x)))
        return DarcyProblem(fm, props, [zero], **kwargs)

    def run(self, problem: DarcyProblem, final: float, steps: int) -> float:
        """Implicit Euler from the exact initial state; relative L² error at ``final``."""
        problem.set_pressure(self.pressure, 0.0)
        s = problem.properties.storage
        phi_prev = s * problem.cell_pressure
        dt = final / steps
        for n in range(1, steps + 1):
            step = TimeStep(dt, phi_prev, np.zeros_like(phi_prev), np.zeros(0))
            problem.solve(n * dt, step)
            phi_prev = problem.porosity(step)
        g = problem.geom
        exact = self.pressure(g.centroid, final)
        comm = problem.comm
        return l2(comm, g.volume, problem.cell_pressure - exact) / l2(comm, g.volume, exact)


#: The barrier alone: ``configs/flow_barrier_conduit.yaml`` without the conduit (an override).
BARRIER_ONLY = ("geometry={domain: {rectangle: [0.0, 0.0, 1.0, 1.0]}, "
                "fractures: [{name: barrier, points: [[0.5, 0.0], [0.5, 1.0]]}]}")

#: Barrier-conduit variants: scene file in ``configs/`` and overrides. ``crossing``: the conduit
#: crosses the barrier (X junction); ``cut``: the conduit stops 1 mm short of it on both sides;
#: ``barrier``: no conduit.
BARRIER_VARIANTS = {
    "crossing": ("flow_barrier_conduit.yaml", ()),
    "cut": ("flow_barrier_conduit_cut.yaml", ()),
    "barrier": ("flow_barrier_conduit.yaml", (BARRIER_ONLY,)),
}

#: Distance from the barrier ``x = 0.5`` at which ``p_m`` is read on ``y = 0.5`` (m).
JUMP_OFFSET = 1e-4


def barrier_scene(variant: str, refinement: int = 0, overrides=()) -> Scene:
    """A variant of the barrier-conduit scene (:data:`BARRIER_VARIANTS`) at a refinement level."""
    name, extra = BARRIER_VARIANTS[variant]
    path = importlib.resources.files("poromech.configs").joinpath(name)
    return load_scene(path, [*extra, f"mesh.refinement={refinement}", *overrides])


def solve_scene(scene: Scene, comm: MPI.Comm, owner=None) -> DarcyProblem:
    """Mesh a steady flow scene and solve it, without output (collective).

    ``owner(centroids) -> ranks`` optionally imposes the partition.
    """
    geo, sizes = scene_geometry(scene), mesh_sizes(scene)
    fm = distribute_mesh(comm, geo, lambda: generate_mesh(geo, sizes), owner)
    problem = problem_from_scene(scene, fm)
    problem.solve(0.0)
    return problem


def line_pressure(problem: DarcyProblem, start, end, samples: int) -> Array:
    """Linear reconstruction of ``p_m`` at ``samples`` points of a segment, on every rank.

    The reconstruction ``p_K + ∇_K p·(x - x_K)`` of the probes (collective).
    """
    g = problem.geom
    grads = cell_gradients(g.area, g.normal, g.volume, problem.cell_pressure,
                           problem.face_pressure)
    sampler = LineSampler(problem.fm.msh, start, end, samples)
    values = sampler.cells(problem.cell_pressure, grads, g.centroid)
    return problem.comm.bcast(values, root=0)


def barrier_metrics(problem: DarcyProblem, offset: float = JUMP_OFFSET) -> dict[str, float]:
    """Outflow on the right, pressure jump across the barrier on ``y = 0.5`` (collective).

    Returns:
        ``outflow`` (m²/s per unit depth), ``jump`` ``p_m(0.5 - offset, 0.5) -
        p_m(0.5 + offset, 0.5)`` (Pa), the ``relative_residual`` of the mass balance and the
        number of ``unknowns``.
    """
    fluxes = compute_fluxes(problem)
    left, right = line_pressure(problem, (0.5 - offset, 0.5), (0.5 + offset, 0.5), 2)
    return {
        "outflow": boundary_fluxes(problem, fluxes)["right"]["total"],
        "jump": float(left - right),
        "relative_residual": mass_balance(problem, fluxes)["relative_residual"],
        "unknowns": problem.dofs.num_global,
    }
