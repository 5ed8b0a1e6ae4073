"""Expressions checked at sample points before meshing: finite and within their field's range.

A field is sampled on a grid of the domain, boundary data along their edges and fracture data
along the fractures, at the step times (thinned to :data:`MAX_CHECK_TIMES`). After meshing,
:mod:`poromech.scene.fields` checks them again where the solvers evaluate them.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from poromech.errors import ConfigError
from poromech.geometry.box import BoxGeometry
from poromech.geometry.plane import PlaneGeometry
from poromech.scene.builder import RANGE_RULES, format_value
from poromech.scene.expressions import Expression, ExpressionError
from poromech.scene.schema import Scene, step_times

__all__ = [
    "check_expression",
    "check_field",
    "check_permeability",
    "check_times",
    "check_values",
    "edge_points",
    "fracture_points",
    "grid_points",
]


#: Before meshing, fields are checked on this many grid points per axis inside the domain, and
#: boundary and fracture data at this many points per domain edge and fracture segment.
FIELD_GRID = 201


LINE_SAMPLES = 1001


#: Most time points at which a time-dependent expression is checked before meshing (evenly
#: chosen among the step times); after meshing every step time is checked.
MAX_CHECK_TIMES = 200


def inside(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Mask of the points strictly inside a polygon (crossing number; vectorized)."""
    x, y = points[:, 0], points[:, 1]
    inside = np.zeros(len(points), dtype=bool)
    for a, b in zip(polygon, np.roll(polygon, -1, axis=0), strict=True):
        crosses = (a[1] > y) != (b[1] > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = a[0] + (y - a[1]) * (b[0] - a[0]) / (b[1] - a[1])
        inside ^= crosses & (x < xc)
    return inside


#: Grid points per axis in a box (3D), and per side of a box face or fracture.
BOX_GRID = 41
SURFACE_GRID = 101


def grid_points(geo: PlaneGeometry | BoxGeometry, n: int = FIELD_GRID) -> np.ndarray:
    """Cell-centred grid points of the bounding box that lie inside the domain, ``(m, d)``."""
    if isinstance(geo, BoxGeometry):
        s = (np.arange(BOX_GRID) + 0.5) / BOX_GRID
        axes = [lo + s * (hi - lo) for lo, hi in zip(geo.lower, geo.upper, strict=True)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    lo, hi = geo.boundary.min(axis=0), geo.boundary.max(axis=0)
    s = (np.arange(n) + 0.5) / n
    gx, gy = np.meshgrid(lo[0] + s * (hi[0] - lo[0]), lo[1] + s * (hi[1] - lo[1]))
    points = np.column_stack([gx.ravel(), gy.ravel()])
    return points[inside(points, geo.boundary)]


def edge_points(geo: PlaneGeometry | BoxGeometry, name: str, n: int = LINE_SAMPLES
                ) -> np.ndarray:
    """Points along the domain edges (box faces) called ``name``, their ends (edges) included."""
    if isinstance(geo, BoxGeometry):
        axis, value = geo.face_plane(geo.boundary_names.index(name))
        others = [a for a in range(3) if a != axis]
        s = np.linspace(0.0, 1.0, SURFACE_GRID)
        u, v = np.meshgrid(*[geo.lower[a] + s * (geo.upper[a] - geo.lower[a]) for a in others])
        pts = np.empty((u.size, 3))
        pts[:, axis], pts[:, others[0]], pts[:, others[1]] = value, u.ravel(), v.ravel()
        return pts
    poly = geo.boundary
    s = np.linspace(0.0, 1.0, n)[:, None]
    return np.concatenate([poly[e] + s * (poly[(e + 1) % len(poly)] - poly[e])
                           for e, edge in enumerate(geo.boundary_names) if edge == name])


def fracture_points(geo: PlaneGeometry | BoxGeometry, which=None, n: int = LINE_SAMPLES
                    ) -> np.ndarray:
    """Points of fractures ``which`` (default all) where face midpoints can lie.

    2D: segment end points are excluded (no face has its midpoint there). 3D: a grid of each
    fracture's plane inside the fracture, and points just inside its edge (no triangle has its
    barycentre on the edge).
    """
    if isinstance(geo, BoxGeometry):
        parts = [_surface_points(f) for k, f in enumerate(geo.fractures)
                 if which is None or k in which]
        return np.concatenate(parts) if parts else np.empty((0, 3))
    s = ((np.arange(n) + 0.5) / n)[:, None]
    parts = [p[i] + s * (p[i + 1] - p[i]) for k, p in enumerate(geo.fractures)
             if which is None or k in which for i in range(len(p) - 1)]
    return np.concatenate(parts) if parts else np.empty((0, 2))


def _surface_points(fracture) -> np.ndarray:
    """Grid points of a planar fracture (inside it) and points just inside its edge, ``(m, 3)``.

    The edge points are pulled towards the fracture's origin by half a grid spacing (relative),
    as the 2D samples stop half a spacing short of the segment ends: a field that vanishes on
    the edge (an aperture law of the distance to the tips) is positive on every face.
    """
    t1, t2 = fracture.tangents
    uv = fracture.to_plane(fracture.outline())
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    s = (np.arange(SURFACE_GRID) + 0.5) / SURFACE_GRID
    u, v = np.meshgrid(lo[0] + s * (hi[0] - lo[0]), lo[1] + s * (hi[1] - lo[1]))
    pts = fracture.origin + u.reshape(-1, 1) * t1 + v.reshape(-1, 1) * t2
    pts = pts[fracture.contains(pts, 0.0)]
    edge = fracture.boundary_points(4 * SURFACE_GRID)
    edge = fracture.origin + (1.0 - 0.5 / SURFACE_GRID) * (edge - fracture.origin)
    return np.concatenate([pts, edge[fracture.projects_inside(edge)]])


def check_times(scene: Scene) -> list[float]:
    """Times at which expressions are checked before meshing: the step times (thinned)."""
    times = step_times(scene)
    if len(times) > MAX_CHECK_TIMES:
        keep = np.unique(np.linspace(0, len(times) - 1, MAX_CHECK_TIMES).round().astype(int))
        times = [times[i] for i in keep]
    return times


def check_values(values: np.ndarray, points: np.ndarray, path: str, expr: Expression,
                 meta: Mapping | None = None, t: float | None = None, what: str = "") -> None:
    """Refuse the first point where an expression's values are not finite or out of range.

    Args:
        values: The values at ``points``.
        points: ``(n, 2)`` evaluation points (m).
        path: Scene key of the expression.
        expr: The expression (for its text).
        meta: Field metadata with the checks (``gt``, ``min``, ...).
        t: The time of the values, when it matters (s).
        what: What the points are (e.g. "a cell centre"), for the message.

    Raises:
        ConfigError: One line with the key, the expression, the value and the point.
    """
    values = np.broadcast_to(np.asarray(values, dtype=np.float64), (len(points),))
    bad, rule = ~np.isfinite(values), None
    for name, (ok, text) in RANGE_RULES.items():
        if bad.any():
            break
        if meta and name in meta:
            bad, rule = ~ok(values, meta[name]), text.format(meta[name])
    if not bad.any():
        return
    i = int(np.flatnonzero(bad)[0])
    at = ", ".join(f"{c}={points[i, k]:g}" for k, c in enumerate("xyz"[:points.shape[1]]))
    at += "" if t is None else f", t={t:g}"
    at += f" ({what})" if what else ""
    head = f"scene key '{path}' = {format_value(expr.source)} is {float(values[i]):g} at {at}"
    if rule is None:
        raise ConfigError(f"{head}: must be finite")
    raise ConfigError(f"{head}, not allowed: must be {rule}")


def check_expression(expr: Expression | None, points: np.ndarray, path: str,
                     meta: Mapping | None, times, what: str = "") -> None:
    """Check an expression at points and times (one point if uniform, one time if static).

    Raises:
        ConfigError: See :func:`check_values`.
    """
    if expr is None or not len(points):
        return
    pts = points[:1] if expr.is_uniform else points
    for t in (times if expr.depends_on_time else times[:1]):
        try:
            values = expr(pts, t)
        except ExpressionError as err:
            raise ConfigError(f"scene key '{path}' = {format_value(expr.source)}: {err}") \
                from None
        check_values(values, pts, path, expr, meta, t if expr.depends_on_time else None, what)


def check_field(expr: Expression | None, path: str, meta: Mapping, geo, times) -> None:
    """Check a space/time-dependent field on a grid of points inside the domain."""
    check_expression(expr, grid_points(geo), path, meta, times)


def check_permeability(perm, points: np.ndarray, times, what: str = "") -> None:
    """Refuse the first point where the permeability tensor is not finite and SPD."""
    x, y = points[:, 0], points[:, 1]
    steps = times if any(e.depends_on_time for e in perm) else times[:1]
    three = points.shape[1] == 3
    for t in steps:
        k = [np.broadcast_to(e(points, t), x.shape) for e in perm]
        if three:
            bad = ~_positive_definite_3d(k)
        else:
            kxx, kyy = k[0], k[-1]
            det = kxx * kyy - (k[1] ** 2 if len(k) == 3 else 0.0)
            bad = ~(np.isfinite(det) & (kxx > 0) & (kyy > 0) & (det > 0))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            value = [float(c[i]) for c in k]
            where = f" ({what})" if what else ""
            uniform = all(e.is_uniform for e in perm)
            at = "" if uniform else f" at x={x[i]:g}, y={y[i]:g}"
            if three:
                at += "" if uniform else f", z={points[i, 2]:g}"
                entries = {1: "[k]", 3: "[k_xx, k_yy, k_zz]",
                           6: "[k_xx, k_xy, k_xz, k_yy, k_yz, k_zz]"}.get(len(perm), "a tensor")
                raise ConfigError(
                    f"scene key 'flow.permeability' = {value}{at}{where} is not allowed: read as "
                    f"{entries} in 3D, it must be a finite, positive definite tensor")
            raise ConfigError(
                f"scene key 'flow.permeability' = {value}{at}{where} is "
                "not allowed: must be positive definite (k_xx > 0, k_yy > 0, k_xx k_yy > k_xy²)"
            )


def _positive_definite_3d(k: list[np.ndarray]) -> np.ndarray:
    """Finite and positive definite 3D tensors from 1, 3 or 6 components (mask per point)."""
    n = len(k[0])
    if len(k) == 1:
        T = k[0][:, None, None] * np.eye(3)[None]
    elif len(k) == 3:
        T = np.stack(k, -1)[..., None] * np.eye(3)[None]
    else:
        xx, xy, xz, yy, yz, zz = k
        T = np.stack([np.stack([xx, xy, xz], -1), np.stack([xy, yy, yz], -1),
                      np.stack([xz, yz, zz], -1)], -2)
    scale = np.zeros(n)
    finite = np.isfinite(T).all(axis=(1, 2))
    scale[finite] = np.abs(T[finite]).max(axis=(1, 2))
    ok = scale > 0  # finite and not zero (a zero tensor is not positive definite)
    out = np.zeros(n, dtype=bool)
    if ok.any():
        out[ok] = np.linalg.eigvalsh(T[ok] / scale[ok, None, None]).min(axis=1) > 1e-14
    return out
