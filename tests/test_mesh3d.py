"""3D fractured boxes: geometry checks, gmsh meshing, cracked topology and cracked spaces."""

import json

import dolfinx_solver  # noqa: F401

import numpy as np
import pytest
import ufl
from conftest import config_error, mechanics_scene, run_parallel
from dolfinx import fem
from mpi4py import MPI
from scipy.spatial import cKDTree

from poromech.geometry.box import (
    BoxGeometry,
    Fracture3D,
    GeometryError,
    check_box_geometry,
    fracture_distance,
    intersection_segments,
)
from poromech.mesh.cracking import (
    bisect_edges,
    crack_vertices,
    deficient_edges,
    edge_star_copies,
    edge_table,
    facet_table,
    rule_dof_count,
    topological_copies,
    unique_rows,
)
from poromech.mesh.fractured import (
    FRACTURE_TAG_OFFSET,
    cracked_space,
    create_fractured_mesh,
    fracture_measure,
)
from poromech.mesh.generate import MeshSizes
from poromech.mesh.generate3d import build_mesh_3d

UNIT = (0.0, 0.0, 0.0, 1.0, 1.0, 1.0)


def plane_owner(arrays, origin, normal):
    """Rank 1 for cells whose centroid is on the ``+normal`` side of a plane, else rank 0.

    With a fracture's plane this puts a process boundary on that fracture.
    """
    c = arrays.x[arrays.cells].mean(axis=1)
    return ((c - np.asarray(origin)) @ np.asarray(normal) >= 0).astype(np.int32)
TOL = 1e-9


def square(name, center, normal_axis, half):
    """Axis-aligned square fracture, counter-clockwise about +e_axis."""
    i, j = [(1, 2), (2, 0), (0, 1)][normal_axis]
    corners = [(-1, -1), (1, -1), (1, 1), (-1, 1)]
    pts = np.tile(np.asarray(center, float), (4, 1))
    for k, (a, b) in enumerate(corners):
        pts[k, i] += a * half
        pts[k, j] += b * half
    return Fracture3D.polygon(name, pts)


def rect(name, axis, value, lo, hi):
    """Rectangle in the plane x[axis] = value spanning [lo, hi] in the two other axes."""
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    pts = np.zeros((4, 3))
    pts[:, axis] = value
    for k, (a, b) in enumerate([(lo[0], lo[1]), (hi[0], lo[1]), (hi[0], hi[1]), (lo[0], hi[1])]):
        pts[k, i], pts[k, j] = a, b
    return Fracture3D.polygon(name, pts)


