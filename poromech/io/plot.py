"""Pictures of a run: the deformed mesh with its fractures, the jumps along them, the pressure.

``poromech plot OUTDIR`` (and :func:`plot_run`) writes, for one output time (the last by
default), the PNGs that a run's outputs allow:

* ``deformed_t<T>.png`` — the mesh displaced by ``scale · u`` and coloured by ``|u|``, with
  every fracture face drawn on both sides, each side where its own nodes of the duplicated-node
  displacement mesh have moved, coloured by contact state (blue open, green stick, red slip, as
  in Fig. 2 of Beaude et al. 2023);
* ``jumps_t<T>.png`` — normal and tangential jumps along each fracture, faces coloured by state;
* ``pressure_t<T>.png`` — matrix pressure ``p_m`` per cell, fracture pressure ``p_f`` on the
  fractures (flow and coupled runs);
* in 3D, ``opening_t<T>.png`` — the fracture triangles in perspective, coloured by their
  opening ``-jump_n``, instead of the deformed mesh; the jumps are drawn against the distance
  from each fracture's centre.

Each picture is described once, backend-neutral (:class:`Picture`), and drawn by pyvista
(off-screen VTK) or, when pyvista/VTK cannot be imported or cannot render off-screen, by
matplotlib. Both come with the ``plot`` extra (``pip install 'poromech[plot]'``). Reading is
serial (:mod:`poromech.io.results`); nothing here needs DOLFINx.
"""

from __future__ import annotations

import ctypes.util
import importlib
import logging
import os
from dataclasses import dataclass, field
from itertools import chain
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from poromech.io.results import STATES, Results, open_results
from poromech.io.xdmf import Series

__all__ = [
    "BACKENDS",
    "STATE_COLORS",
    "Faces3D",
    "FractureEdges",
    "Lines",
    "Picture",
    "PlotError",
    "Surface",
    "choose_backend",
    "deformed_picture",
    "draw",
    "draw_3d",
    "fracture_edges",
    "limit_size",
    "mesh_edges",
    "nice_scale",
    "opening_picture",
    "plot_jumps",
    "plot_run",
    "pressure_picture",
]

log = logging.getLogger("poromech")

#: Contact-state colours, indexed by state code (open, stick, slip): Fig. 2 of the paper.
STATE_COLORS = ((0.12, 0.47, 0.71), (0.17, 0.63, 0.17), (0.84, 0.15, 0.16))

BACKENDS = ("auto", "pyvista", "matplotlib")

#: What to install when no backend can be imported (one line, for the command line).
INSTALL_HINT = ("poromech plot needs matplotlib (pictures) and, for VTK rendering, pyvista: "
                "pip install 'poromech[plot]'  (or: pip install matplotlib pyvista)")

#: Size of the field pictures (pixels).
WINDOW = (1400, 800)

#: Largest PNG written (bytes): a larger picture is reduced to a 256-colour palette.
MAX_PNG_BYTES = 300_000

#: The P2 triangle split into four sub-triangles by :func:`poromech.io.output.displacement_mesh`:
#: sub-triangles 0-2 hold one vertex each, sub-triangle 3 is the middle one, ``[5, 3, 4]``.
#: These six half-edges (local nodes of sub-triangles 0, 1, 2) are the triangle's boundary.
_P2_BOUNDARY = ((0, 0, 1), (0, 2, 0), (1, 0, 1), (1, 1, 2), (2, 1, 2), (2, 2, 0))


class PlotError(RuntimeError):
    """A picture cannot be made (a missing package, a series the run did not write)."""


# -- geometry of the outputs -----------------------------------------------------------------
@dataclass(frozen=True)
class FractureEdges:
    """The edges of the displacement output mesh that lie on fracture faces, one per side.

    The mesh has duplicated nodes across the fractures, so each side of a fracture face is a
    chain of its own edges (two per side for P2, one for P1), each in exactly one triangle.

    Attributes:
        nodes: Displacement-mesh points of each edge, ``(k, 2)``.
        face: The fracture face (cell of the ``fractures`` series) each edge lies on, ``(k,)``.
        side: +1 on the ``+`` side (the side ``n⁺``, the left normal of the polyline
            direction, points out of), -1 on the ``−`` side, ``(k,)``.
    """

    nodes: npt.NDArray[np.int64]
    face: npt.NDArray[np.int64]
    side: npt.NDArray[np.int8]


