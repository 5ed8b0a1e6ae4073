"""Plane geometry of a fractured domain: the polygon, the fracture polylines, and their checks.

Pure NumPy, no meshing and no MPI. A fracture is a polyline ``P_0, ..., P_k``; a polyline with a
corner is one fracture. Its orientation is fixed by the order of its points: on segment
``[P_i, P_{i+1}]`` the unit tangent is ``t = (P_{i+1} - P_i) / |P_{i+1} - P_i|`` and the fracture
normal is the left normal ``n⁺ = (-t_y, t_x)``. The ``+`` side of the fracture is the side that
``n⁺`` points *out of* (the right-hand side when walking from ``P_0`` to ``P_k``), as in the paper:
``[[u]] = u⁺ - u⁻``, ``[[u]]_n = [[u]]·n⁺`` (negative when the fracture opens).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = [
    "GeometryError",
    "PlaneGeometry",
    "arc_length_positions",
    "segment_meets_polygon",
    "segment_normals",
]


class GeometryError(ValueError):
    """A domain or fracture network that cannot be meshed."""


@dataclass(frozen=True)
class PlaneGeometry:
    """A polygonal domain cut by fracture polylines.

    Attributes:
        boundary: Polygon vertices, shape ``(n, 2)`` (m), either orientation. Boundary edge ``i``
            joins vertex ``i`` and vertex ``i+1`` (cyclically).
        boundary_names: Name of each boundary edge, ``len == n``.
        fractures: One ``(k_i + 1, 2)`` array of points per fracture (m).
        fracture_names: Name of each fracture.
    """

    boundary: npt.NDArray[np.float64]
    boundary_names: tuple[str, ...]
    fractures: tuple[npt.NDArray[np.float64], ...]
    fracture_names: tuple[str, ...]

    @property
    def diameter(self) -> float:
        """Diameter of the bounding box of the domain (m)."""
        return float(np.linalg.norm(self.boundary.max(axis=0) - self.boundary.min(axis=0)))

    @property
    def dim(self) -> int:
        """The space dimension, 2."""
        return 2

    def on_boundary(self, points, tol: float) -> npt.NDArray[np.bool_]:
        """``(n, num_edges)`` mask of the boundary edges each point lies on (within ``tol``)."""
        points = np.asarray(points, dtype=float)
        a, b = self.boundary, np.roll(self.boundary, -1, axis=0)
        ab = b - a
        rel = points[:, None, :] - a[None]
        s = np.clip(np.einsum("nei,ei->ne", rel, ab) / np.einsum("ei,ei->e", ab, ab), 0.0, 1.0)
        return np.linalg.norm(rel - s[..., None] * ab[None], axis=2) <= tol

    def fracture_lengths(self) -> npt.NDArray[np.float64]:
        """Length of every fracture (m)."""
        return np.array([np.linalg.norm(np.diff(p, axis=0), axis=1).sum() for p in self.fractures])

    def face_normals(self, fracture: npt.NDArray[np.int32],
                     segment: npt.NDArray[np.int32]) -> npt.NDArray[np.float64]:
        """``n⁺`` of fracture faces given by their fracture and polyline segment, ``(n, 2)``."""
        normals = np.empty((len(fracture), 2))
        for k, pts in enumerate(self.fractures):
            sel = fracture == k
            normals[sel] = segment_normals(pts)[segment[sel]]
        return normals

    def face_tangents(self, normals: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """The tangent frame of faces with normals ``n⁺``: ``τ = (n_y, -n_x)``, ``(n, 1, 2)``.

        ``τ`` runs along the polyline, from its first point to its last.
        """
        return np.column_stack([normals[:, 1], -normals[:, 0]])[:, None, :]

    def face_frames(self, fracture: npt.NDArray[np.int32], segment: npt.NDArray[np.int32]
                    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """``n⁺`` ``(n, 2)`` and the tangent frame ``(n, 1, 2)`` of faces (fracture, segment)."""
        normals = self.face_normals(fracture, segment)
        return normals, self.face_tangents(normals)


def segment_normals(points: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Unit normals ``n⁺`` (left normals) of the segments of a polyline, shape ``(k, 2)``."""
    t = np.diff(points, axis=0)
    t /= np.linalg.norm(t, axis=1)[:, None]
    return np.column_stack([-t[:, 1], t[:, 0]])


