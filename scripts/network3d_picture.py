"""The picture of the shipped 3D contact scene: the seven-fracture network after the shear.

Runs ``configs/network3d.yaml`` (an X, a T, a fracture reaching the front face and a kink in a
2 m box; compression, then shear along x; Coulomb friction F = 0.5, ``nitsche`` θ = -1, P2) and
draws from its output files, with pyvista (off-screen VTK), the fracture faces at the final
time:

* left, coloured by their contact state (open, stick, slip, from ``fractures.csv``'s rule);
* right, coloured by the slip magnitude ``|[[u]]_τ|`` (mm), with the slip vectors of the
  slipping faces as arrows.

Usage::

    .venv/bin/python scripts/network3d_picture.py     # -> docs/images/network3d/states.png
"""

import poromech  # noqa: F401, I001  (first: loads MPI before DOLFINx/PETSc)

import argparse
from pathlib import Path

import numpy as np
from mpi4py import MPI

from poromech.io.plot import limit_size
from poromech.io.results import open_results
from poromech.run import run_scene
from poromech.scene.loading import load_scene_and_raw

ROOT = Path(__file__).resolve().parents[1]
WINDOW = (1600, 700)
BAR = {"color": "black", "vertical": False, "position_x": 0.2, "position_y": 0.03,
       "width": 0.6, "height": 0.07, "title_font_size": 16, "label_font_size": 14}
#: State colours: open, stick, slip.
COLORS = ("#d9d9d9", "#2b83ba", "#d7191c")
VIEW = (0.55, -0.9, 0.7)


def draw(outdir: Path, png: Path) -> Path:
    """The two panels from the outputs of a network run (serial)."""
    import pyvista as pv
    from matplotlib.colors import ListedColormap

    frac = open_results(outdir).series("fractures")
    f = frac.fields(-1)
    faces = pv.PolyData(frac.points, np.column_stack(
        [np.full(len(frac.cells), 3), frac.cells]).ravel())
    state = np.rint(f["state"]).astype(int)
    faces.cell_data["state"] = state
    faces.cell_data["slip (mm)"] = 1e3 * f["jump_t"]
    counts = {name: int(np.count_nonzero(state == k))
              for k, name in enumerate(("open", "stick", "slip"))}
    box = pv.Box(bounds=(0.0, 2.0, 0.0, 2.0, 0.0, 2.0))

    pl = pv.Plotter(off_screen=True, window_size=WINDOW, shape=(1, 2), border=False)
    pl.set_background("white")
    pl.subplot(0, 0)
    pl.add_mesh(box, style="wireframe", color="black", line_width=1)
    pl.add_mesh(faces, scalars="state", cmap=ListedColormap(COLORS), clim=(-0.5, 2.5),
                show_edges=True, edge_color="grey", line_width=0.5, show_scalar_bar=False)
    pl.add_text(f"t = {frac.times[-1]:g} s: contact state per face\n"
                f"open {counts['open']} (grey), stick {counts['stick']} (blue), "
                f"slip {counts['slip']} (red)", font_size=10, color="black")
    pl.view_vector(VIEW, viewup=(0.0, 0.0, 1.0))
    pl.camera.zoom(1.3)

    pl.subplot(0, 1)
    pl.add_mesh(box, style="wireframe", color="black", line_width=1)
    pl.add_mesh(faces, scalars="slip (mm)", cmap="viridis", show_edges=True,
                edge_color="grey", line_width=0.5,
                scalar_bar_args={**BAR, "title": "slip |[[u]]_t| (mm)", "fmt": "%.3f"})
    sliding = state == 2
    if np.any(sliding):
        centres = frac.points[frac.cells[sliding]].mean(axis=1)
        vec = np.column_stack([f[f"jump_t{c}"][sliding] for c in "xyz"])
        scale = 0.08 / max(np.linalg.norm(vec, axis=1).max(), 1e-30)
        arrows = pv.PolyData(centres)
        arrows["v"] = vec * scale
        pl.add_mesh(arrows.glyph(orient="v", scale=False, factor=0.06), color="black")
    pl.add_text("slip magnitude per face; arrows: slip direction of the slipping faces",
                font_size=10, color="black")
    pl.view_vector(VIEW, viewup=(0.0, 0.0, 1.0))
    pl.camera.zoom(1.3)
    png.parent.mkdir(parents=True, exist_ok=True)
    pl.screenshot(str(png))
    pl.close()
    return limit_size(png)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, default=ROOT / "results" / "network3d_picture")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images" / "network3d" /
                        "states.png")
    parser.add_argument("--draw-only", action="store_true", help="draw from --run's outputs")
    args = parser.parse_args()
    if not args.draw_only:
        scene, raw = load_scene_and_raw(str(ROOT / "configs" / "network3d.yaml"))
        run_scene(scene, args.run, raw=raw)
    if MPI.COMM_WORLD.rank == 0:
        png = draw(args.run, args.out)
        print(png.relative_to(ROOT) if png.is_relative_to(ROOT) else png,
              f"{png.stat().st_size // 1000} KB")


if __name__ == "__main__":
    main()