def fracture_edges(points: npt.NDArray, cells: npt.NDArray,
                   face_points: npt.NDArray) -> FractureEdges:
    """Find the edges of a cracked triangle mesh that lie on the fracture faces.

    Args:
        points: Points of the displacement mesh, ``(n, 2)`` (m).
        cells: Its triangles, ``(m, 3)``.
        face_points: Points of the fracture mesh, ``(2F, 2)``: face ``i`` runs from point
            ``2i`` to ``2i + 1`` in the direction of its polyline.
    """
    points = np.asarray(points)[:, :2]
    edges = np.asarray(cells)[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2)
    opposite = np.asarray(cells)[:, [2, 0, 1]].ravel()
    key = np.sort(edges, axis=1) @ np.array([len(points), 1])
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    once = counts[inverse] == 1  # in one triangle only: outer boundary or a fracture side
    edges, opposite = edges[once], opposite[once]
    mid = points[edges].mean(axis=1)
    a, b = face_points[0::2, :2], face_points[1::2, :2]
    diameter = np.ptp(points, axis=0).max()
    tol = 1e-8 * diameter
    near = cKDTree(0.5 * (a + b)).query_ball_point(
        mid, 0.5 * np.linalg.norm(b - a, axis=1).max() + tol)
    counts = np.fromiter(map(len, near), dtype=np.int64, count=len(near))
    edge = np.repeat(np.arange(len(mid)), counts)
    face = np.fromiter(chain.from_iterable(near), dtype=np.int64, count=counts.sum())
    hit = _distance_to_segment(mid[edge], a[face], b[face]) < tol
    edge, face = edge[hit], face[hit]
    edge, first = np.unique(edge, return_index=True)
    face = face[first]
    t = b[face] - a[face]
    c = points[opposite[edge]] - a[face]
    side = np.where(t[:, 0] * c[:, 1] - t[:, 1] * c[:, 0] < 0, 1, -1).astype(np.int8)
    return FractureEdges(edges[edge].astype(np.int64), face, side)


def _distance_to_segment(x: npt.NDArray, a: npt.NDArray, b: npt.NDArray) -> npt.NDArray:
    """Distance from each point ``x[i]`` to the segment ``[a[i], b[i]]``."""
    ab = b - a
    s = np.clip(np.einsum("ij,ij->i", x - a, ab) / np.einsum("ij,ij->i", ab, ab), 0.0, 1.0)
    return np.linalg.norm(x - a - s[:, None] * ab, axis=1)


def mesh_edges(cells: npt.NDArray) -> npt.NDArray[np.int64]:
    """Edges to draw as the mesh: the cell edges (the P2 sub-triangles' outer half-edges).

    A displacement mesh written by :func:`poromech.io.output.displacement_mesh` for P2 holds four
    sub-triangles per cell; its interior sub-edges are not mesh edges and are left out.
    """
    cells = np.asarray(cells)
    if _is_p2_split(cells):
        quads = cells.reshape(-1, 4, 3)
        edges = np.stack([np.column_stack([quads[:, s, i], quads[:, s, j]])
                          for s, i, j in _P2_BOUNDARY], axis=1).reshape(-1, 2)
    else:
        edges = cells[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2)
    return np.unique(np.sort(edges, axis=1), axis=0)


def _is_p2_split(cells: npt.NDArray) -> bool:
    """Whether triangles come in fours of the P2 split (the middle one is ``[5, 3, 4]``)."""
    if len(cells) == 0 or len(cells) % 4:
        return False
    q = cells.reshape(-1, 4, 3)
    middle = np.column_stack([q[:, 0, 1], q[:, 1, 2], q[:, 0, 2]])
    return bool(np.array_equal(q[:, 3], middle))


