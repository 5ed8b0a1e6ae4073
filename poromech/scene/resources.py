"""Size of a run before meshing: cells, unknowns and memory, against the memory of the machine.

A scene that cannot fit (``mesh.refinement: 7``, ``mesh.size: 1e-4`` on a unit square) is
refused in one line, with the estimate and the limit, instead of running for minutes and being
killed. The estimates:

* **cells** — gmsh's frontal-Delaunay triangles of edge length ``h`` have area about
  ``√3/4 h²``, so ``cells ≈ C ∫_Ω h(x)⁻² dx`` (:data:`CELLS_PER_AREA` = ``C``). The size field of
  :mod:`poromech.mesh.generate` grows linearly from ``fracture_size`` on a fracture
  (``tip_size`` at a fracture end or junction) to ``size`` at the distance ``transition``; the
  integral is the domain at ``size`` plus, in closed form, the excess of a band along every
  fracture, of a disc at every fracture end, and of each mesh zone (the fracture area or length
  in its ball with a slab or band of its size, or the whole ball). Each ``mesh.refinement``
  level multiplies by 4. On the shipped
  scenes and graded variants of them, the estimate is within 15 % of gmsh's count.
* **unknowns** — P2 displacements: 4 per cell (2 × (vertices + edges) ≈ 2 × 2 cells); P1: 1 per
  cell; HFV flow: cells + faces ≈ 2.5 per cell.
* **memory** — :data:`BASE_BYTES` per rank (Python, PETSc, MPI) plus, per unknown of a direct
  (MUMPS) solve, ``DIRECT_BYTES_LOG · log₂ n`` bytes (nested-dissection fill of 2D problems
  grows as ``n log n``), or :data:`ITERATIVE_BYTES` for the flow's CG + GAMG. Fitted to
  measured peak memory of the six-fracture scene at refinements 0-3 (P1, P2 and flow).
  In 3D rank 0 first meshes the whole body (gmsh, the mesh arrays, the cracked topology:
  :data:`MESH_BYTES_PER_CELL_3D`) and then holds its share of the solve (MUMPS:
  :data:`DIRECT_BYTES_3D` ``n^{4/3}``; CG + GAMG: :data:`ITERATIVE_BYTES_3D` ``n``), so the
  peak summed over ``R`` ranks is ``R·BASE + max(mesh, solve/R) + solve·(R-1)/R``. Fitted to
  the peak memory (max RSS summed over ranks) of the P2 penny crack from 16k to 1M unknowns,
  on 1 and 2 ranks, direct and iterative: every estimate within a factor 1.2 of the measurement
  (docs/mechanics3d/solvers.md).

The limit is the memory the machine has available (``MemAvailable``), or the cgroup limit or the
address-space limit (``ulimit -v``) when lower, summed over the nodes of the run.
"""

from __future__ import annotations

import logging
import math
import resource
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import combinations
from pathlib import Path

import numpy as np
from mpi4py import MPI

from poromech.geometry.box import BoxGeometry
from poromech.geometry.plane import PlaneGeometry
from poromech.mesh.generate import CELLS_PER_AREA, SizeZone
from poromech.scene.geometry import mesh_sizes
from poromech.scene.schema import ITERATIVE_FROM_UNKNOWNS_3D, scene_dimension

__all__ = [
    "ELIMINATED_FORMULATIONS",
    "ITERATIVE_FORMULATIONS",
    "ITERATIVE_FROM_UNKNOWNS_3D",
    "ResourceError",
    "RunEstimate",
    "available_memory",
    "check_resources",
    "direct_fallback_fits",
    "direct_solve_bytes",
    "direct_solve_bytes_3d",
    "estimate_cells",
    "estimate_run",
    "mechanics_solver",
]

log = logging.getLogger("poromech")

