"""Sampling of cell-wise and fracture-face data along straight lines (collective).

A :class:`LineSampler` places ``samples`` equidistant points on a segment. Cell data and finite
element functions are read from the owned cell containing each point; a point on a shared edge
or vertex takes the cell with the smallest *input* (original) index, so the answer does not
depend on the partition. A point on a fracture face, where the displacement and the matrix
pressure have two values, takes a cell on the face's ``+`` side (``n⁺`` points out of it, the
side of ``contact.traction_side: plus``): by input index alone a probe along a crack read
``u_y`` from alternating sides, +1.7e-3 and -1.8e-3 m at neighbouring points.
Optionally a cell gradient gives the linear reconstruction ``v_K + g_K·(x - x_K)``. Face data
(one value per fracture face, optionally with values at the face ends for a piecewise linear
profile) are read only where the line runs *along* a fracture: a face counts when both its end
points lie on the line. Results are gathered on rank 0, NaN where a
point has no value; :func:`write_csv` writes them with empty fields there.

:class:`ProbeTable` writes one ``probe_<name>.csv`` per line, a block of rows per output time
(``time`` first), crash-safe like ``fractures.csv``; a physics gives the columns of each time.
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path

import dolfinx_solver  # noqa: F401  (orders MPI before the bindings)

import dolfinx
import numpy as np
import numpy.typing as npt
from mpi4py import MPI

from poromech.errors import OutputError
from poromech.io.xdmf import atomic_write_text, root_write
from poromech.mesh.entities import fracture_segments

__all__ = ["LineSampler", "ProbeTable", "fracture_sides", "line_differences", "open_probes",
           "read_csv", "read_number_table", "write_csv"]

Array = npt.NDArray[np.float64]


def _global_choice(comm: MPI.Comm, key: Array) -> npt.NDArray[np.bool_]:
    """Mask of the points for which this rank holds the smallest key over all ranks."""
    best = np.empty_like(key)
    comm.Allreduce(key, best, op=MPI.MIN)
    return np.isfinite(key) & (key == best)


def _in_triangle(r: Array, e1: Array, e2: Array, eps: float = 1e-9) -> npt.NDArray[np.bool_]:
    """Whether ``a + r`` lies in the triangle ``a, a + e1, a + e2`` of its plane (to ``eps``).

    Arrays of 3-vectors along the last axis, broadcast against each other: one point against
    many triangles or many points against one. Barycentric coordinates by Cramer's rule.
    """
    g11, g12, g22 = (e1 * e1).sum(-1), (e1 * e2).sum(-1), (e2 * e2).sum(-1)
    b1, b2 = (r * e1).sum(-1), (r * e2).sum(-1)
    det = g11 * g22 - g12 * g12
    l1, l2 = (g22 * b1 - g12 * b2) / det, (g11 * b2 - g12 * b1) / det
    return (l1 >= -eps) & (l2 >= -eps) & (l1 + l2 <= 1 + eps)


#: 3D: a probe's line lies in a fracture's plane when both ends are within this fraction of the
#: scene's scale (line length or coordinates) of it. Coordinates of a line in an inclined
#: fracture written to 4-5 digits are ~5e-6 of the scale off its plane: with 1e-8 such a
#: probe had empty fracture columns and no warning.
PLANE_TOLERANCE = 1e-5


class LineSampler:
    """Sample points on the segment ``[start, end]`` and where they lie (collective).

    Args:
        msh: The mesh (triangles).
        start: First point (m).
        end: Last point (m).
        samples: Number of points (>= 2).
        faces: Optional ``(segments (nf, 2, 2), keys (nf,))`` of the owned fracture faces,
            with partition-independent keys (global face numbers).
        sides: Optional ``(vertices (nf, d, d), normals n⁺ (nf, d), keys (nf,))`` of the owned
            fracture faces (:func:`fracture_sides`): a point on one of them takes a cell on its
            ``+`` side.
    """

    def __init__(self, msh: dolfinx.mesh.Mesh, start, end, samples: int,
                 faces: tuple[Array, Array] | None = None,
                 sides: tuple[Array, Array, Array] | None = None):
        self.comm = msh.comm
        self.start, self.end = np.asarray(start, float), np.asarray(end, float)
        s = np.linspace(0.0, 1.0, samples)
        self.points = self.start + s[:, None] * (self.end - self.start)
        self.arc_length = s * float(np.linalg.norm(self.end - self.start))
        normals = None if sides is None else self._normals_at_points(*sides)
        self._cell, self._mine = self._locate_cells(msh, normals)
        self._face, self._face_mine = (None, None) if faces is None else self._locate_faces(*faces)

    def _normals_at_points(self, vertices: Array, normals: Array, keys: Array) -> Array:
        """``n⁺`` of the fracture face (lowest key) each point lies on; NaN off the fractures.

        Collective: the ranks holding the faces tell the others.
        """
        d = self.points.shape[1]
        scale = max(float(np.linalg.norm(self.end - self.start)),
                    float(np.abs(self.points).max(initial=0.0)), 1e-300)
        tol = 1e-9 * scale
        best = np.full(len(self.points), np.inf)
        mine = np.zeros((len(self.points), d))
        a = vertices[:, 0]
        for i, p in enumerate(self.points):  # the sample points: few
            if d == 2:
                e = vertices[:, 1] - a
                t = np.clip(np.einsum("ni,ni->n", p - a, e) / np.einsum("ni,ni->n", e, e), 0, 1)
                on = np.linalg.norm(p - a - t[:, None] * e, axis=1) <= tol
            else:
                on = np.abs(np.einsum("ni,ni->n", p - a, normals)) <= tol
                k = np.flatnonzero(on)  # in a face's plane: inside the triangle?
                on[k] = _in_triangle(p - a[k], vertices[k, 1] - a[k], vertices[k, 2] - a[k])
            if on.any():
                k = np.flatnonzero(on)[np.argmin(keys[on])]
                best[i], mine[i] = keys[k], normals[k]
        lowest = np.empty_like(best)
        self.comm.Allreduce(best, lowest, op=MPI.MIN)
        mine[~(np.isfinite(best) & (best == lowest))] = 0.0
        out = np.empty_like(mine)
        self.comm.Allreduce(mine, out, op=MPI.SUM)
        out[~np.isfinite(lowest)] = np.nan
        return out

    def _locate_cells(self, msh, normals: Array | None = None):
        """The owned cell of each point (see the module docstring) and which rank's it is.

        ``normals``: ``n⁺`` of the fracture face each point lies on (NaN elsewhere), whose
        ``+`` cell (centroid on the ``-n⁺`` side) is taken before the other.
        """
        nc = msh.topology.index_map(msh.topology.dim).size_local
        owned = np.arange(nc, dtype=np.int32)
        tree = dolfinx.geometry.bb_tree(msh, msh.topology.dim, entities=owned)
        x3 = np.column_stack([self.points, np.zeros((len(self.points), 3 - self.points.shape[1]))])
        candidates = dolfinx.geometry.compute_collisions_points(tree, x3)
        hits = dolfinx.geometry.compute_colliding_cells(msh, candidates, x3)
        orig = np.asarray(msh.topology.original_cell_index, dtype=np.float64)
        key = np.full(len(self.points), np.inf)
        cell = np.full(len(self.points), -1, dtype=np.int64)
        counts = np.diff(hits.offsets)
        other_side = float(msh.topology.index_map(msh.topology.dim).size_global)
        x, dofs = msh.geometry.x[:, :self.points.shape[1]], msh.geometry.dofmaps[0]
        for i in np.flatnonzero(counts):  # small: the number of sample points
            links = hits.links(i)
            links = links[links < nc]
            if len(links):
                rank = orig[links]
                if normals is not None and np.isfinite(normals[i, 0]):
                    side = (x[dofs[links]].mean(axis=1) - self.points[i]) @ normals[i]
                    rank = rank + np.where(side < 0.0, 0.0, other_side)
                j = int(np.argmin(rank))
                key[i], cell[i] = rank[j], links[j]
        return cell, _global_choice(self.comm, key)

    def _locate_faces(self, segments: Array, keys: Array):
        if segments.shape[-1] == 3:
            return self._locate_triangles(segments, keys)
        direction = self.end - self.start
        length = float(np.linalg.norm(direction))
        unit = direction / length
        normal = np.array([-unit[1], unit[0]])
        tol = 1e-8 * length
        rel = segments - self.start
        along = np.all(np.abs(rel @ normal) <= tol, axis=1)
        self._face_ends = rel @ unit  # arc length of the two ends of every face
        lo = self._face_ends.min(axis=1) - tol
        hi = self._face_ends.max(axis=1) + tol
        t = self.arc_length
        key = np.full(len(t), np.inf)
        face = np.full(len(t), -1, dtype=np.int64)
        for k in np.flatnonzero(along):  # faces on the line only
            inside = (t >= lo[k]) & (t <= hi[k]) & (keys[k] < key)
            key[inside], face[inside] = keys[k], k
        return face, _global_choice(self.comm, key)

    def _locate_triangles(self, triangles: Array, keys: Array):
        """3D: the fracture triangle holding each point, for a line lying in a fracture plane."""
        self._face_ends = None
        a = triangles[:, 0]
        e1, e2 = triangles[:, 1] - a, triangles[:, 2] - a
        normal = np.cross(e1, e2)
        normal /= np.linalg.norm(normal, axis=1)[:, None]
        # a line typed to a few digits in an inclined plane is off it by ~1e-5 of the scale
        tol = PLANE_TOLERANCE * max(float(np.linalg.norm(self.end - self.start)),
                                    float(np.abs(triangles).max(initial=1.0)))
        coplanar = ((np.abs(np.einsum("ni,ni->n", self.start - a, normal)) <= tol)
                    & (np.abs(np.einsum("ni,ni->n", self.end - a, normal)) <= tol))
        key = np.full(len(self.points), np.inf)
        face = np.full(len(self.points), -1, dtype=np.int64)
        for k in np.flatnonzero(coplanar):
            inside = _in_triangle(self.points - a[k], e1[k], e2[k]) & (keys[k] < key)
            key[inside], face[inside] = keys[k], k
        return face, _global_choice(self.comm, key)

    def _gather(self, local: Array, mine: npt.NDArray[np.bool_]) -> Array | None:
        values = np.where(mine, local, 0.0)
        found = mine.astype(np.float64)
        total = self.comm.reduce(values, op=MPI.SUM, root=0)
        count = self.comm.reduce(found, op=MPI.SUM, root=0)
        if self.comm.rank != 0:
            return None
        return np.where(count > 0, total, np.nan)

    def cells(self, values: Array, gradients: Array | None = None,
              centroids: Array | None = None) -> Array | None:
        """Cell data at the points, on rank 0 (collective).

        Args:
            values: One value per owned cell.
            gradients: Optional ``(nc, d)`` cell gradients for a linear reconstruction.
            centroids: Cell centres ``(nc, d)``, required with ``gradients``.
        """
        c = np.maximum(self._cell, 0)
        local = np.asarray(values)[c] if len(values) else np.zeros(len(c))
        if gradients is not None and len(values):
            local = local + np.einsum("ni,ni->n", gradients[c], self.points - centroids[c])
        return self._gather(local, self._mine)

    def function(self, u) -> Array | None:
        """A finite element function at the points, ``(samples, value size)`` on rank 0.

        Evaluated in the cell each point was assigned to (collective).
        """
        x3 = np.column_stack([self.points, np.zeros((len(self.points), 3 - self.points.shape[1]))])
        size = max(1, int(np.prod(u.ufl_shape)))
        local = np.zeros((len(self.points), size))
        mine = np.flatnonzero(self._mine)
        if len(mine):
            local[mine] = u.eval(x3[mine], self._cell[mine].astype(np.int32)).reshape(-1, size)
        columns = [self._gather(local[:, k], self._mine) for k in range(size)]
        return None if self.comm.rank else np.column_stack(columns)

    def faces(self, values: Array, end_values: Array | None = None) -> Array | None:
        """Face data where the line runs along a fracture, on rank 0 (collective).

        Args:
            values: One value per owned face (at its midpoint).
            end_values: Optional ``(nf, 2)`` values at the face ends (same order as the
                segments): the result is then linear between each end and the midpoint (2D;
                in 3D the face value holds on the whole triangle).
        """
        if self._face is None:
            return None if self.comm.rank else np.full(len(self.points), np.nan)
        f = np.maximum(self._face, 0)
        local = np.asarray(values)[f] if len(values) else np.zeros(len(f))
        if end_values is not None and len(values) and self._face_ends is not None:
            s0, s1 = self._face_ends[f, 0], self._face_ends[f, 1]
            mid = 0.5 * (s0 + s1)
            near1 = np.abs(self.arc_length - s1) < np.abs(self.arc_length - s0)
            s_end = np.where(near1, s1, s0)
            v_end = np.where(near1, end_values[f, 1], end_values[f, 0])
            w = np.clip((self.arc_length - mid) / np.where(s_end != mid, s_end - mid, 1.0), 0, 1)
            local = (1.0 - w) * local + w * v_end
        return self._gather(local, self._face_mine)


def write_csv(path: Path, columns: dict[str, Array]) -> None:
    """Write columns to a CSV file (call on one rank); NaN becomes an empty field."""
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], dtype=float) for n in names])
    lines = [",".join(names)]
    for row in data:
        lines.append(",".join("" if np.isnan(v) else f"{v:.12g}" for v in row))
    Path(path).write_text("\n".join(lines) + "\n")


def read_csv(path: Path) -> tuple[list[str], np.ndarray]:
    """Header and float data of a CSV file (empty fields become NaN)."""
    with open(path) as f:
        rows = list(csv.reader(f))
    data = np.array([[float(v) if v.strip() else np.nan for v in r] for r in rows[1:]])
    return [h.strip() for h in rows[0]], data


def read_number_table(path: Path) -> np.ndarray:
    """Rows of numbers of a comma-separated file without header; Fortran ``D`` exponents allowed.

    The format of the 3D fracture-flow benchmark's data (Berre et al. 2021): ``*_dol_*.csv``
    hold curves along a line as (arc length, value) column pairs (``0.40000D+01`` is 4.0),
    ``*_results*.csv`` a row of cell counts and unknowns per refinement. Blank lines are skipped,
    and so is one trailing comma of a line (some participants' files end their rows with one).

    Raises:
        ValueError: A field is not a number, or the rows differ in length.
    """
    rows = []
    with open(path) as f:
        for k, line in enumerate(f, start=1):
            if not line.strip():
                continue
            try:
                rows.append([float(v.strip().replace("D", "e").replace("d", "e"))
                             for v in line.rstrip().removesuffix(",").split(",")])
            except ValueError:
                raise ValueError(f"{path}, line {k}: not a row of numbers: {line.strip()!r}")\
                    from None
    if len({len(r) for r in rows}) > 1:
        raise ValueError(f"{path}: rows of different lengths")
    return np.array(rows, dtype=np.float64)


def line_differences(s_ref, p_ref, s, p, keep=None) -> dict[str, float]:
    """Differences along a line, trapezoidal rule on the reference points.

    Returns ``rel`` = ‖p - p_ref‖ / ‖p_ref‖ and ``range`` = ‖p - p_ref‖ / (|line|^½ Δp_ref)
    with Δp_ref = max - min of the reference (the normalization of Flemisch et al. 2018),
    both in L² along the line; ``keep`` restricts the integral to a mask of reference points.
    """
    ok = np.isfinite(p)
    q = np.interp(s_ref, s[ok], p[ok])
    w = np.zeros_like(s_ref)
    ds = np.diff(s_ref)
    w[:-1] += 0.5 * ds
    w[1:] += 0.5 * ds
    if keep is not None:
        w = w * keep
    err = np.sqrt(np.sum(w * (q - p_ref) ** 2))
    return {
        "rel": float(err / np.sqrt(np.sum(w * p_ref**2))),
        "range": float(err / np.sqrt(np.sum(w)) / (p_ref.max() - p_ref.min())),
    }


class ProbeTable:
    """``probe_<name>.csv``: the columns of a probe line, a block of rows per output time.

    Collective :meth:`write`; rank 0 appends each time in one write. After a restart the rows up
    to ``resume_until`` are kept.

    Args:
        comm: Communicator.
        path: The CSV file.
        sampler: The probe line.
        resume_until: When continuing a run, keep the rows up to this time; None starts anew.
    """

    def __init__(self, comm: MPI.Comm, path: Path, sampler: LineSampler,
                 resume_until: float | None = None):
        self.comm, self.path, self.sampler = comm, Path(path), sampler
        self._resume_until = resume_until
        self._header: list[str] | None = None

    def _start(self, header: list[str]) -> None:
        """The header, and the rows of an earlier run up to ``resume_until`` (rank 0)."""
        keep = ""
        if self._resume_until is not None and self.path.exists():
            # the time as the rows print it (66.66666666666667 prints above it, 66.6666666667)
            limit = float(f"{self._resume_until:.12g}")
            keep = "".join(line for line in self.path.read_text().splitlines(True)[1:]
                           if float(line.split(",", 1)[0]) <= limit)
        atomic_write_text(self.path, ",".join(header) + "\n" + keep)

    def write(self, t: float, columns: dict[str, Array | None]) -> None:
        """Append the rows of time ``t`` (collective).

        ``columns`` maps a name to the values at the points on rank 0 (as the sampler gathers
        them), None on the other ranks.
        """
        s = self.sampler
        coords = dict(zip("xyz", s.points.T, strict=False))
        table = {"arc_length": s.arc_length, **coords, **columns}
        if self._header is None:
            self._header = ["time", *table]
            root_write(self.comm, self._start, self._header)
        root_write(self.comm, self._append, t, table)

    def _append(self, t: float, table: dict[str, Array]) -> None:
        data = np.column_stack([np.full(len(self.sampler.points), t)]
                               + [np.asarray(v, dtype=float) for v in table.values()])
        buf = io.StringIO()
        for row in data:
            buf.write(",".join("" if np.isnan(v) else f"{v:.12g}" for v in row) + "\n")
        try:
            with open(self.path, "a") as fh:
                fh.write(buf.getvalue())
        except OSError as err:
            raise OutputError(f"could not write {self.path}: {os.strerror(err.errno)}") from None


def fracture_sides(fm) -> tuple[Array, Array, Array]:
    """The owned fracture faces of ``fm`` as a :class:`LineSampler`'s ``sides`` (local)."""
    faces = fm.fractures
    return (fracture_segments(fm.msh, faces.facets), faces.normal,
            faces.index.astype(np.float64))


def open_probes(msh: dolfinx.mesh.Mesh, probes, outdir: Path, faces: tuple[Array, Array] | None,
                resume_until: float | None = None,
                sides: tuple[Array, Array, Array] | None = None) -> list[tuple]:
    """The probe lines of a scene and their files: ``[(probe, table), ...]`` (collective).

    Args:
        msh: The mesh.
        probes: The scene's ``probes``.
        outdir: Output directory (``probe_<name>.csv``).
        faces: The owned fracture faces as ``(segments (nf, 2, 2), keys)`` in 2D or
            ``(triangles (nf, 3, 3), keys)`` in 3D, or None.
        resume_until: When continuing a run, keep the rows up to this time.
        sides: The owned fracture faces with their normals (:func:`fracture_sides`), for the
            side a point on a fracture is read from.
    """
    return [(p, ProbeTable(msh.comm, Path(outdir) / f"probe_{p.name}.csv",
                           LineSampler(msh, p.start, p.end, p.samples, faces, sides),
                           resume_until))
            for p in probes]