def nice_scale(points: npt.NDArray, u: npt.NDArray, fraction: float = 0.1) -> float:
    """A round displacement magnification: 1, 2 or 5 × 10ᵏ.

    It moves the largest ``|u|`` by about ``fraction`` of the domain size (1 when nothing moves).
    """
    umax = float(np.linalg.norm(u, axis=1).max()) if len(u) else 0.0
    if umax == 0.0:
        return 1.0
    target = fraction * float(np.ptp(points[:, :2], axis=0).max()) / umax
    k = np.floor(np.log10(target))
    return float(max(m for m in (1.0, 2.0, 5.0, 10.0) if m * 10**k <= target) * 10**k)


# -- backend-neutral pictures ----------------------------------------------------------------
@dataclass
class Surface:
    """Triangles coloured by a field.

    Attributes:
        points: ``(n, 2)`` (m).
        triangles: ``(m, 3)``.
        values: Per point ``(n,)`` (interpolated) or per triangle ``(m,)``.
        label: Colour-bar title (with unit).
        cmap: Matplotlib/VTK colour-map name.
    """

    points: npt.NDArray
    triangles: npt.NDArray
    values: npt.NDArray
    label: str
    cmap: str = "viridis"

    @property
    def clim(self) -> tuple[float, float]:
        """Colour range."""
        lo, hi = float(np.min(self.values)), float(np.max(self.values))
        return (lo, hi) if hi > lo else (lo - 0.5, hi + 0.5)


@dataclass
class Lines:
    """Line segments, each in its own colour or coloured by a value on the surface's map.

    Attributes:
        segments: ``(k, 2, 2)`` (m).
        width: Line width (points).
        rgb: Colours ``(k, 3)`` in [0, 1]; None: ``values`` on the surface's colour map.
        values: ``(k,)``, used when ``rgb`` is None.
        alpha: Opacity.
    """

    segments: npt.NDArray
    width: float
    rgb: npt.NDArray | None = None
    values: npt.NDArray | None = None
    alpha: float = 1.0


@dataclass
class Picture:
    """One picture: a coloured surface, lines over it (drawn in order), a legend, a title."""

    title: str
    surface: Surface
    lines: list[Lines] = field(default_factory=list)
    legend: list[tuple[str, tuple[float, float, float]]] = field(default_factory=list)


def deformed_picture(disp: Series, fractures: Series | None, step: int, fstep: int,
                     scale: float | None = None, name: str = "") -> Picture:
    """The deformed mesh coloured by ``|u|``, its fracture faces on both sides by state.

    Args:
        disp: The ``displacement`` series.
        fractures: The ``fractures`` series (segment cells with ``state``); None for a scene
            without fractures (the deformed mesh alone).
        step: Output step of ``disp``; ``fstep`` the one of ``fractures``.
        fstep: Output step of ``fractures``.
        scale: Displacement magnification (None: :func:`nice_scale`).
        name: Scene name for the title.
    """
    u = disp.fields(step)["u"][:, :2]
    scale = nice_scale(disp.points, u) if scale is None else scale
    x = disp.points[:, :2] + scale * u
    surface = Surface(x, disp.cells, 1e3 * np.linalg.norm(u, axis=1), "displacement magnitude (mm)")
    grid = Lines(x[mesh_edges(disp.cells)], 0.4, rgb=np.zeros((1, 3)), alpha=0.3)
    if fractures is None:
        title = f"{name}  t = {disp.times[step]:g} s: displacement ×{scale:g}"
        return Picture(title.strip(), surface, [grid])
    state = np.rint(fractures.fields(fstep)["state"]).astype(int)
    sides = fracture_edges(disp.points, disp.cells, fractures.points)
    cracks = Lines(x[sides.nodes], 2.5, rgb=np.asarray(STATE_COLORS)[state[sides.face]])
    counts = np.bincount(state, minlength=3)
    legend = [(f"{w} ({n} faces)", STATE_COLORS[i]) for i, (w, n) in
              enumerate(zip(STATES, counts, strict=True))]
    title = (f"{name}  t = {disp.times[step]:g} s: displacement ×{scale:g}; "
             "fracture faces (both sides) by contact state")
    return Picture(title.strip(), surface, [grid, cracks], legend)