def rotation(a, b):
    ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
    return np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]]) @ np.array(
        [[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])


def network():
    """X (A, B), T (D's lower edge on A), C reaching the face x = 0."""
    a = rect("A", 2, 0.5, (0.2, 0.2), (0.8, 0.8))  # z = 0.5; (x, y) in [0.2, 0.8]^2
    b = rect("B", 0, 0.5, (0.3, 0.3), (0.7, 0.7))  # x = 0.5; (y, z)
    c = rect("C", 1, 0.1, (0.3, 0.0), (0.7, 0.4))  # y = 0.1; (z, x): x in [0, 0.4]
    d = rect("D", 0, 0.7, (0.3, 0.5), (0.6, 0.8))  # x = 0.7; y in [0.3, 0.6], z in [0.5, 0.8]
    return BoxGeometry(UNIT, (a, b, c, d))


def tilted():
    sq = np.array([[-0.25, -0.25, 0], [0.25, -0.25, 0], [0.25, 0.25, 0], [-0.25, 0.25, 0]])
    return BoxGeometry(UNIT, (Fracture3D.polygon("tilted", sq @ rotation(0.4, 0.4).T + 0.5),))


def acute():
    t = np.tan(np.radians(15))
    pts = [[0.2, 0.4, 0.5], [0.85, 0.4, 0.5], [0.85, 0.4 + 0.65 * t, 0.5]]
    return BoxGeometry(UNIT, (Fracture3D.polygon("acute", pts),))


CASES = {
    "penny": (BoxGeometry((-2.0,) * 3 + (2.0,) * 3,
                          (Fracture3D.disc("penny", [0, 0, 0], [0, 0, 1], 1.0),)),
              MeshSizes(1.0, 0.3, 0.15, 1.0)),
    "tilted": (tilted(), MeshSizes(0.25, 0.1, 0.05, 0.3)),
    "network": (network(), MeshSizes(0.2, 0.1, 0.1, 0.3)),
    "face": (BoxGeometry(UNIT, (rect("face", 1, 0.5, (0.2, 0.0), (0.8, 0.6)),)),
             MeshSizes(0.25, 0.1, 0.05, 0.3)),
    "disc": (BoxGeometry(UNIT, (Fracture3D.disc("disc", [0.5, 0.5, 0.5], [1, 1, 2], 0.3),)),
             MeshSizes(0.25, 0.1, 0.05, 0.3)),
    "acute": (acute(), MeshSizes(0.2, 0.1, 0.1, 0.3)),
    "oblique": (BoxGeometry(UNIT, (
        Fracture3D.polygon("tilted", 0.5 + np.array([[-0.3, -0.3, 0], [0.3, -0.3, 0], [0.3, 0.3, 0],
                                                     [-0.3, 0.3, 0]]) @ rotation(np.pi / 6, 0).T),
        rect("upright", 0, 0.5, (0.35, 0.25), (0.65, 0.75)))),
        MeshSizes(0.2, 0.08, 0.08, 0.3)),
    "through": (BoxGeometry(UNIT, (Fracture3D.polygon(
        "through", [[0, 0, 0.3], [1, 0, 0.3], [1, 1, 0.7], [0, 1, 0.7]]),)),
        MeshSizes(0.25, 0.12, 0.12, 0.3)),
}



def scaled(name, k):
    """Case ``name`` with every length multiplied by ``k``."""
    geo, sizes = CASES[name]

    def fracture(f):
        if f.is_disc:
            return Fracture3D.disc(f.name, f.center * k, f.normal, f.radius * k)
        return Fracture3D.polygon(f.name, f.points * k)

    return (BoxGeometry(tuple(v * k for v in geo.box), tuple(map(fracture, geo.fractures))),
            MeshSizes(sizes.size * k, sizes.fracture_size * k, sizes.tip_size * k,
                      sizes.transition * k))


# a 1.7 mm box: gmsh's geometry kernel enlarges bounding boxes by 1e-7 in the model's units
CASES["network_mm"] = scaled("network", 1e-3)
_MESHES: dict = {}


def mesh_of(name):
    """Mesh arrays and report of a case (generated once per session)."""
    if name not in _MESHES:
        geo, sizes = CASES[name]
        _MESHES[name] = build_mesh_3d(geo, sizes)
    return _MESHES[name]


# ------------------------------------------------------------------------------------------------
# Geometry


def test_fracture_frame_and_measures():
    for normal in ([0, 0, 1], [1, 1, 2], [0, -1, 0], [1e-3, 1, 0], [-3, 2, 1]):
        fr = Fracture3D.disc("d", [0, 0, 0], normal, 0.5)
        n = np.asarray(normal) / np.linalg.norm(normal)
        t1, t2 = fr.tangents
        assert np.allclose(fr.normal, n)
        assert np.allclose([t1 @ t1, t2 @ t2, t1 @ t2, t1 @ n], [1, 1, 0, 0], atol=1e-14)
        assert np.allclose(np.cross(t1, t2), n, atol=1e-14)
        assert abs(t1[int(np.argmin(np.abs(n)))]) == np.abs(t1).max()  # least aligned axis
        rim = fr.boundary_points(64)
        assert len(rim) == 64 and np.allclose(np.linalg.norm(rim, axis=1), 0.5)
        assert np.allclose(rim @ n, 0) and np.allclose(fr.rim_distance(rim), 0, atol=1e-14)
    assert np.isclose(Fracture3D.disc("d", [0, 0, 0], [0, 0, 2], 0.5).area, np.pi / 4)
    # polygon orientation by the right-hand rule; area; contains
    sq = square("s", [0.5, 0.5, 0.5], 2, 0.25)
    assert np.allclose(sq.normal, [0, 0, 1]) and np.isclose(sq.area, 0.25)
    flipped = Fracture3D.polygon("f", sq.points[::-1])
    assert np.allclose(flipped.normal, [0, 0, -1])
    inside = sq.contains([[0.5, 0.5, 0.5], [0.75, 0.5, 0.5], [0.76, 0.5, 0.5], [0.5, 0.5, 0.51]],
                         TOL)
    assert inside.tolist() == [True, True, False, False]
    bp = sq.boundary_points(16)
    assert len(bp) == 16 and np.allclose(sq.rim_distance(bp), 0)
    assert np.isclose(tilted().fractures[0].area, 0.25)


def test_line_intervals_nonconvex_polygon():
    # U shape in z = 0: the line y = 0.8 crosses both arms
    u = Fracture3D.polygon("U", [[0, 0, 0], [3, 0, 0], [3, 1, 0], [2, 1, 0], [2, 0.5, 0],
                                 [1, 0.5, 0], [1, 1, 0], [0, 1, 0]])
    iv = u.line_intervals(np.array([0.0, 0.8, 0.0]), np.array([1.0, 0, 0]), TOL)
    assert np.allclose(iv, [[0, 1], [2, 3]])
    # along an edge (closed set) and touching a vertex only
    assert np.allclose(u.line_intervals(np.array([0.0, 0.0, 0]), np.array([1.0, 0, 0]), TOL),
                       [[0, 3]])
    tip = u.line_intervals(np.array([3.0, 1.0, 0]), np.array([1.0, -1.0, 0]) / np.sqrt(2), TOL)
    assert tip.shape == (1, 2) and np.isclose(tip[0, 0], tip[0, 1])


def test_intersection_segments():
    geo = network()
    a, b, c, d = geo.fractures
    assert np.allclose(np.sort(intersection_segments(a, b, TOL)[0], axis=0),
                       [[0.5, 0.3, 0.5], [0.5, 0.7, 0.5]])  # X
    assert np.allclose(np.sort(intersection_segments(a, d, TOL)[0], axis=0),
                       [[0.7, 0.3, 0.5], [0.7, 0.6, 0.5]])  # T
    assert len(intersection_segments(a, c, TOL)) == 0
    assert np.isclose(fracture_distance(a, c), 0.1)
    disc = Fracture3D.disc("d", [0.5, 0.5, 0.5], [1, 0, 0], 0.2)
    seg = intersection_segments(a, disc, TOL)[0]
    assert np.isclose(np.linalg.norm(seg[1] - seg[0]), 0.4)
    check_box_geometry(geo, 0.1)
    for g, sizes in CASES.values():
        check_box_geometry(g, sizes.fracture_size)


def _random_fracture(rng, name):
    n = rng.normal(size=3)
    if rng.random() < 0.5:
        return Fracture3D.disc(name, rng.uniform(0.35, 0.65, 3), n, rng.uniform(0.1, 0.4))
    t1 = np.cross(n, rng.normal(size=3))
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(n, t1) / np.linalg.norm(n)
    k = int(rng.integers(3, 7))
    th = np.sort(rng.uniform(0, 2 * np.pi, k))  # convex: points on a circle
    r = rng.uniform(0.1, 0.4)
    return Fracture3D.polygon(name, rng.uniform(0.35, 0.65, 3)
                              + r * (np.cos(th)[:, None] * t1 + np.sin(th)[:, None] * t2))


def _samples(fr, n=16):
    """Points filling a fracture: rays from its origin to its rim (polygons are convex here)."""
    o = fr.origin
    rim = fr.outline(4 * n) if fr.is_disc else fr.boundary_points(4 * n)
    s = np.linspace(0, 1, n)[1:, None, None]
    return np.concatenate([o[None], (o + s * (rim - o)[None]).reshape(-1, 3)])


def test_intersections_and_distances_random():
    """Segments lie on both fractures and end on a rim; distances match brute force."""
    rng = np.random.default_rng(7)
    hits = misses = 0
    for k in range(40):
        a, b = _random_fracture(rng, "a"), _random_fracture(rng, "b")
        segs = intersection_segments(a, b, TOL)
        if len(segs):
            hits += 1
            p = np.concatenate([segs.reshape(-1, 3), segs.mean(axis=1)])
            assert np.all(a.contains(p, 1e-9) & b.contains(p, 1e-9)), k
            ends = segs.reshape(-1, 3)
            assert np.all(np.minimum(a.rim_distance(ends), b.rim_distance(ends)) <= 1e-9), k
        else:
            misses += 1
            sa, sb = _samples(a), _samples(b)
            brute = np.sqrt(((sa[:, None] - sb[None]) ** 2).sum(axis=2).min())
            d = fracture_distance(a, b)
            # discs are 256-gons in fracture_distance: within 7.5e-5 r of the exact rim
            assert d <= brute + 1e-4 and brute - d < 0.03, (k, d, brute)
    assert hits >= 10 and misses >= 10


def _reject(geo, size=None) -> str:
    with pytest.raises(GeometryError) as info:
        check_box_geometry(geo, size)
    msg = str(info.value)
    assert "\n" not in msg
    return msg


def _box(*fractures, box=UNIT):
    return BoxGeometry(box, tuple(fractures))


def _poly(name, pts):
    return Fracture3D.polygon(name, pts)


A = rect("A", 2, 0.5, (0.2, 0.2), (0.8, 0.8))

REJECTIONS = {
    "extent": (lambda: _box(box=(0, 0, 0, 1, 0, 1)), None, ["box", "extent in y", "0 m"]),
    "names": (lambda: _box(A, rect("A", 2, 0.2, (0.2, 0.2), (0.8, 0.8))), None,
              ["'A'", "more than once"]),
    "few_points": (lambda: _box(_poly("P", [[0.1, 0.1, 0.1], [0.5, 0.5, 0.5]])), None,
                   ["'P'", "2 point(s)", "at least 3"]),
    "repeated": (lambda: _box(_poly("P", [[0.1, 0.1, 0.5], [0.6, 0.1, 0.5], [0.1, 0.1, 0.5],
                                          [0.1, 0.6, 0.5]])), None,
                 ["'P'", "repeats point", "(0.1, 0.1, 0.5)"]),
    "collinear": (lambda: _box(_poly("P", [[0.1, 0.1, 0.5], [0.3, 0.3, 0.5],
                                           [0.6, 0.6, 0.5]])), None, ["'P'", "zero area"]),
    "nonplanar": (lambda: _box(_poly("P", [[0.2, 0.2, 0.5], [0.8, 0.2, 0.5], [0.8, 0.8, 0.5],
                                           [0.2, 0.8, 0.51]])), None,
                  ["'P'", "not planar", "0.0025 m", "best plane"]),
    "bowtie": (lambda: _box(_poly("P", [[0.2, 0.2, 0.5], [0.8, 0.8, 0.5], [0.8, 0.2, 0.5],
                                        [0.2, 0.6, 0.5]])), None,
               ["'P'", "intersects itself"]),
    "radius": (lambda: _box(Fracture3D.disc("D", [0.5] * 3, [0, 0, 1], 0.0)), None,
               ["disc 'D'", "radius 0"]),
    # gmsh corrupted its memory on a disc of 1e-11 m in an 8 m box (exit 134)
    "tiny_radius": (lambda: _box(Fracture3D.disc("D", [0.5] * 3, [0, 0, 1], 1e-11)), None,
                    ["disc 'D'", "radius 1e-11 m", "zero area"]),
    "normal": (lambda: _box(Fracture3D.disc("D", [0.5] * 3, [0, 0, 0], 0.2)), None,
               ["disc 'D'", "zero normal"]),
    "outside": (lambda: _box(_poly("P", [[0.2, 0.2, 0.5], [1.3, 0.2, 0.5], [0.2, 0.8, 0.5]])),
                None, ["'P'", "(1.3, 0.2, 0.5)", "outside the box by 0.3 m", "'right'"]),
    "poke": (lambda: _box(Fracture3D.disc("D", [0.5, 0.5, 0.85], [1, 0, 0], 0.25)), None,
             ["disc 'D'", "pokes out", "by 0.1 m", "'top'"]),
    "in_face": (lambda: _box(rect("P", 2, 0.0, (0.2, 0.2), (0.8, 0.8))), None,
                ["'P'", "lies in the box face 'bottom'"]),
    "coplanar": (lambda: _box(A, rect("B", 2, 0.5, (0.7, 0.7), (0.9, 0.9))), None,
                 ["'A'", "'B'", "coplanar and overlap"]),
    "coplanar_same": (lambda: _box(A, rect("B", 2, 0.5, (0.2, 0.2), (0.8, 0.8))), None,
                      ["coplanar and overlap"]),
    "grazing": (lambda: _box(A, _poly("B", (rect("B", 2, 0.0, (-0.3, -0.3), (0.3, 0.3)).points
                                            @ rotation(np.radians(5), 0).T) + 0.5)), None,
                ["'A'", "'B'", "grazing angle of 5°", "minimum 10°"]),
    "grazing_face": (lambda: _box(_poly("B", [[0, 0.2, 0.2], [0, 0.8, 0.2],
                                              [0.5 * np.tan(np.radians(4)), 0.8, 0.7],
                                              [0.5 * np.tan(np.radians(4)), 0.2, 0.7]])),
                     None, ["'B'", "box face 'left'", "grazing angle of 4°", "minimum 10°"]),
    "short": (lambda: _box(A, rect("B", 0, 0.5, (0.19, 0.3), (0.23, 0.7))), 0.05,
              ["'A'", "'B'", "0.03 m long", "shorter than the fracture size 0.05 m"]),
    "near_miss": (lambda: _box(A, rect("B", 0, 0.5, (0.3, 0.51), (0.7, 0.9))), 0.05,
                  ["'A'", "'B'", "0.01 m apart", "without intersecting"]),
    "tiny_overlap": (lambda: _box(A, rect("B", 0, 0.5, (0.3, 0.49), (0.7, 0.9))), 0.05,
                     ["'B'", "passes through 'A'", "by only 0.01 m"]),
    "touch_point": (lambda: _box(A, _poly("B", [[0.5, 0.5, 0.5], [0.6, 0.5, 0.8],
                                                [0.4, 0.5, 0.8]])), None,
                    ["'A'", "'B'", "touch at a single point", "(0.5, 0.5, 0.5)"]),
    "end_near_edge": (lambda: _box(A, rect("B", 0, 0.5, (0.22, 0.3), (0.7, 0.7))), 0.05,
                      ["intersection", "'A'", "'B'", "ends 0.02 m from the edge of 'A'"]),
    "face_near_miss": (lambda: _box(rect("P", 0, 0.5, (0.01, 0.2), (0.8, 0.8))), 0.05,
                       ["'P'", "0.01 m from the box face 'front'", "without reaching it"]),
    "face_point": (lambda: _box(_poly("P", [[0.0, 0.5, 0.5], [0.5, 0.3, 0.5],
                                            [0.5, 0.7, 0.5]])), None,
                   ["'P'", "touches the box face 'left' at a single point"]),
    "disc_tangent": (lambda: _box(Fracture3D.disc("D", [0.5, 0.5, 0.7], [1, 0, 0], 0.3)), None,
                     ["'D'", "touches the box face 'top' at a single point",
                      "(0.5, 0.5, 1)"]),
}


@pytest.mark.parametrize("case", sorted(REJECTIONS))
def test_geometry_rejected(case):
    build, size, words = REJECTIONS[case]
    msg = _reject(build(), size)
    for w in words:
        assert w in msg, (w, msg)


def test_geometry_accepted():
    """X, T, a fracture reaching a face, a through-cut, and near things farther than h/2."""
    through = _poly("cut", [[0, 0, 0.3], [1, 0, 0.3], [1, 1, 0.7], [0, 1, 0.7]])
    check_box_geometry(_box(through, rect("B", 0, 0.5, (0.2, 0.2), (0.8, 0.8))), 0.1)
    check_box_geometry(_box(A, rect("B", 0, 0.5, (0.3, 0.56), (0.7, 0.9))), 0.1)  # gap 0.06
    with pytest.raises(GeometryError):  # same with h = 0.2
        check_box_geometry(_box(A, rect("B", 0, 0.5, (0.3, 0.56), (0.7, 0.9))), 0.2)


# ------------------------------------------------------------------------------------------------
# Meshing


def _facet_rows(cells):
    return np.sort(cells[:, facet_table(4)], axis=2).reshape(-1, 3)


def _tri_area(x, tri):
    return 0.5 * np.linalg.norm(np.cross(x[tri[:, 1]] - x[tri[:, 0]], x[tri[:, 2]] - x[tri[:, 0]]),
                                axis=1)


@pytest.mark.parametrize("name", ["penny", "tilted", "network", "face", "disc", "through",
                                  "oblique", "network_mm"])
def test_generate(name):
    geo, sizes = CASES[name]
    ar, rep = mesh_of(name)
    x, cells = ar.x, ar.cells
    assert x.shape[1] == 3 and cells.shape[1] == 4 and ar.fracture_facets.shape[1] == 3
    assert rep.num_cells == len(cells) and rep.bisected_edges == 0
    d = x[cells[:, 1:]] - x[cells[:, :1]]
    assert np.all(np.einsum("ij,ij->i", d[:, 0], np.cross(d[:, 1], d[:, 2])) > 0)
    assert np.array_equal(np.unique(cells), np.arange(len(x)))  # no unused nodes
    # fracture facets: interior facets of the mesh, on their fracture
    ids, n = unique_rows(np.concatenate([_facet_rows(cells), np.sort(ar.fracture_facets, 1),
                                         np.sort(ar.boundary_facets, 1)]))
    count = np.bincount(ids[: 4 * len(cells)], minlength=n)
    nf = len(ar.fracture_facets)
    assert np.all(count[ids[4 * len(cells): 4 * len(cells) + nf]] == 2)
    for j, fr in enumerate(geo.fractures):
        sel = ar.fracture_id == j
        assert np.all(fr.contains(x[ar.fracture_facets[sel]].reshape(-1, 3), 1e-9))
        area = _tri_area(x, ar.fracture_facets[sel]).sum()
        if fr.is_disc:
            assert 0.98 * fr.area < area < fr.area
        else:
            assert np.isclose(area, fr.area, rtol=1e-12)
    # boundary facets: exactly the facets seen once, on their faces, covering each face
    assert np.all(count[ids[4 * len(cells) + nf:]] == 1)
    assert np.count_nonzero(count[ids[: 4 * len(cells)]] == 1) == len(ar.boundary_facets)
    for face in range(6):
        axis, value = geo.face_plane(face)
        tri = ar.boundary_facets[ar.boundary_edge == face]
        assert np.allclose(x[tri][..., axis], value)
        ext = np.delete(geo.upper - geo.lower, axis)
        assert np.isclose(_tri_area(x, tri).sum(), ext[0] * ext[1], rtol=1e-12)
    # 3D conventions and numbering by (fracture, t1·c, t2·c)
    assert np.all(ar.fracture_segment == 0) and np.all(np.isnan(ar.fracture_s))
    c = x[ar.fracture_facets].mean(axis=1)
    for j, fr in enumerate(geo.fractures):
        sel = np.flatnonzero(ar.fracture_id == j)
        assert np.all(np.diff(sel) == 1)
        t1, t2 = fr.tangents
        key = np.column_stack([c[sel] @ t1, c[sel] @ t2])
        assert np.all(np.diff(key[:, 0]) >= 0)
    assert np.all(np.diff(ar.fracture_id) >= 0) and np.all(np.diff(ar.boundary_edge) >= 0)


def test_a_small_box_is_meshed_as_its_scaled_copy():
    """A box below a metre is meshed in units that bring its diameter between 1 and 10 (the
    1.7 mm network in millimetres): the mesh of the unit-box network scaled by 1e-3, the same
    tetrahedra, fracture and boundary faces, the nodes to round-off. With the model in metres
    OpenCASCADE's absolute precision (1e-7) was about 600 times the classification tolerance
    and the box faces were not found."""
    from poromech.mesh.generate3d import model_scale

    assert model_scale(CASES["network"][0]) == 1.0
    assert model_scale(CASES["network_mm"][0]) == pytest.approx(1e-3, rel=1e-15)
    big, _ = mesh_of("network")
    small, _ = mesh_of("network_mm")
    assert np.array_equal(small.cells, big.cells)
    assert np.abs(small.x - 1e-3 * big.x).max() < 1e-15 * 1e-3

    def tagged(facets, tags):  # (tag, sorted nodes) rows, sorted: the faces sort by
        rows = np.column_stack([tags, np.sort(facets, axis=1)])  # centroids, ties by round-off
        return rows[np.lexsort(rows.T[::-1])]

    assert np.array_equal(tagged(small.fracture_facets, small.fracture_id),
                          tagged(big.fracture_facets, big.fracture_id))
    assert np.array_equal(tagged(small.boundary_facets, small.boundary_edge),
                          tagged(big.boundary_facets, big.boundary_edge))


def test_hxt_conforms_and_frontal_is_refused():
    geo, sizes = CASES["network"]
    ar, rep = build_mesh_3d(geo, sizes, algorithm_3d=10)
    cracked, _ = crack_vertices(ar.cells, ar.fracture_facets, len(ar.x))
    assert len(deficient_edges(ar.cells, ar.fracture_facets, len(ar.x), cracked)) == 0
    assert rep.num_fracture_faces == len(mesh_of("network")[0].fracture_facets)
    with pytest.raises(RuntimeError, match="did not conform"):
        build_mesh_3d(geo, MeshSizes(0.5, 0.25, 0.25, 0.5), algorithm_3d=4)


def test_reproducible_numbering():
    geo, sizes = CASES["network"]
    again, _ = build_mesh_3d(geo, sizes)
    first, _ = mesh_of("network")
    for f in ("x", "cells", "fracture_facets", "fracture_id", "boundary_facets", "boundary_edge"):
        assert np.array_equal(getattr(first, f), getattr(again, f)), f


def test_refinement_multiplies_cells_by_8():
    geo, sizes = CASES["tilted"]
    coarse, rc = build_mesh_3d(geo, MeshSizes(0.3, 0.15, 0.15, 0.3))
    fine, rf = build_mesh_3d(geo, MeshSizes(0.3, 0.15, 0.15, 0.3, refinement=1))
    assert rf.gmsh_cells == 8 * rc.gmsh_cells
    assert len(fine.fracture_facets) == 4 * len(coarse.fracture_facets)
    assert len(fine.boundary_facets) == 4 * len(coarse.boundary_facets)
    assert np.isclose(_tri_area(fine.x, fine.fracture_facets).sum(), 0.25)


def surfaces_geometry():
    """A fracture cut by an interface plane z = 0.4, and a patch in the face x = 0."""
    frac = rect("F", 0, 0.5, (0.2, 0.2), (0.8, 0.8))  # x = 0.5, (y, z) in [0.2, 0.8]^2
    layer = rect("layer", 2, 0.4, (0.0, 0.0), (1.0, 1.0))
    patch = rect("patch", 0, 0.0, (0.0, 0.7), (0.3, 1.0))  # x = 0: y in [0, 0.3], z in [0.7, 1]
    return BoxGeometry(UNIT, (frac,), (layer, patch))


def test_conforming_surfaces():
    """No tet crosses an interface, boundary triangles tile a patch, fractures are unchanged."""
    geo = surfaces_geometry()
    check_box_geometry(geo, 0.15)
    sizes = MeshSizes(0.3, 0.15, 0.15, 0.6)
    ar, rep = build_mesh_3d(geo, sizes)
    x, cells = ar.x, ar.cells
    side = np.sign(np.round(x[cells][..., 2] - 0.4, 12))
    assert np.all((side.min(axis=1) >= 0) | (side.max(axis=1) <= 0))
    tri = ar.boundary_facets[ar.boundary_edge == 0]
    c = x[tri].mean(axis=1)
    inside = (c[:, 1] < 0.3) & (c[:, 2] > 0.7)
    assert np.isclose(_tri_area(x, tri[inside]).sum(), 0.09, rtol=1e-12)
    assert np.isclose(_tri_area(x, ar.fracture_facets).sum(), 0.36, rtol=1e-12)
    assert rep.tip_curves == 6  # 4 edges, the 2 crossing z = 0.4 cut in two; the cut no tip
    assert np.all(ar.fracture_id == 0) and rep.bisected_edges == 0


def test_conforming_surfaces_rejected():
    frac = rect("F", 0, 0.5, (0.2, 0.2), (0.8, 0.8))
    outside = rect("S", 2, 0.4, (0.0, 0.0), (1.2, 1.0))
    msg = _reject(BoxGeometry(UNIT, (frac,), (outside,)))
    assert "surface 'S'" in msg and "outside the box" in msg
    overlap = rect("S", 0, 0.5, (0.0, 0.0), (0.5, 0.5))
    msg = _reject(BoxGeometry(UNIT, (frac,), (overlap,)))
    assert "surface 'S' overlaps fracture 'F' in its plane" in msg
    flat = _poly("S", [[0.1, 0.1, 0.1], [0.5, 0.5, 0.5], [0.9, 0.9, 0.9]])
    assert "surface 'S' is degenerate" in _reject(BoxGeometry(UNIT, (), (flat,)))
    # a surface that passes within half the fracture size of a fracture without meeting it
    # (0.1 mm above it: slivers, the fracture's tractions moved by 20 %) was accepted
    above = rect("S", 2, 0.5001, (0.5, 0.2), (0.8, 0.8))
    msg = _reject(BoxGeometry(UNIT, (frac_h := rect("F", 2, 0.5, (0.2, 0.2), (0.8, 0.8)),),
                              (above,)), 0.1)
    assert "surface 'S' and fracture 'F' are 0.0001 m apart without meeting" in msg
    check_box_geometry(BoxGeometry(UNIT, (frac_h,), (rect("S", 2, 0.6, (0.5, 0.2),
                                                          (0.8, 0.8)),)), 0.1)
    check_box_geometry(BoxGeometry(UNIT, (frac_h,), (rect("S", 0, 0.5, (0.0, 0.0),
                                                          (1.0, 1.0)),)), 0.1)  # crosses it


# ------------------------------------------------------------------------------------------------
# Cracked topology: copy counts against a geometric classification

#: Copies per class (DESIGN.md §3; dolfinx_3d_fractures.md §2.2).
EXPECTED = {"off": 1, "interior": 2, "tip": 1, "boundary": 2, "tip_boundary": 1, "x_line": 4,
            "x_end": 2, "t_line": 3, "t_end": 2}


def _edges_through(fr, p):
    """Polygon edges (a, b) containing point p."""
    a, b = fr.points, np.roll(fr.points, -1, axis=0)
    return [(a[i], b[i]) for i in range(len(a))
            if np.linalg.norm(np.cross(b[i] - a[i], p - a[i])) <= TOL * np.linalg.norm(b[i] - a[i])
            and -TOL <= (p - a[i]) @ (b[i] - a[i]) <= (b[i] - a[i]) @ (b[i] - a[i]) + TOL]


def _rim_tol(fr):
    """A disc's mesh rim is a polygon: chord midpoints are within ~0.006 r of the circle (the
    nearest interior edge midpoints are > 0.06 r away); polygons are exact."""
    return 0.03 * fr.radius if fr.is_disc else TOL


def _classify_point(geo, p, inside, rim, face):
    """The rarer classes: a rim point on a box face, or a point on two fractures."""
    if len(inside) == 1:
        edges = _edges_through(geo.fractures[inside[0]], p)
        in_face = [any(abs(a[k // 2] - geo.face_plane(k)[1]) <= TOL
                       and abs(b[k // 2] - geo.face_plane(k)[1]) <= TOL for k in face)
                   for a, b in edges]
        return "boundary" if all(in_face) else "tip_boundary"
    assert len(inside) == 2 and len(rim) == 1 and not face, p
    j, k = rim[0], [i for i in inside if i != rim[0]][0]
    on_k = [bool(np.all(geo.fractures[k].contains(np.array([a, b]), TOL)))
            for a, b in _edges_through(geo.fractures[j], p)]
    if not any(on_k):
        return "x_end"
    return "t_line" if all(on_k) else "t_end"


def classify(geo, points):
    """Geometric class of points of a fracture network (independent of the mesh)."""
    p = np.atleast_2d(points)
    inside = np.column_stack([f.contains(p, TOL) for f in geo.fractures])
    rim = inside & np.column_stack([f.rim_distance(p) <= _rim_tol(f) for f in geo.fractures])
    face = np.column_stack([np.abs(p[:, k // 2] - geo.face_plane(k)[1]) <= TOL
                            for k in range(6)])
    count, on_rim, on_face = inside.sum(axis=1), rim.any(axis=1), face.any(axis=1)
    out = np.full(len(p), "off", dtype=object)
    out[(count == 1) & ~on_rim] = "interior"
    out[(count == 1) & on_rim & ~on_face] = "tip"
    out[(count == 2) & ~on_rim] = "x_line"
    assert np.all(count <= 2)
    rare = ((count == 1) & on_rim & on_face) | ((count == 2) & on_rim)
    for i in np.flatnonzero(rare):
        out[i] = _classify_point(geo, p[i], np.flatnonzero(inside[i]).tolist(),
                                 np.flatnonzero(rim[i]).tolist(),
                                 np.flatnonzero(face[i]).tolist())
    return out.astype(str)


def _mesh_edges(cells):
    return np.unique(np.sort(cells[:, edge_table(4)], axis=2).reshape(-1, 2), axis=0)


@pytest.mark.parametrize("name", ["network", "through", "face", "disc", "penny", "oblique"])
def test_copy_counts_vertices_and_edges(name):
    """Tip 1, interior 2, X line 4, on ∂Ω 2, ends of intersection lines 2, T line 3."""
    geo, _ = CASES[name]
    ar, _ = mesh_of(name)
    cracked, ncv = crack_vertices(ar.cells, ar.fracture_facets, len(ar.x))
    pairs = np.unique(np.column_stack([ar.cells.ravel(), cracked.ravel()]), axis=0)
    vcopies = np.bincount(pairs[:, 0], minlength=len(ar.x))
    assert ncv == len(pairs)
    vclass = classify(geo, ar.x)
    edges, copies, index = edge_star_copies(ar.cells, ar.fracture_facets)
    topo = topological_copies(cracked, index, 1, len(edges))
    assert np.array_equal(edges, _mesh_edges(ar.cells))
    eclass = classify(geo, ar.x[edges].mean(axis=1))
    seen = set()
    for cls, n in EXPECTED.items():
        for kind, got, classes in (("vertex", vcopies, vclass), ("edge", copies, eclass),
                                   ("edge (cracked topology)", topo, eclass)):
            sel = classes == cls
            if sel.any():
                seen.add((cls, kind.split()[0]))
                assert np.all(got[sel] == n), (kind, cls, np.unique(got[sel]))
    vertex_classes = {c for c, k in seen if k == "vertex"}
    edge_classes = {c for c, k in seen if k == "edge"}
    if name == "network":
        assert vertex_classes == set(EXPECTED)
        assert edge_classes == {"off", "interior", "tip", "boundary", "x_line", "t_line"}
    elif name == "oblique":
        assert vertex_classes == {"off", "interior", "tip", "x_line", "x_end"}
    elif name == "through":  # the plane reaches the box everywhere: no tip at all
        assert vertex_classes == edge_classes == {"off", "interior", "boundary"}


def test_crack_vertices_tets_of_one_fracture():
    """Two tets sharing a fracture facet: the 3 shared vertices are split, the others not."""
    cells = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    cracked, n = crack_vertices(cells, np.array([[3, 2, 1]]), 5)
    assert n == 8 and cracked[0].tolist() == [0, 1, 2, 3] and cracked[1].tolist() == [5, 6, 7, 4]
    cracked, n = crack_vertices(cells, np.empty((0, 3), dtype=np.int64), 5)
    assert n == 5 and np.array_equal(cracked, cells)
    with pytest.raises(ValueError, match="not a facet"):
        crack_vertices(cells, np.array([[0, 1, 4]]), 5)


def test_crack_vertices_on_triangles_follow_the_rule():
    """On 2D networks (tips, corners, T, X, boundary) the cracked vertices are the rule's count
    of P1 dofs, and no edge is deficient (2D outputs are bitwise those of the 2D-only version:
    docs/regression.md)."""
    from poromech.mesh.generate import generate_mesh
    from poromech.scene.geometry import mesh_sizes, scene_geometry
    from poromech.scene.loading import load_scene, scene_from_dict

    for scene in (load_scene("six_fractures_mechanics"), scene_from_dict(mechanics_scene())):
        ar = generate_mesh(scene_geometry(scene), mesh_sizes(scene))
        cracked, n = crack_vertices(ar.cells, ar.fracture_facets, len(ar.x))
        assert n > len(ar.x)
        assert n == rule_dof_count(ar.cells, ar.fracture_facets, len(ar.x), 1)
        assert len(deficient_edges(ar.cells, ar.fracture_facets, len(ar.x), cracked)) == 0


def test_unique_rows_beyond_packed_key_range():
    """Node ids above 2e6 (where a packed triple key overflows int64) are handled."""
    big = 3_000_000_000
    cells = np.array([[0, 1, 2, 3], [1, 2, 3, 4]], dtype=np.int64) + big
    cracked, n = crack_vertices(cells, np.array([[big + 3, big + 2, big + 1]]), big + 5)
    assert n == big + 8 and cracked[1].tolist() == [big + 5, big + 6, big + 7, big + 4]
    ids, m = unique_rows([[big, 2 * big, 1], [big, 2 * big, 0], [big, 2 * big, 1]])
    assert m == 2 and ids.tolist() == [1, 0, 1]


def test_bisect_edges_keeps_orientation_and_facets():
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1.0]])
    cells = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    ff, bf = np.array([[1, 2, 3]]), np.array([[0, 1, 2], [0, 2, 3], [0, 1, 3]])
    x2, c2, ff2, fpar, bf2, bpar = bisect_edges(x, cells, ff, bf, np.array([[2, 1]]))
    assert len(x2) == 6 and np.allclose(x2[5], [0.5, 0.5, 0])
    assert len(c2) == 4 and len(ff2) == 2 and fpar.tolist() == [0, 0]
    assert len(bf2) == 4 and sorted(bpar.tolist()) == [0, 0, 1, 2]

    def vol(x, c):
        d = x[c[:, 1:]] - x[c[:, :1]]
        return np.einsum("ij,ij->i", d[:, 0], np.cross(d[:, 1], d[:, 2])) / 6

    assert np.all(np.sign(vol(x2, c2)) == np.sign(vol(x, cells))[[0, 1, 0, 1]])
    assert np.isclose(vol(x2, c2).sum(), vol(x, cells).sum())
    assert np.isclose(_tri_area(x2, ff2).sum(), _tri_area(x, ff).sum())


def test_acute_triangle_deficient_edges_bisected():
    """Raw gmsh mesh: P2 loses dofs; bisected: none deficient and the P2 count is the rule."""
    geo, sizes = CASES["acute"]
    raw, _ = build_mesh_3d(geo, sizes, repair=False)
    cracked, _ = crack_vertices(raw.cells, raw.fracture_facets, len(raw.x))
    bad = deficient_edges(raw.cells, raw.fracture_facets, len(raw.x), cracked)
    assert len(bad) > 0
    assert np.all(classify(geo, raw.x[bad].mean(axis=1)) == "interior")
    edges, copies, index = edge_star_copies(raw.cells, raw.fracture_facets)  # whole mesh
    full = edges[topological_copies(cracked, index, 1, len(edges)) < copies]
    assert np.array_equal(full, bad)
    fixed, rep = mesh_of("acute")
    assert rep.bisected_edges == len(bad) and len(fixed.x) == len(raw.x) + len(bad)
    cracked, _ = crack_vertices(fixed.cells, fixed.fracture_facets, len(fixed.x))
    assert len(deficient_edges(fixed.cells, fixed.fracture_facets, len(fixed.x), cracked)) == 0
    assert np.isclose(_tri_area(fixed.x, fixed.fracture_facets).sum(), geo.fractures[0].area)
    comm = MPI.COMM_SELF
    for arrays, equal in ((raw, False), (fixed, True)):
        V = cracked_space(create_fractured_mesh(comm, geo, arrays), 2)
        n = V.dofmap.index_map.size_global * V.dofmap.index_map_bs
        rule = rule_dof_count(arrays.cells, arrays.fracture_facets, len(arrays.x), 2, 3)
        assert (n == rule) == equal, (n, rule)


# ------------------------------------------------------------------------------------------------
# Distributed mesh and cracked spaces (the same helper runs serially and under mpirun)


def space_summary(comm, name, force_partition=False, degrees=(1, 2)) -> dict:
    """Dof counts, per-class dof copies at vertices and edge midpoints, orientation integrals."""
    geo, _ = CASES[name]
    root = comm.rank == 0
    ar = mesh_of(name)[0] if root else None
    owner = plane_owner(ar, *geo.fractures[0].plane()) if root and force_partition else None
    fm = create_fractured_mesh(comm, geo, ar, owner=owner if force_partition else None)
    out: dict = {"dofs": {}, "rule": {}, "copies": {}}
    for degree in degrees:
        V = cracked_space(fm, degree)
        imap = V.dofmap.index_map
        out["dofs"][degree] = imap.size_global * V.dofmap.index_map_bs
        xd = comm.gather(V.tabulate_dof_coordinates()[: imap.size_local], root=0)
        if root:
            out["rule"][degree] = rule_dof_count(ar.cells, ar.fracture_facets, len(ar.x),
                                                 degree, 3)
            tree = cKDTree(np.concatenate(xd))
            points = {"vertex": ar.x}
            if degree == 2:
                points["edge"] = ar.x[_mesh_edges(ar.cells)].mean(axis=1)
            for kind, p in points.items():
                n = tree.query_ball_point(p, 1e-10, return_length=True)
                cls = classify(geo, p)
                out["copies"][f"P{degree} {kind}"] = {
                    c: sorted(set(n[cls == c].tolist())) for c in np.unique(cls)}
    out.update(_orientation(fm))
    imap = fm.msh.topology.index_map(3)
    ghost = (fm.fractures.plus[:, 0] >= imap.size_local) | (
        fm.fractures.minus[:, 0] >= imap.size_local)
    out["faces_with_ghost_side"] = comm.allreduce(int(ghost.sum()))
    out["faces"] = comm.allreduce(len(fm.fractures.facets))
    return out


def _orientation(fm) -> dict:
    """Per fracture: ∫ n('+')·n_ref, |Γ|, ∫ |n('+') - n_ref|², ∫ |x('+') - x('-')|²."""
    msh, comm = fm.msh, fm.comm
    nf = len(fm.geometry.fractures)
    dG = fracture_measure(fm)
    n, x = ufl.FacetNormal(msh), ufl.SpatialCoordinate(msh)
    c = [fem.Constant(msh, np.zeros(3)) for _ in range(nf)]
    w = [fem.Constant(msh, 0.0) for _ in range(nf)]
    jump = x("+") - x("-")
    forms = [
        fem.form(sum(ufl.dot(n("+"), c[j]) * dG(FRACTURE_TAG_OFFSET + j) for j in range(nf))),
        fem.form(sum(w[j] * dG(FRACTURE_TAG_OFFSET + j) for j in range(nf))),
        fem.form(sum(ufl.dot(n("+") - c[j], n("+") - c[j]) * w[j] * dG(FRACTURE_TAG_OFFSET + j)
                     for j in range(nf))),
        fem.form(sum(ufl.dot(jump, jump) * w[j] * dG(FRACTURE_TAG_OFFSET + j)
                     for j in range(nf))),
    ]
    values = []
    for j, fr in enumerate(fm.geometry.fractures):
        for k in range(nf):
            c[k].value[:] = fr.normal if k == j else 0.0
            w[k].value = 1.0 if k == j else 0.0
        values.append([comm.allreduce(fem.assemble_scalar(f)) for f in forms])
    return {"orientation": values}


def _check_summary(name, s, force_partition=False):
    geo, _ = CASES[name]
    ar, _ = mesh_of(name)
    for degree, n in s["dofs"].items():
        assert n == s["rule"][degree], (degree, n, s["rule"][degree])
    for kind, by_class in s["copies"].items():
        for cls, counts in by_class.items():
            assert counts == [EXPECTED[cls]], (kind, cls, counts)
    for j, (flux, area, dn, dx) in enumerate(s["orientation"]):
        exact = _tri_area(ar.x, ar.fracture_facets[ar.fracture_id == j]).sum()
        assert abs(flux - exact) <= 1e-13 and abs(area - exact) <= 1e-13
        assert dn <= 1e-28 and dx <= 1e-28
    assert s["faces"] == len(ar.fracture_facets)
    if name == "network":  # every class is present
        assert set(s["copies"]["P1 vertex"]) == set(EXPECTED)
        assert set(s["copies"]["P2 edge"]) == set(EXPECTED) - {"tip_boundary", "x_end", "t_end"}
    if force_partition:  # every face of fracture 0 has a ghost side on one of the ranks
        assert s["faces_with_ghost_side"] >= np.count_nonzero(ar.fracture_id == 0)


@pytest.mark.parametrize("name", ["network", "disc"])
def test_cracked_space_serial(name):
    s = space_summary(MPI.COMM_SELF, name)
    _check_summary(name, json.loads(json.dumps(s)))
    assert s["dofs"] == s["rule"] and s["faces_with_ghost_side"] == 0


MPI_CODE = """
import sys, json
sys.path.insert(0, "tests")
import dolfinx_solver
from mpi4py import MPI
from test_mesh3d import space_summary
comm = MPI.COMM_WORLD
out = {f"{name} {force}": space_summary(comm, name, force)
       for name in ("network", "tilted", "acute") for force in (False, True)}
if comm.rank == 0:
    print(json.dumps(out))
"""


@pytest.mark.mpi
def test_cracked_space_two_ranks():
    """Same dof counts, copies and orientation on 2 ranks, also with the boundary on a fracture."""
    result = run_parallel(MPI_CODE)
    for key, s in result.items():
        name, force = key.split()
        _check_summary(name, s, force == "True")
    assert result["network True"]["faces_with_ghost_side"] > 0


def test_surfaces_refused_in_2d():
    raw = mechanics_scene()
    raw["geometry"]["surfaces"] = [{"polygon": [[0, 0, 0], [1, 0, 0], [1, 1, 0]]}]
    assert "'geometry.surfaces' is for a box (3D) only" in config_error(raw)


def test_zones_refine_fractures_or_balls():
    """A zone on the fractures refines the fracture in its ball only; a ball zone the whole
    ball; the cell estimate follows both."""
    from dataclasses import replace

    from poromech.mesh.generate import SizeZone
    from poromech.scene.resources import estimate_cells_3d

    geo = BoxGeometry(UNIT, (rect("F", 2, 0.5, (0.1, 0.1), (0.9, 0.9)),))  # z = 0.5
    base = MeshSizes(0.25, 0.1, 0.1, 0.25)
    on_fracture = SizeZone((0.3, 0.3, 0.5), 0.15, 0.025, 0.25)
    ball = SizeZone((0.7, 0.7, 0.22), 0.1, 0.04, 0.25, on_fractures=False)
    sizes = replace(base, zones=(on_fracture, ball))
    ar, rep = build_mesh_3d(geo, sizes)
    x, ff = ar.x, ar.fracture_facets
    h = np.sqrt(4 * _tri_area(x, ff) / np.sqrt(3))  # edge of the equilateral of that area
    r = np.linalg.norm(x[ff].mean(axis=1) - on_fracture.center, axis=1)
    assert h[r < 0.1].mean() < 1.4 * 0.025
    assert h[r > 0.5].mean() > 0.07  # fracture_size away from the zone
    c = x[ar.cells].mean(axis=1)
    d = x[ar.cells[:, 1:]] - x[ar.cells[:, :1]]
    volume = np.abs(np.einsum("ij,ij->i", d[:, 0], np.cross(d[:, 1], d[:, 2]))) / 6
    edge = np.cbrt(6 * np.sqrt(2) * volume)  # edge of the regular tet of that volume
    in_ball = np.linalg.norm(c - ball.center, axis=1) < 0.06
    assert edge[in_ball].mean() < 1.4 * 0.04
    # the rock in the fracture zone's ball, 0.2 from the fracture, is not refined to 0.025
    above = (np.linalg.norm(c[:, :2] - 0.3, axis=1) < 0.1) & (np.abs(c[:, 2] - 0.5) > 0.2)
    assert edge[above].mean() > 0.1
    # the estimate is as close to gmsh's count with the zones as without them (the small box's
    # boundary makes both low)
    est = estimate_cells_3d(geo, 0.25, 0.1, 0.1, 0.25, 0, sizes.zones)
    plain = estimate_cells_3d(geo, 0.25, 0.1, 0.1, 0.25, 0)
    ratio = (est / rep.num_cells) / (plain / build_mesh_3d(geo, base)[1].num_cells)
    assert 0.8 < ratio < 1.25


def test_a_fracture_of_a_few_faces_is_said_to_be_under_resolved(caplog):
    """A disc of radius 0.02 m in a 0.25 m mesh became a heptagon of 7 faces around one node,
    every face with the same jump, without a word: a warning now names it."""
    from poromech.run import FEWEST_FACES_3D, build_mesh, warn_unresolved_fractures
    from poromech.scene.loading import scene_from_dict

    raw = {"name": "tiny", "physics": "mechanics",
           "geometry": {"domain": {"box": [0.0, 0.0, 0.0, 1.0, 1.0, 1.0]},
                        "fractures": [
                            {"name": "tiny", "disc": {"center": [0.5, 0.5, 0.5],
                                                      "normal": [0.0, 0.0, 1.0],
                                                      "radius": 0.02}},
                            {"name": "big", "disc": {"center": [0.5, 0.5, 0.2],
                                                     "normal": [0.0, 0.0, 1.0],
                                                     "radius": 0.15}}]},
           "mesh": {"size": 0.25, "fracture_size": 0.05},
           "material": {"young": 1.0e10, "poisson": 0.25},
           "boundary_conditions": [{"boundary": "bottom", "displacement": [0.0, 0.0, 0.0]},
                                   {"boundary": "top", "traction": [0.0, 0.0, -1.0e6]}]}
    fm = build_mesh(scene_from_dict(raw), MPI.COMM_WORLD)
    counts = np.bincount(fm.fractures.fracture, minlength=2)
    assert counts[0] < FEWEST_FACES_3D <= counts[1]
    with caplog.at_level("WARNING", logger="poromech"):
        caplog.clear()
        warn_unresolved_fractures(fm)
    said = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(said) == 1 and said[0].startswith(f"fracture 'tiny' has only {counts[0]} face")


def test_a_short_transition_keeps_the_fracture_size():
    """gmsh measures the distance to samples of the fracture surface and tip curves: with a
    ``transition`` of 0.005 against their spacing of about 0.04 a disc of radius 1 at
    ``fracture_size`` 0.1 got 23 faces instead of about π/(√3/4 · 0.1²) = 725. A constant field
    holds the size on the fracture where the sampling leaves more than
    ``SAMPLING_EXCESS_3D`` of it."""
    geo = BoxGeometry((-3.0, -3.0, -3.0, 3.0, 3.0, 3.0),
                      (Fracture3D.disc("penny", [0, 0, 0], [0, 0, 1], 1.0),))
    ar, _ = build_mesh_3d(geo, MeshSizes(2.0, 0.1, 0.1, 0.005))
    h = np.sqrt(4 * _tri_area(ar.x, ar.fracture_facets) / np.sqrt(3))
    assert len(ar.fracture_facets) > 0.9 * np.pi / (np.sqrt(3) / 4 * 0.1**2)
    assert h.mean() < 1.1 * 0.1


def test_a_fracture_size_above_the_size_is_checked_at_the_size():
    """gmsh meshes a fracture at the smaller of fracture_size and size; the geometry checks
    took fracture_size alone, and refused a disc 0.2 m from a face for being nearer than half
    of 0.41 m, on a mesh of 0.2 m."""
    from poromech.errors import ConfigError
    from poromech.scene.loading import scene_from_dict

    raw = {"name": "bigfs", "geometry": {
        "domain": {"box": [0.0, 0.0, 0.0, 1.0, 1.0, 1.0]},
        "fractures": [{"name": "d", "disc": {"center": [0.5, 0.5, 0.5], "normal": [0, 0, 1],
                                             "radius": 0.3}}]},
        "mesh": {"size": 0.2, "fracture_size": 0.41},
        "material": {"young": 1.0e10, "poisson": 0.25},
        "contact": {"formulation": "none"}, "fracture_pressure": 1.0e6,
        "boundary_conditions": [{"boundary": "bottom", "displacement": [0, 0, 0]}]}
    scene_from_dict(raw)
    raw["mesh"]["size"] = 0.41
    with pytest.raises(ConfigError, match="without reaching it"):
        scene_from_dict(raw)
