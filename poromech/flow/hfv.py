"""Local matrices of the hybrid finite volume (HFV/SUSHI) scheme, vectorized over cells.

Pure NumPy: no mesh, MPI or PETSc. Shapes use ``n`` cells, ``F`` faces per cell and space
dimension ``d``. The construction follows DESIGN §5 (Eymard, Gallouët, Herbin 2010; Brenner,
Hennicker, Masson, Samier 2017, eq. (9)-(10)):

* ``A_K = (1/|K|) N Λ_K Nᵀ + Pᵀ D_β P`` with ``N`` rows ``|σ| n_{K,σ}ᵀ``, ``C`` rows
  ``(x_σ - x_K)ᵀ``, ``P = I - (1/|K|) C Nᵀ`` and
  ``D_β = diag(β² |σ| (n_{K,σ}·Λ_K n_{K,σ}) / (d d_{K,σ}))``, ``d_{K,σ} = (x_σ - x_K)·n_{K,σ}``;
* fluxes ``F_{K,σ} = Σ_σ' A_K^{σσ'} (p_K - p_{K,σ'})`` (outward, m²·Pa per unit depth in 2D
  when ``Λ`` is in m²; divide by the viscosity for a volumetric flux).

The matrices are symmetric positive definite and exact for affine pressures: when
``p_K - p_{K,σ} = -(x_σ - x_K)·∇p`` the stabilization term vanishes (``Nᵀ C = |K| I``) and
``F_{K,σ} = -|σ| Λ_K ∇p·n_{K,σ}``.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = [
    "cell_gradients",
    "cell_matrices",
    "fracture_face_matrices",
    "fracture_half_transmissibilities",
    "isotropic_tensor",
    "permeability_tensors",
    "series_matrices",
]

Array = npt.NDArray[np.float64]


def cell_matrices(
    area: Array, normal: Array, offset: Array, volume: Array, perm: Array, beta: float
) -> Array:
    """HFV cell matrices ``A_K`` (DESIGN §5), shape ``(n, F, F)``.

    Args:
        area: Face measures ``|σ|``, ``(n, F)`` (m in 2D).
        normal: Outward unit normals ``n_{K,σ}``, ``(n, F, d)``.
        offset: ``x_σ - x_K`` (face centre minus cell centre), ``(n, F, d)`` (m).
        volume: Cell measures ``|K|``, ``(n,)`` (m² in 2D).
        perm: Mobility tensors ``Λ_K`` (permeability / viscosity), ``(n, d, d)``.
        beta: Stabilization ``β`` (``√d`` in DESIGN §5).

    Returns:
        The symmetric positive definite matrices ``A_K``.
    """
    n, nf, d = normal.shape
    N = area[..., None] * normal
    Nt = N.transpose(0, 2, 1)
    inv_vol = (1.0 / volume)[:, None, None]
    consistent = (N @ perm @ Nt) * inv_vol
    P = np.eye(nf)[None] - (offset @ Nt) * inv_vol
    dist = np.einsum("nfi,nfi->nf", offset, normal)
    lam_n = np.einsum("nfi,nfi->nf", normal @ perm, normal)
    D = beta**2 * area * lam_n / (d * dist)
    return consistent + P.transpose(0, 2, 1) @ (D[..., None] * P)


def cell_gradients(
    area: Array, normal: Array, volume: Array, p_cell: Array, p_face: Array
) -> Array:
    """Consistent cell gradients ``∇_K p = (1/|K|) Σ_σ |σ| (p_{K,σ} - p_K) n_{K,σ}``, ``(n, d)``.

    Exact for affine pressures; used for the linear reconstruction of probes (Pa/m).
    """
    jump = p_face - p_cell[:, None]
    return np.einsum("nf,nfi->ni", area * jump, normal) / volume[:, None]


def fracture_half_transmissibilities(length: Array, conductivity: Array) -> Array:
    """Two-point transmissibilities between a 2D fracture face and each of its two nodes.

    The HFV construction one dimension down (DESIGN §5, "fracture face σ") with ``β = 1``
    reduces in 1D to ``T_{σ,e} = C_f / (|σ|/2)``; returns ``(n,)`` (m² per unit depth for a
    conductivity in m³, before dividing by the viscosity).
    """
    return 2.0 * conductivity / length


def isotropic_tensor(k: Array, dim: int = 2) -> Array:
    """``k I`` as ``(n, dim, dim)`` tensors."""
    return k[:, None, None] * np.eye(dim)[None]


def permeability_tensors(components: list[Array], dim: int = 2) -> Array:
    """Tensors ``(n, d, d)`` from their components (m²).

    2D: ``[k]``, ``[k_xx, k_yy]`` or ``[k_xx, k_xy, k_yy]``; 3D: ``[k]``, ``[k_xx, k_yy, k_zz]``
    or ``[k_xx, k_xy, k_xz, k_yy, k_yz, k_zz]``.
    """
    if len(components) == 1:
        return isotropic_tensor(components[0], dim)
    if dim == 3:
        if len(components) == 3:
            return np.stack(components, -1)[..., None] * np.eye(3)[None]
        if len(components) != 6:
            raise ValueError(f"permeability needs 1, 3 or 6 components in 3D, got "
                             f"{len(components)}")
        xx, xy, xz, yy, yz, zz = components
        return np.stack([np.stack([xx, xy, xz], -1), np.stack([xy, yy, yz], -1),
                         np.stack([xz, yz, zz], -1)], -2)
    if len(components) == 2:
        kxx, kyy = components
        kxy = np.zeros_like(kxx)
    elif len(components) == 3:
        kxx, kxy, kyy = components
    else:
        raise ValueError(f"permeability needs 1, 2 or 3 components, got {len(components)}")
    return np.stack([np.stack([kxx, kxy], -1), np.stack([kxy, kyy], -1)], -2)


def fracture_face_matrices(edges: Array, tangents: Array, beta: float) -> Array:
    """HFV matrices of triangular fracture faces for a unit conductivity, ``(n, 3, 3)``.

    The construction of :func:`cell_matrices` in the plane of each face (DESIGN §5, "the same
    construction one dimension down"): the faces of the fracture cell are its three edges
    (measure ``|e|``, outward in-plane normal, centre the edge midpoint), the cell measure is
    the triangle's area. Multiply by ``C_f / η`` for the fluxes ``F_{σ,e}`` (m³/s when
    ``C_f`` is in m³).

    Args:
        edges: End points of the three edges of each face, ``(n, 3, 2, 3)`` (m).
        tangents: An orthonormal in-plane frame of each face, ``(n, 2, 3)``.
        beta: Stabilization (``√2``, the ``√d`` rule in the fracture's dimension).
    """
    local = np.einsum("nepi,nki->nepk", edges, tangents)
    mid = local.mean(axis=2)
    vec = local[:, :, 1] - local[:, :, 0]
    length = np.linalg.norm(vec, axis=2)
    normal = np.stack([vec[..., 1], -vec[..., 0]], -1) / length[..., None]
    offset = mid - mid.mean(axis=1, keepdims=True)
    normal *= np.sign(np.einsum("nei,nei->ne", offset, normal))[..., None]
    area = 0.5 * np.abs(vec[:, 0, 0] * vec[:, 1, 1] - vec[:, 0, 1] * vec[:, 1, 0])
    unit = isotropic_tensor(np.ones(len(edges)), 2)
    return cell_matrices(length, normal, offset, area, unit, beta)


def series_matrices(A: Array, resistance: Array) -> Array:
    """``(A⁻¹ + diag(R))⁻¹``: face matrices in series with a resistance at each node.

    The flux ``F = A (p_f - q)`` through the face reaches the node pressure ``p_e`` across
    the resistance, ``q - p_e = R F``; eliminating the branch values ``q`` gives
    ``F = (I + A R)⁻¹ A (p_f - p_e)``. Rows without a resistance are unchanged; an infinite
    resistance is capped at ``1e30`` times the face's largest coefficient (its flux is then
    zero to that ratio). Symmetric positive definite like ``A``.

    Args:
        A: Face matrices ``(n, k, k)``.
        resistance: ``R ≥ 0`` per face and node ``(n, k)``, possibly infinite.
    """
    out = A.copy()
    rows = np.flatnonzero((resistance > 0).any(axis=1))
    if len(rows) == 0:
        return out
    a, r = A[rows], resistance[rows]
    scale = np.abs(a).max(axis=(1, 2))[:, None]
    r = np.minimum(r, 1e30 / scale)
    k = A.shape[1]
    S = np.linalg.solve(np.eye(k)[None] + a * r[:, None, :], a)
    out[rows] = 0.5 * (S + S.transpose(0, 2, 1))
    return out