def pressure_picture(flow: Series, step: int, fractures: Series | None = None,
                     fstep: int = -1, name: str = "") -> Picture:
    """Matrix pressure per cell; fracture pressure ``p_f`` on the fractures when given."""
    p_m = flow.fields(step)["p_m"]
    unit, factor = _pressure_unit(p_m)
    surface = Surface(flow.points, flow.cells, p_m / factor, f"p_m, p_f ({unit})", "plasma")
    lines = []
    if fractures is not None:
        p_f = fractures.fields(fstep)["p_f"] / factor
        seg = fractures.points[fractures.cells]
        lines = [Lines(seg, 8.0, rgb=np.zeros((1, 3))), Lines(seg, 5.0, values=p_f)]
    title = (f"{name}  t = {flow.times[step]:g} s: matrix pressure p_m (cells), fracture "
             "pressure p_f (outlined)")
    return Picture(title.strip(), surface, lines)


def _pressure_unit(p: npt.NDArray) -> tuple[str, float]:
    big = float(np.max(np.abs(p))) if len(p) else 0.0
    return ("MPa", 1e6) if big >= 1e6 else ("kPa", 1e3) if big >= 1e3 else ("Pa", 1.0)


@dataclass
class Faces3D:
    """Triangles in space coloured by a value per triangle (a 3D picture).

    Attributes:
        points: ``(n, 3)`` (m).
        triangles: ``(m, 3)``.
        values: ``(m,)``.
        label: Colour-bar title (with unit).
        title: Picture title.
        cmap: Matplotlib/VTK colour-map name.
    """

    points: npt.NDArray
    triangles: npt.NDArray
    values: npt.NDArray
    label: str
    title: str
    cmap: str = "magma"

    @property
    def clim(self) -> tuple[float, float]:
        """Colour range."""
        lo, hi = float(np.min(self.values)), float(np.max(self.values))
        return (lo, hi) if hi > lo else (lo - 0.5, hi + 0.5)


def opening_picture(fractures: Series, step: int, name: str = "") -> Faces3D:
    """The fracture faces of a 3D run coloured by their opening ``-jump_n`` (mm)."""
    opening = -1e3 * fractures.fields(step)["jump_n"]
    title = f"{name}  t = {fractures.times[step]:g} s: fracture opening -jump_n per face"
    return Faces3D(fractures.points, fractures.cells, opening, "opening (mm)", title.strip())


def fracture_pressure_picture(fractures: Series, step: int, name: str = "") -> Faces3D:
    """The fracture faces of a 3D run coloured by their fluid pressure ``p_f``."""
    p_f = fractures.fields(step)["p_f"]
    unit, factor = _pressure_unit(p_f)
    title = f"{name}  t = {fractures.times[step]:g} s: fracture pressure p_f per face"
    return Faces3D(fractures.points, fractures.cells, p_f / factor, f"p_f ({unit})",
                   title.strip(), cmap="plasma")


def bar_format(values, clim=None) -> str:
    """A printf format whose labels tell apart 5 ticks of the colour bar of ``values``.

    ``%.3g`` labelled a fracture pressure of 10.42-10.54 MPa (an injection at depth, 1 % above
    the hydrostatic pressure) 10.4, 10.5, 10.5, 10.5, 10.5.
    """
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    lo, hi = clim if clim is not None else ((v.min(), v.max()) if v.size else (0.0, 0.0))
    span, size = abs(hi - lo), max(abs(lo), abs(hi))
    if span == 0.0 or size == 0.0:
        return "%.3g"
    digits = int(np.ceil(np.log10(4 * size / span))) + 1
    return f"%.{min(max(digits, 3), 8)}g"


#: Direction the 3D pictures are seen from (z up).
VIEW_3D = (0.35, -0.75, 1.0)