#: Tetrahedra per unit of ``∫ h⁻³`` (gmsh's Delaunay meshes of fractured boxes give 6-8; a
#: regular tetrahedron of edge h has volume h³/(6√2), 8.5 per h³).
CELLS_PER_VOLUME = 7.0
#: Displacement unknowns per cell, (dimension, degree): P2 triangles 2 × (vertices + edges) ≈ 4
#: per cell; P2 tetrahedra 3 × (vertices + edges) ≈ 4.5 (vertices ≈ cells/5.5, edges ≈
#: vertices + cells); P1 tetrahedra 3 × vertices ≈ 0.55.
UNKNOWNS_PER_CELL = {(2, 1): 1.0, (2, 2): 4.0, (3, 1): 0.55, (3, 2): 4.5}
#: Bytes per ``n^{4/3}`` of a direct solve in 3D (nested-dissection fill grows as ``n^{4/3}``;
#: MUMPS on the P2 penny crack: 1.7 GB at 79k and 5.1 GB at 192k unknowns, peak of the process).
DIRECT_BYTES_3D = 380.0
#: Bytes per unknown of an iterative (CG + GAMG) elastic solve in 3D (matrix, hierarchy, vectors;
#: the P2 penny crack: 3.2 GB at 1.0M unknowns on 1 rank, 5.0 GB summed over 2 ranks).
ITERATIVE_BYTES_3D = 2400.0
#: Bytes per (estimated) tetrahedron on rank 0 while it meshes the body: gmsh, the mesh arrays,
#: the cracked topology and the distribution.
MESH_BYTES_PER_CELL_3D = 6700.0
#: Memory of one rank before any mesh (interpreter, PETSc, MPI, compiled forms), bytes.
BASE_BYTES = 250e6
#: Bytes per unknown and per ``log₂(unknowns)`` of a direct solve (matrix, factors, vectors).
DIRECT_BYTES_LOG = 180.0
#: Bytes per unknown of an iterative (CG + GAMG) flow solve.
ITERATIVE_BYTES = 1000.0
#: Bytes per cell held by gmsh and the distributed mesh on rank 0.
MESH_BYTES_PER_CELL = 600.0


class ResourceError(RuntimeError):
    """A run that does not fit in memory; the message is one line."""


@dataclass(frozen=True)
class RunEstimate:
    """What a scene will need.

    Attributes:
        cells: Triangles of the mesh.
        unknowns: Unknowns of the largest solve (mechanics and flow summed for a coupled run).
        memory: Peak memory over all ranks together (bytes).
    """

    cells: float
    unknowns: float
    memory: float


def _band_excess(size: float, near: float, transition: float) -> float:
    """``∫ (h(d)⁻² - size⁻²)`` over ``0 <= d <= transition`` for ``h`` linear from ``near``."""
    if near >= size:
        return 0.0
    return transition / (near * size) - transition / size**2


def _disc_excess(size: float, near: float, transition: float) -> float:
    """``∫ 2πr (h(r)⁻² - size⁻²) dr`` over the disc of radius ``transition`` around a point."""
    if near >= size:
        return 0.0
    k = (size - near) / transition
    return 2 * math.pi / k**2 * (math.log(size / near) - 1 + near / size) \
        - math.pi * transition**2 / size**2