def arc_length_positions(
    points: npt.NDArray[np.float64], segment: npt.NDArray[np.int32], x: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """Arc length from the first point of a polyline to points ``x`` lying on ``segment``."""
    lengths = np.linalg.norm(np.diff(points, axis=0), axis=1)
    start = np.concatenate([[0.0], np.cumsum(lengths)])
    t = np.diff(points, axis=0) / lengths[:, None]
    return start[segment] + np.einsum("ij,ij->i", x - points[segment], t[segment])


def _point(p) -> str:
    """A point for a message: ``(0.5, 1.5)``, plain numbers."""
    return f"({float(p[0]):g}, {float(p[1]):g})"


def _orient(a, b, c) -> float:
    """Twice the signed area of triangle ``abc``."""
    return float((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))


def _on_segment(p, a, b, tol: float) -> bool:
    """True when ``p`` lies on segment ``[a, b]`` within distance ``tol``."""
    ab = b - a
    s = np.clip(np.dot(p - a, ab) / np.dot(ab, ab), 0.0, 1.0)
    return bool(np.linalg.norm(a + s * ab - p) <= tol)


def _segments_relation(a, b, c, d, tol: float) -> str:
    """Classify two segments: 'disjoint', 'touch' (share isolated points), 'cross', 'overlap'."""
    scale = max(np.linalg.norm(b - a), np.linalg.norm(d - c))
    o1, o2 = _orient(a, b, c), _orient(a, b, d)
    o3, o4 = _orient(c, d, a), _orient(c, d, b)
    area_tol = tol * scale
    collinear = abs(o1) <= area_tol and abs(o2) <= area_tol
    if collinear:
        t = (b - a) / np.linalg.norm(b - a)
        s = sorted([np.dot(c - a, t), np.dot(d - a, t)])
        lo, hi = max(0.0, s[0]), min(np.linalg.norm(b - a), s[1])
        if hi - lo > tol:
            return "overlap"
        return "touch" if hi - lo > -tol else "disjoint"
    if (o1 > area_tol and o2 < -area_tol or o1 < -area_tol and o2 > area_tol) and (
        o3 > area_tol and o4 < -area_tol or o3 < -area_tol and o4 > area_tol
    ):
        return "cross"
    if any(_on_segment(p, q, r, tol) for p, q, r in ((c, a, b), (d, a, b), (a, c, d), (b, c, d))):
        return "touch"
    return "disjoint"


def _point_in_polygon(p, poly, tol: float) -> bool:
    """True when ``p`` is inside the polygon or on its boundary (within ``tol``)."""
    n = len(poly)
    for i in range(n):
        if _on_segment(p, poly[i], poly[(i + 1) % n], tol):
            return True
    inside = False
    for i in range(n):
        a, b = poly[i], poly[(i + 1) % n]
        if (a[1] > p[1]) != (b[1] > p[1]):
            xc = a[0] + (p[1] - a[1]) * (b[0] - a[0]) / (b[1] - a[1])
            if p[0] < xc:
                inside = not inside
    return inside


def _in_polygon(points, poly, tol: float) -> npt.NDArray[np.bool_]:
    """:func:`_point_in_polygon` of many points at once."""
    a, b = poly, np.roll(poly, -1, axis=0)
    ab = b - a
    rel = points[:, None, :] - a[None]
    s = np.clip(np.einsum("pei,ei->pe", rel, ab) / np.einsum("ei,ei->e", ab, ab), 0.0, 1.0)
    on = np.any(np.linalg.norm(rel - s[..., None] * ab[None], axis=2) <= tol, axis=1)
    y = points[:, 1:2]
    crosses = (a[None, :, 1] > y) != (b[None, :, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xc = a[None, :, 0] + (y - a[None, :, 1]) * (ab[None, :, 0] / ab[None, :, 1])
    inside = np.count_nonzero(crosses & (points[:, 0:1] < xc), axis=1) % 2 == 1
    return on | inside


def _near(s1, s2, tol: float) -> npt.NDArray[np.bool_]:
    """``(len(s1), len(s2))`` mask of segment pairs whose bounding boxes meet (within ``tol``).

    Segments are ``(k, 2, 2)`` arrays of end points; only such pairs can touch or cross.
    """
    lo1, hi1 = s1.min(axis=1) - tol, s1.max(axis=1) + tol
    lo2, hi2 = s2.min(axis=1), s2.max(axis=1)
    return np.all((lo1[:, None] <= hi2[None]) & (hi1[:, None] >= lo2[None]), axis=2)


def segment_meets_polygon(a, b, polygon: npt.NDArray[np.float64]) -> bool:
    """True when segment ``[a, b]`` has a point inside the polygon or on its boundary."""
    tol = 1e-9 * float(np.linalg.norm(polygon.max(axis=0) - polygon.min(axis=0)))
    if _point_in_polygon(a, polygon, tol) or _point_in_polygon(b, polygon, tol):
        return True
    n = len(polygon)
    return any(_segments_relation(a, b, polygon[i], polygon[(i + 1) % n], tol) != "disjoint"
               for i in range(n))


#: Shortest fracture segment, relative to the domain's diameter. gmsh's geometric tolerance is
#: 1e-8 of the model: a segment of 1e-7 of a 1 m domain failed in gmsh alone ("Could not create
#: line") and at a T junction gave a mesh whose fracture facets lacked a side (exit 1, and a hang
#: on 2 ranks before that check was collective); 1e-6 meshes.
MIN_SEGMENT = 1e-6


def check_geometry(geo: PlaneGeometry) -> None:
    """Reject geometries that cannot be meshed or are physically meaningless.

    Checks: polygon with >= 3 vertices, no zero-length or crossing edges; every fracture with
    >= 2 points, no segment shorter than :data:`MIN_SEGMENT` of the domain, no self-crossing
    or folding back, inside the domain, not crossing the boundary and not running along it; no
    two fractures overlapping.
    Crossings of different fractures (X or T junctions) and fractures ending on the boundary
    are allowed.

    Raises:
        GeometryError: With a one-line message naming the offending item.
    """
    poly = geo.boundary
    tol = 1e-9 * geo.diameter
    n = len(poly)
    if n < 3:
        raise GeometryError(f"domain polygon has {n} vertices (at least 3 needed)")
    edges = [(poly[i], poly[(i + 1) % n]) for i in range(n)]
    for i, (a, b) in enumerate(edges):
        if np.linalg.norm(b - a) <= tol:
            raise GeometryError(f"domain edge {i} has zero length at {_point(a)}")
    near_edges = _near(np.array(edges), np.array(edges), tol)
    for i, j in np.argwhere(np.triu(near_edges, 2)):
        if i == 0 and j == n - 1:
            continue
        if _segments_relation(*edges[i], *edges[j], tol) != "disjoint":
            raise GeometryError(f"domain polygon crosses itself (edges {i} and {j})")
    all_segments = []
    for pts, name in zip(geo.fractures, geo.fracture_names, strict=True):
        label = f"fracture '{name}'"
        if len(pts) < 2:
            raise GeometryError(f"{label} has {len(pts)} point(s) (at least 2 needed)")
        if len(pts) > 2 and np.linalg.norm(pts[-1] - pts[0]) <= tol:
            raise GeometryError(f"{label} is a closed loop: its last point is its first, "
                                f"{_point(pts[0])} (allowed: an open polyline; a closed one "
                                "would cut a piece out of the domain)")
        segs = [(pts[i], pts[i + 1]) for i in range(len(pts) - 1)]
        for i, (a, b) in enumerate(segs):
            length = np.linalg.norm(b - a)
            if length <= tol:
                raise GeometryError(f"{label} has a zero-length segment {i} at {_point(a)}")
            if length < MIN_SEGMENT * geo.diameter:
                raise GeometryError(
                    f"{label} segment {i} at {_point(a)} is {length:.3g} m long, shorter than "
                    f"the mesh generator resolves ({MIN_SEGMENT:g} of the domain size, "
                    f"{MIN_SEGMENT * geo.diameter:.3g} m)")
        for i, j in np.argwhere(np.triu(_near(np.array(segs), np.array(segs), tol), 1)):
            rel = _segments_relation(*segs[i], *segs[j], tol)
            if j == i + 1 and rel == "touch":
                continue
            if rel != "disjoint":
                raise GeometryError(f"{label} crosses or folds onto itself (segments {i}, {j})")
        outside = ~_in_polygon(pts, poly, tol)
        if outside.any():
            p = pts[np.argmax(outside)]
            raise GeometryError(f"{label} has point {_point(p)} outside the domain")
        near = _near(np.array(segs), np.array(edges), tol)
        mid_inside = _in_polygon(0.5 * (pts[:-1] + pts[1:]), poly, tol)
        for i, (a, b) in enumerate(segs):
            for e in np.flatnonzero(near[i]):
                rel = _segments_relation(a, b, *edges[e], tol)
                if rel == "cross":
                    raise GeometryError(f"{label} segment {i} crosses domain edge {e}")
                if rel == "overlap":
                    raise GeometryError(f"{label} segment {i} runs along domain edge {e}")
            if not mid_inside[i]:
                raise GeometryError(f"{label} segment {i} leaves the domain")
        all_segments.append((name, segs))
    if not all_segments:
        return
    # only fractures whose bounding boxes meet can overlap (networks of many fractures)
    lo = np.array([p.min(axis=0) for p in geo.fractures]) - tol
    hi = np.array([p.max(axis=0) for p in geo.fractures]) + tol
    for k in range(len(all_segments)):
        near = np.all((lo[k + 1:] <= hi[k]) & (hi[k + 1:] >= lo[k]), axis=1)
        for m in k + 1 + np.flatnonzero(near):
            for a, b in all_segments[k][1]:
                for c, d in all_segments[m][1]:
                    if _segments_relation(a, b, c, d, tol) == "overlap":
                        raise GeometryError(
                            f"fractures '{all_segments[k][0]}' and '{all_segments[m][0]}' overlap"
                        )