def draw_3d(picture: Faces3D, path: Path, backend: str) -> Path:
    """Draw a 3D picture into a PNG file with ``backend`` (``pyvista`` or ``matplotlib``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if backend == "pyvista":
        import pyvista as pv

        pl = pv.Plotter(off_screen=True, window_size=WINDOW)
        pl.set_background("white")
        faces = pv.PolyData(picture.points, np.column_stack(
            [np.full(len(picture.triangles), 3), picture.triangles]).ravel())
        faces.cell_data[picture.label] = picture.values
        pl.add_mesh(faces, scalars=picture.label, cmap=picture.cmap, clim=picture.clim,
                    show_edges=True, edge_color="grey", line_width=0.5,
                    scalar_bar_args={"title": picture.label, "color": "black",
                                     "fmt": bar_format(picture.values, picture.clim)})
        pl.add_text(picture.title, position="upper_edge", font_size=9, color="black")
        pl.view_vector(VIEW_3D, viewup=(0.0, 0.0, 1.0))
        pl.show_bounds(color="black", xtitle="x (m)", ytitle="y (m)", ztitle="z (m)",
                       font_size=10)
        pl.screenshot(str(path))
        pl.close()
    else:
        _draw_3d_matplotlib(picture, path)
    return limit_size(path)


def _draw_3d_matplotlib(pic: Faces3D, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    norm = Normalize(*pic.clim)
    mappable = ScalarMappable(norm, pic.cmap)
    fig = plt.figure(figsize=(WINDOW[0] / 140, WINDOW[1] / 140))
    ax = fig.add_subplot(projection="3d")
    ax.add_collection3d(Poly3DCollection(pic.points[pic.triangles],
                                         facecolors=mappable.to_rgba(pic.values),
                                         edgecolors=(0.5, 0.5, 0.5, 0.5), linewidths=0.2))
    lo, hi = pic.points.min(axis=0), pic.points.max(axis=0)
    pad = np.where(hi > lo, 0.0, 0.05 * float(np.max(hi - lo)) or 1.0)
    lo, hi = lo - pad, hi + pad
    for axis, a, b in zip("xyz", lo, hi, strict=True):
        getattr(ax, f"set_{axis}lim")(a, b)
        getattr(ax, f"set_{axis}label")(f"{axis} (m)")
    ax.set_box_aspect(hi - lo)
    x, y, z = VIEW_3D
    ax.view_init(elev=float(np.degrees(np.arctan2(z, np.hypot(x, y)))),
                 azim=float(np.degrees(np.arctan2(y, x))))
    fig.colorbar(mappable, ax=ax, label=pic.label, shrink=0.7)
    ax.set_title(pic.title, fontsize=9)
    fig.savefig(path, dpi=140)
    plt.close(fig)


# -- backends --------------------------------------------------------------------------------
def choose_backend(preferred: str = "auto") -> str:
    """The backend to draw with: pyvista if it can render off-screen, else matplotlib.

    Raises:
        PlotError: The preferred backend (or, for ``auto``, every backend) is unavailable.
    """
    if preferred not in BACKENDS:
        raise PlotError(f"unknown backend {preferred!r}: choose one of {', '.join(BACKENDS)}")
    if preferred in ("auto", "pyvista"):
        problem = _pyvista_problem()
        if problem is None:
            return "pyvista"
        if preferred == "pyvista":
            raise PlotError(f"pyvista cannot be used: {problem}")
        log.debug("pyvista not used (%s): drawing with matplotlib", problem)
    if not _importable("matplotlib"):
        raise PlotError(INSTALL_HINT)
    return "matplotlib"


def _importable(module: str) -> bool:
    try:
        importlib.import_module(module)
    except (ImportError, OSError):
        return False
    return True


def _pyvista_problem() -> str | None:
    """Why pyvista cannot render here, or None when it can (as far as can be seen)."""
    if not _importable("pyvista"):
        return "pyvista/VTK is not importable (pip install 'poromech[plot]')"
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        if ctypes.util.find_library("EGL"):
            os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
        elif not ctypes.util.find_library("OSMesa"):
            return "no display, and neither EGL nor OSMesa for off-screen rendering"
    return None


def draw(picture: Picture, path: Path, backend: str) -> Path:
    """Draw a picture into a PNG file with ``backend`` (``pyvista`` or ``matplotlib``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if backend == "pyvista":
        _draw_pyvista(picture, path)
    else:
        _draw_matplotlib(picture, path)
    return limit_size(path)


def limit_size(path: Path, limit: int = MAX_PNG_BYTES) -> Path:
    """Keep a PNG under ``limit`` bytes: a 256-colour palette, then smaller if need be."""
    from PIL import Image

    scale = 1.0
    while path.stat().st_size > limit and scale > 0.3:
        with Image.open(path) as im:
            img = im.convert("RGB")
        if scale < 1.0:
            img = img.resize((int(img.width * scale), int(img.height * scale)),
                             Image.Resampling.LANCZOS)
        img.quantize(256, dither=Image.Dither.NONE).save(path, optimize=True)
        scale *= 0.8
    return path


def _draw_matplotlib(pic: Picture, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.lines import Line2D
    from matplotlib.tri import Triangulation

    s = pic.surface
    lo, hi = s.clim
    fig, ax = plt.subplots(figsize=(WINDOW[0] / 140, WINDOW[1] / 140))
    tri = Triangulation(s.points[:, 0], s.points[:, 1], s.triangles)
    if len(s.values) == len(s.points):
        pc = ax.tripcolor(tri, s.values, shading="gouraud", cmap=s.cmap, vmin=lo, vmax=hi)
    else:
        pc = ax.tripcolor(tri, facecolors=s.values, cmap=s.cmap, vmin=lo, vmax=hi)
    fig.colorbar(pc, ax=ax, label=s.label, shrink=0.8)
    for ln in pic.lines:
        colors = ln.rgb if ln.rgb is not None else pc.cmap(pc.norm(ln.values))
        ax.add_collection(LineCollection(ln.segments, colors=colors, linewidths=ln.width * 0.6,
                                         alpha=ln.alpha, capstyle="round"))
    if pic.legend:
        ax.legend(handles=[Line2D([], [], color=c, lw=2.5, label=t) for t, c in pic.legend],
                  loc="upper center", bbox_to_anchor=(0.5, -0.12), fontsize=8,
                  ncol=len(pic.legend), frameon=False)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(pic.title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=140)
    plt.close(fig)


def _draw_pyvista(pic: Picture, path: Path) -> None:
    import pyvista as pv

    s = pic.surface
    size = float(np.ptp(s.points, axis=0).max())
    pl = pv.Plotter(off_screen=True, window_size=WINDOW)
    pl.set_background("white")
    grid = pv.UnstructuredGrid({pv.CellType.TRIANGLE: np.asarray(s.triangles)}, _xyz(s.points))
    center = grid.point_data if len(s.values) == len(s.points) else grid.cell_data
    center[s.label] = s.values
    pl.add_mesh(grid, scalars=s.label, cmap=s.cmap, clim=s.clim, lighting=False,
                scalar_bar_args={"title": s.label, "color": "black", "vertical": False,
                                 "position_x": 0.55, "position_y": 0.02, "width": 0.4,
                                 "height": 0.1, "fmt": bar_format(s.values, s.clim),
                                 "title_font_size": 16,
                                 "label_font_size": 14, "n_labels": 5})
    for level, ln in enumerate(pic.lines, start=1):
        poly = _polylines(ln.segments, 1e-3 * level * size)
        if ln.rgb is not None:
            rgb = np.broadcast_to(ln.rgb, (len(ln.segments), 3))
            poly.cell_data["rgb"] = (255 * rgb).astype(np.uint8)
            pl.add_mesh(poly, scalars="rgb", rgb=True, line_width=ln.width, opacity=ln.alpha,
                        lighting=False)
        else:
            poly.cell_data["v"] = ln.values
            pl.add_mesh(poly, scalars="v", cmap=s.cmap, clim=s.clim, line_width=ln.width,
                        show_scalar_bar=False, lighting=False)
    if pic.legend:
        pl.add_legend([[t, c] for t, c in pic.legend], bcolor="white", border=False,
                      loc="lower left", size=(0.24, 0.11), face="line")
    pl.add_text(pic.title, position="upper_edge", font_size=9, color="black")
    _frame(pl, s.points)
    pl.screenshot(str(path))
    pl.close()


def _frame(pl, points: npt.NDArray, top: float = 0.08, bottom: float = 0.2,
           side: float = 0.03) -> None:
    """Look at the xy-plane in parallel projection, the points filling the window.

    Margins (fractions of the window height/width) are left for the title, the legend and the
    colour bar.
    """
    lo, hi = points.min(axis=0), points.max(axis=0)
    w, h = hi - lo
    aspect = WINDOW[0] / WINDOW[1]
    height = max(h / (1 - top - bottom), w / (1 - 2 * side) / aspect)
    cx, cy = 0.5 * (lo + hi)
    cy -= 0.5 * (bottom - top) * height
    pl.enable_parallel_projection()
    pl.camera.focal_point = (cx, cy, 0.0)
    pl.camera.position = (cx, cy, 10.0 * max(w, h))
    pl.camera.up = (0.0, 1.0, 0.0)
    pl.camera.parallel_scale = 0.5 * height
    pl.reset_camera_clipping_range()


def _xyz(points: npt.NDArray, z: float = 0.0) -> npt.NDArray:
    return np.column_stack([points[:, 0], points[:, 1], np.full(len(points), z)])


def _polylines(segments: npt.NDArray, z: float):
    import pyvista as pv

    k = len(segments)
    lines = np.column_stack([np.full(k, 2), 2 * np.arange(k), 2 * np.arange(k) + 1])
    return pv.PolyData(_xyz(segments.reshape(-1, 2), z), lines=lines.ravel())


# -- jumps (matplotlib) ----------------------------------------------------------------------
def plot_jumps(res: Results, time: float | None, path: Path) -> Path:
    """Normal and tangential jumps (mm) along each fracture at one output time (matplotlib)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    rows = res.fractures(time=res.times("fractures")[-1] if time is None else time)
    names = list(dict.fromkeys(rows["fracture"]))
    ncol = min(3, len(names))
    nrow = -(-len(names) // ncol)
    height = 2.6 * nrow + (0.6 if nrow == 1 else 0.0)  # room for the title and the legend
    fig, axes = plt.subplots(nrow, ncol, figsize=(max(4 * ncol, 7), height), squeeze=False,
                             sharey=True)
    colors = np.asarray(STATE_COLORS)[[STATES.index(w) for w in rows["state"]]]
    along = "s" in rows  # 2D: the arc length; 3D: the distance from the fracture's centre
    for ax, name in zip(axes.flat, names, strict=False):
        on = rows["fracture"] == name
        if along:
            s = rows["s"][on]
        else:
            x = np.column_stack([rows["x"][on], rows["y"][on], rows["z"][on]])
            s = np.linalg.norm(x - x.mean(axis=0), axis=1)
        order = np.argsort(s, kind="stable")
        for key, style in (("jump_n", "-"), ("jump_t", "--")):
            v = 1e3 * rows[key][on][order]
            if along:
                ax.plot(s[order], v, style, color="0.3", lw=1)
            ax.scatter(s[order], v, c=colors[on][order], s=9, zorder=3,
                       marker="o" if key == "jump_n" else "^")
        ax.axhline(0.0, color="0.7", lw=0.5)
        ax.set_title(f"fracture {name}", fontsize=9)
        ax.set_xlabel("s (m)" if along else "distance from the fracture's centre (m)",
                      fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in axes.flat[len(names):]:
        ax.set_visible(False)
    for ax in axes[:, 0]:
        ax.set_ylabel("jump (mm)", fontsize=8)
    line = {"ls": "-"} if along else {"ls": "", "marker": "o"}
    handles = [Line2D([], [], color="0.3", **line, label="jump_n (< 0 open)"),
               Line2D([], [], color="0.3", **({"ls": "--"} if along else
                                             {"ls": "", "marker": "^"}), label="jump_t"),
               *(Line2D([], [], ls="", marker="o", color=c, label=w)
                 for w, c in zip(STATES, STATE_COLORS, strict=True))]
    fig.legend(handles=handles, loc="lower center", ncol=5, fontsize=8, frameon=False)
    t = float(rows["time"][0]) if len(rows["time"]) else float("nan")
    fig.suptitle(f"{res.summary.get('scene', '')}  t = {t:g} s: jumps along each fracture "
                 "(faces coloured by contact state)", fontsize=10)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return limit_size(path)


# -- a run -----------------------------------------------------------------------------------
def _step(series: Series, time: float | None) -> int:
    """Index of the output step nearest to ``time`` (the last one when None)."""
    if not series.times:
        raise PlotError("the series has no completed output step yet")
    if time is None:
        return len(series.times) - 1
    return int(np.argmin(np.abs(np.asarray(series.times) - time)))


def _tag(t: float) -> str:
    return f"t{t:g}"


def plot_run(outdir: str | Path, time: float | None = None, scale: float | None = None,
             out: str | Path | None = None, backend: str = "auto") -> list[Path]:
    """Write the pictures of a run's outputs at one output time (serial).

    Args:
        outdir: Output directory of the run.
        time: Output time to show (the nearest one written); None: the last.
        scale: Displacement magnification of the deformed mesh; None: chosen so that the
            largest displacement is drawn as about 10 % of the domain size.
        out: Directory of the PNGs (default ``OUTDIR/plots``).
        backend: ``auto`` (pyvista when it can render, else matplotlib), ``pyvista`` or
            ``matplotlib``; the jump plots are always matplotlib.

    Returns:
        The PNG files written.

    Raises:
        PlotError: No backend, or a run with nothing to draw.
        FileNotFoundError: ``outdir`` is not an output directory.
    """
    res = open_results(outdir)
    backend = choose_backend(backend)
    out = Path(out) if out is not None else res.path / "plots"
    name = str(res.summary.get("scene", ""))
    present = res.series_names
    if time is None and present:  # the last time every series has (a killed run may differ)
        time = min((res.times(s)[-1] for s in present if res.times(s)), default=None)
    written: list[Path] = []
    if "displacement" in present:
        disp = res.series("displacement")
        frac = res.series("fractures") if "fractures" in present else None
        k = _step(disp, time)
        if disp.cells.shape[1] != 3:  # not triangles: 3D, the opening on the fractures
            if frac is not None:
                pic3 = opening_picture(frac, _step(frac, disp.times[k]), name)
                written.append(draw_3d(pic3, out / f"opening_{_tag(disp.times[k])}.png",
                                       backend))
            else:
                log.info("a 3D displacement without fractures is not drawn: open "
                         "displacement.xdmf in ParaView")
        else:
            fk = _step(frac, disp.times[k]) if frac is not None else -1
            pic = deformed_picture(disp, frac, k, fk, scale, name)
            written.append(draw(pic, out / f"deformed_{_tag(disp.times[k])}.png", backend))
        if (res.path / "fractures.csv").exists():
            written.append(plot_jumps(res, disp.times[k], out / f"jumps_{_tag(disp.times[k])}.png"))
    if "flow" in present:
        flow = res.series("flow")
        k = _step(flow, time)
        stem = "fractures" if "fractures" in present else "fractures_flow"
        frac = res.series(stem) if stem in present else None
        fk = _step(frac, flow.times[k]) if frac is not None else -1
        if frac is not None and "p_f" not in frac.fields(fk):
            frac = None
        if flow.cells.shape[1] == 4:  # tetrahedra: the fracture pressure on the fractures
            if frac is not None:
                pic3 = fracture_pressure_picture(frac, fk, name)
                written.append(draw_3d(pic3, out / f"pressure_{_tag(flow.times[k])}.png",
                                       backend))
            else:
                log.info("the 3D matrix pressure is not drawn: open flow.xdmf in ParaView")
        else:
            pic = pressure_picture(flow, k, frac, fk, name)
            written.append(draw(pic, out / f"pressure_{_tag(flow.times[k])}.png", backend))
    if not written:
        raise PlotError(f"{res.path}: nothing to draw (no displacement or flow series, which a "
                        "run writes from its first completed output step; or 3D without "
                        "fractures: open the .xdmf files in ParaView)")
    return written