def _polygon_area(p: np.ndarray) -> float:
    x, y = p[:, 0], p[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def _cross(u: np.ndarray, v: np.ndarray) -> float:
    return float(u[0] * v[1] - u[1] * v[0])


def _crossings(geo: PlaneGeometry) -> int:
    """Number of crossings between segments of different fractures (junction points)."""
    segs = [(k, p[i], p[i + 1]) for k, p in enumerate(geo.fractures) for i in range(len(p) - 1)]
    count = 0
    for (k, a, b), (m, c, d) in combinations(segs, 2):
        if k == m:
            continue
        d1 = _cross(b - a, c - a) * _cross(b - a, d - a)
        d2 = _cross(d - c, a - c) * _cross(d - c, b - c)
        count += d1 < 0 and d2 < 0
    return count


def _slab_excess(size: float, near: float, transition: float) -> float:
    """``∫ (h(d)⁻³ - size⁻³)`` over ``0 <= d <= transition`` for ``h`` linear from ``near``."""
    if near >= size:
        return 0.0
    k = (size - near) / transition
    return (near**-2 - size**-2) / (2 * k) - transition / size**3


def _tube_excess(size: float, near: float, transition: float) -> float:
    """``∫ 2πr (h(r)⁻³ - size⁻³) dr`` over the disc of radius ``transition`` around a curve."""
    if near >= size:
        return 0.0
    k = (size - near) / transition
    return 2 * math.pi / k**2 * (0.5 / near - 1 / size + near / (2 * size**2)) \
        - math.pi * transition**2 / size**3


def _tip_length(fracture) -> float:
    """Length of a fracture's edge (disc rim or polygon perimeter), m."""
    if fracture.is_disc:
        return 2 * math.pi * fracture.radius
    p = fracture.points
    return float(np.linalg.norm(np.roll(p, -1, axis=0) - p, axis=1).sum())


def _zones_excess_3d(geo: BoxGeometry, size: float, fracture_size: float, transition: float,
                     zones: Sequence[SizeZone]) -> float:
    """``∫ (h⁻³ - size⁻³)`` added by the zones.

    On fractures: the fracture area in the ball (the disc where its plane cuts the ball, at most
    the fracture) with its slab of ``zone.size``; else the ball with a shell of ``transition``.
    """
    out = 0.0
    for z in zones:
        c = np.asarray(z.center, dtype=float)
        if not z.on_fractures:
            out += 4 / 3 * math.pi * z.radius**3 * (z.size**-3 - size**-3) \
                + 4 * math.pi * z.radius**2 * _slab_excess(size, z.size, z.transition)
            continue
        extra = max(_slab_excess(size, z.size, z.transition)
                    - _slab_excess(size, fracture_size, transition), 0.0)
        for f in geo.fractures:
            d = abs(float(f.height(c[None, :])[0]))
            if d < z.radius:
                out += 2 * min(f.area, math.pi * (z.radius**2 - d**2)) * extra
    return out


def _zones_excess_2d(geo: PlaneGeometry, size: float, fracture_size: float, transition: float,
                     zones: Sequence[SizeZone]) -> float:
    """``∫ (h⁻² - size⁻²)`` added by the zones.

    On fractures: the fracture length in the disc with its band of ``zone.size``; else the disc
    with a ring of ``transition``.
    """
    out = 0.0
    for z in zones:
        c = np.asarray(z.center[:2], dtype=float)
        if not z.on_fractures:
            out += math.pi * z.radius**2 * (z.size**-2 - size**-2) \
                + 2 * math.pi * z.radius * _band_excess(size, z.size, z.transition)
            continue
        extra = max(_band_excess(size, z.size, z.transition)
                    - _band_excess(size, fracture_size, transition), 0.0)
        for pts in geo.fractures:
            for a, b in zip(pts[:-1], pts[1:], strict=True):
                out += 2 * _chord_in_disc(a, b, c, z.radius) * extra
    return out


def _chord_in_disc(a: np.ndarray, b: np.ndarray, c: np.ndarray, r: float) -> float:
    """Length of the part of the segment ``[a, b]`` in the disc of centre ``c``, radius ``r``."""
    d = b - a
    dd = float(d @ d)
    if dd == 0.0:
        return 0.0
    t = float((c - a) @ d) / dd
    h2 = float(np.sum((a + t * d - c) ** 2))
    if h2 >= r * r:
        return 0.0
    half = math.sqrt((r * r - h2) / dd)
    return max(0.0, min(1.0, t + half) - max(0.0, t - half)) * math.sqrt(dd)


def estimate_cells_3d(geo: BoxGeometry, size: float, fracture_size: float, tip_size: float,
                      transition: float, refinement: int,
                      zones: Sequence[SizeZone] = ()) -> float:
    """Expected number of tetrahedra of the gmsh mesh of a fractured box (module docstring)."""
    volume = float(np.prod(geo.upper - geo.lower))
    density = volume / size**3
    for f in geo.fractures:
        density += 2 * f.area * _slab_excess(size, fracture_size, transition)
        tip = _tube_excess(size, tip_size, transition) - _tube_excess(size, fracture_size,
                                                                      transition)
        density += _tip_length(f) * max(tip, 0.0)
    density += _zones_excess_3d(geo, size, fracture_size, transition, zones)
    finest = min([size, fracture_size, tip_size] + [z.size for z in zones])
    density = min(density, volume / finest**3)
    return CELLS_PER_VOLUME * density * 8.0**refinement


def estimate_cells(geo: PlaneGeometry, size: float, fracture_size: float, tip_size: float,
                   transition: float, refinement: int,
                   zones: Sequence[SizeZone] = ()) -> float:
    """Expected number of triangles of the gmsh mesh of ``geo`` (see the module docstring)."""
    if isinstance(geo, BoxGeometry):
        return estimate_cells_3d(geo, size, fracture_size, tip_size, transition, refinement,
                                 zones)
    area = _polygon_area(geo.boundary)
    density = area / size**2
    length = float(geo.fracture_lengths().sum()) if geo.fractures else 0.0
    density += 2 * length * _band_excess(size, fracture_size, transition)
    if geo.fractures:
        ends = len({tuple(p) for pts in geo.fractures for p in pts}) + _crossings(geo)
        # a fracture end is already inside the band of fracture_size: only the tip excess
        tip = _disc_excess(size, tip_size, transition) - _disc_excess(size, fracture_size,
                                                                      transition)
        density += ends * max(tip, 0.0)
    density += _zones_excess_2d(geo, size, fracture_size, transition, zones)
    finest = min([size, fracture_size, tip_size] + [z.size for z in zones])
    density = min(density, area / finest**2)
    return CELLS_PER_AREA * density * 4.0**refinement


#: Contact formulations solved by a Krylov method with GAMG and the rigid-body modes: those with
#: displacement unknowns only, and those whose face unknowns (averages, and the multipliers of
#: ``stabilized_mixed``) are eliminated exactly face by face (:data:`ELIMINATED_FORMULATIONS`).
#: ``mixed`` is solved directly: its multiplier rows have no multiplier derivative on faces in
#: contact, so its face block cannot be inverted.
ITERATIVE_FORMULATIONS = ("none", "nitsche", "mean_nitsche", "stabilized_mixed")
#: Formulations whose iterative solve works on the displacement Schur complement
#: (:class:`~poromech.mechanics.linear.FaceElimination`).
ELIMINATED_FORMULATIONS = ("mean_nitsche", "stabilized_mixed")


def mechanics_solver(scene, unknowns: float) -> str:
    """``direct`` or ``iterative``: ``solver.linear_solver``, or chosen by dimension and size.

    ``auto`` is iterative for a 3D system of a formulation of :data:`ITERATIVE_FORMULATIONS` of
    more than :data:`ITERATIVE_FROM_UNKNOWNS_3D` unknowns, direct otherwise (every 2D scene).
    Called before meshing with the estimated unknowns (memory) and after it with the actual
    ones (the solver that runs).
    """
    choice = scene.solver.linear_solver
    if choice != "auto":
        return choice
    iterative = (scene_dimension(scene) == 3 and scene.contact.formulation in ITERATIVE_FORMULATIONS
                 and unknowns > ITERATIVE_FROM_UNKNOWNS_3D)
    return "iterative" if iterative else "direct"


def _direct_bytes(n: float) -> float:
    return n * DIRECT_BYTES_LOG * math.log2(max(n, 2.0))


def estimate_run(scene, geo: PlaneGeometry, ranks: int = 1) -> RunEstimate:
    """Cells, unknowns and peak memory of a scene on ``ranks`` ranks (local, no meshing)."""
    m = mesh_sizes(scene)
    try:
        cells = estimate_cells(geo, m.size, m.fracture_size, m.tip_size, m.transition,
                               m.refinement, m.zones)
    except (ZeroDivisionError, OverflowError):  # a size whose square or cube is below 1e-308
        cells = math.inf
    if geo.dim == 3:
        return _estimate_3d(scene, cells, ranks)
    memory = ranks * BASE_BYTES + MESH_BYTES_PER_CELL * cells
    unknowns = 0.0
    if scene.physics in ("mechanics", "poromechanics"):
        mech = UNKNOWNS_PER_CELL[(geo.dim, scene.degree)] * cells
        unknowns += mech
        memory += _direct_bytes(mech)
    if scene.physics in ("flow", "poromechanics") and scene.flow is not None:
        flow = 2.5 * cells
        unknowns += flow
        direct = scene.flow.linear_solver == "direct"
        memory += _direct_bytes(flow) if direct else ITERATIVE_BYTES * flow
    return RunEstimate(cells, unknowns, memory)


#: A run whose Krylov solve failed is handed to MUMPS LU (``solver.linear_solver`` and
#: ``flow.linear_solver`` ``auto``) only when this many times the factorization's estimated
#: memory is available (the estimate was within a factor 1.2 of the measured peaks): a run that
#: would not fit fails with the Krylov method's message instead of being killed for want of
#: memory.
FALLBACK_MEMORY_MARGIN = 1.5


def direct_fallback_fits(unknowns: int, dim: int, comm: MPI.Comm) -> tuple[bool, str]:
    """Whether a MUMPS LU of ``unknowns`` fits now, and the figures for a message.

    :data:`FALLBACK_MEMORY_MARGIN` times the estimate must be available; the figures read
    ``about 0.02 GB for 8683 unknowns, 24.1 GB available, <limit>`` (collective).
    """
    need = direct_solve_bytes(unknowns, dim)
    available, limit = available_memory(comm)
    return (FALLBACK_MEMORY_MARGIN * need <= available,
            f"about {need / 1e9:.2g} GB for {unknowns} unknowns, {available / 1e9:.3g} GB "
            f"available, {limit}")


def direct_solve_bytes(unknowns: float, dim: int) -> float:
    """Memory of a MUMPS solve over all ranks: ``n log₂ n`` in 2D, ``n^{4/3}`` in 3D."""
    return direct_solve_bytes_3d(unknowns) if dim == 3 else _direct_bytes(unknowns)


def direct_solve_bytes_3d(unknowns: float) -> float:
    """Memory of a 3D MUMPS solve over all ranks: :data:`DIRECT_BYTES_3D` ``n^{4/3}`` bytes."""
    return DIRECT_BYTES_3D * unknowns ** (4 / 3)


def _estimate_3d(scene, cells: float, ranks: int) -> RunEstimate:
    """3D (mechanics only): rank 0's meshing peak, or its share of the solve, plus the others'."""
    unknowns = UNKNOWNS_PER_CELL[(3, scene.degree)] * cells
    if mechanics_solver(scene, unknowns) == "direct":
        solve = direct_solve_bytes_3d(unknowns)
    else:
        solve = ITERATIVE_BYTES_3D * unknowns
    others = solve * (ranks - 1) / ranks if ranks > 1 else 0.0  # (inf * 0 would be nan)
    memory = ranks * BASE_BYTES + max(MESH_BYTES_PER_CELL_3D * cells, solve / ranks) + others
    return RunEstimate(cells, unknowns, memory)


def _meminfo(key: str) -> float | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith(key + ":"):
                return float(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def _read_number(path: str) -> float | None:
    try:
        text = Path(path).read_text().strip()
    except OSError:
        return None
    return float(text) if text.isdigit() else None


def _cgroup_available() -> float | None:
    """Memory left under the cgroup limit (v2, else v1), None without a limit."""
    for limit, usage in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                         ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                          "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        cap = _read_number(limit)
        if cap is not None and cap < 2**60:
            return cap - (_read_number(usage) or 0.0)
    return None


def _address_space_available() -> float | None:
    """Address space left under ``ulimit -v`` for this process, None without a limit."""
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY:
        return None
    used = 0.0
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmSize:"):
                used = float(line.split()[1]) * 1024
    except OSError:
        pass
    return soft - used


def available_memory(comm: MPI.Comm = MPI.COMM_WORLD) -> tuple[float, str]:
    """Memory the run may use, summed over its nodes, and where the limit comes from (collective).

    Returns:
        Bytes, and the name of the binding limit (``MemAvailable``, ``cgroup``, ``ulimit -v``).
    """
    node = comm.Split_type(MPI.COMM_TYPE_SHARED)
    try:
        ranks_here = node.size
        leader = node.rank == 0
    finally:
        node.Free()
    limits = {"MemAvailable": _meminfo("MemAvailable"), "cgroup": _cgroup_available()}
    per_rank = _address_space_available()
    if per_rank is not None:
        limits["ulimit -v"] = per_rank * ranks_here
    known = {k: v for k, v in limits.items() if v is not None}
    name, value = min(known.items(), key=lambda kv: kv[1]) if known else ("unknown", math.inf)
    total = comm.allreduce(max(value, 0.0) if leader else 0.0, op=MPI.SUM)
    names = comm.allgather(name)
    return total, min(set(names), key=names.index)


def _gb(x: float) -> str:
    return f"{x / 1e9:.3g} GB"


def check_resources(scene, geo: PlaneGeometry, comm: MPI.Comm = MPI.COMM_WORLD,
                    force: bool = False) -> RunEstimate:
    """Refuse a scene whose estimated memory exceeds what the machine has (collective).

    Args:
        scene: The validated scene.
        geo: Its plane geometry.
        comm: Communicator of the run.
        force: Only warn instead of refusing.

    Returns:
        The estimate (identical on every rank).

    Raises:
        ResourceError: On every rank, when the estimate exceeds the available memory.
    """
    est = estimate_run(scene, geo, comm.size)
    limit, source = available_memory(comm)
    m = scene.mesh
    log.debug("estimate: %.3g cells, %.3g unknowns, %s of memory (%s available, %s)",
              est.cells, est.unknowns, _gb(est.memory), _gb(limit), source)
    if est.memory <= limit:
        return est
    # the sizes that set the count: the finer fracture and tip sizes too, when given
    finer = "".join(f", mesh.{key} = {value:g}" for key, value in
                    (("fracture_size", m.fracture_size), ("tip_size", m.tip_size))
                    if value is not None and value < m.size)
    zones = (f", mesh.zones down to size {min(z.size for z in m.zones):g}" if m.zones else "")
    text = (f"scene mesh (mesh.size = {m.size:g}{finer}, mesh.refinement = {m.refinement}{zones}) "
            "gives "
            f"~{est.cells:.2g} cells and ~{est.unknowns:.2g} unknowns, estimated to need "
            f"~{_gb(est.memory)} of memory, more than the {_gb(limit)} available ({source})")
    if force:
        log.warning("%s; running anyway (--force)", text)
        return est
    raise ResourceError(f"{text}: coarsen the mesh or pass --force to run anyway")
