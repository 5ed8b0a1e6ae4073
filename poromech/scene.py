"""The scene: a frozen, validated description of one simulation.

Every field carries its unit, default and meaning in its metadata; ``poromech.config`` builds
these classes from YAML (rejecting unknown keys and wrong types) and ``docs/scene_schema.md`` is
generated from them. Expressions (``Expr``) are numbers or strings in ``x``, ``y``, ``t`` and the
scene ``parameters``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from poromech.expressions import Expression

__all__ = [
    "BoundaryCondition",
    "Contact",
    "Domain",
    "FlowBoundaryCondition",
    "Flow",
    "FractureFlow",
    "FractureSpec",
    "Geometry",
    "Material",
    "MeshSpec",
    "Output",
    "Probe",
    "Scene",
    "Solver",
    "TimeSpec",
]

Expr = Expression
Formulation = Literal["none", "mixed", "stabilized_mixed", "mean_nitsche", "nitsche"]
Friction = Literal["coulomb", "tresca", "frictionless"]


def doc(text: str, unit: str = "", **checks) -> dict:
    """Field metadata: description, SI unit and value checks (``min``, ``max``, ``gt``, ...)."""
    return {"doc": text, "unit": unit, **checks}


@dataclass(frozen=True)
class Domain:
    """The matrix domain: a rectangle or a polygon."""

    rectangle: tuple[float, float, float, float] | None = field(
        default=None,
        metadata=doc("[x0, y0, x1, y1]; edges are named bottom, right, top, left", "m"),
    )
    polygon: tuple[tuple[float, float], ...] | None = field(
        default=None, metadata=doc("vertices [[x, y], ...]; edge i joins vertex i and i+1", "m")
    )
    boundary_names: dict[str, tuple[int, ...]] = field(
        default_factory=dict,
        metadata=doc("names of polygon edges, {name: [edge indices]}; unnamed edges are edge<i>"),
    )


@dataclass(frozen=True)
class FractureSpec:
    """One fracture: a polyline; a corner does not split it into two fractures."""

    points: tuple[tuple[float, float], ...] = field(
        metadata=doc("polyline points [[x, y], ...]; their order fixes n⁺ (left normal)", "m")
    )
    name: str = field(default="", metadata=doc("fracture name (default: its 1-based number)"))


@dataclass(frozen=True)
class Geometry:
    """Domain and fracture network."""

    domain: Domain = field(metadata=doc("the matrix domain"))
    fractures: tuple[FractureSpec, ...] = field(default=(), metadata=doc("the fracture network"))


@dataclass(frozen=True)
class MeshSpec:
    """gmsh size control and uniform refinement."""

    size: float = field(metadata=doc("element size away from fractures", "m", gt=0))
    fracture_size: float | None = field(
        default=None, metadata=doc("element size along fractures (default: size)", "m", gt=0)
    )
    tip_size: float | None = field(
        default=None, metadata=doc("element size at fracture ends (default: fracture_size)", "m",
                                   gt=0)
    )
    transition: float | None = field(
        default=None, metadata=doc("distance over which sizes grow to size (default: 4 size)", "m",
                                   gt=0)
    )
    refinement: int = field(
        default=0, metadata=doc("uniform refinement level m (cells x4, fracture faces x2)", "",
                                min=0, max=7)
    )


@dataclass(frozen=True)
class Material:
    """Linear elastic matrix (plane strain)."""

    young: Expr = field(metadata=doc("Young's modulus E (may vary in space)", "Pa", gt=0))
    poisson: Expr = field(metadata=doc("Poisson's ratio ν", "", gt=-1, lt=0.5))
    body_force: tuple[Expr, Expr] = field(
        default=(Expression(0.0), Expression(0.0)), metadata=doc("body force f", "N/m³")
    )


@dataclass(frozen=True)
class Contact:
    """Contact on the fractures: formulation, friction law and Nitsche parameters."""

    formulation: Formulation = field(
        default="nitsche",
        metadata=doc("mixed | stabilized_mixed | mean_nitsche | nitsche | none (open fractures)"),
    )
    friction: Friction = field(default="coulomb", metadata=doc("coulomb | tresca | frictionless"))
    friction_coefficient: float = field(
        default=0.5, metadata=doc("Coulomb friction coefficient F", "", min=0)
    )
    slip_bound: Expr | None = field(
        default=None, metadata=doc("Tresca slip bound s (required for tresca)", "Pa", min=0)
    )
    theta: float = field(
        default=-1.0,
        metadata=doc("Nitsche symmetry parameter θ: -1, 0 or 1", "", choices=(-1, 0, 1)),
    )
    beta_n: float = field(default=1e12, metadata=doc("β_n⁰; β_n = β_n⁰/h_σ", "Pa", gt=0))
    beta_t: float = field(default=4e10, metadata=doc("β_τ⁰; β_τ = β_τ⁰/h_σ", "Pa", gt=0))
    traction_side: Literal["plus", "mean"] = field(
        default="plus",
        metadata=doc("side whose stress defines T(u): plus (as in the paper) or mean of both"),
    )


@dataclass(frozen=True)
class BoundaryCondition:
    """A mechanical condition on named boundary edges (default: traction free)."""

    boundary: str = field(metadata=doc("boundary name (rectangle: bottom, right, top, left)"))
    displacement: tuple[Expr | None, Expr | None] | None = field(
        default=None, metadata=doc("imposed [u_x, u_y]; null leaves a component free", "m")
    )
    traction: tuple[Expr, Expr] | None = field(
        default=None, metadata=doc("imposed traction [t_x, t_y]", "Pa")
    )


@dataclass(frozen=True)
class TimeSpec:
    """Uniform time stepping (quasi-static); friction then acts on slip increments."""

    final: float = field(metadata=doc("final time T", "s", gt=0))
    steps: int = field(metadata=doc("number of uniform steps", "", min=1))


@dataclass(frozen=True)
class Solver:
    """Semi-smooth Newton (mechanics) and its linear solver."""

    line_search: Literal["contact", "basic", "bt", "l2", "cp"] = field(
        default="contact",
        metadata=doc("contact (poromech's active-set aware search) or a PETSc line search"),
    )
    reuse_jacobian: bool = field(
        default=True, metadata=doc("skip refactorization when the Jacobian did not change")
    )
    stale_factorization: bool = field(
        default=True,
        metadata=doc("after few contact-state changes, try GMRES preconditioned by the last "
                     "factorization before refactorizing"),
    )
    petsc: dict[str, str | float | int | bool | None] = field(
        default_factory=dict,
        metadata=doc("PETSc options for the mechanics solver, without the mech_ prefix"),
    )


@dataclass(frozen=True)
class FlowBoundaryCondition:
    """A flow condition on named boundary edges (unlisted boundaries are impervious)."""

    boundary: str = field(metadata=doc("boundary name"))
    pressure: Expr | None = field(default=None, metadata=doc("imposed pressure", "Pa"))
    flux: Expr | None = field(
        default=None,
        metadata=doc("imposed outward volumetric flux per area (negative: inflow)", "m/s"),
    )
    fracture_ends: Literal["inherit", "no_flow"] = field(
        default="inherit",
        metadata=doc("fracture ends on this boundary: inherit its condition (pressure, or the "
                     "flux through the fracture cross-section d_f) or no_flow"),
    )


@dataclass(frozen=True)
class FractureFlow:
    """Flow properties of one named fracture, overriding the fracture defaults of ``flow``."""

    fracture: str = field(metadata=doc("fracture name"))
    aperture: Expr | None = field(default=None, metadata=doc("aperture d_f", "m", gt=0))
    permeability: Expr | None = field(
        default=None, metadata=doc("tangential permeability K_f,τ", "m²", gt=0)
    )
    normal_permeability: Expr | None = field(
        default=None, metadata=doc("normal permeability Λ_f,n", "m²", gt=0)
    )
    conductivity: Expr | None = field(
        default=None, metadata=doc("conductivity C_f (replaces K_f,τ d_f)", "m³", gt=0)
    )


@dataclass(frozen=True)
class Flow:
    """Single-phase Darcy flow in matrix and fractures (HFV, DESIGN §5)."""

    permeability: tuple[Expr, ...] = field(
        metadata=doc("matrix permeability: [k] or [k_xx, k_yy] or [k_xx, k_xy, k_yy]", "m²")
    )
    viscosity: float = field(default=1e-3, metadata=doc("fluid viscosity η", "Pa·s", gt=0))
    aperture: Expr = field(default=Expression(1e-4), metadata=doc("fracture aperture d_f", "m",
                                                                   gt=0))
    fracture_permeability: Expr | None = field(
        default=None,
        metadata=doc("tangential fracture permeability K_f,τ (default d_f²/12)", "m²", gt=0),
    )
    fracture_normal_permeability: Expr | None = field(
        default=None, metadata=doc("normal fracture permeability Λ_f,n (default d_f²/12); "
                                   "T_f = 2 Λ_f,n / d_f", "m²", gt=0)
    )
    fracture_conductivity: Expr | None = field(
        default=None,
        metadata=doc("fracture conductivity C_f (default K_f,τ d_f, i.e. d_f³/12)", "m³", gt=0),
    )
    fractures: tuple[FractureFlow, ...] = field(
        default=(), metadata=doc("per-fracture values overriding the fracture defaults")
    )
    source: Expr = field(default=Expression(0.0), metadata=doc("matrix volumetric source", "1/s"))
    fracture_source: Expr = field(
        default=Expression(0.0), metadata=doc("fracture source per fracture area", "m/s")
    )
    boundary_conditions: tuple[FlowBoundaryCondition, ...] = field(
        default=(), metadata=doc("pressure / flux conditions; other boundaries are impervious")
    )
    initial_pressure: Expr = field(
        default=Expression(0.0), metadata=doc("initial pressure p⁰ (transient)", "Pa")
    )
    porosity: float = field(default=0.0, metadata=doc("initial matrix porosity φ⁰ (transient)", "",
                                                      min=0, max=1))
    biot_modulus: float | None = field(
        default=None,
        metadata=doc("Biot modulus M, matrix storage 1/M (transient; absent: no storage)", "Pa",
                     gt=0),
    )
    stabilization: float | None = field(
        default=None, metadata=doc("HFV stabilization β (default √d)", "", gt=0)
    )
    linear_solver: Literal["iterative", "direct"] = field(
        default="iterative",
        metadata=doc("defaults of the flow_ solver: iterative (CG + GAMG) or direct (MUMPS)"),
    )
    petsc: dict[str, str | float | int | bool | None] = field(
        default_factory=dict,
        metadata=doc("PETSc options for the flow solver, without the flow_ prefix; null removes "
                     "a default"),
    )


@dataclass(frozen=True)
class Probe:
    """A straight line along which fields are sampled to probe_<name>.csv."""

    name: str = field(metadata=doc("probe name (file probe_<name>.csv)"))
    start: tuple[float, float] = field(metadata=doc("start point", "m"))
    end: tuple[float, float] = field(metadata=doc("end point", "m"))
    samples: int = field(default=201, metadata=doc("number of sample points", "", min=2))
    interpolation: Literal["linear", "constant"] = field(
        default="linear",
        metadata=doc("linear: p_m from the HFV cell gradient, p_f linear between face and node "
                     "values; constant: the cell / face value"),
    )


@dataclass(frozen=True)
class Output:
    """What is written to the output directory."""

    xdmf: bool = field(default=True, metadata=doc("XDMF files for ParaView"))
    vtx: bool = field(default=True, metadata=doc("VTX (ADIOS2) file of a P2 displacement"))
    fractures_csv: bool = field(default=True, metadata=doc("fractures.csv, one row per face/time"))
    every: int = field(default=1, metadata=doc("write every n-th time step", "", min=1))


@dataclass(frozen=True)
class Scene:
    """A complete simulation description."""

    name: str = field(metadata=doc("scene name"))
    physics: Literal["mechanics", "flow"] = field(
        default="mechanics", metadata=doc("mechanics (contact) or flow (Darcy only)")
    )
    description: str = field(default="", metadata=doc("free text"))
    parameters: dict[str, float] = field(
        default_factory=dict, metadata=doc("named constants usable in every expression")
    )
    geometry: Geometry | None = field(
        default=None, metadata=doc("domain and fractures, or the name of a file in meshes/")
    )
    mesh: MeshSpec | None = field(default=None, metadata=doc("mesh size control"))
    degree: int = field(default=2, metadata=doc("displacement degree (1 or 2)", "",
                                                choices=(1, 2)))
    material: Material | None = field(default=None, metadata=doc("elastic matrix"))
    contact: Contact = field(default_factory=Contact, metadata=doc("contact on the fractures"))
    fracture_pressure: Expr | None = field(
        default=None, metadata=doc("fluid pressure p_f acting on both fracture faces", "Pa")
    )
    boundary_conditions: tuple[BoundaryCondition, ...] = field(
        default=(), metadata=doc("mechanical boundary conditions")
    )
    time: TimeSpec | None = field(default=None, metadata=doc("time stepping (absent: one solve)"))
    solver: Solver = field(default_factory=Solver, metadata=doc("nonlinear solver"))
    flow: Flow | None = field(default=None, metadata=doc("Darcy flow (physics: flow)"))
    probes: tuple[Probe, ...] = field(default=(), metadata=doc("sampling lines"))
    output: Output = field(default_factory=Output, metadata=doc("output selection"))
