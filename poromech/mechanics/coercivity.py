"""When is symmetric Nitsche (θ = 1) coercive? A local trace-inverse bound, computed on the mesh.

With θ = 1 the open branch of eq. (8) leaves ``-∫_Γ (1/β_n) T_n(u) T_n(v) + (1/β_τ) T_τ(u) T_τ(v)``
in the bilinear form, and the contact branch ``a - 2 T·[[v]] + β [[v]]²`` is bounded below by the
same ``a - T²/β``. The Jacobian is therefore positive definite on every branch when, for all
``v``, ``a(v, v) > Σ_F h_F ∫_F T_n(v)²/β_n⁰ + |T_τ(v)|²/β_τ⁰`` (``β = β⁰/h_F``). A sufficient,
computable condition is that every cell ``K`` next to the fractures satisfies it alone:

    ρ_K = max_{v ∈ P_k(K)^d} Σ_{F ⊂ ∂K ∩ Γ} w_F h_F ∫_F (T_n(v)²/β_n⁰ + |T_τ(v)|²/β_τ⁰) / a_K(v, v)

and ``ρ = max_K ρ_K < 1`` (``w_F = 1`` for the ``+`` cell when the traction is taken on the
``+`` side, ``1/2`` for each side for the mean traction). ``ρ`` is proportional to ``E/β⁰``, and
grows with the degree, with flat cells and towards incompressibility. Below ``ρ < 1`` nothing is
guaranteed: the discrete problem may have no solution or several, and Newton may converge to a
wrong one (docs/mechanics.md, "Nitsche parameters and symmetric Nitsche").
"""

from __future__ import annotations

import dolfinx_solver  # noqa: F401

import numpy as np
import numpy.typing as npt
import scipy.linalg
import ufl
from dolfinx import fem
from mpi4py import MPI

from poromech.forms.elasticity import epsilon, sigma
from poromech.forms.fracture import face_max, tangent
from poromech.mesh.fractured import FRACTURE_TAG, FracturedMesh, face_size, fracture_measure

__all__ = ["symmetric_nitsche_ratio"]


def _traction_form(u, v, n, h, young, poisson, side: str, beta_n0: float,
                   beta_t0: float | None):
    """``Σ w h (T_n(u) T_n(v)/β_n⁰ + T_τ(u) T_τ(v)/β_τ⁰)`` on the chosen side(s) (integrand).

    No tangential term when ``beta_t0`` is None (frictionless).
    """
    planar = n.ufl_shape == (2,)
    tau = tangent(n) if planar else None
    sides = (("+", 1.0),) if side == "plus" else (("+", 0.5), ("-", 0.5))
    terms = []
    for s, w in sides:
        tu = ufl.dot(sigma(u, young, poisson)(s), n)
        tv = ufl.dot(sigma(v, young, poisson)(s), n)
        term = ufl.dot(tu, n) * ufl.dot(tv, n) / beta_n0
        if beta_t0 is not None and planar:
            term += ufl.dot(tu, tau) * ufl.dot(tv, tau) / beta_t0
        elif beta_t0 is not None:  # 3D: T_τ(u)·T_τ(v), the tangential part in any frame
            term += ufl.dot(tu - ufl.dot(tu, n) * n, tv) / beta_t0
        terms.append(w * term)
    return h * sum(terms[1:], terms[0])


def _cell_ratio(A: npt.NDArray[np.float64], B: npt.NDArray[np.float64]) -> float:
    """Largest ``vᵀBv / vᵀAv`` off the kernel of ``A`` (the rigid motions of the cell)."""
    lam, Z = scipy.linalg.eigh(A)
    keep = lam > 1e-10 * lam.max()
    Zs = Z[:, keep] / np.sqrt(lam[keep])
    return float(scipy.linalg.eigvalsh(Zs.T @ B @ Zs).max())


def symmetric_nitsche_ratio(fm: FracturedMesh, degree: int, young: npt.ArrayLike,
                            poisson: npt.ArrayLike, beta_n0: float, beta_t0: float | None,
                            side: str = "plus", local: bool = False) -> float:
    """The ratio ``ρ`` above: symmetric Nitsche is coercive on this mesh when ``ρ < 1``.

    Args:
        fm: The fractured mesh.
        degree: Displacement degree ``k``.
        young: Young's modulus (Pa) per local cell (owned and ghost), or one value.
        poisson: Poisson's ratio per local cell, or one value.
        beta_n0: ``β_n⁰`` (Pa).
        beta_t0: ``β_τ⁰`` (Pa), or None without friction (no tangential Nitsche terms).
        side: ``"plus"`` or ``"mean"``, as ``contact.traction_side``.
        local: ``β⁰`` are the values at the largest modulus, each face taking ``β⁰ E_σ/E_max``
            (``contact.beta_scaling: local``).

    Returns:
        ``ρ`` (identical on every rank; 0 without fractures). Collective. In parallel, a cell
        whose fracture faces belong to different ranks is bounded per rank.
    """
    msh = fm.msh
    if fm.num_fracture_faces == 0:
        return 0.0
    Q0 = fem.functionspace(msh, ("DG", 0))
    E, nu = fem.Function(Q0), fem.Function(Q0)
    ncells = Q0.dofmap.index_map.size_local + Q0.dofmap.index_map.num_ghosts
    E.x.array[Q0.dofmap.list[:ncells, 0]] = np.broadcast_to(young, (ncells,))
    nu.x.array[Q0.dofmap.list[:ncells, 0]] = np.broadcast_to(poisson, (ncells,))
    gdim = msh.geometry.dim
    W = fem.functionspace(msh, ("DG", degree, (gdim,)))
    u, v = ufl.TrialFunction(W), ufl.TestFunction(W)
    entities = fm.fractures.integration_entities.reshape(-1, 4)
    cells = np.unique(entities[:, [0, 2]] if side == "mean" else entities[:, 0])
    dx = ufl.Measure("dx", domain=msh, subdomain_data=[(1, cells.astype(np.int32))])
    n = ufl.FacetNormal(msh)("+")
    a = fem.form(ufl.inner(sigma(u, E, nu), epsilon(v)) * dx(1))
    dG = fracture_measure(fm)(FRACTURE_TAG)
    h = face_size(msh)("+")
    if local:
        young_max = msh.comm.allreduce(float(np.max(young, initial=0.0)), op=MPI.MAX)
        scale = face_max(E) / young_max
        beta_n0 = beta_n0 * scale
        beta_t0 = None if beta_t0 is None else beta_t0 * scale
    b = fem.form(_traction_form(u, v, n, h, E, nu, side, beta_n0, beta_t0) * dG)
    A = fem.assemble_matrix(a).to_scipy(ghosted=True).tocsr()
    B = fem.assemble_matrix(b).to_scipy(ghosted=True).tocsr()
    dofs = W.dofmap.list
    rho = 0.0
    for c in cells:
        d = (gdim * dofs[c][:, None] + np.arange(gdim)).ravel()
        rho = max(rho, _cell_ratio(A[d][:, d].toarray(), B[d][:, d].toarray()))
    return float(msh.comm.allreduce(rho, op=MPI.MAX))
