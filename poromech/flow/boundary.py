"""Flow boundary conditions and the unknowns they act on (local data).

Matrix faces on a domain edge with a ``pressure`` condition are Dirichlet unknowns (value at
the face midpoint); on a ``flux`` edge the face equation receives ``|σ| q_N``. Fracture-network
nodes lying on the domain boundary (fractures reaching ∂Ω) follow the rule of
:class:`FlowBoundary`: by default they *inherit* the condition of the edge, a pressure edge
fixing ``p_e = g(x_e)`` and a flux edge letting ``d_f q_N(x_e)`` leave through each fracture
face ending there (the fracture cross-section times the imposed flux); ``no_flow`` makes them
impervious. When a node lies on two edges (a corner), a pressure condition wins. Immersed tips
get no condition: their node equation states zero flux.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from poromech.flow.dofs import FlowDofs
from poromech.mesh.entities import CellGeometry

__all__ = ["BoundaryDofs", "FlowBoundary", "boundary_dofs", "edges_at"]

Array = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True)
class FlowBoundary:
    """A flow condition on domain polygon edges (unlisted edges are impervious).

    Attributes:
        name: Boundary name (reported fluxes are grouped by it).
        edges: Domain polygon edges it covers.
        kind: ``pressure`` (Pa) or ``flux`` (outward volumetric flux per area, m/s).
        value: The imposed value ``f(x, t)`` at points ``x`` ``(n, d)``.
        fracture_ends: ``inherit`` (fracture nodes on these edges get the same condition) or
            ``no_flow`` (fracture ends there are impervious).
    """

    name: str
    edges: tuple[int, ...]
    kind: Literal["pressure", "flux"]
    value: Callable[..., Array]
    fracture_ends: Literal["inherit", "no_flow"] = "inherit"


@dataclass(frozen=True)
class BoundaryDofs:
    """Where each boundary condition acts, on this rank.

    Attributes:
        mask: Dirichlet mask over the local dofs.
        dirichlet: Local Dirichlet dofs (each once) and their condition index.
        flux_faces: ``(local dof, condition, |σ|)`` of the flux faces of owned cells.
        flux_nodes: ``(local dof, condition, owned fracture face)`` of the fracture ends on flux
            edges, one entry per fracture face ending there.
        face_edge: Domain edge of each face of the owned cells, ``(nc, 3)``, ``-1`` inside.
        node_edge: Domain edge (with a condition if any) of each end of the owned fracture
            faces, ``(nf, 2)``, ``-1`` inside.
    """

    mask: npt.NDArray[np.bool_]
    dirichlet: tuple[IntArray, IntArray]
    flux_faces: tuple[IntArray, IntArray, Array]
    flux_nodes: tuple[IntArray, IntArray, IntArray]
    face_edge: IntArray
    node_edge: IntArray


def edges_at(points: Array, polygon: Array, tol: float) -> npt.NDArray[np.bool_]:
    """``(n, num_edges)`` mask of the domain polygon edges each point lies on (within ``tol``)."""
    a, b = polygon, np.roll(polygon, -1, axis=0)
    ab = b - a
    rel = points[:, None, :] - a[None]
    s = np.clip(np.einsum("nei,ei->ne", rel, ab) / np.einsum("ei,ei->e", ab, ab), 0.0, 1.0)
    return np.linalg.norm(rel - s[..., None] * ab[None], axis=2) <= tol


def _edge_conditions(bcs: Sequence[FlowBoundary], num_edges: int) -> IntArray:
    """Condition index of every domain edge, ``-1`` for impervious edges."""
    out = np.full(num_edges, -1, dtype=np.int64)
    for i, bc in enumerate(bcs):
        out[list(bc.edges)] = i
    return out


def _node_conditions(on_edge, edge_bc, bcs):
    """Condition of each boundary node (pressure first) and the edge it is attributed to."""
    n = len(on_edge)
    cond = np.full(n, -1, dtype=np.int64)
    edge = np.full(n, -1, dtype=np.int64)
    for priority in ("flux", "pressure"):  # later assignments win
        for e in range(on_edge.shape[1]):
            i = edge_bc[e]
            if i < 0 or bcs[i].kind != priority or bcs[i].fracture_ends != "inherit":
                continue
            cond[on_edge[:, e]] = i
            edge[on_edge[:, e]] = e
    unconditioned = (edge < 0) & on_edge.any(axis=1)
    edge[unconditioned] = np.argmax(on_edge[unconditioned], axis=1)
    return cond, edge


def boundary_dofs(
    dofs: FlowDofs, geom: CellGeometry, polygon: Array, bcs: Sequence[FlowBoundary]
) -> BoundaryDofs:
    """Classify the boundary unknowns of this rank (local).

    Args:
        dofs: The numbering.
        geom: The cell geometry.
        polygon: Domain polygon vertices (m).
        bcs: The conditions.
    """
    edge_bc = _edge_conditions(bcs, len(polygon))
    kinds = np.array([bc.kind == "pressure" for bc in bcs] + [False])
    face_edge = dofs.facet_edge[geom.facets]
    face_bc = np.where(face_edge >= 0, edge_bc[face_edge], -1)
    is_dir = kinds[face_bc] & (face_bc >= 0)
    is_flux = (face_bc >= 0) & ~is_dir
    tol = 1e-8 * float(np.linalg.norm(polygon.max(axis=0) - polygon.min(axis=0)))
    ends = dofs.node.ravel()
    on_edge = edges_at(dofs.points[ends], polygon, tol)
    node_bc, node_edge = _node_conditions(on_edge, edge_bc, bcs)
    node_dir = (node_bc >= 0) & kinds[node_bc]
    node_flux = (node_bc >= 0) & ~node_dir
    dir_dofs = np.concatenate([dofs.cell_faces[is_dir], ends[node_dir]])
    dir_bc = np.concatenate([face_bc[is_dir], node_bc[node_dir]])
    dir_dofs, first = np.unique(dir_dofs, return_index=True)
    mask = np.zeros(dofs.num_local, dtype=bool)
    mask[dir_dofs] = True
    face_index = np.repeat(np.arange(len(dofs.fracture)), 2)
    return BoundaryDofs(
        mask,
        (dir_dofs, dir_bc[first]),
        (dofs.cell_faces[is_flux], face_bc[is_flux], geom.area[is_flux]),
        (ends[node_flux], node_bc[node_flux], face_index[node_flux]),
        face_edge,
        node_edge.reshape(-1, 2),
    )
