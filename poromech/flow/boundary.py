"""Flow boundary conditions and the unknowns they act on (local data).

The domain boundary is made of *parts*: the edges of the domain polygon in 2D, the six faces
of the box in 3D. Matrix faces on a part with a ``pressure`` condition are Dirichlet unknowns
(value at the face midpoint); on a ``flux`` part the face equation receives ``|σ| q_N``. A
condition may be restricted to the faces whose midpoint satisfies a ``where`` predicate.
Fracture-network nodes lying on the domain boundary (fractures reaching ∂Ω: a vertex in 2D,
an edge in 3D) follow the rule of :class:`FlowBoundary`: by default they *inherit* the
condition of the part, a pressure part fixing ``p_e = g(x_e)`` and a flux part letting
``d_f |e| q_N(x_e)`` leave through each fracture face ending there (the fracture cross-section
times the imposed flux; ``|e| = 1`` in 2D); ``no_flow`` makes them impervious. When a node lies
on two parts (a corner), a pressure condition wins. Immersed tips get no condition: their node
equation states zero flux.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from poromech.flow.dofs import FlowDofs
from poromech.geometry.box import BoxGeometry
from poromech.geometry.plane import PlaneGeometry
from poromech.mesh.entities import CellGeometry

__all__ = ["BoundaryDofs", "FlowBoundary", "boundary_dofs", "parts_at"]

Array = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True)
class FlowBoundary:
    """A flow condition on boundary parts (unlisted parts are impervious).

    Attributes:
        name: Boundary name (reported fluxes are grouped by it).
        edges: Boundary parts it covers (domain polygon edges in 2D, box faces in 3D).
        kind: ``pressure`` (Pa) or ``flux`` (outward volumetric flux per area, m/s).
        value: The imposed value ``f(x, t)`` at points ``x`` ``(n, d)``.
        fracture_ends: ``inherit`` (fracture nodes on these edges get the same condition) or
            ``no_flow`` (fracture ends there are impervious).
        where: Optional predicate ``f(x, t)``: the condition acts only on the faces and nodes
            of its parts where ``f(x, 0)`` is nonzero; the rest stays impervious unless
            another condition covers it.
    """

    name: str
    edges: tuple[int, ...]
    kind: Literal["pressure", "flux"]
    value: Callable[..., Array]
    fracture_ends: Literal["inherit", "no_flow"] = "inherit"
    where: Callable[..., Array] | None = None


@dataclass(frozen=True)
class BoundaryDofs:
    """Where each boundary condition acts, on this rank.

    Attributes:
        mask: Dirichlet mask over the local dofs.
        dirichlet: Local Dirichlet dofs (each once) and their condition index.
        flux_faces: ``(local dof, condition, |σ|)`` of the flux faces of owned cells.
        flux_nodes: ``(local dof, condition, owned fracture face, |e|)`` of the fracture ends
            on flux parts, one entry per fracture face ending there (``|e|`` the edge length in
            3D, 1 in 2D).
        face_edge: Boundary part of each face of the owned cells, ``(nc, d + 1)``, ``-1``
            inside.
        node_edge: Boundary part (with a condition if any) of each node of the owned fracture
            faces, ``(nf, d)``, ``-1`` inside.
    """

    mask: npt.NDArray[np.bool_]
    dirichlet: tuple[IntArray, IntArray]
    flux_faces: tuple[IntArray, IntArray, Array]
    flux_nodes: tuple[IntArray, IntArray, IntArray, Array]
    face_edge: IntArray
    node_edge: IntArray


def parts_at(geometry: PlaneGeometry | BoxGeometry, points: Array, tol: float
             ) -> npt.NDArray[np.bool_]:
    """``(n, num_parts)`` mask of the boundary parts each point lies on (within ``tol``).

    Polygon edges in 2D, box faces (in :attr:`BoxGeometry.boundary_names` order) in 3D.
    """
    return geometry.on_boundary(points, tol)


def _face_conditions(bcs: Sequence[FlowBoundary], face_part: IntArray, x: Array) -> IntArray:
    """Condition of each boundary face (the last listed condition covering it), ``-1`` if none."""
    out = np.full(face_part.shape, -1, dtype=np.int64)
    on = face_part >= 0
    for i, bc in enumerate(bcs):
        sel = on & np.isin(face_part, bc.edges)
        if bc.where is not None and sel.any():
            sel[sel] = np.asarray(bc.where(x[sel], 0.0)) != 0
        out[sel] = i
    return out


def _node_conditions(on_edge, bcs, x):
    """Condition of each boundary node (pressure first) and the part it is attributed to.

    On each part a node takes the last listed condition covering it there (as faces do).
    """
    n, parts = on_edge.shape
    cover = np.column_stack([_face_conditions(bcs, np.where(on_edge[:, e], e, -1), x)
                             for e in range(parts)]) if n else np.full((0, parts), -1)
    cond = np.full(n, -1, dtype=np.int64)
    edge = np.full(n, -1, dtype=np.int64)
    for priority in ("flux", "pressure"):  # later assignments win
        ok = np.array([bc.kind == priority and bc.fracture_ends == "inherit" for bc in bcs]
                      + [False])
        for e in range(parts):
            i = cover[:, e]
            sel = ok[i]
            cond[sel] = i[sel]
            edge[sel] = e
    unconditioned = (edge < 0) & on_edge.any(axis=1)
    edge[unconditioned] = np.argmax(on_edge[unconditioned], axis=1)
    return cond, edge


def boundary_dofs(
    dofs: FlowDofs, geom: CellGeometry, geometry: PlaneGeometry | BoxGeometry,
    bcs: Sequence[FlowBoundary], node_length: Array | None = None,
) -> BoundaryDofs:
    """Classify the boundary unknowns of this rank (local).

    Args:
        dofs: The numbering.
        geom: The cell geometry.
        geometry: The domain (polygon edges or box faces are the boundary parts).
        bcs: The conditions.
        node_length: ``|e|`` of each node of the owned fracture faces ``(nf, d)`` (3D; None
            in 2D: 1).
    """
    face_edge = dofs.facet_edge[geom.facets]
    face_bc = _face_conditions(bcs, face_edge, geom.facet_midpoint[geom.facets])
    kinds = np.array([bc.kind == "pressure" for bc in bcs] + [False])
    is_dir = kinds[face_bc] & (face_bc >= 0)
    is_flux = (face_bc >= 0) & ~is_dir
    ends = dofs.node.ravel()
    x = dofs.points[ends]
    on_edge = parts_at(geometry, x, 1e-8 * geometry.diameter)
    node_bc, node_edge = _node_conditions(on_edge, bcs, x)
    node_dir = (node_bc >= 0) & kinds[node_bc]
    node_flux = (node_bc >= 0) & ~node_dir
    dir_dofs = np.concatenate([dofs.cell_faces[is_dir], ends[node_dir]])
    dir_bc = np.concatenate([face_bc[is_dir], node_bc[node_dir]])
    dir_dofs, first = np.unique(dir_dofs, return_index=True)
    mask = np.zeros(dofs.num_local, dtype=bool)
    mask[dir_dofs] = True
    nv = dofs.node.shape[1] if dofs.node.ndim == 2 else 2
    face_index = np.repeat(np.arange(len(dofs.fracture)), nv)
    length = np.ones(len(ends)) if node_length is None else np.asarray(node_length).ravel()
    return BoundaryDofs(
        mask,
        (dir_dofs, dir_bc[first]),
        (dofs.cell_faces[is_flux], face_bc[is_flux], geom.area[is_flux]),
        (ends[node_flux], node_bc[node_flux], face_index[node_flux], length[node_flux]),
        face_edge,
        node_edge.reshape(-1, nv),
    )
