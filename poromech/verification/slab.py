"""A 2D scene as a one-layer 3D slab: the plane-strain check of the 3D discretization.

The 2D scene's ``(x, y)`` plane becomes the 3D ``(x, z)`` plane and the slab is one layer of
cells thick in ``y``: every triangle of the 2D mesh is extruded into a prism, split into three
tetrahedra, and every fracture segment into a rectangle made of two triangles. With ``u_y = 0``
on the front and back faces (every node lies on one of them) the 3D problem is the plane-strain
problem of the 2D scene, so its fracture jumps must reproduce the 2D ones to the 2D
discretization error (``tests/test_mechanics3d.py``).

Prisms are split by the rule of the sorted vertex numbers: with the triangle's nodes
``a < b < c``, the tetrahedra ``(a₀ b₀ c₀ c₁)``, ``(a₀ b₀ b₁ c₁)`` and ``(a₀ a₁ b₁ c₁)``, where
``₀`` and ``₁`` are the front and back copies of a node. Every quadrilateral side is then cut
along the diagonal from its lower-numbered front node to its higher-numbered back node, the same
from both prisms that share it, so the tetrahedra are conforming.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from poromech.geometry.box import BoxGeometry, Fracture3D
from poromech.geometry.plane import PlaneGeometry
from poromech.mesh.generate import MeshArrays

__all__ = ["SLAB_FACES", "slab_arrays", "slab_geometry"]

#: The 3D face of each 2D rectangle edge (the 2D y axis is the 3D z axis).
SLAB_FACES = {"bottom": "bottom", "right": "right", "top": "top", "left": "left"}


def _lift(points: npt.NDArray[np.float64], y: float) -> npt.NDArray[np.float64]:
    """2D points ``(x, y)`` as 3D points ``(x, y3, y)``."""
    return np.column_stack([points[:, 0], np.full(len(points), y), points[:, 1]])


def slab_geometry(geo: PlaneGeometry, thickness: float) -> BoxGeometry:
    """The box and rectangular fractures of a rectangle with straight fractures, extruded.

    A fracture from ``a`` to ``b`` becomes the rectangle ``a₀ b₀ b₁ a₁``, whose right-hand normal
    is the 2D left normal ``n⁺`` in the ``(x, z)`` plane.

    Raises:
        ValueError: The domain is not a rectangle or a fracture has a corner.
    """
    lo, hi = geo.boundary.min(axis=0), geo.boundary.max(axis=0)
    if len(geo.boundary) != 4 or set(geo.boundary_names) != set(SLAB_FACES):
        raise ValueError("a slab extrudes a rectangle (edges bottom, right, top, left)")
    fractures = []
    for pts, name in zip(geo.fractures, geo.fracture_names, strict=True):
        if len(pts) != 2:
            raise ValueError(f"fracture '{name}' has a corner: a slab extrudes straight fractures")
        front, back = _lift(pts, 0.0), _lift(pts, thickness)
        fractures.append(Fracture3D.polygon(name, np.array([front[0], front[1], back[1],
                                                            back[0]])))
    box = (float(lo[0]), 0.0, float(lo[1]), float(hi[0]), float(thickness), float(hi[1]))
    return BoxGeometry(box, tuple(fractures))


def _quads(edges: npt.NDArray[np.int64], n: int) -> npt.NDArray[np.int64]:
    """The two triangles of the extruded side of each edge, cut as the prisms cut it."""
    p, q = edges.min(axis=1), edges.max(axis=1)
    first = np.column_stack([p, q, q + n])
    second = np.column_stack([p, p + n, q + n])
    return np.stack([first, second], axis=1).reshape(-1, 3)


def slab_arrays(arrays: MeshArrays, geo: PlaneGeometry, slab: BoxGeometry) -> MeshArrays:
    """The one-layer tetrahedral mesh of a 2D triangle mesh (input numbering, 3D shapes).

    Node ``i`` of the 2D mesh gives nodes ``i`` (front, ``y = 0``) and ``i + n`` (back).
    Fracture and boundary faces are numbered after the 2D faces they come from (two each); the
    front and back faces of the box are the 2D triangles on either side.
    """
    n = len(arrays.x)
    thickness = slab.upper[1]
    x = np.concatenate([_lift(arrays.x, 0.0), _lift(arrays.x, thickness)])
    a, b, c = np.sort(arrays.cells, axis=1).T
    cells = np.concatenate([np.column_stack([a, b, c, c + n]),
                            np.column_stack([a, b, b + n, c + n]),
                            np.column_stack([a, a + n, b + n, c + n])])
    d = x[cells[:, 1:]] - x[cells[:, :1]]
    negative = np.einsum("ij,ij->i", d[:, 0], np.cross(d[:, 1], d[:, 2])) < 0
    cells[negative] = cells[negative][:, [0, 1, 3, 2]]
    faces = list(slab.boundary_names)
    edge_face = np.array([faces.index(SLAB_FACES[geo.boundary_names[e]])
                          for e in arrays.boundary_edge], dtype=np.int32)
    boundary = np.concatenate([_quads(arrays.boundary_facets, n), arrays.cells,
                               arrays.cells + n])
    boundary_face = np.concatenate([np.repeat(edge_face, 2),
                                    np.full(len(arrays.cells), faces.index("front")),
                                    np.full(len(arrays.cells), faces.index("back"))])
    nf = len(arrays.fracture_facets)
    return MeshArrays(
        x=x, cells=cells.astype(np.int64),
        fracture_facets=_quads(arrays.fracture_facets, n),
        fracture_id=np.repeat(arrays.fracture_id, 2).astype(np.int32),
        fracture_segment=np.zeros(2 * nf, dtype=np.int32),
        fracture_s=np.full(2 * nf, np.nan),
        boundary_facets=boundary.astype(np.int64),
        boundary_edge=boundary_face.astype(np.int32),
    )
